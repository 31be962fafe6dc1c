// validate.h applies the codec's rules to phys definitions (scenes, engine snapshots). The two
// must agree: a definition checkBodyDef accepts is one a SpawnBodies carrying it decodes, and
// one it refuses is refused by the decoder too. Checked on definitions with one field pushed
// out of range at a time, and on a random mix.
#include <cmath>
#include <limits>
#include <random>

#include "phys/protocol/validate.h"
#include "protocol_test_util.h"

namespace phys::protocol::test {
namespace {

/// The decoder's verdict on a SpawnBodies of `d`, and checkBodyDef's.
void expectAgree(const phys::BodyDef& d, const std::string& what) {
  Bytes b = CommandBuilder().spawnBodies(std::span<const phys::BodyDef>(&d, 1)).finish(header());
  Decoded<wire::Command> wire = decodeCommand(std::move(b));
  Status mine = checkBodyDef(d, Limits{}, "body");
  EXPECT_EQ(wire.ok(), mine.ok()) << what << ": decoder: " << wire.status.message
                                  << " | validate: " << mine.message;
  if (!wire.ok() && !mine.ok()) {
    EXPECT_EQ(wire.status.code, mine.code) << what;
  }
}

void expectAgree(const phys::JointDef& j, const std::string& what) {
  Bytes b = CommandBuilder().addJoints(std::span<const phys::JointDef>(&j, 1)).finish(header());
  Decoded<wire::Command> wire = decodeCommand(std::move(b));
  Status mine = checkJointDef(j, Limits{}, "joint");
  EXPECT_EQ(wire.ok(), mine.ok()) << what << ": decoder: " << wire.status.message
                                  << " | validate: " << mine.message;
}

TEST(Validate, AgreesWithTheDecoderOnBodies) {
  const float inf = std::numeric_limits<float>::infinity();
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const phys::BodyDef base = boxBody({0, 0, 1});
  expectAgree(base, "a box");
  expectAgree(hullBody(), "a hull");
  expectAgree(groundBody(), "a ground");
  struct Case {
    const char* what;
    void (*edit)(phys::BodyDef&);
  };
  static float bad;
  for (float v : {3.4e38f, -2e6f, inf, nan, 1e-45f, -1.0f, 0.0f, 2e4f, 150.0f, 2e9f}) {
    bad = v;
    const Case cases[] = {
        {"position.x", [](phys::BodyDef& d) { d.position.x = bad; }},
        {"linear velocity", [](phys::BodyDef& d) { d.linearVelocity.y = bad; }},
        {"angular velocity", [](phys::BodyDef& d) { d.angularVelocity.z = bad; }},
        {"damping", [](phys::BodyDef& d) { d.linearDamping = bad; }},
        {"gravity scale", [](phys::BodyDef& d) { d.gravityScale = bad; }},
        {"mass", [](phys::BodyDef& d) { d.mass = bad; }},
        {"inertia", [](phys::BodyDef& d) { d.inertia = {bad, bad, bad}; }},
        {"half extent", [](phys::BodyDef& d) { d.shapes[0].geom.halfExtents.x = bad; }},
        {"friction", [](phys::BodyDef& d) { d.shapes[0].material.friction = bad; }},
        {"restitution", [](phys::BodyDef& d) { d.shapes[0].material.restitution = bad; }},
        {"density", [](phys::BodyDef& d) { d.shapes[0].material.density = bad; }},
        {"local position", [](phys::BodyDef& d) { d.shapes[0].local.p.z = bad; }},
    };
    for (const Case& c : cases) {
      phys::BodyDef d = base;
      c.edit(d);
      expectAgree(d, std::string(c.what) + " = " + std::to_string(v));
    }
  }
  phys::BodyDef d = base;
  d.name = std::string("a\x01z");
  expectAgree(d, "a control character in the name");
  d.name = std::string(300, 'n');
  expectAgree(d, "a 300-byte name");
  d = base;
  d.shapes.assign(65, base.shapes[0]);
  expectAgree(d, "65 shapes");
  d = base;
  d.type = phys::BodyType::Static;
  d.mass = 1;
  expectAgree(d, "a static body with a mass");
}

TEST(Validate, AgreesWithTheDecoderOnJoints) {
  phys::JointDef j;
  j.bodyA = phys::BodyId::fromPacked(0x100000001ull);
  j.bodyB = phys::BodyId::fromPacked(0x100000002ull);
  expectAgree(j, "a ball joint");
  j.type = phys::JointType::Hinge;
  j.enableLimit = true;
  j.lower = -4;
  j.upper = 1;
  expectAgree(j, "a hinge limit beyond pi");
  j.lower = 1;
  expectAgree(j, "a hinge limit");
  j.anchorA.x = 3e38f;
  expectAgree(j, "a far anchor");
  j.anchorA.x = 0;
  j.springHertz = -1;
  expectAgree(j, "a negative spring");
  j.springHertz = 0;
  j.name = std::string(257, 'j');
  expectAgree(j, "a long name");
}

TEST(Validate, WorldParams) {
  EXPECT_TRUE(checkWorldParams({0, 0, -9.81f}, 1.0f / 60, Limits{}, "w").ok());
  Status s = checkWorldParams({0, 0, -9.81f}, 1e-45f, Limits{}, "w");
  EXPECT_EQ(s.code, Code::InvalidArgument);
  EXPECT_NE(s.message.find("w.time_step"), std::string::npos) << s.message;
  EXPECT_FALSE(checkWorldParams({0, 0, 3e38f}, 0.01f, Limits{}, "w").ok());
  EXPECT_FALSE(checkWorldParams({0, 0, -9.81f}, 2.0f, Limits{}, "w").ok());
}

TEST(Validate, QuotedCutsLongText) {
  EXPECT_EQ(shortQuote("abc"), "\"abc\"");
  const std::string q = shortQuote(std::string(1 << 20, 'x'));
  EXPECT_LT(q.size(), 100u);
  EXPECT_NE(q.find("1048576 bytes"), std::string::npos) << q;
}

}  // namespace
}  // namespace phys::protocol::test
