#version 450
// The joints' direct solve (Roblox's LDL hybrid; the CPU's EqualityLdl, solver_ldl.cpp): all
// equality rows of an island at once, exactly, whatever the mass ratio. A workgroup per
// island works through the plan's fixed index lists (joint_ldl.h) in double precision:
//   PHYS_GPU_LDL_FACTOR  A = J M^-1 J^T from the rows now (plus the CPU's 1e-6 relative
//                        regularization) as L D L^T;
//   PHYS_GPU_LDL_SOLVE   d = -A^-1 (J v + jointBiasRate C) (the bias only with useBias),
//                        added to the rows' impulses and applied to the bodies;
//   PHYS_GPU_LDL_PUSH    d = -A^-1 J v_push on the split push-out's pseudo velocities,
//                        applied to them (EqualityLdl::solvePush: no bias, no impulse kept).
// What has no order runs across the workgroup at once: A's entries, the right-hand side, the
// impulses (a thread per dynamic body applies its rows' in row order). What has one runs
// level by level of the elimination tree (the plan orders an island's rows by level): the
// columns of a level are factored at once, a thread per entry of L (and per pivot), each
// reading only lower levels' columns; the forward and back substitutions take a level's rows
// at once, a thread per row. Every sum is taken by one thread in the plan's order, so runs are
// bit-identical (no atomics). An island's numbers sit in shared memory while they fit.
// An island's bodies belong to it alone, so its workgroup writes their velocities directly.
// Dispatched with jacobi = 0 (the bodies' whole masses: loadSide splits none), one workgroup
// per island.
#extension GL_GOOGLE_include_directive : require
#extension GL_ARB_gpu_shader_fp64 : require
#include "shared.h"
#include "common.glsl"
#define LDL_GROUP 64
// Doubles of an island's L, D and work vector kept in shared memory (16 KiB, Vulkan's least
// maxComputeSharedMemorySize): a 40-link chain needs about 700. Larger islands work on the
// global buffers.
#define LDL_SHARED 2048
layout(local_size_x = LDL_GROUP) in;
layout(std430, binding = 0) buffer Bodies { GpuSolverBody bodies[]; };
layout(std430, binding = 1) readonly buffer Params { GpuBodyParams params[]; };
layout(std430, binding = 2) readonly buffer Refs { uvec4 refs[]; };
layout(std430, binding = 3) readonly buffer Joints { GpuJoint joints[]; };
layout(std430, binding = 4) buffer Rows { GpuJointRows jointRows[]; };
layout(std430, binding = 5) readonly buffer Islands { GpuLdlIsland islands[]; };
layout(std430, binding = 6) readonly buffer LdlRows { GpuLdlRow ldlRows[]; };
layout(std430, binding = 7) readonly buffer Pattern { uvec2 pattern[]; };
layout(std430, binding = 8) readonly buffer ColumnRows { uint columnRows[]; };
// Written and read by the workgroup's threads between barriers: coherent.
layout(std430, binding = 9) coherent buffer Values { double values[]; };
layout(std430, binding = 10) coherent buffer Diagonal { double diagonal[]; };
layout(std430, binding = 11) coherent buffer Work { double work[]; };
// The split push-out's pseudo velocities: body b's linear at 2b, angular at 2b + 1.
layout(std430, binding = 12) buffer PushVelocities { vec4 pushVelocity[]; };
layout(std430, binding = 13) readonly buffer Counters { uint counters[]; };
layout(std430, binding = 14) readonly buffer EntryColumns { uint entryColumns[]; };
layout(std430, binding = 15) readonly buffer Levels { uvec2 levels[]; };
layout(std430, binding = 16) readonly buffer LdlBodies { uvec4 ldlBodies[]; };
layout(std430, binding = 17) readonly buffer BodyRows { uint bodyRows[]; };
layout(push_constant) uniform Push { GpuSolveConstants k; };
#include "contact.glsl"
#include "joint.glsl"

shared double scratch[LDL_SHARED];

// This workgroup's island: its entries of L and its rows, and where their numbers are (the
// same for every thread of the workgroup, so the branches below never diverge).
bool inShared;
uint entry0, entryCount, row0, rowCount;

double getL(uint p) { return inShared ? scratch[p - entry0] : values[p]; }
void setL(uint p, double x) {
  if (inShared)
    scratch[p - entry0] = x;
  else
    values[p] = x;
}
double getD(uint r) { return inShared ? scratch[entryCount + r - row0] : diagonal[r]; }
void setD(uint r, double x) {
  if (inShared)
    scratch[entryCount + r - row0] = x;
  else
    diagonal[r] = x;
}
double getW(uint r) { return inShared ? scratch[entryCount + rowCount + r - row0] : work[r]; }
void setW(uint r, double x) {
  if (inShared)
    scratch[entryCount + rowCount + r - row0] = x;
  else
    work[r] = x;
}

