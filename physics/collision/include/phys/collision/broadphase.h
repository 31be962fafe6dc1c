// Broad phase: candidate pairs of shapes whose fat bounds overlap.
// Proxies keep a fat AABB (the tight box plus a margin) so a slowly moving shape does not
// touch the structure every step; a proxy is re-inserted only when its tight box leaves
// its fat box. Static proxies never pair with each other.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <type_traits>
#include <vector>

#include "phys/defs/math.h"

namespace phys {

struct ProxyPair {
  uint32_t a, b;  ///< user values of the two proxies, a < b
  friend bool operator==(ProxyPair x, ProxyPair y) { return x.a == y.a && x.b == y.b; }
  friend bool operator<(ProxyPair x, ProxyPair y) { return x.a != y.a ? x.a < y.a : x.b < y.b; }
};

class BroadPhase {
 public:
  BroadPhase();
  ~BroadPhase();
  BroadPhase(const BroadPhase&) = delete;
  BroadPhase& operator=(const BroadPhase&) = delete;
  /// Movable, so a world restored from a snapshot can build its broad phase aside and swap it
  /// in. A moved-from broad phase may only be destroyed or assigned to.
  BroadPhase(BroadPhase&&) noexcept;
  BroadPhase& operator=(BroadPhase&&) noexcept;

  /// Adds a proxy; `user` is the caller's id (unique among live proxies, e.g. a shape index).
  /// Returns the proxy index.
  int32_t createProxy(const AABB& tight, float fatMargin, uint32_t user, bool isStatic);
  /// Adds a proxy whose fat box is `fat` exactly (a snapshot's saved fat box). The pairs
  /// depend only on the live proxies' fat boxes and static flags, so proxies rebuilt with
  /// their saved fat boxes give the same pairs now and after any later sequence of calls.
  int32_t createProxyWithFatBox(const AABB& fat, uint32_t user, bool isStatic);
  void destroyProxy(int32_t proxy);
  /// Updates a proxy's tight box; re-fattens with fatMargin only if it left the fat box.
  /// Returns true when the fat box changed.
  bool moveProxy(int32_t proxy, const AABB& tight, float fatMargin);
  /// Changes whether a proxy is static (a body switched type).
  void setStatic(int32_t proxy, bool isStatic);
  const AABB& fatAABB(int32_t proxy) const;

  /// Every pair of proxies whose fat boxes overlap, excluding static-static pairs, as user
  /// values with a < b, sorted ascending and without duplicates. Deterministic.
  void computePairs(std::vector<ProxyPair>* out);
  /// The same list, but at most `maxPairs` of it: when more pairs overlap, the first
  /// `maxPairs` of the list (the smallest (a, b)), which again depend only on the live
  /// proxies' fat boxes and static flags. Production stops at the bound: the work and the
  /// memory are proportional to maxPairs plus the proxies, never to the pairs there are.
  /// Returns 0 when the list is complete; otherwise how many pairs were left out, at least
  /// 1 and counted only as far as a work budget of maxPairs allows (a lower bound). A list
  /// under the bound is exactly what computePairs(out) gives.
  uint64_t computePairs(std::vector<ProxyPair>* out, size_t maxPairs);
  /// Drops the pair list and its buffers (memory back after a failed step); the next
  /// computePairs finds every pair from scratch. The proxies stay.
  void forgetPairs();
  /// Gives back the pair search's scratch (new pairs, the merge's second buffer) and trims
  /// the pair list to its pairs; the list stays (World::Impl::releaseStepBuffers). The
  /// bytes those buffers hold: scratchBytes().
  void releaseScratch() noexcept;
  size_t scratchBytes() const;

  /// Calls visit(user) for every proxy whose fat box overlaps `box` (ray/region queries).
  template <class F>
  void query(const AABB& box, F&& visit) const;

  int proxyCount() const;

  struct Impl;

 private:
  std::unique_ptr<Impl> impl_;
  void queryImpl(const AABB& box, void (*cb)(void*, uint32_t), void* ctx) const;
};

template <class F>
void BroadPhase::query(const AABB& box, F&& visit) const {
  queryImpl(
      box, [](void* c, uint32_t user) { (*static_cast<std::remove_reference_t<F>*>(c))(user); },
      const_cast<void*>(static_cast<const void*>(&visit)));
}

}  // namespace phys
