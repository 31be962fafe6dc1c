// Generational handles: an index into a pool plus the slot's generation when the handle was
// made. A handle whose generation no longer matches (the object was destroyed, the slot
// reused) is stale and is rejected, never dereferenced. The all-zero handle is null.
#pragma once

#include <cstddef>
#include <cstdint>
#include <utility>
#include <vector>

namespace phys {

template <class Tag>
struct Handle {
  uint32_t index = 0;
  uint32_t generation = 0;  ///< 0 only for the null handle; live slots start at 1
  constexpr bool isNull() const { return generation == 0; }
  /// Packed form used on the wire and in scene files: generation << 32 | index.
  constexpr uint64_t packed() const { return (uint64_t(generation) << 32) | index; }
  static constexpr Handle fromPacked(uint64_t v) { return {uint32_t(v), uint32_t(v >> 32)}; }
  friend constexpr bool operator==(Handle a, Handle b) {
    return a.index == b.index && a.generation == b.generation;
  }
  friend constexpr bool operator<(Handle a, Handle b) { return a.packed() < b.packed(); }
};

struct BodyTag {};
struct ShapeTag {};
struct JointTag {};
using BodyId = Handle<BodyTag>;
using ShapeId = Handle<ShapeTag>;
using JointId = Handle<JointTag>;

/// Slot pool with a free list. Indices of live objects are stable; iteration is in index
/// order, which keeps everything that walks a pool deterministic.
template <class T, class Tag>
class Pool {
 public:
  using Id = Handle<Tag>;

  Id add(T value) {
    uint32_t index;
    if (!free_.empty()) {
      index = free_.back();
      free_.pop_back();
    } else {
      index = uint32_t(slots_.size());
      slots_.push_back({});
    }
    Slot& s = slots_[index];
    s.value = std::move(value);
    s.alive = true;
    ++live_;
    return {index, s.generation};
  }
  bool remove(Id id) {
    if (!valid(id)) return false;
    Slot& s = slots_[id.index];
    s.alive = false;
    s.value = T{};
    ++s.generation;
    if (s.generation == 0) s.generation = 1;  // wrap-around: never hand out generation 0
    free_.push_back(id.index);
    --live_;
    return true;
  }
  bool valid(Id id) const {
    return id.generation != 0 && id.index < slots_.size() && slots_[id.index].alive &&
           slots_[id.index].generation == id.generation;
  }
  T* get(Id id) { return valid(id) ? &slots_[id.index].value : nullptr; }
  const T* get(Id id) const { return valid(id) ? &slots_[id.index].value : nullptr; }

  /// Slot access by raw index, for internal loops; check alive(i) first.
  uint32_t capacity() const { return uint32_t(slots_.size()); }
  bool alive(uint32_t i) const { return slots_[i].alive; }
  T& at(uint32_t i) { return slots_[i].value; }
  const T& at(uint32_t i) const { return slots_[i].value; }
  Id idAt(uint32_t i) const { return {i, slots_[i].generation}; }
  uint32_t size() const { return live_; }
  void clear() {
    slots_.clear();
    free_.clear();
    live_ = 0;
  }

  // Snapshot support (World::saveSnapshot / restoreSnapshot): the exact slot layout, so ids
  // handed out after a restore are the ones the saved world would have handed out.
  uint32_t generationAt(uint32_t i) const { return slots_[i].generation; }
  /// Free slot indices; the next add takes the back one.
  const std::vector<uint32_t>& freeList() const { return free_; }
  /// Replaces the whole pool: slot i gets generations[i], alive[i] and (if alive) values[i];
  /// dead slots hold T{}. Returns false and changes nothing unless the three sizes agree,
  /// every generation is nonzero and freeList names every dead slot exactly once.
  bool assign(std::vector<T> values, const std::vector<uint32_t>& generations,
              const std::vector<uint8_t>& alive, std::vector<uint32_t> freeList) {
    const size_t n = values.size();
    if (generations.size() != n || alive.size() != n) return false;
    size_t dead = 0;
    for (size_t i = 0; i < n; ++i) {
      if (generations[i] == 0) return false;
      dead += alive[i] ? 0 : 1;
    }
    if (freeList.size() != dead) return false;
    std::vector<uint8_t> listed(n, 0);
    for (uint32_t i : freeList) {
      if (i >= n || alive[i] || listed[i]) return false;
      listed[i] = 1;
    }
    std::vector<Slot> slots(n);
    for (size_t i = 0; i < n; ++i) {
      slots[i].generation = generations[i];
      slots[i].alive = alive[i] != 0;
      if (slots[i].alive) slots[i].value = std::move(values[i]);
    }
    slots_ = std::move(slots);
    free_ = std::move(freeList);
    live_ = uint32_t(n - dead);
    return true;
  }

 private:
  struct Slot {
    T value{};
    uint32_t generation = 1;
    bool alive = false;
  };
  std::vector<Slot> slots_;
  std::vector<uint32_t> free_;
  uint32_t live_ = 0;
};

}  // namespace phys
