// ServerCore::apply: every command of the protocol, checked against the server's state,
// applied all-or-nothing, answered with a reply payload.
//
// World edits (and Batches of them) run in two passes: a check pass (ids live, presets
// exist, definitions convert) that changes nothing, then the apply pass. Before the apply
// pass the world is saved with World::saveSnapshot; if an engine call still fails midway
// (e.g. engine validation of a body definition, or a batch item that refers to a body an
// earlier item removed) the world is restored from it, so nothing changes.
#include <array>
#include <cinttypes>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <set>
#include <string>

#include "phys/protocol/topics.h"
#include "phys/protocol/convert.h"
#include "phys/protocol/requests.h"
#include "phys/protocol/validate.h"
#include "phys/scene/scene.h"
#include "phys/server/core.h"
#include "internal.h"

namespace phys::server {

namespace {

using protocol::ReplyHeader;
namespace fs = std::filesystem;

std::string hex(uint64_t v) {
  char buf[24];
  std::snprintf(buf, sizeof buf, "0x%" PRIx64, v);
  return buf;
}

Status err(Code c, std::string m) {
  return Status::Error(c, std::move(m));
}

Status fromPhys(const phys::Status& s, const std::string& path) {
  Status out = protocol::fromPhys(s);
  if (!out.ok()) out.message = path + ": " + out.message;
  return out;
}

/// Ids created by one command (a batch concatenates).
struct CreatedIds {
  std::vector<uint64_t> bodies, joints;
};

bool liveJoint(const phys::World& w, uint64_t packed) {
  phys::JointDef d;
  phys::JointState s;
  return w.getJoint(phys::JointId::fromPacked(packed), &d, &s).ok();
}

/// Names are checked by the codec to be plain ([A-Za-z0-9._-], no leading dot).
std::string underDir(const std::string& dir, const std::string& name, const char* ext) {
  return (fs::path(dir) / (name + ext)).string();
}

}  // namespace

phys::BodyDef bodyDefOf(const phys::World& w, phys::BodyId id) {
  phys::BodyDef d;
  w.getBodyDef(id, &d);
  return d;
}

// Per-command state (the core, the sender, the target world, the reply) and the handler of
// each request: Context::kHandlers, indexed by wire::Request, says which function applies it.
struct ServerCore::Context {
  /// Whether a handler answered the command, or left it to a job that answers when it ends.
  enum class Answer { Now, Later };
  using Apply = Answer (Context::*)(const wire::Command& c);
  /// A world edit: dryRun, only the checks that need the server's state, nothing changes;
  /// otherwise applies it (editAll rolls back on error). p: its path in messages.
  using Edit = Status (Context::*)(const void* table, const std::string& p, bool dryRun);
  struct Handler {
    wire::Request type;
    Apply apply;
    // World edits (batchable requests) only:
    Edit edit;
    bool (*present)(const void* table);  ///< it carries the lists and tables it must have
    size_t (*calls)(const void* table);  ///< engine calls it makes (each applies or not)
    bool motion;  ///< moves bodies only: cannot fail once checked (no rollback needed)
  };
  /// The handler of a request kind (kinds past wire::Request::MAX: unsupported()).
  static const Handler& handler(wire::Request type);

  Context(ServerCore& c, ReplyHeader h) : core(c), header(std::move(h)) {}

  ServerCore& core;
  ReplyHeader header;  ///< header.status is the command's status
  CreatedIds ids;
  uint64_t envelopeKey = 0, principal = 0;
  bool proven = false;
  ServerWorld* sw = nullptr;  ///< the target world (null: none, or destroyed by the command)
  Bytes reply;                ///< a reply of its own kind, when Ok; else finish() encodes one
  /// Hulls built for this message (a hull table that many shapes share is built once) and
  /// the body definitions converted by the check pass, by SpawnBodies table, for the apply
  /// pass.
  protocol::HullCache hulls;
  std::map<const void*, std::vector<phys::BodyDef>> converted;
  /// The hulls of this message built from their points, by points object (the protocol
  /// carries points; a world would build each shape's own).
  phys::HullBuildCache builtHulls;

  /// A body definition's hulls built for its world (shapes of one hull table share one).
  Status buildHulls(phys::BodyDef* d, const std::string& path) {
    for (size_t i = 0; i < d->shapes.size(); ++i) {
      phys::ShapeGeom& g = d->shapes[i].geom;
      if (g.type != phys::ShapeType::Hull) continue;
      std::string error;
      auto built = phys::buildHull(g.hull, &error, &builtHulls);
      if (!built)
        return err(Code::InvalidArgument, path + ".shapes[" + std::to_string(i) +
                                              "].convex_hull.points do not make a hull: " + error);
      g.hull = std::move(built);
    }
    return Status::Ok();
  }

  Status checkBodies(const phys::World& w, const flatbuffers::Vector<uint64_t>* v,
                     const std::string& path) {
    if (!v) return Status::Ok();
    for (uint32_t i = 0; i < v->size(); ++i)
      if (!w.isValid(phys::BodyId::fromPacked(v->Get(i))))
        return err(Code::NotFound,
                   path + "[" + std::to_string(i) + "] " + hex(v->Get(i)) + " is not a live body");
    return Status::Ok();
  }
  template <class Item>
  Status checkItems(const phys::World& w, const flatbuffers::Vector<const Item*>* v,
                    const std::string& path) {
    if (!v) return Status::Ok();
    for (uint32_t i = 0; i < v->size(); ++i)
      if (!w.isValid(phys::BodyId::fromPacked(v->Get(i)->id())))
        return err(Code::NotFound, path + "[" + std::to_string(i) + "].id " + hex(v->Get(i)->id()) +
                                       " is not a live body");
    return Status::Ok();
  }

  /// The world point of a force: the centre of mass, a world point or a body-frame point.
  static Status forcePoint(const phys::World& w, phys::BodyId id, const wire::BodyForce& f,
                           wire::PointFrame frame, phys::Vec3* out) {
    phys::BodyState s;
    phys::Status st = w.getBody(id, &s);
    if (!st.ok()) return protocol::fromPhys(st);
    switch (frame) {
      case wire::PointFrame::World:
        *out = protocol::toPhys(f.point());
        break;
      case wire::PointFrame::Local:
        *out = phys::apply(phys::Transform{s.position, s.rotation}, protocol::toPhys(f.point()));
        break;
      default:
        *out = s.centerOfMass;
        break;
    }
    return Status::Ok();
  }

  /// One world edit (a batchable request): its handler's edit (dryRun: checks only).
  Status edit(wire::Request type, const void* table, const std::string& path, bool dryRun) {
    const std::string p = path + protocol::requestName(type);
    const Handler& h = handler(type);
    // The codec requires these lists (non-empty); checked again so that a gap there can
    // never become a null dereference here.
    if (!table || (h.present && !h.present(table)))
      return err(Code::Malformed, p + " lacks a required field");
    if (!h.edit) return err(Code::Internal, p + " is not a world edit");
    return (this->*h.edit)(table, p, dryRun);
  }

  /// Edits all-or-nothing: check every item, snapshot, apply, roll back on failure.
  Status editAll(const std::vector<std::pair<wire::Request, const void*>>& items,
                 const std::vector<std::string>& paths) {
    uint64_t newBodies = 0, newJoints = 0;
    for (size_t i = 0; i < items.size(); ++i) {
      Status s = edit(items[i].first, items[i].second, paths[i], true);
      if (!s.ok()) return s;
      if (items[i].first == wire::Request::SpawnBodies)
        newBodies += static_cast<const wire::SpawnBodies*>(items[i].second)->bodies()->size();
      if (items[i].first == wire::Request::AddJoints)
        newJoints += static_cast<const wire::AddJoints*>(items[i].second)->joints()->size();
    }
    if (newBodies + newJoints > 0) {
      Status s = core.checkGrowth(sw, newBodies, newJoints, paths[0] + "this command");
      if (!s.ok()) return s;
    }
    // One engine call either applies or changes nothing: no snapshot needed (the common
    // interactive case: one force, one pose). Nor for motion edits alone (poses, velocities,
    // forces, impulses, torques), which cannot fail once checked: their bodies stay live and
    // their values were validated. Otherwise save the world to roll back to; a small edit of
    // a large world then costs a copy of it, so only edits that need it pay.
    size_t calls = 0;
    bool motionOnly = true;
    for (auto& [type, table] : items) {
      const Handler& h = handler(type);
      calls += h.calls ? h.calls(table) : 1;
      motionOnly &= h.motion;
    }
    const bool rollback = calls > 1 && !motionOnly;
    std::vector<uint8_t> saved;
    phys::Status snap = rollback ? sw->world->saveSnapshot(&saved) : phys::Status::Ok();
    const std::string preset = sw->preset;
    const bool infoDirty = sw->infoDirty;
    for (size_t i = 0; i < items.size(); ++i) {
      Status s = edit(items[i].first, items[i].second, paths[i], false);
      if (s.ok()) continue;
      ids = {};
      if (calls <= 1) return s;  // nothing was applied
      if (!rollback)
        return err(Code::Internal, s.message + " (a motion edit failed after its checks; the " +
                                       "items before it were applied)");
      if (!snap.ok())
        return err(Code::Internal, s.message + " (and the world could not be saved before the " +
                                       "command, so it may be partly applied: " + snap.message +
                                       ")");
      phys::Status back = sw->world->restoreSnapshot(saved.data(), saved.size());
      if (!back.ok())
        return err(Code::Internal, s.message + " (rollback failed: " + back.message + ")");
      sw->preset = preset;
      sw->infoDirty = infoDirty;
      return s;
    }
    sw->frameDirty = true;
    if (sw->infoDirty) ++sw->revision;
    return Status::Ok();
  }

