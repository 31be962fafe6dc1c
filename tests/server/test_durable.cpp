// Durable worlds (docs/SERVER.md "Durable worlds"): a world's checkpoint and journal under
// the data directory, restored by a new ServerCore as a restarted daemon does. A "crash" is
// a copy of the data directory taken while the first core goes on (everything acknowledged
// is on disk by then), or the first core dropped without any shutdown.
#include <signal.h>
#include <sys/resource.h>
#include <sys/wait.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <thread>

#include "server_test_util.h"

namespace phys::server::test {
namespace {

namespace fs = std::filesystem;
using protocol::CommandBuilder;

fs::path scratch(const std::string& what) {
  fs::path p = fs::temp_directory_path() /
               ("physd_durable_" + what + "_" + std::to_string(getpid()));
  fs::remove_all(p);
  return p;
}

CoreConfig durableConfig(const fs::path& data) {
  CoreConfig c = testConfig();
  c.dataDir = data.string();
  return c;
}

using Client = CoreClient;

std::unique_ptr<ServerCore> restart(const fs::path& data, std::vector<std::string>* notes) {
  return startedCore(durableConfig(data), notes);
}

/// Stepping a restored world on to the original's tick gives the original's state.
void expectSameFuture(ServerCore& original, uint32_t id, ServerCore& restored) {
  const ServerWorld* a = original.world(id);
  ServerWorld* b = restored.world(id);
  ASSERT_TRUE(a && b);
  ASSERT_LE(b->tick, a->tick);
  ASSERT_TRUE(restored.stepWorld(id, a->tick - b->tick).ok());
  EXPECT_EQ(b->tick, a->tick);
  EXPECT_EQ(b->world->stateHash(), a->world->stateHash());
  EXPECT_EQ(b->world->bodies(), a->world->bodies());
  EXPECT_EQ(b->world->joints(), a->world->joints());
  EXPECT_EQ(b->name, a->name);
  // World info's revision: not the same count (the original's depends on when world info
  // was published), but never behind, so a client never takes the new info for stale.
  EXPECT_GE(b->revision, a->revision);
}

/// What a core queued for the publisher since the last drain: the replies, the highest tick
/// of a state frame of each world, the events' codes.
struct Queued {
  std::vector<Reply> replies;
  std::map<uint32_t, uint64_t> maxFrameTick;
  std::vector<std::string> events;
  bool has(const std::string& code) const {
    return std::find(events.begin(), events.end(), code) != events.end();
  }
};
Queued drain(ServerCore& core, Queued* into = nullptr) {
  Queued local;
  Queued& q = into ? *into : local;
  for (;;) {
    PublishQueue::Item item = core.out().pop(std::chrono::milliseconds(0));
    if (!item.reliable && !item.frame) break;
    if (item.frame) {
      uint64_t& t = q.maxFrameTick[item.frame->world];
      t = std::max(t, item.frame->tick);
    } else if (item.reliable->type == ReliableMessage::Type::Reply) {
      q.replies.push_back(decode(item.reliable->chunks.at(0)));
    } else if (item.reliable->type == ReliableMessage::Type::Event) {
      auto e = protocol::decodeEvent(item.reliable->chunks.at(0));
      if (e.ok() && e->code()) q.events.push_back(e->code()->str());
    }
  }
  return q;
}

/// A full disk (RLIMIT_FSIZE, SIGXFSZ ignored: writes past it fail with EFBIG as they would
/// with ENOSPC) for as long as it lives.
struct FullDisk {
  rlimit old{};
  void (*handler)(int) = nullptr;
  explicit FullDisk(rlim_t bytes) {
    EXPECT_EQ(getrlimit(RLIMIT_FSIZE, &old), 0);
    handler = signal(SIGXFSZ, SIG_IGN);
    rlimit tiny = old;
    tiny.rlim_cur = bytes;
    EXPECT_EQ(setrlimit(RLIMIT_FSIZE, &tiny), 0);
  }
  ~FullDisk() {
    setrlimit(RLIMIT_FSIZE, &old);
    signal(SIGXFSZ, handler);
  }
};

/// Why a world kept on disk was not restored (WorldSummary.damage); empty when it was, or
/// when the core does not list it at all.
std::string damageOf(const ServerCore& core, uint32_t id) {
  for (const protocol::WorldSummary& w : core.summaries())
    if (w.world == id) return w.damage;
  return {};
}

fs::path journalOf(const fs::path& data, uint32_t id) {
  for (auto& e : fs::directory_iterator(data / "worlds" / std::to_string(id)))
    if (e.path().filename().string().rfind("journal-", 0) == 0) return e.path();
  return {};
}

std::vector<uint8_t> bytesOf(const fs::path& p) {
  std::ifstream f(p, std::ios::binary);
  return std::vector<uint8_t>(std::istreambuf_iterator<char>(f), {});
}

std::vector<phys::BodyDef> tower(int n, float x = 0) {
  std::vector<phys::BodyDef> defs;
  for (int i = 0; i < n; ++i) defs.push_back(boxBody({x, 0, 0.5f + 1.01f * float(i)}));
  return defs;
}

TEST(Durable, EveryAcknowledgedEditSurvivesARestart) {
  const fs::path data = scratch("edits");
  ServerCore a(durableConfig(data));
  ASSERT_TRUE(a.init().ok());
  Client c{&a};
  Reply r = c.send(CommandBuilder().createWorld({"kept", "", std::nullopt, 0}), 0);
  ASSERT_EQ(r->status(), Code::Ok) << message(r);
  const uint32_t id = r->world();
  std::vector<phys::BodyDef> defs = tower(4);
  defs.push_back(groundBody());
  defs[0].name = "bottom";
  defs[1].linearDamping = 0.3f;
  r = c.send(CommandBuilder().spawnBodies(defs), id);
  ASSERT_EQ(r->status(), Code::Ok) << message(r);
  const std::vector<uint64_t> ids = bodyIds(r);
  ASSERT_EQ(c.send(CommandBuilder().step(30), id)->status(), Code::Ok);
  // A batch (all or nothing), motion edits, a solver change, a removal, more steps.
  CommandBuilder batch;
  batch.setBodyVelocity(ids[3], {1, 0, 0}, {0, 0, 2}).applyImpulse(ids[2], {0, 3, 0});
  ASSERT_EQ(c.send(batch, id)->status(), Code::Ok);
  ASSERT_EQ(c.send(CommandBuilder().setSolver("pgs"), id)->status(), Code::Ok);
  ASSERT_EQ(c.send(CommandBuilder().step(7), id)->status(), Code::Ok);
  ASSERT_EQ(c.send(CommandBuilder().removeBodies(std::vector<uint64_t>{ids[1]}), id)->status(),
            Code::Ok);
  ASSERT_EQ(c.send(CommandBuilder().spawnBodies(tower(2, 3)), id)->status(), Code::Ok);
  ASSERT_EQ(c.send(CommandBuilder().step(5), id)->status(), Code::Ok);
  // A refused command is not journaled (a stale id): it changes nothing either way.
  EXPECT_EQ(c.send(CommandBuilder().removeBodies(std::vector<uint64_t>{ids[1]}), id)->status(),
            Code::NotFound);

  // The crash: the data directory as it is now; the first core goes on, undisturbed.
  const fs::path copy = scratch("edits_copy");
  fs::copy(data, copy, fs::copy_options::recursive);
  std::vector<std::string> notes;
  auto b = restart(copy, &notes);
  ASSERT_TRUE(b->world(id)) << (notes.empty() ? "" : notes[0]);
  EXPECT_EQ(b->world(id)->tick, a.world(id)->tick);  // every Step was acknowledged
  EXPECT_EQ(b->world(id)->world->stateHash(), a.world(id)->world->stateHash());
  // The definitions too (the engine's): names as given.
  phys::BodyDef bottom;
  ASSERT_TRUE(b->world(id)->world->getBodyDef(phys::BodyId::fromPacked(ids[0]), &bottom).ok());
  EXPECT_EQ(bottom.name, "bottom");
  EXPECT_EQ(b->world(id)->world->bodyCount(), a.world(id)->world->bodyCount());
  EXPECT_EQ(b->world(id)->preset, "pgs");
  EXPECT_EQ(b->world(id)->owner, kClient);  // access is kept too
  ASSERT_TRUE(a.stepWorld(id, 40).ok());
  expectSameFuture(a, id, *b);
  // New ids continue where the original's do.
  Client cb{b.get(), kClient, 100};
  Reply ra = c.send(CommandBuilder().spawnBodies(tower(1, 6)), id);
  Reply rb = cb.send(CommandBuilder().spawnBodies(tower(1, 6)), id);
  EXPECT_EQ(bodyIds(ra), bodyIds(rb));
  fs::remove_all(data);
  fs::remove_all(copy);
}

TEST(Durable, ARunningWorldResumesWhereItsJournalEndsAndEqualsAnUninterruptedRun) {
  // Commands through the queue at tick boundaries of a world running in real time, as the
  // tick thread applies them; the crash comes between two ticks.
  const fs::path data = scratch("running");
  CoreConfig cfg = durableConfig(data);
  cfg.leasePeriodS = 0;  // a lease per tick: the restart resumes at the last tick
  ServerCore a(cfg);
  ASSERT_TRUE(a.init().ok());
  Client c{&a};
  Reply r = c.send(CommandBuilder().createWorld({"runner", "", std::nullopt, 0}), 0);
  const uint32_t id = r->world();
  std::vector<phys::BodyDef> defs = tower(3);
  defs.push_back(groundBody());
  const std::vector<uint64_t> ids = bodyIds(c.send(CommandBuilder().spawnBodies(defs), id));
  c.submit(CommandBuilder().run(60), id);
  a.processPending();
  for (int tick = 0; tick < 90; ++tick) {
    if (tick % 10 == 3) c.submit(CommandBuilder().applyImpulse(ids[tick % 3], {0.5f, 0, 0}), id);
    if (tick == 41) c.submit(CommandBuilder().spawnBodies(tower(1, 2)), id);
    if (tick == 60) c.submit(CommandBuilder().step(25), id);  // a Step job, in slices
    a.processPending();
    a.advance(1.0 / 60);
  }
  for (const Reply& rep : takeReplies(a)) EXPECT_EQ(rep->status(), Code::Ok) << message(rep);
  ASSERT_GT(a.world(id)->tick, 100u);

  const fs::path copy = scratch("running_copy");
  fs::copy(data, copy, fs::copy_options::recursive);
  std::vector<std::string> notes;
  auto b = restart(copy, &notes);
  ASSERT_TRUE(b->world(id));
  EXPECT_EQ(b->world(id)->mode, RunMode::RealTime);
  EXPECT_EQ(b->world(id)->tick, a.world(id)->tick);  // marks every tick here
  ASSERT_TRUE(a.stepWorld(id, 30).ok());
  expectSameFuture(a, id, *b);
  fs::remove_all(data);
  fs::remove_all(copy);
}

TEST(Durable, ReplacedWorldsEphemeralWorldsAndDestroyedWorlds) {
  const fs::path data = scratch("kinds");
  auto a = std::make_unique<ServerCore>(durableConfig(data));
  ASSERT_TRUE(a->init().ok());
  Client c{a.get()};
  const uint32_t loaded = c.send(CommandBuilder().createWorld({"loaded", "", std::nullopt, 0}), 0)->world();
  ASSERT_EQ(c.send(CommandBuilder().loadSceneNamed("box_stack"), loaded)->status(), Code::Ok);
  ASSERT_EQ(c.send(CommandBuilder().step(12), loaded)->status(), Code::Ok);
  protocol::CreateWorldArgs eph{"scratch", "", std::nullopt, 0};
  eph.ephemeral = true;
  const uint32_t ephemeral = c.send(CommandBuilder().createWorld(eph), 0)->world();
  ASSERT_EQ(c.send(CommandBuilder().spawnBodies(tower(2)), ephemeral)->status(), Code::Ok);
  EXPECT_FALSE(fs::exists(data / "worlds" / std::to_string(ephemeral)));
  const uint32_t doomed = c.send(CommandBuilder().createWorld({"doomed", "", std::nullopt, 0}), 0)->world();
  EXPECT_TRUE(fs::exists(data / "worlds" / std::to_string(doomed)));
  ASSERT_EQ(c.send(CommandBuilder().destroyWorld(), doomed)->status(), Code::Ok);
  EXPECT_FALSE(fs::exists(data / "worlds" / std::to_string(doomed)));
  // A reset world is kept reset; a restored snapshot is kept as restored.
  const uint32_t reset = c.send(CommandBuilder().createWorld({"reset", "", std::nullopt, 0}), 0)->world();
  ASSERT_EQ(c.send(CommandBuilder().spawnBodies(tower(3)), reset)->status(), Code::Ok);
  Reply snap = c.send(CommandBuilder().saveSnapshot(), reset);
  ASSERT_EQ(snap->status(), Code::Ok);
  std::vector<uint8_t> bytes(snap->result_as_SnapshotResult()->snapshot()->begin(),
                             snap->result_as_SnapshotResult()->snapshot()->end());
  ASSERT_EQ(c.send(CommandBuilder().resetWorld(), reset)->status(), Code::Ok);
  const uint32_t restored = c.send(CommandBuilder().createWorld({"restored", "", std::nullopt, 0}), 0)->world();
  ASSERT_EQ(c.send(CommandBuilder().restoreSnapshot(bytes), restored)->status(), Code::Ok);
  const uint64_t restoredHash = a->world(restored)->world->stateHash();
  const uint64_t loadedHash = a->world(loaded)->world->stateHash();
  a.reset();  // the daemon goes away without any shutdown

  std::vector<std::string> notes;
  auto b = restart(data, &notes);
  EXPECT_EQ(b->worldIds(), (std::vector<uint32_t>{loaded, reset, restored}));
  EXPECT_EQ(b->world(loaded)->tick, 12u);
  EXPECT_EQ(b->world(loaded)->world->stateHash(), loadedHash);
  EXPECT_EQ(b->world(reset)->world->bodyCount(), 0);
  EXPECT_EQ(b->world(restored)->world->bodyCount(), 3);
  EXPECT_EQ(b->world(restored)->world->stateHash(), restoredHash);
  // Ids of destroyed and ephemeral worlds are not given again.
  Client cb{b.get(), kClient, 50};
  EXPECT_GT(cb.send(CommandBuilder().createWorld({"new", "", std::nullopt, 0}), 0)->world(), restored);
  fs::remove_all(data);
}

TEST(Durable, ATornJournalTailIsDroppedAndSaidSo) {
  const fs::path data = scratch("torn");
  uint32_t id = 0;
  uint64_t hashAfterTwo = 0;
  {
    ServerCore a(durableConfig(data));
    ASSERT_TRUE(a.init().ok());
    Client c{&a};
    id = c.send(CommandBuilder().createWorld({"torn", "", std::nullopt, 0}), 0)->world();
    ASSERT_EQ(c.send(CommandBuilder().spawnBodies(tower(2)), id)->status(), Code::Ok);
    ASSERT_EQ(c.send(CommandBuilder().step(5), id)->status(), Code::Ok);
    hashAfterTwo = a.world(id)->world->stateHash();
    ASSERT_EQ(c.send(CommandBuilder().spawnBodies(tower(1, 4)), id)->status(), Code::Ok);
  }
  // The last record loses its last 3 bytes, as a crash in the middle of a write leaves it.
  fs::path journal;
  for (auto& e : fs::directory_iterator(data / "worlds" / std::to_string(id)))
    if (e.path().filename().string().rfind("journal-", 0) == 0) journal = e.path();
  ASSERT_FALSE(journal.empty());
  fs::resize_file(journal, fs::file_size(journal) - 3);
  std::vector<std::string> notes;
  auto b = restart(data, &notes);
  ASSERT_TRUE(b->world(id));
  EXPECT_EQ(b->world(id)->world->bodyCount(), 2);
  EXPECT_EQ(b->world(id)->world->stateHash(), hashAfterTwo);
  bool said = false;
  for (const std::string& n : notes) said |= n.find("torn or corrupt") != std::string::npos;
  EXPECT_TRUE(said);
  // A flipped byte inside a record is corruption, found by its checksum, the same way.
  Client cb{b.get(), kClient, 10};
  ASSERT_EQ(cb.send(CommandBuilder().spawnBodies(tower(1, 8)), id)->status(), Code::Ok);
  ASSERT_EQ(cb.send(CommandBuilder().spawnBodies(tower(1, 9)), id)->status(), Code::Ok);
  b.reset();
  for (auto& e : fs::directory_iterator(data / "worlds" / std::to_string(id)))
    if (e.path().filename().string().rfind("journal-", 0) == 0) journal = e.path();
  {
    std::fstream f(journal, std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(std::streamoff(fs::file_size(journal) - 5));
    f.put('\x5a');
  }
  notes.clear();
  b = restart(data, &notes);
  EXPECT_EQ(b->world(id)->world->bodyCount(), 3);  // the first of the two spawns only
  said = false;
  for (const std::string& n : notes) said |= n.find("torn or corrupt") != std::string::npos;
  EXPECT_TRUE(said);
  fs::remove_all(data);
}

TEST(Durable, AFullDiskRefusesCommandsInsteadOfAcknowledgingThem) {
  // A file size limit (RLIMIT_FSIZE, SIGXFSZ ignored) stands for a full disk: writes past it
  // fail with EFBIG as they would with ENOSPC.
  const fs::path data = scratch("full");
  ServerCore a(durableConfig(data));
  ASSERT_TRUE(a.init().ok());
  Client c{&a};
  const uint32_t id = c.send(CommandBuilder().createWorld({"full", "", std::nullopt, 0}), 0)->world();
  std::vector<phys::BodyDef> defs = tower(3);
  defs.push_back(groundBody());
  ASSERT_EQ(c.send(CommandBuilder().spawnBodies(defs), id)->status(), Code::Ok);
  ASSERT_EQ(c.send(CommandBuilder().step(4), id)->status(), Code::Ok);
  const uint64_t hash = a.world(id)->world->stateHash();
  const int bodies = a.world(id)->world->bodyCount();

  rlimit old{};
  ASSERT_EQ(getrlimit(RLIMIT_FSIZE, &old), 0);
  auto oldHandler = signal(SIGXFSZ, SIG_IGN);
  rlimit tiny = old;
  tiny.rlim_cur = 64;  // below every file's size: no journal record or checkpoint fits
  ASSERT_EQ(setrlimit(RLIMIT_FSIZE, &tiny), 0);
  Reply r = c.send(CommandBuilder().spawnBodies(tower(40, 5)), id);
  Reply q = c.send(CommandBuilder().createWorld({"another", "", std::nullopt, 0}), 0);
  Reply l = c.send(CommandBuilder().loadSceneNamed("box_stack"), id);
  ASSERT_EQ(setrlimit(RLIMIT_FSIZE, &old), 0);
  signal(SIGXFSZ, oldHandler);

  EXPECT_EQ(r->status(), Code::ResourceExhausted) << message(r);
  EXPECT_NE(message(r).find("not stored"), std::string::npos) << message(r);
  EXPECT_EQ(q->status(), Code::ResourceExhausted) << message(q);
  EXPECT_EQ(l->status(), Code::ResourceExhausted) << message(l);
  EXPECT_EQ(a.worldIds().size(), 1u);
  EXPECT_EQ(a.world(id)->world->bodyCount(), bodies);
  EXPECT_EQ(a.world(id)->world->stateHash(), hash);
  // Space again: commands are stored again, and a restart has exactly what was acknowledged.
  ASSERT_EQ(c.send(CommandBuilder().spawnBodies(tower(1, 7)), id)->status(), Code::Ok);
  const fs::path copy = scratch("full_copy");
  fs::copy(data, copy, fs::copy_options::recursive);
  std::vector<std::string> notes;
  auto b = restart(copy, &notes);
  EXPECT_EQ(b->world(id)->world->bodyCount(), bodies + 1);
  EXPECT_EQ(b->world(id)->world->stateHash(), a.world(id)->world->stateHash());
  fs::remove_all(data);
  fs::remove_all(copy);
}

TEST(Durable, CheckpointsFoldTheJournalAndACorruptCheckpointIsNotRestored) {
  const fs::path data = scratch("fold");
  CoreConfig cfg = durableConfig(data);
  cfg.journalMaxBytes = 4096;  // a checkpoint once the journal passes 4 KiB
  uint32_t id = 0, other = 0;
  {
    ServerCore a(cfg);
    ASSERT_TRUE(a.init().ok());
    Client c{&a};
    id = c.send(CommandBuilder().createWorld({"fold", "", std::nullopt, 0}), 0)->world();
    other = c.send(CommandBuilder().createWorld({"other", "", std::nullopt, 0}), 0)->world();
    std::vector<uint64_t> ids = bodyIds(c.send(CommandBuilder().spawnBodies(tower(3)), id));
    for (int i = 0; i < 100; ++i) {
      c.submit(CommandBuilder().applyForce(ids[i % 3], {1, 0, 0}), id);
      a.processPending();
      a.advance(0);
    }
    for (const Reply& rep : takeReplies(a)) EXPECT_EQ(rep->status(), Code::Ok);
    EXPECT_GT(a.world(id)->store->generation(), 2u);
    EXPECT_LE(a.world(id)->store->journalBytes(), 4096u + 512u);
  }
  // The other world's checkpoint is damaged: it is left on disk, not restored, and said so.
  const fs::path ck = data / "worlds" / std::to_string(other) / "checkpoint";
  {
    std::fstream f(ck, std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(40);
    f.put('\x01');
  }
  std::vector<std::string> notes;
  auto b = restart(data, &notes);
  EXPECT_TRUE(b->world(id));
  EXPECT_FALSE(b->world(other));
  EXPECT_TRUE(fs::exists(ck));
  bool said = false;
  for (const std::string& n : notes) said |= n.find("checksum") != std::string::npos;
  EXPECT_TRUE(said);
  fs::remove_all(data);
}

// A world whose owner proved its id (issue 39 point 4) keeps needing proven commands after a
// restart: the flag lives in its checkpoint beside owner, editors and shared.
TEST(Durable, AProofOwnedWorldStaysProofOwnedAfterARestart) {
  const fs::path data = scratch("proof_owned");
  std::vector<std::string> notes;
  uint32_t id = 0;
  {
    ServerCore a(durableConfig(data));
    ASSERT_TRUE(a.init().ok());
    ASSERT_TRUE(a.restoreWorlds(&notes).ok());
    CommandBuilder create;
    create.createWorld({"proven", "", std::nullopt, 0});
    Incoming in = queuedCommand(kClient, 1, create, 0);
    in.proven = true;
    Reply r = decode(a.apply(in));
    ASSERT_EQ(r->status(), Code::Ok) << message(r);
    id = r->world();
    ASSERT_TRUE(a.world(id)->ownerProven);
  }
  auto b = restart(data, &notes);
  ASSERT_TRUE(b->world(id));
  EXPECT_TRUE(b->world(id)->ownerProven);
  EXPECT_EQ(b->world(id)->owner, kClient);
  Client plain{b.get(), kClient, 10};  // the owner's id, unproven
  EXPECT_EQ(plain.send(CommandBuilder().step(1), id)->status(), Code::PermissionDenied);
  fs::remove_all(data);
}

TEST(Durable, TwoDaemonsNeverShareADataDirectory) {
  const fs::path data = scratch("lock");
  std::vector<std::string> notes;
  auto a = restart(data, &notes);
  ServerCore b(durableConfig(data));
  ASSERT_TRUE(b.init().ok());
  Status s = b.restoreWorlds(&notes);
  EXPECT_EQ(s.code, Code::IncorrectState);
  EXPECT_NE(s.message.find("in use by another physd (pid " + std::to_string(getpid())),
            std::string::npos)
      << s.message;
  a.reset();  // the first goes away: the directory is free
  ServerCore c(durableConfig(data));
  ASSERT_TRUE(c.init().ok());
  EXPECT_TRUE(c.restoreWorlds(&notes).ok());
  fs::remove_all(data);
}

// Issue 39, finding 2: on a full disk a Step was refused ("step: not stored") but its steps
// had been taken and published, and the next reload took the world back in time.
TEST(Durable, AStepThatCannotBeStoredDoesNotMoveTheWorld) {
  const fs::path data = scratch("step_full");
  ServerCore a(durableConfig(data));
  ASSERT_TRUE(a.init().ok());
  Client c{&a};
  const uint32_t id = c.send(CommandBuilder().createWorld({"stepper", "", std::nullopt, 0}), 0)->world();
  std::vector<phys::BodyDef> defs = tower(3);
  defs.push_back(groundBody());
  ASSERT_EQ(c.send(CommandBuilder().spawnBodies(defs), id)->status(), Code::Ok);
  c.submit(CommandBuilder().step(5), id);
  a.processPending();
  a.advance(0);
  Queued q = drain(a);
  ASSERT_EQ(q.replies.size(), 1u);
  ASSERT_EQ(q.replies[0]->status(), Code::Ok) << message(q.replies[0]);
  const uint64_t storedTick = a.world(id)->tick;
  const uint64_t storedHash = a.world(id)->world->stateHash();
  ASSERT_EQ(storedTick, 5u);

  {
    FullDisk full(64);  // no record fits
    for (int i = 0; i < 12; ++i) {
      c.submit(CommandBuilder().step(5), id);
      a.processPending();
      for (int k = 0; k < 3; ++k) a.advance(0);
    }
    drain(a, &q);
  }
  ASSERT_EQ(q.replies.size(), 13u);
  for (size_t i = 1; i < q.replies.size(); ++i) {
    EXPECT_EQ(q.replies[i]->status(), Code::ResourceExhausted) << message(q.replies[i]);
    EXPECT_NE(message(q.replies[i]).find("not stored"), std::string::npos) << message(q.replies[i]);
    EXPECT_EQ(q.replies[i]->tick(), storedTick);
  }
  // The live world did not move, and no subscriber saw a tick past what is stored.
  EXPECT_EQ(a.world(id)->tick, storedTick);
  EXPECT_EQ(a.world(id)->world->stateHash(), storedHash);
  EXPECT_LE(q.maxFrameTick[id], storedTick);
  // Room again: Steps are stored and taken again, and a restart has exactly that.
  c.submit(CommandBuilder().step(5), id);
  a.processPending();
  a.advance(0);
  drain(a, &q);
  EXPECT_EQ(q.replies.back()->status(), Code::Ok) << message(q.replies.back());
  EXPECT_EQ(a.world(id)->tick, storedTick + 5);
  const fs::path copy = scratch("step_full_copy");
  fs::copy(data, copy, fs::copy_options::recursive);
  std::vector<std::string> notes;
  auto b = restart(copy, &notes);
  ASSERT_TRUE(b->world(id));
  EXPECT_EQ(b->world(id)->tick, storedTick + 5);
  EXPECT_EQ(b->world(id)->world->stateHash(), a.world(id)->world->stateHash());
  fs::remove_all(data);
  fs::remove_all(copy);
}

TEST(Durable, ARunningWorldThatCannotStoreItsProgressIsHeldAndSaysSo) {
  const fs::path data = scratch("run_full");
  ServerCore a(durableConfig(data));
  ASSERT_TRUE(a.init().ok());
  Client c{&a};
  const uint32_t id = c.send(CommandBuilder().createWorld({"runner", "", std::nullopt, 0}), 0)->world();
  std::vector<phys::BodyDef> defs = tower(3);
  defs.push_back(groundBody());
  ASSERT_EQ(c.send(CommandBuilder().spawnBodies(defs), id)->status(), Code::Ok);
  c.submit(CommandBuilder().run(60), id);
  a.processPending();
  Queued q = drain(a);
  ASSERT_EQ(q.replies.size(), 1u);
  ASSERT_EQ(q.replies[0]->status(), Code::Ok);
  const uint64_t before = a.world(id)->tick;
  {
    FullDisk full(64);
    for (int tick = 0; tick < 30; ++tick) {
      a.processPending();
      a.advance(1.0 / 60);
    }
    drain(a, &q);
  }
  // Its steps could not be promised to the journal: it is held where its files have it.
  EXPECT_EQ(a.world(id)->tick, before);
  EXPECT_LE(q.maxFrameTick[id], before);
  EXPECT_TRUE(q.has("not_stored"));
  EXPECT_EQ(a.world(id)->mode, RunMode::RealTime);  // held, not paused: it goes on by itself
  for (int tick = 0; tick < 30; ++tick) {
    a.processPending();
    a.advance(1.0 / 60);
  }
  drain(a, &q);
  EXPECT_TRUE(q.has("stored"));
  EXPECT_EQ(a.world(id)->tick, before + 30);
  fs::remove_all(data);
}

TEST(Durable, ARestartNeverTakesBackATickSubscribersSaw) {
  // A world running in real time with edits through the queue; the crash comes between two
  // ticks, long before a checkpoint. Whatever subscribers were shown is in the restored world
  // (its lease), which equals the uninterrupted run.
  const fs::path data = scratch("no_going_back");
  ServerCore a(durableConfig(data));
  ASSERT_TRUE(a.init().ok());
  Client c{&a};
  const uint32_t id = c.send(CommandBuilder().createWorld({"seen", "", std::nullopt, 0}), 0)->world();
  for (int i = 0; i < 3; ++i)  // epochs the restart must go on above (each one checkpointed)
    ASSERT_EQ(c.send(CommandBuilder().resetWorld(), id)->status(), Code::Ok);
  std::vector<phys::BodyDef> defs = tower(3);
  defs.push_back(groundBody());
  const std::vector<uint64_t> ids = bodyIds(c.send(CommandBuilder().spawnBodies(defs), id));
  c.submit(CommandBuilder().run(60), id);
  Queued q;
  for (int tick = 0; tick < 150; ++tick) {
    // Edits until tick 100, then only steps: the journal's last command is well behind.
    if (tick % 7 == 2 && tick < 100)
      c.submit(CommandBuilder().applyImpulse(ids[tick % 3], {0.3f, 0, 0}), id);
    if (tick == 70) c.submit(CommandBuilder().step(12), id);
    a.processPending();
    a.advance(1.0 / 60);
    drain(a, &q);
  }
  for (const Reply& r : q.replies) EXPECT_EQ(r->status(), Code::Ok) << message(r);
  const uint64_t seen = q.maxFrameTick[id];
  ASSERT_GE(seen, 150u);
  const fs::path copy = scratch("no_going_back_copy");
  fs::copy(data, copy, fs::copy_options::recursive);
  std::vector<std::string> notes;
  auto b = restart(copy, &notes);
  ASSERT_TRUE(b->world(id));
  ASSERT_GE(b->world(id)->tick, seen) << "a restart took back ticks subscribers had seen";
  // And a new epoch above the one they saw (issue 40): a subscriber that does not notice the
  // restart takes the restored world's keyframe for what follows.
  EXPECT_GT(b->world(id)->epoch, a.world(id)->epoch);
  EXPECT_EQ(b->world(id)->mode, RunMode::RealTime);
  ASSERT_GE(b->world(id)->tick, a.world(id)->tick);
  ASSERT_TRUE(a.stepWorld(id, b->world(id)->tick + 10 - a.world(id)->tick).ok());
  expectSameFuture(a, id, *b);
  fs::remove_all(data);
  fs::remove_all(copy);
}

// Issue 39, finding 3: with its journal deleted, a world came back without its acknowledged
// commands, and only "0 journal records replayed" was said.
TEST(Durable, ADeletedJournalKeepsTheWorldFromBeingRestored) {
  const fs::path data = scratch("no_journal");
  uint32_t id = 0, other = 0;
  uint64_t checkpointHash = 0;
  {
    ServerCore a(durableConfig(data));
    ASSERT_TRUE(a.init().ok());
    Client c{&a};
    id = c.send(CommandBuilder().createWorld({"lost", "", std::nullopt, 0}), 0)->world();
    other = c.send(CommandBuilder().createWorld({"fine", "", std::nullopt, 0}), 0)->world();
    checkpointHash = a.world(id)->world->stateHash();
    for (int i = 0; i < 10; ++i)
      ASSERT_EQ(c.send(CommandBuilder().spawnBodies(tower(1, float(i))), id)->status(), Code::Ok);
    ASSERT_EQ(c.send(CommandBuilder().spawnBodies(tower(2)), other)->status(), Code::Ok);
  }
  const fs::path journal = journalOf(data, id);
  ASSERT_FALSE(journal.empty());
  fs::remove(journal);
  const fs::path dir = data / "worlds" / std::to_string(id);
  const std::vector<uint8_t> checkpoint = bytesOf(dir / "checkpoint");

  std::vector<std::string> notes;
  auto b = restart(data, &notes);
  EXPECT_FALSE(b->world(id)) << "restored without its 10 acknowledged spawns";
  ASSERT_TRUE(b->world(other));
  EXPECT_EQ(b->world(other)->world->bodyCount(), 2);
  // Clients see it and why; its commands are refused; its name is not given to another.
  const std::string damage = damageOf(*b, id);
  EXPECT_NE(damage.find("missing"), std::string::npos) << damage;
  EXPECT_TRUE(drain(*b).has("world_damaged"));
  Client cb{b.get(), kClient, 10};
  Reply r = cb.send(CommandBuilder().spawnBodies(tower(1)), id);
  EXPECT_EQ(r->status(), Code::IncorrectState) << message(r);
  EXPECT_NE(message(r).find("accept-loss"), std::string::npos) << message(r);
  EXPECT_EQ(cb.send(CommandBuilder().createWorld({"lost", "", std::nullopt, 0}), 0)->status(),
            Code::InvalidArgument);
  // Its files are as they were.
  EXPECT_EQ(bytesOf(dir / "checkpoint"), checkpoint);
  EXPECT_FALSE(fs::exists(journal));
  b.reset();

  // The operator accepts the loss: the world is back as its checkpoint has it, the files
  // are kept aside, and the next start needs nothing more.
  CoreConfig cfg = durableConfig(data);
  cfg.acceptLoss = {id};
  ServerCore accepted(cfg);
  ASSERT_TRUE(accepted.init().ok());
  notes.clear();
  ASSERT_TRUE(accepted.restoreWorlds(&notes).ok());
  ASSERT_TRUE(accepted.world(id));
  EXPECT_EQ(accepted.world(id)->world->bodyCount(), 0);
  EXPECT_EQ(accepted.world(id)->world->stateHash(), checkpointHash);
  EXPECT_TRUE(drain(accepted).has("loss_accepted"));
  const fs::path aside = data / "damaged" / ("world-" + std::to_string(id) + "-1");
  EXPECT_EQ(bytesOf(aside / "checkpoint"), checkpoint);
  EXPECT_TRUE(fs::exists(aside / "DAMAGE.txt"));
  Client ca{&accepted, kClient, 20};
  ASSERT_EQ(ca.send(CommandBuilder().spawnBodies(tower(1)), id)->status(), Code::Ok);
  const uint64_t hash = accepted.world(id)->world->stateHash();
  notes.clear();
  const fs::path copy = scratch("no_journal_copy");
  fs::copy(data, copy, fs::copy_options::recursive);
  auto again = restart(copy, &notes);
  ASSERT_TRUE(again->world(id));
  EXPECT_EQ(again->world(id)->world->stateHash(), hash);
  EXPECT_TRUE(damageOf(*again, id).empty());
  fs::remove_all(data);
  fs::remove_all(copy);
}

// Issue 39, finding 4: damage in the middle of a journal was cut off like a torn tail,
// destroying the acknowledged records after it.
TEST(Durable, DamageInTheMiddleOfAJournalIsNotTakenForATornTail) {
  const fs::path data = scratch("mid_damage");
  uint32_t id = 0;
  uint64_t hashAfterTwo = 0;
  {
    ServerCore a(durableConfig(data));
    ASSERT_TRUE(a.init().ok());
    Client c{&a};
    id = c.send(CommandBuilder().createWorld({"mid", "", std::nullopt, 0}), 0)->world();
    for (int i = 0; i < 6; ++i) {
      ASSERT_EQ(c.send(CommandBuilder().spawnBodies(tower(1, float(2 * i))), id)->status(),
                Code::Ok);
      if (i == 1) hashAfterTwo = a.world(id)->world->stateHash();
    }
  }
  const fs::path journal = journalOf(data, id);
  ASSERT_FALSE(journal.empty());
  // The record offsets ([u32 payload bytes][u32 crc][u64 tick][u8 kind][payload]): a byte
  // of the third spawn's payload is flipped.
  std::vector<uint8_t> bytes = bytesOf(journal);
  std::vector<size_t> at;
  for (size_t p = 0; p + 17 <= bytes.size();) {
    uint32_t len = 0;
    std::memcpy(&len, bytes.data() + p, 4);
    if (bytes[p + 16] == 1) at.push_back(p);  // commands (not the header)
    p += 17 + len;
  }
  ASSERT_EQ(at.size(), 6u);
  bytes[at[2] + 40] ^= 0x5a;
  {
    std::ofstream f(journal, std::ios::binary | std::ios::trunc);
    f.write(reinterpret_cast<const char*>(bytes.data()), std::streamsize(bytes.size()));
  }
  std::vector<std::string> notes;
  auto b = restart(data, &notes);
  EXPECT_FALSE(b->world(id)) << "restored up to the damage, losing 3 acknowledged spawns";
  const std::string damage = damageOf(*b, id);
  EXPECT_NE(damage.find("3 good records follow"), std::string::npos) << damage;
  EXPECT_EQ(bytesOf(journal), bytes);  // not cut
  b.reset();

  CoreConfig cfg = durableConfig(data);
  cfg.acceptLoss = {0};  // all
  notes.clear();
  ServerCore accepted(cfg);
  ASSERT_TRUE(accepted.init().ok());
  ASSERT_TRUE(accepted.restoreWorlds(&notes).ok());
  ASSERT_TRUE(accepted.world(id));
  EXPECT_EQ(accepted.world(id)->world->bodyCount(), 2);
  EXPECT_EQ(accepted.world(id)->world->stateHash(), hashAfterTwo);
  const fs::path aside = data / "damaged" / ("world-" + std::to_string(id) + "-1");
  EXPECT_EQ(bytesOf(aside / journal.filename()), bytes);  // the damaged journal, whole
  fs::remove_all(data);
}

// Issue 39, point 3: physd --verify reports every world's files, and exits 1 on damage.
TEST(Durable, VerifyReportsEveryWorldsFiles) {
  const fs::path data = scratch("verify");
  uint32_t ok = 0, torn = 0, missing = 0, damaged = 0;
  {
    ServerCore a(durableConfig(data));
    ASSERT_TRUE(a.init().ok());
    Client c{&a};
    ok = c.send(CommandBuilder().createWorld({"ok", "", std::nullopt, 0}), 0)->world();
    torn = c.send(CommandBuilder().createWorld({"torn", "", std::nullopt, 0}), 0)->world();
    missing = c.send(CommandBuilder().createWorld({"missing", "", std::nullopt, 0}), 0)->world();
    damaged = c.send(CommandBuilder().createWorld({"damaged", "", std::nullopt, 0}), 0)->world();
    for (uint32_t w : {ok, torn, missing, damaged})
      for (int i = 0; i < 3; ++i)
        ASSERT_EQ(c.send(CommandBuilder().spawnBodies(tower(1, float(i))), w)->status(), Code::Ok);
  }
  fs::resize_file(journalOf(data, torn), fs::file_size(journalOf(data, torn)) - 3);
  fs::remove(journalOf(data, missing));
  {
    const fs::path j = journalOf(data, damaged);
    std::fstream f(j, std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(60);  // inside the first spawn, two good records after it
    f.put('\x5a');
  }
  auto run = [](const std::string& cmd, std::string* out) {
    FILE* p = popen(cmd.c_str(), "r");
    char buf[4096];
    size_t n;
    while (p && (n = fread(buf, 1, sizeof buf, p)) > 0) out->append(buf, n);
    const int st = p ? pclose(p) : -1;
    return WIFEXITED(st) ? WEXITSTATUS(st) : -1;
  };
  std::string out;
  EXPECT_EQ(run(std::string(PHYSD_BINARY) + " --verify " + data.string(), &out), 1) << out;
  auto line = [&](uint32_t id) {
    const std::string key = "world " + std::to_string(id) + " ";
    const size_t p = out.find(key);
    return p == std::string::npos ? std::string() : out.substr(p, out.find("\nworld ", p + 1) - p);
  };
  EXPECT_NE(line(ok).find("'ok': checkpoint ok"), std::string::npos) << out;
  EXPECT_NE(line(ok).find("ok: 3 good records"), std::string::npos) << out;
  EXPECT_NE(line(torn).find("torn tail: 2 good records"), std::string::npos) << out;
  EXPECT_NE(line(missing).find("MISSING"), std::string::npos) << out;
  EXPECT_NE(line(damaged).find("DAMAGED"), std::string::npos) << out;
  EXPECT_NE(line(damaged).find("2 good records follow"), std::string::npos) << out;
  EXPECT_NE(out.find("2 have lost acknowledged data"), std::string::npos) << out;
  // Read only: the torn tail is still there.
  std::string again;
  EXPECT_EQ(run(std::string(PHYSD_BINARY) + " --verify " + data.string(), &again), 1);
  EXPECT_EQ(again, out);
  // Once the loss is accepted, every world's files check out.
  CoreConfig cfg = durableConfig(data);
  cfg.acceptLoss = {missing, damaged};
  {
    ServerCore accepted(cfg);
    ASSERT_TRUE(accepted.init().ok());
    std::vector<std::string> notes;
    ASSERT_TRUE(accepted.restoreWorlds(&notes).ok());
    EXPECT_EQ(accepted.worldIds().size(), 4u);
  }
  out.clear();
  EXPECT_EQ(run(std::string(PHYSD_BINARY) + " --verify " + data.string(), &out), 0) << out;
  EXPECT_NE(out.find("0 have lost acknowledged data"), std::string::npos) << out;
  fs::remove_all(data);
}

// Issue 39, finding 7: physd did not start on a full data disk (it could not write `starts`).
TEST(Durable, AFullDiskAtStartUpServesTheWorldsReadOnly) {
  const fs::path data = scratch("read_only");
  uint32_t id = 0;
  uint64_t hash = 0;
  {
    ServerCore a(durableConfig(data));
    ASSERT_TRUE(a.init().ok());
    Client c{&a};
    id = c.send(CommandBuilder().createWorld({"kept", "", std::nullopt, 0}), 0)->world();
    std::vector<phys::BodyDef> defs = tower(2);
    defs.push_back(groundBody());
    ASSERT_EQ(c.send(CommandBuilder().spawnBodies(defs), id)->status(), Code::Ok);
    ASSERT_EQ(c.send(CommandBuilder().run(60), id)->status(), Code::Ok);
    hash = a.world(id)->world->stateHash();
  }
  auto full = std::make_unique<FullDisk>(0);  // not a byte more
  std::vector<std::string> notes;
  auto b = restart(data, &notes);
  ASSERT_TRUE(b->world(id));
  EXPECT_NE(b->readOnly().find("full"), std::string::npos) << b->readOnly();
  EXPECT_NE(b->status().readOnly.find("full"), std::string::npos);
  bool said = false;
  for (const std::string& n : notes) said |= n.find("read-only") != std::string::npos;
  EXPECT_TRUE(said);
  EXPECT_EQ(b->world(id)->world->stateHash(), hash);
  Client c{b.get(), kClient, 10};
  // Reads are served.
  Reply list = c.send(CommandBuilder().listWorlds(), 0);
  ASSERT_EQ(list->status(), Code::Ok);
  EXPECT_EQ(list->result_as_WorldList()->worlds()->size(), 1u);
  EXPECT_EQ(c.send(CommandBuilder().queryState(), id)->status(), Code::Ok);
  // Edits, steps and new kept worlds are refused with a clear status, and change nothing.
  for (Reply r : {c.send(CommandBuilder().spawnBodies(tower(1, 5)), id),
                  c.send(CommandBuilder().step(3), id),
                  c.send(CommandBuilder().createWorld({"new", "", std::nullopt, 0}), 0)}) {
    EXPECT_EQ(r->status(), Code::ResourceExhausted) << message(r);
    EXPECT_NE(message(r).find("read-only"), std::string::npos) << message(r);
  }
  // The running world does not step past what is stored either.
  for (int tick = 0; tick < 10; ++tick) {
    b->processPending();
    b->advance(1.0 / 60);
  }
  EXPECT_EQ(b->world(id)->world->stateHash(), hash);
  EXPECT_EQ(b->worldIds().size(), 1u);
  // Room again: within a few seconds physd takes writes again by itself.
  full.reset();
  const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(20);
  while (!b->readOnly().empty() && std::chrono::steady_clock::now() < until) {
    b->commitDurable();
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  EXPECT_TRUE(b->readOnly().empty());
  EXPECT_EQ(c.send(CommandBuilder().spawnBodies(tower(1, 5)), id)->status(), Code::Ok);
  fs::remove_all(data);
}

// Data directories written before issue 39: version 1 checkpoints, journals without a header.
TEST(Durable, AVersion1DataDirectoryIsReadAndConverted) {
  const fs::path data = scratch("version1");
  uint32_t id = 0;
  uint64_t hash = 0;
  {
    ServerCore a(durableConfig(data));
    ASSERT_TRUE(a.init().ok());
    Client c{&a};
    id = c.send(CommandBuilder().createWorld({"old", "", std::nullopt, 0}), 0)->world();
    ASSERT_EQ(c.send(CommandBuilder().spawnBodies(tower(2)), id)->status(), Code::Ok);
    ASSERT_EQ(c.send(CommandBuilder().step(9), id)->status(), Code::Ok);
    hash = a.world(id)->world->stateHash();
  }
  // As version 1 wrote them: the version field 1 (and the CRC over it), no journal header.
  const fs::path dir = data / "worlds" / std::to_string(id);
  std::vector<uint8_t> ck = bytesOf(dir / "checkpoint");
  const uint32_t one = 1;
  std::memcpy(ck.data() + 8, &one, 4);
  auto crc32 = [](const uint8_t* p, size_t n) {
    uint32_t c = 0xFFFFFFFFu;
    for (size_t i = 0; i < n; ++i) {
      c ^= p[i];
      for (int k = 0; k < 8; ++k) c = (c >> 1) ^ (0xEDB88320u & (0u - (c & 1u)));
    }
    return ~c;
  };
  const uint32_t sum = crc32(ck.data(), ck.size() - 4);
  std::memcpy(ck.data() + ck.size() - 4, &sum, 4);
  std::ofstream(dir / "checkpoint", std::ios::binary | std::ios::trunc)
      .write(reinterpret_cast<const char*>(ck.data()), std::streamsize(ck.size()));
  const fs::path journal = journalOf(data, id);
  std::vector<uint8_t> j = bytesOf(journal);
  ASSERT_GT(j.size(), 33u);
  ASSERT_EQ(j[16], 4);  // the header record: 17 bytes + 16 of payload
  std::ofstream(journal, std::ios::binary | std::ios::trunc)
      .write(reinterpret_cast<const char*>(j.data() + 33), std::streamsize(j.size() - 33));
  std::string text;
  EXPECT_TRUE(verifyDataDir(data.string(), &text)) << text;
  EXPECT_NE(text.find("version 1"), std::string::npos) << text;

  std::vector<std::string> notes;
  auto b = restart(data, &notes);
  ASSERT_TRUE(b->world(id)) << damageOf(*b, id);
  EXPECT_EQ(b->world(id)->tick, 9u);
  EXPECT_EQ(b->world(id)->world->stateHash(), hash);
  // Its new checkpoint is version 2, with a header in its journal.
  text.clear();
  EXPECT_TRUE(verifyDataDir(data.string(), &text)) << text;
  EXPECT_NE(text.find("version 2"), std::string::npos) << text;
  fs::remove_all(data);
}

TEST(Durable, AMismatchedClientIdIsAnsweredToTheSenderOnly) {
  // Issue 24 6(a): a command naming another client is answered to its envelope's key.
  ServerCore core(testConfig());
  ASSERT_TRUE(core.init().ok());
  const uint64_t victim = 0x51C71, sender = 0xBAD;
  Bytes cmd = CommandBuilder().listWorlds().finish({victim, 77, 0});
  Reply r = decode(core.applyBytes(cmd, sender, 5));
  EXPECT_EQ(r->status(), Code::Malformed);
  EXPECT_EQ(r->client_id(), sender);
}

}  // namespace
}  // namespace phys::server::test
