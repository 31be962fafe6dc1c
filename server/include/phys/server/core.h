// physd's core without DDS: the world registry, command application at tick boundaries,
// time control, state frame production and status numbers. The DDS endpoint (endpoint.h)
// feeds it decoded commands and drains its PublishQueue; tests drive it directly.
//
// Threading: submit() and setSubscribers() may be called from any thread. Everything else
// (apply, processPending, advance, the accessors) belongs to the tick thread (TickThread, or
// the test's own thread).
#pragma once

#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <unordered_map>
#include <memory>
#include <mutex>
#include <set>
#include <optional>
#include <span>
#include <string>
#include <thread>
#include <vector>

#include "phys/scene/presets.h"
#include "phys/scene/scene.h"
#include "phys/protocol/builder.h"
#include "phys/protocol/cluster.h"
#include "phys/protocol/decoder.h"
#include "phys/protocol/limits.h"
#include "phys/protocol/status.h"
#include "phys/server/ring.h"
#include "phys/server/store.h"
#include "phys/world/world.h"

namespace phys::server {

using protocol::Status;
using Code = protocol::Code;
using protocol::ReplyHeader;

struct CoreConfig {
  std::string serverName = "physd";
  uint64_t serverId = 1;    ///< phys/status key; Command.daemon addresses it
  /// A domain of daemons (docs/SERVER.md "Several daemons"): world ids are
  /// protocol::firstWorldIdOf(serverId) on, and the daemon takes only the commands addressed to
  /// it or to a world it owns or whose id is of its range (takes()). serverId <= 4095.
  bool cluster = false;
  /// Hot standby (docs/SERVER.md "Standby and takeover"): etcd's client URL (e.g.
  /// "http://127.0.0.1:2379"); empty: no coordinator, no standby, no takeover. Needs cluster
  /// and dataDir.
  std::string coordinator;
  std::string coordinatorPrefix = "phys/";  ///< every key this domain keeps in etcd
  /// The daemon that stands by for this daemon's kept worlds (0: none): it takes them over
  /// from their files (storage both can read) when this daemon stops renewing its hold.
  uint64_t standby = 0;
  /// The hold: renewed every renewPeriodS; this daemon serves its registered worlds only
  /// within fenceAfterS of sending its last renewal that succeeded; a standby takes over once
  /// it has read the same renewal for takeoverAfterS (> fenceAfterS: the deposed owner has
  /// stopped by then, whatever the clocks between them).
  double renewPeriodS = 0.1, fenceAfterS = 0.3, takeoverAfterS = 0.5;
  /// leasePeriodS for a registered world with a standby: a takeover steps at most this much
  /// simulated time beyond the journal's records (one journal sync per lease).
  double standbyLeasePeriodS = 0.1;
  double statusPeriodS = 1.0;  ///< phys/status period (ServerStatus.status_period_s)
  std::string presetsFile;  ///< empty: phys::defaultPresetsPath()
  std::string scenesDir;    ///< LoadScene by name: <scenesDir>/<name>.json
  std::string snapshotDir;  ///< SaveSnapshot / RestoreSnapshot files; empty: refused
  /// Durable worlds (docs/SERVER.md "Durable worlds"): each world's checkpoint and journal
  /// under <dataDir>/worlds/<id>/, restored at start-up (restoreWorlds); a command's reply
  /// goes out once what it changed is on disk. Empty: worlds live in memory only.
  std::string dataDir;
  /// A world's checkpoint is rewritten this often (s of wall time) while it changes, and
  /// whenever its journal passes journalMaxBytes: restoring replays at most that much.
  double checkpointPeriodS = 30;
  uint64_t journalMaxBytes = 64ull << 20;
  /// A running world's steps are promised to its journal ahead of time, this much (s of
  /// simulated time at its rate) at once: a Lease record, synced before the first step it
  /// allows (docs/ARCHITECTURE.md "Nothing runs ahead of the journal"). A restart resumes at
  /// the last lease's end, at most this far beyond the last tick subscribers saw, never
  /// behind it. 0: a lease per tick, of that tick's steps.
  double leasePeriodS = 1;
  /// Worlds whose journal is missing or damaged before its end are not restored unless
  /// listed here (ids; 0: every world): then their files are copied to <dataDir>/damaged/
  /// and they are restored from what is good (physd --accept-loss).
  std::vector<uint32_t> acceptLoss;
  protocol::Limits limits;  ///< codec limits, also announced in HelloResult
  int threads = 1;          ///< WorldDef::threads of every world
  int maxCatchUpSteps = 4;  ///< steps one tick may take to catch up with real time
  uint32_t maxWorlds = 64;  ///< worlds per daemon
  // Daemon-wide budgets (docs/SERVER.md "Budgets"): a command that would pass one is
  // refused with ResourceExhausted before it changes anything.
  uint32_t maxBodiesPerWorld = 1u << 20;
  uint32_t maxJointsPerWorld = 1u << 20;
  uint64_t maxBodiesTotal = 4u << 20;  ///< over all worlds
  /// Resident memory (bytes) above which commands that add bodies, joints or worlds are
  /// refused; 0: three quarters of the machine's memory.
  uint64_t memoryBudgetBytes = 0;
  uint32_t maxSnapshotFiles = 256;            ///< files in snapshotDir
  uint64_t maxSnapshotBytes = 4ull << 30;     ///< bytes of all files in snapshotDir
  uint32_t maxQueuedPerClient = 256;          ///< commands a client has waiting
  uint64_t maxQueuedBytes = 64ull << 20;      ///< payload bytes waiting, all clients
  uint64_t maxQueuedBytesPerClient = 16ull << 20;  ///< payload bytes one client has waiting
  /// Commands one client may send per second, on average, and at once (a token bucket per
  /// envelope key, refilled at the rate up to the burst); past it a command is answered
  /// ResourceExhausted at once, with Reply.retry_after_ms. 0: no limit. Only the commands
  /// that come while the client has some waiting are counted (here and per participant): a
  /// client with one request in flight is never refused for its rate.
  double maxClientCommandsPerS = 2000;
  double maxClientBurst = 500;
  // The same per DDS participant (Incoming::sender), whatever client ids it writes under, so
  // that one rotating ids costs what one client may (docs/SERVER.md "Budgets"). An SDK
  // client is one participant with one id.
  /// Client ids one participant may hold (the DDS endpoint's ClientKeys); its commands under
  /// others are dropped, one in a while answered ResourceExhausted.
  uint32_t maxKeysPerParticipant = 16;
  /// Commands per second and at once from one participant, all its ids together (0: no limit).
  double maxParticipantCommandsPerS = 2000;
  double maxParticipantBurst = 500;
  /// Payload bytes one participant may have waiting, all its ids together.
  uint64_t maxQueuedBytesPerParticipant = 16ull << 20;
  /// Refusals at submit (rate, queue) answered per participant and second (a bucket of as
  /// many); past it they are dropped unanswered and counted (refusalsDropped), so that a
  /// flood of refused commands does not become a flood of replies.
  double maxParticipantRefusalsPerS = 100;
  /// Interests (Subscribe) one client may hold in one world: per participant, or per client
  /// id for commands without one (in-process callers). Of a world's kMaxInterests, the last
  /// kInterestsForEditors are for clients that may change it (owner, editors).
  uint32_t maxInterestsPerClient = 8;
  /// Principals are DDS Security identities (identity keys, protocol/security.h), not client
  /// ids: physd runs with security ([security] in its config). Only wording here; the
  /// endpoint attributes commands.
  bool identities = false;
  /// Contact pairs per step of a world (WorldDef::maxContactPairs; 0: the engine's automatic
  /// bound). A step past it is not taken (PairOverflow::Refuse): the world pauses and a
  /// contact_budget event says why.
  uint32_t maxContactPairs = 0;
  /// A Step runs at most this long per tick; the rest continues at the next ticks (other
  /// commands and worlds are served between), and the reply goes out when it is done.
  double stepSliceSeconds = 0.02;
  /// LoadScenes built at once on loader threads (each may build a world as large as the
  /// budgets allow); past it: ResourceExhausted.
  uint32_t maxConcurrentLoads = 2;
  uint32_t bodiesPerChunk = protocol::kDefaultBodiesPerChunk;
  /// State frames: a keyframe (every body) at once for a new subscriber and after a world is
  /// replaced (load, reset, restore); deltas (the bodies whose state changed) in between, and
  /// every body sent again once per keyframeTicks frames, to repair what a subscriber lost:
  /// spread over the deltas (rollingRefresh: each carries the next keyframeTicks-th of the
  /// bodies) or as a whole keyframe every keyframeTicks frames. 1: every frame a keyframe.
  uint32_t keyframeTicks = 60;
  bool rollingRefresh = true;
  /// A stream whose deltas have carried no change for a whole period (a world at rest) sends
  /// its bodies again this many times less often.
  uint32_t quietKeyframeFactor = 10;
  /// CompactBodyState (40 bytes, bounded error: protocol/compact.h) instead of BodyState.
  bool compactStates = false;
  /// Encode state frames for worlds nobody subscribes to (in-process tests without DDS);
  /// physd encodes none for them.
  bool framesWithoutSubscribers = false;
  size_t frameRingCapacity = 4;  ///< state frame sets queued for the publisher
  double defaultRateHz = 60;     ///< Run without a rate
  /// Backend of worlds whose CreateWorld names none (start-up worlds: their `backend`).
  phys::Backend backend = phys::Backend::Cpu;
  bool gpuAllowCpuDevice = false;  ///< WorldDef::gpuAllowCpuDevice of every world
};

/// A command as it arrived: the envelope's key and seq, and the decoded payload (or why it
/// could not be decoded).
struct Incoming {
  uint64_t envelopeKey = 0;
  uint64_t envelopeSeq = 0;
  /// Who the command acts as for world access (owner, editors): on a secure daemon the
  /// identity key of the DDS Security identity that wrote it (protocol/security.h); 0: the
  /// envelope key (the client id).
  uint64_t principal = 0;
  /// The participant that wrote it proved, in its Hello, that it holds the key the envelope
  /// key (the client id) names (phys/protocol/client_key.h; the endpoint checks the proof).
  bool proven = false;
  /// The DDS participant that wrote it (ClientKeys' number, never reused; 0: none, an
  /// in-process caller): its budgets beside the key's, and its interests are freed when it
  /// leaves (ServerCore::clientsLeft).
  uint64_t sender = 0;
  size_t bytes = 0;  ///< payload size, for the queue's budget
  protocol::Decoded<wire::Command> command;
};

/// What a LoadScene asks for, captured on the tick thread (a loader thread reads only this
/// and the configuration).
struct SceneRequest {
  std::string sceneName;  ///< a scene of scenes_dir, or
  std::string json;       ///< inline JSON
  bool forReply = true;   ///< the new ids must fit in one reply
  uint64_t otherBodies = 0;  ///< bodies of the other worlds
  phys::Backend backend = phys::Backend::Cpu;  ///< the world's, unless the scene asks for more
};
/// A scene parsed, checked and built into a fresh world, not yet swapped in.
struct SceneLoad {
  Status status;
  phys::Scene scene;
  std::unique_ptr<phys::World> world;
  std::vector<phys::BodyId> bodyIds;
  std::vector<phys::JointId> jointIds;
};
/// A LoadScene run on a loader thread; `done` once `result` is set.
struct LoadTask {
  SceneRequest request;
  SceneLoad result;
  std::atomic<bool> done{false};
};

/// Time control of a world.
enum class RunMode : uint8_t { Paused, RealTime, AsFastAsPossible };

/// One world of the daemon: a phys::World plus what the protocol needs that the engine does
/// not keep (its name, access, time control, streams, numbers). What the world simulates,
/// its settings and its bodies' and joints' definitions, is read from the engine, the one
/// source (docs/ARCHITECTURE.md "One source of definitions").
struct ServerWorld {
  uint32_t id = 0;
  std::string name;
  std::string preset;
  std::unique_ptr<phys::World> world;
  /// Access (docs/SERVER.md "Access"): the client that created the world owns it (0: no
  /// owner, a start-up world: every client may do everything); editors may change it too,
  /// and with `shared` every client may. Reads are open to all.
  uint64_t owner = 0;
  std::vector<uint64_t> editors;
  bool shared = false;
  /// The owner proved its client id when it created the world (Incoming::proven, a daemon
  /// without DDS Security): only commands from a participant that proved its id may then act
  /// as the owner or an editor, so an id read off the wire is not enough to take the world.
  bool ownerProven = false;
  uint64_t tick = 0;      ///< steps since creation, reset or restore (restore: the saved tick)
  /// The world's tick sequence (StateFrame.epoch, docs/PROTOCOL.md "Order of frames"): one
  /// higher whenever its state is replaced rather than stepped or edited (framesReplaced:
  /// LoadScene, ResetWorld, RestoreSnapshot, a reload from its files), so that subscribers
  /// follow a world whose tick went back. A durable server starts each world's epochs above
  /// those of its earlier starts (ServerCore::epochBase_).
  uint64_t epoch = 1;
  /// Frames of edits published at this tick while the world did not step (a paused world's
  /// SetBodyPose, SpawnBodies, ...): 0 for the tick's own frame, then 1, 2, ...
  /// (StateFrame.edit).
  uint32_t edit = 0;
  uint64_t revision = 1;  ///< bumped on every structural change
  // Time control.
  RunMode mode = RunMode::Paused;
  double rateHz = 60;
  double accumulator = 0;  ///< steps owed to real time
  // Numbers.
  float tickMs = 0, tickMsMax = 0;  ///< last tick's step time; worst since the last status
  uint64_t overruns = 0;
  uint64_t framesProduced = 0;
  bool infoDirty = true;   ///< world info to publish
  bool frameDirty = true;  ///< a state frame to publish even without a step
  /// What the world's subscribers hold (ServerCore::queueFrame): the states of its last
  /// frames by body id, the bodies awake at the last frame, the bodies edited since
  /// (touched: poses, velocities, impulses, spawned, removed), when the last keyframe was.
  struct Published {
    /// What the stream's subscribers hold: the last state sent of each body in it, by
    /// protocol::refreshKey (the world's order, which the rolling refresh walks).
    std::map<uint64_t, phys::wire::BodyState> sent;
    std::vector<uint64_t> awake;
    bool valid = false;   ///< a keyframe went out and every frame since
    uint64_t sinceKeyframe = 0;
    /// The tick (and edit) of the last frame that carried something (a keyframe, a body, a
    /// removal): deltas apply to the state as of then, so losing an empty delta costs
    /// nothing.
    uint64_t baseTick = 0;
    uint32_t baseEdit = 0;
    bool changedSinceKeyframe = false;
    /// Readers ever matched to the stream's writer, as of the last frame: one more is a new
    /// subscriber, owed a keyframe now (even when another left meanwhile, the count the same).
    uint64_t matched = 0;
    uint64_t droppedSeen = 0;  ///< the publisher's dropped frames at the last frame
    uint64_t bytes = 0;        ///< of the last frame
    /// The rolling refresh: where the next one starts (a refreshKey) and whether a frame
    /// since the current round began carried a change.
    uint64_t refreshCursor = 0;
    bool changedThisRound = false;
  } published;
  std::vector<uint64_t> touched;  ///< bodies edited outside the step since the last frame
  uint64_t lastFrameTick = UINT64_MAX;  ///< the tick of the last queueFrame
  uint64_t lastFrameEpoch = 0;          ///< and its epoch
  /// Interests (Subscribe): streams of some of the world's bodies, each on its own topic.
  struct Interest {
    std::vector<uint64_t> ids;  ///< sorted; empty for a region
    uint64_t client = 0;        ///< who subscribed (may unsubscribe, as may the world's editors)
    uint64_t sender = 0;        ///< its participant (Incoming::sender; 0: none)
    bool region = false;
    phys::Vec3 lo, hi;          ///< the region
    Published published;
    bool contains(uint64_t id, const phys::BodyState& s) const {
      if (!region) return std::binary_search(ids.begin(), ids.end(), id);
      return s.position.x >= lo.x && s.position.y >= lo.y && s.position.z >= lo.z &&
             s.position.x <= hi.x && s.position.y <= hi.y && s.position.z <= hi.z;
    }
  };
  std::map<uint32_t, Interest> interests;
  uint32_t nextInterest = 1;
  static constexpr size_t kMaxInterests = 64;
  /// Of kMaxInterests, these are kept for clients that may change the world (its owner and
  /// editors; everyone on a shared world or one without an owner): readers fill at most the
  /// rest.
  static constexpr size_t kInterestsForEditors = 16;
  /// The world was replaced (load, reset, restore, reload): a new epoch, and every stream
  /// starts it from a keyframe.
  void framesReplaced() {
    ++epoch;
    published.valid = false;
    for (auto& [id, in] : interests) in.published.valid = false;
  }
  /// A Step longer than one slice (CoreConfig::stepSliceSeconds): its remaining steps run a
  /// slice per tick, its reply goes out when the last is taken.
  struct StepJob {
    uint64_t requested = 0, remaining = 0;
    protocol::ReplyHeader header;  ///< the Step's reply header
    uint64_t envelopeKey = 0, envelopeSeq = 0, sender = 0;
    uint64_t charge = 0;  ///< what the command holds of the queue's byte budgets
    double ms = 0;     ///< wall time spent so far
    /// Its Lease is durable (or none was needed): until then it takes no step.
    bool stored = true;
  };
  std::optional<StepJob> job;
  /// A LoadScene building on a loader thread: swapped in and answered by advance().
  struct LoadJob {
    std::shared_ptr<LoadTask> task;
    protocol::ReplyHeader header;
    uint64_t envelopeKey = 0, envelopeSeq = 0, sender = 0;
    uint64_t charge = 0;
  };
  std::optional<LoadJob> load;
  // Durability (store.h): null store for an ephemeral world or a server without a data
  // directory.
  bool ephemeral = false;
  std::unique_ptr<WorldStore> store;
  uint64_t checkpointTick = 0;
  /// The journal lets the world step up to this tick (its last Lease, or the tick of its
  /// last Mark, Pause or checkpoint): a step past it needs a new Lease first.
  uint64_t leaseUntil = 0;
  /// The furthest tick the world reached since its checkpoint: a reload (after a record
  /// that could not be stored) replays up to here, not to the end of a lease.
  uint64_t reachedTick = 0;
  /// A running world whose next Lease could not be stored: it takes no step until one can
  /// be (an event said so).
  bool held = false;
  bool checkpointFailed = false;  ///< the last try; retried a checkpoint period later
  std::chrono::steady_clock::time_point checkpointAt{};
  /// Commands for this world that arrived during its StepJob or LoadJob, applied in order
  /// after it.
  std::deque<Incoming> waiting;
  /// A MoveWorld under way (docs/SERVER.md "Moving a world"): the world is not stepped and
  /// its commands wait (busy()) until the target is Ready (the world leaves; they are
  /// answered Moved) or the move fails (they apply here).
  struct MoveJob {
    uint64_t target = 0, move = 0;
    protocol::ReplyHeader header;  ///< the MoveWorld's reply header
    uint64_t envelopeKey = 0, envelopeSeq = 0, sender = 0, charge = 0;
    std::chrono::steady_clock::time_point deadline;
    bool committed = false;  ///< Commit sent: the world is the target's, Done awaited
  };
  std::optional<MoveJob> moving;
  /// A world moved here is not stepped until as many readers as its stream had at the source
  /// have matched this daemon's writer (so that they see every tick), or holdUntil passes.
  uint32_t awaitSubscribers = 0;
  std::chrono::steady_clock::time_point holdUntil{};
  /// With a coordinator (docs/SERVER.md "Standby and takeover"): the mod revision of the
  /// world's key in etcd that names this daemon its owner (the ownership epoch; 0: not
  /// registered yet, so no standby can take it).
  uint64_t ownership = 0;
  /// Restored from disk with a coordinator: not served until the coordinator confirms that
  /// the world is still this daemon's (its standby may have taken it meanwhile).
  bool unconfirmed = false;
  /// Not served now: unconfirmed, or registered while this daemon's hold has lapsed. Not
  /// stepped, no frames, its commands wait (busy()).
  bool fenced = false;
  bool busy() const {
    return job.has_value() || load.has_value() || moving.has_value() || fenced;
  }
};


struct CoreCounters {
  uint64_t commands = 0;  ///< received
  uint64_t errors = 0;    ///< rejected (reply status not Ok)
  uint64_t steps = 0;     ///< world steps, all worlds
  uint64_t stepFailures = 0;  ///< steps that threw (world paused, event sent)
};

class ServerCore {
 public:
  explicit ServerCore(CoreConfig config);
  ~ServerCore();
  ServerCore(const ServerCore&) = delete;
  ServerCore& operator=(const ServerCore&) = delete;

