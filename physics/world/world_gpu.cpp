// The GPU backend's side of a World: opening the device, handing bodies and shapes to the
// device world (gpu_solver/) as flat records, stepping it and copying the states back into
// the host mirror (BodyRec), which is what getBody, the metrics and publishing read.
//
// The device takes the whole step for every shape (hulls packed once per structure change),
// joint and preset, with these differences (docs/ARCHITECTURE.md, "The GPU backend"): the
// Gauss-Seidel schemes run on colors, direct_ldl joints by the device's own sparse
// L D L^T (joint_ldl.comp; double precision, a workgroup per joint island), a few settings
// (contactsOffDevice) are the CPU's alone. A world that needs one of those has each step
// with a contact or joint taken by the CPU backend from the same host mirror, counted in
// BackendState::cpuSteps with the reason; the device's copy is refreshed before its next
// step.
#include <algorithm>
#include <atomic>
#include <bit>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <map>
#include <mutex>
#include <string>
#include <tuple>
#include <unordered_map>
#include <vector>

#include "world/world_impl.h"

#ifdef PHYS_WITH_GPU
#include "phys/gpu/gpu_world.h"
#include "phys/gpu/hull_pack.h"
#endif

namespace phys {

const BackendState& World::backendState() const {
  return impl_->backend;
}

#ifndef PHYS_WITH_GPU

struct DeviceWorld {};
void DeviceWorldDeleter::operator()(DeviceWorld* d) const {
  delete d;
}
void World::Impl::openDevice() {
  backend.requested = def.backend;
  if (def.backend == Backend::Cpu) return;  // nothing to say: the CPU is what it asked for
  backend.note = "built without the GPU backend (PHYS_WITH_GPU=OFF)";
}
int gpuValidationErrorsInProcess() {
  return 0;
}
void World::Impl::deviceEdited(uint32_t) {}
void World::Impl::deviceStale() {}
void World::Impl::deviceJointsChanged() {}
bool World::Impl::deviceTakesStep() {
  return false;
}
bool World::Impl::stepOnDevice(int) {
  return false;
}

#else

// The device's split depth is the CPU's (shared.h's is a GLSL literal).
static_assert(float(PHYS_GPU_SPLIT_DEPTH) == SolverSettings::kSplitDepth);
static_assert(float(PHYS_GPU_POINT_PATCH_DEPTH) == SolverSettings::kPointPatchDepth);

struct DeviceWorld {
  std::unique_ptr<gpu::GpuWorld> world;
  bool hulls = false;                ///< a hull the device cannot take (hull_pack.h's limits)
  std::vector<uint32_t> jointSlots;  ///< device joint index -> joint slot
  std::vector<float> stiffness;      ///< body slot -> joints' geometric stiffness this step
  std::vector<uint32_t> slots;       ///< device body index -> body slot
  std::vector<uint32_t> owners;      ///< device shape index -> its body's slot
  std::vector<uint32_t> edited;      ///< body slots edited since the last upload
  std::vector<uint8_t> forcesCleared;  ///< per awake body: the mirror cleared its forces
  bool stale = true;                 ///< bodies or shapes changed: upload everything
  bool jointsChanged = false;        ///< a joint fell asleep or woke: the joints go up again
  // Backend::Auto (deviceTakesStep): the calibrated crossover and the last choice.
  bool autoBackend = false;
  double crossover = 0;     ///< bodies; the device above, the CPU below (+inf: never)
  std::string calibration;  ///< the calibration's figures, for the note
  bool autoOnDevice = false;
  size_t decidedAt = 0;  ///< body count at the last choice (0: none yet)
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

// A sleeping body goes up as a body the step does not move (v and w are zero): contacts
// with it treat it as immovable, and an awake body that touches it wakes it (stepOnDevice).
gpu::GpuBodyParams paramsOf(const BodyRec& b, Vec3 gravity, float stiffness) {
  gpu::GpuBodyParams p;
  // A body the CPU steps this step (BodyRec::held) goes up as a sleeping one.
  const bool dynamic = b.type == BodyType::Dynamic && !b.asleep() && !b.held;
  p.accel = v4(dynamic ? gravity * b.gravityScale + b.force * b.invMass : Vec3{}, b.invMass);
  p.torque = v4(dynamic ? b.torque : Vec3{}, b.linearDamping);
  p.principal = q4(b.principal);
  p.moments = v4(b.principalMoments, b.angularDamping);
  for (int r = 0; r < 3; ++r) p.invInertia[r] = v4(b.invInertiaLocal.row(r));
  p.localCenter = v4(b.localCenter, dynamic ? stiffness : 0.0f);
  // The same rule as Solver bodies (buildSolverBodies): equal moments need no splitting.
  const Vec3 I = b.principalMoments;
  const float spread = std::max({I.x, I.y, I.z}) - std::min({I.x, I.y, I.z});
  const bool gyroscopic = b.gyroscopic && spread > 1e-5f * std::max({I.x, I.y, I.z});
  p.flags.x = (dynamic ? PHYS_GPU_BODY_DYNAMIC : 0u) |
              (dynamic && gyroscopic ? PHYS_GPU_BODY_GYROSCOPIC : 0u) |
              (b.asleep() || b.held ? PHYS_GPU_BODY_ASLEEP : 0u);
  return p;
}

gpu::GpuJoint jointOf(const JointRec& j, const BodyRec* A, const BodyRec& B) {
  const JointDef& d = j.def;
  gpu::GpuJoint g;
  g.type = uint32_t(d.type);
  g.flags =
      (d.enableLimit ? PHYS_GPU_JOINT_LIMIT : 0u) | (d.enableMotor ? PHYS_GPU_JOINT_MOTOR : 0u);
  g.qA = {0, 0, 0, 1};
  if (A && A->deviceIndex >= 0) {
    g.bodyA = A->deviceIndex;
    g.anchorA = v4(d.anchorA - A->localCenter, j.length);
  } else {
    // The world, or a static body: its anchor and orientation in the world (jointFrame).
    g.bodyA = -1;
    g.anchorA = v4(A ? apply(A->xf, d.anchorA) : d.anchorA, j.length);
    if (A) g.qA = q4(A->xf.q);
  }
  g.qB = {0, 0, 0, 1};
  g.bodyB = B.deviceIndex;
  if (B.deviceIndex >= 0) {
    g.anchorB = v4(d.anchorB - B.localCenter, d.lower);
  } else {  // a static body B: its anchor and orientation in the world
    g.anchorB = v4(apply(B.xf, d.anchorB), d.lower);
    g.qB = q4(B.xf.q);
  }
  g.axisA = v4(normalize(d.axisA), d.upper);
  g.axisB = v4(normalize(d.axisB), d.motorSpeed);
  g.relRot0 = q4(j.relRot0);
  g.refA = v4(j.refA, d.maxMotorForce);
  g.refB = v4(j.refB, d.springHertz);
  const bool rigid = !d.enableLimit && d.springHertz <= 0;
  g.spring = {d.springDampingRatio, rigid ? 1.0f : 0.0f, 0, 0};
  return g;
}

gpu::GpuJointOut jointImpulses(const JointRec& j) {
  gpu::GpuJointOut o;
  for (int k = 0; k < j.impulseCount && k < JointRec::kMaxRows; ++k)
    (k < 4 ? (&o.impulses[0].x)[k] : (&o.impulses[1].x)[k - 4]) = j.impulses[k];
  const uint32_t count = uint32_t(j.impulseCount);
  std::memcpy(&o.force.w, &count, 4);
  return o;
}

gpu::GpuShape shapeOf(const ShapeRec& s, const BodyRec& b, const Transform& world,
                      uint32_t hullOffset) {
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
      // The record's offset as float bits (no arithmetic on it); a static hull's bound is a
      // sphere about the shape's position: its farthest vertex.
      g.size = {std::bit_cast<float>(hullOffset), 0, 0, 0};
      if (fixed && geom.hull) {
        float r = 0;
        for (const Vec3& v : geom.hull->vertices) r = std::max(r, length(v));
        g.localP.w = r;
      }
      break;
  }
  return g;
}

}  // namespace

