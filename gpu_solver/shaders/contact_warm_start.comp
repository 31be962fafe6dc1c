#version 450
// WarmStart (contacts): each contact applies its accumulated impulses to copies of its two
// bodies and records the approach speed for restitution (Solver::warmStartGroup), writing
// the velocity changes for apply_deltas.comp.
#extension GL_GOOGLE_include_directive : require
#extension GL_ARB_gpu_shader_fp64 : require
#include "shared.h"
#include "common.glsl"
layout(local_size_x = PHYS_GPU_GROUP) in;
#include "contact_bindings.glsl"
#include "contact.glsl"

vec3 linearAccel(int b) {
  if (b < 0 || (params[b].flags.x & PHYS_GPU_BODY_DYNAMIC) == 0u) return vec3(0);
  return params[b].accel.xyz;
}

void main() {
  uint i = globalIndex();
  if (i >= counters[PHYS_GPU_COUNTER_PAIRS]) return;
  GpuContact c = contacts[i];
  if (c.count == 0u) return;
  Side A = loadSide(c.bodyA), B = loadSide(c.bodyB);
  vec3 va = A.v, wa = A.w, vb = B.v, wb = B.w;
  vec3 n = c.normal.xyz;
  for (uint p = 0u; p < c.count; ++p) {
    vec3 rA = c.rA[p].xyz, rB = c.rB[p].xyz;
    // The fastest approach seen at a substep's start; while apart, extrapolated to the
    // moment of contact with the bodies' constant accelerations.
    float vn = rowVelocity(n, rA, rB, va, wa, vb, wb);
    float C = rowError(c.rA[p].w, n, rA, rB, A, B);
    float an = dot(-n, linearAccel(c.bodyA)) + dot(n, linearAccel(c.bodyB));
    if (vn < 0 && C > 0 && an < 0) vn = -sqrt(vn * vn - 2 * an * C);
    c.rB[p].w = min(c.rB[p].w, vn);
    if (c.lambdaN[p] != 0) applyRow(c.lambdaN[p], n, rA, rB, A, B, va, wa, vb, wb);
  }
  for (uint p = 0u; p < c.count; ++p) {
    vec3 rA = c.rA[p].xyz, rB = c.rB[p].xyz;
    if (c.lambdaT1[p] != 0) applyRow(c.lambdaT1[p], c.t1.xyz, rA, rB, A, B, va, wa, vb, wb);
    if (c.lambdaT2[p] != 0) applyRow(c.lambdaT2[p], c.t2.xyz, rA, rB, A, B, va, wa, vb, wb);
  }
  for (uint p = 0u; p < c.count; ++p) contacts[i].rB[p].w = c.rB[p].w;
  deltas[i] = GpuDelta(vec4(va - A.v, 0), vec4(wa - A.w, 0), vec4(vb - B.v, 0), vec4(wb - B.w, 0));
}
