// World settings as commands and definitions read back (issue 40, points 2 and 3): SetWorld
// changes gravity, the time step, sleeping and the rest of what a living world may change,
// validated, all or nothing, access-checked and journaled like any edit, waking what each
// change affects; GetWorld, GetBodies and GetJoints read what the world simulates from the
// engine, paged and bounded, the same after an engine snapshot, a portable snapshot and a
// restart.
#include <cmath>
#include <filesystem>
#include <limits>
#include <map>

#include "flatbuffers/flatbuffers.h"
#include "../common/defs_compare.h"
#include "server_test_util.h"

namespace phys::server::test {
namespace {

namespace fs = std::filesystem;
using phys::test::expectSameDefinition;
using phys::test::expectSameJoint;
using protocol::CommandBuilder;
using protocol::WorldOverrides;

constexpr uint64_t kOther = 0x0B;

using Client = CoreClient;

uint32_t createWorld(Client& c, const std::string& name) {
  Reply r = c.send(CommandBuilder().createWorld({name, "", std::nullopt, 0}), 0);
  EXPECT_EQ(r->status(), Code::Ok) << message(r);
  return r->world();
}

/// GetWorld's settings as a WorldDef (threads, backend and the contact budget: defaults).
phys::WorldDef settingsOf(Client& c, uint32_t world, std::string* preset = nullptr) {
  Reply r = c.send(CommandBuilder().getWorld(), world);
  EXPECT_EQ(r->status(), Code::Ok) << message(r);
  phys::WorldDef d;
  auto* s = r->result_as_WorldSettingsResult();
  EXPECT_TRUE(s && s->settings() && s->solver());
  if (!s || !s->settings() || !s->solver()) return d;
  protocol::applyOverrides(protocol::toOverrides(*s->settings()), &d);
  protocol::applySolverSettings(*s->solver(), &d.solver);
  if (preset) *preset = s->preset() ? s->preset()->str() : "";
  return d;
}

/// Every body's definition, all pages of GetBodies.
std::vector<protocol::BodyInfo> allBodies(Client& c, uint32_t world, uint32_t maxCount = 0,
                                          int* pages = nullptr) {
  std::vector<protocol::BodyInfo> out;
  for (int page = 1;; ++page) {
    Reply r = c.send(CommandBuilder().getBodies({}, uint32_t(out.size()), maxCount), world);
    EXPECT_EQ(r->status(), Code::Ok) << message(r);
    auto* b = r->result_as_BodiesResult();
    if (!b || !b->bodies() || b->bodies()->size() == 0) break;
    for (uint32_t i = 0; i < b->bodies()->size(); ++i) {
      protocol::BodyInfo info;
      Status st = protocol::toBodyInfo(*b->bodies()->Get(i), &info);
      EXPECT_TRUE(st.ok()) << st.message;
      out.push_back(std::move(info));
    }
    if (pages) *pages = page;
    if (out.size() >= b->total()) break;
  }
  return out;
}

std::vector<protocol::JointEntry> allJoints(Client& c, uint32_t world) {
  std::vector<protocol::JointEntry> out;
  for (;;) {
    Reply r = c.send(CommandBuilder().getJoints({}, uint32_t(out.size())), world);
    EXPECT_EQ(r->status(), Code::Ok) << message(r);
    auto* j = r->result_as_JointsResult();
    if (!j || !j->joints() || j->joints()->size() == 0) break;
    for (auto* e : *j->joints()) out.push_back({e->id(), protocol::toJointDef(*e->def())});
    if (out.size() >= j->total()) break;
  }
  return out;
}

/// Settings other than the defaults in every field SetWorld takes.
WorldOverrides someSettings() {
  WorldOverrides o;
  o.gravity = phys::Vec3{0.5f, -1, -3.7f};
  o.timeStep = 1.0f / 120;
  o.sleep = true;
  o.sleepTime = 1.25f;
  o.sleepLinearSpeed = 0.02f;
  o.sleepAngularSpeed = 0.25f;
  o.maxLinearSpeed = 300;
  o.maxAngularSpeed = 150;
  o.speculativeDistance = 0.03f;
  o.aabbMargin = 0.08f;
  o.guard = false;
  o.guardEnergyJump = 0.75f;
  o.guardRetries = 3;
  return o;
}

void expectSettings(const phys::WorldDef& d, const WorldOverrides& o) {
  EXPECT_TRUE(d.gravity == *o.gravity);
  EXPECT_EQ(d.timeStep, *o.timeStep);
  EXPECT_EQ(d.sleep.enabled, *o.sleep);
  EXPECT_EQ(d.sleep.time, *o.sleepTime);
  EXPECT_EQ(d.sleep.linearSpeed, *o.sleepLinearSpeed);
  EXPECT_EQ(d.sleep.angularSpeed, *o.sleepAngularSpeed);
  EXPECT_EQ(d.maxLinearSpeed, *o.maxLinearSpeed);
  EXPECT_EQ(d.maxAngularSpeed, *o.maxAngularSpeed);
  EXPECT_EQ(d.speculativeDistance, *o.speculativeDistance);
  EXPECT_EQ(d.aabbMargin, *o.aabbMargin);
  EXPECT_EQ(d.guard, *o.guard);
  EXPECT_EQ(d.guardEnergyJump, *o.guardEnergyJump);
  EXPECT_EQ(d.guardRetries, *o.guardRetries);
}

/// Bodies with something other than the default in every definition field, and two joints.
using phys::test::Scenery;
Scenery scenery() { return phys::test::everyKindScenery(); }

/// Spawns the scenery; returns the bodies' ids and the joints'.
std::pair<std::vector<uint64_t>, std::vector<uint64_t>> spawnScenery(Client& c, uint32_t world,
                                                                     const Scenery& s) {
  Reply r = c.send(CommandBuilder().spawnBodies(s.bodies), world);
  EXPECT_EQ(r->status(), Code::Ok) << message(r);
  std::vector<uint64_t> bodies = bodyIds(r);
  std::vector<phys::JointDef> joints = s.joints;
  for (size_t i = 0; i < joints.size(); ++i) {
    auto map = [&](int k) {
      return k < 0 ? phys::BodyId{} : phys::BodyId::fromPacked(bodies.at(size_t(k)));
    };
    joints[i].bodyA = map(s.ends[i].first);
    joints[i].bodyB = map(s.ends[i].second);
  }
  r = c.send(CommandBuilder().addJoints(joints), world);
  EXPECT_EQ(r->status(), Code::Ok) << message(r);
  return {bodies, jointIds(r)};
}

/// The scenery's definitions read back: every field as spawned.
void expectScenery(Client& c, uint32_t world, const Scenery& s, const std::string& when) {
  SCOPED_TRACE(when);
  std::vector<protocol::BodyInfo> got = allBodies(c, world);
  ASSERT_EQ(got.size(), s.bodies.size());
  for (size_t i = 0; i < got.size(); ++i)
    expectSameDefinition(s.bodies[i], got[i].def, "body " + std::to_string(i));
  EXPECT_EQ(got[1].mass.mass, 7);
  EXPECT_NEAR(got[2].mass.mass, 1500 * 4.0f / 3 * phys::kPi * 0.027f, 0.01f);
  std::vector<protocol::JointEntry> joints = allJoints(c, world);
  ASSERT_EQ(joints.size(), s.joints.size());
  for (size_t i = 0; i < joints.size(); ++i) {
    expectSameJoint(s.joints[i], joints[i].def);
    EXPECT_EQ(joints[i].def.bodyB.packed(), got.at(size_t(s.ends[i].second)).id);
    EXPECT_EQ(joints[i].def.bodyA.packed(),
              s.ends[i].first < 0 ? 0 : got.at(size_t(s.ends[i].first)).id);
  }
}

/// World info's bodies, by id (its first chunk: small worlds).
std::map<uint64_t, phys::BodyDef> worldInfoBodies(ServerCore& core, uint32_t world) {
  core.world(world)->infoDirty = true;
  core.publishWorldInfo();
  std::map<uint64_t, phys::BodyDef> out;
  for (;;) {
    auto item = core.out().pop(std::chrono::milliseconds(0));
    if (!item.reliable && !item.frame) break;
    if (!item.reliable || item.reliable->type != ReliableMessage::Type::WorldInfo ||
        item.reliable->world != world)
      continue;
    out.clear();
    auto wi = protocol::decodeWorldInfo(std::move(item.reliable->chunks.at(0)));
    EXPECT_TRUE(wi.ok()) << wi.status.message;
    if (!wi.ok() || !wi->bodies()) continue;
    for (auto* e : *wi->bodies()) {
      phys::BodyDef d;
      EXPECT_TRUE(protocol::toBodyDef(*e->def(), &d).ok());
      out[e->id()] = d;
    }
  }
  return out;
}

class SettingsTest : public ::testing::Test {
 protected:
  void SetUp() override {
    ASSERT_TRUE(core.init().ok());
    world = createWorld(c, "w");
  }
  void TearDown() override {
    std::error_code ec;
    fs::remove_all(core.config().snapshotDir, ec);
  }
  phys::World& engine() { return *core.world(world)->world; }
  /// What must not change after a refused command: the engine's whole state.
  std::vector<uint8_t> state() {
    std::vector<uint8_t> b;
    EXPECT_TRUE(engine().saveSnapshot(&b).ok());
    return b;
  }

