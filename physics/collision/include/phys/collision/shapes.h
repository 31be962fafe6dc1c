// What the engine computes of shapes (phys/defs/shape_def.h says what they are): convex
// hulls from points, mass properties, bounds, and the narrow phase (contact manifolds).
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <unordered_map>
#include <vector>

#include "phys/defs/math.h"
#include "phys/defs/shape_def.h"

namespace phys {

/// Builds the convex hull of a point cloud (coplanar facets merged into polygons).
/// Returns nullptr and fills *error when the points span no volume or are not finite.
std::shared_ptr<const ConvexHull> buildConvexHull(const std::vector<Vec3>& points,
                                                  std::string* error);

/// Hulls built from points objects, by the points object's address: the points object (held,
/// so that no other object takes its address while the cache lives) and its built hull.
using HullBuildCache =
    std::unordered_map<const ConvexHull*, std::pair<std::shared_ptr<const ConvexHull>,
                                                    std::shared_ptr<const ConvexHull>>>;
/// A shape's hull ready for a world: a hull given by its points only (ConvexHull::built()
/// false: ShapeGeom::hullOf, what the protocol carries) built from them, a built one as it is.
/// With a cache, shapes holding one points object share one build. Returns nullptr and fills
/// *error like buildConvexHull.
std::shared_ptr<const ConvexHull> buildHull(const std::shared_ptr<const ConvexHull>& hull,
                                            std::string* error, HullBuildCache* cache = nullptr);

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
