// Joint rows and joint error measurement.
#pragma once

#include "dynamics/records.h"
#include "dynamics/solver.h"

namespace phys {

/// What a joint needs of a body's pose: its orientation, centre of mass, and the centre of
/// mass in the body frame (anchors are given relative to the body origin). The world makes
/// one from its body record (poseOf, world_impl.h).
struct BodyPose {
  Quat q;
  Vec3 com;
  Vec3 localCenter;
};

/// World-space geometry of a joint at the bodies' current poses. A null body A is the world.
struct JointFrame {
  Quat qA, qB;
  Vec3 rA, rB;  ///< anchors relative to each centre of mass (rA = world anchor when A is null)
  Vec3 pA, pB;  ///< world anchors
};
JointFrame jointFrame(const JointRec& j, const BodyPose* A, const BodyPose& B);

/// Fills the reference data a joint keeps from its creation pose (relative rotation, hinge
/// reference vectors, distance rest length).
void initJoint(JointRec& j, const BodyPose* A, const BodyPose& B);

/// Appends the joint's rows for this step (solver body indices ia, ib) and records them in
/// j.firstRow/rowCount. h is the substep length (motor impulse bound).
void buildJointRows(JointRec& j, const BodyPose* A, const BodyPose& B, int32_t ia, int32_t ib,
                    float h, Solver* solver);

/// Rebuilds the joint's rows in place from the bodies' poses inside a substep (Jacobians at
/// the current rotation, as Box2D v3 does for joints), keeping their impulses. C0 is set so
/// that Solver::rowError gives the current error from the bodies' accumulated deltas.
void refreshJointRows(JointRec& j, const BodyPose* A, const BodyPose& B, int32_t ia, int32_t ib,
                      float h, Solver* solver);

/// Position error (m) and angle error (rad) at the bodies' current poses.
void measureJoint(const JointRec& j, const BodyPose* A, const BodyPose& B, float* positionError,
                  float* angleError);

}  // namespace phys
