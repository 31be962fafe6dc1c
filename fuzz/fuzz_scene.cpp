// Fuzz target: the scene loader (phys::parseScene) on the input as JSON text, with small
// budgets, then what physd does with a scene (server/src/commands.cpp, prepareScene): the
// codec's rules on the world, every body and joint (protocol/validate.h), and if they pass,
// the world built (instantiateScene) and stepped twice.
//
// Besides crashes and sanitizer reports, it aborts when the loader breaks its contract: an
// error without a message or with a code other than InvalidArgument / ResourceExhausted, a
// scene over its budget, or a scene whose sceneToJson text does not parse back to the same
// text.
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "phys/protocol/validate.h"
#include "phys/scene/scene.h"
#include "phys/world/world.h"

namespace {

[[noreturn]] void die(const std::string& what) {
  std::fprintf(stderr, "fuzz_scene: %s\n", what.c_str());
  std::fflush(stderr);
  std::abort();
}

phys::SceneBudget budget() {
  phys::SceneBudget b;
  b.maxBodies = 256;  // pyramid_20 (210 bodies) builds; larger scenes are refused
  b.maxJoints = 256;
  b.maxShapes = 1024;
  b.maxShapesPerBody = 64;
  b.maxHullPoints = 256;
  b.maxHullPointsTotal = 8192;
  b.maxNameBytes = 256;
  b.maxPatternWork = 1'000'000;
  return b;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string json(reinterpret_cast<const char*>(data), size);
  const phys::SceneBudget b = budget();
  phys::Scene scene;
  phys::Status st = phys::parseScene(json, "fuzz", &scene, b);
  if (!st.ok()) {
    if (st.message.empty() || (st.code != phys::StatusCode::InvalidArgument &&
                               st.code != phys::StatusCode::ResourceExhausted))
      die("parseScene failed with code " + std::to_string(int(st.code)) + " and message '" +
          st.message + "'");
    return 0;
  }
  size_t shapes = 0;
  for (const phys::BodyDef& d : scene.bodies) shapes += d.shapes.size();
  if (scene.bodies.size() > b.maxBodies || scene.joints.size() > b.maxJoints ||
      shapes > b.maxShapes)
    die("a scene over its budget was accepted");

  // sceneToJson's text parses back to a scene that writes the same text.
  const std::string text = phys::sceneToJson(scene);
  phys::Scene again;
  st = phys::parseScene(text, "fuzz (written back)", &again, b);
  if (!st.ok()) die("sceneToJson's text does not parse: " + st.message + "\n" + text);
  if (phys::sceneToJson(again) != text) die("sceneToJson's text reads back differently:\n" + text);

  // What physd checks before it builds a scene.
  const phys::protocol::Limits lim;
  phys::protocol::Status ps =
      phys::protocol::checkWorldParams(scene.world.gravity, scene.world.timeStep, lim, "scene");
  for (size_t i = 0; ps.ok() && i < scene.bodies.size(); ++i)
    ps = phys::protocol::checkBodyDef(scene.bodies[i], lim, "scene body");
  for (size_t i = 0; ps.ok() && i < scene.joints.size(); ++i)
    ps = phys::protocol::checkJointDef(scene.joints[i].def, lim, "scene joint");
  if (!ps.ok()) return 0;

  phys::WorldDef def = scene.world;
  def.threads = 1;
  def.backend = phys::Backend::Cpu;
  phys::World world(def);
  std::vector<phys::BodyId> ids;
  std::vector<phys::JointId> joints;
  st = phys::instantiateScene(scene, &world, &ids, &joints);
  if (!st.ok()) return 0;
  if (ids.size() != scene.bodies.size() || joints.size() != scene.joints.size())
    die("instantiateScene made a different number of bodies or joints");
  world.step();
  world.step();
  return 0;
}
