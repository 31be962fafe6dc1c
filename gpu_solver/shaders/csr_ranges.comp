#version 450
// Prepare, body references: each body's range in the sorted references (two binary
// searches) and its mass split, the number of its contacts (at least 1).
#extension GL_GOOGLE_include_directive : require
#extension GL_ARB_gpu_shader_fp64 : require
#include "shared.h"
#include "common.glsl"
layout(local_size_x = PHYS_GPU_GROUP) in;
layout(std430, binding = 0) readonly buffer Keys { uvec2 refKeys[]; };
layout(std430, binding = 1) writeonly buffer Refs { uvec4 refs[]; };
layout(push_constant) uniform Push { GpuSolveConstants k; };

uint lowerBound(uint body) {
  uint lo = 0u, hi = k.refCount;
  while (lo < hi) {
    uint mid = (lo + hi) / 2u;
    if (refKeys[mid].x < body) lo = mid + 1u; else hi = mid;
  }
  return lo;
}

void main() {
  uint i = globalIndex();
  if (i >= k.bodyCount) return;
  uint begin = lowerBound(i), end = lowerBound(i + 1u);
  refs[i] = uvec4(begin, end, floatBitsToUint(float(max(end - begin, 1u))), 0u);
}
