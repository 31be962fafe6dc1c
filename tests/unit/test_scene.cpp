// Scene files: parsing, error messages, generators, round trip, the shipped scenes, and
// instantiation into a World.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "../common/solver_fields.h"
#include "phys/scene/metrics.h"
#include "phys/scene/scene.h"
#include "phys/world/world.h"
#include "test_util.h"

namespace phys {
namespace {

// ------------------------------------------------------------------------------------------
// Helpers

Scene parseOk(const std::string& json) {
  Scene s;
  Status st = parseScene(json, "test.json", &s);
  EXPECT_TRUE(st.ok()) << st.message;
  return s;
}

/// Parses `json`, expects InvalidArgument and returns the message.
std::string parseError(const std::string& json) {
  Scene s;
  Status st = parseScene(json, "test.json", &s);
  EXPECT_FALSE(st.ok()) << "parsed although it should not:\n" << json;
  EXPECT_EQ(st.code, StatusCode::InvalidArgument) << st.message;
  EXPECT_EQ(st.message.rfind("test.json: ", 0), 0u)
      << "message must start with the source: " << st.message;
  return st.message;
}

#define EXPECT_CONTAINS(haystack, needle)                          \
  EXPECT_NE(std::string(haystack).find(needle), std::string::npos) \
      << "expected \"" << (needle) << "\" in: " << (haystack)

int countNamed(const Scene& s, const std::string& prefix) {
  return int(std::count_if(s.bodies.begin(), s.bodies.end(),
                           [&](const BodyDef& b) { return b.name.rfind(prefix, 0) == 0; }));
}

int bodyIndex(const Scene& s, const std::string& name) {
  for (size_t i = 0; i < s.bodies.size(); ++i) {
    if (s.bodies[i].name == name) return int(i);
  }
  ADD_FAILURE() << "no body " << name;
  return -1;
}

Vec3 worldAnchor(const Scene& s, int body, Vec3 local) {
  if (body < 0) return local;
  const BodyDef& b = s.bodies[size_t(body)];
  return b.position + rotate(b.rotation, local);
}

AABB bodyBox(const BodyDef& b) {
  AABB box{{1e30f, 1e30f, 1e30f}, {-1e30f, -1e30f, -1e30f}};
  for (const ShapeDef& sd : b.shapes) {
    Transform xf = Transform{b.position, b.rotation} * sd.local;
    Vec3 e;
    switch (sd.geom.type) {
      case ShapeType::Sphere:
        e = {sd.geom.radius, sd.geom.radius, sd.geom.radius};
        break;
      case ShapeType::Box: {
        Mat3 r = toMat3(xf.q);
        Vec3 h = sd.geom.halfExtents;
        e = vabs(r.c0) * h.x + vabs(r.c1) * h.y + vabs(r.c2) * h.z;
        break;
      }
      default: {
        float l = sd.geom.radius + sd.geom.halfHeight;
        e = {l, l, l};
      }
    }
    box = merge(box, AABB{xf.p - e, xf.p + e});
  }
  return box;
}

bool sameVec(Vec3 a, Vec3 b) {
  return a == b;
}

// Field-by-field comparison of two scenes (bit-exact floats).
void expectSameScene(const Scene& a, const Scene& b) {
  EXPECT_EQ(a.name, b.name);
  EXPECT_EQ(a.description, b.description);
  EXPECT_EQ(a.duration, b.duration);
  const WorldDef &wa = a.world, &wb = b.world;
  EXPECT_TRUE(sameVec(wa.gravity, wb.gravity));
  EXPECT_EQ(wa.timeStep, wb.timeStep);
  EXPECT_EQ(wa.maxLinearSpeed, wb.maxLinearSpeed);
  EXPECT_EQ(wa.maxAngularSpeed, wb.maxAngularSpeed);
  EXPECT_EQ(wa.speculativeDistance, wb.speculativeDistance);
  EXPECT_EQ(wa.aabbMargin, wb.aabbMargin);
  phys::test::expectSameSettings(wa.solver, wb.solver, "solver");

  ASSERT_EQ(a.bodies.size(), b.bodies.size());
  for (size_t i = 0; i < a.bodies.size(); ++i) {
    SCOPED_TRACE("body " + std::to_string(i) + " " + a.bodies[i].name);
    const BodyDef &x = a.bodies[i], &y = b.bodies[i];
    EXPECT_EQ(x.name, y.name);
    EXPECT_EQ(x.type, y.type);
    EXPECT_TRUE(sameVec(x.position, y.position));
    EXPECT_TRUE(x.rotation == y.rotation);
    EXPECT_TRUE(sameVec(x.linearVelocity, y.linearVelocity));
    EXPECT_TRUE(sameVec(x.angularVelocity, y.angularVelocity));
    EXPECT_EQ(x.linearDamping, y.linearDamping);
    EXPECT_EQ(x.angularDamping, y.angularDamping);
    EXPECT_EQ(x.gravityScale, y.gravityScale);
    EXPECT_EQ(x.mass, y.mass);
    EXPECT_TRUE(sameVec(x.inertia, y.inertia));
    EXPECT_EQ(x.gyroscopic, y.gyroscopic);
    ASSERT_EQ(x.shapes.size(), y.shapes.size());
    for (size_t k = 0; k < x.shapes.size(); ++k) {
      const ShapeDef &p = x.shapes[k], &q = y.shapes[k];
      EXPECT_EQ(p.geom.type, q.geom.type);
      switch (p.geom.type) {
        case ShapeType::Sphere:
          EXPECT_EQ(p.geom.radius, q.geom.radius);
          break;
        case ShapeType::Box:
          EXPECT_TRUE(sameVec(p.geom.halfExtents, q.geom.halfExtents));
          break;
        case ShapeType::Capsule:
          EXPECT_EQ(p.geom.radius, q.geom.radius);
          EXPECT_EQ(p.geom.halfHeight, q.geom.halfHeight);
          break;
        case ShapeType::Plane:
          EXPECT_TRUE(sameVec(p.geom.normal, q.geom.normal));
          EXPECT_EQ(p.geom.offset, q.geom.offset);
          break;
        case ShapeType::Hull: {
          ASSERT_TRUE(p.geom.hull && q.geom.hull);
          auto key = [](Vec3 v) { return std::tuple(v.x, v.y, v.z); };
          std::set<std::tuple<float, float, float>> vp, vq;
          for (Vec3 v : p.geom.hull->vertices) vp.insert(key(v));
          for (Vec3 v : q.geom.hull->vertices) vq.insert(key(v));
          EXPECT_EQ(vp, vq);
          break;
        }
      }
      EXPECT_TRUE(sameVec(p.local.p, q.local.p));
      EXPECT_TRUE(p.local.q == q.local.q);
      EXPECT_EQ(p.material.friction, q.material.friction);
      EXPECT_EQ(p.material.restitution, q.material.restitution);
      EXPECT_EQ(p.material.density, q.material.density);
    }
  }
  ASSERT_EQ(a.joints.size(), b.joints.size());
  for (size_t i = 0; i < a.joints.size(); ++i) {
    SCOPED_TRACE("joint " + std::to_string(i));
    const SceneJoint &x = a.joints[i], &y = b.joints[i];
    EXPECT_EQ(x.bodyA, y.bodyA);
    EXPECT_EQ(x.bodyB, y.bodyB);
    const JointDef &p = x.def, &q = y.def;
    EXPECT_EQ(p.type, q.type);
    EXPECT_EQ(p.name, q.name);
    EXPECT_TRUE(sameVec(p.anchorA, q.anchorA));
    EXPECT_TRUE(sameVec(p.anchorB, q.anchorB));
    EXPECT_TRUE(sameVec(p.axisA, q.axisA));
    EXPECT_TRUE(sameVec(p.axisB, q.axisB));
    EXPECT_EQ(p.enableLimit, q.enableLimit);
    EXPECT_EQ(p.lower, q.lower);
    EXPECT_EQ(p.upper, q.upper);
    EXPECT_EQ(p.enableMotor, q.enableMotor);
    EXPECT_EQ(p.motorSpeed, q.motorSpeed);
    EXPECT_EQ(p.maxMotorForce, q.maxMotorForce);
    EXPECT_EQ(p.length, q.length);
    EXPECT_EQ(p.springHertz, q.springHertz);
    EXPECT_EQ(p.springDampingRatio, q.springDampingRatio);
    EXPECT_EQ(p.collideConnected, q.collideConnected);
  }
  EXPECT_EQ(a.metrics.topBodies, b.metrics.topBodies);
  EXPECT_EQ(a.metrics.settleTime, b.metrics.settleTime);
  EXPECT_EQ(a.metrics.conservesEnergy, b.metrics.conservesEnergy);
  EXPECT_EQ(a.metrics.groups, b.metrics.groups);
  EXPECT_EQ(a.metrics.params, b.metrics.params);
  ASSERT_EQ(a.criteria.size(), b.criteria.size());
  for (size_t i = 0; i < a.criteria.size(); ++i) {
    EXPECT_EQ(a.criteria[i].metric, b.criteria[i].metric);
    EXPECT_EQ(a.criteria[i].min, b.criteria[i].min);
    EXPECT_EQ(a.criteria[i].max, b.criteria[i].max);
  }
}

const char* kGround = R"({"name": "ground", "type": "static", "shapes": [{"type": "plane"}]})";

// A scene using every feature of the format.
const std::string kRich = std::string(R"({
  // comments are allowed
  "name": "rich",
  "description": "every feature",
  "gravity": [0, 0.5, -9.8],
  "time_step": 0.004,
  "duration": 3.5,
  "solver": {"substeps": 2, "iterations": 7, "relax_iterations": 0, "stabilization": "baumgarte",
             "baumgarte": 0.3, "contact_hertz": 25, "contact_damping_ratio": 5, "joint_hertz": 50,
             "joint_damping_ratio": 1, "max_pushout": 2, "linear_slop": 0.01, "warm_start": false,
             "restitution": false, "restitution_threshold": 0.5},
  "world": {"max_linear_speed": 500, "max_angular_speed": 100, "speculative_distance": 0.03,
            "aabb_margin": 0.1},
  "materials": {"default": {"friction": 0.4}, "ice": {"friction": 0.02, "restitution": 0.1},
                "steel": {"friction": 0.5, "density": 7800}},
  "bodies": [
    )") + kGround + R"(,
    {"name": "a", "position": [1, 2, 3], "rotation": [0, 0, 0.7071068, 0.7071068],
     "linear_velocity": [1, 0, 0], "angular_velocity": [0, 0.1, 0], "linear_damping": 0.1,
     "angular_damping": 0.2, "gravity_scale": 0.5, "mass": 3, "inertia": [1, 2, 3],
     "gyroscopic": false, "material": "ice",
     "shapes": [{"type": "box", "half_extents": [0.5, 0.25, 0.125]},
                {"type": "sphere", "radius": 0.3, "position": [0, 0, 1], "material": "steel"},
                {"type": "capsule", "radius": 0.1, "half_height": 0.4,
                 "rotation_axis_angle": [1, 0, 0, 1.5707963]},
                {"type": "hull", "points": [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]],
                 "material": {"friction": 0.9, "restitution": 0.3, "density": 500}}]},
    {"name": "k", "type": "kinematic", "position": [0, 5, 1], "linear_velocity": [0, 1, 0],
     "shapes": [{"type": "sphere", "radius": 0.5}]},
    {"position": [3, 0, 1], "shapes": [{"type": "sphere", "radius": 0.25}]},
    {"name": "wall", "type": "static", "shapes": [{"type": "plane", "normal": [1, 0, 0],
                                                    "offset": -10}]}
  ],
  "generators": [
    {"type": "pyramid", "base": 3, "origin": [10, 0, 0], "material": "ice"},
    {"type": "chain", "links": 3, "anchor": [0, -5, 5], "end_ball": {"radius": 0.2, "mass": 5}}
  ],
  "joints": [
    {"type": "ball", "name": "j0", "body_a": "a", "body_b": "k", "anchor_world": [0.5, 3, 2]},
    {"type": "hinge", "body_a": null, "body_b": "a", "anchor_a": [1, 2, 4], "anchor_b": [0, 0, 1],
     "axis_world": [0, 1, 0], "limit": {"lower": -0.5, "upper": 0.5},
     "motor": {"speed": 2, "max_force": 10}},
    {"type": "prismatic", "body_a": "k", "body_b": 3, "axis_a": [1, 0, 0], "axis_b": [0, 1, 0],
     "limit": {"lower": -1, "upper": 1, "enabled": false}, "collide_connected": true},
    {"type": "distance", "body_a": "pyramid/0", "body_b": "chain/ball", "length": 2,
     "spring_hertz": 3, "spring_damping_ratio": 0.5, "limit": {"lower": 1, "upper": 3}},
    {"type": "fixed", "body_a": "chain/0", "body_b": "chain/1", "anchor_world": [0.75, -5, 5]}
  ],
  "metrics": {"top_bodies": ["pyramid/5"], "settle_time": 2, "conserves_energy": true,
              "groups": {"links": ["chain/*"], "pair": ["a", 3]},
              "params": {"finish_x": 12.5}},
  "criteria": [{"metric": "top_drift", "max": 0.01}, {"metric": "nan", "max": 0},
               {"metric": "energy_drift", "min": -0.1, "max": 0.1}]
})";

