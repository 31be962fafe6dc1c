#version 450
// BroadPhase (tree), 2: the sort keys, (30-bit Morton code of the box's centre, shape index).
// The codes quantize the scene's bounds (bvh_scene.comp) in cubes, 1024 along its longest
// side: a flat pile's height then takes few of the bits, which keeps the tree's splits
// across the floor where they separate boxes. Equal codes are told apart by index (the
// sort's second key, and the build's tie-break). Planes and the padding sort last as
// (~0u, ~0u), past every code.
#extension GL_GOOGLE_include_directive : require
#extension GL_ARB_gpu_shader_fp64 : require
#include "shared.h"
#include "common.glsl"
layout(local_size_x = PHYS_GPU_GROUP) in;
layout(std430, binding = 0) readonly buffer Bounds { GpuAabb bounds[]; };
layout(std430, binding = 1) readonly buffer Shapes { GpuShape shapes[]; };
layout(std430, binding = 2) writeonly buffer Keys { uvec2 keys[]; };
layout(std430, binding = 3) readonly buffer Scene { uint scene[]; };
layout(push_constant) uniform Push { GpuStepConstants k; };
#include "bvh.glsl"

// The low 10 bits of v spread to every third bit.
uint spreadBits(uint v) {
  v = (v * 0x00010001u) & 0xFF0000FFu;
  v = (v * 0x00000101u) & 0x0F00F00Fu;
  v = (v * 0x00000011u) & 0xC30C30C3u;
  v = (v * 0x00000005u) & 0x49249249u;
  return v;
}

void main() {
  uint i = globalIndex();
  if (i >= k.shapeSortCount) return;
  if (i >= k.shapeCount || shapes[i].type == PHYS_GPU_SHAPE_PLANE) {
    keys[i] = uvec2(0xFFFFFFFFu);
    return;
  }
  uint code = 0u;
  vec3 c = 0.5 * (bounds[i].lo.xyz + bounds[i].hi.xyz);
  if (scene[0] != 0xFFFFFFFFu && bvhFinite(c)) {
    vec3 lo = vec3(bvhUnordered(scene[0]), bvhUnordered(scene[1]), bvhUnordered(scene[2]));
    vec3 hi = vec3(bvhUnordered(~scene[4]), bvhUnordered(~scene[5]), bvhUnordered(~scene[6]));
    float side = max(hi.x - lo.x, max(hi.y - lo.y, hi.z - lo.z));
    float scale = side > 0.0 && !isinf(side) ? 1024.0 / side : 0.0;
    uvec3 cell = uvec3(clamp((c - lo) * scale, vec3(0), vec3(1023)));
    code = (spreadBits(cell.x) << 2) | (spreadBits(cell.y) << 1) | spreadBits(cell.z);
  }
  keys[i] = uvec2(code, i);
}
