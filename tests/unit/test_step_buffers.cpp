// The step's buffers follow the world's activity (World::Impl::followActivity): a world whose
// contact pairs fell to a fraction of an earlier peak gives the peak's memory back, and a
// world whose activity holds steady keeps its buffers (no reallocation churn).
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
  EXPECT_EQ(w.stepBufferBytes(), peak) << "within a window nothing is given back";

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
