// physd's DDS wrappers are the protocol library's (shared with the client SDK).
#pragma once

#include "phys/protocol/dds.h"

namespace phys::server {
namespace dds = protocol::dds;
}  // namespace phys::server
