// Builders: every payload of the protocol from plain C++ values (phys types where the engine
// has them, the generated wire structs for fixed-size records). Every function returns a
// finished FlatBuffer with its root type's file identifier, ready for an Envelope.
//
// Builders do not validate: they write what they are given, so a client learns about a bad
// value from the server's reply (or from decodeCommand, which a client may run locally).
#pragma once

#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "flatbuffers/flatbuffers.h"
#include "phys/protocol/limits.h"
#include "phys/protocol/status.h"
#include "phys/protocol/wire.h"
#include "phys/defs/body_def.h"
#include "phys/defs/joint_def.h"
#include "phys/defs/world_def.h"

namespace phys::protocol {

using Bytes = std::vector<uint8_t>;

// ---------------------------------------------------------------------------------------------
// Commands

/// Correlation and target of a command. clientId is the Envelope key on phys/cmd.
struct CommandHeader {
  uint64_t clientId = 0;  ///< non-zero, unique per client process
  uint64_t seq = 0;       ///< increasing per client; echoed in the reply
  uint32_t world = 0;     ///< target world; 0 for hello, createWorld, listWorlds
  /// The daemon (server.id) to take it; 0: the world's owner (Command.daemon).
  uint64_t daemon = 0;
  /// Command.daemon is written even when 0, so that setCommandDaemon can set it in place
  /// (8 bytes more).
  bool addressable = false;
};

struct CreateWorldArgs {
  std::string name;                   ///< required, unique per server
  std::string preset;                 ///< solver preset; empty: the server's default
  std::optional<phys::Vec3> gravity;  ///< m/s^2; absent: (0, 0, -9.81)
  float timeStep = 0;                 ///< s; 0: 1/60
  /// "cpu", "gpu" or "auto" (phys::toString(Backend)); empty: the server's default.
  std::string backend = {};
  /// Islands and sleeping (phys::SleepSettings, the default thresholds); worlds sleep unless
  /// this says otherwise.
  bool sleep = true;
  /// Not kept on a durable server's disk (docs/SERVER.md "Durable worlds"): a restart loses
  /// it, and its commands are answered without waiting for a disk.
  bool ephemeral = false;
  /// Access (docs/SERVER.md "Access"): the creating client owns the world; these clients may
  /// change it too; shared: any client may.
  std::vector<uint64_t> editors = {};
  bool shared = false;
};

/// Solver settings to change; unset fields keep the world's current value. One member per
/// row of PHYS_SOLVER_FIELDS (phys/defs/solver_settings.h), named as SolverSettings'.
struct SolverOverrides {
#define PHYS_SOLVER_OVERRIDE(type, member, ...) \
  std::optional<decltype(phys::SolverSettings::member)> member;
  PHYS_SOLVER_FIELDS(PHYS_SOLVER_OVERRIDE)
#undef PHYS_SOLVER_OVERRIDE

  /// Every field set from s.
  static SolverOverrides from(const phys::SolverSettings& s);
  /// Whether no field is set.
  bool empty() const;
};

/// World settings to change (SetWorld; WorldSettings in physics.fbs), named as
/// phys::WorldDef's; unset fields keep the world's current value.
struct WorldOverrides {
  // One optional per row of PHYS_WORLD_FIELDS (phys/defs/world_def.h), named as its member:
  // gravity, timeStep, sleep (SleepSettings::enabled), sleepTime, sleepLinearSpeed, ...
#define PHYS_WORLD_OVERRIDE(type, member, ...) std::optional<type> member;
  PHYS_WORLD_FIELDS(PHYS_WORLD_OVERRIDE)
#undef PHYS_WORLD_OVERRIDE

  /// Every field set from d.
  static WorldOverrides from(const phys::WorldDef& d);
  /// Whether no field is set.
  bool empty() const;
};

/// Builds one command. Each call appends a request; finish() makes a plain command of a
/// single request and a Batch (all-or-nothing, one tick boundary) of several, which the
/// server accepts only when every request is batchable (decoder.h: isBatchable).
///
///   Bytes b = CommandBuilder().step(10).finish({clientId, seq, world});
///
/// Ids are phys handles packed with BodyId::packed() (generation << 32 | index).
class CommandBuilder {
 public:
  CommandBuilder() = default;

