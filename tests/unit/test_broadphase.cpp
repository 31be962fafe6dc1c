// Broad phase: pair lists and queries checked against O(n^2) brute force on random scenes,
// fat-margin rules, static handling, determinism, and a disabled timing run at scale.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <random>
#include <string>
#include <vector>

#include "phys/collision/broadphase.h"

namespace phys {
namespace {

// The test's own model of the proxies: fat boxes are tracked here by the documented rule,
// not read back from the broad phase, so a wrong fat box shows up as a wrong pair list.
struct ModelProxy {
  int32_t id = -1;
  uint32_t user = 0;
  AABB fat;
  bool isStatic = false;
};

std::vector<ProxyPair> bruteForcePairs(const std::vector<ModelProxy>& live) {
  std::vector<ProxyPair> pairs;
  for (size_t i = 0; i < live.size(); ++i) {
    for (size_t j = i + 1; j < live.size(); ++j) {
      if (live[i].isStatic && live[j].isStatic) continue;
      if (!overlaps(live[i].fat, live[j].fat)) continue;
      uint32_t a = live[i].user, b = live[j].user;
      pairs.push_back({std::min(a, b), std::max(a, b)});
    }
  }
  std::sort(pairs.begin(), pairs.end());
  return pairs;
}

AABB boxAt(Vec3 c, Vec3 half) {
  return {c - half, c + half};
}

// A random scene driver: boxes of mixed sizes (a few large "ground" boxes, some degenerate),
// random small and large moves, creates, destroys and static switches. Users are a shuffled
// sparse set so user order differs from proxy-index order, and freed users get reused.
class RandomScene {
 public:
  // userBase: added to every user value (large values take the broad phase's other path).
  explicit RandomScene(uint32_t seed, uint32_t userBase = 0) : rng_(seed) {
    for (uint32_t u = 0; u < 200000; u += 7) freeUsers_.push_back(userBase + u * 13 + 5);
    std::shuffle(freeUsers_.begin(), freeUsers_.end(), rng_);
  }

  float uniform(float lo, float hi) { return std::uniform_real_distribution<float>(lo, hi)(rng_); }
  int randInt(int n) { return std::uniform_int_distribution<int>(0, n - 1)(rng_); }

  AABB randomTight() {
    Vec3 c{uniform(-kWorld, kWorld), uniform(-kWorld, kWorld), uniform(-kWorld, kWorld)};
    int kind = randInt(100);
    Vec3 half;
    if (kind == 0) {
      half = {uniform(5, 15), uniform(0.2f, 1), uniform(5, 15)};  // ground-like slab
    } else if (kind == 1) {
      half = {0, 0, 0};  // degenerate point box
    } else {
      half = {uniform(0.1f, 1), uniform(0.1f, 1), uniform(0.1f, 1)};
    }
    return boxAt(c, half);
  }

  void create(BroadPhase* bp, bool isStatic) {
    ModelProxy m;
    m.user = freeUsers_.back();
    freeUsers_.pop_back();
    AABB tight = randomTight();
    m.fat = inflate(tight, kMargin);
    m.isStatic = isStatic;
    m.id = bp->createProxy(tight, kMargin, m.user, isStatic);
    live_.push_back(m);
  }

  void destroy(BroadPhase* bp, int k) {
    bp->destroyProxy(live_[k].id);
    freeUsers_.insert(freeUsers_.begin() + randInt(int(freeUsers_.size()) + 1), live_[k].user);
    live_[k] = live_.back();
    live_.pop_back();
  }

  void move(BroadPhase* bp, int k) {
    ModelProxy& m = live_[k];
    Vec3 c = center(m.fat), half = (m.fat.hi - m.fat.lo) * 0.5f - Vec3{kMargin, kMargin, kMargin};
    float step = randInt(4) == 0 ? 3.0f : 0.08f;  // mostly jitter inside the fat box
    c += Vec3{uniform(-step, step), uniform(-step, step), uniform(-step, step)};
    if (randInt(10) == 0) half = half * uniform(0.5f, 1.5f);
    AABB tight = boxAt(c, half);
    bool expectChange = !contains(m.fat, tight);
    if (expectChange) m.fat = inflate(tight, kMargin);
    EXPECT_EQ(bp->moveProxy(m.id, tight, kMargin), expectChange);
  }

