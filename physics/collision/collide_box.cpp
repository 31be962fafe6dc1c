// Box-box contact: separating-axis test over the 15 axes, then either reference-face clipping
// or one edge-edge point. Called for every touching pair of a box pyramid each step, so it keeps
// everything in fixed arrays.
#include <cmath>
#include <limits>

#include "collision/collide_internal.h"

namespace phys::detail {
namespace {

// Loops of the box faces (+x -x +y -y +z -z), counter-clockwise seen from outside; vertex
// index bits are the signs (x, y, z).
constexpr uint8_t kBoxFaceLoops[6][4] = {{1, 3, 7, 5}, {0, 4, 6, 2}, {2, 6, 7, 3},
                                         {0, 1, 5, 4}, {4, 5, 7, 6}, {0, 2, 3, 1}};

struct Box {
  Vec3 c;
  Vec3 ax[3];
  Vec3 h;
};

Box makeBox(const ShapeGeom& g, const Transform& xf) {
  Mat3 r = toMat3(xf.q);
  return {xf.p, {r.c0, r.c1, r.c2}, g.halfExtents};
}

Vec3 boxVertex(const Box& b, uint32_t bits) {
  Vec3 p = b.c;
  for (int k = 0; k < 3; ++k) p += b.ax[k] * ((bits >> k & 1u) ? b.h[k] : -b.h[k]);
  return p;
}

// Contact with `ref`'s face (axis, sign) as reference; nRef = sign * ref.ax[axis] points to inc.
bool boxFaceContact(const Box& ref, const Box& inc, int axis, float sign, bool refIsB, float margin,
                    Manifold* out) {
  Vec3 nRef = ref.ax[axis] * sign;
  uint32_t refFace = static_cast<uint32_t>(2 * axis + (sign < 0 ? 1 : 0));
  float refOffset = dot(nRef, ref.c) + ref.h[axis];
  int u = (axis + 1) % 3, v = (axis + 2) % 3;
  float cu = dot(ref.ax[u], ref.c), cv = dot(ref.ax[v], ref.c);
  // Side planes, numbered +u, -u, +v, -v.
  ClipPlane planes[4] = {{ref.ax[u], cu + ref.h[u]},
                         {-ref.ax[u], -cu + ref.h[u]},
                         {ref.ax[v], cv + ref.h[v]},
                         {-ref.ax[v], -cv + ref.h[v]}};
  // Incident face: the one of `inc` most anti-parallel to nRef.
  int k = 0;
  float best = -1, kdot = 0;
  for (int m = 0; m < 3; ++m) {
    float d = dot(inc.ax[m], nRef);
    if (std::fabs(d) > best) best = std::fabs(d), k = m, kdot = d;
  }
  uint32_t incFace = static_cast<uint32_t>(2 * k + (kdot > 0 ? 1 : 0));
  ClipVertex bufA[8], bufB[8];
  for (int q = 0; q < 4; ++q) {
    bufA[q].p = boxVertex(inc, kBoxFaceLoops[incFace][q]);
    bufA[q].feature = localFeature(0, static_cast<uint32_t>(q), 0);
    bufA[q].edge = static_cast<uint16_t>(q);
  }
  ClipVertex* pts;
  int n = clipPolygon(bufA, bufB, 4, planes, 4, &pts);
  for (int q = 0; q < n; ++q) pts[q].sep = dot(nRef, pts[q].p) - refOffset;
  return emitFaceContacts(pts, n, nRef, margin, refIsB, refFace, incFace, out);
}

}  // namespace

bool collideBoxBox(const ShapeGeom& a, const Transform& xa, const ShapeGeom& b, const Transform& xb,
                   float margin, Manifold* out) {
  Box A = makeBox(a, xa), B = makeBox(b, xb);
  Vec3 d = B.c - A.c;
  // In A's frame: C[i][j] = A_i . B_j, t = the centre offset.
  float C[3][3], absC[3][3], t[3];
  for (int i = 0; i < 3; ++i) {
    t[i] = dot(d, A.ax[i]);
    for (int j = 0; j < 3; ++j) {
      C[i][j] = dot(A.ax[i], B.ax[j]);
      absC[i][j] = std::fabs(C[i][j]);
    }
  }

  constexpr float kNegInf = -std::numeric_limits<float>::infinity();
  float sepA = kNegInf, signA = 1;
  int axisA = 0;
  for (int i = 0; i < 3; ++i) {
    float rb = B.h.x * absC[i][0] + B.h.y * absC[i][1] + B.h.z * absC[i][2];
    float s = std::fabs(t[i]) - A.h[i] - rb;
    if (s > margin) return false;
    if (s > sepA) sepA = s, axisA = i, signA = t[i] < 0 ? -1.0f : 1.0f;
  }
  float sepB = kNegInf, signB = 1;
  int axisB = 0;
  for (int j = 0; j < 3; ++j) {
    float dist = dot(d, B.ax[j]);
    float ra = A.h.x * absC[0][j] + A.h.y * absC[1][j] + A.h.z * absC[2][j];
    float s = std::fabs(dist) - ra - B.h[j];
    if (s > margin) return false;
    // B's reference normal points from B to A: against d.
    if (s > sepB) sepB = s, axisB = j, signB = dist < 0 ? 1.0f : -1.0f;
  }
  // Edge axes A_i x B_j from the entries of C (Ericson, RTCD 4.4.1), scaled to unit length.
  float sepE = kNegInf, edgeSign = 1;
  int edgeI = 0, edgeJ = 0;
  for (int i = 0; i < 3; ++i) {
    int i1 = (i + 1) % 3, i2 = (i + 2) % 3;
    for (int j = 0; j < 3; ++j) {
      int j1 = (j + 1) % 3, j2 = (j + 2) % 3;
      float len2 = C[i1][j] * C[i1][j] + C[i2][j] * C[i2][j];
      if (len2 < 1e-8f) continue;  // parallel edges: the face axes cover them
      float ra = A.h[i1] * absC[i2][j] + A.h[i2] * absC[i1][j];
      float rb = B.h[j1] * absC[i][j2] + B.h[j2] * absC[i][j1];
      float dist = t[i2] * C[i1][j] - t[i1] * C[i2][j];
      float s = (std::fabs(dist) - ra - rb) / std::sqrt(len2);
      if (s > margin) return false;
      if (s > sepE) sepE = s, edgeI = i, edgeJ = j, edgeSign = dist < 0 ? -1.0f : 1.0f;
    }
  }

  auto edgeContact = [&]() {
    // The edge of A farthest along n and the edge of B farthest along -n.
    Vec3 n = normalize(cross(A.ax[edgeI], B.ax[edgeJ])) * edgeSign;
    Vec3 ca = A.c, cb = B.c;
    uint32_t idA = static_cast<uint32_t>(4 * edgeI), idB = static_cast<uint32_t>(4 * edgeJ);
    for (int m = 1, bit = 0; m <= 2; ++m, ++bit) {
      int k = (edgeI + m) % 3;
      bool pos = dot(n, A.ax[k]) >= 0;
      ca += A.ax[k] * (pos ? A.h[k] : -A.h[k]);
      if (pos) idA |= 1u << bit;
      int l = (edgeJ + m) % 3;
      bool posB = dot(n, B.ax[l]) <= 0;
      cb += B.ax[l] * (posB ? B.h[l] : -B.h[l]);
      if (posB) idB |= 1u << bit;
    }
    Vec3 ea = A.ax[edgeI] * A.h[edgeI], eb = B.ax[edgeJ] * B.h[edgeJ];
    float ua, ub;
    Vec3 pa, pb;
    closestSegmentSegment(ca - ea, ca + ea, cb - eb, cb + eb, &ua, &ub, &pa, &pb);
    out->normal = n;
    out->count = 1;
    out->points[0] = {0.5f * (pa + pb), sepE, edgeFeatureId(idA, idB)};
    return sepE < margin;
  };
  bool haveEdge = sepE > kNegInf;
  if (haveEdge && beats(sepE, maxf(sepA, sepB), kEdgeRelTol, kEdgeAbsTol)) {
    // An edge axis close to a face normal is a face meeting a nearly parallel face across the
    // other's rim, not two crossed edges. The single point where the rims cross cannot hold the
    // rest of the face: a box tumbling onto another swung it through within one step (10+ cm
    // deep in piles). Clipping that face keeps the whole contact region, each point with its
    // own gap, the rim crossing among them.
    Vec3 n = cross(A.ax[edgeI], B.ax[edgeJ]) * edgeSign;  // length sqrt(len2), A to B
    int faceA = 0, faceB = 0;
    float dotA = 0, dotB = 0;
    for (int k = 0; k < 3; ++k) {
      float da = dot(n, A.ax[k]), db = dot(n, B.ax[k]);
      if (std::fabs(da) > std::fabs(dotA)) dotA = da, faceA = k;
      if (std::fabs(db) > std::fabs(dotB)) dotB = db, faceB = k;
    }
    float minDot = kEdgeFaceCos * length(n);
    if (std::fabs(dotA) >= minDot) {
      if (boxFaceContact(A, B, faceA, dotA < 0 ? -1.0f : 1.0f, false, margin, out)) return true;
    } else if (std::fabs(dotB) >= minDot) {
      // B's reference normal points from B to A: against n.
      if (boxFaceContact(B, A, faceB, dotB < 0 ? 1.0f : -1.0f, true, margin, out)) return true;
    }
    return edgeContact();
  }
  // Prefer A's face unless B's is clearly better, so the reference face does not flip-flop.
  bool refB = beats(sepB, sepA, kFaceRelTol, kFaceAbsTol);
  if (refB ? boxFaceContact(B, A, axisB, signB, true, margin, out)
           : boxFaceContact(A, B, axisA, signA, false, margin, out))
    return true;
  // The favoured face's clip came out empty (a near-tie with an edge pair or the other face
  // whose features do not overlap): fall back rather than miss the contact.
  if (haveEdge && edgeContact()) return true;
  return refB ? boxFaceContact(A, B, axisA, signA, false, margin, out)
              : boxFaceContact(B, A, axisB, signB, true, margin, out);
}

}  // namespace phys::detail
