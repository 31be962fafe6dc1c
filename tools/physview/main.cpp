// physview: a live 3D viewer of physd's worlds in the browser (docs/VIEWER.md).
//
//   physview [--domain N] [--config XML] [--identity NAME [--security-dir DIR]]
//            [--listen ADDR] [--port P] [--web DIR] [--world NAME] [--max-fps F] [--stats S]
//
// A client of the SDK that serves the page (tools/physview/web, bundled at build time) and
// streams the chosen world's state frames to it over a WebSocket (/ws) with CivetWeb: one
// binary message a frame (messages.h), the bodies' shapes in a binary message of their own
// when they first appear (from the world's snapshot: frames carry no shapes), commands from
// the page (select, run, pause, step, spawn) as small JSON text messages.
//
// Threads: CivetWeb's thread per connection reads the page's commands and runs them (one
// request at a time, waiting for physd's answer); the SDK's thread encodes each frame of the
// connection's subscription into the connection's one pending frame (latest wins: a frame
// the browser has not taken yet is replaced, never queued); a sender thread per connection
// writes the pending frame and the queued text and shapes messages; a worker thread per
// connection asks for the world's snapshot when a frame holds bodies the page has no shapes
// for, and for the state of a world that sends no frames (a paused one) when phys/status says
// that it changed.
#include <civetweb.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <atomic>
#include <cctype>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <deque>
#include <filesystem>
#include <fstream>
#include <limits>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <optional>
#include <sstream>
#include <string>
#include <thread>
#include <unordered_set>
#include <vector>

#include "messages.h"
#include "phys/client/client.h"

namespace pc = phys::client;
using json = nlohmann::json;
using Clock = std::chrono::steady_clock;

namespace {

std::atomic<bool> gStop{false};
void onSignal(int) {
  gStop = true;
}

bool readFile(const std::string& path, std::string* out) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return false;
  std::stringstream ss;
  ss << in.rdbuf();
  *out = ss.str();
  return true;
}

struct Options {
  std::string world = "default";  ///< selected first when it exists (else the first world)
  double maxFps = 90;             ///< frames a second to one page at most
  std::chrono::milliseconds timeout{10000};
};

/// Pages (WebSocket connections) served at once: each holds a CivetWeb thread, two threads of
/// its own and a subscription; the next one is refused (503).
constexpr int kMaxPages = 8;
/// The largest message a page may send (its commands are a few dozen bytes): a larger one
/// closes the connection.
constexpr size_t kMaxIncoming = 4096;

/// JSON text for the page; a string that is not UTF-8 (a world's name) is repaired, not
/// thrown on (nlohmann's dump throws type_error 316).
std::string dumpJson(const json& j) {
  return j.dump(-1, ' ', false, json::error_handler_t::replace);
}

void logError(const char* where, const std::exception& e) {
  std::fprintf(stderr, "physview: %s: %s\n", where, e.what());
}

/// Counters over every connection (--stats).
struct Stats {
  std::atomic<uint64_t> framesIn{0}, framesSent{0}, framesReplaced{0}, bytesSent{0},
      shapeMessages{0}, commands{0};
  std::atomic<int> sessions{0};
};

class Session;

struct Bridge {
  pc::Client& client;
  Options options;
  Stats stats;
  std::string listen;         ///< --listen: a host name pages may use besides loopback's
  std::atomic<int> pages{0};  ///< connections accepted by wsConnect, not yet closed
};

/// One browser connection: its world, subscription, pending frame and outgoing messages.
class Session : public std::enable_shared_from_this<Session> {
 public:
  Session(Bridge& bridge, mg_connection* conn) : bridge_(bridge), conn_(conn) {}

  /// Throws (std::system_error: no thread) only before the page was told anything.
  void start() {
    ++bridge_.stats.sessions;  // first: stop() counts it down whatever start() did
    sender_ = std::thread([this] { sendLoop(); });
    worker_ = std::thread([this] { workLoop(); });
    json hello = {{"type", "hello"},
                  {"server", bridge_.client.server().name},
                  {"version", bridge_.client.server().version}};
    pushText(dumpJson(hello));
    // The first world: the one named by --world, else the first one physd lists.
    try {
      auto worlds = bridge_.client.listWorlds({bridge_.options.timeout}).get();
      uint32_t pick = 0;
      for (const auto& w : worlds)
        if (w.name == bridge_.options.world) pick = w.world;
      if (!pick && !worlds.empty()) pick = worlds.front().world;
      if (pick) select(pick);
      pushWorlds();
    } catch (const std::exception& e) {
      logError("start", e);
      pushError("list", e);
    }
  }

  /// Ends the subscription and the threads; the connection is closing (CivetWeb's close
  /// handler, its thread).
  void stop() {
    pc::Subscription old;
    {
      std::lock_guard<std::mutex> lk(m_);
      stop_ = true;
      ++epoch_;
      old = std::move(sub_);
    }
    cv_.notify_all();
    old.reset();
    if (sender_.joinable()) sender_.join();
    if (worker_.joinable()) worker_.join();
    --bridge_.stats.sessions;
  }

