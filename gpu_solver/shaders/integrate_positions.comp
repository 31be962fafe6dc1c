#version 450
// IntegratePositions: the centre of mass by v h, the orientation by the free-rotation
// splitting of Dullweber, Leimkuhler and McLachlan for gyroscopic bodies (as
// Solver::integratePositions), else by the plain quaternion update.
#extension GL_GOOGLE_include_directive : require
#extension GL_ARB_gpu_shader_fp64 : require
#include "shared.h"
#include "common.glsl"
layout(local_size_x = PHYS_GPU_GROUP) in;
layout(std430, binding = 0) readonly buffer Params { GpuBodyParams params[]; };
layout(std430, binding = 1) buffer Solver { GpuSolverBody bodies[]; };
// The split push-out's pseudo velocities (body i: linear at 2i, angular at 2i + 1).
layout(std430, binding = 2) readonly buffer PushVelocities { vec4 pushVelocity[]; };
layout(push_constant) uniform Push { GpuStepConstants k; };

vec4 axisRotation(int i, float a) {
  vec4 r = vec4(0, 0, 0, cos(0.5 * a));
  r[i] = sin(0.5 * a);
  return r;
}

// Exact rotations about the principal axes, 1(h/2) 2(h/2) 3(h) 2(h/2) 1(h/2).
void rotateFree(inout vec4 q, inout vec3 w, vec4 principal, vec3 I, float h) {
  vec4 Q = quatMul(q, principal);
  vec3 L = I * quatInvRotate(Q, w);
  const int axes[5] = int[5](0, 1, 2, 1, 0);
  const float frac[5] = float[5](0.5, 0.5, 1.0, 0.5, 0.5);
  float L0 = length(L);
  for (int s = 0; s < 5; ++s) {
    int i = axes[s], j = (i + 1) % 3, m = (i + 2) % 3;
    float angle = frac[s] * h * L[i] / I[i];
    Q = quatMul(Q, axisRotation(i, angle));
    float c = cos(angle), sn = sin(angle);
    float Lj = c * L[j] + sn * L[m], Lm = -sn * L[j] + c * L[m];
    L[j] = Lj;
    L[m] = Lm;
  }
  float Ln = length(L);
  if (Ln > 0) L *= L0 / Ln;
  Q = quatNormalize(Q);
  q = quatNormalize(quatMul(Q, quatConj(principal)));
  w = quatRotate(Q, L / I);
}

void main() {
  uint i = globalIndex();
  if (i >= k.bodyCount) return;
  GpuBodyParams p = params[i];
  if ((p.flags.x & PHYS_GPU_BODY_ASLEEP) != 0u) return;  // held exactly where it fell asleep
  GpuSolverBody b = bodies[i];
  vec4 q0 = b.q;
  vec3 pv = vec3(0), pw = vec3(0);
  if (k.splitPushout != 0u) {
    pv = pushVelocity[2 * i].xyz;
    pw = pushVelocity[2 * i + 1].xyz;
  }
  vec3 w = b.w.xyz;
  if (pv != vec3(0) || pw != vec3(0)) {
    // Pushed out this substep: the pseudo velocity moves the body, the velocity stays
    // (plain rotation, as the CPU's Solver::integratePositions).
    b.dp.xyz += (b.v.xyz + pv) * k.h;
    b.q = integrateRotation(b.q, w + pw, k.h);
  } else if ((p.flags.x & PHYS_GPU_BODY_GYROSCOPIC) != 0u) {
    b.dp.xyz += b.v.xyz * k.h;
    rotateFree(b.q, w, p.principal, p.moments.xyz, k.h);
    b.w.xyz = w;
  } else {
    b.dp.xyz += b.v.xyz * k.h;
    b.q = integrateRotation(b.q, w, k.h);
  }
  b.dtheta.xyz += rotationVector(quatMul(b.q, quatConj(q0)));
  bodies[i] = b;
}
