// The World API: validated edits, queries, and observing states computed elsewhere. The step
// and its stages are in step.cpp.
#include "phys/world/world.h"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <cstring>

#include "dynamics/joints.h"
#include "world/world_impl.h"

namespace phys {

// ---------------------------------------------------------------------------------------------
// Validation: every public edit checks its input completely before changing anything.

namespace {

Status invalid(std::string m) {
  return Status::Error(StatusCode::InvalidArgument, std::move(m));
}
Status notFound(const char* what) {
  return Status::Error(StatusCode::NotFound, std::string(what) + " id is unknown or stale");
}
bool finite(float f) {
  return std::isfinite(f);
}
bool positive(float f) {
  return std::isfinite(f) && f > 0;
}
bool positive(Vec3 v) {
  return positive(v.x) && positive(v.y) && positive(v.z);
}

/// (x, y, z) scaled to length maxLength when longer (computed in double; the result is finite
/// for finite input).
Vec3 clampedLength(double x, double y, double z, float maxLength) {
  const double len = std::sqrt(x * x + y * y + z * z);
  const double s = len > double(maxLength) ? double(maxLength) / len : 1.0;
  return {float(x * s), float(y * s), float(z * s)};
}

/// Accepts quaternions within 1e-3 of unit length (normalizing them); rejects others.
Status checkRotation(Quat* q, const char* what) {
  if (!isFinite(*q)) return invalid(std::string(what) + ": rotation is not finite");
  if (std::fabs(lengthSquared(*q) - 1) > 2e-3f)
    return invalid(std::string(what) + ": rotation is not a unit quaternion");
  *q = normalize(*q);
  return Status::Ok();
}

Status checkMaterial(const Material& m, const std::string& what) {
  if (!finite(m.friction) || m.friction < 0) return invalid(what + ": friction must be >= 0");
  if (!finite(m.restitution) || m.restitution < 0 || m.restitution > 1)
    return invalid(what + ": restitution must be in [0, 1]");
  if (!positive(m.density)) return invalid(what + ": density must be > 0");
  return Status::Ok();
}

Status checkShape(ShapeDef* s, BodyType bodyType, const std::string& what) {
  const ShapeGeom& g = s->geom;
  switch (g.type) {
    case ShapeType::Sphere:
      if (!positive(g.radius)) return invalid(what + ": sphere radius must be > 0");
      break;
    case ShapeType::Box:
      if (!positive(g.halfExtents)) return invalid(what + ": box half extents must be > 0");
      break;
    case ShapeType::Capsule:
      if (!positive(g.radius)) return invalid(what + ": capsule radius must be > 0");
      if (!finite(g.halfHeight) || g.halfHeight < 0)
        return invalid(what + ": capsule half height must be >= 0");
      break;
    case ShapeType::Plane:
      if (!isFinite(g.normal) || length(g.normal) < 1e-6f || !finite(g.offset))
        return invalid(what + ": plane needs a finite non-zero normal and offset");
      if (bodyType != BodyType::Static)
        return Status::Error(StatusCode::IncorrectState,
                             what + ": a plane is only allowed on a static body");
      s->geom.normal = normalize(g.normal);
      break;
    case ShapeType::Hull: {
      if (!g.hull || g.hull->vertices.size() < 4) return invalid(what + ": hull is empty");
      for (Vec3 v : g.hull->vertices)
        if (!isFinite(v)) return invalid(what + ": hull vertex is not finite");
      if (!g.hull->built()) {  // given by its points (ShapeGeom::hullOf, the protocol's hulls)
        std::string error;
        auto built = buildHull(g.hull, &error);
        if (!built) return invalid(what + ": hull points make no hull: " + error);
        s->geom.hull = std::move(built);
      }
      for (const ConvexHull::Face& f : g.hull->faces) {
        if (f.indices.size() < 3) return invalid(what + ": hull face has fewer than 3 vertices");
        for (uint32_t i : f.indices)
          if (i >= g.hull->vertices.size())
            return invalid(what + ": hull face refers to a vertex that does not exist");
      }
      if (!(computeMass(g, 1.0f).mass > 0)) return invalid(what + ": hull encloses no volume");
      break;
    }
    default:
      return invalid(what + ": unknown shape type");
  }
  if (!isFinite(s->local.p)) return invalid(what + ": local position is not finite");
  Status st = checkRotation(&s->local.q, (what + " local").c_str());
  if (!st.ok()) return st;
  return checkMaterial(s->material, what);
}

/// Max distance of a shape's surface from point c (body frame), a bound for swept margins.
float boundRadius(const ShapeDef& s, Vec3 c) {
  Vec3 o = s.local.p - c;
  float r = 0;
  switch (s.geom.type) {
    case ShapeType::Sphere:
      r = s.geom.radius;
      break;
    case ShapeType::Box:
      r = length(s.geom.halfExtents);
      break;
    case ShapeType::Capsule:
      r = s.geom.radius + s.geom.halfHeight;
      break;
    case ShapeType::Plane:
      return 0;
    case ShapeType::Hull:
      for (Vec3 v : s.geom.hull->vertices) r = std::max(r, length(v));
      break;
  }
  return length(o) + r;
}

}  // namespace

Status World::validate(const SolverSettings& s) {
  if (s.substeps < 1 || s.substeps > 64) return invalid("solver.substeps must be in [1, 64]");
  if (s.iterations < 1 || s.iterations > 1000)
    return invalid("solver.iterations must be in [1, 1000]");
  if (s.relaxIterations < 0 || s.relaxIterations > 1000)
    return invalid("solver.relax_iterations must be in [0, 1000]");
  if (!finite(s.baumgarte) || s.baumgarte < 0 || s.baumgarte > 1)
    return invalid("solver.baumgarte must be in [0, 1]");
  if (!positive(s.contactHertz) || !finite(s.contactDampingRatio) || s.contactDampingRatio < 0)
    return invalid("solver.contact_hertz must be > 0 and contact_damping_ratio >= 0");
  if (!positive(s.jointHertz) || !finite(s.jointDampingRatio) || s.jointDampingRatio < 0)
    return invalid("solver.joint_hertz must be > 0 and joint_damping_ratio >= 0");
  if (!positive(s.maxPushout)) return invalid("solver.max_pushout must be > 0");
  if (!finite(s.linearSlop) || s.linearSlop < 0) return invalid("solver.linear_slop must be >= 0");
  if (!finite(s.restitutionThreshold) || s.restitutionThreshold < 0)
    return invalid("solver.restitution_threshold must be >= 0");
  if (s.positionIterations < 0 || s.positionIterations > 1000)
    return invalid("solver.position_iterations must be in [0, 1000]");
  if (!finite(s.positionBaumgarte) || s.positionBaumgarte < 0 || s.positionBaumgarte > 1)
    return invalid("solver.position_baumgarte must be in [0, 1]");
  if (!positive(s.maxPositionCorrection))
    return invalid("solver.max_position_correction must be > 0");
  if (s.scheme == SolverSettings::Scheme::Jacobi &&
      s.equalitySolve == SolverSettings::EqualitySolve::DirectLdl)
    return invalid("solver: equality direct_ldl needs a Gauss-Seidel scheme");
  if (!finite(s.tolerance) || s.tolerance < 0) return invalid("solver.tolerance must be >= 0");
  if (!finite(s.directContactRatio) || (s.directContactRatio != 0 && s.directContactRatio < 1))
    return invalid("solver.direct_contact_ratio must be 0 (never) or >= 1");
  return Status::Ok();
}

// ---------------------------------------------------------------------------------------------
// World lifetime and settings

World::World(const WorldDef& def) : impl_(std::make_unique<Impl>()) {
  impl_->def = def;
  if (!validate(def.solver).ok()) impl_->def.solver = SolverSettings();
  if (!(def.timeStep > 0 && def.timeStep <= 1)) impl_->def.timeStep = 1.0f / 60;
  if (!isFinite(def.gravity)) impl_->def.gravity = WorldDef().gravity;
  impl_->def.threads = resolveThreadCount(std::clamp(def.threads, 0, 64));
  if (impl_->def.threads > 1) impl_->pool = std::make_unique<ThreadPool>(impl_->def.threads);
  impl_->solver.pool = impl_->pool.get();
  impl_->openDevice();
}
World::~World() = default;

const WorldDef& World::def() const {
  return impl_->def;
}

Status World::setGravity(Vec3 g) {
  if (!isFinite(g)) return invalid("gravity must be finite");
  if (!(g == impl_->def.gravity)) {
    impl_->forgetStacks();
    impl_->wakeEverything();
  }
  impl_->def.gravity = g;
  impl_->deviceStale();
  return Status::Ok();
}
Status World::setTimeStep(float dt) {
  if (!(finite(dt) && dt > 0 && dt <= 1)) return invalid("time step must be in (0, 1] s");
  if (dt != impl_->def.timeStep) {
    impl_->forgetStacks();
    impl_->wakeEverything();
  }
  impl_->def.timeStep = dt;
  return Status::Ok();
}
Status World::setSolverSettings(const SolverSettings& s) {
  Status st = validate(s);
  if (!st.ok()) return st;
  const SolverSettings& old = impl_->def.solver;
  if (s.stackStiffening != old.stackStiffening || s.contactHertz != old.contactHertz ||
      s.substeps != old.substeps)
    impl_->forgetStacks();
  if (std::memcmp(&s, &old, sizeof s) != 0) impl_->wakeEverything();
  impl_->def.solver = s;
  return st;
}
void World::setContactBudget(uint32_t maxContactPairs, WorldDef::PairOverflow overflow) {
  impl_->def.maxContactPairs = maxContactPairs;
  impl_->def.pairOverflow = overflow;
}

Status World::validate(const WorldDef& d) {
  if (!isFinite(d.gravity)) return invalid("gravity must be finite");
  if (!(finite(d.timeStep) && d.timeStep > 0 && d.timeStep <= 1))
    return invalid("time step must be in (0, 1] s");
  if (!positive(d.maxLinearSpeed) || !positive(d.maxAngularSpeed))
    return invalid("max linear and angular speeds must be finite and > 0");
  if (!finite(d.speculativeDistance) || d.speculativeDistance < 0 || !finite(d.aabbMargin) ||
      d.aabbMargin < 0)
    return invalid("speculative distance and aabb margin must be finite and >= 0");
  if (!finite(d.guardEnergyJump) || d.guardEnergyJump < 0)
    return invalid("guard energy jump must be finite and >= 0");
  // As a snapshot's bound (snapshot.cpp): a step retried for hours is no guard.
  if (d.guardRetries < 0 || d.guardRetries > 1000) return invalid("guard retries must be in [0, 1000]");
  if (d.pairOverflow != WorldDef::PairOverflow::Drop &&
      d.pairOverflow != WorldDef::PairOverflow::Refuse)
    return invalid("pair overflow must be drop or refuse");
  Status st = validate(d.solver);
  if (!st.ok()) return st;
  return validate(d.sleep);
}

Status World::setDef(const WorldDef& next) {
  Impl& w = *impl_;
  const WorldDef d = next;  // (next may be def() itself)
  if (d.threads != w.def.threads || d.backend != w.def.backend ||
      d.gpuAllowCpuDevice != w.def.gpuAllowCpuDevice)
    return invalid("threads, backend and gpuAllowCpuDevice are fixed when a world is made");
  Status st = validate(d);
  if (!st.ok()) return st;
  // Everything checked: the setters below cannot fail.
  const WorldDef& old = w.def;
  const bool margins =
      d.speculativeDistance != old.speculativeDistance || d.aabbMargin != old.aabbMargin;
  if (!(d.gravity == old.gravity)) setGravity(d.gravity);  // (the device's copy too)
  setTimeStep(d.timeStep);
  setSolverSettings(d.solver);
  setSleepSettings(d.sleep);
  if (margins) w.wakeEverything();  // the sleepers' contacts and boxes were found with the old ones
  w.def.maxLinearSpeed = d.maxLinearSpeed;
  w.def.maxAngularSpeed = d.maxAngularSpeed;
  w.def.speculativeDistance = d.speculativeDistance;
  w.def.aabbMargin = d.aabbMargin;
  w.def.maxContactPairs = d.maxContactPairs;
  w.def.pairOverflow = d.pairOverflow;
  w.def.guard = d.guard;
  w.def.guardEnergyJump = d.guardEnergyJump;
  w.def.guardRetries = d.guardRetries;
  return Status::Ok();
}
const StepProfile& World::profile() const {
  return impl_->profile;
}
const StepStats& World::stats() const {
  return impl_->stats;
}
double World::time() const {
  return impl_->time;
}

// ---------------------------------------------------------------------------------------------
// Bodies

void World::Impl::updateMass(BodyRec& b) {
  if (b.type != BodyType::Dynamic) {
    b.mass = 0;
    b.invMass = 0;
    b.inertiaLocal = Mat3::zero();
    b.invInertiaLocal = Mat3::zero();
    b.localCenter = {};
    for (ShapeId sid : b.shapes) {
      ShapeRec* s = shapes.get(sid);
      s->boundRadius = boundRadius(s->def, {});
    }
    b.com = b.xf.p;
    return;
  }
  // Combine the shapes: centre of mass, then each shape's inertia moved to it (parallel axes).
  double m = 0;
  Vec3 c;
  std::vector<MassProperties> props;
  for (ShapeId sid : b.shapes) {
    const ShapeRec* s = shapes.get(sid);
    MassProperties mp = computeMass(s->def.geom, s->def.material.density);
    mp.center = apply(s->def.local, mp.center);
    mp.inertia = toMat3(s->def.local.q) * mp.inertia * transpose(toMat3(s->def.local.q));
    props.push_back(mp);
    m += mp.mass;
    c += mp.center * mp.mass;
  }
  if (m > 0) c = c / float(m);
  Mat3 I = Mat3::zero();
  for (const MassProperties& mp : props) {
    Vec3 d = mp.center - c;
    I = I + mp.inertia + (Mat3::diagonal({1, 1, 1}) * dot(d, d) - outer(d, d)) * mp.mass;
  }
  float mass = float(m);
  if (!b.autoMass) {
    // A given mass scales the shapes' inertia; with no volume, a unit sphere's shape.
    if (mass > 0)
      I = I * (b.givenMass / mass);
    else
      I = Mat3::diagonal({1, 1, 1}) * (0.4f * b.givenMass * 0.25f);
    mass = b.givenMass;
  }
  if (positive(b.givenInertia)) I = Mat3::diagonal(b.givenInertia);
  b.mass = mass;
  b.invMass = mass > 0 ? 1 / mass : 0;
  b.inertiaLocal = I;
  b.invInertiaLocal = inverse(I);
  // Principal axes for the free-rotation integrator.
  Eigen::Matrix3d Id;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) Id(r, c) = (&I.c0)[c][r];
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(Id);
  Eigen::Matrix3d V = eig.eigenvectors();
  if (V.determinant() < 0) V.col(2) *= -1;  // a rotation, not a reflection
  Eigen::Quaterniond pq(V);
  b.principal = normalize(Quat{float(pq.x()), float(pq.y()), float(pq.z()), float(pq.w())});
  Eigen::Vector3d ev = eig.eigenvalues();
  b.principalMoments = {float(std::max(ev(0), 1e-12)), float(std::max(ev(1), 1e-12)),
                        float(std::max(ev(2), 1e-12))};
  Vec3 oldCom = b.com;
  b.localCenter = c;
  b.com = apply(b.xf, c);
  (void)oldCom;
  for (ShapeId sid : b.shapes) {
    ShapeRec* s = shapes.get(sid);
    s->boundRadius = boundRadius(s->def, c);
  }
}

