// The world's joint and contact records: what the dynamics reads and writes of them each
// step (joint rows from a JointRec, stacks from the contacts). World::Impl keeps them
// (physics/world/world_impl.h) beside its body and shape records, which the dynamics does not
// see: what it needs of a body comes to it as a BodyPose (joints.h) or a StackBody (stacks.h).
#pragma once

#include <cstdint>

#include "phys/defs/ids.h"
#include "phys/defs/math.h"
#include "phys/collision/shapes.h"
#include "phys/defs/joint_def.h"

namespace phys {

struct JointRec {
  JointDef def;
  Quat relRot0;      ///< fixed/prismatic: conj(qA) * qB at creation
  Vec3 refA, refB;   ///< hinge: local reference vectors perpendicular to the axis
  float length = 0;  ///< distance: rest length
  JointState state;
  int32_t firstRow = 0, rowCount = 0;  ///< this step's rows
  static constexpr int kMaxRows = 8;  ///< a hinge's or slider's 5 + 2 limit rows + motor
  /// m, the shortest rest length of a distance joint that pulls along its anchors' line
  static constexpr float kMinDistanceLength = 1e-3f;
  float impulses[kMaxRows] = {};  ///< last step's row impulses, for warm starting
  int32_t impulseCount = 0;
};

/// Persistent contact between two shapes (keyed by their shape indices, a < b).
struct Contact {
  uint32_t shapeA = 0, shapeB = 0;  ///< shape slots (broad-phase user values)
  ShapeId idA, idB;                 ///< the shapes themselves, generation included
  BodyId bodyA, bodyB;
  Manifold manifold;
  float normalImpulse[Manifold::kMaxPoints] = {};
  /// Per point: the friction pair's impulses. With patch friction the manifold's three
  /// (tangent 1, tangent 2, twist) in the first three slots instead: patchImpulse(d).
  float tangentImpulse[Manifold::kMaxPoints][2] = {};
  float friction = 0, restitution = 0;
  int32_t firstRow = -1;  ///< this step's first normal row

  float& patchImpulse(int d) { return tangentImpulse[d / 2][d % 2]; }
  float patchImpulse(int d) const { return tangentImpulse[d / 2][d % 2]; }
};

}  // namespace phys
