// The coordinator thread (phys/server/ownership.h).
#include "phys/server/ownership.h"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <random>

namespace phys::server {

namespace {
std::chrono::milliseconds ms(double s) {
  return std::chrono::milliseconds(int64_t(s * 1000));
}
}  // namespace

Ownership::Ownership(ServerCore* core)
    : core_(core),
      config_(core->config()),
      // A renewal that comes back late still counts from when it was sent (and is useless
      // past the fence window); reads are safe however late. A loaded etcd (its WAL fsync)
      // can take a while: no shorter than a second.
      etcd_(core->config().coordinator,
            std::max(ms(2 * core->config().takeoverAfterS), std::chrono::milliseconds(1000))),
      incarnation_(std::random_device{}() | uint64_t(std::random_device{}()) << 32) {}

Ownership::~Ownership() {
  stop();
}

void Ownership::start() {
  stop_ = false;
  thread_ = std::thread([this] {
    while (!stop_) {
      const auto t = Clock::now();
      round();
      const auto next = t + ms(config_.renewPeriodS);
      while (!stop_ && Clock::now() < next)
        std::this_thread::sleep_for(std::min<Clock::duration>(next - Clock::now(),
                                                              std::chrono::milliseconds(20)));
    }
  });
}

void Ownership::stop() {
  stop_ = true;
  if (thread_.joinable()) thread_.join();
}

std::string Ownership::key(const char* kind, uint64_t id) const {
  return config_.coordinatorPrefix + kind + "/" + std::to_string(id);
}

std::map<uint32_t, WorldRecord> worldRecords(const std::vector<Etcd::Kv>& kvs,
                                             const std::string& prefix,
                                             std::vector<std::string>* bad) {
  std::map<uint32_t, WorldRecord> out;
  const std::string worlds = prefix + "worlds/";
  for (const Etcd::Kv& kv : kvs) {
    if (!kv.key.starts_with(worlds)) continue;
    unsigned long long id = 0;
    try {
      id = std::stoull(kv.key.substr(worlds.size()));
    } catch (...) {
      continue;  // not a world id: not ours to read
    }
    if (id == 0 || id > UINT32_MAX) continue;
    try {
      const nlohmann::json j = nlohmann::json::parse(kv.value);
      out[uint32_t(id)] = {j.value("owner", uint64_t(0)), j.value("standby", uint64_t(0)),
                           j.value("dir", std::string()), kv.modRevision};
    } catch (...) {
      if (bad) bad->push_back(kv.key);
    }
  }
  return out;
}

std::map<uint32_t, uint64_t> worldsHeldElsewhere(const CoreConfig& c, Status* status) {
  std::map<uint32_t, uint64_t> out;
  Etcd etcd(c.coordinator, std::chrono::milliseconds(2000));
  std::vector<Etcd::Kv> kvs;
  *status = etcd.range(c.coordinatorPrefix + "worlds/", true, &kvs);
  if (!status->ok()) return out;
  for (const auto& [id, w] : worldRecords(kvs, c.coordinatorPrefix))
    if (w.owner != 0 && w.owner != c.serverId) out[id] = w.owner;
  return out;
}

void Ownership::trouble(const char* what, const Status& s) {
  // Once a second at most: a coordinator that is away fails every round.
  const auto now = Clock::now();
  ++troubles_;
  if (now - troubleLogged_ < std::chrono::seconds(1)) return;
  core_->log(true, std::string("coordinator: ") + what + " failed (" +
                        std::to_string(troubles_) + " requests since the last report): " +
                        s.message);
  troubleLogged_ = now;
  troubles_ = 0;
}

void Ownership::round() {
  renew();
  look();
}

void Ownership::renew() {
  const std::string k = key("daemons", config_.serverId);
  if (heartbeat_ < 0) {
    std::vector<Etcd::Kv> kvs;
    if (!etcd_.range(k, false, &kvs).ok()) return;
    heartbeat_ = kvs.empty() ? 0 : kvs[0].modRevision;
  }
  const auto sent = Clock::now();
  const std::string value = nlohmann::json{{"id", config_.serverId},
                                           {"data", config_.dataDir},
                                           {"incarnation", incarnation_}}
                                .dump();
  // The renewal holds only if every world this daemon serves is still its own (its key's
  // revision is the one it registered): a daemon that was paused past its hold renews nothing
  // until it has let go of what its standby took (look()).
  std::vector<Etcd::Compare> compares{{k, heartbeat_}};
  for (const ServerCore::OwnedWorld& o : core_->ownedWorlds())
    if (o.ownership != 0 && !o.unconfirmed)
      compares.push_back({key("worlds", o.id), int64_t(o.ownership)});
  bool ok = false;
  int64_t revision = 0;
  Status s = etcd_.txn(compares, {{k, value}}, {}, &ok, &revision);
  if (!s.ok()) {
    heartbeat_ = -1;  // it may have landed after all: read again (the hold lapses meanwhile)
    trouble("renewal", s);
    return;
  }
  if (!ok) {
    // A world's key changed (look() finds which), or the heartbeat did: a renewal of ours
    // whose answer was lost (the same incarnation), or another physd with the same server.id.
    std::vector<Etcd::Kv> kvs;
    if (!etcd_.range(k, false, &kvs).ok()) return;
    if (!kvs.empty() && kvs[0].modRevision == heartbeat_) return;  // a world's key
    if (!kvs.empty()) {
      try {
        if (nlohmann::json::parse(kvs[0].value).value("incarnation", uint64_t(0)) ==
            incarnation_) {
          heartbeat_ = kvs[0].modRevision;
          return;
        }
      } catch (...) {
      }
    }
    if (!heartbeatClash_)
      core_->log(true, "coordinator: another daemon renews server.id " +
                            std::to_string(config_.serverId) +
                            "'s hold in etcd; give each daemon its own server.id");
    heartbeatClash_ = true;
    heartbeat_ = -1;
    return;
  }
  heartbeatClash_ = false;
  heartbeat_ = revision;
  core_->holdUntil(sent + ms(config_.fenceAfterS));
}

void Ownership::look() {
  const std::string& prefix = config_.coordinatorPrefix;
  std::vector<Etcd::Kv> kvs;
  if (Status s = etcd_.range(prefix, true, &kvs); !s.ok()) {
    heartbeats_.clear();  // a standby counts only unbroken successful reads
    trouble("read", s);
    return;
  }
  const auto now = Clock::now();
  const uint64_t me = config_.serverId;
  std::map<uint64_t, int64_t> beats;  // daemon -> its heartbeat's mod revision
  const std::string daemons = prefix + "daemons/";
  for (const Etcd::Kv& kv : kvs) {
    if (!kv.key.starts_with(daemons)) continue;
    try {
      beats[std::stoull(kv.key.substr(daemons.size()))] = kv.modRevision;
    } catch (...) {
    }
  }
  std::vector<std::string> bad;
  const std::map<uint32_t, WorldRecord> keys = worldRecords(kvs, prefix, &bad);
  for (const std::string& k : bad)
    core_->log(true, "coordinator: " + k + " is not a world's record; left alone");
  // Takeovers the tick thread could not carry out: the key goes back to the owner as it was
  // (this daemon its standby), so that the owner, restarted, restores the world instead of
  // setting it aside as taken, and this daemon tries again after a wait.
  if (std::vector<ServerCore::FailedTakeover> failed = core_->takeFailedTakeovers();
      !failed.empty()) {
    for (const ServerCore::FailedTakeover& f : failed) {
      takingOver_.erase(f.world);
      Retry& r = retries_[f.world];
      r.wait = std::clamp(2 * r.wait, std::chrono::milliseconds(1000),
                          std::chrono::milliseconds(30000));
      r.at = now + r.wait;
      const std::string wk = key("worlds", f.world);
      const std::string back =
          nlohmann::json{{"owner", f.owner}, {"standby", config_.serverId}, {"dir", f.dir}}.dump();
      bool ok = false;
      etcd_.txn({{wk, int64_t(f.revision)}}, {{wk, back}}, {}, &ok, nullptr);
      core_->log(!ok, "coordinator: world " + std::to_string(f.world) +
                          (ok ? " given back to daemon " : " could not be given back to daemon ") +
                          std::to_string(f.owner) + "; taking it over again in " +
                          std::to_string(r.wait.count()) + " ms");
    }
    return;  // the keys read are stale now: the next round reads them again
  }
  std::erase_if(retries_, [&](const auto& r) { return !keys.count(r.first); });
  // Every owner's heartbeat as read now (0: it has none), and since when it is the same.
  for (const auto& [id, k] : keys) beats.try_emplace(k.owner, 0);
  for (const auto& [d, revision] : beats) {
    auto [it, added] = heartbeats_.try_emplace(d, Seen{revision, now});
    if (!added && it->second.revision != revision) it->second = {revision, now};
  }

  // The worlds this daemon stands by for: the tick thread replays their owners' files.
  std::map<uint32_t, ServerCore::Followed> followed;
  for (const auto& [id, k] : keys)
    if (k.standby == me && k.owner != me && !k.dir.empty()) followed[id] = {k.dir, k.owner};
  core_->standBy(std::move(followed));

  bool fresh = false;
  const std::vector<ServerCore::OwnedWorld> owned = core_->ownedWorlds(&fresh);
  if (!fresh) return;  // the tick thread has not listed its worlds yet
  auto value = [&](const std::string& dir) {
    return nlohmann::json{{"owner", me}, {"standby", config_.standby}, {"dir", dir}}.dump();
  };
  auto submit = [&](ServerCore::OwnershipNote::Kind kind, uint32_t world, int64_t revision,
                    uint64_t daemon, std::string dir = {}) {
    ServerCore::OwnershipNote n;
    n.kind = kind;
    n.world = world;
    n.revision = uint64_t(revision);
    n.daemon = daemon;
    n.dir = std::move(dir);
    core_->submitOwnership(std::move(n));
  };
  std::set<uint32_t> mine;
  for (const ServerCore::OwnedWorld& o : owned) {
    mine.insert(o.id);
    takingOver_.erase(o.id);
    retries_.erase(o.id);
    auto it = keys.find(o.id);
    const bool ours = it != keys.end() && it->second.owner == me;
    // A world that came here by MoveWorld (never registered here, not restored): its key
    // may still name the daemon it left, which drops it soon; it is this daemon's now.
    const bool movedIn = o.ownership == 0 && !o.unconfirmed;
    if (it != keys.end() && !ours && !movedIn) {
      // Another daemon holds it now: this one stands down (once).
      if (noted_.count(o.id) && noted_[o.id] == it->second.revision) continue;
      noted_[o.id] = it->second.revision;
      submit(ServerCore::OwnershipNote::Kind::StandDown, o.id, it->second.revision,
             it->second.owner);
      continue;
    }
    // Registered, still ours. (A key of ours at another revision than the one registered:
    // a standby that failed to take the world over gave it back while this daemon was
    // paused; registered again, so that its renewals hold.)
    if (o.ownership != 0 && !o.unconfirmed && ours && int64_t(o.ownership) == it->second.revision)
      continue;
    if (noted_.count(o.id) && it != keys.end() && noted_[o.id] == it->second.revision) continue;
    // Not registered (new), restored and not yet confirmed, or a key gone: (re)registered.
    // A new revision, so its epoch is above any this world had before.
    const int64_t expected = it == keys.end() ? 0 : it->second.revision;
    bool ok = false;
    int64_t revision = 0;
    const std::string k = key("worlds", o.id);
    if (!etcd_.txn({{k, expected}}, {{k, value(o.dir)}}, {}, &ok, &revision).ok() || !ok)
      continue;  // looked at again next round
    noted_[o.id] = revision;
    submit(ServerCore::OwnershipNote::Kind::Registered, o.id, revision, me);
  }
  std::erase_if(noted_, [&](const auto& n) { return !mine.count(n.first); });
  // Where the worlds this daemon does not hold are: a world that left it (moved, taken
  // over) is answered Moved with its owner of now.
  for (const auto& [id, k] : keys) {
    if (k.owner == me || k.owner == 0 || mine.count(id)) continue;
    auto [it, added] = told_.try_emplace(id, k.owner);
    if (!added && it->second == k.owner) continue;
    it->second = k.owner;
    submit(ServerCore::OwnershipNote::Kind::Elsewhere, id, k.revision, k.owner);
  }

  for (const auto& [id, k] : keys) {
    if (k.owner == me) {
      // Ours and no world here (destroyed, moved to a daemon that registers it itself):
      // the key goes, so no standby takes over a world that does not exist.
      if (!mine.count(id) && !takingOver_.count(id)) {
        bool ok = false;
        etcd_.txn({{key("worlds", id), k.revision}}, {}, {key("worlds", id)}, &ok, nullptr);
      }
      continue;
    }
    // A world this daemon stands by for, whose owner has not renewed for takeoverAfterS.
    if (k.standby != me || mine.count(id) || takingOver_.count(id)) continue;
    const Seen& seen = heartbeats_[k.owner];
    if (now - seen.since < ms(config_.takeoverAfterS)) {
      retries_.erase(id);  // its owner renews (again): a later failure waits from 1 s
      continue;
    }
    if (auto r = retries_.find(id); r != retries_.end() && now < r->second.at) continue;
    const std::string wk = key("worlds", id);
    // (dataDir is absolute with a coordinator: ServerCore's constructor.)
    const std::string dir = config_.dataDir + "/worlds/" + std::to_string(id);
    bool ok = false;
    int64_t revision = 0;
    // Only if neither the owner renewed nor the world's key changed since they were read.
    if (!etcd_.txn({{key("daemons", k.owner), seen.revision}, {wk, k.revision}},
                   {{wk, value(dir)}}, {}, &ok, &revision)
             .ok() ||
        !ok)
      continue;
    const auto silent = std::chrono::duration_cast<std::chrono::milliseconds>(now - seen.since);
    core_->log(false, "coordinator: daemon " + std::to_string(k.owner) +
                           " has not renewed its hold for " + std::to_string(silent.count()) +
                           " ms: taking over world " + std::to_string(id) + " (ownership " +
                           std::to_string(revision) + ")");
    takingOver_.insert(id);
    submit(ServerCore::OwnershipNote::Kind::TakeOver, id, revision, k.owner, k.dir);
  }
}

}  // namespace phys::server
