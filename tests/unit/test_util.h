// Small helpers shared by the world-level tests (the body builders: tests/common/bodies.h).
#pragma once

#include <gtest/gtest.h>

#include <string>

#include "../common/bodies.h"
#include "phys/scene/scene.h"
#include "phys/world/world.h"

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

/// configs/scenes/NAME.json of the source tree (a load failure is reported as a test failure
/// and leaves the scene empty).
inline Scene loadScene(const std::string& name) {
  Scene s;
  Status st = loadSceneFile(std::string(PHYS_SOURCE_DIR) + "/configs/scenes/" + name + ".json", &s);
  EXPECT_TRUE(st.ok()) << name << ": " << st.message;
  return s;
}

/// A scene from JSON text (a parse failure is reported as a test failure and leaves the scene
/// empty).
inline Scene sceneFromJson(const std::string& json) {
  Scene s;
  Status st = parseScene(json, "inline", &s);
  EXPECT_TRUE(st.ok()) << st.message;
  return s;
}

inline BodyState stateOf(const World& w, BodyId id) {
  BodyState s;
  EXPECT_TRUE(w.getBody(id, &s).ok());
  return s;
}

}  // namespace phys::test
