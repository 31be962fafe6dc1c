// configs/physd.toml parsing, and core behaviour that depends on configured limits.
#include <filesystem>

#include "phys/server/config.h"
#include "server_test_util.h"

namespace phys::server::test {
namespace {

using protocol::CommandBuilder;

TEST(ServerConfig, ShippedConfigLoads) {
  DaemonConfig c;
  Status s = loadDaemonConfig(std::string(PHYS_SOURCE_DIR) + "/configs/physd.toml", &c);
  ASSERT_TRUE(s.ok()) << s.message;
  EXPECT_EQ(c.core.serverName, "physd");
  EXPECT_EQ(c.domain, 0u);
  EXPECT_TRUE(std::filesystem::exists(c.cycloneConfig)) << c.cycloneConfig;
  EXPECT_TRUE(std::filesystem::exists(c.core.presetsFile)) << c.core.presetsFile;
  EXPECT_TRUE(std::filesystem::is_directory(c.core.scenesDir)) << c.core.scenesDir;
  ASSERT_EQ(c.worlds.size(), 1u);
  EXPECT_EQ(c.worlds[0].scene, "default");
  EXPECT_TRUE(c.worlds[0].run);
  // CI has no GPU: the shipped default keeps worlds on the CPU.
  EXPECT_EQ(c.core.backend, phys::Backend::Cpu);
  EXPECT_FALSE(c.core.gpuAllowCpuDevice);
  EXPECT_EQ(c.worlds[0].backend, "");
  // Worlds are kept on disk, checkpointed every 30 s (here: in a scratch directory, not in
  // the shipped /tmp/physd/data that a running physd may be using).
  EXPECT_EQ(c.core.dataDir, "/tmp/physd/data");
  EXPECT_EQ(c.core.checkpointPeriodS, 30);
  EXPECT_EQ(c.core.journalMaxBytes, 64u << 20);
  EXPECT_FALSE(c.worlds[0].ephemeral);
  const auto data =
      std::filesystem::temp_directory_path() / ("physd_shipped_" + std::to_string(getpid()));
  c.core.dataDir = data.string();
  // The start-up world of the shipped config can be created.
  ServerCore core(c.core);
  ASSERT_TRUE(core.init().ok());
  uint32_t id = 0;
  s = core.createWorld(c.worlds[0].name, c.worlds[0].preset, c.worlds[0].scene, &id);
  ASSERT_TRUE(s.ok()) << s.message;
  EXPECT_GT(core.world(id)->world->bodyCount(), 0);
  EXPECT_EQ(core.counters().commands, 0u);
  EXPECT_TRUE(std::filesystem::exists(data / "worlds" / std::to_string(id) / "checkpoint"));
  std::filesystem::remove_all(data);
}

TEST(ServerConfig, RejectsUnknownKeysAndWrongTypes) {
  DaemonConfig c;
  Status s = parseDaemonConfig("[server]\nnmae = \"x\"\n", "/tmp", &c);
  EXPECT_FALSE(s.ok());
  EXPECT_NE(s.message.find("nmae"), std::string::npos) << s.message;
  EXPECT_FALSE(parseDaemonConfig("[dds]\ndomain = \"seven\"\n", "/tmp", &c).ok());
  EXPECT_FALSE(parseDaemonConfig("[dds]\ndomain = -1\n", "/tmp", &c).ok());
  EXPECT_FALSE(parseDaemonConfig("[[worlds]]\nscene = \"default\"\n", "/tmp", &c).ok());
  EXPECT_FALSE(parseDaemonConfig("this is not toml", "/tmp", &c).ok());
  s = parseDaemonConfig("[server]\nrealtime_priority = 100\n", "/tmp", &c);
  EXPECT_FALSE(s.ok());
  EXPECT_NE(s.message.find("realtime_priority"), std::string::npos) << s.message;
  EXPECT_FALSE(parseDaemonConfig("[server]\nrealtime_priority = -1\n", "/tmp", &c).ok());
  s = parseDaemonConfig(
      "[server]\nrealtime_priority = 10\n[dds]\ndomain = 9\nconfig = "
      "\"x.xml\"\n[limits]\nmax_steps_per_command = 10\n"
      "[[worlds]]\nname = \"a\"\nrun = false\n",
      "/base", &c);
  ASSERT_TRUE(s.ok()) << s.message;
  EXPECT_EQ(c.domain, 9u);
  EXPECT_EQ(c.realtimePriority, 10);
  EXPECT_EQ(c.cycloneConfig, "/base/x.xml");
  EXPECT_EQ(c.core.limits.maxStepsPerCommand, 10u);
  ASSERT_EQ(c.worlds.size(), 1u);
  EXPECT_FALSE(c.worlds[0].run);
}

TEST(ServerConfig, TwoWordKeys) {
  // refresh and state_encoding: each one of two words, its default without the key.
  DaemonConfig c;
  Status s = parseDaemonConfig("", "/tmp", &c);
  ASSERT_TRUE(s.ok()) << s.message;
  EXPECT_TRUE(c.core.rollingRefresh);
  EXPECT_FALSE(c.core.compactStates);
  s = parseDaemonConfig("[server]\nrefresh = \"keyframe\"\nstate_encoding = \"compact\"\n",
                        "/tmp", &c);
  ASSERT_TRUE(s.ok()) << s.message;
  EXPECT_FALSE(c.core.rollingRefresh);
  EXPECT_TRUE(c.core.compactStates);
  s = parseDaemonConfig("[server]\nrefresh = \"Rolling\"\n", "/tmp", &c);
  EXPECT_EQ(s.code, Code::InvalidArgument);
  EXPECT_NE(s.message.find("server.refresh must be \"rolling\" or \"keyframe\", got \"Rolling\""),
            std::string::npos)
      << s.message;
  s = parseDaemonConfig("[server]\nstate_encoding = \"half\"\n", "/tmp", &c);
  EXPECT_NE(s.message.find("server.state_encoding must be \"full\" or \"compact\", got \"half\""),
            std::string::npos)
      << s.message;
}

TEST(ServerConfig, LivelinessLease) {
  // dds.liveliness_s: 1 s without the key, 0 turns it off, anything else out of range fails.
  DaemonConfig c;
  ASSERT_TRUE(parseDaemonConfig("", "/tmp", &c).ok());
  EXPECT_EQ(c.livelinessS, 1.0);
  for (const char* ok : {"0", "0.05", "2.5"}) {
    Status s = parseDaemonConfig(std::string("[dds]\nliveliness_s = ") + ok + "\n", "/tmp", &c);
    EXPECT_TRUE(s.ok()) << ok << ": " << s.message;
    EXPECT_EQ(c.livelinessS, std::stod(ok));
  }
  for (const char* bad : {"-1", "0.01", "1e9", "nan"}) {
    Status s = parseDaemonConfig(std::string("[dds]\nliveliness_s = ") + bad + "\n", "/tmp", &c);
    EXPECT_EQ(s.code, Code::InvalidArgument) << bad;
    EXPECT_NE(s.message.find("dds.liveliness_s"), std::string::npos) << s.message;
  }
}

TEST(ServerConfig, Backend) {
  DaemonConfig c;
  Status s = parseDaemonConfig("", "/tmp", &c);
  ASSERT_TRUE(s.ok()) << s.message;
  EXPECT_EQ(c.core.backend, phys::Backend::Cpu);  // without the keys
  EXPECT_FALSE(c.core.gpuAllowCpuDevice);
  for (auto [text, want] :
       {std::pair{"cpu", phys::Backend::Cpu}, std::pair{"gpu", phys::Backend::Gpu},
        std::pair{"auto", phys::Backend::Auto}}) {
    s = parseDaemonConfig(std::string("[server]\nbackend = \"") + text +
                              "\"\ngpu_allow_cpu_device = true\n"
                              "[[worlds]]\nname = \"a\"\nbackend = \"" +
                              text + "\"\n[[worlds]]\nname = \"b\"\n",
                          "/tmp", &c);
    ASSERT_TRUE(s.ok()) << text << ": " << s.message;
    EXPECT_EQ(c.core.backend, want) << text;
    EXPECT_TRUE(c.core.gpuAllowCpuDevice);
    ASSERT_EQ(c.worlds.size(), 2u);
    EXPECT_EQ(c.worlds[0].backend, text);
    EXPECT_EQ(c.worlds[1].backend, "");  // server.backend
  }
  // Unknown names, wrong case and wrong types are config errors that name the key.
  for (const char* bad : {"GPU", "cuda", "", "cpu "}) {
    s = parseDaemonConfig(std::string("[server]\nbackend = \"") + bad + "\"\n", "/tmp", &c);
    EXPECT_FALSE(s.ok()) << bad;
    EXPECT_EQ(s.code, Code::InvalidArgument);
    EXPECT_NE(s.message.find("server.backend must be \"cpu\", \"gpu\" or \"auto\", got \"" +
                             std::string(bad) + "\""),
              std::string::npos)
        << s.message;
    s = parseDaemonConfig(std::string("[[worlds]]\nname = \"a\"\nbackend = \"") + bad + "\"\n",
                          "/tmp", &c);
    EXPECT_FALSE(s.ok()) << bad;
    EXPECT_NE(s.message.find("worlds[0].backend must be"), std::string::npos) << s.message;
  }
  s = parseDaemonConfig("[server]\nbackend = 1\n", "/tmp", &c);
  EXPECT_FALSE(s.ok());
  EXPECT_NE(s.message.find("server.backend"), std::string::npos) << s.message;
  s = parseDaemonConfig("[server]\ngpu_allow_cpu_device = \"yes\"\n", "/tmp", &c);
  EXPECT_FALSE(s.ok());
  EXPECT_NE(s.message.find("server.gpu_allow_cpu_device"), std::string::npos) << s.message;
}

TEST(ServerConfig, Security) {
  DaemonConfig c;
  Status s = parseDaemonConfig("", "/etc/physd", &c);
  ASSERT_TRUE(s.ok()) << s.message;
  EXPECT_FALSE(c.security.enabled());
  s = parseDaemonConfig("[security]\ndir = \"sec\"\nidentity = \"physd\"\n", "/etc/physd", &c);
  ASSERT_TRUE(s.ok()) << s.message;
  EXPECT_TRUE(c.security.enabled());
  EXPECT_EQ(c.security.certificate, "/etc/physd/sec/physd_cert.pem");  // relative to the file
  EXPECT_EQ(c.security.permissions, "/etc/physd/sec/permissions.p7s");
  EXPECT_EQ(c.security.pluginDir, "");  // Debian's
  // Both keys are needed, the name is what make_security.sh accepts, no unknown keys.
  for (const char* bad : {"[security]\ndir = \"sec\"\n", "[security]\nidentity = \"physd\"\n",
                          "[security]\ndir = \"sec\"\nidentity = \"a b\"\n",
                          "[security]\ndir = \"sec\"\nidentity = \"physd\"\ncert = \"x\"\n"}) {
    s = parseDaemonConfig(bad, "/etc/physd", &c);
    EXPECT_FALSE(s.ok()) << bad;
    EXPECT_NE(s.message.find("security"), std::string::npos) << s.message;
  }
}

TEST(ServerConfig, BadStartupWorldFails) {
  ServerCore core(testConfig());
  ASSERT_TRUE(core.init().ok());
  uint32_t id = 0;
  EXPECT_EQ(core.createWorld("a", "", "no_such_scene", &id).code, Code::NotFound);
  EXPECT_TRUE(core.worldIds().empty());
  EXPECT_EQ(core.createWorld("a", "no_such_preset", "", &id).code, Code::NotFound);
  ASSERT_TRUE(core.createWorld("a", "", "", &id).ok());
  EXPECT_EQ(core.createWorld("a", "", "", &id).code, Code::InvalidArgument);
}

TEST(ServerLimits, SnapshotTooLargeForAReplyGoesToAFile) {
  CoreConfig cfg = testConfig();
  cfg.limits.maxMessageBytes = 8192;
  ServerCore core(cfg);
  ASSERT_TRUE(core.init().ok());
  uint32_t world = 0;
  ASSERT_TRUE(core.createWorld("big", "", "", &world).ok());
  std::vector<phys::BodyDef> defs;
  for (int i = 0; i < 40; ++i) defs.push_back(boxBody({float(i) * 2, 0, 1}));
  Reply r = decode(
      core.applyBytes(CommandBuilder().spawnBodies(defs).finish({kClient, 1, world}), kClient, 1));
  ASSERT_EQ(r->status(), Code::Ok) << message(r);
  r = decode(
      core.applyBytes(CommandBuilder().saveSnapshot().finish({kClient, 2, world}), kClient, 2));
  EXPECT_EQ(r->status(), Code::ResourceExhausted) << message(r);
  r = decode(core.applyBytes(
      CommandBuilder().saveSnapshot("big.snap", false).finish({kClient, 3, world}), kClient, 3));
  EXPECT_EQ(r->status(), Code::Ok) << message(r);
  std::error_code ec;
  std::filesystem::remove_all(cfg.snapshotDir, ec);
}

TEST(ServerLimits, MaxWorlds) {
  CoreConfig cfg = testConfig();
  cfg.maxWorlds = 2;
  ServerCore core(cfg);
  ASSERT_TRUE(core.init().ok());
  for (int i = 0; i < 3; ++i) {
    protocol::CreateWorldArgs a;
    a.name = "w" + std::to_string(i);
    Reply r = decode(
        core.applyBytes(CommandBuilder().createWorld(a).finish({kClient, 1, 0}), kClient, 1));
    EXPECT_EQ(r->status(), i < 2 ? Code::Ok : Code::ResourceExhausted) << message(r);
  }
}

TEST(ServerFrames, StalledPublisherKeepsTheNewestTicks) {
  ServerCore core(testConfig());  // frame ring of 4
  ASSERT_TRUE(core.init().ok());
  uint32_t world = 0;
  ASSERT_TRUE(core.createWorld("f", "", "box_stack", &world).ok());
  ASSERT_TRUE(core.setRun(world, RunMode::AsFastAsPossible, 0).ok());
  for (int i = 0; i < 10; ++i) EXPECT_EQ(core.advance(0), 1u);  // nobody pops
  EXPECT_EQ(core.out().framesQueued(), 4u);
  EXPECT_GE(core.out().framesDropped(), 6u);
  std::vector<uint64_t> ticks;
  for (;;) {
    auto item = core.out().pop(std::chrono::milliseconds(0));
    if (item.frame) ticks.push_back(item.frame->tick);
    if (!item.frame && !item.reliable) break;
  }
  EXPECT_EQ(ticks, (std::vector<uint64_t>{7, 8, 9, 10}));
  EXPECT_EQ(core.world(world)->tick, 10u);
}

}  // namespace
}  // namespace phys::server::test
