// The Box3D peer (github.com/erincatto/box3d, built from -DPHYS_BOX3D_DIR; docs/PEERS.md): one
// b3World per run, stepped by b3World_Step with the scene's time step.
//
// Settings (Box3D's own defaults where the scene says nothing, what a game using it runs with):
//   - substeps: PeerBudget::substeps when > 1, else Box3D's default 4 (its soft-step solver takes
//     one iteration per substep plus a relax pass; it has no iteration count, so a budget with
//     iterations > 0 is reported as unsupported);
//   - threads: Box3D's own task system (its internal scheduler, b3WorldDef::workerCount =
//     PeerBudget::threads; 1 runs serially on the caller's thread, no scheduler);
//   - contact softness (30 Hz, damping ratio 10, push-out 3 m/s), linear slop 5 mm, continuous
//     collision on, warm starting on, contact recycling on: Box3D's defaults;
//   - from the scene: gravity, the restitution threshold, the linear speed clamp, sleeping (the
//     world's switch, each body's allowSleep, the linear sleep speed; Box3D's time to sleep is
//     a constant 0.5 s, phys's default).
// Box3D's body frame is phys's own: a Box3D body takes a centre of mass anywhere in its frame
// and a full inertia tensor about it (b3Body_SetMassData), so each body sits at phys's body
// origin and rotation, its shapes at their `local` transforms and its joint frames at phys's
// anchors, with no conversion. The masses, centres of mass and inertias are phys's
// (computePeerBodies; the tensor is R diag(I) R^T of its principal form). Box3D reports the
// origin's pose and the centre of mass's linear velocity, as phys does.
// Box3D has no plane: a static plane becomes a large static box (see planeBox).
#include <box3d/box3d.h>
#include <box3d/collision.h>
#include <box3d/constants.h>
#include <box3d/math_functions.h>
#include <box3d/types.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <string>

#include "peers/peer.h"
#include "peers/peer_common.h"

namespace phys::peers {
namespace {

constexpr int kDefaultSubsteps = 4;  // Box3D's documented "usually 4" (b3World_Step)

b3Vec3 b3(Vec3 v) {
  return {v.x, v.y, v.z};
}
b3Quat b3(Quat q) {
  return {{q.x, q.y, q.z}, q.w};
}
b3Transform b3(const Transform& t) {
  return {b3(t.p), b3(t.q)};
}
Vec3 toVec(b3Vec3 v) {
  return {v.x, v.y, v.z};
}
Quat toQuat(b3Quat q) {
  return {q.v.x, q.v.y, q.v.z, q.s};
}

/// The rotation whose columns are x, y = z cross x, z (x and z unit and perpendicular).
Quat basis(Vec3 x, Vec3 z) {
  const Vec3 y = cross(z, x);
  const b3Matrix3 m{b3(x), b3(y), b3(z)};
  return normalize(toQuat(b3MakeQuatFromMatrix(&m)));
}

bool isIdentity(const Transform& t) {
  return lengthSquared(t.p) == 0 && t.q.x == 0 && t.q.y == 0 && t.q.z == 0 && std::fabs(t.q.w) == 1;
}

class Box3dPeer : public PeerEngine {
 public:
  ~Box3dPeer() override {
    if (b3World_IsValid(world_)) b3DestroyWorld(world_);
    for (auto& [hull, data] : hulls_) b3DestroyHull(data);
  }

  std::string name() const override { return "box3d"; }
  std::string version() const override {
    const b3Version v = b3GetVersion();
    return std::to_string(v.major) + "." + std::to_string(v.minor) + "." +
           std::to_string(v.revision);
  }

