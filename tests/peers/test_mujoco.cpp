// The MuJoCo peer's own tests: the joint features it reports as unsupported (hinge motors,
// prismatic joints) and pyramid_40, which MuJoCo 2.2.2 cannot allocate. The analytic checks it
// shares with the other engines (free fall, a box at rest, a body whose centre of mass is off
// its origin (frame conversions, the free joint's body-frame angular velocity), a hinge
// pendulum's period (two connect constraints) and a distance pendulum's (a tendon), joints
// between bodies, hulls (meshes), capsules, kinematic (mocap) bodies, damping, a distance spring
// it reports as unsupported) are in test_engines.cpp.
#include <gtest/gtest.h>

#include <string>

#include "peer_test_util.h"
#include "peers/peer.h"

namespace phys::peers {
namespace {

using namespace testutil;

std::unique_ptr<PeerEngine> makeMujoco() {
  return makePeer("mujoco");
}

TEST(MujocoPeer, HingeMotorIsUnsupported) {
  auto peer = makeMujoco();
  if (!peer) GTEST_SKIP() << "MuJoCo is not compiled in";
  Scene scene = pendulum(1, 0);
  scene.joints[0].def.enableMotor = true;
  scene.joints[0].def.motorSpeed = 2;
  scene.joints[0].def.maxMotorForce = 1000;
  Status st = peer->build(scene, {});
  EXPECT_FALSE(st.ok());
  EXPECT_NE(st.message.find("unsupported"), std::string::npos) << st.message;
  EXPECT_NE(st.message.find("hinge"), std::string::npos) << st.message;
}

TEST(MujocoPeer, PrismaticIsUnsupported) {
  auto peer = makeMujoco();
  if (!peer) GTEST_SKIP() << "MuJoCo is not compiled in";
  Scene scene = pendulum(1, 0);
  scene.joints[0].def.type = JointType::Prismatic;
  Status st = peer->build(scene, {});
  EXPECT_FALSE(st.ok());
  EXPECT_NE(st.message.find("prismatic"), std::string::npos) << st.message;
}

TEST(MujocoPeer, Pyramid40FailsWithMujocosMessage) {
  auto peer = makeMujoco();
  if (!peer) GTEST_SKIP() << "MuJoCo is not compiled in";
  Scene scene;
  ASSERT_TRUE(loadSceneFile(PHYS_SOURCE_DIR "/configs/scenes/pyramid_40.json", &scene).ok());
  Status st = peer->build(scene, {});
  EXPECT_FALSE(st.ok());
  EXPECT_NE(st.message.find("mujoco: "), std::string::npos) << st.message;
  EXPECT_NE(st.message.find("could not create mjData"), std::string::npos) << st.message;
}

}  // namespace
}  // namespace phys::peers
