// World snapshots: the whole state a world carries from one step to the next, saved bit for
// bit in a small explicit binary format, and restored all-or-nothing.
//
// Layout. Every field is little-endian and fixed-size; floats and doubles are stored as their
// IEEE-754 bits (std::bit_cast), never as whole structs, so padding and host layout never
// reach the bytes.
//   header   "PHYSNAP\0" (8 bytes), format version (u32), payload size (u64),
//            FNV-1a 64 of the payload (u64)
//   payload  sections in this fixed order, each a 4-character tag, its content's length in
//            bytes (u64), then the content:
//     WDEF   the world definition (gravity, time step, clamps, margins, pair bound, solver
//            settings, guard)
//     STAT   simulated time and StepStats (step count, guard counters, last guard event, pair
//            bound counters, failed steps, ...)
//     HULL   the convex hulls, each once (shapes refer to them by index)
//     BODY   \  the three id pools: capacity (u32), then per slot its generation (u32), alive
//     SHAP    > flag (u8) and, if alive, the record; then the free list (u32 count, indices)
//     JOIN   /  in its order (the next id handed out is its back)
//     CONT   the persistent contacts, sorted by shape pair, with manifolds and impulses
//     BRPH   the broad phase's fat box of every live shape, in shape index order
//     ISLE   the sleeping islands: capacity (u32), per slot its body slots (u32s), the
//            substep length of its impulses, its potential energy and its touching contacts
//            (as CONT), then the free list; bodies name their island (BODY)
// Variable-length parts are a u32 count then the elements; a count is rejected when the bytes
// left could not hold that many elements, so a corrupted count never makes a restore allocate
// more than a small multiple of the snapshot's size.
//
// Every record is described once, by a template over the archive (`io`), used both by the
// Writer and the Reader, so the two cannot disagree on the order of fields.
//
// The checksum finds damage, not intent: anyone who may restore a world can compute one. So a
// restore checks every field it takes against the world it describes (the read* functions
// below: ranges, references between records both ways, islands and sleep state, mass data,
// what the API would accept) or rebuilds it, and only then swaps the state in; a field the
// step later uses as an index is never taken on trust (docs/ARCHITECTURE.md, "Snapshots").
//
// Not saved, because each step rebuilds it before use: the broad phase's trees and pair
// list (pairs depend only on the live proxies' fat boxes and static flags), the solver's
// bodies and rows, the LDL factorization, the body pairs that must not collide (rebuilt from
// the joints), the guard's rollback copy, the profile. The thread count is the host's.
#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <memory>
#include <string>
#include <unordered_map>
#include <utility>
#include <vector>

#include "phys/world/world.h"
#include "world/world_impl.h"

namespace phys {
namespace {

static_assert(sizeof(float) == 4 && sizeof(double) == 8 && sizeof(int) == 4);
static_assert(std::numeric_limits<float>::is_iec559 && std::numeric_limits<double>::is_iec559);

// A field added to one of these structs must be added to its `io` below (and kVersion
// bumped), or snapshots silently lose it and restored worlds diverge. The sizes catch most
// additions; they are only checked where they were measured (libstdc++, 64-bit).
#if defined(__GLIBCXX__) && UINTPTR_MAX == UINT64_MAX
static_assert(sizeof(SolverSettings) == 88, "SolverSettings changed: update snapshot.cpp");
// WorldDef's backend and gpuAllowCpuDevice are not saved: where a world runs is the
// restoring process's choice.
static_assert(sizeof(WorldDef) == 164, "WorldDef changed: update snapshot.cpp");
static_assert(sizeof(StepStats) == 208, "StepStats changed: update snapshot.cpp");
static_assert(sizeof(BodyRec) == 352, "BodyRec changed: update snapshot.cpp");
static_assert(sizeof(ShapeGeom) == 56, "ShapeGeom changed: update snapshot.cpp");
static_assert(sizeof(ShapeRec) == 112, "ShapeRec changed: update snapshot.cpp");
static_assert(sizeof(JointDef) == 144, "JointDef changed: update snapshot.cpp");
static_assert(sizeof(JointRec) == 272, "JointRec changed: update snapshot.cpp");
static_assert(sizeof(Contact) == 196, "Contact changed: update snapshot.cpp");
static_assert(sizeof(ConvexHull) == 112, "ConvexHull changed: update snapshot.cpp");
#endif

constexpr char kMagic[8] = {'P', 'H', 'Y', 'S', 'N', 'A', 'P', '\0'};
// 2: SolverSettings::patchFriction; 3: stackStiffening; 4: WorldDef::maxContactPairs and
// pairOverflow, and the pair bound's, failed and refused steps' StepStats; 6:
// SolverSettings::directContactRatio.
constexpr uint32_t kVersion = 6;
constexpr size_t kHeaderSize = 8 + 4 + 8 + 8;
constexpr int kMaxGuardRetries = 1000;

uint64_t fnv1a(const uint8_t* p, size_t n) {
  uint64_t h = 1469598103934665603ull;
  for (size_t i = 0; i < n; ++i) {
    h ^= p[i];
    h *= 1099511628211ull;
  }
  return h;
}

void putU32(uint8_t* p, uint32_t v) {
  for (int i = 0; i < 4; ++i) p[i] = uint8_t(v >> (8 * i));
}
void putU64(uint8_t* p, uint64_t v) {
  for (int i = 0; i < 8; ++i) p[i] = uint8_t(v >> (8 * i));
}
uint32_t getU32(const uint8_t* p) {
  uint32_t v = 0;
  for (int i = 0; i < 4; ++i) v |= uint32_t(p[i]) << (8 * i);
  return v;
}
uint64_t getU64(const uint8_t* p) {
  uint64_t v = 0;
  for (int i = 0; i < 8; ++i) v |= uint64_t(p[i]) << (8 * i);
  return v;
}

using HullPtr = std::shared_ptr<const ConvexHull>;

// ---------------------------------------------------------------------------------------------
// Archives. Both expose the same calls; the Writer's take const references, the Reader's
// references it fills. Both name where they are (what, index) for their error messages.

class Writer {
 public:
  explicit Writer(std::vector<uint8_t>* out) : out_(out) {}
  static constexpr bool kReading = false;