  /// The reply: the handler's own, or the header (with the ids created, for the requests
  /// that list them). Counts the command's status.
  Bytes finish(wire::Request type) {
    const Status& st = header.status;
    core.lastStatus_ = st;
    if (!st.ok()) ++core.counters_.errors;
    if (sw && header.tick == 0) header.tick = sw->tick;
    if (!reply.empty() && st.ok()) return std::move(reply);
    if (st.ok() && (!ids.bodies.empty() || !ids.joints.empty() ||
                    protocol::requestInfo(type).has(protocol::kIdsReply)))
      return protocol::encodeIdsReply(header, ids.bodies, ids.joints);
    return protocol::encodeReply(header);
  }

  // Requests ---------------------------------------------------------------------------------

  Answer hello(const wire::Command& c) {
    Status& st = header.status;
    auto* r = c.request_as_Hello();
    if (r->protocol_version() != protocol::kProtocolVersion) {
      st = err(Code::Unsupported, "hello.protocol_version " +
                                      std::to_string(r->protocol_version()) +
                                      " is not supported; this server speaks " +
                                      std::to_string(protocol::kProtocolVersion));
      return Answer::Now;
    }
    protocol::HelloInfo info;
    info.serverName = core.config_.serverName;
    info.serverVersion = PHYSD_VERSION;
    info.features = {"batch", "snapshot", "engine_snapshot", "load_scene", "run", "query_state"};
    info.limits = core.config_.limits;
    info.clientProven = proven;
    reply = protocol::encodeHelloReply(header, info);
    return Answer::Now;
  }

  Answer createWorld(const wire::Command& c) {
    Status& st = header.status;
    auto* r = c.request_as_CreateWorld();
    if (!r->name()) {
      st = err(Code::Malformed, "create_world.name is missing");
      return Answer::Now;
    }
    const std::string name = r->name()->str();
    for (auto& [id, w] : core.worlds_)
      if (w->name == name) {
        st = err(Code::InvalidArgument,
                 "create_world.name '" + name + "' is taken by world " + std::to_string(id));
        return Answer::Now;
      }
    for (auto& [id, d] : core.damaged_)
      if (d.name == name) {
        st = err(Code::InvalidArgument, "create_world.name '" + name +
                                            "' is taken by world " + std::to_string(id) +
                                            " (kept on disk, not restored: damaged)");
        return Answer::Now;
      }
    if (core.worlds_.size() >= core.config_.maxWorlds) {
      st = err(Code::ResourceExhausted,
               "this server holds at most " + std::to_string(core.config_.maxWorlds) + " worlds");
      return Answer::Now;
    }
    st = core.checkGrowth(nullptr, 0, 0, "create_world");
    if (!st.ok()) return Answer::Now;
    std::string preset =
        r->preset() && r->preset()->size() ? r->preset()->str() : core.defaultPreset_;
    auto it = core.presets_.find(preset);
    if (it == core.presets_.end()) {
      st = err(Code::NotFound, "create_world.preset '" + preset + "' is not a preset");
      return Answer::Now;
    }
    phys::WorldDef def;
    def.backend = core.config_.backend;
    if (r->backend() && r->backend()->size() &&
        !phys::parseBackend(r->backend()->str(), &def.backend)) {
      // The codec rejects it first; checked again for commands applied without it.
      st = err(Code::InvalidArgument,
               "create_world.backend must be \"cpu\", \"gpu\" or \"auto\" (or empty: the "
               "server's default), got \"" +
                   r->backend()->str() + "\"");
      return Answer::Now;
    }
    def.solver = it->second.settings;
    if (r->gravity()) def.gravity = protocol::toPhys(*r->gravity());
    if (r->time_step() > 0) def.timeStep = r->time_step();
    def.sleep.enabled = r->sleep();
    if (core.config_.cluster &&
        core.nextWorldId_ >= protocol::worldIdsEndOf(core.config_.serverId)) {
      st = err(Code::ResourceExhausted,
               "create_world: this daemon has used every world id of its range (server.id " +
                   std::to_string(core.config_.serverId) + ")");
      return Answer::Now;
    }
    auto w = core.makeWorld(name, preset, def);
    w->id = core.nextWorldId_++;
    w->ephemeral = r->ephemeral();
    w->owner = core.startupCreate_ ? 0 : principal;
    // On a secure daemon the owner is an identity, which DDS Security vouches for.
    w->ownerProven = !core.startupCreate_ && !core.config_.identities && proven;
    if (r->editors()) w->editors.assign(r->editors()->begin(), r->editors()->end());
    w->shared = r->shared();
    header.world = w->id;
    ServerWorld& made = *w;
    core.worlds_[w->id] = std::move(w);
    if (core.durable() && !made.ephemeral && !core.replaying_) {
      // Its directory and first checkpoint before the reply names it.
      st = core.createStore(made);
      if (!st.ok()) {
        st.message = "create_world: " + st.message;
        core.worlds_.erase(made.id);
        header.world = 0;
      }
    }
    return Answer::Now;
  }

  Answer destroyWorld(const wire::Command&) {
    Status& st = header.status;
    ReliableMessage m;
    m.type = ReliableMessage::Type::WorldRemoved;
    m.world = sw->id;
    header.tick = sw->tick;
    if (sw->store) {
      st = sw->store->remove();
      if (!st.ok()) return Answer::Now;
    }
    core.worlds_.erase(sw->id);
    sw = nullptr;
    core.out_.pushReliable(std::move(m));
    return Answer::Now;
  }

  Answer resetWorld(const wire::Command&) {
    Status& st = header.status;
    phys::WorldDef def = sw->world->def();
    sw->world = std::make_unique<phys::World>(def);
    sw->tick = 0;
    sw->accumulator = 0;
    ++sw->revision;
    sw->framesReplaced();  // a new world: subscribers start from a keyframe
    sw->infoDirty = sw->frameDirty = true;
    st = core.durableReplaced(*sw, "reset_world");
    return Answer::Now;
  }

  Answer listWorlds(const wire::Command&) {
    auto list = core.summaries();
    reply = protocol::encodeWorldListReply(header, list);
    return Answer::Now;
  }

  Answer loadScene(const wire::Command& c) {
    Status& st = header.status;
    auto* r = c.request_as_LoadScene();
    if (!core.current_) {  // applied directly (tests): loaded now
      st = core.loadScene(*sw, r, "", /*forReply=*/true, &ids.bodies, &ids.joints);
      if (!st.ok()) ids = {};
      return Answer::Now;
    }
    // From the queue: parsed, checked and built on a loader thread while the other worlds
    // tick; the world waits for it (as for a Step job), advance() swaps it in and answers.
    st = core.checkGrowth(nullptr, 0, 0, "load_scene");
    if (st.ok() && !r->json() && !(r->scene_name() && r->scene_name()->size()))
      st = err(Code::Malformed, "load_scene needs json or scene_name");
    // Each loader may build a world as large as the budgets allow: how many build at once
    // bounds the memory of loads in flight.
    core.reapLoaders();
    if (st.ok() && core.loaders_.size() >= core.config_.maxConcurrentLoads)
      st = err(Code::ResourceExhausted,
               "load_scene: " + std::to_string(core.loaders_.size()) +
                   " scenes are being loaded already, the limit is " +
                   std::to_string(core.config_.maxConcurrentLoads) +
                   " (server.max_concurrent_loads); retry after their replies");
    if (!st.ok()) return Answer::Now;
    auto task = std::make_shared<LoadTask>();
    task->request = core.sceneRequest(*sw, r, "", /*forReply=*/true);
    ServerWorld::LoadJob job;
    job.task = task;
    job.header = header;
    job.envelopeKey = core.current_->envelopeKey;
    job.envelopeSeq = core.current_->envelopeSeq;
    job.sender = core.current_->sender;
    job.charge = core.queueCharge(*core.current_);
    core.startLoad(task);  // first: if the thread cannot start, nothing waits for it
    sw->load = std::move(job);
    core.deferred_ = true;
    return Answer::Later;
  }

  Answer step(const wire::Command& c) {
    Status& st = header.status;
    const uint64_t n = c.request_as_Step()->count();
    const uint64_t bodies = std::max<uint64_t>(1, uint64_t(sw->world->bodyCount()));
    if (n * bodies > core.config_.limits.maxBodyStepsPerCommand) {
      st = err(Code::ResourceExhausted,
               "step.count " + std::to_string(n) + " x " + std::to_string(bodies) +
                   " bodies is " + std::to_string(n * bodies) +
                   " body steps, the limit is " +
                   std::to_string(core.config_.limits.maxBodyStepsPerCommand) +
                   " (max_body_steps_per_command); step in smaller counts");
      return Answer::Now;
    }
    if (!core.current_) {  // applied directly (tests, start-up): all steps now
      st = core.stepWorld(sw->id, n);
      header.tick = sw->tick;
      return Answer::Now;
    }
    // From the queue: a slice now; what is left runs a slice per tick, between other
    // commands and worlds, and answers when done (or when a Pause ends it). Its steps are
    // stored ahead (a Lease, synced with the tick's commands) before the first is taken.
    bool leased = false;
    Status ls = core.leaseTo(*sw, sw->tick + n, /*syncNow=*/false, &leased);
    if (!ls.ok()) {
      st = err(ls.code, "step: not stored: " + ls.message + "; the world did not step");
      return Answer::Now;
    }
    ServerWorld::StepJob job;
    job.stored = !leased;
    job.requested = job.remaining = n;
    job.header = header;
    job.envelopeKey = core.current_->envelopeKey;
    job.envelopeSeq = core.current_->envelopeSeq;
    job.sender = core.current_->sender;
    job.charge = core.queueCharge(*core.current_);
    sw->job = job;
    core.deferred_ = true;  // advance() runs its slices, the first one right after this command
    return Answer::Later;
  }

