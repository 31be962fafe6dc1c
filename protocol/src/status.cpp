// Status codes (status.h) and topic helpers (topics.h).
#include "phys/protocol/status.h"

#include "phys/protocol/topics.h"

namespace phys::protocol {

const char* toString(Code c) {
  const char* name = wire::EnumNameStatusCode(c);
  return name && *name ? name : "Unknown";
}

Code toWireCode(phys::StatusCode c) {
  switch (c) {
    case phys::StatusCode::Ok:
      return Code::Ok;
    case phys::StatusCode::InvalidArgument:
      return Code::InvalidArgument;
    case phys::StatusCode::NotFound:
      return Code::NotFound;
    case phys::StatusCode::IncorrectState:
      return Code::IncorrectState;
    case phys::StatusCode::ResourceExhausted:
      return Code::ResourceExhausted;
  }
  return Code::Internal;
}

Status fromPhys(const phys::Status& s) {
  return {toWireCode(s.code), s.message};
}

std::string stateTopic(uint32_t world) {
  return std::string(kStateTopicPrefix) + std::to_string(world);
}

std::string stateTopic(uint32_t world, uint32_t interest) {
  return interest == 0 ? stateTopic(world) : stateTopic(world) + "/" + std::to_string(interest);
}

const char* toString(PayloadKind k) {
  switch (k) {
    case PayloadKind::Command:
      return "Command";
    case PayloadKind::Reply:
      return "Reply";
    case PayloadKind::StateFrame:
      return "StateFrame";
    case PayloadKind::WorldInfo:
      return "WorldInfo";
    case PayloadKind::ServerStatus:
      return "ServerStatus";
    case PayloadKind::Event:
      return "Event";
    case PayloadKind::Handoff:
      return "Handoff";
  }
  return "Unknown";
}

}  // namespace phys::protocol
