// The codec's rules on phys definitions (validate.h).
#include "phys/protocol/validate.h"

#include <cmath>
#include <cstdio>

#include "value_rules.h"

namespace phys::protocol {

namespace {

using detail::kMaxDampingRatio;
using detail::kMaxGuardEnergyJump;
using detail::kMaxGuardRetries;
using detail::kMaxHertz;
using detail::kMaxMargin;
using detail::kMaxSleepTime;
using detail::num;
using detail::ValueRules;

/// Check helpers in the decoder's words (value_rules.h): each returns false after recording
/// the first failure.
struct V : ValueRules<V> {
  V(const Limits& limits, std::string path) : lim(limits), base(std::move(path)) {}
  const Limits& lim;
  std::string base;
  Status status = Status::Ok();

  std::string path(std::string_view field) const {
    std::string p = base;
    if (!field.empty()) p += (p.empty() ? "" : ".") + std::string(field);
    return p;
  }
  bool fail(Code code, std::string_view field, const std::string& what) {
    status = Status::Error(code, path(field) + " " + what);
    return false;
  }
  bool invalid(std::string_view f, const std::string& what) {
    return fail(Code::InvalidArgument, f, what);
  }
  bool vec(Vec3 v, float maxAbs, std::string_view f) { return vec3(v.x, v.y, v.z, maxAbs, f); }
  bool direction(Vec3 v, std::string_view f) { return direction3(v.x, v.y, v.z, f); }
  bool quat(Quat q, std::string_view f) { return quat4(q.x, q.y, q.z, q.w, f); }
  bool pose(Vec3 p, Quat q, std::string_view f) {
    return vec(p, lim.maxCoordinate, std::string(f) + ".position") &&
           quat(q, std::string(f) + ".rotation");
  }
  bool name(std::string_view s, std::string_view f) {
    status = checkName(s, lim.maxNameBytes, path(f));
    return status.ok();
  }
  bool material(const Material& m, std::string_view f) {
    std::string p(f);
    return nonNegative(m.friction, lim.maxFriction, p + ".friction") &&
           range(m.restitution, 0.0f, 1.0f, p + ".restitution") &&
           positive(m.density, lim.maxDensity, p + ".density");
  }
  bool shape(const ShapeDef& s, BodyType type, const std::string& f) {
    const ShapeGeom& g = s.geom;
    switch (g.type) {
      case ShapeType::Sphere:
        if (!size(g.radius, f + ".sphere.radius")) return false;
        break;
      case ShapeType::Box:
        if (!size(g.halfExtents.x, f + ".box.half_extents.x") ||
            !size(g.halfExtents.y, f + ".box.half_extents.y") ||
            !size(g.halfExtents.z, f + ".box.half_extents.z"))
          return false;
        break;
      case ShapeType::Capsule:
        if (!size(g.radius, f + ".capsule.radius") ||
            !nonNegative(g.halfHeight, lim.maxSize, f + ".capsule.half_height"))
          return false;
        break;
      case ShapeType::Plane:
        if (type != BodyType::Static) return invalid(f + ".plane", "is only allowed on a static body");
        if (!direction(g.normal, f + ".plane.normal") ||
            !range(g.offset, -lim.maxCoordinate, lim.maxCoordinate, f + ".plane.offset"))
          return false;
        break;
      case ShapeType::Hull: {
        if (!g.hull) return invalid(f + ".convex_hull", "has no hull");
        const size_t n = g.hull->vertices.size();
        if (n < 4) return invalid(f + ".convex_hull.points", "needs at least 4 points, got " + std::to_string(n));
        if (n > lim.maxHullPoints)
          return fail(Code::ResourceExhausted, f + ".convex_hull.points",
                      "has " + std::to_string(n) + " points, the limit is " +
                          std::to_string(lim.maxHullPoints) + " (max_hull_points)");
        for (size_t i = 0; i < n; ++i) {
          const Vec3 p = g.hull->vertices[i];
          // The common case without building a path per vertex (a NaN fails the test).
          if (std::fabs(p.x) <= lim.maxSize && std::fabs(p.y) <= lim.maxSize &&
              std::fabs(p.z) <= lim.maxSize)
            continue;
          if (!vec(p, lim.maxSize, f + ".convex_hull.points[" + std::to_string(i) + "]"))
            return false;
        }
        break;
      }
      default:
        return invalid(f + ".geom", "is not a known shape");
    }
    return pose(s.local.p, s.local.q, f + ".local") && material(s.material, f + ".material");
  }
};

}  // namespace

bool validUtf8(std::string_view s) {
  size_t i = 0, n = s.size();
  while (i < n) {
    unsigned char c = static_cast<unsigned char>(s[i]);
    if (c < 0x80) {
      ++i;
      continue;
    }
    int len;
    uint32_t cp;
    if ((c & 0xE0) == 0xC0) {
      len = 2;
      cp = c & 0x1F;
    } else if ((c & 0xF0) == 0xE0) {
      len = 3;
      cp = c & 0x0F;
    } else if ((c & 0xF8) == 0xF0) {
      len = 4;
      cp = c & 0x07;
    } else {
      return false;
    }
    if (i + size_t(len) > n) return false;
    for (int k = 1; k < len; ++k) {
      unsigned char cc = static_cast<unsigned char>(s[i + size_t(k)]);
      if ((cc & 0xC0) != 0x80) return false;
      cp = (cp << 6) | (cc & 0x3F);
    }
    static constexpr uint32_t kMin[5] = {0, 0, 0x80, 0x800, 0x10000};
    if (cp < kMin[len] || cp > 0x10FFFF || (cp >= 0xD800 && cp <= 0xDFFF)) return false;
    i += size_t(len);
  }
  return true;
}

std::string shortQuote(std::string_view text, size_t maxBytes) {
  if (text.size() <= maxBytes) return "\"" + std::string(text) + "\"";
  // Cut at a character boundary.
  size_t cut = maxBytes;
  while (cut > 0 && (static_cast<unsigned char>(text[cut]) & 0xC0) == 0x80) --cut;
  return "\"" + std::string(text.substr(0, cut)) + "...\" (" + std::to_string(text.size()) +
         " bytes)";
}

Status checkName(std::string_view name, uint32_t maxBytes, std::string_view path) {
  const std::string p(path);
  if (name.size() > maxBytes)
    return Status::Error(Code::ResourceExhausted, p + " is " + std::to_string(name.size()) +
                                                      " bytes, the limit is " +
                                                      std::to_string(maxBytes));
  if (!validUtf8(name)) return Status::Error(Code::InvalidArgument, p + " is not valid UTF-8");
  for (char ch : name) {
    unsigned char c = static_cast<unsigned char>(ch);
    if (c < 0x20 || c == 0x7F)
      return Status::Error(Code::InvalidArgument, p + " must not contain control characters");
  }
  return Status::Ok();
}

Status checkBodyDef(const phys::BodyDef& b, const Limits& lim, std::string_view path) {
  V v{lim, std::string(path)};
  auto run = [&]() -> bool {
    if (unsigned(b.type) > unsigned(BodyType::Dynamic))
      return v.invalid("motion", "is " + std::to_string(unsigned(b.type)) + ", not a known MotionType");
    if (!v.pose(b.position, b.rotation, "pose")) return false;
    if (!v.vec(b.linearVelocity, lim.maxLinearSpeed, "linear_velocity") ||
        !v.vec(b.angularVelocity, lim.maxAngularSpeed, "angular_velocity"))
      return false;
    if (!v.nonNegative(b.linearDamping, lim.maxDamping, "linear_damping") ||
        !v.nonNegative(b.angularDamping, lim.maxDamping, "angular_damping") ||
        !v.range(b.gravityScale, -lim.maxGravityScale, lim.maxGravityScale, "gravity_scale"))
      return false;
    if (!v.nonNegative(b.mass, lim.maxMass, "mass")) return false;
    const bool dynamic = b.type == BodyType::Dynamic;
    const char* kind = b.type == BodyType::Static ? "a static" : "a kinematic";
    if (!dynamic && b.mass != 0)
      return v.invalid("mass", std::string("must be 0 for ") + kind + " body, got " + num(b.mass));
    if (!v.nonNegative(b.inertia.x, lim.maxInertia, "inertia.x") ||
        !v.nonNegative(b.inertia.y, lim.maxInertia, "inertia.y") ||
        !v.nonNegative(b.inertia.z, lim.maxInertia, "inertia.z"))
      return false;
    const int positives = (b.inertia.x > 0) + (b.inertia.y > 0) + (b.inertia.z > 0);
    if (positives != 0 && positives != 3)
      return v.invalid("inertia", "must be all 0 (automatic) or all > 0, got (" +
                                      num(b.inertia.x) + ", " + num(b.inertia.y) + ", " +
                                      num(b.inertia.z) + ")");
    if (!dynamic && positives != 0)
      return v.invalid("inertia", std::string("must be 0 for ") + kind + " body");
    if (!v.name(b.name, "name")) return false;
    if (b.shapes.size() > lim.maxShapesPerBody)
      return v.fail(Code::ResourceExhausted, "shapes",
                    "has " + std::to_string(b.shapes.size()) + " shapes, the limit is " +
                        std::to_string(lim.maxShapesPerBody) + " (max_shapes_per_body)");
    bool volume = false;
    for (size_t i = 0; i < b.shapes.size(); ++i) {
      if (!v.shape(b.shapes[i], b.type, "shapes[" + std::to_string(i) + "]")) return false;
      volume |= b.shapes[i].geom.type != ShapeType::Plane;
    }
    if (dynamic && b.mass == 0 && !volume)
      return v.invalid("shapes",
                       "must hold a shape with volume when a dynamic body's mass is 0 "
                       "(automatic)");
    return true;
  };
  run();
  return v.status;
}

Status checkJointDef(const phys::JointDef& j, const Limits& lim, std::string_view path) {
  V v{lim, std::string(path)};
  auto run = [&]() -> bool {
    if (unsigned(j.type) > unsigned(JointType::Prismatic))
      return v.invalid("type", "is " + std::to_string(unsigned(j.type)) + ", not a known JointType");
    if (!v.vec(j.anchorA, lim.maxCoordinate, "anchor_a") ||
        !v.vec(j.anchorB, lim.maxCoordinate, "anchor_b") || !v.direction(j.axisA, "axis_a") ||
        !v.direction(j.axisB, "axis_b"))
      return false;
    if (!v.range(j.lower, -lim.maxCoordinate, lim.maxCoordinate, "lower") ||
        !v.range(j.upper, -lim.maxCoordinate, lim.maxCoordinate, "upper"))
      return false;
    if (j.enableLimit) {
      if (j.lower > j.upper)
        return v.invalid("lower", "must be <= upper, got " + num(j.lower) + " > " + num(j.upper));
      if (j.type == JointType::Hinge && (j.lower < -phys::kPi || j.upper > phys::kPi))
        return v.invalid("lower", "and upper must lie in [-pi, pi] for a hinge");
      if (j.type == JointType::Distance && j.lower < 0)
        return v.invalid("lower", "must be >= 0 for a distance joint, got " + num(j.lower));
    }
    const float maxSpeed = std::max(lim.maxLinearSpeed, lim.maxAngularSpeed);
    return v.range(j.motorSpeed, -maxSpeed, maxSpeed, "motor_speed") &&
           v.nonNegative(j.maxMotorForce, lim.maxForce, "max_motor_force") &&
           v.range(j.length, -lim.maxCoordinate, lim.maxCoordinate, "length") &&
           v.nonNegative(j.springHertz, kMaxHertz, "spring_hertz") &&
           v.nonNegative(j.springDampingRatio, kMaxDampingRatio, "spring_damping_ratio") &&
           v.name(j.name, "name");
  };
  run();
  return v.status;
}

Status checkWorldParams(phys::Vec3 gravity, float timeStep, const Limits& lim,
                        std::string_view path) {
  V v{lim, std::string(path)};
  if (!v.vec(gravity, lim.maxGravity, "gravity")) return v.status;
  if (!v.positive(timeStep, lim.maxTimeStep, "time_step")) return v.status;
  if (timeStep < lim.minTimeStep)
    v.invalid("time_step", "must be >= " + num(lim.minTimeStep) + ", got " + num(timeStep));
  return v.status;
}

Status checkWorldSettings(const phys::WorldDef& d, const Limits& lim, std::string_view path) {
  Status st = checkWorldParams(d.gravity, d.timeStep, lim, path);
  if (!st.ok()) return st;
  V v{lim, std::string(path)};
  auto run = [&]() -> bool {
    if (!v.positive(d.sleep.time, kMaxSleepTime, "sleep_time") ||
        !v.nonNegative(d.sleep.linearSpeed, lim.maxLinearSpeed, "sleep_linear_speed") ||
        !v.nonNegative(d.sleep.angularSpeed, lim.maxAngularSpeed, "sleep_angular_speed") ||
        !v.positive(d.maxLinearSpeed, lim.maxLinearSpeed, "max_linear_speed") ||
        !v.positive(d.maxAngularSpeed, lim.maxAngularSpeed, "max_angular_speed") ||
        !v.nonNegative(d.speculativeDistance, kMaxMargin, "speculative_distance") ||
        !v.nonNegative(d.aabbMargin, kMaxMargin, "aabb_margin") ||
        !v.nonNegative(d.guardEnergyJump, kMaxGuardEnergyJump, "guard_energy_jump"))
      return false;
    if (d.guardRetries < 0 || d.guardRetries > kMaxGuardRetries)
      return v.invalid("guard_retries", "must be in [0, " + std::to_string(kMaxGuardRetries) +
                                            "], got " + std::to_string(d.guardRetries));
    return true;
  };
  run();
  return v.status;
}

}  // namespace phys::protocol
