// Split push-out: penetration deeper than a resting sag is resolved by pseudo velocities that
// move positions and are then dropped. A column of boxes spawned 20 cm into each other and the
// ground must come apart without being launched, and a resting stack must behave exactly as
// without the split (the soft contacts keep the sag).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <vector>

#include "phys/world.h"
#include "test_util.h"

namespace phys {
namespace {

using test::addBody;
using test::addGround;
using test::boxBody;
using test::stateOf;

struct ColumnRun {
  double maxSpeed = 0;         ///< fastest body over the run, m/s
  double finalPenetration = 0; ///< deepest contact at the end, m
  double topZ = 0;             ///< the top box's height at the end
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
    for (BodyId id : ids) r.maxSpeed = std::max(r.maxSpeed, double(length(stateOf(w, id).linearVelocity)));
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
    for (int i = 0; i < 8; ++i) ids.push_back(addBody(w, boxBody({0, 0, 0.5f + i}, {0.5f, 0.5f, 0.5f})));
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

}  // namespace
}  // namespace phys
