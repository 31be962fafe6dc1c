// The client SDK over Cyclone DDS: one participant per Client, a command writer, readers on
// phys/reply and phys/status, one reader per state subscription, and one SDK thread that
// takes samples, completes futures, reassembles state frames, expires deadlines and notices
// when the daemon goes away or a new one appears.
#include "phys/client/client.h"

#include "phys/protocol/client_key.h"
#include "phys/protocol/cluster.h"
#include "phys/protocol/compact.h"

#include <algorithm>
#include <atomic>
#include <condition_variable>
#include <deque>
#include <map>
#include <mutex>
#include <random>
#include <set>
#include <thread>
#include <tuple>
#include <unordered_set>

#include "dds.h"
#include "phys/protocol/convert.h"
#include "phys/protocol/dds_envelope.h"
#include "phys/protocol/decoder.h"

namespace phys::client {

using Clock = std::chrono::steady_clock;
using protocol::CommandBuilder;

const char* toString(ErrorCode c) {
  switch (c) {
    case ErrorCode::Ok:
      return "Ok";
    case ErrorCode::Malformed:
      return "Malformed";
    case ErrorCode::InvalidArgument:
      return "InvalidArgument";
    case ErrorCode::NotFound:
      return "NotFound";
    case ErrorCode::IncorrectState:
      return "IncorrectState";
    case ErrorCode::Unsupported:
      return "Unsupported";
    case ErrorCode::ResourceExhausted:
      return "ResourceExhausted";
    case ErrorCode::Internal:
      return "Internal";
    case ErrorCode::PermissionDenied:
      return "PermissionDenied";
    case ErrorCode::Moved:
      return "Moved";
    case ErrorCode::Timeout:
      return "Timeout";
    case ErrorCode::Disconnected:
      return "Disconnected";
    case ErrorCode::Transport:
      return "Transport";
    case ErrorCode::BadReply:
      return "BadReply";
  }
  return "Unknown";
}

namespace {

BodyState toState(const wire::BodyState& s) {
  // The rotation as physd sent it (a unit quaternion of the World): normalizing it again,
  // as commands' quaternions are, cost a square root and a division per body and tick.
  const wire::Quat& q = s.rotation();
  return {s.id(), protocol::toPhys(s.position()), phys::Quat{q.x(), q.y(), q.z(), q.w()},
          protocol::toPhys(s.linear_velocity()), protocol::toPhys(s.angular_velocity())};
}

std::string str(const flatbuffers::String* s) {
  return s ? s->str() : std::string();
}

WorldSummary toSummary(const wire::WorldSummary& w) {
  return protocol::toWorldSummary(w);
}

Ack ack(const wire::Reply& r) {
  return {r.world(), r.tick()};
}

Ids ids(const wire::Reply& r) {
  Ids out;
  if (auto* i = r.result_as_Ids()) {
    if (i->bodies()) out.bodies.assign(i->bodies()->begin(), i->bodies()->end());
    if (i->joints()) out.joints.assign(i->joints()->begin(), i->joints()->end());
  }
  return out;
}

}  // namespace

// ---------------------------------------------------------------------------------------------

struct Subscription::State {
  uint32_t world = 0;
  /// 0: the world's own stream. An interest's id changes when the SDK subscribes it again on
  /// a new daemon (after a restart): written by the SDK thread under Impl::subsMutex.
  uint32_t interest = 0;
  Interest spec;  ///< what the interest asked for (subscribed again after a restart)
  /// In a domain of daemons, the daemon that holds the interest (the world's owner when it
  /// was subscribed): when the world's owner changes (a takeover, a move), the SDK
  /// subscribes it again there (Impl::followInterests). SDK thread once subscribed.
  uint64_t daemon = 0;
  dds::Topic topic;
  dds::Reader reader;
  std::function<void(const StateFrame&)> fn;
  /// Held while the callback runs; reset() takes it to stop the callbacks, so that none runs
  /// once the Subscription is gone (what it touches may go with it). Recursive: a callback
  /// may reset its own subscription.
  std::recursive_mutex fnMutex;
  bool fnStopped = false;  ///< under fnMutex

  mutable std::mutex m;
  std::condition_variable cv;
  /// The last frame delivered (under m): its header in `delivered`, its bodies wherever
  /// deliveredBodies points: the full state while it is that tick's (no copy per tick: a
  /// tick of a 10,000-body world is 0.6 MB, and most subscribers use the callback), the
  /// callback's frame while the callback runs, or delivered.bodies, a copy made only when
  /// the full state moves on without delivering (a lost frame). latest() and waitForFrame()
  /// copy it out.
  StateFrame delivered;
  const std::vector<BodyState>* deliveredBodies = nullptr;  ///< null: nothing delivered
  StateFrame copyDelivered() const {
    StateFrame f = delivered;
    if (deliveredBodies != &delivered.bodies) f.bodies = *deliveredBodies;
    return f;
  }
  /// Before the full state changes into something that may not be delivered.
  void keepDelivered() {
    if (deliveredBodies != &full) return;
    delivered.bodies = full;
    deliveredBodies = &delivered.bodies;
  }
  uint64_t frames = 0;
  /// The epoch of the last frame latest() or waitForFrame() returned (under m; handedOut:
  /// whether one did): what a caller's afterTick refers to, unless it says (waitForFrame).
  mutable uint64_t handedEpoch = 0;
  mutable bool handedOut = false;
  StateFrame handOut() const {
    handedOut = true;
    handedEpoch = delivered.epoch;
    return copyDelivered();
  }

  std::mutex ownerMutex;
  Client::Impl* owner = nullptr;
  /// Under m: the last delivered frame's callback has returned (or there is none), so a
  /// waitForFrame that returns it finds what the callback recorded; the thread delivering
  /// (the SDK's), which may wait inside its own callback.
  bool settled = true;
  std::thread::id delivering;

  uint64_t skipped = 0;
  uint64_t stale = 0;  ///< chunks of an older epoch, dropped

  // Reassembly (SDK thread only): the chunks of a frame, then the frame applied to the full
  // state (a keyframe replaces it, a delta on the frame it holds changes it). Within an epoch
  // a frame is named by its tick and edit number (docs/PROTOCOL.md "Order of frames").
  using Key = std::pair<uint64_t, uint32_t>;  ///< (tick, edit)
  struct Partial {
    uint32_t chunkCount = 0;
    std::set<uint32_t> got;
    StateFrame frame;  ///< what the chunks carried (bodies changed this tick)
    std::vector<uint64_t> removed;
    Key base;  ///< the frame a delta applies to
    uint64_t refreshLo = 0, refreshHi = 0;  ///< a rolling refresh's keys (hi 0: none)
  };
  std::map<Key, Partial> partial;
  uint64_t epoch = 0;  ///< of the frames reassembled (0: none yet, or an older server)
  Key lastComplete;
  bool any = false;
  /// The last frame handed out (epoch, tick, edit): a keyframe of it again (one sent for a new
  /// subscriber, or by a world's new daemon after a move) is applied, not handed out twice.
  Key deliveredKey;
  uint64_t deliveredEpoch = 0;
  /// The full state as of the last frame applied, sorted by body index then generation (the
  /// world's order): a sorted vector, so that applying a delta is a binary search per
  /// carried body and handing the frame out one copy.
  std::vector<BodyState> full;
  Key stateKey;  ///< the last frame applied that carried something (deltas' base)
  bool haveFull = false;
  /// Out of step with a stream that refreshes (the server's rolling refresh): a frame was
  /// lost, so the state is not the world's. The deltas are still applied, and once
  /// refreshes without a gap between them have gone round every key (from wherever they
  /// were, to the end and on from 0 back to there), the state is the world's again: frames
  /// are delivered from then on. Until then they are skipped, as while waiting for a keyframe.
  bool resyncing = false;
  /// Where the last tick's changed bodies are in `full` (their marks come off at the next),
  /// valid while no body came or went since.
  std::vector<uint32_t> changedAt;
  bool changedAtValid = false;
  bool covering = false;  ///< refreshes since the last gap ...
  uint64_t coverStart = 0, coveredTo = 0;  ///< ... began at this key and reach that one
  bool wrapped = false;                    ///< ... past the end, and on from key 0

  static constexpr size_t kReserveBodies = 65536;  ///< 4 MB of states
  static uint64_t order(uint64_t id) { return (id << 32) | (id >> 32); }  // index, generation
  static bool before(const BodyState& a, const BodyState& b) { return order(a.id) < order(b.id); }

  /// A new daemon's stream (after a restart, or an interest subscribed again): its ticks and
  /// epochs may be behind the last ones delivered (a restored world resumes at its last
  /// mark; a daemon that keeps no worlds numbers epochs from 1 again), so nothing of the old
  /// stream's reassembly holds; it starts again from a keyframe.
  void restart() {
    startOver();
    epoch = 0;
    deliveredEpoch = 0;  // a new daemon's frames all count (under the SDK thread, as onChunk)
  }
  /// Nothing reassembled holds any more (a new daemon, or a new epoch of the world).
  void startOver() {
    std::lock_guard<std::mutex> lk(m);
    partial.clear();
    any = false;
    haveFull = resyncing = covering = false;
    keepDelivered();
    full.clear();
  }

