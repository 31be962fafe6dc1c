// The Bullet adapter against analytic answers and phys's conventions: free fall, a resting
// box, a body whose shapes are offset from its origin (centre-of-mass frame conversions), a
// hinge pendulum and motor, phys's material mixing. Skips when Bullet is not compiled in.
#include <gtest/gtest.h>

#include <cmath>

#include "peer_test_util.h"
#include "peers/peer.h"
#include "peers/runner.h"
#include "phys/scene/scene.h"

using namespace phys;
using namespace phys::peers;

namespace {

BodyDef groundDef(float restitution = 0) {
  BodyDef g;
  g.type = BodyType::Static;
  ShapeDef s;
  s.geom = ShapeGeom::plane({0, 0, 1}, 0);
  s.material.restitution = restitution;
  g.shapes.push_back(s);
  return g;
}

BodyDef shapeBody(Vec3 p, ShapeGeom geom, Transform local = {}) {
  BodyDef b;
  b.position = p;
  ShapeDef s;
  s.geom = std::move(geom);
  s.local = local;
  b.shapes.push_back(s);
  return b;
}

std::unique_ptr<PeerEngine> bulletOrSkip() {
  return makePeer("bullet");
}

#define REQUIRE_BULLET(peer) \
  if (!(peer)) GTEST_SKIP() << "Bullet is not compiled in"

using testutil::stepAndRead;

}  // namespace

TEST(Bullet, FreeFallFollowsSemiImplicitEuler) {
  auto peer = bulletOrSkip();
  REQUIRE_BULLET(peer);
  Scene scene;
  scene.bodies = {shapeBody({0, 0, 10}, ShapeGeom::sphere(0.5f))};
  ASSERT_TRUE(peer->build(scene, {}).ok());
  const int n = 60;
  const double h = scene.world.timeStep, g = 9.81, t = n * h;
  auto s = stepAndRead(*peer, n);
  // Symplectic Euler: z_n = z0 - g h^2 n (n + 1) / 2, which is z0 - g t^2 / 2 - g t h / 2.
  EXPECT_NEAR(s[0].position.z, 10 - g * h * h * n * (n + 1) / 2, 1e-4);
  EXPECT_NEAR(s[0].position.z, 10 - g * t * t / 2, g * t * h / 2 + 1e-4);
  EXPECT_NEAR(s[0].linearVelocity.z, -g * t, 1e-4);
  EXPECT_EQ(peer->name(), "bullet");
  EXPECT_EQ(peer->version(), "3.24");
}

TEST(Bullet, BoxRestsOnTheGround) {
  auto peer = bulletOrSkip();
  REQUIRE_BULLET(peer);
  Scene scene;
  scene.bodies = {groundDef(), shapeBody({0, 0, 0.5f}, ShapeGeom::box({0.5f, 0.5f, 0.5f}))};
  scene.metrics.topBodies = {1};
  PeerRun run = runPeer(scene, *peer, {}, 2.0);
  ASSERT_TRUE(run.status.ok()) << run.status.message;
  EXPECT_EQ(run.summary.steps, 120);
  EXPECT_LT(*run.summary.penetrationMax, 0.005);
  EXPECT_LT(*run.summary.topDrift, 0.005);  // Bullet: 1.4 mm in 2 s
  EXPECT_EQ(run.summary.nan, 0);
}

TEST(Bullet, OffsetShapeSpinsAboutItsCentreOfMassAndTheOriginFollows) {
  auto peer = bulletOrSkip();
  REQUIRE_BULLET(peer);
  Scene scene;
  scene.world.gravity = {0, 0, 0};
  // The box's centre (the centre of mass) is 1 m from the body origin along x.
  BodyDef b = shapeBody({0, 0, 5}, ShapeGeom::box({0.4f, 0.2f, 0.1f}), {{1, 0, 0}, {}});
  b.angularVelocity = {0, 0, 2};
  scene.bodies = {b};
  ASSERT_TRUE(peer->build(scene, {}).ok());
  auto s = stepAndRead(*peer, 60);
  const float angle = 2.0f * 60 * scene.world.timeStep;
  Quat q = Quat::fromAxisAngle({0, 0, 1}, angle);
  EXPECT_NEAR(std::fabs(s[0].rotation.z), std::fabs(q.z), 1e-4);
  EXPECT_NEAR(std::fabs(s[0].rotation.w), std::fabs(q.w), 1e-4);
  // The origin circles the fixed centre of mass (1, 0, 5) at radius 1.
  Vec3 com = s[0].position + rotate(s[0].rotation, {1, 0, 0});
  EXPECT_NEAR(com.x, 1, 1e-4);
  EXPECT_NEAR(com.y, 0, 1e-4);
  EXPECT_NEAR(s[0].position.x, 1 - std::cos(angle), 1e-3);
  EXPECT_NEAR(s[0].position.y, -std::sin(angle), 1e-3);
  EXPECT_NEAR(s[0].angularVelocity.z, 2, 1e-4);
  EXPECT_NEAR(length(s[0].linearVelocity), 0, 1e-4);
}

