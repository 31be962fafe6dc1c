// Forged snapshots (issue 39): a snapshot whose checksum is right but whose fields no world
// holds. A restore refuses it, with a message, and leaves the world as it was; or it accepts
// a state the steps can take: memory-safe (the sanitizer builds check that), finite, and
// saved and restored again. The forged fields and the world they are forged from are
// fuzz/snapshot_forge.h's (fuzz_restore's corpus holds the same cases).
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <map>
#include <string>
#include <vector>

#include "../../fuzz/snapshot_forge.h"
#include "phys/world/world.h"

using namespace phys;
namespace forge = phys::forge;
using forge::Bytes;

namespace {

Bytes save(const World& w) {
  Bytes b;
  Status st = w.saveSnapshot(&b);
  EXPECT_TRUE(st.ok()) << st.message;
  return b;
}

/// forge::buildWorld's snapshot, made once.
const Bytes& forgedFrom() {
  static const Bytes bytes = [] {
    World w(forge::worldDef());
    EXPECT_TRUE(forge::buildWorld(w));
    return save(w);
  }();
  return bytes;
}

bool finite(Vec3 v) {
  return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z);
}

/// Empty when every body's pose and velocities are finite, else the first that is not.
std::string nonFiniteBody(const World& w) {
  for (BodyId id : w.bodies()) {
    BodyState s;
    if (!w.getBody(id, &s).ok()) return "a listed body cannot be read";
    const Quat q = s.rotation;
    if (!finite(s.position) || !finite(s.linearVelocity) || !finite(s.angularVelocity) ||
        !std::isfinite(q.x + q.y + q.z + q.w))
      return "body " + std::to_string(id.packed()) + " is not finite";
  }
  return {};
}

/// A world holding forge::buildWorld's state, which forged snapshots are restored into.
struct Target {
  World w{forge::worldDef()};
  Target() { EXPECT_TRUE(w.restoreSnapshot(forgedFrom().data(), forgedFrom().size()).ok()); }
  /// Puts the original back after a forgery was accepted.
  void reset() {
    Status st = w.restoreSnapshot(forgedFrom().data(), forgedFrom().size());
    ASSERT_TRUE(st.ok()) << st.message;
  }
};

}  // namespace

TEST(SnapshotForgery, TheWorldHoldsEveryRecordKindAndEveryCaseIsFound) {
  World w(forge::worldDef());
  std::map<std::string, BodyId> ids;
  ASSERT_TRUE(forge::buildWorld(w, &ids));
  for (const char* name : {"stack0", "stack1", "stack2", "hinged-a", "hinged-b", "tetra", "pill"})
    EXPECT_TRUE(w.isSleeping(ids[name])) << name;
  for (const char* name :
       {"pendulum", "bob", "ball", "slider", "anvil", "plinth", "sweeper", "ground", "ledge"})
    EXPECT_FALSE(w.isSleeping(ids[name])) << name;
  EXPECT_FALSE(w.isValid(ids["doomed"]));
  EXPECT_EQ(w.stats().sleepingIslands, 4) << "the stack, the hinged pair, the hull, the capsule";
  const forge::Records r = forge::records(forgedFrom());
  ASSERT_FALSE(r.awakeContacts.empty());
  size_t islandContacts = 0;
  for (const auto& list : r.islandContacts) islandContacts += list.size();
  EXPECT_GT(islandContacts, 0u) << "sleeping islands keep their touching contacts";
  ASSERT_NE(r.freeIslands, forge::kNone);
  EXPECT_GT(forge::getU32(forgedFrom(), r.freeIslands), 0u) << "the doomed body's island";
  for (const forge::Forgery& f : forge::forgeries(forgedFrom()))
    EXPECT_FALSE(f.bytes.empty()) << f.name << ": the field was not found in the snapshot";
}

// The finding of issue 39: the ground's solver index at 0x7FFFFFFF was accepted, and the next
// step read solver body 2^31 - 1 (SIGSEGV in WideContacts::build).
TEST(SnapshotForgery, StaticBodySolverIndexIsRefused) {
  std::vector<forge::Forgery> all = forge::forgeries(forgedFrom());
  ASSERT_FALSE(all.empty());
  const forge::Forgery& f = all.front();
  ASSERT_EQ(f.name, "static_solver_index_i32_max");
  Target t;
  Status st = t.w.restoreSnapshot(f.bytes.data(), f.bytes.size());
  EXPECT_EQ(st.code, StatusCode::InvalidArgument);
  EXPECT_NE(st.message.find("solver index"), std::string::npos) << st.message;
  EXPECT_EQ(save(t.w), forgedFrom()) << "a refused snapshot changed the world";
  for (int i = 0; i < 10; ++i) t.w.step();
  EXPECT_EQ(nonFiniteBody(t.w), "");
}

