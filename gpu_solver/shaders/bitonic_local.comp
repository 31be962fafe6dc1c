#version 450
// The bitonic sort's passes whose compare distance j is below a workgroup's tile, in shared
// memory: each workgroup loads PHYS_GPU_SORT_TILE keys, runs the passes and stores them.
// c.k = 0: every pass for k = 2 .. tile (sorting each tile in the direction the global
// network gives it); else the passes j = tile/2 .. 1 of sequence length c.k. The same
// compare-exchange as bitonic_sort.comp, so the same network and the same result.
// A sort shorter than a tile (c.n < tile, c.k = 0) is one workgroup: the tile's tail is
// padded with (~0u, ~0u), which sorts last, and only the first c.n come back. The order is
// total, so the result is the one the global passes give, bit for bit, in one dispatch.
#extension GL_GOOGLE_include_directive : require
#extension GL_ARB_gpu_shader_fp64 : require
#include "shared.h"
#include "common.glsl"
layout(local_size_x = PHYS_GPU_SORT_TILE / 2) in;
layout(std430, binding = 0) buffer Keys { uvec2 keys[]; };
layout(push_constant) uniform Push { GpuSortConstants c; };
shared uvec2 tile[PHYS_GPU_SORT_TILE];

void exchange(uint k, uint j) {
  // Thread t handles the pair (i, i ^ j) with i the t-th index whose bit j is clear.
  uint t = gl_LocalInvocationID.x;
  uint i = (t / j) * 2u * j + (t % j);
  uint l = i + j;
  uint base = groupIndex() * PHYS_GPU_SORT_TILE;
  bool ascending = ((base + i) & k) == 0u;
  uvec2 a = tile[i], b = tile[l];
  bool greater = a.x > b.x || (a.x == b.x && a.y > b.y);
  if (greater == ascending) {
    tile[i] = b;
    tile[l] = a;
  }
}

void main() {
  uint base = groupIndex() * PHYS_GPU_SORT_TILE;
  if (base >= c.n) return;
  uint t = gl_LocalInvocationID.x;
  uint hi = t + PHYS_GPU_SORT_TILE / 2u;
  tile[t] = base + t < c.n ? keys[base + t] : uvec2(0xFFFFFFFFu);
  tile[hi] = base + hi < c.n ? keys[base + hi] : uvec2(0xFFFFFFFFu);
  barrier();
  if (c.k == 0u) {
    for (uint k = 2u; k <= PHYS_GPU_SORT_TILE; k <<= 1) {
      for (uint j = k >> 1; j > 0u; j >>= 1) {
        exchange(k, j);
        barrier();
      }
    }
  } else {
    for (uint j = PHYS_GPU_SORT_TILE / 2u; j > 0u; j >>= 1) {
      exchange(c.k, j);
      barrier();
    }
  }
  if (base + t < c.n) keys[base + t] = tile[t];
  if (base + hi < c.n) keys[base + hi] = tile[hi];
}
