// The contact solver's shared part: a body's solver state as a contact sees it (the static
// world when the index is -1), and the rows' Jacobians, as the CPU's contactRow.
#ifndef PHYS_GPU_CONTACT_GLSL
#define PHYS_GPU_CONTACT_GLSL

// This step takes the split push-out (contact_gs.comp sets it): the velocity passes
// correct penetration only down to PHYS_GPU_SPLIT_DEPTH, the pseudo velocities the rest.
bool splitActive = false;

struct Side {
  vec3 v, w, dp, dtheta;
  float invMass;  // split: the body's inverse mass times its contact count (Jacobi)
  mat3 invI;      // split likewise
};

// Needs bindings `bodies` (GpuSolverBody), `params` (GpuBodyParams), `refs` (uvec4) and the
// push constants `k` (GpuSolveConstants). With the Jacobi scheme a body's mass is split
// among its contacts (refs[b].z), with Gauss-Seidel it is whole.
Side loadSide(int b) {
  Side s;
  s.v = s.w = s.dp = s.dtheta = vec3(0);
  s.invMass = 0;
  s.invI = mat3(0);
  if (b < 0) return s;
  GpuSolverBody sb = bodies[b];
  s.v = sb.v.xyz;
  s.w = sb.w.xyz;
  s.dp = sb.dp.xyz;
  s.dtheta = sb.dtheta.xyz;
  if ((params[b].flags.x & PHYS_GPU_BODY_DYNAMIC) != 0u) {
    float split = k.jacobi != 0u ? uintBitsToFloat(refs[b].z) : 1.0;
    s.invMass = params[b].accel.w * split;
    s.invI = transpose(mat3(sb.invI[0].xyz, sb.invI[1].xyz, sb.invI[2].xyz)) * split;
  }
  return s;
}

// A row: J = (linA, angA, linB, angB) = (-axis, -rA x axis, axis, rB x axis).
float rowVelocity(vec3 axis, vec3 rA, vec3 rB, vec3 va, vec3 wa, vec3 vb, vec3 wb) {
  return dot(-axis, va) + dot(-cross(rA, axis), wa) + dot(axis, vb) + dot(cross(rB, axis), wb);
}
float rowError(float C0, vec3 axis, vec3 rA, vec3 rB, Side A, Side B) {
  return C0 + dot(-axis, A.dp) + dot(-cross(rA, axis), A.dtheta) + dot(axis, B.dp) +
         dot(cross(rB, axis), B.dtheta);
}
void applyRow(float impulse, vec3 axis, vec3 rA, vec3 rB, Side A, Side B, inout vec3 va,
              inout vec3 wa, inout vec3 vb, inout vec3 wb) {
  va += -axis * (A.invMass * impulse);
  wa += (A.invI * -cross(rA, axis)) * impulse;
  vb += axis * (B.invMass * impulse);
  wb += (B.invI * cross(rB, axis)) * impulse;
}
float effectiveMass(vec3 axis, vec3 rA, vec3 rB, Side A, Side B) {
  vec3 angA = -cross(rA, axis), angB = cross(rB, axis);
  float k = dot(axis, axis) * A.invMass + dot(angA, A.invI * angA) + dot(axis, axis) * B.invMass +
            dot(angB, B.invI * angB);
  return k > 1e-12 ? 1.0 / k : 0.0;
}

// The twist row of patch friction: J = (0, -n, 0, n).
void applyTwist(float impulse, vec3 n, Side A, Side B, inout vec3 wa, inout vec3 wb) {
  wa += (A.invI * -n) * impulse;
  wb += (B.invI * n) * impulse;
}

vec3 linearAccel(int b) {
  if (b < 0 || (params[b].flags.x & PHYS_GPU_BODY_DYNAMIC) == 0u) return vec3(0);
  return params[b].accel.xyz;
}

// The passes over one contact, on velocities va, wa, vb, wb of its two bodies, in the
// order of the CPU's rows (World::Impl::contactRowsOf): the normal rows of its points, then
// the friction pair of each point, or the patch's tangent pair and twist row.

