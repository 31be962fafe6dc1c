// Scene-specific metrics (friction ramp, restitution, tunnelling, free flight, windmill,
// bridge, Newton's cradle). Each hook watches the bodies of the groups its scene declares in "metrics.groups".
#pragma once

#include <map>
#include <memory>
#include <string>
#include <vector>

#include "phys/scene/scene.h"
#include "phys/world/world.h"

namespace phys {

class SceneMetricHook {
 public:
  virtual ~SceneMetricHook() = default;
  virtual void afterStep(const World& world) = 0;
  /// Adds this scene's metrics ("scene.metric" -> value) to *out.
  virtual void summarize(std::map<std::string, double>* out) const = 0;
};

/// The hooks a scene's groups ask for, combined; nullptr when the scene needs none.
std::unique_ptr<SceneMetricHook> makeSceneMetricHook(const Scene& scene, const World& world,
                                                     const std::vector<BodyId>& ids);

}  // namespace phys
