// The small server the apply target fuzzes, shared with the corpus generator (make_corpus.cpp)
// so that the seeds address its world, its client and its body and joint ids.
//
// One ServerCore with small budgets and world 1 ("fuzz"): a ground plane and a body of every
// shape kind (box, sphere, capsule, hull, a kinematic box), with a hinge and a ball joint, and
// interest 1 (a region) subscribed; a snapshot file of it in the snapshot directory.
// Ids are deterministic: a fresh core builds the same world with the same ids, and the
// world's engine snapshot (taken once) restores exactly that state, ids included.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "phys/protocol/builder.h"
#include "phys/protocol/decoder.h"
#include "phys/server/core.h"
#include "phys/world/world.h"

namespace phys::fuzz {

/// The client every seed of the apply corpus speaks as (Command.client_id), which created and
/// so owns the fuzz world. The target uses the decoded command's client_id as the envelope
/// key, so any id reaches the apply path (other clients may read the world, not change it);
/// this one is what the seeds carry.
inline constexpr uint64_t kClient = 0xF0220C11E47ull;
/// The fuzz world: the first world a fresh core creates.
inline constexpr uint32_t kWorld = 1;
/// A snapshot file kept in the fuzz server's snapshot directory (RestoreSnapshot by file).
inline constexpr const char* kBaseSnapshotFile = "base.snap";

/// The fuzz world's interest (Subscribe): a region around its bodies.
inline constexpr uint32_t kInterest = 1;
inline constexpr Vec3 kInterestLo{-5, -5, -1}, kInterestHi{5, 5, 5};

/// Small budgets: one input costs at most a few bodies' worth of steps. compact: state frames
/// in compact states with whole keyframes (instead of full states with a rolling refresh).
inline server::CoreConfig coreConfig(const std::string& snapshotDir, bool compact = false) {
  server::CoreConfig c;
  c.serverName = "physd-fuzz";
  c.presetsFile = std::string(PHYS_SOURCE_DIR) + "/configs/presets.json";
  c.scenesDir = std::string(PHYS_SOURCE_DIR) + "/configs/scenes";
  c.snapshotDir = snapshotDir;
  c.threads = 1;
  c.framesWithoutSubscribers = true;  // frames are encoded (and decoded by the target)
  c.bodiesPerChunk = 8;               // several chunks per frame
  c.keyframeTicks = 4;
  c.compactStates = compact;
  c.rollingRefresh = !compact;
  c.maxWorlds = 4;
  c.maxBodiesPerWorld = 256;  // pyramid_20 (210 bodies) loads, pyramid_40 is refused
  c.maxJointsPerWorld = 256;
  c.maxBodiesTotal = 1024;
  c.memoryBudgetBytes = 1536ull << 20;  // below tools/fuzz.sh's -rss_limit_mb
  c.maxSnapshotFiles = 8;
  c.maxSnapshotBytes = 1u << 20;
  c.maxContactPairs = 4096;
  c.dataDir.clear();  // worlds in memory only: nothing written but snapshot files
  // No per-client rate limit: it depends on wall-clock time, so a finding would not replay.
  c.maxClientCommandsPerS = 0;
  protocol::Limits& l = c.limits;
  l.maxMessageBytes = 1u << 20;
  l.maxBodiesPerCommand = 64;
  l.maxShapesPerCommand = 512;
  l.maxHullPointsPerCommand = 4096;
  l.maxJointsPerCommand = 64;
  l.maxIdsPerCommand = 1024;
  l.maxItemsPerCommand = 1024;
  l.maxStepsPerCommand = 8;
  l.maxBodyStepsPerCommand = 2048;
  l.maxSnapshotBodies = 1024;
  l.maxSnapshotShapes = 4096;
  l.maxSnapshotHullPoints = 65536;
  return c;
}

/// A convex hull body: an octahedron stretched along z (6 points).
inline BodyDef hullBody(Vec3 p) {
  std::vector<Vec3> pts = {{0.4f, 0, 0}, {-0.4f, 0, 0}, {0, 0.4f, 0},
                           {0, -0.4f, 0}, {0, 0, 0.6f}, {0, 0, -0.6f}};
  std::string err;
  BodyDef d;
  d.position = p;
  ShapeDef s;
  s.geom = ShapeGeom::convexHull(buildConvexHull(pts, &err));
  d.shapes.push_back(s);
  d.name = "hull";
  return d;
}

inline BodyDef shapeBody(Vec3 p, ShapeGeom g, const char* name,
                         BodyType type = BodyType::Dynamic) {
  BodyDef d;
  d.type = type;
  d.position = p;
  ShapeDef s;
  s.geom = g;
  d.shapes.push_back(s);
  d.name = name;
  return d;
}

/// The fuzz world's bodies, in spawn order.
inline std::vector<BodyDef> baseBodies() {
  std::vector<BodyDef> v;
  v.push_back(shapeBody({0, 0, 0}, ShapeGeom::plane({0, 0, 1}, 0), "ground", BodyType::Static));
  v.push_back(shapeBody({0, 0, 0.5f}, ShapeGeom::box({0.5f, 0.5f, 0.5f}), "box"));
  v.push_back(shapeBody({0, 0, 1.6f}, ShapeGeom::sphere(0.4f), "sphere"));
  v.push_back(shapeBody({2, 0, 0.8f}, ShapeGeom::capsule(0.2f, 0.4f), "capsule"));
  v.push_back(hullBody({-2, 0, 0.7f}));
  BodyDef k = shapeBody({0, 3, 1}, ShapeGeom::box({1, 0.2f, 0.1f}), "paddle", BodyType::Kinematic);
  k.angularVelocity = {0, 0, 1};
  v.push_back(k);
  return v;
}

/// The fuzz world's joints between baseBodies() (ids as spawned): a hinge box-sphere and a
/// ball joint hanging the capsule from the world.
inline std::vector<JointDef> baseJoints(const std::vector<uint64_t>& bodies) {
  std::vector<JointDef> v;
  JointDef h;
  h.type = JointType::Hinge;
  h.bodyA = BodyId::fromPacked(bodies.at(1));
  h.bodyB = BodyId::fromPacked(bodies.at(2));
  h.anchorA = {0, 0, 0.5f};
  h.anchorB = {0, 0, -0.6f};
  h.axisA = h.axisB = {1, 0, 0};
  h.name = "hinge";
  v.push_back(h);
  JointDef b;
  b.type = JointType::Ball;
  b.bodyB = BodyId::fromPacked(bodies.at(3));
  b.anchorA = {2, 0, 1.5f};
  b.anchorB = {0, 0, 0.6f};
  b.name = "hang";
  v.push_back(b);
  return v;
}

/// A core with the fuzz world built. `error` says what failed (then the core is null).
struct FuzzServer {
  std::unique_ptr<server::ServerCore> core;
  std::vector<uint64_t> bodies, joints;  ///< the fuzz world's ids
  protocol::Bytes snapshot;              ///< its Snapshot buffer (engine state), as built
  std::string error;

