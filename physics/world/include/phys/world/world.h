// The world: bodies, shapes, joints, and the step. In-process API; no I/O. What bodies,
// joints and worlds are defined with is plain data of phys/defs/ (the client SDK shares it).
// Units are SI (m, kg, s, rad). z is up; the default gravity is (0, 0, -9.81).
// Every create/edit call validates its input and returns a Status; a rejected call changes
// nothing. Ids are generational handles: a stale id is reported as NotFound.
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "phys/collision/shapes.h"
#include "phys/defs/body_def.h"
#include "phys/defs/ids.h"
#include "phys/defs/joint_def.h"
#include "phys/defs/math.h"
#include "phys/defs/shape_def.h"
#include "phys/defs/solver_settings.h"
#include "phys/defs/status.h"
#include "phys/defs/world_def.h"

namespace phys {

/// Which backend a world runs on and how its steps were taken.
struct BackendState {
  Backend requested = Backend::Cpu;
  Backend active = Backend::Cpu;  ///< Gpu when a device was opened
  std::string device;             ///< the Vulkan device's name, when active is Gpu
  std::string note;               ///< why the CPU runs a world that asked for the GPU
  uint64_t gpuSteps = 0;          ///< steps taken on the device (those with every body asleep
                                  ///< need no device work and count here too)
  uint64_t cpuSteps = 0;          ///< steps taken by the CPU backend (all of a CPU world's)
  std::string lastFallback;       ///< why the last CPU step of a GPU world was not on the device
  /// Islands the CPU stepped inside device steps (docs/ARCHITECTURE.md, "Islands on the CPU
  /// beside the device"): those with a touching pair of mass ratio directContactRatio or
  /// more (direct contacts) or with an elastic contact (restitution's collision phase). Those
  /// steps count in gpuSteps; the rest of the world was on the device.
  int cpuIslands = 0;                 ///< islands the CPU stepped in the last step
  int cpuIslandBodies = 0;            ///< their bodies
  double cpuIslandMs = 0;             ///< ms, the CPU's part of the last step (wall)
  uint64_t cpuIslandSteps = 0;        ///< device steps with islands on the CPU
  uint64_t cpuIslandBodySteps = 0;    ///< bodies the CPU stepped, summed over those steps
  uint64_t cpuIslandRetakes = 0;      ///< device steps taken again: an island joined the CPU's
  std::string cpuIslandReason;        ///< why, in the last step that had any
  /// Errors the Vulkan validation layer reported on the world's device so far (only with
  /// PHYS_GPU_VALIDATION=1; tests and physbench --require-device fail on any).
  int validationErrors = 0;
  bool validationRequested = false;  ///< PHYS_GPU_VALIDATION asked for the validation layer
  bool validation = false;           ///< the validation layer is loaded on the world's device
  /// Bytes the last device step brought back to the host (0 when every body slept).
  uint64_t readbackBytes = 0;
  /// Bytes the last device step sent up: the records edited since the step before (all of
  /// them after a structure change), not the world's size.
  uint64_t uploadBytes = 0;
  /// Dispatches and barriers the device's steps recorded, summed over gpuSteps (divide for
  /// the per-step figure physbench reports).
  uint64_t gpuDispatches = 0, gpuBarriers = 0;
  /// Backend::Auto: the body count above which the device's step is the faster, from the
  /// calibration taken when the device opened (+inf: never; 0: not an auto world on a
  /// device). `active` is the backend auto chose for the world's size (`note` says why).
  double autoCrossoverBodies = 0;
};

/// Vulkan validation errors reported in this process so far, by every GPU world's device,
/// including those raised while a device was destroyed (what a world's teardown left behind).
/// 0 without validation (PHYS_GPU_VALIDATION=1) or without the GPU backend.
int gpuValidationErrorsInProcess();

/// Wall time of each step stage in milliseconds. Stage names are used everywhere.
/// On the GPU backend the stages are the device's timestamps, plus the uploads of edited
/// bodies (syncToDevice) and the states' readback; total is the wall time.
struct StepProfile {
  double syncToDevice = 0, readback = 0;
  double applyCommands = 0, updateBounds = 0, broadPhase = 0, narrowPhase = 0, buildIslands = 0,
         prepare = 0, integrateVelocities = 0, warmStart = 0, solve = 0, integratePositions = 0,
         relax = 0, restitution = 0, positionPass = 0, storeImpulses = 0, finalize = 0, total = 0;
  /// GPU backend: the dispatches and pipeline barriers the step recorded (0 for a step the
  /// CPU took): a small world's device step costs about this many launches and drains.
  int dispatches = 0, barriers = 0;
  /// GPU backend: the host's own work in a device step (ms, inside total; 0 after a CPU
  /// step), which should follow what changed, not the world's size. hostUpload: the edited
  /// records built and staged (uploadToDevice, recording the commands with the uploads'
  /// copies); hostReadback: what came back copied out of the staging memory; hostMirror: the
  /// host mirror written from it (states, joints, touches); hostOther: the rest of total
  /// outside the device's stages (the energies, the statistics, the submit and the wait
  /// beyond the stages' timestamps).
  double hostUpload = 0, hostReadback = 0, hostMirror = 0, hostOther = 0;
  /// The guard's work around the step (ms; not in total, which is the step's own): its copy
  /// for a rollback, the health check, and keeping the bodies inside the world's extent.
  double guard = 0;
};

/// What the last step did, for metrics and monitors (double precision).
struct StepStats {
  uint64_t step = 0;  ///< steps taken so far
  /// bodies: all of them; awake: the non-static bodies the last step moved (the solver's);
  /// joints: the joints it solved; contacts: the contacts it collided (not those of sleeping
  /// islands).
  int bodies = 0, awake = 0, contacts = 0, contactPoints = 0, joints = 0, pairs = 0;
  /// The GPU backend's broad phase: box tests its query made per shape (planes aside), the
  /// measure of its work that does not depend on the machine (gpu_world.h, BroadPhase);
  /// 0 after a CPU step (not measured there).
  double broadPhaseTestsPerShape = 0;
  /// After the last step: dynamic bodies asleep, islands of awake dynamic bodies (as the
  /// last step found them) and sleeping islands.
  int sleepingBodies = 0, awakeIslands = 0, sleepingIslands = 0;
  int vectorizedManifolds = 0;  ///< contact manifolds solved in SIMD lanes (solver_wide.h)
  /// Gauss-Seidel in nested parts (solver_wide.h): the contacts between the parts (in the
  /// separators, which run after the leaves); -1 when the step's contact order was not split
  /// (too few contacts, another scheme, a step on the GPU backend). The parts run on all
  /// threads when the contacts are solved in SIMD lanes (vectorizedManifolds > 0); otherwise
  /// the rows are in the split order and solved serially.
  int contactsBetweenHalves = -1;
  /// The leaf parts of the step's contact order (2, 4 or 8: solver_wide.h's partLevels,
  /// a function of the contact count alone); 0 when not split.
  int contactParts = 0;
  double energyBefore = 0;      ///< J, kinetic + potential at step start
  double energyAfter = 0;       ///< J, at step end
  /// Norm of J v + bias over active rows after the solve; after a step whose bodies the guard
  /// stopped (guardQuarantined), the largest double if the solve diverged.
  double velocityResidual = 0;
  double maxPenetration = 0;    ///< m, deepest contact overlap at the start of the step
  int iterationsUsed =
      0;  ///< velocity iterations of the step (substeps x iterations, as redone by the guard)
  int substeps = 0;  ///< substeps of the step (after stack stiffening and guard retries)
  /// s, the substep length of the last CPU step: the unit of the warm-start impulses it
  /// stored (0 after a device step, whose impulses stay on the device).
  float substepTime = 0;
  int stackDepth = 0;        ///< bodies in the deepest support chain (with stack stiffening on)
  float stackHertz = 0;      ///< Hz, the contact frequency stack stiffening asks for (0: none)
  int guardRetries = 0;      ///< times this step was rolled back and redone
  uint64_t guardEvents = 0;  ///< steps redone so far
  uint64_t guardQuarantined = 0;  ///< bodies stopped so far because retries did not help
  /// What the last violation was, or the last failed step (stepFailures), for logs.
  std::string lastGuardEvent;
  /// The contact pair bound (WorldDef::maxContactPairs, resolved) the last step ran under.
  uint32_t pairLimit = 0;
  /// Broad-phase pairs the last step left out at the bound: 0 when every pair fit;
  /// otherwise at least 1, and a lower bound (counting stops after a work budget of
  /// pairLimit). The bodies of those pairs were not collided with each other this step.
  uint64_t pairsDropped = 0;
  uint64_t pairLimitSteps = 0;  ///< steps so far that reached the pair bound
  /// Steps so far that failed with an exception inside the step (std::bad_alloc,
  /// std::length_error): World::step catches it and does not take the step. The bodies, the
  /// time and the step count are as before it; so are the contacts and their warm starts
  /// with the guard on (its copy), while without it they are dropped (the next step starts
  /// them cold). The step's buffers are freed, the broad phase is built again from its fat
  /// boxes, and lastGuardEvent says what happened; the other fields are the failed attempt's.
  uint64_t stepFailures = 0;
  /// Steps so far not taken because their pairs passed the bound under
  /// WorldDef::PairOverflow::Refuse (the world is as before each; pairsDropped says by how
  /// many at least, lastGuardEvent says so in words).
  uint64_t stepsRefused = 0;
};

/// A body's state computed elsewhere (a peer engine's step), for World::observe. Conventions
/// as BodyState: body frame origin and rotation; centre-of-mass and angular velocity, world.
struct ObservedBody {
  Vec3 position;
  Quat rotation;
  Vec3 linearVelocity, angularVelocity;
};

/// A contact for inspection (metrics, debugging).
struct ContactInfo {
  BodyId bodyA, bodyB;
  ShapeId shapeA, shapeB;
  Manifold manifold;
  float normalImpulse[Manifold::kMaxPoints] = {};
};

class World {
 public:
  explicit World(const WorldDef& def = WorldDef());
  ~World();
  World(const World&) = delete;
  World& operator=(const World&) = delete;

