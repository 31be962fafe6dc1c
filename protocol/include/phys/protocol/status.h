// Status codes and results of the codec. The codes travel in Reply.status.
#pragma once

#include <cstdint>
#include <memory>
#include <span>
#include <string>

#include "phys/protocol/wire.h"
#include "phys/defs/status.h"

namespace phys::protocol {

using Code = wire::StatusCode;

/// A code and a human message. The message of an error names the offending field by its path
/// in the message, e.g. "spawn_bodies.bodies[3].shapes[0].box.half_extents.y must be > 0, got
/// -1".
struct Status {
  Code code = Code::Ok;
  std::string message;
  bool ok() const { return code == Code::Ok; }
  static Status Ok() { return {}; }
  static Status Error(Code c, std::string m) { return {c, std::move(m)}; }
};

/// "Ok", "Malformed", "InvalidArgument", ... (the schema's names).
const char* toString(Code c);

/// The wire code of an engine status (phys::StatusCode is a subset).
Code toWireCode(phys::StatusCode c);
Status fromPhys(const phys::Status& s);

/// A verified and validated root table of a payload, or the reason it was rejected.
///
/// `root` points into the bytes given to the decoder. A decoder given a span does not own
/// them: the caller keeps them alive as long as the Decoded is used (unless they were not
/// 8-byte aligned: the decoder then copied them into `storage`). A decoder given a
/// std::vector by rvalue keeps it in `storage`. Copies of a Decoded share the storage. `root`
/// is null unless ok().
template <class T>
struct Decoded {
  const T* root = nullptr;
  Status status;
  std::shared_ptr<const void> storage;  ///< the bytes, when the Decoded owns them
  /// The verified buffer `root` lies in (the caller's bytes or `storage`); empty unless ok().
  /// physd journals a command's exact bytes from it.
  std::span<const uint8_t> bytes;

  bool ok() const { return status.ok(); }
  const T* operator->() const { return root; }
  const T& operator*() const { return *root; }
};

}  // namespace phys::protocol
