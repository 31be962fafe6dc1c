// What one step may cost (issue 21): the broad phase's pairs are bounded
// (WorldDef::maxContactPairs), production stops at the bound instead of building every pair
// and cutting, the pairs kept are deterministic and depend only on the bodies' bounds, scenes
// under the bound are untouched, and nothing thrown inside a step (std::bad_alloc) leaves
// World::step: the step is undone and counted.
//
// Allocation failures are injected by this file's replacement of the global operator new (the
// test program's only one): armed, the n-th allocation from then on throws std::bad_alloc.
#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <cstdlib>
#include <new>
#include <vector>

#include "phys/collision/broadphase.h"
#include "test_util.h"

namespace {
std::atomic<long> gFailIn{0};  // 0: off; n > 0: the n-th allocation from now throws
std::atomic<long> gFailed{0};  // allocations made to fail so far
}  // namespace

[[gnu::noinline]] void* operator new(std::size_t n) {
  if (gFailIn.load(std::memory_order_relaxed) > 0 && gFailIn.fetch_sub(1) == 1) {
    gFailed.fetch_add(1);
    throw std::bad_alloc();
  }
  if (void* p = std::malloc(n ? n : 1)) return p;
  throw std::bad_alloc();
}
[[gnu::noinline]] void operator delete(void* p) noexcept {
  std::free(p);
}
[[gnu::noinline]] void operator delete(void* p, std::size_t) noexcept {
  std::free(p);
}

