// Collision shapes, their mass properties, and the narrow phase (contact manifolds).
// Conventions: z is up; a capsule's segment runs along its local z axis; a plane is
// {x : dot(normal, x) = offset} in the owning body's frame and is only allowed on static bodies.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "phys/base/math.h"

namespace phys {

enum class ShapeType : uint8_t { Sphere = 0, Box = 1, Capsule = 2, Plane = 3, Hull = 4 };
constexpr int kShapeTypeCount = 5;
const char* toString(ShapeType t);

/// A convex polyhedron with its faces and edges, built once and shared by every shape using it.
struct ConvexHull {
  struct Face {
    Vec3 normal;                    ///< outward unit normal
    float offset = 0;               ///< dot(normal, x) = offset on the face
    std::vector<uint32_t> indices;  ///< vertex indices, counter-clockwise seen from outside
  };
  std::vector<Vec3> vertices;  ///< m, relative to the shape's local origin
  std::vector<Face> faces;
  std::vector<std::pair<uint32_t, uint32_t>> edges;  ///< unique undirected edges
  Vec3 centroid;                                     ///< volume centroid, m
  /// The two faces sharing each edge, parallel to `edges`; filled by buildConvexHull. The
  /// narrow phase derives it on the fly (slower) when a hull built by hand leaves it empty.
  std::vector<std::pair<uint32_t, uint32_t>> edgeFaces;
};

/// Builds the convex hull of a point cloud (coplanar facets merged into polygons).
/// Returns nullptr and fills *error when the points span no volume or are not finite.
std::shared_ptr<const ConvexHull> buildConvexHull(const std::vector<Vec3>& points,
                                                  std::string* error);

/// Geometry of one shape in its local frame.
struct ShapeGeom {
  ShapeType type = ShapeType::Sphere;
  float radius = 0.5f;                     ///< sphere, capsule: m
  Vec3 halfExtents{0.5f, 0.5f, 0.5f};      ///< box: m
  float halfHeight = 0.5f;                 ///< capsule: half the segment length along local z, m
  Vec3 normal{0, 0, 1};                    ///< plane: unit normal
  float offset = 0;                        ///< plane: dot(normal, x) = offset
  std::shared_ptr<const ConvexHull> hull;  ///< hull only

  static ShapeGeom sphere(float r) {
    ShapeGeom g;
    g.type = ShapeType::Sphere;
    g.radius = r;
    return g;
  }
  static ShapeGeom box(Vec3 he) {
    ShapeGeom g;
    g.type = ShapeType::Box;
    g.halfExtents = he;
    return g;
  }
  static ShapeGeom capsule(float r, float halfHeight) {
    ShapeGeom g;
    g.type = ShapeType::Capsule;
    g.radius = r;
    g.halfHeight = halfHeight;
    return g;
  }
  static ShapeGeom plane(Vec3 n, float d) {
    ShapeGeom g;
    g.type = ShapeType::Plane;
    g.normal = normalize(n);
    g.offset = d;
    return g;
  }
  static ShapeGeom convexHull(std::shared_ptr<const ConvexHull> h) {
    ShapeGeom g;
    g.type = ShapeType::Hull;
    g.hull = std::move(h);
    return g;
  }
};

/// Mass properties of a shape of uniform density, in the shape's local frame.
struct MassProperties {
  float mass = 0;  ///< kg
  Vec3 center;     ///< centre of mass, m (local)
  Mat3 inertia;    ///< about the centre of mass, kg m^2 (local axes)
};
/// Mass properties for a density in kg/m^3. A plane has none (mass 0).
MassProperties computeMass(const ShapeGeom& g, float density);

/// World-space bounds of a shape at a transform. A plane gets a huge but finite box.
AABB computeAABB(const ShapeGeom& g, const Transform& xf);

/// One contact point. The point lies midway between the two surfaces.
struct ContactPoint {
  Vec3 point;              ///< world, m
  float separation = 0;    ///< m, negative when penetrating
  uint32_t featureId = 0;  ///< stable across steps while the same features touch
};

/// Up to four contact points sharing one normal.
struct Manifold {
  static constexpr int kMaxPoints = 4;
  Vec3 normal;  ///< world unit normal pointing from shape A to shape B
  int count = 0;
  ContactPoint points[kMaxPoints];
};

/// Narrow phase for any pair of shapes. Reports every point whose separation is below
/// `margin` (speculative contacts, margin >= 0), at most 4, reduced to keep the area.
/// The normal always points from A to B, whichever order the pair-specific routine needs.
/// Returns false (count 0) when the shapes are farther apart than margin.
/// Plane-plane gives no contact.
bool collide(const ShapeGeom& a, const Transform& xa, const ShapeGeom& b, const Transform& xb,
             float margin, Manifold* out);

}  // namespace phys
