// A domain of daemons (docs/SERVER.md "Several daemons"): how world ids name the daemon that
// made them, and how a daemon reads a command's address before it spends anything on it.
#pragma once

#include <cstdint>
#include <optional>
#include <span>

namespace phys::protocol {

/// In a cluster a world id is (daemon << kWorldIdDaemonShift) | n: unique across the domain
/// without a coordinator, and the daemon that made a world answers "no such world" for the ids
/// of its range that it does not hold. 12 bits of daemon, 20 of worlds.
inline constexpr int kWorldIdDaemonShift = 20;
inline constexpr uint64_t kMaxClusterDaemonId = (uint64_t(1) << (32 - kWorldIdDaemonShift)) - 1;
inline constexpr uint64_t daemonOfWorld(uint32_t world) { return world >> kWorldIdDaemonShift; }
/// The first and one past the last world id of a cluster daemon's range.
inline constexpr uint32_t firstWorldIdOf(uint64_t daemon) {
  return uint32_t(daemon << kWorldIdDaemonShift) | 1u;
}
inline constexpr uint64_t worldIdsEndOf(uint64_t daemon) {
  return (daemon + 1) << kWorldIdDaemonShift;
}

/// What a daemon needs of a command to decide whether it is the one to take it.
struct CommandAddress {
  uint32_t world = 0;
  uint64_t daemon = 0;  ///< Command.daemon
  bool hello = false;   ///< the request is a Hello
};

/// Command.world, .daemon and whether it is a Hello, read from a command's FlatBuffer after
/// verifying only the root table and those fields: O(1) whatever the payload's size (the full
/// verification comes after the daemon's budgets). nullopt when even that does not verify.
std::optional<CommandAddress> peekAddress(std::span<const uint8_t> bytes);

/// Sets Command.daemon in a command's bytes (a CommandBuilder's, which always writes the
/// field); false when the field is not in the buffer or the buffer does not verify as
/// peekAddress reads it.
bool setCommandDaemon(std::span<uint8_t> bytes, uint64_t daemon);

}  // namespace phys::protocol
