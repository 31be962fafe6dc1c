// phys/protocol/client_key.h: a client's Ed25519 key, the id it names, the binding proof a
// Hello carries, and the key file (issue 39 point 4).
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>

#include "phys/protocol/builder.h"
#include "phys/protocol/client_key.h"
#include "phys/protocol/decoder.h"

namespace phys::protocol {
namespace {

ParticipantGuid guid(uint8_t fill) {
  ParticipantGuid g{};
  g.fill(fill);
  g[15] = 0xC1;
  return g;
}

TEST(ClientKey, AProofBindsOneKeyOneIdAndOneParticipant) {
  const ClientKey key = ClientKey::generate();
  const ClientKey other = ClientKey::generate();
  EXPECT_NE(key.clientId(), other.clientId());
  EXPECT_NE(key.clientId(), 0u);
  EXPECT_EQ(key.clientId(), clientIdOfKey(key.publicKey()));

  const auto proof = key.proveBinding(guid(1));
  EXPECT_TRUE(verifyBinding(key.publicKey(), guid(1), key.clientId(), proof));
  // Replayed from another participant (what a reader of the wire could try).
  EXPECT_FALSE(verifyBinding(key.publicKey(), guid(2), key.clientId(), proof));
  // Another id than the key's, or another key offered with this proof.
  EXPECT_FALSE(verifyBinding(key.publicKey(), guid(1), key.clientId() ^ 1, proof));
  EXPECT_FALSE(verifyBinding(other.publicKey(), guid(1), other.clientId(), proof));
  // Any bit of the proof or the key changed; short proofs and keys.
  for (size_t i = 0; i < proof.size(); i += 7) {
    auto bad = proof;
    bad[i] ^= 0x10;
    EXPECT_FALSE(verifyBinding(key.publicKey(), guid(1), key.clientId(), bad)) << i;
  }
  auto badKey = key.publicKey();
  badKey[3] ^= 1;
  EXPECT_FALSE(verifyBinding(badKey, guid(1), key.clientId(), proof));
  EXPECT_FALSE(verifyBinding(key.publicKey(), guid(1), key.clientId(),
                             std::span<const uint8_t>(proof.data(), 63)));
  EXPECT_FALSE(verifyBinding(std::span<const uint8_t>(key.publicKey().data(), 31), guid(1),
                             key.clientId(), proof));
}

TEST(ClientKey, TheSameSeedIsTheSameKey) {
  std::array<uint8_t, 32> seed{};
  for (size_t i = 0; i < seed.size(); ++i) seed[i] = uint8_t(i * 7 + 1);
  const ClientKey a = ClientKey::fromSeed(seed), b = ClientKey::fromSeed(seed);
  EXPECT_EQ(a.publicKey(), b.publicKey());
  EXPECT_EQ(a.clientId(), b.clientId());
  // Ed25519 signatures are deterministic: the same key proves the same binding the same way.
  EXPECT_EQ(a.proveBinding(guid(4)), b.proveBinding(guid(4)));
}

TEST(ClientKey, KeyFilesAreMadeOnceKeptPrivateAndCheckedWhenRead) {
  namespace fs = std::filesystem;
  const fs::path dir = fs::temp_directory_path() / ("phys_key_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  const std::string path = (dir / "sub" / "client.key").string();
  ClientKey made, again;
  EXPECT_FALSE(ClientKey::load(path, false, &made).ok());  // missing, not to be made
  ASSERT_TRUE(ClientKey::load(path, true, &made).ok());
  struct stat st {};
  ASSERT_EQ(::stat(path.c_str(), &st), 0);
  EXPECT_EQ(st.st_mode & 0777, 0600u);
  ASSERT_TRUE(ClientKey::load(path, true, &again).ok());
  EXPECT_EQ(again.clientId(), made.clientId()) << "a second run has the same id";

  // Readable by others: refused, like ssh refuses such a private key.
  ::chmod(path.c_str(), 0644);
  Status s = ClientKey::load(path, true, &again);
  EXPECT_FALSE(s.ok());
  EXPECT_NE(s.message.find("0600"), std::string::npos) << s.message;
  ::chmod(path.c_str(), 0600);
  // Malformed contents.
  for (const char* text : {"", "abc\n", "zz00000000000000000000000000000000000000000000000000000000000000\n"}) {
    std::ofstream(path) << text;
    s = ClientKey::load(path, false, &again);
    EXPECT_FALSE(s.ok()) << text;
    EXPECT_NE(s.message.find(path), std::string::npos) << s.message;
  }
  fs::remove_all(dir);
}

TEST(ClientKey, HelloCarriesAWholeKeyAndProofOrNeither) {
  const ClientKey key = ClientKey::generate();
  const auto proof = key.proveBinding(guid(9));
  Bytes ok = CommandBuilder().hello("c", key.publicKey(), proof).finish({key.clientId(), 1, 0});
  auto d = decodeCommand(ok);
  ASSERT_TRUE(d.ok()) << d.status.message;
  auto* h = d->request_as_Hello();
  ASSERT_TRUE(h && h->public_key() && h->proof());
  EXPECT_TRUE(verifyBinding({h->public_key()->data(), h->public_key()->size()}, guid(9),
                            d->client_id(), {h->proof()->data(), h->proof()->size()}));
  // A key without its proof, a short proof.
  Bytes noProof = CommandBuilder().hello("c", key.publicKey(), {}).finish({key.clientId(), 2, 0});
  EXPECT_EQ(decodeCommand(noProof).status.code, Code::Malformed);
  Bytes shortProof = CommandBuilder()
                         .hello("c", key.publicKey(), std::span<const uint8_t>(proof.data(), 10))
                         .finish({key.clientId(), 3, 0});
  EXPECT_EQ(decodeCommand(shortProof).status.code, Code::Malformed);
  // Hello without a proof stays valid (a client of the plain protocol).
  EXPECT_TRUE(decodeCommand(CommandBuilder().hello("c").finish({5, 4, 0})).ok());
}

}  // namespace
}  // namespace phys::protocol
