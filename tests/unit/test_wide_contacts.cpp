// The Gauss-Seidel scheme's vectorized contacts (physics/src/solver_wide.h): a schedule that
// keeps every body's order of constraints, blocks whose lanes share no dynamic body, and
// results bit-identical to the scalar pass on every Gauss-Seidel preset.
#include <gtest/gtest.h>

#include <map>
#include <set>
#include <string>
#include <vector>

#include "../../physics/src/solver.h"
#include "../../physics/src/solver_wide.h"
#include "phys/presets.h"
#include "phys/scene.h"
#include "phys/world.h"

using namespace phys;

namespace {

/// Turns the vectorized contacts off for one scope.
struct ScalarContacts {
  ScalarContacts() { setVectorizedContacts(false); }
  ~ScalarContacts() { setVectorizedContacts(true); }
};

/// A contact group between solver bodies a and b with `points` points: the normal rows, then
/// a friction pair per point, as World builds them.
void addManifold(Solver& s, int a, int b, int points) {
  const int first = int(s.rows.size());
  for (int k = 0; k < points; ++k) {
    Row r;
    r.kind = RowKind::ContactNormal;
    r.a = a;
    r.b = b;
    r.groupStart = k == 0;
    r.linA = {0, 0, -1};
    r.linB = {0, 0, 1};
    r.angA = {0.1f * float(k), 0, 0};
    s.rows.push_back(r);
  }
  for (int k = 0; k < points; ++k) {
    for (Vec3 t : {Vec3{1, 0, 0}, Vec3{0, 1, 0}}) {
      Row r;
      r.kind = RowKind::Friction;
      r.a = a;
      r.b = b;
      r.linA = -t;
      r.linB = t;
      r.mu = 0.5f;
      r.parent = first + k;
      s.rows.push_back(r);
    }
  }
}

void addJoint(Solver& s, int a, int b) {
  Row r;
  r.kind = RowKind::Equality;
  r.a = a;
  r.b = b;
  r.groupStart = true;
  r.linA = {1, 0, 0};
  r.linB = {-1, 0, 0};
  s.rows.push_back(r);
}

TEST(WideContacts, ScheduleKeepsEveryBodysOrderAndPacksDisjointLanes) {
  // A wall of bodies in rows, each resting on the two below it (a pyramid's contact graph),
  // in the order a pyramid's contacts come: row by row. Two joints and one body that is
  // kinematic (its constraints may share lanes: the solve never writes it).
  const int base = 16;
  std::vector<std::vector<int>> id;
  int n = 0;
  for (int row = 0; row < base; ++row) {
    id.emplace_back();
    for (int i = 0; i < base - row; ++i) id.back().push_back(++n);
  }
  Solver s;
  s.bodies.resize(size_t(n) + 1);
  for (int i = 1; i <= n; ++i) {
    s.bodies[size_t(i)].dynamic = i != 5;
    s.bodies[size_t(i)].invMass = i != 5 ? 1 : 0;
  }
  addJoint(s, id[3][0], id[3][1]);
  for (int i = 0; i < base; ++i) addManifold(s, 0, id[0][size_t(i)], 4);
  for (int row = 1; row < base; ++row) {
    for (size_t i = 0; i < id[size_t(row)].size(); ++i) {
      addManifold(s, id[size_t(row) - 1][i], id[size_t(row)][i], 4);
      addManifold(s, id[size_t(row) - 1][i + 1], id[size_t(row)][i], 1 + int(i % 4));
    }
    if (row == 7) addJoint(s, id[6][0], id[7][0]);
  }
  s.scheme = SolverSettings::Scheme::GaussSeidel;
  s.indexUnits();
  s.finishRows(0, s.rows.size());
  WideContacts w;
  w.build(s);
  ASSERT_TRUE(w.active);

  // Every group exactly once; joints stay scalar.
  std::vector<uint32_t> order;  // groups in schedule order, lanes of a block together
  std::multiset<uint32_t> seen;
  size_t scalar = 0;
  for (size_t item = 0; item < w.schedule.size(); ++item) {
    const WideContacts::Item& it = w.schedule[item];
    if (!it.wide) {
      ++scalar;
      EXPECT_EQ(s.rows[s.units[s.groups[it.index].unitBegin]].kind, RowKind::Equality);
      order.push_back(it.index);
      seen.insert(it.index);
      continue;
    }
    std::set<int> bodies;
    for (uint32_t g : w.groupsOf(it.index)) {
      for (int body : {s.groups[g].a, s.groups[g].b}) {
        if (!s.bodies[size_t(body)].dynamic) continue;
        EXPECT_TRUE(bodies.insert(body).second) << "body " << body << " twice in block " << item;
      }
      order.push_back(g);
      seen.insert(g);
    }
  }
  EXPECT_EQ(scalar, 2u);
  ASSERT_EQ(seen.size(), s.groups.size());
  for (uint32_t g = 0; g < s.groups.size(); ++g) EXPECT_EQ(seen.count(g), 1u) << g;

  // Each dynamic body meets its groups in row order, as serial Gauss-Seidel does.
  std::map<int, uint32_t> lastGroup;
  for (uint32_t g : order) {
    for (int body : {s.groups[g].a, s.groups[g].b}) {
      if (!s.bodies[size_t(body)].dynamic) continue;
      auto it = lastGroup.find(body);
      if (it != lastGroup.end()) {
        EXPECT_LT(it->second, g) << "body " << body;
      }
      lastGroup[body] = g;
    }
  }
  // Packing: no schedule is shorter than the longest chain of groups that share bodies (each
  // must follow the one before), nor than the groups over the lanes; this one is close to it.
  std::vector<int> depthOf(s.bodies.size(), 0);
  int depth = 0;
  for (const Solver::Group& g : s.groups) {
    const bool da = s.bodies[size_t(g.a)].dynamic, db = s.bodies[size_t(g.b)].dynamic;
    const int d = 1 + std::max(da ? depthOf[size_t(g.a)] : 0, db ? depthOf[size_t(g.b)] : 0);
    if (da) depthOf[size_t(g.a)] = d;
    if (db) depthOf[size_t(g.b)] = d;
    depth = std::max(depth, d);
  }
  const size_t bound = std::max(size_t(depth), (s.groups.size() + wide::kLanes - 1) / wide::kLanes);
  EXPECT_LE(double(w.schedule.size()), 1.2 * double(bound))
      << w.laneCount() << " lanes in " << w.blockCount() << " blocks; chain " << depth;
}

TEST(WideContacts, StoreHandsTheImpulsesBackToTheRows) {
  Solver s;
  s.bodies.resize(3);
  for (int i = 1; i <= 2; ++i) {
    s.bodies[size_t(i)].dynamic = true;
    s.bodies[size_t(i)].invMass = 1;
    s.bodies[size_t(i)].invI = Mat3::diagonal({1, 1, 1});
  }
  addManifold(s, 0, 1, 3);
  addManifold(s, 1, 2, 4);
  for (size_t i = 0; i < s.rows.size(); ++i) s.rows[i].lambda = 0.25f * float(i + 1);
  s.scheme = SolverSettings::Scheme::GaussSeidel;
  s.indexUnits();
  s.finishRows(0, s.rows.size());
  const std::vector<Row> before = s.rows;
  WideContacts w;
  w.build(s);
  for (Row& r : s.rows) r.lambda = -1;  // the blocks own the impulses now
  w.store(s);
  EXPECT_FALSE(w.active);
  for (size_t i = 0; i < s.rows.size(); ++i) EXPECT_EQ(s.rows[i].lambda, before[i].lambda) << i;
}

struct Case {
  const char* scene;
  int steps;
};

/// State hash after `steps` of a scene file with a preset, and the last step's count of
/// vectorized manifolds.
std::pair<uint64_t, int> run(const std::string& scenePath, const SolverSettings& solver,
                             int steps) {
  Scene scene;
  Status st = loadSceneFile(scenePath, &scene);
  EXPECT_TRUE(st.ok()) << st.message;
  scene.world.solver = solver;
  scene.world.threads = 1;
  World world(scene.world);
  std::vector<BodyId> ids;
  EXPECT_TRUE(instantiateScene(scene, &world, &ids).ok());
  int vectorized = 0;
  for (int i = 0; i < steps; ++i) {
    world.step();
    vectorized = std::max(vectorized, world.stats().vectorizedManifolds);
  }
  return {world.stateHash(), vectorized};
}

TEST(WideContacts, BitIdenticalToTheScalarPassOnEveryGaussSeidelPreset) {
  std::map<std::string, Preset> presets;
  ASSERT_TRUE(
      loadPresetsFile(std::string(PHYS_SOURCE_DIR) + "/configs/presets.json", &presets, nullptr)
          .ok());
  // Stacks, an impact, deep overlap, bounces, friction on a slope, motors and joints beside
  // contacts; each long enough for contacts to come, go and be warm-started.
  const Case cases[] = {{"pyramid_20", 90},  {"box_stack", 20},     {"overlap", 40},
                        {"restitution", 90}, {"friction_ramp", 60}, {"windmill", 60},
                        {"suspension_bridge", 60}};
  int presetsRun = 0;
  for (const auto& [name, preset] : presets) {
    if (preset.settings.scheme != SolverSettings::Scheme::GaussSeidel) continue;
    ++presetsRun;
    for (const Case& c : cases) {
      const std::string path =
          std::string(PHYS_SOURCE_DIR) + "/configs/scenes/" + c.scene + ".json";
      auto [wide, lanes] = run(path, preset.settings, c.steps);
      std::pair<uint64_t, int> scalar;
      {
        ScalarContacts off;
        scalar = run(path, preset.settings, c.steps);
      }
      EXPECT_EQ(scalar.second, 0) << c.scene;
      if (preset.settings.splitPushout || preset.settings.blockContacts) {
        EXPECT_EQ(lanes, 0) << name << " solves its contacts with rows only";
      } else {
        EXPECT_GT(lanes, 0) << c.scene << " with " << name;
      }
      EXPECT_EQ(wide, scalar.first) << c.scene << " with " << name;
    }
  }
  EXPECT_GE(presetsRun, 4);  // soft_step, pgs, pgs_ngs, ldl_pgs
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