  void onChunk(const wire::StateFrame& f, size_t bytes) {
    // A newer epoch (the world was reset, restored, loaded) is followed at once, whatever its
    // tick: the old epoch's reassembly and state are dropped, and its first frame (a
    // keyframe, or deltas repaired by their refreshes) starts the state again. An older
    // epoch's frames are late.
    if (f.epoch() < epoch) {
      std::lock_guard<std::mutex> lk(m);
      ++stale;
      return;
    }
    if (f.epoch() > epoch) {
      startOver();
      epoch = f.epoch();
    }
    const uint64_t t = f.tick();
    const Key k{t, f.edit()};
    // Older frames are superseded; the frame already delivered comes again only as a
    // keyframe (sent for a new subscriber), which is applied again, so that the deltas after
    // it (based on it) apply.
    if (any && (k < lastComplete || (k == lastComplete && !f.keyframe()))) return;
    Partial& p = partial[k];
    if (p.got.empty()) {
      p.chunkCount = f.chunk_count();
      p.frame.world = f.world();
      p.frame.tick = t;
      p.frame.time = f.time();
      p.frame.total = f.total_bodies();
      p.frame.stampNs = f.stamp_ns();
      p.frame.keyframe = f.keyframe();
      p.frame.epoch = f.epoch();
      p.frame.edit = f.edit();
      p.base = {f.base_tick(), f.base_edit()};
      p.refreshLo = f.refresh_lo();
      p.refreshHi = f.refresh_hi();
      // Room for the tick once (a keyframe holds them all; a delta's chunks are about this
      // one's size), not a reallocation per chunk; at most kReserveBodies on the word of one
      // chunk (a sender's claims cost no more than that until its chunks arrive).
      const size_t n = f.bodies() ? f.bodies()->size() : f.compact() ? f.compact()->size() : 0;
      const size_t want = std::min<size_t>(n * p.chunkCount, f.total_bodies());
      p.frame.bodies.reserve(std::min(want, kReserveBodies));
    }
    if (!p.got.insert(f.chunk_index()).second) return;
    p.frame.bytes += bytes;
    if (f.bodies())
      for (const wire::BodyState* s : *f.bodies()) p.frame.bodies.push_back(toState(*s));
    if (f.compact() && f.bounds_min() && f.bounds_max()) {
      const protocol::CompactBounds b{protocol::toPhys(*f.bounds_min()),
                                      protocol::toPhys(*f.bounds_max())};
      for (const wire::CompactBodyState* c : *f.compact())
        p.frame.bodies.push_back(toState(protocol::expandState(*c, b)));
    }
    if (f.removed()) p.removed.insert(p.removed.end(), f.removed()->begin(), f.removed()->end());
    if (p.got.size() < p.chunkCount) {
      while (partial.size() > 8) partial.erase(partial.begin());  // superseded frames
      return;
    }
    Partial done = std::move(p);
    any = true;
    lastComplete = k;
    partial.erase(partial.begin(), partial.upper_bound(k));
    // physd sends a tick's bodies in the world's order; applying them is then one walk.
    if (!std::is_sorted(done.frame.bodies.begin(), done.frame.bodies.end(), before))
      std::sort(done.frame.bodies.begin(), done.frame.bodies.end(), before);
    std::vector<BodyState> carried = std::move(done.frame.bodies);
    StateFrame header = done.frame;  // the tick without its bodies
    header.changed = uint32_t(carried.size());
    done.frame.bodies = std::move(carried);
    {
      // The full state changes under the lock: latest() may be copying it.
      std::lock_guard<std::mutex> lk(m);
      const bool again = deliveredEpoch == epoch && epoch != 0 && deliveredKey == k;
      if (!apply(done)) {
        ++skipped;
        return;
      }
      if (again) return;  // applied (the deltas after it build on it); seen already
      deliveredKey = k;
      deliveredEpoch = epoch;
      delivered = header;
      deliveredBodies = &full;
      ++frames;
      settled = !fn;
      delivering = std::this_thread::get_id();
    }
    if (fn) {
      // The callback's frame borrows the full state and gives it back.
      StateFrame view = std::move(header);
      {
        std::lock_guard<std::mutex> lk(m);
        view.bodies = std::move(full);
        deliveredBodies = &view.bodies;
      }
      {
        std::lock_guard<std::recursive_mutex> calling(fnMutex);
        if (!fnStopped) fn(view);
      }
      std::lock_guard<std::mutex> lk(m);
      full = std::move(view.bodies);
      deliveredBodies = &full;
      settled = true;
    }
    // After the callback: a waitForFrame that returns this frame finds the callback done
    // with it (what the callback recorded is there to read).
    cv.notify_all();
  }

  /// A complete tick onto the full state (under m); false when the state is not the
  /// world's at that tick: a delta on another tick than the one held, or one that does not
  /// add up to the world's count. The state is then dropped until the next keyframe or, when
  /// the stream refreshes, repaired by the refreshes (resyncing).
  bool apply(const Partial& p) {
    auto drop = [&] {
      haveFull = resyncing = false;
      keepDelivered();
      full.clear();
      return false;
    };
    const bool refresh = p.refreshHi != 0;
    if (p.frame.keyframe) {
      full = p.frame.bodies;
      if (!std::is_sorted(full.begin(), full.end(), before))
        std::sort(full.begin(), full.end(), before);
      for (BodyState& s : full) s.changed = true;
      changedAtValid = false;
      resyncing = false;
    } else {
      const bool inStep = haveFull && p.base == stateKey;
      if (!inStep) keepDelivered();  // what follows may not be delivered
      if (!inStep) {
        if (!refresh && !resyncing) return drop();  // wait for the next keyframe
        if (!resyncing || p.base != stateKey) covering = false;  // (another) frame lost
        resyncing = true;
        haveFull = false;
      }
      applyDelta(p, /*refreshRemoves=*/!inStep);
    }
    if (p.frame.keyframe || !p.frame.bodies.empty() || !p.removed.empty())
      stateKey = {p.frame.tick, p.frame.edit};
    if (resyncing) {
      if (refresh) {
        if (!covering || p.refreshLo != coveredTo) {  // the first since a loss, or a gap
          covering = true;
          wrapped = false;
          coverStart = p.refreshLo;
        }
        coveredTo = p.refreshHi;
        if (coveredTo == UINT64_MAX) {  // the end: on from the first key
          coveredTo = 0;
          wrapped = true;
        }
      }
      if (!covering || !wrapped || coveredTo < coverStart) return false;
      resyncing = false;  // every key refreshed since the last loss
    }
    if (full.size() != p.frame.total) {
      // A server that miscounted (never expected): the tick delivered last was in `full`.
      if (deliveredBodies == &full) deliveredBodies = nullptr;
      if (!refresh) return drop();
      resyncing = true;  // repaired by the next round of refreshes
      covering = haveFull = false;
      return false;
    }
    haveFull = true;
    return true;
  }

  /// A delta's removals, changed bodies and refresh onto the full state. refreshRemoves: a
  /// body held in the refresh's range that it does not carry is gone (only out of step: in
  /// step the state holds exactly the stream's bodies already).
  void applyDelta(const Partial& p, bool refreshRemoves) {
    // Last tick's marks off: where they were, unless bodies came or went since.
    if (changedAtValid) {
      for (uint32_t i : changedAt) full[i].changed = false;
    } else {
      for (BodyState& s : full) s.changed = false;
    }
    changedAt.clear();
    changedAtValid = true;
    // The body with this id among full's first n (sorted) entries, or null.
    auto find = [&](size_t n, uint64_t id) -> BodyState* {
      BodyState key;
      key.id = id;
      const auto end = full.begin() + std::ptrdiff_t(n);
      auto it = std::lower_bound(full.begin(), end, key, before);
      return it != end && it->id == id ? &*it : nullptr;
    };
    bool erase = false;
    for (uint64_t id : p.removed) {
      if (BodyState* b = find(full.size(), id)) {
        b->id = 0;  // erased below (0 is never a body's id)
        erase = true;
      }
    }
    auto eraseMarked = [&] {
      if (erase)
        full.erase(std::remove_if(full.begin(), full.end(), [](const BodyState& s) { return s.id == 0; }),
                   full.end());
      erase = false;
    };
    changedAtValid = !erase;  // positions move when bodies go
    eraseMarked();            // before the binary searches below
    const size_t old = full.size();
    // The carried bodies come sorted (onChunk): each is looked for after the last one, by a
    // galloping search (the next is usually a few places on).
    size_t from = 0;
    for (const BodyState& s : p.frame.bodies) {
      BodyState key;
      key.id = s.id;
      size_t lo = from, bound = from, step = 1;  // [from, lo) < key <= full[bound]
      while (bound < old && before(full[bound], key)) {
        lo = bound + 1;
        bound = from + step;
        step *= 2;
      }
      const auto end = full.begin() + std::ptrdiff_t(old);
      const auto it = std::lower_bound(full.begin() + std::ptrdiff_t(lo),
                                       full.begin() + std::ptrdiff_t(std::min(bound + 1, old)),
                                       key, before);
      from = size_t(it - full.begin());
      if (it != end && it->id == s.id) {
        *it = s;
        it->changed = true;
        changedAt.push_back(uint32_t(from));
      } else {
        full.push_back(s);  // a new body: sorted in below
        full.back().changed = true;
      }
    }
    if (full.size() != old) {
      changedAtValid = false;  // and when bodies come
      std::sort(full.begin() + std::ptrdiff_t(old), full.end(), before);
      std::inplace_merge(full.begin(), full.begin() + std::ptrdiff_t(old), full.end(), before);
    }
    if (p.refreshHi != 0 && refreshRemoves) {
      // A refresh carries every body of its key range: one held there that it does not carry
      // is gone (removed in a frame this subscriber lost).
      std::vector<uint64_t> carried;
      for (const BodyState& s : p.frame.bodies) {
        const uint64_t k = order(s.id);
        if (k >= p.refreshLo && (p.refreshHi == UINT64_MAX || k < p.refreshHi)) carried.push_back(k);
      }  // in order, as the bodies are
      BodyState lo;
      lo.id = order(p.refreshLo);  // order() is its own inverse
      auto it = std::lower_bound(full.begin(), full.end(), lo, before);
      for (; it != full.end() && (p.refreshHi == UINT64_MAX || order(it->id) < p.refreshHi); ++it) {
        if (!std::binary_search(carried.begin(), carried.end(), order(it->id))) {
          it->id = 0;
          erase = true;
        }
      }
      if (erase) changedAtValid = false;
      eraseMarked();
    }
  }
};

struct Client::Impl {
  ClientOptions options;
  uint64_t clientId = 0;
  std::optional<protocol::ClientKey> key;  ///< none: a plain fixed id (not proven)
  /// The key's binding proof for this client's participant (made once: it does not change).
  std::array<uint8_t, protocol::kClientProofBytes> proof{};
  dds::Participant participant;
  dds::Topic cmdTopic, replyTopic, statusTopic, eventsTopic;
  dds::Writer cmdWriter;
  dds::Reader replyReader, statusReader, eventsReader;
  dds::WaitSet waitset;

  std::mutex writeMutex;
  std::atomic<uint64_t> seq{0};
  /// Command readers (daemons) this client's proof was written to since they matched; under
  /// writeMutex. See proveToNewDaemons.
  std::set<dds_instance_handle_t> proofSentTo;

