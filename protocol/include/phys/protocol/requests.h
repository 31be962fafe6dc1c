// The requests' properties: one row per wire::Request, in the union's order. The codec, the
// server and the tools read a request's name and rules here instead of each keeping its own
// list; docs/ARCHITECTURE.md "Adding a request" says what else a new request needs.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>

#include "phys/protocol/wire.h"

namespace phys::protocol {

/// What a participant must be to apply a request to a world with an owner (docs/SERVER.md
/// "Access"). Two exceptions are the server's: SaveSnapshot with a file needs Edit, and
/// Unsubscribe of another client's interest needs Edit.
enum class Access : uint8_t {
  Read,  ///< anyone
  Edit,  ///< the owner, an editor, or anyone when the world is shared
  Own,   ///< the owner only
};

/// Properties of a request (RequestInfo::flags).
enum RequestFlag : uint16_t {
  kNeedsWorld = 1u << 0,  ///< Command.world names its target
  kBatchable = 1u << 1,   ///< a world edit: may appear in a Batch, applied all-or-nothing
  kJournaled = 1u << 2,   ///< a durable server's journal keeps its effect
  kStored = 1u << 3,      ///< changes a kept world: refused while the server is read-only
  kStartsJob = 1u << 4,   ///< becomes a job of its world when applied from the queue
  kEndsJob = 1u << 5,     ///< ends its world's running job instead of waiting for it
  kIdsReply = 1u << 6,    ///< answered with the ids it created (an IdsResult), even none
};

struct RequestInfo {
  wire::Request type;
  const char* name;  ///< snake_case, as in messages ("spawn_bodies")
  Access access;
  uint16_t flags;

  constexpr bool has(RequestFlag f) const { return (flags & f) != 0; }
};

// The table: a new request of physics.fbs gets its row here, at the union's position; the
// static_assert refuses a table out of step with the union.

namespace detail {

using R = wire::Request;

// Short names for the rows.
inline constexpr uint16_t W = kNeedsWorld;
inline constexpr uint16_t kEdit = kNeedsWorld | kBatchable | kJournaled | kStored;

// Requests without a world (Hello, CreateWorld, ListWorlds) have no access check; CreateWorld
// is stored unless ephemeral, which the server decides (ServerCore::checkWritable).
inline constexpr std::array<RequestInfo, size_t(R::MAX) + 1> kRequests = {{
    {R::NONE, "unknown", Access::Edit, 0},
    {R::Hello, "hello", Access::Read, 0},
    {R::CreateWorld, "create_world", Access::Edit, 0},
    {R::DestroyWorld, "destroy_world", Access::Own, W | kEndsJob},
    {R::ResetWorld, "reset_world", Access::Edit, W | kStored | kEndsJob},
    {R::ListWorlds, "list_worlds", Access::Read, 0},
    {R::LoadScene, "load_scene", Access::Edit, W | kStored | kStartsJob | kIdsReply},
    {R::SpawnBodies, "spawn_bodies", Access::Edit, kEdit | kIdsReply},
    {R::RemoveBodies, "remove_bodies", Access::Edit, kEdit},
    {R::AddJoints, "add_joints", Access::Edit, kEdit | kIdsReply},
    {R::RemoveJoints, "remove_joints", Access::Edit, kEdit},
    {R::SetBodyPose, "set_body_pose", Access::Edit, kEdit},
    {R::SetBodyVelocity, "set_body_velocity", Access::Edit, kEdit},
    {R::ApplyForce, "apply_force", Access::Edit, kEdit},
    {R::ApplyImpulse, "apply_impulse", Access::Edit, kEdit},
    {R::ApplyTorque, "apply_torque", Access::Edit, kEdit},
    {R::SetMaterial, "set_material", Access::Edit, kEdit},
    {R::SetSolver, "set_solver", Access::Edit, kEdit},
    {R::Step, "step", Access::Edit, W | kStored | kStartsJob},
    {R::Run, "run", Access::Edit, W | kJournaled | kStored},
    {R::Pause, "pause", Access::Edit, W | kJournaled | kStored | kEndsJob},
    {R::QueryState, "query_state", Access::Read, W},
    // Bytes are a read; a file on the server is not (Edit: the server's exception).
    {R::SaveSnapshot, "save_snapshot", Access::Read, W},
    // Its reply lists ids only for the portable form (the server's handler says).
    {R::RestoreSnapshot, "restore_snapshot", Access::Edit, W | kStored},
    {R::Batch, "batch", Access::Edit, W | kJournaled | kStored | kIdsReply},
    {R::Subscribe, "subscribe", Access::Read, W},
    // Its own interest; another client's needs Edit (the server's exception).
    {R::Unsubscribe, "unsubscribe", Access::Read, W},
    {R::SetAccess, "set_access", Access::Own, W | kJournaled | kStored},
    {R::SetWorld, "set_world", Access::Edit, kEdit},
    {R::GetWorld, "get_world", Access::Read, W},
    {R::GetBodies, "get_bodies", Access::Read, W},
    {R::GetJoints, "get_joints", Access::Read, W},
    // Not journaled: the world leaves; the target keeps it (and its checkpoint) from then on.
    {R::MoveWorld, "move_world", Access::Own, W | kStored},
}};

inline constexpr RequestInfo kUnknown = {R::NONE, "unknown", Access::Edit, W};

constexpr bool wellFormed() {
  for (size_t i = 0; i < kRequests.size(); ++i) {
    const RequestInfo& r = kRequests[i];
    if (size_t(r.type) != i || !r.name) return false;
    // A world edit is stored, journaled and has a world, as editAll and the journal assume.
    if (r.has(kBatchable) && !(r.has(kNeedsWorld) && r.has(kJournaled) && r.has(kStored)))
      return false;
  }
  return true;
}

}  // namespace detail

static_assert(detail::wellFormed(), "one row per wire::Request, in the union's order");

/// The row of a request kind. NONE and kinds past wire::Request::MAX get rows named
/// "unknown": NONE's needs no world, an unknown kind's needs one (its world is looked up
/// before it is refused).
constexpr const RequestInfo& requestInfo(wire::Request r) {
  return size_t(r) < detail::kRequests.size() ? detail::kRequests[size_t(r)] : detail::kUnknown;
}

}  // namespace phys::protocol
