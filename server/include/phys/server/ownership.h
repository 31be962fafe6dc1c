// The coordinator thread of a daemon with `[cluster] coordinator` (docs/SERVER.md "Standby
// and takeover"): keeps this daemon's hold in etcd, registers its kept worlds, tells the tick
// thread (ServerCore::submitOwnership) what changed, and takes over the worlds it stands by
// for when their owner stops renewing.
//
// Keys, under CoreConfig::coordinatorPrefix:
//   daemons/<id>  {"id":..,"data":..}: rewritten every renewPeriodS by compare-and-swap on its
//                 own mod revision (the heartbeat; its revision changing is the owner alive)
//   worlds/<id>   {"owner":..,"standby":..,"dir":..}: the world's owner, its standby and its
//                 directory; its mod revision is the ownership epoch
//
// The owner serves a registered world only within fenceAfterS of *sending* its last renewal
// that succeeded; a standby takes the world (a transaction that holds only if neither the
// owner's heartbeat nor the world's key changed) after it has read the same heartbeat revision
// for takeoverAfterS of successful reads. The renewal was committed after it was sent and read
// after it was committed, so the owner has stopped serving before the standby starts, whatever
// the delays between them (only the clocks' rates are assumed alike).
#pragma once

#include <atomic>
#include <chrono>
#include <map>
#include <set>
#include <string>
#include <thread>

#include "phys/server/core.h"
#include "phys/server/etcd.h"

namespace phys::server {

/// A world's record in etcd (<prefix>worlds/<id>): its owner, its standby and its directory;
/// the key's mod revision is the world's ownership epoch.
struct WorldRecord {
  uint64_t owner = 0, standby = 0;
  std::string dir;
  int64_t revision = 0;
};
/// The world records among `kvs` (keys under <prefix>worlds/); keys whose value is not a
/// record go to *bad.
std::map<uint32_t, WorldRecord> worldRecords(const std::vector<Etcd::Kv>& kvs,
                                             const std::string& prefix,
                                             std::vector<std::string>* bad = nullptr);
/// Start-up, before restoreWorlds (ServerCore::takenElsewhere): the worlds other daemons
/// hold, read from etcd once. Empty, with *status saying why, when etcd cannot be read.
std::map<uint32_t, uint64_t> worldsHeldElsewhere(const CoreConfig& c, Status* status);

class Ownership {
 public:
  explicit Ownership(ServerCore* core);
  ~Ownership();
  void start();
  void stop();

  /// One round (the thread calls it every renewPeriodS; tests may call it directly).
  void round();

 private:
  using Clock = std::chrono::steady_clock;
  void renew();
  void look();
  std::string key(const char* kind, uint64_t id) const;
  /// A request to etcd failed: logged, once a second at most.
  void trouble(const char* what, const Status& s);
  Clock::time_point troubleLogged_{};
  uint64_t troubles_ = 0;

  ServerCore* core_;
  const CoreConfig& config_;
  Etcd etcd_;
  std::thread thread_;
  std::atomic<bool> stop_{true};

  /// This process's mark in its heartbeat: a renewal whose answer was lost is told apart
  /// from another daemon with the same server.id.
  uint64_t incarnation_ = 0;
  int64_t heartbeat_ = -1;  ///< our heartbeat key's mod revision (-1: not read yet)
  bool heartbeatClash_ = false;
  /// Another daemon's heartbeat as this one has read it: its mod revision, and since when
  /// (this daemon's clock) it has read that same revision in unbroken successful reads.
  struct Seen {
    int64_t revision = 0;
    Clock::time_point since;
  };
  std::map<uint64_t, Seen> heartbeats_;
  /// Worlds being taken over (submitted, not yet in ownedWorlds()); their keys are ours.
  std::set<uint32_t> takingOver_;
  /// Worlds whose takeover failed (ServerCore::FailedTakeover): not tried again before `at`;
  /// the wait doubles from 1 s to 30 s while it keeps failing.
  struct Retry {
    Clock::time_point at;
    std::chrono::milliseconds wait{0};
  };
  std::map<uint32_t, Retry> retries_;
  /// Worlds whose StandDown or Registered note is on its way: not sent twice.
  std::map<uint32_t, int64_t> noted_;
  /// The owner last told to the tick thread of each world held elsewhere (Elsewhere notes).
  std::map<uint32_t, uint64_t> told_;
};

}  // namespace phys::server
