// The SDK against the physd binary: the daemon killed (SIGKILL) and started again under a
// running client; the client greets the new daemon by itself and keeps working.
#include <gtest/gtest.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <thread>

#include "phys/client/client.h"

extern char** environ;

namespace phys::client {
namespace {

using namespace std::chrono_literals;

TEST(ClientPhysdProcess, ReconnectsAfterTheDaemonIsKilledAndRestarted) {
  const std::string src = PHYS_SOURCE_DIR;
  const uint32_t domain = 230 + uint32_t(getpid() % 2);
  const auto dir =
      std::filesystem::temp_directory_path() / ("physclient_proc_" + std::to_string(getpid()));
  std::filesystem::create_directories(dir);
  // loopback.xml with a discovery tag of this process (isolation from parallel tests).
  std::string xml;
  {
    std::ifstream in(src + "/configs/cyclonedds/loopback.xml");
    std::stringstream ss;
    ss << in.rdbuf();
    xml = ss.str();
    const std::string tag =
        "<Discovery><Tag>physclient-test-" + std::to_string(getpid()) + "</Tag>";
    xml.replace(xml.find("<Discovery>"), std::string("<Discovery>").size(), tag);
    std::ofstream out(dir / "cyclone.xml");
    out << xml;
  }
  const std::string config = (dir / "physd.toml").string();
  {
    std::ofstream f(config);
    f << "[server]\nname = \"physd-restart\"\nlog_level = \"warn\"\nstatus_period_s = 0.2\n"
      << "[dds]\ndomain = " << domain << "\nconfig = \"" << (dir / "cyclone.xml").string()
      << "\"\n[paths]\npresets = \"" << src << "/configs/presets.json\"\nscenes = \"" << src
      << "/configs/scenes\"\n"
      << "[[worlds]]\nname = \"proc\"\nscene = \"box_stack\"\nrun = true\nrate_hz = 60\n";
  }
  std::string bin = PHYSD_BINARY;
  std::string arg1 = "--config";
  char* argv[] = {bin.data(), arg1.data(), const_cast<char*>(config.c_str()), nullptr};
  auto spawn = [&] {
    pid_t pid = 0;
    EXPECT_EQ(posix_spawn(&pid, bin.c_str(), nullptr, nullptr, argv, environ), 0);
    return pid;
  };

  ClientOptions o;
  o.domain = domain;
  o.cycloneXml = xml;
  o.connectTimeout = 20s;
  o.requestTimeout = 20s;
  Client c(o);
  pid_t pid = spawn();
  ASSERT_GT(pid, 0);
  EXPECT_EQ(c.connect().name, "physd-restart");
  EXPECT_EQ(c.worldNamed("proc").id(), 1u);
  WorldHandle w = c.createWorld({"mine", "", std::nullopt, 0}).get();
  EXPECT_EQ(w.step(3).get().tick, 3u);

  ASSERT_EQ(kill(pid, SIGKILL), 0);
  int st = 0;
  ASSERT_EQ(waitpid(pid, &st, 0), pid);
  // Nobody answers now: the request fails cleanly.
  try {
    w.step(1, {500ms}).get();
    ADD_FAILURE() << "a killed daemon answered";
  } catch (const Error& e) {
    EXPECT_TRUE(e.code() == ErrorCode::Timeout || e.code() == ErrorCode::Disconnected) << e.what();
  }

  pid = spawn();
  ASSERT_GT(pid, 0);
  const auto end = std::chrono::steady_clock::now() + 20s;
  while (c.reconnects() < 1 && std::chrono::steady_clock::now() < end)
    std::this_thread::sleep_for(10ms);
  EXPECT_GE(c.reconnects(), 1u);
  EXPECT_TRUE(c.connected());
  // The new daemon has only its start-up world; the client works with it.
  auto worlds = c.listWorlds().get();
  ASSERT_EQ(worlds.size(), 1u);
  EXPECT_EQ(worlds[0].name, "proc");
  WorldHandle w2 = c.createWorld({"again", "", std::nullopt, 0}).get();
  EXPECT_EQ(w2.step(2).get().tick, 2u);

  ASSERT_EQ(kill(pid, SIGTERM), 0);
  ASSERT_EQ(waitpid(pid, &st, 0), pid);
  EXPECT_TRUE(WIFEXITED(st) && WEXITSTATUS(st) == 0);
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace phys::client
