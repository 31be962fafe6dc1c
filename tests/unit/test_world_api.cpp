// World API: generational ids, validation of every edit, all-or-nothing rejection.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include "phys/world/world.h"
#include "test_util.h"

using namespace phys;

namespace {

BodyDef box(Vec3 p = {}) {
  BodyDef d;
  d.position = p;
  ShapeDef s;
  s.geom = ShapeGeom::box({0.5f, 0.5f, 0.5f});
  d.shapes.push_back(s);
  return d;
}

const float kNaN = std::numeric_limits<float>::quiet_NaN();
const float kInf = std::numeric_limits<float>::infinity();

}  // namespace

TEST(WorldApi, StaleBodyIdIsRejectedAfterSlotReuse) {
  World w;
  BodyId a, b;
  ASSERT_TRUE(w.createBody(box(), &a).ok());
  ASSERT_TRUE(w.destroyBody(a).ok());
  ASSERT_TRUE(w.createBody(box({3, 0, 0}), &b).ok());
  EXPECT_EQ(a.index, b.index);            // the slot is reused...
  EXPECT_NE(a.generation, b.generation);  // ...with a new generation
  EXPECT_FALSE(w.isValid(a));
  EXPECT_TRUE(w.isValid(b));
  BodyState s;
  EXPECT_EQ(w.getBody(a, &s).code, StatusCode::NotFound);
  EXPECT_EQ(w.setVelocity(a, {1, 0, 0}, {}).code, StatusCode::NotFound);
  EXPECT_EQ(w.destroyBody(a).code, StatusCode::NotFound);
  EXPECT_EQ(w.applyForce(a, {1, 0, 0}, {}).code, StatusCode::NotFound);
  // b is untouched by the attempts through the stale id.
  ASSERT_TRUE(w.getBody(b, &s).ok());
  EXPECT_EQ(s.position, (Vec3{3, 0, 0}));
  EXPECT_EQ(s.linearVelocity, (Vec3{}));
  EXPECT_FALSE(w.isValid(BodyId{}));  // null
}

TEST(WorldApi, StaleJointAndShapeIdsAreRejected) {
  World w;
  BodyId a, b;
  ASSERT_TRUE(w.createBody(box(), &a).ok());
  ASSERT_TRUE(w.createBody(box({2, 0, 0}), &b).ok());
  JointDef jd;
  jd.bodyA = a;
  jd.bodyB = b;
  JointId j;
  ASSERT_TRUE(w.createJoint(jd, &j).ok());
  ShapeId s = w.bodyShapes(b)[0];
  ASSERT_TRUE(w.destroyBody(b).ok());  // takes its joint and shapes along
  EXPECT_EQ(w.getJoint(j, nullptr, nullptr).code, StatusCode::NotFound);
  EXPECT_EQ(w.getShape(s, nullptr, nullptr).code, StatusCode::NotFound);
  EXPECT_EQ(w.jointCount(), 0);
  jd.bodyB = b;
  EXPECT_EQ(w.createJoint(jd, nullptr).code, StatusCode::NotFound);
}

TEST(WorldApi, BadBodyDefinitionsAreRejectedAndChangeNothing) {
  World w;
  struct Case {
    const char* what;
    BodyDef def;
    StatusCode code;
  };
  std::vector<Case> cases;
  {
    BodyDef d = box();
    d.position.x = kNaN;
    cases.push_back({"nan position", d, StatusCode::InvalidArgument});
  }
  {
    BodyDef d = box();
    d.linearVelocity.z = kInf;
    cases.push_back({"infinite velocity", d, StatusCode::InvalidArgument});
  }
  {
    BodyDef d = box();
    d.mass = -1;
    cases.push_back({"negative mass", d, StatusCode::InvalidArgument});
  }
  {
    BodyDef d = box();
    d.rotation = {0, 0, 0, 2};
    cases.push_back({"non-unit quaternion", d, StatusCode::InvalidArgument});
  }
  {
    BodyDef d = box();
    d.shapes[0].geom.halfExtents.y = 0;
    cases.push_back({"zero box size", d, StatusCode::InvalidArgument});
  }
  {
    BodyDef d = box();
    d.shapes[0].geom = ShapeGeom::sphere(-1);
    cases.push_back({"negative radius", d, StatusCode::InvalidArgument});
  }
  {
    BodyDef d = box();
    d.shapes[0].material.friction = -0.1f;
    cases.push_back({"negative friction", d, StatusCode::InvalidArgument});
  }
  {
    BodyDef d = box();
    d.shapes[0].material.restitution = 1.5f;
    cases.push_back({"restitution above 1", d, StatusCode::InvalidArgument});
  }
  {
    BodyDef d = box();
    d.shapes[0].geom = ShapeGeom::plane({0, 0, 1}, 0);
    cases.push_back({"plane on a dynamic body", d, StatusCode::IncorrectState});
  }
  {
    BodyDef d;
    cases.push_back({"dynamic body without mass", d, StatusCode::InvalidArgument});
  }
  for (const Case& c : cases) {
    BodyId id;
    Status st = w.createBody(c.def, &id);
    EXPECT_EQ(st.code, c.code) << c.what << ": " << st.message;
    EXPECT_FALSE(st.message.empty()) << c.what;
  }
  EXPECT_EQ(w.bodyCount(), 0);
  // Nothing leaked into the broad phase either: a step with no bodies finds no pairs.
  w.step();
  EXPECT_EQ(w.stats().pairs, 0);
}

