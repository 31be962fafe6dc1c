// Analytic and invariant tests of the integrator, joints and contacts.
#include <gtest/gtest.h>

#include <cmath>

#include "phys/world/world.h"
#include "test_util.h"

using namespace phys;

using namespace phys::test;

class FreeFall : public ::testing::TestWithParam<int> {};

TEST_P(FreeFall, VelocityIsGTimesTAndPositionMatchesSymplecticEuler) {
  WorldDef def;
  def.solver.substeps = GetParam();
  World w(def);
  BodyId b;
  ASSERT_TRUE(w.createBody(sphereBody({0, 0, 100}, 0.5f), &b).ok());
  const int steps = 60;
  for (int i = 0; i < steps; ++i) w.step();
  const double t = steps * double(def.timeStep), g = 9.81;
  const double h = def.timeStep / GetParam();
  BodyState s = stateOf(w, b);
  EXPECT_NEAR(s.linearVelocity.z, -g * t, 1e-4 * g * t);
  // Semi-implicit Euler with n substeps of h: z = z0 - g t (t + h) / 2 exactly.
  EXPECT_NEAR(s.position.z, 100 - 0.5 * g * t * (t + h), 1e-3);
  // And the analytic answer within the method's O(h) error.
  EXPECT_NEAR(s.position.z, 100 - 0.5 * g * t * t, 0.5 * g * t * h + 1e-3);
}
INSTANTIATE_TEST_SUITE_P(Substeps, FreeFall, ::testing::Values(1, 2, 4));

TEST(Dynamics, ProjectileFollowsParabola) {
  World w;
  BodyDef d = sphereBody({0, 0, 0}, 0.1f);
  d.linearVelocity = {10, 3, 20};
  BodyId b;
  ASSERT_TRUE(w.createBody(d, &b).ok());
  const int steps = 120;
  for (int i = 0; i < steps; ++i) w.step();
  const double t = steps / 60.0, h = 1 / (60.0 * SolverSettings{}.substeps), g = 9.81;
  BodyState s = stateOf(w, b);
  EXPECT_NEAR(s.position.x, 10 * t, 1e-3);
  EXPECT_NEAR(s.position.y, 3 * t, 1e-3);
  EXPECT_NEAR(s.position.z, 20 * t - 0.5 * g * t * (t + h), 2e-3);
  EXPECT_NEAR(s.linearVelocity.z, 20 - g * t, 1e-3);
}

TEST(Dynamics, TorqueFreeBodyConservesAngularMomentum) {
  WorldDef def;
  def.gravity = {0, 0, 0};
  World w(def);
  // A generic tumble (no principal axis near w) for 60 s, as in SCENES.md's free_flight.
  BodyDef d = boxBody({0, 0, 0}, {0.2f, 0.4f, 0.8f});
  d.angularVelocity = {1, 2, 3};
  BodyId b;
  ASSERT_TRUE(w.createBody(d, &b).ok());
  BodyState s0 = stateOf(w, b);
  Vec3 L0 = s0.inertia * s0.angularVelocity;
  const double E0 = 0.5 * dot(s0.angularVelocity, L0);
  double drift = 0, energyDrift = 0;
  for (int i = 0; i < 3600; ++i) {
    w.step();
    BodyState s = stateOf(w, b);
    Vec3 L = s.inertia * s.angularVelocity;
    drift = std::max(drift, double(length(L - L0) / length(L0)));
    energyDrift = std::max(energyDrift, std::fabs(0.5 * dot(s.angularVelocity, L) / E0 - 1));
  }
  EXPECT_LT(drift, 1e-3);
  EXPECT_LT(energyDrift, 1e-2);  // no gyroscopic energy gain or damping
}

