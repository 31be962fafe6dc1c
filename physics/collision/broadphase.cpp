// Broad phase: two dynamic AABB trees plus a persistent, sorted pair list.
//
// Why a dynamic AABB tree (Box2D v3's b2DynamicTree: fat leaves, incremental insertion that
// picks the sibling by the surface-area heuristic with branch and bound, tree rotations on
// the way up, and a binned-SAH rebuild for bulk changes) rather than sweep-and-prune or a grid:
//  - Work is proportional to what moved. Updating a proxy whose fat box changed is
//    O(log n) and finding its new pairs is one tree query; the ~99% of proxies whose fat box
//    stayed put in a settling pile or a pyramid are not touched at all.
//  - Sweep-and-prune sweeps every proxy each step or, incremental, suffers in piles and
//    towers where most boxes overlap on the sweep axis. A grid needs a cell size that fits
//    the scene; a large static ground or mixed sizes put one proxy in thousands of cells.
//  - The same tree answers `query` (ray casts, regions) with no extra structure.
// Static and non-static proxies live in separate trees. Statics never move, so their tree
// stays as built; a static proxy only ever looks into the non-static tree, so static-static
// pairs are never even visited.
//
// Tree updates: a proxy whose new fat box still overlaps the one it was placed with is
// refitted in place (leaf box set, ancestors refitted; no restructuring), which is what a
// settling body does. A created proxy, one that moved farther, or one whose static flag
// flipped waits in a pending list (query scans it linearly meanwhile) until computePairs,
// which inserts them one by one or, when they are a large part of their tree (the initial
// build, an explosion), rebuilds that tree top-down with binned SAH: several times faster
// than as many insertions, a better tree, and a layout with siblings side by side and
// subtrees contiguous. So that a caller who rarely calls computePairs does not make queries
// linear, the mutators also flush once the pending list outgrows the trees.
//
// Pairs: the current pair list is kept between calls, sorted by (a, b) user values. A proxy
// whose fat box changed (created, moved out of its fat box, destroyed, static flag flipped)
// is marked dirty, and its user value recorded. computePairs queries the trees once per
// live dirty proxy for its pairs, sorts those (radix), and merges them with the kept old
// pairs, dropping every old pair with a dirty user (a bitmap test). The merge is linear in
// the pair count, but so is the output (the contract is the full list), so a step costs a
// small constant times the unavoidable copy, and the merge writes the output in the same
// pass; with nothing dirty it is just the copy. When a third or more of the proxies are
// dirty the list is recomputed by one simultaneous traversal of tree pairs instead.
// Everything is ordered by user values or by the call sequence (free lists are LIFO, trees
// built by fixed rules), never by addresses or hash order: same calls, same output. Buffers
// are kept between calls, so the steady state does not allocate.
//
// The bound (computePairs with maxPairs): a pile of n coincident boxes has n^2 / 2 pairs, so
// both ways of finding pairs stop as soon as they hold more than the bound, and the list is
// then found again as its first maxPairs entries (findFirstPairs: proxies in user order, one
// query each, at a cost proportional to what it keeps). Which pairs those are depends only on
// the fat boxes, as the full list does, so a world restored from a snapshot keeps the same
// ones. A cut list is not updated incrementally: the next call with anything dirty starts
// from scratch, and returns to the incremental path once the pairs fit again.
#include "phys/collision/broadphase.h"

#include <algorithm>
#include <bit>
#include <cassert>
#include <cfloat>
#include <new>
#include <type_traits>

namespace phys {
namespace {

constexpr int32_t kNull = -1;
constexpr int kDynamicTree = 0;
constexpr int kStaticTree = 1;
// User values below this get a direct bitmap (at most 2 MiB) in the pair merge.
constexpr uint32_t kDirectUserBits = 1u << 24;

// Half the surface area: the SAH cost of a node (the constant factor does not matter).
inline float area(const AABB& b) {
  float dx = b.hi.x - b.lo.x, dy = b.hi.y - b.lo.y, dz = b.hi.z - b.lo.z;
  return dx * dy + dy * dz + dz * dx;
}

// By value, unlike std::min (a reference, which GCC sometimes turns into a branch on which
// operand to load) and fmin (NaN handling): this compiles to minss/maxss.
inline float minOf(float a, float b) {
  return b < a ? b : a;
}
inline float maxOf(float a, float b) {
  return a < b ? b : a;
}

inline AABB unite(const AABB& a, const AABB& b) {
  return {{minOf(a.lo.x, b.lo.x), minOf(a.lo.y, b.lo.y), minOf(a.lo.z, b.lo.z)},
          {maxOf(a.hi.x, b.hi.x), maxOf(a.hi.y, b.hi.y), maxOf(a.hi.z, b.hi.z)}};
}

inline Vec3 center(const AABB& b) {
  return (b.lo + b.hi) * 0.5f;
}

// overlaps() without short-circuit branches: in a traversal the outcome is unpredictable,
// so one branch on the combined result beats six.
inline bool touches(const AABB& a, const AABB& b) {
  return (a.lo.x <= b.hi.x) & (b.lo.x <= a.hi.x) & (a.lo.y <= b.hi.y) & (b.lo.y <= a.hi.y) &
         (a.lo.z <= b.hi.z) & (b.lo.z <= a.hi.z);
}

// Traversal stack: inline storage covers any sane tree height; a pathologically deep tree
// spills to the heap instead of overflowing. Local, so queries are reentrant and const.
template <class T>
class SmallStack {
 public:
  bool empty() const { return n_ == 0; }
  void push(T v) {
    if (n_ < kInline) {
      inline_[n_] = v;
    } else {
      spill_.push_back(v);
    }
    ++n_;
  }
  T pop() {
    --n_;
    if (n_ < kInline) return inline_[n_];
    T v = spill_.back();
    spill_.pop_back();
    return v;
  }

