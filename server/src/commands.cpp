// ServerCore::apply: every command of the protocol, checked against the server's state,
// applied all-or-nothing, answered with a reply payload.
//
// World edits (and Batches of them) run in two passes: a check pass (ids live, presets
// exist, definitions convert) that changes nothing, then the apply pass. Before the apply
// pass the world is saved with World::saveSnapshot; if an engine call still fails midway
// (e.g. engine validation of a body definition, or a batch item that refers to a body an
// earlier item removed) the world is restored from it, so nothing changes.
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

/// Whether a world edit carries the vectors and tables it must have.
bool requiredPresent(wire::Request type, const void* t) {
  switch (type) {
    case wire::Request::SpawnBodies:
      return static_cast<const wire::SpawnBodies*>(t)->bodies();
    case wire::Request::RemoveBodies:
      return static_cast<const wire::RemoveBodies*>(t)->bodies();
    case wire::Request::AddJoints:
      return static_cast<const wire::AddJoints*>(t)->joints();
    case wire::Request::RemoveJoints:
      return static_cast<const wire::RemoveJoints*>(t)->joints();
    case wire::Request::SetBodyPose:
      return static_cast<const wire::SetBodyPose*>(t)->items();
    case wire::Request::SetBodyVelocity:
      return static_cast<const wire::SetBodyVelocity*>(t)->items();
    case wire::Request::ApplyForce:
      return static_cast<const wire::ApplyForce*>(t)->items();
    case wire::Request::ApplyImpulse:
      return static_cast<const wire::ApplyImpulse*>(t)->items();
    case wire::Request::ApplyTorque:
      return static_cast<const wire::ApplyTorque*>(t)->items();
    case wire::Request::SetMaterial: {
      auto* r = static_cast<const wire::SetMaterial*>(t);
      return r->bodies() && r->material();
    }
    default:
      return true;
  }
}

/// Engine calls a world edit makes (each either applies or changes nothing).
size_t engineCalls(wire::Request type, const void* t) {
  switch (type) {
    case wire::Request::SpawnBodies:
      return static_cast<const wire::SpawnBodies*>(t)->bodies()->size();
    case wire::Request::RemoveBodies:
      return static_cast<const wire::RemoveBodies*>(t)->bodies()->size();
    case wire::Request::AddJoints:
      return static_cast<const wire::AddJoints*>(t)->joints()->size();
    case wire::Request::RemoveJoints:
      return static_cast<const wire::RemoveJoints*>(t)->joints()->size();
    case wire::Request::SetBodyPose:
      return static_cast<const wire::SetBodyPose*>(t)->items()->size();
    case wire::Request::SetBodyVelocity:
      return static_cast<const wire::SetBodyVelocity*>(t)->items()->size();
    case wire::Request::ApplyForce:
      return static_cast<const wire::ApplyForce*>(t)->items()->size();
    case wire::Request::ApplyImpulse:
      return static_cast<const wire::ApplyImpulse*>(t)->items()->size();
    case wire::Request::ApplyTorque:
      return static_cast<const wire::ApplyTorque*>(t)->items()->size();
    case wire::Request::SetMaterial:
      return static_cast<const wire::SetMaterial*>(t)->bodies()->size();
    default:
      return 1;
  }
}

// Per-command state: the core, the reply header and the ids created.
struct ServerCore::Context {
  ServerCore& core;
  ReplyHeader header;
  CreatedIds ids;
  /// Hulls built for this message (a hull table that many shapes share is built once) and
  /// the body definitions converted by the check pass, by SpawnBodies table, for the apply
  /// pass.
  protocol::HullCache hulls;
  std::map<const void*, std::vector<phys::BodyDef>> converted;

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

