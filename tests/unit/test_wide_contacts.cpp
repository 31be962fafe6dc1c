// The Gauss-Seidel scheme's vectorized contacts (physics/dynamics/solver_wide.h): a schedule that
// keeps every body's order of constraints, blocks whose lanes share no dynamic body, and
// results and velocity residuals bit-identical to the scalar pass on every Gauss-Seidel preset.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <map>
#include <set>
#include <string>
#include <vector>

#include "dynamics/solver.h"
#include "dynamics/solver_wide.h"
#include "phys/scene/presets.h"
#include "phys/scene/scene.h"
#include "phys/world/world.h"
#include "solver_test_util.h"
#include "test_util.h"

using namespace phys;

namespace {

/// Turns the vectorized contacts off for one scope.
struct ScalarContacts {
  ScalarContacts() { setVectorizedContacts(false); }
  ~ScalarContacts() { setVectorizedContacts(true); }
};

/// A manifold between solver bodies a and b with `points` points.
SolverManifold manifold(int a, int b, int points) {
  SolverManifold m;
  m.a = a;
  m.b = b;
  m.count = points;
  m.normal = {0, 0, 1};
  m.t1 = {1, 0, 0};
  m.t2 = {0, 1, 0};
  m.friction = 0.5f;
  for (int k = 0; k < points; ++k) {
    m.rA[k] = {0.1f * float(k), 0, 0.5f};
    m.rB[k] = {0.1f * float(k), 0, -0.5f};
  }
  return m;
}

void addJoint(Solver& s, int a, int b) {
  s.rows.push_back(test::jointRow(a, b));
}

Solver bodiesSolver(int n) {
  Solver s;
  s.bodies.resize(size_t(n) + 1);
  for (int i = 1; i <= n; ++i) {
    s.bodies[size_t(i)].dynamic = true;
    s.bodies[size_t(i)].invMass = 1;
    s.bodies[size_t(i)].invI = Mat3::diagonal({1, 1, 1});
  }
  s.scheme = SolverSettings::Scheme::GaussSeidel;
  return s;
}

TEST(WideContacts, ScheduleKeepsEveryBodysOrderAndPacksDisjointLanes) {
  // A wall of bodies in rows, each resting on the two below it (a pyramid's contact graph),
  // in the order a pyramid's contacts come: row by row; two joints (solved before every
  // contact, as the World orders them) and one kinematic body, whose constraints may share
  // lanes: the solve never writes it.
  const int base = 16;
  std::vector<std::vector<int>> id;
  int n = 0;
  for (int row = 0; row < base; ++row) {
    id.emplace_back();
    for (int i = 0; i < base - row; ++i) id.back().push_back(++n);
  }
  Solver s = bodiesSolver(n);
  s.bodies[5].dynamic = false;
  s.bodies[5].invMass = 0;
  s.bodies[5].invI = Mat3::zero();
  addJoint(s, id[3][0], id[3][1]);
  addJoint(s, id[6][0], id[7][0]);
  std::vector<SolverManifold> manifolds;
  for (int i = 0; i < base; ++i) manifolds.push_back(manifold(0, id[0][size_t(i)], 4));
  for (int row = 1; row < base; ++row) {
    for (size_t i = 0; i < id[size_t(row)].size(); ++i) {
      manifolds.push_back(manifold(id[size_t(row) - 1][i], id[size_t(row)][i], 4));
      manifolds.push_back(manifold(id[size_t(row) - 1][i + 1], id[size_t(row)][i], 1 + int(i % 4)));
    }
  }
  s.indexUnits();
  s.finishRows(0, s.rows.size());
  ASSERT_EQ(s.groups.size(), 2u);
  WideContacts w;
  w.build(s, manifolds);
  ASSERT_TRUE(w.active);

  // The serial order: the joints' groups, then the manifolds. Each constraint is a pair of
  // bodies; `order` lists them as the schedule meets them.
  auto bodiesOf = [&](size_t c) {
    return c < s.groups.size()
               ? std::pair(s.groups[c].a, s.groups[c].b)
               : std::pair(manifolds[c - s.groups.size()].a, manifolds[c - s.groups.size()].b);
  };
  std::vector<size_t> order;
  std::multiset<size_t> seen;
  for (size_t item = 0; item < w.schedule.size(); ++item) {
    const WideContacts::Item& it = w.schedule[item];
    if (!it.wide) {
      order.push_back(it.index);
      seen.insert(it.index);
      continue;
    }
    std::set<int> inBlock;
    for (uint32_t m : w.manifoldsOf(it.index)) {
      const size_t c = s.groups.size() + m;
      for (int body : {bodiesOf(c).first, bodiesOf(c).second}) {
        if (!s.bodies[size_t(body)].dynamic) continue;
        EXPECT_TRUE(inBlock.insert(body).second) << "body " << body << " twice in block " << item;
      }
      order.push_back(c);
      seen.insert(c);
    }
  }
  const size_t constraints = s.groups.size() + manifolds.size();
  ASSERT_EQ(seen.size(), constraints);
  for (size_t c = 0; c < constraints; ++c) EXPECT_EQ(seen.count(c), 1u) << c;

  // Each dynamic body meets its constraints in the serial order.
  std::map<int, size_t> last;
  for (size_t c : order) {
    for (int body : {bodiesOf(c).first, bodiesOf(c).second}) {
      if (!s.bodies[size_t(body)].dynamic) continue;
      auto it = last.find(body);
      if (it != last.end()) {
        EXPECT_LT(it->second, c) << "body " << body;
      }
      last[body] = c;
    }
  }
  // Packing: no schedule is shorter than the longest chain of constraints that share bodies
  // (each must follow the one before), nor than the manifolds over the lanes; this one is
  // close to that bound.
  std::vector<int> depthOf(s.bodies.size(), 0);
  int depth = 0;
  for (size_t c = 0; c < constraints; ++c) {
    auto [a, b] = bodiesOf(c);
    const bool da = s.bodies[size_t(a)].dynamic, db = s.bodies[size_t(b)].dynamic;
    const int d = 1 + std::max(da ? depthOf[size_t(a)] : 0, db ? depthOf[size_t(b)] : 0);
    if (da) depthOf[size_t(a)] = d;
    if (db) depthOf[size_t(b)] = d;
    depth = std::max(depth, d);
  }
  const size_t bound =
      std::max(size_t(depth), (manifolds.size() + wide::kLanes - 1) / wide::kLanes);
  EXPECT_LE(double(w.schedule.size()), 1.2 * double(bound))
      << w.laneCount() << " lanes in " << w.blockCount() << " blocks; chain " << depth;
}

TEST(WideContacts, StoreHandsTheImpulsesBackToTheContacts) {
  Solver s = bodiesSolver(2);
  std::vector<SolverManifold> manifolds = {manifold(0, 1, 3), manifold(1, 2, 4)};
  float x = 0;
  for (SolverManifold& m : manifolds) {
    for (int k = 0; k < m.count; ++k) {
      m.normalImpulse[k] = x += 0.25f;
      m.tangentImpulse[k][0] = x += 0.25f;
      m.tangentImpulse[k][1] = -(x += 0.25f);
    }
  }
  s.indexUnits();
  const std::vector<SolverManifold> before = manifolds;
  WideContacts w;
  w.build(s, manifolds);
  for (SolverManifold& m : manifolds) {  // the blocks own the impulses now
    for (int k = 0; k < m.count; ++k) m.normalImpulse[k] = m.tangentImpulse[k][0] = -1;
  }
  // Each manifold's contact, in another order than the manifolds' (contactOf).
  std::vector<Contact> contacts(manifolds.size());
  const std::vector<uint32_t> contactOf = {1, 0};
  w.store(contacts, contactOf);
  EXPECT_FALSE(w.active);
  for (size_t i = 0; i < manifolds.size(); ++i) {
    const Contact& c = contacts[contactOf[i]];
    for (int k = 0; k < manifolds[i].count; ++k) {
      EXPECT_EQ(c.normalImpulse[k], before[i].normalImpulse[k]) << i << " " << k;
      EXPECT_EQ(c.tangentImpulse[k][0], before[i].tangentImpulse[k][0]);
      EXPECT_EQ(c.tangentImpulse[k][1], before[i].tangentImpulse[k][1]);
    }
  }
}

struct Case {
  const char* scene;
  int steps;
};

struct Outcome {
  uint64_t hash = 0;             ///< state after the run
  std::vector<double> residual;  ///< each step's velocity residual
  int vectorized = 0;            ///< most manifolds solved in lanes in a step
};

Outcome run(const std::string& scenePath, const SolverSettings& solver, int steps) {
  Scene scene;
  Status st = loadSceneFile(scenePath, &scene);
  EXPECT_TRUE(st.ok()) << st.message;
  scene.world.solver = solver;
  scene.world.threads = 1;
  World world(scene.world);
  std::vector<BodyId> ids;
  EXPECT_TRUE(instantiateScene(scene, &world, &ids).ok());
  Outcome out;
  for (int i = 0; i < steps; ++i) {
    world.step();
    out.vectorized = std::max(out.vectorized, world.stats().vectorizedManifolds);
    out.residual.push_back(world.stats().velocityResidual);
  }
  out.hash = world.stateHash();
  return out;
}

TEST(WideContacts, BitIdenticalToTheScalarPassOnEveryGaussSeidelPreset) {
  std::map<std::string, Preset> presets;
  ASSERT_TRUE(
      loadPresetsFile(std::string(PHYS_SOURCE_DIR) + "/configs/presets.json", &presets, nullptr)
          .ok());
  // Stacks, an impact, deep overlap, bounces, friction on a slope, motors and joints beside
  // contacts; each long enough for contacts to come, go and be warm-started.
  const Case cases[] = {{"pyramid_20", 90},       {"box_stack", 20},     {"overlap", 40},
                        {"restitution", 90},      {"friction_ramp", 60}, {"windmill", 60},
                        {"suspension_bridge", 60}};
  // Every Gauss-Seidel preset, and the default with the other friction model.
  Preset flipped = presets.at("soft_step");
  flipped.settings.patchFriction = !flipped.settings.patchFriction;
  presets["soft_step, patch_friction flipped"] = flipped;
  int presetsRun = 0;
  for (const auto& [name, preset] : presets) {
    if (preset.settings.scheme != SolverSettings::Scheme::GaussSeidel) continue;
    ++presetsRun;
    for (const Case& c : cases) {
      const std::string path =
          std::string(PHYS_SOURCE_DIR) + "/configs/scenes/" + c.scene + ".json";
      const Outcome wide = run(path, preset.settings, c.steps);
      Outcome scalar;
      {
        ScalarContacts off;
        scalar = run(path, preset.settings, c.steps);
      }
      EXPECT_EQ(scalar.vectorized, 0) << c.scene;
      const SolverSettings& ps = preset.settings;
      if (ps.blockContacts ||
          (ps.positionPass != SolverSettings::PositionPass::None && ps.positionIterations > 0)) {
        EXPECT_EQ(wide.vectorized, 0) << name << " solves its contacts with rows only";
      } else if (!ps.splitPushout || c.scene != std::string("overlap")) {
        // With the split push-out, the steps with a contact deeper than 1 cm take rows (all
        // of overlap's first 40); the others are vectorized.
        EXPECT_GT(wide.vectorized, 0) << c.scene << " with " << name;
      }
      EXPECT_EQ(wide.hash, scalar.hash) << c.scene << " with " << name;
      EXPECT_EQ(wide.residual, scalar.residual) << c.scene << " with " << name;
    }
  }
  EXPECT_GE(presetsRun, 5);  // soft_step (both ways), pgs, pgs_ngs (rows), ldl_pgs
}

TEST(WideContacts, ConvergenceControlCountsTheSameIterations) {
  // With a tolerance the kernels also measure each iteration's largest velocity change.
  SolverSettings s;
  s.tolerance = 1e-3f;
  s.iterations = 8;
  const std::string path = std::string(PHYS_SOURCE_DIR) + "/configs/scenes/pyramid_20.json";
  auto iterations = [&](bool vectorized) {
    setVectorizedContacts(vectorized);
    Scene scene;
    EXPECT_TRUE(loadSceneFile(path, &scene).ok());
    scene.world.solver = s;
    World world(scene.world);
    std::vector<BodyId> ids;
    EXPECT_TRUE(instantiateScene(scene, &world, &ids).ok());
    std::vector<int> used;
    for (int i = 0; i < 60; ++i) {
      world.step();
      used.push_back(world.stats().iterationsUsed);
    }
    setVectorizedContacts(true);
    return std::make_pair(used, world.stateHash());
  };
  const auto wide = iterations(true), scalar = iterations(false);
  EXPECT_EQ(wide.first, scalar.first);
  EXPECT_EQ(wide.second, scalar.second);
  // The tolerance cut some substeps short (the measure is not always zero).
  int total = 0;
  for (int u : wide.first) total += u;
  EXPECT_LT(total, 60 * s.substeps * s.iterations);
}

}  // namespace

