// physd's DDS side: a reader thread that takes phys/cmd envelopes, checks and decodes them
// and queues them to the core (ServerCore::submit), and a publisher thread that drains the
// core's PublishQueue onto phys/reply, phys/state/<world>, phys/world_info and phys/status.
// The tick thread (TickThread) never calls DDS.
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <map>
#include <memory>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "phys/server/client_keys.h"
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
  /// How often the reader thread looks for participants that left (their client ids and
  /// interests are freed); sooner, down to a tenth of it, when the id table is full.
  std::chrono::milliseconds sweepPeriod{1000};
  /// The lease of phys/status's liveliness (DaemonConfig::livelinessS); 0: none. The reader
  /// thread asserts it four times a lease, so clients see a killed or frozen daemon go within
  /// one lease, and a busy tick thread does not make it look gone.
  std::chrono::milliseconds liveliness{1000};
};

struct EndpointCounters {
  std::atomic<uint64_t> commandsTaken{0};
  /// Commands for another daemon of the domain (ServerCore::takes): dropped unanswered, before
  /// any budget counts them.
  std::atomic<uint64_t> forOthers{0};
  /// Handoffs (phys/peer) taken for this daemon, and those dropped (undecodable, past the
  /// bounds on what a move may hold).
  std::atomic<uint64_t> handoffsTaken{0};
  std::atomic<uint64_t> handoffsDropped{0};
  std::atomic<uint64_t> undecodable{0};  ///< envelopes or payloads that failed the codec
  std::atomic<uint64_t> repliesWritten{0};
  std::atomic<uint64_t> framesWritten{0};  ///< state chunks
  /// State frames not written because this daemon's hold had lapsed when their turn came.
  std::atomic<uint64_t> framesFenced{0};
  std::atomic<uint64_t> writeErrors{0};
  /// Commands dropped unanswered because their envelope key belongs to another participant
  /// (a client's key is bound to the participant that first used it, while it is there).
  std::atomic<uint64_t> spoofed{0};
  /// Commands dropped because their participant holds max_keys_per_participant other keys
  /// (or the id table is full); one in a while is answered ResourceExhausted.
  std::atomic<uint64_t> pastKeyLimit{0};
  /// Participants found gone by the sweep (their keys and interests freed).
  std::atomic<uint64_t> participantsLeft{0};
  /// Secure daemon: commands refused because their writer is in no identity partition.
  std::atomic<uint64_t> unidentified{0};
  /// Client keys' binding proofs (Hello) checked, and those that did not hold.
  std::atomic<uint64_t> proofsChecked{0};
  std::atomic<uint64_t> proofsFailed{0};
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
  /// Commands DDS filtered out before they reached the reader: their writer had made
  /// 2 x max_keys_per_participant instances (client ids) already, or wrote faster than twice
  /// max_participant_commands_per_s (InstanceGate).
  uint64_t commandsFiltered() const { return gate_.refused(); }

 private:
  void readLoop();
  /// Whether the participant that wrote a command may use its envelope key (keys_: the first
  /// participant to use a key holds it while DDS matches it; each holds at most
  /// max_keys_per_participant; a proven Hello takes its key from anyone): O(1), the writer's
  /// discovery data asked once per writer. proof: the command is a Hello with a binding proof
  /// (null: it is not). Reader thread only.
  ClientKeys::Result vouch(uint64_t key, dds_instance_handle_t writer,
                           ClientKeys::Clock::time_point now, const ClientKeys::Proof* proof);
  /// Payloads up to limits.max_name_bytes plus this are read before the key is claimed, for a
  /// Hello's proof (a Hello with the longest name, a key and a proof fits).
  static constexpr size_t kHelloBytesBesideName = 512;
  /// Forgets the writers DDS no longer matches and the participants gone with them: their
  /// keys are free, and the core frees what they held (ServerCore::clientsLeft).
  void sweep();
  /// A participant's GUID for the log (its number when unknown).
  std::string participantName(uint64_t participant) const;
  ClientKeys keys_;
  /// The command topic's filter (before cmdReader_, which uses it, and gone after it).
  InstanceGate gate_;
  static bool admitSample(const dds_sample_info_t* info, void* gate);
  ClientKeys::Clock::time_point sweptAt_{};
  std::vector<dds_instance_handle_t> live_;  ///< sweep's scratch
  /// phys/peer (a daemon of a cluster): Handoffs for this daemon, a Chunk's pieces put
  /// together before the core sees them. Reader thread only.
  void takeHandoffs();
  /// Other daemons' status samples: ServerCore::notePeerStatus.
  void takePeerStatuses();
  struct Assembly {
    ServerCore::HandoffIn head;
    std::vector<std::vector<uint8_t>> parts;
    uint32_t got = 0;
    std::chrono::steady_clock::time_point started;
  };
  std::map<std::pair<uint64_t, uint64_t>, Assembly> assemblies_;  ///< by (from, move)
  /// Moves put together at once; the oldest beyond are dropped (their source times out).
  static constexpr size_t kMaxAssemblies = 4;
  void publishLoop();
  void publish(ReliableMessage& m);
  void publish(StateFrameSet& f);

  ServerCore* core_;
  EndpointConfig config_;
  dds::Participant participant_;
  dds::Topic cmdTopic_, replyTopic_, infoTopic_, statusTopic_, eventsTopic_, peerTopic_;
  dds::Reader cmdReader_, peerReader_;
  /// In a cluster: the other daemons' phys/status, so this daemon's status names its peers.
  dds::Reader statusReader_;
  dds::Writer replyWriter_, infoWriter_, statusWriter_, eventsWriter_, peerWriter_;
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
  /// Until then a world moved here waits for its subscribers (publisher thread).
  std::chrono::steady_clock::time_point movedInUntil_{};
  std::atomic<bool> stop_{false};
  std::thread reader_, publisher_;
  EndpointCounters counters_;
};

}  // namespace phys::server
