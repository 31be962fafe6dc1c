// The narrow phase of physics/collision/narrowphase.cpp, collide_box.cpp and collide_poly.cpp for
// spheres, boxes, capsules, planes and convex hulls, routine for routine and formula for
// formula, so the GPU finds the same points with the same feature ids (warm starting matches
// points by id). Hull records come from binding 6 (layout in collide_hull.glsl); the includer
// declares `layout(std430, binding = 6) readonly buffer Hulls { uint hullData[]; };` first.
// Include after shared.h and common.glsl.
#ifndef PHYS_GPU_COLLIDE_GLSL
#define PHYS_GPU_COLLIDE_GLSL

// ---- Constants of collide_internal.h --------------------------------------------------------

const uint kKindFaceA = 0u << 30, kKindFaceB = 1u << 30, kKindEdges = 2u << 30,
           kKindOther = 3u << 30;
const float kFaceRelTol = 0.02, kFaceAbsTol = 0.0005;  // B's face over A's face
const float kEdgeRelTol = 0.05, kEdgeAbsTol = 0.0005;  // an edge pair over a face
const float kEdgeFaceCos = 0.99;
const float kClipSlop = 1e-3;
const uint kSideLabel = 0x8000u;
#define kInf uintBitsToFloat(0x7F800000u)

uint otherFeatureId(uint sub, uint feature) {
  return kKindOther | (sub << 28) | (feature & 0x0FFFFFFFu);
}
uint edgeFeatureId(uint edgeA, uint edgeB) {
  return kKindEdges | (edgeA & 0x7FFFu) << 15 | (edgeB & 0x7FFFu);
}
uint localFeature(uint type, uint a, uint b) { return type << 12 | (a & 63u) << 6 | (b & 63u); }
bool beats(float candidate, float best, float rel, float abs_) {
  return candidate > best + rel * abs(best) + abs_;
}
float minf(float a, float b) { return a < b ? a : b; }
float maxf(float a, float b) { return a > b ? a : b; }
float clamp01(float x) { return x < 0.0 ? 0.0 : (x > 1.0 ? 1.0 : x); }
float lengthSquared(vec3 a) { return dot(a, a); }
// phys::normalize(Vec3): zero for a (near) zero vector.
vec3 safeNormalize(vec3 a) {
  float l = length(a);
  return l > 1e-20 ? a * (1.0 / l) : vec3(0);
}
// copysignf and tangentBasis (phys::tangentBasis) are in common.glsl.

// ---- Shapes, transforms, manifolds -----------------------------------------------------------

struct Xf {  // phys::Transform
  vec3 p;
  vec4 q;
};
vec3 xfApply(Xf t, vec3 v) { return t.p + quatRotate(t.q, v); }
vec3 xfApplyInverse(Xf t, vec3 v) { return quatInvRotate(t.q, v - t.p); }

struct Geom {  // phys::ShapeGeom
  uint type;   // PHYS_GPU_SHAPE_*
  vec4 size;   // as GpuShape.size; a plane's in the world frame
};

struct Manifold {  // phys::Manifold
  vec3 normal;
  int count;
  vec3 point[4];
  float sep[4];
  uint id[4];
};
void setPoint(inout Manifold m, int k, vec3 point, float sep, uint id) {
  m.point[k] = point;
  m.sep[k] = sep;
  m.id[k] = id;
}

// Hull records and PolyRef (a box or a hull in its local frame).
#include "collide_hull.glsl"

// ---- Contact clipping and reduction (narrowphase.cpp, collide_internal.h) -------------------

struct ClipVertex {
  vec3 p;
  float sep;
  uint feature;  // localFeature()
  uint edge;     // label of the edge to the next vertex: incident edge, or kSideLabel | side
};
struct ClipPlane {
  vec3 n;
  float d;  // inside: dot(n, x) <= d
};
// The two clip buffers: an incident face (at most PHYS_HULL_MAX_FACE_VERTICES) grows by at
// most one vertex per side plane of the reference face (as many).
#define PHYS_CLIP_CAPACITY (2 * PHYS_HULL_MAX_FACE_VERTICES + 2)
ClipVertex gClip[2][PHYS_CLIP_CAPACITY];

// One pass of detail::clipPolygon: the polygon in gClip[inb] (n vertices) against plane
// number p, into gClip[1 - inb]; returns the new count.
int clipPass(int inb, int n, ClipPlane pl, uint p) {
  int outb = 1 - inb;
  uint side = kSideLabel | p;
  int m = 0;
  for (int k = 0; k < n; ++k) {
    ClipVertex cur = gClip[inb][k];
    ClipVertex nxt = gClip[inb][k + 1 == n ? 0 : k + 1];
    float dc = dot(pl.n, cur.p) - pl.d;
    float dn = dot(pl.n, nxt.p) - pl.d;
    // Vertices within the slop count as inside; new points go exactly onto the plane.
    bool curIn = dc <= kClipSlop, nxtIn = dn <= kClipSlop;
    if (curIn && m < PHYS_CLIP_CAPACITY) gClip[outb][m++] = cur;
    if (curIn == nxtIn) continue;
    if (curIn && dc >= 0.0) {
      if (m > 0) gClip[outb][m - 1].edge = side;  // cur sits on the plane: leave from it
      continue;
    }
    if (!curIn && dn >= 0.0) continue;  // nxt sits on the plane: enter at nxt itself
    if (m == PHYS_CLIP_CAPACITY) continue;  // (never with faces the packer accepts)
    ClipVertex v;
    float t = dc / (dc - dn);
    v.p = cur.p + (nxt.p - cur.p) * t;
    v.sep = 0.0;
    if ((cur.edge & kSideLabel) != 0u) {
      uint s0 = cur.edge & ~kSideLabel, s1 = p;
      v.feature = localFeature(2u, s0 < s1 ? s0 : s1, s0 < s1 ? s1 : s0);
    } else {
      v.feature = localFeature(1u, cur.edge, p);
    }
    // Leaving: the polygon now runs along the plane; entering: along cur's edge.
    v.edge = curIn ? side : cur.edge;
    gClip[outb][m++] = v;
  }
  return m;
}

// Mirrors detail::clipPolygon on the polygon in gClip[0]; returns the count and the buffer
// holding the result in `result`.
int clipPolygon(int n, ClipPlane planes[4], int numPlanes, out int result) {
  int inb = 0;
  for (int p = 0; p < numPlanes && n > 0; ++p) {
    n = clipPass(inb, n, planes[p], uint(p));
    inb = 1 - inb;
  }
  result = inb;
  return n;
}

