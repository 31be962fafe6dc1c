// Durable worlds through the SDK against the physd binary (issue 24): the daemon is killed
// with SIGKILL in the middle of a stepping run and of a stream of edits, and started again
// on the same data directory. Every acknowledged command is there, the restored world
// equals an uninterrupted run (an in-process ServerCore given the same commands) at the
// restored tick, bit for bit, and the client's WorldHandle keeps working.
#include <gtest/gtest.h>

#include <chrono>
#include <stop_token>
#include <thread>

#include "../common/bodies.h"
#include "phys/protocol/builder.h"
#include "phys/protocol/decoder.h"
#include "phys/server/core.h"
#include "physd_process.h"

namespace phys::client {
namespace {

using namespace std::chrono_literals;
using protocol::CommandBuilder;

/// physd as a process on a data directory of its own, to be killed and started again.
struct DurableDaemon {
  testing::ScratchDir dir;
  std::string data;
  testing::PhysdConfig cfg;
  DurableDaemon(const std::string& name, uint32_t domain)
      : dir(name), data((dir.path / "data").string()),
        cfg(dir.path, name, domain, "data = \"" + data + "\"\n") {}
  pid_t spawn() const { return testing::spawnProcess(PHYSD_BINARY, {"--config", cfg.toml}); }
};

/// What the client did that the daemon acknowledged, in order: spawns and steps.
struct Op {
  enum Kind { Spawn, Impulse, Step } kind;
  std::vector<phys::BodyDef> bodies;
  uint64_t body = 0;
  phys::Vec3 impulse;
  uint32_t steps = 0;
};

/// The uninterrupted run: a ServerCore without DDS given the same commands.
struct Reference {
  server::ServerCore core{[] {
    server::CoreConfig c;
    c.presetsFile = std::string(PHYS_SOURCE_DIR) + "/configs/presets.json";
    c.threads = 1;
    return c;
  }()};
  uint32_t world = 0;
  uint64_t seq = 0;
  Reference() {
    EXPECT_TRUE(core.init().ok());
    EXPECT_TRUE(core.createWorld("kept", "", "", &world).ok());
  }
  void apply(const Op& op) {
    CommandBuilder b;
    if (op.kind == Op::Spawn) b.spawnBodies(op.bodies);
    if (op.kind == Op::Impulse) b.applyImpulse(op.body, op.impulse);
    if (op.kind == Op::Step) b.step(op.steps);
    ++seq;
    auto r = protocol::decodeReply(core.applyBytes(b.finish({7, seq, world}), 7, seq));
    ASSERT_TRUE(r.ok());
    EXPECT_EQ(r->status(), protocol::Code::Ok);
  }
};

TEST(ClientPhysdProcess, AKilledDaemonRestoresEveryAcknowledgedCommand) {
  DurableDaemon d("physd-durable", 200 + uint32_t(getpid() % 29));
  Client c(d.cfg.clientOptions(20s));
  pid_t pid = d.spawn();
  testing::ProcessGuard guard{pid};
  ASSERT_GT(pid, 0);
  c.connect();
  WorldHandle w = c.createWorld({"kept", "", std::nullopt, 0}).get();
  std::vector<Op> done;
  std::vector<phys::BodyDef> defs;
  for (int i = 0; i < 4; ++i) defs.push_back(phys::test::boxBody({0, 0, 0.5f + 1.01f * float(i)}));
  defs.push_back(phys::test::groundBody());
  std::vector<uint64_t> ids = w.spawn(defs).get();
  done.push_back({Op::Spawn, defs, 0, {}, 0});

  for (int round = 0; round < 2; ++round) {
    // Round 0: killed while stepping; round 1: killed in a stream of edits.
    std::vector<Op> acked;
    std::optional<Op> inFlight;
    std::mutex m;
    // A jthread: a failed assertion below leaves the round with the driver asked to stop and
    // joined (a joinable std::thread destroyed would end the whole test binary).
    std::jthread driver([&](std::stop_token stop) {
      for (int i = 0; !stop.stop_requested(); ++i) {
        Op op;
        if (round == 0 || i % 3 == 2) {
          op = {Op::Step, {}, 0, {}, uint32_t(1 + i % 4)};
        } else if (i % 3 == 0) {
          op = {Op::Spawn, {phys::test::boxBody({2.0f + float(i % 5), 0, 3})}, 0, {}, 0};
        } else {
          op = {Op::Impulse, {}, ids[size_t(i) % 4], {0.2f, 0, 0}};
        }
        {
          std::lock_guard<std::mutex> lock(m);
          inFlight = op;
        }
        try {
          if (op.kind == Op::Step) w.step(op.steps, {2s}).get();
          if (op.kind == Op::Spawn) w.spawn(op.bodies, {2s}).get();
          if (op.kind == Op::Impulse) w.applyImpulse(op.body, op.impulse, {}, {}, {2s}).get();
        } catch (const Error&) {
          return;  // the daemon is gone: this one was not acknowledged
        }
        std::lock_guard<std::mutex> lock(m);
        acked.push_back(op);
        inFlight.reset();
      }
    });
    std::this_thread::sleep_for(round == 0 ? 700ms : 900ms);
    ASSERT_EQ(kill(pid, SIGKILL), 0);
    int st = 0;
    ASSERT_EQ(waitpid(pid, &st, 0), pid);
    pid = 0;
    driver.request_stop();
    driver.join();
    ASSERT_GT(acked.size(), 5u) << "the client barely ran before the kill";

    pid = d.spawn();
    ASSERT_GT(pid, 0);
    ASSERT_TRUE(testing::awaitReconnects(c, uint64_t(round + 1)));
    // The same handle: same world id, same body ids.
    StateFrame s = w.queryState().get();
    // The uninterrupted run, with the acknowledged commands, and with the one in flight if
    // the daemon had stored it before it died (it may have: its reply had not gone out yet).
    Reference ref;
    for (const Op& op : done) ref.apply(op);
    for (const Op& op : acked) ref.apply(op);
    const server::ServerWorld* rw = ref.core.world(ref.world);
    if ((s.tick > rw->tick || s.total > uint32_t(rw->world->bodyCount())) && inFlight)
      ref.apply(*inFlight), acked.push_back(*inFlight);
    ASSERT_EQ(s.tick, rw->tick) << "round " << round;
    ASSERT_EQ(s.total, uint32_t(rw->world->bodyCount())) << "round " << round;
    for (const BodyState& b : s.bodies) {
      phys::BodyState e;
      ASSERT_TRUE(rw->world->getBody(phys::BodyId::fromPacked(b.id), &e).ok()) << b.id;
      EXPECT_EQ(b.position.x, e.position.x);
      EXPECT_EQ(b.position.y, e.position.y);
      EXPECT_EQ(b.position.z, e.position.z);
      EXPECT_EQ(b.rotation.w, e.rotation.w);
    }
    // And it goes on: the handle still works on the restored world.
    EXPECT_EQ(w.step(2).get().tick, s.tick + 2);
    done.insert(done.end(), acked.begin(), acked.end());
    done.push_back({Op::Step, {}, 0, {}, 2});
  }
  ASSERT_EQ(kill(pid, SIGTERM), 0);
  int st = 0;
  ASSERT_EQ(waitpid(pid, &st, 0), pid);
  pid = 0;
  EXPECT_TRUE(WIFEXITED(st) && WEXITSTATUS(st) == 0);
}

TEST(ClientPhysdProcess, SubscriptionsGoOnAfterTheDaemonIsKilledAndRestarted) {
  // A running world; one subscription to its own stream and one to an interest (one body).
  // physd is SIGKILLed and restarted on its data: both subscriptions deliver frames of the
  // restored world again, the interest one only the body it asked for (the SDK subscribed
  // it again: the new daemon kept no interests, and numbered its interests anew).
  DurableDaemon d("physd-resubscribe", 200 + uint32_t((getpid() + 7) % 29));
  Client c(d.cfg.clientOptions(20s));
  pid_t pid = d.spawn();
  testing::ProcessGuard guard{pid};
  ASSERT_GT(pid, 0);
  c.connect();
  // No gravity, three boxes drifting apart at 1 m/s: every tick changes every body.
  WorldHandle w =
      c.createWorld({"watched", "", phys::Vec3{0, 0, 0}, 0, "", /*sleep=*/false}).get();
  std::vector<phys::BodyDef> defs;
  for (float x : {-3.0f, 0.0f, 3.0f}) {
    defs.push_back(phys::test::boxBody({x, 0, 3}));
    defs.back().linearVelocity = {x / 3, 1, 0};
  }
  const std::vector<uint64_t> ids = w.spawn(defs).get();
  w.run(60).get();
  Subscription all = w.subscribe();
  Interest one;
  one.bodies = {ids[1]};
  Subscription some = w.subscribe(one);
  auto frameAfter = [](Subscription& s, uint64_t n) {
    const auto end = std::chrono::steady_clock::now() + 20s;
    while (s.framesReceived() < n && std::chrono::steady_clock::now() < end)
      std::this_thread::sleep_for(10ms);
    return s.framesReceived() >= n;
  };
  ASSERT_TRUE(frameAfter(all, 5));
  ASSERT_TRUE(frameAfter(some, 5));
  ASSERT_EQ(kill(pid, SIGKILL), 0);
  int st = 0;
  ASSERT_EQ(waitpid(pid, &st, 0), pid);
  pid = 0;
  const uint64_t allBefore = all.framesReceived(), someBefore = some.framesReceived();
  pid = d.spawn();
  ASSERT_GT(pid, 0);
  ASSERT_TRUE(testing::awaitReconnects(c, 1));
  EXPECT_TRUE(frameAfter(all, allBefore + 5)) << all.framesReceived() << " frames";
  EXPECT_TRUE(frameAfter(some, someBefore + 5)) << some.framesReceived() << " frames";
  std::optional<StateFrame> f = some.latest();
  ASSERT_TRUE(f.has_value());
  ASSERT_EQ(f->bodies.size(), 1u);
  EXPECT_EQ(f->bodies[0].id, ids[1]);
  f = all.latest();
  ASSERT_TRUE(f.has_value());
  EXPECT_EQ(f->bodies.size(), 3u);
  ASSERT_EQ(kill(pid, SIGTERM), 0);
  ASSERT_EQ(waitpid(pid, &st, 0), pid);
  pid = 0;
  EXPECT_TRUE(WIFEXITED(st) && WEXITSTATUS(st) == 0);
}

}  // namespace
}  // namespace phys::client
