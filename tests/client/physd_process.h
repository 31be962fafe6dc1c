// The physd binary run as a child process for the SDK's process tests: a config of its own
// (domain, Cyclone loopback with a discovery tag of this test process, the source tree's presets
// and scenes, extra TOML appended), spawned with posix_spawn, stopped with SIGTERM.
#pragma once

#include <gtest/gtest.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "../common/sanitizer.h"
#include "in_process_daemon.h"
#include "phys/client/client.h"

extern char** environ;

namespace phys::client::testing {

/// A scratch directory for one test process, removed on destruction.
struct ScratchDir {
  std::filesystem::path path;
  explicit ScratchDir(const std::string& what)
      : path(std::filesystem::temp_directory_path() / (what + "_" + std::to_string(getpid()))) {
    std::filesystem::create_directories(path);
  }
  ~ScratchDir() {
    std::error_code ec;
    std::filesystem::remove_all(path, ec);
  }
};


/// Spawns `binary` with `args`; returns its pid (0 on failure).
inline pid_t spawnProcess(const std::string& binary, const std::vector<std::string>& args) {
  std::vector<std::string> all{binary};
  all.insert(all.end(), args.begin(), args.end());
  std::vector<char*> argv;
  for (std::string& a : all) argv.push_back(a.data());
  argv.push_back(nullptr);
  pid_t pid = 0;
  if (posix_spawn(&pid, binary.c_str(), nullptr, nullptr, argv.data(), environ) != 0) return 0;
  return pid;
}

/// Sends `sig` and waits for the process; returns its wait status.
inline int stopProcess(pid_t pid, int sig) {
  int st = 0;
  kill(pid, sig);
  waitpid(pid, &st, 0);
  return st;
}

/// Kills (SIGKILL) and reaps the child `pid` names when it goes out of scope, unless the test
/// stopped it itself and set `pid` to 0: a test that fails halfway must not leave a daemon
/// behind holding ctest's output pipe (ctest would wait for it until the test's time limit).
struct ProcessGuard {
  pid_t& pid;
  ~ProcessGuard() {
    if (pid > 0) stopProcess(pid, SIGKILL);
  }
};

/// Waits up to `wait` (longer under a sanitizer) until the client has greeted `n` daemons
/// after its first (a restart each); true when it has.
inline bool awaitReconnects(const Client& c, uint64_t n,
                            std::chrono::milliseconds wait = std::chrono::seconds(20)) {
  const auto end = std::chrono::steady_clock::now() + wait * int64_t(phys::test::kTimeFactor);
  while (c.reconnects() < n && std::chrono::steady_clock::now() < end)
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  return c.reconnects() >= n;
}

/// A physd configuration in `dir`: physd.toml (server name, domain, more [server] keys and
/// text after [paths], e.g. start-up worlds, as TOML) and cyclone.xml.
struct PhysdConfig {
  std::string toml, xml;
  uint32_t domain = 0;

  PhysdConfig(const std::filesystem::path& dir, const std::string& name, uint32_t domainId,
              const std::string& worldsToml, const std::string& serverToml = "",
              const std::string& ddsToml = "") {
    const std::string src = PHYS_SOURCE_DIR;
    domain = domainId;
    xml = (dir / "cyclone.xml").string();
    {
      std::ofstream out(xml);
      out << taggedLoopbackXml();
    }
    toml = (dir / "physd.toml").string();
    std::ofstream f(toml);
    f << "[server]\nname = \"" << name << "\"\nlog_level = \"warn\"\n"
      << (serverToml.find("status_period_s") == std::string::npos ? "status_period_s = 0.2\n" : "")
      << serverToml << "[dds]\ndomain = " << domain << "\nconfig = \"" << xml << "\"\n"
      << ddsToml << "[paths]\npresets = \""
      << src << "/configs/presets.json\"\nscenes = \"" << src << "/configs/scenes\"\n"
      << worldsToml;
  }
  ClientOptions clientOptions(std::chrono::milliseconds timeout) const {
    ClientOptions o;
    o.domain = domain;
    std::ifstream in(xml);
    std::stringstream ss;
    ss << in.rdbuf();
    o.cycloneXml = ss.str();
    o.connectTimeout = o.requestTimeout = timeout * int64_t(phys::test::kTimeFactor);
    return o;
  }
};

}  // namespace phys::client::testing
