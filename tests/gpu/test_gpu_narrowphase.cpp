// The GPU narrow phase (gpu_solver/shaders/narrow_phase.comp) against the CPU's phys::collide,
// run through the device layer on seeded random configurations of every pair of spheres,
// boxes, capsules, planes and convex hulls (packed by phys/gpu/hull_pack.h), in both orders, on
// static and moving bodies, with centres of mass off the body origin and shapes off their body
// frame. The two must find the same points with the same feature ids (warm starting matches points
// across steps by id), and agree on normals, positions and separations to about 1e-4.
//
// A configuration within a rounding error of a decision (two SAT axes within the tolerance, a
// point at the margin, a vertex at a clip plane's slop) may go either way on either side; such
// near-ties are found by nudging the CPU's input by 2e-5 (m, rad) and need only match one of
// the nudged answers. A reduction to four points that chose other candidates as good as the
// CPU's (the same deepest point, the same area within 0.1 %) is a near-tie too: on an NVIDIA
// H100 (2026-11-26) four random hull-plane pairs of 400 kept another fourth vertex than the
// CPU, which 32 nudges of the pose did not reproduce.
#include <gtest/gtest.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <map>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "phys/gpu/hull_pack.h"
#include "phys/gpu/shared.h"
#include "phys/collision/shapes.h"
#include "shader_table.h"
#include "vk_device.h"

namespace phys {
namespace {

constexpr float kDt = 1.0f / 60.0f;
constexpr float kSpeculative = 0.02f;
constexpr float kPi2 = 2.0f * kPi;
constexpr float kDeg = kPi / 180.0f;

// ---------------------------------------------------------------------------------------------
// Random configurations

class Rng {
 public:
  explicit Rng(uint32_t seed) : e_(seed) {}
  float uniform(float lo, float hi) { return lo + (hi - lo) * unit01(); }
  bool chance(float p) { return unit01() < p; }
  int below(int n) { return std::min(n - 1, static_cast<int>(unit01() * float(n))); }
  Vec3 box(float s) { return {uniform(-s, s), uniform(-s, s), uniform(-s, s)}; }
  Vec3 box(Vec3 s) { return {uniform(-s.x, s.x), uniform(-s.y, s.y), uniform(-s.z, s.z)}; }
  Vec3 direction() {
    for (;;) {
      Vec3 v = box(1.0f);
      float l2 = lengthSquared(v);
      if (l2 > 0.01f && l2 <= 1.0f) return v * (1.0f / std::sqrt(l2));
    }
  }
  Quat rotation() {
    for (;;) {
      Quat q{uniform(-1, 1), uniform(-1, 1), uniform(-1, 1), uniform(-1, 1)};
      float l2 = lengthSquared(q);
      if (l2 > 0.01f && l2 <= 1.0f) return normalize(q);
    }
  }

 private:
  float unit01() { return float(e_() >> 8) * (1.0f / 16777216.0f); }
  std::mt19937 e_;
};

Quat axisAngle(Vec3 axis, float angle) {
  return normalize(Quat::fromAxisAngle(axis, angle));
}

/// A shape as the GPU step sees it: static (its world transform) or on a body of its own.
struct SceneShape {
  ShapeGeom geom;
  bool isStatic = false;
  Transform body;   ///< dynamic: the body frame (origin, orientation)
  Transform local;  ///< dynamic: the shape in the body frame; static: the shape in the world
  Vec3 localCenter, v, w;
  float boundRadius = 0;
  float friction = 0.5f, restitution = 0;
  Transform world() const { return isStatic ? local : body * local; }
};

struct Scene {
  std::vector<SceneShape> shapes;
  std::vector<std::pair<uint32_t, uint32_t>> pairs;
  uint32_t add(const SceneShape& s) {
    shapes.push_back(s);
    return static_cast<uint32_t>(shapes.size() - 1);
  }
  /// Pair (a, b) with a < b: the shape added first is A.
  void pair(uint32_t a, uint32_t b) { pairs.push_back({std::min(a, b), std::max(a, b)}); }
  /// Two new shapes paired, in a random order (both argument orders get tested).
  void pairOf(Rng& rng, const SceneShape& a, const SceneShape& b) {
    bool swap = rng.chance(0.5f);
    uint32_t ia = add(swap ? b : a);
    uint32_t ib = add(swap ? a : b);
    pair(ia, ib);
  }
};

float extent(const ShapeGeom& g) {
  switch (g.type) {
    case ShapeType::Sphere:
      return g.radius;
    case ShapeType::Box:
      return length(g.halfExtents);
    case ShapeType::Capsule:
      return g.radius + g.halfHeight;
    case ShapeType::Hull: {
      float r = 0;
      if (g.hull)
        for (const Vec3& v : g.hull->vertices) r = std::max(r, length(v));
      return r;
    }
    default:
      return 0;
  }
}

enum class Motion { Any, Dynamic, Static };

/// `g` at world transform `world`, on a static or dynamic body chosen at random (unless told),
/// half the time off its body's frame and with the centre of mass off the body origin, half
/// the time moving (which widens the margin).
SceneShape place(Rng& rng, const ShapeGeom& g, Transform world, Motion motion = Motion::Any) {
  SceneShape s;
  s.geom = g;
  s.friction = rng.uniform(0, 1.2f);
  s.restitution = rng.uniform(0, 1);
  world.q = normalize(world.q);
  s.isStatic = motion == Motion::Static || (motion == Motion::Any && rng.chance(0.25f));
  if (s.isStatic) {
    s.local = world;
    return s;
  }
  if (rng.chance(0.5f)) s.local = {rng.box(0.4f), rng.rotation()};
  if (rng.chance(0.5f)) s.localCenter = rng.box(0.3f);
  // body * local = world.
  Quat qb = normalize(world.q * conjugate(s.local.q));
  s.body = {world.p - rotate(qb, s.local.p), qb};
  if (rng.chance(0.5f)) {
    s.v = rng.direction() * rng.uniform(0, 3);
    s.w = rng.direction() * rng.uniform(0, 5);
  }
  s.boundRadius = length(s.local.p - s.localCenter) + extent(g);
  return s;
}

/// The static plane dot(n, x) = d, held by a random frame (as a plane on a static body).
SceneShape planeShape(Rng& rng, Vec3 n, float d) {
  Transform t{rng.box(3.0f), rng.rotation()};
  n = normalize(n);
  SceneShape s =
      place(rng, ShapeGeom::plane(invRotate(t.q, n), d - dot(n, t.p)), t, Motion::Static);
  return s;
}

/// The world plane of a plane shape, as the CPU's worldPlane computes it.
void worldPlane(const SceneShape& s, Vec3* n, float* d) {
  Transform t = s.world();
  *n = rotate(t.q, s.geom.normal);
  *d = s.geom.offset + dot(*n, t.p);
}

float boxSupport(Vec3 he, Quat q, Vec3 dir) {
  Vec3 l = invRotate(q, dir);
  return dot(vabs(l), he);
}

Vec3 randomHalfExtents(Rng& rng, float lo = 0.1f, float hi = 1.0f) {
  return {rng.uniform(lo, hi), rng.uniform(lo, hi), rng.uniform(lo, hi)};
}

using HullPtr = std::shared_ptr<const ConvexHull>;

HullPtr hullOf(const std::vector<Vec3>& points) {
  std::string error;
  HullPtr h = buildConvexHull(points, &error);
  EXPECT_NE(h, nullptr) << error;
  return h;
}

/// The convex hull of 4 to 30 random points (in a box, on an ellipsoid, or a box's corners
/// with points on its faces, which merge into polygons), off the shape's origin.
HullPtr randomHull(Rng& rng) {
  for (;;) {
    const int n = 4 + rng.below(27);
    const Vec3 s = randomHalfExtents(rng, 0.15f, 0.8f);
    const Vec3 shift = rng.box(0.2f);
    std::vector<Vec3> points;
    const int kind = rng.below(3);
    for (int i = 0; i < n; ++i) {
      Vec3 p;
      if (kind == 0) {
        p = rng.box(s);
      } else if (kind == 1) {
        p = mulComponents(rng.direction(), s);
      } else if (i < 8) {
        p = {i & 1 ? s.x : -s.x, i & 2 ? s.y : -s.y, i & 4 ? s.z : -s.z};
      } else {
        p = rng.box(s);
        int axis = rng.below(3);
        p[axis] = rng.chance(0.5f) ? s[axis] : -s[axis];
      }
      points.push_back(p + shift);
    }
    std::string error;
    if (HullPtr h = buildConvexHull(points, &error)) return h;
  }
}

/// A prism over a regular polygon of `sides` (radius r, half height hh along z): two faces of
/// `sides` vertices.
HullPtr prismHull(int sides, float r, float hh) {
  std::vector<Vec3> points;
  for (int i = 0; i < sides; ++i) {
    float a = kPi2 * float(i) / float(sides);
    points.push_back({r * std::cos(a), r * std::sin(a), -hh});
    points.push_back({r * std::cos(a), r * std::sin(a), hh});
  }
  return hullOf(points);
}

/// The hull of a box's 8 corners.
HullPtr boxCornersHull(Vec3 he) {
  std::vector<Vec3> points;
  for (int i = 0; i < 8; ++i)
    points.push_back({i & 1 ? he.x : -he.x, i & 2 ? he.y : -he.y, i & 4 ? he.z : -he.z});
  return hullOf(points);
}

/// A random hull: half the time from a point cloud, else a prism of 3 to 24 sides.
HullPtr anyHull(Rng& rng) {
  if (rng.chance(0.6f)) return randomHull(rng);
  return prismHull(3 + rng.below(22), rng.uniform(0.2f, 0.8f), rng.uniform(0.1f, 0.6f));
}

/// max over the hull at `xf` of dot(dir, x), relative to xf.p.
float hullSupport(const ConvexHull& h, Quat q, Vec3 dir) {
  float best = -1e30f;
  for (const Vec3& v : h.vertices) best = std::max(best, dot(rotate(q, v), dir));
  return best;
}

/// The mean of a hull face's vertices.
Vec3 faceCentre(const ConvexHull& h, size_t f) {
  Vec3 c;
  for (uint32_t i : h.faces[f].indices) c += h.vertices[i];
  return c * (1.0f / float(h.faces[f].indices.size()));
}

// ---------------------------------------------------------------------------------------------
// The kernel on the device

class GpuNarrow : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    gpu::DeviceOptions o;
    o.allowCpu = true;
    // PHYS_GPU_VALIDATION=1 runs under the validation layer (TearDown counts its errors).
    device_ = gpu::Device::open(gpu::deviceOptionsFromEnv(o), &error_);
    if (!device_) return;
    try {
      kernel_ =
          std::make_unique<gpu::Kernel>(device_, "narrow_phase", gpu::shaderCode("narrow_phase"), 7,
                                        uint32_t(sizeof(gpu::GpuStepConstants)));
    } catch (const std::exception& e) {
      error_ = e.what();
    }
  }
  static void TearDownTestSuite() {
    kernel_.reset();
    device_.reset();
  }
  void SetUp() override {
    if (!device_) GTEST_SKIP() << "no Vulkan device: " << error_;
    ASSERT_NE(kernel_, nullptr) << error_;
  }
  void TearDown() override {
    if (device_) {
      EXPECT_EQ(device_->validationErrors(), 0);
    }
  }

