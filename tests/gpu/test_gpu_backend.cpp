// The GPU backend against the CPU backend and against analytic answers, on whatever Vulkan
// device is present (lavapipe in CI): bodies, contacts (Jacobi and colored Gauss-Seidel),
// joints (with the LDL solve of their equality rows); a step the device cannot take (a
// setting it does not have, docs/ARCHITECTURE.md) is taken by the CPU (the fallback is tested
// too).
#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <string>
#include <vector>

#include "../common/bodies.h"
#include "gpu_test_util.h"
#include "phys/gpu/gpu_world.h"
#include "phys/scene/scene.h"
#include "phys/world/world.h"

namespace phys {
namespace {

using test::boxBody;
using test::groundBody;
using test::sphereBody;

/// tjsoft's settings (configs/presets.json): the Jacobi scheme the device solves.
SolverSettings jacobiSettings(int substeps = 4, int iterations = 8) {
  SolverSettings s;
  s.scheme = SolverSettings::Scheme::Jacobi;
  s.substeps = substeps;
  s.iterations = iterations;
  s.relaxIterations = 1;
  s.stabilization = SolverSettings::Stabilization::Soft;
  s.contactHertz = 30;
  s.contactDampingRatio = 10;
  s.patchFriction = false;
  s.equalitySolve = SolverSettings::EqualitySolve::Iterative;
  s.geometricStiffness = false;
  s.splitPushout = false;
  return s;
}

WorldDef gpuDef(Backend backend = Backend::Gpu) {
  WorldDef d;
  d.backend = backend;
  d.gpuAllowCpuDevice = true;
  d.threads = 1;
  return d;
}

constexpr auto add = test::addBody;
constexpr auto state = test::stateOf;

Vec3 angularMomentum(const BodyState& s) {
  return s.inertia * s.angularVelocity;
}

// ---------------------------------------------------------------------------------------------
// Device choice

TEST(GpuDevice, CpuImplementationOnlyWhenAllowed) {
  std::vector<gpu::DeviceInfo> devices = gpu::listDevices();
  if (devices.empty()) GTEST_SKIP() << "no Vulkan loader or driver";
  bool onlyCpu = true;
  for (const auto& d : devices) onlyCpu &= d.isCpu;
  gpu::DeviceOptions strict;
  std::string error;
  auto world = gpu::GpuWorld::create(strict, &error);
  if (onlyCpu) {
    EXPECT_EQ(world, nullptr);
    EXPECT_NE(error.find("PHYS_GPU_ALLOW_CPU"), std::string::npos) << error;
  } else {
    ASSERT_NE(world, nullptr) << error;
    EXPECT_FALSE(world->device().isCpu);
  }
  gpu::DeviceOptions lenient;
  lenient.allowCpu = true;
  world = gpu::GpuWorld::create(lenient, &error);
  ASSERT_NE(world, nullptr) << error;
  EXPECT_FALSE(world->device().name.empty());
  // A GPU is preferred to a CPU implementation whenever there is one.
  EXPECT_EQ(world->device().isCpu, onlyCpu);
}

TEST(GpuDevice, NoDeviceFallsBackToTheCpuAndSaysWhy) {
  WorldDef d = gpuDef();
  d.gpuAllowCpuDevice = false;
  std::vector<gpu::DeviceInfo> devices = gpu::listDevices();
  bool onlyCpu = true;
  for (const auto& dev : devices) onlyCpu &= dev.isCpu;
  if (!onlyCpu) GTEST_SKIP() << "a GPU is present";
  World w(d);
  const BackendState& b = w.backendState();
  EXPECT_EQ(b.requested, Backend::Gpu);
  EXPECT_EQ(b.active, Backend::Cpu);
  EXPECT_NE(b.note.find("no GPU device"), std::string::npos) << b.note;
  // The world still works, on the CPU.
  BodyId s = add(w, sphereBody({0, 0, 10}, 0.5f));
  w.step();
  EXPECT_LT(state(w, s).linearVelocity.z, 0);
  EXPECT_EQ(b.cpuSteps, 1u);
  EXPECT_EQ(b.gpuSteps, 0u);
}

TEST(GpuDevice, ValidationLayerReportsNothing) {
  gpu::DeviceOptions o;
  o.allowCpu = true;
  o.validation = true;
  std::string error;
  auto world = gpu::GpuWorld::create(o, &error);
  ASSERT_NE(world, nullptr) << error;
  if (!world->device().validation) GTEST_SKIP() << "VK_LAYER_KHRONOS_validation not installed";
  gpu::GpuBodyState s;
  s.q.w = 1;
  s.com.z = 5;
  gpu::GpuBodyParams p;
  p.accel = {0, 0, -9.81f, 1};
  p.principal.w = 1;
  p.moments = {1, 2, 3, 0};
  p.flags.x = PHYS_GPU_BODY_DYNAMIC | PHYS_GPU_BODY_GYROSCOPIC;
  std::vector<gpu::GpuBodyState> states(100, s);
  std::vector<gpu::GpuBodyParams> params(100, p);
  world->setBodies(states, params);
  gpu::GpuShape shape;
  shape.type = PHYS_GPU_SHAPE_SPHERE;
  shape.size.x = 0.5f;
  shape.localQ.w = 1;
  world->setShapes(std::vector<gpu::GpuShape>(100, shape));
  gpu::StepInput in;
  in.substeps = 4;
  in.readBounds = true;
  for (int i = 0; i < 5; ++i) ASSERT_TRUE(world->step(in, &error)) << error;
  world->setBody(3, s, p);  // a partial upload too
  ASSERT_TRUE(world->step(in, &error)) << error;
  EXPECT_EQ(world->validationErrors(), 0);
  // Teardown: buffers, memory, pipelines or the device left behind are reported when the
  // device and the instance are destroyed, after the world's own count can be read.
  const int before = gpu::validationErrorsInProcess();
  world.reset();
  EXPECT_EQ(gpu::validationErrorsInProcess(), before);
}

// A whole World on the device (contacts, joints and their LDL solve, colors), stepped and
// destroyed under the validation layer: nothing reported, teardown included.
TEST(GpuDevice, WorldTeardownIsCleanUnderValidation) {
  gpu::DeviceOptions o;
  o.allowCpu = true;
  o.validation = true;
  std::string error;
  if (auto probe = gpu::GpuWorld::create(o, &error); !probe || !probe->device().validation)
    GTEST_SKIP() << "no device with VK_LAYER_KHRONOS_validation: " << error;
  const int before = gpu::validationErrorsInProcess();
  // The World opens its device with the environment's options; unset on every way out.
  struct ValidationEnv {
    ValidationEnv() { ::setenv("PHYS_GPU_VALIDATION", "1", 1); }
    ~ValidationEnv() { ::unsetenv("PHYS_GPU_VALIDATION"); }
  } env;
  {
    Scene sc;
    ASSERT_TRUE(
        loadSceneFile(std::string(PHYS_SOURCE_DIR) + "/configs/scenes/ball_and_chain.json", &sc)
            .ok());
    sc.world.backend = Backend::Gpu;
    sc.world.gpuAllowCpuDevice = true;
    World w(sc.world);
    std::vector<BodyId> ids;
    ASSERT_TRUE(instantiateScene(sc, &w, &ids).ok());
    for (int i = 0; i < 5; ++i) w.step();
    EXPECT_EQ(w.backendState().active, Backend::Gpu) << w.backendState().note;
    EXPECT_EQ(w.backendState().cpuSteps, 0u) << w.backendState().lastFallback;
  }
  EXPECT_EQ(gpu::validationErrorsInProcess(), before);
}

// ---------------------------------------------------------------------------------------------
// Bounds

TEST(GpuBounds, MatchTheCpuShapesBounds) {
  gpu::DeviceOptions o;
  o.allowCpu = true;
  std::string error;
  auto world = gpu::GpuWorld::create(o, &error);
  if (!world) GTEST_SKIP() << error;
  // One body per shape kind at a tilted pose, and a static box in world coordinates.
  const Quat q = normalize(Quat{0.3f, -0.2f, 0.5f, 0.8f});
  const Vec3 com{1, -2, 3};
  std::vector<ShapeGeom> geoms = {ShapeGeom::sphere(0.4f), ShapeGeom::box({0.2f, 0.5f, 0.9f}),
                                  ShapeGeom::capsule(0.3f, 0.7f)};
  std::vector<gpu::GpuBodyState> states;
  std::vector<gpu::GpuBodyParams> params;
  std::vector<gpu::GpuShape> shapes;
  std::vector<AABB> expected;
  const float margin = 0.01f;  // half the speculative distance
  const Transform local{{0.1f, 0.2f, -0.3f}, normalize(Quat{0, 0.3f, 0, 1})};
  for (size_t i = 0; i < geoms.size(); ++i) {
    gpu::GpuBodyState s;
    s.com = {com.x + float(i), com.y, com.z, 0};
    s.q = {q.x, q.y, q.z, q.w};
    states.push_back(s);
    gpu::GpuBodyParams p;
    p.localCenter = {0, 0, 0, 0};
    params.push_back(p);
    gpu::GpuShape g;
    g.body = int(i);
    g.type = uint32_t(geoms[i].type);
    g.localP = {local.p.x, local.p.y, local.p.z, 0};
    g.localQ = {local.q.x, local.q.y, local.q.z, local.q.w};
    if (geoms[i].type == ShapeType::Sphere) g.size = {geoms[i].radius, 0, 0, 0};
    if (geoms[i].type == ShapeType::Box)
      g.size = {geoms[i].halfExtents.x, geoms[i].halfExtents.y, geoms[i].halfExtents.z, 0};
    if (geoms[i].type == ShapeType::Capsule) g.size = {geoms[i].radius, geoms[i].halfHeight, 0, 0};
    shapes.push_back(g);
    const Transform body{{com.x + float(i), com.y, com.z}, q};
    AABB box = computeAABB(geoms[i], body * local);
    box.lo -= Vec3{margin, margin, margin};
    box.hi += Vec3{margin, margin, margin};
    expected.push_back(box);
  }
  world->setBodies(states, params);
  world->setShapes(shapes);
  gpu::StepInput in;
  in.speculativeDistance = 2 * margin;  // the bodies are at rest: no sweep
  in.readBounds = true;
  ASSERT_TRUE(world->step(in, &error)) << error;
  ASSERT_EQ(world->bounds().size(), expected.size());
  for (size_t i = 0; i < expected.size(); ++i) {
    const gpu::GpuAabb& b = world->bounds()[i];
    SCOPED_TRACE("shape " + std::to_string(i));
    EXPECT_NEAR(b.lo.x, expected[i].lo.x, 1e-5f);
    EXPECT_NEAR(b.lo.y, expected[i].lo.y, 1e-5f);
    EXPECT_NEAR(b.lo.z, expected[i].lo.z, 1e-5f);
    EXPECT_NEAR(b.hi.x, expected[i].hi.x, 1e-5f);
    EXPECT_NEAR(b.hi.y, expected[i].hi.y, 1e-5f);
    EXPECT_NEAR(b.hi.z, expected[i].hi.z, 1e-5f);
  }
}

// ---------------------------------------------------------------------------------------------
// Bodies: the device against the CPU and analytic answers

TEST(GpuBodies, FreeFallMatchesTheCpuAndTheAnalyticAnswer) {
  World g(gpuDef()), c(gpuDef(Backend::Cpu));
  REQUIRE_DEVICE(g);
  BodyDef d = sphereBody({0, 0, 100}, 0.5f);
  d.linearVelocity = {3, -1, 20};
  BodyId gs = add(g, d), cs = add(c, d);
  const int steps = 120;
  for (int i = 0; i < steps; ++i) {
    g.step();
    c.step();
  }
  EXPECT_EQ(g.backendState().gpuSteps, uint64_t(steps));
  EXPECT_EQ(g.backendState().cpuSteps, 0u);
  const BodyState a = state(g, gs), b = state(c, cs);
  // Linear motion is the same few adds and multiplies on both: equal to float rounding.
  EXPECT_NEAR(a.position.x, b.position.x, 1e-4f);
  EXPECT_NEAR(a.position.z, b.position.z, 1e-4f);
  EXPECT_NEAR(a.linearVelocity.z, b.linearVelocity.z, 1e-4f);
  // Semi-implicit Euler: z = z0 + v0 t - g t^2 / 2 - g h t / 2 (h = the substep).
  const double t = steps / 60.0, h = 1.0 / 60 / g.def().solver.substeps;
  const double z = 100 + 20 * t - 9.81 * t * t / 2 - 9.81 * h * t / 2;
  EXPECT_NEAR(a.position.z, z, 1e-3);
  EXPECT_NEAR(a.position.x, 3 * t, 1e-4);
}

TEST(GpuBodies, TorqueFreeTumblingKeepsAngularMomentumAsTheCpuDoes) {
  World g(gpuDef()), c(gpuDef(Backend::Cpu));
  REQUIRE_DEVICE(g);
  BodyDef d = boxBody({0, 0, 10}, {0.2f, 0.4f, 0.8f});
  d.gravityScale = 0;
  d.angularVelocity = {1, 2, 3};
  BodyId gs = add(g, d), cs = add(c, d);
  const Vec3 L0 = angularMomentum(state(g, gs));
  for (int i = 0; i < 600; ++i) {
    g.step();
    c.step();
  }
  const BodyState a = state(g, gs), b = state(c, cs);
  const Vec3 L = angularMomentum(a);
  EXPECT_LT(length(L - L0) / length(L0), 1e-3f);
  // The same splitting on both: the orientations agree to float rounding growth.
  const float align = std::abs(a.rotation.x * b.rotation.x + a.rotation.y * b.rotation.y +
                               a.rotation.z * b.rotation.z + a.rotation.w * b.rotation.w);
  EXPECT_GT(align, 1 - 1e-5f);
  EXPECT_LT(length(a.angularVelocity - b.angularVelocity), 1e-3f);
}

// Fast-spinning bodies keep their angular momentum on the device as well as on the CPU. The
// gyroscopic step computes as the CPU does (integrate_positions.comp): sin and cos evaluated
// in double and rounded once, as libm's sinf and cosf; IEEE division and square root; no fused
// multiply-adds. A device's own sin and cos may be far coarser (NVIDIA's: an absolute error
// near 2^-21, a relative error of 1e-5 and more on a substep's small angles): with them
// free_flight's drift was 1.19e-3 on an H200 against the CPU's 7.60e-4 (bound 1e-3).
TEST(GpuBodies, SpinningBodiesKeepAngularMomentumAsOnTheCpu) {
  World g(gpuDef()), c(gpuDef(Backend::Cpu));
  REQUIRE_DEVICE(g);
  const Vec3 spins[] = {{1, 2, 3}, {40, -0.5f, 0.25f}, {-7, 30, 90}};
  BodyId gi[3], ci[3];
  Vec3 L0[3];
  for (int i = 0; i < 3; ++i) {
    BodyDef d = boxBody({3.0f * i, 0, 10}, {0.2f, 0.4f + 0.1f * i, 0.8f});
    d.gravityScale = 0;
    d.angularVelocity = spins[i];
    gi[i] = add(g, d);
    ci[i] = add(c, d);
    L0[i] = angularMomentum(state(c, ci[i]));
  }
  for (int i = 0; i < 240; ++i) {
    g.step();
    c.step();
  }
  EXPECT_EQ(g.backendState().cpuSteps, 0u);
  for (int i = 0; i < 3; ++i) {
    SCOPED_TRACE("body " + std::to_string(i));
    const BodyState a = state(g, gi[i]), b = state(c, ci[i]);
    const float driftGpu = length(angularMomentum(a) - L0[i]) / length(L0[i]);
    const float driftCpu = length(angularMomentum(b) - L0[i]) / length(L0[i]);
    // On lavapipe the two agree to 15 %; the device's own sin and cos emulated (2^-21 of
    // noise) gave 3.7 times the CPU's drift on the second body.
    EXPECT_LE(driftGpu, std::max(2 * driftCpu, 1e-6f)) << "cpu " << driftCpu;
  }
}

TEST(GpuBodies, KinematicBodyMovesAtItsVelocity) {
  World g(gpuDef());
  REQUIRE_DEVICE(g);
  BodyDef d = boxBody({0, 0, 1}, {0.5f, 0.5f, 0.5f}, BodyType::Kinematic);
  d.linearVelocity = {1, 0, 0};
  d.angularVelocity = {0, 0, 0.5f};
  BodyId k = add(g, d);
  for (int i = 0; i < 60; ++i) g.step();
  const BodyState s = state(g, k);
  EXPECT_NEAR(s.position.x, 1, 1e-4f);
  EXPECT_NEAR(s.position.z, 1, 1e-6f);  // no gravity on a kinematic body
  EXPECT_NEAR(s.linearVelocity.x, 1, 1e-6f);
  // Turned by 0.5 rad about z (to the plain update's O((w h)^3) per substep).
  EXPECT_NEAR(2 * std::atan2(s.rotation.z, s.rotation.w), 0.5f, 1e-4f);
}

TEST(GpuBodies, EditsBetweenStepsReachTheDevice) {
  World g(gpuDef());
  REQUIRE_DEVICE(g);
  BodyDef d = sphereBody({0, 0, 50}, 0.5f);
  d.gravityScale = 0;
  BodyId a = add(g, d), b = add(g, sphereBody({5, 0, 50}, 0.5f));
  g.step();
  // A new velocity, a teleport and a one-step force, each seen by the next step only.
  ASSERT_TRUE(g.setVelocity(a, {2, 0, 0}, {}).ok());
  g.step();
  EXPECT_NEAR(state(g, a).linearVelocity.x, 2, 1e-6f);
  EXPECT_NEAR(state(g, a).position.x, 2.0f / 60, 1e-5f);
  ASSERT_TRUE(g.setTransform(a, {10, 0, 50}, {}).ok());
  const float m = state(g, a).mass;
  ASSERT_TRUE(g.applyForce(a, {0, m * 6, 0}, state(g, a).centerOfMass).ok());
  g.step();
  EXPECT_NEAR(state(g, a).linearVelocity.y, 6.0f / 60, 1e-5f);
  EXPECT_NEAR(state(g, a).position.x, 10 + 2.0f / 60, 1e-5f);
  g.step();  // the force lasted one step
  EXPECT_NEAR(state(g, a).linearVelocity.y, 6.0f / 60, 1e-5f);
  // Destroying a body re-uploads the rest; the other body kept falling all along.
  const float vz = state(g, b).linearVelocity.z;
  ASSERT_TRUE(g.destroyBody(a).ok());
  g.step();
  EXPECT_NEAR(state(g, b).linearVelocity.z, vz - 9.81f / 60, 1e-4f);
  EXPECT_EQ(g.backendState().cpuSteps, 0u);
}

TEST(GpuBodies, RunsAreBitIdentical) {
  auto run = [] {
    World g(gpuDef());
    if (g.backendState().active != Backend::Gpu) return uint64_t(0);
    for (int i = 0; i < 20; ++i) {
      BodyDef d = boxBody({float(i), 0, 10 + float(i)}, {0.1f + 0.02f * float(i), 0.3f, 0.5f});
      d.angularVelocity = {0.3f * float(i), 1, -0.5f};
      d.linearVelocity = {0, float(i) * 0.1f, 5};
      add(g, d);
    }
    for (int i = 0; i < 100; ++i) g.step();
    return g.stateHash();
  };
  const uint64_t a = run();
  if (a == 0) GTEST_SKIP() << "no Vulkan device";
  EXPECT_EQ(a, run());
}

TEST(GpuBodies, SnapshotRestoredIntoAGpuWorldContinuesTheSame) {
  World g(gpuDef());
  REQUIRE_DEVICE(g);
  BodyDef d = boxBody({0, 0, 20}, {0.2f, 0.4f, 0.8f});
  d.angularVelocity = {1, 2, 3};
  add(g, d);
  for (int i = 0; i < 30; ++i) g.step();
  std::vector<uint8_t> snap;
  ASSERT_TRUE(g.saveSnapshot(&snap).ok());
  for (int i = 0; i < 30; ++i) g.step();
  const uint64_t expected = g.stateHash();
  World r(gpuDef());
  ASSERT_TRUE(r.restoreSnapshot(snap.data(), snap.size()).ok());
  EXPECT_EQ(r.def().backend, Backend::Gpu);  // the restoring world keeps its backend
  for (int i = 0; i < 30; ++i) r.step();
  EXPECT_EQ(r.stateHash(), expected);
  EXPECT_EQ(r.backendState().gpuSteps, 30u);
}

// ---------------------------------------------------------------------------------------------
// What the device does not cover yet is taken by the CPU

TEST(GpuFallback, ContactsWithAPositionPassAreSteppedByTheCpuWithTheReason) {
  WorldDef d = gpuDef();
  d.solver = jacobiSettings();
  // Jacobi with a nonlinear Gauss-Seidel position pass: a pairing the device does not run.
  d.solver.positionPass = SolverSettings::PositionPass::NonlinearGaussSeidel;
  d.solver.positionIterations = 4;
  WorldDef dc = d;
  dc.backend = Backend::Cpu;
  World g(d), c(dc);
  REQUIRE_DEVICE(g);
  for (World* w : {&g, &c}) {
    add(*w, groundBody());
    add(*w, boxBody({0, 0, 0.5f}));
  }
  for (int i = 0; i < 30; ++i) {
    g.step();
    c.step();
  }
  EXPECT_EQ(g.backendState().cpuSteps, 30u);
  EXPECT_NE(g.backendState().lastFallback.find("position pass's form"), std::string::npos)
      << g.backendState().lastFallback;
  // Every step was the CPU's: bit for bit the CPU world.
  EXPECT_EQ(g.stateHash(), c.stateHash());
}

TEST(GpuFallback, ABallFallsOnTheDeviceAndLandsOnTheCpu) {
  // With a pairing of scheme and position pass the device does not run, the free fall is
  // the device's and the steps with a contact the CPU's, from the same host mirror.
  WorldDef d = gpuDef();
  d.solver = jacobiSettings();
  d.solver.positionPass = SolverSettings::PositionPass::NonlinearGaussSeidel;
  d.solver.positionIterations = 4;
  World g(d);
  REQUIRE_DEVICE(g);
  add(g, groundBody());
  BodyId s = add(g, sphereBody({0, 0, 3}, 0.5f));
  for (int i = 0; i < 120; ++i) g.step();
  const BackendState& b = g.backendState();
  EXPECT_GT(b.gpuSteps, 20u);  // ~0.65 s of free fall before the bounds meet the ground
  EXPECT_GT(b.cpuSteps, 20u);
  const BodyState st = state(g, s);
  EXPECT_NEAR(st.position.z, 0.5f, 5e-3f);  // resting on the ground
  EXPECT_LT(length(st.linearVelocity), 0.05f);
}

TEST(GpuFallback, SceneFilesChooseTheBackend) {
  Scene scene;
  const char* json = R"({"name": "t", "world": {"backend": "gpu"},
    "bodies": [{"name": "b", "position": [0, 0, 5], "shapes": [{"type": "sphere", "radius": 0.5}]}]})";
  Status parsed = parseScene(json, "t.json", &scene);
  ASSERT_TRUE(parsed.ok()) << parsed.message;
  EXPECT_EQ(scene.world.backend, Backend::Gpu);
  Scene back;
  ASSERT_TRUE(parseScene(sceneToJson(scene), "again", &back).ok());
  EXPECT_EQ(back.world.backend, Backend::Gpu);
  Status st = parseScene(R"({"name": "t", "world": {"backend": "cuda"}})", "t.json", &scene);
  EXPECT_FALSE(st.ok());
  EXPECT_NE(st.message.find("world.backend"), std::string::npos) << st.message;
}

