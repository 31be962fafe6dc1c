// physbench's single-scene mode: one scene, one preset, its metrics on stdout (and as JSON).
// The ctest scene tests rely on its output and exit status; keep both stable.
#include <cassert>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>

#include "bench.h"
#include "phys/scene/metrics.h"
#include "phys/scene/presets.h"
#include "phys/scene/scene.h"
#include "phys/world/world.h"

namespace phys::bench {

std::string backendLabel(const World& world) {
  const BackendState& b = world.backendState();
  if (b.requested == Backend::Cpu) return "cpu";
  if (b.active == Backend::Cpu && b.note.rfind("auto: ", 0) == 0)
    return "cpu (" + b.note + ")";  // auto chose the CPU for the world's size
  if (b.active == Backend::Cpu)
    return "cpu (" + std::string(toString(b.requested)) + ": " + b.note + ")";
  std::string label = "gpu (" + b.device + "; " + std::to_string(b.gpuSteps) +
                      " steps on the device, " + std::to_string(b.cpuSteps) + " on the CPU";
  if (b.cpuSteps > 0) label += ": " + b.lastFallback;
  // Islands the CPU stepped inside device steps: those steps count on the device, but the
  // CPU did their islands' physics (docs/ARCHITECTURE.md, "Islands on the CPU beside the
  // device").
  if (b.cpuIslandSteps > 0) {
    char mean[32];
    std::snprintf(mean, sizeof mean, "%.1f", double(b.cpuIslandBodySteps) / double(b.cpuIslandSteps));
    label += "; in " + std::to_string(b.cpuIslandSteps) + " of them islands on the CPU (" + mean +
             " bodies a step, " + std::to_string(b.cpuIslandRetakes) +
             " device steps retaken): " + b.cpuIslandReason;
  }
  if (b.requested == Backend::Auto) label += "; " + b.note;
  return label + ")";
}

namespace {

nlohmann::json optional(const std::optional<double>& v) {
  return v && std::isfinite(*v) ? nlohmann::json(*v) : nlohmann::json(nullptr);
}

nlohmann::json toJson(const MetricsSummary& m) {
  nlohmann::json j;
  for (const std::string& name : metricNames()) j[name] = optional(m.value(name));
  j["state_hash"] = hashText(m.stateHash);
  j["ms_per_step_settled_median"] = optional(m.msPerStepSettledMedian);
  j["awake_bodies_final"] = m.awakeBodiesFinal;
  j["contacts_final"] = m.contactsFinal;
  j["manifolds_final"] = m.manifoldsFinal;
  j["contact_parts_final"] = m.contactPartsFinal;
  for (const auto& [k, v] : m.extra) j[k] = std::isfinite(v) ? nlohmann::json(v) : nullptr;
  return j;
}

nlohmann::json toJson(const std::vector<CriterionResult>& results) {
  nlohmann::json out = nlohmann::json::array();
  for (const CriterionResult& cr : results) {
    nlohmann::json c{{"name", cr.name}, {"value", optional(cr.value)}, {"passed", cr.passed}};
    c["limit"] = cr.max ? nlohmann::json(*cr.max) : optional(cr.min);
    c["kind"] = cr.max ? "max" : "min";
    if (cr.min && cr.max) c["min"] = *cr.min;
    out.push_back(c);
  }
  return out;
}

/// A scene run from its instantiation for a number of steps, its world kept for a look at
/// the bodies afterwards.
struct SceneRun {
  std::unique_ptr<World> world;
  std::vector<BodyId> ids;  ///< ids[i]: scene.bodies[i]
  MetricsSummary metrics;   ///< state hash included
};

Status runScene(const Scene& scene, int steps, SceneRun* out) {
  out->world = std::make_unique<World>(scene.world);
  Status st = instantiateScene(scene, out->world.get(), &out->ids);
  if (!st.ok()) return st;
  MetricsRecorder rec(scene, *out->world, out->ids);
  for (int i = 0; i < steps; ++i) {
    out->world->step();
    rec.afterStep(*out->world);
  }
  out->metrics = rec.summary();
  out->metrics.stateHash = out->world->stateHash();
  return Status::Ok();
}

CpuComparison compare(const Scene& scene, const SceneRun& run, const SceneRun& cpu) {
  CpuComparison c;
  c.cpu = cpu.metrics;
  c.cpuCriteria = evaluate(cpu.metrics, scene.criteria);
  for (size_t i = 0; i < run.ids.size(); ++i) {
    BodyState a, b;
    if (!run.world->getBody(run.ids[i], &a).ok() || !cpu.world->getBody(cpu.ids[i], &b).ok())
      continue;
    // A NaN on either side is the worst difference, and stays so.
    const double dp = length(a.position - b.position);
    if (!std::isnan(c.maxPositionDifference) && !(dp <= c.maxPositionDifference)) {
      c.maxPositionDifference = dp;
      c.worstBody = scene.bodies[i].name.empty() ? "#" + std::to_string(i) : scene.bodies[i].name;
    }
    const double dv = length(a.linearVelocity - b.linearVelocity);
    if (!std::isnan(c.maxVelocityDifference) && !(dv <= c.maxVelocityDifference))
      c.maxVelocityDifference = dv;
  }
  return c;
}

/// "<= 0.01", ">= 1", ">= 1, <= 2".
std::string bounds(const CriterionResult& c) {
  std::string out = c.min ? ">= " + fmtNumber(c.min) : "";
  if (c.min && c.max) out += ", ";
  if (c.max) out += "<= " + fmtNumber(c.max);
  return out;
}

}  // namespace

std::string hashText(uint64_t h) {
  char b[17];
  std::snprintf(b, sizeof b, "%016llx", static_cast<unsigned long long>(h));
  return b;
}

std::string fmtNumber(const std::optional<double>& v) {
  if (!v) return "-";
  char b[32];
  std::snprintf(b, sizeof b, "%.6g", *v);
  return b;
}

int runSingle(SingleOptions opt) {
  if (!opt.peer.empty()) return runSinglePeer(opt);
  Scene scene;
  Status st = loadSceneFile(opt.scenePath, &scene);
  if (!st.ok()) {
    std::cerr << "physbench: " << st.message << "\n";
    return 2;
  }
  std::string usedPreset = "scene";
  if (!opt.presetName.empty()) {
    std::map<std::string, Preset> presets;
    std::string def;
    st = loadPresetsFile(opt.presetsPath, &presets, &def);
    if (!st.ok()) {
      std::cerr << "physbench: " << st.message << "\n";
      return 2;
    }
    if (opt.presetName == "default") opt.presetName = def;
    auto it = presets.find(opt.presetName);
    if (it == presets.end()) {
      std::cerr << "physbench: unknown preset '" << opt.presetName << "'; known:";
      for (const auto& [k, v] : presets) std::cerr << " " << k;
      std::cerr << "\n";
      return 2;
    }
    scene.world.solver = it->second.settings;
    usedPreset = opt.presetName;
  }
  double seconds = opt.seconds < 0 ? scene.duration : opt.seconds;

  scene.world.threads = opt.threads;
  if (!opt.backend.empty()) parseBackend(opt.backend, &scene.world.backend);
  if (!opt.sleep.empty()) scene.world.sleep.enabled = opt.sleep == "on";
  const int validationBefore = gpuValidationErrorsInProcess();
  const int steps = int(std::lround(seconds / scene.world.timeStep));
  SceneRun run;
  st = runScene(scene, steps, &run);
  if (!st.ok()) {
    std::cerr << "physbench: " << opt.scenePath << ": " << st.message << "\n";
    return 2;
  }
  std::unique_ptr<World>& world = run.world;
  SingleResult result{usedPreset,         backendLabel(*world), world->def().threads,
                      world->bodyCount(), world->jointCount(),  steps,
                      run.metrics,        {},
                      std::nullopt,       std::nullopt};
  if (const BackendState& b = world->backendState(); b.gpuSteps > 0 && b.gpuDispatches > 0) {
    result.dispatchesPerStep = double(b.gpuDispatches) / double(b.gpuSteps);
    result.barriersPerStep = double(b.gpuBarriers) / double(b.gpuSteps);
  }
  if (opt.againstCpu) {
    if (scene.world.backend == Backend::Cpu)
      std::cerr << "physbench: --against-cpu on the CPU backend compares it with itself "
                   "(--backend gpu or auto puts the run on a device)\n";
    Scene onCpu = scene;
    onCpu.world.backend = Backend::Cpu;
    SceneRun cpu;
    st = runScene(onCpu, steps, &cpu);
    if (!st.ok()) {
      std::cerr << "physbench: " << opt.scenePath << " on the CPU: " << st.message << "\n";
      return 2;
    }
    result.againstCpu = compare(scene, run, cpu);
  }
  const int code = reportSingle(opt, scene, result);
  const BackendState b = world->backendState();
  // The world's teardown under validation: what it leaves behind is reported when its device
  // is destroyed.
  world.reset();
  const int validationErrors = gpuValidationErrorsInProcess() - validationBefore;
  if (opt.requireDevice && validationErrors > 0) {
    std::printf(
        "FAILED: --require-device, but the validation layer reported %d errors (%d of them "
        "at teardown)\n",
        validationErrors, validationErrors - b.validationErrors);
    return 1;
  }
  if (opt.requireDevice && b.active == Backend::Gpu && b.validationRequested && !b.validation) {
    std::printf(
        "FAILED: --require-device with PHYS_GPU_VALIDATION=1, but the validation layer is not "
        "loaded (package vulkan-validationlayers)\n");
    return 1;
  }
  if (opt.requireDevice && (b.active != Backend::Gpu || b.cpuSteps > 0)) {
    std::printf(
        "FAILED: --require-device, but %s\n",
        b.active != Backend::Gpu
            ? ("no device: " + b.note).c_str()
            : (std::to_string(b.cpuSteps) + " steps ran on the CPU: " + b.lastFallback).c_str());
    return 1;
  }
  return code;
}

int reportSingle(const SingleOptions& opt, const Scene& scene, const SingleResult& r) {
  const MetricsSummary& m = r.metrics;
  const int steps = r.steps;
  std::vector<CriterionResult> results = evaluate(m, scene.criteria);
  bool passed = true;
  for (const CriterionResult& c : results) passed &= c.passed;

  std::printf(
      "scene %s, preset %s, backend %s, %d threads, %d bodies, %d joints, %d steps (%.2f s)\n",
      scene.name.c_str(), r.preset.c_str(), r.backend.c_str(), r.threads, r.bodies, r.joints, steps,
      steps * double(scene.world.timeStep));
  std::printf("  ms/step median %.3f  p99 %.3f  settled median %s  (awake bodies at the end: %d)\n",
              m.msPerStepMedian, m.msPerStepP99, fmtNumber(m.msPerStepSettledMedian).c_str(),
              m.awakeBodiesFinal);
  std::printf("  at the end: %d contact pairs, %d manifolds in SIMD lanes, %d parts (0: not cut)\n",
              m.contactsFinal, m.manifoldsFinal, m.contactPartsFinal);
  for (const std::string& name : metricNames()) {
    if (name.rfind("ms_per_step", 0) == 0) continue;
    std::printf("  %-26s %s\n", name.c_str(), fmtNumber(m.value(name)).c_str());
  }
  for (const auto& [k, v] : m.extra) std::printf("  %-26s %.6g\n", k.c_str(), v);
  std::printf("  %-26s %016llx\n", "state_hash", static_cast<unsigned long long>(m.stateHash));
  std::printf("  stages (ms/step):");
  for (const auto& [k, v] : m.stageMs)
    if (v > 0.0005) std::printf(" %s %.3f", k.c_str(), v);
  std::printf("\n");
  if (!m.gpuProfile.empty()) {
    std::printf("  gpu profile:");
    for (const auto& [k, v] : m.gpuProfile) std::printf(" %s %.4g", k.c_str(), v);
    std::printf("\n");
  }
  if (m.readbackBytesPerStep > 0)
    std::printf("  device readback (bytes/step) %.0f\n", m.readbackBytesPerStep);
  if (m.uploadBytesPerStep > 0)
    std::printf("  device upload (bytes/step) %.0f\n", m.uploadBytesPerStep);
  {
    // The host's parts (device steps; guard: around the step, not in ms/step).
    std::printf("  host (ms/step):");
    for (const auto& [k, v] : m.hostMs) std::printf(" %s %.3f", k.c_str(), v);
    std::printf("\n");
  }
  if (r.dispatchesPerStep)
    std::printf("  device launches: %.1f dispatches/step, %.1f barriers/step\n",
                *r.dispatchesPerStep, *r.barriersPerStep);
  for (const CriterionResult& c : results) {
    std::printf("  [%s] %s = %s (%s)\n", c.passed ? "PASS" : "FAIL", c.name.c_str(),
                fmtNumber(c.value).c_str(), bounds(c).c_str());
  }
  if (r.againstCpu) {
    // The run is judged against the CPU backend's at the same length (CpuComparison).
    const CpuComparison& c = *r.againstCpu;
    std::printf("  against the CPU backend (the same preset, %d steps):\n", steps);
    passed = true;
    assert(c.cpuCriteria.size() == results.size());  // both are evaluate(.., scene.criteria)
    for (size_t i = 0; i < results.size(); ++i) {
      const CriterionResult& d = results[i];
      const CriterionResult& h = c.cpuCriteria[i];
      const char* verdict = d.passed ? "PASS" : h.passed ? "FAIL" : "BOTH FAIL";
      passed &= d.passed || !h.passed;
      std::printf("  [%s] %s: device %s, cpu %s (%s)\n", verdict, d.name.c_str(),
                  fmtNumber(d.value).c_str(), fmtNumber(h.value).c_str(), bounds(d).c_str());
    }
    const bool parityFailed = opt.parity >= 0 && !(c.maxPositionDifference <= opt.parity);
    passed &= !parityFailed;
    std::printf("  %s largest position difference %.3g m (%s), velocity %.3g m/s",
                parityFailed ? "[FAIL]" : opt.parity >= 0 ? "[PASS]" : "      ",
                c.maxPositionDifference, c.worstBody.empty() ? "-" : c.worstBody.c_str(),
                c.maxVelocityDifference);
    if (opt.parity >= 0) std::printf(" (<= %.3g m)", opt.parity);
    std::printf("\n  state hash: device %016llx, cpu %016llx%s\n",
                static_cast<unsigned long long>(m.stateHash),
                static_cast<unsigned long long>(c.cpu.stateHash),
                m.stateHash == c.cpu.stateHash ? " (the same bits)" : "");
    std::printf("%s\n", results.empty() && opt.parity < 0 ? "no criteria"
                         : passed                            ? "PASSED"
                                                             : "FAILED");
  } else {
    std::printf("%s\n", results.empty() ? "no criteria" : passed ? "PASSED" : "FAILED");
  }

  if (!opt.jsonOut.empty()) {
    nlohmann::json j;
    j["scene"] = scene.name;
    j["preset"] = r.preset;
    j["backend"] = r.backend;
    j["threads"] = r.threads;
    j["steps"] = steps;
    j["metrics"] = toJson(m);
    j["criteria"] = toJson(results);
    if (r.againstCpu) {
      const CpuComparison& c = *r.againstCpu;
      nlohmann::json a;
      a["metrics"] = toJson(c.cpu);
      a["criteria"] = toJson(c.cpuCriteria);
      a["max_position_difference"] = optional(c.maxPositionDifference);
      a["max_velocity_difference"] = optional(c.maxVelocityDifference);
      a["worst_body"] = c.worstBody;
      if (opt.parity >= 0) a["parity"] = opt.parity;
      j["against_cpu"] = a;
    }
    j["passed"] = passed;
    nlohmann::json stages;
    for (const auto& [k, v] : m.stageMs) stages[k] = v;
    j["stage_ms"] = stages;
    if (!m.gpuProfile.empty()) {
      nlohmann::json profile;
      for (const auto& [k, v] : m.gpuProfile) profile[k] = v;
      j["gpu_profile"] = profile;
    }
    j["readback_bytes_per_step"] = m.readbackBytesPerStep;
    j["upload_bytes_per_step"] = m.uploadBytesPerStep;
    nlohmann::json host;
    for (const auto& [k, v] : m.hostMs) host[k] = v;
    j["host_ms"] = host;
    if (r.dispatchesPerStep) {
      j["gpu"] = {{"dispatches_per_step", *r.dispatchesPerStep},
                  {"barriers_per_step", *r.barriersPerStep}};
    }
    std::ofstream f(opt.jsonOut);
    f << j.dump(2) << "\n";
    if (!f) {
      std::cerr << "physbench: cannot write " << opt.jsonOut << "\n";
      return 2;
    }
  }
  return passed ? 0 : 1;
}

}  // namespace phys::bench
