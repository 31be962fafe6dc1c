// A living world's settings and definitions (issue 40): World::setDef changes every setting
// that may change while a world lives, all-or-nothing and waking what each change affects;
// World::getBodyDef reads back what the world simulates, the engine being the one source,
// and a snapshot carries all of it.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <vector>

#include "test_util.h"

namespace phys {
namespace {

using test::addBody;
using test::addGround;
using test::boxBody;
using test::sphereBody;

WorldDef sleepy() {
  WorldDef d;
  d.sleep.enabled = true;
  d.threads = 1;
  return d;
}

/// A column of n unit cubes on the ground, stepped until every cube sleeps.
std::vector<BodyId> sleepingColumn(World& w, int n) {
  addGround(w);
  std::vector<BodyId> ids;
  for (int i = 0; i < n; ++i) ids.push_back(addBody(w, boxBody({0, 0, 0.5f + float(i)})));
  for (int i = 0; i < 600 && !w.isSleeping(ids.back()); ++i) w.step();
  for (BodyId id : ids) EXPECT_TRUE(w.isSleeping(id));
  return ids;
}

bool anyAsleep(const World& w, const std::vector<BodyId>& ids) {
  for (BodyId id : ids)
    if (w.isSleeping(id)) return true;
  return false;
}

std::vector<uint8_t> saved(const World& w) {
  std::vector<uint8_t> b;
  Status st = w.saveSnapshot(&b);
  EXPECT_TRUE(st.ok()) << st.message;
  return b;
}

TEST(WorldSettings, EverySettableFieldChangesAtOnce) {
  World w(sleepy());
  WorldDef d = w.def();
  d.gravity = {1, 2, -3};
  d.timeStep = 1.0f / 120;
  d.maxLinearSpeed = 250;
  d.maxAngularSpeed = 125;
  d.speculativeDistance = 0.04f;
  d.aabbMargin = 0.1f;
  d.guard = false;
  d.guardEnergyJump = 2;
  d.guardRetries = 4;
  d.sleep.time = 1.5f;
  d.sleep.linearSpeed = 0.02f;
  d.sleep.angularSpeed = 0.3f;
  d.solver.iterations = 17;
  ASSERT_TRUE(w.setDef(d).ok());
  const WorldDef& n = w.def();
  EXPECT_TRUE(n.gravity == d.gravity);
  EXPECT_EQ(n.timeStep, d.timeStep);
  EXPECT_EQ(n.maxLinearSpeed, 250);
  EXPECT_EQ(n.maxAngularSpeed, 125);
  EXPECT_EQ(n.speculativeDistance, 0.04f);
  EXPECT_EQ(n.aabbMargin, 0.1f);
  EXPECT_FALSE(n.guard);
  EXPECT_EQ(n.guardEnergyJump, 2);
  EXPECT_EQ(n.guardRetries, 4);
  EXPECT_EQ(n.sleep.time, 1.5f);
  EXPECT_EQ(n.sleep.linearSpeed, 0.02f);
  EXPECT_EQ(n.sleep.angularSpeed, 0.3f);
  EXPECT_EQ(n.solver.iterations, 17);
  // And a snapshot carries them.
  World r;
  std::vector<uint8_t> b = saved(w);
  ASSERT_TRUE(r.restoreSnapshot(b.data(), b.size()).ok());
  EXPECT_EQ(r.def().maxLinearSpeed, 250);
  EXPECT_EQ(r.def().aabbMargin, 0.1f);
  EXPECT_EQ(r.def().guardRetries, 4);
  EXPECT_EQ(r.def().sleep.time, 1.5f);
}

TEST(WorldSettings, AnInvalidFieldChangesNothing) {
  World w(sleepy());
  const std::vector<uint8_t> before = saved(w);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  auto refused = [&](auto edit) {
    WorldDef d = w.def();
    d.gravity = {0, 0, -1};  // a valid change beside the bad one: not applied either
    edit(d);
    Status st = w.setDef(d);
    EXPECT_EQ(st.code, StatusCode::InvalidArgument) << st.message;
    EXPECT_EQ(saved(w), before);
  };
  refused([&](WorldDef& d) { d.gravity.x = nan; });
  refused([&](WorldDef& d) { d.timeStep = 0; });
  refused([&](WorldDef& d) { d.timeStep = 2; });
  refused([&](WorldDef& d) { d.maxLinearSpeed = 0; });
  refused([&](WorldDef& d) { d.maxAngularSpeed = std::numeric_limits<float>::infinity(); });
  refused([&](WorldDef& d) { d.speculativeDistance = -1; });
  refused([&](WorldDef& d) { d.aabbMargin = nan; });
  refused([&](WorldDef& d) { d.guardEnergyJump = -0.5f; });
  refused([&](WorldDef& d) { d.guardRetries = -1; });
  refused([&](WorldDef& d) { d.guardRetries = 1001; });
  refused([&](WorldDef& d) { d.sleep.time = 0; });
  refused([&](WorldDef& d) { d.sleep.linearSpeed = nan; });
  refused([&](WorldDef& d) { d.solver.substeps = 0; });
  // Fixed when the world was made.
  refused([&](WorldDef& d) { d.backend = Backend::Gpu; });
  refused([&](WorldDef& d) { d.threads = w.def().threads + 1; });
  refused([&](WorldDef& d) { d.gpuAllowCpuDevice = !d.gpuAllowCpuDevice; });
}

TEST(WorldSettings, AGravityChangeWakesEveryBody) {
  World w(sleepy());
  const std::vector<BodyId> column = sleepingColumn(w, 3);
  // A sideways pull: the column must feel it at once, not hang asleep.
  WorldDef d = w.def();
  d.gravity = {5, 0, -9.81f};
  ASSERT_TRUE(w.setDef(d).ok());
  EXPECT_FALSE(anyAsleep(w, column));
  EXPECT_EQ(w.awakeBodyCount(), 3);
  const float x0 = test::stateOf(w, column.back()).position.x;
  for (int i = 0; i < 30; ++i) w.step();
  EXPECT_GT(test::stateOf(w, column.back()).position.x, x0 + 0.01f);
}

TEST(WorldSettings, ABodyAboutToSleepGetsTheWholeSleepTimeUnderTheNewGravity) {
  // A flat box at rest, awake, its rest timer 27 steps into the 30 it needs. Gravity then
  // pulls sideways a little past what friction holds (friction 0.6: 5.9 m/s^2): it starts
  // sliding slowly (0.5 m/s^2). Had it kept its timer it would fall asleep three steps later,
  // still slower than the sleep threshold, and hang on the slope of the new gravity.
  World w(sleepy());
  addGround(w);
  const BodyId box = addBody(w, boxBody({0, 0, 0.1f}, {0.5f, 0.5f, 0.1f}));
  for (int i = 0; i < 27; ++i) w.step();
  ASSERT_FALSE(w.isSleeping(box));
  WorldDef d = w.def();
  d.gravity = {6.4f, 0, -9.81f};
  ASSERT_TRUE(w.setDef(d).ok());
  for (int i = 0; i < 60; ++i) w.step();
  EXPECT_GT(test::stateOf(w, box).position.x, 0.1f);
  EXPECT_FALSE(w.isSleeping(box));
}

TEST(WorldSettings, ChangesWakeWhatTheyAffectAndNoMore) {
  struct Case {
    const char* what;
    void (*edit)(WorldDef&);
    bool wakes;
  };
  const Case cases[] = {
      {"time step", [](WorldDef& d) { d.timeStep = 1.0f / 90; }, true},
      {"solver", [](WorldDef& d) { d.solver.iterations += 3; }, true},
      {"sleep thresholds", [](WorldDef& d) { d.sleep.time = 2; }, true},
      {"sleeping off", [](WorldDef& d) { d.sleep.enabled = false; }, true},
      {"speculative distance", [](WorldDef& d) { d.speculativeDistance = 0.05f; }, true},
      {"aabb margin", [](WorldDef& d) { d.aabbMargin = 0.2f; }, true},
      {"speed clamps", [](WorldDef& d) { d.maxLinearSpeed = 50, d.maxAngularSpeed = 40; }, false},
      {"guard", [](WorldDef& d) { d.guard = false, d.guardRetries = 1; }, false},
      {"contact budget", [](WorldDef& d) { d.maxContactPairs = 1000; }, false},
      {"nothing", [](WorldDef&) {}, false},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.what);
    World w(sleepy());
    const std::vector<BodyId> column = sleepingColumn(w, 2);
    WorldDef d = w.def();
    c.edit(d);
    ASSERT_TRUE(w.setDef(d).ok());
    EXPECT_EQ(!anyAsleep(w, column), c.wakes);
  }
}

TEST(WorldSettings, ChangingNothingChangesNoStep) {
  // setDef with the world's own definition is no edit: the world steps as an untouched twin.
  World a(sleepy()), b(sleepy());
  for (World* w : {&a, &b}) {
    addGround(*w);
    addBody(*w, boxBody({0, 0, 2}, {0.5f, 0.5f, 0.5f}, BodyType::Dynamic,
                        normalize(Quat{0.1f, 0.2f, 0, 1})));
  }
  for (int i = 0; i < 20; ++i) a.step(), b.step();
  ASSERT_TRUE(a.setDef(a.def()).ok());
  for (int i = 0; i < 40; ++i) a.step(), b.step();
  EXPECT_EQ(a.stateHash(), b.stateHash());
}

TEST(WorldDefinitions, GetBodyDefReturnsWhatTheBodyWasMadeFrom) {
  World w(sleepy());
  BodyDef d = boxBody({1, 2, 3}, {0.5f, 0.25f, 0.75f});
  d.rotation = normalize(Quat{0.1f, 0, 0.2f, 1});
  d.linearVelocity = {1, 0, 0};
  d.angularVelocity = {0, 0.5f, 0};
  d.linearDamping = 0.3f;
  d.angularDamping = 0.7f;
  d.gravityScale = -0.5f;
  d.mass = 12;
  d.inertia = {1, 2, 3};
  d.gyroscopic = false;
  d.allowSleep = false;
  d.name = "crate";
  d.shapes[0].material = {0.2f, 0.4f, 500};
  ShapeDef ball;
  ball.geom = ShapeGeom::sphere(0.3f);
  ball.local.p = {0, 0, 1};
  d.shapes.push_back(ball);
  const BodyId id = addBody(w, d);
  const BodyId ground = addGround(w, 0.9f, 0.1f);

  BodyDef got;
  BodyMass mass;
  ASSERT_TRUE(w.getBodyDef(id, &got, &mass).ok());
  EXPECT_EQ(got.type, BodyType::Dynamic);
  EXPECT_TRUE(got.position == d.position);
  EXPECT_TRUE(got.rotation == d.rotation);
  EXPECT_TRUE(got.linearVelocity == d.linearVelocity);
  EXPECT_TRUE(got.angularVelocity == d.angularVelocity);
  EXPECT_EQ(got.linearDamping, 0.3f);
  EXPECT_EQ(got.angularDamping, 0.7f);
  EXPECT_EQ(got.gravityScale, -0.5f);
  EXPECT_EQ(got.mass, 12);
  EXPECT_TRUE(got.inertia == (Vec3{1, 2, 3}));
  EXPECT_FALSE(got.gyroscopic);
  EXPECT_FALSE(got.allowSleep);
  EXPECT_EQ(got.name, "crate");
  ASSERT_EQ(got.shapes.size(), 2u);
  EXPECT_EQ(got.shapes[0].geom.type, ShapeType::Box);
  EXPECT_TRUE(got.shapes[0].geom.halfExtents == (Vec3{0.5f, 0.25f, 0.75f}));
  EXPECT_EQ(got.shapes[0].material.friction, 0.2f);
  EXPECT_EQ(got.shapes[0].material.restitution, 0.4f);
  EXPECT_EQ(got.shapes[0].material.density, 500);
  EXPECT_EQ(got.shapes[1].geom.type, ShapeType::Sphere);
  EXPECT_TRUE(got.shapes[1].local.p == (Vec3{0, 0, 1}));
  EXPECT_EQ(mass.mass, 12);
  EXPECT_TRUE(mass.inertia == (Vec3{1, 2, 3}));

  // Automatic mass: 0 in the definition, the shapes' mass in BodyMass.
  const BodyId ballId = addBody(w, sphereBody({5, 0, 1}, 0.5f, 1000));
  ASSERT_TRUE(w.getBodyDef(ballId, &got, &mass).ok());
  EXPECT_EQ(got.mass, 0);
  EXPECT_NEAR(mass.mass, 1000 * 4.0f / 3 * kPi * 0.125f, 1e-2f);
  EXPECT_NEAR(mass.inertia.x, 0.4f * mass.mass * 0.25f, 1e-3f);
  // A static body: no mass either way.
  ASSERT_TRUE(w.getBodyDef(ground, &got, &mass).ok());
  EXPECT_EQ(got.type, BodyType::Static);
  EXPECT_EQ(got.mass, 0);
  EXPECT_EQ(mass.mass, 0);
  EXPECT_EQ(got.shapes[0].material.friction, 0.9f);
  // A material set later is what the definition says.
  ASSERT_TRUE(w.setMaterial(id, {0.05f, 0.9f, 2000}).ok());
  ASSERT_TRUE(w.getBodyDef(id, &got).ok());
  for (const ShapeDef& s : got.shapes) EXPECT_EQ(s.material.restitution, 0.9f);
  // A stale id.
  ASSERT_TRUE(w.destroyBody(ballId).ok());
  EXPECT_EQ(w.getBodyDef(ballId, &got).code, StatusCode::NotFound);
}

TEST(WorldDefinitions, ASnapshotCarriesEveryDefinition) {
  // What a server reads back after restoring an engine snapshot: names, damping, gravity
  // scale and given masses, not the defaults.
  World w(sleepy());
  BodyDef d = boxBody({0, 0, 3});
  d.name = "named";
  d.linearDamping = 0.4f;
  d.angularDamping = 0.2f;
  d.gravityScale = 0.5f;
  d.mass = 3;
  d.allowSleep = false;
  const BodyId id = addBody(w, d);
  const BodyId other = addBody(w, boxBody({3, 0, 3}));
  JointDef j;
  j.type = JointType::Hinge;
  j.bodyA = id;
  j.bodyB = other;
  j.anchorA = {1.5f, 0, 0};
  j.anchorB = {-1.5f, 0, 0};
  j.enableMotor = true;
  j.motorSpeed = 1;
  j.maxMotorForce = 10;
  j.name = "hinge";
  JointId jid;
  ASSERT_TRUE(w.createJoint(j, &jid).ok());
  for (int i = 0; i < 10; ++i) w.step();
  World r;
  std::vector<uint8_t> b = saved(w);
  ASSERT_TRUE(r.restoreSnapshot(b.data(), b.size()).ok());
  BodyDef a, c;
  ASSERT_TRUE(w.getBodyDef(id, &a).ok());
  ASSERT_TRUE(r.getBodyDef(id, &c).ok());
  EXPECT_EQ(c.name, "named");
  EXPECT_EQ(c.linearDamping, 0.4f);
  EXPECT_EQ(c.angularDamping, 0.2f);
  EXPECT_EQ(c.gravityScale, 0.5f);
  EXPECT_EQ(c.mass, 3);
  EXPECT_FALSE(c.allowSleep);
  EXPECT_TRUE(c.position == a.position);
  EXPECT_TRUE(c.linearVelocity == a.linearVelocity);
  JointDef jr;
  JointState js;
  ASSERT_TRUE(r.getJoint(jid, &jr, &js).ok());
  EXPECT_EQ(jr.name, "hinge");
  EXPECT_EQ(jr.type, JointType::Hinge);
  EXPECT_TRUE(jr.enableMotor);
  EXPECT_EQ(jr.maxMotorForce, 10);
  // A body made from a definition read back is the same body: stepped alike.
  World twinA(sleepy()), twinB(sleepy());
  addBody(twinA, d);
  BodyDef again;
  ASSERT_TRUE(w.getBodyDef(id, &again).ok());
  again.position = d.position, again.rotation = d.rotation;
  again.linearVelocity = d.linearVelocity, again.angularVelocity = d.angularVelocity;
  addBody(twinB, again);
  for (int i = 0; i < 30; ++i) twinA.step(), twinB.step();
  EXPECT_EQ(twinA.stateHash(), twinB.stateHash());
}

}  // namespace
}  // namespace phys