  struct Pending {
    Clock::time_point deadline;
    bool sentWithServer = false;
    std::function<void(const wire::Reply*, const Error*)> done;
    /// The command as sent, kept to send it again after a refusal at the door (retryBusy) or
    /// to a world's new owner (Moved).
    std::shared_ptr<const protocol::Bytes> bytes;
    uint32_t world = 0;
    uint32_t retries = 0;    ///< times refused at the door so far
    uint32_t redirects = 0;  ///< times sent on to a world's new owner (Moved)
    /// The daemon that should answer it: the one addressed, or the world's range daemon;
    /// 0 with a lone daemon (or for Hello, which every daemon answers). When that daemon is
    /// gone (its status's DDS liveliness lapsed) before answering, the request fails at once
    /// (failGone).
    uint64_t daemon = 0;
    /// Not sent yet: its world's daemon is gone, and the request waits for a live daemon to
    /// list the world (its standby taking it over) to go there; see sendParked.
    bool parked = false;
    /// In the backlog (see `held`): not (or no longer) at the daemon, sent by the SDK thread
    /// at `sendAt` at the earliest.
    bool held = false;
    Clock::time_point sendAt{};
  };
  std::mutex pendMutex;
  std::map<uint64_t, Pending> pending;  ///< by seq, so in the order they were made
  /// The backlog of refusals at the door (retryBusy), under pendMutex: from a client's first
  /// refusal until its backlog is empty, its requests go out one at a time, in order (the
  /// refused ones again after the wait the daemon names, the ones made meanwhile behind
  /// them), each when the one before it is answered. A daemon counts no command against a
  /// client's rate while none of its others waits, so the backlog drains at the round trip's
  /// pace without being refused again, and a client refused for sending ahead cannot keep
  /// flooding by retrying.
  size_t held = 0;           ///< entries of `pending` held
  size_t parked = 0;         ///< entries of `pending` parked (their daemon gone)
  uint64_t backlogSeq = 0;   ///< the backlog's request at the daemon now (0: none)
  bool backlogged() const { return held > 0 || backlogSeq != 0; }  // pendMutex held

  mutable std::mutex infoMutex;
  ServerInfo server;
  std::optional<ServerStatus> status;
  /// Every daemon's last status (under infoMutex), by server.id, and the worlds this client
  /// created on it that no sample has listed yet (placement counts them until one does: a
  /// sample read out before a CreateWorld may arrive after its reply), each for at most
  /// kPlacedKept.
  struct DaemonView {
    ServerStatus status;
    Clock::time_point seen;
    /// DDS said its status has no live writer any more (its liveliness lease passed without
    /// a sign: killed, frozen, or stopped), at goneAt; a later sample makes it live again.
    bool gone = false;
    Clock::time_point goneAt{};
    std::map<uint32_t, Clock::time_point> placed;
    uint32_t worlds() const { return uint32_t(status.worlds.size() + placed.size()); }
  };
  static constexpr std::chrono::seconds kPlacedKept{10};
  std::map<uint64_t, DaemonView> daemonViews;
  /// Worlds held by another daemon than their id's range's, and by which (under infoMutex).
  std::unordered_map<uint32_t, uint64_t> owners;
  /// A daemon of a cluster has been seen: commands look up their world's owner (a lone
  /// daemon's clients pay nothing for it).
  std::atomic<bool> clusterSeen{false};
  /// Seqs answered lately (under pendMutex), to count a second answer (duplicateReplies).
  std::deque<uint64_t> answeredOrder;
  std::unordered_set<uint64_t> answered;
  static constexpr size_t kAnsweredKept = 4096;
  std::atomic<uint64_t> duplicates{0};
  std::function<void(const Event&)> eventFn;  // under infoMutex
  std::deque<Event> events;                   // under infoMutex, the last kKeptEvents
  static constexpr size_t kKeptEvents = 64;

  std::atomic<bool> everConnected{false}, helloOk{false}, helloInFlight{false}, needHello{false};
  std::atomic<uint64_t> reconnects{0};
  std::atomic<size_t> serversMatched{0};
  std::set<dds_instance_handle_t> servers;  // SDK thread only

  std::mutex subsMutex;
  std::vector<std::shared_ptr<Subscription::State>> subs;

  std::atomic<bool> stop{false};
  std::thread thread;

  void fail(const std::string& what, std::string err) {
    throw Error(ErrorCode::Transport, what + ": " + err);
  }

  explicit Impl(ClientOptions o) : options(std::move(o)) {
    // The client's id: its key's (proven in every Hello), or a plain fixed id without a key.
    if (!options.keyFile.empty()) {
      protocol::ClientKey k;
      protocol::Status s = protocol::ClientKey::load(options.keyFile, true, &k);
      if (!s.ok()) throw Error(ErrorCode::InvalidArgument, s.message);
      if (options.clientId && options.clientId != k.clientId())
        throw Error(ErrorCode::InvalidArgument,
                    "ClientOptions::clientId differs from the id of the key in " +
                        options.keyFile + " (leave it 0: the key names the client)");
      key = k;
    } else if (!options.clientId) {
      key = protocol::ClientKey::generate();
    }
    clientId = key ? key->clientId() : options.clientId;
    std::string err;
    std::string xml = options.cycloneXml;
    std::vector<std::string> cmdPartitions;
    if (options.security.enabled()) {
      protocol::Status s = protocol::addSecurity(&xml, options.security);
      if (!s.ok()) throw Error(ErrorCode::InvalidArgument, s.message);
      cmdPartitions.push_back(protocol::identityPartition(options.security.identity));
    }
    if (!participant.create(options.domain, xml, &err)) fail("participant", err);
    if (key) proof = key->proveBinding(participant.guid());
    if (!cmdTopic.create(participant, std::string(protocol::kCommandTopic), &err) ||
        !replyTopic.create(participant, std::string(protocol::kReplyTopic), &err) ||
        !statusTopic.create(participant, std::string(protocol::kStatusTopic), &err) ||
        !eventsTopic.create(participant, std::string(protocol::kEventsTopic), &err))
      fail("topic", err);
    if (!cmdWriter.create(participant, cmdTopic, protocol::kCommandQos,
                          protocol::PayloadKind::Command, &err, cmdPartitions))
      fail("writer", err);
    if (!replyReader.create(participant, replyTopic, protocol::kReplyQos, &err) ||
        !statusReader.create(participant, statusTopic, protocol::kStatusQos, &err) ||
        !eventsReader.create(participant, eventsTopic, protocol::kEventsQos, &err))
      fail("reader", err);
    if (!waitset.create(participant, &err) || !waitset.attach(replyReader, &err) ||
        !waitset.attach(statusReader, &err) || !waitset.attach(eventsReader, &err))
      fail("waitset", err);
    thread = std::thread([this] { loop(); });
  }

  ~Impl() {
    stop = true;
    waitset.wake();
    if (thread.joinable()) thread.join();
    failAll(ErrorCode::Disconnected, "the client was closed", false);
    std::vector<std::shared_ptr<Subscription::State>> copy;
    {
      std::lock_guard<std::mutex> lk(subsMutex);
      copy.swap(subs);
    }
    for (auto& s : copy) {
      std::lock_guard<std::mutex> lk(s->ownerMutex);
      s->owner = nullptr;
      waitset.detach(s->reader);
      s->reader.reset();
      s->topic.reset();
    }
  }

  std::chrono::milliseconds timeoutOf(const CallOptions& o) const {
    return o.timeout.count() > 0 ? o.timeout : options.requestTimeout;
  }

  /// Sends a command; done runs once, on the SDK thread (or here on a write failure).
  /// daemon: Command.daemon (0: the world's owner; see CallOptions::daemon).
  void send(CommandBuilder& b, uint32_t world, std::chrono::milliseconds timeout,
            std::function<void(const wire::Reply*, const Error*)> done, uint64_t daemon = 0) {
    const bool hello = b.requestCount() == 1 && b.requestType(0) == wire::Request::Hello;
    if (world != 0 && daemon == 0 && clusterSeen.load()) {
      daemon = ownerOf(world);  // held by another daemon than its range's
    }
    const bool park = world != 0 && clusterSeen.load() && !hello && heldByGone(world, daemon);
    if (world != 0 && daemon == 0 && clusterSeen.load() && !park) {
      if (std::optional<std::string> why = unreachable(world)) {
        // In a domain of daemons nobody would answer: said now, not after the timeout.
        Error e(ErrorCode::NotFound, *why);
        done(nullptr, &e);
        return;
      }
    }
    const uint64_t s = ++seq;
    auto bytes =
        std::make_shared<const protocol::Bytes>(b.finish({clientId, s, world, daemon, true}));
    bool later = false;
    {
      std::lock_guard<std::mutex> lk(pendMutex);
      Pending& p = pending[s];
      p.deadline = Clock::now() + timeout;
      p.sentWithServer = serversMatched.load() > 0;
      p.done = done;
      p.bytes = bytes;
      p.world = world;
      p.daemon = daemon != 0 ? daemon
                             : (clusterSeen.load() && world != 0 ? protocol::daemonOfWorld(world)
                                                                 : 0);
      if (park) {
        // Its world's daemon is gone: sent when a live daemon lists the world (sendParked).
        p.parked = later = true;
        p.sentWithServer = true;
        ++parked;
      } else if (options.retryBusy && backlogged()) {
        // Behind the requests the daemon refused: the SDK thread sends it in its turn.
        p.held = later = true;
        p.sentWithServer = true;  // not lost to a missing daemon: sent later
        ++held;
      }
    }
    if (later) {
      waitset.wake();
      return;
    }
    dds_return_t rc;
    {
      std::lock_guard<std::mutex> lk(writeMutex);
      proveToNewDaemons(hello);
      rc = cmdWriter.write(clientId, *bytes, s);
    }
    if (rc < 0) {
      bool mine = false;
      {
        std::lock_guard<std::mutex> lk(pendMutex);
        mine = pending.erase(s) > 0;
      }
      if (mine) {
        Error e(ErrorCode::Transport, "dds_write on phys/cmd: " + dds::error(rc));
        done(nullptr, &e);
      }
    }
    waitset.wake();
  }

  template <class T>
  std::future<T> request(CommandBuilder& b, uint32_t world, const CallOptions& o,
                         std::function<T(const wire::Reply&)> parse) {
    auto prom = std::make_shared<std::promise<T>>();
    std::future<T> fut = prom->get_future();
    send(
        b, world, timeoutOf(o),
        [prom, parse](const wire::Reply* r, const Error* e) {
          try {
            if (e) throw *e;
            if (r->status() != wire::StatusCode::Ok)
              throw Error(ErrorCode(uint8_t(r->status())), str(r->message()),
                          r->retry_after_ms());
            prom->set_value(parse(*r));
          } catch (...) {
            prom->set_exception(std::current_exception());
          }
        },
        o.daemon);
    return fut;
  }

