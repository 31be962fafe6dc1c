// What a shape is: its geometry in its local frame, its place on a body and its material.
// Plain data: no collision code comes with it (phys/collision/shapes.h has the hull builder,
// the mass properties and the narrow phase). z is up; a capsule's segment runs along its
// local z axis; a plane is {x : dot(normal, x) = offset} in the owning body's frame and is
// only allowed on static bodies.
#pragma once

#include <cstdint>
#include <memory>
#include <utility>
#include <vector>

#include "phys/defs/math.h"

namespace phys {

enum class ShapeType : uint8_t { Sphere = 0, Box = 1, Capsule = 2, Plane = 3, Hull = 4 };
constexpr int kShapeTypeCount = 5;
inline const char* toString(ShapeType t) {
  switch (t) {
    case ShapeType::Sphere:
      return "sphere";
    case ShapeType::Box:
      return "box";
    case ShapeType::Capsule:
      return "capsule";
    case ShapeType::Plane:
      return "plane";
    case ShapeType::Hull:
      return "hull";
  }
  return "unknown";
}

/// A convex polyhedron with its faces and edges, built once and shared by every shape using it
/// (the engine's buildConvexHull, phys/collision/shapes.h). A hull may also be given by its
/// points alone (no faces: ShapeGeom::hullOf, and every hull the protocol carries, which
/// sends vertices only): the world that receives it builds it (World::createBody, addShape),
/// and refuses points that span no volume. So a program that only defines bodies needs no
/// hull builder.
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
  /// Built (faces known), not points awaiting the world's hull builder.
  bool built() const { return !faces.empty(); }
};

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
  /// The convex hull of these points (m, local), built by the world that receives it.
  static ShapeGeom hullOf(std::vector<Vec3> points) {
    auto h = std::make_shared<ConvexHull>();
    h->vertices = std::move(points);
    return convexHull(std::move(h));
  }
};

/// Surface material. Mixing for a contact: friction = sqrt(fa * fb) (geometric mean, so a
/// frictionless surface makes any contact frictionless), restitution = max(ea, eb) (so a
/// bouncy ball bounces on any floor).
struct Material {
  float friction = 0.6f;     ///< Coulomb coefficient (static = dynamic), >= 0
  float restitution = 0.0f;  ///< 0 (plastic) .. 1 (elastic)
  float density = 1000.0f;   ///< kg/m^3, used when a body's mass comes from its shapes
};

/// One shape on a body.
struct ShapeDef {
  ShapeGeom geom;
  Transform local;  ///< shape frame relative to the body frame
  Material material;
};

}  // namespace phys
