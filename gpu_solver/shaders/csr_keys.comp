#version 450
// Prepare, body references: each constraint (joints first, then the contacts with points)
// adds (body, constraint * 2 + side) for each of its dynamic bodies; sorted, these are every
// body's constraints in order, the order the CPU's Jacobi gathers them in
// (Solver::indexUnits: joints, then contacts).
#extension GL_GOOGLE_include_directive : require
#extension GL_ARB_gpu_shader_fp64 : require
#include "shared.h"
#include "common.glsl"
layout(local_size_x = PHYS_GPU_GROUP) in;
layout(std430, binding = 0) readonly buffer Manifolds { GpuManifold manifolds[]; };
layout(std430, binding = 1) readonly buffer Shapes { GpuShape shapes[]; };
layout(std430, binding = 2) readonly buffer Params { GpuBodyParams params[]; };
layout(std430, binding = 3) writeonly buffer Keys { uvec2 refKeys[]; };
layout(std430, binding = 4) readonly buffer Counters { uint counters[]; };
layout(std430, binding = 5) readonly buffer Joints { GpuJoint joints[]; };
layout(push_constant) uniform Push { GpuSolveConstants k; };

uvec2 ref(uint c, uint side, int b) {
  if (b < 0 || (params[b].flags.x & PHYS_GPU_BODY_DYNAMIC) == 0u) return uvec2(0xFFFFFFFFu);
  return uvec2(uint(b), c * 2u + side);
}

void main() {
  uint i = globalIndex();
  if (2u * i >= k.refCount) return;
  uvec2 a = uvec2(0xFFFFFFFFu), b = uvec2(0xFFFFFFFFu);
  if (i < k.jointCount) {
    a = ref(i, 0u, joints[i].bodyA);
    b = ref(i, 1u, joints[i].bodyB);
  } else {
    uint c = i - k.jointCount;
    if (c < counters[PHYS_GPU_COUNTER_PAIRS] && manifolds[c].count > 0u) {
      a = ref(i, 0u, shapes[manifolds[c].shapeA].body);
      b = ref(i, 1u, shapes[manifolds[c].shapeB].body);
    }
  }
  refKeys[2u * i] = a;
  refKeys[2u * i + 1u] = b;
}
