// DDS Security configuration and identity partitions (phys/protocol/security.h).
#include "phys/protocol/security.h"

#include <openssl/sha.h>

#include <cstring>
#include <filesystem>
#include <fstream>
#include <tuple>

namespace phys::protocol {

bool validIdentityName(std::string_view name) {
  if (name.empty() || name.size() > kMaxIdentityName) return false;
  for (size_t i = 0; i < name.size(); ++i) {
    const char c = name[i];
    const bool alnum = (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9');
    if (!alnum && (i == 0 || (c != '_' && c != '.' && c != '-'))) return false;
  }
  return true;
}

std::string identityPartition(std::string_view name) {
  return std::string(kIdentityPartitionPrefix) + std::string(name);
}

std::optional<std::string> identityOfPartition(std::string_view partition) {
  if (!partition.starts_with(kIdentityPartitionPrefix)) return std::nullopt;
  std::string_view name = partition.substr(kIdentityPartitionPrefix.size());
  if (!validIdentityName(name)) return std::nullopt;
  return std::string(name);
}

uint64_t identityKey(std::string_view name) {
  const std::string text = identityPartition(name);
  unsigned char digest[SHA256_DIGEST_LENGTH];
  SHA256(reinterpret_cast<const unsigned char*>(text.data()), text.size(), digest);
  uint64_t key = 0;
  for (int i = 7; i >= 0; --i) key = (key << 8) | digest[i];
  return key;
}

SecurityFiles SecurityFiles::fromDir(const std::string& dir, const std::string& name) {
  SecurityFiles f;
  f.identity = name;
  f.certificate = dir + "/" + name + "_cert.pem";
  f.privateKey = dir + "/" + name + "_key.pem";
  f.identityCa = f.permissionsCa = dir + "/ca_cert.pem";
  f.governance = dir + "/governance.p7s";
  f.permissions = dir + "/permissions.p7s";
  return f;
}

namespace {
/// "file:<absolute path>", or an error naming the file that cannot be read.
Status fileUri(const std::string& what, const std::string& path, std::string* out) {
  if (path.empty()) return Status::Error(Code::InvalidArgument, "security: no " + what);
  std::ifstream in(path);
  if (!in) return Status::Error(Code::InvalidArgument,
                                "security: cannot read the " + what + " " + path);
  std::error_code ec;
  std::filesystem::path abs = std::filesystem::absolute(path, ec);
  if (ec) abs = path;
  const std::string s = abs.string();
  // Cyclone expands ${...} in its configuration: a path must not contain one, nor XML markup.
  if (s.find_first_of("<>&\"$") != std::string::npos)
    return Status::Error(Code::InvalidArgument,
                         "security: the " + what + " path " + s + " holds one of < > & \" $");
  *out = "file:" + s;
  return Status::Ok();
}
}  // namespace

Status addSecurity(std::string* xml, const SecurityFiles& f) {
  if (!validIdentityName(f.identity))
    return Status::Error(Code::InvalidArgument,
                         "security: identity '" + f.identity +
                             "' is not 1-64 characters of A-Z a-z 0-9 _ . - (first a letter or digit)");
  std::string cert, key, idCa, permCa, gov, perm;
  for (auto [what, path, out] :
       {std::tuple{"certificate", &f.certificate, &cert}, {"private key", &f.privateKey, &key},
        {"identity CA", &f.identityCa, &idCa}, {"permissions CA", &f.permissionsCa, &permCa},
        {"governance document", &f.governance, &gov},
        {"permissions document", &f.permissions, &perm}}) {
    Status s = fileUri(what, *path, out);
    if (!s.ok()) return s;
  }
  const std::string plugins =
      f.pluginDir.empty() ? "/usr/lib/x86_64-linux-gnu/libddsc0debian" : f.pluginDir;
  if (plugins.find_first_of("<>&\"$") != std::string::npos)
    return Status::Error(Code::InvalidArgument,
                         "security: the plugin folder holds one of < > & \" $");
  const std::string security =
      "<Security><Authentication>"
      "<Library path=\"" + plugins + "/libdds_security_auth.so\" initFunction=\"init_authentication\" "
      "finalizeFunction=\"finalize_authentication\"/>"
      "<IdentityCA>" + idCa + "</IdentityCA>"
      "<IdentityCertificate>" + cert + "</IdentityCertificate>"
      "<PrivateKey>" + key + "</PrivateKey>"
      "</Authentication><AccessControl>"
      "<Library path=\"" + plugins + "/libdds_security_ac.so\" initFunction=\"init_access_control\" "
      "finalizeFunction=\"finalize_access_control\"/>"
      "<PermissionsCA>" + permCa + "</PermissionsCA>"
      "<Governance>" + gov + "</Governance>"
      "<Permissions>" + perm + "</Permissions>"
      "</AccessControl><Cryptographic>"
      "<Library path=\"" + plugins + "/libdds_security_crypto.so\" initFunction=\"init_crypto\" "
      "finalizeFunction=\"finalize_crypto\"/>"
      "</Cryptographic></Security>";
  if (xml->find("<Security") != std::string::npos)
    return Status::Error(Code::InvalidArgument,
                         "security: the Cyclone configuration has a <Security> element already");
  if (xml->empty()) {
    *xml = "<CycloneDDS xmlns=\"https://cdds.io/config\"><Domain id=\"any\">" + security +
           "</Domain></CycloneDDS>";
    return Status::Ok();
  }
  const size_t end = xml->find("</Domain>");
  if (end == std::string::npos)
    return Status::Error(Code::InvalidArgument,
                         "security: the Cyclone configuration has no <Domain> element to put "
                         "<Security> into");
  xml->insert(end, security);
  return Status::Ok();
}

}  // namespace phys::protocol