// WarmStart: record the approach speed for restitution and apply the impulses
// (Solver::warmStartGroup).
void warmStartContact(inout GpuContact c, Side A, Side B, inout vec3 va, inout vec3 wa,
                      inout vec3 vb, inout vec3 wb) {
  vec3 n = c.normal.xyz;
  for (uint p = 0u; p < c.count; ++p) {
    vec3 rA = c.rA[p].xyz, rB = c.rB[p].xyz;
    // The fastest approach seen at a substep's start; while apart, extrapolated to the
    // moment of contact with the bodies' constant accelerations.
    float vn = rowVelocity(n, rA, rB, va, wa, vb, wb);
    float C = rowError(c.rA[p].w, n, rA, rB, A, B);
    float an = dot(-n, linearAccel(c.bodyA)) + dot(n, linearAccel(c.bodyB));
    if (vn < 0 && C > 0 && an < 0) vn = -sqrt(vn * vn - 2 * an * C);
    c.rB[p].w = min(c.rB[p].w, vn);
    if (c.lambdaN[p] != 0) applyRow(c.lambdaN[p], n, rA, rB, A, B, va, wa, vb, wb);
  }
  if (c.patchRB.w != 0) {
    vec3 pa = c.patchRA.xyz, pb = c.patchRB.xyz;
    if (c.lambdaT1[0] != 0) applyRow(c.lambdaT1[0], c.t1.xyz, pa, pb, A, B, va, wa, vb, wb);
    if (c.lambdaT2[0] != 0) applyRow(c.lambdaT2[0], c.t2.xyz, pa, pb, A, B, va, wa, vb, wb);
    if (c.lambdaT1[1] != 0) applyTwist(c.lambdaT1[1], n, A, B, wa, wb);
    return;
  }
  for (uint p = 0u; p < c.count; ++p) {
    vec3 rA = c.rA[p].xyz, rB = c.rB[p].xyz;
    if (c.lambdaT1[p] != 0) applyRow(c.lambdaT1[p], c.t1.xyz, rA, rB, A, B, va, wa, vb, wb);
    if (c.lambdaT2[p] != 0) applyRow(c.lambdaT2[p], c.t2.xyz, rA, rB, A, B, va, wa, vb, wb);
  }
}

// Both tangent impulses at once, clamped to the friction disc (Solver::solveFrictionPair).
void frictionPair(inout float lambda1, inout float lambda2, float mass1, float mass2,
                  float bound, vec3 t1, vec3 t2, vec3 rA, vec3 rB, Side A, Side B,
                  inout vec3 va, inout vec3 wa, inout vec3 vb, inout vec3 wb) {
  float l1 = lambda1 - mass1 * rowVelocity(t1, rA, rB, va, wa, vb, wb);
  float l2 = lambda2 - mass2 * rowVelocity(t2, rA, rB, va, wa, vb, wb);
  float len2 = l1 * l1 + l2 * l2;
  if (len2 > bound * bound) {
    float s = len2 > 0 ? bound / sqrt(len2) : 0.0;
    l1 *= s;
    l2 *= s;
  }
  float d1 = l1 - lambda1, d2 = l2 - lambda2;
  lambda1 = l1;
  lambda2 = l2;
  if (d1 != 0) applyRow(d1, t1, rA, rB, A, B, va, wa, vb, wb);
  if (d2 != 0) applyRow(d2, t2, rA, rB, A, B, va, wa, vb, wb);
}

// Solve (useBias) or Relax: one pass over the contact's rows (Solver::solveGroup).
void solveContact(inout GpuContact c, Side A, Side B, bool useBias, inout vec3 va,
                  inout vec3 wa, inout vec3 vb, inout vec3 wb) {
  vec3 n = c.normal.xyz;
  for (uint p = 0u; p < c.count; ++p) {
    vec3 rA = c.rA[p].xyz, rB = c.rB[p].xyz;
    float vn = rowVelocity(n, rA, rB, va, wa, vb, wb);
    float C = rowError(c.rA[p].w, n, rA, rB, A, B);
    float bias = 0, massScale = 1, impulseScale = 0;
    if (C > 0) {
      bias = C * k.invH;  // speculative: close exactly the gap this substep, no more
    } else if (useBias) {
      float slop = k.soft != 0u ? 0.0 : k.linearSlop;
      float Cs = min(0.0, C + slop);
      if (splitActive) Cs = max(Cs, -PHYS_GPU_SPLIT_DEPTH);
      bias = max(k.biasRate * Cs, -k.maxPushout);
      massScale = k.massScale;
      impulseScale = k.impulseScale;
    }
    float impulse = -c.massN[p] * massScale * (vn + bias) - impulseScale * c.lambdaN[p];
    float next = max(c.lambdaN[p] + impulse, 0.0);
    impulse = next - c.lambdaN[p];
    c.lambdaN[p] = next;
    c.maxLambdaN[p] = max(c.maxLambdaN[p], next);
    if (impulse != 0) applyRow(impulse, n, rA, rB, A, B, va, wa, vb, wb);
  }
  if (c.patchRB.w != 0) {
    float load = 0;
    for (uint p = 0u; p < c.count; ++p) load += c.lambdaN[p];
    frictionPair(c.lambdaT1[0], c.lambdaT2[0], c.massT1[0], c.massT2[0], c.friction * load,
                 c.t1.xyz, c.t2.xyz, c.patchRA.xyz, c.patchRB.xyz, A, B, va, wa, vb, wb);
    float bound = c.friction * c.patchRA.w * load;
    float vn = dot(-n, wa) + dot(n, wb);
    float next = clamp(c.lambdaT1[1] - c.massT1[1] * vn, -bound, bound);
    float impulse = next - c.lambdaT1[1];
    c.lambdaT1[1] = next;
    if (impulse != 0) applyTwist(impulse, n, A, B, wa, wb);
    return;
  }
  for (uint p = 0u; p < c.count; ++p) {
    float lt1 = c.lambdaT1[p], lt2 = c.lambdaT2[p];
    frictionPair(lt1, lt2, c.massT1[p], c.massT2[p], c.friction * c.lambdaN[p], c.t1.xyz,
                 c.t2.xyz, c.rA[p].xyz, c.rB[p].xyz, A, B, va, wa, vb, wb);
    c.lambdaT1[p] = lt1;
    c.lambdaT2[p] = lt2;
  }
}

