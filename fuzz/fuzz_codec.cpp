// Fuzz target: the codec. Every input goes to every decoder of phys/protocol/decoder.h (each
// rejects a foreign file identifier at once, so a valid message of any kind reaches its own
// decoder and mutations of the identifier reach the others), both as a span and as an owned
// vector, and to the envelope check. Whatever a decoder accepts is then read the way the
// server and the SDK read it: converted to phys types (toBodyDef, toJointDef, solver settings,
// toWorldSummary, toSnapshotData, expandState), bodies created in a world, nested snapshots
// decoded, an engine snapshot restored into a world.
//
// Besides crashes and sanitizer reports, it aborts when the codec breaks its own contract:
//   - a rejection without a message, with code Ok or Internal;
//   - an accepted command whose nested snapshot does not decode on its own;
//   - an accepted body or joint (a command's, a world info's, a portable snapshot's) that
//     converts but fails validate.h's rules, which physd applies to everything it creates
//     (decoder.h and validate.h must agree);
//   - a portable snapshot that decodes and converts but whose re-encoding does not decode.
#include <cstdio>
#include <cstdlib>
#include <span>
#include <string>
#include <vector>

#include "phys/protocol/builder.h"
#include "phys/protocol/cluster.h"
#include "phys/protocol/compact.h"
#include "phys/protocol/convert.h"
#include "phys/protocol/dds_envelope.h"
#include "phys/protocol/decoder.h"
#include "phys/protocol/validate.h"
#include "phys/scene/scene.h"

