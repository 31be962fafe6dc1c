// Durable worlds: what ServerCore does with WorldStore (store.h). docs/SERVER.md "Durable
// worlds" says what is promised; this is how:
//
// - A command that changes a world (an edit, a Batch, Run, Pause) is appended to the world's
//   journal with the tick it was applied at, right after it is applied; if the append fails
//   the world is rebuilt from its files (so it is as it was before the command) and the
//   command answered with the error. Its reply is held (pushReply) until commitDurable has
//   synced the journal: one fdatasync per world per tick however many commands it applied.
// - Steps are not journaled one by one: stepping is deterministic, so a record's tick says
//   how many steps came before it. A Step's end and a running world (every markPeriodS)
//   journal a Mark with the tick reached and the run state.
// - A command that replaces the whole world (LoadScene, ResetWorld, RestoreSnapshot) writes a
//   checkpoint before its reply, as does CreateWorld. Checkpoints are also taken every
//   checkpointPeriodS while a world changes, and when its journal passes journalMaxBytes.
// - At start-up each world is rebuilt from its checkpoint, then its records are replayed:
//   step to the record's tick, apply the command (or take the mark's run state).
#include <fcntl.h>
#include <sys/file.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <filesystem>
#include <fstream>

#include "internal.h"
#include "phys/protocol/convert.h"
#include "phys/protocol/decoder.h"

