// Mass properties against textbook formulas and independent integration; bounds of each shape.
#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "phys/collision/shapes.h"

namespace phys {
namespace {

void expectMatNear(const Mat3& a, const Mat3& b, float relTol) {
  float scale = 0;
  for (int c = 0; c < 3; ++c)
    for (int r = 0; r < 3; ++r) scale = std::fmax(scale, std::fabs(b.row(r)[c]));
  for (int c = 0; c < 3; ++c)
    for (int r = 0; r < 3; ++r)
      EXPECT_NEAR(a.row(r)[c], b.row(r)[c], relTol * scale) << "entry " << r << "," << c;
}

std::shared_ptr<const ConvexHull> boxHull(Vec3 he, const Transform& xf = {}) {
  std::vector<Vec3> pts;
  for (int i = 0; i < 8; ++i)
    pts.push_back(
        apply(xf, {(i & 1) ? he.x : -he.x, (i & 2) ? he.y : -he.y, (i & 4) ? he.z : -he.z}));
  std::string err;
  auto h = buildConvexHull(pts, &err);
  EXPECT_NE(h, nullptr) << err;
  return h;
}

TEST(ShapeMass, Sphere) {
  float r = 0.3f, rho = 800;
  MassProperties mp = computeMass(ShapeGeom::sphere(r), rho);
  float m = rho * 4.0f / 3.0f * kPi * r * r * r;
  EXPECT_NEAR(mp.mass, m, 1e-5f * m);
  expectMatNear(mp.inertia, Mat3::diagonal(Vec3{1, 1, 1} * (0.4f * m * r * r)), 1e-6f);
  EXPECT_EQ(mp.center, (Vec3{0, 0, 0}));
}

TEST(ShapeMass, Box) {
  Vec3 he{0.5f, 1.0f, 1.5f};
  float rho = 1000;
  MassProperties mp = computeMass(ShapeGeom::box(he), rho);
  float w = 1, h = 2, d = 3, m = rho * w * h * d;
  EXPECT_NEAR(mp.mass, m, 1e-3f);
  // Full-extent textbook form m/12 (b^2 + c^2).
  expectMatNear(mp.inertia,
                Mat3::diagonal(
                    {m / 12 * (h * h + d * d), m / 12 * (w * w + d * d), m / 12 * (w * w + h * h)}),
                1e-6f);
}

// Capsule against slicing it into discs along z and integrating numerically (Simpson).
TEST(ShapeMass, CapsuleMatchesIntegration) {
  for (auto [r, hh] : {std::pair{0.2f, 0.5f}, std::pair{0.5f, 0.1f}, std::pair{0.3f, 1.0f}}) {
    float rho = 500;
    MassProperties mp = computeMass(ShapeGeom::capsule(r, hh), rho);
    double R = r, H = hh, top = H + R;
    const int n = 20000;
    double dz = 2 * top / n, m = 0, ixx = 0, izz = 0;
    for (int i = 0; i <= n; ++i) {
      double z = -top + i * dz;
      double az = std::fabs(z);
      double rad2 = az <= H ? R * R : std::fmax(0.0, R * R - (az - H) * (az - H));
      double w = (i == 0 || i == n) ? 1 : (i % 2 ? 4 : 2);
      double dm = rho * kPi * rad2;  // mass per unit length
      m += w * dm;
      izz += w * dm * rad2 / 2;
      ixx += w * dm * (rad2 / 4 + z * z);
    }
    m *= dz / 3;
    izz *= dz / 3;
    ixx *= dz / 3;
    EXPECT_NEAR(mp.mass, m, 1e-4 * m);
    expectMatNear(
        mp.inertia,
        Mat3::diagonal({static_cast<float>(ixx), static_cast<float>(ixx), static_cast<float>(izz)}),
        1e-4f);
  }
  // A capsule with no segment is a sphere.
  MassProperties c = computeMass(ShapeGeom::capsule(0.4f, 0), 100);
  MassProperties s = computeMass(ShapeGeom::sphere(0.4f), 100);
  EXPECT_NEAR(c.mass, s.mass, 1e-5f * s.mass);
  expectMatNear(c.inertia, s.inertia, 1e-5f);
}

TEST(ShapeMass, PlaneHasNoMass) {
  MassProperties mp = computeMass(ShapeGeom::plane({0, 0, 1}, 0), 1000);
  EXPECT_EQ(mp.mass, 0);
  expectMatNear(mp.inertia, Mat3::zero(), 0);
}

TEST(ShapeMass, HullOfBoxCornersMatchesBox) {
  Vec3 he{0.3f, 0.7f, 1.1f};
  MassProperties box = computeMass(ShapeGeom::box(he), 700);
  MassProperties hull = computeMass(ShapeGeom::convexHull(boxHull(he)), 700);
  EXPECT_NEAR(hull.mass, box.mass, 1e-4f * box.mass);
  EXPECT_NEAR(length(hull.center), 0, 1e-6f);
  expectMatNear(hull.inertia, box.inertia, 1e-4f);
}

TEST(ShapeMass, HullOfMovedBoxHasMovedCentroidAndRotatedInertia) {
  Vec3 he{0.3f, 0.7f, 1.1f};
  Transform xf{{2, -1, 0.5f}, normalize(Quat::fromAxisAngle({1, 2, -1}, 0.8f))};
  auto h = boxHull(he, xf);
  MassProperties box = computeMass(ShapeGeom::box(he), 700);
  MassProperties hull = computeMass(ShapeGeom::convexHull(h), 700);
  EXPECT_NEAR(hull.mass, box.mass, 1e-4f * box.mass);
  EXPECT_NEAR(hull.center.x, 2, 1e-5f);
  EXPECT_NEAR(hull.center.y, -1, 1e-5f);
  EXPECT_NEAR(hull.center.z, 0.5f, 1e-5f);
  EXPECT_NEAR(h->centroid.x, 2, 1e-5f);
  EXPECT_NEAR(h->centroid.y, -1, 1e-5f);
  EXPECT_NEAR(h->centroid.z, 0.5f, 1e-5f);
  Mat3 r = toMat3(xf.q);
  expectMatNear(hull.inertia, r * box.inertia * transpose(r), 1e-4f);
}

TEST(ShapeMass, Tetrahedron) {
  // Corner tetrahedron: volume 1/6, centroid 1/4, Ixx = 3m/40, Ixy = m/80 about the centroid.
  auto h = buildConvexHull({{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}}, nullptr);
  ASSERT_NE(h, nullptr);
  MassProperties mp = computeMass(ShapeGeom::convexHull(h), 6);
  EXPECT_NEAR(mp.mass, 1, 1e-6f);
  for (int k = 0; k < 3; ++k) EXPECT_NEAR(mp.center[k], 0.25f, 1e-6f);
  Mat3 expected{{3.f / 40, 1.f / 80, 1.f / 80},
                {1.f / 80, 3.f / 40, 1.f / 80},
                {1.f / 80, 1.f / 80, 3.f / 40}};
  expectMatNear(mp.inertia, expected, 1e-5f);
}

TEST(ShapeMass, AabbOfEachShape) {
  Transform xf{{1, 2, 3}, Quat::fromAxisAngle({0, 0, 1}, kPi / 4)};
  AABB s = computeAABB(ShapeGeom::sphere(0.5f), xf);
  EXPECT_NEAR(s.lo.x, 0.5f, 1e-6f);
  EXPECT_NEAR(s.hi.z, 3.5f, 1e-6f);
  // A 1 x 1 x 2 box rotated 45 degrees about z: sqrt(2)/2 wide in x and y.
  AABB b = computeAABB(ShapeGeom::box({0.5f, 0.5f, 1}), xf);
  EXPECT_NEAR(b.hi.x - 1, std::sqrt(2.0f) / 2, 1e-5f);
  EXPECT_NEAR(b.lo.y - 2, -std::sqrt(2.0f) / 2, 1e-5f);
  EXPECT_NEAR(b.hi.z, 4, 1e-5f);
  // Capsule along x (rotated about y): spans hh + r in x, r in y and z.
  Transform xc{{0, 0, 0}, Quat::fromAxisAngle({0, 1, 0}, kPi / 2)};
  AABB c = computeAABB(ShapeGeom::capsule(0.2f, 0.5f), xc);
  EXPECT_NEAR(c.hi.x, 0.7f, 1e-5f);
  EXPECT_NEAR(c.lo.x, -0.7f, 1e-5f);
  EXPECT_NEAR(c.hi.z, 0.2f, 1e-5f);
  EXPECT_NEAR(c.hi.y, 0.2f, 1e-5f);
  // Hull: the tight box of its rotated vertices (a box hull matches the box).
  AABB h = computeAABB(ShapeGeom::convexHull(boxHull({0.5f, 0.5f, 1})), xf);
  for (int k = 0; k < 3; ++k) {
    EXPECT_NEAR(h.lo[k], b.lo[k], 1e-5f);
    EXPECT_NEAR(h.hi[k], b.hi[k], 1e-5f);
  }
  // Floor: z-up plane at z = 0.25 -> the top is exact, the rest huge but finite.
  AABB p = computeAABB(ShapeGeom::plane({0, 0, 1}, 0.25f), {});
  EXPECT_EQ(p.hi.z, 0.25f);
  EXPECT_LE(p.lo.z, -1e5f);
  EXPECT_GE(p.hi.x, 1e5f);
  EXPECT_LE(p.lo.x, -1e5f);
  EXPECT_TRUE(std::isfinite(p.lo.z));
  // A wall facing -x at x = 3 (plane on a body at x = 3): the solid is x >= 3.
  AABB wall = computeAABB(ShapeGeom::plane({-1, 0, 0}, 0), {{3, 0, 0}, {}});
  EXPECT_EQ(wall.lo.x, 3);
  EXPECT_GE(wall.hi.x, 1e5f);
  // A tilted plane: the box must contain points of the solid side near the origin.
  AABB t = computeAABB(ShapeGeom::plane({1, 0, 1}, 0), {});
  EXPECT_TRUE(overlaps(t, AABB{{-1, -1, -1}, {-0.5f, -0.5f, -0.5f}}));
  EXPECT_TRUE(overlaps(t, AABB{{10, 0, -20}, {10, 0, -20}}));
  EXPECT_TRUE(std::isfinite(t.lo.x) && std::isfinite(t.hi.x));
}

TEST(ShapeMass, ToString) {
  EXPECT_STREQ(toString(ShapeType::Sphere), "sphere");
  EXPECT_STREQ(toString(ShapeType::Box), "box");
  EXPECT_STREQ(toString(ShapeType::Capsule), "capsule");
  EXPECT_STREQ(toString(ShapeType::Plane), "plane");
  EXPECT_STREQ(toString(ShapeType::Hull), "hull");
}

}  // namespace
}  // namespace phys
