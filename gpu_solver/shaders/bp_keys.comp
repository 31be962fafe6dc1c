#version 450
// BroadPhase, 1: the sort keys, (low end of the bounds on the sweep axis as an ordered uint,
// shape index);
// planes and the padding sort last as (~0u, ~0u).
#extension GL_GOOGLE_include_directive : require
#extension GL_ARB_gpu_shader_fp64 : require
#include "shared.h"
#include "common.glsl"
layout(local_size_x = PHYS_GPU_GROUP) in;
layout(std430, binding = 0) readonly buffer Bounds { GpuAabb bounds[]; };
layout(std430, binding = 1) readonly buffer Shapes { GpuShape shapes[]; };
layout(std430, binding = 2) writeonly buffer Keys { uvec2 keys[]; };
layout(push_constant) uniform Push { GpuStepConstants k; };

// Float bits to a uint with the same order (negatives flipped entirely, positives' sign set).
uint orderedBits(float f) {
  uint u = floatBitsToUint(f);
  return (u & 0x80000000u) != 0u ? ~u : u | 0x80000000u;
}

void main() {
  uint i = globalIndex();
  if (i >= k.shapeSortCount) return;
  if (i >= k.shapeCount || shapes[i].type == PHYS_GPU_SHAPE_PLANE) {
    keys[i] = uvec2(0xFFFFFFFFu);
    return;
  }
  keys[i] = uvec2(orderedBits(bounds[i].lo[k.sweepAxis]), i);
}
