#include "phys/gpu/gpu_world.h"

#include <algorithm>
#include <bit>
#include <chrono>
#include <cstdlib>
#include <cstring>
#include <iterator>
#include <map>
#include <mutex>
#include <stdexcept>
#include <tuple>

#include "gpu_primitives.h"
#include "joint_ldl.h"
#include "shader_table.h"
#include "vk_device.h"

namespace phys::gpu {

const char* stageName(Stage s) {
  switch (s) {
    case Stage::SyncToDevice:
      return "sync_to_device";
    case Stage::UpdateBounds:
      return "update_bounds";
    case Stage::BroadPhase:
      return "broad_phase";
    case Stage::NarrowPhase:
      return "narrow_phase";
    case Stage::Prepare:
      return "prepare";
    case Stage::IntegrateVelocities:
      return "integrate_velocities";
    case Stage::IntegratePositions:
      return "integrate_positions";
    case Stage::WarmStart:
      return "warm_start";
    case Stage::Solve:
      return "solve";
    case Stage::Relax:
      return "relax";
    case Stage::Restitution:
      return "restitution";
    case Stage::PositionPass:
      return "position_pass";
    case Stage::StoreImpulses:
      return "store_impulses";
    case Stage::Finalize:
      return "finalize";
    case Stage::Readback:
      return "readback";
    case Stage::Count:
      break;
  }
  return "?";
}

namespace {

/// The step's kernels, built once per device. The narrow phase may be missing from a build
/// (then the device steps only worlds without contacts).
struct Kernels {
  std::unique_ptr<Kernel> prepareBodies, integrateVelocities, integratePositions, finalize,
      updateBounds, bpKeys, bpCount, bpWrite, bpPairs, bvhScene, bvhKeys, bvhBuild, bvhFit,
      bvhCount, bvhWrite, narrowPhase, matchContacts, csrKeys,
      csrRanges, prepareContacts, contactWarmStart, contactSolve, contactRestitution, applyDeltas,
      storeImpulses, contactStats, colorRound, colorKeys, colorRanges, contactGs,
      positionJacobi, applyPositions, prepareJoints, jointJacobi, storeJoints, jointLdl,
      touchFlags, touchWrite;
  Primitives primitives;
  /// The one-workgroup build of contact_gs (a small world's colored passes, on GPUs): made
  /// at its first use, not with the others. Lavapipe never runs it (the slower path there)
  /// and takes minutes to compile it: made eagerly, it cost every process opening a device
  /// with a cold shader cache (CI's gpu.shader_cache: 287 s against about 150).
  const Kernel& contactGsGroup() {
    std::call_once(contactGsGroupMade_, [&] {
      std::span<const uint32_t> c = shaderCode("contact_gs_group");
      if (c.empty()) throw std::runtime_error("shader not embedded: contact_gs_group");
      contactGsGroup_ = std::make_unique<Kernel>(device_, "contact_gs_group", c, 10,
                                                 uint32_t(sizeof(GpuSolveConstants)));
    });
    return *contactGsGroup_;
  }
  explicit Kernels(const std::shared_ptr<Device>& d) : primitives(d), device_(d) {
    auto make = [&](const char* name, uint32_t bindings, uint32_t push) {
      std::span<const uint32_t> c = shaderCode(name);
      if (c.empty()) throw std::runtime_error(std::string("shader not embedded: ") + name);
      return std::make_unique<Kernel>(d, name, c, bindings, push);
    };
    const uint32_t step = sizeof(GpuStepConstants), solve = sizeof(GpuSolveConstants);
    prepareBodies = make("prepare_bodies", 3, step);
    integrateVelocities = make("integrate_velocities", 2, step);
    integratePositions = make("integrate_positions", 3, step);
    finalize = make("finalize", 2, step);
    updateBounds = make("update_bounds", 4, step);
    bpKeys = make("bp_keys", 3, step);
    bpCount = make("bp_count", 10, step);
    bpWrite = make("bp_write", 10, step);
    bpPairs = make("bp_pairs", 3, step);
    bvhScene = make("bvh_scene", 3, step);
    bvhKeys = make("bvh_keys", 4, step);
    bvhBuild = make("bvh_build", 7, step);
    bvhFit = make("bvh_fit", 4, step);
    bvhCount = make("bvh_count", 12, step);
    bvhWrite = make("bvh_write", 12, step);
    if (!shaderCode("narrow_phase").empty()) narrowPhase = make("narrow_phase", 7, step);
    matchContacts = make("match_contacts", 3, step);
    csrKeys = make("csr_keys", 6, solve);
    csrRanges = make("csr_ranges", 2, solve);
    prepareContacts = make("prepare_contacts", 9, solve);
    contactWarmStart = make("contact_warm_start", 6, solve);
    contactSolve = make("contact_solve", 6, solve);
    contactRestitution = make("contact_restitution", 6, solve);
    applyDeltas = make("apply_deltas", 4, solve);
    storeImpulses = make("store_impulses", 3, step);
    contactStats = make("contact_stats", 2, step);
    colorRound = make("color_round", 8, solve);
    colorKeys = make("color_keys", 3, solve);
    colorRanges = make("color_ranges", 3, solve);
    contactGs = make("contact_gs", 10, solve);
    positionJacobi = make("position_jacobi", 6, solve);
    prepareJoints = make("prepare_joints", 8, solve);
    jointJacobi = make("joint_jacobi", 6, solve);
    storeJoints = make("store_joints", 2, solve);
    jointLdl = make("joint_ldl", 18, solve);
    applyPositions = make("apply_positions", 4, solve);
    touchFlags = make("touch_flags", 4, step);
    touchWrite = make("touch_write", 5, step);
  }

 private:
  std::shared_ptr<Device> device_;
  std::once_flag contactGsGroupMade_;
  std::unique_ptr<Kernel> contactGsGroup_;
};

/// A device and its kernels, shared by every world opened with the same options.
struct SharedDevice {
  std::shared_ptr<Device> device;
  std::unique_ptr<Kernels> kernels;
  ~SharedDevice() { kernels.reset(); }  // the kernels before the device
};

/// The devices open in this process. Once opened, a device stays open until the process
/// exits (`kept`), so the next world opened after the last one was destroyed finds it (physd
/// and the tests open world after world). Opening one and building its kernels takes seconds
/// on lavapipe (the narrow phase's pipeline alone about 2 s) and tens of milliseconds on a
/// GPU. Not with validation: such a device is destroyed with its last world, so what a world's
/// teardown leaves behind is reported then (gpuValidationErrorsInProcess). A device whose
/// submit failed (lost, out of memory) is let go too: the next world opens a new one.
struct DeviceRegistry {
  using Key = std::tuple<bool, bool, std::string>;
  std::mutex mutex;
  std::map<Key, std::weak_ptr<SharedDevice>> open;
  std::map<Key, std::shared_ptr<SharedDevice>> kept;
  bool releaseAtExit = false;