// ---------------------------------------------------------------------------------------------
// Contacts on the device (Jacobi): against the CPU's Jacobi and physical answers

/// A 5-box column and a sphere on the ground, stepped by both backends with one preset.
struct TwinWorlds {
  World gpu, cpu;
  std::vector<BodyId> g, c;
  explicit TwinWorlds(const SolverSettings& s)
      : gpu([&] {
          WorldDef d = gpuDef();
          d.solver = s;
          return d;
        }()),
        cpu([&] {
          WorldDef d = gpuDef(Backend::Cpu);
          d.solver = s;
          return d;
        }()) {
    for (int w = 0; w < 2; ++w) {
      World& world = w == 0 ? gpu : cpu;
      std::vector<BodyId>& ids = w == 0 ? g : c;
      add(world, groundBody());
      for (int i = 0; i < 5; ++i) ids.push_back(add(world, boxBody({0, 0, 0.5f + float(i)})));
      ids.push_back(add(world, sphereBody({3, 0, 2}, 0.5f)));
    }
  }
  void step(int n) {
    for (int i = 0; i < n; ++i) {
      gpu.step();
      cpu.step();
    }
  }
};

TEST(GpuContacts, JacobiStackAndBallMatchTheCpu) {
  for (bool soft : {true, false}) {
    SCOPED_TRACE(soft ? "soft" : "baumgarte");
    SolverSettings s = jacobiSettings(soft ? 4 : 1, soft ? 8 : 50);
    if (!soft) {
      s.stabilization = SolverSettings::Stabilization::Baumgarte;
      s.relaxIterations = 0;
    }
    TwinWorlds t(s);
    REQUIRE_DEVICE(t.gpu);
    t.step(120);
    EXPECT_EQ(t.gpu.backendState().gpuSteps, 120u);
    EXPECT_GT(t.gpu.stats().contacts, 5);
    for (size_t i = 0; i < t.g.size(); ++i) {
      const BodyState a = state(t.gpu, t.g[i]), b = state(t.cpu, t.c[i]);
      SCOPED_TRACE("body " + std::to_string(i));
      // The same passes in the same order; only the device's rounding differs.
      EXPECT_LT(length(a.position - b.position), 1e-3f);
      EXPECT_LT(length(a.linearVelocity), 0.05f);  // at rest
    }
    // The column stands and the sphere rests on the ground.
    EXPECT_NEAR(state(t.gpu, t.g[4]).position.z, 4.5f, 0.02f);
    EXPECT_LT(std::abs(state(t.gpu, t.g[4]).position.x), 0.01f);
    EXPECT_NEAR(state(t.gpu, t.g[5]).position.z, 0.5f, 0.01f);
    // The step's report: the contacts and their penetration, as the CPU's.
    EXPECT_EQ(t.gpu.stats().contacts, t.cpu.stats().contacts);
    EXPECT_EQ(t.gpu.stats().contactPoints, t.cpu.stats().contactPoints);
    EXPECT_NEAR(t.gpu.stats().maxPenetration, t.cpu.stats().maxPenetration, 1e-3);
  }
}