// The candidate points of selectFour: the clipped points in gClip[buf] (buf >= 0), or the
// vertices of a box or hull against the plane dot(n, x) = d in its frame (buf < 0).
struct Candidates {
  int buf;
  Poly poly;
  vec3 n;
  float d;
  float margin;  // a point counts when its separation is below the margin
};
Candidates clipCandidates(int buf, float margin) {
  Candidates c;
  c.buf = buf;
  polyOf(PHYS_GPU_SHAPE_BOX, vec4(0), c.poly);
  c.n = vec3(0);
  c.d = 0.0;
  c.margin = margin;
  return c;
}
vec3 candPoint(Candidates c, int i) {
  return c.buf >= 0 ? gClip[c.buf][i].p : polyVertex(c.poly, uint(i));
}
float candSep(Candidates c, int i) {
  return c.buf >= 0 ? gClip[c.buf][i].sep : dot(c.n, polyVertex(c.poly, uint(i))) - c.d;
}
bool candValid(Candidates c, int i) { return candSep(c, i) < c.margin; }

// Mirrors detail::selectFour: at most four of the n candidates, the deepest, the farthest
// from it, then the two spanning the largest area (projected along `normal`).
int selectFour(Candidates c, int n, vec3 normal, out int sel[4]) {
  sel = int[4](0, 0, 0, 0);
  int count = 0;
  float minSep = kInf;
  for (int i = 0; i < n; ++i) {
    if (!candValid(c, i)) continue;
    ++count;
    minSep = minf(minSep, candSep(c, i));
  }
  if (count <= 4) {
    int k = 0;
    for (int i = 0; i < n; ++i)
      if (candValid(c, i)) sel[k++] = i;
    return k;
  }
  // The first point within 0.1 mm of the deepest, so depth noise does not change the choice.
  int i0 = -1;
  for (int i = 0; i < n && i0 < 0; ++i)
    if (candValid(c, i) && candSep(c, i) <= minSep + 1e-4) i0 = i;
  sel[0] = i0;
  vec3 p0 = candPoint(c, i0);
  int i1 = -1;
  float bestD = 0.0;
  for (int i = 0; i < n; ++i) {
    if (!candValid(c, i) || i == i0) continue;
    vec3 d = candPoint(c, i) - p0;
    d -= normal * dot(d, normal);
    float d2 = lengthSquared(d);
    if (d2 > bestD) {
      bestD = d2;
      i1 = i;
    }
  }
  if (i1 < 0 || bestD < 1e-14) return 1;
  sel[1] = i1;
  vec3 p1 = candPoint(c, i1);
  int i2 = -1;
  float bestA = 0.0, signA = 1.0;
  for (int i = 0; i < n; ++i) {
    if (!candValid(c, i) || i == i0 || i == i1) continue;
    float a = dot(cross(p1 - p0, candPoint(c, i) - p0), normal);
    if (abs(a) > bestA) {
      bestA = abs(a);
      signA = a < 0.0 ? -1.0 : 1.0;
      i2 = i;
    }
  }
  if (i2 < 0 || bestA < 1e-14) return 2;
  sel[2] = i2;
  vec3 p2 = candPoint(c, i2);
  int i3 = -1;
  float bestOut = 0.0;
  for (int i = 0; i < n; ++i) {
    if (!candValid(c, i) || i == i0 || i == i1 || i == i2) continue;
    vec3 p = candPoint(c, i);
    float a01 = signA * dot(cross(p1 - p0, p - p0), normal);
    float a12 = signA * dot(cross(p2 - p1, p - p1), normal);
    float a20 = signA * dot(cross(p0 - p2, p - p2), normal);
    float outside = -minf(a01, minf(a12, a20));  // area the point adds outside the triangle
    if (outside > bestOut) {
      bestOut = outside;
      i3 = i;
    }
  }
  if (i3 < 0) return 3;
  sel[3] = i3;
  return 4;
}

// Mirrors detail::emitFaceContacts: the clipped points in gClip[buf] (sep filled in) as a
// manifold: keeps sep < margin, reduces to four, places each point midway.
bool emitFaceContacts(int buf, int n, vec3 nRef, float margin, bool refIsB, uint refFace,
                      uint incFace, inout Manifold m) {
  int sel[4];
  int count = selectFour(clipCandidates(buf, margin), n, nRef, sel);
  uint base = (refIsB ? kKindFaceB : kKindFaceA) | (refFace & 0xFFu) << 22 |
              (incFace & 0xFFu) << 14;
  m.normal = refIsB ? -nRef : nRef;
  m.count = count;
  for (int k = 0; k < count; ++k) {
    ClipVertex v = gClip[buf][sel[k]];
    setPoint(m, k, v.p - nRef * (0.5 * v.sep), v.sep, base | v.feature);
  }
  return count > 0;
}

// ---- Geometry helpers (narrowphase.cpp) ------------------------------------------------------

// Mirrors detail::closestOnSegment: parameter in [0, 1] of the point of ab closest to p.
float closestOnSegment(vec3 a, vec3 b, vec3 p) {
  vec3 ab = b - a;
  float l2 = dot(ab, ab);
  if (l2 <= 1e-20) return 0.0;
  return clamp01(dot(p - a, ab) / l2);
}

// Mirrors detail::closestSegmentSegment (Ericson, RTCD 5.1.9).
void closestSegmentSegment(vec3 p1, vec3 q1, vec3 p2, vec3 q2, out float s, out float t,
                           out vec3 c1, out vec3 c2) {
  vec3 d1 = q1 - p1, d2 = q2 - p2, r = p1 - p2;
  float a = dot(d1, d1), e = dot(d2, d2), f = dot(d2, r);
  const float kEps = 1e-20;
  float ss = 0.0, tt = 0.0;
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
      ss = denom > 1e-10 * a * e ? clamp01((b * f - c * e) / denom) : 0.0;
      tt = (b * ss + f) / e;
      if (tt < 0.0) {
        tt = 0.0;
        ss = clamp01(-c / a);
      } else if (tt > 1.0) {
        tt = 1.0;
        ss = clamp01((b - c) / a);
      }
    }
  }
  s = ss;
  t = tt;
  c1 = p1 + d1 * ss;
  c2 = p2 + d2 * tt;
}

// anyPerpendicular (narrowphase.cpp): a unit vector perpendicular to v, deterministic.
vec3 anyPerpendicular(vec3 v) {
  vec3 n = safeNormalize(v);
  if (lengthSquared(n) == 0.0) return vec3(0, 0, 1);
  vec3 t1, t2;
  tangentBasis(n, t1, t2);
  return t1;
}

// capsuleSegment (narrowphase.cpp): size = (radius, half height), the segment on local z.
void capsuleSegment(Geom g, Xf xf, out vec3 p0, out vec3 p1) {
  vec3 axis = quatRotate(xf.q, vec3(0, 0, g.size.y));
  p0 = xf.p - axis;
  p1 = xf.p + axis;
}

void setSingle(inout Manifold m, vec3 normal, vec3 point, float sep, uint id) {
  m.normal = normal;
  m.count = 1;
  setPoint(m, 0, point, sep, id);
}

