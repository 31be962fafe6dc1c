// Both cores: the thread pool, the coloring of the colored Gauss-Seidel scheme, results that
// are bit-identical for any thread count, and the convergence control.
#include <gtest/gtest.h>

#include <atomic>
#include <set>
#include <string>
#include <vector>

#include "dynamics/solver.h"
#include "base/thread_pool.h"
#include "phys/scene/scene.h"
#include "phys/world/world.h"
#include "test_util.h"

using namespace phys;
using phys::test::sceneFromJson;

namespace {

TEST(ThreadPool, EveryIndexRunsExactlyOnce) {
  for (int threads : {1, 2, 3, 5}) {
    ThreadPool pool(threads);
    EXPECT_EQ(pool.threads(), threads);
    for (size_t count : {size_t(0), size_t(1), size_t(7), size_t(100), size_t(10007)}) {
      for (size_t grain : {size_t(1), size_t(16), size_t(256)}) {
        std::vector<std::atomic<int>> hits(count);
        pool.parallelFor(count, grain, [&](size_t b, size_t e) {
          ASSERT_LE(b, e);
          ASSERT_LE(e, count);
          for (size_t i = b; i < e; ++i) hits[i].fetch_add(1);
        });
        for (size_t i = 0; i < count; ++i)
          ASSERT_EQ(hits[i].load(), 1) << threads << " threads, " << count << " items, " << i;
      }
    }
  }
}

TEST(ThreadPool, ManyShortLoopsBackToBack) {
  // A step posts hundreds of short loops; a lost wake-up would hang here.
  ThreadPool pool(3);
  std::atomic<long> sum{0};
  for (int loop = 0; loop < 20000; ++loop)
    pool.parallelFor(64, 1, [&](size_t b, size_t e) { sum.fetch_add(long(e - b)); });
  EXPECT_EQ(sum.load(), 20000L * 64);
}

/// A solver with `n` dynamic bodies (1..n) and contact groups between the given pairs (0 is
/// the world), plus one joint group at the front.
Solver contactSolver(int n, const std::vector<std::pair<int, int>>& pairs) {
  Solver s;
  s.bodies.resize(size_t(n) + 1);
  for (int i = 1; i <= n; ++i) {
    s.bodies[size_t(i)].dynamic = true;
    s.bodies[size_t(i)].invMass = 1;
  }
  Row joint;
  joint.kind = RowKind::Equality;
  joint.a = 1;
  joint.b = 2;
  joint.groupStart = true;
  joint.linA = {1, 0, 0};
  joint.linB = {-1, 0, 0};
  s.rows.push_back(joint);
  for (auto [a, b] : pairs) {
    Row r;
    r.kind = RowKind::ContactNormal;
    r.a = a;
    r.b = b;
    r.groupStart = true;
    r.linA = {0, 0, -1};
    r.linB = {0, 0, 1};
    s.rows.push_back(r);
  }
  s.scheme = SolverSettings::Scheme::ColoredGaussSeidel;
  s.indexUnits();
  s.finishRows(0, s.rows.size());
  return s;
}

TEST(ColoredGaussSeidel, NoTwoGroupsOfAColorShareADynamicBody) {
  // A grid of bodies each touching its right and upper neighbour and the ground.
  const int side = 12;
  std::vector<std::pair<int, int>> pairs;
  auto id = [&](int x, int y) { return 1 + x + y * side; };
  for (int y = 0; y < side; ++y) {
    for (int x = 0; x < side; ++x) {
      pairs.push_back({0, id(x, y)});
      if (x + 1 < side) pairs.push_back({id(x, y), id(x + 1, y)});
      if (y + 1 < side) pairs.push_back({id(x, y), id(x, y + 1)});
    }
  }
  Solver s = contactSolver(side * side, pairs);
  ASSERT_GE(s.colorStart.size(), 2u);
  std::multiset<uint32_t> seen;
  for (size_t c = 0; c + 1 < s.colorStart.size(); ++c) {
    std::set<int> bodies;
    for (uint32_t k = s.colorStart[c]; k < s.colorStart[c + 1]; ++k) {
      const Solver::Group& g = s.groups[s.colorGroups[k]];
      seen.insert(s.colorGroups[k]);
      for (int body : {g.a, g.b}) {
        if (body == 0) continue;  // the world is never written
        EXPECT_TRUE(bodies.insert(body).second) << "body " << body << " twice in color " << c;
      }
    }
  }
  // The joint is solved first and serially; every contact group is in exactly one color.
  ASSERT_EQ(s.overflowBegin, 1u);
  EXPECT_EQ(s.serialGroups[0], 0u);
  for (size_t k = s.overflowBegin; k < s.serialGroups.size(); ++k) seen.insert(s.serialGroups[k]);
  EXPECT_EQ(seen.size(), pairs.size());
  for (uint32_t g = 1; g <= pairs.size(); ++g) EXPECT_EQ(seen.count(g), 1u) << g;
  // A grid with the ground needs few colors (greedy: at most degree + 1 = 5).
  EXPECT_LE(s.colorStart.size() - 1, 5u);
}

/// A scene with stacking, a pile of mixed shapes, a jointed chain and a motor.
const char* kMixedScene = R"({
  "name": "mixed",
  "bodies": [{"name": "ground", "type": "static", "shapes": [{"type": "plane"}]}],
  "generators": [
    {"type": "pyramid", "name": "pyr", "base": 8, "half_extent": 0.5, "origin": [-6, 0, 0]},
    {"type": "pile", "name": "pile", "count": 300, "seed": 3,
     "mix": {"box": 1, "sphere": 1, "capsule": 1}, "size": [0.2, 0.3], "spacing": 0.7,
     "orientation": "random", "center": [4, 0, 0], "half_extents": [2, 2],
     "walls": {"height": 2, "thickness": 0.3}},
    {"type": "chain", "name": "chain", "links": 10, "link_length": 0.5, "link_radius": 0.05,
     "link_mass": 1, "anchor": [0, 8, 8], "direction": [1, 0, 0],
     "end_ball": {"radius": 0.3, "mass": 20}}
  ]
})";

