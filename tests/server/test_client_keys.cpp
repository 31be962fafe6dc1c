// Issue 39, finding 1: client ids bound to the DDS participant that sent them (ClientKeys),
// without DDS. The liveness oracle stands for the DDS call the endpoint makes
// (dds_get_matched_publication_data): counting its calls shows what a command costs. Before
// the fix, once 65,536 ids were held, every command under a new id called it for every id
// held (a scan per command: 80-110 ms each in physd), and one participant could hold them all.
#include <gtest/gtest.h>

#include <set>

#include "phys/server/client_keys.h"

namespace phys::server::test {
namespace {

using Clock = ClientKeys::Clock;
using Verdict = ClientKeys::Verdict;
using namespace std::chrono_literals;

Guid guid(uint32_t n) {
  Guid g{};
  g[0] = 0x01;
  g[1] = 0x10;
  for (int i = 0; i < 4; ++i) g[4 + i] = uint8_t(n >> (8 * i));
  g[15] = 0xc1;
  return g;
}

/// A table with a liveness oracle over `alive` (writers still matched) that counts its calls.
struct Keys {
  explicit Keys(ClientKeys::Limits limits = {})
      : keys(limits, [this](ClientKeys::Writer w) {
          ++calls;
          return alive.count(w) != 0;
        }) {}
  /// A participant's writer appears (matched) and is added.
  void join(ClientKeys::Writer w, uint32_t participant, uint64_t principal = 0) {
    alive.insert(w);
    ASSERT_TRUE(keys.addWriter(w, guid(participant), principal));
  }
  ClientKeys::Result claim(uint64_t key, ClientKeys::Writer w) { return keys.claim(key, w, now); }
  std::vector<ClientKeys::Departed> sweep() {
    std::vector<ClientKeys::Writer> live(alive.begin(), alive.end());
    return keys.sweep(live);
  }
  std::set<ClientKeys::Writer> alive;
  uint64_t calls = 0;
  Clock::time_point now = Clock::time_point{} + 1h;
  ClientKeys keys;
};

TEST(ClientKeys, OneParticipantHoldsAtMostItsShareOfIds) {
  Keys k;  // 16 ids a participant (server.max_keys_per_participant)
  k.join(1, 1);
  k.join(2, 2);
  for (uint64_t key = 100; key < 116; ++key) EXPECT_EQ(k.claim(key, 1).verdict, Verdict::Ok);
  // The 70,000 ids of the finding: the 16 first are its own, the rest are refused, and the
  // table does not grow.
  int reported = 0;
  for (uint64_t key = 116; key < 70000; ++key) {
    const ClientKeys::Result r = k.claim(key, 1);
    ASSERT_EQ(r.verdict, Verdict::TooManyKeys) << key;
    EXPECT_EQ(r.participant, k.claim(100, 1).participant);
    reported += r.report;
  }
  EXPECT_EQ(k.keys.keys(), 16u);
  EXPECT_EQ(k.keys.keysOf(k.claim(100, 1).participant), 16u);
  EXPECT_EQ(reported, 1) << "the first refusal is reported, then one per reportEvery";
  k.now += 10s;
  EXPECT_TRUE(k.claim(70001, 1).report);
  // Its own ids still work, and another participant is not held back.
  EXPECT_EQ(k.claim(100, 1).verdict, Verdict::Ok);
  EXPECT_EQ(k.claim(200, 2).verdict, Verdict::Ok);
  EXPECT_EQ(k.calls, 0u) << "nothing here needs DDS";
}

TEST(ClientKeys, ANewIdCostsNoDdsCallWhateverTheTableHolds) {
  // The table full of live participants' ids (as 65,536 were in the finding): a command under
  // one more id is refused at once, and costs no liveness call, let alone one per id held.
  ClientKeys::Limits limits;
  limits.maxKeys = 4096;
  Keys k(limits);
  for (uint32_t p = 1; p <= 4096; ++p) {
    k.join(p, p);
    ASSERT_EQ(k.claim(0x100000 + p, p).verdict, Verdict::Ok);
  }
  k.join(5000, 5000);
  for (uint64_t key = 1; key <= 1000; ++key) {
    const ClientKeys::Result r = k.claim(key, 5000);
    ASSERT_EQ(r.verdict, Verdict::Full);
    EXPECT_EQ(r.report, key == 1);
  }
  EXPECT_EQ(k.calls, 0u);
  EXPECT_TRUE(k.keys.sweepWanted());
  // Half of them leave: one sweep (O(writers)) frees their ids, and the newcomer gets one.
  for (uint32_t p = 1; p <= 2048; ++p) k.alive.erase(p);
  EXPECT_EQ(k.sweep().size(), 2048u);
  EXPECT_FALSE(k.keys.sweepWanted());
  EXPECT_EQ(k.keys.keys(), 2048u);
  EXPECT_EQ(k.claim(1, 5000).verdict, Verdict::Ok);
  EXPECT_EQ(k.calls, 0u);
}

TEST(ClientKeys, AHeldIdIsRefusedToOthersAndAskedAboutAtMostOncePerRecheck) {
  Keys k;
  k.join(1, 1);  // the holder
  k.join(2, 2);  // a participant writing under the holder's id
  ASSERT_EQ(k.claim(0xA11CE, 1).verdict, Verdict::Ok);
  for (int i = 0; i < 10000; ++i) ASSERT_EQ(k.claim(0xA11CE, 2).verdict, Verdict::HeldByOther);
  EXPECT_EQ(k.calls, 1u) << "the holder's writer is asked about once per recheck, not per command";
  k.now += 100ms;
  EXPECT_EQ(k.claim(0xA11CE, 2).verdict, Verdict::HeldByOther);
  EXPECT_EQ(k.calls, 2u);
  EXPECT_EQ(k.keys.holder(0xA11CE), k.claim(0xA11CE, 1).participant);
  // Its holder answers as before.
  EXPECT_EQ(k.claim(0xA11CE, 1).verdict, Verdict::Ok);
}

TEST(ClientKeys, AnIdPassesAtOnceWhenItsHoldersWriterIsGone) {
  // A client restarted with the same id: its old participant's writer is no longer matched,
  // so the id passes at the new participant's first command, before any sweep.
  Keys k;
  k.join(1, 1);
  ASSERT_EQ(k.claim(0xBEEF, 1).verdict, Verdict::Ok);
  k.alive.erase(1);
  k.join(2, 2);
  const ClientKeys::Result r = k.claim(0xBEEF, 2);
  EXPECT_EQ(r.verdict, Verdict::Ok);
  EXPECT_EQ(k.keys.holder(0xBEEF), r.participant);
  EXPECT_EQ(k.calls, 1u);
  // The old participant goes at the next sweep, without the id it no longer holds.
  std::vector<ClientKeys::Departed> gone = k.sweep();
  ASSERT_EQ(gone.size(), 1u);
  EXPECT_EQ(gone[0].guid, guid(1));
  EXPECT_TRUE(gone[0].keys.empty());
  EXPECT_EQ(k.keys.holder(0xBEEF), r.participant);
}

TEST(ClientKeys, AParticipantsIdsAreFreedWhenItsLastWriterLeaves) {
  Keys k;
  k.join(10, 7, /*principal=*/0x1D);
  k.join(11, 7);  // a second writer of the same participant: one share of ids
  for (uint64_t key = 1; key <= 10; ++key) ASSERT_EQ(k.claim(key, 10).verdict, Verdict::Ok);
  for (uint64_t key = 11; key <= 16; ++key) ASSERT_EQ(k.claim(key, 11).verdict, Verdict::Ok);
  EXPECT_EQ(k.claim(17, 11).verdict, Verdict::TooManyKeys);
  EXPECT_EQ(k.claim(1, 10).principal, 0x1Du);
  EXPECT_EQ(k.claim(1, 11).verdict, Verdict::Ok) << "either writer may use the participant's ids";
  EXPECT_EQ(k.keys.participants(), 1u);
  const uint64_t number = k.claim(1, 10).participant;

  k.alive.erase(10);
  EXPECT_TRUE(k.sweep().empty()) << "one writer left: the participant is still there";
  EXPECT_EQ(k.keys.keys(), 16u);
  EXPECT_EQ(k.keys.writers(), 1u);
  k.alive.erase(11);
  std::vector<ClientKeys::Departed> gone = k.sweep();
  ASSERT_EQ(gone.size(), 1u);
  EXPECT_EQ(gone[0].participant, number);
  EXPECT_EQ(gone[0].guid, guid(7));
  EXPECT_EQ(std::set<uint64_t>(gone[0].keys.begin(), gone[0].keys.end()).size(), 16u);
  EXPECT_EQ(k.keys.keys(), 0u);
  EXPECT_EQ(k.keys.participants(), 0u);
  EXPECT_EQ(k.keys.guidOf(number), nullptr);
  // Its ids are free: another participant takes them without a liveness call.
  k.join(20, 8);
  EXPECT_EQ(k.claim(5, 20).verdict, Verdict::Ok);
  EXPECT_NE(k.claim(5, 20).participant, number) << "numbers are never reused";
  EXPECT_EQ(k.calls, 0u);
}

TEST(ClientKeys, TheWriterTableIsBoundedToo) {
  ClientKeys::Limits limits;
  limits.maxWriters = 8;
  Keys k(limits);
  for (ClientKeys::Writer w = 1; w <= 8; ++w) k.join(w, uint32_t(w));
  EXPECT_FALSE(k.keys.addWriter(9, guid(9), 0));
  EXPECT_EQ(k.claim(1, 9).verdict, Verdict::Full);
  EXPECT_TRUE(k.keys.sweepWanted());
  k.alive.erase(8);
  EXPECT_EQ(k.sweep().size(), 1u);
  k.join(9, 9);
  EXPECT_EQ(k.claim(1, 9).verdict, Verdict::Ok);
}

// Issue 39, finding 5: a key proven by its holder (a Hello with the key's binding proof; here
// a Proof that accepts one participant's GUID, as protocol::verifyBinding would) takes the key
// from whoever holds it, proven or not, and the commands under it are proven; a plain claim
// takes nothing from a live holder. (Before, the first participant kept the key while it was
// there, so an owner coming back found its id held and got no answer.)
TEST(ClientKeys, AProofTakesTheKeyFromAnyHolderAndItsCommandsAreProven) {
  Keys k;
  k.join(1, 1);  // a squatter, using the owner's id without a proof
  k.join(2, 2);  // the owner, back with its key
  k.join(3, 3);  // someone replaying the owner's proof from another participant
  const uint64_t id = 0xAB;
  int checks = 0;
  const ClientKeys::Proof owners = [&](const Guid& g) {
    ++checks;
    return g == guid(2);
  };
  ASSERT_EQ(k.claim(id, 1).verdict, Verdict::Ok);
  EXPECT_FALSE(k.claim(id, 1).proven);
  // The replayed proof does not hold for participant 3: the key stays the squatter's.
  EXPECT_EQ(k.keys.claim(id, 3, k.now, &owners).verdict, Verdict::HeldByOther);
  EXPECT_EQ(k.keys.holder(id), 1u);
  // The owner's does: the key is its own at once, though the squatter is still there.
  const ClientKeys::Result back = k.keys.claim(id, 2, k.now, &owners);
  EXPECT_EQ(back.verdict, Verdict::Ok);
  EXPECT_TRUE(back.proven);
  EXPECT_EQ(k.keys.holder(id), 2u);
  EXPECT_EQ(k.keys.keysOf(1), 0u);
  // Its later commands (no proof offered) stay proven, without another check.
  const int before = checks;
  EXPECT_TRUE(k.claim(id, 2).proven);
  EXPECT_TRUE(k.keys.claim(id, 2, k.now, &owners).proven);
  EXPECT_EQ(checks, before) << "a proven key is not checked again";
  // The squatter's commands under it are now refused (dropped unanswered by the endpoint).
  EXPECT_EQ(k.claim(id, 1).verdict, Verdict::HeldByOther);
  // When the owner leaves, a plain claim may have the key again, unproven.
  k.alive.erase(2);
  k.sweep();
  const ClientKeys::Result again = k.claim(id, 1);
  EXPECT_EQ(again.verdict, Verdict::Ok);
  EXPECT_FALSE(again.proven);
}

TEST(ClientKeys, AParticipantsProofsAreCheckedAtMostItsBudget) {
  ClientKeys::Limits limits;
  limits.proofsPerSecond = 2;
  limits.proofBurst = 4;
  Keys k(limits);
  k.join(1, 1);
  int checks = 0;
  const ClientKeys::Proof wrong = [&](const Guid&) {
    ++checks;
    return false;
  };
  // A participant sending Hellos with bad proofs as fast as it can: 4 at once, then 2 a
  // second; the others are not looked at (their Hellos stay unproven).
  for (int i = 0; i < 1000; ++i) EXPECT_FALSE(k.keys.claim(0xC0, 1, k.now, &wrong).proven);
  EXPECT_EQ(checks, 4);
  k.now += 1s;
  for (int i = 0; i < 1000; ++i) k.keys.claim(0xC0, 1, k.now, &wrong);
  EXPECT_EQ(checks, 6);
}

TEST(ClientKeys, GuidsPrintAsCycloneDoes) {
  Guid g{};
  for (int i = 0; i < 16; ++i) g[i] = uint8_t(i + 1);
  EXPECT_EQ(toString(g), "1020304:5060708:90a0b0c:d0e0f10");
}

TEST(InstanceGate, AWriterMakesAtMostItsInstancesAndKeepsUsingThem) {
  InstanceGate gate({32, 0, 1});
  for (uint64_t i = 1; i <= 32; ++i) EXPECT_TRUE(gate.admit(7, 1000 + i));
  for (uint64_t i = 33; i <= 70000; ++i) ASSERT_FALSE(gate.admit(7, 1000 + i));
  EXPECT_EQ(gate.refused(), 70000u - 32u);
  EXPECT_TRUE(gate.admit(7, 1001)) << "its own instances";
  EXPECT_TRUE(gate.admit(8, 1001)) << "another writer, even on the same instance";
  // Reported once per reportEvery; a writer that left is forgotten.
  const auto t0 = InstanceGate::Clock::time_point{} + std::chrono::hours(1);
  const uint64_t live[] = {7, 8};
  std::vector<InstanceGate::Refused> r = gate.sweep(live, t0);
  ASSERT_EQ(r.size(), 1u);
  EXPECT_EQ(r[0].writer, 7u);
  EXPECT_EQ(r[0].instances, 70000u - 32u);
  EXPECT_EQ(r[0].rate, 0u);
  EXPECT_FALSE(gate.admit(7, 1));
  EXPECT_TRUE(gate.sweep(live, t0 + std::chrono::seconds(1)).empty());
  EXPECT_EQ(gate.sweep(live, t0 + std::chrono::seconds(10)).size(), 1u);
  EXPECT_EQ(gate.writers(), 2u);
  const uint64_t only8[] = {8};
  gate.sweep(only8, t0 + std::chrono::seconds(20));
  EXPECT_EQ(gate.writers(), 1u);
  EXPECT_TRUE(gate.admit(7, 5)) << "a new writer with the same handle starts afresh";
}

TEST(InstanceGate, AWriterPastItsRateIsFilteredAndOthersAreNot) {
  InstanceGate gate({32, 4000, 1000});
  auto t = InstanceGate::Clock::time_point{} + std::chrono::hours(1);
  int admitted = 0;
  for (int i = 0; i < 100000; ++i) admitted += gate.admit(7, 1, t);  // all at once
  EXPECT_EQ(admitted, 1000) << "the burst";
  EXPECT_TRUE(gate.admit(8, 1, t)) << "another writer";
  t += std::chrono::milliseconds(250);
  admitted = 0;
  for (int i = 0; i < 100000; ++i) admitted += gate.admit(7, 1, t);
  EXPECT_EQ(admitted, 1000) << "what a quarter second refilled";
  const uint64_t live[] = {7, 8};
  std::vector<InstanceGate::Refused> r = gate.sweep(live, t);
  ASSERT_EQ(r.size(), 1u);
  EXPECT_EQ(r[0].rate, 200000u - 2000u);
}

TEST(InstanceGate, AWriterThatWaitsForItsRepliesIsNeverFiltered) {
  // A synchronous client on loopback sends a command every 0.07 ms, past twice the
  // participant's rate: each sample after a reply to one of its keys passes free.
  InstanceGate gate({32, 10, 5});
  auto t = InstanceGate::Clock::time_point{} + std::chrono::hours(1);
  ASSERT_TRUE(gate.admit(7, 1, t));
  gate.bind(7, 0xA);
  for (int i = 0; i < 10000; ++i) {
    gate.answered(0xA);
    ASSERT_TRUE(gate.admit(7, 1, t)) << "sample " << i;
  }
  // One free sample per reply, no more: a writer that sends ahead has its burst.
  gate.answered(0xA);
  int admitted = 0;
  for (int i = 0; i < 100; ++i) admitted += gate.admit(7, 1, t);
  EXPECT_EQ(admitted, 1 + 4) << "the free one and what is left of the burst";
  // Replies to a key of no writer (or another's) free nothing here.
  gate.answered(0xB);
  EXPECT_FALSE(gate.admit(7, 1, t));
  // A writer gone forgets its keys.
  const uint64_t none[] = {8};
  gate.sweep(none, t);
  gate.answered(0xA);
  EXPECT_EQ(gate.writers(), 0u);
}

}  // namespace
}  // namespace phys::server::test
