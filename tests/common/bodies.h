// Body definitions every test suite builds (unit, protocol, server, client): one box, one
// sphere, one ground plane, with the engine's defaults unless a test says otherwise.
#pragma once

#include "phys/world/world.h"

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

/// The split push-out's jointed pair (tests/unit/test_split_pushout.cpp and its device twin in
/// tests/gpu): a static block, a 1 kg box buried 8 cm (in x) in it, and a 500 kg box above
/// the light one, jointed to it at its top face by a joint of `type` (a prismatic one slides
/// along y). Meant for a world without gravity.
struct BuriedJointedPair {
  BodyId light, heavy;
  JointId joint;
};
inline Status addBuriedJointedPair(World& w, JointType type, BuriedJointedPair* out) {
  BodyId block;
  Status st = w.createBody(boxBody({0, 0, 0}, {0.5f, 0.5f, 0.2f}, BodyType::Static), &block);
  BodyDef light = boxBody({0.62f, 0, 0}, {0.2f, 0.2f, 0.2f});
  light.shapes[0].material.density = 1 / 0.064f;  // 1 kg
  BodyDef heavy = boxBody({0.62f, 0, 0.71f});
  heavy.shapes[0].material.density = 500;  // 500 kg
  if (st.ok()) st = w.createBody(light, &out->light);
  if (st.ok()) st = w.createBody(heavy, &out->heavy);
  if (!st.ok()) return st;
  JointDef j;
  j.type = type;
  j.bodyA = out->light;
  j.bodyB = out->heavy;
  j.anchorA = {0, 0, 0.205f};
  j.anchorB = {0, 0, -0.505f};
  j.axisA = j.axisB = {0, 1, 0};
  return w.createJoint(j, &out->joint);
}

}  // namespace phys::test
