// Direct contacts (SolverSettings::directContactRatio, dynamics/solver_contact_direct.h): an
// island in which a heavy body rests on light ones has its contact normal rows solved exactly,
// so a 1000:1 column stands where iteration lets the heavy body sink; islands without such a
// pair are solved as before, bit for bit.
#include <gtest/gtest.h>

#include <cmath>

#include "phys/world/world.h"
#include "test_util.h"

namespace phys {
namespace {

using test::addBody;
using test::addGround;
using test::boxBody;
using test::stateOf;

WorldDef columnDef(float directRatio) {
  WorldDef d;
  d.solver.directContactRatio = directRatio;
  d.threads = 1;
  return d;
}

/// A 1 m cube of ratio x 1000 kg on a 1 m cube of 1000 kg on the ground.
struct Column {
  BodyId light, heavy;
};
Column addColumn(World& w, float ratio) {
  addGround(w);
  Column c;
  c.light = addBody(w, boxBody({0, 0, 0.5f}));
  BodyDef h = boxBody({0, 0, 1.5f});
  h.mass = 1000.0f * ratio;
  c.heavy = addBody(w, h);
  return c;
}

TEST(DirectContacts, AThousandToOneColumnStandsOnlyWhenSolvedDirectly) {
  for (float directRatio : {10.0f, 0.0f}) {
    SCOPED_TRACE(directRatio);
    World w(columnDef(directRatio));
    const Column c = addColumn(w, 1000);
    for (int i = 0; i < 600; ++i) w.step();  // 10 s
    const BodyState heavy = stateOf(w, c.heavy), light = stateOf(w, c.light);
    const float sink = 1.5f - heavy.position.z;  // both contacts' penetration
    if (directRatio > 0) {
      EXPECT_LT(std::fabs(sink), 1e-4f);
      EXPECT_LT(std::hypot(light.position.x, light.position.y), 1e-4f);
      EXPECT_LT(length(heavy.linearVelocity), 1e-3f);
    } else {
      // Iterated, the soft contacts give way under the load (measured: every preset).
      EXPECT_GT(sink, 0.01f);
    }
  }
}

TEST(DirectContacts, EachContactCarriesTheWeightAboveIt) {
  World w(columnDef(10));
  const Column c = addColumn(w, 1000);
  for (int i = 0; i < 120; ++i) w.step();
  const float g = 9.81f, heavyMass = 1e6f, lightMass = 1000;
  double onLight = 0, onGround = 0;  // N: the last substep's impulses over its length
  for (const ContactInfo& ci : w.contacts()) {
    double sum = 0;
    for (int k = 0; k < ci.manifold.count; ++k) sum += ci.normalImpulse[k];
    const double force = sum / double(w.stats().substepTime);
    const bool ground = !(ci.bodyA == c.light || ci.bodyA == c.heavy) ||
                        !(ci.bodyB == c.light || ci.bodyB == c.heavy);
    (ground ? onGround : onLight) += force;
  }
  EXPECT_NEAR(onLight, heavyMass * g, 1e-3 * heavyMass * g);
  EXPECT_NEAR(onGround, (heavyMass + lightMass) * g, 1e-3 * heavyMass * g);
}

TEST(DirectContacts, ABodyLeavingIsNotHeldBack) {
  // The rows are unilateral: a heavy body thrown up off a light one leaves at its own speed.
  World w(columnDef(10));
  const Column c = addColumn(w, 1000);
  for (int i = 0; i < 30; ++i) w.step();
  ASSERT_TRUE(w.setVelocity(c.heavy, {0, 0, 3}, {0, 0, 0}).ok());
  w.step();
  const BodyState s = stateOf(w, c.heavy);
  EXPECT_NEAR(s.linearVelocity.z, 3 - 9.81f / 60, 1e-4f);
  for (const ContactInfo& ci : w.contacts()) {
    if (!(ci.bodyA == c.heavy || ci.bodyB == c.heavy)) continue;
    for (int k = 0; k < ci.manifold.count; ++k) EXPECT_EQ(ci.normalImpulse[k], 0.0f);
  }
}

TEST(DirectContacts, IslandsOfSimilarMassesAreSolvedAsBefore) {
  // A ten-to-one pair makes the column direct; a two-to-one one leaves it iterated, the same
  // bits as with direct contacts off.
  for (float ratio : {2.0f, 10.0f}) {
    World on(columnDef(10)), off(columnDef(0));
    addColumn(on, ratio);
    addColumn(off, ratio);
    for (int i = 0; i < 60; ++i) {
      on.step();
      off.step();
    }
    if (ratio < 10) {
      EXPECT_EQ(on.stateHash(), off.stateHash());
    } else {
      EXPECT_NE(on.stateHash(), off.stateHash());
    }
  }
}

/// A heavy cube resting on a light block that is welded (fixed joint, no contact between
/// them) to a light foot on the ground: the load reaches the ground only through the joint,
/// and the foot's ground contact carries it (issue 41's jointed piles in one path).
struct WeldedFoot {
  BodyId foot, shin, heavy;
};
WeldedFoot addWeldedFoot(World& w, float heavyMass) {
  addGround(w);
  WeldedFoot f;
  BodyDef foot = boxBody({0, 0, 0.1f}, {0.5f, 0.5f, 0.1f});
  foot.mass = 1;
  f.foot = addBody(w, foot);
  BodyDef shin = boxBody({0, 0, 0.45f}, {0.25f, 0.25f, 0.25f});
  shin.mass = 1;
  f.shin = addBody(w, shin);
  BodyDef heavy = boxBody({0, 0, 1.2f});
  heavy.mass = heavyMass;
  f.heavy = addBody(w, heavy);
  JointDef j;
  j.type = JointType::Fixed;
  j.bodyA = f.foot;
  j.bodyB = f.shin;
  j.anchorA = {0, 0, 0.1f};
  j.anchorB = {0, 0, -0.25f};
  EXPECT_TRUE(w.createJoint(j, nullptr).ok());
  return f;
}

TEST(DirectContacts, AJointCarriesTheLoadToTheGroundExactly) {
  // The light foot and shin are two bodies: joined by their joint into the heavy cube's
  // island, the foot's ground rows are solved with the joint holding (the Schur complement of
  // its rows), and the cube stands. Before issue 41 the island was the cube and the shin
  // alone: solved exactly without the joint (which the LDL solve then restored, undoing it),
  // the shin was squeezed out and the cube fell 0.7 m to the ground, as it does iterated.
  for (float directRatio : {10.0f, 0.0f}) {
    SCOPED_TRACE(directRatio);
    World w(columnDef(directRatio));
    const WeldedFoot f = addWeldedFoot(w, 1000);
    for (int i = 0; i < 300; ++i) w.step();  // 5 s
    const BodyState foot = stateOf(w, f.foot), heavy = stateOf(w, f.heavy);
    const float footSink = 0.1f - foot.position.z, heavySink = 1.2f - heavy.position.z;
    if (directRatio > 0) {
      EXPECT_LT(std::fabs(footSink), 2e-5f);
      EXPECT_LT(std::fabs(heavySink), 1e-3f);  // the joint's own error (biased) included
      EXPECT_LT(std::hypot(heavy.position.x, heavy.position.y), 1e-4f);
      EXPECT_LT(length(heavy.linearVelocity), 1e-3f);
    } else {
      EXPECT_GT(heavySink, 0.1f);
    }
  }
}

TEST(DirectContacts, TheRatioIsValidatedAndKeptBySnapshots) {
  SolverSettings s;
  s.directContactRatio = 0.5f;
  EXPECT_FALSE(World::validate(s).ok());
  s.directContactRatio = std::nanf("");
  EXPECT_FALSE(World::validate(s).ok());
  s.directContactRatio = 37;
  EXPECT_TRUE(World::validate(s).ok());
  World w(columnDef(37));
  addColumn(w, 100);
  std::vector<uint8_t> bytes;
  ASSERT_TRUE(w.saveSnapshot(&bytes).ok());
  World back;
  ASSERT_TRUE(back.restoreSnapshot(bytes.data(), bytes.size()).ok());
  EXPECT_EQ(back.def().solver.directContactRatio, 37.0f);
}

}  // namespace
}  // namespace phys
