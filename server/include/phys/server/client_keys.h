// Which DDS participant may use which client id (the envelope key of phys/cmd), without DDS:
// the endpoint (endpoint.cpp) tells it what discovery says of each command writer and asks it
// about every command; it answers in O(1) and calls DDS back only through the Alive oracle,
// at most once per `recheck` per held key. Reader thread only (not thread-safe).
//
// The rules (docs/SERVER.md "Commands"):
// - A key belongs to the participant that first wrote a command under it, for as long as that
//   participant is there; another participant's commands under it are refused (HeldByOther,
//   dropped unanswered by the endpoint: a reply would reach the holder as its own).
// - A participant holds at most `keysPerParticipant` keys; its commands under further keys are
//   refused (TooManyKeys). All keys together are at most `maxKeys` (Full).
// - A participant is gone when DDS matches none of its writers any more: sweep() finds it
//   (against the reader's matched publications) and frees its keys. A key whose holder's
//   writer is no longer matched passes at once to the next participant that uses it (a
//   client restarted with the same id), without waiting for the sweep.
// - A participant that *proves* a key (a Hello with the key's binding proof, checked through the
//   Proof the endpoint passes: phys/protocol/client_key.h) holds it from then on, whoever held
//   it before, and its commands under it are proven (Result::proven) until it leaves. At most
//   `proofsPerSecond` proofs of a participant are checked (a signature check costs ~0.1 ms);
//   past that its proofs are not looked at and its Hellos stay unproven.
#pragma once

#include <array>
#include <chrono>
#include <cstdint>
#include <functional>
#include <mutex>
#include <span>
#include <string>
#include <unordered_map>
#include <vector>

namespace phys::server {

/// A DDS participant's GUID (its 12-byte prefix and 4-byte entity id).
using Guid = std::array<uint8_t, 16>;
struct GuidHash {
  size_t operator()(const Guid& g) const noexcept;
};
/// As Cyclone DDS prints GUIDs: four 32-bit words in hex, "0110d1a2:5b1c4e3f:9a0b1c2d:1c1".
std::string toString(const Guid& g);

class ClientKeys {
 public:
  using Clock = std::chrono::steady_clock;
  using Writer = uint64_t;  ///< the instance handle DDS gives a matched writer

  struct Limits {
    uint32_t keysPerParticipant = 16;  ///< server.max_keys_per_participant
    size_t maxKeys = size_t(1) << 16;     ///< keys held by all participants together
    size_t maxWriters = size_t(1) << 16;  ///< command writers known at once
    /// A key held by another participant: its holder's writer is asked about (Alive) at most
    /// this often per key, so a participant writing under held keys costs no DDS call each.
    Clock::duration recheck = std::chrono::milliseconds(100);
    /// A participant's refusals are reported (Result::report: a log line, a reply) at its
    /// first and then at most this often.
    Clock::duration reportEvery = std::chrono::seconds(10);
    /// Proofs of one participant checked a second, on average and at once (a token bucket).
    double proofsPerSecond = 4, proofBurst = 8;
  };
  /// Whether DDS still matches a writer (the endpoint: dds_get_matched_publication_data).
  using Alive = std::function<bool(Writer)>;

  enum class Verdict : uint8_t {
    Ok,           ///< the key is the participant's (from now on, or already)
    HeldByOther,  ///< another participant, still there, holds it
    TooManyKeys,  ///< the participant holds keysPerParticipant keys already
    Full,         ///< maxKeys keys are held, or maxWriters writers known
  };
  static const char* toString(Verdict v);

  struct Result {
    Verdict verdict = Verdict::Ok;
    /// The participant's number (from 1 in order of appearance, never reused): the sender
    /// the core counts budgets and interests by (Incoming::sender).
    uint64_t participant = 0;
    /// The identity key of the writer's partition (secure daemon; 0: none).
    uint64_t principal = 0;
    /// A refusal worth reporting: the participant's first, then one per reportEvery.
    bool report = false;
    /// The participant's refusals so far (all verdicts but Ok), this one included.
    uint64_t refusals = 0;
    /// Ok: the participant proved the key (this command's proof, or an earlier one).
    bool proven = false;
  };
  /// A command's offer of a binding proof: checks it against the sending participant's GUID
  /// (the endpoint: protocol::verifyBinding with the Hello's public key and signature).
  using Proof = std::function<bool(const Guid& participant)>;

  ClientKeys(Limits limits, Alive alive);

  /// Whether a writer is known (a command of it was claimed, and no sweep has forgotten it).
  bool knows(Writer w) const { return writers_.count(w) != 0; }
  /// What discovery said of a new writer: its participant and its identity key (0: none).
  /// The endpoint asks DDS once per writer, before the writer's first claim. False when
  /// maxWriters are known (its commands are then refused Full until a sweep frees some).
  bool addWriter(Writer w, const Guid& participant, uint64_t principal);
  /// Whether `writer`'s participant (addWriter first) may use `key` now. proof: the command
  /// offers one (null: it does not); asked only when it would change something (the key is
  /// not yet proven by this participant) and the participant's proof budget allows.
  Result claim(uint64_t key, Writer writer, Clock::time_point now, const Proof* proof = nullptr);

  /// A participant that left: its number and GUID and the keys it held (now free).
  struct Departed {
    uint64_t participant = 0;
    Guid guid{};
    std::vector<uint64_t> keys;
  };
  /// Forgets the writers not in `live` (every writer DDS matches now), and the participants
  /// left without a writer: returns those, whose keys are free again. O(writers known).
  std::vector<Departed> sweep(std::span<const Writer> live);
  /// A claim found the tables full: a sweep is due before the next period.
  bool sweepWanted() const { return sweepWanted_; }

