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
};
[[noreturn]] void fail(const std::string& path, const std::string& reason);

/// "path.key" (or "key" at the top level) and "path[i]".
std::string member(const std::string& path, const std::string& key);
std::string element(const std::string& path, size_t index);

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

/// Bodies and joints as they are loaded; generators append to it.
struct Builder {
  /// More than this many bodies in one scene is an error, not an out-of-memory crash.
  static constexpr int64_t kMaxBodies = 4'000'000;

  std::vector<BodyDef>* bodies = nullptr;
  std::vector<SceneJoint> generatedJoints;
  std::unordered_map<std::string, int> bodyIndex;  ///< name -> index in *bodies
  /// Where each body was defined (index into sourcePaths), for duplicate-name errors.
  std::vector<uint32_t> bodySource;
  std::vector<std::string> sourcePaths;
  std::map<std::string, Material> materials;
  Material defaultMaterial;  ///< materials["default"] when given

  /// Appends a body; fails at `path` when its name is already taken.
  int addBody(BodyDef def, const std::string& path);
  /// Fails at `path` when adding `count` more bodies would pass kMaxBodies.
  void reserve(int64_t count, const std::string& path);
  /// A material given by name (from "materials") or inline.
  Material material(const Json& j, const std::string& path) const;
};

/// Parses one material object {friction, restitution, density}.
Material readMaterial(const Json& j, const std::string& path);

/// Expands one entry of "generators" into bodies and joints.
void runGenerator(const Json& j, const std::string& path, Builder* b);

/// Quaternion rotating unit vector `from` onto unit vector `to`.
Quat quatFromTo(Vec3 from, Vec3 to);
/// Quaternion of the rotation whose matrix has columns x, y, z (orthonormal, right-handed).
Quat quatFromBasis(Vec3 x, Vec3 y, Vec3 z);

}  // namespace phys::scene_detail