TEST(Bullet, TiltedCompoundKeepsItsAngularMomentum) {
  auto peer = bulletOrSkip();
  REQUIRE_BULLET(peer);
  // Two boxes off the origin and tilted: the principal axes are not the body axes, so the
  // body is a compound in its principal frame. Spinning freely, its world angular momentum
  // (measured with phys's inertia at the states Bullet reports) must stay put.
  Scene scene;
  scene.world.gravity = {0, 0, 0};
  BodyDef b;
  b.position = {0, 0, 5};
  b.angularVelocity = {0.3f, 0.5f, 2};
  b.linearVelocity = {1, 0, 0};
  ShapeDef s1, s2;
  s1.geom = ShapeGeom::box({0.5f, 0.2f, 0.1f});
  s1.local = {{0.5f, 0, 0}, Quat::fromAxisAngle({1, 0, 0}, 0.4f)};
  s2.geom = ShapeGeom::sphere(0.3f);
  s2.local = {{-0.2f, 0.4f, 0.1f}, {}};
  b.shapes = {s1, s2};
  scene.bodies = {b};
  ASSERT_TRUE(peer->build(scene, {}).ok());

  World mirror(scene.world);
  std::vector<BodyId> ids;
  ASSERT_TRUE(instantiateScene(scene, &mirror, &ids).ok());
  auto momentum = [&](const PeerBodyState& st) {
    EXPECT_TRUE(
        mirror.observe(ids, {{st.position, st.rotation, st.linearVelocity, st.angularVelocity}}, 0)
            .ok());
    BodyState bs;
    mirror.getBody(ids[0], &bs);
    return bs.inertia * bs.angularVelocity;
  };
  BodyState start;
  mirror.getBody(ids[0], &start);
  const Vec3 L0 = start.inertia * start.angularVelocity;
  const Vec3 com0 = start.centerOfMass;
  const double E0 = mirror.energy();
  auto s = stepAndRead(*peer, 1);
  // The first state read back is the scene's body (frame conversions are exact).
  EXPECT_LT(length(momentum(s[0]) - L0), 2e-3 * length(L0));
  s = stepAndRead(*peer, 119);
  EXPECT_LT(length(momentum(s[0]) - L0), 2e-2 * length(L0));
  EXPECT_NEAR(mirror.energy(), E0, 2e-2 * E0);
  BodyState end;
  mirror.getBody(ids[0], &end);
  // The centre of mass moves in a straight line at 1 m/s for 2 s.
  EXPECT_NEAR(end.centerOfMass.x, com0.x + 2, 1e-3);
  EXPECT_NEAR(end.centerOfMass.y, com0.y, 1e-3);
  EXPECT_NEAR(end.centerOfMass.z, com0.z, 1e-3);
}

TEST(Bullet, HingePendulumHoldsItsJoint) {
  auto peer = bulletOrSkip();
  REQUIRE_BULLET(peer);
  Scene scene;
  // A 2 m bar hinged to the world at one end about y, released horizontally.
  scene.bodies = {shapeBody({1, 0, 5}, ShapeGeom::box({1, 0.05f, 0.05f}))};
  SceneJoint j;
  j.def.type = JointType::Hinge;
  j.def.anchorA = {0, 0, 5};
  j.def.anchorB = {-1, 0, 0};
  j.def.axisA = j.def.axisB = {0, 1, 0};
  j.bodyB = 0;
  scene.joints = {j};
  PeerRun run = runPeer(scene, *peer, {}, 3.0);
  ASSERT_TRUE(run.status.ok()) << run.status.message;
  EXPECT_LT(*run.summary.jointErrorMax, 0.01);
  EXPECT_LT(*run.summary.jointAngleErrorMax, 0.01);
  // It swings: at the bottom, w^2 = 3 g / L, so its centre moves at sqrt(3 g / 2) = 3.8 m/s.
  EXPECT_NEAR(run.summary.maxSpeed, std::sqrt(3 * 9.81 / 2), 0.2);
  EXPECT_EQ(run.summary.nan, 0);
}

TEST(Bullet, HingeMotorTurnsTheWayPhysDoes) {
  auto peer = bulletOrSkip();
  REQUIRE_BULLET(peer);
  ASSERT_TRUE(peer->build(testutil::hingedPlate(/*motor=*/true), {}).ok());
  auto s = stepAndRead(*peer, 60);
  // phys: the motor drives B's angular velocity relative to A along A's axis to the speed.
  EXPECT_NEAR(s[0].angularVelocity.z, 1.5, 0.02);
}

TEST(Bullet, HingeLimitStopsAtPhysAngles) {
  auto peer = bulletOrSkip();
  REQUIRE_BULLET(peer);
  ASSERT_TRUE(peer->build(testutil::hingedPlate(/*motor=*/false), {}).ok());
  EXPECT_NEAR(testutil::largestTurnAboutZ(*peer, 30), 0.3, 0.05);
}

