#include "phys/scene/metrics.h"

#include <algorithm>
#include <cmath>
#include <memory>

#include "scene_metrics.h"

namespace phys {

namespace {

using StageField = double StepProfile::*;
const std::pair<const char*, StageField> kStages[] = {
    {"sync_to_device", &StepProfile::syncToDevice},
    {"apply_commands", &StepProfile::applyCommands},
    {"update_bounds", &StepProfile::updateBounds},
    {"broad_phase", &StepProfile::broadPhase},
    {"narrow_phase", &StepProfile::narrowPhase},
    {"build_islands", &StepProfile::buildIslands},
    {"prepare", &StepProfile::prepare},
    {"integrate_velocities", &StepProfile::integrateVelocities},
    {"warm_start", &StepProfile::warmStart},
    {"solve", &StepProfile::solve},
    {"integrate_positions", &StepProfile::integratePositions},
    {"relax", &StepProfile::relax},
    {"restitution", &StepProfile::restitution},
    {"position_pass", &StepProfile::positionPass},
    {"store_impulses", &StepProfile::storeImpulses},
    {"finalize", &StepProfile::finalize},
    {"readback", &StepProfile::readback},
};
/// The host's part of a step (StepProfile::hostUpload and the rest; guard: outside total).
const std::pair<const char*, StageField> kHostParts[] = {
    {"upload", &StepProfile::hostUpload}, {"readback", &StepProfile::hostReadback},
    {"mirror", &StepProfile::hostMirror}, {"other", &StepProfile::hostOther},
    {"guard", &StepProfile::guard},
};

double percentile(std::vector<double> v, double p) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  size_t i =
      size_t(std::min<double>(double(v.size() - 1), std::floor(p * double(v.size() - 1) + 0.5)));
  return v[i];
}

bool finiteState(const BodyState& s) {
  return isFinite(s.position) && isFinite(s.rotation) && isFinite(s.linearVelocity) &&
         isFinite(s.angularVelocity);
}

}  // namespace

struct MetricsRecorder::Impl {
  const Scene* scene = nullptr;
  std::vector<BodyId> ids;
  std::vector<std::pair<BodyId, Vec3>> tops;  ///< top bodies and where they started
  std::vector<double> stepMs, settledStepMs;
  std::map<std::string, double> stageSum, hostSum;
  double uploadSum = 0;
  double bpTestsSum = 0;  ///< StepStats::broadPhaseTestsPerShape over the device's steps
  int bpTestsSteps = 0;
  double readbackSum = 0;
  double energyStart = 0, energyEnd = 0;
  std::optional<double> energySettled;  ///< energy at the first step past the settle time
  double jointErrMax = 0, jointErrSq = 0, jointAngMax = 0;
  long long jointSamples = 0;
  double penMax = 0, penSettledMax = 0;
  bool sawContacts = false;
  bool settled = false;  ///< a step past the scene's settle time was seen
  MetricsSummary s;
  std::unique_ptr<SceneMetricHook> hook;
};

MetricsRecorder::MetricsRecorder(const Scene& scene, const World& world, std::vector<BodyId> ids)
    : impl_(std::make_shared<Impl>()) {
  Impl& m = *impl_;
  m.scene = &scene;
  m.ids = std::move(ids);
  for (int i : scene.metrics.topBodies) {
    BodyState st;
    if (i >= 0 && size_t(i) < m.ids.size() && world.getBody(m.ids[size_t(i)], &st).ok())
      m.tops.push_back({m.ids[size_t(i)], st.position});
  }
  m.energyStart = m.energyEnd = world.energy();
  m.hook = makeSceneMetricHook(scene, world, m.ids);
}

void MetricsRecorder::afterStep(const World& world) {
  Impl& m = *impl_;
  MetricsSummary& s = m.s;
  s.steps++;
  const StepProfile& p = world.profile();
  m.stepMs.push_back(p.total);
  for (const auto& [name, field] : kStages) m.stageSum[name] += p.*field;
  for (const auto& [name, field] : kHostParts) m.hostSum[name] += p.*field;
  m.readbackSum += double(world.backendState().readbackBytes);
  m.uploadSum += double(world.backendState().uploadBytes);

  const StepStats& st = world.stats();
  if (st.broadPhaseTestsPerShape > 0) {
    m.bpTestsSum += st.broadPhaseTestsPerShape;
    m.bpTestsSteps++;
  }
  s.energySolveDeltaMax = std::max(s.energySolveDeltaMax, st.energyAfter - st.energyBefore);
  s.velocityResidualMax = std::max(s.velocityResidualMax, st.velocityResidual);
  s.substepsMax = std::max(s.substepsMax, st.substeps);
  m.energyEnd = st.energyAfter;
  const double E = st.energyAfter;
  s.energyRiseMax =
      std::max(s.energyRiseMax, (E - m.energyStart) / std::max(std::fabs(m.energyStart), 1e-9));
  if (world.time() >= m.scene->metrics.settleTime) {
    if (!m.energySettled) m.energySettled = E;
    double gain = (E - *m.energySettled) / std::max(std::fabs(*m.energySettled), 1e-9);
    s.energyGainSettledMax = std::max(s.energyGainSettledMax.value_or(gain), gain);
  }
  if (st.contactPoints > 0) m.sawContacts = true;
  m.penMax = std::max(m.penMax, st.maxPenetration);
  s.awakeBodiesFinal = st.awake;
  s.contactsFinal = st.contacts;
  s.manifoldsFinal = st.vectorizedManifolds;
  s.contactPartsFinal = st.contactParts;
  if (world.time() > m.scene->metrics.settleTime) {
    m.settledStepMs.push_back(p.total);
    m.settled = true;
    m.penSettledMax = std::max(m.penSettledMax, st.maxPenetration);
  }

  for (BodyId id : m.ids) {
    BodyState b;
    if (!world.getBody(id, &b).ok()) continue;
    if (!finiteState(b)) {
      s.nan++;
      continue;
    }
    s.maxSpeed = std::max(s.maxSpeed, double(length(b.linearVelocity)));
  }
  for (const auto& [id, start] : m.tops) {
    BodyState b;
    if (!world.getBody(id, &b).ok()) continue;
    double dx = double(b.position.x) - start.x, dy = double(b.position.y) - start.y;
    double d = std::sqrt(dx * dx + dy * dy);
    if (!std::isfinite(d)) d = 1e30;
    s.topDrift = std::max(s.topDrift.value_or(0), d);
  }
  for (JointId j : world.joints()) {
    JointState js;
    world.getJoint(j, nullptr, &js);
    double e = js.positionError;
    m.jointErrMax = std::max(m.jointErrMax, std::isfinite(e) ? e : 1e30);
    m.jointErrSq += e * e;
    m.jointAngMax = std::max(m.jointAngMax, double(js.angleError));
    m.jointSamples++;
  }
  if (m.hook) m.hook->afterStep(world);
}

