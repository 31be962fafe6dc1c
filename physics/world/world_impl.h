// Private state of a World, shared by world.cpp (the API), step.cpp (the step and its
// stages), snapshot.cpp and world_gpu.cpp (the device's side). The joint and contact records
// are the dynamics' (physics/dynamics/records.h).
#pragma once

#include <algorithm>
#include <atomic>
#include <exception>

#include <cstdint>
#include <unordered_set>
#include <vector>

#include "phys/collision/broadphase.h"
#include "phys/world/world.h"
#include "dynamics/impacts.h"
#include "dynamics/joints.h"
#include "dynamics/records.h"
#include "dynamics/solver.h"
#include "dynamics/solver_contact_direct.h"
#include "dynamics/solver_ldl.h"
#include "dynamics/solver_wide.h"
#include "dynamics/stacks.h"
#include "base/disjoint_sets.h"
#include "base/thread_pool.h"

namespace phys {

/// Thrown by a step's broad phase (CPU or device) when its pairs pass the bound under
/// WorldDef::PairOverflow::Refuse; World::step undoes the step (Impl::stepRefused).
struct PairLimitReached : std::exception {
  const char* what() const noexcept override { return "contact pair bound reached"; }
};

struct ShapeRec {
  BodyId body;
  ShapeDef def;
  int32_t proxy = -1;
  float boundRadius = 0;  ///< m, max distance of the shape's surface from the body's centre of mass
};

struct BodyRec {
  BodyType type = BodyType::Dynamic;
  Transform xf;      ///< body frame
  Vec3 localCenter;  ///< centre of mass in the body frame
  Vec3 com;          ///< centre of mass in the world
  Vec3 v, w;         ///< m/s, rad/s (world)
  float mass = 0, invMass = 0;
  Mat3 inertiaLocal = Mat3::zero();  ///< about the centre of mass, body axes
  Mat3 invInertiaLocal = Mat3::zero();
  Quat principal;                  ///< principal axes frame -> body frame
  Vec3 principalMoments{1, 1, 1};  ///< kg m^2, eigenvalues of inertiaLocal
  float linearDamping = 0, angularDamping = 0, gravityScale = 1;
  bool gyroscopic = true;
  bool autoMass = true;  ///< mass from shapes
  float givenMass = 0;   ///< when !autoMass
  Vec3 givenInertia;     ///< when nonzero
  Vec3 force, torque;    ///< accumulated for the next step
  std::vector<ShapeId> shapes;
  std::vector<JointId> joints;
  std::string name;
  int32_t solverIndex = -1;  ///< this step's index into the solver body array, 0 if static or asleep
  int32_t deviceIndex = -1;  ///< index among the GPU backend's bodies, -1 if static or none
  bool allowSleep = true;
  float sleepTime = 0;  ///< s, how long the body has been slow enough to sleep
  int32_t island = -1;  ///< its sleeping island (World::Impl::islands), -1 when awake
  /// Stepped by the CPU inside a device step (world_gpu_islands.cpp): on the device as a
  /// sleeping body (not moved, immovable to what touches it).
  bool held = false;
  bool asleep() const { return island >= 0; }
  /// In the step: not static and not asleep (World::Impl::awakeBodies).
  bool awake() const { return type != BodyType::Static && island < 0; }
};

/// What the joints' rows read of a body (joints.h).
inline BodyPose poseOf(const BodyRec& b) {
  return {b.xf.q, b.com, b.localCenter};
}

/// Warm-start impulses are per substep: the factor that takes impulses solved with substeps of
/// `before` s to substeps of `after` s, keeping the forces they stand for; 1 when there is
/// nothing to scale. Bounded, so that a corrupt or absurd unit cannot blow them up.
/// A dynamic body's kinetic plus potential energy (J), as World::energy sums it. Shared by
/// energy() and the guard's copy (takeSnapshot), which sums the same terms in the same
/// order in the pass it makes anyway (the build has no floating-point contraction: the same
/// bits in either place).
inline double bodyEnergy(const BodyRec& b, Vec3 g) {
  const Vec3 wb = invRotate(b.xf.q, b.w);
  const Vec3 Iw = b.inertiaLocal * wb;
  const double ke =
      0.5 * b.mass * (double(b.v.x) * b.v.x + double(b.v.y) * b.v.y + double(b.v.z) * b.v.z) +
      0.5 * (double(wb.x) * Iw.x + double(wb.y) * Iw.y + double(wb.z) * Iw.z);
  const double pe = -double(b.mass) * b.gravityScale *
                    (double(g.x) * b.com.x + double(g.y) * b.com.y + double(g.z) * b.com.z);
  return ke + pe;
}

inline float impulseScale(float before, float after) {
  if (!(before > 0) || !(after > 0) || before == after) return 1;
  return std::clamp(after / before, 1e-4f, 1e4f);
}
inline void scaleImpulses(std::vector<Contact>* contacts, float k) {
  for (Contact& c : *contacts) {
    for (float& f : c.normalImpulse) f *= k;
    for (auto& t : c.tangentImpulse) t[0] *= k, t[1] *= k;
  }
}

/// Dynamic bodies asleep together (islands.cpp): they woke together and sleep together.
struct SleepingIsland {
  std::vector<uint32_t> bodies;   ///< body slots, ascending; empty: a free slot
  std::vector<Contact> contacts;  ///< their touching contacts, sorted by shape pair
  float substepTime = 0;          ///< the contacts' impulses' unit (StepStats::substepTime)
  double potential = 0;           ///< J, the bodies' potential energy (they are at rest)
};

/// What a step changes, kept to roll it back (guard rails).
struct Snapshot {
  struct Body {
    uint32_t index;
    Transform xf;
    Vec3 com, v, w, force, torque;
  };
  struct JointImpulses {
    uint32_t index;
    int32_t count;
    float impulses[JointRec::kMaxRows];
  };
  std::vector<Body> bodies;  ///< non-static bodies
  std::vector<Contact> contacts;
  std::vector<JointImpulses> jointImpulses;
  double time = 0;
  uint64_t step = 0;
  float substepTime = 0;  ///< StepStats::substepTime: the contacts' impulses' unit
  double kinetic = 0;     ///< J, kinetic energy at the step start
  double liftEnergy = 0;  ///< J, lifting every dynamic body by 0.1 m (the jump floor)
};

/// The GPU backend's part of a world (world_gpu.cpp).
struct DeviceWorld;
struct DeviceWorldDeleter {
  void operator()(DeviceWorld* d) const;
};

/// What makes the same body in a world of the same settings (World::getBodyDef, and the
/// GPU backend's private CPU world, world_gpu_islands.cpp).
BodyDef bodyDefOf(const Pool<ShapeRec, ShapeTag>& shapes, const BodyRec& b);

/// The GPU backend's islands stepped by the CPU (world_gpu_islands.cpp).
struct CpuIslands;
struct CpuIslandsDeleter {
  void operator()(CpuIslands* c) const;
};

struct World::Impl {
  WorldDef def;
  Pool<BodyRec, BodyTag> bodies;
  Pool<ShapeRec, ShapeTag> shapes;
  Pool<JointRec, JointTag> joints;
  BroadPhase broadPhase;
  std::vector<ProxyPair> pairs;
  std::vector<Contact> contacts;  ///< sorted by (shapeA, shapeB)
  std::vector<Contact> contactScratch;
  /// updateBounds' scratch, per shape slot: this step's tight box, and whether it left the
  /// proxy's fat box.
  std::vector<AABB> boundsTight;
  std::vector<uint8_t> boundsLeft;
  std::unordered_set<uint64_t> noCollide;  ///< body index pairs joined without collideConnected
  std::unique_ptr<ThreadPool> pool;        ///< null with one thread
  /// The passes over every awake body that the step's guard and the device step's mirror
  /// make (the guard's copy and check, keepInsideWorld, the step's energies, the mirror):
  /// fn(begin, end) over [0, n) on the world's threads, inline without a pool. Each index
  /// writes its own slots; sums are formed afterwards in index order (the same bits as one
  /// thread, whatever the threads: thread_pool.h).
  template <class F>
  void forEachRange(size_t n, F&& fn) const {
    constexpr size_t kBodyGrain = 2048;  // a pass over a few thousand bodies runs inline
    if (pool)
      pool->parallelFor(n, kBodyGrain, fn);
    else if (n > 0)
      fn(size_t(0), n);
  }
  /// Whether pred holds for a contact of this step's (contactOrder), looked for on the world's
  /// threads.
  template <class P>
  bool anyContact(P&& pred) const {
    std::atomic<bool> found{false};
    forEachRange(contactOrder.size(), [&](size_t begin, size_t end) {
      for (size_t k = begin; k < end && !found.load(std::memory_order_relaxed); ++k)
        if (pred(contacts[contactOrder[k]])) found.store(true, std::memory_order_relaxed);
    });
    return found.load();
  }
  /// Lowers `first` to k if k is below it: a parallel pass's first index found (the lowest,
  /// whichever thread found it, so the result is one thread's).
  static void lowerTo(std::atomic<size_t>& first, size_t k) {
    size_t seen = first.load(std::memory_order_relaxed);
    while (k < seen && !first.compare_exchange_weak(seen, k, std::memory_order_relaxed)) {
    }
  }
  /// Per awake body, the terms that a pass sums afterwards in order (forEachRange): the
  /// world's energy (bodyEnergy), and for the guard's copy the kinetic energy and the lift.
  struct EnergyTerms {
    double energy, kinetic, lift;
  };
  std::vector<EnergyTerms> energyTerms;
  /// World::energy's sum, its per-body terms formed on the world's threads (the step's
  /// energyAfter and energyBefore): the same bits as World::energy.
  double stepEnergy();
  Solver solver;
  WideContacts wide;  ///< the Gauss-Seidel scheme's contacts in SIMD lanes (solver_wide.h)
  /// With wide contacts: this step's manifolds (instead of contact rows) and their contacts.
  std::vector<SolverManifold> manifolds;
  std::vector<uint32_t> manifoldContact;
  /// This step's contacts went to the solver as rows (Contact::firstRow), not manifolds.
  bool contactRowsBuilt = false;
  /// The Gauss-Seidel order of this step's touching contacts and its nested parts
  /// (solver_wide.h), and per solver body its centre of mass and leaf part.
  std::vector<uint32_t> contactOrder;
  ContactParts contactParts;
  std::vector<Vec3> solverCom;
  std::vector<uint8_t> solverPart;
  EqualityLdl ldl;  ///< the joints' direct solve (equality = direct_ldl)
  /// The contact normal rows of mass-ratio islands, solved directly (directContactRatio).
  DirectContacts directContacts;
  /// The elastic contacts' normal rows for restitution's collision phase (impacts.h).
  Impacts impacts;
  /// Per entry of contactOrder: the mass-ratio island whose direct solve takes its normal
  /// rows (a solver body index, the island's root), or -1.
  std::vector<int32_t> directIsland;
  Snapshot snapshot;
  // Islands and sleeping (islands.cpp).
  /// Slots of the bodies the step moves (not static, not asleep), ascending: every per-body
  /// stage walks this list, so a world's cost follows its awake bodies.
  std::vector<uint32_t> awakeBodies;
  std::vector<SleepingIsland> islands;  ///< by island index (BodyRec::island)
  std::vector<uint32_t> freeIslands;    ///< empty island slots; the next one is the back
  int sleepingBodyCount = 0;
  bool lastStepOnCpu = false;  ///< the last stepOnce ran the CPU stages (not the device)
  /// Joint slots the step solves (not asleep), ascending: collectStepJoints.
  std::vector<uint32_t> stepJoints;
  DisjointSets islandSets;  ///< updateSleep's scratch: union-find over awakeBodies
  std::vector<uint32_t> wakeList;     ///< wakeTouched's scratch: islands to wake
  void awakeInsert(uint32_t slot);    ///< a body became awake (created, woken, made non-static)
  void awakeErase(uint32_t slot);     ///< a body left the step (destroyed, made static)
  void rebuildAwake();                ///< awakeBodies and the counts from the bodies (restore)
  bool sleepActive() const { return def.sleep.enabled; }
  /// A device step's touching pairs (body slots, contacts with points between non-static
  /// bodies: the device's touch list), read back for the islands (updateSleep's edges when
  /// the device took the step).
  std::vector<std::pair<uint32_t, uint32_t>> deviceTouches;
  /// Wakes island k: its bodies join the step with their timers reset, their proxies move
  /// again, their contacts rejoin the list. Inside a step the guard's copy gets them too.
  void wakeIsland(int32_t k);
  void wakeAll();
  /// A change of a setting every body feels (gravity, time step, solver, sleep thresholds,
  /// margins): wakes every island and resets the rest timer of every awake body too, so that
  /// none falls asleep on time it rested under the old setting before the new one moved it.
  void wakeEverything();
  /// An edit of body `slot`: wakes its island and resets its timer.
  void wake(uint32_t slot);
  /// ... and wakes whatever its shapes' fat boxes overlap and whatever is jointed to it (the
  /// edit may change what holds them: a moved, removed or reshaped body).
  void wakeNeighbours(uint32_t slot);
  /// After the narrow phase: islands touched by an awake body or a moving kinematic body
  /// (contacts with points, joints) wake.
  void wakeTouched();
  /// wakeTouched's second half: islands jointed to a moving kinematic body (known before the
  /// step: the device's step calls it first).
  void wakeJointedToMovingKinematic();
  /// Whether a touch of a sleeping body by `other` wakes it: not by a static body, nor by a
  /// kinematic one at rest (it holds what sleeps on it).
  static bool wakesSleeper(const BodyRec& other);
  /// After an accepted step (CPU or device): rest timers, islands of the awake dynamic
  /// bodies, and the islands whose bodies all rested long enough fall asleep.
  void updateSleep(float dt);
  void collectStepJoints();
  /// The sleeping islands' potential energy, summed in island order; cached until an island
  /// sleeps or wakes (a world of 10,000 one-body islands would sum them twice a step).
  double sleepingPotential() const;
  mutable double sleepingPotentialSum = 0;
  mutable bool sleepingPotentialValid = false;
  StepProfile profile;
  StepStats stats;
  double time = 0;
  // The GPU backend (world_gpu.cpp): null on the CPU backend.
  BackendState backend;
  std::unique_ptr<DeviceWorld, DeviceWorldDeleter> device;

