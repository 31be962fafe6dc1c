#version 450
// After each Jacobi pass over the contacts: every dynamic body moves by the average of its
// contacts' velocity changes, summed in contact order (its sorted references), as the
// CPU's Solver::forEachGroup gathers them: the same sums for any device scheduling.
#extension GL_GOOGLE_include_directive : require
#extension GL_ARB_gpu_shader_fp64 : require
#include "shared.h"
#include "common.glsl"
layout(local_size_x = PHYS_GPU_GROUP) in;
layout(std430, binding = 0) buffer Bodies { GpuSolverBody bodies[]; };
layout(std430, binding = 1) readonly buffer Deltas { GpuDelta deltas[]; };
layout(std430, binding = 2) readonly buffer Keys { uvec2 refKeys[]; };
layout(std430, binding = 3) readonly buffer Refs { uvec4 refs[]; };
layout(push_constant) uniform Push { GpuSolveConstants k; };

void main() {
  uint i = globalIndex();
  if (i >= k.bodyCount) return;
  uvec4 r = refs[i];
  if (r.x == r.y) return;
  vec3 dv = vec3(0), dw = vec3(0);
  for (uint e = r.x; e < r.y; ++e) {
    uint ref = refKeys[e].y;
    GpuDelta d = deltas[ref >> 1];
    bool sideB = (ref & 1u) != 0u;
    dv += sideB ? d.dvB.xyz : d.dvA.xyz;
    dw += sideB ? d.dwB.xyz : d.dwA.xyz;
  }
  float split = uintBitsToFloat(r.z);
  bodies[i].v.xyz += dv / split;
  bodies[i].w.xyz += dw / split;
}