  /// One world edit (a batchable request). dryRun: only the checks that need the server's
  /// state, nothing changes. Otherwise applies it (the caller rolls back on error).
  Status edit(ServerWorld& sw, wire::Request type, const void* table, const std::string& path,
              bool dryRun) {
    phys::World& w = *sw.world;
    const std::string p = path + protocol::requestName(type);
    // The codec requires these lists (non-empty); checked again so that a gap there can
    // never become a null dereference here.
    if (!table || !requiredPresent(type, table))
      return err(Code::Malformed, p + " lacks a required field");
    switch (type) {
      case wire::Request::SpawnBodies: {
        auto* r = static_cast<const wire::SpawnBodies*>(table);
        auto* v = r->bodies();
        if (dryRun) {
          std::vector<phys::BodyDef> defs(v ? v->size() : 0);
          for (uint32_t i = 0; i < defs.size(); ++i) {
            const std::string bp = p + ".bodies[" + std::to_string(i) + "]";
            Status s = protocol::toBodyDef(*v->Get(i), &defs[i], bp, &hulls);
            if (s.ok()) s = protocol::checkBodyDef(defs[i], core.config_.limits, bp);
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
          sw.touched.push_back(id.packed());
        }
        sw.infoDirty = true;
        return Status::Ok();
      }
      case wire::Request::RemoveBodies: {
        auto* v = static_cast<const wire::RemoveBodies*>(table)->bodies();
        Status s = checkBodies(w, v, p + ".bodies");
        if (!s.ok() || dryRun) return s;
        for (uint32_t i = 0; i < v->size(); ++i) {
          phys::Status st = w.destroyBody(phys::BodyId::fromPacked(v->Get(i)));
          if (!st.ok()) return fromPhys(st, p + ".bodies[" + std::to_string(i) + "]");
          sw.touched.push_back(v->Get(i));
        }
        sw.infoDirty = true;  // (their joints went with them)
        return Status::Ok();
      }
      case wire::Request::AddJoints: {
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
        sw.infoDirty = true;
        return Status::Ok();
      }
      case wire::Request::RemoveJoints: {
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
        sw.infoDirty = true;
        return Status::Ok();
      }
      case wire::Request::SetBodyPose: {
        auto* v = static_cast<const wire::SetBodyPose*>(table)->items();
        Status s = checkItems(w, v, p + ".items");
        if (!s.ok() || dryRun) return s;
        for (uint32_t i = 0; i < v->size(); ++i) {
          const wire::BodyPose* it = v->Get(i);
          phys::Transform t = protocol::toPhys(it->pose());
          phys::Status st = w.setTransform(phys::BodyId::fromPacked(it->id()), t.p, t.q);
          if (!st.ok()) return fromPhys(st, p + ".items[" + std::to_string(i) + "]");
          sw.touched.push_back(it->id());
        }
        return Status::Ok();
      }
      case wire::Request::SetBodyVelocity: {
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
          sw.touched.push_back(it->id());  // its published state changed now (a paused world's
                                           // subscribers see it at once: queueFrame)
        }
        return Status::Ok();
      }
      case wire::Request::ApplyForce:
      case wire::Request::ApplyImpulse: {
        const bool impulse = type == wire::Request::ApplyImpulse;
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
          if (impulse) sw.touched.push_back(it->id());  // its velocities changed now; a force
                                                        // acts in the next step
        }
        return Status::Ok();
      }
      case wire::Request::ApplyTorque: {
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
      case wire::Request::SetMaterial: {
        auto* r = static_cast<const wire::SetMaterial*>(table);
        Status s = checkBodies(w, r->bodies(), p + ".bodies");
        if (!s.ok() || dryRun) return s;
        const phys::Material m = protocol::toPhys(*r->material());
        for (uint32_t i = 0; i < r->bodies()->size(); ++i) {
          phys::Status st = w.setMaterial(phys::BodyId::fromPacked(r->bodies()->Get(i)), m);
          if (!st.ok()) return fromPhys(st, p + ".bodies[" + std::to_string(i) + "]");
        }
        sw.infoDirty = true;
        return Status::Ok();
      }
      case wire::Request::SetSolver: {
        auto* r = static_cast<const wire::SetSolver*>(table);
        phys::SolverSettings settings = w.def().solver;
        std::string presetName = sw.preset;
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
        sw.preset = presetName;
        return Status::Ok();
      }
      case wire::Request::SetWorld: {
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
        sw.infoDirty = true;
        return Status::Ok();
      }
      default:
        return err(Code::Internal, p + " is not a world edit");
    }
  }

  /// Edits all-or-nothing: check every item, snapshot, apply, roll back on failure.
  Status editAll(ServerWorld& sw, const std::vector<std::pair<wire::Request, const void*>>& items,
                 const std::vector<std::string>& paths) {
    uint64_t newBodies = 0, newJoints = 0;
    for (size_t i = 0; i < items.size(); ++i) {
      Status s = edit(sw, items[i].first, items[i].second, paths[i], true);
      if (!s.ok()) return s;
      if (items[i].first == wire::Request::SpawnBodies)
        newBodies += static_cast<const wire::SpawnBodies*>(items[i].second)->bodies()->size();
      if (items[i].first == wire::Request::AddJoints)
        newJoints += static_cast<const wire::AddJoints*>(items[i].second)->joints()->size();
    }
    if (newBodies + newJoints > 0) {
      Status s = core.checkGrowth(&sw, newBodies, newJoints, paths[0] + "this command");
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
      calls += engineCalls(type, table);
      motionOnly &= type == wire::Request::SetBodyPose || type == wire::Request::SetBodyVelocity ||
                    type == wire::Request::ApplyForce || type == wire::Request::ApplyImpulse ||
                    type == wire::Request::ApplyTorque;
    }
    const bool rollback = calls > 1 && !motionOnly;
    std::vector<uint8_t> saved;
    phys::Status snap = rollback ? sw.world->saveSnapshot(&saved) : phys::Status::Ok();
    const std::string preset = sw.preset;
    const bool infoDirty = sw.infoDirty;
    for (size_t i = 0; i < items.size(); ++i) {
      Status s = edit(sw, items[i].first, items[i].second, paths[i], false);
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
      phys::Status back = sw.world->restoreSnapshot(saved.data(), saved.size());
      if (!back.ok())
        return err(Code::Internal, s.message + " (rollback failed: " + back.message + ")");
      sw.preset = preset;
      sw.infoDirty = infoDirty;
      return s;
    }
    sw.frameDirty = true;
    if (sw.infoDirty) ++sw.revision;
    return Status::Ok();
  }
};

