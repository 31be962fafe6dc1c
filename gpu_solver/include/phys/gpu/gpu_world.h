// A world's step on the GPU. phys_core's World owns one when its backend is the GPU: it
// hands over bodies and shapes as the flat records of shared.h (all of them when the world's
// structure changes, one at a time when a body is edited), calls step(), and reads the body
// states back for its host mirror (getBody, publishing, metrics).
//
// The step records every stage into one command buffer, submits it once and waits; only
// dirty records go up and only the body states (and the bounds when asked) come down.
#pragma once

#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "phys/gpu/device_info.h"
#include "phys/gpu/shared.h"

namespace phys::gpu {

/// The GPU step's stages, named as the CPU profile's (phys::StepProfile) where they match.
enum class Stage : int {
  SyncToDevice,
  UpdateBounds,
  BroadPhase,
  NarrowPhase,
  Prepare,
  IntegrateVelocities,
  WarmStart,
  Solve,
  IntegratePositions,
  Relax,
  Restitution,
  PositionPass,
  StoreImpulses,
  Finalize,
  Readback,
  Count
};
const char* stageName(Stage s);
constexpr int kStageCount = int(Stage::Count);

/// The contact solver's settings on the device (phys::SolverSettings' names and meanings):
/// the Jacobi scheme with mass splitting, or Gauss-Seidel on colors (the device colors the
/// contacts every step; within a color the order does not matter).
struct ContactSettings {
  bool jacobi = true;
  bool patchFriction = false;
  int iterations = 8;
  int relaxIterations = 0;
  bool soft = true;  ///< soft contacts (hertz, damping ratio), else Baumgarte
  float contactHertz = 30, contactDampingRatio = 10, baumgarte = 0.2f;
  float jointHertz = 60, jointDampingRatio = 2;  ///< joints' equality rows when soft
  float linearSlop = 0.005f;                     ///< m, Baumgarte only
  float maxPushout = 3;                          ///< m/s
  bool warmStart = true;
  bool restitution = true;
  float restitutionThreshold = 1;  ///< m/s
  /// The position pass after the velocity solve: nonlinear Jacobi with the Jacobi scheme,
  /// nonlinear Gauss-Seidel on colors otherwise; 0 passes: none.
  int positionIterations = 0;
  float positionBaumgarte = 0.2f;
  float maxPositionCorrection = 0.2f;  ///< m
  /// The joints' equality rows solved together and exactly (an L D L^T factorization of
  /// J M^-1 J^T per substep, joint_ldl.comp) after every pass, as the CPU's direct_ldl;
  /// otherwise iterated with the rest.
  bool directJoints = false;
  /// Split push-out (Gauss-Seidel on colors only): in a step whose deepest contact is
  /// deeper than SolverSettings::kSplitDepth, penetration beyond that depth is pushed out by
  /// pseudo velocities that move the bodies and are dropped, as the CPU's.
  bool splitPushout = false;
};

struct StepInput {
  float dt = 1.0f / 60;
  int substeps = 1;
  float maxLinearSpeed = 1e4f, maxAngularSpeed = 1e3f;
  float speculativeDistance = 0.02f;  ///< m, as WorldDef::speculativeDistance
  bool readBounds = false;            ///< bring the shapes' bounds back too (tests, diagnostics)
  bool readContacts = false;          ///< bring the pairs and manifolds back too
  /// Bring back the touch list (touches()): what the host's islands and sleeping need of
  /// the contacts, 8 bytes a touching pair instead of the manifolds' records.
  bool readTouches = false;
  /// Solve contacts (needs the narrow phase in the build); without, bodies pass through
  /// each other and only the collision stages run.
  bool solveContacts = true;
  ContactSettings contacts;
  /// Bound on the broad phase's pairs (WorldDef::maxContactPairs): the pair buffers grow to
  /// the power of two at or above it (at least 64, at most 2^31) and no further; pairs past
  /// them are left out (ContactStats::dropped). Between the bound and the buffers' size
  /// pairs are kept: pairs + dropped is what the broad phase found, to compare with it.
  uint32_t maxPairs = UINT32_MAX;
  /// A small world: up to this many constraints (joints + pair slots), the colored passes
  /// and the coloring rounds run in one workgroup, a dispatch for a whole run of passes
  /// instead of one per color and pass (the same arithmetic in the same order: the same
  /// bits). 0: never (tests compare the two). World's default (world_gpu.cpp): 256 on a GPU,
  /// 0 on a CPU implementation, where lavapipe runs such a workgroup's barriers some 20-80
  /// times slower than the dispatches and takes minutes to compile it.
  uint32_t smallWorldConstraints = 256;
};

/// Two non-static bodies (GpuWorld body indices) whose manifold has points this step.
struct Touch {
  uint32_t a = 0, b = 0;
};

struct ContactStats {
  uint32_t pairs = 0, manifolds = 0, points = 0;
  float deepest = 0;
  uint32_t dropped = 0;  ///< pairs left out for want of room (StepInput::maxPairs)
  /// Box-against-box tests the broad phase's query made (planes not counted): its work,
  /// the GPU profile's "candidate tests" (per shape: GpuWorld::candidateTestsPerShape).
  uint64_t candidateTests = 0;
};

/// How the device's broad phase finds the candidate pairs; either gives the same sorted pair
/// list, so the rest of the step is the same bits with both.
enum class BroadPhase {
  /// A linear BVH over Morton codes, built and queried on the device every step (the
  /// default): its cost follows the pairs, not how the bodies lie.
  Tree,
  /// Sort and sweep along one axis, chosen on the host from the states: what the tree
  /// replaced, kept to measure it against. A pile spread on a floor makes it quadratic.
  Sweep,
};

/// What the last step recorded into its command buffer: beyond its arithmetic, a step costs
/// the device a launch and a drain per dispatch and barrier (a few microseconds each on a
/// GPU), which is all a small world's step is. Pinned by tests (GpuDispatch.*).
struct StepCounts {
  uint32_t dispatches = 0;  ///< dispatches recorded, the indirect ones included
  uint32_t indirect = 0;    ///< of them, sized on the device (some may run no workgroup)
  uint32_t barriers = 0;    ///< pipeline barriers
  uint32_t transfers = 0;   ///< uploads, downloads, fills and copies
};

/// The host's own work in the last step (ms), beside the device's stages (stageMs): what
/// a step costs the CPU that drives the device. Measured with the host's clock.
struct HostTimes {
  /// Recording the step's commands, with the uploads' copies into the staging memory and
  /// the host's buffers for what comes back.
  double record = 0;
  /// Copying what came back out of the staging memory into the host's arrays.
  double copyOut = 0;
};

class GpuWorld {
 public:
  /// A world on the device the options choose (one device per process and options, shared
  /// by every world on it). Null with *error when there is no usable device.
  static std::unique_ptr<GpuWorld> create(const DeviceOptions& options, std::string* error);
  ~GpuWorld();
  GpuWorld(const GpuWorld&) = delete;
  GpuWorld& operator=(const GpuWorld&) = delete;