  Status build(const Scene& scene, const PeerBudget& budget) override {
    if (b3World_IsValid(world_)) return engineError("box3d: build() called twice");
    if (budget.iterations > 0)
      return unsupported(
          "solver iterations (Box3D's soft-step solver takes one iteration per substep; its "
          "budget is the substep count, PeerBudget::substeps)");
    Status st = computePeerBodies(scene, &mass_);
    if (!st.ok()) return st;
    dt_ = scene.world.timeStep;
    substeps_ = budget.substeps > 1 ? budget.substeps : kDefaultSubsteps;

    b3WorldDef def = b3DefaultWorldDef();
    def.gravity = b3(scene.world.gravity);
    def.restitutionThreshold = scene.world.solver.restitutionThreshold;
    def.maximumLinearSpeed = scene.world.maxLinearSpeed;
    def.enableSleep = scene.world.sleep.enabled;
    def.workerCount = uint32_t(std::clamp(budget.threads, 1, int(B3_MAX_WORKERS)));
    for (const BodyDef& b : scene.bodies) {
      const bool isStatic = b.type == BodyType::Static;
      (isStatic ? def.capacity.staticBodyCount : def.capacity.dynamicBodyCount) += 1;
      (isStatic ? def.capacity.staticShapeCount : def.capacity.dynamicShapeCount) +=
          int(b.shapes.size());
    }
    world_ = b3CreateWorld(&def);
    if (!b3World_IsValid(world_))
      return engineError("box3d: b3CreateWorld failed (more than B3_MAX_WORLDS worlds?)");

    planeCentre_ = sceneCentre(scene);
    bodies_.reserve(scene.bodies.size());
    for (size_t i = 0; i < scene.bodies.size(); ++i) {
      st = addBody(scene, scene.bodies[i], mass_[i], "bodies[" + std::to_string(i) + "]");
      if (!st.ok()) return st;
    }
    for (size_t i = 0; i < scene.joints.size(); ++i) {
      st = addJoint(scene, scene.joints[i], "joints[" + std::to_string(i) + "]");
      if (!st.ok()) return st;
    }
    return Status::Ok();
  }

  void step() override { b3World_Step(world_, dt_, substeps_); }

  void read(std::vector<PeerBodyState>* out) const override {
    out->resize(bodies_.size());
    for (size_t i = 0; i < bodies_.size(); ++i) {
      const b3BodyId id = bodies_[i];
      const b3Transform xf = b3Body_GetTransform(id);
      // Origin and rotation of phys's body frame; the centre of mass's linear velocity.
      (*out)[i] = {toVec(xf.p), toQuat(xf.q), toVec(b3Body_GetLinearVelocity(id)),
                   toVec(b3Body_GetAngularVelocity(id))};
    }
  }

 private:
  /// Where the plane boxes are centred (projected onto each plane): the mean position of the
  /// scene's bodies without planes (the origin when there are none).
  static Vec3 sceneCentre(const Scene& scene) {
    Vec3 sum;
    int n = 0;
    for (const BodyDef& b : scene.bodies) {
      bool plane = false;
      for (const ShapeDef& s : b.shapes) plane = plane || s.geom.type == ShapeType::Plane;
      if (plane) continue;
      sum += b.position;
      ++n;
    }
    return n ? sum / float(n) : Vec3{};
  }

  /// Half the side of a plane's box: 400 m (Box3D's large_pyramid ground) or more, so that
  /// every body of the scene lies over it with 100 m to spare.
  float planeHalfSide(const Scene& scene) const {
    float reach = 0;
    for (const BodyDef& b : scene.bodies)
      reach = std::max(reach, length(b.position - planeCentre_));
    return std::max(400.0f, reach + 100);
  }

  b3ShapeDef shapeDef(const ShapeDef& s) const {
    b3ShapeDef d = b3DefaultShapeDef();
    d.baseMaterial.friction = s.material.friction;
    d.baseMaterial.restitution = s.material.restitution;
    // Box3D mixes as phys does (its defaults: friction sqrt(fa fb), restitution max(ea, eb)).
    d.updateBodyMass = false;  // phys's mass properties are set once the shapes are on
    return d;
  }

