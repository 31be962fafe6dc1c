// Durable worlds: one directory per world under `[paths] data`, holding a checkpoint (the
// world's whole state at one tick) and a journal of what happened since (the commands
// applied, and marks of the ticks reached). No DDS, no engine: bytes, files and checksums.
//
//   <data>/next_world_id            the next world id to give (decimal text)
//   <data>/worlds/<id>/checkpoint   Checkpoint (below), replaced atomically
//   <data>/worlds/<id>/journal-<g>  the records after checkpoint generation g
//   <data>/damaged/world-<id>-<n>/  files set aside when the operator accepted a loss
//
// Every file is written aside (`*.partial`), fsync'ed and renamed over the old one, and the
// directory fsync'ed, so a crash leaves the old file or the new one, never a torn one. The
// journal is appended to: a record is [u32 payload bytes][u32 crc32 of what follows]
// [u64 tick][u8 kind][payload]. Its first record (checkpoint version 2) is a header naming
// the checkpoint it follows. A journal is read as far as its records are good: a bad record
// with no good record after it is a torn tail (a crash while writing it: never acknowledged),
// dropped and cut off the file; a missing journal, a wrong or missing header, or a bad record
// followed by good ones is damage (acknowledged records lost), and the world is not loaded
// unless the operator accepts the loss (WorldStore::load, acceptLoss).
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
  uint32_t version = 0;     ///< the file's format version (read; writing writes the current)
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
  /// Empty since issue 40 (the engine state carries every definition); before, a portable
  /// protocol Snapshot of the bodies' and joints' definitions, which a restore now skips.
  std::vector<uint8_t> defs;
};

/// One journal record.
struct JournalRecord {
  enum class Kind : uint8_t {
    Command = 1,  ///< payload: the command's exact bytes, applied at `tick`
    /// The world stopped stepping at `tick` (a Step ended early, a step failed; ends a Lease);
    /// payload: u8 run mode, f64 rate (Hz)
    Mark = 2,
    /// Written before the steps it allows: from `tick` the world may step up to the tick in
    /// the payload (u64), and a restart steps it there unless a later Mark or Pause says
    /// where it stopped.
    Lease = 3,
    /// A journal's first record: `tick` is the checkpoint's; payload u32 world id, u64
    /// generation, u32 the checkpoint file's CRC-32. Never returned by load().
    Header = 4,
  };
  uint64_t tick = 0;
  Kind kind = Kind::Command;
  std::vector<uint8_t> payload;
};
constexpr size_t kJournalRecordHeader = 17;  ///< bytes a record adds to its payload

/// What reading a world's journal found (scanJournal).
struct JournalScan {
  enum class State : uint8_t {
    Ok,        ///< every record good
    TornTail,  ///< the last record cut short or bad, nothing good after it: a crash mid-write
    Missing,   ///< the checkpoint's journal is not there
    Damaged,   ///< a bad record with good ones after it, or a wrong or missing header
  };
  State state = State::Ok;
  std::vector<JournalRecord> records;  ///< the good records before any damage (no header)
  uint64_t goodBytes = 0;  ///< bytes up to the end of the last good record (header included)
  uint64_t fileBytes = 0;
  uint64_t laterRecords = 0;  ///< Damaged: good records found after the damage (lost with it)
  std::string detail;         ///< a sentence on what is wrong; empty when Ok
  /// Acknowledged records would be lost by loading only the good ones.
  bool lossy() const { return state == State::Missing || state == State::Damaged; }
};

/// What WorldStore::load found beside the checkpoint and records.
struct LoadReport {
  /// Why loading would lose acknowledged records (the journal is missing or damaged before
  /// its end); empty when it would not. The world is then not loaded unless acceptLoss.
  std::string damage;
  /// acceptLoss: where the damaged files were set aside (copies), for the operator.
  std::string setAside;
  uint64_t tornBytes = 0;  ///< a torn tail's bytes, cut off
};

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
  /// Makes what was appended durable (fdatasync); nothing to do when nothing was. On failure
  /// the journal is cut back to what the last good sync made durable, so that a record that
  /// was refused can never reach the disk later and be replayed.
  Status sync();
  bool dirty() const { return dirty_; }
  uint64_t generation() const { return generation_; }
  uint64_t journalBytes() const { return size_; }
  uint64_t journalRecords() const { return records_; }
  /// Removes the world's directory (renamed away first, so a crash midway leaves no world).
  Status remove();

  /// Reads a world's directory: its checkpoint and the journal's good records; opens the
  /// journal for appending after the last good record (a torn tail is cut off). `notes` gets
  /// a sentence for anything dropped. A missing or damaged journal (JournalScan::lossy) is an
  /// IncorrectState error naming the damage (report->damage), and nothing in the directory
  /// changes, unless acceptLoss: then the checkpoint and the journal are first copied to
  /// `<data>/damaged/world-<id>-<n>/` (report->setAside; if that fails, the error), and the
  /// world loads from the good records as after a torn tail.
  Status load(Checkpoint* checkpoint, std::vector<JournalRecord>* records,
              std::vector<std::string>* notes, LoadReport* report = nullptr,
              bool acceptLoss = false);

 private:
  /// Opens journal-<generation> for appending after goodSize bytes (cut there); a new empty
  /// journal of a version 2 checkpoint gets its header (checkpointCrc) first.
  Status openJournal(uint64_t generation, uint64_t goodSize, bool header = false,
                     uint64_t headerTick = 0, uint32_t worldId = 0, uint32_t checkpointCrc = 0);
  std::string journalPath(uint64_t generation) const;
  std::string dir_;
  int fd_ = -1;  ///< the open journal
  uint64_t generation_ = 0;
  uint64_t size_ = 0;  ///< bytes of good records in the journal
  uint64_t records_ = 0;
  uint64_t syncedSize_ = 0, syncedRecords_ = 0;  ///< what the last good sync made durable
  bool dirty_ = false;
};

/// Reads a world's checkpoint file (read only), and the CRC-32 its journal's header names.
Status readCheckpoint(const std::string& worldDir, Checkpoint* checkpoint, uint32_t* crc);

/// Reads a journal file (read only) as load() would, against the checkpoint it follows.
JournalScan scanJournal(const std::string& path, const CheckpointMeta& meta,
                        uint32_t checkpointCrc);

/// Copies a world's files (its checkpoint and journals, `<data>/worlds/<id>/`) to a new
/// `<data>/damaged/world-<id>-<n>/` with a note saying why, fsync'ed; `moveWhole`: the
/// directory is renamed there instead (a world dropped). Returns where in *where.
Status setAside(const std::string& worldDir, const std::string& why, bool moveWhole,
                std::string* where);

/// A world directory that a crash left in the middle of CreateWorld (never acknowledged): no
/// checkpoint, and nothing but its first journal (a header at most) and files written aside.
bool unfinishedCreate(const std::string& worldDir);

/// `physd --verify DATA`: every world's files under a data directory, read only (nothing is
/// cut, moved or written): a line per world and per file, appended to *text. True when no
/// world has lost acknowledged data (an unreadable checkpoint, a missing or damaged journal).
bool verifyDataDir(const std::string& data, std::string* text);

/// Writes a small file atomically (aside, fsync, rename, fsync of the directory).
Status writeFileAtomically(const std::string& path, std::span<const uint8_t> bytes);
/// The checkpoint's file form and back (with its magic, version and checksum).
std::vector<uint8_t> encodeCheckpoint(const Checkpoint& checkpoint);
Status decodeCheckpoint(std::span<const uint8_t> bytes, Checkpoint* out);

}  // namespace phys::server
