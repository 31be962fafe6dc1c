#version 450
// Colored Gauss-Seidel (contacts): the contacts of one color, in parallel (no two share a
// dynamic body), each applying its rows straight to its bodies' velocities; the overflow
// slot is walked by one thread in contact order. The pass (warm start, solve or relax,
// restitution, the position pass, the split push-out's passes) is GpuSolveConstants.mode;
// contact.glsl has the rows.
// Compiled twice (gpu_solver/CMakeLists.txt): contact_gs, a dispatch per color, and
// contact_gs_group (PHYS_GPU_GROUP_PASSES, a small world): one workgroup runs
// GpuSolveConstants.groupPasses passes over every color in one dispatch, a barrier after each
// color; the first pass is k.mode, the
// next ones solve (after a warm start) or push out (after the push-out's warm start). Each
// contact runs the same arithmetic in the same color order as with a dispatch per color, so
// the bits are the same. The push-out's warm start then zeroes the pseudo velocities itself
// (the host's fill is left out).
#extension GL_GOOGLE_include_directive : require
#extension GL_ARB_gpu_shader_fp64 : require
#include "shared.h"
#include "common.glsl"
layout(local_size_x = PHYS_GPU_GROUP) in;
#ifdef PHYS_GPU_GROUP_PASSES
// Coherent: the workgroup reads in one color what it wrote in the last, after a barrier.
#define PHYS_GPU_COHERENT coherent
#else
#define PHYS_GPU_COHERENT
#endif
layout(std430, binding = 0) PHYS_GPU_COHERENT buffer Bodies { GpuSolverBody bodies[]; };
layout(std430, binding = 1) readonly buffer Params { GpuBodyParams params[]; };
layout(std430, binding = 2) PHYS_GPU_COHERENT buffer Contacts { GpuContact contacts[]; };
layout(std430, binding = 3) readonly buffer Keys { uvec2 colorKeys[]; };
layout(std430, binding = 4) readonly buffer Ranges { uvec4 ranges[]; };
layout(std430, binding = 5) readonly buffer Refs { uvec4 refs[]; };
layout(std430, binding = 6) readonly buffer Joints { GpuJoint joints[]; };
layout(std430, binding = 7) PHYS_GPU_COHERENT buffer Rows { GpuJointRows jointRows[]; };
layout(std430, binding = 8) readonly buffer Counters { uint counters[]; };
// The split push-out's pseudo velocities: body b's linear at 2b, angular at 2b + 1.
layout(std430, binding = 9) PHYS_GPU_COHERENT buffer PushVelocities { vec4 pushVelocity[]; };
layout(push_constant) uniform Push { GpuSolveConstants k; };
#ifdef PHYS_GPU_GROUP_PASSES
uint passMode;  // this pass's PHYS_GPU_PASS_* (k.mode, or a later pass of the workgroup's run)
#else
#define passMode k.mode
#endif
#include "contact.glsl"
#include "joint.glsl"

void store(int b, vec3 v, vec3 w) {
  if (b < 0 || (params[b].flags.x & PHYS_GPU_BODY_DYNAMIC) == 0u) return;
  bodies[b].v.xyz = v;
  bodies[b].w.xyz = w;
}

// Nonlinear Gauss-Seidel: the contact's corrections move its bodies' poses at once.
void moveBody(int b, vec3 dp, vec3 dth) {
  if (b < 0 || (params[b].flags.x & PHYS_GPU_BODY_DYNAMIC) == 0u) return;
  if (dp == vec3(0) && dth == vec3(0)) return;
  bodies[b].dp.xyz += dp;
  bodies[b].dtheta.xyz += dth;
  bodies[b].q = integrateRotation(bodies[b].q, dth, 1.0);
}