  /// A text message from the page: {"op": "select" | "run" | "pause" | "step" | "spawn" |
  /// "ping", ...}. Runs the request and waits for physd's answer (CivetWeb's thread).
  void command(std::string_view text) {
    ++bridge_.stats.commands;
    json j = json::parse(text, nullptr, false);
    if (j.is_discarded() || !j.is_object() || !j.contains("op") || !j["op"].is_string()) {
      pushText(dumpJson({{"type", "error"}, {"op", ""}, {"message", "not a command"}}));
      return;
    }
    const std::string op = j["op"];
    if (op == "ping") return;
    try {
      if (op == "select") {
        uint32_t id = 0;
        const json world = j.contains("world") ? j["world"] : json();
        if (world.is_string()) {
          id = bridge_.client.worldNamed(world.get<std::string>(), {bridge_.options.timeout}).id();
        } else if (world.is_number_unsigned()) {
          // World ids are u32 on the wire: a larger number is no world, not its low word.
          const uint64_t n = world.get<uint64_t>();
          if (n == 0 || n > std::numeric_limits<uint32_t>::max())
            throw pc::Error(pc::ErrorCode::InvalidArgument,
                            "select: world id " + std::to_string(n) + " out of range");
          id = uint32_t(n);
          // An id physd does not list (as of its newest phys/status) is refused, not
          // subscribed to: no frame would ever come. A name was just looked up by physd.
          if (std::optional<pc::ServerStatus> status = bridge_.client.latestStatus()) {
            const bool listed =
                std::any_of(status->worlds.begin(), status->worlds.end(),
                            [&](const pc::WorldSummary& w) { return w.world == id; });
            if (!listed)
              throw pc::Error(pc::ErrorCode::NotFound, "select: no world " + std::to_string(id));
          }
        } else {
          throw pc::Error(pc::ErrorCode::InvalidArgument, "select: world must be an id or a name");
        }
        select(id);
        pushText(dumpJson({{"type", "ack"}, {"op", op}, {"world", id}}));
        pushWorlds();
        return;
      }
      const uint32_t id = world();
      if (!id) throw pc::Error(pc::ErrorCode::NotFound, "no world selected");
      pc::WorldHandle w = bridge_.client.world(id);
      const pc::CallOptions call{bridge_.options.timeout};
      json ack = {{"type", "ack"}, {"op", op}, {"world", id}};
      if (op == "run") {
        const float rate = j.contains("rate") && j["rate"].is_number() ? float(j["rate"]) : 60.0f;
        ack["tick"] = w.run(rate, call).get().tick;
      } else if (op == "pause") {
        ack["tick"] = w.pause(call).get().tick;
      } else if (op == "step") {
        int n = j.contains("n") && j["n"].is_number_integer() ? int(j["n"]) : 1;
        n = std::clamp(n, 1, 1000);
        ack["tick"] = w.step(uint32_t(n), call).get().tick;
      } else if (op == "spawn") {
        phys::BodyDef def;
        if (!j.contains("at") || !j["at"].is_array() || j["at"].size() != 3)
          throw pc::Error(pc::ErrorCode::InvalidArgument, "spawn: at must be [x, y, z]");
        float at[3];
        for (int i = 0; i < 3; ++i) {
          if (!j["at"][i].is_number())
            throw pc::Error(pc::ErrorCode::InvalidArgument, "spawn: at must be numbers");
          at[i] = float(j["at"][i]);
          if (!std::isfinite(at[i]) || std::fabs(at[i]) > 1e4f)
            throw pc::Error(pc::ErrorCode::InvalidArgument, "spawn: at out of range");
        }
        def.position = {at[0], at[1], at[2]};
        const std::string shape =
            j.contains("shape") && j["shape"].is_string() ? j["shape"] : "box";
        phys::ShapeDef s;
        if (shape == "ball")
          s.geom = phys::ShapeGeom::sphere(0.4f);
        else if (shape == "box")
          s.geom = phys::ShapeGeom::box({0.4f, 0.4f, 0.4f});
        else
          throw pc::Error(pc::ErrorCode::InvalidArgument, "spawn: shape must be box or ball");
        def.shapes.push_back(s);
        def.name = "physview_" + shape;
        const std::vector<uint64_t> ids = w.spawn(def, call).get();
        ack["id"] = ids.empty() ? 0 : ids.front();
        ack["shape"] = shape;
        {
          // A paused world sends no frame: the page sees the body in the state asked for.
          std::lock_guard<std::mutex> lk(m_);
          if (Clock::now() - lastFrame_ > std::chrono::milliseconds(300)) needQuery_ = true;
        }
        cv_.notify_all();
      } else {
        throw pc::Error(pc::ErrorCode::InvalidArgument, "unknown op '" + op + "'");
      }
      pushText(dumpJson(ack));
    } catch (const pc::Error& e) {
      pushError(op, e);
    }
  }

  void pushError(const std::string& op, const std::string& message) {
    pushText(dumpJson({{"type", "error"}, {"op", op}, {"message", message}}));
  }