int gpuValidationErrorsInProcess() {
  return gpu::validationErrorsInProcess();
}

namespace {

/// Backend::Auto's calibration of one device (per process and device options): the median
/// wall time of a step of a small and of a medium synthetic world (spheres resting on a
/// plane, the default solver settings, one thread) on the device and on the CPU, taken
/// once, when the first auto world opens the device. A line through each pair of points is
/// that backend's cost; where they cross is the size above which the device is the faster.
struct AutoCalibration {
  double deviceMs[2] = {0, 0}, cpuMs[2] = {0, 0};
  double crossover = 0;  ///< bodies
  std::string text;
};

double medianStepMs(World& w, int steps) {
  for (int i = 0; i < 2; ++i) w.step();  // first steps: buffers, pipelines
  std::vector<double> ms;
  for (int i = 0; i < steps; ++i) {
    w.step();
    ms.push_back(w.profile().total);
  }
  std::sort(ms.begin(), ms.end());
  return ms[ms.size() / 2];
}

constexpr int kCalibrationBodies[2] = {2, 65};  ///< the ground and 1 or 64 spheres

AutoCalibration calibrate(const WorldDef& like) {
  AutoCalibration c;
  for (int size = 0; size < 2; ++size) {
    for (int onDevice = 0; onDevice < 2; ++onDevice) {
      WorldDef d;
      d.backend = onDevice ? Backend::Gpu : Backend::Cpu;
      d.gpuAllowCpuDevice = like.gpuAllowCpuDevice;
      d.threads = 1;
      World w(d);
      BodyDef ground;
      ground.type = BodyType::Static;
      ShapeDef plane;
      plane.geom = ShapeGeom::plane({0, 0, 1}, 0);
      ground.shapes.push_back(plane);
      BodyId id;
      w.createBody(ground, &id);
      for (int i = 0; i < kCalibrationBodies[size] - 1; ++i) {
        BodyDef b;
        b.position = {float(i % 8) * 1.5f, float(i / 8) * 1.5f, 0.25f};
        ShapeDef sphere;
        sphere.geom = ShapeGeom::sphere(0.25f);
        b.shapes.push_back(sphere);
        w.createBody(b, &id);
      }
      (onDevice ? c.deviceMs : c.cpuMs)[size] = medianStepMs(w, 7);
    }
  }
  // ms = a + b n for each backend; the device is the faster above n = (ad - ac) / (bc - bd).
  const double dn = kCalibrationBodies[1] - kCalibrationBodies[0];
  const double bd = std::max(0.0, (c.deviceMs[1] - c.deviceMs[0]) / dn);
  const double bc = std::max(0.0, (c.cpuMs[1] - c.cpuMs[0]) / dn);
  const double ad = c.deviceMs[0] - bd * kCalibrationBodies[0];
  const double ac = c.cpuMs[0] - bc * kCalibrationBodies[0];
  if (ad <= ac)
    c.crossover = 0;
  else
    c.crossover = bc > bd ? (ad - ac) / (bc - bd) : std::numeric_limits<double>::infinity();
  char text[256];
  std::snprintf(text, sizeof text,
                "a step of %d / %d bodies: %.3g / %.3g ms on the device, %.3g / %.3g ms on the "
                "CPU (one thread)",
                kCalibrationBodies[0], kCalibrationBodies[1], c.deviceMs[0], c.deviceMs[1],
                c.cpuMs[0], c.cpuMs[1]);
  c.text = text;
  return c;
}

/// The calibration for these device options, taken the first time an auto world asks.
const AutoCalibration& calibrationFor(const WorldDef& like, const gpu::DeviceOptions& o) {
  static std::mutex mutex;
  static std::map<std::tuple<bool, bool, std::string>, AutoCalibration> done;
  std::lock_guard<std::mutex> lock(mutex);
  const auto key = std::make_tuple(o.allowCpu, o.validation, o.nameContains);
  auto it = done.find(key);
  if (it == done.end()) it = done.emplace(key, calibrate(like)).first;
  return it->second;
}

}  // namespace

