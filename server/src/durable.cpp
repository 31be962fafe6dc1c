// Durable worlds: what ServerCore does with WorldStore (store.h). docs/SERVER.md "Durable
// worlds" says what is promised; this is how:
//
// - A command that changes a world (an edit, a Batch, Run, Pause) is appended to the world's
//   journal with the tick it was applied at, right after it is applied; if the append fails
//   the world is rebuilt from its files (so it is as it was before the command) and the
//   command answered with the error. Its reply is held (pushReply) until commitDurable has
//   synced the journal: one fdatasync per world per tick however many commands it applied.
// - Steps are not journaled one by one: stepping is deterministic, so a record's tick says
//   how many steps came before it. But no step is taken before the journal allows it: a Lease
//   record ("from this tick the world may step up to tick H") is durable before the first
//   step it allows (a Step's, synced with its tick's commands; a running world's, about
//   leasePeriodS ahead, synced at once). A restart steps to the last lease's end unless a
//   Mark (a Step ended early, a step failed) or a Pause says where the world stopped. If a
//   lease cannot be stored, the Step is refused unchanged, a running world is held.
// - A command that replaces the whole world (LoadScene, ResetWorld, RestoreSnapshot) writes a
//   checkpoint before its reply, as does CreateWorld. Checkpoints are also taken every
//   checkpointPeriodS while a world changes, and when its journal passes journalMaxBytes.
// - At start-up each world is rebuilt from its checkpoint, then its records are replayed:
//   step to the record's tick, apply the command (or take the mark's run state, or the
//   lease), then the steps of a lease still open. A world whose journal is missing or damaged
//   before its end is not restored (listed as damaged) unless the operator accepts the loss.
#include <fcntl.h>
#include <sys/file.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>

#include "internal.h"
#include "phys/protocol/convert.h"
#include "phys/protocol/decoder.h"
#include "phys/protocol/requests.h"

