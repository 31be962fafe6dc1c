#version 450
// The touch list, first pass: 1 for each manifold slot that is a touch (touch_list.glsl),
// else 0; the prefix sum of these is each touch's place in the list.
#extension GL_GOOGLE_include_directive : require
#extension GL_ARB_gpu_shader_fp64 : require
#include "shared.h"
#include "common.glsl"
layout(local_size_x = PHYS_GPU_GROUP) in;
layout(std430, binding = 0) readonly buffer Manifolds { GpuManifold manifolds[]; };
layout(std430, binding = 1) readonly buffer Shapes { GpuShape shapes[]; };
layout(std430, binding = 2) readonly buffer Counters { uint counters[]; };
layout(std430, binding = 3) writeonly buffer Flags { uint flags[]; };
layout(push_constant) uniform Push { GpuStepConstants k; };
#include "touch_list.glsl"

void main() {
  uint i = globalIndex();
  if (i >= k.pairCapacity) return;
  ivec2 pair;
  flags[i] = touching(i, pair) ? 1u : 0u;
}