  Answer moveWorld(const wire::Command& c) {
    Status& st = header.status;
    const uint64_t to = c.request_as_MoveWorld()->daemon();
    if (!core.config_.cluster)
      st = err(Code::Unsupported, "move_world: this daemon is not in a cluster ([cluster] "
                                  "enabled, docs/SERVER.md \"Several daemons\")");
    else if (to == core.config_.serverId)
      st = err(Code::InvalidArgument, "move_world.daemon " + std::to_string(to) +
                                          " is the daemon that holds the world");
    else if (!core.current_)
      st = err(Code::IncorrectState, "move_world: only from the command queue");
    if (!st.ok()) return Answer::Now;
    st = core.startMove(*sw, to, header);
    if (!st.ok()) return Answer::Now;
    core.deferred_ = true;  // answered when the target is ready (or the move fails)
    return Answer::Later;
  }

  Answer run(const wire::Command& c) {
    float rate = c.request_as_Run()->rate_hz();
    sw->mode = rate > 0 ? RunMode::RealTime : RunMode::AsFastAsPossible;
    if (rate > 0) sw->rateHz = rate;
    sw->accumulator = 0;
    return Answer::Now;
  }

  Answer subscribe(const wire::Command& c) {
    Status& st = header.status;
    auto* r = c.request_as_Subscribe();
    // Whose interests these are: the participant's (all its client ids), or the client id's
    // for a command without one (in-process callers).
    const uint64_t sender = core.current_ ? core.current_->sender : 0;
    auto mine = [&](const ServerWorld::Interest& in) {
      return sender ? in.sender == sender : in.sender == 0 && in.client == envelopeKey;
    };
    const size_t held = size_t(std::count_if(sw->interests.begin(), sw->interests.end(),
                                             [&](const auto& e) { return mine(e.second); }));
    const bool editor = sw->owner == 0 || sw->shared || principal == sw->owner ||
                        std::find(sw->editors.begin(), sw->editors.end(), principal) !=
                            sw->editors.end();
    const size_t open = editor ? ServerWorld::kMaxInterests
                               : ServerWorld::kMaxInterests - ServerWorld::kInterestsForEditors;
    if (held >= core.config_.maxInterestsPerClient) {
      st = err(Code::ResourceExhausted,
               "subscribe: this client holds " + std::to_string(held) +
                   " interests in this world, the most one client may "
                   "(server.max_interests_per_client); unsubscribe one first");
      return Answer::Now;
    }
    if (sw->interests.size() >= open) {
      st = err(Code::ResourceExhausted,
               "subscribe: this world has " + std::to_string(sw->interests.size()) +
                   " interests, the most it keeps" +
                   (editor ? std::string()
                           : " for clients that may not change it (the other " +
                                 std::to_string(ServerWorld::kInterestsForEditors) +
                                 " are kept for its owner and editors)") +
                   "; unsubscribe one first");
      return Answer::Now;
    }
    ServerWorld::Interest in;
    if (r->bodies()) {
      in.ids.assign(r->bodies()->begin(), r->bodies()->end());
      std::sort(in.ids.begin(), in.ids.end());
    } else if (r->region_min() && r->region_max()) {
      in.region = true;
      in.lo = protocol::toPhys(*r->region_min());
      in.hi = protocol::toPhys(*r->region_max());
    } else {  // the codec refuses it first
      st = err(Code::InvalidArgument, "subscribe: give bodies or a region");
      return Answer::Now;
    }
    const uint32_t id = sw->nextInterest++;
    in.client = envelopeKey;
    in.sender = sender;
    sw->interests.emplace(id, std::move(in));
    ReliableMessage m;
    m.type = ReliableMessage::Type::InterestAdded;
    m.world = sw->id;
    m.key = id;
    core.out_.pushReliable(std::move(m));
    sw->frameDirty = true;
    header.tick = sw->tick;
    reply = protocol::encodeInterestReply(header, id, protocol::stateTopic(sw->id, id));
    return Answer::Now;
  }

  Answer unsubscribe(const wire::Command& c) {
    Status& st = header.status;
    const uint32_t id = c.request_as_Unsubscribe()->interest();
    auto it = sw->interests.find(id);
    if (it == sw->interests.end()) {
      st = err(Code::NotFound, "unsubscribe.interest " + std::to_string(id) +
                                   " is not an interest of this world");
      return Answer::Now;
    }
    // Its subscriber, or whoever may change the world.
    if (it->second.client != envelopeKey) {
      st = core.checkAccess(*sw, c, principal, envelopeKey, proven);
      if (!st.ok()) return Answer::Now;
    }
    sw->interests.erase(it);
    ReliableMessage m;
    m.type = ReliableMessage::Type::InterestRemoved;
    m.world = sw->id;
    m.key = id;
    core.out_.pushReliable(std::move(m));
    return Answer::Now;
  }

  Answer pause(const wire::Command&) {
    sw->mode = RunMode::Paused;
    sw->accumulator = 0;
    return Answer::Now;
  }

  Answer setAccess(const wire::Command& c) {
    auto* r = c.request_as_SetAccess();
    sw->editors.clear();
    if (r->editors()) sw->editors.assign(r->editors()->begin(), r->editors()->end());
    sw->shared = r->shared();
    return Answer::Now;
  }

  Answer queryState(const wire::Command& c) {
    Status& st = header.status;
    auto* r = c.request_as_QueryState();
    std::vector<wire::BodyState> out;
    const uint32_t maxFrame = core.config_.limits.maxBodiesPerFrame;
    uint32_t total = 0;
    phys::BodyState bs;
    if (r->bodies() && r->bodies()->size() > 0) {
      auto* v = r->bodies();
      Status s = checkBodies(*sw->world, v, "query_state.bodies");
      if (!s.ok()) {
        st = s;
        return Answer::Now;
      }
      if (v->size() > maxFrame) {
        st = err(Code::ResourceExhausted,
                 "query_state.bodies asks for " + std::to_string(v->size()) +
                     " bodies; one reply holds at most " + std::to_string(maxFrame) +
                     " (max_bodies_per_frame)");
        return Answer::Now;
      }
      total = v->size();
      for (uint32_t i = 0; i < v->size(); ++i) {
        sw->world->getBody(phys::BodyId::fromPacked(v->Get(i)), &bs);
        out.push_back(protocol::toWire(bs));
      }
    } else {
      std::vector<phys::BodyId> all = sw->world->bodies();
      total = uint32_t(all.size());
      uint32_t count = r->max_count() == 0 ? maxFrame : std::min(r->max_count(), maxFrame);
      for (uint32_t i = r->first(); i < all.size() && out.size() < count; ++i) {
        sw->world->getBody(all[i], &bs);
        out.push_back(protocol::toWire(bs));
      }
    }
    header.tick = sw->tick;
    // Stamped as a state frame is (queueStream): the wall clock once the states are read.
    const auto stamp = std::chrono::system_clock::now().time_since_epoch();
    reply = protocol::encodeStateReply(
        header, sw->world->time(), total, out,
        uint64_t(std::chrono::duration_cast<std::chrono::nanoseconds>(stamp).count()),
        sw->epoch);
    return Answer::Now;
  }

  Answer getWorld(const wire::Command&) {
    header.tick = sw->tick;
    reply = protocol::encodeWorldSettingsReply(header, sw->world->def(), sw->preset);
    return Answer::Now;
  }

  Answer getDefinitions(const wire::Command& c) {  // GetBodies, GetJoints
    header.status = core.readDefinitions(*sw, c, &header, &reply);
    return Answer::Now;
  }

  Answer saveSnapshot(const wire::Command& c) {
    Status& st = header.status;
    auto* r = c.request_as_SaveSnapshot();
    const std::string file = r->file() ? r->file()->str() : "";
    if (!file.empty() && core.config_.snapshotDir.empty()) {
      st = err(Code::Unsupported, "save_snapshot.file: this server has no snapshot directory");
      return Answer::Now;
    }
    protocol::SnapshotData data;
    phys::Status ps = sw->world->saveSnapshot(&data.engineState);
    if (!ps.ok()) {
      st = fromPhys(ps, "save_snapshot");
      st.code = Code::IncorrectState;
      return Answer::Now;
    }
    data.name = sw->name;
    data.gravity = sw->world->def().gravity;
    data.timeStep = sw->world->def().timeStep;
    data.solver = sw->world->def().solver;
    data.settings = protocol::WorldOverrides::from(sw->world->def());
    data.tick = sw->tick;
    data.time = sw->world->time();
    Bytes snap = protocol::encodeSnapshot(data);
    // The reply adds little around the snapshot bytes; keep a margin for it.
    if (r->return_bytes() && snap.size() + 1024 > core.config_.limits.maxMessageBytes) {
      st = err(Code::ResourceExhausted,
               "save_snapshot: the snapshot is " + std::to_string(snap.size()) +
                   " bytes, more than a reply holds (max_message_bytes); save it to a file");
      return Answer::Now;
    }
    if (!file.empty()) {
      std::error_code ec;
      fs::create_directories(core.config_.snapshotDir, ec);
      const std::string path = underDir(core.config_.snapshotDir, file, "");
      // The directory's quota: files and bytes after this save (a file of the same name is
      // replaced, so it does not count).
      uint64_t files = 1, bytes = snap.size();
      for (const auto& e : fs::directory_iterator(core.config_.snapshotDir, ec)) {
        std::error_code fe;
        if (!e.is_regular_file(fe) || e.path().filename() == file) continue;
        ++files;
        bytes += e.file_size(fe);
      }
      if (files > core.config_.maxSnapshotFiles || bytes > core.config_.maxSnapshotBytes) {
        st = err(Code::ResourceExhausted,
                 "save_snapshot.file: the snapshot directory would hold " +
                     std::to_string(files) + " files and " + std::to_string(bytes) +
                     " bytes, the limits are " + std::to_string(core.config_.maxSnapshotFiles) +
                     " files (server.max_snapshot_files) and " +
                     std::to_string(core.config_.maxSnapshotBytes) +
                     " bytes (server.max_snapshot_mb); overwrite an old file instead");
        return Answer::Now;
      }
      // Written aside, synced and renamed (as checkpoints are): a failed write never leaves
      // a torn snapshot.
      if (Status w = writeFileAtomically(path, snap); !w.ok()) {
        st = err(Code::Internal, "save_snapshot.file: cannot write '" + file + "': " + w.message);
        return Answer::Now;
      }
    }
    header.tick = sw->tick;
    reply = protocol::encodeSnapshotReply(
        header,
        r->return_bytes() ? std::span<const uint8_t>(snap) : std::span<const uint8_t>(), file);
    return Answer::Now;
  }

