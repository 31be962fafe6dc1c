#version 450
// Prepare (joints), and again at every later substep: each joint's rows from its bodies'
// current poses, as the CPU's buildJointRows and refreshJointRows (physics/dynamics/joints.cpp):
// a point's three rows as one block, the hinge's two misalignment rows, the rotation lock,
// limits and motors along the hinge or slider axis, the distance row or spring. C0 is set
// so that the error from the bodies' accumulated deltas starts at the exact value now;
// effective masses (split among the bodies' constraints with Jacobi) and the blocks'
// K^-1. Impulses: last step's when warm starting (first build) or kept (refresh).
#extension GL_GOOGLE_include_directive : require
#extension GL_ARB_gpu_shader_fp64 : require
#include "shared.h"
#include "common.glsl"
layout(local_size_x = PHYS_GPU_GROUP) in;
layout(std430, binding = 0) readonly buffer Bodies { GpuSolverBody bodies[]; };
layout(std430, binding = 1) readonly buffer Params { GpuBodyParams params[]; };
layout(std430, binding = 2) readonly buffer Refs { uvec4 refs[]; };
layout(std430, binding = 3) readonly buffer States { GpuBodyState states[]; };
layout(std430, binding = 4) readonly buffer Joints { GpuJoint joints[]; };
layout(std430, binding = 5) buffer Rows { GpuJointRows jointRows[]; };
layout(std430, binding = 6) readonly buffer Out { GpuJointOut jointOut[]; };
layout(std430, binding = 7) writeonly buffer Colors { uint colors[]; };
layout(push_constant) uniform Push { GpuSolveConstants k; };
#include "contact.glsl"
#include "joint.glsl"

GpuJointRow rows[PHYS_GPU_JOINT_MAX_ROWS];
uint count = 0u;
vec3 rA, rB;

void push(uint kind, vec3 linA, vec3 angA, vec3 linB, vec3 angB, float C) {
  GpuJointRow r;
  r.linA = vec4(linA, C);
  r.angA = vec4(angA, 0);
  r.linB = vec4(linB, 0);
  r.angB = vec4(angB, 0);
  r.info = uvec4(kind, 1u, 0u, 0u);
  rows[count++] = r;
}
// A row on the anchor points along e (leverA: A's arm); a row on the relative rotation about u.
void linearRow(uint kind, vec3 e, float C, vec3 leverA) {
  push(kind, -e, -cross(leverA, e), e, cross(rB, e), C);
}
void angularRow(uint kind, vec3 u, float C) { push(kind, vec3(0), -u, vec3(0), u, C); }
void markBlock(uint first) { rows[first].info.y = count - first; }

void limitAndMotor(GpuJoint j, float position, vec3 dir, bool linear, vec3 leverA) {
  if ((j.flags & PHYS_GPU_JOINT_LIMIT) != 0u) {
    if (linear) {
      linearRow(PHYS_GPU_ROW_LIMIT, dir, position - j.anchorB.w, leverA);
      linearRow(PHYS_GPU_ROW_LIMIT, -dir, j.axisA.w - position, leverA);
    } else {
      angularRow(PHYS_GPU_ROW_LIMIT, dir, position - j.anchorB.w);
      angularRow(PHYS_GPU_ROW_LIMIT, -dir, j.axisA.w - position);
    }
  }
  if ((j.flags & PHYS_GPU_JOINT_MOTOR) != 0u) {
    if (linear)
      linearRow(PHYS_GPU_ROW_MOTOR, dir, 0, leverA);
    else
      angularRow(PHYS_GPU_ROW_MOTOR, dir, 0);
    rows[count - 1u].info.z = floatBitsToUint(j.axisB.w);          // target speed
    rows[count - 1u].info.w = floatBitsToUint(j.refA.w * k.h);     // max impulse per substep
  }
}

