// The client SDK against physd's components in-process (core, tick thread, DDS endpoint) on
// loopback DDS. Each test process uses a domain id of its own range (230 or 231, unused by
// tests/server and tests/protocol; 232 is avoided: its ports overflow 65535 for high participant
// indices) and a Cyclone discovery tag made from its process id, so tests running in parallel never
// see each other's daemons.
#include <gtest/gtest.h>
#include <unistd.h>

#include <atomic>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <future>
#include <limits>
#include <map>
#include <memory>
#include <mutex>
#include <set>
#include <sstream>
#include <thread>

#include "../common/bodies.h"
#include "../common/sanitizer.h"
#include "phys/client/client.h"
#include "phys/server/core.h"
#include "phys/server/endpoint.h"
#include "in_process_daemon.h"

namespace phys::client {
namespace {

using namespace std::chrono_literals;
// A loaded 2-core machine; 10x under a sanitizer (tests/common/sanitizer.h).
constexpr auto kTimeout = std::chrono::milliseconds(int64_t(20000 * test::kTimeFactor));
/// How long a frame may take to reach every matched reader before the test steps again (the
/// warm-ups step until their readers are matched: a frame before that never arrives).
constexpr auto kDelivery = std::chrono::milliseconds(int64_t(500 * test::kTimeFactor));
/// A new subscription's whole state (docs/CLIENT.md "Subscriptions"): matching, the server's
/// look at its subscribers (every 250 ms) and one turn of its tick thread: well under 2 s.
constexpr auto kKeyframe = std::chrono::milliseconds(int64_t(2000 * test::kTimeFactor));

ClientOptions options(std::string name = "client-test") {
  return testing::inProcessOptions(std::move(name));
}

server::CoreConfig coreConfig() {
  server::CoreConfig c = testing::withSourceTree();
  c.snapshotDir = (std::filesystem::temp_directory_path() /
                   ("physclient_test_snapshots_" + std::to_string(getpid())))
                      .string();
  return c;
}

/// The daemon's components, as physd's main() wires them, with a snapshot folder.
struct Daemon : testing::InProcessDaemon {
  Daemon() : InProcessDaemon(coreConfig()) {}
};

using phys::test::boxBody;
using phys::test::groundBody;

std::vector<phys::BodyDef> grid(int n) {
  std::vector<phys::BodyDef> v{groundBody()};
  for (int i = 0; i < n; ++i) v.push_back(boxBody({float(i % 50) * 2, float(i / 50) * 2, 1}));
  return v;
}

template <class F>
ErrorCode codeOf(F&& f) {
  try {
    f();
  } catch (const Error& e) {
    EXPECT_FALSE(e.message().empty());
    return e.code();
  }
  return ErrorCode::Ok;
}

template <class Pred>
bool waitFor(Pred pred, std::chrono::milliseconds timeout = kTimeout) {
  auto end = std::chrono::steady_clock::now() + timeout;
  while (std::chrono::steady_clock::now() < end) {
    if (pred()) return true;
    std::this_thread::sleep_for(5ms);
  }
  return pred();
}

/// What a subscription was given: each tick's frame, in the order delivered.
struct TickLog {
  std::mutex m;
  std::map<uint64_t, StateFrame> frames;
  std::vector<uint64_t> order;
  void add(const StateFrame& f) {
    std::lock_guard<std::mutex> lk(m);
    frames[f.tick] = f;
    order.push_back(f.tick);
  }
  bool has(uint64_t t) {
    std::lock_guard<std::mutex> lk(m);
    return frames.count(t) > 0;
  }
};

/// A subscriber on a client of its own whose callback can be held: arm() makes the next
/// callback wait (on the SDK thread, as a slow application would) until release(). Released
/// on every path out of a test (a failed ASSERT included), and the client (which joins its
/// SDK thread, the one running the callback) goes before what the callback touches.
struct HeldSubscriber {
  explicit HeldSubscriber(uint32_t world) {
    sub = client->subscribe(world, [this, released = released](const StateFrame& f) {
      log.add(f);
      if (armed.exchange(false)) released.wait();
    });
  }
  ~HeldSubscriber() {
    release();
    sub.reset();
    client.reset();
  }
  /// Steps `w` until this subscriber and `observed` both have a tick (their readers are
  /// matched), then one more tick, whose callback it holds. That tick, or 0 if it failed.
  uint64_t holdNextTick(WorldHandle& w, TickLog& observed) {
    uint64_t tick = 0;
    const bool matched = waitFor([&] {
      tick = w.step(1).get().tick;
      return waitFor([&] { return observed.has(tick) && log.has(tick); }, kDelivery);
    });
    if (!matched) return 0;
    armed = true;
    const uint64_t held = w.step(1).get().tick;
    return waitFor([&] { return log.has(held) && !armed; }) ? held : 0;
  }
  void release() {
    if (!std::exchange(done, true)) promise.set_value();
  }
  std::unique_ptr<Client> client = std::make_unique<Client>(options("slow"));
  std::promise<void> promise;
  std::shared_future<void> released = promise.get_future().share();
  bool done = false;
  std::atomic<bool> armed{false};
  TickLog log;
  Subscription sub;
};

// The client is created before the daemon: its participant then owns the process's domain,
// so the daemon can be stopped and started under it.
struct Env {
  Client client{options()};
  std::unique_ptr<Daemon> daemon = std::make_unique<Daemon>();
};

TEST(ClientSdk, RoundTripOfEveryCommand) {
  Env env;
  Client& c = env.client;
  ServerInfo info = c.connect();
  EXPECT_EQ(info.protocolVersion, protocol::kProtocolVersion);
  EXPECT_EQ(info.name, "physd");
  EXPECT_TRUE(c.connected());
  EXPECT_EQ(c.hello().get().name, "physd");

  WorldHandle w = c.createWorld({"rt", "", phys::Vec3{0, 0, -9.81f}, 0}).get();
  ASSERT_TRUE(w);
  auto worlds = c.listWorlds().get();
  ASSERT_EQ(worlds.size(), 1u);
  EXPECT_EQ(worlds[0].name, "rt");
  EXPECT_EQ(c.worldNamed("rt").id(), w.id());

  auto defs = grid(4);
  std::vector<uint64_t> ids = w.spawn(defs).get();
  ASSERT_EQ(ids.size(), defs.size());
  const uint64_t a = ids[1], b = ids[2];
  EXPECT_EQ(w.spawn(boxBody({20, 20, 1})).get().size(), 1u);

  phys::JointDef j;
  j.type = phys::JointType::Ball;
  j.bodyA = phys::BodyId::fromPacked(a);
  j.bodyB = phys::BodyId::fromPacked(b);
  j.anchorA = {1, 0, 0};
  j.anchorB = {-1, 0, 0};
  std::vector<uint64_t> joints = w.addJoints(std::span(&j, 1)).get();
  ASSERT_EQ(joints.size(), 1u);

  w.setPose(a, {0, 0, 3}, {}).get();
  w.setVelocity(a, {1, 0, 0}, {0, 0, 1}).get();
  w.applyForce(a, {0, 0, 100}).get();
  w.applyImpulse(b, {1, 0, 0}, {0.5f, 0, 0}, PointFrame::Local).get();
  w.applyTorque(b, {0, 0, 1}).get();
  phys::Material m;
  m.friction = 0.3f;
  w.setMaterial(std::span(&a, 1), m).get();
  SolverOverrides so;
  so.iterations = 12;
  w.setSolver("", so).get();

  Ack stepped = w.step(3).get();
  EXPECT_EQ(stepped.world, w.id());
  StateFrame q = w.queryState().get();
  EXPECT_EQ(q.total, ids.size() + 1);
  EXPECT_EQ(q.bodies.size(), ids.size() + 1);
  EXPECT_EQ(q.tick, 3u);
  StateFrame one = w.queryState(std::span(&a, 1)).get();
  ASSERT_EQ(one.bodies.size(), 1u);
  EXPECT_EQ(one.bodies[0].id, a);

  // Snapshot bytes: save, step on, restore -> back at the saved tick.
  Bytes snap = w.saveSnapshot().get();
  EXPECT_FALSE(snap.empty());
  w.step(5).get();
  EXPECT_EQ(w.queryState().get().tick, 8u);
  w.restoreSnapshot(snap).get();
  EXPECT_EQ(w.queryState().get().tick, 3u);
  // Snapshot file on the server.
  w.saveSnapshotFile("rt_snap").get();
  w.step(2).get();
  w.restoreSnapshotFile("rt_snap").get();
  EXPECT_EQ(w.queryState().get().tick, 3u);

  w.run(120).get();
  ASSERT_TRUE(waitFor([&] { return w.queryState().get().tick > 3; }));
  w.pause().get();
  auto running = c.listWorlds().get();
  ASSERT_EQ(running.size(), 1u);
  EXPECT_FALSE(running[0].running);
  // Where it runs: the server's default backend (cpu), every step on the CPU.
  EXPECT_EQ(running[0].backend, "cpu");
  EXPECT_TRUE(running[0].device.empty());
  EXPECT_TRUE(running[0].backendNote.empty()) << running[0].backendNote;
  EXPECT_GT(running[0].cpuSteps, 0u);
  EXPECT_EQ(running[0].gpuSteps, 0u);

  w.removeJoints(joints).get();
  w.removeBodies(std::span(&b, 1)).get();
  EXPECT_EQ(w.queryState().get().total, ids.size());

  Ids scene = w.loadScene("restitution").get();
  EXPECT_FALSE(scene.bodies.empty());
  EXPECT_EQ(w.queryState().get().total, scene.bodies.size());
  Ids inline_ = w.loadSceneJson(R"({"bodies": []})").get();
  (void)inline_;
  w.reset().get();
  EXPECT_EQ(w.queryState().get().total, 0u);
  w.destroy().get();
  EXPECT_TRUE(c.listWorlds().get().empty());

  // The status topic reaches the client.
  EXPECT_TRUE(waitFor([&] { return c.latestStatus().has_value(); }));
}

TEST(ClientSdk, ErrorRepliesAreTypedErrors) {
  Env env;
  Client& c = env.client;
  c.connect();
  EXPECT_EQ(codeOf([&] { c.world(987654).step(1).get(); }), ErrorCode::NotFound);
  WorldHandle w = c.createWorld({"err", "", std::nullopt, 0}).get();
  auto ids = w.spawn(grid(2)).get();
  EXPECT_EQ(codeOf([&] { w.setPose(0xDEAD00000007ull, {0, 0, 1}).get(); }), ErrorCode::NotFound);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  EXPECT_EQ(codeOf([&] { w.setVelocity(ids[1], {nan, 0, 0}).get(); }), ErrorCode::InvalidArgument);
  EXPECT_EQ(codeOf([&] {
              c.createWorld({"err", "", std::nullopt, 0}).get();
            }),
            ErrorCode::InvalidArgument);
  EXPECT_EQ(codeOf([&] { w.loadScene("no_such_scene").get(); }), ErrorCode::NotFound);
  try {
    c.createWorld({"warp", "", std::nullopt, 0, "warp"}).get();
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_EQ(e.code(), ErrorCode::InvalidArgument);
    EXPECT_NE(e.message().find("create_world.backend must be"), std::string::npos) << e.message();
  }
  EXPECT_EQ(c.listWorlds().get().size(), 1u);  // no world "warp"
  try {
    w.applyForce(ids[1], {0, std::numeric_limits<float>::infinity(), 0}).get();
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_EQ(e.code(), ErrorCode::InvalidArgument);
    EXPECT_TRUE(e.fromServer());
    EXPECT_NE(e.message().find("finite"), std::string::npos) << e.message();
  }
  // The world is unchanged and the client keeps working.
  EXPECT_EQ(w.queryState().get().total, ids.size());
}

TEST(ClientSdk, RequestTimesOutWithoutServer) {
  ClientOptions o = options();
  o.connectTimeout = 1500ms;
  o.requestTimeout = 500ms;
  Client c(o);
  try {
    c.connect();
    FAIL() << "connected without a server";
  } catch (const Error& e) {
    EXPECT_EQ(e.code(), ErrorCode::Timeout);
    EXPECT_FALSE(e.fromServer());
  }
  EXPECT_FALSE(c.connected());
  EXPECT_EQ(codeOf([&] { c.listWorlds().get(); }), ErrorCode::Timeout);
  EXPECT_EQ(codeOf([&] { c.world(1).step(1, {200ms}).get(); }), ErrorCode::Timeout);
}

TEST(ClientSdk, SubscriptionDeliversEveryBodyOfATick) {
  Env env;
  Client& c = env.client;
  c.connect();
  WorldHandle w = c.createWorld({"sub", "", std::nullopt, 0}).get();
  auto ids = w.spawn(grid(2400)).get();  // 2401 bodies: 3 chunks
  std::mutex m;
  std::map<uint64_t, size_t> seen;  // tick -> bodies, from the callback
  Subscription sub = w.subscribe([&](const StateFrame& f) {
    std::lock_guard<std::mutex> lk(m);
    seen[f.tick] = f.bodies.size();
  });
  ASSERT_TRUE(sub);
  w.run(30).get();
  auto frame = sub.waitForFrame(0, kTimeout);
  ASSERT_TRUE(frame);
  EXPECT_EQ(frame->world, w.id());
  EXPECT_EQ(frame->total, ids.size());
  std::set<uint64_t> got;
  for (const BodyState& s : frame->bodies) got.insert(s.id);
  EXPECT_EQ(got, std::set<uint64_t>(ids.begin(), ids.end()));
  // Stamped by the server's wall clock when it read the states: in the past, and recent.
  const auto now = std::chrono::duration_cast<std::chrono::nanoseconds>(
      std::chrono::system_clock::now().time_since_epoch());
  EXPECT_LE(frame->stampNs, uint64_t(now.count()));
  EXPECT_GT(frame->stampNs, uint64_t((now - std::chrono::seconds(30)).count()));
  w.pause().get();
  std::lock_guard<std::mutex> lk(m);
  EXPECT_FALSE(seen.empty());
  for (auto& [tick, n] : seen) EXPECT_EQ(n, ids.size()) << "tick " << tick;
}

// Issue 22: the server sends keyframes and deltas; the SDK rebuilds every tick's full state.
// Over 10 s of a world where some bodies fall, some drift and most fall asleep, every frame the
// subscription delivers equals the world's state at its tick, bit for bit (full encoding).
TEST(ClientSdk, RebuiltStateEqualsTheWorldsEveryTick) {
  Env env;
  Client& c = env.client;
  c.connect();
  WorldHandle w = c.createWorld({"delta", "", std::nullopt, 0}).get();  // sleeps by default
  std::vector<phys::BodyDef> defs = grid(60);  // the ground and 60 boxes resting on it
  for (int i = 0; i < 10; ++i) {
    phys::BodyDef d = boxBody({float(i) * 3, 40, 5});
    d.gravityScale = 0;
    d.linearVelocity = {0, 0.3f, 0};  // drifting for good
    defs.push_back(d);
    defs.push_back(boxBody({float(i) * 3, -20, 2 + float(i)}));  // falling, then asleep
  }
  const auto ids = w.spawn(defs).get();
  std::mutex m;
  std::map<uint64_t, StateFrame> got;
  Subscription sub = w.subscribe([&](const StateFrame& f) {
    std::lock_guard<std::mutex> lk(m);
    got[f.tick] = f;
  });
  // Until the subscription is matched and has its first keyframe.
  uint64_t tick = 0;
  ASSERT_TRUE(waitFor([&] {
    tick = w.step(1).get().tick;
    return waitFor(
        [&] {
          std::lock_guard<std::mutex> lk(m);
          return got.count(tick) > 0;
        },
        300ms);
  }));
  size_t deltas = 0, changedInDeltas = 0;
  for (int i = 0; i < 600; ++i) {
    if (i == 300) {  // a body removed and one spawned: both in the next delta
      const std::vector<uint64_t> gone = {ids[5]};
      w.removeBodies(gone).get();
      w.spawn(boxBody({-30, 0, 3})).get();
    }
    tick = w.step(1).get().tick;
    ASSERT_TRUE(waitFor([&] {
      std::lock_guard<std::mutex> lk(m);
      return got.count(tick) > 0;
    })) << "tick "
        << tick;
    const StateFrame truth = w.queryState().get();
    ASSERT_EQ(truth.tick, tick);
    StateFrame f;
    {
      std::lock_guard<std::mutex> lk(m);
      f = got[tick];
      got.clear();
    }
    ASSERT_EQ(truth.bodies.size(), ids.size());  // one removed, one spawned at 300
    ASSERT_EQ(f.bodies.size(), truth.bodies.size());
    std::map<uint64_t, BodyState> want;
    for (const BodyState& b : truth.bodies) want[b.id] = b;
    for (const BodyState& b : f.bodies) {
      const BodyState& t = want.at(b.id);
      ASSERT_TRUE(std::memcmp(&b.position, &t.position, sizeof t.position) == 0 &&
                  std::memcmp(&b.rotation, &t.rotation, sizeof t.rotation) == 0 &&
                  std::memcmp(&b.linearVelocity, &t.linearVelocity, sizeof t.linearVelocity) == 0 &&
                  std::memcmp(&b.angularVelocity, &t.angularVelocity, sizeof t.angularVelocity) ==
                      0)
          << "body " << b.id << " at tick " << tick;
    }
    if (!f.keyframe) {
      ++deltas;
      changedInDeltas += f.changed;
      // Marked changed: exactly the bodies this tick's frame carried.
      size_t marked = 0;
      for (const BodyState& b : f.bodies) marked += b.changed;
      ASSERT_EQ(marked, f.changed) << "tick " << tick;
    }
  }
  // Most frames were deltas, and once the boxes slept they carried the drifting ones only.
  EXPECT_GT(deltas, 500u);
  EXPECT_LT(double(changedInDeltas) / double(deltas), 0.5 * double(ids.size()));
}

// A subscriber that comes while the world runs has every body within a keyframe's time.
TEST(ClientSdk, LateSubscriberHasTheFullStateWithinAKeyframe) {
  Env env;
  Client& c = env.client;
  c.connect();
  WorldHandle w = c.createWorld({"late", "", std::nullopt, 0}).get();
  const auto ids = w.spawn(grid(300)).get();
  w.run(60).get();
  std::this_thread::sleep_for(1500ms);  // everything asleep; deltas are empty now
  const auto start = std::chrono::steady_clock::now();
  Subscription sub = w.subscribe();
  auto frame = sub.waitForFrame(0, kTimeout);
  const double waited =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  ASSERT_TRUE(frame);
  EXPECT_EQ(frame->bodies.size(), ids.size());
  EXPECT_EQ(frame->total, ids.size());
  // Matching plus the server's look at its subscribers (every 250 ms) plus a keyframe every
  // 60 ticks (1 s): well under 2 s.
  EXPECT_LT(waited, 2.0);
  w.pause().get();
}

// A second subscriber to a paused world gets a keyframe at the tick the first already has;
// the first applies it again, so the deltas after it still apply for both.
TEST(ClientSdk, ASecondSubscriberToAPausedWorldBreaksNobodysDeltas) {
  Env env;
  Client& c = env.client;
  c.connect();
  WorldHandle w = c.createWorld({"paused", "", std::nullopt, 0}).get();
  // A box at rest in zero gravity: after the first keyframe every delta is empty.
  phys::BodyDef still = boxBody({0, 0, 5});
  still.gravityScale = 0;
  const uint64_t id = w.spawn(still).get()[0];
  Subscription a = w.subscribe();
  uint64_t tick = 0;
  ASSERT_TRUE(waitFor([&] {
    tick = w.step(1).get().tick;
    return a.waitForFrame(tick - 1, 300ms).has_value();
  }));
  for (int i = 0; i < 3; ++i) {  // empty deltas: a holds the state as of an earlier tick
    tick = w.step(1).get().tick;
    ASSERT_TRUE(a.waitForFrame(tick - 1, kTimeout));
  }
  Subscription b = w.subscribe();
  // An edit while paused (since issue 40 b's keyframe needs none): b's keyframe goes out at
  // once, at the tick a already has.
  std::this_thread::sleep_for(400ms);  // physd counts b (every 250 ms)
  const std::vector<uint64_t> ids = {id};
  w.setMaterial(ids, phys::Material{0.3f, 0, 1000}).get();
  ASSERT_TRUE(b.waitForFrame(0, kTimeout).has_value());
  for (int i = 0; i < 5; ++i) {
    tick = w.step(1).get().tick;
    auto fa = a.waitForFrame(tick - 1, kTimeout), fb = b.waitForFrame(tick - 1, kTimeout);
    ASSERT_TRUE(fa && fb) << "tick " << tick;
    EXPECT_EQ(fa->tick, tick);
    EXPECT_EQ(fb->tick, tick);
  }
  EXPECT_EQ(a.framesSkipped(), 0u);
  EXPECT_EQ(b.framesSkipped(), 0u);
}

/// The subscription's first frame, within kKeyframe (none: nullopt).
std::optional<StateFrame> firstFrame(Subscription& s) {
  return s.waitForFrame(0, kKeyframe);
}

/// Every body of f equals the world's now (QueryState), bit for bit, and f is at its tick.
void expectWorldsState(WorldHandle& w, const StateFrame& f, const char* what) {
  const StateFrame truth = w.queryState().get();
  EXPECT_EQ(f.tick, truth.tick) << what;
  EXPECT_EQ(f.epoch, truth.epoch) << what;
  ASSERT_EQ(f.bodies.size(), truth.bodies.size()) << what;
  std::map<uint64_t, BodyState> want;
  for (const BodyState& b : truth.bodies) want[b.id] = b;
  for (const BodyState& b : f.bodies) {
    ASSERT_TRUE(want.count(b.id)) << what << ": body " << b.id;
    const BodyState& t = want[b.id];
    EXPECT_TRUE(std::memcmp(&b.position, &t.position, sizeof t.position) == 0 &&
                std::memcmp(&b.rotation, &t.rotation, sizeof t.rotation) == 0)
        << what << ": body " << b.id;
  }
}

// Issue 40, finding 1: new subscribers to a paused world got nothing (a keyframe waited for a
// step), and one opened just after another closed never got its keyframe. Now a new
// subscription, the world's own or an interest, has the whole state within 2 s in every
// state of the world, whatever the order subscriptions open and close in.
TEST(ClientSdk, ANewSubscriptionGetsTheWholeStateInEveryWorldState) {
  Env env;
  Client& c = env.client;
  c.connect();
  WorldHandle w = c.createWorld({"states", "", std::nullopt, 0}).get();
  w.spawn(grid(300)).get();
  struct Case {
    const char* what;
    std::function<void()> setUp;
  };
  Bytes snapshot;
  const std::vector<Case> cases = {
      {"paused, never stepped (tick 0)", [] {}},
      {"paused after steps, asleep", [&] { w.step(120).get(); }},
      {"running, asleep",
       [&] {
         w.run(60).get();
         std::this_thread::sleep_for(300ms);
       }},
      {"paused again", [&] {
         w.pause().get();
         snapshot = w.saveSnapshot().get();
         w.step(30).get();
       }},
      {"just restored (paused)", [&] { w.restoreSnapshot(snapshot).get(); }},
      {"just reset (paused, empty)", [&] { w.reset().get(); }},
      {"bodies spawned after the reset", [&] { w.spawn(grid(50)).get(); }},
  };
  for (const Case& k : cases) {
    k.setUp();
    const bool running = std::string(k.what).starts_with("running");
    Subscription s = w.subscribe();
    auto f = firstFrame(s);
    ASSERT_TRUE(f) << k.what << ": no frame within 2 s";
    const StateFrame truth = w.queryState().get();
    EXPECT_EQ(f->total, truth.total) << k.what;
    EXPECT_EQ(f->bodies.size(), truth.bodies.size()) << k.what;
    if (!running) expectWorldsState(w, *f, k.what);
  }
  // Running and asleep (empty deltas, a slow refresh: 10 s a round for a world at rest): one
  // opened just after another closed has the whole state at once, not after a round.
  w.run(60).get();
  std::this_thread::sleep_for(2s);  // the spawned boxes settle and sleep
  {
    Subscription r1 = w.subscribe();
    ASSERT_TRUE(firstFrame(r1)) << "running";
  }
  Subscription r2 = w.subscribe();
  auto fr = firstFrame(r2);
  ASSERT_TRUE(fr) << "running, asleep, opened just after another closed";
  EXPECT_EQ(fr->bodies.size(), w.queryState().get().total);
  r2.reset();
  w.pause().get();
  const uint64_t count = w.queryState().get().total;
  // Closing and opening in any order, on the paused world: each new one gets its frame at once,
  // each one still open goes on with the next tick.
  Subscription a = w.subscribe();
  ASSERT_TRUE(firstFrame(a)) << "a";
  a.reset();
  Subscription b = w.subscribe();  // just after a closed: the same count at physd's next look
  ASSERT_TRUE(firstFrame(b)) << "b, opened just after a closed";
  Subscription d = w.subscribe();
  b.reset();
  Subscription e = w.subscribe();
  ASSERT_TRUE(firstFrame(d)) << "d";
  ASSERT_TRUE(firstFrame(e)) << "e, opened just after b closed";
  // An interest opened just after another on the same world closed.
  const auto now = w.queryState().get();
  std::vector<uint64_t> live;
  for (size_t k = 0; k < 10 && k < now.bodies.size(); ++k) live.push_back(now.bodies[k].id);
  Subscription i1 = w.subscribe(Interest{live, std::nullopt});
  auto fi = firstFrame(i1);
  ASSERT_TRUE(fi) << "an interest on a paused world";
  EXPECT_EQ(fi->bodies.size(), live.size());
  i1.reset();
  Subscription i2 = w.subscribe(Interest{live, std::nullopt});
  fi = firstFrame(i2);
  ASSERT_TRUE(fi) << "an interest opened just after another closed";
  EXPECT_EQ(fi->bodies.size(), live.size());
  // A step: every open subscription has it.
  const uint64_t next = w.step(1).get().tick;
  for (Subscription* s : {&d, &e, &i2}) {
    auto f = s->waitForFrame(next - 1, kKeyframe);
    ASSERT_TRUE(f);
    EXPECT_EQ(f->tick, next);
  }
  EXPECT_EQ(d.latest()->bodies.size(), count);
}

// Issue 40, finding 2: a restore to an earlier tick, or a reset, froze every subscription until
// the world passed its old tick again (the SDK dropped frames whose tick was not above the
// last one delivered). Both start a new epoch of the world's ticks: the subscription delivers
// its first frame at once, with the epoch, and goes on from there; waitForFrame with the old
// tick returns it too.
TEST(ClientSdk, RestoreAndResetStartANewEpochThatSubscribersFollowAtOnce) {
  Env env;
  Client& c = env.client;
  c.connect();
  WorldHandle w = c.createWorld({"epochs", "", std::nullopt, 0}).get();
  std::vector<phys::BodyDef> defs = grid(40);
  for (int i = 0; i < 10; ++i) defs.push_back(boxBody({float(i) * 3, 30, 4 + float(i)}));  // falling
  w.spawn(defs).get();
  w.step(5).get();
  const Bytes snapshot = w.saveSnapshot().get();
  TickLog log;
  Subscription sub = w.subscribe([&](const StateFrame& f) { log.add(f); });
  ASSERT_TRUE(firstFrame(sub));
  ASSERT_EQ(w.step(72).get().tick, 77u);
  auto f = sub.waitForFrame(76, kTimeout);
  ASSERT_TRUE(f);
  ASSERT_EQ(f->tick, 77u);
  const uint64_t before = f->epoch;
  EXPECT_GE(before, 1u);
  // Restored to tick 5 while paused: the frame of tick 5 within 2 s, no step needed.
  w.restoreSnapshot(snapshot).get();
  f = sub.waitForFrame(77, kKeyframe);
  ASSERT_TRUE(f) << "the subscription froze after a restore to an earlier tick";
  EXPECT_EQ(f->tick, 5u);
  EXPECT_GT(f->epoch, before);
  expectWorldsState(w, *f, "restored");
  const uint64_t restored = f->epoch;
  // And on from there, tick by tick.
  for (uint64_t t = 6; t <= 8; ++t) {
    ASSERT_EQ(w.step(1).get().tick, t);
    f = sub.waitForFrame(t - 1, kTimeout);
    ASSERT_TRUE(f) << "tick " << t;
    EXPECT_EQ(f->tick, t);
    EXPECT_EQ(f->epoch, restored);
    expectWorldsState(w, *f, "after the restore");
  }
  // A running world restored: its subscribers follow too.
  w.run(60).get();
  ASSERT_TRUE(waitFor([&] { return sub.latest()->tick > 30; }));
  w.restoreSnapshot(snapshot).get();
  ASSERT_TRUE(waitFor([&] { return sub.latest()->epoch > restored; }, kKeyframe))
      << "a running world's restore";
  EXPECT_LT(sub.latest()->tick, 30u);
  w.pause().get();
  // A reset: tick 0 of a new epoch, an empty world, at once.
  const uint64_t last = sub.latest()->tick, running = sub.latest()->epoch;
  w.reset().get();
  f = sub.waitForFrame(last, kKeyframe);
  ASSERT_TRUE(f) << "the subscription froze after a reset";
  EXPECT_EQ(f->tick, 0u);
  EXPECT_GT(f->epoch, running);
  EXPECT_EQ(f->total, 0u);
  EXPECT_TRUE(f->bodies.empty());
  EXPECT_EQ(sub.framesSkipped(), 0u);
}

// A callback may touch what its owner destroys right after the Subscription (a log, a
// window): once reset() or the destructor returns, no callback runs, a running one finished.
TEST(ClientSdk, NoCallbackRunsOnceItsSubscriptionIsGone) {
  Env env;
  Client& c = env.client;
  c.connect();
  WorldHandle w = c.createWorld({"gone", "", std::nullopt, 0}).get();
  w.spawn(grid(4)).get();
  std::atomic<bool> inside{false}, gone{false};
  std::atomic<int> calls{0}, callsAfter{0};
  Subscription sub = w.subscribe([&](const StateFrame&) {
    if (gone) ++callsAfter;
    inside = true;
    ++calls;
    std::this_thread::sleep_for(50ms);  // a slow callback: the reset meets it running
    inside = false;
  });
  w.run(60).get();
  ASSERT_TRUE(waitFor([&] { return calls >= 2 && inside; }));
  sub.reset();
  gone = true;
  EXPECT_FALSE(inside) << "reset() returned while the callback ran";
  std::this_thread::sleep_for(300ms);  // ticks go on at 60 Hz
  EXPECT_EQ(callsAfter, 0);
  w.pause().get();
}

// SERVER.md "Time control": a paused world's subscribers see spawns and pose edits. They did
// not until the world stepped (issue 40); now each edit comes at once as a frame of the same
// tick (its edit number 1, 2, ...), and the next step's frame follows it.
TEST(ClientSdk, EditsToAPausedWorldReachSubscribersAtOnce) {
  Env env;
  Client& c = env.client;
  c.connect();
  WorldHandle w = c.createWorld({"edits", "", std::nullopt, 0}).get();
  const auto ids = w.spawn(grid(100)).get();
  TickLog log;
  Subscription sub = w.subscribe([&](const StateFrame& f) { log.add(f); });
  // Stepped once, so that what follows does not depend on the new subscriber's keyframe.
  const uint64_t tick = w.step(1).get().tick;
  auto f = sub.waitForFrame(tick - 1, kTimeout);
  ASSERT_TRUE(f);
  ASSERT_EQ(f->tick, tick);
  // A pose set: delivered without a step.
  w.setPose(ids[7], {3, 4, 5}).get();
  ASSERT_TRUE(waitFor(
      [&] {
        auto l = sub.latest();
        for (const BodyState& b : l->bodies)
          if (b.id == ids[7]) return b.position.z == 5.0f;
        return false;
      },
      kKeyframe))
      << "a pose set in a paused world did not reach its subscriber";
  f = sub.latest();
  EXPECT_EQ(f->tick, tick);
  EXPECT_EQ(f->edit, 1u);
  EXPECT_FALSE(f->keyframe);
  expectWorldsState(w, *f, "after the pose");
  // A spawn and a removal.
  const uint64_t added = w.spawn(boxBody({-20, 0, 4})).get()[0];
  const std::vector<uint64_t> gone = {ids[3]};
  w.removeBodies(gone).get();
  ASSERT_TRUE(waitFor(
      [&] {
        auto l = sub.latest();
        bool hasAdded = false, hasGone = false;
        for (const BodyState& b : l->bodies) {
          hasAdded |= b.id == added;
          hasGone |= b.id == ids[3];
        }
        return hasAdded && !hasGone;
      },
      kKeyframe))
      << "a spawn or removal in a paused world did not reach its subscriber";
  f = sub.latest();
  EXPECT_EQ(f->tick, tick);
  EXPECT_GE(f->edit, 2u);
  expectWorldsState(w, *f, "after the spawn and removal");
  // The next step follows the edits.
  const uint64_t next = w.step(1).get().tick;
  f = sub.waitForFrame(tick, kTimeout);
  ASSERT_TRUE(f);
  EXPECT_EQ(f->tick, next);
  EXPECT_EQ(f->edit, 0u);
  expectWorldsState(w, *f, "the next step");
  EXPECT_EQ(sub.framesSkipped(), 0u);
}

// Issue 40: frames from query_state carried timestamp 0. They carry the server's wall clock
// when it read the states, as a subscription's frames do, and the world's epoch.
TEST(ClientSdk, QueryStateFramesAreStamped) {
  Env env;
  Client& c = env.client;
  c.connect();
  WorldHandle w = c.createWorld({"stamped", "", std::nullopt, 0}).get();
  w.spawn(grid(10)).get();
  const auto before = std::chrono::duration_cast<std::chrono::nanoseconds>(
      std::chrono::system_clock::now().time_since_epoch());
  const StateFrame f = w.queryState().get();
  const auto after = std::chrono::duration_cast<std::chrono::nanoseconds>(
      std::chrono::system_clock::now().time_since_epoch());
  EXPECT_GE(f.stampNs, uint64_t(before.count()));  // one clock: the daemon is in-process
  EXPECT_LE(f.stampNs, uint64_t(after.count()));
  EXPECT_GE(f.epoch, 1u);
  Subscription sub = w.subscribe();
  auto s = firstFrame(sub);
  ASSERT_TRUE(s);
  EXPECT_EQ(s->epoch, f.epoch);
  w.reset().get();
  EXPECT_GT(w.queryState().get().epoch, f.epoch);
}

// An interest: a subscription to some bodies (or a box) gets exactly those, rebuilt every
// tick, on its own topic.
TEST(ClientSdk, AnInterestDeliversExactlyTheBodiesAskedFor) {
  Env env;
  Client& c = env.client;
  c.connect();
  WorldHandle w = c.createWorld({"interest", "", std::nullopt, 0}).get();
  const auto ids = w.spawn(grid(200)).get();  // ground + 200 boxes on a 50 x 4 grid, 2 m apart
  const std::set<uint64_t> picked = {ids[5], ids[17], ids[150]};
  std::mutex m;
  std::vector<std::set<uint64_t>> byIds, byRegion;
  Subscription a =
      w.subscribe(Interest{{ids[5], ids[17], ids[150]}, std::nullopt}, [&](const StateFrame& f) {
        std::lock_guard<std::mutex> lk(m);
        std::set<uint64_t> got;
        for (const BodyState& b : f.bodies) got.insert(b.id);
        byIds.push_back(got);
      });
  // The box x in [-1, 5], y in [-1, 1]: the boxes at x = 0, 2, 4 of the first row.
  Subscription r =
      w.subscribe(Interest{{}, std::make_pair(phys::Vec3{-1, -1, 0.25f}, phys::Vec3{5, 1, 3})},
                  [&](const StateFrame& f) {
                    std::lock_guard<std::mutex> lk(m);
                    std::set<uint64_t> got;
                    for (const BodyState& b : f.bodies) got.insert(b.id);
                    byRegion.push_back(got);
                  });
  ASSERT_TRUE(waitFor([&] {
    w.step(1).get();
    std::lock_guard<std::mutex> lk(m);
    return byIds.size() >= 3 && byRegion.size() >= 3;
  }));
  std::lock_guard<std::mutex> lk(m);
  for (const auto& got : byIds) EXPECT_EQ(got, picked);
  const std::set<uint64_t> inBox = {ids[1], ids[2], ids[3]};  // not the ground (z = 0)
  for (const auto& got : byRegion) EXPECT_EQ(got, inBox);
}

TEST(ClientSdk, EightSubscribersReceiveEveryBodyOfEveryTick) {
  constexpr int kSubscribers = 8;
  constexpr int kTicks = 4;
  std::vector<std::unique_ptr<Client>> clients;
  for (int i = 0; i < kSubscribers; ++i)
    clients.push_back(std::make_unique<Client>(options("sub" + std::to_string(i))));
  Daemon daemon;
  Client& c = *clients[0];
  c.connect();
  WorldHandle w = c.createWorld({"fanout", "", std::nullopt, 0}).get();
  auto ids = w.spawn(grid(1499)).get();  // 1500 bodies: 2 chunks
  const std::set<uint64_t> all(ids.begin(), ids.end());

  struct Seen {
    std::mutex m;
    std::map<uint64_t, std::set<uint64_t>> ticks;
  };
  std::vector<std::unique_ptr<Seen>> seen;
  std::vector<Subscription> subs;
  for (int i = 0; i < kSubscribers; ++i) {
    seen.push_back(std::make_unique<Seen>());
    Seen* s = seen.back().get();
    subs.push_back(clients[i]->subscribe(w.id(), [s](const StateFrame& f) {
      std::lock_guard<std::mutex> lk(s->m);
      for (const BodyState& b : f.bodies) s->ticks[f.tick].insert(b.id);
    }));
  }
  auto allHave = [&](uint64_t tick) {
    for (auto& s : seen) {
      std::lock_guard<std::mutex> lk(s->m);
      if (!s->ticks.count(tick)) return false;
    }
    return true;
  };
  // Warm up until every reader is matched (a frame before that is not delivered to it).
  uint64_t tick = 0;
  ASSERT_TRUE(waitFor([&] {
    tick = w.step(1).get().tick;
    return waitFor([&] { return allHave(tick); }, kDelivery);
  }));
  // Then every stepped tick reaches every subscriber with every body.
  for (int t = 0; t < kTicks; ++t) {
    tick = w.step(1).get().tick;
    ASSERT_TRUE(waitFor([&] { return allHave(tick); })) << "tick " << tick;
    for (int i = 0; i < kSubscribers; ++i) {
      std::lock_guard<std::mutex> lk(seen[i]->m);
      EXPECT_EQ(seen[i]->ticks[tick], all) << "subscriber " << i << " tick " << tick;
    }
  }
  subs.clear();
}

// A subscriber held up (here: its callback blocks) while three more ticks are published
// still gets each of them afterwards, oldest first: state readers keep the last 4 samples
// per chunk (protocol::kStateReaderDepth). With a reader depth of 1 it would get only the
// newest.
TEST(ClientSdk, SubscriberHeldUpForThreeTicksStillGetsEachOfThem) {
  Env env;
  Client& c = env.client;
  c.connect();
  WorldHandle w = c.createWorld({"held", "", std::nullopt, 0}).get();
  auto ids = w.spawn(grid(1499)).get();  // 1500 bodies: 2 chunks
  TickLog observed;
  Subscription observer = c.subscribe(w.id(), [&](const StateFrame& f) { observed.add(f); });
  HeldSubscriber slow(w.id());
  const uint64_t first = slow.holdNextTick(w, observed);
  ASSERT_NE(first, 0u);
  std::vector<uint64_t> later;
  for (int i = 0; i < 3; ++i) later.push_back(w.step(1).get().tick);
  // Delivered to every reader (the observer has them), while the slow one's thread waits.
  ASSERT_TRUE(waitFor([&] { return observed.has(later.back()); }));
  std::this_thread::sleep_for(200ms);
  EXPECT_FALSE(slow.log.has(later.front()));
  slow.release();
  ASSERT_TRUE(waitFor([&] { return slow.log.has(later.back()); }));
  std::lock_guard<std::mutex> lk(slow.log.m);
  for (uint64_t t : later) {
    ASSERT_TRUE(slow.log.frames.count(t)) << "tick " << t << " lost";
    EXPECT_EQ(slow.log.frames[t].bodies.size(), ids.size()) << "tick " << t;
  }
  EXPECT_TRUE(std::is_sorted(slow.log.order.begin(), slow.log.order.end()));
}

// A subscriber held up for longer than its reader keeps frames (kStateReaderDepth ticks)
// loses some; the server does not know. With the rolling refresh (the default) the SDK keeps
// applying what comes and is whole again once one round of refreshes (keyframe_ticks frames)
// has covered every body: no keyframe needed, and the state it then delivers is the world's.
TEST(ClientSdk, ASubscriberThatLostFramesIsRepairedByTheRollingRefresh) {
  Env env;
  Client& c = env.client;
  c.connect();
  WorldHandle w = c.createWorld({"resync", "", std::nullopt, 0}).get();
  std::vector<phys::BodyDef> defs = grid(100);  // resting, then asleep
  for (int i = 0; i < 10; ++i) {
    phys::BodyDef d = boxBody({float(i) * 3, 40, 5});
    d.gravityScale = 0;
    d.linearVelocity = {0.3f, 0.1f * float(i), 0};  // drifting for good
    defs.push_back(d);
  }
  w.spawn(defs).get();
  TickLog observed;
  Subscription observer = c.subscribe(w.id(), [&](const StateFrame& f) { observed.add(f); });
  HeldSubscriber slow(w.id());
  const uint64_t first = slow.holdNextTick(w, observed);
  ASSERT_NE(first, 0u);
  // Three times what the reader keeps go by while the slow subscriber's thread waits.
  uint64_t last = first;
  for (int i = 0; i < 3 * protocol::kStateReaderDepth; ++i) {
    last = w.step(1).get().tick;
    ASSERT_TRUE(waitFor([&] { return observed.has(last); }));
  }
  const uint64_t skippedBefore = slow.sub.framesSkipped();
  slow.release();
  // Tick by tick until the slow subscriber delivers again.
  uint64_t repaired = 0;
  for (int i = 0; i < 150 && !repaired; ++i) {
    const uint64_t t = w.step(1).get().tick;
    ASSERT_TRUE(waitFor([&] { return observed.has(t); }));
    if (waitFor([&] { return slow.log.has(t); }, 50ms)) repaired = t;
  }
  ASSERT_NE(repaired, 0u) << "the slow subscriber never delivered again";
  EXPECT_GT(slow.sub.framesSkipped(), skippedBefore) << "it did lose frames";
  // One round of refreshes (60 frames) from the first frame it read after the release (the
  // oldest its reader kept).
  EXPECT_LE(repaired - last, 60u + 2);
  const StateFrame truth = w.queryState().get();
  ASSERT_EQ(truth.tick, repaired);
  StateFrame f;
  {
    std::lock_guard<std::mutex> lk(slow.log.m);
    f = slow.log.frames.at(repaired);
  }
  EXPECT_FALSE(f.keyframe) << "repaired by the refreshes, not by a keyframe";
  ASSERT_EQ(f.bodies.size(), truth.bodies.size());
  std::map<uint64_t, BodyState> want;
  for (const BodyState& b : truth.bodies) want[b.id] = b;
  for (const BodyState& b : f.bodies) {
    ASSERT_TRUE(want.count(b.id)) << "body " << b.id;
    const BodyState& t = want.at(b.id);
    EXPECT_TRUE(std::memcmp(&b.position, &t.position, sizeof t.position) == 0 &&
                std::memcmp(&b.rotation, &t.rotation, sizeof t.rotation) == 0 &&
                std::memcmp(&b.linearVelocity, &t.linearVelocity, sizeof t.linearVelocity) == 0)
        << "body " << b.id;
  }
}

TEST(ClientSdk, GuardRailsAreAnnouncedOnTheEventsTopic) {
  Env env;
  Client& c = env.client;
  c.connect();
  std::mutex m;
  std::vector<Event> seen;
  c.onEvent([&](const Event& e) {
    std::lock_guard<std::mutex> lk(m);
    seen.push_back(e);
  });
  WorldHandle w = c.createWorld({"guarded", "", std::nullopt, 0}).get();
  const std::vector<phys::BodyDef> bodies{groundBody(), boxBody({0, 0, 5})};
  auto ids = w.spawn(bodies).get();
  // The largest force the protocol accepts, on a 1000 kg box: it would leave at an absurd
  // speed in one step, so the engine redoes the step, then stops the body.
  w.applyForce(ids[1], {1e12f, 0, 0}, {0, 0, 5}).get();
  const uint64_t tick = w.step(2).get().tick;
  ASSERT_TRUE(waitFor([&] {
    std::lock_guard<std::mutex> lk(m);
    return seen.size() >= 2;
  })) << "events seen: "
      << seen.size();
  std::lock_guard<std::mutex> lk(m);
  EXPECT_EQ(seen[0].code, "guard_rollback");
  EXPECT_EQ(seen[0].severity, Event::Severity::Warning);
  EXPECT_EQ(seen[1].code, "guard_quarantine");
  EXPECT_EQ(seen[1].severity, Event::Severity::Error);
  for (const Event& e : seen) {
    EXPECT_EQ(e.world, w.id());
    // The tick of the step that acted (a Step runs step by step: the first of the two).
    EXPECT_GE(e.tick, 1u);
    EXPECT_LE(e.tick, tick);
    EXPECT_FALSE(e.message.empty());
  }
  EXPECT_EQ(c.recentEvents().size(), seen.size());
  // The world is still healthy: the box was stopped, not lost to infinity.
  const uint64_t boxId = ids[1];
  StateFrame f = w.queryState(std::span<const uint64_t>(&boxId, 1)).get();
  ASSERT_EQ(f.bodies.size(), 1u);
  EXPECT_TRUE(std::isfinite(f.bodies[0].position.x));
  EXPECT_LT(std::fabs(f.bodies[0].position.x), 1.0f);
}

TEST(ClientSdk, ReconnectsWhenTheDaemonRestarts) {
  Env env;
  Client& c = env.client;
  c.connect();
  WorldHandle w = c.createWorld({"before", "", std::nullopt, 0}).get();
  w.spawn(grid(3)).get();

  env.daemon.reset();  // the daemon goes away
  ASSERT_TRUE(waitFor([&] { return !c.connected(); }));
  // A request now cannot be answered: it fails cleanly (Timeout, or Disconnected when a new
  // daemon appears first).
  ErrorCode lost = codeOf([&] { w.step(1, {300ms}).get(); });
  EXPECT_TRUE(lost == ErrorCode::Timeout || lost == ErrorCode::Disconnected) << toString(lost);

  env.daemon = std::make_unique<Daemon>();  // a new daemon: the client greets it
  ASSERT_TRUE(waitFor([&] { return c.connected() && c.reconnects() >= 1; }));
  EXPECT_TRUE(c.listWorlds().get().empty());  // the old daemon's worlds are gone
  WorldHandle w2 = c.createWorld({"after", "", std::nullopt, 0}).get();
  EXPECT_EQ(w2.spawn(grid(2)).get().size(), 3u);
  EXPECT_EQ(w2.step(2).get().tick, 2u);
}

// Issue 39 point 4: on a daemon without DDS Security an owner's client id is no secret (it is
// in every command and in every PermissionDenied message). A client with a key proves its id
// in Hello, so another participant that uses the id, while the owner is away or beside it,
// cannot change the owner's world; and the owner coming back with its key file takes its id
// back and is answered at once. (Old code: the squatter's step and destroy succeeded, and the
// returning owner got no reply while the squatter held the id.)
TEST(ClientSdk, AnOwnersIdReadOffTheWireDoesNotTakeItsWorldAndTheOwnerComesBack) {
  Daemon daemon;
  const std::filesystem::path dir =
      std::filesystem::temp_directory_path() / ("physclient_key_" + std::to_string(getpid()));
  std::filesystem::remove_all(dir);
  ClientOptions ownerOptions = options("owner");
  ownerOptions.keyFile = (dir / "owner.key").string();
  uint64_t ownerId = 0;
  uint32_t world = 0;
  {
    Client owner(ownerOptions);
    EXPECT_TRUE(owner.connect().clientProven);
    ownerId = owner.clientId();
    world = owner.createWorld({"owned", "", std::nullopt, 0}).get().id();
    owner.world(world).spawn(grid(3)).get();
  }  // the owner goes away

  // Another participant writes the owner's id into its commands (the plain, unproven form).
  ClientOptions squatterOptions = options("squatter");
  squatterOptions.clientId = ownerId;
  Client squatter(squatterOptions);
  EXPECT_FALSE(squatter.connect().clientProven);
  WorldHandle taken = squatter.world(world);
  EXPECT_EQ(codeOf([&] { taken.step(5).get(); }), ErrorCode::PermissionDenied);
  EXPECT_EQ(codeOf([&] { taken.setAccess({}, true).get(); }), ErrorCode::PermissionDenied);
  EXPECT_EQ(codeOf([&] { taken.destroy().get(); }), ErrorCode::PermissionDenied);
  EXPECT_EQ(taken.queryState().get().tick, 0u) << "reads stay open to all";

  // The owner comes back with its key while the squatter still holds the id: answered.
  Client owner(ownerOptions);
  EXPECT_EQ(owner.clientId(), ownerId);
  EXPECT_TRUE(owner.connect().clientProven);
  EXPECT_EQ(owner.world(world).step(2).get().tick, 2u);
  // The id is the owner's now: the squatter's commands under it go unanswered.
  EXPECT_EQ(codeOf([&] { taken.step(1, {500ms}).get(); }), ErrorCode::Timeout);
  EXPECT_EQ(owner.world(world).queryState().get().tick, 2u);
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace phys::client
