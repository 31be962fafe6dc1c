// ServerCore: registry, time control, frames, status (commands.cpp applies commands).
#include "phys/server/core.h"

#include <malloc.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <unistd.h>
#include <string>

#include "phys/protocol/convert.h"
#include "phys/protocol/requests.h"
#include "phys/scene/scene.h"
#include "internal.h"

namespace phys::server {

using protocol::ReplyHeader;

ServerCore::ServerCore(CoreConfig config)
    : config_(std::move(config)),
      started_(std::chrono::steady_clock::now()),
      out_(config_.frameRingCapacity) {
  if (config_.cluster) nextWorldId_ = protocol::firstWorldIdOf(config_.serverId);
  // With a coordinator, world directories are named in etcd for a standby to read: absolute.
  if (!config_.coordinator.empty() && !config_.dataDir.empty()) {
    std::error_code ec;
    const std::filesystem::path abs = std::filesystem::absolute(config_.dataDir, ec);
    if (!ec) config_.dataDir = abs.lexically_normal().string();
  }
  // Moves are told apart by (daemon, number): numbered from the clock, a restarted daemon's
  // never meet an earlier start's at a target.
  nextMove_ = uint64_t(std::chrono::system_clock::now().time_since_epoch().count());
}

bool ServerCore::takes(const protocol::CommandAddress& a) const {
  if (a.daemon != 0) return a.daemon == config_.serverId;
  if (!config_.cluster) return true;
  if (a.world == 0) return a.hello;
  return protocol::daemonOfWorld(a.world) == config_.serverId;
}

void ServerCore::reserveWorldId(uint32_t id) {
  if (config_.cluster && protocol::daemonOfWorld(id) != config_.serverId) return;
  nextWorldId_ = std::max(nextWorldId_, id + 1);
}

ServerCore::~ServerCore() {
  if (dataLock_ >= 0) ::close(dataLock_);
  // A loader still building a scene finishes first (its world is then dropped).
  for (auto& [thread, task] : loaders_)
    if (thread.joinable()) thread.join();
}

void ServerCore::reapLoaders() {
  // Loaders that finished are joined, and what a cancelled one built is freed.
  std::erase_if(loaders_, [](auto& l) {
    if (!l.second->done.load()) return false;
    l.first.join();
    return true;
  });
}

void ServerCore::startLoad(std::shared_ptr<LoadTask> task) {
  loaders_.emplace_back(std::thread([this, task] {
    try {
      task->result = prepareScene(task->request);
    } catch (const std::bad_alloc&) {
      task->result = SceneLoad{};
      task->result.status = Status::Error(Code::ResourceExhausted, "load_scene: out of memory");
    } catch (const std::exception& e) {
      task->result = SceneLoad{};
      task->result.status = Status::Error(Code::Internal, std::string("load_scene: ") + e.what());
    }
    task->done.store(true);
  }), task);
}

void ServerCore::finishLoad(ServerWorld& w) {
  if (!w.load || !w.load->task->done.load()) return;
  ServerWorld::LoadJob job = std::move(*w.load);
  w.load.reset();
  ReplyHeader h = job.header;
  std::vector<uint64_t> bodies, joints;
  Status st = std::move(job.task->result.status);
  // What the world holds may have changed meanwhile only through this load (commands
  // waited), but other worlds may have grown: the daemon-wide count is checked again.
  if (st.ok())
    st = checkGrowth(nullptr, uint64_t(job.task->result.bodyIds.size()), 0, "load_scene",
                     uint64_t(w.world->bodyCount()));
  if (st.ok()) {
    commitScene(w, std::move(job.task->result), &bodies, &joints);
    st = durableReplaced(w, "load_scene");  // on disk before the reply
    if (!st.ok()) bodies.clear(), joints.clear();
  }
  job.task->result = SceneLoad{};  // the unused world goes now, not with the thread
  h.tick = w.tick;
  if (!st.ok()) ++counters_.errors;
  h.status = st;
  release(job.envelopeKey, job.sender, job.charge);  // before the reply (applyNow)
  pushReply(job.envelopeKey, job.envelopeSeq,
            st.ok() ? protocol::encodeIdsReply(h, bodies, joints) : protocol::encodeReply(h));
}

Status ServerCore::init() {
  std::string path = config_.presetsFile.empty() ? phys::defaultPresetsPath() : config_.presetsFile;
  if (!path.empty()) {
    phys::Status s = phys::loadPresetsFile(path, &presets_, &defaultPreset_);
    if (!s.ok()) return protocol::fromPhys(s);
  }
  if (presets_.empty()) {
    presets_["default"] = phys::Preset{"default", "the engine's defaults", phys::SolverSettings{}};
    defaultPreset_ = "default";
  }
  return Status::Ok();
}

void ServerCore::applyPolicy(phys::WorldDef* def) const {
  def->maxContactPairs = config_.maxContactPairs;
  def->pairOverflow = phys::WorldDef::PairOverflow::Refuse;
}
void ServerCore::applyPolicy(phys::World& w) const {
  w.setContactBudget(config_.maxContactPairs, phys::WorldDef::PairOverflow::Refuse);
}

std::unique_ptr<ServerWorld> ServerCore::makeWorld(const std::string& name,
                                                   const std::string& preset,
                                                   const phys::WorldDef& def) {
  auto w = std::make_unique<ServerWorld>();
  w->name = name;
  w->preset = preset;
  phys::WorldDef d = def;
  d.threads = config_.threads;
  d.gpuAllowCpuDevice = config_.gpuAllowCpuDevice;
  applyPolicy(&d);
  w->world = std::make_unique<phys::World>(d);
  w->rateHz = config_.defaultRateHz;
  w->nextInterest = interestBase_ + 1;
  w->epoch = epochBase_ + 1;
  return w;
}

Status ServerCore::createWorld(const std::string& name, const std::string& preset,
                               const std::string& scene, uint32_t* id, const std::string& backend,
                               bool ephemeral) {
  const CoreCounters saved = counters_;  // start-up worlds are not client commands
  protocol::CommandBuilder b;
  protocol::CreateWorldArgs args;
  args.name = name;
  args.preset = preset;
  args.backend = backend;
  args.ephemeral = ephemeral;
  startupCreate_ = true;  // no owner: every client may use a start-up world
  Bytes reply =
      applyBytes(b.createWorld(args).finish({config_.serverId, 0, 0}), config_.serverId, 0);
  startupCreate_ = false;
  auto d = protocol::decodeReply(std::move(reply), config_.limits);
  if (!d.ok()) return Status::Error(Code::Internal, "create world reply: " + d.status.message);
  if (d->status() != Code::Ok) {
    counters_.commands = saved.commands;
    counters_.errors = saved.errors;
    return Status::Error(d->status(), d->message() ? d->message()->str() : "");
  }
  uint32_t wid = d->world();
  if (!scene.empty()) {
    // Not through a LoadScene reply: a start-up world may hold more bodies than one reply
    // can list (pile_1m).
    std::vector<uint64_t> bodies, joints;
    Status s = loadScene(*worlds_.at(wid), nullptr, scene, /*forReply=*/false, &bodies, &joints);
    if (!s.ok()) {
      if (worlds_.at(wid)->store) worlds_.at(wid)->store->remove();
      worlds_.erase(wid);
      counters_.commands = saved.commands;
      counters_.errors = saved.errors;
      return s;
    }
  }
  counters_.commands = saved.commands;
  counters_.errors = saved.errors;
  if (id) *id = wid;
  return Status::Ok();
}

Status ServerCore::setRun(uint32_t id, RunMode mode, double rateHz) {
  ServerWorld* w = world(id);
  if (!w) return Status::Error(Code::NotFound, "no world " + std::to_string(id));
  w->mode = mode;
  if (mode == RunMode::RealTime) w->rateHz = rateHz > 0 ? rateHz : config_.defaultRateHz;
  w->accumulator = 0;
  if (w->store) {
    Status s = journalMark(*w);
    return s.ok() ? w->store->sync() : s;
  }
  return Status::Ok();
}

const ServerWorld* ServerCore::world(uint32_t id) const {
  auto it = worlds_.find(id);
  return it == worlds_.end() ? nullptr : it->second.get();
}
ServerWorld* ServerCore::world(uint32_t id) {
  auto it = worlds_.find(id);
  return it == worlds_.end() ? nullptr : it->second.get();
}
std::vector<uint32_t> ServerCore::worldIds() const {
  std::vector<uint32_t> ids;
  for (auto& [id, w] : worlds_) ids.push_back(id);
  return ids;
}

void ServerCore::setSubscribers(uint32_t world, uint32_t n) {
  setSubscribers(world, 0, n);
}
void ServerCore::setSubscribers(uint32_t world, uint32_t interest, uint32_t n) {
  uint64_t matched = 0;
  {
    std::lock_guard<std::mutex> lock(subscribersMutex_);
    const Subscribers& s = subscribers_[streamKey(world, interest)];
    matched = s.matched + (n > s.now ? n - s.now : 0);  // a count that grew: new ones
  }
  setSubscribers(world, interest, n, matched);
}
void ServerCore::setSubscribers(uint32_t world, uint32_t interest, uint32_t n,
                                uint64_t matched) {
  {
    std::lock_guard<std::mutex> lock(subscribersMutex_);
    Subscribers& s = subscribers_[streamKey(world, interest)];
    if (s.now == n && s.matched == matched) return;  // the usual case: every 250 ms
    s.now = n;
    s.matched = matched;
    subscribersChanged_.push_back(world);
  }
  // The tick thread looks at once (a paused world's new subscriber waits for nothing).
  {
    std::lock_guard<std::mutex> lock(inboxMutex_);
    anySubscribersChanged_.store(true);
  }
  inboxCv_.notify_one();
}

// ---------------------------------------------------------------------------------------------
// Inbox

void ServerCore::submit(Incoming in) {
  std::string refused;
  uint32_t retryMs = 0;  // when the same command may come again (Reply.retry_after_ms)
  bool answer = true;
  {
    std::lock_guard<std::mutex> lock(inboxMutex_);
    const auto now = std::chrono::steady_clock::now();
    // O(1) here (hash maps; pendingPerClient_ is a map of the clients with commands waiting):
    // this runs on the reader thread, for every command.
    SenderBudget* sender = nullptr;
    if (in.sender) {
      auto [it, added] = senders_.try_emplace(in.sender);
      sender = &it->second;
      if (added) {
        sender->commands = {std::max(1.0, config_.maxParticipantBurst), now};
        sender->refusals = {std::max(1.0, config_.maxParticipantRefusalsPerS), now};
      }
    }
    Pending& p = pendingPerClient_[in.envelopeKey];
    RateBucket& bucket = bucketOf(in.envelopeKey, now);
    const uint64_t bytes = queueCharge(in);
    // The rates count only the commands sent while some of the sender's are still waiting
    // to be answered: a client with one request in flight (a synchronous loop, however fast
    // its round trip) cannot flood, since the queue is first come, first served and it is
    // never in it twice; what it may cost is one command's turn at a time. A client that
    // sends ahead of its replies is counted (docs/SERVER.md "Budgets").
    const bool clientIdle = p.commands == 0;
    const bool senderIdle = !sender || sender->pending.commands == 0;
    // How long until a bucket has its next token, in whole ms (at least 1).
    auto wait = [&](const RateBucket& b, double rate) {
      return uint32_t(std::clamp(std::ceil((1 - b.tokens) / rate * 1000), 1.0, 60000.0));
    };
    if (sender && !senderIdle &&
        !sender->commands.ready(config_.maxParticipantCommandsPerS,
                                config_.maxParticipantBurst, now)) {
      retryMs = wait(sender->commands, config_.maxParticipantCommandsPerS);
      refused = "this participant (client " + std::to_string(in.envelopeKey) +
                " and any other ids it writes under) sends more than " +
                std::to_string(int64_t(config_.maxParticipantCommandsPerS)) +
                " commands a second (server.max_participant_commands_per_s, bursts of " +
                std::to_string(int64_t(config_.maxParticipantBurst)) +
                ": server.max_participant_burst) while it has commands waiting; slow down";
    } else if (!clientIdle &&
               !bucket.ready(config_.maxClientCommandsPerS, config_.maxClientBurst, now)) {
      retryMs = wait(bucket, config_.maxClientCommandsPerS);
      refused = "client " + std::to_string(in.envelopeKey) + " sends more than " +
                std::to_string(int64_t(config_.maxClientCommandsPerS)) +
                " commands a second (server.max_client_commands_per_s, bursts of " +
                std::to_string(int64_t(config_.maxClientBurst)) +
                ": server.max_client_burst) while it has commands waiting; slow down";
    } else if (p.commands >= config_.maxQueuedPerClient) {
      retryMs = kQueueRetryMs;
      refused = "client " + std::to_string(in.envelopeKey) + " has " +
                std::to_string(p.commands) +
                " commands waiting to be applied, the limit is " +
                std::to_string(config_.maxQueuedPerClient) +
                " (server.max_queued_per_client); wait for replies";
    } else if (p.bytes + bytes > config_.maxQueuedBytesPerClient) {
      retryMs = kQueueRetryMs;
      refused = "client " + std::to_string(in.envelopeKey) + " has " + std::to_string(p.bytes) +
                " bytes of commands waiting, the limit is " +
                std::to_string(config_.maxQueuedBytesPerClient) +
                " (server.max_queued_mb_per_client); wait for replies";
    } else if (sender &&
               sender->pending.bytes + bytes > config_.maxQueuedBytesPerParticipant) {
      retryMs = kQueueRetryMs;
      refused = "this participant (client " + std::to_string(in.envelopeKey) +
                " and any other ids it writes under) has " +
                std::to_string(sender->pending.bytes) +
                " bytes of commands waiting, the limit is " +
                std::to_string(config_.maxQueuedBytesPerParticipant) +
                " (server.max_queued_mb_per_participant); wait for replies";
    } else if (pendingBytes_ + bytes > config_.maxQueuedBytes) {
      retryMs = kServerQueueRetryMs;
      refused = "the server's command queue holds " + std::to_string(pendingBytes_) +
                " bytes, the limit is " + std::to_string(config_.maxQueuedBytes) +
                " (server.max_queued_mb); retry later";
    }
    if (refused.empty()) {
      if (config_.maxClientCommandsPerS > 0 && !clientIdle) bucket.tokens -= 1;
      ++p.commands;
      p.bytes += bytes;
      if (sender) {
        if (config_.maxParticipantCommandsPerS > 0 && !senderIdle) sender->commands.tokens -= 1;
        ++sender->pending.commands;
        sender->pending.bytes += bytes;
      }
      pendingBytes_ += bytes;
      inbox_.push_back(std::move(in));
    } else {
      if (p.commands == 0) pendingPerClient_.erase(in.envelopeKey);
      // One participant's refusals are answered up to a rate; the rest go unanswered, so a
      // flood of refused commands is not a flood of replies for the publisher.
      if (sender) {
        answer = config_.maxParticipantRefusalsPerS <= 0 ||
                 sender->refusals.ready(config_.maxParticipantRefusalsPerS,
                                        config_.maxParticipantRefusalsPerS, now);
        if (answer && config_.maxParticipantRefusalsPerS > 0) sender->refusals.tokens -= 1;
      }
    }
  }
  if (!refused.empty()) {
    refusedAtSubmit_.fetch_add(1);
    if (!answer) {
      refusalsDropped_.fetch_add(1);
      return;
    }
    // Answered at once (the tick thread may be busy), to the envelope's correlation.
    ReplyHeader h;
    h.clientId = in.envelopeKey;
    h.seq = in.envelopeSeq;
    if (in.command.ok()) {
      h.seq = in.command->seq();
      h.world = in.command->world();
    }
    h.status = Status::Error(Code::ResourceExhausted, refused);
    h.retryAfterMs = retryMs;
    pushReplyNow(in.envelopeKey, in.envelopeSeq, protocol::encodeReply(h));
    return;
  }
  inboxCv_.notify_one();
}

bool ServerCore::RateBucket::ready(double rate, double burst,
                                   std::chrono::steady_clock::time_point now) {
  if (rate <= 0) return true;
  tokens = std::min(std::max(1.0, burst),
                    tokens + std::chrono::duration<double>(now - last).count() * rate);
  last = now;
  return tokens >= 1;
}

ServerCore::RateBucket& ServerCore::bucketOf(uint64_t client,
                                             std::chrono::steady_clock::time_point now) {
  const double burst = std::max(1.0, config_.maxClientBurst);
  auto it = rates_.find(client);
  if (it != rates_.end()) return it->second;
  if (rates_.size() >= ratesCombAt_) {
    // Forget the clients whose buckets are full again (idle): as cheap as a bucket each, over
    // the size reached since the last comb.
    std::erase_if(rates_, [&](const auto& e) {
      return e.second.tokens + std::chrono::duration<double>(now - e.second.last).count() *
                                   config_.maxClientCommandsPerS >=
             burst;
    });
    ratesCombAt_ = std::max<size_t>(65536, 2 * rates_.size());
  }
  return rates_.emplace(client, RateBucket{burst, now}).first->second;
}

void ServerCore::clientsLeft(uint64_t sender, std::vector<uint64_t> keys) {
  {
    std::lock_guard<std::mutex> lock(inboxMutex_);
    // Their budgets: what they have waiting is released into nothing as it is answered.
    if (sender) senders_.erase(sender);
    for (uint64_t k : keys) rates_.erase(k);
    left_.push_back({sender, std::move(keys)});
  }
  inboxCv_.notify_one();
}

void ServerCore::applyLeft(const Left& l) {
  for (auto& [id, w] : worlds_) {
    for (auto it = w->interests.begin(); it != w->interests.end();) {
      const ServerWorld::Interest& in = it->second;
      const bool theirs =
          l.sender ? in.sender == l.sender
                   : in.sender == 0 &&
                         std::find(l.keys.begin(), l.keys.end(), in.client) != l.keys.end();
      if (!theirs) {
        ++it;
        continue;
      }
      ReliableMessage m;  // its topic goes, as an Unsubscribe's
      m.type = ReliableMessage::Type::InterestRemoved;
      m.world = w->id;
      m.key = it->first;
      out_.pushReliable(std::move(m));
      it = w->interests.erase(it);
    }
  }
}

void ServerCore::release(const Incoming& in) {
  release(in.envelopeKey, in.sender, queueCharge(in));
}

void ServerCore::release(uint64_t envelopeKey, uint64_t sender, uint64_t bytes) {
  std::lock_guard<std::mutex> lock(inboxMutex_);
  auto it = pendingPerClient_.find(envelopeKey);
  if (it != pendingPerClient_.end()) {
    it->second.bytes -= std::min(it->second.bytes, bytes);
    if (--it->second.commands == 0) pendingPerClient_.erase(it);
  }
  if (sender) {
    auto s = senders_.find(sender);  // gone when the participant left
    if (s != senders_.end()) {
      s->second.pending.bytes -= std::min(s->second.pending.bytes, bytes);
      if (s->second.pending.commands > 0) --s->second.pending.commands;
    }
  }
  pendingBytes_ -= std::min(pendingBytes_, bytes);
}

void ServerCore::pushReply(uint64_t key, uint64_t seq, Bytes reply, uint32_t durableWorld,
                           const ReplyHeader* failed) {
  if (!durable()) return pushReplyNow(key, seq, std::move(reply));
  HeldReply h;
  h.key = key;
  h.seq = seq;
  h.reply = std::move(reply);
  h.durableWorld = durableWorld;
  if (failed) {
    h.hasFailed = true;
    h.failed = *failed;
  }
  held_.push_back(std::move(h));
}

void ServerCore::pushReplyNow(uint64_t key, uint64_t seq, Bytes reply) {
  ReliableMessage m;
  m.type = ReliableMessage::Type::Reply;
  m.key = key;
  m.seq = seq;
  m.chunks.push_back(std::move(reply));
  out_.pushReliable(std::move(m));
}

void ServerCore::waitForCommands(std::chrono::microseconds timeout) {
  std::unique_lock<std::mutex> lock(inboxMutex_);
  inboxCv_.wait_for(lock, timeout, [&] {
    return !inbox_.empty() || !left_.empty() || !handoffs_.empty() ||
           anySubscribersChanged_.load();
  });
}

size_t ServerCore::processPending() {
  std::deque<Incoming> batch;
  std::vector<Left> left;
  std::deque<HandoffIn> handoffs;
  std::deque<OwnershipNote> notes;
  {
    std::lock_guard<std::mutex> lock(inboxMutex_);
    batch.swap(inbox_);
    left.swap(left_);
    handoffs.swap(handoffs_);
    notes.swap(ownershipNotes_);
  }
  // Moves between daemons first: a world that left answers its waiting commands Moved.
  for (HandoffIn& h : handoffs) applyHandoff(std::move(h));
  expireMoves();
  // Then what the coordinator found (registrations, worlds taken from or by this daemon),
  // and which worlds this daemon may serve now (docs/SERVER.md "Standby and takeover").
  if (coordinated()) {
    for (OwnershipNote& n : notes) applyOwnership(n);
    updateFences();
    followOwners();  // the worlds this daemon stands by for, replayed as their journals grow
  }
  // Commands that waited for a Step job which has ended go first, in their order.
  for (uint32_t id : worldIds()) drainWaiting(id);
  for (Incoming& in : batch) dispatch(std::move(in));
  for (const Left& l : left) applyLeft(l);  // after what they sent before they left
  commitDurable();  // the journals synced, then the replies go out
  for (uint32_t id : movedAway_) {
    ReliableMessage removed;
    removed.type = ReliableMessage::Type::WorldRemoved;
    removed.world = id;
    out_.pushReliable(std::move(removed));
  }
  movedAway_.clear();
  // (A world moved here publishes its info at once: its state writer comes with it.)
  if (!batch.empty() || !handoffs.empty() || !notes.empty()) publishWorldInfo();
  if (coordinated()) refreshOwned();
  return batch.size();
}

namespace {
/// The world a decoded command targets (0: none or undecodable).
uint32_t targetWorld(const Incoming& in) {
  if (!in.command.ok() || !protocol::needsWorld(in.command->request_type())) return 0;
  return in.command->world();
}
/// Requests that end a world's running Step job instead of waiting for it.
bool endsJob(const Incoming& in) {
  return in.command.ok() &&
         protocol::requestInfo(in.command->request_type()).has(protocol::kEndsJob);
}
/// Requests that become a job of their world when applied from the queue.
bool startsJob(const Incoming& in) {
  return in.command.ok() &&
         protocol::requestInfo(in.command->request_type()).has(protocol::kStartsJob);
}
}  // namespace

void ServerCore::dispatch(Incoming in) {
  ServerWorld* w = world(targetWorld(in));
  if (w && (w->busy() || !w->waiting.empty())) {
    if (!endsJob(in) || w->moving) {  // after the job (or move) and what waits, in order
      w->waiting.push_back(std::move(in));
      return;
    }
    // A client that may not do this to the world does not end its job: refused now.
    if (in.command->client_id() != in.envelopeKey ||
        !checkAccess(*w, *in.command, in.principal ? in.principal : in.envelopeKey,
                     in.envelopeKey, in.proven).ok()) {
      applyNow(in);
      return;
    }
    // Pause, ResetWorld, DestroyWorld end the job. What waited for it came first: it applies
    // now, in order, except Steps and LoadScenes, which end like the job without starting
    // (started, they would make the world busy again ahead of the commands after them).
    const std::string why = std::string("stopped by ") +
                            protocol::requestName(in.command->request_type()) + " (client " +
                            std::to_string(in.envelopeKey) + ")";
    cancelJob(*w, why);
    const uint32_t id = w->id;
    while ((w = world(id)) && !w->waiting.empty()) {
      Incoming waited = std::move(w->waiting.front());
      w->waiting.pop_front();
      if (startsJob(waited)) {
        ReplyHeader h = protocol::replyTo(*waited.command);
        h.tick = w->tick;
        h.status = Status::Error(Code::IncorrectState,
                                 std::string(protocol::requestName(
                                     waited.command->request_type())) +
                                     ": " + why + " before it started");
        ++counters_.commands;
        ++counters_.errors;
        pushReply(waited.envelopeKey, waited.envelopeSeq, protocol::encodeReply(h));
        release(waited);
      } else {
        applyNow(waited);
      }
    }
  }
  applyNow(in);
}

void ServerCore::applyNow(const Incoming& in) {
  current_ = &in;
  deferred_ = false;
  journaledWorld_ = 0;
  Bytes reply = apply(in);
  current_ = nullptr;
  if (deferred_) return;  // a Step job answers when it ends
  // Released before its reply can reach the client, so that the client's next command finds
  // nothing of it waiting (the rates count only commands sent while some wait: submit).
  release(in);
  if (journaledWorld_) {
    const ReplyHeader failed = protocol::replyTo(*in.command);
    pushReply(in.envelopeKey, in.envelopeSeq, std::move(reply), journaledWorld_, &failed);
  } else {
    pushReply(in.envelopeKey, in.envelopeSeq, std::move(reply));
  }
}

void ServerCore::drainWaiting(uint32_t id) {
  for (ServerWorld* w; (w = world(id)) && !w->busy() && !w->waiting.empty();) {
    Incoming in = std::move(w->waiting.front());
    w->waiting.pop_front();
    applyNow(in);  // may destroy the world: looked up again
  }
}

void ServerCore::continueJob(ServerWorld& w, double seconds) {
  ServerWorld::StepJob& job = *w.job;
  if (!job.stored) return;  // its lease is synced with the tick's commands first
  const auto t0 = std::chrono::steady_clock::now();
  const auto until = t0 + std::chrono::duration<double>(seconds);
  uint64_t n = 0;
  bool failed = false;
  while (job.remaining > 0) {  // at least one step
    stepTimed(w, 1);
    if (!stepProblem_.ok()) {
      failed = true;
      break;
    }
    --job.remaining;
    ++n;
    if (std::chrono::steady_clock::now() >= until) break;
  }
  const double ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  job.ms += ms;
  if (n > 0) {
    w.tickMs = float(ms / double(n));
    w.tickMsMax = std::max(w.tickMsMax, w.tickMs);
    w.frameDirty = true;
  }
  if (failed) {
    endJob(w, stepProblem_);
    return;
  }
  if (job.remaining == 0) endJob(w, Status::Ok());
}

void ServerCore::endJob(ServerWorld& w, Status status) {
  if (!w.job) return;
  const ServerWorld::StepJob job = *w.job;
  w.job.reset();
  ReplyHeader h = job.header;
  h.tick = w.tick;
  // Its steps were stored ahead (a Lease) before they were taken. One that ends early says
  // where the world stopped, so that a restart does not step on to the lease's end (a step
  // that failed has said so already, and a Pause that stopped it is in the journal).
  bool marked = false;
  if (w.store && job.stored && job.remaining > 0 && w.leaseUntil > w.tick) {
    Status ms = journalMark(w);
    marked = ms.ok();
  }
  if (!status.ok()) {
    status.message += " after " + std::to_string(job.requested - job.remaining) + " of " +
                      std::to_string(job.requested) + " steps";
    ++counters_.errors;
  }
  const ReplyHeader failed = h;
  h.status = std::move(status);
  release(job.envelopeKey, job.sender, job.charge);  // before the reply (applyNow)
  pushReply(job.envelopeKey, job.envelopeSeq, protocol::encodeReply(h), marked ? w.id : 0,
            &failed);
}

void ServerCore::cancelJob(ServerWorld& w, const std::string& why) {
  endJob(w, Status::Error(Code::IncorrectState, "step: " + why));
  if (w.load) {
    // The loader thread cannot be stopped: it finishes, and its world is dropped.
    ServerWorld::LoadJob job = std::move(*w.load);
    w.load.reset();
    ReplyHeader h = job.header;
    h.tick = w.tick;
    h.status = Status::Error(Code::IncorrectState, "load_scene: " + why);
    ++counters_.errors;
    pushReply(job.envelopeKey, job.envelopeSeq, protocol::encodeReply(h));
    release(job.envelopeKey, job.sender, job.charge);
  }
}

uint64_t ServerCore::totalBodies() const {
  uint64_t n = 0;
  for (auto& [id, w] : worlds_) n += uint64_t(w->world->bodyCount());
  return n;
}

namespace {
/// Resident set size of this process, bytes (0 when unknown).
uint64_t residentBytes() {
  std::FILE* f = std::fopen("/proc/self/statm", "r");
  if (!f) return 0;
  unsigned long long pages = 0, resident = 0;
  const int got = std::fscanf(f, "%llu %llu", &pages, &resident);
  std::fclose(f);
  return got == 2 ? resident * uint64_t(sysconf(_SC_PAGESIZE)) : 0;
}
uint64_t defaultMemoryBudget() {
  const long pages = sysconf(_SC_PHYS_PAGES), size = sysconf(_SC_PAGESIZE);
  return pages > 0 && size > 0 ? uint64_t(pages) * uint64_t(size) / 4 * 3 : (8ull << 30);
}
}  // namespace

Status ServerCore::checkGrowth(const ServerWorld* w, uint64_t bodies, uint64_t joints,
                               const std::string& what, uint64_t replaced) const {
  if (replaying_) return Status::Ok();  // the command passed them when it was first applied
  // A count past its limit, in one sentence for every count.
  auto over = [&](uint64_t would, uint64_t limit, const char* things, const char* key) {
    return Status::Error(Code::ResourceExhausted, what + " would make " + std::to_string(would) +
                                                      " " + things + ", the limit is " +
                                                      std::to_string(limit) + " (" + key + ")");
  };
  const uint64_t worldBodies = w ? uint64_t(w->world->bodyCount()) : 0;
  const uint64_t worldJoints = w ? uint64_t(w->world->jointCount()) : 0;
  if (worldBodies + bodies > config_.maxBodiesPerWorld)
    return over(worldBodies + bodies, config_.maxBodiesPerWorld, "bodies in the world",
                "server.max_bodies_per_world");
  if (worldJoints + joints > config_.maxJointsPerWorld)
    return over(worldJoints + joints, config_.maxJointsPerWorld, "joints in the world",
                "server.max_joints_per_world");
  const uint64_t all = totalBodies(), total = all - std::min(all, replaced);
  if (total + bodies > config_.maxBodiesTotal)
    return over(total + bodies, config_.maxBodiesTotal, "bodies in this server",
                "server.max_bodies_total");
  const uint64_t budget =
      config_.memoryBudgetBytes ? config_.memoryBudgetBytes : defaultMemoryBudget();
  const uint64_t rss = residentBytes();
  if (rss > budget)
    return Status::Error(Code::ResourceExhausted,
                         what + ": the server uses " + std::to_string(rss >> 20) +
                             " MiB, over its memory budget of " + std::to_string(budget >> 20) +
                             " MiB (server.memory_budget_mb); remove bodies or worlds first");
  return Status::Ok();
}

// ---------------------------------------------------------------------------------------------
// Time

double ServerCore::stepTimed(ServerWorld& w, uint64_t n) {
  const uint64_t redone = w.world->stats().guardEvents;
  const uint64_t stopped = w.world->stats().guardQuarantined;
  auto t0 = std::chrono::steady_clock::now();
  uint64_t taken = 0;
  std::string failure, code;
  stepProblem_ = Status::Ok();
  for (; taken < n; ++taken) {
    const phys::StepStats& before = w.world->stats();
    const uint64_t refused = before.stepsRefused, failed = before.stepFailures;
    try {
      w.world->step();
    } catch (const std::bad_alloc&) {  // the engine catches its own; this is a last resort
      failure = "out of memory";
    } catch (const std::exception& e) {
      failure = e.what();
    } catch (...) {
      failure = "an unknown exception";
    }
    const phys::StepStats& after = w.world->stats();
    if (failure.empty() && after.stepsRefused != refused) {
      code = "contact_budget";
      failure = after.lastGuardEvent;
      stepProblem_ = Status::Error(Code::ResourceExhausted,
                                   "step: " + failure +
                                       " (server.max_contact_pairs); the world is paused");
    } else if (failure.empty() && after.stepFailures != failed) {
      failure = after.lastGuardEvent.empty() ? "a step failed inside the engine"
                                             : after.lastGuardEvent;
    }
    if (!failure.empty()) break;
  }
  double ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  w.tick += taken;
  w.reachedTick = std::max(w.reachedTick, w.tick);
  counters_.steps += taken;
  if (!failure.empty()) {
    // A step that was not taken (refused at the contact budget, or failed inside the engine):
    // the world stops here, as it was before that step, rather than trying again every tick.
    if (code.empty()) {
      code = "step_failed";
      stepProblem_ = Status::Error(Code::Internal, "step: " + failure + "; the world is paused");
    }
    ++counters_.stepFailures;
    w.mode = RunMode::Paused;
    w.accumulator = 0;
    journalMark(w);  // the run state changed outside a command
    queueEvent(w, wire::Severity::Error, code,
               failure + "; the world is paused at tick " + std::to_string(w.tick));
  }
  // The engine's guard rails acted: every client hears of it (phys/events).
  const phys::StepStats& st = w.world->stats();
  if (st.guardEvents > redone)
    queueEvent(
        w, wire::Severity::Warning, "guard_rollback",
        std::to_string(st.guardEvents - redone) +
            " step(s) rolled back and redone with a safer setting; last: " + st.lastGuardEvent);
  if (st.guardQuarantined > stopped)
    queueEvent(
        w, wire::Severity::Error, "guard_quarantine",
        std::to_string(st.guardQuarantined - stopped) +
            " body(ies) stopped because redoing the step did not help; last: " + st.lastGuardEvent);
  return ms;
}

void ServerCore::queueEvent(const ServerWorld& w, wire::Severity severity, std::string_view code,
                            std::string_view message) {
  queueEvent(w.id, w.tick, severity, code, message);
}

void ServerCore::queueEvent(uint32_t world, uint64_t tick, wire::Severity severity,
                            std::string_view code, std::string_view message) {
  if (replaying_) return;  // told when it first happened
  ReliableMessage m;
  m.type = ReliableMessage::Type::Event;
  m.key = world;
  m.world = world;
  m.chunks.push_back(protocol::encodeEvent(world, tick, severity, code, message));
  out_.pushReliable(std::move(m));
}

Status ServerCore::stepWorld(uint32_t id, uint64_t n) {
  ServerWorld* w = world(id);
  if (!w) return Status::Error(Code::NotFound, "no world " + std::to_string(id));
  // Applied directly (tests, Step without the queue): the steps are stored before they are
  // taken, or not taken.
  Status ls = leaseTo(*w, w->tick + n, /*syncNow=*/true);
  if (!ls.ok())
    return Status::Error(ls.code, "step: not stored: " + ls.message + "; the world did not step");
  const double ms = stepTimed(*w, n);
  if (w->store && w->store->dirty() && !replaying_) {  // a step failed: its mark
    Status s = w->store->sync();
    if (!s.ok()) log(true, "world " + std::to_string(id) + ": " + s.message);
  }
  if (!stepProblem_.ok()) {
    w->frameDirty = true;
    return stepProblem_;
  }
  if (n > 0) {
    w->tickMs = float(ms / double(n));
    w->tickMsMax = std::max(w->tickMsMax, w->tickMs);
    w->frameDirty = true;
  }
  return Status::Ok();
}

uint64_t ServerCore::advance(double wallSeconds) {
  uint64_t total = 0;
  size_t busy = 0;
  if (anySubscribersChanged_.exchange(false)) {
    // Streams with new subscribers (or fewer) are looked at below, stepping or not: a new
    // one's keyframe goes out now (queueStream), whatever the world is doing.
    std::vector<uint32_t> changed;
    {
      std::lock_guard<std::mutex> lock(subscribersMutex_);
      changed.swap(subscribersChanged_);
    }
    for (uint32_t id : changed)
      if (ServerWorld* w = world(id)) w->frameDirty = true;
  }
  for (auto& [id, w] : worlds_) busy += w->job.has_value();
  if (!loaders_.empty()) reapLoaders();
  for (auto& [id, wp] : worlds_) {
    ServerWorld& w = *wp;
    uint64_t n = 0;
    if (w.load) {
      finishLoad(w);  // when the loader is done; the world's time waits for it
      if (w.frameDirty && !w.busy()) queueFrame(w);
      continue;
    }
    if (w.moving || w.fenced || heldForSubscribers(w)) {
      // A moving world's time stops, and a fenced one's; one moved here starts from now.
      w.accumulator = 0;
      continue;
    }
    if (w.busy()) {
      // A Step job owns the world's time: a slice per tick (the busy worlds share
      // step_slice_ms), a frame after it.
      const uint64_t before = w.tick;
      try {
        continueJob(w, config_.stepSliceSeconds / double(busy));
        total += w.tick - before;
      } catch (const std::exception& e) {
        endJob(w, Status::Error(Code::Internal, std::string("step: ") + e.what()));
      }
      w.accumulator = 0;
      if (w.frameDirty) queueFrame(w);
      continue;
    }
    if (w.mode == RunMode::RealTime) {
      w.accumulator += std::max(0.0, wallSeconds) * w.rateHz;
      n = uint64_t(std::floor(w.accumulator));
      const uint64_t cap = uint64_t(std::max(1, config_.maxCatchUpSteps));
      if (n > cap) {
        // Behind real time by more than we may catch up in one tick: drop the backlog.
        ++w.overruns;
        n = cap;
        w.accumulator = 0;
      } else {
        w.accumulator -= double(n);
      }
    } else if (w.mode == RunMode::AsFastAsPossible) {
      n = 1;
    }
    n = leaseForRun(w, n);  // no step the journal does not allow (0: the world is held)
    if (n > 0) {
      // Every step of real time is a tick its subscribers see: steps taken to catch up
      // (at most maxCatchUpSteps) get a frame each, not only the last one.
      double ms = 0;
      uint64_t taken = 0;
      for (; taken < n; ++taken) {
        ms += stepTimed(w, 1);
        if (!stepProblem_.ok()) break;  // not taken: the world is paused (an event says why)
        if (taken + 1 < n) queueFrame(w);
      }
      n = taken;
      total += n;
      w.tickMs = float(ms);
      w.tickMsMax = std::max(w.tickMsMax, w.tickMs);
      // A real-time tick that took longer than its period missed its deadline.
      if (w.mode == RunMode::RealTime && ms > 1000.0 / w.rateHz) ++w.overruns;
      w.frameDirty = true;
    }
    if (w.frameDirty) queueFrame(w);
  }
  commitDurable();  // Steps' marks synced before their replies; checkpoints that are due
  return total;
}

double ServerCore::secondsUntilDue(double idle) const {
  double best = idle;
  for (auto& [id, w] : worlds_) {
    if (w->mode == RunMode::AsFastAsPossible || w->job) return 0;
    // Commands that waited for a job that has ended: the next tick applies them (not after a
    // sleep of up to `idle` each, which held requests pipelined to one world to ~50 a second).
    if (!w->busy() && !w->waiting.empty()) return 0;
    if (w->load) best = std::min(best, 0.001);  // look for the loader's result soon
    if (w->mode == RunMode::RealTime) {
      double s = std::max(0.0, (1.0 - w->accumulator) / w->rateHz);
      best = std::min(best, s);
    }
  }
  return best;
}

Status ServerCore::queueFrame(ServerWorld& w) {
  // State frames (docs/PROTOCOL.md "State frames"): the world's stream and each interest's,
  // keyframes and deltas. What changed is found once for all of them: the bodies awake now
  // (and, per stream, those awake at its last frame) and those edited outside the step.
  w.frameDirty = false;
  std::vector<phys::BodyId> awake;
  w.world->awakeBodies(&awake);
  std::vector<uint64_t> awakeIds(awake.size());
  for (size_t i = 0; i < awake.size(); ++i) awakeIds[i] = awake[i].packed();
  std::sort(awakeIds.begin(), awakeIds.end());
  std::sort(w.touched.begin(), w.touched.end());
  w.touched.erase(std::unique(w.touched.begin(), w.touched.end()), w.touched.end());
  // Frames are ordered by (epoch, tick, edit) (docs/PROTOCOL.md "Order of frames"). A new
  // tick (or epoch) is frame edit 0. Edits between ticks of a world that does not step by
  // itself (paused, no Step running) go out at once in a frame of their own at the same
  // tick, the next edit number: its subscribers see poses set, bodies spawned and removed
  // without a step. A running world's edits wait for its next tick's delta (within a period;
  // touched is kept until then), so that edits do not double its frames. A frame that is
  // neither (the same tick, nothing edited) goes only to streams that need a keyframe (a new
  // subscriber), at the edit number their other subscribers already hold.
  const bool newTick = w.tick != w.lastFrameTick || w.epoch != w.lastFrameEpoch;
  const bool stepsByItself = w.mode != RunMode::Paused || w.busy();
  const bool editFrame = !newTick && !w.touched.empty() && !stepsByItself;
  if (newTick) w.edit = 0;
  if (editFrame) ++w.edit;
  const bool fresh = newTick || editFrame;
  // framesProduced counts the world's own stream's frames (WorldSummary.frames).
  if (queueStream(w, 0, nullptr, &w.published, awakeIds, fresh)) ++w.framesProduced;
  for (auto& [id, in] : w.interests) queueStream(w, id, &in, &in.published, awakeIds, fresh);
  if (fresh) w.touched.clear();
  w.lastFrameTick = w.tick;
  w.lastFrameEpoch = w.epoch;
  return Status::Ok();
}

bool ServerCore::queueStream(ServerWorld& w, uint32_t interest, const ServerWorld::Interest* filter,
                             ServerWorld::Published* streamState,
                             const std::vector<uint64_t>& awakeIds, bool fresh) {
  // A keyframe holds every body of the stream; a delta the bodies whose state changed among
  // those awake now, awake at the last frame (one that just fell asleep sends its final state
  // once) and edited since, and those gone (removed, or out of the interest's region). A
  // stream nobody subscribes to encodes nothing.
  ServerWorld::Published& pub = *streamState;
  Subscribers subscribers;
  {
    std::lock_guard<std::mutex> lock(subscribersMutex_);
    auto it = subscribers_.find(streamKey(w.id, interest));
    if (it != subscribers_.end()) subscribers = it->second;
  }
  if (subscribers.now == 0 && !config_.framesWithoutSubscribers) {
    pub = ServerWorld::Published();  // the next subscriber starts from a keyframe
    return false;
  }
  // This stream's frames the publisher dropped (a stalled writer) break its chain of deltas.
  const uint64_t dropped = out_.framesDropped(w.id, interest);
  // Every body goes again once a period, to repair what a subscriber lost: spread over the
  // deltas (the rolling refresh) or as a whole keyframe. A stream at rest for a whole period
  // has had nothing to lose but empty deltas, so its next period is quietKeyframeFactor times
  // longer (an idle world costs a tenth).
  const bool rolling = config_.rollingRefresh && config_.keyframeTicks > 1;
  const bool quiet = rolling ? !pub.changedThisRound : !pub.changedSinceKeyframe;
  // (keyframe_ticks 1 is every frame a keyframe, quiet or not.)
  const uint64_t period =
      uint64_t(config_.keyframeTicks) *
      (quiet && config_.keyframeTicks > 1 ? std::max<uint32_t>(1, config_.quietKeyframeFactor) : 1);
  // A new subscriber (a reader matched since the last frame) gets a keyframe now.
  const bool keyframe = !pub.valid || subscribers.matched > pub.matched ||
                        dropped != pub.droppedSeen ||
                        (!rolling && pub.sinceKeyframe + 1 >= period);
  // The same tick and edit again: nothing for a stream that has it (what changed since waits
  // for the next fresh frame).
  if (!keyframe && !fresh) return false;
  phys::World& world = *w.world;
  std::vector<wire::BodyState> states;
  std::vector<uint64_t> removed;
  phys::BodyState s;
  uint64_t refreshLo = 0, refreshHi = 0;
  bool changed = false;  // a delta carrying a change (not only the refresh)
  if (keyframe) {
    std::vector<phys::BodyId> ids;
    if (filter && !filter->region) {
      for (uint64_t id : filter->ids)
        if (world.isValid(phys::BodyId::fromPacked(id))) ids.push_back(phys::BodyId::fromPacked(id));
    } else {
      ids = world.bodies();
    }
    pub.sent.clear();
    for (phys::BodyId id : ids) {
      if (!world.getBody(id, &s).ok() || (filter && !filter->contains(id.packed(), s))) continue;
      states.push_back(protocol::toWire(s));
      pub.sent.emplace_hint(pub.sent.end(), protocol::refreshKey(id.packed()), states.back());
    }
    pub.sinceKeyframe = 0;
    pub.refreshCursor = 0;
    pub.changedThisRound = false;
  } else {
    std::vector<uint64_t> candidates;
    candidates.reserve(awakeIds.size() + pub.awake.size() + w.touched.size());
    std::set_union(awakeIds.begin(), awakeIds.end(), pub.awake.begin(), pub.awake.end(),
                   std::back_inserter(candidates));
    std::vector<uint64_t> all;
    all.reserve(candidates.size() + w.touched.size());
    std::set_union(candidates.begin(), candidates.end(), w.touched.begin(), w.touched.end(),
                   std::back_inserter(all));
    std::vector<uint64_t> carried;  // refresh keys of the bodies this delta carries
    for (uint64_t id : all) {
      if (filter && !filter->region && !std::binary_search(filter->ids.begin(), filter->ids.end(), id))
        continue;
      const uint64_t key = protocol::refreshKey(id);
      if (world.getBody(phys::BodyId::fromPacked(id), &s).ok() &&
          (!filter || filter->contains(id, s))) {
        const wire::BodyState ws = protocol::toWire(s);
        auto [it, added] = pub.sent.try_emplace(key, ws);
        if (!added && std::memcmp(&it->second, &ws, sizeof ws) == 0) continue;  // unchanged
        it->second = ws;
        states.push_back(ws);
        carried.push_back(key);
      } else if (pub.sent.erase(key) > 0) {
        removed.push_back(id);  // gone, or out of the region
      }
    }
    changed = !states.empty() || !removed.empty();
    if (rolling) {
      // The next period-th of the stream's bodies, in key order, as its subscribers hold them
      // (every change since went out in a delta), those already carried left out.
      std::sort(carried.begin(), carried.end());
      const size_t per = std::max<size_t>(1, (pub.sent.size() + period - 1) / period);
      auto it = pub.sent.lower_bound(pub.refreshCursor);
      refreshLo = pub.refreshCursor;
      for (size_t k = 0; k < per && it != pub.sent.end(); ++k, ++it)
        if (!std::binary_search(carried.begin(), carried.end(), it->first))
          states.push_back(it->second);
      refreshHi = it == pub.sent.end() ? UINT64_MAX : it->first;  // above lo: keys are unique
      pub.changedThisRound = pub.changedThisRound || changed;
      pub.refreshCursor = it == pub.sent.end() ? 0 : refreshHi;  // at the end: round again
      if (it == pub.sent.end()) pub.changedThisRound = false;
    }
    // In the world's order, as keyframes are: a subscriber applies them in one walk.
    std::sort(states.begin(), states.end(), [](const wire::BodyState& a, const wire::BodyState& b) {
      return protocol::refreshKey(a.id()) < protocol::refreshKey(b.id());
    });
    ++pub.sinceKeyframe;
  }
  StateFrameSet f;
  f.world = w.id;
  f.interest = interest;
  f.tick = w.tick;
  const auto stamp = std::chrono::system_clock::now().time_since_epoch();
  protocol::FrameHeader h{w.id, w.tick, world.time(),
                          uint64_t(std::chrono::duration_cast<std::chrono::nanoseconds>(stamp).count())};
  h.keyframe = keyframe;
  h.baseTick = pub.baseTick;
  h.compact = config_.compactStates;
  h.interest = interest;
  h.refreshLo = refreshLo;
  h.refreshHi = refreshHi;
  h.epoch = w.epoch;
  h.edit = w.edit;
  h.baseEdit = pub.baseEdit;
  f.chunks = protocol::encodeStateFrames(h, states, std::max<uint32_t>(1, config_.bodiesPerChunk),
                                         removed, uint32_t(pub.sent.size()));
  pub.awake = awakeIds;
  pub.valid = true;
  const bool carried = keyframe || !states.empty() || !removed.empty();
  if (carried) {
    pub.baseTick = w.tick;
    pub.baseEdit = w.edit;
  }
  pub.changedSinceKeyframe = !keyframe && (pub.changedSinceKeyframe || changed);
  pub.matched = subscribers.matched;
  pub.droppedSeen = dropped;
  pub.bytes = 0;
  for (const protocol::Bytes& c : f.chunks) pub.bytes += c.size();
  out_.pushFrame(std::move(f));
  return true;
}

// ---------------------------------------------------------------------------------------------
// World info and status

void ServerCore::publishWorldInfo() {
  for (auto& [id, wp] : worlds_) {
    ServerWorld& w = *wp;
    if (!w.infoDirty) continue;
    w.infoDirty = false;
    // The definitions as the engine holds them (the one source), poses and velocities now.
    std::vector<protocol::BodyEntry> bodies;
    bodies.reserve(size_t(w.world->bodyCount()));
    for (phys::BodyId id : w.world->bodies())
      bodies.push_back({id.packed(), bodyDefOf(*w.world, id)});
    std::vector<protocol::JointEntry> joints;
    joints.reserve(size_t(w.world->jointCount()));
    phys::JointState js;
    for (phys::JointId id : w.world->joints()) {
      protocol::JointEntry e{id.packed(), {}};
      if (w.world->getJoint(id, &e.def, &js).ok()) joints.push_back(std::move(e));
    }
    protocol::WorldInfoHeader h;
    h.world = w.id;
    h.name = w.name;
    h.revision = w.revision;
    h.tick = w.tick;
    h.gravity = w.world->def().gravity;
    h.timeStep = w.world->def().timeStep;
    h.daemon = config_.serverId;
    ReliableMessage m;
    m.type = ReliableMessage::Type::WorldInfo;
    m.world = w.id;
    m.chunks = protocol::encodeWorldInfo(h, bodies, joints, config_.limits);
    out_.pushReliable(std::move(m));
  }
}

std::vector<protocol::WorldSummary> ServerCore::summaries() const {
  std::vector<protocol::WorldSummary> out;
  std::lock_guard<std::mutex> lock(subscribersMutex_);
  for (auto& [id, w] : worlds_) {
    protocol::WorldSummary s;
    s.world = id;
    s.name = w->name;
    s.preset = w->preset;
    s.bodies = uint32_t(w->world->bodyCount());
    s.joints = uint32_t(w->world->jointCount());
    s.tick = w->tick;
    s.time = w->world->time();
    s.running = w->mode != RunMode::Paused;
    s.rateHz = w->mode == RunMode::RealTime ? float(w->rateHz) : 0.0f;
    s.tickMs = w->tickMs;
    s.tickMsMax = w->tickMsMax;
    s.overruns = w->overruns;
    s.frames = w->framesProduced;
    const phys::BackendState& b = w->world->backendState();
    s.backend = phys::toString(b.active);
    if (b.active == phys::Backend::Gpu) s.device = b.device;
    // Why the CPU runs it, or (a GPU world) why its last CPU-taken step was not on the device.
    s.backendNote = b.note.empty() && b.cpuSteps > 0 ? b.lastFallback : b.note;
    s.gpuSteps = b.gpuSteps;
    s.cpuSteps = b.cpuSteps;
    s.awakeBodies = uint32_t(w->world->awakeBodyCount());
    s.sleepingBodies = uint32_t(w->world->stats().sleepingBodies);
    s.frameBytes = uint32_t(std::min<uint64_t>(w->published.bytes, UINT32_MAX));
    s.contacts = uint32_t(w->world->stats().contacts);
    s.stepBufferBytes = w->world->stepBufferBytes();
    auto it = subscribers_.find(streamKey(id, 0));
    s.subscribers = it == subscribers_.end() ? 0 : it->second.now;
    s.daemon = config_.serverId;
    if (w->moving) s.movingTo = w->moving->target;
    out.push_back(std::move(s));
  }
  // Worlds kept on disk but not restored: listed so that clients see why (not only absent).
  for (auto& [id, d] : damaged_) {
    protocol::WorldSummary s;
    s.world = id;
    s.name = d.name;
    s.damage = d.damage;
    s.daemon = config_.serverId;
    out.push_back(std::move(s));
  }
  std::sort(out.begin(), out.end(), [](const auto& a, const auto& b) { return a.world < b.world; });
  return out;
}

protocol::ServerStatusInfo ServerCore::status() const {
  protocol::ServerStatusInfo s;
  s.serverName = config_.serverName;
  s.serverVersion = PHYSD_VERSION;
  s.uptimeS = std::chrono::duration<double>(std::chrono::steady_clock::now() - started_).count();
  s.commands = counters_.commands + refusedAtSubmit_.load();
  s.errors = counters_.errors + refusedAtSubmit_.load();
  s.worlds = summaries();
  s.framesDropped = out_.framesDropped();
  // glibc: bytes handed out from the arenas plus those in their own mappings. What the
  // resident set holds beyond this is the allocator's free pages (and code, stacks).
  const struct mallinfo2 mi = mallinfo2();
  s.heapBytes = mi.uordblks + mi.hblkhd;
  s.readOnly = readOnly_;
  s.daemon = config_.serverId;
  s.cluster = config_.cluster;
  s.statusPeriodS = float(config_.statusPeriodS);
  if (config_.cluster) s.peers = livePeers();
  return s;
}

void ServerCore::notePeerStatus(uint64_t daemon, double periodS) {
  if (daemon == 0 || daemon == config_.serverId) return;
  std::lock_guard<std::mutex> lk(peersMutex_);
  const auto now = std::chrono::steady_clock::now();
  auto it = peersSeen_.find(daemon);
  // A peer not named now: this daemon's status names it at once, not a period later (a
  // client connecting while the domain starts waits for the status of every daemon named,
  // and would otherwise miss one that only this daemon has seen yet).
  if (it == peersSeen_.end() ||
      now - it->second.first > std::chrono::duration<double>(it->second.second))
    statusWanted_ = true;
  // (A period past a minute is not believed: a peer is named for three minutes at most.)
  peersSeen_[daemon] = {now, std::clamp(3 * periodS, 2.0, 180.0)};
}

void ServerCore::notePeerGone(uint64_t daemon) {
  std::lock_guard<std::mutex> lk(peersMutex_);
  if (peersSeen_.erase(daemon) > 0) statusWanted_ = true;
}

std::vector<uint64_t> ServerCore::livePeers() const {
  const auto now = std::chrono::steady_clock::now();
  std::vector<uint64_t> out;
  std::lock_guard<std::mutex> lk(peersMutex_);
  for (const auto& [id, seen] : peersSeen_)
    if (now - seen.first <= std::chrono::duration<double>(seen.second)) out.push_back(id);
  return out;
}

void ServerCore::publishStatus() {
  ReliableMessage m;
  m.type = ReliableMessage::Type::Status;
  m.key = config_.serverId;
  m.chunks.push_back(protocol::encodeServerStatus(status()));
  out_.pushReliable(std::move(m));
  for (auto& [id, w] : worlds_) w->tickMsMax = 0;
}

// ---------------------------------------------------------------------------------------------
// Tick thread

TickThread::TickThread(ServerCore* core, std::chrono::milliseconds statusPeriod)
    : core_(core), statusPeriod_(statusPeriod) {}

TickThread::~TickThread() {
  stop();
}

void TickThread::start() {
  stop_ = false;
  thread_ = std::thread([this] { run(); });
}

void TickThread::stop() {
  stop_ = true;
  if (thread_.joinable()) thread_.join();
}

void TickThread::run() {
  using Clock = std::chrono::steady_clock;
  auto last = Clock::now();
  auto lastStatus = last - statusPeriod_;
  while (!stop_) {
    auto now = Clock::now();
    // Commands and steps answer their own failures; this is the last resort that keeps the
    // tick thread alive (out of memory while publishing, say): the tick is skipped.
    try {
      core_->processPending();
      now = Clock::now();
      double dt = std::chrono::duration<double>(now - last).count();
      last = now;
      core_->advance(dt);
      core_->publishWorldInfo();
      if (now - lastStatus >= statusPeriod_ || core_->takeStatusWanted()) {
        core_->publishStatus();
        lastStatus = now;
      }
    } catch (const std::exception& e) {
      std::fprintf(stderr, "physd: tick failed: %s\n", e.what());
      last = Clock::now();
    }
    ticks_.fetch_add(1);
    // Sleep until a world owes a step (at most 20 ms, so stop and status stay responsive),
    // waking early for commands.
    double wait = core_->secondsUntilDue(0.02);
    if (wait > 0)
      core_->waitForCommands(std::chrono::microseconds(int64_t(std::min(wait, 0.02) * 1e6)));
  }
}

}  // namespace phys::server
