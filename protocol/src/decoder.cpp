// Decoders: size check -> FlatBuffers Verifier with tight limits -> semantic validation
// (decoder.h says what is checked and what is left to the server).
#include "phys/protocol/decoder.h"

#include "phys/protocol/client_key.h"
#include "phys/protocol/cluster.h"

#include <algorithm>
#include <array>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <string>
#include <string_view>
#include <type_traits>
#include <unordered_set>
#include <utility>
#include <vector>

#include "flatbuffers/flatbuffers.h"
#include "phys/defs/world_def.h"
#include "phys/protocol/validate.h"
#include "value_rules.h"
#include "write.h"

namespace phys::protocol {

namespace {

using flatbuffers::Vector;

using detail::kMaxDampingRatio;
using detail::kMaxDirectContactRatio;
using detail::kMaxGuardEnergyJump;
using detail::kMaxGuardRetries;
using detail::kMaxHertz;
using detail::kMaxMargin;
using detail::kMaxSleepTime;
using detail::num;
using detail::ValueRules;

/// Bounds with no Limits field of their own (documented in docs/PROTOCOL.md).
constexpr int kMaxSolverIterations = 1000;
constexpr int kMaxSubsteps = 64;
constexpr uint32_t kMaxEventMessageBytes = 64u << 10;

std::string hexId(uint64_t v) {
  char buf[24];
  std::snprintf(buf, sizeof buf, "0x%llx", static_cast<unsigned long long>(v));
  return buf;
}

// ---------------------------------------------------------------------------------------------
// The checker: a path of field names for messages and one check per kind of value. Every
// check returns false after recording the first failure, so callers write `if (!x) return
// false;` and the message names the field that failed.

class Checker : public ValueRules<Checker> {
 public:
  explicit Checker(const Limits& limits) : lim(limits) {}

  const Limits& lim;
  Status status;
  // Totals over the whole message: a Batch's commands share one budget. Shapes and hull
  // points count every use of a shared table.
  uint64_t bodies = 0, joints = 0, ids = 0, items = 0, shapeUses = 0, hullPointUses = 0;
  bool inSnapshot = false;  ///< shapes and hull points against the snapshot budgets
  /// false: one definition checked on its own (checkBodyDef), not a message's part of the
  /// per-message budgets.
  bool budgets = true;
  /// Prefix of every path (checkBodyDef's caller's words, e.g. "scene 'x': bodies[3]").
  std::string base;

  void push(const char* name, int64_t index) {
    if (depth_ < path_.size()) path_[depth_] = {name, index};
    ++depth_;
  }
  void pop() { --depth_; }

  std::string path(std::string_view field) const {
    std::string s = base;
    for (size_t i = 0; i < std::min(depth_, path_.size()); ++i) {
      if (!s.empty()) s += '.';
      s += path_[i].name;
      if (path_[i].index >= 0) s += "[" + std::to_string(path_[i].index) + "]";
    }
    if (!field.empty()) {
      if (!s.empty()) s += '.';
      s += field;
    }
    return s;
  }

  bool fail(Code code, std::string_view field, const std::string& what) {
    status = Status::Error(code, path(field) + " " + what);
    return false;
  }
  bool invalid(std::string_view field, const std::string& what) {
    return fail(Code::InvalidArgument, field, what);
  }

  // Numbers (value_rules.h, shared with validate.cpp) --------------------------------------

  using ValueRules<Checker>::range;
  bool range(int64_t v, int64_t lo, int64_t hi, std::string_view f) {
    if (v < lo || v > hi)
      return invalid(f, "must be in [" + std::to_string(lo) + ", " + std::to_string(hi) +
                            "], got " + std::to_string(v));
    return true;
  }
  /// Every component finite and within [-maxAbs, maxAbs].
  bool vec(const wire::Vec3& v, float maxAbs, std::string_view f) {
    return vec3(v.x(), v.y(), v.z(), maxAbs, f);
  }
  bool vec(const wire::Vec3* v, float maxAbs, std::string_view f) {
    return !v || vec(*v, maxAbs, f);
  }
  bool nonZeroDirection(const wire::Vec3& v, std::string_view f) {
    return direction3(v.x(), v.y(), v.z(), f);
  }
  bool quat(const wire::Quat& q, std::string_view f) { return quat4(q.x(), q.y(), q.z(), q.w(), f); }
  bool pose(const wire::Pose* p, std::string_view f) {
    if (!p) return true;
    return vec(p->position(), lim.maxCoordinate, std::string(f) + ".position") &&
           quat(p->rotation(), std::string(f) + ".rotation");
  }

  // Names, enums, ids, counts --------------------------------------------------------------

  template <class E>
  bool known(E v, E max, std::string_view f, const char* type) {
    if (static_cast<unsigned>(v) <= static_cast<unsigned>(max)) return true;
    return invalid(f, "is " + std::to_string(static_cast<unsigned>(v)) + ", not a known " + type);
  }
  /// Bounded UTF-8; names allow no control characters, JSON text allows tab, CR and LF.
  bool text(const flatbuffers::String* s, uint32_t maxBytes, std::string_view f, bool required,
            bool multiline = false) {
    if (!s) return !required || invalid(f, "must be given");
    if (required && s->size() == 0) return invalid(f, "must not be empty");
    if (s->size() > maxBytes)
      return fail(
          Code::ResourceExhausted, f,
          "is " + std::to_string(s->size()) + " bytes, the limit is " + std::to_string(maxBytes));
    std::string_view sv(s->c_str(), s->size());
    if (!validUtf8(sv)) return invalid(f, "is not valid UTF-8");
    for (char ch : sv) {
      unsigned char c = static_cast<unsigned char>(ch);
      if (c < 0x20 || c == 0x7F) {
        if (multiline && (c == '\t' || c == '\n' || c == '\r')) continue;
        return invalid(f, "must not contain control characters");
      }
    }
    return true;
  }
  /// A world backend: absent or empty (the server's default), "cpu", "gpu" or "auto".
  bool backend(const flatbuffers::String* s, std::string_view f) {
    if (!text(s, lim.maxFileNameBytes, f, false)) return false;
    phys::Backend b;
    if (!s || s->size() == 0 || phys::parseBackend(s->str(), &b)) return true;
    return invalid(f,
                   "must be \"cpu\", \"gpu\" or \"auto\" (or empty: the server's default), got \"" +
                       s->str() + "\"");
  }
  /// A server-side file, scene or preset name: [A-Za-z0-9._-], not starting with '.'.
  bool fileName(const flatbuffers::String* s, std::string_view f, bool required) {
    if (!text(s, lim.maxFileNameBytes, f, required)) return false;
    if (!s) return true;
    std::string_view sv(s->c_str(), s->size());
    if (sv.empty() || sv[0] == '.')
      return invalid(f, "must be a plain name ([A-Za-z0-9._-], not starting with '.')");
    for (char c : sv)
      if (!(std::isalnum(static_cast<unsigned char>(c)) || c == '.' || c == '_' || c == '-'))
        return invalid(f, "must be a plain name ([A-Za-z0-9._-], not starting with '.'), got \"" +
                              std::string(sv) + "\"");
    return true;
  }
  bool id(uint64_t v, std::string_view f) { return v != 0 || invalid(f, "must be a non-zero id"); }
  /// A time step: > 0, within [minTimeStep, maxTimeStep].
  bool timeStep(float v, std::string_view f) {
    if (!positive(v, lim.maxTimeStep, f)) return false;
    if (v < lim.minTimeStep)
      return invalid(f, "must be >= " + num(lim.minTimeStep) + ", got " + num(v));
    return true;
  }
  /// Adds n to a message-wide total and checks it against its limit.
  bool budget(uint64_t* total, size_t n, uint32_t max, std::string_view f, const char* limit) {
    if (!budgets) return true;
    *total += n;
    if (*total <= max) return true;
    std::string what = "has " + std::to_string(n) + " entries";
    if (*total != n) what += " (" + std::to_string(*total) + " in the whole message)";
    return fail(Code::ResourceExhausted, f,
                what + ", the limit is " + std::to_string(max) + " (" + limit + ")");
  }
  /// The Verifier of FlatBuffers 2.0.8 checks a vector's length word (4-byte aligned) but not
  /// that 8-byte elements (ids, records holding an id) are 8-byte aligned; reading them
  /// misaligned is undefined behaviour, so such vectors are checked here. The buffer itself
  /// starts 8-byte aligned (decodeRoot), so the address tells. An empty vector has nothing to
  /// misread (FlatBuffers 2.0.8 may leave an empty vector of 8-byte elements 4-aligned, e.g.
  /// encodeIdsReply's joints when a command created none).
  template <class T>
  bool aligned8(const Vector<T>* v, std::string_view f) {
    if (!v || v->size() == 0 || reinterpret_cast<uintptr_t>(v->Data()) % 8 == 0) return true;
    return fail(Code::Malformed, f, "is not 8-byte aligned");
  }
  /// Client ids a world's owner lets change it: non-zero, no repeats, at most kMaxEditors.
  bool editorList(const Vector<uint64_t>* v, std::string_view f) {
    if (v && v->size() > kMaxEditors)
      return fail(Code::ResourceExhausted, f,
                  "has " + std::to_string(v->size()) + " ids, the limit is " +
                      std::to_string(kMaxEditors));
    return idList(v, f, false, true);
  }
  template <class T>
  bool nonEmpty(const Vector<T>* v, std::string_view f) {
    return (v && v->size() > 0) || invalid(f, "must not be empty");
  }
  /// A list of ids: non-zero, optionally without repeats, counted against max_ids_per_command.
  bool idList(const Vector<uint64_t>* v, std::string_view f, bool required, bool unique) {
    if (required && !nonEmpty(v, f)) return false;
    if (!v) return true;
    if (!aligned8(v, f)) return false;
    if (!budget(&ids, v->size(), lim.maxIdsPerCommand, f, "max_ids_per_command")) return false;
    for (uint32_t i = 0; i < v->size(); ++i)
      if (v->Get(i) == 0)
        return invalid(std::string(f) + "[" + std::to_string(i) + "]", "must be a non-zero id");
    if (unique) {
      std::vector<std::pair<uint64_t, uint32_t>> sorted(v->size());
      for (uint32_t i = 0; i < v->size(); ++i) sorted[i] = {v->Get(i), i};
      std::sort(sorted.begin(), sorted.end());
      for (size_t i = 1; i < sorted.size(); ++i)
        if (sorted[i].first == sorted[i - 1].first)
          return invalid(std::string(f) + "[" + std::to_string(sorted[i].second) + "]",
                         "repeats " + std::string(f) + "[" + std::to_string(sorted[i - 1].second) +
                             "] (" + hexId(sorted[i].first) + ")");
    }
    return true;
  }