 private:
  static constexpr int kInline = 256;
  T inline_[kInline];
  int n_ = 0;
  std::vector<T> spill_;
};

// std::allocator with 64-byte (cache line) alignment.
template <class T>
struct CacheLineAllocator {
  using value_type = T;
  static constexpr std::align_val_t kAlign{64};
  CacheLineAllocator() = default;
  template <class U>
  CacheLineAllocator(const CacheLineAllocator<U>&) {}
  T* allocate(size_t n) { return static_cast<T*>(::operator new(n * sizeof(T), kAlign)); }
  void deallocate(T* p, size_t) { ::operator delete(p, kAlign); }
  friend bool operator==(const CacheLineAllocator&, const CacheLineAllocator&) { return true; }
};

// Calls a traversal's callback; true when it asks to stop (a callback returning void never
// does).
template <class F, class... A>
inline bool callStops(F& f, A... args) {
  if constexpr (std::is_void_v<std::invoke_result_t<F&, A...>>) {
    f(args...);
    return false;
  } else {
    return bool(f(args...));
  }
}

// The part of a node that traversals read, 32 bytes so two share a cache line.
struct alignas(32) Node {
  AABB box;
  int32_t child1;  // internal: first child; leaf: ~proxy (negative)
  int32_t child2;  // internal: second child; leaf: the proxy's user value, so a traversal
                   // need not look the proxy up
  bool isLeaf() const { return child1 < 0; }
  int32_t proxy() const { return ~child1; }
  uint32_t user() const { return uint32_t(child2); }
};
static_assert(sizeof(Node) == 32);

// The part only updates read.
struct Link {
  int32_t parent;  // next free node while on the free list
  int32_t height;  // 0 for a leaf
};

struct LeafRef {
  AABB box;
  int32_t proxy;
  uint32_t user;
};

struct Bounds {
  AABB box;        // union of the boxes
  AABB centroids;  // bounds of their centroids (lo + hi)
};

class Tree {
 public:
  int32_t insert(const AABB& box, int32_t proxy, uint32_t user);
  void remove(int32_t leaf);
  /// Changes a leaf's box in place and refits its ancestors (no restructuring).
  void moveLeaf(int32_t leaf, const AABB& box);
  /// Replaces the tree by a binned-SAH build over `refs` (reordered), laid out depth first
  /// with siblings side by side. Leaves get new nodes: see forEachLeaf.
  void rebuild(std::vector<LeafRef>* refs);
  int leafCount() const { return leafCount_; }

  template <class F>
  void forEachLeaf(F&& f) const {
    for (size_t i = 0; i < nodes_.size(); ++i) {
      if (links_[i].height == 0) f(int32_t(i), nodes_[i].proxy());
    }
  }

  /// Calls f(proxy, user) for every leaf whose box overlaps `box`. f may return bool: true
  /// stops the query (then query returns false; otherwise true).
  template <class F>
  bool query(const AABB& box, F&& f) const {
    if (root_ == kNull || !touches(nodes_[root_].box, box)) return true;
    if (nodes_[root_].isLeaf()) return !callStops(f, nodes_[root_].proxy(), nodes_[root_].user());
    // The stack holds internal nodes known to overlap; children are tested from the parent
    // (siblings usually share a cache line).
    SmallStack<int32_t> stack;
    stack.push(root_);
    while (!stack.empty()) {
      const Node& n = nodes_[stack.pop()];
      for (int32_t c : {n.child1, n.child2}) {
        const Node& child = nodes_[c];
        if (!touches(child.box, box)) continue;
        if (child.isLeaf()) {
          if (callStops(f, child.proxy(), child.user())) return false;
        } else {
          stack.push(c);
        }
      }
    }
    return true;
  }

  /// Calls f(proxyA, userA, proxyB, userB) once for every overlapping pair of leaves, one
  /// from this tree and one from `other`, or, with other == this, two distinct leaves of it.
  /// As in query, f may return true to stop (then the call returns false).
  template <class F>
  bool overlappingPairs(const Tree& other, F&& f) const;

 private:
  int32_t allocNode();
  void freeNode(int32_t i);
  int32_t findBestSibling(const AABB& boxD) const;
  void rotate(int32_t iA);
  void refit(int32_t i) {
    Node& n = nodes_[i];
    n.box = unite(nodes_[n.child1].box, nodes_[n.child2].box);
    links_[i].height = 1 + std::max(links_[n.child1].height, links_[n.child2].height);
  }
  int32_t split(std::vector<LeafRef>& refs, int32_t begin, int32_t end, const Bounds& all,
                Bounds* left, Bounds* right);

