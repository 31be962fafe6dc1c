// World snapshots: a world restored from a snapshot continues bit for bit like the world
// that saved it, whatever world it is restored into; a bad snapshot changes nothing.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <set>
#include <string>
#include <vector>

#include "phys/scene/scene.h"
#include "phys/world/world.h"
#include "test_util.h"

using namespace phys;
using namespace phys::test;

namespace {

using Bytes = std::vector<uint8_t>;

Bytes save(const World& w) {
  Bytes b;
  Status st = w.saveSnapshot(&b);
  EXPECT_TRUE(st.ok()) << st.message;
  return b;
}

template <class T>
void mixBits(uint64_t* h, const T& v) {
  unsigned char p[sizeof(T)];
  std::memcpy(p, &v, sizeof(T));
  for (unsigned char c : p) {
    *h ^= c;
    *h *= 1099511628211ull;
  }
}

/// Everything observable after a step, beyond stateHash: velocities, contacts with their
/// impulses, joint states, time and statistics that feed later steps.
uint64_t observableHash(const World& w) {
  uint64_t h = 1469598103934665603ull;
  mixBits(&h, w.stateHash());
  for (BodyId id : w.bodies()) {
    BodyState s = stateOf(w, id);
    mixBits(&h, id.packed());
    mixBits(&h, s.linearVelocity);
    mixBits(&h, s.angularVelocity);
    mixBits(&h, s.centerOfMass);
  }
  for (const ContactInfo& c : w.contacts()) {
    mixBits(&h, c.shapeA.packed());
    mixBits(&h, c.shapeB.packed());
    mixBits(&h, c.manifold.normal);
    mixBits(&h, c.manifold.count);
    for (int k = 0; k < c.manifold.count; ++k) {
      mixBits(&h, c.manifold.points[k].point);
      mixBits(&h, c.manifold.points[k].separation);
      mixBits(&h, c.manifold.points[k].featureId);
      mixBits(&h, c.normalImpulse[k]);
    }
  }
  for (JointId id : w.joints()) {
    JointState s;
    EXPECT_TRUE(w.getJoint(id, nullptr, &s).ok());
    mixBits(&h, id.packed());
    mixBits(&h, s.reactionForce);
    mixBits(&h, s.reactionTorque);
    mixBits(&h, s.positionError);
    mixBits(&h, s.angleError);
  }
  mixBits(&h, w.time());
  mixBits(&h, w.stats().step);
  mixBits(&h, w.stats().guardEvents);
  return h;
}

/// Steps m times, recording stateHash and the observable hash after each step.
std::vector<uint64_t> run(World& w, int m) {
  std::vector<uint64_t> out;
  for (int i = 0; i < m; ++i) {
    w.step();
    out.push_back(w.stateHash());
    out.push_back(observableHash(w));
  }
  return out;
}

/// The first step at which two runs differ, or -1.
int firstDifference(const std::vector<uint64_t>& a, const std::vector<uint64_t>& b) {
  for (size_t i = 0; i < std::min(a.size(), b.size()); ++i)
    if (a[i] != b[i]) return int(i / 2);
  return a.size() == b.size() ? -1 : int(std::min(a.size(), b.size()) / 2);
}

std::shared_ptr<const ConvexHull> hullOf(std::vector<Vec3> pts) {
  std::string err;
  auto h = buildConvexHull(pts, &err);
  EXPECT_NE(h, nullptr) << err;
  return h;
}

/// A box pyramid, a pile of mixed shapes (boxes, spheres, capsules, two kinds of hull, a
/// two-shape body) falling onto it, a kinematic sweeper and a static ledge; some bodies
/// destroyed and others created, so every pool has free slots and bumped generations.
void buildMixedScene(World& w) {
  addGround(w);
  const float he = 0.25f;
  const int base = 6;
  for (int row = 0; row < base; ++row)
    for (int i = 0; i < base - row; ++i)
      addBody(w, boxBody({(i - 0.5f * (base - row - 1)) * 2.02f * he, 0, he + row * 2 * he},
                         {he, he, he}));
  auto tetra = hullOf(
      {{0.3f, 0.3f, 0.3f}, {-0.3f, -0.3f, 0.3f}, {-0.3f, 0.3f, -0.3f}, {0.3f, -0.3f, -0.3f}});
  auto prism = hullOf({{0.3f, 0, -0.2f},
                       {-0.15f, 0.26f, -0.2f},
                       {-0.15f, -0.26f, -0.2f},
                       {0.3f, 0, 0.2f},
                       {-0.15f, 0.26f, 0.2f},
                       {-0.15f, -0.26f, 0.2f}});
  std::vector<BodyId> pile;
  for (int i = 0; i < 24; ++i) {
    BodyDef d;
    d.position = {-1.2f + 0.8f * float(i % 4), -0.6f + 0.4f * float((i / 4) % 3),
                  2.5f + 0.7f * float(i / 4)};
    d.rotation = Quat::fromAxisAngle({1, 0.3f * float(i), 0.2f}, 0.4f * float(i));
    d.angularVelocity = {0.1f * float(i % 3), 0, 0.5f};
    ShapeDef s;
    switch (i % 6) {
      case 0:
        s.geom = ShapeGeom::sphere(0.2f);
        break;
      case 1:
        s.geom = ShapeGeom::capsule(0.12f, 0.2f);
        break;
      case 2:
        s.geom = ShapeGeom::convexHull(tetra);
        break;
      case 3:
        s.geom = ShapeGeom::convexHull(prism);
        break;
      case 4:
        s.geom = ShapeGeom::box({0.25f, 0.15f, 0.1f});
        break;
      case 5: {  // a dumbbell: two spheres on a capsule
        s.geom = ShapeGeom::capsule(0.06f, 0.25f);
        ShapeDef end;
        end.geom = ShapeGeom::sphere(0.12f);
        end.local.p = {0, 0, 0.3f};
        d.shapes.push_back(end);
        end.local.p = {0, 0, -0.3f};
        end.material.restitution = 0.5f;
        d.shapes.push_back(end);
        break;
      }
    }
    s.material.friction = 0.3f + 0.05f * float(i % 5);
    d.shapes.push_back(s);
    pile.push_back(addBody(w, d));
  }
  BodyDef k = boxBody({-3, 1.5f, 0.3f}, {0.2f, 0.6f, 0.3f}, BodyType::Kinematic);
  k.linearVelocity = {0.8f, 0, 0};
  k.angularVelocity = {0, 0, 0.3f};
  addBody(w, k);
  addBody(w, boxBody({2.5f, -1.5f, 0.5f}, {0.5f, 0.5f, 0.5f}, BodyType::Static));
  // Free slots and bumped generations: destroy a few, create a few (some reuse the slots).
  ASSERT_TRUE(w.destroyBody(pile[3]).ok());
  ASSERT_TRUE(w.destroyBody(pile[10]).ok());
  ASSERT_TRUE(w.destroyBody(pile[17]).ok());
  addBody(w, sphereBody({0.3f, 0.2f, 7}, 0.3f));
  addBody(w, sphereBody({-0.3f, 0.1f, 8}, 0.25f, 500));
}

/// Steps `src` n times, snapshots it, steps it m more times; a world made by `makeTarget`
/// restored from the snapshot and stepped m times must match step for step, and the same
/// world restored into itself too.
template <class MakeTarget>
void expectContinuesBitExact(World& src, int n, int m, MakeTarget makeTarget) {
  for (int i = 0; i < n; ++i) src.step();
  Bytes snap = save(src);
  std::vector<uint64_t> expected = run(src, m);

  std::unique_ptr<World> other = makeTarget();
  Status st = other->restoreSnapshot(snap.data(), snap.size());
  ASSERT_TRUE(st.ok()) << st.message;
  EXPECT_EQ(save(*other), snap) << "save -> restore -> save changed the bytes";
  std::vector<uint64_t> got = run(*other, m);
  EXPECT_EQ(firstDifference(expected, got), -1) << "restored world diverged at that step";

  // The source itself, rewound after it moved on.
  st = src.restoreSnapshot(snap.data(), snap.size());
  ASSERT_TRUE(st.ok()) << st.message;
  EXPECT_EQ(firstDifference(expected, run(src, m)), -1) << "rewound world diverged";
}

std::unique_ptr<World> defaultWorld() {
  return std::make_unique<World>();
}

}  // namespace