bool World::Impl::deviceTakesStep() {
  DeviceWorld& d = *device;
  if (!d.autoBackend) return true;
  // Chosen at the first step, and again when the body count has doubled or halved since:
  // a world is usually made empty and filled before it runs, and switching costs a full
  // upload and cold contacts, so not at every body. A margin of a quarter around the
  // crossover keeps a world near it from flipping.
  const size_t n = bodies.size();
  if (d.decidedAt == 0 || n >= 2 * d.decidedAt || 2 * n <= d.decidedAt) {
    const double margin = d.decidedAt == 0 ? 1.0 : d.autoOnDevice ? 0.8 : 1.25;
    d.autoOnDevice = double(n) > d.crossover * margin;
    d.decidedAt = std::max<size_t>(n, 1);
    char text[160];
    std::snprintf(text, sizeof text, "auto: %s for %zu bodies (the device is the faster above %.4g; ",
                  d.autoOnDevice ? "the device" : "the CPU backend", n, d.crossover);
    backend.note = text + d.calibration + ")";
    backend.active = d.autoOnDevice ? Backend::Gpu : Backend::Cpu;
  }
  return d.autoOnDevice;
}

void World::Impl::openDevice() {
  backend.requested = def.backend;
  if (def.backend == Backend::Cpu) return;
  gpu::DeviceOptions options;
  options.allowCpu = def.gpuAllowCpuDevice;
  options = gpu::deviceOptionsFromEnv(options);
  backend.validationRequested = options.validation;
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
  backend.validation = world->device().validation;
  backend.active = Backend::Gpu;
  device->world = std::move(world);
  if (def.backend == Backend::Auto) {
    const AutoCalibration& c = calibrationFor(def, options);
    device->autoBackend = true;
    device->crossover = c.crossover;
    device->calibration = c.text;
    backend.autoCrossoverBodies = c.crossover;
  }
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

void World::Impl::deviceJointsChanged() {
  if (device) device->jointsChanged = true;
}

/// Why the device cannot solve this world's contacts (empty: it can).
static std::string contactsOffDevice(const SolverSettings& s, bool hulls, bool narrowPhase) {
  if (!narrowPhase) return "this build has no narrow phase on the GPU";
  if (hulls) return "a hull shape is beyond the GPU backend's hull limits (hull_pack.h)";
  // The device pairs the position pass's form with the scheme (as the presets do).
  const bool jacobi = s.scheme == SolverSettings::Scheme::Jacobi;
  if (s.positionIterations > 0 &&
      ((s.positionPass == SolverSettings::PositionPass::NonlinearJacobi && !jacobi) ||
       (s.positionPass == SolverSettings::PositionPass::NonlinearGaussSeidel && jacobi)))
    return "the position pass's form differs from the scheme's (the GPU backend pairs "
           "nonlinear_jacobi with jacobi and nonlinear_gauss_seidel with the Gauss-Seidel "
           "schemes)";
  if (s.blockContacts) return "the contact block solve is not on the GPU backend yet";
  if (s.splitPushout && (jacobi || s.stabilization != SolverSettings::Stabilization::Soft))
    return "the GPU backend has the split push-out with soft Gauss-Seidel only";
  return {};
}

static gpu::ContactSettings contactSettings(const SolverSettings& s) {
  gpu::ContactSettings c;
  // Both Gauss-Seidel schemes run on colors on the device (the CPU's gauss_seidel runs the
  // contacts in one fixed order: the results differ in rounding and order).
  c.jacobi = s.scheme == SolverSettings::Scheme::Jacobi;
  c.patchFriction = s.patchFriction;
  c.iterations = s.iterations;
  c.relaxIterations = s.relaxIterations;
  c.soft = s.stabilization == SolverSettings::Stabilization::Soft;
  c.contactHertz = s.contactHertz;
  c.contactDampingRatio = s.contactDampingRatio;
  c.jointHertz = s.jointHertz;
  c.jointDampingRatio = s.jointDampingRatio;
  c.baumgarte = s.baumgarte;
  c.linearSlop = s.linearSlop;
  c.maxPushout = s.maxPushout;
  c.warmStart = s.warmStart;
  c.restitution = s.restitution;
  c.restitutionThreshold = s.restitutionThreshold;
  // The position pass: nonlinear Jacobi with the Jacobi scheme, nonlinear Gauss-Seidel on
  // colors with the others (contactsOffDevice sends other pairings to the CPU).
  c.positionIterations =
      s.positionPass == SolverSettings::PositionPass::None ? 0 : s.positionIterations;
  c.positionBaumgarte = s.positionBaumgarte;
  c.maxPositionCorrection = s.maxPositionCorrection;
  c.directJoints = s.equalitySolve == SolverSettings::EqualitySolve::DirectLdl;
  c.splitPushout = s.splitPushout;
  return c;
}

/// What changed on the host goes up: everything when stale, else the edited bodies, and the
/// joints when one fell asleep or woke. A sleeping joint (its bodies asleep) stays on the
/// host with its impulses, which warm-start it when it wakes.
void World::Impl::uploadToDevice() {
  DeviceWorld& d = *device;
  gpu::GpuWorld& g = *d.world;
  const auto stiffnessOf = [&](uint32_t slot) {
    return slot < d.stiffness.size() ? d.stiffness[slot] : 0.0f;
  };
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
      params.push_back(paramsOf(b, def.gravity, stiffnessOf(i)));
    }
    g.setBodies(states, params);
    std::vector<gpu::GpuShape> shapeRecs;
    std::vector<uint32_t> hullWords(4, 0);  // no record at offset 0
    std::unordered_map<const ConvexHull*, uint32_t> packed;
    d.owners.clear();
    d.hulls = false;
    for (uint32_t i = 0; i < shapes.capacity(); ++i) {
      if (!shapes.alive(i)) continue;
      const ShapeRec& s = shapes.at(i);
      uint32_t hull = gpu::kNoHull;
      if (s.def.geom.type == ShapeType::Hull && s.def.geom.hull) {
        const ConvexHull* h = s.def.geom.hull.get();
        auto it = packed.find(h);
        if (it == packed.end()) {
          std::string error;
          it = packed.emplace(h, gpu::packHull(gpu::hullInputOf(*h), &hullWords, &error)).first;
          d.hulls |= it->second == gpu::kNoHull;  // unusable on the device: the CPU takes it
        }
        hull = it->second;
      }
      const BodyRec& b = *bodies.get(s.body);
      shapeRecs.push_back(shapeOf(s, b, shapeTransform(b, s), hull));
      d.owners.push_back(s.body.index);
    }
    g.setShapes(shapeRecs, d.owners);
    g.setHulls(std::move(hullWords));
    std::vector<std::pair<uint32_t, uint32_t> > apart;
    for (uint64_t key : noCollide) apart.push_back({uint32_t(key >> 32), uint32_t(key)});
    g.setNoCollide(std::move(apart));
    d.jointsChanged = true;
  } else {
    for (uint32_t slot : d.edited) {
      if (!bodies.alive(slot)) continue;
      const BodyRec& b = bodies.at(slot);
      if (b.deviceIndex >= 0)
        g.setBody(uint32_t(b.deviceIndex), stateOf(b),
                  paramsOf(b, def.gravity, stiffnessOf(slot)));
    }
  }
  if (d.jointsChanged) {
    std::vector<gpu::GpuJoint> jointRecs;
    std::vector<gpu::GpuJointOut> jointWarm;
    d.jointSlots.clear();
    for (uint32_t i = 0; i < joints.capacity(); ++i) {
      if (!joints.alive(i)) continue;
      const JointRec& j = joints.at(i);
      const BodyRec* A = j.def.bodyA.isNull() ? nullptr : bodies.get(j.def.bodyA);
      const BodyRec& B = *bodies.get(j.def.bodyB);
      if (B.asleep() || (A && A->asleep())) continue;
      if (B.held || (A && A->held)) continue;  // the CPU steps it (world_gpu_islands.cpp)
      d.jointSlots.push_back(i);
      jointRecs.push_back(jointOf(j, A, B));
      jointWarm.push_back(jointImpulses(j));
    }
    g.setJoints(jointRecs, jointWarm);
  }
  d.edited.clear();
  d.stale = d.jointsChanged = false;
}