  /// An error text message to the page (pc::Error: with its code).
  void pushError(const std::string& op, const std::exception& e) {
    json j = {{"type", "error"}, {"op", op}};
    if (const auto* pe = dynamic_cast<const pc::Error*>(&e)) {
      j["code"] = pc::toString(pe->code());
      j["message"] = pe->message();
    } else {
      j["message"] = e.what();
    }
    pushText(dumpJson(j));
  }

 private:
  uint32_t world() {
    std::lock_guard<std::mutex> lk(m_);
    return world_;
  }

  /// Shows world id (0: none): a shapes reset for the page, then the world's frames.
  void select(uint32_t id) {
    pc::Subscription old;
    uint64_t epoch = 0;
    const uint64_t reconnects = bridge_.client.reconnects();
    const std::optional<pc::ServerStatus> status = bridge_.client.latestStatus();
    {
      std::lock_guard<std::mutex> lk(m_);
      epoch = ++epoch_;
      world_ = id;
      reconnects_ = reconnects;
      selectUptime_ = status ? status->uptimeS : -1.0;
      statusTick_ = 0;
      described_.clear();
      needDescribe_ = id != 0;
      haveFrame_ = false;
      // lastDescribe_ is kept: a page selecting again and again gets at most one snapshot a
      // kDescribePeriod, as for bodies it has no shapes for.
      lastFrame_ = Clock::now();
      queriedKey_ = {~0ull, ~0u};
      extras_ = {};
      old = std::move(sub_);
      // The reset goes ahead of every frame of the new world (the sender writes the outbox
      // first, and the old world's pending frame is dropped above), so the page never draws
      // them with the old world's shapes. Old shapes still queued are of no use now; dropping
      // them also keeps a page that selects in a loop from growing the outbox.
      outbox_.erase(
          std::remove_if(outbox_.begin(), outbox_.end(),
                         [](const Outgoing& o) { return o.opcode == MG_WEBSOCKET_OPCODE_BINARY; }),
          outbox_.end());
      Outgoing reset{MG_WEBSOCKET_OPCODE_BINARY, {}};
      physview::encodeShapes(id, physview::kShapesReset, {}, &reset.bytes);
      outbox_.push_back(std::move(reset));
    }
    cv_.notify_all();
    old.reset();  // outside the lock: callbacks in flight check the epoch
    if (!id) return;
    std::weak_ptr<Session> weak = weak_from_this();
    pc::Subscription sub = bridge_.client.subscribe(id, [weak, epoch](const pc::StateFrame& f) {
      // The SDK's thread: nothing may escape into it.
      try {
        if (auto self = weak.lock()) self->onFrame(f, epoch);
      } catch (const std::exception& e) {
        logError("frame", e);
      }
    });
    {
      std::lock_guard<std::mutex> lk(m_);
      if (epoch_ == epoch && !stop_) {
        sub_ = std::move(sub);
        sub = {};
      }
    }
    sub.reset();
    cv_.notify_all();
  }

  /// One complete tick of the selected world: the SDK's thread (a subscription's frame), or
  /// the worker's (a QueryState answer for a world that sends no frames: paused).
  void onFrame(const pc::StateFrame& f, uint64_t epoch, bool queried = false) {
    std::lock_guard<std::mutex> frameLock(frameMutex_);
    ++bridge_.stats.framesIn;
    physview::FrameExtras extras;
    {
      std::lock_guard<std::mutex> lk(m_);
      if (epoch != epoch_) return;
      extras = extras_;
      if (!queried) lastFrame_ = Clock::now();
    }
    physview::encodeFrame(f, extras, &scratch_);
    // Bodies the page may have no shapes for: only when the ids changed since the last frame.
    if (epoch != idsEpoch_) {
      lastIds_.clear();
      idsEpoch_ = epoch;
    }
    bool idsChanged = f.bodies.size() != lastIds_.size();
    for (size_t i = 0; !idsChanged && i < f.bodies.size(); ++i)
      idsChanged = f.bodies[i].id != lastIds_[i];
    if (idsChanged) {
      lastIds_.resize(f.bodies.size());
      for (size_t i = 0; i < f.bodies.size(); ++i) lastIds_[i] = f.bodies[i].id;
    }
    {
      std::lock_guard<std::mutex> lk(m_);
      if (epoch != epoch_) return;
      if (idsChanged || recheck_) {
        recheck_ = false;
        for (uint64_t id : lastIds_)
          if (!described_.count(id)) {
            needDescribe_ = true;
            break;
          }
      }
      scratch_.swap(pending_);
      if (haveFrame_) ++bridge_.stats.framesReplaced;
      haveFrame_ = true;
    }
    cv_.notify_all();
  }

  /// A text message for the page; with onlyFor, only while that world is the selected one
  /// (a worlds list made just before a select would name the world the page left).
  void pushText(std::string text, std::optional<uint32_t> onlyFor = std::nullopt) {
    {
      std::lock_guard<std::mutex> lk(m_);
      if (onlyFor && *onlyFor != world_) return;
      if (outbox_.size() >= 64) return;  // a page that reads nothing: drop, never grow
      outbox_.push_back({MG_WEBSOCKET_OPCODE_TEXT, std::vector<uint8_t>(text.begin(), text.end())});
    }
    cv_.notify_all();
  }

