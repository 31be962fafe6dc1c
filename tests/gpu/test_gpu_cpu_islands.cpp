// Islands on the CPU beside the device (issue 42 point 5, world_gpu_islands.cpp): on the GPU
// backend an island holding a touching pair of mass ratio directContactRatio or more, or an
// elastic contact, is stepped by the CPU in the same step while the device steps the rest;
// such islands then behave as on the CPU backend, the counters say what went where, and a
// world without such islands never reads its contacts back (the other GPU suites pin it).
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

constexpr auto add = test::addBody;
constexpr auto state = test::stateOf;

WorldDef islandDef(Backend backend) {
  WorldDef d;
  d.backend = backend;
  d.gpuAllowCpuDevice = true;
  d.threads = 1;
  return d;
}

/// A 1000:1 pile (as mass_ratio_1000's): a 1 m cube of 1000 x 1000 kg on a column of two
/// 1000 kg cubes at x, resting on the ground. Returns {light0, light1, heavy}.
std::vector<BodyId> addHeavyPile(World& w, float x) {
  std::vector<BodyId> ids;
  ids.push_back(add(w, boxBody({x, 0, 0.5f})));
  ids.push_back(add(w, boxBody({x, 0, 1.5f})));
  BodyDef heavy = boxBody({x, 0, 2.5f});
  heavy.shapes[0].material.density = 1000 * 1000;
  ids.push_back(add(w, heavy));
  return ids;
}

/// A column of three equal 1000 kg cubes at x: the device's alone.
std::vector<BodyId> addLightColumn(World& w, float x) {
  std::vector<BodyId> ids;
  for (int i = 0; i < 3; ++i) ids.push_back(add(w, boxBody({x, 0, 0.5f + float(i)})));
  return ids;
}

TEST(GpuCpuIslands, AHeavyOnLightPileIsSteppedByTheCpuAndTheRestOnTheDevice) {
  World gpu(islandDef(Backend::Gpu)), cpu(islandDef(Backend::Cpu));
  REQUIRE_DEVICE(gpu);
  add(gpu, groundBody());
  add(cpu, groundBody());
  const std::vector<BodyId> pile = addHeavyPile(gpu, 0), cpuPile = addHeavyPile(cpu, 0);
  const std::vector<BodyId> column = addLightColumn(gpu, 20), cpuColumn = addLightColumn(cpu, 20);
  double deepest = 0;
  for (int i = 0; i < 120; ++i) {
    gpu.step();
    cpu.step();
    deepest = std::max(deepest, gpu.stats().maxPenetration);
    const BackendState& b = gpu.backendState();
    // Every step: the pile's island (3 bodies) on the CPU, the column on the device.
    ASSERT_EQ(b.cpuIslands, 1) << "step " << i;
    ASSERT_EQ(b.cpuIslandBodies, 3) << "step " << i;
  }
  const BackendState& b = gpu.backendState();
  EXPECT_EQ(b.cpuSteps, 0u);
  EXPECT_EQ(b.gpuSteps, 120u);
  EXPECT_EQ(b.cpuIslandSteps, 120u);
  EXPECT_EQ(b.cpuIslandBodySteps, 360u);
  EXPECT_NE(b.cpuIslandReason.find("direct contacts"), std::string::npos) << b.cpuIslandReason;
  // The scene's criteria: no contact deeper than 1 cm, nothing moves sideways.
  EXPECT_LT(deepest, 0.01);
  for (size_t i = 0; i < pile.size(); ++i) {
    SCOPED_TRACE("pile body " + std::to_string(i));
    const BodyState g = state(gpu, pile[i]), c = state(cpu, cpuPile[i]);
    EXPECT_NEAR(g.position.z, 0.5f + float(i), 0.01f);
    // Its own island, stepped by the CPU with the CPU's settings: the CPU backend's bits.
    EXPECT_EQ(g.position, c.position);
    EXPECT_EQ(g.linearVelocity, c.linearVelocity);
  }
  // The column is the device's: where the CPU puts it, up to the device's rounding.
  for (size_t i = 0; i < column.size(); ++i) {
    SCOPED_TRACE("column body " + std::to_string(i));
    EXPECT_LT(length(state(gpu, column[i]).position - state(cpu, cpuColumn[i]).position), 0.01f);
  }
}