// Every thread's writes (shared or global) visible to the workgroup.
void sync() {
  memoryBarrierShared();
  memoryBarrierBuffer();
  barrier();
}

GpuJointRow rowOf(uint r) {
  return jointRows[ldlRows[r].joint].rows[ldlRows[r].row];
}

// One body's part of A(i, j): row i's Jacobian on it times row j's M^-1 J^T on it.
double onBody(int b, vec3 linI, vec3 angI, vec3 linJ, vec3 angJ) {
  Side s = loadSide(b);
  return double(dot(linI, linJ * s.invMass)) + double(dot(angI, s.invI * angJ));
}

// A(i, j): the rows meet through every dynamic body they share (loadSide gives a static or
// kinematic body no mass, so it adds nothing; rows that share none, L's fill, give 0).
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

// D(j) from A(j, j) (kept in the work vector while factoring) and row j of L, whose columns
// are all of lower levels. The pivot's thread and every thread of column j's entries compute
// it alike (precise: no contraction that could differ between them).
double pivot(uint j) {
  double arr = getW(j);
  precise double d = arr * (1.0 + 1e-6) + 1e-12;  // the CPU's regularization (redundant joints)
  for (uint e = ldlRows[j].patternBegin; e < ldlRows[j].patternEnd; ++e) {
    double l = getL(pattern[e].y);
    d -= l * l * getD(pattern[e].x);
  }
  // A positive definite A keeps d > 0; rounding on a nearly redundant row may not: keep the
  // row solvable rather than divide by nothing.
  if (!(d > 1e-9 * arr)) d = arr * 1e-6 + 1e-12;
  return d;
}

// Sum over the columns k < j that rows i and j of L share of L(i, k) D(k) L(j, k): their row
// patterns, both ascending, merged.
double sharedColumns(uint i, uint j) {
  precise double sum = 0;
  uint a = ldlRows[i].patternBegin, aEnd = ldlRows[i].patternEnd;
  uint b = ldlRows[j].patternBegin, bEnd = ldlRows[j].patternEnd;
  while (a < aEnd && b < bEnd) {
    uvec2 pa = pattern[a], pb = pattern[b];
    if (pa.x >= j) break;
    if (pa.x < pb.x) {
      ++a;
    } else if (pb.x < pa.x) {
      ++b;
    } else {
      sum += getL(pa.y) * getD(pa.x) * getL(pb.y);
      ++a;
      ++b;
    }
  }
  return sum;
}

