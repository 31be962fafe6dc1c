// The physd client SDK: a connection (Client), world handles, state subscriptions.
//
//   phys::client::Client c({.domain = 0});
//   c.connect();                                    // waits for physd, Hello
//   phys::client::WorldHandle w = c.createWorld({"demo"}).get();
//   auto ids = w.spawn(bodies).get();               // futures; .get() throws Error
//   auto sub = w.subscribe([](const phys::client::StateFrame& f) { ... });
//   w.run(60).get();
//
// Every request returns a std::future resolved by the server's reply with the same
// correlation (client id, seq); a failed request's future throws phys::client::Error with the
// server's code and message, or Timeout / Disconnected. Every DDS call stays inside the SDK.
// When the daemon restarts, pending requests fail with Disconnected and the client says
// Hello again by itself (worlds of the old daemon are gone: their ids may be reused).
//
// Several daemons on one domain (docs/CLIENT.md "Several daemons"): a world's commands reach
// its owner whichever daemon that is; createWorld picks a daemon (CallOptions::daemon, or the
// one with the fewest awake bodies) and listWorlds gathers every daemon's worlds.
#pragma once

#include <chrono>
#include <cstdint>
#include <functional>
#include <future>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "phys/client/error.h"
#include "phys/protocol/builder.h"
#include "phys/protocol/security.h"
#include "phys/defs/body_def.h"
#include "phys/defs/joint_def.h"
#include "phys/defs/world_def.h"

