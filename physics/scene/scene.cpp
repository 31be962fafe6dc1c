// Scene files: parsing (with a JSON path in every error), serialization and instantiation.
// The format is documented in docs/SCENES.md; generators live in scene_generators.cpp.
#include "phys/scene/scene.h"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstring>
#include <fstream>
#include <limits>
#include <set>
#include <sstream>
#include <string_view>
#include <system_error>

#include "scene_internal.h"
#include "settings_json.h"

namespace phys {
namespace scene_detail {

// ---------------------------------------------------------------------------------------
// Paths, errors and value readers.

void fail(const std::string& path, const std::string& reason) {
  throw LoadError{path, reason, StatusCode::InvalidArgument};
}

void failExhausted(const std::string& path, const std::string& reason) {
  throw LoadError{path, reason, StatusCode::ResourceExhausted};
}

std::string member(const std::string& path, const std::string& key) {
  std::string k = keyText(key);
  return path.empty() ? k : path + "." + k;
}

bool validUtf8(const std::string& s, bool* control) {
  *control = false;
  const auto* p = reinterpret_cast<const unsigned char*>(s.data());
  const size_t n = s.size();
  for (size_t i = 0; i < n;) {
    unsigned c = p[i];
    if (c < 0x80) {
      if (c < 0x20 || c == 0x7F) *control = true;
      ++i;
      continue;
    }
    size_t len;
    unsigned lo = 0x80, hi = 0xBF;  // range of the second byte
    if (c >= 0xC2 && c <= 0xDF) {
      len = 2;
    } else if (c >= 0xE0 && c <= 0xEF) {
      len = 3;
      if (c == 0xE0) lo = 0xA0;  // overlong
      if (c == 0xED) hi = 0x9F;  // surrogates
    } else if (c >= 0xF0 && c <= 0xF4) {
      len = 4;
      if (c == 0xF0) lo = 0x90;  // overlong
      if (c == 0xF4) hi = 0x8F;  // > U+10FFFF
    } else {
      return false;
    }
    if (n - i < len) return false;
    if (p[i + 1] < lo || p[i + 1] > hi) return false;
    for (size_t k = 2; k < len; ++k) {
      if (p[i + k] < 0x80 || p[i + k] > 0xBF) return false;
    }
    i += len;
  }
  return true;
}

std::string keyText(const std::string& s) {
  bool plain = s.size() <= kShownBytes;
  for (size_t i = 0; plain && i < s.size(); ++i) {
    unsigned char c = static_cast<unsigned char>(s[i]);
    plain = c >= 0x20 && c != 0x7F;
  }
  if (plain) return s;
  // Cut at kShownBytes, backing off to the start of a UTF-8 sequence.
  size_t end = std::min(s.size(), kShownBytes);
  if (end < s.size()) {
    while (end > 0 && (static_cast<unsigned char>(s[end]) & 0xC0) == 0x80) --end;
  }
  std::string out;
  out.reserve(end + 32);
  static const char* kHex = "0123456789abcdef";
  for (size_t i = 0; i < end; ++i) {
    unsigned char c = static_cast<unsigned char>(s[i]);
    if (c < 0x20 || c == 0x7F) {
      out += "\\x";
      out += kHex[c >> 4];
      out += kHex[c & 15];
    } else {
      out += char(c);
    }
  }
  if (end < s.size()) out += "...(" + std::to_string(s.size()) + " bytes)";
  return out;
}

std::string quote(const std::string& s) {
  return "\"" + keyText(s) + "\"";
}

void checkName(const std::string& name, const std::string& path, const SceneBudget& budget,
               const char* what) {
  if (name.size() > budget.maxNameBytes) {  // a size limit, as in the protocol
    failExhausted(path, std::string("a ") + what + " must be at most " +
                   std::to_string(budget.maxNameBytes) + " bytes long (got " +
                   std::to_string(name.size()) + " bytes: " + quote(name) + ")");
  }
  bool control = false;
  if (!validUtf8(name, &control)) {
    fail(path, std::string("a ") + what + " must be valid UTF-8 (got " + quote(name) + ")");
  }
  if (control) {
    fail(path, std::string("a ") + what + " must not contain control characters (got " +
                   quote(name) + ")");
  }
}

uint64_t addSat(uint64_t a, uint64_t b) {
  return a > UINT64_MAX - b ? UINT64_MAX : a + b;
}

uint64_t mulSat(uint64_t a, uint64_t b) {
  if (a == 0 || b == 0) return 0;
  return a > UINT64_MAX / b ? UINT64_MAX : a * b;
}

std::string element(const std::string& path, size_t index) {
  return path + "[" + std::to_string(index) + "]";
}

namespace {

const char* typeName(const Json& j) {
  switch (j.type()) {
    case Json::value_t::null:
      return "null";
    case Json::value_t::object:
      return "an object";
    case Json::value_t::array:
      return "an array";
    case Json::value_t::string:
      return "a string";
    case Json::value_t::boolean:
      return "a boolean";
    case Json::value_t::number_integer:
    case Json::value_t::number_unsigned:
    case Json::value_t::number_float:
      return "a number";
    default:
      return "an unsupported value";
  }
}

std::string got(const Json& j) {
  return std::string(" (got ") + typeName(j) + ")";
}

const char* rangeText(Range range) {
  switch (range) {
    case Range::Positive:
      return "a finite number > 0";
    case Range::NonNegative:
      return "a finite number >= 0";
    case Range::UnitInterval:
      return "a number in [0, 1]";
    default:
      return "a finite number";
  }
}

bool inRange(double v, Range range) {
  switch (range) {
    case Range::Positive:
      return v > 0;
    case Range::NonNegative:
      return v >= 0;
    case Range::UnitInterval:
      return v >= 0 && v <= 1;
    default:
      return true;
  }
}

// A double outside the float range becomes +-inf (a plain cast would be undefined).
float toFloat(double d) {
  if (std::fabs(d) > double(std::numeric_limits<float>::max())) {
    return d > 0 ? std::numeric_limits<float>::infinity() : -std::numeric_limits<float>::infinity();
  }
  return float(d);
}

std::string formatNumber(double v) {
  std::ostringstream s;
  s << v;
  return s.str();
}

// Edit distance, for "did you mean" hints on unknown keys (quadratic: short keys only).
size_t editDistance(const std::string& a, const std::string& b) {
  std::vector<size_t> row(b.size() + 1);
  for (size_t j = 0; j <= b.size(); ++j) row[j] = j;
  for (size_t i = 1; i <= a.size(); ++i) {
    size_t diag = row[0];
    row[0] = i;
    for (size_t j = 1; j <= b.size(); ++j) {
      size_t up = row[j];
      row[j] = std::min({row[j] + 1, row[j - 1] + 1, diag + (a[i - 1] == b[j - 1] ? 0 : 1)});
      diag = up;
    }
  }
  return row[b.size()];
}

}  // namespace

double readDouble(const Json& j, const std::string& path, Range range) {
  if (!j.is_number()) fail(path, std::string("must be ") + rangeText(range) + got(j));
  double v = j.get<double>();
  if (!std::isfinite(v) || !inRange(v, range)) {
    fail(path, std::string("must be ") + rangeText(range) + " (got " + formatNumber(v) + ")");
  }
  return v;
}

float readFloat(const Json& j, const std::string& path, Range range) {
  double v = readDouble(j, path, range);
  float f = toFloat(v);
  if (!std::isfinite(f)) fail(path, "is out of the float range (got " + formatNumber(v) + ")");
  if (range == Range::Positive && !(f > 0)) fail(path, "must be > 0 (underflows to 0)");
  return f;
}

int64_t readInt(const Json& j, const std::string& path, int64_t lo, int64_t hi) {
  std::string expected =
      "must be an integer in [" + std::to_string(lo) + ", " + std::to_string(hi) + "]";
  if (!j.is_number_integer()) fail(path, expected + got(j));
  int64_t v;
  if (j.is_number_unsigned()) {
    uint64_t u = j.get<uint64_t>();
    if (u > uint64_t(hi)) fail(path, expected + " (got " + std::to_string(u) + ")");
    v = int64_t(u);
  } else {
    v = j.get<int64_t>();
  }
  if (v < lo || v > hi) fail(path, expected + " (got " + std::to_string(v) + ")");
  return v;
}

bool readBool(const Json& j, const std::string& path) {
  if (!j.is_boolean()) fail(path, "must be true or false" + got(j));
  return j.get<bool>();
}

std::string readString(const Json& j, const std::string& path) {
  if (!j.is_string()) fail(path, "must be a string" + got(j));
  return j.get<std::string>();
}

/// n finite numbers (positive ones if asked); `expected` says what they are for errors.
void readFloats(const Json& j, const std::string& path, const char* expected, int n, float* out,
                bool positive = false) {
  if (!j.is_array() || j.size() != size_t(n)) fail(path, expected + got(j));
  for (int i = 0; i < n; ++i) {
    if (!j[i].is_number()) fail(path, expected + got(j));
    double d = j[i].get<double>();
    float f = toFloat(d);
    if (!std::isfinite(f) || (positive && !(f > 0)))
      fail(path, std::string(expected) + " (got " + formatNumber(d) + ")");
    out[i] = f;
  }
}

Vec3 readVec3(const Json& j, const std::string& path) {
  Vec3 v;
  readFloats(j, path, "must be an array of three finite numbers [x, y, z]", 3, &v.x);
  return v;
}

Vec3 readPositiveVec3(const Json& j, const std::string& path) {
  Vec3 v;
  readFloats(j, path, "must be three positive finite numbers", 3, &v.x, true);
  return v;
}

Vec3 readDirection(const Json& j, const std::string& path) {
  Vec3 v = readVec3(j, path);
  double l2 = double(v.x) * v.x + double(v.y) * v.y + double(v.z) * v.z;
  if (!(l2 > 1e-12)) fail(path, "must be a non-zero direction");
  // Already unit (to float precision): keep the bits, so a written scene reads back equal.
  if (std::fabs(l2 - 1) <= 1e-6) return v;
  return normalize(v);
}

Quat readQuat(const Json& j, const std::string& path) {
  const char* expected = "must be a unit quaternion [x, y, z, w]";
  float c[4];
  readFloats(j, path, expected, 4, c);
  Quat q{c[0], c[1], c[2], c[3]};
  double l2 = double(q.x) * q.x + double(q.y) * q.y + double(q.z) * q.z + double(q.w) * q.w;
  double l = std::sqrt(l2);
  if (std::fabs(l - 1) > 1e-3) {
    fail(path, std::string(expected) + " (its length is " + formatNumber(l) +
                   "; lengths within 1e-3 of 1 are normalized)");
  }
  if (std::fabs(l2 - 1) <= 1e-6) return q;  // unit to float precision: keep the bits
  return normalize(q);
}

Quat readAxisAngle(const Json& j, const std::string& path) {
  const char* expected = "must be [ax, ay, az, angle] with a non-zero axis and the angle in rad";
  float c[4];
  readFloats(j, path, expected, 4, c);
  Vec3 axis{c[0], c[1], c[2]};
  if (!(lengthSquared(axis) > 1e-12f)) fail(path, expected);
  return Quat::fromAxisAngle(axis, c[3]);
}

// ---------------------------------------------------------------------------------------
// Object

Object::Object(const Json& j, std::string path, std::initializer_list<const char*> allowed)
    : json_(j), path_(std::move(path)) {
  if (!j.is_object()) fail(path_.empty() ? "(top level)" : path_, "must be an object" + got(j));
  for (auto it = j.begin(); it != j.end(); ++it) {
    const std::string& key = it.key();
    bool known = false;
    const char* best = nullptr;
    size_t bestDistance = 3;  // suggest only close names
    for (const char* a : allowed) {
      if (key == a) {
        known = true;
        break;
      }
      if (key.size() > kShownBytes) continue;  // no hint for a huge key
      size_t d = editDistance(key, a);
      if (d < bestDistance) {
        bestDistance = d;
        best = a;
      }
    }
    if (known) continue;
    std::string reason = "unknown field";
    if (best) reason += " (did you mean \"" + std::string(best) + "\"?)";
    reason += "; allowed here:";
    bool first = true;
    for (const char* a : allowed) {
      reason += (first ? " " : ", ") + std::string(a);
      first = false;
    }
    fail(member(path_, key), reason);
  }
}

const Json* Object::find(const char* key) const {
  auto it = json_.find(key);
  return it == json_.end() ? nullptr : &*it;
}

const Json& Object::require(const char* key) const {
  const Json* j = find(key);
  if (!j) fail(path(key), "is required");
  return *j;
}

void Object::forbid(const char* key, const std::string& reason) const {
  if (has(key)) fail(path(key), reason);
}

float Object::number(const char* key, float def, Range range) const {
  const Json* j = find(key);
  return j ? readFloat(*j, path(key), range) : def;
}

float Object::number(const char* key, Range range) const {
  return readFloat(require(key), path(key), range);
}

int64_t Object::integer(const char* key, int64_t def, int64_t lo, int64_t hi) const {
  const Json* j = find(key);
  return j ? readInt(*j, path(key), lo, hi) : def;
}

int64_t Object::integer(const char* key, int64_t lo, int64_t hi) const {
  return readInt(require(key), path(key), lo, hi);
}

bool Object::boolean(const char* key, bool def) const {
  const Json* j = find(key);
  return j ? readBool(*j, path(key)) : def;
}

std::string Object::string(const char* key, const std::string& def) const {
  const Json* j = find(key);
  return j ? readString(*j, path(key)) : def;
}

Vec3 Object::vec3(const char* key, Vec3 def) const {
  const Json* j = find(key);
  return j ? readVec3(*j, path(key)) : def;
}

Vec3 Object::positiveVec3(const char* key, Vec3 def) const {
  const Json* j = find(key);
  return j ? readPositiveVec3(*j, path(key)) : def;
}

Vec3 Object::direction(const char* key, Vec3 def) const {
  const Json* j = find(key);
  return j ? readDirection(*j, path(key)) : def;
}

// ---------------------------------------------------------------------------------------
// Builder

namespace {

bool positiveFinite(float v) {
  return std::isfinite(v) && v > 0;
}

// What is wrong with a body, or "" when it is valid. Explicit bodies are valid by
// construction; this catches generator parameters that are each fine but combine into
// something that is not (a size that underflows to 0, positions that overflow).
std::string invalidBody(const BodyDef& d) {
  if (!isFinite(d.position)) return "its position is not finite";
  if (!isFinite(d.rotation) || std::fabs(lengthSquared(d.rotation) - 1) > 1e-4f) {
    return "its rotation is not a unit quaternion";
  }
  if (!isFinite(d.linearVelocity) || !isFinite(d.angularVelocity)) {
    return "its velocity is not finite";
  }
  if (!std::isfinite(d.mass) || d.mass < 0) return "its mass is not a finite number >= 0";
  for (size_t i = 0; i < d.shapes.size(); ++i) {
    const ShapeDef& s = d.shapes[i];
    const ShapeGeom& g = s.geom;
    bool ok = isFinite(s.local.p) && isFinite(s.local.q);
    if (g.type == ShapeType::Sphere) ok = ok && positiveFinite(g.radius);
    if (g.type == ShapeType::Capsule) {
      ok = ok && positiveFinite(g.radius) && positiveFinite(g.halfHeight);
    }
    if (g.type == ShapeType::Box) {
      ok = ok && positiveFinite(g.halfExtents.x) && positiveFinite(g.halfExtents.y) &&
           positiveFinite(g.halfExtents.z);
    }
    if (!ok) return "shape " + std::to_string(i) + " has a size or pose out of range";
  }
  return "";
}

}  // namespace

int Builder::addBody(BodyDef def, const std::string& path) {
  if (std::string why = invalidBody(def); !why.empty()) {
    fail(path, "the body " + quote(def.name) + " would be invalid: " + why +
                   " (check the sizes, spacing and positions)");
  }
  // Generators add many bodies from one path: store each distinct path once.
  if (sourcePaths.empty() || sourcePaths.back() != path) sourcePaths.push_back(path);
  if (!def.name.empty()) {
    auto [it, inserted] = bodyIndex.emplace(def.name, int(bodies->size()));
    if (!inserted) {
      fail(path, "duplicate body name " + quote(def.name) + " (already used by " +
                     sourcePaths[bodySource[size_t(it->second)]] + ")");
    }
  }
  nameBytes += def.name.size();
  bodySource.push_back(uint32_t(sourcePaths.size() - 1));
  bodies->push_back(std::move(def));
  return int(bodies->size()) - 1;
}

namespace {

// Adds `count` to *total; fails at `path` when that passes `limit`.
void planCount(uint64_t* total, uint64_t count, uint64_t limit, const char* what,
               const std::string& path) {
  uint64_t after = addSat(*total, count);
  if (after > limit) {
    std::string has = *total == 0 ? "" : ", " + std::to_string(*total) + " before it";
    failExhausted(path, "would make the scene have " +
                            (after == UINT64_MAX ? std::string("over 2^64") : std::to_string(after)) +
                            " " + what + ", more than the limit of " + std::to_string(limit) +
                            " (this adds " +
                            (count == UINT64_MAX ? std::string("over 2^64") : std::to_string(count)) +
                            has + ")");
  }
  *total = after;
}

}  // namespace

void Builder::planBodies(uint64_t count, const std::string& path) {
  // Body indices are ints.
  uint64_t limit = std::min<uint64_t>(budget->maxBodies, uint64_t(INT32_MAX));
  planCount(&plannedBodies, count, limit, "bodies", path);
}

void Builder::planJoints(uint64_t count, const std::string& path, bool generated) {
  planCount(&plannedJoints, count, budget->maxJoints, "joints", path);
  if (generated) plannedGeneratedJoints += count;
}

void Builder::planShapes(uint64_t count, const std::string& path) {
  planCount(&plannedShapes, count, budget->maxShapes, "shapes", path);
}

void Builder::planHullPoints(uint64_t count, const std::string& path) {
  planCount(&plannedHullPoints, count, budget->maxHullPointsTotal, "hull points", path);
}

bool Builder::plan(const Object& o, const std::string& prefix, const GeneratorCounts& c) {
  if (!planning) return true;
  const std::string& path = o.path();
  // The names it makes: the prefix's own content, then its length with the longest suffix.
  std::string namePath = o.has("name") ? o.path("name") : path;
  checkName(prefix, namePath, *budget, "generator name");
  if (prefix.size() + c.longestSuffix > budget->maxNameBytes) {
    failExhausted(namePath, "the names this generator makes would be up to " +
                       std::to_string(prefix.size() + c.longestSuffix) +
                       " bytes long, more than the limit of " +
                       std::to_string(budget->maxNameBytes) + " (the prefix " + quote(prefix) +
                       " has " + std::to_string(prefix.size()) + " bytes, the suffixes up to " +
                       std::to_string(c.longestSuffix) + ")");
  }
  if (c.maxShapesPerBody > budget->maxShapesPerBody) {
    failExhausted(path, "would make a body with " + std::to_string(c.maxShapesPerBody) +
                            " shapes, more than the limit of " +
                            std::to_string(budget->maxShapesPerBody) + " per body");
  }
  planBodies(c.bodies, path);
  planJoints(c.joints, path, true);
  planShapes(c.shapes, path);
  return false;
}

void Builder::chargePattern(size_t patternBytes, const std::string& path) {
  // A pattern costs its length (split into pieces once) plus, for every named body, the
  // name's length + 1 (the match is linear in the name).
  uint64_t cost = addSat(addSat(patternBytes, nameBytes), bodies->size());
  uint64_t after = addSat(patternWork, cost);
  if (after > budget->maxPatternWork) {
    failExhausted(path, "matching the pattern against " + std::to_string(bodies->size()) +
                            " bodies exceeds the work budget (" + std::to_string(cost) +
                            " character comparisons, " + std::to_string(patternWork) +
                            " before it, limit " + std::to_string(budget->maxPatternWork) + ")");
  }
  patternWork = after;
}

Material readMaterial(const Json& j, const std::string& path) {
  Object o(j, path, {"friction", "restitution", "density"});
  Material m;
  m.friction = o.number("friction", m.friction, Range::NonNegative);
  m.restitution = o.number("restitution", m.restitution, Range::UnitInterval);
  m.density = o.number("density", m.density, Range::Positive);
  return m;
}

Material Builder::material(const Json& j, const std::string& path) const {
  if (j.is_string()) {
    std::string name = j.get<std::string>();
    auto it = materials.find(name);
    if (it == materials.end()) {
      std::string known;
      size_t shown = 0;
      for (const auto& [k, v] : materials) {
        if (shown == 8) {
          known += ", ... (" + std::to_string(materials.size()) + " in all)";
          break;
        }
        known += (known.empty() ? "" : ", ") + keyText(k);
        ++shown;
      }
      fail(path, "unknown material " + quote(name) +
                     " (defined in \"materials\": " + (known.empty() ? "none" : known) + ")");
    }
    return it->second;
  }
  if (!j.is_object()) {
    fail(path, "must be a material name or an object {friction, restitution, density}" + got(j));
  }
  return readMaterial(j, path);
}

// ---------------------------------------------------------------------------------------
// Rotation helpers shared with the generators.

Quat quatFromTo(Vec3 from, Vec3 to) {
  float d = dot(from, to);
  if (d < -0.999999f) {
    // Opposite: half a turn about any axis perpendicular to `from`.
    Vec3 axis = cross(from, Vec3{1, 0, 0});
    if (lengthSquared(axis) < 1e-6f) axis = cross(from, Vec3{0, 1, 0});
    axis = normalize(axis);
    return {axis.x, axis.y, axis.z, 0};
  }
  Vec3 c = cross(from, to);
  return normalize(Quat{c.x, c.y, c.z, 1 + d});
}

Quat quatFromBasis(Vec3 x, Vec3 y, Vec3 z) {
  // Shepperd's method on the matrix with columns x, y, z.
  float m00 = x.x, m10 = x.y, m20 = x.z;
  float m01 = y.x, m11 = y.y, m21 = y.z;
  float m02 = z.x, m12 = z.y, m22 = z.z;
  float tr = m00 + m11 + m22;
  Quat q;
  if (tr > 0) {
    float s = std::sqrt(tr + 1) * 2;
    q = {(m21 - m12) / s, (m02 - m20) / s, (m10 - m01) / s, 0.25f * s};
  } else if (m00 > m11 && m00 > m22) {
    float s = std::sqrt(1 + m00 - m11 - m22) * 2;
    q = {0.25f * s, (m01 + m10) / s, (m02 + m20) / s, (m21 - m12) / s};
  } else if (m11 > m22) {
    float s = std::sqrt(1 + m11 - m00 - m22) * 2;
    q = {(m01 + m10) / s, 0.25f * s, (m12 + m21) / s, (m02 - m20) / s};
  } else {
    float s = std::sqrt(1 + m22 - m00 - m11) * 2;
    q = {(m02 + m20) / s, (m12 + m21) / s, 0.25f * s, (m10 - m01) / s};
  }
  return normalize(q);
}

}  // namespace scene_detail

// ---------------------------------------------------------------------------------------
// Metric names. Criteria naming anything else are rejected (a typo would otherwise make a
// criterion silently unchecked). Each lists the groups and params its computation needs.

namespace {

using namespace scene_detail;

struct MetricInfo {
  const char* name;
  bool needsTopBodies = false;
  bool needsConservesEnergy = false;
  std::vector<const char*> groups = {};
  std::vector<const char*> params = {};
};

// Generic metrics are physbench's (phys/scene/metrics.h); the scene-specific ones are computed by
// the hooks of scene_metrics.cpp from the groups named here.
const std::vector<MetricInfo>& metricTable() {
  static const std::vector<MetricInfo> table = {
      {"ms_per_step_median"},
      {"ms_per_step_p99"},
      {"top_drift", true},
      {"penetration_max"},
      {"penetration_settled_max"},
      {"joint_error_max"},
      {"joint_error_rms"},
      {"joint_angle_error_max"},
      {"energy_drift", false, true},
      {"energy_rise_max"},
      {"energy_gain_settled_max"},
      {"energy_solve_delta_max"},
      {"velocity_residual_max"},
      {"max_speed"},
      {"substeps_max"},
      {"nan"},
      {"friction_ramp.static_displacement_max", false, false, {"ramp", "ramp_box"}},
      {"friction_ramp.accel_error_max", false, false, {"ramp", "ramp_box"}},
      {"restitution.rebound_height", false, false, {"bounce_ball"}},
      {"restitution.rebound_ratio", false, false, {"bounce_ball"}},
      {"tunnelling.passed_through", false, false, {"tunnel_wall", "tunnel_projectile"}},
      {"free_flight.trajectory_error", false, false, {"flight_projectile"}},
      {"free_flight.angular_momentum_drift", false, false, {"flight_spinner"}},
      {"windmill.speed_error", false, false, {"windmill_rotor"}},
      {"bridge.cars_arrived", false, false, {"bridge_car"}, {"finish_x"}},
      {"cradle.last_speed_ratio", false, false, {"cradle_ball"}},
      {"cradle.others_speed_ratio_max", false, false, {"cradle_ball"}},
  };
  return table;
}

const MetricInfo* findMetric(const std::string& name) {
  for (const MetricInfo& m : metricTable()) {
    if (name == m.name) return &m;
  }
  return nullptr;
}

// ---------------------------------------------------------------------------------------
// Loading.

BodyType readBodyType(const Json& j, const std::string& path) {
  std::string s = readString(j, path);
  if (s == "static") return BodyType::Static;
  if (s == "kinematic") return BodyType::Kinematic;
  if (s == "dynamic") return BodyType::Dynamic;
  fail(path, "must be \"static\", \"kinematic\" or \"dynamic\" (got " + quote(s) + ")");
}

// A rotation from "rotation" (quaternion) or "rotation_axis_angle"; identity when neither.
Quat readRotation(const Object& o) {
  if (o.has("rotation") && o.has("rotation_axis_angle")) {
    fail(o.path("rotation_axis_angle"), "give \"rotation\" or \"rotation_axis_angle\", not both");
  }
  if (const Json* j = o.find("rotation")) return readQuat(*j, o.path("rotation"));
  if (const Json* j = o.find("rotation_axis_angle")) {
    return readAxisAngle(*j, o.path("rotation_axis_angle"));
  }
  return Quat{};
}

ShapeDef readShape(const Json& j, const std::string& path, const Builder& b,
                   const Material& bodyMaterial, BodyType bodyType) {
  Object o(j, path,
           {"type", "radius", "half_extents", "half_height", "normal", "offset", "points",
            "position", "rotation", "rotation_axis_angle", "material"});
  std::string type = readString(o.require("type"), o.path("type"));
  // Geometry fields of other shape types are errors: they would be silently ignored.
  auto only = [&](std::initializer_list<const char*> used) {
    for (const char* key :
         {"radius", "half_extents", "half_height", "normal", "offset", "points"}) {
      bool isUsed = false;
      for (const char* u : used) isUsed = isUsed || std::strcmp(u, key) == 0;
      if (!isUsed) o.forbid(key, "is not a field of a " + keyText(type));
    }
  };
  ShapeDef s;
  if (type == "sphere") {
    only({"radius"});
    s.geom = ShapeGeom::sphere(o.number("radius", Range::Positive));
  } else if (type == "box") {
    only({"half_extents"});
    s.geom = ShapeGeom::box(readPositiveVec3(o.require("half_extents"), o.path("half_extents")));
  } else if (type == "capsule") {
    only({"radius", "half_height"});
    s.geom = ShapeGeom::capsule(o.number("radius", Range::Positive),
                                o.number("half_height", Range::Positive));
  } else if (type == "plane") {
    only({"normal", "offset"});
    if (bodyType != BodyType::Static) {
      fail(o.path("type"), "a plane is only allowed on a static body");
    }
    s.geom.type = ShapeType::Plane;
    s.geom.normal = o.direction("normal", Vec3{0, 0, 1});
    s.geom.offset = o.number("offset", 0.0f);
  } else if (type == "hull") {
    only({"points"});
    const Json& pts = o.require("points");
    std::string ppath = o.path("points");
    if (!pts.is_array() || pts.size() < 4) {
      fail(ppath, "must be an array of at least four points [x, y, z]" + got(pts));
    }
    // Counted in the planning pass already; checked again before the (costly) hull build.
    if (pts.size() > b.budget->maxHullPoints) {
      failExhausted(ppath, "has " + std::to_string(pts.size()) +
                               " points, more than the limit of " +
                               std::to_string(b.budget->maxHullPoints) + " per hull");
    }
    std::vector<Vec3> points;
    points.reserve(pts.size());
    for (size_t i = 0; i < pts.size(); ++i) points.push_back(readVec3(pts[i], element(ppath, i)));
    std::string error;
    auto hull = buildConvexHull(points, &error);
    if (!hull) fail(ppath, "the points span no volume (" + error + ")");
    s.geom = ShapeGeom::convexHull(std::move(hull));
  } else {
    fail(o.path("type"),
         "must be \"sphere\", \"box\", \"capsule\", \"plane\" or \"hull\" (got " + quote(type) +
             ")");
  }
  s.local.p = o.vec3("position", Vec3{});
  s.local.q = readRotation(o);
  if (const Json* m = o.find("material")) {
    s.material = b.material(*m, o.path("material"));
  } else {
    s.material = bodyMaterial;
  }
  return s;
}

void readSleep(const Json& j, const std::string& path, SleepSettings* out) {
  if (j.is_boolean()) {
    out->enabled = j.get<bool>();
    return;
  }
  Object o(j, path, {"enabled", "time", "linear_speed", "angular_speed"});
  out->enabled = o.boolean("enabled", true);
  out->time = o.number("time", out->time, Range::Positive);
  out->linearSpeed = o.number("linear_speed", out->linearSpeed, Range::NonNegative);
  out->angularSpeed = o.number("angular_speed", out->angularSpeed, Range::NonNegative);
  Status st = World::validate(*out);
  if (!st.ok()) fail(path, st.message);
}

BodyDef readBody(const Json& j, const std::string& path, const Builder& b) {
  Object o(j, path,
           {"name", "type", "position", "rotation", "rotation_axis_angle", "linear_velocity",
            "angular_velocity", "linear_damping", "angular_damping", "gravity_scale", "mass",
            "inertia", "gyroscopic", "allow_sleep", "material", "shapes"});
  BodyDef d;
  d.name = o.string("name", "");
  checkName(d.name, o.path("name"), *b.budget, "body name");
  if (const Json* t = o.find("type")) d.type = readBodyType(*t, o.path("type"));
  d.position = o.vec3("position", Vec3{});
  d.rotation = readRotation(o);
  d.linearVelocity = o.vec3("linear_velocity", Vec3{});
  d.angularVelocity = o.vec3("angular_velocity", Vec3{});
  d.linearDamping = o.number("linear_damping", 0.0f, Range::NonNegative);
  d.angularDamping = o.number("angular_damping", 0.0f, Range::NonNegative);
  d.gravityScale = o.number("gravity_scale", 1.0f);
  d.gyroscopic = o.boolean("gyroscopic", true);
  d.allowSleep = o.boolean("allow_sleep", true);
  if (d.type != BodyType::Dynamic) {
    o.forbid("mass", "only a dynamic body has a mass");
    o.forbid("inertia", "only a dynamic body has an inertia");
  }
  d.mass = o.has("mass") ? o.number("mass", Range::Positive) : 0.0f;
  if (const Json* in = o.find("inertia")) d.inertia = readPositiveVec3(*in, o.path("inertia"));
  Material bodyMaterial = b.defaultMaterial;
  if (const Json* m = o.find("material")) bodyMaterial = b.material(*m, o.path("material"));
  if (const Json* shapes = o.find("shapes")) {
    std::string spath = o.path("shapes");
    if (!shapes->is_array()) fail(spath, "must be an array of shapes" + got(*shapes));
    if (shapes->size() > b.budget->maxShapesPerBody) {
      failExhausted(spath, "has " + std::to_string(shapes->size()) +
                               " shapes, more than the limit of " +
                               std::to_string(b.budget->maxShapesPerBody) + " per body");
    }
    d.shapes.reserve(shapes->size());
    for (size_t i = 0; i < shapes->size(); ++i) {
      d.shapes.push_back(readShape((*shapes)[i], element(spath, i), b, bodyMaterial, d.type));
    }
  }
  if (d.type == BodyType::Dynamic && d.shapes.empty() && d.mass == 0) {
    fail(path, "a dynamic body needs at least one shape or a \"mass\"");
  }
  return d;
}

// A body given by name (string) or index (integer). Body names and indices are resolved
// after the generators ran, so joints and metrics can refer to generated bodies.
int readBodyRef(const Json& j, const std::string& path, const Builder& b) {
  if (j.is_string()) {
    std::string name = j.get<std::string>();
    auto it = b.bodyIndex.find(name);
    if (it == b.bodyIndex.end()) fail(path, "unknown body " + quote(name));
    return it->second;
  }
  if (j.is_number_integer()) {
    return int(readInt(j, path, 0, int64_t(b.bodies->size()) - 1));
  }
  fail(path, "must be a body name or index" + got(j));
}

JointType readJointType(const Json& j, const std::string& path) {
  std::string s = readString(j, path);
  if (s == "ball") return JointType::Ball;
  if (s == "hinge") return JointType::Hinge;
  if (s == "fixed") return JointType::Fixed;
  if (s == "distance") return JointType::Distance;
  if (s == "prismatic") return JointType::Prismatic;
  fail(path,
       "must be \"ball\", \"hinge\", \"fixed\", \"distance\" or \"prismatic\" (got " + quote(s) +
           ")");
}

Transform bodyPose(const Builder& b, int index) {
  if (index < 0) return Transform{};
  const BodyDef& d = (*b.bodies)[size_t(index)];
  return {d.position, d.rotation};
}

SceneJoint readJoint(const Json& j, const std::string& path, const Builder& b) {
  Object o(j, path,
           {"name", "type", "body_a", "body_b", "anchor_a", "anchor_b", "anchor_world", "axis_a",
            "axis_b", "axis_world", "limit", "motor", "length", "spring_hertz",
            "spring_damping_ratio", "collide_connected"});
  SceneJoint sj;
  JointDef& d = sj.def;
  d.type = readJointType(o.require("type"), o.path("type"));
  d.name = o.string("name", "");
  checkName(d.name, o.path("name"), *b.budget, "joint name");
  std::string typeName = toString(d.type);
  bool hasAxis = d.type == JointType::Hinge || d.type == JointType::Prismatic;
  bool hasLimit = hasAxis || d.type == JointType::Distance;
  bool isDistance = d.type == JointType::Distance;
  if (!hasAxis) {
    for (const char* k : {"axis_a", "axis_b", "axis_world", "motor"}) {
      o.forbid(k, std::string("is not a field of a ") + typeName + " joint");
    }
  }
  if (!hasLimit) o.forbid("limit", std::string("is not a field of a ") + typeName + " joint");
  if (!isDistance) {
    for (const char* k : {"length", "spring_hertz", "spring_damping_ratio"}) {
      o.forbid(k, std::string("is only a field of a distance joint"));
    }
  }

  if (const Json* a = o.find("body_a"); a && !a->is_null()) {
    sj.bodyA = readBodyRef(*a, o.path("body_a"), b);
  }
  sj.bodyB = readBodyRef(o.require("body_b"), o.path("body_b"), b);
  if (sj.bodyA == sj.bodyB) {
    fail(o.path("body_b"), "a joint must connect two different bodies (body_a is body_b)");
  }
  Transform xa = bodyPose(b, sj.bodyA), xb = bodyPose(b, sj.bodyB);

  if (const Json* w = o.find("anchor_world")) {
    o.forbid("anchor_a", "give \"anchor_world\" or \"anchor_a\"/\"anchor_b\", not both");
    o.forbid("anchor_b", "give \"anchor_world\" or \"anchor_a\"/\"anchor_b\", not both");
    Vec3 p = readVec3(*w, o.path("anchor_world"));
    d.anchorA = applyInverse(xa, p);
    d.anchorB = applyInverse(xb, p);
  } else {
    d.anchorA = o.vec3("anchor_a", Vec3{});
    d.anchorB = o.vec3("anchor_b", Vec3{});
  }
  if (const Json* w = o.find("axis_world")) {
    o.forbid("axis_a", "give \"axis_world\" or \"axis_a\"/\"axis_b\", not both");
    o.forbid("axis_b", "give \"axis_world\" or \"axis_a\"/\"axis_b\", not both");
    Vec3 axis = readDirection(*w, o.path("axis_world"));
    d.axisA = invRotate(xa.q, axis);
    d.axisB = invRotate(xb.q, axis);
  } else if (o.has("axis_a") != o.has("axis_b")) {
    fail(o.path(o.has("axis_a") ? "axis_b" : "axis_a"),
         "is required with the other local axis (or give \"axis_world\")");
  } else {
    d.axisA = o.direction("axis_a", Vec3{0, 0, 1});
    d.axisB = o.direction("axis_b", Vec3{0, 0, 1});
  }
  if (const Json* l = o.find("limit")) {
    Object lo(*l, o.path("limit"), {"lower", "upper", "enabled"});
    d.lower = lo.number("lower", Range::Any);
    d.upper = lo.number("upper", Range::Any);
    d.enableLimit = lo.boolean("enabled", true);
    if (d.lower > d.upper) fail(lo.path("upper"), "must be >= lower");
    if (isDistance && d.lower < 0) fail(lo.path("lower"), "must be >= 0 for a distance joint");
  }
  if (const Json* m = o.find("motor")) {
    Object mo(*m, o.path("motor"), {"speed", "max_force", "enabled"});
    d.motorSpeed = mo.number("speed", Range::Any);
    d.maxMotorForce = mo.number("max_force", Range::NonNegative);
    d.enableMotor = mo.boolean("enabled", true);
  }
  if (o.has("length")) d.length = o.number("length", Range::Positive);
  d.springHertz = o.number("spring_hertz", 0.0f, Range::NonNegative);
  d.springDampingRatio = o.number("spring_damping_ratio", 0.0f, Range::NonNegative);
  d.collideConnected = o.boolean("collide_connected", false);
  return sj;
}

// A '*' pattern over body names: '*' matches any run of characters other than '/'. The
// pattern and a name are split at '/' into segments, which must be as many; each pattern
// segment is pieces of literal text between '*'s: the first piece must start the name's
// segment, the last must end it, and the middle ones are found left to right, each with
// Knuth-Morris-Pratt (the leftmost match of each is the right one). Matching one name is
// linear in its length, whatever the pattern; nothing recurses or backtracks.
class GlobPattern {
 public:
  explicit GlobPattern(const std::string& pattern) : pattern_(pattern) {
    std::string_view p = pattern_;
    size_t start = 0;
    for (;;) {
      size_t slash = p.find('/', start);
      size_t end = slash == std::string_view::npos ? p.size() : slash;
      addSegment(start, end);
      if (slash == std::string_view::npos) break;
      start = slash + 1;
    }
  }