  Answer restoreSnapshot(const wire::Command& c) {
    Status& st = header.status;
    protocol::Decoded<wire::Snapshot> decoded;
    st = readSnapshot(c.request_as_RestoreSnapshot(), &decoded);
    if (!st.ok()) return Answer::Now;
    if (!decoded->engine_state()) {
      // The portable form's counts, before anything is converted or built.
      const uint64_t nb = decoded->bodies() ? decoded->bodies()->size() : 0;
      const uint64_t nj = decoded->joints() ? decoded->joints()->size() : 0;
      if (nb + nj > protocol::maxIdsPerReply(core.config_.limits)) {
        st = err(Code::ResourceExhausted,
                 "restore_snapshot: the snapshot has " + std::to_string(nb) + " bodies and " +
                     std::to_string(nj) + " joints; one reply lists at most " +
                     std::to_string(protocol::maxIdsPerReply(core.config_.limits)) +
                     " new ids (max_ids_per_reply): save it with engine state instead");
        return Answer::Now;
      }
      st = core.checkGrowth(nullptr, nb, nj, "restore_snapshot", uint64_t(sw->world->bodyCount()));
      if (!st.ok()) return Answer::Now;
    }
    protocol::SnapshotData data;
    st = protocol::toSnapshotData(*decoded, &data);
    if (!st.ok()) return Answer::Now;
    if (data.engineState.empty()) return restorePortable(data);
    // Restored aside and checked by the codec's rules before it replaces the world.
    auto scratch = std::make_unique<phys::World>(sw->world->def());
    phys::Status ps = scratch->restoreSnapshot(data.engineState.data(), data.engineState.size());
    if (!ps.ok()) {
      st = fromPhys(ps, "restore_snapshot.snapshot.engine_state");
      return Answer::Now;
    }
    core.applyPolicy(*scratch);  // the server's contact budget, whatever the snapshot says
    st = core.checkRestored(*scratch, "restore_snapshot.snapshot.engine_state");
    if (!st.ok()) return Answer::Now;
    st = core.checkGrowth(nullptr, uint64_t(scratch->bodyCount()),
                          uint64_t(scratch->jointCount()), "restore_snapshot",
                          uint64_t(sw->world->bodyCount()));
    if (!st.ok()) return Answer::Now;
    core.cancelJob(*sw, "replaced by restore_snapshot");
    sw->world = std::move(scratch);
    sw->tick = data.tick;
    sw->accumulator = 0;
    ++sw->revision;
    sw->framesReplaced();  // a new world: subscribers start from a keyframe
    sw->infoDirty = sw->frameDirty = true;
    header.tick = sw->tick;
    st = core.durableReplaced(*sw, "restore_snapshot");
    return Answer::Now;
  }

  /// RestoreSnapshot's snapshot, decoded: a file of the snapshot directory, or the bytes.
  Status readSnapshot(const wire::RestoreSnapshot* r,
                      protocol::Decoded<wire::Snapshot>* decoded) {
    if (r->file() && r->file()->size()) {
      const std::string path = underDir(core.config_.snapshotDir, r->file()->str(), "");
      if (core.config_.snapshotDir.empty() || !fs::exists(path))
        return err(Code::NotFound,
                   "restore_snapshot.file '" + r->file()->str() + "' is not a snapshot file");
      // The memory budget, before reading.
      if (Status s = core.checkGrowth(nullptr, 0, 0, "restore_snapshot"); !s.ok()) return s;
      std::error_code ec;
      const uintmax_t size = fs::file_size(path, ec);
      if (ec || size > core.config_.maxSnapshotBytes)
        return err(ec ? Code::NotFound : Code::ResourceExhausted,
                   "restore_snapshot.file '" + r->file()->str() + "' " +
                       (ec ? "cannot be read"
                           : "is " + std::to_string(size) + " bytes, more than " +
                                 std::to_string(core.config_.maxSnapshotBytes) +
                                 " (server.max_snapshot_mb)"));
      std::ifstream f(path, std::ios::binary);
      std::vector<uint8_t> bytes(size);
      f.read(reinterpret_cast<char*>(bytes.data()), std::streamsize(size));
      if (!f)
        return err(Code::NotFound,
                   "restore_snapshot.file '" + r->file()->str() + "' cannot be read");
      // A file is not a message: its own size bound (server.max_snapshot_mb).
      protocol::Limits fileLimits = core.config_.limits;
      fileLimits.maxMessageBytes =
          uint32_t(std::min<uint64_t>(core.config_.maxSnapshotBytes, UINT32_MAX));
      fileLimits.maxTables = UINT32_MAX;  // then bytes / 8 + 16, as for any payload
      *decoded = protocol::decodeSnapshot(std::move(bytes), fileLimits);
      Status s = decoded->status;
      if (!s.ok()) s.message = "restore_snapshot.file: " + s.message;
      return s;
    }
    if (!r->snapshot()) return err(Code::Malformed, "restore_snapshot needs snapshot or file");
    *decoded = protocol::decodeSnapshot(
        std::span<const uint8_t>(r->snapshot()->data(), r->snapshot()->size()),
        core.config_.limits);
    return decoded->status;
  }

  /// RestoreSnapshot's portable form: a fresh world from the definitions, saved ids mapped to
  /// new ones (the reply lists them), with the snapshot's settings (those it lacks: this
  /// world's).
  Answer restorePortable(protocol::SnapshotData& data) {
    Status& st = header.status;
    phys::WorldDef def = sw->world->def();
    def.gravity = data.gravity;
    def.timeStep = data.timeStep;
    def.solver = data.solver;
    protocol::applyOverrides(data.settings, &def);
    st = protocol::checkWorldSettings(def, core.config_.limits, "restore_snapshot.snapshot");
    for (size_t i = 0; st.ok() && i < data.bodies.size(); ++i) {
      const std::string bp = "restore_snapshot.snapshot.bodies[" + std::to_string(i) + "].def";
      st = protocol::checkBodyDef(data.bodies[i].def, core.config_.limits, bp);
      if (st.ok()) st = buildHulls(&data.bodies[i].def, bp);
    }
    for (size_t i = 0; st.ok() && i < data.joints.size(); ++i)
      st = protocol::checkJointDef(data.joints[i].def, core.config_.limits,
                                   "restore_snapshot.snapshot.joints[" + std::to_string(i) +
                                       "].def");
    if (!st.ok()) return Answer::Now;
    if (phys::Status ps = phys::World::validate(def); !ps.ok()) {
      st = fromPhys(ps, "restore_snapshot.snapshot");
      return Answer::Now;
    }
    auto fresh = std::make_unique<phys::World>(def);
    std::map<uint64_t, phys::BodyId> map;
    for (size_t i = 0; i < data.bodies.size(); ++i) {
      phys::BodyId id;
      phys::Status ps = fresh->createBody(data.bodies[i].def, &id);
      if (!ps.ok()) {
        st = fromPhys(ps, "restore_snapshot.snapshot.bodies[" + std::to_string(i) + "]");
        return Answer::Now;
      }
      map[data.bodies[i].id] = id;
      ids.bodies.push_back(id.packed());
    }
    for (size_t i = 0; i < data.joints.size(); ++i) {
      phys::JointDef d = data.joints[i].def;
      d.bodyA = d.bodyA.isNull() ? phys::BodyId{} : map[d.bodyA.packed()];
      d.bodyB = map[d.bodyB.packed()];
      phys::JointId id;
      phys::Status ps = fresh->createJoint(d, &id);
      if (!ps.ok()) {
        st = fromPhys(ps, "restore_snapshot.snapshot.joints[" + std::to_string(i) + "]");
        return Answer::Now;
      }
      ids.joints.push_back(id.packed());
    }
    core.cancelJob(*sw, "replaced by restore_snapshot");
    sw->world = std::move(fresh);
    header.tick = data.tick;
    sw->tick = data.tick;
    ++sw->revision;
    sw->framesReplaced();  // a new world: subscribers start from a keyframe
    sw->infoDirty = sw->frameDirty = true;
    st = core.durableReplaced(*sw, "restore_snapshot");
    if (st.ok())
      reply = protocol::encodeIdsReply(header, ids.bodies, ids.joints);
    else
      ids = {};
    return Answer::Now;
  }