// ------------------------------------------------------------------------------------------
// Parsing and round trip

TEST(Scene, DefaultsOfAMinimalScene) {
  Scene s = parseOk(R"({"name": "m", "bodies": [)" + std::string(kGround) + "]}");
  EXPECT_EQ(s.name, "m");
  EXPECT_TRUE(sameVec(s.world.gravity, Vec3(0, 0, -9.81f)));
  EXPECT_FLOAT_EQ(s.world.timeStep, 1.0f / 60);
  EXPECT_EQ(s.duration, 10);
  ASSERT_EQ(s.bodies.size(), 1u);
  EXPECT_EQ(s.bodies[0].type, BodyType::Static);
  EXPECT_EQ(s.bodies[0].shapes[0].geom.type, ShapeType::Plane);
  EXPECT_TRUE(sameVec(s.bodies[0].shapes[0].geom.normal, Vec3(0, 0, 1)));
  EXPECT_EQ(s.bodies[0].shapes[0].material.friction, Material().friction);
  EXPECT_EQ(s.world.solver.substeps, SolverSettings().substeps);
}

TEST(Scene, ParsesEveryFeature) {
  Scene s = parseOk(kRich);
  EXPECT_EQ(s.world.solver.stabilization, SolverSettings::Stabilization::Baumgarte);
  EXPECT_EQ(s.world.solver.iterations, 7);
  EXPECT_FLOAT_EQ(s.world.aabbMargin, 0.1f);
  // 5 explicit + 6 pyramid boxes + 3 links + ball.
  ASSERT_EQ(s.bodies.size(), 5u + 6u + 4u);
  const BodyDef& a = s.bodies[1];
  EXPECT_EQ(a.shapes[0].material.friction, 0.02f);           // the body's material
  EXPECT_EQ(a.shapes[1].material.density, 7800.0f);          // the shape's own
  EXPECT_EQ(a.shapes[3].material.restitution, 0.3f);         // inline
  EXPECT_EQ(s.bodies[2].shapes[0].material.friction, 0.4f);  // "default" material
  EXPECT_EQ(s.bodies[bodyIndex(s, "pyramid/0")].shapes[0].material.friction, 0.02f);
  EXPECT_FALSE(a.gyroscopic);
  EXPECT_EQ(s.bodies[4].shapes[0].geom.offset, -10.0f);
  // Explicit joints first, then the chain's 4.
  ASSERT_EQ(s.joints.size(), 5u + 4u);
  // anchor_world: both local anchors map to the same world point.
  const SceneJoint& j0 = s.joints[0];
  Vec3 pa = worldAnchor(s, j0.bodyA, j0.def.anchorA), pb = worldAnchor(s, j0.bodyB, j0.def.anchorB);
  EXPECT_NEAR(pa.x, 0.5f, 1e-5f);
  EXPECT_NEAR(pa.y, 3.0f, 1e-5f);
  EXPECT_NEAR(pb.z, 2.0f, 1e-5f);
  EXPECT_NEAR(length(pa - pb), 0.0f, 1e-5f);
  // axis_world on a body rotated 90 degrees about z: +y in the world is -x locally.
  const SceneJoint& j1 = s.joints[1];
  EXPECT_EQ(j1.bodyA, -1);
  EXPECT_TRUE(j1.def.enableLimit && j1.def.enableMotor);
  EXPECT_NEAR(j1.def.axisB.x, 1.0f, 1e-5f);
  EXPECT_FALSE(s.joints[2].def.enableLimit);
  EXPECT_EQ(s.joints[2].bodyB, 3);
  EXPECT_EQ(s.metrics.groups.at("links").size(), 4u);  // chain/0..2 and chain/ball
  EXPECT_EQ(s.metrics.groups.at("pair"), (std::vector<int>{1, 3}));
  EXPECT_EQ(s.metrics.params.at("finish_x"), 12.5);
  ASSERT_EQ(s.criteria.size(), 3u);
  EXPECT_EQ(*s.criteria[0].max, 0.01);
  EXPECT_FALSE(s.criteria[0].min.has_value());
}