  bool match(std::string_view name) const {
    size_t start = 0;
    for (size_t k = 0; k < segments_.size(); ++k) {
      size_t slash = name.find('/', start);
      bool last = k + 1 == segments_.size();
      if ((slash == std::string_view::npos) != last) return false;  // segment counts differ
      size_t end = last ? name.size() : slash;
      if (!matchSegment(segments_[k], name.substr(start, end - start))) return false;
      start = end + 1;
    }
    return true;
  }

 private:
  // Everything in flat arrays: a pattern of a million '*' or '/' is a few allocations.
  struct Piece {
    size_t begin, size;  ///< in pattern_
    size_t next;         ///< its KMP failure function: next_[next, next + size)
  };
  struct Segment {
    bool star = false;        ///< has a '*'; else pieces_[first] is the whole segment
    size_t first = 0, count = 0;  ///< pieces_[first, first + count): first, middles, last
    size_t literalBytes = 0;  ///< sum of the pieces' sizes
  };

  std::string_view text(const Piece& p) const {
    return std::string_view(pattern_).substr(p.begin, p.size);
  }

  void addPiece(Segment* s, size_t begin, size_t end, bool middle) {
    Piece piece{begin, end - begin, next_.size()};
    if (middle) {
      // KMP failure function of the piece.
      std::string_view p = text(piece);
      next_.resize(next_.size() + p.size(), 0);
      uint32_t* f = next_.data() + piece.next;
      uint32_t k = 0;
      for (size_t i = 1; i < p.size(); ++i) {
        while (k > 0 && p[i] != p[k]) k = f[k - 1];
        if (p[i] == p[k]) ++k;
        f[i] = k;
      }
    }
    pieces_.push_back(piece);
    ++s->count;
    s->literalBytes += piece.size;
  }

