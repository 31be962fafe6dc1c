#version 450
// NarrowPhase, warm starts: each manifold takes the impulses of last step's points with the
// same feature ids, from last step's manifold of the same shape pair (both lists are sorted
// by pair, so a binary search finds it), as World::Impl::narrowPhase does.
#extension GL_GOOGLE_include_directive : require
#extension GL_ARB_gpu_shader_fp64 : require
#include "shared.h"
#include "common.glsl"
layout(local_size_x = PHYS_GPU_GROUP) in;
layout(std430, binding = 0) readonly buffer Prev { GpuManifold prev[]; };
layout(std430, binding = 1) buffer Current { GpuManifold manifolds[]; };
layout(std430, binding = 2) readonly buffer Counters { uint counters[]; };
layout(push_constant) uniform Push { GpuStepConstants k; };

bool before(uvec2 a, uvec2 b) { return a.x < b.x || (a.x == b.x && a.y < b.y); }

void main() {
  uint i = globalIndex();
  if (i >= counters[PHYS_GPU_COUNTER_PAIRS]) return;
  uint n = manifolds[i].count;
  if (n == 0u) return;
  uvec2 key = uvec2(manifolds[i].shapeA, manifolds[i].shapeB);
  uint lo = 0u, hi = counters[PHYS_GPU_COUNTER_PREV_PAIRS];
  while (lo < hi) {
    uint mid = (lo + hi) / 2u;
    if (before(uvec2(prev[mid].shapeA, prev[mid].shapeB), key)) lo = mid + 1u; else hi = mid;
  }
  if (lo >= counters[PHYS_GPU_COUNTER_PREV_PAIRS] || prev[lo].shapeA != key.x ||
      prev[lo].shapeB != key.y)
    return;
  GpuManifold old = prev[lo];
  vec4 ni = vec4(0), t1 = vec4(0), t2 = vec4(0);
  bool persists = false;
  for (uint p = 0u; p < n; ++p) {
    for (uint q = 0u; q < old.count; ++q) {
      if (old.featureIds[q] == manifolds[i].featureIds[p]) {
        ni[p] = old.normalImpulse[q];
        t1[p] = old.tangentImpulse1[q];
        t2[p] = old.tangentImpulse2[q];
        persists = true;
        break;
      }
    }
  }
  // Patch friction keeps the manifold's friction impulses while any point persists.
  if (k.patchFriction != 0u && persists) {
    t1 = old.tangentImpulse1;
    t2 = old.tangentImpulse2;
  }
  manifolds[i].normalImpulse = ni;
  manifolds[i].tangentImpulse1 = t1;
  manifolds[i].tangentImpulse2 = t2;
}
