#version 450
// Restitution (after the substeps): points that approached faster than the threshold and
// carried load bounce with e times their approach speed (Solver::restitutionGroup).
#extension GL_GOOGLE_include_directive : require
#extension GL_ARB_gpu_shader_fp64 : require
#include "shared.h"
#include "common.glsl"
layout(local_size_x = PHYS_GPU_GROUP) in;
#include "contact_bindings.glsl"
#include "contact.glsl"

void main() {
  uint i = globalIndex();
  if (i >= counters[PHYS_GPU_COUNTER_PAIRS]) return;
  GpuContact c = contacts[i];
  if (c.count == 0u) return;
  Side A = loadSide(c.bodyA), B = loadSide(c.bodyB);
  vec3 va = A.v, wa = A.w, vb = B.v, wb = B.w;
  vec3 n = c.normal.xyz;
  float e = c.normal.w;
  for (uint p = 0u; p < c.count && e != 0; ++p) {
    float approach = c.rB[p].w;
    if (approach > -k.restitutionThreshold || c.maxLambdaN[p] == 0) continue;
    vec3 rA = c.rA[p].xyz, rB = c.rB[p].xyz;
    float vn = rowVelocity(n, rA, rB, va, wa, vb, wb);
    float impulse = -c.massN[p] * (vn + e * approach);
    float next = max(c.lambdaN[p] + impulse, 0.0);
    impulse = next - c.lambdaN[p];
    c.lambdaN[p] = next;
    c.maxLambdaN[p] = max(c.maxLambdaN[p], next);
    if (impulse != 0) applyRow(impulse, n, rA, rB, A, B, va, wa, vb, wb);
  }
  contacts[i].lambdaN = c.lambdaN;
  contacts[i].maxLambdaN = c.maxLambdaN;
  deltas[i] = GpuDelta(vec4(va - A.v, 0), vec4(wa - A.w, 0), vec4(vb - B.v, 0), vec4(wb - B.w, 0));
}
