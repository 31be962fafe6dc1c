// Conversions between wire tables and phys types. The *to phys* direction expects input that
// passed the decoders (decoder.h); it normalizes quaternions and plane normals. Convex hulls
// travel as their points and stay points here (phys/defs/shape_def.h's ConvexHull): the
// world that receives a body builds its hulls (World::createBody), the one check the decoders
// leave to the engine.
#pragma once

#include <memory>
#include <unordered_map>

#include "phys/defs/body_def.h"
#include "phys/defs/joint_def.h"
#include "phys/defs/math.h"
#include "phys/defs/world_def.h"
#include "phys/protocol/builder.h"
#include "phys/protocol/status.h"
#include "phys/protocol/wire.h"

namespace phys::protocol {

inline wire::Vec3 toWire(phys::Vec3 v) {
  return {v.x, v.y, v.z};
}
inline wire::Quat toWire(phys::Quat q) {
  return {q.x, q.y, q.z, q.w};
}
inline wire::Pose toWire(const phys::Transform& t) {
  return {toWire(t.p), toWire(t.q)};
}
inline wire::Material toWire(const phys::Material& m) {
  return {m.friction, m.restitution, m.density};
}
inline phys::Vec3 toPhys(const wire::Vec3& v) {
  return {v.x(), v.y(), v.z()};
}
/// Normalized (the wire accepts up to Limits::quatTolerance off unit length).
inline phys::Quat toPhys(const wire::Quat& q) {
  return phys::normalize(phys::Quat{q.x(), q.y(), q.z(), q.w()});
}
inline phys::Transform toPhys(const wire::Pose& p) {
  return {toPhys(p.position()), toPhys(p.rotation())};
}
inline phys::Material toPhys(const wire::Material& m) {
  return {m.friction(), m.restitution(), m.density()};
}

/// A published state record of a body.
wire::BodyState toWire(const phys::BodyState& s);

/// Hulls read from wire tables (points only), by table address: the shapes of a message that
/// share one hull table (FlatBuffers allows it) share one hull, which their world then builds
/// once (the server's spawn and restore). Valid for one message's buffer.
using HullCache = std::unordered_map<const void*, std::shared_ptr<const phys::ConvexHull>>;

/// A body definition for World::createBody, its hulls as points (unbuilt). Fails
/// (InvalidArgument, message prefixed with `path`) only for a shape of no known kind. With a
/// cache, shapes of one hull table share one hull.
Status toBodyDef(const wire::BodyDef& in, phys::BodyDef* out, std::string_view path = "body",
                 HullCache* cache = nullptr);
/// A joint definition for World::createJoint (ids unpacked; absent axes are (0, 0, 1)).
phys::JointDef toJointDef(const wire::JointDef& in);
/// Overwrites the fields present in `in`.
void applySolverSettings(const wire::SolverSettings& in, phys::SolverSettings* out);
SolverOverrides toOverrides(const wire::SolverSettings& in);
/// Applies the overrides that are set.
void applyOverrides(const SolverOverrides& in, phys::SolverSettings* out);

/// World settings (SetWorld, WorldSettingsResult, Snapshot): the fields present.
WorldOverrides toOverrides(const wire::WorldSettings& in);
/// Applies the world settings that are set (gravity, time step, sleeping, clamps, margins,
/// guard).
void applyOverrides(const WorldOverrides& in, phys::WorldDef* out);
/// A body of a BodiesResult as plain data (hulls as points; fails like toBodyDef).
Status toBodyInfo(const wire::BodyInfo& in, BodyInfo* out, std::string_view path = "body",
                  HullCache* cache = nullptr);

/// A world's summary (WorldList, ServerStatus) as plain data; absent strings are empty.
WorldSummary toWorldSummary(const wire::WorldSummary& in);

/// A decoded snapshot as plain data (hulls as points; fails like toBodyDef).
Status toSnapshotData(const wire::Snapshot& in, SnapshotData* out);

}  // namespace phys::protocol
