// The ODE peer's own tests: a hinge motor and a slider's limit. The analytic checks it shares
// with the other engines (free fall, a box at rest, an offset centre of mass, pendulums' periods,
// joints between bodies, hulls, capsules, kinematic bodies, damping, a distance spring it reports
// as unsupported) are in test_engines.cpp.
#include <gtest/gtest.h>

#include "peer_test_util.h"
#include "peers/peer.h"

namespace phys::peers {
namespace {

using namespace testutil;

std::unique_ptr<PeerEngine> makeOde() {
  return makePeer("ode");
}

TEST(OdePeer, HingeMotorTurnsBodyBRelativeToA) {
  auto peer = makeOde();
  if (!peer) GTEST_SKIP() << "ODE is not compiled in";
  Scene scene = pendulum(1, 0);
  scene.world.gravity = {};
  scene.joints[0].def.axisA = scene.joints[0].def.axisB = {0, 0, 1};
  scene.joints[0].def.enableMotor = true;
  scene.joints[0].def.motorSpeed = 2;
  scene.joints[0].def.maxMotorForce = 1000;
  ASSERT_TRUE(peer->build(scene, {}).ok());
  PeerBodyState s = run(*peer, 30, 0);
  EXPECT_NEAR(s.angularVelocity.z, 2, 1e-3);
}

TEST(OdePeer, PrismaticLimitStopsTheSlide) {
  auto peer = makeOde();
  if (!peer) GTEST_SKIP() << "ODE is not compiled in";
  // A box on a vertical slider whose anchors start 0.5 m apart (phys's position 0.5), falling
  // to its lower limit -0.5: it stops 1 m below its start.
  Scene scene;
  BodyDef box;
  box.position = {1, 2, 5};
  box.shapes.push_back({ShapeGeom::box({0.2f, 0.2f, 0.2f}), {}, {}});
  scene.bodies.push_back(box);
  SceneJoint slider;
  slider.def.type = JointType::Prismatic;
  slider.def.anchorA = {1, 2, 4.5f};
  slider.def.axisA = slider.def.axisB = {0, 0, 1};
  slider.def.enableLimit = true;
  slider.def.lower = -0.5f;
  slider.def.upper = 1;
  slider.bodyA = -1;
  slider.bodyB = 0;
  scene.joints.push_back(slider);
  ASSERT_TRUE(peer->build(scene, {}).ok());
  PeerBodyState s = run(*peer, 120, 0);
  EXPECT_NEAR(s.position.z, 4, 0.01);
  EXPECT_NEAR(s.position.x, 1, 1e-4);
  EXPECT_NEAR(s.position.y, 2, 1e-4);
  EXPECT_LT(length(s.linearVelocity), 0.05f);
}

}  // namespace
}  // namespace phys::peers