  const DeviceInfo& device() const;
  /// Errors the validation layer reported on this world's device (runs with validation).
  int validationErrors() const;

  /// Replaces every body: body i of the GPU world is states[i] / params[i].
  void setBodies(std::span<const GpuBodyState> states, std::span<const GpuBodyParams> params);
  /// One body was edited: its records go up with the next step.
  void setBody(uint32_t index, const GpuBodyState& state, const GpuBodyParams& params);
  /// Replaces every shape; owners[i] names shape i's body for setNoCollide (any ids; empty:
  /// every shape its own).
  void setShapes(std::span<const GpuShape> shapes, std::span<const uint32_t> owners = {});
  /// The packed hull records (hull_pack.h) hull shapes point into (GpuShape.size.x holds a
  /// record's offset as float bits).
  void setHulls(std::vector<uint32_t> words);
  /// Pairs of owners whose shapes never collide (bodies joined without collide_connected).
  void setNoCollide(std::vector<std::pair<uint32_t, uint32_t>> pairs);
  /// Replaces every joint, with the impulses to warm-start them from (GpuJointOut.impulses
  /// and the row count in force.w's bits; zeros: none).
  void setJoints(std::span<const GpuJoint> joints, std::span<const GpuJointOut> impulses);
  uint32_t jointCount() const;
  /// After a step: every joint's impulses and reaction on B, in setJoints order.
  std::span<const GpuJointOut> jointResults() const;
  uint32_t bodyCount() const;
  uint32_t shapeCount() const;

