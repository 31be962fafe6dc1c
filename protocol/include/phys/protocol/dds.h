// Thin RAII wrappers around the Cyclone DDS C API for the envelope topics: participant,
// topic, writer, reader, waitset. Shared by physd (server/) and the client SDK
// (client_sdk/): every DDS call of both goes through here or their endpoint code.
#pragma once

#include <dds/dds.h>

#include <cstdint>
#include <array>
#include <functional>
#include <span>
#include <string>
#include <unordered_map>
#include <utility>
#include <vector>

#include "phys/protocol/dds_envelope.h"
#include "phys/protocol/topics.h"

namespace phys::protocol::dds {

/// Owns one DDS entity (deleted with its children on destruction).
class Entity {
 public:
  Entity() = default;
  explicit Entity(dds_entity_t e) : e_(e) {}
  ~Entity() { reset(); }
  Entity(Entity&& o) noexcept : e_(std::exchange(o.e_, 0)) {}
  Entity& operator=(Entity&& o) noexcept {
    if (this != &o) {
      reset();
      e_ = std::exchange(o.e_, 0);
    }
    return *this;
  }
  Entity(const Entity&) = delete;
  Entity& operator=(const Entity&) = delete;
  void reset() {
    if (e_ > 0) dds_delete(e_);
    e_ = 0;
  }
  dds_entity_t get() const { return e_; }
  explicit operator bool() const { return e_ > 0; }

 protected:
  dds_entity_t e_ = 0;
};

/// "" when rc >= 0, else Cyclone's name for the error.
std::string error(dds_return_t rc);

/// A participant on a domain. configXml: Cyclone XML for the domain (empty: CYCLONEDDS_URI or
/// Cyclone's defaults). When the domain already exists in this process, it is shared.
class Participant : public Entity {
 public:
  Participant() = default;
  ~Participant() { reset(); }  // the participant before its domain
  /// Returns false and sets *err on failure.
  bool create(uint32_t domain, const std::string& configXml, std::string* err);
  uint32_t domain() const { return domain_; }
  /// Its GUID, as other participants' discovery data names it (Reader::participantOf); all
  /// zero before create().
  std::array<uint8_t, 16> guid() const;

 private:
  Entity domainEntity_;
  uint32_t domain_ = 0;
};

/// A topic of phys_wire_Envelope.
class Topic : public Entity {
 public:
  bool create(const Participant& p, const std::string& name, std::string* err);
  /// A filter that readers of this topic entity (created after it is set) apply to each
  /// sample before storing it, from what DDS knows of the sample without deserialising it
  /// (its writer's and instance's handles): a sample filtered out of a new instance makes no
  /// instance. fn runs on Cyclone's delivery threads with the reader's cache locked. Cyclone
  /// calls this API unstable (dds_set_topic_filter_extended, 0.10).
  bool setSampleInfoFilter(bool (*fn)(const dds_sample_info_t* info, void* arg), void* arg,
                           std::string* err);
  const std::string& name() const { return name_; }

 private:
  std::string name_;
};

/// An envelope writer with the topic's QoS preset; counts seq per writer.
class Writer : public Entity {
 public:
  Writer() = default;
  Writer(Writer&&) = default;
  Writer& operator=(Writer&&) = default;  // the old writer goes before its publisher
  ~Writer() { reset(); }                  // the writer before its publisher
  /// partitions: DDS partitions of the writer's own publisher (empty: the participant's
  /// implicit publisher, default partition). A client writes its commands in its identity's
  /// partition on a secure daemon (phys/protocol/security.h).
  bool create(const Participant& p, const Topic& t, const protocol::QosPreset& qos,
              protocol::PayloadKind kind, std::string* err,
              const std::vector<std::string>& partitions = {});
  /// Writes one envelope (Cyclone serializes it before returning).
  dds_return_t write(uint64_t key, std::span<const uint8_t> bytes, uint64_t seq = 0);
  /// Asserts the liveliness of a writer whose QoS has a lease (QosPreset::livelinessLeaseMs):
  /// its readers keep its instances alive for another lease without a sample.
  dds_return_t assertLiveliness();
  /// Disposes the instance of key (transient-local readers forget it).
  dds_return_t dispose(uint64_t key);
  /// Matched readers now.
  uint32_t matched() const;
  /// Matched readers now and, in *total, readers ever matched (DDS's total_count: it grows
  /// by one for each new reader, even when another went meanwhile).
  uint32_t matched(uint64_t* total) const;
  /// Instance handles of the matched readers (a new handle: a new reader, e.g. a restarted
  /// daemon).
  std::vector<dds_instance_handle_t> matchedHandles() const;