 public:
  /// Runs the kernel over the scene's pairs with counters[PAIRS] = pairCount; the manifold
  /// buffer starts filled with the byte 0xA5. Hulls are packed once each (shapes sharing a
  /// hull share its record), after a few words of padding so no offset is 0; a scene without
  /// hulls binds a 16-byte hull buffer of zeros.
  static std::vector<gpu::GpuManifold> run(const Scene& scene, uint32_t pairCount) {
    std::vector<gpu::GpuBodyState> states;
    std::vector<gpu::GpuBodyParams> params;
    std::vector<gpu::GpuShape> shapes;
    std::vector<uint32_t> hullWords;
    std::map<const ConvexHull*, uint32_t> hullOffsets;
    for (const SceneShape& s : scene.shapes) {
      gpu::GpuShape g;
      g.type = static_cast<uint32_t>(s.geom.type);
      g.friction = s.friction;
      g.restitution = s.restitution;
      g.localP = {s.local.p.x, s.local.p.y, s.local.p.z, s.boundRadius};
      g.localQ = {s.local.q.x, s.local.q.y, s.local.q.z, s.local.q.w};
      switch (s.geom.type) {
        case ShapeType::Sphere:
          g.size = {s.geom.radius, 0, 0, 0};
          break;
        case ShapeType::Box:
          g.size = {s.geom.halfExtents.x, s.geom.halfExtents.y, s.geom.halfExtents.z, 0};
          break;
        case ShapeType::Capsule:
          g.size = {s.geom.radius, s.geom.halfHeight, 0, 0};
          break;
        case ShapeType::Plane: {
          Vec3 n;
          float d;
          worldPlane(s, &n, &d);
          g.size = {n.x, n.y, n.z, d};
          break;
        }
        case ShapeType::Hull: {
          uint32_t offset = gpu::kNoHull;  // no hull: no contact, as on the CPU
          if (s.geom.hull) {
            auto it = hullOffsets.find(s.geom.hull.get());
            if (it != hullOffsets.end()) {
              offset = it->second;
            } else {
              if (hullWords.empty()) hullWords.assign(5, 0xDEADBEEFu);
              std::string error;
              offset = gpu::packHull(gpu::hullInputOf(*s.geom.hull), &hullWords, &error);
              EXPECT_NE(offset, gpu::kNoHull) << error;
              hullOffsets[s.geom.hull.get()] = offset;
            }
          }
          g.size = {std::bit_cast<float>(offset), 0, 0, 0};
          break;
        }
        default:
          break;
      }
      if (s.isStatic) {
        g.body = -1;
      } else {
        g.body = static_cast<int>(states.size());
        gpu::GpuBodyState b;
        Vec3 com = s.body.p + rotate(s.body.q, s.localCenter);
        b.com = {com.x, com.y, com.z, 0};
        b.q = {s.body.q.x, s.body.q.y, s.body.q.z, s.body.q.w};
        b.v = {s.v.x, s.v.y, s.v.z, 0};
        b.w = {s.w.x, s.w.y, s.w.z, 0};
        states.push_back(b);
        gpu::GpuBodyParams p;
        p.localCenter = {s.localCenter.x, s.localCenter.y, s.localCenter.z, 0};
        params.push_back(p);
      }
      shapes.push_back(g);
    }
    std::vector<gpu::GpuPair> pairs;
    for (const auto& pr : scene.pairs) pairs.push_back({pr.first, pr.second, 0, 0});
    const size_t np = pairs.size();
    std::vector<gpu::GpuManifold> out(np);
    std::memset(static_cast<void*>(out.data()), 0xA5, np * sizeof(gpu::GpuManifold));
    uint32_t counters[PHYS_GPU_COUNTER_COUNT] = {pairCount};

    using gpu::Buffer;
    auto bytesOf = [](const auto& v) { return VkDeviceSize(v.size() * sizeof(v[0])); };
    Buffer stateBuf(device_, bytesOf(states), Buffer::Kind::Device);
    Buffer paramBuf(device_, bytesOf(params), Buffer::Kind::Device);
    Buffer shapeBuf(device_, bytesOf(shapes), Buffer::Kind::Device);
    Buffer pairBuf(device_, bytesOf(pairs), Buffer::Kind::Device);
    Buffer manifoldBuf(device_, bytesOf(out), Buffer::Kind::Device);
    Buffer counterBuf(device_, sizeof counters, Buffer::Kind::Device);
    if (hullWords.empty()) hullWords.assign(4, 0u);
    Buffer hullBuf(device_, bytesOf(hullWords), Buffer::Kind::Device);
    gpu::GpuStepConstants k;
    k.dt = kDt;
    k.h = kDt / 4;
    k.maxLinearSpeed = 100;
    k.maxAngularSpeed = 100;
    k.speculativeDistance = kSpeculative;
    k.bodyCount = static_cast<uint32_t>(states.size());
    k.shapeCount = static_cast<uint32_t>(shapes.size());
    k.pairCapacity = static_cast<uint32_t>(np);

    gpu::Stream stream(device_);
    stream.begin();
    stream.upload(stateBuf, 0, states.data(), bytesOf(states));
    stream.upload(paramBuf, 0, params.data(), bytesOf(params));
    stream.upload(shapeBuf, 0, shapes.data(), bytesOf(shapes));
    stream.upload(pairBuf, 0, pairs.data(), bytesOf(pairs));
    stream.upload(manifoldBuf, 0, out.data(), bytesOf(out));
    stream.upload(counterBuf, 0, counters, sizeof counters);
    stream.upload(hullBuf, 0, hullWords.data(), bytesOf(hullWords));
    const Buffer* bindings[] = {&stateBuf,    &paramBuf,   &shapeBuf, &pairBuf,
                                &manifoldBuf, &counterBuf, &hullBuf};
    stream.dispatch(*kernel_, bindings, &k,
                    static_cast<uint32_t>((np + PHYS_GPU_GROUP - 1) / PHYS_GPU_GROUP));
    stream.download(manifoldBuf, 0, out.data(), bytesOf(out));
    std::string error;
    EXPECT_TRUE(stream.submit(&error)) << error;
    return out;
  }