  /// The daemons whose last status is fresh: within 3 of their periods, at least 2 s.
  /// infoMutex held.
  std::vector<std::pair<uint64_t, const DaemonView*>> liveDaemons() const {
    std::vector<std::pair<uint64_t, const DaemonView*>> out;
    const auto now = Clock::now();
    for (const auto& [id, v] : daemonViews) {
      if (v.gone) continue;
      const double period = v.status.statusPeriodS > 0 ? v.status.statusPeriodS : 1.0;
      if (now - v.seen <= std::chrono::duration<double>(std::max(3 * period, 2.0)))
        out.emplace_back(id, &v);
    }
    return out;
  }

  /// Where createWorld goes without CallOptions::daemon: in a domain of daemons, the live one
  /// with the fewest awake bodies, then the fewest worlds (counting those this client made
  /// since its last sample), then the lowest id; 0 (whoever takes it) with a lone daemon.
  uint64_t placeWorld() const {
    std::lock_guard<std::mutex> lk(infoMutex);
    uint64_t best = 0;
    std::tuple<uint64_t, uint64_t, uint64_t> bestKey{};
    for (const auto& [id, v] : liveDaemons()) {
      if (!v->status.cluster) continue;
      uint64_t awake = 0;
      for (const WorldSummary& w : v->status.worlds) awake += w.awakeBodies;
      const std::tuple<uint64_t, uint64_t, uint64_t> key{awake,
                                                         v->worlds(), id};
      if (best == 0 || key < bestKey) {
        best = id;
        bestKey = key;
      }
    }
    return best;
  }

  /// Why no daemon would take a command for `world`, in a domain of daemons: the daemon of its
  /// id's range is not live and no live daemon lists it. nullopt: someone answers (also with
  /// a lone daemon, which answers every world).
  std::optional<std::string> unreachable(uint32_t world) const {
    std::lock_guard<std::mutex> lk(infoMutex);
    const auto live = liveDaemons();
    if (std::none_of(live.begin(), live.end(), [](auto& d) { return d.second->status.cluster; }))
      return std::nullopt;
    const uint64_t range = protocol::daemonOfWorld(world);
    if (owners.count(world)) return std::nullopt;
    for (const auto& [id, v] : live) {
      if (id == range) return std::nullopt;
      for (const WorldSummary& w : v->status.worlds)
        if (w.world == world) return std::nullopt;
    }
    return "command.world " + std::to_string(world) +
           " does not exist: no daemon of the domain holds it (its id is of daemon " +
           std::to_string(range) + "'s range, which is not running)";
  }

  /// Whether a command for `world` (addressed to `daemon`, 0: its range's) would go to a
  /// daemon that is gone while its last status listed the world: the command then waits for
  /// a live daemon to list it (a standby taking it over) instead of being sent into the void.
  bool heldByGone(uint32_t world, uint64_t daemon) const {
    std::lock_guard<std::mutex> lk(infoMutex);
    auto it = daemonViews.find(daemon != 0 ? daemon : protocol::daemonOfWorld(world));
    if (it == daemonViews.end() || !it->second.gone) return false;
    const auto& listed = it->second.status.worlds;
    return std::any_of(listed.begin(), listed.end(),
                       [&](const WorldSummary& w) { return w.world == world; });
  }

  /// Where a command for `world` goes now that its daemon is gone: the live daemon that
  /// lists it (0: its range's daemon, unaddressed); nullopt while none does. infoMutex held.
  std::optional<uint64_t> liveHolder(uint32_t world) const {
    for (const auto& [id, v] : liveDaemons())
      for (const WorldSummary& w : v->status.worlds)
        if (w.world == world) return id == protocol::daemonOfWorld(world) ? 0 : id;
    return std::nullopt;
  }

  /// How long a command waits for its gone daemon's world to be taken over (from the moment
  /// the SDK saw the daemon gone; a standby takes over about half a second after the
  /// daemon's last heartbeat, before its liveliness lease even passes).
  static constexpr std::chrono::seconds kTakeoverWait{3};

  /// Sends the parked commands whose world a live daemon now lists; fails those whose
  /// daemon has been gone for kTakeoverWait with none listing it (SDK thread).
  void sendParked() {
    struct Go {
      uint64_t seq;
      std::shared_ptr<const protocol::Bytes> bytes;
    };
    std::vector<Go> go;
    std::vector<std::pair<Pending, uint64_t>> orphans;  // and the gone daemon
    {
      std::lock_guard<std::mutex> lk(pendMutex);
      if (parked == 0) return;
      std::lock_guard<std::mutex> lk2(infoMutex);
      const auto now = Clock::now();
      for (auto it = pending.begin(); it != pending.end();) {
        Pending& p = it->second;
        if (!p.parked) {
          ++it;
          continue;
        }
        if (std::optional<uint64_t> to = liveHolder(p.world)) {
          auto patched = std::make_shared<protocol::Bytes>(*p.bytes);
          if (protocol::setCommandDaemon(*patched, *to)) p.bytes = patched;
          p.daemon = *to != 0 ? *to : protocol::daemonOfWorld(p.world);
          p.parked = false;
          p.sentWithServer = serversMatched.load() > 0;
          --parked;
          go.push_back({it->first, p.bytes});
          ++it;
          continue;
        }
        auto v = daemonViews.find(p.daemon);
        const bool stillGone = v != daemonViews.end() && v->second.gone;
        if (stillGone && now - v->second.goneAt < kTakeoverWait) {
          ++it;
          continue;
        }
        if (!stillGone) {  // its daemon is back (it was frozen): to it again
          p.parked = false;
          --parked;
          go.push_back({it->first, p.bytes});
          ++it;
          continue;
        }
        --parked;
        const uint64_t gone = p.daemon;
        orphans.emplace_back(std::move(p), gone);
        it = pending.erase(it);
      }
    }
    for (const Go& g : go) {
      std::lock_guard<std::mutex> lk(writeMutex);
      proveToNewDaemons(false);
      cmdWriter.write(clientId, *g.bytes, g.seq);
    }
    for (auto& [p, daemon] : orphans) {
      Error e(ErrorCode::Disconnected,
              "daemon " + std::to_string(daemon) + ", which held world " + std::to_string(p.world) +
                  ", is gone (no DDS liveliness) and no daemon took the world over within " +
                  std::to_string(kTakeoverWait.count()) + " s; the command was not sent");
      p.done(nullptr, &e);
    }
  }

  /// A daemon is gone (its status lost its liveliness): the requests it has not answered
  /// fail now, their outcome unknown (it may have applied one and died before answering; a
  /// standby that took its world over has then applied it too). SDK thread.
  void failGone(uint64_t daemon) {
    bool anyLive = false;
    {
      std::lock_guard<std::mutex> lk(infoMutex);
      anyLive = !liveDaemons().empty();
    }
    std::vector<Pending> failed;
    {
      std::lock_guard<std::mutex> lk(pendMutex);
      for (auto it = pending.begin(); it != pending.end();) {
        const Pending& p = it->second;
        const bool its = p.daemon == daemon || (p.daemon == 0 && !anyLive);
        if (p.held || p.parked || !its) {
          ++it;
          continue;
        }
        if (it->first == backlogSeq) backlogSeq = 0;
        failed.push_back(std::move(it->second));
        it = pending.erase(it);
      }
    }
    Error e(ErrorCode::Disconnected,
            "daemon " + std::to_string(daemon) +
                " is gone (its DDS liveliness lapsed: killed, frozen or stopped) with the request "
                "unanswered; whether it was applied is unknown (read the world to see)");
    for (auto& p : failed) p.done(nullptr, &e);
  }

  /// The live daemons of a domain (none with a lone daemon: one request reaches it).
  std::vector<uint64_t> clusterDaemons() const {
    std::lock_guard<std::mutex> lk(infoMutex);
    std::vector<uint64_t> out;
    for (const auto& [id, v] : liveDaemons())
      if (v->status.cluster) out.push_back(id);
    return out;
  }

  std::future<Ack> ackRequest(CommandBuilder& b, uint32_t world, const CallOptions& o) {
    return request<Ack>(b, world, o, [](const wire::Reply& r) { return ack(r); });
  }

  /// Before a command goes out (writeMutex held): a daemon that matched this client's writer
  /// since the last Hello (a restarted daemon the SDK thread has not noticed yet) gets a Hello
  /// with the proof first, on the same writer, so it reads the proof before the command and
  /// treats the command as the key holder's. Without this, a command written in the moment
  /// between a new daemon matching and the SDK thread's greeting would reach it unproven and be
  /// refused on a proof-owned world. (The answer to this Hello is not awaited; the SDK thread
  /// greets the daemon too, for its ServerInfo.)
  void proveToNewDaemons(bool isHello) {
    if (!key) return;
    const std::vector<dds_instance_handle_t> now = cmdWriter.matchedHandles();
    bool fresh = false;
    for (dds_instance_handle_t h : now) fresh = fresh || !proofSentTo.count(h);
    proofSentTo = std::set<dds_instance_handle_t>(now.begin(), now.end());
    if (!fresh || isHello) return;
    CommandBuilder b;
    greet(b);
    const uint64_t s = ++seq;
    cmdWriter.write(clientId, b.finish({clientId, s, 0}), s);
  }

  /// Hello, with the key's binding proof when the client has a key.
  void greet(CommandBuilder& b) const {
    if (key)
      b.hello(options.name, key->publicKey(), proof);
    else
      b.hello(options.name);
  }

  static ServerInfo parseHello(const wire::Reply& r) {
    auto* h = r.result_as_HelloResult();
    if (!h) throw Error(ErrorCode::BadReply, "hello reply without HelloResult");
    ServerInfo i;
    i.protocolVersion = h->protocol_version();
    i.name = str(h->server_name());
    i.version = str(h->server_version());
    i.clientProven = h->client_proven();
    if (h->features())
      for (auto* f : *h->features()) i.features.push_back(f->str());
    return i;
  }

  std::future<ServerInfo> hello(const CallOptions& o) {
    CommandBuilder b;
    greet(b);
    return request<ServerInfo>(b, 0, o, [this](const wire::Reply& r) {
      ServerInfo i = parseHello(r);
      {
        std::lock_guard<std::mutex> lk(infoMutex);
        server = i;
      }
      helloOk = true;
      return i;
    });
  }

  void failAll(ErrorCode code, const std::string& why, bool onlyUnsent) {
    std::vector<Pending> failed;
    {
      std::lock_guard<std::mutex> lk(pendMutex);
      for (auto it = pending.begin(); it != pending.end();) {
        if (onlyUnsent && it->second.sentWithServer) {
          ++it;
          continue;
        }
        if (it->second.held) --held;
        if (it->second.parked) --parked;
        failed.push_back(std::move(it->second));
        it = pending.erase(it);
      }
    }
    Error e(code, why);
    for (auto& p : failed) p.done(nullptr, &e);
  }

