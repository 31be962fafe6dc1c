// etcd's v3 JSON gateway over libcurl (phys/server/etcd.h).
#include "phys/server/etcd.h"

#include <curl/curl.h>

#include <mutex>
#include <nlohmann/json.hpp>

namespace phys::server {

using protocol::Code;

namespace {

constexpr char kAlphabet[] = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";

size_t collect(char* data, size_t size, size_t n, void* out) {
  static_cast<std::string*>(out)->append(data, size * n);
  return size * n;
}

/// etcd's JSON writes 64-bit numbers as strings.
int64_t number(const nlohmann::json& j, const char* name) {
  auto it = j.find(name);
  if (it == j.end()) return 0;
  if (it->is_string()) return std::stoll(it->get<std::string>());
  if (it->is_number_integer()) return it->get<int64_t>();
  return 0;
}

}  // namespace

std::string base64Encode(const std::string& bytes) {
  std::string out;
  out.reserve((bytes.size() + 2) / 3 * 4);
  size_t i = 0;
  for (; i + 2 < bytes.size(); i += 3) {
    const uint32_t v = uint32_t(uint8_t(bytes[i])) << 16 | uint32_t(uint8_t(bytes[i + 1])) << 8 |
                       uint8_t(bytes[i + 2]);
    for (int s = 18; s >= 0; s -= 6) out += kAlphabet[(v >> s) & 63];
  }
  if (i < bytes.size()) {
    uint32_t v = uint32_t(uint8_t(bytes[i])) << 16;
    if (i + 1 < bytes.size()) v |= uint32_t(uint8_t(bytes[i + 1])) << 8;
    out += kAlphabet[(v >> 18) & 63];
    out += kAlphabet[(v >> 12) & 63];
    out += i + 1 < bytes.size() ? kAlphabet[(v >> 6) & 63] : '=';
    out += '=';
  }
  return out;
}

bool base64Decode(const std::string& text, std::string* bytes) {
  bytes->clear();
  uint32_t v = 0;
  int bits = 0;
  for (char c : text) {
    if (c == '=') break;
    const char* p = std::char_traits<char>::find(kAlphabet, 64, c);
    if (!p) return false;
    v = (v << 6) | uint32_t(p - kAlphabet);
    bits += 6;
    if (bits >= 8) {
      bits -= 8;
      bytes->push_back(char((v >> bits) & 0xff));
    }
  }
  return true;
}

Etcd::Etcd(std::string endpoint, std::chrono::milliseconds timeout)
    : endpoint_(std::move(endpoint)), timeout_(timeout) {
  static std::once_flag once;
  std::call_once(once, [] { curl_global_init(CURL_GLOBAL_DEFAULT); });
  curl_ = curl_easy_init();
}

Etcd::~Etcd() {
  if (curl_) curl_easy_cleanup(static_cast<CURL*>(curl_));
}

Status Etcd::post(const std::string& path, const std::string& body, std::string* response) {
  CURL* c = static_cast<CURL*>(curl_);
  if (!c) return Status::Error(Code::Internal, "etcd: libcurl did not start");
  response->clear();
  const std::string url = endpoint_ + path;
  curl_easy_setopt(c, CURLOPT_URL, url.c_str());
  curl_easy_setopt(c, CURLOPT_POST, 1L);
  curl_easy_setopt(c, CURLOPT_POSTFIELDS, body.c_str());
  curl_easy_setopt(c, CURLOPT_POSTFIELDSIZE, long(body.size()));
  curl_easy_setopt(c, CURLOPT_TIMEOUT_MS, long(timeout_.count()));
  curl_easy_setopt(c, CURLOPT_CONNECTTIMEOUT_MS, long(timeout_.count()));
  curl_easy_setopt(c, CURLOPT_NOSIGNAL, 1L);
  curl_easy_setopt(c, CURLOPT_WRITEFUNCTION, &collect);
  curl_easy_setopt(c, CURLOPT_WRITEDATA, response);
  const CURLcode rc = curl_easy_perform(c);
  if (rc != CURLE_OK)
    return Status::Error(Code::Internal,
                         "etcd at " + endpoint_ + ": " + curl_easy_strerror(rc));
  long http = 0;
  curl_easy_getinfo(c, CURLINFO_RESPONSE_CODE, &http);
  if (http != 200)
    return Status::Error(Code::Internal, "etcd at " + endpoint_ + path + ": HTTP " +
                                                std::to_string(http) + ": " +
                                                response->substr(0, 200));
  return Status::Ok();
}

Status Etcd::range(const std::string& key, bool prefix, std::vector<Kv>* out,
                   int64_t* revision) {
  nlohmann::json req{{"key", base64Encode(key)}};
  if (prefix) {
    // Every key that starts with `key`: the range end is the prefix with its last byte + 1.
    std::string end = key;
    while (!end.empty() && uint8_t(end.back()) == 0xff) end.pop_back();
    if (!end.empty()) end.back() = char(uint8_t(end.back()) + 1);
    req["range_end"] = base64Encode(end.empty() ? std::string(1, '\0') : end);
  }
  std::string text;
  if (Status s = post("/v3/kv/range", req.dump(), &text); !s.ok()) return s;
  try {
    const nlohmann::json j = nlohmann::json::parse(text);
    out->clear();
    if (revision) *revision = number(j.value("header", nlohmann::json::object()), "revision");
    for (const auto& kv : j.value("kvs", nlohmann::json::array())) {
      Kv e;
      if (!base64Decode(kv.value("key", ""), &e.key) ||
          !base64Decode(kv.value("value", ""), &e.value))
        return Status::Error(Code::Internal, "etcd: a key or value that is not base64");
      e.createRevision = number(kv, "create_revision");
      e.modRevision = number(kv, "mod_revision");
      out->push_back(std::move(e));
    }
  } catch (const std::exception& e) {
    return Status::Error(Code::Internal, std::string("etcd: range: ") + e.what());
  }
  return Status::Ok();
}

Status Etcd::txn(const std::vector<Compare>& compares, const std::vector<Put>& puts,
                 const std::vector<std::string>& deletes, bool* succeeded, int64_t* revision) {
  nlohmann::json req;
  req["compare"] = nlohmann::json::array();
  for (const Compare& c : compares)
    req["compare"].push_back({{"key", base64Encode(c.key)},
                              {"target", "MOD"},
                              {"result", "EQUAL"},
                              {"mod_revision", std::to_string(c.modRevision)}});
  req["success"] = nlohmann::json::array();
  for (const Put& p : puts)
    req["success"].push_back(
        {{"request_put", {{"key", base64Encode(p.key)}, {"value", base64Encode(p.value)}}}});
  for (const std::string& k : deletes)
    req["success"].push_back({{"request_delete_range", {{"key", base64Encode(k)}}}});
  std::string text;
  if (Status s = post("/v3/kv/txn", req.dump(), &text); !s.ok()) return s;
  try {
    const nlohmann::json j = nlohmann::json::parse(text);
    *succeeded = j.value("succeeded", false);
    if (revision) *revision = number(j.value("header", nlohmann::json::object()), "revision");
  } catch (const std::exception& e) {
    return Status::Error(Code::Internal, std::string("etcd: txn: ") + e.what());
  }
  return Status::Ok();
}

}  // namespace phys::server
