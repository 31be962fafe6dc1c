// The attacks of issue 21 as payload builders, shared by the core tests (test_budgets.cpp) and
// the daemon test (test_physd_attacks.cpp). Each was reproduced against physd before the fix:
// a hang, a crash or gigabytes from one small message.
#pragma once

#include <cmath>
#include <random>
#include <string>
#include <vector>

#include "phys/protocol/builder.h"

namespace phys::server::test::attacks {

/// 40 bodies named a, aa, ...; a metrics pattern of 16 "*a" then "*b" (exponential backtracking).
inline std::string backtrackingPattern() {
  std::string json = R"({"bodies": [)";
  for (int i = 0; i < 40; ++i)
    json += std::string(i ? "," : "") + R"({"name": "a)" + std::string(size_t(i), 'a') +
            R"(", "shapes": [{"type": "sphere", "radius": 0.5}], "position": [0, 0, )" +
            std::to_string(2 * i) + "]}";
  std::string pattern;
  for (int i = 0; i < 16; ++i) pattern += "*a";
  pattern += "*b";
  return json + R"(], "metrics": {"top_bodies": [")" + pattern + R"("]}})";
}

/// A pattern of 1.5 million '*' and an x (stack overflow in a recursive matcher).
inline std::string millionStars() {
  return R"({"bodies": [{"name": "a", "shapes": [{"type": "sphere", "radius": 0.5}]}],)"
         R"( "metrics": {"top_bodies": [")" +
         std::string(1500000, '*') + R"(x"]}})";
}

/// A pile of 10,000 with a 256 KiB generator name (copied into every body).
inline std::string longGeneratorName() {
  return R"({"generators": [{"type": "pile", "name": ")" + std::string(256 << 10, 'n') +
         R"(", "count": 10000, "seed": 1, "half_extents": [15, 15]}]})";
}

/// A 1 MiB key over 300,000 empty arrays (JSON paths copied per array).
inline std::string hugeKey() {
  std::string json = "{\"" + std::string(1 << 20, 'k') + "\": [";
  for (int i = 0; i < 300000; ++i) json += i ? ",[]" : "[]";
  return json + "]}";
}

/// 41 stack generators of 100,000 (counted only after they were built).
inline std::string manyGenerators() {
  std::string json = R"({"generators": [)";
  for (int i = 0; i < 41; ++i)
    json += std::string(i ? "," : "") + R"({"type": "stack", "name": "s)" + std::to_string(i) +
            R"(", "count": 100000})";
  return json + "]}";
}

/// A pile of 600,000 (more new ids than one reply holds).
inline std::string bigPile() {
  return R"({"generators": [{"type": "pile", "name": "p", "count": 600000, "seed": 1,)"
         R"( "half_extents": [100, 100]}]})";
}

/// A SpawnBodies whose `bodies` entries all point at one BodyDef table, whose `shapes` all
/// point at one ShapeDef with one hull of `points` points. `padBytes` of unreferenced data
/// raise the Verifier's table budget (bytes / 8), as the attacker did with 1 MiB.
inline protocol::Bytes sharedSpawn(uint64_t client, uint64_t seq, uint32_t world, int bodies,
                                   int shapes, int points, size_t padBytes = 1 << 20) {
  flatbuffers::FlatBufferBuilder fbb;
  fbb.CreateVector(std::vector<uint8_t>(padBytes, 0));
  std::mt19937 rng(7);
  std::normal_distribution<float> n;
  std::vector<wire::Vec3> pts;
  for (int i = 0; i < points; ++i) {
    float x = n(rng), y = n(rng), z = n(rng), l = std::sqrt(x * x + y * y + z * z);
    pts.emplace_back(x / l, y / l, z / l);
  }
  auto hull = wire::CreateConvexHull(fbb, fbb.CreateVectorOfStructs(pts));
  auto shape = wire::CreateShapeDef(fbb, wire::Shape::ConvexHull, hull.Union());
  std::vector<flatbuffers::Offset<wire::ShapeDef>> shapeRefs(size_t(shapes), shape);
  auto shapeVec = fbb.CreateVector(shapeRefs);
  wire::BodyDefBuilder bb(fbb);
  bb.add_shapes(shapeVec);
  auto body = bb.Finish();
  std::vector<flatbuffers::Offset<wire::BodyDef>> bodyRefs(size_t(bodies), body);
  auto spawn = wire::CreateSpawnBodies(fbb, fbb.CreateVector(bodyRefs));
  auto cmd = wire::CreateCommand(fbb, client, seq, world, wire::Request::SpawnBodies,
                                 spawn.Union());
  fbb.Finish(cmd, "PHCM");
  return protocol::Bytes(fbb.GetBufferPointer(), fbb.GetBufferPointer() + fbb.GetSize());
}

/// n boxes of 2 m at one point (every pair overlaps).
inline std::vector<phys::BodyDef> coincidentBoxes(int n) {
  phys::BodyDef d;
  phys::ShapeDef s;
  s.geom = phys::ShapeGeom::box({1, 1, 1});
  d.shapes.push_back(s);
  d.position = {0, 0, 5};
  return std::vector<phys::BodyDef>(size_t(n), d);
}

/// n separated 1 m boxes on a grid.
inline std::vector<phys::BodyDef> gridBoxes(int n) {
  std::vector<phys::BodyDef> v;
  phys::BodyDef d;
  phys::ShapeDef s;
  s.geom = phys::ShapeGeom::box({0.5f, 0.5f, 0.5f});
  d.shapes.push_back(s);
  for (int i = 0; i < n; ++i) {
    d.position = {float(i % 150) * 3, float(i / 150) * 3, 1};
    v.push_back(d);
  }
  return v;
}

}  // namespace phys::server::test::attacks