  // Definitions ----------------------------------------------------------------------------

  bool material(const wire::Material* m, std::string_view f) {
    if (!m) return true;
    std::string p(f);
    return nonNegative(m->friction(), lim.maxFriction, p + ".friction") &&
           range(m->restitution(), 0.0f, 1.0f, p + ".restitution") &&
           positive(m->density(), lim.maxDensity, p + ".density");
  }

  bool shape(const wire::ShapeDef& s, wire::MotionType motion);
  bool body(const wire::BodyDef& b);
  bool joint(const wire::JointDef& j);
  /// A joint's values: every field but its type and body ids (checkJointDef's too).
  bool jointValues(const wire::JointDef& j);
  bool solver(const wire::SolverSettings& s, int* fieldsSet);
  bool worldSettings(const wire::WorldSettings& s, int* fieldsSet);
  /// A definition read back (BodiesResult): the body's definition and its mass properties.
  bool bodyInfo(const wire::BodyInfo& b);

  bool command(const wire::Command& c);
  bool request(wire::Request type, const void* table);
  bool snapshot(const wire::Snapshot& s);

  // One check per request (kChecks), given the request's table; request() has pushed the
  // request's name onto the path.
  bool nothing(const void*) { return true; }
  bool hello(const void* t);
  bool createWorld(const void* t);
  bool loadScene(const void* t);
  bool spawnBodies(const void* t);
  bool removeBodies(const void* t);
  bool addJoints(const void* t);
  bool removeJoints(const void* t);
  bool setBodyPose(const void* t);
  bool setBodyVelocity(const void* t);
  bool applyForce(const void* t);
  bool applyImpulse(const void* t);
  bool forces(const Vector<const wire::BodyForce*>* v, wire::PointFrame frame);
  bool applyTorque(const void* t);
  bool setMaterial(const void* t);
  bool setSolver(const void* t);
  bool step(const void* t);
  bool run(const void* t);
  bool queryState(const void* t);
  bool saveSnapshot(const void* t);
  bool restoreSnapshot(const void* t);
  bool batch(const void* t);
  bool subscribe(const void* t);
  bool unsubscribe(const void* t);
  bool setAccess(const void* t);
  bool setWorld(const void* t);
  bool getBodies(const void* t);
  bool getJoints(const void* t);
  bool moveWorld(const void* t);

 private:
  struct Segment {
    const char* name;
    int64_t index;
  };
  std::array<Segment, 24> path_{};
  size_t depth_ = 0;
  /// Hull tables already checked: a table shared by many shapes is read once.
  std::unordered_set<const void*> checkedHulls_;

 public:
  bool hullChecked(const void* hull) { return !checkedHulls_.insert(hull).second; }
};

/// Pushes a path segment for its lifetime.
class Scope {
 public:
  Scope(Checker& c, const char* name, int64_t index = -1) : c_(c) { c_.push(name, index); }
  ~Scope() { c_.pop(); }
  Scope(const Scope&) = delete;
  Scope& operator=(const Scope&) = delete;