TEST(GpuContacts, RunsWithContactsAreBitIdentical) {
  // The column knocked over by the ball: many contacts changing every step, with Jacobi
  // (tjsoft's settings) and with Gauss-Seidel on colors (the default preset).
  for (bool jacobi : {true, false}) {
    SCOPED_TRACE(jacobi ? "jacobi" : "colors");
    auto run = [&] {
      TwinWorlds t(jacobi ? jacobiSettings() : SolverSettings{});
      if (t.gpu.backendState().active != Backend::Gpu) return uint64_t(0);
      t.gpu.setVelocity(t.g[5], {-8, 0, 3}, {});
      for (int i = 0; i < 60; ++i) t.gpu.step();
      return t.gpu.stateHash();
    };
    const uint64_t a = run();
    if (a == 0) GTEST_SKIP() << "no Vulkan device";
    EXPECT_EQ(a, run());
  }
}

TEST(GpuContacts, SoftStepOnColorsHoldsTheStackAsTheCpu) {
  // The default preset (soft_step: Gauss-Seidel, patch friction, 6 substeps): on the device
  // the contacts are solved color by color, on the CPU in one fixed order, so the two agree
  // on the physics, not to the bit.
  TwinWorlds t{SolverSettings{}};
  REQUIRE_DEVICE(t.gpu);
  t.gpu.setVelocity(t.g[5], {0, 3, 0}, {});  // the ball rolls away: friction and twist work
  t.cpu.setVelocity(t.c[5], {0, 3, 0}, {});
  t.step(120);
  EXPECT_EQ(t.gpu.backendState().gpuSteps, 120u);
  for (int i = 0; i < 5; ++i) {
    const BodyState a = state(t.gpu, t.g[size_t(i)]), b = state(t.cpu, t.c[size_t(i)]);
    SCOPED_TRACE("box " + std::to_string(i));
    EXPECT_NEAR(a.position.z, 0.5f + float(i), 5e-3f);
    EXPECT_LT(std::hypot(a.position.x, a.position.y), 2e-3f);
    EXPECT_LT(length(a.position - b.position), 5e-3f);
  }
  const BodyState ball = state(t.gpu, t.g[5]), cpuBall = state(t.cpu, t.c[5]);
  EXPECT_NEAR(ball.position.z, 0.5f, 5e-3f);
  EXPECT_LT(length(ball.position - cpuBall.position), 0.02f);  // rolling at the same speed
  EXPECT_LT(length(ball.linearVelocity - cpuBall.linearVelocity), 0.02f);
}

