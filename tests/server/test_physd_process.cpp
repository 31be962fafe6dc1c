// The physd binary itself: starts from a config, answers over loopback DDS, and exits 0 on
// SIGTERM; on a full data disk it starts read-only.
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

/// A client of a physd process over loopback DDS, made of the protocol's builders.
struct ProcessClient {
  dds::Participant p;
  dds::Topic cmdTopic, replyTopic;
  dds::Writer cmd;
  dds::Reader replies;
  uint64_t id = 0xB0B0000ull + uint64_t(getpid());
  uint64_t seq = 0;
  bool create(uint32_t domain, std::string* err) {
    return p.create(domain, "", err) && cmdTopic.create(p, "phys/cmd", err) &&
           replyTopic.create(p, "phys/reply", err) &&
           cmd.create(p, cmdTopic, protocol::kCommandQos, protocol::PayloadKind::Command, err) &&
           replies.create(p, replyTopic, protocol::kReplyQos, err);
  }
  /// The reply to a command, resent until matched and answered (the daemon may still be
  /// starting); none after 20 s.
  std::optional<Reply> call(protocol::CommandBuilder& b, uint32_t world = 0) {
    const uint64_t s = ++seq;
    protocol::Bytes bytes = b.finish({id, s, world});
    auto end = Clock::now() + std::chrono::seconds(20);
    std::optional<Reply> got;
    auto lastSend = Clock::now() - std::chrono::seconds(10);
    while (!got && Clock::now() < end) {
      if (cmd.matched() > 0 && replies.matched() > 0 &&
          Clock::now() - lastSend > std::chrono::seconds(2)) {
        cmd.write(id, bytes, s);
        lastSend = Clock::now();
      }
      replies.take([&](const phys_wire_Envelope& env) {
        if (env.key != id) return;
        auto b2 = protocol::envelopeBytes(env);
        Reply r = protocol::decodeReply(std::vector<uint8_t>(b2.begin(), b2.end()));
        if (r.ok() && r->seq() == s) got = r;
      });
      std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
    return got;
  }
};

/// SIGTERM, then the exit status (-1: it did not stop within 20 s and was killed).
int stopDaemon(pid_t pid) {
  if (kill(pid, SIGTERM) != 0) return -1;
  int status = 0;
  pid_t done = 0;
  auto end = Clock::now() + std::chrono::seconds(20);
  while ((done = waitpid(pid, &status, WNOHANG)) == 0 && Clock::now() < end)
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  if (done == 0) {
    kill(pid, SIGKILL);
    waitpid(pid, &status, 0);
    return -1;
  }
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

/// A config for a daemon on loopback DDS (domain from the process id), and its directory.
std::string writeConfig(const std::filesystem::path& dir, uint32_t domain, const std::string& extra) {
  const std::string src = PHYS_SOURCE_DIR;
  const std::string loopback = src + "/configs/cyclonedds/loopback.xml";
  setenv("CYCLONEDDS_URI", ("file://" + loopback).c_str(), 1);
  std::filesystem::create_directories(dir);
  const std::string config = (dir / "physd.toml").string();
  std::ofstream f(config);
  f << "[server]\nname = \"physd-test\"\nlog_level = \"warn\"\nstatus_period_s = 0.2\n"
    << "[dds]\ndomain = " << domain << "\nconfig = \"" << loopback << "\"\n"
    << "[paths]\npresets = \"" << src << "/configs/presets.json\"\nscenes = \"" << src
    << "/configs/scenes\"\nsnapshots = \"" << (dir / "snapshots").string() << "\"\n"
    << extra;
  return config;
}

TEST(PhysdProcess, ServesAndStopsCleanlyOnSigterm) {
  const uint32_t domain = 1 + uint32_t(getpid() % 200);
  const auto dir =
      std::filesystem::temp_directory_path() / ("physd_proc_" + std::to_string(getpid()));
  const std::string config = writeConfig(
      dir, domain, "[[worlds]]\nname = \"proc\"\nscene = \"box_stack\"\nrun = true\nrate_hz = 60\n");
  std::string bin = PHYSD_BINARY;
  std::string arg1 = "--config";
  char* argv[] = {bin.data(), arg1.data(), const_cast<char*>(config.c_str()), nullptr};
  pid_t pid = 0;
  ASSERT_EQ(posix_spawn(&pid, bin.c_str(), nullptr, nullptr, argv, environ), 0);

  // A client: Hello, then ListWorlds finds the start-up world ticking.
  std::string err;
  ProcessClient client;
  ASSERT_TRUE(client.create(domain, &err)) << err;
  auto hello = client.call(protocol::CommandBuilder().hello("proc-test"));
  ASSERT_TRUE(hello) << "physd did not answer Hello";
  EXPECT_EQ((*hello)->status(), Code::Ok);
  EXPECT_EQ((*hello)->result_as_HelloResult()->server_name()->str(), "physd-test");
  auto list = client.call(protocol::CommandBuilder().listWorlds());
  ASSERT_TRUE(list);
  auto* worlds = (*list)->result_as_WorldList()->worlds();
  ASSERT_EQ(worlds->size(), 1u);
  EXPECT_EQ(worlds->Get(0)->name()->str(), "proc");
  EXPECT_TRUE(worlds->Get(0)->running());
  EXPECT_GT(worlds->Get(0)->bodies(), 1u);

  const int code = stopDaemon(pid);
  EXPECT_EQ(code, 0) << "physd did not stop cleanly within 20 s of SIGTERM";
  std::error_code ec;
  std::filesystem::remove_all(dir, ec);
}

// Issue 39, finding 7: on a full data disk physd exited 2 (it could not write `starts`). It
// starts read-only instead: the kept worlds are served, commands that must be stored refused.
TEST(PhysdProcess, StartsReadOnlyOnAFullDataDisk) {
  const uint32_t domain = 1 + uint32_t((getpid() + 100) % 200);
  const auto dir =
      std::filesystem::temp_directory_path() / ("physd_proc_full_" + std::to_string(getpid()));
  std::filesystem::remove_all(dir);
  const std::string data = (dir / "data").string();
  uint32_t id = 0;
  {
    CoreConfig cc = testConfig();
    cc.dataDir = data;
    ServerCore core(cc);
    ASSERT_TRUE(core.init().ok());
    std::vector<std::string> notes;
    ASSERT_TRUE(core.restoreWorlds(&notes).ok());
    ASSERT_TRUE(core.createWorld("kept", "", "box_stack", &id).ok());
  }
  const std::string config = writeConfig(dir, domain, "data = \"" + data + "\"\n");
  // Not a byte may be written (RLIMIT_FSIZE 0; SIGXFSZ ignored, so writes fail with EFBIG,
  // as with ENOSPC on a full disk).
  std::string sh = "/bin/sh", c = "-c";
  std::string script = "trap '' XFSZ; ulimit -f 0; exec \"$0\" --config \"$1\"";
  std::string bin = PHYSD_BINARY;
  char* argv[] = {sh.data(), c.data(), script.data(), bin.data(), const_cast<char*>(config.c_str()),
                  nullptr};
  pid_t pid = 0;
  ASSERT_EQ(posix_spawn(&pid, sh.c_str(), nullptr, nullptr, argv, environ), 0);

  std::string err;
  ProcessClient client;
  ASSERT_TRUE(client.create(domain, &err)) << err;
  auto hello = client.call(protocol::CommandBuilder().hello("proc-test"));
  ASSERT_TRUE(hello) << "physd did not start on a full data disk";
  auto list = client.call(protocol::CommandBuilder().listWorlds());
  ASSERT_TRUE(list);
  auto* worlds = (*list)->result_as_WorldList()->worlds();
  ASSERT_EQ(worlds->size(), 1u);
  EXPECT_EQ(worlds->Get(0)->name()->str(), "kept");
  EXPECT_GT(worlds->Get(0)->bodies(), 1u);
  auto step = client.call(protocol::CommandBuilder().step(3), id);
  ASSERT_TRUE(step);
  EXPECT_EQ((*step)->status(), Code::ResourceExhausted);
  const std::string m = (*step)->message() ? (*step)->message()->str() : "";
  EXPECT_NE(m.find("read-only"), std::string::npos) << m;
  EXPECT_EQ(stopDaemon(pid), 0);
  std::error_code ec;
  std::filesystem::remove_all(dir, ec);
}

}  // namespace
}  // namespace phys::server::test
