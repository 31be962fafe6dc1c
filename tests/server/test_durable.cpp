// Durable worlds (docs/SERVER.md "Durable worlds"): a world's checkpoint and journal under
// the data directory, restored by a new ServerCore as a restarted daemon does. A "crash" is
// a copy of the data directory taken while the first core goes on (everything acknowledged
// is on disk by then), or the first core dropped without any shutdown.
#include <signal.h>
#include <sys/resource.h>

#include <filesystem>
#include <fstream>

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

/// A client of one core: commands applied directly (applyBytes) or through the queue.
struct Client {
  ServerCore* core;
  uint64_t seq = 0;
  Reply send(CommandBuilder& b, uint32_t world) {
    ++seq;
    return decode(core->applyBytes(b.finish({kClient, seq, world}), kClient, seq));
  }
  void submit(CommandBuilder& b, uint32_t world) {
    core->submit(queuedCommand(kClient, ++seq, b, world));
  }
};

std::unique_ptr<ServerCore> restart(const fs::path& data, std::vector<std::string>* notes) {
  auto core = std::make_unique<ServerCore>(durableConfig(data));
  EXPECT_TRUE(core->init().ok());
  Status s = core->restoreWorlds(notes);
  EXPECT_TRUE(s.ok()) << s.message;
  return core;
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
  // World info's definitions too: names and damping as given.
  EXPECT_EQ(b->world(id)->bodyDefs.at(ids[0]).name, "bottom");
  EXPECT_EQ(b->world(id)->bodyDefs.size(), a.world(id)->bodyDefs.size());
  EXPECT_EQ(b->world(id)->preset, "pgs");
  EXPECT_EQ(b->world(id)->owner, kClient);  // access is kept too
  ASSERT_TRUE(a.stepWorld(id, 40).ok());
  expectSameFuture(a, id, *b);
  // New ids continue where the original's do.
  Client cb{b.get(), 100};
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
  cfg.markPeriodS = 0;  // a mark every tick: the restart resumes at the last tick
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
  Client cb{b.get(), 50};
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
  Client cb{b.get(), 10};
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