  void toggleStatic(BroadPhase* bp, int k) {
    live_[k].isStatic = !live_[k].isStatic;
    bp->setStatic(live_[k].id, live_[k].isStatic);
  }

  // One round of `edits` random edits.
  void randomRound(BroadPhase* bp, int edits) {
    for (int e = 0; e < edits; ++e) {
      int r = randInt(100);
      if (r < 70 && !live_.empty()) {
        move(bp, randInt(int(live_.size())));
      } else if (r < 82) {
        create(bp, randInt(3) == 0);
      } else if (r < 94 && !live_.empty()) {
        destroy(bp, randInt(int(live_.size())));
      } else if (!live_.empty()) {
        toggleStatic(bp, randInt(int(live_.size())));
      }
    }
  }

  static Vec3 center(const AABB& b) { return (b.lo + b.hi) * 0.5f; }

  const std::vector<ModelProxy>& live() const { return live_; }

  static constexpr float kWorld = 20.0f;
  static constexpr float kMargin = 0.1f;

 private:
  std::mt19937 rng_;
  std::vector<ModelProxy> live_;
  std::vector<uint32_t> freeUsers_;
};

TEST(BroadPhase, EmptyAndCount) {
  BroadPhase bp;
  std::vector<ProxyPair> out{{1, 2}};
  bp.computePairs(&out);
  EXPECT_TRUE(out.empty());
  EXPECT_EQ(bp.proxyCount(), 0);
  int32_t a = bp.createProxy(boxAt({0, 0, 0}, {1, 1, 1}), 0.1f, 5, false);
  int32_t b = bp.createProxy(boxAt({10, 0, 0}, {1, 1, 1}), 0.1f, 6, false);
  EXPECT_EQ(bp.proxyCount(), 2);
  bp.computePairs(&out);
  EXPECT_TRUE(out.empty());
  bp.destroyProxy(a);
  bp.destroyProxy(b);
  EXPECT_EQ(bp.proxyCount(), 0);
  bp.computePairs(&out);
  EXPECT_TRUE(out.empty());
}

void expectQueriesMatch(const BroadPhase& bp, const std::vector<ModelProxy>& live,
                        std::mt19937* rng, int count) {
  std::uniform_real_distribution<float> pos(-25, 25), size(0, 4);
  for (int q = 0; q < count; ++q) {
    AABB box = boxAt({pos(*rng), pos(*rng), pos(*rng)}, {size(*rng), size(*rng), size(*rng)});
    std::vector<uint32_t> got, expected;
    bp.query(box, [&](uint32_t u) { got.push_back(u); });
    for (const ModelProxy& m : live) {
      if (overlaps(m.fat, box)) expected.push_back(m.user);
    }
    std::sort(got.begin(), got.end());
    std::sort(expected.begin(), expected.end());
    ASSERT_EQ(got, expected) << "query " << q;
  }
}

// The core check: after every round of random edits the incremental pair list equals the
// brute-force list over the model's fat boxes (sorted, a < b, no duplicates, no
// static-static pairs), and every fat box matches the model. Small rounds take the
// incremental path, big ones the rebuild and full-recompute paths.
void checkRandomScene(uint32_t seed, uint32_t userBase, int rounds) {
  RandomScene scene(seed, userBase);
  BroadPhase bp;
  std::mt19937 queryRng(seed);
  for (int i = 0; i < 2500; ++i) scene.create(&bp, i % 4 == 0);
  std::vector<ProxyPair> out;
  for (int round = 0; round < rounds; ++round) {
    SCOPED_TRACE(round);
    scene.randomRound(&bp, round % 5 == 4 ? 2000 : 60);
    // Queries between edits and computePairs see the proxies not yet in the trees too.
    if (round % 3 == 0) expectQueriesMatch(bp, scene.live(), &queryRng, 20);
    if (round % 7 == 3) bp.computePairs(&out);  // back-to-back calls, one with no edits
    bp.computePairs(&out);
    ASSERT_EQ(bp.proxyCount(), int(scene.live().size()));
    std::vector<ProxyPair> expected = bruteForcePairs(scene.live());
    ASSERT_EQ(out.size(), expected.size());
    ASSERT_TRUE(out == expected);
    for (const ModelProxy& m : scene.live()) {
      const AABB& f = bp.fatAABB(m.id);
      ASSERT_TRUE(f.lo == m.fat.lo && f.hi == m.fat.hi);
    }
  }
  EXPECT_GT(out.size(), 1000u);  // the scene is dense enough to mean something
}

TEST(BroadPhase, RandomScenesMatchBruteForce) {
  for (uint32_t seed : {1u, 2u, 3u}) {
    SCOPED_TRACE(seed);
    checkRandomScene(seed, 0, 30);
  }
}

// User values near the top of the range (no direct bitmap over them).
TEST(BroadPhase, RandomSceneLargeUserValues) {
  checkRandomScene(4, 0xF0000000u, 15);
}

// Many identical boxes (coincident centroids: the tree builder cannot split them by
// position) plus a static group, all overlapping: every dynamic pair and every
// dynamic-static pair, then a few leave.
TEST(BroadPhase, DenseClusterAllOverlap) {
  BroadPhase bp;
  std::vector<ModelProxy> live;
  const AABB box = boxAt({1, 2, 3}, {0.5f, 0.5f, 0.5f});
  for (uint32_t u = 0; u < 301; ++u) {
    ModelProxy m;
    m.user = u * 100 + 7;  // spread so that the pair sort needs an odd number of passes
    m.isStatic = u >= 256;
    m.fat = inflate(box, 0.1f);
    m.id = bp.createProxy(box, 0.1f, m.user, m.isStatic);
    live.push_back(m);
  }
  std::vector<ProxyPair> out;
  bp.computePairs(&out);
  EXPECT_EQ(out.size(), 256u * 255u / 2 + 256u * 45u);
  EXPECT_TRUE(out == bruteForcePairs(live));
  for (int k = 0; k < 40; ++k) {
    ModelProxy& m = live[k * 7];
    AABB moved = boxAt({1, 2 + float(k + 1) * 0.3f, 3}, {0.5f, 0.5f, 0.5f});
    EXPECT_TRUE(bp.moveProxy(m.id, moved, 0.1f));
    m.fat = inflate(moved, 0.1f);
  }
  bp.computePairs(&out);
  EXPECT_TRUE(out == bruteForcePairs(live));
}

// Identical boxes inserted one at a time: the insertion cost cannot tell them apart, so the
// tree degenerates into a chain hundreds of levels deep. Slow by nature (everything
// overlaps), but it must stay correct through long descents and refit walks.
TEST(BroadPhase, DegenerateDeepTree) {
  BroadPhase bp;
  std::vector<ModelProxy> live;
  std::vector<ProxyPair> out;
  const AABB box = boxAt({0, 0, 0}, {1, 1, 1});
  for (uint32_t u = 0; u < 600; ++u) {
    ModelProxy m;
    m.user = 1000 - u;
    m.fat = inflate(box, 0.1f);
    m.id = bp.createProxy(box, 0.1f, m.user, false);
    live.push_back(m);
    if (u % 50 == 0 || u < 64) bp.computePairs(&out);  // small batches: incremental inserts
  }
  bp.computePairs(&out);
  EXPECT_TRUE(out == bruteForcePairs(live));
  for (int k = 0; k < 300; ++k) {
    bp.destroyProxy(live[k].id);
    live[k] = live.back();
    live.pop_back();
  }
  bp.computePairs(&out);
  EXPECT_TRUE(out == bruteForcePairs(live));
  std::vector<uint32_t> hits;
  bp.query(boxAt({0.5f, 0.5f, 0.5f}, {0.1f, 0.1f, 0.1f}), [&](uint32_t u) { hits.push_back(u); });
  EXPECT_EQ(hits.size(), live.size());
}

TEST(BroadPhase, StaticStaticNeverPaired) {
  BroadPhase bp;
  std::vector<ProxyPair> out;
  // A stack of overlapping static boxes: no pairs at all.
  for (uint32_t u = 0; u < 20; ++u) {
    bp.createProxy(boxAt({0, float(u) * 0.5f, 0}, {1, 1, 1}), 0.1f, 100 + u, true);
  }
  bp.computePairs(&out);
  EXPECT_TRUE(out.empty());
  // One dynamic box overlapping all of them pairs with each one.
  int32_t d = bp.createProxy(boxAt({0, 5, 0}, {1, 6, 1}), 0.1f, 7, false);
  bp.computePairs(&out);
  ASSERT_EQ(out.size(), 20u);
  for (uint32_t u = 0; u < 20; ++u) EXPECT_EQ(out[u], (ProxyPair{7, 100 + u}));
  // Turning it static removes them all again.
  bp.setStatic(d, true);
  bp.computePairs(&out);
  EXPECT_TRUE(out.empty());
}

TEST(BroadPhase, MoveProxyFatMargin) {
  BroadPhase bp;
  const float margin = 0.25f;
  const AABB tight = boxAt({0, 0, 0}, {1, 1, 1});
  int32_t p = bp.createProxy(tight, margin, 1, false);
  const AABB fat0 = bp.fatAABB(p);
  EXPECT_TRUE(fat0.lo == (Vec3{-1.25f, -1.25f, -1.25f}));
  EXPECT_TRUE(fat0.hi == (Vec3{1.25f, 1.25f, 1.25f}));

  // Small move inside the fat box: nothing changes.
  EXPECT_FALSE(bp.moveProxy(p, boxAt({0.1f, -0.2f, 0.05f}, {1, 1, 1}), margin));
  EXPECT_TRUE(bp.fatAABB(p).lo == fat0.lo && bp.fatAABB(p).hi == fat0.hi);
  // Touching the fat box from inside still counts as contained.
  EXPECT_FALSE(bp.moveProxy(p, boxAt({0.25f, 0, 0}, {1, 1, 1}), margin));
  // Leaving it: the fat box becomes the new tight box inflated by the (new) margin.
  const AABB moved = boxAt({0.5f, 0, 0}, {1, 1, 1});
  EXPECT_TRUE(bp.moveProxy(p, moved, 0.5f));
  EXPECT_TRUE(bp.fatAABB(p).lo == inflate(moved, 0.5f).lo);
  EXPECT_TRUE(bp.fatAABB(p).hi == inflate(moved, 0.5f).hi);
  // Growing in place past the margin also re-fattens.
  EXPECT_TRUE(bp.moveProxy(p, boxAt({0.5f, 0, 0}, {2, 1, 1}), margin));

  // A fat-box change is what the pair list sees: a pair appears only when the fat box moves.
  int32_t q = bp.createProxy(boxAt({5, 0, 0}, {1, 1, 1}), margin, 2, false);
  std::vector<ProxyPair> out;
  bp.computePairs(&out);
  EXPECT_TRUE(out.empty());
  EXPECT_TRUE(bp.moveProxy(q, boxAt({3.5f, 0, 0}, {1, 1, 1}), margin));
  bp.computePairs(&out);
  ASSERT_EQ(out.size(), 1u);
  EXPECT_EQ(out[0], (ProxyPair{1, 2}));
  // Moving back inside its new fat box keeps the pair (the fat boxes did not change).
  EXPECT_FALSE(bp.moveProxy(q, boxAt({3.6f, 0, 0}, {1, 1, 1}), margin));
  bp.computePairs(&out);
  EXPECT_EQ(out.size(), 1u);
}

TEST(BroadPhase, DestroyedProxiesVanish) {
  BroadPhase bp;
  std::vector<ProxyPair> out;
  int32_t a = bp.createProxy(boxAt({0, 0, 0}, {1, 1, 1}), 0.1f, 30, false);
  int32_t b = bp.createProxy(boxAt({1, 0, 0}, {1, 1, 1}), 0.1f, 10, false);
  int32_t c = bp.createProxy(boxAt({2, 0, 0}, {1, 1, 1}), 0.1f, 20, true);
  bp.computePairs(&out);
  EXPECT_EQ(out, (std::vector<ProxyPair>{{10, 20}, {10, 30}, {20, 30}}));
  bp.destroyProxy(b);
  bp.computePairs(&out);
  EXPECT_EQ(out, (std::vector<ProxyPair>{{20, 30}}));
  // Destroy and recreate before the next computePairs; the slot is reused under a new
  // user, far away: the old pairs must not survive under either user.
  bp.destroyProxy(a);
  int32_t d = bp.createProxy(boxAt({50, 0, 0}, {1, 1, 1}), 0.1f, 40, false);
  bp.computePairs(&out);
  EXPECT_TRUE(out.empty());
  // And the reused slot pairs correctly once it overlaps again.
  EXPECT_TRUE(bp.moveProxy(d, boxAt({2.5f, 0, 0}, {1, 1, 1}), 0.1f));
  bp.computePairs(&out);
  EXPECT_EQ(out, (std::vector<ProxyPair>{{20, 40}}));
  bp.destroyProxy(c);
  bp.computePairs(&out);
  EXPECT_TRUE(out.empty());
  EXPECT_EQ(bp.proxyCount(), 1);
}

TEST(BroadPhase, SetStaticSwitching) {
  BroadPhase bp;
  std::vector<ProxyPair> out;
  int32_t a = bp.createProxy(boxAt({0, 0, 0}, {1, 1, 1}), 0.1f, 1, false);
  int32_t b = bp.createProxy(boxAt({1, 0, 0}, {1, 1, 1}), 0.1f, 2, false);
  bp.computePairs(&out);
  EXPECT_EQ(out, (std::vector<ProxyPair>{{1, 2}}));
  bp.setStatic(a, true);  // static-dynamic still pairs
  bp.computePairs(&out);
  EXPECT_EQ(out, (std::vector<ProxyPair>{{1, 2}}));
  bp.setStatic(b, true);  // static-static does not
  bp.computePairs(&out);
  EXPECT_TRUE(out.empty());
  bp.setStatic(b, true);  // no-op
  bp.computePairs(&out);
  EXPECT_TRUE(out.empty());
  bp.setStatic(a, false);
  bp.computePairs(&out);
  EXPECT_EQ(out, (std::vector<ProxyPair>{{1, 2}}));
  // Static proxies can still be queried and keep their fat box.
  std::vector<uint32_t> hits;
  bp.query(boxAt({1, 0, 0}, {0.1f, 0.1f, 0.1f}), [&](uint32_t u) { hits.push_back(u); });
  std::sort(hits.begin(), hits.end());
  EXPECT_EQ(hits, (std::vector<uint32_t>{1, 2}));
}

TEST(BroadPhase, QueryMatchesBruteForce) {
  RandomScene scene(42);
  BroadPhase bp;
  std::mt19937 rng(7);
  // Before any computePairs: 5000 creations, past the point where the pending list is
  // folded into the trees on its own.
  for (int i = 0; i < 5000; ++i) scene.create(&bp, i % 3 == 0);
  expectQueriesMatch(bp, scene.live(), &rng, 200);
  std::vector<ProxyPair> out;
  bp.computePairs(&out);
  expectQueriesMatch(bp, scene.live(), &rng, 200);
  scene.randomRound(&bp, 300);
  expectQueriesMatch(bp, scene.live(), &rng, 200);
  bp.computePairs(&out);
  expectQueriesMatch(bp, scene.live(), &rng, 200);
}

// Two broad phases fed the same calls give identical outputs (and proxy indices) in every
// round, including after heavy churn of the trees and free lists.
TEST(BroadPhase, Deterministic) {
  auto run = [](std::vector<std::vector<ProxyPair>>* pairs, std::vector<int32_t>* ids,
                std::vector<std::vector<uint32_t>>* hits) {
    RandomScene scene(99);
    BroadPhase bp;
    for (int i = 0; i < 2000; ++i) scene.create(&bp, i % 5 == 0);
    for (int round = 0; round < 20; ++round) {
      scene.randomRound(&bp, 300);
      pairs->emplace_back();
      bp.computePairs(&pairs->back());
      hits->emplace_back();
      bp.query(boxAt({0, 0, 0}, {5, 5, 5}), [&](uint32_t u) { hits->back().push_back(u); });
    }
    for (const ModelProxy& m : scene.live()) ids->push_back(m.id);
  };
  std::vector<std::vector<ProxyPair>> p1, p2;
  std::vector<int32_t> i1, i2;
  std::vector<std::vector<uint32_t>> h1, h2;
  run(&p1, &i1, &h1);
  run(&p2, &i2, &h2);
  ASSERT_EQ(p1.size(), p2.size());
  for (size_t r = 0; r < p1.size(); ++r) EXPECT_TRUE(p1[r] == p2[r]) << "round " << r;
  EXPECT_EQ(i1, i2);
  EXPECT_EQ(h1, h2);  // same visiting order too, not just the same set
}

// Wall-clock and CPU time in ms since construction. Both are printed: the build machines
// are shared, and CPU time is far less disturbed by the neighbours.
struct Stopwatch {
  using Clock = std::chrono::steady_clock;
  Clock::time_point wall0 = Clock::now();
  std::clock_t cpu0 = std::clock();
  double wallMs() const {
    return std::chrono::duration<double, std::milli>(Clock::now() - wall0).count();
  }
  double cpuMs() const { return 1000.0 * double(std::clock() - cpu0) / CLOCKS_PER_SEC; }
};

std::string medianAndMin(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.2f ms (min %.2f)", v[v.size() / 2], v[0]);
  return buf;
}

// A settling-pile-like scene: n unit boxes in a lattice with small gaps and slight jitter
// (every fat box touches its 26 neighbours), a static ground, and each round 1% of the
// boxes slide out of their fat box while the rest jitter inside it.
void runScale(int n) {
  const float margin = 0.1f;
  const int side = int(std::ceil(std::cbrt(double(n))));
  std::mt19937 rng(1);
  std::uniform_real_distribution<float> jitter(-0.02f, 0.02f);
  std::vector<AABB> tight(n);
  for (int i = 0; i < n; ++i) {
    Vec3 c{float(i % side) * 1.05f, 0.55f + float(i / (side * side)) * 1.05f,
           float((i / side) % side) * 1.05f};
    c += Vec3{jitter(rng), jitter(rng), jitter(rng)};
    tight[i] = boxAt(c, {0.5f, 0.5f, 0.5f});
  }

  BroadPhase bp;
  std::vector<int32_t> ids(n);
  std::vector<ProxyPair> out;
  Stopwatch create;
  bp.createProxy({{-1000, -1, -1000}, {1000, 0, 1000}}, margin, uint32_t(n), true);
  for (int i = 0; i < n; ++i) ids[i] = bp.createProxy(tight[i], margin, uint32_t(i), false);
  const double createWall = create.wallMs(), createCpu = create.cpuMs();
  Stopwatch first;
  bp.computePairs(&out);
  const double firstWall = first.wallMs(), firstCpu = first.cpuMs();
  std::printf(
      "n=%d initial build: createProxy x%d %.1f ms (cpu %.1f), first computePairs %.1f ms"
      " (cpu %.1f), %zu pairs\n",
      n, n + 1, createWall, createCpu, firstWall, firstCpu, out.size());

  std::uniform_int_distribution<int> pick(0, n - 1);
  const int rounds = 50, moved = n / 100;
  std::vector<double> moveWall, pairsWall, pairsCpu, noopWall;
  size_t changed = 0;
  for (int r = 0; r < rounds; ++r) {
    Stopwatch move;
    for (int i = 0; i < n; ++i) {
      // Everyone jitters a little inside the fat box...
      AABB b = tight[i];
      Vec3 d{jitter(rng) * 0.5f, jitter(rng) * 0.5f, jitter(rng) * 0.5f};
      changed += bp.moveProxy(ids[i], {b.lo + d, b.hi + d}, margin);
    }
    for (int k = 0; k < moved; ++k) {
      // ...and 1% slide by more than the margin.
      int i = pick(rng);
      Vec3 d{jitter(rng) * 10, -0.15f, jitter(rng) * 10};
      tight[i] = {tight[i].lo + d, tight[i].hi + d};
      changed += bp.moveProxy(ids[i], tight[i], margin);
    }
    moveWall.push_back(move.wallMs());
    Stopwatch pairs;
    bp.computePairs(&out);
    pairsWall.push_back(pairs.wallMs());
    pairsCpu.push_back(pairs.cpuMs());
    Stopwatch noop;
    bp.computePairs(&out);  // nothing changed in between
    noopWall.push_back(noop.wallMs());
  }
  std::printf(
      "n=%d per round, median over %d rounds; %d moved out of the fat box (%.0f fat boxes"
      " changed):\n",
      n, rounds, moved, double(changed) / rounds);
  std::printf("  moveProxy x%d: %s\n", n + moved, medianAndMin(moveWall).c_str());
  std::printf("  computePairs: %s, cpu %s\n", medianAndMin(pairsWall).c_str(),
              medianAndMin(pairsCpu).c_str());
  std::printf("  computePairs with nothing changed: %s, %zu pairs\n",
              medianAndMin(noopWall).c_str(), out.size());
}

TEST(BroadPhase, DISABLED_Scale100k) {
  runScale(100000);
}
TEST(BroadPhase, DISABLED_Scale1M) {
  runScale(1000000);
}

}  // namespace
}  // namespace phys