  static DeviceRegistry& get() {
    static DeviceRegistry r;
    return r;
  }
  /// Destroys the kept devices before the driver's own exit handlers run: Mesa finishes
  /// its shader cache writes when a device goes, and its atexit handler, registered when
  /// the first device was opened, would stop them unfinished. Registered after that
  /// device, so it runs first.
  static void releaseKept() {
    DeviceRegistry& r = get();
    std::map<Key, std::shared_ptr<SharedDevice>> kept;
    {
      std::lock_guard<std::mutex> lock(r.mutex);
      kept.swap(r.kept);
    }
  }
};

std::shared_ptr<SharedDevice> openShared(const DeviceOptions& o, std::string* error) {
  DeviceRegistry& r = DeviceRegistry::get();
  std::lock_guard<std::mutex> lock(r.mutex);
  const DeviceRegistry::Key key = std::make_tuple(o.allowCpu, o.validation, o.nameContains);
  if (auto s = r.open[key].lock()) return s;
  auto s = std::make_shared<SharedDevice>();
  s->device = Device::open(o, error);
  if (!s->device) return nullptr;
  s->kernels = std::make_unique<Kernels>(s->device);
  r.open[key] = s;
  if (!o.validation) {
    r.kept[key] = s;
    if (!r.releaseAtExit) r.releaseAtExit = std::atexit(DeviceRegistry::releaseKept) == 0;
  }
  return s;
}

/// A device that failed a submit is no longer kept for later worlds.
void forgetShared(const std::shared_ptr<SharedDevice>& s) {
  DeviceRegistry& r = DeviceRegistry::get();
  std::lock_guard<std::mutex> lock(r.mutex);
  for (auto it = r.kept.begin(); it != r.kept.end();)
    it = it->second == s ? r.kept.erase(it) : std::next(it);
}

/// A row's stabilization as (bias rate, mass scale, impulse scale): Catto's soft constraint
/// at `hertz` (capped at a quarter of the substep rate) and `zeta`, as Solver's
/// makeSoftness(cappedHertz(..)), or Baumgarte's rigid row.
struct Stabilization {
  float biasRate = 0, massScale = 1, impulseScale = 0;
};
Stabilization stabilization(bool soft, float hertz, float zeta, float baumgarte, float h) {
  if (!soft) return {baumgarte / h, 1, 0};
  hertz = std::min(hertz, 0.25f / h);
  if (hertz <= 0) return {};
  const float omega = 2 * 3.14159265358979f * hertz;
  const float a1 = 2 * zeta + h * omega;
  const float a2 = h * omega * a1;
  const float a3 = 1 / (1 + a2);
  return {omega / a1, a2 * a3, a3};
}

GpuSolveConstants solveConstants(const ContactSettings& cs, float h, uint32_t bodies,
                                 uint32_t pairCapacity) {
  GpuSolveConstants sc{};
  sc.h = h;
  sc.invH = 1 / h;
  const Stabilization contact =
      stabilization(cs.soft, cs.contactHertz, cs.contactDampingRatio, cs.baumgarte, h);
  sc.biasRate = contact.biasRate;
  sc.massScale = contact.massScale;
  sc.impulseScale = contact.impulseScale;
  // Joints: with their own frequency (Solver::solveIteration's jointSoft).
  const Stabilization joint =
      stabilization(cs.soft, cs.jointHertz, cs.jointDampingRatio, cs.baumgarte, h);
  sc.jointBiasRate = joint.biasRate;
  sc.jointMassScale = joint.massScale;
  sc.jointImpulseScale = joint.impulseScale;
  sc.linearSlop = cs.linearSlop;
  sc.maxPushout = cs.maxPushout;
  sc.restitutionThreshold = cs.restitutionThreshold;
  sc.useBias = 1;
  sc.soft = cs.soft ? 1 : 0;
  sc.bodyCount = bodies;
  sc.refCount = 2 * pairCapacity;
  sc.warmStart = cs.warmStart ? 1 : 0;
  sc.jacobi = cs.jacobi ? 1 : 0;
  sc.patchFriction = cs.patchFriction ? 1 : 0;
  sc.splitPushout = cs.splitPushout && !cs.jacobi ? 1 : 0;
  sc.positionBaumgarte = cs.positionBaumgarte;
  sc.maxPositionCorrection = cs.maxPositionCorrection;
  return sc;
}

uint32_t groupsFor(uint32_t n) {
  return (n + PHYS_GPU_GROUP - 1) / PHYS_GPU_GROUP;
}

/// Grows `b` to hold `bytes` (contents not kept: callers re-upload after growing).
bool reserve(const std::shared_ptr<Device>& d, Buffer& b, VkDeviceSize bytes) {
  if (b && b.size() >= bytes) return false;
  VkDeviceSize size = std::max<VkDeviceSize>(bytes + bytes / 2, 1024);
  b = Buffer(d, size, Buffer::Kind::Device);
  return true;
}

}  // namespace

struct GpuWorld::Impl {
  std::shared_ptr<SharedDevice> shared;
  std::unique_ptr<Stream> stream;
  // Host mirror of what goes up; the states are also where readback lands.
  std::vector<GpuBodyState> states;
  std::vector<GpuBodyParams> params;
  std::vector<GpuShape> shapes;
  std::vector<uint32_t> planes;                          ///< indices of the plane shapes
  std::vector<uint32_t> owners;                          ///< each shape's body (host slot)
  std::vector<uint32_t> hulls;                           ///< packed hull records (hull_pack.h)
  std::vector<std::pair<uint32_t, uint32_t>> noCollide;  ///< sorted slot pairs
  std::vector<GpuJoint> joints;
  std::vector<GpuJointOut> jointOut;  ///< warm starts going up, results coming back
  bool jointsDirty = false;
  // The last step's inputs, kept so that it can be undone (undoStep): the states and joint
  // impulses before it; prevJointOut holds something only when the step changed them.
  std::vector<GpuBodyState> prevStates;
  std::vector<GpuJointOut> prevJointOut;
  /// Where the next step's states and joint results land: the arrays the step before last
  /// left (kept rather than allocated and zeroed every step: at a million bodies a fresh
  /// 64 MB array a step, page faults and all, was most of the host's readback).
  std::vector<GpuBodyState> nextStates;
  std::vector<GpuJointOut> nextJointOut;
  bool undoable = false, jointOutStepped = false;
  /// After an undo the counters' previous pair count is still the one before the undone
  /// step: the next broad phase must not overwrite it with the undone step's.
  bool keepPrevPairs = false;
  std::vector<uint32_t> dirtyBodies;
  bool allBodiesDirty = false, shapesDirty = false;
  // What came back from the last step.
  std::vector<GpuAabb> bounds;
  std::vector<GpuPair> pairs;
  std::vector<GpuManifold> manifolds;
  std::vector<Touch> touches;
  uint32_t touchHeader[2] = {};  ///< the touch list's length, then 0
  uint64_t readbackBytes = 0, uploadBytes = 0;
  HostTimes hostMs;
  uint32_t counters[PHYS_GPU_COUNTER_COUNT] = {};
  // Device buffers: bodies and shapes.
  Buffer stateBuf, paramBuf, solverBuf, shapeBuf, boundsBuf, planeBuf, ownerBuf, noCollideBuf,
      hullBuf;
  // The broad phase's: sort keys, per-position counts (then offsets), pair keys, pairs;
  // the manifolds of this step and of the last (warm starts), and the counters.
  Buffer keyBuf, countBuf, pairKeyBuf, pairBuf, counterBuf;
  Buffer manifoldBuf[2];
  // The tree's (bvh.glsl): the scene's bounds (8 uints), its internal nodes, its leaves' boxes
  // in sorted order, every node's parent and the fit's visit flags.
  Buffer sceneBuf, nodeBuf, leafBuf, parentBuf, flagBuf;
  BroadPhase broadPhase = defaultBroadPhase();
  static BroadPhase defaultBroadPhase() {
    const char* e = std::getenv("PHYS_GPU_BROAD_PHASE");
    return e && std::strcmp(e, "sweep") == 0 ? BroadPhase::Sweep : BroadPhase::Tree;
  }
  // The contact solver's: rows per manifold, velocity changes per manifold, the bodies'
  // sorted references to their contacts and each body's range in them (and mass split).
  Buffer contactBuf, deltaBuf, refKeyBuf, refBuf;
  // Colored Gauss-Seidel's: each contact's color (two, for the coloring rounds), the
  // contacts sorted by color, each color's range and its indirect dispatch size.
  Buffer colorBuf[2], colorKeyBuf, rangeBuf, argsBuf;
  // The split push-out's pseudo velocities (two vec4 a body), zeroed every substep.
  Buffer pushBuf;
  // Joints: their records, this substep's rows, and their impulses and reactions.
  Buffer jointBuf, jointRowBuf, jointOutBuf;
  // The joints' direct solve (joint_ldl.h): the plan's islands, rows, L's pattern by row and
  // by column, and the numbers: L, D and a work vector (doubles). Planned again when the
  // joints or the set of dynamic bodies change.
  Buffer ldlIslandBuf, ldlRowBuf, ldlPatternBuf, ldlColumnBuf, ldlValueBuf, ldlDiagBuf, ldlWorkBuf;
  // The plan's lists for a workgroup per island: each entry's column, the levels' row ranges,
  // each dynamic body's rows.
  Buffer ldlEntryColumnBuf, ldlLevelBuf, ldlBodyBuf, ldlBodyRowBuf;
  bool ldlDirty = true;
  uint32_t ldlIslands = 0;
  // The touch list (touch_list.glsl): a flag per manifold slot, scanned into places, and the
  // list (its length first), with its own prefix-sum scratch.
  Buffer touchFlagBuf, touchBuf;
  Primitives::ScanScratch touchScratch;
  /// The broad phase's sweep axis: the one along which the shapes' bodies spread most (a
  /// column or a stack along x would otherwise make the sweep quadratic in its length).
  /// Chosen again every kSweepAxisPeriod steps from the host's copy of the states.
  uint32_t sweepAxis = 0;
  uint64_t stepsSinceSweepAxis = ~uint64_t(0);
  static constexpr uint64_t kSweepAxisPeriod = 16;
  void chooseSweepAxis();
  uint32_t colorLimit = 16;  ///< colors dispatched (then the serial overflow), from the last step
  /// This step's world is small (StepInput::smallWorldConstraints): the colored passes and
  /// the coloring run in one workgroup, a run of passes in one dispatch.
  bool smallWorld = false;
  int current = 0;           ///< manifoldBuf[current] is this step's
  uint32_t pairCapacity = 64;
  Primitives::ScanScratch scanScratch;
  std::vector<double> stageMs = std::vector<double>(kStageCount, 0.0);
  StepCounts counts;

