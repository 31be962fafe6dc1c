// Boxes meeting nearly face to face across a rim. The separating-axis test finds an edge pair
// there (the two rims cross), but one point at the crossing cannot hold the rest of the face: a
// box tumbling onto another swung its face through the other within a step, which is how piles
// and bins came to rest with centimetres of penetration while aligned pyramids kept millimetres.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "phys/collision/shapes.h"
#include "phys/world/world.h"

namespace phys {
namespace {

constexpr uint32_t kEdgeEdgeKind = 2;

Transform at(Vec3 p, Quat q = {}) {
  return {p, q};
}

float deepest(const Manifold& m) {
  float s = std::numeric_limits<float>::infinity();
  for (int i = 0; i < m.count; ++i) s = std::min(s, m.points[i].separation);
  return s;
}

std::shared_ptr<const ConvexHull> boxHull(Vec3 he) {
  std::vector<Vec3> pts;
  for (int i = 0; i < 8; ++i)
    pts.push_back({(i & 1) ? he.x : -he.x, (i & 2) ? he.y : -he.y, (i & 4) ? he.z : -he.z});
  std::string error;
  auto h = buildConvexHull(pts, &error);
  EXPECT_TRUE(h) << error;
  return h;
}

// A cube tilted 0.04 rad about x, and above it one turned 0.2 rad about z and shifted over the
// lower one's +x rim: the two top/bottom faces are 2.3 degrees apart and the rims cross at
// (0.5, -0.03, 0.50). Edge axis and faces disagree on the gap, the face (with its clipped
// points) is what holds the upper cube.
TEST(DeepContacts, NearlyParallelFacesAcrossARimGiveAFaceManifold) {
  ShapeGeom cube = ShapeGeom::box({0.5f, 0.5f, 0.5f});
  ShapeGeom hull = ShapeGeom::convexHull(boxHull({0.5f, 0.5f, 0.5f}));
  Transform xa = at({}, Quat::fromAxisAngle({1, 0, 0}, -0.04f));
  Vec3 upA = rotate(xa.q, {0, 0, 1});
  // The gap at the rim crossing (edge-edge distance) for each height: 4.4 mm apart, 1.6 mm and
  // 6.6 mm deep.
  const float heights[] = {1.006f, 1.0f, 0.995f};
  const float rimGap[] = {0.00443f, -0.00156f, -0.00656f};
  for (int k = 0; k < 3; ++k) {
    Transform xb = at({0.9f, 0.4f, heights[k]}, Quat::fromAxisAngle({0, 0, 1}, -0.2f));
    for (bool swap : {false, true}) {
      for (bool asHull : {false, true}) {
        SCOPED_TRACE(testing::Message()
                     << "z " << heights[k] << (swap ? " swapped" : "") << (asHull ? " hull" : ""));
        const ShapeGeom& g = asHull ? hull : cube;
        Manifold m;
        ASSERT_TRUE(swap ? collide(g, xb, g, xa, 0.02f, &m) : collide(g, xa, g, xb, 0.02f, &m));
        // Before: one edge-edge point at the crossing.
        EXPECT_GE(m.count, 2);
        for (int i = 0; i < m.count; ++i)
          EXPECT_NE(m.points[i].featureId >> 30, kEdgeEdgeKind) << "point " << i;
        // The rim crossing stays the deepest point, at its true gap or depth.
        EXPECT_NEAR(deepest(m), rimGap[k], 1e-4f);
        // The normal is one of the two faces' (2.3 degrees apart), pointing from the first
        // shape to the second.
        EXPECT_GT(std::fabs(dot(m.normal, upA)), 0.998f);
        EXPECT_GT(dot(m.normal, swap ? -upA : upA), 0);
      }
    }
  }
}

// Cubes lowered onto a cube until they first come within 1 cm, both tilted up to 0.05 rad
// (about 3 degrees) and turned and shifted at random: nearly flat landings. Almost every one
// meets face to face with two or more points; before, four in ten got a single edge point.
TEST(DeepContacts, NearlyFlatLandingsGetMoreThanOnePoint) {
  ShapeGeom cube = ShapeGeom::box({0.5f, 0.5f, 0.5f});
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(-1, 1);
  int landings = 0, single = 0;
  for (int k = 0; k < 2000; ++k) {
    Quat qa = Quat::fromAxisAngle(normalize(Vec3{u(rng), u(rng), 0}), 0.05f * u(rng));
    Quat qb = Quat::fromAxisAngle(normalize(Vec3{u(rng), u(rng), 0}), 0.05f * u(rng)) *
              Quat::fromAxisAngle({0, 0, 1}, u(rng));
    Vec3 offset{u(rng), u(rng), 0};
    for (float z = 1.3f; z > 0.9f; z -= 0.0005f) {
      Manifold m;
      if (!collide(cube, at({}, qa), cube, at(offset + Vec3{0, 0, z}, qb), 0.05f, &m)) continue;
      if (deepest(m) > 0.01f) continue;
      ++landings;
      single += m.count == 1;
      break;
    }
  }
  ASSERT_GT(landings, 1900);
  EXPECT_LT(single, landings / 20) << single << " of " << landings << " single-point";
}

// The same rim crossing in a world: the upper cube falls onto the tilted static one and must
// not sink into it. With one rim point its face swung 1.7 cm (at 3 m/s) to 3.2 cm (6 m/s) deep.
TEST(DeepContacts, CubeFallingFlatAcrossARimStaysOut) {
  for (float speed : {3.0f, 6.0f}) {
    SCOPED_TRACE(testing::Message() << "falling at " << speed << " m/s");
    World w;
    ShapeDef s;
    s.geom = ShapeGeom::box({0.5f, 0.5f, 0.5f});
    BodyDef a;
    a.type = BodyType::Static;
    a.rotation = Quat::fromAxisAngle({1, 0, 0}, -0.04f);
    a.shapes.push_back(s);
    BodyDef b;
    b.position = {0.9f, 0.4f, 1.05f};
    b.rotation = Quat::fromAxisAngle({0, 0, 1}, -0.2f);
    b.linearVelocity = {0, 0, -speed};
    b.shapes.push_back(s);
    BodyId ia, ib;
    ASSERT_TRUE(w.createBody(a, &ia).ok());
    ASSERT_TRUE(w.createBody(b, &ib).ok());
    double worst = 0;
    for (int i = 0; i < 90; ++i) {
      w.step();
      worst = std::max(worst, w.stats().maxPenetration);
    }
    EXPECT_LT(worst, 0.005);
  }
}

}  // namespace
}  // namespace phys
