#include "phys/protocol/cluster.h"

#include "phys/protocol/wire.h"

namespace phys::protocol {

std::optional<CommandAddress> peekAddress(std::span<const uint8_t> bytes) {
  if (bytes.size() < 8) return std::nullopt;
  // Only the root offset, the root table and the three scalars: not the request itself.
  flatbuffers::Verifier v(bytes.data(), bytes.size());
  if (!v.VerifyOffset(0)) return std::nullopt;
  const auto* c = flatbuffers::GetRoot<wire::Command>(bytes.data());
  const auto* t = reinterpret_cast<const flatbuffers::Table*>(c);
  if (!v.VerifyTableStart(reinterpret_cast<const uint8_t*>(c)) ||
      !t->VerifyField<uint32_t>(v, wire::Command::VT_WORLD, 4) ||
      !t->VerifyField<uint64_t>(v, wire::Command::VT_DAEMON, 8) ||
      !t->VerifyField<uint8_t>(v, wire::Command::VT_REQUEST_TYPE, 1))
    return std::nullopt;
  return CommandAddress{c->world(), c->daemon(), c->request_type() == wire::Request::Hello};
}

bool setCommandDaemon(std::span<uint8_t> bytes, uint64_t daemon) {
  if (!peekAddress(bytes)) return false;
  auto* t = reinterpret_cast<flatbuffers::Table*>(flatbuffers::GetMutableRoot<wire::Command>(bytes.data()));
  return t->SetField<uint64_t>(wire::Command::VT_DAEMON, daemon, 0);
}

}  // namespace phys::protocol
