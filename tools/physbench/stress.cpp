// physbench's stress mode: seeded random scenes (stacks, piles, chains and random joint trees
// with mass ratios up to 1000:1, random initial overlaps), each run for a few seconds with
// every preset asked for, and a failure rate per preset:
//   nan        a non-finite number in a body's state;
//   explosion  the total energy rising 5 % above its start (every scene starts at rest and
//              nothing drives it; not for the overlap scenes, whose push-out lifts bodies), or,
//              in scenes without joints, a body faster than free fall from the highest body
//              plus 10 m/s (with joints a light body at the end of a heavy swinging arm
//              legitimately goes faster, as a whip does);
//   joint      a joint's anchors more than 10 cm apart.
// The elastic kind (only with --kinds elastic: it is not in the default rotation, so the
// other kinds' seeds keep their scenes) is bodies with restitution 0.5 to 1 touching each
// other, hit at speed: a row on the ground hit along its length, or a cluster floating in
// zero gravity hit by one or two projectiles; and, a third of the seeds (issue 41), rows and
// clusters an impact must travel through: a Newton's cradle on joints, a free row struck at
// one end or both, a rack of balls on the ground struck by a cue ball. It fails when the
// energy ever rises 0.1 % above its start: an impact may lose energy, never make it.
// A seed fully determines its scene (the generator uses its own integer-to-float mapping, not
// the standard distributions, whose output differs between libraries), so a failing seed is
// replayed with --seed and written out as a scene file with --dump-scene.
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <limits>
#include <map>
#include <mutex>
#include <thread>

#include "bench.h"
#include "phys/scene/metrics.h"
#include "phys/scene/presets.h"
#include "phys/scene/scene.h"
#include "phys/world/world.h"

