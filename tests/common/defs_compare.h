// Every field of a body's, a shape's and a joint's definition compared, for the tests that
// check what a world reports against what it was given (the server's settings tests and the
// SDK's, through a save, a restore and a daemon restart). Pose and velocities are state:
// compared only where the caller asks (a world that has stepped has moved them).
#pragma once

#include <gtest/gtest.h>

#include <string>
#include <utility>
#include <vector>

#include "bodies.h"
#include "phys/collision/shapes.h"
#include "phys/world/world.h"

namespace phys::test {

inline void expectSameShape(const ShapeDef& want, const ShapeDef& got) {
  EXPECT_EQ(got.geom.type, want.geom.type);
  switch (want.geom.type) {
    case ShapeType::Sphere:
      EXPECT_EQ(got.geom.radius, want.geom.radius);
      break;
    case ShapeType::Box:
      EXPECT_TRUE(got.geom.halfExtents == want.geom.halfExtents);
      break;
    case ShapeType::Capsule:
      EXPECT_EQ(got.geom.radius, want.geom.radius);
      EXPECT_EQ(got.geom.halfHeight, want.geom.halfHeight);
      break;
    case ShapeType::Plane:
      EXPECT_TRUE(got.geom.normal == want.geom.normal);
      EXPECT_EQ(got.geom.offset, want.geom.offset);
      break;
    case ShapeType::Hull:
      ASSERT_TRUE(want.geom.hull && got.geom.hull);
      ASSERT_EQ(got.geom.hull->vertices.size(), want.geom.hull->vertices.size());
      for (size_t i = 0; i < want.geom.hull->vertices.size(); ++i)
        EXPECT_TRUE(got.geom.hull->vertices[i] == want.geom.hull->vertices[i]) << "vertex " << i;
      break;
  }
  EXPECT_TRUE(got.local.p == want.local.p);
  EXPECT_TRUE(got.local.q.x == want.local.q.x && got.local.q.y == want.local.q.y &&
              got.local.q.z == want.local.q.z && got.local.q.w == want.local.q.w);
  EXPECT_EQ(got.material.friction, want.material.friction);
  EXPECT_EQ(got.material.restitution, want.material.restitution);
  EXPECT_EQ(got.material.density, want.material.density);
}

/// Every field of `got` against `want`; pose and velocities too when `withState`.
inline void expectSameDefinition(const BodyDef& want, const BodyDef& got, const std::string& what,
                                 bool withState = false) {
  SCOPED_TRACE(what);
  EXPECT_EQ(got.type, want.type);
  EXPECT_EQ(got.name, want.name);
  EXPECT_EQ(got.linearDamping, want.linearDamping);
  EXPECT_EQ(got.angularDamping, want.angularDamping);
  EXPECT_EQ(got.gravityScale, want.gravityScale);
  EXPECT_EQ(got.mass, want.mass);
  EXPECT_TRUE(got.inertia == want.inertia);
  EXPECT_EQ(got.gyroscopic, want.gyroscopic);
  EXPECT_EQ(got.allowSleep, want.allowSleep);
  if (withState) {
    EXPECT_TRUE(got.position == want.position);
    EXPECT_TRUE(got.linearVelocity == want.linearVelocity);
    EXPECT_TRUE(got.angularVelocity == want.angularVelocity);
  }
  ASSERT_EQ(got.shapes.size(), want.shapes.size());
  for (size_t i = 0; i < want.shapes.size(); ++i) {
    SCOPED_TRACE("shape " + std::to_string(i));
    expectSameShape(want.shapes[i], got.shapes[i]);
  }
}

/// Every field of a joint but its bodies' ids (which the caller maps).
inline void expectSameJoint(const JointDef& want, const JointDef& got) {
  SCOPED_TRACE(want.name);
  EXPECT_EQ(got.type, want.type);
  EXPECT_EQ(got.name, want.name);
  EXPECT_TRUE(got.anchorA == want.anchorA);
  EXPECT_TRUE(got.anchorB == want.anchorB);
  EXPECT_TRUE(got.axisA == want.axisA);
  EXPECT_TRUE(got.axisB == want.axisB);
  EXPECT_EQ(got.enableLimit, want.enableLimit);
  EXPECT_EQ(got.lower, want.lower);
  EXPECT_EQ(got.upper, want.upper);
  EXPECT_EQ(got.enableMotor, want.enableMotor);
  EXPECT_EQ(got.motorSpeed, want.motorSpeed);
  EXPECT_EQ(got.maxMotorForce, want.maxMotorForce);
  EXPECT_EQ(got.length, want.length);
  EXPECT_EQ(got.springHertz, want.springHertz);
  EXPECT_EQ(got.springDampingRatio, want.springDampingRatio);
  EXPECT_EQ(got.collideConnected, want.collideConnected);
}

/// Bodies and joints of every kind with a value other than the default in every field a
/// definition has: static (a plane), dynamic (a box with a capsule beside it, every setting
/// given; a sphere; a hull; a small box), kinematic (a capsule turned in its body), and every
/// joint type.
struct Scenery {
  std::vector<BodyDef> bodies;
  std::vector<JointDef> joints;
  std::vector<std::pair<int, int>> ends;  ///< each joint's bodies: indices into bodies (-1: world)
};
inline Scenery everyKindScenery() {
  Scenery s;
  s.bodies.push_back(groundBody(0.8f, 0.1f));
  s.bodies.back().name = "ground";
  BodyDef a = boxBody({0, 0, 2}, {0.5f, 0.25f, 0.4f});
  a.name = "crate";
  a.linearDamping = 0.3f;
  a.angularDamping = 0.6f;
  a.gravityScale = 0.5f;
  a.mass = 7;
  a.inertia = {1, 2, 3};
  a.gyroscopic = false;
  a.allowSleep = false;
  a.shapes[0].material = {0.2f, 0.4f, 700};
  ShapeDef cap;
  cap.geom = ShapeGeom::capsule(0.1f, 0.3f);
  cap.local.p = {0, 0, 0.6f};
  a.shapes.push_back(cap);
  s.bodies.push_back(a);
  BodyDef b = sphereBody({2, 0, 2}, 0.3f, 1500);
  b.name = "ball";
  b.gravityScale = -0.25f;
  s.bodies.push_back(b);
  BodyDef h;
  h.position = {-2, 0, 2};
  h.name = "hull";
  ShapeDef hs;
  auto hull = buildConvexHull(
      {{-0.3f, -0.3f, -0.3f}, {0.3f, -0.3f, -0.3f}, {0, 0.3f, -0.3f}, {0, 0, 0.4f},
       {0.1f, 0.1f, 0}},
      nullptr);
  hs.geom = ShapeGeom::convexHull(hull);
  h.shapes.push_back(hs);
  s.bodies.push_back(h);
  BodyDef k;
  k.type = BodyType::Kinematic;
  k.position = {0, 3, 1};
  k.linearVelocity = {0.5f, 0, 0};
  k.angularVelocity = {0, 0, 0.25f};
  k.name = "platform";
  ShapeDef ks;
  ks.geom = ShapeGeom::capsule(0.2f, 0.5f);
  ks.local.p = {0.1f, 0, 0};
  ks.local.q = Quat{0, 0.70710677f, 0, 0.70710677f};  // lying along x
  ks.material = {0.9f, 0.2f, 300};
  k.shapes.push_back(ks);
  s.bodies.push_back(k);
  BodyDef slide = boxBody({3, -2, 0.5f}, {0.2f, 0.2f, 0.2f});
  slide.name = "slide";
  slide.mass = 2;
  s.bodies.push_back(slide);

  JointDef hinge;
  hinge.type = JointType::Hinge;
  hinge.anchorA = {1, 0, 0};
  hinge.anchorB = {-1, 0, 0};
  hinge.axisA = hinge.axisB = {0, 1, 0};
  hinge.enableLimit = true;
  hinge.lower = -0.5f;
  hinge.upper = 0.7f;
  hinge.enableMotor = true;
  hinge.motorSpeed = 0.5f;
  hinge.maxMotorForce = 20;
  hinge.name = "hinge";
  s.joints.push_back(hinge);
  s.ends.push_back({1, 2});
  JointDef rope;
  rope.type = JointType::Distance;
  rope.anchorA = {-2, 0, 4};
  rope.length = 2;
  rope.springHertz = 3;
  rope.springDampingRatio = 0.5f;
  rope.collideConnected = true;
  rope.name = "rope";
  s.joints.push_back(rope);
  s.ends.push_back({-1, 3});
  JointDef ball;
  ball.type = JointType::Ball;
  ball.anchorA = {0, 0.5f, 0};
  ball.anchorB = {0, -0.5f, 0.1f};
  ball.name = "ball joint";
  s.joints.push_back(ball);
  s.ends.push_back({2, 3});
  JointDef fixed;
  fixed.type = JointType::Fixed;
  fixed.anchorA = {0.2f, 0, 0};
  fixed.anchorB = {-0.2f, 0, 0};
  fixed.collideConnected = true;
  fixed.name = "weld";
  s.joints.push_back(fixed);
  s.ends.push_back({4, 1});
  JointDef slider;
  slider.type = JointType::Prismatic;
  slider.anchorA = {3, -2, 0.5f};
  slider.axisA = slider.axisB = {1, 0, 0};
  slider.enableLimit = true;
  slider.lower = -0.25f;
  slider.upper = 0.75f;
  slider.enableMotor = true;
  slider.motorSpeed = -0.1f;
  slider.maxMotorForce = 40;
  slider.name = "slider";
  s.joints.push_back(slider);
  s.ends.push_back({-1, 5});
  return s;
}

}  // namespace phys::test
