// What the GPU backend's test files share: adding a body, reading its state, and skipping a
// test where no Vulkan device can be opened at all.
#pragma once

#include <gtest/gtest.h>

#include "phys/world/world.h"

namespace phys::gpu_test {

inline BodyId add(World& w, const BodyDef& d) {
  BodyId id;
  Status st = w.createBody(d, &id);
  EXPECT_TRUE(st.ok()) << st.message;
  return id;
}

inline BodyState state(const World& w, BodyId id) {
  BodyState s;
  EXPECT_TRUE(w.getBody(id, &s).ok());
  return s;
}

}  // namespace phys::gpu_test

/// Skips the test when no Vulkan device can be opened at all (no loader or driver).
#define REQUIRE_DEVICE(world)                                              \
  do {                                                                     \
    if ((world).backendState().active != ::phys::Backend::Gpu)            \
      GTEST_SKIP() << "no Vulkan device: " << (world).backendState().note; \
  } while (0)
