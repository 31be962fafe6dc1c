// The Gauss-Seidel scheme's contact manifolds, eight at a time.
//
// Serial Gauss-Seidel visits the constraint groups in row order. Two groups that share no
// dynamic body commute: solving them in either order gives the same bits. WideContacts
// builds a schedule that keeps, for every dynamic body, the order of the groups touching it,
// and packs contact manifolds that do not share a body into blocks of eight, which the
// kernels solve in the eight lanes of one SIMD register. Each lane runs the scalar kernels'
// arithmetic operation for operation (same order, no FMA, masked instead of skipped
// updates), so the result is bit-identical to the scalar pass: the schedule is a speed
// setting, like the thread count. Groups that do not fit the contact pattern (joints,
// manifolds with the block solve) stay scalar items of the schedule, in place.
//
// The World hands the manifolds over instead of making contact rows; a block holds their
// rows in a compact structure-of-arrays form (356 bytes a four-point manifold with patch
// friction, 292 between isotropic bodies, instead of seven rows of 164 bytes) and owns the
// contact impulses between build() and store().
//
// Nested parts: in a world with many contacts, the World cuts the dynamic bodies in two
// (at the median, on the axis whose cut the fewest contacts cross), and each half again by the
// same rule, `levels` times (partLevels: more levels for more contacts, never by the thread
// count), into 2^levels leaf parts. The contacts are ordered as: each leaf's, leaf by leaf,
// then the separators, from the deepest cuts up to the first: a cut's separator holds the
// contacts between the two sides of that cut (contactSegment). That order is the world's, not
// the threads': it is the Gauss-Seidel order of the scalar rows too, whatever the thread count.
// The leaves share no dynamic body, so they commute: their blocks run on all threads at once,
// then the separators of each depth (which also share none), the first cut's last. The
// result is the same bits as the serial pass. Scalar groups (joints) come first, serially.
// One level is "Gauss-Seidel in halves" (docs/ARCHITECTURE.md).
#pragma once

#include <bit>
#include <cstdint>
#include <utility>
#include <vector>

#include "base/thread_pool.h"
#include "dynamics/records.h"
#include "dynamics/solver.h"
#include "phys/collision/shapes.h"

namespace phys {

namespace wide {
constexpr int kLanes = 8;
/// Eight floats and eight lane masks (GCC/Clang vector extensions): two SSE registers on
/// baseline x86-64, one AVX register in the kernels' AVX2 clones (solver_wide.cpp). The
/// alignment is explicit: without AVX enabled GCC gives these types only 16, and the AVX2
/// clones' aligned loads then fault on blocks the baseline code allocated.
typedef float vf __attribute__((vector_size(32), aligned(32)));
typedef int32_t vm __attribute__((vector_size(32), aligned(32)));
struct V3 {
  vf x, y, z;
};
/// A 3x3 matrix of eight lanes, by columns (math.h's Mat3).
struct M3 {
  V3 c0, c1, c2;
};
/// The velocities of the bodies in a block's lanes.
struct Lanes {
  V3 vA, wA, vB, wB;
};
}  // namespace wide

/// The constants of one pass over the contacts (Solver::IterationParams, minus joints).
struct WideParams {
  float invH = 0, linearSlop = 0, maxPushout = 0;
  float biasRate = 0, massScale = 1, impulseScale = 0;  ///< contact softness
  bool soft = true, useBias = true, measure = false;
};

/// Nested parts (see the file comment): at most this many levels, 8 leaf parts, one for each
/// of the pool's default of at most 8 threads (resolveThreadCount). A fourth level cost more
/// than the third in most runs on this 2-core VM (docs/ARCHITECTURE.md, "Nested parts").
constexpr int kMaxPartLevels = 3;
/// The most levels the code handles (setPartLevelsOverride may ask for a fourth, to measure).
constexpr int kPartLevelsLimit = 4;
/// The leaves (2^levels), then the separators (2^levels - 1).
constexpr size_t segmentCount(int levels) {
  return levels > 0 ? (size_t(2) << levels) - 1 : 0;
}
/// The segments run in levels + 1 phases: phase 0 the leaves, phase k >= 1 the separators of
/// the cuts at depth levels - k (the first cut is depth 0); phase k is the segments
/// [phaseBegin(levels, k), phaseBegin(levels, k + 1)).
constexpr size_t phaseBegin(int levels, int k) {
  return (size_t(2) << levels) - ((size_t(2) << levels) >> k);
}
constexpr size_t kMaxSegments = segmentCount(kPartLevelsLimit);

/// The World's contact order in nested parts: manifolds [end[i-1], end[i]) are segment i's
/// (end[-1] = 0), the segments in the order above.
struct ContactParts {
  int levels = 0;  ///< 0: one part, not cut
  std::vector<uint32_t> end;
};

class WideContacts {
 public:
  /// One entry of the schedule: a block of manifolds, or one group solved by the scalar code.
  struct Item {
    uint32_t index;  ///< block index, or group index
    bool wide;
  };
  std::vector<Item> schedule;
  bool active = false;
  /// The points' C hold the position errors at the bodies' current deltas: warmStart and
  /// every pass of Solver::solveIteration set it, Solver::integratePositions clears it (the
  /// bodies moved).
  bool errorsCurrent = false;

