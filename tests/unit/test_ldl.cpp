// The LDL hybrid: joints solved exactly inside the iteration hold at high mass ratios where
// the iterative solve stretches.
#include <gtest/gtest.h>

#include <string>

#include "phys/scene/presets.h"
#include "phys/scene/scene.h"
#include "phys/world/world.h"

using namespace phys;

namespace {

/// Largest joint position error over `seconds` of a chain of `links` 1 kg links from a world
/// point, released horizontally, ending in a ball of `ballMass` kg.
double chainError(int links, double ballMass, const SolverSettings& solver, double seconds) {
  std::string json = R"({"name": "chain", "generators": [{"type": "chain", "name": "chain",
      "links": )" + std::to_string(links) +
                     R"(, "link_length": 0.5, "link_radius": 0.05, "link_mass": 1,
      "anchor": [0, 0, 50], "direction": [1, 0, 0],
      "end_ball": {"radius": 0.3, "mass": )" +
                     std::to_string(ballMass) + "}}]}";
  Scene scene;
  Status st = parseScene(json, "inline", &scene);
  EXPECT_TRUE(st.ok()) << st.message;
  scene.world.solver = solver;
  World world(scene.world);
  std::vector<BodyId> ids;
  EXPECT_TRUE(instantiateScene(scene, &world, &ids).ok());
  double worst = 0;
  for (int i = 0; i < int(seconds * 60); ++i) {
    world.step();
    for (JointId j : world.joints()) {
      JointState js;
      world.getJoint(j, nullptr, &js);
      worst = std::max(worst, double(js.positionError));
    }
  }
  return worst;
}

SolverSettings preset(const std::string& name) {
  std::map<std::string, Preset> presets;
  Status st =
      loadPresetsFile(std::string(PHYS_SOURCE_DIR) + "/configs/presets.json", &presets, nullptr);
  EXPECT_TRUE(st.ok()) << st.message;
  EXPECT_TRUE(presets.count(name)) << name;
  return presets[name].settings;
}

}  // namespace

TEST(LdlHybrid, HeavyBallOnAChainHoldsWhereIterationStretches) {
  // 10 links of 1 kg and a 1000 kg ball: the mass ratio that defeats iterative solvers.
  SolverSettings ldl = preset("ldl_pgs");
  SolverSettings iterative = ldl;
  iterative.equalitySolve = SolverSettings::EqualitySolve::Iterative;
  double errLdl = chainError(10, 1000, ldl, 3);
  double errIter = chainError(10, 1000, iterative, 3);
  EXPECT_LT(errLdl, 0.01);
  EXPECT_GT(errIter, 10 * errLdl);  // the same budget iterated stretches much more
}

TEST(LdlHybrid, SameAnswerAsIterationOnAnEasyChain) {
  // Equal masses: both solves hold the chain; the direct one at least as tightly.
  SolverSettings ldl = preset("ldl_pgs");
  SolverSettings iterative = ldl;
  iterative.equalitySolve = SolverSettings::EqualitySolve::Iterative;
  double errLdl = chainError(5, 1, ldl, 2);
  double errIter = chainError(5, 1, iterative, 2);
  EXPECT_LT(errLdl, 5e-3);
  EXPECT_LT(errIter, 5e-2);
}

TEST(LdlHybrid, GeometricStiffnessKeepsFewSubstepsStable) {
  // Two 1 kg links and a 1000 kg ball at 4 substeps (fewer than the default's): at the bottom
  // of the swing
  // the links' tension (about 3e4 N) makes their rotation stiff beyond what a substep of
  // frozen Jacobians integrates (omega h ~ 1.4), and without the geometric-stiffness
  // inertia the chain tears apart (9 m of joint error measured).
  SolverSettings s;  // the defaults: joints by LDL, geometric stiffness on
  ASSERT_TRUE(s.geometricStiffness);
  s.substeps = 4;
  EXPECT_LT(chainError(2, 1000, s, 3), 0.01);
  s.geometricStiffness = false;
  EXPECT_GT(chainError(2, 1000, s, 3), 0.1);
}
