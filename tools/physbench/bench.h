// physbench's two modes: one scene with one preset (what the ctest scene tests call), and the
// suite (every preset on every scene) with its CSV, Markdown and docs/SOLVERS.md reports.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

namespace phys::bench {

struct SingleOptions {
  std::string scenePath, presetName, presetsPath, jsonOut;
  double seconds = -1;  ///< < 0: the scene's duration
  int threads = 0;      ///< the world's threads; 0: the machine's
};

/// Runs one scene and prints its metrics. Exit status: 0 when every criterion of the scene
/// passed, 1 when one failed, 2 on bad input.
int runSingle(SingleOptions opt);

struct SuiteOptions {
  std::string presetsPath;
  std::string scenesDir;
  std::vector<std::string> presets;  ///< empty: every preset of the presets file
  std::vector<std::string> scenes;   ///< empty: every scene of scenesDir but the scale ones
  double secondsScale = 1;
  double maxSeconds = 0;  ///< simulated seconds per run at most; 0: no limit
  bool quick = false;     ///< at most kQuickSeconds per run
  int jobs = 1;
  int threads = 0;  ///< each world's threads; 0: the machine's divided among the jobs
  std::string csvOut, markdownOut, docPath;
  bool failOnCriteria = false;
  bool failOnNan = false;  ///< exit 1 when a run went NaN
  std::string commandLine;  ///< as typed, printed in the reports
};

inline constexpr double kQuickSeconds = 3;

/// Runs the suite. Exit status: 2 when a run could not be executed (or a report not
/// written), 1 when --fail-on-criteria is set and a run failed its criteria or when
/// --fail-on-nan is set and a run went NaN, else 0.
int runSuite(const SuiteOptions& opt);

struct StressOptions {
  std::string presetsPath;
  std::vector<std::string> presets;  ///< empty: the default preset; "all": every preset
  int seeds = 100;                   ///< seeds seedStart, seedStart + 1, ...
  uint64_t seedStart = 1;
  std::optional<uint64_t> seed;  ///< replay one seed
  double seconds = 5;            ///< simulated seconds per run
  int jobs = 0;                  ///< runs in parallel (0: the machine's threads)
  std::string csvOut, dumpScene;
  bool failOnFailure = false;
};

/// A joint whose anchors drift further apart than this (m) fails a stress run.
inline constexpr double kStressJointError = 0.1;

/// Runs seeded random scenes with each preset and prints failure rates (see stress.cpp).
/// Exit status: 2 on bad input or a scene that could not be built, 1 with failOnFailure when
/// a run failed, else 0.
int runStress(const StressOptions& opt);

/// "%.6g", or "-" when empty.
std::string fmtNumber(const std::optional<double>& v);

}  // namespace phys::bench
