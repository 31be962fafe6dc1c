// physdemo: runs a scene in real time (fixed step with an accumulator) and prints a live
// readout: tick, simulated time, bodies, contacts, energy, step time per stage, errors.
// Until physd exists, this is what ./run.sh shows. Ctrl-C stops it.
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <thread>

#include "phys/scene/metrics.h"
#include "phys/scene/scene.h"
#include "phys/world/world.h"

using namespace phys;

namespace {
volatile std::sig_atomic_t gStop = 0;
void onSignal(int) {
  gStop = 1;
}
}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"physdemo: run a scene in real time with a live readout"};
  std::string scenePath = std::string(PHYS_SOURCE_DIR) + "/configs/scenes/default.json";
  double seconds = 0, speed = 1;
  app.add_option("--scene", scenePath, "scene file");
  app.add_option("--seconds", seconds, "stop after this much simulated time (0: run until Ctrl-C)");
  app.add_option("--speed", speed, "simulated seconds per wall second");
  CLI11_PARSE(app, argc, argv);
  std::signal(SIGINT, onSignal);
  std::signal(SIGTERM, onSignal);

  Scene scene;
  Status st = loadSceneFile(scenePath, &scene);
  if (!st.ok()) {
    std::fprintf(stderr, "physdemo: %s\n", st.message.c_str());
    return 2;
  }
  World world(scene.world);
  std::vector<BodyId> ids;
  st = instantiateScene(scene, &world, &ids);
  if (!st.ok()) {
    std::fprintf(stderr, "physdemo: %s: %s\n", scenePath.c_str(), st.message.c_str());
    return 2;
  }
  std::printf("physdemo: scene '%s' (%s): %d bodies, %d joints, dt %.4f s. Ctrl-C to stop.\n",
              scene.name.c_str(), scene.description.c_str(), world.bodyCount(), world.jointCount(),
              scene.world.timeStep);
  const bool tty = isatty(STDOUT_FILENO);
  const double dt = scene.world.timeStep;
  using Clock = std::chrono::steady_clock;
  auto last = Clock::now();
  double accumulator = 0, nextPrint = 0, e0 = world.energy();
  while (!gStop && (seconds <= 0 || world.time() < seconds)) {
    auto now = Clock::now();
    accumulator += std::chrono::duration<double>(now - last).count() * speed;
    last = now;
    // Fixed step with an accumulator; at most 5 steps per frame so a slow machine falls
    // behind real time instead of spiralling.
    int n = 0;
    while (accumulator >= dt && n < 5) {
      world.step();
      accumulator -= dt;
      ++n;
    }
    if (n == 5) accumulator = 0;
    if (world.time() >= nextPrint) {
      nextPrint = world.time() + 0.5;
      const StepStats& s = world.stats();
      const StepProfile& p = world.profile();
      double jointErr = 0;
      for (JointId j : world.joints()) {
        JointState js;
        world.getJoint(j, nullptr, &js);
        jointErr = std::max(jointErr, double(js.positionError));
      }
      std::printf(
          "%stick %6llu  t %7.2f s  bodies %5d  contacts %5d  E %+.4e J (%+.2f%%)  "
          "step %.2f ms [bp %.2f np %.2f solve %.2f]  joint err %.1f mm  pen %.1f mm%s",
          tty ? "\r" : "", static_cast<unsigned long long>(s.step), world.time(), s.bodies,
          s.contactPoints, s.energyAfter,
          e0 != 0 ? 100 * (s.energyAfter - e0) / std::fabs(e0) : 0.0, p.total, p.broadPhase,
          p.narrowPhase, p.warmStart + p.solve + p.relax, 1000 * jointErr, 1000 * s.maxPenetration,
          tty ? "" : "\n");
      std::fflush(stdout);
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  }
  std::printf("\nphysdemo: stopped at tick %llu, t = %.2f s, state hash %016llx\n",
              static_cast<unsigned long long>(world.stats().step), world.time(),
              static_cast<unsigned long long>(world.stateHash()));
  return 0;
}
