// physbench --sweep: the suite run over solver budgets (each preset at several substeps x
// iterations, each peer engine at several iteration counts), read as time-against-error points
// per scene: one CSV row per run, each configuration's Pareto front, plots (gnuplot) and a
// plain reading of where a peer is ahead (sweep_report.cpp).
#pragma once

#include <optional>
#include <string>
#include <vector>

#include "suite.h"

namespace phys::bench {

/// One run of the sweep as a point: time per step against the scene's main error metric.
struct SweepPoint {
  std::string scene;
  std::string engine;  ///< "phys", or the peer engine ("bullet", "ode", "mujoco")
  std::string config;  ///< the preset's name, or the peer engine's name: one series per config
  std::string label;   ///< the suite column, e.g. "soft_step 6x2" or "bullet (10 it)"
  int substeps = 0;    ///< phys: the run's substeps; peers: 0
  int iterations = 0;  ///< phys: iterations per substep; peers: solver iterations (0: default)
  double msMedian = 0, msP99 = 0;
  std::string metric;           ///< the main metric's name (mainMetricFor)
  std::optional<double> error;  ///< its value; empty when the run has none (NaN, cannot run)
  RunStatus status = RunStatus::Error;
  std::string note;     ///< the run's error or failed criteria, for the tables
  bool pareto = false;  ///< on its config's front in this scene
};

/// The report's runs as points, in the report's order, with the Pareto flags set: within one
/// (scene, engine, config), a point with an error value and a positive time is on the front
/// when no other such point has msMedian <= and error <= with one of them strictly smaller
/// (equal points are both on it). Runs that went NaN, errored or could not run are points
/// without an error, never on a front.
std::vector<SweepPoint> sweepPoints(const SuiteReport& report);

/// One row per point with every field above; returns an error message, empty on success.
std::string writeSweepCsv(const std::vector<SweepPoint>& points, const std::string& path);

/// Writes (creating dir), for each scene with a point that has a value, `<dir>/<scene>.dat`
/// and `<dir>/<scene>.gp` and, when gnuplot is on the PATH, renders `<dir>/<scene>.png` and
/// `<dir>/<scene>.svg`: ms/step (x, log) against the error (y, log; errors <= 0 drawn at a
/// floor the title names), one colour and point type per config (presets solid, peers
/// dashed), each config's front joined by a line and labelled with its budgets. The files
/// hold no date, so reruns on the same points give the same bytes. *files gets the paths
/// written. Returns an error message, empty on success; gnuplot not on the PATH is no error
/// (the scripts are written, not rendered: the caller says so, from gnuplotVersion()).
std::string writeSweepPlots(const std::vector<SweepPoint>& points, const std::string& dir,
                            std::vector<std::string>* files);
/// gnuplot's version line, or empty when it is not on the PATH.
std::string gnuplotVersion();

/// Markdown: per scene (### heading) a link to its plot (`plotDir/<scene>.svg`, plotDir
/// relative to the Markdown file), a table (config, budget, ms/step, error, status, front;
/// by config, then ms) and the reading: the front of all phys runs together; for each peer
/// point that no phys point dominates, a sentence with its value and the best phys value at
/// that cost or less (or the fastest phys run when none is as fast); for each peer whose
/// points are all dominated, one phys point that dominates its most accurate one.
std::string sweepMarkdown(const SuiteReport& report, const std::vector<SweepPoint>& points,
                          const std::string& plotDir);

}  // namespace phys::bench
