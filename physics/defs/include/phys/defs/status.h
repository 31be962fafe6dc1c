// Status: what every call that can fail returns (codes shared with the network protocol).
#pragma once

#include <cstdint>
#include <string>
#include <utility>

namespace phys {

/// Result codes shared with the network protocol.
enum class StatusCode : uint8_t {
  Ok = 0,
  InvalidArgument,    ///< a number out of range, a NaN, a malformed definition
  NotFound,           ///< unknown or stale id
  IncorrectState,     ///< valid request, wrong moment (e.g. a plane on a dynamic body)
  ResourceExhausted,  ///< a count limit
};
struct Status {
  StatusCode code = StatusCode::Ok;
  std::string message;
  bool ok() const { return code == StatusCode::Ok; }
  static Status Ok() { return {}; }
  static Status Error(StatusCode c, std::string m) { return {c, std::move(m)}; }
};
inline const char* toString(StatusCode c) {
  switch (c) {
    case StatusCode::Ok:
      return "OK";
    case StatusCode::InvalidArgument:
      return "INVALID_ARGUMENT";
    case StatusCode::NotFound:
      return "NOT_FOUND";
    case StatusCode::IncorrectState:
      return "INCORRECT_STATE";
    case StatusCode::ResourceExhausted:
      return "RESOURCE_EXHAUSTED";
  }
  return "?";
}

}  // namespace phys