  Answer batch(const wire::Command& c) {
    Status& st = header.status;
    auto* v = c.request_as_Batch()->commands();
    if (!v) {
      st = err(Code::Malformed, "batch.commands is missing");
      return Answer::Now;
    }
    std::vector<std::pair<wire::Request, const void*>> items;
    std::vector<std::string> paths;
    for (uint32_t i = 0; i < v->size(); ++i) {
      items.emplace_back(v->Get(i)->request_type(), v->Get(i)->request());
      paths.push_back("batch.commands[" + std::to_string(i) + "].");
    }
    st = editAll(items, paths);
    return Answer::Now;
  }

  /// A world edit on its own: one item of editAll.
  Answer worldEdit(const wire::Command& c) {
    header.status = editAll({{c.request_type(), c.request()}}, {""});
    return Answer::Now;
  }

  Answer unsupported(const wire::Command& c) {
    header.status = err(Code::Unsupported, std::string("request ") +
                                               protocol::requestName(c.request_type()) +
                                               " is not supported");
    return Answer::Now;
  }

  // World edits ------------------------------------------------------------------------------

  Status spawnBodies(const void* table, const std::string& p, bool dryRun) {
    phys::World& w = *sw->world;
    auto* r = static_cast<const wire::SpawnBodies*>(table);
    auto* v = r->bodies();
    if (dryRun) {
      std::vector<phys::BodyDef> defs(v ? v->size() : 0);
      for (uint32_t i = 0; i < defs.size(); ++i) {
        const std::string bp = p + ".bodies[" + std::to_string(i) + "]";
        Status s = protocol::toBodyDef(*v->Get(i), &defs[i], bp, &hulls);
        if (s.ok()) s = protocol::checkBodyDef(defs[i], core.config_.limits, bp);
        if (s.ok()) s = buildHulls(&defs[i], bp);
        if (!s.ok()) return s;
      }
      converted[table] = std::move(defs);
      return Status::Ok();
    }
    // Copied, not moved: a batch may hold the same SpawnBodies table twice.
    const std::vector<phys::BodyDef>& defs = converted.at(table);
    for (uint32_t i = 0; i < defs.size(); ++i) {
      phys::BodyId id;
      phys::Status s = w.createBody(defs[i], &id);
      if (!s.ok()) return fromPhys(s, p + ".bodies[" + std::to_string(i) + "]");
      ids.bodies.push_back(id.packed());
      sw->touched.push_back(id.packed());
    }
    sw->infoDirty = true;
    return Status::Ok();
  }

  Status removeBodies(const void* table, const std::string& p, bool dryRun) {
    phys::World& w = *sw->world;
    auto* v = static_cast<const wire::RemoveBodies*>(table)->bodies();
    Status s = checkBodies(w, v, p + ".bodies");
    if (!s.ok() || dryRun) return s;
    for (uint32_t i = 0; i < v->size(); ++i) {
      phys::Status st = w.destroyBody(phys::BodyId::fromPacked(v->Get(i)));
      if (!st.ok()) return fromPhys(st, p + ".bodies[" + std::to_string(i) + "]");
      sw->touched.push_back(v->Get(i));
    }
    sw->infoDirty = true;  // (their joints went with them)
    return Status::Ok();
  }

  Status addJoints(const void* table, const std::string& p, bool dryRun) {
    phys::World& w = *sw->world;
    auto* v = static_cast<const wire::AddJoints*>(table)->joints();
    std::vector<phys::JointDef> defs;
    for (uint32_t i = 0; v && i < v->size(); ++i) {
      const wire::JointDef* j = v->Get(i);
      const std::string jp = p + ".joints[" + std::to_string(i) + "]";
      if (j->body_a() != 0 && !w.isValid(phys::BodyId::fromPacked(j->body_a())))
        return err(Code::NotFound, jp + ".body_a " + hex(j->body_a()) + " is not a live body");
      if (!w.isValid(phys::BodyId::fromPacked(j->body_b())))
        return err(Code::NotFound, jp + ".body_b " + hex(j->body_b()) + " is not a live body");
      defs.push_back(protocol::toJointDef(*j));
      Status s = protocol::checkJointDef(defs.back(), core.config_.limits, jp);
      if (!s.ok()) return s;
    }
    if (dryRun) return Status::Ok();
    for (size_t i = 0; i < defs.size(); ++i) {
      phys::JointId id;
      phys::Status st = w.createJoint(defs[i], &id);
      if (!st.ok()) return fromPhys(st, p + ".joints[" + std::to_string(i) + "]");
      ids.joints.push_back(id.packed());
    }
    sw->infoDirty = true;
    return Status::Ok();
  }

  Status removeJoints(const void* table, const std::string& p, bool dryRun) {
    phys::World& w = *sw->world;
    auto* v = static_cast<const wire::RemoveJoints*>(table)->joints();
    for (uint32_t i = 0; v && i < v->size(); ++i)
      if (!liveJoint(w, v->Get(i)))
        return err(Code::NotFound, p + ".joints[" + std::to_string(i) + "] " + hex(v->Get(i)) +
                                       " is not a live joint");
    if (dryRun || !v) return Status::Ok();
    for (uint32_t i = 0; i < v->size(); ++i) {
      phys::Status st = w.destroyJoint(phys::JointId::fromPacked(v->Get(i)));
      if (!st.ok()) return fromPhys(st, p + ".joints[" + std::to_string(i) + "]");
    }
    sw->infoDirty = true;
    return Status::Ok();
  }

  Status setBodyPose(const void* table, const std::string& p, bool dryRun) {
    phys::World& w = *sw->world;
    auto* v = static_cast<const wire::SetBodyPose*>(table)->items();
    Status s = checkItems(w, v, p + ".items");
    if (!s.ok() || dryRun) return s;
    for (uint32_t i = 0; i < v->size(); ++i) {
      const wire::BodyPose* it = v->Get(i);
      phys::Transform t = protocol::toPhys(it->pose());
      phys::Status st = w.setTransform(phys::BodyId::fromPacked(it->id()), t.p, t.q);
      if (!st.ok()) return fromPhys(st, p + ".items[" + std::to_string(i) + "]");
      sw->touched.push_back(it->id());
    }
    return Status::Ok();
  }

  Status setBodyVelocity(const void* table, const std::string& p, bool dryRun) {
    phys::World& w = *sw->world;
    auto* v = static_cast<const wire::SetBodyVelocity*>(table)->items();
    Status s = checkItems(w, v, p + ".items");
    if (!s.ok()) return s;
    for (uint32_t i = 0; v && i < v->size(); ++i) {
      phys::BodyState bs;
      w.getBody(phys::BodyId::fromPacked(v->Get(i)->id()), &bs);
      if (bs.type == phys::BodyType::Static)
        return err(Code::IncorrectState, p + ".items[" + std::to_string(i) + "].id " +
                                             hex(v->Get(i)->id()) +
                                             " is a static body (no velocity)");
    }
    if (dryRun) return Status::Ok();
    for (uint32_t i = 0; i < v->size(); ++i) {
      const wire::BodyVelocity* it = v->Get(i);
      phys::Status st =
          w.setVelocity(phys::BodyId::fromPacked(it->id()), protocol::toPhys(it->linear()),
                        protocol::toPhys(it->angular()));
      if (!st.ok()) return fromPhys(st, p + ".items[" + std::to_string(i) + "]");
      sw->touched.push_back(it->id());  // its published state changed now (a paused world's
                                        // subscribers see it at once: queueFrame)
    }
    return Status::Ok();
  }

  Status applyForce(const void* table, const std::string& p, bool dryRun) {
    return forces(false, table, p, dryRun);
  }
  Status applyImpulse(const void* table, const std::string& p, bool dryRun) {
    return forces(true, table, p, dryRun);
  }
  /// ApplyForce's and ApplyImpulse's items (the same record).
  Status forces(bool impulse, const void* table, const std::string& p, bool dryRun) {
    phys::World& w = *sw->world;
    auto* v = impulse ? static_cast<const wire::ApplyImpulse*>(table)->items()
                      : static_cast<const wire::ApplyForce*>(table)->items();
    wire::PointFrame frame = impulse
                                 ? static_cast<const wire::ApplyImpulse*>(table)->point_frame()
                                 : static_cast<const wire::ApplyForce*>(table)->point_frame();
    Status s = checkItems(w, v, p + ".items");
    if (!s.ok() || dryRun) return s;
    for (uint32_t i = 0; i < v->size(); ++i) {
      const wire::BodyForce* it = v->Get(i);
      const phys::BodyId id = phys::BodyId::fromPacked(it->id());
      const std::string ip = p + ".items[" + std::to_string(i) + "]";
      phys::Vec3 point;
      s = forcePoint(w, id, *it, frame, &point);
      if (!s.ok()) return err(s.code, ip + ": " + s.message);
      phys::Vec3 vec = protocol::toPhys(it->vector());
      phys::Status st = impulse ? w.applyImpulse(id, vec, point) : w.applyForce(id, vec, point);
      if (!st.ok()) return fromPhys(st, ip);
      if (impulse) sw->touched.push_back(it->id());  // its velocities changed now; a force
                                                     // acts in the next step
    }
    return Status::Ok();
  }

  Status applyTorque(const void* table, const std::string& p, bool dryRun) {
    phys::World& w = *sw->world;
    auto* v = static_cast<const wire::ApplyTorque*>(table)->items();
    Status s = checkItems(w, v, p + ".items");
    if (!s.ok() || dryRun) return s;
    for (uint32_t i = 0; i < v->size(); ++i) {
      phys::Status st = w.applyTorque(phys::BodyId::fromPacked(v->Get(i)->id()),
                                      protocol::toPhys(v->Get(i)->torque()));
      if (!st.ok()) return fromPhys(st, p + ".items[" + std::to_string(i) + "]");
    }
    return Status::Ok();
  }