  std::vector<Node, CacheLineAllocator<Node>> nodes_;
  std::vector<Link> links_;
  int32_t root_ = kNull;
  int32_t free_ = kNull;
  int leafCount_ = 0;
  struct BuildItem {
    int32_t begin, end;  // range of refs
    int32_t node;        // already allocated
    Bounds bounds;       // of the range
  };
  std::vector<BuildItem> buildStack_;
};

int32_t Tree::allocNode() {
  if (free_ != kNull) {
    int32_t i = free_;
    free_ = links_[i].parent;
    return i;
  }
  nodes_.push_back({});
  links_.push_back({});
  return int32_t(nodes_.size() - 1);
}

void Tree::freeNode(int32_t i) {
  links_[i] = {free_, -1};
  free_ = i;
}

// Box2D v3's greedy descent with a lower bound on the cost of going deeper: the cost of
// making D a sibling of node X is area(X u D) plus the growth of all of X's ancestors.
int32_t Tree::findBestSibling(const AABB& boxD) const {
  const Vec3 centerD = center(boxD);
  const float areaD = area(boxD);
  int32_t index = root_;
  float areaBase = area(nodes_[index].box);
  float directCost = area(unite(nodes_[index].box, boxD));
  float inheritedCost = 0.0f;
  int32_t best = index;
  float bestCost = directCost;
  while (!nodes_[index].isLeaf()) {
    const int32_t c1 = nodes_[index].child1, c2 = nodes_[index].child2;
    float cost = directCost + inheritedCost;
    if (cost < bestCost) {
      best = index;
      bestCost = cost;
    }
    // Every node below `index` also pays for `index` growing.
    inheritedCost += directCost - areaBase;

    const bool leaf1 = nodes_[c1].isLeaf(), leaf2 = nodes_[c2].isLeaf();
    const float direct1 = area(unite(nodes_[c1].box, boxD));
    const float direct2 = area(unite(nodes_[c2].box, boxD));
    float lower1 = FLT_MAX, lower2 = FLT_MAX, area1 = 0.0f, area2 = 0.0f;
    if (leaf1) {
      if (direct1 + inheritedCost < bestCost) {
        best = c1;
        bestCost = direct1 + inheritedCost;
      }
    } else {
      area1 = area(nodes_[c1].box);
      lower1 = inheritedCost + direct1 + std::min(areaD - area1, 0.0f);
    }
    if (leaf2) {
      if (direct2 + inheritedCost < bestCost) {
        best = c2;
        bestCost = direct2 + inheritedCost;
      }
    } else {
      area2 = area(nodes_[c2].box);
      lower2 = inheritedCost + direct2 + std::min(areaD - area2, 0.0f);
    }
    if (leaf1 && leaf2) break;
    if (bestCost <= lower1 && bestCost <= lower2) break;
    if (lower1 == lower2 && !leaf1) {
      // Both children contain D (equal bounds): break the tie by centroid distance.
      lower1 = lengthSquared(center(nodes_[c1].box) - centerD);
      lower2 = lengthSquared(center(nodes_[c2].box) - centerD);
    }
    if (lower1 < lower2 && !leaf1) {
      index = c1;
      areaBase = area1;
      directCost = direct1;
    } else {
      index = c2;
      areaBase = area2;
      directCost = direct2;
    }
  }
  return best;
}

// Box2D v3's SAH rotation: swap a child of A with a grandchild (or two grandchildren) when
// that lowers the summed area of A's children. A's own box and leaf set do not change.
// Names: A = {B = {D, E}, C = {F, G}}.
void Tree::rotate(int32_t iA) {
  if (links_[iA].height < 2) return;
  Node& A = nodes_[iA];
  const int32_t iB = A.child1, iC = A.child2;
  Node& B = nodes_[iB];
  Node& C = nodes_[iC];
  const float areaB = B.isLeaf() ? 0.0f : area(B.box);
  const float areaC = C.isLeaf() ? 0.0f : area(C.box);

  enum { kNone, kBF, kBG, kCD, kCE, kDF, kDG } best = kNone;
  float bestCost = areaB + areaC;  // summed area of A's internal children
  auto consider = [&](float cost, decltype(best) r) {
    if (cost < bestCost) {
      bestCost = cost;
      best = r;
    }
  };
  if (!C.isLeaf()) {
    const AABB& F = nodes_[C.child1].box;
    const AABB& G = nodes_[C.child2].box;
    consider(areaB + area(unite(B.box, G)), kBF);  // A = {F, C = {B, G}}
    consider(areaB + area(unite(B.box, F)), kBG);  // A = {G, C = {F, B}}
  }
  if (!B.isLeaf()) {
    const AABB& D = nodes_[B.child1].box;
    const AABB& E = nodes_[B.child2].box;
    consider(areaC + area(unite(C.box, E)), kCD);  // A = {B = {C, E}, D}
    consider(areaC + area(unite(C.box, D)), kCE);  // A = {B = {D, C}, E}
    if (!C.isLeaf()) {
      const AABB& F = nodes_[C.child1].box;
      const AABB& G = nodes_[C.child2].box;
      consider(area(unite(F, E)) + area(unite(D, G)), kDF);  // B = {F, E}, C = {D, G}
      consider(area(unite(G, E)) + area(unite(F, D)), kDG);  // B = {G, E}, C = {F, D}
    }
  }

  auto swapChild = [&](int32_t& slotX, int32_t parentX, int32_t& slotY, int32_t parentY) {
    std::swap(slotX, slotY);
    links_[slotX].parent = parentX;
    links_[slotY].parent = parentY;
  };
  switch (best) {
    case kNone:
      return;
    case kBF:
      swapChild(A.child1, iA, C.child1, iC);
      refit(iC);
      break;
    case kBG:
      swapChild(A.child1, iA, C.child2, iC);
      refit(iC);
      break;
    case kCD:
      swapChild(A.child2, iA, B.child1, iB);
      refit(iB);
      break;
    case kCE:
      swapChild(A.child2, iA, B.child2, iB);
      refit(iB);
      break;
    case kDF:
      swapChild(B.child1, iB, C.child1, iC);
      refit(iB);
      refit(iC);
      break;
    case kDG:
      swapChild(B.child1, iB, C.child2, iC);
      refit(iB);
      refit(iC);
      break;
  }
  links_[iA].height = 1 + std::max(links_[A.child1].height, links_[A.child2].height);
}

int32_t Tree::insert(const AABB& box, int32_t proxy, uint32_t user) {
  ++leafCount_;
  const int32_t leaf = allocNode();
  nodes_[leaf] = {box, ~proxy, int32_t(user)};
  links_[leaf] = {kNull, 0};
  if (root_ == kNull) {
    root_ = leaf;
    return leaf;
  }
  const int32_t sibling = findBestSibling(box);
  const int32_t oldParent = links_[sibling].parent;
  const int32_t newParent = allocNode();
  nodes_[newParent] = {unite(box, nodes_[sibling].box), sibling, leaf};
  links_[newParent] = {oldParent, links_[sibling].height + 1};
  links_[sibling].parent = newParent;
  links_[leaf].parent = newParent;
  if (oldParent == kNull) {
    root_ = newParent;
  } else if (nodes_[oldParent].child1 == sibling) {
    nodes_[oldParent].child1 = newParent;
  } else {
    nodes_[oldParent].child2 = newParent;
  }
  for (int32_t i = oldParent; i != kNull; i = links_[i].parent) {
    refit(i);
    rotate(i);
  }
  return leaf;
}

void Tree::remove(int32_t leaf) {
  --leafCount_;
  if (leaf == root_) {
    root_ = kNull;
    freeNode(leaf);
    return;
  }
  const int32_t parent = links_[leaf].parent;
  const int32_t grand = links_[parent].parent;
  const int32_t sibling =
      nodes_[parent].child1 == leaf ? nodes_[parent].child2 : nodes_[parent].child1;
  links_[sibling].parent = grand;
  if (grand == kNull) {
    root_ = sibling;
  } else {
    if (nodes_[grand].child1 == parent) {
      nodes_[grand].child1 = sibling;
    } else {
      nodes_[grand].child2 = sibling;
    }
    for (int32_t i = grand; i != kNull; i = links_[i].parent) refit(i);
  }
  freeNode(parent);
  freeNode(leaf);
}

void Tree::moveLeaf(int32_t leaf, const AABB& box) {
  nodes_[leaf].box = box;
  for (int32_t i = links_[leaf].parent; i != kNull; i = links_[i].parent) {
    Node& n = nodes_[i];
    const AABB b = unite(nodes_[n.child1].box, nodes_[n.child2].box);
    // An unchanged box leaves every ancestor unchanged too.
    if (b.lo == n.box.lo && b.hi == n.box.hi) break;
    n.box = b;
  }
}

constexpr AABB kEmptyBox{{FLT_MAX, FLT_MAX, FLT_MAX}, {-FLT_MAX, -FLT_MAX, -FLT_MAX}};

// Bounds of refs[begin, end): their union, and the box of their centroids (as lo + hi,
// twice the center, which bins just as well).
Bounds boundsOf(const LeafRef* refs, int32_t begin, int32_t end) {
  Bounds b{kEmptyBox, kEmptyBox};
  for (int32_t i = begin; i < end; ++i) {
    const AABB& r = refs[i].box;
    const Vec3 c = r.lo + r.hi;
    b.box = unite(b.box, r);
    b.centroids = unite(b.centroids, {c, c});
  }
  return b;
}

// Splits refs[begin, end) in two by the best of 15 planes along the widest centroid axis
// (binned SAH); returns the first index of the second half and the bounds of both halves
// (from the bins, so no extra pass over the refs).
int32_t Tree::split(std::vector<LeafRef>& refs, int32_t begin, int32_t end, const Bounds& all,
                    Bounds* left, Bounds* right) {
  constexpr int kBins = 16;
  const int32_t count = end - begin;
  const Vec3 ext = all.centroids.hi - all.centroids.lo;
  const int axis = ext.x >= ext.y && ext.x >= ext.z ? 0 : (ext.y >= ext.z ? 1 : 2);
  const float lo = all.centroids.lo[axis], width = ext[axis];
  auto halves = [&] {
    // Two refs, or coincident centroids: any split is as good.
    const int32_t half = begin + count / 2;
    *left = boundsOf(refs.data(), begin, half);
    *right = boundsOf(refs.data(), half, end);
    return half;
  };
  if (!(width > 0.0f) || count <= 2) return halves();
  const float scale = float(kBins) / width;
  auto binOf = [&](const LeafRef& r) {
    int b = int((r.box.lo[axis] + r.box.hi[axis] - lo) * scale);
    return std::clamp(b, 0, kBins - 1);
  };
  Bounds bins[kBins];
  int binCount[kBins] = {};
  for (int b = 0; b < kBins; ++b) bins[b] = {kEmptyBox, kEmptyBox};
  for (int32_t i = begin; i < end; ++i) {
    const AABB& r = refs[i].box;
    const Vec3 c = r.lo + r.hi;
    const int b = binOf(refs[i]);
    bins[b].box = unite(bins[b].box, r);
    bins[b].centroids = unite(bins[b].centroids, {c, c});
    ++binCount[b];
  }
  // Sweep from the right for the right-hand costs, then from the left choosing the plane.
  float rightCost[kBins];
  AABB acc = kEmptyBox;
  int n = 0;
  for (int b = kBins - 1; b > 0; --b) {
    acc = unite(acc, bins[b].box);
    n += binCount[b];
    rightCost[b] = n ? float(n) * area(acc) : 0.0f;
  }
  int bestPlane = -1;
  float bestCost = FLT_MAX;
  acc = kEmptyBox;
  n = 0;
  for (int b = 0; b < kBins - 1; ++b) {
    acc = unite(acc, bins[b].box);
    n += binCount[b];
    if (n == 0 || n == count) continue;
    const float cost = float(n) * area(acc) + rightCost[b + 1];
    if (cost < bestCost) {
      bestCost = cost;
      bestPlane = b;
    }
  }
  if (bestPlane < 0) return halves();
  auto mid = std::partition(refs.begin() + begin, refs.begin() + end,
                            [&](const LeafRef& r) { return binOf(r) <= bestPlane; });
  *left = *right = {kEmptyBox, kEmptyBox};
  for (int b = 0; b < kBins; ++b) {
    Bounds& side = b <= bestPlane ? *left : *right;
    side.box = unite(side.box, bins[b].box);
    side.centroids = unite(side.centroids, bins[b].centroids);
  }
  return int32_t(mid - refs.begin());
}

void Tree::rebuild(std::vector<LeafRef>* refsPtr) {
  std::vector<LeafRef>& refs = *refsPtr;
  nodes_.clear();
  links_.clear();
  root_ = kNull;
  free_ = kNull;
  leafCount_ = int(refs.size());
  if (refs.empty()) return;
  nodes_.reserve(2 * refs.size() + 1);
  links_.reserve(2 * refs.size() + 1);
  // Siblings are allocated side by side at an even index, so with the 64-byte aligned
  // storage a traversal reads both children of a node from one cache line. Slot 0 is a
  // spare (on the free list) so that the root sits alone at 1 and pairs start at 2.
  nodes_.push_back({});
  links_.push_back({kNull, 0});
  freeNode(0);
  nodes_.push_back({});
  links_.push_back({kNull, 0});
  root_ = 1;
  buildStack_.clear();
  buildStack_.push_back(
      {0, int32_t(refs.size()), root_, boundsOf(refs.data(), 0, int32_t(refs.size()))});
  while (!buildStack_.empty()) {
    const BuildItem item = buildStack_.back();
    buildStack_.pop_back();
    if (item.end - item.begin == 1) {
      const LeafRef& r = refs[item.begin];
      nodes_[item.node] = {r.box, ~r.proxy, int32_t(r.user)};
      continue;
    }
    Bounds left, right;
    const int32_t mid = split(refs, item.begin, item.end, item.bounds, &left, &right);
    const int32_t c1 = int32_t(nodes_.size());
    nodes_.push_back({});
    nodes_.push_back({});
    links_.push_back({item.node, 0});
    links_.push_back({item.node, 0});
    nodes_[item.node] = {item.bounds.box, c1, c1 + 1};
    // Depth first, first child first: subtrees stay contiguous in memory.
    buildStack_.push_back({mid, item.end, c1 + 1, right});
    buildStack_.push_back({item.begin, mid, c1, left});
  }
  // Children come after their parent, so one backward pass sets every height.
  for (int32_t i = int32_t(nodes_.size()) - 1; i >= 1; --i) {
    const Node& n = nodes_[i];
    if (!n.isLeaf()) {
      links_[i].height = 1 + std::max(links_[n.child1].height, links_[n.child2].height);
    }
  }
}

template <class F>
bool Tree::overlappingPairs(const Tree& other, F&& f) const {
  const bool self = &other == this;
  if (root_ == kNull || other.root_ == kNull) return true;
  const Node* bNodes = other.nodes_.data();
  // Items are (a in this tree, b in other) whose boxes are known to overlap and which are
  // not both leaves, or (a, kNull): all pairs inside a's subtree (a internal). As in query,
  // children are tested before they are pushed.
  struct Item {
    int32_t a, b;
  };
  SmallStack<Item> stack;
  bool stop = false;
  auto found = [&](int32_t a, int32_t b) {
    const Node& A = nodes_[a];
    const Node& B = bNodes[b];
    if (A.isLeaf() && B.isLeaf()) {
      stop |= callStops(f, A.proxy(), A.user(), B.proxy(), B.user());
    } else {
      stack.push({a, b});
    }
  };
  if (self) {
    if (!nodes_[root_].isLeaf()) stack.push({root_, kNull});
  } else if (touches(nodes_[root_].box, bNodes[other.root_].box)) {
    found(root_, other.root_);
  }
  while (!stack.empty()) {
    if (stop) return false;
    const Item it = stack.pop();
    const Node& A = nodes_[it.a];
    if (it.b == kNull) {
      if (!nodes_[A.child1].isLeaf()) stack.push({A.child1, kNull});
      if (!nodes_[A.child2].isLeaf()) stack.push({A.child2, kNull});
      if (touches(nodes_[A.child1].box, nodes_[A.child2].box)) found(A.child1, A.child2);
      continue;
    }
    const Node& B = bNodes[it.b];
    // Descend the larger box (a leaf cannot be descended).
    if (B.isLeaf() || (!A.isLeaf() && area(A.box) >= area(B.box))) {
      for (int32_t c : {A.child1, A.child2}) {
        if (touches(nodes_[c].box, B.box)) found(c, it.b);
      }
    } else {
      for (int32_t c : {B.child1, B.child2}) {
        if (touches(A.box, bNodes[c].box)) found(it.a, c);
      }
    }
  }
  return !stop;
}

struct Proxy {
  AABB fat;
  AABB home;  // fat box when last placed in the tree: bounds how far a leaf is refitted
  uint32_t user;
  int32_t leaf;     // node in trees[isStatic]; kNull while pending or dead
  int32_t pending;  // slot in Impl::pending while waiting for the tree; kNull otherwise
  int32_t nextFree;
  bool isStatic;
  bool alive;
};

inline uint64_t keyOf(ProxyPair p) {
  return (uint64_t(p.a) << 32) | p.b;
}
inline ProxyPair makePair(uint32_t u, uint32_t v) {
  return u < v ? ProxyPair{u, v} : ProxyPair{v, u};
}

// Stable LSD radix sort by (a, b). The pair is first packed into the fewest bits that hold
// it ((a - minA) above (b - minB)), so 100k or 1M user values need 4 passes of at most 11
// bits. On return *v holds the result; *tmp is scratch.
void sortPairs(std::vector<ProxyPair>* v, std::vector<ProxyPair>* tmp) {
  const size_t n = v->size();
  if (n < 512) {
    std::sort(v->begin(), v->end());
    return;
  }
  if (tmp->size() < n) tmp->resize(n);
  ProxyPair* src = v->data();
  ProxyPair* dst = tmp->data();
  uint32_t minA = UINT32_MAX, maxA = 0, minB = UINT32_MAX, maxB = 0;
  for (size_t i = 0; i < n; ++i) {
    minA = std::min(minA, src[i].a);
    maxA = std::max(maxA, src[i].a);
    minB = std::min(minB, src[i].b);
    maxB = std::max(maxB, src[i].b);
  }
  const int bitsB = std::bit_width(maxB - minB);
  const int totalBits = std::bit_width(maxA - minA) + bitsB;
  if (totalBits == 0) return;
  constexpr int kMaxDigitBits = 11, kMaxDigits = 6;  // 6 * 11 >= 64
  const int digits = (totalBits + kMaxDigitBits - 1) / kMaxDigitBits;
  const int digitBits = (totalBits + digits - 1) / digits;
  const uint64_t mask = (uint64_t(1) << digitBits) - 1;
  auto packed = [=](ProxyPair p) { return (uint64_t(p.a - minA) << bitsB) | (p.b - minB); };
  uint32_t count[kMaxDigits][1 << kMaxDigitBits] = {};
  for (size_t i = 0; i < n; ++i) {
    const uint64_t k = packed(src[i]);
    for (int d = 0; d < digits; ++d) ++count[d][(k >> (d * digitBits)) & mask];
  }
  for (int d = 0; d < digits; ++d) {
    uint32_t sum = 0;
    for (uint64_t k = 0; k <= mask; ++k) {
      const uint32_t c = count[d][k];
      count[d][k] = sum;
      sum += c;
    }
    uint32_t* offset = count[d];
    for (size_t i = 0; i < n; ++i) {
      dst[offset[(packed(src[i]) >> (d * digitBits)) & mask]++] = src[i];
    }
    std::swap(src, dst);
  }
  if (src != v->data()) {
    v->swap(*tmp);
    v->resize(n);  // shrinks only: the scratch may have been longer
  }
}

}  // namespace

struct BroadPhase::Impl {
  std::vector<Proxy> proxies;
  std::vector<uint8_t> dirtyFlag;  // by proxy index
  std::vector<int32_t> dirty;      // indices with dirtyFlag set, in marking order
  // User values whose old pairs must go: recorded when marked, since a destroyed proxy's
  // index (and so its user field) may be reused before computePairs.
  std::vector<uint32_t> dirtyUsers;
  std::vector<int32_t> pending;  // live proxies not in their tree yet
  int32_t freeProxy = kNull;
  int count = 0;
  Tree trees[2];

