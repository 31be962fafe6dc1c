#include "gpu_primitives.h"

#include <stdexcept>

#include "phys/gpu/shared.h"
#include "shader_table.h"

namespace phys::gpu {
namespace {
std::span<const uint32_t> code(const char* name) {
  std::span<const uint32_t> c = shaderCode(name);
  if (c.empty()) throw std::runtime_error(std::string("shader not embedded: ") + name);
  return c;
}
uint32_t groups(uint32_t n, uint32_t size) {
  return (n + size - 1) / size;
}
}  // namespace

Primitives::Primitives(const std::shared_ptr<Device>& device) : device_(device) {
  const uint32_t push = sizeof(GpuSortConstants);
  bitonic_ = std::make_unique<Kernel>(device, "bitonic_sort", code("bitonic_sort"), 1, push);
  bitonicLocal_ = std::make_unique<Kernel>(device, "bitonic_local", code("bitonic_local"), 1, push);
  scanLocal_ = std::make_unique<Kernel>(device, "scan_local", code("scan_local"), 2, push);
  scanAdd_ = std::make_unique<Kernel>(device, "scan_add", code("scan_add"), 2, push);
}

uint32_t Primitives::pow2(uint32_t n) {
  uint32_t p = 1;
  while (p < n) p <<= 1;
  return p;
}

void Primitives::sort(Stream& s, const Buffer& keys, uint32_t n) const {
  if (n < 2) return;
  if (n != pow2(n)) throw std::invalid_argument("Primitives::sort: n must be a power of two");
  const Buffer* b[] = {&keys};
  auto global = [&](uint32_t k, uint32_t j) {
    GpuSortConstants c{n, j, k, 0};
    s.dispatch(*bitonic_, b, &c, groups(n, PHYS_GPU_GROUP));
  };
  constexpr uint32_t tile = PHYS_GPU_SORT_TILE;
  if (n < tile) {
    // One workgroup, the tail of its tile padded (bitonic_local.comp): the same sorted keys
    // as the log(n) * (log(n) + 1) / 2 global passes, in one dispatch (a small world's pair
    // and reference sorts were 21 and 28 dispatches each).
    GpuSortConstants c{n, 0, 0, 0};
    s.dispatch(*bitonicLocal_, b, &c, 1);
    return;
  }
  // The passes with j < tile in shared memory, one dispatch for all of them at a time: the
  // same network in log(n/tile) * (log(n/tile) + 3) / 2 + 1 dispatches instead of
  // log(n) * (log(n) + 1) / 2.
  auto local = [&](uint32_t k) {
    GpuSortConstants c{n, 0, k, 0};
    s.dispatch(*bitonicLocal_, b, &c, n / tile);
  };
  local(0);
  for (uint32_t k = 2 * tile; k <= n; k <<= 1) {
    for (uint32_t j = k >> 1; j >= tile; j >>= 1) global(k, j);
    local(k);
  }
}

void Primitives::scan(Stream& s, const Buffer& data, uint32_t n, ScanScratch& scratch) const {
  // Level 0 scans the data in groups; level l+1 scans the group totals of level l, until
  // one group holds them all; then each level adds the scanned totals back, top down.
  std::vector<uint32_t> counts;  // values scanned at each level
  for (uint32_t m = n; m > 0;) {
    counts.push_back(m);
    const uint32_t g = groups(m, PHYS_GPU_SCAN_GROUP);
    m = g > 1 ? g : 0;
  }
  if (scratch.levels.size() < counts.size()) scratch.levels.resize(counts.size());
  for (size_t l = 0; l < counts.size(); ++l) {
    const VkDeviceSize bytes = VkDeviceSize(groups(counts[l], PHYS_GPU_SCAN_GROUP)) * 4;
    if (!scratch.levels[l] || scratch.levels[l].size() < bytes)
      scratch.levels[l] = Buffer(device_, 2 * bytes, Buffer::Kind::Device);
  }
  auto input = [&](size_t l) -> const Buffer& { return l == 0 ? data : scratch.levels[l - 1]; };
  for (size_t l = 0; l < counts.size(); ++l) {
    GpuSortConstants c{counts[l], 0, 0, 0};
    const Buffer* b[] = {&input(l), &scratch.levels[l]};
    s.dispatch(*scanLocal_, b, &c, groups(counts[l], PHYS_GPU_SCAN_GROUP));
  }
  for (size_t l = counts.size() - 1; l-- > 0;) {
    GpuSortConstants c{counts[l], 0, 0, 0};
    const Buffer* b[] = {&input(l), &scratch.levels[l]};
    s.dispatch(*scanAdd_, b, &c, groups(counts[l], PHYS_GPU_SCAN_GROUP));
  }
}

}  // namespace phys::gpu