 private:
  Entity publisher_;
  protocol::PayloadKind kind_ = protocol::PayloadKind::Command;
  uint64_t seq_ = 0;
};

/// An envelope reader with the topic's QoS preset.
/// The envelope of a sample in its serialized (CDR) form, `size` bytes from the 4-byte
/// encapsulation header on, read in place: env's payload points into `cdr`. Little-endian
/// XCDR1 (0x0001) and PLAIN_CDR2 (0x0007) only; false for anything else, or a short or
/// inconsistent buffer (Reader::take then deserializes the sample the ordinary way).
bool viewSerializedEnvelope(const uint8_t* cdr, size_t size, phys_wire_Envelope* env);

class Reader : public Entity {
 public:
  Reader() = default;
  Reader(Reader&&) = default;
  Reader& operator=(Reader&&) = default;  // the old reader goes before its subscriber
  ~Reader() { reset(); }                  // the reader before its subscriber
  /// partitions: DDS partitions (wildcards allowed) of the reader's own subscriber (empty:
  /// the implicit subscriber, default partition).
  bool create(const Participant& p, const Topic& t, const protocol::QosPreset& qos,
              std::string* err, const std::vector<std::string>& partitions = {});
  /// Takes every available sample, calling fn for each valid one; returns the count or a
  /// negative retcode.
  int take(const std::function<void(const phys_wire_Envelope&)>& fn);
  /// The same, with the instance handle of the writer each sample came from (what DDS vouches
  /// for about its sender: see participantOf).
  int take(const std::function<void(const phys_wire_Envelope&, dds_instance_handle_t writer)>& fn);
  /// The same, and gone(key) for each instance that DDS says has no live writer any more
  /// (its writer's liveliness lapsed, or the writer was deleted) or was disposed: only for
  /// instances this reader took a sample of through this overload (one entry per instance
  /// kept: for topics of few instances, like phys/status).
  int take(const std::function<void(const phys_wire_Envelope&, dds_instance_handle_t writer)>& fn,
           const std::function<void(uint64_t key)>& gone);
  /// The participant (its GUID, 16 bytes) of a writer matched with this reader; false when
  /// the writer is not (or no longer) matched.
  bool participantOf(dds_instance_handle_t writer, std::array<uint8_t, 16>* guid) const;
  /// The same, and the writer's partitions (as discovery announced them; on a secure domain
  /// the access-control plugin has checked them against the writer's signed permissions).
  bool publicationOf(dds_instance_handle_t writer, std::array<uint8_t, 16>* guid,
                     std::vector<std::string>* partitions) const;
  /// Instance handles of every writer matched with this reader now (the same handles as a
  /// sample's publication handle); false on an error (*out then says nothing).
  bool matchedPublications(std::vector<dds_instance_handle_t>* out) const;
  uint32_t matched() const;

 private:
  Entity subscriber_;
  std::unordered_map<dds_instance_handle_t, uint64_t> instanceKeys_;  ///< see take(fn, gone)
};

/// A waitset with a data-available condition per attached reader and a guard to wake it.
class WaitSet : public Entity {
 public:
  bool create(const Participant& p, std::string* err);
  bool attach(const Reader& r, std::string* err);
  /// Detaches and deletes the condition of r.
  void detach(const Reader& r);
  void wake();
  /// Waits up to timeout; returns the number of triggered conditions (0 on timeout).
  int wait(dds_duration_t timeout);

 private:
  Entity guard_;
  std::vector<std::pair<dds_entity_t, Entity>> conditions_;  ///< reader, condition
};

}  // namespace phys::protocol::dds