  /// Packs the manifolds into blocks and orders them after the solver's row groups (the
  /// joints; see the file comment). The rows must be finished; sets active. With parts
  /// (levels > 0) each segment's manifolds get blocks of their own (see "Nested parts"
  /// above); without, all are one part.
  void build(const Solver& s, const std::vector<SolverManifold>& manifolds,
             const ContactParts* parts = nullptr);
  /// With parts: their levels (0 without), and the schedule's segments: [0, segment(0)) the
  /// row groups, [segment(i), segment(i + 1)) segment i's blocks (segment(segments) is the
  /// schedule's end).
  int levels() const { return levels_; }
  size_t segment(size_t i) const { return segment_[i]; }
  /// fn(i) for every segment i, phase by phase, the segments of a phase on all threads at
  /// once, each on the thread that normally runs it (the pool gives a loop's chunk to the same
  /// thread unless that one is late, when another takes it: only speed depends on it). fn must
  /// touch only segment i's bodies and data.
  static constexpr size_t kInlinePhaseItems = 16;
  template <class F>
  void forEachSegment(F&& fn) const {
    for (int k = 0; k <= levels_; ++k) {
      const size_t first = phaseBegin(levels_, k), count = phaseBegin(levels_, k + 1) - first;
      // A phase of a few items (the separators between piles that hardly touch) runs on the
      // caller: waking the others would cost more than it saves.
      const bool small = segment_[first + count] - segment_[first] < kInlinePhaseItems;
      if (pool_ && !small) {
        pool_->parallelFor(count, 1, [&](size_t begin, size_t end) {
          for (size_t i = begin; i < end; ++i) fn(first + i);
        });
      } else {
        for (size_t i = 0; i < count; ++i) fn(first + i);
      }
    }
  }
  /// Writes the contact impulses into the contacts the manifolds were made from (manifold
  /// i's is contacts[contactOf[i]]), for their next warm start, and deactivates: the solver
  /// passes run over the rows alone again. The blocks stay for residual().
  void store(std::vector<Contact>& contacts, const std::vector<uint32_t>& contactOf);
  void clear();
  /// clear(), and the blocks' storage back to the allocator (World::Impl::releaseStepBuffers).
  void release() noexcept;
  size_t capacityBytes() const;  ///< the storage held (blocks, friction, lanes, schedule)
  /// Adds the contacts' part of Solver::velocityResidual to sum, in the rows' order.
  double residual(const std::vector<SolverBody>& bodies, float h, double sum) const;
  /// residual()'s terms of one block's lanes, formed in SIMD lanes.
  void residualBlock(uint32_t block, const std::vector<SolverBody>& bodies, float h) const;

  void warmStart(uint32_t block, std::vector<SolverBody>& bodies);
  /// One Gauss-Seidel pass over a block; returns the largest velocity change (p.measure).
  float solve(uint32_t block, std::vector<SolverBody>& bodies, const WideParams& p);

  size_t blockCount() const { return blockCount_; }
  size_t laneCount() const;
  /// The manifolds in a block's lanes, for tests.
  std::vector<uint32_t> manifoldsOf(uint32_t block) const;