  ServerCore core{testConfig()};
  Client c{&core};
  uint32_t world = 0;
};

TEST_F(SettingsTest, SetWorldChangesEverySettingAndGetWorldReadsThemBack) {
  const WorldOverrides o = someSettings();
  Reply r = c.send(CommandBuilder().setWorld(o), world);
  ASSERT_EQ(r->status(), Code::Ok) << message(r);
  expectSettings(engine().def(), o);
  std::string preset;
  const phys::WorldDef got = settingsOf(c, world, &preset);
  expectSettings(got, o);
  EXPECT_EQ(preset, core.world(world)->preset);
  EXPECT_EQ(got.solver.iterations, engine().def().solver.iterations);
  // A field left out keeps its value.
  WorldOverrides one;
  one.gravity = phys::Vec3{0, 0, -1.62f};
  ASSERT_EQ(c.send(CommandBuilder().setWorld(one), world)->status(), Code::Ok);
  EXPECT_EQ(engine().def().gravity.z, -1.62f);
  EXPECT_EQ(engine().def().timeStep, *o.timeStep);
  EXPECT_EQ(engine().def().guardRetries, *o.guardRetries);
  // World info carries the new gravity and time step.
  core.publishWorldInfo();
  bool info = false;
  for (;;) {
    auto item = core.out().pop(std::chrono::milliseconds(0));
    if (!item.reliable && !item.frame) break;
    if (!item.reliable || item.reliable->type != ReliableMessage::Type::WorldInfo) continue;
    auto wi = protocol::decodeWorldInfo(std::move(item.reliable->chunks.at(0)));
    ASSERT_TRUE(wi.ok());
    EXPECT_EQ(wi->gravity()->z(), -1.62f);
    EXPECT_EQ(wi->time_step(), *o.timeStep);
    info = true;
  }
  EXPECT_TRUE(info);
}

TEST_F(SettingsTest, AGravityChangeWakesASleepingPyramid) {
  // A pyramid of boxes (rows of 3, 2, 1) at rest, asleep.
  std::vector<phys::BodyDef> defs{groundBody()};
  for (int row = 0; row < 3; ++row)
    for (int i = 0; i < 3 - row; ++i)
      defs.push_back(boxBody({float(i) * 1.02f + 0.51f * float(row) - 1.02f, 0,
                              0.5f + 1.0f * float(row)}));
  Reply r = c.send(CommandBuilder().spawnBodies(defs), world);
  ASSERT_EQ(r->status(), Code::Ok) << message(r);
  const std::vector<uint64_t> ids = bodyIds(r);
  for (int i = 0; i < 20 && engine().awakeBodyCount() > 0; ++i)
    ASSERT_EQ(c.send(CommandBuilder().step(30), world)->status(), Code::Ok);
  ASSERT_EQ(engine().awakeBodyCount(), 0) << "the pyramid did not fall asleep";
  ASSERT_EQ(core.summaries().at(0).sleepingBodies, 6u);

  // Gravity pulls sideways now, past what friction holds: every body is awake at once and
  // the pyramid slides away.
  WorldOverrides o;
  o.gravity = phys::Vec3{9.81f, 0, -9.81f};
  ASSERT_EQ(c.send(CommandBuilder().setWorld(o), world)->status(), Code::Ok);
  EXPECT_EQ(engine().awakeBodyCount(), 6);
  EXPECT_EQ(core.summaries().at(0).sleepingBodies, 0u);
  EXPECT_EQ(core.summaries().at(0).awakeBodies, 6u);
  phys::BodyState top;
  ASSERT_TRUE(engine().getBody(phys::BodyId::fromPacked(ids.back()), &top).ok());
  ASSERT_EQ(c.send(CommandBuilder().step(60), world)->status(), Code::Ok);
  phys::BodyState later;
  ASSERT_TRUE(engine().getBody(phys::BodyId::fromPacked(ids.back()), &later).ok());
  EXPECT_GT(later.position.x, top.position.x + 0.2f);
}

TEST_F(SettingsTest, SetWorldIsValidatedAndARefusedOneChangesNothing) {
  ASSERT_EQ(c.send(CommandBuilder().spawnBodies(std::vector<phys::BodyDef>{
                       groundBody(), boxBody({0, 0, 2})}),
                   world)
                ->status(),
            Code::Ok);
  ASSERT_EQ(c.send(CommandBuilder().step(3), world)->status(), Code::Ok);
  const std::vector<uint8_t> before = state();
  const float nan = std::numeric_limits<float>::quiet_NaN();
  struct Case {
    const char* what;
    WorldOverrides o;
  };
  std::vector<Case> cases;
  auto add = [&](const char* what, auto edit) {
    WorldOverrides o;
    o.gravity = phys::Vec3{0, 0, -1};  // a valid change beside the bad one: not applied either
    edit(o);
    cases.push_back({what, o});
  };
  add("gravity", [&](WorldOverrides& o) { o.gravity = phys::Vec3{nan, 0, 0}; });
  add("gravity", [&](WorldOverrides& o) { o.gravity = phys::Vec3{0, 0, -1e5f}; });
  add("time_step", [&](WorldOverrides& o) { o.timeStep = 0; });
  add("time_step", [&](WorldOverrides& o) { o.timeStep = 2; });
  add("sleep_time", [&](WorldOverrides& o) { o.sleepTime = 0; });
  add("sleep_linear_speed", [&](WorldOverrides& o) { o.sleepLinearSpeed = -1; });
  add("max_linear_speed", [&](WorldOverrides& o) { o.maxLinearSpeed = 1e9f; });
  add("max_angular_speed", [&](WorldOverrides& o) { o.maxAngularSpeed = 0; });
  add("speculative_distance", [&](WorldOverrides& o) { o.speculativeDistance = -0.1f; });
  add("aabb_margin", [&](WorldOverrides& o) { o.aabbMargin = 100; });
  add("guard_energy_jump", [&](WorldOverrides& o) { o.guardEnergyJump = nan; });
  add("guard_retries", [&](WorldOverrides& o) { o.guardRetries = 9; });
  for (const Case& k : cases) {
    Reply r = c.send(CommandBuilder().setWorld(k.o), world);
    EXPECT_EQ(r->status(), Code::InvalidArgument) << k.what;
    EXPECT_NE(message(r).find(k.what), std::string::npos) << message(r);
    EXPECT_EQ(state(), before) << k.what;
  }
  // Nothing to set.
  Reply r = c.send(CommandBuilder().setWorld({}), world);
  EXPECT_EQ(r->status(), Code::InvalidArgument) << message(r);
  // The server checks again what a command applied without the codec carries.
  CommandBuilder b;
  WorldOverrides bad;
  bad.gravity = phys::Vec3{0, nan, 0};
  protocol::Bytes bytes = b.setWorld(bad).finish({kClient, 99, world});
  r = decode(core.apply(*flatbuffers::GetRoot<wire::Command>(bytes.data()), kClient));
  EXPECT_EQ(r->status(), Code::InvalidArgument) << message(r);
  EXPECT_EQ(state(), before);
}

TEST_F(SettingsTest, SetWorldInABatchIsAllOrNothing) {
  const phys::Vec3 g = engine().def().gravity;
  WorldOverrides o;
  o.gravity = phys::Vec3{0, 0, -3};
  CommandBuilder b;
  b.setWorld(o).removeBodies(std::vector<uint64_t>{0x77700000001});  // not a body
  EXPECT_EQ(c.send(b, world)->status(), Code::NotFound);
  EXPECT_TRUE(engine().def().gravity == g);
  b.setWorld(o).spawnBodies(std::vector<phys::BodyDef>{boxBody({0, 0, 1})});
  ASSERT_EQ(c.send(b, world)->status(), Code::Ok);
  EXPECT_EQ(engine().def().gravity.z, -3);
  EXPECT_EQ(engine().bodyCount(), 1);
}

TEST_F(SettingsTest, SetWorldIsAnEditTheReadsAreOpen) {
  Client other{&core, kOther};
  const std::vector<uint8_t> before = state();
  WorldOverrides o;
  o.timeStep = 0.01f;
  Reply r = other.send(CommandBuilder().setWorld(o), world);
  EXPECT_EQ(r->status(), Code::PermissionDenied) << message(r);
  EXPECT_NE(message(r).find("set_world"), std::string::npos) << message(r);
  EXPECT_EQ(state(), before);
  // Reads need no access.
  EXPECT_EQ(other.send(CommandBuilder().getWorld(), world)->status(), Code::Ok);
  EXPECT_EQ(other.send(CommandBuilder().getBodies(), world)->status(), Code::Ok);
  EXPECT_EQ(other.send(CommandBuilder().getJoints(), world)->status(), Code::Ok);
  // An editor may.
  ASSERT_EQ(c.send(CommandBuilder().setAccess(std::vector<uint64_t>{kOther}, false), world)->status(),
            Code::Ok);
  EXPECT_EQ(other.send(CommandBuilder().setWorld(o), world)->status(), Code::Ok);
  EXPECT_EQ(engine().def().timeStep, 0.01f);
}

TEST_F(SettingsTest, GetBodiesAndGetJointsReturnWhatTheWorldSimulates) {
  const Scenery s = scenery();
  auto [bodies, joints] = spawnScenery(c, world, s);
  expectScenery(c, world, s, "as spawned");
  // A material set later is what the definition says.
  ASSERT_EQ(c.send(CommandBuilder().setMaterial(std::vector<uint64_t>{bodies[2]}, {0.1f, 0.9f, 800}),
                   world)
                ->status(),
            Code::Ok);
  Reply r = c.send(CommandBuilder().getBodies(std::vector<uint64_t>{bodies[2], bodies[0], bodies[2]}),
                   world);
  ASSERT_EQ(r->status(), Code::Ok) << message(r);
  auto* b = r->result_as_BodiesResult();
  ASSERT_TRUE(b && b->bodies());
  EXPECT_EQ(b->total(), 3u);
  ASSERT_EQ(b->bodies()->size(), 3u);
  EXPECT_EQ(b->bodies()->Get(0)->id(), bodies[2]);
  EXPECT_EQ(b->bodies()->Get(1)->def()->name()->str(), "ground");
  EXPECT_EQ(b->bodies()->Get(2)->def()->shapes()->Get(0)->material()->restitution(), 0.9f);
  // Poses and velocities are the world's now.
  ASSERT_EQ(c.send(CommandBuilder().step(10), world)->status(), Code::Ok);
  r = c.send(CommandBuilder().getBodies(std::vector<uint64_t>{bodies[2]}), world);
  phys::BodyState st;
  ASSERT_TRUE(engine().getBody(phys::BodyId::fromPacked(bodies[2]), &st).ok());
  EXPECT_EQ(r->tick(), core.world(world)->tick);
  EXPECT_EQ(r->result_as_BodiesResult()->bodies()->Get(0)->def()->pose()->position().z(),
            st.position.z);
  // Stale ids are refused: NotFound, naming the id.
  ASSERT_EQ(c.send(CommandBuilder().removeJoints(std::vector<uint64_t>{joints[0]}), world)->status(),
            Code::Ok);
  r = c.send(CommandBuilder().getJoints(std::vector<uint64_t>{joints[1], joints[0]}), world);
  EXPECT_EQ(r->status(), Code::NotFound) << message(r);
  EXPECT_NE(message(r).find("get_joints.joints[1]"), std::string::npos) << message(r);
  r = c.send(CommandBuilder().getBodies(std::vector<uint64_t>{0x99900000001}), world);
  EXPECT_EQ(r->status(), Code::NotFound) << message(r);
}

TEST_F(SettingsTest, GetBodiesIsPagedAndBounded) {
  // A small message cap: a page holds what fits, and never more than one message.
  ServerCore small([] {
    CoreConfig cfg = testConfig();
    cfg.limits.maxMessageBytes = 64 << 10;
    return cfg;
  }());
  ASSERT_TRUE(small.init().ok());
  Client sc{&small};
  const uint32_t w = createWorld(sc, "paged");
  // 300 hull bodies of 40 points each (about 500 bytes each encoded) and 100 spheres.
  std::vector<phys::Vec3> points;
  for (int i = 0; i < 40; ++i) {
    const float a = 0.7f * float(i), z = -0.5f + float(i) / 39.0f;
    const float r = 0.5f * std::sqrt(1 - 4 * z * z) + 0.01f;
    points.push_back({r * std::cos(a), r * std::sin(a), z});
  }
  auto hull = phys::buildConvexHull(points, nullptr);
  ASSERT_TRUE(hull);
  std::vector<phys::BodyDef> defs;
  for (int i = 0; i < 300; ++i) {
    phys::BodyDef d;
    d.position = {float(i % 20) * 2, float(i / 20) * 2, 1};
    phys::ShapeDef s;
    s.geom = phys::ShapeGeom::convexHull(hull);
    d.shapes.push_back(s);
    d.name = "hull" + std::to_string(i);
    defs.push_back(d);
  }
  for (int i = 0; i < 100; ++i)
    defs.push_back(phys::test::sphereBody({float(i) * 2, -10, 1}, 0.5f));
  for (size_t at = 0; at < defs.size(); at += 50) {
    std::vector<phys::BodyDef> part(defs.begin() + long(at), defs.begin() + long(at + 50));
    ASSERT_EQ(sc.send(CommandBuilder().spawnBodies(part), w)->status(), Code::Ok);
  }
  int pages = 0;
  std::vector<protocol::BodyInfo> got = allBodies(sc, w, 0, &pages);
  ASSERT_EQ(got.size(), defs.size());
  EXPECT_GT(pages, 2);
  for (size_t i = 0; i < got.size(); ++i) ASSERT_EQ(got[i].def.name, defs[i].name);
  // Each reply within the cap (decoded with the daemon's limits).
  for (uint32_t first = 0; first < defs.size();) {
    protocol::Bytes bytes = small.applyBytes(
        CommandBuilder().getBodies({}, first).finish({kClient, 1000 + first, w}), kClient,
        1000 + first);
    EXPECT_LE(bytes.size(), small.config().limits.maxMessageBytes);
    Reply r = protocol::decodeReply(std::move(bytes), small.config().limits);
    ASSERT_TRUE(r.ok()) << r.status.message;
    const uint32_t n = r->result_as_BodiesResult()->bodies()->size();
    ASSERT_GT(n, 0u);
    EXPECT_EQ(r->result_as_BodiesResult()->total(), defs.size());
    first += n;
  }
  // max_count bounds a page; past the end a page is empty.
  Reply r = sc.send(CommandBuilder().getBodies({}, 5, 7), w);
  ASSERT_EQ(r->result_as_BodiesResult()->bodies()->size(), 7u);
  EXPECT_EQ(r->result_as_BodiesResult()->bodies()->Get(0)->def()->name()->str(), "hull5");
  r = sc.send(CommandBuilder().getBodies({}, 400), w);
  ASSERT_EQ(r->status(), Code::Ok);
  EXPECT_EQ(r->result_as_BodiesResult()->bodies()->size(), 0u);
  EXPECT_EQ(r->result_as_BodiesResult()->total(), 400u);
  // Ids: the first of them that fit; the rest asked again.
  std::vector<uint64_t> ids;
  for (const protocol::BodyInfo& b : got) ids.push_back(b.id);
  r = sc.send(CommandBuilder().getBodies(ids), w);
  ASSERT_EQ(r->status(), Code::Ok) << message(r);
  EXPECT_EQ(r->result_as_BodiesResult()->total(), 400u);
  EXPECT_LT(r->result_as_BodiesResult()->bodies()->size(), 400u);
}

TEST_F(SettingsTest, DefinitionsSurviveAnEngineSnapshotRestore) {
  const Scenery s = scenery();
  spawnScenery(c, world, s);
  ASSERT_EQ(c.send(CommandBuilder().setWorld(someSettings()), world)->status(), Code::Ok);
  ASSERT_EQ(c.send(CommandBuilder().step(5), world)->status(), Code::Ok);
  Reply r = c.send(CommandBuilder().saveSnapshot(), world);
  ASSERT_EQ(r->status(), Code::Ok) << message(r);
  const auto* bytes = r->result_as_SnapshotResult()->snapshot();
  const std::vector<uint8_t> snap(bytes->begin(), bytes->end());
  // Restored into a world that never had those bodies.
  const uint32_t other = createWorld(c, "other");
  r = c.send(CommandBuilder().restoreSnapshot(snap), other);
  ASSERT_EQ(r->status(), Code::Ok) << message(r);
  expectScenery(c, other, s, "after an engine snapshot restore");
  expectSettings(settingsOf(c, other), someSettings());
  // World info says the same.
  std::map<uint64_t, phys::BodyDef> info = worldInfoBodies(core, other);
  std::vector<protocol::BodyInfo> got = allBodies(c, other);
  ASSERT_EQ(info.size(), got.size());
  for (const protocol::BodyInfo& b : got) expectSameDefinition(info.at(b.id), b.def, b.def.name);
}

TEST_F(SettingsTest, DefinitionsSurviveAPortableSnapshotRestore) {
  // A portable snapshot written from what GetWorld, GetBodies and GetJoints return (as a tool
  // would), restored into another world: every field comes back.
  const Scenery s = scenery();
  spawnScenery(c, world, s);
  WorldOverrides settings = someSettings();
  ASSERT_EQ(c.send(CommandBuilder().setWorld(settings), world)->status(), Code::Ok);
  protocol::SnapshotData data;
  const phys::WorldDef d = settingsOf(c, world);
  data.name = "portable";
  data.gravity = d.gravity;
  data.timeStep = d.timeStep;
  data.solver = d.solver;
  data.settings = WorldOverrides::from(d);
  for (protocol::BodyInfo& b : allBodies(c, world)) data.bodies.push_back({b.id, b.def});
  data.joints = allJoints(c, world);
  const uint32_t other = createWorld(c, "other");
  Reply r = c.send(CommandBuilder().restoreSnapshot(protocol::encodeSnapshot(data)), other);
  ASSERT_EQ(r->status(), Code::Ok) << message(r);
  expectScenery(c, other, s, "after a portable snapshot restore");
  expectSettings(settingsOf(c, other), settings);
  // A portable snapshot's settings are checked as SetWorld's.
  data.settings.guardRetries = 40;
  r = c.send(CommandBuilder().restoreSnapshot(protocol::encodeSnapshot(data)), other);
  EXPECT_EQ(r->status(), Code::InvalidArgument) << message(r);
}

TEST_F(SettingsTest, SettingsPhysdCannotDescribeAreRefusedAtTheDoor) {
  // A scene's world settings pass the rules GetWorld's reply is read with.
  Reply r = c.send(CommandBuilder().loadSceneJson(
                       R"({"world": {"max_linear_speed": 1e9}, "bodies": []})"),
                   world);
  EXPECT_EQ(r->status(), Code::InvalidArgument) << message(r);
  EXPECT_NE(message(r).find("max_linear_speed"), std::string::npos) << message(r);
}

// ---------------------------------------------------------------------------------------------
// Durable worlds

fs::path scratch(const std::string& what) {
  fs::path p = fs::temp_directory_path() /
               ("physd_settings_" + what + "_" + std::to_string(getpid()));
  fs::remove_all(p);
  return p;
}

CoreConfig durableConfig(const fs::path& data) {
  CoreConfig cfg = testConfig();
  cfg.dataDir = data.string();
  return cfg;
}

TEST(DurableSettings, SetWorldIsJournaledAndEveryDefinitionSurvivesARestart) {
  const fs::path data = scratch("restart");
  auto a = std::make_unique<ServerCore>(durableConfig(data));
  ASSERT_TRUE(a->init().ok());
  Client c{a.get()};
  const uint32_t id = createWorld(c, "kept");
  const Scenery s = scenery();
  spawnScenery(c, id, s);
  ASSERT_EQ(c.send(CommandBuilder().step(3), id)->status(), Code::Ok);
  // After the world's checkpoint: in its journal only.
  ASSERT_EQ(c.send(CommandBuilder().setWorld(someSettings()), id)->status(), Code::Ok);
  ASSERT_EQ(c.send(CommandBuilder().step(4), id)->status(), Code::Ok);
  const uint64_t hash = a->world(id)->world->stateHash();
  a.reset();  // gone without a shutdown

  auto b = std::make_unique<ServerCore>(durableConfig(data));
  ASSERT_TRUE(b->init().ok());
  std::vector<std::string> notes;
  ASSERT_TRUE(b->restoreWorlds(&notes).ok());
  ASSERT_TRUE(b->world(id));
  EXPECT_EQ(b->world(id)->world->stateHash(), hash);
  Client cb{b.get(), kClient, 100};
  expectSettings(settingsOf(cb, id), someSettings());
  expectScenery(cb, id, s, "after a restart");
  // And again from a checkpoint (the journal folded into it).
  ASSERT_TRUE(b->checkpointNow(id).ok());
  b.reset();
  ServerCore d(durableConfig(data));
  ASSERT_TRUE(d.init().ok());
  ASSERT_TRUE(d.restoreWorlds(&notes).ok());
  Client cd{&d, kClient, 200};
  expectSettings(settingsOf(cd, id), someSettings());
  expectScenery(cd, id, s, "after a checkpoint and a restart");
  fs::remove_all(data);
}

TEST(DurableSettings, ARefusedSetWorldIsNotJournaled) {
  const fs::path data = scratch("refused");
  auto a = std::make_unique<ServerCore>(durableConfig(data));
  ASSERT_TRUE(a->init().ok());
  Client c{a.get()};
  const uint32_t id = createWorld(c, "kept");
  Client other{a.get(), kOther};
  WorldOverrides o;
  o.gravity = phys::Vec3{0, 0, -1};
  EXPECT_EQ(other.send(CommandBuilder().setWorld(o), id)->status(), Code::PermissionDenied);
  a.reset();
  ServerCore b(durableConfig(data));
  ASSERT_TRUE(b.init().ok());
  std::vector<std::string> notes;
  ASSERT_TRUE(b.restoreWorlds(&notes).ok());
  ASSERT_TRUE(b.world(id));
  EXPECT_EQ(b.world(id)->world->def().gravity.z, -9.81f);
  fs::remove_all(data);
}

}  // namespace
}  // namespace phys::server::test