  /// Times one request is sent on to a world's new owner before its Moved is the answer.
  static constexpr uint32_t kMaxRedirects = 3;

  void takeReplies() {
    struct Resend {  // Moved: the command again, to the world's new owner
      uint64_t seq = 0;
      std::shared_ptr<const protocol::Bytes> bytes;
      uint32_t world = 0;
      uint64_t owner = 0;
    };
    std::vector<Resend> resend;
    replyReader.take([&](const phys_wire_Envelope& env) {
      if (env.key != clientId) return;
      if (!protocol::checkEnvelope(env, protocol::PayloadKind::Reply).ok()) return;
      auto b = protocol::envelopeBytes(env);
      auto r = protocol::decodeReply(b);
      Pending p;
      {
        std::lock_guard<std::mutex> lk(pendMutex);
        auto it = pending.find(r.ok() ? r->seq() : env.seq);
        if (it == pending.end() && r.ok() && answered.count(r->seq()) &&
            !r->result_as_HelloResult())
          ++duplicates;  // a second daemon took the command
        if (it == pending.end() || it->second.held || it->second.parked)
          return;  // not this send's answer
        if (r.ok() && r->status() == wire::StatusCode::Moved && r->owner() != 0 &&
            it->second.redirects < kMaxRedirects) {
          // The world moved, nothing was done: the same command (same seq) to its new owner.
          Pending& q = it->second;
          ++q.redirects;
          q.daemon = r->owner();
          auto patched = std::make_shared<protocol::Bytes>(*q.bytes);
          if (protocol::setCommandDaemon(*patched, r->owner())) {
            q.bytes = patched;
            resend.push_back({it->first, patched, q.world, r->owner()});  // after the take
            return;  // still the backlog's request at a daemon, if it was
          }
        }
        if (it->first == backlogSeq) backlogSeq = 0;  // the next of the backlog may go
        if (r.ok() && options.retryBusy &&
            r->status() == wire::StatusCode::ResourceExhausted && r->retry_after_ms() > 0) {
          // Refused at the door, nothing done: into the backlog, to go again after the wait
          // the daemon names and a backoff, if that is before the request's deadline.
          Pending& q = it->second;
          const auto wait = retryWait(q.retries, r->retry_after_ms());
          if (Clock::now() + wait < q.deadline) {
            ++q.retries;
            q.held = true;
            q.sendAt = Clock::now() + wait;
            ++held;
            return;
          }
        }
        p = std::move(it->second);
        pending.erase(it);
        remember(r.ok() ? r->seq() : env.seq);
      }
      if (r.ok()) {
        p.done(r.root, nullptr);
      } else {
        Error e(ErrorCode::BadReply, r.status.message);
        p.done(nullptr, &e);
      }
    });
    for (const Resend& r : resend) {
      learnOwner(r.world, r.owner);
      std::lock_guard<std::mutex> lk(writeMutex);
      proveToNewDaemons(false);
      cmdWriter.write(clientId, *r.bytes, r.seq);
    }
  }

  /// The daemon to address a command for `world` to: the one that holds it when that is not
  /// its range's daemon (from the daemons' status, and Moved replies); 0: unaddressed.
  uint64_t ownerOf(uint32_t world) const {
    std::lock_guard<std::mutex> lk(infoMutex);
    auto it = owners.find(world);
    return it == owners.end() ? 0 : it->second;
  }
  /// A daemon's own list (ListWorlds): where each of its worlds is, as fresh as its status
  /// (after a takeover the list may come before the new owner's status sample).
  void learnOwners(const std::vector<WorldSummary>& listed) {
    if (!clusterSeen.load()) return;
    for (const WorldSummary& w : listed)
      if (w.daemon != 0 && w.movingTo == 0) learnOwner(w.world, w.daemon);
  }
  void learnOwner(uint32_t world, uint64_t daemon) {
    std::lock_guard<std::mutex> lk(infoMutex);
    if (protocol::daemonOfWorld(world) == daemon)
      owners.erase(world);
    else
      owners[world] = daemon;
  }

  /// A request answered (pendMutex held): kept a while, to recognize a second answer.
  void remember(uint64_t s) {
    if (!answered.insert(s).second) return;
    answeredOrder.push_back(s);
    if (answeredOrder.size() > kAnsweredKept) {
      answered.erase(answeredOrder.front());
      answeredOrder.pop_front();
    }
  }

  void takeStatus() {
    std::vector<uint64_t> gone;
    statusReader.take([&](const phys_wire_Envelope& env, dds_instance_handle_t) {
      if (!protocol::checkEnvelope(env, protocol::PayloadKind::ServerStatus).ok()) return;
      auto s = protocol::decodeServerStatus(protocol::envelopeBytes(env));
      if (!s.ok()) return;
      ServerStatus st;
      st.serverName = str(s->server_name());
      st.serverVersion = str(s->server_version());
      st.uptimeS = s->uptime_s();
      st.commands = s->commands();
      st.errors = s->errors();
      st.framesDropped = s->frames_dropped();
      st.heapBytes = s->heap_bytes();
      st.readOnly = str(s->read_only());
      st.daemon = s->daemon() ? s->daemon() : env.key;
      st.cluster = s->cluster();
      st.statusPeriodS = s->status_period_s();
      if (s->peers()) st.peers.assign(s->peers()->begin(), s->peers()->end());
      if (s->worlds())
        for (auto* w : *s->worlds()) st.worlds.push_back(toSummary(*w));
      std::lock_guard<std::mutex> lk(infoMutex);
      if (st.cluster) clusterSeen = true;
      if (st.cluster)
        for (const WorldSummary& w : st.worlds) {
          if (protocol::daemonOfWorld(w.world) == st.daemon)
            owners.erase(w.world);
          else
            owners[w.world] = st.daemon;
        }
      DaemonView& view = daemonViews[st.daemon];
      const auto now = Clock::now();
      for (const WorldSummary& w : st.worlds) view.placed.erase(w.world);  // counted now
      std::erase_if(view.placed, [&](const auto& p) { return now - p.second > kPlacedKept; });
      view.status = st;
      view.seen = now;
      view.gone = false;
      status = std::move(st);
    }, [&](uint64_t daemon) {
      std::lock_guard<std::mutex> lk(infoMutex);
      auto it = daemonViews.find(daemon);
      if (it == daemonViews.end() || it->second.gone) return;
      it->second.gone = true;
      it->second.goneAt = Clock::now();
      gone.push_back(daemon);
    });
    if (gone.empty()) return;
    takeReplies();  // what it answered before it went
    for (uint64_t d : gone) failGone(d);
  }

  void takeEvents() {
    eventsReader.take([&](const phys_wire_Envelope& env) {
      if (!protocol::checkEnvelope(env, protocol::PayloadKind::Event).ok()) return;
      auto d = protocol::decodeEvent(protocol::envelopeBytes(env));
      if (!d.ok()) return;
      Event e;
      e.world = d->world();
      e.tick = d->tick();
      e.severity = Event::Severity(uint8_t(d->severity()));
      e.code = str(d->code());
      e.message = str(d->message());
      std::function<void(const Event&)> fn;
      {
        std::lock_guard<std::mutex> lk(infoMutex);
        events.push_back(e);
        if (events.size() > kKeptEvents) events.pop_front();
        fn = eventFn;
      }
      if (fn) fn(e);
    });
  }

  void takeStates() {
    std::vector<std::shared_ptr<Subscription::State>> copy;
    {
      std::lock_guard<std::mutex> lk(subsMutex);
      copy = subs;
    }
    for (auto& s : copy)
      s->reader.take([&](const phys_wire_Envelope& env) {
        if (!protocol::checkEnvelope(env, protocol::PayloadKind::StateFrame).ok()) return;
        const std::span<const uint8_t> bytes = protocol::envelopeBytes(env);
        auto f = protocol::decodeStateFrame(bytes);
        if (f.ok() && f->world() == s->world && f->interest() == s->interest)
          s->onChunk(*f, bytes.size());
      });
  }

  void checkServers() {
    auto now = cmdWriter.matchedHandles();
    std::set<dds_instance_handle_t> cur(now.begin(), now.end());
    bool removed = false, added = false;
    for (auto h : servers)
      if (!cur.count(h)) removed = true;
    for (auto h : cur)
      if (!servers.count(h)) added = true;
    servers = std::move(cur);
    serversMatched = servers.size();
    // A daemon that went away while another is still matched (a killed daemon whose lease
    // ran out after its successor started) changes nothing: the other one answers.
    if (removed && servers.empty()) {
      helloOk = false;
      failAll(ErrorCode::Disconnected, "physd went away before replying", false);
      if (everConnected && options.autoReconnect) needHello = true;
    }
    if (added) {
      failAll(ErrorCode::Disconnected, "sent while no physd was matched; not delivered", true);
      if (everConnected && options.autoReconnect) needHello = true;
    }
    if (needHello && !helloInFlight && !servers.empty() && replyReader.matched() > 0) {
      helloInFlight = true;
      needHello = false;
      CommandBuilder b;
      greet(b);
      send(b, 0, std::chrono::milliseconds(2000), [this](const wire::Reply* r, const Error* e) {
        helloInFlight = false;
        if (!e && r->status() == wire::StatusCode::Ok && r->result_as_HelloResult()) {
          ServerInfo i = parseHello(*r);
          {
            std::lock_guard<std::mutex> lk(infoMutex);
            server = i;
            helloOk = true;
            ++reconnects;
          }
          resubscribe();
        } else {
          needHello = true;  // retried while a server is matched
        }
      });
    }
  }

  /// After a daemon (re)appeared: every stream starts over, and every interest is subscribed
  /// again (a daemon keeps no interests across a restart: docs/SERVER.md "Durable worlds").
  /// SDK thread.
  void resubscribe() {
    std::vector<std::shared_ptr<Subscription::State>> copy;
    {
      std::lock_guard<std::mutex> lk(subsMutex);
      copy = subs;
    }
    for (auto& s : copy) {
      s->restart();
      if (s->interest != 0) subscribeAgain(s);
    }
  }

  /// The daemon a command for `world` goes to now (0 with a lone daemon). infoMutex free.
  uint64_t currentOwner(uint32_t world) const {
    if (!clusterSeen.load()) return 0;
    const uint64_t o = ownerOf(world);
    return o != 0 ? o : protocol::daemonOfWorld(world);
  }

