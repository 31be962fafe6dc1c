// Issue 39, finding 6: a read-only client took 63 of a world's 64 interest slots, the owner's
// Subscribe was refused, and interests outlived their client. Now each client holds at most
// server.max_interests_per_client interests in a world (a participant's ids together), the
// last ServerWorld::kInterestsForEditors slots are kept for the world's owner and editors, and
// a client's interests go when it leaves (ServerCore::clientsLeft, which the DDS endpoint calls
// when a participant's liveliness is lost; test_dds.cpp has that end of it).
#include <algorithm>

#include "server_test_util.h"

namespace phys::server::test {
namespace {

using protocol::CommandBuilder;

constexpr uint64_t kOwner = 0x0E1, kReader = 0x5EAD;

class InterestTest : public ::testing::Test {
 protected:
  void SetUp() override {
    ASSERT_TRUE(core.init().ok());
    Reply r = call(kOwner, CommandBuilder().createWorld({"owned", "", std::nullopt, 0}), 0);
    ASSERT_EQ(r->status(), Code::Ok) << message(r);
    world = r->world();
    const std::vector<phys::BodyDef> defs{groundBody(), boxBody({0, 0, 1})};
    r = call(kOwner, CommandBuilder().spawnBodies(defs), world);
    ASSERT_EQ(r->status(), Code::Ok) << message(r);
    bodies = bodyIds(r);
  }
  /// Through the queue, as the endpoint submits: `sender` is the participant (0: none).
  Reply call(uint64_t client, CommandBuilder& b, uint32_t w, uint64_t sender = 0) {
    Incoming in = queuedCommand(client, ++seq, b, w);
    in.sender = sender;
    core.submit(std::move(in));
    core.processPending();
    std::vector<Reply> r = takeReplies(core);
    EXPECT_EQ(r.size(), 1u);
    return r.empty() ? Reply{} : r.back();
  }
  Reply subscribe(uint64_t client, uint64_t sender = 0) {
    return call(client, CommandBuilder().subscribeBodies({&bodies[1], 1}), world, sender);
  }
  size_t interests() const { return core.world(world)->interests.size(); }

  ServerCore core{testConfig()};  // max_interests_per_client 8
  uint32_t world = 0;
  uint64_t seq = 0;
  std::vector<uint64_t> bodies;
};

TEST_F(InterestTest, AReaderHoldsItsQuotaAndTheOwnersSlotsStayFree) {
  // The finding: one read-only client subscribes over and over.
  int ok = 0;
  for (int i = 0; i < 64; ++i) {
    Reply r = subscribe(kReader);
    if (r->status() == Code::Ok) {
      ++ok;
      continue;
    }
    EXPECT_EQ(r->status(), Code::ResourceExhausted);
    EXPECT_NE(message(r).find("server.max_interests_per_client"), std::string::npos)
        << message(r);
  }
  EXPECT_EQ(ok, 8);
  // The owner subscribes.
  Reply r = subscribe(kOwner);
  EXPECT_EQ(r->status(), Code::Ok) << message(r);
  // Many readers together fill only the readers' share (48 of 64): the rest is the owner's
  // and its editors'.
  for (uint64_t reader = 1; reader <= 10; ++reader)
    for (int i = 0; i < 8; ++i) subscribe(kReader + reader);
  EXPECT_EQ(interests(), 48u);
  r = subscribe(kReader + 20);
  EXPECT_EQ(r->status(), Code::ResourceExhausted);
  EXPECT_NE(message(r).find("kept for its owner and editors"), std::string::npos) << message(r);
  for (int i = 0; i < 7; ++i) EXPECT_EQ(subscribe(kOwner)->status(), Code::Ok);
  EXPECT_EQ(subscribe(kOwner)->status(), Code::ResourceExhausted) << "its own quota";
  // Editors take the last ones.
  const uint64_t editors[] = {0xED17, 0xED18};
  ASSERT_EQ(call(kOwner, CommandBuilder().setAccess(editors, false), world)->status(), Code::Ok);
  for (int i = 0; i < 8; ++i) EXPECT_EQ(subscribe(0xED17)->status(), Code::Ok) << i;
  EXPECT_EQ(subscribe(0xED18)->status(), Code::Ok);
  EXPECT_EQ(interests(), 64u);
  r = subscribe(0xED18);
  EXPECT_EQ(r->status(), Code::ResourceExhausted);
  EXPECT_NE(message(r).find("64 interests, the most it keeps"), std::string::npos) << message(r);
}

TEST_F(InterestTest, AParticipantsIdsShareOneQuota) {
  // One participant (sender 5) subscribing under several client ids is one client.
  int ok = 0;
  for (uint64_t id = 0; id < 32; ++id) ok += subscribe(kReader + id, 5)->status() == Code::Ok;
  EXPECT_EQ(ok, 8);
  EXPECT_EQ(subscribe(kReader + 100, 6)->status(), Code::Ok) << "another participant is not";
}

TEST_F(InterestTest, AClientsInterestsGoWhenItLeaves) {
  for (int i = 0; i < 3; ++i) ASSERT_EQ(subscribe(kReader, 5)->status(), Code::Ok);
  for (int i = 0; i < 2; ++i) ASSERT_EQ(subscribe(kReader + 1)->status(), Code::Ok);
  ASSERT_EQ(subscribe(kOwner, 6)->status(), Code::Ok);
  ASSERT_EQ(interests(), 6u);
  takeReplies(core);

  // Participant 5 is gone (its liveliness lost): applied at the next tick boundary, its
  // interests removed and their topics dropped, as an Unsubscribe's.
  core.clientsLeft(5, {kReader});
  EXPECT_EQ(interests(), 6u) << "the tick thread applies it";
  core.processPending();
  EXPECT_EQ(interests(), 3u);
  int removed = 0;
  for (;;) {
    PublishQueue::Item item = core.out().pop(std::chrono::milliseconds(0));
    if (!item.reliable && !item.frame) break;
    if (item.reliable && item.reliable->type == ReliableMessage::Type::InterestRemoved) {
      EXPECT_EQ(item.reliable->world, world);
      ++removed;
    }
  }
  EXPECT_EQ(removed, 3);
  // A client without a participant (an in-process caller) is named by its ids; the owner's
  // interest (participant 6) stays.
  core.clientsLeft(0, {kReader + 1});
  core.processPending();
  ASSERT_EQ(interests(), 1u);
  EXPECT_EQ(core.world(world)->interests.begin()->second.client, kOwner);
  // The slots are free again.
  for (int i = 0; i < 8; ++i) EXPECT_EQ(subscribe(kReader, 7)->status(), Code::Ok);
}

TEST_F(InterestTest, CommandsQueuedBeforeTheLeaveApplyFirst) {
  // A Subscribe the participant sent before it left is applied, then freed with the rest.
  CommandBuilder b;
  Incoming in = queuedCommand(kReader, ++seq, b.subscribeBodies({&bodies[1], 1}), world);
  in.sender = 9;
  core.submit(std::move(in));
  core.clientsLeft(9, {kReader});
  core.processPending();
  std::vector<Reply> r = takeReplies(core);
  ASSERT_EQ(r.size(), 1u);
  EXPECT_EQ(r[0]->status(), Code::Ok);
  EXPECT_EQ(interests(), 0u);
}

}  // namespace
}  // namespace phys::server::test
