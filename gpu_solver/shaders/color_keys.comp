#version 450
// Colored Gauss-Seidel: sort keys (color, constraint) of the joints and the contacts with
// points. Colors at
// or past the limit, and contacts the rounds left uncolored, go to the overflow slot
// (colorLimit), which one thread solves in contact order.
#extension GL_GOOGLE_include_directive : require
#extension GL_ARB_gpu_shader_fp64 : require
#include "shared.h"
#include "common.glsl"
layout(local_size_x = PHYS_GPU_GROUP) in;
layout(std430, binding = 0) readonly buffer Colors { uint colors[]; };
layout(std430, binding = 1) writeonly buffer Keys { uvec2 colorKeys[]; };
layout(std430, binding = 2) buffer Counters { uint counters[]; };
layout(push_constant) uniform Push { GpuSolveConstants k; };

void main() {
  uint c = globalIndex();
  if (c >= k.refCount / 2u) return;  // the key sort's length: the pair capacity
  uint color =
      c < k.jointCount + counters[PHYS_GPU_COUNTER_PAIRS] ? colors[c] : PHYS_GPU_NO_COLOR;
  if (color == PHYS_GPU_NO_COLOR) {
    colorKeys[c] = uvec2(0xFFFFFFFFu);
    return;
  }
  if (color < PHYS_GPU_MAX_COLORS) atomicMax(counters[PHYS_GPU_COUNTER_COLORS], color + 1u);
  colorKeys[c] = uvec2(min(color, k.colorLimit), c);
}
