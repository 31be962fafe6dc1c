// Scene generators: "generators" entries expanded into bodies and joints at load time. Each
// generated body is named "<name>/<...>" (name defaults to the generator type) so metrics and
// explicit joints can refer to it. Layouts are documented in docs/SCENES.md.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include "scene_internal.h"

namespace phys::scene_detail {
namespace {

/// splitmix64: tiny, seedable and the same on every platform (std:: distributions are not).
class Rng {
 public:
  explicit Rng(uint64_t seed) : state_(seed) {}
  uint64_t next() {
    uint64_t z = (state_ += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
  }
  /// Uniform in [0, 1).
  double uniform() { return double(next() >> 11) * 0x1.0p-53; }
  double uniform(double lo, double hi) { return lo + (hi - lo) * uniform(); }
  /// Uniformly distributed unit quaternion, by rejection in the 4-ball (only + * / sqrt,
  /// which IEEE rounds the same everywhere, unlike sin/cos).
  Quat rotation() {
    for (;;) {
      double x = uniform(-1, 1), y = uniform(-1, 1), z = uniform(-1, 1), w = uniform(-1, 1);
      double n2 = x * x + y * y + z * z + w * w;
      if (n2 > 1e-4 && n2 <= 1) {
        double inv = 1 / std::sqrt(n2);
        return {float(x * inv), float(y * inv), float(z * inv), float(w * inv)};
      }
    }
  }

 private:
  uint64_t state_;
};

BodyDef makeBody(std::string name, BodyType type, Vec3 position, Quat rotation) {
  BodyDef d;
  d.name = std::move(name);
  d.type = type;
  d.position = position;
  d.rotation = rotation;
  return d;
}

ShapeDef makeShape(const ShapeGeom& g, const Material& m, Vec3 p = {}, Quat q = {}) {
  ShapeDef s;
  s.geom = g;
  s.local = {p, q};
  s.material = m;
  return s;
}

BodyDef boxBody(std::string name, Vec3 position, Vec3 halfExtents, const Material& m,
                Quat rotation = {}) {
  BodyDef d = makeBody(std::move(name), BodyType::Dynamic, position, rotation);
  d.shapes.push_back(makeShape(ShapeGeom::box(halfExtents), m));
  return d;
}

Vec3 v3(double x, double y, double z) {
  return {float(x), float(y), float(z)};
}

/// The generator's material: "material" (name or inline), else the scene default.
Material genMaterial(const Object& o, const Builder& b, const char* key = "material") {
  const Json* m = o.find(key);
  return m ? b.material(*m, o.path(key)) : b.defaultMaterial;
}

/// Decimal digits of n (>= 1): the length of the longest index suffix "/<n>".
size_t digits(uint64_t n) {
  size_t d = 1;
  while (n >= 10) n /= 10, ++d;
  return d;
}

/// Length of the largest index i in [0, count): "/" + digits(count - 1).
size_t indexSuffix(uint64_t count) {
  return 1 + digits(count == 0 ? 0 : count - 1);
}

std::string typeOf(const Json& j, const std::string& path) {
  if (!j.is_object()) fail(path, "must be an object with a \"type\"");
  auto it = j.find("type");
  if (it == j.end()) fail(member(path, "type"), "is required");
  return readString(*it, member(path, "type"));
}

// ---------------------------------------------------------------------------------------
// pyramid: a 2-D pyramid of cubes in the x-z plane, rows centred on origin.

struct PyramidParams {
  int64_t base;
  float halfExtent, gap, overlap;
};

void addPyramid(Builder* b, const std::string& prefix, const PyramidParams& p, Vec3 origin,
                const Material& m, const std::string& path) {
  // Boxes overlap their neighbours (and the bottom row the ground) by `overlap` of their size.
  double h = p.halfExtent;
  double sx = 2 * h * (1 - p.overlap) + p.gap, sz = 2 * h * (1 - p.overlap);
  double z0 = origin.z + h - 2 * h * p.overlap;
  int64_t k = 0;
  for (int64_t row = 0; row < p.base; ++row) {
    int64_t count = p.base - row;
    for (int64_t j = 0; j < count; ++j) {
      double x = origin.x + (double(j) - 0.5 * double(count - 1)) * sx;
      b->addBody(boxBody(prefix + "/" + std::to_string(k++), v3(x, origin.y, z0 + double(row) * sz),
                         v3(h, h, h), m),
                 path);
    }
  }
}

PyramidParams readPyramidParams(const Object& o) {
  PyramidParams p;
  p.base = o.integer("base", 1, 5000);
  p.halfExtent = o.number("half_extent", 0.5f, Range::Positive);
  p.gap = o.number("gap", 0.0f, Range::NonNegative);
  p.overlap = o.number("overlap", 0.0f, Range::NonNegative);
  if (p.overlap >= 0.9f) fail(o.path("overlap"), "must be in [0, 0.9) (a fraction of a box)");
  return p;
}

int64_t pyramidCount(int64_t base) {
  return base * (base + 1) / 2;
}

void genPyramid(const Json& j, const std::string& path, Builder* b) {
  Object o(j, path,
           {"type", "name", "material", "base", "half_extent", "gap", "overlap", "origin"});
  std::string prefix = o.string("name", "pyramid");
  PyramidParams p = readPyramidParams(o);
  GeneratorCounts c;
  c.bodies = c.shapes = uint64_t(pyramidCount(p.base));
  c.longestSuffix = indexSuffix(c.bodies);
  if (!b->plan(o, prefix, c)) return;
  addPyramid(b, prefix, p, o.vec3("origin", Vec3{}), genMaterial(o, *b), path);
}

// pyramid_grid: rows x cols pyramids, rows along y, columns along x, centred on origin.
void genPyramidGrid(const Json& j, const std::string& path, Builder* b) {
  Object o(j, path,
           {"type", "name", "material", "rows", "cols", "base", "half_extent", "gap", "overlap",
            "spacing", "origin"});
  std::string prefix = o.string("name", "pyramid_grid");
  PyramidParams p = readPyramidParams(o);
  int64_t rows = o.integer("rows", 1, 10000), cols = o.integer("cols", 1, 10000);
  GeneratorCounts c;
  uint64_t perPyramid = uint64_t(pyramidCount(p.base));
  c.bodies = c.shapes = mulSat(mulSat(uint64_t(rows), uint64_t(cols)), perPyramid);
  c.longestSuffix = indexSuffix(uint64_t(rows * cols)) + indexSuffix(perPyramid);
  if (!b->plan(o, prefix, c)) return;
  double width = double(p.base) * (2 * p.halfExtent + p.gap);
  Vec3 spacing = v3(width + 2 * p.halfExtent, 4 * p.halfExtent, 0);
  if (const Json* s = o.find("spacing")) {
    const std::string sp = o.path("spacing");
    if (!s->is_array() || s->size() != 2) fail(sp, "must be [x, y] (m between pyramid centres)");
    spacing.x = readFloat((*s)[0], element(sp, 0), Range::Positive);
    spacing.y = readFloat((*s)[1], element(sp, 1), Range::Positive);
  }
  Vec3 origin = o.vec3("origin", Vec3{});
  Material m = genMaterial(o, *b);
  for (int64_t r = 0; r < rows; ++r) {
    for (int64_t c = 0; c < cols; ++c) {
      Vec3 at = v3(origin.x + (double(c) - 0.5 * double(cols - 1)) * spacing.x,
                   origin.y + (double(r) - 0.5 * double(rows - 1)) * spacing.y, origin.z);
      addPyramid(b, prefix + "/" + std::to_string(r * cols + c), p, at, m, path);
    }
  }
}

// stack: `count` cubes in one column standing on origin.
void genStack(const Json& j, const std::string& path, Builder* b) {
  Object o(j, path, {"type", "name", "material", "count", "half_extent", "gap", "origin"});
  std::string prefix = o.string("name", "stack");
  int64_t n = o.integer("count", 1, 100000);
  double h = o.number("half_extent", 0.5f, Range::Positive);
  double gap = o.number("gap", 0.0f, Range::NonNegative);
  Vec3 origin = o.vec3("origin", Vec3{});
  Material m = genMaterial(o, *b);
  GeneratorCounts c;
  c.bodies = c.shapes = uint64_t(n);
  c.longestSuffix = indexSuffix(c.bodies);
  if (!b->plan(o, prefix, c)) return;
  for (int64_t i = 0; i < n; ++i) {
    double z = origin.z + h + double(i) * (2 * h + gap);
    b->addBody(boxBody(prefix + "/" + std::to_string(i), v3(origin.x, origin.y, z), v3(h, h, h), m),
               path);
  }
}

// grid: nx x ny x nz boxes, centred on origin in x and y, the bottom layer resting on origin.z;
// optionally all of them moving at linear_velocity.
void genGrid(const Json& j, const std::string& path, Builder* b) {
  Object o(j, path,
           {"type", "name", "material", "nx", "ny", "nz", "half_extent", "half_extents", "spacing",
            "origin", "linear_velocity"});
  std::string prefix = o.string("name", "grid");
  int64_t nx = o.integer("nx", 1, 10000), ny = o.integer("ny", 1, 10000),
          nz = o.integer("nz", 1, 10000);
  if (o.has("half_extent") && o.has("half_extents")) {
    fail(o.path("half_extents"), "give \"half_extent\" or \"half_extents\", not both");
  }
  Vec3 he = o.positiveVec3("half_extents", Vec3{0.5f, 0.5f, 0.5f});
  if (o.has("half_extent")) {
    float h = o.number("half_extent", Range::Positive);
    he = {h, h, h};
  }
  Vec3 spacing = he * 2.0f;
  if (const Json* s = o.find("spacing")) {
    if (s->is_number()) {
      float v = readFloat(*s, o.path("spacing"), Range::Positive);
      spacing = {v, v, v};
    } else {
      spacing = readPositiveVec3(*s, o.path("spacing"));
    }
  }
  Vec3 origin = o.vec3("origin", Vec3{});
  const Vec3 velocity = o.vec3("linear_velocity", Vec3{});
  Material m = genMaterial(o, *b);
  GeneratorCounts c;
  c.bodies = c.shapes = mulSat(mulSat(uint64_t(nx), uint64_t(ny)), uint64_t(nz));
  c.longestSuffix = indexSuffix(c.bodies);
  if (!b->plan(o, prefix, c)) return;
  int64_t k = 0;
  for (int64_t iz = 0; iz < nz; ++iz) {
    for (int64_t iy = 0; iy < ny; ++iy) {
      for (int64_t ix = 0; ix < nx; ++ix) {
        Vec3 p = v3(origin.x + (double(ix) - 0.5 * double(nx - 1)) * spacing.x,
                    origin.y + (double(iy) - 0.5 * double(ny - 1)) * spacing.y,
                    origin.z + he.z + double(iz) * spacing.z);
        BodyDef d = boxBody(prefix + "/" + std::to_string(k++), p, he, m);
        d.linearVelocity = velocity;
        b->addBody(std::move(d), path);
      }
    }
  }
}

// chain: links joined end to end by ball joints, hanging from a world point, laid out
// straight along `direction`; optionally a ball at the free end.
void genChain(const Json& j, const std::string& path, Builder* b) {
  Object o(j, path,
           {"type", "name", "material", "links", "link_length", "link_radius", "link_shape",
            "link_mass", "anchor", "direction", "end_ball"});
  std::string prefix = o.string("name", "chain");
  int64_t n = o.integer("links", 1, 100000);
  double len = o.number("link_length", 0.5f, Range::Positive);
  double r = o.number("link_radius", float(0.1 * len), Range::Positive);
  std::string shape = o.string("link_shape", "capsule");
  if (shape != "capsule" && shape != "box") {
    fail(o.path("link_shape"), "must be \"capsule\" or \"box\" (got " + quote(shape) + ")");
  }
  Vec3 anchor = readVec3(o.require("anchor"), o.path("anchor"));
  Vec3 dir = o.direction("direction", Vec3{1, 0, 0});
  Material m = genMaterial(o, *b);
  float linkMass = o.has("link_mass") ? o.number("link_mass", Range::Positive) : 0.0f;
  const bool endBall = o.has("end_ball");
  GeneratorCounts c;
  c.bodies = c.shapes = c.joints = uint64_t(n) + (endBall ? 1 : 0);
  // "/<link>", "/joint/<k>" (k up to n with the ball), "/ball".
  c.longestSuffix = std::max({indexSuffix(uint64_t(n)), 6 + indexSuffix(c.joints), size_t(5)});
  if (!b->plan(o, prefix, c)) return;

  // Each link's local z runs along the chain; the joints sit at the segment ends (+-len/2),
  // so neighbouring capsules' caps overlap there (connected bodies do not collide).
  Quat q = quatFromTo(Vec3{0, 0, 1}, dir);
  ShapeGeom g = shape == "capsule" ? ShapeGeom::capsule(float(r), float(0.5 * len))
                                   : ShapeGeom::box(v3(r, r, 0.5 * len));
  const float half = float(0.5 * len);
  int first = int(b->bodies->size());
  for (int64_t i = 0; i < n; ++i) {
    Vec3 p = anchor + dir * float((double(i) + 0.5) * len);
    BodyDef d = makeBody(prefix + "/" + std::to_string(i), BodyType::Dynamic, p, q);
    d.shapes.push_back(makeShape(g, m));
    d.mass = linkMass;
    b->addBody(std::move(d), path);
  }
  auto joint = [&](int64_t k, int bodyA, Vec3 anchorA, int bodyB, Vec3 anchorB) {
    SceneJoint sj;
    sj.def.type = JointType::Ball;
    sj.def.name = prefix + "/joint/" + std::to_string(k);
    sj.def.anchorA = anchorA;
    sj.def.anchorB = anchorB;
    sj.bodyA = bodyA;
    sj.bodyB = bodyB;
    b->generatedJoints.push_back(std::move(sj));
  };
  joint(0, -1, anchor, first, Vec3{0, 0, -half});
  for (int64_t i = 1; i < n; ++i) {
    joint(i, first + int(i - 1), Vec3{0, 0, half}, first + int(i), Vec3{0, 0, -half});
  }
  if (const Json* e = o.find("end_ball")) {
    Object eo(*e, o.path("end_ball"), {"radius", "mass", "mass_ratio", "material"});
    double radius = eo.number("radius", Range::Positive);
    if (eo.has("mass") == eo.has("mass_ratio")) {
      fail(eo.path(), "give exactly one of \"mass\" (kg) and \"mass_ratio\" (to one link)");
    }
    float mass = 0;
    if (eo.has("mass")) {
      mass = eo.number("mass", Range::Positive);
    } else {
      double link = linkMass;
      if (link == 0) {
        double volume =
            shape == "capsule" ? kPi * r * r * len + 4.0 / 3.0 * kPi * r * r * r : 4 * r * r * len;
        link = volume * m.density;
      }
      mass = float(eo.number("mass_ratio", Range::Positive) * link);
    }
    Material bm = eo.has("material") ? b->material(*eo.find("material"), eo.path("material")) : m;
    Vec3 p = anchor + dir * float(double(n) * len + radius);
    BodyDef d = makeBody(prefix + "/ball", BodyType::Dynamic, p, Quat{});
    d.shapes.push_back(makeShape(ShapeGeom::sphere(float(radius)), bm));
    d.mass = mass;
    int ball = b->addBody(std::move(d), path);
    joint(n, first + int(n - 1), Vec3{0, 0, half}, ball, dir * float(-radius));
  }
}

// pile: `count` boxes, spheres and capsules of random size and orientation on a lattice in
// a bin region, filled layer by layer upwards; optionally with the bin's four walls.
void genPile(const Json& j, const std::string& path, Builder* b) {
  Object o(j, path,
           {"type", "name", "material", "count", "seed", "mix", "size", "center", "half_extents",
            "spacing", "orientation", "walls"});
  std::string prefix = o.string("name", "pile");
  int64_t count = o.integer("count", 1, INT32_MAX);
  uint64_t seed = uint64_t(o.integer("seed", 1, 0, INT64_MAX));
  double wBox = 1, wSphere = 1, wCapsule = 1;
  if (const Json* mix = o.find("mix")) {
    Object mo(*mix, o.path("mix"), {"box", "sphere", "capsule"});
    wBox = mo.number("box", 0.0f, Range::NonNegative);
    wSphere = mo.number("sphere", 0.0f, Range::NonNegative);
    wCapsule = mo.number("capsule", 0.0f, Range::NonNegative);
    if (!(wBox + wSphere + wCapsule > 0)) fail(mo.path(), "needs at least one positive weight");
  }
  double sizeMin = 0.25, sizeMax = 0.5;
  if (const Json* s = o.find("size")) {
    const std::string sp = o.path("size");
    if (!s->is_array() || s->size() != 2) fail(sp, "must be [min, max] (m)");
    sizeMin = readFloat((*s)[0], element(sp, 0), Range::Positive);
    sizeMax = readFloat((*s)[1], element(sp, 1), Range::Positive);
    if (sizeMin > sizeMax) fail(sp, "min must be <= max");
  }
  Vec3 center = o.vec3("center", Vec3{});
  const Json& hj = o.require("half_extents");
  const std::string hp = o.path("half_extents");
  if (!hj.is_array() || hj.size() != 2) fail(hp, "must be [x, y] (m, half size of the bin floor)");
  double hx = readFloat(hj[0], element(hp, 0), Range::Positive);
  double hy = readFloat(hj[1], element(hp, 1), Range::Positive);
  std::string orientation = o.string("orientation", "random");
  if (orientation != "random" && orientation != "aligned") {
    fail(o.path("orientation"), "must be \"random\" or \"aligned\" (got " + quote(orientation) + ")");
  }
  // Bounding radius of the largest body of each enabled kind; the default lattice spacing
  // keeps any two bodies apart whatever their orientation.
  double bound = 0;
  if (wBox > 0) bound = std::max(bound, std::sqrt(3.0) * sizeMax);
  if (wSphere > 0) bound = std::max(bound, sizeMax);
  if (wCapsule > 0) bound = std::max(bound, 1.5 * sizeMax);
  double spacing = o.number("spacing", float(2.1 * bound), Range::Positive);
  Material m = genMaterial(o, *b);
  bool walls = o.has("walls");
  GeneratorCounts c;
  c.bodies = uint64_t(count) + (walls ? 1 : 0);
  c.shapes = uint64_t(count) + (walls ? 4 : 0);
  c.maxShapesPerBody = walls ? 4 : 1;
  c.longestSuffix = std::max(indexSuffix(uint64_t(count)), size_t(walls ? 4 : 0));  // "/bin"
  if (!b->plan(o, prefix, c)) return;

  int64_t nx = std::max<int64_t>(1, int64_t(std::floor(2 * hx / spacing)));
  int64_t ny = std::max<int64_t>(1, int64_t(std::floor(2 * hy / spacing)));
  Rng rng(seed);
  double total = wBox + wSphere + wCapsule;
  for (int64_t i = 0; i < count; ++i) {
    int64_t layer = i / (nx * ny), cell = i % (nx * ny);
    int64_t ix = cell % nx, iy = cell / nx;
    double pick = rng.uniform() * total;
    ShapeGeom g;
    double radius;  // bounding radius, for the jitter
    if (pick < wBox) {
      Vec3 he = v3(rng.uniform(sizeMin, sizeMax), rng.uniform(sizeMin, sizeMax),
                   rng.uniform(sizeMin, sizeMax));
      g = ShapeGeom::box(he);
      radius = length(he);
    } else if (pick < wBox + wSphere) {
      g = ShapeGeom::sphere(float(rng.uniform(sizeMin, sizeMax)));
      radius = g.radius;
    } else {
      float cr = float(0.5 * rng.uniform(sizeMin, sizeMax));
      float hh = float(rng.uniform(sizeMin, sizeMax));
      g = ShapeGeom::capsule(cr, hh);
      radius = cr + hh;
    }
    double slack = std::max(0.0, 0.5 * spacing - radius);
    double jx = rng.uniform(-slack, slack), jy = rng.uniform(-slack, slack);
    Quat q = orientation == "random" ? rng.rotation() : Quat{};
    Vec3 p = v3(center.x + (double(ix) - 0.5 * double(nx - 1)) * spacing + jx,
                center.y + (double(iy) - 0.5 * double(ny - 1)) * spacing + jy,
                center.z + (double(layer) + 0.5) * spacing);
    BodyDef d = makeBody(prefix + "/" + std::to_string(i), BodyType::Dynamic, p, q);
    d.shapes.push_back(makeShape(g, m));
    b->addBody(std::move(d), path);
  }
  if (walls) {
    Object wo(*o.find("walls"), o.path("walls"), {"height", "thickness", "material"});
    double height = wo.number("height", 2.0f, Range::Positive);
    double t = wo.number("thickness", 0.2f, Range::Positive);
    Material wm = wo.has("material") ? b->material(*wo.find("material"), wo.path("material")) : m;
    // One static body with four wall boxes whose inner faces are at +-hx and +-hy.
    BodyDef d = makeBody(prefix + "/bin", BodyType::Static, center, Quat{});
    double zc = 0.5 * height;
    for (int side = -1; side <= 1; side += 2) {
      d.shapes.push_back(makeShape(ShapeGeom::box(v3(0.5 * t, hy + t, 0.5 * height)), wm,
                                   v3(side * (hx + 0.5 * t), 0, zc)));
      d.shapes.push_back(makeShape(ShapeGeom::box(v3(hx, 0.5 * t, 0.5 * height)), wm,
                                   v3(0, side * (hy + 0.5 * t), zc)));
    }
    b->addBody(std::move(d), path);
  }
}

// bridge: planks hinged end to end along +x between two static banks. With a span shorter
// than the chain the deck hangs as a catenary, so it starts at rest rather than stretched.
void genBridge(const Json& j, const std::string& path, Builder* b) {
  Object o(j, path,
           {"type", "name", "material", "planks", "plank_half_extents", "gap", "origin", "span",
            "joint", "plank_mass", "bank_length", "bank_material"});
  std::string prefix = o.string("name", "bridge");
  int64_t n = o.integer("planks", 1, 100000);
  Vec3 he = o.positiveVec3("plank_half_extents", Vec3{0.5f, 2.0f, 0.1f});
  double gap = o.number("gap", 0.02f, Range::NonNegative);
  Vec3 origin = readVec3(o.require("origin"), o.path("origin"));
  double link = 2.0 * he.x + gap;  // distance between consecutive joints along the deck
  double chain = double(n) * link;
  double span = o.number("span", float(chain), Range::Positive);
  if (span > chain * (1 + 1e-6)) {
    fail(o.path("span"), "must be at most the deck length " + std::to_string(chain) +
                             " m (planks * (2 * half_extents.x + gap))");
  }
  std::string jointType = o.string("joint", "hinge");
  if (jointType != "hinge" && jointType != "ball") {
    fail(o.path("joint"), "must be \"hinge\" or \"ball\" (got " + quote(jointType) + ")");
  }
  float plankMass = o.has("plank_mass") ? o.number("plank_mass", Range::Positive) : 0.0f;
  double bankLength = o.number("bank_length", 20.0f, Range::Positive);
  Material m = genMaterial(o, *b);
  Material bankMaterial = o.has("bank_material") ? genMaterial(o, *b, "bank_material") : m;
  GeneratorCounts c;
  c.bodies = c.shapes = uint64_t(n) + 2;
  c.joints = uint64_t(n) + 1;
  // "/bank/0", "/plank/<k>", "/joint/<k>" (k up to n).
  c.longestSuffix =
      std::max({size_t(7), 6 + indexSuffix(uint64_t(n)), 6 + indexSuffix(uint64_t(n) + 1)});
  if (!b->plan(o, prefix, c)) return;

  // Joint points P_k, k = 0..n, on the catenary z = a cosh(x / a) through both pins, spaced
  // by equal arc length `link` (x(s) = a asinh(s / a) for arc length s from the low point).
  std::vector<double> px(static_cast<size_t>(n + 1)), pz(static_cast<size_t>(n + 1));
  if (chain - span <= 1e-9 * chain) {
    for (int64_t k = 0; k <= n; ++k) px[size_t(k)] = double(k) * link, pz[size_t(k)] = 0;
  } else {
    // Solve 2 a sinh(span / 2a) = chain for a (decreasing in a) by bisection.
    auto excess = [&](double a) { return 2 * a * std::sinh(span / (2 * a)) - chain; };
    double lo = span, hi = span;
    while (excess(lo) < 0) lo *= 0.5;
    while (excess(hi) > 0) hi *= 2;
    for (int it = 0; it < 200; ++it) {
      double mid = 0.5 * (lo + hi);
      (excess(mid) > 0 ? lo : hi) = mid;
    }
    double a = 0.5 * (lo + hi), top = std::cosh(span / (2 * a));
    for (int64_t k = 0; k <= n; ++k) {
      double s = -0.5 * chain + double(k) * link;
      double x = a * std::asinh(s / a);
      px[size_t(k)] = x + 0.5 * span;
      pz[size_t(k)] = a * (std::cosh(x / a) - top);
    }
    px[size_t(n)] = span;  // exact pins despite rounding
    pz[0] = pz[size_t(n)] = 0;
  }
  auto point = [&](int64_t k) {
    return v3(origin.x + px[size_t(k)], origin.y, origin.z + pz[size_t(k)]);
  };

  // Banks: static boxes whose tops are flush with the deck top, ending at the pins.
  double bankHeight = std::max(0.5, double(origin.z) + he.z);
  Vec3 bankHe = v3(0.5 * bankLength, he.y, 0.5 * bankHeight);
  double bankZ = origin.z + he.z - 0.5 * bankHeight;
  int bank0 = b->addBody(
      [&] {
        BodyDef d = makeBody(prefix + "/bank/0", BodyType::Static,
                             v3(origin.x - 0.5 * bankLength, origin.y, bankZ), Quat{});
        d.shapes.push_back(makeShape(ShapeGeom::box(bankHe), bankMaterial));
        return d;
      }(),
      path);
  int bank1 = b->addBody(
      [&] {
        BodyDef d = makeBody(prefix + "/bank/1", BodyType::Static,
                             v3(origin.x + span + 0.5 * bankLength, origin.y, bankZ), Quat{});
        d.shapes.push_back(makeShape(ShapeGeom::box(bankHe), bankMaterial));
        return d;
      }(),
      path);
  int first = int(b->bodies->size());
  std::vector<float> halfChord(static_cast<size_t>(n));
  for (int64_t k = 0; k < n; ++k) {
    Vec3 p0 = point(k), p1 = point(k + 1);
    Vec3 d = p1 - p0;
    float c = length(d);
    halfChord[size_t(k)] = 0.5f * c;
    // Pitch about +y: rotating x by theta about y gives (cos, 0, -sin).
    float theta = std::atan2(-d.z, d.x);
    BodyDef body = boxBody(prefix + "/plank/" + std::to_string(k), (p0 + p1) * 0.5f, he, m,
                           Quat::fromAxisAngle(Vec3{0, 1, 0}, theta));
    body.mass = plankMass;
    b->addBody(std::move(body), path);
  }
  auto joint = [&](int64_t k, int bodyA, Vec3 anchorA, int bodyB, Vec3 anchorB) {
    SceneJoint sj;
    sj.def.type = jointType == "hinge" ? JointType::Hinge : JointType::Ball;
    sj.def.name = prefix + "/joint/" + std::to_string(k);
    sj.def.anchorA = anchorA;
    sj.def.anchorB = anchorB;
    sj.def.axisA = sj.def.axisB = Vec3{0, 1, 0};  // plank rotations are about y only
    sj.bodyA = bodyA;
    sj.bodyB = bodyB;
    b->generatedJoints.push_back(std::move(sj));
  };
  const BodyDef& b0 = (*b->bodies)[size_t(bank0)];
  const BodyDef& b1 = (*b->bodies)[size_t(bank1)];
  joint(0, bank0, point(0) - b0.position, first, Vec3{-halfChord[0], 0, 0});
  for (int64_t k = 1; k < n; ++k) {
    joint(k, first + int(k - 1), Vec3{halfChord[size_t(k - 1)], 0, 0}, first + int(k),
          Vec3{-halfChord[size_t(k)], 0, 0});
  }
  joint(n, first + int(n - 1), Vec3{halfChord[size_t(n - 1)], 0, 0}, bank1, point(n) - b1.position);
}

// car: a box chassis and four sphere wheels on motorized hinges; drives along +x rotated by
// yaw. Wheel order: front left, front right, rear left, rear right.
void genCar(const Json& j, const std::string& path, Builder* b) {
  Object o(j, path,
           {"type", "name", "material", "wheel_material", "position", "yaw", "chassis_half_extents",
            "chassis_mass", "wheel_radius", "wheel_mass", "wheel_base", "track", "wheel_drop",
            "motor_speed", "max_torque"});
  std::string prefix = o.string("name", "car");
  Vec3 pos = readVec3(o.require("position"), o.path("position"));
  float yaw = o.number("yaw", 0.0f);
  Vec3 che = o.positiveVec3("chassis_half_extents", Vec3{1.5f, 0.8f, 0.25f});
  float chassisMass = o.has("chassis_mass") ? o.number("chassis_mass", Range::Positive) : 0.0f;
  float wheelR = o.number("wheel_radius", 0.4f, Range::Positive);
  float wheelMass = o.has("wheel_mass") ? o.number("wheel_mass", Range::Positive) : 0.0f;
  float wheelBase = o.number("wheel_base", 2.4f, Range::Positive);
  float track = o.number("track", 2.2f, Range::Positive);
  float drop = o.number("wheel_drop", 0.2f);
  float speed = o.number("motor_speed", 10.0f);
  float torque = o.number("max_torque", 500.0f, Range::NonNegative);
  Material m = genMaterial(o, *b);
  Material wm = o.has("wheel_material") ? genMaterial(o, *b, "wheel_material") : m;
  GeneratorCounts counts;
  counts.bodies = counts.shapes = 5;
  counts.joints = 4;
  counts.longestSuffix = 8;  // "/chassis", "/wheel/3", "/axle/3"
  if (!b->plan(o, prefix, counts)) return;

  Quat q = Quat::fromAxisAngle(Vec3{0, 0, 1}, yaw);
  BodyDef chassis = boxBody(prefix + "/chassis", pos, che, m, q);
  chassis.mass = chassisMass;
  int c = b->addBody(std::move(chassis), path);
  const Vec3 offsets[4] = {{0.5f * wheelBase, 0.5f * track, -drop},
                           {0.5f * wheelBase, -0.5f * track, -drop},
                           {-0.5f * wheelBase, 0.5f * track, -drop},
                           {-0.5f * wheelBase, -0.5f * track, -drop}};
  for (int i = 0; i < 4; ++i) {
    BodyDef w = makeBody(prefix + "/wheel/" + std::to_string(i), BodyType::Dynamic,
                         pos + rotate(q, offsets[i]), q);
    w.shapes.push_back(makeShape(ShapeGeom::sphere(wheelR), wm));
    w.mass = wheelMass;
    int wi = b->addBody(std::move(w), path);
    // The motor drives (w_wheel - w_chassis) . axis; about +y (left) that rolls it forward.
    SceneJoint sj;
    sj.def.type = JointType::Hinge;
    sj.def.name = prefix + "/axle/" + std::to_string(i);
    sj.def.anchorA = offsets[i];
    sj.def.anchorB = Vec3{};
    sj.def.axisA = sj.def.axisB = Vec3{0, 1, 0};
    sj.def.enableMotor = true;
    sj.def.motorSpeed = speed;
    sj.def.maxMotorForce = torque;
    sj.bodyA = c;
    sj.bodyB = wi;
    b->generatedJoints.push_back(std::move(sj));
  }
}

// windmill: one rotor body (hub sphere + box blades) on a motorized hinge to the world.
void genWindmill(const Json& j, const std::string& path, Builder* b) {
  Object o(j, path,
           {"type", "name", "material", "hub", "axis", "blades", "blade_length", "blade_width",
            "blade_thickness", "hub_radius", "start_angle", "motor_speed", "max_torque"});
  std::string prefix = o.string("name", "windmill");
  Vec3 hub = readVec3(o.require("hub"), o.path("hub"));
  Vec3 axis = o.direction("axis", Vec3{0, 1, 0});
  int64_t blades = o.integer("blades", 4, 1, 64);
  float bladeLength = o.number("blade_length", 3.0f, Range::Positive);
  float width = o.number("blade_width", 0.6f, Range::Positive);
  float thickness = o.number("blade_thickness", 0.1f, Range::Positive);
  float hubRadius = o.number("hub_radius", 0.3f, Range::Positive);
  double start = o.number("start_angle", 0.0f);
  float speed = o.number("motor_speed", 1.0f);
  float torque = o.number("max_torque", 1e5f, Range::NonNegative);
  Material m = genMaterial(o, *b);
  GeneratorCounts c;
  c.bodies = c.joints = 1;
  c.shapes = c.maxShapesPerBody = 1 + uint64_t(blades);  // the hub and the blades
  c.longestSuffix = 6;                                   // "/rotor", "/hinge"
  if (!b->plan(o, prefix, c)) return;

  // Blade i points along cos(phi) u + sin(phi) v, phi = start + 2 pi i / blades, with
  // u = axis x z (horizontal for a horizontal axis) and v = axis x u.
  Vec3 u = cross(axis, Vec3{0, 0, 1});
  if (lengthSquared(u) < 1e-6f) u = cross(axis, Vec3{1, 0, 0});
  u = normalize(u);
  Vec3 v = cross(axis, u);
  BodyDef rotor = makeBody(prefix + "/rotor", BodyType::Dynamic, hub, Quat{});
  rotor.shapes.push_back(makeShape(ShapeGeom::sphere(hubRadius), m));
  for (int64_t i = 0; i < blades; ++i) {
    double phi = start + 2.0 * double(kPi) * double(i) / double(blades);
    Vec3 radial = normalize(u * float(std::cos(phi)) + v * float(std::sin(phi)));
    Vec3 tangent = cross(axis, radial);
    // Thin along the sweep direction, wide along the axis: the blade's face pushes.
    rotor.shapes.push_back(
        makeShape(ShapeGeom::box(Vec3{0.5f * bladeLength, 0.5f * thickness, 0.5f * width}), m,
                  radial * (0.5f * bladeLength), quatFromBasis(radial, tangent, axis)));
  }
  int r = b->addBody(std::move(rotor), path);
  SceneJoint sj;
  sj.def.type = JointType::Hinge;
  sj.def.name = prefix + "/hinge";
  sj.def.anchorA = hub;
  sj.def.anchorB = Vec3{};
  sj.def.axisA = sj.def.axisB = axis;
  sj.def.enableMotor = true;
  sj.def.motorSpeed = speed;
  sj.def.maxMotorForce = torque;
  sj.bodyA = -1;
  sj.bodyB = r;
  b->generatedJoints.push_back(std::move(sj));
}

}  // namespace

void runGenerator(const Json& j, const std::string& path, Builder* b) {
  std::string type = typeOf(j, path);
  if (type == "pyramid") return genPyramid(j, path, b);
  if (type == "pyramid_grid") return genPyramidGrid(j, path, b);
  if (type == "stack") return genStack(j, path, b);
  if (type == "grid") return genGrid(j, path, b);
  if (type == "chain") return genChain(j, path, b);
  if (type == "pile") return genPile(j, path, b);
  if (type == "bridge") return genBridge(j, path, b);
  if (type == "car") return genCar(j, path, b);
  if (type == "windmill") return genWindmill(j, path, b);
  fail(member(path, "type"),
       "unknown generator " + quote(type) +
           " (known: pyramid, pyramid_grid, stack, grid, chain, pile, bridge, car, windmill)");
}

}  // namespace phys::scene_detail
