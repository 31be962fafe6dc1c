// The SDK's DDS wrappers are the protocol library's (shared with physd).
#pragma once

#include "phys/protocol/dds.h"

namespace phys::client {
namespace dds = protocol::dds;
}  // namespace phys::client
