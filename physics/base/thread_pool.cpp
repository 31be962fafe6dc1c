#include "base/thread_pool.h"

#include <algorithm>
#include <bit>

#if defined(__x86_64__) || defined(__i386__)
#include <immintrin.h>
#define PHYS_CPU_PAUSE() _mm_pause()
#else
#define PHYS_CPU_PAUSE() ((void)0)
#endif

namespace phys {

namespace {
// Spin this many pause instructions (a hundred microseconds or so) before sleeping. The loops
// of one step are a few microseconds apart; a sleeping worker costs a wake-up at the next
// loop. Yielding in between was tried: on this VM sched_yield is a costly exit and did not
// help.
constexpr int kSpins = 4000;
}  // namespace

int resolveThreadCount(int requested) {
  if (requested > 0) return requested;
  unsigned hw = std::thread::hardware_concurrency();
  return int(std::clamp(hw, 1u, 8u));
}

ThreadPool::ThreadPool(int threads) {
  try {
    for (int i = 1; i < threads; ++i) workers_.emplace_back([this, i] { workerLoop(i); });
  } catch (...) {
    stopWorkers();  // a thread that failed to start: join the others, then report it
    throw;
  }
}

ThreadPool::~ThreadPool() {
  stopWorkers();
}

void ThreadPool::stopWorkers() {
  {
    std::lock_guard<std::mutex> lock(sleepMutex_);
    stop_.store(true);
  }
  wake_.notify_all();
  for (std::thread& t : workers_) t.join();
  workers_.clear();
}

void ThreadPool::run(size_t count, size_t grain, void* ctx, Invoke invoke) {
  // kChunksPerThread chunks per thread: thread t first takes its own contiguous share, so a
  // thread solves the same constraints and bodies in every pass and they stay in its cache
  // (moving cache lines between the two cores of this VM costs more than it saves), then
  // helps with what is left, so a slow or late thread does not hold the loop.
  const size_t threads = workers_.size() + 1;
  const size_t maxChunks = std::min<size_t>(kMaxChunks, kChunksPerThread * threads);
  const size_t chunk = std::max(grain, (count + maxChunks - 1) / maxChunks);
  const uint64_t chunks = (count + chunk - 1) / chunk;
  ctx_ = ctx;
  invoke_ = invoke;
  count_ = count;
  chunk_ = chunk;
  done_.store(0, std::memory_order_relaxed);
  ++loop_;
  const uint64_t work = (loop_ << kLoopShift) | (chunks << kChunksShift);
  // Sequentially consistent with the worker's sleepers_ increment: either the caller sees
  // the sleeper and wakes it (under the mutex, so the wake-up cannot fall between the
  // sleeper's check and its wait), or the sleeper sees the new loop.
  work_.store(work);
  if (sleepers_.load() > 0) {
    std::lock_guard<std::mutex> lock(sleepMutex_);
    wake_.notify_all();
  }
  runChunks(work, 0);
  for (int spin = 0; done_.load(std::memory_order_acquire) < chunks; ++spin) {
    if (spin < kSpins)
      PHYS_CPU_PAUSE();
    else
      std::this_thread::yield();
  }
}

void ThreadPool::runChunks(uint64_t work, int self) {
  const uint64_t chunks = (work >> kChunksShift) & 0xff;
  const uint64_t all = (uint64_t(1) << chunks) - 1;
  // Chunk c belongs to thread c * threads / chunks: contiguous shares in thread order.
  const uint64_t threads = workers_.size() + 1;
  uint64_t own = 0;
  for (uint64_t c = 0; c < chunks; ++c)
    if (c * threads / chunks == uint64_t(self)) own |= uint64_t(1) << c;
  for (uint64_t wanted : {own, all}) {
    uint64_t w = work_.load(std::memory_order_acquire);
    for (;;) {
      // Loop number and chunk count both: after 2^24 loops a number comes back, and a
      // stalled worker must then not apply this loop's chunk count to another loop.
      if ((w >> kChunksShift) != (work >> kChunksShift)) return;
      const uint64_t free = ~w & all & wanted;
      if (free == 0) break;
      const uint64_t bit = free & (~free + 1);  // lowest free chunk
      if (!work_.compare_exchange_weak(w, w | bit, std::memory_order_acq_rel,
                                       std::memory_order_acquire))
        continue;
      // This chunk is ours: the loop cannot finish, nor its fields change, before it is done.
      const size_t begin = size_t(std::countr_zero(bit)) * chunk_;
      invoke_(ctx_, begin, std::min(begin + chunk_, count_));
      done_.fetch_add(1, std::memory_order_release);
      w = work_.load(std::memory_order_acquire);
    }
  }
}

void ThreadPool::workerLoop(int self) {
  uint64_t seen = 0;  // the last loop this worker looked at
  auto newLoop = [&] { return (work_.load() >> kLoopShift) != (seen >> kLoopShift); };
  for (;;) {
    bool fresh = newLoop();
    for (int spin = 0; !fresh && spin < kSpins; ++spin) {
      PHYS_CPU_PAUSE();
      fresh = newLoop();
    }
    if (!fresh) {
      // A condition variable, not std::atomic::wait: libstdc++ 12's atomic wait was seen
      // to lose wake-ups.
      std::unique_lock<std::mutex> lock(sleepMutex_);
      sleepers_.fetch_add(1);
      wake_.wait(lock, [&] { return stop_.load() || newLoop(); });
      sleepers_.fetch_sub(1);
    }
    if (stop_.load()) return;
    seen = work_.load(std::memory_order_acquire);
    runChunks(seen, self);
  }
}

}  // namespace phys
