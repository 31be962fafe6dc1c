// The broad phase's candidate tests (PHYS_GPU_COUNTER_BP_TESTS), summed by the count pass of
// either method (bvh_count.comp, bp_count.comp), which declares `counters`.
#ifndef PHYS_GPU_BP_TESTS_GLSL
#define PHYS_GPU_BP_TESTS_GLSL

// Adds a workgroup's candidate tests to the 64-bit counter: the carry out of the low word
// goes to the high word (each wrap is seen by exactly one add).
shared uint groupTests[PHYS_GPU_GROUP];
void addGroupTests(uint tests, uint counterLo, uint counterHi) {
  groupTests[gl_LocalInvocationID.x] = tests;
  barrier();
  if (gl_LocalInvocationID.x == 0u) {
    uint sum = 0u;
    for (uint i = 0u; i < PHYS_GPU_GROUP; ++i) sum += groupTests[i];
    if (sum > 0u) {
      uint before = atomicAdd(counters[counterLo], sum);
      if (before + sum < before) atomicAdd(counters[counterHi], 1u);
    }
  }
}

#endif
