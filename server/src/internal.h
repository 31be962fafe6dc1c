// What the server's source files share beyond core.h.
#pragma once

#include "phys/server/core.h"

namespace phys::server {

/// A world's body and joint definitions rebuilt from its engine (after an engine snapshot
/// restore, which carries none): type, pose, velocities, shapes and joints; damping, gravity
/// scale, explicit masses and names take their defaults.
void rebuildDefs(ServerWorld& w);

}  // namespace phys::server
