// What a world is made with (WorldDef): gravity, the time step, clamps, collision margins,
// the contact budget, the solver's settings, the guard, the backend and sleeping. Plain data;
// World::validate (phys/world/world.h) says which values a world takes.
#pragma once

#include <cstdint>
#include <initializer_list>
#include <string_view>

#include "phys/defs/math.h"
#include "phys/defs/solver_settings.h"

namespace phys {

/// Where a world's step runs. `Auto`: the faster backend for the world's size, by a
/// calibration of the device against the CPU taken once per process when the device opens
/// (docs/ARCHITECTURE.md "backend = auto"), chosen at the first step and again when the
/// world's body count has doubled or halved since. `Gpu` and `Auto` open a Vulkan device
/// (gpu_solver/): a discrete GPU first, then an integrated one; a CPU implementation
/// (lavapipe) only with WorldDef::gpuAllowCpuDevice or PHYS_GPU_ALLOW_CPU=1. With no usable
/// device both run on the CPU and World::backendState() says why. The GPU backend does not
/// cover every stage yet: a step it cannot take is taken by the CPU backend (counted, with
/// the reason).
enum class Backend : uint8_t { Cpu = 0, Gpu = 1, Auto = 2 };
inline const char* toString(Backend b) {
  switch (b) {
    case Backend::Cpu:
      return "cpu";
    case Backend::Gpu:
      return "gpu";
    case Backend::Auto:
      return "auto";
  }
  return "?";
}
/// "cpu", "gpu", "auto"; false (out untouched) for anything else.
inline bool parseBackend(std::string_view text, Backend* out) {
  for (Backend b : {Backend::Cpu, Backend::Gpu, Backend::Auto}) {
    if (text == toString(b)) {
      *out = b;
      return true;
    }
  }
  return false;
}

/// Sleeping (islands): bodies that have rested long enough stop costing anything. Islands
/// are the dynamic bodies joined by touching contacts and joints (static and kinematic
/// bodies do not join them). A body is ready to sleep once, for `time` seconds in a row,
/// |v| <= linearSpeed and |w| <= min(angularSpeed, linearSpeed / r), r its shapes' largest
/// reach from its centre of mass (so a large body must turn more slowly); an island sleeps
/// when every body in it is ready and allows it. A sleeping body is not integrated, solved or
/// collided with static or other sleeping bodies, and its broad-phase proxies stop moving;
/// its velocities are zero. It wakes, with its whole island, when an awake body (or a moving
/// kinematic body) touches it, and on every edit of it or of what holds it (World's edits
/// wake what they touch: see docs/ARCHITECTURE.md "Islands and sleeping").
struct SleepSettings {
  bool enabled = false;       ///< off by default in code; scenes and physd turn it on
  float time = 0.5f;          ///< s, at rest this long before sleeping
  float linearSpeed = 0.05f;  ///< m/s
  float angularSpeed = 0.5f;  ///< rad/s, the cap for small bodies
};

struct WorldDef {
  Vec3 gravity{0, 0, -9.81f};   ///< m/s^2
  float timeStep = 1.0f / 60;   ///< s, the fixed step used by step()
  /// m: bodies are kept within |x|, |y|, |z| <= this (the origin of each): one that leaves
  /// stops at the face it crossed (World::step's last stage; counted in
  /// StepStats::guardQuarantined). The protocol's coordinate range (protocol::Limits::
  /// maxCoordinate) is the same, so every state physd sends can be decoded.
  static constexpr float kWorldExtent = 1e6f;
  float maxLinearSpeed = 1000;  ///< m/s, clamp
  float maxAngularSpeed = 500;  ///< rad/s, clamp
  /// m: every contact closer than this is solved (speculatively when apart); the margin also
  /// grows with the bodies' speeds so fast bodies do not tunnel.
  float speculativeDistance = 0.02f;
  float aabbMargin = 0.05f;  ///< m, broad-phase fattening
  /// Bound on the broad phase's candidate pairs per step, and so on what a step builds from
  /// them (contacts, manifolds, solver rows: its memory and time). 0: automatic,
  /// max(kMinAutoContactPairs, kAutoContactPairsPerShape x shapes). Past the bound the step
  /// keeps the first pairs in shape order (deterministic: they depend only on the bodies'
  /// bounds), leaves the others out, so those bodies may interpenetrate this step, still
  /// completes, and says so in StepStats (pairsDropped, pairLimitSteps). Scenes stay well
  /// below the automatic bound: a lattice of touching boxes has 13 pairs per box, the pile
  /// scenes at most 12.2 per shape; what reaches it is something like thousands of bodies
  /// spawned into one place (20,000 coincident boxes make 200 million pairs).
  uint32_t maxContactPairs = 0;
  static constexpr uint32_t kMinAutoContactPairs = 65536;
  static constexpr uint32_t kAutoContactPairsPerShape = 32;
  /// What a step does when the broad phase finds more pairs than maxContactPairs. Drop: the
  /// pairs past the bound are left out and the step goes on (as above). Refuse: the step is
  /// not taken; the world stays exactly as it was (StepStats::stepsRefused), having cost only
  /// the broad phase, until something moves or removes the crowded bodies. physd uses Refuse,
  /// so that one crowded world costs neither seconds nor gigabytes per tick.
  enum class PairOverflow : uint8_t { Drop, Refuse };
  PairOverflow pairOverflow = PairOverflow::Drop;
  SolverSettings solver;
  /// Threads for the step's parallel loops, the caller included; 0: the machine's hardware
  /// threads (at most 8). Results do not depend on it.
  int threads = 0;
  /// Guard rails: after every step, check for non-finite state, speeds at the clamp, a
  /// dynamic body's centre of mass moving more than 2 x (maxLinearSpeed + solver.maxPushout)
  /// x timeStep, and energy jumps; on a violation roll the step back and redo it with twice
  /// the substeps (up to guardRetries times), then stop the bodies still at fault (and zero
  /// the non-finite joint impulses). Costs a copy of the bodies' state and the contacts per
  /// step. (Bodies leaving kWorldExtent are stopped at its edge with or without the guard.)
  bool guard = true;
  /// An energy gain in one step above guardEnergyJump * kinetic energy + the energy of
  /// lifting every dynamic body by 0.1 m counts as an explosion.
  float guardEnergyJump = 0.5f;
  int guardRetries = 2;
  Backend backend = Backend::Cpu;
  bool gpuAllowCpuDevice = false;  ///< let the GPU backend run on a CPU Vulkan device (tests)
  /// Islands and sleeping, on either backend (the same decisions; docs/ARCHITECTURE.md).
  SleepSettings sleep;
};

/// The world settings a living world may change (World::setDef; the protocol's SetWorld,
/// WorldSettings and snapshots), one row each, in the wire order (physics.fbs's WorldSettings
/// table): the protocol's WorldOverrides, its from() and empty(), its writer and converter and
/// the Python client's set_world keywords and WorldSettings properties are generated from it
/// (docs/ARCHITECTURE.md, "Adding a world setting"). WorldDef above keeps the defaults and
/// what each does; the value rules (decoder.cpp, World::validate) and physics.fbs are by hand.
///
///   X(type, member, path, name)
///
/// member: WorldOverrides' field; path: the WorldDef field it sets (def.path); name: the wire
/// field (its FlatBuffers accessor and add_ setter) and Python's keyword.
#define PHYS_WORLD_FIELDS(X)                                                   \
  X(phys::Vec3, gravity, gravity, gravity)                                     \
  X(float, timeStep, timeStep, time_step)                                      \
  X(bool, sleep, sleep.enabled, sleep)                                         \
  X(float, sleepTime, sleep.time, sleep_time)                                  \
  X(float, sleepLinearSpeed, sleep.linearSpeed, sleep_linear_speed)            \
  X(float, sleepAngularSpeed, sleep.angularSpeed, sleep_angular_speed)         \
  X(float, maxLinearSpeed, maxLinearSpeed, max_linear_speed)                   \
  X(float, maxAngularSpeed, maxAngularSpeed, max_angular_speed)                \
  X(float, speculativeDistance, speculativeDistance, speculative_distance)     \
  X(float, aabbMargin, aabbMargin, aabb_margin)                                \
  X(bool, guard, guard, guard)                                                 \
  X(float, guardEnergyJump, guardEnergyJump, guard_energy_jump)                \
  X(int, guardRetries, guardRetries, guard_retries)

}  // namespace phys
