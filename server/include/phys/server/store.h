// Durable worlds: one directory per world under `[paths] data`, holding a checkpoint (the
// world's whole state at one tick) and a journal of what happened since (the commands
// applied, and marks of the ticks reached). No DDS, no engine: bytes, files and checksums.
//
//   <data>/next_world_id            the next world id to give (decimal text)
//   <data>/worlds/<id>/checkpoint   Checkpoint (below), replaced atomically
//   <data>/worlds/<id>/journal-<g>  the records after checkpoint generation g
//
// Every file is written aside (`*.partial`), fsync'ed and renamed over the old one, and the
// directory fsync'ed, so a crash leaves the old file or the new one, never a torn one. The
// journal is appended to: a record is [u32 payload bytes][u32 crc32 of what follows]
// [u64 tick][u8 kind][payload]; a tail cut short by a crash or corrupted fails its length or
// checksum and is dropped (and cut off the file) when the world is loaded.
#pragma once

#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "phys/protocol/limits.h"
#include "phys/protocol/status.h"

namespace phys::server {

using protocol::Status;

/// What a checkpoint keeps beside the engine's snapshot: the server's view of the world.
struct CheckpointMeta {
  uint64_t generation = 0;  ///< the journal that follows it is journal-<generation>
  uint32_t worldId = 0;
  std::string name, preset, backend;
  uint64_t tick = 0, revision = 0;
  uint8_t mode = 0;  ///< RunMode
  double rateHz = 60;
  uint64_t owner = 0;  ///< access (ServerWorld::owner, editors, shared)
  std::vector<uint64_t> editors;
  bool shared = false;
  bool ownerProven = false;  ///< ServerWorld::ownerProven
};

struct Checkpoint {
  CheckpointMeta meta;
  std::vector<uint8_t> engine;  ///< phys::World::saveSnapshot
  /// The definitions bodies and joints were made from (names, damping, masses as given):
  /// a portable protocol Snapshot (bodies and joints with their ids, no engine state).
  std::vector<uint8_t> defs;
};

/// One journal record.
struct JournalRecord {
  enum class Kind : uint8_t {
    Command = 1,  ///< payload: the command's exact bytes, applied at `tick`
    Mark = 2,     ///< the world reached `tick` (steps); payload: u8 run mode, f64 rate (Hz)
  };
  uint64_t tick = 0;
  Kind kind = Kind::Command;
  std::vector<uint8_t> payload;
};
constexpr size_t kJournalRecordHeader = 17;  ///< bytes a record adds to its payload

/// A world's directory: its checkpoint and the open journal. Not thread-safe (the tick
/// thread owns it).
class WorldStore {
 public:
  explicit WorldStore(std::string dir) : dir_(std::move(dir)) {}
  ~WorldStore();
  WorldStore(const WorldStore&) = delete;
  WorldStore& operator=(const WorldStore&) = delete;

  const std::string& dir() const { return dir_; }
  /// Writes a checkpoint as generation generation()+1 (atomically), starts its empty journal
  /// and removes the older checkpoint's journal. On failure nothing changes: the old
  /// checkpoint and journal stay in use.
  Status writeCheckpoint(Checkpoint checkpoint);
  /// Appends a record (written, not yet synced). On failure the journal is cut back to the
  /// record before, so it never holds a torn record the next append would hide.
  Status append(uint64_t tick, JournalRecord::Kind kind, std::span<const uint8_t> payload);
  /// Makes what was appended durable (fdatasync); nothing to do when nothing was.
  Status sync();
  bool dirty() const { return dirty_; }
  uint64_t generation() const { return generation_; }
  uint64_t journalBytes() const { return size_; }
  uint64_t journalRecords() const { return records_; }
  /// Removes the world's directory (renamed away first, so a crash midway leaves no world).
  Status remove();

  /// Reads a world's directory: its checkpoint and the journal's good records; opens the
  /// journal for appending after the last good record (a torn or corrupt tail is cut off).
  /// `notes` gets a sentence for anything dropped.
  Status load(Checkpoint* checkpoint, std::vector<JournalRecord>* records,
              std::vector<std::string>* notes);

 private:
  Status openJournal(uint64_t generation, uint64_t goodSize);
  std::string journalPath(uint64_t generation) const;
  std::string dir_;
  int fd_ = -1;  ///< the open journal
  uint64_t generation_ = 0;
  uint64_t size_ = 0;  ///< bytes of good records in the journal
  uint64_t records_ = 0;
  bool dirty_ = false;
};

/// Writes a small file atomically (aside, fsync, rename, fsync of the directory).
Status writeFileAtomically(const std::string& path, std::span<const uint8_t> bytes);
/// The checkpoint's file form and back (with its magic, version and checksum).
std::vector<uint8_t> encodeCheckpoint(const Checkpoint& checkpoint);
Status decodeCheckpoint(std::span<const uint8_t> bytes, Checkpoint* out);

}  // namespace phys::server
