// Private to the scene loader (scene.cpp, scene_generators.cpp): JSON reading helpers that
// carry the JSON path of every value, and the builder that generators append bodies to.
#pragma once

#include <cstdint>
#include <initializer_list>
#include <map>
#include <nlohmann/json.hpp>
#include <string>
#include <unordered_map>
#include <vector>

#include "phys/scene/scene.h"

namespace phys::scene_detail {

using Json = nlohmann::json;

/// The loader reports errors by throwing this from deep inside the reading helpers; the
/// public functions catch it and turn it into a Status, so nothing escapes the API. It keeps
/// the many field readers one line each instead of a Status check per field.
struct LoadError {
  std::string path;    ///< JSON path, e.g. "bodies[3].shapes[0].half_extents"
  std::string reason;  ///< what is wrong and what is expected
  StatusCode code = StatusCode::InvalidArgument;
};
[[noreturn]] void fail(const std::string& path, const std::string& reason);
/// A count over the budget (StatusCode::ResourceExhausted).
[[noreturn]] void failExhausted(const std::string& path, const std::string& reason);

/// "path.key" (or "key" at the top level) and "path[i]". A key from the input is shown as
/// keyText does, so a path stays short whatever the input.
std::string member(const std::string& path, const std::string& key);
std::string element(const std::string& path, size_t index);

/// Bytes of a key, name or pattern echoed in an error message.
constexpr size_t kShownBytes = 64;
/// `s` for a message, unquoted: control bytes escaped (\xNN), and a text over kShownBytes
/// cut there (at a UTF-8 boundary) followed by "...(N bytes)".
std::string keyText(const std::string& s);
/// keyText(s) in double quotes, e.g. "box_*" or "aaaa...(262144 bytes)".
std::string quote(const std::string& s);
/// Fails at `path` (InvalidArgument) unless `name` is at most budget.maxNameBytes bytes of
/// valid UTF-8 without control characters (bytes < 0x20 and 0x7F); `what` says whose name.
void checkName(const std::string& name, const std::string& path, const SceneBudget& budget,
               const char* what);
/// Whether `s` is valid UTF-8 (no overlong forms, surrogates or code points > U+10FFFF);
/// *control is set when it has a byte < 0x20 or 0x7F.
bool validUtf8(const std::string& s, bool* control);
/// "a + b" saturating at UINT64_MAX, and "a * b" likewise (counts from untrusted input).
uint64_t addSat(uint64_t a, uint64_t b);
uint64_t mulSat(uint64_t a, uint64_t b);

/// Range checks for numbers.
enum class Range { Any, Positive, NonNegative, UnitInterval };

float readFloat(const Json& j, const std::string& path, Range range = Range::Any);
double readDouble(const Json& j, const std::string& path, Range range = Range::Any);
int64_t readInt(const Json& j, const std::string& path, int64_t lo, int64_t hi);
bool readBool(const Json& j, const std::string& path);
std::string readString(const Json& j, const std::string& path);
/// Three finite numbers [x, y, z].
Vec3 readVec3(const Json& j, const std::string& path);
/// Three positive finite numbers (sizes).
Vec3 readPositiveVec3(const Json& j, const std::string& path);
/// A non-zero vector, returned normalized (kept bit-exact when already unit).
Vec3 readDirection(const Json& j, const std::string& path);
/// A unit quaternion [x, y, z, w]; normalized when within 1e-3 of unit, an error otherwise.
Quat readQuat(const Json& j, const std::string& path);
/// [ax, ay, az, angle]: a rotation of angle (rad) about a non-zero axis.
Quat readAxisAngle(const Json& j, const std::string& path);

/// A JSON object whose keys are checked against the allowed list on construction: an
/// unknown key is an error (it catches typos), with a suggestion when one is close.
class Object {
 public:
  Object(const Json& j, std::string path, std::initializer_list<const char*> allowed);

  const std::string& path() const { return path_; }
  std::string path(const char* key) const { return member(path_, key); }
  const Json* find(const char* key) const;
  bool has(const char* key) const { return find(key) != nullptr; }
  /// The value of a required key.
  const Json& require(const char* key) const;
  /// Fails when a key that only makes sense in another context is present.
  void forbid(const char* key, const std::string& reason) const;

