#version 450
// IntegrateVelocities: gravity, applied force and torque, damping, speed caps (one substep).
#extension GL_GOOGLE_include_directive : require
#extension GL_ARB_gpu_shader_fp64 : require
#include "shared.h"
#include "common.glsl"
layout(local_size_x = PHYS_GPU_GROUP) in;
layout(std430, binding = 0) readonly buffer Params { GpuBodyParams params[]; };
layout(std430, binding = 1) buffer Solver { GpuSolverBody bodies[]; };
layout(push_constant) uniform Push { GpuStepConstants k; };

void main() {
  uint i = globalIndex();
  if (i >= k.bodyCount) return;
  GpuBodyParams p = params[i];
  if ((p.flags.x & PHYS_GPU_BODY_DYNAMIC) == 0u) return;
  GpuSolverBody b = bodies[i];
  float h = k.h;
  vec3 v = b.v.xyz + p.accel.xyz * h;
  mat3 invI = transpose(mat3(b.invI[0].xyz, b.invI[1].xyz, b.invI[2].xyz));
  vec3 w = b.w.xyz + invI * p.torque.xyz * h;
  v *= 1.0 / (1.0 + h * p.torque.w);
  w *= 1.0 / (1.0 + h * p.moments.w);
  // Lengths in double: a huge finite speed would overflow a float length to infinity.
  double vl = length(dvec3(v));
  if (vl > double(k.maxLinearSpeed)) v *= float(double(k.maxLinearSpeed) / vl);
  double wl = length(dvec3(w));
  if (wl > double(k.maxAngularSpeed)) w *= float(double(k.maxAngularSpeed) / wl);
  bodies[i].v = vec4(v, 0);
  bodies[i].w = vec4(w, 0);
}