// ---- Spheres, capsules, planes (narrowphase.cpp) ---------------------------------------------

// Mirrors roundContact: two cores with radii, one point.
bool roundContact(vec3 ca, float ra, vec3 cb, float rb, vec3 fallbackNormal, float margin,
                  inout Manifold m) {
  vec3 v = cb - ca;
  float dist = length(v);
  float sep = dist - ra - rb;
  if (sep >= margin) return false;
  vec3 n = dist > 1e-6 ? v * (1.0 / dist) : fallbackNormal;
  vec3 point = 0.5 * ((ca + n * ra) + (cb - n * rb));
  setSingle(m, n, point, sep, otherFeatureId(0u, 0u));
  return true;
}

// Mirrors collideSphereSphere.
bool collideSphereSphere(Geom a, Xf xa, Geom b, Xf xb, float margin, inout Manifold m) {
  return roundContact(xa.p, a.size.x, xb.p, b.size.x, vec3(0, 0, 1), margin, m);
}

// Mirrors collideCapsuleSphere: capsule (A) against sphere (B).
bool collideCapsuleSphere(Geom a, Xf xa, Geom b, Xf xb, float margin, inout Manifold m) {
  vec3 p0, p1;
  capsuleSegment(a, xa, p0, p1);
  float t = closestOnSegment(p0, p1, xb.p);
  vec3 c = p0 + (p1 - p0) * t;
  return roundContact(c, a.size.x, xb.p, b.size.x, anyPerpendicular(p1 - p0), margin, m);
}

// Mirrors collideCapsuleCapsule.
bool collideCapsuleCapsule(Geom a, Xf xa, Geom b, Xf xb, float margin, inout Manifold m) {
  float ra = a.size.x, rb = b.size.x;
  vec3 pa0, pa1, pb0, pb1;
  capsuleSegment(a, xa, pa0, pa1);
  capsuleSegment(b, xb, pb0, pb1);
  float s, t;
  vec3 c1, c2;
  closestSegmentSegment(pa0, pa1, pb0, pb1, s, t, c1, c2);
  vec3 v = c2 - c1;
  float dist = length(v);
  float rsum = ra + rb;
  if (dist - rsum >= margin) return false;

  vec3 ua = pa1 - pa0, ub = pb1 - pb0;
  float la = length(ua), lb = length(ub);
  if (la > 1e-6 && lb > 1e-6) {
    vec3 ea = ua * (1.0 / la);
    // Nearly parallel and overlapping: two points at the overlap's ends.
    if (length(cross(ea, ub * (1.0 / lb))) < 0.05) {
      float tb0 = dot(pb0 - pa0, ea), tb1 = dot(pb1 - pa0, ea);
      float lo = maxf(0.0, minf(tb0, tb1)), hi = minf(la, maxf(tb0, tb1));
      if (hi - lo > 1e-3 * minf(la, lb)) {
        vec3 perp = v - ea * dot(v, ea);
        float pl = length(perp);
        vec3 n;
        if (pl > 1e-6) {
          n = perp * (1.0 / pl);
        } else {
          vec3 dc = (pb0 + pb1) * 0.5 - (pa0 + pa1) * 0.5;
          dc -= ea * dot(dc, ea);
          n = length(dc) > 1e-6 ? safeNormalize(dc) : anyPerpendicular(ea);
        }
        int count = 0;
        float ends[2] = float[2](lo, hi);
        for (int k = 0; k < 2; ++k) {
          float w = clamp01((ends[k] - tb0) / (tb1 - tb0));
          vec3 xb2 = pb0 + ub * w;
          vec3 xa2 = pa0 + ea * ends[k];
          float sep = dot(xb2 - xa2, n) - rsum;
          if (sep >= margin) continue;
          vec3 point = 0.5 * ((xa2 + n * ra) + (xb2 - n * rb));
          setPoint(m, count++, point, sep, otherFeatureId(2u, uint(k)));
        }
        if (count > 0) {
          m.normal = n;
          m.count = count;
          return true;
        }
      }
    }
  }
  vec3 fallback = cross(ua, ub);
  if (lengthSquared(fallback) > 1e-12) {
    fallback = safeNormalize(fallback);
    if (dot(fallback, xb.p - xa.p) < 0.0) fallback = -fallback;
  } else {
    fallback = anyPerpendicular(la > 1e-6 ? ua : ub);
  }
  return roundContact(c1, ra, c2, rb, fallback, margin, m);
}

// worldPlane: a plane's size is already (world normal, offset): dot(n, x) = d.
void worldPlane(Geom g, out vec3 n, out float d) {
  n = g.size.xyz;
  d = g.size.w;
}

// Mirrors collidePlaneSphere: plane (A) against sphere (B).
bool collidePlaneSphere(Geom a, Xf xa, Geom b, Xf xb, float margin, inout Manifold m) {
  vec3 n;
  float d;
  worldPlane(a, n, d);
  float r = b.size.x;
  float sep = dot(n, xb.p) - d - r;
  if (sep >= margin) return false;
  setSingle(m, n, xb.p - n * (r + 0.5 * sep), sep, otherFeatureId(0u, 0u));
  return true;
}

// Mirrors collidePlaneCapsule: plane (A) against capsule (B), both segment ends.
bool collidePlaneCapsule(Geom a, Xf xa, Geom b, Xf xb, float margin, inout Manifold m) {
  vec3 n;
  float d;
  worldPlane(a, n, d);
  float r = b.size.x;
  vec3 ends[2];
  capsuleSegment(b, xb, ends[0], ends[1]);
  int count = 0;
  for (int k = 0; k < 2; ++k) {
    float sep = dot(n, ends[k]) - d - r;
    if (sep >= margin) continue;
    setPoint(m, count++, ends[k] - n * (r + 0.5 * sep), sep, otherFeatureId(1u, uint(k)));
  }
  m.normal = n;
  m.count = count;
  return count > 0;
}

// ---- Boxes and hulls (collide_poly.cpp; a box is the unit-box hull scaled, see
// collide_hull.glsl) ----------------------------------------------------------------------------

// Mirrors insideFace: x (in the face's plane) within face f's loop.
bool polyInsideFace(Poly p, int f, vec3 x) {
  vec3 n = polyNormal(p, f);
  int m = polyLoopSize(p, f);
  for (int k = 0; k < m; ++k) {
    vec3 a = polyVertex(p, polyLoopVertex(p, f, k));
    vec3 b = polyVertex(p, polyLoopVertex(p, f, k + 1 == m ? 0 : k + 1));
    if (dot(cross(b - a, x - a), n) < 0.0) return false;
  }
  return true;
}

