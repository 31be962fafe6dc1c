#pragma once
// Bounds of time and memory in tests, widened under a sanitizer. ThreadSanitizer runs code
// 5-15 times slower and keeps shadow memory beside every byte the program touches
// (AddressSanitizer less so); a test that checks "answered within 1 s" or "grew less than
// 100 MiB" checks that a cost is bounded, and a wider bound still tells bounded from
// unbounded there.

namespace phys::test {

#if defined(__SANITIZE_THREAD__) || defined(__SANITIZE_ADDRESS__)
/// A sanitizer's allocator stands in for glibc's (so mallinfo2 reports nothing, for one).
inline constexpr bool kSanitized = true;
inline constexpr double kTimeFactor = 10;      ///< times a wall-clock bound
inline constexpr long long kMemoryFactor = 4;  ///< times a resident-memory bound
#else
inline constexpr bool kSanitized = false;
inline constexpr double kTimeFactor = 1;
inline constexpr long long kMemoryFactor = 1;
#endif

}  // namespace phys::test
