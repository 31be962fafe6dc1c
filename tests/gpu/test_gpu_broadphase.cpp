// The device's broad phase against a brute-force pass over the same bounds: the same pairs,
// sorted, with the CPU's filters (no pair within a body, none without a dynamic body), with
// either method (the tree, and the sweep on whichever axis it takes), and a pair list that
// grows its buffers when a step finds more pairs than they hold. Then the tree's work: its
// candidate tests per shape stay bounded on a pile spread over a floor as the pile grows
// (where the sweep's grow with its side), and the same pairs and states run to run and
// method to method.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <iostream>
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

const char* methodName(BroadPhase m) {
  return m == BroadPhase::Tree ? "tree" : "sweep";
}

std::vector<std::pair<uint32_t, uint32_t>> pairsOf(const GpuWorld& world) {
  std::vector<std::pair<uint32_t, uint32_t>> got;
  for (const GpuPair& p : world.pairs()) got.push_back({p.a, p.b});
  return got;
}

TEST(GpuBroadPhase, SamePairsAsBruteForceOverTheSameBounds) {
  auto world = openWorld();
  if (!world) GTEST_SKIP() << "no Vulkan device";
  // Sparse to dense (the dense one overflows the first pair buffer and is retried); then
  // columns along y and z, which the sweep takes along their length, long thin stacks along
  // each axis, and a pile spread thin over a floor.
  struct Case {
    uint32_t seed;
    int bodies;
    float side;
    vec4 stretch;
    uint32_t axis;
  };
  for (BroadPhase method : {BroadPhase::Tree, BroadPhase::Sweep}) {
    world->setBroadPhase(method);
    for (const Case& c :
         {Case{1u, 80, 10.0f, {1, 1, 1, 0}, 99}, Case{2u, 300, 12.0f, {1, 1, 1, 0}, 99},
          Case{3u, 400, 6.0f, {1, 1, 1, 0}, 99}, Case{4u, 300, 3.0f, {1, 8, 1, 0}, 1},
          Case{5u, 300, 3.0f, {0.5f, 1, 10, 0}, 2}, Case{6u, 300, 2.0f, {60, 0.3f, 0.3f, 0}, 0},
          Case{7u, 300, 2.0f, {0.3f, 60, 0.3f, 0}, 1}, Case{8u, 300, 2.0f, {0.3f, 0.3f, 60, 0}, 2},
          Case{9u, 600, 30.0f, {1, 1, 0.02f, 0}, 99}}) {
      SCOPED_TRACE(std::string(methodName(method)) + ", seed " + std::to_string(c.seed));
      Arrangement s = randomSetup(c.seed, c.bodies, c.side, c.stretch);
      world->setBodies(s.states, s.params);
      world->setShapes(s.shapes);
      StepInput in;
      in.readBounds = true;
      in.readContacts = true;
      std::string error;
      ASSERT_TRUE(world->step(in, &error)) << error;
      auto expected = bruteForce(s, world->bounds());
      auto got = pairsOf(*world);
      EXPECT_TRUE(std::is_sorted(got.begin(), got.end()));
      EXPECT_EQ(got.size(), expected.size());
      EXPECT_EQ(got, expected);
      EXPECT_EQ(world->pairCount(), uint32_t(expected.size()));
      EXPECT_GT(expected.size(), 10u);
      EXPECT_GT(world->contactStats().candidateTests, 0u);
      if (method == BroadPhase::Sweep && c.axis < 3) {
        EXPECT_EQ(world->sweepAxis(), c.axis);
      }
    }
  }
}

