#version 450
// BroadPhase, 3: each sorted position writes its pairs at its offset (the prefix sum of the
// counts), as (lower shape index, higher) sort keys; the last position writes the total.
#extension GL_GOOGLE_include_directive : require
#extension GL_ARB_gpu_shader_fp64 : require
#include "shared.h"
#include "common.glsl"
#include "broad_phase.glsl"
layout(local_size_x = PHYS_GPU_GROUP) in;
layout(std430, binding = 5) readonly buffer Offsets { uint offsets[]; };
layout(std430, binding = 6) writeonly buffer Pairs { uvec2 pairKeys[]; };
layout(std430, binding = 7) buffer Counters { uint counters[]; };

void main() {
  uint p = globalIndex();
  if (p >= k.shapeSortCount) return;
  uint s = keys[p].y;
  uint at = offsets[p];
  uint tests = 0u;  // counted by bp_count.comp
  if (s != 0xFFFFFFFFu) {
#define WRITE(t)                                                   \
  {                                                                \
    if (at < k.pairCapacity) pairKeys[at] = uvec2(min(s, t), max(s, t)); \
    ++at;                                                          \
  }
    FOR_EACH_PAIR(p, s, WRITE)
  }
  if (p == k.shapeSortCount - 1u) {
    counters[PHYS_GPU_COUNTER_PAIRS] = min(at, k.pairCapacity);
    counters[PHYS_GPU_COUNTER_OVERFLOW] = at > k.pairCapacity ? at - k.pairCapacity : 0u;
  }
}