  float number(const char* key, float def, Range range = Range::Any) const;
  float number(const char* key, Range range) const;  ///< required
  int64_t integer(const char* key, int64_t def, int64_t lo, int64_t hi) const;
  int64_t integer(const char* key, int64_t lo, int64_t hi) const;  ///< required
  bool boolean(const char* key, bool def) const;
  std::string string(const char* key, const std::string& def) const;
  Vec3 vec3(const char* key, Vec3 def) const;
  Vec3 positiveVec3(const char* key, Vec3 def) const;
  Vec3 direction(const char* key, Vec3 def) const;

 private:
  const Json& json_;
  std::string path_;
};

/// What one generator makes, computed from its parameters before it runs.
struct GeneratorCounts {
  uint64_t bodies = 0;
  uint64_t joints = 0;
  uint64_t shapes = 0;            ///< over all its bodies
  uint64_t maxShapesPerBody = 1;  ///< of its body with the most shapes
  size_t longestSuffix = 0;       ///< bytes it appends to its "name" prefix, at most
};

/// Bodies and joints as they are loaded; generators append to it. Loading runs in two
/// passes: the planning pass counts everything (the explicit bodies, shapes, hull points and
/// joints, and each generator's counts from its parameters) against the budget, building
/// nothing; the building pass then builds, with every container reserved to its final size.
struct Builder {
  const SceneBudget* budget = nullptr;
  /// True in the planning pass: generators read their parameters, call plan() and stop.
  bool planning = false;

  std::vector<BodyDef>* bodies = nullptr;
  std::vector<SceneJoint> generatedJoints;
  std::unordered_map<std::string, int> bodyIndex;  ///< name -> index in *bodies
  /// Where each body was defined (index into sourcePaths), for duplicate-name errors.
  std::vector<uint32_t> bodySource;
  std::vector<std::string> sourcePaths;
  std::map<std::string, Material> materials;
  Material defaultMaterial;  ///< materials["default"] when given

  /// Totals of the planning pass.
  uint64_t plannedBodies = 0, plannedJoints = 0, plannedGeneratedJoints = 0;
  uint64_t plannedShapes = 0, plannedHullPoints = 0;
  /// Bytes of all body names (for the cost of a '*' pattern), and the pattern work so far.
  uint64_t nameBytes = 0;
  uint64_t patternWork = 0;

  /// Appends a body; fails at `path` when its name is already taken.
  int addBody(BodyDef def, const std::string& path);
  /// Planning pass: adds `count` bodies (joints, shapes, hull points) from `path` to the
  /// totals; fails (ResourceExhausted) when a total passes its limit.
  void planBodies(uint64_t count, const std::string& path);
  void planJoints(uint64_t count, const std::string& path, bool generated);
  void planShapes(uint64_t count, const std::string& path);
  void planHullPoints(uint64_t count, const std::string& path);
  /// Called by every generator once its counts are known, before it builds anything. In the
  /// planning pass it checks the generator's name prefix (with the longest suffix it
  /// appends) and shapes per body, adds its counts to the totals and returns false: the
  /// generator stops there. In the building pass it returns true.
  bool plan(const Object& o, const std::string& prefix, const GeneratorCounts& c);
  /// Adds the pattern's cost (see SceneBudget::maxPatternWork) to the work so far; fails at
  /// `path` (ResourceExhausted) when that passes the budget.
  void chargePattern(size_t patternBytes, const std::string& path);
  /// A material given by name (from "materials") or inline.
  Material material(const Json& j, const std::string& path) const;
};

/// Parses one material object {friction, restitution, density}.
Material readMaterial(const Json& j, const std::string& path);

/// Expands one entry of "generators" into bodies and joints (in the planning pass: reads
/// its parameters and plans its counts, see Builder::plan).
void runGenerator(const Json& j, const std::string& path, Builder* b);

/// Quaternion rotating unit vector `from` onto unit vector `to`.
Quat quatFromTo(Vec3 from, Vec3 to);
/// Quaternion of the rotation whose matrix has columns x, y, z (orthonormal, right-handed).
Quat quatFromBasis(Vec3 x, Vec3 y, Vec3 z);

}  // namespace phys::scene_detail
