// Fuzz target: physd's apply path. Each input is a command payload as it would arrive on
// phys/cmd, decoded and applied by a ServerCore (no DDS) to a small world (fuzz_server.h);
// after a command that succeeded, the world is stepped and its frames, world info and status
// are produced as the tick thread would.
//
// Two servers, picked by the command's seq (an input that does not decode goes to the first):
//   even seq: ServerCore::applyBytes (a command applied at once, as the tests do), state
//             frames in full states with a rolling refresh;
//   odd seq:  the daemon's queue: submit(), processPending(), then advance() until the
//             world's Step job or LoadScene (built on a loader thread) is done; state frames
//             in compact states with whole keyframes.
//
// Every input starts from the same state: after a command that changed anything, the world is
// restored from the snapshot it was built with (same ids), other worlds are destroyed (by
// their owners), the interest, access and run state put back and written snapshot files
// removed, so a finding
// reproduces from its input alone.
//
// Besides crashes and sanitizer reports, it aborts when
//   - the server emits something its own codec rejects: every reply, state frame, world info
//     chunk, status sample and event is decoded with the default limits, as a client would;
//   - a command gets no reply, or one not addressed to it (client id, seq);
//   - a world edit (a batchable request or a Batch) is refused but changed the world: edits
//     are all-or-nothing.
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <optional>
#include <span>
#include <string>
#include <thread>

#include "fuzz_server.h"
#include "phys/protocol/convert.h"

namespace {

namespace fs = std::filesystem;
using phys::fuzz::FuzzServer;
using phys::fuzz::kClient;
using phys::fuzz::kWorld;
using phys::protocol::Bytes;
using phys::protocol::CommandBuilder;
using phys::server::ReliableMessage;

[[noreturn]] void die(const std::string& what) {
  std::fprintf(stderr, "fuzz_apply: %s\n", what.c_str());
  std::fflush(stderr);
  std::abort();
}

template <class T>
void mustDecode(const T& d, const char* what) {
  if (!d.ok())
    die(std::string("the server emitted ") + what + " its codec rejects: " +
        phys::protocol::toString(d.status.code) + ": " + d.status.message);
}

/// What a refused edit must leave as it was.
struct Fingerprint {
  uint64_t hash = 0, tick = 0, revision = 0;
  int bodies = 0, joints = 0;
  bool operator==(const Fingerprint&) const = default;
};

/// One fuzz server and what putting it back needs.
struct Instance {
  bool queued = false;
  std::string dir;  ///< its snapshot directory
  std::unique_ptr<FuzzServer> server;
  Bytes restore;  ///< RestoreSnapshot of the fuzz world's first state
  Fingerprint base;
  uint64_t seq = 1000;
  /// The reply to (key, seq) when drain() sees it go out.
  uint64_t wantKey = 0, wantSeq = 0;
  std::optional<Bytes> reply;

  Instance(bool queuedPath, std::string snapshotDir) : queued(queuedPath), dir(std::move(snapshotDir)) {
    build();
  }
  void build() {
    std::error_code ec;
    fs::remove_all(dir, ec);
    server = std::make_unique<FuzzServer>(dir, /*compact=*/queued);
    if (!server->ok()) die("set-up failed: " + server->error);
    restore = CommandBuilder().restoreSnapshot(server->snapshot).finish({kClient, 0, kWorld});
    drain();
    base = fingerprint();
  }
  phys::server::ServerCore& core() { return *server->core; }

  Fingerprint fingerprint() {
    const phys::server::ServerWorld* w = core().world(kWorld);
    if (!w) return {};
    return {w->world->stateHash(), w->tick, w->revision, w->world->bodyCount(),
            w->world->jointCount()};
  }

  /// Applies a harness command at once, as `client`; it must succeed.
  void must(CommandBuilder& b, uint32_t world, const char* what, uint64_t client = kClient) {
    ++seq;
    auto r = phys::protocol::decodeReply(
        core().applyBytes(b.finish({client, seq, world}), client, seq));
    mustDecode(r, "a reply");
    if (r->status() != phys::wire::StatusCode::Ok)
      die(std::string("reset: ") + what + " failed: " + (r->message() ? r->message()->str() : ""));
  }

