// Client keys and binding proofs (phys/protocol/client_key.h), over OpenSSL's Ed25519.
#include "phys/protocol/client_key.h"

#include <openssl/evp.h>
#include <openssl/rand.h>
#include <openssl/sha.h>
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cctype>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <memory>
#include <stdexcept>
#include <string_view>
#include <vector>

namespace phys::protocol {

namespace {

constexpr std::string_view kIdPrefix = "phys.client.";
/// What a binding proof signs: this text, the participant's GUID and the client id (8 bytes,
/// little-endian). The text keeps a signature for anything else from passing as a proof.
constexpr std::string_view kBindingText = "phys.client.binding.v1";

struct PkeyFree {
  void operator()(EVP_PKEY* k) const { EVP_PKEY_free(k); }
};
struct CtxFree {
  void operator()(EVP_MD_CTX* c) const { EVP_MD_CTX_free(c); }
};
using Pkey = std::unique_ptr<EVP_PKEY, PkeyFree>;
using MdCtx = std::unique_ptr<EVP_MD_CTX, CtxFree>;

using BindingMessage = std::array<uint8_t, kBindingText.size() + 16 + 8>;
BindingMessage bindingMessage(const ParticipantGuid& participant, uint64_t clientId) {
  BindingMessage m{};
  std::memcpy(m.data(), kBindingText.data(), kBindingText.size());
  std::memcpy(m.data() + kBindingText.size(), participant.data(), participant.size());
  for (size_t i = 0; i < 8; ++i) m[kBindingText.size() + 16 + i] = uint8_t(clientId >> (8 * i));
  return m;
}

Status fail(const std::string& message) {
  return Status::Error(Code::InvalidArgument, message);
}

}  // namespace

uint64_t clientIdOfKey(std::span<const uint8_t> publicKey) {
  std::string text(kIdPrefix);
  text.append(reinterpret_cast<const char*>(publicKey.data()), publicKey.size());
  unsigned char digest[SHA256_DIGEST_LENGTH];
  SHA256(reinterpret_cast<const unsigned char*>(text.data()), text.size(), digest);
  uint64_t id = 0;
  for (int i = 7; i >= 0; --i) id = (id << 8) | digest[i];
  return id ? id : 1;
}

bool verifyBinding(std::span<const uint8_t> publicKey, const ParticipantGuid& participant,
                   uint64_t clientId, std::span<const uint8_t> proof) {
  if (publicKey.size() != kClientPublicKeyBytes || proof.size() != kClientProofBytes)
    return false;
  if (clientIdOfKey(publicKey) != clientId) return false;
  Pkey key(EVP_PKEY_new_raw_public_key(EVP_PKEY_ED25519, nullptr, publicKey.data(),
                                       publicKey.size()));
  MdCtx ctx(EVP_MD_CTX_new());
  if (!key || !ctx) return false;
  if (EVP_DigestVerifyInit(ctx.get(), nullptr, nullptr, nullptr, key.get()) != 1) return false;
  const BindingMessage m = bindingMessage(participant, clientId);
  return EVP_DigestVerify(ctx.get(), proof.data(), proof.size(), m.data(), m.size()) == 1;
}

ClientKey ClientKey::generate() {
  std::array<uint8_t, 32> seed{};
  if (RAND_bytes(seed.data(), int(seed.size())) != 1)
    throw std::runtime_error("client key: no random bytes from OpenSSL");
  return fromSeed(seed);
}

ClientKey ClientKey::fromSeed(const std::array<uint8_t, 32>& seed) {
  ClientKey k;
  k.seed_ = seed;
  Pkey key(EVP_PKEY_new_raw_private_key(EVP_PKEY_ED25519, nullptr, seed.data(), seed.size()));
  size_t n = k.public_.size();
  if (!key || EVP_PKEY_get_raw_public_key(key.get(), k.public_.data(), &n) != 1 ||
      n != k.public_.size())
    throw std::runtime_error("client key: OpenSSL cannot make an Ed25519 key");
  return k;
}

std::array<uint8_t, kClientProofBytes> ClientKey::proveBinding(
    const ParticipantGuid& participant) const {
  std::array<uint8_t, kClientProofBytes> sig{};
  Pkey key(EVP_PKEY_new_raw_private_key(EVP_PKEY_ED25519, nullptr, seed_.data(), seed_.size()));
  MdCtx ctx(EVP_MD_CTX_new());
  const BindingMessage m = bindingMessage(participant, clientId());
  size_t n = sig.size();
  if (!key || !ctx || EVP_DigestSignInit(ctx.get(), nullptr, nullptr, nullptr, key.get()) != 1 ||
      EVP_DigestSign(ctx.get(), sig.data(), &n, m.data(), m.size()) != 1 || n != sig.size())
    throw std::runtime_error("client key: OpenSSL cannot sign");
  return sig;
}

Status ClientKey::load(const std::string& path, bool create, ClientKey* out) {
  namespace fs = std::filesystem;
  std::error_code ec;
  if (!fs::exists(path, ec)) {
    if (!create) return fail("client key file " + path + " does not exist");
    ClientKey k = generate();
    if (fs::path(path).has_parent_path()) {
      fs::create_directories(fs::path(path).parent_path(), ec);
      if (ec) return fail("client key: cannot make the folder of " + path + ": " + ec.message());
    }
    Status s = k.save(path);
    if (!s.ok()) return s;
    *out = k;
    return Status::Ok();
  }
  struct stat st {};
  if (::stat(path.c_str(), &st) != 0) return fail("client key file " + path + " cannot be read");
  if (st.st_mode & 077)
    return fail("client key file " + path +
                " can be read by others than its owner; a private key must be mode 0600 "
                "(chmod 600 " + path + ")");
  std::ifstream in(path);
  std::string hex;
  if (!in || !(in >> hex)) return fail("client key file " + path + " cannot be read");
  if (hex.size() != 64) return fail("client key file " + path + ": expected 64 hex digits");
  std::array<uint8_t, 32> seed{};
  for (size_t i = 0; i < 32; ++i) {
    unsigned v = 0;
    if (std::sscanf(hex.c_str() + 2 * i, "%2x", &v) != 1 ||
        !std::isxdigit(uint8_t(hex[2 * i])) || !std::isxdigit(uint8_t(hex[2 * i + 1])))
      return fail("client key file " + path + ": expected 64 hex digits");
    seed[i] = uint8_t(v);
  }
  *out = fromSeed(seed);
  return Status::Ok();
}

Status ClientKey::save(const std::string& path) const {
  const std::string tmp = path + ".partial";
  // Made 0600 from the start: the key is never readable by others, not even briefly.
  const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0600);
  if (fd < 0) return fail("client key: cannot write " + tmp + ": " + std::strerror(errno));
  std::string text;
  char digits[3];
  for (uint8_t b : seed_) {
    std::snprintf(digits, sizeof digits, "%02x", b);
    text += digits;
  }
  text += '\n';
  bool ok = ::write(fd, text.data(), text.size()) == ssize_t(text.size()) && ::fsync(fd) == 0;
  ok = (::close(fd) == 0) && ok;
  if (!ok || std::rename(tmp.c_str(), path.c_str()) != 0) {
    std::remove(tmp.c_str());
    return fail("client key: cannot write " + path);
  }
  return Status::Ok();
}

}  // namespace phys::protocol
