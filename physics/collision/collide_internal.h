// Internals of the narrow phase shared by its source files: pair routines, contact clipping and
// reduction, the box seen as a hull, and the feature-id layout.
#pragma once

#include <cmath>
#include <cstdint>
#include <limits>
#include <utility>
#include <vector>

#include "phys/collision/shapes.h"

namespace phys::detail {

// Feature ids (ContactPoint::featureId), 32 bits:
//   bits 30-31 kind: 0 = face contact with A's face as reference, 1 = face contact with B's face
//              as reference, 2 = edge-edge, 3 = any other routine.
//   kinds 0, 1: bits 22-29 reference face index, bits 14-21 incident face index (both mod 256),
//              bits 0-13 the clip feature of the point (localFeature below):
//              bits 12-13 type: 0 = incident-face vertex, 1 = incident edge cut by a side plane of
//              the reference face, 2 = corner of the reference face (two side planes);
//              bits 6-11 a, bits 0-5 b (mod 64): type 0: a = vertex position in the incident
//              face's loop; type 1: a = incident edge (loop position of its first vertex),
//              b = side plane (loop position of the reference edge); type 2: a < b side planes.
//   kind 2:    bits 15-29 edge of A, bits 0-14 edge of B (indices into the hull's edges; a box
//              edge is 4 * axis + signs of the two other axes).
//   kind 3:    bits 28-29 sub-kind (0 = single point of a rounded shape, 1 = vertex or segment
//              end against a face/plane, 2 = segment end clipped to a face, 3 = segment/edge),
//              bits 0-27 the feature (vertex index, face << 1 | segment end, edge index).
// Box indices: vertex = (x > 0) | (y > 0) << 1 | (z > 0) << 2, face = 2 * axis + (normal < 0).
// Every part depends only on which features touch, so the id of a point survives small motion.
constexpr uint32_t kKindFaceA = 0u << 30, kKindFaceB = 1u << 30, kKindEdges = 2u << 30,
                   kKindOther = 3u << 30;
inline uint32_t otherFeatureId(uint32_t sub, uint32_t feature) {
  return kKindOther | (sub << 28) | (feature & 0x0FFFFFFFu);
}
inline uint32_t edgeFeatureId(uint32_t edgeA, uint32_t edgeB) {
  return kKindEdges | (edgeA & 0x7FFFu) << 15 | (edgeB & 0x7FFFu);
}
inline uint16_t localFeature(uint32_t type, uint32_t a, uint32_t b) {
  return static_cast<uint16_t>(type << 12 | (a & 63u) << 6 | (b & 63u));
}

// Tolerances of the SAT feature choice: an axis of lower priority must beat the best one of
// higher priority by a relative and an absolute amount, so near-ties keep the previous choice.
constexpr float kFaceRelTol = 0.02f, kFaceAbsTol = 0.0005f;  // B's face over A's face
constexpr float kEdgeRelTol = 0.05f, kEdgeAbsTol = 0.0005f;  // an edge pair over a face
inline bool beats(float candidate, float best, float rel, float abs) {
  return candidate > best + rel * std::fabs(best) + abs;
}
// An edge-edge axis within this cosine (about 8 degrees) of a face normal is taken as that face's
// contact instead: two nearly parallel faces, or an edge lying along a face, meeting over the
// other's rim. Depths along the face normal then differ from those along the edge axis by about
// 1 %, well inside kEdgeRelTol; much wider angles tilt the normal enough to let sliding boxes
// wedge into each other.
constexpr float kEdgeFaceCos = 0.99f;
// Clipping keeps incident vertices up to this far outside the reference face (m), so a box
// sitting flush on an equal box keeps its corner ids instead of flickering to clip points.
constexpr float kClipSlop = 1e-3f;

// Plain min/max/clamp: std::fmin and std::fmax are library calls on the hot paths.
inline float minf(float a, float b) {
  return a < b ? a : b;
}
inline float maxf(float a, float b) {
  return a > b ? a : b;
}
inline float clamp01(float x) {
  return x < 0 ? 0 : (x > 1 ? 1 : x);
}

// ---- Contact clipping and reduction --------------------------------------------------------

struct ClipVertex {
  Vec3 p;
  float sep = 0;
  uint16_t feature = 0;  // localFeature()
  uint16_t edge = 0;     // label of the edge to the next vertex: incident edge, or kSideLabel|side
};
constexpr uint16_t kSideLabel = 0x8000;
struct ClipPlane {
  Vec3 n;
  float d = 0;  // inside: dot(n, x) <= d
};

/// Sutherland-Hodgman clip of the polygon in `a` (n vertices) against the planes; vertices up to
/// kClipSlop outside a plane are kept as they are. `a` and `b` need room for n + numPlanes
/// vertices; returns the count and sets *result to whichever buffer holds it.
int clipPolygon(ClipVertex* a, ClipVertex* b, int n, const ClipPlane* planes, int numPlanes,
                ClipVertex** result);

/// Picks at most four of n points: the deepest, the farthest from it, then the two spanning the
/// largest area (projected along `normal`). pointAt(i) -> Vec3, sepAt(i) -> float,
/// valid(i) -> bool (points failing it are ignored). Writes the chosen indices to sel.
template <class PointAt, class SepAt, class Valid>
int selectFour(int n, Vec3 normal, PointAt pointAt, SepAt sepAt, Valid valid, int sel[4]) {
  int count = 0;
  float minSep = std::numeric_limits<float>::infinity();
  for (int i = 0; i < n; ++i) {
    if (!valid(i)) continue;
    ++count;
    minSep = minf(minSep, sepAt(i));
  }
  if (count <= 4) {
    int k = 0;
    for (int i = 0; i < n; ++i)
      if (valid(i)) sel[k++] = i;
    return k;
  }
  // The first point within 0.1 mm of the deepest, so depth noise does not change the choice.
  int i0 = -1;
  for (int i = 0; i < n && i0 < 0; ++i)
    if (valid(i) && sepAt(i) <= minSep + 1e-4f) i0 = i;
  sel[0] = i0;
  Vec3 p0 = pointAt(i0);
  int i1 = -1;
  float bestD = 0;
  for (int i = 0; i < n; ++i) {
    if (!valid(i) || i == i0) continue;
    Vec3 d = pointAt(i) - p0;
    d -= normal * dot(d, normal);
    float d2 = lengthSquared(d);
    if (d2 > bestD) bestD = d2, i1 = i;
  }
  if (i1 < 0 || bestD < 1e-14f) return 1;
  sel[1] = i1;
  Vec3 p1 = pointAt(i1);
  int i2 = -1;
  float bestA = 0, signA = 1;
  for (int i = 0; i < n; ++i) {
    if (!valid(i) || i == i0 || i == i1) continue;
    float a = dot(cross(p1 - p0, pointAt(i) - p0), normal);
    if (std::fabs(a) > bestA) bestA = std::fabs(a), signA = a < 0 ? -1.0f : 1.0f, i2 = i;
  }
  if (i2 < 0 || bestA < 1e-14f) return 2;
  sel[2] = i2;
  Vec3 p2 = pointAt(i2);
  int i3 = -1;
  float bestOut = 0;
  for (int i = 0; i < n; ++i) {
    if (!valid(i) || i == i0 || i == i1 || i == i2) continue;
    Vec3 p = pointAt(i);
    float a01 = signA * dot(cross(p1 - p0, p - p0), normal);
    float a12 = signA * dot(cross(p2 - p1, p - p1), normal);
    float a20 = signA * dot(cross(p0 - p2, p - p2), normal);
    float out = -minf(a01, minf(a12, a20));  // area the point adds outside the triangle
    if (out > bestOut) bestOut = out, i3 = i;
  }
  if (i3 < 0) return 3;
  sel[3] = i3;
  return 4;
}

/// Writes the clipped incident points (already carrying sep against the reference plane) as a
/// manifold: keeps sep < margin, reduces to four, places each point midway. nRef points from the
/// reference shape to the incident one.
bool emitFaceContacts(ClipVertex* pts, int n, Vec3 nRef, float margin, bool refIsB,
                      uint32_t refFace, uint32_t incFace, Manifold* out);

// ---- Geometry helpers -----------------------------------------------------------------------

/// Parameter in [0, 1] of the point of segment ab closest to p.
float closestOnSegment(Vec3 a, Vec3 b, Vec3 p);
/// Closest points c1 = p1 + s (q1 - p1), c2 = p2 + t (q2 - p2) of two segments.
void closestSegmentSegment(Vec3 p1, Vec3 q1, Vec3 p2, Vec3 q2, float* s, float* t, Vec3* c1,
                           Vec3* c2);

// ---- Boxes and hulls seen alike --------------------------------------------------------------

/// Topology of the box [-1, 1]^3: vertices by sign bits, faces +x -x +y -y +z -z, edges
/// 4 * axis + signs. Scaled by the half extents it serves box-hull and capsule-box.
const ConvexHull& unitBoxHull();
/// Fills faces-per-edge for a hull (ConvexHull::edgeFaces layout).
void computeEdgeFaces(const ConvexHull& h, std::vector<std::pair<uint32_t, uint32_t>>* out);

/// A box or hull in its local frame.
struct PolyRef {
  const ConvexHull* h = nullptr;
  Vec3 scale{1, 1, 1};  // box half extents; (1, 1, 1) for a hull
  bool isBox = false;