namespace phys::client {

using Bytes = std::vector<uint8_t>;
using WorldSummary = protocol::WorldSummary;
using CreateWorldArgs = protocol::CreateWorldArgs;
using SolverOverrides = protocol::SolverOverrides;
using PointFrame = wire::PointFrame;
using SecurityFiles = protocol::SecurityFiles;
using protocol::identityKey;
/// World settings to change (WorldHandle::setWorld): unset fields keep their value.
using WorldOverrides = protocol::WorldOverrides;
/// A body as its world simulates it (WorldHandle::getBodies): its definition, read from the
/// engine (pose and velocities as of the reply's tick; mass and inertia as given, 0: from the
/// shapes), and the mass properties the world derived (phys::BodyMass).
using BodyInfo = protocol::BodyInfo;
/// A joint's definition (bodyA / bodyB: ids of the world's bodies; a null bodyA: the world).
using JointInfo = protocol::JointEntry;

struct ClientOptions {
  uint32_t domain = 0;
  /// Cyclone XML (the contents, not a path) for the domain; empty: CYCLONEDDS_URI / defaults.
  std::string cycloneXml;
  std::string name = "physclient";                  ///< sent in Hello
  /// The client's key file (phys/protocol/client_key.h; made with a fresh key, mode 0600, when
  /// missing): the client id is the key's, the same at every run, and proven to physd in
  /// every Hello, so worlds it creates stay its own across its restarts and nobody else can
  /// act as it by using its id (docs/SERVER.md "Access"). Empty (the default): a fresh key,
  /// hence a fresh proven id, for each Client, unless clientId is given.
  std::string keyFile;
  /// A fixed client id without a key (the protocol's plain form): not proven, so physd treats
  /// it as any participant's to claim while this client is away. 0: the key's id. With
  /// keyFile it must be 0 or the key's id.
  uint64_t clientId = 0;
  std::chrono::milliseconds connectTimeout{10000};  ///< connect(): server match + Hello
  std::chrono::milliseconds requestTimeout{10000};  ///< default per-request deadline
  bool autoReconnect = true;                        ///< say Hello again when a (new) daemon appears
  /// A request physd refused at the door ("slow down", "wait for replies": ResourceExhausted
  /// from its rate and queue budgets, marked by Reply.retry_after_ms; nothing was done) is
  /// sent again after the wait the daemon names, backing off (1, 2, 4, ... 200 ms, with
  /// jitter) while it is refused again, until the request's deadline; then the refusal is
  /// its error. false: the first refusal is (Error::retryAfterMs() says it may be retried).
  /// docs/CLIENT.md "Rate limits".
  bool retryBusy = true;
  /// DDS Security (docs/SECURITY.md): this client's identity and its files, e.g.
  /// SecurityFiles::fromDir("build/security", "client1") for what tools/make_security.sh
  /// made. Added to cycloneXml; the commands go out in the identity's partition, so that a
  /// secure physd knows who sent them (worlds this client creates are owned by the identity,
  /// whatever its client id). Empty identity: no security of the SDK's own.
  SecurityFiles security;
};

/// What the server said in HelloResult.
struct ServerInfo {
  uint16_t protocolVersion = 0;
  std::string name;
  std::string version;
  std::vector<std::string> features;
  /// physd checked this client's binding proof (a daemon without DDS Security that knows
  /// client keys): its id is its own on that daemon.
  bool clientProven = false;
};

/// Reply to a request without a result: where and when it took effect.
struct Ack {
  uint32_t world = 0;
  uint64_t tick = 0;
};

struct Ids {
  std::vector<uint64_t> bodies;
  std::vector<uint64_t> joints;
};

struct BodyState {
  uint64_t id = 0;
  phys::Vec3 position;
  phys::Quat rotation;  ///< as physd sent it: unit length to float rounding, not re-normalized
  phys::Vec3 linearVelocity;
  phys::Vec3 angularVelocity;
  /// In a subscription's frame: this tick's frame carried the body (its state changed since
  /// the previous frame, or the frame is a keyframe); otherwise the state is the one it last
  /// carried. Always true in a QueryState answer.
  bool changed = true;
};

/// One complete tick of a world, or a QueryState answer. A subscription rebuilds every tick's
/// full state from the server's keyframes and deltas (docs/PROTOCOL.md "State frames"): its
/// frames hold every body of the world at that one tick, in index order, never a mix of
/// ticks; a tick whose delta cannot be applied (one was lost) is skipped until the next
/// keyframe. Frames come in (epoch, tick, edit) order (docs/CLIENT.md "Subscriptions"): a
/// reset or restored world's first frame has a higher epoch and may have a lower tick, and
/// an edit to a paused world comes as a frame of the same tick with the next edit number.
struct StateFrame {
  uint32_t world = 0;
  uint64_t tick = 0;
  double time = 0;
  uint32_t total = 0;  ///< bodies in the world (QueryState: matching the query)
  std::vector<BodyState> bodies;
  bool keyframe = true;  ///< the server sent every body (else a delta: see BodyState::changed)
  uint32_t changed = 0;  ///< bodies the server sent for this tick
  uint64_t bytes = 0;    ///< the encoded size of what the server sent for this tick
  /// The server's wall clock (ns since the Unix epoch) when it read these states (QueryState:
  /// when it answered). Now minus this is the tick-to-subscriber latency (same host or
  /// synced clocks). 0 from servers older than the field (QueryState: before issue 40).
  uint64_t stampNs = 0;
  /// The world's epoch: one higher (or more) each time its state was replaced rather than
  /// stepped (LoadScene, ResetWorld, RestoreSnapshot, a durable daemon's restart or reload),
  /// its ticks then starting again from the new state's. 0 from older servers.
  uint64_t epoch = 0;
  /// Frames of edits applied to a paused world at this tick (SetBodyPose, SpawnBodies, ...):
  /// 1, 2, ...; 0 for the tick's own frame (and in QueryState answers).
  uint32_t edit = 0;
};

/// A world's settings (GetWorld): every setting SetWorld takes and the solver's, in a
/// phys::WorldDef (threads, backend and the contact budget are the daemon's and left at their
/// defaults here), and the solver preset last applied.
struct WorldSettings {
  phys::WorldDef def;
  std::string preset;
  uint64_t tick = 0;  ///< the world's tick when it was read
};

/// One reply of getBodies / getJoints: total is what matched before paging (every body or
/// joint of the world, or the ids asked for); the page holds as many as one reply does.
struct BodiesPage {
  uint64_t tick = 0;
  uint32_t total = 0;
  std::vector<BodyInfo> bodies;
};
struct JointsPage {
  uint64_t tick = 0;
  uint32_t total = 0;
  std::vector<JointInfo> joints;
};

/// What a subscription asks for (docs/PROTOCOL.md "Interests"): every body (the default),
/// these bodies, or the bodies whose position is inside a box. A filtered subscription's
/// frames hold just those bodies (`total` is their count); a body leaving the box leaves the
/// frames, one entering it joins them.
struct Interest {
  std::vector<uint64_t> bodies;
  std::optional<std::pair<phys::Vec3, phys::Vec3>> region;  ///< min and max corners
  bool all() const { return bodies.empty() && !region; }
};

/// The latest phys/status sample.
struct ServerStatus {
  std::string serverName;
  std::string serverVersion;
  double uptimeS = 0;
  uint64_t commands = 0, errors = 0;
  std::vector<WorldSummary> worlds;
  uint64_t framesDropped = 0;  ///< state frames the daemon's publisher dropped, total
  uint64_t heapBytes = 0;      ///< bytes in use in the daemon's heap (0: not reported)
  /// Why the daemon refuses commands that change kept worlds (its data disk is full); empty
  /// when it does not.
  std::string readOnly;
  uint64_t daemon = 0;     ///< the daemon's server.id
  bool cluster = false;    ///< it is in a domain of daemons (docs/SERVER.md "Several daemons")
  float statusPeriodS = 0; ///< s between its samples (0: an older daemon that did not say)
  /// In a domain of daemons: the other daemons whose status it has seen lately, by id.
  std::vector<uint64_t> peers;
};

/// A daemon of the domain as this client sees it (its phys/status samples).
struct DaemonInfo {
  uint64_t id = 0;  ///< server.id
  std::string name;
  bool cluster = false;
  uint32_t worlds = 0;        ///< worlds it holds (its last sample, and those made since)
  uint64_t awakeBodies = 0;   ///< over its worlds, in its last sample
  double sinceSampleS = 0;    ///< s since its last sample arrived
  std::vector<uint64_t> peers;  ///< the other daemons it has seen lately (its last sample)
};

/// A notice from the daemon (phys/events), e.g. the engine's guard rails redoing a step.
struct Event {
  enum class Severity : uint8_t { Info = 0, Warning = 1, Error = 2 };
  uint32_t world = 0;
  uint64_t tick = 0;
  Severity severity = Severity::Info;
  std::string code;  ///< short, machine readable: "guard_rollback", "guard_quarantine"
  std::string message;
};

/// Per-request options.
struct CallOptions {
  std::chrono::milliseconds timeout{0};  ///< 0: ClientOptions::requestTimeout
  /// The daemon (server.id) to send it to (Command.daemon); 0: the SDK's choice: a world's
  /// owner, for createWorld the daemon with the fewest awake bodies, for listWorlds every one.
  uint64_t daemon = 0;
};

class Client;

/// A live subscription to one world's state frames; unsubscribes when destroyed. Once the
/// destructor or reset() returns, its callback does not run again: they wait for a callback
/// that is running on the SDK thread (so what the callback touches may be destroyed next),
/// except from inside the callback itself, which may reset its own subscription.
class Subscription {
 public:
  Subscription() = default;
  ~Subscription();
  Subscription(Subscription&&) noexcept;
  Subscription& operator=(Subscription&&) noexcept;
  Subscription(const Subscription&) = delete;
  Subscription& operator=(const Subscription&) = delete;