// Mirrors closestPointOutside: the closest point of the shape to x, x outside.
vec3 polyClosestPointOutside(Poly p, vec3 x) {
  if (p.box)
    return vec3(maxf(-p.scale.x, minf(p.scale.x, x.x)), maxf(-p.scale.y, minf(p.scale.y, x.y)),
                maxf(-p.scale.z, minf(p.scale.z, x.z)));
  // A projection that lands on its face is the answer; otherwise the closest point lies on an
  // edge.
  for (int f = 0; f < p.nf; ++f) {
    vec3 n = polyNormal(p, f);
    float d = dot(n, x) - polyOffset(p, f);
    if (d <= 0.0) continue;
    vec3 proj = x - n * d;
    if (polyInsideFace(p, f, proj)) return proj;
  }
  vec3 best = x;
  float bestD2 = kInf;
  for (int e = 0; e < p.ne; ++e) {
    uint i0, i1;
    polyEdge(p, e, i0, i1);
    vec3 a = polyVertex(p, i0), b = polyVertex(p, i1);
    vec3 c = a + (b - a) * closestOnSegment(a, b, x);
    float d2 = lengthSquared(x - c);
    if (d2 < bestD2) {
      bestD2 = d2;
      best = c;
    }
  }
  return best;
}

// Mirrors collidePolySphere: box or hull (A) against a sphere (B).
bool collidePolySphere(Geom a, Xf xa, Geom b, Xf xb, float margin, inout Manifold m) {
  Poly p;
  if (!polyOf(a.type, a.size, p)) return false;
  vec3 c = xfApplyInverse(xa, xb.p);
  float r = b.size.x;
  int fmax = 0;
  float dmax = -kInf;
  for (int f = 0; f < p.nf; ++f) {
    float d = dot(polyNormal(p, f), c) - polyOffset(p, f);
    if (d > dmax) {
      dmax = d;
      fmax = f;
    }
  }
  if (dmax - r >= margin) return false;
  vec3 q, n;
  float sep;
  if (dmax <= 0.0) {
    // Centre inside: push out through the nearest face.
    n = polyNormal(p, fmax);
    q = c - n * dmax;
    sep = dmax - r;
  } else {
    q = polyClosestPointOutside(p, c);
    vec3 v = c - q;
    float dist = length(v);
    n = dist > 1e-7 ? v * (1.0 / dist) : polyNormal(p, fmax);
    sep = dist - r;
  }
  if (sep >= margin) return false;
  m.normal = quatRotate(xa.q, n);
  m.count = 1;
  setPoint(m, 0, xfApply(xa, q + n * (0.5 * sep)), sep, otherFeatureId(0u, 0u));
  return true;
}

// Mirrors clipSegmentToFace: clips p0 p1 to the prism over face f.
bool polyClipSegmentToFace(Poly p, int f, vec3 p0, vec3 p1, out float t0, out float t1) {
  vec3 n = polyNormal(p, f);
  int m = polyLoopSize(p, f);
  float lo = 0.0, hi = 1.0;
  t0 = 0.0;
  t1 = 0.0;
  for (int k = 0; k < m; ++k) {
    vec3 a = polyVertex(p, polyLoopVertex(p, f, k));
    vec3 b = polyVertex(p, polyLoopVertex(p, f, k + 1 == m ? 0 : k + 1));
    vec3 sn = safeNormalize(cross(b - a, n));
    float d = dot(sn, a);
    float d0 = dot(sn, p0) - d, d1 = dot(sn, p1) - d;
    // Ends within the slop stay; cuts go exactly onto the side plane.
    if (d0 > kClipSlop && d1 > kClipSlop) return false;
    if (d0 > kClipSlop) lo = maxf(lo, d1 >= 0.0 ? 1.0 : d0 / (d0 - d1));
    if (d1 > kClipSlop) hi = minf(hi, d0 >= 0.0 ? 0.0 : d0 / (d0 - d1));
  }
  t0 = lo;
  t1 = hi;
  return lo <= hi;
}

// Mirrors segmentFaceContacts: capsule core p0 p1 (radius r, shape-local) over face f, up to
// two points, normal = the face's.
int polySegmentFaceContacts(Poly p, int f, vec3 p0, vec3 p1, float r, float margin, Xf xf,
                            inout Manifold m) {
  float t0, t1;
  if (!polyClipSegmentToFace(p, f, p0, p1, t0, t1)) return 0;
  vec3 n = polyNormal(p, f);
  float o = polyOffset(p, f);
  vec3 x[2] = vec3[2](p0 + (p1 - p0) * t0, p0 + (p1 - p0) * t1);
  bool clipped[2] = bool[2](t0 > 0.0, t1 < 1.0);
  int ends = (t1 - t0) * length(p1 - p0) > 1e-6 ? 2 : 1;
  int count = 0;
  for (int k = 0; k < ends; ++k) {
    float sep = dot(n, x[k]) - o - r;
    if (sep >= margin) continue;
    uint feature = uint(f) << 1 | uint(k);
    setPoint(m, count++, xfApply(xf, x[k] - n * (r + 0.5 * sep)), sep,
             otherFeatureId(clipped[k] ? 2u : 1u, feature));
  }
  m.count = count;
  m.normal = quatRotate(xf.q, n);
  return count;
}

