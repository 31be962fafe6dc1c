// Builders of every payload (builder.h).
#include "phys/protocol/builder.h"

#include <algorithm>

#include "phys/protocol/compact.h"
#include "phys/protocol/convert.h"
#include "write.h"

namespace phys::protocol {

using detail::alignedBytes;
using detail::Fbb;
using detail::finishBytes;
using detail::optString;
using flatbuffers::Offset;

// The wire enums mirror phys's value for value, so conversions are casts.
static_assert(int(wire::MotionType::Static) == int(phys::BodyType::Static) &&
              int(wire::MotionType::Kinematic) == int(phys::BodyType::Kinematic) &&
              int(wire::MotionType::Dynamic) == int(phys::BodyType::Dynamic));
static_assert(int(wire::JointType::Ball) == int(phys::JointType::Ball) &&
              int(wire::JointType::Hinge) == int(phys::JointType::Hinge) &&
              int(wire::JointType::Fixed) == int(phys::JointType::Fixed) &&
              int(wire::JointType::Distance) == int(phys::JointType::Distance) &&
              int(wire::JointType::Prismatic) == int(phys::JointType::Prismatic));
static_assert(int(wire::Scheme::GaussSeidel) == int(phys::SolverSettings::Scheme::GaussSeidel) &&
              int(wire::Scheme::Jacobi) == int(phys::SolverSettings::Scheme::Jacobi) &&
              int(wire::Scheme::ColoredGaussSeidel) ==
                  int(phys::SolverSettings::Scheme::ColoredGaussSeidel));
static_assert(int(wire::PositionPass::None) == int(phys::SolverSettings::PositionPass::None) &&
              int(wire::PositionPass::NonlinearGaussSeidel) ==
                  int(phys::SolverSettings::PositionPass::NonlinearGaussSeidel) &&
              int(wire::PositionPass::NonlinearJacobi) ==
                  int(phys::SolverSettings::PositionPass::NonlinearJacobi));
static_assert(int(wire::Stabilization::Baumgarte) ==
                  int(phys::SolverSettings::Stabilization::Baumgarte) &&
              int(wire::Stabilization::Soft) == int(phys::SolverSettings::Stabilization::Soft));
static_assert(int(wire::EqualitySolve::Iterative) ==
                  int(phys::SolverSettings::EqualitySolve::Iterative) &&
              int(wire::EqualitySolve::DirectLdl) ==
                  int(phys::SolverSettings::EqualitySolve::DirectLdl));

// ---------------------------------------------------------------------------------------------
// Shared writers

namespace detail {

namespace {

bool isZero(phys::Vec3 v) {
  return v.x == 0 && v.y == 0 && v.z == 0;
}

Offset<wire::ShapeDef> writeShape(Fbb& fbb, const phys::ShapeDef& s) {
  const phys::ShapeGeom& g = s.geom;
  wire::Shape type = wire::Shape::NONE;
  Offset<void> geom;
  switch (g.type) {
    case phys::ShapeType::Sphere:
      type = wire::Shape::Sphere;
      geom = wire::CreateSphere(fbb, g.radius).Union();
      break;
    case phys::ShapeType::Box: {
      wire::Vec3 he = toWire(g.halfExtents);
      type = wire::Shape::Box;
      geom = wire::CreateBox(fbb, &he).Union();
      break;
    }
    case phys::ShapeType::Capsule:
      type = wire::Shape::Capsule;
      geom = wire::CreateCapsule(fbb, g.radius, g.halfHeight).Union();
      break;
    case phys::ShapeType::Plane: {
      wire::Vec3 n = toWire(g.normal);
      type = wire::Shape::Plane;
      geom = wire::CreatePlane(fbb, &n, g.offset).Union();
      break;
    }
    case phys::ShapeType::Hull: {
      std::vector<wire::Vec3> points;
      if (g.hull) {
        points.reserve(g.hull->vertices.size());
        for (phys::Vec3 v : g.hull->vertices) points.push_back(toWire(v));
      }
      auto pv = fbb.CreateVectorOfStructs(points.data(), points.size());
      type = wire::Shape::ConvexHull;
      geom = wire::CreateConvexHull(fbb, pv).Union();
      break;
    }
  }
  // Identity frames and default materials are left out (absent means exactly these).
  bool identity = isZero(s.local.p) && s.local.q == phys::Quat{};
  wire::Pose local = toWire(s.local);
  const phys::Material def;
  bool defaultMaterial = s.material.friction == def.friction &&
                         s.material.restitution == def.restitution &&
                         s.material.density == def.density;
  wire::Material material = toWire(s.material);
  return wire::CreateShapeDef(fbb, type, geom, identity ? nullptr : &local,
                              defaultMaterial ? nullptr : &material);
}

}  // namespace

Offset<wire::BodyDef> writeBodyDef(Fbb& fbb, const phys::BodyDef& def) {
  std::vector<Offset<wire::ShapeDef>> shapes;
  shapes.reserve(def.shapes.size());
  for (const phys::ShapeDef& s : def.shapes) shapes.push_back(writeShape(fbb, s));
  auto shapesVec = fbb.CreateVector(shapes);
  auto name = optString(fbb, def.name);
  wire::Pose pose = toWire(phys::Transform{def.position, def.rotation});
  wire::Vec3 v = toWire(def.linearVelocity), w = toWire(def.angularVelocity);
  wire::Vec3 inertia = toWire(def.inertia);
  wire::BodyDefBuilder b(fbb);
  b.add_motion(wire::MotionType(def.type));
  b.add_pose(&pose);
  if (!isZero(def.linearVelocity)) b.add_linear_velocity(&v);
  if (!isZero(def.angularVelocity)) b.add_angular_velocity(&w);
  b.add_linear_damping(def.linearDamping);
  b.add_angular_damping(def.angularDamping);
  b.add_gravity_scale(def.gravityScale);
  b.add_mass(def.mass);
  if (!isZero(def.inertia)) b.add_inertia(&inertia);
  b.add_gyroscopic(def.gyroscopic);
  if (!def.allowSleep) b.add_allow_sleep(false);
  b.add_name(name);
  b.add_shapes(shapesVec);
  return b.Finish();
}

Offset<wire::JointDef> writeJointDef(Fbb& fbb, const phys::JointDef& def) {
  auto name = optString(fbb, def.name);
  wire::Vec3 anchorA = toWire(def.anchorA), anchorB = toWire(def.anchorB);
  wire::Vec3 axisA = toWire(def.axisA), axisB = toWire(def.axisB);
  wire::JointDefBuilder b(fbb);
  b.add_type(wire::JointType(def.type));
  b.add_body_a(def.bodyA.packed());
  b.add_body_b(def.bodyB.packed());
  b.add_anchor_a(&anchorA);
  b.add_anchor_b(&anchorB);
  b.add_axis_a(&axisA);
  b.add_axis_b(&axisB);
  b.add_enable_limit(def.enableLimit);
  b.add_lower(def.lower);
  b.add_upper(def.upper);
  b.add_enable_motor(def.enableMotor);
  b.add_motor_speed(def.motorSpeed);
  b.add_max_motor_force(def.maxMotorForce);
  b.add_length(def.length);
  b.add_spring_hertz(def.springHertz);
  b.add_spring_damping_ratio(def.springDampingRatio);
  b.add_collide_connected(def.collideConnected);
  b.add_name(name);
  return b.Finish();
}

/// A value as the wire setter takes it: a phys enum as the wire's (the same values), any other
/// as it is.
template <class T>
struct AsWire {
  T v;
  template <class W>
  operator W() const {
    return W(v);
  }
};
template <class T>
AsWire<T> asWire(T v) {
  return {v};
}

Offset<wire::SolverSettings> writeSolver(Fbb& fbb, const SolverOverrides& s) {
  wire::SolverSettingsBuilder b(fbb);
  // In the list's order, the schema's: the order of the adds is the order of the bytes.
#define PHYS_WRITE_SOLVER(type, member, name, ...) \
  if (s.member) b.add_##name(asWire(*s.member));
  PHYS_SOLVER_FIELDS(PHYS_WRITE_SOLVER)
#undef PHYS_WRITE_SOLVER
  return b.Finish();
}

// A world setting's wire value: the value itself, or a Vec3 struct kept in `slot` (the
// builder copies it at once).
template <class T>
T worldWire(T v, wire::Vec3*) {
  return v;
}
const wire::Vec3* worldWire(phys::Vec3 v, wire::Vec3* slot) {
  *slot = toWire(v);
  return slot;
}

Offset<wire::WorldSettings> writeWorldSettings(Fbb& fbb, const WorldOverrides& s) {
  wire::WorldSettingsBuilder b(fbb);
  wire::Vec3 slot;
  // In the list's order, the schema's: the order of the adds is the order of the bytes.
#define PHYS_WRITE_WORLD(type, member, path, name) \
  if (s.member) b.add_##name(worldWire(*s.member, &slot));
  PHYS_WORLD_FIELDS(PHYS_WRITE_WORLD)
#undef PHYS_WRITE_WORLD
  return b.Finish();
}

Offset<wire::WorldSummary> writeWorldSummary(Fbb& fbb, const WorldSummary& w) {
  auto name = optString(fbb, w.name);
  auto preset = optString(fbb, w.preset);
  auto backend = optString(fbb, w.backend);
  auto device = optString(fbb, w.device);
  auto note = optString(fbb, w.backendNote);
  auto damage = optString(fbb, w.damage);
  return wire::CreateWorldSummary(fbb, w.world, name, preset, w.bodies, w.joints, w.tick, w.time,
                                  w.running, w.rateHz, w.tickMs, w.tickMsMax, w.overruns,
                                  w.subscribers, w.frames, backend, device, note, w.gpuSteps,
                                  w.cpuSteps, w.awakeBodies, w.sleepingBodies, w.frameBytes,
                                  w.contacts, w.stepBufferBytes, damage, w.daemon, w.movingTo);
}

Offset<wire::LimitsInfo> writeLimits(Fbb& fbb, const Limits& l) {
  return wire::CreateLimitsInfo(fbb, l.maxMessageBytes, l.maxBodiesPerCommand, l.maxShapesPerBody,
                                l.maxHullPoints, l.maxJointsPerCommand, l.maxIdsPerCommand,
                                l.maxItemsPerCommand, l.maxBatchCommands, l.maxStepsPerCommand,
                                l.maxBodiesPerFrame, l.maxShapesPerCommand,
                                l.maxHullPointsPerCommand, l.maxBodyStepsPerCommand,
                                maxIdsPerReply(l));
}

}  // namespace detail

// ---------------------------------------------------------------------------------------------
// SolverOverrides

// A tripwire: phys::SolverSettings gained or lost a field. Its row in PHYS_SOLVER_FIELDS
// reaches SolverOverrides, writeSolver, convert.cpp and the decoder; physics.fbs
// (SolverSettings, appended at the end) and docs/PROTOCOL.md are by hand. Then update the size.
static_assert(sizeof(phys::SolverSettings) == 88,
              "phys::SolverSettings changed: mirror the change in the protocol (see comment)");

SolverOverrides SolverOverrides::from(const phys::SolverSettings& s) {
  SolverOverrides o;
#define PHYS_FROM_SETTINGS(type, member, ...) o.member = s.member;
  PHYS_SOLVER_FIELDS(PHYS_FROM_SETTINGS)
#undef PHYS_FROM_SETTINGS
  return o;
}

bool SolverOverrides::empty() const {
#define PHYS_UNSET(type, member, ...) && !member
  return true PHYS_SOLVER_FIELDS(PHYS_UNSET);
#undef PHYS_UNSET
}

// ---------------------------------------------------------------------------------------------
// WorldOverrides

// A tripwire like SolverSettings': WorldDef gained or lost a field. A field a living world may
// change gets a row in PHYS_WORLD_FIELDS (which reaches WorldOverrides, its from()/empty(),
// detail::writeWorldSettings, convert.cpp and Python), a field in physics.fbs (WorldSettings,
// at the end), its value rule (the decoder's and World::validate) and its line in
// docs/PROTOCOL.md "World settings"; then update the size here.
#if defined(__GLIBCXX__) && UINTPTR_MAX == UINT64_MAX
static_assert(sizeof(phys::WorldDef) == 164,
              "phys::WorldDef changed: mirror a settable field in the protocol (see comment)");
#endif

WorldOverrides WorldOverrides::from(const phys::WorldDef& d) {
  WorldOverrides o;
#define PHYS_FROM_WORLD(type, member, path, name) o.member = d.path;
  PHYS_WORLD_FIELDS(PHYS_FROM_WORLD)
#undef PHYS_FROM_WORLD
  return o;
}

bool WorldOverrides::empty() const {
#define PHYS_WORLD_UNSET(type, member, ...) && !member
  return true PHYS_WORLD_FIELDS(PHYS_WORLD_UNSET);
#undef PHYS_WORLD_UNSET
}

// ---------------------------------------------------------------------------------------------
// Commands

CommandBuilder& CommandBuilder::add(wire::Request type, Offset<void> table) {
  items_.emplace_back(type, table);
  return *this;
}

CommandBuilder& CommandBuilder::raw(wire::Request type, Offset<void> table) {
  return add(type, table);
}

CommandBuilder& CommandBuilder::hello(std::string_view clientName, uint16_t version) {
  auto name = optString(fbb_, clientName);
  return add(wire::Request::Hello, wire::CreateHello(fbb_, version, name).Union());
}

CommandBuilder& CommandBuilder::hello(std::string_view clientName,
                                      std::span<const uint8_t> publicKey,
                                      std::span<const uint8_t> proof) {
  auto name = optString(fbb_, clientName);
  auto key = fbb_.CreateVector(publicKey.data(), publicKey.size());
  auto sig = fbb_.CreateVector(proof.data(), proof.size());
  return add(wire::Request::Hello,
             wire::CreateHello(fbb_, kProtocolVersion, name, key, sig).Union());
}

CommandBuilder& CommandBuilder::createWorld(const CreateWorldArgs& args) {
  auto name = optString(fbb_, args.name);
  auto preset = optString(fbb_, args.preset);
  auto backend = optString(fbb_, args.backend);
  wire::Vec3 g = toWire(args.gravity.value_or(phys::Vec3{}));
  flatbuffers::Offset<flatbuffers::Vector<uint64_t>> editors;
  if (!args.editors.empty()) editors = fbb_.CreateVector(args.editors);
  return add(wire::Request::CreateWorld,
             wire::CreateCreateWorld(fbb_, name, preset, args.gravity ? &g : nullptr, args.timeStep,
                                     backend, args.sleep, args.ephemeral, editors, args.shared)
                 .Union());
}

CommandBuilder& CommandBuilder::destroyWorld() {
  return add(wire::Request::DestroyWorld, wire::CreateDestroyWorld(fbb_).Union());
}

CommandBuilder& CommandBuilder::resetWorld() {
  return add(wire::Request::ResetWorld, wire::CreateResetWorld(fbb_).Union());
}

CommandBuilder& CommandBuilder::listWorlds() {
  return add(wire::Request::ListWorlds, wire::CreateListWorlds(fbb_).Union());
}

CommandBuilder& CommandBuilder::loadSceneJson(std::string_view json) {
  auto s = fbb_.CreateString(json.data(), json.size());
  return add(wire::Request::LoadScene, wire::CreateLoadScene(fbb_, s, 0).Union());
}

CommandBuilder& CommandBuilder::loadSceneNamed(std::string_view sceneName) {
  auto s = fbb_.CreateString(sceneName.data(), sceneName.size());
  return add(wire::Request::LoadScene, wire::CreateLoadScene(fbb_, 0, s).Union());
}

CommandBuilder& CommandBuilder::spawnBodies(std::span<const phys::BodyDef> bodies) {
  std::vector<Offset<wire::BodyDef>> defs;
  defs.reserve(bodies.size());
  for (const phys::BodyDef& b : bodies) defs.push_back(detail::writeBodyDef(fbb_, b));
  auto v = fbb_.CreateVector(defs);
  return add(wire::Request::SpawnBodies, wire::CreateSpawnBodies(fbb_, v).Union());
}

CommandBuilder& CommandBuilder::removeBodies(std::span<const uint64_t> ids) {
  auto v = fbb_.CreateVector(ids.data(), ids.size());
  return add(wire::Request::RemoveBodies, wire::CreateRemoveBodies(fbb_, v).Union());
}

CommandBuilder& CommandBuilder::addJoints(std::span<const phys::JointDef> joints) {
  std::vector<Offset<wire::JointDef>> defs;
  defs.reserve(joints.size());
  for (const phys::JointDef& j : joints) defs.push_back(detail::writeJointDef(fbb_, j));
  auto v = fbb_.CreateVector(defs);
  return add(wire::Request::AddJoints, wire::CreateAddJoints(fbb_, v).Union());
}

CommandBuilder& CommandBuilder::removeJoints(std::span<const uint64_t> ids) {
  auto v = fbb_.CreateVector(ids.data(), ids.size());
  return add(wire::Request::RemoveJoints, wire::CreateRemoveJoints(fbb_, v).Union());
}

CommandBuilder& CommandBuilder::setBodyPose(std::span<const wire::BodyPose> items) {
  auto v = fbb_.CreateVectorOfStructs(items.data(), items.size());
  return add(wire::Request::SetBodyPose, wire::CreateSetBodyPose(fbb_, v).Union());
}

CommandBuilder& CommandBuilder::setBodyPose(uint64_t id, phys::Vec3 position, phys::Quat rotation) {
  wire::BodyPose item(id, toWire(phys::Transform{position, rotation}));
  return setBodyPose(std::span<const wire::BodyPose>(&item, 1));
}

CommandBuilder& CommandBuilder::setBodyVelocity(std::span<const wire::BodyVelocity> items) {
  auto v = fbb_.CreateVectorOfStructs(items.data(), items.size());
  return add(wire::Request::SetBodyVelocity, wire::CreateSetBodyVelocity(fbb_, v).Union());
}

CommandBuilder& CommandBuilder::setBodyVelocity(uint64_t id, phys::Vec3 linear,
                                                phys::Vec3 angular) {
  wire::BodyVelocity item(id, toWire(linear), toWire(angular));
  return setBodyVelocity(std::span<const wire::BodyVelocity>(&item, 1));
}

CommandBuilder& CommandBuilder::applyForce(std::span<const wire::BodyForce> items,
                                           wire::PointFrame frame) {
  auto v = fbb_.CreateVectorOfStructs(items.data(), items.size());
  return add(wire::Request::ApplyForce, wire::CreateApplyForce(fbb_, v, frame).Union());
}

CommandBuilder& CommandBuilder::applyForce(uint64_t id, phys::Vec3 force, phys::Vec3 point,
                                           wire::PointFrame frame) {
  wire::BodyForce item(id, toWire(force), toWire(point));
  return applyForce(std::span<const wire::BodyForce>(&item, 1), frame);
}

CommandBuilder& CommandBuilder::applyImpulse(std::span<const wire::BodyForce> items,
                                             wire::PointFrame frame) {
  auto v = fbb_.CreateVectorOfStructs(items.data(), items.size());
  return add(wire::Request::ApplyImpulse, wire::CreateApplyImpulse(fbb_, v, frame).Union());
}

CommandBuilder& CommandBuilder::applyImpulse(uint64_t id, phys::Vec3 impulse, phys::Vec3 point,
                                             wire::PointFrame frame) {
  wire::BodyForce item(id, toWire(impulse), toWire(point));
  return applyImpulse(std::span<const wire::BodyForce>(&item, 1), frame);
}

CommandBuilder& CommandBuilder::applyTorque(std::span<const wire::BodyTorque> items) {
  auto v = fbb_.CreateVectorOfStructs(items.data(), items.size());
  return add(wire::Request::ApplyTorque, wire::CreateApplyTorque(fbb_, v).Union());
}

CommandBuilder& CommandBuilder::applyTorque(uint64_t id, phys::Vec3 torque) {
  wire::BodyTorque item(id, toWire(torque));
  return applyTorque(std::span<const wire::BodyTorque>(&item, 1));
}

CommandBuilder& CommandBuilder::setMaterial(std::span<const uint64_t> ids,
                                            const phys::Material& material) {
  auto v = fbb_.CreateVector(ids.data(), ids.size());
  wire::Material m = toWire(material);
  return add(wire::Request::SetMaterial, wire::CreateSetMaterial(fbb_, v, &m).Union());
}

CommandBuilder& CommandBuilder::setSolver(std::string_view preset,
                                          const SolverOverrides& overrides) {
  auto name = optString(fbb_, preset);
  Offset<wire::SolverSettings> settings;
  if (!overrides.empty()) settings = detail::writeSolver(fbb_, overrides);
  return add(wire::Request::SetSolver, wire::CreateSetSolver(fbb_, name, settings).Union());
}

CommandBuilder& CommandBuilder::step(uint32_t count) {
  return add(wire::Request::Step, wire::CreateStep(fbb_, count).Union());
}

CommandBuilder& CommandBuilder::run(float rateHz) {
  return add(wire::Request::Run, wire::CreateRun(fbb_, rateHz).Union());
}

CommandBuilder& CommandBuilder::moveWorld(uint64_t daemon) {
  return add(wire::Request::MoveWorld, wire::CreateMoveWorld(fbb_, daemon).Union());
}

CommandBuilder& CommandBuilder::pause() {
  return add(wire::Request::Pause, wire::CreatePause(fbb_).Union());
}

CommandBuilder& CommandBuilder::queryState(std::span<const uint64_t> ids, uint32_t first,
                                           uint32_t maxCount) {
  Offset<flatbuffers::Vector<uint64_t>> v;
  if (!ids.empty()) v = fbb_.CreateVector(ids.data(), ids.size());
  return add(wire::Request::QueryState, wire::CreateQueryState(fbb_, v, first, maxCount).Union());
}

CommandBuilder& CommandBuilder::subscribeBodies(std::span<const uint64_t> ids) {
  auto v = fbb_.CreateVector(ids.data(), ids.size());
  return add(wire::Request::Subscribe, wire::CreateSubscribe(fbb_, v).Union());
}

CommandBuilder& CommandBuilder::subscribeRegion(phys::Vec3 lo, phys::Vec3 hi) {
  const wire::Vec3 a = toWire(lo), b = toWire(hi);
  return add(wire::Request::Subscribe, wire::CreateSubscribe(fbb_, 0, &a, &b).Union());
}

CommandBuilder& CommandBuilder::unsubscribe(uint32_t interest) {
  return add(wire::Request::Unsubscribe, wire::CreateUnsubscribe(fbb_, interest).Union());
}

CommandBuilder& CommandBuilder::setAccess(std::span<const uint64_t> editors, bool shared) {
  auto v = fbb_.CreateVector(editors.data(), editors.size());
  return add(wire::Request::SetAccess, wire::CreateSetAccess(fbb_, v, shared).Union());
}

CommandBuilder& CommandBuilder::saveSnapshot(std::string_view file, bool returnBytes) {
  auto f = optString(fbb_, file);
  return add(wire::Request::SaveSnapshot, wire::CreateSaveSnapshot(fbb_, f, returnBytes).Union());
}

CommandBuilder& CommandBuilder::restoreSnapshot(std::span<const uint8_t> snapshot) {
  auto v = alignedBytes(fbb_, snapshot);
  return add(wire::Request::RestoreSnapshot, wire::CreateRestoreSnapshot(fbb_, v, 0).Union());
}

CommandBuilder& CommandBuilder::restoreSnapshotFile(std::string_view file) {
  auto f = fbb_.CreateString(file.data(), file.size());
  return add(wire::Request::RestoreSnapshot, wire::CreateRestoreSnapshot(fbb_, 0, f).Union());
}

CommandBuilder& CommandBuilder::setWorld(const WorldOverrides& settings) {
  auto t = detail::writeWorldSettings(fbb_, settings);
  return add(wire::Request::SetWorld, wire::CreateSetWorld(fbb_, t).Union());
}

CommandBuilder& CommandBuilder::getWorld() {
  return add(wire::Request::GetWorld, wire::CreateGetWorld(fbb_).Union());
}

CommandBuilder& CommandBuilder::getBodies(std::span<const uint64_t> ids, uint32_t first,
                                          uint32_t maxCount) {
  Offset<flatbuffers::Vector<uint64_t>> v;
  if (!ids.empty()) v = fbb_.CreateVector(ids.data(), ids.size());
  return add(wire::Request::GetBodies, wire::CreateGetBodies(fbb_, v, first, maxCount).Union());
}

CommandBuilder& CommandBuilder::getJoints(std::span<const uint64_t> ids, uint32_t first,
                                          uint32_t maxCount) {
  Offset<flatbuffers::Vector<uint64_t>> v;
  if (!ids.empty()) v = fbb_.CreateVector(ids.data(), ids.size());
  return add(wire::Request::GetJoints, wire::CreateGetJoints(fbb_, v, first, maxCount).Union());
}

Bytes CommandBuilder::finish(const CommandHeader& header) {
  wire::Request type = wire::Request::NONE;
  Offset<void> request;
  if (items_.size() == 1) {
    type = items_[0].first;
    request = items_[0].second;
  } else if (items_.size() > 1) {
    std::vector<Offset<wire::CommandItem>> commands;
    commands.reserve(items_.size());
    for (const auto& [t, o] : items_) commands.push_back(wire::CreateCommandItem(fbb_, t, o));
    auto v = fbb_.CreateVector(commands);
    type = wire::Request::Batch;
    request = wire::CreateBatch(fbb_, v).Union();
  }
  items_.clear();
  // CreateCommand's order; Command.daemon written even when 0 for an addressable command, so
  // that it can be set in place later (setCommandDaemon: the SDK sends a command on to a
  // world's new owner).
  wire::CommandBuilder cb(fbb_);
  fbb_.ForceDefaults(header.addressable);
  cb.add_daemon(header.daemon);
  fbb_.ForceDefaults(false);
  cb.add_seq(header.seq);
  cb.add_client_id(header.clientId);
  cb.add_request(request);
  cb.add_world(header.world);
  cb.add_request_type(type);
  auto root = cb.Finish();
  return finishBytes(fbb_, root, wire::kCommandId);
}

// ---------------------------------------------------------------------------------------------
// Replies

ReplyHeader replyTo(const wire::Command& command, Status status) {
  ReplyHeader h;
  h.clientId = command.client_id();
  h.seq = command.seq();
  h.world = command.world();
  h.status = std::move(status);
  return h;
}

namespace {

Bytes finishReply(Fbb& fbb, const ReplyHeader& h, wire::Result type, Offset<void> result) {
  auto message = optString(fbb, h.status.message);
  auto root = wire::CreateReply(fbb, h.clientId, h.seq, h.status.code, message, h.world, h.tick,
                                type, result, h.retryAfterMs, h.owner);
  return finishBytes(fbb, root, wire::kReplyId);
}

}  // namespace

Bytes encodeReply(const ReplyHeader& header) {
  Fbb fbb(256);
  return finishReply(fbb, header, wire::Result::NONE, 0);
}

Bytes encodeHelloReply(const ReplyHeader& header, const HelloInfo& info) {
  Fbb fbb(512);
  auto name = optString(fbb, info.serverName);
  auto version = optString(fbb, info.serverVersion);
  auto features = fbb.CreateVectorOfStrings(info.features);
  auto limits = detail::writeLimits(fbb, info.limits);
  auto r = wire::CreateHelloResult(fbb, kProtocolVersion, name, version, features, limits,
                                   info.clientProven);
  return finishReply(fbb, header, wire::Result::HelloResult, r.Union());
}

Bytes encodeIdsReply(const ReplyHeader& header, std::span<const uint64_t> bodies,
                     std::span<const uint64_t> joints) {
  Fbb fbb(256 + 8 * (bodies.size() + joints.size()));
  auto b = fbb.CreateVector(bodies.data(), bodies.size());
  auto j = fbb.CreateVector(joints.data(), joints.size());
  return finishReply(fbb, header, wire::Result::Ids, wire::CreateIds(fbb, b, j).Union());
}

Bytes encodeWorldListReply(const ReplyHeader& header, std::span<const WorldSummary> worlds) {
  Fbb fbb(256 + 128 * worlds.size());
  std::vector<Offset<wire::WorldSummary>> v;
  v.reserve(worlds.size());
  for (const WorldSummary& w : worlds) v.push_back(detail::writeWorldSummary(fbb, w));
  auto list = wire::CreateWorldList(fbb, fbb.CreateVector(v));
  return finishReply(fbb, header, wire::Result::WorldList, list.Union());
}

Bytes encodeStateReply(const ReplyHeader& header, double time, uint32_t total,
                       std::span<const wire::BodyState> bodies, uint64_t stampNs,
                       uint64_t epoch) {
  Fbb fbb(256 + sizeof(wire::BodyState) * bodies.size());
  auto v = fbb.CreateVectorOfStructs(bodies.data(), bodies.size());
  auto r = wire::CreateStateResult(fbb, time, total, v, stampNs, epoch);
  return finishReply(fbb, header, wire::Result::StateResult, r.Union());
}

Bytes encodeInterestReply(const ReplyHeader& header, uint32_t interest, std::string_view topic) {
  Fbb fbb(128 + topic.size());
  auto t = optString(fbb, topic);
  auto r = wire::CreateInterestResult(fbb, interest, t);
  return finishReply(fbb, header, wire::Result::InterestResult, r.Union());
}

Bytes encodeSnapshotReply(const ReplyHeader& header, std::span<const uint8_t> snapshot,
                          std::string_view file) {
  Fbb fbb(256 + snapshot.size());
  Offset<flatbuffers::Vector<uint8_t>> bytes;
  if (!snapshot.empty()) bytes = alignedBytes(fbb, snapshot);
  auto f = optString(fbb, file);
  auto r = wire::CreateSnapshotResult(fbb, bytes, f);
  return finishReply(fbb, header, wire::Result::SnapshotResult, r.Union());
}

// ---------------------------------------------------------------------------------------------
// Published data

Bytes encodeStateFrame(const FrameHeader& header, uint32_t chunkIndex, uint32_t chunkCount,
                       uint32_t totalBodies, std::span<const wire::BodyState> bodies) {
  return encodeStateFrame(header, chunkIndex, chunkCount, totalBodies, bodies, {});
}

Bytes encodeStateFrame(const FrameHeader& header, uint32_t chunkIndex, uint32_t chunkCount,
                       uint32_t totalBodies, std::span<const wire::BodyState> bodies,
                       std::span<const uint64_t> removed) {
  Fbb fbb(160 + sizeof(wire::BodyState) * bodies.size() + 8 * removed.size());
  Offset<flatbuffers::Vector<const wire::BodyState*>> full;
  Offset<flatbuffers::Vector<const wire::CompactBodyState*>> compact;
  wire::Vec3 lo{}, hi{};
  if (header.compact) {
    const CompactBounds b = compactBounds(bodies);
    lo = toWire(b.lo);
    hi = toWire(b.hi);
    wire::CompactBodyState* out = nullptr;
    compact = fbb.CreateUninitializedVectorOfStructs(bodies.size(), &out);
    for (size_t i = 0; i < bodies.size(); ++i) out[i] = compactState(bodies[i], b);
  } else {
    full = fbb.CreateVectorOfStructs(bodies.data(), bodies.size());
  }
  auto gone = removed.empty() ? 0 : fbb.CreateVector(removed.data(), removed.size());
  wire::StateFrameBuilder f(fbb);
  f.add_world(header.world);
  f.add_tick(header.tick);
  f.add_time(header.time);
  f.add_chunk_index(chunkIndex);
  f.add_chunk_count(chunkCount);
  f.add_total_bodies(totalBodies);
  if (!header.compact) f.add_bodies(full);
  f.add_stamp_ns(header.stampNs);
  if (!header.keyframe) {
    f.add_keyframe(false);
    f.add_base_tick(header.baseTick);
  }
  if (!removed.empty()) f.add_removed(gone);
  if (header.compact) {
    f.add_compact(compact);
    f.add_bounds_min(&lo);
    f.add_bounds_max(&hi);
  }
  if (header.interest != 0) f.add_interest(header.interest);
  if (header.refreshHi != 0) {
    f.add_refresh_lo(header.refreshLo);
    f.add_refresh_hi(header.refreshHi);
  }
  f.add_epoch(header.epoch);  // (zeros are left out by FlatBuffers' defaults)
  f.add_edit(header.edit);
  if (!header.keyframe) f.add_base_edit(header.baseEdit);
  return finishBytes(fbb, f.Finish(), wire::kStateFrameId);
}

std::vector<Bytes> encodeStateFrames(const FrameHeader& header,
                                     std::span<const wire::BodyState> bodies,
                                     uint32_t bodiesPerChunk, std::span<const uint64_t> removed,
                                     uint32_t totalBodies) {
  size_t per = std::max<uint32_t>(bodiesPerChunk, 1);
  uint32_t count = uint32_t(std::max<size_t>(1, (bodies.size() + per - 1) / per));
  if (totalBodies == UINT32_MAX) totalBodies = uint32_t(bodies.size());
  std::vector<Bytes> out;
  out.reserve(count);
  for (uint32_t c = 0; c < count; ++c) {
    size_t begin = std::min(c * per, bodies.size());  // an empty world: one empty chunk
    size_t n = std::min(per, bodies.size() - begin);
    out.push_back(encodeStateFrame(header, c, count, totalBodies, bodies.subspan(begin, n),
                                   c == 0 ? removed : std::span<const uint64_t>{}));
  }
  return out;
}

namespace {

/// Rough encoded size of a body and a joint, to keep WorldInfo chunks under the message cap.
size_t estimateBytes(const BodyEntry& b) {
  size_t n = 160 + b.def.name.size();
  for (const phys::ShapeDef& s : b.def.shapes)
    n += 96 + (s.geom.hull ? 12 * s.geom.hull->vertices.size() : 0);
  return n;
}
size_t estimateBytes(const JointEntry& j) {
  return 192 + j.def.name.size();
}

}  // namespace

std::vector<Bytes> encodeWorldInfo(const WorldInfoHeader& header, std::span<const BodyEntry> bodies,
                                   std::span<const JointEntry> joints, const Limits& limits) {
  // Chunk boundaries first (chunk_count goes into every chunk): bodies, then joints, each
  // chunk under half the message cap and within the per-command counts the decoder accepts.
  struct Range {
    size_t bodyBegin, bodyEnd, jointBegin, jointEnd;
  };
  const size_t budget = std::max<size_t>(limits.maxMessageBytes / 2, 4096);
  std::vector<Range> ranges;
  Range r{0, 0, 0, 0};
  size_t bytes = 0;
  auto flush = [&] {
    ranges.push_back(r);
    r = {r.bodyEnd, r.bodyEnd, r.jointEnd, r.jointEnd};
    bytes = 0;
  };
  for (size_t i = 0; i < bodies.size(); ++i) {
    size_t b = estimateBytes(bodies[i]);
    if (r.bodyEnd > r.bodyBegin &&
        (bytes + b > budget || r.bodyEnd - r.bodyBegin >= limits.maxBodiesPerCommand))
      flush();
    r.bodyEnd = i + 1;
    bytes += b;
  }
  for (size_t i = 0; i < joints.size(); ++i) {
    size_t b = estimateBytes(joints[i]);
    bool any = r.bodyEnd > r.bodyBegin || r.jointEnd > r.jointBegin;
    if (any && (bytes + b > budget || r.jointEnd - r.jointBegin >= limits.maxJointsPerCommand))
      flush();
    r.jointEnd = i + 1;
    bytes += b;
  }
  ranges.push_back(r);

  std::vector<Bytes> out;
  out.reserve(ranges.size());
  Fbb fbb(std::min<size_t>(budget + 4096, 1u << 20));
  wire::Vec3 gravity = toWire(header.gravity);
  for (size_t c = 0; c < ranges.size(); ++c) {
    const Range& rc = ranges[c];
    std::vector<Offset<wire::BodyEntry>> be;
    be.reserve(rc.bodyEnd - rc.bodyBegin);
    for (size_t i = rc.bodyBegin; i < rc.bodyEnd; ++i)
      be.push_back(
          wire::CreateBodyEntry(fbb, bodies[i].id, detail::writeBodyDef(fbb, bodies[i].def)));
    std::vector<Offset<wire::JointEntry>> je;
    je.reserve(rc.jointEnd - rc.jointBegin);
    for (size_t i = rc.jointBegin; i < rc.jointEnd; ++i)
      je.push_back(
          wire::CreateJointEntry(fbb, joints[i].id, detail::writeJointDef(fbb, joints[i].def)));
    auto bv = fbb.CreateVector(be);
    auto jv = fbb.CreateVector(je);
    auto name = optString(fbb, header.name);
    auto root =
        wire::CreateWorldInfo(fbb, header.world, name, header.revision, header.tick, &gravity,
                              header.timeStep, uint32_t(c), uint32_t(ranges.size()), bv, jv,
                              header.daemon);
    out.push_back(finishBytes(fbb, root, wire::kWorldInfoId));
  }
  return out;
}

Bytes encodeServerStatus(const ServerStatusInfo& status) {
  Fbb fbb(512 + 128 * status.worlds.size());
  auto name = optString(fbb, status.serverName);
  auto version = optString(fbb, status.serverVersion);
  std::vector<Offset<wire::WorldSummary>> v;
  v.reserve(status.worlds.size());
  for (const WorldSummary& w : status.worlds) v.push_back(detail::writeWorldSummary(fbb, w));
  auto worlds = fbb.CreateVector(v);
  auto readOnly = optString(fbb, status.readOnly);
  auto peers = status.peers.empty() ? Offset<flatbuffers::Vector<uint64_t>>()
                                    : fbb.CreateVector(status.peers);
  auto root = wire::CreateServerStatus(fbb, name, version, status.uptimeS, status.commands,
                                       status.errors, worlds, status.framesDropped,
                                       status.heapBytes, readOnly, status.daemon,
                                       status.cluster, status.statusPeriodS, peers);
  return finishBytes(fbb, root, wire::kServerStatusId);
}

Bytes encodeHandoff(const HandoffInfo& h, std::span<const uint8_t> bytes) {
  Fbb fbb(256 + bytes.size());
  auto b = bytes.empty() ? Offset<flatbuffers::Vector<uint8_t>>()
                         : fbb.CreateVector(bytes.data(), bytes.size());
  auto message = optString(fbb, h.status.message);
  auto root = wire::CreateHandoff(fbb, h.kind, h.world, h.from, h.to, h.move, h.epoch,
                                  h.subscribers, h.chunkIndex, h.chunkCount, b, h.status.code,
                                  message, h.ephemeral);
  return finishBytes(fbb, root, wire::kHandoffId);
}

Bytes encodeEvent(uint32_t world, uint64_t tick, wire::Severity severity, std::string_view code,
                  std::string_view message) {
  Fbb fbb(256);
  auto c = optString(fbb, code);
  auto m = optString(fbb, message);
  return finishBytes(fbb, wire::CreateEvent(fbb, world, tick, severity, c, m), wire::kEventId);
}

Bytes encodeSnapshot(const SnapshotData& s) {
  Fbb fbb(1024);
  std::vector<Offset<wire::BodyEntry>> be;
  be.reserve(s.bodies.size());
  for (const BodyEntry& b : s.bodies)
    be.push_back(wire::CreateBodyEntry(fbb, b.id, detail::writeBodyDef(fbb, b.def)));
  std::vector<Offset<wire::JointEntry>> je;
  je.reserve(s.joints.size());
  for (const JointEntry& j : s.joints)
    je.push_back(wire::CreateJointEntry(fbb, j.id, detail::writeJointDef(fbb, j.def)));
  auto bv = fbb.CreateVector(be);
  auto jv = fbb.CreateVector(je);
  flatbuffers::Offset<flatbuffers::Vector<uint8_t>> engine;
  if (!s.engineState.empty()) engine = alignedBytes(fbb, s.engineState);
  auto name = optString(fbb, s.name);
  auto solver = detail::writeSolver(fbb, SolverOverrides::from(s.solver));
  Offset<wire::WorldSettings> settings;
  if (!s.settings.empty()) settings = detail::writeWorldSettings(fbb, s.settings);
  wire::Vec3 gravity = toWire(s.gravity);
  wire::SnapshotBuilder b(fbb);
  b.add_format_version(1);
  b.add_name(name);
  b.add_gravity(&gravity);
  b.add_time_step(s.timeStep);
  b.add_solver(solver);
  b.add_tick(s.tick);
  b.add_time(s.time);
  b.add_bodies(bv);
  b.add_joints(jv);
  b.add_engine_state(engine);
  if (!s.settings.empty()) b.add_settings(settings);
  return finishBytes(fbb, b.Finish(), wire::kSnapshotId);
}

// ---------------------------------------------------------------------------------------------
// World settings and definitions

Bytes encodeWorldSettingsReply(const ReplyHeader& header, const phys::WorldDef& def,
                               std::string_view preset) {
  Fbb fbb(1024);
  auto settings = detail::writeWorldSettings(fbb, WorldOverrides::from(def));
  auto solver = detail::writeSolver(fbb, SolverOverrides::from(def.solver));
  auto name = optString(fbb, preset);
  auto r = wire::CreateWorldSettingsResult(fbb, settings, solver, name);
  return finishReply(fbb, header, wire::Result::WorldSettingsResult, r.Union());
}

Bytes encodeBodiesReply(const ReplyHeader& header, uint32_t total,
                        std::span<const BodyInfo> bodies) {
  size_t bytes = kReplyOverheadBytes;
  for (const BodyInfo& b : bodies) bytes += encodedBytesBound(b);
  Fbb fbb(std::min<size_t>(bytes, size_t(1) << 24));
  std::vector<Offset<wire::BodyInfo>> v;
  v.reserve(bodies.size());
  for (const BodyInfo& b : bodies) {
    auto def = detail::writeBodyDef(fbb, b.def);
    const wire::Vec3 center = toWire(b.mass.localCenter), inertia = toWire(b.mass.inertia);
    const wire::Quat axes = toWire(b.mass.inertiaRotation);
    v.push_back(wire::CreateBodyInfo(fbb, b.id, def, b.mass.mass, &center, &inertia, &axes));
  }
  auto list = fbb.CreateVector(v);
  auto r = wire::CreateBodiesResult(fbb, total, list);
  return finishReply(fbb, header, wire::Result::BodiesResult, r.Union());
}

Bytes encodeJointsReply(const ReplyHeader& header, uint32_t total,
                        std::span<const JointEntry> joints) {
  size_t bytes = kReplyOverheadBytes;
  for (const JointEntry& j : joints) bytes += encodedBytesBound(j);
  Fbb fbb(std::min<size_t>(bytes, size_t(1) << 24));
  std::vector<Offset<wire::JointEntry>> v;
  v.reserve(joints.size());
  for (const JointEntry& j : joints)
    v.push_back(wire::CreateJointEntry(fbb, j.id, detail::writeJointDef(fbb, j.def)));
  auto list = fbb.CreateVector(v);
  auto r = wire::CreateJointsResult(fbb, total, list);
  return finishReply(fbb, header, wire::Result::JointsResult, r.Union());
}

// Bounds, generous: a table costs its vtable (2 bytes a field, 4 more) and its fields, each
// padded to 8 bytes at most; a string or vector its length word, its bytes and padding; every
// offset 4 bytes. BodyDef has 13 fields (a pose of 28 bytes, three Vec3s), ShapeDef 4 (a pose,
// a material), a geometry table at most 2 (a Vec3 or a vector), BodyInfo 6, JointDef 18.
size_t encodedBytesBound(const BodyInfo& body) {
  size_t n = 96 /* BodyInfo */ + 256 /* BodyDef */ + 16 + body.def.name.size();
  for (const phys::ShapeDef& s : body.def.shapes) {
    n += 4 + 96 /* ShapeDef */ + 48 /* geometry */;
    if (s.geom.hull) n += 16 + 12 * s.geom.hull->vertices.size();
  }
  return n;
}

size_t encodedBytesBound(const JointEntry& joint) {
  return 4 + 32 /* JointEntry */ + 256 /* JointDef */ + 16 + joint.def.name.size();
}

}  // namespace phys::protocol
