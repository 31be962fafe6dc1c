// physbench --suite: every preset of the presets file on every scene of configs/scenes/, one
// World per run, --jobs runs at a time. A run that fails its criteria, goes NaN or throws
// never stops the others; whatever could not be run is printed and makes the exit status 2.
#include "suite.h"

#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <exception>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <mutex>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>
#include <stdexcept>
#include <thread>

#include "phys/scene/metrics.h"
#include "phys/scene/presets.h"
#include "phys/scene/scene.h"
#include "phys/world/world.h"
#include "sweep.h"

namespace phys::bench {

namespace {

using Clock = std::chrono::steady_clock;

/// Scale scenes take minutes per run: only run when named.
bool isScaleScene(const std::string& name) {
  return name == "many_pyramids" || name == "pile_10k" || name == "pile_100k" || name == "pile_1m";
}

/// Steps between full checks for non-finite body states. A NaN world stays NaN, so the run
/// stops there instead of spending the rest of its duration (or hanging) on garbage.
constexpr int kNanCheckSteps = 30;

double secondsSince(Clock::time_point t) {
  return std::chrono::duration<double>(Clock::now() - t).count();
}

std::string clockText(double s) {
  long t = std::lround(s);
  char b[32];
  if (t >= 3600)
    std::snprintf(b, sizeof b, "%ld:%02ld:%02ld", t / 3600, t / 60 % 60, t % 60);
  else
    std::snprintf(b, sizeof b, "%ld:%02ld", t / 60, t % 60);
  return b;
}

bool readFile(const std::string& path, std::string* out) {
  std::ifstream f(path, std::ios::binary);
  if (!f) return false;
  std::ostringstream ss;
  ss << f.rdbuf();
  *out = ss.str();
  return bool(f) || f.eof();
}

struct SceneEntry {
  std::string name, path, error;
  Scene scene;
  double seconds = 0;
  int steps = 0;
};

struct Job {
  size_t scene = 0;    ///< index into the scene list
  std::string preset;  ///< the column: a preset's name or a peer's label
  const Preset* settings = nullptr;
  std::string peer;  ///< a peer column: the engine (settings is null)
  int peerIterations = 0;
  std::string error;  ///< known before running: the scene did not load, the preset is unknown
  double cost = 0;    ///< for ordering parallel runs, steps x (bodies + joints)
  std::atomic<int> stepsDone{0};
  std::atomic<int> state{0};  ///< 0 queued, 1 running, 2 done
  Clock::time_point started;
  RunResult result;
};

bool finiteWorld(const World& world, const std::vector<BodyId>& ids) {
  for (BodyId id : ids) {
    BodyState s;
    if (!world.getBody(id, &s).ok()) continue;
    if (!isFinite(s.position) || !isFinite(s.rotation) || !isFinite(s.linearVelocity) ||
        !isFinite(s.angularVelocity))
      return false;
  }
  return true;
}

/// Runs one job; every failure ends up in job.result (status Error), never thrown.
void runJob(const SceneEntry& se, Job& job, int threads, int peerThreads,
            const std::string& backend, double maxWallSeconds) {
  RunResult& r = job.result;
  r.main = mainMetricFor(se.name);
  if (!job.error.empty()) {
    r.status = RunStatus::Error;
    r.error = job.error;
    return;
  }
  try {
    if (!job.peer.empty()) {
      runPeerJob(se.scene, job.peer, job.peerIterations, peerThreads, se.steps, maxWallSeconds,
                 &r, &job.stepsDone);
      return;
    }
    Scene scene = se.scene;  // a copy per run: the recorder keeps a pointer to it
    scene.world.solver = job.settings->settings;
    scene.world.threads = threads;
    if (!backend.empty()) parseBackend(backend, &scene.world.backend);
    Status st = World::validate(scene.world.solver);
    if (!st.ok()) throw std::runtime_error("preset " + job.preset + ": " + st.message);
    World world(scene.world);
    std::vector<BodyId> ids;
    st = instantiateScene(scene, &world, &ids);
    if (!st.ok()) throw std::runtime_error(se.path + ": " + st.message);
    r.bodies = world.bodyCount();
    r.joints = world.jointCount();
    MetricsRecorder rec(scene, world, ids);
    const Clock::time_point start = Clock::now();
    for (int i = 0; i < se.steps; ++i) {
      world.step();
      rec.afterStep(world);
      job.stepsDone.store(i + 1, std::memory_order_relaxed);
      if (maxWallSeconds > 0 && secondsSince(start) > maxWallSeconds) {
        r.status = RunStatus::CannotRun;
        r.error = wallLimitMessage(maxWallSeconds, i + 1, se.steps);
        r.metrics = rec.summary();
        r.steps = r.metrics.steps;
        return;
      }
      // The energy sums every body's state: a cheap check each step, the full one sometimes.
      const bool full = (i + 1) % kNanCheckSteps == 0 || i + 1 == se.steps;
      if (!std::isfinite(world.stats().energyAfter) || (full && !finiteWorld(world, ids))) {
        r.nanTime = world.time();
        break;
      }
    }
    r.metrics = rec.summary();
    r.metrics.stateHash = world.stateHash();
    r.steps = r.metrics.steps;
    r.mainValue = r.metrics.value(r.main.name);
    // A run that ends before the settle time never measured its settled metrics (they read 0).
    if (r.main.name.find("settled") != std::string::npos &&
        world.time() <= scene.metrics.settleTime)
      r.mainValue.reset();
    std::vector<CriterionResult> results = evaluate(r.metrics, scene.criteria);
    for (const CriterionResult& c : results)
      if (!c.passed) r.failed.push_back(c);
    if (r.nanTime >= 0 || r.metrics.nan > 0)
      r.status = RunStatus::NaN;
    else if (results.empty())
      r.status = RunStatus::NoCriteria;
    else
      r.status = r.failed.empty() ? RunStatus::Pass : RunStatus::Fail;
    if (r.status == RunStatus::NaN && r.nanTime < 0) r.nanTime = world.time();
  } catch (const std::exception& e) {
    r.status = RunStatus::Error;
    r.error = e.what();
  } catch (...) {
    r.status = RunStatus::Error;
    r.error = "unknown exception";
  }
}

/// "soft_step 6x2": a preset's column at a sweep budget.
std::string budgetLabel(const std::string& preset, int substeps, int iterations) {
  return preset + " " + std::to_string(substeps) + "x" + std::to_string(iterations);
}

/// One line for a finished run, for the progress log.
std::string runLine(const RunResult& r) {
  char b[256];
  std::string out = r.scene + " / " + r.preset + ": " + toString(r.status);
  switch (r.status) {
    case RunStatus::Error:
    case RunStatus::CannotRun:
      return out + ": " + r.error;
    case RunStatus::NaN:
      std::snprintf(b, sizeof b, " at %.3g s", r.nanTime);
      out += b;
      break;
    default:
      break;
  }
  std::snprintf(b, sizeof b, ", %s %s, %.3g ms/step (%.1f s)", r.main.name.c_str(),
                fmtNumber(r.mainValue).c_str(), r.metrics.msPerStepMedian, r.wallSeconds);
  out += b;
  if (!r.failed.empty()) {
    out += "; failed:";
    for (const CriterionResult& c : r.failed) out += " " + c.name;
  }
  return out;
}

/// The progress display on stderr: a status line redrawn twice a second on a terminal
/// (what runs now, done/left, elapsed), a line per finished run, and a line per started run
/// plus a heartbeat every 30 s when stderr is a file or pipe.
class Progress {
 public:
  Progress(std::vector<Job>& jobs, Clock::time_point start)
      : jobs_(jobs), start_(start), tty_(isatty(STDERR_FILENO)) {}

