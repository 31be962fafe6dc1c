// The broad phase's shared part (bp_count.comp, bp_write.comp): a sweep along x over the
// shapes sorted by the low x of their bounds. Sorted position p meets every later shape
// whose low x is below its high x; those whose boxes overlap and that can collide are its
// pairs. Each static plane is paired with every shape whose box reaches below it.
// Both passes enumerate the same pairs in the same order, so the counts of the first are
// the offsets of the second after a prefix sum: no atomics, a deterministic pair list.
// The sweep is GpuWorld::BroadPhase::Sweep, kept to measure the tree against (bvh.glsl);
// the tree's query (bvh_query.glsl) uses the filters below too.
#ifndef PHYS_GPU_BROAD_PHASE_GLSL
#define PHYS_GPU_BROAD_PHASE_GLSL

layout(std430, binding = 0) readonly buffer Bounds { GpuAabb bounds[]; };
layout(std430, binding = 1) readonly buffer Shapes { GpuShape shapes[]; };
layout(std430, binding = 2) readonly buffer Params { GpuBodyParams params[]; };
layout(std430, binding = 3) readonly buffer Keys { uvec2 keys[]; };
layout(std430, binding = 4) readonly buffer Planes { uint planes[]; };
// The body (host slot) owning each shape, and the sorted pairs of slots joined by a joint
// without collide_connected (World::Impl::noCollide).
layout(std430, binding = 8) readonly buffer Owners { uint owners[]; };
layout(std430, binding = 9) readonly buffer NoCollide { uvec2 noCollide[]; };
layout(push_constant) uniform Push { GpuStepConstants k; };

bool dynamicShape(uint s) {
  int b = shapes[s].body;
  return b >= 0 && (params[b].flags.x & PHYS_GPU_BODY_DYNAMIC) != 0u;
}

// As the CPU's broadPhaseStage: not two shapes of one body, and one of them dynamic.
bool joinedApart(uint s, uint t) {
  uint a = min(owners[s], owners[t]), b = max(owners[s], owners[t]);
  uint lo = 0u, hi = k.noCollideCount;
  while (lo < hi) {
    uint mid = (lo + hi) / 2u;
    uvec2 key = noCollide[mid];
    if (key.x < a || (key.x == a && key.y < b)) lo = mid + 1u; else hi = mid;
  }
  return lo < k.noCollideCount && noCollide[lo] == uvec2(a, b);
}

bool canCollide(uint s, uint t) {
  if (shapes[s].body >= 0 && shapes[s].body == shapes[t].body) return false;
  if (!dynamicShape(s) && !dynamicShape(t)) return false;
  return k.noCollideCount == 0u || !joinedApart(s, t);
}

bool overlaps(uint s, uint t) {
  return all(lessThanEqual(bounds[s].lo.xyz, bounds[t].hi.xyz)) &&
         all(lessThanEqual(bounds[t].lo.xyz, bounds[s].hi.xyz));
}

// The box's lowest corner along the plane's normal is below the plane, padded like any
// shape by half the speculative distance (the box has the other half).
bool belowPlane(uint s, uint plane) {
  vec4 pl = shapes[plane].size;
  vec3 corner = mix(bounds[s].hi.xyz, bounds[s].lo.xyz, greaterThan(pl.xyz, vec3(0)));
  return dot(pl.xyz, corner) <= pl.w + 0.5 * k.speculativeDistance;
}

// Calls PAIR(plane) for every plane the shape s reaches, in the planes' order (after its
// other pairs, for the sweep and the tree alike).
#define FOR_EACH_PLANE_PAIR(s, PAIR)                         \
  for (uint j = 0u; j < k.planeCount; ++j) {                 \
    uint pl = planes[j];                                     \
    if (canCollide(s, pl) && belowPlane(s, pl)) PAIR(pl);    \
  }

// Calls PAIR(other) for every pair of the shape at sorted position p, in a fixed order;
// counts the box tests in `tests` (the candidate tests of the GPU profile).
#define FOR_EACH_PAIR(p, s, PAIR)                                       \
  {                                                                     \
    float hiX = bounds[s].hi[k.sweepAxis];                              \
    for (uint q = p + 1u; q < k.shapeSortCount; ++q) {                  \
      uint t = keys[q].y;                                               \
      if (t == 0xFFFFFFFFu || bounds[t].lo[k.sweepAxis] > hiX) break;   \
      ++tests;                                                          \
      if (overlaps(s, t) && canCollide(s, t)) PAIR(t);                  \
    }                                                                   \
    FOR_EACH_PLANE_PAIR(s, PAIR)                                        \
  }

#endif