namespace phys::bench {

namespace {

/// SplitMix64: a small, fully specified generator.
struct Rng {
  uint64_t s;
  uint64_t next() {
    uint64_t z = (s += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
  }
  float uniform(float a, float b) {
    return a + (b - a) * float(next() >> 40) * (1.0f / 16777216.0f);
  }
  int range(int lo, int hi) { return lo + int(next() % uint64_t(hi - lo + 1)); }  ///< [lo, hi]
  /// 10^U(0, decades): densities and masses spread over `decades` orders of magnitude.
  float logUniform(float decades) { return std::pow(10.0f, uniform(0, decades)); }
  Quat rotation() {
    // A uniformly random unit quaternion (Shoemake).
    float u1 = uniform(0, 1), u2 = uniform(0, 6.2831853f), u3 = uniform(0, 6.2831853f);
    float a = std::sqrt(1 - u1), b = std::sqrt(u1);
    return normalize(Quat{a * std::sin(u2), a * std::cos(u2), b * std::sin(u3), b * std::cos(u3)});
  }
};

ShapeDef boxShape(Vec3 he, float density) {
  ShapeDef s;
  s.geom = ShapeGeom::box(he);
  s.material.density = density;
  return s;
}

BodyDef staticBody(const std::string& name, ShapeDef shape, Vec3 position) {
  BodyDef b;
  b.type = BodyType::Static;
  b.name = name;
  b.position = position;
  b.shapes.push_back(std::move(shape));
  return b;
}

BodyDef groundBody() {
  ShapeDef s;
  s.geom = ShapeGeom::plane({0, 0, 1}, 0);
  return staticBody("ground", s, {});
}

/// A column of boxes of random sizes and densities, each centred on the one below within a
/// random offset, spawned touching.
void makeStack(Rng& r, Scene* sc) {
  const int n = r.range(3, 12);
  float z = 0;
  for (int i = 0; i < n; ++i) {
    Vec3 he{r.uniform(0.2f, 0.8f), r.uniform(0.2f, 0.8f), r.uniform(0.15f, 0.6f)};
    BodyDef b;
    b.name = "box/" + std::to_string(i);
    b.position = {r.uniform(-0.1f, 0.1f), r.uniform(-0.1f, 0.1f), z + he.z};
    b.shapes.push_back(boxShape(he, 10 * r.logUniform(3)));
    sc->bodies.push_back(b);
    z += 2 * he.z;
  }
}

/// Boxes, spheres and capsules of random sizes and densities on a jittered grid in a walled
/// bin, spaced so their bounding spheres do not touch (overlaps are the overlap scenes' job).
void makePile(Rng& r, Scene* sc) {
  const float half = 2.5f, wall = 0.2f, height = 3;
  for (int k = 0; k < 4; ++k) {
    Vec3 he = k < 2 ? Vec3{wall, half + wall, height} : Vec3{half + wall, wall, height};
    Vec3 p = k == 0   ? Vec3{-half - wall, 0, height}
             : k == 1 ? Vec3{half + wall, 0, height}
             : k == 2 ? Vec3{0, -half - wall, height}
                      : Vec3{0, half + wall, height};
    sc->bodies.push_back(staticBody("wall/" + std::to_string(k), boxShape(he, 1000), p));
  }
  const int n = r.range(20, 60);
  const float size = r.uniform(0.15f, 0.35f), spacing = 2 * 1.7321f * size * r.uniform(1.02f, 1.2f);
  const int perRow = std::max(1, int((2 * half - spacing) / spacing));
  // The jitter (1 % of the spacing each way) stays inside the 2 % to 20 % gap.
  for (int i = 0; i < n; ++i) {
    int ix = i % perRow, iy = (i / perRow) % perRow, iz = i / (perRow * perRow);
    BodyDef b;
    b.name = "pile/" + std::to_string(i);
    const float jitter = 0.01f * spacing;
    b.position = {-half + spacing * (ix + 1) + r.uniform(-jitter, jitter),
                  -half + spacing * (iy + 1) + r.uniform(-jitter, jitter),
                  spacing * (0.5f + float(iz))};
    b.rotation = r.rotation();
    ShapeDef s;
    const float sz = size * r.uniform(0.6f, 1.0f);
    switch (r.range(0, 2)) {
      case 0:
        s.geom = ShapeGeom::box({sz, sz * r.uniform(0.5f, 1), sz * r.uniform(0.5f, 1)});
        break;
      case 1:
        s.geom = ShapeGeom::sphere(sz);
        break;
      default:
        s.geom = ShapeGeom::capsule(sz * 0.5f, sz * 0.7f);
        break;
    }
    s.material.density = 10 * r.logUniform(3);
    b.shapes.push_back(s);
    sc->bodies.push_back(b);
  }
}

/// A chain of links from a fixed point, ball or hinge joints, released from a random angle,
/// with a heavy end ball (up to 1000 times a link).
void makeChain(Rng& r, Scene* sc) {
  const int n = r.range(5, 30);
  const float link = r.uniform(0.2f, 0.6f), linkDensity = 100;
  const bool hinge = r.range(0, 1) == 1;
  const float angle = r.uniform(0, 1.5707963f);  // from hanging down to horizontal
  const Vec3 dir{std::sin(angle), 0, -std::cos(angle)};
  const Vec3 top{0, 0, n * link + 2};
  int prev = -1;
  for (int i = 0; i <= n; ++i) {
    const bool ball = i == n;
    BodyDef b;
    b.name = ball ? "ball" : "link/" + std::to_string(i);
    const float radius = ball ? link * 0.6f : link * 0.15f;
    b.position = top + dir * (link * (float(i) + 0.5f) + (ball ? radius : 0.0f));
    ShapeDef s;
    if (ball) {
      s.geom = ShapeGeom::sphere(radius);
      // The ball's mass is linkMass * ratio; its volume is known, so set the density.
      const float linkMass = linkDensity * 3.1415927f * (link * 0.15f) * (link * 0.15f) * link;
      const float volume = 4.0f / 3 * 3.1415927f * radius * radius * radius;
      s.material.density = linkMass * r.logUniform(3) / volume;
    } else {
      s.geom = ShapeGeom::capsule(link * 0.15f, link * 0.35f);
      s.material.density = linkDensity;
      b.rotation = normalize(
          Quat{0, std::sin(0.5f * (3.1415927f - angle)), 0, std::cos(0.5f * (3.1415927f - angle))});
    }
    b.shapes.push_back(s);
    sc->bodies.push_back(b);
    const int self = int(sc->bodies.size()) - 1;
    SceneJoint j;
    j.def.type = hinge ? JointType::Hinge : JointType::Ball;
    j.bodyA = prev;
    j.bodyB = self;
    // World anchor where this body meets the one before (the fixed point for the first).
    const Vec3 anchor = top + dir * (link * float(i));
    const BodyDef& self_ = sc->bodies[size_t(self)];
    j.def.anchorB = rotate(conjugate(self_.rotation), anchor - self_.position);
    if (prev < 0) {
      j.def.anchorA = anchor;
    } else {
      const BodyDef& a = sc->bodies[size_t(prev)];
      j.def.anchorA = rotate(conjugate(a.rotation), anchor - a.position);
      j.def.axisA = rotate(conjugate(a.rotation), Vec3{0, 1, 0});
    }
    j.def.axisB = rotate(conjugate(self_.rotation), Vec3{0, 1, 0});
    if (prev < 0) j.def.axisA = {0, 1, 0};
    sc->joints.push_back(j);
    prev = self;
  }
}

/// A random tree of bodies joined by random joint types (ball, hinge, fixed, distance,
/// prismatic), densities over three decades, hanging from the world above the ground.
void makeJointTree(Rng& r, Scene* sc) {
  const int n = r.range(5, 20);
  const int first = int(sc->bodies.size());
  for (int i = 0; i < n; ++i) {
    BodyDef b;
    b.name = "tree/" + std::to_string(i);
    // Bodies on a line at height 8, 0.7 m apart, each joined to an earlier one (or the world)
    // at the midpoint between them.
    b.position = {0.7f * float(i), r.uniform(-0.2f, 0.2f), 8};
    b.shapes.push_back(boxShape({0.25f, 0.2f, 0.15f}, 10 * r.logUniform(3)));
    sc->bodies.push_back(b);
    SceneJoint j;
    j.def.type = JointType(r.range(0, 4));
    const int parent = i == 0 ? -1 : first + r.range(std::max(0, i - 3), i - 1);
    j.bodyA = parent;
    j.bodyB = first + i;
    const Vec3 pa =
        parent < 0 ? b.position + Vec3{-0.35f, 0, 0.3f} : sc->bodies[size_t(parent)].position;
    const Vec3 anchor = 0.5f * (pa + b.position);
    j.def.anchorA = parent < 0 ? anchor : anchor - pa;
    j.def.anchorB = anchor - b.position;
    if (j.def.type == JointType::Distance) {
      // A rod between the two centres (a distance joint needs a length).
      j.def.anchorA = parent < 0 ? pa : Vec3{};
      j.def.anchorB = {};
    }
    const Vec3 axis = normalize(Vec3{r.uniform(-1, 1), r.uniform(-1, 1), r.uniform(0.1f, 1)});
    j.def.axisA = axis;
    j.def.axisB = axis;
    if (j.def.type == JointType::Prismatic || j.def.type == JointType::Hinge) {
      j.def.enableLimit = r.range(0, 1) == 1;
      j.def.lower = -0.5f;
      j.def.upper = 0.5f;
    }
    sc->joints.push_back(j);
  }
}

/// Boxes of random sizes spawned up to a third of their size into each other above the ground.
void makeOverlap(Rng& r, Scene* sc) {
  const int n = r.range(5, 40);
  const float size = r.uniform(0.2f, 0.5f);
  const float spacing = 2 * size * r.uniform(0.67f, 1.0f);
  const int side = std::max(1, int(std::cbrt(float(n))) + 1);
  for (int i = 0; i < n; ++i) {
    int ix = i % side, iy = (i / side) % side, iz = i / (side * side);
    BodyDef b;
    b.name = "overlap/" + std::to_string(i);
    b.position = {spacing * ix, spacing * iy, size * 0.8f + spacing * iz};
    b.rotation = r.rotation();
    b.shapes.push_back(boxShape({size, size, size}, 10 * r.logUniform(2)));
    sc->bodies.push_back(b);
  }
}

/// The elastic kind's rows and clusters through which an impact must travel (issue 41), a
/// third of its seeds (see makeElastic): spheres of restitution 0.5 to 1, touching,
///   0: a cradle: 3 to 7 balls hanging in contact on ball or hinge joints from the world
///      (0.3 to 1 m), equal masses or within a decade, the first (or the first two) pulled
///      aside 20 to 70 degrees and released into the others;
///   1: a free row in zero gravity, 2 to 8 spheres or boxes, struck along its length at one
///      end or at both at once;
///   2: a rack on the ground (billiards): 3 to 5 rows of touching balls in a triangle, struck
///      along its axis by a cue ball a little off centre.
void makeElasticRows(Rng& r, Scene* sc) {
  const float size = r.uniform(0.1f, 0.3f);
  const float e = r.uniform(0.5f, 1.0f), friction = r.uniform(0, 0.6f);
  const bool equal = r.range(0, 1) == 0;
  auto body = [&](const std::string& name, Vec3 p, bool sphere) {
    BodyDef b;
    b.name = name;
    b.position = p;
    ShapeDef s;
    s.geom = sphere ? ShapeGeom::sphere(size) : ShapeGeom::box({size, size, size});
    s.material.restitution = e;
    s.material.friction = friction;
    s.material.density = equal ? 500 : 100 * r.logUniform(1);  // masses within a decade
    b.shapes.push_back(s);
    sc->bodies.push_back(b);
    return int(sc->bodies.size()) - 1;
  };
  switch (r.range(0, 2)) {
    case 0: {
      const int n = r.range(3, 7), pulled = r.range(1, 2);
      const float length = r.uniform(0.3f, 1.0f), angle = r.uniform(0.35f, 1.22f);
      const bool hinge = r.range(0, 1) == 1;
      const float top = length + size + 0.5f;
      for (int i = 0; i < n; ++i) {
        const Vec3 pivot{2 * size * float(i), 0, top};
        // The pulled balls swing out together towards -x, each on its own string.
        const float a = i < pulled ? angle : 0;
        const int self = body("cradle/" + std::to_string(i),
                              pivot + Vec3{-length * std::sin(a), 0, -length * std::cos(a)}, true);
        SceneJoint j;
        j.def.type = hinge ? JointType::Hinge : JointType::Ball;
        j.bodyA = -1;
        j.bodyB = self;
        j.def.anchorA = pivot;
        j.def.anchorB = pivot - sc->bodies[size_t(self)].position;
        j.def.axisA = j.def.axisB = {0, 1, 0};
        sc->joints.push_back(j);
      }
      break;
    }
    case 1: {
      sc->world.gravity = {};
      const int n = r.range(2, 8);
      const bool spheres = r.range(0, 2) > 0, both = r.range(0, 2) == 0;
      for (int i = 0; i < n; ++i)
        body("free_row/" + std::to_string(i), {2 * size * float(i), 0, 5}, spheres);
      const int first = body("striker/0", {-2 * size - r.uniform(0.05f, 0.5f), 0, 5}, spheres);
      sc->bodies[size_t(first)].linearVelocity = {r.uniform(2, 12), 0, 0};
      if (both) {
        const int last =
            body("striker/1", {2 * size * float(n) + r.uniform(0.05f, 0.5f), 0, 5}, spheres);
        sc->bodies[size_t(last)].linearVelocity = {-r.uniform(2, 12), 0, 0};
      }
      break;
    }
    default: {
      const int rows = r.range(3, 5);
      const float dx = 1.7320508f * size;  // rows of touching balls, 60 degrees apart
      for (int row = 0; row < rows; ++row)
        for (int k = 0; k <= row; ++k)
          body("rack/" + std::to_string(row) + "/" + std::to_string(k),
               {dx * float(row), size * float(2 * k - row), size}, true);
      const int cue = body(
          "cue", {-2 * size - r.uniform(0.1f, 1.0f), r.uniform(-0.3f, 0.3f) * size, size}, true);
      sc->bodies[size_t(cue)].linearVelocity = {r.uniform(2, 12), 0, 0};
      break;
    }
  }
}

/// Spheres and boxes with restitution 0.5 to 1, touching, hit at speed (see the top).
void makeElastic(Rng& r, Scene* sc) {
  const float size = r.uniform(0.15f, 0.4f);
  auto shape = [&](bool sphere) {
    ShapeDef s;
    s.geom = sphere ? ShapeGeom::sphere(size) : ShapeGeom::box({size, size, size});
    s.material.restitution = r.uniform(0.5f, 1.0f);
    s.material.friction = r.uniform(0, 0.6f);
    s.material.density = 100 * r.logUniform(1);  // masses within a decade
    return s;
  };
  auto body = [&](const std::string& name, Vec3 p, bool sphere) {
    BodyDef b;
    b.name = name;
    b.position = p;
    b.shapes.push_back(shape(sphere));
    sc->bodies.push_back(b);
    return &sc->bodies.back();
  };
  const bool spheres = r.range(0, 2) > 0;  // boxes a third of the time
  if (r.range(0, 1) == 0) {
    // A row on the ground, touching, hit along its length by one more of its kind.
    const int n = r.range(2, 8);
    for (int i = 0; i < n; ++i) body("row/" + std::to_string(i), {2 * size * float(i), 0, size}, spheres);
    BodyDef* hit = body("striker", {-2 * size - r.uniform(0.05f, 0.5f), 0, size}, spheres);
    hit->linearVelocity = {r.uniform(2, 12), 0, 0};
  } else {
    // A cluster floating in zero gravity (a cube of touching bodies), hit by one or two.
    sc->world.gravity = {};
    const int side = r.range(2, 3);
    for (int i = 0; i < side * side * side; ++i)
      body("cluster/" + std::to_string(i),
           {2 * size * float(i % side), 2 * size * float((i / side) % side),
            5 + 2 * size * float(i / (side * side))},
           spheres);
    const int projectiles = r.range(1, 2);
    for (int k = 0; k < projectiles; ++k) {
      const Vec3 dir = normalize(Vec3{r.uniform(-1, 1), r.uniform(-1, 1), r.uniform(-1, 1)});
      const Vec3 centre{size * float(side - 1), size * float(side - 1), 5 + size * float(side - 1)};
      BodyDef* hit = body("projectile/" + std::to_string(k), centre - dir * (2 * size * float(side) + 1),
                          r.range(0, 1) == 0);
      hit->linearVelocity = dir * r.uniform(3, 15);
    }
  }
}

const char* const kKinds[] = {"stack", "pile", "chain", "joint_tree", "overlap", "elastic"};
constexpr int kOverlapKind = 4, kElasticKind = 5;
/// The default rotation: the first five kinds by seed mod 5 (elastic only when asked for).
int defaultKindOf(uint64_t seed) {
  return int(seed % 5);
}

/// The scene of a seed and kind: everything comes from the seed's stream.
Scene makeScene(uint64_t seed, int kind) {
  Rng r{seed * 0x2545F4914F6CDD1Dull + 1};
  Scene sc;
  sc.name = std::string("stress_") + kKinds[kind] + "_" + std::to_string(seed);
  sc.description = "physbench --stress scene for seed " + std::to_string(seed);
  sc.bodies.push_back(groundBody());
  switch (kind) {
    case 0:
      makeStack(r, &sc);
      break;
    case 1:
      makePile(r, &sc);
      break;
    case 2:
      makeChain(r, &sc);
      break;
    case 3:
      makeJointTree(r, &sc);
      break;
    case kOverlapKind:
      makeOverlap(r, &sc);
      break;
    default: {  // kElasticKind
      // A third of the seeds are the rows and clusters an impact travels through, chosen by
      // a stream of their own: the other seeds keep the scenes they had before (issue 41).
      Rng pick{seed * 0x9E3779B97F4A7C15ull + 41};
      if (pick.range(0, 2) == 0)
        makeElasticRows(r, &sc);
      else
        makeElastic(r, &sc);
      break;
    }
  }
  sc.metrics.settleTime = 1;
  return sc;
}

constexpr double kEnergyRise = 0.05;
constexpr double kElasticEnergyRise = 0.001;  ///< an elastic impact makes no energy

struct RunResult {
  uint64_t seed = 0;
  std::string kind, preset, error;
  long long nan = 0;
  double maxSpeed = 0, speedBound = 0, jointError = 0, energyRise = 0;
  unsigned long long guardEvents = 0;
  bool checkEnergy = true;
  double energyBound = kEnergyRise;  ///< the rise that fails it
  std::string firstFailure;  ///< when and where it first failed (replays of failed runs only)
  /// With --backend: steps on the device, steps the CPU took whole, device steps with
  /// islands on the CPU (world_gpu_islands.cpp), and the run's wall time.
  unsigned long long gpuSteps = 0, cpuSteps = 0, cpuIslandSteps = 0;
  double ms = 0;
  int steps = 0;
  bool exploded() const {
    return maxSpeed > speedBound || (checkEnergy && energyRise > energyBound);
  }
  bool jointFailed() const { return jointError > kStressJointError; }
  bool failed() const { return !error.empty() || nan > 0 || exploded() || jointFailed(); }
};

/// The run's failure measures so far, from the recorder's summary.
void takeSummary(const MetricsSummary& m, RunResult* res) {
  res->nan = m.nan;
  res->maxSpeed = m.maxSpeed;
  res->jointError = m.jointErrorMax.value_or(0);
  res->energyRise = m.energyRiseMax;
}

/// "pile/19 (3.14 kg)": a body's scene name and mass, for the failure report.
std::string bodyLabel(const Scene& sc, const World& world, const std::vector<BodyId>& ids,
                      BodyId id) {
  if (id.isNull()) return "the world";
  for (size_t i = 0; i < ids.size(); ++i) {
    if (ids[i] != id) continue;
    BodyState b;
    world.getBody(id, &b);
    const std::string name =
        sc.bodies[i].name.empty() ? "body " + std::to_string(i) : sc.bodies[i].name;
    char buf[160];
    if (b.type == BodyType::Dynamic)
      std::snprintf(buf, sizeof buf, "%s (%.3g kg)", name.c_str(), b.mass);
    else
      std::snprintf(buf, sizeof buf, "%s (%s)", name.c_str(),
                    b.type == BodyType::Static ? "static" : "kinematic");
    return buf;
  }
  return "an unknown body";
}

/// What touches `body` this step: "touching pile/10 (3.86 kg, 4.5 cm deep), ground (static)".
std::string contactsOf(const Scene& sc, const World& world, const std::vector<BodyId>& ids,
                       BodyId body) {
  std::string out;
  for (const ContactInfo& c : world.contacts()) {
    if (c.bodyA != body && c.bodyB != body) continue;
    float deepest = 0;
    for (int k = 0; k < c.manifold.count; ++k)
      deepest = std::min(deepest, c.manifold.points[k].separation);
    std::string other = bodyLabel(sc, world, ids, c.bodyA == body ? c.bodyB : c.bodyA);
    if (deepest < -0.0005f) {
      char buf[48];
      std::snprintf(buf, sizeof buf, ", %.1f cm deep", -100 * deepest);
      other.insert(other.size() - 1, buf);
    }
    out += (out.empty() ? "touching " : ", ") + other;
  }
  return out.empty() ? "touching nothing" : out;
}

/// Names the criterion that `now` newly fails and the body or joint behind it at step
/// `step`, with what touches it: how a failed run is first triaged.
std::string describeFailure(const Scene& sc, const World& world, const std::vector<BodyId>& ids,
                            const std::vector<JointId>& jointIds, const RunResult& now, int step) {
  char buf[256];
  std::snprintf(buf, sizeof buf,
                "first at t = %.3f s (step %d): ", (step + 1) * double(sc.world.timeStep),
                step + 1);
  std::string out = buf;
  if (now.nan > 0) return out + "a non-finite number in a body's state";
  if (now.jointFailed()) {
    JointId worst;
    JointDef worstDef;
    float worstError = -1;
    for (JointId j : jointIds) {
      JointDef d;
      JointState js;
      if (world.getJoint(j, &d, &js).ok() && js.positionError > worstError) {
        worst = j;
        worstDef = d;
        worstError = js.positionError;
      }
    }
    int index = 0;
    while (index < int(jointIds.size()) && jointIds[index] != worst) ++index;
    std::snprintf(buf, sizeof buf, "joint %d (%s) %.1f cm apart, between ", index,
                  toString(worstDef.type), 100 * worstError);
    out += buf;
    out += bodyLabel(sc, world, ids, worstDef.bodyA) + " and " +
           bodyLabel(sc, world, ids, worstDef.bodyB);
    for (BodyId b : {worstDef.bodyA, worstDef.bodyB})
      if (!b.isNull())
        out += "; " + bodyLabel(sc, world, ids, b) + " " + contactsOf(sc, world, ids, b);
    return out;
  }
  if (now.maxSpeed > now.speedBound) {
    BodyId fastest;
    float speed = -1;
    for (BodyId id : ids) {
      BodyState b;
      world.getBody(id, &b);
      if (b.type == BodyType::Dynamic && length(b.linearVelocity) > speed) {
        speed = length(b.linearVelocity);
        fastest = id;
      }
    }
    std::snprintf(buf, sizeof buf, " at %.3g m/s, ", speed);
    return out + bodyLabel(sc, world, ids, fastest) + buf + contactsOf(sc, world, ids, fastest);
  }
  std::snprintf(buf, sizeof buf, "the energy %.1f %% above its start", 100 * now.energyRise);
  return out + buf;
}

/// Runs one seed with one preset. With `explain` (a replay of a failed run: runs are
/// deterministic with one thread), the measures are checked after every step as well and the
/// first step that fails is described in RunResult::firstFailure.
RunResult runOne(uint64_t seed, int kind, const std::string& presetName,
                 const SolverSettings& settings, double seconds, const std::string& backend,
                 bool explain = false) {
  Scene sc = makeScene(seed, kind);
  sc.world.solver = settings;
  sc.world.threads = 1;
  if (!backend.empty()) parseBackend(backend, &sc.world.backend);
  RunResult res;
  res.seed = seed;
  res.kind = kKinds[kind];
  res.preset = presetName;
  res.checkEnergy = kind != kOverlapKind;
  if (kind == kElasticKind) res.energyBound = kElasticEnergyRise;
  float top = 0;
  for (const BodyDef& b : sc.bodies)
    if (b.type == BodyType::Dynamic) top = std::max(top, b.position.z);
  res.speedBound = sc.joints.empty() ? std::sqrt(2 * 9.81 * (top + 1.0)) + 10
                                     : std::numeric_limits<double>::infinity();
  if (kind == kElasticKind) {
    // Struck by a body up to ten times its mass, a body leaves at up to twice the speed.
    double fastest = 0;
    for (const BodyDef& b : sc.bodies) fastest = std::max(fastest, double(length(b.linearVelocity)));
    res.speedBound = 2 * fastest + std::sqrt(2 * 9.81 * (top + 1.0)) + 1;
  }
  World world(sc.world);
  std::vector<BodyId> ids;
  std::vector<JointId> jointIds;
  Status st = instantiateScene(sc, &world, &ids, &jointIds);
  if (!st.ok()) {
    res.error = st.message;
    return res;
  }
  MetricsRecorder rec(sc, world, ids);
  const int steps = int(std::lround(seconds / sc.world.timeStep));
  const auto t0 = std::chrono::steady_clock::now();
  for (int i = 0; i < steps; ++i) {
    world.step();
    rec.afterStep(world);
    if (explain && res.firstFailure.empty()) {
      RunResult now = res;
      takeSummary(rec.summary(), &now);
      if (now.failed()) res.firstFailure = describeFailure(sc, world, ids, jointIds, now, i);
    }
  }
  takeSummary(rec.summary(), &res);
  res.guardEvents = world.stats().guardEvents;
  res.ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  res.steps = steps;
  const BackendState& b = world.backendState();
  res.gpuSteps = b.gpuSteps;
  res.cpuSteps = b.cpuSteps;
  res.cpuIslandSteps = b.cpuIslandSteps;
  return res;
}

}  // namespace

int runStress(const StressOptions& opt) {
  std::map<std::string, Preset> presets;
  std::string defaultName;
  Status st = loadPresetsFile(opt.presetsPath, &presets, &defaultName);
  if (!st.ok()) {
    std::cerr << "physbench: " << st.message << "\n";
    return 2;
  }
  std::vector<std::string> names = opt.presets;
  if (names.empty()) names = {defaultName};
  for (std::string& n : names) {
    if (n == "default") n = defaultName;
    if (n == "all") {
      names.clear();
      for (const auto& [k, v] : presets) names.push_back(k);
      break;
    }
  }
  for (const std::string& n : names) {
    if (!presets.count(n)) {
      std::cerr << "physbench: unknown preset '" << n << "'\n";
      return 2;
    }
  }
  std::vector<int> kinds;
  for (const std::string& k : opt.kinds) {
    const auto it = std::find(std::begin(kKinds), std::end(kKinds), k);
    if (it == std::end(kKinds)) {
      std::cerr << "physbench: unknown stress kind '" << k
                << "' (stack, pile, chain, joint_tree, overlap, elastic)\n";
      return 2;
    }
    kinds.push_back(int(it - std::begin(kKinds)));
  }
  auto kindFor = [&](uint64_t seed) {
    return kinds.empty() ? defaultKindOf(seed) : kinds[size_t(seed % kinds.size())];
  };
  std::vector<uint64_t> seeds;
  if (opt.seed) {
    seeds.push_back(*opt.seed);
  } else {
    for (int i = 0; i < opt.seeds; ++i) seeds.push_back(opt.seedStart + uint64_t(i));
  }
  if (!opt.dumpScene.empty()) {
    if (seeds.size() != 1) {
      std::cerr << "physbench: --dump-scene needs --seed\n";
      return 2;
    }
    std::ofstream f(opt.dumpScene);
    f << sceneToJson(makeScene(seeds[0], kindFor(seeds[0])));
    if (!f) {
      std::cerr << "physbench: cannot write " << opt.dumpScene << "\n";
      return 2;
    }
    std::printf("wrote %s\n", opt.dumpScene.c_str());
  }

  struct Job {
    uint64_t seed;
    size_t preset;
  };
  std::vector<Job> jobs;
  for (uint64_t s : seeds)
    for (size_t p = 0; p < names.size(); ++p) jobs.push_back({s, p});
  std::vector<RunResult> results(jobs.size());
  std::atomic<size_t> next{0}, done{0};
  std::mutex printMutex;
  const auto t0 = std::chrono::steady_clock::now();
  auto worker = [&] {
    for (size_t k; (k = next.fetch_add(1)) < jobs.size();) {
      const Job& j = jobs[k];
      results[k] = runOne(j.seed, kindFor(j.seed), names[j.preset],
                          presets[names[j.preset]].settings, opt.seconds, opt.backend);
      const size_t d = ++done;
      if (d % 50 == 0 || d == jobs.size()) {
        std::lock_guard<std::mutex> lock(printMutex);
        const double el =
            std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        std::fprintf(stderr, "\r%zu / %zu runs, %.0f s", d, jobs.size(), el);
      }
    }
  };
  const int threads =
      std::max(1, opt.jobs > 0 ? opt.jobs : int(std::thread::hardware_concurrency()));
  std::vector<std::thread> pool;
  for (int i = 0; i < threads; ++i) pool.emplace_back(worker);
  for (std::thread& t : pool) t.join();
  std::fprintf(stderr, "\n");

  if (!opt.csvOut.empty()) {
    std::ofstream f(opt.csvOut);
    f << "seed,kind,preset,nan,max_speed,speed_bound,energy_rise_max,joint_error_max,guard_events,"
         "failed,error\n";
    for (const RunResult& r : results)
      f << r.seed << ',' << r.kind << ',' << r.preset << ',' << r.nan << ',' << r.maxSpeed << ','
        << r.speedBound << ',' << r.energyRise << ',' << r.jointError << ',' << r.guardEvents << ','
        << r.failed() << ",\"" << r.error << "\"\n";
    if (!f) {
      std::cerr << "physbench: cannot write " << opt.csvOut << "\n";
      return 2;
    }
  }

  // The report, printed and kept for --report (opt.reportOut).
  std::string out;
  auto say = [&out](const char* format, auto... args) {
    char buf[512];
    std::snprintf(buf, sizeof buf, format, args...);
    out += buf;
  };
  say("stress: %zu seeds from %llu, %.3g s each, %zu presets\n", seeds.size(),
      static_cast<unsigned long long>(seeds.front()), opt.seconds, names.size());
  if (!opt.backend.empty()) {
    // Where the steps ran, and their wall time per step (jobs in parallel share the cores).
    unsigned long long gpu = 0, cpu = 0, islands = 0, steps = 0;
    double ms = 0;
    for (const RunResult& r : results) {
      gpu += r.gpuSteps, cpu += r.cpuSteps, islands += r.cpuIslandSteps;
      steps += static_cast<unsigned long long>(r.steps);
      ms += r.ms;
    }
    say("backend %s: %llu steps on the device (%llu of them with islands on the CPU), %llu "
        "taken whole by the CPU; %.3f ms/step\n",
        opt.backend.c_str(), gpu, islands, cpu, steps ? ms / double(steps) : 0.0);
  }
  say("| preset | runs | nan | explosion | joint > 10 cm | failed | failure rate | guard "
      "events |\n|---|---|---|---|---|---|---|---|\n");
  bool anyFailed = false, anyError = false;
  for (size_t p = 0; p < names.size(); ++p) {
    int runs = 0, nan = 0, exploded = 0, joint = 0, failed = 0;
    unsigned long long guard = 0;
    for (const RunResult& r : results) {
      if (r.preset != names[p]) continue;
      ++runs;
      nan += r.nan > 0;
      exploded += r.exploded();
      joint += r.jointFailed();
      failed += r.failed();
      guard += r.guardEvents;
      anyError |= !r.error.empty();
    }
    anyFailed |= failed > 0;
    say("| %s | %d | %d | %d | %d | %d | %.1f %% | %llu |\n", names[p].c_str(), runs, nan, exploded,
        joint, failed, runs ? 100.0 * failed / runs : 0.0, guard);
  }
  int shown = 0;
  for (const RunResult& r : results) {
    if (!r.failed()) continue;
    if (shown++ == 0) {
      std::string kindsArg;
      for (const std::string& k : opt.kinds) kindsArg += (kindsArg.empty() ? " --kinds " : ",") + k;
      say("\nfailures (replay: physbench --stress --seed S --presets P%s):\n", kindsArg.c_str());
    }
    if (shown > 20) continue;
    say("  seed %llu (%s) preset %s:", static_cast<unsigned long long>(r.seed), r.kind.c_str(),
        r.preset.c_str());
    if (!r.error.empty()) say(" error: %s", r.error.c_str());
    if (r.nan) say(" nan %lld", r.nan);
    if (r.maxSpeed > r.speedBound) say(" max speed %.3g m/s > %.3g", r.maxSpeed, r.speedBound);
    if (r.checkEnergy && r.energyRise > kEnergyRise) say(" energy rise %.3g", r.energyRise);
    if (r.jointFailed()) say(" joint error %.3g m", r.jointError);
    say("\n");
    // Replayed step by step to say when it first failed, on what, and what touched it.
    const RunResult replay =
        runOne(r.seed, kindFor(r.seed), r.preset, presets[r.preset].settings, opt.seconds,
               opt.backend, /*explain=*/true);
    if (!replay.firstFailure.empty()) say("    %s\n", replay.firstFailure.c_str());
  }
  if (shown > 20) say("  ... and %d more (see --csv)\n", shown - 20);
  std::fputs(out.c_str(), stdout);
  if (opt.reportOut) *opt.reportOut = out;
  if (anyError) return 2;
  return opt.failOnFailure && anyFailed ? 1 : 0;
}

}  // namespace phys::bench