// Mirrors collidePolyCapsule: box or hull (A) against a capsule (B).
bool collidePolyCapsule(Geom a, Xf xa, Geom b, Xf xb, float margin, inout Manifold m) {
  Poly p;
  if (!polyOf(a.type, a.size, p)) return false;
  vec3 axis = quatRotate(xb.q, vec3(0, 0, b.size.y));
  vec3 p0 = xfApplyInverse(xa, xb.p - axis), p1 = xfApplyInverse(xa, xb.p + axis);
  float r = b.size.x;

  // Face axes, and whether the core segment crosses the shape (Cyrus-Beck).
  float faceSep = -kInf;
  int face = 0;
  float tlo = 0.0, thi = 1.0;
  bool apart = false;
  for (int f = 0; f < p.nf; ++f) {
    vec3 n = polyNormal(p, f);
    float o = polyOffset(p, f);
    float d0 = dot(n, p0) - o, d1 = dot(n, p1) - o;
    float sf = minf(d0, d1) - r;
    if (sf > margin) return false;
    if (sf > faceSep) {
      faceSep = sf;
      face = f;
    }
    if (d0 > 0.0 && d1 > 0.0) {
      apart = true;
    } else if (d0 > 0.0) {
      tlo = maxf(tlo, d0 / (d0 - d1));
    } else if (d1 > 0.0) {
      thi = minf(thi, d0 / (d0 - d1));
    }
  }
  if (tlo > thi) apart = true;

  if (apart) {
    // Exact closest points: a segment end against a face, or the segment against an edge.
    float best = kInf;
    vec3 bs = vec3(0), bq = vec3(0);
    vec3 segEnds[2] = vec3[2](p0, p1);
    for (int k = 0; k < 2; ++k) {
      vec3 e = segEnds[k];
      if (p.box) {
        vec3 q = polyClosestPointOutside(p, e);
        float d2 = lengthSquared(e - q);
        if (d2 < best) {
          best = d2;
          bs = e;
          bq = q;
        }
        continue;
      }
      for (int f = 0; f < p.nf; ++f) {
        vec3 n = polyNormal(p, f);
        float d = dot(n, e) - polyOffset(p, f);
        if (d <= 0.0 || d * d >= best) continue;
        vec3 proj = e - n * d;
        if (polyInsideFace(p, f, proj)) {
          best = d * d;
          bs = e;
          bq = proj;
        }
      }
    }
    for (int e = 0; e < p.ne; ++e) {
      uint v0, v1;
      polyEdge(p, e, v0, v1);
      float s, t;
      vec3 c1, c2;
      closestSegmentSegment(p0, p1, polyVertex(p, v0), polyVertex(p, v1), s, t, c1, c2);
      float d2 = lengthSquared(c1 - c2);
      if (d2 < best) {
        best = d2;
        bs = c1;
        bq = c2;
      }
    }
    vec3 v = bs - bq;
    float dist = length(v);
    if (dist > 1e-6) {
      vec3 n = v * (1.0 / dist);
      float sep = dist - r;
      if (sep >= margin) return false;
      // Lying on a face: both ends of the core over that face.
      int fbest = 0;
      float cbest = -2.0;
      for (int f = 0; f < p.nf; ++f) {
        float c = dot(polyNormal(p, f), n);
        if (c > cbest) {
          cbest = c;
          fbest = f;
        }
      }
      if (cbest > 0.9999 && polySegmentFaceContacts(p, fbest, p0, p1, r, margin, xa, m) > 0)
        return true;
      m.normal = quatRotate(xa.q, n);
      m.count = 1;
      setPoint(m, 0, xfApply(xa, bq + n * (0.5 * sep)), sep, otherFeatureId(0u, 0u));
      return true;
    }
  }

  // The core touches or crosses the shape: least-penetration axis over the faces and the
  // crosses of the core with the edges.
  vec3 u = p1 - p0;
  float edgeSep = -kInf;
  int edge = -1;
  vec3 edgeN = vec3(0);
  if (lengthSquared(u) > 1e-12) {
    for (int e = 0; e < p.ne; ++e) {
      uint i0, i1;
      polyEdge(p, e, i0, i1);
      vec3 va = polyVertex(p, i0), vb = polyVertex(p, i1);
      vec3 n = cross(vb - va, u);
      float len = length(n);
      if (len < 1e-4 * sqrt(lengthSquared(vb - va) * lengthSquared(u))) continue;
      n = n * (1.0 / len);
      float sp = dot(n, p0);
      float hi = polySupport(p, n), lo = -polySupport(p, -n);
      float s1 = sp - r - hi;  // capsule on the +n side
      float s2 = lo - sp - r;  // capsule on the -n side
      float se = maxf(s1, s2);
      if (se > margin) return false;
      // Parallel edges share the axis; only the one on the shape's support along it touches.
      float ve = dot(n, va), tol = 1e-5 * (hi - lo);
      bool onSupport = s1 >= s2 ? ve >= hi - tol : ve <= lo + tol;
      if (onSupport && se > edgeSep) {
        edgeSep = se;
        edge = e;
        edgeN = s1 >= s2 ? n : -n;
      }
    }
  }
  if (edge >= 0 && beats(edgeSep, faceSep, kEdgeRelTol, kEdgeAbsTol)) {
    uint i0, i1;
    polyEdge(p, edge, i0, i1);
    float s, t;
    vec3 c1, c2;
    closestSegmentSegment(p0, p1, polyVertex(p, i0), polyVertex(p, i1), s, t, c1, c2);
    m.normal = quatRotate(xa.q, edgeN);
    m.count = 1;
    setPoint(m, 0, xfApply(xa, c2 + edgeN * (0.5 * edgeSep)), edgeSep,
             otherFeatureId(3u, uint(edge)));
    return edgeSep < margin;
  }
  if (polySegmentFaceContacts(p, face, p0, p1, r, margin, xa, m) > 0) return true;
  // The core's shadow misses the face (rare): the deeper end alone.
  vec3 n = polyNormal(p, face);
  vec3 e = dot(n, p0) <= dot(n, p1) ? p0 : p1;
  float sep = dot(n, e) - polyOffset(p, face) - r;
  if (sep >= margin) return false;
  m.normal = quatRotate(xa.q, n);
  m.count = 1;
  setPoint(m, 0, xfApply(xa, e - n * (r + 0.5 * sep)), sep, otherFeatureId(1u, uint(face) << 1));
  return true;
}

// Mirrors collidePlanePoly: a plane (A) against a box or hull (B): every vertex below the
// margin, reduced to four, in B's frame.
bool collidePlanePoly(Geom a, Xf xa, Geom b, Xf xb, float margin, inout Manifold m) {
  Poly p;
  if (!polyOf(b.type, b.size, p)) return false;
  vec3 n;
  float d;
  worldPlane(a, n, d);
  vec3 nl = quatInvRotate(xb.q, n);
  float dl = d - dot(n, xb.p);
  // Quick reject on the lowest point.
  if (-polySupport(p, -nl) - dl >= margin) return false;
  Candidates c;
  c.buf = -1;
  c.poly = p;
  c.n = nl;
  c.d = dl;
  c.margin = margin;
  int sel[4];
  int count = selectFour(c, p.nv, nl, sel);
  m.normal = n;
  m.count = count;
  for (int k = 0; k < count; ++k) {
    float sep = candSep(c, sel[k]);
    setPoint(m, k, xfApply(xb, candPoint(c, sel[k]) - nl * (0.5 * sep)), sep,
             otherFeatureId(1u, uint(sel[k])));
  }
  return count > 0;
}

// ---- Box or hull against box or hull (collidePolyPoly: SAT with Gauss-map pruning) ----------

// A box or hull in the world (toWorld): what the CPU stores per vertex and face is computed
// where needed, formula for formula.
struct WorldPoly {
  Poly p;
  vec3 pos;
  mat3 r;  // columns: the shape's axes in the world (phys::toMat3)
  vec3 center;  // the world centroid
};
vec3 mat3Mul(mat3 r, vec3 v) { return r[0] * v.x + r[1] * v.y + r[2] * v.z; }  // as Mat3 * Vec3
WorldPoly toWorld(Poly p, Xf xf) {
  WorldPoly w;
  w.p = p;
  w.pos = xf.p;
  w.r = quatToMat3(xf.q);
  w.center = xf.p + mat3Mul(w.r, polyCentroid(p));
  return w;
}
vec3 worldVertex(WorldPoly w, uint i) { return w.pos + mat3Mul(w.r, polyVertex(w.p, i)); }
vec3 worldNormal(WorldPoly w, int f) { return mat3Mul(w.r, polyNormal(w.p, f)); }
float worldOffset(WorldPoly w, int f) { return polyOffset(w.p, f) + dot(worldNormal(w, f), w.pos); }

