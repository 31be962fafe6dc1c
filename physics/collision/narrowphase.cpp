// Narrow phase: the dispatch table, contact clipping and reduction, and the pairs of spheres,
// capsules and planes. Box-box is in collide_box.cpp, the box/hull pairs in collide_poly.cpp.
#include <cmath>

#include "collision/collide_internal.h"
#include "phys/collision/shapes.h"

namespace phys {
namespace detail {

int clipPolygon(ClipVertex* a, ClipVertex* b, int n, const ClipPlane* planes, int numPlanes,
                ClipVertex** result) {
  ClipVertex* in = a;
  ClipVertex* out = b;
  for (int p = 0; p < numPlanes && n > 0; ++p) {
    const ClipPlane& pl = planes[p];
    uint16_t side = static_cast<uint16_t>(kSideLabel | p);
    int m = 0;
    for (int k = 0; k < n; ++k) {
      const ClipVertex& cur = in[k];
      const ClipVertex& nxt = in[k + 1 == n ? 0 : k + 1];
      float dc = dot(pl.n, cur.p) - pl.d;
      float dn = dot(pl.n, nxt.p) - pl.d;
      // Vertices within the slop count as inside; new points go exactly onto the plane.
      bool curIn = dc <= kClipSlop, nxtIn = dn <= kClipSlop;
      if (curIn) out[m++] = cur;
      if (curIn == nxtIn) continue;
      if (curIn && dc >= 0) {
        out[m - 1].edge = side;  // cur sits on the plane (within the slop): leave from it
        continue;
      }
      if (!curIn && dn >= 0) continue;  // nxt sits on the plane: enter at nxt itself
      ClipVertex& v = out[m++];
      float t = dc / (dc - dn);
      v.p = cur.p + (nxt.p - cur.p) * t;
      if (cur.edge & kSideLabel) {
        uint32_t s0 = cur.edge & ~kSideLabel, s1 = static_cast<uint32_t>(p);
        v.feature = localFeature(2, s0 < s1 ? s0 : s1, s0 < s1 ? s1 : s0);
      } else {
        v.feature = localFeature(1, cur.edge, static_cast<uint32_t>(p));
      }
      // Leaving: the polygon now runs along the plane; entering: along cur's edge.
      v.edge = curIn ? side : cur.edge;
    }
    n = m;
    ClipVertex* t = in;
    in = out;
    out = t;
  }
  *result = in;
  return n;
}

bool emitFaceContacts(ClipVertex* pts, int n, Vec3 nRef, float margin, bool refIsB,
                      uint32_t refFace, uint32_t incFace, Manifold* out) {
  int sel[4];
  int count = selectFour(
      n, nRef, [&](int i) { return pts[i].p; }, [&](int i) { return pts[i].sep; },
      [&](int i) { return pts[i].sep < margin; }, sel);
  uint32_t base =
      (refIsB ? kKindFaceB : kKindFaceA) | (refFace & 0xFFu) << 22 | (incFace & 0xFFu) << 14;
  out->normal = refIsB ? -nRef : nRef;
  out->count = count;
  for (int k = 0; k < count; ++k) {
    const ClipVertex& v = pts[sel[k]];
    out->points[k].point = v.p - nRef * (0.5f * v.sep);
    out->points[k].separation = v.sep;
    out->points[k].featureId = base | v.feature;
  }
  return count > 0;
}

float closestOnSegment(Vec3 a, Vec3 b, Vec3 p) {
  Vec3 ab = b - a;
  float l2 = dot(ab, ab);
  if (l2 <= 1e-20f) return 0;
  return clamp01(dot(p - a, ab) / l2);
}

void closestSegmentSegment(Vec3 p1, Vec3 q1, Vec3 p2, Vec3 q2, float* s, float* t, Vec3* c1,
                           Vec3* c2) {
  // Ericson, Real-Time Collision Detection 5.1.9.
  Vec3 d1 = q1 - p1, d2 = q2 - p2, r = p1 - p2;
  float a = dot(d1, d1), e = dot(d2, d2), f = dot(d2, r);
  constexpr float kEps = 1e-20f;
  float ss = 0, tt = 0;
  if (a <= kEps && e <= kEps) {
  } else if (a <= kEps) {
    tt = clamp01(f / e);
  } else {
    float c = dot(d1, r);
    if (e <= kEps) {
      ss = clamp01(-c / a);
    } else {
      float b = dot(d1, d2);
      float denom = a * e - b * b;
      ss = denom > 1e-10f * a * e ? clamp01((b * f - c * e) / denom) : 0;
      tt = (b * ss + f) / e;
      if (tt < 0) {
        tt = 0;
        ss = clamp01(-c / a);
      } else if (tt > 1) {
        tt = 1;
        ss = clamp01((b - c) / a);
      }
    }
  }
  *s = ss;
  *t = tt;
  *c1 = p1 + d1 * ss;
  *c2 = p2 + d2 * tt;
}

}  // namespace detail

namespace {

using namespace detail;

// A unit vector perpendicular to v (deterministic), for normals of coincident cores.
Vec3 anyPerpendicular(Vec3 v) {
  Vec3 n = normalize(v);
  if (lengthSquared(n) == 0) return {0, 0, 1};
  Vec3 t1, t2;
  tangentBasis(n, &t1, &t2);
  return t1;
}

void capsuleSegment(const ShapeGeom& g, const Transform& xf, Vec3* p0, Vec3* p1) {
  Vec3 axis = rotate(xf.q, Vec3{0, 0, g.halfHeight});
  *p0 = xf.p - axis;
  *p1 = xf.p + axis;
}

void setSingle(Manifold* out, Vec3 normal, Vec3 point, float sep, uint32_t id) {
  out->normal = normal;
  out->count = 1;
  out->points[0] = {point, sep, id};
}

// Two cores (points or segment points) ca, cb with radii: one point.
bool roundContact(Vec3 ca, float ra, Vec3 cb, float rb, Vec3 fallbackNormal, float margin,
                  Manifold* out) {
  Vec3 v = cb - ca;
  float dist = length(v);
  float sep = dist - ra - rb;
  if (sep >= margin) return false;
  Vec3 n = dist > 1e-6f ? v * (1.0f / dist) : fallbackNormal;
  Vec3 point = 0.5f * ((ca + n * ra) + (cb - n * rb));
  setSingle(out, n, point, sep, otherFeatureId(0, 0));
  return true;
}

bool collideSphereSphere(const ShapeGeom& a, const Transform& xa, const ShapeGeom& b,
                         const Transform& xb, float margin, Manifold* out) {
  return roundContact(xa.p, a.radius, xb.p, b.radius, {0, 0, 1}, margin, out);
}

// Capsule (A) against sphere (B).
bool collideCapsuleSphere(const ShapeGeom& a, const Transform& xa, const ShapeGeom& b,
                          const Transform& xb, float margin, Manifold* out) {
  Vec3 p0, p1;
  capsuleSegment(a, xa, &p0, &p1);
  float t = closestOnSegment(p0, p1, xb.p);
  Vec3 c = p0 + (p1 - p0) * t;
  return roundContact(c, a.radius, xb.p, b.radius, anyPerpendicular(p1 - p0), margin, out);
}

bool collideCapsuleCapsule(const ShapeGeom& a, const Transform& xa, const ShapeGeom& b,
                           const Transform& xb, float margin, Manifold* out) {
  Vec3 pa0, pa1, pb0, pb1;
  capsuleSegment(a, xa, &pa0, &pa1);
  capsuleSegment(b, xb, &pb0, &pb1);
  float s, t;
  Vec3 c1, c2;
  closestSegmentSegment(pa0, pa1, pb0, pb1, &s, &t, &c1, &c2);
  Vec3 v = c2 - c1;
  float dist = length(v);
  float rsum = a.radius + b.radius;
  if (dist - rsum >= margin) return false;

  Vec3 ua = pa1 - pa0, ub = pb1 - pb0;
  float la = length(ua), lb = length(ub);
  if (la > 1e-6f && lb > 1e-6f) {
    Vec3 ea = ua * (1.0f / la);
    // Nearly parallel (within ~3 degrees) and overlapping: two points at the overlap's ends, so
    // a capsule lying on another does not rock about a single point.
    if (length(cross(ea, ub * (1.0f / lb))) < 0.05f) {
      float tb0 = dot(pb0 - pa0, ea), tb1 = dot(pb1 - pa0, ea);
      float lo = maxf(0.0f, minf(tb0, tb1)), hi = minf(la, maxf(tb0, tb1));
      if (hi - lo > 1e-3f * minf(la, lb)) {
        Vec3 perp = v - ea * dot(v, ea);
        float pl = length(perp);
        Vec3 n;
        if (pl > 1e-6f) {
          n = perp * (1.0f / pl);
        } else {
          Vec3 dc = (pb0 + pb1) * 0.5f - (pa0 + pa1) * 0.5f;
          dc -= ea * dot(dc, ea);
          n = length(dc) > 1e-6f ? normalize(dc) : anyPerpendicular(ea);
        }
        int count = 0;
        float ends[2] = {lo, hi};
        for (int k = 0; k < 2; ++k) {
          float w = clamp01((ends[k] - tb0) / (tb1 - tb0));
          Vec3 xb2 = pb0 + ub * w;
          Vec3 xa2 = pa0 + ea * ends[k];
          float sep = dot(xb2 - xa2, n) - rsum;
          if (sep >= margin) continue;
          Vec3 point = 0.5f * ((xa2 + n * a.radius) + (xb2 - n * b.radius));
          out->points[count++] = {point, sep, otherFeatureId(2, static_cast<uint32_t>(k))};
        }
        if (count > 0) {
          out->normal = n;
          out->count = count;
          return true;
        }
      }
    }
  }
  Vec3 fallback = cross(ua, ub);
  if (lengthSquared(fallback) > 1e-12f) {
    fallback = normalize(fallback);
    if (dot(fallback, xb.p - xa.p) < 0) fallback = -fallback;
  } else {
    fallback = anyPerpendicular(la > 1e-6f ? ua : ub);
  }
  return roundContact(c1, a.radius, c2, b.radius, fallback, margin, out);
}

// World plane of a plane shape: dot(n, x) = d.
void worldPlane(const ShapeGeom& g, const Transform& xf, Vec3* n, float* d) {
  *n = rotate(xf.q, g.normal);
  *d = g.offset + dot(*n, xf.p);
}

// Plane (A) against sphere (B).
bool collidePlaneSphere(const ShapeGeom& a, const Transform& xa, const ShapeGeom& b,
                        const Transform& xb, float margin, Manifold* out) {
  Vec3 n;
  float d;
  worldPlane(a, xa, &n, &d);
  float sep = dot(n, xb.p) - d - b.radius;
  if (sep >= margin) return false;
  setSingle(out, n, xb.p - n * (b.radius + 0.5f * sep), sep, otherFeatureId(0, 0));
  return true;
}

// Plane (A) against capsule (B): both segment ends.
bool collidePlaneCapsule(const ShapeGeom& a, const Transform& xa, const ShapeGeom& b,
                         const Transform& xb, float margin, Manifold* out) {
  Vec3 n;
  float d;
  worldPlane(a, xa, &n, &d);
  Vec3 ends[2];
  capsuleSegment(b, xb, &ends[0], &ends[1]);
  int count = 0;
  for (int k = 0; k < 2; ++k) {
    float sep = dot(n, ends[k]) - d - b.radius;
    if (sep >= margin) continue;
    out->points[count++] = {ends[k] - n * (b.radius + 0.5f * sep), sep,
                            otherFeatureId(1, static_cast<uint32_t>(k))};
  }
  out->normal = n;
  out->count = count;
  return count > 0;
}

// Plane (A) against box or hull (B): every vertex below the margin, reduced to four. Works in
// B's frame so nothing is stored per vertex.
bool collidePlanePoly(const ShapeGeom& a, const Transform& xa, const ShapeGeom& b,
                      const Transform& xb, float margin, Manifold* out) {
  if (b.type == ShapeType::Hull && !b.hull) return false;
  Vec3 n;
  float d;
  worldPlane(a, xa, &n, &d);
  Vec3 nl = invRotate(xb.q, n);
  float dl = d - dot(n, xb.p);
  PolyRef poly = PolyRef::of(b);
  // Quick reject on the lowest point.
  if (-poly.support(-nl) - dl >= margin) return false;
  int nv = static_cast<int>(poly.h->vertices.size());
  auto pointAt = [&](int i) { return poly.vertex(static_cast<uint32_t>(i)); };
  auto sepAt = [&](int i) { return dot(nl, pointAt(i)) - dl; };
  int sel[4];
  int count = selectFour(
      nv, nl, pointAt, sepAt, [&](int i) { return sepAt(i) < margin; }, sel);
  out->normal = n;
  out->count = count;
  for (int k = 0; k < count; ++k) {
    float sep = sepAt(sel[k]);
    out->points[k] = {apply(xb, pointAt(sel[k]) - nl * (0.5f * sep)), sep,
                      otherFeatureId(1, static_cast<uint32_t>(sel[k]))};
  }
  return count > 0;
}

bool collideHullHull(const ShapeGeom& a, const Transform& xa, const ShapeGeom& b,
                     const Transform& xb, float margin, Manifold* out) {
  if (!a.hull || !b.hull) return false;
  return collidePolyPoly(a, xa, b, xb, margin, out);
}
bool collideHullOther(const ShapeGeom& a, const Transform& xa, const ShapeGeom& b,
                      const Transform& xb, float margin, Manifold* out) {
  if (!a.hull) return false;
  switch (b.type) {
    case ShapeType::Sphere:
      return collidePolySphere(a, xa, b, xb, margin, out);
    case ShapeType::Capsule:
      return collidePolyCapsule(a, xa, b, xb, margin, out);
    default:
      return false;
  }
}
bool collideBoxHull(const ShapeGeom& a, const Transform& xa, const ShapeGeom& b,
                    const Transform& xb, float margin, Manifold* out) {
  if (!b.hull) return false;
  return collidePolyPoly(a, xa, b, xb, margin, out);
}

using PairFn = bool (*)(const ShapeGeom&, const Transform&, const ShapeGeom&, const Transform&,
                        float, Manifold*);
struct PairEntry {
  PairFn fn;
  bool flip;  // the routine is written for (B, A): swap the shapes and negate its normal
};

// Rows: A's type, columns: B's type (Sphere, Box, Capsule, Plane, Hull).
constexpr PairEntry kPairs[kShapeTypeCount][kShapeTypeCount] = {
    {{collideSphereSphere, false},
     {collidePolySphere, true},
     {collideCapsuleSphere, true},
     {collidePlaneSphere, true},
     {collideHullOther, true}},
    {{collidePolySphere, false},
     {collideBoxBox, false},
     {collidePolyCapsule, false},
     {collidePlanePoly, true},
     {collideBoxHull, false}},
    {{collideCapsuleSphere, false},
     {collidePolyCapsule, true},
     {collideCapsuleCapsule, false},
     {collidePlaneCapsule, true},
     {collideHullOther, true}},
    {{collidePlaneSphere, false},
     {collidePlanePoly, false},
     {collidePlaneCapsule, false},
     {nullptr, false},
     {collidePlanePoly, false}},
    {{collideHullOther, false},
     {collideBoxHull, true},
     {collideHullOther, false},
     {collidePlanePoly, true},
     {collideHullHull, false}},
};

}  // namespace

bool collide(const ShapeGeom& a, const Transform& xa, const ShapeGeom& b, const Transform& xb,
             float margin, Manifold* out) {
  out->count = 0;
  int ta = static_cast<int>(a.type), tb = static_cast<int>(b.type);
  if (ta < 0 || ta >= kShapeTypeCount || tb < 0 || tb >= kShapeTypeCount) return false;
  const PairEntry& e = kPairs[ta][tb];
  if (!e.fn) return false;
  bool hit = e.flip ? e.fn(b, xb, a, xa, margin, out) : e.fn(a, xa, b, xb, margin, out);
  if (!hit) {
    out->count = 0;
    return false;
  }
  if (e.flip) out->normal = -out->normal;
  return out->count > 0;
}

}  // namespace phys
