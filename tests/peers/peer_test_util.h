// Scene builders and helpers shared by the peers' tests (test_engines.cpp runs the same tests on
// every engine; test_<engine>.cpp keeps each engine's own).
#pragma once

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <vector>

#include "peers/peer.h"

namespace phys::peers::testutil {

inline constexpr float kG = 9.81f;
inline constexpr float kPi = 3.14159265f;

/// A static plane z = 0.
inline BodyDef ground() {
  BodyDef b;
  b.type = BodyType::Static;
  b.name = "ground";
  b.shapes.push_back({ShapeGeom::plane({0, 0, 1}, 0), {}, {}});
  return b;
}

/// A dynamic ball of `radius` at `position`, its sphere `shapeOffset` off the body's origin.
inline BodyDef ball(Vec3 position, float radius, Vec3 shapeOffset = {}) {
  BodyDef b;
  b.position = position;
  b.shapes.push_back({ShapeGeom::sphere(radius), {shapeOffset, {}}, {}});
  return b;
}

/// A dynamic box of `halfExtents` at `position`.
inline BodyDef box(Vec3 position, Vec3 halfExtents) {
  BodyDef b;
  b.position = position;
  b.shapes.push_back({ShapeGeom::box(halfExtents), {}, {}});
  return b;
}

/// The joints' sign conventions, in zero gravity: a 1 x 1 x 0.2 m plate at (0, 0, 1) hinged
/// to the world about +z through its centre. With `motor`, driven at +1.5 rad/s (100 N m):
/// phys turns B at +1.5 rad/s about A's axis. Else spinning at +2 rad/s against the limit
/// [-0.5, 0.3] rad: phys stops it at +0.3 (a flipped angle would stop at 0.5).
inline Scene hingedPlate(bool motor) {
  Scene scene;
  scene.world.gravity = {};
  BodyDef b = box({0, 0, 1}, {0.5f, 0.5f, 0.1f});
  SceneJoint j;
  j.def.type = JointType::Hinge;
  j.def.anchorA = {0, 0, 1};
  if (motor) {
    j.def.enableMotor = true;
    j.def.motorSpeed = 1.5f;
    j.def.maxMotorForce = 100;
  } else {
    b.angularVelocity = {0, 0, 2};
    j.def.enableLimit = true;
    j.def.lower = -0.5f;
    j.def.upper = 0.3f;
  }
  j.bodyB = 0;
  scene.bodies = {b};
  scene.joints = {j};
  return scene;
}

/// The largest hinge angle about +z of body 0 over `steps` single steps (hingedPlate(false)).
inline double largestTurnAboutZ(PeerEngine& peer, int steps) {
  double largest = 0;
  std::vector<PeerBodyState> s;
  for (int i = 0; i < steps; ++i) {
    peer.step();
    peer.read(&s);
    largest = std::max(largest, 2 * std::atan2(double(s[0].rotation.z), s[0].rotation.w));
  }
  return largest;
}

/// A 0.4 m box at (0, 0, 1) on a slider along +x, in zero gravity, driven at +0.5 m/s
/// (1000 N) up to the limit [-0.1, 0.2] m: phys's translation is dot(axis, pB - pA).
inline Scene drivenSlider() {
  Scene scene;
  scene.world.gravity = {};
  scene.bodies = {box({0, 0, 1}, {0.2f, 0.2f, 0.2f})};
  SceneJoint j;
  j.def.type = JointType::Prismatic;
  j.def.anchorA = {0, 0, 1};
  j.def.axisA = j.def.axisB = {1, 0, 0};
  j.def.enableMotor = true;
  j.def.motorSpeed = 0.5f;
  j.def.maxMotorForce = 1000;
  j.def.enableLimit = true;
  j.def.lower = -0.1f;
  j.def.upper = 0.2f;
  j.bodyB = 0;
  scene.joints = {j};
  return scene;
}

/// A 0.4 m box at (1, 2, 5) on a vertical slider whose anchors start 0.5 m apart (phys's
/// translation 0.5), under gravity, limited to [-0.5, 1]: it falls to -0.5 and stops at
/// z = 4, 1 m below its start.
inline Scene fallingSlider() {
  Scene scene;
  scene.bodies = {box({1, 2, 5}, {0.2f, 0.2f, 0.2f})};
  SceneJoint slider;
  slider.def.type = JointType::Prismatic;
  slider.def.anchorA = {1, 2, 4.5f};
  slider.def.axisA = slider.def.axisB = {0, 0, 1};
  slider.def.enableLimit = true;
  slider.def.lower = -0.5f;
  slider.def.upper = 1;
  slider.bodyA = -1;
  slider.bodyB = 0;
  scene.joints = {slider};
  return scene;
}

/// Steps `n` times and returns the states of all bodies.
inline std::vector<PeerBodyState> stepAndRead(PeerEngine& peer, int n) {
  for (int k = 0; k < n; ++k) peer.step();
  std::vector<PeerBodyState> states;
  peer.read(&states);
  return states;
}

/// Steps `n` times and returns the last state of body `i`.
inline PeerBodyState run(PeerEngine& peer, int n, size_t i) {
  return stepAndRead(peer, n).at(i);
}

/// A small ball on a massless rod of length `len`, hinged to the world about y at (0, 0, 5),
/// released `angle` rad from the vertical.
inline Scene pendulum(float len, float angle) {
  Scene scene;
  Vec3 pivot{0, 0, 5};
  scene.bodies.push_back(
      ball(pivot + Vec3{len * std::sin(angle), 0, -len * std::cos(angle)}, 0.05f));
  SceneJoint j;
  j.def.type = JointType::Hinge;
  j.def.anchorA = pivot;
  j.def.anchorB = pivot - scene.bodies[0].position;
  j.def.axisA = j.def.axisB = {0, 1, 0};
  j.bodyA = -1;
  j.bodyB = 0;
  scene.joints.push_back(j);
  return scene;
}

/// The mean period of x(t) of body 0 over `seconds`, from its upward zero crossings.
inline double measurePeriod(PeerEngine& peer, double h, double seconds) {
  std::vector<PeerBodyState> s;
  peer.read(&s);
  double prev = s[0].position.x, first = -1, last = -1;
  int crossings = 0;
  for (int k = 1; k * h <= seconds; ++k) {
    peer.step();
    peer.read(&s);
    double x = s[0].position.x;
    if (prev < 0 && x >= 0) {
      double tc = (k - 1 + prev / (prev - x)) * h;
      if (first < 0) first = tc;
      last = tc;
      ++crossings;
    }
    prev = x;
  }
  return crossings > 1 ? (last - first) / (crossings - 1) : 0;
}

/// The largest distance between a joint's two world anchors (phys's joint_error) in states s.
inline float jointError(const Scene& scene, const std::vector<PeerBodyState>& s) {
  auto world = [&](int b, Vec3 p) {
    return b < 0 ? p : s[size_t(b)].position + rotate(s[size_t(b)].rotation, p);
  };
  float worst = 0;
  for (const SceneJoint& j : scene.joints)
    worst = std::max(worst, length(world(j.bodyA, j.def.anchorA) - world(j.bodyB, j.def.anchorB)));
  return worst;
}

}  // namespace phys::peers::testutil
