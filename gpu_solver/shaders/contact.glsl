// The contact solver's shared part: a body's solver state as a contact sees it (the static
// world when the index is -1), and the rows' Jacobians, as the CPU's contactRow.
#ifndef PHYS_GPU_CONTACT_GLSL
#define PHYS_GPU_CONTACT_GLSL

struct Side {
  vec3 v, w, dp, dtheta;
  float invMass;  // split: the body's inverse mass times its contact count (Jacobi)
  mat3 invI;      // split likewise
};

// Needs bindings `bodies` (GpuSolverBody), `params` (GpuBodyParams), `refs` (uvec4).
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
    float split = uintBitsToFloat(refs[b].z);
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

#endif
