// Bullet 3.24 adapter (docs/PEERS.md): btDiscreteDynamicsWorld with Bullet's sequential
// impulse solver at its defaults (10 iterations, split impulse on, warm starting), sleeping
// (deactivation) as the scene's sleep switch says, at Bullet's own defaults (2 s below
// 0.8 m/s and 1 rad/s), the scene's masses, inertias and centres of mass from peer_common.h.
#include <BulletCollision/CollisionDispatch/btManifoldResult.h>
#include <BulletDynamics/ConstraintSolver/btFixedConstraint.h>
#include <btBulletDynamicsCommon.h>

#include <algorithm>
#include <cmath>

#include "peers/peer.h"
#include "peers/peer_common.h"

namespace phys::peers {
namespace {

btVector3 bt(Vec3 v) {
  return {v.x, v.y, v.z};
}
btQuaternion bt(Quat q) {
  return {q.x, q.y, q.z, q.w};
}
btTransform bt(const Transform& t) {
  return btTransform(bt(t.q), bt(t.p));
}
Vec3 toVec(const btVector3& v) {
  return {float(v.x()), float(v.y()), float(v.z())};
}
Quat toQuat(const btQuaternion& q) {
  return {float(q.x()), float(q.y()), float(q.z()), float(q.w())};
}

// phys's material mixing instead of Bullet's products (friction fa * fb, restitution ea * eb).
// Bullet reads these process-wide hooks in every contact it creates.
btScalar combinedFriction(const btCollisionObject* a, const btCollisionObject* b) {
  return btScalar(mixFriction(a->getFriction(), b->getFriction()));
}
btScalar combinedRestitution(const btCollisionObject* a, const btCollisionObject* b) {
  return btScalar(mixRestitution(a->getRestitution(), b->getRestitution()));
}

/// A frame whose x axis is `x` and z axis is `z` (both unit and perpendicular), at `origin`.
btTransform frame(Vec3 origin, Vec3 x, Vec3 z) {
  Vec3 y = cross(z, x);
  btMatrix3x3 basis(x.x, y.x, z.x, x.y, y.y, z.y, x.z, y.z, z.z);
  return btTransform(basis, bt(origin));
}

class BulletPeer : public PeerEngine {
 public:
  ~BulletPeer() override {
    if (!world_) return;
    for (auto& c : constraints_) world_->removeConstraint(c.get());
    for (auto& b : bodies_) world_->removeRigidBody(b.get());
  }

  std::string name() const override { return "bullet"; }
  std::string version() const override {
    int v = btGetVersion();
    return std::to_string(v / 100) + "." + std::to_string(v % 100);
  }

  Status build(const Scene& scene, const PeerBudget& budget) override {
    if (world_) return engineError("bullet: build() called twice");
    Status st = computePeerBodies(scene, &mass_);
    if (!st.ok()) return st;
    static const bool hooked = [] {  // once, so that runs in parallel threads do not race
      gCalculateCombinedFrictionCallback = combinedFriction;
      gCalculateCombinedRestitutionCallback = combinedRestitution;
      return true;
    }();
    (void)hooked;
    dt_ = scene.world.timeStep;
    sleep_ = scene.world.sleep.enabled;
    substeps_ = std::max(budget.substeps, 1);
    config_ = std::make_unique<btDefaultCollisionConfiguration>();
    dispatcher_ = std::make_unique<btCollisionDispatcher>(config_.get());
    broadphase_ = std::make_unique<btDbvtBroadphase>();
    solver_ = std::make_unique<btSequentialImpulseConstraintSolver>();
    world_ = std::make_unique<btDiscreteDynamicsWorld>(dispatcher_.get(), broadphase_.get(),
                                                       solver_.get(), config_.get());
    world_->setGravity(bt(scene.world.gravity));
    if (budget.iterations > 0) world_->getSolverInfo().m_numIterations = budget.iterations;

    for (size_t i = 0; i < scene.bodies.size(); ++i) {
      st = addBody(scene.bodies[i], mass_[i], "bodies[" + std::to_string(i) + "]");
      if (!st.ok()) return st;
    }
    for (size_t i = 0; i < scene.joints.size(); ++i) {
      st = addJoint(scene, scene.joints[i], "joints[" + std::to_string(i) + "]");
      if (!st.ok()) return st;
    }
    return Status::Ok();
  }

