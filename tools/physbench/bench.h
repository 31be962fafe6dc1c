// physbench's modes: one scene with one preset (what the ctest scene tests call), the suite
// (every preset on every scene) with its CSV, Markdown and docs/SOLVERS.md reports, the
// stress runs; the suite and single runs can also run peer engines (docs/PEERS.md).
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "phys/scene/metrics.h"
#include "phys/scene/scene.h"
#include "phys/world/world.h"

namespace phys::bench {

struct SingleOptions {
  std::string scenePath, presetName, presetsPath, jsonOut;
  double seconds = -1;     ///< < 0: the scene's duration
  int threads = 0;         ///< the world's threads; 0: the machine's
  std::string backend;     ///< "cpu", "gpu", "auto"; empty: the scene's
  std::string sleep;       ///< "on", "off"; empty: the scene's (--sleep; a peer's too)
  bool requireDevice = false;  ///< fail unless every step ran on the GPU backend
  /// Also run the scene on the CPU backend for the same steps and judge the run by the
  /// comparison (--against-cpu): see CpuComparison.
  bool againstCpu = false;
  double parity = -1;  ///< m; >= 0: a body ending further than this from its CPU twin fails
  std::string peer;        ///< run the scene in this peer engine instead (--peer)
  int peerIterations = 0;  ///< the peer's solver iterations; 0: the engine's default
};

/// Runs one scene and prints its metrics. Exit status: 0 when every criterion of the scene
/// passed, 1 when one failed, 2 on bad input.
int runSingle(SingleOptions opt);

/// "cpu", or where a world asked to run on the GPU ran: its device and how many steps the
/// device and the CPU took (and why the CPU did).
std::string backendLabel(const World& world);

/// --against-cpu: the same scene, preset and steps on the CPU backend beside the run. A
/// criterion is judged by what the CPU makes of it at the same length: one the CPU run
/// passes must pass on the device too; one both fail is reported and not counted (a
/// CI-sized run is often too short for a whole-scene criterion, e.g. the bridge's cars).
struct CpuComparison {
  MetricsSummary cpu;
  std::vector<CriterionResult> cpuCriteria;  ///< the scene's criteria on the CPU run
  double maxPositionDifference = 0;          ///< m, largest |p_device - p_cpu| over bodies
  double maxVelocityDifference = 0;          ///< m/s, largest |v_device - v_cpu|
  std::string worstBody;                     ///< the body of maxPositionDifference
};

/// What runSingle prints (and writes as JSON) about one finished run.
struct SingleResult {
  std::string preset;   ///< "scene", a preset name or a peer's label
  std::string backend;  ///< "cpu" or the peer engine and its version
  int threads = 0, bodies = 0, joints = 0, steps = 0;
  MetricsSummary metrics;
  std::optional<CpuComparison> againstCpu;
  /// The GPU backend's launches: dispatches and barriers per device step (BackendState's
  /// sums over its gpuSteps); empty when no step ran on a device.
  std::optional<double> dispatchesPerStep, barriersPerStep;
};
/// Prints a run's metrics and criteria and writes opt.jsonOut; returns runSingle's status.
int reportSingle(const SingleOptions& opt, const Scene& scene, const SingleResult& r);

// Peer engines (peers.cpp; Bullet, ODE, MuJoCo and Box3D through tools/peers when the build has
// them).
/// The peers this build can run, in peers::peerNames() order (empty without PHYS_WITH_PEERS).
std::vector<std::string> compiledPeers();
/// Expands "all" and checks every name; returns an error message naming the unknown or not
/// compiled-in peers, empty when all can run.
std::string resolvePeers(std::vector<std::string>* names);
/// "bullet 3.24" for each of these compiled-in peers (the engines' own version reports).
std::vector<std::string> peerVersions(const std::vector<std::string>& peers);
/// A suite column / single-run label: "bullet" (the engine's default iterations) or
/// "bullet (10 it)".
std::string peerLabel(const std::string& peer, int iterations);
/// --scene with --peer: runs the scene in the peer and reports as runSingle does.
int runSinglePeer(const SingleOptions& opt);

struct SuiteOptions {
  std::string presetsPath;
  std::string scenesDir;
  std::vector<std::string> presets;  ///< empty: every preset of the presets file
  std::vector<std::string> scenes;   ///< empty: every scene of scenesDir but the scale ones
  double secondsScale = 1;
  double maxSeconds = 0;  ///< simulated seconds per run at most; 0: no limit
  /// Bodies x steps per run at most (a large scene runs fewer steps); 0: no limit.
  int64_t maxBodySteps = 0;
  bool quick = false;     ///< at most kQuickSeconds per run
  int jobs = 1;
  int threads = 0;  ///< each world's threads; 0: the machine's divided among the jobs
  std::string backend;  ///< "cpu", "gpu", "auto"; empty: each scene's
  std::string csvOut, markdownOut, docPath;
  bool failOnCriteria = false;
  bool failOnNan = false;   ///< exit 1 when a run went NaN
  std::string commandLine;  ///< as typed, printed in the reports
  /// Peer engines run as extra columns beside the presets (--peers), each at every budget of
  /// peerIterations (empty: the engine's default).
  std::vector<std::string> peers;
  std::vector<int> peerIterations;
  /// Budgets (--sweep): every preset also runs at each substeps x iterations pair, as columns
  /// "<preset> <substeps>x<iterations>"; empty: the presets' own budgets only.
  std::vector<int> substeps, iterations;
  /// A run still going after this many wall seconds is stopped and reported as CannotRun
  /// (0: no limit). For sweeps, where one slow engine would hold up the rest.
  double maxRunWallSeconds = 0;
  /// --sweep: the output directory (sweep.csv, sweep.md, plots/); empty: not a sweep.
  std::string sweepDir;
  /// How sweep.md's text links the plots directory (default "plots", i.e. beside it).
  std::string sweepPlotLink = "plots";
  std::string* sweepMarkdownOut = nullptr;  ///< when set, also gets sweep.md's text
  /// Pinned state hashes (--expect-hashes FILE): every run of our engine must end with the
  /// state hash the file gives for its scene and preset after the same steps, and every
  /// line of the file must be run; else exit 1. --write-hashes FILE writes such a file.
  std::string expectHashes, writeHashes;
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
  std::string backend;  ///< cpu, gpu or auto (empty: the scenes' own, the CPU)
  /// The kinds to run (stress.cpp's kKinds); empty: the five of the default rotation (seed
  /// mod 5), without "elastic". Given, seed s runs kinds[s mod kinds.size()].
  std::vector<std::string> kinds;
  bool failOnFailure = false;
  std::string* reportOut = nullptr;  ///< when set, also gets the printed report (--report)
};

/// A joint whose anchors drift further apart than this (m) fails a stress run.
inline constexpr double kStressJointError = 0.1;

/// Runs seeded random scenes with each preset and prints failure rates (see stress.cpp).
/// Exit status: 2 on bad input or a scene that could not be built, 1 with failOnFailure when
/// a run failed, else 0.
int runStress(const StressOptions& opt);

/// "%.6g", or "-" when empty.
std::string fmtNumber(const std::optional<double>& v);
/// A state hash as the reports write it: 16 hex digits.
std::string hashText(uint64_t h);

}  // namespace phys::bench