uint64_t runMixed(SolverSettings::Scheme scheme, int threads, int steps) {
  Scene scene = sceneFromJson(kMixedScene);
  scene.world.solver.scheme = scheme;
  // The default solves joints by LDL, which needs a Gauss-Seidel scheme.
  if (scheme == SolverSettings::Scheme::Jacobi)
    scene.world.solver.equalitySolve = SolverSettings::EqualitySolve::Iterative;
  scene.world.threads = threads;
  World world(scene.world);
  EXPECT_EQ(world.def().threads, threads);
  EXPECT_EQ(world.def().solver.scheme, scheme);  // not replaced by the defaults as invalid
  std::vector<BodyId> ids;
  EXPECT_TRUE(instantiateScene(scene, &world, &ids).ok());
  for (int i = 0; i < steps; ++i) world.step();
  EXPECT_GT(world.stats().contacts, 100);
  return world.stateHash();
}

TEST(Determinism, SameStateForAnyThreadCount) {
  using S = SolverSettings::Scheme;
  for (S scheme : {S::GaussSeidel, S::ColoredGaussSeidel, S::Jacobi}) {
    const uint64_t one = runMixed(scheme, 1, 90);
    EXPECT_EQ(runMixed(scheme, 2, 90), one) << int(scheme);
    EXPECT_EQ(runMixed(scheme, 3, 90), one) << int(scheme);
    // More threads than this machine's cores: the chunks are split otherwise, the bits not.
    EXPECT_EQ(runMixed(scheme, 8, 90), one) << int(scheme);
    EXPECT_EQ(runMixed(scheme, 16, 90), one) << int(scheme);
  }
  // The schemes really differ (the setting is not ignored).
  EXPECT_NE(runMixed(S::GaussSeidel, 2, 90), runMixed(S::ColoredGaussSeidel, 2, 90));
}

/// A pyramid large enough for three levels of nested parts (about 9,400 contacts: eight
/// leaves, solver_wide.h) beside a jointed chain (joints first, on one thread).
const char* kPartsScene = R"({
  "name": "parts",
  "bodies": [{"name": "ground", "type": "static", "shapes": [{"type": "plane"}]}],
  "generators": [
    {"type": "pyramid", "name": "pyr", "base": 80, "half_extent": 0.5},
    {"type": "chain", "name": "chain", "links": 10, "link_length": 0.5, "link_radius": 0.05,
     "link_mass": 1, "anchor": [0, 8, 8], "direction": [1, 0, 0],
     "end_ball": {"radius": 0.3, "mass": 20}}
  ]
})";

