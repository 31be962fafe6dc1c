// GLSL helpers shared by the step's kernels: the quaternion and matrix math of
// physics/defs/include/phys/defs/math.h, formula for formula, so the two backends round alike.
#ifndef PHYS_GPU_COMMON_GLSL
#define PHYS_GPU_COMMON_GLSL

// Linear thread and workgroup indices: Stream::dispatch spreads more workgroups than a
// dimension holds (65535 on some devices) over y.
uint globalIndex() {
  return gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * gl_WorkGroupSize.x;
}
uint groupIndex() { return gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x; }

vec4 quatMul(vec4 a, vec4 b) {
  return vec4(a.w * b.x + a.x * b.w + a.y * b.z - a.z * b.y,
              a.w * b.y - a.x * b.z + a.y * b.w + a.z * b.x,
              a.w * b.z + a.x * b.y - a.y * b.x + a.z * b.w,
              a.w * b.w - a.x * b.x - a.y * b.y - a.z * b.z);
}
vec4 quatConj(vec4 q) { return vec4(-q.xyz, q.w); }
// Normalized in double, as on the CPU (float normalization drifts spinning bodies' momentum).
vec4 quatNormalize(vec4 q) {
  dvec4 d = dvec4(q);
  double l2 = dot(d, d);
  if (l2 < 1e-30) return vec4(0, 0, 0, 1);
  return vec4(d * (1.0lf / sqrt(l2)));
}
vec3 quatRotate(vec4 q, vec3 v) {
  vec3 t = 2.0 * cross(q.xyz, v);
  return v + q.w * t + cross(q.xyz, t);
}
vec3 quatInvRotate(vec4 q, vec3 v) { return quatRotate(quatConj(q), v); }
// q advanced by angular velocity w (world) over h: q + 0.5 h (w, 0) q, normalized.
vec4 integrateRotation(vec4 q, vec3 w, float h) {
  vec4 dq = quatMul(vec4(w, 0), q);
  return quatNormalize(q + (0.5 * h) * dq);
}
// Rotation vector (axis * angle, angle in [0, pi]) of a unit quaternion.
vec3 rotationVector(vec4 q) {
  if (q.w < 0) q = -q;
  float s = length(q.xyz);
  if (s < 1e-12) return q.xyz * 2.0;
  return q.xyz * (2.0 * atan(s, q.w) / s);
}
float copysignf(float mag, float sgn) {
  return uintBitsToFloat((floatBitsToUint(mag) & 0x7FFFFFFFu) |
                         (floatBitsToUint(sgn) & 0x80000000u));
}
// phys::tangentBasis: Pixar's branchless orthonormal basis (Duff et al. 2017).
void tangentBasis(vec3 n, out vec3 t1, out vec3 t2) {
  float sgn = copysignf(1.0, n.z);
  float a = -1.0 / (sgn + n.z);
  float b = n.x * n.y * a;
  t1 = vec3(1.0 + sgn * n.x * n.x * a, sgn * b, -sgn * n.x);
  t2 = vec3(b, sgn + n.y * n.y * a, -n.y);
}
// Column-major 3x3 from a quaternion (GLSL mat3 is column-major, as phys::Mat3).
mat3 quatToMat3(vec4 q) {
  return mat3(quatRotate(q, vec3(1, 0, 0)), quatRotate(q, vec3(0, 1, 0)),
              quatRotate(q, vec3(0, 0, 1)));
}

#endif