  /// One phys shape on Box3D body `body` (whose frame is phys's body frame).
  Status addShape(const Scene& scene, const BodyDef& def, b3BodyId body, const ShapeDef& s,
                  const std::string& what) {
    const b3ShapeDef sd = shapeDef(s);
    const ShapeGeom& g = s.geom;
    b3ShapeId id = b3_nullShapeId;
    switch (g.type) {
      case ShapeType::Sphere: {
        b3Sphere sphere{b3(s.local.p), g.radius};
        id = b3CreateSphereShape(body, &sd, &sphere);
        break;
      }
      case ShapeType::Capsule: {  // phys's capsule runs along its local z
        const Vec3 half = rotate(s.local.q, {0, 0, g.halfHeight});
        if (2 * g.halfHeight < B3_MIN_CAPSULE_LENGTH) {
          // Box3D's shortest capsule is its linear slop (5 mm); below it, a sphere.
          b3Sphere sphere{b3(s.local.p), g.radius};
          id = b3CreateSphereShape(body, &sd, &sphere);
        } else {
          b3Capsule capsule{b3(s.local.p - half), b3(s.local.p + half), g.radius};
          id = b3CreateCapsuleShape(body, &sd, &capsule);
        }
        break;
      }
      case ShapeType::Box: {
        const b3BoxHull box = b3MakeTransformedBoxHull(g.halfExtents.x, g.halfExtents.y,
                                                       g.halfExtents.z, b3(s.local));
        id = b3CreateHullShape(body, &sd, &box.base);
        break;
      }
      case ShapeType::Hull: {
        if (!g.hull) return engineError("box3d: " + what + ": a hull shape without its hull");
        const b3HullData* hull = hullData(*g.hull);
        if (!hull)
          return unsupported(what + ": a hull of " + std::to_string(g.hull->vertices.size()) +
                             " vertices that b3CreateHull rejects (Box3D's hulls have at most " +
                             std::to_string(B3_MAX_HULL_VERTICES) + " vertices and faces)");
        id = isIdentity(s.local)
                 ? b3CreateHullShape(body, &sd, hull)
                 : b3CreateTransformedHullShape(body, &sd, hull, b3(s.local), b3Vec3{1, 1, 1});
        break;
      }
      case ShapeType::Plane: {
        if (def.type != BodyType::Static)
          return unsupported(what +
                             ": a plane on a body that is not static (Box3D has no "
                             "plane; a static one becomes a large box)");
        id = planeBox(scene, def, body, s, sd);
        break;
      }
    }
    if (!b3Shape_IsValid(id))
      return engineError("box3d: " + what + ": Box3D refused a " + std::string(toString(g.type)) +
                         " shape");
    return Status::Ok();
  }

  /// A static plane as a box 1 m thick whose top face is the plane, 400 m or more on a side
  /// (planeHalfSide), centred under the scene (Box3D's own benchmarks use a 400 x 400 m box).
  b3ShapeId planeBox(const Scene& scene, const BodyDef& def, b3BodyId body, const ShapeDef& s,
                     const b3ShapeDef& sd) {
    constexpr float kHalfThickness = 0.5f;
    // The plane in the body frame: dot(n, x) = d, n and d from its shape's local transform.
    const Vec3 n = normalize(rotate(s.local.q, s.geom.normal));
    const float d = s.geom.offset + dot(n, s.local.p);
    // The scene's centre in the body frame, projected onto the plane, then half a box below.
    Vec3 c = invRotate(def.rotation, planeCentre_ - def.position);
    c = c - n * (dot(n, c) - d) - n * kHalfThickness;
    Vec3 x, y;
    tangentBasis(n, &x, &y);
    const float side = planeHalfSide(scene);
    const b3BoxHull box =
        b3MakeTransformedBoxHull(side, side, kHalfThickness, b3(Transform{c, basis(x, n)}));
    return b3CreateHullShape(body, &sd, &box.base);
  }

  /// The Box3D hull of a phys hull (its vertices, in the shape's frame), made once per hull.
  const b3HullData* hullData(const ConvexHull& hull) {
    auto it = hulls_.find(&hull);
    if (it != hulls_.end()) return it->second;
    std::vector<b3Vec3> points;
    points.reserve(hull.vertices.size());
    for (Vec3 v : hull.vertices) points.push_back(b3(v));
    b3HullData* data = nullptr;
    if (hull.vertices.size() <= size_t(B3_MAX_HULL_VERTICES))
      data = b3CreateHull(points.data(), int(points.size()), B3_MAX_HULL_VERTICES);
    if (data) hulls_[&hull] = data;
    return data;
  }

