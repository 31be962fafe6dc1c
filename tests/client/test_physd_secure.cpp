// physd, physctl and the SDK with DDS Security, as processes (issue 24, 4; docs/SECURITY.md):
// physd's [security] section and physctl's --identity / --security-dir (the SDK's
// ClientOptions::security) on loopback, with credentials from tools/make_security.sh. A world
// belongs to the identity that created it: another identity's edit is refused with
// PermissionDenied, the same identity from another process (so another client id) may edit,
// and a client without an identity gets no answer at all.
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <thread>

#include "in_process_daemon.h"
#include "physd_process.h"

namespace phys::client {
namespace {

using namespace std::chrono_literals;

using testing::Shell;
using testing::shell;
using testing::shq;

TEST(ClientPhysdSecure, AWorldBelongsToTheIdentityThatCreatedIt) {
  for (const char* lib : {"auth", "ac", "crypto"}) {
    const std::string so =
        std::string("/usr/lib/x86_64-linux-gnu/libddsc0debian/libdds_security_") + lib + ".so";
    if (!std::filesystem::exists(so)) GTEST_SKIP() << so << " is missing";
  }
  if (shell("command -v openssl").code != 0) GTEST_SKIP() << "openssl is not installed";
  testing::ScratchDir dir("physclient_secure");
  const std::string sec = (dir.path / "security").string();
  Shell made = shell("bash " + shq(std::string(PHYS_SOURCE_DIR) + "/tools/make_security.sh") +
                   " --out " + shq(sec) + " --identities 'physd client1 client2' --days 2");
  ASSERT_EQ(made.code, 0) << made.output;
  // Domains of the signed documents: 0-230.
  testing::PhysdConfig cfg(dir.path, "physd-secure", 1 + uint32_t(getpid() % 200),
                           "[security]\ndir = \"" + sec + "\"\nidentity = \"physd\"\n");
  const pid_t pid = testing::spawnProcess(PHYSD_BINARY, {"--config", cfg.toml});
  ASSERT_GT(pid, 0);
  auto physctl = [&](const std::string& identity, const std::string& args) {
    std::string line = shq(PHYSCTL_BINARY) + " --domain " + std::to_string(cfg.domain) +
                       " --config " + shq(cfg.xml) + " --timeout 8000 --key " +
                       shq((dir.path / ("client_" + identity + ".key")).string());
    if (!identity.empty()) line += " --identity " + identity + " --security-dir " + shq(sec);
    return shell(line + " " + args);
  };
  Shell r = physctl("client1", "create owned");
  EXPECT_EQ(r.code, 0) << r.output;
  r = physctl("client2", "step owned 3");
  EXPECT_NE(r.code, 0) << r.output;
  EXPECT_NE(r.output.find("PermissionDenied"), std::string::npos) << r.output;
  r = physctl("client1", "step owned 3");  // another process: another client id
  EXPECT_EQ(r.code, 0) << r.output;
  r = physctl("client2", "list");  // reads are open
  EXPECT_EQ(r.code, 0) << r.output;
  EXPECT_NE(r.output.find("owned"), std::string::npos) << r.output;
  // Without an identity: not let into the domain, so no daemon answers.
  r = shell(shq(PHYSCTL_BINARY) + " --domain " + std::to_string(cfg.domain) + " --config " +
            shq(cfg.xml) + " --timeout 2000 list");
  EXPECT_NE(r.code, 0) << r.output;
  // An identity name the SDK refuses before it touches DDS.
  r = physctl("'bad name'", "list");
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.output.find("identity"), std::string::npos) << r.output;
  EXPECT_EQ(testing::stopProcess(pid, SIGTERM) & 0x7f, 0) << "physd did not exit on SIGTERM";
}

}  // namespace
}  // namespace phys::client