  explicit operator bool() const { return state_ != nullptr; }
  uint32_t world() const;
  /// The latest complete frame (every chunk of one tick), if any arrived.
  std::optional<StateFrame> latest() const;
  /// Waits for a complete frame with tick > afterTick, or of another epoch than afterTick's
  /// (the world was reset or restored since: its ticks started again, docs/CLIENT.md
  /// "Subscriptions"). afterTick's epoch is `epoch`, or (0) that of the last frame latest() or
  /// waitForFrame() returned; before they returned any, afterTick 0 takes the first frame
  /// whatever its tick (a world just created or reset is at tick 0). A paused world's edits
  /// come as frames of the tick already delivered (StateFrame::edit): latest() and the
  /// callback see them. It returns a frame once the callback (if any) has returned from it,
  /// so what the callback recorded of that frame is there to read.
  std::optional<StateFrame> waitForFrame(uint64_t afterTick, std::chrono::milliseconds timeout,
                                         uint64_t epoch = 0);
  uint64_t framesReceived() const;  ///< complete frames
  /// Ticks skipped because a delta arrived without the frame it applies to (a lost chunk, a
  /// subscription started between keyframes): each is repaired by the next keyframe.
  uint64_t framesSkipped() const;
  /// Frame chunks dropped because their epoch is below the stream's: late frames of a world
  /// since reset or restored, or a deposed owner's (docs/SERVER.md "Standby and takeover").
  uint64_t staleChunks() const;
  void reset();                     ///< unsubscribes

  struct State;