void World::Impl::syncProxies(BodyId id, bool moved) {
  BodyRec* b = bodies.get(id);
  for (ShapeId sid : b->shapes) {
    ShapeRec* s = shapes.get(sid);
    AABB box = computeAABB(s->def.geom, shapeTransform(*b, *s));
    box = inflate(box, 0.5f * def.speculativeDistance);
    if (s->proxy < 0) {
      s->proxy =
          broadPhase.createProxy(box, def.aabbMargin, sid.index, b->type == BodyType::Static);
    } else if (moved) {
      broadPhase.moveProxy(s->proxy, box, def.aabbMargin);
    }
  }
}

Status World::createBody(const BodyDef& in, BodyId* out) {
  Impl& w = *impl_;
  BodyDef def = in;
  if (def.type != BodyType::Static && def.type != BodyType::Kinematic &&
      def.type != BodyType::Dynamic)
    return invalid("body: unknown type");
  if (!isFinite(def.position)) return invalid("body: position is not finite");
  Status st = checkRotation(&def.rotation, "body");
  if (!st.ok()) return st;
  if (!isFinite(def.linearVelocity) || !isFinite(def.angularVelocity))
    return invalid("body: velocities must be finite");
  if (!finite(def.linearDamping) || def.linearDamping < 0 || !finite(def.angularDamping) ||
      def.angularDamping < 0)
    return invalid("body: damping must be >= 0");
  if (!finite(def.gravityScale)) return invalid("body: gravity scale must be finite");
  if (!finite(def.mass) || def.mass < 0)
    return invalid("body: mass must be >= 0 (0 = from shapes)");
  if (!isFinite(def.inertia) || def.inertia.x < 0 || def.inertia.y < 0 || def.inertia.z < 0)
    return invalid("body: inertia must be >= 0 (0 = from shapes)");
  bool givenInertia = def.inertia.x > 0 || def.inertia.y > 0 || def.inertia.z > 0;
  if (givenInertia && !positive(def.inertia))
    return invalid("body: inertia must have three positive moments, or be all 0");
  for (size_t i = 0; i < def.shapes.size(); ++i) {
    st = checkShape(&def.shapes[i], def.type, "body.shapes[" + std::to_string(i) + "]");
    if (!st.ok()) return st;
  }
  if (def.type == BodyType::Dynamic && def.mass == 0) {
    bool volume = false;
    for (const ShapeDef& s : def.shapes) volume |= s.geom.type != ShapeType::Plane;
    if (!volume) return invalid("body: a dynamic body needs a shape with volume or a mass > 0");
  }

  BodyRec rec;
  rec.type = def.type;
  rec.xf = {def.position, def.rotation};
  rec.v = def.type == BodyType::Static ? Vec3{} : def.linearVelocity;
  rec.w = def.type == BodyType::Static ? Vec3{} : def.angularVelocity;
  rec.linearDamping = def.linearDamping;
  rec.angularDamping = def.angularDamping;
  rec.gravityScale = def.gravityScale;
  rec.gyroscopic = def.gyroscopic;
  rec.allowSleep = def.allowSleep;
  if (def.type == BodyType::Static) rec.solverIndex = 0;
  rec.autoMass = def.mass == 0;
  rec.givenMass = def.mass;
  rec.givenInertia = def.inertia;
  rec.name = def.name;
  BodyId id = w.bodies.add(std::move(rec));
  BodyRec& b = *w.bodies.get(id);
  for (const ShapeDef& s : def.shapes) {
    ShapeRec sr;
    sr.body = id;
    sr.def = s;
    b.shapes.push_back(w.shapes.add(std::move(sr)));
  }
  w.updateMass(b);
  w.syncProxies(id, false);
  if (b.type != BodyType::Static) w.awakeInsert(id.index);
  w.wakeNeighbours(id.index);  // a body made inside a sleeping pile
  w.deviceStale();
  if (out) *out = id;
  return Status::Ok();
}