  void addSegment(size_t begin, size_t end) {
    std::string_view seg = std::string_view(pattern_).substr(begin, end - begin);
    Segment s;
    s.first = pieces_.size();
    size_t star = seg.find('*');
    if (star == std::string_view::npos) {
      addPiece(&s, begin, end, false);
    } else {
      s.star = true;
      size_t lastStar = seg.rfind('*');
      addPiece(&s, begin, begin + star, false);
      for (size_t at = star + 1; at <= lastStar;) {
        size_t nextStar = seg.find('*', at);
        if (nextStar > at) addPiece(&s, begin + at, begin + nextStar, true);  // skip "**"
        at = nextStar + 1;
      }
      addPiece(&s, begin + lastStar + 1, end, false);
    }
    segments_.push_back(s);
  }

  // The end of the leftmost occurrence of the middle piece `piece` in t[from, to), or npos.
  size_t find(const Piece& piece, std::string_view t, size_t from, size_t to) const {
    std::string_view p = text(piece);
    const uint32_t* f = next_.data() + piece.next;
    size_t k = 0;
    for (size_t i = from; i < to; ++i) {
      while (k > 0 && t[i] != p[k]) k = f[k - 1];
      if (t[i] == p[k]) ++k;
      if (k == p.size()) return i + 1;
    }
    return std::string_view::npos;
  }

