// Conversions between wire tables and phys types (convert.h).
#include "phys/protocol/convert.h"

#include <string>
#include <vector>

namespace phys::protocol {

wire::BodyState toWire(const phys::BodyState& s) {
  return {s.id.packed(), toWire(s.position), toWire(s.rotation), toWire(s.linearVelocity),
          toWire(s.angularVelocity)};
}

namespace {

const wire::Vec3 kZ(0, 0, 1);

Status toShapeDef(const wire::ShapeDef& in, phys::ShapeDef* out, const std::string& path,
                  HullCache* cache) {
  phys::ShapeDef s;
  switch (in.geom_type()) {
    case wire::Shape::Sphere:
      s.geom = phys::ShapeGeom::sphere(in.geom_as_Sphere()->radius());
      break;
    case wire::Shape::Box: {
      const wire::Vec3* he = in.geom_as_Box()->half_extents();
      s.geom = phys::ShapeGeom::box(he ? toPhys(*he) : phys::Vec3{});
      break;
    }
    case wire::Shape::Capsule: {
      const wire::Capsule* c = in.geom_as_Capsule();
      s.geom = phys::ShapeGeom::capsule(c->radius(), c->half_height());
      break;
    }
    case wire::Shape::Plane: {
      const wire::Plane* p = in.geom_as_Plane();
      s.geom = phys::ShapeGeom::plane(toPhys(p->normal() ? *p->normal() : kZ), p->offset());
      break;
    }
    case wire::Shape::ConvexHull: {
      const void* key = in.geom_as_ConvexHull();
      if (cache) {
        auto it = cache->find(key);
        if (it != cache->end()) {
          s.geom = phys::ShapeGeom::convexHull(it->second);
          break;
        }
      }
      // Points only: the world that receives the body builds the hull (and refuses points
      // that span no volume), so neither the protocol nor a client needs a hull builder.
      std::vector<phys::Vec3> points;
      if (auto* pts = in.geom_as_ConvexHull()->points()) {
        points.reserve(pts->size());
        for (const wire::Vec3* v : *pts) points.push_back(toPhys(*v));
      }
      s.geom = phys::ShapeGeom::hullOf(std::move(points));
      if (cache) (*cache)[key] = s.geom.hull;
      break;
    }
    default:
      return Status::Error(Code::InvalidArgument, path + ".geom is not a known shape");
  }
  if (in.local()) s.local = toPhys(*in.local());
  if (in.material()) s.material = toPhys(*in.material());
  *out = std::move(s);
  return Status::Ok();
}

}  // namespace

Status toBodyDef(const wire::BodyDef& in, phys::BodyDef* out, std::string_view path,
                 HullCache* cache) {
  phys::BodyDef d;
  d.type = phys::BodyType(in.motion());
  if (in.pose()) {
    phys::Transform t = toPhys(*in.pose());
    d.position = t.p;
    d.rotation = t.q;
  }
  if (in.linear_velocity()) d.linearVelocity = toPhys(*in.linear_velocity());
  if (in.angular_velocity()) d.angularVelocity = toPhys(*in.angular_velocity());
  d.linearDamping = in.linear_damping();
  d.angularDamping = in.angular_damping();
  d.gravityScale = in.gravity_scale();
  d.mass = in.mass();
  if (in.inertia()) d.inertia = toPhys(*in.inertia());
  d.gyroscopic = in.gyroscopic();
  d.allowSleep = in.allow_sleep();
  if (in.name()) d.name = in.name()->str();
  if (auto* shapes = in.shapes()) {
    d.shapes.resize(shapes->size());
    for (uint32_t i = 0; i < shapes->size(); ++i) {
      Status st = toShapeDef(*shapes->Get(i), &d.shapes[i],
                             std::string(path) + ".shapes[" + std::to_string(i) + "]", cache);
      if (!st.ok()) return st;
    }
  }
  *out = std::move(d);
  return Status::Ok();
}

phys::JointDef toJointDef(const wire::JointDef& in) {
  phys::JointDef d;
  d.type = phys::JointType(in.type());
  d.bodyA = phys::BodyId::fromPacked(in.body_a());
  d.bodyB = phys::BodyId::fromPacked(in.body_b());
  if (in.anchor_a()) d.anchorA = toPhys(*in.anchor_a());
  if (in.anchor_b()) d.anchorB = toPhys(*in.anchor_b());
  d.axisA = toPhys(in.axis_a() ? *in.axis_a() : kZ);
  d.axisB = toPhys(in.axis_b() ? *in.axis_b() : kZ);
  d.enableLimit = in.enable_limit();
  d.lower = in.lower();
  d.upper = in.upper();
  d.enableMotor = in.enable_motor();
  d.motorSpeed = in.motor_speed();
  d.maxMotorForce = in.max_motor_force();
  d.length = in.length();
  d.springHertz = in.spring_hertz();
  d.springDampingRatio = in.spring_damping_ratio();
  d.collideConnected = in.collide_connected();
  if (in.name()) d.name = in.name()->str();
  return d;
}

SolverOverrides toOverrides(const wire::SolverSettings& in) {
  SolverOverrides o;
  // A wire enum as the phys one of the same values, any other value as it is.
#define PHYS_FROM_WIRE(type, member, name, ...) \
  if (auto v = in.name()) o.member = decltype(o.member)::value_type(*v);
  PHYS_SOLVER_FIELDS(PHYS_FROM_WIRE)
#undef PHYS_FROM_WIRE
  return o;
}

void applyOverrides(const SolverOverrides& o, phys::SolverSettings* s) {
#define PHYS_APPLY(type, member, ...) \
  if (o.member) s->member = *o.member;
  PHYS_SOLVER_FIELDS(PHYS_APPLY)
#undef PHYS_APPLY
}

void applySolverSettings(const wire::SolverSettings& in, phys::SolverSettings* out) {
  applyOverrides(toOverrides(in), out);
}

namespace {
// A world setting read from the wire: present or not.
template <class T>
std::optional<T> worldSetting(flatbuffers::Optional<T> v) {
  return v ? std::optional<T>(*v) : std::nullopt;
}
std::optional<phys::Vec3> worldSetting(const wire::Vec3* v) {
  return v ? std::optional<phys::Vec3>(toPhys(*v)) : std::nullopt;
}
}  // namespace

WorldOverrides toOverrides(const wire::WorldSettings& in) {
  WorldOverrides o;
#define PHYS_WORLD_FROM_WIRE(type, member, path, name) o.member = worldSetting(in.name());
  PHYS_WORLD_FIELDS(PHYS_WORLD_FROM_WIRE)
#undef PHYS_WORLD_FROM_WIRE
  return o;
}

void applyOverrides(const WorldOverrides& o, phys::WorldDef* d) {
#define PHYS_WORLD_APPLY(type, member, path, name) \
  if (o.member) d->path = *o.member;
  PHYS_WORLD_FIELDS(PHYS_WORLD_APPLY)
#undef PHYS_WORLD_APPLY
}

Status toBodyInfo(const wire::BodyInfo& in, BodyInfo* out, std::string_view path,
                  HullCache* cache) {
  BodyInfo b;
  b.id = in.id();
  if (in.def()) {
    Status st = toBodyDef(*in.def(), &b.def, std::string(path) + ".def", cache);
    if (!st.ok()) return st;
  }
  b.mass.mass = in.mass();
  if (in.center_of_mass()) b.mass.localCenter = toPhys(*in.center_of_mass());
  if (in.inertia()) b.mass.inertia = toPhys(*in.inertia());
  if (in.inertia_axes()) b.mass.inertiaRotation = toPhys(*in.inertia_axes());
  *out = std::move(b);
  return Status::Ok();
}

WorldSummary toWorldSummary(const wire::WorldSummary& in) {
  auto str = [](const flatbuffers::String* s) { return s ? s->str() : std::string(); };
  WorldSummary s;
  s.world = in.world();
  s.name = str(in.name());
  s.preset = str(in.preset());
  s.bodies = in.bodies();
  s.joints = in.joints();
  s.tick = in.tick();
  s.time = in.time();
  s.running = in.running();
  s.rateHz = in.rate_hz();
  s.tickMs = in.tick_ms();
  s.tickMsMax = in.tick_ms_max();
  s.overruns = in.overruns();
  s.subscribers = in.subscribers();
  s.frames = in.frames();
  s.backend = str(in.backend());
  s.device = str(in.device());
  s.backendNote = str(in.backend_note());
  s.gpuSteps = in.gpu_steps();
  s.cpuSteps = in.cpu_steps();
  s.awakeBodies = in.awake_bodies();
  s.sleepingBodies = in.sleeping_bodies();
  s.frameBytes = in.frame_bytes();
  s.contacts = in.contacts();
  s.stepBufferBytes = in.step_buffer_bytes();
  s.damage = str(in.damage());
  s.daemon = in.daemon();
  s.movingTo = in.moving_to();
  return s;
}

Status toSnapshotData(const wire::Snapshot& in, SnapshotData* out) {
  SnapshotData s;
  if (in.name()) s.name = in.name()->str();
  if (in.gravity()) s.gravity = toPhys(*in.gravity());
  s.timeStep = in.time_step();
  if (in.solver()) applySolverSettings(*in.solver(), &s.solver);
  s.tick = in.tick();
  s.time = in.time();
  if (auto* e = in.engine_state()) s.engineState.assign(e->begin(), e->end());
  if (in.settings()) s.settings = toOverrides(*in.settings());
  if (auto* bv = in.bodies()) {
    HullCache hulls;  // a hull table shared by many shapes is built once
    s.bodies.resize(bv->size());
    for (uint32_t i = 0; i < bv->size(); ++i) {
      const wire::BodyEntry* e = bv->Get(i);
      s.bodies[i].id = e->id();
      if (!e->def()) continue;
      Status st =
          toBodyDef(*e->def(), &s.bodies[i].def, "snapshot.bodies[" + std::to_string(i) + "].def",
                    &hulls);
      if (!st.ok()) return st;
    }
  }
  if (auto* jv = in.joints()) {
    s.joints.resize(jv->size());
    for (uint32_t i = 0; i < jv->size(); ++i) {
      const wire::JointEntry* e = jv->Get(i);
      s.joints[i].id = e->id();
      if (e->def()) s.joints[i].def = toJointDef(*e->def());
    }
  }
  *out = std::move(s);
  return Status::Ok();
}

}  // namespace phys::protocol
