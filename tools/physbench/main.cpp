// physbench: runs a scene headless with a solver preset and prints its metrics.
//   physbench --scene FILE [--preset NAME] [--seconds S] [--json OUT]
// Exit status: 0 when every criterion of the scene passed, 1 when one failed, 2 on bad input.
#include <CLI/CLI.hpp>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <nlohmann/json.hpp>

#include "phys/metrics.h"
#include "phys/presets.h"
#include "phys/scene.h"
#include "phys/world.h"

using namespace phys;

namespace {

nlohmann::json optional(const std::optional<double>& v) {
  return v && std::isfinite(*v) ? nlohmann::json(*v) : nlohmann::json(nullptr);
}

nlohmann::json toJson(const MetricsSummary& m) {
  nlohmann::json j;
  for (const std::string& name : metricNames()) j[name] = optional(m.value(name));
  char hash[17];
  std::snprintf(hash, sizeof hash, "%016llx", static_cast<unsigned long long>(m.stateHash));
  j["state_hash"] = hash;
  for (const auto& [k, v] : m.extra) j[k] = std::isfinite(v) ? nlohmann::json(v) : nullptr;
  return j;
}

std::string fmt(const std::optional<double>& v) {
  if (!v) return "-";
  char b[32];
  std::snprintf(b, sizeof b, "%.6g", *v);
  return b;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"physbench: run a scene headless and report its metrics"};
  std::string scenePath, presetName, jsonOut, presetsPath = defaultPresetsPath();
  double seconds = -1;
  app.add_option("--scene", scenePath, "scene file (JSON)")->required();
  app.add_option("--preset", presetName,
                 "solver preset (configs/presets.json); default: the scene's solver");
  app.add_option("--presets-file", presetsPath, "presets file");
  app.add_option("--seconds", seconds, "simulated seconds (default: the scene's duration)");
  app.add_option("--json", jsonOut, "write the result as JSON to this file");
  CLI11_PARSE(app, argc, argv);

  Scene scene;
  Status st = loadSceneFile(scenePath, &scene);
  if (!st.ok()) {
    std::cerr << "physbench: " << st.message << "\n";
    return 2;
  }
  std::string usedPreset = "scene";
  if (!presetName.empty()) {
    std::map<std::string, Preset> presets;
    std::string def;
    st = loadPresetsFile(presetsPath, &presets, &def);
    if (!st.ok()) {
      std::cerr << "physbench: " << st.message << "\n";
      return 2;
    }
    if (presetName == "default") presetName = def;
    auto it = presets.find(presetName);
    if (it == presets.end()) {
      std::cerr << "physbench: unknown preset '" << presetName << "'; known:";
      for (const auto& [k, v] : presets) std::cerr << " " << k;
      std::cerr << "\n";
      return 2;
    }
    scene.world.solver = it->second.settings;
    usedPreset = presetName;
  }
  if (seconds < 0) seconds = scene.duration;

  World world(scene.world);
  std::vector<BodyId> ids;
  st = instantiateScene(scene, &world, &ids);
  if (!st.ok()) {
    std::cerr << "physbench: " << scenePath << ": " << st.message << "\n";
    return 2;
  }
  MetricsRecorder rec(scene, world, ids);
  const int steps = int(std::lround(seconds / scene.world.timeStep));
  for (int i = 0; i < steps; ++i) {
    world.step();
    rec.afterStep(world);
  }
  MetricsSummary m = rec.summary();
  m.stateHash = world.stateHash();
  std::vector<CriterionResult> results = evaluate(m, scene.criteria);
  bool passed = true;
  for (const CriterionResult& r : results) passed &= r.passed;

  std::printf("scene %s, preset %s, backend cpu, %d bodies, %d joints, %d steps (%.2f s)\n",
              scene.name.c_str(), usedPreset.c_str(), world.bodyCount(), world.jointCount(), steps,
              steps * double(scene.world.timeStep));
  std::printf("  ms/step median %.3f  p99 %.3f\n", m.msPerStepMedian, m.msPerStepP99);
  for (const std::string& name : metricNames()) {
    if (name.rfind("ms_per_step", 0) == 0) continue;
    std::printf("  %-26s %s\n", name.c_str(), fmt(m.value(name)).c_str());
  }
  for (const auto& [k, v] : m.extra) std::printf("  %-26s %.6g\n", k.c_str(), v);
  std::printf("  %-26s %016llx\n", "state_hash", static_cast<unsigned long long>(m.stateHash));
  std::printf("  stages (ms/step):");
  for (const auto& [k, v] : m.stageMs)
    if (v > 0.0005) std::printf(" %s %.3f", k.c_str(), v);
  std::printf("\n");
  for (const CriterionResult& r : results) {
    std::printf("  [%s] %s = %s (%s%s%s)\n", r.passed ? "PASS" : "FAIL", r.name.c_str(),
                fmt(r.value).c_str(), r.min ? (">= " + fmt(r.min)).c_str() : "",
                r.min && r.max ? ", " : "", r.max ? ("<= " + fmt(r.max)).c_str() : "");
  }
  std::printf("%s\n", results.empty() ? "no criteria" : passed ? "PASSED" : "FAILED");

  if (!jsonOut.empty()) {
    nlohmann::json j;
    j["scene"] = scene.name;
    j["preset"] = usedPreset;
    j["backend"] = "cpu";
    j["steps"] = steps;
    j["metrics"] = toJson(m);
    j["criteria"] = nlohmann::json::array();
    for (const CriterionResult& r : results) {
      nlohmann::json c{{"name", r.name}, {"value", optional(r.value)}, {"passed", r.passed}};
      c["limit"] = r.max ? nlohmann::json(*r.max) : optional(r.min);
      c["kind"] = r.max ? "max" : "min";
      if (r.min && r.max) c["min"] = *r.min;
      j["criteria"].push_back(c);
    }
    j["passed"] = passed;
    nlohmann::json stages;
    for (const auto& [k, v] : m.stageMs) stages[k] = v;
    j["stage_ms"] = stages;
    std::ofstream f(jsonOut);
    f << j.dump(2) << "\n";
    if (!f) {
      std::cerr << "physbench: cannot write " << jsonOut << "\n";
      return 2;
    }
  }
  return passed ? 0 : 1;
}