TEST(Snapshot, SameSceneRunTwiceIsIdentical) {
  World a, b;
  buildMixedScene(a);
  buildMixedScene(b);
  EXPECT_EQ(firstDifference(run(a, 40), run(b, 40)), -1);
}

TEST(Snapshot, PyramidAndMixedPileContinueBitExact) {
  WorldDef def;
  def.threads = 2;
  World w(def);
  buildMixedScene(w);
  // Forces pending at the snapshot carry over.
  for (int i = 0; i < 30; ++i) w.step();
  BodyId first = w.bodies()[1];
  ASSERT_TRUE(
      w.applyForce(first, {40, 0, 30}, stateOf(w, first).centerOfMass + Vec3{0, 0.1f, 0}).ok());
  ASSERT_TRUE(w.applyTorque(w.bodies()[5], {0, 3, 0}).ok());
  expectContinuesBitExact(w, 0, 60, [] {
    WorldDef d;
    d.threads = 1;           // results do not depend on the thread count
    d.timeStep = 1.0f / 30;  // replaced by the snapshot's
    d.gravity = {0, 0, -1};
    return std::make_unique<World>(d);
  });
}

TEST(Snapshot, ContinuesAfterEditsBetweenSteps) {
  // Bodies destroyed after the last step leave stale contacts; a body switched to static,
  // a shape added and one removed, a setTransform (static fat boxes), a joint destroyed.
  World w;
  buildMixedScene(w);
  for (int i = 0; i < 40; ++i) w.step();
  std::vector<BodyId> ids = w.bodies();
  ASSERT_TRUE(w.destroyBody(ids[3]).ok());  // a pyramid box, in contact
  ASSERT_TRUE(w.setBodyType(ids[8], BodyType::Static).ok());
  ShapeDef extra;
  extra.geom = ShapeGeom::sphere(0.1f);
  extra.local.p = {0.3f, 0, 0};
  ShapeId added;
  ASSERT_TRUE(w.addShape(ids[20], extra, &added).ok());
  ASSERT_TRUE(w.setTransform(ids.back(), {2.5f, -1.5f, 0.45f}, {}).ok());
  JointDef jd;
  jd.type = JointType::Distance;
  jd.bodyA = ids[22];
  jd.bodyB = ids[23];
  JointId j;
  ASSERT_TRUE(w.createJoint(jd, &j).ok());
  jd.bodyB = ids[24];
  JointId j2;
  ASSERT_TRUE(w.createJoint(jd, &j2).ok());
  ASSERT_TRUE(w.destroyJoint(j).ok());
  expectContinuesBitExact(w, 0, 40, defaultWorld);
}