  bool matchSegment(const Segment& s, std::string_view t) const {
    const Piece& firstPiece = pieces_[s.first];
    if (!s.star) return t == text(firstPiece);
    if (t.size() < s.literalBytes) return false;
    std::string_view first = text(firstPiece), last = text(pieces_[s.first + s.count - 1]);
    if (t.substr(0, first.size()) != first) return false;
    if (t.substr(t.size() - last.size()) != last) return false;
    size_t at = first.size(), to = t.size() - last.size();
    for (size_t i = s.first + 1; i + 1 < s.first + s.count; ++i) {
      at = find(pieces_[i], t, at, to);
      if (at == std::string_view::npos) return false;
    }
    return true;
  }

  const std::string& pattern_;
  std::vector<Segment> segments_;
  std::vector<Piece> pieces_;
  std::vector<uint32_t> next_;
};

// A list of bodies: names, '*' patterns over names, or indices.
std::vector<int> readBodyList(const Json& j, const std::string& path, Builder& b) {
  if (!j.is_array()) fail(path, "must be an array of body names, patterns or indices" + got(j));
  std::vector<int> out;
  std::set<int> seen;
  auto add = [&](int i) {
    if (seen.insert(i).second) out.push_back(i);
  };
  for (size_t i = 0; i < j.size(); ++i) {
    std::string epath = element(path, i);
    const Json& e = j[i];
    if (e.is_string()) {
      const std::string& name = e.get_ref<const std::string&>();
      auto it = b.bodyIndex.find(name);
      if (it != b.bodyIndex.end()) {
        add(it->second);
        continue;
      }
      if (name.find('*') == std::string::npos) fail(epath, "unknown body " + quote(name));
      b.chargePattern(name.size(), epath);  // before any work
      GlobPattern pattern(name);
      size_t before = out.size();
      for (size_t k = 0; k < b.bodies->size(); ++k) {
        const std::string& n = (*b.bodies)[k].name;
        if (!n.empty() && pattern.match(n)) add(int(k));
      }
      if (out.size() == before) fail(epath, "the pattern " + quote(name) + " matches no body");
    } else {
      add(readBodyRef(e, epath, b));
    }
  }
  return out;
}

// One reader for solver settings, shared with the presets file (settings_json.h).
void readSolver(const Json& j, const std::string& path, SolverSettings* s) {
  Status st = solverSettingsFromJson(j, path, s);
  if (!st.ok()) fail("", st.message);
}

void readMetrics(const Json& j, const std::string& path, Builder& b, SceneMetrics* m) {
  Object o(j, path, {"top_bodies", "settle_time", "conserves_energy", "groups", "params"});
  if (const Json* t = o.find("top_bodies"))
    m->topBodies = readBodyList(*t, o.path("top_bodies"), b);
  m->settleTime = o.number("settle_time", float(m->settleTime), Range::NonNegative);
  m->conservesEnergy = o.boolean("conserves_energy", m->conservesEnergy);
  if (const Json* g = o.find("groups")) {
    std::string gpath = o.path("groups");
    if (!g->is_object()) fail(gpath, "must be an object {group name: [bodies]}" + got(*g));
    for (auto it = g->begin(); it != g->end(); ++it) {
      checkName(it.key(), member(gpath, it.key()), *b.budget, "group name");
      m->groups[it.key()] = readBodyList(it.value(), member(gpath, it.key()), b);
    }
  }
  if (const Json* p = o.find("params")) {
    std::string ppath = o.path("params");
    if (!p->is_object()) fail(ppath, "must be an object {name: number}" + got(*p));
    for (auto it = p->begin(); it != p->end(); ++it) {
      checkName(it.key(), member(ppath, it.key()), *b.budget, "param name");
      m->params[it.key()] = readDouble(it.value(), member(ppath, it.key()));
    }
  }
}

void readCriteria(const Json& j, const std::string& path, Scene* s) {
  if (!j.is_array()) fail(path, "must be an array of {metric, min, max}" + got(j));
  for (size_t i = 0; i < j.size(); ++i) {
    Object o(j[i], element(path, i), {"metric", "min", "max"});
    Criterion c;
    c.metric = readString(o.require("metric"), o.path("metric"));
    const MetricInfo* info = findMetric(c.metric);
    if (!info) {
      std::string known;
      for (const MetricInfo& mi : metricTable())
        known += (known.empty() ? "" : ", ") + std::string(mi.name);
      fail(o.path("metric"), "unknown metric " + quote(c.metric) + " (known: " + known + ")");
    }
    if (const Json* v = o.find("min")) c.min = readDouble(*v, o.path("min"));
    if (const Json* v = o.find("max")) c.max = readDouble(*v, o.path("max"));
    if (!c.min && !c.max) fail(o.path(), "a criterion needs \"min\" and/or \"max\"");
    if (c.min && c.max && *c.min > *c.max) fail(o.path("max"), "must be >= min");
    // The data the metric needs must be declared, or it could not be computed.
    if (info->needsTopBodies && s->metrics.topBodies.empty()) {
      fail(o.path("metric"), c.metric + " needs \"metrics.top_bodies\"");
    }
    if (info->needsConservesEnergy && !s->metrics.conservesEnergy) {
      fail(o.path("metric"), c.metric + " needs \"metrics.conserves_energy\": true");
    }
    for (const char* g : info->groups) {
      if (!s->metrics.groups.count(g)) {
        fail(o.path("metric"), c.metric + " needs the group \"metrics.groups." + g + "\"");
      }
    }
    for (const char* p : info->params) {
      if (!s->metrics.params.count(p)) {
        fail(o.path("metric"), c.metric + " needs the parameter \"metrics.params." + p + "\"");
      }
    }
    s->criteria.push_back(std::move(c));
  }
}

// The planning pass over the explicit bodies and joints: their counts, the shapes of each
// body and the points of each hull, from the sizes of the JSON arrays (their contents are
// checked when they are read).
void planExplicit(const Object& top, Builder* b) {
  const SceneBudget& budget = *b->budget;
  if (const Json* bodies = top.find("bodies"); bodies && bodies->is_array()) {
    b->planBodies(bodies->size(), "bodies");
    for (size_t i = 0; i < bodies->size(); ++i) {
      const Json& body = (*bodies)[i];
      if (!body.is_object()) continue;
      auto shapes = body.find("shapes");
      if (shapes == body.end() || !shapes->is_array()) continue;
      std::string spath = member(element("bodies", i), "shapes");
      if (shapes->size() > budget.maxShapesPerBody) {
        failExhausted(spath, "has " + std::to_string(shapes->size()) +
                                 " shapes, more than the limit of " +
                                 std::to_string(budget.maxShapesPerBody) + " per body");
      }
      b->planShapes(shapes->size(), spath);
      for (size_t k = 0; k < shapes->size(); ++k) {
        const Json& shape = (*shapes)[k];
        if (!shape.is_object()) continue;
        auto points = shape.find("points");
        if (points == shape.end() || !points->is_array()) continue;
        std::string ppath = member(element(spath, k), "points");
        if (points->size() > budget.maxHullPoints) {
          failExhausted(ppath, "has " + std::to_string(points->size()) +
                                   " points, more than the limit of " +
                                   std::to_string(budget.maxHullPoints) + " per hull");
        }
        b->planHullPoints(points->size(), ppath);
      }
    }
  }
  if (const Json* joints = top.find("joints"); joints && joints->is_array()) {
    b->planJoints(joints->size(), "joints", false);
  }
}

void loadScene(const Json& root, const SceneBudget& budget, Scene* s) {
  Object top(root, "",
             {"name", "description", "gravity", "time_step", "duration", "solver", "world",
              "sleep", "materials", "bodies", "joints", "generators", "metrics", "criteria"});
  s->name = top.string("name", "");
  checkName(s->name, "name", budget, "scene name");
  s->description = top.string("description", "");
  s->world.gravity = top.vec3("gravity", s->world.gravity);
  s->world.timeStep = top.number("time_step", s->world.timeStep, Range::Positive);
  if (const Json* d = top.find("duration"))
    s->duration = readDouble(*d, "duration", Range::Positive);
  if (const Json* sv = top.find("solver")) readSolver(*sv, "solver", &s->world.solver);
  // Scene files sleep unless they say otherwise: "sleep": false, or an object of settings.
  s->world.sleep.enabled = true;
  if (const Json* sl = top.find("sleep")) readSleep(*sl, "sleep", &s->world.sleep);
  if (const Json* w = top.find("world")) {
    Object o(*w, "world",
             {"max_linear_speed", "max_angular_speed", "speculative_distance", "aabb_margin",
              "backend"});
    WorldDef& wd = s->world;
    wd.maxLinearSpeed = o.number("max_linear_speed", wd.maxLinearSpeed, Range::Positive);
    wd.maxAngularSpeed = o.number("max_angular_speed", wd.maxAngularSpeed, Range::Positive);
    wd.speculativeDistance =
        o.number("speculative_distance", wd.speculativeDistance, Range::NonNegative);
    wd.aabbMargin = o.number("aabb_margin", wd.aabbMargin, Range::NonNegative);
    const std::string backend = o.string("backend", toString(wd.backend));
    if (!parseBackend(backend, &wd.backend))
      fail(o.path("backend"), "must be \"cpu\", \"gpu\" or \"auto\", got " + quote(backend));
  }

  Builder b;
  b.budget = &budget;
  b.bodies = &s->bodies;
  if (const Json* mats = top.find("materials")) {
    if (!mats->is_object()) fail("materials", "must be an object {name: material}" + got(*mats));
    for (auto it = mats->begin(); it != mats->end(); ++it) {
      checkName(it.key(), member("materials", it.key()), budget, "material name");
      b.materials[it.key()] = readMaterial(it.value(), member("materials", it.key()));
    }
    auto def = b.materials.find("default");
    if (def != b.materials.end()) b.defaultMaterial = def->second;
  }
  const Json* bodies = top.find("bodies");
  if (bodies && !bodies->is_array()) fail("bodies", "must be an array of bodies" + got(*bodies));
  const Json* gens = top.find("generators");
  if (gens && !gens->is_array()) fail("generators", "must be an array of generators" + got(*gens));
  if (const Json* joints = top.find("joints"); joints && !joints->is_array()) {
    fail("joints", "must be an array of joints" + got(*joints));
  }

  // Planning: every count against the budget before anything is built.
  b.planning = true;
  planExplicit(top, &b);
  if (gens) {
    for (size_t i = 0; i < gens->size(); ++i) runGenerator((*gens)[i], element("generators", i), &b);
  }
  b.planning = false;
  s->bodies.reserve(size_t(b.plannedBodies));
  b.bodyIndex.reserve(size_t(b.plannedBodies));
  b.bodySource.reserve(size_t(b.plannedBodies));
  b.generatedJoints.reserve(size_t(b.plannedGeneratedJoints));
  s->joints.reserve(size_t(b.plannedJoints));

  if (bodies) {
    for (size_t i = 0; i < bodies->size(); ++i) {
      std::string path = element("bodies", i);
      b.addBody(readBody((*bodies)[i], path, b), path);
    }
  }
  if (gens) {
    for (size_t i = 0; i < gens->size(); ++i) {
      size_t before = b.generatedJoints.size();
      runGenerator((*gens)[i], element("generators", i), &b);
      for (size_t k = before; k < b.generatedJoints.size(); ++k) {
        const JointDef& d = b.generatedJoints[k].def;
        if (!isFinite(d.anchorA) || !isFinite(d.anchorB)) {
          fail(element("generators", i),
               "the joint " + quote(d.name) + " would have anchors that are not finite");
        }
      }
    }
  }
  if (const Json* joints = top.find("joints")) {
    if (!joints->is_array()) fail("joints", "must be an array of joints" + got(*joints));
    for (size_t i = 0; i < joints->size(); ++i) {
      s->joints.push_back(readJoint((*joints)[i], element("joints", i), b));
    }
  }
  size_t explicitJoints = s->joints.size();
  for (SceneJoint& j : b.generatedJoints) s->joints.push_back(std::move(j));
  std::unordered_map<std::string, size_t> jointNames;
  for (size_t i = 0; i < s->joints.size(); ++i) {
    const std::string& n = s->joints[i].def.name;
    if (n.empty()) continue;
    auto [it, inserted] = jointNames.emplace(n, i);
    if (!inserted) {
      std::string where = i < explicitJoints ? element("joints", i) : "generators";
      fail(i < explicitJoints ? member(where, "name") : where,
           "duplicate joint name " + quote(n));
    }
  }
  if (const Json* m = top.find("metrics")) readMetrics(*m, "metrics", b, &s->metrics);
  if (const Json* c = top.find("criteria")) readCriteria(*c, "criteria", s);
}

// Reads JSON text into a Json document through nlohmann's SAX interface, noting the first
// duplicate key (which a DOM would silently collapse, last one winning) and refusing deep
// nesting. Not nlohmann's callback parser: that one scans the parent container at the end
// of every object (quadratic for an array of many objects). Each open container keeps only
// whether it is an array, its element count and its current key; a JSON path is built only
// for an error, so the cost is linear in the input whatever its keys.
class SceneJsonReader {
 public:
  explicit SceneJsonReader(Json* root) : root_(root) {}

