#include "messages.h"

#include <cstring>
#include <unordered_map>

#include "phys/protocol/convert.h"
#include "phys/protocol/decoder.h"
#include "phys/world/world.h"

namespace physview {

namespace {

/// Appends 32-bit words to a byte buffer (little-endian hosts only: x86-64, arm64).
struct Writer {
  std::vector<uint8_t>* out;
  size_t at = 0;
  void u32(uint32_t v) {
    std::memcpy(out->data() + at, &v, 4);
    at += 4;
  }
  void f32(float v) {
    std::memcpy(out->data() + at, &v, 4);
    at += 4;
  }
  void f64(double v) {
    std::memcpy(out->data() + at, &v, 8);
    at += 8;
  }
};

static_assert(sizeof(float) == 4 && sizeof(double) == 8);

}  // namespace

void encodeFrame(const phys::client::StateFrame& frame, const FrameExtras& extras,
                 std::vector<uint8_t>* out) {
  const size_t n = frame.bodies.size();
  out->resize(kFrameHeaderBytes + n * kFrameBodyWords * 4);
  Writer w{out};
  w.u32(kFrameMessage);
  w.u32(frame.world);
  w.u32(uint32_t(frame.tick & 0xffffffffu));
  w.u32(uint32_t(frame.tick >> 32));
  w.f64(frame.time);
  w.f32(extras.tickMs);
  w.u32(extras.awake);
  w.u32(frame.total);
  w.u32(uint32_t(n));
  w.u32(extras.contacts);
  w.u32(extras.running ? kFrameRunning : 0);
  for (const phys::client::BodyState& b : frame.bodies) {
    w.u32(uint32_t(b.id & 0xffffffffu));
    w.u32(uint32_t(b.id >> 32));
    w.f32(b.position.x);
    w.f32(b.position.y);
    w.f32(b.position.z);
    w.f32(b.rotation.x);
    w.f32(b.rotation.y);
    w.f32(b.rotation.z);
    w.f32(b.rotation.w);
  }
}

namespace {

ShapeDesc describeShape(const phys::ShapeDef& def) {
  ShapeDesc s;
  s.type = def.geom.type;
  s.local = def.local;
  const phys::ShapeGeom& g = def.geom;
  switch (g.type) {
    case phys::ShapeType::Sphere:
      s.dims[0] = g.radius;
      break;
    case phys::ShapeType::Box:
      s.dims[0] = g.halfExtents.x;
      s.dims[1] = g.halfExtents.y;
      s.dims[2] = g.halfExtents.z;
      break;
    case phys::ShapeType::Capsule:
      s.dims[0] = g.radius;
      s.dims[1] = g.halfHeight;
      break;
    case phys::ShapeType::Plane:
      s.dims[0] = g.normal.x;
      s.dims[1] = g.normal.y;
      s.dims[2] = g.normal.z;
      s.dims[3] = g.offset;
      break;
    case phys::ShapeType::Hull:
      s.hull = g.hull;
      break;
  }
  return s;
}

}  // namespace

bool describeWorld(phys::client::WorldHandle world, std::chrono::milliseconds timeout,
                   std::vector<BodyDesc>* out, std::string* error) {
  out->clear();
  phys::client::Bytes bytes;
  try {
    bytes = world.saveSnapshot({timeout}).get();
  } catch (const phys::client::Error& e) {
    *error = std::string("SaveSnapshot: ") + phys::client::toString(e.code()) + ": " + e.message();
    return false;
  }
  auto snap = phys::protocol::decodeSnapshot(std::move(bytes));
  if (!snap.ok()) {
    *error = "the snapshot does not decode: " + snap.status.message;
    return false;
  }
  const auto* engine = snap->engine_state();
  if (engine && engine->size() > 0) {
    // What physd sends: the engine's own state. A local World reads it back.
    phys::World local;
    const phys::Status st = local.restoreSnapshot(engine->data(), engine->size());
    if (!st.ok()) {
      *error = "the engine state does not restore: " + st.message;
      return false;
    }
    const std::vector<phys::BodyId> ids = local.bodies();
    out->reserve(ids.size());
    for (phys::BodyId id : ids) {
      BodyDesc d;
      d.id = id.packed();
      phys::BodyState bs;
      if (local.getBody(id, &bs).ok()) d.type = bs.type;
      for (phys::ShapeId sid : local.bodyShapes(id)) {
        phys::ShapeDef def;
        phys::BodyId owner;
        if (local.getShape(sid, &def, &owner).ok()) d.shapes.push_back(describeShape(def));
      }
      out->push_back(std::move(d));
    }
    return true;
  }
  // A portable snapshot: the body definitions themselves.
  phys::protocol::SnapshotData data;
  const auto st = phys::protocol::toSnapshotData(*snap, &data);
  if (!st.ok()) {
    *error = "the snapshot's bodies do not convert: " + st.message;
    return false;
  }
  out->reserve(data.bodies.size());
  phys::HullBuildCache hulls;  // the wire carries a hull's points: built here to be drawn
  for (const phys::protocol::BodyEntry& e : data.bodies) {
    BodyDesc d;
    d.id = e.id;
    d.type = e.def.type;
    for (phys::ShapeDef s : e.def.shapes) {
      if (s.geom.type == phys::ShapeType::Hull) {
        std::string why;
        s.geom.hull = phys::buildHull(s.geom.hull, &why, &hulls);
        if (!s.geom.hull) {
          *error = "a hull of body " + std::to_string(e.id) + " does not build: " + why;
          return false;
        }
      }
      d.shapes.push_back(describeShape(s));
    }
    out->push_back(std::move(d));
  }
  return true;
}

void encodeShapes(uint32_t world, uint32_t flags, const std::vector<const BodyDesc*>& bodies,
                  std::vector<uint8_t>* out) {
  // Hulls first, each once, numbered in order of first use.
  std::unordered_map<const phys::ConvexHull*, uint32_t> hullIndex;
  std::vector<const phys::ConvexHull*> hulls;
  size_t words = kShapesHeaderBytes / 4;
  for (const BodyDesc* b : bodies) {
    words += 4 + b->shapes.size() * kShapeWords;
    for (const ShapeDesc& s : b->shapes) {
      if (s.type != phys::ShapeType::Hull || !s.hull) continue;
      if (hullIndex.emplace(s.hull.get(), uint32_t(hulls.size())).second) {
        hulls.push_back(s.hull.get());
        size_t triangles = 0;
        for (const auto& f : s.hull->faces)
          if (f.indices.size() >= 3) triangles += f.indices.size() - 2;
        words += 2 + s.hull->vertices.size() * 3 + triangles * 3;
      }
    }
  }
  out->resize(words * 4);
  Writer w{out};
  w.u32(kShapesMessage);
  w.u32(world);
  w.u32(flags);
  w.u32(uint32_t(bodies.size()));
  w.u32(uint32_t(hulls.size()));
  w.u32(0);
  for (const phys::ConvexHull* h : hulls) {
    size_t triangles = 0;
    for (const auto& f : h->faces)
      if (f.indices.size() >= 3) triangles += f.indices.size() - 2;
    w.u32(uint32_t(h->vertices.size()));
    w.u32(uint32_t(triangles * 3));
    for (const phys::Vec3& v : h->vertices) {
      w.f32(v.x);
      w.f32(v.y);
      w.f32(v.z);
    }
    // Faces are convex polygons, counter-clockwise seen from outside: fans.
    for (const auto& f : h->faces)
      for (size_t i = 2; i < f.indices.size(); ++i) {
        w.u32(f.indices[0]);
        w.u32(f.indices[i - 1]);
        w.u32(f.indices[i]);
      }
  }
  for (const BodyDesc* b : bodies) {
    w.u32(uint32_t(b->id & 0xffffffffu));
    w.u32(uint32_t(b->id >> 32));
    w.u32(uint32_t(b->type));
    w.u32(uint32_t(b->shapes.size()));
    for (const ShapeDesc& s : b->shapes) {
      w.u32(uint32_t(s.type));
      w.f32(s.local.p.x);
      w.f32(s.local.p.y);
      w.f32(s.local.p.z);
      w.f32(s.local.q.x);
      w.f32(s.local.q.y);
      w.f32(s.local.q.z);
      w.f32(s.local.q.w);
      if (s.type == phys::ShapeType::Hull) {
        auto it = s.hull ? hullIndex.find(s.hull.get()) : hullIndex.end();
        w.u32(it == hullIndex.end() ? 0xffffffffu : it->second);
        w.f32(0);
        w.f32(0);
        w.f32(0);
      } else {
        for (float d : s.dims) w.f32(d);
      }
    }
  }
}

}  // namespace physview