  void begin() {
    thread_ = std::thread([this] { loop(); });
  }
  void end() {
    {
      std::lock_guard<std::mutex> lock(mu_);
      stop_ = true;
    }
    cv_.notify_all();
    thread_.join();
    std::lock_guard<std::mutex> lock(mu_);
    clearStatus();
  }
  void started(const Job& job) {
    if (tty_ || !job.error.empty()) return;  // the status line shows it; nothing to run
    const RunResult& r = job.result;
    char b[128];
    std::snprintf(b, sizeof b, " (%g s, %d steps)", r.seconds, r.plannedSteps);
    print("start " + r.scene + " / " + r.preset + b);
  }
  void finished(const Job& job) { print(runLine(job.result)); }

 private:
  std::string counts() {
    int done = 0;
    for (const Job& j : jobs_) done += j.state.load() == 2;
    char b[96];
    std::snprintf(b, sizeof b, "[%d/%zu done, %zu left, %s]", done, jobs_.size(),
                  jobs_.size() - size_t(done), clockText(secondsSince(start_)).c_str());
    return b;
  }
  std::string running() {
    std::string out;
    for (const Job& j : jobs_) {
      if (j.state.load() != 1) continue;
      const RunResult& r = j.result;
      double frac = r.plannedSteps ? double(j.stepsDone.load()) / r.plannedSteps : 0;
      char b[96];
      std::snprintf(b, sizeof b, " %.0f%% of %g s", 100 * frac, r.seconds);
      out += (out.empty() ? "" : ", ") + r.scene + " / " + r.preset + b;
    }
    return out.empty() ? "-" : out;
  }
  void clearStatus() {
    if (tty_ && drawn_) std::fputs("\r\033[K", stderr);
    drawn_ = false;
  }
  void print(const std::string& line) {
    std::lock_guard<std::mutex> lock(mu_);
    clearStatus();
    std::fprintf(stderr, "%s %s\n", counts().c_str(), line.c_str());
    if (tty_) draw();
  }
  void draw() {
    std::string s = counts() + " running: " + running();
    if (s.size() > 200) s = s.substr(0, 197) + "...";
    std::fprintf(stderr, "\r\033[K%s", s.c_str());
    drawn_ = true;
  }
  void loop() {
    std::unique_lock<std::mutex> lock(mu_);
    const auto period = tty_ ? std::chrono::milliseconds(500) : std::chrono::seconds(30);
    while (!cv_.wait_for(lock, period, [this] { return stop_; })) {
      if (tty_)
        draw();
      else
        std::fprintf(stderr, "%s running: %s\n", counts().c_str(), running().c_str());
    }
  }