  void u8(const uint8_t& v) { out_->push_back(v); }
  void u32(const uint32_t& v) {
    uint8_t b[4];
    putU32(b, v);
    out_->insert(out_->end(), b, b + 4);
  }
  void u64(const uint64_t& v) {
    uint8_t b[8];
    putU64(b, v);
    out_->insert(out_->end(), b, b + 8);
  }
  void i32(const int32_t& v) { u32(uint32_t(v)); }
  void flag(const bool& v) { u8(v ? 1 : 0); }
  template <class E>
  void e8(const E& v, E /*max*/) {
    u8(uint8_t(v));
  }
  void f32(const float& v) {
    if (!std::isfinite(v)) nonFinite();
    u32(std::bit_cast<uint32_t>(v));
  }
  void f64(const double& v) {
    if (!std::isfinite(v)) nonFinite();
    u64(std::bit_cast<uint64_t>(v));
  }
  void vec(const Vec3& v) {
    f32(v.x);
    f32(v.y);
    f32(v.z);
  }
  void quat(const Quat& q) {
    f32(q.x);
    f32(q.y);
    f32(q.z);
    f32(q.w);
  }
  void mat(const Mat3& m) {
    vec(m.c0);
    vec(m.c1);
    vec(m.c2);
  }
  void xf(const Transform& t) {
    vec(t.p);
    quat(t.q);
  }
  void box(const AABB& b) {
    vec(b.lo);
    vec(b.hi);
  }
  template <class Tag>
  void id(const Handle<Tag>& h) {
    u64(h.packed());
  }
  void str(const std::string& s) {
    u32(uint32_t(s.size()));
    out_->insert(out_->end(), s.begin(), s.end());
  }
  template <class Tag>
  void ids(const std::vector<Handle<Tag>>& v) {
    u32(uint32_t(v.size()));
    for (const Handle<Tag>& h : v) id(h);
  }
  void u32s(const std::vector<uint32_t>& v) {
    u32(uint32_t(v.size()));
    for (uint32_t x : v) u32(x);
  }
  void u32Pairs(const std::vector<std::pair<uint32_t, uint32_t>>& v) {
    u32(uint32_t(v.size()));
    for (const auto& [a, b] : v) {
      u32(a);
      u32(b);
    }
  }
  void hull(const HullPtr& h) {
    if (!h) {
      i32(-1);
      return;
    }
    auto [it, added] = hullIndex_.try_emplace(h.get(), uint32_t(hulls_.size()));
    if (added) hulls_.push_back(h.get());
    i32(int32_t(it->second));
  }

  /// Opens a section: its tag, and a length patched by endSection.
  size_t beginSection(const char* tag) {
    out_->insert(out_->end(), tag, tag + 4);
    size_t at = out_->size();
    u64(0);
    return at;
  }
  void endSection(size_t at) { putU64(out_->data() + at, uint64_t(out_->size() - at - 8)); }

  void where(const char* what, int64_t index = -1) {
    what_ = what;
    index_ = index;
  }
  const std::string& error() const { return error_; }
  /// Hulls in the order shapes first referred to them (filled while writing shapes).
  const std::vector<const ConvexHull*>& hulls() const { return hulls_; }
  std::vector<uint8_t>& bytes() { return *out_; }

 private:
  void nonFinite() {
    if (!error_.empty()) return;
    error_ = std::string("snapshot: ") + what_ +
             (index_ >= 0 ? " " + std::to_string(index_) : std::string()) +
             " holds a non-finite number; such a state cannot be restored";
  }
  std::vector<uint8_t>* out_;
  const char* what_ = "world";
  int64_t index_ = -1;
  std::string error_;
  std::unordered_map<const ConvexHull*, uint32_t> hullIndex_;
  std::vector<const ConvexHull*> hulls_;
};

class Reader {
 public:
  Reader(const uint8_t* data, size_t size, const std::vector<HullPtr>* hulls = nullptr)
      : p_(data), end_(data + size), hulls_(hulls) {}
  static constexpr bool kReading = true;

  bool ok() const { return error_.empty(); }
  const std::string& error() const { return error_; }
  size_t remaining() const { return size_t(end_ - p_); }
  /// Records the first error (with where it happened) and stops reading.
  void fail(const std::string& reason) {
    if (!error_.empty()) return;
    error_ = "snapshot: " + std::string(what_) +
             (index_ >= 0 ? " " + std::to_string(index_) : std::string()) + ": " + reason;
    p_ = end_;
  }
  void where(const char* what, int64_t index = -1) {
    what_ = what;
    index_ = index;
  }
  /// Takes a section reader's error as it is (it already says where).
  void failWith(const Reader& sub) {
    if (!error_.empty() || sub.ok()) return;
    error_ = sub.error_;
    p_ = end_;
  }

  void u8(uint8_t& v) { v = need(1) ? *p_++ : 0; }
  void u32(uint32_t& v) {
    v = need(4) ? getU32(p_) : 0;
    if (ok()) p_ += 4;
  }
  void u64(uint64_t& v) {
    v = need(8) ? getU64(p_) : 0;
    if (ok()) p_ += 8;
  }
  void i32(int32_t& v) {
    uint32_t u;
    u32(u);
    v = int32_t(u);
  }
  void flag(bool& v) {
    uint8_t b;
    u8(b);
    if (b > 1) fail("a flag byte is " + std::to_string(b) + ", not 0 or 1");
    v = b == 1;
  }
  template <class E>
  void e8(E& v, E max) {
    uint8_t b;
    u8(b);
    if (b > uint8_t(max)) fail("enum value " + std::to_string(b) + " is out of range");
    v = ok() ? E(b) : E{};
  }
  void f32(float& v) {
    uint32_t bits;
    u32(bits);
    v = std::bit_cast<float>(bits);
    if (!std::isfinite(v)) {
      fail("non-finite number");
      v = 0;
    }
  }
  void f64(double& v) {
    uint64_t bits;
    u64(bits);
    v = std::bit_cast<double>(bits);
    if (!std::isfinite(v)) {
      fail("non-finite number");
      v = 0;
    }
  }
  void vec(Vec3& v) {
    f32(v.x);
    f32(v.y);
    f32(v.z);
  }
  void quat(Quat& q) {
    f32(q.x);
    f32(q.y);
    f32(q.z);
    f32(q.w);
  }
  void mat(Mat3& m) {
    vec(m.c0);
    vec(m.c1);
    vec(m.c2);
  }
  void xf(Transform& t) {
    vec(t.p);
    quat(t.q);
  }
  void box(AABB& b) {
    vec(b.lo);
    vec(b.hi);
  }
  template <class Tag>
  void id(Handle<Tag>& h) {
    uint64_t v;
    u64(v);
    h = Handle<Tag>::fromPacked(v);
  }
  /// A count of elements of at least minBytes each, bounded by the bytes left.
  uint32_t count(size_t minBytes, const char* what) {
    uint32_t n;
    u32(n);
    if (ok() && n > remaining() / minBytes) {
      fail(std::string(what) + " count " + std::to_string(n) + " exceeds what the " +
           std::to_string(remaining()) + " remaining bytes can hold");
    }
    return ok() ? n : 0;
  }
  void str(std::string& s) {
    uint32_t n = count(1, "string length");
    s.assign(reinterpret_cast<const char*>(p_), n);
    p_ += n;
  }
  template <class Tag>
  void ids(std::vector<Handle<Tag>>& v) {
    uint32_t n = count(8, "id list");
    v.resize(n);
    for (Handle<Tag>& h : v) id(h);
  }
  void u32s(std::vector<uint32_t>& v) {
    uint32_t n = count(4, "index list");
    v.resize(n);
    for (uint32_t& x : v) u32(x);
  }
  void u32Pairs(std::vector<std::pair<uint32_t, uint32_t>>& v) {
    uint32_t n = count(8, "index pair list");
    v.resize(n);
    for (auto& [a, b] : v) {
      u32(a);
      u32(b);
    }
  }
  void hull(HullPtr& h) {
    int32_t i;
    i32(i);
    h = nullptr;
    if (!ok() || i == -1) return;
    if (i < 0 || !hulls_ || size_t(i) >= hulls_->size()) {
      fail("refers to hull " + std::to_string(i) + ", which does not exist");
      return;
    }
    h = (*hulls_)[size_t(i)];
  }

