// The tree's query, shared by bvh_count.comp and bvh_write.comp (as broad_phase.glsl's sweep
// by bp_count and bp_write, whose filters it uses): the shape at sorted position p walks the
// tree from the root with a stack, visiting the children whose boxes meet its own. It
// skips every subtree whose positions all lie at or before p (that pair belongs to the
// other shape's walk: each pair found once), and, when the shape is not dynamic, every
// subtree without a dynamic shape (no pair there can collide). Each box it compares with
// its own is a candidate test (`tests`). Both passes walk the same way in the same order,
// so the counts of the first are the offsets of the second after a prefix sum.
#ifndef PHYS_GPU_BVH_QUERY_GLSL
#define PHYS_GPU_BVH_QUERY_GLSL

layout(std430, binding = 10) readonly buffer Nodes { GpuBvhNode nodes[]; };
layout(std430, binding = 11) readonly buffer Leaves { GpuAabb leaves[]; };
#include "bvh.glsl"

bool boxesMeet(vec3 lo, vec3 hi, vec4 otherLo, vec4 otherHi) {
  return all(lessThanEqual(lo, otherHi.xyz)) && all(lessThanEqual(otherLo.xyz, hi));
}

// Calls PAIR(other) for every pair of the shape s at sorted position p, in a fixed order;
// counts the box tests in `tests`.
#define FOR_EACH_TREE_PAIR(p, s, PAIR)                                              \
  {                                                                                 \
    uint leafCount = bvhLeafCount();                                                \
    vec3 ownLo = leaves[p].lo.xyz, ownHi = leaves[p].hi.xyz;                        \
    bool ownDynamic = leaves[p].lo.w != 0.0;                                        \
    uint stack[PHYS_GPU_BVH_STACK];                                                 \
    uint depth = 0u;                                                                \
    uint node = leafCount > 1u ? 0u : PHYS_GPU_BVH_NONE;                            \
    while (node != PHYS_GPU_BVH_NONE) {                                             \
      uvec4 link = nodes[node].link;                                                \
      uint first = PHYS_GPU_BVH_NONE, second = PHYS_GPU_BVH_NONE;                   \
      for (uint side = 0u; side < 2u; ++side) {                                     \
        uint c = side == 0u ? link.x : link.y;                                      \
        if ((c & PHYS_GPU_BVH_LEAF) != 0u) {                                        \
          uint j = c & ~PHYS_GPU_BVH_LEAF;                                          \
          if (j <= p) continue;                                                     \
          vec4 lo = leaves[j].lo;                                                   \
          if (!ownDynamic && lo.w == 0.0) continue;                                 \
          ++tests;                                                                  \
          if (!boxesMeet(ownLo, ownHi, lo, leaves[j].hi)) continue;                 \
          uint t = keys[j].y;                                                       \
          if (canCollide(s, t)) PAIR(t);                                            \
        } else {                                                                    \
          if (nodes[c].link.z <= p) continue;                                       \
          vec4 lo = nodes[c].lo;                                                    \
          if (!ownDynamic && lo.w == 0.0) continue;                                 \
          ++tests;                                                                  \
          if (!boxesMeet(ownLo, ownHi, lo, nodes[c].hi)) continue;                  \
          if (first == PHYS_GPU_BVH_NONE)                                           \
            first = c;                                                              \
          else                                                                      \
            second = c;                                                             \
        }                                                                           \
      }                                                                             \
      if (second != PHYS_GPU_BVH_NONE) stack[depth++] = second;                     \
      node = first != PHYS_GPU_BVH_NONE ? first                                     \
             : depth > 0u               ? stack[--depth]                            \
                                        : PHYS_GPU_BVH_NONE;                        \
    }                                                                               \
    FOR_EACH_PLANE_PAIR(s, PAIR)                                                    \
  }

#endif
