// Joint rows and joint error measurement.
#pragma once

#include "solver.h"
#include "world_impl.h"

namespace phys {

/// World-space geometry of a joint at the bodies' current poses. A null body A is the world.
struct JointFrame {
  Quat qA, qB;
  Vec3 rA, rB;  ///< anchors relative to each centre of mass (rA = world anchor when A is null)
  Vec3 pA, pB;  ///< world anchors
};
JointFrame jointFrame(const JointRec& j, const BodyRec* A, const BodyRec& B);

/// Fills the reference data a joint keeps from its creation pose (relative rotation, hinge
/// reference vectors, distance rest length).
void initJoint(JointRec& j, const BodyRec* A, const BodyRec& B);

/// Appends the joint's rows for this step (solver body indices ia, ib) and records them in
/// j.firstRow/rowCount. h is the substep length (motor impulse bound).
void buildJointRows(JointRec& j, const BodyRec* A, const BodyRec& B, int32_t ia, int32_t ib,
                    float h, Solver* solver);

/// Position error (m) and angle error (rad) at the bodies' current poses.
void measureJoint(const JointRec& j, const BodyRec* A, const BodyRec& B, float* positionError,
                  float* angleError);

}  // namespace phys