 private:
  Checker& c_;
};

bool Checker::shape(const wire::ShapeDef& s, wire::MotionType motion) {
  wire::Shape type = s.geom_type();
  if (type == wire::Shape::NONE) return invalid("geom", "must be given");
  if (!known(type, wire::Shape::MAX, "geom", "shape type")) return false;
  if (!s.geom()) return invalid("geom", "must be given");
  switch (type) {
    case wire::Shape::Sphere: {
      Scope sc(*this, "sphere");
      if (!size(s.geom_as_Sphere()->radius(), "radius")) return false;
      break;
    }
    case wire::Shape::Box: {
      Scope sc(*this, "box");
      const wire::Vec3* he = s.geom_as_Box()->half_extents();
      if (!he) return invalid("half_extents", "must be given");
      if (!size(he->x(), "half_extents.x") || !size(he->y(), "half_extents.y") ||
          !size(he->z(), "half_extents.z"))
        return false;
      break;
    }
    case wire::Shape::Capsule: {
      Scope sc(*this, "capsule");
      const wire::Capsule* c = s.geom_as_Capsule();
      if (!size(c->radius(), "radius") ||
          !nonNegative(c->half_height(), lim.maxSize, "half_height"))
        return false;
      break;
    }
    case wire::Shape::Plane: {
      if (motion != wire::MotionType::Static)
        return invalid("plane", "is only allowed on a static body");
      Scope sc(*this, "plane");
      const wire::Plane* p = s.geom_as_Plane();
      if (!p->normal()) return invalid("normal", "must be given");
      if (!nonZeroDirection(*p->normal(), "normal") ||
          !range(p->offset(), -lim.maxCoordinate, lim.maxCoordinate, "offset"))
        return false;
      break;
    }
    case wire::Shape::ConvexHull: {
      Scope sc(*this, "convex_hull");
      const Vector<const wire::Vec3*>* pts = s.geom_as_ConvexHull()->points();
      size_t n = pts ? pts->size() : 0;
      if (n < 4) return invalid("points", "needs at least 4 points, got " + std::to_string(n));
      if (n > lim.maxHullPoints)
        return fail(Code::ResourceExhausted, "points",
                    "has " + std::to_string(n) + " points, the limit is " +
                        std::to_string(lim.maxHullPoints) + " (max_hull_points)");
      if (!budget(&hullPointUses, n,
                  inSnapshot ? lim.maxSnapshotHullPoints : lim.maxHullPointsPerCommand, "points",
                  inSnapshot ? "max_snapshot_hull_points" : "max_hull_points_per_command"))
        return false;
      if (hullChecked(s.geom_as_ConvexHull())) break;  // a shared table, checked at its first use
      for (uint32_t i = 0; i < n; ++i) {
        const wire::Vec3& p = *pts->Get(i);
        // The common case without building a path string per point.
        if (std::fabs(p.x()) <= lim.maxSize && std::fabs(p.y()) <= lim.maxSize &&
            std::fabs(p.z()) <= lim.maxSize)
          continue;
        if (!vec(p, lim.maxSize, "points[" + std::to_string(i) + "]")) return false;
      }
      break;
    }
    default:
      break;
  }
  return pose(s.local(), "local") && material(s.material(), "material");
}

bool Checker::body(const wire::BodyDef& b) {
  wire::MotionType motion = b.motion();
  if (!known(motion, wire::MotionType::MAX, "motion", "MotionType")) return false;
  if (!pose(b.pose(), "pose")) return false;
  if (!vec(b.linear_velocity(), lim.maxLinearSpeed, "linear_velocity") ||
      !vec(b.angular_velocity(), lim.maxAngularSpeed, "angular_velocity"))
    return false;
  if (!nonNegative(b.linear_damping(), lim.maxDamping, "linear_damping") ||
      !nonNegative(b.angular_damping(), lim.maxDamping, "angular_damping") ||
      !range(b.gravity_scale(), -lim.maxGravityScale, lim.maxGravityScale, "gravity_scale"))
    return false;
  if (!nonNegative(b.mass(), lim.maxMass, "mass")) return false;
  bool dynamic = motion == wire::MotionType::Dynamic;
  const char* kind = motion == wire::MotionType::Static ? "a static" : "a kinematic";
  if (!dynamic && b.mass() != 0)
    return invalid("mass", std::string("must be 0 for ") + kind + " body, got " + num(b.mass()));
  if (const wire::Vec3* in = b.inertia()) {
    if (!nonNegative(in->x(), lim.maxInertia, "inertia.x") ||
        !nonNegative(in->y(), lim.maxInertia, "inertia.y") ||
        !nonNegative(in->z(), lim.maxInertia, "inertia.z"))
      return false;
    int positives = (in->x() > 0) + (in->y() > 0) + (in->z() > 0);
    if (positives != 0 && positives != 3)
      return invalid("inertia", "must be all 0 (automatic) or all > 0, got (" + num(in->x()) +
                                    ", " + num(in->y()) + ", " + num(in->z()) + ")");
    if (!dynamic && positives != 0)
      return invalid("inertia", std::string("must be 0 for ") + kind + " body");
  }
  if (!text(b.name(), lim.maxNameBytes, "name", false)) return false;
  const Vector<flatbuffers::Offset<wire::ShapeDef>>* shapes = b.shapes();
  size_t n = shapes ? shapes->size() : 0;
  if (n > lim.maxShapesPerBody)
    return fail(Code::ResourceExhausted, "shapes",
                "has " + std::to_string(n) + " shapes, the limit is " +
                    std::to_string(lim.maxShapesPerBody) + " (max_shapes_per_body)");
  if (n > 0 && !budget(&shapeUses, n, inSnapshot ? lim.maxSnapshotShapes : lim.maxShapesPerCommand,
                       "shapes", inSnapshot ? "max_snapshot_shapes" : "max_shapes_per_command"))
    return false;
  bool volume = false;
  for (uint32_t i = 0; i < n; ++i) {
    Scope sc(*this, "shapes", i);
    const wire::ShapeDef* s = shapes->Get(i);
    if (!shape(*s, motion)) return false;
    volume |= s->geom_type() != wire::Shape::Plane;
  }
  if (dynamic && b.mass() == 0 && !volume)
    return invalid("shapes",
                   "must hold a shape with volume when a dynamic body's mass is 0 "
                   "(automatic)");
  return true;
}

bool Checker::joint(const wire::JointDef& j) {
  wire::JointType type = j.type();
  if (!known(type, wire::JointType::MAX, "type", "JointType")) return false;
  if (!id(j.body_b(), "body_b")) return false;
  if (j.body_a() == j.body_b()) return invalid("body_a", "must differ from body_b");
  return jointValues(j);
}

bool Checker::jointValues(const wire::JointDef& j) {
  const wire::JointType type = j.type();
  if (!vec(j.anchor_a(), lim.maxCoordinate, "anchor_a") ||
      !vec(j.anchor_b(), lim.maxCoordinate, "anchor_b"))
    return false;
  if ((j.axis_a() && !nonZeroDirection(*j.axis_a(), "axis_a")) ||
      (j.axis_b() && !nonZeroDirection(*j.axis_b(), "axis_b")))
    return false;
  if (!range(j.lower(), -lim.maxCoordinate, lim.maxCoordinate, "lower") ||
      !range(j.upper(), -lim.maxCoordinate, lim.maxCoordinate, "upper"))
    return false;
  if (j.enable_limit()) {
    if (j.lower() > j.upper())
      return invalid("lower", "must be <= upper, got " + num(j.lower()) + " > " + num(j.upper()));
    if (type == wire::JointType::Hinge && (j.lower() < -phys::kPi || j.upper() > phys::kPi))
      return invalid("lower", "and upper must lie in [-pi, pi] for a hinge");
    if (type == wire::JointType::Distance && j.lower() < 0)
      return invalid("lower", "must be >= 0 for a distance joint, got " + num(j.lower()));
  }
  float maxSpeed = std::max(lim.maxLinearSpeed, lim.maxAngularSpeed);
  return range(j.motor_speed(), -maxSpeed, maxSpeed, "motor_speed") &&
         nonNegative(j.max_motor_force(), lim.maxForce, "max_motor_force") &&
         range(j.length(), -lim.maxCoordinate, lim.maxCoordinate, "length") &&
         nonNegative(j.spring_hertz(), kMaxHertz, "spring_hertz") &&
         nonNegative(j.spring_damping_ratio(), kMaxDampingRatio, "spring_damping_ratio") &&
         text(j.name(), lim.maxNameBytes, "name", false);
}

bool Checker::solver(const wire::SolverSettings& s, int* fieldsSet) {
  int n = 0;
  // Each optional field: counted when present, then checked as its row in PHYS_SOLVER_FIELDS
  // says, in the list's order (the first failing field is the one named). The rows' bounds
  // are this file's constants and these Limits.
  const float maxSize = lim.maxSize, maxLinearSpeed = lim.maxLinearSpeed;
  auto present = [&](const auto& v) {
    n += v.has_value();
    return v.has_value();
  };
  auto inRange = [&](auto v, auto lo, auto hi, const char* f) {
    if (!present(v)) return true;
    if constexpr (std::is_integral_v<typename decltype(v)::value_type>)
      return range(int64_t(*v), int64_t(lo), int64_t(hi), f);
    else
      return range(*v, float(lo), float(hi), f);
  };
#define PHYS_CHECK_Flag(type, name, lo, hi) (present(s.name()), true)
#define PHYS_CHECK_Known(type, name, lo, hi) \
  (!present(s.name()) || known(*s.name(), wire::type::MAX, #name, #type))
#define PHYS_CHECK_Range(type, name, lo, hi) inRange(s.name(), lo, hi, #name)
#define PHYS_CHECK_Positive(type, name, lo, hi) \
  (!present(s.name()) || positive(*s.name(), hi, #name))
#define PHYS_CHECK(type, member, name, json, check, lo, hi, ...) \
  && PHYS_CHECK_##check(type, name, lo, hi)
  bool ok = true PHYS_SOLVER_FIELDS(PHYS_CHECK);
#undef PHYS_CHECK
#undef PHYS_CHECK_Positive
#undef PHYS_CHECK_Range
#undef PHYS_CHECK_Known
#undef PHYS_CHECK_Flag
  if (!ok) return false;
  if (fieldsSet) *fieldsSet = n;
  return true;
}

bool Checker::worldSettings(const wire::WorldSettings& s, int* fieldsSet) {
  int n = 0;
  // Each optional field: counted when present, then range-checked (as validate.cpp's
  // checkWorldSettings on phys::WorldDef).
  auto pos = [&](flatbuffers::Optional<float> v, float hi, const char* f) {
    if (!v) return true;
    ++n;
    return positive(*v, hi, f);
  };
  auto nonNeg = [&](flatbuffers::Optional<float> v, float hi, const char* f) {
    if (!v) return true;
    ++n;
    return nonNegative(*v, hi, f);
  };
  if (s.gravity()) {
    ++n;
    if (!vec(*s.gravity(), lim.maxGravity, "gravity")) return false;
  }
  if (auto v = s.time_step()) {
    ++n;
    if (!timeStep(*v, "time_step")) return false;
  }
  if (auto v = s.guard_retries()) {
    ++n;
    if (!range(int64_t(*v), 0, kMaxGuardRetries, "guard_retries")) return false;
  }
  bool ok = pos(s.sleep_time(), kMaxSleepTime, "sleep_time") &&
            nonNeg(s.sleep_linear_speed(), lim.maxLinearSpeed, "sleep_linear_speed") &&
            nonNeg(s.sleep_angular_speed(), lim.maxAngularSpeed, "sleep_angular_speed") &&
            pos(s.max_linear_speed(), lim.maxLinearSpeed, "max_linear_speed") &&
            pos(s.max_angular_speed(), lim.maxAngularSpeed, "max_angular_speed") &&
            nonNeg(s.speculative_distance(), kMaxMargin, "speculative_distance") &&
            nonNeg(s.aabb_margin(), kMaxMargin, "aabb_margin") &&
            nonNeg(s.guard_energy_jump(), kMaxGuardEnergyJump, "guard_energy_jump");
  if (!ok) return false;
  n += s.sleep().has_value() + s.guard().has_value();
  if (fieldsSet) *fieldsSet = n;
  return true;
}

bool Checker::bodyInfo(const wire::BodyInfo& b) {
  if (!id(b.id(), "id")) return false;
  if (!b.def()) return invalid("def", "must be given");
  {
    Scope d(*this, "def");
    if (!body(*b.def())) return false;
  }
  // Derived from the shapes' densities, a mass may pass max_mass (as the engine holds it).
  if (!finite(b.mass(), "mass")) return false;
  if (b.mass() < 0) return invalid("mass", "must be >= 0, got " + num(b.mass()));
  return vec(b.center_of_mass(), lim.maxCoordinate, "center_of_mass") &&
         vec(b.inertia(), std::numeric_limits<float>::max(), "inertia") &&
         (!b.inertia_axes() || quat(*b.inertia_axes(), "inertia_axes"));
}

// ---------------------------------------------------------------------------------------------
// Commands

bool Checker::command(const wire::Command& c) {
  wire::Request type = c.request_type();
  if (c.client_id() == 0) return invalid("command.client_id", "must be non-zero");
  if (type == wire::Request::NONE) return fail(Code::Malformed, "command.request", "is missing");
  if (type > wire::Request::MAX)
    return fail(Code::Unsupported, "command.request",
                "has unknown kind " + std::to_string(unsigned(type)) + " (protocol " +
                    std::to_string(kProtocolVersion) + " knows 1.." +
                    std::to_string(unsigned(wire::Request::MAX)) + ")");
  if (needsWorld(type) && c.world() == 0)
    return invalid("command.world", std::string("must name a world for ") + requestName(type));
  if (!c.request()) return fail(Code::Malformed, "command.request", "is missing its table");
  return request(type, c.request());
}

/// The check of each request kind, indexed by wire::Request (NONE: none, refused).
struct RequestCheck {
  wire::Request type;
  bool (Checker::*check)(const void* table);
};
constexpr std::array<RequestCheck, size_t(wire::Request::MAX) + 1> kChecks = {{
    {wire::Request::NONE, nullptr},
    {wire::Request::Hello, &Checker::hello},
    {wire::Request::CreateWorld, &Checker::createWorld},
    {wire::Request::DestroyWorld, &Checker::nothing},
    {wire::Request::ResetWorld, &Checker::nothing},
    {wire::Request::ListWorlds, &Checker::nothing},
    {wire::Request::LoadScene, &Checker::loadScene},
    {wire::Request::SpawnBodies, &Checker::spawnBodies},
    {wire::Request::RemoveBodies, &Checker::removeBodies},
    {wire::Request::AddJoints, &Checker::addJoints},
    {wire::Request::RemoveJoints, &Checker::removeJoints},
    {wire::Request::SetBodyPose, &Checker::setBodyPose},
    {wire::Request::SetBodyVelocity, &Checker::setBodyVelocity},
    {wire::Request::ApplyForce, &Checker::applyForce},
    {wire::Request::ApplyImpulse, &Checker::applyImpulse},
    {wire::Request::ApplyTorque, &Checker::applyTorque},
    {wire::Request::SetMaterial, &Checker::setMaterial},
    {wire::Request::SetSolver, &Checker::setSolver},
    {wire::Request::Step, &Checker::step},
    {wire::Request::Run, &Checker::run},
    {wire::Request::Pause, &Checker::nothing},
    {wire::Request::QueryState, &Checker::queryState},
    {wire::Request::SaveSnapshot, &Checker::saveSnapshot},
    {wire::Request::RestoreSnapshot, &Checker::restoreSnapshot},
    {wire::Request::Batch, &Checker::batch},
    {wire::Request::Subscribe, &Checker::subscribe},
    {wire::Request::Unsubscribe, &Checker::unsubscribe},
    {wire::Request::SetAccess, &Checker::setAccess},
    {wire::Request::SetWorld, &Checker::setWorld},
    {wire::Request::GetWorld, &Checker::nothing},
    {wire::Request::GetBodies, &Checker::getBodies},
    {wire::Request::GetJoints, &Checker::getJoints},
    {wire::Request::MoveWorld, &Checker::moveWorld},
}};
constexpr bool inOrder() {
  for (size_t i = 0; i < kChecks.size(); ++i)
    if (size_t(kChecks[i].type) != i || (i > 0 && !kChecks[i].check)) return false;
  return true;
}
static_assert(inOrder(), "one check per wire::Request, in the union's order");

bool Checker::request(wire::Request type, const void* table) {
  Scope sc(*this, requestName(type));
  const auto check = size_t(type) < kChecks.size() ? kChecks[size_t(type)].check : nullptr;
  if (!check) return fail(Code::Unsupported, "", "is not supported");
  return (this->*check)(table);
}

bool Checker::hello(const void* t) {
  auto* r = static_cast<const wire::Hello*>(t);
  if (r->protocol_version() == 0) return invalid("protocol_version", "must be >= 1, got 0");
  if (!text(r->client_name(), lim.maxNameBytes, "client_name", false)) return false;
  // A binding proof (client_key.h): a whole key and a whole signature, or neither.
  const size_t key = r->public_key() ? r->public_key()->size() : 0;
  const size_t proof = r->proof() ? r->proof()->size() : 0;
  if ((key || proof) && (key != kClientPublicKeyBytes || proof != kClientProofBytes))
    return fail(Code::Malformed, "public_key",
                "a binding proof is a " + std::to_string(kClientPublicKeyBytes) +
                    "-byte public key and a " + std::to_string(kClientProofBytes) +
                    "-byte proof, got " + std::to_string(key) + " and " + std::to_string(proof));
  return true;
}

bool Checker::createWorld(const void* t) {
  auto* r = static_cast<const wire::CreateWorld*>(t);
  if (!text(r->name(), lim.maxNameBytes, "name", true) ||
      !fileName(r->preset(), "preset", false) || !vec(r->gravity(), lim.maxGravity, "gravity"))
    return false;
  if (r->time_step() != 0 && !timeStep(r->time_step(), "time_step")) return false;
  if (!editorList(r->editors(), "editors")) return false;
  return backend(r->backend(), "backend");
}

bool Checker::setAccess(const void* t) {
  return editorList(static_cast<const wire::SetAccess*>(t)->editors(), "editors");
}

bool Checker::subscribe(const void* t) {
  auto* r = static_cast<const wire::Subscribe*>(t);
  const bool region = r->region_min() || r->region_max();
  if (region && (!r->region_min() || !r->region_max()))
    return invalid("region_min", "and region_max go together");
  if (region == (r->bodies() != nullptr))
    return invalid("bodies", "or a region (region_min, region_max): give exactly one");
  if (r->bodies()) return idList(r->bodies(), "bodies", true, true);
  if (!vec(r->region_min(), lim.maxCoordinate, "region_min") ||
      !vec(r->region_max(), lim.maxCoordinate, "region_max"))
    return false;
  const wire::Vec3 &a = *r->region_min(), &b = *r->region_max();
  if (!(a.x() <= b.x() && a.y() <= b.y() && a.z() <= b.z()))
    return invalid("region_max", "must be >= region_min on every axis");
  return true;
}

bool Checker::unsubscribe(const void* t) {
  if (static_cast<const wire::Unsubscribe*>(t)->interest() == 0)
    return invalid("interest", "must be non-zero (an id Subscribe returned)");
  return true;
}

bool Checker::loadScene(const void* t) {
  auto* r = static_cast<const wire::LoadScene*>(t);
  if (r->json() && r->scene_name())
    return invalid("json", "and scene_name are both given; give one");
  if (!r->json() && !r->scene_name()) return invalid("json", "or scene_name must be given");
  if (r->json()) return text(r->json(), lim.maxSceneJsonBytes, "json", true, true);
  return fileName(r->scene_name(), "scene_name", true);
}

bool Checker::spawnBodies(const void* t) {
  auto* v = static_cast<const wire::SpawnBodies*>(t)->bodies();
  if (!nonEmpty(v, "bodies") ||
      !budget(&bodies, v->size(), lim.maxBodiesPerCommand, "bodies", "max_bodies_per_command"))
    return false;
  for (uint32_t i = 0; i < v->size(); ++i) {
    Scope s(*this, "bodies", i);
    if (!body(*v->Get(i))) return false;
  }
  return true;
}

bool Checker::removeBodies(const void* t) {
  return idList(static_cast<const wire::RemoveBodies*>(t)->bodies(), "bodies", true, true);
}

bool Checker::addJoints(const void* t) {
  auto* v = static_cast<const wire::AddJoints*>(t)->joints();
  if (!nonEmpty(v, "joints") ||
      !budget(&joints, v->size(), lim.maxJointsPerCommand, "joints", "max_joints_per_command"))
    return false;
  for (uint32_t i = 0; i < v->size(); ++i) {
    Scope s(*this, "joints", i);
    if (!joint(*v->Get(i))) return false;
  }
  return true;
}

bool Checker::removeJoints(const void* t) {
  return idList(static_cast<const wire::RemoveJoints*>(t)->joints(), "joints", true, true);
}

bool Checker::setBodyPose(const void* t) {
  auto* v = static_cast<const wire::SetBodyPose*>(t)->items();
  if (!nonEmpty(v, "items") || !aligned8(v, "items") ||
      !budget(&items, v->size(), lim.maxItemsPerCommand, "items", "max_items_per_command"))
    return false;
  for (uint32_t i = 0; i < v->size(); ++i) {
    Scope s(*this, "items", i);
    const wire::BodyPose* p = v->Get(i);
    if (!id(p->id(), "id") || !pose(&p->pose(), "pose")) return false;
  }
  return true;
}

bool Checker::setBodyVelocity(const void* t) {
  auto* v = static_cast<const wire::SetBodyVelocity*>(t)->items();
  if (!nonEmpty(v, "items") || !aligned8(v, "items") ||
      !budget(&items, v->size(), lim.maxItemsPerCommand, "items", "max_items_per_command"))
    return false;
  for (uint32_t i = 0; i < v->size(); ++i) {
    Scope s(*this, "items", i);
    const wire::BodyVelocity* p = v->Get(i);
    if (!id(p->id(), "id") || !vec(p->linear(), lim.maxLinearSpeed, "linear") ||
        !vec(p->angular(), lim.maxAngularSpeed, "angular"))
      return false;
  }
  return true;
}

bool Checker::applyForce(const void* t) {
  auto* r = static_cast<const wire::ApplyForce*>(t);
  return forces(r->items(), r->point_frame());
}

bool Checker::applyImpulse(const void* t) {
  auto* r = static_cast<const wire::ApplyImpulse*>(t);
  return forces(r->items(), r->point_frame());
}

/// ApplyForce's and ApplyImpulse's items (the same record).
bool Checker::forces(const Vector<const wire::BodyForce*>* v, wire::PointFrame frame) {
  if (!known(frame, wire::PointFrame::MAX, "point_frame", "PointFrame") ||
      !nonEmpty(v, "items") || !aligned8(v, "items") ||
      !budget(&items, v->size(), lim.maxItemsPerCommand, "items", "max_items_per_command"))
    return false;
  for (uint32_t i = 0; i < v->size(); ++i) {
    Scope s(*this, "items", i);
    const wire::BodyForce* p = v->Get(i);
    if (!id(p->id(), "id") || !vec(p->vector(), lim.maxForce, "vector") ||
        !vec(p->point(), lim.maxCoordinate, "point"))
      return false;
  }
  return true;
}

bool Checker::applyTorque(const void* t) {
  auto* v = static_cast<const wire::ApplyTorque*>(t)->items();
  if (!nonEmpty(v, "items") || !aligned8(v, "items") ||
      !budget(&items, v->size(), lim.maxItemsPerCommand, "items", "max_items_per_command"))
    return false;
  for (uint32_t i = 0; i < v->size(); ++i) {
    Scope s(*this, "items", i);
    const wire::BodyTorque* p = v->Get(i);
    if (!id(p->id(), "id") || !vec(p->torque(), lim.maxForce, "torque")) return false;
  }
  return true;
}

bool Checker::setMaterial(const void* t) {
  auto* r = static_cast<const wire::SetMaterial*>(t);
  if (!idList(r->bodies(), "bodies", true, false)) return false;
  if (!r->material()) return invalid("material", "must be given");
  return material(r->material(), "material");
}

bool Checker::setSolver(const void* t) {
  auto* r = static_cast<const wire::SetSolver*>(t);
  if (!fileName(r->preset(), "preset", false)) return false;
  int set = 0;
  if (r->settings()) {
    Scope s(*this, "settings");
    if (!solver(*r->settings(), &set)) return false;
  }
  if (!r->preset() && set == 0) return invalid("", "needs a preset or at least one setting");
  return true;
}

bool Checker::setWorld(const void* t) {
  auto* r = static_cast<const wire::SetWorld*>(t);
  int set = 0;
  if (r->settings()) {
    Scope s(*this, "settings");
    if (!worldSettings(*r->settings(), &set)) return false;
  }
  if (set == 0) return invalid("settings", "must set at least one field");
  return true;
}

bool Checker::getBodies(const void* t) {
  return idList(static_cast<const wire::GetBodies*>(t)->bodies(), "bodies", false, false);
}

bool Checker::getJoints(const void* t) {
  return idList(static_cast<const wire::GetJoints*>(t)->joints(), "joints", false, false);
}

bool Checker::moveWorld(const void* t) {
  const uint64_t d = static_cast<const wire::MoveWorld*>(t)->daemon();
  if (d == 0 || d > kMaxClusterDaemonId)
    return invalid("daemon", "must be a daemon's server.id, 1.." +
                                 std::to_string(kMaxClusterDaemonId) + ", got " +
                                 std::to_string(d));
  return true;
}

bool Checker::step(const void* t) {
  uint32_t n = static_cast<const wire::Step*>(t)->count();
  if (n == 0) return invalid("count", "must be >= 1, got 0");
  if (n > lim.maxStepsPerCommand)
    return fail(Code::ResourceExhausted, "count",
                "is " + std::to_string(n) + ", the limit is " +
                    std::to_string(lim.maxStepsPerCommand) + " (max_steps_per_command)");
  return true;
}

bool Checker::run(const void* t) {
  return nonNegative(static_cast<const wire::Run*>(t)->rate_hz(), lim.maxRateHz, "rate_hz");
}

bool Checker::queryState(const void* t) {
  return idList(static_cast<const wire::QueryState*>(t)->bodies(), "bodies", false, false);
}

bool Checker::saveSnapshot(const void* t) {
  auto* r = static_cast<const wire::SaveSnapshot*>(t);
  if (!fileName(r->file(), "file", false)) return false;
  if (!r->return_bytes() && !r->file())
    return invalid("return_bytes", "is false and no file is given: nothing to do");
  return true;
}

bool Checker::restoreSnapshot(const void* t) {
  auto* r = static_cast<const wire::RestoreSnapshot*>(t);
  if (r->snapshot() && r->file()) return invalid("snapshot", "and file are both given; give one");
  if (!r->snapshot() && !r->file()) return invalid("snapshot", "or file must be given");
  if (r->file()) return fileName(r->file(), "file", true);
  if (!nonEmpty(r->snapshot(), "snapshot")) return false;
  Decoded<wire::Snapshot> s = decodeSnapshot(
      std::span<const uint8_t>(r->snapshot()->data(), r->snapshot()->size()), lim);
  if (!s.ok()) {
    status = Status::Error(s.status.code, path("snapshot") + ": " + s.status.message);
    return false;
  }
  return true;
}

bool Checker::batch(const void* t) {
  auto* v = static_cast<const wire::Batch*>(t)->commands();
  if (!nonEmpty(v, "commands")) return false;
  if (v->size() > lim.maxBatchCommands)
    return fail(Code::ResourceExhausted, "commands",
                "has " + std::to_string(v->size()) + " entries, the limit is " +
                    std::to_string(lim.maxBatchCommands) + " (max_batch_commands)");
  for (uint32_t i = 0; i < v->size(); ++i) {
    Scope s(*this, "commands", i);
    const wire::CommandItem* item = v->Get(i);
    wire::Request type = item->request_type();
    if (type == wire::Request::NONE) return fail(Code::Malformed, "request", "is missing");
    if (type > wire::Request::MAX)
      return fail(Code::Unsupported, "request",
                  "has unknown kind " + std::to_string(unsigned(type)));
    if (!isBatchable(type))
      return invalid("request", std::string("is ") + requestName(type) +
                                    ", which cannot be batched (only world edits can)");
    if (!item->request()) return fail(Code::Malformed, "request", "is missing its table");
    if (!request(type, item->request())) return false;
  }
  return true;
}

// ---------------------------------------------------------------------------------------------
// Snapshots

bool Checker::snapshot(const wire::Snapshot& s) {
  Scope sc(*this, "snapshot");
  inSnapshot = true;
  if (s.format_version() != 1)
    return fail(Code::Unsupported, "format_version",
                "is " + std::to_string(s.format_version()) + "; this codec reads 1");
  // The engine's state is opaque here (phys::World::restoreSnapshot checks it); the
  // settings fields are then optional metadata.
  const bool engine = s.engine_state() != nullptr;
  if (engine) {
    if (s.engine_state()->size() == 0) return invalid("engine_state", "must not be empty");
    if ((s.bodies() && s.bodies()->size() > 0) || (s.joints() && s.joints()->size() > 0))
      return invalid("engine_state", "and bodies/joints are both given; give one form");
  }
  if (!text(s.name(), lim.maxNameBytes, "name", false) ||
      !vec(s.gravity(), lim.maxGravity, "gravity") || !finite(float(s.time()), "time"))
    return false;
  if ((!engine || s.time_step() != 0) && !timeStep(s.time_step(), "time_step"))
    return false;
  if (s.solver()) {
    Scope ss(*this, "solver");
    if (!solver(*s.solver(), nullptr)) return false;
  }
  if (s.settings()) {
    Scope ss(*this, "settings");
    if (!worldSettings(*s.settings(), nullptr)) return false;
  }
  auto* bv = s.bodies();
  auto* jv = s.joints();
  size_t nb = bv ? bv->size() : 0, nj = jv ? jv->size() : 0;
  if (nb > lim.maxSnapshotBodies || nj > lim.maxSnapshotBodies)
    return fail(Code::ResourceExhausted, nb > lim.maxSnapshotBodies ? "bodies" : "joints",
                "has " + std::to_string(std::max(nb, nj)) + " entries, the limit is " +
                    std::to_string(lim.maxSnapshotBodies) + " (max_snapshot_bodies)");
  std::vector<std::pair<uint64_t, uint32_t>> ids(nb);
  for (uint32_t i = 0; i < nb; ++i) {
    Scope e(*this, "bodies", i);
    const wire::BodyEntry* b = bv->Get(i);
    if (!id(b->id(), "id")) return false;
    if (!b->def()) return invalid("def", "must be given");
    {
      Scope d(*this, "def");
      if (!body(*b->def())) return false;
    }
    ids[i] = {b->id(), i};
  }
  std::sort(ids.begin(), ids.end());
  for (size_t i = 1; i < ids.size(); ++i)
    if (ids[i].first == ids[i - 1].first)
      return invalid("bodies[" + std::to_string(ids[i].second) + "].id",
                     "repeats bodies[" + std::to_string(ids[i - 1].second) + "].id (" +
                         hexId(ids[i].first) + ")");
  auto isBody = [&](uint64_t v) {
    auto it = std::lower_bound(ids.begin(), ids.end(), std::make_pair(v, uint32_t(0)));
    return it != ids.end() && it->first == v;
  };
  std::vector<std::pair<uint64_t, uint32_t>> jids(nj);
  for (uint32_t i = 0; i < nj; ++i) {
    Scope e(*this, "joints", i);
    const wire::JointEntry* j = jv->Get(i);
    if (!id(j->id(), "id")) return false;
    if (!j->def()) return invalid("def", "must be given");
    Scope d(*this, "def");
    if (!joint(*j->def())) return false;
    if (j->def()->body_a() != 0 && !isBody(j->def()->body_a()))
      return invalid("body_a", hexId(j->def()->body_a()) + " is not a body of the snapshot");
    if (!isBody(j->def()->body_b()))
      return invalid("body_b", hexId(j->def()->body_b()) + " is not a body of the snapshot");
    jids[i] = {j->id(), i};
  }
  std::sort(jids.begin(), jids.end());
  for (size_t i = 1; i < jids.size(); ++i)
    if (jids[i].first == jids[i - 1].first)
      return invalid("joints[" + std::to_string(jids[i].second) + "].id",
                     "repeats joints[" + std::to_string(jids[i - 1].second) + "].id (" +
                         hexId(jids[i].first) + ")");
  return true;
}

// ---------------------------------------------------------------------------------------------
// The pipeline shared by every decoder

std::string printableId(const uint8_t* p) {
  std::string s;
  for (int i = 0; i < 4; ++i) {
    char c = static_cast<char>(p[i]);
    if (std::isprint(static_cast<unsigned char>(c))) {
      s += c;
    } else {
      char buf[8];
      std::snprintf(buf, sizeof buf, "\\x%02x", p[i]);
      s += buf;
    }
  }
  return s;
}

template <class T, class Check>
Decoded<T> decodeRoot(std::span<const uint8_t> bytes, const Limits& lim, const char* identifier,
                      const char* what, Check check) {
  Decoded<T> out;
  // 1. Size, before any Verifier exists (it asserts on sizes >= 2^31).
  const size_t cap = std::min<size_t>(lim.maxMessageBytes, (size_t(1) << 31) - 1);
  if (bytes.size() > cap) {
    out.status =
        Status::Error(Code::ResourceExhausted,
                      std::string(what) + " is " + std::to_string(bytes.size()) +
                          " bytes, the limit is " + std::to_string(cap) + " (max_message_bytes)");
    return out;
  }
  if (bytes.size() < 8 || !bytes.data()) {
    out.status =
        Status::Error(Code::Malformed, std::string(what) + " is " + std::to_string(bytes.size()) +
                                           " bytes, too short for a FlatBuffer");
    return out;
  }
  if (!flatbuffers::BufferHasIdentifier(bytes.data(), identifier)) {
    out.status = Status::Error(Code::Malformed, std::string(what) + " has file identifier \"" +
                                                    printableId(bytes.data() + 4) +
                                                    "\", expected \"" + identifier + "\"");
    return out;
  }
  // Scalars are read in place: copy to aligned storage when the caller's bytes are not.
  const uint8_t* data = bytes.data();
  if (reinterpret_cast<uintptr_t>(data) % 8 != 0) {
    auto copy = std::shared_ptr<uint64_t[]>(new uint64_t[(bytes.size() + 7) / 8]);
    std::memcpy(copy.get(), bytes.data(), bytes.size());
    data = reinterpret_cast<const uint8_t*>(copy.get());
    out.storage = std::move(copy);
  }
  // 2. The Verifier, with a depth limit and a table budget proportional to the size (every
  // table takes at least 8 bytes with the offset pointing at it), so that a buffer whose
  // offsets share one table many times cannot make verification expensive.
  flatbuffers::Verifier::Options opts;
  opts.max_depth = lim.maxDepth;
  opts.max_tables = std::min<flatbuffers::uoffset_t>(lim.maxTables,
                                                     flatbuffers::uoffset_t(bytes.size() / 8 + 16));
  opts.check_alignment = true;
  flatbuffers::Verifier verifier(data, bytes.size(), opts);
  if (!verifier.VerifyBuffer<T>(identifier)) {
    out.storage.reset();
    out.status = Status::Error(Code::Malformed,
                               std::string(what) +
                                   " failed FlatBuffers verification (truncated or corrupt, nested "
                                   "deeper than " +
                                   std::to_string(opts.max_depth) + " tables, or more than " +
                                   std::to_string(opts.max_tables) + " tables)");
    return out;
  }
  // 3. Semantic validation.
  const T* root = flatbuffers::GetRoot<T>(data);
  Checker checker(lim);
  if (!check(checker, *root)) {
    out.storage.reset();
    out.status = std::move(checker.status);
    return out;
  }
  out.root = root;
  out.bytes = std::span<const uint8_t>(data, bytes.size());
  return out;
}

bool checkChunk(Checker& c, uint32_t index, uint32_t count) {
  if (count == 0) return c.invalid("chunk_count", "must be >= 1, got 0");
  if (index >= count)
    return c.invalid("chunk_index", "must be < chunk_count (" + std::to_string(count) + "), got " +
                                        std::to_string(index));
  return true;
}

/// Decodes bytes it takes ownership of: the result keeps them.
template <class T>
Decoded<T> keep(std::vector<uint8_t>&& bytes,
                Decoded<T> (*decode)(std::span<const uint8_t>, const Limits&),
                const Limits& limits) {
  auto owned = std::make_shared<const std::vector<uint8_t>>(std::move(bytes));
  Decoded<T> d = decode(*owned, limits);
  if (d.ok() && !d.storage) d.storage = std::move(owned);
  return d;
}

}  // namespace

Decoded<wire::Command> decodeCommand(std::span<const uint8_t> bytes, const Limits& limits) {
  return decodeRoot<wire::Command>(bytes, limits, wire::kCommandId, "command",
                                   [](Checker& c, const wire::Command& m) { return c.command(m); });
}

Decoded<wire::Snapshot> decodeSnapshot(std::span<const uint8_t> bytes, const Limits& limits) {
  return decodeRoot<wire::Snapshot>(
      bytes, limits, wire::kSnapshotId, "snapshot",
      [](Checker& c, const wire::Snapshot& m) { return c.snapshot(m); });
}

Decoded<wire::Reply> decodeReply(std::span<const uint8_t> bytes, const Limits& limits) {
  return decodeRoot<wire::Reply>(
      bytes, limits, wire::kReplyId, "reply", [](Checker& c, const wire::Reply& r) {
        Scope sc(c, "reply");
        if (!c.known(r.status(), wire::StatusCode::MAX, "status", "StatusCode")) return false;
        if (r.result_type() > wire::Result::MAX)
          return c.fail(Code::Unsupported, "result",
                        "has unknown kind " + std::to_string(unsigned(r.result_type())));
        if (r.result_type() != wire::Result::NONE && !r.result())
          return c.fail(Code::Malformed, "result", "is missing its table");
        switch (r.result_type()) {
          case wire::Result::HelloResult: {
            auto* f = r.result_as_HelloResult()->features();
            if (f && f->size() > c.lim.maxFeatures)
              return c.fail(Code::ResourceExhausted, "hello_result.features",
                            "has " + std::to_string(f->size()) + " entries, the limit is " +
                                std::to_string(c.lim.maxFeatures));
            return true;
          }
          case wire::Result::WorldList: {
            auto* w = r.result_as_WorldList()->worlds();
            if (w && w->size() > c.lim.maxWorlds)
              return c.fail(Code::ResourceExhausted, "world_list.worlds",
                            "has " + std::to_string(w->size()) + " entries, the limit is " +
                                std::to_string(c.lim.maxWorlds));
            return true;
          }
          case wire::Result::Ids:
            return c.aligned8(r.result_as_Ids()->bodies(), "ids.bodies") &&
                   c.aligned8(r.result_as_Ids()->joints(), "ids.joints");
          case wire::Result::StateResult: {
            auto* b = r.result_as_StateResult()->bodies();
            if (!c.aligned8(b, "state_result.bodies")) return false;
            if (b && b->size() > c.lim.maxBodiesPerFrame)
              return c.fail(Code::ResourceExhausted, "state_result.bodies",
                            "has " + std::to_string(b->size()) + " entries, the limit is " +
                                std::to_string(c.lim.maxBodiesPerFrame));
            return true;
          }
          // Settings and definitions: checked as commands' are (the SDK turns them into phys
          // types); the solver's settings are the world's, whatever their origin (presets).
          case wire::Result::WorldSettingsResult: {
            auto* w = r.result_as_WorldSettingsResult();
            if (!c.text(w->preset(), c.lim.maxFileNameBytes, "world_settings_result.preset", false))
              return false;
            if (!w->settings()) return true;
            Scope s(c, "world_settings_result");
            Scope t(c, "settings");
            return c.worldSettings(*w->settings(), nullptr);
          }
          case wire::Result::BodiesResult: {
            Scope s(c, "bodies_result");
            auto* v = r.result_as_BodiesResult()->bodies();
            if (!v) return true;
            if (v->size() > c.lim.maxBodiesPerFrame)
              return c.fail(Code::ResourceExhausted, "bodies",
                            "has " + std::to_string(v->size()) + " entries, the limit is " +
                                std::to_string(c.lim.maxBodiesPerFrame) +
                                " (max_bodies_per_frame)");
            for (uint32_t i = 0; i < v->size(); ++i) {
              Scope e(c, "bodies", i);
              if (!c.bodyInfo(*v->Get(i))) return false;
            }
            return true;
          }
          case wire::Result::JointsResult: {
            Scope s(c, "joints_result");
            auto* v = r.result_as_JointsResult()->joints();
            if (!v) return true;
            if (!c.budget(&c.joints, v->size(), c.lim.maxJointsPerCommand, "joints",
                          "max_joints_per_command"))
              return false;
            for (uint32_t i = 0; i < v->size(); ++i) {
              Scope e(c, "joints", i);
              const wire::JointEntry* j = v->Get(i);
              if (!c.id(j->id(), "id")) return false;
              if (!j->def()) return c.invalid("def", "must be given");
              Scope d(c, "def");
              if (!c.joint(*j->def())) return false;
            }
            return true;
          }
          default:
            return true;
        }
      });
}

Decoded<wire::StateFrame> decodeStateFrame(std::span<const uint8_t> bytes, const Limits& limits) {
  return decodeRoot<wire::StateFrame>(
      bytes, limits, wire::kStateFrameId, "state frame", [](Checker& c, const wire::StateFrame& f) {
        Scope sc(c, "state_frame");
        if (!checkChunk(c, f.chunk_index(), f.chunk_count())) return false;
        if (!c.aligned8(f.bodies(), "bodies") || !c.aligned8(f.compact(), "compact") ||
            !c.aligned8(f.removed(), "removed"))
          return false;
        if (f.bodies() && f.compact())
          return c.invalid("compact", "and bodies are both present (one or the other)");
        if (f.compact() && (!f.bounds_min() || !f.bounds_max()))
          return c.invalid("compact", "needs bounds_min and bounds_max");
        if (f.keyframe() && f.removed() && f.removed()->size() > 0)
          return c.invalid("removed", "is only for deltas (keyframe false)");
        if (f.refresh_hi() != 0 && f.keyframe())
          return c.invalid("refresh_hi", "is only for deltas (keyframe false)");
        if (f.refresh_hi() != 0 && f.refresh_lo() >= f.refresh_hi())
          return c.invalid("refresh_lo", "must be below refresh_hi");
        if (f.refresh_hi() == 0 && f.refresh_lo() != 0)
          return c.invalid("refresh_lo", "without refresh_hi");
        if (f.removed() && f.removed()->size() > c.lim.maxBodiesPerFrame)
          return c.fail(Code::ResourceExhausted, "removed",
                        "has " + std::to_string(f.removed()->size()) + " entries, the limit is " +
                            std::to_string(c.lim.maxBodiesPerFrame) + " (max_bodies_per_frame)");
        size_t n = f.bodies() ? f.bodies()->size() : f.compact() ? f.compact()->size() : 0;
        if (n > c.lim.maxBodiesPerFrame)
          return c.fail(Code::ResourceExhausted, "bodies",
                        "has " + std::to_string(n) + " entries, the limit is " +
                            std::to_string(c.lim.maxBodiesPerFrame) + " (max_bodies_per_frame)");
        if (n > f.total_bodies())
          return c.invalid("bodies", "has " + std::to_string(n) +
                                         " entries, more than total_bodies (" +
                                         std::to_string(f.total_bodies()) + ")");
        return true;
      });
}

Decoded<wire::WorldInfo> decodeWorldInfo(std::span<const uint8_t> bytes, const Limits& limits) {
  return decodeRoot<wire::WorldInfo>(
      bytes, limits, wire::kWorldInfoId, "world info", [](Checker& c, const wire::WorldInfo& w) {
        Scope sc(c, "world_info");
        if (!checkChunk(c, w.chunk_index(), w.chunk_count()) ||
            !c.text(w.name(), c.lim.maxNameBytes, "name", false))
          return false;
        if (auto* bv = w.bodies()) {
          if (!c.budget(&c.bodies, bv->size(), c.lim.maxBodiesPerCommand, "bodies",
                        "max_bodies_per_command"))
            return false;
          for (uint32_t i = 0; i < bv->size(); ++i) {
            Scope e(c, "bodies", i);
            const wire::BodyEntry* b = bv->Get(i);
            if (!c.id(b->id(), "id")) return false;
            if (!b->def()) return c.invalid("def", "must be given");
            Scope d(c, "def");
            if (!c.body(*b->def())) return false;
          }
        }
        if (auto* jv = w.joints()) {
          if (!c.budget(&c.joints, jv->size(), c.lim.maxJointsPerCommand, "joints",
                        "max_joints_per_command"))
            return false;
          for (uint32_t i = 0; i < jv->size(); ++i) {
            Scope e(c, "joints", i);
            const wire::JointEntry* j = jv->Get(i);
            if (!c.id(j->id(), "id")) return false;
            if (!j->def()) return c.invalid("def", "must be given");
            Scope d(c, "def");
            if (!c.joint(*j->def())) return false;
          }
        }
        return true;
      });
}

Decoded<wire::ServerStatus> decodeServerStatus(std::span<const uint8_t> bytes,
                                               const Limits& limits) {
  return decodeRoot<wire::ServerStatus>(
      bytes, limits, wire::kServerStatusId, "server status",
      [](Checker& c, const wire::ServerStatus& s) {
        Scope sc(c, "server_status");
        if (!c.text(s.server_name(), c.lim.maxNameBytes, "server_name", false) ||
            !c.text(s.server_version(), c.lim.maxNameBytes, "server_version", false))
          return false;
        size_t n = s.worlds() ? s.worlds()->size() : 0;
        if (n > c.lim.maxWorlds)
          return c.fail(Code::ResourceExhausted, "worlds",
                        "has " + std::to_string(n) + " entries, the limit is " +
                            std::to_string(c.lim.maxWorlds) + " (max_worlds)");
        // Daemon ids are 1..4095 (server.id), so a status names at most 4095 others.
        if (s.peers() && s.peers()->size() > kMaxClusterDaemonId)
          return c.fail(Code::ResourceExhausted, "peers",
                        "has " + std::to_string(s.peers()->size()) +
                            " entries, more than there are daemon ids (" +
                            std::to_string(kMaxClusterDaemonId) + ")");
        return true;
      });
}

Decoded<wire::Handoff> decodeHandoff(std::span<const uint8_t> bytes, const Limits& limits) {
  return decodeRoot<wire::Handoff>(
      bytes, limits, wire::kHandoffId, "handoff", [](Checker& c, const wire::Handoff& h) {
        Scope sc(c, "handoff");
        if (h.kind() == wire::HandoffKind::Chunk && h.chunk_index() >= h.chunk_count())
          return c.invalid("chunk_index", "must be below chunk_count");
        return c.known(h.kind(), wire::HandoffKind::MAX, "kind", "HandoffKind") &&
               c.known(h.status(), wire::StatusCode::MAX, "status", "StatusCode") &&
               c.text(h.message(), kMaxEventMessageBytes, "message", false, true);
      });
}

Decoded<wire::Event> decodeEvent(std::span<const uint8_t> bytes, const Limits& limits) {
  return decodeRoot<wire::Event>(
      bytes, limits, wire::kEventId, "event", [](Checker& c, const wire::Event& e) {
        Scope sc(c, "event");
        return c.known(e.severity(), wire::Severity::MAX, "severity", "Severity") &&
               c.text(e.code(), c.lim.maxNameBytes, "code", false) &&
               c.text(e.message(), kMaxEventMessageBytes, "message", false, true);
      });
}

}  // namespace phys::protocol

namespace phys::protocol {

Decoded<wire::Command> decodeCommand(std::vector<uint8_t>&& bytes, const Limits& limits) {
  return keep<wire::Command>(std::move(bytes), &decodeCommand, limits);
}
Decoded<wire::Reply> decodeReply(std::vector<uint8_t>&& bytes, const Limits& limits) {
  return keep<wire::Reply>(std::move(bytes), &decodeReply, limits);
}
Decoded<wire::StateFrame> decodeStateFrame(std::vector<uint8_t>&& bytes, const Limits& limits) {
  return keep<wire::StateFrame>(std::move(bytes), &decodeStateFrame, limits);
}
Decoded<wire::WorldInfo> decodeWorldInfo(std::vector<uint8_t>&& bytes, const Limits& limits) {
  return keep<wire::WorldInfo>(std::move(bytes), &decodeWorldInfo, limits);
}
Decoded<wire::ServerStatus> decodeServerStatus(std::vector<uint8_t>&& bytes, const Limits& limits) {
  return keep<wire::ServerStatus>(std::move(bytes), &decodeServerStatus, limits);
}
Decoded<wire::Event> decodeEvent(std::vector<uint8_t>&& bytes, const Limits& limits) {
  return keep<wire::Event>(std::move(bytes), &decodeEvent, limits);
}
Decoded<wire::Handoff> decodeHandoff(std::vector<uint8_t>&& bytes, const Limits& limits) {
  return keep<wire::Handoff>(std::move(bytes), &decodeHandoff, limits);
}
Decoded<wire::Snapshot> decodeSnapshot(std::vector<uint8_t>&& bytes, const Limits& limits) {
  return keep<wire::Snapshot>(std::move(bytes), &decodeSnapshot, limits);
}

// ---------------------------------------------------------------------------------------------
// Definitions that did not arrive as protocol tables (validate.h): each is written as the
// table it would arrive as and checked by the checks above, so the rules exist once. Alone,
// not as part of a message: no per-message budgets.

namespace {

/// A builder per thread, kept for its buffer (a scene checks thousands of bodies).
flatbuffers::FlatBufferBuilder& scratchBuilder() {
  thread_local flatbuffers::FlatBufferBuilder fbb(1024);
  fbb.Clear();
  return fbb;
}

Checker alone(const Limits& limits, std::string_view path) {
  Checker c(limits);
  c.budgets = false;
  c.base = std::string(path);
  c.status = Status::Ok();
  return c;
}

}  // namespace

Status checkBodyDef(const phys::BodyDef& def, const Limits& limits, std::string_view path) {
  flatbuffers::FlatBufferBuilder& fbb = scratchBuilder();
  fbb.Finish(detail::writeBodyDef(fbb, def));
  Checker c = alone(limits, path);
  c.body(*flatbuffers::GetRoot<wire::BodyDef>(fbb.GetBufferPointer()));
  return c.status;
}

Status checkJointDef(const phys::JointDef& def, const Limits& limits, std::string_view path) {
  flatbuffers::FlatBufferBuilder& fbb = scratchBuilder();
  fbb.Finish(detail::writeJointDef(fbb, def));
  Checker c = alone(limits, path);
  const wire::JointDef& j = *flatbuffers::GetRoot<wire::JointDef>(fbb.GetBufferPointer());
  // Its body ids are the world's to check (a scene's joints name bodies by index).
  if (c.known(j.type(), wire::JointType::MAX, "type", "JointType")) c.jointValues(j);
  return c.status;
}

}  // namespace phys::protocol
