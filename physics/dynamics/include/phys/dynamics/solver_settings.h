// The solver space: every setting a world's solver takes (scheme, substeps, iterations,
// stabilization, position pass, equality solve, ...). The named points of this space, the
// presets, are data (configs/presets.json, read by the scene library's phys/scene/presets.h).
#pragma once

#include <cstdint>

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
