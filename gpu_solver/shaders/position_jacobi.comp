#version 450
// PositionPass, Jacobi (the seed paper's NJ): every contact's corrections from the same
// poses (contact.glsl's positionContact), written as displacements for
// apply_positions.comp, which moves each body by the average of its contacts'.
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
  vec3 dpA = vec3(0), dthA = vec3(0), dpB = vec3(0), dthB = vec3(0);
  positionContact(c, A, B, dpA, dthA, dpB, dthB);
  deltas[k.jointCount + i] = GpuDelta(vec4(dpA, 0), vec4(dthA, 0), vec4(dpB, 0), vec4(dthB, 0));
}
