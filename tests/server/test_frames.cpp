// State frames that publish only what changed (issue 22): keyframes every keyframe_ticks
// frames, at once for a new subscriber and after the world is replaced; deltas in between
// with the bodies whose state changed (moving ones, one that fell asleep, a static body moved,
// spawned ones) and the removed ones; nothing encoded for a world without subscribers; compact
// states on request. The SDK's side (rebuilding every tick) is tests/client/test_client.cpp.
#include <cstring>
#include <map>

#include "../common/bodies.h"
#include "phys/protocol/compact.h"
#include "phys/protocol/topics.h"
#include "server_test_util.h"

namespace phys::server::test {
namespace {

using protocol::CommandBuilder;

struct Frame {
  uint32_t interest = 0;
  uint64_t tick = 0, baseTick = 0;
  uint64_t epoch = 0;
  uint32_t edit = 0, baseEdit = 0;
  bool keyframe = true;
  uint32_t total = 0;
  std::map<uint64_t, wire::BodyState> bodies;
  std::vector<uint64_t> removed;
  uint64_t refreshLo = 0, refreshHi = 0;
};

class FramesTest : public ::testing::Test {
 protected:
  void start(CoreConfig c) {
    core = std::make_unique<ServerCore>(std::move(c));
    ASSERT_TRUE(core->init().ok());
    Reply r = send(CommandBuilder().createWorld({"w", "", std::nullopt, 0}), 0);
    ASSERT_EQ(r->status(), Code::Ok) << message(r);
    world = r->world();
  }
  void TearDown() override {
    std::error_code ec;
    if (core) std::filesystem::remove_all(core->config().snapshotDir, ec);
  }
  Reply send(CommandBuilder& b, uint32_t w) {
    return decode(core->applyBytes(b.finish({kClient, ++seq, w}), kClient, seq));
  }
  Reply send(CommandBuilder& b) { return send(b, world); }
  /// Every frame set queued since the last call, decoded.
  std::vector<Frame> frames() {
    std::vector<Frame> out;
    for (;;) {
      PublishQueue::Item item = core->out().pop(std::chrono::milliseconds(0));
      if (!item.reliable && !item.frame) break;
      if (!item.frame) continue;
      Frame f;
      for (protocol::Bytes& bytes : item.frame->chunks) {
        auto d = protocol::decodeStateFrame(std::move(bytes));
        EXPECT_TRUE(d.ok()) << d.status.message;
        f.tick = d->tick();
        f.interest = d->interest();
        EXPECT_EQ(item.frame->interest, f.interest);
        f.keyframe = d->keyframe();
        f.baseTick = d->base_tick();
        f.total = d->total_bodies();
        f.refreshLo = d->refresh_lo();
        f.refreshHi = d->refresh_hi();
        f.epoch = d->epoch();
        f.edit = d->edit();
        f.baseEdit = d->base_edit();
        if (d->bodies())
          for (const wire::BodyState* s : *d->bodies()) f.bodies[s->id()] = *s;
        if (d->compact()) {
          const protocol::CompactBounds b{protocol::toPhys(*d->bounds_min()),
                                          protocol::toPhys(*d->bounds_max())};
          for (const wire::CompactBodyState* c : *d->compact())
            f.bodies[c->id()] = protocol::expandState(*c, b);
        }
        if (d->removed()) f.removed.assign(d->removed()->begin(), d->removed()->end());
      }
      out.push_back(std::move(f));
    }
    return out;
  }
  Frame step(uint32_t n = 1) {
    std::vector<Frame> f = stepAll(n);
    EXPECT_EQ(f.size(), 1u);
    return f.empty() ? Frame() : f.back();
  }
  /// Every stream's frame of the step (the world's first, then the interests' in order).
  std::vector<Frame> stepAll(uint32_t n = 1) {
    EXPECT_EQ(send(CommandBuilder().step(n))->status(), Code::Ok);
    core->advance(0);
    return frames();
  }
  std::vector<uint64_t> spawn(std::vector<BodyDef> defs) {
    Reply r = send(CommandBuilder().spawnBodies(defs));
    EXPECT_EQ(r->status(), Code::Ok) << message(r);
    return bodyIds(r);
  }

