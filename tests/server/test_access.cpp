// Access to worlds (docs/SERVER.md "Access", issue 24 point 4b): the client that creates a
// world owns it; others may read it (QueryState, Subscribe, snapshot bytes) but their edits
// are refused with PermissionDenied and change nothing, unless the owner names them editors
// or shares the world. Start-up worlds have no owner.
#include "server_test_util.h"

namespace phys::server::test {
namespace {

using protocol::CommandBuilder;

constexpr uint64_t kOwner = 0x0A, kOther = 0x0B, kEditor = 0x0E;

struct AccessTest : ::testing::Test {
  void SetUp() override {
    ASSERT_TRUE(core.init().ok());
    Reply r = send(kOwner, CommandBuilder().createWorld({"mine", "", std::nullopt, 0}), 0);
    ASSERT_EQ(r->status(), Code::Ok) << message(r);
    world = r->world();
    std::vector<phys::BodyDef> defs{boxBody({0, 0, 1}), groundBody()};
    r = send(kOwner, CommandBuilder().spawnBodies(defs), world);
    ASSERT_EQ(r->status(), Code::Ok);
    body = bodyIds(r).at(0);
  }
  Reply send(uint64_t client, CommandBuilder& b, uint32_t w) {
    ++seq;
    return decode(core.applyBytes(b.finish({client, seq, w}), client, seq));
  }
  uint64_t hash() { return core.world(world)->world->stateHash(); }
  ServerCore core{testConfig()};
  uint32_t world = 0;
  uint64_t body = 0, seq = 0;
};

TEST_F(AccessTest, OthersReadButTheirEditsAreRefusedAndChangeNothing) {
  const uint64_t before = hash();
  const uint64_t tick = core.world(world)->tick;
  std::vector<std::pair<const char*, CommandBuilder>> edits;
  edits.emplace_back("step", std::move(CommandBuilder().step(3)));
  edits.emplace_back("set_body_pose", std::move(CommandBuilder().setBodyPose(body, {1, 2, 3}, {})));
  edits.emplace_back("apply_impulse", std::move(CommandBuilder().applyImpulse(body, {0, 0, 5})));
  edits.emplace_back("spawn_bodies", std::move(CommandBuilder().spawnBodies(
                                         std::vector<phys::BodyDef>{boxBody({3, 0, 1})})));
  edits.emplace_back("run", std::move(CommandBuilder().run(60)));
  edits.emplace_back("reset_world", std::move(CommandBuilder().resetWorld()));
  edits.emplace_back("set_solver", std::move(CommandBuilder().setSolver("pgs")));
  edits.emplace_back("destroy_world", std::move(CommandBuilder().destroyWorld()));
  edits.emplace_back("set_access", std::move(CommandBuilder().setAccess(
                                       std::vector<uint64_t>{kOther}, true)));
  edits.emplace_back("save_snapshot", std::move(CommandBuilder().saveSnapshot("other.snap")));
  for (auto& [name, b] : edits) {
    Reply r = send(kOther, b, world);
    EXPECT_EQ(r->status(), Code::PermissionDenied) << name << ": " << message(r);
    EXPECT_NE(message(r).find("belongs to client 0xa"), std::string::npos) << message(r);
  }
  EXPECT_EQ(hash(), before);
  EXPECT_EQ(core.world(world)->tick, tick);
  EXPECT_EQ(core.world(world)->mode, RunMode::Paused);
  EXPECT_EQ(core.world(world)->world->bodyCount(), 2);
  // Reads work.
  EXPECT_EQ(send(kOther, CommandBuilder().queryState(), world)->status(), Code::Ok);
  Reply sub = send(kOther, CommandBuilder().subscribeRegion({-5, -5, -5}, {5, 5, 5}), world);
  ASSERT_EQ(sub->status(), Code::Ok);
  EXPECT_EQ(send(kOther, CommandBuilder().saveSnapshot(), world)->status(), Code::Ok);
  EXPECT_EQ(send(kOther, CommandBuilder().listWorlds(), 0)->status(), Code::Ok);
  // A subscriber may end its own interest; another client may not end it for it.
  const uint32_t interest = sub->result_as_InterestResult()->interest();
  Reply sub2 = send(kOwner, CommandBuilder().subscribeRegion({-5, -5, -5}, {5, 5, 5}), world);
  const uint32_t ownerInterest = sub2->result_as_InterestResult()->interest();
  EXPECT_EQ(send(kOther, CommandBuilder().unsubscribe(ownerInterest), world)->status(),
            Code::PermissionDenied);
  EXPECT_EQ(send(kOther, CommandBuilder().unsubscribe(interest), world)->status(), Code::Ok);
  // The owner does what it likes.
  EXPECT_EQ(send(kOwner, CommandBuilder().step(2), world)->status(), Code::Ok);
}

TEST_F(AccessTest, EditorsEditSharedWorldsAreOpenOnlyTheOwnerDestroys) {
  ASSERT_EQ(send(kOwner, CommandBuilder().setAccess(std::vector<uint64_t>{kEditor}, false), world)
                ->status(),
            Code::Ok);
  EXPECT_EQ(send(kEditor, CommandBuilder().step(2), world)->status(), Code::Ok);
  EXPECT_EQ(send(kEditor, CommandBuilder().applyImpulse(body, {0, 0, 1}), world)->status(),
            Code::Ok);
  EXPECT_EQ(send(kEditor, CommandBuilder().destroyWorld(), world)->status(),
            Code::PermissionDenied);
  EXPECT_EQ(send(kEditor, CommandBuilder().setAccess({}, true), world)->status(),
            Code::PermissionDenied);
  EXPECT_EQ(send(kOther, CommandBuilder().step(1), world)->status(), Code::PermissionDenied);
  // Shared: anyone edits; the list is replaced.
  ASSERT_EQ(send(kOwner, CommandBuilder().setAccess({}, true), world)->status(), Code::Ok);
  EXPECT_EQ(send(kOther, CommandBuilder().step(1), world)->status(), Code::Ok);
  EXPECT_EQ(send(kOther, CommandBuilder().destroyWorld(), world)->status(),
            Code::PermissionDenied);
  ASSERT_EQ(send(kOwner, CommandBuilder().setAccess({}, false), world)->status(), Code::Ok);
  EXPECT_EQ(send(kEditor, CommandBuilder().step(1), world)->status(), Code::PermissionDenied);
  // Editors given at creation; bad lists are refused by the codec.
  protocol::CreateWorldArgs args{"team", "", std::nullopt, 0};
  args.editors = {kEditor};
  Reply r = send(kOwner, CommandBuilder().createWorld(args), 0);
  ASSERT_EQ(r->status(), Code::Ok);
  EXPECT_EQ(send(kEditor, CommandBuilder().step(1), r->world())->status(), Code::Ok);
  EXPECT_EQ(send(kOwner, CommandBuilder().setAccess(std::vector<uint64_t>{0}, false), world)
                ->status(),
            Code::InvalidArgument);
  EXPECT_EQ(send(kOwner, CommandBuilder().setAccess(std::vector<uint64_t>(257, 1), false), world)
                ->status(),
            Code::ResourceExhausted);
  EXPECT_EQ(send(kOwner, CommandBuilder().destroyWorld(), world)->status(), Code::Ok);
}

TEST_F(AccessTest, ANonEditorsPauseDoesNotEndTheOwnersStep) {
  // Pause, ResetWorld and DestroyWorld end a running Step job, but only when the client may.
  auto submit = [&](uint64_t client, CommandBuilder& b) {
    core.submit(queuedCommand(client, ++seq, b, world));
  };
  std::vector<phys::BodyDef> defs;
  for (int i = 0; i < 300; ++i) defs.push_back(boxBody({float(i % 20) * 2, float(i / 20) * 2, 1}));
  ASSERT_EQ(send(kOwner, CommandBuilder().spawnBodies(defs), world)->status(), Code::Ok);
  submit(kOwner, CommandBuilder().step(20000));
  core.processPending();
  ASSERT_TRUE(core.world(world)->busy());
  submit(kOther, CommandBuilder().pause());
  core.processPending();
  EXPECT_TRUE(core.world(world)->busy());
  bool refused = false;
  for (const Reply& r : takeReplies(core)) {
    EXPECT_EQ(r->client_id(), kOther) << "only the refusal is answered yet";
    refused |= r->status() == Code::PermissionDenied;
  }
  EXPECT_TRUE(refused);
}

TEST_F(AccessTest, StartUpWorldsHaveNoOwner) {
  uint32_t id = 0;
  ASSERT_TRUE(core.createWorld("startup", "", "", &id).ok());
  EXPECT_EQ(core.world(id)->owner, 0u);
  EXPECT_EQ(send(kOther, CommandBuilder().step(1), id)->status(), Code::Ok);
  EXPECT_EQ(send(kEditor, CommandBuilder().destroyWorld(), id)->status(), Code::Ok);
}

/// Issue 39 point 4: on a daemon without DDS Security a client id is a number anyone may
/// write into a command. A world whose creator proved its id (Hello with its key's binding
/// proof: Incoming::proven) can be changed as its owner or an editor only by commands whose
/// sender proved its id too; a command that merely carries the id is refused and changes
/// nothing. (On the old code the same id was enough: every edit below succeeded.)
struct ProvenAccessTest : ::testing::Test {
  void SetUp() override {
    ASSERT_TRUE(core.init().ok());
    Reply r = send(kOwner, CommandBuilder().createWorld({"proven", "", std::nullopt, 0}), 0, true);
    ASSERT_EQ(r->status(), Code::Ok) << message(r);
    world = r->world();
    ASSERT_TRUE(core.world(world)->ownerProven);
    std::vector<phys::BodyDef> defs{boxBody({0, 0, 1}), groundBody()};
    r = send(kOwner, CommandBuilder().spawnBodies(defs), world, true);
    ASSERT_EQ(r->status(), Code::Ok) << message(r);
    body = bodyIds(r).at(0);
  }
  /// A command as it arrives from a participant that did (proven) or did not prove its id.
  Reply send(uint64_t client, CommandBuilder& b, uint32_t w, bool proven) {
    ++seq;
    Incoming in = queuedCommand(client, seq, b, w);
    in.proven = proven;
    return decode(core.apply(in));
  }
  uint64_t hash() { return core.world(world)->world->stateHash(); }
  ServerCore core{testConfig()};
  uint32_t world = 0;
  uint64_t body = 0, seq = 0;
};

TEST_F(ProvenAccessTest, TheOwnersIdWithoutItsProofChangesNothing) {
  const uint64_t before = hash();
  std::vector<std::pair<const char*, CommandBuilder>> edits;
  edits.emplace_back("step", std::move(CommandBuilder().step(3)));
  edits.emplace_back("set_body_pose", std::move(CommandBuilder().setBodyPose(body, {1, 2, 3}, {})));
  edits.emplace_back("reset_world", std::move(CommandBuilder().resetWorld()));
  edits.emplace_back("set_access", std::move(CommandBuilder().setAccess(
                                       std::vector<uint64_t>{kOther}, true)));
  edits.emplace_back("destroy_world", std::move(CommandBuilder().destroyWorld()));
  for (auto& [name, b] : edits) {
    Reply r = send(kOwner, b, world, false);
    EXPECT_EQ(r->status(), Code::PermissionDenied) << name << ": " << message(r);
    EXPECT_NE(message(r).find("has not proved its id"), std::string::npos) << message(r);
  }
  EXPECT_EQ(hash(), before);
  EXPECT_EQ(core.world(world)->tick, 0u);
  EXPECT_FALSE(core.world(world)->shared);
  // Reads stay open to all.
  EXPECT_EQ(send(kOwner, CommandBuilder().queryState(), world, false)->status(), Code::Ok);
  // The proven owner does what it likes.
  EXPECT_EQ(send(kOwner, CommandBuilder().step(2), world, true)->status(), Code::Ok);
  EXPECT_EQ(core.world(world)->tick, 2u);
}

TEST_F(ProvenAccessTest, EditorsOfAProvenWorldProveTheirIdsSharedWorldsStayOpen) {
  ASSERT_EQ(send(kOwner, CommandBuilder().setAccess(std::vector<uint64_t>{kEditor}, false), world,
                 true)
                ->status(),
            Code::Ok);
  EXPECT_EQ(send(kEditor, CommandBuilder().step(1), world, false)->status(),
            Code::PermissionDenied);
  EXPECT_EQ(send(kEditor, CommandBuilder().step(1), world, true)->status(), Code::Ok);
  // Shared: every client edits, proven or not; only the proven owner owns.
  ASSERT_EQ(send(kOwner, CommandBuilder().setAccess({}, true), world, true)->status(), Code::Ok);
  EXPECT_EQ(send(kOther, CommandBuilder().step(1), world, false)->status(), Code::Ok);
  EXPECT_EQ(send(kOwner, CommandBuilder().destroyWorld(), world, false)->status(),
            Code::PermissionDenied);
}

TEST_F(ProvenAccessTest, WorldsOfUnprovenCreatorsKeepThePlainIdRuleAndHelloSaysWhatWasProven) {
  Reply r = send(kOther, CommandBuilder().createWorld({"plain", "", std::nullopt, 0}), 0, false);
  ASSERT_EQ(r->status(), Code::Ok) << message(r);
  const uint32_t plain = r->world();
  EXPECT_FALSE(core.world(plain)->ownerProven);
  EXPECT_EQ(send(kOther, CommandBuilder().step(1), plain, false)->status(), Code::Ok);
  EXPECT_EQ(send(kOwner, CommandBuilder().step(1), plain, true)->status(),
            Code::PermissionDenied);
  for (bool proven : {false, true}) {
    Reply h = send(kOther, CommandBuilder().hello("t"), 0, proven);
    ASSERT_EQ(h->status(), Code::Ok);
    EXPECT_EQ(h->result_as_HelloResult()->client_proven(), proven);
  }
}

}  // namespace
}  // namespace phys::server::test