 private:
  /// One row direction (normal, tangent 1, tangent 2, twist) of eight manifolds.
  struct Dir {
    wide::V3 angA, angB;
    wide::vf effMass, lambda;
  };
  struct Point {
    Dir n;
    wide::vf C0;  ///< the normal row's
    wide::vf C;   ///< position error at this substep's deltas (set by warmStart)
  };
  /// A point's friction pair (without patch friction).
  struct PointFriction {
    Dir t1, t2;
    wide::vf mu;
  };
  /// The twist row of patch friction: its angular parts are the normal's linear ones (-n, n)
  /// and it has no linear part.
  struct Twist {
    wide::vf effMass, lambda;
  };
  /// Patch friction (SolverManifold::patch): a tangent pair at the centroid and the twist.
  struct Patch {
    Dir t1, t2;
    Twist twist;
    wide::vf mu, twistMu;  ///< friction, and friction times the twist arm
  };
  /// The Jacobian's linear parts are the manifold's normal and tangents, the same at every
  /// point: stored once per lane for each direction (0 = normal, 1, 2 = tangents), as body
  /// B's part (body A's is its negation) with the two inverse masses and inverse inertias; the
  /// kernels form -J and M^-1 J^T from them (Linear) as fillBlock formed the rows', so the
  /// bits are the same. A pass streams the blocks from memory once (many_pyramids' 58,000
  /// manifolds of cubes are about 17 MB of them, 73 floats a lane; 89 with matrices): every
  /// float stored is bandwidth, and in a world that large two 3x3 products a row cost less
  /// than reading M^-1 J^T's angular parts (docs/ARCHITECTURE.md, "What the passes stream").
  ///
  /// Isotropic bodies (SolverBody::isotropic: cubes, spheres, the world) need no matrix: a
  /// block whose bodies all are stores their inverse inertias as one number a lane (invIsoA,
  /// invIsoB, 73 floats a lane), and only the other blocks have their matrices, in inertia_.
  struct Block {
    wide::V3 lin[3];
    wide::vf invMassA, invMassB;
    /// With `iso`: the bodies' inverse inertia (times the identity), else unused (zero).
    wide::vf invIsoA, invIsoB;
    Point pt[Manifold::kMaxPoints];
    int32_t a[wide::kLanes] = {}, b[wide::kLanes] = {};  ///< solver bodies; 0 in empty lanes
    uint32_t manifold[wide::kLanes] = {};
    uint8_t count[wide::kLanes] = {};                           ///< points of each lane's manifold
    bool writeA[wide::kLanes] = {}, writeB[wide::kLanes] = {};  ///< dynamic bodies only
    int lanes = 0, points = 0;
    bool iso = false;  ///< every body of the block is isotropic (no inertia_ entry)
  };
  /// The inverse inertias of a block that is not `iso`: the bodies' world matrices (M^-1
  /// J^T's angular parts), and which lanes' bodies are isotropic (their products are formed
  /// as the rows' are, by the one number).
  struct Inertia {
    wide::M3 invIA, invIB;
    wide::vm isoA, isoB;
  };
  /// Fills a zeroed block with `used` manifolds (index: theirs), the rows formed in SIMD lanes.
  void fillBlock(uint32_t block, const Solver& s, const std::vector<SolverManifold>& manifolds,
                 const uint32_t* index, int used);
  /// Solver::solveFrictionPair on a block's lanes: the pair clamped to the disc of `bound`.
  struct Linear;  ///< a block's linear parts, formed for a pass (solver_wide.cpp)
  static void frictionPair(const Linear& L, Dir& r1, Dir& r2, wide::vf bound, bool measure,
                           wide::vf& change, wide::Lanes& s);
  PointFriction* frictionOf(uint32_t block) {
    return &friction_[size_t(block) * Manifold::kMaxPoints];
  }
  std::vector<Block> blocks_;  ///< the first blockCount_ are this step's
  std::vector<Inertia> inertia_;  ///< per block; read for the blocks that are not iso
  size_t blockCount_ = 0;
  std::vector<std::pair<uint32_t, uint32_t>> laneOf_;  ///< per manifold: block, lane
  bool patch_ = false;  ///< every manifold has patch friction (else every one per point)
  int levels_ = 0;
  size_t segment_[kMaxSegments + 1] = {};       ///< see segment()
  size_t segmentBlock_[kMaxSegments + 1] = {};  ///< with parts: the blocks before each segment
  ThreadPool* pool_ = nullptr;
  mutable std::vector<double> residualTerms_;  ///< residual(): per manifold, kMaxPoints
  /// fn(firstBlock, endBlock) over the blocks: with parts each segment's, by forEachSegment.
  template <class F>
  void forEachPart(F&& fn) const;
  /// Per block: its points' friction (kMaxPoints each), or with patch friction its patch.
  std::vector<PointFriction> friction_;
  std::vector<Patch> patches_;
};

/// Nested parts (see the file comment) from this many contact manifolds: below it, one more
/// fork-join per pass costs about what the second core saves.
constexpr size_t kHalvesMinManifolds = 256;
/// Deeper than halves only while every leaf keeps this many manifolds. A leaf's blocks fill
/// less than the whole sweep's (its dependency chain is not much shorter) and each level adds
/// a fork-join per pass: measured on this 2-core VM, pyramid_40 (2,380 manifolds) in four
/// parts took 12-16 % longer than in halves with two threads, while pyramid_100 (14,950) in
/// four or eight took about as long (docs/ARCHITECTURE.md, "Nested parts").
constexpr size_t kMinLeafManifolds = 1024;
/// The levels of nested parts for a step with `manifolds` touching contacts: 0 below
/// kHalvesMinManifolds, 1 (halves) from there, 2 from 4,096 and 3 from 8,192 (leaves of at
/// least kMinLeafManifolds), at most kMaxPartLevels. A function of the world alone, never of
/// the thread count.
int partLevels(size_t manifolds);
/// (setPartLevelsOverride, solver_settings.h, replaces the rule for measurements and tests.)
constexpr uint8_t kNoPart = 0xff;
constexpr uint8_t kNoHalf = kNoPart;
/// Per solver body: its leaf part (0 to 2^levels - 1), the bits of its sides of the cuts from
/// the first (the highest bit) down; kNoPart for the world and kinematic bodies. Each set of
/// dynamic bodies is cut at the median of their centres of mass (`com`, per solver body) along
/// the axis whose cut the fewest of the set's own contacts (`pairs`, solver bodies a, b) cross.
/// The axes' cuts run on `pool`'s threads (in a world of kParallelSplitBodies dynamic bodies or
/// more); the result is the same with any.
void splitParts(const std::vector<SolverBody>& bodies, const std::vector<Vec3>& com,
                const std::vector<std::pair<int32_t, int32_t>>& pairs, int levels,
                std::vector<uint8_t>& part, ThreadPool* pool = nullptr);
constexpr size_t kParallelSplitBodies = 2048;
/// splitParts with one level: the halves 0 and 1.
inline void splitHalves(const std::vector<SolverBody>& bodies, const std::vector<Vec3>& com,
                        const std::vector<std::pair<int32_t, int32_t>>& pairs,
                        std::vector<uint8_t>& half) {
  splitParts(bodies, com, pairs, 1, half);
}
/// The order in which to solve the contacts of a separator: they touch the bodies along
/// the cut, each after the last in the contacts' order (a row's neighbours, then the row
/// above), and in that order they form one long chain, a manifold per wide block. By colour
/// (greedily, the first colour neither dynamic body has yet), in their order within a colour,
/// they fill blocks. Returns the permutation of `pairs` (solver bodies a, b of each contact).
std::vector<uint32_t> colorOrder(const std::vector<SolverBody>& bodies,
                                 const std::vector<std::pair<int32_t, int32_t>>& pairs);
/// A manifold's segment (see ContactParts) from its bodies' parts: the leaf of its dynamic
/// bodies (a contact with the world or a kinematic body belongs to its dynamic body's leaf),
/// or the separator of the deepest cut that has them both below it and on its two sides.
inline uint32_t contactSegment(const std::vector<uint8_t>& part, int levels, int32_t a, int32_t b) {
  const uint32_t pa = part[size_t(a)], pb = part[size_t(b)];
  if (pa == kNoPart) return pb == kNoPart ? 0 : pb;
  if (pb == kNoPart || pb == pa) return pa;
  // The highest differing bit is the cut between them: at depth levels - w, the node whose
  // leaves share the bits above it.
  const int w = std::bit_width(pa ^ pb);
  return uint32_t(phaseBegin(levels, w)) + (pa >> w);
}
/// One level: 0 and 1 the halves, 2 between them.
inline uint8_t manifoldPart(const std::vector<uint8_t>& half, int32_t a, int32_t b) {
  return uint8_t(contactSegment(half, 1, a, b));
}

}  // namespace phys