TEST(Scene, RoundTripGivesTheSameScene) {
  Scene a = parseOk(kRich);
  std::string text = sceneToJson(a);
  Scene b;
  Status st = parseScene(text, "written.json", &b);
  ASSERT_TRUE(st.ok()) << st.message << "\n" << text;
  expectSameScene(a, b);
  // Writing is a fixed point, and short numbers stay short.
  EXPECT_EQ(sceneToJson(b), text);
  EXPECT_CONTAINS(text, "\"time_step\": 0.004");
  EXPECT_EQ(text.find("0.0040000"), std::string::npos) << text;
}

TEST(Scene, RoundTripOfGeneratedScenes) {
  Scene a = parseOk(R"({"name": "g", "bodies": [)" + std::string(kGround) + R"(],
    "generators": [{"type": "pile", "count": 50, "half_extents": [3, 3], "walls": {}},
                   {"type": "bridge", "planks": 6, "origin": [0, 10, 5], "span": 5.9},
                   {"type": "car", "name": "car0", "position": [-3, 10, 6.5], "yaw": 0.1},
                   {"type": "windmill", "hub": [0, -10, 4]}]})");
  Scene b;
  ASSERT_TRUE(parseScene(sceneToJson(a), "w.json", &b).ok());
  expectSameScene(a, b);
}

TEST(Scene, NearUnitQuaternionIsNormalized) {
  Scene s = parseOk(R"({"bodies": [{"type": "static", "rotation": [0, 0, 0, 1.0005],
                                    "shapes": [{"type": "plane"}]}]})");
  EXPECT_NEAR(lengthSquared(s.bodies[0].rotation), 1.0f, 1e-6f);
}

// ------------------------------------------------------------------------------------------
// Errors: each names the source, the JSON path and the reason.

std::string withBodies(const std::string& bodies, const std::string& rest = "") {
  return R"({"name": "e", "bodies": [)" + std::string(kGround) + "," + bodies + "]" + rest + "}";
}

TEST(Scene, SyntaxErrorsGiveLineAndColumn) {
  std::string m = parseError("{\n  \"name\": \"x\",\n  \"bodies\": [}\n}");
  EXPECT_CONTAINS(m, "line 3");
  EXPECT_CONTAINS(m, "column");
  m = parseError("{\"name\": \"x\",\n \"gravity\": [0, 0, 1e999]}");
  EXPECT_CONTAINS(m, "line 2");
  EXPECT_CONTAINS(m, "finite");
  m = parseError("[1, 2]");
  EXPECT_CONTAINS(m, "(top level): must be an object");
  m = parseError(R"({"name": "a", "name": "b"})");
  EXPECT_CONTAINS(m, "name: duplicate key");
  m = parseError(R"({"bodies": [{"shapes": [{"name": "a", "name": "b"}]}]})");
  EXPECT_CONTAINS(m, "bodies[0].shapes[0].name: duplicate key \"name\"");
  m = parseError(R"({"metrics": )" + std::string(100000, '[') + std::string(100000, ']') + "}");
  EXPECT_CONTAINS(m, "nested deeper than 64 levels");
}