  /// Loads the presets file. Without it only the engine's defaults exist (preset "default").
  Status init();

  const CoreConfig& config() const { return config_; }
  /// Whether this daemon is the one to take a command with this address (any thread; docs/
  /// SERVER.md "Several daemons"): one addressed to it (Command.daemon); an unaddressed one
  /// for a world whose id is of its range (it answers "no such world" for the ids of its
  /// range it does not hold); any unaddressed one when it is not in a cluster, and an
  /// unaddressed Hello always. The others are dropped unanswered: one daemon answers each,
  /// decided by the command alone. (A world held by another daemon than its range's is
  /// reached by commands addressed to its holder: the SDK addresses them.)
  bool takes(const protocol::CommandAddress& a) const;
  PublishQueue& out() { return out_; }

  // --- Start-up (tick thread or before it runs) ---
  /// A world with a preset (empty: the default), optionally a scene by name, and a backend
  /// ("cpu", "gpu", "auto"; empty: config().backend; a scene's other than "cpu" wins).
  Status createWorld(const std::string& name, const std::string& preset, const std::string& scene,
                     uint32_t* id, const std::string& backend = {}, bool ephemeral = false);
  Status setRun(uint32_t world, RunMode mode, double rateHz);
  /// Start-up, before any command: every world kept under config().dataDir, from its
  /// checkpoint and journal (docs/SERVER.md "Durable worlds"). `notes` gets a line per world
  /// restored and per thing dropped (a torn journal tail, an unreadable world).
  Status restoreWorlds(std::vector<std::string>* notes);
  /// Before restoreWorlds, with a coordinator: the kept worlds that other daemons hold now
  /// (world id -> daemon, read from etcd at start-up). They are not restored (a restart would
  /// replay them only to let them go): their files are set aside and their commands answered
  /// Moved. Worlds not named here are restored unconfirmed as before.
  void takenElsewhere(std::map<uint32_t, uint64_t> worlds) { takenElsewhere_ = std::move(worlds); }
  /// The world of that name, or null.
  ServerWorld* findWorld(const std::string& name);
  /// A world kept under dataDir that was not restored because restoring it would lose
  /// acknowledged data (its journal missing or damaged, its checkpoint unreadable): listed
  /// with `damage` (WorldSummary.damage), commands to it refused, its files untouched.
  struct DamagedWorld {
    uint32_t id = 0;
    std::string name;  ///< from its checkpoint; empty when that cannot be read
    std::string damage;
  };
  const std::map<uint32_t, DamagedWorld>& damagedWorlds() const { return damaged_; }
  /// Why edits are refused: the data directory could not be written at start-up (a full
  /// disk); empty when they are not. Retried every second; cleared when a write succeeds.
  const std::string& readOnly() const { return readOnly_; }
  /// Where the core reports what it does not answer to a client (a journal that cannot be
  /// synced, a failed checkpoint): physd logs it; the default prints to stderr.
  void setLog(std::function<void(bool error, const std::string& line)> log) { log_ = std::move(log); }
  /// A line to the daemon's log (any thread: the log function is spdlog's, thread-safe).
  void log(bool error, const std::string& line) const;
  /// Makes every world's journal durable and takes the checkpoints that are due (also done
  /// after each processPending and advance); for tests and shutdown.
  void commitDurable();
  /// Writes a world's checkpoint now (its journal starts empty); Ok for a world not kept.
  Status checkpointNow(uint32_t world);

