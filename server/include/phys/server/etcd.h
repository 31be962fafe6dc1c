// A small client of etcd's v3 API through its JSON gateway (HTTP POST /v3/kv/range and
// /v3/kv/txn on the client URL, which etcd serves beside gRPC), over libcurl. What a domain of
// daemons keeps in etcd (docs/SERVER.md "Standby and takeover") needs reads of a key or a
// prefix and compare-and-swap transactions on mod revisions, nothing else: no watches, no
// leases (their TTL is whole seconds; see docs/ARCHITECTURE.md "Ownership in etcd").
//
// Blocking calls with a timeout each; one thread uses a client at a time.
#pragma once

#include <chrono>
#include <cstdint>
#include <string>
#include <vector>

#include "phys/protocol/status.h"

namespace phys::server {

using protocol::Status;

class Etcd {
 public:
  /// endpoint: etcd's client URL, e.g. "http://127.0.0.1:2379".
  Etcd(std::string endpoint, std::chrono::milliseconds timeout);
  ~Etcd();
  Etcd(const Etcd&) = delete;
  Etcd& operator=(const Etcd&) = delete;

  struct Kv {
    std::string key, value;
    int64_t createRevision = 0, modRevision = 0;
  };
  /// The key (or every key under it, `prefix`), and the store's revision at the read.
  Status range(const std::string& key, bool prefix, std::vector<Kv>* out,
               int64_t* revision = nullptr);

  /// A condition of a transaction: the key's mod revision equals modRevision (0: the key
  /// does not exist).
  struct Compare {
    std::string key;
    int64_t modRevision = 0;
  };
  struct Put {
    std::string key, value;
  };
  /// If every compare holds, the puts and deletes, atomically. *succeeded says whether they
  /// held; *revision is the store's revision after the transaction (the mod revision of
  /// what it put).
  Status txn(const std::vector<Compare>& compares, const std::vector<Put>& puts,
             const std::vector<std::string>& deletes, bool* succeeded, int64_t* revision);

  const std::string& endpoint() const { return endpoint_; }

 private:
  Status post(const std::string& path, const std::string& body, std::string* response);
  std::string endpoint_;
  std::chrono::milliseconds timeout_;
  void* curl_ = nullptr;  ///< CURL*, reused (keeps the connection)
};

std::string base64Encode(const std::string& bytes);
/// False on a character outside the alphabet.
bool base64Decode(const std::string& text, std::string* bytes);

}  // namespace phys::server