/// After a device step: the sleeping islands an awake body (or a moving kinematic one) now
/// touches wake, as the CPU's wakeTouched. The touching pairs come back with the step (the
/// device's touch list, readTouches: pairs of non-static bodies with contact points); the
/// device finds no pair between two bodies that are asleep or static. Returns whether any
/// woke.
bool World::Impl::wakeTouchedOnDevice() {
  const DeviceWorld& d = *device;
  if (sleepingBodyCount == 0) return false;
  std::vector<int32_t> wake;
  for (const gpu::Touch& t : d.world->touches()) {
    const BodyRec& A = bodies.at(d.slots[t.a]);
    const BodyRec& B = bodies.at(d.slots[t.b]);
    if (A.asleep() == B.asleep()) continue;
    const BodyRec& sleeper = A.asleep() ? A : B;
    if (wakesSleeper(A.asleep() ? B : A)) wake.push_back(sleeper.island);
  }
  std::sort(wake.begin(), wake.end());
  wake.erase(std::unique(wake.begin(), wake.end()), wake.end());
  for (int32_t k : wake) wakeIsland(k);
  return !wake.empty();
}

void World::Impl::deviceTouchingPairs(std::vector<std::pair<uint32_t, uint32_t>>* out) const {
  out->clear();
  const DeviceWorld& d = *device;
  for (const gpu::GpuManifold& m : d.world->manifolds())
    if (m.count > 0) out->push_back({d.owners[m.shapeA], d.owners[m.shapeB]});
}

