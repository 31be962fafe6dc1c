// Worlds' backends through ServerCore (no DDS): CreateWorld's backend, the server's default,
// start-up worlds, LoadScene, and what ListWorlds and ServerStatus report.
#include <cstdlib>
#include <optional>

#include "phys/scene/scene.h"
#include "server_test_util.h"

namespace phys::server::test {
namespace {

using protocol::CommandBuilder;

/// PHYS_GPU_ALLOW_CPU=1 would let every GPU world use lavapipe: these tests decide with
/// WorldDef::gpuAllowCpuDevice (the config) alone.
class NoAllowCpuEnv {
 public:
  NoAllowCpuEnv() {
    if (const char* v = std::getenv("PHYS_GPU_ALLOW_CPU")) saved_ = v;
    unsetenv("PHYS_GPU_ALLOW_CPU");
  }
  ~NoAllowCpuEnv() {
    if (saved_) setenv("PHYS_GPU_ALLOW_CPU", saved_->c_str(), 1);
  }

 private:
  std::optional<std::string> saved_;
};

/// What the engine itself does with a GPU world here (the machine decides).
phys::BackendState engineGpuWorld(bool allowCpuDevice) {
  phys::WorldDef d;
  d.backend = phys::Backend::Gpu;
  d.gpuAllowCpuDevice = allowCpuDevice;
  d.threads = 1;
  phys::World w(d);
  return w.backendState();
}

class BackendTest : public ::testing::Test {
 protected:
  void start(bool allowCpuDevice, phys::Backend defaultBackend = phys::Backend::Cpu) {
    CoreConfig cfg = testConfig();
    cfg.gpuAllowCpuDevice = allowCpuDevice;
    cfg.backend = defaultBackend;
    core = std::make_unique<ServerCore>(cfg);
    ASSERT_TRUE(core->init().ok());
  }

  Reply send(CommandBuilder& b, uint32_t w) {
    ++seq;
    return decode(core->applyBytes(b.finish({kClient, seq, w}), kClient, seq));
  }
  /// A new world; 0 (and a test failure) when refused.
  uint32_t create(const std::string& name, const std::string& backend) {
    Reply r = send(CommandBuilder().createWorld({name, "", std::nullopt, 0, backend}), 0);
    EXPECT_EQ(r->status(), Code::Ok) << message(r);
    return r->status() == Code::Ok ? r->world() : 0;
  }
  /// The world's entry in a ListWorlds reply.
  protocol::WorldSummary listed(uint32_t world) {
    Reply r = send(CommandBuilder().listWorlds(), 0);
    EXPECT_EQ(r->status(), Code::Ok) << message(r);
    if (auto* l = r->result_as_WorldList())
      for (const wire::WorldSummary* w : *l->worlds())
        if (w->world() == world) return protocol::toWorldSummary(*w);
    ADD_FAILURE() << "world " << world << " not listed";
    return {};
  }
  phys::Backend setting(uint32_t world) { return core->world(world)->world->def().backend; }

