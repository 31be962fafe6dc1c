#version 450
// Prepare, contacts: each manifold's rows as World::Impl::solverManifold and contactRowsOf
// build them: anchors from the bodies' centres of mass at the step's start, the tangent
// basis, effective masses with the bodies' masses split among their contacts, the approach
// speed for restitution, and last step's impulses when warm starting.
#extension GL_GOOGLE_include_directive : require
#extension GL_ARB_gpu_shader_fp64 : require
#include "shared.h"
#include "common.glsl"
layout(local_size_x = PHYS_GPU_GROUP) in;
layout(std430, binding = 0) readonly buffer Bodies { GpuSolverBody bodies[]; };
layout(std430, binding = 1) readonly buffer Params { GpuBodyParams params[]; };
layout(std430, binding = 2) readonly buffer Refs { uvec4 refs[]; };
layout(std430, binding = 3) readonly buffer States { GpuBodyState states[]; };
layout(std430, binding = 4) readonly buffer Shapes { GpuShape shapes[]; };
layout(std430, binding = 5) readonly buffer Manifolds { GpuManifold manifolds[]; };
layout(std430, binding = 6) writeonly buffer Contacts { GpuContact contacts[]; };
layout(std430, binding = 7) readonly buffer Counters { uint counters[]; };
layout(std430, binding = 8) writeonly buffer Colors { uint colors[]; };
layout(push_constant) uniform Push { GpuSolveConstants k; };
#include "contact.glsl"

void main() {
  uint i = globalIndex();
  if (i >= counters[PHYS_GPU_COUNTER_PAIRS]) return;
  GpuManifold m = manifolds[i];
  GpuContact c;
  c.count = m.count;
  // Colored Gauss-Seidel colors the contacts with points (color_round.comp).
  colors[k.jointCount + i] = m.count == 0u ? PHYS_GPU_NO_COLOR : PHYS_GPU_UNCOLORED;
  if (m.count == 0u) {
    contacts[i].count = 0u;
    return;
  }
  c.bodyA = shapes[m.shapeA].body;
  c.bodyB = shapes[m.shapeB].body;
  c.friction = m.normal.w;
  vec3 n = m.normal.xyz;
  c.normal = vec4(n, m.restitution);
  vec3 t1, t2;
  tangentBasis(n, t1, t2);
  c.t1 = vec4(t1, 0);
  c.t2 = vec4(t2, 0);
  Side A = loadSide(c.bodyA), B = loadSide(c.bodyB);
  vec3 comA = c.bodyA >= 0 ? states[c.bodyA].com.xyz : vec3(0);
  vec3 comB = c.bodyB >= 0 ? states[c.bodyB].com.xyz : vec3(0);
  vec3 vA = c.bodyA >= 0 ? states[c.bodyA].v.xyz : vec3(0), wA = c.bodyA >= 0 ? states[c.bodyA].w.xyz : vec3(0);
  vec3 vB = c.bodyB >= 0 ? states[c.bodyB].v.xyz : vec3(0), wB = c.bodyB >= 0 ? states[c.bodyB].w.xyz : vec3(0);
  for (uint p = 0u; p < 4u; ++p) {
    c.rA[p] = vec4(0);
    c.rB[p] = vec4(0);
  }
  c.massN = c.massT1 = c.massT2 = vec4(0);
  for (uint p = 0u; p < m.count; ++p) {
    vec3 point = m.points[p].xyz;
    vec3 rA = point - comA, rB = point - comB;
    float approach = dot(n, (vB + cross(wB, rB)) - (vA + cross(wA, rA)));
    c.rA[p] = vec4(rA, m.points[p].w);
    c.rB[p] = vec4(rB, approach);
    c.massN[p] = effectiveMass(n, rA, rB, A, B);
    c.massT1[p] = effectiveMass(t1, rA, rB, A, B);
    c.massT2[p] = effectiveMass(t2, rA, rB, A, B);
  }
  // Patch friction: the tangent pair at the points' centroid, the twist about the normal
  // with the points' mean distance from it as arm (World::Impl::solverManifold).
  c.patchRA = c.patchRB = vec4(0);
  if (k.patchFriction != 0u) {
    vec3 patchCenter = vec3(0);
    for (uint p = 0u; p < m.count; ++p) patchCenter += m.points[p].xyz;
    patchCenter = patchCenter * (1.0 / float(m.count));
    float arm = 0;
    for (uint p = 0u; p < m.count; ++p) arm += length(m.points[p].xyz - patchCenter);
    vec3 pa = patchCenter - comA, pb = patchCenter - comB;
    arm = arm / float(m.count);
    if (m.count == 1u) {
      // A Hertz patch's 2a/3 (World::Impl::solverManifold, pointPatchArm).
      float k = 0.0;
      GpuShape sa = shapes[m.shapeA], sb = shapes[m.shapeB];
      if (sa.type == PHYS_GPU_SHAPE_SPHERE || sa.type == PHYS_GPU_SHAPE_CAPSULE) k += 1.0 / sa.size.x;
      if (sb.type == PHYS_GPU_SHAPE_SPHERE || sb.type == PHYS_GPU_SHAPE_CAPSULE) k += 1.0 / sb.size.x;
      arm = k > 0.0 ? (2.0 / 3.0) * sqrt(float(PHYS_GPU_POINT_PATCH_DEPTH) / k) : 0.0;
    }
    c.patchRA = vec4(pa, arm);
    c.patchRB = vec4(pb, 1);
    c.massT1 = c.massT2 = vec4(0);
    c.massT1[0] = effectiveMass(t1, pa, pb, A, B);
    c.massT2[0] = effectiveMass(t2, pa, pb, A, B);
    float kt = dot(-n, A.invI * -n) + dot(n, B.invI * n);
    c.massT1[1] = kt > 1e-12 ? 1.0 / kt : 0.0;
  }
  bool warm = k.warmStart != 0u;
  c.lambdaN = warm ? m.normalImpulse : vec4(0);
  c.lambdaT1 = warm ? m.tangentImpulse1 : vec4(0);
  c.lambdaT2 = warm ? m.tangentImpulse2 : vec4(0);
  c.maxLambdaN = vec4(0);
  c.pushLambda = vec4(0);  // the split push-out starts each step from zero
  contacts[i] = c;
}