TEST(Snapshot, JacobiSplitPushoutBlockContactsContinueBitExact) {
  WorldDef def;
  def.threads = 3;
  def.solver.scheme = SolverSettings::Scheme::Jacobi;
  def.solver.equalitySolve = SolverSettings::EqualitySolve::Iterative;
  def.solver.splitPushout = true;
  def.solver.blockContacts = true;
  def.solver.substeps = 4;
  World w(def);
  buildMixedScene(w);
  expectContinuesBitExact(w, 40, 40, defaultWorld);
}

TEST(Snapshot, PatchFrictionContinuesBitExact) {
  // The manifolds' friction impulses (tangent pair and twist) are in the snapshot.
  WorldDef def;
  def.solver.patchFriction = !def.solver.patchFriction;
  for (int flip = 0; flip < 2; ++flip) {
    def.solver.patchFriction = !def.solver.patchFriction;
    World w(def);
    buildMixedScene(w);
    expectContinuesBitExact(w, 40, 40, defaultWorld);
  }
}

TEST(Snapshot, ChainWithLdlAndGeometricStiffnessContinuesBitExact) {
  Scene scene = test::loadScene("ball_and_chain");
  ASSERT_EQ(scene.world.solver.equalitySolve, SolverSettings::EqualitySolve::DirectLdl);
  ASSERT_TRUE(scene.world.solver.geometricStiffness);
  World w(scene.world);
  std::vector<BodyId> ids;
  ASSERT_TRUE(instantiateScene(scene, &w, &ids).ok());
  expectContinuesBitExact(w, 45, 45, defaultWorld);
}

