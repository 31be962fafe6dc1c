#version 450
// NarrowPhase, statistics for the step's report: manifolds with points, points, and the
// deepest penetration. Integer sums and a max of non-negative float bits: the same result
// in any order.
#extension GL_GOOGLE_include_directive : require
#extension GL_ARB_gpu_shader_fp64 : require
#include "shared.h"
#include "common.glsl"
layout(local_size_x = PHYS_GPU_GROUP) in;
layout(std430, binding = 0) readonly buffer Manifolds { GpuManifold manifolds[]; };
layout(std430, binding = 1) buffer Counters { uint counters[]; };
layout(push_constant) uniform Push { GpuStepConstants k; };

void main() {
  uint i = globalIndex();
  if (i >= counters[PHYS_GPU_COUNTER_PAIRS]) return;
  uint n = manifolds[i].count;
  if (n == 0u) return;
  float deepest = 0;
  for (uint p = 0u; p < n; ++p) deepest = max(deepest, -manifolds[i].points[p].w);
  atomicAdd(counters[PHYS_GPU_COUNTER_CONTACTS], 1u);
  atomicAdd(counters[PHYS_GPU_COUNTER_POINTS], n);
  if (deepest > 0) atomicMax(counters[PHYS_GPU_COUNTER_DEEPEST], floatBitsToUint(deepest));
}
