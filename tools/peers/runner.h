// Runs a scene in a peer engine and measures it with phys_core's own metrics code: each peer
// step's states are mirrored into a phys::World built from the same scene (World::observe),
// and MetricsRecorder reads that world exactly as it reads our own steps. So every number in
// a table (penetration, joint error, energy, drift) is computed by the same code for every
// engine; only ms_per_step is the peer's own (its step() call, timed here).
#pragma once

#include <functional>
#include <string>
#include <vector>

#include "peers/peer.h"
#include "phys/scene/metrics.h"
#include "phys/scene/scene.h"

namespace phys::peers {

struct PeerRun {
  std::string engine;   ///< the peer's name()
  std::string version;  ///< the peer's version()
  /// Ok, or the peer's build() error (Unsupported feature, the engine's own error text), or
  /// the mirror world's error: then nothing ran and summary is empty.
  Status status;
  MetricsSummary summary;  ///< stateHash: the mirror's, i.e. of the peer's last poses
  std::vector<CriterionResult> criteria;  ///< phys::evaluate(summary, scene.criteria)
  double buildMs = 0;                     ///< wall time of the peer's build()
  /// Empty when the run went the whole duration; else why it stopped early (the peer's state
  /// went non-finite, counted in summary.nan; or a state the mirror rejected).
  std::string stopped;
};

/// Builds `scene` in `peer` with `budget` and runs it for `seconds` of simulated time (<= 0:
/// the scene's duration), one peer step per scene time step; ms_per_step is the wall time of
/// each peer.step() (steady_clock).
/// `onStep(n)`, when given, is called after each measured step n = 1, 2, ... (progress displays);
/// returning false stops the run there (run.stopped says so; a wall-time limit, say).
PeerRun runPeer(const Scene& scene, PeerEngine& peer, const PeerBudget& budget, double seconds,
                const std::function<bool(int)>& onStep = {});

}  // namespace phys::peers
