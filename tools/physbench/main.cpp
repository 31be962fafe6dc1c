// physbench: runs scenes headless with solver presets and reports their metrics.
//   physbench --scene FILE [--preset NAME] [--seconds S] [--json OUT]
//     one scene; exit status 0 when every criterion of the scene passed, 1 when one failed,
//     2 on bad input.
//   physbench --scene FILE --backend gpu [--require-device] --against-cpu [--parity M]
//     the same on the device and on the CPU backend for the same steps: exit status 1 when a
//     criterion the CPU run passes fails on the device (or a body ends > M m from its twin).
//   physbench --suite [--presets a,b] [--scenes x,y] [--seconds-scale F] [--max-seconds S]
//             [--max-body-steps N] [--quick] [--jobs N] [--csv OUT] [--markdown OUT] [--update-doc FILE]
//             [--fail-on-criteria] [--fail-on-nan] [--expect-hashes F] [--write-hashes F]
//     every preset on every scene (see suite.cpp); exit status 2 when a run could not be
//     executed, 1 with --fail-on-criteria when a run failed its criteria, else 0.
//   physbench --scene FILE --peer NAME [--peer-iterations N] [--seconds S] [--json OUT]
//   physbench --suite ... --peers bullet,ode,mujoco,box3d|all [--peer-iterations 10,100]
//     the same scenes in peer engines, measured by the same metrics code (docs/PEERS.md);
//     an unknown or not compiled-in peer exits 2.
//   physbench --sweep [--sweep-dir DIR] [--substeps 1,2,4,8] [--iterations 1,2,4]
//             [--max-run-seconds W] [any --suite option]
//     the suite over budgets (each preset at every substeps x iterations pair, each peer at
//     every --peer-iterations): DIR/sweep.csv (the points), DIR/runs.csv (every metric),
//     DIR/sweep.md (tables, Pareto fronts, reading) and DIR/plots/<scene>.{svg,png}
//     (gnuplot). Defaults: pyramid_20, pyramid_40, ball_and_chain, box_stack; presets
//     default, pgs, tjsoft; every peer at 5..100 iterations; 10 s per run, 120 s of wall time
//     at most. --quick: a CI-sized sweep (the defaults below).
//   physbench --report [--report-doc FILE] [--quick]
//     regenerates the <!-- report:begin --> .. <!-- report:end --> region of
//     docs/BENCHMARKS.md: the default sweep (with the peers; tables, fronts, plots in
//     docs/benchmarks/) and the stress run (1000 seeds, every preset). --quick: CI-sized.
//   physbench --stress [--presets a,b|all] [--seeds N] [--seed-start S] [--seed S]
//             [--stress-seconds T] [--jobs N] [--csv OUT] [--dump-scene FILE] [--kinds K,..]
//             [--fail-on-failure]
//     seeded random scenes and each preset's failure rate (see stress.cpp).
#include <CLI/CLI.hpp>
#include <chrono>
#include <ctime>
#include <filesystem>
#include <iostream>
#include <string>

#include "bench.h"
#include "phys/scene/presets.h"
#include "suite.h"

using namespace phys;

namespace {

std::string defaultScenesDir() {
#ifdef PHYS_SOURCE_DIR
  std::string d = std::string(PHYS_SOURCE_DIR) + "/configs/scenes";
  if (std::filesystem::is_directory(d)) return d;
#endif
  return "configs/scenes";
}

/// The command as typed, for the reports; arguments with spaces or quotes are quoted.
std::string commandLine(int argc, char** argv) {
  std::string out;
  for (int i = 0; i < argc; ++i) {
    std::string a = argv[i];
    if (i) out += ' ';
    if (a.empty() || a.find_first_of(" \t\"'$`\\|&;<>()*?") != std::string::npos) {
      std::string q = "'";
      for (char c : a) q += c == '\'' ? std::string("'\\''") : std::string(1, c);
      out += q + "'";
    } else {
      out += a;
    }
  }
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"physbench: run scenes headless with solver presets and report their metrics"};
  bench::SingleOptions single;
  bench::SuiteOptions suite;
  std::string presetsPath = defaultPresetsPath();
  bool suiteMode = false;

