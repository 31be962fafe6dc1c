#version 450
// The Jacobi passes over the joints (warm start, solve or relax, the position pass; nothing
// at restitution), on copies of their bodies, writing the changes as constraint `joint`'s
// deltas for apply_deltas.comp / apply_positions.comp (joint.glsl has the rows).
#extension GL_GOOGLE_include_directive : require
#extension GL_ARB_gpu_shader_fp64 : require
#include "shared.h"
#include "common.glsl"
layout(local_size_x = PHYS_GPU_GROUP) in;
layout(std430, binding = 0) readonly buffer Bodies { GpuSolverBody bodies[]; };
layout(std430, binding = 1) readonly buffer Params { GpuBodyParams params[]; };
layout(std430, binding = 2) readonly buffer Refs { uvec4 refs[]; };
layout(std430, binding = 3) readonly buffer Joints { GpuJoint joints[]; };
layout(std430, binding = 4) buffer Rows { GpuJointRows jointRows[]; };
layout(std430, binding = 5) writeonly buffer Deltas { GpuDelta deltas[]; };
layout(push_constant) uniform Push { GpuSolveConstants k; };
#include "contact.glsl"
#include "joint.glsl"

void main() {
  uint ji = globalIndex();
  if (ji >= k.jointCount) return;
  GpuJoint j = joints[ji];
  Side A = loadSide(j.bodyA), B = loadSide(j.bodyB);
  if (k.mode == PHYS_GPU_PASS_POSITION) {
    vec3 dpA = vec3(0), dthA = vec3(0), dpB = vec3(0), dthB = vec3(0);
    positionJoint(jointRows[ji], A, B, dpA, dthA, dpB, dthB);
    deltas[ji] = GpuDelta(vec4(dpA, 0), vec4(dthA, 0), vec4(dpB, 0), vec4(dthB, 0));
    return;
  }
  vec3 va = A.v, wa = A.w, vb = B.v, wb = B.w;
  if (k.mode == PHYS_GPU_PASS_WARM_START) {
    warmStartJoint(jointRows[ji], A, B, va, wa, vb, wb);
  } else if (k.mode == PHYS_GPU_PASS_SOLVE) {
    GpuJointRows J = jointRows[ji];
    solveJoint(J, A, B, k.useBias != 0u, va, wa, vb, wb);
    for (uint i = 0u; i < J.count; ++i) jointRows[ji].rows[i].angA.w = J.rows[i].angA.w;
  }
  deltas[ji] = GpuDelta(vec4(va - A.v, 0), vec4(wa - A.w, 0), vec4(vb - B.v, 0), vec4(wb - B.w, 0));
}