// Each forged case: refused for its field, the world unchanged and still stepping.
TEST(SnapshotForgery, EveryForgedCaseIsRefused) {
  Target t;
  for (const forge::Forgery& f : forge::forgeries(forgedFrom())) {
    ASSERT_FALSE(f.bytes.empty()) << f.name;
    Status st = t.w.restoreSnapshot(f.bytes.data(), f.bytes.size());
    EXPECT_FALSE(st.ok()) << f.name << " was accepted";
    if (st.ok()) {
      t.reset();
      continue;
    }
    EXPECT_EQ(st.code, StatusCode::InvalidArgument) << f.name;
    EXPECT_NE(st.message.find(f.expect), std::string::npos)
        << f.name << ": refused for another reason: " << st.message;
    EXPECT_EQ(save(t.w), forgedFrom()) << f.name << " changed the world: " << st.message;
  }
  for (int i = 0; i < 10; ++i) t.w.step();
  EXPECT_EQ(nonFiniteBody(t.w), "");
}

// An awake body's solver index is last step's number: the step numbers the awake bodies
// again before it reads any. Any value in range restores to the same simulation.
TEST(SnapshotForgery, AnAwakeBodysSolverIndexIsNotRead) {
  const Bytes& valid = forgedFrom();
  const size_t at = forge::afterName(valid, forge::section(valid, "BODY"), "pendulum");
  ASSERT_NE(at, forge::kNone);
  auto run = [](const Bytes& snap) {
    World w(forge::worldDef());
    Status st = w.restoreSnapshot(snap.data(), snap.size());
    EXPECT_TRUE(st.ok()) << st.message;
    std::vector<uint64_t> hashes;
    for (int i = 0; i < 30; ++i) {
      w.step();
      hashes.push_back(w.stateHash());
    }
    return hashes;
  };
  const std::vector<uint64_t> expected = run(valid);
  const uint32_t capacity = forge::getU32(valid, forge::section(valid, "BODY").at);  // slots
  for (uint32_t v : {uint32_t(-1), 0u, 1u, capacity}) {
    Bytes b = valid;
    forge::putU32(&b, at + forge::body::kSolverIndex, v);
    forge::seal(&b);
    EXPECT_EQ(run(b), expected) << "solver index " << int32_t(v);
  }
}

// Every 4-byte window of the records that refer to one another (bodies, shapes, joints,
// contacts, the broad phase's proxies, the sleeping islands; one section per test) set to
// each of a few extreme values, the checksum recomputed: refused with the world unchanged,
// or accepted, then saved and restored again, and stepped 10 times, staying finite.
class SnapshotForgeryWords : public ::testing::TestWithParam<const char*> {};

TEST_P(SnapshotForgeryWords, RefusedOrSafeToStep) {
  const char* tag = GetParam();
  const Bytes& valid = forgedFrom();
  // Indices and counts out of range, -1, null ids, small indices, the body pool's capacity
  // (one past its last slot), the largest float.
  const uint32_t capacity = forge::getU32(valid, forge::section(valid, "BODY").at);
  const uint32_t values[] = {0x7FFFFFFF, 0xFFFFFFFF, 0x80000000, 0x00000000,
                             0x00000001, 0x00000002, capacity,   0x7F7FFFFF};
  Target t;
  const uint64_t hash = t.w.stateHash();
  int refused = 0, accepted = 0;
  const forge::Section s = forge::section(valid, tag);
  ASSERT_TRUE(s.found()) << tag;
  for (size_t p = s.at; p + 4 <= s.end(); ++p) {
    for (uint32_t v : values) {
      if (forge::getU32(valid, p) == v) continue;
      Bytes bad = valid;
      forge::putU32(&bad, p, v);
      forge::seal(&bad);
      const std::string what =
          std::string(tag) + " +" + std::to_string(p - s.at) + " = " + std::to_string(v);
      Status st = t.w.restoreSnapshot(bad.data(), bad.size());
      if (!st.ok()) {
        ++refused;
        ASSERT_FALSE(st.message.empty()) << what;
        // The world as it was (its poses: saving it for every case would be slow; the bytes
        // are compared once at the end).
        ASSERT_EQ(t.w.stateHash(), hash) << what;
        continue;
      }
      ++accepted;
      Bytes again;
      st = t.w.saveSnapshot(&again);
      ASSERT_TRUE(st.ok()) << what << ": " << st.message;
      World other(forge::worldDef());
      st = other.restoreSnapshot(again.data(), again.size());
      ASSERT_TRUE(st.ok()) << what << ": saved again, refused: " << st.message;
      for (int i = 0; i < 10; ++i) t.w.step();
      ASSERT_EQ(nonFiniteBody(t.w), "") << what;
      t.reset();
    }
  }
  EXPECT_EQ(save(t.w), valid);
  std::printf("[ forgery  ] %s: %d forged snapshots refused, %d accepted and stepped\n", tag,
              refused, accepted);
}

INSTANTIATE_TEST_SUITE_P(Sections, SnapshotForgeryWords,
                         ::testing::Values("BODY", "SHAP", "JOIN", "CONT", "BRPH", "ISLE"),
                         [](const ::testing::TestParamInfo<const char*>& info) {
                           return std::string(info.param);
                         });