TEST(Determinism, NestedPartsSameStateForAnyThreadCount) {
  auto run = [](int threads, int* parts) {
    Scene scene = sceneFromJson(kPartsScene);
    scene.world.threads = threads;
    World world(scene.world);
    std::vector<BodyId> ids;
    EXPECT_TRUE(instantiateScene(scene, &world, &ids).ok());
    for (int i = 0; i < 30; ++i) world.step();
    *parts = world.stats().contactParts;
    EXPECT_GE(world.stats().vectorizedManifolds, 8192);
    return world.stateHash();
  };
  int parts = 0;
  const uint64_t one = run(1, &parts);
  EXPECT_EQ(parts, 8);  // the order's parts come from the contact count, not the threads
  for (int threads : {2, 3, 4, 8, 16}) {
    EXPECT_EQ(run(threads, &parts), one) << threads << " threads";
    EXPECT_EQ(parts, 8) << threads << " threads";
  }
}

/// A base-6 pyramid resting for `steps`; returns the last step's stats.
StepStats restingPyramid(float tolerance, int steps) {
  Scene scene;
  Status st = parseScene(R"({"name": "p", "bodies": [{"name": "ground", "type": "static",
      "shapes": [{"type": "plane"}]}], "generators": [{"type": "pyramid", "name": "p",
      "base": 6, "half_extent": 0.5}]})",
                         "inline", &scene);
  EXPECT_TRUE(st.ok()) << st.message;
  scene.world.solver.tolerance = tolerance;
  scene.world.solver.iterations = 8;
  World world(scene.world);
  std::vector<BodyId> ids;
  EXPECT_TRUE(instantiateScene(scene, &world, &ids).ok());
  for (int i = 0; i < steps; ++i) world.step();
  return world.stats();
}

TEST(Convergence, ToleranceStopsIterationsEarlyOnceAtRest) {
  const int substeps = SolverSettings{}.substeps;
  const StepStats full = restingPyramid(0, 120);
  EXPECT_EQ(full.iterationsUsed, substeps * 8);  // the whole budget without a tolerance
  const StepStats loose = restingPyramid(1e3f, 120);
  EXPECT_EQ(loose.iterationsUsed, substeps);  // one iteration per substep is always run
  // A tolerance of 1 mm/s: a warm-started pyramid at rest converges in fewer iterations, and
  // the residual after the solve stays of the order of the tolerance.
  const StepStats tol = restingPyramid(1e-3f, 120);
  EXPECT_LT(tol.iterationsUsed, substeps * 8);
  EXPECT_GE(tol.iterationsUsed, substeps);
  EXPECT_LT(tol.velocityResidual, 0.05);
}

TEST(Convergence, TheDirectJointSolveCountsTowardsConvergence) {
  // A jointed chain solved by the LDL hybrid: the joints' change is measured too, so a
  // substep runs the iteration that moves them and one more that finds nothing left to do,
  // instead of stopping after one because the iterated rows alone did not move.
  Scene scene;
  Status st = parseScene(R"({"name": "c", "generators": [{"type": "chain", "name": "chain",
      "links": 8, "link_length": 0.5, "link_radius": 0.05, "link_mass": 1,
      "anchor": [0, 0, 10], "direction": [1, 0, 0], "end_ball": {"radius": 0.3, "mass": 50}}]})",
                         "inline", &scene);
  ASSERT_TRUE(st.ok()) << st.message;
  SolverSettings& s = scene.world.solver;
  s.equalitySolve = SolverSettings::EqualitySolve::DirectLdl;
  s.substeps = 8;
  s.iterations = 6;
  s.tolerance = 1e-3f;
  World world(scene.world);
  std::vector<BodyId> ids;
  ASSERT_TRUE(instantiateScene(scene, &world, &ids).ok());
  for (int i = 0; i < 30; ++i) world.step();
  EXPECT_GE(world.stats().iterationsUsed, 2 * s.substeps);
  EXPECT_LT(world.stats().iterationsUsed, s.iterations * s.substeps);
}

TEST(Convergence, ToleranceIsValidated) {
  SolverSettings s;
  s.tolerance = -1;
  EXPECT_EQ(World::validate(s).code, StatusCode::InvalidArgument);
  s.tolerance = std::numeric_limits<float>::quiet_NaN();
  EXPECT_EQ(World::validate(s).code, StatusCode::InvalidArgument);
}

}  // namespace