TEST(Dynamics, THandleSpinningAboutIntermediateAxisFlips) {
  // Dzhanibekov effect: rotation about the intermediate principal axis is unstable, so the
  // body-frame spin component along it reverses sign periodically. An explicit integrator
  // without the gyroscopic term never flips.
  WorldDef def;
  def.gravity = {0, 0, 0};
  World w(def);
  BodyDef d = boxBody({0, 0, 0}, {0.2f, 0.6f, 1.2f});  // moments: x largest, y middle, z smallest
  d.angularVelocity = {0.01f, 5.0f, 0.01f};
  BodyId b;
  ASSERT_TRUE(w.createBody(d, &b).ok());
  bool flipped = false;
  for (int i = 0; i < 600 && !flipped; ++i) {
    w.step();
    BodyState s = stateOf(w, b);
    Vec3 wb = invRotate(s.rotation, s.angularVelocity);
    flipped = wb.y < -2.5f;
  }
  EXPECT_TRUE(flipped);
}

TEST(Dynamics, SmallAnglePendulumPeriod) {
  World w;
  const float L = 1.0f, r = 0.05f, theta0 = 0.05f;
  Vec3 pivot{0, 0, 3};
  Vec3 c{L * std::sin(theta0), 0, 3 - L * std::cos(theta0)};
  BodyId ball;
  ASSERT_TRUE(w.createBody(sphereBody(c, r), &ball).ok());
  JointDef j;
  j.type = JointType::Ball;
  j.bodyB = ball;
  j.anchorA = pivot;
  j.anchorB = pivot - c;
  ASSERT_TRUE(w.createJoint(j, nullptr).ok());
  // Physical pendulum: T = 2 pi sqrt(I_pivot / (m g L)), I_pivot = 2/5 m r^2 + m L^2.
  const double expected = 2 * M_PI * std::sqrt((0.4 * r * r + L * L) / (9.81 * L));
  // Period from upward zero crossings of x.
  std::vector<double> crossings;
  double prevX = c.x;
  for (int i = 0; i < 60 * 12; ++i) {
    w.step();
    double x = stateOf(w, ball).position.x;
    if (prevX < 0 && x >= 0) crossings.push_back(w.time() - (x / (x - prevX)) / 60.0);
    prevX = x;
  }
  ASSERT_GE(crossings.size(), 3u);
  double period = (crossings.back() - crossings.front()) / double(crossings.size() - 1);
  EXPECT_NEAR(period, expected, 0.01 * expected);
  JointState js;
  ASSERT_TRUE(w.getJoint(w.joints()[0], nullptr, &js).ok());
  EXPECT_LT(js.positionError, 1e-3f);
  // The joint's force on the ball carries its weight (plus a little centripetal force).
  BodyState s = stateOf(w, ball);
  EXPECT_NEAR(js.reactionForce.z, s.mass * 9.81, 0.05 * s.mass * 9.81);
}

class Incline : public ::testing::TestWithParam<float> {};

TEST_P(Incline, SticksBelowFrictionAngleSlidesAboveWithKnownAcceleration) {
  const float mu = GetParam();
  const float theta = 0.3f;  // tan = 0.309
  World w;
  Quat q = Quat::fromAxisAngle({1, 0, 0}, theta);
  BodyDef slope = boxBody({0, 0, 0}, {5, 20, 0.5f}, BodyType::Static, q);
  slope.shapes[0].material.friction = 1.0f;
  ASSERT_TRUE(w.createBody(slope, nullptr).ok());
  // A box resting on the slope: centre 0.5 + 0.25 above the slope's centre plane.
  Vec3 up = rotate(q, {0, 0, 1});
  BodyDef box = boxBody(up * 0.75f, {0.25f, 0.25f, 0.25f}, BodyType::Dynamic, q);
  box.shapes[0].material.friction = mu * mu;  // mixing: sqrt(mu^2 * 1) = mu
  BodyId b;
  ASSERT_TRUE(w.createBody(box, &b).ok());
  for (int i = 0; i < 30; ++i) w.step();  // settle
  Vec3 p0 = stateOf(w, b).position;
  float v0 = length(stateOf(w, b).linearVelocity);
  const int steps = 120;
  for (int i = 0; i < steps; ++i) w.step();
  BodyState s = stateOf(w, b);
  const double t = steps / 60.0, g = 9.81;
  const double a = g * (std::sin(theta) - mu * std::cos(theta));
  if (a <= 0) {
    EXPECT_LT(length(s.position - p0), 1e-3) << "mu " << mu;
  } else {
    double measured = (length(s.linearVelocity) - v0) / t;
    EXPECT_NEAR(measured, a, 0.03 * a) << "mu " << mu;
    // It slides down the slope (negative y for a rotation about +x).
    EXPECT_LT(s.position.y, p0.y);
  }
}
INSTANTIATE_TEST_SUITE_P(Friction, Incline, ::testing::Values(0.5f, 0.35f, 0.2f, 0.0f));

