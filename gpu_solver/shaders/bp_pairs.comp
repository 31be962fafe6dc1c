#version 450
// BroadPhase, 4: the sorted pair keys as the pair list the narrow phase reads.
#extension GL_GOOGLE_include_directive : require
#extension GL_ARB_gpu_shader_fp64 : require
#include "shared.h"
#include "common.glsl"
layout(local_size_x = PHYS_GPU_GROUP) in;
layout(std430, binding = 0) readonly buffer Keys { uvec2 pairKeys[]; };
layout(std430, binding = 1) writeonly buffer Pairs { GpuPair pairs[]; };
layout(std430, binding = 2) readonly buffer Counters { uint counters[]; };
layout(push_constant) uniform Push { GpuStepConstants k; };

void main() {
  uint i = globalIndex();
  if (i >= counters[PHYS_GPU_COUNTER_PAIRS]) return;
  uvec2 key = pairKeys[i];
  pairs[i] = GpuPair(key.x, key.y, 0u, 0u);
}