TEST(Scene, UnknownFieldsAreErrors) {
  std::string m = parseError(withBodies(R"({"positon": [0, 0, 1], "shapes": []})"));
  EXPECT_CONTAINS(m, "test.json: bodies[1].positon: unknown field");
  EXPECT_CONTAINS(m, "did you mean \"position\"");
  m = parseError(
      withBodies(R"({"shapes": [{"type": "sphere", "radius": 1, "half_extents": [1, 1, 1]}]})"));
  EXPECT_CONTAINS(m, "bodies[1].shapes[0].half_extents: is not a field of a sphere");
  m = parseError(R"({"solver": {"substep": 2}})");
  EXPECT_CONTAINS(m, "solver.substep: unknown field");
  m = parseError(R"({"generators": [{"type": "stack", "count": 3, "hlaf_extent": 1}]})");
  EXPECT_CONTAINS(m, "generators[0].hlaf_extent: unknown field");
  m = parseError(R"({"metrics": {"top_body": []}})");
  EXPECT_CONTAINS(m, "metrics.top_body: unknown field");
}

TEST(Scene, WrongTypesAreErrors) {
  EXPECT_CONTAINS(
      parseError(withBodies(R"({"mass": "heavy", "shapes": [{"type": "sphere", "radius": 1}]})")),
      "bodies[1].mass: must be a finite number > 0 (got a string)");
  EXPECT_CONTAINS(parseError(R"({"gravity": [0, 0]})"), "gravity: must be an array of three");
  EXPECT_CONTAINS(parseError(R"({"bodies": {}})"), "bodies: must be an array");
  EXPECT_CONTAINS(parseError(withBodies(R"({"type": "wobbly", "shapes": []})")),
                  "bodies[1].type: must be \"static\", \"kinematic\" or \"dynamic\"");
  EXPECT_CONTAINS(parseError(R"({"solver": {"substeps": 2.5}})"), "solver.substeps");
  EXPECT_CONTAINS(parseError(R"({"solver": {"stabilization": "stiff"}})"), "solver.stabilization");
  EXPECT_CONTAINS(parseError(withBodies(R"({"gyroscopic": 1, "mass": 1})")),
                  "bodies[1].gyroscopic: must be true or false");
}

TEST(Scene, NonFiniteAndOutOfRangeNumbersAreErrors) {
  EXPECT_CONTAINS(parseError(withBodies(R"({"position": [0, 1e39, 0], "mass": 1})")),
                  "bodies[1].position: must be an array of three finite numbers");
  EXPECT_CONTAINS(parseError(R"({"time_step": 0})"), "time_step: must be a finite number > 0");
  EXPECT_CONTAINS(parseError(R"({"duration": -1})"), "duration: must be a finite number > 0");
  EXPECT_CONTAINS(parseError(R"({"materials": {"m": {"restitution": 1.5}}})"),
                  "materials.m.restitution: must be a number in [0, 1]");
  EXPECT_CONTAINS(parseError(R"({"materials": {"m": {"friction": -0.1}}})"),
                  "materials.m.friction: must be a finite number >= 0");
}

TEST(Scene, NonPositiveSizesAndMassesAreErrors) {
  std::string three = R"({"type": "static", "shapes": [{"type": "sphere", "radius": 1}]},)"
                      R"({"type": "static", "shapes": [{"type": "sphere", "radius": 1}]},)";
  EXPECT_CONTAINS(
      parseError(withBodies(three + R"({"shapes": [{"type": "box", "half_extents": [1, 0, 1]}]})")),
      "test.json: bodies[3].shapes[0].half_extents: must be three positive finite numbers");
  EXPECT_CONTAINS(parseError(withBodies(R"({"shapes": [{"type": "sphere", "radius": -1}]})")),
                  "bodies[1].shapes[0].radius: must be a finite number > 0");
  EXPECT_CONTAINS(parseError(withBodies(R"({"shapes": [{"type": "capsule", "radius": 1}]})")),
                  "bodies[1].shapes[0].half_height: is required");
  EXPECT_CONTAINS(
      parseError(withBodies(R"({"mass": 0, "shapes": [{"type": "sphere", "radius": 1}]})")),
      "bodies[1].mass: must be a finite number > 0");
  EXPECT_CONTAINS(parseError(withBodies(R"({"mass": 1, "inertia": [1, -1, 1]})")),
                  "bodies[1].inertia: must be three positive finite numbers");
  EXPECT_CONTAINS(parseError(withBodies(R"({"position": [0, 0, 1]})")),
                  "bodies[1]: a dynamic body needs at least one shape or a \"mass\"");
  EXPECT_CONTAINS(parseError(withBodies(R"({"type": "static", "mass": 2})")),
                  "bodies[1].mass: only a dynamic body has a mass");
  EXPECT_CONTAINS(parseError(R"({"generators": [{"type": "pyramid", "base": 0}]})"),
                  "generators[0].base: must be an integer in [1, 5000]");
  EXPECT_CONTAINS(parseError(R"({"generators": [{"type": "chain", "links": 2, "anchor": [0, 0, 1],
                                                 "link_length": 0}]})"),
                  "generators[0].link_length: must be a finite number > 0");
}

TEST(Scene, NonUnitQuaternionsAreErrors) {
  EXPECT_CONTAINS(parseError(withBodies(R"({"rotation": [0, 0, 0, 2], "mass": 1})")),
                  "bodies[1].rotation: must be a unit quaternion [x, y, z, w] (its length is 2");
  EXPECT_CONTAINS(parseError(withBodies(R"({"rotation_axis_angle": [0, 0, 0, 1], "mass": 1})")),
                  "bodies[1].rotation_axis_angle: must be [ax, ay, az, angle]");
  EXPECT_CONTAINS(
      parseError(withBodies(
          R"({"rotation": [0, 0, 0, 1], "rotation_axis_angle": [0, 0, 1, 1], "mass": 1})")),
      "not both");
}

