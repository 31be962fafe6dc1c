// DdsEndpoint: phys/cmd -> ServerCore, PublishQueue -> the published topics.
#include "phys/server/endpoint.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <optional>

#include <spdlog/spdlog.h>

#include "phys/protocol/dds_envelope.h"
#include "phys/protocol/client_key.h"
#include "phys/protocol/cluster.h"
#include "phys/protocol/decoder.h"
#include "phys/protocol/security.h"

namespace phys::server {

using protocol::PayloadKind;

namespace {
ClientKeys::Limits keyLimits(const CoreConfig& c) {
  ClientKeys::Limits l;
  l.keysPerParticipant = c.maxKeysPerParticipant;
  return l;
}
/// Twice what the core serves and ClientKeys binds: a writer past its ids or its rate still has
/// some of those commands reach them, which report them and answer one in a while; what is
/// beyond that costs the reader nothing.
InstanceGate::Limits gateLimits(const CoreConfig& c) {
  InstanceGate::Limits l;
  l.instances = 2 * std::max<uint32_t>(1, c.maxKeysPerParticipant);
  l.rate = 2 * c.maxParticipantCommandsPerS;
  l.burst = 2 * c.maxParticipantBurst;
  return l;
}
}  // namespace

DdsEndpoint::DdsEndpoint(ServerCore* core, EndpointConfig config)
    : keys_(keyLimits(core->config()),
            [this](ClientKeys::Writer w) {
              Guid g;
              return cmdReader_.participantOf(w, &g);
            }),
      gate_(gateLimits(core->config())),
      core_(core),
      config_(std::move(config)) {}

DdsEndpoint::~DdsEndpoint() {
  stop();
}

Status DdsEndpoint::start() {
  std::string err;
  auto fail = [&]() { return Status::Error(Code::Internal, err); };
  if (!participant_.create(config_.domain, config_.cycloneXml, &err)) return fail();
  if (!cmdTopic_.create(participant_, std::string(protocol::kCommandTopic), &err) ||
      !cmdTopic_.setSampleInfoFilter(&DdsEndpoint::admitSample, &gate_, &err) ||
      !replyTopic_.create(participant_, std::string(protocol::kReplyTopic), &err) ||
      !infoTopic_.create(participant_, std::string(protocol::kWorldInfoTopic), &err) ||
      !statusTopic_.create(participant_, std::string(protocol::kStatusTopic), &err) ||
      !eventsTopic_.create(participant_, std::string(protocol::kEventsTopic), &err))
    return fail();
  // Commands come in the default partition and, from clients with a DDS Security identity,
  // in that identity's partition (protocol/security.h).
  protocol::QosPreset statusQos = protocol::kStatusQos;
  statusQos.livelinessLeaseMs = int32_t(config_.liveliness.count());
  const std::vector<std::string> cmdPartitions = {
      "", std::string(protocol::kIdentityPartitionPrefix) + "*"};
  if (!cmdReader_.create(participant_, cmdTopic_, protocol::kCommandQos, &err, cmdPartitions) ||
      !replyWriter_.create(participant_, replyTopic_, protocol::kReplyQos, PayloadKind::Reply,
                           &err) ||
      !infoWriter_.create(participant_, infoTopic_, protocol::kWorldInfoQos, PayloadKind::WorldInfo,
                          &err) ||
      !statusWriter_.create(participant_, statusTopic_, statusQos, PayloadKind::ServerStatus,
                            &err) ||
      !eventsWriter_.create(participant_, eventsTopic_, protocol::kEventsQos, PayloadKind::Event,
                            &err))
    return fail();
  if (!waitset_.create(participant_, &err) || !waitset_.attach(cmdReader_, &err)) return fail();
  // A daemon of a cluster talks to the others on phys/peer (moving worlds).
  if (core_->config().cluster &&
      (!peerTopic_.create(participant_, std::string(protocol::kPeerTopic), &err) ||
       !peerReader_.create(participant_, peerTopic_, protocol::kPeerQos, &err) ||
       !peerWriter_.create(participant_, peerTopic_, protocol::kPeerQos, PayloadKind::Handoff,
                           &err) ||
       !statusReader_.create(participant_, statusTopic_, protocol::kStatusQos, &err) ||
       !waitset_.attach(peerReader_, &err)))
    return fail();
  stop_ = false;
  reader_ = std::thread([this] { readLoop(); });
  publisher_ = std::thread([this] { publishLoop(); });
  spdlog::info("dds: domain {} ready ({}, {}, {}, {}, {})", config_.domain, protocol::kCommandTopic,
               protocol::kReplyTopic, protocol::kWorldInfoTopic, protocol::kStatusTopic,
               protocol::kEventsTopic);
  return Status::Ok();
}

void DdsEndpoint::stop() {
  if (stop_.exchange(true)) return;
  waitset_.wake();
  if (reader_.joinable()) reader_.join();
  if (publisher_.joinable()) publisher_.join();
}

void DdsEndpoint::readLoop() {
  const protocol::Limits& limits = core_->config().limits;
  sweptAt_ = ClientKeys::Clock::now();
  auto sweepIfDue = [&](ClientKeys::Clock::time_point now) {
    if (now - sweptAt_ >= config_.sweepPeriod ||
        (keys_.sweepWanted() && now - sweptAt_ >= config_.sweepPeriod / 10))
      sweep();
  };
  uint64_t taken = 0;
  // Liveliness: asserted here, where commands come in, so a daemon counts as alive exactly
  // while it can take them (a long tick does not make it look gone).
  const auto livelinessEvery = config_.liveliness / 4;
  auto assertedAt = ClientKeys::Clock::now();
  const dds_duration_t waitFor =
      livelinessEvery.count() > 0
          ? DDS_MSECS(std::min<int64_t>(200, std::max<int64_t>(10, livelinessEvery.count())))
          : DDS_MSECS(200);
  while (!stop_) {
    waitset_.wait(waitFor);
    if (stop_) break;
    if (livelinessEvery.count() > 0 && ClientKeys::Clock::now() - assertedAt >= livelinessEvery) {
      statusWriter_.assertLiveliness();
      assertedAt = ClientKeys::Clock::now();
    }
    // Every command costs O(1) before it is dropped or queued: whatever one participant sends,
    // the others' commands keep flowing (docs/SERVER.md "Budgets").
    cmdReader_.take([&](const phys_wire_Envelope& env, dds_instance_handle_t writer) {
      counters_.commandsTaken.fetch_add(1);
      const auto now = ClientKeys::Clock::now();
      if ((++taken & 1023) == 0) sweepIfDue(now);  // a take that does not end sweeps too
      // Another daemon's command (a domain of daemons): its owner answers it. Read in O(1);
      // one whose address does not even verify is answered here (refused by the codec).
      if (auto a = protocol::peekAddress(protocol::envelopeBytes(env)); a && !core_->takes(*a)) {
        counters_.forOthers.fetch_add(1);
        return;
      }
      // A Hello may carry a proof of its key, which decides who holds the key: read before
      // the claim (a Hello is small; larger payloads are not looked at here).
      std::optional<protocol::Decoded<wire::Command>> early;
      ClientKeys::Proof proof;
      if (env.bytes._length <= limits.maxNameBytes + kHelloBytesBesideName &&
          protocol::checkEnvelope(env, PayloadKind::Command, limits).ok()) {
        auto bytes = protocol::envelopeBytes(env);
        early = protocol::decodeCommand(std::vector<uint8_t>(bytes.begin(), bytes.end()), limits);
        const wire::Hello* hello = early->ok() ? (*early)->request_as_Hello() : nullptr;
        if (hello && hello->public_key() && hello->proof() && (*early)->client_id() == env.key)
          proof = [&, hello](const Guid& participant) {
            counters_.proofsChecked.fetch_add(1);
            const bool ok = protocol::verifyBinding(
                {hello->public_key()->data(), hello->public_key()->size()}, participant,
                env.key, {hello->proof()->data(), hello->proof()->size()});
            if (!ok) counters_.proofsFailed.fetch_add(1);
            return ok;
          };
      }
      const ClientKeys::Result who = vouch(env.key, writer, now, proof ? &proof : nullptr);
      if (who.verdict == ClientKeys::Verdict::HeldByOther) {
        // Not answered: every reply on this key goes to the participant that holds it, which
        // would take an answer to someone else's command for one of its own.
        const uint64_t n = counters_.spoofed.fetch_add(1) + 1;
        if (who.report)  // its first, then one in reportEvery: a flood does not flood the log
          spdlog::warn("phys/cmd: participant {} wrote under client id {:#x}, which another "
                       "participant holds; dropped unanswered ({} from it, {} in all)",
                       participantName(who.participant), env.key, who.refusals, n);
        return;
      }
      if (who.verdict == ClientKeys::Verdict::Ok) gate_.bind(writer, env.key);
      Incoming in;
      in.envelopeKey = env.key;
      in.envelopeSeq = env.seq;
      in.sender = who.participant;
      in.proven = who.proven;
      in.bytes = env.bytes._length;
      if (who.verdict != ClientKeys::Verdict::Ok) {
        // Past the participant's ids (or a full table): dropped, but answered once in a while
        // (who.report) so that a client past the limit learns why. Such a key is nobody's, so
        // the answer reaches no one else's requests.
        counters_.pastKeyLimit.fetch_add(1);
        if (!who.report) return;
        const std::string why =
            who.verdict == ClientKeys::Verdict::TooManyKeys
                ? "this participant uses more than " +
                      std::to_string(keys_.limits().keysPerParticipant) +
                      " client ids (server.max_keys_per_participant); commands under its "
                      "other ids are dropped (" + std::to_string(who.refusals) + " so far)"
                : std::string("the server holds as many client ids as it may; retry later");
        spdlog::warn("phys/cmd: participant {}: {} (latest id {:#x})",
                     participantName(who.participant), why, env.key);
        in.command.status = Status::Error(Code::ResourceExhausted, why);
        core_->submit(std::move(in));
        return;
      }
      Status s = protocol::checkEnvelope(env, PayloadKind::Command, limits);
      if (config_.identities) {
        in.principal = who.principal;
        if (s.ok() && who.principal == 0) {
          // Answered (the key is this participant's), but with no identity nobody's world
          // access can be decided: a client that writes outside its identity partition.
          const uint64_t n = counters_.unidentified.fetch_add(1) + 1;
          if ((n & (n - 1)) == 0)
            spdlog::warn("phys/cmd from client {:#x}: written outside an identity partition "
                         "on a secure domain; refused ({} so far)",
                         env.key, n);
          s = Status::Error(
              Code::PermissionDenied,
              "this daemon runs DDS Security and attributes commands to identities: write them "
              "in partition " +
                  std::string(protocol::kIdentityPartitionPrefix) +
                  "<your identity> (the SDK and physctl do when given their identity)");
        }
      }
      if (s.ok() && early) {
        in.command = std::move(*early);
      } else if (s.ok()) {
        auto bytes = protocol::envelopeBytes(env);
        in.command =
            protocol::decodeCommand(std::vector<uint8_t>(bytes.begin(), bytes.end()), limits);
      } else {
        in.command.status = s;
      }
      if (!in.command.ok() && in.command.status.code != Code::PermissionDenied) {
        // Still answered (to the envelope's key and seq) by the core, in arrival order, within
        // the sender's budgets; logged at the 1st, 2nd, 4th, ... time.
        const uint64_t n = counters_.undecodable.fetch_add(1) + 1;
        if ((n & (n - 1)) == 0)
          spdlog::warn("phys/cmd from client {:#x} (participant {}) seq {}: {} ({}; {} so far)",
                       env.key, participantName(who.participant), env.seq,
                       protocol::toString(in.command.status.code), in.command.status.message, n);
      }
      core_->submit(std::move(in));
    });
    sweepIfDue(ClientKeys::Clock::now());
    if (core_->config().cluster) {
      takeHandoffs();
      takePeerStatuses();
    }
  }
}

void DdsEndpoint::takePeerStatuses() {
  const protocol::Limits& limits = core_->config().limits;
  statusReader_.take(
      [&](const phys_wire_Envelope& env, dds_instance_handle_t) {
        if (env.key == core_->config().serverId) return;  // its own
        if (!protocol::checkEnvelope(env, PayloadKind::ServerStatus, limits).ok()) return;
        auto st = protocol::decodeServerStatus(protocol::envelopeBytes(env), limits);
        if (!st.ok() || !st->cluster()) return;
        const float period = st->status_period_s();
        core_->notePeerStatus(st->daemon() ? st->daemon() : env.key,
                              std::isfinite(period) && period > 0 ? double(period) : 1.0);
      },
      // Its liveliness lapsed (killed, frozen) or it stopped: named no more, at once.
      [&](uint64_t daemon) { core_->notePeerGone(daemon); });
}

void DdsEndpoint::takeHandoffs() {
  const protocol::Limits& limits = core_->config().limits;
  const uint64_t me = core_->config().serverId;
  const auto now = std::chrono::steady_clock::now();
  std::erase_if(assemblies_, [&](const auto& a) {
    return now - a.second.started > ServerCore::kMoveTimeout;
  });
  peerReader_.take([&](const phys_wire_Envelope& env) {
    if (env.key != me) return;  // another daemon's
    counters_.handoffsTaken.fetch_add(1);
    auto drop = [&] { counters_.handoffsDropped.fetch_add(1); };
    if (!protocol::checkEnvelope(env, PayloadKind::Handoff, limits).ok()) return drop();
    auto h = protocol::decodeHandoff(protocol::envelopeBytes(env), limits);
    if (!h.ok() || h->to() != me) return drop();
    ServerCore::HandoffIn in;
    in.kind = h->kind();
    in.world = h->world();
    in.from = h->from();
    in.move = h->move();
    in.epoch = h->epoch();
    in.subscribers = h->subscribers();
    in.ephemeral = h->ephemeral();
    in.status = Status{h->status(), h->message() ? h->message()->str() : std::string()};
    if (in.kind != wire::HandoffKind::Chunk) return core_->submitHandoff(std::move(in));
    const uint32_t count = h->chunk_count();
    const size_t size = h->bytes() ? h->bytes()->size() : 0;
    if (count > ServerCore::kMaxHandoffChunks || size > ServerCore::kHandoffChunkBytes)
      return drop();
    const auto key = std::make_pair(in.from, in.move);
    auto it = assemblies_.find(key);
    if (it == assemblies_.end()) {
      if (assemblies_.size() >= kMaxAssemblies) {
        auto oldest = std::min_element(assemblies_.begin(), assemblies_.end(),
                                       [](const auto& a, const auto& b) {
                                         return a.second.started < b.second.started;
                                       });
        assemblies_.erase(oldest);
      }
      Assembly a;
      a.head = std::move(in);
      a.parts.resize(count);
      a.started = now;
      it = assemblies_.emplace(key, std::move(a)).first;
    }
    Assembly& a = it->second;
    std::vector<uint8_t>& part = a.parts.at(h->chunk_index());
    if (a.parts.size() != count || a.head.world != h->world() || !part.empty() || size == 0)
      return drop();
    part.assign(h->bytes()->begin(), h->bytes()->end());
    if (++a.got < count) return;
    ServerCore::HandoffIn whole = std::move(a.head);
    for (const std::vector<uint8_t>& p : a.parts)
      whole.checkpoint.insert(whole.checkpoint.end(), p.begin(), p.end());
    assemblies_.erase(it);
    core_->submitHandoff(std::move(whole));
  });
}

ClientKeys::Result DdsEndpoint::vouch(uint64_t key, dds_instance_handle_t writer,
                                      ClientKeys::Clock::time_point now,
                                      const ClientKeys::Proof* proof) {
  if (!keys_.knows(writer)) {
    // A new writer: what discovery says of it, once. Cyclone delivers data only from matched
    // writers; should the discovery data be gone already, the writer's own handle stands for
    // its participant (and it has no identity).
    Guid participant{};
    uint64_t principal = 0;
    std::vector<std::string> partitions;
    if (cmdReader_.publicationOf(writer, &participant, &partitions)) {
      // One identity partition and no other: a writer in two would have two identities.
      if (partitions.size() == 1)
        if (auto identity = protocol::identityOfPartition(partitions[0]))
          principal = protocol::identityKey(*identity);
    } else {
      std::memcpy(participant.data(), &writer, sizeof writer);
    }
    keys_.addWriter(writer, participant, principal);
  }
  return keys_.claim(key, writer, now, proof);
}

bool DdsEndpoint::admitSample(const dds_sample_info_t* info, void* gate) {
  return static_cast<InstanceGate*>(gate)->admit(info->publication_handle, info->instance_handle);
}

void DdsEndpoint::sweep() {
  sweptAt_ = ClientKeys::Clock::now();
  if (!cmdReader_.matchedPublications(&live_)) return;  // next time
  for (const InstanceGate::Refused& r : gate_.sweep(live_, sweptAt_)) {
    // Named by its participant: known when some of its commands came through, else asked.
    std::string name;
    if (const uint64_t p = keys_.participantOf(r.writer)) {
      name = participantName(p);
    } else {
      Guid g{};
      name = cmdReader_.participantOf(r.writer, &g) ? toString(g) : "(gone)";
    }
    if (r.instances)
      spdlog::warn("phys/cmd: participant {} writes under more client ids than its {} "
                   "(server.max_keys_per_participant); {} of its commands under further ids "
                   "dropped before they reached physd",
                   name, keys_.limits().keysPerParticipant, r.instances);
    if (r.rate)
      spdlog::warn("phys/cmd: participant {} writes more than {:.0f} commands a second (twice "
                   "server.max_participant_commands_per_s); {} of them dropped before they "
                   "reached physd",
                   name, gate_.limits().rate, r.rate);
  }
  for (ClientKeys::Departed& d : keys_.sweep(live_)) {
    counters_.participantsLeft.fetch_add(1);
    spdlog::debug("phys/cmd: participant {} left; its {} client id(s) are free", toString(d.guid),
                  d.keys.size());
    core_->clientsLeft(d.participant, std::move(d.keys));
  }
}

std::string DdsEndpoint::participantName(uint64_t participant) const {
  const Guid* g = keys_.guidOf(participant);
  return g ? toString(*g) : "#" + std::to_string(participant);
}

void DdsEndpoint::publishLoop() {
  auto lastSubscribers = std::chrono::steady_clock::now();
  for (;;) {
    // A world moved here waits for its subscribers to match its new writer: they are looked
    // for every 10 ms meanwhile (movedInUntil_), not every 250.
    const bool movedIn = std::chrono::steady_clock::now() < movedInUntil_;
    PublishQueue::Item item =
        core_->out().pop(std::chrono::milliseconds(movedIn ? 10 : 100));
    if (item.reliable) publish(*item.reliable);
    if (item.frame) publish(*item.frame);
    auto now = std::chrono::steady_clock::now();
    if (now - lastSubscribers > std::chrono::milliseconds(movedIn ? 10 : 250)) {
      // Readers ever matched too: a reader that came while another went (the same count)
      // is a new subscriber, owed a keyframe.
      for (auto& [key, st] : state_) {
        uint64_t total = 0;
        const uint32_t n = st->writer.matched(&total);
        core_->setSubscribers(uint32_t(key >> 32), uint32_t(key), n, total);
      }
      lastSubscribers = now;
    }
    if (stop_ && !item.reliable && !item.frame) break;
  }
}

void DdsEndpoint::publish(ReliableMessage& m) {
  dds_return_t rc = DDS_RETCODE_OK;
  switch (m.type) {
    case ReliableMessage::Type::Reply:
      // Before the write: the client's next command may be here before write() returns.
      gate_.answered(m.key);  // the writer's next command passes the gate free
      rc = replyWriter_.write(m.key, m.chunks.at(0), m.seq);
      if (rc == DDS_RETCODE_OK) counters_.repliesWritten.fetch_add(1);
      break;
    case ReliableMessage::Type::Status:
      rc = statusWriter_.write(m.key, m.chunks.at(0));
      break;
    case ReliableMessage::Type::Event:
      rc = eventsWriter_.write(m.key, m.chunks.at(0));
      break;
    case ReliableMessage::Type::WorldInfo: {
      if (removed_.count(m.world)) break;
      // The state writer exists from the world's first info on, so that its subscribers are
      // counted before any frame is encoded (a world without subscribers encodes none).
      stateTopic(m.world);
      for (uint32_t i = 0; i < m.chunks.size() && rc == DDS_RETCODE_OK; ++i)
        rc = infoWriter_.write(protocol::worldInfoKey(m.world, i), m.chunks[i]);
      // Chunks the world no longer has.
      uint32_t& last = infoChunks_[m.world];
      for (uint32_t i = uint32_t(m.chunks.size()); i < last; ++i)
        infoWriter_.dispose(protocol::worldInfoKey(m.world, i));
      last = uint32_t(m.chunks.size());
      break;
    }
    case ReliableMessage::Type::InterestAdded:
      stateTopic(m.world, uint32_t(m.key));  // its readers are counted before any frame
      break;
    case ReliableMessage::Type::InterestRemoved:
      state_.erase(streamKey(m.world, uint32_t(m.key)));
      break;
    case ReliableMessage::Type::Handoff:
      rc = peerWriter_.write(m.key, m.chunks.at(0));
      break;
    case ReliableMessage::Type::WorldAdded:
      removed_.erase(m.world);  // moved here (perhaps back): its info and frames go out
      movedInUntil_ = std::chrono::steady_clock::now() + std::chrono::seconds(2);
      break;
    case ReliableMessage::Type::WorldRemoved: {
      auto it = infoChunks_.find(m.world);
      if (it != infoChunks_.end()) {
        for (uint32_t i = 0; i < it->second; ++i)
          infoWriter_.dispose(protocol::worldInfoKey(m.world, i));
        infoChunks_.erase(it);
      }
      state_.erase(state_.lower_bound(streamKey(m.world, 0)),
                   state_.lower_bound(streamKey(m.world + 1, 0)));
      removed_.insert(m.world);
      core_->setSubscribers(m.world, 0);
      spdlog::info("world {} destroyed", m.world);
      break;
    }
  }
  if (rc != DDS_RETCODE_OK) {
    counters_.writeErrors.fetch_add(1);
    spdlog::error("dds write failed ({}): {}", int(m.type), dds::error(rc));
  }
}

DdsEndpoint::StateTopic* DdsEndpoint::stateTopic(uint32_t world, uint32_t interest) {
  if (removed_.count(world)) return nullptr;  // queued before its world was destroyed
  const uint64_t key = streamKey(world, interest);
  auto it = state_.find(key);
  if (it == state_.end()) {
    auto st = std::make_unique<StateTopic>();
    std::string err;
    if (!st->topic.create(participant_, protocol::stateTopic(world, interest), &err) ||
        !st->writer.create(participant_, st->topic, protocol::kStateQos, PayloadKind::StateFrame,
                           &err)) {
      counters_.writeErrors.fetch_add(1);
      spdlog::error("state topic for world {}: {}", world, err);
      return nullptr;
    }
    it = state_.emplace(key, std::move(st)).first;
  }
  return it->second.get();
}

void DdsEndpoint::publish(StateFrameSet& f) {
  // An interest's writer is made when it is added; a frame queued after it was removed goes.
  if (f.interest != 0 && !state_.count(streamKey(f.world, f.interest))) return;
  StateTopic* st = stateTopic(f.world, f.interest);
  if (!st) return;
  const bool coordinated = core_->coordinated();
  for (uint32_t i = 0; i < f.chunks.size(); ++i) {
    // A frame that waited in the queue while this daemon's hold lapsed (it was stopped, say)
    // is not written, nor the rest of one whose writing the stop interrupted: its world may
    // be another daemon's now (docs/SERVER.md "Standby and takeover").
    if (coordinated && !core_->holding()) {
      counters_.framesFenced.fetch_add(1);
      return;
    }
    dds_return_t rc = st->writer.write(i, f.chunks[i], f.tick);
    if (rc == DDS_RETCODE_OK) {
      counters_.framesWritten.fetch_add(1);
    } else {
      counters_.writeErrors.fetch_add(1);
      spdlog::error("state write world {} chunk {}: {}", f.world, i, dds::error(rc));
    }
  }
}

}  // namespace phys::server
