// Convex hulls of point clouds through qhull (reentrant C API), with coplanar facets merged into
// polygons, plus the edge/face adjacency the narrow phase needs.
#include <algorithm>
#include <cfloat>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <string>
#include <utility>
#include <vector>

extern "C" {
#include <libqhull_r/qhull_ra.h>
}

#include "collision/collide_internal.h"
#include "phys/collision/shapes.h"

namespace phys {
namespace detail {

void computeEdgeFaces(const ConvexHull& h, std::vector<std::pair<uint32_t, uint32_t>>* out) {
  constexpr uint32_t kNone = 0xFFFFFFFFu;
  size_t ne = h.edges.size();
  std::vector<std::pair<uint64_t, uint32_t>> keys(ne);
  auto key = [](uint32_t a, uint32_t b) {
    return static_cast<uint64_t>(std::min(a, b)) << 32 | std::max(a, b);
  };
  for (size_t e = 0; e < ne; ++e)
    keys[e] = {key(h.edges[e].first, h.edges[e].second), static_cast<uint32_t>(e)};
  std::sort(keys.begin(), keys.end());
  out->assign(ne, {kNone, kNone});
  for (size_t f = 0; f < h.faces.size(); ++f) {
    const std::vector<uint32_t>& loop = h.faces[f].indices;
    for (size_t k = 0; k < loop.size(); ++k) {
      uint32_t a = loop[k], b = loop[k + 1 == loop.size() ? 0 : k + 1];
      auto it = std::lower_bound(keys.begin(), keys.end(), std::make_pair(key(a, b), 0u));
      if (it == keys.end() || it->first != key(a, b)) continue;
      auto& slot = (*out)[it->second];
      (a < b ? slot.first : slot.second) = static_cast<uint32_t>(f);
    }
  }
  // A hull built by hand may be inconsistent: never leave an index out of range.
  for (auto& s : *out) {
    if (s.first == kNone) s.first = s.second;
    if (s.second == kNone) s.second = s.first;
    if (s.first == kNone) s.first = s.second = 0;
  }
}

}  // namespace detail

namespace {

// Owns qhull's state and its error stream for one run.
class Qhull {
 public:
  Qhull() {
    err_ = open_memstream(&errText_, &errSize_);
    if (!err_) err_ = std::fopen("/dev/null", "w");
    qh_zero(&qh_, err_);
  }
  ~Qhull() {
    qh_freeqhull(&qh_, !qh_ALL);
    int curlong = 0, totlong = 0;
    qh_memfreeshort(&qh_, &curlong, &totlong);
    if (err_) std::fclose(err_);
    std::free(errText_);
  }
  Qhull(const Qhull&) = delete;
  Qhull& operator=(const Qhull&) = delete;

  int run(std::vector<double>& coords, const std::string& options) {
    std::string cmd = "qhull " + options;
    // Output goes nowhere (null outfile); messages go to err_.
    return qh_new_qhull(&qh_, 3, static_cast<int>(coords.size() / 3), coords.data(), False,
                        cmd.data(), nullptr, err_);
  }
  /// First line of qhull's messages.
  std::string firstError() {
    if (err_) std::fflush(err_);
    if (!errText_) return "";
    std::string s(errText_, errSize_);
    size_t nl = s.find('\n');
    return nl == std::string::npos ? s : s.substr(0, nl);
  }
  qhT* qh() { return &qh_; }