TEST(Snapshot, WindmillMotorContinuesBitExact) {
  Scene scene = test::loadScene("windmill");
  World w(scene.world);
  std::vector<BodyId> ids;
  std::vector<JointId> joints;
  ASSERT_TRUE(instantiateScene(scene, &w, &ids, &joints).ok());
  // A motor changed before the snapshot must carry over.
  bool motor = false;
  for (JointId j : joints) {
    JointDef d;
    ASSERT_TRUE(w.getJoint(j, &d, nullptr).ok());
    if (d.enableMotor && !motor) {
      ASSERT_TRUE(w.setMotor(j, true, -1.5f, d.maxMotorForce).ok());
      motor = true;
    }
  }
  ASSERT_TRUE(motor);
  expectContinuesBitExact(w, 60, 60, defaultWorld);
}

TEST(Snapshot, SuspensionBridgeContinuesBitExact) {
  Scene scene = test::loadScene("suspension_bridge");
  World w(scene.world);
  std::vector<BodyId> ids;
  ASSERT_TRUE(instantiateScene(scene, &w, &ids).ok());
  expectContinuesBitExact(w, 20, 20, defaultWorld);
}

TEST(Snapshot, IdsCreatedAfterRestoreAreTheSame) {
  World a;
  buildMixedScene(a);
  std::vector<BodyId> ids = a.bodies();
  // Free joint and shape slots too.
  JointDef jd;
  jd.bodyA = ids[7];
  jd.bodyB = ids[8];
  JointId j1, j2;
  ASSERT_TRUE(a.createJoint(jd, &j1).ok());
  jd.bodyB = ids[9];
  ASSERT_TRUE(a.createJoint(jd, &j2).ok());
  JointId j3;
  jd.bodyB = ids[10];
  ASSERT_TRUE(a.createJoint(jd, &j3).ok());
  ASSERT_TRUE(a.destroyJoint(j1).ok());
  ASSERT_TRUE(a.destroyJoint(j3).ok());
  ShapeDef extra;
  extra.geom = ShapeGeom::sphere(0.1f);
  ShapeId s1, s2;
  ASSERT_TRUE(a.addShape(ids[12], extra, &s1).ok());
  ASSERT_TRUE(a.addShape(ids[11], extra, &s2).ok());
  ASSERT_TRUE(a.removeShape(s2).ok());
  ASSERT_TRUE(a.removeShape(s1).ok());
  // Several free body slots, so the order of the free list shows in the ids.
  ASSERT_TRUE(a.destroyBody(ids[30]).ok());
  ASSERT_TRUE(a.destroyBody(ids[25]).ok());
  ASSERT_TRUE(a.destroyBody(ids[33]).ok());
  ids = a.bodies();
  for (int i = 0; i < 5; ++i) a.step();
  Bytes snap = save(a);

  auto createSome = [&](World& w) {
    std::vector<uint64_t> out;
    for (int i = 0; i < 5; ++i)
      out.push_back(addBody(w, sphereBody({0, 5, 1.0f + i}, 0.2f)).packed());
    JointDef d;
    d.bodyA = ids[13];
    d.bodyB = ids[14];
    JointId j;
    EXPECT_TRUE(w.createJoint(d, &j).ok());
    out.push_back(j.packed());
    d.bodyB = ids[15];
    EXPECT_TRUE(w.createJoint(d, &j).ok());
    out.push_back(j.packed());
    ShapeId s;
    EXPECT_TRUE(w.addShape(ids[16], extra, &s).ok());
    out.push_back(s.packed());
    EXPECT_TRUE(w.addShape(ids[16], extra, &s).ok());
    out.push_back(s.packed());
    return out;
  };
  std::vector<uint64_t> expected = createSome(a);
  EXPECT_EQ(a.bodyCount(), int(ids.size()) + 5);

  World b;
  ASSERT_TRUE(b.restoreSnapshot(snap.data(), snap.size()).ok());
  EXPECT_EQ(b.bodies(), ids);
  std::vector<uint64_t> got = createSome(b);
  EXPECT_EQ(got, expected);
  // And they simulate the same.
  EXPECT_EQ(firstDifference(run(a, 10), run(b, 10)), -1);
}

