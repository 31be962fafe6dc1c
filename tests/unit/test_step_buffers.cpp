// The step's buffers follow the world's activity (World::Impl::followActivity): a world whose
// contact pairs, or awake bodies, fell to a fraction of an earlier peak gives the peak's
// memory back, a world whose activity holds steady keeps its buffers (no reallocation
// churn), and bodies woken between steps do not grow them.
#include <gtest/gtest.h>

#include "phys/world/world.h"
#include "test_util.h"

using namespace phys;
using namespace phys::test;

namespace {

/// A layer of n x n boxes (0.5 m half extents, 1 mm gaps) resting on the ground: about 5 n^2
/// contact pairs (the ground, and the neighbours within the fat boxes' margin).
std::vector<BodyId> layer(World& w, int n) {
  std::vector<BodyId> ids;
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j) {
      BodyDef d;
      d.position = {i * 1.001f, j * 1.001f, 0.5f};
      ShapeDef s;
      s.geom = ShapeGeom::box({0.5f, 0.5f, 0.5f});
      d.shapes.push_back(s);
      ids.push_back(addBody(w, d));
    }
  return ids;
}

}  // namespace

TEST(StepBuffers, AWorldWhoseActivityFellGivesThePeaksMemoryBack) {
  World w;
  addGround(w);
  std::vector<BodyId> ids = layer(w, 30);  // 900 boxes
  for (int i = 0; i < 5; ++i) w.step();
  const int peakPairs = w.stats().pairs;
  const size_t peak = w.stepBufferBytes();
  ASSERT_GT(peakPairs, 1000);
  ASSERT_GT(peak, size_t(1) << 20) << "the peak's buffers should be MiBs";

  // 850 of them go: some 50 boxes' pairs are left.
  for (size_t i = 50; i < ids.size(); ++i) ASSERT_TRUE(w.destroyBody(ids[i]).ok());
  for (int i = 0; i < 5; ++i) w.step();
  EXPECT_LT(w.stats().pairs * 4, peakPairs);
  EXPECT_GE(w.stepBufferBytes(), peak) << "within a window nothing is given back";

  // Two windows (10 s each at 60 Hz) later the buffers are sized for what is left.
  for (int i = 0; i < 1200; ++i) w.step();
  EXPECT_LT(w.stepBufferBytes() * 4, peak) << "peak " << peak;
  // And the world goes on: the boxes left rest on the ground.
  for (size_t i = 0; i < 50; ++i) EXPECT_NEAR(stateOf(w, ids[i]).position.z, 0.5f, 0.02f);
}

TEST(StepBuffers, ASteadyWorldKeepsItsBuffers) {
  World w;  // sleeping off: the boxes stay in the step
  addGround(w);
  layer(w, 12);
  for (int i = 0; i < 60; ++i) w.step();
  const size_t bytes = w.stepBufferBytes();
  ASSERT_GT(w.stats().pairs, 256);
  for (int i = 0; i < 1300; ++i) w.step();
  EXPECT_EQ(w.stepBufferBytes(), bytes);
}

TEST(StepBuffers, AWorldWhoseAwakeBodiesFellGivesThePeaksMemoryBack) {
  // 1,000 spheres apart in zero gravity: no contact pairs at all, so only the buffers sized
  // by the bodies (the solver's, the guard's copy) hold memory.
  WorldDef def;
  def.gravity = {0, 0, 0};
  World w(def);
  std::vector<BodyId> ids;
  for (int i = 0; i < 1000; ++i)
    ids.push_back(addBody(w, sphereBody({float(i % 32) * 3, float(i / 32) * 3, 0}, 0.5f)));
  for (int i = 0; i < 5; ++i) w.step();
  ASSERT_EQ(w.stats().pairs, 0);
  const size_t peak = w.stepBufferBytes();
  ASSERT_GT(peak, size_t(100) << 10) << "1,000 bodies' buffers should be 100s of KiB";

  for (size_t i = 50; i < ids.size(); ++i) ASSERT_TRUE(w.destroyBody(ids[i]).ok());
  for (int i = 0; i < 1200; ++i) w.step();
  EXPECT_LT(w.stepBufferBytes() * 4, peak) << "peak " << peak;
}

TEST(StepBuffers, BodiesWokenBetweenStepsDoNotGrowThem) {
  // 300 spheres at rest apart in zero gravity fall asleep, and their buffers are given back
  // (no awake body for a window). A solver change wakes every island: the next step takes
  // them all, but until then nothing of the step's is held for them (without contacts, the
  // persistent contact list has nothing to take back either).
  WorldDef def;
  def.gravity = {0, 0, 0};
  def.sleep.enabled = true;
  World w(def);
  std::vector<BodyId> ids;
  for (int i = 0; i < 300; ++i)
    ids.push_back(addBody(w, sphereBody({float(i % 20) * 3, float(i / 20) * 3, 0}, 0.5f)));
  for (int i = 0; i < 1500; ++i) w.step();
  for (BodyId id : ids) ASSERT_TRUE(w.isSleeping(id));
  const size_t asleep = w.stepBufferBytes();

  SolverSettings s = w.def().solver;
  s.iterations += 1;
  ASSERT_TRUE(w.setSolverSettings(s).ok());
  ASSERT_FALSE(w.isSleeping(ids[0]));
  EXPECT_EQ(w.stepBufferBytes(), asleep);
  w.step();
  EXPECT_GT(w.stepBufferBytes(), asleep + 300 * 64) << "the step takes all 300";
  EXPECT_EQ(stateOf(w, ids[299]).position.x, float(299 % 20) * 3);
}
