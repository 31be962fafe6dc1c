// Two of the exact shortcuts of the substep (physics/dynamics/solver.h): warm starting by
// bodies (the substeps after the first add each body's impulses of the last substep instead of
// a pass over the contacts) and a body's turn in integratePositions formed from its angular
// velocity. Each must give what the long way gives, up to float rounding. (The third, the
// isotropic bodies' inverse inertia as one number, must keep the wide blocks' bits equal to
// the rows': WideContacts.BitIdenticalToTheScalarPassOnEveryGaussSeidelPreset.)
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "dynamics/solver.h"
#include "phys/scene/scene.h"
#include "phys/world/world.h"
#include "test_util.h"

using namespace phys;

namespace {

struct SceneRun {
  std::vector<Vec3> positions;
  uint64_t hash = 0;
  double energyDrift = 0;  // J, the last step's energy less the first's
};

SceneRun runScene(Scene scene, int steps) {
  scene.world.threads = 1;
  World world(scene.world);
  std::vector<BodyId> ids;
  EXPECT_TRUE(instantiateScene(scene, &world, &ids).ok());
  SceneRun r;
  world.step();
  const double e0 = world.energy();
  for (int i = 1; i < steps; ++i) world.step();
  r.energyDrift = world.energy() - e0;
  for (BodyId id : ids) r.positions.push_back(test::stateOf(world, id).position);
  r.hash = world.stateHash();
  return r;
}

/// Bodies of unequal moments (gyroscopic: their w turns inside integratePositions): a column of
/// four bricks, and one that slides and spins across the ground beside it.
const char* kBricks = R"({
  "name": "bricks", "duration": 2, "sleep": false,
  "materials": {"default": {"friction": 0.5, "restitution": 0, "density": 700}},
  "bodies": [
    {"name": "ground", "type": "static", "shapes": [{"type": "plane"}]},
    {"name": "b0", "position": [0, 0, 0.2], "shapes": [{"type": "box", "half_extents": [0.6, 0.35, 0.2]}]},
    {"name": "b1", "position": [0.05, 0, 0.6], "shapes": [{"type": "box", "half_extents": [0.6, 0.35, 0.2]}]},
    {"name": "b2", "position": [0, 0.05, 1.0], "shapes": [{"type": "box", "half_extents": [0.6, 0.35, 0.2]}]},
    {"name": "b3", "position": [-0.05, 0, 1.4], "shapes": [{"type": "box", "half_extents": [0.6, 0.35, 0.2]}]},
    {"name": "slider", "position": [0, 3, 0.25], "linear_velocity": [2, 0, 0],
     "angular_velocity": [0, 0, 3], "shapes": [{"type": "box", "half_extents": [0.5, 0.3, 0.25]}]}
  ]
})";

struct ContactWarmStart {
  ContactWarmStart() { setBodyWarmStart(false); }
  ~ContactWarmStart() { setBodyWarmStart(true); }
};

}  // namespace

// The same impulses either way: a pyramid of cubes, a ramp's friction, and bricks (unequal
// moments: their w turns inside integratePositions, which is not an impulse) end where the pass
// over the contacts leaves them, to float rounding, while the bits differ (both ways ran).
TEST(BodyWarmStart, EndsWhereThePassOverTheContactsEnds) {
  const std::pair<std::string, Scene> scenes[] = {{"pyramid_20", test::loadScene("pyramid_20")},
                                                  {"friction_ramp", test::loadScene("friction_ramp")},
                                                  {"bricks", test::sceneFromJson(kBricks)}};
  for (const auto& [name, scene] : scenes) {
    const SceneRun byBodies = runScene(scene, 120);
    SceneRun byContacts;
    {
      ContactWarmStart off;
      byContacts = runScene(scene, 120);
    }
    ASSERT_EQ(byBodies.positions.size(), byContacts.positions.size());
    double worst = 0;
    for (size_t i = 0; i < byBodies.positions.size(); ++i)
      worst = std::max(worst, double(length(byBodies.positions[i] - byContacts.positions[i])));
    EXPECT_LT(worst, 1e-4) << name;  // 2 s: rounding, not another solve
    EXPECT_NEAR(byBodies.energyDrift, byContacts.energyDrift,
                1e-3 * std::max(1.0, std::abs(byContacts.energyDrift)))
        << name;
    EXPECT_NE(byBodies.hash, byContacts.hash) << name << ": the switch changed nothing";
  }
}

// integratedTurn against the closed form in double, from a slow drift to a fast spin (the
// series below 0.1 of a half-turn's tangent, atan above), and against the rotation between the
// quaternions integrateRotation makes (what integratePositions took before), to that way's
// own rounding (the float quaternions' product: some 1e-7 rad).
TEST(IntegratedTurn, IsTheTurnBetweenTheIntegratedQuaternions) {
  const float h = 1.0f / 360;
  const Quat q = normalize(Quat{0.3f, -0.2f, 0.5f, 0.79f});
  const Vec3 axis = normalize(Vec3{0.6f, -0.3f, 0.74f});
  for (float speed : {0.0f, 1e-4f, 0.01f, 1.0f, 30.0f, 71.0f, 73.0f, 300.0f, 3000.0f}) {
    const Vec3 w = axis * speed;
    const Vec3 turn = integratedTurn(w, h);
    const double angle = 2 * std::atan(double(length(w)) * h / 2);
    const double exact[3] = {double(axis.x) * angle, double(axis.y) * angle,
                             double(axis.z) * angle};
    const double got[3] = {turn.x, turn.y, turn.z};
    for (int k = 0; k < 3; ++k)
      EXPECT_NEAR(got[k], exact[k], 1e-6 * angle + 1e-12) << "speed " << speed << ", axis " << k;
    const Vec3 between = rotationVector(integrateRotation(q, w, h) * conjugate(q));
    EXPECT_LT(length(between - turn), 3e-7f + 1e-6f * float(angle)) << "speed " << speed;
  }
}