MetricsSummary MetricsRecorder::summary() const {
  const Impl& m = *impl_;
  MetricsSummary s = m.s;
  s.msPerStepMedian = percentile(m.stepMs, 0.5);
  s.msPerStepP99 = percentile(m.stepMs, 0.99);
  if (!m.settledStepMs.empty()) s.msPerStepSettledMedian = percentile(m.settledStepMs, 0.5);
  if (m.jointSamples > 0) {
    s.jointErrorMax = m.jointErrMax;
    s.jointErrorRms = std::sqrt(m.jointErrSq / double(m.jointSamples));
    s.jointAngleErrorMax = m.jointAngMax;
  }
  if (m.sawContacts) {
    s.penetrationMax = m.penMax;
    // A run that ends before the settle time measured nothing settled: missing, not 0.
    if (m.settled) s.penetrationSettledMax = m.penSettledMax;
  }
  if (m.scene->metrics.conservesEnergy && m.energyStart != 0)
    s.energyDrift = (m.energyEnd - m.energyStart) / std::fabs(m.energyStart);
  for (const auto& [name, sum] : m.stageSum) s.stageMs[name] = s.steps ? sum / s.steps : 0;
  if (m.bpTestsSteps > 0)
    s.gpuProfile["broad_phase_tests_per_shape"] = m.bpTestsSum / m.bpTestsSteps;
  s.readbackBytesPerStep = s.steps ? m.readbackSum / s.steps : 0;
  s.uploadBytesPerStep = s.steps ? m.uploadSum / s.steps : 0;
  for (const auto& [name, sum] : m.hostSum) s.hostMs[name] = s.steps ? sum / s.steps : 0;
  if (m.hook) m.hook->summarize(&s.extra);
  return s;
}

const std::vector<std::string>& metricNames() {
  static const std::vector<std::string> names = {"ms_per_step_median",
                                                 "ms_per_step_p99",
                                                 "joint_error_max",
                                                 "joint_error_rms",
                                                 "joint_angle_error_max",
                                                 "penetration_max",
                                                 "penetration_settled_max",
                                                 "energy_solve_delta_max",
                                                 "energy_drift",
                                                 "energy_rise_max",
                                                 "energy_gain_settled_max",
                                                 "top_drift",
                                                 "velocity_residual_max",
                                                 "max_speed",
                                                 "substeps_max",
                                                 "nan"};
  return names;
}

std::optional<double> MetricsSummary::value(const std::string& name) const {
  if (name == "ms_per_step_median") return msPerStepMedian;
  if (name == "ms_per_step_p99") return msPerStepP99;
  if (name == "joint_error_max") return jointErrorMax;
  if (name == "joint_error_rms") return jointErrorRms;
  if (name == "joint_angle_error_max") return jointAngleErrorMax;
  if (name == "penetration_max") return penetrationMax;
  if (name == "penetration_settled_max") return penetrationSettledMax;
  if (name == "energy_solve_delta_max") return energySolveDeltaMax;
  if (name == "energy_drift") return energyDrift;
  if (name == "energy_rise_max") return energyRiseMax;
  if (name == "energy_gain_settled_max") return energyGainSettledMax;
  if (name == "top_drift") return topDrift;
  if (name == "velocity_residual_max") return velocityResidualMax;
  if (name == "max_speed") return maxSpeed;
  if (name == "substeps_max") return double(substepsMax);
  if (name == "nan") return double(nan);
  auto it = extra.find(name);
  if (it != extra.end()) return it->second;
  return std::nullopt;
}

std::vector<CriterionResult> evaluate(const MetricsSummary& m,
                                      const std::vector<Criterion>& criteria) {
  std::vector<CriterionResult> out;
  for (const Criterion& c : criteria) {
    CriterionResult r;
    r.name = c.metric;
    r.value = m.value(c.metric);
    r.min = c.min;
    r.max = c.max;
    r.passed = r.value.has_value() && std::isfinite(*r.value) && (!c.min || *r.value >= *c.min) &&
               (!c.max || *r.value <= *c.max);
    out.push_back(r);
  }
  return out;
}

}  // namespace phys