  // --- Commands ---
  /// Applies one decoded command now and returns the reply payload. envelopeKey must equal
  /// the command's client id; principal, proven: Incoming::principal, Incoming::proven.
  Bytes apply(const wire::Command& command, uint64_t envelopeKey, uint64_t principal = 0,
              bool proven = false);
  /// Decodes and applies a raw payload as the daemon does (an undecodable payload is
  /// answered to client envelopeKey, seq envelopeSeq).
  Bytes applyBytes(std::span<const uint8_t> payload, uint64_t envelopeKey, uint64_t envelopeSeq);
  /// The reply for an Incoming (decoded or not).
  Bytes apply(const Incoming& in);

  /// Thread-safe: queues a command for the next tick boundary. A client with
  /// maxQueuedPerClient commands waiting, or a queue holding maxQueuedBytes, gets a
  /// ResourceExhausted reply at once instead.
  void submit(Incoming in);
  /// A Handoff from another daemon (docs/SERVER.md "Moving a world"), from the endpoint's
  /// reader thread with a Chunk's pieces put together; applied by the tick thread.
  struct HandoffIn {
    wire::HandoffKind kind = wire::HandoffKind::Chunk;
    uint32_t world = 0;
    uint64_t from = 0, move = 0, epoch = 0;
    uint32_t subscribers = 0;
    bool ephemeral = false;
    Status status;                    ///< Ready
    std::vector<uint8_t> checkpoint;  ///< Chunk: the whole world (encodeCheckpoint)
  };
  void submitHandoff(HandoffIn h);
  /// What the coordinator thread (Ownership, server/src/ownership.cpp) found in etcd, for the
  /// tick thread: a world registered (its ownership epoch), one another daemon took
  /// (StandDown), one this daemon takes over from its files (TakeOver), where a world that
  /// left this daemon is now (Elsewhere: its Moved answers name the current owner, not the
  /// first daemon it went to).
  struct OwnershipNote {
    enum class Kind : uint8_t { Registered, StandDown, TakeOver, Elsewhere };
    Kind kind = Kind::Registered;
    uint32_t world = 0;
    uint64_t revision = 0;  ///< Registered, TakeOver: the key's new mod revision
    uint64_t daemon = 0;    ///< StandDown, Elsewhere: who holds it now; TakeOver: who held it
    std::string dir;        ///< TakeOver: the world's directory in its owner's data
  };
  void submitOwnership(OwnershipNote n);
  /// The coordinator thread's latest renewal that succeeded allows serving until `until`.
  void holdUntil(std::chrono::steady_clock::time_point until);
  /// A kept world as the coordinator thread needs it (ownedWorlds).
  struct OwnedWorld {
    uint32_t id = 0;
    std::string dir;         ///< absolute
    uint64_t ownership = 0;  ///< ServerWorld::ownership
    bool unconfirmed = false;
  };
  /// Thread-safe: this daemon's kept worlds as of the last tick boundary; `fresh` false until
  /// the tick thread has written it once.
  std::vector<OwnedWorld> ownedWorlds(bool* fresh = nullptr) const;
  /// The worlds this daemon stands by for (coordinator thread, every round): their owner and
  /// directory. The tick thread keeps a replayed copy of each (a hot standby).
  struct Followed {
    std::string dir;
    uint64_t owner = 0;
  };
  void standBy(std::map<uint32_t, Followed> worlds);
  /// A TakeOver the tick thread could not carry out (the owner's files unreadable, a world of
  /// that id or name here already): the coordinator thread gives the world's key back to
  /// its owner (so the owner, restarted, restores the world) and tries again later.
  struct FailedTakeover {
    uint32_t world = 0;
    uint64_t revision = 0;  ///< the key's revision that named this daemon
    uint64_t owner = 0;     ///< who held it
    std::string dir;        ///< its directory in the owner's data
  };
  /// Thread-safe (coordinator thread): the takeovers that failed since the last call.
  std::vector<FailedTakeover> takeFailedTakeovers();
  /// Thread-safe: a status sample is wanted before the period ends (a world taken over).
  bool takeStatusWanted() { return statusWanted_.exchange(false); }
  bool coordinated() const { return !config_.coordinator.empty(); }
  /// Thread-safe: with a coordinator, whether this daemon's hold is renewed now (its
  /// registered worlds may be served).
  bool holding() const;
  /// Handoff pieces at most, and bytes of one move at most, that the endpoint puts together.
  static constexpr uint32_t kHandoffChunkBytes = 1u << 20;
  static constexpr uint32_t kMaxHandoffChunks = 2048;
  /// How long a source waits for Ready, and a target for Commit.
  static constexpr std::chrono::seconds kMoveTimeout{10};
  /// Thread-safe: clients are gone (the DDS endpoint: their participant's liveliness was
  /// lost). sender: its number (Incoming::sender; 0: none, then `keys` say whose); keys: the
  /// client ids it held. At the next tick boundary, after the commands queued before, the
  /// interests they held are removed (as an Unsubscribe would); their budgets are forgotten.
  void clientsLeft(uint64_t sender, std::vector<uint64_t> keys);
  /// Refusals at submit dropped unanswered (CoreConfig::maxParticipantRefusalsPerS).
  uint64_t refusalsDropped() const { return refusalsDropped_.load(); }
  /// Applies every queued command in arrival order, pushing the replies (and changed world
  /// info) to out(). Returns the number applied.
  size_t processPending();
  /// Waits until a command is queued or the timeout passes (the tick thread's sleep).
  void waitForCommands(std::chrono::microseconds timeout);

