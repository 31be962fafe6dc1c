// The solver space: every setting a world's solver takes (scheme, substeps, iterations,
// stabilization, position pass, equality solve, ...). The named points of this space, the
// presets, are data (configs/presets.json, read by the scene library's phys/scene/presets.h).
#pragma once

#include <cstdint>
#include <span>
#include <type_traits>

namespace phys {

/// The solver's settings. The baseline is projected Gauss-Seidel with warm starting; the
/// same loop runs with `substeps` > 1 in the TGS style (positions advance per substep).
struct SolverSettings {
  enum class Stabilization : uint8_t { Baumgarte = 0, Soft = 1 };
  /// How joints' equality rows are solved: iterated with everything else, or all together
  /// by a sparse LDL^T factorization inside each iteration (rigid rows; for high mass ratios).
  enum class EqualitySolve : uint8_t { Iterative = 0, DirectLdl = 1 };
  /// Gauss-Seidel sweeps rows in order, on one thread; Jacobi solves every constraint (a
  /// contact manifold, a joint) from the same velocities with masses split among a body's
  /// constraints (Tonge et al. 2012) and averages: order-free, as on a GPU, and parallel.
  /// Colored Gauss-Seidel solves joints in order, then the contacts color by color (no two
  /// contacts of a color share a dynamic body), each color in parallel. Every scheme gives
  /// bit-identical results for any thread count.
  enum class Scheme : uint8_t { GaussSeidel = 0, Jacobi = 1, ColoredGaussSeidel = 2 };
  /// Post-stabilization after the velocity solve: positions projected directly.
  enum class PositionPass : uint8_t { None = 0, NonlinearGaussSeidel = 1, NonlinearJacobi = 2 };
  Scheme scheme = Scheme::GaussSeidel;
  PositionPass positionPass = PositionPass::None;
  int positionIterations = 0;          ///< position pass iterations, >= 0
  float positionBaumgarte = 0.2f;      ///< fraction of the position error removed per pass, 0..1
  float maxPositionCorrection = 0.2f;  ///< m (rad) at most per pass and row
  int substeps = 6;                    ///< >= 1
  int iterations = 2;                  ///< velocity iterations per substep, >= 1
  /// Convergence control: a substep's velocity iterations stop early once an iteration
  /// changes no row's velocity by more than this (m/s; rad/s for angular rows). 0: always
  /// run all `iterations`. StepStats reports the iterations used and the final residual.
  float tolerance = 0;
  int relaxIterations = 1;  ///< iterations without position bias after each substep, >= 0
  Stabilization stabilization = Stabilization::Soft;
  float baumgarte = 0.2f;  ///< Baumgarte beta, 0..1
  /// Soft contact stiffness, capped at a quarter of the substep rate (stiffer contacts topple
  /// stacks). A soft contact's static sag is about (load / effective mass) g / (2 pi hertz)^2:
  /// a corner carrying ten boxes sinks about 5.5 mm at 60 Hz and 2.5 mm at 90 Hz.
  float contactHertz = 90;
  float contactDampingRatio = 10;
  float jointHertz = 60;        ///< soft joint stiffness; capped at a quarter of substep rate
  float jointDampingRatio = 2;  ///< for soft joints
  float maxPushout = 3;         ///< m/s, the fastest speed penetration recovery may add
  /// Split push-out: penetration deeper than kSplitDepth is resolved by pseudo velocities
  /// that move positions and are then dropped (split impulses), not by the contacts'
  /// velocity bias. Bodies buried in each other separate without keeping the push. Only a
  /// step that starts with a contact deeper than kSplitDepth takes it; every other step is
  /// the unsplit solve, bit for bit (and as fast).
  bool splitPushout = true;
  /// m: the soft contacts' own bias corrects penetration up to this depth (deeper than a
  /// resting sag), the split push-out the rest.
  static constexpr float kSplitDepth = 0.01f;
  float linearSlop = 0.005f;  ///< m, penetration left uncorrected (Baumgarte only)
  bool warmStart = true;
  bool restitution = true;
  float restitutionThreshold = 1;  ///< m/s, approach speed below which no bounce
  EqualitySolve equalitySolve = EqualitySolve::DirectLdl;
  /// Direct contacts: an island of touching bodies in which a dynamic body touches one this
  /// many times lighter (or heavier) has its contact normal rows solved all together and
  /// exactly, as rigid rows, by an active-set Cholesky solve inside every Gauss-Seidel
  /// iteration (solver_contact_direct.h); friction stays iterated. Iteration alone cannot
  /// carry a 1000:1 load (a light body between a heavy one and the ground passes on about
  /// 1/ratio of the missing impulse per sweep), and a soft contact's compliance, relative to
  /// its own effective mass, lets a light body's ground contact sag ratio times as far.
  /// 0: never. Joints solved by the LDL hybrid join islands, and the direct solve takes them
  /// into account (the Schur complement of their rows); with iterated joints, jointed bodies'
  /// contacts are iterated. Islands with more than kDirectContactMaxRows touching normal rows
  /// are iterated, and so, in a step, is an island with an impact or a deep contact
  /// (DirectContacts::setup). The Jacobi scheme and the GPU backend ignore it (they iterate
  /// every contact).
  float directContactRatio = 10;
  static constexpr int kDirectContactMaxRows = 256;
  /// m: a contact point further apart than this at the step's start carries no load (0.3 %
  /// of them did in a pile of ragdolls) and is iterated even in a direct island; most of an
  /// island's points are such speculative ones (56 % in that pile), which would otherwise
  /// count against kDirectContactMaxRows and the dense solve's size.
  static constexpr float kDirectContactGap = 0.001f;
  /// Contact block solve: the 2-4 normal rows of a manifold solved together as one small LCP
  /// in every biased iteration (soft stabilization; speculative manifolds go row by row).
  bool blockContacts = false;
  /// Joints' geometric stiffness (Andrews et al. 2017): each jointed body's inertia grows by
  /// h^2 |f| |r| from last step's joint forces, which keeps light links under heavy loads
  /// stable at few substeps (their rotation then lags slightly).
  bool geometricStiffness = true;
  /// Stack stiffening: a tall stack on soft contacts buckles (leans out and falls) unless its
  /// contacts are stiff enough for its height. Every kStackInterval-th step cuts every stack
  /// into levels by support depth (contacts within 45 degrees of gravity, counted up from
  /// static and kinematic bodies) and finds the contact frequency at which it stands
  /// (physics/dynamics/stacks.h); where that is above 1/kStackMargin of the preset's, the steps
  /// take kStackMargin times it and the substeps that keep it under a quarter of the substep
  /// rate (which also lifts that cap for joints) until the next measurement
  /// (docs/ARCHITECTURE.md, "Tall stacks"). Other steps are the preset's, bit for bit. CPU
  /// backend only.
  bool stackStiffening = true;
  static constexpr float kStackMargin = 1.2f;
  /// Stacks that need more than this many times the preset's frequency are left alone.
  static constexpr float kStackMaxFactor = 3;
  /// Stacks with a level whose support points spread (RMS, across its softer axis) less than
  /// this fraction of its height are left alone: such a level tips over whatever the stiffness.
  static constexpr float kStackMinSpread = 0.05f;
  static constexpr int kStackInterval = 8;
  /// Patch friction: a manifold's friction as two tangent rows at the centroid of its points
  /// and a twist row about the normal, bounded by mu times the manifold's total normal
  /// impulse (and the points' mean distance from the centroid, for the twist), instead of a
  /// tangent pair at every point: 3 friction rows instead of 8 for a face contact.
  /// A manifold of one point (a sphere or a capsule's end on something) has no spread to
  /// measure; its twist arm is a Hertz contact patch's: radius a = sqrt(R kPointPatchDepth),
  /// R the reduced radius of curvature of the curved shapes (boxes, hulls and planes count as
  /// flat; two flat ones leave the arm 0), and the twist friction of a uniformly loaded disc
  /// acts at 2a/3. Without it a sphere spinning about the contact normal never stops.
  bool patchFriction = true;
  static constexpr float kPointPatchDepth = 0.005f;  ///< m
};

/// Every field of SolverSettings, one row each, in the wire order (physics.fbs's SolverSettings
/// table): the presets' JSON, the protocol's SolverOverrides, builder, converter and range
/// checks and the Python client are generated from it (docs/ARCHITECTURE.md, "Adding a solver
/// setting"). The struct above keeps the defaults and what each setting does; the snapshot
/// (snapshot.cpp, ioSolver) and physics.fbs are pinned formats written by hand, and the unit
/// and protocol tests walk this list through both.
///
///   X(type, member, name, json, check, lo, hi, meaning)
///
/// name: the wire field (its FlatBuffers accessor and add_ setter) and Python's keyword; json:
/// the presets file's key. check is what the protocol's decoder requires of a value: Flag
/// (none), Known (a value of the enum), Range (lo <= v <= hi) or Positive (0 < v <= hi). lo and
/// hi are read only for Range and Positive; the bounds are the decoder's names: kMaxSubsteps
/// (64), kMaxSolverIterations (1000), kMaxHertz, kMaxDampingRatio, kMaxDirectContactRatio
/// (1e6), and its Limits' maxSize and maxLinearSpeed.
#define PHYS_SOLVER_FIELDS(X)                                                                    \
  X(Scheme, scheme, scheme, scheme, Known, 0, 0, "how the rows are swept")                       \
  X(PositionPass, positionPass, position_pass, position_pass, Known, 0, 0,                       \
    "post-stabilization after the velocity solve")                                               \
  X(int, positionIterations, position_iterations, position_iterations, Range, 0,                 \
    kMaxSolverIterations, "position pass iterations")                                            \
  X(float, positionBaumgarte, position_baumgarte, position_baumgarte, Range, 0, 1,               \
    "fraction of the position error a position pass removes")                                    \
  X(float, maxPositionCorrection, max_position_correction, max_position_correction, Positive, 0, \
    maxSize, "m (rad) a position pass moves a row at most")                                      \
  X(int, substeps, substeps, substeps, Range, 1, kMaxSubsteps, "substeps per step")              \
  X(int, iterations, iterations, iterations, Range, 1, kMaxSolverIterations,                     \
    "velocity iterations per substep")                                                           \
  X(float, tolerance, tolerance, tolerance, Range, 0, maxLinearSpeed,                            \
    "m/s: a substep's iterations stop once no row changes more; 0: all run")                     \
  X(int, relaxIterations, relax_iterations, relax_iterations, Range, 0, kMaxSolverIterations,    \
    "iterations without position bias after each substep")                                       \
  X(Stabilization, stabilization, stabilization, stabilization, Known, 0, 0,                     \
    "Baumgarte or soft constraints")                                                             \
  X(float, baumgarte, baumgarte, baumgarte, Range, 0, 1, "Baumgarte beta")                       \
  X(float, contactHertz, contact_hertz, contact_hertz, Positive, 0, kMaxHertz,                   \
    "soft contact stiffness, Hz")                                                                \
  X(float, contactDampingRatio, contact_damping_ratio, contact_damping_ratio, Range, 0,          \
    kMaxDampingRatio, "soft contact damping ratio")                                              \
  X(float, jointHertz, joint_hertz, joint_hertz, Positive, 0, kMaxHertz,                         \
    "soft joint stiffness, Hz")                                                                  \
  X(float, jointDampingRatio, joint_damping_ratio, joint_damping_ratio, Range, 0,                \
    kMaxDampingRatio, "soft joint damping ratio")                                                \
  X(float, maxPushout, max_pushout, max_pushout, Positive, 0, maxLinearSpeed,                    \
    "m/s, the fastest speed penetration recovery may add")                                       \
  X(float, linearSlop, linear_slop, linear_slop, Range, 0, maxSize,                              \
    "m of penetration left uncorrected (Baumgarte)")                                             \
  X(bool, warmStart, warm_start, warm_start, Flag, 0, 0, "start from the last step's impulses")  \
  X(bool, restitution, restitution, restitution, Flag, 0, 0, "bounces")                          \
  X(float, restitutionThreshold, restitution_threshold, restitution_threshold, Range, 0,         \
    maxLinearSpeed, "m/s, the approach speed below which nothing bounces")                       \
  X(EqualitySolve, equalitySolve, equality_solve, equality, Known, 0, 0,                         \
    "joints' equality rows iterated or solved by LDL^T")                                         \
  X(bool, blockContacts, block_contacts, block_contacts, Flag, 0, 0,                             \
    "a manifold's normal rows solved as one LCP")                                                \
  X(bool, geometricStiffness, geometric_stiffness, geometric_stiffness, Flag, 0, 0,              \
    "joints' geometric stiffness")                                                               \
  X(bool, splitPushout, split_pushout, split_pushout, Flag, 0, 0,                                \
    "deep penetration resolved by split impulses")                                               \
  X(bool, patchFriction, patch_friction, patch_friction, Flag, 0, 0,                             \
    "a manifold's friction at its centroid")                                                     \
  X(bool, stackStiffening, stack_stiffening, stack_stiffening, Flag, 0, 0,                       \
    "tall stacks' contacts stiffened")                                                           \
  X(float, directContactRatio, direct_contact_ratio, direct_contact_ratio, Range, 0,             \
    kMaxDirectContactRatio, "mass ratio from which contacts are solved directly; 0: never")

namespace solver_fields {

#define PHYS_SOLVER_FIELD_COUNT(...) +1
inline constexpr int kCount = 0 PHYS_SOLVER_FIELDS(PHYS_SOLVER_FIELD_COUNT);
#undef PHYS_SOLVER_FIELD_COUNT

// The rows' types are SolverSettings' own.
using Scheme = SolverSettings::Scheme;
using PositionPass = SolverSettings::PositionPass;
using Stabilization = SolverSettings::Stabilization;
using EqualitySolve = SolverSettings::EqualitySolve;
#define PHYS_SOLVER_FIELD_TYPE(type, member, ...)                       \
  static_assert(std::is_same_v<decltype(SolverSettings::member), type>, \
                "the row of " #member " names another type");
PHYS_SOLVER_FIELDS(PHYS_SOLVER_FIELD_TYPE)
#undef PHYS_SOLVER_FIELD_TYPE

// A member without a row fails here, on every compiler (the sizeof tripwires of snapshot.cpp
// and builder.cpp only where they were measured): an aggregate takes as many initializers as
// it has members.
struct AnyValue {
  template <class T>
  operator T() const;
};
template <class T, class... A>
constexpr int memberCount() {
  if constexpr (requires { T{A{}..., AnyValue{}}; })
    return memberCount<T, A..., AnyValue>();
  else
    return sizeof...(A);
}
static_assert(memberCount<SolverSettings>() == kCount,
              "SolverSettings' members and PHYS_SOLVER_FIELDS' rows differ");

}  // namespace solver_fields

/// An enum setting's value and its names: the C++ enumerator's (Python's) and the presets
/// file's.
template <class E>
struct SettingName {
  E value;
  const char* name;
  const char* json;
};
/// Each enum's names, in the order of its values (error messages list them so).
inline constexpr SettingName<SolverSettings::Scheme> kSchemeNames[] = {
    {SolverSettings::Scheme::GaussSeidel, "GaussSeidel", "gauss_seidel"},
    {SolverSettings::Scheme::Jacobi, "Jacobi", "jacobi"},
    {SolverSettings::Scheme::ColoredGaussSeidel, "ColoredGaussSeidel", "colored_gauss_seidel"}};
inline constexpr SettingName<SolverSettings::PositionPass> kPositionPassNames[] = {
    {SolverSettings::PositionPass::None, "None", "none"},
    {SolverSettings::PositionPass::NonlinearGaussSeidel, "NonlinearGaussSeidel",
     "nonlinear_gauss_seidel"},
    {SolverSettings::PositionPass::NonlinearJacobi, "NonlinearJacobi", "nonlinear_jacobi"}};
inline constexpr SettingName<SolverSettings::Stabilization> kStabilizationNames[] = {
    {SolverSettings::Stabilization::Baumgarte, "Baumgarte", "baumgarte"},
    {SolverSettings::Stabilization::Soft, "Soft", "soft"}};
inline constexpr SettingName<SolverSettings::EqualitySolve> kEqualitySolveNames[] = {
    {SolverSettings::EqualitySolve::Iterative, "Iterative", "iterative"},
    {SolverSettings::EqualitySolve::DirectLdl, "DirectLdl", "direct_ldl"}};
/// An enum's table by its type: settingNames(E{}).
template <class E>
constexpr std::span<const SettingName<E>> settingNames(E) {
  using S = SolverSettings;
  if constexpr (std::is_same_v<E, S::Scheme>)
    return kSchemeNames;
  else if constexpr (std::is_same_v<E, S::PositionPass>)
    return kPositionPassNames;
  else if constexpr (std::is_same_v<E, S::Stabilization>)
    return kStabilizationNames;
  else
    return kEqualitySolveNames;
}
/// The names of value v (nullptr for a value outside the enum).
template <class E>
constexpr const SettingName<E>* settingName(E v) {
  for (const SettingName<E>& n : settingNames(v))
    if (n.value == v) return &n;
  return nullptr;
}

/// The Gauss-Seidel scheme solves contact manifolds eight at a time in SIMD lanes, in an
/// order that keeps every body's sequence of constraints, so the result is bit-identical to
/// solving them one by one (physics/dynamics/solver_wide.h). On by default; turned off only to
/// compare the two (tests, `physbench --scalar-contacts`). Process-wide.
void setVectorizedContacts(bool on);
bool vectorizedContacts();
/// Gauss-Seidel in nested parts (physics/dynamics/solver_wide.h): the levels of the cut come
/// from the contact count alone (partLevels). For measurements and tests only: every step with
/// enough contacts to be cut (256) gets `levels` levels instead (1 to 4, more than the rule
/// allows, for measurements; 0 or -1 restores the
/// rule). Results change with it, as with any other order. Process-wide.
void setPartLevelsOverride(int levels);

}  // namespace phys