TEST(WorldApi, BadEditsLeaveTheBodyAsItWas) {
  World w;
  BodyId b;
  ASSERT_TRUE(w.createBody(box({1, 2, 3}), &b).ok());
  EXPECT_EQ(w.setTransform(b, {kNaN, 0, 0}, {}).code, StatusCode::InvalidArgument);
  EXPECT_EQ(w.setTransform(b, {0, 0, 0}, {1, 1, 1, 1}).code, StatusCode::InvalidArgument);
  EXPECT_EQ(w.setVelocity(b, {0, kInf, 0}, {}).code, StatusCode::InvalidArgument);
  EXPECT_EQ(w.setMass(b, -2).code, StatusCode::InvalidArgument);
  EXPECT_EQ(w.setMass(b, 0).code, StatusCode::InvalidArgument);
  Material m;
  m.density = 0;
  EXPECT_EQ(w.setMaterial(b, m).code, StatusCode::InvalidArgument);
  EXPECT_EQ(w.applyImpulse(b, {kNaN, 0, 0}, {}).code, StatusCode::InvalidArgument);
  BodyState s;
  ASSERT_TRUE(w.getBody(b, &s).ok());
  EXPECT_EQ(s.position, (Vec3{1, 2, 3}));
  EXPECT_EQ(s.linearVelocity, (Vec3{}));
  EXPECT_NEAR(s.mass, 1000.0f, 1e-2f);  // 1 m^3 at the default density
}

TEST(WorldApi, BadJointsAndSolverSettingsAreRejected) {
  World w;
  BodyId a;
  ASSERT_TRUE(w.createBody(box(), &a).ok());
  JointDef j;
  j.bodyA = a;
  j.bodyB = a;
  EXPECT_EQ(w.createJoint(j, nullptr).code, StatusCode::InvalidArgument);  // same body
  j.bodyA = {};
  j.anchorA.x = kNaN;
  EXPECT_EQ(w.createJoint(j, nullptr).code, StatusCode::InvalidArgument);
  j.anchorA = {};
  j.type = JointType::Hinge;
  j.enableLimit = true;
  j.lower = 1;
  j.upper = -1;
  EXPECT_EQ(w.createJoint(j, nullptr).code, StatusCode::InvalidArgument);
  EXPECT_EQ(w.jointCount(), 0);

  SolverSettings s;
  s.substeps = 0;
  EXPECT_EQ(w.setSolverSettings(s).code, StatusCode::InvalidArgument);
  s = SolverSettings();
  s.contactHertz = kNaN;
  EXPECT_EQ(w.setSolverSettings(s).code, StatusCode::InvalidArgument);
  EXPECT_EQ(w.def().solver.substeps, SolverSettings().substeps);
  EXPECT_EQ(w.setTimeStep(-1).code, StatusCode::InvalidArgument);
  EXPECT_EQ(w.setGravity({0, kNaN, 0}).code, StatusCode::InvalidArgument);
}

TEST(WorldApi, MassAndInertiaFromShapesOrGiven) {
  World w;
  BodyId b;
  BodyDef d = box();
  d.shapes[0].geom.halfExtents = {1, 0.5f, 0.25f};  // 2 x 1 x 0.5 m
  ASSERT_TRUE(w.createBody(d, &b).ok());
  BodyState s;
  ASSERT_TRUE(w.getBody(b, &s).ok());
  const float m = 1000 * 2 * 1 * 0.5f;
  EXPECT_NEAR(s.mass, m, 1e-2f);
  EXPECT_NEAR(s.inertia.c0.x, m / 12 * (1 + 0.25f), 1e-2f);
  EXPECT_NEAR(s.inertia.c1.y, m / 12 * (4 + 0.25f), 1e-2f);
  EXPECT_NEAR(s.inertia.c2.z, m / 12 * (4 + 1), 1e-2f);
  d.mass = 10;
  d.inertia = {1, 2, 3};
  ASSERT_TRUE(w.createBody(d, &b).ok());
  ASSERT_TRUE(w.getBody(b, &s).ok());
  EXPECT_FLOAT_EQ(s.mass, 10);
  EXPECT_FLOAT_EQ(s.inertia.c1.y, 2);
}