  // Single-scene mode (the ctest scene tests use it).
  CLI::Option* sceneOpt = app.add_option("--scene", single.scenePath, "scene file (JSON)");
  CLI::Option* presetOpt =
      app.add_option("--preset", single.presetName,
                     "solver preset (configs/presets.json); default: the scene's solver");
  app.add_option("--presets-file", presetsPath, "presets file");
  CLI::Option* secondsOpt = app.add_option("--seconds", single.seconds,
                                           "simulated seconds (default: the scene's duration)");
  CLI::Option* jsonOpt =
      app.add_option("--json", single.jsonOut, "write the result as JSON to this file");
  int threads = 0;
  app.add_option("--threads", threads,
                 "threads per world (default 0: the machine's; with --jobs, divided among them); "
                 "for a peer, Box3D's worker threads (default 1; the other peers use one)")
      ->check(CLI::Range(0, 64));
  std::string backend;
  app.add_option("--backend", backend,
                 "where worlds run: cpu, gpu or auto (default: the scene's). Without a usable "
                 "Vulkan device gpu and auto run on the CPU; PHYS_GPU_ALLOW_CPU=1 lets them use "
                 "a CPU implementation such as lavapipe")
      ->check(CLI::IsMember({"cpu", "gpu", "auto"}));
  app.add_option("--sleep", single.sleep,
                 "islands and sleeping on or off, overriding the scene's \"sleep\" (scenes "
                 "sleep unless they say otherwise; with --peer bullet, Bullet's deactivation)")
      ->check(CLI::IsMember({"on", "off"}));
  app.add_flag("--require-device", single.requireDevice,
               "with --backend gpu or auto: fail (exit 1) unless every step ran on the device "
               "(and, with PHYS_GPU_VALIDATION=1, the validation layer reported nothing)");
  CLI::Option* againstCpuOpt = app.add_flag(
      "--against-cpu", single.againstCpu,
      "with --backend gpu or auto: run the scene on the CPU backend too, for the same steps; "
      "the run passes when every criterion the CPU run passes at this length passes here (and "
      "with --parity, every body ends within that distance of its CPU twin)");
  app.add_option("--parity", single.parity,
                 "with --against-cpu: the largest position difference (m) a body may end with")
      ->check(CLI::NonNegativeNumber)
      ->needs(againstCpuOpt);
  bool scalarContacts = false;
  app.add_flag("--scalar-contacts", scalarContacts,
               "solve Gauss-Seidel contacts one manifold at a time instead of in SIMD lanes "
               "(bit-identical results; to compare the speeds)");
  int partLevels = 0;
  app.add_option("--part-levels", partLevels,
                 "Gauss-Seidel in nested parts: cut every step with 256 contacts or more this "
                 "many levels deep (1-4) instead of by its contact count (a different order, "
                 "so different results; for measurements)")
      ->check(CLI::Range(0, 4));

  // Peer engines (docs/PEERS.md): --peer in single-scene mode, --peers in the suite.
  CLI::Option* peerOpt = app.add_option(
      "--peer", single.peer,
      "run the scene in this peer engine (bullet, ode, mujoco, box3d) instead");
  std::vector<int> peerIterations;
  CLI::Option* peerItOpt =
      app.add_option("--peer-iterations", peerIterations,
                     "the peers' solver iterations, comma-separated in the suite (default: each "
                     "engine's own)")
          ->delimiter(',')
          ->check(CLI::Range(1, 100000));
  peerOpt->excludes(presetOpt);
  peerOpt->excludes(againstCpuOpt);
  againstCpuOpt->needs(sceneOpt);

