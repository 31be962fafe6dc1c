#version 450
// The joints' direct solve (Roblox's LDL hybrid; the CPU's EqualityLdl, solver_ldl.cpp): all
// equality rows of an island at once, exactly, whatever the mass ratio. One thread per
// island walks the plan's fixed index lists (joint_ldl.h) in double precision:
//   PHYS_GPU_LDL_FACTOR  A = J M^-1 J^T from the rows now (plus the CPU's 1e-6 relative
//                        regularization) as L D L^T, row by row (Davis' up-looking LDL);
//   PHYS_GPU_LDL_SOLVE   d = -A^-1 (J v + jointBiasRate C) (the bias only with useBias),
//                        added to the rows' impulses and applied to the bodies;
//   PHYS_GPU_LDL_PUSH    d = -A^-1 J v_push on the split push-out's pseudo velocities,
//                        applied to them (EqualityLdl::solvePush: no bias, no impulse kept).
// An island's bodies belong to it alone, so its thread writes their velocities directly.
// Dispatched with jacobi = 0: the bodies' whole masses (loadSide splits none).
#extension GL_GOOGLE_include_directive : require
#extension GL_ARB_gpu_shader_fp64 : require
#include "shared.h"
#include "common.glsl"
layout(local_size_x = PHYS_GPU_GROUP) in;
layout(std430, binding = 0) buffer Bodies { GpuSolverBody bodies[]; };
layout(std430, binding = 1) readonly buffer Params { GpuBodyParams params[]; };
layout(std430, binding = 2) readonly buffer Refs { uvec4 refs[]; };
layout(std430, binding = 3) readonly buffer Joints { GpuJoint joints[]; };
layout(std430, binding = 4) buffer Rows { GpuJointRows jointRows[]; };
layout(std430, binding = 5) readonly buffer Islands { uvec4 islands[]; };
layout(std430, binding = 6) readonly buffer LdlRows { GpuLdlRow ldlRows[]; };
layout(std430, binding = 7) readonly buffer Pattern { uvec2 pattern[]; };
layout(std430, binding = 8) readonly buffer ColumnRows { uint columnRows[]; };
layout(std430, binding = 9) buffer Values { double values[]; };
layout(std430, binding = 10) buffer Diagonal { double diagonal[]; };
layout(std430, binding = 11) buffer Work { double work[]; };
// The split push-out's pseudo velocities: body b's linear at 2b, angular at 2b + 1.
layout(std430, binding = 12) buffer PushVelocities { vec4 pushVelocity[]; };
layout(std430, binding = 13) readonly buffer Counters { uint counters[]; };
layout(push_constant) uniform Push { GpuSolveConstants k; };
#include "contact.glsl"
#include "joint.glsl"

GpuJointRow rowOf(uint r) {
  return jointRows[ldlRows[r].joint].rows[ldlRows[r].row];
}

// One body's part of A(i, j): row i's Jacobian on it times row j's M^-1 J^T on it.
double onBody(int b, vec3 linI, vec3 angI, vec3 linJ, vec3 angJ) {
  Side s = loadSide(b);
  return double(dot(linI, linJ * s.invMass)) + double(dot(angI, s.invI * angJ));
}

// A(i, j): the rows meet through every dynamic body they share (loadSide gives a static or
// kinematic body no mass, so it adds nothing).
double coupling(uint i, uint j) {
  GpuJointRow ri = rowOf(i), rj = rowOf(j);
  GpuJoint ji = joints[ldlRows[i].joint], jj = joints[ldlRows[j].joint];
  double a = 0;
  if (ji.bodyA >= 0 && ji.bodyA == jj.bodyA)
    a += onBody(ji.bodyA, ri.linA.xyz, ri.angA.xyz, rj.linA.xyz, rj.angA.xyz);
  if (ji.bodyA >= 0 && ji.bodyA == jj.bodyB)
    a += onBody(ji.bodyA, ri.linA.xyz, ri.angA.xyz, rj.linB.xyz, rj.angB.xyz);
  if (ji.bodyB >= 0 && ji.bodyB == jj.bodyA)
    a += onBody(ji.bodyB, ri.linB.xyz, ri.angB.xyz, rj.linA.xyz, rj.angA.xyz);
  if (ji.bodyB >= 0 && ji.bodyB == jj.bodyB)
    a += onBody(ji.bodyB, ri.linB.xyz, ri.angB.xyz, rj.linB.xyz, rj.angB.xyz);
  return a;
}