  /// The worlds from the newest phys/status sample (none yet: nothing), and this page's
  /// frame extras from its world's entry. The selected world is shown afresh when physd was
  /// greeted again (restarted: its ids may name other worlds now) or its tick went back (a
  /// snapshot loaded): the page's shapes are not that world's. A world gone from a sample
  /// newer than the selection is replaced by the --world one or the first (or none).
  void pushWorlds() {
    std::optional<pc::ServerStatus> status = bridge_.client.latestStatus();
    if (!status) return;
    const uint64_t reconnects = bridge_.client.reconnects();
    const uint32_t selected = world();
    const pc::WorldSummary* entry = nullptr;
    for (const pc::WorldSummary& w : status->worlds)
      if (w.world == selected) entry = &w;
    bool restarted = false, gone = false;
    {
      std::lock_guard<std::mutex> lk(m_);
      if (selected && world_ == selected) {
        restarted = reconnects != reconnects_ || (entry && entry->tick < statusTick_);
        // A sample taken before the selection may not list a world created just before it.
        gone = !restarted && !entry && status->uptimeS != selectUptime_;
        if (entry && !restarted) {
          extras_ = {entry->tickMs, entry->awakeBodies, entry->contacts, entry->running};
          statusKey_ = {entry->tick, entry->bodies};
          statusTick_ = entry->tick;
        }
      }
    }
    cv_.notify_all();
    if (restarted) {
      std::fprintf(stderr,
                   "physview: world %u: physd restarted or the world went back: shown afresh\n",
                   selected);
      select(selected);
    } else if (gone || !selected) {
      // No world (gone, or physd had none when the page came): the named one, or the first.
      uint32_t pick = status->worlds.empty() ? 0 : status->worlds.front().world;
      for (const auto& w : status->worlds)
        if (w.name == bridge_.options.world) pick = w.world;
      if (gone)
        pushError("select", "world " + std::to_string(selected) + " is gone" +
                                (pick ? ": showing world " + std::to_string(pick) : ""));
      if (pick || gone) select(pick);
    }
    const uint32_t shown = world();
    json worlds = json::array();
    for (const pc::WorldSummary& w : status->worlds)
      worlds.push_back({{"id", w.world},
                        {"name", w.name},
                        {"bodies", w.bodies},
                        {"awake", w.awakeBodies},
                        {"joints", w.joints},
                        {"contacts", w.contacts},
                        {"tick", w.tick},
                        {"time", w.time},
                        {"running", w.running},
                        {"rate", w.rateHz},
                        {"tickMs", w.tickMs}});
    pushText(dumpJson({{"type", "worlds"}, {"world", shown}, {"worlds", worlds}}), shown);
  }

  bool write(int opcode, const std::vector<uint8_t>& bytes) {
    if (dead_) return false;
    const int n = mg_websocket_write(conn_, opcode, reinterpret_cast<const char*>(bytes.data()),
                                     bytes.size());
    if (n <= 0) {
      dead_ = true;  // the page went away: CivetWeb's reader will close the connection
      return false;
    }
    bridge_.stats.bytesSent += bytes.size();
    return true;
  }

  void sendLoop() {
    const auto framePeriod = std::chrono::duration_cast<Clock::duration>(
        std::chrono::duration<double>(1.0 / std::max(1.0, bridge_.options.maxFps)));
    auto nextWorlds = Clock::now() + std::chrono::milliseconds(500);
    auto nextFrame = Clock::now();
    std::vector<uint8_t> sending;
    std::unique_lock<std::mutex> lk(m_);
    while (!stop_) {
      try {
        const auto now = Clock::now();
        if (now >= nextWorlds) {
          nextWorlds = now + std::chrono::milliseconds(500);
          lk.unlock();
          pushWorlds();
          lk.lock();
          continue;
        }
        if (!outbox_.empty()) {
          Outgoing o = std::move(outbox_.front());
          outbox_.pop_front();
          lk.unlock();
          if (write(o.opcode, o.bytes) && o.opcode == MG_WEBSOCKET_OPCODE_BINARY)
            ++bridge_.stats.shapeMessages;
          lk.lock();
          continue;
        }
        if (haveFrame_ && now >= nextFrame) {
          sending.swap(pending_);
          haveFrame_ = false;
          lk.unlock();
          if (write(MG_WEBSOCKET_OPCODE_BINARY, sending)) ++bridge_.stats.framesSent;
          nextFrame = std::max(now, nextFrame + framePeriod);
          if (nextFrame - now > framePeriod) nextFrame = now + framePeriod;
          lk.lock();
          continue;
        }
        const auto until = haveFrame_ ? std::min(nextWorlds, nextFrame) : nextWorlds;
        cv_.wait_until(lk, until, [&] {
          return stop_ || !outbox_.empty() || (haveFrame_ && Clock::now() >= nextFrame);
        });
      } catch (const std::exception& e) {
        // pushWorlds (a re-select's subscribe: pc::Error), an allocation: this page's pass
        // fails, the page is told, the next pass (the worlds 500 ms later) tries again.
        if (lk.owns_lock()) lk.unlock();
        logError("sender", e);
        try {
          pushError("worlds", e);
        } catch (const std::exception&) {
        }
        lk.lock();
      }
    }
  }

