// The metrics of shared/SCENES.md, computed after every step in double precision and
// summarized over a run. physbench and the tests use this one implementation.
#pragma once

#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "phys/scene/scene.h"
#include "phys/world/world.h"

namespace phys {

/// A run's summary. Metrics that do not apply to the scene are empty.
struct MetricsSummary {
  int steps = 0;
  double msPerStepMedian = 0, msPerStepP99 = 0;
  /// Median ms per step of the steps after the scene's settle time (empty if none): what a
  /// world costs once it has come to rest (sleeping).
  std::optional<double> msPerStepSettledMedian;
  int awakeBodiesFinal = 0;  ///< StepStats::awake after the last step
  /// After the last step: StepStats::contacts (pairs, touching or not), vectorizedManifolds
  /// (the touching ones the Gauss-Seidel scheme solved in SIMD lanes) and contactParts (the
  /// nested parts they were cut into).
  int contactsFinal = 0, manifoldsFinal = 0, contactPartsFinal = 0;
  std::optional<double> jointErrorMax, jointErrorRms, jointAngleErrorMax;
  std::optional<double> penetrationMax, penetrationSettledMax;
  double energySolveDeltaMax = 0;     ///< J, largest energy increase across one step
  std::optional<double> energyDrift;  ///< (E_end - E_start) / |E_start|
  double energyRiseMax = 0;           ///< max over the run of (E(t) - E_start) / |E_start|
  /// max over t >= settle time of (E(t) - E(settle)) / |E(settle)|; empty if never settled
  std::optional<double> energyGainSettledMax;
  std::optional<double> topDrift;  ///< m, largest horizontal displacement of a top body
  double velocityResidualMax = 0;
  double maxSpeed = 0;  ///< m/s
  int substepsMax = 0;  ///< most substeps a step took (stack stiffening, guard retries)
  long long nan = 0;    ///< non-finite numbers seen in body states
  uint64_t stateHash = 0;
  /// Scene-specific metrics ("friction_ramp.static_displacement_max", ...).
  std::map<std::string, double> extra;
  /// Average ms per step of each stage.
  std::map<std::string, double> stageMs;
  /// The GPU profile's figures that are not times, averaged over the steps that ran on the
  /// device: "broad_phase_tests_per_shape" (StepStats::broadPhaseTestsPerShape). Empty
  /// when no step did.
  std::map<std::string, double> gpuProfile;
  /// Average bytes a step brought back from the GPU backend's device (0 on the CPU).
  double readbackBytesPerStep = 0;
  /// Average bytes a step sent up to the GPU backend's device (0 on the CPU).
  double uploadBytesPerStep = 0;
  /// Average ms per step of the host's parts (StepProfile::hostUpload ... and guard):
  /// "upload", "readback", "mirror", "other", "guard".
  std::map<std::string, double> hostMs;

  /// Value of a metric by its physbench name, if it applies.
  std::optional<double> value(const std::string& name) const;
};

struct CriterionResult {
  std::string name;
  std::optional<double> value;
  std::optional<double> min, max;
  bool passed = false;
};

/// Records metrics while a scene runs. Construct after instantiateScene, call afterStep()
/// after each World::step().
class MetricsRecorder {
 public:
  MetricsRecorder(const Scene& scene, const World& world, std::vector<BodyId> ids);
  void afterStep(const World& world);
  MetricsSummary summary() const;

 private:
  struct Impl;
  std::shared_ptr<Impl> impl_;
};

/// Checks a summary against criteria (a missing metric fails its criterion).
std::vector<CriterionResult> evaluate(const MetricsSummary& m,
                                      const std::vector<Criterion>& criteria);

/// Names of every metric value() knows besides the scene-specific ones.
const std::vector<std::string>& metricNames();

}  // namespace phys
