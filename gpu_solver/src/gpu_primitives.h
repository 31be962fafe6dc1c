// Building blocks the step's stages share: a deterministic sort of (key, value) pairs and an
// exclusive prefix sum, both recorded into a Stream.
#pragma once

#include <memory>
#include <vector>

#include "vk_device.h"

namespace phys::gpu {

class Primitives {
 public:
  explicit Primitives(const std::shared_ptr<Device>& device);

  /// Records an ascending sort of the first `n` uvec2 (key, value) of `keys`, by key then
  /// value. `n` must be a power of two; pad the tail with (~0u, ~0u).
  void sort(Stream& s, const Buffer& keys, uint32_t n) const;

  /// Scratch of the prefix sum: one buffer of group totals per level, kept by the caller
  /// until the stream has run.
  struct ScanScratch {
    std::vector<Buffer> levels;
  };
  /// Records an exclusive prefix sum of the first `n` uints of `data`, in place.
  void scan(Stream& s, const Buffer& data, uint32_t n, ScanScratch& scratch) const;

  /// The smallest power of two >= n (1 for 0).
  static uint32_t pow2(uint32_t n);

 private:
  std::shared_ptr<Device> device_;
  std::unique_ptr<Kernel> bitonic_, bitonicLocal_, scanLocal_, scanAdd_;
};

}  // namespace phys::gpu
