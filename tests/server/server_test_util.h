// Shared helpers for the server tests.
#pragma once

#include <gtest/gtest.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>
#include <vector>

#include "../common/bodies.h"
#include "phys/protocol/builder.h"
#include "phys/protocol/convert.h"
#include "phys/protocol/decoder.h"
#include "phys/server/core.h"

namespace phys::server::test {

inline constexpr uint64_t kClient = 0xC11E47;

inline CoreConfig testConfig() {
  CoreConfig c;
  c.presetsFile = std::string(PHYS_SOURCE_DIR) + "/configs/presets.json";
  c.scenesDir = std::string(PHYS_SOURCE_DIR) + "/configs/scenes";
  c.snapshotDir = (std::filesystem::temp_directory_path() /
                   ("physd_test_snapshots_" + std::to_string(getpid())))
                      .string();
  c.threads = 1;
  c.framesWithoutSubscribers = true;  // no DDS here: frames are read from the queue
  return c;
}

using phys::test::boxBody;
using phys::test::groundBody;

/// A core started as physd starts one: presets loaded, its kept worlds restored (notes: what
/// restoring said).
inline std::unique_ptr<ServerCore> startedCore(const CoreConfig& cfg,
                                               std::vector<std::string>* notes = nullptr) {
  auto core = std::make_unique<ServerCore>(cfg);
  EXPECT_TRUE(core->init().ok());
  std::vector<std::string> local;
  Status s = core->restoreWorlds(notes ? notes : &local);
  EXPECT_TRUE(s.ok()) << s.message;
  return core;
}

/// A decoded reply that owns its bytes.
using Reply = protocol::Decoded<wire::Reply>;

inline Reply decode(protocol::Bytes b) {
  Reply r = protocol::decodeReply(std::move(b));
  EXPECT_TRUE(r.ok()) << r.status.message;
  return r;
}

inline std::string message(const Reply& r) {
  return r.ok() && r->message() ? r->message()->str() : r.status.message;
}

inline std::vector<uint64_t> bodyIds(const Reply& r) {
  std::vector<uint64_t> v;
  if (auto* ids = r->result_as_Ids())
    if (ids->bodies())
      for (uint64_t id : *ids->bodies()) v.push_back(id);
  return v;
}
inline std::vector<uint64_t> jointIds(const Reply& r) {
  std::vector<uint64_t> v;
  if (auto* ids = r->result_as_Ids())
    if (ids->joints())
      for (uint64_t id : *ids->joints()) v.push_back(id);
  return v;
}

/// A command as the reader thread queues it (ServerCore::submit): envelope key and seq, the
/// payload decoded.
inline Incoming queuedCommand(uint64_t client, uint64_t seq, protocol::CommandBuilder& b,
                              uint32_t world) {
  Incoming in;
  in.envelopeKey = client;
  in.envelopeSeq = seq;
  protocol::Bytes bytes = b.finish({client, seq, world});
  in.bytes = bytes.size();
  in.command = protocol::decodeCommand(std::move(bytes));
  EXPECT_TRUE(in.command.ok()) << in.command.status.message;
  return in;
}

/// A client of one core: commands applied directly (applyBytes, as the tick thread applies
/// them) or queued as the reader thread queues them (submit).
struct CoreClient {
  ServerCore* core;
  uint64_t id = kClient;
  uint64_t seq = 0;
  Reply send(protocol::CommandBuilder& b, uint32_t world) {
    ++seq;
    return decode(core->applyBytes(b.finish({id, seq, world}), id, seq));
  }
  Reply send(protocol::CommandBuilder&& b, uint32_t world) { return send(b, world); }
  void submit(protocol::CommandBuilder& b, uint32_t world) {
    core->submit(queuedCommand(id, ++seq, b, world));
  }
  void submit(protocol::CommandBuilder&& b, uint32_t world) { submit(b, world); }
};

/// The replies the core has pushed so far, decoded, in order (other queued items dropped).
inline std::vector<Reply> takeReplies(ServerCore& core) {
  std::vector<Reply> out;
  for (;;) {
    PublishQueue::Item item = core.out().pop(std::chrono::milliseconds(0));
    if (!item.reliable && !item.frame) break;
    if (item.reliable && item.reliable->type == ReliableMessage::Type::Reply)
      out.push_back(decode(item.reliable->chunks.at(0)));
  }
  return out;
}

/// A size field of /proc/<pid>/status ("VmRSS", "VmHWM"), bytes; -1 when absent. pid 0: this
/// process.
inline int64_t procStatusBytes(pid_t pid, const char* field) {
  std::ifstream f("/proc/" + (pid ? std::to_string(pid) : std::string("self")) + "/status");
  std::string line;
  const std::string key = std::string(field) + ":";
  while (std::getline(f, line))
    if (line.rfind(key, 0) == 0) return std::stoll(line.substr(key.size())) * 1024;
  return -1;
}
/// Resets the process's peak resident size (VmHWM); false where the kernel does not let us
/// (then peaks are not checked). pid 0: this process.
inline bool resetPeakMemory(pid_t pid) {
  std::ofstream f("/proc/" + (pid ? std::to_string(pid) : std::string("self")) + "/clear_refs");
  f << "5";
  f.flush();
  return bool(f);
}

}  // namespace phys::server::test
