// Scene files: JSON descriptions of a world (gravity, time step, solver, materials, bodies,
// joints) plus what a run should measure and the criteria it must pass. The format is
// documented in docs/SCENES.md. physbench, the tests and (later) physd all load scenes here.
#pragma once

#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "phys/world/world.h"

namespace phys {

/// A joint in a scene refers to bodies by their index in Scene::bodies (-1 = the world).
struct SceneJoint {
  JointDef def;  ///< def.bodyA / def.bodyB are ignored; the indices below are used
  int bodyA = -1;
  int bodyB = -1;
};

/// A pass criterion: `metric` (a physbench metric name, e.g. "top_drift") must be
/// <= max and/or >= min.
struct Criterion {
  std::string metric;
  std::optional<double> min, max;
};

/// What a scene asks the metrics to look at.
struct SceneMetrics {
  std::vector<int> topBodies;    ///< body indices whose horizontal drift is top_drift
  double settleTime = 1.0;       ///< s, after which penetration counts as "settled"
  bool conservesEnergy = false;  ///< energy_drift applies (free flight, pendulum)
  /// Named body indices for scene-specific metrics (e.g. "ball", "car0").
  std::map<std::string, std::vector<int>> groups;
  /// Named numbers for scene-specific metrics (e.g. "finish_x" for the bridge), JSON
  /// "metrics": {"params": {"finish_x": 60}}.
  std::map<std::string, double> params;
};

struct Scene {
  std::string name;
  std::string description;
  WorldDef world;
  double duration = 10;  ///< s, default run length
  std::vector<BodyDef> bodies;
  std::vector<SceneJoint> joints;
  SceneMetrics metrics;
  std::vector<Criterion> criteria;
};

/// What one scene may cost. Every count is checked before anything is built (a generator's
/// counts are computed from its parameters), so a scene over budget is refused within
/// milliseconds with StatusCode::ResourceExhausted and nothing big allocated. Parsing takes
/// time and memory linear in the input's size plus these counts.
struct SceneBudget {
  uint64_t maxBodies = 4'000'000;           ///< after expanding the generators
  uint64_t maxJoints = 4'000'000;           ///< explicit and generated
  uint64_t maxShapes = 8'000'000;           ///< over all bodies
  uint32_t maxShapesPerBody = 64;
  uint32_t maxHullPoints = 256;             ///< points of one hull
  uint64_t maxHullPointsTotal = 4'000'000;  ///< points of all hulls, each use counted
  /// Bytes of a name: of a body, a joint, a name a generator makes from its "name" prefix,
  /// a material key, a metrics group or param, the scene. Names must also be valid UTF-8
  /// without control characters (InvalidArgument).
  uint32_t maxNameBytes = 256;
  /// Character comparisons of all '*' patterns (metrics body lists) together; each pattern
  /// costs its length plus, for every named body, the name's length + 1.
  uint64_t maxPatternWork = 50'000'000;
};

/// Parses scene JSON. `source` names the file in error messages. Every error message names
/// the source, the JSON path of the field (e.g. "bodies[3].shapes[0].half_extents") and the
/// reason; keys, names and patterns are shown cut to 64 bytes, so a message stays under
/// about 1 KiB plus the source. Malformed input is InvalidArgument; a scene over `budget`
/// is ResourceExhausted. On error *out is unspecified.
Status parseScene(const std::string& json, const std::string& source, Scene* out,
                  const SceneBudget& budget = {});
/// Reads and parses a scene file.
Status loadSceneFile(const std::string& path, Scene* out, const SceneBudget& budget = {});
/// Serializes a scene to JSON text that parseScene reads back to the same scene.
std::string sceneToJson(const Scene& scene);

/// Metric names a criterion may use (docs/SCENES.md defines each); others are rejected.
const std::vector<std::string>& knownSceneMetrics();

/// Creates every body and joint of a scene in a world (whose WorldDef should be
/// scene.world). ids[i] is the id of scene.bodies[i]. All-or-nothing: on error the world
/// is left as it was.
Status instantiateScene(const Scene& scene, World* world, std::vector<BodyId>* ids,
                        std::vector<JointId>* jointIds = nullptr);

}  // namespace phys
