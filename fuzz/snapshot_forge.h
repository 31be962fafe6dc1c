// Forged engine snapshots (issue 39): a world with every kind of record a snapshot holds, where
// the fields of those records lie in its bytes, and the seal (payload size and checksum) that a
// forger recomputes after changing them. Shared by the unit tests' SnapshotForgery suite,
// fuzz_restore (which seals every input, so that its mutations reach the parser) and
// make_corpus (which writes this world's snapshots and the forged cases as seeds).
//
// The layout is snapshot.cpp's (physics/world/snapshot.cpp, kVersion 6): a 28-byte header
// (magic, version, payload size u64 at 12, FNV-1a 64 of the payload at 20), then sections of
// a 4-character tag, a u64 length and the content. Little-endian throughout.
#pragma once

#include <bit>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <map>
#include <string>
#include <vector>

#include "phys/world/world.h"

namespace phys::forge {

using Bytes = std::vector<uint8_t>;

constexpr size_t kHeader = 28;
constexpr size_t kNone = size_t(-1);

inline uint64_t fnv1a(const uint8_t* p, size_t n) {
  uint64_t h = 1469598103934665603ull;
  for (size_t i = 0; i < n; ++i) {
    h ^= p[i];
    h *= 1099511628211ull;
  }
  return h;
}

inline uint32_t getU32(const Bytes& b, size_t at) {
  uint32_t v = 0;
  for (int i = 0; i < 4; ++i) v |= uint32_t(b[at + size_t(i)]) << (8 * i);
  return v;
}
inline uint64_t getU64(const Bytes& b, size_t at) {
  return uint64_t(getU32(b, at)) | uint64_t(getU32(b, at + 4)) << 32;
}
inline void putU32(Bytes* b, size_t at, uint32_t v) {
  for (int i = 0; i < 4; ++i) (*b)[at + size_t(i)] = uint8_t(v >> (8 * i));
}
inline void putU64(Bytes* b, size_t at, uint64_t v) {
  putU32(b, at, uint32_t(v));
  putU32(b, at + 4, uint32_t(v >> 32));
}

/// Makes the header agree with the payload, as a forger would: the payload size and its
/// checksum. Bytes too short for a header are left as they are.
inline void seal(uint8_t* data, size_t size) {
  if (size < kHeader) return;
  const uint64_t payload = size - kHeader;
  const uint64_t h = fnv1a(data + kHeader, size - kHeader);
  for (int i = 0; i < 8; ++i) {
    data[12 + i] = uint8_t(payload >> (8 * i));
    data[20 + i] = uint8_t(h >> (8 * i));
  }
}
inline void seal(Bytes* b) {
  seal(b->data(), b->size());
}

/// A section's content: where it starts and how long it is (size 0 and at 0: not found).
struct Section {
  size_t at = 0, size = 0;
  bool found() const { return at != 0; }
  size_t end() const { return at + size; }
};

inline Section section(const Bytes& b, const char* tag) {
  size_t p = kHeader;
  while (p + 12 <= b.size()) {
    const uint64_t len = getU64(b, p + 4);
    if (len > b.size() - p - 12) break;
    if (std::memcmp(b.data() + p, tag, 4) == 0) return {p + 12, size_t(len)};
    p += 12 + size_t(len);
  }
  return {};
}

/// The offset just past `name` (a record's name: a u32 length, then its bytes) inside
/// section s, or kNone when it is not there exactly once.
inline size_t afterName(const Bytes& b, Section s, const std::string& name) {
  size_t found = kNone;
  for (size_t p = s.at; p + 4 + name.size() <= s.end(); ++p) {
    if (getU32(b, p) != name.size() || std::memcmp(b.data() + p + 4, name.data(), name.size()) != 0)
      continue;
    if (found != kNone) return kNone;
    found = p + 4 + name.size();
  }
  return found;
}

// Fields of the records, as snapshot.cpp's io functions write them.
/// A body's, from just past its name (ioBody ends with the name and these).
namespace body {
constexpr size_t kSolverIndex = 0, kAllowSleep = 4, kSleepTime = 5, kIsland = 9;
/// How far its principal moments lie before its name's length, for a body of `shapes` shapes
/// and `joints` joints (then damping, gravity scale, two flags, given mass and inertia,
/// force, torque, and the shape and joint id lists).
constexpr size_t momentsBeforeName(size_t shapes, size_t joints) {
  return 66 + (4 + 8 * shapes) + (4 + 8 * joints);
}
/// Its inverse inertia's first element, before its principal moments (then the principal
/// frame's quaternion).
constexpr size_t kInverseInertiaBeforeMoments = 36 + 16;
}
/// A joint's, from just past its name (its definition's last field; ioJoint's state follows).
namespace joint {
constexpr size_t kRelRot0 = 0, kRefA = 16, kRefB = 28, kLength = 40, kStateId = 44,
                 kReactionForce = 52, kFirstRow = 84, kRowCount = 88, kImpulses = 92,
                 kImpulseCount = 124;
}
/// A contact's, from its start (ioContact).
namespace contact {
constexpr size_t kSize = 196, kShapeA = 0, kShapeB = 4, kIdA = 8, kIdB = 16, kBodyA = 24,
                 kBodyB = 32, kNormal = 40, kCount = 52, kPoints = 56, kNormalImpulse = 136,
                 kFriction = 184, kFirstRow = 192;
}

/// Where the contact records and the sleeping islands' body lists start.
struct Records {
  std::vector<size_t> awakeContacts;                 ///< CONT
  std::vector<std::vector<size_t>> islandContacts;   ///< ISLE, per island
  std::vector<size_t> islandBodies;                  ///< ISLE, per island: its u32 count
  size_t freeIslands = kNone;                        ///< ISLE: the free list's u32 count
};

inline Records records(const Bytes& b) {
  Records r;
  const Section cont = section(b, "CONT");
  if (cont.found() && cont.size >= 4) {
    const uint32_t n = getU32(b, cont.at);
    for (uint32_t i = 0; i < n && cont.at + 4 + (i + 1) * contact::kSize <= cont.end(); ++i)
      r.awakeContacts.push_back(cont.at + 4 + i * contact::kSize);
  }
  const Section isle = section(b, "ISLE");
  if (!isle.found() || isle.size < 4) return r;
  const uint32_t n = getU32(b, isle.at);
  size_t p = isle.at + 4;
  for (uint32_t k = 0; k < n && p + 4 <= isle.end(); ++k) {
    r.islandBodies.push_back(p);
    p += 4 + size_t(getU32(b, p)) * 4 + 4 + 8;  // body slots, substep length, potential
    if (p + 4 > isle.end()) break;
    const uint32_t nc = getU32(b, p);
    p += 4;
    r.islandContacts.emplace_back();
    for (uint32_t i = 0; i < nc && p + contact::kSize <= isle.end(); ++i, p += contact::kSize)
      r.islandContacts.back().push_back(p);
  }
  if (p + 4 <= isle.end()) r.freeIslands = p;
  return r;
}

// ---------------------------------------------------------------------------------------------
// The world: every record kind and both sleep states. After buildWorld:
//   asleep  "stack0".."stack2" (boxes on the ground: an island with contacts), "hinged-a" and
//           "hinged-b" (a hinge between two dynamic bodies, in one island), "tetra" (a hull),
//           "pill" (a capsule)
//   awake   "pendulum" (a ball joint to the world) and "bob" (a distance joint to it),
//           swinging; "ball", rolling on the ground (awake contacts with points); "slider",
//           driven along a prismatic joint to the world; "anvil" on "plinth", 500 times
//           lighter (their contacts solved directly), not allowed to sleep; "sweeper", a
//           kinematic box turning in the air
//   static  "ground" (a plane), "ledge" (a box)
//   gone    "doomed", destroyed after the last step: free body and shape slots, a freed
//           island, and its contacts still in the awake list with stale shape ids

inline WorldDef worldDef() {
  WorldDef d;
  d.threads = 1;
  d.backend = Backend::Cpu;
  d.sleep.enabled = true;
  d.sleep.time = 0.25f;
  return d;
}

inline BodyDef namedBody(const char* name, BodyType type, Vec3 at, ShapeGeom geom) {
  BodyDef d;
  d.name = name;
  d.type = type;
  d.position = at;
  ShapeDef s;
  s.geom = geom;
  d.shapes.push_back(s);
  return d;
}

/// Builds the world above into `w` (made with worldDef()); false if an edit failed. `ids`,
/// if given, gets each body's id by name.
inline bool buildWorld(World& w, std::map<std::string, BodyId>* ids = nullptr) {
  bool ok = true;
  auto add = [&](const BodyDef& d) {
    BodyId id;
    ok = ok && w.createBody(d, &id).ok();
    if (ids) (*ids)[d.name] = id;
    return id;
  };
  add(namedBody("ground", BodyType::Static, {}, ShapeGeom::plane({0, 0, 1}, 0)));
  add(namedBody("ledge", BodyType::Static, {-8, 4, 0.25f}, ShapeGeom::box({1, 1, 0.25f})));
  for (int i = 0; i < 3; ++i) {
    const std::string name = "stack" + std::to_string(i);
    add(namedBody(name.c_str(), BodyType::Dynamic, {0, 0, 0.25f + 0.5f * float(i)},
                  ShapeGeom::box({0.25f, 0.25f, 0.25f})));
  }
  const BodyId ha = add(namedBody("hinged-a", BodyType::Dynamic, {3, 0, 0.2f},
                                  ShapeGeom::box({0.3f, 0.2f, 0.2f})));
  const BodyId hb = add(namedBody("hinged-b", BodyType::Dynamic, {3.62f, 0, 0.2f},
                                  ShapeGeom::box({0.3f, 0.2f, 0.2f})));
  std::string error;
  auto tetra = buildConvexHull(
      {{0.3f, 0.3f, 0.3f}, {-0.3f, -0.3f, 0.3f}, {-0.3f, 0.3f, -0.3f}, {0.3f, -0.3f, -0.3f}},
      &error);
  ok = ok && tetra;
  if (tetra) add(namedBody("tetra", BodyType::Dynamic, {6, 0, 0.2f}, ShapeGeom::convexHull(tetra)));
  BodyDef pill = namedBody("pill", BodyType::Dynamic, {-3, -3, 0.15f}, ShapeGeom::capsule(0.15f, 0.3f));
  pill.rotation = Quat::fromAxisAngle({1, 0, 0}, kPi / 2);  // lying on its side
  add(pill);
  const BodyId slider = add(namedBody("slider", BodyType::Dynamic, {12, 0, 3},
                                      ShapeGeom::box({0.2f, 0.2f, 0.2f})));
  // 500 times heavier than what it stands on: a direct contacts island (directContactRatio),
  // kept awake.
  BodyDef plinth = namedBody("plinth", BodyType::Dynamic, {-6, -4, 0.1f},
                             ShapeGeom::box({0.3f, 0.3f, 0.1f}));
  plinth.shapes[0].material.density = 100;
  plinth.allowSleep = false;
  add(plinth);
  BodyDef anvil = namedBody("anvil", BodyType::Dynamic, {-6, -4, 0.4f},
                            ShapeGeom::box({0.2f, 0.2f, 0.2f}));
  anvil.shapes[0].material.density = 50000;
  anvil.allowSleep = false;
  add(anvil);
  const BodyId pendulum = add(namedBody("pendulum", BodyType::Dynamic, {-2.5f, 0, 4},
                                        ShapeGeom::box({0.2f, 0.2f, 0.2f})));
  const BodyId bob =
      add(namedBody("bob", BodyType::Dynamic, {-2.5f, 0, 3}, ShapeGeom::sphere(0.15f)));
  BodyDef ball = namedBody("ball", BodyType::Dynamic, {-5, 5, 0.3f}, ShapeGeom::sphere(0.3f));
  ball.linearVelocity = {1, 0, 0};
  ball.angularVelocity = {0, 1 / 0.3f, 0};
  add(ball);
  BodyDef sweeper = namedBody("sweeper", BodyType::Kinematic, {10, 0, 2},
                              ShapeGeom::box({1, 0.1f, 0.1f}));
  sweeper.angularVelocity = {0, 0, 0.5f};
  add(sweeper);
  const BodyId doomed = add(namedBody("doomed", BodyType::Dynamic, {-8, 4, 0.75f},
                                      ShapeGeom::box({0.25f, 0.25f, 0.25f})));

  JointDef hinge;
  hinge.name = "hinge";
  hinge.type = JointType::Hinge;
  hinge.bodyA = ha;
  hinge.bodyB = hb;
  hinge.anchorA = {0.31f, 0, 0};
  hinge.anchorB = {-0.31f, 0, 0};
  hinge.axisA = hinge.axisB = {0, 1, 0};
  hinge.enableLimit = true;
  hinge.lower = -0.5f;
  hinge.upper = 0.5f;
  ok = ok && w.createJoint(hinge, nullptr).ok();
  JointDef rope;
  rope.name = "rope";
  rope.type = JointType::Ball;
  rope.bodyB = pendulum;
  rope.anchorA = {-4, 0, 4};
  rope.anchorB = {-1.5f, 0, 0};
  ok = ok && w.createJoint(rope, nullptr).ok();
  JointDef link;
  link.name = "link";
  link.type = JointType::Distance;
  link.bodyA = pendulum;
  link.bodyB = bob;
  link.length = 1;
  ok = ok && w.createJoint(link, nullptr).ok();

  JointDef rail;
  rail.name = "rail";
  rail.type = JointType::Prismatic;
  rail.bodyB = slider;
  rail.anchorA = {12, 0, 3};
  rail.axisA = rail.axisB = {1, 0, 0};
  rail.enableLimit = true;
  rail.lower = -5;
  rail.upper = 5;
  rail.enableMotor = true;
  rail.motorSpeed = 0.5f;
  rail.maxMotorForce = 100;
  ok = ok && w.createJoint(rail, nullptr).ok();

  for (int i = 0; i < 90 && ok; ++i) w.step();
  ok = ok && w.destroyBody(doomed).ok();
  return ok;
}

// ---------------------------------------------------------------------------------------------
// Forged cases: one field of buildWorld's snapshot each, set to a value no world holds, the
// header sealed. Every one must be refused (each was accepted before issue 39, and those
// marked so crashed or read out of bounds in the steps after).

struct Forgery {
  std::string name;    ///< what was forged, a file name's part
  Bytes bytes;         ///< empty when the field was not found (the layout changed)
  std::string expect;  ///< words of the refusal (so each case is refused for its field)
};

inline std::vector<Forgery> forgeries(const Bytes& valid) {
  std::vector<Forgery> out;
  // Sets the u32 words at `where` to v (all of them found, or the forgery stays empty).
  auto forge = [&](const std::string& what, const std::vector<size_t>& where, uint32_t v,
                   const std::string& expect) {
    Forgery f{what, {}, expect};
    bool found = !where.empty();
    for (size_t p : where) found = found && p != kNone && p + 4 <= valid.size();
    if (found) {
      f.bytes = valid;
      for (size_t p : where) putU32(&f.bytes, p, v);
      seal(&f.bytes);
    }
    out.push_back(std::move(f));
  };
  auto field = [](size_t record, size_t offset) {
    return record == kNone ? kNone : record + offset;
  };
  auto vec3 = [&](size_t p) {
    return std::vector<size_t>{p, field(p, 4), field(p, 8)};
  };
  const Section bodies = section(valid, "BODY"), joints = section(valid, "JOIN");
  auto body = [&](const char* name, size_t offset) {
    return field(afterName(valid, bodies, name), offset);
  };
  auto joint = [&](const char* name, size_t offset) {
    return field(afterName(valid, joints, name), offset);
  };
  const uint32_t lastBody = bodies.found() ? getU32(valid, bodies.at) - 1 : 0;  // "doomed"
  // The finding: a static body's solver index (the step takes it as it is).
  const char* solverIndex = "solver index";
  forge("static_solver_index_i32_max", {body("ground", body::kSolverIndex)}, 0x7FFFFFFF,
        solverIndex);
  forge("static_solver_index_minus_one", {body("ground", body::kSolverIndex)}, 0xFFFFFFFF,
        solverIndex);
  forge("static_solver_index_one", {body("ledge", body::kSolverIndex)}, 1, solverIndex);
  forge("sleeping_solver_index_i32_max", {body("stack0", body::kSolverIndex)}, 0x7FFFFFFF,
        solverIndex);
  forge("sleeping_solver_index_two", {body("tetra", body::kSolverIndex)}, 2, solverIndex);
  forge("awake_solver_index_i32_max", {body("pendulum", body::kSolverIndex)}, 0x7FFFFFFF,
        solverIndex);
  forge("awake_solver_index_minus_two", {body("ball", body::kSolverIndex)}, 0xFFFFFFFE,
        solverIndex);
  forge("sleeping_island_i32_max", {body("stack1", body::kIsland)}, 0x7FFFFFFF,
        "not a dynamic body asleep in it");
  forge("awake_body_island_zero", {body("pendulum", body::kIsland)}, 0, "does not list it");
  {  // Mass data that is not the inertia's (fuzz_restore's findings: the body went non-finite).
    const size_t name = afterName(valid, bodies, "ball");
    const size_t moments =
        name == kNone ? kNone : name - std::strlen("ball") - 4 - body::momentsBeforeName(1, 0);
    forge("awake_principal_moment_1e14", {field(moments, 8)}, std::bit_cast<uint32_t>(1.8e14f),
          "principal moments");
    const size_t inverse =
        moments == kNone ? kNone : moments - body::kInverseInertiaBeforeMoments;
    forge("awake_inverse_inertia_3e12", {inverse}, std::bit_cast<uint32_t>(3.5e12f),
          "inverse inertia");
  }
  forge("joint_row_count_i32_max", {joint("rope", joint::kRowCount)}, 0x7FFFFFFF, "row range");
  forge("joint_first_row_minus_one", {joint("link", joint::kFirstRow)}, 0xFFFFFFFF, "row range");
  forge("joint_impulse_count_nine", {joint("hinge", joint::kImpulseCount)}, 9, "impulse count");
  forge("joint_length_zero", {joint("link", joint::kLength)}, 0, "rest length");
  forge("joint_reference_zero", vec3(joint("hinge", joint::kRefA)), 0, "reference vector");
  const Records r = records(valid);
  const size_t awake = r.awakeContacts.empty() ? kNone : r.awakeContacts.front();
  forge("awake_contact_body_index_i32_max", {field(awake, contact::kBodyA)}, 0x7FFFFFFF,
        "another body's");
  forge("awake_contact_first_row_minus_two", {field(awake, contact::kFirstRow)}, 0xFFFFFFFE,
        "first row");
  // A stale contact (its shape removed since the last step: the doomed body's) names a body
  // that never existed.
  size_t stale = kNone;
  for (size_t c : r.awakeContacts)
    if (stale == kNone && uint32_t(getU64(valid, c + contact::kBodyB)) == lastBody) stale = c;
  forge("stale_contact_body_index_i32_max", {field(stale, contact::kBodyB)}, 0x7FFFFFFF,
        "body that never existed");
  size_t sleeping = kNone;
  for (const std::vector<size_t>& list : r.islandContacts)
    if (!list.empty() && sleeping == kNone) sleeping = list.front();
  forge("island_contact_body_index_i32_max", {field(sleeping, contact::kBodyA)}, 0x7FFFFFFF,
        "another body's");
  forge("island_contact_body_generation_i32_max", {field(sleeping, contact::kBodyA + 4)},
        0x7FFFFFFF, "another body's");
  forge("island_contact_no_points", {field(sleeping, contact::kCount)}, 0, "without points");
  forge("island_contact_zero_normal", vec3(field(sleeping, contact::kNormal)), 0,
        "a unit normal");
  const size_t list = r.islandBodies.empty() ? kNone : r.islandBodies.front();
  forge("island_body_slot_i32_max", {field(list, 4)}, 0x7FFFFFFF, "lists body slot 2147483647");
  const bool anyFree = r.freeIslands != kNone && getU32(valid, r.freeIslands) > 0;
  forge("free_island_i32_max", {anyFree ? r.freeIslands + 4 : kNone}, 0x7FFFFFFF,
        "the free list names island 2147483647");
  return out;
}

}  // namespace phys::forge