  // Helpers shared by the source files.
  void updateMass(BodyRec& b);
  /// What the broad phase takes for static: static bodies and sleeping ones (no pairs with
  /// each other).
  static bool proxyStatic(const BodyRec& b) { return b.type == BodyType::Static || b.asleep(); }
  void syncProxies(BodyId id, bool moved);
  Transform shapeTransform(const BodyRec& b, const ShapeRec& s) const { return b.xf * s.def.local; }
  static uint64_t bodyPairKey(uint32_t a, uint32_t b) {
    return a < b ? (uint64_t(a) << 32 | b) : (uint64_t(b) << 32 | a);
  }
  void rebuildNoCollide();

  // Step stages (in step.cpp), in order.
  void applyCommands();
  void updateBounds(float h);
  void broadPhaseStage();
  void narrowPhase(float h);
  /// Stack stiffening (SolverSettings::stackStiffening): the contact frequency and substeps
  /// this step's stacks need, into `s`; measureStacks finds the frequency (StepStats) with
  /// `stacks` (physics/dynamics/stacks.h).
  void stiffenForStacks(float dt, SolverSettings* s);
  void measureStacks(float dt, const SolverSettings& s);
  /// The measured stacks are for other settings (gravity, time step, contact frequency,
  /// substeps): the preset's until the next measuring step (deterministic: StepStats).
  void forgetStacks() {
    stats.stackDepth = 0;
    stats.stackHertz = 0;
  }
  /// Scales the stored warm-start impulses (per substep) to substeps of length h.
  void rescaleWarmStarts(float h);
  /// measureStacks' scratch, and what it passes of each body slot.
  StackScratch stacks;
  std::vector<StackBody> stackBodies;
  /// Fills contactOrder; with nested parts (solver_wide.h) returns true and fills `parts`.
  bool orderContacts(const SolverSettings& s, ContactParts& parts);
  /// Finds the islands of contactOrder's contacts in which a dynamic body touches one
  /// directContactRatio times lighter or heavier, small enough for the direct solve, and
  /// fills directIsland. Returns whether there are any.
  bool findDirectContactIslands(const SolverSettings& s);
  /// At the end of a step with collisions (impacts.h): in each island of touching bodies
  /// whose velocities the collisions changed (`before`: the solver bodies' velocities less
  /// those changes), scales the changes down, where needed, so that the island's kinetic
  /// energy ends no higher than at the step's start plus the work its forces did over the
  /// step. Returns the islands scaled.
  int limitRestitutionEnergy(const std::vector<Velocity>& before);
  std::vector<Velocity> beforeRestitution;
  void buildSolverBodies(const SolverSettings& s);  ///< s: this step's (substeps may differ)
  /// Joints' geometric stiffness added to the solver bodies' inertia (substep h).
  void addGeometricStiffness(float h);
  /// Joints' geometric stiffness per body slot, from last step's joint forces.
  std::vector<float> jointStiffness() const;
  /// A contact in the solver's terms (its points relative to the centres of mass, warm start).
  SolverManifold solverManifold(const Contact& c, const SolverSettings& s) const;
  void contactRowsOf(const Contact& c, const SolverManifold& m);  ///< appended
  void refreshJoints(float h);
  void storeImpulses();  ///< rows' impulses back to contacts and joints (warm starting)
  // GPU backend (world_gpu.cpp).
  void openDevice();                 ///< at construction, for Backend::Gpu and Auto
  void deviceEdited(uint32_t slot);  ///< a body's pose, velocity or forces changed
  void deviceStale();                ///< anything else changed: everything goes up again
  void deviceJointsChanged();        ///< a joint fell asleep or woke: the device's set changes
  /// Whether this step goes to the device: a GPU world's always, an auto world's when its
  /// size is past the calibrated crossover (chosen again when its body count doubles or halves).
  bool deviceTakesStep();
  /// The step on the device; false (the CPU takes it) when the device cannot take it.
  bool stepOnDevice(int substeps);
  void uploadToDevice();        ///< stepOnDevice's: what changed on the host goes up
  bool wakeTouchedOnDevice();   ///< stepOnDevice's: wakes what its step found touched
  // Islands on the CPU beside the device (world_gpu_islands.cpp; docs/ARCHITECTURE.md
  // "Islands on the CPU beside the device").
  std::unique_ptr<CpuIslands, CpuIslandsDeleter> cpuIslands;
  /// Before the device step: which islands the CPU steps (from the last step's touching
  /// pairs), held on the device. Returns whether any island could need the CPU (the device
  /// then reads its touching pairs back).
  bool cpuIslandsBegin(bool structureChanged);
  /// After a device step, its touching pairs (body slots): whether islands joined the held
  /// set (the device step is then undone and taken again).
  bool cpuIslandsGrow(const std::vector<std::pair<uint32_t, uint32_t>>& deviceNow);
  void cpuIslandsStep(int substeps);  ///< the held islands' step on the CPU, into the mirror
  void cpuIslandsFinish();            ///< their touches and statistics into the step's
  bool cpuIslandsWatch() const;
  std::vector<uint32_t> chooseCpuIslands(const std::vector<std::pair<uint32_t, uint32_t>>& touches,
                                         uint32_t* reasons, int* islandCount);
  bool holdCpuIslands(std::vector<uint32_t> next);
  void buildCpuIslandWorld();
  /// The device step's touching pairs (body slots of manifolds with points, static bodies
  /// included), read back with StepInput::readContacts.
  void deviceTouchingPairs(std::vector<std::pair<uint32_t, uint32_t>>* out) const;
  /// The contact pair bound this step runs under (WorldDef::maxContactPairs resolved).
  uint32_t pairLimit() const;
  /// Whether the joints' direct solve (DirectLdl) stays small this step: no dynamic body in
  /// more than kMaxDirectRowsPerBody equality rows (a body's rows make a dense block).
  bool directSolveFits();
  static constexpr uint32_t kMaxDirectRowsPerBody = 512;
  std::vector<uint32_t> equalityRowsAt;  ///< its scratch: equality rows per solver body
  // Guard rails (step.cpp).
  /// A step threw: put the world back as it was before it, free the step's buffers and count
  /// it (StepStats::stepFailures).
  void stepFailed(const char* what) noexcept;
  /// The step's buffers (contacts' scratch and guard copy, pairs, manifolds, rows, SIMD
  /// blocks) back to the allocator; the next step grows them again.
  void releaseStepBuffers() noexcept;
  /// After an accepted step: the step's buffers follow the world's activity (step.cpp).
  struct ActivityWindow {
    static constexpr int kSteps = 600;  ///< a window: 10 s at 60 Hz
    /// What the buffers are sized by (contact pairs, awake bodies), seen after each step.
    struct Demand {
      static constexpr size_t kMin = 256;  ///< buffers grown for less are left alone
      size_t window = 0;    ///< the most of a step in this window
      size_t grownFor = 0;  ///< the most the buffers served since their last release
      void see(size_t n) {
        window = std::max(window, n);
        grownFor = std::max(grownFor, n);
      }
      /// The window needed under two thirds of what the buffers were grown for.
      bool fell() const { return grownFor >= kMin && window * 3 < grownFor * 2; }
      /// A new window; after a release the buffers are grown for this one's needs.
      void next(bool released) {
        if (released) grownFor = window;
        window = 0;
      }
    };
    int steps = 0;
    Demand pairs, bodies;
  } activity;
  void followActivity() noexcept;
  /// The step passed the pair bound under PairOverflow::Refuse: undone like a failed step,
  /// counted as refused.
  void stepRefused() noexcept;
  bool snapshotValid = false;  ///< `snapshot` holds this step's start (takeSnapshot finished)
  /// The world's energy (World::energy) summed by takeSnapshot in its pass over the awake
  /// bodies, for the stepOnce that follows it at once (its energyBefore); used once.
  bool snapshotEnergyKnown = false;
  double snapshotEnergy = 0;
  bool stepTouched = false;    ///< this step's stepOnce has begun changing the world
  /// The broad phase built again from its proxies' fat boxes (the same pairs), aside and
  /// swapped in; the shapes get their new proxies.
  void rebuildBroadPhase();
  void takeSnapshot();
  /// Back to the guard's copy. moveContacts: the copy's contacts are swapped in rather than
  /// copied (nothing allocates: a failed step's undo), leaving the copy without them.
  void restoreSnapshot(bool moveContacts = false);
  std::string checkHealth() const;                ///< empty when the step was healthy
  /// The health check's quick test, without square roots: true when a body is certainly
  /// healthy after the step (`before`: its state when the step began); the others take
  /// bodyFault's exact tests, whose verdict it is.
  struct QuickHealth {
    float vMax, wMax, dMax;
    bool clear(const BodyRec& b, const Snapshot::Body& before) const;
  };
  QuickHealth quickHealth() const;
  /// A body strictly inside WorldDef::kWorldExtent on every axis (keepInsideWorld leaves it).
  static bool insideExtent(const BodyRec& b);
  /// What the device step's mirror pass (stepOnDevice) found on its way over the awake
  /// bodies, so that the passes after it need not go over them again: the step's energy
  /// (World::energy's sum, for energyAfter), and where the health check (in the guard's
  /// copy) and keepInsideWorld (in awakeBodies) must begin: every body before those was
  /// found clear by the same quick tests on the same states. Valid from that pass until the
  /// bodies change again (a retry's restore, quarantine, the next stepOnce).
  struct MirrorScan {
    bool valid = false;
    double energy = 0;
    size_t healthFrom = 0, insideFrom = 0;
  } mirrorScan;
  /// What is wrong with a body after a step (before: its state when the step began), or null.
  const char* bodyFault(const BodyRec& b, const Snapshot::Body& before) const;
  void quarantine();  ///< joint rows at the current poses, inside the substep loop
  bool jointAsleep(const JointRec& j) const;  ///< its island sleeps
  /// Stops every moving body outside WorldDef::kWorldExtent at the extent's face.
  void keepInsideWorld();
  void finalize(float hSub);
  void measureJoints();  ///< joints' position and angle errors at the bodies' poses
};

}  // namespace phys
