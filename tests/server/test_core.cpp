// Every command through ServerCore (no DDS): replies, error codes, all-or-nothing.
#include <cmath>
#include <filesystem>
#include <limits>
#include <set>

#include "../../fuzz/snapshot_forge.h"
#include "phys/scene/scene.h"
#include "server_test_util.h"

namespace phys::server::test {
namespace {

using protocol::CommandBuilder;

class CoreTest : public ::testing::Test {
 protected:
  void SetUp() override {
    ASSERT_TRUE(core.init().ok());
    Reply r = send(CommandBuilder().createWorld({"w", "", std::nullopt, 0}), 0);
    ASSERT_EQ(r->status(), Code::Ok) << message(r);
    world = r->world();
    ASSERT_NE(world, 0u);
  }
  void TearDown() override {
    std::error_code ec;
    std::filesystem::remove_all(core.config().snapshotDir, ec);
  }

  Reply send(CommandBuilder& b, uint32_t w) { return send(b.finish({kClient, ++seq, w})); }
  Reply send(CommandBuilder& b) { return send(b, world); }
  Reply send(const protocol::Bytes& bytes) {
    Reply r = decode(core.applyBytes(bytes, kClient, seq));
    if (r.ok()) {
      EXPECT_EQ(r->seq(), seq);
    }
    return r;
  }

  std::vector<uint64_t> spawn(std::vector<phys::BodyDef> defs) {
    Reply r = send(CommandBuilder().spawnBodies(defs));
    EXPECT_EQ(r->status(), Code::Ok) << message(r);
    return bodyIds(r);
  }

  phys::World& engine() { return *core.world(world)->world; }

  /// State that must not change after a rejected command.
  struct Fingerprint {
    uint64_t hash;
    int bodies, joints;
    uint64_t tick, revision;
    bool operator==(const Fingerprint&) const = default;
  };
  Fingerprint fingerprint() {
    const ServerWorld* w = core.world(world);
    return {w->world->stateHash(), w->world->bodyCount(), w->world->jointCount(), w->tick,
            w->revision};
  }

