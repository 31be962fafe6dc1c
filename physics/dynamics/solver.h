// Constraint rows as data, and the iterative scheme that runs over them.
//
// Every constraint (contact normal, friction direction, joint axis, limit, motor, spring) is
// one scalar row: a Jacobian J = (linA, angA, linB, angB), a position error C at the start of
// the step, bounds on its accumulated impulse, and the softness class that turns C into a
// velocity bias. Contact rows never change inside a step (joint rows are rebuilt per substep,
// see joints.h); the position error inside a substep is
// C0 + J . (dpB, dthetaB, dpA, dthetaA) from the bodies' accumulated position deltas (the TGS
// linearization), so no collision detection or Jacobian rebuild happens between substeps.
// The schemes (Gauss-Seidel, colored Gauss-Seidel, Jacobi with mass splitting; see
// forEachGroup) and the LDL joint solve (solver_ldl.h) all run over the same array.
#pragma once

#include <array>
#include <cstdint>
#include <span>
#include <vector>

#include "phys/defs/math.h"
#include "phys/defs/solver_settings.h"

namespace phys {

class EqualityLdl;
class ThreadPool;
class WideContacts;

/// What the iterations write: a body's velocities. Jacobi solves each constraint against its
/// own copy, and parallel Gauss-Seidel gives a constraint a scratch copy of a body it must
/// not write (the static world, kinematic bodies), so the kernels take velocities by reference.
struct Velocity {
  Vec3 v, w;  ///< m/s, rad/s
};

/// A body as the solver sees it: small and contiguous. Index 0 is the static world (zero
/// velocity, zero inverse mass), so rows touching static bodies need no branch.
struct SolverBody : Velocity {
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
  /// Its inverse inertia is invI.c0.x times the identity in every frame (a cube, a sphere; the
  /// world and kinematic bodies, zero): M^-1 J^T's angular parts are one product a component,
  /// in the rows (finishRows) and in the wide blocks, which then store no matrix.
  bool isotropic = false;
  /// Its accumulated rotation (dtheta) is read this step: it is in a constraint row or a
  /// manifold, or has a torque (the forces' work). A free body's is not kept: the rotation
  /// vector costs an atan2 per body and substep (markTrackedRotations).
  bool tracksRotation = true;
};

enum class RowKind : uint8_t {
  ContactNormal,  ///< lambda >= 0, speculative when C > 0
  Friction,       ///< pairs of rows (t1, t2): |(lambda1, lambda2)| <= mu * lambda(parent)
  Equality,       ///< lambda free, soft joint bias
  Limit,          ///< lambda >= 0, C >= 0 is allowed (speculative when C > 0)
  Motor,          ///< |lambda| <= maxImpulse, drives J v to target
  Spring,         ///< lambda free, soft with the row's own hertz and damping ratio
  Twist,          ///< patch friction about the normal: |lambda| <= mu * sum(lambda(normals))
};

struct Row {
  int32_t a = 0, b = 0;             ///< solver body indices (0 = world)
  Vec3 linA, angA, linB, angB;      ///< Jacobian
  Vec3 mLinA, mAngA, mLinB, mAngB;  ///< M^-1 J^T
  float effMass = 0;                ///< 1 / (J M^-1 J^T)
  float C0 = 0;                     ///< position error at the step's start (m or rad)
  float lambda = 0;                 ///< accumulated impulse of the current substep, N s
  float maxImpulse = 0;             ///< motor bound, N s per substep
  float target = 0;                 ///< motor target velocity
  float mu = 0;                     ///< friction coefficient
  int32_t parent = -1;              ///< friction: the normal row bounding it
  /// Patch friction and twist rows: the manifold's normal rows from `parent` whose impulses
  /// bound it (0: the parent alone).
  uint8_t patchPoints = 0;
  float restitution = 0;              ///< normal rows (the collision phase's, impacts.h)
  float maxLambda = 0;                ///< normal rows: largest impulse in the step
  float pushLambda = 0;               ///< normal rows: split push-out impulse, this substep
  float hertz = 0, dampingRatio = 0;  ///< spring rows
  /// Equality rows of one joint part (a point: 3, a rotation lock: 3, hinge axes: 2) are
  /// solved together as a block: on the block's first row, the row count and the index of
  /// the block's inverse K in Solver::blockInvK.
  uint8_t blockSize = 0;
  /// On a manifold's first normal row with the contact block solve: its point count (2-4),
  /// with blockIndex the index of its K in Solver::contactK.
  uint8_t contactPoints = 0;
  int32_t blockIndex = -1;
  RowKind kind = RowKind::Equality;
  /// First row of a constraint (a joint, a contact manifold): the unit of the Jacobi scheme,
  /// whose rows all act on the same two bodies.
  bool groupStart = false;
  /// A contact normal row of an island solved by DirectContacts, not by the iterations.
  bool direct = false;
};

/// A contact manifold in the solver's terms, from which the World makes its rows (three per
/// point: the normal, then after every normal a friction pair per point) or the wide blocks
/// make their lanes (solver_wide.h), with the same arithmetic either way.
struct SolverManifold {
  int32_t a = 0, b = 0;  ///< solver bodies
  int count = 0;         ///< points
  Vec3 normal, t1, t2;   ///< from A to B, and the friction directions
  float friction = 0, restitution = 0;
  Vec3 rA[4], rB[4];               ///< contact points relative to the bodies' centres of mass
  float separation[4] = {};        ///< C0 of the normal rows (m, negative when overlapping)
  /// The warm start (zero without); the step's impulses go to the contacts, not back here.
  float normalImpulse[4] = {}, tangentImpulse[4][2] = {};
  /// Patch friction (SolverSettings::patchFriction): the tangent rows act at the points'
  /// centroid (patchRA, patchRB), the twist row about the normal with arm twistArm (the
  /// points' mean distance from the centroid); impulses t1, t2, twist in patchImpulse.
  bool patch = false;
  Vec3 patchRA, patchRB;
  float twistArm = 0;
  float patchImpulse[3] = {};
};

/// A contact row along `axis` (from A to B) at point k of m (linA = -axis, angA = -rA x axis).
Row contactRow(const SolverManifold& m, RowKind kind, Vec3 axis, int k);

struct Softness {
  float biasRate = 0, massScale = 1, impulseScale = 0;
};
/// Catto's soft constraint coefficients for a spring of `hertz` and damping ratio `zeta`
/// over a step of h seconds. hertz == 0 gives a rigid row without position correction.
Softness makeSoftness(float hertz, float zeta, float h);

/// How a contact normal (or limit) row with position error C is solved in an iteration: the
/// velocity bias and Catto's scales, impulse = -effMass massScale (J v + bias) - impulseScale
/// lambda. The one rule of the iterations and the direct contact solve.
struct ContactTerms {
  float bias = 0, massScale = 1, impulseScale = 0;
};
struct ContactRule {
  Softness soft;  ///< the contacts' softness this substep (Baumgarte: {beta / h, 1, 0})
  float invH = 0, linearSlop = 0, maxPushout = 0;
  bool softStabilization = true, useBias = true, splitPushout = false;
  ContactTerms terms(const Row& r, float C) const;
};

/// Warm starting by bodies (Solver::BodyWarmStart) where it applies: on by default; turned off
/// only to compare it with the pass over the contacts (tests). Process-wide.
void setBodyWarmStart(bool on);
bool bodyWarmStart();

/// The rotation vector of integrateRotation(q, w, h)'s turn (q to the result), formed from
/// w alone: a turn by 2 atan(|w| h / 2) about w.
Vec3 integratedTurn(Vec3 w, float h);

class Solver {
 public:
  std::vector<SolverBody> bodies;  ///< [0] is the world
  /// Split push-out: per body, the pseudo velocity that resolves penetration this substep.
  /// It moves positions (integratePositions) and is then dropped, so pushing bodies apart
  /// never becomes kinetic energy. Used by the next integratePositions only (pushActive).
  std::vector<Velocity> push;
  bool pushActive = false;
  std::vector<Row> rows;
  std::vector<uint32_t> units;  ///< first row of each solve unit, in row order
  /// A constraint (a joint, a contact manifold): its solve units and its two bodies. The
  /// schemes differ only in how they order and batch groups (see forEachGroup).
  struct Group {
    uint32_t unitBegin, unitEnd;
    int32_t a, b;
  };
  std::vector<Group> groups;
  /// Set before indexUnits/finishRows.
  SolverSettings::Scheme scheme = SolverSettings::Scheme::GaussSeidel;
  bool jacobi() const { return scheme == SolverSettings::Scheme::Jacobi; }
  ThreadPool* pool = nullptr;  ///< parallel loops (colors, Jacobi, bodies); null: serial
  /// The Gauss-Seidel scheme's vectorized contacts (solver_wide.h), owned by the World. While
  /// active, warmStart and solveIteration run its schedule and the contact rows' impulses
  /// live in its blocks until WideContacts::store. Null: rows only.
  WideContacts* wide = nullptr;
  std::vector<float> split;     ///< per body: constraints sharing its mass (Jacobi), else 1
  std::vector<Mat3> blockInvK;  ///< inverse of J M^-1 J^T per row block (2x2 padded to 3x3)
  /// Contact block solve: the normal rows of a manifold (2-4 points) solved together.
  bool blockContacts = false;                   ///< set before finishRows
  std::vector<std::array<float, 16>> contactK;  ///< K = J M^-1 J^T of a manifold, row-major

