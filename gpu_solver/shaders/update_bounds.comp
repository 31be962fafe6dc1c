#version 450
// UpdateBounds: each shape's world box, swept by its body's motion over the step and padded
// by half the speculative distance and by how far its rotation can carry it (as the CPU's
// World::Impl::updateBounds), so every pair that can touch during the step is found.
#extension GL_GOOGLE_include_directive : require
#extension GL_ARB_gpu_shader_fp64 : require
#include "shared.h"
#include "common.glsl"
layout(local_size_x = PHYS_GPU_GROUP) in;
layout(std430, binding = 0) readonly buffer States { GpuBodyState states[]; };
layout(std430, binding = 1) readonly buffer Params { GpuBodyParams params[]; };
layout(std430, binding = 2) readonly buffer Shapes { GpuShape shapes[]; };
layout(std430, binding = 3) writeonly buffer Bounds { GpuAabb bounds[]; };
layout(push_constant) uniform Push { GpuStepConstants k; };

void main() {
  uint i = globalIndex();
  if (i >= k.shapeCount) return;
  GpuShape s = shapes[i];
  vec3 p = s.localP.xyz;
  vec4 q = s.localQ;
  vec3 sweepLo = vec3(0), sweepHi = vec3(0);
  float pad = 0.5 * k.speculativeDistance;
  if (s.body >= 0) {
    // Body frame: origin = com - R localCenter.
    GpuBodyState b = states[s.body];
    vec3 origin = b.com.xyz - quatRotate(b.q, params[s.body].localCenter.xyz);
    p = origin + quatRotate(b.q, p);
    q = quatNormalize(quatMul(b.q, q));
    vec3 sweep = b.v.xyz * k.dt;
    sweepLo = min(sweep, vec3(0));
    sweepHi = max(sweep, vec3(0));
    pad += length(b.w.xyz) * k.dt * s.localP.w;
  }
  vec3 ext;
  if (s.type == PHYS_GPU_SHAPE_SPHERE) {
    ext = vec3(s.size.x);
  } else if (s.type == PHYS_GPU_SHAPE_BOX) {
    mat3 R = quatToMat3(q);
    ext = abs(R[0]) * s.size.x + abs(R[1]) * s.size.y + abs(R[2]) * s.size.z;
  } else if (s.type == PHYS_GPU_SHAPE_CAPSULE) {
    vec3 axis = quatRotate(q, vec3(0, 0, 1));
    ext = abs(axis) * s.size.y + vec3(s.size.x);
  } else if (s.type == PHYS_GPU_SHAPE_PLANE) {
    ext = vec3(1e18);
    p = vec3(0);
  } else {
    // Hull: a sphere of its bounding radius about the body's centre of mass.
    ext = vec3(s.localP.w);
    if (s.body >= 0) p = states[s.body].com.xyz;
  }
  bounds[i].lo = vec4(p - ext + sweepLo - vec3(pad), 0);
  bounds[i].hi = vec4(p + ext + sweepHi + vec3(pad), 0);
}
