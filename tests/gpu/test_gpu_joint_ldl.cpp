// The joints' direct solve as the host plans it (gpu_solver/src/joint_ldl.h): islands, the
// rows' order and L's fixed pattern. No device needed: a reference of joint_ldl.comp's
// arithmetic on the plan's index lists is checked against a dense factorization, so a
// pattern that misses an entry of L (or of A) fails here. Then on the device
// (GpuJointLdl): islands of many sizes in one world, each solved by its own workgroup,
// against the CPU backend.
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <cmath>
#include <cstdio>
#include <random>
#include <set>
#include <vector>

#include "../common/bodies.h"
#include "gpu_test_util.h"
#include "joint_ldl.h"
#include "phys/world/world.h"

namespace phys::gpu {
namespace {

GpuJoint joint(uint32_t type, int a, int b, bool rigid = true) {
  GpuJoint j{};
  j.type = type;
  j.bodyA = a;
  j.bodyB = b;
  j.spring.y = rigid ? 1.0f : 0.0f;
  return j;
}

std::vector<GpuBodyParams> bodies(int n, std::set<int> notDynamic = {}) {
  std::vector<GpuBodyParams> p(static_cast<size_t>(n));
  for (int i = 0; i < n; ++i)
    p[size_t(i)].flags.x = notDynamic.count(i) ? 0u : PHYS_GPU_BODY_DYNAMIC;
  return p;
}

bool dynamic(const std::vector<GpuBodyParams>& p, int b) {
  return b >= 0 && (p[size_t(b)].flags.x & PHYS_GPU_BODY_DYNAMIC) != 0;
}

/// A symmetric positive definite A with the joints' coupling pattern: a random value where
/// two rows share a dynamic body, a dominant diagonal.
Eigen::MatrixXd couplingMatrix(const JointLdlPlan& plan, const std::vector<GpuJoint>& joints,
                               const std::vector<GpuBodyParams>& params, std::mt19937& rng) {
  const int n = int(plan.rows.size());
  Eigen::MatrixXd A = Eigen::MatrixXd::Zero(n, n);
  std::uniform_real_distribution<double> u(-1, 1);
  for (int i = 0; i < n; ++i)
    for (int k = 0; k < i; ++k) {
      const GpuJoint& a = joints[plan.rows[size_t(i)].joint];
      const GpuJoint& b = joints[plan.rows[size_t(k)].joint];
      bool share = false;
      for (int x : {a.bodyA, a.bodyB})
        for (int y : {b.bodyA, b.bodyB}) share |= x == y && dynamic(params, x);
      if (share) A(i, k) = A(k, i) = u(rng);
    }
  for (int i = 0; i < n; ++i) A(i, i) = 1 + A.row(i).cwiseAbs().sum();
  return A;
}

/// L(i, k) D(k) L(j, k) summed over the columns k < j that rows i and j share (their row
/// patterns, both ascending), as joint_ldl.comp's factor merges them.
double sharedColumns(const JointLdlPlan& plan, const std::vector<double>& values,
                     const std::vector<double>& diagonal, uint32_t i, uint32_t j) {
  double sum = 0;
  uint32_t a = plan.rows[i].patternBegin, b = plan.rows[j].patternBegin;
  const uint32_t aEnd = plan.rows[i].patternEnd, bEnd = plan.rows[j].patternEnd;
  while (a < aEnd && b < bEnd) {
    const uint32_t ka = plan.pattern[2 * a], kb = plan.pattern[2 * b];
    if (ka >= j) break;
    if (ka < kb) {
      ++a;
    } else if (kb < ka) {
      ++b;
    } else {
      sum += values[plan.pattern[2 * a + 1]] * diagonal[ka] * values[plan.pattern[2 * b + 1]];
      ++a;
      ++b;
    }
  }
  return sum;
}

/// joint_ldl.comp's factor and solve on the plan's lists, on the host: x = A^-1 b. Level by
/// level as the device's workgroup takes them (a level's columns and rows in any order: each
/// reads only lower levels', which the plan's structure is checked for).
Eigen::VectorXd solveWithPlan(const JointLdlPlan& plan, const Eigen::MatrixXd& A,
                              const Eigen::VectorXd& b) {
  const size_t n = plan.rows.size();
  std::vector<double> values(plan.entries(), 0.0), diagonal(n, 0.0), work(n, 0.0);
  for (const GpuLdlIsland& island : plan.islands) {
    for (uint32_t l = island.firstLevel; l < island.firstLevel + island.levels; ++l) {
      const uint32_t begin = plan.levels[2 * l], end = plan.levels[2 * l + 1];
      for (uint32_t j = begin; j < end; ++j) {
        double d = A(j, j);
        for (uint32_t e = plan.rows[j].patternBegin; e < plan.rows[j].patternEnd; ++e) {
          const double l = values[plan.pattern[2 * e + 1]];
          d -= l * l * diagonal[plan.pattern[2 * e]];
        }
        for (uint32_t p = plan.rows[j].columnBegin; p < plan.rows[j].columnEnd; ++p) {
          const uint32_t i = plan.columnRows[p];
          values[p] = (A(i, j) - sharedColumns(plan, values, diagonal, i, j)) / d;
        }
        diagonal[j] = d;
      }
    }
  }
  for (size_t r = 0; r < n; ++r) work[r] = b[Eigen::Index(r)];
  for (const GpuLdlIsland& island : plan.islands) {
    for (uint32_t l = island.firstLevel; l < island.firstLevel + island.levels; ++l)
      for (uint32_t r = plan.levels[2 * l]; r < plan.levels[2 * l + 1]; ++r)
        for (uint32_t e = plan.rows[r].patternBegin; e < plan.rows[r].patternEnd; ++e)
          work[r] -= values[plan.pattern[2 * e + 1]] * work[plan.pattern[2 * e]];
    for (uint32_t l = island.firstLevel + island.levels; l-- > island.firstLevel;)
      for (uint32_t r = plan.levels[2 * l]; r < plan.levels[2 * l + 1]; ++r) {
        work[r] /= diagonal[r];
        for (uint32_t p = plan.rows[r].columnBegin; p < plan.rows[r].columnEnd; ++p)
          work[r] -= values[p] * work[plan.columnRows[p]];
      }
  }
  return Eigen::Map<Eigen::VectorXd>(work.data(), Eigen::Index(n));
}

/// What joint_ldl.comp relies on: each island's levels cover its rows in order; a row's
/// entries of L lie in lower levels (so a level's columns and rows can go side by side);
/// the entries' columns and rows agree with the patterns; every dynamic body's rows are its
/// joints' rows, ascending.
void expectWellFormed(const JointLdlPlan& plan, const std::vector<GpuJoint>& joints,
                      const std::vector<GpuBodyParams>& params) {
  ASSERT_EQ(plan.entryColumns.size(), plan.entries());
  for (const GpuLdlIsland& island : plan.islands) {
    uint32_t next = island.firstRow;
    for (uint32_t l = island.firstLevel; l < island.firstLevel + island.levels; ++l) {
      const uint32_t begin = plan.levels[2 * l], end = plan.levels[2 * l + 1];
      ASSERT_EQ(begin, next);
      ASSERT_LT(begin, end);
      next = end;
      for (uint32_t r = begin; r < end; ++r)
        for (uint32_t e = plan.rows[r].patternBegin; e < plan.rows[r].patternEnd; ++e) {
          EXPECT_LT(plan.pattern[2 * e], begin) << "row " << r << " needs its own level";
          EXPECT_GE(plan.pattern[2 * e], island.firstRow);
          EXPECT_EQ(plan.entryColumns[plan.pattern[2 * e + 1]], plan.pattern[2 * e]);
          EXPECT_EQ(plan.columnRows[plan.pattern[2 * e + 1]], r);
        }
    }
    EXPECT_EQ(next, island.firstRow + island.rows);
    std::set<uint32_t> rowsOnBodies;
    for (uint32_t k = island.firstBody; k < island.firstBody + island.bodies; ++k) {
      const uvec4& body = plan.bodies[k];
      EXPECT_TRUE(dynamic(params, int(body.x)));
      for (uint32_t e = body.y; e < body.z; ++e) {
        const uint32_t r = plan.bodyRows[e];
        if (e > body.y) {
          EXPECT_LT(plan.bodyRows[e - 1], r);
        }
        EXPECT_GE(r, island.firstRow);
        EXPECT_LT(r, island.firstRow + island.rows);
        const GpuJoint& j = joints[plan.rows[r].joint];
        EXPECT_TRUE(j.bodyA == int(body.x) || j.bodyB == int(body.x));
        rowsOnBodies.insert(r);
      }
    }
    // Every row reaches a dynamic body (a joint in the solve has one).
    EXPECT_EQ(rowsOnBodies.size(), island.rows);
  }
}

TEST(GpuJointLdlPlan, EqualityRowsOfEveryJointType) {
  // As prepare_joints.comp builds them (limits, motors and springs come after, not counted).
  EXPECT_EQ(equalityRowCount(joint(PHYS_GPU_JOINT_BALL, 0, 1)), 3u);
  EXPECT_EQ(equalityRowCount(joint(PHYS_GPU_JOINT_HINGE, 0, 1)), 5u);
  EXPECT_EQ(equalityRowCount(joint(PHYS_GPU_JOINT_FIXED, 0, 1)), 6u);
  EXPECT_EQ(equalityRowCount(joint(PHYS_GPU_JOINT_PRISMATIC, 0, 1)), 5u);
  EXPECT_EQ(equalityRowCount(joint(PHYS_GPU_JOINT_DISTANCE, 0, 1, true)), 1u);
  EXPECT_EQ(equalityRowCount(joint(PHYS_GPU_JOINT_DISTANCE, 0, 1, false)), 0u);
}

TEST(GpuJointLdlPlan, AChainIsOneIslandWithoutFill) {
  // 40 ball joints in a chain from the world: 120 rows, each joint's 3 coupled with its
  // neighbours'. A good order eliminates from the ends with little fill: L stays within a
  // few entries per row (a dense L would hold 7140).
  std::vector<GpuJoint> joints;
  for (int i = 0; i < 40; ++i) joints.push_back(joint(PHYS_GPU_JOINT_BALL, i - 1, i));
  const JointLdlPlan plan = planJointLdl(joints, bodies(40));
  ASSERT_EQ(plan.islands.size(), 1u);
  EXPECT_EQ(plan.islands[0].firstRow, 0u);
  EXPECT_EQ(plan.islands[0].rows, 120u);
  EXPECT_LE(plan.entries(), 120u * 6);
  expectWellFormed(plan, joints, bodies(40));
  std::printf("chain of 40: %u levels, %zu entries\n", plan.islands[0].levels, plan.entries());
}

TEST(GpuJointLdlPlan, IslandsSplitAtStaticAndKinematicBodies) {
  // Two chains, one joined to the other through a kinematic body, one joint between two
  // static (non-dynamic) bodies and a spring-only distance joint: the kinematic body takes
  // no impulse, so it joins nothing; the last two have nothing to solve.
  std::vector<GpuJoint> joints = {
      joint(PHYS_GPU_JOINT_BALL, -1, 0),          joint(PHYS_GPU_JOINT_HINGE, 0, 1),
      joint(PHYS_GPU_JOINT_BALL, 1, 2),  // body 2 kinematic
      joint(PHYS_GPU_JOINT_FIXED, 2, 3),          joint(PHYS_GPU_JOINT_BALL, 3, 4),
      joint(PHYS_GPU_JOINT_BALL, -1, 2),  // kinematic to the world
      joint(PHYS_GPU_JOINT_DISTANCE, 3, 4, false)};
  const JointLdlPlan plan = planJointLdl(joints, bodies(5, {2}));
  ASSERT_EQ(plan.islands.size(), 2u);
  EXPECT_EQ(plan.islands[0].rows, 3u + 5u + 3u);  // joints 0-2 (joint 2 through body 1)
  EXPECT_EQ(plan.islands[1].rows, 6u + 3u);       // joints 3-4
  std::set<uint32_t> first, second;
  for (uint32_t r = 0; r < plan.islands[0].rows; ++r) first.insert(plan.rows[r].joint);
  for (uint32_t r = plan.islands[1].firstRow; r < plan.islands[1].firstRow + plan.islands[1].rows;
       ++r)
    second.insert(plan.rows[r].joint);
  EXPECT_EQ(first, (std::set<uint32_t>{0, 1, 2}));
  EXPECT_EQ(second, (std::set<uint32_t>{3, 4}));
  // Every equality row of a planned joint exactly once.
  std::set<std::pair<uint32_t, uint32_t>> seen;
  for (const GpuLdlRow& r : plan.rows) {
    EXPECT_LT(r.row, equalityRowCount(joints[r.joint]));
    EXPECT_TRUE(seen.insert({r.joint, r.row}).second);
  }
}

TEST(GpuJointLdlPlan, FactorOnThePlanSolvesLikeADenseFactorization) {
  // Random joint graphs (trees, loops, hubs, mixed types, some non-dynamic bodies): the
  // plan's pattern must hold every entry of L, or the solve goes wrong.
  std::mt19937 rng(7);
  for (int trial = 0; trial < 40; ++trial) {
    SCOPED_TRACE("trial " + std::to_string(trial));
    const int nBodies = 2 + int(rng() % 30);
    std::set<int> fixed;
    for (int b = 0; b < nBodies; ++b)
      if (rng() % 8 == 0) fixed.insert(b);
    std::vector<GpuBodyParams> params = bodies(nBodies, fixed);
    std::vector<GpuJoint> joints;
    const int nJoints = 1 + int(rng() % 50);
    for (int j = 0; j < nJoints; ++j) {
      const int a = int(rng() % uint32_t(nBodies + 1)) - 1;  // -1: the world
      int b = int(rng() % uint32_t(nBodies));
      if (b == a) b = (b + 1) % nBodies;
      joints.push_back(joint(uint32_t(rng() % 5), a, b, rng() % 4 != 0));
    }
    const JointLdlPlan plan = planJointLdl(joints, params);
    expectWellFormed(plan, joints, params);
    if (plan.rows.empty()) continue;
    const Eigen::MatrixXd A = couplingMatrix(plan, joints, params, rng);
    Eigen::VectorXd b(Eigen::Index(plan.rows.size()));
    for (Eigen::Index i = 0; i < b.size(); ++i) b[i] = std::uniform_real_distribution<>(-1, 1)(rng);
    const Eigen::VectorXd expected = A.ldlt().solve(b);
    const Eigen::VectorXd x = solveWithPlan(plan, A, b);
    EXPECT_LT((x - expected).norm(), 1e-9 * (1 + expected.norm()));
    EXPECT_LT((A * x - b).norm(), 1e-9 * (1 + b.norm()));
  }
}

TEST(GpuJointLdlPlan, ALongChainAndATreeHaveLevelsSideBySide) {
  // A 240-link chain (720 rows: past joint_ldl.comp's shared memory, on the global buffers)
  // and a binary tree of 31 bodies hanging from the world by its root: the tree's
  // subtrees are eliminated side by side, in far fewer levels than rows. (Rows on one body
  // all couple: a star of links on one hub is dense, one row a level.)
  std::vector<GpuJoint> joints;
  for (int i = 0; i < 240; ++i) joints.push_back(joint(PHYS_GPU_JOINT_BALL, i - 1, i));
  joints.push_back(joint(PHYS_GPU_JOINT_BALL, -1, 240));
  for (int i = 1; i < 31; ++i) joints.push_back(joint(PHYS_GPU_JOINT_BALL, 240 + (i - 1) / 2, 240 + i));
  const std::vector<GpuBodyParams> params = bodies(271);
  const JointLdlPlan plan = planJointLdl(joints, params);
  ASSERT_EQ(plan.islands.size(), 2u);
  expectWellFormed(plan, joints, params);
  EXPECT_EQ(plan.islands[0].rows, 720u);
  EXPECT_GT(plan.entries(), 2048u - 2 * 720u);  // the chain is beyond the shared memory
  EXPECT_EQ(plan.islands[1].rows, 93u);
  std::printf("chain of 240: %u levels; tree of 31: %u levels\n", plan.islands[0].levels,
              plan.islands[1].levels);
  EXPECT_LT(plan.islands[1].levels, 93u * 2 / 3);
  std::mt19937 rng(3);
  const Eigen::MatrixXd A = couplingMatrix(plan, joints, params, rng);
  Eigen::VectorXd b = Eigen::VectorXd::Random(Eigen::Index(plan.rows.size()));
  const Eigen::VectorXd x = solveWithPlan(plan, A, b);
  EXPECT_LT((A * x - b).norm(), 1e-9 * (1 + b.norm()));
}

}  // namespace

// On the device: a workgroup per island.
namespace {

using phys::Backend;
using phys::BodyId;
using phys::JointDef;
using phys::JointId;
using phys::JointState;
using phys::JointType;
using phys::Vec3;
using phys::World;
using phys::WorldDef;

/// Joint islands of very different sizes in one world, far apart (nothing collides): a
/// 240-link chain hanging straight down, nudged (720 rows, beyond the kernel's shared
/// memory); a 20-link chain ending in a 1000:1 ball, released horizontally; a 5-link hinge
/// chain; a chandelier of 8 links on a hub hanging from the world; a box welded to the world.
struct JointIslands {
  World world;
  std::vector<BodyId> bodies;
  std::vector<JointId> joints;
  BodyId longChainEnd;
  double longChainMass = 0;
  JointId longChainAnchor;

