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
// rows in a compact structure-of-arrays form (about 190 bytes per contact point instead of
// three 164-byte rows) and owns the contact impulses between build() and store().
//
// Halves: in a world with many contacts, the World splits the dynamic bodies into two halves
// (splitHalves: at the median, on the axis whose cut the fewest contacts cross) and orders the
// contacts as the first half's, the second half's, then those between the halves. That order
// is the world's, not the threads': it is the Gauss-Seidel order of the scalar rows too,
// whatever the thread count. The first two parts share no dynamic body, so they commute:
// their blocks run on two threads at once, then the few between the halves on one, and the
// result is the same bits as the serial pass. Scalar groups (joints) come first, serially.
#pragma once

#include <cstdint>
#include <utility>
#include <vector>

#include "dynamics/solver.h"
#include "phys/collision/shapes.h"

namespace phys {

class ThreadPool;

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

class WideContacts {
 public:
  /// One entry of the schedule: a block of manifolds, or one group solved by the scalar code.
  struct Item {
    uint32_t index;  ///< block index, or group index
    bool wide;
  };
  std::vector<Item> schedule;
  bool active = false;
  /// The points' C hold the position errors at the bodies' current deltas: warmStart sets
  /// it, Solver::integratePositions clears it (the bodies moved).
  bool errorsCurrent = false;

  /// Packs the manifolds into blocks and orders them after the solver's row groups (the
  /// joints; see the file comment). The rows must be finished; sets active. With halves,
  /// manifolds [0, halfEnd[0]) are the first half's, [halfEnd[0], halfEnd[1]) the second's,
  /// and the rest lie between them (see "Halves" above); without, all are one part.
  void build(const Solver& s, const std::vector<SolverManifold>& manifolds,
             const uint32_t* halfEnd = nullptr);
  /// With halves: the schedule's parts, [0, part(0)) the row groups, [part(0), part(1)) the
  /// first half's blocks, [part(1), part(2)) the second half's, then those between.
  bool halves() const { return halves_; }
  size_t part(int i) const { return part_[i]; }
  /// Writes the contact impulses into the manifolds and deactivates: the solver passes run
  /// over the rows alone again. The blocks stay for residual().
  void store(std::vector<SolverManifold>& manifolds);
  void clear();
  /// clear(), and the blocks' storage back to the allocator (World::Impl::releaseStepBuffers).
  void release() noexcept;
  size_t capacityBytes() const;  ///< the storage held (blocks, friction, lanes, schedule)
  /// Adds the contacts' part of Solver::velocityResidual to sum, in the rows' order.
  double residual(const std::vector<SolverBody>& bodies, float h, double sum) const;

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
    wide::V3 angA, angB, mAngA, mAngB;
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
  /// Patch friction (SolverManifold::patch): a tangent pair at the centroid and the twist.
  struct Patch {
    Dir t1, t2, twist;
    wide::vf mu, twistMu;  ///< friction, and friction times the twist arm
  };
  /// The Jacobian's linear parts are the manifold's normal and tangents, the same at every
  /// point: stored once per lane for each direction (0 = normal, 1, 2 = tangents).
  struct Block {
    wide::V3 linA[3], linB[3], mLinA[3], mLinB[3];
    Point pt[Manifold::kMaxPoints];
    int32_t a[wide::kLanes] = {}, b[wide::kLanes] = {};  ///< solver bodies; 0 in empty lanes
    uint32_t manifold[wide::kLanes] = {};
    uint8_t count[wide::kLanes] = {};                           ///< points of each lane's manifold
    bool writeA[wide::kLanes] = {}, writeB[wide::kLanes] = {};  ///< dynamic bodies only
    int lanes = 0, points = 0;
  };
  void addLane(uint32_t block, const Solver& s, uint32_t index, const SolverManifold& m);
  /// Solver::solveFrictionPair on a block's lanes: the pair clamped to the disc of `bound`.
  static void frictionPair(const Block& blk, Dir& r1, Dir& r2, wide::vf bound, bool measure,
                           wide::vf& change, wide::Lanes& s);
  PointFriction* frictionOf(uint32_t block) {
    return &friction_[size_t(block) * Manifold::kMaxPoints];
  }
  std::vector<Block> blocks_;  ///< the first blockCount_ are this step's
  size_t blockCount_ = 0;
  std::vector<std::pair<uint32_t, uint32_t>> laneOf_;  ///< per manifold: block, lane
  bool patch_ = false;  ///< every manifold has patch friction (else every one per point)
  bool halves_ = false;
  size_t part_[3] = {};       ///< see part()
  size_t partBlock_[3] = {};  ///< with halves: the blocks before each part
  ThreadPool* pool_ = nullptr;
  mutable std::vector<double> residualTerms_;  ///< residual(): per manifold, kMaxPoints
  /// fn(firstBlock, endBlock) over the blocks: with halves each half's on the thread that
  /// normally solves it (the pool gives a loop's chunk h to the same thread unless that one is
  /// late, when another takes it: only speed depends on it), then the rest.
  template <class F>
  void forEachPart(F&& fn) const;
  /// Per block: its points' friction (kMaxPoints each), or with patch friction its patch.
  std::vector<PointFriction> friction_;
  std::vector<Patch> patches_;
};

/// Halves (see the file comment) from this many contact manifolds: below it, one more
/// fork-join per pass costs about what the second core saves.
constexpr size_t kHalvesMinManifolds = 256;
constexpr uint8_t kNoHalf = 0xff;
/// Per solver body: its half (0 or 1), cut at the median of the dynamic bodies' centres of
/// mass (`com`, per solver body) along the axis whose cut the fewest contacts (`pairs`, solver
/// bodies a, b) cross; kNoHalf for the world and kinematic bodies.
void splitHalves(const std::vector<SolverBody>& bodies, const std::vector<Vec3>& com,
                 const std::vector<std::pair<int32_t, int32_t>>& pairs, std::vector<uint8_t>& half);
/// The order in which to solve the contacts between the halves: they touch the bodies along
/// the cut, each after the last in the contacts' order (a row's neighbours, then the row
/// above), and in that order they form one long chain, a manifold per wide block. By colour
/// (greedily, the first colour neither dynamic body has yet), in their order within a colour,
/// they fill blocks. Returns the permutation of `pairs` (solver bodies a, b of each contact).
std::vector<uint32_t> colorOrder(const std::vector<SolverBody>& bodies,
                                 const std::vector<std::pair<int32_t, int32_t>>& pairs);
/// A manifold's part: the half of its dynamic bodies, or 2 between the halves.
inline uint8_t manifoldPart(const std::vector<uint8_t>& half, int32_t a, int32_t b) {
  const uint8_t ha = half[size_t(a)], hb = half[size_t(b)];
  if (ha == kNoHalf) return hb == kNoHalf ? 0 : hb;
  return hb == kNoHalf || hb == ha ? ha : 2;
}

}  // namespace phys
