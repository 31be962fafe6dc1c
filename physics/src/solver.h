// Constraint rows as data, and the iterative scheme that runs over them.
//
// Every constraint (contact normal, friction direction, joint axis, limit, motor, spring) is
// one scalar row: a Jacobian J = (linA, angA, linB, angB), a position error C at the start of
// the step, bounds on its accumulated impulse, and the softness class that turns C into a
// velocity bias. Rows never change inside a step; the position error inside a substep is
// C0 + J . (dpB, dthetaB, dpA, dthetaA) from the bodies' accumulated position deltas (the TGS
// linearization), so no collision detection or Jacobian rebuild happens between substeps.
// The scheme (here: projected Gauss-Seidel) is separate from the rows: a later Jacobi or LDL
// scheme runs over the same array.
#pragma once

#include <cstdint>
#include <vector>

#include "phys/math.h"
#include "phys/world.h"

namespace phys {

/// A body as the solver sees it: small and contiguous. Index 0 is the static world (zero
/// velocity, zero inverse mass), so rows touching static bodies need no branch.
struct SolverBody {
  Vec3 v, w;                 ///< m/s, rad/s
  Vec3 dp;                   ///< m, centre-of-mass displacement since the step began
  Vec3 dtheta;               ///< rad, accumulated rotation vector since the step began
  Quat q;                    ///< current orientation
  float invMass = 0;         ///< 1/kg (0 for kinematic bodies and the world)
  Mat3 invI = Mat3::zero();  ///< world inverse inertia at the step's start
  // Integration inputs (dynamic bodies only).
  Vec3 linearAccel;  ///< m/s^2: gravity * scale + force / mass
  Vec3 torque;       ///< N m
  Mat3 inertiaLocal = Mat3::zero();
  Quat principal;                  ///< principal axes frame -> body frame
  Vec3 principalMoments{1, 1, 1};  ///< kg m^2
  float linearDamping = 0, angularDamping = 0;
  bool dynamic = false, gyroscopic = false;
};

enum class RowKind : uint8_t {
  ContactNormal,  ///< lambda >= 0, speculative when C > 0
  Friction,       ///< pairs of rows (t1, t2): |(lambda1, lambda2)| <= mu * lambda(parent)
  Equality,       ///< lambda free, soft joint bias
  Limit,          ///< lambda >= 0, C >= 0 is allowed (speculative when C > 0)
  Motor,          ///< |lambda| <= maxImpulse, drives J v to target
  Spring,         ///< lambda free, soft with the row's own hertz and damping ratio
};

struct Row {
  int32_t a = 0, b = 0;               ///< solver body indices (0 = world)
  Vec3 linA, angA, linB, angB;        ///< Jacobian
  Vec3 mLinA, mAngA, mLinB, mAngB;    ///< M^-1 J^T
  float effMass = 0;                  ///< 1 / (J M^-1 J^T)
  float C0 = 0;                       ///< position error at the step's start (m or rad)
  float lambda = 0;                   ///< accumulated impulse of the current substep, N s
  float maxImpulse = 0;               ///< motor bound, N s per substep
  float target = 0;                   ///< motor target velocity
  float mu = 0;                       ///< friction coefficient
  int32_t parent = -1;                ///< friction: the normal row bounding it
  float restitution = 0;              ///< normal rows
  float relativeVelocity = 0;         ///< normal rows: J v before the solve
  float maxLambda = 0;                ///< normal rows: largest impulse in the step
  float hertz = 0, dampingRatio = 0;  ///< spring rows
  /// Equality rows of one joint part (a point: 3, a rotation lock: 3, hinge axes: 2) are
  /// solved together as a block: on the block's first row, the row count and the index of
  /// the block's inverse K in Solver::blockInvK.
  uint8_t blockSize = 0;
  int32_t blockIndex = -1;
  RowKind kind = RowKind::Equality;
  /// First row of a constraint (a joint, a contact manifold): the unit of the Jacobi scheme,
  /// whose rows all act on the same two bodies.
  bool groupStart = false;
};

struct Softness {
  float biasRate = 0, massScale = 1, impulseScale = 0;
};
/// Catto's soft constraint coefficients for a spring of `hertz` and damping ratio `zeta`
/// over a step of h seconds. hertz == 0 gives a rigid row without position correction.
Softness makeSoftness(float hertz, float zeta, float h);

class Solver {
 public:
  std::vector<SolverBody> bodies;  ///< [0] is the world
  std::vector<Row> rows;
  std::vector<uint32_t> units;  ///< first row of each solve unit, in row order
  /// A constraint of the Jacobi scheme: its units and its two bodies.
  struct Group {
    uint32_t unitBegin, unitEnd;
    int32_t a, b;
  };
  std::vector<Group> groups;
  bool jacobi = false;          ///< set before indexUnits/finishRows
  std::vector<float> split;     ///< per body: constraints sharing its mass (Jacobi), else 1
  std::vector<Mat3> blockInvK;  ///< inverse of J M^-1 J^T per row block (2x2 padded to 3x3)

