// Solver presets file and criterion evaluation.
#include <gtest/gtest.h>

#include "../common/solver_fields.h"
#include "phys/scene/metrics.h"
#include "phys/scene/presets.h"
#include "phys/scene/scene.h"

using namespace phys;
using phys::test::expectSameSettings;

TEST(Presets, ShippedFileLoadsAndItsDefaultExists) {
  std::map<std::string, Preset> presets;
  std::string def;
  Status st =
      loadPresetsFile(std::string(PHYS_SOURCE_DIR) + "/configs/presets.json", &presets, &def);
  ASSERT_TRUE(st.ok()) << st.message;
  ASSERT_TRUE(presets.count(def));
  // The default preset is the engine's default solver, so scenes without a solver block and
  // physbench --preset default run the same thing.
  expectSameSettings(presets[def].settings, SolverSettings(), "the default preset");
}

TEST(Presets, BadFieldsAreRejectedWithTheirPath) {
  std::map<std::string, Preset> presets;
  auto parse = [&](const std::string& body) {
    return parsePresets(R"({"default": "a", "presets": {"a": )" + body + "}}", "p.json", &presets,
                        nullptr);
  };
  EXPECT_TRUE(parse(R"({"substeps": 2})").ok());
  Status st = parse(R"({"substeps": 9999999999})");
  EXPECT_EQ(st.code, StatusCode::InvalidArgument);
  EXPECT_NE(st.message.find("presets.a.substeps"), std::string::npos) << st.message;
  EXPECT_FALSE(parse(R"({"substeps": 0})").ok());
  EXPECT_FALSE(parse(R"({"substeps": 2.5})").ok());
  EXPECT_FALSE(parse(R"({"substepz": 2})").ok());
  EXPECT_FALSE(parse(R"({"stabilization": "stiff"})").ok());
  EXPECT_FALSE(parse(R"({"warm_start": 1})").ok());
  EXPECT_TRUE(parse(R"({"direct_contact_ratio": 0})").ok());
  st = parse(R"({"direct_contact_ratio": 0.5})");
  EXPECT_NE(st.message.find("direct_contact_ratio must be 0 (never) or >= 1"), std::string::npos)
      << st.message;
  // The Jacobi scheme has no direct contacts and ignores the ratio (as the GPU backend does).
  EXPECT_TRUE(
      parse(R"({"scheme": "jacobi", "equality": "iterative", "direct_contact_ratio": 10})").ok());
  EXPECT_FALSE(parsePresets("{", "p.json", &presets, nullptr).ok());
  EXPECT_FALSE(
      parsePresets(R"({"default": "zz", "presets": {"a": {}}})", "p.json", &presets, nullptr).ok());
}

TEST(Criteria, MissingOrNonFiniteMetricFailsItsCriterion) {
  MetricsSummary m;
  m.topDrift = 0.004;
  m.nan = 0;
  std::vector<Criterion> c = {{"top_drift", std::nullopt, 0.01},
                              {"top_drift", 0.005, std::nullopt},
                              {"joint_error_max", std::nullopt, 1.0},
                              {"nan", std::nullopt, 0.0}};
  std::vector<CriterionResult> r = evaluate(m, c);
  ASSERT_EQ(r.size(), 4u);
  EXPECT_TRUE(r[0].passed);
  EXPECT_FALSE(r[1].passed);  // below its min
  EXPECT_FALSE(r[2].passed);  // no joints: the metric does not apply, so it cannot pass
  EXPECT_TRUE(r[3].passed);
}

TEST(Criteria, SettledMetricIsMissingWhenTheRunEndsBeforeSettling) {
  Scene scene;
  ASSERT_TRUE(parseScene(R"({"name": "s", "duration": 1,
      "bodies": [{"name": "ground", "type": "static", "shapes": [{"type": "plane"}]},
                 {"name": "box", "position": [0, 0, 0.5],
                  "shapes": [{"type": "box", "half_extents": [0.5, 0.5, 0.5]}]}],
      "metrics": {"settle_time": 2},
      "criteria": [{"metric": "penetration_settled_max", "max": 0.005}]})",
                         "inline", &scene)
                  .ok());
  World world(scene.world);
  std::vector<BodyId> ids;
  ASSERT_TRUE(instantiateScene(scene, &world, &ids).ok());
  MetricsRecorder rec(scene, world, ids);
  for (int i = 0; i < 60; ++i) {  // 1 s, before the 2 s settle time
    world.step();
    rec.afterStep(world);
  }
  MetricsSummary m = rec.summary();
  EXPECT_FALSE(m.penetrationSettledMax.has_value());
  EXPECT_FALSE(evaluate(m, scene.criteria)[0].passed);
}