  const WorldDef& def() const;
  /// A change of gravity or of the time step wakes every body: sleeping ones, and the rest
  /// timers of the awake ones start again.
  Status setGravity(Vec3 g);
  Status setTimeStep(float dt);
  Status setSolverSettings(const SolverSettings& s);
  /// WorldDef::maxContactPairs and pairOverflow (a server's policy, also over a restored
  /// snapshot's).
  void setContactBudget(uint32_t maxContactPairs, WorldDef::PairOverflow overflow);
  /// Validates solver settings without applying them.
  static Status validate(const SolverSettings& s);
  /// Sleeping on or off and its thresholds (time > 0, speeds >= 0, finite). Turning it off,
  /// or changing a threshold, wakes every body (as setGravity).
  Status setSleepSettings(const SleepSettings& s);
  static Status validate(const SleepSettings& s);
  /// Every setting of a living world at once, all-or-nothing: what differs between d and
  /// def() changes (gravity, time step, speed clamps, collision margins, contact budget,
  /// solver settings, guard, sleeping). threads, backend and gpuAllowCpuDevice are fixed when
  /// a world is made (its thread pool, its device): d must carry the world's own, as def()
  /// has them, or nothing changes (InvalidArgument). Each change wakes what it affects:
  /// gravity, the time step, solver settings (as setSolverSettings), sleeping turned off or
  /// its thresholds (as setSleepSettings) and the collision margins (a sleeping island keeps
  /// the contacts found with the old ones) wake every sleeping body and restart every awake
  /// body's rest timer (none falls asleep on rest it had before the change); the speed clamps, the
  /// guard and the contact budget wake none (a sleeping body has no speed, is not stepped and
  /// adds no pairs). Lowered clamps apply from the next step on, which clamps faster bodies
  /// (and the guard, on, takes a body at its clamp for one that blew up: it stops it).
  Status setDef(const WorldDef& d);
  /// Every field setDef takes: finite gravity, time step in (0, 1] s, clamps > 0, margins
  /// >= 0, guardEnergyJump >= 0, guardRetries in [0, 1000], and the solver and sleep settings
  /// (validate above).
  static Status validate(const WorldDef& d);

