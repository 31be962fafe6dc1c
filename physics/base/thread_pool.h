// A small fork-join pool for the step's parallel loops (the solver's colors and Jacobi
// batches, the per-body integrations). The calling thread takes part in every loop.
//
// Determinism does not depend on the pool: every parallel loop of the engine writes disjoint
// data (the bodies of one color, one slot per constraint, one body per index), and every sum
// is formed afterwards in a fixed order, so which thread ran which chunk never shows in a
// result. The same world gives bit-identical states with 1, 2 or 16 threads.
//
// Waiting: a step dispatches a few hundred loops a few microseconds apart, so workers spin
// briefly between loops, then sleep on a condition variable. The caller never waits for a
// worker that has not started on a loop (see work_).
#pragma once

#include <atomic>
#include <condition_variable>
#include <cstddef>
#include <cstdint>
#include <mutex>
#include <thread>
#include <type_traits>
#include <vector>

namespace phys {

class ThreadPool {
 public:
  /// `threads` in all, the caller included (1: every loop runs inline, no thread started).
  explicit ThreadPool(int threads);
  ~ThreadPool();
  ThreadPool(const ThreadPool&) = delete;
  ThreadPool& operator=(const ThreadPool&) = delete;

  int threads() const { return int(workers_.size()) + 1; }

  /// Calls fn(begin, end) over [0, count) in chunks of about `grain` items, on every thread,
  /// and returns when all are done. Loops of at most `grain` items run inline.
  template <class F>
  void parallelFor(size_t count, size_t grain, F&& fn) {
    if (count == 0) return;
    if (workers_.empty() || count <= grain) {
      fn(size_t(0), count);
      return;
    }
    using Fn = std::remove_reference_t<F>;
    run(count, grain, const_cast<void*>(static_cast<const void*>(&fn)),
        [](void* f, size_t b, size_t e) { (*static_cast<Fn*>(f))(b, e); });
  }

 private:
  using Invoke = void (*)(void*, size_t, size_t);
  void run(size_t count, size_t grain, void* ctx, Invoke invoke);
  /// Claims and runs chunks of the loop `work` names while any are left: first those of
  /// thread `self` (0 is the caller), then any.
  void runChunks(uint64_t work, int self);
  void workerLoop(int self);
  void stopWorkers();

  // The loop in flight, as one word: (loop number << 40 | chunks << 32 | claimed-chunk
  // bits). A chunk is claimed by a compare-and-swap on the whole word, so a worker that wakes
  // late can only claim chunks of the loop it saw, and only while that loop has chunks left:
  // the caller never waits for a thread that claimed nothing (on a busy machine a worker may
  // sleep through whole loops, and the caller then runs them alone).
  static constexpr int kLoopShift = 40, kChunksShift = 32;
  static constexpr size_t kMaxChunks = 32, kChunksPerThread = 2;
  static_assert(kMaxChunks <= kChunksShift, "the claimed-chunk bits end below the count");
  alignas(64) std::atomic<uint64_t> work_{0};
  alignas(64) std::atomic<size_t> done_{0};  ///< chunks finished in the current loop
  // The current loop's fields: written before work_ names the loop, stable until its last
  // chunk is done, read only by a thread holding a claimed chunk.
  void* ctx_ = nullptr;
  Invoke invoke_ = nullptr;
  size_t count_ = 0, chunk_ = 1;
  uint64_t loop_ = 0;

  std::vector<std::thread> workers_;
  std::atomic<int> sleepers_{0};
  std::atomic<bool> stop_{false};
  std::mutex sleepMutex_;
  std::condition_variable wake_;
};

/// Threads to use for `requested` (0: the machine's hardware threads, at most 8).
int resolveThreadCount(int requested);

}  // namespace phys
