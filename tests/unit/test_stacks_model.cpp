// The buckling model of stack stiffening (physics/dynamics/stacks.h) against its independent
// Python implementation, tools/wall_buckling.py, whose pyramid-wall figures are quoted here
// (unit cubes of 1000 kg, g = 9.81; a corner's effective mass is m/8 between two cubes and
// m/4 on the ground). The World-level tests (test_stack_stiffening.cpp) check that the model
// predicts what the solver does.
#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "dynamics/stacks.h"

namespace phys {
namespace {

constexpr double kM = 1000, kG = 9.81, kTwoPi = 6.283185307179586;

/// A pyramid wall of n rows: row r holds n - r cubes on 8 corners each (4 on the ground),
/// at +-0.5 m across the wall: bend = points * m_eff * 0.25 = (n - r) m / 4 either way.
std::vector<StackLevel> wall(int n) {
  std::vector<StackLevel> l;
  for (int r = 0; r < n; ++r) l.push_back({(n - r) * kM, 1.0, (n - r) * kM / 4});
  return l;
}

/// A column of n cubes: 4 corners under each (bend m/8 on a cube, m/4 on the ground).
std::vector<StackLevel> column(int n) {
  std::vector<StackLevel> l;
  for (int r = 0; r < n; ++r) l.push_back({kM, 1.0, r == 0 ? kM / 4 : kM / 8});
  return l;
}

double criticalHertz(const std::vector<StackLevel>& l) {
  return stackCriticalOmega(l, kG, 1.0, 1e5) / kTwoPi;
}

TEST(StackModel, PyramidWallsBuckleWhereTheScriptSays) {
  // tools/wall_buckling.py: 20 rows 20.1 Hz, 40 rows 53.1 Hz, 100 rows 201.1 Hz.
  EXPECT_NEAR(criticalHertz(wall(20)), 20.1, 0.2);
  EXPECT_NEAR(criticalHertz(wall(40)), 53.1, 0.3);
  EXPECT_NEAR(criticalHertz(wall(100)), 201.1, 1.0);
  // Below the critical frequency it falls, above it stands.
  EXPECT_FALSE(stackStands(wall(100), kG, kTwoPi * 195));
  EXPECT_TRUE(stackStands(wall(100), kG, kTwoPi * 207));
}

TEST(StackModel, ColumnsAreMoreSlenderThanWalls) {
  // A column has 4 corners per level whatever its height: 20 cubes need 46.7 Hz (the
  // 20-cube column fell at 30 Hz and stands at 90, docs/ARCHITECTURE.md), 40 need 130 Hz.
  EXPECT_NEAR(criticalHertz(column(20)), 46.7, 0.3);
  EXPECT_NEAR(criticalHertz(column(40)), 129.8, 0.8);
}

TEST(StackModel, StiffnessCannotHoldALevelOnALine) {
  // A level standing on collinear points (bend 0) tips at any stiffness: reported as beyond
  // omegaMax, so that stack stiffening leaves it alone.
  std::vector<StackLevel> l = column(3);
  l[1].bend = 0;
  EXPECT_GT(stackCriticalOmega(l, kG, 1.0, 1e5), 1e5);
  // Zero gravity: anything stands.
  EXPECT_EQ(stackCriticalOmega(wall(100), 0.0, 1.0, 1e5), 0.0);
}

}  // namespace
}  // namespace phys
