// The LDL hybrid (Roblox; Baraff 1996): every equality row of the joints solved together,
// exactly, by a sparse LDL^T factorization of A = J M^-1 J^T, inside each Gauss-Seidel
// iteration while contacts, limits and motors stay projected. The joint subsystem is then
// satisfied whatever the mass ratio (a 1000 kg ball on a chain of 1 kg links).
#pragma once

#include <Eigen/SparseCholesky>
#include <Eigen/SparseCore>
#include <vector>

#include "dynamics/solver.h"

namespace phys {

/// J_i . M^-1 J_j^T restricted to one body: row i's Jacobian on that body times row j's
/// M^-1 J^T on it. `sideI`/`sideJ`: 0 = the body is the row's A, 1 = its B. Summed over the
/// dynamic bodies two rows share, the entry (i, j) of A = J M^-1 J^T.
double rowCoupling(const Row& ri, int sideI, const Row& rj, int sideJ);

class EqualityLdl {
 public:
  /// Collects the equality rows of the solver and analyses A's sparsity pattern (once per
  /// step: the rows' structure does not change inside a step).
  void analyze(const Solver& s);
  /// Assembles A from the rows' current Jacobians and factors it (after every joint refresh).
  /// Returns false if the factorization failed (the caller falls back to iterating).
  bool factor(const Solver& s);
  /// Solves all equality rows at once: d = -A^-1 (J v + biasRate C); rigid rows (no mass or
  /// impulse softening), whose bias corrects position error at biasRate per second. Returns
  /// the largest velocity change it made to a row, |d| / effMass (the convergence measure).
  float solve(Solver& s, float biasRate, bool useBias);
  /// The same projection on the split push-out's pseudo velocities (Solver::push), rigid and
  /// without bias: J v_push = 0 for every equality row.
  void solvePush(Solver& s);
  bool empty() const { return rows_.empty(); }
  size_t rowCount() const { return rows_.size(); }

 private:
  void assemble(const Solver& s);
  /// solve and solvePush: d = -A^-1 (J v + biasRate C) on the bodies' velocities or (push)
  /// their pseudo velocities, applied there (and kept in the rows' lambda unless push).
  float project(Solver& s, float biasRate, bool useBias, bool push);
  std::vector<uint32_t> rows_;  ///< solver row indices of the equality rows
  std::vector<Eigen::Triplet<double>> triplets_;
  Eigen::SparseMatrix<double> A_;
  Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> ldlt_;
  Eigen::VectorXd rhs_, x_;
  bool ok_ = false;
};

}  // namespace phys
