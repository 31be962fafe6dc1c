// The physd binary itself: starts from a config, answers over loopback DDS, and exits 0 on
// SIGTERM.
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <thread>

#include "phys/protocol/dds_envelope.h"
#include "phys/server/dds.h"
#include "server_test_util.h"

extern char** environ;

namespace phys::server::test {
namespace {

using Clock = std::chrono::steady_clock;

TEST(PhysdProcess, ServesAndStopsCleanlyOnSigterm) {
  const std::string src = PHYS_SOURCE_DIR;
  const std::string loopback = src + "/configs/cyclonedds/loopback.xml";
  setenv("CYCLONEDDS_URI", ("file://" + loopback).c_str(), 1);
  const uint32_t domain = 1 + uint32_t(getpid() % 200);
  const auto dir =
      std::filesystem::temp_directory_path() / ("physd_proc_" + std::to_string(getpid()));
  std::filesystem::create_directories(dir);
  const std::string config = (dir / "physd.toml").string();
  {
    std::ofstream f(config);
    f << "[server]\nname = \"physd-test\"\nlog_level = \"warn\"\nstatus_period_s = 0.2\n"
      << "[dds]\ndomain = " << domain << "\nconfig = \"" << loopback << "\"\n"
      << "[paths]\npresets = \"" << src << "/configs/presets.json\"\nscenes = \"" << src
      << "/configs/scenes\"\nsnapshots = \"" << (dir / "snapshots").string() << "\"\n"
      << "[[worlds]]\nname = \"proc\"\nscene = \"box_stack\"\nrun = true\nrate_hz = 60\n";
  }
  std::string bin = PHYSD_BINARY;
  std::string arg1 = "--config";
  char* argv[] = {bin.data(), arg1.data(), const_cast<char*>(config.c_str()), nullptr};
  pid_t pid = 0;
  ASSERT_EQ(posix_spawn(&pid, bin.c_str(), nullptr, nullptr, argv, environ), 0);

  // A client: Hello, then ListWorlds finds the start-up world ticking.
  std::string err;
  dds::Participant p;
  dds::Topic cmdTopic, replyTopic;
  dds::Writer cmd;
  dds::Reader replies;
  ASSERT_TRUE(p.create(domain, "", &err)) << err;
  ASSERT_TRUE(cmdTopic.create(p, "phys/cmd", &err)) << err;
  ASSERT_TRUE(replyTopic.create(p, "phys/reply", &err)) << err;
  ASSERT_TRUE(cmd.create(p, cmdTopic, protocol::kCommandQos, protocol::PayloadKind::Command, &err));
  ASSERT_TRUE(replies.create(p, replyTopic, protocol::kReplyQos, &err));
  const uint64_t id = 0xB0B0000ull + uint64_t(getpid());
  auto call = [&](protocol::CommandBuilder& b, uint64_t seq) -> std::optional<Reply> {
    protocol::Bytes bytes = b.finish({id, seq, 0});
    auto end = Clock::now() + std::chrono::seconds(20);
    std::optional<Reply> got;
    auto lastSend = Clock::now() - std::chrono::seconds(10);
    while (!got && Clock::now() < end) {
      // Resend until matched and answered (the daemon may still be starting).
      if (cmd.matched() > 0 && replies.matched() > 0 &&
          Clock::now() - lastSend > std::chrono::seconds(2)) {
        cmd.write(id, bytes, seq);
        lastSend = Clock::now();
      }
      replies.take([&](const phys_wire_Envelope& env) {
        if (env.key != id) return;
        auto b2 = protocol::envelopeBytes(env);
        Reply r = protocol::decodeReply(std::vector<uint8_t>(b2.begin(), b2.end()));
        if (r.ok() && r->seq() == seq) got = r;
      });
      std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
    return got;
  };
  auto hello = call(protocol::CommandBuilder().hello("proc-test"), 1);
  ASSERT_TRUE(hello) << "physd did not answer Hello";
  EXPECT_EQ((*hello)->status(), Code::Ok);
  EXPECT_EQ((*hello)->result_as_HelloResult()->server_name()->str(), "physd-test");
  auto list = call(protocol::CommandBuilder().listWorlds(), 2);
  ASSERT_TRUE(list);
  auto* worlds = (*list)->result_as_WorldList()->worlds();
  ASSERT_EQ(worlds->size(), 1u);
  EXPECT_EQ(worlds->Get(0)->name()->str(), "proc");
  EXPECT_TRUE(worlds->Get(0)->running());
  EXPECT_GT(worlds->Get(0)->bodies(), 1u);

  ASSERT_EQ(kill(pid, SIGTERM), 0);
  int status = 0;
  pid_t done = 0;
  auto end = Clock::now() + std::chrono::seconds(20);
  while ((done = waitpid(pid, &status, WNOHANG)) == 0 && Clock::now() < end)
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  if (done == 0) {
    kill(pid, SIGKILL);
    waitpid(pid, &status, 0);
    FAIL() << "physd did not stop within 20 s of SIGTERM";
  }
  EXPECT_TRUE(WIFEXITED(status));
  EXPECT_EQ(WEXITSTATUS(status), 0);
  std::error_code ec;
  std::filesystem::remove_all(dir, ec);
}

}  // namespace
}  // namespace phys::server::test