TEST(Snapshot, SaveRestoreSaveGivesIdenticalBytes) {
  {
    World empty;
    Bytes snap = save(empty);
    World other;
    ASSERT_TRUE(other.restoreSnapshot(snap.data(), snap.size()).ok());
    EXPECT_EQ(save(other), snap);
  }
  World w;
  buildMixedScene(w);
  for (int step = 0; step < 3; ++step) {
    Bytes snap = save(w);
    World other;
    ASSERT_TRUE(other.restoreSnapshot(snap.data(), snap.size()).ok());
    EXPECT_EQ(save(other), snap);
    EXPECT_EQ(other.stateHash(), w.stateHash());
    EXPECT_EQ(other.bodyCount(), w.bodyCount());
    EXPECT_EQ(other.time(), w.time());
    EXPECT_EQ(other.stats().step, w.stats().step);
    for (int i = 0; i < 20; ++i) w.step();
  }
}

TEST(Snapshot, SizesOfSomeScenes) {
  // Not a bound, a record: printed so the size per body is visible in test logs.
  World w;
  buildMixedScene(w);
  for (int i = 0; i < 60; ++i) w.step();
  Bytes snap = save(w);
  std::printf("[ snapshot ] mixed scene: %d bodies, %zu contacts, %zu bytes\n", w.bodyCount(),
              w.contacts().size(), snap.size());
  EXPECT_LT(snap.size(), size_t(w.bodyCount()) * 2000);
  for (const char* name : {"ball_and_chain", "windmill", "pyramid_20"}) {
    Scene scene = test::loadScene(name);
    World s(scene.world);
    std::vector<BodyId> ids;
    ASSERT_TRUE(instantiateScene(scene, &s, &ids).ok());
    for (int i = 0; i < 30; ++i) s.step();
    snap = save(s);
    std::printf("[ snapshot ] %s: %d bodies, %d joints, %zu contacts, %zu bytes\n", name,
                s.bodyCount(), s.jointCount(), s.contacts().size(), snap.size());
  }
}

// ---------------------------------------------------------------------------------------------
// Bad snapshots: an error with a message, and the target world exactly as it was.

