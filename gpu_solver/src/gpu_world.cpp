#include "phys/gpu/gpu_world.h"

#include <algorithm>
#include <map>
#include <mutex>
#include <stdexcept>
#include <tuple>

#include "shader_table.h"
#include "vk_device.h"

namespace phys::gpu {

const char* stageName(Stage s) {
  switch (s) {
    case Stage::SyncToDevice:
      return "sync_to_device";
    case Stage::UpdateBounds:
      return "update_bounds";
    case Stage::Prepare:
      return "prepare";
    case Stage::IntegrateVelocities:
      return "integrate_velocities";
    case Stage::IntegratePositions:
      return "integrate_positions";
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

/// The step's kernels, built once per device.
struct Kernels {
  Kernel prepareBodies, integrateVelocities, integratePositions, finalize, updateBounds;
  explicit Kernels(const std::shared_ptr<Device>& d)
      : prepareBodies(d, "prepare_bodies", code("prepare_bodies"), 3, sizeof(GpuStepConstants)),
        integrateVelocities(d, "integrate_velocities", code("integrate_velocities"), 2,
                            sizeof(GpuStepConstants)),
        integratePositions(d, "integrate_positions", code("integrate_positions"), 2,
                           sizeof(GpuStepConstants)),
        finalize(d, "finalize", code("finalize"), 2, sizeof(GpuStepConstants)),
        updateBounds(d, "update_bounds", code("update_bounds"), 4, sizeof(GpuStepConstants)) {}
  static std::span<const uint32_t> code(const char* name) {
    std::span<const uint32_t> c = shaderCode(name);
    if (c.empty()) throw std::runtime_error(std::string("shader not embedded: ") + name);
    return c;
  }
};

/// A device and its kernels, shared by every world opened with the same options.
struct SharedDevice {
  std::shared_ptr<Device> device;
  std::unique_ptr<Kernels> kernels;
  ~SharedDevice() { kernels.reset(); }  // the kernels before the device
};

std::shared_ptr<SharedDevice> openShared(const DeviceOptions& o, std::string* error) {
  static std::mutex mutex;
  static std::map<std::tuple<bool, bool, std::string>, std::weak_ptr<SharedDevice>> cache;
  std::lock_guard<std::mutex> lock(mutex);
  auto key = std::make_tuple(o.allowCpu, o.validation, o.nameContains);
  if (auto s = cache[key].lock()) return s;
  auto s = std::make_shared<SharedDevice>();
  s->device = Device::open(o, error);
  if (!s->device) return nullptr;
  s->kernels = std::make_unique<Kernels>(s->device);
  cache[key] = s;
  return s;
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
  std::vector<GpuAabb> bounds;
  std::vector<uint32_t> dirtyBodies;
  bool allBodiesDirty = false, shapesDirty = false;
  // Device buffers.
  Buffer stateBuf, paramBuf, solverBuf, shapeBuf, boundsBuf;
  std::vector<double> stageMs = std::vector<double>(kStageCount, 0.0);

  Device& device() { return *shared->device; }
  void sync(Stream& s);
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
  impl_->states.assign(states.begin(), states.end());
  impl_->params.assign(params.begin(), params.end());
  impl_->allBodiesDirty = true;
  impl_->dirtyBodies.clear();
}

void GpuWorld::setBody(uint32_t index, const GpuBodyState& state, const GpuBodyParams& params) {
  if (index >= impl_->states.size()) throw std::out_of_range("setBody: no such body");
  impl_->states[index] = state;
  impl_->params[index] = params;
  if (!impl_->allBodiesDirty) impl_->dirtyBodies.push_back(index);
}

void GpuWorld::setShapes(std::span<const GpuShape> shapes) {
  impl_->shapes.assign(shapes.begin(), shapes.end());
  impl_->shapesDirty = true;
}

uint32_t GpuWorld::bodyCount() const {
  return uint32_t(impl_->states.size());
}
uint32_t GpuWorld::shapeCount() const {
  return uint32_t(impl_->shapes.size());
}

void GpuWorld::Impl::sync(Stream& s) {
  const std::shared_ptr<Device>& d = shared->device;
  const size_t n = states.size();
  // Growing a buffer loses its contents: everything in it goes up again.
  bool grown = reserve(d, stateBuf, n * sizeof(GpuBodyState));
  grown |= reserve(d, paramBuf, n * sizeof(GpuBodyParams));
  reserve(d, solverBuf, n * sizeof(GpuSolverBody));
  if (grown) allBodiesDirty = true;
  if (reserve(d, shapeBuf, shapes.size() * sizeof(GpuShape))) shapesDirty = true;
  reserve(d, boundsBuf, shapes.size() * sizeof(GpuAabb));

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
  if (shapesDirty) s.upload(shapeBuf, 0, shapes.data(), shapes.size() * sizeof(GpuShape));
  dirtyBodies.clear();
  allBodiesDirty = shapesDirty = false;
}

bool GpuWorld::step(const StepInput& in, std::string* error) {
  Impl& w = *impl_;
  Stream& s = *w.stream;
  Kernels& k = *w.shared->kernels;
  const uint32_t n = uint32_t(w.states.size()), m = uint32_t(w.shapes.size());
  const int substeps = std::max(in.substeps, 1);
  GpuStepConstants c{};
  c.h = in.dt / float(substeps);
  c.dt = in.dt;
  c.maxLinearSpeed = in.maxLinearSpeed;
  c.maxAngularSpeed = in.maxAngularSpeed;
  c.speculativeDistance = in.speculativeDistance;
  c.bodyCount = n;
  c.shapeCount = m;
  try {
    s.begin();
    w.sync(s);
    s.mark(int(Stage::SyncToDevice));
    const Buffer* bounds[] = {&w.stateBuf, &w.paramBuf, &w.shapeBuf, &w.boundsBuf};
    s.dispatch(k.updateBounds, bounds, &c, groupsFor(m));
    s.mark(int(Stage::UpdateBounds));
    const Buffer* prepare[] = {&w.stateBuf, &w.paramBuf, &w.solverBuf};
    s.dispatch(k.prepareBodies, prepare, &c, groupsFor(n));
    s.mark(int(Stage::Prepare));
    const Buffer* integrate[] = {&w.paramBuf, &w.solverBuf};
    for (int sub = 0; sub < substeps; ++sub) {
      s.dispatch(k.integrateVelocities, integrate, &c, groupsFor(n));
      s.mark(int(Stage::IntegrateVelocities));
      s.dispatch(k.integratePositions, integrate, &c, groupsFor(n));
      s.mark(int(Stage::IntegratePositions));
    }
    const Buffer* finalize[] = {&w.stateBuf, &w.solverBuf};
    s.dispatch(k.finalize, finalize, &c, groupsFor(n));
    s.mark(int(Stage::Finalize));
    // Only what the host mirror needs comes back.
    std::vector<GpuBodyState> result(n);
    s.download(w.stateBuf, 0, result.data(), n * sizeof(GpuBodyState));
    if (in.readBounds) {
      w.bounds.resize(m);
      s.download(w.boundsBuf, 0, w.bounds.data(), m * sizeof(GpuAabb));
    }
    s.mark(int(Stage::Readback));
    if (!s.submit(error)) {
      w.allBodiesDirty = w.shapesDirty = true;  // what went up is not to be trusted
      return false;
    }
    w.states.swap(result);
  } catch (const std::exception& e) {
    if (error) *error = e.what();
    w.allBodiesDirty = w.shapesDirty = true;
    return false;
  }
  w.stageMs.assign(kStageCount, 0.0);
  const std::vector<double>& ms = s.stageMs();
  for (size_t i = 0; i < ms.size() && i < w.stageMs.size(); ++i) w.stageMs[i] = ms[i];
  return true;
}

std::span<const GpuBodyState> GpuWorld::states() const {
  return impl_->states;
}
std::span<const GpuAabb> GpuWorld::bounds() const {
  return impl_->bounds;
}
std::span<const double> GpuWorld::stageMs() const {
  return impl_->stageMs;
}

}  // namespace phys::gpu
