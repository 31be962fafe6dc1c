// The codec of world settings and definitions (issue 40): SetWorld, GetWorld, GetBodies and
// GetJoints and their results round-trip; out-of-range settings are refused by the decoder
// with the words validate.h uses on phys::WorldDef.
#include <limits>

#include "phys/protocol/validate.h"
#include "protocol_test_util.h"

namespace phys::protocol::test {
namespace {

TEST(SettingsCodec, SetWorldRoundTripsEveryField) {
  phys::WorldDef d;
  d.gravity = {1, 2, -3};
  d.timeStep = 0.005f;
  d.sleep = {true, 2, 0.01f, 0.2f};
  d.maxLinearSpeed = 400;
  d.maxAngularSpeed = 200;
  d.speculativeDistance = 0.03f;
  d.aabbMargin = 0.07f;
  d.guard = false;
  d.guardEnergyJump = 1.5f;
  d.guardRetries = 3;
  Bytes b = CommandBuilder().setWorld(WorldOverrides::from(d)).finish(header());
  auto c = decodeCommand(std::move(b));
  ASSERT_TRUE(c.ok()) << c.status.message;
  ASSERT_EQ(c->request_type(), wire::Request::SetWorld);
  EXPECT_TRUE(isBatchable(wire::Request::SetWorld));
  EXPECT_STREQ(requestName(wire::Request::SetWorld), "set_world");
  phys::WorldDef got;
  applyOverrides(toOverrides(*c->request_as_SetWorld()->settings()), &got);
  EXPECT_TRUE(got.gravity == d.gravity);
  EXPECT_EQ(got.timeStep, d.timeStep);
  EXPECT_EQ(got.sleep.enabled, true);
  EXPECT_EQ(got.sleep.time, 2);
  EXPECT_EQ(got.sleep.linearSpeed, 0.01f);
  EXPECT_EQ(got.sleep.angularSpeed, 0.2f);
  EXPECT_EQ(got.maxLinearSpeed, 400);
  EXPECT_EQ(got.maxAngularSpeed, 200);
  EXPECT_EQ(got.speculativeDistance, 0.03f);
  EXPECT_EQ(got.aabbMargin, 0.07f);
  EXPECT_FALSE(got.guard);
  EXPECT_EQ(got.guardEnergyJump, 1.5f);
  EXPECT_EQ(got.guardRetries, 3);
  EXPECT_TRUE(checkWorldSettings(got, Limits{}, "w").ok());
  // One field: the others are absent (they keep the world's values).
  WorldOverrides one;
  one.sleep = false;
  c = decodeCommand(CommandBuilder().setWorld(one).finish(header()));
  ASSERT_TRUE(c.ok()) << c.status.message;
  WorldOverrides back = toOverrides(*c->request_as_SetWorld()->settings());
  EXPECT_TRUE(back.sleep && !*back.sleep);
  EXPECT_FALSE(back.gravity || back.timeStep || back.guard || back.guardRetries);
}

TEST(SettingsCodec, OutOfRangeSettingsAreRefusedAsValidateRefusesThem) {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  struct Case {
    const char* field;
    void (*edit)(phys::WorldDef&, float);
  };
  const Case cases[] = {
      {"gravity.y", [](phys::WorldDef& d, float n) { d.gravity.y = n; }},
      {"time_step", [](phys::WorldDef& d, float) { d.timeStep = 1e-9f; }},
      {"sleep_time", [](phys::WorldDef& d, float) { d.sleep.time = -1; }},
      {"sleep_angular_speed", [](phys::WorldDef& d, float n) { d.sleep.angularSpeed = n; }},
      {"max_linear_speed", [](phys::WorldDef& d, float) { d.maxLinearSpeed = 2e5f; }},
      {"max_angular_speed", [](phys::WorldDef& d, float) { d.maxAngularSpeed = -5; }},
      {"speculative_distance", [](phys::WorldDef& d, float) { d.speculativeDistance = 11; }},
      {"aabb_margin", [](phys::WorldDef& d, float n) { d.aabbMargin = n; }},
      {"guard_energy_jump", [](phys::WorldDef& d, float) { d.guardEnergyJump = -1; }},
      {"guard_retries", [](phys::WorldDef& d, float) { d.guardRetries = 5; }},
  };
  for (const Case& k : cases) {
    SCOPED_TRACE(k.field);
    phys::WorldDef d;
    k.edit(d, nan);
    auto c = decodeCommand(CommandBuilder().setWorld(WorldOverrides::from(d)).finish(header()));
    ASSERT_FALSE(c.ok());
    EXPECT_EQ(c.status.code, Code::InvalidArgument);
    EXPECT_NE(c.status.message.find(std::string("set_world.settings.") + k.field),
              std::string::npos)
        << c.status.message;
    Status v = checkWorldSettings(d, Limits{}, "w");
    EXPECT_EQ(v.code, Code::InvalidArgument);
    EXPECT_NE(v.message.find(k.field), std::string::npos) << v.message;
  }
  auto c = decodeCommand(CommandBuilder().setWorld({}).finish(header()));
  EXPECT_EQ(c.status.code, Code::InvalidArgument);
  // A snapshot's settings too.
  SnapshotData s;
  s.settings.guardRetries = 99;
  auto snap = decodeSnapshot(encodeSnapshot(s));
  EXPECT_EQ(snap.status.code, Code::InvalidArgument) << snap.status.message;
}

TEST(SettingsCodec, ReadsAndTheirResultsRoundTrip) {
  const std::vector<uint64_t> ids{0x100000003, 0x200000001};
  auto c = decodeCommand(CommandBuilder().getBodies(ids, 4, 9).finish(header()));
  ASSERT_TRUE(c.ok()) << c.status.message;
  EXPECT_EQ(c->request_as_GetBodies()->bodies()->size(), 2u);
  EXPECT_EQ(c->request_as_GetBodies()->first(), 4u);
  EXPECT_EQ(c->request_as_GetBodies()->max_count(), 9u);
  c = decodeCommand(CommandBuilder().getJoints().finish(header()));
  ASSERT_TRUE(c.ok()) << c.status.message;
  c = decodeCommand(CommandBuilder().getWorld().finish(header()));
  ASSERT_TRUE(c.ok()) << c.status.message;
  EXPECT_FALSE(isBatchable(wire::Request::GetBodies));

  // BodiesResult: a definition and the mass properties.
  BodyInfo b;
  b.id = 0x100000003;
  b.def = hullBody();
  b.def.name = "hull";
  b.def.linearDamping = 0.25f;
  b.mass = {12, {0.1f, 0, 0}, {1, 2, 3}, normalize(phys::Quat{0, 0, 0.3f, 1})};
  ReplyHeader h;
  h.clientId = kClient;
  h.seq = 3;
  const std::vector<BodyInfo> bodies{b};
  Bytes bytes = encodeBodiesReply(h, 10, bodies);
  EXPECT_LE(bytes.size(), kReplyOverheadBytes + encodedBytesBound(b));
  auto r = decodeReply(std::move(bytes));
  ASSERT_TRUE(r.ok()) << r.status.message;
  auto* br = r->result_as_BodiesResult();
  ASSERT_TRUE(br);
  EXPECT_EQ(br->total(), 10u);
  BodyInfo got;
  ASSERT_TRUE(toBodyInfo(*br->bodies()->Get(0), &got).ok());
  EXPECT_EQ(got.id, b.id);
  EXPECT_EQ(got.def.name, "hull");
  EXPECT_EQ(got.def.linearDamping, 0.25f);
  EXPECT_EQ(got.def.shapes.size(), 1u);
  EXPECT_EQ(got.mass.mass, 12);
  EXPECT_TRUE(got.mass.inertia == (phys::Vec3{1, 2, 3}));
  EXPECT_NEAR(got.mass.inertiaRotation.z, b.mass.inertiaRotation.z, 1e-6f);

  // JointsResult.
  JointEntry j{0x400000001, {}};
  j.def.type = phys::JointType::Distance;
  j.def.bodyB = phys::BodyId::fromPacked(0x100000003);
  j.def.name = "rope";
  r = decodeReply(encodeJointsReply(h, 1, std::vector<JointEntry>{j}));
  ASSERT_TRUE(r.ok()) << r.status.message;
  ASSERT_EQ(r->result_as_JointsResult()->joints()->size(), 1u);
  EXPECT_EQ(r->result_as_JointsResult()->joints()->Get(0)->def()->name()->str(), "rope");

  // WorldSettingsResult: every field present.
  phys::WorldDef d;
  d.gravity = {0, 0, -1.6f};
  d.solver.iterations = 33;
  r = decodeReply(encodeWorldSettingsReply(h, d, "soft_step"));
  ASSERT_TRUE(r.ok()) << r.status.message;
  auto* ws = r->result_as_WorldSettingsResult();
  ASSERT_TRUE(ws && ws->settings() && ws->solver());
  EXPECT_EQ(ws->preset()->str(), "soft_step");
  WorldOverrides o = toOverrides(*ws->settings());
  EXPECT_TRUE(o.gravity && o.timeStep && o.sleep && o.sleepTime && o.sleepLinearSpeed &&
              o.sleepAngularSpeed && o.maxLinearSpeed && o.maxAngularSpeed &&
              o.speculativeDistance && o.aabbMargin && o.guard && o.guardEnergyJump &&
              o.guardRetries);
  EXPECT_EQ(o.gravity->z, -1.6f);
  EXPECT_EQ(toOverrides(*ws->solver()).iterations, 33);
}

}  // namespace
}  // namespace phys::protocol::test
