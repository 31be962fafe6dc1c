// Bad input of every kind gets the right code and a message naming the field.
#include <cmath>
#include <cstring>
#include <limits>
#include <random>

#include "protocol_test_util.h"

namespace phys::protocol::test {
namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
constexpr float kInf = std::numeric_limits<float>::infinity();

/// Expects decodeCommand to reject `b` with `code` and a message containing `text`.
void expectReject(const Bytes& b, Code code, const std::string& text, const Limits& lim = {}) {
  Decoded<wire::Command> d = decodeCommand(b, lim);
  EXPECT_FALSE(d.ok());
  EXPECT_EQ(d.root, nullptr);
  EXPECT_EQ(d.status.code, code) << toString(d.status.code) << ": " << d.status.message;
  EXPECT_NE(d.status.message.find(text), std::string::npos)
      << "message \"" << d.status.message << "\" lacks \"" << text << "\"";
}

Bytes spawn(const phys::BodyDef& b) {
  return CommandBuilder().spawnBodies({&b, 1}).finish(header());
}

phys::BodyDef box() {
  return boxBody({0, 0, 1}, {0.5f, 0.5f, 0.5f});
}

// ---------------------------------------------------------------------------------------------
// Structure: size, identifier, verification

TEST(ProtocolReject, EmptyAndTiny) {
  expectReject({}, Code::Malformed, "too short");
  expectReject({1, 2, 3}, Code::Malformed, "command is 3 bytes, too short");
}

TEST(ProtocolReject, Oversized) {
  Bytes big(kMaxEnvelopeBytes + 1, 0);
  expectReject(big, Code::ResourceExhausted, "the limit is 4194304 (max_message_bytes)");
  // A cap of 2^31 or more is clamped before the Verifier (which asserts there) exists.
  Limits huge;
  huge.maxMessageBytes = 0xFFFFFFFFu;
  Bytes ok = CommandBuilder().step().finish(header());
  EXPECT_TRUE(decodeCommand(ok, huge).ok());
  // A smaller cap applies to an otherwise valid command.
  Limits small;
  small.maxMessageBytes = 64;
  std::vector<phys::BodyDef> bodies(10, box());
  expectReject(CommandBuilder().spawnBodies(bodies).finish(header()), Code::ResourceExhausted,
               "(max_message_bytes)", small);
}

TEST(ProtocolReject, WrongIdentifier) {
  Bytes reply = encodeReply({});
  expectReject(reply, Code::Malformed, "file identifier \"PHRP\", expected \"PHCM\"");
  Bytes cmd = CommandBuilder().step().finish(header());
  EXPECT_FALSE(decodeReply(cmd).ok());
  EXPECT_EQ(decodeReply(cmd).status.code, Code::Malformed);
  EXPECT_FALSE(decodeStateFrame(cmd).ok());
  EXPECT_FALSE(decodeSnapshot(cmd).ok());
}

TEST(ProtocolReject, RandomBytes) {
  std::mt19937 rng(1);
  for (int i = 0; i < 2000; ++i) {
    Bytes b(8 + rng() % 512);
    for (uint8_t& x : b) x = uint8_t(rng());
    if (i % 2) std::memcpy(b.data() + 4, "PHCM", 4);  // past the identifier check
    Decoded<wire::Command> d = decodeCommand(b);
    if (!d.ok()) {
      EXPECT_NE(d.status.code, Code::Ok);
      EXPECT_FALSE(d.status.message.empty());
    }
  }
  Bytes b(64, 0);
  std::memcpy(b.data() + 4, "PHCM", 4);
  b[0] = 0xF0;  // root offset far outside
  expectReject(b, Code::Malformed, "failed FlatBuffers verification");
}

TEST(ProtocolReject, Truncated) {
  std::vector<phys::BodyDef> bodies = sampleBodies();
  Bytes full = CommandBuilder().spawnBodies(bodies).finish(header());
  ASSERT_TRUE(decodeCommand(full).ok());
  for (size_t n = 0; n < full.size(); ++n) {
    Bytes cut(full.begin(), full.begin() + n);
    Decoded<wire::Command> d = decodeCommand(cut);
    EXPECT_FALSE(d.ok()) << "prefix of " << n << " bytes accepted";
    EXPECT_EQ(d.status.code, Code::Malformed) << n << ": " << d.status.message;
  }
}

TEST(ProtocolReject, DeepNesting) {
  // Batches nested in batches: each level adds two tables of depth.
  flatbuffers::FlatBufferBuilder fbb;
  auto step = wire::CreateStep(fbb, 1);
  flatbuffers::Offset<void> inner = step.Union();
  wire::Request type = wire::Request::Step;
  for (int level = 0; level < 12; ++level) {
    std::vector<flatbuffers::Offset<wire::CommandItem>> items = {
        wire::CreateCommandItem(fbb, type, inner)};
    inner = wire::CreateBatch(fbb, fbb.CreateVector(items)).Union();
    type = wire::Request::Batch;
  }
  fbb.Finish(wire::CreateCommand(fbb, kClient, 1, kWorld, type, inner), wire::kCommandId);
  Bytes b(fbb.GetBufferPointer(), fbb.GetBufferPointer() + fbb.GetSize());
  expectReject(b, Code::Malformed, "nested deeper than 16");

  // One level of nesting verifies but a batch is not batchable.
  flatbuffers::FlatBufferBuilder f2;
  std::vector<flatbuffers::Offset<wire::CommandItem>> items2 = {
      wire::CreateCommandItem(f2, wire::Request::Step, wire::CreateStep(f2, 1).Union())};
  auto b1 = wire::CreateBatch(f2, f2.CreateVector(items2));
  std::vector<flatbuffers::Offset<wire::CommandItem>> outer = {
      wire::CreateCommandItem(f2, wire::Request::Batch, b1.Union())};
  auto b2 = wire::CreateBatch(f2, f2.CreateVector(outer));
  f2.Finish(wire::CreateCommand(f2, kClient, 1, kWorld, wire::Request::Batch, b2.Union()),
            wire::kCommandId);
  expectReject(Bytes(f2.GetBufferPointer(), f2.GetBufferPointer() + f2.GetSize()),
               Code::InvalidArgument,
               "batch.commands[0].request is batch, which cannot be batched");
}

TEST(ProtocolReject, SharedTablesCannotAmplifyVerification) {
  // 200,000 offsets to one body table: tiny on the wire, 200,000 tables to the Verifier.
  flatbuffers::FlatBufferBuilder fbb;
  auto radius = wire::CreateSphere(fbb, 0.5f);
  std::vector<flatbuffers::Offset<wire::ShapeDef>> shapes = {
      wire::CreateShapeDef(fbb, wire::Shape::Sphere, radius.Union())};
  auto body = wire::CreateBodyDef(fbb, wire::MotionType::Dynamic, nullptr, nullptr, nullptr, 0, 0,
                                  1, 0, nullptr, true, 0, fbb.CreateVector(shapes));
  std::vector<flatbuffers::Offset<wire::BodyDef>> same(200000, body);
  auto spawn = wire::CreateSpawnBodies(fbb, fbb.CreateVector(same));
  fbb.Finish(
      wire::CreateCommand(fbb, kClient, 1, kWorld, wire::Request::SpawnBodies, spawn.Union()),
      wire::kCommandId);
  Bytes b(fbb.GetBufferPointer(), fbb.GetBufferPointer() + fbb.GetSize());
  expectReject(b, Code::Malformed, "more than");
}

TEST(ProtocolReject, MisalignedIdVector) {
  // The FlatBuffers 2.0.8 Verifier accepts a vector of 8-byte ids that starts only 4-byte
  // aligned; reading it would be undefined behaviour, so the codec rejects it.
  bool found = false;
  for (int pad = 0; pad < 4 && !found; ++pad) {
    flatbuffers::FlatBufferBuilder fbb;
    for (int k = 0; k < pad; ++k) fbb.CreateVector(std::vector<uint8_t>{});  // 4 bytes each
    fbb.StartVector(4, sizeof(uint32_t));  // two ids written as four 4-byte words
    for (uint32_t w : {0u, 5u, 0u, 6u}) fbb.PushElement(w);
    flatbuffers::Offset<flatbuffers::Vector<uint64_t>> ids(fbb.EndVector(2));
    auto remove = wire::CreateRemoveBodies(fbb, ids);
    fbb.Finish(
        wire::CreateCommand(fbb, kClient, 1, kWorld, wire::Request::RemoveBodies, remove.Union()),
        wire::kCommandId);
    Bytes b(fbb.GetBufferPointer(), fbb.GetBufferPointer() + fbb.GetSize());
    flatbuffers::Verifier v(b.data(), b.size());
    ASSERT_TRUE(v.VerifyBuffer<wire::Command>(wire::kCommandId));
    auto* vec = flatbuffers::GetRoot<wire::Command>(b.data())->request_as_RemoveBodies()->bodies();
    if (reinterpret_cast<uintptr_t>(vec->Data()) % 8 == 0) {
      EXPECT_TRUE(decodeCommand(b).ok());
      continue;
    }
    found = true;
    expectReject(b, Code::Malformed, "remove_bodies.bodies is not 8-byte aligned");
  }
  EXPECT_TRUE(found);
}

TEST(ProtocolReject, MissingOrUnknownRequest) {
  expectReject(CommandBuilder().finish(header()), Code::Malformed, "command.request is missing");
  CommandBuilder u;
  auto pause = wire::CreatePause(u.fbb());
  expectReject(u.raw(wire::Request(99), pause.Union()).finish(header()), Code::Unsupported,
               "command.request has unknown kind 99");
  // A type without its table.
  flatbuffers::FlatBufferBuilder fbb;
  fbb.Finish(wire::CreateCommand(fbb, kClient, 1, kWorld, wire::Request::Step, 0),
             wire::kCommandId);
  expectReject(Bytes(fbb.GetBufferPointer(), fbb.GetBufferPointer() + fbb.GetSize()),
               Code::Malformed, "command.request is missing its table");
}

TEST(ProtocolReject, HeaderFields) {
  expectReject(CommandBuilder().step().finish({0, 1, kWorld}), Code::InvalidArgument,
               "command.client_id must be non-zero");
  expectReject(CommandBuilder().step().finish(header(1, 0)), Code::InvalidArgument,
               "command.world must name a world for step");
  // Hello, CreateWorld and ListWorlds need no world.
  EXPECT_TRUE(decodeCommand(CommandBuilder().listWorlds().finish(header(1, 0))).ok());
  expectReject(CommandBuilder().hello("x", 0).finish(header()), Code::InvalidArgument,
               "hello.protocol_version must be >= 1, got 0");
}

// ---------------------------------------------------------------------------------------------
// Numbers

TEST(ProtocolReject, NonFiniteNumbers) {
  phys::BodyDef b = box();
  b.position.x = kNaN;
  expectReject(spawn(b), Code::InvalidArgument,
               "spawn_bodies.bodies[0].pose.position.x must be finite, got nan");
  b = box();
  b.linearVelocity.z = -kInf;
  expectReject(spawn(b), Code::InvalidArgument,
               "spawn_bodies.bodies[0].linear_velocity.z must be finite, got -inf");
  b = box();
  b.shapes[0].material.friction = kNaN;
  expectReject(spawn(b), Code::InvalidArgument,
               "spawn_bodies.bodies[0].shapes[0].material.friction must be finite");
  expectReject(CommandBuilder().applyForce(5, {0, kInf, 0}).finish(header()), Code::InvalidArgument,
               "apply_force.items[0].vector.y must be finite, got inf");
  expectReject(CommandBuilder().applyImpulse(5, {1, 0, 0}, {kNaN, 0, 0}).finish(header()),
               Code::InvalidArgument, "apply_impulse.items[0].point.x must be finite");
  expectReject(CommandBuilder().applyTorque(5, {kNaN, 0, 0}).finish(header()),
               Code::InvalidArgument, "apply_torque.items[0].torque.x");
  expectReject(CommandBuilder().setBodyVelocity(5, {}, {0, 0, kNaN}).finish(header()),
               Code::InvalidArgument, "set_body_velocity.items[0].angular.z must be finite");
  expectReject(CommandBuilder().run(kNaN).finish(header()), Code::InvalidArgument,
               "run.rate_hz must be finite, got nan");
  CreateWorldArgs a{"w", "", phys::Vec3{0, 0, kInf}, 0};
  expectReject(CommandBuilder().createWorld(a).finish(header(1, 0)), Code::InvalidArgument,
               "create_world.gravity.z must be finite");
  SolverOverrides o;
  o.contactHertz = kNaN;
  expectReject(CommandBuilder().setSolver("", o).finish(header()), Code::InvalidArgument,
               "set_solver.settings.contact_hertz must be finite");
}

TEST(ProtocolReject, OutOfRangeNumbers) {
  phys::BodyDef b = box();
  b.position.z = 2e6f;
  expectReject(spawn(b), Code::InvalidArgument,
               "spawn_bodies.bodies[0].pose.position.z must be in [-1e+06, 1e+06], got 2e+06");
  b = box();
  b.shapes[0].material.restitution = 1.5f;
  expectReject(spawn(b), Code::InvalidArgument,
               "shapes[0].material.restitution must be in [0, 1], got 1.5");
  b = box();
  b.shapes[0].material.friction = -0.1f;
  expectReject(spawn(b), Code::InvalidArgument, "material.friction must be >= 0, got -0.1");
  b = box();
  b.shapes[0].material.density = 0;
  expectReject(spawn(b), Code::InvalidArgument, "material.density must be > 0, got 0");
  b = box();
  b.linearDamping = -1;
  expectReject(spawn(b), Code::InvalidArgument, "bodies[0].linear_damping must be >= 0, got -1");
  expectReject(CommandBuilder().run(-1).finish(header()), Code::InvalidArgument,
               "run.rate_hz must be >= 0, got -1");
  expectReject(CommandBuilder().run(1e6f).finish(header()), Code::InvalidArgument,
               "run.rate_hz must be <= 10000");
  CreateWorldArgs a{"w", "", {}, -0.01f};
  expectReject(CommandBuilder().createWorld(a).finish(header(1, 0)), Code::InvalidArgument,
               "create_world.time_step must be > 0, got -0.01");
  SolverOverrides o;
  o.substeps = 0;
  expectReject(CommandBuilder().setSolver("", o).finish(header()), Code::InvalidArgument,
               "set_solver.settings.substeps must be in [1, 64], got 0");
  o = {};
  o.baumgarte = 2;
  expectReject(CommandBuilder().setSolver("", o).finish(header()), Code::InvalidArgument,
               "set_solver.settings.baumgarte must be in [0, 1], got 2");
}

TEST(ProtocolReject, Quaternions) {
  phys::BodyDef b = box();
  b.rotation = {0, 0, 0, 0};
  expectReject(spawn(b), Code::InvalidArgument,
               "spawn_bodies.bodies[0].pose.rotation must be a unit quaternion");
  b.rotation = {0, 0, 0, 2};
  expectReject(spawn(b), Code::InvalidArgument, "got |q| = 2");
  b.rotation = {0, 0, 0, kNaN};
  expectReject(spawn(b), Code::InvalidArgument, "pose.rotation.w must be finite");
  // Within the tolerance: accepted as sent, normalized on conversion.
  b.rotation = {0, 0, 0, 1.0005f};
  auto d = mustDecode(spawn(b));
  EXPECT_EQ(d->request_as_SpawnBodies()->bodies()->Get(0)->pose()->rotation().w(), 1.0005f);
  phys::BodyDef out;
  ASSERT_TRUE(toBodyDef(*d->request_as_SpawnBodies()->bodies()->Get(0), &out).ok());
  EXPECT_EQ(out.rotation.w, 1.0f);
  b.rotation = {0, 0, 0, 1.002f};
  expectReject(spawn(b), Code::InvalidArgument, "must be a unit quaternion");
  // Shape frames and poses too.
  b = box();
  b.shapes[0].local.q = {0.5f, 0, 0, 0.5f};
  expectReject(spawn(b), Code::InvalidArgument,
               "bodies[0].shapes[0].local.rotation must be a unit");
  expectReject(CommandBuilder().setBodyPose(3, {}, {0, 0, 0, 0.9f}).finish(header()),
               Code::InvalidArgument, "set_body_pose.items[0].pose.rotation must be a unit");
}

TEST(ProtocolReject, NegativeMassesAndSizes) {
  phys::BodyDef b = box();
  b.shapes[0].geom.halfExtents.y = -1;
  expectReject(spawn(b), Code::InvalidArgument,
               "spawn_bodies.bodies[0].shapes[0].box.half_extents.y must be > 0, got -1");
  b = box();
  b.mass = -1;
  expectReject(spawn(b), Code::InvalidArgument, "spawn_bodies.bodies[0].mass must be >= 0, got -1");
  b = box();
  b.mass = 1e12f;
  expectReject(spawn(b), Code::InvalidArgument, "mass must be <= 1e+09");
  phys::BodyDef s;
  phys::ShapeDef sphere;
  sphere.geom = phys::ShapeGeom::sphere(0);
  s.shapes.push_back(sphere);
  expectReject(spawn(s), Code::InvalidArgument, "shapes[0].sphere.radius must be > 0, got 0");
  s.shapes[0].geom.radius = 1e-7f;
  expectReject(spawn(s), Code::InvalidArgument, "shapes[0].sphere.radius must be >= 1e-05");
  s.shapes[0].geom = phys::ShapeGeom::capsule(0.5f, -1);
  expectReject(spawn(s), Code::InvalidArgument, "shapes[0].capsule.half_height must be >= 0");
  b = box();
  b.inertia = {1, 0, 1};
  expectReject(spawn(b), Code::InvalidArgument, "bodies[0].inertia must be all 0 (automatic) or");
  b.inertia = {1, -1, 1};
  expectReject(spawn(b), Code::InvalidArgument, "bodies[0].inertia.y must be >= 0, got -1");
}

// ---------------------------------------------------------------------------------------------
// Enums, shapes, combinations

TEST(ProtocolReject, UnknownEnumValues) {
  phys::BodyDef b = box();
  b.type = phys::BodyType(7);
  expectReject(spawn(b), Code::InvalidArgument,
               "spawn_bodies.bodies[0].motion is 7, not a known MotionType");
  phys::JointDef j = sampleJoint();
  j.type = phys::JointType(9);
  expectReject(CommandBuilder().addJoints({&j, 1}).finish(header()), Code::InvalidArgument,
               "add_joints.joints[0].type is 9, not a known JointType");
  expectReject(CommandBuilder().applyForce(1, {1, 0, 0}, {}, wire::PointFrame(5)).finish(header()),
               Code::InvalidArgument, "apply_force.point_frame is 5, not a known PointFrame");
  SolverOverrides o;
  o.scheme = phys::SolverSettings::Scheme(9);
  expectReject(CommandBuilder().setSolver("", o).finish(header()), Code::InvalidArgument,
               "set_solver.settings.scheme is 9, not a known Scheme");

  // An unknown shape union type.
  CommandBuilder cb;
  auto& fbb = cb.fbb();
  auto sphere = wire::CreateSphere(fbb, 1);
  std::vector<flatbuffers::Offset<wire::ShapeDef>> shapes = {
      wire::CreateShapeDef(fbb, wire::Shape(9), sphere.Union())};
  std::vector<flatbuffers::Offset<wire::BodyDef>> bodies = {
      wire::CreateBodyDef(fbb, wire::MotionType::Dynamic, nullptr, nullptr, nullptr, 0, 0, 1, 1,
                          nullptr, true, 0, fbb.CreateVector(shapes))};
  auto sb = wire::CreateSpawnBodies(fbb, fbb.CreateVector(bodies));
  expectReject(cb.raw(wire::Request::SpawnBodies, sb.Union()).finish(header()),
               Code::InvalidArgument, "bodies[0].shapes[0].geom is 9, not a known shape type");
}

TEST(ProtocolReject, ShapeRules) {
  phys::BodyDef b = box();
  b.shapes[0].geom = phys::ShapeGeom::plane({0, 0, 1}, 0);
  expectReject(spawn(b), Code::InvalidArgument,
               "spawn_bodies.bodies[0].shapes[0].plane is only allowed on a static body");
  phys::BodyDef g = groundBody();
  g.shapes[0].geom.normal = {0, 0, 0};
  expectReject(spawn(g), Code::InvalidArgument, "shapes[0].plane.normal must be a non-zero");
  phys::BodyDef empty;  // dynamic, no shapes, mass 0
  expectReject(spawn(empty), Code::InvalidArgument,
               "bodies[0].shapes must hold a shape with volume when a dynamic body's mass is 0");
  empty.mass = 2;  // a given mass needs no shape (a point mass)
  EXPECT_TRUE(decodeCommand(spawn(empty)).ok());
  phys::BodyDef st = groundBody();
  st.mass = 3;
  expectReject(spawn(st), Code::InvalidArgument, "bodies[0].mass must be 0 for a static body");
  phys::BodyDef many = box();
  many.shapes.assign(65, many.shapes[0]);
  expectReject(spawn(many), Code::ResourceExhausted,
               "bodies[0].shapes has 65 shapes, the limit is 64 (max_shapes_per_body)");
}

TEST(ProtocolReject, HullPoints) {
  // Build hull shapes by hand: phys hulls always come from buildConvexHull.
  auto hullCommand = [](size_t n, float coord) {
    CommandBuilder cb;
    auto& fbb = cb.fbb();
    std::vector<wire::Vec3> pts;
    for (size_t i = 0; i < n; ++i)
      pts.emplace_back(float(i % 2) * coord, float((i / 2) % 2), float(i / 4) * 0.01f);
    auto hull = wire::CreateConvexHull(fbb, fbb.CreateVectorOfStructs(pts));
    std::vector<flatbuffers::Offset<wire::ShapeDef>> shapes = {
        wire::CreateShapeDef(fbb, wire::Shape::ConvexHull, hull.Union())};
    std::vector<flatbuffers::Offset<wire::BodyDef>> bodies = {
        wire::CreateBodyDef(fbb, wire::MotionType::Dynamic, nullptr, nullptr, nullptr, 0, 0, 1, 0,
                            nullptr, true, 0, fbb.CreateVector(shapes))};
    auto sb = wire::CreateSpawnBodies(fbb, fbb.CreateVector(bodies));
    return cb.raw(wire::Request::SpawnBodies, sb.Union()).finish(header());
  };
  EXPECT_TRUE(decodeCommand(hullCommand(8, 1)).ok());
  expectReject(hullCommand(3, 1), Code::InvalidArgument,
               "shapes[0].convex_hull.points needs at least 4 points, got 3");
  expectReject(hullCommand(257, 1), Code::ResourceExhausted,
               "convex_hull.points has 257 points, the limit is 256 (max_hull_points)");
  expectReject(hullCommand(8, 5e4f), Code::InvalidArgument,
               "convex_hull.points[1].x must be in [-10000, 10000], got 50000");
}

TEST(ProtocolReject, Joints) {
  phys::JointDef j = sampleJoint();
  j.bodyB = {};
  expectReject(CommandBuilder().addJoints({&j, 1}).finish(header()), Code::InvalidArgument,
               "add_joints.joints[0].body_b must be a non-zero id");
  j = sampleJoint();
  j.bodyA = j.bodyB;
  expectReject(CommandBuilder().addJoints({&j, 1}).finish(header()), Code::InvalidArgument,
               "joints[0].body_a must differ from body_b");
  j = sampleJoint();
  j.lower = 2;
  j.upper = 1;
  expectReject(CommandBuilder().addJoints({&j, 1}).finish(header()), Code::InvalidArgument,
               "joints[0].lower must be <= upper, got 2 > 1");
  j = sampleJoint();
  j.lower = -4;
  expectReject(CommandBuilder().addJoints({&j, 1}).finish(header()), Code::InvalidArgument,
               "must lie in [-pi, pi] for a hinge");
  j = sampleJoint();
  j.axisA = {0, 0, 0};
  expectReject(CommandBuilder().addJoints({&j, 1}).finish(header()), Code::InvalidArgument,
               "joints[0].axis_a must be a non-zero direction");
  j = sampleJoint();
  j.maxMotorForce = -1;
  expectReject(CommandBuilder().addJoints({&j, 1}).finish(header()), Code::InvalidArgument,
               "joints[0].max_motor_force must be >= 0");
  expectReject(CommandBuilder().addJoints({}).finish(header()), Code::InvalidArgument,
               "add_joints.joints must not be empty");
}

TEST(ProtocolReject, IdLists) {
  std::vector<uint64_t> ids = {4, 0, 5};
  expectReject(CommandBuilder().removeBodies(ids).finish(header()), Code::InvalidArgument,
               "remove_bodies.bodies[1] must be a non-zero id");
  ids = {4, 5, 6, 5};
  expectReject(CommandBuilder().removeBodies(ids).finish(header()), Code::InvalidArgument,
               "remove_bodies.bodies[3] repeats bodies[1] (0x5)");
  expectReject(CommandBuilder().removeJoints(ids).finish(header()), Code::InvalidArgument,
               "remove_joints.joints[3] repeats joints[1]");
  expectReject(CommandBuilder().removeBodies({}).finish(header()), Code::InvalidArgument,
               "remove_bodies.bodies must not be empty");
  expectReject(CommandBuilder().setBodyPose(0, {}, {}).finish(header()), Code::InvalidArgument,
               "set_body_pose.items[0].id must be a non-zero id");
  std::vector<uint64_t> one = {0};
  expectReject(CommandBuilder().setMaterial(one, {}).finish(header()), Code::InvalidArgument,
               "set_material.bodies[0] must be a non-zero id");
}

TEST(ProtocolReject, Backend) {
  // Only "cpu", "gpu" and "auto" (or nothing: the server's default); names are exact.
  for (const char* bad : {"GPU", "cuda", " gpu", "cpu,gpu", "vulkan"}) {
    SCOPED_TRACE(bad);
    expectReject(CommandBuilder().createWorld({"w", "", {}, 0, bad}).finish(header(1, 0)),
                 Code::InvalidArgument,
                 std::string("create_world.backend must be \"cpu\", \"gpu\" or \"auto\" (or "
                             "empty: the server's default), got \"") +
                     bad + "\"");
  }
  expectReject(CommandBuilder().createWorld({"w", "", {}, 0, "g\npu"}).finish(header(1, 0)),
               Code::InvalidArgument, "create_world.backend must not contain control characters");
  expectReject(
      CommandBuilder().createWorld({"w", "", {}, 0, std::string(200, 'g')}).finish(header(1, 0)),
      Code::ResourceExhausted, "create_world.backend is 200 bytes, the limit is 128");
  // An empty backend is the server's default.
  EXPECT_TRUE(
      decodeCommand(CommandBuilder().createWorld({"w", "", {}, 0, ""}).finish(header(1, 0))).ok());
}

TEST(ProtocolReject, NamesAndFiles) {
  expectReject(CommandBuilder().createWorld({"", "", {}, 0}).finish(header(1, 0)),
               Code::InvalidArgument, "create_world.name must be given");
  expectReject(
      CommandBuilder().createWorld({std::string(300, 'a'), "", {}, 0}).finish(header(1, 0)),
      Code::ResourceExhausted, "create_world.name is 300 bytes, the limit is 256");
  expectReject(CommandBuilder().createWorld({"bad\xff\xfe", "", {}, 0}).finish(header(1, 0)),
               Code::InvalidArgument, "create_world.name is not valid UTF-8");
  expectReject(CommandBuilder().createWorld({"a\nb", "", {}, 0}).finish(header(1, 0)),
               Code::InvalidArgument, "must not contain control characters");
  EXPECT_TRUE(
      decodeCommand(CommandBuilder().createWorld({"wörld", "", {}, 0}).finish(header(1, 0))).ok());
  expectReject(CommandBuilder().saveSnapshot("../etc/passwd").finish(header()),
               Code::InvalidArgument, "save_snapshot.file must be a plain name");
  expectReject(CommandBuilder().saveSnapshot(".hidden").finish(header()), Code::InvalidArgument,
               "save_snapshot.file must be a plain name");
  expectReject(CommandBuilder().loadSceneNamed("scenes/x").finish(header()), Code::InvalidArgument,
               "load_scene.scene_name must be a plain name");
  expectReject(CommandBuilder().setSolver("a b").finish(header()), Code::InvalidArgument,
               "set_solver.preset must be a plain name");
}

TEST(ProtocolReject, ExactlyOneOf) {
  CommandBuilder cb;
  auto& fbb = cb.fbb();
  auto json = fbb.CreateString("{}");
  auto name = fbb.CreateString("default");
  expectReject(cb.raw(wire::Request::LoadScene, wire::CreateLoadScene(fbb, json, name).Union())
                   .finish(header()),
               Code::InvalidArgument, "load_scene.json and scene_name are both given");
  CommandBuilder cb2;
  expectReject(
      cb2.raw(wire::Request::LoadScene, wire::CreateLoadScene(cb2.fbb()).Union()).finish(header()),
      Code::InvalidArgument, "load_scene.json or scene_name must be given");
  CommandBuilder cb3;
  expectReject(
      cb3.raw(wire::Request::RestoreSnapshot, wire::CreateRestoreSnapshot(cb3.fbb()).Union())
          .finish(header()),
      Code::InvalidArgument, "restore_snapshot.snapshot or file must be given");
  expectReject(CommandBuilder().setSolver("").finish(header()), Code::InvalidArgument,
               "set_solver needs a preset or at least one setting");
  expectReject(CommandBuilder().saveSnapshot("", false).finish(header()), Code::InvalidArgument,
               "save_snapshot.return_bytes is false and no file is given");
  expectReject(CommandBuilder().step(0).finish(header()), Code::InvalidArgument,
               "step.count must be >= 1, got 0");
}

TEST(ProtocolReject, EdgeCasesAsDocumented) {
  // docs/PROTOCOL.md, "Edge cases": one check per row, in the table's order.
  // A required vector present but empty.
  expectReject(CommandBuilder().spawnBodies({}).finish(header()), Code::InvalidArgument,
               "spawn_bodies.bodies must not be empty");
  // A zero id where an id is expected.
  std::vector<uint64_t> zero = {0};
  expectReject(CommandBuilder().removeJoints(zero).finish(header()), Code::InvalidArgument,
               "remove_joints.joints[0] must be a non-zero id");
  expectReject(CommandBuilder().pause().finish({0, 1, kWorld}), Code::InvalidArgument,
               "command.client_id must be non-zero");
  expectReject(CommandBuilder().pause().finish(header(1, 0)), Code::InvalidArgument,
               "command.world must name a world for pause");
  // Step 0, and over the limit.
  expectReject(CommandBuilder().step(0).finish(header()), Code::InvalidArgument,
               "step.count must be >= 1, got 0");
  expectReject(CommandBuilder().step(100001).finish(header()), Code::ResourceExhausted,
               "step.count is 100001, the limit is 100000");
  // A name over its byte limit, and a required name absent or empty.
  auto createWorld = [](const std::string& name) {
    return CommandBuilder().createWorld({name, "", {}, 0, ""}).finish(header(1, 0));
  };
  expectReject(createWorld(std::string(257, 'w')), Code::ResourceExhausted,
               "create_world.name is 257 bytes, the limit is 256");
  EXPECT_TRUE(decodeCommand(createWorld(std::string(256, 'w'))).ok());
  expectReject(createWorld(""), Code::InvalidArgument, "create_world.name must be given");
  CommandBuilder cw;
  auto empty = cw.fbb().CreateString("");
  expectReject(cw.raw(wire::Request::CreateWorld, wire::CreateCreateWorld(cw.fbb(), empty).Union())
                   .finish(header(1, 0)),
               Code::InvalidArgument, "create_world.name must not be empty");
  // A required sub-table missing.
  CommandBuilder cb;
  auto ids = cb.fbb().CreateVector(std::vector<uint64_t>{4});
  expectReject(
      cb.raw(wire::Request::SetMaterial, wire::CreateSetMaterial(cb.fbb(), ids, 0).Union())
          .finish(header()),
      Code::InvalidArgument, "set_material.material must be given");
  // The request missing, or its table.
  expectReject(CommandBuilder().finish(header()), Code::Malformed, "command.request is missing");
}

// ---------------------------------------------------------------------------------------------
// Counts

TEST(ProtocolReject, AbsurdCounts) {
  expectReject(CommandBuilder().step(1000000).finish(header()), Code::ResourceExhausted,
               "step.count is 1000000, the limit is 100000 (max_steps_per_command)");

  // The default body limit, for real: 20,001 small bodies (about 2 MB).
  std::vector<phys::BodyDef> bodies(20001, box());
  expectReject(CommandBuilder().spawnBodies(bodies).finish(header()), Code::ResourceExhausted,
               "spawn_bodies.bodies has 20001 entries, the limit is 20000 "
               "(max_bodies_per_command)");

  std::vector<uint64_t> ids(100001);
  for (size_t i = 0; i < ids.size(); ++i) ids[i] = i + 1;
  expectReject(CommandBuilder().removeBodies(ids).finish(header()), Code::ResourceExhausted,
               "remove_bodies.bodies has 100001 entries, the limit is 100000");

  CommandBuilder batch;
  for (int i = 0; i < 257; ++i) batch.applyTorque(1, {0, 0, 1});
  expectReject(batch.finish(header()), Code::ResourceExhausted,
               "batch.commands has 257 entries, the limit is 256 (max_batch_commands)");

  // A batch shares one budget.
  Limits lim;
  lim.maxBodiesPerCommand = 10;
  std::vector<phys::BodyDef> six(6, box());
  expectReject(CommandBuilder().spawnBodies(six).spawnBodies(six).finish(header()),
               Code::ResourceExhausted,
               "batch.commands[1].spawn_bodies.bodies has 6 entries (12 in the whole message), "
               "the limit is 10",
               lim);
  EXPECT_TRUE(decodeCommand(CommandBuilder().spawnBodies(six).finish(header()), lim).ok());
}

TEST(ProtocolReject, BatchRules) {
  expectReject(CommandBuilder().spawnBodies(sampleBodies()).step(1).finish(header()),
               Code::InvalidArgument,
               "batch.commands[1].request is step, which cannot be batched (only world edits can)");
  expectReject(CommandBuilder().hello("x").listWorlds().finish(header()), Code::InvalidArgument,
               "batch.commands[0].request is hello, which cannot be batched");
  // An error deep inside a batch names its whole path.
  phys::BodyDef bad = box();
  bad.shapes[0].geom.halfExtents.z = -2;
  expectReject(CommandBuilder().applyTorque(1, {}).spawnBodies({&bad, 1}).finish(header()),
               Code::InvalidArgument,
               "batch.commands[1].spawn_bodies.bodies[0].shapes[0].box.half_extents.z must be > "
               "0, got -2");
}

// ---------------------------------------------------------------------------------------------
// Snapshots

SnapshotData sampleSnapshot() {
  SnapshotData s;
  std::vector<phys::BodyDef> bodies = sampleBodies();
  for (size_t i = 0; i < bodies.size(); ++i) s.bodies.push_back({i + 1, bodies[i]});
  phys::JointDef j = sampleJoint();
  j.bodyA = phys::BodyId::fromPacked(2);
  j.bodyB = phys::BodyId::fromPacked(3);
  s.joints.push_back({1, j});
  return s;
}

TEST(ProtocolReject, Snapshots) {
  EXPECT_TRUE(decodeSnapshot(encodeSnapshot(sampleSnapshot())).ok());

  SnapshotData s = sampleSnapshot();
  s.bodies[2].id = s.bodies[0].id;
  auto d = decodeSnapshot(encodeSnapshot(s));
  EXPECT_EQ(d.status.code, Code::InvalidArgument);
  EXPECT_NE(d.status.message.find("snapshot.bodies[2].id repeats bodies[0].id"), std::string::npos)
      << d.status.message;

  s = sampleSnapshot();
  s.joints[0].def.bodyB = phys::BodyId::fromPacked(99);
  d = decodeSnapshot(encodeSnapshot(s));
  EXPECT_EQ(d.status.code, Code::InvalidArgument);
  EXPECT_NE(d.status.message.find("snapshot.joints[0].def.body_b 0x63 is not a body of the "
                                  "snapshot"),
            std::string::npos)
      << d.status.message;

  s = sampleSnapshot();
  s.timeStep = 0;
  d = decodeSnapshot(encodeSnapshot(s));
  EXPECT_NE(d.status.message.find("snapshot.time_step must be > 0"), std::string::npos);

  // Engine state and a portable description are exclusive.
  s = sampleSnapshot();
  s.engineState = {1, 2, 3};
  d = decodeSnapshot(encodeSnapshot(s));
  EXPECT_EQ(d.status.code, Code::InvalidArgument);
  EXPECT_NE(d.status.message.find("snapshot.engine_state and bodies/joints are both given"),
            std::string::npos)
      << d.status.message;

  // A bad snapshot inside RestoreSnapshot fails the command with the nested path.
  s = sampleSnapshot();
  s.bodies[1].def.mass = -5;
  expectReject(CommandBuilder().restoreSnapshot(encodeSnapshot(s)).finish(header()),
               Code::InvalidArgument,
               "restore_snapshot.snapshot: snapshot.bodies[1].def.mass must be >= 0, got -5");
  Bytes garbage(100, 0x11);
  expectReject(CommandBuilder().restoreSnapshot(garbage).finish(header()), Code::Malformed,
               "restore_snapshot.snapshot: snapshot has file identifier");
}

// ---------------------------------------------------------------------------------------------
// The other decoders

TEST(ProtocolReject, FramesRepliesStatus) {
  std::vector<wire::BodyState> states(3);
  auto f = decodeStateFrame(encodeStateFrame({1, 1, 0}, 2, 2, 3, states));
  EXPECT_EQ(f.status.code, Code::InvalidArgument);
  EXPECT_NE(f.status.message.find("state_frame.chunk_index must be < chunk_count (2), got 2"),
            std::string::npos)
      << f.status.message;
  f = decodeStateFrame(encodeStateFrame({1, 1, 0}, 0, 0, 3, states));
  EXPECT_NE(f.status.message.find("state_frame.chunk_count must be >= 1"), std::string::npos);
  f = decodeStateFrame(encodeStateFrame({1, 1, 0}, 0, 1, 2, states));
  EXPECT_NE(f.status.message.find("more than total_bodies (2)"), std::string::npos);
  Limits lim;
  lim.maxBodiesPerFrame = 2;
  f = decodeStateFrame(encodeStateFrame({1, 1, 0}, 0, 1, 3, states), lim);
  EXPECT_EQ(f.status.code, Code::ResourceExhausted);
  // A rolling refresh: only on a delta, its range not empty; a good one decodes.
  FrameHeader refresh{1, 1, 0};
  refresh.refreshLo = 5;
  refresh.refreshHi = 9;
  f = decodeStateFrame(encodeStateFrame(refresh, 0, 1, 3, states));
  EXPECT_NE(f.status.message.find("state_frame.refresh_hi is only for deltas"), std::string::npos)
      << f.status.message;
  refresh.keyframe = false;
  f = decodeStateFrame(encodeStateFrame(refresh, 0, 1, 3, states));
  ASSERT_TRUE(f.ok()) << f.status.message;
  EXPECT_EQ(f->refresh_lo(), 5u);
  EXPECT_EQ(f->refresh_hi(), 9u);
  refresh.refreshLo = 9;
  f = decodeStateFrame(encodeStateFrame(refresh, 0, 1, 3, states));
  EXPECT_NE(f.status.message.find("state_frame.refresh_lo must be below refresh_hi"),
            std::string::npos)
      << f.status.message;

  ReplyHeader h;
  h.status.code = Code(200);
  auto r = decodeReply(encodeReply(h));
  EXPECT_EQ(r.status.code, Code::InvalidArgument);
  EXPECT_NE(r.status.message.find("reply.status is 200, not a known StatusCode"),
            std::string::npos);

  auto e = decodeEvent(encodeEvent(1, 1, wire::Severity(9), "x", "y"));
  EXPECT_NE(e.status.message.find("event.severity is 9"), std::string::npos);

  WorldInfoHeader wh;
  std::vector<BodyEntry> bodies = {{0, box()}};
  std::vector<Bytes> info = encodeWorldInfo(wh, bodies, {});
  auto w = decodeWorldInfo(info[0]);
  EXPECT_NE(w.status.message.find("world_info.bodies[0].id must be a non-zero id"),
            std::string::npos)
      << w.status.message;
}

}  // namespace
}  // namespace phys::protocol::test