  void step() override {
    const float h = dt_ / float(substeps_);
    for (int s = 0; s < substeps_; ++s) {
      moveKinematicBodies(h);
      // One fixed step per call: Bullet's accumulator (stepSimulation(dt, n, dt / n)) can
      // take n - 1 or n + 1 substeps when dt / (dt / n) rounds below n.
      world_->stepSimulation(h, 0, h);
    }
  }

  void read(std::vector<PeerBodyState>* out) const override {
    out->resize(bodies_.size());
    for (size_t i = 0; i < bodies_.size(); ++i) {
      const btRigidBody& b = *bodies_[i];
      const btTransform& xf = b.getCenterOfMassTransform();
      (*out)[i] = peerStateToPhys(mass_[i], toVec(xf.getOrigin()), toQuat(xf.getRotation()),
                                  toVec(b.getLinearVelocity()), toVec(b.getAngularVelocity()));
    }
    for (const Kinematic& k : kinematic_) {
      (*out)[k.body].linearVelocity = k.linearVelocity;
      (*out)[k.body].angularVelocity = k.angularVelocity;
    }
  }

 private:
  /// The collision shape of one phys shape, in its own frame (nullptr: unsupported).
  std::unique_ptr<btCollisionShape> makeShape(const ShapeGeom& g) {
    switch (g.type) {
      case ShapeType::Sphere:
        return std::make_unique<btSphereShape>(g.radius);
      case ShapeType::Box:
        return std::make_unique<btBoxShape>(bt(g.halfExtents));
      case ShapeType::Capsule:  // phys's capsule runs along z; Bullet's height is the segment
        return std::make_unique<btCapsuleShapeZ>(g.radius, 2 * g.halfHeight);
      case ShapeType::Plane:
        return std::make_unique<btStaticPlaneShape>(bt(g.normal), g.offset);
      case ShapeType::Hull: {
        auto hull = std::make_unique<btConvexHullShape>();
        for (Vec3 v : g.hull->vertices) hull->addPoint(bt(v), false);
        hull->recalcLocalAabb();
        return hull;
      }
    }
    return nullptr;
  }

  /// One shape for the body in its peer frame: the shape itself when it sits at the frame's
  /// origin, else a compound with each shape at its offset from the centre of mass (a body
  /// without shapes, whose mass the scene gives, gets an empty shape).
  btCollisionShape* bodyShape(const BodyDef& def, const PeerBodyMass& m) {
    auto keep = [&](std::unique_ptr<btCollisionShape> s) {
      shapes_.push_back(std::move(s));
      return shapes_.back().get();
    };
    if (def.shapes.empty()) return keep(std::make_unique<btEmptyShape>());  // mass given
    if (def.shapes.size() == 1) {
      Transform t = shapeInPeerFrame(m, def.shapes[0].local);
      if (lengthSquared(t.p) < 1e-12f && std::fabs(std::fabs(t.q.w) - 1) < 1e-7f)
        return keep(makeShape(def.shapes[0].geom));
    }
    auto compound = std::make_unique<btCompoundShape>();
    for (const ShapeDef& s : def.shapes) {
      btCollisionShape* child = keep(makeShape(s.geom));
      compound->addChildShape(bt(shapeInPeerFrame(m, s.local)), child);
    }
    return keep(std::move(compound));
  }

