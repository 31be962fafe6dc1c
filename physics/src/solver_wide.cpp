#include "solver_wide.h"

#include <algorithm>
#include <cmath>
#include <cstring>

#if defined(__SSE__)
#include <immintrin.h>
#endif

namespace phys {

using wide::vf;
using wide::kLanes;
using wide::vm;
using wide::V3;

namespace {

#define PHYS_WIDE_INLINE inline __attribute__((always_inline))
// The kernels come in an AVX2 clone, picked at load time where the CPU has it, and a
// baseline one. AVX2 brings no FMA (and -ffp-contract=off): both give the same bits.
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
#define PHYS_WIDE_CLONES __attribute__((target_clones("avx2", "default")))
#else
#define PHYS_WIDE_CLONES
#endif

// The scalar kernels' helpers, lane by lane, in the same operation order (math.h's dot is
// (x*x + y*y) + z*z; std::max(a, b) is a < b ? b : a; std::min(a, b) is b < a ? b : a).
PHYS_WIDE_INLINE vf dot(const V3& a, const V3& b) {
  return a.x * b.x + a.y * b.y + a.z * b.z;
}
PHYS_WIDE_INLINE vf select(vm mask, vf a, vf b) {
  return mask ? a : b;
}
PHYS_WIDE_INLINE vf vmax(vf a, vf b) {
  return select(a < b, b, a);
}
PHYS_WIDE_INLINE vf vmin(vf a, vf b) {
  return select(b < a, b, a);
}
PHYS_WIDE_INLINE vf vabs(vf a) {
  return select(a < 0, -a, a);
}
PHYS_WIDE_INLINE vf vsqrt(vf a) {
  vf r;
#if defined(__SSE__)
  // IEEE-exact, as std::sqrt; four lanes at a time in every clone.
  static_assert(kLanes % 4 == 0);
  for (int l = 0; l < kLanes; l += 4) {
    __m128 q;
    std::memcpy(&q, reinterpret_cast<const float*>(&a) + l, sizeof q);
    q = _mm_sqrt_ps(q);
    std::memcpy(reinterpret_cast<float*>(&r) + l, &q, sizeof q);
  }
#else
  for (int l = 0; l < kLanes; ++l) r[l] = std::sqrt(a[l]);
#endif
  return r;
}
PHYS_WIDE_INLINE vf splat(float s) {
  return vf{} + s;
}
/// v += m * impulse where mask (the scalar code skips zero impulses: no -0 + 0 = +0 flips).
PHYS_WIDE_INLINE void addScaled(vm mask, V3& v, const V3& m, vf impulse) {
  v.x = select(mask, v.x + m.x * impulse, v.x);
  v.y = select(mask, v.y + m.y * impulse, v.y);
  v.z = select(mask, v.z + m.z * impulse, v.z);
}

struct Lanes {
  V3 vA, wA, vB, wB;
};

PHYS_WIDE_INLINE void load(V3& out, int l, Vec3 v) {
  out.x[l] = v.x;
  out.y[l] = v.y;
  out.z[l] = v.z;
}
PHYS_WIDE_INLINE Vec3 lane(const V3& in, int l) {
  return {in.x[l], in.y[l], in.z[l]};
}
PHYS_WIDE_INLINE void put(V3& out, int l, Vec3 v) {
  load(out, l, v);
}

PHYS_WIDE_INLINE void gatherVelocities(const std::vector<SolverBody>& bodies, const int32_t* a, const int32_t* b,
                      Lanes& s) {
  for (int l = 0; l < kLanes; ++l) {
    const SolverBody& A = bodies[size_t(a[l])];
    const SolverBody& B = bodies[size_t(b[l])];
    load(s.vA, l, A.v);
    load(s.wA, l, A.w);
    load(s.vB, l, B.v);
    load(s.wB, l, B.w);
  }
}
PHYS_WIDE_INLINE void gatherDeltas(const std::vector<SolverBody>& bodies, const int32_t* a, const int32_t* b,
                  V3& dpA, V3& dtA, V3& dpB, V3& dtB) {
  for (int l = 0; l < kLanes; ++l) {
    const SolverBody& A = bodies[size_t(a[l])];
    const SolverBody& B = bodies[size_t(b[l])];
    load(dpA, l, A.dp);
    load(dtA, l, A.dtheta);
    load(dpB, l, B.dp);
    load(dtB, l, B.dtheta);
  }
}
PHYS_WIDE_INLINE void scatterVelocities(std::vector<SolverBody>& bodies, const int32_t* a, const int32_t* b,
                       const bool* writeA, const bool* writeB, const Lanes& s) {
  for (int l = 0; l < kLanes; ++l) {
    if (writeA[l]) {
      SolverBody& A = bodies[size_t(a[l])];
      A.v = lane(s.vA, l);
      A.w = lane(s.wA, l);
    }
    if (writeB[l]) {
      SolverBody& B = bodies[size_t(b[l])];
      B.v = lane(s.vB, l);
      B.w = lane(s.wB, l);
    }
  }
}

/// J v of one row direction at one point (Solver::rowVelocity).
PHYS_WIDE_INLINE vf rowVelocity(const V3& linA, const V3& linB, const V3& angA, const V3& angB,
                      const Lanes& s) {
  return dot(linA, s.vA) + dot(angA, s.wA) + dot(linB, s.vB) + dot(angB, s.wB);
}
PHYS_WIDE_INLINE void applyImpulse(vm mask, const V3& mLinA, const V3& mLinB, const V3& mAngA,
                         const V3& mAngB, vf impulse, Lanes& s) {
  addScaled(mask, s.vA, mLinA, impulse);
  addScaled(mask, s.wA, mAngA, impulse);
  addScaled(mask, s.vB, mLinB, impulse);
  addScaled(mask, s.wB, mAngB, impulse);
}

bool sameVec(Vec3 a, Vec3 b) {
  return a.x == b.x && a.y == b.y && a.z == b.z;
}

/// How many levels past its own a manifold looks for a block with a free lane (build()).
constexpr int32_t kLevelSearch = 4;

}  // namespace

int WideContacts::lanePoints(const Solver& s, const Solver::Group& g, size_t begin,
                             size_t end) {
  const Row& first = s.rows[begin];
  if (first.kind != RowKind::ContactNormal) return 0;
  int n = 0;
  while (begin + size_t(n) < end && s.rows[begin + size_t(n)].kind == RowKind::ContactNormal)
    ++n;
  if (n > Manifold::kMaxPoints || end - begin != size_t(3 * n)) return 0;
  if (g.unitEnd - g.unitBegin != uint32_t(2 * n)) return 0;
  for (int k = 0; k < n; ++k) {
    const Row& r = s.rows[begin + size_t(k)];
    const Row& t1 = s.rows[begin + size_t(n + 2 * k)];
    const Row& t2 = s.rows[begin + size_t(n + 2 * k + 1)];
    if (r.blockSize > 1 || r.contactPoints > 1) return 0;
    if (t1.kind != RowKind::Friction || t2.kind != RowKind::Friction) return 0;
    if (t1.parent != int32_t(begin) + k) return 0;
    for (const Row* x : {&r, &t1, &t2})
      if (x->a != g.a || x->b != g.b) return 0;
    // The linear parts are stored once per lane: they must be the same at every point.
    const Row* refs[3] = {&first, &s.rows[begin + size_t(n)], &s.rows[begin + size_t(n) + 1]};
    const Row* mine[3] = {&r, &t1, &t2};
    for (int d = 0; d < 3; ++d) {
      if (!sameVec(refs[d]->linA, mine[d]->linA) || !sameVec(refs[d]->linB, mine[d]->linB) ||
          !sameVec(refs[d]->mLinA, mine[d]->mLinA) || !sameVec(refs[d]->mLinB, mine[d]->mLinB))
        return 0;
    }
  }
  return n;
}

void WideContacts::addLane(Block& blk, const Solver& s, uint32_t group, size_t begin, int n) {
  const Solver::Group& g = s.groups[group];
  const int l = blk.lanes++;
  blk.group[l] = group;
  blk.a[l] = g.a;
  blk.b[l] = g.b;
  blk.writeA[l] = s.bodies[size_t(g.a)].dynamic;
  blk.writeB[l] = s.bodies[size_t(g.b)].dynamic;
  blk.firstRow[l] = int32_t(begin);
  blk.count[l] = uint8_t(n);
  blk.points = std::max(blk.points, n);
  const Row* lin[3] = {&s.rows[begin], &s.rows[begin + size_t(n)],
                       &s.rows[begin + size_t(n) + 1]};
  for (int d = 0; d < 3; ++d) {
    put(blk.linA[d], l, lin[d]->linA);
    put(blk.linB[d], l, lin[d]->linB);
    put(blk.mLinA[d], l, lin[d]->mLinA);
    put(blk.mLinB[d], l, lin[d]->mLinB);
  }
  const SolverBody& A = s.bodies[size_t(g.a)];
  const SolverBody& B = s.bodies[size_t(g.b)];
  for (int k = 0; k < n; ++k) {
    const Row& r = s.rows[begin + size_t(k)];
    const Row* dirs[3] = {&r, &s.rows[begin + size_t(n + 2 * k)],
                          &s.rows[begin + size_t(n + 2 * k + 1)]};
    Point& p = blk.pt[k];
    Dir* out[3] = {&p.n, &p.t1, &p.t2};
    for (int d = 0; d < 3; ++d) {
      put(out[d]->angA, l, dirs[d]->angA);
      put(out[d]->angB, l, dirs[d]->angB);
      put(out[d]->mAngA, l, dirs[d]->mAngA);
      put(out[d]->mAngB, l, dirs[d]->mAngB);
      out[d]->effMass[l] = dirs[d]->effMass;
      out[d]->lambda[l] = dirs[d]->lambda;
    }
    p.C0[l] = r.C0;
    p.maxLambda[l] = r.maxLambda;
    p.relativeVelocity[l] = r.relativeVelocity;
    p.restitution[l] = r.restitution;
    p.mu[l] = dirs[1]->mu;
    p.accelN[l] = dot(r.linA, A.linearAccel) + dot(r.linB, B.linearAccel);
  }
}

void WideContacts::clear() {
  schedule.clear();
  blocks_.clear();
  active = false;
}

void WideContacts::build(const Solver& s) {
  clear();
  active = true;
  // Levels: a group goes on the level after the last one that touched either of its dynamic
  // bodies, so the groups of a level share no dynamic body and a level's items may run in
  // any order; each body still meets its groups in row order. A manifold may also take a
  // free lane of a block a few levels further on, which fills blocks at the price of
  // pushing its bodies' later groups back.
  struct Level {
    std::vector<Item> items;
    int32_t open = -1;  ///< a block of this level with a free lane
  };
  std::vector<Level> levels;
  std::vector<int32_t> levelOf(s.bodies.size(), -1);  // last level touching a dynamic body
  blocks_.reserve(s.groups.size() / 4);
  for (uint32_t gi = 0; gi < s.groups.size(); ++gi) {
    const Solver::Group& g = s.groups[gi];
    const size_t begin = s.units[g.unitBegin];
    const size_t end = g.unitEnd < s.units.size() ? s.units[g.unitEnd] : s.rows.size();
    const bool da = s.bodies[size_t(g.a)].dynamic, db = s.bodies[size_t(g.b)].dynamic;
    int32_t at =
        1 + std::max(da ? levelOf[size_t(g.a)] : -1, db ? levelOf[size_t(g.b)] : -1);
    const int n = lanePoints(s, g, begin, end);
    if (n == 0) {
      if (size_t(at) >= levels.size()) levels.resize(size_t(at) + 1);
      levels[size_t(at)].items.push_back({gi, false});
    } else {
      int32_t found = -1;
      for (int32_t lv = at; lv < at + kLevelSearch && size_t(lv) < levels.size(); ++lv) {
        if (levels[size_t(lv)].open >= 0) {
          found = lv;
          break;
        }
      }
      if (found >= 0) {
        at = found;
      } else {
        if (size_t(at) >= levels.size()) levels.resize(size_t(at) + 1);
        levels[size_t(at)].open = int32_t(blocks_.size());
        levels[size_t(at)].items.push_back({uint32_t(blocks_.size()), true});
        blocks_.emplace_back();
      }
      Level& level = levels[size_t(at)];
      Block& blk = blocks_[size_t(level.open)];
      addLane(blk, s, gi, begin, n);
      if (blk.lanes == kLanes) level.open = -1;
    }
    if (da) levelOf[size_t(g.a)] = at;
    if (db) levelOf[size_t(g.b)] = at;
  }
  schedule.reserve(s.groups.size());
  for (const Level& level : levels)
    schedule.insert(schedule.end(), level.items.begin(), level.items.end());
}

size_t WideContacts::laneCount() const {
  size_t n = 0;
  for (const Block& b : blocks_) n += size_t(b.lanes);
  return n;
}

std::vector<uint32_t> WideContacts::groupsOf(uint32_t block) const {
  const Block& b = blocks_[block];
  return std::vector<uint32_t>(b.group, b.group + b.lanes);
}

void WideContacts::store(Solver& s) {
  for (const Block& blk : blocks_) {
    for (int l = 0; l < blk.lanes; ++l) {
      const size_t first = size_t(blk.firstRow[l]);
      const int n = blk.count[l];
      for (int k = 0; k < n; ++k) {
        const Point& p = blk.pt[k];
        Row& r = s.rows[first + size_t(k)];
        r.lambda = p.n.lambda[l];
        r.maxLambda = p.maxLambda[l];
        r.relativeVelocity = p.relativeVelocity[l];
        s.rows[first + size_t(n + 2 * k)].lambda = p.t1.lambda[l];
        s.rows[first + size_t(n + 2 * k + 1)].lambda = p.t2.lambda[l];
      }
    }
  }
  clear();
}

PHYS_WIDE_CLONES void WideContacts::warmStart(uint32_t block, std::vector<SolverBody>& bodies) {
  Block& blk = blocks_[block];
  Lanes s;
  gatherVelocities(bodies, blk.a, blk.b, s);
  V3 dpA, dtA, dpB, dtB;
  gatherDeltas(bodies, blk.a, blk.b, dpA, dtA, dpB, dtB);
  // Solver::warmStartGroup: normal rows (recording the approach speed), then friction pairs.
  for (int k = 0; k < blk.points; ++k) {
    Point& p = blk.pt[k];
    Dir& r = p.n;
    vf vn = rowVelocity(blk.linA[0], blk.linB[0], r.angA, r.angB, s);
    const vf C = p.C0 + dot(blk.linA[0], dpA) + dot(r.angA, dtA) + dot(blk.linB[0], dpB) +
                 dot(r.angB, dtB);
    const vm apart = (vn < 0) & (C > 0) & (p.accelN < 0);
    vn = select(apart, -vsqrt(vn * vn - 2.0f * p.accelN * C), vn);
    p.relativeVelocity = vmin(p.relativeVelocity, vn);
    applyImpulse(r.lambda != 0, blk.mLinA[0], blk.mLinB[0], r.mAngA, r.mAngB, r.lambda, s);
  }
  for (int k = 0; k < blk.points; ++k) {
    Point& p = blk.pt[k];
    for (int d = 1; d < 3; ++d) {
      Dir& r = d == 1 ? p.t1 : p.t2;
      applyImpulse(r.lambda != 0, blk.mLinA[d], blk.mLinB[d], r.mAngA, r.mAngB, r.lambda, s);
    }
  }
  scatterVelocities(bodies, blk.a, blk.b, blk.writeA, blk.writeB, s);
}

PHYS_WIDE_CLONES float WideContacts::solve(uint32_t block, std::vector<SolverBody>& bodies, const WideParams& prm) {
  Block& blk = blocks_[block];
  Lanes s;
  gatherVelocities(bodies, blk.a, blk.b, s);
  V3 dpA, dtA, dpB, dtB;
  gatherDeltas(bodies, blk.a, blk.b, dpA, dtA, dpB, dtB);
  vf change = splat(0);
  // Solver::solveGroup's ContactNormal case, row by row.
  const float slop = !prm.soft ? prm.linearSlop : 0;
  for (int k = 0; k < blk.points; ++k) {
    Point& p = blk.pt[k];
    Dir& r = p.n;
    const vf vn = rowVelocity(blk.linA[0], blk.linB[0], r.angA, r.angB, s);
    const vf C = p.C0 + dot(blk.linA[0], dpA) + dot(r.angA, dtA) + dot(blk.linB[0], dpB) +
                 dot(r.angB, dtB);
    const vm speculative = C > 0;
    vf bias = C * prm.invH;  // close exactly the gap this substep, no more
    vf massScale = splat(1), impulseScale = splat(0);
    if (prm.useBias) {
      const vf Cs = vmin(splat(0), C + slop);
      const vf soft = vmax(prm.biasRate * Cs, splat(-prm.maxPushout));
      bias = select(speculative, bias, soft);
      massScale = select(speculative, massScale, splat(prm.massScale));
      impulseScale = select(speculative, impulseScale, splat(prm.impulseScale));
    } else {
      bias = select(speculative, bias, splat(0));
    }
    vf impulse = -r.effMass * massScale * (vn + bias) - impulseScale * r.lambda;
    const vf next = vmax(r.lambda + impulse, splat(0));
    impulse = next - r.lambda;
    r.lambda = next;
    p.maxLambda = vmax(p.maxLambda, next);
    const vm moved = impulse != 0;
    applyImpulse(moved, blk.mLinA[0], blk.mLinB[0], r.mAngA, r.mAngB, impulse, s);
    if (prm.measure)
      change = select(moved & (r.effMass > 0), vmax(change, vabs(impulse) / r.effMass), change);
  }
  // Solver::solveFrictionPair: both tangents clamped to the friction disc.
  for (int k = 0; k < blk.points; ++k) {
    Point& p = blk.pt[k];
    Dir& r1 = p.t1;
    Dir& r2 = p.t2;
    vf l1 = r1.lambda - r1.effMass * rowVelocity(blk.linA[1], blk.linB[1], r1.angA, r1.angB, s);
    vf l2 = r2.lambda - r2.effMass * rowVelocity(blk.linA[2], blk.linB[2], r2.angA, r2.angB, s);
    const vf bound = p.mu * p.n.lambda;
    const vf len2 = l1 * l1 + l2 * l2;
    const vm outside = len2 > bound * bound;
    const vf scale = select(len2 > 0, bound / vsqrt(len2), splat(0));
    l1 = select(outside, l1 * scale, l1);
    l2 = select(outside, l2 * scale, l2);
    const vf d1 = l1 - r1.lambda, d2 = l2 - r2.lambda;
    r1.lambda = l1;
    r2.lambda = l2;
    applyImpulse(d1 != 0, blk.mLinA[1], blk.mLinB[1], r1.mAngA, r1.mAngB, d1, s);
    applyImpulse(d2 != 0, blk.mLinA[2], blk.mLinB[2], r2.mAngA, r2.mAngB, d2, s);
    if (prm.measure) {
      vf c = select(r1.effMass > 0, vabs(d1) / r1.effMass, splat(0));
      c = select(r2.effMass > 0, vmax(c, vabs(d2) / r2.effMass), c);
      change = vmax(change, c);
    }
  }
  scatterVelocities(bodies, blk.a, blk.b, blk.writeA, blk.writeB, s);
  if (!prm.measure) return 0;
  float m = 0;
  for (int l = 0; l < kLanes; ++l) m = std::max(m, change[l]);
  return m;
}

PHYS_WIDE_CLONES void WideContacts::restitution(uint32_t block, std::vector<SolverBody>& bodies, float threshold) {
  Block& blk = blocks_[block];
  Lanes s;
  gatherVelocities(bodies, blk.a, blk.b, s);
  // Solver::restitutionGroup: normal rows that approached fast and carried an impulse.
  for (int k = 0; k < blk.points; ++k) {
    Point& p = blk.pt[k];
    Dir& r = p.n;
    const vm bounce = (p.restitution != 0) & ~(p.relativeVelocity > -threshold) &
                      (p.maxLambda != 0);
    const vf vn = rowVelocity(blk.linA[0], blk.linB[0], r.angA, r.angB, s);
    vf impulse = -r.effMass * (vn + p.restitution * p.relativeVelocity);
    const vf next = vmax(r.lambda + impulse, splat(0));
    impulse = next - r.lambda;
    r.lambda = select(bounce, next, r.lambda);
    p.maxLambda = select(bounce, vmax(p.maxLambda, next), p.maxLambda);
    applyImpulse(bounce & (impulse != 0), blk.mLinA[0], blk.mLinB[0], r.mAngA, r.mAngB, impulse,
                 s);
  }
  scatterVelocities(bodies, blk.a, blk.b, blk.writeA, blk.writeB, s);
}

}  // namespace phys
