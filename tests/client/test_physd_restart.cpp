// The SDK against the physd binary: the daemon killed (SIGKILL) and started again under a
// running client; the client greets the new daemon by itself and keeps working.
#include <gtest/gtest.h>

#include <chrono>
#include <thread>

#include "physd_process.h"

namespace phys::client {
namespace {

using namespace std::chrono_literals;

TEST(ClientPhysdProcess, ReconnectsAfterTheDaemonIsKilledAndRestarted) {
  testing::ScratchDir dir("physclient_proc");
  testing::PhysdConfig cfg(dir.path, "physd-restart", 230 + uint32_t(getpid() % 2),
                           "[[worlds]]\nname = \"proc\"\nscene = \"box_stack\"\nrun = true\n"
                           "rate_hz = 60\n");
  auto spawn = [&] { return testing::spawnProcess(PHYSD_BINARY, {"--config", cfg.toml}); };

  Client c(cfg.clientOptions(20s));
  pid_t pid = spawn();
  testing::ProcessGuard guard{pid};
  ASSERT_GT(pid, 0);
  EXPECT_EQ(c.connect().name, "physd-restart");
  EXPECT_EQ(c.worldNamed("proc").id(), 1u);
  WorldHandle w = c.createWorld({"mine", "", std::nullopt, 0}).get();
  EXPECT_EQ(w.step(3).get().tick, 3u);

  ASSERT_EQ(kill(pid, SIGKILL), 0);
  int st = 0;
  ASSERT_EQ(waitpid(pid, &st, 0), pid);
  pid = 0;
  // Nobody answers now: the request fails cleanly.
  try {
    w.step(1, {500ms}).get();
    ADD_FAILURE() << "a killed daemon answered";
  } catch (const Error& e) {
    EXPECT_TRUE(e.code() == ErrorCode::Timeout || e.code() == ErrorCode::Disconnected) << e.what();
  }

  pid = spawn();
  ASSERT_GT(pid, 0);
  EXPECT_TRUE(testing::awaitReconnects(c, 1));
  EXPECT_TRUE(c.connected());
  // The new daemon has only its start-up world; the client works with it.
  auto worlds = c.listWorlds().get();
  ASSERT_EQ(worlds.size(), 1u);
  EXPECT_EQ(worlds[0].name, "proc");
  WorldHandle w2 = c.createWorld({"again", "", std::nullopt, 0}).get();
  EXPECT_EQ(w2.step(2).get().tick, 2u);

  ASSERT_EQ(kill(pid, SIGTERM), 0);
  ASSERT_EQ(waitpid(pid, &st, 0), pid);
  pid = 0;
  EXPECT_TRUE(WIFEXITED(st) && WEXITSTATUS(st) == 0);
}

}  // namespace
}  // namespace phys::client
