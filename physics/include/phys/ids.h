// Generational handles: an index into a pool plus the slot's generation when the handle was
// made. A handle whose generation no longer matches (the object was destroyed, the slot
// reused) is stale and is rejected, never dereferenced. The all-zero handle is null.
#pragma once

#include <cstdint>
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
