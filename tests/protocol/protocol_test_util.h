// Shared samples for the protocol tests.
#pragma once

#include <gtest/gtest.h>

#include <cstdint>
#include <fstream>
#include <string>
#include <string_view>
#include <vector>

#include "../common/bodies.h"
#include "phys/protocol/builder.h"
#include "phys/protocol/convert.h"
#include "phys/protocol/decoder.h"
#include "phys/world/world.h"

namespace phys::protocol::test {

inline constexpr uint64_t kClient = 0xC0FFEE;
inline constexpr uint32_t kWorld = 7;

inline CommandHeader header(uint64_t seq = 1, uint32_t world = kWorld) {
  return {kClient, seq, world};
}

/// FNV-1a of bytes: pins of a format (a message's bytes, a list of answers) in one number.
inline uint64_t fnv1a(std::string_view s) {
  uint64_t h = 1469598103934665603ull;
  for (unsigned char c : s) h = (h ^ c) * 1099511628211ull;
  return h;
}
inline uint64_t fnv1a(const Bytes& b) {
  return fnv1a(std::string_view(reinterpret_cast<const char*>(b.data()), b.size()));
}

/// The field names of a table of physics.fbs (`table NAME {` to `}`), in order.
inline std::vector<std::string> schemaFields(const std::string& table) {
  std::ifstream f(std::string(PHYS_SOURCE_DIR) + "/protocol/physics.fbs");
  std::vector<std::string> names;
  std::string line;
  bool in = false;
  while (std::getline(f, line)) {
    if (line.starts_with("table " + table + " {"))
      in = true;
    else if (in && line.starts_with("}"))
      break;
    else if (in && line.find(':') != std::string::npos && !line.starts_with("  //"))
      names.push_back(line.substr(2, line.find(':') - 2));
  }
  return names;
}

using phys::test::boxBody;

/// A named ground with a friction other than the default, so round trips show both.
inline phys::BodyDef groundBody() {
  phys::BodyDef d = phys::test::groundBody(0.9f);
  d.name = "ground";
  return d;
}

/// A cube as a convex hull (8 points).
inline phys::BodyDef hullBody() {
  std::vector<phys::Vec3> pts;
  for (int i = 0; i < 8; ++i)
    pts.push_back({i & 1 ? 0.5f : -0.5f, i & 2 ? 0.5f : -0.5f, i & 4 ? 0.5f : -0.5f});
  std::string err;
  phys::BodyDef d;
  d.position = {1, 2, 3};
  phys::ShapeDef s;
  s.geom = phys::ShapeGeom::convexHull(phys::buildConvexHull(pts, &err));
  d.shapes.push_back(s);
  return d;
}

/// One body of every shape and most fields off their defaults.
inline std::vector<phys::BodyDef> sampleBodies() {
  std::vector<phys::BodyDef> v;
  v.push_back(groundBody());
  phys::BodyDef a = boxBody({0, 0, 1}, {0.5f, 0.25f, 0.125f});
  a.rotation = phys::Quat::fromAxisAngle({0, 0, 1}, 0.3f);
  a.linearVelocity = {1, 2, 3};
  a.angularVelocity = {0.1f, 0.2f, 0.3f};
  a.linearDamping = 0.5f;
  a.angularDamping = 0.25f;
  a.gravityScale = 0.5f;
  a.mass = 12;
  a.inertia = {1, 2, 3};
  a.gyroscopic = false;
  a.name = "crate";
  a.shapes[0].material = {0.3f, 0.4f, 500};
  a.shapes[0].local = {{0.1f, 0, 0}, phys::Quat::fromAxisAngle({1, 0, 0}, 0.2f)};
  phys::ShapeDef sphere;
  sphere.geom = phys::ShapeGeom::sphere(0.2f);
  sphere.local.p = {0, 0, 0.5f};
  a.shapes.push_back(sphere);
  v.push_back(a);
  phys::BodyDef c;
  c.type = phys::BodyType::Kinematic;
  phys::ShapeDef cap;
  cap.geom = phys::ShapeGeom::capsule(0.25f, 0.75f);
  c.shapes.push_back(cap);
  v.push_back(c);
  v.push_back(hullBody());
  return v;
}

inline phys::JointDef sampleJoint() {
  phys::JointDef j;
  j.type = phys::JointType::Hinge;
  j.bodyA = phys::BodyId{3, 1};
  j.bodyB = phys::BodyId{4, 2};
  j.anchorA = {0.5f, 0, 0};
  j.anchorB = {-0.5f, 0, 0};
  j.axisA = {0, 1, 0};
  j.axisB = {0, 1, 0};
  j.enableLimit = true;
  j.lower = -1;
  j.upper = 1;
  j.enableMotor = true;
  j.motorSpeed = 2;
  j.maxMotorForce = 50;
  j.collideConnected = true;
  j.name = "elbow";
  return j;
}

/// Decodes a command that must be valid (the result owns the bytes).
inline Decoded<wire::Command> mustDecode(Bytes b, const Limits& lim = {}) {
  Decoded<wire::Command> d = decodeCommand(std::move(b), lim);
  EXPECT_TRUE(d.ok()) << toString(d.status.code) << ": " << d.status.message;
  return d;
}

}  // namespace phys::protocol::test
