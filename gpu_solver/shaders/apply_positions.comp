#version 450
// After a Jacobi position pass: every dynamic body moves by the average of its contacts'
// displacements, summed in contact order (as apply_deltas.comp does for velocities).
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
  vec3 dp = vec3(0), dth = vec3(0);
  for (uint e = r.x; e < r.y; ++e) {
    uint ref = refKeys[e].y;
    GpuDelta d = deltas[ref >> 1];
    bool sideB = (ref & 1u) != 0u;
    dp += sideB ? d.dvB.xyz : d.dvA.xyz;
    dth += sideB ? d.dwB.xyz : d.dwA.xyz;
  }
  if (dp == vec3(0) && dth == vec3(0)) return;
  float split = uintBitsToFloat(r.z);
  dp /= split;
  dth /= split;
  bodies[i].dp.xyz += dp;
  bodies[i].dtheta.xyz += dth;
  bodies[i].q = integrateRotation(bodies[i].q, dth, 1.0);
}
