// Sleeping on the GPU backend (issue 22): the host finds the islands from the pairs the
// device's step found and makes the same decisions as the CPU; a sleeping body goes up as a
// body the step does not move, makes no pairs with static or sleeping bodies, and an awake
// body that touches it wakes it in the step that found the touch (the step is undone and
// taken again); a world whose bodies all sleep gives the device nothing to do. The touching
// pairs come back as the device's touch list (touch_list.glsl), not as manifolds.
#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <string>
#include <vector>

#include "../common/bodies.h"
#include "gpu_test_util.h"
#include "phys/gpu/gpu_world.h"
#include "phys/world/world.h"

namespace phys {
namespace {

using test::boxBody;
using test::groundBody;
using test::sphereBody;

WorldDef sleepyDef(Backend backend) {
  WorldDef d;
  d.backend = backend;
  d.gpuAllowCpuDevice = true;
  d.threads = 1;
  d.sleep.enabled = true;
  return d;
}

constexpr auto add = test::addBody;
constexpr auto state = test::stateOf;

bool allAsleep(const World& w, const std::vector<BodyId>& ids) {
  for (BodyId id : ids)
    if (!w.isSleeping(id)) return false;
  return true;
}

/// Steps until every body in ids sleeps; the step count, or -1 after maxSteps.
int stepUntilAsleep(World& w, const std::vector<BodyId>& ids, int maxSteps = 240) {
  for (int i = 0; i < maxSteps; ++i) {
    if (allAsleep(w, ids)) return i;
    w.step();
  }
  return allAsleep(w, ids) ? maxSteps : -1;
}

/// A ground plane and a column of n unit cubes at (x, 0), the lowest `lift` above the ground.
std::vector<BodyId> addColumn(World& w, float x, int n, float lift = 0) {
  std::vector<BodyId> ids;
  for (int i = 0; i < n; ++i) ids.push_back(add(w, boxBody({x, 0, 0.5f + lift + float(i)})));
  return ids;
}

TEST(GpuSleep, AColumnFallsAsleepWhenItDoesOnTheCpuAndThenCostsTheDeviceNothing) {
  World gpu(sleepyDef(Backend::Gpu)), cpu(sleepyDef(Backend::Cpu));
  REQUIRE_DEVICE(gpu);
  add(gpu, groundBody());
  add(cpu, groundBody());
  const std::vector<BodyId> g = addColumn(gpu, 0, 3, 0.05f), c = addColumn(cpu, 0, 3, 0.05f);
  const int gpuAsleep = stepUntilAsleep(gpu, g), cpuAsleep = stepUntilAsleep(cpu, c);
  ASSERT_GE(gpuAsleep, 0) << "the column never slept on the device";
  ASSERT_GE(cpuAsleep, 0);
  // The same rule on the same motion: the device's rounding differs, its decision barely.
  EXPECT_LE(std::abs(gpuAsleep - cpuAsleep), 3) << gpuAsleep << " vs " << cpuAsleep;
  EXPECT_EQ(gpu.awakeBodyCount(), 0);
  EXPECT_EQ(gpu.stats().sleepingBodies, 3);
  EXPECT_EQ(gpu.stats().sleepingIslands, 1);
  for (size_t i = 0; i < g.size(); ++i) {
    SCOPED_TRACE("box " + std::to_string(i));
    EXPECT_NEAR(state(gpu, g[i]).position.z, 0.5f + float(i), 0.01f);
    EXPECT_LT(length(state(gpu, g[i]).position - state(cpu, c[i]).position), 0.01f);
  }
  // Asleep: held exactly, no pairs, every step still the device backend's.
  const uint64_t hash = gpu.stateHash();
  const uint64_t gpuSteps = gpu.backendState().gpuSteps;
  for (int i = 0; i < 30; ++i) gpu.step();
  EXPECT_EQ(gpu.stateHash(), hash);
  EXPECT_EQ(gpu.stats().pairs, 0);
  EXPECT_EQ(gpu.backendState().gpuSteps, gpuSteps + 30);
  EXPECT_EQ(gpu.backendState().cpuSteps, 0u);
  // An edit wakes the column; it goes back up as dynamic and falls asleep again.
  ASSERT_TRUE(gpu.setVelocity(g[2], {0.5f, 0, 0}, {}).ok());
  EXPECT_FALSE(gpu.isSleeping(g[0]));
  gpu.step();
  EXPECT_GT(state(gpu, g[2]).position.x, 0.0f);
  EXPECT_GE(stepUntilAsleep(gpu, g), 0);
  EXPECT_EQ(gpu.backendState().cpuSteps, 0u);
}

TEST(GpuSleep, ABallWakesASleepingColumnInTheStepThatFindsTheTouch) {
  // The step that first finds the ball on the top box is taken again with the column
  // awake: the top box is pushed down in that very step, as on the CPU (whose narrow phase
  // wakes it before the solve), rather than holding like a wall for one step.
  for (Backend backend : {Backend::Gpu, Backend::Cpu}) {
    SCOPED_TRACE(backend == Backend::Gpu ? "gpu" : "cpu");
    World w(sleepyDef(backend));
    if (backend == Backend::Gpu) {
      REQUIRE_DEVICE(w);
    }
    add(w, groundBody());
    const std::vector<BodyId> column = addColumn(w, 0, 3);
    ASSERT_GE(stepUntilAsleep(w, column), 0);
    BodyDef ball = sphereBody({0, 0, 4.0f}, 0.25f, 4000);
    ball.linearVelocity = {0, 0, -4};
    const BodyId b = add(w, ball);
    ASSERT_TRUE(allAsleep(w, column)) << "a new body away from the column must not wake it";
    int woke = -1;
    for (int i = 0; i < 60 && woke < 0; ++i) {
      w.step();
      if (!w.isSleeping(column[2])) woke = i;
    }
    ASSERT_GE(woke, 0) << "the ball never woke the column";
    // Asleep in that step it would not have moved at all (v exactly zero); solved, the soft
    // contacts below give way and spring back within the step.
    EXPECT_GT(length(state(w, column[2]).linearVelocity), 0.01f)
        << "the top box did not take part in the step that woke it";
    EXPECT_FALSE(w.isSleeping(column[0]));  // the island wakes whole
    // The ball is stopped by the column, not bounced off a wall.
    EXPECT_GT(state(w, b).linearVelocity.z, -4.5f);
    EXPECT_LT(state(w, b).linearVelocity.z, 1.0f);
    if (backend == Backend::Gpu) {
      EXPECT_EQ(w.backendState().cpuSteps, 0u);
    }
  }
}

TEST(GpuSleep, OnlyTheTouchedIslandWakesAndRunsAreBitIdentical) {
  auto run = [](std::vector<bool>* asleepAtEnd) {
    World w(sleepyDef(Backend::Gpu));
    if (w.backendState().active != Backend::Gpu) return uint64_t(0);
    add(w, groundBody());
    std::vector<std::vector<BodyId>> columns;
    for (int k = 0; k < 3; ++k) columns.push_back(addColumn(w, 3.0f * float(k), 2, 0.02f));
    for (int i = 0; i < 90; ++i) w.step();
    for (const auto& col : columns) EXPECT_TRUE(allAsleep(w, col));
    BodyDef ball = sphereBody({0, 0, 3.0f}, 0.3f);
    ball.linearVelocity = {0, 0, -3};
    add(w, ball);
    for (int i = 0; i < 30; ++i) w.step();
    asleepAtEnd->clear();
    for (const auto& col : columns) asleepAtEnd->push_back(allAsleep(w, col));
    return w.stateHash();
  };
  std::vector<bool> first, second;
  const uint64_t a = run(&first);
  if (a == 0) GTEST_SKIP() << "no Vulkan device";
  EXPECT_EQ(a, run(&second));
  EXPECT_EQ(first, second);
  EXPECT_EQ(first, (std::vector<bool>{false, true, true}));
}

TEST(GpuSleep, ARestoredWorldKeepsItsSleepingIslandsOnTheDevice) {
  // A sleeping column and a ball in free flight far from it (no contacts: the device's warm
  // starts are not in a snapshot, the sleep state is): the restored world continues bit for
  // bit, its column asleep and held.
  World g(sleepyDef(Backend::Gpu));
  REQUIRE_DEVICE(g);
  add(g, groundBody());
  const std::vector<BodyId> column = addColumn(g, 0, 3);
  ASSERT_GE(stepUntilAsleep(g, column), 0);
  BodyDef ball = sphereBody({20, 0, 50}, 0.3f);
  ball.linearVelocity = {1, 0, 2};
  add(g, ball);
  g.step();
  std::vector<uint8_t> snap;
  ASSERT_TRUE(g.saveSnapshot(&snap).ok());
  for (int i = 0; i < 30; ++i) g.step();
  World r(sleepyDef(Backend::Gpu));
  ASSERT_TRUE(r.restoreSnapshot(snap.data(), snap.size()).ok());
  EXPECT_EQ(r.stats().sleepingBodies, 3);
  for (int i = 0; i < 30; ++i) r.step();
  EXPECT_EQ(r.stateHash(), g.stateHash());
  EXPECT_EQ(r.awakeBodyCount(), 1);
  EXPECT_EQ(r.backendState().gpuSteps, 30u);
}

TEST(GpuSleep, AHangingChainSleepsWithItsJointsAndHoldsWhenWoken) {
  World w(sleepyDef(Backend::Gpu));
  REQUIRE_DEVICE(w);
  // Five links hanging straight down from a world anchor at z = 5.
  std::vector<BodyId> links;
  std::vector<JointId> joints;
  BodyId prev;
  for (int i = 0; i < 5; ++i) {
    const BodyId id = add(w, boxBody({0, 0, 4.5f - float(i)}, {0.1f, 0.1f, 0.4f}));
    JointDef j;
    j.type = JointType::Ball;
    j.bodyA = prev;
    j.bodyB = id;
    j.anchorA = prev.isNull() ? Vec3{0, 0, 5} : Vec3{0, 0, -0.5f};
    j.anchorB = {0, 0, 0.5f};
    JointId jid;
    ASSERT_TRUE(w.createJoint(j, &jid).ok());
    links.push_back(id);
    joints.push_back(jid);
    prev = id;
  }
  ASSERT_GE(stepUntilAsleep(w, links), 0) << "the chain never slept";
  EXPECT_EQ(w.stats().sleepingIslands, 1);
  const BodyState endAsleep = state(w, links.back());
  w.step();
  EXPECT_EQ(w.stats().joints, 0);  // the device solves no sleeping joint
  ASSERT_TRUE(w.wakeBody(links.back()).ok());
  EXPECT_FALSE(w.isSleeping(links.front()));
  double mass = 0;
  for (BodyId id : links) mass += state(w, id).mass;
  // Awake (it could sleep again after the sleep time, 30 steps): the joints are solved.
  for (int i = 0; i < 20; ++i) {
    w.step();
    EXPECT_EQ(w.stats().joints, 5);
    EXPECT_LT(length(state(w, links.back()).position - endAsleep.position), 0.01f)
        << "step " << i << " after waking";
  }
  JointState anchor;
  ASSERT_TRUE(w.getJoint(joints[0], nullptr, &anchor).ok());
  EXPECT_NEAR(anchor.reactionForce.z, mass * 9.81, 0.02 * mass * 9.81);
  EXPECT_EQ(w.backendState().cpuSteps, 0u);
}

TEST(GpuSleep, TheTouchListIsTheManifoldsWithPointsBetweenNonStaticBodies) {
  // What the host's sleep pass read from the manifolds before (each manifold with points;
  // those with a static body change nothing there) now comes back as the touch list: the same
  // pairs in the same order, 8 bytes each, whatever else the step brings back.
  gpu::DeviceOptions o;
  o.allowCpu = true;
  std::string error;
  auto world = gpu::GpuWorld::create(o, &error);
  if (!world || !world->hasNarrowPhase()) GTEST_SKIP() << "no Vulkan device or narrow phase";
  // A heap of boxes and spheres over a ground plane and a static box, every fifth body
  // kinematic and every seventh asleep.
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(0, 1);
  std::vector<gpu::GpuBodyState> states;
  std::vector<gpu::GpuBodyParams> params;
  std::vector<gpu::GpuShape> shapes;
  auto shape = [](int body, uint32_t type, gpu::vec4 size, gpu::vec4 p) {
    gpu::GpuShape s;
    s.body = body;
    s.type = type;
    s.size = size;
    s.localP = p;
    s.localQ = {0, 0, 0, 1};
    s.friction = 0.6f;
    return s;
  };
  for (int i = 0; i < 120; ++i) {
    gpu::GpuBodyState st;
    st.com = {4 * u(rng), 4 * u(rng), 0.4f + 3 * u(rng), 0};
    st.q = {0, 0, 0, 1};
    gpu::GpuBodyParams p;
    const bool kinematic = i % 5 == 4, asleep = i % 7 == 6;
    p.flags.x = kinematic || asleep ? (asleep ? PHYS_GPU_BODY_ASLEEP : 0u) : PHYS_GPU_BODY_DYNAMIC;
    if (p.flags.x == PHYS_GPU_BODY_DYNAMIC) {
      p.accel = {0, 0, -9.81f, 1};
      for (int r = 0; r < 3; ++r) (&p.invInertia[r].x)[r] = 6;
    }
    p.principal = {0, 0, 0, 1};
    p.moments = {1 / 6.0f, 1 / 6.0f, 1 / 6.0f, 0};
    states.push_back(st);
    params.push_back(p);
    shapes.push_back(i % 2 ? shape(i, PHYS_GPU_SHAPE_SPHERE, {0.4f, 0, 0, 0}, {0, 0, 0, 0.4f})
                           : shape(i, PHYS_GPU_SHAPE_BOX, {0.3f, 0.3f, 0.3f, 0},
                                   {0, 0, 0, 0.52f}));
  }
  shapes.push_back(shape(-1, PHYS_GPU_SHAPE_PLANE, {0, 0, 1, 0}, {0, 0, 0, 0}));
  shapes.push_back(shape(-1, PHYS_GPU_SHAPE_BOX, {1, 1, 0.5f, 0}, {2, 2, 0.5f, 1.5f}));
  world->setBodies(states, params);
  world->setShapes(shapes);
  gpu::StepInput in;
  in.readContacts = in.readTouches = true;
  in.contacts.jacobi = false;
  size_t touching = 0, withStatic = 0;
  for (int step = 0; step < 20; ++step) {
    SCOPED_TRACE("step " + std::to_string(step));
    ASSERT_TRUE(world->step(in, &error)) << error;
    std::vector<std::pair<uint32_t, uint32_t>> expected;
    for (const gpu::GpuManifold& m : world->manifolds()) {
      if (m.count == 0) continue;
      const int a = shapes[m.shapeA].body, b = shapes[m.shapeB].body;
      if (a >= 0 && b >= 0)
        expected.push_back({uint32_t(a), uint32_t(b)});
      else
        ++withStatic;
    }
    std::vector<std::pair<uint32_t, uint32_t>> got;
    for (const gpu::Touch& t : world->touches()) got.push_back({t.a, t.b});
    EXPECT_EQ(got, expected);
    touching += got.size();
    // The states, the counters, the list's length and the list, then what readContacts adds.
    const uint64_t counters = PHYS_GPU_COUNTER_COUNT * 4;
    const uint64_t base =
        states.size() * sizeof(gpu::GpuBodyState) + counters + 8 + 8 * got.size();
    EXPECT_GT(world->readbackBytes(), base);  // plus the capacity's pairs and manifolds
    EXPECT_EQ((world->readbackBytes() - base) % (sizeof(gpu::GpuPair) + sizeof(gpu::GpuManifold)),
              0u);
  }
  EXPECT_GT(touching, 100u);  // the heap touches itself...
  EXPECT_GT(withStatic, 20u);  // ...and the ground
  // Without readContacts only the list comes back.
  in.readContacts = false;
  ASSERT_TRUE(world->step(in, &error)) << error;
  EXPECT_EQ(world->readbackBytes(),
            states.size() * sizeof(gpu::GpuBodyState) + PHYS_GPU_COUNTER_COUNT * 4 + 8 +
                8 * world->touches().size());
}

TEST(GpuSleep, APileFallsAsleepOnTheTouchListAsOnTheCpu) {
  // A pile of 18 boxes dropped in a heap: it falls asleep on the device from the touch list
  // as on the CPU (islands, sleep step, the bodies where they rest), the same every run, and
  // what a step brings back is the states and 8 bytes a touching pair, no manifolds.
  auto run = [](Backend backend, int* asleepAt, uint64_t* maxReadback, int* contactsAtMax) {
    World w(sleepyDef(backend));
    if (w.backendState().active != backend) return std::vector<BodyState>{};
    add(w, groundBody());
    std::vector<BodyId> ids;
    for (int i = 0; i < 18; ++i)
      ids.push_back(add(w, boxBody({0.3f * float(i % 3), 0.3f * float((i / 3) % 3),
                                    0.5f + 1.05f * float(i / 9) + 0.1f * float(i % 2)})));
    *asleepAt = -1;
    *maxReadback = 0;
    for (int i = 0; i < 400 && *asleepAt < 0; ++i) {
      w.step();
      if (w.backendState().readbackBytes > *maxReadback) {
        *maxReadback = w.backendState().readbackBytes;
        *contactsAtMax = w.stats().contacts;
      }
      if (allAsleep(w, ids)) *asleepAt = i;
    }
    std::vector<BodyState> out;
    for (BodyId id : ids) out.push_back(state(w, id));
    if (backend == Backend::Gpu) {
      EXPECT_EQ(w.backendState().cpuSteps, 0u);
    }
    return out;
  };
  int gpuAt = -1, cpuAt = -1, again = -1, contacts = 0, contacts2 = 0;
  uint64_t bytes = 0, bytes2 = 0;
  const std::vector<BodyState> g = run(Backend::Gpu, &gpuAt, &bytes, &contacts);
  if (g.empty()) GTEST_SKIP() << "no Vulkan device";
  const std::vector<BodyState> c = run(Backend::Cpu, &cpuAt, &bytes2, &contacts2);
  ASSERT_GE(gpuAt, 0) << "the pile never slept on the device";
  ASSERT_GE(cpuAt, 0);
  std::printf("asleep at step %d on the device, %d on the CPU; at most %llu bytes back a step\n",
              gpuAt, cpuAt, static_cast<unsigned long long>(bytes));
  // The pile's heap is chaotic: the boxes settle near, not at, the CPU's places.
  EXPECT_LE(std::abs(gpuAt - cpuAt), 30);
  // At most the states (64 bytes a body), counters and joints' results (none), the list's
  // length and 8 bytes a touching pair (the manifolds with points, those on the ground too,
  // bound them): a manifold's record alone is 160 bytes.
  EXPECT_LE(bytes, 19u * 64 + 32 + 8 + 8u * uint64_t(contacts));
  const std::vector<BodyState> g2 = run(Backend::Gpu, &again, &bytes2, &contacts2);
  EXPECT_EQ(again, gpuAt);
  ASSERT_EQ(g2.size(), g.size());
  for (size_t i = 0; i < g.size(); ++i) {
    EXPECT_EQ(g2[i].position, g[i].position) << "box " << i;
    EXPECT_EQ(g2[i].rotation.w, g[i].rotation.w) << "box " << i;
  }
}

}  // namespace
}  // namespace phys