bool World::Impl::stepOnDevice(int substeps) {
  DeviceWorld& d = *device;
  const float dt = def.timeStep;
  const bool sleeping = sleepActive();
  if (sleeping) {
    wakeJointedToMovingKinematic();
    if (awakeBodies.empty()) {
      // Every body asleep (or static): nothing for the device to do, nothing moves.
      stats.bodies = int(bodies.size());
      stats.awake = 0;
      stats.pairs = stats.contacts = stats.contactPoints = stats.joints = 0;
      stats.broadPhaseTestsPerShape = 0;
      stats.pairsDropped = 0;
      stats.pairLimit = pairLimit();
      stats.maxPenetration = 0;
      stats.velocityResidual = 0;
      stats.iterationsUsed = 0;
      deviceTouches.clear();
      backend.readbackBytes = 0;
      backend.uploadBytes = 0;
      backend.gpuSteps++;
      return true;
    }
  }
  // Joints' geometric stiffness from last step's forces (addGeometricStiffness): it goes up
  // in the bodies' parameters, so a body that has or had some goes up again.
  if (def.solver.geometricStiffness && joints.size() > 0) {
    std::vector<float> k = jointStiffness();
    for (uint32_t i = 0; i < k.size(); ++i)
      if (k[i] > 0 || (i < d.stiffness.size() && d.stiffness[i] > 0)) d.edited.push_back(i);
    d.stiffness.swap(k);
  } else if (!d.stiffness.empty()) {
    for (uint32_t i = 0; i < d.stiffness.size(); ++i)
      if (d.stiffness[i] > 0) d.edited.push_back(i);
    d.stiffness.clear();
  }
  gpu::GpuWorld& g = *d.world;
  // Islands that need the CPU's physics are held on the device and stepped by the CPU
  // (world_gpu_islands.cpp).
  const bool cpuIslandsOn = cpuIslandsBegin(d.stale);
  // The host's part of the step (StepProfile::hostUpload and the others).
  using Clock = std::chrono::steady_clock;
  const auto msSince = [](Clock::time_point t) {
    return std::chrono::duration<double, std::milli>(Clock::now() - t).count();
  };
  double hostUpload = 0, hostReadback = 0;
  const auto upload = [&]() {
    const Clock::time_point t = Clock::now();
    uploadToDevice();
    hostUpload += msSince(t);
  };
  upload();

  // A world whose contacts or joints the device cannot solve yet steps on the device only
  // while it has none (the CPU's broad phase tells).
  std::string why = contactsOffDevice(def.solver, d.hulls, d.world->hasNarrowPhase());
  const bool solveOnDevice = why.empty();
  if (!solveOnDevice && joints.size() == 0) {
    updateBounds(dt);
    broadPhaseStage();
    if (contacts.empty()) why.clear();
  }
  if (!why.empty()) {
    backend.lastFallback = why;
    return false;
  }

  gpu::StepInput in;
  in.dt = dt;
  in.substeps = substeps;
  in.maxLinearSpeed = def.maxLinearSpeed;
  in.maxAngularSpeed = def.maxAngularSpeed;
  in.speculativeDistance = def.speculativeDistance;
  in.solveContacts = solveOnDevice;
  in.contacts = contactSettings(def.solver);
  in.maxPairs = pairLimit();
  // A small world's colored passes in one workgroup on a GPU; not on a CPU implementation
  // (lavapipe), where it is the slower path. PHYS_GPU_SMALL_WORLD=0 or 1 says otherwise.
  in.smallWorldConstraints = g.device().isCpu ? 0 : 256;
  if (const char* e = std::getenv("PHYS_GPU_SMALL_WORLD"); e && *e)
    in.smallWorldConstraints = std::string(e) == "0" ? 0 : 256;
  // With sleeping on, the touching pairs come back (the device's touch list, not the
  // manifolds): the islands are found on the host. The CPU's islands (world_gpu_islands.cpp)
  // judge each contact by its shapes' materials, the ground's too, which the touch list
  // leaves out: for them the manifolds come back (only in worlds that have such contacts).
  in.readTouches = sleeping;
  in.readContacts = cpuIslandsOn;
  // Past the pair bound under PairOverflow::Refuse the step is not taken: refused before the
  // host mirror is written (the device's copy is marked stale by the refusal), so the world
  // is as it was even without the guard.
  auto take = [&]() {
    std::string error;
    if (!g.step(in, &error)) {
      backend.lastFallback = "the device step failed: " + error;
      d.stale = true;
      return false;
    }
    hostUpload += g.hostMs().record;
    hostReadback += g.hostMs().copyOut;
    const gpu::ContactStats cs = g.contactStats();
    const uint64_t found = uint64_t(cs.pairs) + cs.dropped;
    if (def.pairOverflow == WorldDef::PairOverflow::Refuse && found > in.maxPairs) {
      stats.pairLimit = in.maxPairs;
      stats.pairsDropped = found - in.maxPairs;
      throw PairLimitReached();
    }
    return true;
  };
  if (!take()) return false;
  if (sleeping && wakeTouchedOnDevice()) {
    // On the CPU a sleeping island that the step's narrow phase finds touched joins that
    // step (wakeTouched). The device found it only after its step: the step is undone and
    // taken again with the island awake (a wake is rare: one more step's work then).
    g.undoStep();
    upload();
    if (!take()) return false;
    // Islands the woken ones touch wake for the next step (as on the CPU, which finds them
    // in the next step's narrow phase).
    wakeTouchedOnDevice();
  }
  if (cpuIslandsOn) {
    // Islands this step's contacts show needing the CPU (or touching one it holds) join the
    // CPU's part, and the device step is taken again without them: no island is split.
    std::vector<std::pair<uint32_t, uint32_t>> touches;
    deviceTouchingPairs(&touches);
    while (cpuIslandsGrow(touches)) {
      g.undoStep();
      upload();
      if (!take()) return false;
      deviceTouchingPairs(&touches);
    }
    cpuIslandsStep(substeps);
  }

  // The host mirror of the awake bodies (a sleeping body is where it fell asleep, at rest),
  // in one pass over them on the world's threads, each body its own. The pass also forms
  // what the passes after the step would otherwise go over every body again for
  // (mirrorScan): each body's energy term, summed afterwards in World::energy's order (the
  // same bits), and the first body that the guard's health check and keepInsideWorld must
  // look at (the same quick tests on the same states). Forces last one step: a body that
  // had some goes up again without (listed afterwards in awakeBodies' order).
  const Clock::time_point mirrorStart = Clock::now();
  std::span<const gpu::GpuBodyState> out = g.states();
  const size_t n = awakeBodies.size();
  energyTerms.resize(n);
  d.forcesCleared.resize(n);
  const QuickHealth quick = quickHealth();
  const Vec3 gravity = def.gravity;
  std::atomic<size_t> healthFrom{n}, insideFrom{n};
  forEachRange(n, [&](size_t begin, size_t end) {
    bool healthy = true, inside = true;  // every body of this range so far
    for (size_t k = begin; k < end; ++k) {
      const uint32_t slot = awakeBodies[k];
      BodyRec& b = bodies.at(slot);
      d.forcesCleared[k] = 0;
      if (!b.asleep() && !b.held && b.deviceIndex >= 0) {  // held: the CPU stepped it
        const gpu::GpuBodyState& s = out[size_t(b.deviceIndex)];
        b.com = {s.com.x, s.com.y, s.com.z};
        b.xf.q = {s.q.x, s.q.y, s.q.z, s.q.w};
        b.xf.p = b.com - rotate(b.xf.q, b.localCenter);
        b.v = {s.v.x, s.v.y, s.v.z};
        b.w = {s.w.x, s.w.y, s.w.z};
        if (b.force != Vec3{} || b.torque != Vec3{}) {
          b.force = b.torque = {};
          d.forcesCleared[k] = 1;
        }
      }
      if (sleeping) b.solverIndex = int32_t(k + 1);  // updateSleep's numbering
      energyTerms[k].energy = b.type == BodyType::Dynamic ? bodyEnergy(b, gravity) : 0.0;
      // The guard's copy lists the awake bodies in this order (takeSnapshot); a body it
      // does not have at k (woken during the step) ends the quick tests' run here.
      const bool clear = snapshotValid && k < snapshot.bodies.size() &&
                         snapshot.bodies[k].index == slot && quick.clear(b, snapshot.bodies[k]);
      if (healthy && !clear) {
        lowerTo(healthFrom, k);
        healthy = false;
      }
      if (inside && !insideExtent(b)) {
        lowerTo(insideFrom, k);
        inside = false;
      }
    }
  });
  double energy = 0;  // World::energy's sum (a body that is not dynamic adds +0.0)
  for (size_t k = 0; k < n; ++k) {
    energy += energyTerms[k].energy;
    if (d.forcesCleared[k]) d.edited.push_back(awakeBodies[k]);
  }
  if (sleepingBodyCount > 0) energy += sleepingPotential();
  if (sleeping) {
    // The islands' edges (updateSleep).
    deviceTouches.clear();
    for (const gpu::Touch& t : g.touches()) deviceTouches.push_back({d.slots[t.a], d.slots[t.b]});
  }
  mirrorScan = {true, energy, healthFrom.load(), insideFrom.load()};

  // Joints: impulses (next step's warm start on either backend, snapshots), reactions, and
  // their errors at the new poses.
  std::span<const gpu::GpuJointOut> jout = g.jointResults();
  for (size_t k = 0; k < d.jointSlots.size() && k < jout.size(); ++k) {
    JointRec& j = joints.at(d.jointSlots[k]);
    uint32_t count;
    std::memcpy(&count, &jout[k].force.w, 4);
    j.impulseCount = int32_t(std::min<uint32_t>(count, JointRec::kMaxRows));
    for (int r = 0; r < j.impulseCount; ++r)
      j.impulses[r] = r < 4 ? (&jout[k].impulses[0].x)[r] : (&jout[k].impulses[1].x)[r - 4];
    j.state.reactionForce = {jout[k].force.x, jout[k].force.y, jout[k].force.z};
    j.state.reactionTorque = {jout[k].torque.x, jout[k].torque.y, jout[k].torque.z};
  }
  if (!d.jointSlots.empty()) measureJoints();
  profile.hostMirror = msSince(mirrorStart);
  profile.hostUpload = hostUpload;
  profile.hostReadback = hostReadback;

  std::span<const double> ms = g.stageMs();
  auto stage = [&](gpu::Stage s) { return ms[size_t(s)]; };
  profile.syncToDevice = stage(gpu::Stage::SyncToDevice);
  profile.updateBounds = stage(gpu::Stage::UpdateBounds);
  profile.broadPhase = stage(gpu::Stage::BroadPhase);
  profile.narrowPhase = stage(gpu::Stage::NarrowPhase);
  profile.prepare = stage(gpu::Stage::Prepare);
  profile.integrateVelocities = stage(gpu::Stage::IntegrateVelocities);
  profile.integratePositions = stage(gpu::Stage::IntegratePositions);
  profile.warmStart = stage(gpu::Stage::WarmStart);
  profile.solve = stage(gpu::Stage::Solve);
  profile.relax = stage(gpu::Stage::Relax);
  profile.restitution = stage(gpu::Stage::Restitution);
  profile.positionPass = stage(gpu::Stage::PositionPass);
  profile.storeImpulses = stage(gpu::Stage::StoreImpulses);
  profile.finalize = stage(gpu::Stage::Finalize);
  profile.readback = stage(gpu::Stage::Readback);
  const gpu::StepCounts counts = g.stepCounts();
  profile.dispatches = int(counts.dispatches);
  profile.barriers = int(counts.barriers);
  backend.gpuDispatches += counts.dispatches;
  backend.gpuBarriers += counts.barriers;
  stats.bodies = int(bodies.size());
  stats.awake = int(awakeBodies.size());
  const gpu::ContactStats cs = g.contactStats();
  stats.pairs = int(cs.pairs);
  stats.broadPhaseTestsPerShape = g.candidateTestsPerShape();
  stats.pairLimit = in.maxPairs;
  stats.pairsDropped = cs.dropped;
  stats.contacts = int(cs.manifolds);
  stats.contactPoints = int(cs.points);
  stats.joints = int(d.jointSlots.size());
  stats.maxPenetration = cs.deepest;
  stats.velocityResidual = 0;
  stats.iterationsUsed = 0;
  if (cpuIslandsOn) cpuIslandsFinish();
  backend.validationErrors = g.validationErrors();
  backend.readbackBytes = g.readbackBytes();
  backend.uploadBytes = g.uploadBytes();
  backend.gpuSteps++;
  return true;
}

#endif

}  // namespace phys