  // --- Time ---
  /// Advances every running world by wallSeconds of real time (RealTime: fixed steps from
  /// the accumulator, at most maxCatchUpSteps; AsFastAsPossible: one step), then queues a
  /// state frame for every world that stepped or changed. Returns steps taken.
  uint64_t advance(double wallSeconds);
  /// Steps world n times now (Step command); frames are queued by the next advance().
  Status stepWorld(uint32_t world, uint64_t n);
  /// Seconds until some running world owes a step (0 if one runs as fast as possible,
  /// `idle` when none runs).
  double secondsUntilDue(double idle) const;

  /// Pushes world info for every world whose description changed.
  void publishWorldInfo();
  /// Pushes a ServerStatus sample (and resets tick_ms_max).
  void publishStatus();
  /// Another daemon's status sample arrived (any thread): it is live for 3 of its periods
  /// (at least 2 s), and named in this daemon's status as a peer meanwhile.
  void notePeerStatus(uint64_t daemon, double periodS);
  /// Thread-safe: a peer's status lost its DDS liveliness (or its writer): not named from
  /// the next status on, which goes at once.
  void notePeerGone(uint64_t daemon);
  /// The other daemons seen live, by id.
  std::vector<uint64_t> livePeers() const;

  // --- Numbers and inspection ---
  protocol::ServerStatusInfo status() const;
  std::vector<protocol::WorldSummary> summaries() const;
  const CoreCounters& counters() const { return counters_; }
  const ServerWorld* world(uint32_t id) const;
  ServerWorld* world(uint32_t id);
  std::vector<uint32_t> worldIds() const;
  /// Thread-safe: matched state readers of a world (set by the publisher).
  void setSubscribers(uint32_t world, uint32_t n);
  /// An interest's stream (Subscribe); interest 0 is the world's own.
  void setSubscribers(uint32_t world, uint32_t interest, uint32_t n);
  /// The same with the readers ever matched (the DDS writer's total_count): one more than
  /// before is a new subscriber even when the count is the same (another left meanwhile).
  /// Without it, a count that grew stands for as many new ones. A stream with a new
  /// subscriber gets a keyframe at the tick thread's next turn, whatever the world does
  /// (paused, asleep, running).
  void setSubscribers(uint32_t world, uint32_t interest, uint32_t n, uint64_t matched);

