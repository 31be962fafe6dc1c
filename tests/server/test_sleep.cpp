// Sleeping through physd (issue 22): worlds sleep by default, CreateWorld can say otherwise,
// BodyDef.allow_sleep reaches the engine, every editing command wakes the body it edits (or
// what rests on the body it removes), and the world summary counts awake bodies.
#include <functional>

#include "../common/bodies.h"
#include "../common/sanitizer.h"
#include "server_test_util.h"

namespace phys::server::test {
namespace {

using protocol::CommandBuilder;

class SleepServerTest : public ::testing::Test {
 protected:
  void SetUp() override { ASSERT_TRUE(core.init().ok()); }
  void TearDown() override {
    std::error_code ec;
    std::filesystem::remove_all(core.config().snapshotDir, ec);
  }

  uint32_t createWorld(bool sleep, const std::string& name = "w") {
    protocol::CreateWorldArgs a{name, "", std::nullopt, 0};
    a.sleep = sleep;
    Reply r = send(CommandBuilder().createWorld(a), 0);
    EXPECT_EQ(r->status(), Code::Ok) << message(r);
    return r->world();
  }
  Reply send(CommandBuilder& b, uint32_t w) {
    return decode(core.applyBytes(b.finish({kClient, ++seq, w}), kClient, seq));
  }
  Reply send(CommandBuilder&& b, uint32_t w) { return send(b, w); }
  /// A ground and a box resting on it; returns {ground, box}.
  std::vector<uint64_t> groundAndBox(uint32_t w, bool allowSleep = true) {
    BodyDef box = phys::test::boxBody({0, 0, 0.5f});
    box.allowSleep = allowSleep;
    Reply r =
        send(CommandBuilder().spawnBodies(std::vector<BodyDef>{phys::test::groundBody(), box}), w);
    EXPECT_EQ(r->status(), Code::Ok) << message(r);
    return bodyIds(r);
  }
  World& engine(uint32_t w) { return *core.world(w)->world; }
  bool sleeping(uint32_t w, uint64_t id) { return engine(w).isSleeping(BodyId::fromPacked(id)); }
  void step(uint32_t w, uint32_t n) {
    Reply r = send(CommandBuilder().step(n), w);
    ASSERT_EQ(r->status(), Code::Ok) << message(r);
  }

  ServerCore core{testConfig()};
  uint64_t seq = 0;
};

TEST_F(SleepServerTest, WorldsSleepByDefaultAndCreateWorldCanSayOtherwise) {
  const uint32_t on = createWorld(true, "on"), off = createWorld(false, "off");
  const auto a = groundAndBox(on), b = groundAndBox(off);
  step(on, 60);
  step(off, 60);
  EXPECT_TRUE(sleeping(on, a[1]));
  EXPECT_FALSE(sleeping(off, b[1]));
  // The summary counts them: the box is asleep in one world, awake in the other.
  for (const protocol::WorldSummary& s : core.summaries()) {
    EXPECT_EQ(s.bodies, 2u);
    EXPECT_EQ(s.awakeBodies, s.world == on ? 0u : 1u) << s.name;
    EXPECT_EQ(s.sleepingBodies, s.world == on ? 1u : 0u) << s.name;
    // The awake box touches the ground (its contacts are in the step's buffers); a sleeping
    // island is not collided.
    if (s.world == off) {
      EXPECT_GE(s.contacts, 1u);
      EXPECT_GT(s.stepBufferBytes, 0u);
    } else {
      EXPECT_EQ(s.contacts, 0u);
    }
  }
  // The daemon's heap in use (glibc's mallinfo2; a sanitizer's allocator reports 0, which
  // the status documents as "not reported").
  if (!phys::test::kSanitized) {
    EXPECT_GT(core.status().heapBytes, 0u);
  }
  // The default CreateWorldArgs sleep.
  const uint32_t plain =
      send(CommandBuilder().createWorld({"plain", "", std::nullopt, 0}), 0)->world();
  EXPECT_TRUE(engine(plain).def().sleep.enabled);
}

TEST_F(SleepServerTest, AllowSleepReachesTheEngine) {
  const uint32_t w = createWorld(true);
  const auto ids = groundAndBox(w, /*allowSleep=*/false);
  step(w, 120);
  EXPECT_FALSE(sleeping(w, ids[1]));
  BodyState s;
  ASSERT_TRUE(engine(w).getBody(BodyId::fromPacked(ids[1]), &s).ok());
  EXPECT_FALSE(s.allowSleep);
}

TEST_F(SleepServerTest, EveryEditingCommandWakesItsBody) {
  struct Edit {
    const char* name;
    std::function<CommandBuilder(const std::vector<uint64_t>&)> command;
  };
  const std::vector<Edit> edits = {
      {"SetBodyPose",
       [](auto& ids) {
         return std::move(CommandBuilder().setBodyPose(ids[1], {0, 0, 0.6f}, {}));
       }},
      {"SetBodyVelocity",
       [](auto& ids) {
         return std::move(CommandBuilder().setBodyVelocity(ids[1], {0.1f, 0, 0}, {}));
       }},
      {"ApplyForce",
       [](auto& ids) {
         return std::move(CommandBuilder().applyForce(ids[1], {10, 0, 0}));
       }},
      {"ApplyImpulse",
       [](auto& ids) {
         return std::move(CommandBuilder().applyImpulse(ids[1], {10, 0, 0}));
       }},
      {"ApplyTorque",
       [](auto& ids) {
         return std::move(CommandBuilder().applyTorque(ids[1], {0, 0, 10}));
       }},
      {"SetMaterial (the box)",
       [](auto& ids) {
         return std::move(
             CommandBuilder().setMaterial(std::vector<uint64_t>{ids[1]}, Material{0.2f, 0, 800}));
       }},
      {"SetMaterial (the ground under it)",
       [](auto& ids) {
         return std::move(
             CommandBuilder().setMaterial(std::vector<uint64_t>{ids[0]}, Material{0.1f, 0, 1000}));
       }},
      {"AddJoints",
       [](auto& ids) {
         JointDef j;
         j.type = JointType::Ball;
         j.bodyB = BodyId::fromPacked(ids[1]);
         j.anchorA = {0, 0, 1};
         j.anchorB = {0, 0, 0.5f};
         return std::move(CommandBuilder().addJoints(std::vector<JointDef>{j}));
       }},
      {"RemoveBodies (the ground under it)",
       [](auto& ids) {
         return std::move(CommandBuilder().removeBodies(std::vector<uint64_t>{ids[0]}));
       }},
      {"SetSolver", [](auto&) { return std::move(CommandBuilder().setSolver("ldl_pgs")); }},
  };
  for (const Edit& e : edits) {
    const uint32_t w = createWorld(true, e.name);
    const auto ids = groundAndBox(w);
    step(w, 60);
    ASSERT_TRUE(sleeping(w, ids[1])) << e.name;
    CommandBuilder b = e.command(ids);
    Reply r = send(b, w);
    ASSERT_EQ(r->status(), Code::Ok) << e.name << ": " << message(r);
    EXPECT_FALSE(sleeping(w, ids[1])) << e.name << " left the box asleep";
  }
}

}  // namespace
}  // namespace phys::server::test
