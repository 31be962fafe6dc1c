#version 450
// BroadPhase (tree), 5: how many pairs each sorted position has (bvh_query.glsl), and the
// candidate tests of the query in all (PHYS_GPU_COUNTER_BP_TESTS).
#extension GL_GOOGLE_include_directive : require
#extension GL_ARB_gpu_shader_fp64 : require
#include "shared.h"
#include "common.glsl"
#include "broad_phase.glsl"
layout(local_size_x = PHYS_GPU_GROUP) in;
layout(std430, binding = 5) writeonly buffer Counts { uint counts[]; };
layout(std430, binding = 7) buffer Counters { uint counters[]; };
#include "bvh_query.glsl"
#include "bp_tests.glsl"

void main() {
  uint p = globalIndex();
  uint tests = 0u;
  if (p < k.shapeSortCount) {
    uint n = 0u;
    if (p < bvhLeafCount()) {
      uint s = keys[p].y;
#define COUNT(t) ++n
      FOR_EACH_TREE_PAIR(p, s, COUNT)
    }
    counts[p] = n;
  }
  addGroupTests(tests, PHYS_GPU_COUNTER_BP_TESTS, PHYS_GPU_COUNTER_BP_TESTS_HI);
}