 private:
  static std::shared_ptr<gpu::Device> device_;
  static std::unique_ptr<gpu::Kernel> kernel_;
  static std::string error_;
};

std::shared_ptr<gpu::Device> GpuNarrow::device_;
std::unique_ptr<gpu::Kernel> GpuNarrow::kernel_;
std::string GpuNarrow::error_;

// ---------------------------------------------------------------------------------------------
// The comparison

/// The margin of World::Impl::narrowPhase.
float pairMargin(const SceneShape& a, const SceneShape& b) {
  float reach =
      (length(a.v) + length(a.w) * a.boundRadius + length(b.v) + length(b.w) * b.boundRadius) * kDt;
  return kSpeculative + reach;
}

std::vector<uint32_t> sortedIds(int count, const uint32_t* ids) {
  std::vector<uint32_t> v(ids, ids + count);
  std::sort(v.begin(), v.end());
  return v;
}
std::vector<uint32_t> sortedIds(const Manifold& m) {
  uint32_t ids[Manifold::kMaxPoints];
  for (int i = 0; i < m.count; ++i) ids[i] = m.points[i].featureId;
  return sortedIds(m.count, ids);
}

/// How the GPU's manifold differs from the CPU's: empty when they agree (same count, the same
/// feature ids, normals within 1e-4, each point within 2e-4 m of the CPU's point of that id,
/// separations within 2e-4 m).
std::string difference(const gpu::GpuManifold& g, const Manifold& cpu) {
  char buf[256];
  const int gcount = static_cast<int>(g.count);
  if (gcount != cpu.count || sortedIds(gcount, &g.featureIds.x) != sortedIds(cpu)) {
    std::string s = "GPU " + std::to_string(gcount) + " points, ids";
    for (int k = 0; k < gcount; ++k) s += " " + std::to_string((&g.featureIds.x)[k]);
    s += "; CPU " + std::to_string(cpu.count) + " points, ids";
    for (int k = 0; k < cpu.count; ++k) s += " " + std::to_string(cpu.points[k].featureId);
    return s;
  }
  if (cpu.count == 0) return {};
  const Vec3 gn{g.normal.x, g.normal.y, g.normal.z};
  const Vec3 dn = vabs(gn - cpu.normal);
  if (std::max(dn.x, std::max(dn.y, dn.z)) > 1e-4f) {
    std::snprintf(buf, sizeof buf, "normal GPU (%.6f %.6f %.6f) CPU (%.6f %.6f %.6f)", gn.x, gn.y,
                  gn.z, cpu.normal.x, cpu.normal.y, cpu.normal.z);
    return buf;
  }
  for (int k = 0; k < gcount; ++k) {
    const uint32_t id = (&g.featureIds.x)[k];
    const Vec3 gp{g.points[k].x, g.points[k].y, g.points[k].z};
    for (int c = 0; c < cpu.count; ++c) {
      const ContactPoint& cp = cpu.points[c];
      if (cp.featureId != id) continue;
      const Vec3 d = vabs(gp - cp.point);
      if (std::max(d.x, std::max(d.y, d.z)) > 2e-4f ||
          std::fabs(g.points[k].w - cp.separation) > 2e-4f) {
        std::snprintf(buf, sizeof buf,
                      "point %u: GPU (%.6f %.6f %.6f) sep %.6f, CPU (%.6f %.6f %.6f) sep %.6f", id,
                      gp.x, gp.y, gp.z, g.points[k].w, cp.point.x, cp.point.y, cp.point.z,
                      cp.separation);
        return buf;
      }
    }
  }
  return {};
}

/// Area of the convex hull of up to four points seen along `n` (the manifold's normal).
float spreadArea(const Vec3* p, int count, Vec3 n) {
  auto tri = [&](int a, int b, int c) {
    return std::fabs(dot(cross(p[b] - p[a], p[c] - p[a]), n)) * 0.5f;
  };
  if (count < 3) return 0;
  if (count == 3) return tri(0, 1, 2);
  // Four points: the largest of the three quadrilaterals (the convex one is the hull) and of
  // the four triangles (one point inside the triangle of the others).
  auto quad = [&](int a, int b, int c, int d) {
    return std::fabs(dot(cross(p[c] - p[a], p[d] - p[b]), n)) * 0.5f;
  };
  float best = std::max({quad(0, 1, 2, 3), quad(0, 2, 1, 3), quad(0, 1, 3, 2)});
  return std::max({best, tri(0, 1, 2), tri(0, 1, 3), tri(0, 2, 3), tri(1, 2, 3)});
}

/// A reduction to four that picked other candidates as good as the CPU's: the same count, the
/// same deepest separation, the same normal, and an area within 0.1 % of the CPU's points'
/// (two hull vertices of nearly equal merit, where a nudge of the pose moves both alike and
/// the device's rounding decides).
bool equallyGoodReduction(const gpu::GpuManifold& g, const Manifold& cpu) {
  const int n = static_cast<int>(g.count);
  if (n != cpu.count || n < 4) return false;
  const Vec3 gn{g.normal.x, g.normal.y, g.normal.z};
  const Vec3 dn = vabs(gn - cpu.normal);
  if (std::max(dn.x, std::max(dn.y, dn.z)) > 1e-4f) return false;
  Vec3 gp[4], cp[4];
  float gDeep = 1e9f, cDeep = 1e9f;
  for (int k = 0; k < n; ++k) {
    gp[k] = {g.points[k].x, g.points[k].y, g.points[k].z};
    cp[k] = cpu.points[k].point;
    gDeep = std::min(gDeep, g.points[k].w);
    cDeep = std::min(cDeep, cpu.points[k].separation);
  }
  if (std::fabs(gDeep - cDeep) > 2e-4f) return false;
  const float ga = spreadArea(gp, n, cpu.normal), ca = spreadArea(cp, n, cpu.normal);
  return std::fabs(ga - ca) <= 1e-3f * std::max(ca, 1e-6f);
}

/// What a test's pairs came to on the CPU, for the coverage checks.
struct Tally {
  int pairs = 0, touching = 0, points = 0, ambiguous = 0;
  int byCount[5] = {};
  int faceA = 0, faceB = 0, edges = 0, other = 0;  // feature-id kinds of all points
  int clipPoints = 0;                              // face-contact points made by clipping
  int otherSub[4] = {};                            // kind 3 by sub-kind
};

