// Writes the seed corpus of the fuzz targets (fuzz/corpus/): a valid message of every kind.
//
//   make_corpus OUT_DIR   (tools/fuzz.sh --make-corpus: OUT_DIR = fuzz/corpus)
//
//   apply/  every Request kind of the protocol as a command of the fuzz client to the fuzz
//           world (fuzz_server.h), with the body and joint ids that world has: CreateWorld,
//           DestroyWorld, ResetWorld, ListWorlds, Hello, SpawnBodies with every shape kind,
//           RemoveBodies, AddJoints with every joint kind, RemoveJoints, SetBodyPose,
//           SetBodyVelocity, ApplyForce / ApplyImpulse (every point frame) / ApplyTorque,
//           SetMaterial, SetSolver, Step, Run, Pause, Subscribe (bodies, region), Unsubscribe,
//           SetAccess (editors, shared), MoveWorld,
//           QueryState, SaveSnapshot (bytes, file), RestoreSnapshot (engine state, portable,
//           file), LoadScene (inline JSON, by name), Batch;
//   codec/  the same commands and every published kind: Reply with each result, StateFrame
//           (keyframe, delta, compact), WorldInfo, ServerStatus, Event, Snapshot (both forms);
//   scene/  the small scenes of configs/scenes and one with every shape and joint kind;
//   restore/ engine snapshots (World::saveSnapshot): an empty world, snapshot_forge.h's world
//           (bodies awake and asleep, joints, contacts, free slots), restitution,
//           friction_ramp and tunnelling after 30 steps (small: a step of ball_and_chain or
//           mass_ratio_10 takes a tenth of a second under ASan, and their mutants filled the
//           corpus), and each of snapshot_forge.h's forged cases
//           (seed-forged-*: one field set to a value no world holds, the checksum sealed).
//
// Seeds are named seed-*; files named otherwise (regression-*) are never touched. The output
// is deterministic: running it again rewrites the same bytes.
#include <unistd.h>

#include <cstdio>
#include <cstring>
#include <iterator>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "fuzz_server.h"
#include "phys/protocol/convert.h"
#include "phys/scene/scene.h"
#include "snapshot_forge.h"

