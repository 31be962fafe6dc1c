// phys/protocol/cluster.h: world id ranges of a domain of daemons, and reading a command's
// address (world, daemon, Hello) without verifying its request.
#include <gtest/gtest.h>

#include "phys/protocol/builder.h"
#include "phys/protocol/cluster.h"
#include "phys/protocol/decoder.h"

namespace phys::protocol::test {
namespace {

TEST(ClusterIds, EachDaemonNumbersItsOwnRange) {
  EXPECT_EQ(firstWorldIdOf(1), (1u << 20) | 1u);
  EXPECT_EQ(daemonOfWorld(firstWorldIdOf(7)), 7u);
  EXPECT_EQ(daemonOfWorld(uint32_t(worldIdsEndOf(7) - 1)), 7u);
  EXPECT_EQ(daemonOfWorld(uint32_t(worldIdsEndOf(7))), 8u);
  EXPECT_EQ(daemonOfWorld(firstWorldIdOf(kMaxClusterDaemonId)), kMaxClusterDaemonId);
  EXPECT_EQ(worldIdsEndOf(kMaxClusterDaemonId), uint64_t(1) << 32);  // the last id fits
  EXPECT_EQ(daemonOfWorld(5), 0u);  // a lone daemon's ids are nobody's range
}

TEST(ClusterIds, PeekAddressReadsWorldDaemonAndHello) {
  CommandBuilder b;
  Bytes step = b.step(3).finish({0xC1, 9, firstWorldIdOf(2) + 4, 0});
  auto a = peekAddress(step);
  ASSERT_TRUE(a);
  EXPECT_EQ(a->world, firstWorldIdOf(2) + 4);
  EXPECT_EQ(a->daemon, 0u);
  EXPECT_FALSE(a->hello);

  CreateWorldArgs args;
  args.name = "x";
  Bytes create = b.createWorld(args).finish({0xC1, 10, 0, 3});
  a = peekAddress(create);
  ASSERT_TRUE(a);
  EXPECT_EQ(a->world, 0u);
  EXPECT_EQ(a->daemon, 3u);
  EXPECT_FALSE(a->hello);

  Bytes hello = b.hello("me").finish({0xC1, 11, 0});
  a = peekAddress(hello);
  ASSERT_TRUE(a);
  EXPECT_TRUE(a->hello);
  EXPECT_EQ(a->daemon, 0u);
  // The full decoder agrees.
  auto d = decodeCommand(create);
  ASSERT_TRUE(d.ok()) << d.status.message;
  EXPECT_EQ(d->daemon(), 3u);
}

TEST(ClusterIds, AnAddressableCommandIsSentOnByItsDaemonAlone) {
  CommandBuilder b;
  CommandHeader h{0xC1, 9, firstWorldIdOf(1) + 2, 0};
  h.addressable = true;
  Bytes step = b.step(3).finish(h);
  Bytes plain = b.step(3).finish({0xC1, 9, firstWorldIdOf(1) + 2, 0});
  EXPECT_EQ(step.size(), plain.size() + 8);  // the daemon field, written as 0
  ASSERT_TRUE(setCommandDaemon(step, 3));
  auto a = peekAddress(step);
  ASSERT_TRUE(a);
  EXPECT_EQ(a->daemon, 3u);
  auto d = decodeCommand(step);
  ASSERT_TRUE(d.ok()) << d.status.message;
  EXPECT_EQ(d->daemon(), 3u);
  EXPECT_EQ(d->world(), firstWorldIdOf(1) + 2);
  ASSERT_TRUE(d->request_as_Step());
  EXPECT_EQ(d->request_as_Step()->count(), 3u);
  // Without the field there is nothing to set in place.
  EXPECT_FALSE(setCommandDaemon(plain, 3));
  EXPECT_TRUE(setCommandDaemon(plain, 0));  // (0 is what it says already)
  EXPECT_EQ(peekAddress(plain)->daemon, 0u);
}

TEST(ClusterIds, PeekAddressRefusesWhatDoesNotVerify) {
  EXPECT_FALSE(peekAddress({}));
  const std::vector<uint8_t> junk(64, 0xFF);
  EXPECT_FALSE(peekAddress(junk));
  CommandBuilder b;
  Bytes step = b.step(3).finish({0xC1, 9, 77, 0});
  // Cut short: the root table's fields lie past the end.
  for (size_t n : {size_t(4), size_t(8), step.size() / 2}) {
    std::vector<uint8_t> cut(step.begin(), step.begin() + long(n));
    auto a = peekAddress(cut);
    if (a) {
      EXPECT_TRUE(a->world == 77 || a->world == 0);  // never read out of bounds
    }
  }
  // Every single-byte change either verifies (and is then read in bounds) or is refused;
  // run under the sanitizers this is the check that nothing is read out of bounds.
  for (size_t i = 0; i < step.size(); ++i) {
    std::vector<uint8_t> m = step;
    m[i] ^= 0xA5;
    (void)peekAddress(m);
  }
}

}  // namespace
}  // namespace phys::protocol::test