TEST(Scene, UnknownNamesAreErrors) {
  EXPECT_CONTAINS(parseError(withBodies(
                      R"({"shapes": [{"type": "sphere", "radius": 1, "material": "rubber"}]})")),
                  "bodies[1].shapes[0].material: unknown material \"rubber\"");
  EXPECT_CONTAINS(parseError(withBodies(R"({"name": "b", "mass": 1})",
                                        R"(, "joints": [{"type": "ball", "body_b": "c"}])")),
                  "joints[0].body_b: unknown body \"c\"");
  EXPECT_CONTAINS(parseError(withBodies(R"({"name": "b", "mass": 1})",
                                        R"(, "joints": [{"type": "ball", "body_b": 7}])")),
                  "joints[0].body_b: must be an integer in [0, 1]");
  EXPECT_CONTAINS(parseError(withBodies(R"({"name": "b", "mass": 1})",
                                        R"(, "metrics": {"groups": {"g": ["b", "x/*"]}})")),
                  "metrics.groups.g[1]: the pattern \"x/*\" matches no body");
  EXPECT_CONTAINS(parseError(R"({"criteria": [{"metric": "top_drfit", "max": 1}]})"),
                  "criteria[0].metric: unknown metric \"top_drfit\"");
  EXPECT_CONTAINS(parseError(R"({"criteria": [{"metric": "top_drift", "max": 1}]})"),
                  "criteria[0].metric: top_drift needs \"metrics.top_bodies\"");
  EXPECT_CONTAINS(parseError(R"({"criteria": [{"metric": "bridge.cars_arrived", "min": 3}]})"),
                  "needs the group \"metrics.groups.bridge_car\"");
  EXPECT_CONTAINS(parseError(R"({"criteria": [{"metric": "nan"}]})"),
                  "needs \"min\" and/or \"max\"");
}

TEST(Scene, DuplicateNamesAreErrors) {
  EXPECT_CONTAINS(parseError(withBodies(R"({"name": "b", "mass": 1}, {"name": "b", "mass": 1})")),
                  "bodies[2]: duplicate body name \"b\" (already used by bodies[1])");
  EXPECT_CONTAINS(parseError(withBodies(R"({"name": "stack/1", "mass": 1})",
                                        R"(, "generators": [{"type": "stack", "count": 3}])")),
                  "generators[0]: duplicate body name \"stack/1\"");
  EXPECT_CONTAINS(
      parseError(withBodies(R"({"name": "b", "mass": 1})",
                            R"(, "joints": [{"type": "ball", "body_b": "b", "name": "j"},
                                                       {"type": "ball", "body_b": "b", "name": "j"}])")),
      "joints[1].name: duplicate joint name \"j\"");
}

TEST(Scene, StructuralErrors) {
  EXPECT_CONTAINS(parseError(withBodies(R"({"shapes": [{"type": "plane"}]})")),
                  "bodies[1].shapes[0].type: a plane is only allowed on a static body");
  EXPECT_CONTAINS(parseError(withBodies(R"({"type": "kinematic", "shapes": [{"type": "plane"}]})")),
                  "a plane is only allowed on a static body");
  EXPECT_CONTAINS(parseError(R"({"generators": [{"type": "tower", "count": 3}]})"),
                  "generators[0].type: unknown generator \"tower\"");
  EXPECT_CONTAINS(
      parseError(withBodies(R"({"name": "b", "mass": 1})",
                            R"(, "joints": [{"type": "ball", "body_a": "b", "body_b": "b"}])")),
      "joints[0].body_b: a joint must connect two different bodies");
  EXPECT_CONTAINS(parseError(withBodies(
                      R"({"name": "b", "mass": 1})",
                      R"(, "joints": [{"type": "ball", "body_b": "b", "axis_world": [0, 0, 1]}])")),
                  "joints[0].axis_world: is not a field of a");
  EXPECT_CONTAINS(
      parseError(withBodies(
          R"({"name": "b", "mass": 1})",
          R"(, "joints": [{"type": "hinge", "body_b": "b", "limit": {"lower": 1, "upper": 0}}])")),
      "joints[0].limit.upper: must be >= lower");
  EXPECT_CONTAINS(parseError(withBodies(
                      R"({"name": "b", "mass": 1})",
                      R"(, "joints": [{"type": "hinge", "body_b": "b", "axis_a": [0, 0, 1]}])")),
                  "joints[0].axis_b: is required");
  EXPECT_CONTAINS(
      parseError(
          withBodies(R"({"name": "b", "mass": 1})",
                     R"(, "joints": [{"type": "hinge", "body_b": "b", "axis_world": [0, 0, 0]}])")),
      "joints[0].axis_world: must be a non-zero direction");
  EXPECT_CONTAINS(
      parseError(
          R"({"generators": [{"type": "bridge", "planks": 3, "origin": [0, 0, 5], "span": 10}]})"),
      "generators[0].span: must be at most the deck length");
  // Parameters that are each valid but make an invalid body.
  EXPECT_CONTAINS(parseError(R"({"generators": [{"type": "windmill", "hub": [0, 0, 5],
                                                 "blade_thickness": 1e-45}]})"),
                  "generators[0]: the body \"windmill/rotor\" would be invalid: shape 1");
  EXPECT_CONTAINS(
      parseError(R"({"generators": [{"type": "stack", "count": 10, "half_extent": 1e38}]})"),
      "generators[0]: the body \"stack/2\" would be invalid: its position is not finite");
}

TEST(Scene, HullPointsMustSpanAVolume) {
  std::string m = parseError(withBodies(
      R"({"shapes": [{"type": "hull", "points": [[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]]}]})"));
  EXPECT_CONTAINS(m, "bodies[1].shapes[0].points: the points span no volume");
  EXPECT_CONTAINS(
      parseError(withBodies(R"({"shapes": [{"type": "hull", "points": [[0, 0, 0]]}]})")),
      "must be an array of at least four points");
}

TEST(Scene, MissingFileIsNotFound) {
  Scene s;
  Status st = loadSceneFile("/nonexistent/scene.json", &s);
  EXPECT_EQ(st.code, StatusCode::NotFound);
  EXPECT_CONTAINS(st.message, "/nonexistent/scene.json");
}

// ------------------------------------------------------------------------------------------
// Generators

TEST(Scene, PyramidCountAndLayout) {
  Scene s = parseOk(R"({"bodies": [)" + std::string(kGround) +
                    R"(], "generators": [{"type": "pyramid", "base": 20}]})");
  ASSERT_EQ(s.bodies.size(), 211u);  // 20 * 21 / 2 boxes + ground
  EXPECT_EQ(countNamed(s, "pyramid/"), 210);
  const BodyDef& first = s.bodies[1];
  EXPECT_EQ(first.name, "pyramid/0");
  EXPECT_FLOAT_EQ(first.position.z, 0.5f);   // resting on the ground
  EXPECT_FLOAT_EQ(first.position.x, -9.5f);  // the base row is centred on the origin
  const BodyDef& top = s.bodies[bodyIndex(s, "pyramid/209")];
  EXPECT_FLOAT_EQ(top.position.z, 19.5f);
  EXPECT_FLOAT_EQ(top.position.x, 0.0f);
  // No two boxes overlap (touching faces allowed), checked over the first three rows.
  for (int i = 1; i <= 57; ++i) {
    for (int j = i + 1; j <= 57; ++j) {
      AABB a = bodyBox(s.bodies[size_t(i)]), b = bodyBox(s.bodies[size_t(j)]);
      float ox = std::min(a.hi.x, b.hi.x) - std::max(a.lo.x, b.lo.x);
      float oy = std::min(a.hi.y, b.hi.y) - std::max(a.lo.y, b.lo.y);
      float oz = std::min(a.hi.z, b.hi.z) - std::max(a.lo.z, b.lo.z);
      EXPECT_FALSE(ox > 1e-5f && oy > 1e-5f && oz > 1e-5f) << i << " overlaps " << j;
    }
  }
  // Neighbours touch: the second box sits exactly one box width further.
  EXPECT_FLOAT_EQ(s.bodies[2].position.x - s.bodies[1].position.x, 1.0f);
}

TEST(Scene, PyramidOverlapAndGap) {
  Scene s = parseOk(R"({"generators": [{"type": "pyramid", "base": 4, "overlap": 0.25},
                                       {"type": "pyramid", "name": "g", "base": 2, "gap": 0.1,
                                        "half_extent": 1, "origin": [0, 10, 0]}]})");
  ASSERT_EQ(s.bodies.size(), 13u);
  EXPECT_FLOAT_EQ(s.bodies[1].position.x - s.bodies[0].position.x, 0.75f);
  EXPECT_FLOAT_EQ(s.bodies[0].position.z, 0.25f);  // sunk a quarter into the ground
  EXPECT_FLOAT_EQ(s.bodies[4].position.z - s.bodies[0].position.z, 0.75f);
  const BodyDef& g0 = s.bodies[bodyIndex(s, "g/0")];
  const BodyDef& g1 = s.bodies[bodyIndex(s, "g/1")];
  EXPECT_FLOAT_EQ(g1.position.x - g0.position.x, 2.1f);
  EXPECT_FLOAT_EQ(g0.position.y, 10.0f);
}

TEST(Scene, StackGridAndPyramidGridCounts) {
  Scene s = parseOk(R"({"generators": [
      {"type": "stack", "count": 20},
      {"type": "grid", "nx": 10, "ny": 10, "nz": 10, "half_extent": 1},
      {"type": "pyramid_grid", "rows": 3, "cols": 4, "base": 10}]})");
  EXPECT_EQ(countNamed(s, "stack/"), 20);
  EXPECT_EQ(countNamed(s, "grid/"), 1000);
  EXPECT_EQ(countNamed(s, "pyramid_grid/"), 12 * 55);
  EXPECT_FLOAT_EQ(s.bodies[bodyIndex(s, "stack/19")].position.z, 19.5f);
  const BodyDef& g0 = s.bodies[bodyIndex(s, "grid/0")];
  const BodyDef& gLast = s.bodies[bodyIndex(s, "grid/999")];
  EXPECT_FLOAT_EQ(g0.position.z, 1.0f);
  EXPECT_FLOAT_EQ(g0.position.x, -9.0f);
  EXPECT_FLOAT_EQ(gLast.position.z, 19.0f);
  EXPECT_FLOAT_EQ(gLast.position.y, 9.0f);
  EXPECT_FLOAT_EQ(g0.shapes[0].geom.halfExtents.x, 1.0f);
  // Pyramids of the grid do not overlap each other: compare two neighbours' base rows.
  const BodyDef& p0 = s.bodies[bodyIndex(s, "pyramid_grid/0/9")];  // right end of pyramid 0
  const BodyDef& p1 = s.bodies[bodyIndex(s, "pyramid_grid/1/0")];  // left end of pyramid 1
  EXPECT_GT(p1.position.x - p0.position.x, 1.0f);
}

TEST(Scene, ChainLinksAndJoints) {
  Scene s = parseOk(R"({"generators": [{"type": "chain", "links": 40, "link_length": 0.5,
      "link_mass": 1, "anchor": [0, 0, 30], "direction": [1, 0, 0],
      "end_ball": {"radius": 0.4, "mass_ratio": 1000}}]})");
  EXPECT_EQ(countNamed(s, "chain/"), 41);
  ASSERT_EQ(s.joints.size(), 41u);
  const BodyDef& ball = s.bodies[bodyIndex(s, "chain/ball")];
  EXPECT_FLOAT_EQ(ball.mass, 1000.0f);
  EXPECT_FLOAT_EQ(s.bodies[0].mass, 1.0f);
  EXPECT_NEAR(ball.position.x, 20.4f, 1e-4f);
  EXPECT_EQ(s.joints[0].bodyA, -1);  // hung from the world
  // Every joint's two anchors start at the same world point, along the chain.
  for (const SceneJoint& j : s.joints) {
    EXPECT_EQ(j.def.type, JointType::Ball);
    Vec3 a = worldAnchor(s, j.bodyA, j.def.anchorA), b = worldAnchor(s, j.bodyB, j.def.anchorB);
    EXPECT_LT(length(a - b), 1e-4f) << j.def.name;
    EXPECT_NEAR(a.z, 30.0f, 1e-4f);
  }
  // Link capsules run along the chain direction.
  Vec3 axis = rotate(s.bodies[0].rotation, Vec3{0, 0, 1});
  EXPECT_NEAR(axis.x, 1.0f, 1e-5f);
}

TEST(Scene, PileCountsDeterminismAndSpacing) {
  const std::string pile = R"({"generators": [{"type": "pile", "count": 500, "seed": 7,
      "size": [0.2, 0.4], "center": [1, 2, 0], "half_extents": [4, 3], "walls": {"height": 3}}]})";
  Scene a = parseOk(pile), b = parseOk(pile);
  ASSERT_EQ(a.bodies.size(), 501u);  // 500 + the bin
  EXPECT_EQ(countNamed(a, "pile/"), 501);
  const BodyDef& bin = a.bodies[bodyIndex(a, "pile/bin")];
  EXPECT_EQ(bin.type, BodyType::Static);
  EXPECT_EQ(bin.shapes.size(), 4u);
  int kinds[3] = {0, 0, 0};
  for (size_t i = 0; i < 500; ++i) {
    const BodyDef& x = a.bodies[i];
    EXPECT_TRUE(x.position == b.bodies[i].position && x.rotation == b.bodies[i].rotation);
    kinds[x.shapes[0].geom.type == ShapeType::Box      ? 0
          : x.shapes[0].geom.type == ShapeType::Sphere ? 1
                                                       : 2]++;
    // Inside the bin, above the floor.
    AABB box = bodyBox(x);
    EXPECT_GE(box.lo.x, 1 - 4.0f - 1e-4f);
    EXPECT_LE(box.hi.x, 1 + 4.0f + 1e-4f);
    EXPECT_GE(box.lo.y, 2 - 3.0f - 1e-4f);
    EXPECT_GE(box.lo.z, 0.0f);
  }
  EXPECT_GT(kinds[0], 100);
  EXPECT_GT(kinds[1], 100);
  EXPECT_GT(kinds[2], 100);
  // Bounding spheres of distinct bodies do not intersect (the default spacing).
  for (size_t i = 0; i < 500; ++i) {
    for (size_t j = i + 1; j < std::min<size_t>(500, i + 40); ++j) {
      auto radius = [](const BodyDef& d) {
        const ShapeGeom& g = d.shapes[0].geom;
        return g.type == ShapeType::Box      ? length(g.halfExtents)
               : g.type == ShapeType::Sphere ? g.radius
                                             : g.radius + g.halfHeight;
      };
      EXPECT_GT(length(a.bodies[i].position - a.bodies[j].position),
                radius(a.bodies[i]) + radius(a.bodies[j]))
          << i << " " << j;
    }
  }
  Scene c = parseOk(R"({"generators": [{"type": "pile", "count": 500, "seed": 8,
      "size": [0.2, 0.4], "center": [1, 2, 0], "half_extents": [4, 3]}]})");
  EXPECT_EQ(c.bodies.size(), 500u);
  EXPECT_FALSE(c.bodies[3].position == a.bodies[3].position);
  Scene boxes = parseOk(R"({"generators": [{"type": "pile", "count": 200, "mix": {"box": 1},
      "orientation": "aligned", "size": [0.25, 0.25], "spacing": 0.375, "half_extents": [1, 1]}]})");
  for (const BodyDef& d : boxes.bodies) {
    EXPECT_EQ(d.shapes[0].geom.type, ShapeType::Box);
    EXPECT_TRUE(d.rotation == Quat{});
  }
  // Spacing below the size: neighbours interpenetrate by design (the overlap scene).
  EXPECT_FLOAT_EQ(boxes.bodies[1].position.x - boxes.bodies[0].position.x, 0.375f);
}

TEST(Scene, BridgeHangsAsACatenaryWithCoincidentJoints) {
  Scene s = parseOk(R"({"generators": [{"type": "bridge", "planks": 100, "origin": [0, 0, 10],
                                        "span": 101.8}]})");
  EXPECT_EQ(countNamed(s, "bridge/plank/"), 100);
  EXPECT_EQ(countNamed(s, "bridge/bank/"), 2);
  ASSERT_EQ(s.joints.size(), 101u);
  float lowest = 1e30f;
  for (const SceneJoint& j : s.joints) {
    EXPECT_EQ(j.def.type, JointType::Hinge);
    Vec3 a = worldAnchor(s, j.bodyA, j.def.anchorA), b = worldAnchor(s, j.bodyB, j.def.anchorB);
    EXPECT_LT(length(a - b), 1e-3f) << j.def.name;
    lowest = std::min(lowest, a.z);
  }
  Vec3 farPin = worldAnchor(s, s.joints.back().bodyB, s.joints.back().def.anchorB);
  EXPECT_NEAR(farPin.x, 101.8f, 1e-3f);
  EXPECT_NEAR(farPin.z, 10.0f, 1e-3f);
  // 102 m of deck over a 101.8 m span sags by sqrt(3 * 101.8 * 0.2 / 8) ~ 2.76 m.
  EXPECT_NEAR(10.0f - lowest, 2.76f, 0.1f);
  // Banks are static, joined to the first and last planks.
  EXPECT_EQ(s.bodies[size_t(s.joints.front().bodyA)].type, BodyType::Static);
}

TEST(Scene, CarAndWindmill) {
  Scene s = parseOk(R"({"generators": [{"type": "car", "name": "car0", "position": [0, 0, 1]},
                                       {"type": "windmill", "hub": [0, 5, 4], "blades": 4}]})");
  ASSERT_EQ(s.bodies.size(), 6u);
  ASSERT_EQ(s.joints.size(), 5u);
  for (int i = 0; i < 4; ++i) {
    const SceneJoint& j = s.joints[size_t(i)];
    EXPECT_EQ(j.def.type, JointType::Hinge);
    EXPECT_TRUE(j.def.enableMotor);
    EXPECT_EQ(s.bodies[size_t(j.bodyA)].name, "car0/chassis");
    Vec3 a = worldAnchor(s, j.bodyA, j.def.anchorA), b = worldAnchor(s, j.bodyB, j.def.anchorB);
    EXPECT_LT(length(a - b), 1e-5f);
  }
  const BodyDef& rotor = s.bodies[bodyIndex(s, "windmill/rotor")];
  EXPECT_EQ(rotor.shapes.size(), 5u);  // hub + 4 blades
  // The first blade points along +x (axis y, start angle 0), its tip at the blade length.
  BodyDef bladeOnly;
  bladeOnly.position = rotor.position;
  bladeOnly.shapes = {rotor.shapes[1]};
  AABB blade = bodyBox(bladeOnly);
  EXPECT_NEAR(blade.hi.x, 3.0f, 1e-4f);
  EXPECT_EQ(s.joints[4].bodyA, -1);
}

// ------------------------------------------------------------------------------------------
// The shipped scenes

TEST(Scene, EveryShippedSceneParses) {
  namespace fs = std::filesystem;
  fs::path dir = fs::path(PHYS_SOURCE_DIR) / "configs" / "scenes";
  std::set<std::string> found;
  for (const auto& entry : fs::directory_iterator(dir)) {
    if (entry.path().extension() != ".json") continue;
    std::string stem = entry.path().stem().string();
    found.insert(stem);
    if (stem == "pile_1m") continue;  // 1M bodies (3 s, 330 MB): see PileOfAMillionIsWellFormed
    SCOPED_TRACE(stem);
    Scene s;
    Status st = loadSceneFile(entry.path().string(), &s);
    ASSERT_TRUE(st.ok()) << st.message;
    EXPECT_EQ(s.name, stem);
    EXPECT_FALSE(s.description.empty());
    EXPECT_FALSE(s.criteria.empty());
    bool ground = std::any_of(s.bodies.begin(), s.bodies.end(), [](const BodyDef& b) {
      return b.type == BodyType::Static && !b.shapes.empty();
    });
    // Every scene with gravity has something to land on (fanout_10k floats in zero gravity).
    const bool weightless = lengthSquared(s.world.gravity) == 0;
    EXPECT_TRUE(ground || weightless) << "every scene with gravity has a static ground";
    bool nanCriterion = std::any_of(s.criteria.begin(), s.criteria.end(),
                                    [](const Criterion& c) { return c.metric == "nan"; });
    EXPECT_TRUE(nanCriterion);
    // Writing and reading back changes nothing.
    if (s.bodies.size() <= 25000) {
      Scene back;
      ASSERT_TRUE(parseScene(sceneToJson(s), stem + " (written)", &back).ok());
      expectSameScene(s, back);
    }
  }
  for (const char* name : {"default", "pyramid_20", "pyramid_40", "pyramid_100", "vertical_stack",
                           "box_stack", "ball_and_chain", "overlap", "suspension_bridge",
                           "windmill", "friction_ramp", "restitution", "tunnelling", "free_flight",
                           "many_pyramids", "pile_10k", "pile_100k", "pile_1m"}) {
    EXPECT_TRUE(found.count(name)) << "configs/scenes/" << name << ".json is missing";
  }
}

TEST(Scene, ShippedSceneBodyCounts) {
  auto load = [](const char* name) { return test::loadScene(name); };
  EXPECT_EQ(countNamed(load("pyramid_20"), "pyramid/"), 210);
  EXPECT_EQ(countNamed(load("pyramid_40"), "pyramid/"), 820);
  EXPECT_EQ(countNamed(load("pyramid_100"), "pyramid/"), 5050);
  EXPECT_EQ(countNamed(load("vertical_stack"), "stack/"), 20);
  EXPECT_EQ(countNamed(load("box_stack"), "grid/"), 1000);
  Scene chain = load("ball_and_chain");
  EXPECT_EQ(countNamed(chain, "chain/"), 41);
  EXPECT_EQ(chain.joints.size(), 41u);
  EXPECT_EQ(countNamed(load("many_pyramids"), "pyramids/"), 22000);
  EXPECT_EQ(countNamed(load("pile_10k"), "pile/"), 10001);  // + the bin
  Scene bridge = load("suspension_bridge");
  EXPECT_EQ(countNamed(bridge, "bridge/plank/"), 100);
  EXPECT_EQ(bridge.metrics.groups.at("bridge_car").size(), 3u);
}

TEST(Scene, PileOfAMillionIsWellFormed) {
  // Parsing the real file takes seconds; the same file with a smaller count checks every
  // other field, and the count itself is checked in the text.
  std::ifstream f(std::string(PHYS_SOURCE_DIR) + "/configs/scenes/pile_1m.json");
  ASSERT_TRUE(f.good());
  std::stringstream text;
  text << f.rdbuf();
  std::string json = text.str();
  const std::string count = "\"count\": 1000000,";
  size_t at = json.find(count);
  ASSERT_NE(at, std::string::npos);
  json.replace(at, count.size(), "\"count\": 1000,");
  Scene s;
  Status st = parseScene(json, "pile_1m.json (count 1000)", &s);
  ASSERT_TRUE(st.ok()) << st.message;
  EXPECT_EQ(s.name, "pile_1m");
  EXPECT_EQ(countNamed(s, "pile/"), 1001);
}

// ------------------------------------------------------------------------------------------
// Instantiation

TEST(Scene, InstantiateCreatesEveryBodyAndJoint) {
  Scene s = parseOk(withBodies(
      R"({"name": "b", "position": [0, 0, 3], "shapes": [{"type": "sphere", "radius": 0.5}]})",
      R"(, "generators": [{"type": "chain", "links": 5, "anchor": [0, 5, 5]},
                                                   {"type": "pyramid", "base": 4, "origin": [5, 0, 0]}])"));
  World world(s.world);
  std::vector<BodyId> ids;
  std::vector<JointId> joints;
  Status st = instantiateScene(s, &world, &ids, &joints);
  ASSERT_TRUE(st.ok()) << st.message;
  EXPECT_EQ(world.bodyCount(), 2 + 5 + 10);
  EXPECT_EQ(world.jointCount(), 5);
  ASSERT_EQ(ids.size(), s.bodies.size());
  ASSERT_EQ(joints.size(), 5u);
  BodyState b;
  ASSERT_TRUE(world.getBody(ids[1], &b).ok());
  EXPECT_FLOAT_EQ(b.position.z, 3.0f);
  JointDef jd;
  ASSERT_TRUE(world.getJoint(joints[1], &jd, nullptr).ok());
  EXPECT_TRUE(jd.bodyA == ids[2] && jd.bodyB == ids[3]);
}

TEST(Scene, InstantiateIsAllOrNothing) {
  Scene s = parseOk(R"({"name": "aon", "bodies": [)" + std::string(kGround) +
                    R"(], "generators": [{"type": "chain", "links": 5, "anchor": [0, 0, 5]}]})");
  World world(s.world);
  BodyDef existing;
  existing.shapes.push_back(ShapeDef{ShapeGeom::sphere(1), {}, {}});
  BodyId keep;
  ASSERT_TRUE(world.createBody(existing, &keep).ok());

  // A bad joint at the end: every body and joint created before it is removed again.
  Scene badJoint = s;
  SceneJoint j = badJoint.joints.back();
  j.def.anchorA.x = std::nanf("");
  j.def.name = "broken";
  badJoint.joints.push_back(j);
  std::vector<BodyId> ids{BodyId{}};
  Status st = instantiateScene(badJoint, &world, &ids);
  EXPECT_FALSE(st.ok());
  EXPECT_CONTAINS(st.message, "joints[5] (\"broken\")");
  EXPECT_EQ(world.bodyCount(), 1);
  EXPECT_EQ(world.jointCount(), 0);
  EXPECT_TRUE(world.isValid(keep));
  EXPECT_EQ(ids.size(), 1u);  // untouched on error

  // A bad body in the middle.
  Scene badBody = s;
  badBody.bodies[3].position.z = std::numeric_limits<float>::infinity();
  st = instantiateScene(badBody, &world, &ids);
  EXPECT_FALSE(st.ok());
  EXPECT_CONTAINS(st.message, "bodies[3] (\"chain/2\")");
  EXPECT_EQ(world.bodyCount(), 1);

  // A joint index out of range is caught before anything is created.
  Scene badIndex = s;
  badIndex.joints[0].bodyB = 99;
  st = instantiateScene(badIndex, &world, &ids);
  EXPECT_EQ(st.code, StatusCode::InvalidArgument);
  EXPECT_EQ(world.bodyCount(), 1);

  // And the good scene still goes in afterwards.
  ASSERT_TRUE(instantiateScene(s, &world, &ids).ok());
  EXPECT_EQ(world.bodyCount(), 1 + 6);
  EXPECT_EQ(world.jointCount(), 5);
}

TEST(Scene, EveryPhysbenchMetricIsAKnownCriterion) {
  const std::vector<std::string>& known = knownSceneMetrics();
  for (const std::string& name : metricNames()) {
    EXPECT_NE(std::find(known.begin(), known.end(), name), known.end()) << name;
  }
}

}  // namespace
}  // namespace phys
