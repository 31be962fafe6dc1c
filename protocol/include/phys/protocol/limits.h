// Protocol version and the limits the codec enforces on untrusted messages.
#pragma once

#include <cstdint>

namespace phys::protocol {

/// Version of physics.fbs and its semantics. Carried in Envelope.schema_version and in
/// Hello / HelloResult. Bumped only for incompatible changes (appended fields are not).
inline constexpr uint16_t kProtocolVersion = 1;

/// Bound of Envelope.bytes in envelope.idl (4 MiB). A DDS write of a longer payload fails.
inline constexpr uint32_t kMaxEnvelopeBytes = 4u << 20;

/// Default number of bodies per StateFrame chunk (a lost datagram loses little).
inline constexpr uint32_t kDefaultBodiesPerChunk = 1000;
/// Editors a world's owner may name (CreateWorld.editors, SetAccess.editors).
inline constexpr uint32_t kMaxEditors = 256;

/// Every limit the decoders check, with its default. Counts are per message: a Batch's
/// commands share one budget. Exceeding a count or size gives ResourceExhausted; a number out
/// of range gives InvalidArgument. The same numbers are announced to clients in HelloResult.
struct Limits {
  // Structure (checked before and by the FlatBuffers Verifier).
  uint32_t maxMessageBytes = kMaxEnvelopeBytes;  ///< bytes per payload; <= kMaxEnvelopeBytes
  uint32_t maxDepth = 16;         ///< table nesting for the Verifier (a command needs <= 8)
  uint32_t maxTables = 1u << 20;  ///< Verifier table budget; also capped at bytes / 8 + 16

  // Counts.
  uint32_t maxNameBytes = 256;            ///< world, body, joint, client and server names
  uint32_t maxFileNameBytes = 128;        ///< snapshot file and scene names
  uint32_t maxSceneJsonBytes = 2u << 20;  ///< LoadScene.json
  uint32_t maxFeatures = 64;              ///< HelloResult.features
  uint32_t maxBatchCommands = 256;        ///< Batch.commands
  uint32_t maxBodiesPerCommand = 20000;   ///< SpawnBodies (summed over a batch), WorldInfo chunk
  uint32_t maxShapesPerBody = 64;         ///< BodyDef.shapes
  uint32_t maxHullPoints = 256;           ///< ConvexHull.points (at least 4)
  /// Shapes of all bodies of a message, and hull points of all its hull shapes. A table that
  /// several bodies or shapes share (FlatBuffers allows it) counts at every use, so a small
  /// message cannot stand for a huge world.
  uint32_t maxShapesPerCommand = 100000;
  uint32_t maxHullPointsPerCommand = 1u << 20;
  uint32_t maxJointsPerCommand = 10000;   ///< AddJoints (summed over a batch)
  uint32_t maxIdsPerCommand = 100000;     ///< RemoveBodies/Joints, SetMaterial, QueryState ids
  uint32_t maxItemsPerCommand = 100000;   ///< SetBodyPose/Velocity, ApplyForce/Impulse/Torque
  uint32_t maxStepsPerCommand = 100000;   ///< Step.count
  uint32_t maxBodiesPerFrame = 16384;     ///< StateFrame.bodies, StateResult.bodies
  uint32_t maxWorlds = 4096;              ///< WorldList / ServerStatus entries
  uint32_t maxSnapshotBodies = 1000000;   ///< Snapshot.bodies (and joints)
  uint32_t maxSnapshotShapes = 4000000;   ///< shapes of all bodies of a snapshot (each use)
  uint32_t maxSnapshotHullPoints = 16u << 20;  ///< hull points of a snapshot (each use)
  /// Step.count times the world's bodies (at least 1): what one Step may cost. 10^8 body
  /// steps is of the order of a minute of one core.
  uint64_t maxBodyStepsPerCommand = 100000000;

  // Numbers (InvalidArgument when outside; NaN and infinities always are).
  float quatTolerance = 1e-3f;   ///< | |q| - 1 | must be below this; decoders then normalize
  float maxCoordinate = 1e6f;    ///< m, |position component|, anchors, force points
  float minSize = 1e-5f;         ///< m, radii and half extents at least this
  float maxSize = 1e4f;          ///< m, radii, half extents, half heights, hull coordinates
  float maxLinearSpeed = 1e5f;   ///< m/s per component (the world clamps lower)
  float maxAngularSpeed = 1e5f;  ///< rad/s per component
  float maxMass = 1e9f;          ///< kg
  float maxDensity = 1e6f;       ///< kg/m^3
  float maxInertia = 1e12f;      ///< kg m^2 per principal moment
  float maxFriction = 100.0f;    ///< Coulomb coefficient
  float maxDamping = 1e4f;       ///< 1/s
  float maxGravityScale = 100.0f;
  float maxGravity = 1e4f;   ///< m/s^2 per component
  float maxForce = 1e12f;    ///< N, N s, N m per component (forces, impulses, torques)
  float minTimeStep = 1e-6f;  ///< s; a smaller step only produces rounding noise
  float maxTimeStep = 1.0f;   ///< s
  float maxRateHz = 10000;   ///< Run.rate_hz
};

/// Ids one reply can list (bodies and joints together): what fits in max_message_bytes with
/// room for the reply's other fields. A command that would create more is refused before it
/// changes anything.
inline uint32_t maxIdsPerReply(const Limits& l) {
  return l.maxMessageBytes > 4096 ? (l.maxMessageBytes - 4096) / 8 : 0;
}

}  // namespace phys::protocol
