// Private: writers of the wire tables shared by the builders.
#pragma once

#include <string_view>

#include "flatbuffers/flatbuffers.h"
#include "phys/protocol/builder.h"
#include "phys/protocol/wire.h"

namespace phys::protocol::detail {

using Fbb = flatbuffers::FlatBufferBuilder;

/// 0 (field absent) for an empty string.
inline flatbuffers::Offset<flatbuffers::String> optString(Fbb& fbb, std::string_view s) {
  return s.empty() ? 0 : fbb.CreateString(s.data(), s.size());
}

flatbuffers::Offset<wire::BodyDef> writeBodyDef(Fbb& fbb, const phys::BodyDef& def);
flatbuffers::Offset<wire::JointDef> writeJointDef(Fbb& fbb, const phys::JointDef& def);
flatbuffers::Offset<wire::SolverSettings> writeSolver(Fbb& fbb, const SolverOverrides& s);
flatbuffers::Offset<wire::WorldSettings> writeWorldSettings(Fbb& fbb, const WorldOverrides& s);
flatbuffers::Offset<wire::WorldSummary> writeWorldSummary(Fbb& fbb, const WorldSummary& w);
flatbuffers::Offset<wire::LimitsInfo> writeLimits(Fbb& fbb, const Limits& l);

/// The finished buffer as bytes; fbb is cleared.
template <class T>
Bytes finishBytes(Fbb& fbb, flatbuffers::Offset<T> root, const char* identifier) {
  fbb.Finish(root, identifier);
  Bytes out(fbb.GetBufferPointer(), fbb.GetBufferPointer() + fbb.GetSize());
  fbb.Clear();
  return out;
}

/// A byte vector whose data starts 8-byte aligned in the buffer, so that a FlatBuffer held in
/// it (a Snapshot) can be read in place.
inline flatbuffers::Offset<flatbuffers::Vector<uint8_t>> alignedBytes(
    Fbb& fbb, std::span<const uint8_t> bytes) {
  fbb.ForceVectorAlignment(bytes.size(), 1, 8);
  return fbb.CreateVector(bytes.data(), bytes.size());
}

}  // namespace phys::protocol::detail