  Status addBody(const BodyDef& def, const PeerBodyMass& m, const std::string& what) {
    for (size_t k = 1; k < def.shapes.size(); ++k) {
      const Material &a = def.shapes[0].material, &b = def.shapes[k].material;
      if (a.friction != b.friction || a.restitution != b.restitution)
        return unsupported(what +
                           ": shapes of one body with different materials (Bullet has "
                           "one friction and restitution per body)");
    }
    const bool dynamic = def.type == BodyType::Dynamic;
    btCollisionShape* shape = bodyShape(def, m);
    btRigidBody::btRigidBodyConstructionInfo info(btScalar(m.mass), nullptr, shape,
                                                  dynamic ? bt(m.principalInertia) : btVector3());
    info.m_startWorldTransform = bt(toPeerPose(m, def.position, def.rotation));
    const Material material = def.shapes.empty() ? Material() : def.shapes[0].material;
    info.m_friction = material.friction;
    info.m_restitution = material.restitution;
    // phys damps v *= 1 / (1 + dt c) per step, Bullet v *= (1 - d)^dt: the same factor per step.
    auto damping = [&](float c) {
      return btScalar(std::clamp(1 - std::pow(1 + double(dt_) * c, -1.0 / dt_), 0.0, 1.0));
    };
    info.m_linearDamping = damping(def.linearDamping);
    info.m_angularDamping = damping(def.angularDamping);
    auto body = std::make_unique<btRigidBody>(info);
    if (def.type == BodyType::Kinematic)
      body->setCollisionFlags(body->getCollisionFlags() | btCollisionObject::CF_KINEMATIC_OBJECT);
    // Deactivation (Bullet's sleeping) when the scene sleeps; its thresholds are Bullet's.
    if (!sleep_) body->setActivationState(DISABLE_DEACTIVATION);
    body->setLinearVelocity(bt(def.linearVelocity));
    body->setAngularVelocity(bt(def.angularVelocity));
    body->setFlags(def.gyroscopic ? BT_ENABLE_GYROSCOPIC_FORCE_IMPLICIT_BODY : 0);
    world_->addRigidBody(body.get());
    if (dynamic) body->setGravity(world_->getGravity() * def.gravityScale);
    if (def.type == BodyType::Kinematic)
      kinematic_.push_back({bodies_.size(), def.linearVelocity, def.angularVelocity});
    bodies_.push_back(std::move(body));
    return Status::Ok();
  }

  /// phys moves kinematic bodies at their velocities; Bullet wants their poses set before
  /// each step (it derives their velocities from the motion, so the scene's are kept here).
  void moveKinematicBodies(float h) {
    for (const Kinematic& k : kinematic_) {
      btTransform& xf = bodies_[k.body]->getWorldTransform();
      const float angle = length(k.angularVelocity) * h;
      if (angle > 0)
        xf.setRotation(bt(Quat::fromAxisAngle(k.angularVelocity, angle)) * xf.getRotation());
      xf.setOrigin(xf.getOrigin() + bt(k.linearVelocity) * h);
    }
  }