namespace {

constexpr size_t kHeader = 28;  // magic, version, payload size, checksum

uint64_t fnv1a(const uint8_t* p, size_t n) {
  uint64_t h = 1469598103934665603ull;
  for (size_t i = 0; i < n; ++i) {
    h ^= p[i];
    h *= 1099511628211ull;
  }
  return h;
}

/// Rewrites the header's checksum, so a deliberate change reaches the parser.
void fixChecksum(Bytes* b) {
  uint64_t h = fnv1a(b->data() + kHeader, b->size() - kHeader);
  for (int i = 0; i < 8; ++i) (*b)[20 + size_t(i)] = uint8_t(h >> (8 * i));
}

/// A small world: ground, a few bodies in contact, a hull, a joint, free slots.
void buildSmallWorld(World& w) {
  addGround(w);
  BodyId a = addBody(w, boxBody({0, 0, 0.5f}, {0.5f, 0.5f, 0.5f}));
  BodyId gone = addBody(w, sphereBody({3, 0, 0.5f}, 0.5f));
  BodyDef hd;
  hd.position = {0, 0, 1.4f};
  ShapeDef hs;
  hs.geom = ShapeGeom::convexHull(hullOf(
      {{0.3f, 0.3f, 0.3f}, {-0.3f, -0.3f, 0.3f}, {-0.3f, 0.3f, -0.3f}, {0.3f, -0.3f, -0.3f}}));
  hd.shapes.push_back(hs);
  BodyId h = addBody(w, hd);
  JointDef jd;
  jd.type = JointType::Hinge;
  jd.bodyA = a;
  jd.bodyB = h;
  jd.anchorA = {0, 0, 0.5f};
  jd.anchorB = {0, 0, -0.4f};
  jd.axisA = jd.axisB = {1, 0, 0};
  jd.enableMotor = true;
  jd.motorSpeed = 1;
  jd.maxMotorForce = 10;
  ASSERT_TRUE(w.createJoint(jd, nullptr).ok());
  ASSERT_TRUE(w.destroyBody(gone).ok());
  for (int i = 0; i < 10; ++i) w.step();
}

/// A used world the bad snapshots are restored into, and what it looks like.
struct Target {
  World w;
  Bytes before;
  uint64_t hash = 0;
  int bodies = 0;
  Target() {
    addGround(w);
    for (int i = 0; i < 5; ++i) addBody(w, sphereBody({0.1f * i, 0, 0.5f + 1.1f * i}, 0.5f));
    for (int i = 0; i < 7; ++i) w.step();
    before = save(w);
    hash = w.stateHash();
    bodies = w.bodyCount();
  }
  /// Restores `bad`, which must fail and leave the world as it was; returns the message.
  std::string expectRejected(const Bytes& bad, const std::string& what) {
    Status st = w.restoreSnapshot(bad.data(), bad.size());
    EXPECT_FALSE(st.ok()) << what;
    EXPECT_FALSE(st.message.empty()) << what;
    EXPECT_EQ(w.stateHash(), hash) << what;
    EXPECT_EQ(w.bodyCount(), bodies) << what;
    return st.message;
  }
  void expectUnchanged() { EXPECT_EQ(save(w), before); }
};

}  // namespace

TEST(Snapshot, RejectsEmptyBuffer) {
  Target t;
  t.expectRejected({}, "empty");
  EXPECT_FALSE(t.w.restoreSnapshot(nullptr, 0).ok());
  EXPECT_NE(t.expectRejected({}, "empty").find("truncated"), std::string::npos);
  t.expectUnchanged();
}

TEST(Snapshot, RejectsWrongMagicAndVersion) {
  World src;
  buildSmallWorld(src);
  Bytes snap = save(src);
  Target t;
  Bytes bad = snap;
  bad[0] = 'X';
  EXPECT_NE(t.expectRejected(bad, "magic").find("magic"), std::string::npos);
  bad = snap;
  bad[8] = 3;  // version 3 (this build writes 4)
  EXPECT_NE(t.expectRejected(bad, "version").find("version"), std::string::npos);
  bad = snap;
  bad[11] = 0x80;
  t.expectRejected(bad, "version");
  t.expectUnchanged();
}