/// Compares every pair's GPU manifold with phys::collide; returns the CPU's tally.
Tally compareAll(const Scene& scene, const std::vector<gpu::GpuManifold>& gpuOut) {
  Tally tally;
  Rng nudge(12345);
  for (size_t i = 0; i < scene.pairs.size(); ++i) {
    const SceneShape& sa = scene.shapes[scene.pairs[i].first];
    const SceneShape& sb = scene.shapes[scene.pairs[i].second];
    const Transform xa = sa.world(), xb = sb.world();
    const float margin = pairMargin(sa, sb);
    Manifold cpu;
    collide(sa.geom, xa, sb.geom, xb, margin, &cpu);
    const gpu::GpuManifold& g = gpuOut[i];
    SCOPED_TRACE("pair " + std::to_string(i) + ": " + toString(sa.geom.type) + " - " +
                 toString(sb.geom.type) + ", margin " + std::to_string(margin));

    ++tally.pairs;
    tally.byCount[cpu.count]++;
    if (cpu.count > 0) ++tally.touching;
    tally.points += cpu.count;
    for (int k = 0; k < cpu.count; ++k) {
      uint32_t id = cpu.points[k].featureId;
      switch (id >> 30) {
        case 0:
          ++tally.faceA;
          break;
        case 1:
          ++tally.faceB;
          break;
        case 2:
          ++tally.edges;
          break;
        default:
          ++tally.other;
          ++tally.otherSub[id >> 28 & 3u];
      }
      if (id >> 30 <= 1 && (id >> 12 & 3u) != 0) ++tally.clipPoints;
    }

    // The pair's record.
    EXPECT_EQ(g.shapeA, scene.pairs[i].first);
    EXPECT_EQ(g.shapeB, scene.pairs[i].second);
    EXPECT_NEAR(g.normal.w, std::sqrt(sa.friction * sb.friction), 1e-6f);
    EXPECT_EQ(g.restitution, std::max(sa.restitution, sb.restitution));
    for (int k = 0; k < 4; ++k) {
      EXPECT_EQ((&g.normalImpulse.x)[k], 0.0f);
      EXPECT_EQ((&g.tangentImpulse1.x)[k], 0.0f);
      EXPECT_EQ((&g.tangentImpulse2.x)[k], 0.0f);
    }
    EXPECT_LE(g.count, 4u);
    if (g.count > 4) continue;

    const std::string nominal = difference(g, cpu);
    if (nominal.empty()) continue;
    // A near-tie? The CPU nudged by 2e-5 (m, rad, margin) must then give the GPU's answer.
    bool matched = false;
    for (int t = 0; t < 32 && !matched; ++t) {
      const float eps = 2e-5f;
      Transform nb = xb;
      nb.p += nudge.direction() * eps;
      nb.q = normalize(axisAngle(nudge.direction(), eps) * nb.q);
      Transform na = xa;
      if (t & 1) na.q = normalize(axisAngle(nudge.direction(), eps) * na.q);
      float nm = margin + ((t & 2) ? eps : -eps);
      Manifold alt;
      collide(sa.geom, na, sb.geom, nb, nm, &alt);
      matched = difference(g, alt).empty();
    }
    if (!matched) matched = equallyGoodReduction(g, cpu);
    if (matched) {
      ++tally.ambiguous;
      std::printf("[ near-tie ] pair %zu (%s - %s): %s\n", i, toString(sa.geom.type),
                  toString(sb.geom.type), nominal.c_str());
      continue;
    }
    ADD_FAILURE() << nominal;
  }
  std::printf(
      "[ tally    ] %d pairs, %d touching, %d points (manifolds of 1..4: %d %d %d %d), ids: "
      "faceA %d faceB %d edges %d other %d (clipped %d; other by sub-kind %d %d %d %d), "
      "near-ties %d\n",
      tally.pairs, tally.touching, tally.points, tally.byCount[1], tally.byCount[2],
      tally.byCount[3], tally.byCount[4], tally.faceA, tally.faceB, tally.edges, tally.other,
      tally.clipPoints, tally.otherSub[0], tally.otherSub[1], tally.otherSub[2], tally.otherSub[3],
      tally.ambiguous);
  // Near-ties are rare on random input: more means a systematic difference.
  EXPECT_LE(tally.ambiguous * 50, tally.pairs);
  return tally;
}

Tally runAndCompare(const Scene& scene) {
  std::vector<gpu::GpuManifold> out =
      GpuNarrow::run(scene, static_cast<uint32_t>(scene.pairs.size()));
  if (out.size() != scene.pairs.size()) return {};
  return compareAll(scene, out);
}

/// The rotation taking unit vector `from` to unit vector `to` (not opposite).
Quat fromTo(Vec3 from, Vec3 to) {
  Vec3 c = cross(from, to);
  return normalize(Quat{c.x, c.y, c.z, 1.0f + dot(from, to)});
}