  // Suite mode.
  CLI::Option* suiteFlag =
      app.add_flag("--suite", suiteMode, "run every preset on every scene and tabulate");
  for (CLI::Option* o : {sceneOpt, presetOpt, secondsOpt, jsonOpt, peerOpt}) o->excludes(suiteFlag);
  std::vector<CLI::Option*> suiteOnly = {
      app.add_option("--presets", suite.presets,
                     "presets to run, comma-separated (default: every preset of the file)")
          ->delimiter(','),
      app.add_option("--scenes", suite.scenes,
                     "scenes to run, comma-separated names in --scenes-dir or paths (default: "
                     "all but the scale scenes many_pyramids, pile_10k, pile_100k, pile_1m)")
          ->delimiter(','),
      app.add_option("--scenes-dir", suite.scenesDir, "directory of scene files")
          ->default_str(defaultScenesDir()),
      app.add_option("--seconds-scale", suite.secondsScale,
                     "run each scene for this fraction of its duration")
          ->check(CLI::PositiveNumber),
      app.add_option("--max-seconds", suite.maxSeconds, "simulated seconds per run at most")
          ->check(CLI::PositiveNumber),
      app.add_option("--max-body-steps", suite.maxBodySteps,
                     "bodies x steps per run at most (at least one step)")
          ->check(CLI::PositiveNumber),
      app.add_flag("--quick", suite.quick, "at most 3 simulated seconds per run"),
      app.add_option("--jobs", suite.jobs,
                     "runs in parallel threads (default 1: timings are measured)")
          ->check(CLI::PositiveNumber),
      app.add_option("--csv", suite.csvOut, "write one row per run to this CSV file"),
      app.add_option("--markdown", suite.markdownOut, "write the Markdown table to this file"),
      app.add_option("--update-doc", suite.docPath,
                     "rewrite the <!-- suite:begin --> .. <!-- suite:end --> region of this "
                     "file (docs/SOLVERS.md)"),
      app.add_flag("--fail-on-criteria", suite.failOnCriteria,
                   "exit 1 when a run fails its scene's criteria"),
      app.add_flag("--fail-on-nan", suite.failOnNan, "exit 1 when a run goes NaN"),
      app.add_option("--expect-hashes", suite.expectHashes,
                     "pinned state hashes (scene,preset,steps,state_hash): exit 1 when a run "
                     "ends with another hash, or a pinned run is not run, or a run not pinned"),
      app.add_option("--write-hashes", suite.writeHashes,
                     "write every run's state hash to this file (for --expect-hashes)"),
      app.add_option("--peers", suite.peers,
                     "peer engines to run beside the presets, comma-separated, or all")
          ->delimiter(','),
  };
  // Sweep mode: the suite over budgets.
  bool sweepMode = false;
  CLI::Option* sweepFlag = app.add_flag(
      "--sweep", sweepMode, "the suite over solver budgets: time against error, Pareto fronts");
  for (CLI::Option* o : {sceneOpt, presetOpt, secondsOpt, jsonOpt, peerOpt, suiteFlag})
    o->excludes(sweepFlag);
  std::vector<CLI::Option*> sweepOnly = {
      app.add_option("--sweep-dir", suite.sweepDir, "output directory (default: sweep)"),
      app.add_option("--substeps", suite.substeps, "substeps of each budget, comma-separated")
          ->delimiter(',')
          ->check(CLI::Range(1, 64)),
      app.add_option("--iterations", suite.iterations,
                     "iterations per substep of each budget, comma-separated")
          ->delimiter(',')
          ->check(CLI::Range(1, 1000)),
      app.add_option("--max-run-seconds", suite.maxRunWallSeconds,
                     "stop a run after this many wall seconds (reported as cannot run)")
          ->check(CLI::PositiveNumber),
  };
  // Report mode: the sweep and the stress run into docs/BENCHMARKS.md.
  bool reportMode = false;
  std::string reportDoc;
  CLI::Option* reportFlag = app.add_flag(
      "--report", reportMode,
      "rerun the sweep and the stress run and rewrite docs/BENCHMARKS.md's generated region");
  CLI::Option* reportDocOpt =
      app.add_option("--report-doc", reportDoc, "the file to update (default docs/BENCHMARKS.md)")
          ->needs(reportFlag);
  (void)reportDocOpt;
  for (CLI::Option* o : {sceneOpt, presetOpt, secondsOpt, jsonOpt, peerOpt, suiteFlag, sweepFlag})
    o->excludes(reportFlag);
  for (CLI::Option* o : sweepOnly) o->needs(sweepFlag);
  // Stress mode.
  bench::StressOptions stress;
  bool stressMode = false;
  CLI::Option* stressFlag = app.add_flag(
      "--stress", stressMode, "seeded random scenes; failure rates per preset (stress.cpp)");
  uint64_t replaySeed = 0;
  std::vector<CLI::Option*> stressOnly = {
      app.add_option("--seeds", stress.seeds, "how many seeds (default 100)")
          ->check(CLI::PositiveNumber),
      app.add_option("--seed-start", stress.seedStart, "first seed (default 1)"),
      app.add_option("--seed", replaySeed, "replay this one seed"),
      app.add_option("--stress-seconds", stress.seconds, "simulated seconds per run (default 5)")
          ->check(CLI::PositiveNumber),
      app.add_option("--dump-scene", stress.dumpScene,
                     "with --seed: write the seed's scene as a scene file"),
      app.add_flag("--fail-on-failure", stress.failOnFailure, "exit 1 when a run failed"),
      app.add_option("--kinds", stress.kinds,
                     "scene kinds, comma-separated: stack, pile, chain, joint_tree, overlap, "
                     "elastic (default: the first five, seed mod 5)")
          ->delimiter(','),
  };
  for (CLI::Option* o : stressOnly) o->needs(stressFlag);
  for (CLI::Option* o :
       {sceneOpt, presetOpt, secondsOpt, jsonOpt, suiteFlag, sweepFlag, peerOpt, peerItOpt})
    o->excludes(stressFlag);
  CLI11_PARSE(app, argc, argv);
  if (scalarContacts) phys::setVectorizedContacts(false);
  if (partLevels > 0) phys::setPartLevelsOverride(partLevels);
  if (reportMode) sweepMode = true;  // the report's first half is the sweep
  // The suite's options serve the sweep too; --presets, --jobs and --csv also the stress mode.
  for (CLI::Option* o : suiteOnly) {
    const std::string n = o->get_name();
    const bool shared = n == "--presets" || n == "--jobs" || n == "--csv";
    if (o->count() && !suiteMode && !sweepMode && !(shared && stressMode))
      return app.exit(CLI::ValidationError(
          n, shared ? "needs --suite, --sweep or --stress" : "needs --suite or --sweep"));
  }
  if (sweepMode) {
    // What a sweep runs unless told otherwise (docs/BENCHMARKS.md's sweep uses these); --quick
    // is the CI-sized form.
    const bool q = suite.quick;
    using Names = std::vector<std::string>;
    using Ints = std::vector<int>;
    if (!app.count("--scenes"))
      suite.scenes = q ? Names{"pyramid_20", "ball_and_chain"}
                       : Names{"pyramid_20", "pyramid_40", "ball_and_chain", "box_stack"};
    if (!app.count("--presets"))
      suite.presets = q ? Names{"default"} : Names{"default", "pgs", "tjsoft"};
    if (!app.count("--substeps")) suite.substeps = q ? Ints{1, 4} : Ints{1, 2, 4, 8};
    if (!app.count("--iterations")) suite.iterations = q ? Ints{1, 2} : Ints{1, 2, 4};
    if (!app.count("--peers") && !bench::compiledPeers().empty()) suite.peers = {"all"};
    if (!app.count("--peer-iterations")) peerIterations = q ? Ints{10} : Ints{5, 10, 20, 50, 100};
    if (!app.count("--max-seconds")) suite.maxSeconds = q ? 1 : 10;
    if (!app.count("--max-run-seconds")) suite.maxRunWallSeconds = q ? 20 : 120;
    if (suite.sweepDir.empty()) suite.sweepDir = "sweep";
    suiteMode = true;
  }