  /// In a domain of daemons, an interest whose world changed owner (taken over, moved) is
  /// subscribed again on the new owner, once that daemon is live and lists the world: its
  /// old daemon is gone or let the world go, and with it the interest. SDK thread.
  void followInterests() {
    if (!clusterSeen.load()) return;
    std::vector<std::shared_ptr<Subscription::State>> copy;
    {
      std::lock_guard<std::mutex> lk(subsMutex);
      for (auto& s : subs)
        if (s->interest != 0) copy.push_back(s);
    }
    for (auto& s : copy) {
      const uint64_t owner = currentOwner(s->world);
      if (owner == s->daemon) continue;
      if (s->daemon == 0) {  // subscribed before the SDK knew of a domain: where it is now
        s->daemon = owner;
        continue;
      }
      {
        std::lock_guard<std::mutex> lk(infoMutex);
        const std::optional<uint64_t> holder = liveHolder(s->world);
        if (!holder || (*holder != 0 ? *holder : protocol::daemonOfWorld(s->world)) != owner)
          continue;  // not served there yet
      }
      s->daemon = owner;
      s->restart();
      subscribeAgain(s);
    }
  }

  /// Subscribes interest subscription s again (a new interest id, topic and reader once
  /// answered). SDK thread.
  void subscribeAgain(const std::shared_ptr<Subscription::State>& s) {
    CommandBuilder b;
    if (s->spec.region)
      b.subscribeRegion(s->spec.region->first, s->spec.region->second);
    else
      b.subscribeBodies(s->spec.bodies);
    std::weak_ptr<Subscription::State> weak = s;
    send(b, s->world, options.requestTimeout, [this, weak](const wire::Reply* r, const Error* e) {
      auto s = weak.lock();
      const wire::InterestResult* i =
          !e && r->status() == wire::StatusCode::Ok ? r->result_as_InterestResult() : nullptr;
      if (!s || !i || i->interest() == 0) return;  // gone, or the world with it
      const uint32_t id = i->interest();
      std::string err;
      dds::Topic topic;
      dds::Reader reader;
      bool live = false;
      {
        std::lock_guard<std::mutex> lk(subsMutex);
        live = std::find(subs.begin(), subs.end(), s) != subs.end();
        if (live && topic.create(participant, protocol::stateTopic(s->world, id), &err) &&
            reader.create(participant, topic, protocol::kStateReaderQos, &err)) {
          waitset.detach(s->reader);
          s->reader = std::move(reader);
          s->topic = std::move(topic);
          s->interest = id;
          if (!waitset.attach(s->reader, &err)) live = false;
        }
      }
      if (!live) {  // unsubscribed meanwhile: the new interest is not wanted either
        CommandBuilder u;
        u.unsubscribe(id);
        send(u, s->world, options.requestTimeout, [](const wire::Reply*, const Error*) {});
      }
    });
  }

  /// How long to wait before sending a refused command again: what the daemon says, and at
  /// least 1, 2, 4, ... up to 200 ms as it keeps refusing; times 1 to 1.5 at random, so that
  /// clients refused together do not come back together.
  std::chrono::microseconds retryWait(uint32_t retries, uint32_t afterMs) {
    const double backoffMs = double(1u << std::min(retries, 8u));
    const double ms = std::max(double(afterMs), std::min(backoffMs, 200.0));
    std::uniform_real_distribution<double> jitter(1.0, 1.5);
    return std::chrono::microseconds(int64_t(ms * 1000 * jitter(rng)));
  }
  std::minstd_rand rng{std::random_device{}()};  ///< SDK thread only (retryWait)

  /// The backlog's next request, when the one before it was answered and its wait is over
  /// (SDK thread); returns when to look again (Clock::time_point::max(): at the next reply).
  Clock::time_point sendBacklog() {
    uint64_t s = 0;
    std::shared_ptr<const protocol::Bytes> bytes;
    {
      std::lock_guard<std::mutex> lk(pendMutex);
      if (backlogSeq != 0 && !pending.count(backlogSeq)) backlogSeq = 0;  // failed, expired
      if (held == 0 || backlogSeq != 0) return Clock::time_point::max();
      auto it = std::find_if(pending.begin(), pending.end(),
                             [](const auto& e) { return e.second.held; });
      if (it == pending.end()) {  // never expected: the count is kept with the flags
        held = 0;
        return Clock::time_point::max();
      }
      if (it->second.sendAt > Clock::now()) return it->second.sendAt;
      s = it->first;
      bytes = it->second.bytes;
      it->second.held = false;
      it->second.sentWithServer = serversMatched.load() > 0;
      --held;
      backlogSeq = s;
    }
    dds_return_t rc;
    {
      std::lock_guard<std::mutex> lk(writeMutex);
      proveToNewDaemons(false);
      rc = cmdWriter.write(clientId, *bytes, s);
    }
    if (rc >= 0) return Clock::time_point::max();
    Pending p;
    {
      std::lock_guard<std::mutex> lk(pendMutex);
      auto it = pending.find(s);
      if (it == pending.end()) return Clock::now();
      p = std::move(it->second);
      pending.erase(it);
      backlogSeq = 0;
    }
    Error e(ErrorCode::Transport, "dds_write on phys/cmd: " + dds::error(rc));
    p.done(nullptr, &e);
    return Clock::now();  // the next one now
  }

  void expire() {
    const auto now = Clock::now();
    std::vector<Pending> expired;
    {
      std::lock_guard<std::mutex> lk(pendMutex);
      for (auto it = pending.begin(); it != pending.end();) {
        if (it->second.deadline <= now) {
          if (it->second.held) --held;
          if (it->second.parked) --parked;
          expired.push_back(std::move(it->second));
          it = pending.erase(it);
        } else {
          ++it;
        }
      }
    }
    if (expired.empty()) return;  // the usual case: runs after every wake-up
    Error e(ErrorCode::Timeout, "no reply from physd within the request's timeout (domain " +
                                    std::to_string(options.domain) + ")");
    Error behind(ErrorCode::Timeout,
                 "still waiting behind requests physd refused at the door (its rate and queue "
                 "budgets: docs/CLIENT.md \"Rate limits\") at the request's timeout");
    Error orphan(ErrorCode::Disconnected,
                 "the daemon that held its world is gone (DDS liveliness) and no daemon took the "
                 "world over before the request's timeout; nothing was sent");
    for (auto& p : expired) p.done(nullptr, p.held ? &behind : p.parked ? &orphan : &e);
  }

  void loop() {
    auto resendAt = Clock::time_point::max();
    while (!stop) {
      // Up to 50 ms, or until a refused command is due again.
      auto wait = std::chrono::milliseconds(50);
      if (resendAt != Clock::time_point::max())
        wait = std::clamp(std::chrono::ceil<std::chrono::milliseconds>(resendAt - Clock::now()),
                          std::chrono::milliseconds(0), wait);
      waitset.wait(DDS_MSECS(wait.count()));
      if (stop) break;
      takeReplies();
      takeStatus();
      takeEvents();
      takeStates();
      checkServers();
      expire();
      sendParked();
      followInterests();
      resendAt = sendBacklog();
    }
  }

  Subscription subscribe(uint32_t world, std::function<void(const StateFrame&)> fn,
                         uint32_t interest = 0, Interest spec = {}) {
    auto s = std::make_shared<Subscription::State>();
    s->world = world;
    s->interest = interest;
    s->spec = std::move(spec);
    s->fn = std::move(fn);
    s->owner = this;
    if (interest != 0) s->daemon = currentOwner(world);
    std::string err;
    if (!s->topic.create(participant, protocol::stateTopic(world, interest), &err) ||
        !s->reader.create(participant, s->topic, protocol::kStateReaderQos, &err))
      fail("state subscription", err);
    {
      std::lock_guard<std::mutex> lk(subsMutex);
      if (!waitset.attach(s->reader, &err)) fail("state subscription", err);
      subs.push_back(s);
    }
    waitset.wake();
    return Subscription(s);
  }