void solveJointOne(uint ji) {
  GpuJoint j = joints[ji];
  Side A = loadSide(j.bodyA), B = loadSide(j.bodyB);
  if (passMode == PHYS_GPU_PASS_POSITION) {
    // Row by row, each from the poses the previous rows left (Solver::positionPass).
    GpuJointRows J = jointRows[ji];
    for (uint i = 0u; i < J.count; ++i) {
      GpuJointRow r = J.rows[i];
      float d = positionCorrection(r, A, B);
      if (d == 0) continue;
      moveBody(j.bodyA, r.linA.xyz * (A.invMass * d), (A.invI * r.angA.xyz) * d);
      moveBody(j.bodyB, r.linB.xyz * (B.invMass * d), (B.invI * r.angB.xyz) * d);
      A = loadSide(j.bodyA);
      B = loadSide(j.bodyB);
    }
    return;
  }
  if (passMode == PHYS_GPU_PASS_RESTITUTION) return;
  vec3 va = A.v, wa = A.w, vb = B.v, wb = B.w;
  if (passMode == PHYS_GPU_PASS_WARM_START) {
    warmStartJoint(jointRows[ji], A, B, va, wa, vb, wb);
  } else {
    GpuJointRows J = jointRows[ji];
    solveJoint(J, A, B, k.useBias != 0u, va, wa, vb, wb);
    for (uint i = 0u; i < J.count; ++i) jointRows[ji].rows[i].angA.w = J.rows[i].angA.w;
  }
  store(j.bodyA, va, wa);
  store(j.bodyB, vb, wb);
}

// Body b's pseudo velocities (zero for the world).
void loadPush(int b, out vec3 v, out vec3 w) {
  v = b >= 0 ? pushVelocity[2 * b].xyz : vec3(0);
  w = b >= 0 ? pushVelocity[2 * b + 1].xyz : vec3(0);
}

void storePush(int b, vec3 v, vec3 w) {
  if (b < 0 || (params[b].flags.x & PHYS_GPU_BODY_DYNAMIC) == 0u) return;
  pushVelocity[2 * b] = vec4(v, 0);
  pushVelocity[2 * b + 1] = vec4(w, 0);
}

// The split push-out's passes over one contact, on its bodies' pseudo velocities.
void pushOne(uint i) {
  GpuContact c = contacts[i];
  Side A = loadSide(c.bodyA), B = loadSide(c.bodyB);
  vec3 va, wa, vb, wb;
  loadPush(c.bodyA, va, wa);
  loadPush(c.bodyB, vb, wb);
  if (passMode == PHYS_GPU_PASS_PUSH_WARM) {
    pushWarmStartContact(c, A, B, va, wa, vb, wb);
  } else {
    pushoutContact(c, A, B, va, wa, vb, wb);
    contacts[i].pushLambda = c.pushLambda;
  }
  storePush(c.bodyA, va, wa);
  storePush(c.bodyB, vb, wb);
}

// The split push-out's pass over one joint: its equality rows hold the pseudo velocities as
// they hold the real ones, rigid, without bias or warm start (Solver::pushoutGroup); with the
// direct solve joint_ldl.comp's PHYS_GPU_LDL_PUSH does it instead.
void pushJointOne(uint ji) {
  if (k.ldlIslands != 0u) return;
  GpuJoint j = joints[ji];
  Side A = loadSide(j.bodyA), B = loadSide(j.bodyB);
  vec3 va, wa, vb, wb;
  loadPush(j.bodyA, va, wa);
  loadPush(j.bodyB, vb, wb);
  GpuJointRows J = jointRows[ji];
  for (uint i = 0u; i < J.count; ++i) {
    GpuJointRow r = J.rows[i];
    if (r.info.x != PHYS_GPU_ROW_EQUALITY) continue;
    float impulse = -r.linB.w * jrVelocity(r, va, wa, vb, wb);
    if (impulse != 0) jrApply(r, impulse, A, B, va, wa, vb, wb);
  }
  storePush(j.bodyA, va, wa);
  storePush(j.bodyB, vb, wb);
}