  explicit JointIslands(Backend backend) : world(def(backend)) {
    if (world.backendState().active != Backend::Gpu && backend == Backend::Gpu) return;
    auto link = [&](phys::BodyDef d) {
      const BodyId id = phys::test::addBody(world, d);
      bodies.push_back(id);
      return id;
    };
    auto join = [&](JointType type, BodyId a, BodyId b, Vec3 anchorA, Vec3 anchorB) {
      JointDef j;
      j.type = type;
      j.bodyA = a;
      j.bodyB = b;
      j.anchorA = anchorA;
      j.anchorB = anchorB;
      j.axisA = j.axisB = {0, 1, 0};
      JointId id;
      EXPECT_TRUE(world.createJoint(j, &id).ok());
      joints.push_back(id);
      return id;
    };
    // The long chain: links of 0.5 m from z = 130 down.
    BodyId prev;
    for (int i = 0; i < 240; ++i) {
      const BodyId id = link(phys::test::boxBody({0, 0, 129.75f - 0.5f * float(i)},
                                                 {0.05f, 0.05f, 0.2f}));
      const JointId jid = join(JointType::Ball, prev, id,
                               prev.isNull() ? Vec3{0, 0, 130} : Vec3{0, 0, -0.25f},
                               Vec3{0, 0, 0.25f});
      if (prev.isNull()) longChainAnchor = jid;
      longChainMass += phys::test::stateOf(world, id).mass;
      prev = id;
    }
    longChainEnd = prev;
    EXPECT_TRUE(world.setVelocity(prev, {0.5f, 0, 0}, {}).ok());
    // The heavy-ended chain, horizontal from (20, 0, 20).
    prev = {};
    for (int i = 0; i < 20; ++i) {
      const BodyId id = link(phys::test::boxBody({20.5f + float(i), 0, 20}, {0.4f, 0.1f, 0.1f}));
      join(JointType::Ball, prev, id, prev.isNull() ? Vec3{20, 0, 20} : Vec3{0.5f, 0, 0},
           Vec3{-0.5f, 0, 0});
      prev = id;
    }
    EXPECT_TRUE(world.setMass(prev, 1000 * phys::test::stateOf(world, prev).mass).ok());
    // The hinge chain.
    prev = {};
    for (int i = 0; i < 5; ++i) {
      const BodyId id = link(phys::test::boxBody({40.5f + float(i), 0, 20}, {0.4f, 0.1f, 0.1f}));
      join(JointType::Hinge, prev, id, prev.isNull() ? Vec3{40, 0, 20} : Vec3{0.5f, 0, 0},
           Vec3{-0.5f, 0, 0});
      prev = id;
    }
    // The chandelier: a hub hanging from the world, 8 links hanging from a ring around it
    // (apart: they never touch), the hub pushed. Every row acts on the hub: a dense island.
    const BodyId hub = link(phys::test::boxBody({60, 0, 19}, {0.2f, 0.2f, 0.2f}));
    join(JointType::Ball, {}, hub, {60, 0, 20}, {0, 0, 1});
    for (int i = 0; i < 8; ++i) {
      const float a = 0.785398f * float(i);
      const Vec3 ring{0.6f * std::cos(a), 0.6f * std::sin(a), 0};
      const BodyId id = link(phys::test::boxBody(Vec3{60, 0, 18.6f} + ring, {0.1f, 0.1f, 0.1f}));
      join(JointType::Ball, hub, id, ring, {0, 0, 0.4f});
    }
    EXPECT_TRUE(world.setVelocity(hub, {0, 0.5f, 0}, {0, 0, 0.5f}).ok());
    // The welded box.
    const BodyId box = link(phys::test::boxBody({80, 0, 20}, {0.3f, 0.3f, 0.3f}));
    join(JointType::Fixed, {}, box, {80, 0, 20.5f}, {0, 0, 0.5f});
  }
  static WorldDef def(Backend backend) {
    WorldDef d;
    d.backend = backend;
    d.gpuAllowCpuDevice = true;
    d.threads = 1;
    return d;  // the default solver: soft_step, the joints' LDL hybrid on both backends
  }
  float worstJointError() const { return test::worstJointError(world, joints); }
};

TEST(GpuJointLdl, IslandsOfEverySizeMatchTheCpuAndRunsAreBitIdentical) {
  JointIslands gpu(Backend::Gpu), cpu(Backend::Cpu);
  REQUIRE_DEVICE(gpu.world);
  ASSERT_EQ(gpu.world.def().solver.equalitySolve, phys::SolverSettings::EqualitySolve::DirectLdl);
  constexpr int kSteps = 30;
  float worstGpu = 0, worstCpu = 0;
  for (int i = 0; i < kSteps; ++i) {
    gpu.world.step();
    cpu.world.step();
    worstGpu = std::max(worstGpu, gpu.worstJointError());
    worstCpu = std::max(worstCpu, cpu.worstJointError());
  }
  EXPECT_EQ(gpu.world.backendState().gpuSteps, uint64_t(kSteps));
  EXPECT_EQ(gpu.world.backendState().cpuSteps, 0u) << gpu.world.backendState().lastFallback;
  EXPECT_EQ(gpu.world.stats().joints, int(gpu.joints.size()));
  // Every joint held as on the CPU, every body where the CPU has it.
  EXPECT_LT(worstGpu, 0.01f);
  EXPECT_LT(worstGpu, worstCpu + 1e-3f) << "cpu " << worstCpu;
  float farthest = 0;
  for (size_t i = 0; i < gpu.bodies.size(); ++i) {
    const float d = length(phys::test::stateOf(gpu.world, gpu.bodies[i]).position -
                           phys::test::stateOf(cpu.world, cpu.bodies[i]).position);
    EXPECT_LT(d, 5e-4f) << "body " << i;
    farthest = std::max(farthest, d);
  }
  std::printf("largest difference to the CPU %.3g m; joint error %.3g m (cpu %.3g m)\n", farthest,
              worstGpu, worstCpu);
  // The long chain hangs: its anchor carries its weight.
  JointState anchor;
  ASSERT_TRUE(gpu.world.getJoint(gpu.longChainAnchor, nullptr, &anchor).ok());
  EXPECT_NEAR(anchor.reactionForce.z, gpu.longChainMass * 9.81, 0.02 * gpu.longChainMass * 9.81);
  EXPECT_GT(phys::test::stateOf(gpu.world, gpu.longChainEnd).position.x, 0.01f);
  // The same bits again from the same start (fixed sums, no atomics).
  JointIslands again(Backend::Gpu);
  for (int i = 0; i < kSteps; ++i) again.world.step();
  EXPECT_EQ(again.world.stateHash(), gpu.world.stateHash());
}

}  // namespace
}  // namespace phys::gpu