  /// Sets M^-1 J^T, the effective mass and block matrices of rows [first, last) from the
  /// bodies' masses. A block keeps its blockInvK slot if it has one.
  void finishRows(size_t first, size_t last);

  /// One substep's stages. h is the substep length.
  void integrateVelocities(float h, float maxLinearSpeed, float maxAngularSpeed);
  /// Applies last impulses again; also records contacts' approach speed for restitution.
  void warmStart();
  void warmStartRows(size_t begin, size_t end);
  /// One iteration over every solve unit. useBias=false is the relax pass. skipEquality
  /// leaves the joints' equality rows to a direct solve (EqualityLdl).
  void solveIteration(const SolverSettings& s, float h, bool useBias, bool skipEquality = false);
  /// The bias rate (1/s) at which equality rows correct position error over a substep h.
  static float equalityBiasRate(const SolverSettings& s, float h);
  /// Records where each solve unit (a row, a friction pair, a joint block) starts.
  void indexUnits();
  /// Post-stabilization: `iterations` passes projecting positions (contacts, limits, joint
  /// equalities) with the rows' linearized errors; Jacobi averages per body like the solve.
  void positionPass(const SolverSettings& s, int iterations, bool jacobiPass);
  void solveFrictionPair(Row& r1, Row& r2);
  /// Runs solveGroup on every constraint group against its own copy of its two bodies'
  /// velocities, then moves each body by the average of its copies (Jacobi with mass
  /// splitting; the rows' M^-1 J^T already carry the split).
  template <class F>
  void forEachGroupAveraged(F&& solveGroup);
  std::vector<Vec3> dv_, dw_;
  void solveBlock(size_t first, const Softness& soft, bool useBias);
  void integratePositions(float h);
  void applyRestitution(float threshold);
  void restitutionRows(size_t begin, size_t end, float threshold);
  /// Norm of the rows' velocity error after the solve (see SOLVER_NOTES "Residual").
  double velocityResidual(float h) const;
  /// J v of a row at the current velocities.
  float rowVelocity(const Row& r) const {
    const SolverBody& A = bodies[size_t(r.a)];
    const SolverBody& B = bodies[size_t(r.b)];
    return dot(r.linA, A.v) + dot(r.angA, A.w) + dot(r.linB, B.v) + dot(r.angB, B.w);
  }
  /// Position error of a row at the current substep, from the accumulated deltas.
  float rowError(const Row& r) const {
    const SolverBody& A = bodies[size_t(r.a)];
    const SolverBody& B = bodies[size_t(r.b)];
    return r.C0 + dot(r.linA, A.dp) + dot(r.angA, A.dtheta) + dot(r.linB, B.dp) +
           dot(r.angB, B.dtheta);
  }
  void applyImpulse(const Row& r, float impulse) {
    SolverBody& A = bodies[size_t(r.a)];
    SolverBody& B = bodies[size_t(r.b)];
    A.v += r.mLinA * impulse;
    A.w += r.mAngA * impulse;
    B.v += r.mLinB * impulse;
    B.w += r.mAngB * impulse;
  }
};

}  // namespace phys