namespace phys::server {

namespace fs = std::filesystem;

namespace {

/// Requests whose effect a journal record keeps (others change nothing, replace the world
/// and checkpoint, or are steps).
bool journaled(wire::Request t) {
  return protocol::isBatchable(t) || t == wire::Request::Batch || t == wire::Request::Run ||
         t == wire::Request::Pause || t == wire::Request::SetAccess;
}

std::vector<uint8_t> markPayload(const ServerWorld& w) {
  std::vector<uint8_t> p(9);
  p[0] = uint8_t(w.mode);
  std::memcpy(p.data() + 1, &w.rateHz, 8);
  return p;
}

std::string worldDir(const std::string& data, uint32_t id) {
  return data + "/worlds/" + std::to_string(id);
}

/// A file's limits, not a message's: a checkpoint's definitions may list a whole world.
protocol::Limits fileLimits(protocol::Limits l) {
  l.maxMessageBytes = uint32_t(std::min<uint64_t>(uint64_t(1) << 31, UINT32_MAX)) - 1;
  l.maxTables = UINT32_MAX;
  return l;
}

}  // namespace

void ServerCore::log(bool error, const std::string& line) const {
  if (log_)
    log_(error, line);
  else
    std::fprintf(stderr, "physd: %s%s\n", error ? "error: " : "", line.c_str());
}

ServerWorld* ServerCore::findWorld(const std::string& name) {
  for (auto& [id, w] : worlds_)
    if (w->name == name) return w.get();
  return nullptr;
}

Status ServerCore::createStore(ServerWorld& w) {
  w.store = std::make_unique<WorldStore>(worldDir(config_.dataDir, w.id));
  Status s = checkpointWorld(w);
  if (s.ok()) {
    const std::string next = std::to_string(nextWorldId_) + "\n";
    s = writeFileAtomically(config_.dataDir + "/next_world_id",
                            std::span<const uint8_t>(
                                reinterpret_cast<const uint8_t*>(next.data()), next.size()));
  }
  if (!s.ok()) {
    w.store->remove();
    w.store.reset();
  }
  return s;
}

Status ServerCore::checkpointWorld(ServerWorld& w) {
  if (!w.store) return Status::Ok();
  // A failed checkpoint is tried again a period later, not at every tick.
  w.checkpointAt = std::chrono::steady_clock::now();
  w.checkpointFailed = true;
  Checkpoint c;
  c.meta.worldId = w.id;
  c.meta.name = w.name;
  c.meta.preset = w.preset;
  c.meta.backend = phys::toString(w.world->def().backend);
  c.meta.tick = w.tick;
  c.meta.revision = w.revision;
  c.meta.mode = uint8_t(w.mode);
  c.meta.rateHz = w.rateHz;
  c.meta.owner = w.owner;
  c.meta.editors = w.editors;
  c.meta.ownerProven = w.ownerProven;
  c.meta.shared = w.shared;
  phys::Status ps = w.world->saveSnapshot(&c.engine);
  if (!ps.ok())
    return Status::Error(Code::Internal, "checkpoint of world " + std::to_string(w.id) + ": " +
                                             ps.message);
  protocol::SnapshotData defs;
  defs.name = w.name;
  defs.gravity = w.world->def().gravity;
  defs.timeStep = w.world->def().timeStep;
  defs.solver = w.world->def().solver;
  for (auto& [id, d] : w.bodyDefs) defs.bodies.push_back({id, d});
  for (auto& [id, d] : w.jointDefs) defs.joints.push_back({id, d});
  c.defs = protocol::encodeSnapshot(defs);
  Status s = w.store->writeCheckpoint(std::move(c));
  if (!s.ok()) return s;
  w.checkpointFailed = false;
  w.checkpointTick = w.journaledTick = w.tick;
  return Status::Ok();
}

Status ServerCore::checkpointNow(uint32_t id) {
  ServerWorld* w = world(id);
  if (!w) return Status::Error(Code::NotFound, "no world " + std::to_string(id));
  return checkpointWorld(*w);
}

Status ServerCore::durableReplaced(ServerWorld& w, const std::string& what) {
  if (!w.store || replaying_) return Status::Ok();
  Status s = checkpointWorld(w);
  if (s.ok()) return s;
  std::vector<std::string> notes;
  Status back = reloadWorld(w, &notes);
  s.message = what + ": " + s.message +
              (back.ok() ? "; the world is as it was before this command"
                         : "; and the world could not be reloaded from its files: " + back.message);
  log(true, "world " + std::to_string(w.id) + ": " + s.message);
  return s;
}

Status ServerCore::journalMark(ServerWorld& w) {
  if (!w.store || replaying_) return Status::Ok();
  Status s = w.store->append(w.tick, JournalRecord::Kind::Mark, markPayload(w));
  w.markAt = std::chrono::steady_clock::now();
  if (s.ok()) w.journaledTick = w.tick;
  return s;
}

void ServerCore::journalApplied(const Incoming& in, Bytes* reply) {
  if (!durable() || replaying_ || !lastStatus_.ok() || !in.command.ok()) return;
  const wire::Command& c = *in.command;
  if (!journaled(c.request_type())) return;
  ServerWorld* w = world(c.world());
  if (!w || !w->store) return;
  Status s = w->store->append(w->tick, JournalRecord::Kind::Command, in.command.bytes);
  if (s.ok()) {
    w->journaledTick = w->tick;
    journaledWorld_ = w->id;
    if (current_) return;  // from the queue: synced with the tick's others (commitDurable)
    s = w->store->sync();  // applied directly (tests, start-up): durable before the reply
    if (s.ok()) return;
  }
  // Not stored: the world goes back to what its files hold, and the client hears why.
  std::vector<std::string> notes;
  Status back = reloadWorld(*w, &notes);
  ReplyHeader h = protocol::replyTo(c);
  h.tick = w->tick;
  h.status = Status::Error(s.code, std::string(protocol::requestName(c.request_type())) +
                                       ": not stored: " + s.message +
                                       (back.ok() ? "; the world is as it was before it"
                                                  : "; reloading the world failed: " +
                                                        back.message));
  ++counters_.errors;
  log(true, "world " + std::to_string(w->id) + ": " + h.status.message);
  *reply = protocol::encodeReply(h);
}

void ServerCore::commitDurable() {
  const auto now = std::chrono::steady_clock::now();
  std::vector<uint32_t> failed;
  if (durable()) {
    for (auto& [id, w] : worlds_) {
      if (!w->store) continue;
      // A running world's progress, so that a restart resumes close to where it stopped.
      if (!w->busy() && w->tick != w->journaledTick &&
          now - w->markAt >= std::chrono::duration<double>(config_.markPeriodS))
        journalMark(*w);
      Status s = w->store->sync();
      if (!s.ok()) {
        failed.push_back(id);
        log(true, "world " + std::to_string(id) + ": " + s.message);
      }
    }
  }
  // The replies, now that what they acknowledge is on disk; those of a world whose journal
  // failed to sync become errors (the world goes back to what its files hold).
  for (HeldReply& r : held_) {
    if (r.durableWorld && r.hasFailed &&
        std::find(failed.begin(), failed.end(), r.durableWorld) != failed.end()) {
      r.failed.status = Status::Error(Code::Internal,
                                      "not stored: the world's journal could not be synced; the "
                                      "world is as its files hold it");
      ++counters_.errors;
      r.reply = protocol::encodeReply(r.failed);
    }
    pushReplyNow(r.key, r.seq, std::move(r.reply));
  }
  held_.clear();
  for (uint32_t id : failed) {
    std::vector<std::string> notes;
    if (ServerWorld* w = world(id)) {
      Status s = reloadWorld(*w, &notes);
      if (!s.ok()) log(true, "world " + std::to_string(id) + ": reload failed: " + s.message);
    }
  }
  if (!durable()) return;
  // Checkpoints that are due: a long journal, or a period of changes.
  for (auto& [id, w] : worlds_) {
    if (!w->store || w->busy()) continue;
    const bool changed = w->store->journalRecords() > 0 || w->tick != w->checkpointTick;
    const bool period =
        now - w->checkpointAt >= std::chrono::duration<double>(config_.checkpointPeriodS);
    // A long journal is folded at once, unless the last try failed (then a period later).
    const bool due = (w->store->journalBytes() > config_.journalMaxBytes &&
                      (!w->checkpointFailed || period)) ||
                     (changed && period);
    if (!due) continue;
    Status s = checkpointWorld(*w);
    if (!s.ok()) log(true, "world " + std::to_string(id) + ": checkpoint: " + s.message);
  }
}

Status ServerCore::restoreInto(ServerWorld& w, const Checkpoint& c,
                               const std::vector<JournalRecord>& records,
                               std::vector<std::string>* notes) {
  phys::WorldDef def;
  if (!phys::parseBackend(c.meta.backend, &def.backend)) def.backend = config_.backend;
  auto fresh = makeWorld(c.meta.name, c.meta.preset, def);
  w.nextInterest = std::max(w.nextInterest, fresh->nextInterest);  // a reload keeps its count
  phys::Status ps = fresh->world->restoreSnapshot(c.engine.data(), c.engine.size());
  if (!ps.ok())
    return Status::Error(Code::Internal, "checkpoint engine state: " + ps.message);
  applyPolicy(*fresh->world);
  w.world = std::move(fresh->world);
  w.name = c.meta.name;
  w.preset = c.meta.preset;
  w.tick = w.checkpointTick = w.journaledTick = c.meta.tick;
  w.revision = c.meta.revision;
  w.mode = RunMode(c.meta.mode);
  w.rateHz = c.meta.rateHz;
  w.owner = c.meta.owner;
  w.editors = c.meta.editors;
  w.ownerProven = c.meta.ownerProven;
  w.shared = c.meta.shared;
  w.accumulator = 0;
  w.bodyDefs.clear();
  w.jointDefs.clear();
  auto defs = protocol::decodeSnapshot(c.defs, fileLimits(config_.limits));
  protocol::SnapshotData data;
  if (defs.ok() && protocol::toSnapshotData(*defs, &data).ok()) {
    for (auto& b : data.bodies) w.bodyDefs[b.id] = b.def;
    for (auto& j : data.joints) w.jointDefs[j.id] = j.def;
  } else {
    notes->push_back("world " + std::to_string(w.id) +
                     ": the checkpoint's definitions cannot be read (" + defs.status.message +
                     "); rebuilt from the engine");
    rebuildDefs(w);
  }
  // Replay: steps up to each record's tick, then the record.
  replaying_ = true;
  size_t applied = 0;
  for (const JournalRecord& r : records) {
    while (w.tick < r.tick) {
      stepTimed(w, 1);
      if (!stepProblem_.ok()) break;
    }
    if (w.tick != r.tick) {
      notes->push_back("world " + std::to_string(w.id) + ": replay stopped at tick " +
                       std::to_string(w.tick) + " (a step was not taken: " +
                       stepProblem_.message + "); " + std::to_string(records.size() - applied) +
                       " journal records not replayed");
      break;
    }
    if (r.kind == JournalRecord::Kind::Mark && r.payload.size() == 9) {
      w.mode = RunMode(r.payload[0]);
      std::memcpy(&w.rateHz, r.payload.data() + 1, 8);
    } else if (r.kind == JournalRecord::Kind::Command) {
      auto cmd = protocol::decodeCommand(r.payload, config_.limits);
      if (!cmd.ok()) {
        notes->push_back("world " + std::to_string(w.id) + ": journal record " +
                         std::to_string(applied) + " is not a command (" + cmd.status.message +
                         "); replay stopped");
        break;
      }
      // Access was checked when it was first applied; nothing it does depends on who sent it.
      applyChecked(*cmd, cmd->client_id(), cmd->client_id(), /*proven=*/false);
      if (!lastStatus_.ok())
        notes->push_back("world " + std::to_string(w.id) + ": journal record " +
                         std::to_string(applied) + " (" +
                         protocol::requestName(cmd->request_type()) +
                         ") was refused on replay: " + lastStatus_.message);
    }
    ++applied;
  }
  replaying_ = false;
  ++w.revision;  // never behind what subscribers last saw (replay bumps it at least as often)
  w.journaledTick = w.tick;
  w.infoDirty = w.frameDirty = true;
  w.framesReplaced();
  w.markAt = w.checkpointAt = std::chrono::steady_clock::now();
  return Status::Ok();
}

Status ServerCore::reloadWorld(ServerWorld& w, std::vector<std::string>* notes) {
  if (!w.store) return Status::Error(Code::Internal, "world " + std::to_string(w.id) + " has no files");
  Checkpoint c;
  std::vector<JournalRecord> records;
  Status s = w.store->load(&c, &records, notes);
  if (!s.ok()) return s;
  cancelJob(w, "the world was reloaded from its files");
  return restoreInto(w, c, records, notes);
}

Status ServerCore::restoreWorlds(std::vector<std::string>* notes) {
  if (!durable()) return Status::Ok();
  std::error_code ec;
  fs::create_directories(config_.dataDir + "/worlds", ec);
  if (ec)
    return Status::Error(Code::Internal,
                         "cannot create " + config_.dataDir + "/worlds: " + ec.message());
  // One daemon per data directory: a second would interleave its writes with ours.
  const std::string lockPath = config_.dataDir + "/lock";
  const int fd = ::open(lockPath.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
  if (fd < 0)
    return Status::Error(Code::Internal, "cannot open " + lockPath + ": " + std::strerror(errno));
  if (::flock(fd, LOCK_EX | LOCK_NB) != 0) {
    char pid[32] = {};
    const ssize_t n = ::pread(fd, pid, sizeof pid - 1, 0);
    ::close(fd);
    return Status::Error(Code::IncorrectState,
                         config_.dataDir + " is in use by another physd" +
                             (n > 0 ? " (pid " + std::string(pid, size_t(n)) + ")" : "") +
                             "; give each daemon its own [paths] data");
  }
  const std::string pid = std::to_string(::getpid());
  if (::ftruncate(fd, 0) != 0 || ::pwrite(fd, pid.data(), pid.size(), 0) < 0) {
    // The pid is for the message above only; the lock is what counts.
  }
  if (dataLock_ >= 0) ::close(dataLock_);
  dataLock_ = fd;
  {
    std::ifstream f(config_.dataDir + "/next_world_id");
    uint32_t next = 0;
    if (f >> next && next > nextWorldId_) nextWorldId_ = next;
  }
  {
    // Interests are not kept across a restart, and their ids name topics
    // (phys/state/<world>/<interest>) that readers of the old daemon may still have: each
    // start of this data directory numbers them from its own base, so that a new interest
    // never takes a stale subscriber's topic (the SDK subscribes its interests again).
    const std::string path = config_.dataDir + "/starts";
    uint64_t starts = 0;
    std::ifstream(path) >> starts;
    ++starts;
    const std::string text = std::to_string(starts) + "\n";
    Status st = writeFileAtomically(
        path, std::span<const uint8_t>(reinterpret_cast<const uint8_t*>(text.data()), text.size()));
    if (!st.ok()) return st;
    interestBase_ = uint32_t(starts % 32768) << 16;
  }
  std::vector<uint32_t> ids;
  for (const auto& e : fs::directory_iterator(config_.dataDir + "/worlds", ec)) {
    const std::string n = e.path().filename().string();
    if (n.ends_with(".removed")) {  // a DestroyWorld that a crash interrupted
      fs::remove_all(e.path(), ec);
      continue;
    }
    char* end = nullptr;
    const unsigned long id = std::strtoul(n.c_str(), &end, 10);
    if (e.is_directory() && end && *end == 0 && id > 0 && id <= UINT32_MAX) ids.push_back(uint32_t(id));
  }
  std::sort(ids.begin(), ids.end());
  for (uint32_t id : ids) {
    auto w = std::make_unique<ServerWorld>();
    w->id = id;
    w->store = std::make_unique<WorldStore>(worldDir(config_.dataDir, id));
    Checkpoint c;
    std::vector<JournalRecord> records;
    Status s = w->store->load(&c, &records, notes);
    if (s.ok() && c.meta.worldId != id)
      s = Status::Error(Code::Malformed, "its checkpoint is of world " +
                                             std::to_string(c.meta.worldId));
    if (s.ok() && findWorld(c.meta.name))
      s = Status::Error(Code::InvalidArgument, "name '" + c.meta.name + "' is taken");
    if (!s.ok()) {
      notes->push_back("world " + std::to_string(id) + " not restored: " + s.message +
                       " (its files are left in place)");
      continue;
    }
    ServerWorld* sw = w.get();
    worlds_[id] = std::move(w);
    nextWorldId_ = std::max(nextWorldId_, id + 1);
    const auto t0 = std::chrono::steady_clock::now();
    s = restoreInto(*sw, c, records, notes);
    if (!s.ok()) {
      notes->push_back("world " + std::to_string(id) + " not restored: " + s.message +
                       " (its files are left in place)");
      sw->store.reset();
      worlds_.erase(id);
      continue;
    }
    const double ms =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    notes->push_back("world " + std::to_string(id) + " '" + sw->name + "' restored at tick " +
                     std::to_string(sw->tick) + " (checkpoint tick " +
                     std::to_string(c.meta.tick) + ", " + std::to_string(records.size()) +
                     " journal records replayed, " + std::to_string(int(ms)) + " ms)");
    // The replayed state becomes the new checkpoint, so the next start replays nothing twice.
    s = checkpointWorld(*sw);
    if (!s.ok()) notes->push_back("world " + std::to_string(id) + ": checkpoint: " + s.message);
  }
  return Status::Ok();
}

}  // namespace phys::server