  static PolyRef of(const ShapeGeom& g) {
    if (g.type == ShapeType::Box) return {&unitBoxHull(), g.halfExtents, true};
    return {g.hull.get(), {1, 1, 1}, false};
  }
  int numFaces() const { return static_cast<int>(h->faces.size()); }
  Vec3 vertex(uint32_t i) const {
    return isBox ? mulComponents(h->vertices[i], scale) : h->vertices[i];
  }
  Vec3 normal(int f) const { return h->faces[f].normal; }
  float offset(int f) const { return isBox ? scale[f >> 1] : h->faces[f].offset; }
  Vec3 centroid() const { return isBox ? Vec3{} : h->centroid; }
  /// max over the shape of dot(d, x).
  float support(Vec3 d) const {
    if (isBox) return dot(vabs(d), scale);
    float best = -std::numeric_limits<float>::infinity();
    for (const Vec3& v : h->vertices) best = maxf(best, dot(d, v));
    return best;
  }
};

// ---- Pair routines (normal from the first shape to the second) -----------------------------

bool collideBoxBox(const ShapeGeom& a, const Transform& xa, const ShapeGeom& b, const Transform& xb,
                   float margin, Manifold* out);
/// Box or hull against box or hull (SAT with Gauss-map pruning, face clipping).
bool collidePolyPoly(const ShapeGeom& a, const Transform& xa, const ShapeGeom& b,
                     const Transform& xb, float margin, Manifold* out);
/// Box or hull (A) against a sphere (B).
bool collidePolySphere(const ShapeGeom& a, const Transform& xa, const ShapeGeom& b,
                       const Transform& xb, float margin, Manifold* out);
/// Box or hull (A) against a capsule (B).
bool collidePolyCapsule(const ShapeGeom& a, const Transform& xa, const ShapeGeom& b,
                        const Transform& xb, float margin, Manifold* out);

}  // namespace phys::detail