Status World::destroyBody(BodyId id) {
  Impl& w = *impl_;
  BodyRec* b = w.bodies.get(id);
  if (!b) return notFound("body");
  w.wake(id.index);
  w.wakeNeighbours(id.index);  // what it held or touched
  w.awakeErase(id.index);
  std::vector<JointId> joints = b->joints;
  for (JointId j : joints) destroyJoint(j);
  for (ShapeId sid : b->shapes) {
    ShapeRec* s = w.shapes.get(sid);
    if (s->proxy >= 0) w.broadPhase.destroyProxy(s->proxy);
    w.shapes.remove(sid);
  }
  w.bodies.remove(id);
  w.deviceStale();
  return Status::Ok();
}

bool World::isValid(BodyId id) const {
  return impl_->bodies.valid(id);
}
int World::bodyCount() const {
  return int(impl_->bodies.size());
}
std::vector<BodyId> World::bodies() const {
  std::vector<BodyId> out;
  for (uint32_t i = 0; i < impl_->bodies.capacity(); ++i)
    if (impl_->bodies.alive(i)) out.push_back(impl_->bodies.idAt(i));
  return out;
}

Status World::setTransform(BodyId id, Vec3 position, Quat rotation) {
  BodyRec* b = impl_->bodies.get(id);
  if (!b) return notFound("body");
  if (!isFinite(position)) return invalid("set transform: position is not finite");
  Status st = checkRotation(&rotation, "set transform");
  if (!st.ok()) return st;
  impl_->wake(id.index);
  impl_->wakeNeighbours(id.index);  // where it was
  b->xf = {position, rotation};
  b->com = apply(b->xf, b->localCenter);
  impl_->syncProxies(id, true);
  impl_->wakeNeighbours(id.index);  // where it is
  impl_->deviceEdited(id.index);
  return Status::Ok();
}