namespace phys {
namespace {

using test::addBody;
using test::addGround;
using test::boxBody;

/// n boxes of 2 m, all at the origin: n (n - 1) / 2 overlapping pairs (2,000 make 1,999,000,
/// which the old step built in full: 53 s and 3.3 GB; 20,000 made it throw std::bad_alloc).
void addCoincidentBoxes(World& w, int n) {
  for (int i = 0; i < n; ++i) addBody(w, boxBody({0, 0, 0}, {1, 1, 1}));
}

/// A loose pile of n boxes over a ground, some overlapping (deterministic positions).
void addPile(World& w, int n) {
  addGround(w);
  for (int i = 0; i < n; ++i) {
    const float x = float(i % 5) * 0.9f, y = float((i / 5) % 5) * 0.9f, z = 0.5f + float(i / 25);
    addBody(w, boxBody({x + 0.03f * float(i % 3), y, z}, {0.5f, 0.5f, 0.5f}));
  }
}

TEST(StepBudget, CoincidentBoxesStopAtTheBound) {
  WorldDef def;
  def.maxContactPairs = 10000;
  World w(def);
  addCoincidentBoxes(w, 2000);
  w.step();
  const StepStats& st = w.stats();
  EXPECT_EQ(st.stepFailures, 0u) << st.lastGuardEvent;
  EXPECT_EQ(st.step, 1u);
  EXPECT_EQ(st.pairLimit, 10000u);
  // What the step held: the pairs, and the contacts and manifolds made of them.
  EXPECT_EQ(st.pairs, 10000);
  EXPECT_LE(st.contacts, 10000);
  EXPECT_LE(st.vectorizedManifolds, 10000);
  EXPECT_LE(st.contactPoints, 4 * 10000);
  EXPECT_GT(st.pairsDropped, 0u);
  EXPECT_EQ(st.pairLimitSteps, 1u);
  EXPECT_EQ(int(w.contacts().size()), st.contacts);
  for (BodyId id : w.bodies()) {
    BodyState s = test::stateOf(w, id);
    ASSERT_TRUE(isFinite(s.position) && isFinite(s.linearVelocity));
  }
  w.step();
  EXPECT_EQ(w.stats().pairLimitSteps, 2u);
  EXPECT_LE(w.stats().pairs, 10000);
}

TEST(StepBudget, AutomaticBound) {
  World w;
  addCoincidentBoxes(w, 3);
  w.step();
  EXPECT_EQ(w.stats().pairLimit, WorldDef::kMinAutoContactPairs);
  EXPECT_EQ(w.stats().pairsDropped, 0u);
  EXPECT_EQ(w.stats().pairs, 3);
  // Past the floor it grows with the shapes.
  World big;
  const int n = int(WorldDef::kMinAutoContactPairs / WorldDef::kAutoContactPairsPerShape) + 100;
  for (int i = 0; i < n; ++i) addBody(big, boxBody({float(i) * 3, 0, 0}));
  big.step();
  EXPECT_EQ(big.stats().pairLimit, uint32_t(n) * WorldDef::kAutoContactPairsPerShape);
  EXPECT_EQ(big.stats().pairs, 0);
}

TEST(StepBudget, OverTheBoundIsDeterministic) {
  WorldDef def;
  def.maxContactPairs = 5000;
  auto build = [&](World& w) {
    addGround(w);
    addCoincidentBoxes(w, 400);
    // A few more at other places, so that some pairs are over the cut and some under.
    for (int i = 0; i < 20; ++i) addBody(w, boxBody({0.3f * float(i), 0, 3}, {0.5f, 0.5f, 0.5f}));
  };
  World a(def), b(def);
  build(a);
  build(b);
  std::vector<uint8_t> snap;
  for (int k = 0; k < 6; ++k) {
    a.step();
    b.step();
    ASSERT_EQ(a.stateHash(), b.stateHash()) << "step " << k;
    EXPECT_GT(a.stats().pairsDropped, 0u);
    EXPECT_LE(a.stats().pairs, 5000);
    if (k == 2) {
      ASSERT_TRUE(a.saveSnapshot(&snap).ok());
    }
  }
  // The pairs kept depend only on the bodies' bounds, not on how the broad phase's trees
  // grew: a world restored from a snapshot (its trees built anew) keeps the same ones.
  World c(def), d(def);
  ASSERT_TRUE(c.restoreSnapshot(snap.data(), snap.size()).ok());
  ASSERT_TRUE(d.restoreSnapshot(snap.data(), snap.size()).ok());
  EXPECT_EQ(c.def().maxContactPairs, 5000u);
  for (int k = 3; k < 6; ++k) {
    c.step();
    d.step();
    ASSERT_EQ(c.stateHash(), d.stateHash());
  }
  EXPECT_EQ(c.stateHash(), a.stateHash());
  EXPECT_EQ(c.stats().pairLimitSteps, a.stats().pairLimitSteps);
}

TEST(StepBudget, UnderTheBoundNothingChanges) {
  // The same pile with the automatic bound and with a bound exactly at its largest pair
  // count: bit-identical, nothing dropped.
  World ref;
  addPile(ref, 60);
  std::vector<uint64_t> hashes;
  int most = 0;
  for (int k = 0; k < 90; ++k) {
    ref.step();
    hashes.push_back(ref.stateHash());
    most = std::max(most, ref.stats().pairs);
    ASSERT_EQ(ref.stats().pairsDropped, 0u);
  }
  ASSERT_GT(most, 60);
  WorldDef def;
  def.maxContactPairs = uint32_t(most);
  World tight(def);
  addPile(tight, 60);
  for (int k = 0; k < 90; ++k) {
    tight.step();
    ASSERT_EQ(tight.stateHash(), hashes[size_t(k)]) << "step " << k;
    ASSERT_EQ(tight.stats().pairsDropped, 0u);
  }
  EXPECT_EQ(tight.stats().pairLimitSteps, 0u);
  // One pair less and the step that needed it is cut (and says so).
  def.maxContactPairs = uint32_t(most - 1);
  World cut(def);
  addPile(cut, 60);
  for (int k = 0; k < 90; ++k) cut.step();
  EXPECT_GT(cut.stats().pairLimitSteps, 0u);
}

TEST(StepBudget, BroadPhaseStopsAtTheBoundWithTheListsFirstPairs) {
  // 2,000 coincident proxies and 100 apart: the bounded list is the full list's beginning,
  // found again after moves (a cut list is not updated incrementally), and back to the full
  // list once the pairs fit.
  BroadPhase full, bounded;
  const AABB box{{-1, -1, -1}, {1, 1, 1}};
  std::vector<int32_t> ids;
  for (uint32_t u = 0; u < 2100; ++u) {
    const AABB b = u < 2000 ? box : AABB{{10.f * float(u), 0, 0}, {10.f * float(u) + 1, 1, 1}};
    full.createProxy(b, 0.05f, u * 3 + 7, false);
    ids.push_back(bounded.createProxy(b, 0.05f, u * 3 + 7, false));
  }
  std::vector<ProxyPair> all, cut;
  full.computePairs(&all);
  ASSERT_EQ(all.size(), size_t(2000) * 1999 / 2);
  EXPECT_GT(bounded.computePairs(&cut, 10000), 0u);
  ASSERT_EQ(cut.size(), 10000u);
  EXPECT_TRUE(std::equal(cut.begin(), cut.end(), all.begin()));
  // Nothing moved: the same cut list, and the same count.
  EXPECT_GT(bounded.computePairs(&cut, 10000), 0u);
  EXPECT_TRUE(std::equal(cut.begin(), cut.end(), all.begin()));
  // Move most of the pile away, one by one: each call gives the full list's first pairs.
  for (int round = 0; round < 3; ++round) {
    for (uint32_t u = 0; u < 2000; u += 7) {
      const int32_t k = int32_t(u + uint32_t(round)) % 2000;
      const AABB far{{100.f + 3.f * float(k), 50, 0}, {101.f + 3.f * float(k), 51, 1}};
      full.moveProxy(ids[size_t(k)], far, 0.05f);
      bounded.moveProxy(ids[size_t(k)], far, 0.05f);
    }
    full.computePairs(&all);
    const uint64_t dropped = bounded.computePairs(&cut, 10000);
    ASSERT_EQ(cut.size(), std::min<size_t>(all.size(), 10000));
    EXPECT_TRUE(std::equal(cut.begin(), cut.end(), all.begin())) << "round " << round;
    EXPECT_EQ(dropped > 0, all.size() > 10000);
  }
  // Spread out in a row (a few thousand pairs): the whole list, nothing dropped, and
  // incremental again.
  for (uint32_t u = 0; u < 2000; ++u) {
    const AABB far{{100.f + 0.5f * float(u), 80, 0}, {101.f + 0.5f * float(u), 81, 1}};
    full.moveProxy(ids[u], far, 0.05f);
    bounded.moveProxy(ids[u], far, 0.05f);
  }
  full.computePairs(&all);
  ASSERT_GT(all.size(), 2000u);
  ASSERT_LT(all.size(), 10000u);
  EXPECT_EQ(bounded.computePairs(&cut, 10000), 0u);
  EXPECT_EQ(cut, all);
  full.moveProxy(ids[3], box, 0.05f);
  bounded.moveProxy(ids[3], box, 0.05f);
  full.computePairs(&all);
  EXPECT_EQ(bounded.computePairs(&cut, 10000), 0u);
  EXPECT_EQ(cut, all);
}

TEST(StepBudget, BroadPhaseNeverBuildsThePairsPastTheBound) {
  // 20,000 coincident proxies overlap in 199,990,000 pairs (1.6 GB of them): at a bound of
  // 10,000 they are never built (this takes milliseconds; building them took the old code
  // tens of seconds and gigabytes), and the first pairs are user 0's.
  BroadPhase bp;
  for (uint32_t u = 0; u < 20000; ++u) bp.createProxy({{-1, -1, -1}, {1, 1, 1}}, 0.05f, u, false);
  std::vector<ProxyPair> out;
  const uint64_t dropped = bp.computePairs(&out, 10000);
  ASSERT_EQ(out.size(), 10000u);
  for (uint32_t i = 0; i < 10000; ++i) ASSERT_EQ(out[i], (ProxyPair{0, i + 1}));
  // Counted up to a budget of as many neighbours as the bound: a lower bound.
  EXPECT_GE(dropped, 9999u);
  EXPECT_LT(dropped, 199990000u);
  // A static proxy there too: its pairs with the dynamic ones count, static-static never.
  bp.createProxy({{-1, -1, -1}, {1, 1, 1}}, 0.05f, 20000, true);
  bp.createProxy({{-1, -1, -1}, {1, 1, 1}}, 0.05f, 20001, true);
  bp.computePairs(&out, 10000);
  ASSERT_EQ(out.size(), 10000u);
  EXPECT_EQ(out.back(), (ProxyPair{0, 10000}));
  bp.computePairs(&out, 40000);
  ASSERT_EQ(out.size(), 40000u);
  // User 0 has 19,999 dynamic and 2 static neighbours, then user 1's pairs begin.
  EXPECT_EQ(out[20000], (ProxyPair{0, 20001}));
  EXPECT_EQ(out[20001], (ProxyPair{1, 2}));
}

/// A dynamic hub with n distance joints to as many bodies around it (no gravity, no contacts).
void addJointHub(World& w, int n) {
  BodyDef hub = test::sphereBody({0, 0, 0}, 0.5f);
  hub.gravityScale = 0;
  const BodyId h = addBody(w, hub);
  for (int i = 0; i < n; ++i) {
    BodyDef b = test::sphereBody({3 + 2 * float(i % 40), 2 * float(i / 40), 0}, 0.5f);
    b.gravityScale = 0;
    b.linearVelocity = {0.1f * float(i % 7), 0, 0.2f};
    JointDef j;
    j.type = JointType::Distance;
    j.bodyA = h;
    j.bodyB = addBody(w, b);
    JointId id;
    ASSERT_TRUE(w.createJoint(j, &id).ok());
  }
}

TEST(StepBudget, JointsOnOneBodyPastTheDirectSolvesBoundAreIterated) {
  // K equality rows on one body make the direct solve a dense K x K block (K^3 per substep:
  // 10,000 joints on one body took minutes a step). Past 512 rows on a body the step
  // iterates the joints instead: bit for bit the iterative equality solve. Under it, the
  // direct solve as before.
  auto run = [](int joints, SolverSettings::EqualitySolve e) {
    WorldDef def;
    def.solver.equalitySolve = e;
    World w(def);
    addJointHub(w, joints);
    for (int k = 0; k < 3; ++k) w.step();
    return w.stateHash();
  };
  using E = SolverSettings::EqualitySolve;
  EXPECT_EQ(run(600, E::DirectLdl), run(600, E::Iterative));
  EXPECT_NE(run(100, E::DirectLdl), run(100, E::Iterative));
}

TEST(StepBudget, FailedAllocationInsideAStepUndoesTheStep) {
  // Every allocation a step makes, failed in turn: World::step returns, the world is as it
  // was before (guard on: its copy, contacts and warm starts included), the failure is
  // counted, and the next step is bit for bit the step that never failed.
  WorldDef def;
  def.threads = 1;  // the parallel loops' bodies do not allocate; one thread keeps it simple
  World src(def);
  addPile(src, 30);
  for (int k = 0; k < 20; ++k) src.step();
  std::vector<uint8_t> snap;
  ASSERT_TRUE(src.saveSnapshot(&snap).ok());
  src.step();
  const uint64_t next = src.stateHash();
  src.step();
  const uint64_t after = src.stateHash();

  long point = 1;
  for (; point < 100000; ++point) {
    World w(def);
    ASSERT_TRUE(w.restoreSnapshot(snap.data(), snap.size()).ok());
    const uint64_t before = w.stateHash();
    const double time = w.time();
    const uint64_t steps = w.stats().step;
    const long failedBefore = gFailed.load();
    gFailIn.store(point);
    ASSERT_NO_THROW(w.step());
    const bool failed = gFailed.load() > failedBefore;
    gFailIn.store(0);
    if (!failed) {
      // Past the step's last allocation: every one of them has failed once.
      EXPECT_EQ(w.stats().stepFailures, 0u);
      EXPECT_EQ(w.stateHash(), next);
      break;
    }
    ASSERT_EQ(w.stats().stepFailures, 1u) << "allocation " << point;
    EXPECT_NE(w.stats().lastGuardEvent.find("failed"), std::string::npos);
    ASSERT_EQ(w.stateHash(), before) << "allocation " << point;
    ASSERT_EQ(w.time(), time);
    ASSERT_EQ(w.stats().step, steps);
    w.step();
    ASSERT_EQ(w.stateHash(), next) << "allocation " << point;
    w.step();
    ASSERT_EQ(w.stateHash(), after) << "allocation " << point;
  }
  EXPECT_GT(point, 10);  // the step does allocate, so this covered something
}

TEST(StepBudget, FailedAllocationWithoutTheGuard) {
  // Without the guard's copy: the bodies are as before the step (only finalize writes them),
  // the contacts start cold, and stepping goes on.
  WorldDef def;
  def.threads = 1;
  def.guard = false;
  World src(def);
  addPile(src, 30);
  for (int k = 0; k < 20; ++k) src.step();
  std::vector<uint8_t> snap;
  ASSERT_TRUE(src.saveSnapshot(&snap).ok());
  for (long point = 1; point < 400; point += 3) {
    World w(def);
    ASSERT_TRUE(w.restoreSnapshot(snap.data(), snap.size()).ok());
    const uint64_t before = w.stateHash();
    const long failedBefore = gFailed.load();
    gFailIn.store(point);
    ASSERT_NO_THROW(w.step());
    const bool failed = gFailed.load() > failedBefore;
    gFailIn.store(0);
    if (!failed) break;
    ASSERT_EQ(w.stats().stepFailures, 1u);
    ASSERT_EQ(w.stateHash(), before);
    for (int k = 0; k < 3; ++k) w.step();
    EXPECT_EQ(w.stats().stepFailures, 1u);
    EXPECT_EQ(w.stats().step, 23u);  // the 20 before, not the failed one, 3 after
    for (BodyId id : w.bodies()) ASSERT_TRUE(isFinite(test::stateOf(w, id).position));
  }
}

}  // namespace
}  // namespace phys
