// Shapes' mass properties and bounds.
#include <cmath>

#include "phys/collision/shapes.h"

namespace phys {

namespace {

// Hull mass properties by tetrahedra from an interior point: each tetrahedron's second moment
// has a closed form (the covariance approach of Blow & Binstock 2004), summed in double.
MassProperties hullMass(const ConvexHull& h, double density) {
  MassProperties mp;
  if (h.vertices.empty()) return mp;
  double ref[3] = {0, 0, 0};
  for (const Vec3& v : h.vertices)
    for (int k = 0; k < 3; ++k) ref[k] += v[k];
  for (int k = 0; k < 3; ++k) ref[k] /= static_cast<double>(h.vertices.size());
  double vol = 0, mom[3] = {0, 0, 0}, cov[3][3] = {};
  for (const auto& f : h.faces) {
    for (size_t i = 1; i + 1 < f.indices.size(); ++i) {
      double w[3][3];
      const Vec3* p[3] = {&h.vertices[f.indices[0]], &h.vertices[f.indices[i]],
                          &h.vertices[f.indices[i + 1]]};
      for (int r = 0; r < 3; ++r)
        for (int k = 0; k < 3; ++k) w[r][k] = (*p[r])[k] - ref[k];
      double det = w[0][0] * (w[1][1] * w[2][2] - w[1][2] * w[2][1]) -
                   w[0][1] * (w[1][0] * w[2][2] - w[1][2] * w[2][0]) +
                   w[0][2] * (w[1][0] * w[2][1] - w[1][1] * w[2][0]);
      double v = det / 6.0;
      vol += v;
      double s[3];
      for (int k = 0; k < 3; ++k) {
        s[k] = w[0][k] + w[1][k] + w[2][k];
        mom[k] += v * s[k] / 4.0;
      }
      // Integral of x x^T over the tetrahedron (0, w0, w1, w2): det/120 (sum w w^T + s s^T).
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c)
          cov[r][c] += det / 120.0 *
                       (w[0][r] * w[0][c] + w[1][r] * w[1][c] + w[2][r] * w[2][c] + s[r] * s[c]);
    }
  }
  if (!(vol > 0)) return mp;
  double m = density * vol;
  double com[3];
  for (int k = 0; k < 3; ++k) com[k] = mom[k] / vol;
  double c[3][3], tr = 0;
  for (int r = 0; r < 3; ++r)
    for (int k = 0; k < 3; ++k) c[r][k] = density * cov[r][k] - m * com[r] * com[k];
  for (int k = 0; k < 3; ++k) tr += c[k][k];
  Mat3 inertia;
  for (int col = 0; col < 3; ++col) {
    Vec3 v;
    for (int row = 0; row < 3; ++row)
      v[row] = static_cast<float>((row == col ? tr : 0.0) - c[row][col]);
    (col == 0 ? inertia.c0 : col == 1 ? inertia.c1 : inertia.c2) = v;
  }
  mp.mass = static_cast<float>(m);
  mp.center = {static_cast<float>(ref[0] + com[0]), static_cast<float>(ref[1] + com[1]),
               static_cast<float>(ref[2] + com[2])};
  mp.inertia = inertia;
  return mp;
}

}  // namespace

MassProperties computeMass(const ShapeGeom& g, float density) {
  MassProperties mp;
  switch (g.type) {
    case ShapeType::Sphere: {
      float r = g.radius;
      mp.mass = density * (4.0f / 3.0f) * kPi * r * r * r;
      mp.inertia = Mat3::diagonal(Vec3{1, 1, 1} * (0.4f * mp.mass * r * r));
      return mp;
    }
    case ShapeType::Box: {
      Vec3 h = g.halfExtents;
      mp.mass = density * 8.0f * h.x * h.y * h.z;
      float k = mp.mass / 3.0f;
      mp.inertia = Mat3::diagonal(
          {k * (h.y * h.y + h.z * h.z), k * (h.x * h.x + h.z * h.z), k * (h.x * h.x + h.y * h.y)});
      return mp;
    }
    case ShapeType::Capsule: {
      // Cylinder of height 2 hh plus two hemispheres whose centres of mass sit 3r/8 beyond the
      // cylinder's ends (parallel-axis terms about the capsule's centre).
      double r = g.radius, hh = g.halfHeight, h = 2 * hh;
      double mc = density * kPi * r * r * h;
      double ms = density * (4.0 / 3.0) * kPi * r * r * r;  // both hemispheres
      double izz = mc * r * r / 2 + ms * 0.4 * r * r;
      double ixx = mc * (h * h / 12 + r * r / 4) + ms * (0.4 * r * r + h * h / 4 + 3 * h * r / 8);
      mp.mass = static_cast<float>(mc + ms);
      mp.inertia = Mat3::diagonal(
          {static_cast<float>(ixx), static_cast<float>(ixx), static_cast<float>(izz)});
      return mp;
    }
    case ShapeType::Plane:
      mp.inertia = Mat3::zero();
      return mp;
    case ShapeType::Hull:
      if (!g.hull) {
        mp.inertia = Mat3::zero();
        return mp;
      }
      mp = hullMass(*g.hull, density);
      if (mp.mass == 0) mp.inertia = Mat3::zero();
      return mp;
  }
  mp.inertia = Mat3::zero();
  return mp;
}

AABB computeAABB(const ShapeGeom& g, const Transform& xf) {
  switch (g.type) {
    case ShapeType::Sphere: {
      Vec3 r{g.radius, g.radius, g.radius};
      return {xf.p - r, xf.p + r};
    }
    case ShapeType::Box: {
      Mat3 m = toMat3(xf.q);
      Vec3 e = vabs(m.c0) * g.halfExtents.x + vabs(m.c1) * g.halfExtents.y +
               vabs(m.c2) * g.halfExtents.z;
      return {xf.p - e, xf.p + e};
    }
    case ShapeType::Capsule: {
      Vec3 a = rotate(xf.q, Vec3{0, 0, g.halfHeight});
      Vec3 r{g.radius, g.radius, g.radius};
      return {vmin(xf.p - a, xf.p + a) - r, vmax(xf.p - a, xf.p + a) + r};
    }
    case ShapeType::Plane: {
      // The solid half-space dot(n, x) <= d clipped to the cube [-H, H]^3: tight on an axis the
      // normal is aligned with (a z-up floor gets hi.z = d), else the cube.
      constexpr float kH = 1e6f;
      Vec3 n = rotate(xf.q, g.normal);
      float d = g.offset + dot(n, xf.p);
      AABB box{{-kH, -kH, -kH}, {kH, kH, kH}};
      for (int i = 0; i < 3; ++i) {
        float rest = std::fabs(n[(i + 1) % 3]) + std::fabs(n[(i + 2) % 3]);
        if (n[i] > 0) {
          box.hi[i] = std::fmax(-kH, std::fmin(kH, (d + kH * rest) / n[i]));
        } else if (n[i] < 0) {
          box.lo[i] = std::fmin(kH, std::fmax(-kH, (d + kH * rest) / n[i]));
        }
      }
      return box;
    }
    case ShapeType::Hull: {
      if (!g.hull || g.hull->vertices.empty()) return {xf.p, xf.p};
      Mat3 m = toMat3(xf.q);
      Vec3 lo = m * g.hull->vertices[0], hi = lo;
      for (const Vec3& v : g.hull->vertices) {
        Vec3 w = m * v;
        lo = vmin(lo, w);
        hi = vmax(hi, w);
      }
      return {xf.p + lo, xf.p + hi};
    }
  }
  return {xf.p, xf.p};
}

}  // namespace phys