/// A unit vector perpendicular to unit vector n.
Vec3 perpendicular(Rng& rng, Vec3 n) {
  for (;;) {
    Vec3 v = rng.direction();
    v -= n * dot(v, n);
    if (lengthSquared(v) > 0.01f) return normalize(v);
  }
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// Spheres

TEST_F(GpuNarrow, SphereSphere) {
  Rng rng(1);
  Scene scene;
  for (int i = 0; i < 300; ++i) {
    float ra = rng.uniform(0.05f, 0.8f), rb = rng.uniform(0.05f, 0.8f);
    Vec3 pa = rng.box(5.0f);
    float dist = std::max(0.0f, ra + rb + rng.uniform(-0.3f, 0.1f));
    if (i % 30 == 0) pa = rng.box(0.2f), dist = 0;  // coincident centres: the fallback normal
    Vec3 pb = pa + rng.direction() * dist;
    scene.pairOf(rng, place(rng, ShapeGeom::sphere(ra), {pa, rng.rotation()}),
                 place(rng, ShapeGeom::sphere(rb), {pb, rng.rotation()}));
  }
  Tally t = runAndCompare(scene);
  EXPECT_GT(t.touching, 150);
}

TEST_F(GpuNarrow, SphereBox) {
  Rng rng(2);
  Scene scene;
  for (int i = 0; i < 400; ++i) {
    Vec3 he = randomHalfExtents(rng);
    Transform box{rng.box(4.0f), rng.rotation()};
    float r = rng.uniform(0.05f, 0.6f);
    // Around the box: face, edge and corner regions, and inside.
    Vec3 local = rng.box(he + Vec3{r, r, r} + Vec3{0.1f, 0.1f, 0.1f});
    if (i % 40 == 0) local = {};
    scene.pairOf(rng, place(rng, ShapeGeom::box(he), box),
                 place(rng, ShapeGeom::sphere(r), {apply(box, local), rng.rotation()}));
  }
  Tally t = runAndCompare(scene);
  EXPECT_GT(t.touching, 150);
}

TEST_F(GpuNarrow, SphereCapsule) {
  Rng rng(3);
  Scene scene;
  for (int i = 0; i < 300; ++i) {
    float rc = rng.uniform(0.05f, 0.5f), hh = rng.uniform(0.05f, 1.0f);
    float rs = rng.uniform(0.05f, 0.6f);
    Transform cap{rng.box(4.0f), rng.rotation()};
    Vec3 radial = perpendicular(rng, {0, 0, 1});
    float along = rng.uniform(-hh - 0.5f, hh + 0.5f);
    float off = std::max(0.0f, rc + rs + rng.uniform(-0.35f, 0.1f));
    if (i % 30 == 0) cap.p = rng.box(0.2f), off = 0;  // centre on the core: the fallback normal
    Vec3 local = Vec3{0, 0, along} + radial * off;
    scene.pairOf(rng, place(rng, ShapeGeom::capsule(rc, hh), cap),
                 place(rng, ShapeGeom::sphere(rs), {apply(cap, local), rng.rotation()}));
  }
  Tally t = runAndCompare(scene);
  EXPECT_GT(t.touching, 150);
}

TEST_F(GpuNarrow, SpherePlane) {
  Rng rng(4);
  Scene scene;
  for (int i = 0; i < 200; ++i) {
    Vec3 n = rng.direction();
    float d = rng.uniform(-2, 2);
    float r = rng.uniform(0.05f, 0.8f);
    Vec3 c = n * (d + r + rng.uniform(-0.3f, 0.08f)) + perpendicular(rng, n) * rng.uniform(0, 4);
    scene.pairOf(rng, planeShape(rng, n, d), place(rng, ShapeGeom::sphere(r), {c, rng.rotation()}));
  }
  Tally t = runAndCompare(scene);
  EXPECT_GT(t.touching, 100);
}

// ---------------------------------------------------------------------------------------------
// Box against box

TEST_F(GpuNarrow, BoxBoxRandom) {
  Rng rng(5);
  Scene scene;
  for (int i = 0; i < 400; ++i) {
    Vec3 ha = randomHalfExtents(rng), hb = randomHalfExtents(rng);
    Transform a{rng.box(3.0f), rng.rotation()};
    Quat qb = rng.rotation();
    Vec3 dir = rng.direction();
    float reach = boxSupport(ha, a.q, dir) + boxSupport(hb, qb, -dir);
    Vec3 pb = a.p + dir * (reach * rng.uniform(0.6f, 1.0f) + rng.uniform(-0.05f, 0.05f));
    scene.pairOf(rng, place(rng, ShapeGeom::box(ha), a), place(rng, ShapeGeom::box(hb), {pb, qb}));
  }
  Tally t = runAndCompare(scene);
  EXPECT_GT(t.touching, 200);
  EXPECT_GT(t.edges, 10);
  EXPECT_GT(t.faceB, 20);
}

TEST_F(GpuNarrow, BoxBoxRestingAndTilted) {
  Rng rng(6);
  Scene scene;
  const Vec3 up{0, 0, 1};
  for (int i = 0; i < 400; ++i) {
    Vec3 ha = randomHalfExtents(rng, 0.2f, 1.0f), hb = randomHalfExtents(rng, 0.1f, 0.8f);
    Quat frame = i % 5 == 0 ? Quat{} : rng.rotation();
    Vec3 pa = rng.box(3.0f);
    float yaw = i % 3 == 0 ? 0.0f : rng.uniform(0, kPi2);
    // Half flat on the face, half tipped onto an edge or a corner.
    float tilt = i % 2 ? rng.uniform(1.0f, 30.0f) * kDeg : 0.0f;
    Quat rel = axisAngle(perpendicular(rng, up), tilt) * axisAngle(up, yaw);
    float lift = ha.z + boxSupport(hb, rel, -up) + rng.uniform(-0.02f, 0.005f);
    Vec3 off{rng.uniform(-ha.x, ha.x), rng.uniform(-ha.y, ha.y), lift};
    scene.pairOf(rng, place(rng, ShapeGeom::box(ha), {pa, frame}),
                 place(rng, ShapeGeom::box(hb), {pa + rotate(frame, off), frame * rel}));
  }
  Tally t = runAndCompare(scene);
  EXPECT_GT(t.byCount[4], 80);
  EXPECT_GT(t.clipPoints, 100);
}

TEST_F(GpuNarrow, BoxBoxEdgeEdge) {
  Rng rng(7);
  Scene scene;
  const Vec3 up{0, 0, 1}, x{1, 0, 0};
  for (int i = 0; i < 300; ++i) {
    Vec3 ha = randomHalfExtents(rng, 0.3f, 1.0f), hb = randomHalfExtents(rng, 0.3f, 1.0f);
    Quat frame = rng.rotation();
    Vec3 pa = rng.box(3.0f);
    // A with an edge along x on top, B with an edge at an angle to it underneath.
    Quat qa = axisAngle(x, (45.0f + rng.uniform(-10, 10)) * kDeg);
    Quat qb = axisAngle(up, rng.uniform(20, 160) * kDeg) *
              axisAngle(x, (45.0f + rng.uniform(-10, 10)) * kDeg);
    float lift = boxSupport(ha, qa, up) + boxSupport(hb, qb, -up) + rng.uniform(-0.04f, 0.01f);
    Vec3 off{rng.uniform(-0.1f, 0.1f), rng.uniform(-0.1f, 0.1f), lift};
    scene.pairOf(rng, place(rng, ShapeGeom::box(ha), {pa, frame * qa}),
                 place(rng, ShapeGeom::box(hb), {pa + rotate(frame, off), frame * qb}));
  }
  Tally t = runAndCompare(scene);
  EXPECT_GT(t.edges, 150);
}

TEST_F(GpuNarrow, BoxBoxDeepPenetration) {
  Rng rng(8);
  Scene scene;
  for (int i = 0; i < 300; ++i) {
    Vec3 ha = randomHalfExtents(rng, 0.2f, 1.0f), hb = randomHalfExtents(rng, 0.1f, 1.0f);
    Transform a{rng.box(3.0f), rng.rotation()};
    Vec3 pb = apply(a, rng.box(ha * 0.6f));
    scene.pairOf(rng, place(rng, ShapeGeom::box(ha), a),
                 place(rng, ShapeGeom::box(hb), {pb, rng.rotation()}));
  }
  Tally t = runAndCompare(scene);
  EXPECT_EQ(t.touching, t.pairs);
  EXPECT_GT(t.byCount[4], 50);
}

TEST_F(GpuNarrow, BoxBoxFlushOnAnEqualBox) {
  // Equal boxes stacked face to face: incident corners exactly on the reference face's side
  // planes, kept by the clip slop, so the ids are the corners' (type 0), not clip points.
  Rng rng(9);
  Scene scene;
  const float gaps[] = {0.0f, 1e-4f, -1e-4f, -5e-4f, 5e-4f, -2e-3f, 0.005f};
  for (int i = 0; i < 280; ++i) {
    Vec3 he = randomHalfExtents(rng, 0.2f, 1.0f);
    bool cube = i % 4 == 0;
    if (cube) he = {he.x, he.x, he.x};
    Quat frame = i % 5 == 0 ? Quat{} : rng.rotation();
    Vec3 pa = rng.box(3.0f);
    float gap = gaps[i % 7];
    Vec3 off{0, 0, 2 * he.z + gap};
    if (i % 3 == 1) off.x = rng.uniform(-0.5f, 0.5f) * he.x;
    if (i % 3 == 2)
      off.x = rng.uniform(-0.3f, 0.3f) * he.x, off.y = rng.uniform(-0.3f, 0.3f) * he.y;
    Quat qb = frame;
    if (cube && i % 8 == 0) qb = frame * axisAngle({0, 0, 1}, 0.5f * kPi);
    scene.pairOf(rng, place(rng, ShapeGeom::box(he), {pa, frame}),
                 place(rng, ShapeGeom::box(he), {pa + rotate(frame, off), qb}));
  }
  Tally t = runAndCompare(scene);
  EXPECT_GT(t.byCount[4], 200);
  EXPECT_EQ(t.edges, 0);
}

TEST_F(GpuNarrow, BoxPyramids) {
  // Pyramids as a solver leaves them: rows offset by half a box, settled a fraction of a
  // millimetre into each other, jittered; on a static ground box or on a plane.
  Rng rng(10);
  Scene scene;
  for (int variant = 0; variant < 4; ++variant) {
    Vec3 he = variant % 2 ? Vec3{0.5f, 0.5f, 0.5f} : Vec3{0.4f, 0.3f, 0.25f};
    Transform frame{rng.box(5.0f), variant < 2 ? Quat{} : axisAngle({0, 0, 1}, rng.uniform(0, 6))};
    const Vec3 up = rotate(frame.q, {0, 0, 1});
    uint32_t ground;
    if (variant % 2 == 0) {
      ground = scene.add(place(rng, ShapeGeom::box({20, 20, 0.5f}),
                               {apply(frame, {0, 0, -0.5f}), frame.q}, Motion::Static));
    } else {
      ground = scene.add(planeShape(rng, up, dot(up, frame.p)));
    }
    const int rows = 7;
    const float pitch = 2 * he.x + 0.015f;
    std::vector<uint32_t> ids;
    std::vector<Vec3> centres;
    for (int r = 0; r < rows; ++r) {
      for (int i = 0; i < rows - r; ++i) {
        Vec3 c{(float(i) + 0.5f * float(r)) * pitch, 0, he.z + float(r) * 2 * he.z};
        c.z -= 0.0005f * float(r + 1);
        c += rng.box(2e-4f);
        Quat q = axisAngle(rng.direction(), rng.uniform(0, 1e-3f));
        SceneShape s =
            place(rng, ShapeGeom::box(he), {apply(frame, c), frame.q * q}, Motion::Dynamic);
        uint32_t id = scene.add(s);
        if (r == 0) scene.pair(ground, id);
        for (size_t k = 0; k < ids.size(); ++k) {
          Vec3 d = c - centres[k];
          if (std::fabs(d.x) < 1.5f * pitch && std::fabs(d.z) < 3 * he.z) scene.pair(ids[k], id);
        }
        ids.push_back(id);
        centres.push_back(c);
      }
    }
  }
  Tally t = runAndCompare(scene);
  EXPECT_GT(t.byCount[4], 70);
  EXPECT_GT(t.clipPoints, 50);
}

// ---------------------------------------------------------------------------------------------
// Boxes against capsules and planes

TEST_F(GpuNarrow, BoxCapsule) {
  Rng rng(11);
  Scene scene;
  const Vec3 z{0, 0, 1};
  for (int i = 0; i < 500; ++i) {
    Vec3 he = randomHalfExtents(rng, 0.15f, 1.0f);
    Transform box{rng.box(3.0f), rng.rotation()};
    float r = rng.uniform(0.05f, 0.4f), hh = rng.uniform(0.1f, 0.8f);
    Vec3 local;
    Quat qLocal;
    switch (i % 4) {
      case 0:
      case 1:  // anywhere around the box
        local = rng.box(he + Vec3{r + 0.5f * hh, r + 0.5f * hh, r + 0.5f * hh});
        qLocal = rng.rotation();
        break;
      case 2: {  // lying on a face, level or tipped by up to 1.5 degrees, overhanging or not
        int f = rng.below(6), axis = f / 2;
        Vec3 n;
        n[axis] = f % 2 ? -1.0f : 1.0f;
        Vec3 dir = perpendicular(rng, n);
        dir = rotate(axisAngle(cross(n, dir), rng.uniform(0, 1.5f) * kDeg), dir);
        if (dot(dir, z) < -0.9f) dir = -dir;
        qLocal = fromTo(z, dir) * axisAngle(z, rng.uniform(0, kPi2));
        Vec3 across = rng.box(he);
        across[axis] = 0;
        local = across + n * (he[axis] + r + rng.uniform(-0.05f, 0.01f));
        break;
      }
      default:  // the core through the box
        local = rng.box(he * 0.5f);
        qLocal = rng.rotation();
    }
    scene.pairOf(rng, place(rng, ShapeGeom::box(he), box),
                 place(rng, ShapeGeom::capsule(r, hh), {apply(box, local), box.q * qLocal}));
  }
  Tally t = runAndCompare(scene);
  EXPECT_GT(t.touching, 250);
  EXPECT_GT(t.byCount[2], 50);
}

TEST_F(GpuNarrow, BoxPlane) {
  Rng rng(12);
  Scene scene;
  const Vec3 z{0, 0, 1};
  for (int i = 0; i < 400; ++i) {
    Vec3 n = rng.direction();
    float d = rng.uniform(-2, 2);
    Vec3 he = randomHalfExtents(rng);
    Quat q = rng.rotation();
    float gap = rng.uniform(-0.2f, 0.05f);
    if (i % 3 == 1) {  // resting flat, tipped by up to 2 degrees
      q = axisAngle(perpendicular(rng, n), rng.uniform(0, 2) * kDeg) * fromTo(z, n) *
          axisAngle(z, rng.uniform(0, kPi2));
      gap = rng.uniform(-0.01f, 0.005f);
    } else if (i % 3 == 2) {  // deep: more than four corners below
      gap = -rng.uniform(0.5f, 1.5f) * std::min(he.x, std::min(he.y, he.z));
    }
    Vec3 c = n * (d + boxSupport(he, q, -n) + gap) + perpendicular(rng, n) * rng.uniform(0, 4);
    scene.pairOf(rng, planeShape(rng, n, d), place(rng, ShapeGeom::box(he), {c, q}));
  }
  Tally t = runAndCompare(scene);
  EXPECT_GT(t.byCount[4], 100);
}

// ---------------------------------------------------------------------------------------------
// Capsules

TEST_F(GpuNarrow, CapsuleCapsule) {
  Rng rng(13);
  Scene scene;
  const Vec3 z{0, 0, 1};
  for (int i = 0; i < 400; ++i) {
    float ra = rng.uniform(0.05f, 0.5f), rb = rng.uniform(0.05f, 0.5f);
    float ha = rng.uniform(0.05f, 1.0f), hb = rng.uniform(0.05f, 1.0f);
    Transform a{rng.box(3.0f), rng.rotation()};
    Vec3 axis = rotate(a.q, z);
    Vec3 pb;
    Quat qb;
    switch (i % 4) {
      case 0:  // crossing at any angle
        pb = a.p + rng.direction() * rng.uniform(0, ra + rb + ha);
        qb = rng.rotation();
        break;
      case 1:    // nearly parallel: within and beyond the 3 degrees of the two-point contact
      case 2: {  // exactly parallel, either way round
        Vec3 side = perpendicular(rng, axis);
        qb = i % 4 == 1 ? axisAngle(perpendicular(rng, axis), rng.uniform(0, 5) * kDeg) * a.q
                        : (rng.chance(0.5f) ? a.q : a.q * axisAngle({1, 0, 0}, kPi));
        pb = a.p + side * std::max(0.0f, ra + rb + rng.uniform(-0.15f, 0.05f)) +
             axis * rng.uniform(-(ha + hb), ha + hb);
        break;
      }
      default:  // on one line (near the origin, so the rounding stays far below 1e-6)
        a.p = rng.box(0.2f);
        qb = a.q;
        pb = a.p + axis * rng.uniform(-1.2f * (ha + hb), 1.2f * (ha + hb));
    }
    scene.pairOf(rng, place(rng, ShapeGeom::capsule(ra, ha), a),
                 place(rng, ShapeGeom::capsule(rb, hb), {pb, qb}));
  }
  Tally t = runAndCompare(scene);
  EXPECT_GT(t.touching, 200);
  EXPECT_GT(t.byCount[2], 60);
}

TEST_F(GpuNarrow, CapsulePlane) {
  Rng rng(14);
  Scene scene;
  const Vec3 z{0, 0, 1};
  for (int i = 0; i < 300; ++i) {
    Vec3 n = rng.direction();
    float d = rng.uniform(-2, 2);
    float r = rng.uniform(0.05f, 0.5f), hh = rng.uniform(0.05f, 1.0f);
    Quat q = rng.rotation();
    if (i % 3 == 1) {  // lying flat, tipped by up to 3 degrees
      Vec3 dir = perpendicular(rng, n);
      dir = rotate(axisAngle(cross(n, dir), rng.uniform(-3, 3) * kDeg), dir);
      if (dot(dir, z) < -0.9f) dir = -dir;
      q = fromTo(z, dir);
    }
    float low = hh * std::fabs(dot(rotate(q, z), n)) + r;
    Vec3 c = n * (d + low + rng.uniform(-0.15f, 0.05f)) + perpendicular(rng, n) * rng.uniform(0, 4);
    scene.pairOf(rng, planeShape(rng, n, d), place(rng, ShapeGeom::capsule(r, hh), {c, q}));
  }
  Tally t = runAndCompare(scene);
  EXPECT_GT(t.byCount[2], 60);
  EXPECT_GT(t.byCount[1], 60);
}

// ---------------------------------------------------------------------------------------------
// Convex hulls

namespace {

/// The rotation taking unit vector `from` to unit vector `to`, opposite ones included.
Quat rotationTo(Vec3 from, Vec3 to) {
  if (dot(from, to) > -0.9999f) return fromTo(from, to);
  Vec3 axis = std::fabs(from.x) < 0.9f ? cross(from, Vec3{1, 0, 0}) : cross(from, Vec3{0, 1, 0});
  return axisAngle(normalize(axis), kPi);
}

/// The world transform putting face fb of hull b against face fa of hull a (at xa): b's face
/// normal opposite a's, turned by `yaw` about it, then tipped by `tilt`; b's face centre
/// `lateral` off a's face centre, b's lowest point along a's normal `gap` above a's face.
Transform restOnFace(const ConvexHull& a, const Transform& xa, size_t fa, const ConvexHull& b,
                     size_t fb, float yaw, Quat tilt, Vec3 lateral, float gap) {
  const Vec3 nA = rotate(xa.q, a.faces[fa].normal);
  const Vec3 cA = apply(xa, faceCentre(a, fa));
  const Quat qb = normalize(tilt * axisAngle(nA, yaw) * rotationTo(b.faces[fb].normal, -nA));
  Vec3 pb = cA + lateral - rotate(qb, faceCentre(b, fb));
  const float lowest = dot(pb, nA) - hullSupport(b, qb, -nA);
  pb += nA * (dot(cA, nA) + gap - lowest);
  return {pb, qb};
}

/// A random in-plane offset (perpendicular to n) of up to `reach`.
Vec3 lateralOffset(Rng& rng, Vec3 n, float reach) {
  return perpendicular(rng, n) * rng.uniform(0, reach);
}

/// Half the hull's extent across its face f (the farthest vertex from the face's centre).
float faceRadius(const ConvexHull& h, size_t f) {
  Vec3 c = faceCentre(h, f);
  float r = 0;
  for (uint32_t i : h.faces[f].indices) r = std::max(r, length(h.vertices[i] - c));
  return r;
}

/// Random hull-hull (or box-hull) pairs: touching, apart or overlapping along a random
/// direction, or face resting on face (flush or tipped by up to 20 degrees).
void addPolyPairs(Rng& rng, Scene& scene, int count, bool boxA) {
  for (int i = 0; i < count; ++i) {
    Vec3 he = randomHalfExtents(rng, 0.15f, 0.8f);
    HullPtr ha = boxA ? boxCornersHull(he) : anyHull(rng);
    HullPtr hb = anyHull(rng);
    ShapeGeom ga = boxA ? ShapeGeom::box(he) : ShapeGeom::convexHull(ha);
    Transform a{rng.box(3.0f), rng.rotation()};
    Transform b;
    if (i % 2 == 0) {
      b.q = rng.rotation();
      Vec3 dir = rng.direction();
      float reach = hullSupport(*ha, a.q, dir) + hullSupport(*hb, b.q, -dir);
      b.p = a.p + dir * (reach * rng.uniform(0.6f, 1.0f) + rng.uniform(-0.05f, 0.05f));
    } else {
      // Either one on the other: the first placed is the one underneath.
      bool bOnA = rng.chance(0.5f);
      const ConvexHull& low = bOnA ? *ha : *hb;
      const ConvexHull& high = bOnA ? *hb : *ha;
      size_t fl = size_t(rng.below(int(low.faces.size())));
      size_t fh = size_t(rng.below(int(high.faces.size())));
      Vec3 nl = rotate(a.q, low.faces[fl].normal);
      Quat tilt =
          i % 4 == 1 ? Quat{} : axisAngle(perpendicular(rng, nl), rng.uniform(0.5f, 20.0f) * kDeg);
      Vec3 lateral = lateralOffset(rng, nl, 0.5f * faceRadius(low, fl));
      float gap = rng.uniform(-0.03f, 0.008f);
      b = restOnFace(low, a, fl, high, fh, rng.uniform(0, kPi2), tilt, lateral, gap);
      if (!bOnA) std::swap(a, b);
    }
    scene.pairOf(rng, place(rng, ga, a), place(rng, ShapeGeom::convexHull(hb), b));
  }
}

/// The lowest face of a hull at orientation q along -n (the face to rest on a plane of normal n).
size_t lowestFace(const ConvexHull& h, Quat q, Vec3 n) {
  size_t best = 0;
  float bestDot = 2;
  for (size_t f = 0; f < h.faces.size(); ++f) {
    float d = dot(rotate(q, h.faces[f].normal), n);
    if (d < bestDot) bestDot = d, best = f;
  }
  return best;
}

}  // namespace

TEST(GpuNarrowHullPack, Layout) {
  HullPtr h = prismHull(5, 0.5f, 0.25f);
  ASSERT_NE(h, nullptr);
  std::vector<uint32_t> data(3, 7u);
  std::string error;
  const uint32_t at = gpu::packHull(gpu::hullInputOf(*h), &data, &error);
  ASSERT_EQ(at, 3u) << error;
  const uint32_t nv = uint32_t(h->vertices.size()), nf = uint32_t(h->faces.size()),
                 ne = uint32_t(h->edges.size());
  EXPECT_EQ(data[at + 0], nv);
  EXPECT_EQ(data[at + 1], nf);
  EXPECT_EQ(data[at + 2], ne);
  EXPECT_EQ(data[at + 3], uint32_t(data.size()) - at);
  EXPECT_EQ(std::bit_cast<float>(data[at + 4]), h->centroid.x);
  EXPECT_EQ(data[at + 7], 5u);
  for (uint32_t i = 0; i < nv; ++i)
    for (int k = 0; k < 3; ++k)
      EXPECT_EQ(std::bit_cast<float>(data[at + data[at + 8] + 3 * i + k]), h->vertices[i][k]);
  for (uint32_t f = 0; f < nf; ++f) {
    EXPECT_EQ(std::bit_cast<float>(data[at + data[at + 9] + 4 * f + 3]), h->faces[f].offset);
    const uint32_t table = at + data[at + 10];
    const uint32_t begin = data[table + f], end = data[table + f + 1];
    ASSERT_EQ(end - begin, h->faces[f].indices.size());
    for (uint32_t k = 0; k < end - begin; ++k)
      EXPECT_EQ(data[at + begin + k], h->faces[f].indices[k]);
  }
  // Edge faces derived by the packer equal buildConvexHull's.
  gpu::HullInput noAdjacency = gpu::hullInputOf(*h);
  noAdjacency.edgeFaces.clear();
  std::vector<uint32_t> derived;
  ASSERT_EQ(gpu::packHull(noAdjacency, &derived, &error), 0u) << error;
  for (uint32_t e = 0; e < ne; ++e) {
    const uint32_t* rec = &data[at + data[at + 11] + 4 * e];
    EXPECT_EQ(rec[0], h->edges[e].first);
    EXPECT_EQ(rec[1], h->edges[e].second);
    EXPECT_EQ(rec[2], h->edgeFaces[e].first);
    EXPECT_EQ(rec[3], h->edgeFaces[e].second);
    const uint32_t* d = &derived[derived[11] + 4 * e];
    EXPECT_EQ(d[2], h->edgeFaces[e].first);
    EXPECT_EQ(d[3], h->edgeFaces[e].second);
  }
  // Unusable hulls are refused and leave the data alone.
  const size_t size = data.size();
  gpu::HullInput bad = gpu::hullInputOf(*h);
  bad.faces[0].indices.push_back(uint32_t(nv));
  EXPECT_EQ(gpu::packHull(bad, &data, &error), gpu::kNoHull);
  EXPECT_FALSE(error.empty());
  gpu::HullInput big = gpu::hullInputOf(*prismHull(int(gpu::kHullMaxFaceVertices) + 1, 1, 1));
  EXPECT_EQ(gpu::packHull(big, &data, &error), gpu::kNoHull);
  std::vector<uint32_t> largest;
  EXPECT_EQ(gpu::packHull(gpu::hullInputOf(*prismHull(int(gpu::kHullMaxFaceVertices), 1, 1)),
                          &largest, &error),
            0u)
      << error;
  EXPECT_EQ(data.size(), size);
}

TEST_F(GpuNarrow, HullHull) {
  Rng rng(17);
  Scene scene;
  addPolyPairs(rng, scene, 400, false);
  Tally t = runAndCompare(scene);
  EXPECT_GT(t.touching, 250);
  EXPECT_GT(t.byCount[4], 60);
  EXPECT_GT(t.edges, 20);
  EXPECT_GT(t.faceA, 100);
  EXPECT_GT(t.faceB, 100);
  EXPECT_GT(t.clipPoints, 100);
}

TEST_F(GpuNarrow, BoxHull) {
  Rng rng(18);
  Scene scene;
  addPolyPairs(rng, scene, 400, true);
  Tally t = runAndCompare(scene);
  EXPECT_GT(t.touching, 250);
  EXPECT_GT(t.byCount[4], 60);
  EXPECT_GT(t.edges, 20);
  EXPECT_GT(t.faceA, 100);
  EXPECT_GT(t.faceB, 100);
}

TEST_F(GpuNarrow, HullSphere) {
  Rng rng(19);
  Scene scene;
  for (int i = 0; i < 400; ++i) {
    HullPtr h = anyHull(rng);
    Vec3 lo = h->vertices[0], hi = h->vertices[0];
    for (const Vec3& v : h->vertices) lo = vmin(lo, v), hi = vmax(hi, v);
    Transform xf{rng.box(4.0f), rng.rotation()};
    float r = rng.uniform(0.05f, 0.6f);
    // Around the hull: face, edge and vertex regions, and inside.
    Vec3 half = (hi - lo) * 0.5f + Vec3{r + 0.1f, r + 0.1f, r + 0.1f};
    Vec3 local = (lo + hi) * 0.5f + rng.box(half);
    // Inside, near the centroid (not on it: a regular prism's faces would tie there).
    if (i % 40 == 0) local = h->centroid + rng.box(0.05f);
    scene.pairOf(rng, place(rng, ShapeGeom::convexHull(h), xf),
                 place(rng, ShapeGeom::sphere(r), {apply(xf, local), rng.rotation()}));
  }
  Tally t = runAndCompare(scene);
  EXPECT_GT(t.touching, 150);
}

TEST_F(GpuNarrow, HullCapsule) {
  Rng rng(20);
  Scene scene;
  const Vec3 z{0, 0, 1};
  for (int i = 0; i < 500; ++i) {
    HullPtr h = anyHull(rng);
    Vec3 lo = h->vertices[0], hi = h->vertices[0];
    for (const Vec3& v : h->vertices) lo = vmin(lo, v), hi = vmax(hi, v);
    Transform xf{rng.box(3.0f), rng.rotation()};
    float r = rng.uniform(0.05f, 0.4f), hh = rng.uniform(0.1f, 0.8f);
    Vec3 local;
    Quat qLocal;
    switch (i % 4) {
      case 0:
      case 1: {  // anywhere around the hull
        float m = r + 0.5f * hh;
        local = (lo + hi) * 0.5f + rng.box((hi - lo) * 0.5f + Vec3{m, m, m});
        qLocal = rng.rotation();
        break;
      }
      case 2: {  // lying on a face, level or tipped by up to 1.5 degrees
        size_t f = size_t(rng.below(int(h->faces.size())));
        Vec3 n = h->faces[f].normal;
        Vec3 dir = perpendicular(rng, n);
        dir = rotate(axisAngle(cross(n, dir), rng.uniform(0, 1.5f) * kDeg), dir);
        qLocal = rotationTo(z, dir) * axisAngle(z, rng.uniform(0, kPi2));
        local = faceCentre(*h, f) + lateralOffset(rng, n, 0.5f * faceRadius(*h, f)) +
                n * (r + rng.uniform(-0.05f, 0.01f));
        break;
      }
      default:  // the core through the hull
        local = h->centroid + rng.box((hi - lo) * 0.2f);
        qLocal = rng.rotation();
    }
    scene.pairOf(rng, place(rng, ShapeGeom::convexHull(h), xf),
                 place(rng, ShapeGeom::capsule(r, hh), {apply(xf, local), xf.q * qLocal}));
  }
  Tally t = runAndCompare(scene);
  EXPECT_GT(t.touching, 250);
  EXPECT_GT(t.byCount[2], 40);
  EXPECT_GT(t.otherSub[3], 5);
}

TEST_F(GpuNarrow, HullPlane) {
  Rng rng(21);
  Scene scene;
  for (int i = 0; i < 400; ++i) {
    Vec3 n = rng.direction();
    float d = rng.uniform(-2, 2);
    HullPtr h = anyHull(rng);
    Quat q = rng.rotation();
    float gap = rng.uniform(-0.2f, 0.05f);
    if (i % 3 == 1) {  // resting on a face, tipped by up to 2 degrees
      size_t f = lowestFace(*h, q, n);
      q = normalize(axisAngle(perpendicular(rng, n), rng.uniform(0, 2) * kDeg) *
                    rotationTo(rotate(q, h->faces[f].normal), -n) * q);
      gap = rng.uniform(-0.01f, 0.005f);
    } else if (i % 3 == 2) {  // deep: many vertices below
      gap = -rng.uniform(0.3f, 0.8f) * (hullSupport(*h, q, n) + hullSupport(*h, q, -n));
    }
    Vec3 c = n * (d + hullSupport(*h, q, -n) + gap) + perpendicular(rng, n) * rng.uniform(0, 4);
    scene.pairOf(rng, planeShape(rng, n, d), place(rng, ShapeGeom::convexHull(h), {c, q}));
  }
  Tally t = runAndCompare(scene);
  EXPECT_GT(t.byCount[4], 100);
  EXPECT_GT(t.byCount[1], 20);
}

TEST_F(GpuNarrow, HullThatIsABox) {
  // A box's corner hull against every kind, flush and tipped; its ids follow the CPU's hull
  // path (not the box path's).
  Rng rng(22);
  Scene scene;
  for (int i = 0; i < 400; ++i) {
    Vec3 he = randomHalfExtents(rng, 0.2f, 0.8f);
    HullPtr h = boxCornersHull(he);
    Transform a{rng.box(3.0f), rng.rotation()};
    const Vec3 up = rotate(a.q, {0, 0, 1});
    Quat tilt = i % 3 == 0 ? Quat{} : axisAngle(perpendicular(rng, up), rng.uniform(0, 10) * kDeg);
    Quat rel = tilt * axisAngle(up, i % 2 ? 0.0f : rng.uniform(0, kPi2));
    SceneShape hull = place(rng, ShapeGeom::convexHull(h), a);
    switch (i % 5) {
      case 0: {  // an equal box or corner hull on top
        Vec3 hb = i % 10 == 0 ? he : randomHalfExtents(rng, 0.2f, 0.8f);
        Quat qb = rel * a.q;
        float lift = he.z + boxSupport(hb, qb, -up) + rng.uniform(-0.02f, 0.003f);
        Vec3 pb = a.p + up * lift + lateralOffset(rng, up, 0.5f * std::min(he.x, he.y));
        ShapeGeom gb =
            rng.chance(0.5f) ? ShapeGeom::box(hb) : ShapeGeom::convexHull(boxCornersHull(hb));
        scene.pairOf(rng, hull, place(rng, gb, {pb, qb}));
        break;
      }
      case 1: {  // a sphere around it
        float r = rng.uniform(0.05f, 0.5f);
        Vec3 local = rng.box(he + Vec3{r + 0.1f, r + 0.1f, r + 0.1f});
        scene.pairOf(rng, hull,
                     place(rng, ShapeGeom::sphere(r), {apply(a, local), rng.rotation()}));
        break;
      }
      case 2: {  // a capsule lying on top or anywhere
        float r = rng.uniform(0.05f, 0.3f), hh = rng.uniform(0.1f, 0.6f);
        Vec3 local = i % 2 ? Vec3{rng.uniform(-he.x, he.x), rng.uniform(-he.y, he.y),
                                  he.z + r + rng.uniform(-0.03f, 0.005f)}
                           : rng.box(he + Vec3{r + hh, r + hh, r + hh});
        Quat ql =
            i % 2 ? axisAngle({0, 0, 1}, rng.uniform(0, kPi2)) * axisAngle({1, 0, 0}, 0.5f * kPi)
                  : rng.rotation();
        scene.pairOf(rng, hull, place(rng, ShapeGeom::capsule(r, hh), {apply(a, local), a.q * ql}));
        break;
      }
      case 3: {  // on a plane
        scene.pairOf(rng, hull,
                     planeShape(rng, up, dot(up, a.p) - he.z - rng.uniform(-0.02f, 0.01f)));
        break;
      }
      default: {  // against a random hull
        HullPtr hb = anyHull(rng);
        Quat qb = rng.rotation();
        Vec3 dir = rng.direction();
        float reach = hullSupport(*h, a.q, dir) + hullSupport(*hb, qb, -dir);
        Vec3 pb = a.p + dir * (reach * rng.uniform(0.7f, 1.0f));
        scene.pairOf(rng, hull, place(rng, ShapeGeom::convexHull(hb), {pb, qb}));
      }
    }
  }
  Tally t = runAndCompare(scene);
  EXPECT_GT(t.touching, 250);
  EXPECT_GT(t.byCount[4], 60);
}

// ---------------------------------------------------------------------------------------------
// Mixed scenes, the pair records and the pair count

namespace {

/// A cluster of random shapes of every kind, every pair among them, and two planes. Hull
/// shapes have no hull (no contact on either side) unless `realHulls`: then most share one of
/// three hulls.
Scene mixedScene(Rng& rng, int n, bool realHulls = false) {
  Scene scene;
  std::vector<HullPtr> hulls;
  if (realHulls)
    for (int k = 0; k < 3; ++k) hulls.push_back(anyHull(rng));
  scene.add(planeShape(rng, {0, 0, 1}, -1.0f));
  scene.add(planeShape(rng, rng.direction(), -1.5f));
  for (int i = 0; i < n; ++i) {
    ShapeGeom g;
    switch (rng.below(5)) {
      case 0:
        g = ShapeGeom::sphere(rng.uniform(0.1f, 0.6f));
        break;
      case 1:
      case 2:
        g = ShapeGeom::box(randomHalfExtents(rng, 0.1f, 0.7f));
        break;
      case 3:
        g = ShapeGeom::capsule(rng.uniform(0.1f, 0.4f), rng.uniform(0.1f, 0.7f));
        break;
      default:
        if (realHulls) {
          g = ShapeGeom::convexHull(rng.chance(0.9f) ? hulls[size_t(rng.below(3))] : nullptr);
        } else {
          g.type = rng.chance(0.5f) ? ShapeType::Hull : ShapeType::Sphere;
        }
    }
    scene.add(place(rng, g, {rng.box(1.0f), rng.rotation()}));
  }
  for (uint32_t a = 0; a < scene.shapes.size(); ++a)
    for (uint32_t b = a + 1; b < scene.shapes.size(); ++b)
      if (scene.shapes[a].geom.type != ShapeType::Plane ||
          scene.shapes[b].geom.type != ShapeType::Plane)
        scene.pair(a, b);
  return scene;
}

}  // namespace

TEST_F(GpuNarrow, MixedCluster) {
  Rng rng(15);
  Scene scene = mixedScene(rng, 40);
  Tally t = runAndCompare(scene);
  EXPECT_GT(t.touching, 100);
}

TEST_F(GpuNarrow, MixedClusterWithHulls) {
  Rng rng(23);
  Scene scene = mixedScene(rng, 40, true);
  Tally t = runAndCompare(scene);
  EXPECT_GT(t.touching, 100);
}

TEST_F(GpuNarrow, PairsBeyondTheCountAreUntouched) {
  Rng rng(16);
  Scene scene = mixedScene(rng, 14);
  const uint32_t total = static_cast<uint32_t>(scene.pairs.size());
  const uint32_t count = total - 7;
  std::vector<gpu::GpuManifold> out = GpuNarrow::run(scene, count);
  ASSERT_EQ(out.size(), total);
  for (uint32_t i = count; i < total; ++i) {
    const unsigned char* bytes = reinterpret_cast<const unsigned char*>(&out[i]);
    for (size_t k = 0; k < sizeof(gpu::GpuManifold); ++k)
      ASSERT_EQ(bytes[k], 0xA5) << "manifold " << i << " byte " << k;
  }
  Scene counted = scene;
  counted.pairs.resize(count);
  out.resize(count);
  compareAll(counted, out);
  // No pairs at all: nothing written.
  out = GpuNarrow::run(scene, 0);
  for (const gpu::GpuManifold& m : out) EXPECT_EQ(m.count, 0xA5A5A5A5u);
}

}  // namespace phys