  NoAllowCpuEnv env;
  std::unique_ptr<ServerCore> core;
  uint64_t seq = 0;
};

TEST_F(BackendTest, GpuWorldWithoutAGpuRunsOnTheCpuAndSaysWhy) {
  start(false);
  const phys::BackendState engine = engineGpuWorld(false);
  const uint32_t w = create("g", "gpu");
  ASSERT_NE(w, 0u);
  EXPECT_EQ(setting(w), phys::Backend::Gpu);
  EXPECT_FALSE(core->world(w)->world->def().gpuAllowCpuDevice);
  Reply r = send(CommandBuilder().spawnBodies(std::vector{groundBody(), boxBody({0, 0, 1})}), w);
  ASSERT_EQ(r->status(), Code::Ok) << message(r);
  ASSERT_EQ(send(CommandBuilder().step(3), w)->status(), Code::Ok);

  protocol::WorldSummary s = listed(w);
  EXPECT_EQ(s.backend, phys::toString(engine.active));
  EXPECT_EQ(s.gpuSteps + s.cpuSteps, 3u);
  if (engine.active == phys::Backend::Cpu) {
    // This machine's only Vulkan device (if any) is a CPU one, which the config does not
    // allow: the world runs on the CPU and the note says why.
    EXPECT_EQ(s.backend, "cpu");
    EXPECT_TRUE(s.device.empty()) << s.device;
    EXPECT_FALSE(s.backendNote.empty());
    EXPECT_EQ(s.backendNote, core->world(w)->world->backendState().note);
    EXPECT_EQ(s.cpuSteps, 3u);
    EXPECT_EQ(s.gpuSteps, 0u);
  } else {
    EXPECT_EQ(s.backend, "gpu");  // a real GPU
    EXPECT_FALSE(s.device.empty());
  }
  // ServerStatus reports the same.
  protocol::ServerStatusInfo st = core->status();
  ASSERT_EQ(st.worlds.size(), 1u);
  EXPECT_EQ(st.worlds[0].backend, s.backend);
  EXPECT_EQ(st.worlds[0].backendNote, s.backendNote);
  EXPECT_EQ(st.worlds[0].cpuSteps, s.cpuSteps);

  // A CPU world: "cpu", no device, no note, every step on the CPU.
  const uint32_t c = create("c", "cpu");
  ASSERT_NE(c, 0u);
  ASSERT_EQ(send(CommandBuilder().step(2), c)->status(), Code::Ok);
  protocol::WorldSummary cs = listed(c);
  EXPECT_EQ(cs.backend, "cpu");
  EXPECT_TRUE(cs.device.empty());
  EXPECT_TRUE(cs.backendNote.empty()) << cs.backendNote;
  EXPECT_EQ(cs.cpuSteps, 2u);
  EXPECT_EQ(cs.gpuSteps, 0u);
}

TEST_F(BackendTest, GpuWorldOnACpuDeviceWhenTheConfigAllowsIt) {
  start(true);
  const uint32_t w = create("lavapipe", "gpu");
  ASSERT_NE(w, 0u);
  EXPECT_TRUE(core->world(w)->world->def().gpuAllowCpuDevice);
  // The engine itself decides (a device is opened once, with the world: lavapipe takes tens
  // of seconds to build the pipelines, so there is no separate probe).
  const phys::BackendState& engine = core->world(w)->world->backendState();
  if (engine.active != phys::Backend::Gpu)
    GTEST_SKIP() << "no Vulkan device at all: " << engine.note;
  Reply r = send(CommandBuilder().spawnBodies(std::vector{groundBody(), boxBody({0, 0, 1})}), w);
  ASSERT_EQ(r->status(), Code::Ok) << message(r);
  ASSERT_EQ(send(CommandBuilder().step(3), w)->status(), Code::Ok);
  protocol::WorldSummary s = listed(w);
  EXPECT_EQ(s.backend, "gpu");
  EXPECT_FALSE(s.device.empty());
  EXPECT_EQ(s.device, core->world(w)->world->backendState().device);
  EXPECT_EQ(s.gpuSteps + s.cpuSteps, 3u);
  // A note only when some step fell back to the CPU, and then it says why.
  EXPECT_EQ(s.backendNote.empty(), s.cpuSteps == 0) << s.backendNote;
}

TEST_F(BackendTest, BadBackendIsRejectedAndChangesNothing) {
  start(false);
  const uint32_t w = create("a", "");
  ASSERT_NE(w, 0u);
  const uint64_t errors = core->counters().errors;
  Reply r = send(CommandBuilder().createWorld({"b", "", std::nullopt, 0, "quantum"}), 0);
  EXPECT_EQ(r->status(), Code::InvalidArgument);
  EXPECT_EQ(message(r),
            "create_world.backend must be \"cpu\", \"gpu\" or \"auto\" (or empty: the server's "
            "default), got \"quantum\"");
  EXPECT_EQ(r->world(), 0u);
  EXPECT_EQ(core->worldIds(), std::vector<uint32_t>{w});
  EXPECT_EQ(core->counters().errors, errors + 1);
  // The name is still free.
  EXPECT_NE(create("b", "cpu"), 0u);
}

TEST_F(BackendTest, CreateWorldsBackendElseTheServersDefault) {
  start(false, phys::Backend::Auto);
  EXPECT_EQ(setting(create("default", "")), phys::Backend::Auto);
  EXPECT_EQ(setting(create("cpu", "cpu")), phys::Backend::Cpu);
  EXPECT_EQ(setting(create("gpu", "gpu")), phys::Backend::Gpu);
  // Start-up worlds: the [[worlds]] entry's backend, else the default.
  uint32_t id = 0;
  ASSERT_TRUE(core->createWorld("startup_cpu", "", "", &id, "cpu").ok());
  EXPECT_EQ(setting(id), phys::Backend::Cpu);
  ASSERT_TRUE(core->createWorld("startup_default", "", "", &id).ok());
  EXPECT_EQ(setting(id), phys::Backend::Auto);
  EXPECT_EQ(core->createWorld("startup_bad", "", "", &id, "fast").code, Code::InvalidArgument);
  EXPECT_EQ(core->worldIds().size(), 5u);
}

TEST_F(BackendTest, LoadSceneKeepsTheWorldsBackendUnlessTheSceneAsksForAnother) {
  start(false);
  phys::Scene scene;
  scene.name = "inline";
  scene.bodies = {groundBody(), boxBody({0, 0, 2})};
  const std::string cpuScene = phys::sceneToJson(scene);  // "cpu": no backend key
  scene.world.backend = phys::Backend::Gpu;
  const std::string gpuScene = phys::sceneToJson(scene);
  scene.world.backend = phys::Backend::Auto;
  const std::string autoScene = phys::sceneToJson(scene);

  const uint32_t a = create("a", "auto");
  ASSERT_EQ(send(CommandBuilder().loadSceneJson(cpuScene), a)->status(), Code::Ok);
  EXPECT_EQ(setting(a), phys::Backend::Auto);
  EXPECT_FALSE(core->world(a)->world->def().gpuAllowCpuDevice);
  ASSERT_EQ(send(CommandBuilder().loadSceneJson(gpuScene), a)->status(), Code::Ok);
  EXPECT_EQ(setting(a), phys::Backend::Gpu);
  // Reset keeps it.
  ASSERT_EQ(send(CommandBuilder().resetWorld(), a)->status(), Code::Ok);
  EXPECT_EQ(setting(a), phys::Backend::Gpu);

  const uint32_t c = create("c", "cpu");
  ASSERT_EQ(send(CommandBuilder().loadSceneJson(autoScene), c)->status(), Code::Ok);
  EXPECT_EQ(setting(c), phys::Backend::Auto);
  ASSERT_EQ(send(CommandBuilder().loadSceneJson(cpuScene), c)->status(), Code::Ok);
  EXPECT_EQ(setting(c), phys::Backend::Auto);  // the world's current setting
  EXPECT_EQ(listed(c).backend, phys::toString(core->world(c)->world->backendState().active));
}

TEST_F(BackendTest, ConfigAllowsTheCpuDeviceForEveryWorld) {
  start(true);
  // A CPU world opens no device; the flag still travels with it (reset, load).
  const uint32_t w = create("w", "cpu");
  EXPECT_TRUE(core->world(w)->world->def().gpuAllowCpuDevice);
  ASSERT_EQ(send(CommandBuilder().loadSceneNamed("box_stack"), w)->status(), Code::Ok);
  EXPECT_TRUE(core->world(w)->world->def().gpuAllowCpuDevice);
  EXPECT_EQ(setting(w), phys::Backend::Cpu);
  EXPECT_EQ(listed(w).backend, "cpu");
}

}  // namespace
}  // namespace phys::server::test