// Mirrors queryFaces: the face of p whose plane q lies farthest in front of.
float queryFaces(WorldPoly p, WorldPoly q, float margin, out int face) {
  float bestSep = -kInf;
  face = -1;
  for (int f = 0; f < p.p.nf; ++f) {
    vec3 n = worldNormal(p, f);
    float mn = kInf;
    for (int j = 0; j < q.p.nv; ++j) mn = minf(mn, dot(n, worldVertex(q, uint(j))));
    float s = mn - worldOffset(p, f);
    if (s > bestSep) {
      bestSep = s;
      face = f;
    }
    if (s > margin) break;
  }
  return bestSep;
}

// Mirrors queryEdges: the edge pairs of p and q that form a face of the Minkowski difference
// (Gregorius, GDC 2013); the best separation, its edges and normal (from p to q).
float queryEdges(WorldPoly p, WorldPoly q, float margin, out int ea, out int eb, out vec3 en) {
  float bestSep = -kInf;
  ea = -1;
  eb = -1;
  en = vec3(0);
  for (int i = 0; i < p.p.ne; ++i) {
    uint pi0, pi1;
    int pf0, pf1;
    polyEdge(p.p, i, pi0, pi1);
    polyEdgeFaces(p.p, i, pf0, pf1);
    vec3 pa = worldVertex(p, pi0);
    vec3 ep = worldVertex(p, pi1) - pa;
    vec3 a = worldNormal(p, pf0), b = worldNormal(p, pf1);
    vec3 bxa = cross(b, a);
    for (int j = 0; j < q.p.ne; ++j) {
      int qf0, qf1;
      polyEdgeFaces(q.p, j, qf0, qf1);
      vec3 c = -worldNormal(q, qf0), d = -worldNormal(q, qf1);
      vec3 dxc = cross(d, c);
      float cba = dot(c, bxa), dba = dot(d, bxa), adc = dot(a, dxc), bdc = dot(b, dxc);
      if (!(cba * dba < 0.0 && adc * bdc < 0.0 && cba * bdc > 0.0)) continue;
      uint qi0, qi1;
      polyEdge(q.p, j, qi0, qi1);
      vec3 qa = worldVertex(q, qi0);
      vec3 eq = worldVertex(q, qi1) - qa;
      vec3 n = cross(ep, eq);
      float len = length(n);
      if (len < 1e-4 * sqrt(lengthSquared(ep) * lengthSquared(eq))) continue;
      n = n * (1.0 / len);
      if (dot(n, pa - p.center) < 0.0) n = -n;
      float s = dot(n, qa - pa);
      if (s > bestSep) {
        bestSep = s;
        ea = i;
        eb = j;
        en = n;
      }
      if (s > margin) return bestSep;
    }
  }
  return bestSep;
}

// Mirrors polyFaceContact: ref's face as reference, inc's most anti-parallel face clipped to
// it.
bool polyFaceContact(WorldPoly ref, WorldPoly inc, int face, bool refIsB, float margin,
                     inout Manifold m) {
  vec3 nRef = worldNormal(ref, face);
  float refOffset = worldOffset(ref, face);
  int incFace = 0;
  float best = kInf;
  for (int g = 0; g < inc.p.nf; ++g) {
    float d = dot(worldNormal(inc, g), nRef);
    if (d < best) {
      best = d;
      incFace = g;
    }
  }
  int nr = polyLoopSize(ref.p, face), ni = polyLoopSize(inc.p, incFace);
  ni = min(ni, PHYS_CLIP_CAPACITY);
  for (int q = 0; q < ni; ++q) {
    gClip[0][q].p = worldVertex(inc, polyLoopVertex(inc.p, incFace, q));
    gClip[0][q].sep = 0.0;
    gClip[0][q].feature = localFeature(0u, uint(q), 0u);
    gClip[0][q].edge = uint(q) & 0x7FFFu;
  }
  // The side planes of the reference face, numbered by loop position.
  int n = ni, buf = 0;
  for (int k = 0; k < nr && n > 0; ++k) {
    vec3 a = worldVertex(ref, polyLoopVertex(ref.p, face, k));
    vec3 b = worldVertex(ref, polyLoopVertex(ref.p, face, k + 1 == nr ? 0 : k + 1));
    vec3 sn = safeNormalize(cross(b - a, nRef));
    n = clipPass(buf, n, ClipPlane(sn, dot(sn, a)), uint(k));
    buf = 1 - buf;
  }
  for (int q = 0; q < n; ++q) gClip[buf][q].sep = dot(nRef, gClip[buf][q].p) - refOffset;
  return emitFaceContacts(buf, n, nRef, margin, refIsB, uint(face), uint(incFace), m);
}

// The edgeContact lambda of collidePolyPoly: one point midway between the two edges.
bool polyEdgeContact(WorldPoly A, WorldPoly B, int ea, int eb, vec3 en, float sep, float margin,
                     inout Manifold m) {
  uint a0, a1, b0, b1;
  polyEdge(A.p, ea, a0, a1);
  polyEdge(B.p, eb, b0, b1);
  float t, u;
  vec3 pa, pb;
  closestSegmentSegment(worldVertex(A, a0), worldVertex(A, a1), worldVertex(B, b0),
                        worldVertex(B, b1), t, u, pa, pb);
  m.normal = en;
  m.count = 1;
  setPoint(m, 0, 0.5 * (pa + pb), sep, edgeFeatureId(uint(ea), uint(eb)));
  return sep < margin;
}

