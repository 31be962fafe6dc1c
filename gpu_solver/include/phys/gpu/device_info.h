// Which Vulkan device the GPU backend runs on, and how it is chosen.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

namespace phys::gpu {

/// How a device is chosen: a discrete GPU first, then an integrated one, then a virtual one;
/// a CPU implementation (Mesa's lavapipe) only when `allowCpu` is set, as CI and tests do.
/// The environment overrides: PHYS_GPU_DEVICE=<substring of the device name> picks a device
/// by name (CPU ones included), PHYS_GPU_ALLOW_CPU=1 allows a CPU device, and
/// PHYS_GPU_VALIDATION=1 loads the Khronos validation layer and counts its errors.
struct DeviceOptions {
  bool allowCpu = false;
  bool validation = false;
  std::string nameContains;  ///< empty: the best by type
};

struct DeviceInfo {
  std::string name;
  std::string type;  ///< "discrete", "integrated", "virtual", "cpu", "other"
  uint32_t apiVersion = 0;
  bool isCpu = false;
  double timestampPeriodNs = 0;  ///< 0: no timestamps on the compute queue
  uint32_t subgroupSize = 0;
  uint64_t maxStorageBufferRange = 0;
  bool validation = false;  ///< the validation layer is loaded
};

/// Options from the defaults and the environment (see DeviceOptions).
DeviceOptions deviceOptionsFromEnv(DeviceOptions base = {});

/// Validation errors reported in this process so far, by every device opened with validation,
/// including those raised while a device was being destroyed (leaked buffers, memory, pipelines
/// show up there). Read it after the last World on the device is gone to check teardown.
int validationErrorsInProcess();

/// Every Vulkan device present (name and type), for diagnostics; empty without a loader.
std::vector<DeviceInfo> listDevices(std::string* error = nullptr);

}  // namespace phys::gpu