  /// Whether the worker should ask for the world's state: it sends no frames (paused, or
  /// never run) and phys/status says that it changed since the last answer (or a spawn from
  /// this page asked). Under m_.
  bool queryDue(Clock::time_point now) const {
    if (!world_) return false;
    if (needQuery_) return true;
    return now - lastFrame_ > std::chrono::milliseconds(500) && statusKey_ != queriedKey_;
  }

  /// Whether the session is ending or another world was selected since epoch.
  bool cancelled(uint64_t epoch) {
    std::lock_guard<std::mutex> lk(m_);
    return stop_ || epoch != epoch_;
  }

  /// The world's state by QueryState (paged), given to onFrame as a frame.
  void query(uint32_t id, uint64_t epoch) {
    pc::WorldHandle w = bridge_.client.world(id);
    pc::StateFrame frame;
    try {
      uint32_t first = 0;
      for (;;) {
        // A large world is many pages, each up to --timeout: not for a page that went away.
        if (cancelled(epoch)) return;
        pc::StateFrame page = w.queryState({}, first, 0, {bridge_.options.timeout}).get();
        if (first == 0) {
          frame.world = id;
          frame.tick = page.tick;
          frame.time = page.time;
          frame.total = page.total;
        }
        first += uint32_t(page.bodies.size());
        frame.bodies.insert(frame.bodies.end(), page.bodies.begin(), page.bodies.end());
        if (page.bodies.empty() || first >= page.total) break;
      }
    } catch (const pc::Error& e) {
      pushError("query", e);
      return;
    }
    frame.total = uint32_t(frame.bodies.size());
    onFrame(frame, epoch, true);
  }

  /// The worker: shapes of bodies the page has not seen (the world's snapshot), and the state
  /// of a world that sends no frames.
  void workLoop() {
    std::unique_lock<std::mutex> lk(m_);
    while (true) {
      try {
        cv_.wait_for(lk, std::chrono::milliseconds(250), [&] {
          return stop_ ||
                 (needDescribe_ && world_ && Clock::now() >= lastDescribe_ + kDescribePeriod) ||
                 queryDue(Clock::now());
        });
        if (stop_) return;
        const auto now = Clock::now();
        if (queryDue(now)) {
          needQuery_ = false;
          queriedKey_ = statusKey_;
          const uint64_t epoch = epoch_;
          const uint32_t id = world_;
          lk.unlock();
          query(id, epoch);
          lk.lock();
          continue;
        }
        // At most one snapshot a kDescribePeriod (a page that spawns a body per click or
        // selects in a loop, a world spawning every tick): what arrives meanwhile is in the next.
        if (!needDescribe_ || !world_ || now < lastDescribe_ + kDescribePeriod) continue;
        needDescribe_ = false;
        const uint64_t epoch = epoch_;
        const uint32_t id = world_;
        lk.unlock();
        std::vector<physview::BodyDesc> bodies;
        std::string error;
        const bool ok = physview::describeWorld(bridge_.client.world(id), bridge_.options.timeout,
                                                &bodies, &error);
        lk.lock();
        lastDescribe_ = Clock::now();
        if (stop_) return;
        if (epoch != epoch_) continue;
        if (!ok) {
          lastDescribe_ += std::chrono::seconds(2);  // not again at once
          recheck_ = true;
          lk.unlock();
          pushError("describe", error);
          lk.lock();
          continue;
        }
        std::vector<const physview::BodyDesc*> fresh;
        for (const physview::BodyDesc& b : bodies)
          if (described_.insert(b.id).second) fresh.push_back(&b);
        // A body the snapshot does not know (spawned after it): the next frame asks again, not
        // before kDescribePeriod. (select() sent the page its shapes reset.)
        recheck_ = true;
        if (fresh.empty()) continue;
        Outgoing o{MG_WEBSOCKET_OPCODE_BINARY, {}};
        physview::encodeShapes(id, 0, fresh, &o.bytes);
        outbox_.push_back(std::move(o));
        cv_.notify_all();
      } catch (const std::exception& e) {
        // A snapshot that does not decode, an allocation: this pass fails, the page is told,
        // the world is asked again after kDescribePeriod.
        if (!lk.owns_lock()) lk.lock();
        if (stop_) return;
        lastDescribe_ = Clock::now();
        recheck_ = true;
        lk.unlock();
        logError("worker", e);
        try {
          pushError("describe", e);
        } catch (const std::exception&) {
        }
        lk.lock();
      }
    }
  }

  struct Outgoing {
    int opcode;
    std::vector<uint8_t> bytes;
  };

  Bridge& bridge_;
  mg_connection* conn_;
  /// At most one snapshot (SaveSnapshot of the whole world) a period per page, whatever asks.
  static constexpr auto kDescribePeriod = std::chrono::seconds(1);
  std::thread sender_, worker_;
  std::atomic<bool> dead_{false};

