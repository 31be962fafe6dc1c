// DDS Security for physd and its clients (docs/SECURITY.md): the files of an identity, the
// <Security> element of Cyclone's configuration made from them, and the partition in which a
// client writes its commands so that physd can tell which identity sent them.
//
// Why a partition: DDS Security authenticates a participant by its certificate, but Cyclone
// 0.10 does not tell an application which identity a remote participant has. What it does
// enforce is the permissions document signed by the permissions CA: tools/make_security.sh
// lets identity NAME publish only in partition "phys.id.NAME", so a command that arrives in
// that partition on a secure domain was written by a participant holding NAME's certificate.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>

#include "phys/protocol/status.h"

namespace phys::protocol {

/// Prefix of the identity partitions; physd's command reader reads "" and "phys.id.*".
inline constexpr std::string_view kIdentityPartitionPrefix = "phys.id.";
/// Identity names: 1-64 characters of [A-Za-z0-9_.-], the first a letter or digit (the
/// certificate's CN as tools/make_security.sh makes it).
inline constexpr size_t kMaxIdentityName = 64;
bool validIdentityName(std::string_view name);
/// "phys.id.<name>".
std::string identityPartition(std::string_view name);
/// The identity a partition names, if it is an identity partition with a valid name.
std::optional<std::string> identityOfPartition(std::string_view partition);
/// Who an identity is in world access lists (CreateWorld.editors, SetAccess.editors, a
/// world's owner) on a secure daemon: the first 8 bytes, little-endian, of
/// SHA-256("phys.id." + name). Client ids and identity keys share the 64-bit space; an open
/// daemon uses only client ids, a secure one only identity keys (docs/SECURITY.md).
uint64_t identityKey(std::string_view name);

/// The files of one identity, as tools/make_security.sh writes them into a folder.
struct SecurityFiles {
  std::string identity;       ///< its name (the certificate's CN)
  std::string certificate;    ///< PEM, signed by identityCa
  std::string privateKey;     ///< PEM
  std::string identityCa;     ///< PEM of the CA that signs identities
  std::string permissionsCa;  ///< PEM of the CA that signed the two documents below
  std::string governance;     ///< signed governance document (.p7s)
  std::string permissions;    ///< signed permissions document (.p7s)
  /// Folder of libdds_security_{auth,ac,crypto}.so; empty: where Debian 12's libddsc0debian
  /// puts them (not on the library path).
  std::string pluginDir;

  bool enabled() const { return !identity.empty(); }
  /// <dir>/<name>_cert.pem, <name>_key.pem, ca_cert.pem (both CAs), governance.p7s,
  /// permissions.p7s.
  static SecurityFiles fromDir(const std::string& dir, const std::string& name);
};

/// Puts a <Security> element for `files` into the Cyclone XML `xml` (inside its first
/// <Domain>; an empty xml becomes a whole configuration). Checks that the name is valid and
/// that every file can be read; fails otherwise (nothing changed). Paths are made absolute.
Status addSecurity(std::string* xml, const SecurityFiles& files);

}  // namespace phys::protocol
