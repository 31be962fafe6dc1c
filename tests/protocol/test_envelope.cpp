// The idlc envelope, topic names, QoS presets, and one real write/read over loopback DDS.
#include <dds/dds.h>
#include <unistd.h>

#include <chrono>
#include <iterator>
#include <map>
#include <span>
#include <string>
#include <thread>
#include <vector>

#include "phys/protocol/dds.h"
#include "phys/protocol/dds_envelope.h"
#include "phys/protocol/qos.h"
#include "phys/protocol/topics.h"
#include "protocol_test_util.h"

namespace phys::protocol::test {
namespace {

TEST(ProtocolEnvelope, GeneratedType) {
  EXPECT_EQ(phys_wire_Envelope_desc.m_size, sizeof(phys_wire_Envelope));
  EXPECT_EQ(phys_wire_Envelope_desc.m_nkeys, 1u);
  EXPECT_STREQ(phys_wire_Envelope_desc.m_typename, "phys::wire::Envelope");
  EXPECT_EQ(phys_wire_ENVELOPE_MAX_BYTES, kMaxEnvelopeBytes);
  EXPECT_EQ(Limits{}.maxMessageBytes, kMaxEnvelopeBytes);
}

TEST(ProtocolEnvelope, WrapAndCheck) {
  Bytes cmd = CommandBuilder().step(2).finish(header());
  phys_wire_Envelope env{};
  wrapEnvelope(&env, kClient, 9, PayloadKind::Command, cmd);
  EXPECT_EQ(env.key, kClient);
  EXPECT_EQ(env.seq, 9u);
  EXPECT_EQ(env.kind, 1);
  EXPECT_EQ(env.schema_version, kProtocolVersion);
  EXPECT_EQ(env.bytes._length, cmd.size());
  EXPECT_FALSE(env.bytes._release);
  EXPECT_TRUE(checkEnvelope(env, PayloadKind::Command).ok());
  auto d = decodeCommand(envelopeBytes(env));
  ASSERT_TRUE(d.ok());
  EXPECT_EQ(d->request_as_Step()->count(), 2u);

  Status s = checkEnvelope(env, PayloadKind::Reply);
  EXPECT_EQ(s.code, Code::Malformed);
  EXPECT_EQ(s.message, "envelope.kind is 1, expected 2 (Reply)");
  env.schema_version = 2;
  EXPECT_EQ(checkEnvelope(env, PayloadKind::Command).code, Code::Unsupported);
  env.schema_version = kProtocolVersion;
  Limits small;
  small.maxMessageBytes = 16;
  s = checkEnvelope(env, PayloadKind::Command, small);
  EXPECT_EQ(s.code, Code::ResourceExhausted);
  EXPECT_NE(s.message.find("(max_message_bytes)"), std::string::npos);
}

TEST(ProtocolTopics, NamesKeysAndQos) {
  EXPECT_EQ(kCommandTopic, "phys/cmd");
  EXPECT_EQ(kReplyTopic, "phys/reply");
  EXPECT_EQ(stateTopic(12), "phys/state/12");
  EXPECT_EQ(kWorldInfoTopic, "phys/world_info");
  EXPECT_EQ(kStatusTopic, "phys/status");
  EXPECT_EQ(kEventsTopic, "phys/events");
  EXPECT_EQ(worldInfoKey(3, 2), (uint64_t(3) << 32) | 2);
  EXPECT_STREQ(toString(PayloadKind::StateFrame), "StateFrame");

  for (const TopicSpec& t : kTopics) {
    QosPtr q = makeQos(t.qos);
    ASSERT_TRUE(q);
    dds_reliability_kind_t rel;
    dds_duration_t blocking;
    ASSERT_TRUE(dds_qget_reliability(q.get(), &rel, &blocking));
    EXPECT_EQ(rel, t.qos.reliability == Reliability::Reliable ? DDS_RELIABILITY_RELIABLE
                                                              : DDS_RELIABILITY_BEST_EFFORT);
    dds_durability_kind_t dur;
    ASSERT_TRUE(dds_qget_durability(q.get(), &dur));
    EXPECT_EQ(dur, t.qos.durability == Durability::TransientLocal ? DDS_DURABILITY_TRANSIENT_LOCAL
                                                                  : DDS_DURABILITY_VOLATILE);
    dds_history_kind_t hist;
    int32_t depth;
    ASSERT_TRUE(dds_qget_history(q.get(), &hist, &depth));
    EXPECT_EQ(hist, DDS_HISTORY_KEEP_LAST);
    EXPECT_EQ(depth, t.qos.depth);
  }
  EXPECT_EQ(kStateQos.depth, 1);
  EXPECT_GT(kStateReaderQos.depth, kStateQos.depth);
  EXPECT_EQ(kStateReaderQos.reliability, kStateQos.reliability);
  EXPECT_EQ(kWorldInfoQos.durability, Durability::TransientLocal);
}

// Loopback-only Cyclone configuration (docs/TOOLCHAIN_FACTS), on a domain of its own.
constexpr const char* kLoopback =
    "<CycloneDDS><Domain><General><Interfaces><NetworkInterface name=\"lo\"/></Interfaces>"
    "<AllowMulticast>false</AllowMulticast></General><Discovery><Peers>"
    "<Peer address=\"127.0.0.1\"/></Peers><ParticipantIndex>auto</ParticipantIndex>"
    "<MaxAutoParticipantIndex>64</MaxAutoParticipantIndex></Discovery></Domain></CycloneDDS>";

/// Polls until pred() or the deadline; true when pred() held.
template <class Pred>
bool waitFor(Pred pred, std::chrono::milliseconds timeout) {
  auto end = std::chrono::steady_clock::now() + timeout;
  while (std::chrono::steady_clock::now() < end) {
    if (pred()) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  return pred();
}

TEST(ProtocolEnvelope, LoopbackWriteRead) {
  const dds_domainid_t domain = 150 + dds_domainid_t(getpid() % 80);
  dds_entity_t dom = dds_create_domain(domain, kLoopback);
  if (dom < 0) GTEST_SKIP() << "no DDS domain on loopback: " << dds_strretcode(dom);
  dds_entity_t participant = dds_create_participant(domain, nullptr, nullptr);
  ASSERT_GT(participant, 0) << dds_strretcode(participant);
  dds_entity_t topic = dds_create_topic(participant, &phys_wire_Envelope_desc,
                                        std::string(kCommandTopic).c_str(), nullptr, nullptr);
  ASSERT_GT(topic, 0) << dds_strretcode(topic);
  // A per-world state topic name is valid too.
  dds_entity_t state = dds_create_topic(participant, &phys_wire_Envelope_desc,
                                        stateTopic(1).c_str(), nullptr, nullptr);
  EXPECT_GT(state, 0) << dds_strretcode(state);
  QosPtr qos = makeQos(kCommandQos);
  dds_entity_t writer = dds_create_writer(participant, topic, qos.get(), nullptr);
  dds_entity_t reader = dds_create_reader(participant, topic, qos.get(), nullptr);
  ASSERT_GT(writer, 0) << dds_strretcode(writer);
  ASSERT_GT(reader, 0) << dds_strretcode(reader);
  ASSERT_TRUE(waitFor(
      [&] {
        dds_publication_matched_status_t m;
        return dds_get_publication_matched_status(writer, &m) == DDS_RETCODE_OK &&
               m.current_count > 0;
      },
      std::chrono::seconds(5)));

  // A command of about 1 MB (many bodies) and a small one.
  std::vector<phys::BodyDef> bodies(10000, boxBody({0, 0, 1}, {0.5f, 0.5f, 0.5f}));
  Bytes big = CommandBuilder().spawnBodies(bodies).finish(header(1));
  Bytes small = CommandBuilder().step(5).finish(header(2));
  ASSERT_GT(big.size(), 500000u);
  for (const Bytes* b : {&big, &small}) {
    phys_wire_Envelope env{};
    wrapEnvelope(&env, kClient, b == &big ? 1 : 2, PayloadKind::Command, *b);
    ASSERT_EQ(dds_write(writer, &env), DDS_RETCODE_OK);
  }
  // Past the IDL bound the write fails (and nothing is sent).
  Bytes tooBig(kMaxEnvelopeBytes + 1, 0);
  phys_wire_Envelope over{};
  wrapEnvelope(&over, kClient, 3, PayloadKind::Command, tooBig);
  EXPECT_EQ(dds_write(writer, &over), DDS_RETCODE_BAD_PARAMETER);

  int received = 0;
  bool ok = waitFor(
      [&] {
        void* samples[4] = {};
        dds_sample_info_t infos[4];
        int n = dds_take(reader, samples, infos, 4, 4);
        for (int i = 0; i < n; ++i) {
          if (!infos[i].valid_data) continue;
          auto* env = static_cast<const phys_wire_Envelope*>(samples[i]);
          EXPECT_TRUE(checkEnvelope(*env, PayloadKind::Command).ok());
          EXPECT_EQ(env->key, kClient);
          auto d = decodeCommand(envelopeBytes(*env));
          EXPECT_TRUE(d.ok()) << d.status.message;
          if (d.ok()) {
            EXPECT_EQ(d->seq(), env->seq);
            if (env->seq == 1) {
              EXPECT_EQ(d->request_as_SpawnBodies()->bodies()->size(), 10000u);
            } else {
              EXPECT_EQ(d->request_as_Step()->count(), 5u);
            }
          }
          ++received;
        }
        if (n > 0) dds_return_loan(reader, samples, n);
        return received >= 2;
      },
      std::chrono::seconds(5));
  EXPECT_TRUE(ok) << "received " << received << " of 2";
  EXPECT_EQ(received, 2);
  dds_delete(participant);
  dds_delete(dom);
}

TEST(ProtocolEnvelope, ReaderTakeHandsOverEveryPayloadByteForByte) {
  // dds::Reader::take reads each sample's envelope in its serialized form, in place
  // (protocol/src/dds.cpp): payloads of 0, 1 and 3 bytes (the end of the CDR stream and
  // its padding), a 1000-body state chunk's size, and 1 MB must come out with the key, seq,
  // kind, schema version and every byte the writer gave. (One participant: delivery is
  // in-process, XCDR1; the other encodings are checked on built buffers below, and the SDK's
  // tests run the same path between processes.)
  const uint32_t domain = 150 + uint32_t(getpid() % 80);
  std::string err;
  dds::Participant participant;
  if (!participant.create(domain, kLoopback, &err)) GTEST_SKIP() << "no DDS domain: " << err;
  dds::Topic topic;
  ASSERT_TRUE(topic.create(participant, "phys/test/take_view", &err)) << err;
  dds::Writer writer;
  ASSERT_TRUE(writer.create(participant, topic, kCommandQos, PayloadKind::Command, &err)) << err;
  dds::Reader reader;
  ASSERT_TRUE(reader.create(participant, topic, kCommandQos, &err)) << err;
  ASSERT_TRUE(waitFor([&] { return writer.matched() > 0; }, std::chrono::seconds(5)));

  const size_t sizes[] = {0, 1, 3, 64200, 1000003};
  std::map<uint64_t, Bytes> sent;
  for (size_t k = 0; k < std::size(sizes); ++k) {
    Bytes b(sizes[k]);
    for (size_t i = 0; i < b.size(); ++i) b[i] = uint8_t(i * 7 + k);
    ASSERT_EQ(writer.write(100 + k, b, 1000 + k), DDS_RETCODE_OK);
    sent[100 + k] = std::move(b);
  }
  std::map<uint64_t, Bytes> got;
  ASSERT_TRUE(waitFor(
      [&] {
        reader.take([&](const phys_wire_Envelope& env) {
          EXPECT_EQ(env.seq, env.key + 900);
          EXPECT_EQ(env.kind, uint16_t(PayloadKind::Command));
          EXPECT_EQ(env.schema_version, kProtocolVersion);
          const std::span<const uint8_t> bytes = envelopeBytes(env);
          got[env.key] = Bytes(bytes.begin(), bytes.end());
        });
        return got.size() >= sent.size();
      },
      std::chrono::seconds(5)));
  EXPECT_EQ(got, sent);
}

/// An envelope serialized as CDR: encapsulation id `enc`, key 7, seq 9, kind 3, schema 1,
/// then the payload's length and bytes.
std::vector<uint8_t> cdrEnvelope(uint8_t enc, const std::vector<uint8_t>& payload) {
  std::vector<uint8_t> b = {0, enc, 0, 0};
  auto put = [&](uint64_t v, int n) {
    for (int i = 0; i < n; ++i) b.push_back(uint8_t(v >> (8 * i)));
  };
  put(7, 8);
  put(9, 8);
  put(3, 2);
  put(1, 2);
  put(payload.size(), 4);
  b.insert(b.end(), payload.begin(), payload.end());
  return b;
}

TEST(ProtocolEnvelope, SerializedViewReadsLittleEndianCdrOnly) {
  const std::vector<uint8_t> payload = {1, 2, 3, 4, 5};
  for (uint8_t enc : {uint8_t(0x01), uint8_t(0x07)}) {  // XCDR1, PLAIN_CDR2 (little-endian)
    const std::vector<uint8_t> b = cdrEnvelope(enc, payload);
    phys_wire_Envelope env{};
    ASSERT_TRUE(dds::viewSerializedEnvelope(b.data(), b.size(), &env)) << int(enc);
    EXPECT_EQ(env.key, 7u);
    EXPECT_EQ(env.seq, 9u);
    EXPECT_EQ(env.kind, 3u);
    EXPECT_EQ(env.schema_version, 1u);
    ASSERT_EQ(env.bytes._length, payload.size());
    EXPECT_EQ(env.bytes._buffer, b.data() + 28);  // in place, not copied
    EXPECT_FALSE(env.bytes._release);
  }
  // Big-endian, delimited and mutable encodings go to Cyclone's own deserializer.
  for (uint8_t enc : {uint8_t(0x00), uint8_t(0x06), uint8_t(0x09), uint8_t(0x0b)}) {
    const std::vector<uint8_t> b = cdrEnvelope(enc, payload);
    phys_wire_Envelope env{};
    EXPECT_FALSE(dds::viewSerializedEnvelope(b.data(), b.size(), &env)) << int(enc);
  }
  // A length past the buffer, a buffer cut inside the fixed fields: refused, nothing read
  // past the end.
  std::vector<uint8_t> b = cdrEnvelope(0x01, payload);
  b.pop_back();
  phys_wire_Envelope env{};
  EXPECT_FALSE(dds::viewSerializedEnvelope(b.data(), b.size(), &env));
  b = cdrEnvelope(0x01, {});
  EXPECT_TRUE(dds::viewSerializedEnvelope(b.data(), b.size(), &env));
  EXPECT_EQ(env.bytes._length, 0u);
  EXPECT_FALSE(dds::viewSerializedEnvelope(b.data(), b.size() - 1, &env));
  EXPECT_FALSE(dds::viewSerializedEnvelope(b.data(), 3, &env));
}

}  // namespace
}  // namespace phys::protocol::test