  Status addBody(const Scene& scene, const BodyDef& def, const PeerBodyMass& m,
                 const std::string& what) {
    if (def.type == BodyType::Dynamic && !def.gyroscopic)
      return unsupported(what +
                         ": gyroscopic false (Box3D always integrates the gyroscopic "
                         "torque, implicitly)");
    b3BodyDef bd = b3DefaultBodyDef();
    bd.type = def.type == BodyType::Static      ? b3_staticBody
              : def.type == BodyType::Kinematic ? b3_kinematicBody
                                                : b3_dynamicBody;
    bd.position = b3(def.position);
    bd.rotation = b3(normalize(def.rotation));
    // phys damps v *= 1 / (1 + h c) per step, Box3D the same per substep: c' with
    // (1 + (h / n) c')^n = 1 + h c gives the same factor per step.
    auto damping = [&](float c) {
      const double h = dt_, n = substeps_;
      return float(n / h * (std::pow(1 + h * c, 1 / n) - 1));
    };
    bd.linearDamping = damping(def.linearDamping);
    bd.angularDamping = damping(def.angularDamping);
    bd.gravityScale = def.gravityScale;
    bd.enableSleep = def.allowSleep;
    bd.sleepThreshold = scene.world.sleep.linearSpeed;
    const b3BodyId body = b3CreateBody(world_, &bd);
    bodies_.push_back(body);
    for (const ShapeDef& s : def.shapes) {
      Status st = addShape(scene, def, body, s, what);
      if (!st.ok()) return st;
    }
    if (def.type == BodyType::Dynamic) {
      // phys's inertia about the centre of mass in body axes: R diag(I) R^T.
      const Mat3 r = toMat3(m.principalRotation);
      const Mat3 inertia = r * Mat3::diagonal(m.principalInertia) * transpose(r);
      b3MassData md;
      md.mass = float(m.mass);
      md.center = b3(m.comLocal);
      md.inertia = {b3(inertia.c0), b3(inertia.c1), b3(inertia.c2)};
      b3Body_SetMassData(body, md);
    } else {
      b3Body_ApplyMassFromShapes(body);  // zero mass, but the extents kinematic sleep needs
    }
    if (def.type != BodyType::Static) {
      // The centre of mass's velocity, set once the centre is in place (a body definition's
      // velocity is its origin's).
      b3Body_SetLinearVelocity(body, b3(def.linearVelocity));
      b3Body_SetAngularVelocity(body, b3(def.angularVelocity));
    }
    return Status::Ok();
  }

  /// The static body at the origin that joints to the world (body_a null) attach to.
  b3BodyId worldAnchor() {
    if (!b3Body_IsValid(worldAnchor_)) {
      b3BodyDef bd = b3DefaultBodyDef();
      worldAnchor_ = b3CreateBody(world_, &bd);
    }
    return worldAnchor_;
  }

