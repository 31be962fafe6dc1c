// The ODE 0.16 peer: a dWorld stepped by QuickStep, geoms in a dHashSpace, contacts from a
// near callback.
//
// Settings (what a game using ODE would run with, ODE's own defaults where it has them):
//   - QuickStep with 20 iterations (ODE's documented default; PeerBudget::iterations
//     overrides), SOR 1.3 (default);
//   - ERP 0.2 and CFM 1e-10 (ODE's defaults for a double-precision build; contacts inherit
//     them), no cap on the contacts' correcting velocity (default), contact surface layer 1 mm
//     (the ODE manual's advice against jitter in resting contacts; default 0);
//   - auto-disable off (scenes run with sleeping off);
//   - contacts: at most 4 per geom pair (phys's manifold size), dContactApprox1 (friction
//     pyramid scaled by the normal force, the usual choice for stacking), friction and
//     restitution mixed as phys mixes them (geometric mean, max; peer_common.h), bouncing above
//     the scene's restitution threshold.
// Each dynamic body's ODE frame is its centre of mass with principal axes (peer_common.h);
// shapes are geoms offset from it. What ODE cannot express (distance-joint limits and springs)
// is reported by build() as unsupported.
#include <ode/ode.h>

#include <algorithm>
#include <mutex>
#include <set>
#include <utility>

#include "peers/peer.h"
#include "peers/peer_common.h"

namespace phys::peers {
namespace {

constexpr int kDefaultIterations = 20;
constexpr int kMaxContactsPerPair = 4;
constexpr double kSurfaceLayer = 0.001;

/// ODE needs one global initialization and its per-thread data on every thread that steps.
void initOdeForThisThread() {
  static std::once_flag once;
  std::call_once(once, [] { dInitODE2(0); });
  thread_local bool allocated = false;
  if (!allocated) allocated = dAllocateODEDataForThread(dAllocateMaskAll) != 0;
}

/// What a geom carries (dGeomSetData): its scene body and material.
struct GeomInfo {
  int body = -1;
  Material material;
};

/// A convex hull in ODE's layout (dCreateConvex keeps pointers to these arrays).
struct OdeHull {
  std::vector<dReal> planes, points;
  std::vector<unsigned int> polygons;
};

class OdePeer final : public PeerEngine {
 public:
  OdePeer() { initOdeForThisThread(); }
  ~OdePeer() override {
    if (contacts_) dJointGroupDestroy(contacts_);
    if (space_) dSpaceDestroy(space_);  // destroys its geoms (cleanup mode on by default)
    if (world_) dWorldDestroy(world_);  // destroys bodies and joints
  }

  std::string name() const override { return "ode"; }
  std::string version() const override { return dODE_VERSION; }

  Status build(const Scene& scene, const PeerBudget& budget) override;
  void step() override;
  void read(std::vector<PeerBodyState>* out) const override;

 private:
  void addShape(int index, const ShapeDef& shape);
  void addJoint(const SceneJoint& sj);
  static void nearCallback(void* self, dGeomID a, dGeomID b);
  void collidePair(dGeomID a, dGeomID b);

