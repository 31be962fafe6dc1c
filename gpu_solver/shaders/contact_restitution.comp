#version 450
// Restitution (contacts, Jacobi, after the substeps): see contact.glsl.
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
  restituteContact(c, A, B, va, wa, vb, wb);
  contacts[i] = c;
  deltas[k.jointCount + i] = GpuDelta(vec4(va - A.v, 0), vec4(wa - A.w, 0), vec4(vb - B.v, 0), vec4(wb - B.w, 0));
}
