// The peer runner: a scripted peer (no engine needed) checks that states reach the metrics
// unchanged, errors pass through and blow-ups count as NaN; then Bullet on pyramid_20.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <numbers>

#include "peers/peer.h"
#include "peers/peer_common.h"
#include "peers/runner.h"
#include "phys/scene/scene.h"

using namespace phys;
using namespace phys::peers;

namespace {

/// Drops every dynamic body straight down at `speed` m/s; optionally fails to build or goes
/// non-finite at some step.
class ScriptedPeer : public PeerEngine {
 public:
  float speed = 1;
  Status buildStatus;
  int nanAtStep = -1;

  std::string name() const override { return "scripted"; }
  std::string version() const override { return "1"; }
  Status build(const Scene& scene, const PeerBudget&) override {
    scene_ = &scene;
    steps_ = 0;
    return buildStatus;
  }
  void step() override { ++steps_; }
  void read(std::vector<PeerBodyState>* out) const override {
    out->clear();
    const float t = float(steps_) * scene_->world.timeStep;
    for (const BodyDef& b : scene_->bodies) {
      PeerBodyState s{b.position, b.rotation, {}, {}};
      if (b.type == BodyType::Dynamic) {
        s.position.z -= speed * t;
        s.linearVelocity = {0, 0, -speed};
        if (steps_ == nanAtStep) s.position.x = NAN;
      }
      out->push_back(s);
    }
  }

 private:
  const Scene* scene_ = nullptr;
  int steps_ = 0;
};

Scene ballScene() {
  Scene scene;
  BodyDef ball;
  ball.position = {0, 0, 10};
  ShapeDef s;
  s.geom = ShapeGeom::sphere(0.5f);
  ball.shapes.push_back(s);
  ball.linearVelocity = {0, 0, -1};  // as ScriptedPeer moves it
  scene.bodies = {ball};
  scene.criteria = {{"max_speed", std::nullopt, 2.0}};
  return scene;
}

}  // namespace

TEST(Runner, MeasuresThePeersStatesWithPhysMetrics) {
  Scene scene = ballScene();
  ScriptedPeer peer;
  PeerRun run = runPeer(scene, peer, {}, 1.0);
  ASSERT_TRUE(run.status.ok()) << run.status.message;
  EXPECT_EQ(run.engine, "scripted");
  EXPECT_TRUE(run.stopped.empty());
  EXPECT_EQ(run.summary.steps, 60);
  EXPECT_NEAR(run.summary.maxSpeed, 1.0, 1e-6);
  EXPECT_EQ(run.summary.nan, 0);
  EXPECT_GE(run.summary.msPerStepMedian, 0.0);
  // Falling at constant speed: each step loses m g dz of potential energy and gains none.
  const double mass = 1000 * 4.0 / 3 * std::numbers::pi * 0.125;
  EXPECT_LT(run.summary.energySolveDeltaMax, 1e-3 * mass);
  ASSERT_EQ(run.criteria.size(), 1u);
  EXPECT_TRUE(run.criteria[0].passed);
}

TEST(Runner, PassesTheBuildErrorThrough) {
  Scene scene = ballScene();
  ScriptedPeer peer;
  peer.buildStatus = unsupported("joints[3]: what this engine cannot do");
  PeerRun run = runPeer(scene, peer, {}, 1.0);
  EXPECT_FALSE(run.status.ok());
  EXPECT_EQ(run.status.message, "unsupported: joints[3]: what this engine cannot do");
  EXPECT_EQ(run.summary.steps, 0);
}

TEST(Runner, ABlowUpCountsAsNanAndStops) {
  Scene scene = ballScene();
  ScriptedPeer peer;
  peer.nanAtStep = 10;
  PeerRun run = runPeer(scene, peer, {}, 1.0);
  EXPECT_TRUE(run.status.ok());
  EXPECT_EQ(run.summary.steps, 9);
  EXPECT_EQ(run.summary.nan, 1);
  EXPECT_NE(run.stopped.find("step 10"), std::string::npos) << run.stopped;
}

TEST(PeerCommon, FramesRoundTrip) {
  Scene scene;
  BodyDef b;
  b.position = {1, 2, 3};
  b.rotation = Quat::fromAxisAngle({1, 1, 0}, 0.7f);
  ShapeDef s;
  s.geom = ShapeGeom::box({0.5f, 0.2f, 0.1f});
  s.local = {{0.3f, -0.2f, 0.1f}, Quat::fromAxisAngle({0, 1, 1}, 0.5f)};
  b.shapes = {s};
  scene.bodies = {b};
  std::vector<PeerBodyMass> m;
  ASSERT_TRUE(computePeerBodies(scene, &m).ok());
  ASSERT_EQ(m.size(), 1u);
  EXPECT_NEAR(m[0].comLocal.x, 0.3f, 1e-5);
  EXPECT_NEAR(m[0].comLocal.y, -0.2f, 1e-5);
  // A box's principal frame is the shape's own frame (up to axis order and sign), so the box
  // sits in the peer frame with a rotation that maps its axes onto the principal axes.
  Transform peer = toPeerPose(m[0], b.position, b.rotation);
  EXPECT_NEAR(length(peer.p - m[0].comWorld), 0, 1e-5);
  Transform back = fromPeerPose(m[0], peer.p, peer.q);
  EXPECT_NEAR(length(back.p - b.position), 0, 1e-5);
  EXPECT_NEAR(std::fabs(back.q.x * b.rotation.x + back.q.y * b.rotation.y +
                        back.q.z * b.rotation.z + back.q.w * b.rotation.w),
              1, 1e-6);
  // Principal moments of a 1 x 0.4 x 0.2 box of 80 kg.
  const double mass = 1000 * 1.0 * 0.4 * 0.2;
  EXPECT_NEAR(m[0].mass, mass, 1e-3);
  std::vector<double> moments = {m[0].principalInertia.x, m[0].principalInertia.y,
                                 m[0].principalInertia.z};
  std::sort(moments.begin(), moments.end());
  EXPECT_NEAR(moments[0], mass / 12 * (0.16 + 0.04), 1e-4);
  EXPECT_NEAR(moments[2], mass / 12 * (1 + 0.16), 1e-4);
  // A point and a direction in the body frame land where the peer frame says.
  Vec3 p{0.1f, 0.2f, 0.3f};
  Vec3 world = apply({b.position, b.rotation}, p);
  EXPECT_NEAR(length(apply(peer, pointInPeerFrame(m[0], p)) - world), 0, 1e-5);
}

TEST(Runner, BulletOnPyramid20) {
  auto peer = makePeer("bullet");
  if (!peer) GTEST_SKIP() << "Bullet is not compiled in";
  Scene scene;
  ASSERT_TRUE(loadSceneFile(PHYS_SOURCE_DIR "/configs/scenes/pyramid_20.json", &scene).ok());
  PeerRun run = runPeer(scene, *peer, {}, 1.0);
  ASSERT_TRUE(run.status.ok()) << run.status.message;
  EXPECT_EQ(run.engine, "bullet");
  EXPECT_EQ(run.summary.steps, 60);
  EXPECT_EQ(run.summary.nan, 0);
  EXPECT_GT(run.summary.msPerStepMedian, 0.0);
  // A second of settling: boxes touch (contacts measured by phys) but barely move.
  ASSERT_TRUE(run.summary.penetrationMax.has_value());
  EXPECT_LT(*run.summary.penetrationMax, 0.05);
  ASSERT_TRUE(run.summary.topDrift.has_value());
  EXPECT_LT(*run.summary.topDrift, 0.05);
  EXPECT_EQ(run.criteria.size(), scene.criteria.size());
}
