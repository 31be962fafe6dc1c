// Scene files: JSON descriptions of a world (gravity, time step, solver, materials, bodies,
// joints) plus what a run should measure and the criteria it must pass. The format is
// documented in docs/SCENES.md. physbench, the tests and (later) physd all load scenes here.
#pragma once

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

/// Parses scene JSON. `source` names the file in error messages. Every error message names
/// the source, the JSON path of the field (e.g. "bodies[3].shapes[0].half_extents") and the
/// reason. On error *out is unspecified.
Status parseScene(const std::string& json, const std::string& source, Scene* out);
/// Reads and parses a scene file.
Status loadSceneFile(const std::string& path, Scene* out);
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
