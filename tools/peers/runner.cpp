// The peer runner (runner.h): a peer steps, a phys::World mirrors its states, our metrics
// measure the mirror.
#include "peers/runner.h"

#include <chrono>
#include <cmath>

namespace phys::peers {
namespace {

double msSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

}  // namespace

PeerRun runPeer(const Scene& scene, PeerEngine& peer, const PeerBudget& budget, double seconds,
                const std::function<bool(int)>& onStep) {
  PeerRun run;
  run.engine = peer.name();
  run.version = peer.version();

  // The mirror: the scene's own world, whose bodies take the peer's states every step.
  // The guard never runs (observe does not step), one thread is plenty for collision only.
  WorldDef def = scene.world;
  def.threads = 1;
  World world(def);
  std::vector<BodyId> ids;
  run.status = instantiateScene(scene, &world, &ids);
  if (!run.status.ok()) return run;

  auto t0 = std::chrono::steady_clock::now();
  run.status = peer.build(scene, budget);
  run.buildMs = msSince(t0);
  if (!run.status.ok()) return run;

  MetricsRecorder recorder(scene, world, ids);
  const double duration = seconds > 0 ? seconds : scene.duration;
  const int steps = int(std::lround(duration / scene.world.timeStep));
  std::vector<PeerBodyState> states;
  std::vector<ObservedBody> observed(ids.size());
  long long nonFinite = 0;
  for (int i = 0; i < steps; ++i) {
    t0 = std::chrono::steady_clock::now();
    peer.step();
    const double ms = msSince(t0);
    peer.read(&states);
    if (states.size() != ids.size()) {
      run.status = Status::Error(StatusCode::IncorrectState,
                                 run.engine + " read " + std::to_string(states.size()) +
                                     " bodies, the scene has " + std::to_string(ids.size()));
      return run;
    }
    for (size_t b = 0; b < ids.size(); ++b) {
      const PeerBodyState& s = states[b];
      observed[b] = {s.position, s.rotation, s.linearVelocity, s.angularVelocity};
    }
    Status st = world.observe(ids, observed, ms);
    if (!st.ok()) {
      // A non-finite state: the peer blew up. Count its non-finite numbers as NaN (the mirror
      // cannot hold them) and stop stepping a dead simulation.
      for (const PeerBodyState& s : states) {
        const float v[13] = {s.position.x,       s.position.y,        s.position.z,
                             s.rotation.x,       s.rotation.y,        s.rotation.z,
                             s.rotation.w,       s.linearVelocity.x,  s.linearVelocity.y,
                             s.linearVelocity.z, s.angularVelocity.x, s.angularVelocity.y,
                             s.angularVelocity.z};
        for (float x : v) nonFinite += std::isfinite(x) ? 0 : 1;
      }
      run.stopped = "stopped at step " + std::to_string(i + 1) + ": " + st.message;
      break;
    }
    recorder.afterStep(world);
    if (onStep && !onStep(i + 1)) {
      run.stopped = "stopped by the caller after step " + std::to_string(i + 1);
      break;
    }
  }
  run.summary = recorder.summary();
  run.summary.nan += nonFinite;
  run.summary.stateHash = world.stateHash();
  run.criteria = evaluate(run.summary, scene.criteria);
  return run;
}

}  // namespace phys::peers
