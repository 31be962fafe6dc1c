// Standby and takeover, the tick thread's side (docs/SERVER.md "Standby and takeover"): what
// the coordinator thread (ownership.cpp) found in etcd becomes OwnershipNotes, applied here at
// a tick boundary. A registered world gets its ownership epoch; a world another daemon took is
// let go (its commands answered Moved); a world this daemon takes over is rebuilt from its
// owner's files (checkpoint and journal, read from storage both daemons can read) exactly as a
// restart would rebuild it, so every acknowledged command is in it and its state at any tick
// is what the owner's would have been. A registered world is served only while this daemon's
// hold is renewed (fenced otherwise: not stepped, no frames, commands wait, acknowledgements
// parked).
#include <sys/stat.h>

#include <cerrno>
#include <cstring>
#include <filesystem>

#include "phys/server/core.h"

namespace phys::server {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

void ServerCore::submitOwnership(OwnershipNote n) {
  {
    std::lock_guard<std::mutex> lock(inboxMutex_);
    ownershipNotes_.push_back(std::move(n));
  }
  inboxCv_.notify_one();
}

void ServerCore::holdUntil(Clock::time_point until) {
  holdUntilNs_.store(until.time_since_epoch().count());
}

bool ServerCore::holding() const {
  const int64_t until = holdUntilNs_.load();
  return until != 0 && Clock::now().time_since_epoch().count() < until;
}

std::vector<ServerCore::FailedTakeover> ServerCore::takeFailedTakeovers() {
  std::lock_guard<std::mutex> lock(ownedMutex_);
  return std::exchange(failedTakeovers_, {});
}

std::vector<ServerCore::OwnedWorld> ServerCore::ownedWorlds(bool* fresh) const {
  std::lock_guard<std::mutex> lock(ownedMutex_);
  if (fresh) *fresh = ownedFresh_;
  return owned_;
}

void ServerCore::refreshOwned() {
  std::vector<OwnedWorld> now;
  for (const auto& [id, w] : worlds_) {
    if (!w->store) continue;  // ephemeral or not kept: nothing a standby could read
    now.push_back({id, w->store->dir(), w->ownership, w->unconfirmed});
  }
  std::lock_guard<std::mutex> lock(ownedMutex_);
  owned_ = std::move(now);
  ownedFresh_ = true;
}

void ServerCore::updateFences() {
  const bool held = holding();
  for (auto& [id, w] : worlds_) {
    const bool fence = w->unconfirmed || (w->ownership != 0 && !held);
    if (fence && !w->fenced) w->accumulator = 0;
    w->fenced = fence;
  }
  if (!held || parked_.empty()) return;
  // The hold is back: what was acknowledged meanwhile goes out.
  std::vector<HeldReply> parked = std::move(parked_);
  parked_.clear();
  for (HeldReply& r : parked) pushReplyNow(r.key, r.seq, std::move(r.reply));
}

void ServerCore::applyOwnership(OwnershipNote& n) {
  switch (n.kind) {
    case OwnershipNote::Kind::Registered: {
      ServerWorld* w = world(n.world);
      if (!w) return;  // destroyed or moved meanwhile: the coordinator drops its key
      const bool first = w->ownership == 0;
      w->ownership = n.revision;
      w->unconfirmed = false;
      // Epochs in this world's frames are above every epoch an earlier owner used (theirs
      // are below their own, lower, revision << 32): a subscriber drops a deposed owner's
      // late frames (docs/PROTOCOL.md "Order of frames").
      if (first) {
        w->epoch = std::max(w->epoch, n.revision << 32);
        w->framesReplaced();
        w->infoDirty = true;
      }
      log(false, "world " + std::to_string(n.world) + " '" + w->name +
                     "': registered with the coordinator (ownership " +
                     std::to_string(n.revision) + ", standby " + std::to_string(config_.standby) +
                     ")");
      return;
    }
    case OwnershipNote::Kind::StandDown:
      return standDown(n.world, n.daemon);
    case OwnershipNote::Kind::TakeOver:
      return takeOver(n);
    case OwnershipNote::Kind::Elsewhere: {
      auto it = movedOut_.find(n.world);
      if (world(n.world) || it == movedOut_.end() || it->second == n.daemon) return;
      it->second = n.daemon;  // one hop to the owner for the commands of old clients
      keepMovedOut();
      return;
    }
  }
}

void ServerCore::standDown(uint32_t id, uint64_t daemon) {
  ServerWorld* w = world(id);
  if (!w) return;
  std::erase_if(parked_, [&](const HeldReply& r) { return r.durableWorld == id; });
  cancelJob(*w, "the world was taken over by daemon " + std::to_string(daemon));
  std::deque<Incoming> waiting = std::move(w->waiting);
  // Its files stay for the operator (the new owner copied them when it took over).
  if (w->store) {
    std::string where;
    Status s = setAside(w->store->dir(),
                        "taken over by daemon " + std::to_string(daemon) + " while this daemon's "
                        "hold had lapsed", /*moveWhole=*/true, &where);
    if (!s.ok()) log(true, "world " + std::to_string(id) + " taken over; its files: " + s.message);
    w->store.reset();
  }
  log(true, "world " + std::to_string(id) + " '" + w->name + "': taken over by daemon " +
                std::to_string(daemon) + "; this daemon stands down (at tick " +
                std::to_string(w->tick) + ")");
  letGo(id, daemon);
  for (Incoming& in : waiting) applyNow(in);  // answered Moved
}

void ServerCore::standBy(std::map<uint32_t, Followed> worlds) {
  std::lock_guard<std::mutex> lock(ownedMutex_);
  standbyFor_ = std::move(worlds);
}

void ServerCore::followOwners() {
  const auto now = Clock::now();
  if (now - followedAt_ < std::chrono::duration<double>(config_.renewPeriodS)) return;
  followedAt_ = now;
  std::map<uint32_t, Followed> want;
  {
    std::lock_guard<std::mutex> lock(ownedMutex_);
    want = standbyFor_;
  }
  std::erase_if(shadows_, [&](const auto& s) { return !want.count(s.first); });
  for (const auto& [id, f] : want) {
    if (world(id)) continue;  // this daemon's already
    Shadow& sh = shadows_[id];
    if (sh.dir != f.dir) sh = Shadow{};
    sh.dir = f.dir;
    sh.owner = f.owner;
    std::vector<std::string> notes;
    Status s = follow(id, sh, &notes);
    for (const std::string& note : notes) log(true, "standby: " + note);
    (void)s;  // read again next time (a checkpoint being replaced, files not there yet)
  }
}

Status ServerCore::follow(uint32_t id, Shadow& sh, std::vector<std::string>* notes) {
  struct stat st {};
  const std::string checkpoint = sh.dir + "/checkpoint";
  if (::stat(checkpoint.c_str(), &st) != 0)
    return Status::Error(Code::NotFound, checkpoint + ": " + std::strerror(errno));
  const int64_t mtime = int64_t(st.st_mtim.tv_sec) * 1000000000 + st.st_mtim.tv_nsec;
  auto journalPath = [&] { return sh.dir + "/journal-" + std::to_string(sh.meta.generation); };
  // The journal replayed from, once per look (again only after a rebuild names another).
  // The owner cut it back (a sync failed: those records were refused, not acknowledged):
  // what was replayed from them goes, the copy is built again.
  struct stat js {};
  bool statted = sh.world && ::stat(journalPath().c_str(), &js) == 0;
  const bool shrunk = statted && uint64_t(js.st_size) < sh.journalBytes;
  if (!sh.world || uint64_t(st.st_ino) != sh.inode || mtime != sh.mtimeNs || shrunk) {
    // Built from the owner's checkpoint: the first time, and after each new one.
    Checkpoint c;
    uint32_t crc = 0;
    Status s = readCheckpoint(sh.dir, &c, &crc);
    if (!s.ok()) return s;
    if (c.meta.worldId != id)
      return Status::Error(Code::Malformed, checkpoint + " is of world " +
                                                std::to_string(c.meta.worldId));
    auto w = std::make_unique<ServerWorld>();
    w->id = id;
    s = beginReplay(*w, c);
    if (!s.ok()) return s;
    sh.world = std::move(w);
    sh.meta = c.meta;
    sh.crc = crc;
    sh.inode = uint64_t(st.st_ino);
    sh.mtimeNs = mtime;
    sh.replay = Replay{};
    sh.journalBytes = 0;
    statted = false;
  }
  const std::string journal = journalPath();
  if (!statted && ::stat(journal.c_str(), &js) != 0)
    return Status::Error(Code::NotFound, journal + ": " + std::strerror(errno));
  if (uint64_t(js.st_size) == sh.journalBytes) return Status::Ok();  // nothing new
  JournalScan scan = scanJournal(journal, sh.meta, sh.crc);
  if (scan.lossy()) return Status::Error(Code::IncorrectState, scan.detail);
  sh.journalBytes = scan.fileBytes;
  if (scan.records.size() <= sh.replay.applied || sh.replay.stopped) return Status::Ok();
  if (world(id)) return Status::Error(Code::IncorrectState, "a world " + std::to_string(id) + " is here");
  // Replayed in place (commands find their world in worlds_), then set aside again.
  worlds_[id] = std::move(sh.world);
  replayRecords(*worlds_[id], scan.records, &sh.replay, notes);
  sh.world = std::move(worlds_[id]);
  worlds_.erase(id);
  return Status::Ok();
}

void ServerCore::takeOver(OwnershipNote& n) {
  const uint32_t id = n.world;
  auto fail = [&](const std::string& why) {
    log(true, "world " + std::to_string(id) + ": taking over from daemon " +
                  std::to_string(n.daemon) + " failed: " + why +
                  " (its key goes back to daemon " + std::to_string(n.daemon) +
                  "; tried again later)");
    std::lock_guard<std::mutex> lock(ownedMutex_);
    failedTakeovers_.push_back({id, n.revision, n.daemon, n.dir});
  };
  if (world(id)) return fail("this daemon holds a world " + std::to_string(id) + " already");
  if (!durable()) return fail("this daemon keeps no worlds ([paths] data)");
  const auto t0 = Clock::now();
  // The copy kept up to date (a hot standby), brought to the end of the owner's journal now;
  // or, without one, built from the owner's files now (a cold standby).
  Shadow& sh = shadows_[id];
  if (sh.dir != n.dir) sh = Shadow{};
  sh.dir = n.dir;
  sh.owner = n.daemon;
  const size_t before = sh.world ? sh.replay.applied : 0;
  std::vector<std::string> notes;
  Status s = follow(id, sh, &notes);
  if (s.ok() && !sh.world) s = Status::Error(Code::NotFound, n.dir + ": nothing to take over");
  if (s.ok() && findWorld(sh.world->name))
    s = Status::Error(Code::InvalidArgument,
                      "this daemon holds a world named '" + sh.world->name + "'");
  for (const std::string& note : notes) log(true, note);
  if (!s.ok()) {
    shadows_.erase(id);
    return fail(s.message);
  }
  std::unique_ptr<ServerWorld> w = std::move(sh.world);
  Replay replay = sh.replay;
  shadows_.erase(id);
  ServerWorld* sw = w.get();
  worlds_[id] = std::move(w);
  // Its info and frames go out from here (the endpoint forgets that this daemon once let the
  // world go, when it stood down for it or moved it away).
  announceHere(id);
  notes.clear();
  endReplay(*sw, replay, &notes);  // the steps of the owner's last lease
  for (const std::string& note : notes) log(true, note);
  // Its own files from now on: a checkpoint of the state reached (fresh directory).
  std::error_code ec;
  fs::remove_all(fs::path(config_.dataDir) / "worlds" / std::to_string(id), ec);
  s = createStore(*sw);
  if (!s.ok()) log(true, "world " + std::to_string(id) + " taken over is not kept on disk: " + s.message);
  movedOut_.erase(id);
  keepMovedOut();
  sw->ownership = n.revision;
  sw->epoch = std::max(sw->epoch, n.revision << 32);
  sw->framesReplaced();
  sw->infoDirty = sw->frameDirty = true;
  statusWanted_ = true;
  const double ms = std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
  log(false, "world " + std::to_string(id) + " '" + sw->name + "': taken over from daemon " +
                 std::to_string(n.daemon) + " at tick " + std::to_string(sw->tick) + " (" +
                 std::to_string(replay.applied - before) + " journal records replayed now, " +
                 std::to_string(before) + " before; " + std::to_string(int(ms)) + " ms)");
  queueEvent(*sw, wire::Severity::Warning, "taken_over",
             "daemon " + std::to_string(n.daemon) + " stopped renewing its hold; daemon " +
                 std::to_string(config_.serverId) + " took the world over from its files at tick " +
                 std::to_string(sw->tick));
}

}  // namespace phys::server
