// Body definitions every test suite builds (unit, protocol, server, client): one box, one
// sphere, one ground plane, with the engine's defaults unless a test says otherwise.
#pragma once

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

/// A box of half-extents `he` (a 1 m cube by default).
inline BodyDef boxBody(Vec3 p, Vec3 he = {0.5f, 0.5f, 0.5f}, BodyType type = BodyType::Dynamic,
                       Quat q = {}) {
  BodyDef d;
  d.type = type;
  d.position = p;
  d.rotation = q;
  ShapeDef s;
  s.geom = ShapeGeom::box(he);
  d.shapes.push_back(s);
  return d;
}

/// A static ground plane z = 0 (Material's default friction and restitution unless given).
inline BodyDef groundBody(float friction = Material().friction,
                          float restitution = Material().restitution) {
  BodyDef g;
  g.type = BodyType::Static;
  ShapeDef s;
  s.geom = ShapeGeom::plane({0, 0, 1}, 0);
  s.material.friction = friction;
  s.material.restitution = restitution;
  g.shapes.push_back(s);
  return g;
}

}  // namespace phys::test
