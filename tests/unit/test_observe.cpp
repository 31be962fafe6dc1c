// World::observe: states computed elsewhere (a peer engine) measured by the same collision
// stages and metrics as our own steps.
#include <gtest/gtest.h>

#include <cmath>

#include "phys/scene/metrics.h"
#include "phys/scene/scene.h"
#include "phys/world/world.h"
#include "test_util.h"

using namespace phys;
using namespace phys::test;

namespace {

ObservedBody observed(Vec3 p, Vec3 v = {}, Vec3 w = {}, Quat q = {}) {
  return {p, q, v, w};
}

}  // namespace

TEST(Observe, BoxObservedInTheGroundReportsItsDepth) {
  World w;
  BodyId ground = addGround(w);
  BodyId box = addBody(w, boxBody({0, 0, 2}, {0.5f, 0.5f, 0.5f}));
  ASSERT_TRUE(w.observe({ground, box}, {observed({}), observed({0, 0, 0.49f})}, 0.25).ok());
  EXPECT_NEAR(w.stats().maxPenetration, 0.01, 1e-5);
  EXPECT_EQ(w.stats().contactPoints, 4);
  EXPECT_EQ(w.contacts().size(), 1u);
  EXPECT_EQ(w.profile().total, 0.25);
  EXPECT_EQ(w.profile().solve, 0.0);
  // The pose is taken as given: nothing is solved or integrated.
  EXPECT_EQ(stateOf(w, box).position.z, 0.49f);
  EXPECT_EQ(stateOf(w, box).linearVelocity.z, 0.0f);
}

TEST(Observe, EnergiesFollowTheGivenStatesAndTimeAdvances) {
  World w;
  BodyId ball = addBody(w, sphereBody({0, 0, 10}, 0.5f));
  const double m = stateOf(w, ball).mass, g = 9.81;
  ASSERT_TRUE(w.observe({ball}, {observed({0, 0, 5}, {0, 0, -3})}, 1).ok());
  EXPECT_NEAR(w.stats().energyBefore, m * g * 10, 1e-3 * m);
  EXPECT_NEAR(w.stats().energyAfter, m * g * 5 + 0.5 * m * 9, 1e-3 * m);
  EXPECT_EQ(w.time(), double(w.def().timeStep));
  EXPECT_EQ(w.stats().step, 1u);
  ASSERT_TRUE(w.observe({ball}, {observed({0, 0, 4})}, 1).ok());
  EXPECT_EQ(w.time(), 2 * double(w.def().timeStep));
  EXPECT_NEAR(w.stats().energyBefore, m * g * 5 + 0.5 * m * 9, 1e-3 * m);
}

TEST(Observe, BallJointErrorIsTheAnchorsDistance) {
  World w;
  BodyId a = addBody(w, sphereBody({0, 0, 1}, 0.1f));
  BodyId b = addBody(w, sphereBody({1, 0, 1}, 0.1f));
  JointDef j;
  j.type = JointType::Ball;
  j.bodyA = a;
  j.bodyB = b;
  j.anchorA = {0.5f, 0, 0};
  j.anchorB = {-0.5f, 0, 0};
  JointId jid;
  ASSERT_TRUE(w.createJoint(j, &jid).ok());
  ASSERT_TRUE(w.observe({a, b}, {observed({0, 0, 1}), observed({1.05f, 0, 1})}, 1).ok());
  JointState js;
  ASSERT_TRUE(w.getJoint(jid, nullptr, &js).ok());
  EXPECT_NEAR(js.positionError, 0.05, 1e-5);
}

TEST(Observe, MetricsRecorderReadsObservedSteps) {
  Scene scene;
  scene.metrics.settleTime = 0;
  BodyDef ground;
  ground.type = BodyType::Static;
  ground.shapes.push_back({ShapeGeom::plane({0, 0, 1}, 0), {}, {}});
  scene.bodies = {ground, boxBody({0, 0, 0.5f}, {0.5f, 0.5f, 0.5f})};
  scene.metrics.topBodies = {1};
  World w(scene.world);
  std::vector<BodyId> ids;
  ASSERT_TRUE(instantiateScene(scene, &w, &ids).ok());
  MetricsRecorder rec(scene, w, ids);
  for (int i = 0; i < 3; ++i) {
    ASSERT_TRUE(
        w.observe(ids, {observed({}), observed({0.1f * float(i + 1), 0, 0.497f})}, 2.0).ok());
    rec.afterStep(w);
  }
  MetricsSummary s = rec.summary();
  EXPECT_EQ(s.steps, 3);
  EXPECT_EQ(s.msPerStepMedian, 2.0);
  EXPECT_NEAR(*s.topDrift, 0.3, 1e-5);
  EXPECT_NEAR(*s.penetrationMax, 0.003, 1e-5);
}

TEST(Observe, RejectsBadInputAndChangesNothing) {
  World w;
  BodyId ball = addBody(w, sphereBody({0, 0, 1}, 0.5f));
  EXPECT_FALSE(w.observe({ball}, {}, 1).ok());
  EXPECT_FALSE(w.observe({ball}, {observed({0, 0, NAN})}, 1).ok());
  EXPECT_FALSE(w.observe({ball}, {observed({}, {}, {}, Quat{0, 0, 0, 2})}, 1).ok());
  EXPECT_EQ(w.stats().step, 0u);
  EXPECT_EQ(w.time(), 0.0);
  EXPECT_EQ(stateOf(w, ball).position.z, 1.0f);
}