Status World::setVelocity(BodyId id, Vec3 linear, Vec3 angular) {
  BodyRec* b = impl_->bodies.get(id);
  if (!b) return notFound("body");
  if (!isFinite(linear) || !isFinite(angular)) return invalid("set velocity: not finite");
  if (b->type == BodyType::Static)
    return Status::Error(StatusCode::IncorrectState, "set velocity: the body is static");
  impl_->wake(id.index);
  b->v = linear;
  b->w = angular;
  impl_->deviceEdited(id.index);
  return Status::Ok();
}

Status World::setBodyType(BodyId id, BodyType type) {
  Impl& w = *impl_;
  BodyRec* b = w.bodies.get(id);
  if (!b) return notFound("body");
  if (type != BodyType::Static && type != BodyType::Kinematic && type != BodyType::Dynamic)
    return invalid("set body type: unknown type");
  for (ShapeId sid : b->shapes) {
    if (w.shapes.get(sid)->def.geom.type == ShapeType::Plane && type != BodyType::Static)
      return Status::Error(StatusCode::IncorrectState,
                           "set body type: a body with a plane must stay static");
  }
  if (type == BodyType::Dynamic && b->autoMass) {
    bool volume = !b->shapes.empty();
    if (!volume) return invalid("set body type: a dynamic body needs a shape or a mass");
  }
  w.wake(id.index);
  w.wakeNeighbours(id.index);
  b->type = type;
  if (type == BodyType::Static) {
    b->v = b->w = {};
    b->solverIndex = 0;
    w.awakeErase(id.index);
  } else {
    w.awakeInsert(id.index);
  }
  w.updateMass(*b);
  for (ShapeId sid : b->shapes) {
    ShapeRec* s = w.shapes.get(sid);
    w.broadPhase.setStatic(s->proxy, type == BodyType::Static);
  }
  w.deviceStale();
  return Status::Ok();
}

