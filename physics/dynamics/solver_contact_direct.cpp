#include "dynamics/solver_contact_direct.h"

#include <algorithm>
#include <cmath>
#include <utility>

#include "dynamics/solver_ldl.h"

namespace phys {

void DirectContacts::setup(Solver& s, std::vector<std::vector<uint32_t>> islands) {
  islands_.clear();
  islands_.reserve(islands.size());
  std::vector<std::pair<int32_t, std::pair<int, int>>> refs;  // (body, (row, side))
  for (std::vector<uint32_t>& rows : islands) {
    // Islands at rest only: one with a row approaching faster than kImpactSpeed at the step's
    // start, or deeper than the split push-out's depth (bodies spawned into each other), is
    // iterated that step. Solved exactly, a heavy body landing on a light one stops dead in
    // one substep and can throw a light body under it; solving only the resting rows directly
    // leaves the impact's iterated rows and the exact ones fighting over the light body
    // (measured: 23 and 7 of 1000 stress runs failed against 3 iterated; ARCHITECTURE).
    bool impact = false;
    for (uint32_t i : rows)
      impact |= s.rowVelocity(s.rows[i]) < -kImpactSpeed ||
                s.rows[i].C0 < -SolverSettings::kSplitDepth;
    if (impact) continue;
    // Made in place (the reserve above: no reallocation moves one either): a moved Island
    // copies its factors' Eigen::LLT, whose status Eigen leaves unset until a compute
    // (UBSan: "load of value 24640, which is not a valid value for type ComputationInfo").
    Island& is = islands_.emplace_back();
    is.rows = std::move(rows);
    const int n = int(is.rows.size());
    // Rows meet through the dynamic bodies they share; the world and kinematic bodies
    // (zero inverse mass) couple nothing.
    refs.clear();
    for (int k = 0; k < n; ++k) {
      Row& r = s.rows[is.rows[size_t(k)]];
      r.direct = true;
      if (s.bodies[size_t(r.a)].invMass > 0) refs.push_back({r.a, {k, 0}});
      if (s.bodies[size_t(r.b)].invMass > 0) refs.push_back({r.b, {k, 1}});
    }
    std::sort(refs.begin(), refs.end());
    is.A.setZero(n, n);
    for (size_t b = 0; b < refs.size();) {
      size_t e = b;
      while (e < refs.size() && refs[e].first == refs[b].first) ++e;
      for (size_t i = b; i < e; ++i)
        for (size_t j = b; j < e; ++j) {
          const auto [ki, si] = refs[i].second;
          const auto [kj, sj] = refs[j].second;
          is.A(ki, kj) += rowCoupling(s.rows[is.rows[size_t(ki)]], si,
                                      s.rows[is.rows[size_t(kj)]], sj);
        }
      b = e;
    }
    // The warm start's active set: the rows that carried load last step.
    is.active.resize(size_t(n));
    for (int k = 0; k < n; ++k) is.active[size_t(k)] = s.rows[is.rows[size_t(k)]].lambda > 0;
  }
}

float DirectContacts::solve(Solver& s, const ContactRule& rule) {
  float change = 0;
  for (Island& is : islands_) change = std::max(change, solveIsland(s, is, rule));
  return change;
}

const Eigen::LLT<Eigen::MatrixXd>& DirectContacts::factorFor(Island& is) {
  const int m = int(set_.size());
  Eigen::VectorXd diag(m);
  for (int a = 0; a < m; ++a) diag[a] = gamma_[set_[size_t(a)]];
  for (Island::Factor& f : is.factors)
    if (f.valid && f.set == set_ && f.diag == diag) return f.ldlt;
  Island::Factor& f = is.factors[is.nextFactor];
  is.nextFactor ^= 1;
  Eigen::MatrixXd M(m, m);
  for (int a = 0; a < m; ++a)
    for (int b = 0; b < m; ++b) M(a, b) = is.A(set_[size_t(a)], set_[size_t(b)]);
  M.diagonal() += diag;
  f.ldlt.compute(M);
  f.set = set_;
  f.diag = std::move(diag);
  f.valid = true;
  return f.ldlt;
}

float DirectContacts::solveIsland(Solver& s, Island& is, const ContactRule& rule) {
  const int n = int(is.rows.size());
  // Each row's residual now, J v + bias, which the rows in the active set bring to zero, and
  // the regularization eps D (the header says why rigid rows, and why 1e-3).
  gamma_.resize(n);
  residual_.resize(n);
  Eigen::VectorXd lambda0(n);
  for (int k = 0; k < n; ++k) {
    const Row& r = s.rows[is.rows[size_t(k)]];
    const ContactTerms t = rule.terms(r, s.rowError(r));
    lambda0[k] = r.lambda;
    residual_[k] = double(s.rowVelocity(r)) + double(t.bias);
    gamma_[k] = 1e-3 * is.A(k, k) + 1e-12;
  }
  // Rows at the edge (an unloaded side contact: its impulse a rounding error either side of
  // zero) would flicker in and out of the set, each time costing a factorization: a row
  // leaves only below -1e-6 of the island's largest impulse, and joins only when it would
  // approach faster than 1e-5 m/s.
  const double leaveBelow = -1e-6 * std::max(lambda0.cwiseAbs().maxCoeff(), 1e-6);
  x_.setZero(n);
  for (int pass = 0; pass < kMaxPasses; ++pass) {
    // Rows outside the set end at zero impulse; the set's rows solve for the rest.
    set_.clear();
    for (int k = 0; k < n; ++k) {
      if (is.active[size_t(k)])
        set_.push_back(k);
      else
        x_[k] = -lambda0[k];
    }
    const int m = int(set_.size());
    if (m > 0) {
      rhs_.resize(m);
      for (int a = 0; a < m; ++a) {
        const int k = set_[size_t(a)];
        double r = residual_[k];
        for (int j = 0; j < n; ++j)
          if (!is.active[size_t(j)]) r += is.A(k, j) * x_[j];
        rhs_[a] = -r;
      }
      xs_ = factorFor(is).solve(rhs_);
      for (int a = 0; a < m; ++a) x_[set_[size_t(a)]] = xs_[a];
    }
    // The violations: a row in the set pulling (impulse below zero), a row outside still
    // approaching (velocity error below zero). The first passes change the set at every
    // violation, the pulling rows first; that can cycle, so later passes change only the
    // first violating row (Murty's least-index rule, which ends for a positive definite M).
    const bool single = pass >= kBlockPasses;
    auto pulling = [&](int k) { return lambda0[k] + x_[k] < leaveBelow; };
    auto approaching = [&](int k) {
      return residual_[k] + is.A.row(k).dot(x_) + gamma_[k] * x_[k] < -1e-5;
    };
    bool changed = false;
    if (!single) {
      for (int k : set_)
        if (pulling(k)) is.active[size_t(k)] = 0, changed = true;
      if (!changed)
        for (int k = 0; k < n; ++k)
          if (!is.active[size_t(k)] && approaching(k)) is.active[size_t(k)] = 1, changed = true;
    } else {
      for (int k = 0; k < n && !changed; ++k)
        if (is.active[size_t(k)] ? pulling(k) : approaching(k)) {
          is.active[size_t(k)] ^= 1;
          changed = true;
        }
    }
    if (!changed) break;
  }
  float change = 0;
  for (int k = 0; k < n; ++k) {
    Row& r = s.rows[is.rows[size_t(k)]];
    const float next = std::max(float(lambda0[k] + x_[k]), 0.0f);
    const float d = next - r.lambda;
    if (!std::isfinite(d) || d == 0) continue;
    r.lambda = next;
    r.maxLambda = std::max(r.maxLambda, next);
    s.applyImpulse(r, d);
    if (r.effMass > 0) change = std::max(change, std::abs(d) / r.effMass);
  }
  return change;
}

}  // namespace phys
