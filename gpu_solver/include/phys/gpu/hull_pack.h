// Convex hulls for the GPU narrow phase: packs a hull (phys::ConvexHull's vertices, faces,
// edges and edge faces) into the word array narrow_phase.comp reads at binding 6
// (`readonly buffer Hulls { uint hullData[]; }`). Plain types only: phys_gpu does not depend
// on phys_core (hullInputOf below adapts a phys::ConvexHull without linking to it).
//
// Layout of one packed hull (uint words; floats as their bits, floatBitsToUint), at the
// header offset H that packHull returns; every offset below is relative to H, so packed hulls
// can be appended one after another and moved as a block:
//   H + 0   vertex count nv
//   H + 1   face count nf
//   H + 2   edge count ne
//   H + 3   words of the whole record (header included)
//   H + 4.. centroid x, y, z (float)
//   H + 7   most vertices of one face
//   H + 8   V: start of the vertices, 3 words each (x, y, z float)
//   H + 9   P: start of the face planes, 4 words each (normal x, y, z, offset float)
//   H + 10  F: start of the face table, nf + 1 words: start of face f's vertex loop (relative
//           to H) at F + f, the end of the last loop at F + nf; the loops (vertex indices,
//           counter-clockwise seen from outside) follow the table
//   H + 11  E: start of the edges, 4 words each (v0, v1, the two faces as edgeFaces)
// A hull shape's GpuShape.size is (uintBitsToFloat(H), 0, 0, 0); shapes may share a record.
// An offset with no record behind it (kNoHull) gives no contact, as a hull shape without a
// hull does on the CPU.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "phys/gpu/shared.h"

namespace phys::gpu {

/// GpuShape.size.x bits of a hull shape without a hull: no contact.
constexpr uint32_t kNoHull = 0xFFFFFFFFu;
/// Words of a packed hull's header (shared.h, as the shaders read it).
constexpr uint32_t kHullHeaderWords = PHYS_GPU_HULL_HEADER_WORDS;
/// The most vertices one face may have (the narrow phase clips a face against another in
/// fixed buffers; shared.h, as collide_hull.glsl's clip buffers are sized).
constexpr uint32_t kHullMaxFaceVertices = PHYS_GPU_HULL_MAX_FACE_VERTICES;

/// A convex hull as phys::ConvexHull holds it, in plain types.
struct HullInput {
  struct Face {
    std::array<float, 3> normal{};  ///< outward unit normal
    float offset = 0;               ///< dot(normal, x) = offset on the face
    std::vector<uint32_t> indices;  ///< vertex loop, counter-clockwise seen from outside
  };
  std::vector<std::array<float, 3>> vertices;  ///< m, shape-local
  std::vector<Face> faces;
  std::vector<std::array<uint32_t, 2>> edges;  ///< unique undirected edges (vertex indices)
  /// The two faces of each edge, parallel to `edges` (ConvexHull::edgeFaces: first = the face
  /// whose loop runs from the lower vertex index to the higher). Empty: derived as the CPU
  /// narrow phase does for a hull built by hand.
  std::vector<std::array<uint32_t, 2>> edgeFaces;
  std::array<float, 3> centroid{};  ///< volume centroid, m
};

/// Appends the hull's record to *data; returns its header offset H (for GpuShape.size.x), or
/// kNoHull with *error set when the hull is unusable (no vertices or faces, an index out of
/// range, a face of fewer than 3 or more than kHullMaxFaceVertices vertices, a value that is
/// not finite, or edgeFaces not parallel to edges). *data is unchanged on failure.
uint32_t packHull(const HullInput& hull, std::vector<uint32_t>* data, std::string* error);

/// A HullInput from anything shaped like phys::ConvexHull (vertices[i].x/.y/.z,
/// faces[f].normal/.offset/.indices, edges[e].first/.second, edgeFaces, centroid).
template <class ConvexHullT>
HullInput hullInputOf(const ConvexHullT& h) {
  HullInput in;
  in.vertices.reserve(h.vertices.size());
  for (const auto& v : h.vertices) in.vertices.push_back({v.x, v.y, v.z});
  in.faces.reserve(h.faces.size());
  for (const auto& f : h.faces) {
    HullInput::Face face;
    face.normal = {f.normal.x, f.normal.y, f.normal.z};
    face.offset = f.offset;
    face.indices.assign(f.indices.begin(), f.indices.end());
    in.faces.push_back(std::move(face));
  }
  in.edges.reserve(h.edges.size());
  for (const auto& e : h.edges) in.edges.push_back({e.first, e.second});
  in.edgeFaces.reserve(h.edgeFaces.size());
  for (const auto& e : h.edgeFaces) in.edgeFaces.push_back({e.first, e.second});
  in.centroid = {h.centroid.x, h.centroid.y, h.centroid.z};
  return in;
}

}  // namespace phys::gpu