TEST(GpuContacts, PositionPassesMatchTheCpu) {
  // pjnj (Jacobi + nonlinear Jacobi) matches the CPU's to rounding; pgs_ngs (nonlinear
  // Gauss-Seidel, on colors on the device) agrees on the physics.
  for (bool jacobi : {true, false}) {
    SCOPED_TRACE(jacobi ? "pjnj" : "pgs_ngs");
    SolverSettings s = jacobiSettings(1, jacobi ? 50 : 10);
    s.stabilization = SolverSettings::Stabilization::Baumgarte;
    s.baumgarte = 0;
    s.relaxIterations = 0;
    s.positionIterations = jacobi ? 4 : 1;
    s.positionPass = jacobi ? SolverSettings::PositionPass::NonlinearJacobi
                            : SolverSettings::PositionPass::NonlinearGaussSeidel;
    if (!jacobi) s.scheme = SolverSettings::Scheme::GaussSeidel;
    TwinWorlds t(s);
    REQUIRE_DEVICE(t.gpu);
    t.step(120);
    EXPECT_EQ(t.gpu.backendState().gpuSteps, 120u);
    EXPECT_GT(t.gpu.profile().positionPass, 0);
    for (size_t i = 0; i < t.g.size(); ++i) {
      const BodyState a = state(t.gpu, t.g[i]), b = state(t.cpu, t.c[i]);
      SCOPED_TRACE("body " + std::to_string(i));
      EXPECT_LT(length(a.position - b.position), jacobi ? 1e-3f : 5e-3f);
    }
    EXPECT_NEAR(state(t.gpu, t.g[4]).position.z, 4.5f, 0.02f);
    EXPECT_LT(t.gpu.stats().maxPenetration, 0.01);
  }
}