  /// Everything the core queued for the publisher, decoded as a client would.
  void drain() {
    while (true) {
      auto item = core().out().pop(std::chrono::milliseconds(0));
      if (item.reliable) {
        const ReliableMessage& m = *item.reliable;
        for (const Bytes& b : m.chunks) {
          switch (m.type) {
            case ReliableMessage::Type::Reply:
              mustDecode(phys::protocol::decodeReply(b), "a reply");
              if (queued && m.key == wantKey && m.seq == wantSeq) {
                if (reply) die("two replies to one command");
                reply = b;
              }
              break;
            case ReliableMessage::Type::WorldInfo:
              mustDecode(phys::protocol::decodeWorldInfo(b), "world info");
              break;
            case ReliableMessage::Type::Status:
              mustDecode(phys::protocol::decodeServerStatus(b), "a status sample");
              break;
            case ReliableMessage::Type::Event:
              mustDecode(phys::protocol::decodeEvent(b), "an event");
              break;
            default:
              break;
          }
        }
      } else if (item.frame) {
        for (const Bytes& b : item.frame->chunks)
          mustDecode(phys::protocol::decodeStateFrame(b), "a state frame");
      } else {
        break;
      }
    }
  }

  bool anyBusy() {
    for (uint32_t id : core().worldIds())
      if (core().world(id)->busy()) return true;
    return false;
  }

  /// Whether the server is as every input finds it (world ids past 1 aside).
  bool pristine() {
    phys::server::ServerCore& c = core();
    const phys::server::ServerWorld* w = c.world(kWorld);
    return w && c.worldIds().size() == 1 && w->mode == phys::server::RunMode::Paused &&
           w->owner == kClient && w->editors.empty() && !w->shared &&
           w->interests.size() == 1 && w->interests.count(phys::fuzz::kInterest) &&
           w->nextInterest == phys::fuzz::kInterest + 1 && !anyBusy() && fingerprint() == base;
  }

  /// Back to the state every input starts from.
  void reset(bool filesWritten) {
    phys::server::ServerCore& c = core();
    if (!c.world(kWorld)) {  // destroyed: a fresh core (same ids)
      build();
      return;
    }
    for (uint32_t id : c.worldIds())
      if (id != kWorld) {
        const uint64_t owner = c.world(id)->owner;  // only the owner may destroy a world
        must(CommandBuilder().destroyWorld(), id, "destroy_world", owner ? owner : kClient);
      }
    phys::server::ServerWorld* w = c.world(kWorld);
    if (w->mode != phys::server::RunMode::Paused) must(CommandBuilder().pause(), kWorld, "pause");
    if (!w->editors.empty() || w->shared) must(CommandBuilder().setAccess({}, false), kWorld, "set_access");
    if (w->interests.size() != 1 || !w->interests.count(phys::fuzz::kInterest) ||
        w->nextInterest != phys::fuzz::kInterest + 1) {
      std::vector<uint32_t> ids;
      for (const auto& [id, in] : w->interests) ids.push_back(id);
      for (uint32_t id : ids) must(CommandBuilder().unsubscribe(id), kWorld, "unsubscribe");
      w->nextInterest = phys::fuzz::kInterest;  // so that the interest gets its id again
      must(CommandBuilder().subscribeRegion(phys::fuzz::kInterestLo, phys::fuzz::kInterestHi),
           kWorld, "subscribe");
    }
    if (filesWritten) {
      // Only the base snapshot stays, as it was (a save may have replaced it).
      std::error_code ec;
      for (const auto& e : fs::directory_iterator(dir, ec))
        if (e.path().filename() != phys::fuzz::kBaseSnapshotFile) fs::remove_all(e.path(), ec);
      must(CommandBuilder().restoreSnapshot(server->snapshot), kWorld, "restore");
      must(CommandBuilder().saveSnapshot(phys::fuzz::kBaseSnapshotFile, false), kWorld,
           "save the base snapshot");
    }
    auto r = phys::protocol::decodeReply(c.applyBytes(restore, kClient, 0));
    mustDecode(r, "a reply");
    if (r->status() != phys::wire::StatusCode::Ok)
      die("reset: restore failed: " + (r->message() ? r->message()->str() : std::string()));
    drain();
    base = fingerprint();
  }

