// The solver settings' list (PHYS_SOLVER_FIELDS, solver_settings.h) against the formats that
// keep SolverSettings: each field alone through a snapshot (ioSolver, a pinned format written
// by hand) and through a scene file's solver block (the presets' JSON, from the list).
#include <gtest/gtest.h>

#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "../common/solver_fields.h"
#include "phys/scene/scene.h"
#include "phys/world/world.h"

using namespace phys;
using phys::solver_fields::kCount;
using phys::test::changedSettings;
using phys::test::expectSameSettings;

TEST(SolverFields, ListHasEveryMember) {
  // memberCount checks the rows against the struct where it is declared; this pins both.
  EXPECT_EQ(kCount, 27);
  const SolverSettings all = changedSettings();
  EXPECT_TRUE(World::validate(all).ok()) << World::validate(all).message;
  int changed = 0;
#define PHYS_CHANGED(type, member, ...) changed += all.member != SolverSettings().member;
  PHYS_SOLVER_FIELDS(PHYS_CHANGED)
#undef PHYS_CHANGED
  EXPECT_EQ(changed, kCount);
}

TEST(SolverFields, EachFieldAloneThroughASnapshot) {
  for (int i = -1; i < kCount; ++i) {
    WorldDef def;
    def.solver = changedSettings(i);
    World w(def);
    std::vector<uint8_t> bytes;
    ASSERT_TRUE(w.saveSnapshot(&bytes).ok());
    World back;
    Status st = back.restoreSnapshot(bytes.data(), bytes.size());
    ASSERT_TRUE(st.ok()) << st.message;
    expectSameSettings(back.def().solver, def.solver, "field " + std::to_string(i));
  }
}

TEST(SolverFields, EachFieldAloneThroughASceneFile) {
  for (int i = -1; i < kCount; ++i) {
    Scene scene;
    scene.name = "fields";
    scene.world.solver = changedSettings(i);
    Scene back;
    Status st = parseScene(sceneToJson(scene), "fields", &back);
    ASSERT_TRUE(st.ok()) << st.message;
    expectSameSettings(back.world.solver, scene.world.solver, "field " + std::to_string(i));
  }
}

// Pinned when the list came to drive the presets' JSON (issue 44), over its first 27 rows
// (rows appended later leave it be): their lines of a scene file's solver block, every field
// changed.
TEST(SolverFields, SceneFileTextIsAsBefore) {
  constexpr int kPinned = 27;
  std::set<std::string> keys;
  int i = 0;
#define PHYS_KEY(type, member, name, json, ...) \
  if (i++ < kPinned) keys.insert("\"" #json "\":");
  PHYS_SOLVER_FIELDS(PHYS_KEY)
#undef PHYS_KEY
  Scene scene;
  scene.name = "fields";
  scene.world.solver = changedSettings();
  std::istringstream text(sceneToJson(scene));
  std::string lines, line;
  while (std::getline(text, line)) {
    line.erase(0, line.find_first_not_of(' '));
    if (line.ends_with(',')) line.pop_back();
    if (keys.count(line.substr(0, line.find(':') + 1))) lines += line + "\n";
  }
  uint64_t h = 1469598103934665603ull;
  for (unsigned char c : lines) h = (h ^ c) * 1099511628211ull;
  EXPECT_EQ(h, 10775038091634066616ull) << lines;
}
