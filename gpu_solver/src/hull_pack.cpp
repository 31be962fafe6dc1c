// Packs convex hulls into the narrow phase's hull words (layout in phys/gpu/hull_pack.h and
// shaders/collide_hull.glsl).
#include "phys/gpu/hull_pack.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <limits>
#include <utility>

namespace phys::gpu {
namespace {

constexpr uint32_t kNone = 0xFFFFFFFFu;

// The faces of each edge, as the CPU's detail::computeEdgeFaces: first = the face whose loop
// runs from the edge's lower vertex index to the higher, second = the other; a missing one
// repeats the one found (0 when neither is).
std::vector<std::array<uint32_t, 2>> deriveEdgeFaces(const HullInput& h) {
  const size_t ne = h.edges.size();
  auto key = [](uint32_t a, uint32_t b) {
    return static_cast<uint64_t>(std::min(a, b)) << 32 | std::max(a, b);
  };
  std::vector<std::pair<uint64_t, uint32_t>> keys(ne);
  for (size_t e = 0; e < ne; ++e)
    keys[e] = {key(h.edges[e][0], h.edges[e][1]), static_cast<uint32_t>(e)};
  std::sort(keys.begin(), keys.end());
  std::vector<std::array<uint32_t, 2>> out(ne, {kNone, kNone});
  for (size_t f = 0; f < h.faces.size(); ++f) {
    const std::vector<uint32_t>& loop = h.faces[f].indices;
    for (size_t k = 0; k < loop.size(); ++k) {
      uint32_t a = loop[k], b = loop[k + 1 == loop.size() ? 0 : k + 1];
      auto it = std::lower_bound(keys.begin(), keys.end(), std::make_pair(key(a, b), 0u));
      if (it == keys.end() || it->first != key(a, b)) continue;
      out[it->second][a < b ? 0 : 1] = static_cast<uint32_t>(f);
    }
  }
  for (auto& s : out) {
    if (s[0] == kNone) s[0] = s[1];
    if (s[1] == kNone) s[1] = s[0];
    if (s[0] == kNone) s[0] = s[1] = 0;
  }
  return out;
}

bool finite3(const std::array<float, 3>& v) {
  return std::isfinite(v[0]) && std::isfinite(v[1]) && std::isfinite(v[2]);
}

uint32_t fail(std::string* error, std::string message) {
  if (error) *error = std::move(message);
  return kNoHull;
}

}  // namespace

uint32_t packHull(const HullInput& hull, std::vector<uint32_t>* data, std::string* error) {
  const size_t nv = hull.vertices.size(), nf = hull.faces.size(), ne = hull.edges.size();
  if (nv == 0 || nf == 0) return fail(error, "a hull needs vertices and faces");
  if (!finite3(hull.centroid)) return fail(error, "the centroid is not finite");
  for (size_t i = 0; i < nv; ++i)
    if (!finite3(hull.vertices[i]))
      return fail(error, "vertex " + std::to_string(i) + " is not finite");
  size_t loopWords = 0, maxFace = 0;
  for (size_t f = 0; f < nf; ++f) {
    const HullInput::Face& face = hull.faces[f];
    const size_t n = face.indices.size();
    if (n < 3 || n > kHullMaxFaceVertices)
      return fail(error, "face " + std::to_string(f) + " has " + std::to_string(n) +
                             " vertices (3.." + std::to_string(kHullMaxFaceVertices) + ")");
    if (!finite3(face.normal) || !std::isfinite(face.offset))
      return fail(error, "face " + std::to_string(f) + "'s plane is not finite");
    for (uint32_t i : face.indices)
      if (i >= nv) return fail(error, "face " + std::to_string(f) + " indexes past the vertices");
    loopWords += n;
    maxFace = std::max(maxFace, n);
  }
  for (size_t e = 0; e < ne; ++e)
    if (hull.edges[e][0] >= nv || hull.edges[e][1] >= nv)
      return fail(error, "edge " + std::to_string(e) + " indexes past the vertices");
  std::vector<std::array<uint32_t, 2>> derived;
  const std::vector<std::array<uint32_t, 2>>* edgeFaces = &hull.edgeFaces;
  if (hull.edgeFaces.empty() && ne > 0) {
    derived = deriveEdgeFaces(hull);
    edgeFaces = &derived;
  } else if (hull.edgeFaces.size() != ne) {
    return fail(error, "edgeFaces is not parallel to edges");
  }
  for (size_t e = 0; e < ne; ++e)
    if ((*edgeFaces)[e][0] >= nf || (*edgeFaces)[e][1] >= nf)
      return fail(error, "edge " + std::to_string(e) + "'s faces index past the faces");

  const size_t vStart = kHullHeaderWords, pStart = vStart + 3 * nv, fStart = pStart + 4 * nf;
  const size_t eStart = fStart + (nf + 1) + loopWords, total = eStart + 4 * ne;
  const size_t base = data->size();
  if (base + total > std::numeric_limits<uint32_t>::max())
    return fail(error, "the hull data outgrows 32-bit offsets");

  auto bits = [](float f) { return std::bit_cast<uint32_t>(f); };
  auto u32 = [](size_t v) { return static_cast<uint32_t>(v); };
  data->insert(data->end(), {u32(nv), u32(nf), u32(ne), u32(total), bits(hull.centroid[0]),
                             bits(hull.centroid[1]), bits(hull.centroid[2]), u32(maxFace),
                             u32(vStart), u32(pStart), u32(fStart), u32(eStart)});
  for (const auto& v : hull.vertices)
    data->insert(data->end(), {bits(v[0]), bits(v[1]), bits(v[2])});
  for (const HullInput::Face& f : hull.faces)
    data->insert(data->end(),
                 {bits(f.normal[0]), bits(f.normal[1]), bits(f.normal[2]), bits(f.offset)});
  size_t loop = fStart + nf + 1;
  for (const HullInput::Face& f : hull.faces) {
    data->push_back(u32(loop));
    loop += f.indices.size();
  }
  data->push_back(u32(loop));
  for (const HullInput::Face& f : hull.faces)
    data->insert(data->end(), f.indices.begin(), f.indices.end());
  for (size_t e = 0; e < ne; ++e)
    data->insert(data->end(),
                 {hull.edges[e][0], hull.edges[e][1], (*edgeFaces)[e][0], (*edgeFaces)[e][1]});
  return static_cast<uint32_t>(base);
}

}  // namespace phys::gpu