  // Colored Gauss-Seidel: joint groups first, serially in order (a chain converges along
  // its length in one sweep), then the contact groups color by color: no two groups of a
  // color share a dynamic body, so a color runs in parallel and the order inside it does not
  // matter. Groups left when the colors run out are solved serially at the end.
  std::vector<uint32_t> serialGroups;  ///< joints, and the overflow of the colors
  std::vector<uint32_t> colorGroups;   ///< contact groups sorted by color
  std::vector<uint32_t> colorStart;    ///< color c: colorGroups[colorStart[c], colorStart[c+1])
  size_t overflowBegin = 0;            ///< serialGroups from here run after the colors
  // Jacobi: each group's velocity change to its two bodies, gathered per body in group order.
  struct GroupDelta {
    Velocity a, b;
  };
  std::vector<GroupDelta> groupDelta;
  std::vector<uint32_t> bodyRefStart, bodyRefs;  ///< per body: (group << 1 | side), CSR

  /// Every array above (and the private scratch) is filled by a step and read only inside
  /// it: release() gives their memory back (World::Impl::releaseStepBuffers) and
  /// capacityBytes() is what they hold.
  void release() noexcept;
  size_t capacityBytes() const;

  /// Sets M^-1 J^T, the effective mass and block matrices of rows [first, last) from the
  /// bodies' masses. A block keeps its blockInvK slot if it has one.
  void finishRows(size_t first, size_t last);

