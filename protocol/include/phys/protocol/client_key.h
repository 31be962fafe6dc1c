// A client's key on a daemon without DDS Security: an Ed25519 key pair whose public half
// names the client (its client id is a hash of it) and whose private half never leaves the
// client. In Hello the client signs "this participant holds this client id" (a binding
// proof); physd checks the signature and from then on knows that commands under that id from
// that participant come from the key's holder (docs/SERVER.md "Access").
//
// Why a signature and not a secret the daemon hands out: on a domain without DDS Security
// every topic is readable by every participant, so a secret sent over it (in a reply, in a
// command) is no secret. A signature over the sender's participant GUID proves possession of
// the key without revealing it, and cannot be replayed from another participant (its GUID
// differs). What it does not stop: a participant that forges another's GUID in raw RTPS
// packets; DDS Security is the protection against that (docs/SECURITY.md).
#pragma once

#include <array>
#include <cstdint>
#include <span>
#include <string>

#include "phys/protocol/status.h"

namespace phys::protocol {

inline constexpr size_t kClientPublicKeyBytes = 32;  ///< Ed25519 public key
inline constexpr size_t kClientProofBytes = 64;      ///< Ed25519 signature
using ParticipantGuid = std::array<uint8_t, 16>;

/// The client id a public key names: the first 8 bytes, little-endian, of
/// SHA-256("phys.client." + key), or 1 should that be 0 (0 is no client id).
uint64_t clientIdOfKey(std::span<const uint8_t> publicKey);

/// Whether `proof` is the holder of `publicKey` signing that participant `participant` uses
/// client id `clientId`, and the id is the key's.
bool verifyBinding(std::span<const uint8_t> publicKey, const ParticipantGuid& participant,
                   uint64_t clientId, std::span<const uint8_t> proof);

/// An Ed25519 key pair (the 32-byte seed and the public key derived from it).
class ClientKey {
 public:
  /// A fresh random key.
  static ClientKey generate();
  static ClientKey fromSeed(const std::array<uint8_t, 32>& seed);
  /// Reads a key file (64 hex digits of the seed and a newline, as save() writes it). With
  /// create, a missing file is made with a fresh key (mode 0600, its folder made too). Fails
  /// with a message naming the file when it cannot be read, is malformed, or can be read by
  /// others than its owner (like ssh, a private key open to others is refused).
  static Status load(const std::string& path, bool create, ClientKey* out);
  /// Writes the key file (mode 0600), aside and renamed, so a crash leaves no torn key.
  Status save(const std::string& path) const;

  const std::array<uint8_t, kClientPublicKeyBytes>& publicKey() const { return public_; }
  uint64_t clientId() const { return clientIdOfKey(public_); }
  /// The binding proof for Hello: this key's holder uses clientId() from `participant`.
  std::array<uint8_t, kClientProofBytes> proveBinding(const ParticipantGuid& participant) const;

 private:
  std::array<uint8_t, 32> seed_{};
  std::array<uint8_t, kClientPublicKeyBytes> public_{};
};

}  // namespace phys::protocol
