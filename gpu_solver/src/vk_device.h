// The Vulkan device layer: a headless compute device, buffers, compute kernels and one
// command stream per step. Everything Vulkan in phys_gpu goes through these few RAII types;
// the step (gpu_world.cpp) records stages with them and never sees a Vk handle it must free.
#pragma once

#include <vulkan/vulkan.h>

#include <atomic>
#include <cstdint>
#include <memory>
#include <mutex>
#include <span>
#include <string>
#include <vector>

#include "phys/gpu/device_info.h"

namespace phys::gpu {

/// The device and its one compute queue. Shared (shared_ptr) by everything made on it, so
/// buffers and kernels outlive nothing they need.
class Device {
 public:
  /// Opens the best device the options allow (device_info.h); null with *error set when
  /// there is none.
  static std::shared_ptr<Device> open(const DeviceOptions& options, std::string* error);
  ~Device();
  Device(const Device&) = delete;
  Device& operator=(const Device&) = delete;

  const DeviceInfo& info() const { return info_; }
  VkDevice handle() const { return device_; }
  VkQueue queue() const { return queue_; }
  uint32_t queueFamily() const { return queueFamily_; }
  /// A memory type with all of `required` among `typeBits`, preferring `preferred` too.
  uint32_t memoryType(uint32_t typeBits, VkMemoryPropertyFlags required,
                      VkMemoryPropertyFlags preferred) const;
  PFN_vkCmdPushDescriptorSetKHR pushDescriptorSet = nullptr;
  uint32_t maxGroupsX = 65535;  ///< workgroups in one dispatch dimension
  /// Validation errors reported so far (runs with the validation layer).
  int validationErrors() const { return validationErrors_; }
  /// Held around vkQueueSubmit: worlds on other threads share the one queue.
  std::mutex submitMutex;

 private:
  Device() = default;
  static VKAPI_ATTR VkBool32 VKAPI_CALL onMessage(VkDebugUtilsMessageSeverityFlagBitsEXT,
                                                  VkDebugUtilsMessageTypeFlagsEXT,
                                                  const VkDebugUtilsMessengerCallbackDataEXT*,
                                                  void*);
  VkInstance instance_ = VK_NULL_HANDLE;
  VkDebugUtilsMessengerEXT messenger_ = VK_NULL_HANDLE;
  VkPhysicalDevice physical_ = VK_NULL_HANDLE;
  VkDevice device_ = VK_NULL_HANDLE;
  VkQueue queue_ = VK_NULL_HANDLE;
  uint32_t queueFamily_ = 0;
  VkPhysicalDeviceMemoryProperties memory_{};
  DeviceInfo info_;
  std::atomic<int> validationErrors_{0};
};

/// A storage buffer with its own memory (the step holds a few dozen large arrays, so one
/// allocation per buffer is the whole allocator). Device-local buffers are filled and read
/// through a Stream's staging; host-visible ones are mapped for their lifetime.
class Buffer {
 public:
  enum class Kind { Device, Upload, Readback };
  Buffer() = default;
  Buffer(std::shared_ptr<Device> device, VkDeviceSize bytes, Kind kind);
  ~Buffer();
  Buffer(Buffer&& o) noexcept { swap(o); }
  Buffer& operator=(Buffer&& o) noexcept {
    swap(o);
    return *this;
  }
  VkBuffer handle() const { return buffer_; }
  VkDeviceSize size() const { return size_; }
  void* mapped() const { return mapped_; }
  explicit operator bool() const { return buffer_ != VK_NULL_HANDLE; }

 private:
  void swap(Buffer& o) noexcept;
  std::shared_ptr<Device> device_;
  VkBuffer buffer_ = VK_NULL_HANDLE;
  VkDeviceMemory memory_ = VK_NULL_HANDLE;
  VkDeviceSize size_ = 0;
  void* mapped_ = nullptr;
};

/// One compute shader: its pipeline, with `bindings` storage buffers (bindings 0..n-1 of set
/// 0, pushed per dispatch) and `pushBytes` of push constants.
class Kernel {
 public:
  Kernel(std::shared_ptr<Device> device, const char* name, std::span<const uint32_t> spirv,
         uint32_t bindings, uint32_t pushBytes);
  ~Kernel();
  Kernel(const Kernel&) = delete;
  Kernel& operator=(const Kernel&) = delete;
  const char* name() const { return name_; }
  uint32_t bindings() const { return bindings_; }
  uint32_t pushBytes() const { return pushBytes_; }
  VkPipeline pipeline() const { return pipeline_; }
  VkPipelineLayout layout() const { return layout_; }