  /// One step of dt in `substeps` substeps. False with *error on a device failure (the
  /// states are then those of the last good step).
  bool step(const StepInput& in, std::string* error);
  /// Undoes the last step (once): the states and joint impulses are those before it, and the
  /// next step warm-starts from the contacts before it, so stepping again gives what that
  /// step would have given with whatever was set since (a body woken by what the step found,
  /// world_gpu.cpp). False when there is no step to undo or something was set since it (set
  /// after the undo instead).
  bool undoStep();
  /// After a step: every body's state, in setBodies order.
  std::span<const GpuBodyState> states() const;
  /// After a step with readBounds: every shape's bounds, in setShapes order.
  std::span<const GpuAabb> bounds() const;
  /// After a step: the broad phase's pairs (shape indices a < b, sorted) and, with the
  /// narrow phase, their manifolds (same index); both only with readContacts.
  std::span<const GpuPair> pairs() const;
  std::span<const GpuManifold> manifolds() const;
  /// After a step with readTouches (and the narrow phase): every manifold with points
  /// between two bodies that are not static (dynamic, kinematic or asleep), in the
  /// manifolds' order (pairs with a static body neither join islands nor wake them).
  std::span<const Touch> touches() const;
  /// Bytes the last step brought back from the device (states, counters, and what the
  /// StepInput asked for).
  uint64_t readbackBytes() const;
  /// Bytes the last step sent up (edited records, or all of them after setBodies,
  /// setShapes, setJoints or an undo; the LDL plan when it changed; the counters' resets).
  uint64_t uploadBytes() const;
  /// The last step's host work (HostTimes).
  HostTimes hostMs() const;
  /// The last step's candidate pairs (always read back).
  uint32_t pairCount() const;
  /// The axis (0 x, 1 y, 2 z) the last step's broad phase sorted and swept the bounds on: the
  /// one along which the shapes' bodies spread most, chosen every 16 steps and after setShapes.
  /// BroadPhase::Sweep only (the tree has no axis).
  uint32_t sweepAxis() const;
  /// The broad phase's method; the default is Tree, or Sweep when the environment has
  /// PHYS_GPU_BROAD_PHASE=sweep (benchmarks: physbench runs the same scene with either).
  void setBroadPhase(BroadPhase method);
  BroadPhase broadPhase() const;
  /// The last step's candidate tests (ContactStats::candidateTests) per shape in the broad
  /// phase's query (the shapes but the planes); 0 when there are none.
  double candidateTestsPerShape() const;
  /// The last step's contacts: candidate pairs, manifolds with points, points, deepest
  /// penetration (m).
  ContactStats contactStats() const;
  /// Whether this build has the narrow phase on the device.
  bool hasNarrowPhase() const;
  /// Device time of each stage in the last step (ms), indexed by Stage; zeros without
  /// timestamp support.
  std::span<const double> stageMs() const;
  /// The last step's dispatches and barriers (the attempt that stood, when a step was taken
  /// again with larger pair buffers).
  StepCounts stepCounts() const;

 private:
  struct Impl;
  explicit GpuWorld(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace phys::gpu