  // --- Inspection ---
  size_t keys() const { return keys_.size(); }
  size_t participants() const { return participants_.size(); }
  size_t writers() const { return writers_.size(); }
  /// The participant holding a key (0: none).
  uint64_t holder(uint64_t key) const;
  /// A participant's GUID by number, or null.
  const Guid* guidOf(uint64_t participant) const;
  /// A known writer's participant number (0: unknown).
  uint64_t participantOf(Writer w) const;
  /// Keys a participant holds.
  size_t keysOf(uint64_t participant) const;
  const Limits& limits() const { return limits_; }

 private:
  struct WriterRec {
    uint64_t participant = 0;
    uint64_t principal = 0;
  };
  struct ParticipantRec {
    Guid guid{};
    uint32_t writers = 0;        ///< known writers
    std::vector<uint64_t> keys;  ///< held, at most keysPerParticipant
    uint64_t refusals = 0;
    Clock::time_point reportedAt{};
    double proofTokens = -1;  ///< -1: a full bucket (not used yet)
    Clock::time_point proofAt{};
  };
  struct KeyRec {
    uint64_t participant = 0;
    Writer writer = 0;  ///< the holder's writer that last used it
    Clock::time_point checkedAt{};  ///< the last Alive(writer) on another's claim
    bool proven = false;  ///< the holder proved it (Proof)
  };
  /// Whether participant `who` (of `guid`) proves a key with `proof`: within its budget, and
  /// the proof holds.
  bool proves(ParticipantRec& who, const Proof* proof, Clock::time_point now);
  /// Whether `claimant` may take a key another participant holds. Today: only when the
  /// holder's writer is gone (asked at most once per recheck).
  bool mayTake(KeyRec& held, uint64_t claimant, Clock::time_point now);
  void release(ParticipantRec& p, uint64_t key);
  Result refuse(Verdict v, uint64_t participant, uint64_t principal, Clock::time_point now);

  Limits limits_;
  Alive alive_;
  std::unordered_map<uint64_t, KeyRec> keys_;
  std::unordered_map<Writer, WriterRec> writers_;
  std::unordered_map<uint64_t, ParticipantRec> participants_;
  std::unordered_map<Guid, uint64_t, GuidHash> byGuid_;
  uint64_t nextParticipant_ = 1;
  bool sweepWanted_ = false;
};

/// What keeps one writer's flood out of the DDS reader itself. Cyclone keeps an instance per
/// key a writer registers (about 600 bytes each, until the writer leaves): 50,000 new ids a
/// second grew physd by 30 MB a second. And every sample taken costs the reader thread a take,
/// a decode and a refusal. The endpoint puts a content filter on its command topic (a
/// sampleinfo filter: no deserialisation) that asks admit() about every sample: one that would
/// make a writer's instance past `instances`, or come past the writer's rate (a token bucket
/// of `rate` a second up to `burst`, set above what the core's per-participant budget answers),
/// is filtered out before Cyclone stores it (and acknowledged, so the writer is not held up).
/// As in the core's budgets, a writer that waits for its replies is not counted: the first
/// sample after a reply to one of its keys (answered(), told by the endpoint as it writes the
/// reply, for the keys bind() tied to the writer) passes free, so a synchronous client, however
/// fast its round trip, is never filtered; a writer gets at most one free sample per reply,
/// so its samples stay within the rate plus the replies it is sent.
/// Thread-safe: admit() runs on Cyclone's delivery threads with the reader's cache locked (it
/// calls nothing).
class InstanceGate {
 public:
  using Clock = std::chrono::steady_clock;
  struct Limits {
    uint32_t instances = 32;  ///< per writer
    double rate = 0;          ///< samples a second per writer; 0: no limit
    double burst = 1;
    Clock::duration reportEvery = std::chrono::seconds(10);
  };
  explicit InstanceGate(Limits limits) : limits_(limits) {}
  /// Whether `writer` may deliver a sample of `instance` (a reader's instance handle) now: one
  /// of its instances or a new one while it has fewer than `instances`, within its rate.
  bool admit(uint64_t writer, uint64_t instance, Clock::time_point now = Clock::now());
  /// `key` (a client id) is the writer's (a command of it under that key came through): a
  /// reply to the key frees the writer's next sample. At most `instances` keys a writer.
  void bind(uint64_t writer, uint64_t key);
  /// A reply to `key` was written: the next sample of the writer bound to it passes free.
  void answered(uint64_t key);
  struct Refused {
    uint64_t writer = 0;
    uint64_t instances = 0;  ///< its samples filtered out for new instances, so far
    uint64_t rate = 0;       ///< ... for its rate
  };
  /// Forgets the writers not in `live`; returns those whose samples were filtered out since
  /// they were last returned, at most once per reportEvery each (for the log).
  std::vector<Refused> sweep(std::span<const uint64_t> live, Clock::time_point now);
  uint64_t refused() const;  ///< samples filtered out, all writers, both reasons
  size_t writers() const;
  const Limits& limits() const { return limits_; }

 private:
  struct WriterRec {
    std::vector<uint64_t> instances;
    std::vector<uint64_t> keys;  ///< bound to it (bind)
    bool answered = false;       ///< a reply went to one of its keys since its last sample
    double tokens = 0;
    Clock::time_point last{};
    uint64_t refusedInstances = 0, refusedRate = 0, reported = 0;
    Clock::time_point reportedAt{};
  };
  const Limits limits_;
  mutable std::mutex mutex_;
  std::unordered_map<uint64_t, WriterRec> writers_;
  std::unordered_map<uint64_t, uint64_t> keyWriters_;  ///< key -> the writer it is bound to
  uint64_t refused_ = 0;
};

}  // namespace phys::server
