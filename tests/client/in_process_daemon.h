// What the SDK tests share: physd's components wired in this process as physd's main() wires
// them (InProcessDaemon), on loopback DDS with a discovery tag of this test process and a
// domain of the in-process range (230 or 231), so that tests running in parallel never see
// each other's daemons; and a shell for the tests that run physctl.
#pragma once

#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <fstream>
#include <sstream>
#include <string>

#include "../common/sanitizer.h"
#include "phys/client/client.h"
#include "phys/server/core.h"
#include "phys/server/endpoint.h"

namespace phys::client::testing {

/// A request's deadline on a loaded 2-core machine (10x under a sanitizer).
inline constexpr auto kClientTimeout =
    std::chrono::milliseconds(int64_t(20000 * test::kTimeFactor));

/// The DDS domain of in-process daemons (the process tests' physd binaries use others).
inline uint32_t inProcessDomain() {
  return 230 + uint32_t(getpid() % 2);
}

/// configs/cyclonedds/loopback.xml with a discovery tag of this process.
inline std::string taggedLoopbackXml() {
  std::ifstream in(std::string(PHYS_SOURCE_DIR) + "/configs/cyclonedds/loopback.xml");
  std::stringstream ss;
  ss << in.rdbuf();
  std::string xml = ss.str();
  const std::string tag = "<Discovery><Tag>physclient-test-" + std::to_string(getpid()) + "</Tag>";
  const auto pos = xml.find("<Discovery>");
  EXPECT_NE(pos, std::string::npos);
  if (pos != std::string::npos) xml.replace(pos, std::string("<Discovery>").size(), tag);
  return xml;
}

/// Options of a client of an InProcessDaemon.
inline ClientOptions inProcessOptions(std::string name) {
  ClientOptions o;
  o.domain = inProcessDomain();
  o.cycloneXml = taggedLoopbackXml();
  o.name = std::move(name);
  o.connectTimeout = kClientTimeout;
  o.requestTimeout = kClientTimeout;
  return o;
}

/// c with the source tree's presets and scenes.
inline server::CoreConfig withSourceTree(server::CoreConfig c = {}) {
  c.presetsFile = std::string(PHYS_SOURCE_DIR) + "/configs/presets.json";
  c.scenesDir = std::string(PHYS_SOURCE_DIR) + "/configs/scenes";
  return c;
}

/// The daemon's components, as physd's main() wires them, ticking every 200 ms when idle.
struct InProcessDaemon {
  explicit InProcessDaemon(server::CoreConfig config = withSourceTree())
      : core(std::move(config)), endpoint(&core, {inProcessDomain(), taggedLoopbackXml()}) {
    EXPECT_TRUE(core.init().ok());
    auto s = endpoint.start();
    EXPECT_TRUE(s.ok()) << s.message;
    tick.start();
  }
  ~InProcessDaemon() {
    tick.stop();
    endpoint.stop();
  }
  server::ServerCore core;
  server::DdsEndpoint endpoint;
  server::TickThread tick{&core, std::chrono::milliseconds(200)};
};

/// s quoted for a POSIX shell.
inline std::string shq(const std::string& s) {
  std::string q = "'";
  for (char c : s) q += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return q + "'";
}

struct Shell {
  int code = -1;
  std::string output;
};

/// Runs a shell command line; its exit code and output (stdout and stderr).
inline Shell shell(const std::string& line) {
  Shell r;
  FILE* f = popen((line + " 2>&1").c_str(), "r");
  if (!f) return r;
  char buf[512];
  while (std::fgets(buf, sizeof buf, f)) r.output += buf;
  const int st = pclose(f);
  r.code = WIFEXITED(st) ? WEXITSTATUS(st) : -1;
  return r;
}

}  // namespace phys::client::testing