TEST(Snapshot, RejectsEveryTruncation) {
  World src;
  buildSmallWorld(src);
  Bytes snap = save(src);
  ASSERT_GT(snap.size(), 200u);
  Target t;
  for (size_t n = 0; n < snap.size(); ++n) {
    Bytes cut(snap.begin(), snap.begin() + ptrdiff_t(n));
    t.expectRejected(cut, "truncated to " + std::to_string(n));
  }
  // Truncated with the header patched to match: the parser itself finds the end.
  for (size_t n = kHeader; n < snap.size(); ++n) {
    Bytes cut(snap.begin(), snap.begin() + ptrdiff_t(n));
    uint64_t payload = n - kHeader;
    for (int i = 0; i < 8; ++i) cut[12 + size_t(i)] = uint8_t(payload >> (8 * i));
    fixChecksum(&cut);
    t.expectRejected(cut, "truncated (header patched) to " + std::to_string(n));
  }
  // Trailing bytes are an error too.
  Bytes longer = snap;
  longer.push_back(0);
  t.expectRejected(longer, "one byte too many");
  t.expectUnchanged();
}

TEST(Snapshot, RejectsEverySingleByteCorruption) {
  World src;
  buildSmallWorld(src);
  Bytes snap = save(src);
  Target t;
  for (size_t i = 0; i < snap.size(); ++i) {
    for (uint8_t flip : {uint8_t(0x01), uint8_t(0x80), uint8_t(0xFF)}) {
      Bytes bad = snap;
      bad[i] ^= flip;
      t.expectRejected(bad, "byte " + std::to_string(i) + " ^ " + std::to_string(flip));
    }
  }
  t.expectUnchanged();
}

TEST(Snapshot, RejectsAbsurdCountsNonFiniteNumbersAndDanglingIds) {
  // Every 4-byte window of the payload set to 0xFFFFFFFF with a valid checksum: counts
  // become absurd, floats NaN, ids dangling, enums and flags out of range. The parser must
  // reject each, or accept a finite in-range value: then the world must still step.
  World src;
  buildSmallWorld(src);
  Bytes snap = save(src);
  Target t;
  std::set<std::string> kinds;
  int accepted = 0;
  for (size_t i = kHeader; i + 4 <= snap.size(); ++i) {
    Bytes bad = snap;
    for (size_t k = 0; k < 4; ++k) bad[i + k] = 0xFF;
    fixChecksum(&bad);
    Status st = t.w.restoreSnapshot(bad.data(), bad.size());
    if (st.ok()) {
      ++accepted;
      t.w.step();  // whatever was accepted must be safe to simulate
      ASSERT_TRUE(t.w.restoreSnapshot(t.before.data(), t.before.size()).ok());
      continue;
    }
    EXPECT_FALSE(st.message.empty());
    EXPECT_EQ(t.w.stateHash(), t.hash) << "offset " << i << ": " << st.message;
    EXPECT_EQ(t.w.bodyCount(), t.bodies) << "offset " << i;
    for (const char* kind : {"count", "non-finite", "does not exist", "never existed", "section",
                             "out of range", "flag", "generation"}) {
      if (st.message.find(kind) != std::string::npos) kinds.insert(kind);
    }
  }
  t.expectUnchanged();
  for (const char* kind : {"count", "non-finite", "does not exist", "section", "out of range"})
    EXPECT_TRUE(kinds.count(kind)) << "no error mentioned \"" << kind << "\"";
  // What is accepted is finite and in range (a float whose top byte became 0xFF is a huge
  // negative number, a statistic any value): nonsense physics, but safe to step.
  std::printf("[ snapshot ] %zu windows, %d accepted\n", snap.size() - kHeader - 3, accepted);
}

TEST(Snapshot, RejectsStructurallyBadButChecksummedSnapshots) {
  World src;
  buildSmallWorld(src);
  Bytes snap = save(src);
  Target t;
  // A huge payload size with the right checksum of what is there.
  Bytes bad = snap;
  bad[19] = 0x7F;
  t.expectRejected(bad, "huge payload size");
  // First section tag renamed.
  bad = snap;
  bad[kHeader] = 'X';
  fixChecksum(&bad);
  EXPECT_NE(t.expectRejected(bad, "section tag").find("section"), std::string::npos);
  // First section's length too large.
  bad = snap;
  bad[kHeader + 4 + 7] = 0x10;
  fixChecksum(&bad);
  t.expectRejected(bad, "section length");
  t.expectUnchanged();
}
