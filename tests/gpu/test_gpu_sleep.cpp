// Sleeping on the GPU backend (issue 22): the host finds the islands from the pairs the
// device's step found and makes the same decisions as the CPU; a sleeping body goes up as a
// body the step does not move, makes no pairs with static or sleeping bodies, and an awake
// body that touches it wakes it in the step that found the touch (the step is undone and
// taken again); a world whose bodies all sleep gives the device nothing to do.
#include <gtest/gtest.h>

#include <cmath>
#include <string>
#include <vector>

#include "../common/bodies.h"
#include "gpu_test_util.h"
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

}  // namespace
}  // namespace phys
