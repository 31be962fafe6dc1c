// The touch list (touch_flags.comp, touch_write.comp): what the host's sleep pass needs of a
// step's contacts, instead of the manifolds themselves (physics/world/world_gpu.cpp): the
// pairs of non-static bodies (dynamic, kinematic or asleep) whose manifold has points, as
// (body A, body B) in GpuWorld's body indices, in the manifolds' order (a prefix sum, not an
// atomic append: the same list every run). Pairs with a static body never join an island
// nor wake one, so they are left out.
#ifndef PHYS_GPU_TOUCH_LIST_GLSL
#define PHYS_GPU_TOUCH_LIST_GLSL

// Needs bindings `manifolds`, `shapes`, `counters` and the push constants `k`
// (GpuStepConstants). Manifold i's bodies, or false.
bool touching(uint i, out ivec2 pair) {
  pair = ivec2(-1);
  if (i >= min(counters[PHYS_GPU_COUNTER_PAIRS], k.pairCapacity)) return false;
  if (manifolds[i].count == 0u) return false;
  pair = ivec2(shapes[manifolds[i].shapeA].body, shapes[manifolds[i].shapeB].body);
  return pair.x >= 0 && pair.y >= 0;
}

#endif