namespace {

/// A 1 m cube resting on the ground, spun about the vertical at w0: time until it stops.
double spinDownSeconds(bool patch, float w0) {
  WorldDef def;
  def.solver.patchFriction = patch;
  World w(def);
  BodyId ground, box;
  EXPECT_TRUE(w.createBody(test::groundBody(0.5f), &ground).ok());
  BodyDef d = test::boxBody({0, 0, 0.5f});
  d.shapes[0].material.friction = 0.5f;
  EXPECT_TRUE(w.createBody(d, &box).ok());
  for (int i = 0; i < 30; ++i) w.step();  // settle
  EXPECT_TRUE(w.setVelocity(box, {0, 0, 0}, {0, 0, w0}).ok());
  for (int i = 1; i <= 600; ++i) {
    w.step();
    BodyState s;
    EXPECT_TRUE(w.getBody(box, &s).ok());
    if (std::abs(s.angularVelocity.z) < 1e-3f) return i * double(def.timeStep);
  }
  return 1e9;
}

TEST(PatchFriction, TwistStopsASpinningBoxAsPointFrictionDoes) {
  // Coulomb friction at the four corners (mu m g / 4 each, at the half-diagonal sqrt(2) h)
  // gives a torque mu m g sqrt(2) h about the vertical; with I = m (2h)^2 / 6 the spin falls
  // at alpha = 3 sqrt(2) mu g / (2 h) = 20.8 rad/s^2 (mu 0.5, h 0.5). The patch's twist row
  // has the same bound: mu times the normal load times the corners' mean distance.
  const double mu = 0.5, g = 9.81, h = 0.5, w0 = 5;
  const double expected = w0 / (3 * std::sqrt(2.0) * mu * g / (2 * h));
  for (bool patch : {false, true}) {
    const double t = spinDownSeconds(patch, float(w0));
    std::printf("%s: stopped after %.3f s (expected %.3f)\n", patch ? "patch" : "point", t,
                expected);
    EXPECT_NEAR(t, expected, 0.15 * expected + 1.0 / 60) << (patch ? "patch" : "point");
  }
}

}  // namespace
