// Convex hull construction: merged faces, counter-clockwise loops, edges and adjacency,
// centroid, rejection of degenerate input, and no output from qhull.
#include <gtest/gtest.h>

#include <cmath>
#include <map>
#include <random>
#include <set>
#include <vector>

#include "phys/collision/shapes.h"

namespace phys {
namespace {

std::vector<Vec3> cubeCorners(float h = 1) {
  std::vector<Vec3> pts;
  for (int i = 0; i < 8; ++i) pts.push_back({(i & 1) ? h : -h, (i & 2) ? h : -h, (i & 4) ? h : -h});
  return pts;
}

// Structural checks every hull must pass: planar CCW convex faces with outward normals, every
// input point inside, unique edges each shared by exactly two faces (matching edgeFaces), Euler.
void checkHull(const ConvexHull& h, const std::vector<Vec3>& input, float tol = 1e-5f) {
  ASSERT_GE(h.vertices.size(), 4u);
  ASSERT_GE(h.faces.size(), 4u);
  std::map<std::pair<uint32_t, uint32_t>, int> directed;
  for (size_t f = 0; f < h.faces.size(); ++f) {
    const auto& face = h.faces[f];
    EXPECT_NEAR(length(face.normal), 1, 1e-5f);
    ASSERT_GE(face.indices.size(), 3u);
    size_t m = face.indices.size();
    for (size_t k = 0; k < m; ++k) {
      Vec3 a = h.vertices[face.indices[k]], b = h.vertices[face.indices[(k + 1) % m]],
           c = h.vertices[face.indices[(k + 2) % m]];
      EXPECT_NEAR(dot(face.normal, a), face.offset, tol) << "vertex on its face plane";
      EXPECT_GT(dot(cross(b - a, c - b), face.normal), 0) << "CCW and convex, face " << f;
      directed[{face.indices[k], face.indices[(k + 1) % m]}]++;
    }
    for (const Vec3& p : input) EXPECT_LE(dot(face.normal, p), face.offset + tol);
  }
  // Each undirected edge appears once in each direction.
  for (const auto& [e, n] : directed) {
    EXPECT_EQ(n, 1);
    EXPECT_EQ(directed.count({e.second, e.first}), 1u);
  }
  std::set<std::pair<uint32_t, uint32_t>> unique(h.edges.begin(), h.edges.end());
  EXPECT_EQ(unique.size(), h.edges.size()) << "edges are unique";
  EXPECT_EQ(h.edges.size() * 2, directed.size());
  ASSERT_EQ(h.edgeFaces.size(), h.edges.size());
  for (size_t e = 0; e < h.edges.size(); ++e) {
    auto [f0, f1] = h.edgeFaces[e];
    EXPECT_NE(f0, f1);
    for (uint32_t f : {f0, f1}) {
      const auto& idx = h.faces[f].indices;
      bool hasA = false, hasB = false;
      for (uint32_t v : idx) hasA |= v == h.edges[e].first, hasB |= v == h.edges[e].second;
      EXPECT_TRUE(hasA && hasB) << "edge " << e << " is on face " << f;
    }
  }
  EXPECT_EQ(static_cast<int>(h.vertices.size()) - static_cast<int>(h.edges.size()) +
                static_cast<int>(h.faces.size()),
            2);
}

TEST(ConvexHull, CubeHasSixQuadsAndTwelveEdges) {
  std::vector<Vec3> pts = cubeCorners();
  std::string err;
  auto h = buildConvexHull(pts, &err);
  ASSERT_NE(h, nullptr) << err;
  EXPECT_EQ(h->vertices.size(), 8u);
  EXPECT_EQ(h->faces.size(), 6u);
  EXPECT_EQ(h->edges.size(), 12u);
  for (const auto& f : h->faces) {
    EXPECT_EQ(f.indices.size(), 4u);
    EXPECT_NEAR(f.offset, 1, 1e-6f);
    EXPECT_NEAR(std::fabs(f.normal.x) + std::fabs(f.normal.y) + std::fabs(f.normal.z), 1, 1e-6f);
  }
  EXPECT_NEAR(length(h->centroid), 0, 1e-6f);
  checkHull(*h, pts);
}

TEST(ConvexHull, InteriorDuplicateAndCoplanarPointsAreDropped) {
  std::vector<Vec3> pts = cubeCorners();
  std::vector<Vec3> corners = pts;
  pts.insert(pts.end(), corners.begin(), corners.end());  // duplicates
  pts.push_back({0, 0, 0});                               // interior
  pts.push_back({0.3f, -0.2f, 0.5f});
  pts.push_back({0, 0, 1});     // face centre
  pts.push_back({1, 0, 1});     // edge midpoint
  pts.push_back({0.5f, 1, 0});  // on a face
  std::string err;
  auto h = buildConvexHull(pts, &err);
  ASSERT_NE(h, nullptr) << err;
  EXPECT_EQ(h->vertices.size(), 8u);
  EXPECT_EQ(h->faces.size(), 6u);
  EXPECT_EQ(h->edges.size(), 12u);
  checkHull(*h, pts);
}

TEST(ConvexHull, RotatedTranslatedBoxStillMergesIntoQuads) {
  // Float rounding of rotated corners leaves the faces very slightly non-planar.
  Transform xf{{3.1f, -7.3f, 1}, normalize(Quat::fromAxisAngle({0.3f, 1, -0.2f}, 0.9f))};
  std::vector<Vec3> pts;
  for (Vec3 p : cubeCorners()) pts.push_back(apply(xf, mulComponents(p, {0.5f, 0.3f, 0.2f})));
  auto h = buildConvexHull(pts, nullptr);
  ASSERT_NE(h, nullptr);
  EXPECT_EQ(h->faces.size(), 6u);
  EXPECT_EQ(h->edges.size(), 12u);
  EXPECT_NEAR(h->centroid.x, 3.1f, 1e-5f);
  EXPECT_NEAR(h->centroid.y, -7.3f, 1e-5f);
  EXPECT_NEAR(h->centroid.z, 1, 1e-5f);
  checkHull(*h, pts, 1e-5f);
}

TEST(ConvexHull, Tetrahedron) {
  std::vector<Vec3> pts{{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
  auto h = buildConvexHull(pts, nullptr);
  ASSERT_NE(h, nullptr);
  EXPECT_EQ(h->vertices.size(), 4u);
  EXPECT_EQ(h->faces.size(), 4u);
  EXPECT_EQ(h->edges.size(), 6u);
  for (const auto& f : h->faces) EXPECT_EQ(f.indices.size(), 3u);
  for (int k = 0; k < 3; ++k) EXPECT_NEAR(h->centroid[k], 0.25f, 1e-6f);
  checkHull(*h, pts);
}

TEST(ConvexHull, PrismAndRandomClouds) {
  std::vector<Vec3> pts;
  for (int i = 0; i < 24; ++i) {
    float t = 2 * kPi * static_cast<float>(i) / 24;
    pts.push_back({std::cos(t), std::sin(t), -1});
    pts.push_back({std::cos(t), std::sin(t), 1});
  }
  auto prism = buildConvexHull(pts, nullptr);
  ASSERT_NE(prism, nullptr);
  EXPECT_EQ(prism->faces.size(), 26u);  // 24 sides + 2 caps
  checkHull(*prism, pts);

  std::mt19937 rng(11);
  std::normal_distribution<float> g;
  for (int trial = 0; trial < 20; ++trial) {
    std::vector<Vec3> cloud;
    for (int i = 0; i < 60; ++i) cloud.push_back(Vec3{g(rng), g(rng), g(rng)} * 0.5f);
    std::string err;
    auto h = buildConvexHull(cloud, &err);
    ASSERT_NE(h, nullptr) << err;
    checkHull(*h, cloud, 1e-4f);
  }
}

TEST(ConvexHull, DegenerateInputIsRejectedQuietly) {
  testing::internal::CaptureStdout();
  testing::internal::CaptureStderr();
  std::string err;
  // Coplanar.
  EXPECT_EQ(buildConvexHull({{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {1, 1, 0}, {0.5f, 0.2f, 0}}, &err),
            nullptr);
  EXPECT_NE(err.find("coplanar"), std::string::npos) << err;
  // Coplanar but tilted and off the origin.
  err.clear();
  std::vector<Vec3> tilted;
  for (int i = 0; i < 10; ++i) {
    float u = static_cast<float>(i % 3), v = static_cast<float>(i / 3);
    tilted.push_back(Vec3{5, 5, 5} + Vec3{1, 0, 1} * u + Vec3{0, 1, 0} * v);
  }
  EXPECT_EQ(buildConvexHull(tilted, &err), nullptr);
  EXPECT_FALSE(err.empty());
  // Collinear, coincident, too few, not finite.
  err.clear();
  EXPECT_EQ(buildConvexHull({{0, 0, 0}, {1, 1, 1}, {2, 2, 2}, {3, 3, 3}}, &err), nullptr);
  EXPECT_FALSE(err.empty());
  err.clear();
  EXPECT_EQ(buildConvexHull({{1, 1, 1}, {1, 1, 1}, {1, 1, 1}, {1, 1, 1}}, &err), nullptr);
  EXPECT_FALSE(err.empty());
  err.clear();
  EXPECT_EQ(buildConvexHull({{0, 0, 0}, {1, 0, 0}, {0, 1, 0}}, &err), nullptr);
  EXPECT_NE(err.find("at least 4"), std::string::npos) << err;
  err.clear();
  EXPECT_EQ(buildConvexHull({{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, NAN}}, &err), nullptr);
  EXPECT_NE(err.find("not finite"), std::string::npos) << err;
  err.clear();
  EXPECT_EQ(buildConvexHull({{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, INFINITY}}, &err), nullptr);
  EXPECT_NE(err.find("not finite"), std::string::npos) << err;
  // A null error pointer is fine.
  EXPECT_EQ(buildConvexHull({{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {1, 1, 0}}, nullptr), nullptr);
  std::string out = testing::internal::GetCapturedStdout();
  std::string errOut = testing::internal::GetCapturedStderr();
  EXPECT_EQ(out, "");
  EXPECT_EQ(errOut, "");
}

}  // namespace
}  // namespace phys
