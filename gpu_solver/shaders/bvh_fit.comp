#version 450
// BroadPhase (tree), 4: the internal nodes' boxes, bottom up. Each leaf's thread climbs
// towards the root; at each node the first child's thread to arrive stops (atomic flags,
// zeroed by the host) and the second, whose sibling's box is then written, joins the two and
// climbs on. Boxes are minima and maxima, exact in any order: the same tree every run.
//
// The climb is one level per round of the workgroup, every thread taking part in each
// round's atomic (a thread done climbing adds to a spare flag of its own), until none of
// the group climbs. Lavapipe (Mesa 22.3) returned wrong values from an atomic that only some
// of a vector's lanes reached inside the loop (the textbook loop, each thread climbing on its
// own, lost nodes there), and a round-based climb costs a GPU little: a few barriers a level.
#extension GL_GOOGLE_include_directive : require
#extension GL_ARB_gpu_shader_fp64 : require
#include "shared.h"
#include "common.glsl"
layout(local_size_x = PHYS_GPU_GROUP) in;
layout(std430, binding = 0) coherent buffer Nodes { GpuBvhNode nodes[]; };
layout(std430, binding = 1) readonly buffer Leaves { GpuAabb leaves[]; };
layout(std430, binding = 2) readonly buffer Parents { uint parents[]; };
// L - 1 node flags, then a spare per thread (2 L + PHYS_GPU_GROUP in all).
layout(std430, binding = 3) buffer Flags { uint flags[]; };
layout(push_constant) uniform Push { GpuStepConstants k; };
#include "bvh.glsl"
shared uint groupClimbing;

void childBox(uint c, out vec4 lo, out vec4 hi) {
  if ((c & PHYS_GPU_BVH_LEAF) != 0u) {
    lo = leaves[c & ~PHYS_GPU_BVH_LEAF].lo;
    hi = leaves[c & ~PHYS_GPU_BVH_LEAF].hi;
  } else {
    lo = nodes[c].lo;
    hi = nodes[c].hi;
  }
}

void main() {
  uint i = globalIndex();
  uint n = bvhLeafCount();
  uint node = i < n && n >= 2u ? parents[i] : PHYS_GPU_BVH_NONE;
  for (;;) {
    // Does anyone in the group still climb? (The same answer for every thread.)
    if (gl_LocalInvocationID.x == 0u) groupClimbing = 0u;
    barrier();
    if (node != PHYS_GPU_BVH_NONE) groupClimbing = 1u;
    barrier();
    bool any = groupClimbing != 0u;
    barrier();
    if (!any) break;
    // What this thread wrote (the child it came from) is seen before its flag is.
    memoryBarrierBuffer();
    uint arrived = atomicAdd(flags[node != PHYS_GPU_BVH_NONE ? node : n + i], 1u);
    memoryBarrierBuffer();
    if (node == PHYS_GPU_BVH_NONE) continue;
    if (arrived == 0u) {
      node = PHYS_GPU_BVH_NONE;  // the sibling's thread goes on from here
      continue;
    }
    uvec4 link = nodes[node].link;
    vec4 aLo, aHi, bLo, bHi;
    childBox(link.x, aLo, aHi);
    childBox(link.y, bLo, bHi);
    // w of lo: whether a dynamic shape is below (the query's filter for static ones).
    nodes[node].lo = vec4(min(aLo.xyz, bLo.xyz), max(aLo.w, bLo.w));
    nodes[node].hi = vec4(max(aHi.xyz, bHi.xyz), 0.0);
    node = parents[n + node];
  }
}