 private:
  std::shared_ptr<Device> device_;
  const char* name_;
  uint32_t bindings_, pushBytes_;
  VkDescriptorSetLayout setLayout_ = VK_NULL_HANDLE;
  VkPipelineLayout layout_ = VK_NULL_HANDLE;
  VkPipeline pipeline_ = VK_NULL_HANDLE;
};

/// One command buffer, recorded and submitted once per step: uploads, dispatches with a
/// barrier after each, stage timestamps and readbacks, then one submit and one wait.
class Stream {
 public:
  static constexpr uint32_t kMaxTimestamps = 128;
  explicit Stream(std::shared_ptr<Device> device);
  ~Stream();
  Stream(const Stream&) = delete;
  Stream& operator=(const Stream&) = delete;

  void begin();
  /// Copies host bytes into `dst` at `offset` through the stream's staging buffer.
  void upload(const Buffer& dst, VkDeviceSize offset, const void* data, VkDeviceSize bytes);
  /// Copies `bytes` of `src` into host memory once the stream has finished (after submit()).
  void download(const Buffer& src, VkDeviceSize offset, void* out, VkDeviceSize bytes);
  void fill(const Buffer& dst, uint32_t value);
  /// Copies between device buffers (the regions must not overlap).
  void copy(const Buffer& src, VkDeviceSize srcOffset, const Buffer& dst, VkDeviceSize dstOffset,
            VkDeviceSize bytes);
  /// Records a dispatch of `groups` workgroups (spread over y beyond the device's x limit:
  /// kernels use common.glsl's globalIndex()), then a compute barrier.
  void dispatch(const Kernel& k, std::span<const Buffer* const> buffers, const void* push,
                uint32_t groups);
  /// Records a dispatch whose workgroup count the device wrote: 3 uints at `offset` of
  /// `args` (a 1D count), then a compute barrier.
  void dispatchIndirect(const Kernel& k, std::span<const Buffer* const> buffers, const void* push,
                        const Buffer& args, VkDeviceSize offset);
  /// Marks the end of a stage: the time since the previous mark is the stage's.
  void mark(int stage);
  /// Submits, waits, copies the downloads out. Returns false (and sets *error) on a device
  /// error; the stream can be begun again.
  bool submit(std::string* error);
  /// ms of each stage marked in the last submitted stream (index = stage), summed.
  const std::vector<double>& stageMs() const { return stageMs_; }
  /// What the stream recorded since begin(): what a step costs the device beyond its
  /// arithmetic (each dispatch and barrier is a launch and a drain of the whole device).
  struct Counts {
    uint32_t dispatches = 0;  ///< every dispatch, the indirect ones included
    uint32_t indirect = 0;    ///< of them, sized on the device (possibly zero workgroups)
    uint32_t barriers = 0;    ///< pipeline barriers (one after each dispatch and copy)
    uint32_t transfers = 0;   ///< uploads, downloads, fills and copies
    uint64_t uploadBytes = 0;    ///< host bytes staged by upload()
    uint64_t downloadBytes = 0;  ///< bytes download() brings back
  };
  const Counts& counts() const { return counts_; }
  /// Host ms the last submit spent copying the downloads out of the staging memory (what
  /// the readback costs the host, beside the device's copy).
  double copyOutMs() const { return copyOutMs_; }

 private:
  struct Download {
    size_t staging;  ///< index into staging_
    VkDeviceSize offset, bytes;
    void* out;
  };
  VkDeviceSize stage(VkDeviceSize bytes);  ///< room in the staging buffer, grown as needed
  void bind(const Kernel& k, std::span<const Buffer* const> buffers, const void* push);
  void barrier();
  std::shared_ptr<Device> device_;
  VkCommandPool pool_ = VK_NULL_HANDLE;
  VkCommandBuffer cmd_ = VK_NULL_HANDLE;
  VkFence fence_ = VK_NULL_HANDLE;
  VkQueryPool queries_ = VK_NULL_HANDLE;
  // Host-visible staging, both ways; the uploads of a step go first, then the downloads.
  std::vector<Buffer> staging_;  ///< retired when grown, freed after the submit
  VkDeviceSize stagingUsed_ = 0;
  std::vector<Download> downloads_;
  std::vector<int> markStages_;
  std::vector<double> stageMs_;
  Counts counts_;
  double copyOutMs_ = 0;
};

}  // namespace phys::gpu
