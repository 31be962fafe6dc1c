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

// sin and cos of a float angle as the C library's sinf and cosf give them: evaluated in
// double and rounded once to float (glibc's sinf/cosf do the same, so the results agree bit
// for bit but in rare halfway cases). A device's own sin and cos are approximations: the
// Vulkan spec allows an absolute error of 2^-11 and NVIDIA's are near 2^-21, which for a
// substep's rotation angle (1e-3 to 1e-1 rad) is a relative error of 1e-5 and more; with them
// free_flight's angular momentum drifted 1.19e-3 on an H200 (its bound 1e-3; the CPU 7.6e-4).
// Reduced by multiples of pi/2 (Cody-Waite, pi/2 in two parts: exact for |n| < 2^20), then
// Taylor series to the 13th power: truncation under 1e-13 for |r| <= pi/4.
void sinCosAsLibm(float a, out float sinA, out float cosA) {
  double x = double(a);
  double n = floor(x * 0.63661977236758134308lf + 0.5lf);  // 2 / pi
  double r = (x - n * 1.57079632673412561417lf) - n * 6.07710050650619224932e-11lf;
  double r2 = r * r;
  double sr = r + r * r2 * (-1.0lf / 6.0lf + r2 * (1.0lf / 120.0lf + r2 * (-1.0lf / 5040.0lf +
      r2 * (1.0lf / 362880.0lf + r2 * (-1.0lf / 39916800.0lf + r2 * (1.0lf / 6227020800.0lf))))));
  double cr = 1.0lf + r2 * (-0.5lf + r2 * (1.0lf / 24.0lf + r2 * (-1.0lf / 720.0lf +
      r2 * (1.0lf / 40320.0lf + r2 * (-1.0lf / 3628800.0lf + r2 * (1.0lf / 479001600.0lf -
      r2 / 87178291200.0lf))))));
  int quadrant = int(n) & 3;  // two's complement: -1 & 3 == 3
  double s = quadrant == 0 ? sr : quadrant == 1 ? cr : quadrant == 2 ? -sr : -cr;
  double c = quadrant == 0 ? cr : quadrant == 1 ? -sr : quadrant == 2 ? -cr : sr;
  sinA = float(s);
  cosA = float(c);
}
// IEEE float division and square root whatever the device's own (SPIR-V allows 2.5 ulp for
// division and 3 for sqrt; NVIDIA uses approximations): in double and rounded once, which is
// the correctly rounded float result (53 >= 2 * 24 + 2 bits).
float divExact(float a, float b) { return float(double(a) / double(b)); }
// phys::length: the float dot product in its order, then the square root.
float lengthExact(vec3 v) {
  precise float d = v.x * v.x + v.y * v.y + v.z * v.z;
  return float(sqrt(double(d)));
}

// quatMul and quatRotate (common.glsl) with no fused multiply-adds.
vec4 quatMulExact(vec4 a, vec4 b) {
  precise vec4 r = vec4(a.w * b.x + a.x * b.w + a.y * b.z - a.z * b.y,
                        a.w * b.y - a.x * b.z + a.y * b.w + a.z * b.x,
                        a.w * b.z + a.x * b.y - a.y * b.x + a.z * b.w,
                        a.w * b.w - a.x * b.x - a.y * b.y - a.z * b.z);
  return r;
}
vec3 crossExact(vec3 a, vec3 b) {
  precise vec3 r = vec3(a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x);
  return r;
}
vec3 quatRotateExact(vec4 q, vec3 v) {
  precise vec3 t = 2.0 * crossExact(q.xyz, v);
  precise vec3 r = v + q.w * t + crossExact(q.xyz, t);
  return r;
}

vec4 axisRotation(int i, float a) {
  float s, c;
  sinCosAsLibm(0.5 * a, s, c);
  vec4 r = vec4(0, 0, 0, c);
  r[i] = s;
  return r;
}

// Exact rotations about the principal axes, 1(h/2) 2(h/2) 3(h) 2(h/2) 1(h/2), with the
// CPU's arithmetic (Solver::integratePositions): libm's sin and cos, IEEE division and square
// root, and no fused multiply-adds (precise), so every device rounds as the CPU does.
void rotateFree(inout vec4 q, inout vec3 w, vec4 principal, vec3 I, float h) {
  precise vec4 Q = quatMulExact(q, principal);
  precise vec3 L = I * quatRotateExact(quatConj(Q), w);
  const int axes[5] = int[5](0, 1, 2, 1, 0);
  const float frac[5] = float[5](0.5, 0.5, 1.0, 0.5, 0.5);
  float L0 = lengthExact(L);
  for (int s = 0; s < 5; ++s) {
    int i = axes[s], j = (i + 1) % 3, m = (i + 2) % 3;
    precise float angle = divExact(frac[s] * h * L[i], I[i]);
    Q = quatMulExact(Q, axisRotation(i, angle));
    float c, sn;
    sinCosAsLibm(angle, sn, c);
    precise float Lj = c * L[j] + sn * L[m], Lm = -sn * L[j] + c * L[m];
    L[j] = Lj;
    L[m] = Lm;
  }
  float Ln = lengthExact(L);
  if (Ln > 0) L *= divExact(L0, Ln);
  Q = quatNormalize(Q);
  q = quatNormalize(quatMulExact(Q, quatConj(principal)));
  w = quatRotateExact(Q, vec3(divExact(L.x, I.x), divExact(L.y, I.y), divExact(L.z, I.z)));
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
