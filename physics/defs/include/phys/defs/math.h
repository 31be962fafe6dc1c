// Small float32 vector, quaternion and 3x3 matrix types used throughout the engine.
// float32 on purpose: the GPU backend uses the same precision, so the two can be compared.
#pragma once

#include <cmath>
#include <cstdint>

namespace phys {

struct Vec3 {
  float x = 0, y = 0, z = 0;
  constexpr Vec3() = default;
  constexpr Vec3(float x_, float y_, float z_) : x(x_), y(y_), z(z_) {}
  float& operator[](int i) { return (&x)[i]; }
  float operator[](int i) const { return (&x)[i]; }
};

inline constexpr Vec3 operator+(Vec3 a, Vec3 b) {
  return {a.x + b.x, a.y + b.y, a.z + b.z};
}
inline constexpr Vec3 operator-(Vec3 a, Vec3 b) {
  return {a.x - b.x, a.y - b.y, a.z - b.z};
}
inline constexpr Vec3 operator-(Vec3 a) {
  return {-a.x, -a.y, -a.z};
}
inline constexpr Vec3 operator*(Vec3 a, float s) {
  return {a.x * s, a.y * s, a.z * s};
}
inline constexpr Vec3 operator*(float s, Vec3 a) {
  return {a.x * s, a.y * s, a.z * s};
}
inline constexpr Vec3 operator/(Vec3 a, float s) {
  return {a.x / s, a.y / s, a.z / s};
}
inline Vec3& operator+=(Vec3& a, Vec3 b) {
  return a = a + b;
}
inline Vec3& operator-=(Vec3& a, Vec3 b) {
  return a = a - b;
}
inline Vec3& operator*=(Vec3& a, float s) {
  return a = a * s;
}
inline constexpr bool operator==(Vec3 a, Vec3 b) {
  return a.x == b.x && a.y == b.y && a.z == b.z;
}

inline constexpr float dot(Vec3 a, Vec3 b) {
  return a.x * b.x + a.y * b.y + a.z * b.z;
}
inline constexpr Vec3 cross(Vec3 a, Vec3 b) {
  return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}
inline constexpr Vec3 mulComponents(Vec3 a, Vec3 b) {
  return {a.x * b.x, a.y * b.y, a.z * b.z};
}
inline float lengthSquared(Vec3 a) {
  return dot(a, a);
}
inline float length(Vec3 a) {
  return std::sqrt(dot(a, a));
}
inline Vec3 normalize(Vec3 a) {
  float l = length(a);
  return l > 1e-20f ? a * (1.0f / l) : Vec3{0, 0, 0};
}
inline Vec3 vmin(Vec3 a, Vec3 b) {
  return {std::fmin(a.x, b.x), std::fmin(a.y, b.y), std::fmin(a.z, b.z)};
}
inline Vec3 vmax(Vec3 a, Vec3 b) {
  return {std::fmax(a.x, b.x), std::fmax(a.y, b.y), std::fmax(a.z, b.z)};
}
inline Vec3 vabs(Vec3 a) {
  return {std::fabs(a.x), std::fabs(a.y), std::fabs(a.z)};
}
inline bool isFinite(Vec3 a) {
  return std::isfinite(a.x) && std::isfinite(a.y) && std::isfinite(a.z);
}

/// Two unit vectors t1, t2 with (n, t1, t2) right-handed and orthonormal; deterministic in n.
inline void tangentBasis(Vec3 n, Vec3* t1, Vec3* t2) {
  // Pixar's branchless ONB (Duff et al. 2017).
  float sign = std::copysign(1.0f, n.z);
  float a = -1.0f / (sign + n.z);
  float b = n.x * n.y * a;
  *t1 = {1.0f + sign * n.x * n.x * a, sign * b, -sign * n.x};
  *t2 = {b, sign + n.y * n.y * a, -n.y};
}

/// Column-major 3x3 matrix.
struct Mat3 {
  Vec3 c0{1, 0, 0}, c1{0, 1, 0}, c2{0, 0, 1};
  static constexpr Mat3 zero() { return {{0, 0, 0}, {0, 0, 0}, {0, 0, 0}}; }
  static constexpr Mat3 diagonal(Vec3 d) { return {{d.x, 0, 0}, {0, d.y, 0}, {0, 0, d.z}}; }
  Vec3 row(int i) const { return {c0[i], c1[i], c2[i]}; }
};
inline Vec3 operator*(const Mat3& m, Vec3 v) {
  return m.c0 * v.x + m.c1 * v.y + m.c2 * v.z;
}
inline Mat3 operator*(const Mat3& a, const Mat3& b) {
  return {a * b.c0, a * b.c1, a * b.c2};
}
inline Mat3 operator+(const Mat3& a, const Mat3& b) {
  return {a.c0 + b.c0, a.c1 + b.c1, a.c2 + b.c2};
}
inline Mat3 operator-(const Mat3& a, const Mat3& b) {
  return {a.c0 - b.c0, a.c1 - b.c1, a.c2 - b.c2};
}
inline Mat3 operator*(const Mat3& a, float s) {
  return {a.c0 * s, a.c1 * s, a.c2 * s};
}
inline Mat3 transpose(const Mat3& m) {
  return {m.row(0), m.row(1), m.row(2)};
}
inline Mat3 skew(Vec3 v) {
  return {{0, v.z, -v.y}, {-v.z, 0, v.x}, {v.y, -v.x, 0}};
}
inline Mat3 outer(Vec3 a, Vec3 b) {
  return {a * b.x, a * b.y, a * b.z};
}
inline float determinant(const Mat3& m) {
  return dot(m.c0, cross(m.c1, m.c2));
}
/// Inverse; returns zero for a singular matrix (a static body's inverse inertia).
inline Mat3 inverse(const Mat3& m) {
  float det = determinant(m);
  if (std::fabs(det) < 1e-30f) return Mat3::zero();
  float inv = 1.0f / det;
  Vec3 r0 = cross(m.c1, m.c2) * inv, r1 = cross(m.c2, m.c0) * inv, r2 = cross(m.c0, m.c1) * inv;
  return transpose(Mat3{r0, r1, r2});
}

/// Unit quaternion (x, y, z vector part; w scalar part).
struct Quat {
  float x = 0, y = 0, z = 0, w = 1;
  static Quat fromAxisAngle(Vec3 axis, float angle) {
    Vec3 a = normalize(axis) * std::sin(0.5f * angle);
    return {a.x, a.y, a.z, std::cos(0.5f * angle)};
  }
};
inline constexpr bool operator==(Quat a, Quat b) {
  return a.x == b.x && a.y == b.y && a.z == b.z && a.w == b.w;
}
inline Quat operator*(Quat a, Quat b) {
  return {
      a.w * b.x + a.x * b.w + a.y * b.z - a.z * b.y, a.w * b.y - a.x * b.z + a.y * b.w + a.z * b.x,
      a.w * b.z + a.x * b.y - a.y * b.x + a.z * b.w, a.w * b.w - a.x * b.x - a.y * b.y - a.z * b.z};
}
inline Quat conjugate(Quat q) {
  return {-q.x, -q.y, -q.z, q.w};
}
inline float lengthSquared(Quat q) {
  return q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w;
}
inline Quat normalize(Quat q) {
  // In double: float normalization lands on the long side of 1 more often than not, and
  // rotate() scales by |q|^2, so a float version makes spinning bodies gain momentum.
  double l2 = double(q.x) * q.x + double(q.y) * q.y + double(q.z) * q.z + double(q.w) * q.w;
  if (l2 < 1e-30) return {};
  double inv = 1.0 / std::sqrt(l2);
  return {float(q.x * inv), float(q.y * inv), float(q.z * inv), float(q.w * inv)};
}
inline bool isFinite(Quat q) {
  return std::isfinite(q.x) && std::isfinite(q.y) && std::isfinite(q.z) && std::isfinite(q.w);
}
inline Vec3 rotate(Quat q, Vec3 v) {
  Vec3 u{q.x, q.y, q.z};
  Vec3 t = 2.0f * cross(u, v);
  return v + q.w * t + cross(u, t);
}
inline Vec3 invRotate(Quat q, Vec3 v) {
  return rotate(conjugate(q), v);
}
inline Mat3 toMat3(Quat q) {
  return {rotate(q, {1, 0, 0}), rotate(q, {0, 1, 0}), rotate(q, {0, 0, 1})};
}
/// q advanced by angular velocity w (world frame) over h: q + 0.5 h (w, 0) q, normalized.
inline Quat integrateRotation(Quat q, Vec3 w, float h) {
  Quat dq = Quat{w.x, w.y, w.z, 0} * q;
  float k = 0.5f * h;
  return normalize(Quat{q.x + k * dq.x, q.y + k * dq.y, q.z + k * dq.z, q.w + k * dq.w});
}
/// Rotation vector (axis * angle, angle in [0, pi]) of a unit quaternion.
inline Vec3 rotationVector(Quat q) {
  if (q.w < 0) q = {-q.x, -q.y, -q.z, -q.w};
  Vec3 v{q.x, q.y, q.z};
  float s = length(v);
  if (s < 1e-12f) return v * 2.0f;
  float angle = 2.0f * std::atan2(s, q.w);
  return v * (angle / s);
}

/// Rigid transform: x_world = p + rotate(q, x_local).
struct Transform {
  Vec3 p;
  Quat q;
};
inline Vec3 apply(const Transform& t, Vec3 v) {
  return t.p + rotate(t.q, v);
}
inline Vec3 applyInverse(const Transform& t, Vec3 v) {
  return invRotate(t.q, v - t.p);
}
inline Transform operator*(const Transform& a, const Transform& b) {
  return {apply(a, b.p), normalize(a.q * b.q)};
}

/// Axis-aligned box.
struct AABB {
  Vec3 lo, hi;
};
inline bool overlaps(const AABB& a, const AABB& b) {
  return a.lo.x <= b.hi.x && b.lo.x <= a.hi.x && a.lo.y <= b.hi.y && b.lo.y <= a.hi.y &&
         a.lo.z <= b.hi.z && b.lo.z <= a.hi.z;
}
inline bool contains(const AABB& outer, const AABB& inner) {
  return outer.lo.x <= inner.lo.x && outer.lo.y <= inner.lo.y && outer.lo.z <= inner.lo.z &&
         inner.hi.x <= outer.hi.x && inner.hi.y <= outer.hi.y && inner.hi.z <= outer.hi.z;
}
inline AABB merge(const AABB& a, const AABB& b) {
  return {vmin(a.lo, b.lo), vmax(a.hi, b.hi)};
}
inline AABB inflate(const AABB& a, float m) {
  return {a.lo - Vec3{m, m, m}, a.hi + Vec3{m, m, m}};
}

constexpr float kPi = 3.14159265358979323846f;

}  // namespace phys
