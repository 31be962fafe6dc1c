#version 450
// NarrowPhase: one contact manifold per candidate pair (one thread each), as the CPU's
// World::Impl::narrowPhase: the shapes' world transforms, the speculative margin grown by the
// bodies' speeds, then phys::collide (collide.glsl) with A = the pair's shape a, B = shape b.
// Impulses start at zero; matching them to last step's by feature id is a later stage's job.
// Hull shapes read their records from binding 6 (layout in collide_hull.glsl, packed by
// phys/gpu/hull_pack.h): GpuShape.size.x = uintBitsToFloat(header offset).
#extension GL_GOOGLE_include_directive : require
#extension GL_ARB_gpu_shader_fp64 : require
#include "shared.h"
#include "common.glsl"
layout(std430, binding = 6) readonly buffer Hulls { uint hullData[]; };
#include "collide.glsl"
layout(local_size_x = PHYS_GPU_GROUP) in;
layout(std430, binding = 0) readonly buffer States { GpuBodyState states[]; };
layout(std430, binding = 1) readonly buffer Params { GpuBodyParams params[]; };
layout(std430, binding = 2) readonly buffer Shapes { GpuShape shapes[]; };
layout(std430, binding = 3) readonly buffer Pairs { GpuPair pairs[]; };
layout(std430, binding = 4) writeonly buffer Manifolds { GpuManifold manifolds[]; };
layout(std430, binding = 5) readonly buffer Counters { uint counters[]; };
layout(push_constant) uniform Push { GpuStepConstants k; };

// A shape's world transform (World::Impl::shapeTransform: body frame * local frame) and its
// body's velocities; static shapes hold their world transform and do not move.
void shapeWorld(GpuShape s, out Xf xf, out vec3 v, out vec3 w) {
  v = vec3(0);
  w = vec3(0);
  xf.p = s.localP.xyz;
  xf.q = s.localQ;
  if (s.body < 0) return;
  GpuBodyState b = states[s.body];
  // Body frame: origin = com - R localCenter.
  vec3 origin = b.com.xyz - quatRotate(b.q, params[s.body].localCenter.xyz);
  xf.p = origin + quatRotate(b.q, s.localP.xyz);
  xf.q = quatNormalize(quatMul(b.q, s.localQ));
  v = b.v.xyz;
  w = b.w.xyz;
}

void main() {
  uint i = globalIndex();
  if (i >= counters[PHYS_GPU_COUNTER_PAIRS]) return;
  GpuPair pair = pairs[i];
  GpuShape sa = shapes[pair.a], sb = shapes[pair.b];
  Xf xa, xb;
  vec3 va, wa, vb, wb;
  shapeWorld(sa, xa, va, wa);
  shapeWorld(sb, xb, vb, wb);
  // The margin grows with the speeds so a fast body meets a speculative contact before it
  // can pass through anything (localP.w: the shape's reach about its body's centre of mass).
  float reach =
      (length(va) + length(wa) * sa.localP.w + length(vb) + length(wb) * sb.localP.w) * k.dt;
  float margin = k.speculativeDistance + reach;

  Manifold m;
  m.normal = vec3(0);
  collide(Geom(sa.type, sa.size), xa, Geom(sb.type, sb.size), xb, margin, m);

  GpuManifold o;
  o.normal = vec4(m.count > 0 ? m.normal : vec3(0), sqrt(sa.friction * sb.friction));
  for (int j = 0; j < 4; ++j) {
    bool used = j < m.count;
    o.points[j] = used ? vec4(m.point[j], m.sep[j]) : vec4(0);
    o.featureIds[j] = used ? m.id[j] : 0u;
  }
  o.count = uint(m.count);
  o.shapeA = pair.a;
  o.shapeB = pair.b;
  o.restitution = max(sa.restitution, sb.restitution);
  o.normalImpulse = vec4(0);
  o.tangentImpulse1 = vec4(0);
  o.tangentImpulse2 = vec4(0);
  manifolds[i] = o;
}