  Scene scene_;
  std::vector<PeerBodyMass> mass_;
  std::vector<dBodyID> bodies_;  ///< nullptr for static bodies
  std::vector<std::unique_ptr<GeomInfo>> geomInfo_;
  std::vector<std::unique_ptr<OdeHull>> hulls_;
  /// Scene body pairs joined without collideConnected (the world, -1, has no geoms).
  std::set<std::pair<int, int>> noCollide_;
  dWorldID world_ = nullptr;
  dSpaceID space_ = nullptr;
  dJointGroupID contacts_ = nullptr;
  int substeps_ = 1;
};

Transform bodyPose(const BodyDef& b) {
  return {b.position, b.rotation};
}

void setOdeQuat(dQuaternion out, Quat q) {
  out[0] = q.w;
  out[1] = q.x;
  out[2] = q.y;
  out[3] = q.z;
}

Status OdePeer::build(const Scene& scene, const PeerBudget& budget) {
  if (world_) return engineError("ode: build() called twice");
  Status st = computePeerBodies(scene, &mass_);
  if (!st.ok()) return st;
  // Validate everything ODE cannot express before creating anything.
  for (size_t i = 0; i < scene.joints.size(); ++i) {
    const JointDef& d = scene.joints[i].def;
    if (d.type == JointType::Distance && (d.enableLimit || d.springHertz > 0))
      return unsupported("ode: joints[" + std::to_string(i) +
                         "]: a distance joint with limits or a spring (ODE's DBall joint only "
                         "holds a fixed length)");
  }
  scene_ = scene;
  substeps_ = std::max(1, budget.substeps);
  world_ = dWorldCreate();
  space_ = dHashSpaceCreate(nullptr);
  contacts_ = dJointGroupCreate(0);
  Vec3 g = scene.world.gravity;
  dWorldSetGravity(world_, g.x, g.y, g.z);
  dWorldSetQuickStepNumIterations(world_,
                                  budget.iterations > 0 ? budget.iterations : kDefaultIterations);
  dWorldSetAutoDisableFlag(world_, 0);
  dWorldSetContactSurfaceLayer(world_, kSurfaceLayer);
  // QuickStep shuffles its rows with ODE's one global generator: reseed it so that a run does
  // not depend on what ran before it in the process (runs stepped one at a time).
  dRandSetSeed(0);

  const double h = double(scene.world.timeStep) / substeps_;
  bodies_.assign(scene.bodies.size(), nullptr);
  for (size_t i = 0; i < scene.bodies.size(); ++i) {
    const BodyDef& b = scene.bodies[i];
    const PeerBodyMass& m = mass_[i];
    if (b.type != BodyType::Static) {
      dBodyID body = dBodyCreate(world_);
      Transform pose = toPeerPose(m, b.position, b.rotation);
      dBodySetPosition(body, pose.p.x, pose.p.y, pose.p.z);
      dQuaternion q;
      setOdeQuat(q, pose.q);
      dBodySetQuaternion(body, q);
      dBodySetLinearVel(body, b.linearVelocity.x, b.linearVelocity.y, b.linearVelocity.z);
      dBodySetAngularVel(body, b.angularVelocity.x, b.angularVelocity.y, b.angularVelocity.z);
      if (b.type == BodyType::Kinematic) {
        dBodySetKinematic(body);
      } else {
        dMass dm;
        Vec3 I = m.principalInertia;
        dMassSetParameters(&dm, m.mass, 0, 0, 0, I.x, I.y, I.z, 0, 0, 0);
        dBodySetMass(body, &dm);
        dBodySetGyroscopicMode(body, b.gyroscopic ? 1 : 0);
        if (b.gravityScale == 0) dBodySetGravityMode(body, 0);
        // phys damps v *= 1 / (1 + h d); ODE removes scale * v per step, below no threshold.
        dBodySetLinearDamping(body, h * b.linearDamping / (1 + h * b.linearDamping));
        dBodySetAngularDamping(body, h * b.angularDamping / (1 + h * b.angularDamping));
        dBodySetLinearDampingThreshold(body, 0);
        dBodySetAngularDampingThreshold(body, 0);
      }
      bodies_[i] = body;
    }
    for (const ShapeDef& shape : b.shapes) addShape(int(i), shape);
  }
  for (const SceneJoint& sj : scene.joints) addJoint(sj);
  return Status::Ok();
}

void OdePeer::addShape(int index, const ShapeDef& shape) {
  const BodyDef& b = scene_.bodies[size_t(index)];
  const ShapeGeom& g = shape.geom;
  dGeomID geom = nullptr;
  switch (g.type) {
    case ShapeType::Sphere:
      geom = dCreateSphere(space_, g.radius);
      break;
    case ShapeType::Box:
      geom = dCreateBox(space_, 2 * g.halfExtents.x, 2 * g.halfExtents.y, 2 * g.halfExtents.z);
      break;
    case ShapeType::Capsule:  // both along the local z axis
      geom = dCreateCapsule(space_, g.radius, 2 * g.halfHeight);
      break;
    case ShapeType::Plane: {
      // Non-placeable in ODE: the plane in world coordinates (planes are on static bodies).
      Transform xf = bodyPose(b) * shape.local;
      Vec3 n = rotate(xf.q, g.normal);
      double d = dot(n, apply(xf, g.normal * g.offset));
      geom = dCreatePlane(space_, n.x, n.y, n.z, d);
      break;
    }
    case ShapeType::Hull: {
      auto hull = std::make_unique<OdeHull>();
      for (const ConvexHull::Face& f : g.hull->faces) {
        hull->planes.insert(hull->planes.end(), {f.normal.x, f.normal.y, f.normal.z, f.offset});
        hull->polygons.push_back(unsigned(f.indices.size()));
        hull->polygons.insert(hull->polygons.end(), f.indices.begin(), f.indices.end());
      }
      for (Vec3 v : g.hull->vertices) hull->points.insert(hull->points.end(), {v.x, v.y, v.z});
      geom = dCreateConvex(space_, hull->planes.data(), unsigned(g.hull->faces.size()),
                           hull->points.data(), unsigned(g.hull->vertices.size()),
                           hull->polygons.data());
      hulls_.push_back(std::move(hull));
      break;
    }
  }
  auto info = std::make_unique<GeomInfo>();
  info->body = index;
  info->material = shape.material;
  dGeomSetData(geom, info.get());
  geomInfo_.push_back(std::move(info));
  if (g.type == ShapeType::Plane) return;
  dQuaternion q;
  if (dBodyID body = bodies_[size_t(index)]) {
    dGeomSetBody(geom, body);
    Transform local = shapeInPeerFrame(mass_[size_t(index)], shape.local);
    dGeomSetOffsetPosition(geom, local.p.x, local.p.y, local.p.z);
    setOdeQuat(q, local.q);
    dGeomSetOffsetQuaternion(geom, q);
  } else {
    Transform xf = bodyPose(b) * shape.local;
    dGeomSetPosition(geom, xf.p.x, xf.p.y, xf.p.z);
    setOdeQuat(q, xf.q);
    dGeomSetQuaternion(geom, q);
  }
}

// ODE's hinge angle and slider position are body 1's relative to body 2, and phys's are B's
// relative to A: joints are attached as (B, A), with 0 for the world (ODE swaps a (0, A) pair
// itself and keeps the signs). ODE takes one world anchor for hinges and sliders (B's): like
// phys they hold the bodies as placed, but where a scene's two anchors start apart ODE keeps
// that gap (phys closes it). Ball and distance joints take both anchors.
void OdePeer::addJoint(const SceneJoint& sj) {
  const JointDef& d = sj.def;
  auto bodyOf = [&](int i) { return i < 0 ? dBodyID(nullptr) : bodies_[size_t(i)]; };
  auto worldPoint = [&](int i, Vec3 p) {
    return i < 0 ? p : apply(bodyPose(scene_.bodies[size_t(i)]), p);
  };
  auto worldDir = [&](int i, Vec3 v) {
    return normalize(i < 0 ? v : rotate(scene_.bodies[size_t(i)].rotation, v));
  };
  Vec3 pA = worldPoint(sj.bodyA, d.anchorA), pB = worldPoint(sj.bodyB, d.anchorB);
  Vec3 axis = worldDir(sj.bodyA, d.axisA);
  dJointID j = nullptr;
  switch (d.type) {
    case JointType::Ball: {
      // dJointSetBallAnchor places both anchors at one world point; dJointSetBallAnchor2 then
      // moves body 2's, in body 2's ODE frame (the world's when body 2 is 0).
      j = dJointCreateBall(world_, nullptr);
      bool bFirst = bodyOf(sj.bodyB) != nullptr;
      int second = bFirst ? sj.bodyA : sj.bodyB;
      Vec3 p1 = bFirst ? pB : pA, p2 = bFirst ? pA : pB;
      if (bodyOf(second))
        p2 = pointInPeerFrame(mass_[size_t(second)], bFirst ? d.anchorA : d.anchorB);
      dJointAttach(j, bodyOf(bFirst ? sj.bodyB : sj.bodyA), bodyOf(second));
      dJointSetBallAnchor(j, p1.x, p1.y, p1.z);
      dJointSetBallAnchor2(j, p2.x, p2.y, p2.z);
      break;
    }
    case JointType::Hinge:
      j = dJointCreateHinge(world_, nullptr);
      dJointAttach(j, bodyOf(sj.bodyB), bodyOf(sj.bodyA));
      dJointSetHingeAnchor(j, pB.x, pB.y, pB.z);
      dJointSetHingeAxis(j, axis.x, axis.y, axis.z);
      if (d.enableLimit) {
        dJointSetHingeParam(j, dParamLoStop, d.lower);
        dJointSetHingeParam(j, dParamHiStop, d.upper);
      }
      if (d.enableMotor) {
        dJointSetHingeParam(j, dParamVel, d.motorSpeed);
        dJointSetHingeParam(j, dParamFMax, d.maxMotorForce);
      }
      break;
    case JointType::Fixed:
      j = dJointCreateFixed(world_, nullptr);
      dJointAttach(j, bodyOf(sj.bodyB), bodyOf(sj.bodyA));
      dJointSetFixed(j);
      break;
    case JointType::Prismatic: {
      j = dJointCreateSlider(world_, nullptr);
      dJointAttach(j, bodyOf(sj.bodyB), bodyOf(sj.bodyA));
      dJointSetSliderAxis(j, axis.x, axis.y, axis.z);
      // ODE's slider position is 0 as built; phys's is dot(axis, pB - pA).
      double p0 = dot(axis, pB - pA);
      if (d.enableLimit) {
        dJointSetSliderParam(j, dParamLoStop, d.lower - p0);
        dJointSetSliderParam(j, dParamHiStop, d.upper - p0);
      }
      if (d.enableMotor) {
        dJointSetSliderParam(j, dParamVel, d.motorSpeed);
        dJointSetSliderParam(j, dParamFMax, d.maxMotorForce);
      }
      break;
    }
    case JointType::Distance:  // rigid only (build() rejected limits and springs)
      j = dJointCreateDBall(world_, nullptr);
      dJointAttach(j, bodyOf(sj.bodyB), bodyOf(sj.bodyA));
      dJointSetDBallAnchor1(j, pB.x, pB.y, pB.z);
      dJointSetDBallAnchor2(j, pA.x, pA.y, pA.z);
      dJointSetDBallDistance(j, d.length >= 0 ? d.length : length(pB - pA));
      break;
  }
  if (!d.collideConnected) noCollide_.insert(std::minmax(sj.bodyA, sj.bodyB));
}

void OdePeer::nearCallback(void* self, dGeomID a, dGeomID b) {
  static_cast<OdePeer*>(self)->collidePair(a, b);
}

void OdePeer::collidePair(dGeomID a, dGeomID b) {
  dBodyID ba = dGeomGetBody(a), bb = dGeomGetBody(b);
  // Only pairs with a dynamic body make contacts (static and kinematic bodies are not pushed).
  bool dynA = ba && !dBodyIsKinematic(ba), dynB = bb && !dBodyIsKinematic(bb);
  if (!dynA && !dynB) return;
  const auto* ia = static_cast<const GeomInfo*>(dGeomGetData(a));
  const auto* ib = static_cast<const GeomInfo*>(dGeomGetData(b));
  if (ia->body == ib->body) return;
  if (noCollide_.count(std::minmax(ia->body, ib->body))) return;
  dContact c[kMaxContactsPerPair];
  int n = dCollide(a, b, kMaxContactsPerPair, &c[0].geom, sizeof(dContact));
  double mu = mixFriction(ia->material.friction, ib->material.friction);
  double e = mixRestitution(ia->material.restitution, ib->material.restitution);
  for (int k = 0; k < n; ++k) {
    c[k].surface.mode = dContactApprox1 | (e > 0 ? dContactBounce : 0);
    c[k].surface.mu = mu;
    c[k].surface.bounce = e;
    c[k].surface.bounce_vel = scene_.world.solver.restitutionThreshold;
    dJointID j = dJointCreateContact(world_, contacts_, &c[k]);
    dJointAttach(j, ba, bb);
  }
}

void OdePeer::step() {
  const double h = double(scene_.world.timeStep) / substeps_;
  const Vec3 g = scene_.world.gravity;
  for (int s = 0; s < substeps_; ++s) {
    // ODE's gravity is on or off per body: other gravity scales add the difference.
    for (size_t i = 0; i < bodies_.size(); ++i) {
      const BodyDef& b = scene_.bodies[i];
      if (b.type != BodyType::Dynamic || b.gravityScale == 0 || b.gravityScale == 1) continue;
      Vec3 f = g * float(mass_[i].mass * (b.gravityScale - 1));
      dBodyAddForce(bodies_[i], f.x, f.y, f.z);
    }
    dSpaceCollide(space_, this, &OdePeer::nearCallback);
    dWorldQuickStep(world_, h);
    dJointGroupEmpty(contacts_);
  }
}

void OdePeer::read(std::vector<PeerBodyState>* out) const {
  out->resize(scene_.bodies.size());
  for (size_t i = 0; i < scene_.bodies.size(); ++i) {
    const BodyDef& b = scene_.bodies[i];
    dBodyID body = bodies_[i];
    if (!body) {
      (*out)[i] = {b.position, b.rotation, {}, {}};
      continue;
    }
    const dReal* p = dBodyGetPosition(body);
    const dReal* q = dBodyGetQuaternion(body);
    const dReal* v = dBodyGetLinearVel(body);
    const dReal* w = dBodyGetAngularVel(body);
    (*out)[i] = peerStateToPhys(mass_[i], Vec3{float(p[0]), float(p[1]), float(p[2])},
                                normalize(Quat{float(q[1]), float(q[2]), float(q[3]), float(q[0])}),
                                Vec3{float(v[0]), float(v[1]), float(v[2])},
                                Vec3{float(w[0]), float(w[1]), float(w[2])});
  }
}

}  // namespace

std::unique_ptr<PeerEngine> makeOdePeer() {
  return std::make_unique<OdePeer>();
}

}  // namespace phys::peers