  Status addJoint(const Scene& scene, const SceneJoint& sj, const std::string& what) {
    const JointDef& d = sj.def;
    const b3BodyId A = sj.bodyA >= 0 ? bodies_[size_t(sj.bodyA)] : worldAnchor();
    const b3BodyId B = bodies_[size_t(sj.bodyB)];
    const Quat qA = sj.bodyA >= 0 ? normalize(scene.bodies[size_t(sj.bodyA)].rotation) : Quat{};
    const Quat qB = normalize(scene.bodies[size_t(sj.bodyB)].rotation);
    const Vec3 xA = sj.bodyA >= 0 ? scene.bodies[size_t(sj.bodyA)].position : Vec3{};
    const Vec3 xB = scene.bodies[size_t(sj.bodyB)].position;

    // Joint frames in each body's frame (phys's body frames: anchors as they are). A world
    // rotation W of the joint frame becomes qA^-1 W in A and qB^-1 W in B, so both frames
    // agree in the world at the initial pose: angles and translations start at 0 as phys's.
    const Vec3 axisW = normalize(rotate(qA, d.axisA));
    Vec3 refW, unused;
    tangentBasis(axisW, &refW, &unused);
    auto frame = [](Vec3 anchor, Quat bodyRotation, Quat worldRotation) {
      return b3(Transform{anchor, normalize(conjugate(bodyRotation) * worldRotation)});
    };
    auto setBase = [&](b3JointDef* b, Quat worldA, Quat worldB) {
      b->bodyIdA = A;
      b->bodyIdB = B;
      b->localFrameA = frame(d.anchorA, qA, worldA);
      b->localFrameB = frame(d.anchorB, qB, worldB);
      b->collideConnected = d.collideConnected;
    };

    b3JointId id = b3_nullJointId;
    switch (d.type) {
      case JointType::Ball: {
        b3SphericalJointDef j = b3DefaultSphericalJointDef();
        setBase(&j.base, Quat{}, Quat{});
        id = b3CreateSphericalJoint(world_, &j);
        break;
      }
      case JointType::Hinge: {
        // Box3D's revolute turns about the frames' z: A's is the axis, B's is B's own axis
        // (phys corrects any initial misalignment), x the shared reference carried into B.
        const Vec3 zB = normalize(rotate(qB, d.axisB));
        const Vec3 xRefB = normalize(refW - zB * dot(refW, zB));
        b3RevoluteJointDef j = b3DefaultRevoluteJointDef();
        setBase(&j.base, basis(refW, axisW), basis(xRefB, zB));
        if (d.enableLimit) {
          j.enableLimit = true;
          j.lowerAngle = d.lower;
          j.upperAngle = d.upper;
        }
        if (d.enableMotor) {
          j.enableMotor = true;
          j.motorSpeed = d.motorSpeed;
          j.maxMotorTorque = d.maxMotorForce;
        }
        id = b3CreateRevoluteJoint(world_, &j);
        break;
      }
      case JointType::Fixed: {
        b3WeldJointDef j = b3DefaultWeldJointDef();  // 0 Hz: Box3D's stiffest weld
        setBase(&j.base, Quat{}, Quat{});
        id = b3CreateWeldJoint(world_, &j);
        break;
      }
      case JointType::Prismatic: {
        // Box3D's prismatic slides B along frame A's x; its translation is 0 where the frame
        // origins coincide (phys's: the anchors' separation along the axis).
        const Quat w = basis(axisW, refW);
        b3PrismaticJointDef j = b3DefaultPrismaticJointDef();
        setBase(&j.base, w, w);
        if (d.enableLimit) {
          j.enableLimit = true;
          j.lowerTranslation = d.lower;
          j.upperTranslation = d.upper;
        }
        if (d.enableMotor) {
          j.enableMotor = true;
          j.motorSpeed = d.motorSpeed;
          j.maxMotorForce = d.maxMotorForce;
        }
        id = b3CreatePrismaticJoint(world_, &j);
        break;
      }
      case JointType::Distance: {
        b3DistanceJointDef j = b3DefaultDistanceJointDef();
        setBase(&j.base, Quat{}, Quat{});
        const Vec3 pA = xA + rotate(qA, d.anchorA), pB = xB + rotate(qB, d.anchorB);
        j.length = d.length >= 0 ? d.length : length(pB - pA);
        if (d.springHertz > 0) {  // else rigid (Box3D's rigid distance ignores the limits)
          j.enableSpring = true;
          j.hertz = d.springHertz;
          j.dampingRatio = d.springDampingRatio;
          if (d.enableLimit) {
            j.enableLimit = true;
            j.minLength = d.lower;
            j.maxLength = d.upper;
          }
        }
        id = b3CreateDistanceJoint(world_, &j);
        break;
      }
    }
    if (!b3Joint_IsValid(id))
      return engineError("box3d: " + what + ": Box3D refused a " + std::string(toString(d.type)) +
                         " joint");
    return Status::Ok();
  }

  std::vector<PeerBodyMass> mass_;
  float dt_ = 1.0f / 60;
  int substeps_ = kDefaultSubsteps;
  Vec3 planeCentre_;
  b3WorldId world_ = b3_nullWorldId;
  std::vector<b3BodyId> bodies_;  ///< one per scene body, static ones too
  b3BodyId worldAnchor_ = b3_nullBodyId;
  std::map<const ConvexHull*, b3HullData*> hulls_;  ///< b3CreateHull's, destroyed last
};

}  // namespace

std::unique_ptr<PeerEngine> makeBox3dPeer() {
  return std::make_unique<Box3dPeer>();
}

}  // namespace phys::peers