TEST(Dynamics, BounceHeightIsRestitutionSquaredTimesDropHeight) {
  World w;
  addGround(w, 0.6f, 0.5f);
  const float r = 0.1f, h = 1.0f;
  BodyDef d = sphereBody({0, 0, r + h}, r);
  d.shapes[0].material.restitution = 0.5f;
  BodyId b;
  ASSERT_TRUE(w.createBody(d, &b).ok());
  bool bounced = false;
  double apex = 0;
  for (int i = 0; i < 120; ++i) {
    w.step();
    BodyState s = stateOf(w, b);
    if (s.linearVelocity.z > 0) bounced = true;
    if (bounced) apex = std::max(apex, double(s.position.z) - r);
  }
  ASSERT_TRUE(bounced);
  EXPECT_NEAR(apex, 0.25 * h, 0.03 * 0.25 * h);
}

TEST(Dynamics, BoxRestsOnGroundWithoutJitter) {
  World w;
  addGround(w);
  BodyId b;
  ASSERT_TRUE(w.createBody(boxBody({0, 0, 0.5f}, {0.5f, 0.5f, 0.5f}), &b).ok());
  for (int i = 0; i < 120; ++i) w.step();
  BodyState s = stateOf(w, b);
  EXPECT_NEAR(s.position.z, 0.5f, 5e-3f);
  EXPECT_LT(length(s.linearVelocity), 1e-3f);
  EXPECT_LT(length(s.angularVelocity), 1e-3f);
}

TEST(Dynamics, SameSceneTwiceGivesSameStateHash) {
  auto run = [] {
    World w;
    addGround(w);
    for (int i = 0; i < 10; ++i)
      w.createBody(boxBody({0.1f * i, 0, 0.5f + 1.01f * i}, {0.5f, 0.5f, 0.5f}), nullptr);
    for (int i = 0; i < 5; ++i) w.createBody(sphereBody({2, 0.3f * i, 1.0f + i}, 0.3f), nullptr);
    for (int i = 0; i < 200; ++i) w.step();
    return w.stateHash();
  };
  uint64_t a = run(), b = run();
  EXPECT_EQ(a, b);
  EXPECT_NE(a, 0u);
}

TEST(Dynamics, KinematicBodyMovesAtItsVelocityAndIsNotPushed) {
  World w;
  BodyDef k = boxBody({0, 0, 1}, {1, 1, 0.1f}, BodyType::Kinematic);
  k.linearVelocity = {1, 0, 0};
  BodyId kin;
  ASSERT_TRUE(w.createBody(k, &kin).ok());
  BodyId box;
  ASSERT_TRUE(w.createBody(boxBody({0, 0, 1.35f}, {0.25f, 0.25f, 0.25f}), &box).ok());
  for (int i = 0; i < 60; ++i) w.step();
  BodyState s = stateOf(w, kin);
  EXPECT_NEAR(s.position.x, 1.0f, 1e-4f);
  EXPECT_NEAR(s.position.z, 1.0f, 1e-6f);
  // The box rides on the platform.
  EXPECT_GT(stateOf(w, box).position.z, 1.2f);
}