  // Bodies. createBody validates the whole definition (finite numbers, unit quaternion,
  // positive sizes and masses, planes only on static bodies) and creates nothing on error.
  Status createBody(const BodyDef& def, BodyId* out);
  Status destroyBody(BodyId id);  ///< also destroys the body's shapes and joints
  Status setTransform(BodyId id, Vec3 position, Quat rotation);
  Status setVelocity(BodyId id, Vec3 linear, Vec3 angular);
  Status setBodyType(BodyId id, BodyType type);
  /// mass > 0; inertia 0 means scale the current inertia with the mass.
  Status setMass(BodyId id, float mass, Vec3 inertia = {});
  Status setMaterial(BodyId id, const Material& m);               ///< every shape of the body
  Status applyForce(BodyId id, Vec3 force, Vec3 worldPoint);      ///< N, for the next step
  Status applyTorque(BodyId id, Vec3 torque);                     ///< N m, for the next step
  Status applyImpulse(BodyId id, Vec3 impulse, Vec3 worldPoint);  ///< N s, immediately
  /// Whether a body may sleep (BodyDef::allowSleep); false wakes it.
  Status setAllowSleep(BodyId id, bool allow);
  /// Wakes a body's island (and resets its rest timer); a no-op for an awake body.
  Status wakeBody(BodyId id);
  bool isSleeping(BodyId id) const;  ///< false for an unknown id
  int awakeBodyCount() const;        ///< bodies the step moves: not static, not asleep
  void awakeBodies(std::vector<BodyId>* out) const;  ///< those bodies, in index order
  Status getBody(BodyId id, BodyState* out) const;
  /// A body's definition as the world holds it, the one source of what it simulates: type,
  /// pose and velocities now, damping, gravity scale, gyroscopic, allowSleep, name and shapes
  /// (materials as setMaterial left them); mass and inertia as given (0: from the shapes),
  /// both 0 for static and kinematic bodies. Creating a body from it in a world of the same
  /// settings makes the same body. mass (optional): what the world derived from it.
  Status getBodyDef(BodyId id, BodyDef* out, BodyMass* mass = nullptr) const;
  bool isValid(BodyId id) const;
  std::vector<BodyId> bodies() const;  ///< live bodies in index order
  int bodyCount() const;
  /// Shapes of a body (ids), and a shape's definition.
  std::vector<ShapeId> bodyShapes(BodyId id) const;
  Status getShape(ShapeId id, ShapeDef* out, BodyId* body) const;
  Status addShape(BodyId body, const ShapeDef& def, ShapeId* out);  ///< mass recomputed if auto
  Status removeShape(ShapeId id);

