#version 450
// The touch list, second pass: each touch at its place (the flags' prefix sum), after the
// list's length in touches[0].x.
#extension GL_GOOGLE_include_directive : require
#extension GL_ARB_gpu_shader_fp64 : require
#include "shared.h"
#include "common.glsl"
layout(local_size_x = PHYS_GPU_GROUP) in;
layout(std430, binding = 0) readonly buffer Manifolds { GpuManifold manifolds[]; };
layout(std430, binding = 1) readonly buffer Shapes { GpuShape shapes[]; };
layout(std430, binding = 2) readonly buffer Counters { uint counters[]; };
layout(std430, binding = 3) readonly buffer Offsets { uint offsets[]; };
layout(std430, binding = 4) writeonly buffer Touches { uvec2 touches[]; };
layout(push_constant) uniform Push { GpuStepConstants k; };
#include "touch_list.glsl"

void main() {
  uint i = globalIndex();
  if (i >= k.pairCapacity) return;
  ivec2 pair;
  bool touch = touching(i, pair);
  if (touch) touches[1u + offsets[i]] = uvec2(pair);
  if (i == k.pairCapacity - 1u) touches[0] = uvec2(offsets[i] + (touch ? 1u : 0u), 0u);
}