TEST(GpuBroadPhase, PairsStopAtTheBound) {
  // StepInput::maxPairs (the world's pair bound): the pair buffers grow to the power of two at
  // or above it and no further (so every pair the CPU keeps has room); the pairs past them
  // are left out and counted.
  auto world = openWorld();
  if (!world) GTEST_SKIP() << "no Vulkan device";
  for (BroadPhase method : {BroadPhase::Tree, BroadPhase::Sweep}) {
    SCOPED_TRACE(methodName(method));
    world->setBroadPhase(method);
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
      auto got = pairsOf(*world);
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
}

TEST(GpuBroadPhase, NothingToPair) {
  auto world = openWorld();
  if (!world) GTEST_SKIP() << "no Vulkan device";
  for (BroadPhase method : {BroadPhase::Tree, BroadPhase::Sweep}) {
    SCOPED_TRACE(methodName(method));
    world->setBroadPhase(method);
    // One body, static boxes and planes: maybe a plane pair.
    Arrangement s = randomSetup(4, 1, 5);
    s.shapes.erase(s.shapes.begin(), s.shapes.begin() + 1);  // drop the body's shape
    world->setBodies(s.states, s.params);
    world->setShapes(s.shapes);
    StepInput in;
    in.readContacts = true;
    std::string error;
    ASSERT_TRUE(world->step(in, &error)) << error;
    EXPECT_EQ(world->pairCount(), 0u);  // static against static is never a pair
    EXPECT_TRUE(world->pairs().empty());
    // Nothing but planes, and nothing at all.
    s.shapes.erase(s.shapes.begin(), s.shapes.end() - 2);
    world->setShapes(s.shapes);
    ASSERT_TRUE(world->step(in, &error)) << error;
    EXPECT_EQ(world->pairCount(), 0u);
    world->setShapes({});
    ASSERT_TRUE(world->step(in, &error)) << error;
    EXPECT_EQ(world->pairCount(), 0u);
  }
}

/// A pile poured from a lattice and come to rest spread over a floor: `count` boxes (half
/// sides 0.2 m, jittered and turned a little) in `layers` layers 0.41 m apart, each
/// touching its neighbours, on a ground plane; every 5th asleep (not dynamic).
Arrangement spreadPile(int count, int layers, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> jitter(-0.01f, 0.01f), turn(-0.05f, 0.05f);
  const int side = int(std::ceil(std::sqrt(double(count) / layers)));
  Arrangement s;
  for (int i = 0; i < count; ++i) {
    const int layer = i / (side * side), cell = i % (side * side);
    GpuBodyState st;
    st.com = {0.41f * float(cell % side) + jitter(rng), 0.41f * float(cell / side) + jitter(rng),
              0.2f + 0.41f * float(layer), 0};
    const float qz = turn(rng);
    st.q = {0, 0, qz, std::sqrt(1 - qz * qz)};
    GpuBodyParams p;
    p.flags.x = i % 5 == 4 ? PHYS_GPU_BODY_ASLEEP : PHYS_GPU_BODY_DYNAMIC;
    s.states.push_back(st);
    s.params.push_back(p);
    s.shapes.push_back(shape(i, PHYS_GPU_SHAPE_BOX, {0.2f, 0.2f, 0.2f, 0}));
  }
  s.shapes.push_back(shape(-1, PHYS_GPU_SHAPE_PLANE, {0, 0, 1, 0}));
  return s;
}

/// The pairs and candidate tests per shape of one step of `s` with `method`.
struct BroadPhaseRun {
  std::vector<std::pair<uint32_t, uint32_t>> pairs;
  std::vector<GpuAabb> bounds;
  double testsPerShape = 0;
};
BroadPhaseRun runBroadPhase(BroadPhase method, const Arrangement& s) {
  // A world of its own: its pair buffers sized for this pile alone (lavapipe's storage
  // buffers end at 128 MiB, and a world's buffers never shrink).
  auto opened = openWorld();
  if (!opened) {
    ADD_FAILURE() << "no device";
    return {};
  }
  GpuWorld& world = *opened;
  world.setBroadPhase(method);
  world.setBodies(s.states, s.params);
  world.setShapes(s.shapes);
  StepInput in;
  in.readBounds = true;
  in.readContacts = true;
  in.solveContacts = false;  // the collision stages only
  std::string error;
  BroadPhaseRun r;
  if (!world.step(in, &error)) {
    ADD_FAILURE() << error;
    return r;
  }
  r.pairs = pairsOf(world);
  r.bounds.assign(world.bounds().begin(), world.bounds().end());
  r.testsPerShape = world.candidateTestsPerShape();
  return r;
}

TEST(GpuBroadPhase, CandidateTestsStayBoundedOnASpreadPile) {
  // The proxy for a broad phase whose cost does not depend on how bodies lie: on a
  // pile spread over a floor, the work per shape must not grow with the pile. Each shape
  // meets about the same neighbours whatever the pile's size; the tree's query tests a few
  // nodes per level on top (log N). The sweep along x meets every box of the pile's slab
  // as wide as a box, a number that grows with the pile's side (sqrt N): it fails this.
  auto world = openWorld();
  if (!world) GTEST_SKIP() << "no Vulkan device";
  for (int layers : {1, 2}) {
    double tree[3] = {}, sweep[3] = {};
    // 16 times the boxes from first to last (16000 boxes in two layers would need pair
    // buffers past lavapipe's 128 MiB).
    const int counts[3] = {1000 / layers, 4000 / layers, 16000 / layers};
    for (int i = 0; i < 3; ++i) {
      SCOPED_TRACE(std::to_string(counts[i]) + " boxes, " + std::to_string(layers) + " layers");
      const Arrangement s = spreadPile(counts[i], layers, 7u);
      const BroadPhaseRun t = runBroadPhase(BroadPhase::Tree, s);
      const BroadPhaseRun w = runBroadPhase(BroadPhase::Sweep, s);
      tree[i] = t.testsPerShape;
      sweep[i] = w.testsPerShape;
      // The same pairs either way (and, while it is affordable, the brute force's).
      EXPECT_EQ(t.pairs, w.pairs);
      if (i < 2) {
        EXPECT_EQ(t.pairs, bruteForce(s, t.bounds));
      }
      EXPECT_GT(t.pairs.size(), size_t(counts[i]));  // neighbours touch
      std::cout << "[ bp tests ] " << layers << " layer(s), " << counts[i]
                << " boxes: candidate tests per shape, tree " << tree[i] << ", sweep "
                << sweep[i] << "\n";
    }
    // 16 times the boxes: the tree's tests per shape grow by well under twice (measured
    // on lavapipe: see docs/BENCHMARKS.md), the sweep's by about the pile's side, 4 times.
    EXPECT_LE(tree[2], 1.5 * tree[0]) << layers << " layer(s)";
    EXPECT_GT(sweep[2], 2.0 * sweep[0]) << layers << " layer(s): the proxy no longer tells";
    EXPECT_LT(tree[2], sweep[2]);
  }
}

TEST(GpuBroadPhase, SamePairsAndStatesRunToRunAndMethodToMethod) {
  // Determinism: the tree is built from a total order (codes, then indices) and fitted with
  // minima and maxima, so a run repeats its pairs and its work exactly; and since the pair
  // list is sorted, the step after it is the same bits with either method.
  auto world = openWorld();
  if (!world) GTEST_SKIP() << "no Vulkan device";
  if (!world->hasNarrowPhase()) GTEST_SKIP() << "no narrow phase in this build";
  Arrangement s = randomSetup(11u, 300, 8.0f);
  for (GpuBodyState& st : s.states) st.com.z += 1.0f;  // above the planes, falling
  auto run = [&](BroadPhase method, std::vector<std::pair<uint32_t, uint32_t>>* pairs,
                 uint64_t* tests) {
    world->setBroadPhase(method);
    world->setBodies(s.states, s.params);
    world->setShapes(s.shapes);
    StepInput in;
    in.readContacts = true;
    std::string error;
    for (int step = 0; step < 5; ++step) {
      if (!world->step(in, &error)) ADD_FAILURE() << error;
      for (const auto& p : pairsOf(*world)) pairs->push_back(p);
      *tests += world->contactStats().candidateTests;
    }
    return std::vector<GpuBodyState>(world->states().begin(), world->states().end());
  };
  std::vector<std::pair<uint32_t, uint32_t>> pairs[3];
  uint64_t tests[3] = {};
  const auto a = run(BroadPhase::Tree, &pairs[0], &tests[0]);
  const auto b = run(BroadPhase::Tree, &pairs[1], &tests[1]);
  const auto c = run(BroadPhase::Sweep, &pairs[2], &tests[2]);
  EXPECT_GT(pairs[0].size(), 100u);
  EXPECT_EQ(pairs[0], pairs[1]);
  EXPECT_EQ(tests[0], tests[1]);
  EXPECT_EQ(pairs[0], pairs[2]);
  ASSERT_EQ(a.size(), b.size());
  ASSERT_EQ(a.size(), c.size());
  EXPECT_EQ(std::memcmp(a.data(), b.data(), a.size() * sizeof(GpuBodyState)), 0);
  EXPECT_EQ(std::memcmp(a.data(), c.data(), a.size() * sizeof(GpuBodyState)), 0);
}

}  // namespace
}  // namespace phys::gpu