void factor(GpuLdlIsland island) {
  uint t = gl_LocalInvocationIndex;
  // A's entries where L has them (its fill: 0), and its diagonal into the work vector.
  for (uint p = entry0 + t; p < entry0 + entryCount; p += LDL_GROUP)
    setL(p, coupling(columnRows[p], entryColumns[p]));
  for (uint r = row0 + t; r < row0 + rowCount; r += LDL_GROUP) setW(r, coupling(r, r));
  sync();
  // Level by level: a level's pivots and its columns' entries, L(i, j) =
  // (A(i, j) - sum_k L(i, k) D(k) L(j, k)) / D(j), all at once.
  for (uint l = island.firstLevel; l < island.firstLevel + island.levels; ++l) {
    uvec2 level = levels[l];
    uint columns = level.y - level.x;
    uint first = ldlRows[level.x].columnBegin, items = columns + ldlRows[level.y - 1].columnEnd - first;
    for (uint item = t; item < items; item += LDL_GROUP) {
      if (item < columns) {
        setD(level.x + item, pivot(level.x + item));
      } else {
        uint p = first + item - columns, j = entryColumns[p];
        setL(p, (getL(p) - sharedColumns(columnRows[p], j)) / pivot(j));
      }
    }
    sync();
  }
  if (inShared) {
    for (uint p = entry0 + t; p < entry0 + entryCount; p += LDL_GROUP) values[p] = getL(p);
    for (uint r = row0 + t; r < row0 + rowCount; r += LDL_GROUP) diagonal[r] = getD(r);
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

// Row r's impulse from the solution (none when it is not a number or zero).
float impulseOf(uint r) {
  float d = float(getW(r));
  return isnan(d) || isinf(d) ? 0.0 : d;
}

void solve(GpuLdlIsland island, bool push) {
  uint t = gl_LocalInvocationIndex;
  bool useBias = k.useBias != 0u && !push;
  if (inShared) {
    for (uint p = entry0 + t; p < entry0 + entryCount; p += LDL_GROUP) setL(p, values[p]);
    for (uint r = row0 + t; r < row0 + rowCount; r += LDL_GROUP) setD(r, diagonal[r]);
  }
  for (uint r = row0 + t; r < row0 + rowCount; r += LDL_GROUP) {
    GpuJoint j = joints[ldlRows[r].joint];
    GpuJointRow row = rowOf(r);
    Side A = loadSide(j.bodyA), B = loadSide(j.bodyB);
    vec3 va, wa, vb, wb;
    velocitiesOf(j.bodyA, A, push, va, wa);
    velocitiesOf(j.bodyB, B, push, vb, wb);
    double rhs = double(jrVelocity(row, va, wa, vb, wb));
    if (useBias) rhs += double(k.jointBiasRate) * double(jrError(row, A, B));
    setW(r, -rhs);
  }
  sync();
  // L y = b: a level's rows at once, each from its row of L (lower levels, done).
  for (uint l = island.firstLevel; l < island.firstLevel + island.levels; ++l) {
    uvec2 level = levels[l];
    for (uint r = level.x + t; r < level.y; r += LDL_GROUP) {
      precise double y = getW(r);
      for (uint e = ldlRows[r].patternBegin; e < ldlRows[r].patternEnd; ++e)
        y -= getL(pattern[e].y) * getW(pattern[e].x);
      setW(r, y);
    }
    sync();
  }
  // D z = y and L^T x = z: from the top level down, each row from its column of L (higher
  // levels, done).
  for (uint l = island.firstLevel + island.levels; l-- > island.firstLevel;) {
    uvec2 level = levels[l];
    for (uint r = level.x + t; r < level.y; r += LDL_GROUP) {
      precise double x = getW(r) / getD(r);
      for (uint p = ldlRows[r].columnBegin; p < ldlRows[r].columnEnd; ++p)
        x -= getL(p) * getW(columnRows[p]);
      setW(r, x);
    }
    sync();
  }
  // The impulses, a thread per dynamic body: its rows in row order.
  for (uint e = island.firstBody + t; e < island.firstBody + island.bodies; e += LDL_GROUP) {
    uvec4 entry = ldlBodies[e];
    int b = int(entry.x);
    Side S = loadSide(b);
    if (S.invMass <= 0) continue;
    vec3 v, w;
    velocitiesOf(b, S, push, v, w);
    for (uint q = entry.y; q < entry.z; ++q) {
      uint r = bodyRows[q];
      float d = impulseOf(r);
      if (d == 0) continue;
      GpuJoint j = joints[ldlRows[r].joint];
      GpuJointRow row = rowOf(r);
      // As jrApply, on this body's side (or both, should a joint hold a body to itself).
      if (j.bodyA == b) {
        v += row.linA.xyz * (S.invMass * d);
        w += (S.invI * row.angA.xyz) * d;
      }
      if (j.bodyB == b) {
        v += row.linB.xyz * (S.invMass * d);
        w += (S.invI * row.angB.xyz) * d;
      }
    }
    if (push) {
      pushVelocity[2 * b] = vec4(v, 0);
      pushVelocity[2 * b + 1] = vec4(w, 0);
    } else {
      bodies[b].v.xyz = v;
      bodies[b].w.xyz = w;
    }
  }
  if (push) return;
  sync();  // the rows were read above: their impulses after
  for (uint r = row0 + t; r < row0 + rowCount; r += LDL_GROUP) {
    float d = impulseOf(r);
    if (d != 0) jointRows[ldlRows[r].joint].rows[ldlRows[r].row].angA.w += d;
  }
}

void main() {
  uint index = groupIndex();
  if (index >= k.ldlIslands) return;
  // The push-out's pass only in a step it runs in (contact_gs.comp's splitActive).
  if (k.mode == PHYS_GPU_LDL_PUSH &&
      !(k.splitPushout != 0u &&
        uintBitsToFloat(counters[PHYS_GPU_COUNTER_DEEPEST]) > PHYS_GPU_SPLIT_DEPTH))
    return;
  GpuLdlIsland island = islands[index];
  row0 = island.firstRow;
  rowCount = island.rows;
  entry0 = ldlRows[row0].columnBegin;
  entryCount = ldlRows[row0 + rowCount - 1].columnEnd - entry0;
  inShared = entryCount + 2 * rowCount <= LDL_SHARED;
  if (k.mode == PHYS_GPU_LDL_FACTOR)
    factor(island);
  else
    solve(island, k.mode == PHYS_GPU_LDL_PUSH);
}
