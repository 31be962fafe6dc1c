// What the GPU backend's test files share: the world-level helpers (tests/unit/test_util.h)
// and skipping a test where no Vulkan device can be opened at all.
#pragma once

#include <algorithm>
#include <vector>

#include "../unit/test_util.h"

namespace phys::test {

/// Largest joint error (m) of `joints` in a world now.
inline float worstJointError(const World& w, const std::vector<JointId>& joints) {
  float worst = 0;
  for (JointId j : joints) {
    JointState st;
    EXPECT_TRUE(w.getJoint(j, nullptr, &st).ok());
    worst = std::max(worst, st.positionError);
  }
  return worst;
}

}  // namespace phys::test

/// Skips the test when no Vulkan device can be opened at all (no loader or driver).
#define REQUIRE_DEVICE(world)                                              \
  do {                                                                     \
    if ((world).backendState().active != ::phys::Backend::Gpu)            \
      GTEST_SKIP() << "no Vulkan device: " << (world).backendState().note; \
  } while (0)
