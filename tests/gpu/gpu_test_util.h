// What the GPU backend's test files share: the world-level helpers (tests/unit/test_util.h)
// and skipping a test where no Vulkan device can be opened at all.
#pragma once

#include "../unit/test_util.h"

/// Skips the test when no Vulkan device can be opened at all (no loader or driver).
#define REQUIRE_DEVICE(world)                                              \
  do {                                                                     \
    if ((world).backendState().active != ::phys::Backend::Gpu)            \
      GTEST_SKIP() << "no Vulkan device: " << (world).backendState().note; \
  } while (0)