  void unsubscribe(const std::shared_ptr<Subscription::State>& s) {
    uint32_t interest = 0;
    {
      std::lock_guard<std::mutex> lk(subsMutex);
      waitset.detach(s->reader);
      subs.erase(std::remove(subs.begin(), subs.end(), s), subs.end());
      interest = s->interest;
    }
    if (interest != 0) {
      // physd drops the interest's stream; nobody waits for the answer.
      CommandBuilder b;
      b.unsubscribe(interest);
      send(b, s->world, options.requestTimeout, [](const wire::Reply*, const Error*) {});
    }
  }
};

// ---------------------------------------------------------------------------------------------
// Subscription

Subscription::~Subscription() {
  reset();
}
Subscription::Subscription(Subscription&& o) noexcept : state_(std::move(o.state_)) {}
Subscription& Subscription::operator=(Subscription&& o) noexcept {
  if (this != &o) {
    reset();
    state_ = std::move(o.state_);
  }
  return *this;
}

void Subscription::reset() {
  if (!state_) return;
  {
    std::lock_guard<std::mutex> lk(state_->ownerMutex);
    if (state_->owner) state_->owner->unsubscribe(state_);
    state_->owner = nullptr;
  }
  {
    // The SDK thread may be inside the callback with a copy of the list of subscriptions:
    // wait for it, and stop the next (from inside the callback itself: no wait).
    std::lock_guard<std::recursive_mutex> calling(state_->fnMutex);
    state_->fnStopped = true;
  }
  state_.reset();
}

uint32_t Subscription::world() const {
  return state_ ? state_->world : 0;
}

std::optional<StateFrame> Subscription::latest() const {
  if (!state_) return std::nullopt;
  std::lock_guard<std::mutex> lk(state_->m);
  if (!state_->deliveredBodies) return std::nullopt;
  return state_->handOut();
}

std::optional<StateFrame> Subscription::waitForFrame(uint64_t afterTick,
                                                     std::chrono::milliseconds timeout,
                                                     uint64_t epoch) {
  if (!state_) return std::nullopt;
  std::unique_lock<std::mutex> lk(state_->m);
  // What afterTick refers to: the caller's epoch, or that of the last frame it was given (a
  // frame of a newer epoch delivered meanwhile is then after it, whatever its tick: the
  // world's ticks started again, and a caller waiting for the old ones would wait for
  // nothing). Given none yet, afterTick 0 takes the first frame (a world just created or
  // reset is at tick 0).
  const bool first = afterTick == 0 && epoch == 0 && !state_->handedOut;
  if (epoch == 0) epoch = state_->handedEpoch;
  const bool inCallback = std::this_thread::get_id() == state_->delivering;
  auto ready = [&] {
    return state_->deliveredBodies && (state_->settled || inCallback) &&
           (first || state_->delivered.tick > afterTick ||
            (epoch != 0 && state_->delivered.epoch != epoch));
  };
  state_->cv.wait_for(lk, timeout, ready);
  if (ready()) return state_->handOut();
  return std::nullopt;
}

uint64_t Subscription::framesSkipped() const {
  if (!state_) return 0;
  std::lock_guard<std::mutex> lk(state_->m);
  return state_->skipped;
}

uint64_t Subscription::staleChunks() const {
  if (!state_) return 0;
  std::lock_guard<std::mutex> lk(state_->m);
  return state_->stale;
}

uint64_t Subscription::framesReceived() const {
  if (!state_) return 0;
  std::lock_guard<std::mutex> lk(state_->m);
  return state_->frames;
}

// ---------------------------------------------------------------------------------------------
// Client

Client::Client(ClientOptions options) : impl_(std::make_unique<Impl>(std::move(options))) {}
Client::~Client() = default;

ServerInfo Client::connect() {
  const auto end = Clock::now() + impl_->options.connectTimeout;
  // The daemon's command reader and reply writer matched, then Hello (retried: the daemon's
  // reply writer may not have matched our reader yet when the first one arrives).
  while (Clock::now() < end) {
    if (impl_->serversMatched.load() > 0 && impl_->replyReader.matched() > 0) {
      auto left = std::chrono::duration_cast<std::chrono::milliseconds>(end - Clock::now());
      auto f = impl_->hello(
          {std::clamp(left, std::chrono::milliseconds(1), std::chrono::milliseconds(1500))});
      try {
        ServerInfo i = f.get();
        impl_->everConnected = true;
        // The daemons' status (transient-local: it comes as the status reader matches), so
        // that createWorld can place a world and listWorlds reach every daemon from the
        // start: one daemon's (for up to 2 s), then for up to 2 s more every daemon's that
        // is matched or that a sampled daemon names as its peer. Discovery is incremental:
        // Hello may be answered while a third daemon's reader has not matched yet, and its
        // peers say it exists. (A reader of phys/cmd that is not a daemon publishes no
        // status, nor does a daemon killed moments ago whose reader is still matched; under a
        // sanitizer a status comes 0.5-1 s after its daemon's reader matched.)
        auto sampled = [&](bool all) {
          std::lock_guard<std::mutex> lk(impl_->infoMutex);
          const auto& views = impl_->daemonViews;
          if (!all) return !views.empty();
          if (views.size() < impl_->serversMatched.load()) return false;
          for (const auto& [id, v] : impl_->liveDaemons())
            for (uint64_t p : v->status.peers)
              if (!views.count(p)) return false;
          return true;
        };
        const auto one = std::min(end, Clock::now() + std::chrono::seconds(2));
        while (Clock::now() < one && !sampled(false))
          std::this_thread::sleep_for(std::chrono::milliseconds(5));
        const auto all = std::min(end, Clock::now() + std::chrono::seconds(2));
        while (Clock::now() < all && !sampled(true))
          std::this_thread::sleep_for(std::chrono::milliseconds(5));
        return i;
      } catch (const Error& e) {
        if (e.code() != ErrorCode::Timeout && e.code() != ErrorCode::Disconnected) throw;
      }
    } else {
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
  }
  throw Error(ErrorCode::Timeout,
              "no physd answered Hello on domain " + std::to_string(impl_->options.domain) +
                  " within " + std::to_string(impl_->options.connectTimeout.count()) + " ms");
}

bool Client::connected() const {
  return impl_->helloOk && impl_->serversMatched.load() > 0;
}
uint64_t Client::reconnects() const {
  return impl_->reconnects;
}
uint64_t Client::clientId() const {
  return impl_->clientId;
}
const ClientOptions& Client::options() const {
  return impl_->options;
}
ServerInfo Client::server() const {
  std::lock_guard<std::mutex> lk(impl_->infoMutex);
  return impl_->server;
}

std::future<ServerInfo> Client::hello(CallOptions o) {
  return impl_->hello(o);
}

std::future<WorldHandle> Client::createWorld(const CreateWorldArgs& args, CallOptions o) {
  CommandBuilder b;
  b.createWorld(args);
  if (!o.daemon) o.daemon = impl_->placeWorld();
  const uint64_t daemon = o.daemon;
  return impl_->request<WorldHandle>(b, 0, o, [this, daemon](const wire::Reply& r) {
    if (daemon) {
      std::lock_guard<std::mutex> lk(impl_->infoMutex);
      auto it = impl_->daemonViews.find(daemon);
      if (it != impl_->daemonViews.end()) it->second.placed[r.world()] = Clock::now();
    }
    return WorldHandle(this, r.world());
  });
}

namespace {
std::vector<WorldSummary> worldList(const wire::Reply& r) {
  std::vector<WorldSummary> v;
  auto* l = r.result_as_WorldList();
  if (!l) throw Error(ErrorCode::BadReply, "list_worlds reply without WorldList");
  if (l->worlds())
    for (auto* w : *l->worlds()) v.push_back(toSummary(*w));
  return v;
}
}  // namespace

std::future<std::vector<WorldSummary>> Client::listWorlds(CallOptions o) {
  const std::vector<uint64_t> daemons =
      o.daemon ? std::vector<uint64_t>{o.daemon} : impl_->clusterDaemons();
  if (daemons.size() <= 1) {
    if (!daemons.empty()) o.daemon = daemons[0];
    CommandBuilder b;
    b.listWorlds();
    Impl* impl = impl_.get();
    return impl_->request<std::vector<WorldSummary>>(b, 0, o, [impl](const wire::Reply& r) {
      std::vector<WorldSummary> v = worldList(r);
      impl->learnOwners(v);
      return v;
    });
  }
  // A domain of daemons: each lists its own; the answer is all of them, by world id, or the
  // first error.
  struct Gather {
    std::mutex m;
    std::promise<std::vector<WorldSummary>> promise;
    std::vector<WorldSummary> worlds;
    size_t left = 0;
    bool done = false;
  };
  auto g = std::make_shared<Gather>();
  g->left = daemons.size();
  auto fut = g->promise.get_future();
  for (uint64_t d : daemons) {
    CommandBuilder b;
    b.listWorlds();
    impl_->send(
        b, 0, impl_->timeoutOf(o),
        [g, impl = impl_.get()](const wire::Reply* r, const Error* e) {
          std::lock_guard<std::mutex> lk(g->m);
          if (g->done) return;
          try {
            if (e) throw *e;
            if (r->status() != wire::StatusCode::Ok)
              throw Error(ErrorCode(uint8_t(r->status())), str(r->message()),
                          r->retry_after_ms());
            std::vector<WorldSummary> v = worldList(*r);
            impl->learnOwners(v);
            g->worlds.insert(g->worlds.end(), v.begin(), v.end());
            if (--g->left > 0) return;
            // By id; a world listed twice (a move ending: its old daemon says where it is
            // going, the new one holds it) once, as its new daemon lists it.
            std::sort(g->worlds.begin(), g->worlds.end(),
                      [](const WorldSummary& a, const WorldSummary& b) {
                        return a.world != b.world ? a.world < b.world
                                                  : (a.movingTo == 0) > (b.movingTo == 0);
                      });
            g->worlds.erase(std::unique(g->worlds.begin(), g->worlds.end(),
                                        [](const WorldSummary& a, const WorldSummary& b) {
                                          return a.world == b.world;
                                        }),
                            g->worlds.end());
            g->done = true;
            g->promise.set_value(std::move(g->worlds));
          } catch (...) {
            g->done = true;
            g->promise.set_exception(std::current_exception());
          }
        },
        d);
  }
  return fut;
}

WorldHandle Client::worldNamed(const std::string& name, CallOptions o) {
  for (const WorldSummary& w : listWorlds(o).get())
    if (w.name == name) return WorldHandle(this, w.world);
  throw Error(ErrorCode::NotFound, "no world named '" + name + "'");
}

std::optional<ServerStatus> Client::latestStatus() const {
  std::lock_guard<std::mutex> lk(impl_->infoMutex);
  return impl_->status;
}

std::vector<DaemonInfo> Client::daemons() const {
  std::lock_guard<std::mutex> lk(impl_->infoMutex);
  std::vector<DaemonInfo> out;
  const auto now = Clock::now();
  for (const auto& [id, v] : impl_->liveDaemons()) {
    DaemonInfo d;
    d.id = id;
    d.name = v->status.serverName;
    d.cluster = v->status.cluster;
    d.worlds = v->worlds();
    for (const WorldSummary& w : v->status.worlds) d.awakeBodies += w.awakeBodies;
    d.sinceSampleS = std::chrono::duration<double>(now - v->seen).count();
    d.peers = v->status.peers;
    out.push_back(std::move(d));
  }
  return out;
}

uint64_t Client::duplicateReplies() const {
  return impl_->duplicates.load();
}

Subscription Client::subscribe(uint32_t world, std::function<void(const StateFrame&)> fn) {
  return impl_->subscribe(world, std::move(fn));
}

void Client::onEvent(std::function<void(const Event&)> fn) {
  std::lock_guard<std::mutex> lk(impl_->infoMutex);
  impl_->eventFn = std::move(fn);
}

std::vector<Event> Client::recentEvents() const {
  std::lock_guard<std::mutex> lk(impl_->infoMutex);
  return {impl_->events.begin(), impl_->events.end()};
}

// ---------------------------------------------------------------------------------------------
// WorldHandle

namespace {
std::vector<uint64_t> bodyIds(const wire::Reply& r) {
  return ids(r).bodies;
}
std::vector<uint64_t> jointIds(const wire::Reply& r) {
  return ids(r).joints;
}
}  // namespace

#define PHYS_WORLD_ACK(builderCall) \
  CommandBuilder b;                 \
  b.builderCall;                    \
  return client_->impl_->ackRequest(b, id_, o)

std::future<Ack> WorldHandle::destroy(CallOptions o) {
  PHYS_WORLD_ACK(destroyWorld());
}
std::future<Ack> WorldHandle::reset(CallOptions o) {
  PHYS_WORLD_ACK(resetWorld());
}

std::future<Ids> WorldHandle::loadScene(std::string_view sceneName, CallOptions o) {
  CommandBuilder b;
  b.loadSceneNamed(sceneName);
  return client_->impl_->request<Ids>(b, id_, o, ids);
}
std::future<Ids> WorldHandle::loadSceneJson(std::string_view json, CallOptions o) {
  CommandBuilder b;
  b.loadSceneJson(json);
  return client_->impl_->request<Ids>(b, id_, o, ids);
}
std::future<std::vector<uint64_t>> WorldHandle::spawn(std::span<const phys::BodyDef> bodies,
                                                      CallOptions o) {
  CommandBuilder b;
  b.spawnBodies(bodies);
  return client_->impl_->request<std::vector<uint64_t>>(b, id_, o, bodyIds);
}
std::future<std::vector<uint64_t>> WorldHandle::spawn(const phys::BodyDef& body, CallOptions o) {
  return spawn(std::span<const phys::BodyDef>(&body, 1), o);
}
std::future<Ack> WorldHandle::removeBodies(std::span<const uint64_t> ids, CallOptions o) {
  PHYS_WORLD_ACK(removeBodies(ids));
}
std::future<std::vector<uint64_t>> WorldHandle::addJoints(std::span<const phys::JointDef> joints,
                                                          CallOptions o) {
  CommandBuilder b;
  b.addJoints(joints);
  return client_->impl_->request<std::vector<uint64_t>>(b, id_, o, jointIds);
}
std::future<Ack> WorldHandle::removeJoints(std::span<const uint64_t> ids, CallOptions o) {
  PHYS_WORLD_ACK(removeJoints(ids));
}
std::future<Ack> WorldHandle::setPose(uint64_t body, phys::Vec3 position, phys::Quat rotation,
                                      CallOptions o) {
  PHYS_WORLD_ACK(setBodyPose(body, position, rotation));
}
std::future<Ack> WorldHandle::setVelocity(uint64_t body, phys::Vec3 linear, phys::Vec3 angular,
                                          CallOptions o) {
  PHYS_WORLD_ACK(setBodyVelocity(body, linear, angular));
}
std::future<Ack> WorldHandle::applyForce(uint64_t body, phys::Vec3 force, phys::Vec3 point,
                                         PointFrame frame, CallOptions o) {
  PHYS_WORLD_ACK(applyForce(body, force, point, frame));
}
std::future<Ack> WorldHandle::applyImpulse(uint64_t body, phys::Vec3 impulse, phys::Vec3 point,
                                           PointFrame frame, CallOptions o) {
  PHYS_WORLD_ACK(applyImpulse(body, impulse, point, frame));
}
std::future<Ack> WorldHandle::applyTorque(uint64_t body, phys::Vec3 torque, CallOptions o) {
  PHYS_WORLD_ACK(applyTorque(body, torque));
}
std::future<Ack> WorldHandle::setMaterial(std::span<const uint64_t> bodies, const phys::Material& m,
                                          CallOptions o) {
  PHYS_WORLD_ACK(setMaterial(bodies, m));
}
std::future<Ack> WorldHandle::setSolver(std::string_view preset, const SolverOverrides& overrides,
                                        CallOptions o) {
  PHYS_WORLD_ACK(setSolver(preset, overrides));
}
std::future<Ack> WorldHandle::step(uint32_t n, CallOptions o) {
  PHYS_WORLD_ACK(step(n));
}
std::future<Ack> WorldHandle::run(float rateHz, CallOptions o) {
  PHYS_WORLD_ACK(run(rateHz));
}
std::future<Ack> WorldHandle::move(uint64_t daemon, CallOptions o) {
  PHYS_WORLD_ACK(moveWorld(daemon));
}
std::future<Ack> WorldHandle::pause(CallOptions o) {
  PHYS_WORLD_ACK(pause());
}

std::future<Ack> WorldHandle::setAccess(std::span<const uint64_t> editors, bool shared,
                                        CallOptions o) {
  PHYS_WORLD_ACK(setAccess(editors, shared));
}

std::future<StateFrame> WorldHandle::queryState(std::span<const uint64_t> ids, uint32_t first,
                                                uint32_t maxCount, CallOptions o) {
  CommandBuilder b;
  b.queryState(ids, first, maxCount);
  return client_->impl_->request<StateFrame>(b, id_, o, [](const wire::Reply& r) {
    auto* s = r.result_as_StateResult();
    if (!s) throw Error(ErrorCode::BadReply, "query_state reply without StateResult");
    StateFrame f;
    f.world = r.world();
    f.tick = r.tick();
    f.time = s->time();
    f.total = s->total();
    f.stampNs = s->stamp_ns();
    f.epoch = s->epoch();
    if (s->bodies())
      for (auto* b : *s->bodies()) f.bodies.push_back(toState(*b));
    return f;
  });
}

std::future<Bytes> WorldHandle::saveSnapshot(CallOptions o) {
  CommandBuilder b;
  b.saveSnapshot({}, true);
  return client_->impl_->request<Bytes>(b, id_, o, [](const wire::Reply& r) {
    auto* s = r.result_as_SnapshotResult();
    if (!s || !s->snapshot())
      throw Error(ErrorCode::BadReply, "save_snapshot reply without snapshot bytes");
    return Bytes(s->snapshot()->begin(), s->snapshot()->end());
  });
}
std::future<Ack> WorldHandle::saveSnapshotFile(std::string_view file, CallOptions o) {
  PHYS_WORLD_ACK(saveSnapshot(file, false));
}
std::future<Ack> WorldHandle::restoreSnapshot(std::span<const uint8_t> snapshot, CallOptions o) {
  PHYS_WORLD_ACK(restoreSnapshot(snapshot));
}
std::future<Ack> WorldHandle::restoreSnapshotFile(std::string_view file, CallOptions o) {
  PHYS_WORLD_ACK(restoreSnapshotFile(file));
}

std::future<Ack> WorldHandle::setWorld(const WorldOverrides& settings, CallOptions o) {
  PHYS_WORLD_ACK(setWorld(settings));
}
std::future<Ack> WorldHandle::setGravity(phys::Vec3 gravity, CallOptions o) {
  WorldOverrides s;
  s.gravity = gravity;
  return setWorld(s, o);
}
std::future<Ack> WorldHandle::setTimeStep(float seconds, CallOptions o) {
  WorldOverrides s;
  s.timeStep = seconds;
  return setWorld(s, o);
}
std::future<Ack> WorldHandle::setSleep(const phys::SleepSettings& sleep, CallOptions o) {
  WorldOverrides s;
  s.sleep = sleep.enabled;
  s.sleepTime = sleep.time;
  s.sleepLinearSpeed = sleep.linearSpeed;
  s.sleepAngularSpeed = sleep.angularSpeed;
  return setWorld(s, o);
}

#undef PHYS_WORLD_ACK

std::future<WorldSettings> WorldHandle::settings(CallOptions o) {
  CommandBuilder b;
  b.getWorld();
  return client_->impl_->request<WorldSettings>(b, id_, o, [](const wire::Reply& r) {
    auto* s = r.result_as_WorldSettingsResult();
    if (!s || !s->settings() || !s->solver())
      throw Error(ErrorCode::BadReply, "get_world reply without WorldSettingsResult");
    WorldSettings w;
    protocol::applyOverrides(protocol::toOverrides(*s->settings()), &w.def);
    protocol::applySolverSettings(*s->solver(), &w.def.solver);
    w.preset = str(s->preset());
    w.tick = r.tick();
    return w;
  });
}

std::future<BodiesPage> WorldHandle::getBodies(std::span<const uint64_t> ids, uint32_t first,
                                               uint32_t maxCount, CallOptions o) {
  CommandBuilder b;
  b.getBodies(ids, first, maxCount);
  return client_->impl_->request<BodiesPage>(b, id_, o, [](const wire::Reply& r) {
    auto* s = r.result_as_BodiesResult();
    if (!s) throw Error(ErrorCode::BadReply, "get_bodies reply without BodiesResult");
    BodiesPage p;
    p.tick = r.tick();
    p.total = s->total();
    if (s->bodies()) {
      protocol::HullCache hulls;
      p.bodies.resize(s->bodies()->size());
      for (uint32_t i = 0; i < s->bodies()->size(); ++i) {
        protocol::Status st = protocol::toBodyInfo(
            *s->bodies()->Get(i), &p.bodies[i],
            "bodies_result.bodies[" + std::to_string(i) + "]", &hulls);
        if (!st.ok()) throw Error(ErrorCode::BadReply, st.message);
      }
    }
    return p;
  });
}

std::future<JointsPage> WorldHandle::getJoints(std::span<const uint64_t> ids, uint32_t first,
                                               uint32_t maxCount, CallOptions o) {
  CommandBuilder b;
  b.getJoints(ids, first, maxCount);
  return client_->impl_->request<JointsPage>(b, id_, o, [](const wire::Reply& r) {
    auto* s = r.result_as_JointsResult();
    if (!s) throw Error(ErrorCode::BadReply, "get_joints reply without JointsResult");
    JointsPage p;
    p.tick = r.tick();
    p.total = s->total();
    if (s->joints())
      for (const wire::JointEntry* e : *s->joints())
        if (e->def()) p.joints.push_back({e->id(), protocol::toJointDef(*e->def())});
    return p;
  });
}

std::future<std::vector<BodyInfo>> WorldHandle::allBodies(CallOptions o) {
  WorldHandle w = *this;
  return std::async(std::launch::async, [w, o]() mutable {
    std::vector<BodyInfo> out;
    for (;;) {
      BodiesPage p = w.getBodies({}, uint32_t(out.size()), 0, o).get();
      for (BodyInfo& b : p.bodies) out.push_back(std::move(b));
      if (p.bodies.empty() || out.size() >= p.total) return out;
    }
  });
}

std::future<std::vector<JointInfo>> WorldHandle::allJoints(CallOptions o) {
  WorldHandle w = *this;
  return std::async(std::launch::async, [w, o]() mutable {
    std::vector<JointInfo> out;
    for (;;) {
      JointsPage p = w.getJoints({}, uint32_t(out.size()), 0, o).get();
      for (JointInfo& j : p.joints) out.push_back(std::move(j));
      if (p.joints.empty() || out.size() >= p.total) return out;
    }
  });
}

Subscription WorldHandle::subscribe(std::function<void(const StateFrame&)> fn) {
  return client_->subscribe(id_, std::move(fn));
}

Subscription WorldHandle::subscribe(const Interest& interest,
                                    std::function<void(const StateFrame&)> fn, CallOptions o) {
  if (interest.all()) return subscribe(std::move(fn));
  CommandBuilder b;
  if (interest.region)
    b.subscribeRegion(interest.region->first, interest.region->second);
  else
    b.subscribeBodies(interest.bodies);
  const uint32_t id =
      client_->impl_->request<uint32_t>(b, id_, o, [](const wire::Reply& r) {
        auto* i = r.result_as_InterestResult();
        if (!i || i->interest() == 0)
          throw Error(ErrorCode::BadReply, "subscribe reply without an interest");
        return i->interest();
      }).get();
  return client_->impl_->subscribe(id_, std::move(fn), id, interest);
}

}  // namespace phys::client
