#include "dynamics/solver_contact_direct.h"

#include <algorithm>
#include <cmath>
#include <utility>

#include "dynamics/solver_ldl.h"

namespace phys {

void DirectContacts::setup(Solver& s, std::vector<std::vector<uint32_t>> islands) {
  islands_.clear();
  jointed_ = false;
  if (islands.empty()) return;
  islands_.reserve(islands.size());
  // The equality rows on each dynamic body (the LDL hybrid's rows), for addJoints.
  eqStart_.clear();
  eqRefs_.clear();
  bool anyEquality = false;
  for (const Row& r : s.rows) anyEquality |= r.kind == RowKind::Equality;
  if (anyEquality) {
    const size_t nb = s.bodies.size();
    eqStart_.assign(nb + 1, 0);
    auto dyn = [&](int32_t b) { return b != 0 && s.bodies[size_t(b)].invMass > 0; };
    for (const Row& r : s.rows) {
      if (r.kind != RowKind::Equality) continue;
      if (dyn(r.a)) ++eqStart_[size_t(r.a) + 1];
      if (dyn(r.b)) ++eqStart_[size_t(r.b) + 1];
    }
    for (size_t b = 0; b < nb; ++b) eqStart_[b + 1] += eqStart_[b];
    eqRefs_.resize(eqStart_[nb]);
    std::vector<uint32_t> fill(eqStart_.begin(), eqStart_.end() - 1);
    for (uint32_t i = 0; i < s.rows.size(); ++i) {
      const Row& r = s.rows[i];
      if (r.kind != RowKind::Equality) continue;
      if (dyn(r.a)) eqRefs_[fill[size_t(r.a)]++] = i << 1;
      if (dyn(r.b)) eqRefs_[fill[size_t(r.b)]++] = i << 1 | 1;
    }
    bodyMark_.assign(nb, 0);
    bodyGroup_.assign(nb, -1);
    rowLocal_.assign(s.rows.size(), -1);
    mark_ = 0;
  }
  std::vector<std::pair<int32_t, std::pair<int, int>>> refs;  // (body, (row, side))
  for (std::vector<uint32_t>& rows : islands) {
    Island is;
    // Islands at rest only: one with a row approaching faster than kImpactSpeed at the step's
    // start, or deeper than kRestDepth (bodies spawned into each other), is iterated that
    // step. Solved exactly, a heavy body landing on a light one stops dead in one substep and
    // can throw a light body under it; solving only the resting rows directly leaves the
    // impact's iterated rows and the exact ones fighting over the light body (measured: 23
    // and 7 of 1000 stress runs failed against 3 iterated; ARCHITECTURE).
    bool impact = false;
    for (uint32_t i : rows)
      impact |= s.rowVelocity(s.rows[i]) < -kImpactSpeed || s.rows[i].C0 < -kRestDepth;
    if (impact || rows.empty()) continue;
    is.rows = std::move(rows);
    const int n = int(is.rows.size());
    // Rows meet through the dynamic bodies they share; the world and kinematic bodies
    // (zero inverse mass) couple nothing.
    refs.clear();
    for (int k = 0; k < n; ++k) {
      const Row& r = s.rows[is.rows[size_t(k)]];
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
    if (anyEquality && !addJoints(s, is)) continue;
    jointed_ |= is.jointed;
    for (uint32_t i : is.rows) s.rows[i].direct = true;
    // The warm start's active set: the rows that carried load last step.
    is.active.resize(size_t(n));
    for (int k = 0; k < n; ++k) is.active[size_t(k)] = s.rows[is.rows[size_t(k)]].lambda > 0;
    islands_.push_back(std::move(is));
  }
}

bool DirectContacts::addJoints(const Solver& s, Island& is) {
  // The jointed groups: the bodies joined by equality rows to a body of the island's rows,
  // each group's equality rows K = J_eq M^-1 J_eq^T (the LDL hybrid's, with its
  // regularization), and per group U = J_eq M^-1 J^T over the island's rows that touch it.
  // The rows' matrix with the joints holding is A - U^T K^-1 U (K = L L^T: V = L^-1 U,
  // A -= V^T V), and their residual J v - U^T K^-1 r_eq (W = K^-1 U kept for it). Groups
  // share no body, so K is block diagonal over them.
  ++mark_;
  const int n = int(is.rows.size());
  auto hasEquality = [&](int32_t b) {
    return b != 0 && eqStart_[size_t(b) + 1] > eqStart_[size_t(b)];
  };
  std::vector<int32_t> groupBodies, groupRows, queue;
  int32_t groups = 0;
  int totalRows = 0;
  Eigen::MatrixXd K, C;
  is.joints.clear();
  for (int k = 0; k < n; ++k) {
    const Row& cr = s.rows[is.rows[size_t(k)]];
    for (int32_t start : {cr.a, cr.b}) {
      if (!hasEquality(start) || !(s.bodies[size_t(start)].invMass > 0) ||
          bodyMark_[size_t(start)] == mark_)
        continue;
      // A new group: its bodies (breadth first over the equality rows) and rows.
      const int32_t g = groups++;
      groupBodies.clear();
      groupRows.clear();
      queue.assign(1, start);
      bodyMark_[size_t(start)] = mark_;
      bodyGroup_[size_t(start)] = g;
      for (size_t q = 0; q < queue.size(); ++q) {
        const int32_t b = queue[q];
        groupBodies.push_back(b);
        for (uint32_t e = eqStart_[size_t(b)]; e < eqStart_[size_t(b) + 1]; ++e) {
          const uint32_t ri = eqRefs_[e] >> 1;
          const Row& r = s.rows[ri];
          const int32_t other = (eqRefs_[e] & 1) ? r.a : r.b;
          // Each row once: from its first dynamic body.
          const bool first = (eqRefs_[e] & 1) == 0 || !(s.bodies[size_t(r.a)].invMass > 0);
          if (first) {
            rowLocal_[ri] = int32_t(groupRows.size());
            groupRows.push_back(int32_t(ri));
          }
          if (other != 0 && s.bodies[size_t(other)].invMass > 0 &&
              bodyMark_[size_t(other)] != mark_) {
            bodyMark_[size_t(other)] = mark_;
            bodyGroup_[size_t(other)] = g;
            queue.push_back(other);
          }
        }
      }
      const int m = int(groupRows.size());
      totalRows += m;
      auto release = [&] {
        for (int32_t ri : groupRows) rowLocal_[size_t(ri)] = -1;
      };
      if (m > kMaxGroupJointRows || totalRows > kMaxIslandJointRows) {
        release();
        return false;
      }
      K.setZero(m, m);
      for (int32_t b : groupBodies)
        for (uint32_t e = eqStart_[size_t(b)]; e < eqStart_[size_t(b) + 1]; ++e)
          for (uint32_t f = eqStart_[size_t(b)]; f < eqStart_[size_t(b) + 1]; ++f)
            K(rowLocal_[eqRefs_[e] >> 1], rowLocal_[eqRefs_[f] >> 1]) +=
                rowCoupling(s.rows[eqRefs_[e] >> 1], int(eqRefs_[e] & 1), s.rows[eqRefs_[f] >> 1],
                            int(eqRefs_[f] & 1));
      for (int i = 0; i < m; ++i) K(i, i) += 1e-6 * K(i, i) + 1e-12;  // as EqualityLdl's
      // The island's rows on this group's bodies: one column of U each.
      Island::Joints& J = is.joints.emplace_back();
      std::vector<int>& cols = J.cols;
      Eigen::MatrixXd& U = J.W;
      for (int c = 0; c < n; ++c) {
        const Row& r = s.rows[is.rows[size_t(c)]];
        auto in = [&](int32_t b) {
          return b != 0 && bodyMark_[size_t(b)] == mark_ && bodyGroup_[size_t(b)] == g;
        };
        if (in(r.a) || in(r.b)) cols.push_back(c);
      }
      U.setZero(m, int(cols.size()));
      for (int j = 0; j < int(cols.size()); ++j) {
        const Row& r = s.rows[is.rows[size_t(cols[size_t(j)])]];
        for (int side = 0; side < 2; ++side) {
          const int32_t b = side == 0 ? r.a : r.b;
          if (b == 0 || bodyMark_[size_t(b)] != mark_ || bodyGroup_[size_t(b)] != g) continue;
          for (uint32_t e = eqStart_[size_t(b)]; e < eqStart_[size_t(b) + 1]; ++e)
            U(rowLocal_[eqRefs_[e] >> 1], j) +=
                rowCoupling(s.rows[eqRefs_[e] >> 1], int(eqRefs_[e] & 1), r, side);
        }
      }
      release();
      J.rows.assign(groupRows.begin(), groupRows.end());
      const Eigen::LLT<Eigen::MatrixXd> llt(K);
      if (llt.info() != Eigen::Success) return false;
      llt.matrixL().solveInPlace(U);  // V = L^-1 U
      C.noalias() = U.transpose() * U;
      llt.matrixU().solveInPlace(U);  // W = L^-T V = K^-1 U, for the residuals
      for (int i = 0; i < int(cols.size()); ++i)
        for (int j = 0; j < int(cols.size()); ++j) is.A(cols[size_t(i)], cols[size_t(j)]) -= C(i, j);
      is.jointed = true;
    }
  }
  return true;
}

void DirectContacts::release() noexcept {
  std::vector<Island>().swap(islands_);
  jointed_ = false;
  std::vector<uint32_t>().swap(eqStart_);
  std::vector<uint32_t>().swap(eqRefs_);
  std::vector<int32_t>().swap(bodyMark_);
  std::vector<int32_t>().swap(bodyGroup_);
  std::vector<int32_t>().swap(rowLocal_);
}

size_t DirectContacts::capacityBytes() const {
  return islands_.capacity() * sizeof(Island) +
         (eqStart_.capacity() + eqRefs_.capacity()) * sizeof(uint32_t) +
         (bodyMark_.capacity() + bodyGroup_.capacity() + rowLocal_.capacity()) * sizeof(int32_t);
}

void DirectContacts::dropJointed(Solver& s) {
  if (!jointed_) return;
  std::vector<Island> kept;
  for (Island& is : islands_) {
    if (!is.jointed) {
      kept.push_back(std::move(is));
      continue;
    }
    for (uint32_t i : is.rows) s.rows[i].direct = false;
  }
  islands_.swap(kept);
  jointed_ = false;
}

float DirectContacts::solve(Solver& s, const ContactRule& rule, float equalityBias) {
  float change = 0;
  for (Island& is : islands_)
    change = std::max(change, solveIsland(s, is, rule, equalityBias));
  return change;
}

void DirectContacts::factorFor(Island& is) {
  if (is.factored) {
    // The rows that left the set and those that joined it since the factorization: a few
    // are deleted and appended, more are factored anew (each change costs about m^2, a new
    // factorization m^3 / 3).
    changed_.clear();
    for (int k : is.order)
      if (!is.active[size_t(k)]) changed_.push_back(k);
    const size_t dropped = changed_.size();
    for (int k : set_)
      if (is.pos[size_t(k)] < 0) changed_.push_back(k);
    if (changed_.empty()) return;
    if (3 * changed_.size() <= set_.size()) {
      bool ok = true;
      for (size_t i = 0; i < changed_.size() && ok; ++i) {
        if (i < dropped)
          dropRow(is, changed_[i]);
        else
          ok = appendRow(is, changed_[i]);
      }
      if (ok) return;
    }
  }
  refactor(is);
}

void DirectContacts::refactor(Island& is) {
  const int n = int(is.rows.size()), m = int(set_.size());
  if (is.L.rows() != n) is.L.resize(n, n);
  is.order = set_;
  is.pos.assign(size_t(n), -1);
  for (int a = 0; a < m; ++a) is.pos[size_t(set_[size_t(a)])] = a;
  auto M = is.L.topLeftCorner(m, m);
  for (int b = 0; b < m; ++b)
    for (int a = b; a < m; ++a) M(a, b) = is.A(set_[size_t(a)], set_[size_t(b)]);
  for (int a = 0; a < m; ++a) M(a, a) += gamma_[set_[size_t(a)]];
  Eigen::LLT<Eigen::Ref<Eigen::MatrixXd>> llt(M);  // in place, the lower triangle
  is.factored = true;
}

void DirectContacts::dropRow(Island& is, int k) {
  // Row and column p out of L; the block below them, L22, then stands for L22 L22^T + x x^T
  // (x: column p below the diagonal), which a rank-one update folds back in.
  const int m = int(is.order.size()), p = is.pos[size_t(k)], t = m - 1 - p;
  Eigen::MatrixXd& L = is.L;
  col_ = L.col(p).segment(p + 1, t);
  for (int j = 0; j < p; ++j) {  // the rows below p up by one (within a column: std::copy)
    double* c = L.col(j).data();
    std::copy(c + p + 1, c + m, c + p);
  }
  for (int j = p + 1; j < m; ++j) L.col(j - 1).segment(j - 1, m - j) = L.col(j).segment(j, m - j);
  for (int j = 0; j < t; ++j) {
    const int d = p + j;  // the column being updated
    const double ljj = L(d, d), xj = col_[j];
    const double r = std::sqrt(ljj * ljj + xj * xj), c = r / ljj, sn = xj / ljj;
    L(d, d) = r;
    const int below = t - j - 1;
    if (below > 0) {
      auto ld = L.col(d).segment(d + 1, below);
      auto xs = col_.segment(j + 1, below);
      ld = (ld + sn * xs) / c;
      xs = c * xs - sn * ld;
    }
  }
  is.order.erase(is.order.begin() + p);
  is.pos[size_t(k)] = -1;
  for (int a = p; a < m - 1; ++a) is.pos[size_t(is.order[size_t(a)])] = a;
}

bool DirectContacts::appendRow(Island& is, int k) {
  // A new last row: l = L^-1 (its column of M), then its pivot; a pivot that is not clearly
  // positive (rounding after many changes) asks for a new factorization instead.
  const int m = int(is.order.size());
  Eigen::MatrixXd& L = is.L;
  col_.resize(m);
  for (int a = 0; a < m; ++a) col_[a] = is.A(is.order[size_t(a)], k);
  L.topLeftCorner(m, m).triangularView<Eigen::Lower>().solveInPlace(col_);
  const double diag = is.A(k, k) + gamma_[k];
  const double d2 = diag - col_.squaredNorm();
  if (!(d2 > 1e-9 * diag)) return false;
  L.row(m).head(m) = col_.transpose();
  L(m, m) = std::sqrt(d2);
  is.order.push_back(k);
  is.pos[size_t(k)] = m;
  return true;
}

void DirectContacts::solveFactor(const Island& is, Eigen::VectorXd& z) const {
  const int m = int(is.order.size());
  const auto L = is.L.topLeftCorner(m, m);
  L.triangularView<Eigen::Lower>().solveInPlace(z);
  L.transpose().triangularView<Eigen::Upper>().solveInPlace(z);
}

float DirectContacts::solveIsland(Solver& s, Island& is, const ContactRule& rule,
                                  float equalityBias) {
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
  // With joints: the residual where they hold, J v - U^T K^-1 r_eq (r_eq: the equality
  // rows' residual as the LDL hybrid solves it, J_eq v + its bias; W = K^-1 U).
  for (const Island::Joints& J : is.joints) {
    const int m = int(J.rows.size());
    y_.resize(m);
    for (int e = 0; e < m; ++e) {
      const Row& r = s.rows[J.rows[size_t(e)]];
      y_[e] = double(s.rowVelocity(r)) +
              (rule.useBias ? double(equalityBias) * double(s.rowError(r)) : 0.0);
    }
    w_.noalias() = J.W.transpose() * y_;
    for (int c = 0; c < int(J.cols.size()); ++c) residual_[J.cols[size_t(c)]] -= w_[c];
  }
  // Rows at the edge (an unloaded side contact: its impulse a rounding error either side of
  // zero) would flicker in and out of the set, each time costing a factorization: a row
  // leaves only below -1e-6 of the island's largest impulse, and joins only when it would
  // approach faster than 1e-5 m/s.
  const double leaveBelow = -1e-6 * std::max(lambda0.cwiseAbs().maxCoeff(), 1e-6);
  x_.setZero(n);
  for (int pass = 0; pass < kMaxPasses; ++pass) {
    // Rows outside the set end at zero impulse (those that carried some, loaded_, give it
    // up); the set's rows solve for the rest.
    set_.clear();
    loaded_.clear();
    for (int k = 0; k < n; ++k) {
      if (is.active[size_t(k)]) {
        set_.push_back(k);
      } else {
        x_[k] = -lambda0[k];
        if (x_[k] != 0) loaded_.push_back(k);
      }
    }
    const int m = int(set_.size());
    if (m > 0) {
      factorFor(is);
      rhs_.resize(m);  // in the factorization's order
      for (int a = 0; a < m; ++a) {
        const int k = is.order[size_t(a)];
        double r = residual_[k];
        for (int j : loaded_) r += is.A(k, j) * x_[j];
        rhs_[a] = -r;
      }
      solveFactor(is, rhs_);
      for (int a = 0; a < m; ++a) x_[is.order[size_t(a)]] = rhs_[a];
    }
    // The violations: a row in the set pulling (impulse below zero), a row outside still
    // approaching (velocity error below zero). The first passes change the set at every
    // violation, the pulling rows first; that can cycle, so later passes change only the
    // first violating row (Murty's least-index rule, which ends for a positive definite M).
    // (A is symmetric: its columns, contiguous, stand for its rows.)
    const bool single = pass >= kBlockPasses;
    auto pulling = [&](int k) { return lambda0[k] + x_[k] < leaveBelow; };
    auto approaching = [&](int k) {
      return residual_[k] + is.A.col(k).dot(x_) + gamma_[k] * x_[k] < -1e-5;
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
