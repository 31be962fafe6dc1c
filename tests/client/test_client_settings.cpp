// World settings and definitions through the SDK (issue 40, points 2 and 3):
// WorldHandle::setWorld / setGravity / setTimeStep / setSleep change a world (a gravity change
// wakes a sleeping pile), settings() and getBodies / getJoints / allBodies / allJoints read
// back what the world simulates, the same after an engine snapshot restore and after the
// physd binary is killed and started again on its data directory.
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <sstream>
#include <thread>

#include "../common/bodies.h"
#include "../common/defs_compare.h"
#include "../common/sanitizer.h"
#include "phys/client/client.h"
#include "phys/server/core.h"
#include "phys/server/endpoint.h"
#include "in_process_daemon.h"
#include "physd_process.h"

namespace phys::client {
namespace {

using namespace std::chrono_literals;
constexpr auto kTimeout = std::chrono::milliseconds(int64_t(20000 * test::kTimeFactor));

ClientOptions options(std::string name) {
  return testing::inProcessOptions(std::move(name));
}

using Daemon = testing::InProcessDaemon;

template <class F>
ErrorCode codeOf(F&& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.code();
  }
  return ErrorCode::Ok;
}

/// Bodies with something other than the default in each definition field, and a joint.
std::vector<phys::BodyDef> scenery() {
  // The ground, the crate (every body setting given; a capsule beside its box) and the ball of
  // test::everyKindScenery().
  const std::vector<phys::BodyDef> all = test::everyKindScenery().bodies;
  return {all[0], all[1], all[2]};
}

phys::JointDef hinge(uint64_t a, uint64_t b) {
  phys::JointDef j;
  j.type = phys::JointType::Hinge;
  j.bodyA = phys::BodyId::fromPacked(a);
  j.bodyB = phys::BodyId::fromPacked(b);
  j.anchorA = {1, 0, 0};
  j.anchorB = {-1, 0, 0};
  j.axisA = j.axisB = {0, 1, 0};
  j.enableMotor = true;
  j.motorSpeed = 0.5f;
  j.maxMotorForce = 20;
  j.name = "hinge";
  return j;
}

void expectScenery(const std::vector<BodyInfo>& got, const std::vector<JointInfo>& joints,
                   const std::string& when) {
  SCOPED_TRACE(when);
  const std::vector<phys::BodyDef> want = scenery();
  ASSERT_EQ(got.size(), want.size());
  for (size_t i = 0; i < want.size(); ++i)
    test::expectSameDefinition(want[i], got[i].def, want[i].name);
  EXPECT_EQ(got[1].mass.mass, 7);
  EXPECT_NEAR(got[2].mass.mass, 1500 * 4.0f / 3 * phys::kPi * 0.027f, 0.01f);
  ASSERT_EQ(joints.size(), 1u);
  EXPECT_EQ(joints[0].def.name, "hinge");
  EXPECT_EQ(joints[0].def.type, phys::JointType::Hinge);
  EXPECT_EQ(joints[0].def.maxMotorForce, 20);
  EXPECT_EQ(joints[0].def.bodyA.packed(), got[1].id);
  EXPECT_EQ(joints[0].def.bodyB.packed(), got[2].id);
}

/// test::everyKindScenery() spawned into a world: the bodies' ids, in the scenery's order.
std::vector<uint64_t> spawnEveryKind(WorldHandle& w, const test::Scenery& s) {
  std::vector<uint64_t> ids = w.spawn(s.bodies).get();
  std::vector<phys::JointDef> joints = s.joints;
  for (size_t i = 0; i < joints.size(); ++i) {
    auto [a, b] = s.ends[i];
    if (a >= 0) joints[i].bodyA = phys::BodyId::fromPacked(ids[size_t(a)]);
    if (b >= 0) joints[i].bodyB = phys::BodyId::fromPacked(ids[size_t(b)]);
  }
  w.addJoints(joints).get();
  return ids;
}

/// What a world reports is the scenery, every field of every body, shape and joint (the
/// bodies in spawn order, each joint between the bodies it was made with).
void expectEveryKind(WorldHandle& w, const test::Scenery& s, const std::string& when) {
  SCOPED_TRACE(when);
  const std::vector<BodyInfo> bodies = w.allBodies().get();
  ASSERT_EQ(bodies.size(), s.bodies.size());
  for (size_t i = 0; i < bodies.size(); ++i)
    test::expectSameDefinition(s.bodies[i], bodies[i].def, s.bodies[i].name);
  const std::vector<JointInfo> joints = w.allJoints().get();
  ASSERT_EQ(joints.size(), s.joints.size());
  for (size_t i = 0; i < joints.size(); ++i) {
    test::expectSameJoint(s.joints[i], joints[i].def);
    auto [a, b] = s.ends[i];
    EXPECT_EQ(joints[i].def.bodyA.packed(), a >= 0 ? bodies[size_t(a)].id : 0u) << s.joints[i].name;
    EXPECT_EQ(joints[i].def.bodyB.packed(), b >= 0 ? bodies[size_t(b)].id : 0u) << s.joints[i].name;
  }
}

TEST(ClientSettings, SettingsAndDefinitionsThroughTheSdk) {
  Daemon d;
  Client c(options("settings"));
  c.connect();
  WorldHandle w = c.createWorld({"settings", "", std::nullopt, 0}).get();
  std::vector<uint64_t> ids = w.spawn(scenery()).get();
  w.addJoints(std::vector<phys::JointDef>{hinge(ids[1], ids[2])}).get();

  // Settings: one at a time and several at once; settings() reads them back.
  w.setGravity({0, 0, -1.62f}).get();
  w.setTimeStep(1.0f / 120).get();
  w.setSleep({true, 1.5f, 0.02f, 0.3f}).get();
  WorldOverrides more;
  more.maxLinearSpeed = 300;
  more.aabbMargin = 0.08f;
  more.guardRetries = 1;
  w.setWorld(more).get();
  WorldSettings s = w.settings().get();
  EXPECT_EQ(s.def.gravity.z, -1.62f);
  EXPECT_EQ(s.def.timeStep, 1.0f / 120);
  EXPECT_TRUE(s.def.sleep.enabled);
  EXPECT_EQ(s.def.sleep.time, 1.5f);
  EXPECT_EQ(s.def.sleep.linearSpeed, 0.02f);
  EXPECT_EQ(s.def.sleep.angularSpeed, 0.3f);
  EXPECT_EQ(s.def.maxLinearSpeed, 300);
  EXPECT_EQ(s.def.aabbMargin, 0.08f);
  EXPECT_EQ(s.def.guardRetries, 1);
  EXPECT_FALSE(s.preset.empty());
  EXPECT_GT(s.def.solver.iterations, 0);

  // Bad values: typed errors, nothing changed.
  EXPECT_EQ(codeOf([&] { w.setGravity({0, 0, std::numeric_limits<float>::quiet_NaN()}).get(); }),
            ErrorCode::InvalidArgument);
  EXPECT_EQ(codeOf([&] { w.setTimeStep(0).get(); }), ErrorCode::InvalidArgument);
  EXPECT_EQ(codeOf([&] { w.setWorld({}).get(); }), ErrorCode::InvalidArgument);
  EXPECT_EQ(w.settings().get().def.gravity.z, -1.62f);

  // Definitions: pages, ids, all of them.
  BodiesPage page = w.getBodies({}, 1, 1).get();
  EXPECT_EQ(page.total, 3u);
  ASSERT_EQ(page.bodies.size(), 1u);
  EXPECT_EQ(page.bodies[0].def.name, "crate");
  page = w.getBodies(std::vector<uint64_t>{ids[2]}).get();
  ASSERT_EQ(page.bodies.size(), 1u);
  EXPECT_EQ(page.bodies[0].def.name, "ball");
  expectScenery(w.allBodies().get(), w.allJoints().get(), "as spawned");
  EXPECT_EQ(codeOf([&] { w.getBodies(std::vector<uint64_t>{0x99900000001}).get(); }),
            ErrorCode::NotFound);

  // Another client reads but may not change the world.
  Client other(options("other"));
  other.connect();
  WorldHandle ow = other.world(w.id());
  EXPECT_EQ(codeOf([&] { ow.setGravity({0, 0, -3}).get(); }), ErrorCode::PermissionDenied);
  EXPECT_EQ(ow.allBodies().get().size(), 3u);
  EXPECT_EQ(ow.settings().get().def.gravity.z, -1.62f);

  // An engine snapshot restored into another world: every definition and setting.
  Bytes snap = w.saveSnapshot().get();
  WorldHandle w2 = c.createWorld({"restored", "", std::nullopt, 0}).get();
  w2.restoreSnapshot(snap).get();
  expectScenery(w2.allBodies().get(), w2.allJoints().get(), "after an engine snapshot restore");
  EXPECT_EQ(w2.settings().get().def.maxLinearSpeed, 300);
  EXPECT_EQ(w2.settings().get().def.gravity.z, -1.62f);
}

TEST(ClientSettings, AGravityChangeWakesASleepingPile) {
  Daemon d;
  Client c(options("pile"));
  c.connect();
  WorldHandle w = c.createWorld({"pile", "", std::nullopt, 0}).get();
  std::vector<phys::BodyDef> defs{phys::test::groundBody()};
  for (int i = 0; i < 3; ++i) defs.push_back(phys::test::boxBody({0, 0, 0.5f + float(i)}));
  std::vector<uint64_t> ids = w.spawn(defs).get();
  auto summary = [&] {
    for (const WorldSummary& s : c.listWorlds().get())
      if (s.world == w.id()) return s;
    return WorldSummary{};
  };
  for (int i = 0; i < 20 && summary().sleepingBodies < 3; ++i) w.step(30).get();
  ASSERT_EQ(summary().sleepingBodies, 3u) << "the pile did not fall asleep";
  const float x0 = w.queryState(std::vector<uint64_t>{ids[3]}).get().bodies.at(0).position.x;
  w.setGravity({9.81f, 0, -9.81f}).get();
  EXPECT_EQ(summary().sleepingBodies, 0u);
  EXPECT_EQ(summary().awakeBodies, 3u);
  w.step(60).get();
  EXPECT_GT(w.queryState(std::vector<uint64_t>{ids[3]}).get().bodies.at(0).position.x, x0 + 0.2f);
}

TEST(ClientSettings, EverySettingAndEveryKindOfDefinitionSurviveAKilledDaemonAndASnapshot) {
  testing::ScratchDir dir("physd-settings");
  const std::string data = (dir.path / "data").string();
  testing::PhysdConfig cfg(dir.path, "physd-settings", 200 + uint32_t(getpid() % 29),
                           "data = \"" + data + "\"\n");
  Client c(cfg.clientOptions(20s));
  pid_t pid = testing::spawnProcess(PHYSD_BINARY, {"--config", cfg.toml});
  testing::ProcessGuard guard{pid};
  ASSERT_GT(pid, 0);
  c.connect();
  WorldHandle w = c.createWorld({"kept", "", std::nullopt, 0}).get();
  const test::Scenery every = test::everyKindScenery();
  spawnEveryKind(w, every);
  expectEveryKind(w, every, "as spawned");
  w.step(5).get();
  // An engine snapshot, restored after the restart into a world that never had the bodies.
  const Bytes snap = w.saveSnapshot().get();
  WorldOverrides o;
  o.gravity = phys::Vec3{0.5f, 0, -4};
  o.sleepTime = 2.5f;
  o.maxAngularSpeed = 120;
  o.guard = false;
  w.setWorld(o).get();
  ASSERT_EQ(kill(pid, SIGKILL), 0);
  int st = 0;
  ASSERT_EQ(waitpid(pid, &st, 0), pid);
  guard.pid = pid = testing::spawnProcess(PHYSD_BINARY, {"--config", cfg.toml});
  ASSERT_GT(pid, 0);
  ASSERT_TRUE(testing::awaitReconnects(c, 1));
  expectEveryKind(w, every, "after a restart");
  WorldHandle w2 = c.createWorld({"restored", "", std::nullopt, 0}).get();
  w2.restoreSnapshot(snap).get();
  expectEveryKind(w2, every, "restored from a snapshot after a restart");
  WorldSettings s = w.settings().get();
  EXPECT_TRUE(s.def.gravity == *o.gravity);
  EXPECT_EQ(s.def.sleep.time, 2.5f);
  EXPECT_EQ(s.def.maxAngularSpeed, 120);
  EXPECT_FALSE(s.def.guard);
}

#ifdef PHYSCTL_BINARY
using testing::shq;

std::pair<int, std::string> shell(const std::string& line) {
  testing::Shell r = testing::shell(line);
  return {r.code, r.output};
}

TEST(ClientSettings, PhysctlSetsSettingsAndPrintsDefinitions) {
  // A start-up world (no owner: any client may change it) of a scene with names and joints.
  testing::ScratchDir dir("physctl-settings");
  testing::PhysdConfig cfg(dir.path, "physctl-settings", 200 + uint32_t(getpid() % 29),
                           "[[worlds]]\nname = \"chain\"\nscene = \"ball_and_chain\"\n"
                           "ephemeral = true\n");
  pid_t pid = testing::spawnProcess(PHYSD_BINARY, {"--config", cfg.toml});
  testing::ProcessGuard guard{pid};
  ASSERT_GT(pid, 0);
  Client c(cfg.clientOptions(20s));
  c.connect();
  const std::string physctl = shq(PHYSCTL_BINARY) + " --domain " + std::to_string(cfg.domain) +
                              " --config " + shq(cfg.xml) + " ";
  auto [code, out] = shell(physctl + "set chain --gravity 0,0,-1.62 --sleep on --guard-retries 3");
  ASSERT_EQ(code, 0) << out;
  std::tie(code, out) = shell(physctl + "settings chain");
  ASSERT_EQ(code, 0) << out;
  EXPECT_NE(out.find("gravity (0, 0, -1.62)"), std::string::npos) << out;
  EXPECT_NE(out.find("sleep on"), std::string::npos) << out;
  EXPECT_NE(out.find("guard_retries 3"), std::string::npos) << out;
  // Refused values: the server's message, exit 1.
  std::tie(code, out) = shell(physctl + "set chain --time-step 0");
  EXPECT_EQ(code, 1);
  EXPECT_NE(out.find("InvalidArgument: set_world.settings.time_step"), std::string::npos) << out;
  std::tie(code, out) = shell(physctl + "bodies chain");
  ASSERT_EQ(code, 0) << out;
  EXPECT_NE(out.find("\"ground\" static"), std::string::npos) << out;
  EXPECT_NE(out.find("\"chain/0\" dynamic mass 1 kg (given)"), std::string::npos) << out;
  EXPECT_NE(out.find("capsule radius 0.05 half_height 0.25"), std::string::npos) << out;
  std::tie(code, out) = shell(physctl + "joints chain");
  ASSERT_EQ(code, 0) << out;
  EXPECT_NE(out.find("\"chain/joint/1\" ball"), std::string::npos) << out;
  std::tie(code, out) = shell(physctl + "bodies chain 0x100000001");
  ASSERT_EQ(code, 0) << out;
  EXPECT_NE(out.find("chain/0"), std::string::npos) << out;
  EXPECT_EQ(out.find("ground"), std::string::npos) << out;
}
#endif

}  // namespace
}  // namespace phys::client