// ---------------------------------------------------------------------------------------------
// Joints on the device

/// A chain of `links` boxes swinging from a world anchor by joints of one type, its last
/// link `endMass` kg, in a GPU and a CPU world with the same (iterative-joint) settings.
struct TwinChains {
  World gpu, cpu;
  std::vector<BodyId> g, c;
  std::vector<JointId> gj, cj;
  TwinChains(const SolverSettings& s, JointType type, int links, float endMass)
      : gpu(def(s, Backend::Gpu)), cpu(def(s, Backend::Cpu)) {
    for (int w = 0; w < 2; ++w) {
      World& world = w == 0 ? gpu : cpu;
      BodyId prev;
      for (int i = 0; i < links; ++i) {
        BodyId id = add(world, boxBody({0.5f + float(i), 0, 5}, {0.4f, 0.1f, 0.1f}));
        JointDef j;
        j.type = type;
        j.bodyA = prev;
        j.bodyB = id;
        j.anchorA = prev.isNull() ? Vec3{0, 0, 5} : Vec3{0.5f, 0, 0};
        j.anchorB = {-0.5f, 0, 0};
        j.axisA = j.axisB = {0, 1, 0};
        if (type == JointType::Prismatic) j.axisA = j.axisB = {1, 0, 0};
        if (type == JointType::Distance) {  // rods of 0.2 m between the links' ends
          j.anchorA = prev.isNull() ? Vec3{-0.1f, 0, 5} : Vec3{0.4f, 0, 0};
          j.anchorB = {-0.4f, 0, 0};
        }
        JointId jid;
        EXPECT_TRUE(world.createJoint(j, &jid).ok());
        (w == 0 ? g : c).push_back(id);
        (w == 0 ? gj : cj).push_back(jid);
        prev = id;
      }
      if (endMass > 0) {
        EXPECT_TRUE(world.setMass(prev, endMass).ok());
      }
    }
  }
  /// The two worlds agree: every link within `position` m of its twin, the first joint's
  /// error within `error` m and its reaction on B within `reaction` of the CPU's (relative,
  /// plus 1 N).
  void expectAgree(float position, float error, float reaction) const {
    for (size_t i = 0; i < g.size(); ++i) {
      SCOPED_TRACE("link " + std::to_string(i));
      EXPECT_LT(length(state(gpu, g[i]).position - state(cpu, c[i]).position), position);
    }
    JointState a, b;
    ASSERT_TRUE(gpu.getJoint(gj[0], nullptr, &a).ok());
    ASSERT_TRUE(cpu.getJoint(cj[0], nullptr, &b).ok());
    EXPECT_NEAR(a.positionError, b.positionError, error);
    EXPECT_LT(length(a.reactionForce - b.reactionForce), reaction * length(b.reactionForce) + 1);
  }
  static WorldDef def(const SolverSettings& s, Backend b) {
    WorldDef d = gpuDef(b);
    d.solver = s;
    return d;
  }
};

