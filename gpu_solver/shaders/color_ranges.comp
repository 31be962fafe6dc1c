#version 450
// Colored Gauss-Seidel: each color's range in the sorted keys and its dispatch size (the
// overflow slot: one workgroup, whose first thread walks it in order).
#extension GL_GOOGLE_include_directive : require
#extension GL_ARB_gpu_shader_fp64 : require
#include "shared.h"
#include "common.glsl"
layout(local_size_x = PHYS_GPU_GROUP) in;
layout(std430, binding = 0) readonly buffer Keys { uvec2 colorKeys[]; };
layout(std430, binding = 1) writeonly buffer Ranges { uvec4 ranges[]; };
layout(std430, binding = 2) writeonly buffer Args { uint args[]; };
layout(push_constant) uniform Push { GpuSolveConstants k; };

uint lowerBound(uint color) {
  uint lo = 0u, hi = k.refCount / 2u;
  while (lo < hi) {
    uint mid = (lo + hi) / 2u;
    if (colorKeys[mid].x < color) lo = mid + 1u; else hi = mid;
  }
  return lo;
}

void main() {
  uint color = globalIndex();
  if (color > k.colorLimit) return;
  uint begin = lowerBound(color), end = lowerBound(color + 1u);
  ranges[color] = uvec4(begin, end, 0u, 0u);
  uint n = end - begin;
  uint groups = color == k.colorLimit ? min(n, 1u) : (n + PHYS_GPU_GROUP - 1u) / PHYS_GPU_GROUP;
  args[3u * color] = groups;
  args[3u * color + 1u] = 1u;
  args[3u * color + 2u] = 1u;
}