void solveOne(uint id) {
  bool push = passMode == PHYS_GPU_PASS_PUSH_WARM || passMode == PHYS_GPU_PASS_PUSHOUT;
  if (id < k.jointCount) {
    if (!push)
      solveJointOne(id);
    else if (passMode == PHYS_GPU_PASS_PUSHOUT)
      pushJointOne(id);
    return;
  }
  uint i = id - k.jointCount;
  if (push) {
    pushOne(i);
    return;
  }
  GpuContact c = contacts[i];
  Side A = loadSide(c.bodyA), B = loadSide(c.bodyB);
  if (passMode == PHYS_GPU_PASS_POSITION) {
    // Row by row, each from the poses the previous rows left (Solver::positionPass).
    vec3 n = c.normal.xyz;
    for (uint p = 0u; p < c.count; ++p) {
      GpuContact one = c;
      one.count = 1u;
      one.rA[0] = c.rA[p];
      one.rB[0] = c.rB[p];
      one.massN[0] = c.massN[p];
      vec3 dpA = vec3(0), dthA = vec3(0), dpB = vec3(0), dthB = vec3(0);
      positionContact(one, A, B, dpA, dthA, dpB, dthB);
      moveBody(c.bodyA, dpA, dthA);
      moveBody(c.bodyB, dpB, dthB);
      A = loadSide(c.bodyA);
      B = loadSide(c.bodyB);
    }
    return;
  }
  vec3 va = A.v, wa = A.w, vb = B.v, wb = B.w;
  if (passMode == PHYS_GPU_PASS_WARM_START)
    warmStartContact(c, A, B, va, wa, vb, wb);
  else if (passMode == PHYS_GPU_PASS_SOLVE)
    solveContact(c, A, B, k.useBias != 0u, va, wa, vb, wb);
  else
    restituteContact(c, A, B, va, wa, vb, wb);
  contacts[i] = c;
  store(c.bodyA, va, wa);
  store(c.bodyB, vb, wb);
}

void main() {
  // The split push-out only in a step with a contact deeper than the contacts' own bias
  // corrects (the CPU's rule, from the same narrow phase's deepest penetration).
  splitActive = k.splitPushout != 0u &&
                uintBitsToFloat(counters[PHYS_GPU_COUNTER_DEEPEST]) > PHYS_GPU_SPLIT_DEPTH;
#ifndef PHYS_GPU_GROUP_PASSES
  if ((k.mode == PHYS_GPU_PASS_PUSH_WARM || k.mode == PHYS_GPU_PASS_PUSHOUT) && !splitActive)
    return;
  uvec4 range = ranges[k.color];
  if (k.color == k.colorLimit) {
    if (globalIndex() != 0u) return;
    for (uint e = range.x; e < range.y; ++e) solveOne(colorKeys[e].y);
    return;
  }
  uint e = range.x + globalIndex();
  if (e < range.y) solveOne(colorKeys[e].y);
#else
  // A small world: this workgroup runs every color of k.groupPasses passes.
  bool push = k.mode == PHYS_GPU_PASS_PUSH_WARM || k.mode == PHYS_GPU_PASS_PUSHOUT;
  passMode = k.mode;
  uint t = gl_LocalInvocationID.x;
  if (k.mode == PHYS_GPU_PASS_PUSH_WARM) {
    for (uint b = t; b < k.bodyCount; b += PHYS_GPU_GROUP) {
      pushVelocity[2 * b] = vec4(0);
      pushVelocity[2 * b + 1] = vec4(0);
    }
    memoryBarrierBuffer();
    barrier();
  }
  if (push && !splitActive) return;
  for (uint p = 0u; p < k.groupPasses; ++p) {
    if (p > 0u && k.mode == PHYS_GPU_PASS_WARM_START) passMode = PHYS_GPU_PASS_SOLVE;
    if (p > 0u && k.mode == PHYS_GPU_PASS_PUSH_WARM) passMode = PHYS_GPU_PASS_PUSHOUT;
    for (uint color = 0u; color <= k.colorLimit; ++color) {
      // One call site of solveOne (the overflow's first thread walks it in order).
      uvec4 range = ranges[color];
      bool overflow = color == k.colorLimit;
      uint e = overflow ? (t == 0u ? range.x : range.y) : range.x + t;
      uint stride = overflow ? 1u : PHYS_GPU_GROUP;
      for (; e < range.y; e += stride) solveOne(colorKeys[e].y);
      memoryBarrierBuffer();
      barrier();
    }
  }
#endif
}
