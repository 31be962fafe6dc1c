// Every builder's output decodes back to what was built.
#include <cmath>

#include "protocol_test_util.h"

namespace phys::protocol::test {
namespace {

void expectVec(phys::Vec3 a, phys::Vec3 b) {
  EXPECT_EQ(a.x, b.x);
  EXPECT_EQ(a.y, b.y);
  EXPECT_EQ(a.z, b.z);
}

void expectQuatNear(phys::Quat a, phys::Quat b) {
  EXPECT_NEAR(a.x, b.x, 1e-6f);
  EXPECT_NEAR(a.y, b.y, 1e-6f);
  EXPECT_NEAR(a.z, b.z, 1e-6f);
  EXPECT_NEAR(a.w, b.w, 1e-6f);
}

void expectBodyEq(const phys::BodyDef& a, const phys::BodyDef& b) {
  EXPECT_EQ(a.type, b.type);
  expectVec(a.position, b.position);
  expectQuatNear(a.rotation, b.rotation);
  expectVec(a.linearVelocity, b.linearVelocity);
  expectVec(a.angularVelocity, b.angularVelocity);
  EXPECT_EQ(a.linearDamping, b.linearDamping);
  EXPECT_EQ(a.angularDamping, b.angularDamping);
  EXPECT_EQ(a.gravityScale, b.gravityScale);
  EXPECT_EQ(a.mass, b.mass);
  expectVec(a.inertia, b.inertia);
  EXPECT_EQ(a.gyroscopic, b.gyroscopic);
  EXPECT_EQ(a.name, b.name);
  ASSERT_EQ(a.shapes.size(), b.shapes.size());
  for (size_t i = 0; i < a.shapes.size(); ++i) {
    const phys::ShapeDef &x = a.shapes[i], &y = b.shapes[i];
    EXPECT_EQ(x.geom.type, y.geom.type);
    switch (x.geom.type) {
      case phys::ShapeType::Sphere:
        EXPECT_EQ(x.geom.radius, y.geom.radius);
        break;
      case phys::ShapeType::Box:
        expectVec(x.geom.halfExtents, y.geom.halfExtents);
        break;
      case phys::ShapeType::Capsule:
        EXPECT_EQ(x.geom.radius, y.geom.radius);
        EXPECT_EQ(x.geom.halfHeight, y.geom.halfHeight);
        break;
      case phys::ShapeType::Plane:
        expectVec(x.geom.normal, y.geom.normal);
        EXPECT_EQ(x.geom.offset, y.geom.offset);
        break;
      case phys::ShapeType::Hull:
        // A hull travels as its points: the built hull's vertices, unbuilt on arrival.
        ASSERT_TRUE(y.geom.hull);
        EXPECT_FALSE(y.geom.hull->built());
        ASSERT_EQ(x.geom.hull->vertices.size(), y.geom.hull->vertices.size());
        for (size_t v = 0; v < x.geom.hull->vertices.size(); ++v)
          expectVec(x.geom.hull->vertices[v], y.geom.hull->vertices[v]);
        break;
    }
    expectVec(x.local.p, y.local.p);
    expectQuatNear(x.local.q, y.local.q);
    EXPECT_EQ(x.material.friction, y.material.friction);
    EXPECT_EQ(x.material.restitution, y.material.restitution);
    EXPECT_EQ(x.material.density, y.material.density);
  }
}

TEST(ProtocolRoundTrip, Hello) {
  auto d = mustDecode(CommandBuilder().hello("tester").finish(header(5, 0)));
  EXPECT_EQ(d->client_id(), kClient);
  EXPECT_EQ(d->seq(), 5u);
  EXPECT_EQ(d->world(), 0u);
  ASSERT_EQ(d->request_type(), wire::Request::Hello);
  EXPECT_EQ(d->request_as_Hello()->protocol_version(), kProtocolVersion);
  EXPECT_EQ(d->request_as_Hello()->client_name()->str(), "tester");
}

TEST(ProtocolRoundTrip, CreateWorld) {
  CreateWorldArgs a;
  a.name = "arena";
  a.preset = "soft_step";
  a.gravity = phys::Vec3{0, 0, -1.62f};
  a.timeStep = 1.0f / 120;
  a.backend = "gpu";
  auto d = mustDecode(CommandBuilder().createWorld(a).finish(header(1, 0)));
  auto* r = d->request_as_CreateWorld();
  ASSERT_TRUE(r);
  EXPECT_EQ(r->name()->str(), "arena");
  EXPECT_EQ(r->preset()->str(), "soft_step");
  expectVec(toPhys(*r->gravity()), {0, 0, -1.62f});
  EXPECT_EQ(r->time_step(), 1.0f / 120);
  ASSERT_TRUE(r->backend());
  EXPECT_EQ(r->backend()->str(), "gpu");

  // Defaults: no gravity, no preset, time step 0 (the server's 1/60), no backend (the
  // server's default).
  auto d2 = mustDecode(CommandBuilder().createWorld({"plain", "", {}, 0}).finish(header(2, 0)));
  EXPECT_EQ(d2->request_as_CreateWorld()->gravity(), nullptr);
  EXPECT_EQ(d2->request_as_CreateWorld()->preset(), nullptr);
  EXPECT_EQ(d2->request_as_CreateWorld()->time_step(), 0.0f);
  EXPECT_EQ(d2->request_as_CreateWorld()->backend(), nullptr);

  // Every backend name decodes.
  for (const char* b : {"cpu", "gpu", "auto"}) {
    auto d3 = mustDecode(CommandBuilder().createWorld({"w", "", {}, 0, b}).finish(header(3, 0)));
    EXPECT_EQ(d3->request_as_CreateWorld()->backend()->str(), b);
  }
}

TEST(ProtocolRoundTrip, WorldLifecycleAndTime) {
  EXPECT_EQ(mustDecode(CommandBuilder().destroyWorld().finish(header()))->request_type(),
            wire::Request::DestroyWorld);
  EXPECT_EQ(mustDecode(CommandBuilder().resetWorld().finish(header()))->request_type(),
            wire::Request::ResetWorld);
  EXPECT_EQ(mustDecode(CommandBuilder().listWorlds().finish(header(1, 0)))->request_type(),
            wire::Request::ListWorlds);
  EXPECT_EQ(mustDecode(CommandBuilder().pause().finish(header()))->request_type(),
            wire::Request::Pause);
  auto step = mustDecode(CommandBuilder().step(240).finish(header()));
  EXPECT_EQ(step->request_as_Step()->count(), 240u);
  auto run = mustDecode(CommandBuilder().run(0).finish(header()));
  EXPECT_EQ(run->request_as_Run()->rate_hz(), 0.0f);
  auto run60 = mustDecode(CommandBuilder().run(60).finish(header()));
  EXPECT_EQ(run60->request_as_Run()->rate_hz(), 60.0f);
}

TEST(ProtocolRoundTrip, LoadScene) {
  auto a = mustDecode(
      CommandBuilder().loadSceneJson("{\"name\": \"x\",\n\"bodies\": []}").finish(header()));
  EXPECT_EQ(a->request_as_LoadScene()->json()->str(), "{\"name\": \"x\",\n\"bodies\": []}");
  EXPECT_EQ(a->request_as_LoadScene()->scene_name(), nullptr);
  auto b = mustDecode(CommandBuilder().loadSceneNamed("pyramid_20").finish(header()));
  EXPECT_EQ(b->request_as_LoadScene()->scene_name()->str(), "pyramid_20");
}

TEST(ProtocolRoundTrip, SpawnBodiesEveryShape) {
  std::vector<phys::BodyDef> bodies = sampleBodies();
  auto d = mustDecode(CommandBuilder().spawnBodies(bodies).finish(header()));
  auto* v = d->request_as_SpawnBodies()->bodies();
  ASSERT_EQ(v->size(), bodies.size());
  for (size_t i = 0; i < bodies.size(); ++i) {
    phys::BodyDef back;
    Status st = toBodyDef(*v->Get(uint32_t(i)), &back);
    ASSERT_TRUE(st.ok()) << st.message;
    SCOPED_TRACE(i);
    expectBodyEq(bodies[i], back);
  }
}

TEST(ProtocolRoundTrip, SpawnedBodiesAreAcceptedByTheWorld) {
  std::vector<phys::BodyDef> bodies = sampleBodies();
  auto d = mustDecode(CommandBuilder().spawnBodies(bodies).finish(header()));
  phys::World world;
  for (const wire::BodyDef* b : *d->request_as_SpawnBodies()->bodies()) {
    phys::BodyDef def;
    ASSERT_TRUE(toBodyDef(*b, &def).ok());
    phys::BodyId id;
    phys::Status st = world.createBody(def, &id);
    EXPECT_TRUE(st.ok()) << st.message;
  }
  EXPECT_EQ(world.bodyCount(), int(bodies.size()));
}

TEST(ProtocolRoundTrip, RemoveAndJoints) {
  std::vector<uint64_t> ids = {phys::BodyId{1, 1}.packed(), phys::BodyId{2, 7}.packed()};
  auto r = mustDecode(CommandBuilder().removeBodies(ids).finish(header()));
  ASSERT_EQ(r->request_as_RemoveBodies()->bodies()->size(), 2u);
  EXPECT_EQ(r->request_as_RemoveBodies()->bodies()->Get(1), ids[1]);

  phys::JointDef j = sampleJoint();
  auto a = mustDecode(CommandBuilder().addJoints({&j, 1}).finish(header()));
  phys::JointDef back = toJointDef(*a->request_as_AddJoints()->joints()->Get(0));
  EXPECT_EQ(back.type, j.type);
  EXPECT_EQ(back.bodyA, j.bodyA);
  EXPECT_EQ(back.bodyB, j.bodyB);
  expectVec(back.anchorA, j.anchorA);
  expectVec(back.anchorB, j.anchorB);
  expectVec(back.axisA, j.axisA);
  expectVec(back.axisB, j.axisB);
  EXPECT_EQ(back.enableLimit, j.enableLimit);
  EXPECT_EQ(back.lower, j.lower);
  EXPECT_EQ(back.upper, j.upper);
  EXPECT_EQ(back.enableMotor, j.enableMotor);
  EXPECT_EQ(back.motorSpeed, j.motorSpeed);
  EXPECT_EQ(back.maxMotorForce, j.maxMotorForce);
  EXPECT_EQ(back.length, j.length);
  EXPECT_EQ(back.collideConnected, j.collideConnected);
  EXPECT_EQ(back.name, j.name);

  // Every joint type, world-anchored (body_a null).
  for (int t = 0; t <= int(phys::JointType::Prismatic); ++t) {
    phys::JointDef w;
    w.type = phys::JointType(t);
    w.bodyB = phys::BodyId{1, 1};
    w.length = 2;
    w.springHertz = 3;
    w.springDampingRatio = 0.5f;
    auto dw = mustDecode(CommandBuilder().addJoints({&w, 1}).finish(header()));
    phys::JointDef bw = toJointDef(*dw->request_as_AddJoints()->joints()->Get(0));
    EXPECT_EQ(bw.type, w.type);
    EXPECT_TRUE(bw.bodyA.isNull());
    EXPECT_EQ(bw.length, 2);
    EXPECT_EQ(bw.springHertz, 3);
    EXPECT_EQ(bw.springDampingRatio, 0.5f);
  }

  auto rj = mustDecode(CommandBuilder().removeJoints(ids).finish(header()));
  EXPECT_EQ(rj->request_as_RemoveJoints()->joints()->Get(0), ids[0]);
}

TEST(ProtocolRoundTrip, PosesVelocitiesForces) {
  phys::Quat q = phys::Quat::fromAxisAngle({0, 1, 0}, 1.0f);
  auto p = mustDecode(CommandBuilder().setBodyPose(42, {1, 2, 3}, q).finish(header()));
  const wire::BodyPose* bp = p->request_as_SetBodyPose()->items()->Get(0);
  EXPECT_EQ(bp->id(), 42u);
  expectVec(toPhys(bp->pose().position()), {1, 2, 3});
  expectQuatNear(toPhys(bp->pose().rotation()), q);

  auto v = mustDecode(CommandBuilder().setBodyVelocity(42, {1, 0, 0}, {0, 0, 2}).finish(header()));
  const wire::BodyVelocity* bv = v->request_as_SetBodyVelocity()->items()->Get(0);
  expectVec(toPhys(bv->linear()), {1, 0, 0});
  expectVec(toPhys(bv->angular()), {0, 0, 2});

  auto f = mustDecode(CommandBuilder()
                          .applyForce(42, {0, 0, 10}, {1, 0, 0}, wire::PointFrame::Local)
                          .finish(header()));
  EXPECT_EQ(f->request_as_ApplyForce()->point_frame(), wire::PointFrame::Local);
  expectVec(toPhys(f->request_as_ApplyForce()->items()->Get(0)->vector()), {0, 0, 10});
  expectVec(toPhys(f->request_as_ApplyForce()->items()->Get(0)->point()), {1, 0, 0});

  auto i = mustDecode(CommandBuilder().applyImpulse(42, {5, 0, 0}).finish(header()));
  EXPECT_EQ(i->request_as_ApplyImpulse()->point_frame(), wire::PointFrame::CenterOfMass);
  expectVec(toPhys(i->request_as_ApplyImpulse()->items()->Get(0)->vector()), {5, 0, 0});

  auto t = mustDecode(CommandBuilder().applyTorque(42, {0, 0, 3}).finish(header()));
  expectVec(toPhys(t->request_as_ApplyTorque()->items()->Get(0)->torque()), {0, 0, 3});

  // Many items in one command: vectors of structs.
  std::vector<wire::BodyForce> many;
  for (uint64_t k = 1; k <= 1000; ++k)
    many.emplace_back(k, toWire(phys::Vec3{0, 0, float(k)}), wire::Vec3(0, 0, 0));
  auto m = mustDecode(CommandBuilder().applyForce(many, wire::PointFrame::World).finish(header()));
  EXPECT_EQ(m->request_as_ApplyForce()->items()->size(), 1000u);
  EXPECT_EQ(m->request_as_ApplyForce()->items()->Get(999)->vector().z(), 1000.0f);
}

TEST(ProtocolRoundTrip, MaterialAndSolver) {
  std::vector<uint64_t> ids = {9};
  auto m = mustDecode(CommandBuilder().setMaterial(ids, {0.1f, 0.9f, 2000}).finish(header()));
  phys::Material mat = toPhys(*m->request_as_SetMaterial()->material());
  EXPECT_EQ(mat.friction, 0.1f);
  EXPECT_EQ(mat.restitution, 0.9f);
  EXPECT_EQ(mat.density, 2000.0f);

  // A preset alone.
  auto p = mustDecode(CommandBuilder().setSolver("pgs").finish(header()));
  EXPECT_EQ(p->request_as_SetSolver()->preset()->str(), "pgs");
  EXPECT_EQ(p->request_as_SetSolver()->settings(), nullptr);

  // Some fields: only those arrive.
  SolverOverrides o;
  o.substeps = 8;
  o.scheme = phys::SolverSettings::Scheme::Jacobi;
  o.equalitySolve = phys::SolverSettings::EqualitySolve::Iterative;
  o.warmStart = false;
  o.contactHertz = 30;
  auto s = mustDecode(CommandBuilder().setSolver("", o).finish(header()));
  SolverOverrides back = toOverrides(*s->request_as_SetSolver()->settings());
  EXPECT_EQ(back.substeps, 8);
  EXPECT_EQ(back.scheme, phys::SolverSettings::Scheme::Jacobi);
  EXPECT_EQ(back.warmStart, false);
  EXPECT_EQ(back.contactHertz, 30.0f);
  EXPECT_FALSE(back.iterations.has_value());
  EXPECT_FALSE(back.baumgarte.has_value());
  phys::SolverSettings merged;
  applyOverrides(back, &merged);
  EXPECT_EQ(merged.substeps, 8);
  EXPECT_EQ(merged.iterations, phys::SolverSettings().iterations);
  EXPECT_TRUE(phys::World::validate(merged).ok());

  // Every field: SolverFields.EachFieldAloneCrossesTheWire.
}

TEST(ProtocolRoundTrip, QueryAndSnapshots) {
  auto all = mustDecode(CommandBuilder().queryState({}, 100, 50).finish(header()));
  EXPECT_EQ(all->request_as_QueryState()->bodies(), nullptr);
  EXPECT_EQ(all->request_as_QueryState()->first(), 100u);
  EXPECT_EQ(all->request_as_QueryState()->max_count(), 50u);
  std::vector<uint64_t> ids = {3, 4};
  auto some = mustDecode(CommandBuilder().queryState(ids).finish(header()));
  EXPECT_EQ(some->request_as_QueryState()->bodies()->size(), 2u);

  auto save = mustDecode(CommandBuilder().saveSnapshot("run-1.snap", false).finish(header()));
  EXPECT_EQ(save->request_as_SaveSnapshot()->file()->str(), "run-1.snap");
  EXPECT_FALSE(save->request_as_SaveSnapshot()->return_bytes());

  auto file = mustDecode(CommandBuilder().restoreSnapshotFile("run-1.snap").finish(header()));
  EXPECT_EQ(file->request_as_RestoreSnapshot()->file()->str(), "run-1.snap");

  SnapshotData snap;
  snap.name = "w";
  snap.tick = 99;
  snap.time = 1.65;
  std::vector<phys::BodyDef> bodies = sampleBodies();
  for (size_t i = 0; i < bodies.size(); ++i)
    snap.bodies.push_back({phys::BodyId{uint32_t(i), 1}.packed(), bodies[i]});
  phys::JointDef j = sampleJoint();
  j.bodyA = phys::BodyId{1, 1};
  j.bodyB = phys::BodyId{2, 1};
  snap.joints.push_back({phys::JointId{0, 1}.packed(), j});
  Bytes sb = encodeSnapshot(snap);
  auto r = mustDecode(CommandBuilder().restoreSnapshot(sb).finish(header()));
  auto* bytes = r->request_as_RestoreSnapshot()->snapshot();
  ASSERT_EQ(bytes->size(), sb.size());
  // The nested snapshot starts 8-byte aligned, so it reads in place.
  EXPECT_EQ(reinterpret_cast<uintptr_t>(bytes->data()) % 8, 0u);
  auto ds = decodeSnapshot(std::span<const uint8_t>(bytes->data(), bytes->size()));
  ASSERT_TRUE(ds.ok()) << ds.status.message;
  EXPECT_EQ(ds.storage, nullptr);
  SnapshotData back;
  ASSERT_TRUE(toSnapshotData(*ds, &back).ok());
  EXPECT_EQ(back.name, "w");
  EXPECT_EQ(back.tick, 99u);
  EXPECT_EQ(back.time, 1.65);
  ASSERT_EQ(back.bodies.size(), bodies.size());
  for (size_t i = 0; i < bodies.size(); ++i) {
    EXPECT_EQ(back.bodies[i].id, snap.bodies[i].id);
    expectBodyEq(bodies[i], back.bodies[i].def);
  }
  ASSERT_EQ(back.joints.size(), 1u);
  EXPECT_EQ(back.joints[0].def.bodyB, j.bodyB);
  EXPECT_EQ(back.solver.substeps, snap.solver.substeps);
  EXPECT_EQ(back.solver.equalitySolve, snap.solver.equalitySolve);
}

TEST(ProtocolRoundTrip, EngineStateSnapshot) {
  // The engine's exact snapshot travels as opaque bytes, 8-byte aligned inside the command.
  SnapshotData snap;
  snap.name = "arena";
  snap.tick = 600;
  snap.time = 10;
  for (int i = 0; i < 1001; ++i) snap.engineState.push_back(uint8_t(i * 7));
  Bytes sb = encodeSnapshot(snap);
  auto r = mustDecode(CommandBuilder().restoreSnapshot(sb).finish(header()));
  auto* bytes = r->request_as_RestoreSnapshot()->snapshot();
  auto ds = decodeSnapshot(std::span<const uint8_t>(bytes->data(), bytes->size()));
  ASSERT_TRUE(ds.ok()) << ds.status.message;
  auto* engine = ds->engine_state();
  ASSERT_TRUE(engine);
  EXPECT_EQ(reinterpret_cast<uintptr_t>(engine->data()) % 8, 0u);
  SnapshotData back;
  ASSERT_TRUE(toSnapshotData(*ds, &back).ok());
  EXPECT_EQ(back.engineState, snap.engineState);
  EXPECT_EQ(back.name, "arena");
  EXPECT_EQ(back.tick, 600u);
  EXPECT_TRUE(back.bodies.empty());
}

TEST(ProtocolRoundTrip, BatchOfWorldEdits) {
  std::vector<phys::BodyDef> bodies = {boxBody({0, 0, 1}, {0.5f, 0.5f, 0.5f})};
  std::vector<uint64_t> ids = {5};
  CommandBuilder b;
  b.spawnBodies(bodies).removeBodies(ids).setBodyVelocity(6, {1, 0, 0}, {}).setSolver("pgs");
  EXPECT_EQ(b.requestCount(), 4u);
  auto d = mustDecode(b.finish(header(3)));
  EXPECT_EQ(b.requestCount(), 0u);
  ASSERT_EQ(d->request_type(), wire::Request::Batch);
  auto* cmds = d->request_as_Batch()->commands();
  ASSERT_EQ(cmds->size(), 4u);
  EXPECT_EQ(cmds->Get(0)->request_type(), wire::Request::SpawnBodies);
  EXPECT_EQ(cmds->Get(1)->request_type(), wire::Request::RemoveBodies);
  EXPECT_EQ(cmds->Get(2)->request_type(), wire::Request::SetBodyVelocity);
  EXPECT_EQ(cmds->Get(3)->request_type(), wire::Request::SetSolver);
  EXPECT_EQ(cmds->Get(0)->request_as_SpawnBodies()->bodies()->size(), 1u);

  // The builder is reusable after finish().
  auto again = mustDecode(b.step(2).finish(header(4)));
  EXPECT_EQ(again->request_type(), wire::Request::Step);
}

TEST(ProtocolRoundTrip, Replies) {
  auto cmd = mustDecode(CommandBuilder().step().finish(header(77)));
  ReplyHeader h = replyTo(*cmd);
  h.tick = 1234;
  auto ok = decodeReply(encodeReply(h));
  ASSERT_TRUE(ok.ok()) << ok.status.message;
  EXPECT_EQ(ok->client_id(), kClient);
  EXPECT_EQ(ok->seq(), 77u);
  EXPECT_EQ(ok->world(), kWorld);
  EXPECT_EQ(ok->tick(), 1234u);
  EXPECT_EQ(ok->status(), Code::Ok);
  EXPECT_EQ(ok->result_type(), wire::Result::NONE);

  ReplyHeader e = replyTo(*cmd, Status::Error(Code::NotFound, "body 0x100000003 is stale"));
  auto err = decodeReply(encodeReply(e));
  ASSERT_TRUE(err.ok());
  EXPECT_EQ(err->status(), Code::NotFound);
  EXPECT_EQ(err->message()->str(), "body 0x100000003 is stale");

  HelloInfo info{"physd", "0.1.0", {"gpu", "snapshots"}, Limits{}};
  auto hello = decodeReply(encodeHelloReply(h, info));
  ASSERT_TRUE(hello.ok());
  auto* hr = hello->result_as_HelloResult();
  ASSERT_TRUE(hr);
  EXPECT_EQ(hr->protocol_version(), kProtocolVersion);
  EXPECT_EQ(hr->server_name()->str(), "physd");
  EXPECT_EQ(hr->features()->size(), 2u);
  EXPECT_EQ(hr->features()->Get(1)->str(), "snapshots");
  EXPECT_EQ(hr->limits()->max_message_bytes(), kMaxEnvelopeBytes);
  EXPECT_EQ(hr->limits()->max_bodies_per_command(), Limits{}.maxBodiesPerCommand);

  std::vector<uint64_t> b = {1, 2, 3}, j = {9};
  auto ids = decodeReply(encodeIdsReply(h, b, j));
  ASSERT_TRUE(ids.ok());
  EXPECT_EQ(ids->result_as_Ids()->bodies()->size(), 3u);
  EXPECT_EQ(ids->result_as_Ids()->joints()->Get(0), 9u);

  WorldSummary w;
  w.world = 7;
  w.name = "arena";
  w.preset = "soft_step";
  w.bodies = 100;
  w.tick = 50;
  w.running = true;
  w.rateHz = 60;
  w.overruns = 2;
  w.frames = 48;
  w.backend = "gpu";
  w.device = "llvmpipe (LLVM 15.0.6, 256 bits)";
  w.backendNote = "hull shapes are not on the device yet";
  w.gpuSteps = 40;
  w.cpuSteps = 10;
  WorldSummary plain;  // a CPU world: no device, no note
  plain.world = 8;
  plain.backend = "cpu";
  plain.cpuSteps = 3;
  std::vector<WorldSummary> both = {w, plain};
  auto list = decodeReply(encodeWorldListReply(h, both));
  ASSERT_TRUE(list.ok());
  auto* ws = list->result_as_WorldList()->worlds()->Get(0);
  EXPECT_EQ(ws->world(), 7u);
  EXPECT_EQ(ws->name()->str(), "arena");
  EXPECT_EQ(ws->bodies(), 100u);
  EXPECT_TRUE(ws->running());
  EXPECT_EQ(ws->overruns(), 2u);
  EXPECT_EQ(ws->frames(), 48u);
  EXPECT_EQ(ws->backend()->str(), "gpu");
  EXPECT_EQ(ws->device()->str(), "llvmpipe (LLVM 15.0.6, 256 bits)");
  EXPECT_EQ(ws->backend_note()->str(), "hull shapes are not on the device yet");
  EXPECT_EQ(ws->gpu_steps(), 40u);
  EXPECT_EQ(ws->cpu_steps(), 10u);
  // The plain-data conversion (what the SDK hands out) carries every field.
  WorldSummary back = toWorldSummary(*ws);
  EXPECT_EQ(back.world, 7u);
  EXPECT_EQ(back.name, "arena");
  EXPECT_EQ(back.preset, "soft_step");
  EXPECT_EQ(back.bodies, 100u);
  EXPECT_EQ(back.tick, 50u);
  EXPECT_TRUE(back.running);
  EXPECT_EQ(back.rateHz, 60.0f);
  EXPECT_EQ(back.overruns, 2u);
  EXPECT_EQ(back.frames, 48u);
  EXPECT_EQ(back.backend, w.backend);
  EXPECT_EQ(back.device, w.device);
  EXPECT_EQ(back.backendNote, w.backendNote);
  EXPECT_EQ(back.gpuSteps, 40u);
  EXPECT_EQ(back.cpuSteps, 10u);
  auto* ws2 = list->result_as_WorldList()->worlds()->Get(1);
  EXPECT_EQ(ws2->backend()->str(), "cpu");
  EXPECT_EQ(ws2->device(), nullptr);  // empty strings are left out
  EXPECT_EQ(ws2->backend_note(), nullptr);
  WorldSummary back2 = toWorldSummary(*ws2);
  EXPECT_EQ(back2.backend, "cpu");
  EXPECT_TRUE(back2.device.empty());
  EXPECT_TRUE(back2.backendNote.empty());
  EXPECT_EQ(back2.gpuSteps, 0u);
  EXPECT_EQ(back2.cpuSteps, 3u);

  phys::BodyState s;
  s.id = phys::BodyId{4, 2};
  s.position = {1, 2, 3};
  s.linearVelocity = {0, 0, -1};
  std::vector<wire::BodyState> states = {toWire(s)};
  auto st = decodeReply(encodeStateReply(h, 2.5, 10, states));
  ASSERT_TRUE(st.ok());
  EXPECT_EQ(st->result_as_StateResult()->time(), 2.5);
  EXPECT_EQ(st->result_as_StateResult()->total(), 10u);
  EXPECT_EQ(st->result_as_StateResult()->bodies()->Get(0)->id(), s.id.packed());
  EXPECT_EQ(st->result_as_StateResult()->bodies()->Get(0)->linear_velocity().z(), -1.0f);

  Bytes snapshot = encodeSnapshot(SnapshotData{});
  auto sr = decodeReply(encodeSnapshotReply(h, snapshot, "a.snap"));
  ASSERT_TRUE(sr.ok());
  auto* sres = sr->result_as_SnapshotResult();
  EXPECT_EQ(sres->file()->str(), "a.snap");
  EXPECT_EQ(sres->snapshot()->size(), snapshot.size());
  EXPECT_TRUE(
      decodeSnapshot(std::span<const uint8_t>(sres->snapshot()->data(), sres->snapshot()->size()))
          .ok());
}

TEST(ProtocolRoundTrip, StateFramesChunk) {
  std::vector<wire::BodyState> states;
  for (uint32_t i = 0; i < 2500; ++i) {
    phys::BodyState s;
    s.id = phys::BodyId{i, 1};
    s.position = {float(i), 0, 0};
    states.push_back(toWire(s));
  }
  FrameHeader h{3, 600, 10.0, 1795000000123456789ull};
  std::vector<Bytes> frames = encodeStateFrames(h, states, 1000);
  ASSERT_EQ(frames.size(), 3u);
  uint32_t seen = 0;
  for (uint32_t c = 0; c < frames.size(); ++c) {
    auto f = decodeStateFrame(frames[c]);
    ASSERT_TRUE(f.ok()) << f.status.message;
    EXPECT_EQ(f->world(), 3u);
    EXPECT_EQ(f->tick(), 600u);
    EXPECT_EQ(f->time(), 10.0);
    EXPECT_EQ(f->chunk_index(), c);
    EXPECT_EQ(f->chunk_count(), 3u);
    EXPECT_EQ(f->total_bodies(), 2500u);
    EXPECT_EQ(f->stamp_ns(), 1795000000123456789ull);
    for (const wire::BodyState* b : *f->bodies()) {
      EXPECT_EQ(b->id(), (phys::BodyId{seen, 1}.packed()));
      EXPECT_EQ(b->position().x(), float(seen));
      ++seen;
    }
  }
  EXPECT_EQ(seen, 2500u);
  // A 64-byte record per body: a 1000-body chunk stays near 64 KB.
  EXPECT_LT(frames[0].size(), 1000 * 64 + 256);

  // An empty world still publishes one (empty) chunk per tick.
  std::vector<Bytes> none = encodeStateFrames(h, {}, 1000);
  ASSERT_EQ(none.size(), 1u);
  auto f = decodeStateFrame(none[0]);
  ASSERT_TRUE(f.ok());
  EXPECT_EQ(f->chunk_count(), 1u);
  EXPECT_EQ(f->bodies()->size(), 0u);
}

TEST(ProtocolRoundTrip, WorldInfoChunksAndValidates) {
  std::vector<BodyEntry> bodies;
  std::vector<phys::BodyDef> samples = sampleBodies();
  for (uint32_t i = 0; i < 10; ++i)
    bodies.push_back({phys::BodyId{i, 1}.packed(), samples[i % samples.size()]});
  std::vector<JointEntry> joints = {{phys::JointId{0, 1}.packed(), sampleJoint()}};
  WorldInfoHeader h;
  h.world = 2;
  h.name = "arena";
  h.revision = 5;
  auto one = encodeWorldInfo(h, bodies, joints);
  ASSERT_EQ(one.size(), 1u);
  auto w = decodeWorldInfo(one[0]);
  ASSERT_TRUE(w.ok()) << w.status.message;
  EXPECT_EQ(w->world(), 2u);
  EXPECT_EQ(w->name()->str(), "arena");
  EXPECT_EQ(w->revision(), 5u);
  EXPECT_EQ(w->bodies()->size(), 10u);
  EXPECT_EQ(w->joints()->size(), 1u);
  phys::BodyDef back;
  ASSERT_TRUE(toBodyDef(*w->bodies()->Get(1)->def(), &back).ok());
  expectBodyEq(samples[1], back);

  // Small limits force several chunks; every chunk decodes under the same limits.
  Limits small;
  small.maxBodiesPerCommand = 3;
  auto many = encodeWorldInfo(h, bodies, joints, small);
  ASSERT_EQ(many.size(), 4u);
  size_t nb = 0, nj = 0;
  for (uint32_t c = 0; c < many.size(); ++c) {
    auto d = decodeWorldInfo(many[c], small);
    ASSERT_TRUE(d.ok()) << d.status.message;
    EXPECT_EQ(d->chunk_index(), c);
    EXPECT_EQ(d->chunk_count(), 4u);
    nb += d->bodies()->size();
    nj += d->joints()->size();
  }
  EXPECT_EQ(nb, 10u);
  EXPECT_EQ(nj, 1u);
}

TEST(ProtocolRoundTrip, StatusAndEvents) {
  ServerStatusInfo s;
  s.serverName = "physd@host";
  s.serverVersion = "0.1.0";
  s.uptimeS = 12.5;
  s.commands = 100;
  s.errors = 3;
  WorldSummary w;
  w.world = 1;
  w.tickMs = 0.8f;
  w.tickMsMax = 2.5f;
  w.subscribers = 8;
  w.backend = "cpu";
  w.backendNote = "no GPU device, running on the CPU: no Vulkan device";
  w.cpuSteps = 12;
  w.contacts = 321;
  w.stepBufferBytes = 5'000'000'000ull;  // past 32 bits
  s.worlds.push_back(w);
  s.framesDropped = 5;
  s.heapBytes = 123'456'789'012ull;
  auto d = decodeServerStatus(encodeServerStatus(s));
  ASSERT_TRUE(d.ok()) << d.status.message;
  EXPECT_EQ(d->server_name()->str(), "physd@host");
  EXPECT_EQ(d->uptime_s(), 12.5);
  EXPECT_EQ(d->errors(), 3u);
  EXPECT_EQ(d->worlds()->Get(0)->tick_ms(), 0.8f);
  EXPECT_EQ(d->worlds()->Get(0)->subscribers(), 8u);
  WorldSummary ws = toWorldSummary(*d->worlds()->Get(0));
  EXPECT_EQ(ws.backend, "cpu");
  EXPECT_EQ(ws.device, "");
  EXPECT_EQ(ws.backendNote, w.backendNote);
  EXPECT_EQ(ws.gpuSteps, 0u);
  EXPECT_EQ(ws.cpuSteps, 12u);
  EXPECT_EQ(ws.contacts, 321u);
  EXPECT_EQ(ws.stepBufferBytes, 5'000'000'000ull);
  EXPECT_EQ(d->frames_dropped(), 5u);
  EXPECT_EQ(d->heap_bytes(), 123'456'789'012ull);

  auto e = decodeEvent(
      encodeEvent(1, 42, wire::Severity::Warning, "guard_rollback", "step redone at 8 substeps"));
  ASSERT_TRUE(e.ok()) << e.status.message;
  EXPECT_EQ(e->tick(), 42u);
  EXPECT_EQ(e->severity(), wire::Severity::Warning);
  EXPECT_EQ(e->code()->str(), "guard_rollback");
}

TEST(ProtocolRoundTrip, MisalignedInputIsCopied) {
  Bytes b = CommandBuilder().step(3).finish(header());
  std::vector<uint8_t> shifted(b.size() + 1);
  std::copy(b.begin(), b.end(), shifted.begin() + 1);
  auto d = decodeCommand({shifted.data() + 1, b.size()});
  ASSERT_TRUE(d.ok()) << d.status.message;
  EXPECT_NE(d.storage, nullptr);
  shifted.assign(shifted.size(), 0);  // the decoded view does not depend on the input any more
  EXPECT_EQ(d->request_as_Step()->count(), 3u);
}

TEST(ProtocolConvert, CodesAndStates) {
  EXPECT_EQ(toWireCode(phys::StatusCode::NotFound), Code::NotFound);
  EXPECT_EQ(toWireCode(phys::StatusCode::ResourceExhausted), Code::ResourceExhausted);
  Status s = fromPhys(phys::Status::Error(phys::StatusCode::IncorrectState, "plane"));
  EXPECT_EQ(s.code, Code::IncorrectState);
  EXPECT_EQ(s.message, "plane");
  EXPECT_STREQ(toString(Code::InvalidArgument), "InvalidArgument");
  EXPECT_STREQ(requestName(wire::Request::SpawnBodies), "spawn_bodies");
  EXPECT_STREQ(requestName(wire::Request(200)), "unknown");
  EXPECT_FALSE(needsWorld(wire::Request::Hello));
  EXPECT_TRUE(needsWorld(wire::Request::Step));
  EXPECT_TRUE(isBatchable(wire::Request::ApplyForce));
  EXPECT_FALSE(isBatchable(wire::Request::Step));

  // A world's body state converts to the wire record and back.
  phys::World world;
  phys::BodyId id;
  ASSERT_TRUE(world.createBody(boxBody({0, 0, 5}, {1, 1, 1}), &id).ok());
  world.step();
  phys::BodyState st;
  ASSERT_TRUE(world.getBody(id, &st).ok());
  wire::BodyState w = toWire(st);
  EXPECT_EQ(w.id(), id.packed());
  EXPECT_EQ(w.position().z(), st.position.z);
  EXPECT_EQ(w.linear_velocity().z(), st.linearVelocity.z);
  EXPECT_LT(w.linear_velocity().z(), 0.0f);
}

TEST(ProtocolConvert, HullsArriveAsPointsAndTheWorldBuildsOrRefusesThem) {
  // Four coplanar points pass the codec (counts and ranges) and convert, as points: the
  // protocol builds no hull. The world that receives them refuses them and creates nothing.
  flatbuffers::FlatBufferBuilder fbb;
  std::vector<wire::Vec3> pts = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {1, 1, 0}};
  auto hull = wire::CreateConvexHull(fbb, fbb.CreateVectorOfStructs(pts));
  auto shape = wire::CreateShapeDef(fbb, wire::Shape::ConvexHull, hull.Union());
  std::vector<flatbuffers::Offset<wire::ShapeDef>> shapes = {shape};
  auto body = wire::CreateBodyDef(fbb, wire::MotionType::Dynamic, nullptr, nullptr, nullptr, 0, 0,
                                  1, 0, nullptr, true, 0, fbb.CreateVector(shapes));
  fbb.Finish(body);
  const auto* def = flatbuffers::GetRoot<wire::BodyDef>(fbb.GetBufferPointer());
  phys::BodyDef flat;
  ASSERT_TRUE(toBodyDef(*def, &flat, "spawn_bodies.bodies[0]").ok());
  ASSERT_TRUE(flat.shapes[0].geom.hull);
  EXPECT_FALSE(flat.shapes[0].geom.hull->built());
  EXPECT_EQ(flat.shapes[0].geom.hull->vertices.size(), 4u);
  phys::World world;
  phys::BodyId id;
  phys::Status ps = world.createBody(flat, &id);
  EXPECT_EQ(ps.code, phys::StatusCode::InvalidArgument);
  EXPECT_NE(ps.message.find("body.shapes[0]: hull points make no hull"), std::string::npos)
      << ps.message;
  EXPECT_EQ(world.bodyCount(), 0);

  // The cube's corners and its centre: built by the world into the cube (8 vertices, 6 faces)
  // with the mass of a unit cube of the body's density.
  phys::BodyDef cube;
  std::vector<phys::Vec3> points;
  for (float x : {0.f, 1.f})
    for (float y : {0.f, 1.f})
      for (float z : {0.f, 1.f}) points.push_back({x, y, z});
  points.push_back({0.5f, 0.5f, 0.5f});
  cube.shapes.push_back({phys::ShapeGeom::hullOf(points), {}, {}});
  ASSERT_TRUE(world.createBody(cube, &id).ok());
  phys::BodyDef back;
  ASSERT_TRUE(world.getBodyDef(id, &back).ok());
  ASSERT_TRUE(back.shapes[0].geom.hull && back.shapes[0].geom.hull->built());
  EXPECT_EQ(back.shapes[0].geom.hull->vertices.size(), 8u);
  EXPECT_EQ(back.shapes[0].geom.hull->faces.size(), 6u);
  phys::BodyState st;
  ASSERT_TRUE(world.getBody(id, &st).ok());
  EXPECT_NEAR(st.mass, 1000.0f, 1e-2f);
  EXPECT_NEAR(st.centerOfMass.z, 0.5f, 1e-5f);
}

}  // namespace
}  // namespace phys::protocol::test