  struct Context;  // per-command state (commands.cpp)

 private:
  friend struct Context;
  Bytes applyChecked(const wire::Command& command, uint64_t envelopeKey, uint64_t principal,
                     bool proven);
  /// GetBodies and GetJoints: the definitions asked for, as many as one reply holds, read
  /// from the engine (docs/PROTOCOL.md "Definitions"); *reply is set when Ok.
  Status readDefinitions(const ServerWorld& w, const wire::Command& c, ReplyHeader* header,
                         Bytes* reply) const;
  /// A world restored from engine state, against the codec's rules (the engine's own checks
  /// guard its invariants, not the protocol's ranges).
  Status checkRestored(const phys::World& w, const std::string& path) const;
  /// Whether principal `key` (Incoming::principal) may apply command c, sent under
  /// envelopeKey, to world w (docs/SERVER.md "Access"): PermissionDenied with who may, or Ok.
  /// proven: Incoming::proven.
  Status checkAccess(const ServerWorld& w, const wire::Command& c, uint64_t key,
                     uint64_t envelopeKey, bool proven) const;
  /// createWorld (start-up worlds) is making a world: it has no owner.
  bool startupCreate_ = false;
  /// The first interest id of every world is this + 1: a durable server's count of its
  /// starts, times 65536 (restoreWorlds), so interest topics are never reused across starts.
  uint32_t interestBase_ = 0;
  /// Every world's epoch is above this: a durable server's count of its starts, times 2^32
  /// (restoreWorlds), so a kept world's epochs go on rising across restarts without being
  /// stored (a read-only start does not count itself, but it cannot replace a world either).
  uint64_t epochBase_ = 0;
  Status queueFrame(ServerWorld& w);
  /// One stream of a world's frames (interest 0: the world's own); false when nothing was
  /// encoded (nobody subscribes to it, or nothing is owed: not fresh and no keyframe due).
  /// fresh: a new (tick, edit) of the world, which every stream gets a frame of.
  bool queueStream(ServerWorld& w, uint32_t interest, const ServerWorld::Interest* filter,
                   ServerWorld::Published* streamState, const std::vector<uint64_t>& awakeIds,
                   bool fresh);
  /// Applies one queued command: a reply is pushed now, or (a Step too long for one slice)
  /// when its job ends. Commands for a busy world wait for its job.
  void dispatch(Incoming in);
  /// A reply to a command: straight to out() or, on a durable server, held until the journals
  /// it depends on are synced (commitDurable). durableWorld: the world whose journal holds
  /// what the command changed (0: none); if that journal then fails, the reply becomes
  /// `failed` (the header of an error reply to the same command) instead.
  void pushReply(uint64_t key, uint64_t seq, Bytes reply, uint32_t durableWorld = 0,
                 const ReplyHeader* failed = nullptr);
  /// The reader thread's replies (refused at submit): never held.
  void pushReplyNow(uint64_t key, uint64_t seq, Bytes reply);
  /// Applies a command now (no queue): pushes its reply, unless it became a Step job.
  void applyNow(const Incoming& in);
  /// Runs about `seconds` (at least one step) of a world's StepJob; at its end pushes the
  /// Step's reply.
  void continueJob(ServerWorld& w, double seconds);
  /// Ends a world's job with `status` (its reply: the tick reached, steps done if not Ok).
  void endJob(ServerWorld& w, Status status);
  /// Ends a world's job early (Pause, ResetWorld, DestroyWorld): the Step's reply says so.
  void cancelJob(ServerWorld& w, const std::string& why);
  /// Applies the commands that waited for a world's job, until one starts a new job.
  void drainWaiting(uint32_t world);
  /// Bodies in every world.
  uint64_t totalBodies() const;
  /// Why a command adding `bodies` bodies and `joints` joints to world w (null: a new world,
  /// or one whose `replaced` bodies it replaces) may not, or Ok: per-world and daemon-wide
  /// counts, the memory budget.
  Status checkGrowth(const ServerWorld* w, uint64_t bodies, uint64_t joints,
                     const std::string& what, uint64_t replaced = 0) const;
  /// Loads a scene into a world now (LoadScene applied directly, start-up worlds). forReply:
  /// the ids must fit in one reply.
  Status loadScene(ServerWorld& w, const wire::LoadScene* request, const std::string& sceneName,
                   bool forReply, std::vector<uint64_t>* bodyIds, std::vector<uint64_t>* jointIds);
  SceneRequest sceneRequest(const ServerWorld& w, const wire::LoadScene* request,
                            const std::string& sceneName, bool forReply) const;
  /// Parses, checks and builds a scene (thread-safe: reads the configuration only).
  SceneLoad prepareScene(const SceneRequest& request) const;
  /// Swaps a prepared scene into a world (tick thread).
  void commitScene(ServerWorld& w, SceneLoad&& load, std::vector<uint64_t>* bodyIds,
                   std::vector<uint64_t>* jointIds);
  /// Starts a loader thread for a task.
  void startLoad(std::shared_ptr<LoadTask> task);
  /// Joins loader threads that are done (a cancelled load's world is freed with its task).
  void reapLoaders();
  /// Swaps in and answers a world's LoadJob when its task is done.
  void finishLoad(ServerWorld& w);
  /// Steps a world n times (tick, counters); returns the wall time in ms. What the engine's
  /// guard rails did in those steps goes out as events.
  double stepTimed(ServerWorld& w, uint64_t n);
  /// Why the last stepTimed stopped early (a step refused at the contact budget, or failed):
  /// Ok when every step was taken.
  Status stepProblem_;
  /// The server's step policy on a world's engine (contact budget, refuse past it).
  void applyPolicy(phys::World& w) const;
  void applyPolicy(phys::WorldDef* def) const;
  void queueEvent(const ServerWorld& w, wire::Severity severity, std::string_view code,
                  std::string_view message);
  std::unique_ptr<ServerWorld> makeWorld(const std::string& name, const std::string& preset,
                                         const phys::WorldDef& def);

