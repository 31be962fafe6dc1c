// The generated FlatBuffers types of protocol/physics.fbs (namespace phys::wire), plus the
// file identifiers of the root types. Include this instead of the generated header.
#pragma once

#include "phys/protocol/physics_generated.h"

namespace phys::wire {

/// File identifiers: every payload is finished with its root type's identifier, and the
/// decoders reject a buffer carrying another (a Reply sent on phys/cmd, say).
inline constexpr const char* kCommandId = "PHCM";
inline constexpr const char* kReplyId = "PHRP";
inline constexpr const char* kStateFrameId = "PHSF";
inline constexpr const char* kWorldInfoId = "PHWI";
inline constexpr const char* kServerStatusId = "PHST";
inline constexpr const char* kEventId = "PHEV";
inline constexpr const char* kSnapshotId = "PHSN";
inline constexpr const char* kHandoffId = "PHHO";

static_assert(sizeof(BodyState) == 64, "BodyState is 64 bytes on the wire");
static_assert(sizeof(Pose) == 28 && sizeof(BodyPose) == 40 && sizeof(BodyForce) == 32);

}  // namespace phys::wire
