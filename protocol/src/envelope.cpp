// Envelope helpers (dds_envelope.h). No DDS calls: only the idlc-generated struct.
#include <string>

#include "phys/protocol/dds_envelope.h"

namespace phys::protocol {

void wrapEnvelope(phys_wire_Envelope* env, uint64_t key, uint64_t seq, PayloadKind kind,
                  std::span<const uint8_t> bytes) {
  env->key = key;
  env->seq = seq;
  env->kind = static_cast<uint16_t>(kind);
  env->schema_version = kProtocolVersion;
  // dds_write only reads the sample; _release = false tells Cyclone it does not own the buffer.
  env->bytes._buffer = const_cast<uint8_t*>(bytes.data());
  env->bytes._length = static_cast<uint32_t>(bytes.size());
  env->bytes._maximum = static_cast<uint32_t>(bytes.size());
  env->bytes._release = false;
}

Status checkEnvelope(const phys_wire_Envelope& env, PayloadKind expected, const Limits& limits) {
  if (env.kind != static_cast<uint16_t>(expected))
    return Status::Error(Code::Malformed, "envelope.kind is " + std::to_string(env.kind) +
                                              ", expected " +
                                              std::to_string(static_cast<int>(expected)) + " (" +
                                              toString(expected) + ")");
  if (env.schema_version != kProtocolVersion)
    return Status::Error(Code::Unsupported,
                         "envelope.schema_version is " + std::to_string(env.schema_version) +
                             "; this side speaks " + std::to_string(kProtocolVersion));
  if (env.bytes._length > limits.maxMessageBytes)
    return Status::Error(Code::ResourceExhausted,
                         "envelope.bytes is " + std::to_string(env.bytes._length) +
                             " bytes, the limit is " + std::to_string(limits.maxMessageBytes) +
                             " (max_message_bytes)");
  if (env.bytes._length > 0 && !env.bytes._buffer)
    return Status::Error(Code::Malformed, "envelope.bytes has a length but no buffer");
  return Status::Ok();
}

}  // namespace phys::protocol