  // --- Durability (durable.cpp) ---
  bool durable() const { return !config_.dataDir.empty(); }
  /// A new durable world's directory and first checkpoint (and the next world id on disk).
  Status createStore(ServerWorld& w);
  /// The world's whole state to its store (a new checkpoint; the journal starts empty).
  Status checkpointWorld(ServerWorld& w);
  /// The world as a checkpoint (its engine state and the server's view of it).
  Status checkpointOf(const ServerWorld& w, Checkpoint* out) const;

  // Moving worlds between daemons (docs/SERVER.md "Moving a world"; server/src/moves.cpp).
  /// MoveWorld: the world's checkpoint in Chunks to `to`; the world waits (MoveJob).
  Status startMove(ServerWorld& w, uint64_t to, const ReplyHeader& header);
  /// A Handoff (tick thread): a Chunk builds the world here and answers Ready; Ready ends
  /// the source's move; Commit runs the world here; Abort drops it.
  void applyHandoff(HandoffIn h);
  void adoptWorld(HandoffIn& h);
  /// The source's end of a move: Ok lets the world go (Commit, the waiting commands answered
  /// Moved), otherwise it stays and steps on here.
  void finishMove(ServerWorld& w, Status status);
  /// Moves whose answer did not come in time fail; worlds built here and not committed in
  /// time are dropped.
  void expireMoves();
  void pushHandoff(uint64_t to, const protocol::HandoffInfo& info,
                   std::span<const uint8_t> bytes = {});
  /// A world moved here that still waits for its subscribers (ServerWorld::awaitSubscribers).
  bool heldForSubscribers(ServerWorld& w);
  /// Worlds that moved from here, and where to (commands for them are answered Moved); a
  /// durable daemon keeps them in <dataDir>/moved_out (keepMovedOut), read at start.
  std::map<uint32_t, uint64_t> movedOut_;
  void keepMovedOut();
  /// The world leaves this daemon for daemon `to` (moved, taken over): its writers go after
  /// the tick's replies, its commands are answered Moved from now on (kept across restarts).
  void letGo(uint32_t id, uint64_t to);
  /// A world came to this daemon (moved here, taken over): its info and frames go out again.
  void announceHere(uint32_t id);
  /// Worlds that left in this batch: their WorldRemoved goes to the publisher after the
  /// batch's replies, since deleting a state writer waits for its readers' acknowledgements
  /// (about 90 ms measured with one subscriber), which held the MoveWorld's reply back.
  std::vector<uint32_t> movedAway_;
  uint64_t nextMove_ = 1;
  /// Worlds built from a Handoff, held until the source commits.
  struct Prepared {
    std::unique_ptr<ServerWorld> world;
    uint64_t from = 0, move = 0;
    std::chrono::steady_clock::time_point deadline;
  };
  std::vector<Prepared> prepared_;

