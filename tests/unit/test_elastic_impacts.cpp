// Restitution at several simultaneous contacts (World::Impl::limitRestitutionEnergy): a body
// hit while it touches others, in a row or a cluster of elastic bodies, must end with no more
// energy than the impact brought, and with the momentum it had.
#include <gtest/gtest.h>

#include <cmath>
#include <string>
#include <vector>

#include "phys/scene/metrics.h"
#include "phys/scene/scene.h"
#include "phys/world/world.h"
#include "test_util.h"

namespace phys {
namespace {

using test::addBody;
using test::sphereBody;
using test::stateOf;

struct Body {
  BodyId id;
  float mass;
};

Vec3 momentum(const World& w, const std::vector<Body>& bodies) {
  Vec3 p;
  for (const Body& b : bodies) p += stateOf(w, b.id).linearVelocity * b.mass;
  return p;
}

/// A cube of 3 x 3 x 3 touching spheres (radius 0.25 m, restitution 1, masses 1 to 8 kg) in
/// zero gravity, hit by two more along diagonals at 12 and 9 m/s.
std::vector<Body> buildCluster(World& w) {
  std::vector<Body> out;
  auto add = [&](Vec3 p, float mass, Vec3 v) {
    BodyDef d = sphereBody(p, 0.25f);
    d.shapes[0].material.restitution = 1;
    d.shapes[0].material.friction = 0.3f;
    d.mass = mass;
    d.linearVelocity = v;
    out.push_back({addBody(w, d), mass});
  };
  for (int i = 0; i < 27; ++i)
    add({0.5f * float(i % 3), 0.5f * float(i / 3 % 3), 0.5f * float(i / 9)}, 1.0f + float(i % 8),
        {});
  const Vec3 c{0.5f, 0.5f, 0.5f};
  const Vec3 d1 = normalize(Vec3{1, 0.6f, 0.3f}), d2 = normalize(Vec3{-0.4f, 1, -0.7f});
  add(c - d1 * 2.5f, 4, d1 * 12);
  add(c - d2 * 2.5f, 2, d2 * 9);
  return out;
}

TEST(ElasticImpacts, AClusterHitByTwoEndsWithNoMoreEnergyAndTheSameMomentum) {
  WorldDef def;
  def.gravity = {};
  def.threads = 1;
  World w(def);
  const std::vector<Body> bodies = buildCluster(w);
  const double e0 = w.energy();
  const Vec3 p0 = momentum(w, bodies);
  double highest = e0;
  for (int i = 0; i < 120; ++i) {
    w.step();
    highest = std::max(highest, w.energy());
  }
  EXPECT_LE(highest, e0 * (1 + 1e-4)) << "energy rose by " << (highest / e0 - 1) * 100 << " %";
  EXPECT_GT(w.energy(), 0.3 * e0);  // the impacts bounced: elastic, not absorbed
  const Vec3 p = momentum(w, bodies);
  EXPECT_LT(length(p - p0), 1e-3f * length(p0));
}

TEST(ElasticImpacts, StressSeed26ClusterMakesNoEnergy) {
  // physbench --stress --kinds elastic --seed 26, dumped: 27 touching elastic boxes in zero
  // gravity, hit by projectiles; the default made 11.6 % more energy before the limit.
  Scene scene;
  ASSERT_TRUE(
      loadSceneFile(std::string(PHYS_SOURCE_DIR) + "/tests/data/elastic_cluster_seed26.json", &scene)
          .ok());
  scene.world.threads = 1;
  World w(scene.world);
  std::vector<BodyId> ids;
  ASSERT_TRUE(instantiateScene(scene, &w, &ids).ok());
  auto momentumOf = [&] {
    Vec3 p;
    for (BodyId id : ids) {
      const BodyState s = stateOf(w, id);
      p += s.linearVelocity * s.mass;
    }
    return p;
  };
  const double e0 = w.energy();
  const Vec3 p0 = momentumOf();
  double highest = e0;
  for (int i = 0; i < 300; ++i) {
    w.step();
    highest = std::max(highest, w.energy());
    // The impacts are over by step 20; the ground plane, 5 m below, takes momentum later.
    if (i == 60) {
      EXPECT_LT(length(momentumOf() - p0), 1e-3f * length(p0));
    }
  }
  EXPECT_LE(highest, e0 * (1 + 1e-3)) << "energy rose by " << (highest / e0 - 1) * 100 << " %";
}

TEST(ElasticImpacts, ARowStruckAlongItsLengthPassesTheImpactOn) {
  // Newton's cradle on the ground: five touching balls (restitution 1), a sixth at 6 m/s.
  WorldDef def;
  def.threads = 1;
  World w(def);
  test::addGround(w, 0.0f, 1.0f);
  std::vector<Body> row;
  for (int i = 0; i < 6; ++i) {
    BodyDef d = sphereBody({i == 0 ? -1.0f : 0.5f * float(i), 0, 0.25f}, 0.25f);
    d.shapes[0].material.restitution = 1;
    d.shapes[0].material.friction = 0;
    d.mass = 1;
    if (i == 0) d.linearVelocity = {6, 0, 0};
    row.push_back({addBody(w, d), 1});
  }
  const double e0 = w.energy();
  double highest = e0;
  for (int i = 0; i < 60; ++i) {
    w.step();
    highest = std::max(highest, w.energy());
  }
  EXPECT_LE(highest, e0 * (1 + 1e-4)) << "energy rose by " << (highest / e0 - 1) * 100 << " %";
  // Momentum along the row is kept (the frictionless ground takes none of it), and it all
  // leaves with the last ball (issue 41: each contact is a collision of equal masses).
  EXPECT_NEAR(momentum(w, row).x, 6.0f, 0.06f);
  EXPECT_NEAR(stateOf(w, row.back().id).linearVelocity.x, 6.0f, 0.3f);
  for (size_t i = 0; i + 1 < row.size(); ++i)
    EXPECT_LT(std::fabs(stateOf(w, row[i].id).linearVelocity.x), 0.3f) << "ball " << i;
}

/// A row of `n` equal free balls (radius 0.25 m, 1 kg, restitution 1, no friction) touching
/// along x in zero gravity, the first struck by one more at `speed`: each contact is a
/// collision of two equal masses, which exchange velocities, so the last ball leaves with
/// the striker's speed and the others stay at rest. With `reversed` the bodies are created
/// from the far end (the contacts then come in the reverse order of the shock). Returns the
/// balls' x velocities after a second, the striker first.
std::vector<float> strikeFreeRow(int n, float speed, bool reversed, double* energyRise) {
  WorldDef def;
  def.gravity = {};
  def.threads = 1;
  World w(def);
  std::vector<BodyId> ids(size_t(n + 1));
  for (int k = 0; k <= n; ++k) {
    const int i = reversed ? n - k : k;  // 0 is the striker
    BodyDef d = sphereBody({i == 0 ? -1.0f : 0.5f * float(i - 1), 0, 0}, 0.25f);
    d.shapes[0].material.restitution = 1;
    d.shapes[0].material.friction = 0;
    d.mass = 1;
    if (i == 0) d.linearVelocity = {speed, 0, 0};
    ids[size_t(i)] = addBody(w, d);
  }
  const double e0 = w.energy();
  double highest = e0;
  for (int s = 0; s < 60; ++s) {
    w.step();
    highest = std::max(highest, w.energy());
  }
  *energyRise = highest / e0 - 1;
  std::vector<float> vx;
  for (BodyId id : ids) vx.push_back(stateOf(w, id).linearVelocity.x);
  return vx;
}

void expectImpactPassedOn(int n, bool reversed) {
  const float v = 3;
  double rise = 0;
  const std::vector<float> vx = strikeFreeRow(n, v, reversed, &rise);
  std::string all;
  for (float x : vx) all += " " + std::to_string(x);
  SCOPED_TRACE("x velocities, striker first:" + all);
  EXPECT_NEAR(vx.back(), v, 0.05f * v) << "the last ball leaves with the striker's speed";
  for (size_t i = 0; i + 1 < vx.size(); ++i)
    EXPECT_LT(std::fabs(vx[i]), 0.05f * v) << "ball " << i << " stays at rest";
  EXPECT_LE(rise, 1e-4) << "energy rose by " << rise * 100 << " %";
}

TEST(ElasticImpacts, AFreeRowOfFiveStruckAtOneEndSendsOffTheLastBallAlone) {
  expectImpactPassedOn(5, false);
}

TEST(ElasticImpacts, AFreeRowOfThreeStruckAtOneEndSendsOffTheLastBallAlone) {
  expectImpactPassedOn(3, false);
}

TEST(ElasticImpacts, AFreeRowBuiltFromTheFarEndPassesTheImpactOnAlike) {
  // The contacts are met against the shock's direction: the impact needs a sweep per ball.
  expectImpactPassedOn(5, true);
}

TEST(ElasticImpacts, NewtonsCradlePassesTheImpactThrough) {
  // configs/scenes/newtons_cradle.json with the default solver: the scene's own criteria.
  Scene scene = test::loadScene("newtons_cradle");
  scene.world.threads = 1;
  World w(scene.world);
  std::vector<BodyId> ids;
  ASSERT_TRUE(instantiateScene(scene, &w, &ids).ok());
  MetricsRecorder rec(scene, w, ids);
  for (int i = 0; i < 60; ++i) {  // the impact comes at about 0.35 s
    w.step();
    rec.afterStep(w);
  }
  const MetricsSummary m = rec.summary();
  ASSERT_TRUE(m.value("cradle.last_speed_ratio").has_value());
  EXPECT_NEAR(*m.value("cradle.last_speed_ratio"), 1.0, 0.1);
  EXPECT_LT(*m.value("cradle.others_speed_ratio_max"), 0.1);
}

TEST(ElasticImpacts, AFreeRowStruckFromBothEndsKeepsEnergyAndMomentum) {
  // Two strikers at 3 and -2 m/s into a touching row of four: the impacts cross in the
  // middle; with equal masses the end balls leave with each other's speeds.
  WorldDef def;
  def.gravity = {};
  def.threads = 1;
  World w(def);
  std::vector<Body> row;
  for (int i = 0; i < 6; ++i) {
    const float x = i == 0 ? -1.0f : i == 5 ? 3.0f : 0.5f * float(i - 1);
    BodyDef d = sphereBody({x, 0, 0}, 0.25f);
    d.shapes[0].material.restitution = 1;
    d.shapes[0].material.friction = 0;
    d.mass = 1;
    if (i == 0) d.linearVelocity = {3, 0, 0};
    if (i == 5) d.linearVelocity = {-2, 0, 0};
    row.push_back({addBody(w, d), 1});
  }
  const double e0 = w.energy();
  double highest = e0;
  for (int i = 0; i < 90; ++i) {
    w.step();
    highest = std::max(highest, w.energy());
  }
  EXPECT_LE(highest, e0 * (1 + 1e-4));
  EXPECT_NEAR(w.energy(), e0, 0.01 * e0) << "elastic: no energy lost either";
  EXPECT_NEAR(momentum(w, row).x, 1.0f, 1e-3f);
  EXPECT_NEAR(stateOf(w, row.front().id).linearVelocity.x, -2.0f, 0.1f);
  EXPECT_NEAR(stateOf(w, row.back().id).linearVelocity.x, 3.0f, 0.1f);
  for (size_t i = 1; i + 1 < row.size(); ++i)
    EXPECT_LT(std::fabs(stateOf(w, row[i].id).linearVelocity.x), 0.1f) << "ball " << i;
}

TEST(ElasticImpacts, ABoxLandingFlatBouncesWithoutSpinning) {
  // Its four corners meet the ground at once: solved together, they bounce it straight up.
  WorldDef def;
  def.threads = 1;
  World w(def);
  test::addGround(w, 0.6f, 0.0f);
  BodyDef d = test::boxBody({0, 0, 1.5f}, {0.5f, 0.3f, 0.2f});
  d.shapes[0].material.restitution = 0.8f;
  const BodyId box = addBody(w, d);
  float fastestUp = 0;
  for (int i = 0; i < 50; ++i) {
    w.step();
    const BodyState s = stateOf(w, box);
    fastestUp = std::max(fastestUp, s.linearVelocity.z);
    EXPECT_LT(length(s.angularVelocity), 1e-3f) << "step " << i;
  }
  EXPECT_GT(fastestUp, 0.7f * std::sqrt(2 * 9.81f * 1.3f)) << "it bounced";
}

TEST(ElasticImpacts, AnElasticBallAtRestStaysAtRest) {
  // Restitution 1 on the ground: resting contacts approach at g h, under the threshold.
  WorldDef def;
  def.threads = 1;
  World w(def);
  test::addGround(w, 0.6f, 1.0f);
  BodyDef d = sphereBody({0, 0, 0.25f}, 0.25f);
  d.shapes[0].material.restitution = 1;
  const BodyId ball = addBody(w, d);
  for (int i = 0; i < 120; ++i) {
    w.step();
    EXPECT_LT(length(stateOf(w, ball).linearVelocity), 0.05f) << "step " << i;
  }
  EXPECT_NEAR(stateOf(w, ball).position.z, 0.25f, 5e-3f);
}

TEST(ElasticImpacts, AnElasticBallBouncesBackToItsHeightAndNoHigher) {
  // Restitution 1: each bounce returns the ball to (nearly) the height it fell from, never
  // above it; the collision lands at its time of impact inside the substep.
  WorldDef def;
  def.threads = 1;
  World w(def);
  test::addGround(w, 0.6f, 1.0f);
  BodyDef d = sphereBody({0, 0, 1.1f}, 0.1f);
  d.shapes[0].material.restitution = 1;
  const BodyId ball = addBody(w, d);
  const double e0 = w.energy();
  double highest = e0, apex = 0, lowest = 1e9;
  for (int i = 0; i < 300; ++i) {
    w.step();
    highest = std::max(highest, w.energy());
    const BodyState s = stateOf(w, ball);
    lowest = std::min(lowest, double(s.position.z));
    if (i > 60) apex = std::max(apex, double(s.position.z));
  }
  EXPECT_LE(highest, e0 * (1 + 1e-6));
  EXPECT_GT(apex, 0.97 * 1.1) << "the bounces keep their height";
  EXPECT_GT(lowest, 0.1 - 0.015) << "no deeper than a substep's travel into the ground";
}

}  // namespace
}  // namespace phys