  if (stressMode) {
    stress.presetsPath = presetsPath;
    stress.presets = suite.presets;
    stress.jobs = app.count("--jobs") ? suite.jobs : 0;
    stress.csvOut = suite.csvOut;
    stress.backend = backend;
    if (app.count("--seed")) stress.seed = replaySeed;
    return bench::runStress(stress);
  }

  if (!suiteMode) {
    // --scene is required in single-scene mode, as before --suite existed.
    if (single.scenePath.empty()) return app.exit(CLI::RequiredError("--scene"));
    if (app.count("--peer-iterations")) {
      if (single.peer.empty())
        return app.exit(CLI::ValidationError("--peer-iterations", "needs --peer or --peers"));
      if (peerIterations.size() != 1)
        return app.exit(CLI::ValidationError("--peer-iterations", "takes one number with --peer"));
      single.peerIterations = peerIterations[0];
    }
    single.presetsPath = presetsPath;
    single.threads = threads;
    single.backend = backend;
    return bench::runSingle(single);
  }
  if (app.count("--peer-iterations") && suite.peers.empty() && !sweepMode)
    return app.exit(CLI::ValidationError("--peer-iterations", "needs --peer or --peers"));
  suite.peerIterations = peerIterations;
  suite.presetsPath = presetsPath;
  suite.threads = threads;
  suite.backend = backend;
  if (suite.scenesDir.empty()) suite.scenesDir = defaultScenesDir();
  suite.commandLine = commandLine(argc, argv);
  if (!reportMode) return bench::runSuite(suite);

