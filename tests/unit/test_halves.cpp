// Gauss-Seidel in halves and in nested parts (physics/dynamics/solver_wide.h, "Nested parts"):
// the cut and its recursion, the colour order of the contacts across a cut, the segments'
// numbering, a schedule whose parts (and separators of one depth) share no dynamic body, and
// whole worlds that give the same bits with any thread count and with the scalar rows.
#include <gtest/gtest.h>

#include <map>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "dynamics/solver.h"
#include "dynamics/solver_wide.h"
#include "phys/scene/scene.h"
#include "phys/world/world.h"
#include "solver_test_util.h"
#include "test_util.h"

using namespace phys;

namespace {

using Pairs = std::vector<std::pair<int32_t, int32_t>>;

/// Solver bodies: [0] the world, then `n` dynamic bodies.
std::vector<SolverBody> dynamicBodies(int n) {
  std::vector<SolverBody> bodies(size_t(n) + 1);
  for (int i = 1; i <= n; ++i) {
    bodies[size_t(i)].dynamic = true;
    bodies[size_t(i)].invMass = 1;
    bodies[size_t(i)].invI = Mat3::diagonal({1, 1, 1});
  }
  return bodies;
}

/// One equality row between bodies a and b, as a joint ahead of the contacts (the schedule's
/// scalar groups come first), and the solver's rows finished.
void addJointRowFirst(Solver& s, int32_t a, int32_t b) {
  s.rows.push_back(test::jointRow(a, b));
  s.indexUnits();
  s.finishRows(0, s.rows.size());
}

/// Each dynamic body meets its manifolds in their order, as in the serial sweep, through the
/// schedule's blocks from the first segment on.
void expectEachBodyMeetsItsManifoldsInOrder(const WideContacts& w,
                                            const std::vector<SolverManifold>& manifolds) {
  std::map<int32_t, uint32_t> last;
  for (size_t k = w.segment(0); k < w.schedule.size(); ++k) {
    for (uint32_t m : w.manifoldsOf(w.schedule[k].index)) {
      for (int32_t body : {manifolds[m].a, manifolds[m].b}) {
        if (body == 0) continue;
        auto it = last.find(body);
        if (it != last.end()) {
          EXPECT_LT(it->second, m) << "body " << body;
        }
        last[body] = m;
      }
    }
  }
}

/// Two rows of ten bodies along x, one above the other (z = 0 and z = 1): body 1 + i + 10 row.
struct TwoRows {
  std::vector<SolverBody> bodies = dynamicBodies(20);
  std::vector<Vec3> com = std::vector<Vec3>(21);
  TwoRows() {
    for (int row = 0; row < 2; ++row)
      for (int i = 0; i < 10; ++i) com[size_t(id(row, i))] = {float(i), 0, float(row)};
  }
  static int32_t id(int row, int i) { return 1 + i + 10 * row; }
};

TEST(Halves, CutAtTheMedianWhereTheFewestContactsCross) {
  TwoRows w;
  w.bodies[7].dynamic = false;  // a kinematic body belongs to no half
  Pairs pairs;
  for (int i = 0; i < 10; ++i) pairs.push_back({0, TwoRows::id(0, i)});  // the ground
  for (int i = 0; i < 10; ++i) pairs.push_back({TwoRows::id(0, i), TwoRows::id(1, i)});
  std::vector<uint8_t> half;
  // Rows side by side along x and stacked: cutting across x crosses the two side contacts
  // at the middle, cutting between the rows all ten vertical ones.
  Pairs withSides = pairs;
  for (int row = 0; row < 2; ++row)
    for (int i = 0; i + 1 < 10; ++i)
      withSides.push_back({TwoRows::id(row, i), TwoRows::id(row, i + 1)});
  splitHalves(w.bodies, w.com, withSides, half);
  ASSERT_EQ(half.size(), w.bodies.size());
  EXPECT_EQ(half[0], kNoHalf);
  EXPECT_EQ(half[7], kNoHalf);
  int counts[2] = {0, 0};
  for (int row = 0; row < 2; ++row) {
    for (int i = 0; i < 10; ++i) {
      const int32_t b = TwoRows::id(row, i);
      if (!w.bodies[size_t(b)].dynamic) continue;
      ASSERT_LT(half[size_t(b)], 2);
      ++counts[half[size_t(b)]];
      // 19 dynamic bodies: the lower 9 by (x, index) in half 0.
      EXPECT_EQ(half[size_t(b)], i < 5 && !(i == 4 && row == 1) ? 0 : 1) << row << " " << i;
    }
  }
  EXPECT_EQ(counts[0], 9);
  EXPECT_EQ(counts[1], 10);

  // Columns that touch only the one above: a cut across x crosses none of their contacts.
  w.bodies[7].dynamic = true;
  Pairs columns;
  for (int i = 0; i < 10; ++i) columns.push_back({TwoRows::id(0, i), TwoRows::id(1, i)});
  splitHalves(w.bodies, w.com, columns, half);
  size_t crossing = 0;
  for (const auto& [a, b] : columns) crossing += manifoldPart(half, a, b) == 2;
  EXPECT_EQ(crossing, 0u);

  // Rows that touch only their neighbours: the cut between the rows crosses none, and is taken
  // though x is the wider spread.
  Pairs rows;
  for (int row = 0; row < 2; ++row)
    for (int i = 0; i + 1 < 10; ++i) rows.push_back({TwoRows::id(row, i), TwoRows::id(row, i + 1)});
  splitHalves(w.bodies, w.com, rows, half);
  for (int i = 0; i < 10; ++i) {
    EXPECT_EQ(half[size_t(TwoRows::id(0, i))], 0) << i;
    EXPECT_EQ(half[size_t(TwoRows::id(1, i))], 1) << i;
  }
}

TEST(Halves, ManifoldPartIgnoresBodiesTheSolveNeverWrites) {
  const std::vector<uint8_t> half = {kNoHalf, 0, 1, kNoHalf};  // world, two bodies, kinematic
  EXPECT_EQ(manifoldPart(half, 0, 1), 0);
  EXPECT_EQ(manifoldPart(half, 2, 0), 1);
  EXPECT_EQ(manifoldPart(half, 3, 2), 1);
  EXPECT_EQ(manifoldPart(half, 1, 2), 2);
  EXPECT_EQ(manifoldPart(half, 1, 1), 0);
}

TEST(Halves, ColourOrderTurnsAChainIntoTwoColours) {
  // A chain 1-2, 2-3, ..., 40-41 (the contacts along a cut, each sharing a body with the
  // last), plus contacts with the world, which never count.
  std::vector<SolverBody> bodies = dynamicBodies(41);
  Pairs pairs;
  for (int i = 1; i <= 40; ++i) {
    pairs.push_back({i, i + 1});
    if (i % 10 == 0) pairs.push_back({0, i});
  }
  const std::vector<uint32_t> order = colorOrder(bodies, pairs);
  ASSERT_EQ(order.size(), pairs.size());
  EXPECT_EQ(std::set<uint32_t>(order.begin(), order.end()).size(), pairs.size());
  // Colour runs: within each, no dynamic body twice, and the contacts' own order kept.
  std::vector<std::set<int32_t>> colours(1);
  uint32_t last = 0;
  for (size_t k = 0; k < order.size(); ++k) {
    const auto [a, b] = pairs[order[k]];
    const bool clash = (a != 0 && colours.back().count(a)) || colours.back().count(b);
    if (k > 0 && (clash || order[k] < last)) colours.emplace_back();
    if (a != 0) {
      EXPECT_TRUE(colours.back().insert(a).second);
    }
    EXPECT_TRUE(colours.back().insert(b).second);
    last = order[k];
  }
  // The chain alternates two colours; each world contact takes the first colour its body
  // lacks (a third where the body has both).
  EXPECT_LE(colours.size(), 3u);
}

TEST(Halves, ScheduleRunsTheHalvesApartAfterTheRowGroups) {
  // A pyramid's contact graph, rows of 12 down to 1; the bodies of the left columns in one
  // half, the right in the other, the contacts ordered as the World orders them (first half,
  // second, between by colour); and one joint, which must come before every contact.
  const int base = 12;
  std::vector<std::vector<int>> id;
  int n = 0;
  for (int row = 0; row < base; ++row) {
    id.emplace_back();
    for (int i = 0; i < base - row; ++i) id.back().push_back(++n);
  }
  Solver s;
  s.bodies = dynamicBodies(n);
  s.scheme = SolverSettings::Scheme::GaussSeidel;
  addJointRowFirst(s, id[2][0], id[2][6]);
  std::vector<uint8_t> half(s.bodies.size(), kNoHalf);
  for (int row = 0; row < base; ++row)
    for (size_t i = 0; i < id[size_t(row)].size(); ++i)
      half[size_t(id[size_t(row)][i])] = 2 * i + size_t(row) < size_t(base) ? 0 : 1;
  Pairs all;
  for (int i = 0; i < base; ++i) all.push_back({0, id[0][size_t(i)]});
  for (int row = 1; row < base; ++row) {
    for (size_t i = 0; i < id[size_t(row)].size(); ++i) {
      all.push_back({id[size_t(row) - 1][i], id[size_t(row)][i]});
      all.push_back({id[size_t(row) - 1][i + 1], id[size_t(row)][i]});
    }
  }
  Pairs parts[3];
  for (const auto& p : all) parts[manifoldPart(half, p.first, p.second)].push_back(p);
  ASSERT_FALSE(parts[0].empty());
  ASSERT_FALSE(parts[1].empty());
  ASSERT_FALSE(parts[2].empty());
  std::vector<SolverManifold> manifolds;
  auto add = [&](std::pair<int32_t, int32_t> p) {
    SolverManifold m;
    m.a = p.first;
    m.b = p.second;
    m.count = 4;
    m.normal = {0, 0, 1};
    m.t1 = {1, 0, 0};
    m.t2 = {0, 1, 0};
    m.friction = 0.5f;
    for (int k = 0; k < 4; ++k) {
      m.rA[k] = {0.1f * float(k), 0, 0.5f};
      m.rB[k] = {0.1f * float(k), 0, -0.5f};
    }
    manifolds.push_back(m);
  };
  for (int part = 0; part < 2; ++part)
    for (const auto& p : parts[part]) add(p);
  for (uint32_t k : colorOrder(s.bodies, parts[2])) add(parts[2][k]);
  const uint32_t halfEnd[2] = {uint32_t(parts[0].size()),
                               uint32_t(parts[0].size() + parts[1].size())};
  ContactParts one;
  one.levels = 1;
  one.end = {halfEnd[0], halfEnd[1], uint32_t(manifolds.size())};
  WideContacts w;
  w.build(s, manifolds, &one);
  ASSERT_EQ(w.levels(), 1);
  ASSERT_LE(w.segment(0), w.segment(1));
  ASSERT_LE(w.segment(1), w.segment(2));
  ASSERT_LE(w.segment(2), w.schedule.size());

  // The joint's group alone before the halves; each half's blocks hold only its manifolds
  // (so only its dynamic bodies); the rest after.
  ASSERT_EQ(w.segment(0), 1u);
  EXPECT_FALSE(w.schedule[0].wide);
  std::multiset<uint32_t> seen;
  for (size_t k = w.segment(0); k < w.schedule.size(); ++k) {
    const WideContacts::Item& item = w.schedule[k];
    ASSERT_TRUE(item.wide) << k;
    const int part = k < w.segment(1) ? 0 : k < w.segment(2) ? 1 : 2;
    for (uint32_t m : w.manifoldsOf(item.index)) {
      seen.insert(m);
      const uint32_t first = part == 0 ? 0 : part == 1 ? halfEnd[0] : halfEnd[1];
      const uint32_t end = part == 0 ? halfEnd[0] : part == 1 ? halfEnd[1] : manifolds.size();
      EXPECT_GE(m, first) << "block " << k;
      EXPECT_LT(m, end) << "block " << k;
    }
  }
  EXPECT_EQ(seen.size(), manifolds.size());
  EXPECT_EQ(std::set<uint32_t>(seen.begin(), seen.end()).size(), manifolds.size());
  expectEachBodyMeetsItsManifoldsInOrder(w, manifolds);
  // The contacts across the cut fill blocks: fewer blocks than contacts.
  EXPECT_LT(w.schedule.size() - w.segment(2), parts[2].size());
}

TEST(NestedParts, LevelsGrowWithTheContactsAlone) {
  EXPECT_EQ(partLevels(0), 0);
  EXPECT_EQ(partLevels(kHalvesMinManifolds - 1), 0);
  EXPECT_EQ(partLevels(256), 1);
  EXPECT_EQ(partLevels(4095), 1);
  EXPECT_EQ(partLevels(4096), 2);  // leaves of kMinLeafManifolds
  EXPECT_EQ(partLevels(8191), 2);
  EXPECT_EQ(partLevels(8192), 3);
  EXPECT_EQ(partLevels(1 << 20), 3);  // at most kMaxPartLevels
  EXPECT_EQ(partLevels(size_t(1) << 30), kMaxPartLevels);
  setPartLevelsOverride(3);
  EXPECT_EQ(partLevels(255), 0);  // too few to cut at all, as without the override
  EXPECT_EQ(partLevels(256), 3);
  setPartLevelsOverride(-1);
  EXPECT_EQ(partLevels(256), 1);
}

TEST(NestedParts, SegmentsAreTheLeavesThenTheSeparatorsFromTheDeepestUp) {
  // Two levels: leaves 0-3, the separators of the cuts at depth 1 (between leaves 0|1 and
  // 2|3), then the first cut's (between 0-1 and 2-3).
  EXPECT_EQ(segmentCount(2), 7u);
  EXPECT_EQ(phaseBegin(2, 0), 0u);
  EXPECT_EQ(phaseBegin(2, 1), 4u);
  EXPECT_EQ(phaseBegin(2, 2), 6u);
  EXPECT_EQ(phaseBegin(2, 3), 7u);
  EXPECT_EQ(segmentCount(4), kMaxSegments);
  // Bodies: 0 the world, 1-4 in leaves 0-3, 5 kinematic.
  const std::vector<uint8_t> part = {kNoPart, 0, 1, 2, 3, kNoPart};
  EXPECT_EQ(contactSegment(part, 2, 0, 3), 2u);  // a body on the world: its leaf
  EXPECT_EQ(contactSegment(part, 2, 4, 5), 3u);
  EXPECT_EQ(contactSegment(part, 2, 0, 5), 0u);
  EXPECT_EQ(contactSegment(part, 2, 2, 2), 1u);
  EXPECT_EQ(contactSegment(part, 2, 1, 2), 4u);  // leaves 0|1
  EXPECT_EQ(contactSegment(part, 2, 4, 3), 5u);  // leaves 2|3
  EXPECT_EQ(contactSegment(part, 2, 1, 3), 6u);  // across the first cut
  EXPECT_EQ(contactSegment(part, 2, 2, 4), 6u);
  // Three levels: 8 leaves, separators 8-11 (depth 2), 12-13 (depth 1), 14 (the first cut).
  const std::vector<uint8_t> p3 = {kNoPart, 0, 1, 5, 6, 7};
  EXPECT_EQ(contactSegment(p3, 3, 1, 2), 8u);
  EXPECT_EQ(contactSegment(p3, 3, 4, 5), 11u);
  EXPECT_EQ(contactSegment(p3, 3, 3, 4), 13u);  // 5 and 6: depth 1, right node
  EXPECT_EQ(contactSegment(p3, 3, 2, 3), 14u);
}

/// A grid of side x side bodies in the plane z = 0, each touching its right and upper
/// neighbour and the world.
struct Grid {
  int side;
  std::vector<SolverBody> bodies;
  std::vector<Vec3> com;
  Pairs pairs;
  explicit Grid(int n) : side(n), bodies(dynamicBodies(n * n)), com(size_t(n * n) + 1) {
    for (int y = 0; y < side; ++y) {
      for (int x = 0; x < side; ++x) {
        com[size_t(id(x, y))] = {float(x), float(y), 0};
        pairs.push_back({0, id(x, y)});
        if (x + 1 < side) pairs.push_back({id(x, y), id(x + 1, y)});
        if (y + 1 < side) pairs.push_back({id(x, y), id(x, y + 1)});
      }
    }
  }
  int32_t id(int x, int y) const { return 1 + x + side * y; }
};

TEST(NestedParts, EachSetIsCutByTheHalvesRule) {
  const Grid g(16);
  std::vector<uint8_t> half, part;
  splitHalves(g.bodies, g.com, g.pairs, half);
  for (int levels = 1; levels <= kPartLevelsLimit; ++levels) {
    splitParts(g.bodies, g.com, g.pairs, levels, part);
    ASSERT_EQ(part.size(), g.bodies.size());
    EXPECT_EQ(part[0], kNoPart);
    std::vector<int> count(size_t(1) << levels, 0);
    for (size_t i = 1; i < part.size(); ++i) {
      ASSERT_LT(part[i], count.size());
      ++count[part[i]];
      // The first cut is the halves' cut: the highest bit.
      EXPECT_EQ(part[i] >> (levels - 1), half[i]) << levels << " " << i;
    }
    // Medians all the way down: 256 bodies in equal leaves.
    for (int c : count) EXPECT_EQ(c, 256 >> levels) << levels;
    // A grid's median cuts alternate between the axes (x first, on the first of equals):
    // the leaves are rectangles, and the contacts a cut of a set crosses are the set's width.
    size_t crossing = 0;
    for (const auto& [a, b] : g.pairs) crossing += a != 0 && part[size_t(a)] != part[size_t(b)];
    const size_t expected[] = {0, 16, 16 + 2 * 8, 16 + 2 * 8 + 4 * 8, 16 + 2 * 8 + 4 * 8 + 8 * 4};
    EXPECT_EQ(crossing, expected[levels]) << levels;
  }
  // With two levels: the first cut (x, the high bit), then each half's (y, the low bit).
  splitParts(g.bodies, g.com, g.pairs, 2, part);
  for (int y = 0; y < 16; ++y)
    for (int x = 0; x < 16; ++x)
      EXPECT_EQ(part[size_t(g.id(x, y))], (x < 8 ? 0 : 2) + (y < 8 ? 0 : 1)) << x << " " << y;
}

TEST(NestedParts, SegmentsOfAPhaseShareNoDynamicBody) {
  // The grid cut three levels deep, its contacts ordered as the World orders them (leaves in
  // contact order, separators by colour), and a joint first: every segment's blocks hold its
  // manifolds only, the segments of a phase touch disjoint dynamic bodies, and each body meets
  // its manifolds in their order.
  const Grid g(16);
  const int levels = 3;
  std::vector<uint8_t> part;
  splitParts(g.bodies, g.com, g.pairs, levels, part);
  Solver s;
  s.bodies = g.bodies;
  s.scheme = SolverSettings::Scheme::GaussSeidel;
  addJointRowFirst(s, g.id(0, 0), g.id(15, 15));
  std::vector<Pairs> bySegment(segmentCount(levels));
  for (const auto& p : g.pairs)
    bySegment[contactSegment(part, levels, p.first, p.second)].push_back(p);
  std::vector<SolverManifold> manifolds;
  ContactParts parts;
  parts.levels = levels;
  for (size_t i = 0; i < bySegment.size(); ++i) {
    const Pairs& seg = bySegment[i];
    EXPECT_FALSE(seg.empty()) << i;
    std::vector<uint32_t> order(seg.size());
    for (uint32_t k = 0; k < seg.size(); ++k) order[k] = k;
    if (i >= size_t(1) << levels) order = colorOrder(s.bodies, seg);
    for (uint32_t k : order) {
      SolverManifold m;
      m.a = seg[k].first;
      m.b = seg[k].second;
      m.count = 1;
      m.normal = {0, 0, 1};
      m.t1 = {1, 0, 0};
      m.t2 = {0, 1, 0};
      m.friction = 0.5f;
      manifolds.push_back(m);
    }
    parts.end.push_back(uint32_t(manifolds.size()));
  }
  WideContacts w;
  w.build(s, manifolds, &parts);
  ASSERT_EQ(w.levels(), levels);
  ASSERT_EQ(w.segment(0), 1u);  // the joint alone before the parts
  EXPECT_FALSE(w.schedule[0].wide);
  ASSERT_EQ(w.segment(segmentCount(levels)), w.schedule.size());
  std::multiset<uint32_t> seen;
  std::vector<std::set<int32_t>> bodiesOf(segmentCount(levels));
  for (size_t i = 0; i < segmentCount(levels); ++i) {
    ASSERT_LE(w.segment(i), w.segment(i + 1));
    const uint32_t first = i == 0 ? 0 : parts.end[i - 1];
    for (size_t k = w.segment(i); k < w.segment(i + 1); ++k) {
      ASSERT_TRUE(w.schedule[k].wide) << k;
      for (uint32_t m : w.manifoldsOf(w.schedule[k].index)) {
        seen.insert(m);
        EXPECT_GE(m, first) << "segment " << i;
        EXPECT_LT(m, parts.end[i]) << "segment " << i;
        for (int32_t b : {manifolds[m].a, manifolds[m].b})
          if (b != 0) bodiesOf[i].insert(b);
      }
    }
  }
  EXPECT_EQ(seen.size(), manifolds.size());
  EXPECT_EQ(std::set<uint32_t>(seen.begin(), seen.end()).size(), manifolds.size());
  for (int k = 0; k <= levels; ++k) {
    std::set<int32_t> phase;
    for (size_t i = phaseBegin(levels, k); i < phaseBegin(levels, k + 1); ++i)
      for (int32_t b : bodiesOf[i]) EXPECT_TRUE(phase.insert(b).second) << "phase " << k;
  }
  expectEachBodyMeetsItsManifoldsInOrder(w, manifolds);
  // The segments run by forEachSegment: each once, phase by phase.
  std::vector<size_t> ran;
  w.forEachSegment([&](size_t i) { ran.push_back(i); });
  ASSERT_EQ(ran.size(), segmentCount(levels));
  for (size_t i = 0; i < ran.size(); ++i) EXPECT_EQ(ran[i], i);
}

struct Outcome {
  uint64_t hash = 0;
  int between = -2;  ///< the last step's contactsBetweenHalves
  int parts = -1;    ///< and contactParts
};

Outcome runScene(const std::string& name, int threads, int steps, bool vectorized = true,
                 int levels = -1) {
  Scene scene = test::loadScene(name);
  scene.world.threads = threads;
  setVectorizedContacts(vectorized);
  setPartLevelsOverride(levels);
  World world(scene.world);
  std::vector<BodyId> ids;
  EXPECT_TRUE(instantiateScene(scene, &world, &ids).ok());
  Outcome r;
  for (int i = 0; i < steps; ++i) world.step();
  setVectorizedContacts(true);
  setPartLevelsOverride(-1);
  r.hash = world.stateHash();
  r.between = world.stats().contactsBetweenHalves;
  r.parts = world.stats().contactParts;
  return r;
}

TEST(Halves, SameBitsWithAnyThreadCountAndWithTheScalarRows) {
  // pyramid_20 (about 600 contacts) and the windmill (joints beside 1000 contacts) are cut in
  // halves; the restitution scene (a few balls) is below the threshold and is not.
  for (const char* name : {"pyramid_20", "windmill"}) {
    const Outcome one = runScene(name, 1, 60);
    EXPECT_GT(one.between, 0) << name;
    EXPECT_EQ(one.parts, 2) << name;
    EXPECT_EQ(runScene(name, 2, 60).hash, one.hash) << name;
    EXPECT_EQ(runScene(name, 3, 60).hash, one.hash) << name;
    EXPECT_EQ(runScene(name, 2, 60, false).hash, one.hash) << name << " (scalar rows)";
  }
  const Outcome few = runScene("restitution", 2, 10);
  EXPECT_EQ(few.between, -1);
  EXPECT_EQ(few.parts, 0);
}

TEST(NestedParts, SameBitsWithAnyThreadCountAndWithTheScalarRows) {
  // Forced depths (setPartLevelsOverride; the rule cuts worlds this size in halves at most):
  // pyramid_40 (2,380 contacts) in four parts, pyramid_20 in eight and the windmill (joints
  // first) in sixteen, of a few dozen contacts each.
  struct Case {
    const char* name;
    int levels, parts, steps;
  };
  for (const Case& c :
       {Case{"pyramid_40", 2, 4, 30}, Case{"pyramid_20", 3, 8, 60}, Case{"windmill", 4, 16, 60}}) {
    const Outcome one = runScene(c.name, 1, c.steps, true, c.levels);
    EXPECT_EQ(one.parts, c.parts) << c.name;
    EXPECT_GT(one.between, 0) << c.name;
    for (int threads : {2, 3, 4, 8, 16})
      EXPECT_EQ(runScene(c.name, threads, c.steps, true, c.levels).hash, one.hash)
          << c.name << " " << threads << " threads";
    EXPECT_EQ(runScene(c.name, 2, c.steps, false, c.levels).hash, one.hash)
        << c.name << " (scalar rows)";
    // A different order, so different bits (the override is not ignored).
    if (c.levels > 0) {
      EXPECT_NE(runScene(c.name, 2, c.steps).hash, one.hash) << c.name;
    }
  }
}

}  // namespace