// Mirrors collidePolyPoly: box or hull (A) against box or hull (B).
bool collidePolyPoly(Geom a, Xf xa, Geom b, Xf xb, float margin, inout Manifold m) {
  Poly pa, pb;
  if (!polyOf(a.type, a.size, pa) || !polyOf(b.type, b.size, pb)) return false;
  WorldPoly A = toWorld(pa, xa), B = toWorld(pb, xb);
  int faceA, faceB;
  float sepA = queryFaces(A, B, margin, faceA);
  if (sepA > margin) return false;
  float sepB = queryFaces(B, A, margin, faceB);
  if (sepB > margin) return false;
  int ea, eb;
  vec3 en;
  float sepE = queryEdges(A, B, margin, ea, eb, en);
  if (sepE > margin) return false;

  bool haveEdge = ea >= 0;
  if (haveEdge && beats(sepE, maxf(sepA, sepB), kEdgeRelTol, kEdgeAbsTol)) {
    // As in collideBoxBox: an edge axis close to a face normal is nearly parallel faces
    // meeting over a rim; that face's clipped contact holds the whole face.
    int fa = -1, fb = -1;
    float dotA = kEdgeFaceCos, dotB = kEdgeFaceCos;
    for (int f = 0; f < A.p.nf; ++f) {
      float d = dot(worldNormal(A, f), en);
      if (d >= dotA) {
        dotA = d;
        fa = f;
      }
    }
    for (int f = 0; f < B.p.nf; ++f) {
      float d = -dot(worldNormal(B, f), en);
      if (d >= dotB) {
        dotB = d;
        fb = f;
      }
    }
    if (fa >= 0) {
      if (polyFaceContact(A, B, fa, false, margin, m)) return true;
    } else if (fb >= 0) {
      if (polyFaceContact(B, A, fb, true, margin, m)) return true;
    }
    return polyEdgeContact(A, B, ea, eb, en, sepE, margin, m);
  }
  // Prefer A's face unless B's is clearly better, so the reference face does not flip-flop.
  bool refB = beats(sepB, sepA, kFaceRelTol, kFaceAbsTol);
  if (refB ? polyFaceContact(B, A, faceB, true, margin, m)
           : polyFaceContact(A, B, faceA, false, margin, m))
    return true;
  // The favoured face's clip came out empty: fall back rather than miss the contact.
  if (haveEdge && polyEdgeContact(A, B, ea, eb, en, sepE, margin, m)) return true;
  return refB ? polyFaceContact(A, B, faceA, false, margin, m)
              : polyFaceContact(B, A, faceB, true, margin, m);
}

// ---- Box against box (collide_box.cpp) ---------------------------------------------------------

struct Box {
  vec3 c;
  mat3 ax;  // columns: the box's axes in the world
  vec3 h;
};

Box makeBox(Geom g, Xf xf) {
  Box b;
  b.c = xf.p;
  b.ax = quatToMat3(xf.q);
  b.h = g.size.xyz;
  return b;
}

vec3 boxVertex(Box b, uint bits) {
  vec3 p = b.c;
  for (int k = 0; k < 3; ++k) p += b.ax[k] * (((bits >> uint(k)) & 1u) != 0u ? b.h[k] : -b.h[k]);
  return p;
}

// Mirrors boxFaceContact: `ref`'s face (axis, sign) as reference; nRef points to inc.
bool boxFaceContact(Box ref, Box inc, int axis, float sgn, bool refIsB, float margin,
                    inout Manifold m) {
  vec3 nRef = ref.ax[axis] * sgn;
  uint refFace = uint(2 * axis + (sgn < 0.0 ? 1 : 0));
  float refOffset = dot(nRef, ref.c) + ref.h[axis];
  int u = (axis + 1) % 3, v = (axis + 2) % 3;
  float cu = dot(ref.ax[u], ref.c), cv = dot(ref.ax[v], ref.c);
  // Side planes, numbered +u, -u, +v, -v.
  ClipPlane planes[4] = ClipPlane[4](
      ClipPlane(ref.ax[u], cu + ref.h[u]), ClipPlane(-ref.ax[u], -cu + ref.h[u]),
      ClipPlane(ref.ax[v], cv + ref.h[v]), ClipPlane(-ref.ax[v], -cv + ref.h[v]));
  // Incident face: the one of `inc` most anti-parallel to nRef.
  int k = 0;
  float best = -1.0, kdot = 0.0;
  for (int mm = 0; mm < 3; ++mm) {
    float d = dot(inc.ax[mm], nRef);
    if (abs(d) > best) {
      best = abs(d);
      k = mm;
      kdot = d;
    }
  }
  uint incFace = uint(2 * k + (kdot > 0.0 ? 1 : 0));
  for (int q = 0; q < 4; ++q) {
    gClip[0][q].p = boxVertex(inc, kBoxFaceLoops[4 * incFace + uint(q)]);
    gClip[0][q].sep = 0.0;
    gClip[0][q].feature = localFeature(0u, uint(q), 0u);
    gClip[0][q].edge = uint(q);
  }
  int buf;
  int n = clipPolygon(4, planes, 4, buf);
  for (int q = 0; q < n; ++q) gClip[buf][q].sep = dot(nRef, gClip[buf][q].p) - refOffset;
  return emitFaceContacts(buf, n, nRef, margin, refIsB, refFace, incFace, m);
}

// The edgeContact lambda of collideBoxBox: the edge of A farthest along n and the edge of B
// farthest along -n, one point.
bool boxEdgeContact(Box A, Box B, int edgeI, int edgeJ, float edgeSign, float sepE,
                    float margin, inout Manifold m) {
  vec3 n = safeNormalize(cross(A.ax[edgeI], B.ax[edgeJ])) * edgeSign;
  vec3 ca = A.c, cb = B.c;
  uint idA = uint(4 * edgeI), idB = uint(4 * edgeJ);
  for (int mm = 1, bit = 0; mm <= 2; ++mm, ++bit) {
    int k = (edgeI + mm) % 3;
    bool pos = dot(n, A.ax[k]) >= 0.0;
    ca += A.ax[k] * (pos ? A.h[k] : -A.h[k]);
    if (pos) idA |= 1u << uint(bit);
    int l = (edgeJ + mm) % 3;
    bool posB = dot(n, B.ax[l]) <= 0.0;
    cb += B.ax[l] * (posB ? B.h[l] : -B.h[l]);
    if (posB) idB |= 1u << uint(bit);
  }
  vec3 ea = A.ax[edgeI] * A.h[edgeI], eb = B.ax[edgeJ] * B.h[edgeJ];
  float ua, ub;
  vec3 pa, pb;
  closestSegmentSegment(ca - ea, ca + ea, cb - eb, cb + eb, ua, ub, pa, pb);
  m.normal = n;
  m.count = 1;
  setPoint(m, 0, 0.5 * (pa + pb), sepE, edgeFeatureId(idA, idB));
  return sepE < margin;
}

