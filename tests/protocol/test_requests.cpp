// The request table (requests.h, issue 44): one row per member of physics.fbs's union in
// order, each named as the schema names it, with the properties the codec and the server
// read from it (the lists they kept in switches before).
#include <cctype>
#include <set>
#include <string>

#include "phys/protocol/requests.h"
#include "protocol_test_util.h"

namespace phys::protocol::test {
namespace {

using R = wire::Request;

/// "SpawnBodies" -> "spawn_bodies".
std::string snake(const char* camel) {
  std::string s;
  for (const char* p = camel; *p; ++p) {
    if (std::isupper(static_cast<unsigned char>(*p))) {
      if (!s.empty()) s += '_';
      s += char(std::tolower(static_cast<unsigned char>(*p)));
    } else {
      s += *p;
    }
  }
  return s;
}

std::set<R> withFlag(RequestFlag f) {
  std::set<R> out;
  for (unsigned i = 1; i <= unsigned(R::MAX); ++i)
    if (requestInfo(R(i)).has(f)) out.insert(R(i));
  return out;
}

TEST(RequestTable, OneRowPerRequestNamedAsTheSchema) {
  for (unsigned i = 1; i <= unsigned(R::MAX); ++i) {
    const RequestInfo& r = requestInfo(R(i));
    EXPECT_EQ(r.type, R(i));
    EXPECT_EQ(r.name, snake(wire::EnumNameRequest(R(i)))) << i;
    EXPECT_STREQ(requestName(R(i)), r.name);
  }
  EXPECT_STREQ(requestName(R::NONE), "unknown");
  EXPECT_STREQ(requestName(R(unsigned(R::MAX) + 1)), "unknown");
  // An unknown kind's world is looked up before it is refused; NONE has none.
  EXPECT_TRUE(needsWorld(R(unsigned(R::MAX) + 1)));
  EXPECT_FALSE(needsWorld(R::NONE));
  EXPECT_FALSE(isBatchable(R(unsigned(R::MAX) + 1)));
}

TEST(RequestTable, Properties) {
  // What the switches and if-chains said before the table.
  std::set<R> noWorld;
  for (unsigned i = 1; i <= unsigned(R::MAX); ++i)
    if (!needsWorld(R(i))) noWorld.insert(R(i));
  EXPECT_EQ(noWorld, (std::set<R>{R::Hello, R::CreateWorld, R::ListWorlds}));
  const std::set<R> edits = {R::SpawnBodies, R::RemoveBodies,    R::AddJoints,  R::RemoveJoints,
                             R::SetBodyPose, R::SetBodyVelocity, R::ApplyForce, R::ApplyImpulse,
                             R::ApplyTorque, R::SetMaterial,     R::SetSolver,  R::SetWorld};
  EXPECT_EQ(withFlag(kBatchable), edits);
  std::set<R> journaled = edits;
  journaled.insert({R::Batch, R::Run, R::Pause, R::SetAccess});
  EXPECT_EQ(withFlag(kJournaled), journaled);
  std::set<R> stored = journaled;
  stored.insert({R::Step, R::LoadScene, R::ResetWorld, R::RestoreSnapshot, R::MoveWorld});
  EXPECT_EQ(withFlag(kStored), stored);
  EXPECT_EQ(withFlag(kStartsJob), (std::set<R>{R::Step, R::LoadScene}));
  EXPECT_EQ(withFlag(kEndsJob), (std::set<R>{R::Pause, R::ResetWorld, R::DestroyWorld}));
  EXPECT_EQ(withFlag(kIdsReply),
            (std::set<R>{R::SpawnBodies, R::AddJoints, R::LoadScene, R::Batch}));

  std::set<R> read, own;
  for (unsigned i = 1; i <= unsigned(R::MAX); ++i) {
    if (!needsWorld(R(i))) continue;  // no world, no access check
    if (requestInfo(R(i)).access == Access::Read) read.insert(R(i));
    if (requestInfo(R(i)).access == Access::Own) own.insert(R(i));
  }
  EXPECT_EQ(read, (std::set<R>{R::QueryState, R::GetWorld, R::GetBodies, R::GetJoints, R::Subscribe,
                               R::Unsubscribe, R::SaveSnapshot}));
  EXPECT_EQ(own, (std::set<R>{R::DestroyWorld, R::SetAccess, R::MoveWorld}));
}

}  // namespace
}  // namespace phys::protocol::test