  void run(std::span<const uint8_t> input, const phys::protocol::Decoded<phys::wire::Command>& decoded,
           bool verbose) {
    phys::server::ServerCore& c = core();
    // The envelope key must be the command's client id for the command to be applied; an
    // input that does not decode is answered to a fixed key.
    const uint64_t key = decoded.ok() ? decoded->client_id() : kClient;
    const uint64_t cseq = decoded.ok() ? decoded->seq() : 1;
    const phys::wire::Request type =
        decoded.ok() ? decoded->request_type() : phys::wire::Request::NONE;
    bool checkEdit = true;  // the world as the command left it, before any step
    if (!queued) {
      reply = c.applyBytes(input, key, cseq);
    } else {
      wantKey = key;
      wantSeq = cseq;
      reply.reset();
      phys::server::Incoming in;
      in.envelopeKey = key;
      in.envelopeSeq = cseq;
      in.bytes = input.size();
      in.command = phys::protocol::decodeCommand(std::vector<uint8_t>(input.begin(), input.end()),
                                                 c.config().limits);
      c.submit(std::move(in));
      c.processPending();
      drain();
      // A Step longer than a slice, or a LoadScene on its loader thread: the tick thread's
      // advance() carries it on and answers it.
      for (int i = 0; !reply && anyBusy(); ++i) {
        checkEdit = false;
        if (i > 200000) die("a world's job never ends");
        c.advance(1.0 / 60);
        drain();
        if (!reply && anyBusy()) std::this_thread::sleep_for(std::chrono::microseconds(20));
      }
      if (!reply) die("no reply to the command");
    }
    auto r = phys::protocol::decodeReply(*reply);
    mustDecode(r, "a reply");
    if (r->client_id() != key || r->seq() != cseq) die("the reply is not addressed to the command");
    const bool ok = r->status() == phys::wire::StatusCode::Ok;
    if (verbose)
      std::fprintf(stderr, "%s %s: %s %s\n", queued ? "queued" : "direct",
                   decoded.ok() ? phys::protocol::requestName(type) : "(undecodable)",
                   phys::protocol::toString(r->status()), r->message() ? r->message()->c_str() : "");
    if (checkEdit && !ok && decoded.ok() && decoded->world() == kWorld &&
        (phys::protocol::isBatchable(type) || type == phys::wire::Request::Batch) &&
        !(fingerprint() == base))
      die(std::string("a refused ") + phys::protocol::requestName(type) +
          " changed the world: " + (r->message() ? r->message()->str() : ""));
    // A reply's snapshot is what a client restores: it must decode and convert.
    if (auto* s = r->result_as_SnapshotResult(); s && s->snapshot() && s->snapshot()->size()) {
      auto snap = phys::protocol::decodeSnapshot(
          std::span<const uint8_t>(s->snapshot()->data(), s->snapshot()->size()));
      mustDecode(snap, "a snapshot");
      phys::protocol::SnapshotData data;
      (void)phys::protocol::toSnapshotData(*snap, &data);
    }
    // A save that failed may have left a file as well (it should not).
    const bool saved = decoded.ok() && type == phys::wire::Request::SaveSnapshot;
    if (!ok && !saved && pristine()) {
      drain();
      wantKey = wantSeq = 0;
      return;  // nothing changed: nothing to step or put back
    }
    // The tick thread's work: a step of the fuzz world, time for the running ones, frames,
    // world info and a status sample.
    if (c.world(kWorld) && !c.world(kWorld)->busy()) (void)c.stepWorld(kWorld, 1);
    c.advance(1.0 / 60);
    c.publishWorldInfo();
    c.publishStatus();
    drain();
    reset(saved);
    wantKey = wantSeq = 0;
  }
};

struct Harness {
  std::string dir;
  std::unique_ptr<Instance> direct, queued;
  /// PHYS_FUZZ_VERBOSE=1: each input's request and reply status on stderr (checking seeds).
  const bool verbose = std::getenv("PHYS_FUZZ_VERBOSE") != nullptr;

  Harness() {
    dir = (fs::temp_directory_path() / ("phys_fuzz_" + std::to_string(getpid()))).string();
    direct = std::make_unique<Instance>(false, dir + "/direct");
    queued = std::make_unique<Instance>(true, dir + "/queued");
  }

  void run(std::span<const uint8_t> input) {
    // Decoded with the servers' limits, only to pick the server and the envelope key.
    auto decoded = phys::protocol::decodeCommand(input, direct->core().config().limits);
    Instance& in = decoded.ok() && decoded->seq() % 2 ? *queued : *direct;
    in.run(input, decoded, verbose);
  }
};

Harness* harness() {
  static Harness* h = [] {
    auto* p = new Harness();  // never deleted: reachable until exit
    std::atexit([] {
      std::error_code ec;
      fs::remove_all(harness()->dir, ec);
    });
    return p;
  }();
  return h;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  harness()->run(std::span<const uint8_t>(data, size));
  return 0;
}
