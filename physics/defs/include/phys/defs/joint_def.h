// What a joint is: its type, the two bodies, their local frames, limits, motor and spring;
// and its state after a step. The joint rows built from it are private
// (physics/dynamics/joints.h).
#pragma once

#include <cstdint>
#include <string>

#include "phys/defs/ids.h"
#include "phys/defs/math.h"

namespace phys {

enum class JointType : uint8_t { Ball = 0, Hinge = 1, Fixed = 2, Distance = 3, Prismatic = 4 };
inline const char* toString(JointType t) {
  switch (t) {
    case JointType::Ball:
      return "ball";
    case JointType::Hinge:
      return "hinge";
    case JointType::Fixed:
      return "fixed";
    case JointType::Distance:
      return "distance";
    case JointType::Prismatic:
      return "prismatic";
  }
  return "?";
}

/// A joint between bodies a and b. Frames are given in each body's local frame (body origin,
/// not centre of mass). Hinge: rotation about `axis`. Prismatic: translation along `axis`.
struct JointDef {
  JointType type = JointType::Ball;
  BodyId bodyA, bodyB;    ///< bodyA may be null: the joint is then anchored to the world
  Vec3 anchorA, anchorB;  ///< m, local to each body
  Vec3 axisA{0, 0, 1}, axisB{0, 0, 1};  ///< hinge/prismatic axis, local to each body
  /// Hinge: angle limits (rad). Prismatic: translation limits (m). Distance: min/max length (m).
  bool enableLimit = false;
  float lower = 0, upper = 0;
  /// Hinge/prismatic motor: target speed (rad/s or m/s) up to maxForce (N m or N).
  bool enableMotor = false;
  float motorSpeed = 0;
  float maxMotorForce = 0;
  /// Distance: rest length (m; < 0 means the initial distance). With springHertz > 0 the
  /// rest length acts as a spring of that frequency; limits still hold hard.
  float length = -1;
  float springHertz = 0;
  float springDampingRatio = 0;
  bool collideConnected = false;  ///< let the two bodies' shapes collide
  std::string name;
};

/// A joint's state after the last step.
struct JointState {
  JointId id;
  Vec3 reactionForce;  ///< N, applied to body B (world frame), last step
  /// N m, applied to body B (world frame) by the joint's angular constraints (locks, hinge
  /// axes, angular limits and motors), last step; the moment of reactionForce about B's
  /// centre is not included (as Box2D's constraint torque).
  Vec3 reactionTorque;
  float positionError =
      0;  ///< m, distance between the two world anchors (length error for distance joints)
  float angleError = 0;  ///< rad, hinge axis misalignment or fixed-frame relative angle
};

}  // namespace phys