  explicit FuzzServer(const std::string& snapshotDir, bool compact = false) {
    core = std::make_unique<server::ServerCore>(coreConfig(snapshotDir, compact));
    protocol::Status st = core->init();
    if (!st.ok()) {
      fail("init: " + st.message);
      return;
    }
    auto send = [&](protocol::CommandBuilder& b, uint32_t world = kWorld) {
      return protocol::decodeReply(core->applyBytes(b.finish({kClient, 1, world}), kClient, 1));
    };
    protocol::CreateWorldArgs args;
    args.name = "fuzz";
    args.backend = "cpu";
    auto r = send(protocol::CommandBuilder().createWorld(args), 0);  // kClient owns it
    if (!r.ok() || r->status() != wire::StatusCode::Ok || r->world() != kWorld) {
      fail("create the fuzz world");
      return;
    }
    const std::vector<BodyDef> defs = baseBodies();
    r = send(protocol::CommandBuilder().spawnBodies(defs));
    if (!r.ok() || r->status() != wire::StatusCode::Ok || !r->result_as_Ids())
      {
      fail("spawn the fuzz bodies");
      return;
    }
    for (uint64_t b : *r->result_as_Ids()->bodies()) bodies.push_back(b);
    const std::vector<JointDef> jd = baseJoints(bodies);
    r = send(protocol::CommandBuilder().addJoints(jd));
    if (!r.ok() || r->status() != wire::StatusCode::Ok || !r->result_as_Ids())
      {
      fail("add the fuzz joints");
      return;
    }
    for (uint64_t j : *r->result_as_Ids()->joints()) joints.push_back(j);
    r = send(protocol::CommandBuilder().subscribeRegion(kInterestLo, kInterestHi));
    if (!r.ok() || r->status() != wire::StatusCode::Ok || !r->result_as_InterestResult() ||
        r->result_as_InterestResult()->interest() != kInterest) {
      fail("subscribe to the fuzz world");
      return;
    }
    r = send(protocol::CommandBuilder().saveSnapshot(kBaseSnapshotFile, true));
    if (!r.ok() || r->status() != wire::StatusCode::Ok || !r->result_as_SnapshotResult() ||
        !r->result_as_SnapshotResult()->snapshot())
      {
      fail("snapshot the fuzz world");
      return;
    }
    auto* s = r->result_as_SnapshotResult()->snapshot();
    snapshot.assign(s->begin(), s->end());
  }
  bool ok() const { return error.empty(); }

 private:
  void fail(std::string why) {
    error = std::move(why);
    core.reset();
  }
};

}  // namespace phys::fuzz