  std::unique_ptr<ServerCore> core;
  uint32_t world = 0;
  uint64_t seq = 0;
};

CoreConfig withSubscribersOnly() {
  CoreConfig c = testConfig();
  c.framesWithoutSubscribers = false;
  c.keyframeTicks = 10;
  return c;
}

/// Every body again as a whole keyframe every keyframeTicks frames (refresh = "keyframe"):
/// deltas carry exactly what changed.
CoreConfig keyframeMode() {
  CoreConfig c = withSubscribersOnly();
  c.rollingRefresh = false;
  return c;
}

TEST_F(FramesTest, NoSubscribersNoFramesThenAKeyframeForTheFirstOne) {
  start(keyframeMode());
  spawn({phys::test::groundBody(), phys::test::boxBody({0, 0, 3})});
  frames();
  for (int i = 0; i < 5; ++i) {
    send(CommandBuilder().step(1));
    core->advance(0);
  }
  EXPECT_TRUE(frames().empty()) << "a world nobody subscribes to encodes no frames";
  EXPECT_EQ(core->world(world)->framesProduced, 0u);
  core->setSubscribers(world, 1);
  Frame f = step();
  EXPECT_TRUE(f.keyframe);
  EXPECT_EQ(f.bodies.size(), 2u);
  EXPECT_EQ(f.total, 2u);
  // The next one is a delta on it: the falling box only (the ground does not move).
  Frame d = step();
  EXPECT_FALSE(d.keyframe);
  EXPECT_EQ(d.baseTick, f.tick);
  EXPECT_EQ(d.bodies.size(), 1u);
  EXPECT_EQ(d.total, 2u);
  // A second subscriber gets a keyframe at once.
  core->setSubscribers(world, 2);
  EXPECT_TRUE(step().keyframe);
}

TEST_F(FramesTest, DeltasCarryWhatChangedAndKeyframesComeOnTime) {
  start(keyframeMode());
  core->setSubscribers(world, 1);
  // A box resting on the ground (asleep after 0.5 s) and a free one drifting in the air.
  BodyDef drifting = phys::test::boxBody({5, 0, 10});
  drifting.gravityScale = 0;
  drifting.linearVelocity = {0.5f, 0, 0};
  const auto ids = spawn({phys::test::groundBody(), phys::test::boxBody({0, 0, 0.5f}), drifting});
  const uint64_t ground = ids[0], resting = ids[1], moving = ids[2];
  frames();
  std::map<uint64_t, wire::BodyState> state;  // rebuilt from the frames, as a subscriber does
  uint64_t held = 0;
  int keyframes = 0;
  for (int i = 0; i < 61; ++i) {
    Frame f = step();
    if (f.keyframe) {
      ++keyframes;
      state.clear();
    } else {
      ASSERT_EQ(f.baseTick, held) << "a delta applies to the previous frame";
      if (i > 45) {  // the resting box is asleep by now: only the moving one changes
        EXPECT_EQ(f.bodies.size(), 1u) << "tick " << f.tick;
        EXPECT_TRUE(f.bodies.count(moving));
      }
    }
    for (auto& [id, s] : f.bodies) state[id] = s;
    held = f.tick;
    // The rebuilt state is the world's, bit for bit.
    ASSERT_EQ(state.size(), 3u);
    for (uint64_t id : ids) {
      BodyState b;
      ASSERT_TRUE(core->world(world)->world->getBody(BodyId::fromPacked(id), &b).ok());
      const wire::BodyState w = protocol::toWire(b);
      ASSERT_EQ(std::memcmp(&state[id], &w, sizeof w), 0) << "body " << id << " tick " << f.tick;
    }
  }
  EXPECT_EQ(keyframes, 7);  // every 10th frame: 0, 10, ..., 60
  EXPECT_TRUE(core->world(world)->world->isSleeping(BodyId::fromPacked(resting)));
  // A static body moved, a body spawned and one removed: all in the next delta.
  ASSERT_EQ(send(CommandBuilder().setBodyPose(ground, {0, 0, -0.1f}, {}))->status(), Code::Ok);
  const uint64_t added = spawn({phys::test::sphereBody({-5, 0, 5}, 0.2f)})[0];
  ASSERT_EQ(send(CommandBuilder().removeBodies(std::vector<uint64_t>{moving}))->status(), Code::Ok);
  Frame f = step();
  ASSERT_FALSE(f.keyframe);
  EXPECT_TRUE(f.bodies.count(ground));
  EXPECT_TRUE(f.bodies.count(added));
  EXPECT_TRUE(f.bodies.count(resting));  // moving the ground under it woke it
  EXPECT_EQ(f.removed, std::vector<uint64_t>{moving});
  EXPECT_EQ(f.total, 3u);
}

TEST_F(FramesTest, RollingRefreshSendsEveryBodyOncePerPeriodBetweenChanges) {
  // refresh = "rolling" (the default), keyframe_ticks 10: after the first keyframe only
  // deltas, each carrying what changed and the next tenth of the bodies in key order; the
  // refreshes tile the keys from 0 to the end, so a subscriber that lost a frame is whole
  // again after one round (the SDK's side: tests/client). A world at rest goes round ten
  // times more slowly.
  start(withSubscribersOnly());
  core->setSubscribers(world, 1);
  std::vector<BodyDef> defs{phys::test::groundBody()};
  for (int i = 0; i < 24; ++i) defs.push_back(phys::test::boxBody({float(i) * 3, 0, 0.5f}));
  BodyDef drifting = phys::test::boxBody({0, 20, 10});
  drifting.gravityScale = 0;
  drifting.linearVelocity = {0.5f, 0, 0};
  defs.push_back(drifting);
  std::vector<uint64_t> ids = spawn(defs);
  const uint64_t moving = ids.back();
  frames();
  ASSERT_TRUE(step().keyframe);
  auto keyOf = [](uint64_t id) { return protocol::refreshKey(id); };
  uint64_t expectLo = 0;
  std::map<uint64_t, int> refreshed;  // this round: times each body was in a refresh
  int rounds = 0, framesThisRound = 0;
  std::vector<int> roundLengths;
  auto check = [&](const Frame& f) {
    ASSERT_FALSE(f.keyframe) << "no periodic keyframe in rolling mode, tick " << f.tick;
    ASSERT_NE(f.refreshHi, 0u) << "every delta refreshes";
    ASSERT_EQ(f.refreshLo, expectLo) << "the refreshes follow each other, tick " << f.tick;
    ++framesThisRound;
    // Every body of the range is carried, and only those of the range besides the changed.
    for (uint64_t id : ids) {
      const uint64_t k = keyOf(id);
      if (k >= f.refreshLo && (f.refreshHi == UINT64_MAX || k < f.refreshHi)) {
        ASSERT_TRUE(f.bodies.count(id)) << "body " << id << " in range, not carried";
        refreshed[id]++;
      }
    }
    expectLo = f.refreshHi == UINT64_MAX ? 0 : f.refreshHi;
    if (f.refreshHi == UINT64_MAX) {  // a round is over: every body exactly once
      ASSERT_EQ(refreshed.size(), ids.size());
      for (auto& [id, n] : refreshed) ASSERT_EQ(n, 1) << "body " << id;
      refreshed.clear();
      ++rounds;
      roundLengths.push_back(framesThisRound);
      framesThisRound = 0;
    }
  };
  for (int i = 0; i < 40; ++i) {
    Frame f = step();
    check(f);
    EXPECT_TRUE(f.bodies.count(moving));
  }
  // 26 bodies, a tenth (3) a frame: a round every 9 frames while something moves.
  ASSERT_GE(rounds, 4);
  for (size_t r = 1; r < roundLengths.size(); ++r) EXPECT_LE(roundLengths[r], 10);
  // At rest (the drifting box removed, the boxes asleep): rounds ten times longer.
  ASSERT_EQ(send(CommandBuilder().removeBodies(std::vector<uint64_t>{moving}))->status(), Code::Ok);
  ids.pop_back();
  bool started = false;
  for (int i = 0; i < 400; ++i) {
    Frame f = step();
    if (i == 0) {
      EXPECT_EQ(f.removed, std::vector<uint64_t>{moving});
    }
    if (!started) {  // from the next round that begins
      if (f.refreshLo != 0) continue;
      started = true;
      refreshed.clear();
      roundLengths.clear();
      framesThisRound = 0;
      expectLo = 0;
    }
    check(f);
  }
  ASSERT_GE(roundLengths.size(), 2u);
  EXPECT_GE(roundLengths.back(), 25) << "a world at rest refreshes its 25 bodies one a frame";
}

TEST_F(FramesTest, KeyframeTicksOneIsEveryFrameAKeyframeEvenAtRest) {
  // The fan-out baseline (configs/bench/fanout_10k.toml): a world whose bodies do not move
  // still sends every body every frame (the quiet factor stretches periods longer than one).
  CoreConfig c = withSubscribersOnly();
  c.keyframeTicks = 1;
  start(c);
  core->setSubscribers(world, 1);
  BodyDef still = phys::test::boxBody({0, 0, 5});
  still.gravityScale = 0;
  spawn({still, still});
  for (int i = 0; i < 12; ++i) {
    Frame f = step();
    EXPECT_TRUE(f.keyframe) << "frame " << i;
    EXPECT_EQ(f.bodies.size(), 2u);
  }
}

TEST_F(FramesTest, LoadResetAndRestoreStartFromAKeyframe) {
  start(withSubscribersOnly());
  core->setSubscribers(world, 1);
  spawn({phys::test::groundBody(), phys::test::boxBody({0, 0, 3})});
  step();
  EXPECT_FALSE(step().keyframe);
  ASSERT_EQ(send(CommandBuilder().resetWorld())->status(), Code::Ok);
  spawn({phys::test::groundBody()});
  EXPECT_TRUE(step().keyframe);
}

TEST_F(FramesTest, CompactStatesAreWithinTheirBounds) {
  CoreConfig c = withSubscribersOnly();
  c.compactStates = true;
  start(c);
  core->setSubscribers(world, 1);
  const auto ids = spawn({phys::test::groundBody(), phys::test::boxBody({0, 0, 3}),
                          phys::test::boxBody({40, -20, 7})});
  Frame f = step();
  ASSERT_TRUE(f.keyframe);
  ASSERT_EQ(f.bodies.size(), 3u);
  for (uint64_t id : ids) {
    BodyState b;
    ASSERT_TRUE(core->world(world)->world->getBody(BodyId::fromPacked(id), &b).ok());
    const wire::BodyState& s = f.bodies[id];
    // The frame's box is 40 x 20 x 7 m: half a 24-bit step is under 1.3 um.
    EXPECT_NEAR(s.position().x(), b.position.x, 40.0 / (1 << 24) + 1e-5);
    EXPECT_NEAR(s.position().y(), b.position.y, 20.0 / (1 << 24) + 1e-5);
    EXPECT_NEAR(s.position().z(), b.position.z, 7.0 / (1 << 24) + 1e-5);
    EXPECT_NEAR(std::fabs(s.rotation().w()), std::fabs(b.rotation.w), 1e-5);
    EXPECT_NEAR(s.linear_velocity().z(), b.linearVelocity.z,
                std::fabs(b.linearVelocity.z) / 2048 + 1e-7);
  }
}

TEST_F(FramesTest, AnInterestDeliversExactlyTheBodiesAskedFor) {
  start(withSubscribersOnly());
  // Ten boxes drifting along x at 1 m/s in zero gravity, 2 m apart along y, staggered by
  // 9 cm along x (they enter and leave the region on different ticks, all inside at once).
  std::vector<BodyDef> defs;
  for (int i = 0; i < 10; ++i) {
    BodyDef d = phys::test::boxBody({-2 - 0.09f * float(i), float(i) * 2, 5}, {0.2f, 0.2f, 0.2f});
    d.gravityScale = 0;
    d.linearVelocity = {1, 0, 0};
    defs.push_back(d);
  }
  const auto ids = spawn(defs);
  // By ids: bodies 3 and 7; by region: x in [0, 1] (every body passes through it).
  Reply a = send(CommandBuilder().subscribeBodies(std::vector<uint64_t>{ids[7], ids[3]}));
  ASSERT_EQ(a->status(), Code::Ok) << message(a);
  const uint32_t byIds = a->result_as_InterestResult()->interest();
  EXPECT_EQ(a->result_as_InterestResult()->topic()->str(), protocol::stateTopic(world, byIds));
  Reply b = send(CommandBuilder().subscribeRegion({0, -1, 0}, {1, 100, 10}));
  ASSERT_EQ(b->status(), Code::Ok) << message(b);
  const uint32_t byRegion = b->result_as_InterestResult()->interest();
  frames();
  core->setSubscribers(world, byIds, 1);
  core->setSubscribers(world, byRegion, 1);  // and nobody on the world's own stream
  std::map<uint64_t, wire::BodyState> inRegion;
  bool sawAllInside = false, sawLeave = false;
  for (int i = 0; i < 240; ++i) {  // 4 s: the boxes cross x = 0..1 between 2 s and 3 s
    std::vector<Frame> f = stepAll();
    ASSERT_EQ(f.size(), 2u) << "two interests, no frame for the world's own stream";
    const Frame& idf = f[0].interest == byIds ? f[0] : f[1];
    const Frame& rf = f[0].interest == byRegion ? f[0] : f[1];
    // The id interest: always exactly bodies 3 and 7 (they move, so every delta has both).
    EXPECT_EQ(idf.total, 2u);
    EXPECT_EQ(idf.bodies.size(), 2u);
    EXPECT_TRUE(idf.bodies.count(ids[3]) && idf.bodies.count(ids[7]));
    // The region: rebuilt, it holds exactly the bodies inside the box.
    if (rf.keyframe) inRegion.clear();
    for (uint64_t id : rf.removed) {
      EXPECT_TRUE(inRegion.erase(id)) << "removed a body it did not hold";
      sawLeave = true;
    }
    for (auto& [id, st] : rf.bodies) inRegion[id] = st;
    ASSERT_EQ(inRegion.size(), rf.total);
    int inside = 0;
    for (uint64_t id : ids) {
      BodyState bs;
      ASSERT_TRUE(core->world(world)->world->getBody(BodyId::fromPacked(id), &bs).ok());
      const bool in = bs.position.x >= 0 && bs.position.x <= 1;
      inside += in;
      EXPECT_EQ(inRegion.count(id) > 0, in) << "body " << id << " x " << bs.position.x;
    }
    sawAllInside |= inside == 10;
  }
  EXPECT_TRUE(sawAllInside);
  EXPECT_TRUE(sawLeave);
  // Unsubscribed, its stream stops; unknown interests are refused.
  ASSERT_EQ(send(CommandBuilder().unsubscribe(byIds))->status(), Code::Ok);
  EXPECT_EQ(stepAll().size(), 1u);
  EXPECT_EQ(send(CommandBuilder().unsubscribe(byIds))->status(), Code::NotFound);
  // Bad requests: a region upside down, ids and a region together, a repeated id.
  EXPECT_EQ(send(CommandBuilder().subscribeRegion({1, 1, 1}, {0, 0, 0}))->status(),
            Code::InvalidArgument);
  EXPECT_EQ(send(CommandBuilder().subscribeBodies(std::vector<uint64_t>{ids[1], ids[1]}))->status(),
            Code::InvalidArgument);
}

// Issue 40, finding 1: a new subscriber to a paused world got nothing until the world stepped
// (its keyframe waited for a frame), and one that came just after another left was not
// counted as new (the count was the same at the publisher's next look). Now the publisher
// also reports the readers ever matched, and a stream with a new one gets its keyframe at the
// tick thread's next turn, whatever the world does.
TEST_F(FramesTest, ANewSubscriberToAPausedWorldGetsAKeyframeWithoutAStep) {
  start(withSubscribersOnly());
  const auto ids = spawn({phys::test::groundBody(), phys::test::boxBody({0, 0, 3})});
  ASSERT_EQ(send(CommandBuilder().step(30))->status(), Code::Ok);
  core->advance(0);
  EXPECT_TRUE(frames().empty()) << "nobody subscribes yet";
  core->setSubscribers(world, 1);
  core->advance(0);  // paused: no step
  std::vector<Frame> f = frames();
  ASSERT_EQ(f.size(), 1u) << "a paused world's new subscriber gets its keyframe without a step";
  EXPECT_TRUE(f[0].keyframe);
  EXPECT_EQ(f[0].tick, 30u);
  EXPECT_EQ(f[0].bodies.size(), 2u);
  core->advance(0);
  EXPECT_TRUE(frames().empty()) << "nothing new: nothing sent";
  // A reader left and another came between two looks of the publisher: the same count, one
  // more ever matched. The newcomer gets a keyframe (the other reader applies it again).
  core->setSubscribers(world, 0, 1, 2);
  core->advance(0);
  f = frames();
  ASSERT_EQ(f.size(), 1u) << "a reader that replaced another is a new subscriber";
  EXPECT_TRUE(f[0].keyframe);
  EXPECT_EQ(f[0].tick, 30u);
  // The last reader left (the stream forgets its state), then a new one came.
  core->setSubscribers(world, 0, 0, 2);
  core->advance(0);
  EXPECT_TRUE(frames().empty());
  core->setSubscribers(world, 0, 1, 3);
  core->advance(0);
  f = frames();
  ASSERT_EQ(f.size(), 1u);
  EXPECT_TRUE(f[0].keyframe);
  EXPECT_EQ(f[0].bodies.size(), 2u);
  // An interest opened on the paused world: its keyframe as soon as it has a reader, and
  // nothing for the world's own stream, whose subscriber holds this tick already.
  Reply r = send(CommandBuilder().subscribeBodies(std::vector<uint64_t>{ids[1]}));
  ASSERT_EQ(r->status(), Code::Ok) << message(r);
  const uint32_t interest = r->result_as_InterestResult()->interest();
  core->advance(0);
  EXPECT_TRUE(frames().empty()) << "the interest has no reader yet";
  core->setSubscribers(world, interest, 1);
  core->advance(0);
  f = frames();
  ASSERT_EQ(f.size(), 1u);
  EXPECT_EQ(f[0].interest, interest);
  EXPECT_TRUE(f[0].keyframe);
  EXPECT_EQ(f[0].tick, 30u);
  ASSERT_EQ(f[0].bodies.size(), 1u);
  EXPECT_TRUE(f[0].bodies.count(ids[1]));
}

// The state a subscriber rebuilds from a stream's frames, as docs/PROTOCOL.md says: a keyframe
// replaces it, a delta on the last frame that carried anything changes it, frames in
// (epoch, tick, edit) order.
struct Rebuilt {
  std::map<uint64_t, wire::BodyState> bodies;
  uint64_t epoch = 0, baseTick = 0;
  uint32_t baseEdit = 0;
  void apply(const Frame& f) {
    if (f.keyframe) {
      bodies.clear();
    } else {
      EXPECT_EQ(f.epoch, epoch);
      EXPECT_EQ(f.baseTick, baseTick) << "tick " << f.tick << " edit " << f.edit;
      EXPECT_EQ(f.baseEdit, baseEdit) << "tick " << f.tick << " edit " << f.edit;
    }
    for (uint64_t id : f.removed) bodies.erase(id);
    for (auto& [id, s] : f.bodies) bodies[id] = s;
    EXPECT_EQ(bodies.size(), f.total);
    epoch = f.epoch;
    if (f.keyframe || !f.bodies.empty() || !f.removed.empty()) {
      baseTick = f.tick;
      baseEdit = f.edit;
    }
  }
  /// Bit for bit the world's bodies.
  void expectWorld(const phys::World& w) {
    EXPECT_EQ(bodies.size(), w.bodyCount());
    for (auto& [id, s] : bodies) {
      BodyState b;
      ASSERT_TRUE(w.getBody(BodyId::fromPacked(id), &b).ok()) << "body " << id;
      const wire::BodyState want = protocol::toWire(b);
      EXPECT_EQ(std::memcmp(&s, &want, sizeof want), 0) << "body " << id;
    }
  }
};

// Issue 40: an edit to a paused world (SetBodyPose, a spawn, a removal) reached no subscriber
// until the world stepped, though docs/SERVER.md "Time control" said its subscribers see them.
// Now each goes out at once in a frame of the same tick with the next edit number, a delta on
// the frame before; the next step's frame is edit 0 of the next tick. A running world's edits
// ride its next tick's frame.
TEST_F(FramesTest, EditsToAPausedWorldGoOutAtOnceAtTheSameTick) {
  start(withSubscribersOnly());
  core->setSubscribers(world, 1);
  const auto ids = spawn({phys::test::groundBody(), phys::test::boxBody({0, 0, 0.5f}),
                          phys::test::boxBody({3, 0, 0.5f})});
  Rebuilt seen;
  Frame k = step();
  ASSERT_TRUE(k.keyframe);
  EXPECT_EQ(k.tick, 1u);
  EXPECT_EQ(k.edit, 0u);
  seen.apply(k);
  ASSERT_EQ(send(CommandBuilder().setBodyPose(ids[1], {1, 2, 3}, {}))->status(), Code::Ok);
  core->advance(0);
  std::vector<Frame> f = frames();
  ASSERT_EQ(f.size(), 1u) << "a pose set in a paused world is published without a step";
  EXPECT_FALSE(f[0].keyframe);
  EXPECT_EQ(f[0].tick, 1u);
  EXPECT_EQ(f[0].edit, 1u);
  EXPECT_EQ(f[0].epoch, k.epoch);
  ASSERT_TRUE(f[0].bodies.count(ids[1]));
  EXPECT_EQ(f[0].bodies[ids[1]].position().y(), 2.0f);
  seen.apply(f[0]);
  seen.expectWorld(*core->world(world)->world);
  // A spawn and a removal: edit 2, a delta on edit 1.
  const uint64_t added = spawn({phys::test::sphereBody({-5, 0, 5}, 0.2f)})[0];
  ASSERT_EQ(send(CommandBuilder().removeBodies(std::vector<uint64_t>{ids[2]}))->status(), Code::Ok);
  core->advance(0);
  f = frames();
  ASSERT_EQ(f.size(), 1u);
  EXPECT_EQ(f[0].tick, 1u);
  EXPECT_EQ(f[0].edit, 2u);
  EXPECT_TRUE(f[0].bodies.count(added));
  EXPECT_EQ(f[0].removed, std::vector<uint64_t>{ids[2]});
  seen.apply(f[0]);
  seen.expectWorld(*core->world(world)->world);
  // A velocity set and an impulse change velocities at once: edit 3.
  ASSERT_EQ(send(CommandBuilder().setBodyVelocity(ids[1], {0, 0, 2}, {}))->status(),
            Code::Ok);
  ASSERT_EQ(send(CommandBuilder().applyImpulse(added, {1, 0, 0}))->status(), Code::Ok);
  core->advance(0);
  f = frames();
  ASSERT_EQ(f.size(), 1u) << "velocities set in a paused world are published without a step";
  EXPECT_EQ(f[0].edit, 3u);
  EXPECT_TRUE(f[0].bodies.count(ids[1]) && f[0].bodies.count(added));
  seen.apply(f[0]);
  seen.expectWorld(*core->world(world)->world);
  core->advance(0);
  EXPECT_TRUE(frames().empty()) << "nothing edited since: nothing sent";
  // The next step: tick 2, edit 0, a delta on edit 2 of tick 1.
  Frame d = step();
  EXPECT_EQ(d.tick, 2u);
  EXPECT_EQ(d.edit, 0u);
  seen.apply(d);
  seen.expectWorld(*core->world(world)->world);
  // A running world's edit waits for the next tick's delta: no frame of its own.
  ASSERT_EQ(send(CommandBuilder().run(60))->status(), Code::Ok);
  core->advance(0);
  frames();
  ASSERT_EQ(send(CommandBuilder().setBodyPose(ids[1], {1, 2, 4}, {}))->status(), Code::Ok);
  core->advance(0);
  EXPECT_TRUE(frames().empty()) << "a running world's edit rides its next tick";
  core->advance(1.5 / 60);  // one step owed
  f = frames();
  ASSERT_EQ(f.size(), 1u);
  EXPECT_EQ(f[0].tick, 3u);
  EXPECT_EQ(f[0].edit, 0u);
  EXPECT_TRUE(f[0].bodies.count(ids[1]));
  seen.apply(f[0]);
  seen.expectWorld(*core->world(world)->world);
}

// Issue 40, finding 2: after a restore to an earlier tick, or a reset, the SDK dropped every
// frame until the world passed its old tick again. Replacing a world's state starts a new
// epoch: every stream's next frame is a keyframe of it, whatever its tick, and the deltas
// after it belong to it.
TEST_F(FramesTest, ResetRestoreAndLoadStartANewEpochOnEveryStream) {
  start(withSubscribersOnly());
  core->setSubscribers(world, 1);
  const auto ids = spawn({phys::test::groundBody(), phys::test::boxBody({0, 0, 3})});
  Reply r = send(CommandBuilder().subscribeBodies(std::vector<uint64_t>{ids[1]}));
  ASSERT_EQ(r->status(), Code::Ok) << message(r);
  const uint32_t interest = r->result_as_InterestResult()->interest();
  core->setSubscribers(world, interest, 1);
  ASSERT_EQ(stepAll(5).size(), 2u);
  Reply saved = send(CommandBuilder().saveSnapshot({}, true));
  ASSERT_EQ(saved->status(), Code::Ok) << message(saved);
  const auto* snap = saved->result_as_SnapshotResult()->snapshot();
  const std::vector<uint8_t> snapshot(snap->begin(), snap->end());
  std::vector<Frame> before = stepAll(72);  // tick 77
  ASSERT_EQ(before.size(), 2u);
  const uint64_t epoch = before[0].epoch;
  EXPECT_GE(epoch, 1u);
  EXPECT_EQ(before[1].epoch, epoch);
  // Restored to tick 5: a keyframe of the next epoch on both streams, without a step.
  ASSERT_EQ(send(CommandBuilder().restoreSnapshot(snapshot))->status(), Code::Ok);
  core->advance(0);
  std::vector<Frame> f = frames();
  ASSERT_EQ(f.size(), 2u);
  for (const Frame& x : f) {
    EXPECT_TRUE(x.keyframe) << "interest " << x.interest;
    EXPECT_EQ(x.tick, 5u);
    EXPECT_EQ(x.edit, 0u);
    EXPECT_GT(x.epoch, epoch) << "interest " << x.interest;
  }
  const uint64_t restored = f[0].epoch;
  // Its deltas go on in it.
  f = stepAll();
  ASSERT_EQ(f.size(), 2u);
  EXPECT_FALSE(f[0].keyframe);
  EXPECT_EQ(f[0].tick, 6u);
  EXPECT_EQ(f[0].epoch, restored);
  EXPECT_EQ(f[0].baseTick, 5u);
  // A reset, then a scene loaded: a new epoch each, at tick 0.
  ASSERT_EQ(send(CommandBuilder().resetWorld())->status(), Code::Ok);
  core->advance(0);
  f = frames();
  ASSERT_GE(f.size(), 1u);
  EXPECT_TRUE(f[0].keyframe);
  EXPECT_EQ(f[0].tick, 0u);
  EXPECT_EQ(f[0].total, 0u);
  EXPECT_GT(f[0].epoch, restored);
  const uint64_t reset = f[0].epoch;
  Reply l = send(CommandBuilder().loadSceneNamed("box_stack"));
  ASSERT_EQ(l->status(), Code::Ok) << message(l);
  core->advance(0);
  f = frames();
  ASSERT_GE(f.size(), 1u);
  EXPECT_TRUE(f[0].keyframe);
  EXPECT_EQ(f[0].tick, 0u);
  EXPECT_GT(f[0].epoch, reset);
  EXPECT_EQ(f[0].total, core->world(world)->world->bodyCount());
}

// Issue 40: frames from query_state carried no wall-clock stamp (0). Its answer is stamped as a
// state frame is, and names the world's epoch.
TEST_F(FramesTest, AQueryStateAnswerIsStampedAndNamesTheEpoch) {
  start(withSubscribersOnly());
  spawn({phys::test::boxBody({0, 0, 3})});
  const auto before = std::chrono::system_clock::now().time_since_epoch();
  Reply r = send(CommandBuilder().queryState());
  const auto after = std::chrono::system_clock::now().time_since_epoch();
  ASSERT_EQ(r->status(), Code::Ok) << message(r);
  const wire::StateResult* s = r->result_as_StateResult();
  ASSERT_TRUE(s);
  EXPECT_GE(s->stamp_ns(),
            uint64_t(std::chrono::duration_cast<std::chrono::nanoseconds>(before).count()));
  EXPECT_LE(s->stamp_ns(),
            uint64_t(std::chrono::duration_cast<std::chrono::nanoseconds>(after).count()));
  EXPECT_EQ(s->epoch(), core->world(world)->epoch);
  ASSERT_EQ(send(CommandBuilder().resetWorld())->status(), Code::Ok);
  EXPECT_GT(send(CommandBuilder().queryState())->result_as_StateResult()->epoch(), s->epoch());
}

}  // namespace
}  // namespace phys::server::test