Status World::setMass(BodyId id, float mass, Vec3 inertia) {
  BodyRec* b = impl_->bodies.get(id);
  if (!b) return notFound("body");
  if (!positive(mass)) return invalid("set mass: mass must be > 0");
  if (!isFinite(inertia) || !(inertia == Vec3{} || positive(inertia)))
    return invalid("set mass: inertia must be three positive moments, or all 0");
  if (b->type != BodyType::Dynamic)
    return Status::Error(StatusCode::IncorrectState, "set mass: the body is not dynamic");
  impl_->wake(id.index);
  b->autoMass = false;
  b->givenMass = mass;
  b->givenInertia = inertia;
  impl_->updateMass(*b);
  impl_->deviceStale();
  return Status::Ok();
}

Status World::setMaterial(BodyId id, const Material& m) {
  BodyRec* b = impl_->bodies.get(id);
  if (!b) return notFound("body");
  Status st = checkMaterial(m, "set material");
  if (!st.ok()) return st;
  impl_->wake(id.index);
  impl_->wakeNeighbours(id.index);  // what rests on it (a floor made slippery)
  for (ShapeId sid : b->shapes) impl_->shapes.get(sid)->def.material = m;
  impl_->updateMass(*b);
  impl_->deviceStale();
  return Status::Ok();
}

Status World::applyForce(BodyId id, Vec3 force, Vec3 point) {
  BodyRec* b = impl_->bodies.get(id);
  if (!b) return notFound("body");
  if (!isFinite(force) || !isFinite(point)) return invalid("apply force: not finite");
  if (b->type != BodyType::Dynamic) return Status::Ok();
  impl_->wake(id.index);
  b->force += force;
  b->torque += cross(point - b->com, force);
  impl_->deviceEdited(id.index);
  return Status::Ok();
}

Status World::applyTorque(BodyId id, Vec3 torque) {
  BodyRec* b = impl_->bodies.get(id);
  if (!b) return notFound("body");
  if (!isFinite(torque)) return invalid("apply torque: not finite");
  if (b->type == BodyType::Dynamic) {
    impl_->wake(id.index);
    b->torque += torque;
  }
  impl_->deviceEdited(id.index);
  return Status::Ok();
}

Status World::applyImpulse(BodyId id, Vec3 impulse, Vec3 point) {
  BodyRec* b = impl_->bodies.get(id);
  if (!b) return notFound("body");
  if (!isFinite(impulse) || !isFinite(point)) return invalid("apply impulse: not finite");
  if (b->type != BodyType::Dynamic) return Status::Ok();
  impl_->wake(id.index);
  Mat3 R = toMat3(b->xf.q);
  Mat3 invI = R * b->invInertiaLocal * transpose(R);
  const Vec3 r = point - b->com;
  const Vec3 v = b->v + impulse * b->invMass;
  const Vec3 w = b->w + invI * cross(r, impulse);
  // The speed clamps hold between steps too: an impulse too large for the body's mass would
  // otherwise leave a velocity far past them (or infinite) until the next step clamps it, which
  // getBody, snapshots and a server's world description (the codec bounds speeds) would read.
  // Within the clamps the result is the plain float sum, as before.
  const float maxV = impl_->def.maxLinearSpeed, maxW = impl_->def.maxAngularSpeed;
  if (isFinite(v) && length(v) <= maxV) {
    b->v = v;
  } else {
    const double m = b->invMass;
    b->v = clampedLength(double(b->v.x) + double(impulse.x) * m,
                         double(b->v.y) + double(impulse.y) * m,
                         double(b->v.z) + double(impulse.z) * m, maxV);
  }
  if (isFinite(w) && length(w) <= maxW) {
    b->w = w;
  } else {
    // r x impulse and invI times it in double: every product of finite floats is finite there.
    const double cx = double(r.y) * impulse.z - double(r.z) * impulse.y;
    const double cy = double(r.z) * impulse.x - double(r.x) * impulse.z;
    const double cz = double(r.x) * impulse.y - double(r.y) * impulse.x;
    auto row = [&](int i) {
      return double(invI.c0[i]) * cx + double(invI.c1[i]) * cy + double(invI.c2[i]) * cz;
    };
    b->w = clampedLength(double(b->w.x) + row(0), double(b->w.y) + row(1),
                         double(b->w.z) + row(2), maxW);
  }
  impl_->deviceEdited(id.index);
  return Status::Ok();
}

