#version 450
// One compare-and-exchange pass of a bitonic sort of (key, value) pairs, ascending by key
// then value: a total order, so the result is the same whatever the device's scheduling.
// The host dispatches it for k = 2, 4, .., n and j = k/2, .., 1 (n a power of two, the tail
// padded with (~0u, ~0u)).
#extension GL_GOOGLE_include_directive : require
#extension GL_ARB_gpu_shader_fp64 : require
#include "shared.h"
#include "common.glsl"
layout(local_size_x = PHYS_GPU_GROUP) in;
layout(std430, binding = 0) buffer Keys { uvec2 keys[]; };
layout(push_constant) uniform Push { GpuSortConstants c; };

void main() {
  uint i = globalIndex();
  if (i >= c.n) return;
  uint l = i ^ c.j;
  if (l <= i) return;
  uvec2 a = keys[i], b = keys[l];
  bool ascending = (i & c.k) == 0u;
  bool greater = a.x > b.x || (a.x == b.x && a.y > b.y);
  if (greater == ascending) {
    keys[i] = b;
    keys[l] = a;
  }
}
