// Topic names, envelope kinds and keys, and QoS presets as plain data: defined here once for
// the daemon, the SDK and the tools. qos.h turns a preset into a Cyclone DDS QoS object.
#pragma once

#include <cstdint>
#include <string>
#include <string_view>

namespace phys::protocol {

inline constexpr std::string_view kCommandTopic = "phys/cmd";           ///< client -> server
inline constexpr std::string_view kReplyTopic = "phys/reply";           ///< server -> client
inline constexpr std::string_view kStateTopicPrefix = "phys/state/";    ///< + world id
inline constexpr std::string_view kWorldInfoTopic = "phys/world_info";  ///< late joiners
inline constexpr std::string_view kStatusTopic = "phys/status";         ///< daemon health
inline constexpr std::string_view kEventsTopic = "phys/events";         ///< optional notices
/// Between the daemons of a domain (Handoff): key = the daemon a message is for.
inline constexpr std::string_view kPeerTopic = "phys/peer";

/// "phys/state/<world>" (decimal world id).
std::string stateTopic(uint32_t world);
/// An interest's state stream (Subscribe): phys/state/<world>/<interest>.
std::string stateTopic(uint32_t world, uint32_t interest);

/// Envelope.kind: what Envelope.bytes holds.
enum class PayloadKind : uint16_t {
  Command = 1,
  Reply = 2,
  StateFrame = 3,
  WorldInfo = 4,
  ServerStatus = 5,
  Event = 6,
  Handoff = 7,  ///< between daemons, on phys/peer
};
const char* toString(PayloadKind k);

/// Envelope.key on phys/world_info: one instance per (world, chunk).
inline constexpr uint64_t worldInfoKey(uint32_t world, uint32_t chunk) {
  return (uint64_t(world) << 32) | chunk;
}

enum class Reliability : uint8_t { BestEffort, Reliable };
enum class Durability : uint8_t { Volatile, TransientLocal };
enum class History : uint8_t { KeepLast, KeepAll };

/// The QoS of one topic, for both its writers and readers. depth is per instance (key).
struct QosPreset {
  Reliability reliability = Reliability::Reliable;
  Durability durability = Durability::Volatile;
  History history = History::KeepLast;
  int32_t depth = 1;            ///< KeepLast depth
  int32_t maxBlockingMs = 100;  ///< reliable writers: how long a full history may block
  /// Writers only: > 0 makes the writer's liveliness MANUAL_BY_TOPIC with this lease (its
  /// writes and Writer::assertLiveliness keep it alive; a reader sees its instances
  /// NOT_ALIVE_NO_WRITERS once a lease passes without either: a killed or frozen process).
  /// Readers never request a lease (Reader::create ignores it), so they match any writer.
  int32_t livelinessLeaseMs = 0;
};

/// Commands: reliable, never dropped while a client keeps <= 256 outstanding; keep-last (not
/// keep-all) so one stalled daemon cannot block a client's writer forever.
inline constexpr QosPreset kCommandQos{Reliability::Reliable, Durability::Volatile,
                                       History::KeepLast, 256, 100};
inline constexpr QosPreset kReplyQos{Reliability::Reliable, Durability::Volatile, History::KeepLast,
                                     256, 100};
/// State chunks: the writer keeps the last 1 per chunk (key = chunk index), so a slow
/// subscriber never stalls the publisher; reliable so a lost fragment is resent while it is
/// still the newest.
inline constexpr QosPreset kStateQos{Reliability::Reliable, Durability::Volatile, History::KeepLast,
                                     1, 0};
/// State readers keep the last 4 per chunk: a subscriber held up for up to 3 ticks (a slow
/// callback, the scheduler) still gets each of them, oldest first; one further behind skips
/// to the newest 4. Reader and writer depths need not match in DDS.
inline constexpr int32_t kStateReaderDepth = 4;
inline constexpr QosPreset kStateReaderQos{Reliability::Reliable, Durability::Volatile,
                                           History::KeepLast, kStateReaderDepth, 0};
/// World descriptions: transient-local, the latest per (world, chunk) kept for late joiners.
inline constexpr QosPreset kWorldInfoQos{Reliability::Reliable, Durability::TransientLocal,
                                         History::KeepLast, 1, 100};
/// Status: the latest sample per server, also for late joiners.
inline constexpr QosPreset kStatusQos{Reliability::Reliable, Durability::TransientLocal,
                                      History::KeepLast, 1, 100};
inline constexpr QosPreset kEventsQos{Reliability::Reliable, Durability::Volatile,
                                      History::KeepLast, 64, 100};
/// Handoffs: every chunk delivered, in order (a move's chunks are one instance's samples).
inline constexpr QosPreset kPeerQos{Reliability::Reliable, Durability::Volatile,
                                    History::KeepAll, 1, 2000};

/// A topic's name (state: the prefix), payload kind and QoS in one record.
struct TopicSpec {
  std::string_view name;
  PayloadKind kind;
  QosPreset qos;
};
inline constexpr TopicSpec kTopics[] = {
    {kCommandTopic, PayloadKind::Command, kCommandQos},
    {kReplyTopic, PayloadKind::Reply, kReplyQos},
    {kStateTopicPrefix, PayloadKind::StateFrame, kStateQos},
    {kWorldInfoTopic, PayloadKind::WorldInfo, kWorldInfoQos},
    {kStatusTopic, PayloadKind::ServerStatus, kStatusQos},
    {kEventsTopic, PayloadKind::Event, kEventsQos},
};

}  // namespace phys::protocol