Status World::getBody(BodyId id, BodyState* out) const {
  const BodyRec* b = impl_->bodies.get(id);
  if (!b) return notFound("body");
  out->id = id;
  out->type = b->type;
  out->position = b->xf.p;
  out->rotation = b->xf.q;
  out->linearVelocity = b->v;
  out->angularVelocity = b->w;
  out->centerOfMass = b->com;
  out->mass = b->mass;
  Mat3 R = toMat3(b->xf.q);
  out->inertia = R * b->inertiaLocal * transpose(R);
  out->sleeping = b->asleep();
  out->allowSleep = b->allowSleep;
  return Status::Ok();
}

BodyDef bodyDefOf(const Pool<ShapeRec, ShapeTag>& shapes, const BodyRec& b) {
  const bool dynamic = b.type == BodyType::Dynamic;
  BodyDef d;
  d.type = b.type;
  d.position = b.xf.p;
  d.rotation = b.xf.q;
  d.linearVelocity = b.v;
  d.angularVelocity = b.w;
  d.linearDamping = b.linearDamping;
  d.angularDamping = b.angularDamping;
  d.gravityScale = b.gravityScale;
  // Only a dynamic body has a mass (a body made static keeps what it was given, unused).
  d.mass = dynamic && !b.autoMass ? b.givenMass : 0;
  d.inertia = dynamic ? b.givenInertia : Vec3{};
  d.gyroscopic = b.gyroscopic;
  d.allowSleep = b.allowSleep;
  d.name = b.name;
  d.shapes.reserve(b.shapes.size());
  for (ShapeId sid : b.shapes) d.shapes.push_back(shapes.get(sid)->def);
  return d;
}

Status World::getBodyDef(BodyId id, BodyDef* out, BodyMass* mass) const {
  const Impl& w = *impl_;
  const BodyRec* b = w.bodies.get(id);
  if (!b) return notFound("body");
  const bool dynamic = b->type == BodyType::Dynamic;
  if (out) *out = bodyDefOf(w.shapes, *b);
  if (mass) {
    *mass = BodyMass{};
    if (dynamic) {
      mass->mass = b->mass;
      mass->localCenter = b->localCenter;
      mass->inertia = b->principalMoments;
      mass->inertiaRotation = b->principal;
    }
  }
  return Status::Ok();
}

std::vector<ShapeId> World::bodyShapes(BodyId id) const {
  const BodyRec* b = impl_->bodies.get(id);
  return b ? b->shapes : std::vector<ShapeId>{};
}

Status World::getShape(ShapeId id, ShapeDef* out, BodyId* body) const {
  const ShapeRec* s = impl_->shapes.get(id);
  if (!s) return notFound("shape");
  if (out) *out = s->def;
  if (body) *body = s->body;
  return Status::Ok();
}

Status World::addShape(BodyId id, const ShapeDef& in, ShapeId* out) {
  Impl& w = *impl_;
  BodyRec* b = w.bodies.get(id);
  if (!b) return notFound("body");
  ShapeDef def = in;
  Status st = checkShape(&def, b->type, "add shape");
  if (!st.ok()) return st;
  w.wake(id.index);
  ShapeRec sr;
  sr.body = id;
  sr.def = def;
  ShapeId sid = w.shapes.add(std::move(sr));
  b->shapes.push_back(sid);
  w.updateMass(*b);
  w.syncProxies(id, false);
  w.wakeNeighbours(id.index);
  w.deviceStale();
  if (out) *out = sid;
  return Status::Ok();
}

Status World::removeShape(ShapeId id) {
  Impl& w = *impl_;
  ShapeRec* s = w.shapes.get(id);
  if (!s) return notFound("shape");
  BodyRec* b = w.bodies.get(s->body);
  if (b->type == BodyType::Dynamic && b->autoMass && b->shapes.size() == 1)
    return Status::Error(StatusCode::IncorrectState,
                         "remove shape: the last shape of a dynamic body carries its mass");
  w.wake(s->body.index);
  w.wakeNeighbours(s->body.index);
  if (s->proxy >= 0) w.broadPhase.destroyProxy(s->proxy);
  b->shapes.erase(std::find(b->shapes.begin(), b->shapes.end(), id));
  w.shapes.remove(id);
  w.updateMass(*b);
  w.deviceStale();
  return Status::Ok();
}

// ---------------------------------------------------------------------------------------------
// Joints

void World::Impl::rebuildNoCollide() {
  noCollide.clear();
  for (uint32_t i = 0; i < joints.capacity(); ++i) {
    if (!joints.alive(i)) continue;
    const JointDef& d = joints.at(i).def;
    if (!d.collideConnected && !d.bodyA.isNull())
      noCollide.insert(bodyPairKey(d.bodyA.index, d.bodyB.index));
  }
}

