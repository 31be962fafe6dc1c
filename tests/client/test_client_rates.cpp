// Rate limits that refuse floods, not users (issue 40, finding 5): the SDK against physd's
// components in-process on loopback DDS (domain 230 or 231 and a discovery tag of this
// process, as test_client.cpp). A synchronous client, one request in flight, is never
// refused at the daemon's defaults however fast its round trip; a client that sends ahead of
// its replies past a low limit is refused at the door, and the SDK sends those requests again
// (ClientOptions::retryBusy) or, told not to, reports them with Error::retryAfterMs().
#include <gtest/gtest.h>
#include <unistd.h>

#include <chrono>
#include <fstream>
#include <future>
#include <sstream>
#include <string>
#include <vector>

#include "../common/bodies.h"
#include "../common/sanitizer.h"
#include "phys/client/client.h"
#include "phys/server/core.h"
#include "phys/server/endpoint.h"
#include "in_process_daemon.h"

namespace phys::client {
namespace {

using namespace std::chrono_literals;
constexpr auto kTimeout = std::chrono::milliseconds(int64_t(20000 * test::kTimeFactor));

ClientOptions options(bool retryBusy) {
  ClientOptions o = testing::inProcessOptions("rates-test");
  o.retryBusy = retryBusy;
  return o;
}

/// The daemon's components, as physd's main() wires them, with `config`'s budgets (the
/// defaults unless a test lowers them).
struct Daemon : testing::InProcessDaemon {
  explicit Daemon(server::CoreConfig config = {})
      : InProcessDaemon(testing::withSourceTree(std::move(config))) {}
};

TEST(ClientRates, ASynchronousLoopIsNeverRefusedAtTheDefaults) {
  // The script: step(1); query_state(); info() in a loop, one request at a time,
  // at 0.07-0.5 ms a round trip on loopback: 2,000 to 14,000 commands a second, past the
  // default 2,000 a second a client and a participant may send. Without the SDK's retry, so
  // that a refusal shows.
  Daemon d;
  const server::CoreConfig defaults;
  ASSERT_EQ(d.core.config().maxClientCommandsPerS, defaults.maxClientCommandsPerS);
  ASSERT_EQ(d.core.config().maxParticipantCommandsPerS, defaults.maxParticipantCommandsPerS);
  Client c(options(/*retryBusy=*/false));
  c.connect();
  WorldHandle w = c.createWorld({"loop", "", std::nullopt, 0}).get();
  std::vector<phys::BodyDef> bodies{phys::test::groundBody()};
  for (int i = 0; i < 10; ++i) bodies.push_back(phys::test::boxBody({float(i) * 2, 0, 1}));
  w.spawn(bodies).get();
  const auto t0 = std::chrono::steady_clock::now();
  const auto end = t0 + 3s;
  uint64_t commands = 0;
  while (std::chrono::steady_clock::now() < end) {
    try {
      w.step(1).get();
      w.queryState().get();
      c.listWorlds().get();
    } catch (const Error& e) {
      FAIL() << "refused after " << commands << " commands: " << e.what();
    }
    commands += 3;
  }
  const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  std::printf("  %llu commands in %.1f s, %.0f a second, none refused\n",
              (unsigned long long)commands, s, double(commands) / s);
}

TEST(ClientRates, TheSdkSendsRequestsRefusedAtTheDoorAgain) {
  // An artificially low limit: 50 commands a second a client, bursts of 5. Sixty requests
  // sent at once (futures, not waiting for replies): the first (nothing waiting) and the
  // burst pass, the rest are refused "slow down" with Reply.retry_after_ms.
  server::CoreConfig low;
  low.maxClientCommandsPerS = 50;
  low.maxClientBurst = 5;
  Daemon d(low);
  constexpr int kRequests = 60;
  {
    // Retried (the default): every one succeeds, in the order they were made.
    Client c(options(/*retryBusy=*/true));
    c.connect();
    WorldHandle w = c.createWorld({"retried", "", std::nullopt, 0}).get();
    std::this_thread::sleep_for(200ms);  // the burst refilled
    std::vector<std::future<Ack>> steps;
    for (int i = 0; i < kRequests; ++i) steps.push_back(w.step(1));
    uint64_t last = 0;
    int inOrder = 0;
    for (auto& f : steps) {
      Ack a;
      ASSERT_NO_THROW(a = f.get());
      inOrder += a.tick > last;
      last = std::max(last, a.tick);
    }
    EXPECT_EQ(last, uint64_t(kRequests)) << "every step taken once";
    std::printf("  %d of %d steps answered in order\n", inOrder, kRequests);
  }
  {
    // Not retried: the refusals are the requests' errors, saying when to try again.
    Client c(options(/*retryBusy=*/false));
    c.connect();
    WorldHandle w = c.createWorld({"refused", "", std::nullopt, 0}).get();
    std::this_thread::sleep_for(200ms);
    std::vector<std::future<Ack>> steps;
    for (int i = 0; i < kRequests; ++i) steps.push_back(w.step(1));
    int ok = 0, refused = 0;
    for (auto& f : steps) {
      try {
        f.get();
        ++ok;
      } catch (const Error& e) {
        EXPECT_EQ(e.code(), ErrorCode::ResourceExhausted) << e.what();
        EXPECT_NE(e.message().find("slow down"), std::string::npos) << e.what();
        EXPECT_GT(e.retryAfterMs(), 0u) << e.what();
        ++refused;
      }
    }
    EXPECT_GE(refused, kRequests / 2) << ok << " passed";
    EXPECT_EQ(ok + refused, kRequests);
  }
}

TEST(ClientRates, OtherErrorsAreNotRetried) {
  // ResourceExhausted for what a command asks (too many bodies) is no refusal at the door:
  // sent again it would fail again. It is the request's error at once.
  server::CoreConfig small;
  small.maxBodiesPerWorld = 5;
  Daemon d(small);
  Client c(options(/*retryBusy=*/true));
  c.connect();
  WorldHandle w = c.createWorld({"small", "", std::nullopt, 0}).get();
  std::vector<phys::BodyDef> bodies(10, phys::test::boxBody({0, 0, 1}));
  const auto t0 = std::chrono::steady_clock::now();
  try {
    w.spawn(bodies).get();
    FAIL() << "10 bodies in a world of at most 5";
  } catch (const Error& e) {
    EXPECT_EQ(e.code(), ErrorCode::ResourceExhausted) << e.what();
    EXPECT_EQ(e.retryAfterMs(), 0u);
  }
  EXPECT_LT(std::chrono::steady_clock::now() - t0, kTimeout / 2) << "answered, not retried";
}

}  // namespace
}  // namespace phys::client
