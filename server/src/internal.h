// What the server's source files share beyond core.h.
#pragma once

#include "phys/server/core.h"

namespace phys::server {

/// A live body's definition as its world holds it (phys::World::getBodyDef: pose and
/// velocities now), the one source of what physd says of a body (world info, GetBodies, the
/// checks of a restored world); a default definition for a stale id.
phys::BodyDef bodyDefOf(const phys::World& w, phys::BodyId id);

}  // namespace phys::server
