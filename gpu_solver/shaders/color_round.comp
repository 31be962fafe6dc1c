#version 450
// Colored Gauss-Seidel, coloring: one round of Jones-Plassmann. A contact not colored yet
// whose hashed priority is the highest among the uncolored contacts it shares a dynamic
// body with takes the lowest color none of its colored neighbours has. Reads one color
// buffer and writes the other, so a round's choices do not see each other: the same
// colors whatever the device's scheduling. Neighbours come from the bodies' sorted
// contact references.
// GpuSolveConstants.groupPasses > 0 (a small world, GpuWorld's kSmallConstraints): one
// workgroup runs that many rounds, ping-ponging the two buffers itself with a barrier between
// rounds (round r reads buffer r % 2): the same rounds, one dispatch instead of 24.
#extension GL_GOOGLE_include_directive : require
#extension GL_ARB_gpu_shader_fp64 : require
#include "shared.h"
#include "common.glsl"
layout(local_size_x = PHYS_GPU_GROUP) in;
layout(std430, binding = 0) readonly buffer Keys { uvec2 refKeys[]; };
layout(std430, binding = 1) readonly buffer Refs { uvec4 refs[]; };
layout(std430, binding = 2) readonly buffer Contacts { GpuContact contacts[]; };
layout(std430, binding = 3) readonly buffer Params { GpuBodyParams params[]; };
// Coherent: a workgroup running every round reads in one round what it wrote in the last.
layout(std430, binding = 4) coherent buffer ColorsA { uint colorA[]; };
layout(std430, binding = 5) coherent buffer ColorsB { uint colorB[]; };
layout(std430, binding = 6) readonly buffer Counters { uint counters[]; };
layout(std430, binding = 7) readonly buffer Joints { GpuJoint joints[]; };
layout(push_constant) uniform Push { GpuSolveConstants k; };

uint hash(uint x) {  // a fixed integer mix (lowbias32)
  x ^= x >> 16;
  x *= 0x7feb352du;
  x ^= x >> 15;
  x *= 0x846ca68bu;
  x ^= x >> 16;
  return x;
}
bool outranks(uint a, uint b) {
  uint ha = hash(a), hb = hash(b);
  return ha > hb || (ha == hb && a > b);
}

// Round `parity` reads colorA and writes colorB (0), or the other way round (1).
uint colorIn(uint parity, uint c) { return parity == 0u ? colorA[c] : colorB[c]; }
void setColorOut(uint parity, uint c, uint color) {
  if (parity == 0u)
    colorB[c] = color;
  else
    colorA[c] = color;
}

// One round for constraint c (id: joints, then contacts).
void colorOne(uint parity, uint c) {
  uint mine = colorIn(parity, c);
  setColorOut(parity, c, mine);
  if (mine != PHYS_GPU_UNCOLORED) return;
  uvec2 used = uvec2(0);  // colors 0..31, 32..63 of the colored neighbours
  for (int side = 0; side < 2; ++side) {
    int b;
    if (c < k.jointCount)
      b = side == 0 ? joints[c].bodyA : joints[c].bodyB;
    else
      b = side == 0 ? contacts[c - k.jointCount].bodyA : contacts[c - k.jointCount].bodyB;
    if (b < 0 || (params[b].flags.x & PHYS_GPU_BODY_DYNAMIC) == 0u) continue;
    for (uint e = refs[b].x; e < refs[b].y; ++e) {
      uint other = refKeys[e].y >> 1;
      if (other == c) continue;
      uint oc = colorIn(parity, other);
      if (oc == PHYS_GPU_UNCOLORED) {
        if (outranks(other, c)) return;  // not this round
      } else if (oc < 32u) {
        used.x |= 1u << oc;
      } else if (oc < 64u) {
        used.y |= 1u << (oc - 32u);
      }
    }
  }
  uint color = used.x != 0xFFFFFFFFu ? uint(findLSB(~used.x))
                                     : (used.y != 0xFFFFFFFFu ? 32u + uint(findLSB(~used.y)) : 64u);
  // Past the colors the passes dispatch: the serial overflow (color_keys.comp).
  setColorOut(parity, c, min(color, PHYS_GPU_MAX_COLORS));
}

void main() {
  uint count = k.jointCount + counters[PHYS_GPU_COUNTER_PAIRS];
  if (k.groupPasses == 0u) {
    uint c = globalIndex();
    if (c < count) colorOne(0u, c);
    return;
  }
  for (uint r = 0u; r < k.groupPasses; ++r) {
    for (uint c = gl_LocalInvocationID.x; c < count; c += PHYS_GPU_GROUP) colorOne(r % 2u, c);
    memoryBarrierBuffer();
    barrier();
  }
}
