// Islands and sleeping (issue 22): bodies that rest long enough sleep, in islands; nothing
// wakes them but a touch by something moving or an edit of them or of what holds them; the
// decisions are deterministic (any thread count) and survive a snapshot.
#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <vector>

#include "test_util.h"

namespace phys {
namespace {

using test::addBody;
using test::addGround;
using test::boxBody;
using test::sphereBody;
using test::stateOf;

WorldDef sleepy(int threads = 1) {
  WorldDef d;
  d.sleep.enabled = true;
  d.threads = threads;
  return d;
}

/// A column of n unit cubes standing on the ground at (x, y).
std::vector<BodyId> addColumn(World& w, float x, float y, int n) {
  std::vector<BodyId> ids;
  for (int i = 0; i < n; ++i) ids.push_back(addBody(w, boxBody({x, y, 0.5f + float(i)})));
  return ids;
}

bool allAsleep(const World& w, const std::vector<BodyId>& ids) {
  for (BodyId id : ids)
    if (!w.isSleeping(id)) return false;
  return true;
}

bool anyAsleep(const World& w, const std::vector<BodyId>& ids) {
  for (BodyId id : ids)
    if (w.isSleeping(id)) return true;
  return false;
}

/// Steps until every body in ids sleeps; false if that takes more than `seconds`.
bool stepUntilAsleep(World& w, const std::vector<BodyId>& ids, float seconds = 4) {
  for (int i = 0; i < int(seconds * 60); ++i) {
    if (allAsleep(w, ids)) return true;
    w.step();
  }
  return allAsleep(w, ids);
}

TEST(Sleep, ABoxSleepsAfterTheSleepTimeAndNotBefore) {
  World w(sleepy());
  addGround(w);
  const BodyId box = addBody(w, boxBody({0, 0, 0.5f}));  // resting exactly on the ground
  // Ready from the first step: asleep once 0.5 s of steps have passed (30 at 60 Hz, or 31
  // where the float sum of 1/60 stays just under 0.5), not before.
  for (int i = 0; i < 29; ++i) {
    w.step();
    ASSERT_FALSE(w.isSleeping(box)) << "asleep after " << i + 1 << " steps";
  }
  w.step();
  w.step();
  ASSERT_TRUE(w.isSleeping(box));
  EXPECT_EQ(w.stats().sleepingBodies, 1);
  EXPECT_EQ(w.stats().sleepingIslands, 1);
  BodyState s = stateOf(w, box);
  EXPECT_TRUE(s.sleeping);
  EXPECT_EQ(s.linearVelocity, Vec3{});
  // Asleep, it costs nothing: no pairs, no contacts, no solver bodies, and it does not move.
  const uint64_t hash = w.stateHash();
  const double energy = w.energy();
  for (int i = 0; i < 60; ++i) w.step();
  EXPECT_EQ(w.stateHash(), hash);
  EXPECT_EQ(w.stats().awake, 0);
  EXPECT_EQ(w.stats().pairs, 0);
  EXPECT_EQ(w.stats().contacts, 0);
  EXPECT_NEAR(w.energy(), energy, 1e-9 * std::fabs(energy));
  // Its contact is kept (for inspection and for warm starting when it wakes).
  EXPECT_EQ(w.contacts().size(), 1u);
}

TEST(Sleep, AFallingBoxDoesNotSleepAndSleepIsOffByDefault) {
  World off;  // WorldDef's default: no sleeping
  addGround(off);
  const BodyId rest = addBody(off, boxBody({0, 0, 0.5f}));
  World on(sleepy());
  addGround(on);
  const BodyId fall = addBody(on, boxBody({0, 0, 20}));
  for (int i = 0; i < 90; ++i) {  // 1.5 s: still falling (it lands after about 2 s)
    off.step();
    on.step();
    ASSERT_FALSE(on.isSleeping(fall));
  }
  for (int i = 0; i < 120; ++i) off.step();
  EXPECT_FALSE(off.isSleeping(rest));
  EXPECT_EQ(off.stats().awake, 1);
}

TEST(Sleep, ABodyThatMayNotSleepKeepsItsIslandAwake) {
  World w(sleepy());
  addGround(w);
  std::vector<BodyId> col = addColumn(w, 0, 0, 3);
  BodyDef top = boxBody({0, 0, 3.5f});
  top.allowSleep = false;
  col.push_back(addBody(w, top));
  for (int i = 0; i < 120; ++i) w.step();
  EXPECT_FALSE(anyAsleep(w, col));
  EXPECT_EQ(w.stats().awakeIslands, 1);
  ASSERT_TRUE(w.setAllowSleep(col.back(), true).ok());
  EXPECT_TRUE(stepUntilAsleep(w, col, 2));
}

TEST(Sleep, ABoxSlidingSlowlyDownASlopeNeverSleeps) {
  // A 20 degree slope whose friction is just under the angle's: the box starts at rest and
  // slides ever faster at 0.18 m/s^2, passing the 0.05 m/s threshold after 0.27 s.
  const float angle = 20 * kPi / 180;
  const float mu = std::tan(angle) - 0.02f;
  World w(sleepy());
  const Quat tilt = Quat::fromAxisAngle({0, 1, 0}, -angle);  // the surface falls towards +x
  BodyDef slope = boxBody({0, 0, 0}, {6, 2, 0.5f}, BodyType::Static, tilt);
  slope.shapes[0].material.friction = mu;
  addBody(w, slope);
  const Vec3 up = rotate(tilt, {0, 0, 1});
  BodyDef d = boxBody(rotate(tilt, {-4, 0, 0}) + up * 0.75f, {0.25f, 0.25f, 0.25f},
                      BodyType::Dynamic, tilt);
  d.shapes[0].material.friction = mu;
  const BodyId box = addBody(w, d);
  const Vec3 start = stateOf(w, box).position;
  for (int i = 0; i < 180; ++i) {
    w.step();
    ASSERT_FALSE(w.isSleeping(box))
        << "asleep at step " << i + 1 << ", speed " << length(stateOf(w, box).linearVelocity);
  }
  // It slid (0.18 m/s^2 for 3 s is 0.83 m).
  EXPECT_GT(length(stateOf(w, box).position - start), 0.5f);
}

TEST(Sleep, ABallRolledIntoOneSleepingStackWakesItAndNotTheOther) {
  World w(sleepy());
  addGround(w);
  const std::vector<BodyId> hit = addColumn(w, 0, 0, 3);
  const std::vector<BodyId> away = addColumn(w, 6, 0, 3);
  std::vector<BodyId> both = hit;
  both.insert(both.end(), away.begin(), away.end());
  ASSERT_TRUE(stepUntilAsleep(w, both, 2));
  EXPECT_EQ(w.stats().sleepingIslands, 2);
  // Made away from both, the ball wakes nothing until it touches the first stack.
  BodyDef ball = sphereBody({-3, 0, 0.3f}, 0.3f);
  ball.linearVelocity = {4, 0, 0};
  const BodyId b = addBody(w, ball);
  EXPECT_TRUE(allAsleep(w, both));
  bool woke = false;
  for (int i = 0; i < 90; ++i) {
    w.step();
    woke = woke || !anyAsleep(w, hit);
    ASSERT_TRUE(allAsleep(w, away)) << "the other stack woke at step " << i + 1;
  }
  EXPECT_TRUE(woke);
  EXPECT_GT(stateOf(w, b).position.x, -1.0f);  // it got there
}

TEST(Sleep, RemovingTheBottomBoxOfASleepingColumnWakesTheColumn) {
  World w(sleepy());
  addGround(w);
  std::vector<BodyId> col = addColumn(w, 0, 0, 4);
  ASSERT_TRUE(stepUntilAsleep(w, col, 2));
  ASSERT_TRUE(w.destroyBody(col[0]).ok());
  col.erase(col.begin());
  EXPECT_FALSE(anyAsleep(w, col));
  const float z0 = stateOf(w, col[0]).position.z;
  for (int i = 0; i < 20; ++i) w.step();
  EXPECT_LT(stateOf(w, col[0]).position.z, z0 - 0.2f);  // falling
}

TEST(Sleep, AMovingKinematicPlatformWakesWhatRestsOnIt) {
  World w(sleepy());
  const BodyId platform = addBody(w, boxBody({0, 0, 0}, {3, 3, 0.5f}, BodyType::Kinematic));
  const BodyId box = addBody(w, boxBody({0, 0, 1}));
  ASSERT_TRUE(stepUntilAsleep(w, {box}, 2));
  // The platform itself never sleeps; resting, it holds the box without waking it.
  EXPECT_FALSE(w.isSleeping(platform));
  for (int i = 0; i < 30; ++i) w.step();
  EXPECT_TRUE(w.isSleeping(box));
  ASSERT_TRUE(w.setVelocity(platform, {1, 0, 0}, {}).ok());
  w.step();
  EXPECT_FALSE(w.isSleeping(box));
  for (int i = 0; i < 60; ++i) {
    w.step();
    ASSERT_FALSE(w.isSleeping(box)) << "asleep on a moving platform at step " << i + 2;
  }
  EXPECT_GT(stateOf(w, box).position.x, 0.5f);  // carried along by friction
}

TEST(Sleep, EveryEditWakesItsBody) {
  struct Edit {
    const char* name;
    std::function<Status(World&, BodyId)> apply;
  };
  const std::vector<Edit> edits = {
      {"setTransform",
       [](World& w, BodyId b) {
         return w.setTransform(b, {0, 0, 0.6f}, {});
       }},
      {"setVelocity",
       [](World& w, BodyId b) {
         return w.setVelocity(b, {0.1f, 0, 0}, {});
       }},
      {"applyForce",
       [](World& w, BodyId b) {
         return w.applyForce(b, {1, 0, 0}, {0, 0, 0.5f});
       }},
      {"applyTorque",
       [](World& w, BodyId b) {
         return w.applyTorque(b, {0, 0, 1});
       }},
      {"applyImpulse",
       [](World& w, BodyId b) {
         return w.applyImpulse(b, {1, 0, 0}, {0, 0, 0.5f});
       }},
      {"setMass", [](World& w, BodyId b) { return w.setMass(b, 2); }},
      {"setMaterial",
       [](World& w, BodyId b) {
         return w.setMaterial(b, Material{0.2f, 0, 500});
       }},
      {"setBodyType", [](World& w, BodyId b) { return w.setBodyType(b, BodyType::Dynamic); }},
      {"addShape",
       [](World& w, BodyId b) {
         ShapeDef s;
         s.geom = ShapeGeom::sphere(0.2f);
         s.local.p = {0, 0, 0.5f};
         return w.addShape(b, s, nullptr);
       }},
      {"createJoint",
       [](World& w, BodyId b) {
         JointDef j;
         j.type = JointType::Ball;
         j.bodyB = b;
         j.anchorA = {0, 0, 1};
         j.anchorB = {0, 0, 0.5f};
         return w.createJoint(j, nullptr);
       }},
      {"setAllowSleep", [](World& w, BodyId b) { return w.setAllowSleep(b, false); }},
      {"wakeBody", [](World& w, BodyId b) { return w.wakeBody(b); }},
      {"setGravity",
       [](World& w, BodyId) {
         return w.setGravity({0, 0, -9.8f});
       }},
      {"setTimeStep", [](World& w, BodyId) { return w.setTimeStep(1.0f / 120); }},
      {"setSolverSettings",
       [](World& w, BodyId) {
         SolverSettings s = w.def().solver;
         s.iterations += 1;
         return w.setSolverSettings(s);
       }},
  };
  for (const Edit& e : edits) {
    World w(sleepy());
    addGround(w);
    const BodyId box = addBody(w, boxBody({0, 0, 0.5f}));
    ASSERT_TRUE(stepUntilAsleep(w, {box}, 2)) << e.name;
    ASSERT_TRUE(e.apply(w, box).ok()) << e.name;
    EXPECT_FALSE(w.isSleeping(box)) << e.name << " left the body asleep";
  }
}

TEST(Sleep, EditingTheGroundWakesWhatRestsOnIt) {
  World w(sleepy());
  const BodyId ground = addGround(w);
  const std::vector<BodyId> col = addColumn(w, 0, 0, 2);
  ASSERT_TRUE(stepUntilAsleep(w, col, 2));
  ASSERT_TRUE(w.setMaterial(ground, Material{0.1f, 0, 1000}).ok());
  EXPECT_FALSE(anyAsleep(w, col));
  ASSERT_TRUE(stepUntilAsleep(w, col, 2));
  ASSERT_TRUE(w.destroyBody(ground).ok());
  EXPECT_FALSE(anyAsleep(w, col));
  for (int i = 0; i < 30; ++i) w.step();
  EXPECT_LT(stateOf(w, col[0]).position.z, 0.0f);  // nothing holds it any more
}

TEST(Sleep, APyramidSleepsAndStandsAsWellAsAwake) {
  // A pyramid of base 10 (55 cubes): with sleeping on it must meet pyramid_20's criteria as
  // it does with sleeping off (top drift under 1 cm, penetration under 5 mm), and sleep.
  auto run = [](bool sleep, double* drift, double* pen, int* asleep) {
    WorldDef d;
    d.sleep.enabled = sleep;
    World w(d);
    addGround(w);
    std::vector<BodyId> ids;
    for (int row = 0; row < 10; ++row)
      for (int i = 0; i < 10 - row; ++i)
        ids.push_back(
            addBody(w, boxBody({float(i) - 0.5f * float(9 - row), 0, 0.5f + float(row)})));
    const Vec3 top0 = stateOf(w, ids.back()).position;
    *pen = 0;
    for (int i = 0; i < 240; ++i) {
      w.step();
      if (w.time() > 1) *pen = std::max(*pen, w.stats().maxPenetration);
    }
    const Vec3 top = stateOf(w, ids.back()).position;
    *drift = std::hypot(double(top.x - top0.x), double(top.y - top0.y));
    *asleep = w.stats().sleepingBodies;
  };
  double driftOff, penOff, driftOn, penOn;
  int asleepOff, asleepOn;
  run(false, &driftOff, &penOff, &asleepOff);
  run(true, &driftOn, &penOn, &asleepOn);
  EXPECT_LT(driftOff, 0.01);
  EXPECT_LT(penOff, 0.005);
  EXPECT_LT(driftOn, 0.01);
  EXPECT_LT(penOn, 0.005);
  EXPECT_EQ(asleepOff, 0);
  EXPECT_EQ(asleepOn, 55);
}

/// Two columns and a ball thrown into one: wakes, sleeps, a ball at rest; its hashes per step.
std::vector<uint64_t> wakeAndSleepRun(int threads, int steps, World* into = nullptr,
                                      int snapshotAt = -1,
                                      std::vector<uint8_t>* snapshot = nullptr) {
  World local(sleepy(threads));
  World& w = into ? *into : local;
  addGround(w);
  addColumn(w, 0, 0, 4);
  addColumn(w, 5, 0, 4);
  BodyDef ball = sphereBody({-4, 0.2f, 0.3f}, 0.3f);
  ball.linearVelocity = {4, 0, 0};
  addBody(w, ball);
  std::vector<uint64_t> hashes;
  for (int i = 0; i < steps; ++i) {
    if (i == snapshotAt) {
      EXPECT_TRUE(w.saveSnapshot(snapshot).ok());
    }
    w.step();
    hashes.push_back(w.stateHash());
  }
  return hashes;
}

TEST(Sleep, DecisionsAreTheSameAtOneAndTwoThreads) {
  World one(sleepy(1)), two(sleepy(2));
  const std::vector<uint64_t> a = wakeAndSleepRun(1, 300, &one);
  const std::vector<uint64_t> b = wakeAndSleepRun(2, 300, &two);
  ASSERT_EQ(a, b);
  EXPECT_GT(one.stats().sleepingBodies, 0);  // the run ends with something asleep
  EXPECT_EQ(one.stats().sleepingBodies, two.stats().sleepingBodies);
}

TEST(Sleep, ASnapshotCarriesSleepStateAndTimers) {
  // Saved at step 100 (the far column asleep, the near one being hit), restored, continued:
  // every hash as in the uninterrupted run, sleeping and waking included.
  std::vector<uint8_t> snap;
  World full(sleepy());
  const std::vector<uint64_t> uninterrupted = wakeAndSleepRun(1, 300, &full, 100, &snap);
  ASSERT_FALSE(snap.empty());
  World restored(sleepy());
  ASSERT_TRUE(restored.restoreSnapshot(snap.data(), snap.size()).ok());
  EXPECT_GT(restored.stats().sleepingBodies, 0);
  for (int i = 100; i < 300; ++i) {
    restored.step();
    ASSERT_EQ(restored.stateHash(), uninterrupted[size_t(i)]) << "step " << i + 1;
  }
  EXPECT_EQ(restored.stats().sleepingBodies, full.stats().sleepingBodies);
  // And again from the restored world's own snapshot: the same bytes as the original's.
  std::vector<uint8_t> again, original;
  ASSERT_TRUE(restored.saveSnapshot(&again).ok());
  ASSERT_TRUE(full.saveSnapshot(&original).ok());
  EXPECT_EQ(again, original);
}

TEST(Sleep, ARestoredSleepingWorldWakesOnAnEdit) {
  World w(sleepy());
  addGround(w);
  const BodyId box = addBody(w, boxBody({0, 0, 0.5f}));
  ASSERT_TRUE(stepUntilAsleep(w, {box}, 2));
  std::vector<uint8_t> snap;
  ASSERT_TRUE(w.saveSnapshot(&snap).ok());
  World r(sleepy());
  ASSERT_TRUE(r.restoreSnapshot(snap.data(), snap.size()).ok());
  EXPECT_TRUE(r.isSleeping(box));
  ASSERT_TRUE(r.applyImpulse(box, {0, 0, 5000}, {0, 0, 0.5f}).ok());  // 5 m/s up
  EXPECT_FALSE(r.isSleeping(box));
  r.step();
  EXPECT_GT(stateOf(r, box).position.z, 0.5f);
}

TEST(Sleep, TurningSleepOffWakesEverything) {
  World w(sleepy());
  addGround(w);
  const std::vector<BodyId> col = addColumn(w, 0, 0, 3);
  ASSERT_TRUE(stepUntilAsleep(w, col, 2));
  SleepSettings s = w.def().sleep;
  s.enabled = false;
  ASSERT_TRUE(w.setSleepSettings(s).ok());
  EXPECT_FALSE(anyAsleep(w, col));
  for (int i = 0; i < 120; ++i) w.step();
  EXPECT_FALSE(anyAsleep(w, col));
  s.time = -1;
  EXPECT_FALSE(w.setSleepSettings(s).ok());
  s.time = 0.5f;
  s.linearSpeed = NAN;
  EXPECT_FALSE(w.setSleepSettings(s).ok());
}

}  // namespace
}  // namespace phys
