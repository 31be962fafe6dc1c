// Small helpers shared by the world-level tests (the body builders: tests/common/bodies.h).
#pragma once

#include <gtest/gtest.h>

#include "../common/bodies.h"
#include "phys/world.h"

namespace phys::test {

inline BodyId addBody(World& w, const BodyDef& d) {
  BodyId id;
  Status st = w.createBody(d, &id);
  EXPECT_TRUE(st.ok()) << st.message;
  return id;
}

/// A static ground plane z = 0.
inline BodyId addGround(World& w, float friction = 0.6f, float restitution = 0) {
  return addBody(w, groundBody(friction, restitution));
}

inline BodyState stateOf(const World& w, BodyId id) {
  BodyState s;
  EXPECT_TRUE(w.getBody(id, &s).ok());
  return s;
}

}  // namespace phys::test
