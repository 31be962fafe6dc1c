// physctl as a user runs it (issue 40, finding 6): separate physctl processes against a fresh
// physd binary, one command each. The README's command-line workflow (create, load, step,
// run, pause, snapshot save and restore, list), read from README.md itself, must work in
// sequence: every physctl run is a new client, so this holds only when physctl keeps its
// identity between runs (its key file). Besides: who else may change the world (whoami,
// create --editors, access), several physctl processes with one key at once, list --json.
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <sys/wait.h>

#include <cstdio>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "in_process_daemon.h"
#include "physd_process.h"

namespace phys::client {
namespace {

using testing::Shell;
using testing::shell;
using testing::shq;

/// A physd binary of its own (no data directory: a fresh daemon) and physctl against it, run
/// in the scratch directory (relative files land there) with a key file there, never the
/// user's.
struct Cli {
  testing::ScratchDir dir;
  testing::PhysdConfig cfg;
  pid_t pid = 0;
  testing::ProcessGuard guard{pid};
  const std::string key;  ///< the default key of physctl() ($PHYSCTL_KEY)

  explicit Cli(const std::string& name)
      : dir(name),
        cfg(dir.path, name, 230 + uint32_t(getpid() % 2), ""),
        key((dir.path / "home" / "physd" / "client.key").string()) {
    pid = testing::spawnProcess(PHYSD_BINARY, {"--config", cfg.toml});
  }
  ~Cli() {
    if (pid > 0) {
      EXPECT_EQ(testing::stopProcess(pid, SIGTERM) & 0x7f, 0) << "physd did not exit on SIGTERM";
      pid = 0;
    }
  }
  /// physctl's command line up to its command: the daemon's domain and Cyclone config, its
  /// key given as users give it, through $PHYSCTL_KEY.
  std::string prefix(const std::string& keyFile = {}) const {
    const int timeoutMs = int(20000 * phys::test::kTimeFactor);
    return "cd " + shq(dir.path.string()) + " && PHYSCTL_KEY=" + shq(keyFile.empty() ? key : keyFile) +
           " " + shq(PHYSCTL_BINARY) + " --domain " + std::to_string(cfg.domain) + " --config " +
           shq(cfg.xml) + " --timeout " + std::to_string(timeoutMs);
  }
  Shell physctl(const std::string& args, const std::string& keyFile = {}) const {
    return shell(prefix(keyFile) + " " + args);
  }
};

/// The lines of the README's command-line workflow: the fenced block after the comment that
/// names this test, without comments.
std::vector<std::string> readmeWorkflow() {
  std::ifstream in(std::string(PHYS_SOURCE_DIR) + "/README.md");
  std::vector<std::string> lines;
  std::string line;
  bool marker = false, inBlock = false;
  while (std::getline(in, line)) {
    if (!marker) {
      marker = line.find("ClientPhysctl.TheReadmeWorkflowWorksOnAFreshDaemon") != std::string::npos;
      continue;
    }
    if (line.rfind("```", 0) == 0) {
      if (inBlock) break;
      inBlock = true;
      continue;
    }
    if (!inBlock) continue;
    if (const auto hash = line.find(" #"); hash != std::string::npos) line.resize(hash);
    while (!line.empty() && line.back() == ' ') line.pop_back();
    if (!line.empty()) lines.push_back(line);
  }
  return lines;
}

TEST(ClientPhysctl, TheReadmeWorkflowWorksOnAFreshDaemon) {
  const std::vector<std::string> steps = readmeWorkflow();
  ASSERT_GE(steps.size(), 8u) << "README.md's command-line workflow not found";
  Cli cli("physctl_readme");
  ASSERT_GT(cli.pid, 0);
  const std::string program = "build/tools/physctl";
  uint64_t pausedAt = 0;
  for (const std::string& step : steps) {
    ASSERT_EQ(step.rfind(program + " ", 0), 0u) << "not a physctl line: " << step;
    const std::string args = step.substr(program.size() + 1);
    const Shell r = cli.physctl(args);
    ASSERT_EQ(r.code, 0) << "physctl " << args << " (each physctl a new process):\n" << r.output;
    if (args.rfind("pause ", 0) == 0) {
      const auto at = r.output.find("paused at tick ");
      ASSERT_NE(at, std::string::npos) << r.output;
      pausedAt = std::stoull(r.output.substr(at + 15));
    }
  }
  EXPECT_GE(pausedAt, 120u);
  // Where the workflow left the world, read as a script would: the restored snapshot's tick.
  const Shell r = cli.physctl("list --json");
  ASSERT_EQ(r.code, 0) << r.output;
  const nlohmann::json worlds = nlohmann::json::parse(r.output, nullptr, false);
  ASSERT_TRUE(worlds.is_array()) << r.output;
  bool found = false;
  for (const auto& w : worlds) {
    if (w.at("name") != "demo") continue;
    found = true;
    EXPECT_EQ(w.at("bodies").get<uint32_t>(), 211u) << w.dump();
    EXPECT_EQ(w.at("tick").get<uint64_t>(), pausedAt) << w.dump();
    EXPECT_EQ(w.at("state"), "paused") << w.dump();
    for (const char* field : {"id", "preset", "awake_bodies", "joints", "contacts", "time_s",
                              "rate_hz", "overruns", "frames", "backend", "subscribers"})
      EXPECT_TRUE(w.contains(field)) << field << " missing from " << w.dump();
  }
  EXPECT_TRUE(found) << r.output;
  // The key file: made on first use, the owner's alone.
  struct stat st {};
  ASSERT_EQ(::stat(cli.key.c_str(), &st), 0) << cli.key;
  EXPECT_EQ(st.st_mode & 0777, 0600u);
}

TEST(ClientPhysctl, OtherClientsChangeAWorldOnlyWhenItsOwnerLetsThem) {
  Cli cli("physctl_access");
  ASSERT_GT(cli.pid, 0);
  const std::string other = (cli.dir.path / "other.key").string();
  // whoami: the key's id, the same at every run; --key names another key file.
  Shell me = cli.physctl("whoami");
  ASSERT_EQ(me.code, 0) << me.output;
  EXPECT_EQ(cli.physctl("whoami").output, me.output);
  Shell them = shell(cli.prefix() + " --key " + shq(other) + " whoami");
  ASSERT_EQ(them.code, 0) << them.output;
  ASSERT_NE(them.output, me.output);
  const std::string themId = them.output.substr(0, them.output.find('\n'));
  ASSERT_EQ(themId.rfind("0x", 0), 0u) << themId;

  ASSERT_EQ(cli.physctl("create mine").code, 0);
  Shell r = cli.physctl("step mine 1", other);
  EXPECT_EQ(r.code, 1) << r.output;
  EXPECT_NE(r.output.find("PermissionDenied"), std::string::npos) << r.output;
  r = cli.physctl("access mine --editors " + themId);
  ASSERT_EQ(r.code, 0) << r.output;
  EXPECT_NE(r.output.find(themId), std::string::npos) << r.output;
  r = cli.physctl("step mine 1", other);
  EXPECT_EQ(r.code, 0) << r.output;
  // Only the owner sets access.
  r = cli.physctl("access mine --shared", other);
  EXPECT_NE(r.output.find("PermissionDenied"), std::string::npos) << r.output;
  ASSERT_EQ(cli.physctl("access mine --private").code, 0);
  r = cli.physctl("step mine 1", other);
  EXPECT_NE(r.output.find("PermissionDenied"), std::string::npos) << r.output;
  ASSERT_EQ(cli.physctl("access mine --shared").code, 0);
  r = cli.physctl("step mine 1", other);
  EXPECT_EQ(r.code, 0) << r.output;
  // At creation.
  ASSERT_EQ(cli.physctl("create theirs --editors " + themId).code, 0);
  r = cli.physctl("load theirs pyramid_20", other);
  EXPECT_EQ(r.code, 0) << r.output;
  ASSERT_EQ(cli.physctl("create everyones --shared").code, 0);
  r = cli.physctl("step everyones 2", (cli.dir.path / "third.key").string());
  EXPECT_EQ(r.code, 0) << r.output;
  // A client id that is none.
  r = cli.physctl("access mine --editors 0xnothex");
  EXPECT_EQ(r.code, 2) << r.output;
}

TEST(ClientPhysctl, PhysctlsWithOneKeyAtOnceTakeTurns) {
  // On physd one participant holds a client id at a time: a second physctl with the same key
  // would take the id in the middle of the first one's commands. They take turns instead.
  Cli cli("physctl_turns");
  ASSERT_GT(cli.pid, 0);
  ASSERT_EQ(cli.physctl("create turns").code, 0);
  std::string line;
  for (int i = 0; i < 4; ++i)
    line += "( " + cli.prefix() + " step turns 5 > out" + std::to_string(i) + ".txt 2>&1; echo $? > rc" +
            std::to_string(i) + ".txt ) & ";
  line += "wait";
  ASSERT_EQ(shell(line).code, 0);
  for (int i = 0; i < 4; ++i) {
    std::ifstream rc(cli.dir.path / ("rc" + std::to_string(i) + ".txt"));
    std::ifstream out(cli.dir.path / ("out" + std::to_string(i) + ".txt"));
    std::stringstream text;
    text << out.rdbuf();
    int code = -1;
    rc >> code;
    EXPECT_EQ(code, 0) << text.str();
  }
  const Shell r = cli.physctl("list --json");
  const nlohmann::json worlds = nlohmann::json::parse(r.output, nullptr, false);
  ASSERT_TRUE(worlds.is_array()) << r.output;
  ASSERT_EQ(worlds.size(), 1u);
  EXPECT_EQ(worlds[0].at("tick").get<uint64_t>(), 20u);
}

}  // namespace
}  // namespace phys::client