  /// Warm starting by bodies. Contact rows keep their Jacobians and M^-1 J^T for the whole
  /// step, so after any substep a body's velocity is the one it had after integrating
  /// velocities plus M^-1 J^T lambda summed over its constraints: exactly what the next
  /// substep's warm start adds again. When every row of the step is such a row (no joints,
  /// which are rebuilt per substep; no collision phase, direct solve or push-out, which change
  /// velocities outside the rows; not Jacobi, whose mass splitting averages), the substeps
  /// after the first take that sum per body (the velocity a substep ended with less the one
  /// it started from; a gyroscopic body's turn of w in integratePositions left out) instead
  /// of a pass over every contact: the same impulses, rounded differently.
  enum class BodyWarmStart : uint8_t {
    Off,    ///< the substep's warmStart() applies the rows' impulses
    Track,  ///< the first substep: its warmStart() does; the sums are recorded from here
    Apply,  ///< integrateVelocities adds the last substep's sum (no warmStart())
  };
  /// One substep's stages. h is the substep length.
  void integrateVelocities(float h, float maxLinearSpeed, float maxAngularSpeed,
                           BodyWarmStart warm = BodyWarmStart::Off);
  /// Applies last impulses again.
  void warmStart();
  /// One iteration over every solve unit. useBias=false is the relax pass. skipEquality
  /// leaves the joints' equality rows to a direct solve (EqualityLdl). Returns the largest
  /// velocity change the iteration made to a row, |delta lambda| / effMass (m/s or rad/s):
  /// the convergence measure.
  float solveIteration(const SolverSettings& s, float h, bool useBias, bool skipEquality = false,
                       bool skipDirect = false);
  /// The contact rule of an iteration (solveIteration's, and the direct contact solve's).
  static ContactRule contactRule(const SolverSettings& s, float h, bool useBias);
  /// The bias rate (1/s) at which equality rows correct position error over a substep h.
  static float equalityBiasRate(const SolverSettings& s, float h);
  /// Records where each solve unit (a row, a friction pair, a joint block) starts, the
  /// groups, the colors and the Jacobi gather lists.
  void indexUnits();
  /// Post-stabilization: `iterations` passes projecting positions (contacts, limits, joint
  /// equalities) with the rows' linearized errors; Jacobi averages per body like the solve.
  void positionPass(const SolverSettings& s, int iterations, bool jacobiPass);
  /// Split push-out: pseudo velocities from zero, warm-started with the rows' push impulses
  /// of the last substep, then `iterations` passes over the contact rows deeper than a
  /// resting sag, on the pseudo velocities only. The joints' equality rows hold there too
  /// (J v_push = 0, no bias): a contact pushing a jointed body out moves what it is jointed
  /// to instead of pulling the joint apart. With `ldl` they are solved exactly after each
  /// pass (EqualityLdl::solvePush), else iterated with the contacts.
  void solvePushout(const SolverSettings& s, float h, int iterations, EqualityLdl* ldl = nullptr);
  /// Which bodies' accumulated rotation the step reads (SolverBody::tracksRotation): those
  /// of the rows, of `manifolds` and those with a torque. Once the step's rows are built.
  void markTrackedRotations(std::span<const SolverManifold> manifolds);
  /// Advances positions by the velocities (plus the push-out velocities when split).
  void integratePositions(float h);
  /// Norm of the rows' velocity error after the solve (see SOLVER_NOTES "Residual").
  double velocityResidual(float h) const;