Status World::createJoint(const JointDef& in, JointId* out) {
  Impl& w = *impl_;
  JointDef def = in;
  if (uint8_t(def.type) > uint8_t(JointType::Prismatic)) return invalid("joint: unknown type");
  BodyRec* A = nullptr;
  if (!def.bodyA.isNull()) {
    A = w.bodies.get(def.bodyA);
    if (!A) return notFound("joint body_a");
  }
  BodyRec* B = w.bodies.get(def.bodyB);
  if (!B) return notFound("joint body_b");
  if (def.bodyA == def.bodyB) return invalid("joint: body_a and body_b are the same body");
  if (!isFinite(def.anchorA) || !isFinite(def.anchorB)) return invalid("joint: anchors not finite");
  if (!isFinite(def.axisA) || !isFinite(def.axisB) || length(def.axisA) < 1e-6f ||
      length(def.axisB) < 1e-6f)
    return invalid("joint: axes must be finite and non-zero");
  if (!finite(def.lower) || !finite(def.upper) || (def.enableLimit && def.lower > def.upper))
    return invalid("joint: limits must be finite with lower <= upper");
  if (!finite(def.motorSpeed) || !finite(def.maxMotorForce) || def.maxMotorForce < 0)
    return invalid("joint: motor speed must be finite and max force >= 0");
  if (!finite(def.length) || !finite(def.springHertz) || def.springHertz < 0 ||
      !finite(def.springDampingRatio) || def.springDampingRatio < 0)
    return invalid("joint: length, spring hertz and damping must be finite (hertz, damping >= 0)");
  if (def.type == JointType::Hinge && def.enableLimit && (def.lower < -kPi || def.upper > kPi))
    return invalid("joint: hinge limits must lie within [-pi, pi] (the angle is measured in it)");
  if (def.type == JointType::Distance && def.enableLimit && def.lower < 0)
    return invalid("joint: distance limits must be >= 0");
  def.axisA = normalize(def.axisA);
  def.axisB = normalize(def.axisB);
  JointRec rec;
  rec.def = def;
  BodyPose pa = A ? poseOf(*A) : BodyPose{}, pb = poseOf(*B);
  initJoint(rec, A ? &pa : nullptr, pb);
  // A rigid or sprung distance joint pulls along the line between its anchors; at zero
  // length that line has no direction and the joint holds nothing.
  if (def.type == JointType::Distance && (!def.enableLimit || def.springHertz > 0) &&
      !(rec.length >= JointRec::kMinDistanceLength))
    return invalid("joint: a distance joint needs a rest length of at least 1 mm (got " +
                   std::to_string(rec.length) + " m); a ball joint pins two points together");
  if (A) w.wake(def.bodyA.index);
  w.wake(def.bodyB.index);
  JointId id = w.joints.add(std::move(rec));
  w.joints.get(id)->state.id = id;
  if (A) A->joints.push_back(id);
  B->joints.push_back(id);
  if (!def.collideConnected && A)
    w.noCollide.insert(Impl::bodyPairKey(def.bodyA.index, def.bodyB.index));
  w.deviceStale();
  if (out) *out = id;
  return Status::Ok();
}

Status World::destroyJoint(JointId id) {
  Impl& w = *impl_;
  JointRec* j = w.joints.get(id);
  if (!j) return notFound("joint");
  for (BodyId bid : {j->def.bodyA, j->def.bodyB})
    if (w.bodies.get(bid)) w.wake(bid.index);
  for (BodyId bid : {j->def.bodyA, j->def.bodyB}) {
    if (BodyRec* b = w.bodies.get(bid)) {
      auto it = std::find(b->joints.begin(), b->joints.end(), id);
      if (it != b->joints.end()) b->joints.erase(it);
    }
  }
  w.joints.remove(id);
  w.rebuildNoCollide();
  w.deviceStale();
  return Status::Ok();
}

Status World::setMotor(JointId id, bool enable, float speed, float maxForce) {
  JointRec* j = impl_->joints.get(id);
  if (!j) return notFound("joint");
  if (!finite(speed) || !finite(maxForce) || maxForce < 0)
    return invalid("set motor: speed must be finite and max force >= 0");
  if (j->def.type != JointType::Hinge && j->def.type != JointType::Prismatic)
    return Status::Error(StatusCode::IncorrectState,
                         "set motor: only hinges and sliders have motors");
  for (BodyId bid : {j->def.bodyA, j->def.bodyB})
    if (impl_->bodies.get(bid)) impl_->wake(bid.index);
  j->def.enableMotor = enable;
  j->def.motorSpeed = speed;
  j->def.maxMotorForce = maxForce;
  impl_->deviceStale();
  return Status::Ok();
}

Status World::getJoint(JointId id, JointDef* def, JointState* state) const {
  const JointRec* j = impl_->joints.get(id);
  if (!j) return notFound("joint");
  if (def) *def = j->def;
  if (state) *state = j->state;
  return Status::Ok();
}

std::vector<JointId> World::joints() const {
  std::vector<JointId> out;
  for (uint32_t i = 0; i < impl_->joints.capacity(); ++i)
    if (impl_->joints.alive(i)) out.push_back(impl_->joints.idAt(i));
  return out;
}
int World::jointCount() const {
  return int(impl_->joints.size());
}

// ---------------------------------------------------------------------------------------------
// Observing states computed elsewhere (peer engines): the step's collision stages only

