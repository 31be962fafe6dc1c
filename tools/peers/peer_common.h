// What every peer adapter needs to simulate the same bodies as phys_core: mass properties
// computed by phys itself, and the conversions between phys's body frame and a peer's
// centre-of-mass frame.
//
// Bullet, ODE and MuJoCo all place a dynamic body's frame at its centre of mass, most with the
// axes along the principal axes of inertia (a diagonal inertia tensor). (Box3D does not: it
// takes a centre of mass and a full inertia tensor in any body frame, so box3d_peer.cpp uses
// phys's body frame as it is and only the masses from step 1 below.) phys places a body's
// frame wherever the scene says (BodyDef::position, the shapes' `local` transforms) and keeps
// the centre of mass and a full inertia tensor relative to it. So an adapter:
//   1. calls computePeerBodies(scene) once: it instantiates the scene in a phys::World and
//      reads back each body's mass, centre of mass and world inertia, which it diagonalizes
//      (Eigen's SelfAdjointEigenSolver) into principal moments and the rotation of the
//      principal axes relative to the body frame (identity when the inertia is already
//      diagonal in body axes, as for a single box, sphere or capsule);
//   2. creates each dynamic body with mass, principalInertia, and the pose
//      toPeerPose(body, position, rotation) (the principal frame in the world), and each
//      shape at shapeInPeerFrame(body, shape.local);
//   3. expresses joint anchors and axes given in phys's body frame (JointDef::anchorA, axisA,
//      ...) in the peer's frame with pointInPeerFrame / directionInPeerFrame;
//   4. in read(), converts the peer's principal-frame pose back with fromPeerPose. Linear
//      velocities are the centre of mass's in both conventions, angular velocities are the
//      same vector in any frame of the body: they pass through unchanged (in world axes).
// Static and kinematic bodies have mass 0 and their peer frame is the body frame itself
// (comLocal 0, principalRotation identity), so their shapes keep their own transforms.
#pragma once

#include <cmath>
#include <string>
#include <vector>

#include "peers/peer.h"
#include "phys/defs/math.h"
#include "phys/scene/scene.h"
#include "phys/world/world.h"

namespace phys::peers {

/// One scene body's mass properties as phys computed them, in double precision.
struct PeerBodyMass {
  BodyType type = BodyType::Dynamic;
  double mass = 0;               ///< kg (0 for static and kinematic bodies)
  Vec3 comWorld;                 ///< centre of mass at the scene's initial pose, world frame
  Vec3 comLocal;                 ///< centre of mass in the body frame (from the body origin)
  Vec3 principalInertia;         ///< kg m^2, principal moments about the centre of mass
  Quat principalRotation;        ///< principal axes in the body frame: I_body = R diag R^T
  Transform peerFrame() const {  ///< the peer's body frame (COM, principal axes), body-local
    return {comLocal, principalRotation};
  }
};

/// Mass properties of every scene body, out->at(i) for scene.bodies[i], computed by
/// instantiating the scene in a phys::World (the scene's own densities, explicit masses and
/// inertias all apply as in phys). Fails with instantiateScene's error.
Status computePeerBodies(const Scene& scene, std::vector<PeerBodyMass>* out);

/// The peer's body pose (principal frame in the world) of a body whose phys frame is at
/// (position, rotation).
Transform toPeerPose(const PeerBodyMass& body, Vec3 position, Quat rotation);
/// phys's body pose (origin, rotation) from the peer's principal-frame pose.
Transform fromPeerPose(const PeerBodyMass& body, Vec3 peerPosition, Quat peerRotation);

/// A shape's transform in the peer's body frame, from its transform in phys's body frame.
Transform shapeInPeerFrame(const PeerBodyMass& body, const Transform& local);
/// A point (joint anchor) given in phys's body frame, in the peer's body frame.
Vec3 pointInPeerFrame(const PeerBodyMass& body, Vec3 p);
/// A direction (joint axis) given in phys's body frame, in the peer's body frame.
Vec3 directionInPeerFrame(const PeerBodyMass& body, Vec3 d);

/// A state in phys's conventions from a peer's principal-frame pose and its centre-of-mass
/// linear and world angular velocities.
PeerBodyState peerStateToPhys(const PeerBodyMass& body, Vec3 peerPosition, Quat peerRotation,
                              Vec3 linearVelocity, Vec3 angularVelocity);

/// A scene feature this engine cannot express (InvalidArgument, "unsupported: " + what); tables
/// print "cannot run: <message>".
inline Status unsupported(const std::string& what) {
  return Status::Error(StatusCode::InvalidArgument, "unsupported: " + what);
}
/// The engine itself failed (IncorrectState), with its own error text.
inline Status engineError(const std::string& engineText) {
  return Status::Error(StatusCode::IncorrectState, engineText);
}

/// phys's contact material mixing (world.h, Material), for adapters whose engine lets them
/// choose: friction = sqrt(fa * fb), restitution = max(ea, eb).
inline double mixFriction(double fa, double fb) {
  return std::sqrt(fa * fb);
}
inline double mixRestitution(double ea, double eb) {
  return ea > eb ? ea : eb;
}

}  // namespace phys::peers
