#include "vk_device.h"

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <stdexcept>

namespace phys::gpu {
namespace {

std::string vkError(const char* what, VkResult r) {
  return std::string(what) + " failed (VkResult " + std::to_string(int(r)) + ")";
}

void check(VkResult r, const char* what) {
  if (r != VK_SUCCESS) throw std::runtime_error(vkError(what, r));
}

const char* typeName(VkPhysicalDeviceType t) {
  switch (t) {
    case VK_PHYSICAL_DEVICE_TYPE_DISCRETE_GPU:
      return "discrete";
    case VK_PHYSICAL_DEVICE_TYPE_INTEGRATED_GPU:
      return "integrated";
    case VK_PHYSICAL_DEVICE_TYPE_VIRTUAL_GPU:
      return "virtual";
    case VK_PHYSICAL_DEVICE_TYPE_CPU:
      return "cpu";
    default:
      return "other";
  }
}

/// Lower is better; CPU devices last.
int typeRank(VkPhysicalDeviceType t) {
  switch (t) {
    case VK_PHYSICAL_DEVICE_TYPE_DISCRETE_GPU:
      return 0;
    case VK_PHYSICAL_DEVICE_TYPE_INTEGRATED_GPU:
      return 1;
    case VK_PHYSICAL_DEVICE_TYPE_VIRTUAL_GPU:
      return 2;
    case VK_PHYSICAL_DEVICE_TYPE_CPU:
      return 4;
    default:
      return 3;
  }
}

bool envFlag(const char* name) {
  const char* v = std::getenv(name);
  return v && *v && std::strcmp(v, "0") != 0;
}

bool hasLayer(const char* name) {
  uint32_t n = 0;
  vkEnumerateInstanceLayerProperties(&n, nullptr);
  std::vector<VkLayerProperties> layers(n);
  vkEnumerateInstanceLayerProperties(&n, layers.data());
  for (const auto& l : layers)
    if (std::strcmp(l.layerName, name) == 0) return true;
  return false;
}

bool hasDeviceExtension(VkPhysicalDevice pd, const char* name) {
  uint32_t n = 0;
  vkEnumerateDeviceExtensionProperties(pd, nullptr, &n, nullptr);
  std::vector<VkExtensionProperties> ext(n);
  vkEnumerateDeviceExtensionProperties(pd, nullptr, &n, ext.data());
  for (const auto& e : ext)
    if (std::strcmp(e.extensionName, name) == 0) return true;
  return false;
}

/// The first queue family with compute, or -1.
int computeFamily(VkPhysicalDevice pd) {
  uint32_t n = 0;
  vkGetPhysicalDeviceQueueFamilyProperties(pd, &n, nullptr);
  std::vector<VkQueueFamilyProperties> families(n);
  vkGetPhysicalDeviceQueueFamilyProperties(pd, &n, families.data());
  for (uint32_t i = 0; i < n; ++i)
    if (families[i].queueFlags & VK_QUEUE_COMPUTE_BIT) return int(i);
  return -1;
}

DeviceInfo describe(VkPhysicalDevice pd) {
  VkPhysicalDeviceSubgroupProperties sub{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_SUBGROUP_PROPERTIES};
  VkPhysicalDeviceProperties2 props{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_PROPERTIES_2, &sub};
  vkGetPhysicalDeviceProperties2(pd, &props);
  const VkPhysicalDeviceProperties& p = props.properties;
  DeviceInfo info;
  info.name = p.deviceName;
  info.type = typeName(p.deviceType);
  info.apiVersion = p.apiVersion;
  info.isCpu = p.deviceType == VK_PHYSICAL_DEVICE_TYPE_CPU;
  info.timestampPeriodNs = p.limits.timestampComputeAndGraphics ? p.limits.timestampPeriod : 0;
  info.subgroupSize = sub.subgroupSize;
  info.maxStorageBufferRange = p.limits.maxStorageBufferRange;
  return info;
}

/// Validation errors reported in this process, every device's and its teardown's included.
std::atomic<int> gValidationErrors{0};

/// Prints a warning or error of the validation layer and counts an error in the process's
/// total; true for an error.
bool reportMessage(VkDebugUtilsMessageSeverityFlagBitsEXT severity,
                   const VkDebugUtilsMessengerCallbackDataEXT* data) {
  if (severity < VK_DEBUG_UTILS_MESSAGE_SEVERITY_WARNING_BIT_EXT) return false;
  std::fprintf(stderr, "[vulkan] %s\n", data->pMessage);
  if (severity < VK_DEBUG_UTILS_MESSAGE_SEVERITY_ERROR_BIT_EXT) return false;
  gValidationErrors++;
  return true;
}

VKAPI_ATTR VkBool32 VKAPI_CALL onInstanceMessage(VkDebugUtilsMessageSeverityFlagBitsEXT severity,
                                                 VkDebugUtilsMessageTypeFlagsEXT,
                                                 const VkDebugUtilsMessengerCallbackDataEXT* data,
                                                 void*) {
  reportMessage(severity, data);
  return VK_FALSE;
}

VkInstance createInstance(bool validation, std::string* error) {
  VkApplicationInfo app{VK_STRUCTURE_TYPE_APPLICATION_INFO};
  app.pApplicationName = "physd";
  app.pEngineName = "phys_gpu";
  app.apiVersion = VK_API_VERSION_1_2;
  std::vector<const char*> layers, extensions;
  if (validation) {
    layers.push_back("VK_LAYER_KHRONOS_validation");
    extensions.push_back(VK_EXT_DEBUG_UTILS_EXTENSION_NAME);
  }
  VkInstanceCreateInfo ci{VK_STRUCTURE_TYPE_INSTANCE_CREATE_INFO};
  ci.pApplicationInfo = &app;
  ci.enabledLayerCount = uint32_t(layers.size());
  ci.ppEnabledLayerNames = layers.data();
  ci.enabledExtensionCount = uint32_t(extensions.size());
  ci.ppEnabledExtensionNames = extensions.data();
  // With validation, a messenger for vkCreateInstance and vkDestroyInstance themselves (the
  // device's own messenger is gone by then): what teardown leaves behind is reported too.
  VkDebugUtilsMessengerCreateInfoEXT mi{VK_STRUCTURE_TYPE_DEBUG_UTILS_MESSENGER_CREATE_INFO_EXT};
  mi.messageSeverity = VK_DEBUG_UTILS_MESSAGE_SEVERITY_WARNING_BIT_EXT |
                       VK_DEBUG_UTILS_MESSAGE_SEVERITY_ERROR_BIT_EXT;
  mi.messageType =
      VK_DEBUG_UTILS_MESSAGE_TYPE_GENERAL_BIT_EXT | VK_DEBUG_UTILS_MESSAGE_TYPE_VALIDATION_BIT_EXT;
  mi.pfnUserCallback = &onInstanceMessage;
  if (validation) ci.pNext = &mi;
  VkInstance instance = VK_NULL_HANDLE;
  VkResult r = vkCreateInstance(&ci, nullptr, &instance);
  if (r != VK_SUCCESS) {
    if (error) *error = vkError("vkCreateInstance (is a Vulkan driver installed?)", r);
    return VK_NULL_HANDLE;
  }
  return instance;
}

std::vector<VkPhysicalDevice> physicalDevices(VkInstance instance) {
  uint32_t n = 0;
  vkEnumeratePhysicalDevices(instance, &n, nullptr);
  std::vector<VkPhysicalDevice> out(n);
  vkEnumeratePhysicalDevices(instance, &n, out.data());
  return out;
}

}  // namespace

DeviceOptions deviceOptionsFromEnv(DeviceOptions base) {
  if (envFlag("PHYS_GPU_ALLOW_CPU")) base.allowCpu = true;
  if (envFlag("PHYS_GPU_VALIDATION")) base.validation = true;
  if (const char* name = std::getenv("PHYS_GPU_DEVICE"); name && *name) base.nameContains = name;
  return base;
}

int validationErrorsInProcess() {
  return gValidationErrors.load();
}

std::vector<DeviceInfo> listDevices(std::string* error) {
  VkInstance instance = createInstance(false, error);
  if (!instance) return {};
  std::vector<DeviceInfo> out;
  for (VkPhysicalDevice pd : physicalDevices(instance)) out.push_back(describe(pd));
  vkDestroyInstance(instance, nullptr);
  return out;
}

// ---------------------------------------------------------------------------------------------
// Device

VKAPI_ATTR VkBool32 VKAPI_CALL Device::onMessage(VkDebugUtilsMessageSeverityFlagBitsEXT severity,
                                                 VkDebugUtilsMessageTypeFlagsEXT,
                                                 const VkDebugUtilsMessengerCallbackDataEXT* data,
                                                 void* user) {
  if (reportMessage(severity, data)) static_cast<Device*>(user)->validationErrors_++;
  return VK_FALSE;
}

std::shared_ptr<Device> Device::open(const DeviceOptions& options, std::string* error) {
  std::string ignored;
  if (!error) error = &ignored;
  const bool validation = options.validation && hasLayer("VK_LAYER_KHRONOS_validation");
  if (options.validation && !validation)
    std::fprintf(stderr,
                 "phys_gpu: validation asked for, but VK_LAYER_KHRONOS_validation is "
                 "not installed (package vulkan-validationlayers)\n");
  std::shared_ptr<Device> d(new Device());
  d->instance_ = createInstance(validation, error);
  if (!d->instance_) return nullptr;
  if (validation) {
    auto create = reinterpret_cast<PFN_vkCreateDebugUtilsMessengerEXT>(
        vkGetInstanceProcAddr(d->instance_, "vkCreateDebugUtilsMessengerEXT"));
    VkDebugUtilsMessengerCreateInfoEXT mi{VK_STRUCTURE_TYPE_DEBUG_UTILS_MESSENGER_CREATE_INFO_EXT};
    mi.messageSeverity = VK_DEBUG_UTILS_MESSAGE_SEVERITY_WARNING_BIT_EXT |
                         VK_DEBUG_UTILS_MESSAGE_SEVERITY_ERROR_BIT_EXT;
    mi.messageType = VK_DEBUG_UTILS_MESSAGE_TYPE_GENERAL_BIT_EXT |
                     VK_DEBUG_UTILS_MESSAGE_TYPE_VALIDATION_BIT_EXT |
                     VK_DEBUG_UTILS_MESSAGE_TYPE_PERFORMANCE_BIT_EXT;
    mi.pfnUserCallback = &Device::onMessage;
    mi.pUserData = d.get();
    if (create) create(d->instance_, &mi, nullptr, &d->messenger_);
  }

  // Choose: by name when asked, else the best type; CPU devices only when allowed.
  VkPhysicalDevice best = VK_NULL_HANDLE;
  int bestRank = 1 << 30;
  std::string seen;
  for (VkPhysicalDevice pd : physicalDevices(d->instance_)) {
    VkPhysicalDeviceProperties p;
    vkGetPhysicalDeviceProperties(pd, &p);
    seen +=
        std::string(seen.empty() ? "" : ", ") + p.deviceName + " (" + typeName(p.deviceType) + ")";
    VkPhysicalDeviceFeatures features;
    vkGetPhysicalDeviceFeatures(pd, &features);
    if (p.apiVersion < VK_API_VERSION_1_2 || computeFamily(pd) < 0 || !features.shaderFloat64 ||
        !hasDeviceExtension(pd, VK_KHR_PUSH_DESCRIPTOR_EXTENSION_NAME))
      continue;
    const bool named = !options.nameContains.empty();
    if (named && std::string(p.deviceName).find(options.nameContains) == std::string::npos)
      continue;
    if (!named && p.deviceType == VK_PHYSICAL_DEVICE_TYPE_CPU && !options.allowCpu) continue;
    int rank = typeRank(p.deviceType);
    if (rank < bestRank) {
      bestRank = rank;
      best = pd;
    }
  }
  if (!best) {
    *error = "no usable Vulkan device (Vulkan 1.2, compute, shaderFloat64, VK_KHR_push_descriptor";
    if (!options.allowCpu)
      *error += "; CPU devices such as lavapipe only with PHYS_GPU_ALLOW_CPU=1";
    if (!options.nameContains.empty())
      *error += "; name containing \"" + options.nameContains + "\"";
    *error += "); present: " + (seen.empty() ? std::string("none") : seen);
    return nullptr;
  }
  d->physical_ = best;
  d->info_ = describe(best);
  d->info_.validation = validation;
  {
    VkPhysicalDeviceProperties p;
    vkGetPhysicalDeviceProperties(best, &p);
    d->maxGroupsX = p.limits.maxComputeWorkGroupCount[0];
  }
  d->queueFamily_ = uint32_t(computeFamily(best));
  vkGetPhysicalDeviceMemoryProperties(best, &d->memory_);

  const float priority = 1;
  VkDeviceQueueCreateInfo qi{VK_STRUCTURE_TYPE_DEVICE_QUEUE_CREATE_INFO};
  qi.queueFamilyIndex = d->queueFamily_;
  qi.queueCount = 1;
  qi.pQueuePriorities = &priority;
  const char* extensions[] = {VK_KHR_PUSH_DESCRIPTOR_EXTENSION_NAME};
  // Doubles: quaternion normalization and speed caps, as on the CPU (common.glsl).
  VkPhysicalDeviceFeatures enabled{};
  enabled.shaderFloat64 = VK_TRUE;
  VkDeviceCreateInfo ci{VK_STRUCTURE_TYPE_DEVICE_CREATE_INFO};
  ci.pEnabledFeatures = &enabled;
  ci.queueCreateInfoCount = 1;
  ci.pQueueCreateInfos = &qi;
  ci.enabledExtensionCount = 1;
  ci.ppEnabledExtensionNames = extensions;
  VkResult r = vkCreateDevice(best, &ci, nullptr, &d->device_);
  if (r != VK_SUCCESS) {
    *error = vkError("vkCreateDevice", r);
    return nullptr;
  }
  vkGetDeviceQueue(d->device_, d->queueFamily_, 0, &d->queue_);
  d->pushDescriptorSet = reinterpret_cast<PFN_vkCmdPushDescriptorSetKHR>(
      vkGetDeviceProcAddr(d->device_, "vkCmdPushDescriptorSetKHR"));
  if (!d->pushDescriptorSet) {
    *error = "vkCmdPushDescriptorSetKHR missing";
    return nullptr;
  }
  // Timestamps need valid bits on the compute queue.
  uint32_t n = 0;
  vkGetPhysicalDeviceQueueFamilyProperties(best, &n, nullptr);
  std::vector<VkQueueFamilyProperties> families(n);
  vkGetPhysicalDeviceQueueFamilyProperties(best, &n, families.data());
  if (families[d->queueFamily_].timestampValidBits == 0) d->info_.timestampPeriodNs = 0;
  return d;
}

Device::~Device() {
  if (device_) {
    vkDeviceWaitIdle(device_);
    vkDestroyDevice(device_, nullptr);
  }
  if (messenger_) {
    auto destroy = reinterpret_cast<PFN_vkDestroyDebugUtilsMessengerEXT>(
        vkGetInstanceProcAddr(instance_, "vkDestroyDebugUtilsMessengerEXT"));
    if (destroy) destroy(instance_, messenger_, nullptr);
  }
  if (instance_) vkDestroyInstance(instance_, nullptr);
}

uint32_t Device::memoryType(uint32_t typeBits, VkMemoryPropertyFlags required,
                            VkMemoryPropertyFlags preferred) const {
  int fallback = -1;
  for (uint32_t i = 0; i < memory_.memoryTypeCount; ++i) {
    if (!(typeBits & (1u << i))) continue;
    VkMemoryPropertyFlags f = memory_.memoryTypes[i].propertyFlags;
    if ((f & required) != required) continue;
    if ((f & preferred) == preferred) return i;
    if (fallback < 0) fallback = int(i);
  }
  if (fallback < 0) throw std::runtime_error("no Vulkan memory type for a buffer");
  return uint32_t(fallback);
}

// ---------------------------------------------------------------------------------------------
// Buffer

Buffer::Buffer(std::shared_ptr<Device> device, VkDeviceSize bytes, Kind kind)
    : device_(std::move(device)), size_(std::max<VkDeviceSize>(bytes, 16)) {
  // Shaders bind whole buffers: one larger than a storage binding may span cannot be bound
  // (a world too large for this device; the step fails with this message and the World
  // takes it on the CPU).
  const uint64_t range = device_->info().maxStorageBufferRange;
  if (kind == Kind::Device && range > 0 && size_ > range)
    throw std::runtime_error("a device buffer of " + std::to_string(size_) +
                             " bytes exceeds this device's maxStorageBufferRange (" +
                             std::to_string(range) + " bytes)");
  VkBufferCreateInfo bi{VK_STRUCTURE_TYPE_BUFFER_CREATE_INFO};
  bi.size = size_;
  bi.usage = VK_BUFFER_USAGE_STORAGE_BUFFER_BIT | VK_BUFFER_USAGE_TRANSFER_SRC_BIT |
             VK_BUFFER_USAGE_TRANSFER_DST_BIT | VK_BUFFER_USAGE_INDIRECT_BUFFER_BIT;
  bi.sharingMode = VK_SHARING_MODE_EXCLUSIVE;
  check(vkCreateBuffer(device_->handle(), &bi, nullptr, &buffer_), "vkCreateBuffer");
  VkMemoryRequirements req;
  vkGetBufferMemoryRequirements(device_->handle(), buffer_, &req);
  VkMemoryAllocateInfo ai{VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_INFO};
  ai.allocationSize = req.size;
  if (kind == Kind::Device) {
    ai.memoryTypeIndex =
        device_->memoryType(req.memoryTypeBits, VK_MEMORY_PROPERTY_DEVICE_LOCAL_BIT, 0);
  } else {
    const VkMemoryPropertyFlags host =
        VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT | VK_MEMORY_PROPERTY_HOST_COHERENT_BIT;
    ai.memoryTypeIndex = device_->memoryType(
        req.memoryTypeBits, host, kind == Kind::Readback ? VK_MEMORY_PROPERTY_HOST_CACHED_BIT : 0);
  }
  VkResult r = vkAllocateMemory(device_->handle(), &ai, nullptr, &memory_);
  if (r != VK_SUCCESS) {
    vkDestroyBuffer(device_->handle(), buffer_, nullptr);
    buffer_ = VK_NULL_HANDLE;
    throw std::runtime_error(vkError("vkAllocateMemory", r) + " for " + std::to_string(bytes) +
                             " bytes");
  }
  check(vkBindBufferMemory(device_->handle(), buffer_, memory_, 0), "vkBindBufferMemory");
  if (kind != Kind::Device)
    check(vkMapMemory(device_->handle(), memory_, 0, VK_WHOLE_SIZE, 0, &mapped_), "vkMapMemory");
}

Buffer::~Buffer() {
  if (!device_) return;
  if (buffer_) vkDestroyBuffer(device_->handle(), buffer_, nullptr);
  if (memory_) vkFreeMemory(device_->handle(), memory_, nullptr);
}

void Buffer::swap(Buffer& o) noexcept {
  std::swap(device_, o.device_);
  std::swap(buffer_, o.buffer_);
  std::swap(memory_, o.memory_);
  std::swap(size_, o.size_);
  std::swap(mapped_, o.mapped_);
}

// ---------------------------------------------------------------------------------------------
// Kernel

Kernel::Kernel(std::shared_ptr<Device> device, const char* name, std::span<const uint32_t> spirv,
               uint32_t bindings, uint32_t pushBytes)
    : device_(std::move(device)), name_(name), bindings_(bindings), pushBytes_(pushBytes) {
  VkDevice dev = device_->handle();
  std::vector<VkDescriptorSetLayoutBinding> b(bindings);
  for (uint32_t i = 0; i < bindings; ++i) {
    b[i].binding = i;
    b[i].descriptorType = VK_DESCRIPTOR_TYPE_STORAGE_BUFFER;
    b[i].descriptorCount = 1;
    b[i].stageFlags = VK_SHADER_STAGE_COMPUTE_BIT;
  }
  VkDescriptorSetLayoutCreateInfo si{VK_STRUCTURE_TYPE_DESCRIPTOR_SET_LAYOUT_CREATE_INFO};
  si.flags = VK_DESCRIPTOR_SET_LAYOUT_CREATE_PUSH_DESCRIPTOR_BIT_KHR;
  si.bindingCount = bindings;
  si.pBindings = b.data();
  check(vkCreateDescriptorSetLayout(dev, &si, nullptr, &setLayout_), "vkCreateDescriptorSetLayout");
  VkPushConstantRange range{VK_SHADER_STAGE_COMPUTE_BIT, 0, pushBytes};
  VkPipelineLayoutCreateInfo li{VK_STRUCTURE_TYPE_PIPELINE_LAYOUT_CREATE_INFO};
  li.setLayoutCount = 1;
  li.pSetLayouts = &setLayout_;
  li.pushConstantRangeCount = pushBytes ? 1 : 0;
  li.pPushConstantRanges = &range;
  check(vkCreatePipelineLayout(dev, &li, nullptr, &layout_), "vkCreatePipelineLayout");
  VkShaderModuleCreateInfo mi{VK_STRUCTURE_TYPE_SHADER_MODULE_CREATE_INFO};
  mi.codeSize = spirv.size_bytes();
  mi.pCode = spirv.data();
  VkShaderModule module;
  check(vkCreateShaderModule(dev, &mi, nullptr, &module), "vkCreateShaderModule");
  VkComputePipelineCreateInfo pi{VK_STRUCTURE_TYPE_COMPUTE_PIPELINE_CREATE_INFO};
  pi.stage.sType = VK_STRUCTURE_TYPE_PIPELINE_SHADER_STAGE_CREATE_INFO;
  pi.stage.stage = VK_SHADER_STAGE_COMPUTE_BIT;
  pi.stage.module = module;
  pi.stage.pName = "main";
  pi.layout = layout_;
  VkResult r = vkCreateComputePipelines(dev, VK_NULL_HANDLE, 1, &pi, nullptr, &pipeline_);
  vkDestroyShaderModule(dev, module, nullptr);
  if (r != VK_SUCCESS)
    throw std::runtime_error(vkError("vkCreateComputePipelines", r) + " for " + name);
}

Kernel::~Kernel() {
  VkDevice dev = device_->handle();
  if (pipeline_) vkDestroyPipeline(dev, pipeline_, nullptr);
  if (layout_) vkDestroyPipelineLayout(dev, layout_, nullptr);
  if (setLayout_) vkDestroyDescriptorSetLayout(dev, setLayout_, nullptr);
}

// ---------------------------------------------------------------------------------------------
// Stream

Stream::Stream(std::shared_ptr<Device> device) : device_(std::move(device)) {
  VkDevice dev = device_->handle();
  VkCommandPoolCreateInfo pi{VK_STRUCTURE_TYPE_COMMAND_POOL_CREATE_INFO};
  pi.flags = VK_COMMAND_POOL_CREATE_RESET_COMMAND_BUFFER_BIT;
  pi.queueFamilyIndex = device_->queueFamily();
  check(vkCreateCommandPool(dev, &pi, nullptr, &pool_), "vkCreateCommandPool");
  VkCommandBufferAllocateInfo ai{VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO};
  ai.commandPool = pool_;
  ai.level = VK_COMMAND_BUFFER_LEVEL_PRIMARY;
  ai.commandBufferCount = 1;
  check(vkAllocateCommandBuffers(dev, &ai, &cmd_), "vkAllocateCommandBuffers");
  VkFenceCreateInfo fi{VK_STRUCTURE_TYPE_FENCE_CREATE_INFO};
  check(vkCreateFence(dev, &fi, nullptr, &fence_), "vkCreateFence");
  if (device_->info().timestampPeriodNs > 0) {
    VkQueryPoolCreateInfo qi{VK_STRUCTURE_TYPE_QUERY_POOL_CREATE_INFO};
    qi.queryType = VK_QUERY_TYPE_TIMESTAMP;
    qi.queryCount = kMaxTimestamps;
    check(vkCreateQueryPool(dev, &qi, nullptr, &queries_), "vkCreateQueryPool");
  }
}

Stream::~Stream() {
  VkDevice dev = device_->handle();
  vkDeviceWaitIdle(dev);
  staging_.clear();
  if (queries_) vkDestroyQueryPool(dev, queries_, nullptr);
  if (fence_) vkDestroyFence(dev, fence_, nullptr);
  if (pool_) vkDestroyCommandPool(dev, pool_, nullptr);
}

void Stream::begin() {
  check(vkResetCommandBuffer(cmd_, 0), "vkResetCommandBuffer");
  VkCommandBufferBeginInfo bi{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO};
  bi.flags = VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT;
  check(vkBeginCommandBuffer(cmd_, &bi), "vkBeginCommandBuffer");
  // Keep only the largest staging buffer: the older ones were retired by the last submit.
  if (staging_.size() > 1) staging_.erase(staging_.begin(), staging_.end() - 1);
  stagingUsed_ = 0;
  downloads_.clear();
  markStages_.clear();
  counts_ = {};
  if (queries_) {
    vkCmdResetQueryPool(cmd_, queries_, 0, kMaxTimestamps);
    vkCmdWriteTimestamp(cmd_, VK_PIPELINE_STAGE_TOP_OF_PIPE_BIT, queries_, 0);
  }
}

VkDeviceSize Stream::stage(VkDeviceSize bytes) {
  const VkDeviceSize offset = (stagingUsed_ + 15) & ~VkDeviceSize(15);
  if (staging_.empty() || offset + bytes > staging_.back().size()) {
    // A bigger staging buffer; the old one stays alive until the submit has run.
    VkDeviceSize size = std::max<VkDeviceSize>(64 << 10, 2 * (offset + bytes));
    if (!staging_.empty()) size = std::max(size, 2 * staging_.back().size());
    staging_.emplace_back(device_, size, Buffer::Kind::Readback);
    stagingUsed_ = bytes;
    return 0;
  }
  stagingUsed_ = offset + bytes;
  return offset;
}

void Stream::upload(const Buffer& dst, VkDeviceSize offset, const void* data, VkDeviceSize bytes) {
  if (bytes == 0) return;
  const VkDeviceSize at = stage(bytes);
  std::memcpy(static_cast<char*>(staging_.back().mapped()) + at, data, size_t(bytes));
  VkBufferCopy copy{at, offset, bytes};
  vkCmdCopyBuffer(cmd_, staging_.back().handle(), dst.handle(), 1, &copy);
  counts_.transfers++;
  counts_.uploadBytes += bytes;
  barrier();
}

void Stream::download(const Buffer& src, VkDeviceSize offset, void* out, VkDeviceSize bytes) {
  if (bytes == 0) return;
  const VkDeviceSize at = stage(bytes);
  VkBufferCopy copy{offset, at, bytes};
  vkCmdCopyBuffer(cmd_, src.handle(), staging_.back().handle(), 1, &copy);
  // A later growth keeps this staging buffer alive until the submit.
  downloads_.push_back({staging_.size() - 1, at, bytes, out});
  counts_.transfers++;
  counts_.downloadBytes += bytes;
  barrier();
}

void Stream::fill(const Buffer& dst, uint32_t value) {
  vkCmdFillBuffer(cmd_, dst.handle(), 0, VK_WHOLE_SIZE, value);
  counts_.transfers++;
  barrier();
}

void Stream::copy(const Buffer& src, VkDeviceSize srcOffset, const Buffer& dst,
                  VkDeviceSize dstOffset, VkDeviceSize bytes) {
  if (bytes == 0) return;
  VkBufferCopy c{srcOffset, dstOffset, bytes};
  vkCmdCopyBuffer(cmd_, src.handle(), dst.handle(), 1, &c);
  counts_.transfers++;
  barrier();
}

void Stream::bind(const Kernel& k, std::span<const Buffer* const> buffers, const void* push) {
  vkCmdBindPipeline(cmd_, VK_PIPELINE_BIND_POINT_COMPUTE, k.pipeline());
  std::vector<VkDescriptorBufferInfo> infos(buffers.size());
  std::vector<VkWriteDescriptorSet> writes(buffers.size());
  for (size_t i = 0; i < buffers.size(); ++i) {
    infos[i] = {buffers[i]->handle(), 0, VK_WHOLE_SIZE};
    writes[i] = {VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET};
    writes[i].dstBinding = uint32_t(i);
    writes[i].descriptorCount = 1;
    writes[i].descriptorType = VK_DESCRIPTOR_TYPE_STORAGE_BUFFER;
    writes[i].pBufferInfo = &infos[i];
  }
  device_->pushDescriptorSet(cmd_, VK_PIPELINE_BIND_POINT_COMPUTE, k.layout(), 0,
                             uint32_t(writes.size()), writes.data());
  if (k.pushBytes()) {
    vkCmdPushConstants(cmd_, k.layout(), VK_SHADER_STAGE_COMPUTE_BIT, 0, k.pushBytes(), push);
  }
}

void Stream::dispatch(const Kernel& k, std::span<const Buffer* const> buffers, const void* push,
                      uint32_t groups) {
  if (groups == 0) return;
  bind(k, buffers, push);
  const uint32_t x = std::min(groups, device_->maxGroupsX);
  vkCmdDispatch(cmd_, x, (groups + x - 1) / x, 1);
  counts_.dispatches++;
  barrier();
}

void Stream::dispatchIndirect(const Kernel& k, std::span<const Buffer* const> buffers,
                              const void* push, const Buffer& args, VkDeviceSize offset) {
  bind(k, buffers, push);
  vkCmdDispatchIndirect(cmd_, args.handle(), offset);
  counts_.dispatches++;
  counts_.indirect++;
  barrier();
}

void Stream::barrier() {
  VkMemoryBarrier mb{VK_STRUCTURE_TYPE_MEMORY_BARRIER};
  mb.srcAccessMask = VK_ACCESS_SHADER_WRITE_BIT | VK_ACCESS_TRANSFER_WRITE_BIT;
  mb.dstAccessMask = VK_ACCESS_SHADER_READ_BIT | VK_ACCESS_SHADER_WRITE_BIT |
                     VK_ACCESS_TRANSFER_READ_BIT | VK_ACCESS_TRANSFER_WRITE_BIT |
                     VK_ACCESS_INDIRECT_COMMAND_READ_BIT;
  const VkPipelineStageFlags stages = VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT |
                                      VK_PIPELINE_STAGE_TRANSFER_BIT |
                                      VK_PIPELINE_STAGE_DRAW_INDIRECT_BIT;
  vkCmdPipelineBarrier(cmd_, stages, stages, 0, 1, &mb, 0, nullptr, 0, nullptr);
  counts_.barriers++;
}

void Stream::mark(int stage) {
  if (!queries_ || markStages_.size() + 1 >= kMaxTimestamps) return;
  markStages_.push_back(stage);
  vkCmdWriteTimestamp(cmd_, VK_PIPELINE_STAGE_BOTTOM_OF_PIPE_BIT, queries_,
                      uint32_t(markStages_.size()));
}

bool Stream::submit(std::string* error) {
  VkResult r = vkEndCommandBuffer(cmd_);
  if (r == VK_SUCCESS) {
    VkSubmitInfo si{VK_STRUCTURE_TYPE_SUBMIT_INFO};
    si.commandBufferCount = 1;
    si.pCommandBuffers = &cmd_;
    std::lock_guard<std::mutex> lock(device_->submitMutex);
    r = vkQueueSubmit(device_->queue(), 1, &si, fence_);
  }
  if (r == VK_SUCCESS) r = vkWaitForFences(device_->handle(), 1, &fence_, VK_TRUE, UINT64_MAX);
  if (r == VK_SUCCESS) r = vkResetFences(device_->handle(), 1, &fence_);
  if (r != VK_SUCCESS) {
    if (error) *error = vkError("GPU step submit", r);
    return false;
  }
  const auto copyStart = std::chrono::steady_clock::now();
  for (const Download& d : downloads_) {
    const char* from = static_cast<const char*>(staging_[d.staging].mapped());
    std::memcpy(d.out, from + d.offset, size_t(d.bytes));
  }
  copyOutMs_ = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() -
                                                         copyStart)
                   .count();
  stageMs_.assign(stageMs_.size(), 0.0);
  if (queries_ && !markStages_.empty()) {
    std::vector<uint64_t> t(markStages_.size() + 1);
    r = vkGetQueryPoolResults(device_->handle(), queries_, 0, uint32_t(t.size()),
                              t.size() * sizeof(uint64_t), t.data(), sizeof(uint64_t),
                              VK_QUERY_RESULT_64_BIT | VK_QUERY_RESULT_WAIT_BIT);
    if (r == VK_SUCCESS) {
      const double msPerTick = device_->info().timestampPeriodNs * 1e-6;
      for (size_t i = 0; i < markStages_.size(); ++i) {
        const size_t s = size_t(markStages_[i]);
        if (stageMs_.size() <= s) stageMs_.resize(s + 1, 0.0);
        stageMs_[s] += double(t[i + 1] - t[i]) * msPerTick;
      }
    }
  }
  return true;
}

}  // namespace phys::gpu