  bool null() { return value(Json(nullptr)); }
  bool boolean(bool v) { return value(Json(v)); }
  bool number_integer(Json::number_integer_t v) { return value(Json(v)); }
  bool number_unsigned(Json::number_unsigned_t v) { return value(Json(v)); }
  bool number_float(Json::number_float_t v, const Json::string_t&) { return value(Json(v)); }
  bool string(Json::string_t& v) { return value(Json(std::move(v))); }
  bool binary(Json::binary_t& v) { return value(Json(std::move(v))); }

  bool start_object(std::size_t) { return open(false); }
  bool start_array(std::size_t) { return open(true); }
  bool end_object() { return close(); }
  bool end_array() { return close(); }

  bool key(Json::string_t& k) {
    Frame& f = frames_.back();
    auto& object = f.json->get_ref<Json::object_t&>();
    auto [it, inserted] = object.emplace(std::move(k), nullptr);
    if (!inserted) {
      if (duplicate.empty()) {
        duplicatePath = member(path(frames_.size()), it->first);
        duplicate = it->first;
      }
      it->second = nullptr;  // the last one wins, as in a DOM
    }
    f.slot = &it->second;
    f.key = &it->first;  // map nodes do not move
    return true;
  }

  template <class Exception>
  bool parse_error(std::size_t, const std::string&, const Exception& e) {
    throw e;
  }

