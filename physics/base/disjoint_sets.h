// Union-find over indices 0..n-1, for the islands the step finds (sleeping, direct contacts,
// restitution's energy limit). The root of a set is its lowest index, so the sets and their
// roots depend only on which pairs were joined, not on the order (deterministic); roots are
// found with path halving.
#pragma once

#include <algorithm>
#include <cstdint>
#include <numeric>
#include <vector>

namespace phys {

class DisjointSets {
 public:
  /// n singletons (the storage is kept between uses).
  void reset(size_t n) {
    parent_.resize(n);
    std::iota(parent_.begin(), parent_.end(), 0);
  }
  int32_t root(int32_t i) {
    while (parent_[size_t(i)] != i) i = parent_[size_t(i)] = parent_[size_t(parent_[size_t(i)])];
    return i;
  }
  void join(int32_t a, int32_t b) {
    a = root(a);
    b = root(b);
    if (a != b) parent_[size_t(std::max(a, b))] = std::min(a, b);
  }
  /// The storage back to the allocator; the next reset takes it again.
  void release() noexcept { std::vector<int32_t>().swap(parent_); }
  size_t capacityBytes() const { return parent_.capacity() * sizeof(int32_t); }

 private:
  std::vector<int32_t> parent_;
};

}  // namespace phys