void factor(uvec4 island) {
  for (uint r = island.x; r < island.x + island.y; ++r) {
    GpuLdlRow R = ldlRows[r];
    // Row r of A left of the diagonal, scattered into the work vector (L's row pattern
    // holds A's, plus the fill).
    for (uint e = R.patternBegin; e < R.patternEnd; ++e) work[pattern[e].x] = coupling(pattern[e].x, r);
    double arr = coupling(r, r);
    double d = arr * (1.0 + 1e-6) + 1e-12;  // the CPU's regularization (redundant joints)
    // Solve L(0:r, 0:r) y = A(0:r, r) along the pattern, in ascending order (a topological
    // order of the elimination tree): L(r, i) = y_i / D_i.
    for (uint e = R.patternBegin; e < R.patternEnd; ++e) {
      uint i = pattern[e].x, at = pattern[e].y;
      double y = work[i];
      work[i] = 0;
      // Column i's entries above row r are those stored before L(r, i).
      for (uint p = ldlRows[i].columnBegin; p < at; ++p) work[columnRows[p]] -= values[p] * y;
      double l = y / diagonal[i];
      d -= l * y;
      values[at] = l;
    }
    // A positive definite A keeps d > 0; rounding on a nearly redundant row may not: keep the
    // row solvable rather than divide by nothing.
    if (!(d > 1e-9 * arr)) d = arr * 1e-6 + 1e-12;
    diagonal[r] = d;
  }
}

// Body b's velocities the solve works on: its own, or (push) its push-out pseudo velocities
// (zero for the world and static bodies, which the push-out never writes).
void velocitiesOf(int b, Side S, bool push, out vec3 v, out vec3 w) {
  v = S.v;
  w = S.w;
  if (!push) return;
  v = b >= 0 ? pushVelocity[2 * b].xyz : vec3(0);
  w = b >= 0 ? pushVelocity[2 * b + 1].xyz : vec3(0);
}

void storeVelocities(int b, Side S, bool push, vec3 v, vec3 w) {
  if (b < 0 || S.invMass <= 0) return;
  if (push) {
    pushVelocity[2 * b] = vec4(v, 0);
    pushVelocity[2 * b + 1] = vec4(w, 0);
  } else {
    bodies[b].v.xyz = v;
    bodies[b].w.xyz = w;
  }
}

void solve(uvec4 island, bool push) {
  uint first = island.x, end = island.x + island.y;
  bool useBias = k.useBias != 0u && !push;
  for (uint r = first; r < end; ++r) {
    GpuJoint j = joints[ldlRows[r].joint];
    GpuJointRow row = rowOf(r);
    Side A = loadSide(j.bodyA), B = loadSide(j.bodyB);
    vec3 va, wa, vb, wb;
    velocitiesOf(j.bodyA, A, push, va, wa);
    velocitiesOf(j.bodyB, B, push, vb, wb);
    double rhs = double(jrVelocity(row, va, wa, vb, wb));
    if (useBias) rhs += double(k.jointBiasRate) * double(jrError(row, A, B));
    work[r] = -rhs;
  }
  // L y = b (column by column), D z = y, L^T x = z.
  for (uint r = first; r < end; ++r) {
    double y = work[r];
    if (y == 0) continue;
    for (uint p = ldlRows[r].columnBegin; p < ldlRows[r].columnEnd; ++p)
      work[columnRows[p]] -= values[p] * y;
  }
  for (uint r = first; r < end; ++r) work[r] /= diagonal[r];
  for (uint r = end; r-- > first;) {
    double x = work[r];
    for (uint p = ldlRows[r].columnBegin; p < ldlRows[r].columnEnd; ++p)
      x -= values[p] * work[columnRows[p]];
    work[r] = x;
  }
  // The impulses, row by row, straight into the island's bodies.
  for (uint r = first; r < end; ++r) {
    float d = float(work[r]);
    if (isnan(d) || isinf(d) || d == 0) continue;
    GpuLdlRow R = ldlRows[r];
    if (!push) jointRows[R.joint].rows[R.row].angA.w += d;
    GpuJoint j = joints[R.joint];
    GpuJointRow row = rowOf(r);
    Side A = loadSide(j.bodyA), B = loadSide(j.bodyB);
    vec3 va, wa, vb, wb;
    velocitiesOf(j.bodyA, A, push, va, wa);
    velocitiesOf(j.bodyB, B, push, vb, wb);
    jrApply(row, d, A, B, va, wa, vb, wb);
    storeVelocities(j.bodyA, A, push, va, wa);
    storeVelocities(j.bodyB, B, push, vb, wb);
  }
}

void main() {
  uint island = globalIndex();
  if (island >= k.ldlIslands) return;
  // The push-out's pass only in a step it runs in (contact_gs.comp's splitActive).
  if (k.mode == PHYS_GPU_LDL_PUSH &&
      !(k.splitPushout != 0u &&
        uintBitsToFloat(counters[PHYS_GPU_COUNTER_DEEPEST]) > PHYS_GPU_SPLIT_DEPTH))
    return;
  if (k.mode == PHYS_GPU_LDL_FACTOR)
    factor(islands[island]);
  else
    solve(islands[island], k.mode == PHYS_GPU_LDL_PUSH);
}
