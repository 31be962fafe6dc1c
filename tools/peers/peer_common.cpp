// Mass properties and frame conversions shared by the peer adapters (peer_common.h).
#include "peers/peer_common.h"

#include <Eigen/Eigenvalues>
#include <cmath>

namespace phys::peers {
namespace {

/// The unit quaternion of a proper rotation matrix (columns = rotated axes).
Quat quatFromMatrix(const Eigen::Matrix3d& m) {
  Eigen::Quaterniond q(m);
  q.normalize();
  return normalize(Quat{float(q.x()), float(q.y()), float(q.z()), float(q.w())});
}

}  // namespace

Status computePeerBodies(const Scene& scene, std::vector<PeerBodyMass>* out) {
  out->clear();
  WorldDef def = scene.world;
  def.threads = 1;
  World world(def);
  std::vector<BodyId> ids;
  Status st = instantiateScene(scene, &world, &ids);
  if (!st.ok()) return st;
  out->reserve(ids.size());
  for (BodyId id : ids) {
    BodyState s;
    world.getBody(id, &s);
    PeerBodyMass m;
    m.type = s.type;
    if (s.type != BodyType::Dynamic) {
      m.comWorld = s.position;
      out->push_back(m);
      continue;
    }
    m.mass = s.mass;
    m.comWorld = s.centerOfMass;
    m.comLocal = invRotate(s.rotation, s.centerOfMass - s.position);
    // The inertia in body axes, R^T I_world R, diagonalized: I_body = V diag(d) V^T.
    Mat3 local = transpose(toMat3(s.rotation)) * s.inertia * toMat3(s.rotation);
    Eigen::Matrix3d I;
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) I(r, c) = 0.5 * (double(local.row(r)[c]) + local.row(c)[r]);
    // Already diagonal (a box, a sphere, a capsule about its own centre): keep the body
    // axes, so a single shape sits in the peer frame untransformed.
    const double off = std::fabs(I(0, 1)) + std::fabs(I(0, 2)) + std::fabs(I(1, 2));
    if (off <= 1e-6 * I.trace()) {
      m.principalInertia = {float(I(0, 0)), float(I(1, 1)), float(I(2, 2))};
      out->push_back(m);
      continue;
    }
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(I);
    Eigen::Matrix3d V = eig.eigenvectors();
    if (V.determinant() < 0) V.col(2) = -V.col(2);  // a rotation, not a reflection
    m.principalInertia = {float(eig.eigenvalues()(0)), float(eig.eigenvalues()(1)),
                          float(eig.eigenvalues()(2))};
    m.principalRotation = quatFromMatrix(V);
    out->push_back(m);
  }
  return Status::Ok();
}

Transform toPeerPose(const PeerBodyMass& body, Vec3 position, Quat rotation) {
  return Transform{position, rotation} * body.peerFrame();
}

Transform fromPeerPose(const PeerBodyMass& body, Vec3 peerPosition, Quat peerRotation) {
  Quat q = normalize(peerRotation * conjugate(body.principalRotation));
  return {peerPosition - rotate(q, body.comLocal), q};
}

Transform shapeInPeerFrame(const PeerBodyMass& body, const Transform& local) {
  Quat inv = conjugate(body.principalRotation);
  return {rotate(inv, local.p - body.comLocal), normalize(inv * local.q)};
}

Vec3 pointInPeerFrame(const PeerBodyMass& body, Vec3 p) {
  return invRotate(body.principalRotation, p - body.comLocal);
}

Vec3 directionInPeerFrame(const PeerBodyMass& body, Vec3 d) {
  return invRotate(body.principalRotation, d);
}

PeerBodyState peerStateToPhys(const PeerBodyMass& body, Vec3 peerPosition, Quat peerRotation,
                              Vec3 linearVelocity, Vec3 angularVelocity) {
  Transform xf = fromPeerPose(body, peerPosition, peerRotation);
  return {xf.p, xf.q, linearVelocity, angularVelocity};
}

}  // namespace phys::peers