void main() {
  uint ji = globalIndex();
  if (ji >= k.jointCount) return;
    GpuJoint j = joints[ji];
  if (k.refresh == 0u) colors[ji] = PHYS_GPU_UNCOLORED;  // colored Gauss-Seidel colors it anew
  // The frame at the current poses (World::Impl::refreshJoints' "current"): orientation
  // and centre of mass advanced by the step's deltas.
  vec4 qA = j.qA, qB;
  vec3 pA;
  if (j.bodyA >= 0) {
    qA = bodies[j.bodyA].q;
    rA = quatRotate(qA, j.anchorA.xyz);
    pA = states[j.bodyA].com.xyz + bodies[j.bodyA].dp.xyz + rA;
  } else {
    rA = j.anchorA.xyz;  // as the CPU: the world anchor (no velocity, no mass: no lever)
    pA = j.anchorA.xyz;
  }
    vec3 pB;
  if (j.bodyB >= 0) {
    qB = bodies[j.bodyB].q;
    rB = quatRotate(qB, j.anchorB.xyz);
    pB = states[j.bodyB].com.xyz + bodies[j.bodyB].dp.xyz + rB;
  } else {
    qB = j.qB;
    rB = j.anchorB.xyz;
    pB = j.anchorB.xyz;
  }
  vec3 dp = pB - pA;
  const vec3 ex = vec3(1, 0, 0), ey = vec3(0, 1, 0), ez = vec3(0, 0, 1);
  uint type = j.type;
  if (type != PHYS_GPU_JOINT_DISTANCE && type != PHYS_GPU_JOINT_PRISMATIC) {
    // The anchor points meet: three rows, one block.
    linearRow(PHYS_GPU_ROW_EQUALITY, ex, dp.x, rA);
    linearRow(PHYS_GPU_ROW_EQUALITY, ey, dp.y, rA);
    linearRow(PHYS_GPU_ROW_EQUALITY, ez, dp.z, rA);
    markBlock(0u);
  }
  vec3 rotErr = rotationVector(quatNormalize(quatMul(qB, quatConj(quatMul(qA, j.relRot0)))));
  if (type == PHYS_GPU_JOINT_FIXED) {
    uint first = count;
    angularRow(PHYS_GPU_ROW_EQUALITY, ex, rotErr.x);
    angularRow(PHYS_GPU_ROW_EQUALITY, ey, rotErr.y);
    angularRow(PHYS_GPU_ROW_EQUALITY, ez, rotErr.z);
    markBlock(first);
  } else if (type == PHYS_GPU_JOINT_HINGE) {
    vec3 aA = quatRotate(qA, j.axisA.xyz), aB = quatRotate(qB, j.axisB.xyz);
    vec3 b1, b2;
    tangentBasis(aA, b1, b2);
    // Small-angle misalignment of the axes: (aA x aB) on the two perpendiculars.
    vec3 mis = cross(aA, aB);
    uint first = count;
    angularRow(PHYS_GPU_ROW_EQUALITY, b1, dot(b1, mis));
    angularRow(PHYS_GPU_ROW_EQUALITY, b2, dot(b2, mis));
    markBlock(first);
    vec3 rfA = quatRotate(qA, j.refA.xyz), rfB = quatRotate(qB, j.refB.xyz);
    float angle = atan(dot(cross(rfA, rfB), aA), dot(rfA, rfB));
    limitAndMotor(j, angle, aA, false, vec3(0));
  } else if (type == PHYS_GPU_JOINT_PRISMATIC) {
    vec3 a = quatRotate(qA, j.axisA.xyz);
    vec3 b1, b2;
    tangentBasis(a, b1, b2);
    // A's lever reaches to B's anchor: sliding along the axis changes no perpendicular row.
    vec3 leverA = rA + dp;
    linearRow(PHYS_GPU_ROW_EQUALITY, b1, dot(b1, dp), leverA);
    linearRow(PHYS_GPU_ROW_EQUALITY, b2, dot(b2, dp), leverA);
    markBlock(0u);
    uint first = count;
    angularRow(PHYS_GPU_ROW_EQUALITY, ex, rotErr.x);
    angularRow(PHYS_GPU_ROW_EQUALITY, ey, rotErr.y);
    angularRow(PHYS_GPU_ROW_EQUALITY, ez, rotErr.z);
    markBlock(first);
    limitAndMotor(j, dot(a, dp), a, true, leverA);
  } else if (type == PHYS_GPU_JOINT_DISTANCE) {
    float len = length(dp);
    vec3 n = len > 1e-6 ? dp / len : ex;
    float rest = j.anchorA.w;
    if (j.spring.y != 0) linearRow(PHYS_GPU_ROW_EQUALITY, n, len - rest, rA);
    if (j.refB.w > 0) {
      linearRow(PHYS_GPU_ROW_SPRING, n, len - rest, rA);
      rows[count - 1u].info.z = floatBitsToUint(j.refB.w);
      rows[count - 1u].info.w = floatBitsToUint(j.spring.x);
    }
    if ((j.flags & PHYS_GPU_JOINT_LIMIT) != 0u) {
      linearRow(PHYS_GPU_ROW_LIMIT, n, len - j.anchorB.w, rA);
      linearRow(PHYS_GPU_ROW_LIMIT, -n, j.axisA.w - len, rA);
    }
  }

  // C0: the error now minus what the accumulated deltas add; masses; blocks' K^-1.
  Side A = loadSide(j.bodyA), B = loadSide(j.bodyB);
  GpuJointRows old = jointRows[ji];
  GpuJointRows J;
  J.count = count;
  J.pad0 = J.pad1 = J.pad2 = 0u;
  for (uint s = 0u; s < 6u; ++s) J.invK[s] = vec4(0);
  bool keep = k.refresh != 0u && old.count == count;
  bool warm = k.refresh == 0u && k.warmStart != 0u && floatBitsToUint(jointOut[ji].force.w) == count;
  for (uint i = 0u; i < PHYS_GPU_JOINT_MAX_ROWS; ++i) {
    if (i >= count) {
      J.rows[i] = GpuJointRow(vec4(0), vec4(0), vec4(0), vec4(0), uvec4(0));
      continue;
    }
    GpuJointRow r = rows[i];
    r.linA.w -= dot(r.linA.xyz, A.dp) + dot(r.angA.xyz, A.dtheta) + dot(r.linB.xyz, B.dp) +
                dot(r.angB.xyz, B.dtheta);
    float kk = jrCoupling(r, r, A, B);
    r.linB.w = kk > 1e-12 ? 1.0 / kk : 0.0;
    r.angA.w = keep ? old.rows[i].angA.w : (warm ? jointOut[ji].impulses[i / 4u][i % 4u] : 0.0);
    J.rows[i] = r;
  }
  for (uint i = 0u; i < count; ++i) {
    uint n = J.rows[i].info.y;
    if (n < 2u) continue;
    mat3 K = mat3(1);
    for (uint a = 0u; a < n; ++a)
      for (uint b = 0u; b < n; ++b) K[b][a] = jrCoupling(J.rows[i + a], J.rows[i + b], A, B);
    mat3 inv = transpose(inverse(K));  // stored as rows
    uint slot = i == 0u ? 0u : 3u;
    J.invK[slot] = vec4(inv[0], 0);
    J.invK[slot + 1u] = vec4(inv[1], 0);
    J.invK[slot + 2u] = vec4(inv[2], 0);
    i += n - 1u;
  }
  jointRows[ji] = J;
}