  void sync(Stream& s, const GpuStepConstants& c);
  void recordBroadPhase(Stream& s, const GpuStepConstants& c);
  /// The sweep's part of the broad phase (BroadPhase::Sweep): keys, sort, counted sweep.
  void recordSweepQuery(Stream& s, const GpuStepConstants& c);
  /// The tree's part of the broad phase: keys, sort, build, fit, then the counted query.
  void recordTreeQuery(Stream& s, const GpuStepConstants& c);
  void recordNarrowPhase(Stream& s, const GpuStepConstants& c);
  void recordPrepareContacts(Stream& s, const GpuSolveConstants& sc);
  /// The joints' rows at the current poses (refresh: a later substep, impulses kept).
  void recordPrepareJoints(Stream& s, GpuSolveConstants sc, bool refresh);
  /// Plans the joints' direct solve again if the joints or the dynamic bodies changed, and
  /// uploads the plan; returns the islands (0: nothing to solve directly).
  uint32_t syncLdl(Stream& s);
  /// The joints' direct solve: factor (after the rows are built), solve (after a pass) or the
  /// same on the push-out's pseudo velocities (after a push-out pass).
  void recordLdl(Stream& s, GpuSolveConstants sc, uint32_t mode, bool useBias);
  /// Colors the contacts (no two of a color share a dynamic body) and sorts them by color.
  void recordColoring(Stream& s, const GpuSolveConstants& sc);
  /// `passes` colored Gauss-Seidel passes over every color (mode: warm start, solve,
  /// restitution, ...; after a warm start the later passes solve, after the push-out's warm
  /// start they push out). A small world's run is one dispatch of one workgroup.
  void recordColoredPass(Stream& s, GpuSolveConstants sc, uint32_t mode, uint32_t passes = 1);
  /// One Jacobi pass of `kernel` over the contacts, then every body takes its average.
  void recordContactPass(Stream& s, const Kernel& kernel, const GpuSolveConstants& sc);
  Kernels& kernels() { return *shared->kernels; }
};

GpuWorld::GpuWorld(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
GpuWorld::~GpuWorld() = default;

std::unique_ptr<GpuWorld> GpuWorld::create(const DeviceOptions& options, std::string* error) {
  auto impl = std::make_unique<Impl>();
  try {
    impl->shared = openShared(options, error);
    if (!impl->shared) return nullptr;
    impl->stream = std::make_unique<Stream>(impl->shared->device);
  } catch (const std::exception& e) {
    if (error) *error = e.what();
    return nullptr;
  }
  return std::unique_ptr<GpuWorld>(new GpuWorld(std::move(impl)));
}

const DeviceInfo& GpuWorld::device() const {
  return impl_->shared->device->info();
}

int GpuWorld::validationErrors() const {
  return impl_->shared->device->validationErrors();
}

void GpuWorld::setBodies(std::span<const GpuBodyState> states,
                         std::span<const GpuBodyParams> params) {
  if (states.size() != params.size()) throw std::invalid_argument("setBodies: sizes differ");
  impl_->undoable = false;
  impl_->states.assign(states.begin(), states.end());
  impl_->params.assign(params.begin(), params.end());
  impl_->allBodiesDirty = true;
  impl_->dirtyBodies.clear();
  impl_->ldlDirty = true;
}

void GpuWorld::setBody(uint32_t index, const GpuBodyState& state, const GpuBodyParams& params) {
  if (index >= impl_->states.size()) throw std::out_of_range("setBody: no such body");
  impl_->undoable = false;
  impl_->states[index] = state;
  if ((impl_->params[index].flags.x ^ params.flags.x) & PHYS_GPU_BODY_DYNAMIC)
    impl_->ldlDirty = true;  // rows couple through dynamic bodies only
  impl_->params[index] = params;
  if (!impl_->allBodiesDirty) impl_->dirtyBodies.push_back(index);
}

void GpuWorld::setShapes(std::span<const GpuShape> shapes, std::span<const uint32_t> owners) {
  if (!owners.empty() && owners.size() != shapes.size())
    throw std::invalid_argument("setShapes: owners and shapes differ in size");
  impl_->undoable = false;
  impl_->shapes.assign(shapes.begin(), shapes.end());
  impl_->owners.assign(owners.begin(), owners.end());
  impl_->stepsSinceSweepAxis = ~uint64_t(0);  // the axis is chosen again at the next step
  if (owners.empty()) {
    impl_->owners.resize(shapes.size());
    for (uint32_t i = 0; i < shapes.size(); ++i) impl_->owners[i] = i;  // every shape its own
  }
  impl_->planes.clear();
  for (uint32_t i = 0; i < shapes.size(); ++i)
    if (shapes[i].type == PHYS_GPU_SHAPE_PLANE) impl_->planes.push_back(i);
  impl_->shapesDirty = true;
}

void GpuWorld::setHulls(std::vector<uint32_t> words) {
  impl_->hulls = std::move(words);
  impl_->shapesDirty = true;
}

void GpuWorld::setNoCollide(std::vector<std::pair<uint32_t, uint32_t>> pairs) {
  for (auto& p : pairs)
    if (p.first > p.second) std::swap(p.first, p.second);
  std::sort(pairs.begin(), pairs.end());
  impl_->noCollide = std::move(pairs);
  impl_->shapesDirty = true;
}

void GpuWorld::setJoints(std::span<const GpuJoint> joints, std::span<const GpuJointOut> impulses) {
  if (joints.size() != impulses.size()) throw std::invalid_argument("setJoints: sizes differ");
  impl_->undoable = false;
  impl_->joints.assign(joints.begin(), joints.end());
  impl_->jointOut.assign(impulses.begin(), impulses.end());
  impl_->jointsDirty = true;
  impl_->ldlDirty = true;
}
uint32_t GpuWorld::jointCount() const {
  return uint32_t(impl_->joints.size());
}
std::span<const GpuJointOut> GpuWorld::jointResults() const {
  return impl_->jointOut;
}

uint32_t GpuWorld::bodyCount() const {
  return uint32_t(impl_->states.size());
}
uint32_t GpuWorld::shapeCount() const {
  return uint32_t(impl_->shapes.size());
}

void GpuWorld::Impl::sync(Stream& s, const GpuStepConstants& c) {
  const std::shared_ptr<Device>& d = shared->device;
  const size_t n = states.size();
  // Growing a buffer loses its contents: everything in it goes up again.
  bool grown = reserve(d, stateBuf, n * sizeof(GpuBodyState));
  grown |= reserve(d, paramBuf, n * sizeof(GpuBodyParams));
  reserve(d, solverBuf, n * sizeof(GpuSolverBody));
  reserve(d, pushBuf, n * 32);
  if (grown) allBodiesDirty = true;
  if (reserve(d, shapeBuf, shapes.size() * sizeof(GpuShape))) shapesDirty = true;
  reserve(d, boundsBuf, shapes.size() * sizeof(GpuAabb));
  if (reserve(d, planeBuf, planes.size() * 4)) shapesDirty = true;
  if (reserve(d, ownerBuf, owners.size() * 4)) shapesDirty = true;
  if (reserve(d, hullBuf, hulls.size() * 4)) shapesDirty = true;
  if (reserve(d, noCollideBuf, noCollide.size() * 8)) shapesDirty = true;
  reserve(d, keyBuf, VkDeviceSize(c.shapeSortCount) * 8);
  // Constraints: the joints, then a slot per pair.
  const uint32_t constraints = uint32_t(joints.size()) + pairCapacity;
  const uint32_t keyLength = Primitives::pow2(constraints);  // = refCount / 2
  reserve(d, contactBuf, VkDeviceSize(pairCapacity) * sizeof(GpuContact));
  reserve(d, deltaBuf, VkDeviceSize(constraints) * sizeof(GpuDelta));
  reserve(d, refKeyBuf, VkDeviceSize(keyLength) * 2 * 8);
  reserve(d, refBuf, n * 16);
  for (Buffer& b : colorBuf) reserve(d, b, VkDeviceSize(keyLength) * 4);
  reserve(d, colorKeyBuf, VkDeviceSize(keyLength) * 8);
  reserve(d, jointBuf, joints.size() * sizeof(GpuJoint));
  reserve(d, jointRowBuf, joints.size() * sizeof(GpuJointRows));
  if (reserve(d, jointOutBuf, joints.size() * sizeof(GpuJointOut))) jointsDirty = true;
  reserve(d, rangeBuf, (PHYS_GPU_MAX_COLORS + 1) * 16);
  reserve(d, argsBuf, (PHYS_GPU_MAX_COLORS + 1) * 12);
  reserve(d, countBuf, VkDeviceSize(c.shapeSortCount) * 4);
  if (broadPhase == BroadPhase::Tree) {
    // Sized by the sort's length, a power of two at or above the shapes in the tree.
    const VkDeviceSize leaves = c.shapeSortCount;
    reserve(d, sceneBuf, 8 * 4);
    reserve(d, nodeBuf, leaves * sizeof(GpuBvhNode));
    reserve(d, leafBuf, leaves * sizeof(GpuAabb));
    reserve(d, parentBuf, 2 * leaves * 4);
    reserve(d, flagBuf, (2 * leaves + PHYS_GPU_GROUP) * 4);
  }
  bool pairsGrown = reserve(d, pairKeyBuf, VkDeviceSize(pairCapacity) * 8);
  pairsGrown |= reserve(d, pairBuf, VkDeviceSize(pairCapacity) * sizeof(GpuPair));
  for (Buffer& m : manifoldBuf)
    pairsGrown |= reserve(d, m, VkDeviceSize(pairCapacity) * sizeof(GpuManifold));
  if (!counterBuf) {
    counterBuf = Buffer(d, PHYS_GPU_COUNTER_COUNT * 4, Buffer::Kind::Device);
    s.fill(counterBuf, 0);
  }
  // New shape indices or lost manifolds: last step's contacts cannot warm-start this one.
  if (shapesDirty || pairsGrown) s.fill(counterBuf, 0);

  // Many scattered edits: one upload of everything is cheaper than a copy per body.
  if (!allBodiesDirty && dirtyBodies.size() > n / 4) allBodiesDirty = true;
  if (allBodiesDirty) {
    s.upload(stateBuf, 0, states.data(), n * sizeof(GpuBodyState));
    s.upload(paramBuf, 0, params.data(), n * sizeof(GpuBodyParams));
  } else {
    std::sort(dirtyBodies.begin(), dirtyBodies.end());
    dirtyBodies.erase(std::unique(dirtyBodies.begin(), dirtyBodies.end()), dirtyBodies.end());
    // Contiguous runs of dirty bodies go up as one copy each.
    for (size_t i = 0; i < dirtyBodies.size();) {
      size_t j = i + 1;
      while (j < dirtyBodies.size() && dirtyBodies[j] == dirtyBodies[j - 1] + 1) ++j;
      const uint32_t first = dirtyBodies[i], count = uint32_t(j - i);
      s.upload(stateBuf, first * sizeof(GpuBodyState), &states[first],
               count * sizeof(GpuBodyState));
      s.upload(paramBuf, first * sizeof(GpuBodyParams), &params[first],
               count * sizeof(GpuBodyParams));
      i = j;
    }
  }
  if (shapesDirty) {
    s.upload(shapeBuf, 0, shapes.data(), shapes.size() * sizeof(GpuShape));
    s.upload(planeBuf, 0, planes.data(), planes.size() * 4);
    s.upload(ownerBuf, 0, owners.data(), owners.size() * 4);
    s.upload(hullBuf, 0, hulls.data(), hulls.size() * 4);
    s.upload(noCollideBuf, 0, noCollide.data(), noCollide.size() * 8);
  }
  if (jointsDirty) {
    s.upload(jointBuf, 0, joints.data(), joints.size() * sizeof(GpuJoint));
    s.upload(jointOutBuf, 0, jointOut.data(), jointOut.size() * sizeof(GpuJointOut));
    jointsDirty = false;
  }
  dirtyBodies.clear();
  allBodiesDirty = shapesDirty = false;
}

void GpuWorld::Impl::recordBroadPhase(Stream& s, const GpuStepConstants& c) {
  Kernels& k = kernels();
  // Last step's pair count is the count of last step's manifolds (warm starts); the
  // statistics start from zero.
  if (!keepPrevPairs)
    s.copy(counterBuf, PHYS_GPU_COUNTER_PAIRS * 4, counterBuf, PHYS_GPU_COUNTER_PREV_PAIRS * 4,
           4);
  const uint32_t zeros[4] = {0, 0, 0, 0};
  s.upload(counterBuf, PHYS_GPU_COUNTER_CONTACTS * 4, zeros, sizeof zeros);
  s.upload(counterBuf, PHYS_GPU_COUNTER_BP_TESTS * 4, zeros, 8);
  if (broadPhase == BroadPhase::Tree) {
    recordTreeQuery(s, c);
  } else {
    recordSweepQuery(s, c);
  }
  // Either way the counts are now per sorted position: their prefix sum places each one's
  // pairs, which are then sorted into the pair list.
  const Buffer* write[] = {&boundsBuf, &shapeBuf,   &paramBuf,   &keyBuf,   &planeBuf, &countBuf,
                           &pairKeyBuf, &counterBuf, &ownerBuf, &noCollideBuf, &nodeBuf, &leafBuf};
  k.primitives.scan(s, countBuf, c.shapeSortCount, scanScratch);
  s.fill(pairKeyBuf, 0xFFFFFFFFu);  // the unused tail sorts last
  if (broadPhase == BroadPhase::Tree)
    s.dispatch(*k.bvhWrite, write, &c, groupsFor(c.shapeSortCount));
  else
    s.dispatch(*k.bpWrite, std::span(write).first(10), &c, groupsFor(c.shapeSortCount));
  k.primitives.sort(s, pairKeyBuf, c.pairCapacity);
  const Buffer* pairs[] = {&pairKeyBuf, &pairBuf, &counterBuf};
  s.dispatch(*k.bpPairs, pairs, &c, groupsFor(c.pairCapacity));
}

void GpuWorld::Impl::recordSweepQuery(Stream& s, const GpuStepConstants& c) {
  Kernels& k = kernels();
  const Buffer* keys[] = {&boundsBuf, &shapeBuf, &keyBuf};
  s.dispatch(*k.bpKeys, keys, &c, groupsFor(c.shapeSortCount));
  k.primitives.sort(s, keyBuf, c.shapeSortCount);
  const Buffer* sweep[] = {&boundsBuf, &shapeBuf,   &paramBuf,   &keyBuf,   &planeBuf,
                           &countBuf,  &pairKeyBuf, &counterBuf, &ownerBuf, &noCollideBuf};
  s.dispatch(*k.bpCount, sweep, &c, groupsFor(c.shapeSortCount));
}

void GpuWorld::Impl::recordTreeQuery(Stream& s, const GpuStepConstants& c) {
  Kernels& k = kernels();
  const uint32_t leaves = c.shapeCount - c.planeCount;
  // The scene's bounds, reduced on the device (no readback): the Morton codes' cube.
  s.fill(sceneBuf, 0xFFFFFFFFu);
  const Buffer* scene[] = {&boundsBuf, &shapeBuf, &sceneBuf};
  s.dispatch(*k.bvhScene, scene, &c, groupsFor(c.shapeCount));
  const Buffer* keys[] = {&boundsBuf, &shapeBuf, &keyBuf, &sceneBuf};
  s.dispatch(*k.bvhKeys, keys, &c, groupsFor(c.shapeSortCount));
  k.primitives.sort(s, keyBuf, c.shapeSortCount);
  // The links of every node at once, then their boxes bottom up.
  const Buffer* build[] = {&boundsBuf, &shapeBuf, &paramBuf, &keyBuf,
                           &nodeBuf,   &leafBuf,  &parentBuf};
  s.dispatch(*k.bvhBuild, build, &c, groupsFor(leaves));
  s.fill(flagBuf, 0);
  const Buffer* fit[] = {&nodeBuf, &leafBuf, &parentBuf, &flagBuf};
  s.dispatch(*k.bvhFit, fit, &c, groupsFor(leaves));
  const Buffer* count[] = {&boundsBuf,  &shapeBuf,   &paramBuf, &keyBuf,       &planeBuf, &countBuf,
                           &pairKeyBuf, &counterBuf, &ownerBuf, &noCollideBuf, &nodeBuf,  &leafBuf};
  s.dispatch(*k.bvhCount, count, &c, groupsFor(c.shapeSortCount));
}

void GpuWorld::Impl::recordNarrowPhase(Stream& s, const GpuStepConstants& c) {
  Kernels& k = kernels();
  if (!k.narrowPhase) return;
  const Buffer* b[] = {&stateBuf,   &paramBuf, &shapeBuf, &pairBuf, &manifoldBuf[current],
                       &counterBuf, &hullBuf};
  s.dispatch(*k.narrowPhase, b, &c, groupsFor(c.pairCapacity));
  const Buffer* match[] = {&manifoldBuf[current ^ 1], &manifoldBuf[current], &counterBuf};
  s.dispatch(*k.matchContacts, match, &c, groupsFor(c.pairCapacity));
  const Buffer* stats[] = {&manifoldBuf[current], &counterBuf};
  s.dispatch(*k.contactStats, stats, &c, groupsFor(c.pairCapacity));
}

void GpuWorld::Impl::recordPrepareContacts(Stream& s, const GpuSolveConstants& sc) {
  Kernels& k = kernels();
  const Buffer* keys[] = {&manifoldBuf[current], &shapeBuf, &paramBuf, &refKeyBuf,
                          &counterBuf,           &jointBuf};
  s.dispatch(*k.csrKeys, keys, &sc, groupsFor(sc.refCount / 2));
  k.primitives.sort(s, refKeyBuf, sc.refCount);
  const Buffer* ranges[] = {&refKeyBuf, &refBuf};
  s.dispatch(*k.csrRanges, ranges, &sc, groupsFor(sc.bodyCount));
  const Buffer* prep[] = {&solverBuf,  &paramBuf,   &refBuf,
                          &stateBuf,   &shapeBuf,   &manifoldBuf[current],
                          &contactBuf, &counterBuf, &colorBuf[0]};
  s.dispatch(*k.prepareContacts, prep, &sc, groupsFor(pairCapacity));
  recordPrepareJoints(s, sc, false);
}

void GpuWorld::Impl::recordPrepareJoints(Stream& s, GpuSolveConstants sc, bool refresh) {
  if (sc.jointCount == 0) return;
  sc.refresh = refresh ? 1 : 0;
  const Buffer* b[] = {&solverBuf, &paramBuf,    &refBuf,      &stateBuf,
                       &jointBuf,  &jointRowBuf, &jointOutBuf, &colorBuf[0]};
  s.dispatch(*kernels().prepareJoints, b, &sc, groupsFor(sc.jointCount));
  recordLdl(s, sc, PHYS_GPU_LDL_FACTOR, true);
}

uint32_t GpuWorld::Impl::syncLdl(Stream& s) {
  if (!ldlDirty) return ldlIslands;
  const JointLdlPlan plan = planJointLdl(joints, params);
  const std::shared_ptr<Device>& d = shared->device;
  const size_t rows = plan.rows.size(), entries = plan.entries();
  reserve(d, ldlIslandBuf, plan.islands.size() * sizeof(GpuLdlIsland));
  reserve(d, ldlRowBuf, rows * sizeof(GpuLdlRow));
  reserve(d, ldlPatternBuf, plan.pattern.size() * 4);
  reserve(d, ldlColumnBuf, entries * 4);
  reserve(d, ldlValueBuf, entries * 8);
  reserve(d, ldlDiagBuf, rows * 8);
  reserve(d, ldlWorkBuf, rows * 8);
  reserve(d, ldlEntryColumnBuf, entries * 4);
  reserve(d, ldlLevelBuf, plan.levels.size() * 4);
  reserve(d, ldlBodyBuf, plan.bodies.size() * sizeof(uvec4));
  reserve(d, ldlBodyRowBuf, plan.bodyRows.size() * 4);
  s.upload(ldlIslandBuf, 0, plan.islands.data(), plan.islands.size() * sizeof(GpuLdlIsland));
  s.upload(ldlRowBuf, 0, plan.rows.data(), rows * sizeof(GpuLdlRow));
  s.upload(ldlPatternBuf, 0, plan.pattern.data(), plan.pattern.size() * 4);
  s.upload(ldlColumnBuf, 0, plan.columnRows.data(), entries * 4);
  s.upload(ldlEntryColumnBuf, 0, plan.entryColumns.data(), entries * 4);
  s.upload(ldlLevelBuf, 0, plan.levels.data(), plan.levels.size() * 4);
  s.upload(ldlBodyBuf, 0, plan.bodies.data(), plan.bodies.size() * sizeof(uvec4));
  s.upload(ldlBodyRowBuf, 0, plan.bodyRows.data(), plan.bodyRows.size() * 4);
  ldlIslands = uint32_t(plan.islands.size());
  ldlDirty = false;
  return ldlIslands;
}

void GpuWorld::Impl::recordLdl(Stream& s, GpuSolveConstants sc, uint32_t mode, bool useBias) {
  if (sc.ldlIslands == 0) return;
  sc.mode = mode;
  sc.useBias = useBias ? 1 : 0;
  sc.jacobi = 0;  // whole masses: the direct solve is not split among constraints
  const Buffer* b[] = {&solverBuf,         &paramBuf,    &refBuf,        &jointBuf,
                       &jointRowBuf,       &ldlIslandBuf, &ldlRowBuf,    &ldlPatternBuf,
                       &ldlColumnBuf,      &ldlValueBuf, &ldlDiagBuf,    &ldlWorkBuf,
                       &pushBuf,           &counterBuf,  &ldlEntryColumnBuf, &ldlLevelBuf,
                       &ldlBodyBuf,        &ldlBodyRowBuf};
  // A workgroup per island (joint_ldl.comp).
  s.dispatch(*kernels().jointLdl, b, &sc, sc.ldlIslands);
}

void GpuWorld::Impl::recordColoring(Stream& s, const GpuSolveConstants& sc) {
  Kernels& k = kernels();
  // Jones-Plassmann rounds, ping-ponging the two color buffers. Contacts still uncolored
  // after them go to the serial overflow, as do colors past the limit.
  constexpr int kRounds = 24;
  const uint32_t constraints = sc.jointCount + pairCapacity;
  if (smallWorld) {
    // Every round in one workgroup, which ping-pongs the buffers itself (round r reads
    // colorBuf[r % 2], as below).
    GpuSolveConstants one = sc;
    one.groupPasses = kRounds;
    const Buffer* b[] = {&refKeyBuf, &refBuf,       &contactBuf, &paramBuf,
                         &colorBuf[0], &colorBuf[1], &counterBuf, &jointBuf};
    s.dispatch(*k.colorRound, b, &one, 1);
  }
  for (int r = 0; r < kRounds && !smallWorld; ++r) {
    const Buffer* b[] = {&refKeyBuf,  &refBuf,          &contactBuf,
                         &paramBuf,   &colorBuf[r % 2], &colorBuf[1 - r % 2],
                         &counterBuf, &jointBuf};
    s.dispatch(*k.colorRound, b, &sc, groupsFor(constraints));
  }
  const Buffer* keys[] = {&colorBuf[kRounds % 2], &colorKeyBuf, &counterBuf};
  s.dispatch(*k.colorKeys, keys, &sc, groupsFor(sc.refCount / 2));
  k.primitives.sort(s, colorKeyBuf, sc.refCount / 2);
  const Buffer* ranges[] = {&colorKeyBuf, &rangeBuf, &argsBuf};
  s.dispatch(*k.colorRanges, ranges, &sc, groupsFor(sc.colorLimit + 1));
}

void GpuWorld::Impl::recordColoredPass(Stream& s, GpuSolveConstants sc, uint32_t mode,
                                       uint32_t passes) {
  sc.mode = mode;
  const Buffer* b[] = {&solverBuf, &paramBuf, &contactBuf,  &colorKeyBuf, &rangeBuf,
                       &refBuf,    &jointBuf, &jointRowBuf, &counterBuf,  &pushBuf};
  if (smallWorld) {
    // One workgroup, every color of every pass, a barrier between colors (contact_gs.comp).
    sc.groupPasses = passes;
    s.dispatch(kernels().contactGsGroup(), b, &sc, 1);
    return;
  }
  for (uint32_t p = 0; p < passes; ++p) {
    if (p > 0 && mode == PHYS_GPU_PASS_WARM_START) sc.mode = PHYS_GPU_PASS_SOLVE;
    if (p > 0 && mode == PHYS_GPU_PASS_PUSH_WARM) sc.mode = PHYS_GPU_PASS_PUSHOUT;
    for (uint32_t color = 0; color <= sc.colorLimit; ++color) {
      sc.color = color;
      s.dispatchIndirect(*kernels().contactGs, b, &sc, argsBuf, VkDeviceSize(color) * 12);
    }
  }
}

void GpuWorld::Impl::recordContactPass(Stream& s, const Kernel& kernel,
                                       const GpuSolveConstants& sc) {
  // The joints' part of the pass first (their deltas; none at restitution), then the
  // contacts', then every body's average.
  if (sc.jointCount > 0) {
    const Buffer* joint[] = {&solverBuf, &paramBuf, &refBuf, &jointBuf, &jointRowBuf, &deltaBuf};
    s.dispatch(*kernels().jointJacobi, joint, &sc, groupsFor(sc.jointCount));
  }
  const Buffer* pass[] = {&solverBuf, &paramBuf, &contactBuf, &deltaBuf, &counterBuf, &refBuf};
  s.dispatch(kernel, pass, &sc, groupsFor(pairCapacity));
  const Buffer* apply[] = {&solverBuf, &deltaBuf, &refKeyBuf, &refBuf};
  s.dispatch(*kernels().applyDeltas, apply, &sc, groupsFor(sc.bodyCount));
}

void GpuWorld::Impl::chooseSweepAxis() {
  if (stepsSinceSweepAxis < kSweepAxisPeriod) {
    ++stepsSinceSweepAxis;
    return;
  }
  stepsSinceSweepAxis = 1;
  // Variance of the (non-plane) shapes' body centres along each axis, in double (a static
  // shape's own position).
  double sum[3] = {0, 0, 0}, sq[3] = {0, 0, 0};
  size_t count = 0;
  for (const GpuShape& s : shapes) {
    if (s.type == PHYS_GPU_SHAPE_PLANE) continue;
    if (s.body >= 0 && size_t(s.body) >= states.size()) continue;
    const vec4& p = s.body >= 0 ? states[size_t(s.body)].com : s.localP;
    const double c[3] = {p.x, p.y, p.z};
    for (int a = 0; a < 3; ++a) {
      sum[a] += c[a];
      sq[a] += c[a] * c[a];
    }
    ++count;
  }
  if (count == 0) return;
  uint32_t best = 0;
  double bestVar = -1;
  for (uint32_t a = 0; a < 3; ++a) {
    const double mean = sum[a] / double(count), var = sq[a] / double(count) - mean * mean;
    if (var > bestVar * 1.0001) {  // ties keep the lower axis (x first)
      best = a;
      bestVar = var;
    }
  }
  sweepAxis = best;
}

bool GpuWorld::step(const StepInput& in, std::string* error) {
  Impl& w = *impl_;
  Stream& s = *w.stream;
  Kernels& k = w.kernels();
  const uint32_t n = uint32_t(w.states.size()), m = uint32_t(w.shapes.size());
  const int substeps = std::max(in.substeps, 1);
  // The pair buffers' bound: the power of two at or above the pair bound (the pair keys are
  // sorted bitonically), so every pair the CPU would keep has room; between the bound and
  // the capacity pairs are kept but ContactStats lets the caller tell (pairs > maxPairs).
  const uint32_t maxCapacity = std::bit_ceil(std::clamp(in.maxPairs, 64u, 1u << 31));
  auto capped = [&](uint64_t want) {
    const uint32_t slots = Primitives::pow2(uint32_t(std::min<uint64_t>(want, 1u << 31)));
    return std::min(slots, maxCapacity);
  };
  if (w.pairCapacity > maxCapacity) {
    // A lower bound than the buffers were grown for: fewer slots, laid out again.
    w.pairCapacity = maxCapacity;
    w.allBodiesDirty = w.shapesDirty = w.jointsDirty = w.ldlDirty = true;
  }
  std::vector<double> stageMs;  // the step's submit's (a later transfer adds to the readback)
  Stream::Counts counts;        // the same: the touch list's transfer is added to it
  HostTimes host;               // the attempt that stands
  for (int attempt = 0;; ++attempt) {
    const auto recordStart = std::chrono::steady_clock::now();
    GpuStepConstants c{};
    c.h = in.dt / float(substeps);
    c.dt = in.dt;
    c.maxLinearSpeed = in.maxLinearSpeed;
    c.maxAngularSpeed = in.maxAngularSpeed;
    c.speculativeDistance = in.speculativeDistance;
    if (attempt == 0 && w.broadPhase == BroadPhase::Sweep) w.chooseSweepAxis();
    c.sweepAxis = w.sweepAxis;
    c.bodyCount = n;
    c.shapeCount = m;
    c.pairCapacity = w.pairCapacity;
    c.planeCount = uint32_t(w.planes.size());
    c.noCollideCount = uint32_t(w.noCollide.size());
    c.shapeSortCount = Primitives::pow2(m);
    const bool solve = in.solveContacts && k.narrowPhase != nullptr;
    const bool jacobi = in.contacts.jacobi;
    c.patchFriction = in.contacts.patchFriction ? 1 : 0;
    GpuSolveConstants sc = solveConstants(in.contacts, c.h, n, w.pairCapacity);
    if (!solve) sc.splitPushout = 0;
    c.splitPushout = sc.splitPushout;
    sc.colorLimit = w.colorLimit;
    sc.jointCount = uint32_t(w.joints.size());
    sc.refCount = 2 * Primitives::pow2(sc.jointCount + w.pairCapacity);
    // A small world's colored passes run in one workgroup (the Jacobi passes are several
    // kernels each: they stay as they are).
    w.smallWorld = !jacobi && in.smallWorldConstraints > 0 &&
                   uint64_t(sc.jointCount) + w.pairCapacity <= in.smallWorldConstraints;
    // Every element is written by the download (or the step fails): no zeroing needed.
    std::vector<GpuBodyState>& result = w.nextStates;
    std::vector<GpuJointOut>& jointResults = w.nextJointOut;
    result.resize(n);
    jointResults.resize(w.joints.size());
    try {
      s.begin();
      w.sync(s, c);
      if (solve && in.contacts.directJoints && sc.jointCount > 0) sc.ldlIslands = w.syncLdl(s);
      s.mark(int(Stage::SyncToDevice));
      const Buffer* bounds[] = {&w.stateBuf, &w.paramBuf, &w.shapeBuf, &w.boundsBuf};
      s.dispatch(*k.updateBounds, bounds, &c, groupsFor(m));
      s.mark(int(Stage::UpdateBounds));
      w.recordBroadPhase(s, c);
      s.mark(int(Stage::BroadPhase));
      w.recordNarrowPhase(s, c);
      s.mark(int(Stage::NarrowPhase));
      const Buffer* prepare[] = {&w.stateBuf, &w.paramBuf, &w.solverBuf};
      s.dispatch(*k.prepareBodies, prepare, &c, groupsFor(n));
      if (solve) {
        w.recordPrepareContacts(s, sc);
        if (!jacobi) w.recordColoring(s, sc);
      }
      s.mark(int(Stage::Prepare));
      // One pass of the contact solver: Jacobi (every contact, then each body's average) or
      // colored Gauss-Seidel (color by color).
      auto pass = [&](const Kernel& jacobiKernel, uint32_t mode, bool useBias) {
        GpuSolveConstants p = sc;
        p.useBias = useBias ? 1 : 0;
        p.mode = mode;
        if (jacobi)
          w.recordContactPass(s, jacobiKernel, p);
        else
          w.recordColoredPass(s, p, mode);
        // The joints' equality rows, all at once, after the rest (the CPU's iterate()).
        if (mode == PHYS_GPU_PASS_SOLVE) w.recordLdl(s, p, PHYS_GPU_LDL_SOLVE, useBias);
      };
      const Buffer* integrate[] = {&w.paramBuf, &w.solverBuf};
      for (int sub = 0; sub < substeps; ++sub) {
        s.dispatch(*k.integrateVelocities, integrate, &c, groupsFor(n));
        s.mark(int(Stage::IntegrateVelocities));
        if (solve && sub > 0 && sc.jointCount > 0) {
          w.recordPrepareJoints(s, sc, true);
          s.mark(int(Stage::Prepare));
        }
        if (solve && w.smallWorld && sc.ldlIslands == 0) {
          // The warm start and every iteration in one dispatch (timed as the solve).
          GpuSolveConstants p = sc;
          p.useBias = 1;
          w.recordColoredPass(s, p, PHYS_GPU_PASS_WARM_START,
                              1 + uint32_t(std::max(in.contacts.iterations, 0)));
          s.mark(int(Stage::Solve));
        } else if (solve) {
          pass(*k.contactWarmStart, PHYS_GPU_PASS_WARM_START, true);
          s.mark(int(Stage::WarmStart));
          for (int it = 0; it < in.contacts.iterations; ++it)
            pass(*k.contactSolve, PHYS_GPU_PASS_SOLVE, true);
          s.mark(int(Stage::Solve));
        }
        if (sc.splitPushout != 0 && w.smallWorld) {
          // The split push-out in one workgroup, which zeroes the pseudo velocities itself;
          // with the joints' direct solve between the passes, a dispatch per pass.
          if (sc.ldlIslands == 0) {
            w.recordColoredPass(s, sc, PHYS_GPU_PASS_PUSH_WARM,
                                1 + uint32_t(std::max(in.contacts.iterations, 0)));
          } else {
            w.recordColoredPass(s, sc, PHYS_GPU_PASS_PUSH_WARM);
            for (int it = 0; it < in.contacts.iterations; ++it) {
              w.recordColoredPass(s, sc, PHYS_GPU_PASS_PUSHOUT);
              w.recordLdl(s, sc, PHYS_GPU_LDL_PUSH, false);
            }
          }
        } else if (sc.splitPushout != 0) {
          // The split push-out (the kernels do nothing in a step without deep contacts).
          s.fill(w.pushBuf, 0);
          w.recordColoredPass(s, sc, PHYS_GPU_PASS_PUSH_WARM);
          for (int it = 0; it < in.contacts.iterations; ++it) {
            w.recordColoredPass(s, sc, PHYS_GPU_PASS_PUSHOUT);
            // The joints hold the pseudo velocities too (Solver::solvePushout).
            w.recordLdl(s, sc, PHYS_GPU_LDL_PUSH, false);
          }
        }
        const Buffer* positions[] = {&w.paramBuf, &w.solverBuf, &w.pushBuf};
        s.dispatch(*k.integratePositions, positions, &c, groupsFor(n));
        s.mark(int(Stage::IntegratePositions));
        if (solve && in.contacts.relaxIterations > 0 && w.smallWorld && sc.ldlIslands == 0) {
          GpuSolveConstants p = sc;
          p.useBias = 0;
          w.recordColoredPass(s, p, PHYS_GPU_PASS_SOLVE, uint32_t(in.contacts.relaxIterations));
          s.mark(int(Stage::Relax));
        } else if (solve && in.contacts.relaxIterations > 0) {
          for (int it = 0; it < in.contacts.relaxIterations; ++it)
            pass(*k.contactSolve, PHYS_GPU_PASS_SOLVE, false);
          s.mark(int(Stage::Relax));
        }
      }
      if (solve) {
        if (in.contacts.restitution) {
          pass(*k.contactRestitution, PHYS_GPU_PASS_RESTITUTION, true);
          s.mark(int(Stage::Restitution));
        }
        if (in.contacts.positionIterations > 0 && w.smallWorld) {
          w.recordColoredPass(s, sc, PHYS_GPU_PASS_POSITION,
                              uint32_t(in.contacts.positionIterations));
          s.mark(int(Stage::PositionPass));
        } else if (in.contacts.positionIterations > 0) {
          for (int it = 0; it < in.contacts.positionIterations; ++it) {
            if (jacobi) {
              GpuSolveConstants pp = sc;
              pp.mode = PHYS_GPU_PASS_POSITION;
              if (sc.jointCount > 0) {
                const Buffer* joint[] = {&w.solverBuf, &w.paramBuf,    &w.refBuf,
                                         &w.jointBuf,  &w.jointRowBuf, &w.deltaBuf};
                s.dispatch(*k.jointJacobi, joint, &pp, groupsFor(sc.jointCount));
              }
              const Buffer* b[] = {&w.solverBuf, &w.paramBuf,   &w.contactBuf,
                                   &w.deltaBuf,  &w.counterBuf, &w.refBuf};
              s.dispatch(*k.positionJacobi, b, &sc, groupsFor(w.pairCapacity));
              const Buffer* apply[] = {&w.solverBuf, &w.deltaBuf, &w.refKeyBuf, &w.refBuf};
              s.dispatch(*k.applyPositions, apply, &sc, groupsFor(n));
            } else {
              w.recordColoredPass(s, sc, PHYS_GPU_PASS_POSITION);
            }
          }
          s.mark(int(Stage::PositionPass));
        }
        if (sc.jointCount > 0) {
          const Buffer* joints[] = {&w.jointRowBuf, &w.jointOutBuf};
          s.dispatch(*k.storeJoints, joints, &sc, groupsFor(sc.jointCount));
        }
        const Buffer* store[] = {&w.contactBuf, &w.manifoldBuf[w.current], &w.counterBuf};
        s.dispatch(*k.storeImpulses, store, &c, groupsFor(w.pairCapacity));
        s.mark(int(Stage::StoreImpulses));
      }
      const Buffer* finalize[] = {&w.stateBuf, &w.solverBuf};
      s.dispatch(*k.finalize, finalize, &c, groupsFor(n));
      s.mark(int(Stage::Finalize));
      // Only what the host mirror needs comes back (and what tests ask for).
      w.readbackBytes = 0;
      auto download = [&](const Buffer& src, void* out, VkDeviceSize bytes) {
        s.download(src, 0, out, bytes);
        w.readbackBytes += bytes;
      };
      const bool touches = in.readTouches && k.narrowPhase != nullptr;
      if (touches) {
        // The sleep pass's touch list: its length comes back now, the list after (readTouches).
        const std::shared_ptr<Device>& d = w.shared->device;
        reserve(d, w.touchFlagBuf, VkDeviceSize(w.pairCapacity) * 4);
        reserve(d, w.touchBuf, VkDeviceSize(w.pairCapacity + 1) * 8);
        const Buffer* flags[] = {&w.manifoldBuf[w.current], &w.shapeBuf, &w.counterBuf,
                                 &w.touchFlagBuf};
        s.dispatch(*k.touchFlags, flags, &c, groupsFor(w.pairCapacity));
        k.primitives.scan(s, w.touchFlagBuf, w.pairCapacity, w.touchScratch);
        const Buffer* write[] = {&w.manifoldBuf[w.current], &w.shapeBuf, &w.counterBuf,
                                 &w.touchFlagBuf, &w.touchBuf};
        s.dispatch(*k.touchWrite, write, &c, groupsFor(w.pairCapacity));
        download(w.touchBuf, w.touchHeader, sizeof w.touchHeader);
      }
      download(w.stateBuf, result.data(), n * sizeof(GpuBodyState));
      download(w.counterBuf, w.counters, sizeof w.counters);
      if (in.readBounds) {
        w.bounds.resize(m);
        download(w.boundsBuf, w.bounds.data(), m * sizeof(GpuAabb));
      }
      if (solve && !w.joints.empty())
        download(w.jointOutBuf, jointResults.data(), jointResults.size() * sizeof(GpuJointOut));
      if (in.readContacts) {
        w.pairs.resize(w.pairCapacity);
        w.manifolds.resize(w.pairCapacity);
        download(w.pairBuf, w.pairs.data(), w.pairs.size() * sizeof(GpuPair));
        download(w.manifoldBuf[w.current], w.manifolds.data(),
                 w.manifolds.size() * sizeof(GpuManifold));
      }
      s.mark(int(Stage::Readback));
      host.record = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() -
                                                              recordStart)
                        .count();
      if (!s.submit(error)) {
        // What went up is not to be trusted, nor the device for the next world.
        w.allBodiesDirty = w.shapesDirty = w.jointsDirty = w.ldlDirty = true;
        forgetShared(w.shared);
        return false;
      }
      stageMs = s.stageMs();
      counts = s.counts();
      host.copyOut = s.copyOutMs();
      w.touches.clear();
      if (touches && w.touchHeader[0] > 0) {
        // The list itself, now that its length is known: 8 bytes a touch, one more transfer
        // (its time counts as the readback's).
        const auto start = std::chrono::steady_clock::now();
        w.touches.resize(std::min(w.touchHeader[0], w.pairCapacity));
        s.begin();
        s.download(w.touchBuf, 8, w.touches.data(), w.touches.size() * sizeof(Touch));
        w.readbackBytes += w.touches.size() * sizeof(Touch);
        if (!s.submit(error)) {
          w.allBodiesDirty = w.shapesDirty = w.jointsDirty = w.ldlDirty = true;
          forgetShared(w.shared);
          return false;
        }
        const std::chrono::duration<double, std::milli> took =
            std::chrono::steady_clock::now() - start;
        if (size_t(Stage::Readback) < stageMs.size()) stageMs[size_t(Stage::Readback)] += took.count();
        counts.transfers += s.counts().transfers;
        counts.barriers += s.counts().barriers;
        counts.downloadBytes += s.counts().downloadBytes;
        host.copyOut += s.copyOutMs();
      }
    } catch (const std::exception& e) {
      if (error) *error = e.what();
      w.allBodiesDirty = w.shapesDirty = w.jointsDirty = w.ldlDirty = true;
      return false;
    }
    const uint64_t found =
        uint64_t(w.counters[PHYS_GPU_COUNTER_PAIRS]) + w.counters[PHYS_GPU_COUNTER_OVERFLOW];
    if (w.counters[PHYS_GPU_COUNTER_OVERFLOW] > 0 && attempt == 0 &&
        capped(found + found / 2) > w.pairCapacity) {
      // More pairs than the buffers hold: grow them (up to the bound) and take the step
      // again from the states before it (the host mirror), which all go up again. At the
      // bound the step stands, without the pairs past it.
      w.pairCapacity = capped(found + found / 2);
      w.allBodiesDirty = w.shapesDirty = w.jointsDirty = w.ldlDirty = true;
      continue;
    }
    if (in.readContacts) {
      w.pairs.resize(w.counters[PHYS_GPU_COUNTER_PAIRS]);
      w.manifolds.resize(w.counters[PHYS_GPU_COUNTER_PAIRS]);
    }
    // Colors to dispatch next step: this step's and a few more (those past it go to the
    // serial overflow, still solved).
    w.colorLimit = std::clamp(w.counters[PHYS_GPU_COUNTER_COLORS] + 4, 8u, PHYS_GPU_MAX_COLORS);
    // Room to grow without a retry next time (the buffers never shrink).
    if (found * 3 > uint64_t(w.pairCapacity) * 2) w.pairCapacity = capped(found * 2);
    w.states.swap(result);
    w.prevStates.swap(result);
    w.jointOutStepped = solve && !w.joints.empty();
    if (w.jointOutStepped) {
      w.jointOut.swap(jointResults);
      w.prevJointOut.swap(jointResults);
    }
    w.current ^= 1;
    w.undoable = true;
    w.keepPrevPairs = false;
    break;
  }
  w.stageMs.assign(kStageCount, 0.0);
  for (size_t i = 0; i < stageMs.size() && i < w.stageMs.size(); ++i) w.stageMs[i] = stageMs[i];
  w.counts = {counts.dispatches, counts.indirect, counts.barriers, counts.transfers};
  w.uploadBytes = counts.uploadBytes;
  w.hostMs = host;
  return true;
}

bool GpuWorld::undoStep() {
  Impl& w = *impl_;
  if (!w.undoable) return false;
  w.undoable = false;
  w.states.swap(w.prevStates);
  if (w.jointOutStepped) w.jointOut.swap(w.prevJointOut);
  // Last step's manifolds (the warm starts) are still in the other buffer, untouched.
  w.current ^= 1;
  w.keepPrevPairs = true;
  // The device holds the undone step's states and joint impulses: they all go up again.
  w.allBodiesDirty = true;
  w.dirtyBodies.clear();
  if (w.jointOutStepped) w.jointsDirty = true;
  return true;
}

std::span<const GpuBodyState> GpuWorld::states() const {
  return impl_->states;
}
std::span<const GpuAabb> GpuWorld::bounds() const {
  return impl_->bounds;
}
std::span<const GpuPair> GpuWorld::pairs() const {
  return impl_->pairs;
}
std::span<const GpuManifold> GpuWorld::manifolds() const {
  return impl_->manifolds;
}
std::span<const Touch> GpuWorld::touches() const {
  return impl_->touches;
}
uint64_t GpuWorld::readbackBytes() const {
  return impl_->readbackBytes;
}
uint64_t GpuWorld::uploadBytes() const {
  return impl_->uploadBytes;
}
HostTimes GpuWorld::hostMs() const {
  return impl_->hostMs;
}
uint32_t GpuWorld::sweepAxis() const {
  return impl_->sweepAxis;
}
uint32_t GpuWorld::pairCount() const {
  return impl_->counters[PHYS_GPU_COUNTER_PAIRS];
}
ContactStats GpuWorld::contactStats() const {
  const uint32_t* c = impl_->counters;
  float deepest;
  std::memcpy(&deepest, &c[PHYS_GPU_COUNTER_DEEPEST], 4);
  const uint64_t tests =
      uint64_t(c[PHYS_GPU_COUNTER_BP_TESTS]) | uint64_t(c[PHYS_GPU_COUNTER_BP_TESTS_HI]) << 32;
  return {c[PHYS_GPU_COUNTER_PAIRS],
          c[PHYS_GPU_COUNTER_CONTACTS],
          c[PHYS_GPU_COUNTER_POINTS],
          deepest,
          c[PHYS_GPU_COUNTER_OVERFLOW],
          tests};
}
void GpuWorld::setBroadPhase(BroadPhase method) {
  if (method == impl_->broadPhase) return;
  impl_->broadPhase = method;
  impl_->stepsSinceSweepAxis = ~uint64_t(0);  // the sweep chooses its axis at its first step
}
BroadPhase GpuWorld::broadPhase() const {
  return impl_->broadPhase;
}
double GpuWorld::candidateTestsPerShape() const {
  const size_t shapes = impl_->shapes.size() - impl_->planes.size();
  return shapes > 0 ? double(contactStats().candidateTests) / double(shapes) : 0.0;
}
bool GpuWorld::hasNarrowPhase() const {
  return impl_->kernels().narrowPhase != nullptr;
}
std::span<const double> GpuWorld::stageMs() const {
  return impl_->stageMs;
}
StepCounts GpuWorld::stepCounts() const {
  return impl_->counts;
}

}  // namespace phys::gpu
