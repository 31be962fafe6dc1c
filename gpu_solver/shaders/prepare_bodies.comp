#version 450
// Prepare (bodies): each body's solver state at the step's start: its velocity, zero
// displacement, its orientation and its world inverse inertia R I^-1 R^T.
#extension GL_GOOGLE_include_directive : require
#extension GL_ARB_gpu_shader_fp64 : require
#include "shared.h"
#include "common.glsl"
layout(local_size_x = PHYS_GPU_GROUP) in;
layout(std430, binding = 0) readonly buffer States { GpuBodyState states[]; };
layout(std430, binding = 1) readonly buffer Params { GpuBodyParams params[]; };
layout(std430, binding = 2) writeonly buffer Solver { GpuSolverBody bodies[]; };
layout(push_constant) uniform Push { GpuStepConstants k; };

void main() {
  uint i = globalIndex();
  if (i >= k.bodyCount) return;
  GpuBodyState s = states[i];
  GpuBodyParams p = params[i];
  GpuSolverBody b;
  b.v = s.v;
  b.w = s.w;
  b.dp = vec4(0);
  b.q = s.q;
  b.dtheta = vec4(0);
  mat3 invI = mat3(0);
  if ((p.flags.x & PHYS_GPU_BODY_DYNAMIC) != 0u) {
    mat3 R = quatToMat3(s.q);
    // The rows are stored: transpose to get GLSL's column-major local inverse inertia.
    mat3 local = transpose(mat3(p.invInertia[0].xyz, p.invInertia[1].xyz, p.invInertia[2].xyz));
    invI = R * local * transpose(R);
    // Joints' geometric stiffness (World::Impl::addGeometricStiffness): h^2 k on the
    // world inertia's diagonal, from last step's joint forces.
    float stiffness = p.localCenter.w;
    if (stiffness > 0) invI = inverse(inverse(invI) + mat3(k.h * k.h * stiffness));
  }
  mat3 rows = transpose(invI);
  b.invI[0] = vec4(rows[0], 0);
  b.invI[1] = vec4(rows[1], 0);
  b.invI[2] = vec4(rows[2], 0);
  bodies[i] = b;
}
