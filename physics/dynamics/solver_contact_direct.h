// Direct contacts: the contact normal rows of an island where a heavy body rests on light
// ones, solved all together and exactly inside every Gauss-Seidel iteration (the joints'
// LDL hybrid, solver_ldl.h, carried over to contacts). Iteration cannot carry such a load: a
// light body between a 1000 kg-times-heavier one and the ground passes on about 1/ratio of
// the missing impulse per sweep, so the heavy body sinks through it or squeezes it out.
//
// Only islands at rest: one with an impact (a row approaching faster than kImpactSpeed) or a
// contact deeper than kRestDepth (twice the split push-out's depth) is iterated in that step
// (setup; why: docs/ARCHITECTURE.md, "Islands at rest only").
//
// The rows are unilateral, so the solve is an active-set one: the rows in the set are
// rigid, (A + eps D) dlambda = -(J v + bias), with A = J M^-1 J^T, D its diagonal and bias the
// iteration's (the soft contacts' position correction rate, or none in the relax pass); a
// row whose impulse would turn negative leaves the set at zero, a row outside it that would
// still approach joins it, until neither happens (the first passes change every violating
// row at once, later ones only the first: Murty's least-index rule, which cannot cycle).
// Rigid, not soft: a soft row's compliance is relative to its own effective mass, so the
// ground contact of a light body under a load R times its mass would sag R times as far
// (3 cm at 1000:1 and 90 Hz). eps = 1e-3 keeps redundant rows (a face's four points, which
// three directions separate; piles with more rows than degrees of freedom) factorable and
// their slightly inconsistent biases from turning into large impulses; it costs a steady
// error of about 1e-3 of the row's impulse times its inverse effective mass, corrected by
// the bias (measured: 6 um of penetration under a 1000:1 load).
// A is fixed for the step (contact rows do not change inside one), so the factorization of
// the active set is kept through the step and changed row by row as the set changes.
// Friction stays iterated, bounded by the exact normal impulses.
//
// Jointed bodies (issue 41): joints solved by the LDL hybrid join the islands, and A is the
// rows' matrix with the joints holding, A - U^T K^-1 U (K, U: the joints' rows among
// themselves and against the contact rows), their residual likewise; the LDL solve after
// every direct solve then carries the impulses through the joints. Solved as if the joints
// were not there, the two exact blocks undid each other through every light jointed body
// (docs/ARCHITECTURE.md, "Direct contacts on jointed bodies").
#pragma once

#include <Eigen/Dense>
#include <vector>

#include "dynamics/solver.h"

namespace phys {

class DirectContacts {
 public:
  /// Takes the islands' normal rows (solver row indices, a list per island), flags them
  /// Row::direct, and assembles each island's A from the rows' Jacobians and masses
  /// (Solver::finishRows has run). The equality rows of the joints on an island's bodies (the
  /// LDL hybrid's, solved exactly after every direct solve) enter through their Schur
  /// complement: A - U^T K^-1 U, with K = J_eq M^-1 J_eq^T and U = J_eq M^-1 J^T, the contact
  /// rows' effective masses with the joints holding (docs/ARCHITECTURE.md, "Direct contacts
  /// on jointed bodies").
  void setup(Solver& s, std::vector<std::vector<uint32_t>> islands);
  /// Gives the islands with joints back to the iteration (the LDL hybrid could not factor
  /// their joints this step: the direct rows would be solved without them).
  void dropJointed(Solver& s);
  void clear() { islands_.clear(); }
  /// clear(), and the scratch's storage back to the allocator (World::Impl::releaseStepBuffers).
  void release() noexcept;
  size_t capacityBytes() const;  ///< the per-body and per-row scratch held
  bool empty() const { return islands_.empty(); }
  size_t islandCount() const { return islands_.size(); }
  /// One exact solve of every island's normal rows under `rule` (the iteration's: biased or
  /// relaxing, soft or Baumgarte), applied to the bodies' velocities and the rows' lambda.
  /// Returns the largest velocity change it made to a row (the convergence measure). In an
  /// island with joints, the rows are solved where the joints hold (their residual with the
  /// joints' own at `equalityBias`, the LDL hybrid's, projected out), and the LDL solve that
  /// follows carries the impulses through the joints.
  float solve(Solver& s, const ContactRule& rule, float equalityBias);

