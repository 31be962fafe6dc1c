// Small builders shared by the world-level tests.
#pragma once

#include <gtest/gtest.h>

#include "phys/world.h"

namespace phys::test {

inline BodyDef sphereBody(Vec3 p, float r, float density = 1000) {
  BodyDef d;
  d.position = p;
  ShapeDef s;
  s.geom = ShapeGeom::sphere(r);
  s.material.density = density;
  d.shapes.push_back(s);
  return d;
}

inline BodyDef boxBody(Vec3 p, Vec3 he, BodyType type = BodyType::Dynamic, Quat q = {}) {
  BodyDef d;
  d.type = type;
  d.position = p;
  d.rotation = q;
  ShapeDef s;
  s.geom = ShapeGeom::box(he);
  d.shapes.push_back(s);
  return d;
}

inline BodyId addBody(World& w, const BodyDef& d) {
  BodyId id;
  Status st = w.createBody(d, &id);
  EXPECT_TRUE(st.ok()) << st.message;
  return id;
}

/// A static ground plane z = 0.
inline BodyId addGround(World& w, float friction = 0.6f, float restitution = 0) {
  BodyDef g;
  g.type = BodyType::Static;
  ShapeDef s;
  s.geom = ShapeGeom::plane({0, 0, 1}, 0);
  s.material.friction = friction;
  s.material.restitution = restitution;
  g.shapes.push_back(s);
  return addBody(w, g);
}

inline BodyState stateOf(const World& w, BodyId id) {
  BodyState s;
  EXPECT_TRUE(w.getBody(id, &s).ok());
  return s;
}

}  // namespace phys::test