TEST(GpuJoints, EveryJointTypeMatchesTheCpu) {
  // Both schemes: Jacobi matches the CPU's to rounding; Gauss-Seidel on colors (a chain:
  // two colors) is another order than the CPU's sweep, and agrees closely.
  for (bool jacobi : {true, false}) {
    SolverSettings s = jacobiSettings();
    s.geometricStiffness = false;
    if (!jacobi) {
      s = SolverSettings();
      s.equalitySolve = SolverSettings::EqualitySolve::Iterative;  // the device's joints
    }
    for (JointType type : {JointType::Ball, JointType::Hinge, JointType::Fixed,
                           JointType::Prismatic, JointType::Distance}) {
      SCOPED_TRACE(std::string(jacobi ? "jacobi " : "gauss-seidel ") + toString(type));
      TwinChains t(s, type, 5, 20);
      REQUIRE_DEVICE(t.gpu);
      for (int i = 0; i < 60; ++i) {
        t.gpu.step();
        t.cpu.step();
      }
      EXPECT_EQ(t.gpu.backendState().gpuSteps, 60u);
      EXPECT_EQ(t.gpu.stats().joints, 5);
      // The joints report what the CPU's do too: errors at the new poses, reactions.
      t.expectAgree(jacobi ? 1e-3f : 1e-2f, 2e-3f, 0.05f);
    }
  }
}

TEST(GpuJoints, HangingChainCarriesItsWeight) {
  // At rest the anchor joint carries the whole chain: 5 links of 8 kg and a 20 kg end.
  SolverSettings s;
  s.equalitySolve = SolverSettings::EqualitySolve::Iterative;
  TwinChains t(s, JointType::Ball, 5, 20);
  REQUIRE_DEVICE(t.gpu);
  for (BodyId id : t.g) {  // hang straight down: rotate the chain to vertical
    BodyState st = state(t.gpu, id);
    ASSERT_TRUE(t.gpu
                    .setTransform(id, {0, 0, 5 - st.position.x},
                                  normalize(Quat{0, 0.70710678f, 0, 0.70710678f}))
                    .ok());
  }
  for (int i = 0; i < 120; ++i) t.gpu.step();
  double mass = 0;
  for (BodyId id : t.g) mass += state(t.gpu, id).mass;
  JointState a;
  ASSERT_TRUE(t.gpu.getJoint(t.gj[0], nullptr, &a).ok());
  EXPECT_NEAR(a.reactionForce.z, mass * 9.81, 0.02 * mass * 9.81);
  EXPECT_LT(a.positionError, 5e-3f);
  EXPECT_LT(length(state(t.gpu, t.g.back()).linearVelocity), 0.05f);
}

TEST(GpuJoints, AStaticBodyCanBeEitherSide) {
  // A pendulum hung from a static body, once as body A and once as body B: the same motion
  // as the CPU's, all on the device.
  for (bool staticIsB : {false, true}) {
    SCOPED_TRACE(staticIsB ? "static B" : "static A");
    SolverSettings s;
    s.equalitySolve = SolverSettings::EqualitySolve::Iterative;
    World g(TwinChains::def(s, Backend::Gpu)), c(TwinChains::def(s, Backend::Cpu));
    REQUIRE_DEVICE(g);
    BodyId gb, cb;
    for (World* w : {&g, &c}) {
      BodyId post = add(*w, boxBody({0, 0, 5}, {0.1f, 0.1f, 0.1f}, BodyType::Static));
      BodyId bob = add(*w, sphereBody({1, 0, 5}, 0.2f));
      JointDef j;
      j.type = JointType::Ball;
      j.bodyA = staticIsB ? bob : post;
      j.bodyB = staticIsB ? post : bob;
      j.anchorA = staticIsB ? Vec3{-1, 0, 0} : Vec3{};
      j.anchorB = staticIsB ? Vec3{} : Vec3{-1, 0, 0};
      ASSERT_TRUE(w->createJoint(j, nullptr).ok());
      (w == &g ? gb : cb) = bob;
    }
    for (int i = 0; i < 60; ++i) {
      g.step();
      c.step();
    }
    EXPECT_EQ(g.backendState().cpuSteps, 0u);
    const BodyState a = state(g, gb), b = state(c, cb);
    EXPECT_LT(length(a.position - b.position), 2e-3f);
    EXPECT_NEAR(length(a.position - Vec3{0, 0, 5}), 1, 5e-3f);  // still 1 m from the post
  }
}

using test::worstJointError;

TEST(GpuJoints, DirectSolveMatchesTheCpuForEveryJointType) {
  // The default preset (soft_step) solves the joints' equality rows with the LDL hybrid on
  // both backends; limits, motors and springs stay in the colored passes. Every joint type,
  // with its limits and a motor where it has them, a spring for the distance joint.
  for (int variant = 0; variant < 7; ++variant) {
    const JointType types[] = {JointType::Ball,    JointType::Hinge,     JointType::Hinge,
                               JointType::Fixed,   JointType::Prismatic, JointType::Distance,
                               JointType::Distance};
    const JointType type = types[variant];
    const bool extras = variant == 2 || variant == 4 || variant == 6;
    SCOPED_TRACE(std::string(toString(type)) + (extras ? " with limits/motor/spring" : ""));
    SolverSettings s;
    ASSERT_EQ(s.equalitySolve, SolverSettings::EqualitySolve::DirectLdl);
    TwinChains t(s, type, 5, 20);
    REQUIRE_DEVICE(t.gpu);
    if (extras) {
      for (World* w : {&t.gpu, &t.cpu}) {
        const std::vector<JointId>& ids = w == &t.gpu ? t.gj : t.cj;
        // Rebuild the chain's joints with limits (and a motor on the first).
        JointDef j;
        ASSERT_TRUE(w->getJoint(ids[1], &j, nullptr).ok());
        ASSERT_TRUE(w->destroyJoint(ids[1]).ok());
        j.enableLimit = true;
        j.lower = type == JointType::Distance ? 0.15f : -0.3f;
        j.upper = type == JointType::Distance ? 0.25f : 0.3f;
        if (type == JointType::Distance) {
          j.springHertz = 4;
          j.springDampingRatio = 0.5f;
        }
        ASSERT_TRUE(w->createJoint(j, nullptr).ok());
        if (type != JointType::Distance) {
          ASSERT_TRUE(w->setMotor(ids[0], true, 0.5f, 50).ok());
        }
      }
    }
    for (int i = 0; i < 60; ++i) {
      t.gpu.step();
      t.cpu.step();
    }
    EXPECT_EQ(t.gpu.backendState().gpuSteps, 60u);
    t.expectAgree(2e-3f, 1e-3f, 0.02f);
  }
}