  Status addJoint(const Scene& scene, const SceneJoint& sj, const std::string& what) {
    const JointDef& d = sj.def;
    // A world anchor is a static body at the origin: anchors stay world points. (This peer's
    // own, not btTypedConstraint::getFixedBody(), which every Bullet world would share.)
    static const PeerBodyMass kWorld;
    const PeerBodyMass& mA = sj.bodyA >= 0 ? mass_[size_t(sj.bodyA)] : kWorld;
    const PeerBodyMass& mB = mass_[size_t(sj.bodyB)];
    if (sj.bodyA < 0 && !worldBody_)
      worldBody_ = std::make_unique<btRigidBody>(0, nullptr, nullptr);
    btRigidBody& A = sj.bodyA >= 0 ? *bodies_[size_t(sj.bodyA)] : *worldBody_;
    btRigidBody& B = *bodies_[size_t(sj.bodyB)];
    const Quat qA = sj.bodyA >= 0 ? scene.bodies[size_t(sj.bodyA)].rotation : Quat{};
    const Quat qB = scene.bodies[size_t(sj.bodyB)].rotation;
    const Vec3 pA = pointInPeerFrame(mA, d.anchorA), pB = pointInPeerFrame(mB, d.anchorB);
    // Joint frames (world directions x, z carried into each body's peer frame at the scene's
    // initial pose) for hinges (z along the axis), sliders (x along it) and welds: B's frame
    // equals A's in the world at the start, so angles and translations start at 0 as phys's.
    const Vec3 axisW = normalize(rotate(qA, d.axisA));
    Vec3 refW, unused;
    tangentBasis(axisW, &refW, &unused);
    auto frameIn = [&](const PeerBodyMass& m, Quat q, Vec3 origin, Vec3 x, Vec3 z) {
      return frame(origin, directionInPeerFrame(m, invRotate(q, x)),
                   directionInPeerFrame(m, invRotate(q, z)));
    };

    std::unique_ptr<btTypedConstraint> c;
    switch (d.type) {
      case JointType::Ball:
        c = std::make_unique<btPoint2PointConstraint>(A, B, bt(pA), bt(pB));
        break;
      case JointType::Hinge: {
        // B's z is its own axis (phys corrects any initial misalignment), x the shared
        // reference carried into B at the initial pose, as phys's refB.
        Vec3 zB = rotate(qB, normalize(d.axisB));
        Vec3 xB = normalize(refW - zB * dot(refW, zB));
        // Bullet's hinge angle, limits and motor turn the other way round its z axis than
        // phys's round the joint axis (its rows act on wA - wB): its z is minus the axis.
        auto hinge = std::make_unique<btHingeConstraint>(A, B, frameIn(mA, qA, pA, refW, -axisW),
                                                         frameIn(mB, qB, pB, xB, -zB));
        if (d.enableLimit) hinge->setLimit(d.lower, d.upper);
        if (d.enableMotor)
          hinge->enableAngularMotor(true, d.motorSpeed, d.maxMotorForce * dt_ / substeps_);
        c = std::move(hinge);
        break;
      }
      case JointType::Fixed:
        c = std::make_unique<btFixedConstraint>(A, B, frameIn(mA, qA, pA, {1, 0, 0}, {0, 0, 1}),
                                                frameIn(mB, qB, pB, {1, 0, 0}, {0, 0, 1}));
        break;
      case JointType::Prismatic: {
        Vec3 y = cross(axisW, refW);
        auto slider = std::make_unique<btSliderConstraint>(A, B, frameIn(mA, qA, pA, axisW, y),
                                                           frameIn(mB, qB, pB, axisW, y), true);
        if (d.enableLimit) {
          slider->setLowerLinLimit(d.lower);
          slider->setUpperLinLimit(d.upper);
        }
        if (d.enableMotor) {
          slider->setPoweredLinMotor(true);
          slider->setTargetLinMotorVelocity(d.motorSpeed);
          slider->setMaxLinMotorForce(d.maxMotorForce);
        }
        c = std::move(slider);
        break;
      }
      case JointType::Distance:
        return unsupported(what +
                           ": distance joints (Bullet has no point-to-point distance "
                           "constraint; a 6-dof spring constrains along axes, not radially)");
    }
    world_->addConstraint(c.get(), !d.collideConnected);
    constraints_.push_back(std::move(c));
    return Status::Ok();
  }

  std::vector<PeerBodyMass> mass_;
  float dt_ = 1.0f / 60;
  bool sleep_ = false;  ///< deactivation on (the scene sleeps)
  int substeps_ = 1;
  std::unique_ptr<btDefaultCollisionConfiguration> config_;
  std::unique_ptr<btCollisionDispatcher> dispatcher_;
  std::unique_ptr<btDbvtBroadphase> broadphase_;
  std::unique_ptr<btSequentialImpulseConstraintSolver> solver_;
  std::unique_ptr<btDiscreteDynamicsWorld> world_;
  std::vector<std::unique_ptr<btCollisionShape>> shapes_;
  std::vector<std::unique_ptr<btRigidBody>> bodies_;  ///< one per scene body, static ones too
  struct Kinematic {
    size_t body;
    Vec3 linearVelocity, angularVelocity;
  };
  std::vector<Kinematic> kinematic_;
  std::unique_ptr<btRigidBody> worldBody_;  ///< joints' world anchor, not in the world
  std::vector<std::unique_ptr<btTypedConstraint>> constraints_;
};

}  // namespace

std::unique_ptr<PeerEngine> makeBulletPeer() {
  return std::make_unique<BulletPeer>();
}

}  // namespace phys::peers