  ServerCore core{testConfig()};
  uint32_t world = 0;
  uint64_t seq = 0;
};

TEST_F(CoreTest, Hello) {
  Reply r = send(CommandBuilder().hello("test"), 0);
  ASSERT_EQ(r->status(), Code::Ok);
  auto* h = r->result_as_HelloResult();
  ASSERT_TRUE(h);
  EXPECT_EQ(h->protocol_version(), protocol::kProtocolVersion);
  EXPECT_EQ(h->server_name()->str(), "physd");
  EXPECT_EQ(h->limits()->max_bodies_per_command(), protocol::Limits{}.maxBodiesPerCommand);
  r = send(CommandBuilder().hello("future", 2), 0);
  EXPECT_EQ(r->status(), Code::Unsupported) << message(r);
}

TEST_F(CoreTest, CreateListDestroyWorlds) {
  Reply r = send(CommandBuilder().createWorld({"second", "", phys::Vec3{0, 0, -1}, 0.01f}), 0);
  ASSERT_EQ(r->status(), Code::Ok) << message(r);
  const uint32_t second = r->world();
  EXPECT_NE(second, world);
  EXPECT_FLOAT_EQ(core.world(second)->world->def().gravity.z, -1);
  EXPECT_FLOAT_EQ(core.world(second)->world->def().timeStep, 0.01f);

  EXPECT_EQ(send(CommandBuilder().createWorld({"second", "", std::nullopt, 0}), 0)->status(),
            Code::InvalidArgument);
  EXPECT_EQ(
      send(CommandBuilder().createWorld({"third", "no_such_preset", std::nullopt, 0}), 0)->status(),
      Code::NotFound);

  r = send(CommandBuilder().listWorlds(), 0);
  ASSERT_EQ(r->status(), Code::Ok);
  auto* list = r->result_as_WorldList();
  ASSERT_TRUE(list);
  ASSERT_EQ(list->worlds()->size(), 2u);
  EXPECT_EQ(list->worlds()->Get(1)->name()->str(), "second");

  EXPECT_EQ(send(CommandBuilder().destroyWorld(), second)->status(), Code::Ok);
  EXPECT_EQ(core.world(second), nullptr);
  EXPECT_EQ(send(CommandBuilder().destroyWorld(), second)->status(), Code::NotFound);
  EXPECT_EQ(send(CommandBuilder().step(1), second)->status(), Code::NotFound);
  EXPECT_EQ(send(CommandBuilder().step(1), 999)->status(), Code::NotFound);
  // The publisher learns that the world is gone.
  bool removed = false;
  while (true) {
    auto item = core.out().pop(std::chrono::milliseconds(0));
    if (!item.reliable && !item.frame) break;
    if (item.reliable && item.reliable->type == ReliableMessage::Type::WorldRemoved)
      removed = item.reliable->world == second;
  }
  EXPECT_TRUE(removed);
}

TEST_F(CoreTest, ResetWorld) {
  spawn({groundBody(), boxBody({0, 0, 1})});
  EXPECT_EQ(send(CommandBuilder().step(3))->status(), Code::Ok);
  EXPECT_EQ(send(CommandBuilder().resetWorld())->status(), Code::Ok);
  EXPECT_EQ(engine().bodyCount(), 0);
  EXPECT_EQ(core.world(world)->tick, 0u);
  EXPECT_EQ(engine().time(), 0.0);
}

TEST_F(CoreTest, LoadScene) {
  Reply r = send(CommandBuilder().loadSceneNamed("box_stack"));
  ASSERT_EQ(r->status(), Code::Ok) << message(r);
  EXPECT_GT(bodyIds(r).size(), 1u);
  EXPECT_EQ(int(bodyIds(r).size()), engine().bodyCount());

  r = send(CommandBuilder().loadSceneNamed("ball_and_chain"));
  ASSERT_EQ(r->status(), Code::Ok) << message(r);
  EXPECT_GT(jointIds(r).size(), 0u);
  EXPECT_EQ(int(jointIds(r).size()), engine().jointCount());

  Fingerprint before = fingerprint();
  EXPECT_EQ(send(CommandBuilder().loadSceneNamed("no_such_scene"))->status(), Code::NotFound);
  EXPECT_EQ(send(CommandBuilder().loadSceneJson("{\"bodies\": 3}"))->status(),
            Code::InvalidArgument);
  EXPECT_EQ(fingerprint(), before);

  phys::Scene scene;
  scene.name = "inline";
  scene.bodies = {groundBody(), boxBody({0, 0, 2})};
  r = send(CommandBuilder().loadSceneJson(phys::sceneToJson(scene)));
  ASSERT_EQ(r->status(), Code::Ok) << message(r);
  EXPECT_EQ(bodyIds(r).size(), 2u);
}

TEST_F(CoreTest, SpawnAndRemoveBodies) {
  auto ids = spawn({groundBody(), boxBody({0, 0, 1}), boxBody({0, 0, 3})});
  ASSERT_EQ(ids.size(), 3u);
  EXPECT_EQ(engine().bodyCount(), 3);
  const uint64_t rev = core.world(world)->revision;

  Reply r = send(CommandBuilder().removeBodies(std::vector<uint64_t>{ids[1]}));
  EXPECT_EQ(r->status(), Code::Ok) << message(r);
  EXPECT_EQ(engine().bodyCount(), 2);
  EXPECT_GT(core.world(world)->revision, rev);

  // Stale id (removed) and never-issued id: NotFound, nothing changes.
  Fingerprint before = fingerprint();
  r = send(CommandBuilder().removeBodies(std::vector<uint64_t>{ids[2], ids[1]}));
  EXPECT_EQ(r->status(), Code::NotFound);
  EXPECT_NE(message(r).find("remove_bodies.bodies[1]"), std::string::npos) << message(r);
  EXPECT_EQ(send(CommandBuilder().removeBodies(std::vector<uint64_t>{0x7700000001}))->status(),
            Code::NotFound);
  EXPECT_EQ(fingerprint(), before);
  EXPECT_TRUE(engine().isValid(phys::BodyId::fromPacked(ids[2])));
}

TEST_F(CoreTest, JointsAddAndRemove) {
  auto ids = spawn({boxBody({0, 0, 5}), boxBody({2, 0, 5})});
  phys::JointDef j;
  j.type = phys::JointType::Ball;
  j.bodyA = phys::BodyId::fromPacked(ids[0]);
  j.bodyB = phys::BodyId::fromPacked(ids[1]);
  j.anchorA = {1, 0, 0};
  j.anchorB = {-1, 0, 0};
  Reply r = send(CommandBuilder().addJoints(std::vector<phys::JointDef>{j}));
  ASSERT_EQ(r->status(), Code::Ok) << message(r);
  auto joints = jointIds(r);
  ASSERT_EQ(joints.size(), 1u);
  EXPECT_EQ(engine().jointCount(), 1);

  // A joint to a stale body: NotFound.
  Fingerprint before = fingerprint();
  phys::JointDef bad = j;
  bad.bodyB = phys::BodyId::fromPacked(0x900000002);
  EXPECT_EQ(send(CommandBuilder().addJoints(std::vector<phys::JointDef>{j, bad}))->status(),
            Code::NotFound);
  EXPECT_EQ(fingerprint(), before);

  EXPECT_EQ(send(CommandBuilder().removeJoints(joints))->status(), Code::Ok);
  EXPECT_EQ(engine().jointCount(), 0);
  EXPECT_EQ(send(CommandBuilder().removeJoints(joints))->status(), Code::NotFound);

  // Removing a body removes its joints (engine and bookkeeping).
  r = send(CommandBuilder().addJoints(std::vector<phys::JointDef>{j}));
  ASSERT_EQ(r->status(), Code::Ok);
  EXPECT_EQ(send(CommandBuilder().removeBodies(std::vector<uint64_t>{ids[0]}))->status(), Code::Ok);
  EXPECT_EQ(engine().jointCount(), 0);
}

TEST_F(CoreTest, PoseVelocityForcesMaterial) {
  auto ids = spawn({groundBody(), boxBody({0, 0, 5})});
  const uint64_t box = ids[1];
  const phys::BodyId boxId = phys::BodyId::fromPacked(box);
  phys::BodyState s;

  EXPECT_EQ(send(CommandBuilder().setBodyPose(box, {1, 2, 3}, phys::Quat{}))->status(), Code::Ok);
  engine().getBody(boxId, &s);
  EXPECT_FLOAT_EQ(s.position.x, 1);
  EXPECT_FLOAT_EQ(s.position.z, 3);

  EXPECT_EQ(send(CommandBuilder().setBodyVelocity(box, {0, 1, 0}, {0, 0, 2}))->status(), Code::Ok);
  engine().getBody(boxId, &s);
  EXPECT_FLOAT_EQ(s.linearVelocity.y, 1);
  EXPECT_FLOAT_EQ(s.angularVelocity.z, 2);
  Reply r = send(CommandBuilder().setBodyVelocity(ids[0], {0, 1, 0}, {}));
  EXPECT_EQ(r->status(), Code::IncorrectState) << message(r);

  EXPECT_EQ(send(CommandBuilder().applyImpulse(box, {1000, 0, 0}))->status(), Code::Ok);
  engine().getBody(boxId, &s);
  EXPECT_FLOAT_EQ(s.linearVelocity.x, 1000 / s.mass);
  EXPECT_EQ(
      send(CommandBuilder().applyImpulse(box, {0, 0, 10}, {0.5f, 0, 0}, wire::PointFrame::Local))
          ->status(),
      Code::Ok);
  EXPECT_EQ(send(CommandBuilder().applyForce(box, {0, 0, 100}, {0, 0, 5}, wire::PointFrame::World))
                ->status(),
            Code::Ok);
  EXPECT_EQ(send(CommandBuilder().applyTorque(box, {0, 0, 1}))->status(), Code::Ok);

  phys::Material m{0.1f, 0.5f, 2000};
  EXPECT_EQ(send(CommandBuilder().setMaterial(std::vector<uint64_t>{box}, m))->status(), Code::Ok);
  phys::ShapeDef sd;
  phys::BodyId owner;
  ASSERT_TRUE(engine().getShape(engine().bodyShapes(boxId)[0], &sd, &owner).ok());
  EXPECT_FLOAT_EQ(sd.material.restitution, 0.5f);

  // Every per-body command with a stale id: NotFound and no change.
  EXPECT_EQ(send(CommandBuilder().removeBodies(std::vector<uint64_t>{box}))->status(), Code::Ok);
  Fingerprint before = fingerprint();
  EXPECT_EQ(send(CommandBuilder().setBodyPose(box, {1, 2, 3}, phys::Quat{}))->status(),
            Code::NotFound);
  EXPECT_EQ(send(CommandBuilder().setBodyVelocity(box, {}, {}))->status(), Code::NotFound);
  EXPECT_EQ(send(CommandBuilder().applyForce(box, {1, 0, 0}))->status(), Code::NotFound);
  EXPECT_EQ(send(CommandBuilder().applyImpulse(box, {1, 0, 0}))->status(), Code::NotFound);
  EXPECT_EQ(send(CommandBuilder().applyTorque(box, {1, 0, 0}))->status(), Code::NotFound);
  EXPECT_EQ(send(CommandBuilder().setMaterial(std::vector<uint64_t>{box}, m))->status(),
            Code::NotFound);
  EXPECT_EQ(send(CommandBuilder().queryState(std::vector<uint64_t>{box}))->status(),
            Code::NotFound);
  EXPECT_EQ(fingerprint(), before);
}

TEST_F(CoreTest, SetSolver) {
  Reply r = send(CommandBuilder().setSolver("soft_step"));
  EXPECT_EQ(r->status(), Code::Ok) << message(r);
  protocol::SolverOverrides o;
  o.iterations = 7;
  EXPECT_EQ(send(CommandBuilder().setSolver("", o))->status(), Code::Ok);
  EXPECT_EQ(engine().def().solver.iterations, 7);
  EXPECT_EQ(send(CommandBuilder().setSolver("no_such_preset"))->status(), Code::NotFound);
  // A combination only the engine rejects: Jacobi with direct LDL equality solving.
  protocol::SolverOverrides bad;
  bad.scheme = phys::SolverSettings::Scheme::Jacobi;
  bad.equalitySolve = phys::SolverSettings::EqualitySolve::DirectLdl;
  const auto before = engine().def().solver.scheme;
  r = send(CommandBuilder().setSolver("", bad));
  EXPECT_EQ(r->status(), Code::InvalidArgument) << message(r);
  EXPECT_EQ(engine().def().solver.scheme, before);
  EXPECT_EQ(engine().def().solver.iterations, 7);
}

TEST_F(CoreTest, StepAdvancesExactlyN) {
  spawn({groundBody(), boxBody({0, 0, 1})});
  const uint64_t steps0 = engine().stats().step;
  Reply r = send(CommandBuilder().step(17));
  ASSERT_EQ(r->status(), Code::Ok);
  EXPECT_EQ(r->tick(), 17u);
  EXPECT_EQ(core.world(world)->tick, 17u);
  EXPECT_EQ(engine().stats().step - steps0, 17u);
  EXPECT_NEAR(engine().time(), 17.0 * double(engine().def().timeStep), 1e-6);
  EXPECT_EQ(send(CommandBuilder().step())->tick(), 18u);
}

TEST_F(CoreTest, RunAndPause) {
  ServerWorld* w = core.world(world);
  // Paused: nothing moves.
  EXPECT_EQ(core.advance(1.0), 0u);
  EXPECT_EQ(send(CommandBuilder().run(60))->status(), Code::Ok);
  EXPECT_EQ(w->mode, RunMode::RealTime);
  // Exactly one step per period, the remainder carried.
  EXPECT_EQ(core.advance(0.75 / 60), 0u);
  EXPECT_EQ(core.advance(0.5 / 60), 1u);
  EXPECT_EQ(core.advance(1.0 / 60), 1u);
  EXPECT_EQ(core.advance(2.0 / 60), 2u);
  EXPECT_EQ(w->tick, 4u);
  EXPECT_EQ(w->overruns, 0u);
  // A long stall: at most maxCatchUpSteps, counted as an overrun, the backlog dropped.
  EXPECT_EQ(core.advance(1.0), uint64_t(core.config().maxCatchUpSteps));
  EXPECT_EQ(w->overruns, 1u);
  EXPECT_EQ(core.advance(0.5 / 60), 0u);
  // As fast as possible: one step per tick.
  EXPECT_EQ(send(CommandBuilder().run(0))->status(), Code::Ok);
  EXPECT_EQ(w->mode, RunMode::AsFastAsPossible);
  EXPECT_EQ(core.secondsUntilDue(1.0), 0.0);
  EXPECT_EQ(core.advance(0), 1u);
  EXPECT_EQ(core.advance(0), 1u);
  EXPECT_EQ(send(CommandBuilder().pause())->status(), Code::Ok);
  EXPECT_EQ(core.advance(10.0), 0u);
  EXPECT_EQ(core.secondsUntilDue(0.5), 0.5);
  // Step works while paused.
  const uint64_t t = w->tick;
  EXPECT_EQ(send(CommandBuilder().step(5))->status(), Code::Ok);
  EXPECT_EQ(w->tick, t + 5);
}

// A real-time tick that steps more than once to catch up publishes a frame for each step:
// subscribers see every tick number (before: one frame, for the last step).
TEST_F(CoreTest, CatchUpStepsPublishAFrameEach) {
  spawn({groundBody(), boxBody({0, 0, 1})});
  ASSERT_EQ(send(CommandBuilder().run(60))->status(), Code::Ok);
  auto frameTicks = [&] {
    std::vector<uint64_t> ticks;
    for (;;) {
      auto item = core.out().pop(std::chrono::milliseconds(0));
      if (!item.reliable && !item.frame) break;
      if (!item.frame) continue;
      auto f = protocol::decodeStateFrame(std::move(item.frame->chunks.at(0)));
      EXPECT_TRUE(f.ok()) << f.status.message;
      EXPECT_EQ(f->tick(), item.frame->tick);
      ticks.push_back(item.frame->tick);
    }
    return ticks;
  };
  frameTicks();
  ASSERT_EQ(core.advance(1.0 / 60), 1u);
  EXPECT_EQ(frameTicks(), (std::vector<uint64_t>{1}));
  ASSERT_EQ(core.advance(3.0 / 60), 3u);
  EXPECT_EQ(frameTicks(), (std::vector<uint64_t>{2, 3, 4}));
  EXPECT_EQ(core.world(world)->overruns, 0u);
  // Step N stays one frame, for the last of the N.
  ASSERT_EQ(send(CommandBuilder().pause())->status(), Code::Ok);
  ASSERT_EQ(send(CommandBuilder().step(5))->status(), Code::Ok);
  core.advance(0);
  EXPECT_EQ(frameTicks(), (std::vector<uint64_t>{9}));
}

TEST_F(CoreTest, QueryState) {
  auto ids = spawn({groundBody(), boxBody({0, 0, 1}), boxBody({0, 0, 3}), boxBody({0, 0, 5})});
  Reply r = send(CommandBuilder().queryState());
  ASSERT_EQ(r->status(), Code::Ok);
  auto* s = r->result_as_StateResult();
  ASSERT_TRUE(s);
  EXPECT_EQ(s->total(), 4u);
  ASSERT_EQ(s->bodies()->size(), 4u);
  EXPECT_EQ(s->bodies()->Get(2)->id(), ids[2]);
  EXPECT_FLOAT_EQ(s->bodies()->Get(2)->position().z(), 3);

  r = send(CommandBuilder().queryState({}, 1, 2));
  s = r->result_as_StateResult();
  ASSERT_EQ(s->bodies()->size(), 2u);
  EXPECT_EQ(s->bodies()->Get(0)->id(), ids[1]);
  EXPECT_EQ(s->total(), 4u);

  r = send(CommandBuilder().queryState(std::vector<uint64_t>{ids[3]}));
  s = r->result_as_StateResult();
  ASSERT_EQ(s->bodies()->size(), 1u);
  EXPECT_FLOAT_EQ(s->bodies()->Get(0)->position().z(), 5);
}

TEST_F(CoreTest, SnapshotBytesRoundTripIsExact) {
  ASSERT_EQ(send(CommandBuilder().loadSceneNamed("box_stack"))->status(), Code::Ok);
  ASSERT_EQ(send(CommandBuilder().step(20))->status(), Code::Ok);
  Reply r = send(CommandBuilder().saveSnapshot());
  ASSERT_EQ(r->status(), Code::Ok) << message(r);
  auto* res = r->result_as_SnapshotResult();
  ASSERT_TRUE(res && res->snapshot());
  std::vector<uint8_t> snap(res->snapshot()->begin(), res->snapshot()->end());
  const int bodies = engine().bodyCount();

  ASSERT_EQ(send(CommandBuilder().step(30))->status(), Code::Ok);
  const uint64_t hash50 = engine().stateHash();
  ASSERT_EQ(
      send(CommandBuilder().spawnBodies(std::vector<phys::BodyDef>{boxBody({9, 9, 9})}))->status(),
      Code::Ok);

  r = send(CommandBuilder().restoreSnapshot(snap));
  ASSERT_EQ(r->status(), Code::Ok) << message(r);
  EXPECT_EQ(core.world(world)->tick, 20u);
  EXPECT_EQ(engine().bodyCount(), bodies);
  ASSERT_EQ(send(CommandBuilder().step(30))->status(), Code::Ok);
  EXPECT_EQ(engine().stateHash(), hash50);

  // Garbage engine state: rejected by the engine, world unchanged.
  Fingerprint before = fingerprint();
  protocol::SnapshotData bad;
  bad.engineState = {1, 2, 3, 4, 5, 6, 7, 8};
  r = send(CommandBuilder().restoreSnapshot(protocol::encodeSnapshot(bad)));
  EXPECT_EQ(r->status(), Code::InvalidArgument) << message(r);
  EXPECT_EQ(fingerprint(), before);
}

// Issue 39: an engine snapshot with a valid checksum whose ground carries solver index
// 0x7FFFFFFF was accepted, and the next step crashed physd (SIGSEGV in WideContacts::build).
// Forged from this world's own snapshot, as a client would: refused, the world unchanged
// and stepping. So is each of fuzz/snapshot_forge.h's forged cases.
TEST_F(CoreTest, ForgedEngineSnapshotIsRefusedAndTheWorldStepsOn) {
  phys::BodyDef ground = groundBody();
  ground.name = "ground";
  spawn({ground, boxBody({0, 0, 0.5f}), boxBody({0, 0, 1.5f})});
  ASSERT_EQ(send(CommandBuilder().step(10))->status(), Code::Ok);
  Reply r = send(CommandBuilder().saveSnapshot());
  ASSERT_EQ(r->status(), Code::Ok) << message(r);
  auto decoded = protocol::decodeSnapshot(std::span<const uint8_t>(
      r->result_as_SnapshotResult()->snapshot()->data(),
      r->result_as_SnapshotResult()->snapshot()->size()));
  ASSERT_TRUE(decoded.ok());
  protocol::SnapshotData data;
  ASSERT_TRUE(protocol::toSnapshotData(*decoded, &data).ok());
  forge::Bytes& engine = data.engineState;
  const size_t at = forge::afterName(engine, forge::section(engine, "BODY"), "ground");
  ASSERT_NE(at, forge::kNone);
  ASSERT_EQ(forge::getU32(engine, at + forge::body::kSolverIndex), 0u);
  forge::putU32(&engine, at + forge::body::kSolverIndex, 0x7FFFFFFF);
  forge::seal(&engine);

  const Fingerprint before = fingerprint();
  r = send(CommandBuilder().restoreSnapshot(protocol::encodeSnapshot(data)));
  EXPECT_EQ(r->status(), Code::InvalidArgument) << message(r);
  EXPECT_NE(message(r).find("solver index"), std::string::npos) << message(r);
  EXPECT_EQ(fingerprint(), before);
  ASSERT_EQ(send(CommandBuilder().step(10))->status(), Code::Ok);
  EXPECT_EQ(core.world(world)->tick, before.tick + 10);

  // The forged cases of the fuzz corpus, each in a snapshot of its own.
  phys::World src(forge::worldDef());
  ASSERT_TRUE(forge::buildWorld(src));
  forge::Bytes valid;
  ASSERT_TRUE(src.saveSnapshot(&valid).ok());
  const Fingerprint now = fingerprint();
  for (const forge::Forgery& f : forge::forgeries(valid)) {
    ASSERT_FALSE(f.bytes.empty()) << f.name;
    protocol::SnapshotData forged;
    forged.engineState = f.bytes;
    r = send(CommandBuilder().restoreSnapshot(protocol::encodeSnapshot(forged)));
    EXPECT_EQ(r->status(), Code::InvalidArgument) << f.name << ": " << message(r);
    EXPECT_EQ(fingerprint(), now) << f.name;
  }
  ASSERT_EQ(send(CommandBuilder().step(10))->status(), Code::Ok);
}

// Restoring into a running world is allowed (docs/PROTOCOL.md, RestoreSnapshot): the content
// is replaced at a tick boundary and the world goes on running from the restored state.
TEST_F(CoreTest, RestoreIntoARunningWorldKeepsItRunning) {
  spawn({groundBody(), boxBody({0, 0, 1})});
  ASSERT_EQ(send(CommandBuilder().step(10))->status(), Code::Ok);
  Reply r = send(CommandBuilder().saveSnapshot());
  ASSERT_EQ(r->status(), Code::Ok) << message(r);
  std::vector<uint8_t> snap(r->result_as_SnapshotResult()->snapshot()->begin(),
                            r->result_as_SnapshotResult()->snapshot()->end());
  ASSERT_EQ(send(CommandBuilder().run(0))->status(), Code::Ok);
  EXPECT_EQ(core.advance(0), 1u);
  EXPECT_EQ(core.advance(0), 1u);
  r = send(CommandBuilder().restoreSnapshot(snap));
  ASSERT_EQ(r->status(), Code::Ok) << message(r);
  ServerWorld* w = core.world(world);
  EXPECT_EQ(w->tick, 10u);
  EXPECT_EQ(w->mode, RunMode::AsFastAsPossible);
  EXPECT_EQ(core.advance(0), 1u);
  EXPECT_EQ(w->tick, 11u);
}

TEST_F(CoreTest, SnapshotFile) {
  spawn({groundBody(), boxBody({0, 0, 1})});
  Reply r = send(CommandBuilder().saveSnapshot("one.snap", false));
  ASSERT_EQ(r->status(), Code::Ok) << message(r);
  EXPECT_EQ(r->result_as_SnapshotResult()->file()->str(), "one.snap");
  EXPECT_EQ(r->result_as_SnapshotResult()->snapshot(), nullptr);
  const uint64_t hash = engine().stateHash();
  ASSERT_EQ(send(CommandBuilder().step(10))->status(), Code::Ok);
  EXPECT_NE(engine().stateHash(), hash);
  r = send(CommandBuilder().restoreSnapshotFile("one.snap"));
  ASSERT_EQ(r->status(), Code::Ok) << message(r);
  EXPECT_EQ(engine().stateHash(), hash);
  EXPECT_EQ(send(CommandBuilder().restoreSnapshotFile("missing.snap"))->status(), Code::NotFound);
}

TEST_F(CoreTest, PortableSnapshotRestore) {
  protocol::SnapshotData data;
  data.bodies.push_back({0x100000005, groundBody()});
  data.bodies.push_back({0x100000009, boxBody({0, 0, 2})});
  data.bodies.push_back({0x10000000A, boxBody({0, 0, 4})});
  phys::JointDef j;
  j.bodyA = phys::BodyId::fromPacked(0x100000009);
  j.bodyB = phys::BodyId::fromPacked(0x10000000A);
  j.anchorA = {0, 0, 1};
  j.anchorB = {0, 0, -1};
  data.joints.push_back({0x100000001, j});
  data.tick = 42;
  Reply r = send(CommandBuilder().restoreSnapshot(protocol::encodeSnapshot(data)));
  ASSERT_EQ(r->status(), Code::Ok) << message(r);
  EXPECT_EQ(bodyIds(r).size(), 3u);
  EXPECT_EQ(jointIds(r).size(), 1u);
  EXPECT_EQ(engine().bodyCount(), 3);
  EXPECT_EQ(engine().jointCount(), 1);
  EXPECT_EQ(core.world(world)->tick, 42u);
}

TEST_F(CoreTest, BatchAppliesInOrder) {
  auto ids = spawn({groundBody(), boxBody({0, 0, 1})});
  CommandBuilder b;
  b.spawnBodies(std::vector<phys::BodyDef>{boxBody({3, 0, 1}), boxBody({6, 0, 1})});
  b.setBodyPose(ids[1], {0, 0, 7}, phys::Quat{});
  b.removeBodies(std::vector<uint64_t>{ids[1]});
  Reply r = send(b, world);
  ASSERT_EQ(r->status(), Code::Ok) << message(r);
  EXPECT_EQ(bodyIds(r).size(), 2u);
  EXPECT_EQ(engine().bodyCount(), 3);
  EXPECT_FALSE(engine().isValid(phys::BodyId::fromPacked(ids[1])));
}

TEST_F(CoreTest, BatchIsAllOrNothing) {
  auto ids = spawn({groundBody(), boxBody({0, 0, 1}), boxBody({0, 0, 3})});
  ASSERT_EQ(send(CommandBuilder().step(5))->status(), Code::Ok);
  Fingerprint before = fingerprint();

  // A stale id after valid items: caught by the check pass.
  {
    CommandBuilder b;
    b.spawnBodies(std::vector<phys::BodyDef>{boxBody({3, 0, 1})});
    b.setBodyPose(ids[1], {0, 0, 7}, phys::Quat{});
    b.setBodyPose(0x5500000003, {0, 0, 7}, phys::Quat{});
    Reply r = send(b, world);
    EXPECT_EQ(r->status(), Code::NotFound);
    EXPECT_NE(message(r).find("batch.commands[2].set_body_pose.items[0]"), std::string::npos)
        << message(r);
    EXPECT_EQ(fingerprint(), before);
  }
  // An item that refers to a body an earlier item removed: passes the check pass, fails
  // while applying, rolled back from the snapshot (ids stay live, nothing moved).
  {
    CommandBuilder b;
    b.spawnBodies(std::vector<phys::BodyDef>{boxBody({3, 0, 1})});
    b.removeBodies(std::vector<uint64_t>{ids[2]});
    b.setBodyPose(ids[2], {0, 0, 7}, phys::Quat{});
    Reply r = send(b, world);
    EXPECT_EQ(r->status(), Code::NotFound) << message(r);
    EXPECT_EQ(fingerprint(), before);
    EXPECT_TRUE(engine().isValid(phys::BodyId::fromPacked(ids[2])));
  }
  // NaN inside a batch after valid items: the codec rejects the whole command.
  {
    CommandBuilder b;
    b.spawnBodies(std::vector<phys::BodyDef>{boxBody({3, 0, 1})});
    b.setBodyPose(ids[1], {0, 0, 2}, phys::Quat{});
    b.setBodyVelocity(ids[1], {std::numeric_limits<float>::quiet_NaN(), 0, 0}, {});
    Reply r = send(b, world);
    EXPECT_EQ(r->status(), Code::InvalidArgument) << message(r);
    EXPECT_EQ(fingerprint(), before);
  }
  // Infinity in a single command.
  {
    Reply r =
        send(CommandBuilder().applyForce(ids[1], {std::numeric_limits<float>::infinity(), 0, 0}));
    EXPECT_EQ(r->status(), Code::InvalidArgument);
    EXPECT_EQ(fingerprint(), before);
  }
  // Ids created after a rollback are the ones the world would have handed out anyway.
  auto fresh = spawn({boxBody({5, 5, 1})});
  ASSERT_EQ(fresh.size(), 1u);
  EXPECT_EQ(fresh[0], (phys::BodyId{3, 1}.packed()));
}

TEST_F(CoreTest, EnvelopeAndGarbage) {
  // client id != envelope key: Malformed.
  protocol::Bytes cmd = CommandBuilder().step(1).finish({kClient + 1, 5, world});
  Reply r = decode(core.applyBytes(cmd, kClient, 5));
  EXPECT_EQ(r->status(), Code::Malformed) << message(r);
  EXPECT_EQ(core.world(world)->tick, 0u);
  // Garbage: Malformed, answered to the envelope's key and seq.
  std::vector<uint8_t> junk(64, 0xAB);
  r = decode(core.applyBytes(junk, 0x1234, 77));
  EXPECT_EQ(r->status(), Code::Malformed);
  EXPECT_EQ(r->client_id(), 0x1234u);
  EXPECT_EQ(r->seq(), 77u);
  r = decode(core.applyBytes({}, 0x1234, 78));
  EXPECT_EQ(r->status(), Code::Malformed);
  EXPECT_GE(core.counters().errors, 3u);
}

TEST_F(CoreTest, ProcessPendingInArrivalOrder) {
  for (int i = 0; i < 3; ++i) {
    Incoming in;
    in.envelopeKey = kClient;
    in.envelopeSeq = 100 + i;
    in.command = protocol::decodeCommand(
        CommandBuilder().step(uint32_t(i + 1)).finish({kClient, uint64_t(100 + i), world}));
    core.submit(std::move(in));
  }
  EXPECT_EQ(core.processPending(), 3u);
  // Queued Steps run in the tick's advance (a slice each, the later ones waiting in order).
  for (int i = 0; i < 100 && core.world(world)->tick < 6; ++i) {
    core.advance(0);
    core.processPending();
  }
  EXPECT_EQ(core.world(world)->tick, 6u);
  std::vector<uint64_t> ticks;
  for (;;) {
    auto item = core.out().pop(std::chrono::milliseconds(0));
    if (!item.reliable && !item.frame) break;
    if (!item.reliable || item.reliable->type != ReliableMessage::Type::Reply) continue;
    EXPECT_EQ(item.reliable->key, kClient);
    Reply rr = decode(std::move(item.reliable->chunks[0]));
    EXPECT_EQ(rr->seq(), 100 + ticks.size());
    ticks.push_back(rr->tick());
  }
  EXPECT_EQ(ticks, (std::vector<uint64_t>{1, 3, 6}));
}

// Commands queued behind a Step job run as soon as the job ends: the tick thread does not
// sleep while a world that is no longer busy has commands waiting (before: up to 20 ms for
// each, so requests pipelined to one world, e.g. asyncio's, ran at about 50 a second).
TEST_F(CoreTest, CommandsWaitingBehindAStepAreDueAtOnce) {
  for (int i = 0; i < 3; ++i) {
    Incoming in;
    in.envelopeKey = kClient;
    in.envelopeSeq = 200 + i;
    in.command = protocol::decodeCommand(
        CommandBuilder().step(1).finish({kClient, uint64_t(200 + i), world}));
    core.submit(std::move(in));
  }
  EXPECT_EQ(core.processPending(), 3u);  // the first is the world's job, two wait behind it
  EXPECT_EQ(core.secondsUntilDue(1.0), 0.0);
  for (int i = 0; i < 100 && core.world(world)->busy(); ++i) core.advance(0);
  ASSERT_FALSE(core.world(world)->busy());
  ASSERT_EQ(core.world(world)->waiting.size(), 2u);
  EXPECT_EQ(core.secondsUntilDue(1.0), 0.0);  // the next tick drains them, without a sleep
  core.processPending();
  for (int i = 0; i < 100 && core.world(world)->tick < 3; ++i) {
    core.advance(0);
    core.processPending();
  }
  EXPECT_EQ(core.world(world)->tick, 3u);
  EXPECT_TRUE(core.world(world)->waiting.empty());
  EXPECT_EQ(core.secondsUntilDue(1.0), 1.0);  // paused, nothing waiting: idle
}

TEST_F(CoreTest, StateFramesChunkEveryBody) {
  std::vector<phys::BodyDef> defs;
  for (int i = 0; i < 2500; ++i) defs.push_back(boxBody({float(i % 50) * 2, float(i / 50) * 2, 1}));
  defs.push_back(groundBody());
  auto ids = spawn(defs);
  ASSERT_EQ(ids.size(), 2501u);
  while (core.out().pop(std::chrono::milliseconds(0)).reliable) {
  }
  ASSERT_EQ(send(CommandBuilder().run(0))->status(), Code::Ok);
  ASSERT_EQ(core.advance(0), 1u);
  std::optional<StateFrameSet> set;
  for (;;) {
    auto item = core.out().pop(std::chrono::milliseconds(0));
    if (!item.reliable && !item.frame) break;
    if (item.frame) set = std::move(item.frame);
  }
  ASSERT_TRUE(set);
  EXPECT_EQ(set->world, world);
  EXPECT_EQ(set->tick, 1u);
  ASSERT_EQ(set->chunks.size(), 3u);
  std::set<uint64_t> seen;
  for (size_t i = 0; i < set->chunks.size(); ++i) {
    auto f = protocol::decodeStateFrame(std::move(set->chunks[i]));
    ASSERT_TRUE(f.ok()) << f.status.message;
    EXPECT_EQ(f->chunk_index(), i);
    EXPECT_EQ(f->chunk_count(), 3u);
    EXPECT_EQ(f->total_bodies(), 2501u);
    EXPECT_EQ(f->tick(), 1u);
    for (auto* b : *f->bodies()) seen.insert(b->id());
  }
  EXPECT_EQ(seen, std::set<uint64_t>(ids.begin(), ids.end()));
}

TEST_F(CoreTest, WorldInfoAndStatus) {
  spawn({groundBody(), boxBody({0, 0, 1})});
  core.publishWorldInfo();
  core.publishStatus();
  bool info = false, status = false;
  for (;;) {
    auto item = core.out().pop(std::chrono::milliseconds(0));
    if (!item.reliable && !item.frame) break;
    if (!item.reliable) continue;
    if (item.reliable->type == ReliableMessage::Type::WorldInfo) {
      auto wi = protocol::decodeWorldInfo(std::move(item.reliable->chunks[0]));
      ASSERT_TRUE(wi.ok()) << wi.status.message;
      EXPECT_EQ(wi->world(), world);
      EXPECT_EQ(wi->name()->str(), "w");
      EXPECT_EQ(wi->bodies()->size(), 2u);
      info = true;
    }
    if (item.reliable->type == ReliableMessage::Type::Status) {
      auto st = protocol::decodeServerStatus(std::move(item.reliable->chunks[0]));
      ASSERT_TRUE(st.ok()) << st.status.message;
      ASSERT_EQ(st->worlds()->size(), 1u);
      EXPECT_EQ(st->worlds()->Get(0)->bodies(), 2u);
      EXPECT_GE(st->commands(), 2u);
      status = true;
    }
  }
  EXPECT_TRUE(info);
  EXPECT_TRUE(status);
}

TEST(ServerRing, DropsOldest) {
  DropOldestRing<int> ring(3);
  for (int i = 0; i < 10; ++i) ring.push(i);
  EXPECT_EQ(ring.size(), 3u);
  EXPECT_EQ(ring.dropped(), 7u);
  EXPECT_EQ(*ring.pop(), 7);
  EXPECT_EQ(*ring.pop(), 8);
  EXPECT_EQ(*ring.pop(), 9);
  EXPECT_FALSE(ring.pop());
}

TEST(ServerRing, StalledConsumerLosesOldFramesNotReplies) {
  PublishQueue q(4);
  for (uint64_t t = 0; t < 100; ++t) {
    q.pushFrame({1, t, {}});
    if (t % 10 == 0) q.pushReliable({ReliableMessage::Type::Reply, 1, t, 0, {}});
  }
  EXPECT_EQ(q.framesDropped(), 96u);
  EXPECT_EQ(q.framesQueued(), 4u);
  std::vector<uint64_t> replies, frames;
  for (;;) {
    auto item = q.pop(std::chrono::milliseconds(0));
    if (item.reliable)
      replies.push_back(item.reliable->seq);
    else if (item.frame)
      frames.push_back(item.frame->tick);
    else
      break;
  }
  EXPECT_EQ(replies.size(), 10u);
  EXPECT_EQ(frames, (std::vector<uint64_t>{96, 97, 98, 99}));
}

TEST(ServerTickThread, RunsCommandsAndSteps) {
  ServerCore core(testConfig());
  ASSERT_TRUE(core.init().ok());
  uint32_t w = 0;
  ASSERT_TRUE(core.createWorld("t", "", "box_stack", &w).ok());
  TickThread tick(&core, std::chrono::milliseconds(50));
  tick.start();
  Incoming in;
  in.envelopeKey = kClient;
  in.envelopeSeq = 1;
  in.command = protocol::decodeCommand(CommandBuilder().run(0).finish({kClient, 1, w}));
  core.submit(std::move(in));
  // Wait (generously) for frames of several ticks to come out.
  uint64_t lastTick = 0;
  bool reply = false;
  auto end = std::chrono::steady_clock::now() + std::chrono::seconds(20);
  while (std::chrono::steady_clock::now() < end && (lastTick < 5 || !reply)) {
    auto item = core.out().pop(std::chrono::milliseconds(50));
    if (item.frame) lastTick = std::max(lastTick, item.frame->tick);
    if (item.reliable && item.reliable->type == ReliableMessage::Type::Reply) reply = true;
  }
  tick.stop();
  EXPECT_TRUE(reply);
  EXPECT_GE(lastTick, 5u);
}

}  // namespace
}  // namespace phys::server::test