  /// After a command replaced a world's state (LoadScene, ResetWorld, RestoreSnapshot): a
  /// checkpoint, or, when it cannot be written, the world as its files hold it and an error.
  Status durableReplaced(ServerWorld& w, const std::string& what);
  /// Journals an applied command (Ok, a kind that changes the world): false when it could
  /// not be stored (the world is then reloaded from its files and *reply says why).
  void journalApplied(const Incoming& in, Bytes* reply);
  /// Journals the tick a world reached and its run state (ends its lease there).
  Status journalMark(ServerWorld& w);
  /// Makes sure the world's journal lets it step to tick `until`: Ok at once when its lease
  /// covers it (or the world is not kept), else appends a Lease to `until` and, with
  /// syncNow, makes it durable. On failure nothing is left of the lease in the journal.
  Status leaseTo(ServerWorld& w, uint64_t until, bool syncNow, bool* appended = nullptr);
  /// Worlds whose journal a failed sync in leaseTo cut back past records that held replies
  /// wait for: commitDurable fails those replies and reloads the world.
  std::vector<std::pair<uint32_t, Status>> lostRecords_;
  /// The steps a running world takes now (n), after its lease: 0 while it cannot be stored
  /// (the world is held, and an event says so; another when it goes on).
  uint64_t leaseForRun(ServerWorld& w, uint64_t n);
  /// Why a command that must be stored is refused on a read-only server (Ok otherwise).
  Status checkWritable(const ServerWorld* w, const wire::Command& c) const;
  /// A world that could not be restored (restoreWorlds), listed and announced.
  void addDamaged(uint32_t id, const std::string& name, const std::string& damage);
  void queueEvent(uint32_t world, uint64_t tick, wire::Severity severity, std::string_view code,
                  std::string_view message);
  /// Rebuilds a world in place from its store (checkpoint + journal): after a journal that
  /// could not be written. It comes back at the tick it had reached (reachedTick), not past.
  Status reloadWorld(ServerWorld& w, std::vector<std::string>* notes);
  /// Replays: the checkpoint, then each record at its tick, then the steps of a lease still
  /// open at the end, up to stopAt.
  Status restoreInto(ServerWorld& w, const Checkpoint& c, const std::vector<JournalRecord>& records,
                     std::vector<std::string>* notes, uint64_t stopAt = UINT64_MAX);
  /// restoreInto in three parts, for a standby that replays a journal as it grows: the
  /// checkpoint; the records from replay->applied on (each at its tick; the world in worlds_
  /// meanwhile, as commands find their world there); the steps of a lease still open, up
  /// to stopAt, and the bookkeeping of a world that is served again.
  struct Replay {
    size_t applied = 0;  ///< records replayed
    uint64_t lease = 0;
    bool leaseOpen = false;
    bool stopped = false;  ///< a step or a record failed: nothing more is replayed
  };
  Status beginReplay(ServerWorld& w, const Checkpoint& c);
  void replayRecords(ServerWorld& w, const std::vector<JournalRecord>& records, Replay* replay,
                     std::vector<std::string>* notes);
  void endReplay(ServerWorld& w, Replay& replay, std::vector<std::string>* notes,
                 uint64_t stopAt = UINT64_MAX);
  /// A world this daemon stands by for, replayed from its owner's files as they grow
  /// (followOwners, takeover.cpp): what a takeover starts from.
  struct Shadow {
    std::unique_ptr<ServerWorld> world;
    std::string dir;
    uint64_t owner = 0;
    uint64_t inode = 0;  ///< the checkpoint file replayed from (another one: rebuilt)
    int64_t mtimeNs = 0;
    CheckpointMeta meta;
    uint32_t crc = 0;     ///< the checkpoint's, as its journal's header names it
    Replay replay;
    uint64_t journalBytes = 0;  ///< the journal's size when last read
  };
  std::map<uint32_t, Shadow> shadows_;
  std::map<uint32_t, uint64_t> takenElsewhere_;  ///< restoreWorlds skips these
  std::chrono::steady_clock::time_point followedAt_{};
  /// Every renewPeriodS: each shadow brought up to its owner's files.
  void followOwners();
  Status follow(uint32_t id, Shadow& sh, std::vector<std::string>* notes);
  /// Replies held until the journals are synced (pushReply).
  struct HeldReply {
    uint64_t key = 0, seq = 0;
    Bytes reply;
    uint32_t durableWorld = 0;
    bool hasFailed = false;
    ReplyHeader failed;
  };
  std::vector<HeldReply> held_;
  /// Restoring: replayed commands are not journaled, budgets are not checked again (they
  /// held when the command was first applied), events are not sent.
  bool replaying_ = false;
  /// The world whose journal the command applyNow is applying went to (0: none).
  uint32_t journaledWorld_ = 0;
  /// The status of the last command applyChecked answered.
  Status lastStatus_;
  /// `<dataDir>/lock`, flock'ed by restoreWorlds for the core's life: two daemons never
  /// write one data directory.
  int dataLock_ = -1;
  std::map<uint32_t, DamagedWorld> damaged_;
  std::string readOnly_;
  uint64_t starts_ = 0;  ///< this start's number (<dataDir>/starts), written when writable
  std::chrono::steady_clock::time_point readOnlyRetryAt_{};
  /// Read-only: tries to write <dataDir>/starts again (once a second); clears readOnly_.
  void retryWritable();
  /// Takes <dataDir>/lock (dataLock_).
  Status lockData();
  /// Writes starts_ to <dataDir>/starts.
  Status writeStarts();
  std::function<void(bool, const std::string&)> log_;

