// The codec's rules for definitions that did not arrive as protocol tables: bodies and joints
// of scene files, of an engine snapshot's state, of start-up worlds. physd runs every body and
// joint it creates through these (SpawnBodies and AddJoints included), so it never holds a
// world that its own protocol could not describe to a client: every value here is one that
// decodeWorldInfo accepts.
//
// The rules are decoder.h's own checks of BodyDef, ShapeDef, Material and JointDef: a
// definition is written as the table it would arrive as and checked by the same code
// (decoder.cpp), alone (no per-message budgets), so there is one set of rules, not two.
#pragma once

#include <string>
#include <string_view>

#include "phys/protocol/limits.h"
#include "phys/protocol/status.h"
#include "phys/defs/body_def.h"
#include "phys/defs/joint_def.h"
#include "phys/defs/world_def.h"

namespace phys::protocol {

/// Whether s is well-formed UTF-8 (no overlongs, no surrogates, <= U+10FFFF).
bool validUtf8(std::string_view s);

/// A name: at most maxBytes bytes of UTF-8 without control characters. InvalidArgument (or
/// ResourceExhausted when too long), the message starting with `path`.
Status checkName(std::string_view name, uint32_t maxBytes, std::string_view path);

/// Every field of a body definition against the limits (positions, speeds, masses, inertia,
/// damping, shapes and their sizes, hull vertices, materials, the name).
Status checkBodyDef(const phys::BodyDef& def, const Limits& limits, std::string_view path);

/// Every field of a joint definition but its body ids (which only the world can check).
Status checkJointDef(const phys::JointDef& def, const Limits& limits, std::string_view path);

/// A world's gravity and time step.
Status checkWorldParams(phys::Vec3 gravity, float timeStep, const Limits& limits,
                        std::string_view path);

/// Every setting of a world that WorldSettings carries (gravity, time step, sleeping, speed
/// clamps, margins, guard), by its wire name: what SetWorld may set and what physd lets a
/// world hold (scenes, snapshots), so that GetWorld can always describe it.
Status checkWorldSettings(const phys::WorldDef& def, const Limits& limits, std::string_view path);

/// At most `maxBytes` of `text` for an error message (longer text is cut, with its length).
std::string shortQuote(std::string_view text, size_t maxBytes = 64);

}  // namespace phys::protocol