  CommandBuilder& hello(std::string_view clientName, uint16_t version = kProtocolVersion);
  /// Hello with a client key's binding proof (phys/protocol/client_key.h): the command's
  /// client id must be the key's.
  CommandBuilder& hello(std::string_view clientName, std::span<const uint8_t> publicKey,
                        std::span<const uint8_t> proof);
  CommandBuilder& createWorld(const CreateWorldArgs& args);
  CommandBuilder& destroyWorld();
  CommandBuilder& resetWorld();
  CommandBuilder& listWorlds();
  CommandBuilder& loadSceneJson(std::string_view json);
  CommandBuilder& loadSceneNamed(std::string_view sceneName);
  /// Hull shapes send their hull's vertices; the server rebuilds the hull.
  CommandBuilder& spawnBodies(std::span<const phys::BodyDef> bodies);
  CommandBuilder& removeBodies(std::span<const uint64_t> ids);
  /// JointDef.bodyA/bodyB are written packed; a null bodyA anchors to the world.
  CommandBuilder& addJoints(std::span<const phys::JointDef> joints);
  CommandBuilder& removeJoints(std::span<const uint64_t> ids);
  CommandBuilder& setBodyPose(std::span<const wire::BodyPose> items);
  CommandBuilder& setBodyPose(uint64_t id, phys::Vec3 position, phys::Quat rotation);
  CommandBuilder& setBodyVelocity(std::span<const wire::BodyVelocity> items);
  CommandBuilder& setBodyVelocity(uint64_t id, phys::Vec3 linear, phys::Vec3 angular);
  /// Forces act during the next step only.
  CommandBuilder& applyForce(std::span<const wire::BodyForce> items, wire::PointFrame frame);
  CommandBuilder& applyForce(uint64_t id, phys::Vec3 force, phys::Vec3 point = {},
                             wire::PointFrame frame = wire::PointFrame::CenterOfMass);
  /// Impulses change velocities when the command is applied.
  CommandBuilder& applyImpulse(std::span<const wire::BodyForce> items, wire::PointFrame frame);
  CommandBuilder& applyImpulse(uint64_t id, phys::Vec3 impulse, phys::Vec3 point = {},
                               wire::PointFrame frame = wire::PointFrame::CenterOfMass);
  CommandBuilder& applyTorque(std::span<const wire::BodyTorque> items);
  CommandBuilder& applyTorque(uint64_t id, phys::Vec3 torque);
  CommandBuilder& setMaterial(std::span<const uint64_t> ids, const phys::Material& material);
  /// preset first (empty: none), then the overrides.
  CommandBuilder& setSolver(std::string_view preset, const SolverOverrides& overrides = {});
  CommandBuilder& step(uint32_t count = 1);
  /// rateHz: steps per wall-clock second; 0: as fast as possible.
  CommandBuilder& run(float rateHz);
  CommandBuilder& pause();
  /// ids empty: every body, paged by first / maxCount (0: as many as fit).
  /// An interest (docs/PROTOCOL.md "Interests"): these bodies, or those inside the box.
  CommandBuilder& subscribeBodies(std::span<const uint64_t> ids);
  CommandBuilder& subscribeRegion(phys::Vec3 lo, phys::Vec3 hi);
  CommandBuilder& unsubscribe(uint32_t interest);
  /// The world to that daemon (server.id): docs/SERVER.md "Moving a world".
  CommandBuilder& moveWorld(uint64_t daemon);
  /// The world's owner only: who else may change it.
  CommandBuilder& setAccess(std::span<const uint64_t> editors, bool shared);
  CommandBuilder& queryState(std::span<const uint64_t> ids = {}, uint32_t first = 0,
                             uint32_t maxCount = 0);
  /// file: also (or only, with returnBytes false) written on the server under that name.
  CommandBuilder& saveSnapshot(std::string_view file = {}, bool returnBytes = true);
  CommandBuilder& restoreSnapshot(std::span<const uint8_t> snapshot);
  CommandBuilder& restoreSnapshotFile(std::string_view file);
  /// World settings (a world edit, batchable): those set change.
  CommandBuilder& setWorld(const WorldOverrides& settings);
  /// Reads (docs/PROTOCOL.md "Definitions"): the world's settings; the definitions of these
  /// bodies or joints, or of every one paged by first / maxCount (0: as many as fit).
  CommandBuilder& getWorld();
  CommandBuilder& getBodies(std::span<const uint64_t> ids = {}, uint32_t first = 0,
                            uint32_t maxCount = 0);
  CommandBuilder& getJoints(std::span<const uint64_t> ids = {}, uint32_t first = 0,
                            uint32_t maxCount = 0);

