// Joints on the device: their rows built from the bodies' current poses (the CPU's
// buildJointRows / refreshJointRows, physics/dynamics/joints.cpp) and the passes over them (the
// CPU's solveGroup and solveBlock for a joint's rows). Needs contact.glsl (Side, loadSide,
// rowVelocity-like helpers), and the bindings `joints` (GpuJoint), `jointRows`
// (GpuJointRows).
#ifndef PHYS_GPU_JOINT_GLSL
#define PHYS_GPU_JOINT_GLSL

float jrVelocity(GpuJointRow r, vec3 va, vec3 wa, vec3 vb, vec3 wb) {
  return dot(r.linA.xyz, va) + dot(r.angA.xyz, wa) + dot(r.linB.xyz, vb) + dot(r.angB.xyz, wb);
}
float jrError(GpuJointRow r, Side A, Side B) {
  return r.linA.w + dot(r.linA.xyz, A.dp) + dot(r.angA.xyz, A.dtheta) + dot(r.linB.xyz, B.dp) +
         dot(r.angB.xyz, B.dtheta);
}
void jrApply(GpuJointRow r, float impulse, Side A, Side B, inout vec3 va, inout vec3 wa,
             inout vec3 vb, inout vec3 wb) {
  va += r.linA.xyz * (A.invMass * impulse);
  wa += (A.invI * r.angA.xyz) * impulse;
  vb += r.linB.xyz * (B.invMass * impulse);
  wb += (B.invI * r.angB.xyz) * impulse;
}
// K_ab = J_a M^-1 J_b^T (the CPU's coupling(ra, rb)).
float jrCoupling(GpuJointRow a, GpuJointRow b, Side A, Side B) {
  return dot(a.linA.xyz, b.linA.xyz * A.invMass) + dot(a.angA.xyz, A.invI * b.angA.xyz) +
         dot(a.linB.xyz, b.linB.xyz * B.invMass) + dot(a.angB.xyz, B.invI * b.angB.xyz);
}

// Catto's soft constraint (Solver's makeSoftness): (bias rate, mass scale, impulse scale).
vec3 softness(float hertz, float zeta, float h) {
  if (hertz <= 0) return vec3(0, 1, 0);
  float omega = 2 * 3.14159265358979 * hertz;
  float a1 = 2 * zeta + h * omega;
  float a2 = h * omega * a1;
  float a3 = 1 / (1 + a2);
  return vec3(omega / a1, a2 * a3, a3);
}

