#version 450
// Finalize (bodies): the step's displacement and orientation into the body states.
#extension GL_GOOGLE_include_directive : require
#extension GL_ARB_gpu_shader_fp64 : require
#include "shared.h"
#include "common.glsl"
layout(local_size_x = PHYS_GPU_GROUP) in;
layout(std430, binding = 0) buffer States { GpuBodyState states[]; };
layout(std430, binding = 1) readonly buffer Solver { GpuSolverBody bodies[]; };
layout(push_constant) uniform Push { GpuStepConstants k; };

void main() {
  uint i = globalIndex();
  if (i >= k.bodyCount) return;
  GpuSolverBody b = bodies[i];
  states[i].com.xyz += b.dp.xyz;
  states[i].q = b.q;
  states[i].v = b.v;
  states[i].w = b.w;
}