// Split push-out (Solver::solvePushout, pushoutGroup): on the pseudo velocities va..wb
// alone, which start at zero each substep. First the last substep's push impulses again
// (none at a step's first substep), then passes of the soft position bias of the depth
// beyond PHYS_GPU_SPLIT_DEPTH, each point's impulse kept >= 0.
void pushWarmStartContact(GpuContact c, Side A, Side B, inout vec3 va, inout vec3 wa,
                          inout vec3 vb, inout vec3 wb) {
  for (uint p = 0u; p < c.count; ++p)
    if (c.pushLambda[p] != 0)
      applyRow(c.pushLambda[p], c.normal.xyz, c.rA[p].xyz, c.rB[p].xyz, A, B, va, wa, vb, wb);
}
void pushoutContact(inout GpuContact c, Side A, Side B, inout vec3 va, inout vec3 wa,
                    inout vec3 vb, inout vec3 wb) {
  vec3 n = c.normal.xyz;
  for (uint p = 0u; p < c.count; ++p) {
    vec3 rA = c.rA[p].xyz, rB = c.rB[p].xyz;
    float C = rowError(c.rA[p].w, n, rA, rB, A, B) + PHYS_GPU_SPLIT_DEPTH;
    if (C >= 0 && c.pushLambda[p] == 0) continue;
    float bias = 0, massScale = 1, impulseScale = 0;
    if (C < 0) {
      bias = max(k.biasRate * C, -k.maxPushout);
      massScale = k.massScale;
      impulseScale = k.impulseScale;
    }
    float vn = rowVelocity(n, rA, rB, va, wa, vb, wb);
    float impulse = -c.massN[p] * massScale * (vn + bias) - impulseScale * c.pushLambda[p];
    float next = max(c.pushLambda[p] + impulse, 0.0);
    impulse = next - c.pushLambda[p];
    c.pushLambda[p] = next;
    if (impulse != 0) applyRow(impulse, n, rA, rB, A, B, va, wa, vb, wb);
  }
}

// Restitution: points that approached faster than the threshold and carried load bounce
// with e times their approach speed (Solver::restitutionGroup).
void restituteContact(inout GpuContact c, Side A, Side B, inout vec3 va, inout vec3 wa,
                      inout vec3 vb, inout vec3 wb) {
  vec3 n = c.normal.xyz;
  float e = c.normal.w;
  if (e == 0) return;
  for (uint p = 0u; p < c.count; ++p) {
    float approach = c.rB[p].w;
    if (approach > -k.restitutionThreshold || c.maxLambdaN[p] == 0) continue;
    vec3 rA = c.rA[p].xyz, rB = c.rB[p].xyz;
    float vn = rowVelocity(n, rA, rB, va, wa, vb, wb);
    float impulse = -c.massN[p] * (vn + e * approach);
    float next = max(c.lambdaN[p] + impulse, 0.0);
    impulse = next - c.lambdaN[p];
    c.lambdaN[p] = next;
    c.maxLambdaN[p] = max(c.maxLambdaN[p], next);
    if (impulse != 0) applyRow(impulse, n, rA, rB, A, B, va, wa, vb, wb);
  }
}

// The position pass (post-stabilization, Solver::positionPass): each normal row's error
// at the current poses (linearized from the accumulated deltas) removed by a fraction, as
// a displacement; velocities untouched. Adds the contact's displacements of its two bodies
// (linear, rotation vector) from the poses in A and B to dpA..dthB.
void positionContact(GpuContact c, Side A, Side B, inout vec3 dpA, inout vec3 dthA,
                     inout vec3 dpB, inout vec3 dthB) {
  vec3 n = c.normal.xyz;
  for (uint p = 0u; p < c.count; ++p) {
    vec3 rA = c.rA[p].xyz, rB = c.rB[p].xyz;
    float C = rowError(c.rA[p].w, n, rA, rB, A, B);
    float d = -c.massN[p] * clamp(k.positionBaumgarte * (C + k.linearSlop),
                                  -k.maxPositionCorrection, 0.0);
    if (d == 0) continue;
    dpA += -n * (A.invMass * d);
    dthA += (A.invI * -cross(rA, n)) * d;
    dpB += n * (B.invMass * d);
    dthB += (B.invI * cross(rB, n)) * d;
  }
}

#endif
