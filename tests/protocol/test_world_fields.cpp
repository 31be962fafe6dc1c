// The world settings' list (PHYS_WORLD_FIELDS, phys/defs/world_def.h) against the wire's
// WorldSettings table, a pinned format written by hand in physics.fbs: the same names in the
// same order, each field through the builder, the decoder and the converter on its own, and
// the bytes as they were when the builder was written by hand.
#include <string>
#include <vector>

#include "protocol_test_util.h"

namespace phys::protocol::test {
namespace {

/// Every settable field other than the defaults, and valid.
phys::WorldDef changedWorld() {
  phys::WorldDef d;
  d.gravity = {1, -2, -9};
  d.timeStep = 0.01f;
  d.sleep.enabled = true;  // the default: off
  d.sleep.time = 0.7f;
  d.sleep.linearSpeed = 0.04f;
  d.sleep.angularSpeed = 0.3f;
  d.maxLinearSpeed = 500;
  d.maxAngularSpeed = 200;
  d.speculativeDistance = 0.03f;
  d.aabbMargin = 0.07f;
  d.guard = false;  // the default: on
  d.guardEnergyJump = 0.8f;
  d.guardRetries = 3;
  return d;
}

TEST(WorldFields, ListIsTheWireTable) {
  std::vector<std::string> names;
#define PHYS_NAME(type, member, path, name) names.push_back(#name);
  PHYS_WORLD_FIELDS(PHYS_NAME)
#undef PHYS_NAME
  EXPECT_EQ(names.size(), 13u);
  EXPECT_EQ(names, schemaFields("WorldSettings"));
}

TEST(WorldFields, EachFieldAloneCrossesTheWire) {
  const phys::WorldDef changed = changedWorld(), defaults;
  int count = 0;
#define PHYS_COUNT(...) ++count;
  PHYS_WORLD_FIELDS(PHYS_COUNT)
#undef PHYS_COUNT
  for (int i = 0; i < count; ++i) {
    // Field i alone, from the changed definition; the others unset.
    WorldOverrides o = WorldOverrides::from(changed);
    int n = 0;
#define PHYS_ONE(type, member, ...) \
  if (n++ != i) o.member.reset();
    PHYS_WORLD_FIELDS(PHYS_ONE)
#undef PHYS_ONE
    auto cmd = mustDecode(CommandBuilder().setWorld(o).finish(header()));
    ASSERT_TRUE(cmd.ok()) << "field " << i;
    phys::WorldDef got;
    applyOverrides(toOverrides(*cmd->request_as_SetWorld()->settings()), &got);
    // That field is the changed one, every other the default.
    n = 0;
#define PHYS_CHECK(type, member, path, name)                                            \
  if (n++ == i)                                                                         \
    EXPECT_TRUE(got.path == changed.path) << #name << " did not cross the wire";        \
  else                                                                                  \
    EXPECT_TRUE(got.path == defaults.path) << #name << " changed with field " << i;
    PHYS_WORLD_FIELDS(PHYS_CHECK)
#undef PHYS_CHECK
  }
}

// Pinned when the list came to drive the builder (issue 44): the same hashes as the
// hand-written builder of 731c2b9 gave for these two commands.
TEST(WorldFields, BytesAreAsBefore) {
  const WorldOverrides all = WorldOverrides::from(changedWorld());
  EXPECT_FALSE(all.empty());
  EXPECT_TRUE(WorldOverrides().empty());
  EXPECT_EQ(fnv1a(CommandBuilder().setWorld(all).finish({7, 1, 2})), 0xe5d084df78ae62fcull);
  WorldOverrides some;
  some.gravity = phys::Vec3{0, 0, -1};
  some.guardRetries = 1;
  some.sleepTime = 2;
  EXPECT_EQ(fnv1a(CommandBuilder().setWorld(some).finish({7, 1, 2})), 0x3c06b39ddc131e8cull);
}

}  // namespace
}  // namespace phys::protocol::test
