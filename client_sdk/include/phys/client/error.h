// Typed errors of the client SDK: the server's status code and message, or a client-side
// failure (timeout, disconnect, transport).
#pragma once

#include <cstdint>
#include <stdexcept>
#include <string>

namespace phys::client {

/// 0..9 are the server's wire codes (docs/PROTOCOL.md, Status codes); >= 100 are the SDK's.
enum class ErrorCode : uint8_t {
  Ok = 0,
  Malformed = 1,
  InvalidArgument = 2,
  NotFound = 3,
  IncorrectState = 4,
  Unsupported = 5,
  ResourceExhausted = 6,
  Internal = 7,
  PermissionDenied = 8,  ///< this client may not change that world (docs/SERVER.md "Access")
  /// The world moved to another daemon: the SDK sends the command there itself; this comes
  /// back only when the new owner cannot be reached either.
  Moved = 9,
  Timeout = 100,       ///< no reply before the request's deadline
  Disconnected = 101,  ///< the server went away (or restarted) with the request pending
  Transport = 102,     ///< a DDS call failed
  BadReply = 103,      ///< the reply could not be decoded or had the wrong result
};

/// "NotFound", "Timeout", ...
const char* toString(ErrorCode c);

/// What a failed request's future throws.
class Error : public std::runtime_error {
 public:
  Error(ErrorCode code, std::string message, uint32_t retryAfterMs = 0)
      : std::runtime_error(std::string(toString(code)) + ": " + message),
        code_(code),
        message_(std::move(message)),
        retryAfterMs_(retryAfterMs) {}
  ErrorCode code() const { return code_; }
  /// A refusal of the daemon's rate or queue budgets (ResourceExhausted, nothing done): the
  /// same request may be sent again after this many ms (ClientOptions::retryBusy does). 0:
  /// any other error.
  uint32_t retryAfterMs() const { return retryAfterMs_; }
  /// The server's message (or the SDK's), without the code.
  const std::string& message() const { return message_; }
  /// Whether the server answered with this code (else the SDK gave up on the request).
  bool fromServer() const { return uint8_t(code_) < 100; }

 private:
  ErrorCode code_;
  std::string message_;
  uint32_t retryAfterMs_ = 0;
};

}  // namespace phys::client
