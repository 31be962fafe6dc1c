// The broad phase's tree, shared by its kernels (bvh_*.comp): a linear BVH (Karras 2012,
// "Maximizing parallelism in the construction of BVHs, octrees and k-d trees") over the
// non-plane shapes sorted by the Morton code of their boxes' centres.
//
// Why a tree and not the sweep it replaced (bp_*.comp, kept as GpuWorld::BroadPhase::Sweep):
// a sweep's cost is the length of its intervals along one axis, and a pile spread on a floor
// makes them long whatever the axis; the tree's query visits only the nodes whose boxes
// meet the shape's, so its cost follows the pairs found, not how the bodies lie. Its build
// is the sort (O(N log^2 N) bitonic, as before) and two O(N) passes, all on the device.
#ifndef PHYS_GPU_BVH_GLSL
#define PHYS_GPU_BVH_GLSL

// Float bits to a uint with the same order (negatives flipped entirely, positives' sign set),
// as bp_keys.comp's; and back.
uint bvhOrdered(float f) {
  uint u = floatBitsToUint(f);
  return (u & 0x80000000u) != 0u ? ~u : u | 0x80000000u;
}
float bvhUnordered(uint u) {
  return uintBitsToFloat((u & 0x80000000u) != 0u ? u & 0x7FFFFFFFu : ~u);
}

// The shapes in the tree: every shape but the planes (the host keeps them apart).
uint bvhLeafCount() { return k.shapeCount - k.planeCount; }

bool bvhFinite(vec3 v) { return !any(isnan(v)) && !any(isinf(v)); }

#endif