  Status setMaterial(const void* table, const std::string& p, bool dryRun) {
    phys::World& w = *sw->world;
    auto* r = static_cast<const wire::SetMaterial*>(table);
    Status s = checkBodies(w, r->bodies(), p + ".bodies");
    if (!s.ok() || dryRun) return s;
    const phys::Material m = protocol::toPhys(*r->material());
    for (uint32_t i = 0; i < r->bodies()->size(); ++i) {
      phys::Status st = w.setMaterial(phys::BodyId::fromPacked(r->bodies()->Get(i)), m);
      if (!st.ok()) return fromPhys(st, p + ".bodies[" + std::to_string(i) + "]");
    }
    sw->infoDirty = true;
    return Status::Ok();
  }

  Status setSolver(const void* table, const std::string& p, bool dryRun) {
    phys::World& w = *sw->world;
    auto* r = static_cast<const wire::SetSolver*>(table);
    phys::SolverSettings settings = w.def().solver;
    std::string presetName = sw->preset;
    if (r->preset() && r->preset()->size() > 0) {
      auto it = core.presets_.find(r->preset()->str());
      if (it == core.presets_.end())
        return err(Code::NotFound, p + ".preset '" + r->preset()->str() + "' is not a preset");
      settings = it->second.settings;
      presetName = it->first;
    }
    if (r->settings()) protocol::applySolverSettings(*r->settings(), &settings);
    phys::Status st = phys::World::validate(settings);
    if (!st.ok()) return fromPhys(st, p + ".settings");
    if (dryRun) return Status::Ok();
    st = w.setSolverSettings(settings);
    if (!st.ok()) return fromPhys(st, p + ".settings");
    sw->preset = presetName;
    return Status::Ok();
  }

