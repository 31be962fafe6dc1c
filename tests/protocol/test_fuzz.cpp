// Mutated valid buffers never crash a decoder, and whatever a decoder accepts converts
// cleanly to phys types (the server's next step).
#include <array>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <functional>
#include <iterator>
#include <random>

#include "protocol_test_util.h"

namespace phys::protocol::test {
namespace {

/// One valid command of every kind, plus a batch.
std::vector<Bytes> commandCorpus() {
  std::vector<Bytes> c;
  std::vector<phys::BodyDef> bodies = sampleBodies();
  phys::JointDef joint = sampleJoint();
  std::vector<uint64_t> ids = {1, 2, 3};
  SolverOverrides o;
  o.substeps = 2;
  o.scheme = phys::SolverSettings::Scheme::Jacobi;
  o.contactHertz = 20;
  SnapshotData snap;
  for (size_t i = 0; i < bodies.size(); ++i) snap.bodies.push_back({i + 1, bodies[i]});
  c.push_back(CommandBuilder().hello("fuzz").finish(header(1, 0)));
  c.push_back(CommandBuilder()
                  .createWorld({"w", "pgs", phys::Vec3{0, 0, -9.8f}, 0.01f})
                  .finish(header(1, 0)));
  c.push_back(CommandBuilder().destroyWorld().finish(header()));
  c.push_back(CommandBuilder().resetWorld().finish(header()));
  c.push_back(CommandBuilder().listWorlds().finish(header(1, 0)));
  c.push_back(CommandBuilder().loadSceneJson("{\"bodies\": []}").finish(header()));
  c.push_back(CommandBuilder().loadSceneNamed("pyramid_20").finish(header()));
  c.push_back(CommandBuilder().spawnBodies(bodies).finish(header()));
  c.push_back(CommandBuilder().removeBodies(ids).finish(header()));
  c.push_back(CommandBuilder().addJoints({&joint, 1}).finish(header()));
  c.push_back(CommandBuilder().removeJoints(ids).finish(header()));
  c.push_back(CommandBuilder().setBodyPose(1, {1, 2, 3}, {}).finish(header()));
  c.push_back(CommandBuilder().setBodyVelocity(1, {1, 2, 3}, {0, 0, 1}).finish(header()));
  c.push_back(CommandBuilder()
                  .applyForce(1, {0, 0, 1}, {1, 0, 0}, wire::PointFrame::World)
                  .finish(header()));
  c.push_back(CommandBuilder().applyImpulse(1, {0, 0, 1}).finish(header()));
  c.push_back(CommandBuilder().applyTorque(1, {0, 0, 1}).finish(header()));
  c.push_back(CommandBuilder().setMaterial(ids, {0.5f, 0.5f, 100}).finish(header()));
  c.push_back(CommandBuilder().setSolver("pgs", o).finish(header()));
  c.push_back(CommandBuilder().step(10).finish(header()));
  c.push_back(CommandBuilder().run(60).finish(header()));
  c.push_back(CommandBuilder().pause().finish(header()));
  c.push_back(CommandBuilder().queryState(ids, 0, 10).finish(header()));
  c.push_back(CommandBuilder().saveSnapshot("a.snap").finish(header()));
  c.push_back(CommandBuilder().restoreSnapshot(encodeSnapshot(snap)).finish(header()));
  SnapshotData exact;
  exact.engineState.assign(200, 0x5A);
  c.push_back(CommandBuilder().restoreSnapshot(encodeSnapshot(exact)).finish(header()));
  c.push_back(CommandBuilder()
                  .spawnBodies(bodies)
                  .addJoints({&joint, 1})
                  .setBodyPose(1, {}, {})
                  .applyForce(2, {1, 0, 0})
                  .setSolver("", o)
                  .finish(header()));
  return c;
}

/// Reads everything the server would read from an accepted command.
void consume(wire::Request type, const void* table) {
  switch (type) {
    case wire::Request::SpawnBodies: {
      phys::WorldDef def;
      def.threads = 1;
      phys::World w(def);
      for (const wire::BodyDef* b : *static_cast<const wire::SpawnBodies*>(table)->bodies()) {
        phys::BodyDef d;
        phys::BodyId id;
        if (toBodyDef(*b, &d).ok()) (void)w.createBody(d, &id);
      }
      break;
    }
    case wire::Request::AddJoints:
      for (const wire::JointDef* j : *static_cast<const wire::AddJoints*>(table)->joints())
        (void)toJointDef(*j);
      break;
    case wire::Request::SetSolver:
      if (auto* s = static_cast<const wire::SetSolver*>(table)->settings()) {
        phys::SolverSettings settings;
        applySolverSettings(*s, &settings);
      }
      break;
    case wire::Request::RestoreSnapshot:
      if (auto* b = static_cast<const wire::RestoreSnapshot*>(table)->snapshot()) {
        auto s = decodeSnapshot(std::span<const uint8_t>(b->data(), b->size()));
        EXPECT_TRUE(s.ok()) << "an accepted command's snapshot must decode: " << s.status.message;
        SnapshotData data;
        if (s.ok()) (void)toSnapshotData(*s, &data);
      }
      break;
    case wire::Request::Batch:
      for (const wire::CommandItem* item : *static_cast<const wire::Batch*>(table)->commands())
        consume(item->request_type(), item->request());
      break;
    default:
      break;
  }
}

void mutate(Bytes* b, std::mt19937& rng) {
  int n = 1 + int(rng() % 6);
  for (int k = 0; k < n && !b->empty(); ++k) {
    size_t at = rng() % b->size();
    switch (rng() % 8) {
      case 0:  // flip a bit
        (*b)[at] ^= uint8_t(1u << (rng() % 8));
        break;
      case 1:  // a random byte
        (*b)[at] = uint8_t(rng());
        break;
      case 2:  // an interesting byte
        (*b)[at] = std::array<uint8_t, 6>{0, 0x7F, 0x80, 0xFF, 0x01, 0x7F}[rng() % 6];
        break;
      case 3: {  // an interesting 32-bit word (offsets, lengths, float bits: NaN, inf)
        static constexpr uint32_t kWords[] = {0,          0xFFFFFFFF, 0x7FFFFFFF, 0x80000000,
                                              0x7FC00000, 0x7F800000, 0xFF800000, 1,
                                              4,          0x00010000, 0xBF800000};
        uint32_t w = kWords[rng() % std::size(kWords)];
        size_t a = at & ~size_t(3);
        if (a + 4 <= b->size()) std::memcpy(b->data() + a, &w, 4);
        break;
      }
      case 4:  // truncate
        b->resize(at);
        break;
      case 5:  // append garbage
        for (int i = 0; i < 8; ++i) b->push_back(uint8_t(rng()));
        break;
      case 6:  // small integer nudge (a union type, an enum, a count)
        (*b)[at] = uint8_t((*b)[at] + (rng() % 2 ? 1 : -1));
        break;
      default: {  // copy a run of bytes from elsewhere
        size_t from = rng() % b->size(), len = std::min<size_t>(rng() % 16, b->size() - at);
        len = std::min(len, b->size() - from);
        std::memmove(b->data() + at, b->data() + from, len);
        break;
      }
    }
  }
}

/// PHYS_FUZZ_ITERATIONS and PHYS_FUZZ_SEED override the defaults for longer soak runs, e.g.
/// PHYS_FUZZ_ITERATIONS=2000000 PHYS_FUZZ_SEED=7 phys_protocol_tests --gtest_filter='*Fuzz*'
long envOr(const char* name, long fallback) {
  const char* v = std::getenv(name);
  return v && *v ? std::strtol(v, nullptr, 10) : fallback;
}

TEST(ProtocolFuzz, MutatedCommandsNeverCrash) {
  const std::vector<Bytes> corpus = commandCorpus();
  for (const Bytes& b : corpus) ASSERT_TRUE(decodeCommand(b).ok());
  std::mt19937 rng(uint32_t(envOr("PHYS_FUZZ_SEED", 12345)));
  auto start = std::chrono::steady_clock::now();
  long accepted = 0, rejected = 0;
  const long kIterations = envOr("PHYS_FUZZ_ITERATIONS", 50000);
  for (long i = 0; i < kIterations; ++i) {
    Bytes b = corpus[rng() % corpus.size()];
    mutate(&b, rng);
    Decoded<wire::Command> d = decodeCommand(b);
    if (d.ok()) {
      ++accepted;
      consume(d->request_type(), d->request());
    } else {
      ++rejected;
      EXPECT_FALSE(d.status.message.empty());
      EXPECT_NE(d.status.code, Code::Internal);
    }
  }
  double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  std::printf("%ld mutated commands: %ld accepted, %ld rejected, %.2f s\n", kIterations, accepted,
              rejected, seconds);
  EXPECT_GT(rejected, kIterations / 4);
}

TEST(ProtocolFuzz, MutatedPublishedDataNeverCrash) {
  std::vector<phys::BodyDef> bodies = sampleBodies();
  std::vector<BodyEntry> entries;
  for (size_t i = 0; i < bodies.size(); ++i) entries.push_back({i + 1, bodies[i]});
  std::vector<JointEntry> joints = {{1, sampleJoint()}};
  std::vector<wire::BodyState> states(20);
  SnapshotData snap;
  snap.bodies = entries;
  WorldSummary ws;
  ws.name = "w";
  ServerStatusInfo status;
  status.worlds = {ws};
  std::vector<uint64_t> ids = {1, 2};
  struct Case {
    Bytes bytes;
    std::function<bool(const Bytes&)> decode;
  };
  std::vector<Case> cases = {
      {encodeStateFrame({1, 2, 3}, 0, 1, 20, states),
       [](const Bytes& b) { return decodeStateFrame(b).ok(); }},
      {encodeWorldInfo({1, "w", 1, 1, {}, 0.01f}, entries, joints)[0],
       [](const Bytes& b) {
         auto d = decodeWorldInfo(b);
         if (d.ok() && d->bodies())
           for (const wire::BodyEntry* e : *d->bodies()) {
             phys::BodyDef def;
             (void)toBodyDef(*e->def(), &def);
           }
         return d.ok();
       }},
      {encodeSnapshot(snap),
       [](const Bytes& b) {
         auto d = decodeSnapshot(b);
         SnapshotData s;
         if (d.ok()) (void)toSnapshotData(*d, &s);
         return d.ok();
       }},
      {encodeIdsReply({1, 2, 3, 4, {}}, ids, ids),
       [](const Bytes& b) { return decodeReply(b).ok(); }},
      {encodeWorldListReply({1, 2, 3, 4, {}}, {&ws, 1}),
       [](const Bytes& b) { return decodeReply(b).ok(); }},
      {encodeServerStatus(status), [](const Bytes& b) { return decodeServerStatus(b).ok(); }},
      {encodeEvent(1, 2, wire::Severity::Error, "c", "m"),
       [](const Bytes& b) { return decodeEvent(b).ok(); }},
  };
  for (const Case& c : cases) ASSERT_TRUE(c.decode(c.bytes));
  std::mt19937 rng(uint32_t(envOr("PHYS_FUZZ_SEED", 777)));
  const long kIterations = envOr("PHYS_FUZZ_ITERATIONS", 50000) / 10;
  for (long i = 0; i < kIterations; ++i) {
    const Case& c = cases[rng() % cases.size()];
    Bytes b = c.bytes;
    mutate(&b, rng);
    (void)c.decode(b);
  }
}

}  // namespace
}  // namespace phys::protocol::test