Status ServerCore::checkAccess(const ServerWorld& w, const wire::Command& c, uint64_t key,
                               uint64_t envelopeKey, bool proven) const {
  enum class Need { Read, Edit, Own };
  Need need = Need::Edit;
  switch (c.request_type()) {
    case wire::Request::QueryState:
    case wire::Request::GetWorld:
    case wire::Request::GetBodies:
    case wire::Request::GetJoints:
    case wire::Request::Subscribe:
    case wire::Request::Unsubscribe:  // its own interest: checked again in apply (others' need Edit)
      need = Need::Read;
      break;
    case wire::Request::SaveSnapshot: {  // bytes are a read; a file on the server is not
      auto* r = c.request_as_SaveSnapshot();
      need = r && r->file() && r->file()->size() ? Need::Edit : Need::Read;
      break;
    }
    case wire::Request::DestroyWorld:
    case wire::Request::SetAccess:
      need = Need::Own;
      break;
    default:
      break;
  }
  if (c.request_type() == wire::Request::Unsubscribe) {
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
  bool stored = false;  // what the command changes must be stored
  switch (t) {
    case wire::Request::CreateWorld: {
      auto* r = c.request_as_CreateWorld();
      stored = durable() && !(r && r->ephemeral());
      break;
    }
    case wire::Request::Step:
    case wire::Request::Run:
    case wire::Request::Pause:
    case wire::Request::LoadScene:
    case wire::Request::ResetWorld:
    case wire::Request::RestoreSnapshot:
    case wire::Request::SetAccess:
    case wire::Request::Batch:
      stored = w && w->store;
      break;
    default:
      stored = w && w->store && protocol::isBatchable(t);
      break;
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

Bytes ServerCore::applyChecked(const wire::Command& c, uint64_t envelopeKey,
                                uint64_t principal, bool proven) {
  ++counters_.commands;
  Context ctx{*this, protocol::replyTo(c), {}, {}, {}};
  Status& st = ctx.header.status;
  const wire::Request type = c.request_type();
  ServerWorld* sw = nullptr;
  Bytes reply;
  auto finish = [&]() -> Bytes {
    lastStatus_ = st;
    if (!st.ok()) ++counters_.errors;
    if (sw && ctx.header.tick == 0) ctx.header.tick = sw->tick;
    if (!reply.empty() && st.ok()) return std::move(reply);
    if (st.ok() && (!ctx.ids.bodies.empty() || !ctx.ids.joints.empty() ||
                    type == wire::Request::SpawnBodies || type == wire::Request::AddJoints ||
                    type == wire::Request::LoadScene || type == wire::Request::Batch))
      return protocol::encodeIdsReply(ctx.header, ctx.ids.bodies, ctx.ids.joints);
    return protocol::encodeReply(ctx.header);
  };

  if (c.client_id() != envelopeKey) {
    // Answered to the envelope's key, the sender's own, never to the client it names.
    ctx.header.clientId = envelopeKey;
    st = err(Code::Malformed, "command.client_id " + hex(c.client_id()) +
                                  " differs from the envelope key " + hex(envelopeKey));
    return finish();
  }
  if (protocol::needsWorld(type)) {
    sw = world(c.world());
    if (!sw && damaged_.count(c.world())) {
      const DamagedWorld& d = damaged_.at(c.world());
      st = err(Code::IncorrectState,
               std::string(protocol::requestName(type)) + ": world " + std::to_string(d.id) +
                   (d.name.empty() ? "" : " '" + d.name + "'") +
                   " is not restored: its files are damaged (" + d.damage +
                   "); the operator restores what is good with physd --accept-loss " +
                   std::to_string(d.id));
      return finish();
    }
    if (!sw) {
      st = err(Code::NotFound, "command.world " + std::to_string(c.world()) + " does not exist");
      return finish();
    }
  }

  if (!c.request()) {
    st = err(Code::Malformed, "command.request is missing");
    return finish();
  }
  if (sw && !replaying_) {  // replayed commands were allowed when first applied
    st = checkAccess(*sw, c, principal, envelopeKey, proven);
    if (!st.ok()) return finish();
  }
  st = checkWritable(sw, c);  // a read-only server (a full data disk) stores nothing
  if (!st.ok()) return finish();
  switch (type) {
    case wire::Request::Hello: {
      auto* r = c.request_as_Hello();
      if (r->protocol_version() != protocol::kProtocolVersion) {
        st = err(Code::Unsupported, "hello.protocol_version " +
                                        std::to_string(r->protocol_version()) +
                                        " is not supported; this server speaks " +
                                        std::to_string(protocol::kProtocolVersion));
        return finish();
      }
      protocol::HelloInfo info;
      info.serverName = config_.serverName;
      info.serverVersion = PHYSD_VERSION;
      info.features = {"batch", "snapshot", "engine_snapshot", "load_scene", "run", "query_state"};
      info.limits = config_.limits;
      info.clientProven = proven;
      reply = protocol::encodeHelloReply(ctx.header, info);
      return finish();
    }
    case wire::Request::CreateWorld: {
      auto* r = c.request_as_CreateWorld();
      if (!r->name()) {
        st = err(Code::Malformed, "create_world.name is missing");
        return finish();
      }
      const std::string name = r->name()->str();
      for (auto& [id, w] : worlds_)
        if (w->name == name) {
          st = err(Code::InvalidArgument,
                   "create_world.name '" + name + "' is taken by world " + std::to_string(id));
          return finish();
        }
      for (auto& [id, d] : damaged_)
        if (d.name == name) {
          st = err(Code::InvalidArgument, "create_world.name '" + name +
                                              "' is taken by world " + std::to_string(id) +
                                              " (kept on disk, not restored: damaged)");
          return finish();
        }
      if (worlds_.size() >= config_.maxWorlds) {
        st = err(Code::ResourceExhausted,
                 "this server holds at most " + std::to_string(config_.maxWorlds) + " worlds");
        return finish();
      }
      st = checkGrowth(nullptr, 0, 0, "create_world");
      if (!st.ok()) return finish();
      std::string preset = r->preset() && r->preset()->size() ? r->preset()->str() : defaultPreset_;
      auto it = presets_.find(preset);
      if (it == presets_.end()) {
        st = err(Code::NotFound, "create_world.preset '" + preset + "' is not a preset");
        return finish();
      }
      phys::WorldDef def;
      def.backend = config_.backend;
      if (r->backend() && r->backend()->size() &&
          !phys::parseBackend(r->backend()->str(), &def.backend)) {
        // The codec rejects it first; checked again for commands applied without it.
        st = err(Code::InvalidArgument,
                 "create_world.backend must be \"cpu\", \"gpu\" or \"auto\" (or empty: the "
                 "server's default), got \"" +
                     r->backend()->str() + "\"");
        return finish();
      }
      def.solver = it->second.settings;
      if (r->gravity()) def.gravity = protocol::toPhys(*r->gravity());
      if (r->time_step() > 0) def.timeStep = r->time_step();
      def.sleep.enabled = r->sleep();
      auto w = makeWorld(name, preset, def);
      w->id = nextWorldId_++;
      w->ephemeral = r->ephemeral();
      w->owner = startupCreate_ ? 0 : principal;
      // On a secure daemon the owner is an identity, which DDS Security vouches for.
      w->ownerProven = !startupCreate_ && !config_.identities && proven;
      if (r->editors()) w->editors.assign(r->editors()->begin(), r->editors()->end());
      w->shared = r->shared();
      ctx.header.world = w->id;
      ServerWorld& made = *w;
      worlds_[w->id] = std::move(w);
      if (durable() && !made.ephemeral && !replaying_) {
        // Its directory and first checkpoint before the reply names it.
        st = createStore(made);
        if (!st.ok()) {
          st.message = "create_world: " + st.message;
          worlds_.erase(made.id);
          ctx.header.world = 0;
        }
      }
      return finish();
    }
    case wire::Request::DestroyWorld: {
      ReliableMessage m;
      m.type = ReliableMessage::Type::WorldRemoved;
      m.world = sw->id;
      ctx.header.tick = sw->tick;
      if (sw->store) {
        st = sw->store->remove();
        if (!st.ok()) return finish();
      }
      worlds_.erase(sw->id);
      sw = nullptr;
      out_.pushReliable(std::move(m));
      return finish();
    }
    case wire::Request::ResetWorld: {
      phys::WorldDef def = sw->world->def();
      sw->world = std::make_unique<phys::World>(def);
      sw->tick = 0;
      sw->accumulator = 0;
      ++sw->revision;
      sw->framesReplaced();  // a new world: subscribers start from a keyframe
      sw->infoDirty = sw->frameDirty = true;
      st = durableReplaced(*sw, "reset_world");
      return finish();
    }
    case wire::Request::ListWorlds: {
      auto list = summaries();
      reply = protocol::encodeWorldListReply(ctx.header, list);
      return finish();
    }
    case wire::Request::LoadScene: {
      auto* r = c.request_as_LoadScene();
      if (!current_) {  // applied directly (tests): loaded now
        st = loadScene(*sw, r, "", /*forReply=*/true, &ctx.ids.bodies, &ctx.ids.joints);
        if (!st.ok()) ctx.ids = {};
        return finish();
      }
      // From the queue: parsed, checked and built on a loader thread while the other worlds
      // tick; the world waits for it (as for a Step job), advance() swaps it in and answers.
      st = checkGrowth(nullptr, 0, 0, "load_scene");
      if (st.ok() && !r->json() && !(r->scene_name() && r->scene_name()->size()))
        st = err(Code::Malformed, "load_scene needs json or scene_name");
      // Each loader may build a world as large as the budgets allow: how many build at once
      // bounds the memory of loads in flight.
      reapLoaders();
      if (st.ok() && loaders_.size() >= config_.maxConcurrentLoads)
        st = err(Code::ResourceExhausted,
                 "load_scene: " + std::to_string(loaders_.size()) +
                     " scenes are being loaded already, the limit is " +
                     std::to_string(config_.maxConcurrentLoads) +
                     " (server.max_concurrent_loads); retry after their replies");
      if (!st.ok()) return finish();
      auto task = std::make_shared<LoadTask>();
      task->request = sceneRequest(*sw, r, "", /*forReply=*/true);
      ServerWorld::LoadJob job;
      job.task = task;
      job.header = ctx.header;
      job.envelopeKey = current_->envelopeKey;
      job.envelopeSeq = current_->envelopeSeq;
      job.sender = current_->sender;
      job.charge = queueCharge(*current_);
      startLoad(task);  // first: if the thread cannot start, nothing waits for it
      sw->load = std::move(job);
      deferred_ = true;
      return {};
    }
    case wire::Request::Step: {
      const uint64_t n = c.request_as_Step()->count();
      const uint64_t bodies = std::max<uint64_t>(1, uint64_t(sw->world->bodyCount()));
      if (n * bodies > config_.limits.maxBodyStepsPerCommand) {
        st = err(Code::ResourceExhausted,
                 "step.count " + std::to_string(n) + " x " + std::to_string(bodies) +
                     " bodies is " + std::to_string(n * bodies) +
                     " body steps, the limit is " +
                     std::to_string(config_.limits.maxBodyStepsPerCommand) +
                     " (max_body_steps_per_command); step in smaller counts");
        return finish();
      }
      if (!current_) {  // applied directly (tests, start-up): all steps now
        st = stepWorld(sw->id, n);
        ctx.header.tick = sw->tick;
        return finish();
      }
      // From the queue: a slice now; what is left runs a slice per tick, between other
      // commands and worlds, and answers when done (or when a Pause ends it). Its steps are
      // stored ahead (a Lease, synced with the tick's commands) before the first is taken.
      bool leased = false;
      Status ls = leaseTo(*sw, sw->tick + n, /*syncNow=*/false, &leased);
      if (!ls.ok()) {
        st = err(ls.code, "step: not stored: " + ls.message + "; the world did not step");
        return finish();
      }
      ServerWorld::StepJob job;
      job.stored = !leased;
      job.requested = job.remaining = n;
      job.header = ctx.header;
      job.envelopeKey = current_->envelopeKey;
      job.envelopeSeq = current_->envelopeSeq;
      job.sender = current_->sender;
      job.charge = queueCharge(*current_);
      sw->job = job;
      deferred_ = true;  // advance() runs its slices, the first one right after this command
      return {};
    }
    case wire::Request::Run: {
      float rate = c.request_as_Run()->rate_hz();
      sw->mode = rate > 0 ? RunMode::RealTime : RunMode::AsFastAsPossible;
      if (rate > 0) sw->rateHz = rate;
      sw->accumulator = 0;
      return finish();
    }
    case wire::Request::Subscribe: {
      auto* r = c.request_as_Subscribe();
      // Whose interests these are: the participant's (all its client ids), or the client id's
      // for a command without one (in-process callers).
      const uint64_t sender = current_ ? current_->sender : 0;
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
      if (held >= config_.maxInterestsPerClient) {
        st = err(Code::ResourceExhausted,
                 "subscribe: this client holds " + std::to_string(held) +
                     " interests in this world, the most one client may "
                     "(server.max_interests_per_client); unsubscribe one first");
        return finish();
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
        return finish();
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
        return finish();
      }
      const uint32_t id = sw->nextInterest++;
      in.client = envelopeKey;
      in.sender = sender;
      sw->interests.emplace(id, std::move(in));
      ReliableMessage m;
      m.type = ReliableMessage::Type::InterestAdded;
      m.world = sw->id;
      m.key = id;
      out_.pushReliable(std::move(m));
      sw->frameDirty = true;
      ctx.header.tick = sw->tick;
      reply = protocol::encodeInterestReply(ctx.header, id, protocol::stateTopic(sw->id, id));
      return finish();
    }
    case wire::Request::Unsubscribe: {
      const uint32_t id = c.request_as_Unsubscribe()->interest();
      auto it = sw->interests.find(id);
      if (it == sw->interests.end()) {
        st = err(Code::NotFound, "unsubscribe.interest " + std::to_string(id) +
                                     " is not an interest of this world");
        return finish();
      }
      // Its subscriber, or whoever may change the world.
      if (it->second.client != envelopeKey) {
        st = checkAccess(*sw, c, principal, envelopeKey, proven);
        if (!st.ok()) return finish();
      }
      sw->interests.erase(it);
      ReliableMessage m;
      m.type = ReliableMessage::Type::InterestRemoved;
      m.world = sw->id;
      m.key = id;
      out_.pushReliable(std::move(m));
      return finish();
    }
    case wire::Request::Pause: {
      sw->mode = RunMode::Paused;
      sw->accumulator = 0;
      return finish();
    }
    case wire::Request::SetAccess: {
      auto* r = c.request_as_SetAccess();
      sw->editors.clear();
      if (r->editors()) sw->editors.assign(r->editors()->begin(), r->editors()->end());
      sw->shared = r->shared();
      return finish();
    }
    case wire::Request::QueryState: {
      auto* r = c.request_as_QueryState();
      std::vector<wire::BodyState> out;
      const uint32_t maxFrame = config_.limits.maxBodiesPerFrame;
      uint32_t total = 0;
      phys::BodyState bs;
      if (r->bodies() && r->bodies()->size() > 0) {
        auto* v = r->bodies();
        Status s = ctx.checkBodies(*sw->world, v, "query_state.bodies");
        if (!s.ok()) {
          st = s;
          return finish();
        }
        if (v->size() > maxFrame) {
          st = err(Code::ResourceExhausted,
                   "query_state.bodies asks for " + std::to_string(v->size()) +
                       " bodies; one reply holds at most " + std::to_string(maxFrame) +
                       " (max_bodies_per_frame)");
          return finish();
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
      ctx.header.tick = sw->tick;
      // Stamped as a state frame is (queueStream): the wall clock once the states are read.
      const auto stamp = std::chrono::system_clock::now().time_since_epoch();
      reply = protocol::encodeStateReply(
          ctx.header, sw->world->time(), total, out,
          uint64_t(std::chrono::duration_cast<std::chrono::nanoseconds>(stamp).count()),
          sw->epoch);
      return finish();
    }
    case wire::Request::GetWorld: {
      ctx.header.tick = sw->tick;
      reply = protocol::encodeWorldSettingsReply(ctx.header, sw->world->def(), sw->preset);
      return finish();
    }
    case wire::Request::GetBodies:
    case wire::Request::GetJoints: {
      st = readDefinitions(*sw, c, &ctx.header, &reply);
      return finish();
    }
    case wire::Request::SaveSnapshot: {
      auto* r = c.request_as_SaveSnapshot();
      const std::string file = r->file() ? r->file()->str() : "";
      if (!file.empty() && config_.snapshotDir.empty()) {
        st = err(Code::Unsupported, "save_snapshot.file: this server has no snapshot directory");
        return finish();
      }
      protocol::SnapshotData data;
      phys::Status ps = sw->world->saveSnapshot(&data.engineState);
      if (!ps.ok()) {
        st = fromPhys(ps, "save_snapshot");
        st.code = Code::IncorrectState;
        return finish();
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
      if (r->return_bytes() && snap.size() + 1024 > config_.limits.maxMessageBytes) {
        st = err(Code::ResourceExhausted,
                 "save_snapshot: the snapshot is " + std::to_string(snap.size()) +
                     " bytes, more than a reply holds (max_message_bytes); save it to a file");
        return finish();
      }
      if (!file.empty()) {
        std::error_code ec;
        fs::create_directories(config_.snapshotDir, ec);
        const std::string path = underDir(config_.snapshotDir, file, "");
        // The directory's quota: files and bytes after this save (a file of the same name is
        // replaced, so it does not count).
        uint64_t files = 1, bytes = snap.size();
        for (const auto& e : fs::directory_iterator(config_.snapshotDir, ec)) {
          std::error_code fe;
          if (!e.is_regular_file(fe) || e.path().filename() == file) continue;
          ++files;
          bytes += e.file_size(fe);
        }
        if (files > config_.maxSnapshotFiles || bytes > config_.maxSnapshotBytes) {
          st = err(Code::ResourceExhausted,
                   "save_snapshot.file: the snapshot directory would hold " +
                       std::to_string(files) + " files and " + std::to_string(bytes) +
                       " bytes, the limits are " + std::to_string(config_.maxSnapshotFiles) +
                       " files (server.max_snapshot_files) and " +
                       std::to_string(config_.maxSnapshotBytes) +
                       " bytes (server.max_snapshot_mb); overwrite an old file instead");
          return finish();
        }
        // Written aside, synced and renamed (as checkpoints are): a failed write never leaves
        // a torn snapshot.
        if (Status w = writeFileAtomically(path, snap); !w.ok()) {
          st = err(Code::Internal, "save_snapshot.file: cannot write '" + file + "': " + w.message);
          return finish();
        }
      }
      ctx.header.tick = sw->tick;
      reply = protocol::encodeSnapshotReply(
          ctx.header,
          r->return_bytes() ? std::span<const uint8_t>(snap) : std::span<const uint8_t>(), file);
      return finish();
    }
    case wire::Request::RestoreSnapshot: {
      auto* r = c.request_as_RestoreSnapshot();
      protocol::Decoded<wire::Snapshot> decoded;
      if (r->file() && r->file()->size()) {
        const std::string path = underDir(config_.snapshotDir, r->file()->str(), "");
        if (config_.snapshotDir.empty() || !fs::exists(path)) {
          st = err(Code::NotFound,
                   "restore_snapshot.file '" + r->file()->str() + "' is not a snapshot file");
          return finish();
        }
        st = checkGrowth(nullptr, 0, 0, "restore_snapshot");  // the memory budget, before reading
        if (!st.ok()) return finish();
        std::error_code ec;
        const uintmax_t size = fs::file_size(path, ec);
        if (ec || size > config_.maxSnapshotBytes) {
          st = err(ec ? Code::NotFound : Code::ResourceExhausted,
                   "restore_snapshot.file '" + r->file()->str() + "' " +
                       (ec ? "cannot be read"
                           : "is " + std::to_string(size) + " bytes, more than " +
                                 std::to_string(config_.maxSnapshotBytes) +
                                 " (server.max_snapshot_mb)"));
          return finish();
        }
        std::ifstream f(path, std::ios::binary);
        std::vector<uint8_t> bytes(size);
        f.read(reinterpret_cast<char*>(bytes.data()), std::streamsize(size));
        if (!f) {
          st = err(Code::NotFound, "restore_snapshot.file '" + r->file()->str() + "' cannot be read");
          return finish();
        }
        // A file is not a message: its own size bound (server.max_snapshot_mb).
        protocol::Limits fileLimits = config_.limits;
        fileLimits.maxMessageBytes =
            uint32_t(std::min<uint64_t>(config_.maxSnapshotBytes, UINT32_MAX));
        fileLimits.maxTables = UINT32_MAX;  // then bytes / 8 + 16, as for any payload
        decoded = protocol::decodeSnapshot(std::move(bytes), fileLimits);
        if (!decoded.ok()) {
          st = decoded.status;
          st.message = "restore_snapshot.file: " + st.message;
          return finish();
        }
      } else if (!r->snapshot()) {
        st = err(Code::Malformed, "restore_snapshot needs snapshot or file");
        return finish();
      } else {
        decoded = protocol::decodeSnapshot(
            std::span<const uint8_t>(r->snapshot()->data(), r->snapshot()->size()), config_.limits);
        if (!decoded.ok()) {
          st = decoded.status;
          return finish();
        }
      }
      if (!decoded->engine_state()) {
        // The portable form's counts, before anything is converted or built.
        const uint64_t nb = decoded->bodies() ? decoded->bodies()->size() : 0;
        const uint64_t nj = decoded->joints() ? decoded->joints()->size() : 0;
        if (nb + nj > protocol::maxIdsPerReply(config_.limits)) {
          st = err(Code::ResourceExhausted,
                   "restore_snapshot: the snapshot has " + std::to_string(nb) + " bodies and " +
                       std::to_string(nj) + " joints; one reply lists at most " +
                       std::to_string(protocol::maxIdsPerReply(config_.limits)) +
                       " new ids (max_ids_per_reply): save it with engine state instead");
          return finish();
        }
        st = checkGrowth(nullptr, nb, nj, "restore_snapshot", uint64_t(sw->world->bodyCount()));
        if (!st.ok()) return finish();
      }
      protocol::SnapshotData data;
      st = protocol::toSnapshotData(*decoded, &data);
      if (!st.ok()) return finish();
      if (!data.engineState.empty()) {
        // Restored aside and checked by the codec's rules before it replaces the world.
        auto scratch = std::make_unique<phys::World>(sw->world->def());
        phys::Status ps = scratch->restoreSnapshot(data.engineState.data(), data.engineState.size());
        if (!ps.ok()) {
          st = fromPhys(ps, "restore_snapshot.snapshot.engine_state");
          return finish();
        }
        applyPolicy(*scratch);  // the server's contact budget, whatever the snapshot says
        st = checkRestored(*scratch, "restore_snapshot.snapshot.engine_state");
        if (!st.ok()) return finish();
        st = checkGrowth(nullptr, uint64_t(scratch->bodyCount()), uint64_t(scratch->jointCount()),
                         "restore_snapshot", uint64_t(sw->world->bodyCount()));
        if (!st.ok()) return finish();
        cancelJob(*sw, "replaced by restore_snapshot");
        sw->world = std::move(scratch);
      } else {
        // Portable form: a fresh world from the definitions, saved ids mapped to new ones,
        // with the snapshot's settings (those it lacks: this world's).
        phys::WorldDef def = sw->world->def();
        def.gravity = data.gravity;
        def.timeStep = data.timeStep;
        def.solver = data.solver;
        protocol::applyOverrides(data.settings, &def);
        st = protocol::checkWorldSettings(def, config_.limits, "restore_snapshot.snapshot");
        for (size_t i = 0; st.ok() && i < data.bodies.size(); ++i)
          st = protocol::checkBodyDef(data.bodies[i].def, config_.limits,
                                      "restore_snapshot.snapshot.bodies[" + std::to_string(i) +
                                          "].def");
        for (size_t i = 0; st.ok() && i < data.joints.size(); ++i)
          st = protocol::checkJointDef(data.joints[i].def, config_.limits,
                                       "restore_snapshot.snapshot.joints[" + std::to_string(i) +
                                           "].def");
        if (!st.ok()) return finish();
        if (phys::Status ps = phys::World::validate(def); !ps.ok()) {
          st = fromPhys(ps, "restore_snapshot.snapshot");
          return finish();
        }
        auto fresh = std::make_unique<phys::World>(def);
        std::map<uint64_t, phys::BodyId> map;
        for (size_t i = 0; i < data.bodies.size(); ++i) {
          phys::BodyId id;
          phys::Status ps = fresh->createBody(data.bodies[i].def, &id);
          if (!ps.ok()) {
            st = fromPhys(ps, "restore_snapshot.snapshot.bodies[" + std::to_string(i) + "]");
            return finish();
          }
          map[data.bodies[i].id] = id;
          ctx.ids.bodies.push_back(id.packed());
        }
        for (size_t i = 0; i < data.joints.size(); ++i) {
          phys::JointDef d = data.joints[i].def;
          d.bodyA = d.bodyA.isNull() ? phys::BodyId{} : map[d.bodyA.packed()];
          d.bodyB = map[d.bodyB.packed()];
          phys::JointId id;
          phys::Status ps = fresh->createJoint(d, &id);
          if (!ps.ok()) {
            st = fromPhys(ps, "restore_snapshot.snapshot.joints[" + std::to_string(i) + "]");
            return finish();
          }
          ctx.ids.joints.push_back(id.packed());
        }
        cancelJob(*sw, "replaced by restore_snapshot");
        sw->world = std::move(fresh);
        ctx.header.tick = data.tick;
        sw->tick = data.tick;
        ++sw->revision;
        sw->framesReplaced();  // a new world: subscribers start from a keyframe
        sw->infoDirty = sw->frameDirty = true;
        st = durableReplaced(*sw, "restore_snapshot");
        if (st.ok())
          reply = protocol::encodeIdsReply(ctx.header, ctx.ids.bodies, ctx.ids.joints);
        else
          ctx.ids = {};
        return finish();
      }
      sw->tick = data.tick;
      sw->accumulator = 0;
      ++sw->revision;
      sw->framesReplaced();  // a new world: subscribers start from a keyframe
      sw->infoDirty = sw->frameDirty = true;
      ctx.header.tick = sw->tick;
      st = durableReplaced(*sw, "restore_snapshot");
      return finish();
    }
    case wire::Request::Batch: {
      auto* v = c.request_as_Batch()->commands();
      if (!v) {
        st = err(Code::Malformed, "batch.commands is missing");
        return finish();
      }
      std::vector<std::pair<wire::Request, const void*>> items;
      std::vector<std::string> paths;
      for (uint32_t i = 0; i < v->size(); ++i) {
        items.emplace_back(v->Get(i)->request_type(), v->Get(i)->request());
        paths.push_back("batch.commands[" + std::to_string(i) + "].");
      }
      st = ctx.editAll(*sw, items, paths);
      return finish();
    }
    default:
      if (protocol::isBatchable(type)) {
        st = ctx.editAll(*sw, {{type, c.request()}}, {""});
        return finish();
      }
      st = err(Code::Unsupported,
               std::string("request ") + protocol::requestName(type) + " is not supported");
      return finish();
  }
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
