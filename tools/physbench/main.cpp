// physbench: runs scenes headless with solver presets and reports their metrics.
//   physbench --scene FILE [--preset NAME] [--seconds S] [--json OUT]
//     one scene; exit status 0 when every criterion of the scene passed, 1 when one failed,
//     2 on bad input.
//   physbench --suite [--presets a,b] [--scenes x,y] [--seconds-scale F] [--max-seconds S]
//             [--quick] [--jobs N] [--csv OUT] [--markdown OUT] [--update-doc FILE]
//             [--fail-on-criteria] [--fail-on-nan]
//     every preset on every scene (see suite.cpp); exit status 2 when a run could not be
//     executed, 1 with --fail-on-criteria when a run failed its criteria, else 0.
//   physbench --scene FILE --peer NAME [--peer-iterations N] [--seconds S] [--json OUT]
//   physbench --suite ... --peers bullet,ode,mujoco|all [--peer-iterations 10,100]
//     the same scenes in peer engines, measured by the same metrics code (docs/PEERS.md);
//     an unknown or not compiled-in peer exits 2.
//   physbench --stress [--presets a,b|all] [--seeds N] [--seed-start S] [--seed S]
//             [--stress-seconds T] [--jobs N] [--csv OUT] [--dump-scene FILE]
//             [--fail-on-failure]
//     seeded random scenes and each preset's failure rate (see stress.cpp).
#include <CLI/CLI.hpp>
#include <filesystem>
#include <string>

#include "bench.h"
#include "phys/presets.h"

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
                 "threads per world (default 0: the machine's; with --jobs, divided among them)")
      ->check(CLI::Range(0, 64));

  // Peer engines (docs/PEERS.md): --peer in single-scene mode, --peers in the suite.
  CLI::Option* peerOpt = app.add_option(
      "--peer", single.peer, "run the scene in this peer engine (bullet, ode, mujoco) instead");
  std::vector<int> peerIterations;
  CLI::Option* peerItOpt =
      app.add_option("--peer-iterations", peerIterations,
                     "the peers' solver iterations, comma-separated in the suite (default: each "
                     "engine's own)")
          ->delimiter(',')
          ->check(CLI::Range(1, 100000));
  peerOpt->excludes(presetOpt);

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
      app.add_option("--peers", suite.peers,
                     "peer engines to run beside the presets, comma-separated, or all")
          ->delimiter(','),
  };
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
  };
  for (CLI::Option* o : stressOnly) o->needs(stressFlag);
  for (CLI::Option* o : {sceneOpt, presetOpt, secondsOpt, jsonOpt, suiteFlag, peerOpt, peerItOpt})
    o->excludes(stressFlag);
  // --presets, --jobs and --csv serve both the suite and the stress mode.
  for (CLI::Option* o : suiteOnly) {
    const std::string n = o->get_name();
    if (n != "--presets" && n != "--jobs" && n != "--csv") o->needs(suiteFlag);
  }
  CLI11_PARSE(app, argc, argv);
  if (!suiteMode && !stressMode) {
    for (const char* shared : {"--presets", "--jobs", "--csv"})
      if (app.count(shared))
        return app.exit(CLI::ValidationError(std::string(shared), "needs --suite or --stress"));
  }

  if (stressMode) {
    stress.presetsPath = presetsPath;
    stress.presets = suite.presets;
    stress.jobs = app.count("--jobs") ? suite.jobs : 0;
    stress.csvOut = suite.csvOut;
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
    return bench::runSingle(single);
  }
  if (app.count("--peer-iterations") && suite.peers.empty())
    return app.exit(CLI::ValidationError("--peer-iterations", "needs --peer or --peers"));
  suite.peerIterations = peerIterations;
  suite.presetsPath = presetsPath;
  suite.threads = threads;
  if (suite.scenesDir.empty()) suite.scenesDir = defaultScenesDir();
  suite.commandLine = commandLine(argc, argv);
  return bench::runSuite(suite);
}
