// World API (validated edits) and the step, whose stages read top to bottom in World::step.
#include "phys/world.h"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstring>

#include "joints.h"
#include "world_impl.h"

namespace phys {

// ---------------------------------------------------------------------------------------------
// Names

const char* toString(StatusCode c) {
  switch (c) {
    case StatusCode::Ok:
      return "OK";
    case StatusCode::InvalidArgument:
      return "INVALID_ARGUMENT";
    case StatusCode::NotFound:
      return "NOT_FOUND";
    case StatusCode::IncorrectState:
      return "INCORRECT_STATE";
    case StatusCode::ResourceExhausted:
      return "RESOURCE_EXHAUSTED";
  }
  return "?";
}
const char* toString(BodyType t) {
  switch (t) {
    case BodyType::Static:
      return "static";
    case BodyType::Kinematic:
      return "kinematic";
    case BodyType::Dynamic:
      return "dynamic";
  }
  return "?";
}
const char* toString(JointType t) {
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

// ---------------------------------------------------------------------------------------------
// Validation: every public edit checks its input completely before changing anything.

namespace {

constexpr float kMinDistanceLength = 1e-3f;  ///< m, shortest rest length of a distance joint
/// Contacts per chunk of the parallel narrow phase and manifold build (a box pair's narrow
/// phase takes about 0.2 us).
constexpr size_t kContactGrain = 256;

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

double nowMs() {
  return std::chrono::duration<double, std::milli>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

/// Times one stage into its profile field.
class StageTimer {
 public:
  explicit StageTimer(double* field) : field_(field), start_(nowMs()) {}
  ~StageTimer() { *field_ += nowMs() - start_; }

 private:
  double* field_;
  double start_;
};

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
  if (!(g == impl_->def.gravity)) impl_->forgetStacks();
  impl_->def.gravity = g;
  impl_->deviceStale();
  return Status::Ok();
}
Status World::setTimeStep(float dt) {
  if (!(finite(dt) && dt > 0 && dt <= 1)) return invalid("time step must be in (0, 1] s");
  if (dt != impl_->def.timeStep) impl_->forgetStacks();
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
  impl_->def.solver = s;
  return st;
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
  w.deviceStale();
  if (out) *out = id;
  return Status::Ok();
}

Status World::destroyBody(BodyId id) {
  Impl& w = *impl_;
  BodyRec* b = w.bodies.get(id);
  if (!b) return notFound("body");
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
  b->xf = {position, rotation};
  b->com = apply(b->xf, b->localCenter);
  impl_->syncProxies(id, true);
  impl_->deviceEdited(id.index);
  return Status::Ok();
}

Status World::setVelocity(BodyId id, Vec3 linear, Vec3 angular) {
  BodyRec* b = impl_->bodies.get(id);
  if (!b) return notFound("body");
  if (!isFinite(linear) || !isFinite(angular)) return invalid("set velocity: not finite");
  if (b->type == BodyType::Static)
    return Status::Error(StatusCode::IncorrectState, "set velocity: the body is static");
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
  b->type = type;
  if (type == BodyType::Static) b->v = b->w = {};
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
  b->force += force;
  b->torque += cross(point - b->com, force);
  impl_->deviceEdited(id.index);
  return Status::Ok();
}

Status World::applyTorque(BodyId id, Vec3 torque) {
  BodyRec* b = impl_->bodies.get(id);
  if (!b) return notFound("body");
  if (!isFinite(torque)) return invalid("apply torque: not finite");
  if (b->type == BodyType::Dynamic) b->torque += torque;
  impl_->deviceEdited(id.index);
  return Status::Ok();
}

Status World::applyImpulse(BodyId id, Vec3 impulse, Vec3 point) {
  BodyRec* b = impl_->bodies.get(id);
  if (!b) return notFound("body");
  if (!isFinite(impulse) || !isFinite(point)) return invalid("apply impulse: not finite");
  if (b->type != BodyType::Dynamic) return Status::Ok();
  Mat3 R = toMat3(b->xf.q);
  Mat3 invI = R * b->invInertiaLocal * transpose(R);
  b->v += impulse * b->invMass;
  b->w += invI * cross(point - b->com, impulse);
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
  ShapeRec sr;
  sr.body = id;
  sr.def = def;
  ShapeId sid = w.shapes.add(std::move(sr));
  b->shapes.push_back(sid);
  w.updateMass(*b);
  w.syncProxies(id, false);
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
      !(rec.length >= kMinDistanceLength))
    return invalid("joint: a distance joint needs a rest length of at least 1 mm (got " +
                   std::to_string(rec.length) + " m); a ball joint pins two points together");
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
// The step

namespace {
std::atomic<bool> gVectorizedContacts{true};
}  // namespace

void setVectorizedContacts(bool on) {
  gVectorizedContacts = on;
}
bool vectorizedContacts() {
  return gVectorizedContacts;
}

void World::step() {
  Impl& w = *impl_;
  w.stats.guardRetries = 0;
  if (!w.def.guard) {
    stepOnce(w.def.solver.substeps);
    return;
  }
  w.takeSnapshot();
  int substeps = w.def.solver.substeps;
  stepOnce(substeps);
  std::string fault = w.checkHealth();
  for (int retry = 0; !fault.empty() && retry < w.def.guardRetries; ++retry) {
    // Roll back and redo with a safer setting: twice the substeps.
    w.stats.guardRetries++;
    w.stats.lastGuardEvent = "step " + std::to_string(w.stats.step) + ": " + fault;
    w.restoreSnapshot();
    // Twice what the failed attempt took (stack stiffening may have taken more than asked).
    substeps = std::min(std::max(substeps, w.stats.substeps) * 2, 64);
    stepOnce(substeps);
    fault = w.checkHealth();
  }
  if (w.stats.guardRetries > 0) w.stats.guardEvents++;
  if (!fault.empty()) w.quarantine();
}

void World::stepOnce(int substeps) {
  Impl& w = *impl_;
  const float dt = w.def.timeStep;
  SolverSettings s = w.def.solver;
  s.substeps = substeps;
  StepProfile& p = w.profile;
  p = StepProfile();
  const double t0 = nowMs();
  w.stats.energyBefore = energy();

  {
    StageTimer t(&p.applyCommands);
    w.applyCommands();
  }
  // The GPU backend takes the whole step when it covers everything the step needs
  // (world_gpu.cpp); otherwise the CPU stages below take it from the same host mirror.
  if (w.device) w.rescaleWarmStarts(dt / float(substeps));  // joints' go up when stale
  if (w.device && w.stepOnDevice(substeps)) {
    // The device does not measure stacks: it runs the preset's substeps. Its joint impulses
    // come back to the host in that unit.
    w.stats.substeps = substeps;
    w.stats.substepTime = dt / float(substeps);
    w.stats.stackDepth = 0;
    w.stats.stackHertz = 0;
    w.stats.contactsBetweenHalves = -1;
    w.time += dt;
    w.stats.step++;
    w.stats.energyAfter = energy();
    p.total = nowMs() - t0;
    return;
  }
  {
    StageTimer t(&p.updateBounds);
    w.updateBounds(dt);
  }
  {
    StageTimer t(&p.broadPhase);
    w.broadPhaseStage();
  }
  {
    StageTimer t(&p.narrowPhase);
    w.narrowPhase(dt);
  }
  {
    // Islands and colors are not needed by the serial solver; the stacks' depth is.
    StageTimer t(&p.buildIslands);
    w.stiffenForStacks(dt, &s);
  }
  w.stats.substeps = s.substeps;
  const float h = dt / float(s.substeps);
  // The split push-out only where there is something to push out: a step whose contacts are
  // all shallower than kSplitDepth is the unsplit solve (vectorized contacts, no pseudo
  // velocities), the same bits as without the option.
  if (s.splitPushout && !(w.stats.maxPenetration > SolverSettings::kSplitDepth))
    s.splitPushout = false;
  {
    StageTimer t(&p.prepare);
    w.rescaleWarmStarts(h);
    w.buildSolverBodies(s);
  }
  Solver& solver = w.solver;
  // Joints solved directly (LDL hybrid) or iterated with everything else.
  bool direct = false;
  if (s.equalitySolve == SolverSettings::EqualitySolve::DirectLdl) {
    StageTimer t(&p.prepare);
    w.ldl.analyze(solver);
    direct = w.ldl.factor(solver);
  }
  const float equalityBias = Solver::equalityBiasRate(s, h);
  auto iterate = [&](bool useBias) {
    float change = solver.solveIteration(s, h, useBias, direct);
    if (direct) change = std::max(change, w.ldl.solve(solver, equalityBias, useBias));
    return change;
  };
  int iterationsUsed = 0;
  for (int sub = 0; sub < s.substeps; ++sub) {
    {
      StageTimer t(&p.integrateVelocities);
      solver.integrateVelocities(h, w.def.maxLinearSpeed, w.def.maxAngularSpeed);
    }
    if (sub > 0) {
      StageTimer t(&p.prepare);
      w.refreshJoints(h);
      if (direct) direct = w.ldl.factor(solver);
    }
    {
      StageTimer t(&p.warmStart);
      solver.warmStart();
    }
    {
      StageTimer t(&p.solve);
      // Convergence control: stop once an iteration barely changes any row's velocity.
      for (int it = 0; it < s.iterations; ++it) {
        ++iterationsUsed;
        if (iterate(true) <= s.tolerance && s.tolerance > 0) break;
      }
    }
    {
      StageTimer t(&p.integratePositions);
      if (s.splitPushout) solver.solvePushout(s, h, s.iterations, direct ? &w.ldl : nullptr);
      solver.integratePositions(h);
    }
    {
      StageTimer t(&p.relax);
      for (int it = 0; it < s.relaxIterations; ++it) iterate(false);
    }
  }
  {
    StageTimer t(&p.restitution);
    if (s.restitution) solver.applyRestitution(s.restitutionThreshold);
  }
  if (w.wide.active) {
    StageTimer t(&p.storeImpulses);
    w.wide.store(w.manifolds);  // the step's contact impulses, for storeImpulses
  }
  if (s.positionPass != SolverSettings::PositionPass::None && s.positionIterations > 0) {
    StageTimer t(&p.positionPass);
    solver.positionPass(s, s.positionIterations,
                        s.positionPass == SolverSettings::PositionPass::NonlinearJacobi);
  }
  {
    StageTimer t(&p.storeImpulses);
    w.stats.velocityResidual = solver.velocityResidual(h);
    w.stats.iterationsUsed = iterationsUsed;
    w.storeImpulses();
    w.stats.substepTime = h;
  }
  {
    StageTimer t(&p.finalize);
    w.finalize(h);
  }
  w.backend.cpuSteps++;
  w.deviceStale();  // the CPU moved the bodies: the device's copy is old

  w.time += dt;
  w.stats.step++;
  w.stats.energyAfter = energy();
  p.total = nowMs() - t0;
}

void World::Impl::rescaleWarmStarts(float h) {
  // Warm starts are impulses per substep: the substeps just changed length (stack
  // stiffening, a guard retry, a new time step), so last step's impulses are scaled to keep
  // the forces they stand for.
  const float before = stats.substepTime;
  stats.substepTime = h;  // their unit from here on
  if (!(before > 0) || before == h) return;
  // Bounded, so that a corrupt or absurd unit cannot blow the impulses up.
  const float k = std::clamp(h / before, 1e-4f, 1e4f);
  for (Contact& c : contacts) {
    for (float& f : c.normalImpulse) f *= k;
    for (auto& t : c.tangentImpulse) t[0] *= k, t[1] *= k;
  }
  for (uint32_t i = 0; i < joints.capacity(); ++i)
    if (joints.alive(i))
      for (float& f : joints.at(i).impulses) f *= k;
}

void World::Impl::storeImpulses() {
  // Hand each row's impulse back to its contact point or joint for the next warm start.
  for (Contact& c : contacts) {
    if (c.firstRow < 0) continue;
    const int n = c.manifold.count;
    for (int i = 0; i < n; ++i) c.normalImpulse[i] = solver.rows[size_t(c.firstRow + i)].lambda;
    if (solver.rows[size_t(c.firstRow + n)].patchPoints > 0) {
      for (int d = 0; d < 3; ++d)
        c.patchImpulse(d) = solver.rows[size_t(c.firstRow + n + d)].lambda;
      continue;
    }
    for (int i = 0; i < n; ++i) {
      c.tangentImpulse[i][0] = solver.rows[size_t(c.firstRow + n + 2 * i)].lambda;
      c.tangentImpulse[i][1] = solver.rows[size_t(c.firstRow + n + 2 * i + 1)].lambda;
    }
  }
  for (size_t m = 0; m < manifolds.size(); ++m) {  // solved in wide blocks, without rows
    const SolverManifold& sm = manifolds[m];
    Contact& c = contacts[manifoldContact[m]];
    std::memcpy(c.normalImpulse, sm.normalImpulse, sizeof(float) * size_t(sm.count));
    if (sm.patch)
      for (int d = 0; d < 3; ++d) c.patchImpulse(d) = sm.patchImpulse[d];
    else
      std::memcpy(c.tangentImpulse, sm.tangentImpulse, sizeof(float) * 2 * size_t(sm.count));
  }
  for (uint32_t i = 0; i < joints.capacity(); ++i) {
    if (!joints.alive(i)) continue;
    JointRec& j = joints.at(i);
    j.impulseCount = std::min(j.rowCount, int32_t(JointRec::kMaxRows));
    for (int32_t k = 0; k < j.impulseCount; ++k)
      j.impulses[k] = solver.rows[size_t(j.firstRow + k)].lambda;
  }
}

void World::Impl::takeSnapshot() {
  snapshot.bodies.clear();
  for (uint32_t i = 0; i < bodies.capacity(); ++i) {
    if (!bodies.alive(i)) continue;
    const BodyRec& b = bodies.at(i);
    if (b.type == BodyType::Static) continue;
    snapshot.bodies.push_back({i, b.xf, b.com, b.v, b.w, b.force, b.torque});
  }
  snapshot.contacts = contacts;
  snapshot.jointImpulses.clear();
  for (uint32_t i = 0; i < joints.capacity(); ++i) {
    if (!joints.alive(i)) continue;
    const JointRec& j = joints.at(i);
    Snapshot::JointImpulses ji{i, j.impulseCount, {}};
    std::copy(j.impulses, j.impulses + JointRec::kMaxRows, ji.impulses);
    snapshot.jointImpulses.push_back(ji);
  }
  snapshot.time = time;
  snapshot.step = stats.step;
  snapshot.substepTime = stats.substepTime;
  snapshot.kinetic = 0;
  snapshot.liftEnergy = 1;
  const double g = length(def.gravity);
  for (const Snapshot::Body& s : snapshot.bodies) {
    const BodyRec& b = bodies.at(s.index);
    if (b.type != BodyType::Dynamic) continue;
    snapshot.kinetic +=
        0.5 * b.mass * double(lengthSquared(b.v)) +
        0.5 * double(dot(invRotate(b.xf.q, b.w), b.inertiaLocal * invRotate(b.xf.q, b.w)));
    snapshot.liftEnergy += 0.1 * g * b.mass;
  }
}

void World::Impl::restoreSnapshot() {
  for (const Snapshot::Body& s : snapshot.bodies) {
    BodyRec& b = bodies.at(s.index);
    b.xf = s.xf;
    b.com = s.com;
    b.v = s.v;
    b.w = s.w;
    b.force = s.force;
    b.torque = s.torque;
  }
  contacts = snapshot.contacts;
  for (const Snapshot::JointImpulses& ji : snapshot.jointImpulses) {
    JointRec& j = joints.at(ji.index);
    j.impulseCount = ji.count;
    std::copy(ji.impulses, ji.impulses + JointRec::kMaxRows, j.impulses);
  }
  time = snapshot.time;
  stats.step = snapshot.step;
  stats.substepTime = snapshot.substepTime;
  deviceStale();
}

const char* World::Impl::bodyFault(const BodyRec& b) const {
  if (!isFinite(b.xf.p) || !isFinite(b.xf.q) || !isFinite(b.v) || !isFinite(b.w))
    return "has a non-finite state";
  // The speed clamp only bites when something has blown up.
  if (length(b.v) >= 0.999f * def.maxLinearSpeed || length(b.w) >= 0.999f * def.maxAngularSpeed)
    return "reached the speed limit";
  return nullptr;
}

std::string World::Impl::checkHealth() const {
  for (const Snapshot::Body& s : snapshot.bodies) {
    if (const char* fault = bodyFault(bodies.at(s.index)))
      return "body " + std::to_string(s.index) + " " + fault;
  }
  double gain = stats.energyAfter - stats.energyBefore;
  double allowed = def.guardEnergyJump * snapshot.kinetic + snapshot.liftEnergy;
  if (!(gain <= allowed))
    return "energy rose " + std::to_string(gain) + " J in one step (allowed " +
           std::to_string(allowed) + " J)";
  return {};
}

void World::Impl::quarantine() {
  // Retries did not help: put each body at fault back where it was, at rest, and let the
  // rest of the world keep its step. A bad body never poisons the others.
  for (const Snapshot::Body& s : snapshot.bodies) {
    BodyRec& b = bodies.at(s.index);
    if (!bodyFault(b)) continue;
    b.xf = s.xf;
    b.com = s.com;
    b.v = b.w = {};
    stats.guardQuarantined++;
    stats.lastGuardEvent += "; body " + std::to_string(s.index) + " stopped";
  }
  deviceStale();
  for (Contact& c : contacts) {  // impulses computed from the bad state are not reused
    std::fill(std::begin(c.normalImpulse), std::end(c.normalImpulse), 0.0f);
    for (auto& t : c.tangentImpulse) t[0] = t[1] = 0;
  }
}

void World::Impl::applyCommands() {
  // In-process edits are applied immediately (the world is single-threaded between steps);
  // the server queues network commands and drains them here.
}

void World::Impl::updateBounds(float dt) {
  // Tight boxes are swept by this step's motion and padded by half the speculative distance,
  // so every pair that can touch during the step is found.
  for (uint32_t i = 0; i < shapes.capacity(); ++i) {
    if (!shapes.alive(i)) continue;
    ShapeRec& s = shapes.at(i);
    const BodyRec& b = *bodies.get(s.body);
    if (b.type == BodyType::Static) continue;
    AABB box = computeAABB(s.def.geom, shapeTransform(b, s));
    Vec3 sweep = b.v * dt;
    box.lo += vmin(sweep, {});
    box.hi += vmax(sweep, {});
    float pad = 0.5f * def.speculativeDistance + length(b.w) * dt * s.boundRadius;
    box = inflate(box, pad);
    broadPhase.moveProxy(s.proxy, box, def.aabbMargin);
  }
}

void World::Impl::broadPhaseStage() {
  broadPhase.computePairs(&pairs);
  // Merge the sorted pair list with the sorted contact list: surviving contacts keep their
  // impulses for warm starting, new pairs start cold, vanished pairs are dropped.
  contactScratch.clear();
  size_t ci = 0;
  for (const ProxyPair& pr : pairs) {
    const ShapeRec& sa = shapes.at(pr.a);
    const ShapeRec& sb = shapes.at(pr.b);
    if (sa.body == sb.body) continue;
    const BodyRec& A = *bodies.get(sa.body);
    const BodyRec& B = *bodies.get(sb.body);
    if (A.type != BodyType::Dynamic && B.type != BodyType::Dynamic) continue;
    if (!noCollide.empty() && noCollide.count(bodyPairKey(sa.body.index, sb.body.index))) continue;
    while (ci < contacts.size() && (contacts[ci].shapeA < pr.a ||
                                    (contacts[ci].shapeA == pr.a && contacts[ci].shapeB < pr.b)))
      ++ci;
    // Same slots, same shapes (generation), so a shape removed and another added in its
    // slot since the last step does not inherit the old one's impulses.
    if (ci < contacts.size() && contacts[ci].shapeA == pr.a && contacts[ci].shapeB == pr.b &&
        contacts[ci].idA == shapes.idAt(pr.a) && contacts[ci].idB == shapes.idAt(pr.b)) {
      contactScratch.push_back(contacts[ci]);
    } else {
      Contact c;
      c.shapeA = pr.a;
      c.shapeB = pr.b;
      c.bodyA = sa.body;
      c.bodyB = sb.body;
      c.idA = shapes.idAt(pr.a);
      c.idB = shapes.idAt(pr.b);
      contactScratch.push_back(c);
    }
    Contact& c = contactScratch.back();
    c.friction = std::sqrt(sa.def.material.friction * sb.def.material.friction);
    c.restitution = std::max(sa.def.material.restitution, sb.def.material.restitution);
  }
  contacts.swap(contactScratch);
  stats.pairs = int(pairs.size());
}

void World::Impl::narrowPhase(float dt) {
  // Every contact on its own (reads bodies and shapes, writes only itself), in parallel;
  // the statistics are a max and a sum, the same for any split.
  std::atomic<int> points{0};
  std::atomic<float> deepest{0};
  auto collideRange = [&](size_t begin, size_t end) {
    int chunkPoints = 0;
    float chunkDeepest = 0;
    for (size_t ci = begin; ci < end; ++ci) {
      Contact& c = contacts[ci];
      const ShapeRec& sa = shapes.at(c.shapeA);
      const ShapeRec& sb = shapes.at(c.shapeB);
      const BodyRec& A = *bodies.get(c.bodyA);
      const BodyRec& B = *bodies.get(c.bodyB);
      // The margin grows with the speeds so a fast body meets a speculative contact before
      // it can pass through anything (no tunnelling without a separate continuous pass).
      float reach = (length(A.v) + length(A.w) * sa.boundRadius + length(B.v) +
                     length(B.w) * sb.boundRadius) *
                    dt;
      float margin = def.speculativeDistance + reach;
      Manifold m;
      collide(sa.def.geom, shapeTransform(A, sa), sb.def.geom, shapeTransform(B, sb), margin, &m);
      // Carry impulses of points whose features persist (warm starting).
      float ni[Manifold::kMaxPoints] = {}, ti[Manifold::kMaxPoints][2] = {};
      for (int i = 0; i < m.count; ++i) {
        const ContactPoint& cp = m.points[i];
        for (int k = 0; k < c.manifold.count; ++k) {
          if (c.manifold.points[k].featureId == cp.featureId) {
            ni[i] = c.normalImpulse[k];
            ti[i][0] = c.tangentImpulse[k][0];
            ti[i][1] = c.tangentImpulse[k][1];
            break;
          }
        }
        chunkDeepest = std::max(chunkDeepest, -cp.separation);
      }
      // Patch friction keeps the manifold's friction impulses while any point persists.
      if (def.solver.patchFriction) {
        bool persists = false;
        for (int i = 0; i < m.count && !persists; ++i)
          for (int k = 0; k < c.manifold.count; ++k)
            persists = persists || c.manifold.points[k].featureId == m.points[i].featureId;
        if (persists) std::memcpy(ti, c.tangentImpulse, sizeof ti);
      }
      c.manifold = m;
      std::memcpy(c.normalImpulse, ni, sizeof ni);
      std::memcpy(c.tangentImpulse, ti, sizeof ti);
      chunkPoints += m.count;
    }
    points += chunkPoints;
    float seen = deepest.load();
    while (chunkDeepest > seen && !deepest.compare_exchange_weak(seen, chunkDeepest)) {
    }
  };
  if (pool)
    pool->parallelFor(contacts.size(), kContactGrain, collideRange);
  else
    collideRange(0, contacts.size());
  stats.contactPoints = points.load();
  stats.maxPenetration = double(deepest.load());
  stats.contacts = int(contacts.size());
}

SolverManifold World::Impl::solverManifold(const Contact& c, const SolverSettings& s) const {
  SolverManifold m;
  const BodyRec& A = *bodies.get(c.bodyA);
  const BodyRec& B = *bodies.get(c.bodyB);
  m.a = A.solverIndex;
  m.b = B.solverIndex;
  m.count = c.manifold.count;
  m.normal = c.manifold.normal;
  tangentBasis(m.normal, &m.t1, &m.t2);
  m.friction = c.friction;
  m.restitution = c.restitution;
  for (int k = 0; k < m.count; ++k) {
    const ContactPoint& cp = c.manifold.points[k];
    m.rA[k] = cp.point - A.com;
    m.rB[k] = cp.point - B.com;
    m.separation[k] = cp.separation;
    m.relativeVelocity[k] =
        dot(m.normal, (B.v + cross(B.w, m.rB[k])) - (A.v + cross(A.w, m.rA[k])));
    m.normalImpulse[k] = s.warmStart ? c.normalImpulse[k] : 0;
    m.tangentImpulse[k][0] = s.warmStart ? c.tangentImpulse[k][0] : 0;
    m.tangentImpulse[k][1] = s.warmStart ? c.tangentImpulse[k][1] : 0;
  }
  if (s.patchFriction && m.count > 0) {
    m.patch = true;
    Vec3 centroid;
    for (int k = 0; k < m.count; ++k) centroid += c.manifold.points[k].point;
    centroid = centroid * (1.0f / float(m.count));
    m.patchRA = centroid - A.com;
    m.patchRB = centroid - B.com;
    float arm = 0;
    for (int k = 0; k < m.count; ++k) arm += length(c.manifold.points[k].point - centroid);
    m.twistArm = arm / float(m.count);
    // Switching friction models between steps warm-starts one step from the other model's
    // slots; the friction clamps bound what that can do.
    for (int d = 0; d < 3; ++d) m.patchImpulse[d] = s.warmStart ? c.patchImpulse(d) : 0;
  }
  return m;
}

void World::Impl::contactRowsOf(const Contact& c, const SolverManifold& m) {
  for (int k = 0; k < m.count; ++k) {
    Row r = contactRow(m, RowKind::ContactNormal, m.normal, k);
    r.C0 = m.separation[k];
    r.lambda = m.normalImpulse[k];
    r.restitution = m.restitution;
    r.groupStart = k == 0;
    r.relativeVelocity = m.relativeVelocity[k];
    solver.rows.push_back(r);
  }
  if (m.patch) {
    // Patch friction: a tangent pair at the centroid, then the twist row.
    for (int d = 0; d < 2; ++d) {
      const Vec3 t = d == 0 ? m.t1 : m.t2;
      Row r;
      r.kind = RowKind::Friction;
      r.a = m.a;
      r.b = m.b;
      r.linA = -t;
      r.angA = -cross(m.patchRA, t);
      r.linB = t;
      r.angB = cross(m.patchRB, t);
      r.mu = m.friction;
      r.parent = c.firstRow;
      r.patchPoints = uint8_t(m.count);
      r.lambda = m.patchImpulse[d];
      solver.rows.push_back(r);
    }
    Row r;
    r.kind = RowKind::Twist;
    r.a = m.a;
    r.b = m.b;
    r.angA = -m.normal;
    r.angB = m.normal;
    r.mu = m.friction * m.twistArm;
    r.parent = c.firstRow;
    r.patchPoints = uint8_t(m.count);
    r.lambda = m.patchImpulse[2];
    solver.rows.push_back(r);
    return;
  }
  for (int k = 0; k < m.count; ++k) {
    for (int d = 0; d < 2; ++d) {
      Row r = contactRow(m, RowKind::Friction, d == 0 ? m.t1 : m.t2, k);
      r.mu = m.friction;
      r.parent = c.firstRow + k;
      r.lambda = m.tangentImpulse[k][d];
      solver.rows.push_back(r);
    }
  }
}

std::vector<float> World::Impl::jointStiffness() const {
  // Each joint's force |f| at each dynamic body's arm |r| (N m/rad), by body slot.
  std::vector<float> k(bodies.capacity(), 0.0f);
  for (uint32_t i = 0; i < joints.capacity(); ++i) {
    if (!joints.alive(i)) continue;
    const JointRec& j = joints.at(i);
    const float f = length(j.state.reactionForce);
    if (!(f > 0)) continue;
    const BodyRec* A = j.def.bodyA.isNull() ? nullptr : bodies.get(j.def.bodyA);
    const BodyRec& B = *bodies.get(j.def.bodyB);
    BodyPose pa = A ? poseOf(*A) : BodyPose{}, pb = poseOf(B);
    JointFrame fr = jointFrame(j, A ? &pa : nullptr, pb);
    if (A && A->type == BodyType::Dynamic) k[j.def.bodyA.index] += f * length(fr.rA);
    if (B.type == BodyType::Dynamic) k[j.def.bodyB.index] += f * length(fr.rB);
  }
  return k;
}

void World::Impl::addGeometricStiffness(float h) {
  // Andrews, Teichmann and Kry 2017: a joint force f at arm r turns into a torque that
  // changes as the body turns, a stiffness of about |f| |r| (N m/rad). Our Jacobians are
  // frozen over a substep, so that stiffness is integrated explicitly and blows up once
  // omega h > ~1: a 1 kg link between a 1000 kg ball and the anchor, at the bottom of the
  // swing (tension 3e4 N), has omega of about 340 rad/s. Adding h^2 k to the inertia (the
  // implicit-Euler term, from last step's joint forces) makes the link's rotation stable at
  // any substep; a light body under a large load turns a little more slowly.
  const std::vector<float> bySlot = jointStiffness();
  std::vector<float> k(solver.bodies.size(), 0.0f);
  for (uint32_t slot = 0; slot < bySlot.size(); ++slot)
    if (bySlot[slot] > 0) k[size_t(bodies.at(slot).solverIndex)] = bySlot[slot];
  for (size_t i = 1; i < solver.bodies.size(); ++i) {
    if (!(k[i] > 0)) continue;
    SolverBody& sb = solver.bodies[i];
    const Mat3 R = toMat3(sb.q);
    Mat3 I = R * sb.inertiaLocal * transpose(R);  // world inertia, as invI was made
    const float add = h * h * k[i];
    I.c0.x += add;
    I.c1.y += add;
    I.c2.z += add;
    sb.invI = inverse(I);
  }
}

void World::Impl::buildSolverBodies(const SolverSettings& s) {
  // Prepare: the compact solver bodies (index 0 is the static world), then one row per
  // joint axis and per contact normal and friction direction.
  const float h = def.timeStep / float(s.substeps);
  solver.bodies.clear();
  solver.rows.clear();
  solver.blockInvK.clear();
  solver.contactK.clear();
  solver.blockContacts = s.blockContacts;
  solver.bodies.push_back(SolverBody{});
  solverCom.assign(1, Vec3{});
  int awake = 0;
  for (uint32_t i = 0; i < bodies.capacity(); ++i) {
    if (!bodies.alive(i)) continue;
    BodyRec& b = bodies.at(i);
    if (b.type == BodyType::Static) {
      b.solverIndex = 0;
      continue;
    }
    b.solverIndex = int32_t(solver.bodies.size());
    SolverBody sb;
    sb.v = b.v;
    sb.w = b.w;
    sb.q = b.xf.q;
    sb.dynamic = b.type == BodyType::Dynamic;
    if (sb.dynamic) {
      Mat3 R = toMat3(b.xf.q);
      sb.invMass = b.invMass;
      sb.invI = R * b.invInertiaLocal * transpose(R);
      sb.inertiaLocal = b.inertiaLocal;
      sb.linearAccel = def.gravity * b.gravityScale + b.force * b.invMass;
      sb.torque = b.torque;
      sb.linearDamping = b.linearDamping;
      sb.angularDamping = b.angularDamping;
      // Equal principal moments (a cube, a sphere) have no gyroscopic torque (w x I w = 0):
      // the plain rotation update of non-gyroscopic bodies serves, a quarter of the cost.
      // It turns by 2 atan(|w| h / 2) instead of |w| h, an O((|w| h)^3) difference.
      const Vec3 I = b.principalMoments;
      const float spread = std::max({I.x, I.y, I.z}) - std::min({I.x, I.y, I.z});
      sb.gyroscopic = b.gyroscopic && spread > 1e-5f * std::max({I.x, I.y, I.z});
      sb.principal = b.principal;
      sb.principalMoments = b.principalMoments;
    }
    solver.bodies.push_back(sb);
    solverCom.push_back(b.com);
    ++awake;
  }
  stats.bodies = int(bodies.size());
  stats.awake = awake;
  if (s.geometricStiffness) addGeometricStiffness(h);

  // Joints first: the solver meets them before contacts in every iteration.
  int jointsBuilt = 0;
  for (uint32_t i = 0; i < joints.capacity(); ++i) {
    if (!joints.alive(i)) continue;
    JointRec& j = joints.at(i);
    const BodyRec* A = j.def.bodyA.isNull() ? nullptr : bodies.get(j.def.bodyA);
    const BodyRec& B = *bodies.get(j.def.bodyB);
    BodyPose pa = A ? poseOf(*A) : BodyPose{}, pb = poseOf(B);
    buildJointRows(j, A ? &pa : nullptr, pb, A ? A->solverIndex : 0, B.solverIndex, h, &solver);
    // Warm start from last step's impulses when the joint still has the same rows.
    if (s.warmStart && j.impulseCount == j.rowCount) {
      for (int32_t k = 0; k < j.rowCount; ++k)
        solver.rows[size_t(j.firstRow + k)].lambda = j.impulses[k];
    }
    ++jointsBuilt;
  }
  stats.joints = jointsBuilt;

  // Contacts: 3 rows per point (normal, two friction directions), or with the vectorized
  // Gauss-Seidel scheme no rows but a manifold each, which the wide blocks take (bit-identical
  // to the rows; solver_wide.h). Not for the split push-out and the position pass, which
  // read the contact rows between the iterations, nor for the contact block solve.
  // Built serially: building them in parallel needs the vector sized first, and
  // value-initializing 28,000 rows of 160 bytes (pyramid_40) cost more than the parallel
  // build saved.
  const bool vectorized =
      vectorizedContacts() && s.scheme == SolverSettings::Scheme::GaussSeidel && !s.blockContacts &&
      !s.splitPushout &&
      (s.positionPass == SolverSettings::PositionPass::None || s.positionIterations == 0);
  uint32_t halfEnd[2] = {};
  const bool halves = orderContacts(s, halfEnd);
  manifoldContact.clear();
  for (uint32_t ci : contactOrder) {
    Contact& c = contacts[ci];
    if (vectorized) {
      manifoldContact.push_back(ci);
      continue;
    }
    c.firstRow = int32_t(solver.rows.size());
    contactRowsOf(c, solverManifold(c, s));
  }
  // Every field of a manifold is assigned below: resizing without a clear spares zeroing
  // the entries that were there last step.
  manifolds.resize(manifoldContact.size());
  auto makeManifolds = [&](size_t begin, size_t end) {
    for (size_t i = begin; i < end; ++i)
      manifolds[i] = solverManifold(contacts[manifoldContact[i]], s);
  };
  if (pool)
    pool->parallelFor(manifolds.size(), kContactGrain, makeManifolds);
  else
    makeManifolds(0, manifolds.size());
  solver.scheme = s.scheme;
  solver.indexUnits();
  solver.finishRows(0, solver.rows.size());
  solver.wide = &wide;
  if (vectorized)
    wide.build(solver, manifolds, halves ? halfEnd : nullptr);
  else
    wide.clear();
  stats.vectorizedManifolds = int(manifolds.size());
}

bool World::Impl::orderContacts(const SolverSettings& s, uint32_t halfEnd[2]) {
  // The Gauss-Seidel order of the touching contacts: with many contacts, the first half's, the
  // second half's, then those between (solver_wide.h, "Halves"), so that the halves run on two
  // threads; the same order with any thread count, and in the rows as in the wide blocks.
  contactOrder.clear();
  for (uint32_t ci = 0; ci < contacts.size(); ++ci) {
    contacts[ci].firstRow = -1;
    if (contacts[ci].manifold.count > 0) contactOrder.push_back(ci);
  }
  const bool halves =
      s.scheme == SolverSettings::Scheme::GaussSeidel && contactOrder.size() >= kHalvesMinManifolds;
  stats.contactsBetweenHalves = -1;
  if (halves) {
    std::vector<std::pair<int32_t, int32_t>> pairs;  // solver bodies
    pairs.reserve(contactOrder.size());
    for (uint32_t ci : contactOrder) {
      const Contact& c = contacts[ci];
      pairs.push_back({bodies.get(c.bodyA)->solverIndex, bodies.get(c.bodyB)->solverIndex});
    }
    splitHalves(solver.bodies, solverCom, pairs, solverHalf);
    std::vector<uint32_t> byPart[3];  // indices into contactOrder and pairs
    for (uint32_t k = 0; k < pairs.size(); ++k)
      byPart[manifoldPart(solverHalf, pairs[k].first, pairs[k].second)].push_back(k);
    // Between the halves: by colour (solver_wide.h), so that they fill blocks.
    std::vector<std::pair<int32_t, int32_t>> betweenPairs;
    for (uint32_t k : byPart[2]) betweenPairs.push_back(pairs[k]);
    const std::vector<uint32_t> byColor = colorOrder(solver.bodies, betweenPairs);
    std::vector<uint32_t> order;
    order.reserve(contactOrder.size());
    for (int part = 0; part < 2; ++part)
      for (uint32_t k : byPart[part]) order.push_back(contactOrder[k]);
    for (uint32_t i : byColor) order.push_back(contactOrder[byPart[2][i]]);
    contactOrder.swap(order);
    halfEnd[0] = uint32_t(byPart[0].size());
    halfEnd[1] = halfEnd[0] + uint32_t(byPart[1].size());
    stats.contactsBetweenHalves = int(byPart[2].size());
  }
  return halves;
}

void World::Impl::refreshJoints(float h) {
  for (uint32_t i = 0; i < joints.capacity(); ++i) {
    if (!joints.alive(i)) continue;
    JointRec& j = joints.at(i);
    const BodyRec* A = j.def.bodyA.isNull() ? nullptr : bodies.get(j.def.bodyA);
    const BodyRec& B = *bodies.get(j.def.bodyB);
    auto current = [&](const BodyRec& b) {
      // Static bodies all share solver body 0 (the world): their pose is their own.
      if (b.solverIndex == 0) return poseOf(b);
      const SolverBody& sb = solver.bodies[size_t(b.solverIndex)];
      return BodyPose{sb.q, b.com + sb.dp, b.localCenter};
    };
    BodyPose pa = A ? current(*A) : BodyPose{}, pb = current(B);
    refreshJointRows(j, A ? &pa : nullptr, pb, A ? A->solverIndex : 0, B.solverIndex, h, &solver);
  }
}

void World::Impl::finalize(float hSub) {
  for (uint32_t i = 0; i < bodies.capacity(); ++i) {
    if (!bodies.alive(i)) continue;
    BodyRec& b = bodies.at(i);
    b.force = b.torque = {};
    if (b.type == BodyType::Static) continue;
    const SolverBody& sb = solver.bodies[size_t(b.solverIndex)];
    b.v = sb.v;
    b.w = sb.w;
    b.com += sb.dp;
    b.xf.q = sb.q;
    b.xf.p = b.com - rotate(b.xf.q, b.localCenter);
  }
  // Joint reactions (the rows' impulses per substep as forces on B) and errors at the new poses.
  for (uint32_t i = 0; i < joints.capacity(); ++i) {
    if (!joints.alive(i)) continue;
    JointRec& j = joints.at(i);
    Vec3 f, tq;
    for (int32_t r = j.firstRow; r < j.firstRow + j.rowCount; ++r) {
      const Row& row = solver.rows[size_t(r)];
      f += row.linB * (row.lambda / hSub);
      // Only rows that are pure rotation: the moment of the force above is not included.
      if (row.linB == Vec3{}) tq += row.angB * (row.lambda / hSub);
    }
    j.state.reactionForce = f;
    j.state.reactionTorque = tq;
  }
  measureJoints();
}

void World::Impl::measureJoints() {
  for (uint32_t i = 0; i < joints.capacity(); ++i) {
    if (!joints.alive(i)) continue;
    JointRec& j = joints.at(i);
    const BodyRec* A = j.def.bodyA.isNull() ? nullptr : bodies.get(j.def.bodyA);
    BodyPose pa = A ? poseOf(*A) : BodyPose{}, pb = poseOf(*bodies.get(j.def.bodyB));
    measureJoint(j, A ? &pa : nullptr, pb, &j.state.positionError, &j.state.angleError);
  }
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
  for (uint32_t i = 0; i < w.joints.capacity(); ++i)
    if (w.joints.alive(i))
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
  for (const Contact& c : impl_->contacts) {
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
  for (uint32_t i = 0; i < w.bodies.capacity(); ++i) {
    if (!w.bodies.alive(i)) continue;
    const BodyRec& b = w.bodies.at(i);
    if (b.type != BodyType::Dynamic) continue;
    Vec3 wb = invRotate(b.xf.q, b.w);
    Vec3 Iw = b.inertiaLocal * wb;
    double ke =
        0.5 * b.mass * (double(b.v.x) * b.v.x + double(b.v.y) * b.v.y + double(b.v.z) * b.v.z) +
        0.5 * (double(wb.x) * Iw.x + double(wb.y) * Iw.y + double(wb.z) * Iw.z);
    double pe = -double(b.mass) * b.gravityScale *
                (double(g.x) * b.com.x + double(g.y) * b.com.y + double(g.z) * b.com.z);
    e += ke + pe;
  }
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