TEST(GpuCpuIslands, ALightBodyThatLandsOnTheHeldPileJoinsItsIslandWithoutSinking) {
  // A light box dropped on the heavy one meets a held body: the step that finds the touch is
  // taken again with the box in the CPU's island (never an island split between the two).
  World gpu(islandDef(Backend::Gpu));
  REQUIRE_DEVICE(gpu);
  add(gpu, groundBody());
  addHeavyPile(gpu, 0);
  const BodyId drop = add(gpu, boxBody({0, 0, 3.7f}, {0.25f, 0.25f, 0.25f}));
  for (int i = 0; i < 90; ++i) gpu.step();
  const BackendState& b = gpu.backendState();
  EXPECT_EQ(b.cpuIslandBodies, 4);
  EXPECT_EQ(b.cpuIslands, 1);
  EXPECT_GE(b.cpuIslandRetakes, 1u);
  EXPECT_EQ(b.cpuSteps, 0u);
  EXPECT_NEAR(state(gpu, drop).position.z, 3.25f, 0.01f);
  EXPECT_LT(gpu.stats().maxPenetration, 0.01f);
}

/// An elastic ball (restitution 1) dropped on the ground from 1 m at x, in a world that also
/// has a plastic ball far away.
struct Balls {
  BodyId elastic, plastic;
};
Balls addBalls(World& w) {
  add(w, groundBody());
  BodyDef e = sphereBody({0, 0, 1.0f}, 0.1f);
  e.shapes[0].material.restitution = 1;
  BodyDef p = sphereBody({20, 0, 1.0f}, 0.1f);
  return {add(w, e), add(w, p)};
}

TEST(GpuCpuIslands, AnElasticBallBouncesAsOnTheCpu) {
  World gpu(islandDef(Backend::Gpu)), cpu(islandDef(Backend::Cpu));
  REQUIRE_DEVICE(gpu);
  const Balls g = addBalls(gpu), c = addBalls(cpu);
  float gpuUp = 0, cpuUp = 0;  // the fastest rise after the bounce
  int elasticSteps = 0;
  for (int i = 0; i < 40; ++i) {
    gpu.step();
    cpu.step();
    gpuUp = std::max(gpuUp, state(gpu, g.elastic).linearVelocity.z);
    cpuUp = std::max(cpuUp, state(cpu, c.elastic).linearVelocity.z);
    elasticSteps += gpu.backendState().cpuIslandBodies == 1;
  }
  // It bounced (about 4.4 m/s up) with the CPU's collision phase and energy limit: the
  // same bits, since its island was the CPU's from the step its contact appeared.
  EXPECT_GT(cpuUp, 3.5f);
  EXPECT_EQ(gpuUp, cpuUp);
  EXPECT_EQ(state(gpu, g.elastic).position, state(cpu, c.elastic).position);
  EXPECT_GT(elasticSteps, 0);
  EXPECT_NE(gpu.backendState().cpuIslandReason.find("restitution"), std::string::npos);
  // The plastic ball (the device's) landed and stays.
  EXPECT_NEAR(state(gpu, g.plastic).position.z, 0.1f, 0.01f);
  EXPECT_LT(std::abs(state(gpu, g.plastic).linearVelocity.z), 0.1f);
  EXPECT_EQ(gpu.backendState().cpuSteps, 0u);
}

TEST(GpuCpuIslands, RunsAreBitIdenticalAndAPlainWorldHoldsNothing) {
  auto run = [](bool heavy) {
    World w(islandDef(Backend::Gpu));
    if (w.backendState().active != Backend::Gpu) return std::pair<uint64_t, uint64_t>{0, 0};
    add(w, groundBody());
    if (heavy) addHeavyPile(w, 0);
    addLightColumn(w, 20);
    for (int i = 0; i < 60; ++i) w.step();
    return std::pair<uint64_t, uint64_t>{w.stateHash(), w.backendState().cpuIslandSteps};
  };
  const auto a = run(true), b = run(true);
  if (a.first == 0) GTEST_SKIP() << "no Vulkan device";
  EXPECT_EQ(a.first, b.first);
  EXPECT_EQ(a.second, 60u);
  // Equal masses and no restitution: nothing goes to the CPU.
  EXPECT_EQ(run(false).second, 0u);
}

}  // namespace
}  // namespace phys