Status World::observe(const std::vector<BodyId>& ids, const std::vector<ObservedBody>& states,
                      double stepMs) {
  Impl& w = *impl_;
  if (ids.size() != states.size()) return invalid("observe: ids and states differ in size");
  std::vector<ObservedBody> checked = states;
  for (size_t i = 0; i < ids.size(); ++i) {
    if (!w.bodies.get(ids[i])) return notFound("body");
    ObservedBody& s = checked[i];
    if (!isFinite(s.position) || !isFinite(s.linearVelocity) || !isFinite(s.angularVelocity))
      return invalid("observe: state " + std::to_string(i) + " is not finite");
    Status st = checkRotation(&s.rotation, "observe");
    if (!st.ok()) return st;
  }

  w.wakeAll();  // every body observed moves
  w.stats.energyBefore = energy();
  for (size_t i = 0; i < ids.size(); ++i) {
    BodyRec& b = *w.bodies.get(ids[i]);
    const ObservedBody& s = checked[i];
    bool moved = !(b.xf.p == s.position && b.xf.q == s.rotation);
    b.xf = {s.position, s.rotation};
    b.com = apply(b.xf, b.localCenter);
    if (b.type != BodyType::Static) {
      b.v = s.linearVelocity;
      b.w = s.angularVelocity;
    } else if (moved) {
      w.syncProxies(ids[i], true);  // updateBounds moves only non-static proxies
    }
  }
  const float dt = w.def.timeStep;
  w.updateBounds(dt);
  w.broadPhaseStage();
  w.narrowPhase(dt);
  w.collectStepJoints();
  for (uint32_t i : w.stepJoints)
    w.joints.at(i).state.reactionForce = w.joints.at(i).state.reactionTorque = {};
  w.measureJoints();

  w.time += dt;
  w.stats.step++;
  w.stats.bodies = int(w.bodies.size());
  w.stats.awake = 0;
  for (uint32_t i = 0; i < w.bodies.capacity(); ++i)
    if (w.bodies.alive(i) && w.bodies.at(i).type != BodyType::Static) w.stats.awake++;
  w.stats.joints = jointCount();
  w.stats.velocityResidual = 0;
  w.stats.iterationsUsed = 0;
  w.stats.guardRetries = 0;
  w.stats.contactsBetweenHalves = -1;
  w.stats.contactParts = 0;
  w.stats.energyAfter = energy();
  w.profile = StepProfile();
  w.profile.total = stepMs;
  w.deviceStale();
  return Status::Ok();
}

// ---------------------------------------------------------------------------------------------
// Queries

std::vector<ContactInfo> World::contacts() const {
  std::vector<ContactInfo> out;
  // The awake contacts, then the sleeping islands' (at rest, as they were when they slept).
  std::vector<const Contact*> all;
  for (const Contact& c : impl_->contacts) all.push_back(&c);
  for (const SleepingIsland& is : impl_->islands)
    for (const Contact& c : is.contacts) all.push_back(&c);
  for (const Contact* cp : all) {
    const Contact& c = *cp;
    if (c.manifold.count == 0) continue;
    // Shapes removed since the last step leave their contacts until the next broad phase.
    if (!impl_->shapes.valid(c.idA) || !impl_->shapes.valid(c.idB)) continue;
    ContactInfo ci;
    ci.bodyA = c.bodyA;
    ci.bodyB = c.bodyB;
    ci.shapeA = c.idA;
    ci.shapeB = c.idB;
    ci.manifold = c.manifold;
    std::memcpy(ci.normalImpulse, c.normalImpulse, sizeof ci.normalImpulse);
    out.push_back(ci);
  }
  return out;
}

double World::energy() const {
  const Impl& w = *impl_;
  double e = 0;
  const Vec3 g = w.def.gravity;
  // The awake bodies, then the sleeping ones (at rest: their islands' potential energy).
  // (takeSnapshot sums the same terms in the same order: keep them alike.)
  for (uint32_t i : w.awakeBodies) {
    const BodyRec& b = w.bodies.at(i);
    if (b.type != BodyType::Dynamic) continue;
    e += bodyEnergy(b, g);
  }
  if (w.sleepingBodyCount > 0) e += w.sleepingPotential();
  return e;
}

double World::Impl::stepEnergy() {
  // World::energy's terms, formed on the world's threads and summed in its order (a body
  // that is not dynamic adds +0.0, which changes no bit of a sum that began at +0.0).
  const size_t n = awakeBodies.size();
  energyTerms.resize(n);
  const Vec3 g = def.gravity;
  forEachRange(n, [&](size_t begin, size_t end) {
    for (size_t k = begin; k < end; ++k) {
      const BodyRec& b = bodies.at(awakeBodies[k]);
      energyTerms[k].energy = b.type == BodyType::Dynamic ? bodyEnergy(b, g) : 0.0;
    }
  });
  double e = 0;
  for (size_t k = 0; k < n; ++k) e += energyTerms[k].energy;
  if (sleepingBodyCount > 0) e += sleepingPotential();
  return e;
}

uint64_t World::stateHash() const {
  // FNV-1a over the bits of every body's position and rotation, in id order.
  uint64_t h = 1469598103934665603ull;
  auto mix = [&h](const void* data, size_t n) {
    const unsigned char* p = static_cast<const unsigned char*>(data);
    for (size_t i = 0; i < n; ++i) {
      h ^= p[i];
      h *= 1099511628211ull;
    }
  };
  const Impl& w = *impl_;
  for (uint32_t i = 0; i < w.bodies.capacity(); ++i) {
    if (!w.bodies.alive(i)) continue;
    const BodyRec& b = w.bodies.at(i);
    float v[7] = {b.xf.p.x, b.xf.p.y, b.xf.p.z, b.xf.q.x, b.xf.q.y, b.xf.q.z, b.xf.q.w};
    mix(&i, sizeof i);
    mix(v, sizeof v);
  }
  return h;
}

}  // namespace phys
