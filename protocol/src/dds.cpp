// RAII wrappers around the Cyclone DDS C API (phys/protocol/dds.h).
#include "phys/protocol/dds.h"

#include <dds/ddsi/ddsi_serdata.h>

#include <algorithm>
#include <bit>
#include <cstring>

#include "phys/protocol/qos.h"

namespace phys::protocol::dds {

std::string error(dds_return_t rc) {
  return rc >= 0 ? std::string() : std::string(dds_strretcode(rc));
}

namespace {
bool check(dds_entity_t e, const std::string& what, std::string* err) {
  if (e > 0) return true;
  if (err) *err = what + ": " + error(e);
  return false;
}
}  // namespace

bool Participant::create(uint32_t domain, const std::string& configXml, std::string* err) {
  domain_ = domain;
  if (!configXml.empty()) {
    dds_entity_t d = dds_create_domain(dds_domainid_t(domain), configXml.c_str());
    // PRECONDITION_NOT_MET: the domain exists already in this process; share it.
    if (d > 0) {
      domainEntity_ = Entity(d);
    } else if (d != DDS_RETCODE_PRECONDITION_NOT_MET) {
      return check(d, "dds_create_domain " + std::to_string(domain), err);
    }
  }
  dds_entity_t p = dds_create_participant(dds_domainid_t(domain), nullptr, nullptr);
  if (!check(p, "dds_create_participant on domain " + std::to_string(domain), err)) return false;
  e_ = p;
  return true;
}

std::array<uint8_t, 16> Participant::guid() const {
  std::array<uint8_t, 16> g{};
  dds_guid_t id;
  static_assert(sizeof id.v == 16);
  if (e_ > 0 && dds_get_guid(e_, &id) == DDS_RETCODE_OK) std::memcpy(g.data(), id.v, 16);
  return g;
}

bool Topic::create(const Participant& p, const std::string& name, std::string* err) {
  name_ = name;
  dds_entity_t t =
      dds_create_topic(p.get(), &phys_wire_Envelope_desc, name.c_str(), nullptr, nullptr);
  if (!check(t, "dds_create_topic " + name, err)) return false;
  e_ = t;
  return true;
}

bool Topic::setSampleInfoFilter(bool (*fn)(const dds_sample_info_t* info, void* arg), void* arg,
                                std::string* err) {
  dds_topic_filter f{};
  f.mode = DDS_TOPIC_FILTER_SAMPLEINFO_ARG;
  f.f.sampleinfo_arg = fn;
  f.arg = arg;
  const dds_return_t rc = dds_set_topic_filter_extended(e_, &f);
  if (rc == DDS_RETCODE_OK) return true;
  if (err) *err = "dds_set_topic_filter_extended " + name_ + ": " + error(rc);
  return false;
}

namespace {
/// A publisher (or subscriber) of its own for an entity in partitions; 0 (the participant's
/// implicit one) for none.
dds_entity_t partitioned(const Participant& p, const std::vector<std::string>& partitions,
                         bool publisher, Entity* out, std::string* err) {
  if (partitions.empty()) return p.get();
  std::vector<const char*> names;
  for (const std::string& s : partitions) names.push_back(s.c_str());
  dds_qos_t* q = dds_create_qos();
  dds_qset_partition(q, uint32_t(names.size()), names.data());
  dds_entity_t e = publisher ? dds_create_publisher(p.get(), q, nullptr)
                             : dds_create_subscriber(p.get(), q, nullptr);
  dds_delete_qos(q);
  if (!check(e, publisher ? "dds_create_publisher" : "dds_create_subscriber", err)) return 0;
  *out = Entity(e);
  return e;
}
}  // namespace

bool Writer::create(const Participant& p, const Topic& t, const protocol::QosPreset& qos,
                    protocol::PayloadKind kind, std::string* err,
                    const std::vector<std::string>& partitions) {
  kind_ = kind;
  const dds_entity_t parent = partitioned(p, partitions, true, &publisher_, err);
  if (!parent) return false;
  protocol::QosPtr q = protocol::makeQos(qos);
  dds_entity_t w = dds_create_writer(parent, t.get(), q.get(), nullptr);
  if (!check(w, "dds_create_writer " + t.name(), err)) return false;
  e_ = w;
  return true;
}

dds_return_t Writer::write(uint64_t key, std::span<const uint8_t> bytes, uint64_t seq) {
  phys_wire_Envelope env{};
  protocol::wrapEnvelope(&env, key, seq ? seq : ++seq_, kind_, bytes);
  return dds_write(e_, &env);
}

dds_return_t Writer::assertLiveliness() {
  return dds_assert_liveliness(e_);
}

dds_return_t Writer::dispose(uint64_t key) {
  phys_wire_Envelope env{};
  protocol::wrapEnvelope(&env, key, 0, kind_, {});
  return dds_dispose(e_, &env);
}

uint32_t Writer::matched() const {
  return matched(nullptr);
}

uint32_t Writer::matched(uint64_t* total) const {
  dds_publication_matched_status_t m{};
  if (dds_get_publication_matched_status(e_, &m) != DDS_RETCODE_OK) return 0;
  if (total) *total = m.total_count;
  return m.current_count;
}

std::vector<dds_instance_handle_t> Writer::matchedHandles() const {
  dds_instance_handle_t h[64];
  dds_return_t n = dds_get_matched_subscriptions(e_, h, 64);
  if (n <= 0) return {};
  return std::vector<dds_instance_handle_t>(h, h + std::min<dds_return_t>(n, 64));
}

bool Reader::create(const Participant& p, const Topic& t, const protocol::QosPreset& qos,
                    std::string* err, const std::vector<std::string>& partitions) {
  const dds_entity_t parent = partitioned(p, partitions, false, &subscriber_, err);
  if (!parent) return false;
  protocol::QosPreset requested = qos;
  requested.livelinessLeaseMs = 0;  // automatic, infinite: any writer's lease matches
  protocol::QosPtr q = protocol::makeQos(requested);
  dds_entity_t r = dds_create_reader(parent, t.get(), q.get(), nullptr);
  if (!check(r, "dds_create_reader " + t.name(), err)) return false;
  e_ = r;
  return true;
}

// Layout, little-endian (XCDR1 and XCDR2 align the same here): a 4-byte encapsulation header,
// then key u64 @0, seq u64 @8, kind u16 @16, schema_version u16 @18, the payload's length u32
// @20 and its bytes @24 (offsets after the header). Delimited (0x0009) and mutable (0x000b)
// encodings, and big-endian ones, are refused. This reads Cyclone DDS 0.10's serialized form
// (dds/ddsi/ddsi_serdata.h, not a stable API): a later version that changes it only sends
// samples down the fallback, at the old speed.
bool viewSerializedEnvelope(const uint8_t* p, size_t size, phys_wire_Envelope* env) {
  constexpr size_t kHeader = 4, kFixed = 24;
  if (size < kHeader + kFixed) return false;
  // Encapsulation identifiers: 0x0001 CDR_LE, 0x0007 PLAIN_CDR2_LE.
  if (p[0] != 0 || (p[1] != 0x01 && p[1] != 0x07)) return false;
  if constexpr (std::endian::native != std::endian::little) return false;
  const uint8_t* d = p + kHeader;
  uint32_t length = 0;
  std::memcpy(&env->key, d, 8);
  std::memcpy(&env->seq, d + 8, 8);
  std::memcpy(&env->kind, d + 16, 2);
  std::memcpy(&env->schema_version, d + 18, 2);
  std::memcpy(&length, d + 20, 4);
  if (length > size - kHeader - kFixed) return false;
  env->bytes._buffer = const_cast<uint8_t*>(d + kFixed);
  env->bytes._length = length;
  env->bytes._maximum = length;
  env->bytes._release = false;
  return true;
}

int Reader::take(const std::function<void(const phys_wire_Envelope&)>& fn) {
  return take([&](const phys_wire_Envelope& env, dds_instance_handle_t) { fn(env); });
}

bool Reader::participantOf(dds_instance_handle_t writer, std::array<uint8_t, 16>* guid) const {
  return publicationOf(writer, guid, nullptr);
}

bool Reader::publicationOf(dds_instance_handle_t writer, std::array<uint8_t, 16>* guid,
                           std::vector<std::string>* partitions) const {
  dds_builtintopic_endpoint_t* ep = dds_get_matched_publication_data(e_, writer);
  if (!ep) return false;
  static_assert(sizeof ep->participant_key.v == 16);
  std::memcpy(guid->data(), ep->participant_key.v, 16);
  if (partitions) {
    partitions->clear();
    uint32_t n = 0;
    char** ps = nullptr;
    if (ep->qos && dds_qget_partition(ep->qos, &n, &ps)) {
      for (uint32_t i = 0; i < n; ++i) {
        partitions->emplace_back(ps[i] ? ps[i] : "");
        dds_free(ps[i]);
      }
      dds_free(ps);
    }
  }
  dds_builtintopic_free_endpoint(ep);
  return true;
}

int Reader::take(
    const std::function<void(const phys_wire_Envelope&, dds_instance_handle_t writer)>& fn) {
  return take(fn, {});
}

int Reader::take(
    const std::function<void(const phys_wire_Envelope&, dds_instance_handle_t writer)>& fn,
    const std::function<void(uint64_t key)>& gone) {
  // Serialized samples (dds_takecdr), viewed in place: dds_take would copy every payload
  // out of Cyclone's sample into a buffer of its own first, 64 KB per state chunk and
  // subscriber (docs/BENCHMARKS.md, fan-out).
  constexpr int kBatch = 32;
  int total = 0;
  for (;;) {
    ddsi_serdata* samples[kBatch] = {};
    dds_sample_info_t infos[kBatch];
    int n = dds_takecdr(e_, samples, kBatch, infos, 0);
    if (n < 0) return total > 0 ? total : n;
    for (int i = 0; i < n; ++i) {
      ddsi_serdata* sd = samples[i];
      if (infos[i].valid_data) {
        const uint32_t size = ddsi_serdata_size(sd);
        ddsrt_iovec_t ref{};
        ddsi_serdata* held = ddsi_serdata_to_ser_ref(sd, 0, size, &ref);
        phys_wire_Envelope env{};
        if (held && ref.iov_len == size &&
            viewSerializedEnvelope(static_cast<const uint8_t*>(ref.iov_base), size, &env)) {
          fn(env, infos[i].publication_handle);
          if (gone) instanceKeys_[infos[i].instance_handle] = env.key;
          ++total;
        } else {
          env = phys_wire_Envelope{};
          if (ddsi_serdata_to_sample(sd, &env, nullptr, nullptr)) {
            fn(env, infos[i].publication_handle);
            if (gone) instanceKeys_[infos[i].instance_handle] = env.key;
            ++total;
          }
          dds_sample_free(&env, &phys_wire_Envelope_desc, DDS_FREE_CONTENTS);
        }
        if (held) ddsi_serdata_to_ser_unref(held, &ref);
      } else if (gone && infos[i].instance_state != DDS_IST_ALIVE) {
        // No data: the instance lost its writers (liveliness lapsed, writer deleted) or was
        // disposed. Its key, from the samples it had (an invalid sample's serdata is
        // Cyclone's untyped key form, which this API cannot decode without the sertype).
        auto k = instanceKeys_.find(infos[i].instance_handle);
        if (k != instanceKeys_.end()) gone(k->second);
      }
      ddsi_serdata_unref(sd);
    }
    if (n < kBatch) return total;
  }
}

bool Reader::matchedPublications(std::vector<dds_instance_handle_t>* out) const {
  // The count comes back even when the buffer is short: grow it and ask again.
  out->resize(std::max<size_t>(out->capacity(), 64));
  for (int tries = 0; tries < 4; ++tries) {
    const dds_return_t n = dds_get_matched_publications(e_, out->data(), out->size());
    if (n < 0) return false;
    if (size_t(n) <= out->size()) {
      out->resize(size_t(n));
      return true;
    }
    out->resize(size_t(n) + 64);
  }
  return false;  // still growing faster than we ask
}

uint32_t Reader::matched() const {
  dds_subscription_matched_status_t m{};
  if (dds_get_subscription_matched_status(e_, &m) != DDS_RETCODE_OK) return 0;
  return m.current_count;
}

bool WaitSet::create(const Participant& p, std::string* err) {
  dds_entity_t ws = dds_create_waitset(p.get());
  if (!check(ws, "dds_create_waitset", err)) return false;
  e_ = ws;
  dds_entity_t g = dds_create_guardcondition(p.get());
  if (!check(g, "dds_create_guardcondition", err)) return false;
  guard_ = Entity(g);
  dds_return_t rc = dds_waitset_attach(e_, g, 0);
  if (rc < 0) {
    if (err) *err = "dds_waitset_attach: " + error(rc);
    return false;
  }
  return true;
}

bool WaitSet::attach(const Reader& r, std::string* err) {
  dds_entity_t c = dds_create_readcondition(r.get(), DDS_ANY_STATE);
  if (!check(c, "dds_create_readcondition", err)) return false;
  dds_return_t rc = dds_waitset_attach(e_, c, r.get());
  if (rc < 0) {
    dds_delete(c);
    if (err) *err = "dds_waitset_attach: " + error(rc);
    return false;
  }
  conditions_.emplace_back(r.get(), Entity(c));
  return true;
}

void WaitSet::detach(const Reader& r) {
  for (auto it = conditions_.begin(); it != conditions_.end(); ++it)
    if (it->first == r.get()) {
      dds_waitset_detach(e_, it->second.get());
      conditions_.erase(it);
      return;
    }
}

void WaitSet::wake() {
  if (guard_) dds_set_guardcondition(guard_.get(), true);
}

int WaitSet::wait(dds_duration_t timeout) {
  int n = dds_waitset_wait(e_, nullptr, 0, timeout);
  if (guard_) dds_set_guardcondition(guard_.get(), false);
  return n;
}

}  // namespace phys::protocol::dds