 private:
  qhT qh_;
  FILE* err_ = nullptr;
  char* errText_ = nullptr;
  size_t errSize_ = 0;
};

}  // namespace

std::shared_ptr<const ConvexHull> buildConvexHull(const std::vector<Vec3>& points,
                                                  std::string* error) {
  auto fail = [&](const std::string& msg) -> std::shared_ptr<const ConvexHull> {
    if (error) *error = msg;
    return nullptr;
  };
  if (points.size() < 4)
    return fail("a convex hull needs at least 4 points, got " + std::to_string(points.size()));
  Vec3 lo = points[0], hi = points[0];
  float maxAbs = 0;
  for (size_t i = 0; i < points.size(); ++i) {
    if (!isFinite(points[i])) return fail("point " + std::to_string(i) + " is not finite");
    lo = vmin(lo, points[i]);
    hi = vmax(hi, points[i]);
    Vec3 a = vabs(points[i]);
    maxAbs = std::fmax(maxAbs, std::fmax(a.x, std::fmax(a.y, a.z)));
  }
  float extent = length(hi - lo);
  if (!(extent > 0)) return fail("all points coincide");

  std::vector<double> coords;
  coords.reserve(points.size() * 3);
  for (const Vec3& p : points) coords.insert(coords.end(), {p.x, p.y, p.z});
  // Merge facets that are coplanar up to float rounding of the input ("C-n": centrum radius),
  // otherwise a rotated box comes back as triangles.
  double centrum = std::max(4.0 * FLT_EPSILON * maxAbs, 1e-9 * extent);
  char opts[64];
  std::snprintf(opts, sizeof opts, "C-%.3g", centrum);

  Qhull q;
  int code = q.run(coords, opts);
  if (code != 0) {
    std::string msg = q.firstError();
    if (code == qh_ERRsingular || msg.find("QH6154") != std::string::npos ||
        msg.find("flat") != std::string::npos)
      return fail("the points are coplanar or collinear (no volume)");
    return fail("qhull failed (" + std::to_string(code) + "): " + msg);
  }

  qhT* qh = q.qh();
  auto hull = std::make_shared<ConvexHull>();
  // Hull vertices, in input order.
  std::vector<int> remap(points.size(), -1);
  {
    std::vector<int> ids;
    facetT* facet;
    vertexT *vertex, **vertexp;
    FORALLfacets {
      FOREACHvertex_(facet->vertices) ids.push_back(qh_pointid(qh, vertex->point));
    }
    std::sort(ids.begin(), ids.end());
    ids.erase(std::unique(ids.begin(), ids.end()), ids.end());
    for (int id : ids) {
      if (id < 0 || static_cast<size_t>(id) >= points.size()) continue;
      remap[id] = static_cast<int>(hull->vertices.size());
      hull->vertices.push_back(points[id]);
    }
  }
  facetT* facet;
  FORALLfacets {
    ConvexHull::Face face;
    Vec3 n{static_cast<float>(facet->normal[0]), static_cast<float>(facet->normal[1]),
           static_cast<float>(facet->normal[2])};
    face.normal = normalize(n);
    face.offset = static_cast<float>(-facet->offset);
    vertexT *vertex, **vertexp;
    FOREACHvertex_(facet->vertices) {
      int id = qh_pointid(qh, vertex->point);
      if (id >= 0 && static_cast<size_t>(id) < points.size() && remap[id] >= 0)
        face.indices.push_back(static_cast<uint32_t>(remap[id]));
    }
    if (face.indices.size() < 3) continue;
    // Counter-clockwise about the outward normal: sort by angle in the face plane.
    double c[3] = {0, 0, 0};
    for (uint32_t i : face.indices)
      for (int k = 0; k < 3; ++k) c[k] += hull->vertices[i][k];
    for (int k = 0; k < 3; ++k) c[k] /= static_cast<double>(face.indices.size());
    Vec3 t1, t2;
    tangentBasis(face.normal, &t1, &t2);
    std::vector<std::pair<double, uint32_t>> byAngle;
    for (uint32_t i : face.indices) {
      double d[3];
      for (int k = 0; k < 3; ++k) d[k] = hull->vertices[i][k] - c[k];
      double x = d[0] * t1.x + d[1] * t1.y + d[2] * t1.z;
      double y = d[0] * t2.x + d[1] * t2.y + d[2] * t2.z;
      byAngle.push_back({std::atan2(y, x), i});
    }
    std::sort(byAngle.begin(), byAngle.end());
    for (size_t k = 0; k < byAngle.size(); ++k) face.indices[k] = byAngle[k].second;
    hull->faces.push_back(std::move(face));
  }

  for (const auto& f : hull->faces) {
    for (size_t k = 0; k < f.indices.size(); ++k) {
      uint32_t a = f.indices[k], b = f.indices[k + 1 == f.indices.size() ? 0 : k + 1];
      hull->edges.push_back({std::min(a, b), std::max(a, b)});
    }
  }
  std::sort(hull->edges.begin(), hull->edges.end());
  hull->edges.erase(std::unique(hull->edges.begin(), hull->edges.end()), hull->edges.end());
  detail::computeEdgeFaces(*hull, &hull->edgeFaces);

  // At density 1 the mass is the volume and the centre of mass the volume centroid.
  MassProperties mp = computeMass(ShapeGeom::convexHull(hull), 1.0f);
  if (hull->faces.size() < 4 || !(double(mp.mass) > 1e-9 * extent * extent * extent))
    return fail("the points are coplanar or collinear (no volume)");
  hull->centroid = mp.center;
  return hull;
}

std::shared_ptr<const ConvexHull> buildHull(const std::shared_ptr<const ConvexHull>& hull,
                                            std::string* error, HullBuildCache* cache) {
  if (!hull || hull->built()) return hull;
  if (cache) {
    auto it = cache->find(hull.get());
    if (it != cache->end()) return it->second.second;
  }
  auto built = buildConvexHull(hull->vertices, error);
  if (built && cache) (*cache)[hull.get()] = {hull, built};
  return built;
}

}  // namespace phys
