// Standby and takeover, the tick thread's side (docs/SERVER.md "Standby and takeover"): what
// the coordinator thread (ownership.cpp) found in etcd becomes OwnershipNotes, applied here at
// a tick boundary. A registered world gets its ownership epoch; a world another daemon took is
// let go (its commands answered Moved); a world this daemon takes over is rebuilt from its
// owner's files (checkpoint and journal, read from storage both daemons can read) exactly as a
// restart would rebuild it, so every acknowledged command is in it and its state at any tick
// is what the owner's would have been. A registered world is served only while this daemon's
// hold is renewed (fenced otherwise: not stepped, no frames, commands wait, acknowledgements
// parked).
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

std::vector<ServerCore::OwnedWorld> ServerCore::ownedWorlds(bool* fresh) const {
  std::lock_guard<std::mutex> lock(ownedMutex_);
  if (fresh) *fresh = ownedFresh_;
  return owned_;
}

void ServerCore::refreshOwned() {
  std::vector<OwnedWorld> now;
  for (const auto& [id, w] : worlds_) {
    if (!w->store) continue;  // ephemeral or not kept: nothing a standby could read
    std::error_code ec;
    const fs::path dir = fs::absolute(w->store->dir(), ec);
    now.push_back({id, ec ? w->store->dir() : dir.string(), w->ownership, w->unconfirmed});
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
  movedAway_.push_back(id);
  worlds_.erase(id);
  movedOut_[id] = daemon;
  keepMovedOut();
  for (Incoming& in : waiting) applyNow(in);  // answered Moved
}

void ServerCore::takeOver(OwnershipNote& n) {
  const uint32_t id = n.world;
  auto fail = [&](const std::string& why) {
    log(true, "world " + std::to_string(id) + ": taking over from daemon " +
                  std::to_string(n.daemon) + " failed: " + why);
  };
  if (world(id)) return fail("this daemon holds a world " + std::to_string(id) + " already");
  if (!durable()) return fail("this daemon keeps no worlds ([paths] data)");
  const auto t0 = Clock::now();
  // The owner's files, copied into this daemon's data: its checkpoint and journals, as they
  // are now (a torn last record, never acknowledged, is cut from the copy by load()).
  const fs::path src(n.dir), dst = fs::path(config_.dataDir) / "worlds" / std::to_string(id);
  std::error_code ec;
  fs::remove_all(dst, ec);
  fs::create_directories(dst, ec);
  if (ec) return fail("cannot create " + dst.string() + ": " + ec.message());
  for (const auto& e : fs::directory_iterator(src, ec)) {
    const std::string name = e.path().filename().string();
    if (name != "checkpoint" && !name.starts_with("journal-")) continue;
    fs::copy_file(e.path(), dst / name, fs::copy_options::overwrite_existing, ec);
    if (ec) return fail("cannot copy " + e.path().string() + ": " + ec.message());
  }
  if (ec) return fail("cannot read " + src.string() + ": " + ec.message());
  auto w = std::make_unique<ServerWorld>();
  w->id = id;
  w->store = std::make_unique<WorldStore>(dst.string());
  Checkpoint c;
  std::vector<JournalRecord> records;
  std::vector<std::string> notes;
  LoadReport report;
  Status s = w->store->load(&c, &records, &notes, &report);
  if (s.ok() && c.meta.worldId != id)
    s = Status::Error(Code::Malformed, "its checkpoint is of world " + std::to_string(c.meta.worldId));
  if (s.ok() && findWorld(c.meta.name))
    s = Status::Error(Code::InvalidArgument, "this daemon holds a world named '" + c.meta.name + "'");
  if (!s.ok()) {
    fs::remove_all(dst, ec);
    return fail(s.message);
  }
  ServerWorld* sw = w.get();
  worlds_[id] = std::move(w);
  s = restoreInto(*sw, c, records, &notes);
  if (s.ok()) s = checkpointWorld(*sw);  // its own files from now on
  for (const std::string& note : notes) log(false, note);
  if (!s.ok()) {
    worlds_.erase(id);
    fs::remove_all(dst, ec);
    return fail(s.message);
  }
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
                std::to_string(records.size()) + " journal records replayed, " +
                std::to_string(int(ms)) + " ms)");
  queueEvent(*sw, wire::Severity::Warning, "taken_over",
             "daemon " + std::to_string(n.daemon) + " stopped renewing its hold; daemon " +
                 std::to_string(config_.serverId) + " took the world over from its files at tick " +
                 std::to_string(sw->tick));
}

}  // namespace phys::server
