// The contact block solve: a manifold's normal rows solved together as one small LCP reach,
// in one iteration, the fixed point that row-by-row soft Gauss-Seidel only approaches.
#include <gtest/gtest.h>

#include <cmath>

#include "dynamics/solver.h"

using namespace phys;

namespace {

constexpr float kH = 1.0f / 240;  // a substep of the default solver

/// A unit cube (1 kg) on the static world, touching it with the 4 corners of its bottom face,
/// penetrating by `depth` on one side more than the other, moving down and rolling.
Solver cubeOnGround(bool block, int points) {
  Solver s;
  s.bodies.resize(2);
  SolverBody& b = s.bodies[1];
  b.dynamic = true;
  b.invMass = 1;
  b.invI = Mat3::diagonal({6, 6, 6});  // 1 / (m (1 + 1) / 12)
  b.v = {0.1f, 0, -1};
  b.w = {0.5f, -0.3f, 0.2f};
  const Vec3 n{0, 0, 1};
  const Vec3 corners[4] = {
      {-0.5f, -0.5f, -0.5f}, {0.5f, -0.5f, -0.5f}, {0.5f, 0.5f, -0.5f}, {-0.5f, 0.5f, -0.5f}};
  for (int k = 0; k < points; ++k) {
    Row r;
    r.kind = RowKind::ContactNormal;
    r.a = 0;
    r.b = 1;
    r.linA = -n;
    r.linB = n;
    r.angB = cross(corners[k], n);
    r.C0 = -0.01f - 0.005f * float(k);
    r.groupStart = k == 0;
    s.rows.push_back(r);
  }
  s.blockContacts = block;
  s.indexUnits();
  s.finishRows(0, s.rows.size());
  return s;
}

/// The soft rows' fixed point: v + bias + c K_ii lambda = 0 where lambda > 0, and
/// v + bias >= 0 where lambda = 0. Returns the largest violation (m/s).
float fixedPointError(const Solver& s, const SolverSettings& st) {
  Softness soft = makeSoftness(std::min(st.contactHertz, 0.25f / kH), st.contactDampingRatio, kH);
  const float c = soft.impulseScale / soft.massScale;
  float worst = 0;
  for (const Row& r : s.rows) {
    float v = s.rowVelocity(r) + std::max(soft.biasRate * s.rowError(r), -st.maxPushout);
    float e = r.lambda > 0 ? std::abs(v + c * r.lambda / r.effMass) : std::max(0.0f, -v);
    worst = std::max(worst, e);
  }
  return worst;
}

TEST(ContactBlock, OneIterationReachesTheRowByRowFixedPoint) {
  SolverSettings st;  // soft contacts
  // The corners are 1-2.5 cm deep: with the split push-out the rows' bias would stop at 1 cm
  // (and the block solve stand aside); this is the bias's own fixed point.
  st.splitPushout = false;
  for (int points : {2, 3, 4}) {
    Solver block = cubeOnGround(true, points);
    ASSERT_EQ(block.rows[0].contactPoints, points);
    block.solveIteration(st, kH, true);
    EXPECT_LT(fixedPointError(block, st), 1e-4f) << points << " points";

    Solver rows = cubeOnGround(false, points);
    ASSERT_EQ(rows.rows[0].contactPoints, 0);
    rows.solveIteration(st, kH, true);
    const float oneSweep = fixedPointError(rows, st);
    EXPECT_GT(oneSweep, 1e-2f) << "row by row needs more than one sweep";
    for (int it = 0; it < 500; ++it) rows.solveIteration(st, kH, true);
    EXPECT_LT(fixedPointError(rows, st), 1e-4f);
    // Same impulses and velocities: the block solve is the converged row-by-row solve.
    for (int k = 0; k < points; ++k)
      EXPECT_NEAR(block.rows[size_t(k)].lambda, rows.rows[size_t(k)].lambda,
                  1e-3f * std::abs(rows.rows[size_t(k)].lambda) + 1e-5f)
          << points << " points, row " << k;
    EXPECT_NEAR(length(block.bodies[1].v - rows.bodies[1].v), 0, 1e-4f);
    EXPECT_NEAR(length(block.bodies[1].w - rows.bodies[1].w), 0, 1e-3f);
  }
}

TEST(ContactBlock, LeavesSpeculativeAndRelaxPassesRowByRow) {
  SolverSettings st;
  Solver s = cubeOnGround(true, 4);
  s.rows[2].C0 = 0.02f;  // this corner is still apart: the manifold goes row by row
  s.solveIteration(st, kH, true);
  Solver rows = cubeOnGround(false, 4);
  rows.rows[2].C0 = 0.02f;
  rows.solveIteration(st, kH, true);
  for (int k = 0; k < 4; ++k) EXPECT_EQ(s.rows[size_t(k)].lambda, rows.rows[size_t(k)].lambda);
  // The relax pass (no bias, rigid rows) is row by row too.
  Solver relax = cubeOnGround(true, 4), relaxRows = cubeOnGround(false, 4);
  relax.solveIteration(st, kH, false);
  relaxRows.solveIteration(st, kH, false);
  for (int k = 0; k < 4; ++k)
    EXPECT_EQ(relax.rows[size_t(k)].lambda, relaxRows.rows[size_t(k)].lambda);
}

}  // namespace
