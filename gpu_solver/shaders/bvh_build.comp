#version 450
// BroadPhase (tree), 3: the tree's links, every node at once (Karras 2012). Thread i makes
// leaf i (the box of the shape at sorted position i, and whether it is dynamic) and, for
// i < L - 1, internal node i: the range of positions it covers (found from the common
// prefixes of the keys around i), where that range splits, and so its two children. Node 0
// is the root. Each child's parent goes to parents[] (leaf j at j, internal node c at L + c)
// for the bottom-up fit (bvh_fit.comp). Keys are distinct (code, index) pairs, so the
// prefix of equal codes continues into the positions' bits, as the paper's tie-break.
#extension GL_GOOGLE_include_directive : require
#extension GL_ARB_gpu_shader_fp64 : require
#include "shared.h"
#include "common.glsl"
layout(local_size_x = PHYS_GPU_GROUP) in;
layout(std430, binding = 0) readonly buffer Bounds { GpuAabb bounds[]; };
layout(std430, binding = 1) readonly buffer Shapes { GpuShape shapes[]; };
layout(std430, binding = 2) readonly buffer Params { GpuBodyParams params[]; };
layout(std430, binding = 3) readonly buffer Keys { uvec2 keys[]; };
layout(std430, binding = 4) writeonly buffer Nodes { GpuBvhNode nodes[]; };
layout(std430, binding = 5) writeonly buffer Leaves { GpuAabb leaves[]; };
layout(std430, binding = 6) writeonly buffer Parents { uint parents[]; };
layout(push_constant) uniform Push { GpuStepConstants k; };
#include "bvh.glsl"

// Length of the common prefix of the keys at positions i and j (codes, then positions);
// -1 past either end.
int prefix(int i, int j, int n) {
  if (j < 0 || j >= n) return -1;
  uint a = keys[i].x, b = keys[j].x;
  if (a != b) return 31 - findMSB(a ^ b);
  return 63 - findMSB(uint(i) ^ uint(j));
}

void main() {
  uint u = globalIndex();
  uint n = bvhLeafCount();
  if (u >= n) return;
  int i = int(u), L = int(n);
  uint s = keys[i].y;
  int body = shapes[s].body;
  bool dynamic = body >= 0 && (params[body].flags.x & PHYS_GPU_BODY_DYNAMIC) != 0u;
  leaves[i].lo = vec4(bounds[s].lo.xyz, dynamic ? 1.0 : 0.0);
  leaves[i].hi = vec4(bounds[s].hi.xyz, 0.0);
  if (i == 0) parents[n] = PHYS_GPU_BVH_NONE;  // the root's (and no leaf's but a lone one)
  if (L == 1) parents[0] = PHYS_GPU_BVH_NONE;
  if (i + 1 >= L) return;
  // The direction of the range: towards the neighbour sharing the longer prefix.
  int d = prefix(i, i + 1, L) > prefix(i, i - 1, L) ? 1 : -1;
  // Its other end: the farthest j whose prefix with i is longer than the other side's.
  int shortest = prefix(i, i - d, L);
  int reach = 2;
  while (prefix(i, i + reach * d, L) > shortest) reach *= 2;
  int length = 0;
  for (int t = reach / 2; t >= 1; t /= 2)
    if (prefix(i, i + (length + t) * d, L) > shortest) length += t;
  int j = i + length * d;
  // The split: the last position sharing more than the range's common prefix with i.
  int rangePrefix = prefix(i, j, L);
  int split = 0;
  int t = length;
  do {
    t = (t + 1) / 2;
    if (prefix(i, i + (split + t) * d, L) > rangePrefix) split += t;
  } while (t > 1);
  int gamma = i + split * d + min(d, 0);
  uint left = min(i, j) == gamma ? PHYS_GPU_BVH_LEAF | uint(gamma) : uint(gamma);
  uint right = max(i, j) == gamma + 1 ? PHYS_GPU_BVH_LEAF | uint(gamma + 1) : uint(gamma + 1);
  nodes[i].link = uvec4(left, right, uint(max(i, j)), 0u);
  parents[(left & PHYS_GPU_BVH_LEAF) != 0u ? left & ~PHYS_GPU_BVH_LEAF : n + left] = u;
  parents[(right & PHYS_GPU_BVH_LEAF) != 0u ? right & ~PHYS_GPU_BVH_LEAF : n + right] = u;
}
