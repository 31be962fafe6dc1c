// Buckling of stacks on soft contacts (SolverSettings::stackStiffening).
//
// A stack is cut into levels by support depth (bodies one contact above the ground, two, ...).
// Each level is taken as rigid, standing on the contact points under it; a soft contact of
// effective mass m_eff at frequency omega is a spring m_eff omega^2, so the points resist a
// tilt of the level above them by omega^2 * bend, bend = sum m_eff (y - y_c)^2 about their
// centre along the softest horizontal axis. Gravity pushes a tilt theta of level d on by
// g * height_d * (mass of levels >= d) * theta. The stack stands while the tridiagonal
// stiffness minus that is positive definite (tools/wall_buckling.py is the same model for a
// pyramid wall). It predicts pyramid_100's lean at 90 Hz and, for a column, the 20-cube
// column's fall at 30 Hz (docs/ARCHITECTURE.md, "Tall stacks").
//
// stacks.cpp also finds the stacks and their levels in a step's contacts (StackScratch), for
// World::Impl::stiffenForStacks (step.cpp), which passes what it reads of the world.
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include "phys/defs/ids.h"
#include "phys/defs/math.h"
#include "phys/defs/solver_settings.h"
#include "base/disjoint_sets.h"
#include "dynamics/records.h"

namespace phys {

struct StackLevel {
  double mass = 0;    ///< kg, the level's bodies
  double height = 0;  ///< m, the level's height (its bodies' mean rise above the level under)
  double bend = 0;    ///< kg m^2, sum of m_eff (y - y_c)^2 over the points under the level
};

/// True when `levels` (bottom first) stand under gravity g on contacts at angular frequency
/// omega (rad/s).
bool stackStands(std::span<const StackLevel> levels, double g, double omega);

/// The smallest omega (rad/s, to 0.1 %) at which `levels` stand, if it is at most omegaMax;
/// 0 when they stand at omegaMin already, and omegaMax * 2 when no omega up to omegaMax
/// holds them (a level on one point or on a line: stiffness cannot help).
double stackCriticalOmega(std::span<const StackLevel> levels, double g, double omegaMin,
                          double omegaMax);

/// What the stacks read of a body (the world fills one per body slot).
struct StackBody {
  Vec3 com;  ///< centre of mass (world)
  float mass = 0, invMass = 0;
  bool dynamic = false;  ///< static and kinematic bodies are the ground stacks stand on
  bool asleep = false;
};

/// What measuring a step's stacks reads of the world.
struct StackInput {
  std::span<const StackBody> bodies;  ///< by body slot
  const Pool<JointRec, JointTag>& joints;
  std::span<const Contact> contacts;  ///< the step's, after the narrow phase
  Vec3 gravity;
  float speculativeDistance = 0;  ///< m, WorldDef::speculativeDistance
};

/// The stacks measured (StepStats::stackDepth, stackHertz).
struct StackMeasure {
  int depth = 0;    ///< bodies in the deepest support chain
  float hertz = 0;  ///< Hz, the contact frequency the stacks need; 0: the preset's holds them
};

/// Finds a step's stacks and their levels and what holds them. Its vectors are scratch that
/// the world keeps from step to step (World::Impl::stacks), for their buffers.
struct StackScratch {
  StackMeasure measureStacks(const StackInput& in, float dt, const SolverSettings& s);
  /// stackDirectContact for measureStacks: findDirectContactIslands's rule (step.cpp) over the
  /// bodies' own indices (it runs before the step's solver bodies exist), for every touching
  /// contact.
  void directContactsByBody(const StackInput& in, const SolverSettings& s);

  /// Per body (index) its support depth, adjacency head, union-find parent and (for a root)
  /// its stack's index; per contact whether it supports and its adjacency links; per stack
  /// its deepest level and its first level in stackLevels.
  std::vector<int32_t> stackDepth, stackHead, stackNext, stackQueue, stackRoot, stackIndex,
      stackDeepest, stackFirstLevel;
  std::vector<uint8_t> stackSupport;
  std::vector<float> stackRise;
  struct LevelSums {
    double mass = 0, rise = 0, w = 0, wx = 0, wy = 0, wxx = 0, wxy = 0, wyy = 0;
    int bodies = 0;
  };
  std::vector<LevelSums> stackLevels;
  std::vector<StackLevel> stackModel;
  /// Per contact, whether the direct solve would take it (directContactsByBody); per stack,
  /// whether one of its support contacts is such (the stack is then not stiffened).
  std::vector<uint8_t> stackDirectContact, stackOnDirect;
  // directContactsByBody's scratch (per body).
  DisjointSets directSets;
  std::vector<uint8_t> directJointed;
  std::vector<int32_t> directRows, directHeavy;
};

}  // namespace phys
