// physd's DDS side: a reader thread that takes phys/cmd envelopes, checks and decodes them
// and queues them to the core (ServerCore::submit), and a publisher thread that drains the
// core's PublishQueue onto phys/reply, phys/state/<world>, phys/world_info and phys/status.
// The tick thread (TickThread) never calls DDS.
#pragma once

#include <atomic>
#include <cstdint>
#include <map>
#include <memory>
#include <set>
#include <string>
#include <thread>

#include <array>
#include <unordered_map>

#include "phys/server/core.h"
#include "phys/server/dds.h"

namespace phys::server {

struct EndpointConfig {
  uint32_t domain = 0;
  std::string cycloneXml;  ///< Cyclone XML for the domain; empty: CYCLONEDDS_URI / defaults
  /// The domain runs DDS Security (cycloneXml has a <Security> element): every command is
  /// attributed to the identity whose partition it was written in (Incoming::principal,
  /// protocol/security.h), and one written outside an identity partition is refused.
  bool identities = false;
};

struct EndpointCounters {
  std::atomic<uint64_t> commandsTaken{0};
  std::atomic<uint64_t> undecodable{0};  ///< envelopes or payloads that failed the codec
  std::atomic<uint64_t> repliesWritten{0};
  std::atomic<uint64_t> framesWritten{0};  ///< state chunks
  std::atomic<uint64_t> writeErrors{0};
  /// Commands dropped unanswered because their envelope key belongs to another participant
  /// (a client's key is bound to the participant that first used it, while it is there).
  std::atomic<uint64_t> spoofed{0};
  /// Secure daemon: commands refused because their writer is in no identity partition.
  std::atomic<uint64_t> unidentified{0};
};

class DdsEndpoint {
 public:
  DdsEndpoint(ServerCore* core, EndpointConfig config);
  ~DdsEndpoint();  ///< stops
  /// Creates the participant, topics, reader and writers and starts both threads.
  Status start();
  /// Stops both threads (the publisher first drains what is queued, briefly).
  void stop();
  const EndpointCounters& counters() const { return counters_; }

 private:
  void readLoop();
  /// Whether the participant that wrote a command may use its envelope key: the first
  /// participant to use a key holds it until DDS no longer matches its writer (it left, or
  /// its lease expired). *principal: the writer's identity key (0: it has no identity
  /// partition). Reader thread only.
  bool vouch(uint64_t key, dds_instance_handle_t writer, uint64_t* principal);
  using Guid = std::array<uint8_t, 16>;
  struct Owner {
    Guid participant{};
    dds_instance_handle_t writer = 0;
  };
  /// What discovery said of a command writer: its participant and its identity's key.
  struct WriterInfo {
    Guid participant{};
    uint64_t principal = 0;
  };
  std::unordered_map<uint64_t, Owner> owners_;                     ///< by client key
  std::unordered_map<dds_instance_handle_t, WriterInfo> writers_;  ///< by writer
  static constexpr size_t kMaxOwners = 1 << 16;
  void publishLoop();
  void publish(ReliableMessage& m);
  void publish(StateFrameSet& f);

  ServerCore* core_;
  EndpointConfig config_;
  dds::Participant participant_;
  dds::Topic cmdTopic_, replyTopic_, infoTopic_, statusTopic_, eventsTopic_;
  dds::Reader cmdReader_;
  dds::Writer replyWriter_, infoWriter_, statusWriter_, eventsWriter_;
  dds::WaitSet waitset_;
  struct StateTopic {
    dds::Topic topic;
    dds::Writer writer;
  };
  /// By streamKey(world, interest) (interest 0: the world's own stream); publisher thread only.
  std::map<uint64_t, std::unique_ptr<StateTopic>> state_;
  /// Made on first use; null for a removed world.
  StateTopic* stateTopic(uint32_t world, uint32_t interest = 0);
  std::map<uint32_t, uint32_t> infoChunks_;                ///< world -> chunks last written
  std::set<uint32_t> removed_;  ///< destroyed worlds (ids are never reused): late frames dropped
  std::atomic<bool> stop_{false};
  std::thread reader_, publisher_;
  EndpointCounters counters_;
};

}  // namespace phys::server
