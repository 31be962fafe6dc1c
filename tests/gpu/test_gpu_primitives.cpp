// The device's sort and prefix sum against std::sort and std::exclusive_scan.
#include <gtest/gtest.h>

#include <algorithm>
#include <numeric>
#include <random>
#include <stdexcept>
#include <string>

#include "gpu_primitives.h"

namespace phys::gpu {
namespace {

std::shared_ptr<Device> openDevice() {
  DeviceOptions o;
  o.allowCpu = true;
  std::string error;
  return Device::open(o, &error);
}

TEST(GpuPrimitives, SortMatchesStdSortWithTies) {
  auto device = openDevice();
  if (!device) GTEST_SKIP() << "no Vulkan device";
  Primitives prim(device);
  Stream stream(device);
  std::mt19937 rng(7);
  for (uint32_t count : {1u, 2u, 5u, 64u, 300u, 512u, 513u, 1000u, 4096u, 70000u, 300000u}) {
    SCOPED_TRACE("count " + std::to_string(count));
    const uint32_t n = Primitives::pow2(count);
    std::vector<std::pair<uint32_t, uint32_t>> keys(n, {~0u, ~0u});
    // Few distinct keys, so ties are decided by the value.
    for (uint32_t i = 0; i < count; ++i) keys[i] = {rng() % 97, rng()};
    Buffer buf(device, n * 8, Buffer::Kind::Device);
    std::vector<std::pair<uint32_t, uint32_t>> out(n);
    std::string error;
    stream.begin();
    stream.upload(buf, 0, keys.data(), n * 8);
    prim.sort(stream, buf, n);
    stream.download(buf, 0, out.data(), n * 8);
    ASSERT_TRUE(stream.submit(&error)) << error;
    std::sort(keys.begin(), keys.end());
    EXPECT_EQ(out, keys);
  }
}

TEST(GpuBuffers, LargerThanAStorageBindingIsRefusedWithTheLimit) {
  // Shaders bind whole buffers; one past maxStorageBufferRange is refused before anything is
  // allocated, with a message naming the limit (a world too large for the device).
  auto device = openDevice();
  if (!device) GTEST_SKIP() << "no Vulkan device";
  const uint64_t range = device->info().maxStorageBufferRange;
  ASSERT_GT(range, 0u);
  try {
    Buffer b(device, range + 16, Buffer::Kind::Device);
    FAIL() << "a buffer of " << range + 16 << " bytes was created";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("maxStorageBufferRange"), std::string::npos) << e.what();
  }
  Buffer fits(device, 1 << 20, Buffer::Kind::Device);  // an ordinary size still works
  EXPECT_EQ(fits.size(), VkDeviceSize(1 << 20));
}

TEST(GpuPrimitives, ExclusiveScanMatchesStd) {
  auto device = openDevice();
  if (!device) GTEST_SKIP() << "no Vulkan device";
  Primitives prim(device);
  Stream stream(device);
  Primitives::ScanScratch scratch;
  std::mt19937 rng(3);
  // One level, exactly one group, a partial second group, two and three levels.
  for (uint32_t n : {1u, 255u, 256u, 257u, 70000u, 300000u}) {
    SCOPED_TRACE("n " + std::to_string(n));
    std::vector<uint32_t> in(n);
    for (uint32_t& x : in) x = rng() % 9;
    Buffer buf(device, n * 4, Buffer::Kind::Device);
    std::vector<uint32_t> out(n);
    std::string error;
    stream.begin();
    stream.upload(buf, 0, in.data(), n * 4);
    prim.scan(stream, buf, n, scratch);
    stream.download(buf, 0, out.data(), n * 4);
    ASSERT_TRUE(stream.submit(&error)) << error;
    std::vector<uint32_t> expected(n);
    std::exclusive_scan(in.begin(), in.end(), expected.begin(), 0u);
    EXPECT_EQ(out, expected);
  }
}

}  // namespace
}  // namespace phys::gpu