  std::string duplicate, duplicatePath;

 private:
  static constexpr size_t kMaxDepth = 64;
  struct Frame {
    bool isArray = false;
    Json* json = nullptr;
    size_t index = 0;                          ///< elements so far (arrays)
    Json* slot = nullptr;                      ///< the current key's value (objects)
    const std::string* key = nullptr;          ///< the current key (objects)
    size_t indexInParent = 0;                  ///< where it is in its parent array
    const std::string* keyInParent = nullptr;  ///< or under which key of its parent object
  };

  // Stores a value where the parser is; returns where it went.
  Json* place(Json&& v) {
    if (frames_.empty()) {
      *root_ = std::move(v);
      return root_;
    }
    Frame& f = frames_.back();
    if (f.isArray) {
      auto& array = f.json->get_ref<Json::array_t&>();
      array.push_back(std::move(v));
      ++f.index;
      return &array.back();
    }
    *f.slot = std::move(v);
    return f.slot;
  }

  bool value(Json&& v) {
    place(std::move(v));
    return true;
  }

  bool open(bool isArray) {
    // Scenes nest a few levels; a deep input is hostile.
    if (frames_.size() >= kMaxDepth) {
      fail(path(frames_.size()), "nested deeper than " + std::to_string(kMaxDepth) + " levels");
    }
    Frame f;
    f.isArray = isArray;
    if (!frames_.empty()) {
      const Frame& parent = frames_.back();
      if (parent.isArray) {
        f.indexInParent = parent.index;
      } else {
        f.keyInParent = parent.key;
      }
    }
    // The parent's element (a pointer into its array) stays put while this one is open.
    f.json = place(Json(isArray ? Json::value_t::array : Json::value_t::object));
    frames_.push_back(f);
    return true;
  }

