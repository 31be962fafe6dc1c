#version 450
// BroadPhase (tree), 1: the bounds of the non-plane shapes' box centres, which the Morton
// codes quantize (bvh_keys.comp). On the device, so no step reads the states back for it:
// each workgroup reduces its shapes in shared memory, then takes the minimum of its minima
// into scene[0..2] and of its complemented maxima into scene[4..6] (all as ordered uints:
// minima commute, so the result is the same in any order). The host fills scene with ~0.
#extension GL_GOOGLE_include_directive : require
#extension GL_ARB_gpu_shader_fp64 : require
#include "shared.h"
#include "common.glsl"
layout(local_size_x = PHYS_GPU_GROUP) in;
layout(std430, binding = 0) readonly buffer Bounds { GpuAabb bounds[]; };
layout(std430, binding = 1) readonly buffer Shapes { GpuShape shapes[]; };
layout(std430, binding = 2) buffer Scene { uint scene[]; };
layout(push_constant) uniform Push { GpuStepConstants k; };
#include "bvh.glsl"
shared uint groupLo[3], groupHi[3];

void main() {
  uint i = globalIndex(), t = gl_LocalInvocationID.x;
  if (t < 3u) {
    groupLo[t] = 0xFFFFFFFFu;
    groupHi[t] = 0xFFFFFFFFu;
  }
  barrier();
  if (i < k.shapeCount && shapes[i].type != PHYS_GPU_SHAPE_PLANE) {
    vec3 c = 0.5 * (bounds[i].lo.xyz + bounds[i].hi.xyz);
    // A body gone to NaN or infinity is left out (its code is 0): it must not stretch the
    // quantization of every other shape.
    if (bvhFinite(c)) {
      for (uint a = 0u; a < 3u; ++a) {
        atomicMin(groupLo[a], bvhOrdered(c[a]));
        atomicMin(groupHi[a], ~bvhOrdered(c[a]));
      }
    }
  }
  barrier();
  if (t < 3u && groupLo[t] != 0xFFFFFFFFu) {
    atomicMin(scene[t], groupLo[t]);
    atomicMin(scene[4u + t], groupHi[t]);
  }
}
