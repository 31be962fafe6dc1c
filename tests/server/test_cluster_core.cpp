// A daemon of a domain of daemons ([cluster], docs/SERVER.md "Several daemons"): its world
// ids and which commands it takes (ServerCore::takes), without DDS.
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

}  // namespace
}  // namespace phys::server::test