  std::vector<Job>& jobs_;
  Clock::time_point start_;
  bool tty_;
  bool drawn_ = false;
  bool stop_ = false;
  std::mutex mu_;
  std::condition_variable cv_;
  std::thread thread_;
};

/// Preset names in the order the file lists them, the default first.
std::vector<std::string> presetOrder(const std::string& text,
                                     const std::map<std::string, Preset>& presets,
                                     const std::string& def) {
  std::vector<std::string> order;
  if (presets.count(def)) order.push_back(def);
  nlohmann::ordered_json j = nlohmann::ordered_json::parse(text, nullptr, false);
  if (j.is_object() && j.contains("presets") && j["presets"].is_object())
    for (const auto& [k, v] : j["presets"].items())
      if (presets.count(k) && k != def) order.push_back(k);
  for (const auto& [k, v] : presets)  // anything the ordered read missed
    if (std::find(order.begin(), order.end(), k) == order.end()) order.push_back(k);
  return order;
}

std::string joinNames(const std::vector<std::string>& v) {
  std::string out;
  for (const std::string& s : v) out += (out.empty() ? "" : ", ") + s;
  return out;
}

bool writeText(const std::string& path, const std::string& text, std::string* err) {
  std::ofstream f(path, std::ios::binary);
  f << text;
  f.close();
  if (!f) *err = "cannot write " + path;
  return bool(f);
}

}  // namespace

std::string wallLimitMessage(double limitSeconds, int stepsDone, int stepsPlanned) {
  char buf[160];
  std::snprintf(buf, sizeof buf,
                "stopped after %d of %d steps: over the %.0f s wall-time limit per run "
                "(--max-run-seconds)",
                stepsDone, stepsPlanned, limitSeconds);
  return buf;
}

namespace {

/// Our engine's runs, keyed "scene,preset" (peers have no state hash of ours).
std::map<std::string, const RunResult*> engineRuns(const SuiteReport& rep) {
  std::map<std::string, const RunResult*> out;
  for (const RunResult& r : rep.runs)
    if (r.engine == "phys") out[r.scene + "," + r.preset] = &r;
  return out;
}

}  // namespace

std::string writeHashes(const SuiteReport& rep, const std::string& path) {
  // The comment lines an existing file opens with are kept (they say what pins it).
  std::string header;
  {
    std::ifstream old(path);
    for (std::string line; std::getline(old, line) && line.rfind('#', 0) == 0;)
      header += line + "\n";
  }
  if (header.empty())
    header =
        "# State hashes pinned by physbench --expect-hashes: each run's World::stateHash() after\n"
        "# the given steps on the CPU backend. Written by physbench --write-hashes.\n";
  std::string text = header + "scene,preset,steps,state_hash\n";
  for (const auto& [key, r] : engineRuns(rep))
    if (r->status != RunStatus::Error)
      text += key + "," + std::to_string(r->steps) + "," + hashText(r->metrics.stateHash) + "\n";
  return writeAtomically(path, text);
}

int checkHashes(const SuiteReport& rep, const std::string& path, std::string* err) {
  std::ifstream in(path);
  if (!in) {
    *err = "cannot read pinned hashes " + path;
    return 0;
  }
  std::map<std::string, const RunResult*> runs = engineRuns(rep);
  int mismatches = 0, pinned = 0;
  auto mismatch = [&](const std::string& what) {
    std::fprintf(stderr, "physbench: pinned hash: %s\n", what.c_str());
    mismatches++;
  };
  std::string line;
  while (std::getline(in, line)) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.empty() || line[0] == '#' || line.rfind("scene,", 0) == 0) continue;
    std::vector<std::string> f;
    std::stringstream ss(line);
    for (std::string field; std::getline(ss, field, ',');) f.push_back(field);
    if (f.size() != 4) {
      *err = path + ": not scene,preset,steps,state_hash: " + line;
      return mismatches;
    }
    pinned++;
    const std::string key = f[0] + "," + f[1];
    auto it = runs.find(key);
    if (it == runs.end()) {
      mismatch(key + " is pinned but was not run");
      continue;
    }
    const RunResult& r = *it->second;
    runs.erase(it);
    if (std::to_string(r.steps) != f[2])
      mismatch(key + ": " + std::to_string(r.steps) + " steps, pinned after " + f[2]);
    else if (hashText(r.metrics.stateHash) != f[3])
      mismatch(key + ": state hash " + hashText(r.metrics.stateHash) + ", pinned " + f[3]);
  }
  for (const auto& [key, r] : runs) mismatch(key + " was run but has no pinned hash");
  std::fprintf(stderr, "physbench: %d pinned state hashes, %d differ or are missing (%s)\n",
               pinned, mismatches, path.c_str());
  return mismatches;
}