  CoreConfig config_;
  std::map<std::string, phys::Preset> presets_;
  std::string defaultPreset_;
  std::map<uint32_t, std::unique_ptr<ServerWorld>> worlds_;
  uint32_t nextWorldId_ = 1;
  /// The next world id is past `id` (of this daemon's range, in a cluster).
  void reserveWorldId(uint32_t id);
  CoreCounters counters_;
  std::chrono::steady_clock::time_point started_;
  PublishQueue out_;

  mutable std::mutex peersMutex_;
  /// Other daemons' last status: when it came and how long it counts (3 periods, >= 2 s).
  std::map<uint64_t, std::pair<std::chrono::steady_clock::time_point, double>> peersSeen_;

  // Standby and takeover (server/src/takeover.cpp).
  std::deque<OwnershipNote> ownershipNotes_;  ///< under inboxMutex_
  std::atomic<int64_t> holdUntilNs_{0};       ///< steady clock; 0: never renewed
  void applyOwnership(OwnershipNote& n);
  void takeOver(OwnershipNote& n);
  void standDown(uint32_t id, uint64_t daemon);
  /// Sets each world's fenced flag from its registration and the hold.
  void updateFences();
  void refreshOwned();
  mutable std::mutex ownedMutex_;
  std::vector<OwnedWorld> owned_;  ///< under ownedMutex_
  std::map<uint32_t, Followed> standbyFor_;  ///< under ownedMutex_
  std::vector<FailedTakeover> failedTakeovers_;  ///< under ownedMutex_
  bool ownedFresh_ = false;        ///< under ownedMutex_
  std::atomic<bool> statusWanted_{false};
  /// Replies of registered worlds that were ready while the hold had lapsed: sent once it is
  /// renewed, dropped if the world was taken (what they acknowledge is in its journal, which
  /// the new owner replays; an acknowledgement from a daemon that may be deposed is not sent).
  std::vector<HeldReply> parked_;

  std::mutex inboxMutex_;
  std::condition_variable inboxCv_;
  std::deque<Incoming> inbox_;
  std::deque<HandoffIn> handoffs_;  ///< under inboxMutex_
  // Commands submitted and not yet answered (queued, waiting for a world, or a Step job),
  // per client and in bytes; guarded by inboxMutex_.
  struct Pending {
    uint32_t commands = 0;
    uint64_t bytes = 0;
  };
  std::map<uint64_t, Pending> pendingPerClient_;
  /// A token bucket: refilled at a rate up to a burst.
  struct RateBucket {
    double tokens = 0;
    std::chrono::steady_clock::time_point last;
    /// Refills it to `now`; whether a token is there (not taken). rate 0: always.
    bool ready(double rate, double burst, std::chrono::steady_clock::time_point now);
  };
  /// Each client's token bucket (maxClientCommandsPerS); guarded by inboxMutex_.
  std::unordered_map<uint64_t, RateBucket> rates_;
  /// rates_ is combed for idle buckets when it reaches this size (then twice what is left, at
  /// least 65536: amortised O(1) per command).
  size_t ratesCombAt_ = 65536;
  /// The client's bucket, made full on first use (inboxMutex_ held).
  RateBucket& bucketOf(uint64_t client, std::chrono::steady_clock::time_point now);
  /// What one participant has waiting and may send (Incoming::sender); guarded by inboxMutex_,
  /// forgotten when it leaves.
  struct SenderBudget {
    Pending pending;
    RateBucket commands;
    RateBucket refusals;  ///< refusals answered (maxParticipantRefusalsPerS)
  };
  std::unordered_map<uint64_t, SenderBudget> senders_;
  /// Clients gone (clientsLeft), applied by processPending after the commands before them.
  struct Left {
    uint64_t sender = 0;
    std::vector<uint64_t> keys;
  };
  std::vector<Left> left_;  ///< guarded by inboxMutex_
  /// Removes the interests of clients that left.
  void applyLeft(const Left& l);
  uint64_t pendingBytes_ = 0;
  /// Reply.retry_after_ms of a refusal for commands waiting (the client's or participant's
  /// queue: its own replies free it) and for the server's whole queue.
  static constexpr uint32_t kQueueRetryMs = 10, kServerQueueRetryMs = 50;
  std::atomic<uint64_t> refusedAtSubmit_{0};
  std::atomic<uint64_t> refusalsDropped_{0};
  /// Bytes a queued command holds of the queue's budgets: its payload and what holding it
  /// costs beside.
  static uint64_t queueCharge(const Incoming& in) { return uint64_t(in.bytes) + 256; }
  /// A submitted command was answered: its place in the queue's budgets is free.
  void release(const Incoming& in);
  void release(uint64_t envelopeKey, uint64_t sender, uint64_t chargedBytes);
  // The command dispatch() is applying: a Step too long for one slice becomes a job that
  // answers it later (apply() then returns no reply and sets deferred_).
  const Incoming* current_ = nullptr;
  bool deferred_ = false;
  /// Loader threads (LoadScene from the queue), joined when done and at destruction.
  std::vector<std::pair<std::thread, std::shared_ptr<LoadTask>>> loaders_;

  mutable std::mutex subscribersMutex_;
  struct Subscribers {
    uint32_t now = 0;      ///< matched readers
    uint64_t matched = 0;  ///< readers ever matched
  };
  std::map<uint64_t, Subscribers> subscribers_;  ///< by streamKey(world, interest)
  /// Worlds with a stream whose subscribers changed since the tick thread last looked
  /// (under subscribersMutex_): advance() queues their frames, so a new subscriber's
  /// keyframe goes out even while the world does not step.
  std::vector<uint32_t> subscribersChanged_;
  std::atomic<bool> anySubscribersChanged_{false};  ///< wakes waitForCommands
};

/// The tick thread: at each boundary applies queued commands, advances time, publishes
/// world info changes and, every statusPeriod, a status sample. Never calls DDS.
class TickThread {
 public:
  TickThread(ServerCore* core, std::chrono::milliseconds statusPeriod = std::chrono::seconds(1));
  ~TickThread();  ///< stops
  void start();
  void stop();
  uint64_t ticks() const { return ticks_.load(); }

 private:
  void run();
  ServerCore* core_;
  std::chrono::milliseconds statusPeriod_;
  std::atomic<bool> stop_{false};
  std::atomic<uint64_t> ticks_{0};
  std::thread thread_;
};

}  // namespace phys::server
