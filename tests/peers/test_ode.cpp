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
  Scene scene = fallingSlider();
  ASSERT_TRUE(peer->build(scene, {}).ok());
  PeerBodyState s = run(*peer, 120, 0);
  EXPECT_NEAR(s.position.z, 4, 0.01);
  EXPECT_NEAR(s.position.x, 1, 1e-4);
  EXPECT_NEAR(s.position.y, 2, 1e-4);
  EXPECT_LT(length(s.linearVelocity), 0.05f);
}

}  // namespace
}  // namespace phys::peers
