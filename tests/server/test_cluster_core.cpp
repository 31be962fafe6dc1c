// A daemon of a domain of daemons ([cluster], docs/SERVER.md "Several daemons"): its world
// ids and which commands it takes (ServerCore::takes), without DDS.
#include <filesystem>
#include <fstream>

#include "phys/protocol/cluster.h"
#include "phys/server/config.h"
#include "server_test_util.h"

namespace phys::server::test {
namespace {

using protocol::CommandAddress;

TEST(ClusterCore, ConfigNeedsAnIdThatFitsTheWorldIds) {
  DaemonConfig c;
  Status s = parseDaemonConfig("[server]\nid = 7\n[cluster]\nenabled = true\n", "/tmp", &c);
  ASSERT_TRUE(s.ok()) << s.message;
  EXPECT_TRUE(c.core.cluster);
  EXPECT_EQ(c.core.serverId, 7u);
  s = parseDaemonConfig("[server]\nid = 4096\n[cluster]\nenabled = true\n", "/tmp", &c);
  EXPECT_FALSE(s.ok());
  EXPECT_NE(s.message.find("server.id"), std::string::npos) << s.message;
  // Alone, any non-zero id.
  EXPECT_TRUE(parseDaemonConfig("[server]\nid = 4096\n", "/tmp", &c).ok());
  EXPECT_FALSE(c.core.cluster);
  EXPECT_FALSE(parseDaemonConfig("[cluster]\nenabeld = true\n", "/tmp", &c).ok());
}

TEST(ClusterCore, WorldIdsAreOfTheDaemonsRange) {
  CoreConfig cfg = testConfig();
  cfg.cluster = true;
  cfg.serverId = 2;
  ServerCore core(cfg);
  ASSERT_TRUE(core.init().ok());
  uint32_t a = 0, b = 0;
  ASSERT_TRUE(core.createWorld("a", "", "", &a).ok());
  ASSERT_TRUE(core.createWorld("b", "", "", &b).ok());
  EXPECT_EQ(a, protocol::firstWorldIdOf(2));
  EXPECT_EQ(b, a + 1);
  const std::vector<protocol::WorldSummary> listed = core.summaries();
  ASSERT_EQ(listed.size(), 2u);
  for (const auto& w : listed) EXPECT_EQ(w.daemon, 2u);
  EXPECT_EQ(core.status().daemon, 2u);
  EXPECT_TRUE(core.status().cluster);

  // Addressed: only to this daemon.
  EXPECT_TRUE(core.takes(CommandAddress{0, 2, false}));
  EXPECT_FALSE(core.takes(CommandAddress{0, 3, false}));
  EXPECT_FALSE(core.takes(CommandAddress{a, 3, false}));
  // Unaddressed world commands: its own worlds and the rest of its range (answered NotFound),
  // not another daemon's range.
  EXPECT_TRUE(core.takes(CommandAddress{a, 0, false}));
  EXPECT_TRUE(core.takes(CommandAddress{a + 100, 0, false}));
  EXPECT_FALSE(core.takes(CommandAddress{protocol::firstWorldIdOf(3), 0, false}));
  EXPECT_FALSE(core.takes(CommandAddress{1, 0, false}));
  // Unaddressed without a world: Hello only (every daemon greets a client).
  EXPECT_TRUE(core.takes(CommandAddress{0, 0, true}));
  EXPECT_FALSE(core.takes(CommandAddress{0, 0, false}));
}

TEST(ClusterCore, ALoneDaemonTakesEveryUnaddressedCommand) {
  ServerCore core(testConfig());
  ASSERT_TRUE(core.init().ok());
  uint32_t a = 0;
  ASSERT_TRUE(core.createWorld("a", "", "", &a).ok());
  EXPECT_EQ(a, 1u);
  EXPECT_FALSE(core.status().cluster);
  EXPECT_TRUE(core.takes(CommandAddress{0, 0, false}));
  EXPECT_TRUE(core.takes(CommandAddress{protocol::firstWorldIdOf(3), 0, false}));
  EXPECT_TRUE(core.takes(CommandAddress{a, 1, false}));   // server.id 1
  EXPECT_FALSE(core.takes(CommandAddress{a, 2, false}));  // addressed to another daemon
}

TEST(ClusterCore, AWorldThatMovedAwayIsAnsweredMovedAlsoAfterARestart) {
  // What moves.cpp writes when a world leaves a durable daemon: its id and where it went.
  const auto data = std::filesystem::temp_directory_path() /
                    ("physd_moved_out_" + std::to_string(getpid()));
  std::filesystem::create_directories(data);
  const uint32_t gone = protocol::firstWorldIdOf(1) + 4;
  {
    std::ofstream f(data / "moved_out");
    f << gone << " 3\n";
  }
  CoreConfig cfg = testConfig();
  cfg.cluster = true;
  cfg.serverId = 1;
  cfg.dataDir = data.string();
  {
    ServerCore core(cfg);
    ASSERT_TRUE(core.init().ok());
    std::vector<std::string> notes;
    ASSERT_TRUE(core.restoreWorlds(&notes).ok());
    protocol::CommandBuilder b;
    Reply r = decode(core.applyBytes(b.step(1).finish({kClient, 1, gone}), kClient, 1));
    EXPECT_EQ(r->status(), wire::StatusCode::Moved) << message(r);
    EXPECT_EQ(r->owner(), 3u);
    // Another id of its range: never held here.
    r = decode(core.applyBytes(b.step(1).finish({kClient, 2, gone + 1}), kClient, 2));
    EXPECT_EQ(r->status(), wire::StatusCode::NotFound) << message(r);
    EXPECT_EQ(r->owner(), 0u);
    // A move to a daemon outside a cluster, or to itself: refused before anything moves.
    uint32_t id = 0;
    ASSERT_TRUE(core.createWorld("here", "", "", &id).ok());
    r = decode(core.applyBytes(b.moveWorld(1).finish({kClient, 3, id}), kClient, 3));
    EXPECT_EQ(r->status(), wire::StatusCode::InvalidArgument) << message(r);
  }
  std::filesystem::remove_all(data);
}

}  // namespace
}  // namespace phys::server::test