  /// Escape hatch for requests built by hand on fbb() (tests, extensions).
  CommandBuilder& raw(wire::Request type, flatbuffers::Offset<void> table);
  flatbuffers::FlatBufferBuilder& fbb() { return fbb_; }

  size_t requestCount() const { return items_.size(); }
  wire::Request requestType(size_t i) const { return items_.at(i).first; }
  /// The finished command; the builder is empty again afterwards.
  Bytes finish(const CommandHeader& header);

 private:
  CommandBuilder& add(wire::Request type, flatbuffers::Offset<void> table);
  flatbuffers::FlatBufferBuilder fbb_;
  std::vector<std::pair<wire::Request, flatbuffers::Offset<void>>> items_;
};

// ---------------------------------------------------------------------------------------------
// Replies

struct ReplyHeader {
  uint64_t clientId = 0;
  uint64_t seq = 0;
  uint32_t world = 0;  ///< the target world; CreateWorld: the new world's id
  uint64_t tick = 0;   ///< the world's tick when the command took effect
  Status status;
  /// A refusal of the daemon's rate and queue budgets: the command may be sent again as it is
  /// after this many ms (Reply.retry_after_ms); 0: not such a refusal.
  uint32_t retryAfterMs = 0;
  uint64_t owner = 0;  ///< Moved: the daemon that holds the world now (Reply.owner)
};
/// Header echoing a command's correlation and world, with the given status.
ReplyHeader replyTo(const wire::Command& command, Status status = {});

struct HelloInfo {
  std::string serverName;
  std::string serverVersion;
  std::vector<std::string> features;
  Limits limits;  ///< announced as LimitsInfo
  bool clientProven = false;  ///< the Hello's binding proof was checked
};

/// One world, as ListWorlds and ServerStatus report it.
struct WorldSummary {
  uint32_t world = 0;
  std::string name;
  std::string preset;
  uint32_t bodies = 0, joints = 0;
  uint64_t tick = 0;
  double time = 0;  ///< s, simulated
  bool running = false;
  float rateHz = 0;
  float tickMs = 0, tickMsMax = 0;
  uint64_t overruns = 0;
  uint32_t subscribers = 0;
  uint64_t frames = 0;  ///< state frames handed to the publisher
  std::string backend;  ///< where the world runs: "cpu" or "gpu" (BackendState::active)
  std::string device;   ///< the Vulkan device's name when on the GPU, else empty
  /// Why the CPU runs a world that asked for the GPU (BackendState::note), or why the last
  /// CPU-taken step of a GPU world was not on the device; empty when there is nothing to say.
  std::string backendNote;
  uint64_t gpuSteps = 0, cpuSteps = 0;  ///< steps taken on the device / by the CPU backend
  uint32_t awakeBodies = 0;     ///< bodies the world steps (not static, not asleep)
  uint32_t sleepingBodies = 0;  ///< dynamic bodies asleep
  uint32_t frameBytes = 0;      ///< bytes of the last state frame (0: none encoded)
  uint32_t contacts = 0;        ///< contacts the last step collided
  uint64_t stepBufferBytes = 0; ///< bytes held by the world's step buffers
  /// A world kept on disk but not restored (its files damaged): why; empty for a world
  /// that runs.
  std::string damage;
  uint64_t daemon = 0;  ///< the daemon (server.id) that owns the world
  uint64_t movingTo = 0;  ///< a MoveWorld under way: the daemon it goes to (0: none)
};

/// A reply without a result (errors; Pause, DestroyWorld, ...).
Bytes encodeReply(const ReplyHeader& header);
Bytes encodeHelloReply(const ReplyHeader& header, const HelloInfo& info);
Bytes encodeIdsReply(const ReplyHeader& header, std::span<const uint64_t> bodies,
                     std::span<const uint64_t> joints = {});
Bytes encodeWorldListReply(const ReplyHeader& header, std::span<const WorldSummary> worlds);
/// stampNs: the wall clock when the states were read (as a frame's); epoch: the world's.
Bytes encodeStateReply(const ReplyHeader& header, double time, uint32_t total,
                       std::span<const wire::BodyState> bodies, uint64_t stampNs = 0,
                       uint64_t epoch = 0);
/// snapshot: a Snapshot buffer (encodeSnapshot), may be empty; file: where it was saved.
Bytes encodeInterestReply(const ReplyHeader& header, uint32_t interest, std::string_view topic);
Bytes encodeSnapshotReply(const ReplyHeader& header, std::span<const uint8_t> snapshot,
                          std::string_view file = {});

// ---------------------------------------------------------------------------------------------
// Published data

struct FrameHeader {
  uint32_t world = 0;
  uint64_t tick = 0;
  double time = 0;       ///< s, simulated
  uint64_t stampNs = 0;  ///< wall clock (ns since the Unix epoch) when the states were read
  bool keyframe = true;  ///< every body; false: a delta on the frame of baseTick
  uint64_t baseTick = 0;
  bool compact = false;  ///< CompactBodyState instead of BodyState (compact.h)
  uint32_t interest = 0;  ///< 0: the whole world; else an interest's stream
  /// A delta's refresh: it also carries every body of the stream whose order key
  /// (refreshKey) is in [refreshLo, refreshHi); refreshHi 0: none; UINT64_MAX: to the end.
  uint64_t refreshLo = 0, refreshHi = 0;
  /// The order of frames (docs/PROTOCOL.md "Order of frames"): the world's epoch, the edit
  /// number at this tick (0: the tick's own frame; 1, 2, ...: a paused world's edits), and the
  /// edit number of the frame a delta applies to (with baseTick).
  uint64_t epoch = 0;
  uint32_t edit = 0, baseEdit = 0;
};
/// A body's place in a stream's rolling refresh: (index << 32) | generation, the world's
/// order (a packed id is generation << 32 | index). Its own inverse.
inline constexpr uint64_t refreshKey(uint64_t packedId) {
  return (packedId << 32) | (packedId >> 32);
}
/// One chunk. A delta's chunk 0 carries `removed`; totalBodies is the world's count.
Bytes encodeStateFrame(const FrameHeader& header, uint32_t chunkIndex, uint32_t chunkCount,
                       uint32_t totalBodies, std::span<const wire::BodyState> bodies,
                       std::span<const uint64_t> removed);
Bytes encodeStateFrame(const FrameHeader& header, uint32_t chunkIndex, uint32_t chunkCount,
                       uint32_t totalBodies, std::span<const wire::BodyState> bodies);
/// One tick's states split into chunks of at most bodiesPerChunk (>= 1); at least one chunk.
/// A keyframe's totalBodies is bodies.size(); a delta's is given (the world's count).
std::vector<Bytes> encodeStateFrames(const FrameHeader& header,
                                     std::span<const wire::BodyState> bodies,
                                     uint32_t bodiesPerChunk = kDefaultBodiesPerChunk,
                                     std::span<const uint64_t> removed = {},
                                     uint32_t totalBodies = UINT32_MAX);

/// A body or joint with its id, as WorldInfo and Snapshot carry them.
struct BodyEntry {
  uint64_t id = 0;
  phys::BodyDef def;
};
struct JointEntry {
  uint64_t id = 0;
  phys::JointDef def;  ///< bodyA / bodyB as ids of the same world
};

struct WorldInfoHeader {
  uint32_t world = 0;
  std::string name;
  uint64_t revision = 0;
  uint64_t tick = 0;
  phys::Vec3 gravity{0, 0, -9.81f};
  float timeStep = 1.0f / 60;
  uint64_t daemon = 0;  ///< the owner (server.id)
};
/// The world split into chunks of at most limits.maxBodiesPerCommand bodies and about half of
/// limits.maxMessageBytes each (bodies first, then joints); at least one chunk.
std::vector<Bytes> encodeWorldInfo(const WorldInfoHeader& header, std::span<const BodyEntry> bodies,
                                   std::span<const JointEntry> joints, const Limits& limits = {});

struct ServerStatusInfo {
  std::string serverName;
  std::string serverVersion;
  double uptimeS = 0;
  uint64_t commands = 0;  ///< received
  uint64_t errors = 0;    ///< rejected
  std::vector<WorldSummary> worlds;
  uint64_t framesDropped = 0;  ///< state frames dropped by the publisher's ring
  uint64_t heapBytes = 0;      ///< bytes in use in the daemon's heap (glibc mallinfo2)
  std::string readOnly;        ///< why edits of kept worlds are refused; empty: they are not
  uint64_t daemon = 0;         ///< server.id
  bool cluster = false;        ///< in a domain of daemons (ServerStatus.cluster)
  float statusPeriodS = 0;     ///< s between samples
  std::vector<uint64_t> peers; ///< the other live daemons of the domain it has seen, by id
};
Bytes encodeServerStatus(const ServerStatusInfo& status);

/// A Handoff between daemons (phys/peer): a chunk of a moving world (with its bytes), or a
/// step of the move (Ready with its status, Commit, Abort).
struct HandoffInfo {
  wire::HandoffKind kind = wire::HandoffKind::Chunk;
  uint32_t world = 0;
  uint64_t from = 0, to = 0, move = 0, epoch = 0;
  uint32_t subscribers = 0;
  uint32_t chunkIndex = 0, chunkCount = 0;
  Status status;
  bool ephemeral = false;
};
Bytes encodeHandoff(const HandoffInfo& info, std::span<const uint8_t> bytes = {});

Bytes encodeEvent(uint32_t world, uint64_t tick, wire::Severity severity, std::string_view code,
                  std::string_view message);

/// A world's content for SaveSnapshot / RestoreSnapshot: engineState (exact; what physd
/// writes), or the portable description in the other fields (physics.fbs, Snapshot).
struct SnapshotData {
  std::string name;
  phys::Vec3 gravity{0, 0, -9.81f};
  float timeStep = 1.0f / 60;
  phys::SolverSettings solver;
  uint64_t tick = 0;
  double time = 0;
  std::vector<BodyEntry> bodies;
  std::vector<JointEntry> joints;
  std::vector<uint8_t> engineState;  ///< phys::World::saveSnapshot bytes; then no bodies/joints
  /// The world's other settings (sleeping, clamps, margins, guard; gravity and time step are
  /// the fields above): empty in snapshots written without them.
  WorldOverrides settings;
};
Bytes encodeSnapshot(const SnapshotData& snapshot);

// ---------------------------------------------------------------------------------------------
// World settings and definitions (GetWorld, GetBodies, GetJoints)

/// A body as its world simulates it (BodiesResult): its definition (phys::World::getBodyDef)
/// and the mass properties the world derived.
struct BodyInfo {
  uint64_t id = 0;
  phys::BodyDef def;
  phys::BodyMass mass;
};
/// The world's settings: every WorldSettings field from def, its solver settings, and the
/// preset's name.
Bytes encodeWorldSettingsReply(const ReplyHeader& header, const phys::WorldDef& def,
                               std::string_view preset);
/// total: what matched the request before paging.
Bytes encodeBodiesReply(const ReplyHeader& header, uint32_t total, std::span<const BodyInfo> bodies);
Bytes encodeJointsReply(const ReplyHeader& header, uint32_t total,
                        std::span<const JointEntry> joints);
/// Bytes a body or a joint adds to an encoded reply at most (each shape and hull counted
/// where it is used), so that a server fills a reply without passing max_message_bytes.
size_t encodedBytesBound(const BodyInfo& body);
size_t encodedBytesBound(const JointEntry& joint);
/// Bytes a reply takes besides its bodies or joints, at most (the header, an error message).
inline constexpr size_t kReplyOverheadBytes = 4096;

}  // namespace phys::protocol