// One pass over a joint's rows (Solver::solveGroup), on velocities va..wb; equality rows
// only when the joints are not solved directly (GpuSolveConstants.ldlIslands).
void solveJoint(inout GpuJointRows J, Side A, Side B, bool useBias, inout vec3 va,
                inout vec3 wa, inout vec3 vb, inout vec3 wb) {
  for (uint i = 0u; i < J.count;) {
    GpuJointRow r = J.rows[i];
    uint n = r.info.y;
    if (k.ldlIslands != 0u && r.info.x == PHYS_GPU_ROW_EQUALITY) {
      i += max(n, 1u);  // the direct solve's (joint_ldl.comp), as Solver's skipEquality
      continue;
    }
    if (n > 1u) {
      // The block's rows at once: d = -K^-1 (J v + bias) scaled, minus the soft decay.
      uint slot = i == 0u ? 0u : 3u;
      mat3 invK = transpose(mat3(J.invK[slot].xyz, J.invK[slot + 1u].xyz, J.invK[slot + 2u].xyz));
      vec3 err = vec3(0), lambda = vec3(0);
      for (uint a = 0u; a < n; ++a) {
        GpuJointRow ra = J.rows[i + a];
        err[a] = jrVelocity(ra, va, wa, vb, wb) +
                 (useBias ? k.jointBiasRate * jrError(ra, A, B) : 0.0);
        lambda[a] = ra.angA.w;
      }
      float massScale = useBias ? k.jointMassScale : 1.0;
      float impulseScale = useBias ? k.jointImpulseScale : 0.0;
      vec3 d = invK * err * -massScale - lambda * impulseScale;
      for (uint a = 0u; a < n; ++a) {
        J.rows[i + a].angA.w += d[a];
        if (d[a] != 0) jrApply(J.rows[i + a], d[a], A, B, va, wa, vb, wb);
      }
      i += n;
      continue;
    }
    float vn = jrVelocity(r, va, wa, vb, wb);
    float lambda = r.angA.w, effMass = r.linB.w;
    float impulse = 0;
    if (r.info.x == PHYS_GPU_ROW_LIMIT) {
      // As a contact's normal row: speculative while apart, soft push-out when past.
      float C = jrError(r, A, B);
      float bias = 0, massScale = 1, impulseScale = 0;
      if (C > 0) {
        bias = C * k.invH;
      } else if (useBias) {
        bias = max(k.biasRate * min(0.0, C), -k.maxPushout);
        massScale = k.massScale;
        impulseScale = k.impulseScale;
      }
      impulse = -effMass * massScale * (vn + bias) - impulseScale * lambda;
      float next = max(lambda + impulse, 0.0);
      impulse = next - lambda;
      lambda = next;
    } else if (r.info.x == PHYS_GPU_ROW_EQUALITY) {
      float bias = 0, massScale = 1, impulseScale = 0;
      if (useBias) {
        bias = k.jointBiasRate * jrError(r, A, B);
        massScale = k.jointMassScale;
        impulseScale = k.jointImpulseScale;
      }
      impulse = -effMass * massScale * (vn + bias) - impulseScale * lambda;
      lambda += impulse;
    } else if (r.info.x == PHYS_GPU_ROW_SPRING) {
      // A spring is soft in both passes: it is the physics, not an error correction.
      vec3 sp = softness(uintBitsToFloat(r.info.z), uintBitsToFloat(r.info.w), k.h);
      impulse = -effMass * sp.y * (vn + sp.x * jrError(r, A, B)) - sp.z * lambda;
      lambda += impulse;
    } else {  // PHYS_GPU_ROW_MOTOR
      float maxImpulse = uintBitsToFloat(r.info.w);
      impulse = -effMass * (vn - uintBitsToFloat(r.info.z));
      float next = clamp(lambda + impulse, -maxImpulse, maxImpulse);
      impulse = next - lambda;
      lambda = next;
    }
    J.rows[i].angA.w = lambda;
    if (impulse != 0) jrApply(r, impulse, A, B, va, wa, vb, wb);
    ++i;
  }
}

void warmStartJoint(GpuJointRows J, Side A, Side B, inout vec3 va, inout vec3 wa, inout vec3 vb,
                    inout vec3 wb) {
  for (uint i = 0u; i < J.count; ++i)
    if (J.rows[i].angA.w != 0) jrApply(J.rows[i], J.rows[i].angA.w, A, B, va, wa, vb, wb);
}

// The position pass's correction of one row (Solver::positionPass): equality rows both
// ways, limits only when past them; others none.
float positionCorrection(GpuJointRow r, Side A, Side B) {
  float C = jrError(r, A, B);
  if (r.info.x == PHYS_GPU_ROW_EQUALITY)
    return -r.linB.w * clamp(k.positionBaumgarte * C, -k.maxPositionCorrection,
                             k.maxPositionCorrection);
  if (r.info.x == PHYS_GPU_ROW_LIMIT)
    return -r.linB.w * clamp(k.positionBaumgarte * C, -k.maxPositionCorrection, 0.0);
  return 0;
}

// The joint's corrections from the poses in A and B (Jacobi: all rows from the same poses).
void positionJoint(GpuJointRows J, Side A, Side B, inout vec3 dpA, inout vec3 dthA,
                   inout vec3 dpB, inout vec3 dthB) {
  for (uint i = 0u; i < J.count; ++i) {
    GpuJointRow r = J.rows[i];
    float d = positionCorrection(r, A, B);
    if (d == 0) continue;
    dpA += r.linA.xyz * (A.invMass * d);
    dthA += (A.invI * r.angA.xyz) * d;
    dpB += r.linB.xyz * (B.invMass * d);
    dthB += (B.invI * r.angB.xyz) * d;
  }
}

#endif