int runSuite(const SuiteOptions& opt) {
  const Clock::time_point t0 = Clock::now();
  SuiteReport rep;
  rep.options = opt;

  // Presets: read at run time (others add presets), in the file's order.
  std::string text;
  if (opt.presetsPath.empty()) {
    std::cerr << "physbench: no presets file found; pass --presets-file\n";
    return 2;
  }
  if (!readFile(opt.presetsPath, &text)) {
    std::cerr << "physbench: cannot read " << opt.presetsPath << "\n";
    return 2;
  }
  std::map<std::string, Preset> presets;
  Status st = parsePresets(text, opt.presetsPath, &presets, &rep.defaultPreset);
  if (!st.ok()) {
    std::cerr << "physbench: " << st.message << "\n";
    return 2;
  }
  std::vector<std::string> known = presetOrder(text, presets, rep.defaultPreset);
  std::set<std::string> unknownPresets;
  if (opt.presets.empty()) rep.presets = known;
  for (std::string name : opt.presets) {
    if (name == "default") name = rep.defaultPreset;
    if (std::find(rep.presets.begin(), rep.presets.end(), name) != rep.presets.end()) continue;
    rep.presets.push_back(name);
    if (!presets.count(name)) {
      unknownPresets.insert(name);
      std::cerr << "physbench: unknown preset '" << name << "'; known: " << joinNames(known)
                << "\n";
    }
  }

  // Sweep budgets: every preset again at each substeps x iterations pair, as its own column
  // (a derived preset, which carries the budget), after the presets' own columns.
  std::map<std::string, std::string> budgetBase;  ///< derived preset -> the preset it varies
  if (!opt.substeps.empty() || !opt.iterations.empty()) {
    const std::vector<std::string> base = rep.presets;
    for (const std::string& name : base) {
      auto p = presets.find(name);
      if (p == presets.end()) continue;
      const std::vector<int> subs =
          opt.substeps.empty() ? std::vector<int>{p->second.settings.substeps} : opt.substeps;
      const std::vector<int> its =
          opt.iterations.empty() ? std::vector<int>{p->second.settings.iterations} : opt.iterations;
      for (int s : subs) {
        for (int it : its) {
          Preset derived = p->second;
          derived.name = budgetLabel(name, s, it);
          derived.settings.substeps = s;
          derived.settings.iterations = it;
          // A budget is a budget: stack stiffening would take more substeps on tall stacks.
          derived.settings.stackStiffening = false;
          budgetBase[derived.name] = name;
          presets[derived.name] = derived;
          rep.presets.push_back(derived.name);
        }
      }
    }
  }

  // Peer engines: one column per engine and iteration budget, after the presets.
  struct PeerColumn {
    std::string label, peer;
    int iterations = 0;
  };
  std::vector<PeerColumn> peerColumns;
  if (!opt.peers.empty()) {
    std::vector<std::string> names = opt.peers;
    std::string err = resolvePeers(&names);
    if (!err.empty()) {
      std::cerr << "physbench: " << err << "\n";
      return 2;
    }
    std::vector<int> budgets =
        opt.peerIterations.empty() ? std::vector<int>{0} : opt.peerIterations;
    for (const std::string& n : names) {
      for (int it : budgets) {
        peerColumns.push_back({peerLabel(n, it), n, it});
        rep.presets.push_back(peerColumns.back().label);
      }
    }
    rep.peerVersions = peerVersions(names);
  }

  // Scenes: every file of the directory but the scale ones, or the named ones.
  std::vector<SceneEntry> scenes;
  auto addScene = [&](const std::string& name, const std::string& path) {
    for (const SceneEntry& s : scenes)
      if (s.name == name) return;
    scenes.push_back({name, path, "", {}, 0, 0});
  };
  if (opt.scenes.empty()) {
    std::vector<std::filesystem::path> files;
    std::error_code ec;
    for (const auto& e : std::filesystem::directory_iterator(opt.scenesDir, ec))
      if (e.path().extension() == ".json") files.push_back(e.path());
    if (ec) {
      std::cerr << "physbench: cannot list " << opt.scenesDir << ": " << ec.message() << "\n";
      return 2;
    }
    std::sort(files.begin(), files.end());
    for (const auto& p : files)
      if (!isScaleScene(p.stem().string())) addScene(p.stem().string(), p.string());
  } else {
    for (const std::string& s : opt.scenes) {
      bool isPath = s.find('/') != std::string::npos || s.ends_with(".json");
      std::string path = isPath ? s : opt.scenesDir + "/" + s + ".json";
      addScene(std::filesystem::path(path).stem().string(), path);
    }
  }
  for (SceneEntry& s : scenes) {
    st = loadSceneFile(s.path, &s.scene);
    if (!st.ok()) {
      s.error = st.message;
      std::cerr << "physbench: " << st.message << "\n";
      continue;
    }
    double seconds = s.scene.duration * opt.secondsScale;
    if (opt.maxSeconds > 0) seconds = std::min(seconds, opt.maxSeconds);
    if (opt.quick) seconds = std::min(seconds, kQuickSeconds);
    // A sweep plots the main metric: one measured after the settle time needs the run to
    // get there (box_stack settles at 15 s), or every point would be empty.
    if (!opt.sweepDir.empty() && !opt.quick &&
        mainMetricFor(s.name).name.find("settled") != std::string::npos)
      seconds = std::max(seconds, std::min(s.scene.duration, s.scene.metrics.settleTime + 2));
    s.steps = std::max(1, int(std::lround(seconds / s.scene.world.timeStep)));
    if (opt.maxBodySteps > 0) {
      const int64_t bodies = std::max<int64_t>(1, int64_t(s.scene.bodies.size()));
      s.steps = int(std::clamp<int64_t>(opt.maxBodySteps / bodies, 1, s.steps));
    }
    s.seconds = s.steps * double(s.scene.world.timeStep);
    rep.sceneDuration[s.name] = s.scene.duration;
    rep.sceneSettleTime[s.name] = s.scene.metrics.settleTime;
  }
  for (const SceneEntry& s : scenes) {
    rep.scenes.push_back(s.name);
    rep.sceneSeconds[s.name] = s.seconds;
  }

  // The runs, row-major: scenes x presets.
  std::vector<Job> jobs(scenes.size() * rep.presets.size());
  for (size_t i = 0; i < scenes.size(); ++i) {
    for (size_t k = 0; k < rep.presets.size(); ++k) {
      Job& j = jobs[i * rep.presets.size() + k];
      j.scene = i;
      j.preset = rep.presets[k];
      j.result.scene = scenes[i].name;
      j.result.preset = j.preset;
      auto base = budgetBase.find(j.preset);
      j.result.config = base != budgetBase.end() ? base->second : j.preset;
      if (auto p = presets.find(j.preset); p != presets.end()) {
        j.result.substeps = p->second.settings.substeps;
        j.result.iterations = p->second.settings.iterations;
      }
      auto peer = std::find_if(peerColumns.begin(), peerColumns.end(),
                               [&](const PeerColumn& c) { return c.label == j.preset; });
      if (peer != peerColumns.end()) {
        j.peer = peer->peer;
        j.peerIterations = peer->iterations;
        j.result.engine = j.result.config = peer->peer;
        j.result.substeps = 0;
        j.result.iterations = peer->iterations;
      }
      auto it = presets.find(j.preset);
      if (it != presets.end() && j.peer.empty()) j.settings = &it->second;
      if (!scenes[i].error.empty())
        j.error = scenes[i].error;
      else if (j.peer.empty() && unknownPresets.count(j.preset))
        j.error = "unknown preset '" + j.preset + "'";
      const Scene& sc = scenes[i].scene;
      j.cost = double(scenes[i].steps) * double(sc.bodies.size() + sc.joints.size() + 1);
    }
  }
  // In parallel, the longest runs first so that no long run starts last.
  std::vector<size_t> order(jobs.size());
  for (size_t i = 0; i < order.size(); ++i) order[i] = i;
  if (opt.jobs > 1)
    std::stable_sort(order.begin(), order.end(),
                     [&](size_t a, size_t b) { return jobs[a].cost > jobs[b].cost; });

  std::cerr << "physbench: suite of " << scenes.size() << " scenes x " << rep.presets.size()
            << " presets = " << jobs.size() << " runs, " << opt.jobs << " at a time; presets "
            << joinNames(rep.presets) << " (" << opt.presetsPath << ")\n";
  Progress progress(jobs, t0);
  progress.begin();
  std::atomic<size_t> next{0};
  const int nThreads = std::max(1, std::min<int>(opt.jobs, int(jobs.size())));
  // Each world's threads: as asked, or the machine's shared among the runs in flight.
  const int worldThreads =
      opt.threads > 0
          ? opt.threads
          : std::clamp(int(std::thread::hardware_concurrency()) / std::max(1, nThreads), 1, 8);
  rep.worldThreads = worldThreads;
  // The peers' threads (Box3D's workers; the other peers step on one): --threads, else 1.
  rep.peerThreads = std::max(opt.threads, 1);
  auto worker = [&] {
    for (size_t n; (n = next.fetch_add(1)) < order.size();) {
      Job& job = jobs[order[n]];
      job.started = Clock::now();
      job.result.seconds = scenes[job.scene].seconds;
      job.result.plannedSteps = scenes[job.scene].steps;
      job.state.store(1);
      progress.started(job);
      runJob(scenes[job.scene], job, worldThreads, rep.peerThreads, opt.backend,
             opt.maxRunWallSeconds);
      job.result.wallSeconds = secondsSince(job.started);
      job.state.store(2);
      progress.finished(job);
    }
  };
  std::vector<std::thread> threads;
  for (int i = 0; i < nThreads; ++i) threads.emplace_back(worker);
  for (std::thread& t : threads) t.join();
  progress.end();
  rep.wallSeconds = secondsSince(t0);

  int pass = 0, fail = 0, nan = 0, cannot = 0;
  for (Job& j : jobs) {
    RunResult& r = j.result;
    pass += r.status == RunStatus::Pass || r.status == RunStatus::NoCriteria;
    fail += r.status == RunStatus::Fail;
    nan += r.status == RunStatus::NaN;
    cannot += r.status == RunStatus::CannotRun;
    rep.errors += r.status == RunStatus::Error;
    rep.runs.push_back(std::move(r));
  }

  // Reports. The table goes to stdout too: it is the product.
  const std::string block = markdownReport(rep);
  std::cout << block << std::flush;
  int reportErrors = 0;
  auto report = [&](const std::string& err) {
    if (err.empty()) return;
    std::cerr << "physbench: " << err << "\n";
    reportErrors++;
  };
  std::string err;
  if (!opt.markdownOut.empty() && !writeText(opt.markdownOut, block, &err)) report(err);
  if (!opt.csvOut.empty()) report(writeCsv(rep, opt.csvOut));
  if (!opt.docPath.empty()) report(updateDoc(opt.docPath, block));
  if (!opt.sweepDir.empty()) {
    // The sweep's own outputs: the points, their fronts, plots and the reading.
    std::error_code ec;
    std::filesystem::create_directories(opt.sweepDir + "/plots", ec);
    if (ec) report("cannot create " + opt.sweepDir + "/plots: " + ec.message());
    const std::vector<SweepPoint> points = sweepPoints(rep);
    report(writeSweepCsv(points, opt.sweepDir + "/sweep.csv"));
    report(writeCsv(rep, opt.sweepDir + "/runs.csv"));  // every metric of every run
    std::vector<std::string> files;
    report(writeSweepPlots(points, opt.sweepDir + "/plots", &files));
    if (gnuplotVersion().empty())
      std::cerr << "physbench: gnuplot is not installed: plot scripts written, not rendered\n";
    const std::string md =
        markdownReport(rep, false) + "\n" + sweepMarkdown(rep, points, opt.sweepPlotLink);
    if (!writeText(opt.sweepDir + "/sweep.md", md, &err)) report(err);
    if (opt.sweepMarkdownOut) *opt.sweepMarkdownOut = md;
    std::cerr << "physbench: sweep written to " << opt.sweepDir
              << " (sweep.csv, runs.csv, sweep.md, " << files.size() << " plot files)\n";
  }

  std::fprintf(stderr,
               "physbench: %zu runs in %s: %d passed, %d failed their criteria, %d went NaN, "
               "%d could not be executed",
               jobs.size(), clockText(rep.wallSeconds).c_str(), pass, fail, nan, rep.errors);
  if (!peerColumns.empty())
    std::fprintf(stderr, ", %d peer runs could not build their scene", cannot);
  std::fprintf(stderr, "\n");
  if (!opt.writeHashes.empty()) report(writeHashes(rep, opt.writeHashes));
  int hashMismatches = 0;
  if (!opt.expectHashes.empty()) {
    std::string hashErr;
    hashMismatches = checkHashes(rep, opt.expectHashes, &hashErr);
    if (!hashErr.empty()) report(hashErr);
  }
  if (rep.errors > 0 || reportErrors > 0) return 2;
  if (opt.failOnCriteria && fail + nan > 0) return 1;
  if (opt.failOnNan && nan > 0) return 1;
  if (hashMismatches > 0) return 1;
  return 0;
}

}  // namespace phys::bench