TEST(GpuJoints, DirectSolveHoldsAThousandToOneChain) {
  // SCENES.md's ball_and_chain in small: 20 links of 1 kg and a 1000 kg ball, released
  // horizontally. The LDL hybrid keeps every joint within 1 cm on the device as on the CPU,
  // and the ball follows the CPU's. (The scene itself, 40 links, where iterated joints
  // stretch 25 cm: ctest's scene.gpu.ball_and_chain for 1 s, tools/device_scenes.sh for its
  // 60 s.)
  auto run = [](SolverSettings::EqualitySolve eq, Backend backend) {
    SolverSettings s;
    s.equalitySolve = eq;
    TwinChains t(s, JointType::Ball, 20, 1000);
    World& w = backend == Backend::Gpu ? t.gpu : t.cpu;
    const std::vector<JointId>& ids = backend == Backend::Gpu ? t.gj : t.cj;
    float worst = 0;
    for (int i = 0; i < 60; ++i) {
      w.step();
      worst = std::max(worst, worstJointError(w, ids));
    }
    if (backend == Backend::Gpu) {
      EXPECT_EQ(w.backendState().cpuSteps, 0u);
    }
    return std::make_pair(worst, state(w, (backend == Backend::Gpu ? t.g : t.c).back()));
  };
  {
    World probe(gpuDef());
    REQUIRE_DEVICE(probe);
  }
  const auto [gpuDirect, gpuBall] = run(SolverSettings::EqualitySolve::DirectLdl, Backend::Gpu);
  const auto [cpuDirect, cpuBall] = run(SolverSettings::EqualitySolve::DirectLdl, Backend::Cpu);
  EXPECT_LT(gpuDirect, 0.01f);
  EXPECT_LT(cpuDirect, 0.01f);
  EXPECT_LT(length(gpuBall.position - cpuBall.position), 5e-3f);
  EXPECT_LT(length(gpuBall.linearVelocity - cpuBall.linearVelocity), 0.05f);
}

TEST(GpuJoints, RunsWithJointsAreBitIdentical) {
  // A 20-link chain with a 1000 kg ball, released: the joints' LDL solve in double precision
  // (the default preset) and the joints iterated with Jacobi (tjsoft's settings), each run
  // twice on the device from the same start.
  for (bool jacobi : {false, true}) {
    SCOPED_TRACE(jacobi ? "jacobi, iterated joints" : "soft_step, LDL");
    auto run = [&] {
      TwinChains t(jacobi ? jacobiSettings() : SolverSettings{}, JointType::Ball, 20, 1000);
      if (t.gpu.backendState().active != Backend::Gpu) return uint64_t(0);
      for (int i = 0; i < 60; ++i) t.gpu.step();
      EXPECT_EQ(t.gpu.backendState().cpuSteps, 0u) << t.gpu.backendState().lastFallback;
      return t.gpu.stateHash();
    };
    const uint64_t a = run();
    if (a == 0) GTEST_SKIP() << "no Vulkan device";
    EXPECT_EQ(a, run());
  }
}

TEST(GpuJoints, DirectSolveFollowsABodyTurnedKinematic) {
  // Rows couple through dynamic bodies only, so the device plans its solve again when a body
  // stops being dynamic and again when it is dynamic once more (then its two neighbours'
  // joints are one island, no longer two): the chain's middle link is held still for a
  // while, then let go, on both backends alike.
  SolverSettings s;
  TwinChains t(s, JointType::Hinge, 6, 5);
  REQUIRE_DEVICE(t.gpu);
  for (int i = 0; i < 80; ++i) {
    if (i == 0 || i == 40) {
      const BodyType type = i == 0 ? BodyType::Kinematic : BodyType::Dynamic;
      for (World* w : {&t.gpu, &t.cpu}) {
        const BodyId id = (w == &t.gpu ? t.g : t.c)[2];
        ASSERT_TRUE(w->setBodyType(id, type).ok());
        ASSERT_TRUE(w->setVelocity(id, {}, {}).ok());  // held still, then let go from rest
      }
    }
    t.gpu.step();
    t.cpu.step();
  }
  EXPECT_EQ(t.gpu.backendState().cpuSteps, 0u);
  EXPECT_LT(worstJointError(t.gpu, t.gj), 0.01f);
  for (size_t i = 0; i < t.g.size(); ++i) {
    SCOPED_TRACE("link " + std::to_string(i));
    // The same solve on both backends: rounding apart (a stale plan misses by 5 mm).
    EXPECT_LT(length(state(t.gpu, t.g[i]).position - state(t.cpu, t.c[i]).position), 2e-4f);
  }
}

TEST(GpuJoints, JoinedBodiesDoNotCollideUnlessAsked) {
  for (bool collide : {false, true}) {
    WorldDef d = gpuDef();
    d.solver = jacobiSettings();
    d.gravity = {};
    World g(d);
    REQUIRE_DEVICE(g);
    BodyId a = add(g, boxBody({0, 0, 5})), b = add(g, boxBody({0.8f, 0, 5}));  // overlapping
    JointDef j;
    j.type = JointType::Ball;
    j.bodyA = a;
    j.bodyB = b;
    j.anchorA = {0.4f, 0, 0};
    j.anchorB = {-0.4f, 0, 0};
    j.collideConnected = collide;
    ASSERT_TRUE(g.createJoint(j, nullptr).ok());
    g.step();
    EXPECT_EQ(g.stats().contacts > 0, collide);
    EXPECT_EQ(g.backendState().cpuSteps, 0u);
  }
}

