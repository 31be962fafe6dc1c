// Standby and takeover, the tick thread's side (server/src/takeover.cpp; docs/SERVER.md
// "Standby and takeover"), without etcd or DDS: what the coordinator thread would tell a core
// (a world registered, its hold renewed, a world to stand by for, to take over, to let go) is
// told by hand, and two cores on two data directories play the owner and its standby.
#include <filesystem>

#include "../common/bodies.h"
#include "phys/protocol/cluster.h"
#include "phys/server/config.h"
#include "server_test_util.h"

namespace phys::server::test {
namespace {

namespace fs = std::filesystem;
using protocol::CommandBuilder;
using Note = ServerCore::OwnershipNote;
using Clock = std::chrono::steady_clock;

fs::path scratch(const std::string& what) {
  fs::path p = fs::temp_directory_path() /
               ("physd_takeover_" + what + "_" + std::to_string(getpid()));
  fs::remove_all(p);
  return p;
}

/// A daemon of a cluster with a coordinator (never contacted: no coordinator thread runs here).
CoreConfig coordinated(const fs::path& data, uint64_t id, uint64_t standby) {
  CoreConfig c = testConfig();
  c.cluster = true;
  c.serverId = id;
  c.dataDir = data.string();
  c.coordinator = "http://127.0.0.1:9";
  c.standby = standby;
  return c;
}

Note note(Note::Kind kind, uint32_t world, uint64_t revision, uint64_t daemon,
          std::string dir = {}) {
  Note n;
  n.kind = kind;
  n.world = world;
  n.revision = revision;
  n.daemon = daemon;
  n.dir = std::move(dir);
  return n;
}

/// A few ticks of the core's loop (commands, steps, journals, replies).
void turn(ServerCore& core, int n = 3) {
  for (int i = 0; i < n; ++i) {
    core.processPending();
    core.advance(0);
  }
}

TEST(Takeover, ConfigNeedsAClusterKeptWorldsAndTimesInOrder) {
  const std::string base = "[server]\nid = 1\n[paths]\ndata = \"/tmp/physd_x\"\n";
  const std::string cluster = "[cluster]\nenabled = true\ncoordinator = \"http://127.0.0.1:2379\"\n";
  DaemonConfig c;
  Status s = parseDaemonConfig(base + cluster + "standby = 2\n", "/tmp", &c);
  ASSERT_TRUE(s.ok()) << s.message;
  EXPECT_EQ(c.core.coordinator, "http://127.0.0.1:2379");
  EXPECT_EQ(c.core.standby, 2u);
  EXPECT_LT(c.core.fenceAfterS, c.core.takeoverAfterS);
  const std::vector<std::pair<std::string, std::string>> bad = {
      {"[server]\nid = 1\n[paths]\ndata = \"/tmp/physd_x\"\n[cluster]\ncoordinator = "
       "\"http://127.0.0.1:2379\"\n",
       "[cluster] enabled"},
      {"[server]\nid = 1\n" + cluster, "[paths] data"},
      {base + cluster + "standby = 1\n", "another daemon"},
      {base + cluster + "fence_after_s = 0.5\ntakeover_after_s = 0.5\n", "fence_after_s"},
      {base + "[cluster]\nenabled = true\ncoordinator = \"127.0.0.1:2379\"\n", "http://"},
      {base + "[cluster]\nenabled = true\nstandby = 2\n", "coordinator"},
  };
  for (const auto& [toml, why] : bad) {
    s = parseDaemonConfig(toml, "/tmp", &c);
    EXPECT_FALSE(s.ok()) << toml;
    EXPECT_NE(s.message.find(why), std::string::npos) << s.message;
  }
}

// The owner's world is registered, stepped and edited; its standby replays the journal as it
// grows and, told to take over, holds the world at the owner's tick with the owner's state
// (every acknowledged command), from files of its own, in an epoch above the owner's. The
// owner, told that another daemon holds the world, lets it go and answers Moved.
TEST(Takeover, AStandbyTakesAWorldAtItsOwnersTickWithItsOwnersState) {
  const fs::path dataA = scratch("a"), dataB = scratch("b");
  auto a = startedCore(coordinated(dataA, 1, 2));
  auto b = startedCore(coordinated(dataB, 2, 1));
  a->holdUntil(Clock::now() + std::chrono::hours(1));
  b->holdUntil(Clock::now() + std::chrono::hours(1));
  uint32_t id = 0;
  ASSERT_TRUE(a->createWorld("w", "", "", &id).ok());
  CoreClient ca{a.get()};
  std::vector<phys::BodyDef> bodies{phys::test::groundBody()};
  for (int i = 0; i < 5; ++i) bodies.push_back(phys::test::boxBody({0.2f * float(i % 2), 0, 0.6f + 1.1f * float(i)}));
  const std::vector<uint64_t> ids = bodyIds(ca.send(CommandBuilder().spawnBodies(bodies), id));
  ASSERT_EQ(ids.size(), bodies.size());
  a->submitOwnership(note(Note::Kind::Registered, id, 7, 1));
  a->processPending();
  ASSERT_EQ(a->world(id)->ownership, 7u);
  EXPECT_GE(a->world(id)->epoch, uint64_t(7) << 32);
  ASSERT_EQ(ca.send(CommandBuilder().step(20), id)->status(), Code::Ok);

  // The standby follows: built from the checkpoint, the records replayed as they come.
  const std::string dir = fs::absolute(dataA / "worlds" / std::to_string(id)).string();
  b->standBy({{id, {dir, 1}}});
  b->processPending();
  ASSERT_EQ(ca.send(CommandBuilder().setBodyVelocity(ids[3], {1.5f, 0, 0}, {}), id)->status(), Code::Ok);
  ASSERT_EQ(ca.send(CommandBuilder().step(15), id)->status(), Code::Ok);
  std::this_thread::sleep_for(std::chrono::milliseconds(120));  // a renew period
  b->processPending();
  EXPECT_EQ(b->world(id), nullptr);  // a copy, not one of its worlds
  ASSERT_EQ(ca.send(CommandBuilder().applyImpulse(ids[4], {0, 0.8f, 0}), id)->status(), Code::Ok);
  ASSERT_EQ(ca.send(CommandBuilder().step(5), id)->status(), Code::Ok);

  b->submitOwnership(note(Note::Kind::TakeOver, id, 9, 1, dir));
  b->processPending();
  ServerWorld* taken = b->world(id);
  ASSERT_NE(taken, nullptr);
  const ServerWorld* original = a->world(id);
  EXPECT_EQ(taken->tick, original->tick);
  EXPECT_EQ(taken->tick, 40u);
  EXPECT_EQ(taken->world->stateHash(), original->world->stateHash());
  EXPECT_EQ(taken->ownership, 9u);
  EXPECT_GT(taken->epoch, original->epoch);
  EXPECT_TRUE(fs::exists(dataB / "worlds" / std::to_string(id) / "checkpoint"));
  // Stepped on alike.
  ASSERT_TRUE(a->stepWorld(id, 10).ok());
  ASSERT_TRUE(b->stepWorld(id, 10).ok());
  EXPECT_EQ(b->world(id)->world->stateHash(), a->world(id)->world->stateHash());

  // The owner lets go: a command that waited for it is answered Moved, to daemon 2.
  a->holdUntil(Clock::now() - std::chrono::seconds(1));  // its hold lapsed
  a->processPending();
  ca.submit(CommandBuilder().step(1), id);
  a->processPending();
  EXPECT_TRUE(takeReplies(*a).empty());  // fenced: the command waits
  a->submitOwnership(note(Note::Kind::StandDown, id, 9, 2));
  a->processPending();
  EXPECT_EQ(a->world(id), nullptr);
  const std::vector<Reply> replies = takeReplies(*a);
  ASSERT_EQ(replies.size(), 1u);
  EXPECT_EQ(replies[0]->status(), Code::Moved) << message(replies[0]);
  EXPECT_EQ(replies[0]->owner(), 2u);
  EXPECT_TRUE(fs::exists(dataA / "damaged"));  // its files kept for the operator
  a.reset();
  b.reset();
  fs::remove_all(dataA);
  fs::remove_all(dataB);
}

// A registered world is served only while the hold is renewed: its Step waits while the hold
// has lapsed and runs once it is renewed; a world not registered yet is served regardless.
// Restarted, a daemon serves a kept world only once the coordinator has confirmed it is still
// its own.
TEST(Takeover, ARegisteredWorldIsServedOnlyWhileTheHoldIsRenewed) {
  const fs::path data = scratch("hold");
  uint32_t id = 0, fresh = 0;
  {
    auto a = startedCore(coordinated(data, 1, 2));
    CoreClient c{a.get()};
    ASSERT_TRUE(a->createWorld("held", "", "", &id).ok());
    ASSERT_TRUE(a->createWorld("fresh", "", "", &fresh).ok());
    a->submitOwnership(note(Note::Kind::Registered, id, 5, 1));
    a->processPending();  // no renewal yet: the hold is lapsed
    c.submit(CommandBuilder().step(3), id);
    c.submit(CommandBuilder().step(3), fresh);
    turn(*a);
    std::vector<Reply> replies = takeReplies(*a);
    ASSERT_EQ(replies.size(), 1u);  // only the unregistered world's Step
    EXPECT_EQ(replies[0]->tick(), 3u);
    EXPECT_EQ(a->world(id)->tick, 0u);
    a->holdUntil(Clock::now() + std::chrono::hours(1));
    turn(*a);
    replies = takeReplies(*a);
    ASSERT_EQ(replies.size(), 1u);
    EXPECT_EQ(replies[0]->status(), Code::Ok) << message(replies[0]);
    EXPECT_EQ(a->world(id)->tick, 3u);
  }
  auto a = startedCore(coordinated(data, 1, 2));
  a->holdUntil(Clock::now() + std::chrono::hours(1));
  CoreClient c{a.get()};
  ASSERT_NE(a->world(id), nullptr);
  EXPECT_TRUE(a->world(id)->unconfirmed);
  c.submit(CommandBuilder().step(2), id);
  turn(*a);
  EXPECT_TRUE(takeReplies(*a).empty());  // not before the coordinator says so
  a->submitOwnership(note(Note::Kind::Registered, id, 11, 1));
  turn(*a);
  const std::vector<Reply> replies = takeReplies(*a);
  ASSERT_EQ(replies.size(), 1u);
  EXPECT_EQ(replies[0]->tick(), 5u);
  a.reset();
  fs::remove_all(data);
}

}  // namespace
}  // namespace phys::server::test