  // The current pairs, sorted, in pairs[0, pairCount). Between releases (releaseScratch)
  // the vectors only grow so the merge writes through raw pointers without clearing;
  // pairsBack is the other half of a double buffer and sorting scratch. fresh: new pairs
  // being found.
  std::vector<ProxyPair> pairs, pairsBack, fresh;
  size_t pairCount = 0;
  std::vector<uint64_t> userBits;  // dirty users as bits (all clear between calls)
  uint32_t maxUser = 0;
  std::vector<LeafRef> refs;
  std::vector<uint64_t> queryOrder;  // (leaf, proxy) of the live dirty proxies
  // The pair bound (computePairs with maxPairs). `truncated`: pairs[0, pairCount) is the
  // first `truncLimit` pairs of a longer list, so the next call with anything dirty (or
  // another bound) recomputes from scratch; `dropped` is what that call reported. `stale`:
  // the list is not to be trusted (a call in progress, one an exception left halfway,
  // forgetPairs), so the next call recomputes it from scratch.
  bool truncated = false, stale = false;
  size_t truncLimit = 0;
  uint64_t dropped = 0;
  std::vector<uint32_t> batch;  // findFirstPairs: one proxy's higher neighbours

  Tree& treeOf(const Proxy& p) { return trees[p.isStatic ? kStaticTree : kDynamicTree]; }
  void markDirty(int32_t p) {
    dirtyUsers.push_back(proxies[p].user);
    if (!dirtyFlag[p]) {
      dirtyFlag[p] = 1;
      dirty.push_back(p);
    }
  }
  void addPending(int32_t p);
  void removePending(int32_t p);
  void flushPending();
  void rebuildTree(int t);
  // Each returns false, leaving the pair list as it was, once it knows the pairs are more
  // than maxPairs.
  bool findNewPairs(size_t maxPairs);
  bool findAllPairs(size_t maxPairs);
  void mergePairs(std::vector<ProxyPair>* result);
  /// The first maxPairs pairs of the full list, found in that order; returns how many pairs
  /// were left out, counted with a work budget (at least 1).
  uint64_t findFirstPairs(size_t maxPairs);
};

void BroadPhase::Impl::addPending(int32_t p) {
  proxies[p].pending = int32_t(pending.size());
  pending.push_back(p);
  // Bound the linear part of query for callers that rarely call computePairs. Flushing when
  // the list outgrows the trees (by 2x) keeps the rebuild work amortized O(log n) per proxy.
  if (pending.size() >=
      std::max<size_t>(4096, 2 * size_t(trees[0].leafCount() + trees[1].leafCount()))) {
    flushPending();
  }
}

void BroadPhase::Impl::removePending(int32_t p) {
  const int32_t slot = proxies[p].pending;
  pending[slot] = pending.back();
  proxies[pending[slot]].pending = slot;
  pending.pop_back();
  proxies[p].pending = kNull;
}

void BroadPhase::Impl::flushPending() {
  if (pending.empty()) return;
  int waiting[2] = {0, 0};
  for (int32_t p : pending) ++waiting[proxies[p].isStatic ? kStaticTree : kDynamicTree];
  bool rebuilt[2] = {false, false};
  for (int t = 0; t < 2; ++t) {
    // A rebuild costs about a quarter of an insertion per leaf and gives a better tree.
    if (waiting[t] >= 64 && 4 * waiting[t] >= trees[t].leafCount() + waiting[t]) {
      rebuildTree(t);
      rebuilt[t] = true;
    }
  }
  for (int32_t p : pending) {
    Proxy& P = proxies[p];
    P.pending = kNull;
    P.home = P.fat;
    const int t = P.isStatic ? kStaticTree : kDynamicTree;
    if (!rebuilt[t]) P.leaf = trees[t].insert(P.fat, p, P.user);
  }
  pending.clear();
}

void BroadPhase::Impl::rebuildTree(int t) {
  refs.clear();
  refs.reserve(trees[t].leafCount() + pending.size());
  for (size_t p = 0; p < proxies.size(); ++p) {
    Proxy& P = proxies[p];
    if (P.alive && (P.isStatic ? kStaticTree : kDynamicTree) == t) {
      refs.push_back({P.fat, int32_t(p), P.user});
      P.home = P.fat;
    }
  }
  trees[t].rebuild(&refs);
  trees[t].forEachLeaf([&](int32_t node, int32_t p) { proxies[p].leaf = node; });
}

// New pairs of every live dirty proxy, by one query each. A pair of two dirty proxies is
// found by both queries (overlap is symmetric and a static proxy still sees the dynamic
// tree), so only the lower index keeps it.
bool BroadPhase::Impl::findNewPairs(size_t maxPairs) {
  // In leaf-node order, so queries of nearby proxies meet warm cache lines more often.
  queryOrder.clear();
  for (int32_t p : dirty) {
    if (proxies[p].alive) queryOrder.push_back((uint64_t(proxies[p].leaf) << 32) | uint32_t(p));
  }
  std::sort(queryOrder.begin(), queryOrder.end());
  fresh.clear();
  for (uint64_t order : queryOrder) {
    const int32_t p = int32_t(uint32_t(order));
    const Proxy& P = proxies[p];
    // Every new pair is in the result: past maxPairs of them, stop.
    auto visit = [&](int32_t q, uint32_t uq) {
      if (q != p && !(dirtyFlag[q] && q < p)) fresh.push_back(makePair(P.user, uq));
      return fresh.size() > maxPairs;
    };
    if (!trees[kDynamicTree].query(P.fat, visit)) return false;
    if (!P.isStatic && !trees[kStaticTree].query(P.fat, visit)) return false;
  }
  sortPairs(&fresh, &pairsBack);
  return true;
}

// Every pair from scratch: dynamic-dynamic and dynamic-static by simultaneous traversal.
bool BroadPhase::Impl::findAllPairs(size_t maxPairs) {
  fresh.clear();
  // Room for a dense pile up front: reserving only maps address space, and it saves the
  // copies of repeated growth.
  fresh.reserve(std::min(std::max(pairCount, size_t(count) * 16), maxPairs));
  auto visit = [&](int32_t, uint32_t up, int32_t, uint32_t uq) {
    fresh.push_back(makePair(up, uq));
    return fresh.size() > maxPairs;
  };
  const Tree& dyn = trees[kDynamicTree];
  if (!dyn.overlappingPairs(dyn, visit) || !dyn.overlappingPairs(trees[kStaticTree], visit))
    return false;
  sortPairs(&fresh, &pairsBack);
  pairs.swap(fresh);
  pairCount = pairs.size();
  return true;
}

// More pairs than the bound: the first maxPairs of the sorted list, without building the
// rest. Proxies are taken in user order and each query keeps its neighbours of higher user
// value, so the pairs come out in list order and each is found once; a static proxy asks
// only the dynamic tree, as in the full list. The work is a query per proxy taken: the
// neighbours it visits are kept pairs, either found now or (lower neighbours) already, but
// for the last proxy's cut-off ones, so it is proportional to maxPairs plus the proxies.
// The pairs depend only on the fat boxes and static flags, like the full list.
uint64_t BroadPhase::Impl::findFirstPairs(size_t maxPairs) {
  queryOrder.clear();
  for (size_t p = 0; p < proxies.size(); ++p)
    if (proxies[p].alive) queryOrder.push_back((uint64_t(proxies[p].user) << 32) | p);
  std::sort(queryOrder.begin(), queryOrder.end());
  fresh.clear();
  uint64_t left = 0;
  // After the bound, the pairs left out are counted on, by the same queries, until they
  // visited as many neighbours as the bound: a lower bound for the price of the pairs kept.
  size_t budget = maxPairs;
  for (uint64_t order : queryOrder) {
    const Proxy& P = proxies[uint32_t(order)];
    const uint32_t u = P.user;
    batch.clear();
    size_t visited = 0;
    auto visit = [&](int32_t, uint32_t uq) {
      ++visited;
      if (uq > u) batch.push_back(uq);
    };
    trees[kDynamicTree].query(P.fat, visit);
    if (!P.isStatic) trees[kStaticTree].query(P.fat, visit);
    if (fresh.size() < maxPairs) {
      std::sort(batch.begin(), batch.end());
      const size_t take = std::min(batch.size(), maxPairs - fresh.size());
      for (size_t i = 0; i < take; ++i) fresh.push_back({u, batch[i]});
      left += batch.size() - take;
    } else {
      left += batch.size();
      budget -= std::min(budget, visited);
      if (budget == 0) break;
    }
  }
  pairs.swap(fresh);
  pairCount = pairs.size();
  return std::max<uint64_t>(left, 1);
}

// Kept old pairs (neither user dirty) merged with the sorted new ones, written both to the
// caller's vector and to the next pair list in the same pass. The kept ones are filtered
// without branches. `isDirty` is a bit test in the common case of small user
// values (shape indices): about 1% of the pairs need any work beyond a copy.
template <class IsDirty>
size_t mergeSorted(const ProxyPair* old, size_t nOld, const ProxyPair* fresh, size_t nNew,
                   ProxyPair* out, ProxyPair* copy, IsDirty isDirty) {
  // Pairs are sorted by a, so runs share it: test a once per run.
  uint32_t lastA = 0;
  bool lastADirty = isDirty(0);
  size_t i = 0, n = 0;
  for (size_t j = 0; j <= nNew; ++j) {
    // Old pairs below the next new one; the last round (j == nNew) takes the rest (no key
    // reaches UINT64_MAX since a < b).
    const uint64_t k = j < nNew ? keyOf(fresh[j]) : UINT64_MAX;
    for (; i < nOld && keyOf(old[i]) < k; ++i) {
      const ProxyPair p = old[i];
      if (p.a != lastA) {
        lastA = p.a;
        lastADirty = isDirty(p.a);
      }
      // Written always, kept by advancing n (the caller leaves one slot spare).
      out[n] = p;
      copy[n] = p;
      n += !(lastADirty | isDirty(p.b));
    }
    if (j < nNew) {
      out[n] = fresh[j];
      copy[n] = fresh[j];
      ++n;
    }
  }
  return n;
}

void BroadPhase::Impl::mergePairs(std::vector<ProxyPair>* result) {
  const size_t nOld = pairCount, nNew = fresh.size();
  if (pairsBack.size() < nOld + nNew + 1) pairsBack.resize(nOld + nNew + 1);
  result->resize(nOld + nNew + 1);  // usually no-op sized: the caller's vector is reused
  size_t n;
  if (maxUser < kDirectUserBits) {
    // One bit per user value; set for this call only, so clearing is as cheap as setting.
    const size_t words = maxUser / 64 + 1;
    if (userBits.size() < words) userBits.resize(words, 0);
    uint64_t* bits = userBits.data();
    for (uint32_t u : dirtyUsers) bits[u >> 6] |= uint64_t(1) << (u & 63);
    n = mergeSorted(pairs.data(), nOld, fresh.data(), nNew, result->data(), pairsBack.data(),
                    [bits](uint32_t u) { return ((bits[u >> 6] >> (u & 63)) & 1) != 0; });
    for (uint32_t u : dirtyUsers) bits[u >> 6] = 0;
  } else {
    // Large user values: a hashed bitmap filters, a binary search confirms.
    std::sort(dirtyUsers.begin(), dirtyUsers.end());
    dirtyUsers.erase(std::unique(dirtyUsers.begin(), dirtyUsers.end()), dirtyUsers.end());
    int log2Bits = 12;
    while ((size_t(1) << log2Bits) < 64 * dirtyUsers.size() && log2Bits < 26) ++log2Bits;
    const int shift = 32 - log2Bits;
    userBits.assign((size_t(1) << log2Bits) / 64, 0);
    uint64_t* bits = userBits.data();
    for (uint32_t u : dirtyUsers) {
      const uint32_t h = (u * 0x9E3779B1u) >> shift;  // Fibonacci hashing
      bits[h >> 6] |= uint64_t(1) << (h & 63);
    }
    const uint32_t* users = dirtyUsers.data();
    const size_t userCount = dirtyUsers.size();
    auto isDirty = [=](uint32_t u) {
      const uint32_t h = (u * 0x9E3779B1u) >> shift;
      return ((bits[h >> 6] >> (h & 63)) & 1) != 0 &&
             std::binary_search(users, users + userCount, u);
    };
    n = mergeSorted(pairs.data(), nOld, fresh.data(), nNew, result->data(), pairsBack.data(),
                    isDirty);
    userBits.assign(userBits.size(), 0);  // the direct path expects a clear bitmap
  }
  pairs.swap(pairsBack);
  pairCount = n;
  result->resize(n);
}

BroadPhase::BroadPhase() : impl_(std::make_unique<Impl>()) {}
BroadPhase::~BroadPhase() = default;
BroadPhase::BroadPhase(BroadPhase&&) noexcept = default;
BroadPhase& BroadPhase::operator=(BroadPhase&&) noexcept = default;

int32_t BroadPhase::createProxy(const AABB& tight, float fatMargin, uint32_t user, bool isStatic) {
  return createProxyWithFatBox(inflate(tight, fatMargin), user, isStatic);
}

int32_t BroadPhase::createProxyWithFatBox(const AABB& fat, uint32_t user, bool isStatic) {
  Impl& m = *impl_;
  int32_t p;
  if (m.freeProxy != kNull) {
    p = m.freeProxy;
    m.freeProxy = m.proxies[p].nextFree;
  } else {
    p = int32_t(m.proxies.size());
    m.proxies.push_back({});
    m.dirtyFlag.push_back(0);
  }
  m.proxies[p] = {fat, fat, user, kNull, kNull, kNull, isStatic, true};
  m.maxUser = std::max(m.maxUser, user);
  m.markDirty(p);
  ++m.count;
  m.addPending(p);
  return p;
}

void BroadPhase::destroyProxy(int32_t proxy) {
  Impl& m = *impl_;
  assert(proxy >= 0 && size_t(proxy) < m.proxies.size() && m.proxies[proxy].alive);
  Proxy& P = m.proxies[proxy];
  if (P.pending != kNull) {
    m.removePending(proxy);
  } else {
    m.treeOf(P).remove(P.leaf);
  }
  m.markDirty(proxy);  // records the user while the slot still holds it
  P.alive = false;
  P.leaf = kNull;
  P.nextFree = m.freeProxy;
  m.freeProxy = proxy;
  --m.count;
}

bool BroadPhase::moveProxy(int32_t proxy, const AABB& tight, float fatMargin) {
  Impl& m = *impl_;
  assert(proxy >= 0 && size_t(proxy) < m.proxies.size() && m.proxies[proxy].alive);
  Proxy& P = m.proxies[proxy];
  if (contains(P.fat, tight)) return false;
  P.fat = inflate(tight, fatMargin);
  m.markDirty(proxy);
  if (P.pending != kNull) return true;
  if (overlaps(P.fat, P.home)) {
    // A short move (the usual settling jiggle): keep the leaf where it is. The tree stays
    // good because the leaf is still next to where it was placed.
    m.treeOf(P).moveLeaf(P.leaf, P.fat);
  } else {
    // Moved away from its place: re-insert at the next flush (or rebuild, if many did).
    m.treeOf(P).remove(P.leaf);
    P.leaf = kNull;
    m.addPending(proxy);
  }
  return true;
}

void BroadPhase::setStatic(int32_t proxy, bool isStatic) {
  Impl& m = *impl_;
  assert(proxy >= 0 && size_t(proxy) < m.proxies.size() && m.proxies[proxy].alive);
  Proxy& P = m.proxies[proxy];
  if (P.isStatic == isStatic) return;
  m.markDirty(proxy);
  if (P.pending == kNull) {
    m.treeOf(P).remove(P.leaf);
    P.leaf = kNull;
    P.isStatic = isStatic;
    m.addPending(proxy);
  } else {
    P.isStatic = isStatic;
  }
}

const AABB& BroadPhase::fatAABB(int32_t proxy) const {
  assert(proxy >= 0 && size_t(proxy) < impl_->proxies.size() && impl_->proxies[proxy].alive);
  return impl_->proxies[proxy].fat;
}

void BroadPhase::computePairs(std::vector<ProxyPair>* out) {
  computePairs(out, SIZE_MAX);
}

uint64_t BroadPhase::computePairs(std::vector<ProxyPair>* out, size_t maxPairs) {
  Impl& m = *impl_;
  m.flushPending();
  // Nothing moved: the same list (complete, or cut at the same bound).
  if (!m.stale && m.dirty.empty() &&
      (m.truncated ? m.truncLimit == maxPairs : m.pairCount <= maxPairs)) {
    out->assign(m.pairs.begin(), m.pairs.begin() + ptrdiff_t(m.pairCount));
    return m.truncated ? m.dropped : 0;
  }
  // A cut list cannot be updated incrementally (pairs of clean proxies are missing from it):
  // the next list is found from scratch, and found cut again only when it is still over.
  const bool incremental =
      !m.stale && !m.truncated && m.pairCount <= maxPairs && 3 * m.dirty.size() < size_t(m.count);
  m.stale = true;  // until this call completes
  bool complete = false;
  // Per-proxy queries find each pair of two dirty proxies twice and pay a root-to-leaf
  // descent each; past about a third of the proxies one joint traversal is cheaper.
  if (incremental) {
    if (m.findNewPairs(maxPairs)) {
      m.mergePairs(out);
      complete = m.pairCount <= maxPairs;
    }
  } else if (m.findAllPairs(maxPairs)) {
    out->assign(m.pairs.begin(), m.pairs.begin() + ptrdiff_t(m.pairCount));
    complete = true;
  }
  m.dropped = 0;
  if (!complete) {
    m.dropped = m.findFirstPairs(maxPairs);
    out->assign(m.pairs.begin(), m.pairs.begin() + ptrdiff_t(m.pairCount));
  }
  for (int32_t p : m.dirty) m.dirtyFlag[p] = 0;
  m.dirty.clear();
  m.dirtyUsers.clear();
  m.truncated = !complete;
  m.truncLimit = maxPairs;
  m.stale = false;
  return m.dropped;
}

void BroadPhase::releaseScratch() noexcept {
  Impl& m = *impl_;
  std::vector<ProxyPair>().swap(m.pairsBack);
  std::vector<ProxyPair>().swap(m.fresh);
  std::vector<uint32_t>().swap(m.batch);
  std::vector<uint64_t>().swap(m.queryOrder);
  if (m.pairs.capacity() > m.pairCount) {
    try {
      std::vector<ProxyPair>(m.pairs.begin(), m.pairs.begin() + ptrdiff_t(m.pairCount))
          .swap(m.pairs);
    } catch (const std::bad_alloc&) {  // the list as it was: still right
    }
  }
}

size_t BroadPhase::scratchBytes() const {
  const Impl& m = *impl_;
  return (m.pairs.capacity() + m.pairsBack.capacity() + m.fresh.capacity()) * sizeof(ProxyPair) +
         m.batch.capacity() * sizeof(uint32_t) + m.queryOrder.capacity() * sizeof(uint64_t);
}

void BroadPhase::forgetPairs() {
  Impl& m = *impl_;
  m.stale = true;
  m.truncated = false;
  m.pairCount = 0;
  std::vector<ProxyPair>().swap(m.pairs);
  std::vector<ProxyPair>().swap(m.pairsBack);
  std::vector<ProxyPair>().swap(m.fresh);
  std::vector<uint32_t>().swap(m.batch);
}

void BroadPhase::queryImpl(const AABB& box, void (*cb)(void*, uint32_t), void* ctx) const {
  const Impl& m = *impl_;
  auto visit = [&](int32_t, uint32_t user) { cb(ctx, user); };
  m.trees[kDynamicTree].query(box, visit);
  m.trees[kStaticTree].query(box, visit);
  for (int32_t p : m.pending) {
    if (overlaps(m.proxies[p].fat, box)) cb(ctx, m.proxies[p].user);
  }
}

int BroadPhase::proxyCount() const {
  return impl_->count;
}

}  // namespace phys
