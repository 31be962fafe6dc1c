// The GPU backend's side of a World: opening the device, handing bodies and shapes to the
// device world (gpu_solver/) as flat records, stepping it and copying the states back into
// the host mirror (BodyRec), which is what getBody, the metrics and publishing read.
//
// What the device covers so far: bodies without contacts or joints (bounds, integration,
// gyroscopic rotation, finalize). A step that has a contact or a joint is taken by the CPU
// backend from the same mirror, counted in BackendState::cpuSteps with the reason; the
// device's copy is then refreshed before its next step. Until the broad phase runs on the
// device, the CPU's broad phase tells whether a step has contacts.
#include <algorithm>
#include <cstdio>

#include "world_impl.h"

#ifdef PHYS_WITH_GPU
#include "phys/gpu/gpu_world.h"
#endif

namespace phys {

const char* toString(Backend b) {
  switch (b) {
    case Backend::Cpu:
      return "cpu";
    case Backend::Gpu:
      return "gpu";
    case Backend::Auto:
      return "auto";
  }
  return "?";
}

bool parseBackend(const std::string& text, Backend* out) {
  for (Backend b : {Backend::Cpu, Backend::Gpu, Backend::Auto}) {
    if (text == toString(b)) {
      *out = b;
      return true;
    }
  }
  return false;
}

const BackendState& World::backendState() const {
  return impl_->backend;
}

#ifndef PHYS_WITH_GPU

struct DeviceWorld {};
void DeviceWorldDeleter::operator()(DeviceWorld* d) const {
  delete d;
}
void World::Impl::openDevice() {
  backend.note = "built without the GPU backend (PHYS_WITH_GPU=OFF)";
}
void World::Impl::deviceEdited(uint32_t) {}
void World::Impl::deviceStale() {}
bool World::Impl::stepOnDevice(int) {
  return false;
}

#else

struct DeviceWorld {
  std::unique_ptr<gpu::GpuWorld> world;
  std::vector<uint32_t> slots;   ///< device body index -> body slot
  std::vector<uint32_t> edited;  ///< body slots edited since the last upload
  bool stale = true;             ///< bodies or shapes changed: upload everything
};

void DeviceWorldDeleter::operator()(DeviceWorld* d) const {
  delete d;
}

namespace {

gpu::vec4 v4(Vec3 v, float w = 0) {
  return {v.x, v.y, v.z, w};
}
gpu::vec4 q4(Quat q) {
  return {q.x, q.y, q.z, q.w};
}

gpu::GpuBodyState stateOf(const BodyRec& b) {
  return {v4(b.com), q4(b.xf.q), v4(b.v), v4(b.w)};
}

gpu::GpuBodyParams paramsOf(const BodyRec& b, Vec3 gravity) {
  gpu::GpuBodyParams p;
  const bool dynamic = b.type == BodyType::Dynamic;
  p.accel = v4(dynamic ? gravity * b.gravityScale + b.force * b.invMass : Vec3{}, b.invMass);
  p.torque = v4(dynamic ? b.torque : Vec3{}, b.linearDamping);
  p.principal = q4(b.principal);
  p.moments = v4(b.principalMoments, b.angularDamping);
  for (int r = 0; r < 3; ++r) p.invInertia[r] = v4(b.invInertiaLocal.row(r));
  p.localCenter = v4(b.localCenter);
  // The same rule as Solver bodies (buildSolverBodies): equal moments need no splitting.
  const Vec3 I = b.principalMoments;
  const float spread = std::max({I.x, I.y, I.z}) - std::min({I.x, I.y, I.z});
  const bool gyroscopic = b.gyroscopic && spread > 1e-5f * std::max({I.x, I.y, I.z});
  p.flags.x = (dynamic ? PHYS_GPU_BODY_DYNAMIC : 0u) |
              (dynamic && gyroscopic ? PHYS_GPU_BODY_GYROSCOPIC : 0u);
  return p;
}

gpu::GpuShape shapeOf(const ShapeRec& s, const BodyRec& b, const Transform& world) {
  gpu::GpuShape g;
  const bool fixed = b.type == BodyType::Static;
  const Transform& xf = fixed ? world : s.def.local;
  g.localP = v4(xf.p, s.boundRadius);
  g.localQ = q4(xf.q);
  g.body = fixed ? -1 : b.deviceIndex;
  g.friction = s.def.material.friction;
  g.restitution = s.def.material.restitution;
  const ShapeGeom& geom = s.def.geom;
  g.type = uint32_t(geom.type);
  switch (geom.type) {
    case ShapeType::Sphere:
      g.size = {geom.radius, 0, 0, 0};
      break;
    case ShapeType::Box:
      g.size = v4(geom.halfExtents);
      break;
    case ShapeType::Capsule:
      g.size = {geom.radius, geom.halfHeight, 0, 0};
      break;
    case ShapeType::Plane: {
      // In the world frame: dot(n, x) = offset + dot(n, p).
      const Vec3 n = rotate(world.q, geom.normal);
      g.size = v4(n, geom.offset + dot(n, world.p));
      break;
    }
    case ShapeType::Hull:
      g.size = {};
      break;
  }
  return g;
}

}  // namespace

void World::Impl::openDevice() {
  backend.requested = def.backend;
  if (def.backend == Backend::Cpu) return;
  gpu::DeviceOptions options;
  options.allowCpu = def.gpuAllowCpuDevice;
  options = gpu::deviceOptionsFromEnv(options);
  std::string error;
  std::unique_ptr<gpu::GpuWorld> world = gpu::GpuWorld::create(options, &error);
  if (!world) {
    backend.note = "no GPU device, running on the CPU: " + error;
    // Said once per process: a server opening many worlds need not repeat it.
    static bool said = false;
    if (!said) std::fprintf(stderr, "phys: %s\n", backend.note.c_str());
    said = true;
    return;
  }
  device.reset(new DeviceWorld);
  backend.device = world->device().name;
  backend.active = Backend::Gpu;
  device->world = std::move(world);
}

void World::Impl::deviceEdited(uint32_t slot) {
  if (!device || device->stale) return;
  if (bodies.at(slot).deviceIndex < 0) {
    device->stale = true;  // a static body moved: its shapes are held in world coordinates
    return;
  }
  device->edited.push_back(slot);
}

void World::Impl::deviceStale() {
  if (device) device->stale = true;
}

bool World::Impl::stepOnDevice(int substeps) {
  DeviceWorld& d = *device;
  const float dt = def.timeStep;
  std::string why;
  if (joints.size() > 0) {
    why = "joints are not on the GPU backend yet";
  } else {
    updateBounds(dt);
    broadPhaseStage();
    if (!contacts.empty()) why = "contacts are not on the GPU backend yet";
  }
  if (!why.empty()) {
    backend.lastFallback = why;
    return false;
  }

  gpu::GpuWorld& g = *d.world;
  if (d.stale) {
    d.slots.clear();
    std::vector<gpu::GpuBodyState> states;
    std::vector<gpu::GpuBodyParams> params;
    for (uint32_t i = 0; i < bodies.capacity(); ++i) {
      if (!bodies.alive(i)) continue;
      BodyRec& b = bodies.at(i);
      b.deviceIndex = -1;
      if (b.type == BodyType::Static) continue;
      b.deviceIndex = int32_t(d.slots.size());
      d.slots.push_back(i);
      states.push_back(stateOf(b));
      params.push_back(paramsOf(b, def.gravity));
    }
    g.setBodies(states, params);
    std::vector<gpu::GpuShape> shapeRecs;
    for (uint32_t i = 0; i < shapes.capacity(); ++i) {
      if (!shapes.alive(i)) continue;
      const ShapeRec& s = shapes.at(i);
      const BodyRec& b = *bodies.get(s.body);
      shapeRecs.push_back(shapeOf(s, b, shapeTransform(b, s)));
    }
    g.setShapes(shapeRecs);
  } else {
    for (uint32_t slot : d.edited) {
      if (!bodies.alive(slot)) continue;
      const BodyRec& b = bodies.at(slot);
      if (b.deviceIndex >= 0)
        g.setBody(uint32_t(b.deviceIndex), stateOf(b), paramsOf(b, def.gravity));
    }
  }
  d.edited.clear();
  d.stale = false;

  gpu::StepInput in;
  in.dt = dt;
  in.substeps = substeps;
  in.maxLinearSpeed = def.maxLinearSpeed;
  in.maxAngularSpeed = def.maxAngularSpeed;
  in.speculativeDistance = def.speculativeDistance;
  std::string error;
  if (!g.step(in, &error)) {
    backend.lastFallback = "the device step failed: " + error;
    d.stale = true;
    return false;
  }

  // The host mirror. Forces last one step: a body that had some goes up again without.
  std::span<const gpu::GpuBodyState> out = g.states();
  for (size_t i = 0; i < d.slots.size(); ++i) {
    BodyRec& b = bodies.at(d.slots[i]);
    const gpu::GpuBodyState& s = out[i];
    b.com = {s.com.x, s.com.y, s.com.z};
    b.xf.q = {s.q.x, s.q.y, s.q.z, s.q.w};
    b.xf.p = b.com - rotate(b.xf.q, b.localCenter);
    b.v = {s.v.x, s.v.y, s.v.z};
    b.w = {s.w.x, s.w.y, s.w.z};
    if (b.force != Vec3{} || b.torque != Vec3{}) {
      b.force = b.torque = {};
      d.edited.push_back(d.slots[i]);
    }
  }

  std::span<const double> ms = g.stageMs();
  auto stage = [&](gpu::Stage s) { return ms[size_t(s)]; };
  profile.syncToDevice = stage(gpu::Stage::SyncToDevice);
  profile.updateBounds = stage(gpu::Stage::UpdateBounds);
  profile.broadPhase = stage(gpu::Stage::BroadPhase);
  profile.narrowPhase = stage(gpu::Stage::NarrowPhase);
  profile.prepare = stage(gpu::Stage::Prepare);
  profile.integrateVelocities = stage(gpu::Stage::IntegrateVelocities);
  profile.integratePositions = stage(gpu::Stage::IntegratePositions);
  profile.finalize = stage(gpu::Stage::Finalize);
  profile.readback = stage(gpu::Stage::Readback);
  stats.bodies = int(bodies.size());
  stats.awake = int(d.slots.size());
  stats.contacts = stats.contactPoints = stats.joints = 0;
  stats.maxPenetration = 0;
  stats.velocityResidual = 0;
  stats.iterationsUsed = 0;
  backend.gpuSteps++;
  return true;
}

#endif

}  // namespace phys