  /// J v of a row at the given velocities of its bodies.
  static float rowVelocity(const Row& r, const Velocity& A, const Velocity& B) {
    return dot(r.linA, A.v) + dot(r.angA, A.w) + dot(r.linB, B.v) + dot(r.angB, B.w);
  }
  float rowVelocity(const Row& r) const {
    return rowVelocity(r, bodies[size_t(r.a)], bodies[size_t(r.b)]);
  }
  /// Position error of a row at the current substep, from the accumulated deltas.
  float rowError(const Row& r) const {
    const SolverBody& A = bodies[size_t(r.a)];
    const SolverBody& B = bodies[size_t(r.b)];
    return r.C0 + dot(r.linA, A.dp) + dot(r.angA, A.dtheta) + dot(r.linB, B.dp) +
           dot(r.angB, B.dtheta);
  }
  static void applyImpulse(const Row& r, float impulse, Velocity& A, Velocity& B) {
    A.v += r.mLinA * impulse;
    A.w += r.mAngA * impulse;
    B.v += r.mLinB * impulse;
    B.w += r.mAngB * impulse;
  }
  void applyImpulse(const Row& r, float impulse) {
    applyImpulse(r, impulse, bodies[size_t(r.a)], bodies[size_t(r.b)]);
  }

 private:
  struct IterationParams;
  /// Runs f(group, velocityA, velocityB) -> float on every group in the scheme's order and
  /// batching; returns the largest value f returned. The velocities are the bodies' own, or
  /// with `pushChannel` their split push-out velocities.
  template <class F>
  float forEachGroup(F&& f, bool pushChannel = false);
  /// forEachGroup, or with active wide contacts their schedule: w(block) for blocks of
  /// manifolds, f(group, A, B) for the groups between them. Returns the largest result. With
  /// nested parts (solver_wide.h) w runs on all threads at once, on blocks that share no
  /// dynamic body; f always on the calling thread.
  template <class F, class W>
  float forEachScheduled(F&& f, W&& w);
  float solveGroup(const Group& g, Velocity& A, Velocity& B, const IterationParams& p);
  float pushoutGroup(const Group& g, Velocity& A, Velocity& B, const IterationParams& p);
  float solveFrictionPair(Row& r1, Row& r2, Velocity& A, Velocity& B, bool measure);
  /// The normal impulse bounding a friction or twist row.
  float frictionLoad(const Row& r) const;
  float solveBlock(size_t first, const IterationParams& p, Velocity& A, Velocity& B);
  /// The normal rows of a manifold at `first` as one small LCP; false when it does not apply
  /// (a speculative point) or no active set solves it, and the rows are solved one by one.
  bool solveContactBlock(size_t first, const IterationParams& p, Velocity& A, Velocity& B,
                         float* change);
  void warmStartGroup(const Group& g, Velocity& A, Velocity& B);
  void assignColors();
  void finishBlocks(size_t first, size_t last);
  template <class F>
  void parallel(size_t count, size_t grain, F&& fn);
  std::vector<Vec3> dv_, dw_;  ///< position pass (Jacobi) scratch
  /// Warm starting by bodies (BodyWarmStart): per body its velocity after the substep's
  /// integration (or after integratePositions turned it), and the impulses' velocity
  /// change summed so far in the substep.
  std::vector<Velocity> warmBase_, warmSum_;
  bool warmTracked_ = false;  ///< this substep records warmBase_/warmSum_
  /// f(v) on each of the arrays: release() and capacityBytes() share the one list.
  template <class Self, class F>
  static void forEachArray(Self& s, F&& f) {
    f(s.bodies), f(s.push), f(s.rows), f(s.units), f(s.groups), f(s.split), f(s.blockInvK);
    f(s.contactK), f(s.serialGroups), f(s.colorGroups), f(s.colorStart), f(s.groupDelta);
    f(s.bodyRefStart), f(s.bodyRefs), f(s.dv_), f(s.dw_), f(s.warmBase_), f(s.warmSum_);
  }
};

}  // namespace phys