  std::mutex m_;
  std::condition_variable cv_;
  bool stop_ = false;
  uint64_t epoch_ = 0;  ///< increases with every select: older subscriptions' frames are dropped
  uint32_t world_ = 0;
  pc::Subscription sub_;
  physview::FrameExtras extras_;
  std::vector<uint8_t> pending_;  ///< the newest encoded frame not yet sent
  bool haveFrame_ = false;
  std::deque<Outgoing> outbox_;             ///< text and shapes messages, in order
  std::unordered_set<uint64_t> described_;  ///< bodies whose shapes the page was sent
  bool needDescribe_ = false, recheck_ = true;
  Clock::time_point lastDescribe_{};
  Clock::time_point lastFrame_{};  ///< of the subscription
  bool needQuery_ = false;
  std::pair<uint64_t, uint32_t> statusKey_{0, 0};  ///< the world's tick and bodies (status)
  std::pair<uint64_t, uint32_t> queriedKey_{~0ull, ~0u};
  // What pushWorlds checks the selection against (select sets them).
  uint64_t reconnects_ = 0;   ///< the client's reconnects() at the selection
  double selectUptime_ = -1;  ///< physd's uptime in the newest phys/status at the selection
  uint64_t statusTick_ = 0;   ///< the world's tick in the newest phys/status since then

  // onFrame's (frameMutex_).
  std::mutex frameMutex_;
  std::vector<uint8_t> scratch_;
  std::vector<uint64_t> lastIds_;
  uint64_t idsEpoch_ = 0;
};

// CivetWeb's WebSocket handlers. The connection's user data is a heap shared_ptr<Session>
// from wsConnect (empty until wsReady) to connectionClose. None may throw into CivetWeb's C.

std::string lowercase(std::string s) {
  for (char& c : s) c = char(std::tolower(static_cast<unsigned char>(c)));
  return s;
}

/// Whether a browser page of origin may use the WebSocket. Browsers let any page open
/// ws://127.0.0.1:8088/ws, so: only a page of this server's own origin (the Origin's host:port
/// is the request's Host) under a name it is served on by design (the --listen address, or
/// loopback's), so that neither another site's page (its own origin) nor a site that points
/// its own name at this address (DNS rebinding: then Origin and Host agree) gets in.
bool originAllowed(const char* origin, const char* host, const std::string& listen) {
  if (!host) return false;
  std::string o = lowercase(origin);
  const size_t sep = o.find("://");  // none: "null" (a file or sandboxed page)
  if (sep == std::string::npos ||
      (o.compare(0, sep, "http") != 0 && o.compare(0, sep, "https") != 0))
    return false;
  o.erase(0, sep + 3);
  const std::string h = lowercase(host);
  if (o != h) return false;
  auto name = [](std::string hp) {  // "[::1]:8088" -> "::1", "localhost:8088" -> "localhost"
    if (!hp.empty() && hp[0] == '[') return hp.substr(1, hp.find(']') - 1);
    const size_t colon = hp.find(':');
    return colon == std::string::npos ? hp : hp.substr(0, colon);
  };
  const std::string n = name(h);
  return n == "localhost" || n == "127.0.0.1" || n == "::1" || n == name(lowercase(listen));
}

/// A refused WebSocket handshake's answer. (CivetWeb's mg_send_http_error writes only the body
/// from a WebSocket connect handler: no status line.)
void refuse(mg_connection* conn, int status, const char* reason, const std::string& text) {
  mg_printf(conn,
            "HTTP/1.1 %d %s\r\nContent-Type: text/plain\r\nContent-Length: %zu\r\n"
            "Connection: close\r\n\r\n%s",
            status, reason, text.size(), text.c_str());
}

int wsConnect(const mg_connection* conn, void* cbdata) {
  auto* bridge = static_cast<Bridge*>(cbdata);
  // The handler gets the connection const; answering a refusal needs it writable (it is).
  auto* c = const_cast<mg_connection*>(conn);
  try {
    // No Origin: not a browser (browsers always send one with a WebSocket handshake), so not
    // a page of some web site.
    const char* origin = mg_get_header(conn, "Origin");
    const char* host = mg_get_header(conn, "Host");
    if (origin && !originAllowed(origin, host, bridge->listen)) {
      std::fprintf(stderr, "physview: refused a WebSocket from origin %s (Host %s)\n", origin,
                   host ? host : "none");
      refuse(c, 403, "Forbidden", "physview: pages of other origins may not connect\n");
      return 1;
    }
    auto holder = std::make_unique<std::shared_ptr<Session>>();
    int n = bridge->pages.load();
    do {
      if (n >= kMaxPages) {
        std::fprintf(stderr, "physview: refused a WebSocket: %d pages open already\n", n);
        refuse(c, 503, "Service Unavailable",
               "physview: " + std::to_string(n) + " pages are open already (at most " +
                   std::to_string(kMaxPages) + ")\n");
        return 1;
      }
    } while (!bridge->pages.compare_exchange_weak(n, n + 1));
    // Given back in connectionClose: CivetWeb calls it for every connection, also when the
    // handshake fails after this (then neither wsReady nor wsClose is called).
    mg_set_user_connection_data(c, holder.release());
    return 0;
  } catch (const std::exception& e) {
    logError("connect", e);
    return 1;
  }
}

