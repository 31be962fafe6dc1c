// The Box3D peer's own tests (built only with -DPHYS_BOX3D_DIR, i.e. when PHYS_PEER_BOX3D is
// defined): free fall at Box3D's substeps, a box resting on the ground (a plane, which Box3D
// gets as a large box), hinge and slider signs, a distance spring (which Box3D has), the
// budget's substeps and threads, and what it reports as unsupported. The checks shared with the
// other engines (test_engines.cpp) run on it as well.
#ifdef PHYS_PEER_BOX3D

#include <gtest/gtest.h>

#include <cmath>

#include "peer_test_util.h"
#include "peers/peer.h"
#include "peers/runner.h"
#include "phys/scene/scene.h"

namespace phys::peers {
namespace {

using namespace testutil;

std::unique_ptr<PeerEngine> makeBox3d() {
  auto peer = makePeer("box3d");
  EXPECT_TRUE(peer) << "PHYS_PEER_BOX3D is defined but makePeer(\"box3d\") failed";
  return peer;
}

/// Symplectic Euler over n steps of h in s substeps: z0 - g (h/s)^2 N (N + 1) / 2, N = s n.
double substeppedFall(double z0, double h, int n, int s) {
  const double hs = h / s, N = double(s) * n;
  return z0 - 0.5 * kG * hs * hs * N * (N + 1);
}

TEST(Box3d, NameVersionAndRegistryOrder) {
  auto peer = makeBox3d();
  ASSERT_TRUE(peer);
  EXPECT_EQ(peer->name(), "box3d");
  EXPECT_EQ(peer->version(), "0.2.0");  // b3GetVersion() of the measured commit
  std::vector<std::string> names = peerNames();
  ASSERT_FALSE(names.empty());
  EXPECT_EQ(names.back(), "box3d");  // bullet, ode, mujoco, box3d
}

TEST(Box3d, FreeFallFollowsSymplecticEulerPerSubstep) {
  for (int substeps : {0, 2, 8}) {  // 0: the budget's default 1, i.e. Box3D's own 4
    SCOPED_TRACE(substeps);
    auto peer = makeBox3d();
    ASSERT_TRUE(peer);
    Scene scene;
    scene.bodies.push_back(ball({0, 0, 10}, 0.5f));
    scene.bodies[0].linearVelocity = {1, 0, 0};
    PeerBudget budget;
    budget.substeps = substeps > 0 ? substeps : 1;
    ASSERT_TRUE(peer->build(scene, budget).ok());
    const int n = 60, s = substeps > 0 ? substeps : 4;
    const double h = scene.world.timeStep;
    PeerBodyState st = run(*peer, n, 0);
    EXPECT_NEAR(st.position.z, substeppedFall(10, h, n, s), 2e-4);
    EXPECT_NEAR(st.position.x, n * h, 1e-4);
    EXPECT_NEAR(st.linearVelocity.z, -kG * n * h, 1e-4);
  }
}

TEST(Box3d, BoxRestsOnTheGroundPlane) {
  auto peer = makeBox3d();
  ASSERT_TRUE(peer);
  Scene scene;
  scene.bodies = {ground(), box({3, -2, 0.5f}, {0.5f, 0.5f, 0.5f})};
  scene.metrics.topBodies = {1};
  PeerRun run = runPeer(scene, *peer, {}, 3.0);
  ASSERT_TRUE(run.status.ok()) << run.status.message;
  EXPECT_EQ(run.summary.steps, 180);
  EXPECT_EQ(run.summary.nan, 0);
  // Box3D lets contacts sink by up to its linear slop (5 mm) before pushing out.
  EXPECT_LT(*run.summary.penetrationMax, 0.006);
  EXPECT_LT(*run.summary.topDrift, 1e-3);
}

TEST(Box3d, PlaneWithOffsetAndTiltIsItsTopFace) {
  auto peer = makeBox3d();
  ASSERT_TRUE(peer);
  // The plane z = 2 given as normal (0, 0, 1), offset 2 on a body turned about z and moved
  // sideways: a ball lands on it at z = 2 + r wherever the plane body is.
  Scene scene;
  BodyDef g = ground();
  g.shapes[0].geom = ShapeGeom::plane({0, 0, 1}, 2);
  g.position = {50, 0, 0};
  g.rotation = Quat::fromAxisAngle({0, 0, 1}, 0.7f);
  scene.bodies = {g, ball({0, 0, 3}, 0.25f)};
  ASSERT_TRUE(peer->build(scene, {}).ok());
  PeerBodyState s = run(*peer, 120, 1);
  EXPECT_NEAR(s.position.z, 2.25f, 0.006f);
  EXPECT_LT(length(s.linearVelocity), 1e-2f);
}

TEST(Box3d, HingeMotorAndLimitFollowPhysSigns) {
  {
    auto peer = makeBox3d();
    ASSERT_TRUE(peer);
    ASSERT_TRUE(peer->build(hingedPlate(/*motor=*/true), {}).ok());
    EXPECT_NEAR(run(*peer, 60, 0).angularVelocity.z, 1.5, 0.02);
  }
  {
    auto peer = makeBox3d();
    ASSERT_TRUE(peer);
    ASSERT_TRUE(peer->build(hingedPlate(/*motor=*/false), {}).ok());
    EXPECT_NEAR(largestTurnAboutZ(*peer, 30), 0.3, 0.02);
  }
}

TEST(Box3d, SliderMotorAndLimitFollowPhysSigns) {
  auto peer = makeBox3d();
  ASSERT_TRUE(peer);
  ASSERT_TRUE(peer->build(drivenSlider(), {}).ok());
  PeerBodyState s = run(*peer, 12, 0);
  EXPECT_NEAR(s.linearVelocity.x, 0.5, 0.02);
  s = run(*peer, 60, 0);
  EXPECT_NEAR(s.position.x, 0.2, 0.01);
  EXPECT_NEAR(s.position.y, 0, 1e-4);
  EXPECT_NEAR(s.position.z, 1, 1e-4);
}

TEST(Box3d, PrismaticLimitUnderGravityStopsTheSlide) {
  auto peer = makeBox3d();
  ASSERT_TRUE(peer);
  ASSERT_TRUE(peer->build(fallingSlider(), {}).ok());
  PeerBodyState s = run(*peer, 120, 0);
  EXPECT_NEAR(s.position.z, 4, 0.01);
  EXPECT_NEAR(s.position.x, 1, 1e-4);
  EXPECT_NEAR(s.position.y, 2, 1e-4);
  EXPECT_LT(length(s.linearVelocity), 0.05f);
}

TEST(Box3d, DistanceSpringOscillatesAtItsFrequency) {
  // Weightless ball on a 1 Hz undamped distance spring of rest length 1 to a world point,
  // released 0.1 m stretched: it oscillates about 1 m with a period near 1 s.
  auto peer = makeBox3d();
  ASSERT_TRUE(peer);
  Scene scene;
  scene.world.gravity = {};
  scene.bodies = {ball({1.1f, 0, 5}, 0.05f)};
  SceneJoint j;
  j.def.type = JointType::Distance;
  j.def.anchorA = {0, 0, 5};
  j.def.length = 1;
  j.def.springHertz = 1;
  j.def.springDampingRatio = 0;
  j.bodyB = 0;
  scene.joints = {j};
  ASSERT_TRUE(peer->build(scene, {}).ok());
  // Period from the upward crossings of x - 1.
  std::vector<PeerBodyState> s;
  const double h = scene.world.timeStep;
  double prev = 0.1, first = -1, last = -1;
  int crossings = 0;
  for (int k = 1; k * h <= 5; ++k) {
    peer->step();
    peer->read(&s);
    const double x = s[0].position.x - 1;
    if (prev < 0 && x >= 0) {
      const double tc = (k - 1 + prev / (prev - x)) * h;
      if (first < 0) first = tc;
      last = tc;
      ++crossings;
    }
    prev = x;
  }
  ASSERT_GT(crossings, 2);
  EXPECT_NEAR((last - first) / (crossings - 1), 1.0, 0.05);
}

TEST(Box3d, SameStatesOnOneAndTwoWorkerThreads) {
  // Box3D is deterministic across worker counts: the budget's threads reach its scheduler and
  // change nothing but the time.
  Scene scene;
  ASSERT_TRUE(loadSceneFile(PHYS_SOURCE_DIR "/configs/scenes/pyramid_20.json", &scene).ok());
  std::vector<PeerBodyState> one, two;
  for (int threads : {1, 2}) {
    auto peer = makeBox3d();
    ASSERT_TRUE(peer);
    PeerBudget budget;
    budget.threads = threads;
    ASSERT_TRUE(peer->build(scene, budget).ok());
    (threads == 1 ? one : two) = stepAndRead(*peer, 60);
  }
  ASSERT_EQ(one.size(), two.size());
  for (size_t i = 0; i < one.size(); ++i) {
    EXPECT_EQ(one[i].position, two[i].position) << "body " << i;
    EXPECT_EQ(one[i].rotation, two[i].rotation) << "body " << i;
  }
}

TEST(Box3d, RestitutionMixesAsPhysDoes) {
  // e = max(0.5, 0) (Box3D's default mixing is phys's): the ball rebounds to about e^2 h.
  auto peer = makeBox3d();
  ASSERT_TRUE(peer);
  Scene scene;
  BodyDef b = ball({0, 0, 1.2f}, 0.2f);
  b.shapes[0].material.restitution = 0.5f;
  scene.bodies = {ground(), b};
  ASSERT_TRUE(peer->build(scene, {}).ok());
  double apex = 0;
  bool bounced = false;
  for (int i = 0; i < 120; ++i) {
    PeerBodyState s = run(*peer, 1, 1);
    if (s.linearVelocity.z > 0.5f) bounced = true;
    if (bounced) apex = std::max(apex, double(s.position.z) - 0.2);
  }
  EXPECT_NEAR(apex, 0.25, 0.03);
}

TEST(Box3d, ReportsWhatItCannotExpress) {
  auto expectUnsupported = [](const Scene& scene, const PeerBudget& budget, const char* what) {
    auto peer = makeBox3d();
    ASSERT_TRUE(peer);
    Status st = peer->build(scene, budget);
    EXPECT_FALSE(st.ok()) << what;
    EXPECT_NE(st.message.find("unsupported"), std::string::npos) << st.message;
    EXPECT_NE(st.message.find(what), std::string::npos) << st.message;
  };
  Scene scene;
  scene.bodies = {ball({0, 0, 1}, 0.5f)};
  PeerBudget iterations;
  iterations.iterations = 10;
  expectUnsupported(scene, iterations, "iterations");
  Scene gyro = scene;
  gyro.bodies[0].gyroscopic = false;
  expectUnsupported(gyro, {}, "gyroscopic");
}

}  // namespace
}  // namespace phys::peers

#endif  // PHYS_PEER_BOX3D
