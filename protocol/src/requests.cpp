// Three of the request table's columns under decoder.h's names.
#include "phys/protocol/requests.h"

#include "phys/protocol/decoder.h"

namespace phys::protocol {

const char* requestName(wire::Request r) {
  return requestInfo(r).name;
}

bool needsWorld(wire::Request r) {
  return requestInfo(r).has(kNeedsWorld);
}

bool isBatchable(wire::Request r) {
  return requestInfo(r).has(kBatchable);
}

}  // namespace phys::protocol
