#include "dynamics/solver_wide.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <bit>
#include <cassert>
#include <cmath>
#include <cstring>
#include <limits>
#include <type_traits>

#include "base/thread_pool.h"

#if defined(__SSE__)
#include <immintrin.h>
#endif

#define PHYS_WIDE_INLINE inline __attribute__((always_inline))
// The kernels come in an AVX2 clone, picked at load time where the CPU has it, and a
// baseline one. AVX2 brings no FMA (and -ffp-contract=off): both give the same bits.
// Sanitizer builds (PHYS_NO_MULTIVERSION, cmake/warnings.cmake) keep the baseline only: the
// clones' ifunc resolver runs inside the dynamic loader, before a sanitizer's runtime is
// ready, and an instrumented resolver faults there (ThreadSanitizer does, before main).
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && \
    !defined(PHYS_NO_MULTIVERSION)
#define PHYS_WIDE_CLONES __attribute__((target_clones("avx2", "default")))
#else
#define PHYS_WIDE_CLONES
#endif

namespace phys {

namespace {
std::atomic<bool> gVectorizedContacts{true};
std::atomic<int> gPartLevels{-1};
}  // namespace

void setVectorizedContacts(bool on) {
  gVectorizedContacts = on;
}
bool vectorizedContacts() {
  return gVectorizedContacts;
}

void setPartLevelsOverride(int levels) {
  gPartLevels = levels < 1 ? -1 : std::min(levels, kPartLevelsLimit);
}

int partLevels(size_t manifolds) {
  if (manifolds < kHalvesMinManifolds) return 0;
  if (const int forced = gPartLevels.load(); forced > 0) return forced;
  int levels = 1;
  while (levels < kMaxPartLevels && (manifolds >> (levels + 1)) >= kMinLeafManifolds) ++levels;
  return levels;
}

using wide::kLanes;
using wide::Lanes;
using wide::M3;
using wide::V3;
using wide::vf;
using wide::vm;

namespace {

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

PHYS_WIDE_INLINE void setLane(V3& out, int l, Vec3 v) {
  out.x[l] = v.x;
  out.y[l] = v.y;
  out.z[l] = v.z;
}
PHYS_WIDE_INLINE Vec3 lane(const V3& in, int l) {
  return {in.x[l], in.y[l], in.z[l]};
}

PHYS_WIDE_INLINE void gatherVelocities(const std::vector<SolverBody>& bodies, const int32_t* a,
                                       const int32_t* b, Lanes& s) {
  for (int l = 0; l < kLanes; ++l) {
    const SolverBody& A = bodies[size_t(a[l])];
    const SolverBody& B = bodies[size_t(b[l])];
    setLane(s.vA, l, A.v);
    setLane(s.wA, l, A.w);
    setLane(s.vB, l, B.v);
    setLane(s.wB, l, B.w);
  }
}
/// The lanes' bodies' position and rotation changes since the substep's start.
struct Deltas {
  V3 pA, tA, pB, tB;
};
PHYS_WIDE_INLINE void gatherDeltas(const std::vector<SolverBody>& bodies, const int32_t* a,
                                   const int32_t* b, Deltas& d) {
  for (int l = 0; l < kLanes; ++l) {
    const SolverBody& A = bodies[size_t(a[l])];
    const SolverBody& B = bodies[size_t(b[l])];
    setLane(d.pA, l, A.dp);
    setLane(d.tA, l, A.dtheta);
    setLane(d.pB, l, B.dp);
    setLane(d.tB, l, B.dtheta);
  }
}
/// A normal row's position error at the bodies' deltas, C0 + J (dp, dtheta): one expression
/// (one order of additions) for the warm start, the passes and the residual, so their bits
/// agree.
PHYS_WIDE_INLINE vf errorAt(const vf& C0, const V3& linA, const V3& angA, const V3& linB,
                            const V3& angB, const Deltas& d) {
  return C0 + dot(linA, d.pA) + dot(angA, d.tA) + dot(linB, d.pB) + dot(angB, d.tB);
}
PHYS_WIDE_INLINE void scatterVelocities(std::vector<SolverBody>& bodies, const int32_t* a,
                                        const int32_t* b, const bool* writeA, const bool* writeB,
                                        const Lanes& s) {
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

/// How many levels past its own a manifold looks for a block with a free lane (build()).
constexpr int32_t kLevelSearch = 4;
/// build() plans the nested parts' segments on the world's threads from this many manifolds.
constexpr uint32_t kParallelPlanManifolds = 4096;

PHYS_WIDE_INLINE V3 neg(const V3& a) {
  return {-a.x, -a.y, -a.z};
}
PHYS_WIDE_INLINE V3 scaled(const V3& a, vf s) {
  return {a.x * s, a.y * s, a.z * s};
}
template <class B, class I, class Lin>
PHYS_WIDE_INLINE void expand(const B& blk, const I& inertia, Lin& L) {
  for (int d = 0; d < 3; ++d) {
    L.linB[d] = blk.lin[d];
    L.linA[d] = neg(blk.lin[d]);
    L.mLinA[d] = scaled(L.linA[d], blk.invMassA);
    L.mLinB[d] = scaled(L.linB[d], blk.invMassB);
  }
  L.inertia = blk.iso ? nullptr : &inertia;
  L.invIsoA = blk.invIsoA;
  L.invIsoB = blk.invIsoB;
}

PHYS_WIDE_INLINE V3 cross(const V3& a, const V3& b) {
  return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}
/// math.h's Mat3 * Vec3: c0 x + c1 y + c2 z, component by component in that order.
PHYS_WIDE_INLINE V3 mul(const M3& m, const V3& v) {
  return {m.c0.x * v.x + m.c1.x * v.y + m.c2.x * v.z, m.c0.y * v.x + m.c1.y * v.y + m.c2.y * v.z,
          m.c0.z * v.x + m.c1.z * v.y + m.c2.z * v.z};
}
PHYS_WIDE_INLINE V3 masked(vm mask, const V3& v) {
  return {select(mask, v.x, splat(0)), select(mask, v.y, splat(0)), select(mask, v.z, splat(0))};
}

}  // namespace

/// A block's linear Jacobians and M^-1 J^T for the three directions, formed from what the
/// block stores (body B's part and the inverse masses) with fillBlock's operations.
struct WideContacts::Linear {
  wide::V3 linA[3], linB[3], mLinA[3], mLinB[3];
  const Inertia* inertia;  ///< the block's matrices; null for an iso block
  vf invIsoA, invIsoB;     ///< an iso block's inverse inertias
  /// M^-1 J^T's angular parts of a row with angular Jacobians (angA, angB), formed as
  /// Solver::finishRows forms them (an isotropic body's by its one number).
  PHYS_WIDE_INLINE void angular(const V3& angA, const V3& angB, V3& mA, V3& mB) const {
    if (!inertia) {
      mA = scaled(angA, invIsoA);
      mB = scaled(angB, invIsoB);
      return;
    }
    mA = isoProduct(inertia->isoA, inertia->invIA, angA);
    mB = isoProduct(inertia->isoB, inertia->invIB, angB);
  }
  /// Per lane: c0.x * v where iso (the matrix is that times the identity), else m * v.
  static PHYS_WIDE_INLINE V3 isoProduct(vm iso, const M3& m, const V3& v) {
    const V3 full = mul(m, v), one = scaled(v, m.c0.x);
    return {select(iso, one.x, full.x), select(iso, one.y, full.y), select(iso, one.z, full.z)};
  }
  /// An impulse of a row along direction d (its linear parts; d < 0: none, the twist) with
  /// angular parts (angA, angB), applied to the lanes' velocities where mask:
  /// Solver::applyImpulse, M^-1 J^T's angular parts formed as fillBlock formed them.
  PHYS_WIDE_INLINE void apply(vm mask, int d, const V3& angA, const V3& angB, vf impulse,
                              Lanes& s) const {
    V3 mA, mB;
    angular(angA, angB, mA, mB);
    if (d < 0) {
      const V3 zero{};
      applyImpulse(mask, zero, zero, mA, mB, impulse, s);
    } else {
      applyImpulse(mask, mLinA[d], mLinB[d], mA, mB, impulse, s);
    }
  }
};

PHYS_WIDE_CLONES void WideContacts::fillBlock(uint32_t block, const Solver& s,
                                              const std::vector<SolverManifold>& manifolds,
                                              const uint32_t* index, int used) {
  // The rows' values as contactRow and Solver::finishRows make them (Gauss-Seidel: no mass
  // splitting; x * 1 is exact), operation for operation in each lane, so the same bits: the
  // manifolds' and their bodies' numbers are gathered into lanes, the rows formed in the
  // lanes. Lanes past `used` and points past a lane's count stay zero.
  Block& blk = blocks_[block];
  V3 axes[3] = {}, rA[Manifold::kMaxPoints] = {}, rB[Manifold::kMaxPoints] = {};
  V3 patchRA = {}, patchRB = {};
  M3 IA = {}, IB = {};
  vf invMassA = {}, invMassB = {}, friction = {}, twistArm = {};
  vf sep[Manifold::kMaxPoints] = {}, normalImpulse[Manifold::kMaxPoints] = {};
  vf tangentImpulse[Manifold::kMaxPoints][2] = {}, patchImpulse[3] = {};
  vm lane = {}, point[Manifold::kMaxPoints] = {}, isoA = {}, isoB = {};
  bool iso = true;
  const bool patch = patch_;  // one setting per step (build)
  for (int l = 0; l < used; ++l) {
    const SolverManifold& m = manifolds[index[l]];
    const SolverBody& A = s.bodies[size_t(m.a)];
    const SolverBody& B = s.bodies[size_t(m.b)];
    blk.manifold[l] = index[l];
    blk.a[l] = m.a;
    blk.b[l] = m.b;
    blk.count[l] = uint8_t(m.count);
    blk.points = std::max(blk.points, m.count);
    blk.writeA[l] = A.dynamic;
    blk.writeB[l] = B.dynamic;
    lane[l] = -1;
    setLane(axes[0], l, m.normal);
    setLane(axes[1], l, m.t1);
    setLane(axes[2], l, m.t2);
    invMassA[l] = A.invMass;
    invMassB[l] = B.invMass;
    setLane(IA.c0, l, A.invI.c0);
    setLane(IA.c1, l, A.invI.c1);
    setLane(IA.c2, l, A.invI.c2);
    setLane(IB.c0, l, B.invI.c0);
    setLane(IB.c1, l, B.invI.c1);
    setLane(IB.c2, l, B.invI.c2);
    isoA[l] = A.isotropic ? -1 : 0;
    isoB[l] = B.isotropic ? -1 : 0;
    iso = iso && A.isotropic && B.isotropic;
    friction[l] = m.friction;
    for (int k = 0; k < m.count; ++k) {
      point[k][l] = -1;
      setLane(rA[k], l, m.rA[k]);
      setLane(rB[k], l, m.rB[k]);
      sep[k][l] = m.separation[k];
      normalImpulse[k][l] = m.normalImpulse[k];
      tangentImpulse[k][0][l] = m.tangentImpulse[k][0];
      tangentImpulse[k][1][l] = m.tangentImpulse[k][1];
    }
    if (patch) {
      setLane(patchRA, l, m.patchRA);
      setLane(patchRB, l, m.patchRB);
      twistArm[l] = m.twistArm;
      for (int d = 0; d < 3; ++d) patchImpulse[d][l] = m.patchImpulse[d];
    }
  }
  blk.lanes = used;
  blk.invMassA = invMassA;
  blk.invMassB = invMassB;
  blk.iso = iso;
  Inertia inertia{IA, IB, isoA, isoB};
  if (iso) {
    blk.invIsoA = IA.c0.x;  // lanes past `used`: zero, as their matrices
    blk.invIsoB = IB.c0.x;
  } else {
    inertia_[block] = inertia;
  }
  Linear L;
  L.inertia = iso ? nullptr : &inertia;
  L.invIsoA = blk.invIsoA;
  L.invIsoB = blk.invIsoB;
  vf linK[3][2];  // dot(linA, mLinA), dot(linB, mLinB)
  for (int d = 0; d < 3; ++d) {
    const V3 linA = neg(axes[d]), linB = axes[d];
    blk.lin[d] = linB;
    linK[d][0] = dot(linA, scaled(linA, invMassA));
    linK[d][1] = dot(linB, scaled(linB, invMassB));
  }
  // (Inlined: a call out of the AVX2 clone would pass the vectors by another ABI.)
  auto fill = [&](auto& r, vm mask, const V3& angA, const V3& angB, vf linKA, vf linKB,
                  vf lambda) __attribute__((always_inline)) {
    V3 mAngA, mAngB;
    L.angular(angA, angB, mAngA, mAngB);
    const vf kk = linKA + dot(angA, mAngA) + linKB + dot(angB, mAngB);
    if constexpr (std::is_same_v<std::decay_t<decltype(r)>, Dir>) {
      r.angA = masked(mask, angA);
      r.angB = masked(mask, angB);
    }
    r.effMass = select(mask & (kk > 1e-12f), splat(1) / kk, splat(0));
    r.lambda = select(mask, lambda, splat(0));
  };
  auto row = [&](auto& r, vm mask, const V3& ra, const V3& rb, int d, vf lambda)
                 __attribute__((always_inline)) {
    fill(r, mask, neg(cross(ra, axes[d])), cross(rb, axes[d]), linK[d][0], linK[d][1], lambda);
  };
  if (patch) {
    Patch& pa = patches_[block];
    row(pa.t1, lane, patchRA, patchRB, 1, patchImpulse[0]);
    row(pa.t2, lane, patchRA, patchRB, 2, patchImpulse[1]);
    const V3 zero{};
    fill(pa.twist, lane, neg(axes[0]), axes[0], dot(zero, scaled(zero, invMassA)),
         dot(zero, scaled(zero, invMassB)), patchImpulse[2]);
    pa.mu = select(lane, friction, splat(0));
    pa.twistMu = select(lane, friction * twistArm, splat(0));
  }
  for (int k = 0; k < blk.points; ++k) {
    Point& p = blk.pt[k];
    if (!patch) {
      PointFriction& f = frictionOf(block)[k];
      row(f.t1, point[k], rA[k], rB[k], 1, tangentImpulse[k][0]);
      row(f.t2, point[k], rA[k], rB[k], 2, tangentImpulse[k][1]);
      f.mu = select(point[k], friction, splat(0));
    }
    row(p.n, point[k], rA[k], rB[k], 0, normalImpulse[k]);
    p.C0 = select(point[k], sep[k], splat(0));
  }
}

void WideContacts::clear() {
  schedule.clear();
  blockCount_ = 0;  // the blocks' storage stays for the next step (see build)
  levels_ = 0;
  laneOf_.clear();
  active = false;
  errorsCurrent = false;
}

void WideContacts::release() noexcept {
  clear();
  std::vector<Item>().swap(schedule);
  std::vector<Block>().swap(blocks_);
  std::vector<Inertia>().swap(inertia_);
  std::vector<std::pair<uint32_t, uint32_t>>().swap(laneOf_);
  std::vector<double>().swap(residualTerms_);
  std::vector<PointFriction>().swap(friction_);
  std::vector<Patch>().swap(patches_);
}

size_t WideContacts::capacityBytes() const {
  return schedule.capacity() * sizeof(Item) + blocks_.capacity() * sizeof(Block) +
         inertia_.capacity() * sizeof(Inertia) +
         laneOf_.capacity() * sizeof(laneOf_[0]) + residualTerms_.capacity() * sizeof(double) +
         friction_.capacity() * sizeof(PointFriction) + patches_.capacity() * sizeof(Patch);
}

template <class F>
void WideContacts::forEachPart(F&& fn) const {
  if (levels_ > 0)
    forEachSegment([&](size_t i) { fn(segmentBlock_[i], segmentBlock_[i + 1]); });
  else
    fn(size_t(0), blockCount_);
}

void WideContacts::build(const Solver& s, const std::vector<SolverManifold>& manifolds,
                         const ContactParts* parts) {
  clear();
  active = true;
  levels_ = parts ? parts->levels : 0;
  assert(levels_ >= 0 && levels_ <= kPartLevelsLimit);
  patch_ = !manifolds.empty() && manifolds.front().patch;
#ifndef NDEBUG
  for (const SolverManifold& m : manifolds) assert(m.patch == patch_);  // one setting per step
#endif
  // Levels: a constraint goes on the level after the last one that touched either of its
  // dynamic bodies, so the constraints of a level share no dynamic body and a level's items
  // may run in any order, while each body still meets its constraints in the serial order
  // (the solver's row groups, the joints, then the manifolds). A manifold may also take a
  // free lane of a block a few levels further on, which fills blocks at the price of
  // pushing its bodies' later constraints back. With parts, each segment (the leaves, then
  // the separators) starts on a level of its own, so the segments follow one another in the
  // schedule and no block mixes two.
  struct Level {
    std::vector<Item> items;  ///< blocks numbered in the order they were opened
    int32_t open = -1;        ///< a block of this level with a free lane
  };
  std::vector<Level> levels;
  std::vector<int32_t> levelOf(s.bodies.size(), -1);  // last level touching a dynamic body
  auto place = [&](int32_t a, int32_t b) {
    const bool da = s.bodies[size_t(a)].dynamic, db = s.bodies[size_t(b)].dynamic;
    return 1 + std::max(da ? levelOf[size_t(a)] : -1, db ? levelOf[size_t(b)] : -1);
  };
  auto touch = [&](int32_t a, int32_t b, int32_t at) {
    if (s.bodies[size_t(a)].dynamic) levelOf[size_t(a)] = at;
    if (s.bodies[size_t(b)].dynamic) levelOf[size_t(b)] = at;
    if (size_t(at) >= levels.size()) levels.resize(size_t(at) + 1);
  };
  for (uint32_t gi = 0; gi < s.groups.size(); ++gi) {
    const Solver::Group& g = s.groups[gi];
    const int32_t at = place(g.a, g.b);
    touch(g.a, g.b, at);
    levels[size_t(at)].items.push_back({gi, false});
  }
  std::vector<std::array<uint32_t, kLanes>> lanes;  // per opened block: its manifolds
  std::vector<uint8_t> used;
  laneOf_.resize(manifolds.size());
  const uint32_t n = uint32_t(manifolds.size());
  // Without parts: one segment, which may share levels with the row groups.
  const size_t segments = levels_ > 0 ? segmentCount(levels_) : 1;
  assert(levels_ == 0 || parts->end.size() == segments);
  // A segment's blocks, levels counted from the segment's first (`open` is per level; `last`
  // per body, the last level touching it, read and left as the segment leaves it).
  struct Plan {
    std::vector<std::array<uint32_t, kLanes>> lanes;  // per block as opened: its manifolds
    std::vector<uint8_t> used;
    std::vector<int32_t> level;  // per block
    std::vector<int32_t> open;   // per level: a block with a free lane, or -1
  };
  auto plan = [&](uint32_t begin, uint32_t end, std::vector<int32_t>& last, Plan& p) {
    for (uint32_t mi = begin; mi < end; ++mi) {
      const SolverManifold& m = manifolds[mi];
      const bool da = s.bodies[size_t(m.a)].dynamic, db = s.bodies[size_t(m.b)].dynamic;
      int32_t at = 1 + std::max(da ? last[size_t(m.a)] : -1, db ? last[size_t(m.b)] : -1);
      for (int32_t lv = at; lv < at + kLevelSearch && size_t(lv) < p.open.size(); ++lv) {
        if (p.open[size_t(lv)] >= 0) {
          at = lv;
          break;
        }
      }
      if (da) last[size_t(m.a)] = at;
      if (db) last[size_t(m.b)] = at;
      if (size_t(at) >= p.open.size()) p.open.resize(size_t(at) + 1, -1);
      int32_t& open = p.open[size_t(at)];
      if (open < 0) {
        open = int32_t(p.lanes.size());
        p.lanes.emplace_back();
        p.used.push_back(0);
        p.level.push_back(at);
      }
      const size_t blk = size_t(open);
      p.lanes[blk][p.used[blk]++] = mi;
      if (p.used[blk] == kLanes) open = -1;
    }
  };
  // The plans laid into the levels: segment by segment from `first`, blocks in the order
  // they were opened (so the levels' items are too).
  size_t segmentLevel[kMaxSegments] = {};  // the level each segment begins on
  auto lay = [&](size_t seg, size_t first, const Plan& p) {
    segmentLevel[seg] = first;
    if (first + p.open.size() > levels.size()) levels.resize(first + p.open.size());
    for (size_t b = 0; b < p.lanes.size(); ++b) {
      levels[first + size_t(p.level[b])].items.push_back({uint32_t(lanes.size()), true});
      lanes.push_back(p.lanes[b]);
      used.push_back(p.used[b]);
    }
  };
  if (levels_ == 0) {
    // After the row groups, on their levels (`levelOf`, the levels' open blocks: none).
    Plan p;
    plan(0, n, levelOf, p);
    lay(0, 0, p);
  } else {
    // Each segment starts on a level of its own, past the last one's, so its blocks depend on
    // its own manifolds alone: planned on the world's threads, each with its own `last`
    // (bodies of two segments of different depths may be the same), then laid one after
    // another: the blocks one serial pass over the segments would make.
    std::vector<Plan> plans(segments);
    auto planRange = [&](size_t from, size_t to) {
      std::vector<int32_t> last(s.bodies.size(), -1);
      for (size_t seg = from; seg < to; ++seg) {
        const uint32_t begin = seg > 0 ? parts->end[seg - 1] : 0, end = parts->end[seg];
        assert(begin <= end && end <= n);
        plan(begin, end, last, plans[seg]);
        for (uint32_t mi = begin; mi < end; ++mi)  // leave `last` all -1 for the next
          last[size_t(manifolds[mi].a)] = last[size_t(manifolds[mi].b)] = -1;
      }
    };
    if (s.pool && n >= kParallelPlanManifolds)
      s.pool->parallelFor(segments, 1, planRange);
    else
      planRange(0, segments);
    for (size_t seg = 0; seg < segments; ++seg) lay(seg, levels.size(), plans[seg]);
  }
  // The schedule, level by level, and the blocks numbered in its order, so that the passes
  // stream through them; then each block is filled in one go, by the thread that solves it
  // (forEachPart). Without parts all on the caller: filling the blocks of one sweep on two
  // cores made the step slower on this 2-core VM, the first pass then fetching every other
  // block from the other core.
  schedule.reserve(s.groups.size() + lanes.size());
  std::vector<uint32_t> openedAs;  // per block in schedule order: its index as opened
  openedAs.reserve(lanes.size());
  size_t nextSegment = 0;
  auto startSegments = [&](size_t level) {  // the segments that begin on this level
    for (; nextSegment < segments && segmentLevel[nextSegment] == level; ++nextSegment) {
      segment_[nextSegment] = schedule.size();
      segmentBlock_[nextSegment] = openedAs.size();
    }
  };
  for (size_t li = 0; li < levels.size(); ++li) {
    startSegments(li);
    for (Item item : levels[li].items) {
      if (item.wide) {
        openedAs.push_back(item.index);
        item.index = uint32_t(openedAs.size() - 1);
      }
      schedule.push_back(item);
    }
  }
  startSegments(levels.size());  // empty segments at the end
  segment_[segments] = schedule.size();
  segmentBlock_[segments] = openedAs.size();
  // The storage only grows; each block is zeroed just before it is filled (empty lanes and
  // points must read as zeros), while its cache lines are about to be written anyway.
  // Zeroing all of it up front (vector::resize after clear) cost 0.1 ms on pyramid_40.
  static_assert(std::is_trivially_copyable_v<Block> && std::is_trivially_copyable_v<Inertia> &&
                std::is_trivially_copyable_v<Patch> &&
                std::is_trivially_copyable_v<PointFriction>);
  blockCount_ = lanes.size();
  if (blocks_.size() < blockCount_) blocks_.resize(blockCount_);
  if (inertia_.size() < blockCount_) inertia_.resize(blockCount_);
  if (patch_ && patches_.size() < blockCount_) patches_.resize(blockCount_);
  if (!patch_ && friction_.size() < blockCount_ * Manifold::kMaxPoints)
    friction_.resize(blockCount_ * Manifold::kMaxPoints);
  auto fill = [&](size_t begin, size_t end) {
    for (size_t b = begin; b < end; ++b) {
      std::memset(static_cast<void*>(&blocks_[b]), 0, sizeof(Block));
      if (patch_)
        std::memset(static_cast<void*>(&patches_[b]), 0, sizeof(Patch));
      else
        std::memset(static_cast<void*>(frictionOf(uint32_t(b))), 0,
                    sizeof(PointFriction) * Manifold::kMaxPoints);
      const uint32_t opened = openedAs[b];
      for (uint8_t l = 0; l < used[opened]; ++l) laneOf_[lanes[opened][l]] = {uint32_t(b), l};
      fillBlock(uint32_t(b), s, manifolds, lanes[opened].data(), used[opened]);
    }
  };
  assert(levels_ == 0 || segmentBlock_[0] == 0);  // the row groups' levels hold no blocks
  pool_ = s.pool;
  forEachPart(fill);
}

void splitParts(const std::vector<SolverBody>& bodies, const std::vector<Vec3>& com,
                const std::vector<std::pair<int32_t, int32_t>>& pairs, int levels,
                std::vector<uint8_t>& part, ThreadPool* pool) {
  assert(levels >= 1 && levels <= 7);
  part.assign(bodies.size(), kNoPart);
  // The sets of one depth, left to right: each a range of `dyn` (its bodies) and of `inner`
  // (its contacts between two of its dynamic bodies, the only ones a cut of it can cross).
  std::vector<uint32_t> dyn, inner;
  for (uint32_t i = 1; i < bodies.size(); ++i) {
    if (!bodies[i].dynamic) continue;
    dyn.push_back(i);
    part[i] = 0;
  }
  for (uint32_t k = 0; k < pairs.size(); ++k) {
    const auto [a, b] = pairs[k];
    if (bodies[size_t(a)].dynamic && bodies[size_t(b)].dynamic) inner.push_back(k);
  }
  struct Set {
    size_t begin, end, innerBegin, innerEnd;
  };
  std::vector<Set> sets = {{0, dyn.size(), 0, inner.size()}}, next;
  // Each axis's median cut of each set is a task of its own (the world's threads take them;
  // the sets of one depth share no body, so an axis's `side` serves all of them): the set's
  // bodies by (coordinate, index), each body's side, and how many of the set's contacts
  // cross. The keys are copied out first: nth_element over indices into `com` takes a cache
  // miss per comparison in a large world.
  std::vector<uint8_t> side[3];  // per axis, per body: its side of that axis's cut
  for (auto& v : side) v.assign(bodies.size(), 0);
  std::vector<std::vector<std::pair<float, uint32_t>>> keyed;  // per task: (coordinate, index)
  std::vector<size_t> crossing;                                // per task
  std::vector<uint32_t> keep[2];  // a set's contacts on either side
  for (int depth = 0; depth < levels; ++depth) {
    const size_t tasks = 3 * sets.size();
    keyed.resize(tasks);
    crossing.assign(tasks, 0);
    auto cut = [&](size_t task) {
      const Set& set = sets[task / 3];
      const int axis = int(task % 3);
      auto& keys = keyed[task];
      keys.clear();
      for (size_t k = set.begin; k < set.end; ++k) {
        const uint32_t i = dyn[k];
        const float c = axis == 0 ? com[i].x : axis == 1 ? com[i].y : com[i].z;
        // A total order even for a body gone non-finite (the guard rolls such steps back).
        keys.push_back({std::isnan(c) ? std::numeric_limits<float>::infinity() : c, i});
      }
      const auto median = keys.begin() + std::ptrdiff_t((set.end - set.begin) / 2);
      std::nth_element(keys.begin(), median, keys.end());  // (coordinate, index)
      std::vector<uint8_t>& sd = side[axis];
      for (auto it = keys.begin(); it != keys.end(); ++it) sd[it->second] = it < median ? 0 : 1;
      size_t n = 0;
      for (size_t k = set.innerBegin; k < set.innerEnd; ++k) {
        const auto [a, b] = pairs[inner[k]];
        n += sd[size_t(a)] != sd[size_t(b)];
      }
      crossing[task] = n;
    };
    if (pool && dyn.size() >= kParallelSplitBodies)
      pool->parallelFor(tasks, 1, [&](size_t begin, size_t end) {
        for (size_t t = begin; t < end; ++t) cut(t);
      });
    else
      for (size_t t = 0; t < tasks; ++t) cut(t);
    next.clear();
    for (size_t si = 0; si < sets.size(); ++si) {
      const Set& set = sets[si];
      // The cut that the fewest of the set's contacts cross wins (the first of equals): the
      // same split whatever order the bodies came in, and whatever the threads.
      int best = 0;
      for (int axis = 1; axis < 3; ++axis)
        if (crossing[3 * si + size_t(axis)] < crossing[3 * si + size_t(best)]) best = axis;
      const auto& keys = keyed[3 * si + size_t(best)];
      const std::vector<uint8_t>& sd = side[best];
      const auto first = dyn.begin() + std::ptrdiff_t(set.begin);
      for (size_t k = 0; k < keys.size(); ++k) first[std::ptrdiff_t(k)] = keys[k].second;
      for (size_t k = set.begin; k < set.end; ++k)
        part[dyn[k]] = uint8_t(2 * part[dyn[k]] + sd[dyn[k]]);
      // The set's contacts that stay on one side are the halves' own; those that cross go to
      // this cut's separator and out of the recursion.
      keep[0].clear();
      keep[1].clear();
      for (size_t k = set.innerBegin; k < set.innerEnd; ++k) {
        const auto [a, b] = pairs[inner[k]];
        if (sd[size_t(a)] == sd[size_t(b)]) keep[sd[size_t(a)]].push_back(inner[k]);
      }
      size_t at = set.innerBegin;
      const size_t midIndex = set.begin + (set.end - set.begin) / 2;
      for (int h = 0; h < 2; ++h) {
        std::copy(keep[h].begin(), keep[h].end(), inner.begin() + std::ptrdiff_t(at));
        next.push_back(
            {h == 0 ? set.begin : midIndex, h == 0 ? midIndex : set.end, at, at + keep[h].size()});
        at += keep[h].size();
      }
    }
    sets.swap(next);
  }
}

std::vector<uint32_t> colorOrder(const std::vector<SolverBody>& bodies,
                                 const std::vector<std::pair<int32_t, int32_t>>& pairs) {
  std::vector<uint32_t> colors(bodies.size(), 0);    // per body: the colours it has, as bits
  std::vector<std::pair<uint32_t, uint32_t>> keyed;  // (colour, index)
  keyed.reserve(pairs.size());
  for (uint32_t i = 0; i < pairs.size(); ++i) {
    const auto [a, b] = pairs[i];
    const bool da = bodies[size_t(a)].dynamic, db = bodies[size_t(b)].dynamic;
    const uint32_t used = (da ? colors[size_t(a)] : 0) | (db ? colors[size_t(b)] : 0);
    // Past 32 colours (a body in 32 contacts across the cut) the last is shared: the order
    // stays valid, only its blocks fill less.
    const uint32_t color = std::min(31u, uint32_t(std::countr_one(used)));
    if (da) colors[size_t(a)] |= 1u << color;
    if (db) colors[size_t(b)] |= 1u << color;
    keyed.push_back({color, i});
  }
  std::stable_sort(keyed.begin(), keyed.end(),
                   [](const auto& x, const auto& y) { return x.first < y.first; });
  std::vector<uint32_t> order;
  order.reserve(keyed.size());
  for (const auto& [color, i] : keyed) order.push_back(i);
  return order;
}

size_t WideContacts::laneCount() const {
  size_t n = 0;
  for (size_t b = 0; b < blockCount_; ++b) n += size_t(blocks_[b].lanes);
  return n;
}

std::vector<uint32_t> WideContacts::manifoldsOf(uint32_t block) const {
  const Block& b = blocks_[block];
  return std::vector<uint32_t>(b.manifold, b.manifold + b.lanes);
}

void WideContacts::store(std::vector<Contact>& contacts, const std::vector<uint32_t>& contactOf) {
  forEachPart([&](size_t begin, size_t end) {
    for (size_t b = begin; b < end; ++b) {
      const Block& blk = blocks_[b];
      for (int l = 0; l < blk.lanes; ++l) {
        Contact& c = contacts[contactOf[blk.manifold[l]]];
        for (int k = 0; k < blk.count[l]; ++k) {
          c.normalImpulse[k] = blk.pt[k].n.lambda[l];
          if (patch_) continue;
          const PointFriction& f = frictionOf(uint32_t(b))[k];
          c.tangentImpulse[k][0] = f.t1.lambda[l];
          c.tangentImpulse[k][1] = f.t2.lambda[l];
        }
        if (patch_) {
          const Patch& pa = patches_[b];
          c.patchImpulse(0) = pa.t1.lambda[l];
          c.patchImpulse(1) = pa.t2.lambda[l];
          c.patchImpulse(2) = pa.twist.lambda[l];
        }
      }
    }
  });
  active = false;
}

double WideContacts::residual(const std::vector<SolverBody>& bodies, float h, double sum) const {
  // Solver::velocityResidual's contact rows: each point's term where its block lives, then
  // the sum in the rows' order (friction rows add zero; so do the unused points, +0.0).
  constexpr int kPoints = Manifold::kMaxPoints;
  residualTerms_.resize(laneOf_.size() * kPoints);
  forEachPart([&](size_t begin, size_t end) {
    for (size_t b = begin; b < end; ++b) residualBlock(uint32_t(b), bodies, h);
  });
  for (double t : residualTerms_) sum += t;
  return sum;
}

PHYS_WIDE_CLONES void WideContacts::residualBlock(uint32_t block,
                                                  const std::vector<SolverBody>& bodies,
                                                  float h) const {
  // The scalar terms' float operations in the lanes (vn, C, the gap, the term before it
  // is squared in double), so the same bits.
  constexpr int kPoints = Manifold::kMaxPoints;
  const Block& blk = blocks_[block];
  const V3 linB = blk.lin[0], linA = neg(linB);
  Lanes s;
  gatherVelocities(bodies, blk.a, blk.b, s);
  // The position errors as the last pass kept them (the relax pass after the last
  // positions), else from the bodies' deltas: the same bits either way.
  Deltas d;
  const bool fresh = !errorsCurrent;
  if (fresh) gatherDeltas(bodies, blk.a, blk.b, d);
  vf e[kPoints];
  for (int k = 0; k < blk.points; ++k) {
    const Dir& r = blk.pt[k].n;
    const vf vn = dot(linA, s.vA) + dot(r.angA, s.wA) + dot(linB, s.vB) + dot(r.angB, s.wB);
    const vf C = fresh ? errorAt(blk.pt[k].C0, linA, r.angA, linB, r.angB, d) : blk.pt[k].C;
    const vf gap = vmax(C, splat(0)) / h;
    e[k] = select(r.lambda > 0, vn, vmin(splat(0), vn + gap));
  }
  for (int l = 0; l < blk.lanes; ++l) {
    double* terms = &residualTerms_[size_t(blk.manifold[l]) * kPoints];
    for (int k = 0; k < kPoints; ++k) {
      const double x = k < blk.count[l] ? double(e[k][l]) : 0.0;  // unused points add +0
      terms[k] = x * x;
    }
  }
}

PHYS_WIDE_INLINE void WideContacts::frictionPair(const Linear& L, Dir& r1, Dir& r2, vf bound,
                                                 bool measure, vf& change, Lanes& s) {
  vf l1 = r1.lambda - r1.effMass * rowVelocity(L.linA[1], L.linB[1], r1.angA, r1.angB, s);
  vf l2 = r2.lambda - r2.effMass * rowVelocity(L.linA[2], L.linB[2], r2.angA, r2.angB, s);
  const vf len2 = l1 * l1 + l2 * l2;
  const vm outside = len2 > bound * bound;
  const vf scale = select(len2 > 0, bound / vsqrt(len2), splat(0));
  l1 = select(outside, l1 * scale, l1);
  l2 = select(outside, l2 * scale, l2);
  const vf d1 = l1 - r1.lambda, d2 = l2 - r2.lambda;
  r1.lambda = l1;
  r2.lambda = l2;
  L.apply(d1 != 0, 1, r1.angA, r1.angB, d1, s);
  L.apply(d2 != 0, 2, r2.angA, r2.angB, d2, s);
  if (measure) {
    vf c = select(r1.effMass > 0, vabs(d1) / r1.effMass, splat(0));
    c = select(r2.effMass > 0, vmax(c, vabs(d2) / r2.effMass), c);
    change = vmax(change, c);
  }
}

PHYS_WIDE_CLONES void WideContacts::warmStart(uint32_t block, std::vector<SolverBody>& bodies) {
  Block& blk = blocks_[block];
  Linear L;
  expand(blk, inertia_[block], L);
  Lanes s;
  gatherVelocities(bodies, blk.a, blk.b, s);
  Deltas d;
  gatherDeltas(bodies, blk.a, blk.b, d);
  // Solver::warmStartGroup: normal rows (their position errors at this substep's deltas,
  // for the iterations), then friction pairs.
  for (int k = 0; k < blk.points; ++k) {
    Point& p = blk.pt[k];
    Dir& r = p.n;
    const vf C = errorAt(p.C0, L.linA[0], r.angA, L.linB[0], r.angB, d);
    p.C = C;
    L.apply(r.lambda != 0, 0, r.angA, r.angB, r.lambda, s);
  }
  if (patch_) {
    Patch& pa = patches_[block];
    L.apply(pa.t1.lambda != 0, 1, pa.t1.angA, pa.t1.angB, pa.t1.lambda, s);
    L.apply(pa.t2.lambda != 0, 2, pa.t2.angA, pa.t2.angB, pa.t2.lambda, s);
    L.apply(pa.twist.lambda != 0, -1, L.linA[0], L.linB[0], pa.twist.lambda, s);  // (-n, n)
  } else {
    PointFriction* fr = frictionOf(block);
    for (int k = 0; k < blk.points; ++k) {
      for (int d = 1; d < 3; ++d) {
        Dir& r = d == 1 ? fr[k].t1 : fr[k].t2;
        L.apply(r.lambda != 0, d, r.angA, r.angB, r.lambda, s);
      }
    }
  }
  scatterVelocities(bodies, blk.a, blk.b, blk.writeA, blk.writeB, s);
}

PHYS_WIDE_CLONES float WideContacts::solve(uint32_t block, std::vector<SolverBody>& bodies,
                                           const WideParams& prm) {
  Block& blk = blocks_[block];
  Linear L;
  expand(blk, inertia_[block], L);
  Lanes s;
  gatherVelocities(bodies, blk.a, blk.b, s);
  // The position errors: as the warm start or the last pass left them while the bodies have
  // not moved since, else from the bodies' deltas (the relax pass after the positions, and
  // the first iteration of a substep warm-started by bodies), kept for the passes after.
  Deltas d;
  const bool fresh = !errorsCurrent;
  if (fresh) gatherDeltas(bodies, blk.a, blk.b, d);
  vf change = splat(0);
  // Solver::solveGroup's ContactNormal case, row by row.
  const float slop = !prm.soft ? prm.linearSlop : 0;
  for (int k = 0; k < blk.points; ++k) {
    Point& p = blk.pt[k];
    Dir& r = p.n;
    const vf vn = rowVelocity(L.linA[0], L.linB[0], r.angA, r.angB, s);
    vf C = p.C;
    if (fresh) {
      C = errorAt(p.C0, L.linA[0], r.angA, L.linB[0], r.angB, d);
      p.C = C;  // for the passes until the bodies move (errorsCurrent)
    }
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
    const vm moved = impulse != 0;
    L.apply(moved, 0, r.angA, r.angB, impulse, s);
    if (prm.measure)
      change = select(moved & (r.effMass > 0), vmax(change, vabs(impulse) / r.effMass), change);
  }
  // Solver::solveFrictionPair: both tangents clamped to the friction disc of mu times the
  // point's normal impulse, or with patch friction the manifold's.
  if (patch_) {
    Patch& pa = patches_[block];
    vf load = splat(0);
    for (int k = 0; k < blk.points; ++k) load = load + blk.pt[k].n.lambda;
    frictionPair(L, pa.t1, pa.t2, pa.mu * load, prm.measure, change, s);
    // Solver::solveGroup's Twist case.
    Twist& r = pa.twist;
    const V3 zero{};
    const vf vn = rowVelocity(zero, zero, L.linA[0], L.linB[0], s);  // twist: (-n, n)
    const vf bound = pa.twistMu * load;
    vf impulse = -r.effMass * vn;
    const vf sum = r.lambda + impulse;
    const vf next = select(sum < -bound, -bound, select(bound < sum, bound, sum));
    impulse = next - r.lambda;
    r.lambda = next;
    const vm moved = impulse != 0;
    L.apply(moved, -1, L.linA[0], L.linB[0], impulse, s);
    if (prm.measure)
      change = select(moved & (r.effMass > 0), vmax(change, vabs(impulse) / r.effMass), change);
  } else {
    PointFriction* fr = frictionOf(block);
    for (int k = 0; k < blk.points; ++k)
      frictionPair(L, fr[k].t1, fr[k].t2, fr[k].mu * blk.pt[k].n.lambda, prm.measure, change, s);
  }
  scatterVelocities(bodies, blk.a, blk.b, blk.writeA, blk.writeB, s);
  if (!prm.measure) return 0;
  float m = 0;
  for (int l = 0; l < kLanes; ++l) m = std::max(m, change[l]);
  return m;
}

}  // namespace phys