  // Joints.
  Status createJoint(const JointDef& def, JointId* out);
  Status destroyJoint(JointId id);
  Status setMotor(JointId id, bool enable, float speed, float maxForce);
  Status getJoint(JointId id, JointDef* def, JointState* state) const;
  std::vector<JointId> joints() const;
  int jointCount() const;

  /// Advances by one fixed step of def().timeStep. Never throws: a step that fails inside
  /// (out of memory) is not taken and is counted in StepStats::stepFailures.
  void step();
  /// Measures states computed by someone else (a peer engine) as if this world had stepped to
  /// them, so MetricsRecorder::afterStep reads them exactly as it reads a step: sets body
  /// ids[i] to states[i] (velocities of static bodies are ignored), advances time() by one
  /// time step and runs the collision stages only (bounds, broad phase, narrow phase: the
  /// contacts and maxPenetration are those of the given states, as a step's are of its start
  /// state). Nothing is solved or integrated. stats() gets energyBefore (the energy before the
  /// update), energyAfter, the contact counts, velocityResidual 0 and the step count; the
  /// joints' positionError and angleError are measured at the given poses (reactions 0);
  /// profile() is all zero but total = stepMs (the other engine's wall time). All-or-nothing:
  /// a size mismatch, a stale id or a non-finite or non-unit state changes nothing.
  Status observe(const std::vector<BodyId>& ids, const std::vector<ObservedBody>& states,
                 double stepMs);
  const StepProfile& profile() const;
  const StepStats& stats() const;
  /// Bytes held by the step's buffers (contacts, pairs, manifolds, rows, SIMD blocks): they
  /// follow the world's activity, given back once a window of 600 steps needed under two
  /// thirds of the pairs they were grown for.
  size_t stepBufferBytes() const;
  const BackendState& backendState() const;
  /// Contacts after the last step (touching or speculative).
  std::vector<ContactInfo> contacts() const;

  /// Total energy (kinetic + gravitational potential), J, in double precision.
  double energy() const;
  /// 64-bit hash of every body's position and rotation bits, in id order (bit exact).
  uint64_t stateHash() const;
  double time() const;  ///< s, simulated time

  /// Serializes the whole world state between steps, bit for bit: the definition (gravity,
  /// time step, solver settings, guard; not `threads`, which results do not depend on),
  /// bodies (with pending forces and torques), shapes (convex hulls included), joints
  /// (motors, warm-start impulses, the last step's reactions that feed geometric stiffness),
  /// persistent contacts with their warm-start impulses, the broad phase's fat boxes, the id
  /// pools (generations and free lists, so ids created after a restore are the same),
  /// simulated time and the step statistics. A world restored from it and stepped M times
  /// has the same stateHash() as this one stepped M times. Fails (out cleared) only when the
  /// state holds a non-finite number, which restoreSnapshot would reject. Format: see
  /// docs/ARCHITECTURE.md "Snapshots".
  Status saveSnapshot(std::vector<uint8_t>* out) const;
  /// Replaces this world's whole state with a snapshot (this world's thread count is kept).
  /// On any error (truncated, corrupted, wrong magic/version, counts over limits, non-finite
  /// numbers, dangling ids) returns an InvalidArgument status whose message says what and
  /// where, and leaves the world unchanged: the snapshot is parsed into a fresh state, which
  /// is swapped in only once all of it has been checked.
  Status restoreSnapshot(const uint8_t* data, size_t size);

  struct Impl;

 private:
  /// The step itself, every stage in order, with `substeps` substeps.
  void stepOnce(int substeps);
  std::unique_ptr<Impl> impl_;
};

}  // namespace phys
