#version 450
// Solve / Relax (contacts, Jacobi): every contact from the same velocities, on copies of
// its two bodies with their masses split among their contacts (Tonge et al. 2012): the
// normal rows of its points in order, then each point's friction pair clamped to the
// Coulomb disc, exactly as Solver::solveGroup does for one group; the velocity changes go
// to apply_deltas.comp, which averages them per body.
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
  for (uint p = 0u; p < c.count; ++p) {
    vec3 rA = c.rA[p].xyz, rB = c.rB[p].xyz;
    float vn = rowVelocity(n, rA, rB, va, wa, vb, wb);
    float C = rowError(c.rA[p].w, n, rA, rB, A, B);
    float bias = 0, massScale = 1, impulseScale = 0;
    if (C > 0) {
      bias = C * k.invH;  // speculative: close exactly the gap this substep, no more
    } else if (k.useBias != 0u) {
      float slop = k.soft != 0u ? 0.0 : k.linearSlop;
      float Cs = min(0.0, C + slop);
      bias = max(k.biasRate * Cs, -k.maxPushout);
      massScale = k.massScale;
      impulseScale = k.impulseScale;
    }
    float impulse = -c.massN[p] * massScale * (vn + bias) - impulseScale * c.lambdaN[p];
    float next = max(c.lambdaN[p] + impulse, 0.0);
    impulse = next - c.lambdaN[p];
    c.lambdaN[p] = next;
    c.maxLambdaN[p] = max(c.maxLambdaN[p], next);
    if (impulse != 0) applyRow(impulse, n, rA, rB, A, B, va, wa, vb, wb);
  }
  for (uint p = 0u; p < c.count; ++p) {
    vec3 rA = c.rA[p].xyz, rB = c.rB[p].xyz;
    vec3 t1 = c.t1.xyz, t2 = c.t2.xyz;
    float l1 = c.lambdaT1[p] - c.massT1[p] * rowVelocity(t1, rA, rB, va, wa, vb, wb);
    float l2 = c.lambdaT2[p] - c.massT2[p] * rowVelocity(t2, rA, rB, va, wa, vb, wb);
    float bound = c.friction * c.lambdaN[p];
    float len2 = l1 * l1 + l2 * l2;
    if (len2 > bound * bound) {
      float s = len2 > 0 ? bound / sqrt(len2) : 0.0;
      l1 *= s;
      l2 *= s;
    }
    float d1 = l1 - c.lambdaT1[p], d2 = l2 - c.lambdaT2[p];
    c.lambdaT1[p] = l1;
    c.lambdaT2[p] = l2;
    if (d1 != 0) applyRow(d1, t1, rA, rB, A, B, va, wa, vb, wb);
    if (d2 != 0) applyRow(d2, t2, rA, rB, A, B, va, wa, vb, wb);
  }
  contacts[i].lambdaN = c.lambdaN;
  contacts[i].lambdaT1 = c.lambdaT1;
  contacts[i].lambdaT2 = c.lambdaT2;
  contacts[i].maxLambdaN = c.maxLambdaN;
  deltas[i] = GpuDelta(vec4(va - A.v, 0), vec4(wa - A.w, 0), vec4(vb - B.v, 0), vec4(wb - B.w, 0));
}
