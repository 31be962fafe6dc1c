// The suite's reports: the Markdown block (also docs/SOLVERS.md's generated region) and the
// CSV with every metric of every run.
#include <cmath>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>

#include "suite.h"

namespace phys::bench {

namespace {

const char* kHeading = "## Every preset on every scene";

/// "AMD EPYC, 2 cores" from /proc/cpuinfo.
std::string machineText() {
  std::ifstream f("/proc/cpuinfo");
  std::string line, model;
  int cores = 0;
  while (std::getline(f, line)) {
    auto colon = line.find(':');
    if (colon == std::string::npos) continue;
    std::string key = line.substr(0, line.find_last_not_of(" \t", colon - 1) + 1);
    std::string value = line.substr(std::min(line.size(), colon + 2));
    if (key == "processor") cores++;
    if (key == "model name" && model.empty()) model = value;
  }
  if (model.empty()) model = "unknown CPU";
  return model + ", " + std::to_string(cores) + (cores == 1 ? " core" : " cores");
}

std::string compilerText() {
#if defined(__clang__)
  std::string c = "clang " __clang_version__;
#elif defined(__GNUC__)
  std::string c = "g++ " __VERSION__;
#else
  std::string c = "unknown compiler";
#endif
#ifdef PHYS_BUILD_TYPE
  c += std::string(", ") + (PHYS_BUILD_TYPE[0] ? PHYS_BUILD_TYPE : "no CMAKE_BUILD_TYPE");
#endif
#ifdef NDEBUG
  c += " (NDEBUG)";
#else
  c += " (asserts on)";
#endif
  return c;
}

std::string dateText() {
  std::time_t t = std::time(nullptr);
  std::tm tm{};
  gmtime_r(&t, &tm);
  char b[32];
  std::strftime(b, sizeof b, "%Y-%m-%d", &tm);
  return b;
}

std::string durationText(double s) {
  long t = std::lround(s);
  char b[32];
  std::snprintf(b, sizeof b, "%ldm %02lds", t / 60, t % 60);
  return b;
}

/// A path as the reader would type it from the working directory.
std::string shortPath(const std::string& p) {
  std::error_code ec;
  std::filesystem::path r = std::filesystem::proximate(p, ec);
  return ec ? p : r.string();
}

std::string cell(const RunResult& r) {
  std::string ms = fmt3(r.metrics.msPerStepMedian) + " ms";
  switch (r.status) {
    case RunStatus::Error:
      return "ERROR";
    case RunStatus::CannotRun:
      return "cannot run";
    case RunStatus::NaN:
      return "NaN at " + fmt3(r.nanTime) + " s / " + ms;
    default:
      return std::string(toString(r.status)) + " " + fmt3(r.mainValue) + " / " + ms;
  }
}

std::string limitText(const CriterionResult& c) {
  std::string out;
  if (c.min) out += ">= " + fmtNumber(c.min);
  if (c.min && c.max) out += ", ";
  if (c.max) out += "<= " + fmtNumber(c.max);
  return out;
}

std::string csvNumber(const std::optional<double>& v) {
  if (!v) return "";
  if (std::isnan(*v)) return "nan";
  char b[32];
  std::snprintf(b, sizeof b, "%.9g", *v);
  return b;
}

}  // namespace

std::string fmt3(double v) {
  char b[32];
  std::snprintf(b, sizeof b, "%.3g", v);
  return b;
}

/// "%.3g", or "-" when empty.
std::string fmt3(const std::optional<double>& v) {
  return v ? fmt3(*v) : std::string("-");
}

std::string csvField(const std::string& s) {
  if (s.find_first_of(",\"\n\r") == std::string::npos) return s;
  std::string q = "\"";
  for (char c : s) q += c == '"' ? std::string("\"\"") : std::string(1, c);
  return q + "\"";
}

std::string writeAtomically(const std::string& path, const std::string& text) {
  const std::string tmp = path + ".tmp";
  {
    std::ofstream f(tmp, std::ios::binary);
    f << text;
    f.close();
    if (!f) return "cannot write " + tmp;
  }
  std::error_code ec;
  std::filesystem::rename(tmp, path, ec);
  if (ec) return "cannot replace " + path + ": " + ec.message();
  return {};
}

MainMetric mainMetricFor(const std::string& scene) {
  if (scene.starts_with("pyramid_") || scene == "many_pyramids" || scene == "vertical_stack")
    return {"top_drift", "m"};
  if (scene == "ball_and_chain" || scene == "suspension_bridge") return {"joint_error_max", "m"};
  if (scene == "friction_ramp") return {"friction_ramp.static_displacement_max", "m"};
  if (scene == "restitution") return {"restitution.rebound_height", "m, target 0.25"};
  if (scene == "tunnelling") return {"tunnelling.passed_through", "spheres"};
  if (scene == "windmill") return {"windmill.speed_error", "relative"};
  if (scene == "free_flight") return {"free_flight.angular_momentum_drift", "relative"};
  if (scene == "newtons_cradle")
    return {"cradle.last_speed_ratio", "of the striker's speed, target 1"};
  // box_stack, overlap, default and any new scene: how far contacts stay apart once settled.
  return {"penetration_settled_max", "m"};
}

const char* toString(RunStatus s) {
  switch (s) {
    case RunStatus::Pass:
      return "PASS";
    case RunStatus::Fail:
      return "FAIL";
    case RunStatus::NoCriteria:
      return "n/a";
    case RunStatus::NaN:
      return "NaN";
    case RunStatus::Error:
      return "ERROR";
    case RunStatus::CannotRun:
      return "cannot run";
  }
  return "?";
}

std::string markdownReport(const SuiteReport& r, bool table) {
  const SuiteOptions& o = r.options;
  std::ostringstream md;
  if (table)
    md << "Generated by `physbench --suite`; do not edit by hand, rerun the command instead.\n\n";
  md << "- Command (from the repository root): `" << o.commandLine << "`\n";
  md << "- Machine: " << machineText() << " (/proc/cpuinfo); " << compilerText() << "\n";
  md << "- Date: " << dateText() << "; " << r.runs.size() << " runs, "
     << (o.jobs == 1 ? std::string("one at a time (--jobs 1)")
                     : std::to_string(o.jobs) + " in parallel threads (--jobs " +
                           std::to_string(o.jobs) + "; timings share the cores)")
     << ", " << r.worldThreads << (r.worldThreads == 1 ? " thread" : " threads") << " per World, "
     << durationText(r.wallSeconds) << " in all\n";
  md << "- Presets: `" << shortPath(o.presetsPath) << "` as it was at the run (default `"
     << r.defaultPreset << "`); one World per run";
  std::vector<std::string> limits;
  if (o.secondsScale != 1) limits.push_back("--seconds-scale " + fmt3(o.secondsScale));
  if (o.maxSeconds > 0) limits.push_back("--max-seconds " + fmt3(o.maxSeconds));
  if (o.maxBodySteps > 0)
    limits.push_back("--max-body-steps " + std::to_string(o.maxBodySteps));
  if (o.quick) limits.push_back("--quick: at most " + fmt3(kQuickSeconds) + " s");
  if (limits.empty()) {
    md << " for the scene's full duration\n";
  } else {
    md << ", shortened by";
    for (size_t i = 0; i < limits.size(); ++i) md << (i ? "," : "") << " " << limits[i];
    md << " (criteria are still the full run's)\n";
  }
  if (!r.peerVersions.empty()) {
    md << "- Peers: ";
    for (size_t i = 0; i < r.peerVersions.size(); ++i) md << (i ? ", " : "") << r.peerVersions[i];
    md << "; their columns read \"engine (N it)\" for N solver iterations (no N: the engine's "
          "default), one thread (Box3D: "
       << r.peerThreads << (r.peerThreads == 1 ? " worker thread" : " worker threads")
       << ", --threads); the same scene files and the same metrics code (docs/PEERS.md)\n";
  }
  if (!table) {
    // The sweep's tables (sweep_report.cpp) carry the runs, their failures and peer errors.
    md << "\n";
    for (const RunResult& run : r.runs)
      if (run.status == RunStatus::Error)
        md << "- Could not be executed: " << run.scene << " / " << run.preset << ": " << run.error
           << "\n";
    return md.str();
  }
  md << "\nCell: PASS or FAIL over the scene's criteria, then the scene's main error metric "
        "(named in the row), then the median wall time per step. \"NaN at t s\": a body "
        "state became non-finite at t and the run stopped there. ERROR: the run could not "
        "be executed (listed below).";
  if (!r.peerVersions.empty())
    md << " \"cannot run\": the peer engine could not build the scene (its error below).";
  if (!o.csvOut.empty()) md << " Every metric of every run: `" << o.csvOut << "`.";
  md << "\n\n";

  md << "| scene (simulated s): main metric |";
  for (const std::string& p : r.presets)
    md << " " << p << (p == r.defaultPreset ? " (default)" : "") << " |";
  md << "\n|---|";
  for (size_t k = 0; k < r.presets.size(); ++k) md << "---|";
  md << "\n";
  for (size_t i = 0; i < r.scenes.size(); ++i) {
    const std::string& s = r.scenes[i];
    const MainMetric mm = mainMetricFor(s);
    std::string secs = fmt3(r.sceneSeconds.at(s));
    auto full = r.sceneDuration.find(s);
    // steps x the float time step misses the duration by float rounding only
    if (full != r.sceneDuration.end() && std::fabs(full->second - r.sceneSeconds.at(s)) > 1e-3)
      secs += " of " + fmt3(full->second);
    if (full == r.sceneDuration.end()) secs = "-";
    md << "| " << s << " (" << secs << " s): " << mm.name << ", " << mm.unit << " |";
    for (size_t k = 0; k < r.presets.size(); ++k)
      md << " " << cell(r.runs[i * r.presets.size() + k]) << " |";
    md << "\n";
  }

  std::ostringstream failed, errors, cannot;
  for (const RunResult& run : r.runs) {
    if (run.status == RunStatus::Error) {
      errors << "- " << run.scene << " / " << run.preset << ": " << run.error << "\n";
      continue;
    }
    if (run.status == RunStatus::CannotRun) {
      cannot << "- " << run.scene << " / " << run.preset << ": cannot run: " << run.error << "\n";
      continue;
    }
    if (run.failed.empty() && run.status != RunStatus::NaN) continue;
    failed << "- " << run.scene << " / " << run.preset << ":";
    if (run.status == RunStatus::NaN) failed << " NaN at " << fmt3(run.nanTime) << " s;";
    for (size_t k = 0; k < run.failed.size(); ++k) {
      const CriterionResult& c = run.failed[k];
      failed << (k ? ";" : "") << " " << c.name << " " << fmtNumber(c.value) << " (" << limitText(c)
             << ")";
    }
    failed << "\n";
  }
  std::ostringstream notes;
  for (const std::string& s : r.scenes) {
    auto settle = r.sceneSettleTime.find(s);
    if (settle != r.sceneSettleTime.end() && r.sceneSeconds.at(s) <= settle->second)
      notes << "- " << s << ": the runs end before the scene's settle time ("
            << fmt3(settle->second)
            << " s), so its settled metrics (shown as -) and their criteria mean nothing.\n";
  }
  if (!notes.str().empty()) md << "\nNotes:\n\n" << notes.str();
  if (!failed.str().empty()) md << "\nFailed criteria (value, limit):\n\n" << failed.str();
  if (!errors.str().empty()) md << "\nRuns that could not be executed:\n\n" << errors.str();
  if (!cannot.str().empty())
    md << "\nPeers that cannot run a scene (the engine's own error):\n\n" << cannot.str();
  return md.str();
}

std::string writeCsv(const SuiteReport& r, const std::string& path) {
  std::set<std::string> extras, stages;
  for (const RunResult& run : r.runs) {
    for (const auto& [k, v] : run.metrics.extra) extras.insert(k);
    for (const auto& [k, v] : run.metrics.stageMs) stages.insert(k);
  }
  std::ostringstream out;
  out << "scene,preset,status,error,simulated_s,steps,planned_steps,bodies,joints,jobs,wall_s,"
         "nan_time_s,main_metric,main_value,failed_criteria";
  for (const std::string& m : metricNames()) out << "," << m;
  out << ",state_hash";
  for (const std::string& m : extras) out << "," << csvField(m);
  for (const std::string& m : stages) out << ",stage_" << m << "_ms";
  out << "\n";
  for (const RunResult& run : r.runs) {
    const bool ran = run.status != RunStatus::Error && run.status != RunStatus::CannotRun;
    std::string failed;
    for (const CriterionResult& c : run.failed) failed += (failed.empty() ? "" : ";") + c.name;
    out << csvField(run.scene) << "," << csvField(run.preset) << "," << toString(run.status) << ","
        << csvField(run.error) << "," << csvNumber(run.seconds) << "," << run.steps << ","
        << run.plannedSteps << "," << run.bodies << "," << run.joints << "," << r.options.jobs
        << "," << csvNumber(run.wallSeconds) << ","
        << (run.nanTime >= 0 ? csvNumber(run.nanTime) : "") << "," << run.main.name << ","
        << (ran ? csvNumber(run.mainValue) : "") << "," << csvField(failed);
    for (const std::string& m : metricNames())
      out << "," << (ran ? csvNumber(run.metrics.value(m)) : "");
    out << "," << (ran ? hashText(run.metrics.stateHash) : "");
    for (const std::string& m : extras) {
      auto it = run.metrics.extra.find(m);
      out << "," << (it != run.metrics.extra.end() ? csvNumber(it->second) : "");
    }
    for (const std::string& m : stages) {
      auto it = run.metrics.stageMs.find(m);
      out << "," << (it != run.metrics.stageMs.end() ? csvNumber(it->second) : "");
    }
    out << "\n";
  }
  return writeAtomically(path, out.str());
}

std::string updateDoc(const std::string& path, const std::string& block) {
  return updateDocRegion(path, "suite", kHeading, block);
}

std::string updateDocRegion(const std::string& path, const std::string& name,
                            const std::string& heading, const std::string& block) {
  const std::string kBegin = "<!-- " + name + ":begin -->", kEnd = "<!-- " + name + ":end -->";
  std::ifstream f(path, std::ios::binary);
  if (!f) return "cannot read " + path;
  std::vector<std::string> lines;
  for (std::string line; std::getline(f, line);) lines.push_back(line);
  auto trimmed = [](std::string s) {
    while (!s.empty() && (s.back() == ' ' || s.back() == '\t' || s.back() == '\r')) s.pop_back();
    return s;
  };
  int begin = -1, end = -1;
  for (size_t i = 0; i < lines.size(); ++i) {
    std::string t = trimmed(lines[i]);
    if (t == kBegin) begin = begin < 0 ? int(i) : -2;
    if (t == kEnd) end = end < 0 ? int(i) : -2;
  }
  std::string out;
  if (begin == -1 && end == -1) {
    // No region yet: append it under its heading.
    for (const std::string& l : lines) out += l + "\n";
    while (out.size() >= 2 && out.ends_with("\n\n")) out.pop_back();
    out += "\n" + heading + "\n\n" + kBegin + "\n\n" + block + "\n" + kEnd + "\n";
  } else if (begin >= 0 && end > begin) {
    for (int i = 0; i <= begin; ++i) out += lines[size_t(i)] + "\n";
    out += "\n" + block + "\n";
    for (size_t i = size_t(end); i < lines.size(); ++i) out += lines[i] + "\n";
  } else {
    return path + ": expected one line " + kBegin + " followed by one line " + kEnd;
  }
  return writeAtomically(path, out);
}

}  // namespace phys::bench
