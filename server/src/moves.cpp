// Moving a world between the daemons of a domain (MoveWorld; docs/SERVER.md "Moving a
// world", docs/ARCHITECTURE.md "Moving a world"). The source holds the world at a tick
// boundary and sends its checkpoint to the target in Handoff chunks on phys/peer; the target
// builds it, holds it unstepped and answers Ready; the source sends Commit (the world is the
// target's from then on; its commands still wait at the source); the target runs the world
// from the same tick, with the same id, epoch, access and run mode, and answers Done; the
// source then drops it and answers the MoveWorld and the commands that waited (Moved: the SDK
// sends them on, and the target holds the world by the time they reach it). Without Ready in
// time the source keeps the world and sends Abort; without Commit in time the target drops
// what it built. No step of this makes the world run on two daemons; a daemon that dies
// between Ready and Done can lose the world (the coordinator of a later part closes that).
#include <algorithm>

#include "phys/protocol/builder.h"
#include "phys/protocol/cluster.h"
#include "phys/server/core.h"

namespace phys::server {

using protocol::HandoffInfo;
using Clock = std::chrono::steady_clock;

namespace {
/// A move's Ready, Commit or Abort.
HandoffInfo control(wire::HandoffKind kind, uint32_t world, uint64_t from, uint64_t to,
                    uint64_t move) {
  HandoffInfo i;
  i.kind = kind;
  i.world = world;
  i.from = from;
  i.to = to;
  i.move = move;
  return i;
}
}  // namespace

void ServerCore::submitHandoff(HandoffIn h) {
  {
    std::lock_guard<std::mutex> lock(inboxMutex_);
    handoffs_.push_back(std::move(h));
  }
  inboxCv_.notify_one();
}

void ServerCore::pushHandoff(uint64_t to, const HandoffInfo& info, std::span<const uint8_t> bytes) {
  ReliableMessage m;
  m.type = ReliableMessage::Type::Handoff;
  m.key = to;
  m.world = info.world;
  m.chunks.push_back(protocol::encodeHandoff(info, bytes));
  out_.pushReliable(std::move(m));
}

Status ServerCore::startMove(ServerWorld& w, uint64_t to, const ReplyHeader& header) {
  Checkpoint c;
  Status s = checkpointOf(w, &c);
  if (!s.ok()) return s;
  const std::vector<uint8_t> bytes = encodeCheckpoint(c);
  const size_t count =
      std::max<size_t>(1, (bytes.size() + kHandoffChunkBytes - 1) / kHandoffChunkBytes);
  if (count > kMaxHandoffChunks)
    return Status::Error(Code::ResourceExhausted,
                         "move_world: the world's checkpoint is " + std::to_string(bytes.size()) +
                             " bytes, more than a move carries (" +
                             std::to_string(uint64_t(kMaxHandoffChunks) * kHandoffChunkBytes) +
                             ")");
  ServerWorld::MoveJob job;
  job.target = to;
  job.move = nextMove_++;
  job.header = header;
  job.envelopeKey = current_->envelopeKey;
  job.envelopeSeq = current_->envelopeSeq;
  job.sender = current_->sender;
  job.charge = queueCharge(*current_);
  job.deadline = Clock::now() + kMoveTimeout;
  HandoffInfo info;
  info.world = w.id;
  info.from = config_.serverId;
  info.to = to;
  info.move = job.move;
  info.epoch = w.epoch;
  info.ephemeral = w.ephemeral;
  {
    std::lock_guard<std::mutex> lock(subscribersMutex_);
    auto it = subscribers_.find(streamKey(w.id, 0));
    info.subscribers = it == subscribers_.end() ? 0 : it->second.now;
  }
  info.chunkCount = uint32_t(count);
  for (size_t i = 0; i < count; ++i) {
    info.chunkIndex = uint32_t(i);
    const size_t at = i * kHandoffChunkBytes;
    pushHandoff(to, info,
                std::span<const uint8_t>(bytes).subspan(
                    at, std::min<size_t>(kHandoffChunkBytes, bytes.size() - at)));
  }
  w.moving = job;
  log(false, "world " + std::to_string(w.id) + " '" + w.name + "': moving to daemon " +
                 std::to_string(to) + " at tick " + std::to_string(w.tick) + " (" +
                 std::to_string(bytes.size()) + " bytes)");
  return Status::Ok();
}

void ServerCore::applyHandoff(HandoffIn h) {
  switch (h.kind) {
    case wire::HandoffKind::Chunk:
      adoptWorld(h);
      return;
    case wire::HandoffKind::Ready:
    case wire::HandoffKind::Done: {
      ServerWorld* w = world(h.world);
      const bool ours = w && w->moving && w->moving->move == h.move && w->moving->target == h.from;
      if (h.kind == wire::HandoffKind::Done) {
        if (ours && w->moving->committed) finishMove(*w, Status::Ok());
        return;
      }
      if (!ours || w->moving->committed) {
        // A move this daemon gave up on: the target drops what it built.
        if (h.status.ok() && !ours)
          pushHandoff(h.from,
                      control(wire::HandoffKind::Abort, h.world, config_.serverId, h.from, h.move));
        return;
      }
      if (!h.status.ok()) return finishMove(*w, h.status);
      // The world is the target's from here; what comes for it waits until the target says
      // it holds it (Done), then goes there.
      w->moving->committed = true;
      w->moving->deadline = Clock::now() + kMoveTimeout;
      pushHandoff(h.from,
                  control(wire::HandoffKind::Commit, h.world, config_.serverId, h.from, h.move));
      return;
    }
    case wire::HandoffKind::Commit:
    case wire::HandoffKind::Abort: {
      auto it = std::find_if(prepared_.begin(), prepared_.end(), [&](const Prepared& p) {
        return p.from == h.from && p.move == h.move && p.world->id == h.world;
      });
      if (it == prepared_.end()) return;
      std::unique_ptr<ServerWorld> w = std::move(it->world);
      prepared_.erase(it);
      if (h.kind == wire::HandoffKind::Abort || world(w->id)) return;
      const uint32_t id = w->id;
      ServerWorld& sw = *w;
      worlds_[id] = std::move(w);
      if (movedOut_.erase(id)) keepMovedOut();
      announceHere(id);
      sw.infoDirty = true;  // its world info from here (after WorldAdded)
      if (durable() && !sw.ephemeral) {
        Status s = createStore(sw);
        if (!s.ok())
          log(true,
              "world " + std::to_string(id) + " moved here is not kept on disk: " + s.message);
      }
      log(false, "world " + std::to_string(id) + " '" + sw.name + "': moved here from daemon " +
                     std::to_string(h.from) + " at tick " + std::to_string(sw.tick));
      pushHandoff(h.from, control(wire::HandoffKind::Done, id, config_.serverId, h.from, h.move));
      return;
    }
  }
}

void ServerCore::adoptWorld(HandoffIn& h) {
  HandoffInfo ready = control(wire::HandoffKind::Ready, h.world, config_.serverId, h.from, h.move);
  auto refuse = [&](Code code, const std::string& why) {
    ready.status = Status::Error(code, "daemon " + std::to_string(config_.serverId) + ": " + why);
    pushHandoff(h.from, ready);
  };
  if (!config_.cluster) return refuse(Code::Unsupported, "not in a cluster ([cluster] enabled)");
  Checkpoint c;
  Status s = decodeCheckpoint(h.checkpoint, &c);
  if (!s.ok()) return refuse(Code::Malformed, "the world's checkpoint: " + s.message);
  if (c.meta.worldId != h.world)
    return refuse(Code::Malformed, "the checkpoint is of world " + std::to_string(c.meta.worldId) +
                                       ", not " + std::to_string(h.world));
  if (world(h.world) || damaged_.count(h.world))
    return refuse(Code::IncorrectState, "it holds a world " + std::to_string(h.world) + " already");
  if (findWorld(c.meta.name))
    return refuse(Code::InvalidArgument, "it holds a world named '" + c.meta.name + "'");
  if (worlds_.size() + prepared_.size() >= config_.maxWorlds)
    return refuse(Code::ResourceExhausted,
                  "it holds " + std::to_string(worlds_.size()) + " worlds, its max_worlds");
  auto w = std::make_unique<ServerWorld>();
  w->id = h.world;
  std::vector<std::string> notes;
  s = restoreInto(*w, c, {}, &notes);
  if (!s.ok()) return refuse(s.code, "the world's checkpoint: " + s.message);
  // The same tick sequence: its subscribers' next frame is the next tick, a keyframe, and no
  // frame of the tick the source published last.
  w->epoch = h.epoch;
  w->ephemeral = h.ephemeral;
  w->frameDirty = false;
  w->lastFrameTick = w->tick;
  w->lastFrameEpoch = w->epoch;
  w->published.valid = false;
  w->awaitSubscribers = h.subscribers;
  w->holdUntil = Clock::now() + std::chrono::seconds(2);
  prepared_.push_back({std::move(w), h.from, h.move, Clock::now() + kMoveTimeout});
  pushHandoff(h.from, ready);
}

void ServerCore::finishMove(ServerWorld& w, Status status) {
  ServerWorld::MoveJob job = *w.moving;
  w.moving.reset();
  ReplyHeader h = job.header;
  h.tick = w.tick;
  release(job.envelopeKey, job.sender, job.charge);
  if (!status.ok()) {
    // It stays: stepped on here, and what waited for the move is applied here (drainWaiting).
    ++counters_.errors;
    h.status = Status::Error(status.code, "move_world: " + status.message);
    pushHandoff(job.target,
                control(wire::HandoffKind::Abort, w.id, config_.serverId, job.target, job.move));
    pushReply(job.envelopeKey, job.envelopeSeq, protocol::encodeReply(h));
    return;
  }
  // It went: the target holds it (Done). Nothing of it is published or kept here any more;
  // commands that waited for the move are answered Moved (the SDK sends them to the new
  // owner, which holds the world by the time they reach it).
  const uint32_t id = w.id;
  std::deque<Incoming> waiting = std::move(w.waiting);
  if (w.store) {
    Status s = w.store->remove();
    if (!s.ok()) log(true, "world " + std::to_string(id) + " moved away; its files: " + s.message);
  }
  log(false, "world " + std::to_string(id) + " '" + w.name + "': moved to daemon " +
                 std::to_string(job.target) + " at tick " + std::to_string(w.tick));
  letGo(id, job.target);
  pushReply(job.envelopeKey, job.envelopeSeq, protocol::encodeReply(h));
  for (Incoming& in : waiting) applyNow(in);
}

void ServerCore::expireMoves() {
  // Every tick: nothing allocated unless a move is due (finishMove erases from worlds_, so the
  // due ones are listed first).
  const auto now = Clock::now();
  std::vector<uint32_t> due;
  for (const auto& [id, w] : worlds_)
    if (w->moving && now >= w->moving->deadline) due.push_back(id);
  for (uint32_t id : due) {
    ServerWorld* w = world(id);
    if (w->moving->committed) {
      // Committed and no Done: the world is the target's (it never runs here again); if the
      // target died meanwhile, it is lost (docs/SERVER.md "Moving a world").
      log(true, "world " + std::to_string(id) + ": daemon " + std::to_string(w->moving->target) +
                    " did not confirm the move within " + std::to_string(kMoveTimeout.count()) +
                    " s; it is that daemon's");
      finishMove(*w, Status::Ok());
      continue;
    }
    finishMove(
        *w, Status::Error(Code::IncorrectState, "daemon " + std::to_string(w->moving->target) +
                                                    " did not take the world within " +
                                                    std::to_string(kMoveTimeout.count()) +
                                                    " s (is it running, with [cluster] enabled?)"));
  }
  std::erase_if(prepared_, [&](const Prepared& p) { return now >= p.deadline; });
}

void ServerCore::letGo(uint32_t id, uint64_t to) {
  movedAway_.push_back(id);  // its writers go after the replies (processPending)
  worlds_.erase(id);
  movedOut_[id] = to;
  keepMovedOut();
}

void ServerCore::announceHere(uint32_t id) {
  ReliableMessage added;
  added.type = ReliableMessage::Type::WorldAdded;
  added.world = id;
  out_.pushReliable(std::move(added));
}

void ServerCore::keepMovedOut() {
  if (!durable()) return;
  std::string text;
  for (const auto& [world, daemon] : movedOut_)
    text += std::to_string(world) + " " + std::to_string(daemon) + "\n";
  Status s = writeFileAtomically(
      config_.dataDir + "/moved_out",
      std::span<const uint8_t>(reinterpret_cast<const uint8_t*>(text.data()), text.size()));
  if (!s.ok()) log(true, "the worlds moved away are not kept on disk: " + s.message);
}

bool ServerCore::heldForSubscribers(ServerWorld& w) {
  if (w.awaitSubscribers == 0) return false;
  uint32_t matched = 0;
  {
    std::lock_guard<std::mutex> lock(subscribersMutex_);
    auto it = subscribers_.find(streamKey(w.id, 0));
    if (it != subscribers_.end()) matched = it->second.now;
  }
  if (matched < w.awaitSubscribers && Clock::now() < w.holdUntil) return true;
  w.awaitSubscribers = 0;
  return false;
}

}  // namespace phys::server