// Mirrors collideBoxBox: SAT over the 15 axes, then reference-face clipping or one edge point.
bool collideBoxBox(Geom a, Xf xa, Geom b, Xf xb, float margin, inout Manifold m) {
  Box A = makeBox(a, xa), B = makeBox(b, xb);
  vec3 d = B.c - A.c;
  // In A's frame: C[i][j] = A_i . B_j, t = the centre offset.
  float C[3][3], absC[3][3], t[3];
  for (int i = 0; i < 3; ++i) {
    t[i] = dot(d, A.ax[i]);
    for (int j = 0; j < 3; ++j) {
      C[i][j] = dot(A.ax[i], B.ax[j]);
      absC[i][j] = abs(C[i][j]);
    }
  }

  float sepA = -kInf, signA = 1.0;
  int axisA = 0;
  for (int i = 0; i < 3; ++i) {
    float rb = B.h.x * absC[i][0] + B.h.y * absC[i][1] + B.h.z * absC[i][2];
    float s = abs(t[i]) - A.h[i] - rb;
    if (s > margin) return false;
    if (s > sepA) {
      sepA = s;
      axisA = i;
      signA = t[i] < 0.0 ? -1.0 : 1.0;
    }
  }
  float sepB = -kInf, signB = 1.0;
  int axisB = 0;
  for (int j = 0; j < 3; ++j) {
    float dist = dot(d, B.ax[j]);
    float ra = A.h.x * absC[0][j] + A.h.y * absC[1][j] + A.h.z * absC[2][j];
    float s = abs(dist) - ra - B.h[j];
    if (s > margin) return false;
    // B's reference normal points from B to A: against d.
    if (s > sepB) {
      sepB = s;
      axisB = j;
      signB = dist < 0.0 ? 1.0 : -1.0;
    }
  }
  // Edge axes A_i x B_j from the entries of C (Ericson, RTCD 4.4.1), scaled to unit length.
  float sepE = -kInf, edgeSign = 1.0;
  int edgeI = 0, edgeJ = 0;
  for (int i = 0; i < 3; ++i) {
    int i1 = (i + 1) % 3, i2 = (i + 2) % 3;
    for (int j = 0; j < 3; ++j) {
      int j1 = (j + 1) % 3, j2 = (j + 2) % 3;
      float len2 = C[i1][j] * C[i1][j] + C[i2][j] * C[i2][j];
      if (len2 < 1e-8) continue;  // parallel edges: the face axes cover them
      float ra = A.h[i1] * absC[i2][j] + A.h[i2] * absC[i1][j];
      float rb = B.h[j1] * absC[i][j2] + B.h[j2] * absC[i][j1];
      float dist = t[i2] * C[i1][j] - t[i1] * C[i2][j];
      float s = (abs(dist) - ra - rb) / sqrt(len2);
      if (s > margin) return false;
      if (s > sepE) {
        sepE = s;
        edgeI = i;
        edgeJ = j;
        edgeSign = dist < 0.0 ? -1.0 : 1.0;
      }
    }
  }

  bool haveEdge = sepE > -kInf;
  if (haveEdge && beats(sepE, maxf(sepA, sepB), kEdgeRelTol, kEdgeAbsTol)) {
    // An edge axis close to a face normal is a face meeting a nearly parallel face across the
    // other's rim: clip that face instead of taking the one rim point.
    vec3 n = cross(A.ax[edgeI], B.ax[edgeJ]) * edgeSign;  // length sqrt(len2), A to B
    int faceA = 0, faceB = 0;
    float dotA = 0.0, dotB = 0.0;
    for (int k = 0; k < 3; ++k) {
      float da = dot(n, A.ax[k]), db = dot(n, B.ax[k]);
      if (abs(da) > abs(dotA)) {
        dotA = da;
        faceA = k;
      }
      if (abs(db) > abs(dotB)) {
        dotB = db;
        faceB = k;
      }
    }
    float minDot = kEdgeFaceCos * length(n);
    if (abs(dotA) >= minDot) {
      if (boxFaceContact(A, B, faceA, dotA < 0.0 ? -1.0 : 1.0, false, margin, m)) return true;
    } else if (abs(dotB) >= minDot) {
      // B's reference normal points from B to A: against n.
      if (boxFaceContact(B, A, faceB, dotB < 0.0 ? 1.0 : -1.0, true, margin, m)) return true;
    }
    return boxEdgeContact(A, B, edgeI, edgeJ, edgeSign, sepE, margin, m);
  }
  // Prefer A's face unless B's is clearly better, so the reference face does not flip-flop.
  bool refB = beats(sepB, sepA, kFaceRelTol, kFaceAbsTol);
  if (refB ? boxFaceContact(B, A, axisB, signB, true, margin, m)
           : boxFaceContact(A, B, axisA, signA, false, margin, m))
    return true;
  // The favoured face's clip came out empty: fall back rather than miss the contact.
  if (haveEdge && boxEdgeContact(A, B, edgeI, edgeJ, edgeSign, sepE, margin, m)) return true;
  return refB ? boxFaceContact(A, B, axisA, signA, false, margin, m)
              : boxFaceContact(B, A, axisB, signB, true, margin, m);
}

// ---- Dispatch (phys::collide) ----------------------------------------------------------------

// Mirrors phys::collide's table kPairs: which routine takes (A, B), and whether it is written
// for (B, A) (then the shapes are swapped and its normal negated).
bool collide(Geom a, Xf xa, Geom b, Xf xb, float margin, inout Manifold m) {
  m.count = 0;
  uint ta = a.type, tb = b.type;
  if (ta > PHYS_GPU_SHAPE_HULL || tb > PHYS_GPU_SHAPE_HULL) return false;
  // Each routine's first shape comes first in the order plane, box, hull, capsule, sphere.
  const int kRank[5] = int[5](4, 1, 3, 0, 2);  // by type: sphere, box, capsule, plane, hull
  bool flip = kRank[tb] < kRank[ta];
  Geom g0 = flip ? b : a, g1 = flip ? a : b;
  Xf x0 = flip ? xb : xa, x1 = flip ? xa : xb;
  uint t0 = g0.type, t1 = g1.type;
  bool hit = false;
  if (t0 == PHYS_GPU_SHAPE_SPHERE) {
    hit = collideSphereSphere(g0, x0, g1, x1, margin, m);
  } else if (t0 == PHYS_GPU_SHAPE_CAPSULE) {
    if (t1 == PHYS_GPU_SHAPE_SPHERE) hit = collideCapsuleSphere(g0, x0, g1, x1, margin, m);
    else hit = collideCapsuleCapsule(g0, x0, g1, x1, margin, m);
  } else if (t0 == PHYS_GPU_SHAPE_PLANE) {
    if (t1 == PHYS_GPU_SHAPE_SPHERE) hit = collidePlaneSphere(g0, x0, g1, x1, margin, m);
    else if (t1 == PHYS_GPU_SHAPE_CAPSULE) hit = collidePlaneCapsule(g0, x0, g1, x1, margin, m);
    else if (t1 != PHYS_GPU_SHAPE_PLANE) hit = collidePlanePoly(g0, x0, g1, x1, margin, m);
    // plane-plane: no contact
  } else {  // box or hull
    if (t1 == PHYS_GPU_SHAPE_SPHERE) hit = collidePolySphere(g0, x0, g1, x1, margin, m);
    else if (t1 == PHYS_GPU_SHAPE_CAPSULE) hit = collidePolyCapsule(g0, x0, g1, x1, margin, m);
    else if (t0 == PHYS_GPU_SHAPE_BOX && t1 == PHYS_GPU_SHAPE_BOX)
      hit = collideBoxBox(g0, x0, g1, x1, margin, m);
    else hit = collidePolyPoly(g0, x0, g1, x1, margin, m);
  }
  if (!hit) {
    m.count = 0;
    return false;
  }
  if (flip) m.normal = -m.normal;
  return m.count > 0;
}

#endif