TEST(Bullet, SliderMotorAndLimitFollowPhysSigns) {
  auto peer = bulletOrSkip();
  REQUIRE_BULLET(peer);
  ASSERT_TRUE(peer->build(testutil::drivenSlider(), {}).ok());
  auto s = stepAndRead(*peer, 12);
  EXPECT_NEAR(s[0].linearVelocity.x, 0.5, 0.02);
  s = stepAndRead(*peer, 60);
  EXPECT_NEAR(s[0].position.x, 0.2, 0.01);
  EXPECT_NEAR(s[0].position.y, 0, 1e-4);
  EXPECT_NEAR(s[0].position.z, 1, 1e-4);
}

TEST(Bullet, FixedJointHoldsABeamAtItsInitialPose) {
  auto peer = bulletOrSkip();
  REQUIRE_BULLET(peer);
  Scene scene;
  // A tilted beam welded to the world at one end: the weld keeps its pose under gravity.
  BodyDef beam = shapeBody({0.5f, 0, 2}, ShapeGeom::box({0.5f, 0.05f, 0.05f}));
  beam.rotation = Quat::fromAxisAngle({0, 0, 1}, 0.3f);
  scene.bodies = {beam};
  SceneJoint j;
  j.def.type = JointType::Fixed;
  j.def.anchorA = beam.position + rotate(beam.rotation, {-0.5f, 0, 0});
  j.def.anchorB = {-0.5f, 0, 0};
  j.bodyB = 0;
  scene.joints = {j};
  // Without gravity the weld starts and stays exact (the frames match phys's).
  scene.world.gravity = {0, 0, 0};
  PeerRun run = runPeer(scene, *peer, {}, 1.0);
  ASSERT_TRUE(run.status.ok()) << run.status.message;
  EXPECT_LT(*run.summary.jointErrorMax, 1e-4);
  EXPECT_LT(*run.summary.jointAngleErrorMax, 1e-4);
  // Under gravity Bullet's weld (a 6-dof constraint with ERP 0.2) sags: 0.03 rad here.
  scene.world.gravity = {0, 0, -9.81f};
  auto gravity = makePeer("bullet");
  run = runPeer(scene, *gravity, {}, 2.0);
  ASSERT_TRUE(run.status.ok()) << run.status.message;
  EXPECT_LT(*run.summary.jointErrorMax, 0.005);
  EXPECT_LT(*run.summary.jointAngleErrorMax, 0.05);
}

TEST(Bullet, KinematicBodyMovesAtItsVelocity) {
  auto peer = bulletOrSkip();
  REQUIRE_BULLET(peer);
  Scene scene;
  BodyDef platform = shapeBody({0, 0, 1}, ShapeGeom::box({1, 1, 0.1f}));
  platform.type = BodyType::Kinematic;
  platform.linearVelocity = {1, 0, 0};
  platform.angularVelocity = {0, 0, 0.5f};
  scene.bodies = {platform};
  ASSERT_TRUE(peer->build(scene, {}).ok());
  auto s = stepAndRead(*peer, 60);
  EXPECT_NEAR(s[0].position.x, 1, 1e-4);
  EXPECT_NEAR(s[0].position.z, 1, 1e-6);
  EXPECT_NEAR(2 * std::atan2(s[0].rotation.z, s[0].rotation.w), 0.5, 1e-3);
  EXPECT_NEAR(s[0].linearVelocity.x, 1, 1e-3);
  EXPECT_NEAR(s[0].angularVelocity.z, 0.5, 1e-3);
}

TEST(Bullet, RestitutionMixesAsPhysDoes) {
  auto peer = bulletOrSkip();
  REQUIRE_BULLET(peer);
  // e = max(0.5, 0): Bullet's own product would be 0 (no bounce).
  Scene scene;
  BodyDef ball = shapeBody({0, 0, 1.2f}, ShapeGeom::sphere(0.2f));
  ball.shapes[0].material.restitution = 0.5f;
  scene.bodies = {groundDef(0), ball};
  ASSERT_TRUE(peer->build(scene, {}).ok());
  double apex = 0;
  bool bounced = false;
  for (int i = 0; i < 120; ++i) {
    auto s = stepAndRead(*peer, 1);
    if (s[1].linearVelocity.z > 0.5f) bounced = true;
    if (bounced) apex = std::max(apex, double(s[1].position.z) - 0.2);
  }
  // Bullet's product would give no bounce at all; with max(0.5, 0) it rebounds to 0.33 m
  // (phys: 0.25 m): Bullet's restitution acts on the approach speed a step late.
  EXPECT_GT(apex, 0.2);
  EXPECT_LT(apex, 0.4);
}

TEST(Bullet, DistanceJointsAreUnsupported) {
  auto peer = bulletOrSkip();
  REQUIRE_BULLET(peer);
  Scene scene;
  scene.bodies = {shapeBody({0, 0, 1}, ShapeGeom::sphere(0.1f))};
  SceneJoint j;
  j.def.type = JointType::Distance;
  j.def.anchorA = {0, 0, 2};
  j.bodyB = 0;
  scene.joints = {j};
  Status st = peer->build(scene, {});
  EXPECT_FALSE(st.ok());
  EXPECT_NE(st.message.find("unsupported: joints[0]: distance"), std::string::npos) << st.message;
}
