#include "dynamics/solver_ldl.h"

#include <algorithm>

namespace phys {

double rowCoupling(const Row& ri, int sideI, const Row& rj, int sideJ) {
  const Vec3& lin = sideI == 0 ? ri.linA : ri.linB;
  const Vec3& ang = sideI == 0 ? ri.angA : ri.angB;
  const Vec3& mlin = sideJ == 0 ? rj.mLinA : rj.mLinB;
  const Vec3& mang = sideJ == 0 ? rj.mAngA : rj.mAngB;
  return double(dot(lin, mlin)) + double(dot(ang, mang));
}

void EqualityLdl::analyze(const Solver& s) {
  rows_.clear();
  for (size_t i = 0; i < s.rows.size(); ++i)
    if (s.rows[i].kind == RowKind::Equality) rows_.push_back(uint32_t(i));
  ok_ = false;
  if (rows_.empty()) return;
  assemble(s);
  ldlt_.analyzePattern(A_);
}

void EqualityLdl::assemble(const Solver& s) {
  // Rows meet through the bodies they share: gather (row, side) per dynamic body, then every
  // pair of entries of one body adds its coupling. The world (body 0) couples nothing.
  const size_t n = rows_.size();
  std::vector<std::vector<std::pair<uint32_t, int>>> byBody(s.bodies.size());
  for (uint32_t k = 0; k < n; ++k) {
    const Row& r = s.rows[rows_[k]];
    if (r.a != 0 && s.bodies[size_t(r.a)].invMass > 0) byBody[size_t(r.a)].push_back({k, 0});
    if (r.b != 0 && s.bodies[size_t(r.b)].invMass > 0) byBody[size_t(r.b)].push_back({k, 1});
  }
  triplets_.clear();
  for (const auto& list : byBody) {
    for (const auto& [i, si] : list)
      for (const auto& [j, sj] : list)
        triplets_.emplace_back(int(i), int(j),
                               rowCoupling(s.rows[rows_[i]], si, s.rows[rows_[j]], sj));
  }
  // A little regularization keeps redundant joints (closed loops, two welds in parallel)
  // factorable; relative to the diagonal so it means the same at any mass.
  std::vector<double> diag(n, 0.0);
  for (const auto& t : triplets_)
    if (t.row() == t.col()) diag[size_t(t.row())] += t.value();
  for (size_t k = 0; k < n; ++k) triplets_.emplace_back(int(k), int(k), 1e-6 * diag[k] + 1e-12);
  A_.resize(int(n), int(n));
  A_.setFromTriplets(triplets_.begin(), triplets_.end());
}

bool EqualityLdl::factor(const Solver& s) {
  if (rows_.empty()) return false;
  assemble(s);
  ldlt_.factorize(A_);
  ok_ = ldlt_.info() == Eigen::Success;
  return ok_;
}

float EqualityLdl::solve(Solver& s, float biasRate, bool useBias) {
  return project(s, biasRate, useBias, /*push=*/false);
}

void EqualityLdl::solvePush(Solver& s) {
  project(s, 0, false, /*push=*/true);
}

float EqualityLdl::project(Solver& s, float biasRate, bool useBias, bool push) {
  if (!ok_) return 0;
  // The velocities solved on: the bodies' own, or their split push-out pseudo velocities.
  auto velocity = [&](int32_t b) -> Velocity& {
    return push ? s.push[size_t(b)] : static_cast<Velocity&>(s.bodies[size_t(b)]);
  };
  const int n = int(rows_.size());
  rhs_.resize(n);
  for (int k = 0; k < n; ++k) {
    const Row& r = s.rows[rows_[size_t(k)]];
    rhs_[k] = -(double(Solver::rowVelocity(r, velocity(r.a), velocity(r.b))) +
                (useBias ? double(biasRate) * s.rowError(r) : 0.0));
  }
  x_ = ldlt_.solve(rhs_);
  float change = 0;
  for (int k = 0; k < n; ++k) {
    Row& r = s.rows[rows_[size_t(k)]];
    float d = float(x_[k]);
    if (!std::isfinite(d) || d == 0) continue;
    if (!push) r.lambda += d;  // the push-out keeps no joint impulse
    Solver::applyImpulse(r, d, velocity(r.a), velocity(r.b));
    if (r.effMass > 0) change = std::max(change, std::abs(d) / r.effMass);
  }
  return change;
}

}  // namespace phys
