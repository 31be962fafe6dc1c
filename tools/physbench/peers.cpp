// physbench's peer engines: --peers in the suite (extra columns beside the presets) and
// --peer in single-scene mode. The scene files are the same, and so is the metrics code:
// tools/peers/runner.h mirrors each peer step into a phys::World (docs/PEERS.md).
#include <algorithm>
#include <chrono>
#include <cmath>
#include <iostream>

#include "bench.h"
#include "suite.h"
#ifdef PHYS_WITH_PEERS
#include "peers/peer.h"
#include "peers/runner.h"
#endif

namespace phys::bench {

namespace {

/// Every peer physbench knows of, compiled in or not.
const std::vector<std::string> kKnownPeers = {"bullet", "ode", "mujoco", "box3d"};

std::string joined(const std::vector<std::string>& v) {
  std::string out;
  for (const std::string& s : v) out += (out.empty() ? "" : ", ") + s;
  return out.empty() ? "none" : out;
}

}  // namespace

std::vector<std::string> compiledPeers() {
#ifdef PHYS_WITH_PEERS
  return peers::peerNames();
#else
  return {};
#endif
}

std::string resolvePeers(std::vector<std::string>* names) {
  const std::vector<std::string> have = compiledPeers();
  std::vector<std::string> out;
  std::string errors;
  for (const std::string& n : *names) {
    std::vector<std::string> add = n == "all" ? have : std::vector<std::string>{n};
    for (const std::string& a : add) {
      if (std::find(out.begin(), out.end(), a) != out.end()) continue;
      if (std::find(have.begin(), have.end(), a) != have.end()) {
        out.push_back(a);
      } else if (std::find(kKnownPeers.begin(), kKnownPeers.end(), a) != kKnownPeers.end()) {
        errors += (errors.empty() ? "" : "; ") + ("peer '" + a + "' is not compiled in");
      } else {
        errors += (errors.empty() ? "" : "; ") + ("unknown peer '" + a + "'");
      }
    }
  }
  if (!errors.empty())
    return errors + " (known: " + joined(kKnownPeers) + "; this build has: " + joined(have) +
           "; PHYS_WITH_PEERS and each engine's package decide)";
  if (out.empty()) return "no peer to run (this build has: " + joined(have) + ")";
  *names = out;
  return {};
}

std::string peerLabel(const std::string& peer, int iterations) {
  return iterations > 0 ? peer + " (" + std::to_string(iterations) + " it)" : peer;
}

#ifdef PHYS_WITH_PEERS

std::vector<std::string> peerVersions(const std::vector<std::string>& names) {
  std::vector<std::string> out;
  for (const std::string& n : names)
    if (auto peer = peers::makePeer(n)) out.push_back(peer->name() + " " + peer->version());
  return out;
}

void runPeerJob(const Scene& scene, const std::string& peerName, int iterations, int threads,
                int steps, double maxWallSeconds, RunResult* r, std::atomic<int>* stepsDone) {
  r->bodies = int(scene.bodies.size());
  r->joints = int(scene.joints.size());
  std::unique_ptr<peers::PeerEngine> peer = peers::makePeer(peerName);
  if (!peer) {
    r->status = RunStatus::Error;
    r->error = "peer '" + peerName + "' is not compiled in";
    return;
  }
  const double seconds = steps * double(scene.world.timeStep);
  const auto start = std::chrono::steady_clock::now();
  bool overTime = false;
  peers::PeerBudget budget;
  budget.iterations = iterations;
  budget.threads = std::max(threads, 1);
  peers::PeerRun run = peers::runPeer(scene, *peer, budget, seconds, [&](int n) {
    stepsDone->store(n, std::memory_order_relaxed);
    overTime = maxWallSeconds > 0 &&
               std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count() >
                   maxWallSeconds;
    return !overTime;
  });
  if (!run.status.ok()) {
    r->status = RunStatus::CannotRun;
    r->error = run.engine + " " + run.version + ": " + run.status.message;
    return;
  }
  if (overTime) {
    r->status = RunStatus::CannotRun;
    r->error = run.engine + " " + run.version + ": " +
               wallLimitMessage(maxWallSeconds, run.summary.steps, steps);
    r->metrics = run.summary;
    r->steps = run.summary.steps;
    return;
  }
  r->metrics = run.summary;
  r->steps = run.summary.steps;
  r->mainValue = r->metrics.value(r->main.name);
  // As for our runs: settled metrics mean nothing before the settle time.
  if (r->main.name.find("settled") != std::string::npos &&
      r->steps * double(scene.world.timeStep) <= scene.metrics.settleTime)
    r->mainValue.reset();
  for (const CriterionResult& c : run.criteria)
    if (!c.passed) r->failed.push_back(c);
  if (run.summary.nan > 0) {
    r->status = RunStatus::NaN;
    r->nanTime = (r->steps + 1) * double(scene.world.timeStep);
  } else if (run.criteria.empty()) {
    r->status = RunStatus::NoCriteria;
  } else {
    r->status = r->failed.empty() ? RunStatus::Pass : RunStatus::Fail;
  }
}

int runSinglePeer(const SingleOptions& opt) {
  std::vector<std::string> names = {opt.peer};
  std::string err = resolvePeers(&names);
  if (!err.empty() || names.size() != 1) {
    std::cerr << "physbench: " << (err.empty() ? "--peer takes one peer, not 'all'" : err) << "\n";
    return 2;
  }
  Scene scene;
  Status st = loadSceneFile(opt.scenePath, &scene);
  if (!st.ok()) {
    std::cerr << "physbench: " << st.message << "\n";
    return 2;
  }
  if (!opt.sleep.empty()) scene.world.sleep.enabled = opt.sleep == "on";
  std::unique_ptr<peers::PeerEngine> peer = peers::makePeer(names[0]);
  // --threads: the peer's worker threads (Box3D's; the others step on one thread), 1 unless
  // given.
  peers::PeerBudget budget;
  budget.iterations = opt.peerIterations;
  budget.threads = std::max(opt.threads, 1);
  peers::PeerRun run =
      peers::runPeer(scene, *peer, budget, opt.seconds < 0 ? scene.duration : opt.seconds);
  if (!run.status.ok()) {
    std::cerr << "physbench: " << scene.name << ": cannot run in " << run.engine << " "
              << run.version << ": " << run.status.message << "\n";
    return 2;
  }
  if (!run.stopped.empty()) std::cerr << "physbench: " << run.engine << " " << run.stopped << "\n";
  SingleResult r{peerLabel(run.engine, opt.peerIterations),
                 run.engine + " " + run.version,
                 run.engine == "box3d" ? budget.threads : 1,
                 int(scene.bodies.size()),
                 int(scene.joints.size()),
                 run.summary.steps,
                 run.summary,
                 {},
                 std::nullopt,
                 std::nullopt};
  return reportSingle(opt, scene, r);
}

#else

std::vector<std::string> peerVersions(const std::vector<std::string>&) {
  return {};
}

void runPeerJob(const Scene&, const std::string& peerName, int, int, int, double, RunResult* r,
                std::atomic<int>*) {
  r->status = RunStatus::Error;
  r->error = "peer '" + peerName + "' is not compiled in (built without PHYS_WITH_PEERS)";
}

int runSinglePeer(const SingleOptions& opt) {
  std::cerr << "physbench: peer '" << opt.peer
            << "' is not compiled in (built without PHYS_WITH_PEERS)\n";
  return 2;
}

#endif

}  // namespace phys::bench
