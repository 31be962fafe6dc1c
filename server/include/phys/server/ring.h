// What the tick thread hands to the publisher thread: a small drop-oldest ring of state
// frames (a stalled publisher never blocks simulation) and a reliable queue of replies,
// world descriptions and status samples (never dropped). No DDS here.
#pragma once

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <map>
#include <mutex>
#include <optional>
#include <vector>

namespace phys::server {

using Bytes = std::vector<uint8_t>;

/// A bounded FIFO that drops its oldest element when full. Not thread-safe by itself.
template <class T>
class DropOldestRing {
 public:
  explicit DropOldestRing(size_t capacity) : capacity_(capacity < 1 ? 1 : capacity) {}
  /// Appends v; returns whether an older element was dropped to make room.
  bool push(T v) {
    bool dropped = false;
    if (items_.size() >= capacity_) {
      items_.pop_front();
      ++dropped_;
      dropped = true;
    }
    items_.push_back(std::move(v));
    return dropped;
  }
  std::optional<T> pop() {
    if (items_.empty()) return std::nullopt;
    T v = std::move(items_.front());
    items_.pop_front();
    return v;
  }
  size_t size() const { return items_.size(); }
  bool empty() const { return items_.empty(); }
  bool full() const { return items_.size() >= capacity_; }
  const T& front() const { return items_.front(); }  ///< the next to go; not when empty
  size_t capacity() const { return capacity_; }
  uint64_t dropped() const { return dropped_; }

 private:
  size_t capacity_;
  std::deque<T> items_;
  uint64_t dropped_ = 0;
};

/// One tick of one world: its state chunks (protocol::encodeStateFrames), keyed by index.
/// A stream of state frames: a world's own (interest 0) or one of its interests'. The key
/// every per-stream map uses (subscriber counts, writers, dropped frames).
inline uint64_t streamKey(uint32_t world, uint32_t interest) {
  return uint64_t(world) << 32 | interest;
}

struct StateFrameSet {
  uint32_t world = 0;
  uint64_t tick = 0;
  std::vector<Bytes> chunks;
  uint32_t interest = 0;  ///< 0: the world's stream; else an interest's (Subscribe)
};

/// A message that must not be dropped.
struct ReliableMessage {
  enum class Type : uint8_t {
    Reply,         ///< phys/reply, key = client id
    WorldInfo,     ///< phys/world_info, one sample per chunk (chunks), key worldInfoKey
    WorldRemoved,  ///< dispose the world's world_info instances, drop its state writer
    Status,        ///< phys/status, key = server id
    Event,         ///< phys/events, key = world id
    InterestAdded,    ///< make phys/state/<world>/<key>'s writer (its readers are counted)
    InterestRemoved,  ///< drop it
    Handoff,          ///< phys/peer, key = the daemon it is for, one payload (chunks)
    WorldAdded,       ///< a world moved here: its info and frames go out again
  };
  Type type = Type::Reply;
  uint64_t key = 0;  ///< Reply: client id; Status: server id; Event: world id
  uint64_t seq = 0;  ///< Reply: the command's seq
  uint32_t world = 0;
  std::vector<Bytes> chunks;  ///< one payload (Reply, Status) or the world info chunks
};

/// Tick thread -> publisher thread. Thread-safe. Reliable messages come out before frames.
class PublishQueue {
 public:
  explicit PublishQueue(size_t frameCapacity = 4) : frames_(frameCapacity) {}

  void pushFrame(StateFrameSet f) {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (frames_.full()) ++droppedByStream_[streamKey(frames_.front().world, frames_.front().interest)];
      frames_.push(std::move(f));
    }
    cv_.notify_one();
  }
  void pushReliable(ReliableMessage m) {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      reliable_.push_back(std::move(m));
    }
    cv_.notify_one();
  }

  struct Item {
    std::optional<ReliableMessage> reliable;
    std::optional<StateFrameSet> frame;
  };
  /// Waits up to timeout for something; empty Item on timeout or close.
  template <class Rep, class Period>
  Item pop(std::chrono::duration<Rep, Period> timeout) {
    std::unique_lock<std::mutex> lock(mutex_);
    cv_.wait_for(lock, timeout, [&] { return closed_ || !reliable_.empty() || !frames_.empty(); });
    Item item;
    if (!reliable_.empty()) {
      item.reliable = std::move(reliable_.front());
      reliable_.pop_front();
    } else if (auto f = frames_.pop()) {
      item.frame = std::move(f);
    }
    return item;
  }
  void close() {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      closed_ = true;
    }
    cv_.notify_all();
  }
  bool closed() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return closed_;
  }
  uint64_t framesDropped() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return frames_.dropped();
  }
  /// Frames of one stream (a world's, or one of its interests') dropped so far: a gap in its
  /// chain of deltas, repaired by a keyframe.
  uint64_t framesDropped(uint32_t world, uint32_t interest) const {
    std::lock_guard<std::mutex> lock(mutex_);
    auto it = droppedByStream_.find(streamKey(world, interest));
    return it == droppedByStream_.end() ? 0 : it->second;
  }
  size_t framesQueued() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return frames_.size();
  }
  size_t reliableQueued() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return reliable_.size();
  }

 private:
  std::map<uint64_t, uint64_t> droppedByStream_;
  mutable std::mutex mutex_;
  std::condition_variable cv_;
  DropOldestRing<StateFrameSet> frames_;
  std::deque<ReliableMessage> reliable_;
  bool closed_ = false;
};

}  // namespace phys::server
