// The joints' direct solve as the host plans it (gpu_solver/src/joint_ldl.h): islands, the
// rows' order and L's fixed pattern. No device needed: a reference of joint_ldl.comp's
// arithmetic on the plan's index lists is checked against a dense factorization, so a
// pattern that misses an entry of L (or of A) fails here.
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <cmath>
#include <random>
#include <set>
#include <vector>

#include "joint_ldl.h"

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

/// joint_ldl.comp's factor and solve on the plan's lists, on the host: x = A^-1 b.
Eigen::VectorXd solveWithPlan(const JointLdlPlan& plan, const Eigen::MatrixXd& A,
                              const Eigen::VectorXd& b) {
  const size_t n = plan.rows.size();
  std::vector<double> values(plan.entries(), 0.0), diagonal(n, 0.0), work(n, 0.0);
  for (const uvec4& island : plan.islands) {
    for (uint32_t r = island.x; r < island.x + island.y; ++r) {
      const GpuLdlRow& R = plan.rows[r];
      for (uint32_t e = R.patternBegin; e < R.patternEnd; ++e) {
        const uint32_t i = plan.pattern[2 * e];
        work[i] = A(i, r);
      }
      double d = A(r, r);
      for (uint32_t e = R.patternBegin; e < R.patternEnd; ++e) {
        const uint32_t i = plan.pattern[2 * e], at = plan.pattern[2 * e + 1];
        const double y = work[i];
        work[i] = 0;
        for (uint32_t p = plan.rows[i].columnBegin; p < at; ++p)
          work[plan.columnRows[p]] -= values[p] * y;
        const double l = y / diagonal[i];
        d -= l * y;
        values[at] = l;
      }
      diagonal[r] = d;
    }
  }
  for (size_t r = 0; r < n; ++r) work[r] = b[Eigen::Index(r)];
  for (size_t r = 0; r < n; ++r)
    for (uint32_t p = plan.rows[r].columnBegin; p < plan.rows[r].columnEnd; ++p)
      work[plan.columnRows[p]] -= values[p] * work[r];
  for (size_t r = 0; r < n; ++r) work[r] /= diagonal[r];
  for (size_t r = n; r-- > 0;)
    for (uint32_t p = plan.rows[r].columnBegin; p < plan.rows[r].columnEnd; ++p)
      work[r] -= values[p] * work[plan.columnRows[p]];
  return Eigen::Map<Eigen::VectorXd>(work.data(), Eigen::Index(n));
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
  EXPECT_EQ(plan.islands[0].x, 0u);
  EXPECT_EQ(plan.islands[0].y, 120u);
  EXPECT_LE(plan.entries(), 120u * 6);
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
  EXPECT_EQ(plan.islands[0].y, 3u + 5u + 3u);  // joints 0-2 (joint 2 through body 1)
  EXPECT_EQ(plan.islands[1].y, 6u + 3u);       // joints 3-4
  std::set<uint32_t> first, second;
  for (uint32_t r = 0; r < plan.islands[0].y; ++r) first.insert(plan.rows[r].joint);
  for (uint32_t r = plan.islands[1].x; r < plan.islands[1].x + plan.islands[1].y; ++r)
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

}  // namespace
}  // namespace phys::gpu
