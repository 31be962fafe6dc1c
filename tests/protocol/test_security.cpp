// phys/protocol/security.h: identity names, partitions and keys, and the <Security> element
// made from an identity's files (docs/SECURITY.md).
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>

#include "phys/protocol/security.h"

namespace phys::protocol {
namespace {

TEST(Security, IdentityNamesAndPartitions) {
  for (const char* good : {"physd", "client1", "a", "Bob_2.test-x"})
    EXPECT_TRUE(validIdentityName(good)) << good;
  for (const char* bad : {"", "-x", ".x", "_x", "a b", "a/b", "a*", "a<b", "é"})
    EXPECT_FALSE(validIdentityName(bad)) << bad;
  EXPECT_TRUE(validIdentityName(std::string(64, 'a')));
  EXPECT_FALSE(validIdentityName(std::string(65, 'a')));
  EXPECT_EQ(identityPartition("client1"), "phys.id.client1");
  EXPECT_EQ(identityOfPartition("phys.id.client1"), "client1");
  // The default partition, a wildcard, another prefix or a bad name: no identity.
  for (const char* none : {"", "phys.id.", "phys.id.*", "phys.id.a b", "phys.idx", "other"})
    EXPECT_FALSE(identityOfPartition(none).has_value()) << none;
}

TEST(Security, IdentityKeyIsTheFirstEightBytesOfSha256LittleEndian) {
  // printf 'phys.id.client1' | openssl dgst -sha256 -> 524c0e3144f79c86...
  EXPECT_EQ(identityKey("client1"), 0x869cf744310e4c52ull);
  EXPECT_NE(identityKey("client1"), identityKey("client2"));
}

TEST(Security, AddSecurityPutsTheFilesIntoTheDomain) {
  const std::filesystem::path dir =
      std::filesystem::temp_directory_path() / ("physsec_" + std::to_string(getpid()));
  std::filesystem::create_directories(dir);
  SecurityFiles f = SecurityFiles::fromDir(dir.string(), "alice");
  std::string xml;
  Status s = addSecurity(&xml, f);  // nothing there yet
  EXPECT_EQ(s.code, Code::InvalidArgument);
  EXPECT_NE(s.message.find("alice_cert.pem"), std::string::npos) << s.message;
  EXPECT_TRUE(xml.empty());  // unchanged
  for (const char* file : {"alice_cert.pem", "alice_key.pem", "ca_cert.pem", "governance.p7s",
                           "permissions.p7s"})
    std::ofstream(dir / file) << "x";
  s = addSecurity(&xml, f);
  ASSERT_TRUE(s.ok()) << s.message;
  EXPECT_EQ(xml.rfind("<CycloneDDS", 0), 0u);
  EXPECT_NE(xml.find("<IdentityCertificate>file:" + (dir / "alice_cert.pem").string() +
                     "</IdentityCertificate>"),
            std::string::npos)
      << xml;
  EXPECT_NE(xml.find("/usr/lib/x86_64-linux-gnu/libddsc0debian/libdds_security_ac.so"),
            std::string::npos);
  // Into an existing configuration's Domain; twice is refused.
  std::string lo = "<CycloneDDS><Domain id=\"any\"><General/></Domain></CycloneDDS>";
  ASSERT_TRUE(addSecurity(&lo, f).ok());
  EXPECT_NE(lo.find("<General/><Security>"), std::string::npos) << lo;
  EXPECT_NE(lo.find("</Security></Domain>"), std::string::npos) << lo;
  EXPECT_EQ(addSecurity(&lo, f).code, Code::InvalidArgument);
  std::string noDomain = "<CycloneDDS/>";
  EXPECT_EQ(addSecurity(&noDomain, f).code, Code::InvalidArgument);
  f.identity = "bad name";
  std::string empty;
  EXPECT_EQ(addSecurity(&empty, f).code, Code::InvalidArgument);
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace phys::protocol
