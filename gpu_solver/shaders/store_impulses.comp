#version 450
// StoreImpulses: the step's contact impulses back into the manifolds, where next step's
// warm start finds them (match_contacts.comp).
#extension GL_GOOGLE_include_directive : require
#extension GL_ARB_gpu_shader_fp64 : require
#include "shared.h"
#include "common.glsl"
layout(local_size_x = PHYS_GPU_GROUP) in;
layout(std430, binding = 0) readonly buffer Contacts { GpuContact contacts[]; };
layout(std430, binding = 1) buffer Manifolds { GpuManifold manifolds[]; };
layout(std430, binding = 2) readonly buffer Counters { uint counters[]; };

void main() {
  uint i = globalIndex();
  if (i >= counters[PHYS_GPU_COUNTER_PAIRS] || manifolds[i].count == 0u) return;
  manifolds[i].normalImpulse = contacts[i].lambdaN;
  manifolds[i].tangentImpulse1 = contacts[i].lambdaT1;
  manifolds[i].tangentImpulse2 = contacts[i].lambdaT2;
}
