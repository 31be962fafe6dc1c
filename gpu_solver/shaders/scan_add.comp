#version 450
// Exclusive prefix sum, second pass: each value gets the scanned total of the groups
// before its own (scan_local.comp).
#extension GL_GOOGLE_include_directive : require
#extension GL_ARB_gpu_shader_fp64 : require
#include "shared.h"
#include "common.glsl"
layout(local_size_x = PHYS_GPU_SCAN_GROUP) in;
layout(std430, binding = 0) buffer Data { uint data[]; };
layout(std430, binding = 1) readonly buffer Sums { uint sums[]; };
layout(push_constant) uniform Push { GpuSortConstants c; };

void main() {
  uint i = globalIndex();
  if (i < c.n) data[i] += sums[groupIndex()];
}