 private:
  friend class Client;
  explicit Subscription(std::shared_ptr<State> s) : state_(std::move(s)) {}
  std::shared_ptr<State> state_;
};

/// A world of the server: every request on it returns a future.
class WorldHandle {
 public:
  WorldHandle() = default;
  WorldHandle(Client* client, uint32_t id) : client_(client), id_(id) {}
  uint32_t id() const { return id_; }
  explicit operator bool() const { return client_ && id_; }

  std::future<Ack> destroy(CallOptions o = {});
  std::future<Ack> reset(CallOptions o = {});
  /// A scene by server-side name (configs/scenes/<name>.json) or inline JSON.
  std::future<Ids> loadScene(std::string_view sceneName, CallOptions o = {});
  std::future<Ids> loadSceneJson(std::string_view json, CallOptions o = {});
  std::future<std::vector<uint64_t>> spawn(std::span<const phys::BodyDef> bodies,
                                           CallOptions o = {});
  std::future<std::vector<uint64_t>> spawn(const phys::BodyDef& body, CallOptions o = {});
  std::future<Ack> removeBodies(std::span<const uint64_t> ids, CallOptions o = {});
  std::future<std::vector<uint64_t>> addJoints(std::span<const phys::JointDef> joints,
                                               CallOptions o = {});
  std::future<Ack> removeJoints(std::span<const uint64_t> ids, CallOptions o = {});
  std::future<Ack> setPose(uint64_t body, phys::Vec3 position, phys::Quat rotation = {},
                           CallOptions o = {});
  std::future<Ack> setVelocity(uint64_t body, phys::Vec3 linear, phys::Vec3 angular = {},
                               CallOptions o = {});
  /// Acts during the next step only. point/frame: see docs/PROTOCOL.md (PointFrame).
  std::future<Ack> applyForce(uint64_t body, phys::Vec3 force, phys::Vec3 point = {},
                              PointFrame frame = PointFrame::CenterOfMass, CallOptions o = {});
  std::future<Ack> applyImpulse(uint64_t body, phys::Vec3 impulse, phys::Vec3 point = {},
                                PointFrame frame = PointFrame::CenterOfMass, CallOptions o = {});
  std::future<Ack> applyTorque(uint64_t body, phys::Vec3 torque, CallOptions o = {});
  std::future<Ack> setMaterial(std::span<const uint64_t> bodies, const phys::Material& m,
                               CallOptions o = {});
  std::future<Ack> setSolver(std::string_view preset, const SolverOverrides& overrides = {},
                             CallOptions o = {});
  /// World settings (docs/PROTOCOL.md "World settings"): the fields set change, all or
  /// nothing, each waking what it affects (a gravity change wakes every body); an edit, so
  /// only the owner and editors may (PermissionDenied), journaled on a durable daemon.
  std::future<Ack> setWorld(const WorldOverrides& settings, CallOptions o = {});
  std::future<Ack> setGravity(phys::Vec3 gravity, CallOptions o = {});
  std::future<Ack> setTimeStep(float seconds, CallOptions o = {});
  /// Sleeping on or off with its thresholds (phys::SleepSettings).
  std::future<Ack> setSleep(const phys::SleepSettings& sleep, CallOptions o = {});
  /// The world's settings (a read: any client).
  std::future<WorldSettings> settings(CallOptions o = {});
  /// Definitions as the world simulates them (docs/PROTOCOL.md "Definitions"; a read): these
  /// ids in their order, or every body (joint) from `first` in id index order, at most
  /// maxCount (0: as many as one reply holds). A page may hold fewer than asked: ask again
  /// from where it ended (allBodies does).
  std::future<BodiesPage> getBodies(std::span<const uint64_t> ids = {}, uint32_t first = 0,
                                    uint32_t maxCount = 0, CallOptions o = {});
  std::future<JointsPage> getJoints(std::span<const uint64_t> ids = {}, uint32_t first = 0,
                                    uint32_t maxCount = 0, CallOptions o = {});
  /// Every body's (joint's) definition, page after page on a thread of its own (the world may
  /// change between pages: a body removed meanwhile may shift the rest by one).
  std::future<std::vector<BodyInfo>> allBodies(CallOptions o = {});
  std::future<std::vector<JointInfo>> allJoints(CallOptions o = {});
  /// Takes n steps now; Ack.tick is the tick after them.
  std::future<Ack> step(uint32_t n = 1, CallOptions o = {});
  /// Real time at rateHz (0: as fast as possible).
  std::future<Ack> run(float rateHz = 60, CallOptions o = {});
  std::future<Ack> pause(CallOptions o = {});
  /// In a domain of daemons (docs/CLIENT.md "Several daemons"): the world to that daemon
  /// (server.id) at a tick boundary, with its id, state, access and run mode; Ack.tick is the
  /// last tick taken where it was. Handles and subscriptions keep working; the world's owner
  /// only.
  std::future<Ack> move(uint64_t daemon, CallOptions o = {});
  /// The world's owner only: who else may change it (docs/SERVER.md "Access"). editors:
  /// client ids (Client::clientId()); shared: every client. Others get PermissionDenied.
  std::future<Ack> setAccess(std::span<const uint64_t> editors, bool shared = false,
                             CallOptions o = {});
  /// ids empty: every body, paged by first / maxCount.
  std::future<StateFrame> queryState(std::span<const uint64_t> ids = {}, uint32_t first = 0,
                                     uint32_t maxCount = 0, CallOptions o = {});
  /// The engine's exact snapshot as bytes (a Snapshot FlatBuffer).
  std::future<Bytes> saveSnapshot(CallOptions o = {});
  /// Saved on the server under its snapshot directory (no bytes returned).
  std::future<Ack> saveSnapshotFile(std::string_view file, CallOptions o = {});
  std::future<Ack> restoreSnapshot(std::span<const uint8_t> snapshot, CallOptions o = {});
  std::future<Ack> restoreSnapshotFile(std::string_view file, CallOptions o = {});