namespace {

namespace fs = std::filesystem;
using namespace phys;
using namespace phys::protocol;

std::string gOut;
int gWritten = 0;

void write(const std::string& dir, const std::string& name, const std::vector<uint8_t>& bytes) {
  fs::create_directories(gOut + "/" + dir);
  std::ofstream f(gOut + "/" + dir + "/seed-" + name, std::ios::binary | std::ios::trunc);
  f.write(reinterpret_cast<const char*>(bytes.data()), std::streamsize(bytes.size()));
  if (!f) {
    std::fprintf(stderr, "cannot write %s/%s\n", dir.c_str(), name.c_str());
    std::exit(1);
  }
  ++gWritten;
}

void writeBoth(const std::string& name, const std::vector<uint8_t>& bytes) {
  write("apply", name, bytes);
  write("codec", "cmd-" + name, bytes);
}

CommandHeader hdr(uint32_t world = fuzz::kWorld) {
  static uint64_t seq = 0;
  return {fuzz::kClient, ++seq, world};
}

/// One body of every shape kind, most fields off their defaults.
std::vector<BodyDef> spawnSet() {
  std::vector<BodyDef> v;
  BodyDef a = fuzz::shapeBody({1, 1, 3}, ShapeGeom::box({0.5f, 0.25f, 0.125f}), "crate");
  a.rotation = Quat::fromAxisAngle({0, 0, 1}, 0.3f);
  a.linearVelocity = {1, 0, 0};
  a.angularVelocity = {0, 0.5f, 0};
  a.linearDamping = 0.1f;
  a.angularDamping = 0.2f;
  a.gravityScale = 0.5f;
  a.mass = 12;
  a.inertia = {1, 2, 3};
  a.gyroscopic = false;
  a.allowSleep = false;
  a.shapes[0].material = {0.3f, 0.4f, 500};
  a.shapes[0].local = {{0.1f, 0, 0}, Quat::fromAxisAngle({1, 0, 0}, 0.2f)};
  ShapeDef sphere;
  sphere.geom = ShapeGeom::sphere(0.2f);
  sphere.local.p = {0, 0, 0.4f};
  a.shapes.push_back(sphere);
  v.push_back(a);
  v.push_back(fuzz::shapeBody({-1, 1, 3}, ShapeGeom::sphere(0.3f), "ball"));
  v.push_back(fuzz::shapeBody({0, -2, 3}, ShapeGeom::capsule(0.25f, 0.5f), "pill",
                              BodyType::Kinematic));
  v.push_back(fuzz::hullBody({2, 2, 3}));
  v.push_back(fuzz::shapeBody({0, 0, -1}, ShapeGeom::plane({0, 0.6f, 0.8f}, -1), "slope",
                              BodyType::Static));
  return v;
}

/// A joint of every kind between the fuzz world's bodies (and one to the world).
std::vector<JointDef> jointSet(const std::vector<uint64_t>& b) {
  std::vector<JointDef> v;
  auto id = [&](size_t i) { return BodyId::fromPacked(b.at(i)); };
  JointDef ball;
  ball.type = JointType::Ball;
  ball.bodyA = id(1);
  ball.bodyB = id(4);
  ball.anchorA = {-1, 0, 0};
  ball.anchorB = {1, 0, 0};
  ball.name = "ball";
  v.push_back(ball);
  JointDef hinge;
  hinge.type = JointType::Hinge;
  hinge.bodyA = id(2);
  hinge.bodyB = id(3);
  hinge.anchorA = {1, 0, 0};
  hinge.anchorB = {-1, 0, 0};
  hinge.axisA = hinge.axisB = {0, 1, 0};
  hinge.enableLimit = true;
  hinge.lower = -1;
  hinge.upper = 1;
  hinge.enableMotor = true;
  hinge.motorSpeed = 2;
  hinge.maxMotorForce = 50;
  hinge.collideConnected = true;
  hinge.name = "elbow";
  v.push_back(hinge);
  JointDef fixed;
  fixed.type = JointType::Fixed;
  fixed.bodyA = id(3);
  fixed.bodyB = id(4);
  v.push_back(fixed);
  JointDef dist;
  dist.type = JointType::Distance;
  dist.bodyB = id(2);  // to the world
  dist.anchorA = {0, 0, 4};
  dist.length = 2;
  dist.springHertz = 2;
  dist.springDampingRatio = 0.5f;
  dist.enableLimit = true;
  dist.lower = 1;
  dist.upper = 3;
  v.push_back(dist);
  JointDef prism;
  prism.type = JointType::Prismatic;
  prism.bodyA = id(1);
  prism.bodyB = id(3);
  prism.axisA = prism.axisB = {0, 0, 1};
  prism.enableLimit = true;
  prism.lower = -0.5f;
  prism.upper = 0.5f;
  prism.enableMotor = true;
  prism.motorSpeed = 0.1f;
  prism.maxMotorForce = 10;
  v.push_back(prism);
  return v;
}

const char* kSceneJson = R"({
  "name": "fuzz_all_kinds",
  "gravity": [0, 0, -9.81], "time_step": 0.0166,
  "solver": {"substeps": 2, "iterations": 2, "stabilization": "soft"},
  "sleep": {"enabled": true, "time": 0.5, "linear_speed": 0.05, "angular_speed": 0.5},
  "materials": {"default": {"friction": 0.6}, "bouncy": {"restitution": 0.5, "density": 300}},
  "bodies": [
    {"name": "ground", "type": "static", "shapes": [{"type": "plane"}]},
    {"name": "box", "position": [0, 0, 0.5], "shapes": [{"type": "box", "half_extents": [0.5, 0.5, 0.5]}]},
    {"name": "ball", "position": [0, 0, 2], "material": "bouncy", "shapes": [{"type": "sphere", "radius": 0.3}]},
    {"name": "pill", "position": [2, 0, 1], "rotation_axis_angle": [0, 1, 0, 1.2],
     "shapes": [{"type": "capsule", "radius": 0.2, "half_height": 0.4}]},
    {"name": "tetra", "position": [-2, 0, 1], "mass": 3, "inertia": [0.1, 0.1, 0.1],
     "shapes": [{"type": "hull", "points": [[0.5, 0.5, 0.5], [-0.5, -0.5, 0.5], [-0.5, 0.5, -0.5], [0.5, -0.5, -0.5]]}]},
    {"name": "arm", "type": "kinematic", "position": [0, 3, 1], "angular_velocity": [0, 0, 1],
     "shapes": [{"type": "box", "half_extents": [1, 0.1, 0.1], "position": [0.5, 0, 0]}]}
  ],
  "joints": [
    {"type": "ball", "body_a": "box", "body_b": "ball", "anchor_world": [0, 0, 1.5]},
    {"type": "hinge", "body_a": null, "body_b": "pill", "anchor_world": [2, 0, 2], "axis_world": [0, 1, 0],
     "limit": {"lower": -1, "upper": 1}, "motor": {"speed": 1, "max_force": 5}},
    {"type": "fixed", "body_a": 1, "body_b": 4, "anchor_world": [-1, 0, 1]},
    {"type": "distance", "body_a": "ball", "body_b": "tetra", "length": 3, "spring_hertz": 2, "spring_damping_ratio": 0.3},
    {"type": "prismatic", "body_a": "box", "body_b": "pill", "axis_world": [1, 0, 0], "limit": {"lower": -0.5, "upper": 0.5}}
  ],
  "generators": [
    {"type": "pyramid", "name": "pyr", "base": 3, "half_extent": 0.25, "origin": [5, 0, 0]},
    {"type": "chain", "name": "chain", "links": 4, "link_length": 0.4, "link_radius": 0.05,
     "link_mass": 1, "anchor": [0, 6, 4], "direction": [1, 0, 0], "end_ball": {"radius": 0.2, "mass": 5}}
  ],
  "metrics": {"top_bodies": ["pyr/*"], "settle_time": 1, "groups": {"movers": ["ball", "pill"]},
              "params": {"finish_x": 10}},
  "criteria": [{"metric": "nan", "max": 0}]
})";

}  // namespace

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: %s OUT_DIR (e.g. fuzz/corpus)\n", argv[0]);
    return 2;
  }
  gOut = argv[1];
  const std::string tmp =
      (fs::temp_directory_path() / ("phys_make_corpus_" + std::to_string(getpid()))).string();
  fuzz::FuzzServer server(tmp);
  if (!server.ok()) {
    std::fprintf(stderr, "fuzz server: %s\n", server.error.c_str());
    return 1;
  }
  const std::vector<uint64_t>& b = server.bodies;
  const std::vector<uint64_t>& j = server.joints;
  const std::vector<BodyDef> bodies = spawnSet();
  const std::vector<JointDef> joints = jointSet(b);

  // --- Commands: apply/ and codec/cmd-* ---
  writeBoth("hello", CommandBuilder().hello("fuzz-seed").finish(hdr(0)));
  {
    CreateWorldArgs args;
    args.name = "second";
    args.preset = "pgs";
    args.gravity = Vec3{0, 0, -1.62f};
    args.timeStep = 0.01f;
    args.backend = "cpu";
    args.sleep = false;
    args.editors = {fuzz::kClient + 1, fuzz::kClient + 2};
    writeBoth("create_world", CommandBuilder().createWorld(args).finish(hdr(0)));
    CreateWorldArgs defaults;
    defaults.name = "third";
    writeBoth("create_world_defaults", CommandBuilder().createWorld(defaults).finish(hdr(0)));
    CreateWorldArgs shared;
    shared.name = "fourth";
    shared.backend = "cpu";
    shared.ephemeral = true;
    shared.shared = true;
    writeBoth("create_world_shared", CommandBuilder().createWorld(shared).finish(hdr(0)));
  }
  writeBoth("destroy_world", CommandBuilder().destroyWorld().finish(hdr()));
  writeBoth("reset_world", CommandBuilder().resetWorld().finish(hdr()));
  writeBoth("list_worlds", CommandBuilder().listWorlds().finish(hdr(0)));
  writeBoth("load_scene_json", CommandBuilder().loadSceneJson(kSceneJson).finish(hdr()));
  writeBoth("load_scene_named", CommandBuilder().loadSceneNamed("ball_and_chain").finish(hdr()));
  writeBoth("load_scene_named_pyramid", CommandBuilder().loadSceneNamed("pyramid_20").finish(hdr()));
  writeBoth("spawn_bodies", CommandBuilder().spawnBodies(bodies).finish(hdr()));
  {
    const uint64_t ids[] = {b[1], b[4]};
    writeBoth("remove_bodies", CommandBuilder().removeBodies(ids).finish(hdr()));
  }
  writeBoth("add_joints", CommandBuilder().addJoints(joints).finish(hdr()));
  for (size_t i = 0; i < joints.size(); ++i)
    writeBoth("add_joint_" + std::string(toString(joints[i].type)),
              CommandBuilder().addJoints({&joints[i], 1}).finish(hdr()));
  {
    const uint64_t ids[] = {j[0]};
    writeBoth("remove_joints", CommandBuilder().removeJoints(ids).finish(hdr()));
  }
  {
    const Quat q = Quat::fromAxisAngle({0, 1, 0}, 0.5f);
    const wire::BodyPose poses[] = {
        {b[1], wire::Pose(wire::Vec3(0.5f, 0, 2), wire::Quat(q.x, q.y, q.z, q.w))},
        {b[4], wire::Pose(wire::Vec3(-2, 1, 1), wire::Quat(0, 0, 0, 1))}};
    writeBoth("set_body_pose", CommandBuilder().setBodyPose(poses).finish(hdr()));
  }
  writeBoth("set_body_velocity",
            CommandBuilder().setBodyVelocity(b[2], {0, 0, 5}, {1, 0, 0}).finish(hdr()));
  writeBoth("apply_force", CommandBuilder()
                               .applyForce(b[1], {0, 0, 200}, {0.5f, 0, 0}, wire::PointFrame::Local)
                               .finish(hdr()));
  writeBoth("apply_force_world",
            CommandBuilder()
                .applyForce(b[3], {50, 0, 0}, {2, 0, 1}, wire::PointFrame::World)
                .finish(hdr()));
  writeBoth("apply_impulse", CommandBuilder().applyImpulse(b[2], {0, 3, 0}).finish(hdr()));
  writeBoth("apply_impulse_world",
            CommandBuilder()
                .applyImpulse(b[4], {1, 0, 0}, {-2, 0.2f, 0.7f}, wire::PointFrame::World)
                .finish(hdr()));
  writeBoth("apply_torque", CommandBuilder().applyTorque(b[4], {0, 0, 20}).finish(hdr()));
  {
    const uint64_t ids[] = {b[1], b[2], b[3]};
    writeBoth("set_material",
              CommandBuilder().setMaterial(ids, {0.2f, 0.8f, 2000}).finish(hdr()));
  }
  {
    SolverOverrides o;
    o.substeps = 2;
    o.iterations = 3;
    o.scheme = SolverSettings::Scheme::Jacobi;
    o.contactHertz = 20;
    o.warmStart = false;
    writeBoth("set_solver", CommandBuilder().setSolver("pgs", o).finish(hdr()));
    writeBoth("set_solver_all",
              CommandBuilder().setSolver("", SolverOverrides::from(SolverSettings())).finish(hdr()));
  }
  writeBoth("step", CommandBuilder().step(1).finish(hdr()));
  writeBoth("step_8", CommandBuilder().step(8).finish(hdr()));
  writeBoth("run", CommandBuilder().run(60).finish(hdr()));
  writeBoth("run_fast", CommandBuilder().run(0).finish(hdr()));
  writeBoth("pause", CommandBuilder().pause().finish(hdr()));
  {
    const uint64_t ids[] = {b[1], b[2]};
    writeBoth("subscribe_bodies", CommandBuilder().subscribeBodies(ids).finish(hdr()));
  }
  writeBoth("subscribe_region",
            CommandBuilder().subscribeRegion({-3, -3, 0}, {3, 3, 3}).finish(hdr()));
  writeBoth("unsubscribe", CommandBuilder().unsubscribe(fuzz::kInterest).finish(hdr()));
  {
    const uint64_t editors[] = {fuzz::kClient + 1, 0xE0D170Bull};
    writeBoth("set_access", CommandBuilder().setAccess(editors, false).finish(hdr()));
    writeBoth("set_access_shared", CommandBuilder().setAccess({}, true).finish(hdr()));
    writeBoth("move_world", CommandBuilder().moveWorld(2).finish(hdr()));
  }
  writeBoth("query_state", CommandBuilder().queryState().finish(hdr()));
  {
    const uint64_t ids[] = {b[2], b[5]};
    writeBoth("query_state_ids", CommandBuilder().queryState(ids, 0, 1).finish(hdr()));
  }
  writeBoth("save_snapshot", CommandBuilder().saveSnapshot().finish(hdr()));
  writeBoth("save_snapshot_file", CommandBuilder().saveSnapshot("mine.snap", false).finish(hdr()));
  writeBoth("restore_snapshot_engine",
            CommandBuilder().restoreSnapshot(server.snapshot).finish(hdr()));
  SnapshotData portable;
  portable.name = "portable";
  portable.gravity = {0, 0, -5};
  portable.timeStep = 0.02f;
  portable.tick = 7;
  portable.time = 0.14;
  {
    const std::vector<BodyDef> base = fuzz::baseBodies();
    for (size_t i = 0; i < base.size(); ++i) portable.bodies.push_back({b[i], base[i]});
    const std::vector<JointDef> bj = fuzz::baseJoints(b);
    for (size_t i = 0; i < bj.size(); ++i) portable.joints.push_back({j[i], bj[i]});
  }
  const Bytes portableSnap = encodeSnapshot(portable);
  writeBoth("restore_snapshot_portable",
            CommandBuilder().restoreSnapshot(portableSnap).finish(hdr()));
  writeBoth("restore_snapshot_file",
            CommandBuilder().restoreSnapshotFile(fuzz::kBaseSnapshotFile).finish(hdr()));
  {
    const uint64_t gone[] = {b[5]};
    SolverOverrides one;
    one.substeps = 1;
    writeBoth("batch", CommandBuilder()
                           .spawnBodies(bodies)
                           .addJoints({&joints[1], 1})
                           .setBodyPose(b[1], {0, 0, 1}, Quat{})
                           .setBodyVelocity(b[2], {0, 1, 0}, {})
                           .applyForce(b[3], {1, 0, 0})
                           .applyImpulse(b[4], {0, 0, 1})
                           .applyTorque(b[1], {0, 0, 1})
                           .setMaterial(gone, {0.1f, 0, 100})
                           .setSolver("", one)
                           .removeJoints({&j[1], 1})
                           .removeBodies(gone)
                           .finish(hdr()));
  }

  // --- Published data: codec/ ---
  ReplyHeader rh;
  rh.clientId = fuzz::kClient;
  rh.seq = 9;
  rh.world = fuzz::kWorld;
  rh.tick = 120;
  write("codec", "reply-ok", encodeReply(rh));
  {
    ReplyHeader e = rh;
    e.status = protocol::Status::Error(Code::InvalidArgument, "spawn_bodies.bodies[0].mass must be > 0");
    write("codec", "reply-error", encodeReply(e));
  }
  HelloInfo hello;
  hello.serverName = "physd";
  hello.serverVersion = "0.1.0";
  hello.features = {"batch", "snapshots", "interests", "compact_states"};
  write("codec", "reply-hello", encodeHelloReply(rh, hello));
  write("codec", "reply-ids", encodeIdsReply(rh, b, j));
  WorldSummary ws;
  ws.world = 1;
  ws.name = "fuzz";
  ws.preset = "soft_step";
  ws.bodies = 6;
  ws.joints = 2;
  ws.tick = 120;
  ws.time = 2;
  ws.running = true;
  ws.rateHz = 60;
  ws.tickMs = 0.2f;
  ws.tickMsMax = 0.5f;
  ws.subscribers = 2;
  ws.frames = 100;
  ws.backend = "cpu";
  ws.backendNote = "no Vulkan device";
  ws.cpuSteps = 120;
  ws.awakeBodies = 4;
  ws.sleepingBodies = 1;
  ws.frameBytes = 640;
  WorldSummary ws2 = ws;
  ws2.world = 2;
  ws2.name = "second";
  ws2.running = false;
  const WorldSummary summaries[] = {ws, ws2};
  write("codec", "reply-world_list", encodeWorldListReply(rh, summaries));
  std::vector<wire::BodyState> states;
  {
    const server::ServerWorld* sw = server.core->world(fuzz::kWorld);
    for (uint64_t id : b) {
      BodyState s;
      sw->world->getBody(BodyId::fromPacked(id), &s);
      states.push_back(toWire(s));
    }
  }
  write("codec", "reply-state", encodeStateReply(rh, 2.0, uint32_t(states.size()), states));
  write("codec", "reply-interest", encodeInterestReply(rh, 1, "phys/state/1/1"));
  write("codec", "reply-snapshot", encodeSnapshotReply(rh, server.snapshot, "a.snap"));
  FrameHeader fh;
  fh.world = 1;
  fh.tick = 120;
  fh.time = 2;
  fh.stampNs = 1'790'000'000'000'000'000ull;
  write("codec", "frame-keyframe", encodeStateFrame(fh, 0, 1, uint32_t(states.size()), states));
  {
    FrameHeader d = fh;
    d.keyframe = false;
    d.baseTick = 119;
    d.refreshLo = 0;
    d.refreshHi = refreshKey(b[2]);
    const std::vector<wire::BodyState> some(states.begin() + 1, states.begin() + 3);
    const uint64_t removed[] = {b[5]};
    write("codec", "frame-delta", encodeStateFrame(d, 0, 2, 6, some, removed));
    d.compact = true;
    d.interest = 1;
    write("codec", "frame-delta-compact", encodeStateFrame(d, 1, 2, 6, some));
  }
  {
    FrameHeader c = fh;
    c.compact = true;
    write("codec", "frame-compact", encodeStateFrame(c, 0, 1, uint32_t(states.size()), states));
  }
  std::vector<BodyEntry> entries;
  std::vector<JointEntry> jentries;
  {
    const std::vector<BodyDef> base = fuzz::baseBodies();
    for (size_t i = 0; i < base.size(); ++i) entries.push_back({b[i], base[i]});
    for (size_t i = 0; i < bodies.size(); ++i) entries.push_back({(uint64_t(1) << 32) | (10 + i), bodies[i]});
    const std::vector<JointDef> bj = fuzz::baseJoints(b);
    for (size_t i = 0; i < bj.size(); ++i) jentries.push_back({j[i], bj[i]});
    for (size_t i = 0; i < joints.size(); ++i)
      jentries.push_back({(uint64_t(1) << 32) | (10 + i), joints[i]});
  }
  WorldInfoHeader wh;
  wh.world = 1;
  wh.name = "fuzz";
  wh.revision = 3;
  wh.tick = 120;
  {
    const std::vector<Bytes> chunks = encodeWorldInfo(wh, entries, jentries);
    for (size_t i = 0; i < chunks.size(); ++i)
      write("codec", "world_info-" + std::to_string(i), chunks[i]);
    Limits small;
    small.maxBodiesPerCommand = 4;
    const std::vector<Bytes> more = encodeWorldInfo(wh, entries, jentries, small);
    for (size_t i = 0; i < more.size() && i < 4; ++i)
      write("codec", "world_info-chunked-" + std::to_string(i), more[i]);
  }
  ServerStatusInfo status;
  status.serverName = "physd";
  status.serverVersion = "0.1.0";
  status.uptimeS = 3600;
  status.commands = 1000;
  status.errors = 3;
  status.worlds = {ws, ws2};
  status.framesDropped = 2;
  write("codec", "status", encodeServerStatus(status));
  write("codec", "event", encodeEvent(1, 120, wire::Severity::Warning, "guard_rollback",
                                      "step 120 redone with 8 substeps"));
  write("codec", "snapshot-engine", server.snapshot);
  write("codec", "snapshot-portable", portableSnap);

  // --- Scenes: scene/ ---
  write("scene", "all_kinds.json", std::vector<uint8_t>(kSceneJson, kSceneJson + std::strlen(kSceneJson)));
  const char* scenes[] = {"default",     "box_stack",        "ball_and_chain", "windmill",
                          "free_flight", "restitution",      "friction_ramp",  "tunnelling",
                          "overlap",     "suspension_bridge", "vertical_stack", "pyramid_20",
                          "mass_ratio_10", "many_pyramids",  "pile_10k",       "fanout_10k_active"};
  for (const char* s : scenes) {
    std::ifstream in(std::string(PHYS_SOURCE_DIR) + "/configs/scenes/" + s + ".json",
                     std::ios::binary);
    std::vector<uint8_t> text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    if (text.empty() || text.size() > 64 * 1024) {
      std::fprintf(stderr, "configs/scenes/%s.json: missing or over 64 KiB\n", s);
      return 1;
    }
    write("scene", std::string(s) + ".json", text);
  }

  // --- Engine snapshots: restore/ ---
  auto saveTo = [](const World& w, const std::string& name) {
    Bytes snap;
    phys::Status st = w.saveSnapshot(&snap);
    if (!st.ok()) {
      std::fprintf(stderr, "restore/%s: %s\n", name.c_str(), st.message.c_str());
      std::exit(1);
    }
    write("restore", name, snap);
    return snap;
  };
  saveTo(World(forge::worldDef()), "empty_world");
  {
    World w(forge::worldDef());
    if (!forge::buildWorld(w)) {
      std::fprintf(stderr, "restore: snapshot_forge.h's world could not be built\n");
      return 1;
    }
    const Bytes snap = saveTo(w, "forge_world");
    for (const forge::Forgery& f : forge::forgeries(snap)) {
      if (f.bytes.empty()) {
        std::fprintf(stderr, "restore: forged case %s: its field is not in the snapshot\n",
                     f.name.c_str());
        return 1;
      }
      write("restore", "forged-" + f.name, f.bytes);
    }
  }
  for (const char* name : {"restitution", "friction_ramp", "tunnelling"}) {
    Scene scene;
    phys::Status st =
        loadSceneFile(std::string(PHYS_SOURCE_DIR) + "/configs/scenes/" + name + ".json", &scene);
    WorldDef def = scene.world;
    def.threads = 1;
    def.backend = Backend::Cpu;
    World w(def);
    std::vector<BodyId> ids;
    if (st.ok()) st = instantiateScene(scene, &w, &ids);
    if (!st.ok()) {
      std::fprintf(stderr, "restore/%s: %s\n", name, st.message.c_str());
      return 1;
    }
    for (int i = 0; i < 30; ++i) w.step();
    saveTo(w, name);
  }

  server.core.reset();
  std::error_code ec;
  fs::remove_all(tmp, ec);
  std::printf("wrote %d seeds under %s\n", gWritten, gOut.c_str());
  return 0;
}
