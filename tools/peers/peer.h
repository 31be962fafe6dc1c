// Peer engines: Bullet, ODE, MuJoCo and Box3D driven through one small interface so physbench can run
// the same scene files in them and measure them with our own metrics code (see runner.h).
//
// An adapter builds a scene in its engine with the scene's own masses, inertias and centres of
// mass (computed by phys_core, so every engine simulates the same bodies), steps it with the
// scene's time step and reports each body's state in phys's conventions. It never measures
// anything itself: the runner mirrors the states into a phys::World and records metrics there.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "phys/defs/math.h"
#include "phys/scene/scene.h"
#include "phys/world/world.h"

namespace phys::peers {

/// One body's state, in phys's conventions (BodyState): the body frame's origin and rotation,
/// the centre of mass's linear velocity and the angular velocity, all in the world frame.
struct PeerBodyState {
  Vec3 position;
  Quat rotation;
  Vec3 linearVelocity, angularVelocity;
};

/// How hard a peer works per step. 0 means the engine's documented default.
struct PeerBudget {
  int iterations = 0;  ///< solver iterations per step (Bullet numIterations, ODE QuickStep
                       ///< iterations, MuJoCo opt.iterations)
  int substeps = 1;    ///< steps of timeStep / substeps per scene step (Box3D: its substep
                       ///< count when > 1, else its default 4)
  int threads = 1;     ///< threads the engine may step with (Box3D's workerCount; Bullet, ODE
                       ///< and MuJoCo step on the caller's thread whatever this says)
};

class PeerEngine {
 public:
  virtual ~PeerEngine() = default;
  /// "bullet", "ode", "mujoco", "box3d".
  virtual std::string name() const = 0;
  /// The library's version as the engine reports it (or as the package pins it).
  virtual std::string version() const = 0;
  /// Builds every body and joint of `scene`. Returns unsupported() (peer_common.h) naming the
  /// feature a scene uses that this engine cannot express, or engineError() with the engine's
  /// own error text (for example MuJoCo's allocation failure on pyramid_40). phys's StatusCode
  /// has no Unsupported or Internal: those helpers say which codes stand for them. Call once.
  virtual Status build(const Scene& scene, const PeerBudget& budget) = 0;
  /// Advances by scene.world.timeStep.
  virtual void step() = 0;
  /// out->at(i) is the state of scene.bodies[i], for every body of the scene (static ones too).
  virtual void read(std::vector<PeerBodyState>* out) const = 0;
};

/// The peers compiled into this build (PHYS_WITH_PEERS and the packages found), in a fixed
/// order: bullet, ode, mujoco, box3d.
std::vector<std::string> peerNames();
/// nullptr when `name` is not compiled in.
std::unique_ptr<PeerEngine> makePeer(const std::string& name);

// The adapters' factories, each defined in its own file when that engine is compiled in.
std::unique_ptr<PeerEngine> makeBulletPeer();
std::unique_ptr<PeerEngine> makeOdePeer();
std::unique_ptr<PeerEngine> makeMujocoPeer();
std::unique_ptr<PeerEngine> makeBox3dPeer();

}  // namespace phys::peers