TEST(WorldApi, DestroyingBodiesBetweenStepsLeavesNoStaleContacts) {
  World w;
  test::addGround(w);
  std::vector<BodyId> boxes;
  for (int i = 0; i < 5; ++i) {
    BodyId b;
    ASSERT_TRUE(w.createBody(box({0, 0, 0.5f + 1.0f * i}), &b).ok());
    boxes.push_back(b);
  }
  for (int i = 0; i < 30; ++i) w.step();
  ASSERT_FALSE(w.contacts().empty());
  // Destroy the middle of the stack, and reuse its slot at once with a new body.
  ASSERT_TRUE(w.destroyBody(boxes[2]).ok());
  for (const ContactInfo& c : w.contacts()) {
    EXPECT_TRUE(w.isValid(c.bodyA));
    EXPECT_TRUE(w.isValid(c.bodyB));
  }
  BodyId fresh;
  ASSERT_TRUE(w.createBody(box({5, 0, 0.5f}), &fresh).ok());
  for (int i = 0; i < 60; ++i) w.step();
  for (const ContactInfo& c : w.contacts()) {
    EXPECT_TRUE(w.isValid(c.bodyA));
    EXPECT_TRUE(w.isValid(c.bodyB));
  }
  // The boxes above the gap fell onto the one below; nothing is left hanging in the air.
  BodyState s;
  ASSERT_TRUE(w.getBody(boxes[3], &s).ok());
  EXPECT_NEAR(s.position.z, 2.5f, 0.05f);
  EXPECT_EQ(w.bodyCount(), 6);
}

TEST(WorldApi, HandBuiltHullsAreCheckedBeforeUse) {
  World w;
  auto hullBody = [](ConvexHull h) {
    BodyDef d;
    ShapeDef s;
    s.geom = ShapeGeom::convexHull(std::make_shared<const ConvexHull>(std::move(h)));
    d.shapes.push_back(s);
    return d;
  };
  std::string error;
  auto cube = buildConvexHull({{-1, -1, -1},
                               {1, -1, -1},
                               {-1, 1, -1},
                               {1, 1, -1},
                               {-1, -1, 1},
                               {1, -1, 1},
                               {-1, 1, 1},
                               {1, 1, 1}},
                              &error);
  ASSERT_TRUE(cube) << error;
  EXPECT_TRUE(w.createBody(hullBody(*cube), nullptr).ok());
  ConvexHull bad = *cube;
  bad.faces[0].indices[0] = 99;  // no such vertex
  EXPECT_EQ(w.createBody(hullBody(bad), nullptr).code, StatusCode::InvalidArgument);
  bad = *cube;
  bad.vertices[0].x = kNaN;
  EXPECT_EQ(w.createBody(hullBody(bad), nullptr).code, StatusCode::InvalidArgument);
  bad = *cube;
  for (Vec3& v : bad.vertices) v.z = 0;  // flat: no volume, no mass
  EXPECT_EQ(w.createBody(hullBody(bad), nullptr).code, StatusCode::InvalidArgument);
  EXPECT_EQ(w.bodyCount(), 1);
}

TEST(WorldApi, HugeFiniteVelocityIsCappedNotZeroed) {
  WorldDef def;
  def.gravity = {0, 0, 0};
  def.guard = false;  // the clamp itself (with the guard on, the body would be stopped)
  World w(def);
  BodyId b;
  ASSERT_TRUE(w.createBody(box(), &b).ok());
  ASSERT_TRUE(w.setVelocity(b, {3e38f, 0, 0}, {}).ok());
  w.step();
  BodyState s;
  ASSERT_TRUE(w.getBody(b, &s).ok());
  EXPECT_NEAR(s.linearVelocity.x, def.maxLinearSpeed, 1e-3f * def.maxLinearSpeed);
}

TEST(WorldApi, ShapeSwappedInTheSameSlotStartsWithoutTheOldContact) {
  World w;
  test::addGround(w);
  BodyDef d = box({0, 0, 0.5f});
  ShapeDef extra;
  extra.geom = ShapeGeom::sphere(0.2f);
  extra.local.p = {0.3f, 0, -0.3f};  // touches the ground too
  d.shapes.push_back(extra);
  BodyId b;
  ASSERT_TRUE(w.createBody(d, &b).ok());
  for (int i = 0; i < 30; ++i) w.step();
  ShapeId old = w.bodyShapes(b)[1];
  ASSERT_TRUE(w.removeShape(old).ok());
  for (const ContactInfo& c : w.contacts()) {
    EXPECT_FALSE(c.shapeA == old || c.shapeB == old);
  }
  ShapeId fresh;
  ASSERT_TRUE(w.addShape(b, extra, &fresh).ok());
  EXPECT_EQ(fresh.index, old.index);  // same slot, new generation
  EXPECT_NE(fresh.generation, old.generation);
  for (const ContactInfo& c : w.contacts()) {
    EXPECT_FALSE(c.shapeA == fresh || c.shapeB == fresh);  // not before it was ever collided
  }
  w.step();
  bool found = false;
  for (const ContactInfo& c : w.contacts()) found |= c.shapeA == fresh || c.shapeB == fresh;
  EXPECT_TRUE(found);
}