  /// State frames of this world: fn (if any) runs on the SDK's thread for every complete
  /// tick, with a frame valid until it returns (copy what you keep: the SDK applies the next
  /// tick to the same bodies); Subscription::latest() returns a copy of the newest.
  Subscription subscribe(std::function<void(const StateFrame&)> fn = {});
  /// Only what `interest` names: physd keeps a stream of it on its own topic until the
  /// subscription ends. Throws Error like a request (e.g. ResourceExhausted past 64
  /// interests on a world).
  Subscription subscribe(const Interest& interest, std::function<void(const StateFrame&)> fn = {},
                         CallOptions o = {});

 private:
  Client* client_ = nullptr;
  uint32_t id_ = 0;
};

class Client {
 public:
  /// Creates the DDS participant, topics, writer and readers (throws Error{Transport}); does
  /// not wait for a server: call connect().
  explicit Client(ClientOptions options = {});
  ~Client();
  Client(const Client&) = delete;
  Client& operator=(const Client&) = delete;

  /// Waits for a server on the domain and says Hello (throws Error: Timeout when none
  /// answers within connectTimeout, Unsupported when the protocol versions differ).
  ServerInfo connect();
  /// Whether the last Hello was answered and the server is still matched.
  bool connected() const;
  /// Times a (new) server was greeted after the first connect.
  uint64_t reconnects() const;
  uint64_t clientId() const;
  const ClientOptions& options() const;
  ServerInfo server() const;

  std::future<ServerInfo> hello(CallOptions o = {});
  std::future<WorldHandle> createWorld(const CreateWorldArgs& args, CallOptions o = {});
  std::future<std::vector<WorldSummary>> listWorlds(CallOptions o = {});
  /// A handle to an existing world by id (no request).
  WorldHandle world(uint32_t id) { return WorldHandle(this, id); }
  /// The world named name (ListWorlds), or Error{NotFound}.
  WorldHandle worldNamed(const std::string& name, CallOptions o = {});

  /// The newest phys/status sample, if one arrived.
  std::optional<ServerStatus> latestStatus() const;
  /// The daemons whose status arrived within the last 3 of their periods (at least 2 s),
  /// by id.
  std::vector<DaemonInfo> daemons() const;
  /// Replies that answered a request already answered (a command taken by two daemons: none
  /// should be; Hello, which every daemon answers, is not counted).
  uint64_t duplicateReplies() const;
  /// fn runs on the SDK's thread for every event from now on (replaces an earlier fn; empty
  /// to stop). Events are volatile: those published before the client matched are not seen.
  void onEvent(std::function<void(const Event&)> fn);
  /// The last (up to 64) events received, oldest first.
  std::vector<Event> recentEvents() const;
  Subscription subscribe(uint32_t world, std::function<void(const StateFrame&)> fn = {});

  struct Impl;

 private:
  friend class WorldHandle;
  std::unique_ptr<Impl> impl_;
};

}  // namespace phys::client
