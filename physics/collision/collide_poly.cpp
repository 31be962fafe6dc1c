// Contacts of boxes and hulls with hulls (SAT with Gauss-map pruning and face clipping), and of
// boxes and hulls with spheres and capsules (exact closest features when the cores are apart,
// SAT when they overlap). A box runs through the same code as a scaled unit-box hull.
#include <cmath>
#include <initializer_list>
#include <limits>
#include <vector>

#include "collision/collide_internal.h"

namespace phys::detail {

const ConvexHull& unitBoxHull() {
  static const ConvexHull hull = [] {
    ConvexHull h;
    for (uint32_t v = 0; v < 8; ++v)
      h.vertices.push_back(
          {(v & 1u) ? 1.0f : -1.0f, (v & 2u) ? 1.0f : -1.0f, (v & 4u) ? 1.0f : -1.0f});
    const uint32_t loops[6][4] = {{1, 3, 7, 5}, {0, 4, 6, 2}, {2, 6, 7, 3},
                                  {0, 1, 5, 4}, {4, 5, 7, 6}, {0, 2, 3, 1}};
    for (int f = 0; f < 6; ++f) {
      ConvexHull::Face face;
      face.normal[f >> 1] = (f & 1) ? -1.0f : 1.0f;
      face.offset = 1;
      face.indices.assign(loops[f], loops[f] + 4);
      h.faces.push_back(face);
    }
    // Edge 4 * axis + bits: bit 0, 1 = positive side on axis + 1, axis + 2.
    for (int axis = 0; axis < 3; ++axis) {
      for (uint32_t bits = 0; bits < 4; ++bits) {
        uint32_t v = 0;
        if (bits & 1u) v |= 1u << ((axis + 1) % 3);
        if (bits & 2u) v |= 1u << ((axis + 2) % 3);
        h.edges.push_back({v, v | 1u << axis});
      }
    }
    computeEdgeFaces(h, &h.edgeFaces);
    return h;
  }();
  return hull;
}

namespace {

constexpr float kInf = std::numeric_limits<float>::infinity();

// ---- Box or hull against box or hull ------------------------------------------------------

struct WorldPoly {
  const ConvexHull* h;
  const std::pair<uint32_t, uint32_t>* edgeFaces;
  const Vec3* v;   // world vertices
  const Vec3* n;   // world face normals
  const float* o;  // world face offsets
  int nv, nf, ne;
  Vec3 centroid;
};

struct PolyScratch {
  std::vector<Vec3> v, n;
  std::vector<float> o;
  std::vector<std::pair<uint32_t, uint32_t>> adj;
};
struct Scratch {
  PolyScratch poly[2];
  std::vector<ClipVertex> clipA, clipB;
  std::vector<ClipPlane> planes;
};
// Per-thread buffers: they grow to the largest hull seen and are then reused.
Scratch& scratch() {
  thread_local Scratch s;
  return s;
}

WorldPoly toWorld(const ShapeGeom& g, const Transform& xf, PolyScratch& s) {
  PolyRef p = PolyRef::of(g);
  const ConvexHull& h = *p.h;
  Mat3 r = toMat3(xf.q);
  int nv = static_cast<int>(h.vertices.size()), nf = static_cast<int>(h.faces.size());
  s.v.resize(nv);
  for (int i = 0; i < nv; ++i) s.v[i] = xf.p + r * p.vertex(static_cast<uint32_t>(i));
  s.n.resize(nf);
  s.o.resize(nf);
  for (int f = 0; f < nf; ++f) {
    s.n[f] = r * p.normal(f);
    s.o[f] = p.offset(f) + dot(s.n[f], xf.p);
  }
  const std::pair<uint32_t, uint32_t>* adj = h.edgeFaces.data();
  if (h.edgeFaces.size() != h.edges.size()) {
    computeEdgeFaces(h, &s.adj);
    adj = s.adj.data();
  }
  return {&h,
          adj,
          s.v.data(),
          s.n.data(),
          s.o.data(),
          nv,
          nf,
          static_cast<int>(h.edges.size()),
          xf.p + r * p.centroid()};
}

struct FaceQuery {
  float sep = -kInf;
  int face = -1;
};
// Best face of p: the one whose plane q lies farthest in front of.
FaceQuery queryFaces(const WorldPoly& p, const WorldPoly& q, float margin) {
  FaceQuery best;
  for (int f = 0; f < p.nf; ++f) {
    float m = kInf;
    for (int j = 0; j < q.nv; ++j) m = minf(m, dot(p.n[f], q.v[j]));
    float s = m - p.o[f];
    if (s > best.sep) best.sep = s, best.face = f;
    if (s > margin) break;
  }
  return best;
}

struct EdgeQuery {
  float sep = -kInf;
  int ea = -1, eb = -1;
  Vec3 n;  // from p to q
};
// Edge pairs of p and q that form a face of the Minkowski difference (Gregorius, GDC 2013).
EdgeQuery queryEdges(const WorldPoly& p, const WorldPoly& q, float margin) {
  EdgeQuery best;
  for (int i = 0; i < p.ne; ++i) {
    Vec3 pa = p.v[p.h->edges[i].first];
    Vec3 ep = p.v[p.h->edges[i].second] - pa;
    Vec3 a = p.n[p.edgeFaces[i].first], b = p.n[p.edgeFaces[i].second];
    Vec3 bxa = cross(b, a);
    for (int j = 0; j < q.ne; ++j) {
      Vec3 c = -q.n[q.edgeFaces[j].first], d = -q.n[q.edgeFaces[j].second];
      Vec3 dxc = cross(d, c);
      float cba = dot(c, bxa), dba = dot(d, bxa), adc = dot(a, dxc), bdc = dot(b, dxc);
      if (!(cba * dba < 0 && adc * bdc < 0 && cba * bdc > 0)) continue;
      Vec3 qa = q.v[q.h->edges[j].first];
      Vec3 eq = q.v[q.h->edges[j].second] - qa;
      Vec3 n = cross(ep, eq);
      float len = length(n);
      if (len < 1e-4f * std::sqrt(lengthSquared(ep) * lengthSquared(eq))) continue;
      n = n * (1.0f / len);
      if (dot(n, pa - p.centroid) < 0) n = -n;
      float s = dot(n, qa - pa);
      if (s > best.sep) best.sep = s, best.ea = i, best.eb = j, best.n = n;
      if (s > margin) return best;
    }
  }
  return best;
}

bool polyFaceContact(const WorldPoly& ref, const WorldPoly& inc, int face, bool refIsB,
                     float margin, Scratch& s, Manifold* out) {
  Vec3 nRef = ref.n[face];
  float refOffset = ref.o[face];
  int incFace = 0;
  float best = kInf;
  for (int g = 0; g < inc.nf; ++g) {
    float d = dot(inc.n[g], nRef);
    if (d < best) best = d, incFace = g;
  }
  const std::vector<uint32_t>& rl = ref.h->faces[face].indices;
  const std::vector<uint32_t>& il = inc.h->faces[incFace].indices;
  int nr = static_cast<int>(rl.size()), ni = static_cast<int>(il.size());
  s.planes.resize(nr);
  for (int k = 0; k < nr; ++k) {
    Vec3 a = ref.v[rl[k]], b = ref.v[rl[k + 1 == nr ? 0 : k + 1]];
    Vec3 sn = normalize(cross(b - a, nRef));
    s.planes[k] = {sn, dot(sn, a)};
  }
  size_t cap = static_cast<size_t>(nr + ni + 1);
  if (s.clipA.size() < cap) s.clipA.resize(cap), s.clipB.resize(cap);
  for (int q = 0; q < ni; ++q) {
    ClipVertex& v = s.clipA[q];
    v.p = inc.v[il[q]];
    v.feature = localFeature(0, static_cast<uint32_t>(q), 0);
    v.edge = static_cast<uint16_t>(q & 0x7FFF);
  }
  ClipVertex* pts;
  int n = clipPolygon(s.clipA.data(), s.clipB.data(), ni, s.planes.data(), nr, &pts);
  for (int q = 0; q < n; ++q) pts[q].sep = dot(nRef, pts[q].p) - refOffset;
  return emitFaceContacts(pts, n, nRef, margin, refIsB, static_cast<uint32_t>(face),
                          static_cast<uint32_t>(incFace), out);
}

// ---- Box or hull in its own frame against points and segments -------------------------------

bool insideFace(const PolyRef& p, int f, Vec3 x) {
  const std::vector<uint32_t>& loop = p.h->faces[f].indices;
  Vec3 n = p.normal(f);
  size_t m = loop.size();
  for (size_t k = 0; k < m; ++k) {
    Vec3 a = p.vertex(loop[k]), b = p.vertex(loop[k + 1 == m ? 0 : k + 1]);
    if (dot(cross(b - a, x - a), n) < 0) return false;
  }
  return true;
}

// Closest point of the shape to x, x outside.
Vec3 closestPointOutside(const PolyRef& p, Vec3 x) {
  if (p.isBox)
    return {maxf(-p.scale.x, minf(p.scale.x, x.x)), maxf(-p.scale.y, minf(p.scale.y, x.y)),
            maxf(-p.scale.z, minf(p.scale.z, x.z))};
  // A projection that lands on its face is the answer (the offset is in that face's normal
  // cone); otherwise the closest point lies on an edge.
  for (int f = 0; f < p.numFaces(); ++f) {
    float d = dot(p.normal(f), x) - p.offset(f);
    if (d <= 0) continue;
    Vec3 proj = x - p.normal(f) * d;
    if (insideFace(p, f, proj)) return proj;
  }
  Vec3 best = x;
  float bestD2 = kInf;
  for (const auto& e : p.h->edges) {
    Vec3 a = p.vertex(e.first), b = p.vertex(e.second);
    Vec3 c = a + (b - a) * closestOnSegment(a, b, x);
    float d2 = lengthSquared(x - c);
    if (d2 < bestD2) bestD2 = d2, best = c;
  }
  return best;
}

// Clips segment p0 p1 to the prism over face f; returns the parameter range.
bool clipSegmentToFace(const PolyRef& p, int f, Vec3 p0, Vec3 p1, float* t0, float* t1) {
  const std::vector<uint32_t>& loop = p.h->faces[f].indices;
  Vec3 n = p.normal(f);
  size_t m = loop.size();
  float lo = 0, hi = 1;
  for (size_t k = 0; k < m; ++k) {
    Vec3 a = p.vertex(loop[k]), b = p.vertex(loop[k + 1 == m ? 0 : k + 1]);
    Vec3 sn = normalize(cross(b - a, n));
    float d = dot(sn, a);
    float d0 = dot(sn, p0) - d, d1 = dot(sn, p1) - d;
    // Ends within the slop stay; cuts go exactly onto the side plane.
    if (d0 > kClipSlop && d1 > kClipSlop) return false;
    if (d0 > kClipSlop) lo = maxf(lo, d1 >= 0 ? 1.0f : d0 / (d0 - d1));
    if (d1 > kClipSlop) hi = minf(hi, d0 >= 0 ? 0.0f : d0 / (d0 - d1));
  }
  *t0 = lo;
  *t1 = hi;
  return lo <= hi;
}

// Capsule core p0 p1 (radius r, shape-local) over face f of p: up to two points, normal = face.
int segmentFaceContacts(const PolyRef& p, int f, Vec3 p0, Vec3 p1, float r, float margin,
                        const Transform& xf, Manifold* out) {
  float t0, t1;
  if (!clipSegmentToFace(p, f, p0, p1, &t0, &t1)) return 0;
  Vec3 n = p.normal(f);
  float o = p.offset(f);
  Vec3 x[2] = {p0 + (p1 - p0) * t0, p0 + (p1 - p0) * t1};
  bool clipped[2] = {t0 > 0, t1 < 1};
  int ends = (t1 - t0) * length(p1 - p0) > 1e-6f ? 2 : 1;
  int count = 0;
  for (int k = 0; k < ends; ++k) {
    float sep = dot(n, x[k]) - o - r;
    if (sep >= margin) continue;
    uint32_t feature = static_cast<uint32_t>(f) << 1 | static_cast<uint32_t>(k);
    out->points[count++] = {apply(xf, x[k] - n * (r + 0.5f * sep)), sep,
                            otherFeatureId(clipped[k] ? 2 : 1, feature)};
  }
  out->count = count;
  out->normal = rotate(xf.q, n);
  return count;
}

}  // namespace

bool collidePolyPoly(const ShapeGeom& a, const Transform& xa, const ShapeGeom& b,
                     const Transform& xb, float margin, Manifold* out) {
  Scratch& s = scratch();
  WorldPoly A = toWorld(a, xa, s.poly[0]);
  WorldPoly B = toWorld(b, xb, s.poly[1]);
  FaceQuery fa = queryFaces(A, B, margin);
  if (fa.sep > margin) return false;
  FaceQuery fb = queryFaces(B, A, margin);
  if (fb.sep > margin) return false;
  EdgeQuery ee = queryEdges(A, B, margin);
  if (ee.sep > margin) return false;

  auto edgeContact = [&]() {
    const auto& ea = A.h->edges[ee.ea];
    const auto& eb = B.h->edges[ee.eb];
    float t, u;
    Vec3 pa, pb;
    closestSegmentSegment(A.v[ea.first], A.v[ea.second], B.v[eb.first], B.v[eb.second], &t, &u, &pa,
                          &pb);
    out->normal = ee.n;
    out->count = 1;
    out->points[0] = {0.5f * (pa + pb), ee.sep,
                      edgeFeatureId(static_cast<uint32_t>(ee.ea), static_cast<uint32_t>(ee.eb))};
    return ee.sep < margin;
  };
  bool haveEdge = ee.ea >= 0;
  if (haveEdge && beats(ee.sep, maxf(fa.sep, fb.sep), kEdgeRelTol, kEdgeAbsTol)) {
    // As in collideBoxBox: an edge axis close to a face normal is nearly parallel faces meeting
    // over a rim; that face's clipped contact holds the whole face, one rim point does not.
    int faceA = -1, faceB = -1;
    float dotA = kEdgeFaceCos, dotB = kEdgeFaceCos;
    for (int f = 0; f < A.nf; ++f) {
      float d = dot(A.n[f], ee.n);
      if (d >= dotA) dotA = d, faceA = f;
    }
    for (int f = 0; f < B.nf; ++f) {
      float d = -dot(B.n[f], ee.n);
      if (d >= dotB) dotB = d, faceB = f;
    }
    if (faceA >= 0) {
      if (polyFaceContact(A, B, faceA, false, margin, s, out)) return true;
    } else if (faceB >= 0) {
      if (polyFaceContact(B, A, faceB, true, margin, s, out)) return true;
    }
    return edgeContact();
  }
  // Prefer A's face unless B's is clearly better, so the reference face does not flip-flop.
  bool refB = beats(fb.sep, fa.sep, kFaceRelTol, kFaceAbsTol);
  if (refB ? polyFaceContact(B, A, fb.face, true, margin, s, out)
           : polyFaceContact(A, B, fa.face, false, margin, s, out))
    return true;
  // The favoured face's clip came out empty: fall back rather than miss the contact.
  if (haveEdge && edgeContact()) return true;
  return refB ? polyFaceContact(A, B, fa.face, false, margin, s, out)
              : polyFaceContact(B, A, fb.face, true, margin, s, out);
}

bool collidePolySphere(const ShapeGeom& a, const Transform& xa, const ShapeGeom& b,
                       const Transform& xb, float margin, Manifold* out) {
  PolyRef p = PolyRef::of(a);
  Vec3 c = applyInverse(xa, xb.p);
  float r = b.radius;
  int fmax = 0;
  float dmax = -kInf;
  for (int f = 0; f < p.numFaces(); ++f) {
    float d = dot(p.normal(f), c) - p.offset(f);
    if (d > dmax) dmax = d, fmax = f;
  }
  if (dmax - r >= margin) return false;
  Vec3 q, n;
  float sep;
  if (dmax <= 0) {
    // Centre inside: push out through the nearest face.
    n = p.normal(fmax);
    q = c - n * dmax;
    sep = dmax - r;
  } else {
    q = closestPointOutside(p, c);
    Vec3 v = c - q;
    float dist = length(v);
    n = dist > 1e-7f ? v * (1.0f / dist) : p.normal(fmax);
    sep = dist - r;
  }
  if (sep >= margin) return false;
  out->normal = rotate(xa.q, n);
  out->count = 1;
  out->points[0] = {apply(xa, q + n * (0.5f * sep)), sep, otherFeatureId(0, 0)};
  return true;
}

bool collidePolyCapsule(const ShapeGeom& a, const Transform& xa, const ShapeGeom& b,
                        const Transform& xb, float margin, Manifold* out) {
  PolyRef p = PolyRef::of(a);
  Vec3 axis = rotate(xb.q, Vec3{0, 0, b.halfHeight});
  Vec3 p0 = applyInverse(xa, xb.p - axis), p1 = applyInverse(xa, xb.p + axis);
  float r = b.radius;

  // Face axes, and whether the core segment crosses the shape (Cyrus-Beck).
  float faceSep = -kInf;
  int face = 0;
  float tlo = 0, thi = 1;
  bool apart = false;
  for (int f = 0; f < p.numFaces(); ++f) {
    Vec3 n = p.normal(f);
    float o = p.offset(f);
    float d0 = dot(n, p0) - o, d1 = dot(n, p1) - o;
    float sf = minf(d0, d1) - r;
    if (sf > margin) return false;
    if (sf > faceSep) faceSep = sf, face = f;
    if (d0 > 0 && d1 > 0) {
      apart = true;
    } else if (d0 > 0) {
      tlo = maxf(tlo, d0 / (d0 - d1));
    } else if (d1 > 0) {
      thi = minf(thi, d0 / (d0 - d1));
    }
  }
  if (tlo > thi) apart = true;

  if (apart) {
    // Exact closest points: a segment end against a face or the segment against an edge.
    float best = kInf;
    Vec3 bs, bq;
    for (Vec3 e : {p0, p1}) {
      if (p.isBox) {
        Vec3 q = closestPointOutside(p, e);
        float d2 = lengthSquared(e - q);
        if (d2 < best) best = d2, bs = e, bq = q;
        continue;
      }
      for (int f = 0; f < p.numFaces(); ++f) {
        float d = dot(p.normal(f), e) - p.offset(f);
        if (d <= 0 || d * d >= best) continue;
        Vec3 proj = e - p.normal(f) * d;
        if (insideFace(p, f, proj)) best = d * d, bs = e, bq = proj;
      }
    }
    for (const auto& e : p.h->edges) {
      float s, t;
      Vec3 c1, c2;
      closestSegmentSegment(p0, p1, p.vertex(e.first), p.vertex(e.second), &s, &t, &c1, &c2);
      float d2 = lengthSquared(c1 - c2);
      if (d2 < best) best = d2, bs = c1, bq = c2;
    }
    Vec3 v = bs - bq;
    float dist = length(v);
    if (dist > 1e-6f) {
      Vec3 n = v * (1.0f / dist);
      float sep = dist - r;
      if (sep >= margin) return false;
      // Lying on a face: both ends of the core over that face.
      int fbest = 0;
      float cbest = -2;
      for (int f = 0; f < p.numFaces(); ++f) {
        float c = dot(p.normal(f), n);
        if (c > cbest) cbest = c, fbest = f;
      }
      if (cbest > 0.9999f && segmentFaceContacts(p, fbest, p0, p1, r, margin, xa, out) > 0)
        return true;
      out->normal = rotate(xa.q, n);
      out->count = 1;
      out->points[0] = {apply(xa, bq + n * (0.5f * sep)), sep, otherFeatureId(0, 0)};
      return true;
    }
  }

  // The core touches or crosses the shape: least-penetration axis over the faces and the
  // crosses of the core with the edges.
  Vec3 u = p1 - p0;
  float edgeSep = -kInf;
  int edge = -1;
  Vec3 edgeN;
  if (lengthSquared(u) > 1e-12f) {
    for (int e = 0; e < static_cast<int>(p.h->edges.size()); ++e) {
      Vec3 va = p.vertex(p.h->edges[e].first), vb = p.vertex(p.h->edges[e].second);
      Vec3 n = cross(vb - va, u);
      float len = length(n);
      if (len < 1e-4f * std::sqrt(lengthSquared(vb - va) * lengthSquared(u))) continue;
      n = n * (1.0f / len);
      float sp = dot(n, p0);
      float hi = p.support(n), lo = -p.support(-n);
      float s1 = sp - r - hi;  // capsule on the +n side
      float s2 = lo - sp - r;  // capsule on the -n side
      float se = maxf(s1, s2);
      if (se > margin) return false;
      // Parallel edges share the axis; only the one on the shape's support along it touches.
      float ve = dot(n, va), tol = 1e-5f * (hi - lo);
      bool onSupport = s1 >= s2 ? ve >= hi - tol : ve <= lo + tol;
      if (onSupport && se > edgeSep) edgeSep = se, edge = e, edgeN = s1 >= s2 ? n : -n;
    }
  }
  if (edge >= 0 && beats(edgeSep, faceSep, kEdgeRelTol, kEdgeAbsTol)) {
    float s, t;
    Vec3 c1, c2;
    closestSegmentSegment(p0, p1, p.vertex(p.h->edges[edge].first),
                          p.vertex(p.h->edges[edge].second), &s, &t, &c1, &c2);
    out->normal = rotate(xa.q, edgeN);
    out->count = 1;
    out->points[0] = {apply(xa, c2 + edgeN * (0.5f * edgeSep)), edgeSep,
                      otherFeatureId(3, static_cast<uint32_t>(edge))};
    return edgeSep < margin;
  }
  if (segmentFaceContacts(p, face, p0, p1, r, margin, xa, out) > 0) return true;
  // The core's shadow misses the face (rare): the deeper end alone.
  Vec3 n = p.normal(face);
  Vec3 e = dot(n, p0) <= dot(n, p1) ? p0 : p1;
  float sep = dot(n, e) - p.offset(face) - r;
  if (sep >= margin) return false;
  out->normal = rotate(xa.q, n);
  out->count = 1;
  out->points[0] = {apply(xa, e - n * (r + 0.5f * sep)), sep,
                    otherFeatureId(1, static_cast<uint32_t>(face) << 1)};
  return true;
}

}  // namespace phys::detail
