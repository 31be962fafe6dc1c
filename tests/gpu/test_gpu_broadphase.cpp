// The device's broad phase against a brute-force pass over the same bounds: the same pairs,
// sorted, with the CPU's filters (no pair within a body, none without a dynamic body), on
// whichever axis the sweep takes, and a pair list that grows its buffers when a step finds
// more pairs than they hold.
#include <gtest/gtest.h>

#include <algorithm>
#include <random>
#include <vector>

#include "phys/gpu/gpu_world.h"

namespace phys::gpu {
namespace {

struct Arrangement {
  std::vector<GpuBodyState> states;
  std::vector<GpuBodyParams> params;
  std::vector<GpuShape> shapes;
};

GpuShape shape(int body, uint32_t type, vec4 size, vec4 p = {}) {
  GpuShape s;
  s.body = body;
  s.type = type;
  s.size = size;
  s.localP = p;
  s.localP.w = 1.5f;  // bounding radius (only the rotation pad uses it)
  s.localQ = {0, 0, 0, 1};
  return s;
}

/// `bodies` bodies in a `side` m cube (stretched by `stretch` along each axis), a third of
/// them with two shapes, a few kinematic, a few static boxes, and two static planes.
Arrangement randomSetup(uint32_t seed, int bodies, float side, vec4 stretch = {1, 1, 1, 0}) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> pos(0, side), unit(-1, 1);
  Arrangement s;
  for (int i = 0; i < bodies; ++i) {
    GpuBodyState st;
    st.com = {pos(rng) * stretch.x, pos(rng) * stretch.y, pos(rng) * stretch.z, 0};
    st.q = {unit(rng), unit(rng), unit(rng), 1.5f};
    const float l =
        std::sqrt(st.q.x * st.q.x + st.q.y * st.q.y + st.q.z * st.q.z + st.q.w * st.q.w);
    st.q = {st.q.x / l, st.q.y / l, st.q.z / l, st.q.w / l};
    st.v = {unit(rng), unit(rng), unit(rng), 0};
    GpuBodyParams p;
    p.flags.x = i % 7 == 3 ? 0u : PHYS_GPU_BODY_DYNAMIC;  // every 7th kinematic
    s.states.push_back(st);
    s.params.push_back(p);
    const uint32_t type = uint32_t(i % 3);  // sphere, box, capsule
    s.shapes.push_back(shape(i, type, {0.3f + 0.2f * float(i % 5), 0.4f, 0.5f, 0}));
    if (i % 3 == 1)
      s.shapes.push_back(shape(i, PHYS_GPU_SHAPE_SPHERE, {0.4f, 0, 0, 0}, {0.5f, 0, 0, 0}));
  }
  for (int i = 0; i < 5; ++i)
    s.shapes.push_back(
        shape(-1, PHYS_GPU_SHAPE_BOX, {1, 1, 0.2f, 0}, {pos(rng), pos(rng), pos(rng), 0}));
  s.shapes.push_back(shape(-1, PHYS_GPU_SHAPE_PLANE, {0, 0, 1, 0.5f}));
  s.shapes.push_back(shape(-1, PHYS_GPU_SHAPE_PLANE, {0.6f, 0, 0.8f, 1.0f}));
  return s;
}

/// The CPU's rules over the device's bounds.
std::vector<std::pair<uint32_t, uint32_t>> bruteForce(const Arrangement& s,
                                                      std::span<const GpuAabb> bounds) {
  auto dynamicShape = [&](uint32_t i) {
    const int b = s.shapes[i].body;
    return b >= 0 && (s.params[size_t(b)].flags.x & PHYS_GPU_BODY_DYNAMIC);
  };
  auto can = [&](uint32_t a, uint32_t b) {
    if (s.shapes[a].body >= 0 && s.shapes[a].body == s.shapes[b].body) return false;
    return dynamicShape(a) || dynamicShape(b);
  };
  std::vector<std::pair<uint32_t, uint32_t>> out;
  const uint32_t n = uint32_t(s.shapes.size());
  for (uint32_t a = 0; a < n; ++a) {
    for (uint32_t b = a + 1; b < n; ++b) {
      const bool pa = s.shapes[a].type == PHYS_GPU_SHAPE_PLANE;
      const bool pb = s.shapes[b].type == PHYS_GPU_SHAPE_PLANE;
      if (pa && pb) continue;
      if (!can(a, b)) continue;
      if (pa || pb) {
        const uint32_t plane = pa ? a : b, other = pa ? b : a;
        const vec4 pl = s.shapes[plane].size;
        const GpuAabb& box = bounds[other];
        // The box's lowest corner along the normal.
        const float x = pl.x > 0 ? box.lo.x : box.hi.x, y = pl.y > 0 ? box.lo.y : box.hi.y,
                    z = pl.z > 0 ? box.lo.z : box.hi.z;
        if (pl.x * x + pl.y * y + pl.z * z <= pl.w + 0.5f * StepInput().speculativeDistance)
          out.push_back({a, b});
        continue;
      }
      const GpuAabb &A = bounds[a], &B = bounds[b];
      if (A.lo.x <= B.hi.x && B.lo.x <= A.hi.x && A.lo.y <= B.hi.y && B.lo.y <= A.hi.y &&
          A.lo.z <= B.hi.z && B.lo.z <= A.hi.z)
        out.push_back({a, b});
    }
  }
  return out;
}

std::unique_ptr<GpuWorld> openWorld() {
  DeviceOptions o;
  o.allowCpu = true;
  std::string error;
  return GpuWorld::create(o, &error);
}

TEST(GpuBroadPhase, SamePairsAsBruteForceOverTheSameBounds) {
  auto world = openWorld();
  if (!world) GTEST_SKIP() << "no Vulkan device";
  // Sparse to dense (the dense one overflows the first pair buffer and is retried); then
  // columns along y and z, which the sweep takes along their length.
  struct Case {
    uint32_t seed;
    int bodies;
    float side;
    vec4 stretch;
    uint32_t axis;
  };
  for (const Case& c :
       {Case{1u, 80, 10.0f, {1, 1, 1, 0}, 99}, Case{2u, 300, 12.0f, {1, 1, 1, 0}, 99},
        Case{3u, 400, 6.0f, {1, 1, 1, 0}, 99}, Case{4u, 300, 3.0f, {1, 8, 1, 0}, 1},
        Case{5u, 300, 3.0f, {0.5f, 1, 10, 0}, 2}}) {
    SCOPED_TRACE("seed " + std::to_string(c.seed));
    Arrangement s = randomSetup(c.seed, c.bodies, c.side, c.stretch);
    world->setBodies(s.states, s.params);
    world->setShapes(s.shapes);
    StepInput in;
    in.readBounds = true;
    in.readContacts = true;
    std::string error;
    ASSERT_TRUE(world->step(in, &error)) << error;
    auto expected = bruteForce(s, world->bounds());
    std::vector<std::pair<uint32_t, uint32_t>> got;
    for (const GpuPair& p : world->pairs()) got.push_back({p.a, p.b});
    EXPECT_TRUE(std::is_sorted(got.begin(), got.end()));
    EXPECT_EQ(got.size(), expected.size());
    EXPECT_EQ(got, expected);
    EXPECT_EQ(world->pairCount(), uint32_t(expected.size()));
    EXPECT_GT(expected.size(), 10u);
    if (c.axis < 3) {
      EXPECT_EQ(world->sweepAxis(), c.axis);
    }
  }
}

TEST(GpuBroadPhase, PairsStopAtTheBound) {
  // StepInput::maxPairs (the world's pair bound): the pair buffers grow to the power of two at
  // or above it and no further (so every pair the CPU keeps has room); the pairs past them
  // are left out and counted.
  auto world = openWorld();
  if (!world) GTEST_SKIP() << "no Vulkan device";
  Arrangement s = randomSetup(3u, 400, 6.0f);
  world->setBodies(s.states, s.params);
  world->setShapes(s.shapes);
  StepInput in;
  in.readBounds = true;
  in.readContacts = true;
  in.maxPairs = 100;  // 128 slots
  std::string error;
  for (int step = 0; step < 2; ++step) {
    ASSERT_TRUE(world->step(in, &error)) << error;
    auto expected = bruteForce(s, world->bounds());
    ASSERT_GT(expected.size(), 200u);
    std::vector<std::pair<uint32_t, uint32_t>> got;
    for (const GpuPair& p : world->pairs()) got.push_back({p.a, p.b});
    EXPECT_EQ(world->pairCount(), 128u);
    EXPECT_EQ(got.size(), 128u);
    EXPECT_TRUE(std::is_sorted(got.begin(), got.end()));
    EXPECT_TRUE(std::includes(expected.begin(), expected.end(), got.begin(), got.end()));
    EXPECT_EQ(world->contactStats().dropped, uint32_t(expected.size()) - 128u);
  }
  // Unbounded: the buffers grow and every pair is there.
  in.maxPairs = UINT32_MAX;
  ASSERT_TRUE(world->step(in, &error)) << error;
  auto expected = bruteForce(s, world->bounds());
  EXPECT_EQ(world->pairCount(), uint32_t(expected.size()));
  EXPECT_EQ(world->contactStats().dropped, 0u);
}

TEST(GpuBroadPhase, NothingToPair) {
  auto world = openWorld();
  if (!world) GTEST_SKIP() << "no Vulkan device";
  Arrangement s = randomSetup(4, 1, 5);  // one body, static boxes and planes: maybe a plane pair
  s.shapes.erase(s.shapes.begin(), s.shapes.begin() + 1);  // drop the body's shape
  world->setBodies(s.states, s.params);
  world->setShapes(s.shapes);
  StepInput in;
  in.readContacts = true;
  std::string error;
  ASSERT_TRUE(world->step(in, &error)) << error;
  EXPECT_EQ(world->pairCount(), 0u);  // static against static is never a pair
  EXPECT_TRUE(world->pairs().empty());
}

}  // namespace
}  // namespace phys::gpu
