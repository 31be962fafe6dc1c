// Stack stiffening: a wall one box thick buckles on soft contacts once it is taller than its
// contacts' stiffness allows (the lean grows out of the wall's plane until it falls); the
// default measures each step's deepest support chain and takes the contact frequency and
// substeps that height needs. Shallow scenes keep the preset bit for bit. Warm starts, which
// are impulses per substep, follow a change of the substep length.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "phys/scene/scene.h"
#include "phys/world/world.h"
#include "test_util.h"

namespace phys {
namespace {

using test::addBody;
using test::addGround;
using test::boxBody;
using test::stateOf;

/// A pyramid wall (one box thick, in the x-z plane) of `base` cubes of half-extent `he`.
Scene wallScene(int base, float he, bool stiffening) {
  const std::string json = R"({"name": "wall", "duration": 10, "sleep": false,
    "bodies": [{"name": "ground", "type": "static", "shapes": [{"type": "plane"}]}],
    "generators": [{"type": "pyramid", "name": "wall", "base": )" +
                           std::to_string(base) + R"(, "half_extent": )" + std::to_string(he) +
                           R"(, "origin": [0, 0, 0]}]})";
  Scene s;
  Status st = parseScene(json, "wall", &s);
  EXPECT_TRUE(st.ok()) << st.message;
  s.world.solver.stackStiffening = stiffening;
  s.world.threads = 1;
  return s;
}

struct WallRun {
  float topDrift = 0;  ///< m, the top box's horizontal displacement at the end
  int substeps = 0;    ///< of the last step
  int depth = 0;       ///< the last step's deepest support chain
};

WallRun runWall(int base, float he, bool stiffening, int steps) {
  Scene s = wallScene(base, he, stiffening);
  World w(s.world);
  std::vector<BodyId> ids;
  EXPECT_TRUE(instantiateScene(s, &w, &ids).ok());
  const BodyState top0 = stateOf(w, ids.back());
  for (int i = 0; i < steps; ++i) w.step();
  const BodyState top = stateOf(w, ids.back());
  WallRun r;
  r.topDrift = std::hypot(top.position.x - top0.position.x, top.position.y - top0.position.y);
  r.substeps = w.stats().substeps;
  r.depth = w.stats().stackDepth;
  return r;
}

TEST(StackStiffening, TallWallBucklesWithoutItAndStandsWithIt) {
  // 465 cubes of 10 cm, 30 high: the default's 90 Hz contacts are too soft for it (the
  // buckling frequency of a wall of N cubes of size L is about 0.4 N^1.5 sqrt(g / L) / 2 pi:
  // 105 Hz here), so it leans out of its plane within seconds; stiffened, it takes 124 Hz
  // contacts at 9 substeps and stands.
  const int steps = 5 * 60;
  WallRun off = runWall(30, 0.05f, false, steps);
  WallRun on = runWall(30, 0.05f, true, steps);
  EXPECT_EQ(off.substeps, 6);
  EXPECT_GT(off.topDrift, 0.05f) << "the wall should lean without stiffening";
  EXPECT_EQ(on.depth, 30);
  EXPECT_GT(on.substeps, 6);
  EXPECT_LE(on.substeps, 12);
  EXPECT_LT(on.topDrift, 0.005f);
}

TEST(StackStiffening, TallColumnFallsWithoutItAndStandsWithIt) {
  // 40 unit cubes in one column need 130 Hz (4 corners a level, whatever the height: far
  // more slender than a wall of the same height, which needs 53 Hz); stiffened to 156 Hz at
  // 11 substeps it stands, at the preset's 90 Hz it leans 13 cm in 10 s and falls by 30 s.
  float drift[2] = {};
  int substeps[2] = {};
  for (int on = 0; on < 2; ++on) {
    WorldDef def;
    def.solver.stackStiffening = on != 0;
    def.threads = 1;
    World w(def);
    addGround(w);
    std::vector<BodyId> ids;
    for (int i = 0; i < 40; ++i) ids.push_back(addBody(w, boxBody({0, 0, 0.5f + float(i)})));
    for (int i = 0; i < 12 * 60; ++i) w.step();
    const Vec3 top = stateOf(w, ids.back()).position;
    drift[on] = std::hypot(top.x, top.y);
    substeps[on] = w.stats().substeps;
  }
  EXPECT_EQ(substeps[0], 6);
  EXPECT_GT(drift[0], 0.1f) << "the column should lean at 90 Hz";
  EXPECT_EQ(substeps[1], 11);
  EXPECT_LT(drift[1], 0.03f);
}

TEST(StackStiffening, AColumnSolvedDirectlyIsLeftAlone) {
  // The same column under a cube ten times heavier: its island is solved directly (direct
  // contacts), its rows rigid whatever the contact frequency, and it stands at the preset's
  // substeps; with direct contacts off the stack model stiffens it as above. (Before issue 41
  // it was stiffened either way: a pile of ragdolls held exactly asked for 8 substeps.)
  float drift[2] = {};
  int substeps[2] = {};
  for (int direct = 0; direct < 2; ++direct) {
    WorldDef def;
    def.solver.directContactRatio = direct ? 10.0f : 0.0f;
    def.threads = 1;
    World w(def);
    addGround(w);
    std::vector<BodyId> ids;
    for (int i = 0; i < 40; ++i) {
      BodyDef b = boxBody({0, 0, 0.5f + float(i)});
      if (i == 39) b.mass = 10000;
      ids.push_back(addBody(w, b));
    }
    int most = 0;
    for (int i = 0; i < 12 * 60; ++i) {
      w.step();
      most = std::max(most, w.stats().substeps);
    }
    const Vec3 top = stateOf(w, ids.back()).position;
    drift[direct] = std::hypot(top.x, top.y);
    substeps[direct] = most;
  }
  EXPECT_GT(substeps[0], 6);
  EXPECT_EQ(substeps[1], 6);
  EXPECT_LT(drift[1], 1e-3f);
}

struct SceneRun {
  uint64_t hash = 0;
  int mostSubsteps = 0;  ///< over the run
  int depth = 0;         ///< the last step's deepest support chain
};

/// configs/scenes/NAME.json with stack stiffening on or off, `steps` steps on one thread.
SceneRun runScene(const std::string& name, bool stiffening, int steps) {
  Scene s = test::loadScene(name);
  s.world.solver.stackStiffening = stiffening;
  s.world.threads = 1;
  World w(s.world);
  EXPECT_TRUE(instantiateScene(s, &w, nullptr).ok());
  SceneRun r;
  for (int i = 0; i < steps; ++i) {
    w.step();
    r.mostSubsteps = std::max(r.mostSubsteps, w.stats().substeps);
  }
  r.hash = w.stateHash();
  r.depth = w.stats().stackDepth;
  return r;
}

TEST(StackStiffening, ShortStacksKeepThePresetBitForBit) {
  // pyramid_20 (20 high, unit cubes) needs 21 Hz: the preset's 90 Hz stand, and the step is
  // the preset's to the bit.
  const SceneRun off = runScene("pyramid_20", false, 60), on = runScene("pyramid_20", true, 60);
  EXPECT_EQ(on.mostSubsteps, 6);
  EXPECT_EQ(on.depth, 20);
  EXPECT_EQ(off.depth, 0);
  EXPECT_EQ(on.hash, off.hash);
}

TEST(StackStiffening, ComparesWithTheFrequencyTheSubstepsAllow) {
  // A column of 30 cubes needs about 85 Hz, so it takes 1.2 times that (7 substeps). Asking
  // for 120 Hz at 6 substeps gets 90 (a quarter of the substep rate): it still needs them.
  WorldDef def;
  def.solver.contactHertz = 120;
  World w(def);
  addGround(w);
  for (int i = 0; i < 30; ++i) addBody(w, boxBody({0, 0, 0.5f + float(i)}));
  w.step();
  EXPECT_GT(w.stats().stackHertz, 90.0f);
  EXPECT_LT(w.stats().stackHertz, 120.0f);
  EXPECT_EQ(w.stats().substeps, 7);
}

TEST(StackStiffening, DebrisOnEdgesIsLeftAlone) {
  // The demo scene's pile: at 1.7 s two bodies rest on nearly collinear points under two
  // more, which the model could only hold at 535 Hz; such a level tips over whatever the
  // stiffness, so the step stays the preset's (and bit for bit the same as without it).
  const SceneRun off = runScene("default", false, 150), on = runScene("default", true, 150);
  EXPECT_EQ(on.mostSubsteps, 6);
  EXPECT_EQ(on.hash, off.hash);
}

TEST(StackStiffening, DepthCountsSupportChainsOnly) {
  // A column of 5 and a row of 8 boxes side by side on the ground: the row's side contacts
  // carry no load, so the deepest chain is the column's.
  World w;
  addGround(w);
  for (int i = 0; i < 5; ++i) addBody(w, boxBody({-5, 0, 0.5f + float(i)}, {0.5f, 0.5f, 0.5f}));
  for (int i = 0; i < 8; ++i) addBody(w, boxBody({float(i), 0, 0.5f}, {0.5f, 0.5f, 0.5f}));
  w.step();
  EXPECT_EQ(w.stats().stackDepth, 5);
  // Without gravity nothing is supported (from the next step that measures).
  ASSERT_TRUE(w.setGravity({0, 0, 0}).ok());
  for (int i = 0; i < SolverSettings::kStackInterval; ++i) w.step();
  EXPECT_EQ(w.stats().stackDepth, 0);
}

TEST(StackStiffening, WarmStartsFollowTheSubstepLength) {
  // A column of 12 boxes at rest; then the substeps go from 4 to 16. The stored impulses are
  // per substep: carried over unscaled they start the first substep at 4 times the column's
  // weight, and two iterations a substep do not work that off within the step (the ground
  // then carries 95 % of the weight at the step's end instead of 100 %).
  WorldDef def;
  def.solver.substeps = 4;
  def.solver.contactHertz = 30;  // under the cap of both: the same springs, the same sag
  def.solver.stackStiffening = false;
  World w(def);
  addGround(w);
  std::vector<BodyId> ids;
  for (int i = 0; i < 12; ++i)
    ids.push_back(addBody(w, boxBody({0, 0, 0.5f + float(i)}, {0.5f, 0.5f, 0.5f})));
  for (int i = 0; i < 120; ++i) w.step();
  const float h0 = w.stats().substepTime;
  EXPECT_FLOAT_EQ(h0, def.timeStep / 4);
  SolverSettings s = def.solver;
  s.substeps = 16;
  ASSERT_TRUE(w.setSolverSettings(s).ok());
  w.step();
  EXPECT_FLOAT_EQ(w.stats().substepTime, def.timeStep / 16);
  // The ground contacts carry the column's weight per 16th of a step.
  double ground = 0;
  for (const ContactInfo& c : w.contacts())
    if (c.bodyA == w.bodies().front() || c.bodyB == w.bodies().front())
      for (int k = 0; k < c.manifold.count; ++k) ground += c.normalImpulse[k];
  const double weight = 12 * 1000.0 * 9.81 * def.timeStep / 16;
  EXPECT_NEAR(ground, weight, 0.01 * weight);
}

}  // namespace
}  // namespace phys