  Status setWorld(const void* table, const std::string& p, bool dryRun) {
    phys::World& w = *sw->world;
    // The world's definition with the settings given, checked whole (the codec's ranges,
    // then the engine's), then set at once: each change wakes what it affects
    // (phys::World::setDef). Gravity and the time step are in world info.
    auto* r = static_cast<const wire::SetWorld*>(table);
    if (!r->settings()) return err(Code::Malformed, p + ".settings is missing");
    phys::WorldDef def = w.def();
    protocol::applyOverrides(protocol::toOverrides(*r->settings()), &def);
    Status s = protocol::checkWorldSettings(def, core.config_.limits, p + ".settings");
    if (!s.ok()) return s;
    phys::Status st = phys::World::validate(def);
    if (!st.ok()) return fromPhys(st, p + ".settings");
    if (dryRun) return Status::Ok();
    st = w.setDef(def);
    if (!st.ok()) return fromPhys(st, p + ".settings");
    sw->infoDirty = true;
    return Status::Ok();
  }
};

namespace {

using Ctx = ServerCore::Context;

/// A world edit whose items are one list of its table (List: the accessor, e.g. bodies()).
template <class T, auto List>
bool listPresent(const void* t) {
  return (static_cast<const T*>(t)->*List)() != nullptr;
}
template <class T, auto List>
size_t listSize(const void* t) {
  return (static_cast<const T*>(t)->*List)()->size();
}

constexpr Ctx::Handler handle(wire::Request type, Ctx::Apply apply) {
  return {type, apply, nullptr, nullptr, nullptr, false};
}
template <class T, auto List>
constexpr Ctx::Handler listEdit(Ctx::Edit edit, bool motion = false) {
  return {wire::RequestTraits<T>::enum_value, &Ctx::worldEdit, edit, &listPresent<T, List>,
          &listSize<T, List>, motion};
}
constexpr bool kMotion = true;

/// Each request's handler, indexed by wire::Request. A world edit's row also holds its edit
/// and what editAll asks of it (listEdit when its items are one list; written out for
/// SetMaterial, which needs a material too, and SetSolver and SetWorld, one engine call each).
constexpr std::array<Ctx::Handler, size_t(wire::Request::MAX) + 1> kHandlers = {{
    handle(wire::Request::NONE, &Ctx::unsupported),
    handle(wire::Request::Hello, &Ctx::hello),
    handle(wire::Request::CreateWorld, &Ctx::createWorld),
    handle(wire::Request::DestroyWorld, &Ctx::destroyWorld),
    handle(wire::Request::ResetWorld, &Ctx::resetWorld),
    handle(wire::Request::ListWorlds, &Ctx::listWorlds),
    handle(wire::Request::LoadScene, &Ctx::loadScene),
    listEdit<wire::SpawnBodies, &wire::SpawnBodies::bodies>(&Ctx::spawnBodies),
    listEdit<wire::RemoveBodies, &wire::RemoveBodies::bodies>(&Ctx::removeBodies),
    listEdit<wire::AddJoints, &wire::AddJoints::joints>(&Ctx::addJoints),
    listEdit<wire::RemoveJoints, &wire::RemoveJoints::joints>(&Ctx::removeJoints),
    listEdit<wire::SetBodyPose, &wire::SetBodyPose::items>(&Ctx::setBodyPose, kMotion),
    listEdit<wire::SetBodyVelocity, &wire::SetBodyVelocity::items>(&Ctx::setBodyVelocity,
                                                                    kMotion),
    listEdit<wire::ApplyForce, &wire::ApplyForce::items>(&Ctx::applyForce, kMotion),
    listEdit<wire::ApplyImpulse, &wire::ApplyImpulse::items>(&Ctx::applyImpulse, kMotion),
    listEdit<wire::ApplyTorque, &wire::ApplyTorque::items>(&Ctx::applyTorque, kMotion),
    {wire::Request::SetMaterial, &Ctx::worldEdit, &Ctx::setMaterial,
     [](const void* t) {
       auto* r = static_cast<const wire::SetMaterial*>(t);
       return r->bodies() && r->material();
     },
     &listSize<wire::SetMaterial, &wire::SetMaterial::bodies>, false},
    {wire::Request::SetSolver, &Ctx::worldEdit, &Ctx::setSolver, nullptr, nullptr, false},
    handle(wire::Request::Step, &Ctx::step),
    handle(wire::Request::Run, &Ctx::run),
    handle(wire::Request::Pause, &Ctx::pause),
    handle(wire::Request::QueryState, &Ctx::queryState),
    handle(wire::Request::SaveSnapshot, &Ctx::saveSnapshot),
    handle(wire::Request::RestoreSnapshot, &Ctx::restoreSnapshot),
    handle(wire::Request::Batch, &Ctx::batch),
    handle(wire::Request::Subscribe, &Ctx::subscribe),
    handle(wire::Request::Unsubscribe, &Ctx::unsubscribe),
    handle(wire::Request::SetAccess, &Ctx::setAccess),
    {wire::Request::SetWorld, &Ctx::worldEdit, &Ctx::setWorld, nullptr, nullptr, false},
    handle(wire::Request::GetWorld, &Ctx::getWorld),
    handle(wire::Request::GetBodies, &Ctx::getDefinitions),
    handle(wire::Request::GetJoints, &Ctx::getDefinitions),
    handle(wire::Request::MoveWorld, &Ctx::moveWorld),
}};

constexpr bool inOrder() {
  for (size_t i = 0; i < kHandlers.size(); ++i) {
    const Ctx::Handler& h = kHandlers[i];
    // A world edit (the request table's kBatchable) has an edit and is applied by editAll.
    const bool edit = protocol::requestInfo(h.type).has(protocol::kBatchable);
    if (size_t(h.type) != i || !h.apply || (h.edit != nullptr) != edit) return false;
  }
  return true;
}

static_assert(inOrder(), "one handler per wire::Request, in the union's order");

constexpr Ctx::Handler kUnsupported = handle(wire::Request::NONE, &Ctx::unsupported);

}  // namespace

const ServerCore::Context::Handler& ServerCore::Context::handler(wire::Request type) {
  return size_t(type) < kHandlers.size() ? kHandlers[size_t(type)] : kUnsupported;
}

Status ServerCore::checkAccess(const ServerWorld& w, const wire::Command& c, uint64_t key,
                               uint64_t envelopeKey, bool proven) const {
  using Need = protocol::Access;
  const wire::Request type = c.request_type();
  Need need = protocol::requestInfo(type).access;
  // The two exceptions to the request table's column: a snapshot saved to a file on the
  // server, and another client's interest.
  if (type == wire::Request::SaveSnapshot) {
    auto* r = c.request_as_SaveSnapshot();
    if (r && r->file() && r->file()->size()) need = Need::Edit;
  }
  if (type == wire::Request::Unsubscribe) {
    auto* r = c.request_as_Unsubscribe();
    auto it = r ? w.interests.find(r->interest()) : w.interests.end();
    if (it != w.interests.end() && it->second.client != envelopeKey) need = Need::Edit;
  }
  if (need == Need::Read || w.owner == 0) return Status::Ok();
  const bool editor = std::find(w.editors.begin(), w.editors.end(), key) != w.editors.end();
  // A world whose owner proved its id: the owner's and editors' ids count only from a
  // participant that proved its own (anyone can write any id into a command).
  const bool idCounts = !w.ownerProven || proven;
  if (idCounts && key == w.owner) return Status::Ok();
  if (need == Need::Edit && (w.shared || (idCounts && editor))) return Status::Ok();
  if (!idCounts && (key == w.owner || editor))
    return err(Code::PermissionDenied,
               std::string(protocol::requestName(c.request_type())) + ": world " +
                   std::to_string(w.id) + " '" + w.name + "' was created by a client that "
                   "proved its id with a key, and client " + hex(key) +
                   " has not proved its id on this connection: say Hello with the key's proof "
                   "(the SDK does; docs/SERVER.md \"Access\")");
  const char* who = config_.identities ? "identity key " : "client ";
  return err(Code::PermissionDenied,
             std::string(protocol::requestName(c.request_type())) + ": world " +
                 std::to_string(w.id) + " '" + w.name + "' belongs to " + who + hex(w.owner) +
                 (need == Need::Own ? "; only its owner may do this"
                                    : std::string("; ") + who + hex(key) +
                                          " is not one of its editors (the owner's SetAccess)"));
}

Status ServerCore::checkWritable(const ServerWorld* w, const wire::Command& c) const {
  if (readOnly_.empty() || replaying_) return Status::Ok();
  const wire::Request t = c.request_type();
  // What the command changes must be stored: a CreateWorld's new world unless ephemeral, a
  // world's stored requests (the request table's kStored) when the world is kept.
  bool stored = w && w->store && protocol::requestInfo(t).has(protocol::kStored);
  if (t == wire::Request::CreateWorld) {
    auto* r = c.request_as_CreateWorld();
    stored = durable() && !(r && r->ephemeral());
  }
  if (!stored) return Status::Ok();
  return err(Code::ResourceExhausted,
             std::string(protocol::requestName(t)) + ": physd is read-only: " + readOnly_ +
                 "; reads are served, and commands that change kept worlds are taken again "
                 "once the data directory can be written (physd tries every second)");
}

Bytes ServerCore::applyBytes(std::span<const uint8_t> payload, uint64_t envelopeKey,
                             uint64_t envelopeSeq) {
  Incoming in;
  in.envelopeKey = envelopeKey;
  in.envelopeSeq = envelopeSeq;
  in.command =
      protocol::decodeCommand(std::vector<uint8_t>(payload.begin(), payload.end()), config_.limits);
  return apply(in);
}

Bytes ServerCore::apply(const Incoming& in) {
  if (in.command.ok()) {
    Bytes reply = apply(*in.command, in.envelopeKey, in.principal, in.proven);
    journalApplied(in, &reply);  // on a durable server: in the world's journal, or an error
    return reply;
  }
  // Not decodable: answer the envelope's key and seq (the only correlation that is known).
  ++counters_.commands;
  ++counters_.errors;
  ReplyHeader h;
  h.clientId = in.envelopeKey;
  h.seq = in.envelopeSeq;
  h.status = in.command.status;
  return protocol::encodeReply(h);
}

Bytes ServerCore::apply(const wire::Command& c, uint64_t envelopeKey, uint64_t principal,
                        bool proven) {
  // No exception leaves a command: the engine and the codec report failures as statuses, so
  // one that escapes anyway is answered here and the daemon goes on. (Such a command is not
  // journaled: lastStatus_ stays an error unless applyChecked answers.)
  lastStatus_ = Status::Error(Code::Internal, "the command threw");
  try {
    return applyChecked(c, envelopeKey, principal ? principal : envelopeKey, proven);
  } catch (const std::bad_alloc&) {
    ++counters_.errors;
    return protocol::encodeReply(protocol::replyTo(
        c, Status::Error(Code::ResourceExhausted,
                         std::string(protocol::requestName(c.request_type())) +
                             ": out of memory; the command may be partly applied")));
  } catch (const std::exception& e) {
    ++counters_.errors;
    return protocol::encodeReply(protocol::replyTo(
        c, Status::Error(Code::Internal, std::string(protocol::requestName(c.request_type())) +
                                             ": " + e.what() +
                                             "; the command may be partly applied")));
  }
}

Bytes ServerCore::applyChecked(const wire::Command& c, uint64_t envelopeKey, uint64_t principal,
                               bool proven) {
  ++counters_.commands;
  Context ctx(*this, protocol::replyTo(c));
  ctx.envelopeKey = envelopeKey;
  ctx.principal = principal;
  ctx.proven = proven;
  Status& st = ctx.header.status;
  const wire::Request type = c.request_type();
  if (c.client_id() != envelopeKey) {
    // Answered to the envelope's key, the sender's own, never to the client it names.
    ctx.header.clientId = envelopeKey;
    st = err(Code::Malformed, "command.client_id " + hex(c.client_id()) +
                                  " differs from the envelope key " + hex(envelopeKey));
    return ctx.finish(type);
  }
  if (protocol::needsWorld(type)) {
    ctx.sw = world(c.world());
    if (!ctx.sw && damaged_.count(c.world())) {
      const DamagedWorld& d = damaged_.at(c.world());
      st = err(Code::IncorrectState,
               std::string(protocol::requestName(type)) + ": world " + std::to_string(d.id) +
                   (d.name.empty() ? "" : " '" + d.name + "'") +
                   " is not restored: its files are damaged (" + d.damage +
                   "); the operator restores what is good with physd --accept-loss " +
                   std::to_string(d.id));
      return ctx.finish(type);
    }
    if (!ctx.sw && movedOut_.count(c.world())) {
      // Moved to another daemon: nothing done; the SDK sends the command there.
      ctx.header.owner = movedOut_.at(c.world());
      st = err(Code::Moved, "command.world " + std::to_string(c.world()) +
                                " moved to daemon " + std::to_string(ctx.header.owner));
      return ctx.finish(type);
    }
    if (!ctx.sw) {
      st = err(Code::NotFound, "command.world " + std::to_string(c.world()) + " does not exist");
      return ctx.finish(type);
    }
  }

  if (!c.request()) {
    st = err(Code::Malformed, "command.request is missing");
    return ctx.finish(type);
  }
  if (ctx.sw && !replaying_) {  // replayed commands were allowed when first applied
    st = checkAccess(*ctx.sw, c, principal, envelopeKey, proven);
    if (!st.ok()) return ctx.finish(type);
  }
  st = checkWritable(ctx.sw, c);  // a read-only server (a full data disk) stores nothing
  if (!st.ok()) return ctx.finish(type);
  // The request's handler; a job (Step, LoadScene from the queue) answers when it ends.
  const Context::Answer answer = (ctx.*Context::handler(type).apply)(c);
  return answer == Context::Answer::Now ? ctx.finish(type) : Bytes{};
}

Status ServerCore::readDefinitions(const ServerWorld& sw, const wire::Command& c,
                                   ReplyHeader* header, Bytes* reply) const {
  // GetBodies and GetJoints: the ids asked for, or every body (joint) from `first` in index
  // order; as many as one reply holds: max_count, max_bodies_per_frame bodies
  // (max_joints_per_command joints), the shapes and hull points a message may carry, and
  // max_message_bytes by a bound on each one's encoding. Its cost is that of the reply, plus
  // listing the world's ids when paging over all of them (as QueryState).
  const protocol::Limits& lim = config_.limits;
  const phys::World& w = *sw.world;
  const bool bodies = c.request_type() == wire::Request::GetBodies;
  const char* what = bodies ? "get_bodies" : "get_joints";
  const flatbuffers::Vector<uint64_t>* asked = nullptr;
  uint32_t first = 0, maxCount = 0;
  if (bodies) {
    auto* r = c.request_as_GetBodies();
    asked = r->bodies();
    first = r->first();
    maxCount = r->max_count();
  } else {
    auto* r = c.request_as_GetJoints();
    asked = r->joints();
    first = r->first();
    maxCount = r->max_count();
  }
  // The ids, checked live before anything is read.
  std::vector<uint64_t> ids;
  if (asked && asked->size() > 0) {
    ids.assign(asked->begin(), asked->end());
    first = 0;
    for (size_t i = 0; i < ids.size(); ++i) {
      const bool live = bodies ? w.isValid(phys::BodyId::fromPacked(ids[i])) : liveJoint(w, ids[i]);
      if (!live)
        return err(Code::NotFound, std::string(what) + (bodies ? ".bodies[" : ".joints[") +
                                       std::to_string(i) + "] " + hex(ids[i]) + " is not a live " +
                                       (bodies ? "body" : "joint"));
    }
  } else if (bodies) {
    for (phys::BodyId id : w.bodies()) ids.push_back(id.packed());
  } else {
    for (phys::JointId id : w.joints()) ids.push_back(id.packed());
  }
  const uint32_t total = uint32_t(ids.size());
  const uint32_t perReply = bodies ? lim.maxBodiesPerFrame : lim.maxJointsPerCommand;
  const uint32_t count = maxCount == 0 ? perReply : std::min(maxCount, perReply);
  const size_t byteBudget = lim.maxMessageBytes > protocol::kReplyOverheadBytes
                                ? lim.maxMessageBytes - protocol::kReplyOverheadBytes
                                : 0;
  size_t bytes = 0;
  uint64_t shapes = 0, hullPoints = 0;
  header->tick = sw.tick;
  if (bodies) {
    std::vector<protocol::BodyInfo> out;
    for (size_t i = first; i < ids.size() && out.size() < count; ++i) {
      protocol::BodyInfo b;
      b.id = ids[i];
      w.getBodyDef(phys::BodyId::fromPacked(b.id), &b.def, &b.mass);
      uint64_t points = 0;
      for (const phys::ShapeDef& s : b.def.shapes)
        if (s.geom.hull) points += s.geom.hull->vertices.size();
      const size_t n = protocol::encodedBytesBound(b);
      if (bytes + n > byteBudget || shapes + b.def.shapes.size() > lim.maxShapesPerCommand ||
          hullPoints + points > lim.maxHullPointsPerCommand) {
        if (out.empty())
          return err(Code::ResourceExhausted,
                     std::string(what) + ": body " + hex(b.id) +
                         " alone passes what one reply holds (max_message_bytes, "
                         "max_shapes_per_command, max_hull_points_per_command)");
        break;
      }
      bytes += n;
      shapes += b.def.shapes.size();
      hullPoints += points;
      out.push_back(std::move(b));
    }
    *reply = protocol::encodeBodiesReply(*header, total, out);
  } else {
    std::vector<protocol::JointEntry> out;
    for (size_t i = first; i < ids.size() && out.size() < count; ++i) {
      protocol::JointEntry j;
      j.id = ids[i];
      phys::JointState js;
      w.getJoint(phys::JointId::fromPacked(j.id), &j.def, &js);
      const size_t n = protocol::encodedBytesBound(j);
      if (bytes + n > byteBudget) {
        if (out.empty())
          return err(Code::ResourceExhausted, std::string(what) + ": joint " + hex(j.id) +
                                                  " alone passes max_message_bytes");
        break;
      }
      bytes += n;
      out.push_back(std::move(j));
    }
    *reply = protocol::encodeJointsReply(*header, total, out);
  }
  return Status::Ok();
}

SceneLoad ServerCore::prepareScene(const SceneRequest& req) const {
  // Runs on the tick thread or a loader thread: reads only the configuration and `req`.
  SceneLoad out;
  const protocol::Limits& lim = config_.limits;
  // The scene's budget, checked by the parser before it builds anything: the world's and the
  // server's body counts (the scene replaces this world's bodies), what one reply can list,
  // and the codec's limits on shapes, hulls and names.
  const uint64_t idsPerReply = req.forReply ? protocol::maxIdsPerReply(lim) : UINT64_MAX;
  phys::SceneBudget budget;
  budget.maxBodies = std::min<uint64_t>(
      {config_.maxBodiesPerWorld,
       config_.maxBodiesTotal > req.otherBodies ? config_.maxBodiesTotal - req.otherBodies : 0,
       idsPerReply});
  budget.maxJoints = std::min<uint64_t>(config_.maxJointsPerWorld, idsPerReply);
  budget.maxShapesPerBody = lim.maxShapesPerBody;
  budget.maxHullPoints = lim.maxHullPoints;
  budget.maxNameBytes = lim.maxNameBytes;
  // Shapes and hull points as for a snapshot (a scene is the other bulk way in).
  budget.maxShapes = lim.maxSnapshotShapes;
  budget.maxHullPointsTotal =
      std::min<uint64_t>(budget.maxHullPointsTotal, lim.maxSnapshotHullPoints);
  const char* limitNames =
      " (server.max_bodies_per_world, server.max_bodies_total, server.max_joints_per_world and, "
      "for LoadScene, the ids one reply lists: max_ids_per_reply)";

  phys::Status ps;
  if (!req.sceneName.empty()) {
    const std::string path = underDir(config_.scenesDir, req.sceneName, ".json");
    if (config_.scenesDir.empty() || !fs::exists(path)) {
      out.status = err(Code::NotFound, "load_scene.scene_name '" + req.sceneName +
                                           "' is not a scene of this server");
      return out;
    }
    ps = phys::loadSceneFile(path, &out.scene, budget);
  } else {
    ps = phys::parseScene(req.json, "load_scene.json", &out.scene, budget);
  }
  if (!ps.ok()) {
    out.status = fromPhys(ps, "load_scene");
    if (out.status.code == Code::NotFound) out.status.code = Code::InvalidArgument;
    if (out.status.code == Code::ResourceExhausted) out.status.message += limitNames;
    return out;
  }
  const phys::Scene& scene = out.scene;
  if (req.forReply && scene.bodies.size() + scene.joints.size() > idsPerReply) {
    out.status = err(Code::ResourceExhausted,
                     "load_scene: the scene has " + std::to_string(scene.bodies.size()) +
                         " bodies and " + std::to_string(scene.joints.size()) +
                         " joints; one reply lists at most " + std::to_string(idsPerReply) +
                         " new ids (max_ids_per_reply): load it as a start-up world or in parts");
    return out;
  }
  // The codec's rules, so that every client can decode the world's description.
  Status st = protocol::checkWorldSettings(scene.world, lim, "load_scene: world settings");
  for (size_t i = 0; st.ok() && i < scene.bodies.size(); ++i)
    st = protocol::checkBodyDef(scene.bodies[i], lim,
                                "load_scene: body " + std::to_string(i) +
                                    (scene.bodies[i].name.empty()
                                         ? std::string()
                                         : " " + protocol::shortQuote(scene.bodies[i].name)));
  for (size_t i = 0; st.ok() && i < scene.joints.size(); ++i)
    st = protocol::checkJointDef(scene.joints[i].def, lim,
                                 "load_scene: joint " + std::to_string(i) +
                                     (scene.joints[i].def.name.empty()
                                          ? std::string()
                                          : " " + protocol::shortQuote(scene.joints[i].def.name)));
  if (!st.ok()) {
    out.status = st;
    return out;
  }
  phys::WorldDef def = scene.world;
  def.threads = config_.threads;
  def.gpuAllowCpuDevice = config_.gpuAllowCpuDevice;
  applyPolicy(&def);
  // A scene that asks for the GPU (or auto) gets it; else the world keeps its setting.
  if (def.backend == phys::Backend::Cpu) def.backend = req.backend;
  out.world = std::make_unique<phys::World>(def);
  ps = phys::instantiateScene(scene, out.world.get(), &out.bodyIds, &out.jointIds);
  if (!ps.ok()) {
    out.status = fromPhys(ps, "load_scene");
    out.world.reset();
  }
  return out;
}

void ServerCore::commitScene(ServerWorld& sw, SceneLoad&& load, std::vector<uint64_t>* bodyIds,
                             std::vector<uint64_t>* jointIds) {
  cancelJob(sw, "replaced by load_scene");
  sw.world = std::move(load.world);
  for (phys::BodyId id : load.bodyIds) bodyIds->push_back(id.packed());
  for (phys::JointId id : load.jointIds) jointIds->push_back(id.packed());
  sw.tick = 0;
  sw.accumulator = 0;
  ++sw.revision;
  sw.framesReplaced();  // a new world: subscribers start from a keyframe
  sw.infoDirty = sw.frameDirty = true;
}

SceneRequest ServerCore::sceneRequest(const ServerWorld& sw, const wire::LoadScene* r,
                                                  const std::string& sceneName,
                                                  bool forReply) const {
  SceneRequest req;
  req.sceneName = r && r->scene_name() ? r->scene_name()->str() : sceneName;
  if (req.sceneName.empty() && r && r->json()) req.json = r->json()->str();
  req.forReply = forReply;
  req.otherBodies = totalBodies() - uint64_t(sw.world->bodyCount());
  req.backend = sw.world->def().backend;
  return req;
}

Status ServerCore::loadScene(ServerWorld& sw, const wire::LoadScene* r,
                             const std::string& sceneName, bool forReply,
                             std::vector<uint64_t>* bodyIds, std::vector<uint64_t>* jointIds) {
  Status st = checkGrowth(nullptr, 0, 0, "load_scene");
  if (!st.ok()) return st;
  if (!r && sceneName.empty()) return err(Code::Malformed, "load_scene needs json or scene_name");
  if (r && !r->json() && !(r->scene_name() && r->scene_name()->size()))
    return err(Code::Malformed, "load_scene needs json or scene_name");
  SceneLoad load = prepareScene(sceneRequest(sw, r, sceneName, forReply));
  if (!load.status.ok()) return load.status;
  commitScene(sw, std::move(load), bodyIds, jointIds);
  st = durableReplaced(sw, "load_scene");  // on disk before the reply
  if (!st.ok()) bodyIds->clear(), jointIds->clear();
  return st;
}

Status ServerCore::checkRestored(const phys::World& w, const std::string& path) const {
  const protocol::Limits& lim = config_.limits;
  // Every setting GetWorld reports, as SetWorld may set it.
  Status st = protocol::checkWorldSettings(w.def(), lim, path);
  if (!st.ok()) return st;
  phys::Status ps = phys::World::validate(w.def().solver);
  if (!ps.ok()) return fromPhys(ps, path + ".solver");
  for (phys::BodyId id : w.bodies()) {
    const std::string bp = path + ": body " + hex(id.packed());
    phys::BodyState s;
    w.getBody(id, &s);
    phys::BodyDef d = bodyDefOf(w, id);
    // A dynamic body without a shape of volume had an explicit mass (the rest derive theirs
    // from densities, which may exceed max_mass legitimately: not an input here).
    bool volume = false;
    for (const phys::ShapeDef& sd : d.shapes) volume |= sd.geom.type != phys::ShapeType::Plane;
    if (d.type == phys::BodyType::Dynamic && !volume) d.mass = s.mass;
    st = protocol::checkBodyDef(d, lim, bp);
    if (!st.ok()) return st;
    // Mass and inertia as the engine holds them: finite, not negative, some for a dynamic body.
    if (!std::isfinite(s.mass) || s.mass < 0 ||
        (s.type == phys::BodyType::Dynamic && !(s.mass > 0)))
      return err(Code::InvalidArgument,
                 bp + ".mass must be finite and > 0 for a dynamic body, got " +
                     std::to_string(s.mass));
    const phys::Vec3 cols[3] = {s.inertia.c0, s.inertia.c1, s.inertia.c2};
    for (int c = 0; c < 3; ++c)
      for (int r = 0; r < 3; ++r) {
        const float v = cols[c][r];
        if (!std::isfinite(v) || (r == c && v < 0))
          return err(Code::InvalidArgument, bp + ".inertia must be finite with moments >= 0");
      }
  }
  for (phys::JointId id : w.joints()) {
    phys::JointDef d;
    phys::JointState js;
    if (!w.getJoint(id, &d, &js).ok()) continue;
    st = protocol::checkJointDef(d, lim, path + ": joint " + hex(id.packed()));
    if (!st.ok()) return st;
  }
  return Status::Ok();
}

}  // namespace phys::server
