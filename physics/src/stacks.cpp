#include "stacks.h"

#include <cmath>

namespace phys {

bool stackStands(std::span<const StackLevel> levels, double g, double omega) {
  // T = omega^2 K - G with K the springs between levels (level 0 on the ground) and G
  // gravity's diagonal; positive definite iff every LDL^T pivot is positive.
  const double w2 = omega * omega;
  const size_t n = levels.size();
  double above = 0;  // mass of the levels above the current one
  double pivot = 0;
  // From the top down, so that the mass above each level accumulates as we go.
  for (size_t k = 0; k < n; ++k) {
    const size_t d = n - 1 - k;
    above += levels[d].mass;
    const double springBelow = w2 * levels[d].bend;
    const double springAbove = d + 1 < n ? w2 * levels[d + 1].bend : 0;
    const double diag = springBelow + springAbove - g * levels[d].height * above;
    // The coupling with the level above is -springAbove.
    pivot = k == 0 ? diag : diag - springAbove * springAbove / pivot;
    if (!(pivot > 0)) return false;
  }
  return true;
}

double stackCriticalOmega(std::span<const StackLevel> levels, double g, double omegaMin,
                          double omegaMax) {
  if (stackStands(levels, g, omegaMin)) return 0;
  if (!stackStands(levels, g, omegaMax)) return 2 * omegaMax;
  double lo = omegaMin, hi = omegaMax;
  while (hi - lo > 1e-3 * hi) {
    const double mid = 0.5 * (lo + hi);
    (stackStands(levels, g, mid) ? hi : lo) = mid;
  }
  return hi;
}

}  // namespace phys
