// Decoders for untrusted payloads: size check -> FlatBuffers Verifier with tight limits ->
// semantic validation. Nothing here touches DDS or a world.
//
// What the codec checks (docs/PROTOCOL.md has the full table): the payload fits the limits
// and verifies as the expected root type with the expected file identifier; every float is
// finite and within its range; quaternions are within Limits::quatTolerance of unit length;
// masses, densities and sizes are positive and bounded; friction and restitution are in
// range; enum values and union types are known; a CreateWorld backend is "cpu", "gpu" or
// "auto" (or empty); counts and strings are within the limits; ids that must be set are
// non-zero and lists of ids to remove have no repeats; commands that need a world name one;
// a Batch holds only batchable commands.
//
// What it cannot check, left to the server: that world, body and joint ids are live, that a
// preset, scene or snapshot file exists, that hull points span a volume (the world
// that builds the hull reports it), cross-field solver rules that depend on the current settings
// (phys::World::validate), and the protocol version the client speaks.
//
// Quaternions are accepted when | |q| - 1 | < quatTolerance but left as sent (the buffer is
// read in place); convert.h's toPhys() normalizes them.
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include "phys/protocol/limits.h"
#include "phys/protocol/status.h"
#include "phys/protocol/wire.h"

namespace phys::protocol {

/// A client's command. Error codes: ResourceExhausted (too large, counts over a limit),
/// Malformed (not a verifiable Command, no request, a misaligned 8-byte vector), Unsupported
/// (unknown request kind, snapshot format), InvalidArgument (everything else).
Decoded<wire::Command> decodeCommand(std::span<const uint8_t> bytes, const Limits& limits = {});

/// The server's reply: verified, status and result kind known, result present when typed.
Decoded<wire::Reply> decodeReply(std::span<const uint8_t> bytes, const Limits& limits = {});

/// A state chunk: verified, chunk_index < chunk_count, bodies within maxBodiesPerFrame and
/// total_bodies. Body values are not checked (a NaN from a diverging world is data).
Decoded<wire::StateFrame> decodeStateFrame(std::span<const uint8_t> bytes,
                                           const Limits& limits = {});

/// World description: verified, chunk fields consistent, every body and joint definition
/// validated as in SpawnBodies / AddJoints, ids non-zero.
Decoded<wire::WorldInfo> decodeWorldInfo(std::span<const uint8_t> bytes, const Limits& limits = {});

Decoded<wire::ServerStatus> decodeServerStatus(std::span<const uint8_t> bytes,
                                               const Limits& limits = {});

Decoded<wire::Event> decodeEvent(std::span<const uint8_t> bytes, const Limits& limits = {});
/// A handoff between daemons (phys/peer).
Decoded<wire::Handoff> decodeHandoff(std::span<const uint8_t> bytes, const Limits& limits = {});

/// A snapshot (RestoreSnapshot.snapshot, SnapshotResult.snapshot): verified and fully
/// validated (format version, settings, bodies, joints, unique ids, joints refer to bodies
/// of the snapshot). decodeCommand already runs this on RestoreSnapshot.snapshot.
Decoded<wire::Snapshot> decodeSnapshot(std::span<const uint8_t> bytes, const Limits& limits = {});

/// The same decoders taking ownership of the bytes (the result keeps them alive), so that
/// `decodeReply(receiveBytes())` is safe. The span versions above never copy unless the bytes
/// are misaligned, and the caller keeps the bytes alive.
Decoded<wire::Command> decodeCommand(std::vector<uint8_t>&& bytes, const Limits& limits = {});
Decoded<wire::Reply> decodeReply(std::vector<uint8_t>&& bytes, const Limits& limits = {});
Decoded<wire::StateFrame> decodeStateFrame(std::vector<uint8_t>&& bytes, const Limits& limits = {});
Decoded<wire::WorldInfo> decodeWorldInfo(std::vector<uint8_t>&& bytes, const Limits& limits = {});
Decoded<wire::ServerStatus> decodeServerStatus(std::vector<uint8_t>&& bytes,
                                               const Limits& limits = {});
Decoded<wire::Event> decodeEvent(std::vector<uint8_t>&& bytes, const Limits& limits = {});
Decoded<wire::Handoff> decodeHandoff(std::vector<uint8_t>&& bytes, const Limits& limits = {});
Decoded<wire::Snapshot> decodeSnapshot(std::vector<uint8_t>&& bytes, const Limits& limits = {});

/// snake_case name of a request kind as used in messages ("spawn_bodies"); "unknown" if none.
const char* requestName(wire::Request r);
/// Whether the request needs Command.world (all but Hello, CreateWorld, ListWorlds).
bool needsWorld(wire::Request r);
/// Whether the request may appear in a Batch: the world edits SpawnBodies, RemoveBodies,
/// AddJoints, RemoveJoints, SetBodyPose, SetBodyVelocity, ApplyForce, ApplyImpulse,
/// ApplyTorque, SetMaterial, SetSolver and SetWorld.
bool isBatchable(wire::Request r);

}  // namespace phys::protocol