void wsReady(mg_connection* conn, void* cbdata) {
  auto* bridge = static_cast<Bridge*>(cbdata);
  auto* holder = static_cast<std::shared_ptr<Session>*>(mg_get_user_connection_data(conn));
  if (!holder) return;
  try {
    *holder = std::make_shared<Session>(*bridge, conn);
    (*holder)->start();
  } catch (const std::exception& e) {
    // No thread for the page (or no memory): tell it and close; it connects again in a second.
    logError("page", e);
    const std::string text =
        dumpJson({{"type", "error"}, {"op", "connect"}, {"message", e.what()}});
    mg_websocket_write(conn, MG_WEBSOCKET_OPCODE_TEXT, text.data(), text.size());
    mg_websocket_write(conn, MG_WEBSOCKET_OPCODE_CONNECTION_CLOSE, "\x03\xf3", 2);  // 1011
  }
}

int wsData(mg_connection* conn, int flags, char* data, size_t len, void*) {
  const int opcode = flags & 0xf;
  if (opcode == MG_WEBSOCKET_OPCODE_CONNECTION_CLOSE) return 0;
  auto* holder = static_cast<std::shared_ptr<Session>*>(mg_get_user_connection_data(conn));
  if (!holder || !*holder) return 1;
  Session& session = **holder;
  try {
    if (len > kMaxIncoming) {
      std::fprintf(stderr, "physview: a page sent a %zu-byte message (at most %zu): closed\n", len,
                   kMaxIncoming);
      return 0;  // closes the connection
    }
    if (opcode != MG_WEBSOCKET_OPCODE_TEXT) return 1;  // continuation frames among them
    // CivetWeb hands over each frame, not each message. Without FIN (0x80) this frame starts
    // a fragmented message: refused whole (its continuation frames are dropped above),
    // never parsed in part. The page sends every command in one frame.
    if (!(flags & 0x80)) {
      session.pushError("", "fragmented messages are not accepted");
      return 1;
    }
    session.command(std::string_view(data, len));
  } catch (const std::exception& e) {
    logError("command", e);
    try {
      session.pushError("command", e);
    } catch (const std::exception&) {
    }
  }
  return 1;
}

void wsClose(const mg_connection* conn, void*) {
  auto* holder = static_cast<std::shared_ptr<Session>*>(mg_get_user_connection_data(conn));
  if (!holder || !*holder) return;
  (*holder)->stop();  // joins the page's threads: not under CivetWeb's connection lock
  holder->reset();
}

/// Every connection's end (CivetWeb's thread, under the connection's lock): a WebSocket's
/// holder and page slot from wsConnect (its session was stopped by wsClose).
void connectionClose(const mg_connection* conn) {
  auto* holder = static_cast<std::shared_ptr<Session>*>(mg_get_user_connection_data(conn));
  if (!holder) return;
  mg_set_user_connection_data(const_cast<mg_connection*>(conn), nullptr);
  delete holder;
  --static_cast<Bridge*>(mg_get_user_data(mg_get_context(conn)))->pages;
}

