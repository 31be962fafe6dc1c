// Convex hulls for the narrow phase: the hull records of binding 6 and PolyRef
// (physics/collision/collide_internal.h), a box or a hull in its local frame, through which
// collide.glsl runs every box/hull routine of collide_poly.cpp (a box as the unit-box hull
// scaled by its half extents, as on the CPU).
//
// The includer declares the records before including collide.glsl:
//   layout(std430, binding = 6) readonly buffer Hulls { uint hullData[]; };
// One hull's record (uint words, floats as their bits), at header offset H; offsets in the
// header are relative to H (the packer: gpu_solver/include/phys/gpu/hull_pack.h):
//   H + 0   vertex count nv          H + 4..6  centroid x, y, z (float)
//   H + 1   face count nf            H + 7     most vertices of one face
//   H + 2   edge count ne            H + 8     V: vertices, 3 words each (x, y, z)
//   H + 3   words of the record      H + 9     P: face planes, 4 words each (nx, ny, nz, offset)
//   H + 10  F: face table, nf + 1 words: start of face f's vertex loop (relative to H) at
//           F + f, the end of the last at F + nf; loops are counter-clockwise from outside
//   H + 11  E: edges, 4 words each: v0, v1 and the two faces (ConvexHull::edgeFaces)
// A hull shape's GpuShape.size.x holds uintBitsToFloat(H); an H with no record behind it
// (0xFFFFFFFF) is a hull shape without a hull: no contact, as on the CPU.
// collide.glsl includes it (after shared.h, common.glsl and its own constants).
#ifndef PHYS_GPU_COLLIDE_HULL_GLSL
#define PHYS_GPU_COLLIDE_HULL_GLSL

#define PHYS_HULL_HEADER_WORDS PHYS_GPU_HULL_HEADER_WORDS
// The most vertices of one face (the packer refuses more): the clip buffers hold an incident
// face clipped by a reference face's side planes. Both from shared.h, as the packer's.
#define PHYS_HULL_MAX_FACE_VERTICES PHYS_GPU_HULL_MAX_FACE_VERTICES

float hullFloat(uint at) { return uintBitsToFloat(hullData[at]); }
vec3 hullVec3(uint at) { return vec3(hullFloat(at), hullFloat(at + 1u), hullFloat(at + 2u)); }

// ---- The unit-box hull (collide_poly.cpp's unitBoxHull) ---------------------------------------
// Vertex i = signs (x, y, z) of its bits; face f = 2 * axis + (normal < 0), offset = h[axis];
// edge e = 4 * axis + bits (bit 0, 1 = positive side on axis + 1, axis + 2), from the vertex
// on the negative side of `axis` to the one on its positive side.

// Loops of the box faces (+x -x +y -y +z -z), counter-clockwise seen from outside.
const uint kBoxFaceLoops[24] = uint[24](1u, 3u, 7u, 5u, 0u, 4u, 6u, 2u, 2u, 6u, 7u, 3u,
                                        0u, 1u, 5u, 4u, 4u, 5u, 7u, 6u, 0u, 2u, 3u, 1u);
// The two faces of each box edge (computeEdgeFaces of the unit box).
const uint kBoxEdgeFaces[24] = uint[24](3u, 5u, 5u, 2u, 4u, 3u, 2u, 4u, 5u, 1u, 1u, 4u,
                                        0u, 5u, 4u, 0u, 1u, 3u, 3u, 0u, 2u, 1u, 0u, 2u);

vec3 boxHullVertex(vec3 h, uint i) {
  return vec3((i & 1u) != 0u ? 1.0 : -1.0, (i & 2u) != 0u ? 1.0 : -1.0,
              (i & 4u) != 0u ? 1.0 : -1.0) * h;
}
vec3 boxHullNormal(int f) {
  vec3 n = vec3(0);
  n[f >> 1] = (f & 1) != 0 ? -1.0 : 1.0;
  return n;
}
void boxHullEdge(int e, out uint v0, out uint v1) {
  int axis = e >> 2;
  uint bits = uint(e & 3), v = 0u;
  if ((bits & 1u) != 0u) v |= 1u << uint((axis + 1) % 3);
  if ((bits & 2u) != 0u) v |= 1u << uint((axis + 2) % 3);
  v0 = v;
  v1 = v | 1u << uint(axis);
}