namespace phys::server {

namespace fs = std::filesystem;

namespace {

/// Requests whose effect a journal record keeps (others change nothing, replace the world
/// and checkpoint, or are steps).
bool journaled(wire::Request t) { return protocol::requestInfo(t).has(protocol::kJournaled); }

std::vector<uint8_t> leasePayload(uint64_t until) {
  std::vector<uint8_t> p(8);
  std::memcpy(p.data(), &until, 8);
  return p;
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
  Status s = checkpointOf(w, &c);
  if (!s.ok()) return s;
  s = w.store->writeCheckpoint(std::move(c));
  if (!s.ok()) return s;
  w.checkpointFailed = false;
  // The new journal holds no lease: the next step needs one.
  w.checkpointTick = w.leaseUntil = w.reachedTick = w.tick;
  return Status::Ok();
}

Status ServerCore::checkpointOf(const ServerWorld& w, Checkpoint* out) const {
  Checkpoint& c = *out;
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
  // c.defs stays empty: the engine's state carries every definition (names, damping, masses
  // as given) and every setting, the one source a restore reads them from.
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
  if (!readOnly_.empty())
    return Status::Error(Code::ResourceExhausted, "physd is read-only: " + readOnly_);
  Status s = w.store->append(w.tick, JournalRecord::Kind::Mark, markPayload(w));
  if (s.ok()) w.leaseUntil = w.tick;  // the world stopped here: its lease ends
  return s;
}

Status ServerCore::leaseTo(ServerWorld& w, uint64_t until, bool syncNow, bool* appended) {
  if (appended) *appended = false;
  if (!w.store || replaying_ || until <= w.leaseUntil) return Status::Ok();
  if (!readOnly_.empty())
    return Status::Error(Code::ResourceExhausted, "physd is read-only: " + readOnly_);
  // Records appended before this one and not yet synced belong to replies still held; a
  // failed sync below would cut them too, so those replies must fail with it.
  const bool others = w.store->dirty();
  Status s = w.store->append(w.tick, JournalRecord::Kind::Lease, leasePayload(until));
  if (s.ok() && syncNow) {
    s = w.store->sync();
    if (!s.ok() && others) lostRecords_.emplace_back(w.id, s);
  }
  if (!s.ok()) return s;  // nothing of it is left in the journal
  w.leaseUntil = until;
  if (appended) *appended = true;
  return Status::Ok();
}

uint64_t ServerCore::leaseForRun(ServerWorld& w, uint64_t n) {
  if (!w.store || replaying_ || n == 0 || w.tick + n <= w.leaseUntil) return n;
  // About leasePeriodS of the world's steps at once: at its rate, or (as fast as possible) at
  // the pace of its last tick; at least this tick's.
  uint64_t ahead = n;
  // A world with a standby promises less at once: its standby replays the records as they
  // come, and a takeover steps the rest of the last lease (docs/SERVER.md "Standby and
  // takeover").
  const double period = w.ownership != 0 && config_.standby != 0
                            ? std::min(config_.leasePeriodS, config_.standbyLeasePeriodS)
                            : config_.leasePeriodS;
  if (period > 0) {
    const double perS = w.mode == RunMode::RealTime ? w.rateHz
                        : w.tickMs > 0              ? 1000.0 / double(w.tickMs)
                                                    : 1000.0;
    ahead = std::max<uint64_t>(
        ahead, uint64_t(std::min(std::ceil(perS * period), double(1 << 20))));
  }
  Status s = leaseTo(w, w.tick + ahead, /*syncNow=*/true);
  if (s.ok()) {
    if (w.held) {
      w.held = false;
      const std::string m = "the world's progress is stored again; it goes on from tick " +
                            std::to_string(w.tick);
      queueEvent(w, wire::Severity::Info, "stored", m);
      log(false, "world " + std::to_string(w.id) + ": " + m);
    }
    return n;
  }
  // Not a step past what is stored: the world waits at this tick (its time does not pile up
  // meanwhile) and tries again at the next tick.
  w.accumulator = 0;
  if (!w.held) {
    w.held = true;
    const std::string m = "the world's progress cannot be stored (" + s.message +
                          "); it is held at tick " + std::to_string(w.tick) +
                          " and goes on by itself once its journal can be written";
    queueEvent(w, wire::Severity::Error, "not_stored", m);
    log(true, "world " + std::to_string(w.id) + ": " + m);
  }
  return 0;
}

void ServerCore::journalApplied(const Incoming& in, Bytes* reply) {
  if (!durable() || replaying_ || !lastStatus_.ok() || !in.command.ok()) return;
  const wire::Command& c = *in.command;
  if (!journaled(c.request_type())) return;
  ServerWorld* w = world(c.world());
  if (!w || !w->store) return;
  Status s = w->store->append(w->tick, JournalRecord::Kind::Command, in.command.bytes);
  if (s.ok()) {
    // A Pause ends the world's lease (a restart stops there too).
    if (c.request_type() == wire::Request::Pause) w->leaseUntil = w->tick;
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
  // Worlds whose journal lost records that replies wait for: a failed sync here, or one a
  // lease took (leaseTo).
  std::vector<std::pair<uint32_t, Status>> failed = std::move(lostRecords_);
  lostRecords_.clear();
  if (durable()) {
    retryWritable();
    for (auto& [id, w] : worlds_) {
      if (!w->store) continue;
      Status s = w->store->sync();
      if (!s.ok()) {
        log(true, "world " + std::to_string(id) + ": " + s.message);
        failed.emplace_back(id, std::move(s));
        continue;
      }
      if (w->job) w->job->stored = true;  // its lease is on disk: its steps may be taken
    }
  }
  auto failure = [&](uint32_t id) -> const Status* {
    for (const auto& [fid, st] : failed)
      if (fid == id) return &st;
    return nullptr;
  };
  // A Step whose lease was not stored takes no step: refused (its reply joins the others).
  for (const auto& [id, st] : failed)
    if (ServerWorld* w = world(id); w && w->job && !w->job->stored)
      endJob(*w, Status::Error(st.code, "step: not stored: " + st.message));
  // The replies, now that what they acknowledge is on disk; those of a world whose journal
  // failed to sync become errors (the world goes back to what its files hold).
  // With a coordinator, a registered world's acknowledgements go out only while this
  // daemon's hold is renewed, checked after the sync (docs/SERVER.md "Standby and takeover").
  const bool held = !coordinated() || holding();
  for (HeldReply& r : held_) {
    const Status* f = r.durableWorld && r.hasFailed ? failure(r.durableWorld) : nullptr;
    if (f) {
      r.failed.status = Status::Error(f->code, "not stored: " + f->message +
                                                   "; the world is as its files hold it");
      ++counters_.errors;
      r.reply = protocol::encodeReply(r.failed);
    }
    if (!held && r.durableWorld)
      if (const ServerWorld* w = world(r.durableWorld); w && w->ownership != 0) {
        parked_.push_back(std::move(r));
        continue;
      }
    pushReplyNow(r.key, r.seq, std::move(r.reply));
  }
  held_.clear();
  for (const auto& [id, st] : failed) {
    std::vector<std::string> notes;
    if (ServerWorld* w = world(id)) {
      Status s = reloadWorld(*w, &notes);
      if (!s.ok()) log(true, "world " + std::to_string(id) + ": reload failed: " + s.message);
    }
  }
  if (!durable() || !readOnly_.empty()) return;
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
                               std::vector<std::string>* notes, uint64_t stopAt) {
  Status s = beginReplay(w, c);
  if (!s.ok()) return s;
  Replay replay;
  replayRecords(w, records, &replay, notes);
  endReplay(w, replay, notes, stopAt);
  return Status::Ok();
}

Status ServerCore::beginReplay(ServerWorld& w, const Checkpoint& c) {
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
  w.tick = w.checkpointTick = c.meta.tick;
  w.revision = c.meta.revision;
  w.mode = RunMode(c.meta.mode);
  w.rateHz = c.meta.rateHz;
  w.owner = c.meta.owner;
  w.editors = c.meta.editors;
  w.ownerProven = c.meta.ownerProven;
  w.shared = c.meta.shared;
  w.accumulator = 0;
  // (A checkpoint written before issue 40 also holds the definitions as a portable snapshot:
  // a copy of what its engine state holds, not read.)
  return Status::Ok();
}

void ServerCore::replayRecords(ServerWorld& w, const std::vector<JournalRecord>& records,
                               Replay* replay, std::vector<std::string>* notes) {
  // Steps up to each record's tick, then the record.
  replaying_ = true;
  for (; replay->applied < records.size() && !replay->stopped; ++replay->applied) {
    const JournalRecord& r = records[replay->applied];
    while (w.tick < r.tick) {
      stepTimed(w, 1);
      if (!stepProblem_.ok()) break;
    }
    if (w.tick != r.tick) {
      notes->push_back("world " + std::to_string(w.id) + ": replay stopped at tick " +
                       std::to_string(w.tick) + " (a step was not taken: " +
                       stepProblem_.message + "); " +
                       std::to_string(records.size() - replay->applied) +
                       " journal records not replayed");
      replay->stopped = true;
      break;
    }
    if (r.kind == JournalRecord::Kind::Mark && r.payload.size() == 9) {
      w.mode = RunMode(r.payload[0]);
      std::memcpy(&w.rateHz, r.payload.data() + 1, 8);
      replay->leaseOpen = false;  // the world stopped stepping here
    } else if (r.kind == JournalRecord::Kind::Lease && r.payload.size() == 8) {
      std::memcpy(&replay->lease, r.payload.data(), 8);
      replay->leaseOpen = true;
    } else if (r.kind == JournalRecord::Kind::Command) {
      auto cmd = protocol::decodeCommand(r.payload, config_.limits);
      if (!cmd.ok()) {
        notes->push_back("world " + std::to_string(w.id) + ": journal record " +
                         std::to_string(replay->applied) + " is not a command (" +
                         cmd.status.message + "); replay stopped");
        replay->stopped = true;
        break;
      }
      // Access was checked when it was first applied; nothing it does depends on who sent it.
      applyChecked(*cmd, cmd->client_id(), cmd->client_id(), /*proven=*/false);
      if (!lastStatus_.ok())
        notes->push_back("world " + std::to_string(w.id) + ": journal record " +
                         std::to_string(replay->applied) + " (" +
                         protocol::requestName(cmd->request_type()) +
                         ") was refused on replay: " + lastStatus_.message);
      if (cmd->request_type() == wire::Request::Pause) replay->leaseOpen = false;
    }
  }
  replaying_ = false;
}

void ServerCore::endReplay(ServerWorld& w, Replay& replay, std::vector<std::string>* notes,
                           uint64_t stopAt) {
  // The steps of a lease that is still open (the world may have taken them, and subscribers
  // seen them).
  replaying_ = true;
  if (replay.leaseOpen && !replay.stopped) {
    const uint64_t end = std::min(replay.lease, stopAt);
    while (w.tick < end) {
      stepTimed(w, 1);
      if (!stepProblem_.ok()) {
        notes->push_back("world " + std::to_string(w.id) + ": replay stopped at tick " +
                         std::to_string(w.tick) + " of its lease to " +
                         std::to_string(replay.lease) + " (a step was not taken: " +
                         stepProblem_.message + ")");
        replay.leaseOpen = false;
        break;
      }
    }
  }
  replaying_ = false;
  ++w.revision;  // never behind what subscribers last saw (replay bumps it at least as often)
  w.leaseUntil = replay.leaseOpen ? std::max(replay.lease, w.tick) : w.tick;
  w.reachedTick = w.tick;
  w.held = false;
  w.infoDirty = w.frameDirty = true;
  w.epoch = std::max(w.epoch, epochBase_);  // this start's range (a reload: the world's own)
  w.framesReplaced();                       // a new epoch
  w.checkpointAt = std::chrono::steady_clock::now();
}

Status ServerCore::reloadWorld(ServerWorld& w, std::vector<std::string>* notes) {
  if (!w.store) return Status::Error(Code::Internal, "world " + std::to_string(w.id) + " has no files");
  Checkpoint c;
  std::vector<JournalRecord> records;
  Status s = w.store->load(&c, &records, notes);
  if (!s.ok()) return s;
  const uint64_t reached = w.reachedTick;
  cancelJob(w, "the world was reloaded from its files");
  return restoreInto(w, c, records, notes, reached);
}

namespace {
/// A failure to write that a full data disk explains (ENOSPC, EDQUOT, EFBIG: store.cpp).
bool diskFull(const Status& s) {
  return s.code == Code::ResourceExhausted;
}
bool diskFull(const std::error_code& ec) {
  return ec.value() == ENOSPC || ec.value() == EDQUOT || ec.value() == EFBIG;
}
}  // namespace

Status ServerCore::lockData() {
  // One daemon per data directory: a second would interleave its writes with ours.
  const std::string lockPath = config_.dataDir + "/lock";
  const int fd = ::open(lockPath.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
  if (fd < 0) {
    const int e = errno;
    return Status::Error(e == ENOSPC || e == EDQUOT ? Code::ResourceExhausted : Code::Internal,
                         "cannot open " + lockPath + ": " + std::strerror(e));
  }
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
  return Status::Ok();
}

Status ServerCore::writeStarts() {
  const std::string text = std::to_string(starts_) + "\n";
  return writeFileAtomically(
      config_.dataDir + "/starts",
      std::span<const uint8_t>(reinterpret_cast<const uint8_t*>(text.data()), text.size()));
}

void ServerCore::retryWritable() {
  const auto now = std::chrono::steady_clock::now();
  if (readOnly_.empty() || now < readOnlyRetryAt_) return;
  readOnlyRetryAt_ = now + std::chrono::seconds(1);
  std::error_code ec;
  fs::create_directories(config_.dataDir + "/worlds", ec);
  if (ec) return;
  if (dataLock_ < 0) {
    Status s = lockData();
    if (!s.ok()) {
      if (s.code == Code::IncorrectState) readOnly_ = s.message;  // another daemon took it
      return;
    }
  }
  if (!writeStarts().ok()) return;
  readOnly_.clear();
  log(false, "the data directory " + config_.dataDir +
                 " takes writes again: physd is no longer read-only");
}

void ServerCore::addDamaged(uint32_t id, const std::string& name, const std::string& damage) {
  damaged_[id] = DamagedWorld{id, name, damage};
  reserveWorldId(id);
  queueEvent(id, 0, wire::Severity::Error, "world_damaged",
             "world " + std::to_string(id) + (name.empty() ? "" : " '" + name + "'") +
                 " is not restored: " + damage +
                 "; its files are kept as they are (physd --accept-loss " + std::to_string(id) +
                 " restores what is good)");
}

Status ServerCore::restoreWorlds(std::vector<std::string>* notes) {
  if (!durable()) return Status::Ok();
  // A data disk that cannot be written (full) does not keep physd from serving what it holds:
  // it starts read-only (readOnly_), and goes on writing when a write succeeds again.
  auto goReadOnly = [&](const std::string& why) {
    if (readOnly_.empty()) readOnly_ = why;
    readOnlyRetryAt_ = std::chrono::steady_clock::now() + std::chrono::seconds(1);
  };
  std::error_code ec;
  fs::create_directories(config_.dataDir + "/worlds", ec);
  if (ec && !diskFull(ec))
    return Status::Error(Code::Internal,
                         "cannot create " + config_.dataDir + "/worlds: " + ec.message());
  if (ec) goReadOnly("the data disk is full: cannot create " + config_.dataDir + "/worlds: " + ec.message());
  Status s = lockData();
  if (!s.ok() && !diskFull(s)) return s;
  if (!s.ok()) goReadOnly("the data disk is full: " + s.message);
  {
    // Worlds that moved to other daemons (moves.cpp): still answered Moved after a restart.
    std::ifstream f(config_.dataDir + "/moved_out");
    uint32_t world = 0;
    uint64_t daemon = 0;
    while (f >> world >> daemon) movedOut_[world] = daemon;
  }
  {
    std::ifstream f(config_.dataDir + "/next_world_id");
    uint32_t next = 0;
    if (f >> next && next > 0) reserveWorldId(next - 1);
  }
  {
    // Interests are not kept across a restart, and their ids name topics
    // (phys/state/<world>/<interest>) that readers of the old daemon may still have: each
    // start of this data directory numbers them from its own base, so that a new interest
    // never takes a stale subscriber's topic (the SDK subscribes its interests again).
    uint64_t starts = 0;
    std::ifstream(config_.dataDir + "/starts") >> starts;
    starts_ = starts + 1;
    if (readOnly_.empty()) {
      s = writeStarts();
      if (!s.ok() && !diskFull(s)) return s;
      if (!s.ok()) goReadOnly("the data disk is full: " + s.message);
    }
    // A read-only start could not count itself: the next start will take the same number,
    // so this one numbers its interests from the other half of the range.
    interestBase_ = uint32_t((starts_ + (readOnly_.empty() ? 0 : 16384)) % 32768) << 16;
    // Epochs the same way (wide enough not to wrap): a restored world starts a new one,
    // above any it had before (a subscriber that did not notice the restart goes on).
    epochBase_ = starts_ << 32;
  }
  if (!readOnly_.empty())
    notes->push_back("physd is read-only: " + readOnly_ +
                     "; worlds are restored and served, commands that must be stored are "
                     "refused until the disk has room (retried every second)");
  const bool acceptAll =
      std::find(config_.acceptLoss.begin(), config_.acceptLoss.end(), 0u) != config_.acceptLoss.end();
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
    const std::string dir = worldDir(config_.dataDir, id);
    if (auto taken = takenElsewhere_.find(id); taken != takenElsewhere_.end()) {
      // Its standby took it while this daemon was away (docs/SERVER.md "Standby and
      // takeover"): its files go aside, its commands are answered Moved.
      std::string where;
      const std::string why = "taken over by daemon " + std::to_string(taken->second) +
                              " while this daemon was down";
      Status aside = setAside(dir, why, /*moveWhole=*/true, &where);
      notes->push_back("world " + std::to_string(id) + " left to daemon " +
                       std::to_string(taken->second) + ": " + why +
                       (aside.ok() ? "; its files are kept in " + where
                                   : "; its files could not be set aside: " + aside.message));
      movedOut_[id] = taken->second;
      reserveWorldId(id);
      continue;
    }
    const bool accept =
        acceptAll ||
        std::find(config_.acceptLoss.begin(), config_.acceptLoss.end(), id) != config_.acceptLoss.end();
    auto w = std::make_unique<ServerWorld>();
    w->id = id;
    w->store = std::make_unique<WorldStore>(dir);
    Checkpoint c;
    std::vector<JournalRecord> records;
    LoadReport report;
    s = w->store->load(&c, &records, notes, &report, accept);
    if (!s.ok() && !report.damage.empty()) {
      // Its journal would lose acknowledged records: not restored, nothing touched.
      notes->push_back("world " + std::to_string(id) + " '" + c.meta.name +
                       "' not restored: " + s.message + " (its files are left as they are; "
                       "physd --accept-loss " + std::to_string(id) +
                       " restores what is good and keeps them under " + config_.dataDir +
                       "/damaged/)");
      addDamaged(id, c.meta.name, report.damage);
      continue;
    }
    if (s.ok() && c.meta.worldId != id)
      s = Status::Error(Code::Malformed, dir + "/checkpoint is of world " +
                                             std::to_string(c.meta.worldId));
    if (s.ok() && (findWorld(c.meta.name) || std::any_of(damaged_.begin(), damaged_.end(),
                                                          [&](const auto& d) {
                                                            return d.second.name == c.meta.name;
                                                          })))
      s = Status::Error(Code::InvalidArgument, "name '" + c.meta.name + "' is taken");
    ServerWorld* sw = w.get();
    const auto t0 = std::chrono::steady_clock::now();
    // With a coordinator, not served until it confirms the world is still this daemon's.
    sw->unconfirmed = sw->fenced = coordinated();
    if (s.ok()) {
      worlds_[id] = std::move(w);
      reserveWorldId(id);
      s = restoreInto(*sw, c, records, notes);
      if (!s.ok()) {
        s.message = dir + "/checkpoint: " + s.message;
        sw->store.reset();
        worlds_.erase(id);
      }
    }
    if (!s.ok()) {
      // Its checkpoint cannot be used (none, unreadable, another world's): nothing to
      // restore from. Left in place and listed, or, the loss accepted, moved aside whole.
      if (s.code == Code::NotFound && unfinishedCreate(dir)) {
        fs::remove_all(dir, ec);  // a CreateWorld a crash interrupted: never acknowledged
        notes->push_back("world " + std::to_string(id) +
                         ": an unfinished CreateWorld (no checkpoint) removed");
        continue;
      }
      std::string where;
      Status moved = accept ? setAside(dir, s.message, /*moveWhole=*/true, &where) : s;
      if (accept && moved.ok()) {
        notes->push_back("world " + std::to_string(id) + " dropped: " + s.message +
                         "; the loss is accepted: its files are kept in " + where);
        reserveWorldId(id);
        continue;
      }
      notes->push_back("world " + std::to_string(id) + " not restored: " + s.message +
                       (accept ? "; accepting the loss failed: " + moved.message : "") +
                       " (its files are left in place)");
      addDamaged(id, c.meta.name, s.message);
      continue;
    }
    const double ms =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    notes->push_back("world " + std::to_string(id) + " '" + sw->name + "' restored at tick " +
                     std::to_string(sw->tick) + " (checkpoint tick " +
                     std::to_string(c.meta.tick) + ", " + std::to_string(records.size()) +
                     " journal records replayed, " + std::to_string(int(ms)) + " ms)");
    if (!report.setAside.empty())
      queueEvent(*sw, wire::Severity::Warning, "loss_accepted",
                 report.damage + "; the operator accepted the loss: the world is restored at "
                 "tick " + std::to_string(sw->tick) + " from the records before the damage, "
                 "and the files are kept in " + report.setAside);
    if (!readOnly_.empty()) continue;
    // The replayed state becomes the new checkpoint, so the next start replays nothing twice.
    s = checkpointWorld(*sw);
    if (!s.ok()) notes->push_back("world " + std::to_string(id) + ": checkpoint: " + s.message);
  }
  if (!takenElsewhere_.empty()) keepMovedOut();
  return Status::Ok();
}

}  // namespace phys::server