int logMessage(const mg_connection*, const char* message) {
  std::fprintf(stderr, "physview: civetweb: %s\n", message);
  return 1;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"physview: a live 3D viewer of physd's worlds in the browser"};
  uint32_t domain = 0;
  std::string config, identity, securityDir = "build/security";
  std::string listen = "127.0.0.1";
  int port = 8088;
  std::string webDir = PHYSVIEW_WEB_DIR;
  int timeoutMs = 10000;
  double statsPeriod = 0;
  Options opts;
  app.add_option("--domain", domain, "DDS domain");
  app.add_option(
      "--config", config,
      "Cyclone DDS XML file (default: CYCLONEDDS_URI, else configs/cyclonedds/loopback.xml)");
  app.add_option("--identity", identity, "DDS Security identity (docs/SECURITY.md)");
  app.add_option("--security-dir", securityDir, "what tools/make_security.sh wrote");
  app.add_option("--listen", listen, "address to serve on (0.0.0.0: every interface)");
  app.add_option("--port", port, "HTTP port (0: a free one, printed)")->check(CLI::Range(0, 65535));
  app.add_option("--web", webDir, "the bundled page's folder")->capture_default_str();
  app.add_option("--world", opts.world, "world shown first (by name; else the first)")
      ->capture_default_str();
  app.add_option("--max-fps", opts.maxFps, "frames a second to one page at most")
      ->capture_default_str()
      ->check(CLI::Range(1.0, 1000.0));
  app.add_option("--timeout", timeoutMs, "connect and request timeout, ms")->capture_default_str();
  app.add_option("--stats", statsPeriod, "print the bridge's counters every S seconds (0: never)");
  CLI11_PARSE(app, argc, argv);
  opts.timeout = std::chrono::milliseconds(timeoutMs);

  if (!std::filesystem::exists(std::filesystem::path(webDir) / "index.html")) {
    std::fprintf(stderr, "physview: no index.html in %s (build the physview target, or --web)\n",
                 webDir.c_str());
    return 2;
  }
  pc::ClientOptions options;
  options.domain = domain;
  options.name = "physview";
  options.connectTimeout = options.requestTimeout = opts.timeout;
  if (config.empty() && !std::getenv("CYCLONEDDS_URI")) {
    const std::string loopback = std::string(PHYS_SOURCE_DIR) + "/configs/cyclonedds/loopback.xml";
    if (std::filesystem::exists(loopback)) config = loopback;
  }
  if (!config.empty() && !readFile(config, &options.cycloneXml)) {
    std::fprintf(stderr, "physview: cannot read Cyclone config %s\n", config.c_str());
    return 2;
  }
  if (!identity.empty()) options.security = pc::SecurityFiles::fromDir(securityDir, identity);

  std::signal(SIGINT, onSignal);
  std::signal(SIGTERM, onSignal);
  std::signal(SIGPIPE, SIG_IGN);

  mg_init_library(MG_FEATURES_WEBSOCKET);
  if (!mg_check_feature(MG_FEATURES_WEBSOCKET)) {
    std::fprintf(stderr, "physview: this CivetWeb was built without WebSockets\n");
    return 2;
  }
  try {
    auto client = std::make_unique<pc::Client>(options);
    // physd may start after us (or restart later: the SDK greets it again by itself).
    while (!gStop) {
      try {
        client->connect();
        break;
      } catch (const pc::Error& e) {
        if (e.code() == pc::ErrorCode::Unsupported || e.code() == pc::ErrorCode::BadReply) {
          std::fprintf(stderr,
                       "physview: the physd on domain %u speaks another protocol (%s: %s): "
                       "build physview and physd from the same source\n",
                       domain, pc::toString(e.code()), e.message().c_str());
          return 1;
        }
        std::fprintf(stderr, "physview: waiting for physd on domain %u (%s)\n", domain,
                     e.message().c_str());
      }
      // A second between tries (a failure that comes at once would spin), Ctrl-C heard.
      for (int i = 0; i < 10 && !gStop; ++i)
        std::this_thread::sleep_for(std::chrono::milliseconds(100));
    }
    if (gStop) return 0;

    Bridge bridge{*client, opts, {}, listen};
    const std::string ports = listen + ":" + std::to_string(port);
    // clang-format off
    const char* mgOptions[] = {"document_root", webDir.c_str(),
                               "listening_ports", ports.c_str(),
                               "num_threads", "32",
                               "enable_directory_listing", "no",
                               "enable_websocket_ping_pong", "yes",
                               "websocket_timeout_ms", "10000",
                               "additional_header", "Cache-Control: no-cache",
                               nullptr};
    // clang-format on
    mg_callbacks callbacks;
    std::memset(&callbacks, 0, sizeof callbacks);
    callbacks.log_message = logMessage;
    callbacks.connection_close = connectionClose;
    mg_context* ctx = mg_start(&callbacks, &bridge, mgOptions);
    if (!ctx) {
      std::fprintf(stderr, "physview: cannot serve on %s (port in use?)\n", ports.c_str());
      return 1;
    }
    mg_set_websocket_handler(ctx, "/ws", wsConnect, wsReady, wsData, wsClose, &bridge);
    mg_server_port served[4];
    const int n = mg_get_server_ports(ctx, 4, served);
    const int actual = n > 0 ? served[0].port : port;
    const std::string host = listen == "0.0.0.0" ? "localhost" : listen;
    std::printf("physview: serving http://%s:%d/ (physd %s %s, domain %u, pages from %s)\n",
                host.c_str(), actual, client->server().name.c_str(),
                client->server().version.c_str(), domain, webDir.c_str());
    std::fflush(stdout);

    auto nextStats = Clock::now();
    while (!gStop) {
      std::this_thread::sleep_for(std::chrono::milliseconds(100));
      if (statsPeriod > 0 && Clock::now() >= nextStats) {
        nextStats = Clock::now() + std::chrono::milliseconds(int64_t(statsPeriod * 1000));
        const Stats& s = bridge.stats;
        std::printf(
            "physview: pages %d  frames in %llu sent %llu replaced %llu  shape messages %llu  "
            "sent %.1f MB  commands %llu\n",
            s.sessions.load(), (unsigned long long)s.framesIn.load(),
            (unsigned long long)s.framesSent.load(), (unsigned long long)s.framesReplaced.load(),
            (unsigned long long)s.shapeMessages.load(), double(s.bytesSent.load()) / 1e6,
            (unsigned long long)s.commands.load());
        std::fflush(stdout);
      }
    }
    mg_stop(ctx);  // closes the pages' connections (their close handlers end the sessions)
    // The client (its thread joined) before the bridge: a frame callback in flight may still
    // hold a session, which uses the bridge.
    client.reset();
  } catch (const pc::Error& e) {
    std::fprintf(stderr, "physview: %s: %s\n", pc::toString(e.code()), e.message().c_str());
    return 1;
  }
  return 0;
}
