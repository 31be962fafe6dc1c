// Split push-out: penetration deeper than a resting sag is resolved by pseudo velocities that
// move positions and are then dropped. A column of boxes spawned 20 cm into each other and the
// ground must come apart without being launched, and a resting stack must behave exactly as
// without the split (the soft contacts keep the sag). The default takes the split only in a
// step that starts with a contact deeper than kSplitDepth: scenes without one step bit for
// bit as without it (vectorized contacts included), and overlap's buried bodies separate.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <string>
#include <vector>

#include "phys/scene/scene.h"
#include "phys/world/world.h"
#include "test_util.h"

namespace phys {
namespace {

using test::addBody;
using test::addGround;
using test::boxBody;
using test::stateOf;

struct ColumnRun {
  double maxSpeed = 0;          ///< fastest body over the run, m/s
  double finalPenetration = 0;  ///< deepest contact at the end, m
  double topZ = 0;              ///< the top box's height at the end
};

/// `n` unit boxes (half-extent 0.5) stacked with `overlap` m of each box inside the one below
/// (and the lowest inside the ground), run for `steps`.
ColumnRun buriedColumn(bool split, int n, float overlap, int steps) {
  WorldDef def;
  def.solver.splitPushout = split;
  World w(def);
  addGround(w);
  std::vector<BodyId> ids;
  for (int i = 0; i < n; ++i)
    ids.push_back(
        addBody(w, boxBody({0, 0, 0.5f - overlap + i * (1 - overlap)}, {0.5f, 0.5f, 0.5f})));
  ColumnRun r;
  for (int s = 0; s < steps; ++s) {
    w.step();
    for (BodyId id : ids)
      r.maxSpeed = std::max(r.maxSpeed, double(length(stateOf(w, id).linearVelocity)));
  }
  r.finalPenetration = w.stats().maxPenetration;
  r.topZ = stateOf(w, ids.back()).position.z;
  return r;
}

TEST(SplitPushout, BuriedColumnSeparatesWithoutBeingLaunched) {
  const ColumnRun split = buriedColumn(true, 5, 0.2f, 180);
  EXPECT_LT(split.finalPenetration, 0.005);
  EXPECT_NEAR(split.topZ, 4.5, 0.01);  // resting, one metre per box
  // The push never became velocity: nothing moved faster than gravity over the ~0.1 s a box
  // needs to leave the one below at the 3 m/s push-out limit.
  EXPECT_LT(split.maxSpeed, 1.0);
  // The velocity push of the soft contacts alone adds up along the column (3 m/s per contact)
  // and throws the top box.
  const ColumnRun velocity = buriedColumn(false, 5, 0.2f, 180);
  EXPECT_GT(velocity.maxSpeed, 3.0);
  EXPECT_GT(velocity.maxSpeed, 4 * split.maxSpeed);
}

TEST(SplitPushout, RestingStackUnchanged) {
  // Spawned touching: contacts never get deeper than a sag, so the split never acts and the
  // run is bit-identical to the one without it.
  auto run = [](bool split) {
    WorldDef def;
    def.solver.splitPushout = split;
    World w(def);
    addGround(w);
    std::vector<BodyId> ids;
    for (int i = 0; i < 8; ++i)
      ids.push_back(addBody(w, boxBody({0, 0, 0.5f + i}, {0.5f, 0.5f, 0.5f})));
    for (int s = 0; s < 120; ++s) w.step();
    std::vector<float> out;
    for (BodyId id : ids) {
      BodyState b = stateOf(w, id);
      out.insert(out.end(), {b.position.x, b.position.y, b.position.z, b.rotation.w});
    }
    return out;
  };
  const std::vector<float> a = run(true), b = run(false);
  ASSERT_EQ(a.size(), b.size());
  EXPECT_EQ(0, std::memcmp(a.data(), b.data(), a.size() * sizeof(float)));
}

/// A scene run with the split push-out on or off (overlap, pyramid_20, restitution).
struct SceneRun {
  uint64_t hash = 0;
  float fastest = 0;      ///< m/s, over the run
  double deepest = 0;     ///< m, the deepest contact at the end
  bool everDeep = false;  ///< some step started with a contact deeper than kSplitDepth
};

SceneRun runScene(const std::string& scene, bool split, int steps) {
  Scene s = test::loadScene(scene);
  s.world.solver.splitPushout = split;
  s.world.threads = 1;
  World w(s.world);
  std::vector<BodyId> ids;
  EXPECT_TRUE(instantiateScene(s, &w, &ids).ok());
  SceneRun r;
  for (int i = 0; i < steps; ++i) {
    r.everDeep |= w.stats().maxPenetration > SolverSettings::kSplitDepth;
    w.step();
    for (BodyId id : ids) {
      BodyState b;
      if (w.getBody(id, &b).ok()) r.fastest = std::max(r.fastest, length(b.linearVelocity));
    }
  }
  r.hash = w.stateHash();
  r.deepest = w.stats().maxPenetration;
  return r;
}

TEST(SplitPushout, StepsWithoutDeepContactsAreTheUnsplitSolveBitForBit) {
  // A pyramid and a bounce: contacts come and go, none deeper than a resting sag.
  for (const char* scene : {"pyramid_20", "restitution"}) {
    SCOPED_TRACE(scene);
    const SceneRun on = runScene(scene, true, 90), off = runScene(scene, false, 90);
    EXPECT_FALSE(on.everDeep);
    EXPECT_EQ(on.hash, off.hash);
  }
}

TEST(SplitPushout, BuriedBodiesSeparateWithoutBeingLaunched) {
  // overlap's first second: a pyramid and 200 cubes spawned 25 % into each other.
  const SceneRun on = runScene("overlap", true, 60), off = runScene("overlap", false, 60);
  EXPECT_TRUE(on.everDeep);
  EXPECT_LT(on.fastest, 3.0f);   // the scene's bound
  EXPECT_GT(off.fastest, 6.0f);  // the contacts' own push, 3 m/s each, adds up
  EXPECT_LT(on.deepest, 0.01);   // separated within the second
}

/// test::addBuriedJointedPair without gravity: the push-out has to move the 1 kg box out of
/// the block along x, and the joint has to take the 500 kg one with it. Returns the joint's
/// largest position error over 90 steps, the deepest contact and the heavy box's x at the end.
struct JointedRun {
  double jointErrorMax = 0, finalPenetration = 0, heavyX = 0;
};

JointedRun buriedJointedPair(bool split, SolverSettings::EqualitySolve equality, JointType type,
                             int iterations) {
  WorldDef def;
  def.gravity = {0, 0, 0};
  def.solver.splitPushout = split;
  def.solver.equalitySolve = equality;
  def.solver.iterations = iterations;
  World w(def);
  test::BuriedJointedPair pair;
  const Status st = test::addBuriedJointedPair(w, type, &pair);
  EXPECT_TRUE(st.ok()) << st.message;
  JointedRun r;
  for (int s = 0; s < 90; ++s) {
    w.step();
    JointState js;
    EXPECT_TRUE(w.getJoint(pair.joint, nullptr, &js).ok());
    r.jointErrorMax = std::max(r.jointErrorMax, double(js.positionError));
  }
  r.finalPenetration = w.stats().maxPenetration;
  r.heavyX = stateOf(w, pair.heavy).position.x;
  return r;
}

TEST(SplitPushout, PushOutMovesWhatAJointHolds) {
  // The push-out's pseudo velocities obey the joints as the velocities do: the pair leaves
  // the block together. When the push-out moved the light box alone, up to 3 m/s x the
  // substep ahead of its joint, the joint opened by 1.3-1.5 cm here even with the joints
  // solved exactly (and 11.4 cm in physbench --stress seed 958, a prismatic joint under a
  // 430 kg box's push); now 0.1 mm.
  using Eq = SolverSettings::EqualitySolve;
  for (JointType type : {JointType::Ball, JointType::Prismatic}) {
    SCOPED_TRACE(toString(type));
    const JointedRun direct = buriedJointedPair(true, Eq::DirectLdl, type, 2);
    EXPECT_LT(direct.jointErrorMax, 0.001);
    EXPECT_LT(direct.finalPenetration, SolverSettings::kSplitDepth);  // out, both of them
    EXPECT_GT(direct.heavyX, 0.62 + 0.07);                            // the heavy box came along
    // Iterated joints do not converge at 500:1 (3.5 cm of error with the velocity push, 20
    // iterations); the push-out must not add to that (it added 0.8 cm when it ignored them).
    const JointedRun iterated = buriedJointedPair(true, Eq::Iterative, type, 20),
                     velocityPush = buriedJointedPair(false, Eq::Iterative, type, 20);
    EXPECT_LT(iterated.jointErrorMax, velocityPush.jointErrorMax);
    EXPECT_LT(iterated.finalPenetration, SolverSettings::kSplitDepth);
    EXPECT_GT(iterated.heavyX, 0.62 + 0.07);
  }
}

}  // namespace
}  // namespace phys