  bool close() {
    if (!frames_.empty()) frames_.pop_back();
    return true;
  }

  // The path of the container frames_[n - 1] ("" for the top level).
  std::string path(size_t n) const {
    std::string p;
    for (size_t i = 1; i < n && i < frames_.size(); ++i) {
      if (frames_[i - 1].isArray) {
        p = element(p, frames_[i].indexInParent);
      } else {
        p = member(p, frames_[i].keyInParent ? *frames_[i].keyInParent : std::string());
      }
    }
    return p;
  }

  Json* root_;
  std::vector<Frame> frames_;
};

std::string lineColumn(const std::string& text, size_t offset) {
  offset = std::min(offset, text.size());
  size_t line = 1, column = 1;
  for (size_t i = 0; i < offset; ++i) {
    if (text[i] == '\n') {
      ++line;
      column = 1;
    } else {
      ++column;
    }
  }
  return "line " + std::to_string(line) + ", column " + std::to_string(column);
}

std::string stripJsonPrefix(const char* what) {
  // "[json.exception.parse_error.101] parse error at ..." -> "parse error at ..."
  std::string s = what;
  if (!s.empty() && s[0] == '[') {
    size_t end = s.find("] ");
    if (end != std::string::npos) s = s.substr(end + 2);
  }
  return s;
}

// nlohmann quotes the input in its messages ("... last read: '<token>'"): the text between
// `opening` and the message's last '\'' is shown as keyText shows it; *token gets it whole.
std::string clipQuotedToken(const std::string& msg, const char* opening, std::string* token) {
  size_t q1 = msg.find(opening), q2 = msg.rfind('\'');
  if (q1 == std::string::npos) return msg;
  q1 += std::strlen(opening);
  if (q2 == std::string::npos || q2 < q1) return msg;
  *token = msg.substr(q1, q2 - q1);
  return msg.substr(0, q1) + keyText(*token) + msg.substr(q2);
}

Status invalid(const std::string& message) {
  return Status::Error(StatusCode::InvalidArgument, message);
}

// ---------------------------------------------------------------------------------------
// Writing.

using OJson = nlohmann::ordered_json;

// A float as the double with the shortest decimal form that reads back to the same float,
// so written files say 0.1 rather than 0.10000000149011612.
double jsonNumber(float f) {
  if (f == 0) return 0.0;  // -0 (from negating a zero component) reads as 0: same value
  char buf[32];
  auto r = std::to_chars(buf, buf + sizeof buf, f);
  double d = 0;
  if (r.ec == std::errc()) {
    auto back = std::from_chars(buf, r.ptr, d);
    if (back.ec == std::errc() && float(d) == f) return d;
  }
  return double(f);
}

OJson jsonVec3(Vec3 v) {
  return OJson::array({jsonNumber(v.x), jsonNumber(v.y), jsonNumber(v.z)});
}
OJson jsonQuat(Quat q) {
  return OJson::array({jsonNumber(q.x), jsonNumber(q.y), jsonNumber(q.z), jsonNumber(q.w)});
}
bool isIdentity(Quat q) {
  return q == Quat{};
}
bool isZero(Vec3 v) {
  return v == Vec3{};
}

OJson jsonMaterial(const Material& m) {
  return OJson{{"friction", jsonNumber(m.friction)},
               {"restitution", jsonNumber(m.restitution)},
               {"density", jsonNumber(m.density)}};
}

bool sameMaterial(const Material& a, const Material& b) {
  return a.friction == b.friction && a.restitution == b.restitution && a.density == b.density;
}

OJson jsonBodyRef(const Scene& s, int index) {
  if (index < 0) return nullptr;
  if (size_t(index) < s.bodies.size() && !s.bodies[size_t(index)].name.empty()) {
    return s.bodies[size_t(index)].name;
  }
  return index;
}

OJson jsonBodyList(const Scene& s, const std::vector<int>& list) {
  OJson a = OJson::array();
  for (int i : list) a.push_back(jsonBodyRef(s, i));
  return a;
}

// Compact form of a value, with spaces after ',' and ':' (used for short containers).
void writeInline(const OJson& j, std::string* out) {
  if (j.is_array()) {
    *out += '[';
    bool first = true;
    for (const OJson& e : j) {
      if (!first) *out += ", ";
      first = false;
      writeInline(e, out);
    }
    *out += ']';
  } else if (j.is_object()) {
    *out += '{';
    bool first = true;
    for (auto it = j.begin(); it != j.end(); ++it) {
      if (!first) *out += ", ";
      first = false;
      *out += OJson(it.key()).dump();
      *out += ": ";
      writeInline(it.value(), out);
    }
    *out += '}';
  } else {
    *out += j.dump();
  }
}

// Pretty printer: a container that fits on its line is written inline, others one member
// per line. Keeps a 1000-body scene readable (one body per line) and diffable.
void writePretty(const OJson& j, int indent, std::string* out) {
  constexpr size_t kWidth = 100;
  if (!j.is_structured() || j.empty()) {
    writeInline(j, out);
    return;
  }
  std::string flat;
  writeInline(j, &flat);
  if (flat.size() + size_t(indent) <= kWidth) {
    *out += flat;
    return;
  }
  std::string pad(size_t(indent + 2), ' ');
  bool isArray = j.is_array();
  *out += isArray ? "[\n" : "{\n";
  bool first = true;
  for (auto it = j.begin(); it != j.end(); ++it) {
    if (!first) *out += ",\n";
    first = false;
    *out += pad;
    if (!isArray) {
      *out += OJson(it.key()).dump();
      *out += ": ";
    }
    writePretty(it.value(), indent + 2, out);
  }
  *out += '\n';
  *out += std::string(size_t(indent), ' ');
  *out += isArray ? ']' : '}';
}

}  // namespace

// ---------------------------------------------------------------------------------------
// Public API.

const std::vector<std::string>& knownSceneMetrics() {
  static const std::vector<std::string> names = [] {
    std::vector<std::string> v;
    for (const MetricInfo& m : metricTable()) v.push_back(m.name);
    return v;
  }();
  return names;
}

// A message's text after the source: at most kMaxDetail bytes (cut at a UTF-8 boundary), so
// a reply stays small whatever the input (nlohmann's parse errors quote the input too).
std::string capped(std::string detail) {
  constexpr size_t kMaxDetail = 960;
  if (detail.size() <= kMaxDetail) return detail;
  size_t end = kMaxDetail;
  while (end > 0 && (static_cast<unsigned char>(detail[end]) & 0xC0) == 0x80) --end;
  detail.resize(end);
  return detail + "...";
}

Status parseScene(const std::string& json, const std::string& source, Scene* out,
                  const SceneBudget& budget) {
  if (!out) return invalid(source + ": no output scene given");
  auto invalid = [&](const std::string& detail) {
    return Status::Error(StatusCode::InvalidArgument, source + ": " + capped(detail));
  };
  try {
    Json root;
    SceneJsonReader dup(&root);
    try {
      Json::sax_parse(json, &dup, Json::input_format_t::json, /*strict=*/true,
                      /*ignore_comments=*/true);
    } catch (const Json::parse_error& e) {
      std::string token;
      return invalid(clipQuotedToken(stripJsonPrefix(e.what()), "last read: '", &token));
    } catch (const Json::exception& e) {
      // Number overflow (e.g. 1e999) carries no position: find the token in the text (a
      // short one only: the search is linear in the text times the token's length).
      std::string token;
      std::string msg = clipQuotedToken(stripJsonPrefix(e.what()), "'", &token);
      if (!token.empty() && token.size() <= kShownBytes) {
        size_t at = json.find(token);
        if (at != std::string::npos) msg = lineColumn(json, at) + ": " + msg;
      }
      return invalid(msg + " (numbers must be finite)");
    }
    if (!dup.duplicate.empty()) {
      return invalid(dup.duplicatePath + ": duplicate key " + quote(dup.duplicate));
    }
    Scene s;
    loadScene(root, budget, &s);
    *out = std::move(s);
    return Status::Ok();
  } catch (const LoadError& e) {
    return Status::Error(e.code,
                         source + ": " + capped((e.path.empty() ? "" : e.path + ": ") + e.reason));
  } catch (const std::bad_alloc&) {
    return Status::Error(StatusCode::ResourceExhausted, source + ": out of memory");
  } catch (const std::exception& e) {
    return invalid(e.what());
  }
}

Status loadSceneFile(const std::string& path, Scene* out, const SceneBudget& budget) {
  std::ifstream f(path, std::ios::binary);
  if (!f) {
    return Status::Error(StatusCode::NotFound,
                         path + ": cannot open the scene file (" + std::strerror(errno) + ")");
  }
  std::ostringstream text;
  text << f.rdbuf();
  if (f.bad()) return invalid(path + ": read error");
  return parseScene(text.str(), path, out, budget);
}

std::string sceneToJson(const Scene& s) {
  OJson root;
  root["name"] = s.name;
  if (!s.description.empty()) root["description"] = s.description;
  root["gravity"] = jsonVec3(s.world.gravity);
  root["time_step"] = jsonNumber(s.world.timeStep);
  root["duration"] = s.duration;
  OJson solver = OJson::parse(solverSettingsToJson(s.world.solver).dump());
  for (auto& [key, value] : solver.items()) {
    if (value.is_number_float()) value = jsonNumber(float(value.get<double>()));
  }
  root["solver"] = std::move(solver);
  root["world"] = OJson{{"max_linear_speed", jsonNumber(s.world.maxLinearSpeed)},
                        {"max_angular_speed", jsonNumber(s.world.maxAngularSpeed)},
                        {"speculative_distance", jsonNumber(s.world.speculativeDistance)},
                        {"aabb_margin", jsonNumber(s.world.aabbMargin)}};
  if (s.world.backend != Backend::Cpu) root["world"]["backend"] = toString(s.world.backend);
  root["sleep"] = OJson{{"enabled", s.world.sleep.enabled},
                        {"time", jsonNumber(s.world.sleep.time)},
                        {"linear_speed", jsonNumber(s.world.sleep.linearSpeed)},
                        {"angular_speed", jsonNumber(s.world.sleep.angularSpeed)}};

  // Materials other than the default are written once and referred to by name.
  std::vector<Material> materials;
  auto materialName = [&](const Material& m) {
    for (size_t i = 0; i < materials.size(); ++i) {
      if (sameMaterial(materials[i], m)) return "m" + std::to_string(i);
    }
    materials.push_back(m);
    return "m" + std::to_string(materials.size() - 1);
  };
  const Material kDefault;
  OJson bodies = OJson::array();
  for (const BodyDef& d : s.bodies) {
    OJson b;
    if (!d.name.empty()) b["name"] = d.name;
    if (d.type != BodyType::Dynamic)
      b["type"] = d.type == BodyType::Static ? "static" : "kinematic";
    if (!isZero(d.position)) b["position"] = jsonVec3(d.position);
    if (!isIdentity(d.rotation)) b["rotation"] = jsonQuat(d.rotation);
    if (!isZero(d.linearVelocity)) b["linear_velocity"] = jsonVec3(d.linearVelocity);
    if (!isZero(d.angularVelocity)) b["angular_velocity"] = jsonVec3(d.angularVelocity);
    if (d.linearDamping != 0) b["linear_damping"] = jsonNumber(d.linearDamping);
    if (d.angularDamping != 0) b["angular_damping"] = jsonNumber(d.angularDamping);
    if (d.gravityScale != 1) b["gravity_scale"] = jsonNumber(d.gravityScale);
    if (d.type == BodyType::Dynamic && d.mass != 0) b["mass"] = jsonNumber(d.mass);
    if (d.type == BodyType::Dynamic && !isZero(d.inertia)) b["inertia"] = jsonVec3(d.inertia);
    if (!d.gyroscopic) b["gyroscopic"] = false;
    if (!d.allowSleep) b["allow_sleep"] = false;
    OJson shapes = OJson::array();
    for (const ShapeDef& sd : d.shapes) {
      OJson sh;
      const ShapeGeom& g = sd.geom;
      sh["type"] = toString(g.type);
      switch (g.type) {
        case ShapeType::Sphere:
          sh["radius"] = jsonNumber(g.radius);
          break;
        case ShapeType::Box:
          sh["half_extents"] = jsonVec3(g.halfExtents);
          break;
        case ShapeType::Capsule:
          sh["radius"] = jsonNumber(g.radius);
          sh["half_height"] = jsonNumber(g.halfHeight);
          break;
        case ShapeType::Plane:
          sh["normal"] = jsonVec3(g.normal);
          if (g.offset != 0) sh["offset"] = jsonNumber(g.offset);
          break;
        case ShapeType::Hull: {
          OJson pts = OJson::array();
          if (g.hull) {
            for (Vec3 p : g.hull->vertices) pts.push_back(jsonVec3(p));
          }
          sh["points"] = std::move(pts);
          break;
        }
      }
      if (!isZero(sd.local.p)) sh["position"] = jsonVec3(sd.local.p);
      if (!isIdentity(sd.local.q)) sh["rotation"] = jsonQuat(sd.local.q);
      if (!sameMaterial(sd.material, kDefault)) sh["material"] = materialName(sd.material);
      shapes.push_back(std::move(sh));
    }
    if (!shapes.empty()) b["shapes"] = std::move(shapes);
    bodies.push_back(std::move(b));
  }
  if (!materials.empty()) {
    OJson mats = OJson::object();
    for (size_t i = 0; i < materials.size(); ++i) {
      mats["m" + std::to_string(i)] = jsonMaterial(materials[i]);
    }
    root["materials"] = std::move(mats);
  }
  root["bodies"] = std::move(bodies);

  OJson joints = OJson::array();
  for (const SceneJoint& sj : s.joints) {
    const JointDef& d = sj.def;
    OJson j;
    j["type"] = toString(d.type);
    if (!d.name.empty()) j["name"] = d.name;
    if (sj.bodyA >= 0) j["body_a"] = jsonBodyRef(s, sj.bodyA);
    j["body_b"] = jsonBodyRef(s, sj.bodyB);
    j["anchor_a"] = jsonVec3(d.anchorA);
    j["anchor_b"] = jsonVec3(d.anchorB);
    bool hasAxis = d.type == JointType::Hinge || d.type == JointType::Prismatic;
    bool hasLimit = hasAxis || d.type == JointType::Distance;
    if (hasAxis) {
      j["axis_a"] = jsonVec3(d.axisA);
      j["axis_b"] = jsonVec3(d.axisB);
    }
    if (hasLimit && (d.enableLimit || d.lower != 0 || d.upper != 0)) {
      OJson l{{"lower", jsonNumber(d.lower)}, {"upper", jsonNumber(d.upper)}};
      if (!d.enableLimit) l["enabled"] = false;
      j["limit"] = std::move(l);
    }
    if (hasAxis && (d.enableMotor || d.motorSpeed != 0 || d.maxMotorForce != 0)) {
      OJson m{{"speed", jsonNumber(d.motorSpeed)}, {"max_force", jsonNumber(d.maxMotorForce)}};
      if (!d.enableMotor) m["enabled"] = false;
      j["motor"] = std::move(m);
    }
    if (d.type == JointType::Distance) {
      if (d.length >= 0) j["length"] = jsonNumber(d.length);
      if (d.springHertz != 0) j["spring_hertz"] = jsonNumber(d.springHertz);
      if (d.springDampingRatio != 0) j["spring_damping_ratio"] = jsonNumber(d.springDampingRatio);
    }
    if (d.collideConnected) j["collide_connected"] = true;
    joints.push_back(std::move(j));
  }
  if (!joints.empty()) root["joints"] = std::move(joints);

  const SceneMetrics& m = s.metrics;
  OJson metrics;
  if (!m.topBodies.empty()) metrics["top_bodies"] = jsonBodyList(s, m.topBodies);
  metrics["settle_time"] = m.settleTime;
  metrics["conserves_energy"] = m.conservesEnergy;
  if (!m.groups.empty()) {
    OJson groups = OJson::object();
    for (const auto& [name, list] : m.groups) groups[name] = jsonBodyList(s, list);
    metrics["groups"] = std::move(groups);
  }
  if (!m.params.empty()) {
    OJson params = OJson::object();
    for (const auto& [name, v] : m.params) params[name] = v;
    metrics["params"] = std::move(params);
  }
  root["metrics"] = std::move(metrics);
  OJson criteria = OJson::array();
  for (const Criterion& c : s.criteria) {
    OJson cj{{"metric", c.metric}};
    if (c.min) cj["min"] = *c.min;
    if (c.max) cj["max"] = *c.max;
    criteria.push_back(std::move(cj));
  }
  if (!criteria.empty()) root["criteria"] = std::move(criteria);

  std::string out;
  writePretty(root, 0, &out);
  out += '\n';
  return out;
}

Status instantiateScene(const Scene& scene, World* world, std::vector<BodyId>* ids,
                        std::vector<JointId>* jointIds) {
  const std::string where = "scene \"" + scene.name + "\": ";
  if (!world) return invalid(where + "no world given");
  int n = int(scene.bodies.size());
  // Check the references first: nothing is created for a scene that cannot be complete.
  for (size_t i = 0; i < scene.joints.size(); ++i) {
    const SceneJoint& j = scene.joints[i];
    if (j.bodyA < -1 || j.bodyA >= n || j.bodyB < 0 || j.bodyB >= n) {
      return invalid(where + "joints[" + std::to_string(i) +
                     "] refers to a body index out of range");
    }
  }
  std::vector<BodyId> bodies;
  std::vector<JointId> joints;
  bodies.reserve(scene.bodies.size());
  joints.reserve(scene.joints.size());
  auto rollback = [&] {
    for (auto it = joints.rbegin(); it != joints.rend(); ++it) world->destroyJoint(*it);
    for (auto it = bodies.rbegin(); it != bodies.rend(); ++it) world->destroyBody(*it);
  };
  auto label = [](const char* kind, size_t i, const std::string& name) {
    std::string s = std::string(kind) + "[" + std::to_string(i) + "]";
    if (!name.empty()) s += " (\"" + name + "\")";
    return s;
  };
  for (size_t i = 0; i < scene.bodies.size(); ++i) {
    BodyId id;
    Status st = world->createBody(scene.bodies[i], &id);
    if (!st.ok()) {
      rollback();
      return Status::Error(st.code,
                           where + label("bodies", i, scene.bodies[i].name) + ": " + st.message);
    }
    bodies.push_back(id);
  }
  for (size_t i = 0; i < scene.joints.size(); ++i) {
    const SceneJoint& sj = scene.joints[i];
    JointDef def = sj.def;
    def.bodyA = sj.bodyA < 0 ? BodyId{} : bodies[size_t(sj.bodyA)];
    def.bodyB = bodies[size_t(sj.bodyB)];
    JointId id;
    Status st = world->createJoint(def, &id);
    if (!st.ok()) {
      rollback();
      return Status::Error(st.code, where + label("joints", i, sj.def.name) + ": " + st.message);
    }
    joints.push_back(id);
  }
  if (ids) *ids = std::move(bodies);
  if (jointIds) *jointIds = std::move(joints);
  return Status::Ok();
}

}  // namespace phys