  /// Active-set passes at most per solve (then the impulses are clamped at zero), the
  /// first kBlockPasses of them changing the set at every violation, the others at one.
  static constexpr int kMaxPasses = 64;
  static constexpr int kBlockPasses = 4;
  /// m/s: rows approaching faster than this at the step's start (impacts) stay iterated.
  static constexpr float kImpactSpeed = 1;
  /// m: so do islands with a row deeper than this. Twice the split push-out's depth: an
  /// island that sagged while iterated (an impact, a load it could not carry) is pushed back
  /// to kSplitDepth and held there, and at kSplitDepth itself it would never come back to the
  /// direct solve (measured: a pile of ragdolls held at 10.0 mm for seconds).
  static constexpr float kRestDepth = 2 * SolverSettings::kSplitDepth;
  /// An island with a jointed group of bodies holding more equality rows than this (each
  /// group's K is factored densely, about N^3 / 3 flops a step), or with more than
  /// kMaxIslandJointRows in all (four such groups, some 20 Mflop; a ragdoll is 54 rows), is
  /// iterated.
  static constexpr int kMaxGroupJointRows = 256;
  static constexpr int kMaxIslandJointRows = 1024;

 private:
  struct Island {
    std::vector<uint32_t> rows;
    /// A jointed group of bodies on the island: its equality rows, and W = K^-1 U over the
    /// island's rows in cols (A has had U^T K^-1 U taken off).
    struct Joints {
      std::vector<uint32_t> rows;
      Eigen::MatrixXd W;
      std::vector<int> cols;
    };
    std::vector<Joints> joints;
    bool jointed = false;         ///< A holds the Schur complement of joints' rows
    Eigen::MatrixXd A;            ///< J M^-1 J^T of the rows (with the joints holding)
    std::vector<uint8_t> active;  ///< the last solve's active set (the next one's start)
    /// The factorization M = L L^T of A + Gamma restricted to the active set, kept through
    /// the step and changed with the set: a row that leaves is deleted from L, one that
    /// joins is appended (each O(m^2) against a new factorization's m^3 / 3). L's leading
    /// m x m lower triangle holds it, its rows the island's rows `order`, `pos` each row's
    /// place (-1: outside the set).
    Eigen::MatrixXd L;
    std::vector<int> order, pos;
    bool factored = false;
  };
  /// Brings is's factorization to the active set set_ (the rows is.active marks), by
  /// deleting and appending rows or, past a few changes, factoring anew.
  void factorFor(Island& is);
  void refactor(Island& is);
  void dropRow(Island& is, int k);
  bool appendRow(Island& is, int k);
  /// z = M^-1 rhs, both in the order of is.order.
  void solveFactor(const Island& is, Eigen::VectorXd& z) const;
  float solveIsland(Solver& s, Island& is, const ContactRule& rule, float equalityBias);
  /// Subtracts U^T K^-1 U of the joints on the island's bodies from is.A; false when the
  /// island cannot be solved directly (too many joint rows, K not factorable).
  bool addJoints(const Solver& s, Island& is);
  std::vector<Island> islands_;
  bool jointed_ = false;
  // Equality rows per dynamic body (CSR over solver bodies: row << 1 | side), from setup.
  std::vector<uint32_t> eqStart_, eqRefs_;
  std::vector<int32_t> bodyMark_;   ///< per solver body: the island (pass) that reached it
  std::vector<int32_t> bodyGroup_;  ///< per solver body: its jointed group in that island
  std::vector<int32_t> rowLocal_;   ///< per solver row: its index in its group's K, or -1
  int32_t mark_ = 0;
  // Scratch.
  Eigen::VectorXd gamma_, residual_, x_, rhs_, xs_, w_, y_, col_;
  std::vector<int> set_, loaded_, changed_;
};

}  // namespace phys