  // --report: the sweep's outputs beside the document (its plots are linked from it), then
  // the stress run, then the generated region.
  const auto started = std::chrono::steady_clock::now();
  if (reportDoc.empty()) reportDoc = std::string(PHYS_SOURCE_DIR) + "/docs/BENCHMARKS.md";
  const std::filesystem::path docDir = std::filesystem::path(reportDoc).parent_path();
  suite.sweepDir = (docDir / "benchmarks").string();
  suite.sweepPlotLink = "benchmarks/plots";
  std::string sweepText, stressText;
  suite.sweepMarkdownOut = &sweepText;
  const int sweepStatus = bench::runSuite(suite);
  if (sweepStatus == 2) return 2;
  stress.presetsPath = presetsPath;
  stress.presets = {"all"};
  stress.seeds = suite.quick ? 50 : 1000;
  stress.csvOut = (docDir / "benchmarks" / "stress.csv").string();
  stress.reportOut = &stressText;
  if (bench::runStress(stress) == 2) return 2;
  const double minutes =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - started).count() / 60;
  char took[64];
  std::snprintf(took, sizeof took, "%.1f", minutes);
  std::string block =
      "Generated by `" + suite.commandLine + "` in " + took +
      " minutes; do not edit by hand, rerun the command (about 20 minutes on the 2-core "
      "machine). Raw data beside this file: `benchmarks/sweep.csv` (the points), "
      "`benchmarks/runs.csv` (every metric of every run), `benchmarks/stress.csv`.\n\n"
      "### Time against error\n\n" +
      sweepText +
      "\n### Stress: failure rates over random scenes\n\n"
      "Seeded random stacks, piles, chains (mass ratios up to 1000:1), joint trees and initial "
      "overlaps, " +
      std::to_string(stress.seeds) +
      " seeds per preset (`physbench --stress`, stress.cpp). A run fails on a NaN, a speed "
      "beyond the scene's bound (explosion) or a joint torn more than 10 cm apart.\n\n```\n" +
      stressText + "```\n";
  const std::string err = bench::updateDocRegion(reportDoc, "report",
                                                 "## Generated report (physbench --report)", block);
  if (!err.empty()) {
    std::cerr << "physbench: " << err << "\n";
    return 2;
  }
  std::cerr << "physbench: " << reportDoc << " updated in " << took << " minutes\n";
  return 0;
}