TEST(GpuContacts, BallBouncesToTheRestitutionHeight) {
  WorldDef d = gpuDef();
  d.solver = jacobiSettings();
  World g(d);
  REQUIRE_DEVICE(g);
  add(g, groundBody(0.6f, 0.5f));
  BodyDef ball = sphereBody({0, 0, 1.5f}, 0.5f);
  ball.shapes[0].material.restitution = 0.5f;
  BodyId s = add(g, ball);
  // Dropped from 1 m (bottom 1 m above the ground): rebounds to e^2 * 1 m = 0.25 m.
  float apex = 0;
  bool bounced = false;
  for (int i = 0; i < 120; ++i) {
    g.step();
    const BodyState b = state(g, s);
    if (b.linearVelocity.z > 0.5f) bounced = true;
    if (bounced) apex = std::max(apex, b.position.z - 0.5f);
  }
  EXPECT_TRUE(bounced);
  EXPECT_NEAR(apex, 0.25f, 0.25f * 0.05f);
  EXPECT_EQ(g.backendState().cpuSteps, 0u);
}

TEST(GpuContacts, SplitPushOutSeparatesBuriedBoxesAsTheCpu) {
  // A column of four 0.5 m cubes each 0.2 m into the one below, the lowest 0.2 m into the
  // ground, and a row of five beside it each 0.15 m into its neighbour: soft_step pushes
  // penetration beyond 1 cm out with pseudo velocities on both backends, so the boxes come
  // apart without being launched (each contact's own push would add up to 12 m/s at the
  // top of the column).
  SolverSettings s;
  ASSERT_TRUE(s.splitPushout);
  World g(TwinChains::def(s, Backend::Gpu)), c(TwinChains::def(s, Backend::Cpu));
  REQUIRE_DEVICE(g);
  std::vector<BodyId> gb, cb;
  for (World* w : {&g, &c}) {
    add(*w, groundBody(0.6f, 0));
    for (int i = 0; i < 4; ++i)
      (w == &g ? gb : cb)
          .push_back(add(*w, boxBody({0, 0, 0.05f + 0.3f * float(i)}, {0.25f, 0.25f, 0.25f})));
    for (int i = 0; i < 5; ++i)
      (w == &g ? gb : cb)
          .push_back(add(*w, boxBody({2 + 0.35f * float(i), 0, 0.25f}, {0.25f, 0.25f, 0.25f})));
  }
  float fastest = 0;
  for (int i = 0; i < 60; ++i) {
    g.step();
    c.step();
    for (BodyId id : gb) fastest = std::max(fastest, length(state(g, id).linearVelocity));
  }
  EXPECT_EQ(g.backendState().cpuSteps, 0u);
  EXPECT_LT(fastest, 3.0f);
  EXPECT_LT(g.stats().maxPenetration, 0.01);
  // The column stands box on box; the row has spread (where each box ends depends on the
  // order the contacts are solved in, colors or the CPU's sweep: a centimetre or two).
  for (int i = 0; i < 4; ++i) {
    SCOPED_TRACE("column box " + std::to_string(i));
    EXPECT_NEAR(state(g, gb[size_t(i)]).position.z, 0.25f + 0.5f * float(i), 0.01f);
    EXPECT_NEAR(state(c, cb[size_t(i)]).position.z, 0.25f + 0.5f * float(i), 0.01f);
  }
  for (size_t i = 0; i < gb.size(); ++i) {
    SCOPED_TRACE("box " + std::to_string(i));
    EXPECT_LT(length(state(g, gb[i]).position - state(c, cb[i]).position), 0.03f);
  }
  // Without the split the column's top box leaves far faster than 3 m/s (what it is for).
  s.splitPushout = false;
  World u(TwinChains::def(s, Backend::Gpu));
  std::vector<BodyId> ub;
  add(u, groundBody(0.6f, 0));
  for (int i = 0; i < 4; ++i)
    ub.push_back(add(u, boxBody({0, 0, 0.05f + 0.3f * float(i)}, {0.25f, 0.25f, 0.25f})));
  float unsplit = 0;
  for (int i = 0; i < 30; ++i) {
    u.step();
    for (BodyId id : ub) unsplit = std::max(unsplit, length(state(u, id).linearVelocity));
  }
  EXPECT_GT(unsplit, 3.0f);
}

TEST(GpuContacts, SplitPushOutMovesWhatAJointHoldsAsTheCpu) {
  // test::addBuriedJointedPair without gravity (the CPU's SplitPushout.PushOutMovesWhatAJoint-
  // Holds), 45 steps: the push-out's pseudo velocities obey the joint on the device too,
  // through joint_ldl.comp's push mode (joints solved directly) or contact_gs.comp's
  // pushJointOne (iterated).
  struct Run {
    float jointErrorMax = 0, heavyX = 0;
    uint64_t cpuSteps = 0;
    bool onDevice = true;
  };
  auto run = [](Backend backend, JointType type, SolverSettings s) {
    WorldDef d = TwinChains::def(s, backend);
    d.gravity = {0, 0, 0};
    World w(d);
    Run r;
    r.onDevice = w.backendState().active == Backend::Gpu;
    test::BuriedJointedPair pair;
    const Status st = test::addBuriedJointedPair(w, type, &pair);
    EXPECT_TRUE(st.ok()) << st.message;
    for (int i = 0; i < 45; ++i) {
      w.step();
      JointState js;
      EXPECT_TRUE(w.getJoint(pair.joint, nullptr, &js).ok());
      r.jointErrorMax = std::max(r.jointErrorMax, js.positionError);
    }
    r.heavyX = state(w, pair.heavy).position.x;
    r.cpuSteps = w.backendState().cpuSteps;
    return r;
  };
  SolverSettings s;  // soft_step: joints solved directly, split push-out
  for (JointType type : {JointType::Ball, JointType::Prismatic}) {
    SCOPED_TRACE(toString(type));
    const Run g = run(Backend::Gpu, type, s), c = run(Backend::Cpu, type, s);
    if (!g.onDevice) GTEST_SKIP() << "no Vulkan device";
    EXPECT_EQ(g.cpuSteps, 0u);
    EXPECT_LT(g.jointErrorMax, 0.001f);  // 1.3-1.5 cm when the push-out ignored the joint
    EXPECT_LT(c.jointErrorMax, 0.001f);
    EXPECT_GT(g.heavyX, 0.62f + 0.05f);  // the heavy box came out with the light one
    EXPECT_NEAR(g.heavyX, c.heavyX, 0.02f);
  }
  // Iterated joints (they do not converge at 500:1): the push-out adds no error to what the
  // velocity push leaves. 8 iterations, the ball joint only: the device's colored passes are
  // slow on a CPU implementation.
  s.equalitySolve = SolverSettings::EqualitySolve::Iterative;
  s.iterations = 8;
  const Run split = run(Backend::Gpu, JointType::Ball, s);
  s.splitPushout = false;
  const Run velocityPush = run(Backend::Gpu, JointType::Ball, s);
  EXPECT_LT(split.jointErrorMax, velocityPush.jointErrorMax);
  EXPECT_GT(split.heavyX, 0.62f + 0.05f);
}

}  // namespace
}  // namespace phys
