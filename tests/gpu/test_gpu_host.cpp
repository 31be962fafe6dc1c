// The host's part of a device step follows what changed, not the world's size (issue 42):
// what goes up is the records edited since the step before (and the counters' resets),
// what comes back is what the host mirror and publishing read (every body's state, the
// counters), and the guard's copy sums the step's starting energy in its own pass, the same
// bits as World::energy (and the mirror pass the step's ending energy, and the guard's quick
// tests, with the same verdicts). Byte counts, not times: they fail on a change that makes a step
// upload the world again or read back a buffer nobody reads, on any device.
#include <gtest/gtest.h>

#include <cstdint>
#include <string>
#include <vector>

#include "../common/bodies.h"
#include "gpu_test_util.h"
#include "phys/gpu/gpu_world.h"
#include "phys/world/world.h"

namespace phys {
namespace {

/// A ground and n spheres in a grid, apart from each other, falling onto it (sleep off:
/// every body awake in every step).
struct Spheres {
  std::unique_ptr<World> world;
  std::vector<BodyId> ids;
  explicit Spheres(int n, Backend backend = Backend::Gpu, bool guard = true) {
    WorldDef d;
    d.backend = backend;
    d.gpuAllowCpuDevice = true;
    d.threads = 1;
    d.guard = guard;
    world = std::make_unique<World>(d);
    test::addBody(*world, test::groundBody());
    for (int i = 0; i < n; ++i)
      ids.push_back(test::addBody(
          *world, test::sphereBody({1.5f * float(i % 32), 1.5f * float(i / 32), 0.6f}, 0.5f)));
  }
};

constexpr uint64_t kBodyRecord = sizeof(gpu::GpuBodyState) + sizeof(gpu::GpuBodyParams);
constexpr uint64_t kCounters = PHYS_GPU_COUNTER_COUNT * 4;

/// Upload bytes of the steps of a world of n spheres: after they landed, a quiet step, then
/// a step after one body's velocity was set, then one after a force was applied to one (the
/// force goes up, then its clearing: two steps), then a quiet one.
std::vector<uint64_t> uploads(int n) {
  Spheres s(n);
  World& w = *s.world;
  if (w.backendState().active != Backend::Gpu) return {};
  std::vector<uint64_t> out;
  auto step = [&]() {
    w.step();
    EXPECT_EQ(w.backendState().cpuSteps, 0u) << w.backendState().lastFallback;
    out.push_back(w.backendState().uploadBytes);
  };
  // The first step uploads the world; so does a step whose pairs outgrow the pair buffers
  // (it is taken again with larger ones, from the host's states): the spheres land first.
  for (int i = 0; i < 20; ++i) w.step();
  step();                                // quiet
  EXPECT_TRUE(w.setVelocity(s.ids[7], {1, 0, 0}, {}).ok());
  step();  // one body's records
  EXPECT_TRUE(w.applyForce(s.ids[n / 2], {0, 0, 5}, {}).ok());
  step();  // the body with its force
  step();  // the same body without it (forces last one step)
  step();  // quiet
  return out;
}

TEST(GpuHost, UploadsFollowTheEditsNotTheWorldsSize) {
  const std::vector<uint64_t> small = uploads(64), large = uploads(1024);
  if (small.empty()) GTEST_SKIP() << "no Vulkan device";
  ASSERT_EQ(small.size(), 5u);
  // A quiet step sends the counters' resets only, a few words.
  const uint64_t quiet = small[0];
  EXPECT_LT(quiet, kBodyRecord);
  EXPECT_EQ(small[4], quiet);
  // An edited body: its state and parameters, once.
  EXPECT_EQ(small[1], quiet + kBodyRecord);
  EXPECT_EQ(small[2], quiet + kBodyRecord);
  EXPECT_EQ(small[3], quiet + kBodyRecord);
  // The same in a world 16 times as large.
  EXPECT_EQ(large, small);
}

TEST(GpuHost, ReadbackIsTheStatesAndCountersOnly) {
  // Sleep off, no joints, no islands on the CPU: the host mirror needs every body's state
  // and the statistics the counters; no bounds, pairs, manifolds or touches come back.
  for (int n : {64, 1024}) {
    SCOPED_TRACE(n);
    Spheres s(n);
    World& w = *s.world;
    REQUIRE_DEVICE(w);
    for (int i = 0; i < 4; ++i) {
      w.step();
      EXPECT_EQ(w.backendState().readbackBytes,
                uint64_t(n) * sizeof(gpu::GpuBodyState) + kCounters);
    }
  }
}

TEST(GpuHost, HostPartsAreMeasured) {
  // Times are no pass/fail criterion; that the profile has them, and what is left outside
  // the device's stages is split between them, is.
  Spheres s(256);
  World& w = *s.world;
  REQUIRE_DEVICE(w);
  for (int i = 0; i < 3; ++i) w.step();
  const StepProfile& p = w.profile();
  EXPECT_GT(p.hostUpload, 0.0);  // recording the commands at least
  EXPECT_GT(p.hostMirror, 0.0);
  EXPECT_GE(p.hostReadback, 0.0);
  EXPECT_GE(p.hostOther, 0.0);
  EXPECT_GT(p.guard, 0.0);
  EXPECT_LE(p.hostUpload + p.hostReadback + p.hostMirror + p.hostOther, p.total);
}

TEST(GpuHost, TheGuardsCopySumsTheEnergyWorldEnergyDoes) {
  // The step's starting energy comes from the guard's pass over the bodies: the same bits
  // as World::energy just before the step, on either backend, with sleeping islands too
  // (their potential) and after an edit between steps.
  for (Backend backend : {Backend::Cpu, Backend::Gpu}) {
    SCOPED_TRACE(backend == Backend::Cpu ? "cpu" : "gpu");
    WorldDef d;
    d.backend = backend;
    d.gpuAllowCpuDevice = true;
    d.threads = 1;
    d.sleep.enabled = true;
    World w(d);
    test::addBody(w, test::groundBody());
    std::vector<BodyId> ids;
    for (int i = 0; i < 12; ++i)
      ids.push_back(test::addBody(w, test::boxBody({2.5f * float(i), 0, 0.5f + 0.02f * float(i)})));
    int sleepers = 0;
    for (int step = 0; step < 150; ++step) {
      if (step == 100) {
        EXPECT_TRUE(w.setVelocity(ids[3], {0, 0, 2}, {0, 1, 0}).ok());
      }
      const double before = w.energy();
      w.step();
      EXPECT_EQ(w.stats().energyBefore, before) << "step " << step;
      sleepers = std::max(sleepers, w.stats().sleepingBodies);
    }
    EXPECT_GT(sleepers, 0);  // the potential of sleeping islands was part of it
  }
}

TEST(GpuHost, TheMirrorPassJudgesAsTheGuardsOwnPassesDo) {
  // The device step's mirror pass also sums the step's energy and runs the guard's quick
  // tests (World::Impl::mirrorScan), so that the health check and keepInsideWorld look only
  // at the bodies from the first it did not clear. They must still find every fault: two
  // runaways far apart in a field of 3,000 spheres (past a pass's grain: on two threads in
  // different ranges) and a kinematic body that leaves the world's extent, the same bodies
  // stopped and the same event on one thread and on two, and energyAfter the bits of
  // World::energy after every step.
  constexpr float e = WorldDef::kWorldExtent;
  auto run = [&](int threads) {
    WorldDef d;
    d.backend = Backend::Gpu;
    d.gpuAllowCpuDevice = true;
    d.threads = threads;
    d.gravity = {0, 0, 0};
    d.guardRetries = 1;  // the retry fails too: the event names the first body at fault
    auto w = std::make_unique<World>(d);
    std::vector<BodyId> ids;
    for (int i = 0; i < 3000; ++i)
      ids.push_back(test::addBody(
          *w, test::sphereBody({3.0f * float(i % 60), 3.0f * float(i / 60), 0}, 0.5f)));
    BodyDef k = test::boxBody({e - 5, -20, 0}, {0.5f, 0.5f, 0.5f}, BodyType::Kinematic);
    k.linearVelocity = {400, 0, 0};
    test::addBody(*w, k);
    for (int step = 0; step < 4; ++step) {
      if (step == 1) {
        for (int i : {2400, 700}) {
          EXPECT_TRUE(w->applyForce(ids[size_t(i)], {1e30f, 0, 0}, {}).ok());
        }
      }
      w->step();
      EXPECT_EQ(w->stats().energyAfter, w->energy()) << "step " << step;
      if (step == 0) {  // it crossed the extent in this step: stopped on its edge at once
        EXPECT_EQ(w->stats().guardQuarantined, 1u);
        EXPECT_NE(w->stats().lastGuardEvent.find("left the world's extent"), std::string::npos)
            << w->stats().lastGuardEvent;
      }
    }
    return w;
  };
  auto one = run(1);
  REQUIRE_DEVICE(*one);
  auto two = run(2);
  EXPECT_EQ(one->backendState().cpuSteps, 0u) << one->backendState().lastFallback;
  EXPECT_EQ(one->stats().guardQuarantined, 3u) << one->stats().lastGuardEvent;
  // Found as a body at fault (the health check's body tests), not by the energy's rise that
  // the same runaways also cause.
  EXPECT_EQ(one->stats().lastGuardEvent.find("energy rose"), std::string::npos)
      << one->stats().lastGuardEvent;
  EXPECT_NE(one->stats().lastGuardEvent.find(": body "), std::string::npos)
      << one->stats().lastGuardEvent;
  EXPECT_EQ(two->stats().guardQuarantined, one->stats().guardQuarantined);
  EXPECT_EQ(two->stats().lastGuardEvent, one->stats().lastGuardEvent);
  EXPECT_EQ(two->stats().energyAfter, one->stats().energyAfter);
  EXPECT_EQ(two->stateHash(), one->stateHash());
}

}  // namespace
}  // namespace phys
