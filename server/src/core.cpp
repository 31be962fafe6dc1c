// ServerCore: registry, time control, frames, status (commands.cpp applies commands).
#include "phys/server/core.h"

#include <algorithm>
#include <cmath>
#include <string>

#include "phys/protocol/convert.h"
#include "phys/scene/scene.h"

namespace phys::server {

ServerCore::ServerCore(CoreConfig config)
    : config_(std::move(config)),
      started_(std::chrono::steady_clock::now()),
      out_(config_.frameRingCapacity) {}

ServerCore::~ServerCore() = default;

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

std::unique_ptr<ServerWorld> ServerCore::makeWorld(const std::string& name,
                                                   const std::string& preset,
                                                   const phys::WorldDef& def) {
  auto w = std::make_unique<ServerWorld>();
  w->name = name;
  w->preset = preset;
  phys::WorldDef d = def;
  d.threads = config_.threads;
  d.gpuAllowCpuDevice = config_.gpuAllowCpuDevice;
  w->world = std::make_unique<phys::World>(d);
  w->rateHz = config_.defaultRateHz;
  return w;
}

Status ServerCore::createWorld(const std::string& name, const std::string& preset,
                               const std::string& scene, uint32_t* id, const std::string& backend) {
  const CoreCounters saved = counters_;  // start-up worlds are not client commands
  protocol::CommandBuilder b;
  protocol::CreateWorldArgs args;
  args.name = name;
  args.preset = preset;
  args.backend = backend;
  Bytes reply =
      applyBytes(b.createWorld(args).finish({config_.serverId, 0, 0}), config_.serverId, 0);
  auto d = protocol::decodeReply(std::move(reply), config_.limits);
  if (!d.ok()) return Status::Error(Code::Internal, "create world reply: " + d.status.message);
  if (d->status() != Code::Ok) {
    counters_.commands = saved.commands;
    counters_.errors = saved.errors;
    return Status::Error(d->status(), d->message() ? d->message()->str() : "");
  }
  uint32_t wid = d->world();
  if (!scene.empty()) {
    Bytes r2 = applyBytes(
        protocol::CommandBuilder().loadSceneNamed(scene).finish({config_.serverId, 0, wid}),
        config_.serverId, 0);
    auto d2 = protocol::decodeReply(std::move(r2), config_.limits);
    if (!d2.ok() || d2->status() != Code::Ok) {
      Status s = d2.ok() ? Status::Error(d2->status(), d2->message() ? d2->message()->str() : "")
                         : d2.status;
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
  std::lock_guard<std::mutex> lock(subscribersMutex_);
  subscribers_[world] = n;
}

// ---------------------------------------------------------------------------------------------
// Inbox

void ServerCore::submit(Incoming in) {
  {
    std::lock_guard<std::mutex> lock(inboxMutex_);
    inbox_.push_back(std::move(in));
  }
  inboxCv_.notify_one();
}

void ServerCore::waitForCommands(std::chrono::microseconds timeout) {
  std::unique_lock<std::mutex> lock(inboxMutex_);
  inboxCv_.wait_for(lock, timeout, [&] { return !inbox_.empty(); });
}

size_t ServerCore::processPending() {
  std::deque<Incoming> batch;
  {
    std::lock_guard<std::mutex> lock(inboxMutex_);
    batch.swap(inbox_);
  }
  for (Incoming& in : batch) {
    ReliableMessage m;
    m.type = ReliableMessage::Type::Reply;
    m.key = in.envelopeKey;
    m.seq = in.envelopeSeq;
    m.chunks.push_back(apply(in));
    out_.pushReliable(std::move(m));
  }
  if (!batch.empty()) publishWorldInfo();
  return batch.size();
}

// ---------------------------------------------------------------------------------------------
// Time

double ServerCore::stepTimed(ServerWorld& w, uint64_t n) {
  const uint64_t redone = w.world->stats().guardEvents;
  const uint64_t stopped = w.world->stats().guardQuarantined;
  auto t0 = std::chrono::steady_clock::now();
  for (uint64_t i = 0; i < n; ++i) w.world->step();
  double ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  w.tick += n;
  counters_.steps += n;
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
  ReliableMessage m;
  m.type = ReliableMessage::Type::Event;
  m.key = w.id;
  m.world = w.id;
  m.chunks.push_back(protocol::encodeEvent(w.id, w.tick, severity, code, message));
  out_.pushReliable(std::move(m));
}

Status ServerCore::stepWorld(uint32_t id, uint64_t n) {
  ServerWorld* w = world(id);
  if (!w) return Status::Error(Code::NotFound, "no world " + std::to_string(id));
  const double ms = stepTimed(*w, n);
  if (n > 0) {
    w->tickMs = float(ms / double(n));
    w->tickMsMax = std::max(w->tickMsMax, w->tickMs);
    w->frameDirty = true;
  }
  return Status::Ok();
}

uint64_t ServerCore::advance(double wallSeconds) {
  uint64_t total = 0;
  for (auto& [id, wp] : worlds_) {
    ServerWorld& w = *wp;
    uint64_t n = 0;
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
    if (n > 0) {
      // Every step of real time is a tick its subscribers see: steps taken to catch up
      // (at most maxCatchUpSteps) get a frame each, not only the last one.
      double ms = 0;
      for (uint64_t i = 0; i < n; ++i) {
        ms += stepTimed(w, 1);
        if (i + 1 < n) queueFrame(w);
      }
      total += n;
      w.tickMs = float(ms);
      w.tickMsMax = std::max(w.tickMsMax, w.tickMs);
      // A real-time tick that took longer than its period missed its deadline.
      if (w.mode == RunMode::RealTime && ms > 1000.0 / w.rateHz) ++w.overruns;
      w.frameDirty = true;
    }
    if (w.frameDirty) queueFrame(w);
  }
  return total;
}

double ServerCore::secondsUntilDue(double idle) const {
  double best = idle;
  for (auto& [id, w] : worlds_) {
    if (w->mode == RunMode::AsFastAsPossible) return 0;
    if (w->mode == RunMode::RealTime) {
      double s = std::max(0.0, (1.0 - w->accumulator) / w->rateHz);
      best = std::min(best, s);
    }
  }
  return best;
}

Status ServerCore::queueFrame(ServerWorld& w) {
  w.frameDirty = false;
  std::vector<wire::BodyState> states;
  std::vector<phys::BodyId> ids = w.world->bodies();
  states.reserve(ids.size());
  phys::BodyState s;
  for (phys::BodyId id : ids)
    if (w.world->getBody(id, &s).ok()) states.push_back(protocol::toWire(s));
  StateFrameSet f;
  f.world = w.id;
  f.tick = w.tick;
  const auto stamp = std::chrono::system_clock::now().time_since_epoch();
  f.chunks = protocol::encodeStateFrames(
      {w.id, w.tick, w.world->time(),
       uint64_t(std::chrono::duration_cast<std::chrono::nanoseconds>(stamp).count())},
      states, std::max<uint32_t>(1, config_.bodiesPerChunk));
  ++w.framesProduced;
  out_.pushFrame(std::move(f));
  return Status::Ok();
}

// ---------------------------------------------------------------------------------------------
// World info and status

void ServerCore::publishWorldInfo() {
  for (auto& [id, wp] : worlds_) {
    ServerWorld& w = *wp;
    if (!w.infoDirty) continue;
    w.infoDirty = false;
    std::vector<protocol::BodyEntry> bodies;
    bodies.reserve(w.bodyDefs.size());
    phys::BodyState s;
    for (auto& [packed, def] : w.bodyDefs) {
      protocol::BodyEntry e{packed, def};
      if (w.world->getBody(phys::BodyId::fromPacked(packed), &s).ok()) {
        e.def.position = s.position;
        e.def.rotation = s.rotation;
        e.def.linearVelocity = s.linearVelocity;
        e.def.angularVelocity = s.angularVelocity;
      }
      bodies.push_back(std::move(e));
    }
    std::vector<protocol::JointEntry> joints;
    for (auto& [packed, def] : w.jointDefs) joints.push_back({packed, def});
    protocol::WorldInfoHeader h;
    h.world = w.id;
    h.name = w.name;
    h.revision = w.revision;
    h.tick = w.tick;
    h.gravity = w.world->def().gravity;
    h.timeStep = w.world->def().timeStep;
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
    auto it = subscribers_.find(id);
    s.subscribers = it == subscribers_.end() ? 0 : it->second;
    out.push_back(std::move(s));
  }
  return out;
}

protocol::ServerStatusInfo ServerCore::status() const {
  protocol::ServerStatusInfo s;
  s.serverName = config_.serverName;
  s.serverVersion = PHYSD_VERSION;
  s.uptimeS = std::chrono::duration<double>(std::chrono::steady_clock::now() - started_).count();
  s.commands = counters_.commands;
  s.errors = counters_.errors;
  s.worlds = summaries();
  s.framesDropped = out_.framesDropped();
  return s;
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
    core_->processPending();
    auto now = Clock::now();
    double dt = std::chrono::duration<double>(now - last).count();
    last = now;
    core_->advance(dt);
    core_->publishWorldInfo();
    if (now - lastStatus >= statusPeriod_) {
      core_->publishStatus();
      lastStatus = now;
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
