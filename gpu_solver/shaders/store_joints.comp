#version 450
// StoreImpulses / Finalize (joints): each joint's impulses for next step's warm start and
// the host (snapshots, a step the CPU takes), and its reaction on B: the rows' impulses per
// substep as forces, as World::Impl::finalize computes them.
#extension GL_GOOGLE_include_directive : require
#extension GL_ARB_gpu_shader_fp64 : require
#include "shared.h"
#include "common.glsl"
layout(local_size_x = PHYS_GPU_GROUP) in;
layout(std430, binding = 0) readonly buffer Rows { GpuJointRows jointRows[]; };
layout(std430, binding = 1) writeonly buffer Out { GpuJointOut jointOut[]; };
layout(push_constant) uniform Push { GpuSolveConstants k; };

void main() {
  uint ji = globalIndex();
  if (ji >= k.jointCount) return;
  GpuJointRows J = jointRows[ji];
  GpuJointOut o;
  o.impulses[0] = o.impulses[1] = vec4(0);
  vec3 f = vec3(0), tq = vec3(0);
  for (uint i = 0u; i < J.count; ++i) {
    GpuJointRow r = J.rows[i];
    o.impulses[i / 4u][i % 4u] = r.angA.w;
    f += r.linB.xyz * (r.angA.w / k.h);
    // Only rows that are pure rotation: the moment of the force above is not included.
    if (r.linB.xyz == vec3(0)) tq += r.angB.xyz * (r.angA.w / k.h);
  }
  o.force = vec4(f, uintBitsToFloat(J.count));
  o.torque = vec4(tq, 0);
  jointOut[ji] = o;
}
