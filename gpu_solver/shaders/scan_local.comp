#version 450
// Exclusive prefix sum, first level: each workgroup scans its PHYS_GPU_SCAN_GROUP values in
// shared memory (Hillis-Steele) and writes its total to sums[group]; scan_add.comp then adds
// the scanned totals of the groups before it. Integer sums: exact in any order.
#extension GL_GOOGLE_include_directive : require
#extension GL_ARB_gpu_shader_fp64 : require
#include "shared.h"
#include "common.glsl"
layout(local_size_x = PHYS_GPU_SCAN_GROUP) in;
layout(std430, binding = 0) buffer Data { uint data[]; };
layout(std430, binding = 1) writeonly buffer Sums { uint sums[]; };
layout(push_constant) uniform Push { GpuSortConstants c; };
shared uint tile[PHYS_GPU_SCAN_GROUP];

void main() {
  uint i = globalIndex(), t = gl_LocalInvocationID.x;
  uint x = i < c.n ? data[i] : 0u;
  tile[t] = x;
  barrier();
  for (uint d = 1u; d < PHYS_GPU_SCAN_GROUP; d <<= 1) {
    uint add = t >= d ? tile[t - d] : 0u;
    barrier();
    tile[t] += add;
    barrier();
  }
  if (i < c.n) data[i] = tile[t] - x;
  // (Workgroups past the data, from a 2D dispatch, write nothing.)
  if (t == PHYS_GPU_SCAN_GROUP - 1u && groupIndex() * PHYS_GPU_SCAN_GROUP < c.n)
    sums[groupIndex()] = tile[t];
}