namespace {

using namespace phys::protocol;
namespace wire = phys::wire;

[[noreturn]] void die(const std::string& what) {
  std::fprintf(stderr, "fuzz_codec: %s\n", what.c_str());
  std::fflush(stderr);
  std::abort();
}

/// Keeps reads of decoded values from being optimized away.
volatile double gSink = 0;
void sink(double v) { gSink = gSink + v; }
void sink(const flatbuffers::String* s) {
  if (s) sink(double(s->size() ? uint8_t(s->c_str()[s->size() - 1]) : 0));
}

template <class T>
bool accepted(const Decoded<T>& d, const char* what) {
  if (d.ok()) {
    if (!d.root || d.bytes.empty()) die(std::string(what) + ": accepted without a root or bytes");
    return true;
  }
  if (d.status.message.empty() || d.status.code == Code::Ok || d.status.code == Code::Internal)
    die(std::string(what) + ": rejected with code " + toString(d.status.code) + " and message '" +
        d.status.message + "'");
  if (d.root) die(std::string(what) + ": rejected but has a root");
  return false;
}

const Limits kLimits;

void body(const wire::BodyDef& in, const std::string& path, HullCache* cache,
          phys::World* world) {
  phys::BodyDef def;
  Status st = toBodyDef(in, &def, path, cache);
  if (!st.ok()) {
    if (st.code != Code::InvalidArgument || st.message.empty())
      die(path + ": toBodyDef failed with " + toString(st.code) + ": " + st.message);
    return;
  }
  st = checkBodyDef(def, kLimits, path);
  if (!st.ok()) die(path + ": decoded and converted, but validate.h rejects it: " + st.message);
  if (world) {
    phys::BodyId id;
    (void)world->createBody(def, &id);
  }
}

void joint(const wire::JointDef& in, const std::string& path) {
  phys::JointDef def = toJointDef(in);
  Status st = checkJointDef(def, kLimits, path);
  if (!st.ok()) die(path + ": decoded and converted, but validate.h rejects it: " + st.message);
}

void solver(const wire::SolverSettings& in) {
  phys::SolverSettings s;
  applySolverSettings(in, &s);
  SolverOverrides o = toOverrides(in);
  phys::SolverSettings t;
  applyOverrides(o, &t);
  (void)o.empty();
  (void)phys::World::validate(s);
  (void)phys::World::validate(t);
}

void summary(const wire::WorldSummary& in) {
  WorldSummary s = toWorldSummary(in);
  sink(double(s.tick) + s.time + s.rateHz + double(s.name.size() + s.backendNote.size()));
}

void snapshot(const wire::Snapshot& in) {
  SnapshotData data;
  Status st = toSnapshotData(in, &data);
  if (!st.ok()) {
    if (st.code != Code::InvalidArgument || st.message.empty())
      die("toSnapshotData failed with " + std::string(toString(st.code)) + ": " + st.message);
    return;
  }
  if (!data.engineState.empty()) {
    // The engine's own format, restored as physd restores it: into a scratch world.
    phys::WorldDef def;
    def.threads = 1;
    phys::World w(def);
    (void)w.restoreSnapshot(data.engineState.data(), data.engineState.size());
    return;
  }
  for (size_t i = 0; i < data.bodies.size(); ++i) {
    Status b = checkBodyDef(data.bodies[i].def, kLimits, "snapshot.bodies");
    if (!b.ok()) die("a decoded snapshot's body fails validate.h: " + b.message);
  }
  for (size_t i = 0; i < data.joints.size(); ++i) {
    Status j = checkJointDef(data.joints[i].def, kLimits, "snapshot.joints");
    if (!j.ok()) die("a decoded snapshot's joint fails validate.h: " + j.message);
  }
  // What a tool does with it: write it out again. It must still decode.
  Decoded<wire::Snapshot> again = decodeSnapshot(encodeSnapshot(data));
  if (!again.ok())
    die("a decoded snapshot re-encoded does not decode: " + std::string(toString(again.status.code)) +
        ": " + again.status.message);
}

void nestedSnapshot(const flatbuffers::Vector<uint8_t>* bytes, bool mustDecode) {
  if (!bytes || bytes->size() == 0) return;
  Decoded<wire::Snapshot> s = decodeSnapshot(std::span<const uint8_t>(bytes->data(), bytes->size()));
  if (mustDecode && !s.ok())
    die("an accepted command's snapshot does not decode: " + s.status.message);
  if (accepted(s, "nested snapshot")) snapshot(*s);
}

void request(wire::Request type, const void* table, int depth) {
  (void)requestName(type);
  (void)needsWorld(type);
  (void)isBatchable(type);
  if (!table) return;
  switch (type) {
    case wire::Request::Hello: {
      auto* r = static_cast<const wire::Hello*>(table);
      sink(r->protocol_version());
      sink(r->client_name());
      break;
    }
    case wire::Request::CreateWorld: {
      auto* r = static_cast<const wire::CreateWorld*>(table);
      sink(r->name());
      sink(r->preset());
      if (r->gravity()) sink(toPhys(*r->gravity()).z);
      phys::Backend b;
      if (r->backend()) (void)phys::parseBackend(r->backend()->str(), &b);
      sink(r->time_step() + r->sleep() + r->ephemeral());
      if (r->editors())
        for (uint64_t id : *r->editors()) sink(double(id));
      break;
    }
    case wire::Request::LoadScene: {
      auto* r = static_cast<const wire::LoadScene*>(table);
      sink(r->scene_name());
      if (r->json()) {
        // The server parses it with budgets from its limits (fuzz_scene goes further).
        phys::SceneBudget budget;
        budget.maxBodies = budget.maxJoints = 256;
        budget.maxShapes = 1024;
        budget.maxHullPointsTotal = 8192;
        phys::Scene scene;
        (void)phys::parseScene(r->json()->str(), "load_scene.json", &scene, budget);
      }
      break;
    }
    case wire::Request::SpawnBodies: {
      auto* r = static_cast<const wire::SpawnBodies*>(table);
      if (!r->bodies()) break;
      phys::WorldDef def;
      def.threads = 1;
      phys::World w(def);
      HullCache cache;
      for (uint32_t i = 0; i < r->bodies()->size(); ++i)
        body(*r->bodies()->Get(i), "spawn_bodies.bodies[" + std::to_string(i) + "]", &cache, &w);
      break;
    }
    case wire::Request::AddJoints: {
      auto* r = static_cast<const wire::AddJoints*>(table);
      if (!r->joints()) break;
      for (uint32_t i = 0; i < r->joints()->size(); ++i)
        joint(*r->joints()->Get(i), "add_joints.joints[" + std::to_string(i) + "]");
      break;
    }
    case wire::Request::RemoveBodies:
      if (auto* v = static_cast<const wire::RemoveBodies*>(table)->bodies())
        for (uint64_t id : *v) sink(double(id));
      break;
    case wire::Request::RemoveJoints:
      if (auto* v = static_cast<const wire::RemoveJoints*>(table)->joints())
        for (uint64_t id : *v) sink(double(id));
      break;
    case wire::Request::SetBodyPose:
      if (auto* v = static_cast<const wire::SetBodyPose*>(table)->items())
        for (const wire::BodyPose* p : *v) sink(toPhys(p->pose()).q.w + double(p->id()));
      break;
    case wire::Request::SetBodyVelocity:
      if (auto* v = static_cast<const wire::SetBodyVelocity*>(table)->items())
        for (const wire::BodyVelocity* p : *v) sink(toPhys(p->linear()).x + toPhys(p->angular()).y);
      break;
    case wire::Request::ApplyForce:
    case wire::Request::ApplyImpulse: {
      const flatbuffers::Vector<const wire::BodyForce*>* v =
          type == wire::Request::ApplyForce ? static_cast<const wire::ApplyForce*>(table)->items()
                                            : static_cast<const wire::ApplyImpulse*>(table)->items();
      if (v)
        for (const wire::BodyForce* f : *v) sink(toPhys(f->vector()).x + toPhys(f->point()).z);
      break;
    }
    case wire::Request::ApplyTorque:
      if (auto* v = static_cast<const wire::ApplyTorque*>(table)->items())
        for (const wire::BodyTorque* t : *v) sink(toPhys(t->torque()).x);
      break;
    case wire::Request::SetMaterial: {
      auto* r = static_cast<const wire::SetMaterial*>(table);
      if (r->material()) sink(toPhys(*r->material()).density);
      break;
    }
    case wire::Request::SetSolver: {
      auto* r = static_cast<const wire::SetSolver*>(table);
      sink(r->preset());
      if (r->settings()) solver(*r->settings());
      break;
    }
    case wire::Request::QueryState: {
      auto* r = static_cast<const wire::QueryState*>(table);
      if (r->bodies())
        for (uint64_t id : *r->bodies()) sink(double(id));
      sink(r->first() + double(r->max_count()));
      break;
    }
    case wire::Request::Subscribe: {
      auto* r = static_cast<const wire::Subscribe*>(table);
      if (r->bodies())
        for (uint64_t id : *r->bodies()) sink(double(id));
      if (r->region_min()) sink(toPhys(*r->region_min()).x);
      if (r->region_max()) sink(toPhys(*r->region_max()).x);
      break;
    }
    case wire::Request::SetAccess: {
      auto* r = static_cast<const wire::SetAccess*>(table);
      if (r->editors())
        for (uint64_t id : *r->editors()) sink(double(id));
      sink(r->shared());
      break;
    }
    case wire::Request::SetWorld: {
      // Settings the codec accepts are settings the server's own check (validate.h) accepts,
      // over the defaults a world starts with.
      auto* r = static_cast<const wire::SetWorld*>(table);
      if (!r->settings()) die("a set_world without settings was accepted");
      phys::WorldDef def;
      applyOverrides(toOverrides(*r->settings()), &def);
      Status st = checkWorldSettings(def, kLimits, "set_world.settings");
      if (!st.ok()) die("set_world accepted by the decoder, refused by validate: " + st.message);
      sink(def.gravity.x + def.timeStep);
      break;
    }
    case wire::Request::GetBodies:
    case wire::Request::GetJoints: {
      auto* v = type == wire::Request::GetBodies
                    ? static_cast<const wire::GetBodies*>(table)->bodies()
                    : static_cast<const wire::GetJoints*>(table)->joints();
      if (v)
        for (uint64_t id : *v) sink(double(id));
      break;
    }
    case wire::Request::SaveSnapshot:
      sink(static_cast<const wire::SaveSnapshot*>(table)->file());
      break;
    case wire::Request::MoveWorld: {
      const uint64_t d = static_cast<const wire::MoveWorld*>(table)->daemon();
      if (d == 0 || d > kMaxClusterDaemonId) die("a move_world to no daemon was accepted");
      sink(double(d));
      break;
    }
    case wire::Request::RestoreSnapshot: {
      auto* r = static_cast<const wire::RestoreSnapshot*>(table);
      sink(r->file());
      nestedSnapshot(r->snapshot(), /*mustDecode=*/true);
      break;
    }
    case wire::Request::Batch: {
      auto* r = static_cast<const wire::Batch*>(table);
      if (depth > 0) die("a batch inside a batch was accepted");
      if (r->commands())
        for (const wire::CommandItem* item : *r->commands()) {
          if (!isBatchable(item->request_type()))
            die(std::string("a batch holding ") + requestName(item->request_type()) +
                " was accepted");
          request(item->request_type(), item->request(), depth + 1);
        }
      break;
    }
    default:
      break;
  }
}

void command(const wire::Command& c) {
  sink(double(c.client_id() + c.seq() + c.world()));
  if (c.client_id() == 0) die("a command with client_id 0 was accepted");
  if (!c.request()) die("a command without a request was accepted");
  if (needsWorld(c.request_type()) && c.world() == 0)
    die(std::string("a ") + requestName(c.request_type()) + " without a world was accepted");
  request(c.request_type(), c.request(), 0);
}

void reply(const wire::Reply& r) {
  sink(toString(r.status())[0]);
  sink(r.message());
  switch (r.result_type()) {
    case wire::Result::HelloResult: {
      auto* h = r.result_as_HelloResult();
      sink(h->server_name());
      sink(h->server_version());
      if (h->features())
        for (const flatbuffers::String* f : *h->features()) sink(f);
      if (h->limits()) sink(double(h->limits()->max_body_steps_per_command()));
      break;
    }
    case wire::Result::Ids: {
      auto* ids = r.result_as_Ids();
      if (ids->bodies())
        for (uint64_t id : *ids->bodies()) sink(double(id));
      if (ids->joints())
        for (uint64_t id : *ids->joints()) sink(double(id));
      break;
    }
    case wire::Result::WorldList:
      if (auto* w = r.result_as_WorldList()->worlds())
        for (const wire::WorldSummary* s : *w) summary(*s);
      break;
    case wire::Result::StateResult:
      if (auto* b = r.result_as_StateResult()->bodies())
        for (const wire::BodyState* s : *b) sink(s->position().x());
      break;
    case wire::Result::SnapshotResult: {
      auto* s = r.result_as_SnapshotResult();
      sink(s->file());
      nestedSnapshot(s->snapshot(), /*mustDecode=*/false);  // the SDK decodes it on its own
      break;
    }
    case wire::Result::InterestResult:
      sink(r.result_as_InterestResult()->topic());
      break;
    case wire::Result::WorldSettingsResult: {
      auto* w = r.result_as_WorldSettingsResult();
      phys::WorldDef def;
      if (w->settings()) applyOverrides(toOverrides(*w->settings()), &def);
      if (w->solver()) applySolverSettings(*w->solver(), &def.solver);
      sink(def.sleep.time + def.solver.iterations);
      sink(w->preset());
      break;
    }
    case wire::Result::BodiesResult:
      if (auto* v = r.result_as_BodiesResult()->bodies()) {
        HullCache cache;
        for (uint32_t i = 0; i < v->size(); ++i) {
          BodyInfo info;
          if (toBodyInfo(*v->Get(i), &info, "bodies_result.bodies", &cache).ok())
            sink(info.mass.mass + info.mass.inertiaRotation.w);
        }
      }
      break;
    case wire::Result::JointsResult:
      if (auto* v = r.result_as_JointsResult()->joints())
        for (uint32_t i = 0; i < v->size(); ++i)
          if (v->Get(i)->def())
            joint(*v->Get(i)->def(), "joints_result.joints[" + std::to_string(i) + "]");
      break;
    default:
      break;
  }
}

void stateFrame(const wire::StateFrame& f) {
  if (f.bodies())
    for (const wire::BodyState* s : *f.bodies()) sink(s->linear_velocity().z());
  if (f.removed())
    for (uint64_t id : *f.removed()) sink(double(id));
  if (f.compact()) {
    CompactBounds b;
    if (f.bounds_min()) b.lo = toPhys(*f.bounds_min());
    if (f.bounds_max()) b.hi = toPhys(*f.bounds_max());
    for (const wire::CompactBodyState* c : *f.compact()) {
      wire::BodyState s = expandState(*c, b);
      sink(s.rotation().w());
    }
  }
}

void worldInfo(const wire::WorldInfo& w) {
  sink(w.name());
  if (w.bodies()) {
    HullCache cache;
    for (uint32_t i = 0; i < w.bodies()->size(); ++i) {
      const wire::BodyEntry* e = w.bodies()->Get(i);
      if (e->def())
        body(*e->def(), "world_info.bodies[" + std::to_string(i) + "]", &cache, nullptr);
    }
  }
  if (w.joints())
    for (uint32_t i = 0; i < w.joints()->size(); ++i) {
      const wire::JointEntry* e = w.joints()->Get(i);
      if (e->def()) joint(*e->def(), "world_info.joints[" + std::to_string(i) + "]");
    }
}

void envelope(std::span<const uint8_t> bytes) {
  phys_wire_Envelope env{};
  const uint16_t kind = bytes.size() >= 2 ? uint16_t(bytes[0] | bytes[1] << 8) : 0;
  wrapEnvelope(&env, 1, 1, PayloadKind(kind % 8), bytes);
  if (bytes.size() >= 3 && bytes[2] == 0xEE) env.schema_version = uint16_t(bytes.size());
  for (int k = 1; k <= 6; ++k) {
    Status st = checkEnvelope(env, PayloadKind(k));
    if (st.ok() != (env.kind == k && env.schema_version == kProtocolVersion &&
                    bytes.size() <= kLimits.maxMessageBytes))
      die("checkEnvelope disagrees with the envelope's header");
    (void)envelopeBytes(env);
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::span<const uint8_t> in(data, size);
  if (auto d = decodeCommand(in); accepted(d, "command")) command(*d);
  if (auto d = decodeReply(in); accepted(d, "reply")) reply(*d);
  if (auto d = decodeStateFrame(in); accepted(d, "state frame")) stateFrame(*d);
  if (auto d = decodeWorldInfo(in); accepted(d, "world info")) worldInfo(*d);
  if (auto d = decodeServerStatus(in); accepted(d, "server status")) {
    sink(d->server_name());
    if (d->worlds())
      for (const wire::WorldSummary* s : *d->worlds()) summary(*s);
  }
  if (auto d = decodeEvent(in); accepted(d, "event")) {
    sink(d->code());
    sink(d->message());
  }
  if (auto d = decodeSnapshot(in); accepted(d, "snapshot")) snapshot(*d);

  // The owning overloads (the SDK's receive path), on the decoder the identifier names; the
  // result must agree with the span decoder's.
  if (size >= 8) {
    const std::string id(reinterpret_cast<const char*>(data) + 4, 4);
    std::vector<uint8_t> copy(data, data + size);
    bool owned = true, viewed = true;
    if (id == wire::kCommandId) {
      owned = decodeCommand(std::move(copy)).ok(), viewed = decodeCommand(in).ok();
    } else if (id == wire::kReplyId) {
      owned = decodeReply(std::move(copy)).ok(), viewed = decodeReply(in).ok();
    } else if (id == wire::kStateFrameId) {
      owned = decodeStateFrame(std::move(copy)).ok(), viewed = decodeStateFrame(in).ok();
    } else if (id == wire::kWorldInfoId) {
      owned = decodeWorldInfo(std::move(copy)).ok(), viewed = decodeWorldInfo(in).ok();
    } else if (id == wire::kServerStatusId) {
      owned = decodeServerStatus(std::move(copy)).ok(), viewed = decodeServerStatus(in).ok();
    } else if (id == wire::kEventId) {
      owned = decodeEvent(std::move(copy)).ok(), viewed = decodeEvent(in).ok();
    } else if (id == wire::kSnapshotId) {
      owned = decodeSnapshot(std::move(copy)).ok(), viewed = decodeSnapshot(in).ok();
    }
    if (owned != viewed) die("the owning and the span decoder disagree");
  }
  envelope(in);
  return 0;
}