// ---- PolyRef: a box or a hull in its local frame ----------------------------------------------

struct Poly {
  bool box;
  vec3 scale;  // box: half extents
  uint base;   // hull: header offset H in hullData
  int nv, nf, ne;
  uint v, p, f, e;  // hull: absolute starts of the vertices, planes, face table, edges
};

// PolyRef::of: false for a hull shape whose record is missing (size.x = 0xFFFFFFFF) or does
// not fit in the buffer.
bool polyOf(uint type, vec4 size, out Poly q) {
  q.box = type == PHYS_GPU_SHAPE_BOX;
  q.scale = q.box ? size.xyz : vec3(1);
  q.base = 0u;
  q.nv = 8;
  q.nf = 6;
  q.ne = 12;
  q.v = q.p = q.f = q.e = 0u;
  if (q.box) return true;
  uint h = floatBitsToUint(size.x), len = uint(hullData.length());
  if (h >= len || len - h < PHYS_HULL_HEADER_WORDS || hullData[h + 3u] > len - h) return false;
  q.base = h;
  q.nv = int(hullData[h]);
  q.nf = int(hullData[h + 1u]);
  q.ne = int(hullData[h + 2u]);
  q.v = h + hullData[h + 8u];
  q.p = h + hullData[h + 9u];
  q.f = h + hullData[h + 10u];
  q.e = h + hullData[h + 11u];
  return q.nv > 0 && q.nf > 0;
}

vec3 polyVertex(Poly q, uint i) {
  return q.box ? boxHullVertex(q.scale, i) : hullVec3(q.v + 3u * i);
}
vec3 polyNormal(Poly q, int f) {
  return q.box ? boxHullNormal(f) : hullVec3(q.p + 4u * uint(f));
}
float polyOffset(Poly q, int f) {
  return q.box ? q.scale[f >> 1] : hullFloat(q.p + 4u * uint(f) + 3u);
}
vec3 polyCentroid(Poly q) { return q.box ? vec3(0) : hullVec3(q.base + 4u); }
// Vertices in face f's loop, and the k-th of them.
int polyLoopSize(Poly q, int f) {
  return q.box ? 4 : int(hullData[q.f + uint(f) + 1u] - hullData[q.f + uint(f)]);
}
uint polyLoopVertex(Poly q, int f, int k) {
  return q.box ? kBoxFaceLoops[4 * f + k] : hullData[q.base + hullData[q.f + uint(f)] + uint(k)];
}
void polyEdge(Poly q, int e, out uint v0, out uint v1) {
  if (q.box) {
    boxHullEdge(e, v0, v1);
    return;
  }
  v0 = hullData[q.e + 4u * uint(e)];
  v1 = hullData[q.e + 4u * uint(e) + 1u];
}
void polyEdgeFaces(Poly q, int e, out int f0, out int f1) {
  if (q.box) {
    f0 = int(kBoxEdgeFaces[2 * e]);
    f1 = int(kBoxEdgeFaces[2 * e + 1]);
    return;
  }
  f0 = int(hullData[q.e + 4u * uint(e) + 2u]);
  f1 = int(hullData[q.e + 4u * uint(e) + 3u]);
}
// PolyRef::support: max over the shape of dot(d, x).
float polySupport(Poly q, vec3 d) {
  if (q.box) return dot(abs(d), q.scale);
  float best = -kInf;
  for (int i = 0; i < q.nv; ++i) best = maxf(best, dot(d, hullVec3(q.v + 3u * uint(i))));
  return best;
}

#endif
