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
// stacks.cpp also holds the world's side (World::Impl::stiffenForStacks, measureStacks):
// finding the stacks and their levels in a step's contacts.
#pragma once

#include <span>

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

}  // namespace phys