  /// The next section, which must be `tag`: a reader over its content.
  Reader section(const char* tag) {
    Reader sub(p_, 0, hulls_);
    where("section header");
    if (!need(12)) return sub;
    if (std::memcmp(p_, tag, 4) != 0) {
      fail(std::string("expected section ") + tag + ", found \"" +
           printable(std::string(reinterpret_cast<const char*>(p_), 4)) + "\"");
      return sub;
    }
    uint64_t len = getU64(p_ + 4);
    p_ += 12;
    if (len > remaining()) {
      fail(std::string("section ") + tag + " claims " + std::to_string(len) + " bytes, " +
           std::to_string(remaining()) + " remain");
      return sub;
    }
    sub = Reader(p_, size_t(len), hulls_);
    p_ += len;
    return sub;
  }
  /// After reading a section's content: everything read, nothing left over.
  void finishSection(const char* tag) {
    if (ok() && remaining() != 0) {
      where(tag);
      fail(std::to_string(remaining()) + " unread bytes at the end of the section");
    }
  }

 private:
  static std::string printable(std::string s) {
    for (char& c : s)
      if (c < 32 || c > 126) c = '?';
    return s;
  }
  bool need(size_t n) {
    if (!ok()) return false;
    if (remaining() < n) {
      fail("truncated: " + std::to_string(n) + " more bytes needed, " +
           std::to_string(remaining()) + " left");
      return false;
    }
    return true;
  }
  const uint8_t* p_;
  const uint8_t* end_;
  const std::vector<HullPtr>* hulls_;
  const char* what_ = "header";
  int64_t index_ = -1;
  std::string error_;
};

// ---------------------------------------------------------------------------------------------
// Records: each field once, in order, for both archives (D is T or const T).

template <class Ar, class D>
void ioSolver(Ar& ar, D& s) {
  using S = SolverSettings;
  ar.e8(s.scheme, S::Scheme::ColoredGaussSeidel);
  ar.e8(s.positionPass, S::PositionPass::NonlinearJacobi);
  ar.i32(s.positionIterations);
  ar.f32(s.positionBaumgarte);
  ar.f32(s.maxPositionCorrection);
  ar.i32(s.substeps);
  ar.i32(s.iterations);
  ar.f32(s.tolerance);
  ar.i32(s.relaxIterations);
  ar.e8(s.stabilization, S::Stabilization::Soft);
  ar.f32(s.baumgarte);
  ar.f32(s.contactHertz);
  ar.f32(s.contactDampingRatio);
  ar.f32(s.jointHertz);
  ar.f32(s.jointDampingRatio);
  ar.f32(s.maxPushout);
  ar.flag(s.splitPushout);
  ar.f32(s.linearSlop);
  ar.flag(s.warmStart);
  ar.flag(s.restitution);
  ar.f32(s.restitutionThreshold);
  ar.e8(s.equalitySolve, S::EqualitySolve::DirectLdl);
  ar.flag(s.blockContacts);
  ar.flag(s.geometricStiffness);
  ar.flag(s.patchFriction);
  ar.flag(s.stackStiffening);
  ar.f32(s.directContactRatio);
}

template <class Ar, class D>
void ioWorldDef(Ar& ar, D& d) {
  ar.vec(d.gravity);
  ar.f32(d.timeStep);
  ar.f32(d.maxLinearSpeed);
  ar.f32(d.maxAngularSpeed);
  ar.f32(d.speculativeDistance);
  ar.f32(d.aabbMargin);
  ar.u32(d.maxContactPairs);
  ar.e8(d.pairOverflow, WorldDef::PairOverflow::Refuse);
  ioSolver(ar, d.solver);
  // d.threads: the host's, not the simulation's (results do not depend on it).
  ar.flag(d.guard);
  ar.f32(d.guardEnergyJump);
  ar.i32(d.guardRetries);
  ar.flag(d.sleep.enabled);
  ar.f32(d.sleep.time);
  ar.f32(d.sleep.linearSpeed);
  ar.f32(d.sleep.angularSpeed);
}

template <class Ar, class D>
void ioStats(Ar& ar, D& s) {
  ar.u64(s.step);
  ar.i32(s.bodies);
  ar.i32(s.awake);
  ar.i32(s.contacts);
  ar.i32(s.contactPoints);
  ar.i32(s.joints);
  ar.i32(s.pairs);
  // s.vectorizedManifolds: how the host solved the last step, not the simulation's state;
  // s.broadPhaseTestsPerShape likewise (how the device found the last step's pairs).
  ar.f64(s.energyBefore);
  ar.f64(s.energyAfter);
  ar.f64(s.velocityResidual);
  ar.f64(s.maxPenetration);
  ar.i32(s.iterationsUsed);
  ar.i32(s.substeps);
  ar.f32(s.substepTime);
  ar.i32(s.stackDepth);
  ar.f32(s.stackHertz);
  ar.i32(s.guardRetries);
  ar.u64(s.guardEvents);
  ar.u64(s.guardQuarantined);
  ar.str(s.lastGuardEvent);
  ar.u32(s.pairLimit);
  ar.u64(s.pairsDropped);
  ar.u64(s.pairLimitSteps);
  ar.u64(s.stepFailures);
  ar.u64(s.stepsRefused);
  ar.i32(s.sleepingBodies);
  ar.i32(s.awakeIslands);
  ar.i32(s.sleepingIslands);
}

template <class Ar, class D>
void ioBody(Ar& ar, D& b) {
  ar.e8(b.type, BodyType::Dynamic);
  ar.xf(b.xf);
  ar.vec(b.localCenter);
  ar.vec(b.com);
  ar.vec(b.v);
  ar.vec(b.w);
  ar.f32(b.mass);
  ar.f32(b.invMass);
  ar.mat(b.inertiaLocal);
  ar.mat(b.invInertiaLocal);
  ar.quat(b.principal);
  ar.vec(b.principalMoments);
  ar.f32(b.linearDamping);
  ar.f32(b.angularDamping);
  ar.f32(b.gravityScale);
  ar.flag(b.gyroscopic);
  ar.flag(b.autoMass);
  ar.f32(b.givenMass);
  ar.vec(b.givenInertia);
  ar.vec(b.force);
  ar.vec(b.torque);
  ar.ids(b.shapes);
  ar.ids(b.joints);
  ar.str(b.name);
  ar.i32(b.solverIndex);
  ar.flag(b.allowSleep);
  ar.f32(b.sleepTime);
  ar.i32(b.island);
}

template <class Ar, class D>
void ioShape(Ar& ar, D& s) {
  ar.id(s.body);
  auto& g = s.def.geom;
  ar.e8(g.type, ShapeType::Hull);
  ar.f32(g.radius);
  ar.vec(g.halfExtents);
  ar.f32(g.halfHeight);
  ar.vec(g.normal);
  ar.f32(g.offset);
  ar.hull(g.hull);
  ar.xf(s.def.local);
  ar.f32(s.def.material.friction);
  ar.f32(s.def.material.restitution);
  ar.f32(s.def.material.density);
  // s.proxy: rebuilt (BRPH); its number does not matter, the fat box does.
  ar.f32(s.boundRadius);
}

template <class Ar, class D>
void ioJoint(Ar& ar, D& j) {
  auto& d = j.def;
  ar.e8(d.type, JointType::Prismatic);
  ar.id(d.bodyA);
  ar.id(d.bodyB);
  ar.vec(d.anchorA);
  ar.vec(d.anchorB);
  ar.vec(d.axisA);
  ar.vec(d.axisB);
  ar.flag(d.enableLimit);
  ar.f32(d.lower);
  ar.f32(d.upper);
  ar.flag(d.enableMotor);
  ar.f32(d.motorSpeed);
  ar.f32(d.maxMotorForce);
  ar.f32(d.length);
  ar.f32(d.springHertz);
  ar.f32(d.springDampingRatio);
  ar.flag(d.collideConnected);
  ar.str(d.name);
  ar.quat(j.relRot0);
  ar.vec(j.refA);
  ar.vec(j.refB);
  ar.f32(j.length);
  // The last step's reactions feed the next step's geometric stiffness.
  ar.id(j.state.id);
  ar.vec(j.state.reactionForce);
  ar.vec(j.state.reactionTorque);
  ar.f32(j.state.positionError);
  ar.f32(j.state.angleError);
  ar.i32(j.firstRow);
  ar.i32(j.rowCount);
  for (auto& x : j.impulses) ar.f32(x);
  ar.i32(j.impulseCount);
}

template <class Ar, class D>
void ioContact(Ar& ar, D& c) {
  ar.u32(c.shapeA);
  ar.u32(c.shapeB);
  ar.id(c.idA);
  ar.id(c.idB);
  ar.id(c.bodyA);
  ar.id(c.bodyB);
  ar.vec(c.manifold.normal);
  ar.i32(c.manifold.count);
  // All four points, used or not, so a restored world saves the same bytes.
  for (auto& p : c.manifold.points) {
    ar.vec(p.point);
    ar.f32(p.separation);
    ar.u32(p.featureId);
  }
  for (auto& x : c.normalImpulse) ar.f32(x);
  for (auto& t : c.tangentImpulse) {
    ar.f32(t[0]);
    ar.f32(t[1]);
  }
  ar.f32(c.friction);
  ar.f32(c.restitution);
  ar.i32(c.firstRow);
}

template <class Ar, class D>
void ioHull(Ar& ar, D& h) {
  uint32_t nv = uint32_t(h.vertices.size());
  if constexpr (Ar::kReading) {
    nv = ar.count(12, "hull vertex");
    h.vertices.resize(nv);
  } else {
    ar.u32(nv);
  }
  for (auto& v : h.vertices) ar.vec(v);
  uint32_t nf = uint32_t(h.faces.size());
  if constexpr (Ar::kReading) {
    nf = ar.count(20, "hull face");
    h.faces.resize(nf);
  } else {
    ar.u32(nf);
  }
  for (auto& f : h.faces) {
    ar.vec(f.normal);
    ar.f32(f.offset);
    ar.u32s(f.indices);
  }
  ar.u32Pairs(h.edges);
  ar.vec(h.centroid);
  ar.u32Pairs(h.edgeFaces);
}

// ---------------------------------------------------------------------------------------------
// Pools

template <class T, class Tag, class F>
void writePool(Writer& w, const Pool<T, Tag>& pool, const char* what, F&& record) {
  w.u32(pool.capacity());
  for (uint32_t i = 0; i < pool.capacity(); ++i) {
    w.where(what, i);
    w.u32(pool.generationAt(i));
    w.flag(pool.alive(i));
    if (pool.alive(i)) record(w, pool.at(i));
  }
  const std::vector<uint32_t>& fl = pool.freeList();
  w.u32(uint32_t(fl.size()));
  for (uint32_t i : fl) w.u32(i);
}

template <class T, class Tag, class F>
void readPool(Reader& r, Pool<T, Tag>* pool, const char* what, F&& record) {
  r.where(what);
  const uint32_t n = r.count(5, "slot");  // a dead slot takes 5 bytes, a live one more
  std::vector<T> values(n);
  std::vector<uint32_t> generations(n);
  std::vector<uint8_t> alive(n);
  for (uint32_t i = 0; i < n && r.ok(); ++i) {
    r.where(what, i);
    r.u32(generations[i]);
    if (r.ok() && generations[i] == 0) r.fail("generation 0 (the null id's)");
    bool a = false;
    r.flag(a);
    alive[i] = a;
    if (a) record(r, values[i]);
  }
  r.where(what);
  std::vector<uint32_t> freeList;
  r.u32s(freeList);
  if (r.ok() && !pool->assign(std::move(values), generations, alive, std::move(freeList)))
    r.fail("the free list does not name every dead slot exactly once");
}

// ---------------------------------------------------------------------------------------------
// Checks of a parsed state (what the format alone cannot rule out).

bool unitQuat(Quat q) {
  return std::fabs(lengthSquared(q) - 1) <= 2e-3f;
}
bool unitVec(Vec3 v) {
  return std::fabs(lengthSquared(v) - 1) <= 2e-3f;
}

std::string checkHull(const ConvexHull& h) {
  const size_t nv = h.vertices.size(), nf = h.faces.size();
  if (nv < 4 || nf < 4) return "has fewer than 4 vertices or faces";
  for (const ConvexHull::Face& f : h.faces) {
    if (f.indices.size() < 3) return "has a face with fewer than 3 vertices";
    for (uint32_t i : f.indices)
      if (i >= nv) return "has a face referring to vertex " + std::to_string(i);
  }
  for (const auto& [a, b] : h.edges)
    if (a >= nv || b >= nv) return "has an edge referring to a vertex that does not exist";
  if (!h.edgeFaces.empty() && h.edgeFaces.size() != h.edges.size())
    return "has edge faces not parallel to its edges";
  for (const auto& [a, b] : h.edgeFaces)
    if (a >= nf || b >= nf) return "has an edge referring to a face that does not exist";
  if (!(computeMass(ShapeGeom::convexHull(std::make_shared<ConvexHull>(h)), 1.0f).mass > 0))
    return "encloses no volume";
  return {};
}

std::string checkShapeGeom(const ShapeGeom& g, BodyType bodyType) {
  switch (g.type) {
    case ShapeType::Sphere:
      if (!(g.radius > 0)) return "sphere radius is not > 0";
      break;
    case ShapeType::Box:
      if (!(g.halfExtents.x > 0 && g.halfExtents.y > 0 && g.halfExtents.z > 0))
        return "box half extents are not > 0";
      break;
    case ShapeType::Capsule:
      if (!(g.radius > 0) || g.halfHeight < 0) return "capsule radius or half height is invalid";
      break;
    case ShapeType::Plane:
      if (!(length(g.normal) > 0.5f)) return "plane normal is not a unit vector";
      if (bodyType != BodyType::Static) return "a plane on a body that is not static";
      break;
    case ShapeType::Hull:
      if (!g.hull) return "a hull shape without a hull";
      break;
  }
  if (g.type != ShapeType::Hull && g.hull) return "a hull attached to a shape that is no hull";
  return {};
}

/// What updateMass derives and the step then takes as it is: a dynamic body's principal frame
/// and moments are its inertia's eigen decomposition (the rotation integrator uses them: a
/// forged moment of 1.8e14 beside an inertia of 167 made a body non-finite at once), its
/// inverse inertia the inertia's inverse (a forged one of 3.5e12 did the same), and its
/// centre of mass is where its pose puts the local centre (finalize keeps the two together).
/// Tolerances far above float rounding, far below what would matter.
std::string checkMassFrame(const BodyRec& b) {
  if (b.type == BodyType::Dynamic) {
    const Mat3& I = b.inertiaLocal;
    const float scale = std::fabs(I.c0.x) + std::fabs(I.c1.y) + std::fabs(I.c2.z);
    const Mat3 R = toMat3(b.principal);
    const Mat3 back = R * Mat3::diagonal(b.principalMoments) * transpose(R);
    for (int c = 0; c < 3; ++c)
      for (int r = 0; r < 3; ++r)
        if (!(std::fabs((&back.c0)[c][r] - (&I.c0)[c][r]) <= 1e-3f * scale + 1e-9f))
          return "principal moments and axes are not its inertia's";
    // Its inverse, as inverse() makes it in float: only as exact as the inertia's condition
    // allows (a thin rod's is 1e7 and more), and zero for an inertia whose determinant is
    // under 1e-30 (a millimetre sphere's): checked to the error that condition permits.
    const Vec3 m = b.principalMoments;
    const float lo = std::min({m.x, m.y, m.z}), hi = std::max({m.x, m.y, m.z});
    if (std::fabs(determinant(I)) >= 1e-29f && lo > 0) {
      const Mat3 P = b.invInertiaLocal * I;
      const float tolerance = 1e-3f + 1e-5f * (hi / lo);
      for (int c = 0; c < 3; ++c)
        for (int r = 0; r < 3; ++r)
          if (!(std::fabs((&P.c0)[c][r] - (c == r ? 1.0f : 0.0f)) <= tolerance))
            return "inverse inertia is not its inertia's inverse";
    }
  }
  if (!(length(apply(b.xf, b.localCenter) - b.com) <= 1e-3f * (1 + length(b.com))))
    return "centre of mass is not where its pose puts it";
  return {};
}

/// A parsed state, complete and checked, ready to be swapped into a world.
struct Parsed {
  WorldDef def;
  StepStats stats;
  double time = 0;
  std::vector<HullPtr> hulls;
  Pool<BodyRec, BodyTag> bodies;
  Pool<ShapeRec, ShapeTag> shapes;
  Pool<JointRec, JointTag> joints;
  std::vector<Contact> contacts;
  BroadPhase broadPhase;
  std::vector<SleepingIsland> islands;
  std::vector<uint32_t> freeIslands;
};

void readWorldDef(Reader& r, Parsed* st) {
  r.where("world definition");
  ioWorldDef(r, st->def);
  if (!r.ok()) return;
  Status s = World::validate(st->def.solver);
  if (!s.ok()) return r.fail(s.message);
  const WorldDef& d = st->def;
  if (!(d.timeStep > 0 && d.timeStep <= 1)) return r.fail("time step is not in (0, 1] s");
  if (!(d.maxLinearSpeed > 0 && d.maxAngularSpeed > 0)) return r.fail("speed clamps are not > 0");
  if (d.speculativeDistance < 0 || d.aabbMargin < 0) return r.fail("negative margins");
  // A bound the constructor does not set, so that a corrupted count cannot make a step
  // retry for hours.
  if (d.guardRetries > kMaxGuardRetries)
    r.fail("guard retries " + std::to_string(d.guardRetries) + " is over the limit of " +
           std::to_string(kMaxGuardRetries));
}

void readHulls(Reader& r, Parsed* st) {
  r.where("hull table");
  const uint32_t n = r.count(4 * 5, "hull");
  for (uint32_t i = 0; i < n && r.ok(); ++i) {
    r.where("hull", i);
    auto h = std::make_shared<ConvexHull>();
    ioHull(r, *h);
    if (!r.ok()) return;
    std::string e = checkHull(*h);
    if (!e.empty()) return r.fail(e);
    st->hulls.push_back(std::move(h));
  }
}

void readBodies(Reader& r, Parsed* st) {
  readPool(r, &st->bodies, "body slot", [&](Reader& rr, BodyRec& b) {
    ioBody(rr, b);
    if (rr.ok() && !unitQuat(b.xf.q)) rr.fail("rotation is not a unit quaternion");
    if (rr.ok() && !unitQuat(b.principal)) rr.fail("principal axes are not a unit quaternion");
    if (!rr.ok()) return;
    // What the step assumes of a body (its API never makes anything else).
    const bool dynamic = b.type == BodyType::Dynamic;
    if (b.mass < 0 || b.invMass < 0 || b.givenMass < 0) return rr.fail("negative mass");
    if (dynamic && !(b.mass > 0 && std::fabs(b.invMass * b.mass - 1) < 1e-3f))
      return rr.fail("a dynamic body's mass and inverse mass disagree");
    if (!dynamic && b.invMass != 0) return rr.fail("a static or kinematic body with a mass");
    if (b.linearDamping < 0 || b.angularDamping < 0) return rr.fail("negative damping");
    if (b.principalMoments.x < 0 || b.principalMoments.y < 0 || b.principalMoments.z < 0 ||
        b.givenInertia.x < 0 || b.givenInertia.y < 0 || b.givenInertia.z < 0)
      return rr.fail("negative moment of inertia");
    const Mat3& ii = b.invInertiaLocal;
    if (ii.c0.x < 0 || ii.c1.y < 0 || ii.c2.z < 0)
      return rr.fail("negative inverse moment of inertia");
    std::string e = checkMassFrame(b);
    if (!e.empty()) return rr.fail(e);
  });
  if (!r.ok()) return;
  // The solver index. The step numbers the awake bodies afresh (buildSolverBodies) before it
  // reads any, but takes a static body's as it is: solver body 0, the world. A sleeping
  // body's is 0 too (readIslands). An awake body's is last step's number, 1 + its place
  // among the bodies awake then (at most the capacity), -1 if it never took a step, or 0 if
  // it was static or asleep since: not read, but bounded all the same.
  const int64_t capacity = st->bodies.capacity();
  for (uint32_t i = 0; i < st->bodies.capacity(); ++i) {
    if (!st->bodies.alive(i)) continue;
    const BodyRec& b = st->bodies.at(i);
    r.where("body slot", i);
    if (b.type == BodyType::Static && b.solverIndex != 0)
      return r.fail("a static body's solver index is " + std::to_string(b.solverIndex) +
                    ", not 0 (the world's)");
    if (b.solverIndex < -1 || b.solverIndex > capacity)
      return r.fail("solver index " + std::to_string(b.solverIndex) + " is out of range [-1, " +
                    std::to_string(capacity) + "]");
  }
}

void readShapes(Reader& r, Parsed* st) {
  readPool(r, &st->shapes, "shape slot", [&](Reader& rr, ShapeRec& s) {
    ioShape(rr, s);
    if (!rr.ok()) return;
    const BodyRec* b = st->bodies.get(s.body);
    if (!b) return rr.fail("belongs to a body that does not exist");
    std::string e = checkShapeGeom(s.def.geom, b->type);
    if (!e.empty()) return rr.fail(e);
    const Material& m = s.def.material;
    if (m.friction < 0 || m.restitution < 0 || m.restitution > 1 || !(m.density > 0))
      return rr.fail("material out of range (friction >= 0, restitution in [0, 1], density > 0)");
    if (!unitQuat(s.def.local.q)) rr.fail("local rotation is not a unit quaternion");
  });
  if (!r.ok()) return;
  // Every live shape listed by exactly its own body, once.
  std::vector<uint8_t> listed(st->shapes.capacity(), 0);
  for (uint32_t i = 0; i < st->bodies.capacity(); ++i) {
    if (!st->bodies.alive(i)) continue;
    r.where("body slot", i);
    const BodyId bid = st->bodies.idAt(i);
    for (ShapeId sid : st->bodies.at(i).shapes) {
      const ShapeRec* s = st->shapes.get(sid);
      if (!s || !(s->body == bid) || listed[sid.index])
        return r.fail("lists shape " + std::to_string(sid.packed()) +
                      ", which does not exist, is another body's or is listed twice");
      listed[sid.index] = 1;
    }
  }
  for (uint32_t i = 0; i < st->shapes.capacity(); ++i) {
    r.where("shape slot", i);
    if (st->shapes.alive(i) && !listed[i]) return r.fail("is not listed by its body");
  }
}

void readJoints(Reader& r, Parsed* st) {
  readPool(r, &st->joints, "joint slot", [&](Reader& rr, JointRec& j) {
    ioJoint(rr, j);
    if (!rr.ok()) return;
    const JointDef& d = j.def;
    if (!st->bodies.get(d.bodyB)) return rr.fail("body_b does not exist");
    if (!d.bodyA.isNull() && !st->bodies.get(d.bodyA)) return rr.fail("body_a does not exist");
    if (d.bodyA == d.bodyB) return rr.fail("body_a and body_b are the same body");
    // What World::createJoint accepts (it normalizes the axes) and initJoint makes.
    if (!unitVec(d.axisA) || !unitVec(d.axisB)) return rr.fail("an axis is not a unit vector");
    if (d.enableLimit && d.lower > d.upper) return rr.fail("lower limit above upper");
    if (d.type == JointType::Hinge && d.enableLimit && (d.lower < -kPi || d.upper > kPi))
      return rr.fail("hinge limits outside [-pi, pi]");
    if (d.type == JointType::Distance && d.enableLimit && d.lower < 0)
      return rr.fail("negative distance limit");
    if (d.maxMotorForce < 0 || d.springHertz < 0 || d.springDampingRatio < 0)
      return rr.fail("negative motor force, spring hertz or damping");
    if (d.type == JointType::Distance && (!d.enableLimit || d.springHertz > 0) &&
        !(j.length >= JointRec::kMinDistanceLength))
      return rr.fail("a distance joint's rest length is under 1 mm");
    if (!unitQuat(j.relRot0)) return rr.fail("reference rotation is not a unit quaternion");
    if (!unitVec(j.refA) || !unitVec(j.refB))
      return rr.fail("a reference vector is not a unit vector");
    if (j.impulseCount < 0 || j.impulseCount > JointRec::kMaxRows)
      return rr.fail("impulse count out of range");
    // Last step's rows (the step builds them again before it reads them).
    if (j.firstRow < 0 || j.rowCount < 0 || j.rowCount > JointRec::kMaxRows)
      return rr.fail("row range out of range");
  });
  if (!r.ok()) return;
  // Each joint's own id in its state; each joint listed once by each of its bodies.
  std::vector<uint8_t> listedA(st->joints.capacity(), 0), listedB(st->joints.capacity(), 0);
  for (uint32_t i = 0; i < st->bodies.capacity(); ++i) {
    if (!st->bodies.alive(i)) continue;
    r.where("body slot", i);
    const BodyId bid = st->bodies.idAt(i);
    for (JointId jid : st->bodies.at(i).joints) {
      const JointRec* j = st->joints.get(jid);
      if (!j) return r.fail("lists joint " + std::to_string(jid.packed()) + ", which is gone");
      std::vector<uint8_t>& listed = j->def.bodyB == bid ? listedB : listedA;
      if ((!(j->def.bodyA == bid) && !(j->def.bodyB == bid)) || listed[jid.index])
        return r.fail("lists joint " + std::to_string(jid.packed()) +
                      ", which is not attached to it or is listed twice");
      listed[jid.index] = 1;
    }
  }
  for (uint32_t i = 0; i < st->joints.capacity(); ++i) {
    if (!st->joints.alive(i)) continue;
    r.where("joint slot", i);
    const JointRec& j = st->joints.at(i);
    if (!(j.state.id == st->joints.idAt(i))) return r.fail("its state names another joint");
    if (!listedB[i] || (!j.def.bodyA.isNull() && !listedA[i]))
      return r.fail("is not listed by its bodies");
  }
}

// A contact's shape id: live (then on the contact's body), or stale (the shape was removed
// since the last step; the next broad phase drops the contact).
bool contactShapeOk(const Pool<ShapeRec, ShapeTag>& shapes, uint32_t slot, ShapeId id,
                    BodyId body) {
  if (id.index != slot || id.generation == 0 || slot >= shapes.capacity()) return false;
  const uint32_t g = shapes.generationAt(slot);
  if (id.generation == g) return shapes.alive(slot) && shapes.at(slot).body == body;
  return id.generation < g;
}

// A contact's body id: a body that exists or did (a stale contact's), whose slot is there to
// read (the step looks up both bodies of every contact by slot).
bool contactBodyOk(const Pool<BodyRec, BodyTag>& bodies, BodyId id) {
  return id.generation != 0 && id.index < bodies.capacity() &&
         id.generation <= bodies.generationAt(id.index);
}

void writeContactList(Writer& w, const std::vector<Contact>& list) {
  w.u32(uint32_t(list.size()));
  for (size_t i = 0; i < list.size(); ++i) {
    w.where("contact", int64_t(i));
    ioContact(w, list[i]);
  }
}

/// The awake contacts (island -1) or sleeping island `island`'s.
void readContactList(Reader& r, Parsed* st, std::vector<Contact>* list, int32_t island) {
  const uint32_t n = r.count(196, "contact");
  list->resize(n);
  for (uint32_t i = 0; i < n && r.ok(); ++i) {
    r.where("contact", i);
    Contact& c = (*list)[i];
    ioContact(r, c);
    if (!r.ok()) return;
    if (!(c.shapeA < c.shapeB)) return r.fail("shape slots are not in order");
    if (i > 0) {
      const Contact& p = (*list)[i - 1];
      if (!(p.shapeA < c.shapeA || (p.shapeA == c.shapeA && p.shapeB < c.shapeB)))
        return r.fail("contacts are not sorted by shape pair");
    }
    if (!contactShapeOk(st->shapes, c.shapeA, c.idA, c.bodyA) ||
        !contactShapeOk(st->shapes, c.shapeB, c.idB, c.bodyB))
      return r.fail("refers to a shape that never existed or to another body's");
    if (!contactBodyOk(st->bodies, c.bodyA) || !contactBodyOk(st->bodies, c.bodyB) ||
        c.bodyA == c.bodyB)
      return r.fail("refers to a body that never existed, or twice to one body");
    if (c.manifold.count < 0 || c.manifold.count > Manifold::kMaxPoints)
      return r.fail("manifold point count out of range");
    if (c.firstRow < -1) return r.fail("negative first row");  // last step's; set again
    if (island < 0) continue;
    // A sleeping island's contacts skip the broad and narrow phases when it wakes: they go
    // to the solver as they are. They are what updateSleep puts there: touching contacts of
    // live shapes between two bodies that no longer move (static or asleep), kept by the
    // first body's island if it sleeps, else by the second's.
    if (c.manifold.count == 0 || !unitVec(c.manifold.normal))
      return r.fail("a sleeping island's contact without points or a unit normal");
    if (!st->shapes.valid(c.idA) || !st->shapes.valid(c.idB))
      return r.fail("a sleeping island's contact refers to a shape that is gone");
    const BodyRec& A = st->bodies.at(c.bodyA.index);
    const BodyRec& B = st->bodies.at(c.bodyB.index);
    const bool aAsleep = A.type == BodyType::Dynamic && A.island >= 0;
    const bool bAsleep = B.type == BodyType::Dynamic && B.island >= 0;
    if (!(aAsleep || A.type == BodyType::Static) || !(bAsleep || B.type == BodyType::Static) ||
        (aAsleep ? A.island : bAsleep ? B.island : -1) != island)
      return r.fail("a contact kept by sleeping island " + std::to_string(island) +
                    " whose bodies are not asleep in it (or static)");
  }
}

void readContacts(Reader& r, Parsed* st) {
  r.where("contact list");
  readContactList(r, st, &st->contacts, -1);
}

void readIslands(Reader& r, Parsed* st) {
  r.where("sleeping islands");
  const uint32_t n = r.count(4 + 4 + 8 + 4, "island");
  st->islands.resize(n);
  // Every sleeping body in exactly the island it names, and every island's body asleep in it.
  std::vector<uint8_t> listed(st->bodies.capacity(), 0);
  for (uint32_t k = 0; k < n && r.ok(); ++k) {
    r.where("island", k);
    SleepingIsland& is = st->islands[k];
    r.u32s(is.bodies);
    r.f32(is.substepTime);
    r.f64(is.potential);
    if (!r.ok()) return;
    if (!(is.substepTime >= 0 && is.substepTime <= 1))
      return r.fail("the substep length is not in [0, 1] s");
    for (size_t i = 0; i < is.bodies.size(); ++i) {
      const uint32_t slot = is.bodies[i];
      if (slot >= st->bodies.capacity() || !st->bodies.alive(slot) || listed[slot] ||
          (i > 0 && !(is.bodies[i - 1] < slot)))
        return r.fail("lists body slot " + std::to_string(slot) +
                      ", which is gone, listed twice or out of order");
      const BodyRec& b = st->bodies.at(slot);
      if (b.island != int32_t(k) || b.type != BodyType::Dynamic)
        return r.fail("lists body slot " + std::to_string(slot) +
                      ", which is not a dynamic body asleep in it");
      // Out of the step, like a static body: the step takes its solver index as it is.
      if (b.solverIndex != 0)
        return r.fail("body slot " + std::to_string(slot) + " sleeps with solver index " +
                      std::to_string(b.solverIndex) + ", not 0 (the world's)");
      listed[slot] = 1;
    }
    readContactList(r, st, &is.contacts, int32_t(k));
  }
  if (!r.ok()) return;
  r.where("sleeping islands");
  r.u32s(st->freeIslands);
  if (!r.ok()) return;
  std::vector<uint8_t> isFree(n, 0);
  for (uint32_t k : st->freeIslands) {
    if (k >= n || isFree[k] || !st->islands[k].bodies.empty() ||
        !st->islands[k].contacts.empty())
      return r.fail("the free list names island " + std::to_string(k) +
                    ", which is out of range, listed twice or holds bodies or contacts");
    isFree[k] = 1;
  }
  // An island without bodies is a free one (wakeIsland frees what it empties).
  for (uint32_t k = 0; k < n; ++k) {
    if (!isFree[k] && st->islands[k].bodies.empty()) {
      r.where("island", k);
      return r.fail("holds no bodies and is not on the free list");
    }
  }
  for (uint32_t i = 0; i < st->bodies.capacity(); ++i) {
    if (!st->bodies.alive(i)) continue;
    const BodyRec& b = st->bodies.at(i);
    if (b.island < -1 || (b.island >= 0 && !listed[i])) {
      r.where("body slot", i);
      return r.fail("names sleeping island " + std::to_string(b.island) + ", which does not list it");
    }
    if (!(b.sleepTime >= 0)) {
      r.where("body slot", i);
      return r.fail("negative rest time");
    }
  }
  // A joint between two dynamic bodies keeps them in one island: both awake or both asleep
  // in the same island (creating the joint woke both, and they fall asleep together).
  for (uint32_t i = 0; i < st->joints.capacity(); ++i) {
    if (!st->joints.alive(i)) continue;
    const JointDef& d = st->joints.at(i).def;
    if (d.bodyA.isNull()) continue;
    const BodyRec& A = *st->bodies.get(d.bodyA);
    const BodyRec& B = *st->bodies.get(d.bodyB);
    if (A.type == BodyType::Dynamic && B.type == BodyType::Dynamic && A.island != B.island) {
      r.where("joint slot", i);
      return r.fail("joins bodies of different sleeping islands (" + std::to_string(A.island) +
                    " and " + std::to_string(B.island) + ")");
    }
  }
}

void readBroadPhase(Reader& r, Parsed* st) {
  r.where("broad phase");
  const uint32_t n = r.count(28, "proxy");
  if (r.ok() && n != st->shapes.size())
    return r.fail(std::to_string(n) + " fat boxes for " + std::to_string(st->shapes.size()) +
                  " shapes");
  uint32_t next = 0;  // proxies in shape index order, one per live shape
  for (uint32_t k = 0; k < n && r.ok(); ++k) {
    r.where("proxy", k);
    uint32_t slot = 0;
    AABB fat;
    r.u32(slot);
    r.box(fat);
    if (!r.ok()) return;
    while (next < st->shapes.capacity() && !st->shapes.alive(next)) ++next;
    if (slot != next) return r.fail("not the next live shape's (" + std::to_string(next) + ")");
    if (!(fat.lo.x <= fat.hi.x && fat.lo.y <= fat.hi.y && fat.lo.z <= fat.hi.z))
      return r.fail("fat box is inverted");
    ShapeRec& s = st->shapes.at(slot);
    const bool isStatic = World::Impl::proxyStatic(*st->bodies.get(s.body));
    s.proxy = st->broadPhase.createProxyWithFatBox(fat, slot, isStatic);
    ++next;
  }
}

}  // namespace

// ---------------------------------------------------------------------------------------------

Status World::saveSnapshot(std::vector<uint8_t>* out) const {
  if (!out) return Status::Error(StatusCode::InvalidArgument, "snapshot: no output buffer");
  const Impl& m = *impl_;
  out->clear();
  out->reserve(kHeaderSize + 512 + size_t(m.bodies.capacity()) * 200 +
               size_t(m.shapes.capacity()) * 120 + m.contacts.size() * 160);
  out->resize(kHeaderSize);
  Writer w(out);

  size_t at = w.beginSection("WDEF");
  w.where("world definition");
  ioWorldDef(w, m.def);
  w.endSection(at);

  at = w.beginSection("STAT");
  w.where("time and statistics");
  w.f64(m.time);
  ioStats(w, m.stats);
  w.endSection(at);

  // Hulls come before the shapes that refer to them, but are numbered as the shapes meet
  // them: write the shapes aside first.
  std::vector<uint8_t> shapeBytes;
  Writer ws(&shapeBytes);
  writePool(ws, m.shapes, "shape slot", [](Writer& a, const ShapeRec& s) { ioShape(a, s); });

  at = w.beginSection("HULL");
  w.where("hull table");
  w.u32(uint32_t(ws.hulls().size()));
  for (size_t i = 0; i < ws.hulls().size(); ++i) {
    w.where("hull", int64_t(i));
    ioHull(w, *ws.hulls()[i]);
  }
  w.endSection(at);

  at = w.beginSection("BODY");
  writePool(w, m.bodies, "body slot", [](Writer& a, const BodyRec& b) { ioBody(a, b); });
  w.endSection(at);

  at = w.beginSection("SHAP");
  out->insert(out->end(), shapeBytes.begin(), shapeBytes.end());
  w.endSection(at);

  at = w.beginSection("JOIN");
  writePool(w, m.joints, "joint slot", [](Writer& a, const JointRec& j) { ioJoint(a, j); });
  w.endSection(at);

  at = w.beginSection("CONT");
  writeContactList(w, m.contacts);
  w.endSection(at);

  at = w.beginSection("BRPH");
  w.where("broad phase");
  w.u32(m.shapes.size());
  for (uint32_t i = 0; i < m.shapes.capacity(); ++i) {
    if (!m.shapes.alive(i)) continue;
    w.u32(i);
    w.box(m.broadPhase.fatAABB(m.shapes.at(i).proxy));
  }
  w.endSection(at);

  at = w.beginSection("ISLE");
  w.where("sleeping islands");
  w.u32(uint32_t(m.islands.size()));
  for (size_t k = 0; k < m.islands.size(); ++k) {
    w.where("island", int64_t(k));
    const SleepingIsland& is = m.islands[k];
    w.u32s(is.bodies);
    w.f32(is.substepTime);
    w.f64(is.potential);
    writeContactList(w, is.contacts);
  }
  w.u32s(m.freeIslands);
  w.endSection(at);

  const std::string& error = !w.error().empty() ? w.error() : ws.error();
  if (!error.empty()) {
    out->clear();
    return Status::Error(StatusCode::InvalidArgument, error);
  }
  uint8_t* h = out->data();
  std::memcpy(h, kMagic, 8);
  putU32(h + 8, kVersion);
  putU64(h + 12, uint64_t(out->size() - kHeaderSize));
  putU64(h + 20, fnv1a(h + kHeaderSize, out->size() - kHeaderSize));
  return Status::Ok();
}

Status World::restoreSnapshot(const uint8_t* data, size_t size) {
  auto bad = [](std::string m) { return Status::Error(StatusCode::InvalidArgument, std::move(m)); };
  if (!data && size > 0) return bad("snapshot: null data");
  if (size < kHeaderSize)
    return bad("snapshot: truncated: " + std::to_string(size) + " bytes, the header alone is " +
               std::to_string(kHeaderSize));
  if (std::memcmp(data, kMagic, 8) != 0) return bad("snapshot: wrong magic (not a snapshot)");
  const uint32_t version = getU32(data + 8);
  if (version != kVersion)
    return bad("snapshot: format version " + std::to_string(version) + " is not supported (" +
               std::to_string(kVersion) + " is)");
  const uint64_t payload = getU64(data + 12);
  if (payload != size - kHeaderSize)
    return bad("snapshot: truncated or padded: the header announces " + std::to_string(payload) +
               " payload bytes, " + std::to_string(size - kHeaderSize) + " are there");
  if (fnv1a(data + kHeaderSize, size_t(payload)) != getU64(data + 20))
    return bad("snapshot: checksum mismatch (corrupted)");

  auto st = std::make_unique<Parsed>();
  Reader r(data + kHeaderSize, size_t(payload), &st->hulls);
  auto run = [&](const char* tag, auto&& parse) {
    if (!r.ok()) return;
    Reader sub = r.section(tag);
    if (!r.ok()) return;
    parse(sub, st.get());
    sub.finishSection(tag);
    r.failWith(sub);
  };
  run("WDEF", readWorldDef);
  run("STAT", [](Reader& s, Parsed* p) {
    s.where("time and statistics");
    s.f64(p->time);
    ioStats(s, p->stats);
    // The warm starts' unit: a wrong one would scale every stored impulse.
    if (s.ok() && !(p->stats.substepTime >= 0 && p->stats.substepTime <= 1))
      s.fail("the last substep length is not in [0, 1] s");
    // Stack stiffening's frequency sets the substeps: at most a quarter of 64 per step of
    // at least 1 us.
    if (s.ok() && !(p->stats.stackHertz >= 0 && p->stats.stackHertz <= 1.6e7f))
      s.fail("the stack stiffening frequency is not in [0, 1.6e7] Hz");
  });
  run("HULL", readHulls);
  run("BODY", readBodies);
  run("SHAP", readShapes);
  run("JOIN", readJoints);
  run("CONT", readContacts);
  run("BRPH", readBroadPhase);
  run("ISLE", readIslands);
  if (r.ok() && r.remaining() != 0) {
    r.where("payload");
    r.fail(std::to_string(r.remaining()) + " bytes after the last section");
  }
  if (!r.ok()) return bad(r.error());

  // Everything checked: swap it in. Nothing below can fail (short of memory).
  Impl& w = *impl_;
  // Where the world runs is the process's choice, not the snapshot's.
  const WorldDef kept = w.def;
  w.def = st->def;
  w.def.threads = kept.threads;
  w.def.backend = kept.backend;
  w.def.gpuAllowCpuDevice = kept.gpuAllowCpuDevice;
  w.bodies = std::move(st->bodies);
  w.shapes = std::move(st->shapes);
  w.joints = std::move(st->joints);
  w.broadPhase = std::move(st->broadPhase);
  w.pairs.clear();
  w.contacts = std::move(st->contacts);
  w.contactScratch.clear();
  w.islands = std::move(st->islands);
  w.freeIslands = std::move(st->freeIslands);
  w.rebuildNoCollide();
  w.snapshot = {};  // the guard's rollback copy: taken again at the next step's start
  w.stats = st->stats;
  w.time = st->time;
  w.rebuildAwake();
  w.deviceStale();
  return Status::Ok();
}

}  // namespace phys
