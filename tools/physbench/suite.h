// The suite's results and reports (suite.cpp runs, suite_report.cpp writes).
#pragma once

#include <atomic>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "bench.h"
#include "phys/scene/metrics.h"

namespace phys::bench {

/// The number a suite table shows for a scene: its main error metric.
struct MainMetric {
  std::string name;  ///< a metric name MetricsSummary::value() knows
  std::string unit;  ///< for the table's row label
};

/// pyramid_*, many_pyramids, vertical_stack: top_drift; ball_and_chain, suspension_bridge:
/// joint_error_max; box_stack, overlap: penetration_settled_max; friction_ramp, restitution,
/// tunnelling, windmill, free_flight: their scene metric; any other: penetration_settled_max.
MainMetric mainMetricFor(const std::string& scene);

/// CannotRun: a peer engine could not build the scene (its own error); not an error of the
/// suite.
enum class RunStatus { Pass, Fail, NoCriteria, NaN, Error, CannotRun };
const char* toString(RunStatus s);

/// One (scene, preset) run.
struct RunResult {
  std::string scene, preset;    ///< preset: the column label
  std::string engine = "phys";  ///< "phys" or the peer engine
  std::string config;           ///< the preset's or the peer engine's name (without budget)
  int substeps = 0;             ///< phys: the run's substeps; peers: 0
  int iterations = 0;  ///< phys: iterations per substep; peers: solver iterations (0: default)
  RunStatus status = RunStatus::Error;
  std::string error;     ///< why the run could not be executed (status Error, CannotRun)
  double seconds = 0;    ///< simulated seconds planned
  int steps = 0;         ///< steps taken (fewer than planned when the world went NaN)
  int plannedSteps = 0;  ///< steps planned
  int bodies = 0, joints = 0;
  double nanTime = -1;  ///< s, when a non-finite body state was first seen; < 0: never
  MainMetric main;
  std::optional<double> mainValue;
  MetricsSummary metrics;
  std::vector<CriterionResult> failed;
  double wallSeconds = 0;
};

/// Everything the reports show.
struct SuiteReport {
  SuiteOptions options;
  std::vector<std::string> scenes;                ///< table rows, in order
  std::map<std::string, double> sceneSeconds;     ///< simulated seconds per run of each scene
  std::map<std::string, double> sceneDuration;    ///< the scene file's full duration
  std::map<std::string, double> sceneSettleTime;  ///< s, when "settled" metrics start
  std::vector<std::string> presets;               ///< table columns, in order (peers last)
  std::vector<std::string> peerVersions;          ///< "bullet 3.24", ... of the peer columns
  std::string defaultPreset;
  std::vector<RunResult> runs;  ///< rows x columns, row-major
  double wallSeconds = 0;
  int errors = 0;        ///< runs that could not be executed
  int worldThreads = 1;  ///< threads of each run's World
  int peerThreads = 1;   ///< PeerBudget::threads of the peer runs (--threads, else 1)
};

/// Runs `scene` in a peer engine for `steps` steps (peers.cpp) into *r (whose main metric is
/// set); a peer that cannot build the scene gives CannotRun with its error.
/// Stops at maxWallSeconds of wall time (0: never) with CannotRun. `threads`: the peer's
/// worker threads (PeerBudget::threads; only Box3D uses more than one).
void runPeerJob(const Scene& scene, const std::string& peer, int iterations, int threads,
                int steps, double maxWallSeconds, RunResult* r, std::atomic<int>* stepsDone);

/// The CannotRun message of a run stopped by SuiteOptions::maxRunWallSeconds.
std::string wallLimitMessage(double limitSeconds, int stepsDone, int stepsPlanned);

// Shared by the suite's and the sweep's reports (suite_report.cpp).
/// "%.3g"; for an optional, "-" when empty.
std::string fmt3(double v);
std::string fmt3(const std::optional<double>& v);
/// A CSV field, quoted when it holds a comma, a quote or a line break.
std::string csvField(const std::string& s);
/// Writes `text` to a temporary file beside `path`, then renames it over `path`. Returns an
/// error message, empty on success.
std::string writeAtomically(const std::string& path, const std::string& text);

/// The Markdown block: command, machine, date, the table and the failed criteria; without
/// `table`, only the command, machine and date lines (and runs that could not be executed).
std::string markdownReport(const SuiteReport& r, bool table = true);
/// Writes one CSV row per run. Returns an error message, empty on success.
std::string writeCsv(const SuiteReport& r, const std::string& path);
/// Writes the state hash of every run of our engine (scene,preset,steps,state_hash) for
/// --expect-hashes. Returns an error message, empty on success.
std::string writeHashes(const SuiteReport& r, const std::string& path);
/// Compares the runs with the pinned hashes of `path` and prints each difference: a hash or
/// step count that differs, a pinned run not run, a run not pinned. Returns how many; *err
/// gets why the file could not be read.
int checkHashes(const SuiteReport& r, const std::string& path, std::string* err);
/// Replaces the region between the `<!-- suite:begin -->` and `<!-- suite:end -->` lines of
/// `path` by `block`, appending the region under "## Every preset on every scene" when the
/// file has no markers. Returns an error message, empty on success.
std::string updateDoc(const std::string& path, const std::string& block);
/// The same for the region `<!-- NAME:begin -->` .. `<!-- NAME:end -->`, appended under
/// `heading` when missing.
std::string updateDocRegion(const std::string& path, const std::string& name,
                            const std::string& heading, const std::string& block);

}  // namespace phys::bench
