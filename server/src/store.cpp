// Durable worlds' files: checkpoints written atomically, journals appended and synced
// (store.h describes the layout).
#include "phys/server/store.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>
#include <zlib.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <filesystem>

namespace phys::server {

namespace fs = std::filesystem;
using Code = protocol::Code;

namespace {

constexpr char kCheckpointMagic[8] = {'P', 'H', 'Y', 'S', 'C', 'K', 'P', 'T'};
/// 2: the journal begins with a header record naming the checkpoint (world, generation,
/// CRC). Version 1 checkpoints (no header) are still read; the next checkpoint is version 2.
constexpr uint32_t kCheckpointVersion = 2;
/// A record's payload bound (a command is at most a message; a mark is 9 bytes): a length
/// past it is corruption, not a record to allocate for.
constexpr uint32_t kMaxRecordPayload = 1u << 30;

/// Why a file operation failed: ENOSPC, EDQUOT and EFBIG (a full disk, a quota, a file size
/// limit) are ResourceExhausted, anything else Internal.
Status ioError(const std::string& what, int err) {
  const bool full = err == ENOSPC || err == EDQUOT || err == EFBIG;
  return Status::Error(full ? Code::ResourceExhausted : Code::Internal,
                       what + ": " + std::strerror(err) + " (nothing was stored)");
}

uint32_t crc(std::span<const uint8_t> bytes, uint32_t seed = 0) {
  uLong c = seed ? seed : crc32(0L, Z_NULL, 0);
  // zlib takes uInt lengths: feed large buffers in pieces.
  size_t done = 0;
  while (done < bytes.size()) {
    const size_t n = std::min<size_t>(bytes.size() - done, 1u << 30);
    c = crc32(c, bytes.data() + done, uInt(n));
    done += n;
  }
  return uint32_t(c);
}

/// Writes all of bytes; errno-style result (0: written).
int writeAll(int fd, const uint8_t* p, size_t n) {
  while (n > 0) {
    ssize_t w = ::write(fd, p, n);
    if (w < 0) {
      if (errno == EINTR) continue;
      return errno;
    }
    if (w == 0) return EIO;
    p += w;
    n -= size_t(w);
  }
  return 0;
}

int syncDir(const std::string& dir) {
  int fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd < 0) return errno;
  int r = ::fsync(fd) == 0 ? 0 : errno;
  ::close(fd);
  return r;
}

/// Reads a whole file; false (and errno in *err) when it cannot be opened.
bool readFile(const std::string& path, std::vector<uint8_t>* out, int* err = nullptr) {
  int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) {
    if (err) *err = errno;
    return false;
  }
  struct stat st {};
  if (::fstat(fd, &st) != 0) {
    if (err) *err = errno;
    ::close(fd);
    return false;
  }
  out->resize(size_t(st.st_size));
  size_t done = 0;
  while (done < out->size()) {
    ssize_t r = ::read(fd, out->data() + done, out->size() - done);
    if (r < 0 && errno == EINTR) continue;
    if (r <= 0) break;
    done += size_t(r);
  }
  ::close(fd);
  out->resize(done);
  return true;
}

// Little-endian scalars and length-prefixed blobs.
struct Writer {
  std::vector<uint8_t> b;
  template <class T>
  void put(T v) {
    const auto* p = reinterpret_cast<const uint8_t*>(&v);
    b.insert(b.end(), p, p + sizeof v);
  }
  void blob(std::span<const uint8_t> s) {
    put<uint64_t>(s.size());
    b.insert(b.end(), s.begin(), s.end());
  }
  void str(const std::string& s) {
    blob(std::span<const uint8_t>(reinterpret_cast<const uint8_t*>(s.data()), s.size()));
  }
};
struct Reader {
  std::span<const uint8_t> b;
  size_t at = 0;
  bool ok = true;
  template <class T>
  T get() {
    T v{};
    if (!ok || b.size() - at < sizeof v) {
      ok = false;
      return v;
    }
    std::memcpy(&v, b.data() + at, sizeof v);
    at += sizeof v;
    return v;
  }
  std::span<const uint8_t> blob() {
    const uint64_t n = get<uint64_t>();
    if (!ok || b.size() - at < n) {
      ok = false;
      return {};
    }
    auto s = b.subspan(at, size_t(n));
    at += size_t(n);
    return s;
  }
  std::string str() {
    auto s = blob();
    return std::string(s.begin(), s.end());
  }
};

/// A journal record's bytes: [u32 payload bytes][u32 crc][u64 tick][u8 kind][payload].
std::vector<uint8_t> encodeRecord(uint64_t tick, JournalRecord::Kind kind,
                                  std::span<const uint8_t> payload) {
  std::vector<uint8_t> rec(kJournalRecordHeader + payload.size());
  const uint32_t len = uint32_t(payload.size());
  std::memcpy(rec.data(), &len, 4);
  std::memcpy(rec.data() + 8, &tick, 8);
  rec[16] = uint8_t(kind);
  if (!payload.empty()) std::memcpy(rec.data() + 17, payload.data(), payload.size());
  const uint32_t sum = crc(std::span<const uint8_t>(rec).subspan(8));
  std::memcpy(rec.data() + 4, &sum, 4);
  return rec;
}

/// The header record's payload: u32 world id, u64 generation, u32 the checkpoint's CRC.
std::vector<uint8_t> headerPayload(uint32_t worldId, uint64_t generation, uint32_t checkpointCrc) {
  std::vector<uint8_t> p(16);
  std::memcpy(p.data(), &worldId, 4);
  std::memcpy(p.data() + 4, &generation, 8);
  std::memcpy(p.data() + 12, &checkpointCrc, 4);
  return p;
}

/// The CRC a checkpoint file ends with.
uint32_t storedCrc(std::span<const uint8_t> checkpointBytes) {
  uint32_t v = 0;
  if (checkpointBytes.size() >= 4) std::memcpy(&v, checkpointBytes.data() + checkpointBytes.size() - 4, 4);
  return v;
}

/// A whole, checksummed record at `at` (kinds the journal holds after its header); its
/// length in *size. minTick: a record found by searching must not go back in time, nor
/// leap implausibly far (cheap tests before the checksum).
bool recordAt(std::span<const uint8_t> bytes, size_t at, JournalRecord* out, size_t* size,
              bool header = false, const uint64_t* minTick = nullptr) {
  if (bytes.size() < at || bytes.size() - at < kJournalRecordHeader) return false;
  uint32_t len = 0, sum = 0;
  std::memcpy(&len, bytes.data() + at, 4);
  std::memcpy(&sum, bytes.data() + at + 4, 4);
  if (len > kMaxRecordPayload || bytes.size() - at - kJournalRecordHeader < len) return false;
  const uint8_t kind = bytes[at + 16];
  const bool known = header ? kind == uint8_t(JournalRecord::Kind::Header)
                            : kind >= uint8_t(JournalRecord::Kind::Command) &&
                                  kind <= uint8_t(JournalRecord::Kind::Lease);
  if (!known) return false;
  uint64_t tick = 0;
  std::memcpy(&tick, bytes.data() + at + 8, 8);
  if (minTick && (tick < *minTick || tick - *minTick > (uint64_t(1) << 40))) return false;
  auto body = bytes.subspan(at + 8, 9 + size_t(len));
  if (crc(body) != sum) return false;
  if (out) {
    out->tick = tick;
    out->kind = JournalRecord::Kind(kind);
    out->payload.assign(body.begin() + 9, body.end());
  }
  *size = kJournalRecordHeader + len;
  return true;
}

/// Copies a file and fsyncs the copy; errno-style result.
int copyFile(const std::string& from, const std::string& to) {
  std::vector<uint8_t> bytes;
  int err = 0;
  if (!readFile(from, &bytes, &err)) return err;
  int fd = ::open(to.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) return errno;
  err = writeAll(fd, bytes.data(), bytes.size());
  if (!err && ::fsync(fd) != 0) err = errno;
  ::close(fd);
  return err;
}

/// Writes a small file (not atomically: a note) and fsyncs it; errno-style result.
int writeNote(const std::string& path, const std::string& text) {
  int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) return errno;
  int err = writeAll(fd, reinterpret_cast<const uint8_t*>(text.data()), text.size());
  if (!err && ::fsync(fd) != 0) err = errno;
  ::close(fd);
  return err;
}

}  // namespace

std::vector<uint8_t> encodeCheckpoint(const Checkpoint& c) {
  Writer w;
  w.b.reserve(c.engine.size() + c.defs.size() + 256);
  w.b.insert(w.b.end(), kCheckpointMagic, kCheckpointMagic + 8);
  w.put<uint32_t>(kCheckpointVersion);
  w.put<uint64_t>(c.meta.generation);
  w.put<uint32_t>(c.meta.worldId);
  w.str(c.meta.name);
  w.str(c.meta.preset);
  w.str(c.meta.backend);
  w.put<uint64_t>(c.meta.tick);
  w.put<uint64_t>(c.meta.revision);
  w.put<uint8_t>(c.meta.mode);
  w.put<double>(c.meta.rateHz);
  w.put<uint64_t>(c.meta.owner);
  // Access flags: bit 0 shared, bit 1 the owner proved its id (files before the second bit
  // existed hold 0 or 1 here and read the same).
  w.put<uint8_t>(uint8_t((c.meta.shared ? 1 : 0) | (c.meta.ownerProven ? 2 : 0)));
  w.put<uint32_t>(uint32_t(c.meta.editors.size()));
  for (uint64_t e : c.meta.editors) w.put<uint64_t>(e);
  w.blob(c.engine);
  w.blob(c.defs);
  w.put<uint32_t>(crc(w.b));
  return std::move(w.b);
}

Status decodeCheckpoint(std::span<const uint8_t> bytes, Checkpoint* out) {
  if (bytes.size() < 12 + 4 || std::memcmp(bytes.data(), kCheckpointMagic, 8) != 0)
    return Status::Error(Code::Malformed, "not a checkpoint (no PHYSCKPT magic)");
  uint32_t stored = 0;
  std::memcpy(&stored, bytes.data() + bytes.size() - 4, 4);
  if (crc(bytes.first(bytes.size() - 4)) != stored)
    return Status::Error(Code::Malformed, "checkpoint checksum mismatch (corrupt file)");
  Reader r{bytes.first(bytes.size() - 4), 8};
  const uint32_t version = r.get<uint32_t>();
  if (r.ok && (version < 1 || version > kCheckpointVersion))
    return Status::Error(Code::Unsupported, "checkpoint version " + std::to_string(version) +
                                                "; this physd reads " +
                                                std::to_string(kCheckpointVersion));
  Checkpoint c;
  c.meta.version = version;
  c.meta.generation = r.get<uint64_t>();
  c.meta.worldId = r.get<uint32_t>();
  c.meta.name = r.str();
  c.meta.preset = r.str();
  c.meta.backend = r.str();
  c.meta.tick = r.get<uint64_t>();
  c.meta.revision = r.get<uint64_t>();
  c.meta.mode = r.get<uint8_t>();
  c.meta.rateHz = r.get<double>();
  c.meta.owner = r.get<uint64_t>();
  const uint8_t access = r.get<uint8_t>();
  c.meta.shared = (access & 1) != 0;
  c.meta.ownerProven = (access & 2) != 0;
  const uint32_t editors = r.get<uint32_t>();
  for (uint32_t i = 0; r.ok && i < editors && i <= protocol::kMaxEditors; ++i)
    c.meta.editors.push_back(r.get<uint64_t>());
  auto engine = r.blob();
  auto defs = r.blob();
  if (!r.ok || r.at != r.b.size())
    return Status::Error(Code::Malformed, "checkpoint truncated or with trailing bytes");
  c.engine.assign(engine.begin(), engine.end());
  c.defs.assign(defs.begin(), defs.end());
  *out = std::move(c);
  return Status::Ok();
}

Status writeFileAtomically(const std::string& path, std::span<const uint8_t> bytes) {
  const std::string tmp = path + ".partial";
  int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) return ioError("cannot create " + tmp, errno);
  int err = writeAll(fd, bytes.data(), bytes.size());
  if (!err && ::fsync(fd) != 0) err = errno;
  ::close(fd);
  if (!err && ::rename(tmp.c_str(), path.c_str()) != 0) err = errno;
  if (err) {
    ::unlink(tmp.c_str());
    return ioError("cannot write " + path, err);
  }
  if (int e = syncDir(fs::path(path).parent_path().string())) return ioError("fsync of " + path, e);
  return Status::Ok();
}

WorldStore::~WorldStore() {
  if (fd_ >= 0) ::close(fd_);
}

std::string WorldStore::journalPath(uint64_t generation) const {
  return dir_ + "/journal-" + std::to_string(generation);
}

Status WorldStore::openJournal(uint64_t generation, uint64_t goodSize, bool header,
                               uint64_t headerTick, uint32_t worldId, uint32_t checkpointCrc) {
  const std::string path = journalPath(generation);
  int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_CLOEXEC, 0644);
  if (fd < 0) return ioError("cannot open " + path, errno);
  // Past the last good record: cut (a torn tail), and append from there.
  if (::ftruncate(fd, off_t(goodSize)) != 0 || ::lseek(fd, off_t(goodSize), SEEK_SET) < 0) {
    const int e = errno;
    ::close(fd);
    return ioError("cannot prepare " + path, e);
  }
  if (header && goodSize == 0) {
    // A journal made again (an accepted loss): its header first, as writeCheckpoint writes it.
    const auto rec = encodeRecord(headerTick, JournalRecord::Kind::Header,
                                  headerPayload(worldId, generation, checkpointCrc));
    if (int e = writeAll(fd, rec.data(), rec.size())) {
      ::close(fd);
      return ioError("cannot write the header of " + path, e);
    }
    goodSize = rec.size();
  }
  // What is there now is what a restart reads: durable before anything is appended to it.
  if (::fdatasync(fd) != 0) {
    const int e = errno;
    ::close(fd);
    return ioError("cannot sync " + path, e);
  }
  if (fd_ >= 0) ::close(fd_);
  fd_ = fd;
  generation_ = generation;
  size_ = syncedSize_ = goodSize;
  records_ = syncedRecords_ = 0;
  dirty_ = false;
  return Status::Ok();
}

Status WorldStore::writeCheckpoint(Checkpoint c) {
  std::error_code ec;
  fs::create_directories(dir_, ec);
  if (ec) return ioError("cannot create " + dir_, ec.value());
  // Everything appended so far goes first: the checkpoint replaces the journal only once it
  // is on disk, and until then the old pair must hold whatever was acknowledged.
  Status s = sync();
  if (!s.ok()) return s;
  const uint64_t next = generation_ + 1;
  c.meta.generation = next;
  const std::vector<uint8_t> bytes = encodeCheckpoint(c);
  // The new journal exists, with its header naming this checkpoint, and is on disk before
  // the checkpoint that names it: a checkpoint never comes without its journal.
  {
    const std::string path = journalPath(next);
    int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    if (fd < 0) return ioError("cannot create " + path, errno);
    const auto rec = encodeRecord(c.meta.tick, JournalRecord::Kind::Header,
                                  headerPayload(c.meta.worldId, next, storedCrc(bytes)));
    int err = writeAll(fd, rec.data(), rec.size());
    if (!err && ::fdatasync(fd) != 0) err = errno;
    ::close(fd);
    if (err) {
      ::unlink(path.c_str());
      return ioError("cannot write " + path, err);
    }
  }
  s = writeFileAtomically(dir_ + "/checkpoint", bytes);
  if (!s.ok()) {
    ::unlink(journalPath(next).c_str());
    return s;
  }
  const uint64_t old = generation_;
  s = openJournal(next, kJournalRecordHeader + 16);  // after its header
  if (!s.ok()) return s;  // the checkpoint stands; appends fail until a new journal opens
  if (old > 0) ::unlink(journalPath(old).c_str());
  return Status::Ok();
}

Status WorldStore::append(uint64_t tick, JournalRecord::Kind kind,
                          std::span<const uint8_t> payload) {
  if (fd_ < 0) return Status::Error(Code::Internal, "the journal of " + dir_ + " is not open");
  const std::vector<uint8_t> rec = encodeRecord(tick, kind, payload);
  if (int e = writeAll(fd_, rec.data(), rec.size())) {
    // Cut back to the last whole record: a later append must not follow a torn one.
    if (::ftruncate(fd_, off_t(size_)) != 0 || ::lseek(fd_, off_t(size_), SEEK_SET) < 0) {
      ::close(fd_);
      fd_ = -1;
    }
    return ioError("cannot append to " + journalPath(generation_), e);
  }
  size_ += rec.size();
  ++records_;
  dirty_ = true;
  return Status::Ok();
}

Status WorldStore::sync() {
  if (!dirty_) return Status::Ok();
  const int e = fd_ < 0 ? EBADF : ::fdatasync(fd_) == 0 ? 0 : errno;
  if (e) {
    // What this sync was to make durable was refused (its commands answered with the error):
    // it must never reach the disk later, where a restart would replay it.
    if (fd_ >= 0) {
      if (::ftruncate(fd_, off_t(syncedSize_)) == 0 &&
          ::lseek(fd_, off_t(syncedSize_), SEEK_SET) >= 0) {
        (void)::fdatasync(fd_);
        size_ = syncedSize_;
        records_ = syncedRecords_;
        dirty_ = false;
      } else {
        ::close(fd_);
        fd_ = -1;
      }
    }
    return ioError("cannot sync " + journalPath(generation_), e);
  }
  syncedSize_ = size_;
  syncedRecords_ = records_;
  dirty_ = false;
  return Status::Ok();
}

Status WorldStore::remove() {
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
  std::error_code ec;
  const std::string gone = dir_ + ".removed";
  fs::remove_all(gone, ec);
  fs::rename(dir_, gone, ec);
  if (ec && fs::exists(dir_)) return ioError("cannot remove " + dir_, ec.value());
  syncDir(fs::path(dir_).parent_path().string());
  fs::remove_all(gone, ec);
  return Status::Ok();
}

JournalScan scanJournal(const std::string& path, const CheckpointMeta& meta,
                        uint32_t checkpointCrc) {
  JournalScan scan;
  const std::string name = fs::path(path).filename().string();
  std::vector<uint8_t> bytes;
  int err = 0;
  if (!readFile(path, &bytes, &err)) {
    scan.state = err == ENOENT ? JournalScan::State::Missing : JournalScan::State::Damaged;
    scan.detail = err == ENOENT
                      ? name + " is missing: the checkpoint (tick " + std::to_string(meta.tick) +
                            ") names it, and whatever was acknowledged after that tick was in it"
                      : name + " cannot be read: " + std::strerror(err);
    return scan;
  }
  scan.fileBytes = bytes.size();
  const std::span<const uint8_t> all(bytes);
  size_t at = 0, n = 0;
  if (meta.version >= 2) {
    // The header ties the journal to its checkpoint: without it the records cannot be
    // trusted to follow this checkpoint, so none is used.
    JournalRecord h;
    if (!recordAt(all, 0, &h, &n, /*header=*/true)) {
      scan.state = JournalScan::State::Damaged;
      scan.detail = name + (bytes.empty() ? " is empty" : " does not begin with a valid header") +
                    " (" + std::to_string(bytes.size()) +
                    " bytes): its records cannot be tied to the checkpoint";
      return scan;
    }
    uint32_t world = 0, crcv = 0;
    uint64_t generation = 0;
    if (h.payload.size() == 16) {
      std::memcpy(&world, h.payload.data(), 4);
      std::memcpy(&generation, h.payload.data() + 4, 8);
      std::memcpy(&crcv, h.payload.data() + 12, 4);
    }
    if (h.payload.size() != 16 || world != meta.worldId || generation != meta.generation ||
        crcv != checkpointCrc) {
      scan.state = JournalScan::State::Damaged;
      scan.detail = name + "'s header names world " + std::to_string(world) + " generation " +
                    std::to_string(generation) +
                    " and another checkpoint: it does not follow this checkpoint (world " +
                    std::to_string(meta.worldId) + ", generation " +
                    std::to_string(meta.generation) + ")";
      return scan;
    }
    at = n;
  }
  JournalRecord r;
  while (recordAt(all, at, &r, &n)) {
    scan.records.push_back(std::move(r));
    at += n;
  }
  scan.goodBytes = at;
  if (at == bytes.size()) return scan;
  // A bad record. If good records follow it, it is damage in the middle (they were written,
  // and synced, after it: acknowledged); if nothing good follows, it is the record a crash
  // interrupted, never acknowledged.
  uint64_t minTick = scan.records.empty() ? meta.tick : scan.records.back().tick;
  for (size_t off = at + 1; off + kJournalRecordHeader <= bytes.size(); ++off) {
    if (!recordAt(all, off, nullptr, &n, false, &minTick)) continue;
    for (size_t p = off; recordAt(all, p, nullptr, &n); p += n) ++scan.laterRecords;
    scan.state = JournalScan::State::Damaged;
    scan.detail = name + ": bytes " + std::to_string(at) + " to " + std::to_string(off) +
                  " (after record " + std::to_string(scan.records.size()) +
                  ") are damaged, and " + std::to_string(scan.laterRecords) +
                  " good records follow them: acknowledged commands would be lost";
    return scan;
  }
  scan.state = JournalScan::State::TornTail;
  scan.detail = name + ": " + std::to_string(bytes.size() - at) + " bytes after record " +
                std::to_string(scan.records.size()) +
                " are torn or corrupt, with nothing good after them (a crash while writing: "
                "never acknowledged); dropped: the world is restored up to the last good record";
  return scan;
}

Status setAside(const std::string& worldDir, const std::string& why, bool moveWhole,
                std::string* where) {
  const fs::path dir(worldDir);
  const fs::path base = dir.parent_path().parent_path() / "damaged";
  std::error_code ec;
  fs::create_directories(base, ec);
  if (ec) return ioError("cannot create " + base.string(), ec.value());
  fs::path dest;
  for (int n = 1;; ++n) {
    dest = base / ("world-" + dir.filename().string() + "-" + std::to_string(n));
    if (!fs::exists(dest, ec)) break;
  }
  const std::string note = why + "\n\nSet aside by physd when the operator accepted the loss "
                           "(--accept-loss); physd never deletes this directory.\n";
  if (moveWhole) {
    fs::rename(dir, dest, ec);
    if (ec) return ioError("cannot move " + worldDir + " to " + dest.string(), ec.value());
    syncDir(base.string());
    syncDir(dir.parent_path().string());
    writeNote((dest / "DAMAGE.txt").string(), note);  // the files count; the note may not fit
    *where = dest.string();
    return Status::Ok();
  }
  fs::create_directory(dest, ec);
  if (ec) return ioError("cannot create " + dest.string(), ec.value());
  for (const auto& e : fs::directory_iterator(dir, ec)) {
    const std::string n = e.path().filename().string();
    if (!e.is_regular_file() || !(n == "checkpoint" || n.rfind("journal-", 0) == 0)) continue;
    if (int err = copyFile(e.path().string(), (dest / n).string()))
      return ioError("cannot copy " + e.path().string() + " to " + dest.string(), err);
  }
  if (ec) return ioError("cannot list " + worldDir, ec.value());
  if (int err = writeNote((dest / "DAMAGE.txt").string(), note))
    return ioError("cannot write " + (dest / "DAMAGE.txt").string(), err);
  if (int err = syncDir(dest.string())) return ioError("fsync of " + dest.string(), err);
  syncDir(base.string());
  *where = dest.string();
  return Status::Ok();
}

Status WorldStore::load(Checkpoint* checkpoint, std::vector<JournalRecord>* records,
                        std::vector<std::string>* notes, LoadReport* report, bool acceptLoss) {
  LoadReport local;
  if (!report) report = &local;
  *report = LoadReport();
  std::vector<uint8_t> bytes;
  if (!readFile(dir_ + "/checkpoint", &bytes))
    return Status::Error(Code::NotFound, dir_ + " has no checkpoint");
  Status s = decodeCheckpoint(bytes, checkpoint);
  if (!s.ok()) return Status::Error(s.code, dir_ + "/checkpoint: " + s.message);
  const uint32_t checkpointCrc = storedCrc(bytes);
  bytes.clear();
  const CheckpointMeta& meta = checkpoint->meta;
  const uint64_t g = meta.generation;
  JournalScan scan = scanJournal(journalPath(g), meta, checkpointCrc);
  if (scan.lossy()) {
    report->damage = dir_ + "/" + scan.detail;
    if (!acceptLoss) return Status::Error(Code::IncorrectState, report->damage);
    // The operator accepts the loss: the files as they are go aside first (copies, so that
    // nothing is lost if this is interrupted), then the world loads from what is good.
    s = setAside(dir_, report->damage, false, &report->setAside);
    if (!s.ok())
      return Status::Error(s.code, report->damage +
                                       "; the loss was accepted, but the damaged files could "
                                       "not be set aside (" + s.message + "), so nothing was changed");
    notes->push_back(report->damage + "; the loss is accepted: the files are kept in " +
                     report->setAside + ", and the world is restored from the " +
                     std::to_string(scan.records.size()) + " good records before the damage");
  } else if (scan.state == JournalScan::State::TornTail) {
    report->tornBytes = scan.fileBytes - scan.goodBytes;
    notes->push_back(dir_ + "/" + scan.detail);
  }
  *records = std::move(scan.records);
  // Journals of other generations are left from a checkpoint that a crash interrupted.
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(dir_, ec)) {
    const std::string n = e.path().filename().string();
    if ((n.rfind("journal-", 0) == 0 && n != "journal-" + std::to_string(g)) ||
        n.ends_with(".partial"))
      fs::remove(e.path(), ec);
  }
  s = openJournal(g, scan.goodBytes, meta.version >= 2, meta.tick, meta.worldId, checkpointCrc);
  records_ = syncedRecords_ = records->size();
  return s;
}

namespace {

const char* stateWord(JournalScan::State s) {
  switch (s) {
    case JournalScan::State::Ok: return "ok";
    case JournalScan::State::TornTail: return "torn tail";
    case JournalScan::State::Missing: return "MISSING";
    case JournalScan::State::Damaged: return "DAMAGED";
  }
  return "?";
}

}  // namespace

bool unfinishedCreate(const std::string& dir) {
  std::error_code ec;
  if (fs::exists(dir + "/checkpoint", ec)) return false;
  for (const auto& e : fs::directory_iterator(dir, ec)) {
    const std::string n = e.path().filename().string();
    if (n.ends_with(".partial")) continue;
    if (n == "journal-1" && e.is_regular_file() && e.file_size(ec) <= kJournalRecordHeader + 16)
      continue;
    return false;
  }
  return !ec;
}

bool verifyDataDir(const std::string& data, std::string* text) {
  std::error_code ec;
  const fs::path worlds = fs::path(data) / "worlds";
  if (!fs::is_directory(data, ec)) {
    *text += data + ": not a directory\n";
    return false;
  }
  std::vector<std::pair<uint64_t, fs::path>> dirs;
  for (const auto& e : fs::directory_iterator(worlds, ec)) {
    const std::string n = e.path().filename().string();
    char* end = nullptr;
    const unsigned long long id = std::strtoull(n.c_str(), &end, 10);
    if (e.is_directory() && end && *end == 0 && id > 0) dirs.emplace_back(id, e.path());
  }
  std::sort(dirs.begin(), dirs.end());
  bool ok = true;
  size_t bad = 0;
  for (const auto& [id, dir] : dirs) {
    std::string line = "world " + std::to_string(id);
    std::vector<uint8_t> bytes;
    Checkpoint c;
    bool worldOk = true;
    const bool have = readFile((dir / "checkpoint").string(), &bytes);
    if (!have && unfinishedCreate(dir.string())) {
      *text += line + ": an unfinished CreateWorld (no checkpoint; never acknowledged), "
                      "removed at start-up\n";
      continue;
    }
    if (!have) {
      line += ": checkpoint MISSING";
      worldOk = false;
    } else if (Status s = decodeCheckpoint(bytes, &c); !s.ok()) {
      line += ": checkpoint DAMAGED (" + s.message + ")";
      worldOk = false;
    } else {
      line += " '" + c.meta.name + "': checkpoint ok (version " + std::to_string(c.meta.version) +
              ", generation " + std::to_string(c.meta.generation) + ", tick " +
              std::to_string(c.meta.tick) + ")";
      const JournalScan scan = scanJournal(
          (dir / ("journal-" + std::to_string(c.meta.generation))).string(), c.meta,
          storedCrc(bytes));
      line += "; journal-" + std::to_string(c.meta.generation) + " " + stateWord(scan.state);
      if (scan.state != JournalScan::State::Missing)
        line += ": " + std::to_string(scan.records.size()) + " good records" +
                (scan.records.empty() ? "" : ", the last at tick " +
                                                 std::to_string(scan.records.back().tick)) +
                ", " + std::to_string(scan.fileBytes) + " bytes";
      if (!scan.detail.empty()) line += "\n    " + scan.detail;
      worldOk = !scan.lossy();
    }
    for (const auto& e : fs::directory_iterator(dir, ec)) {
      const std::string n = e.path().filename().string();
      if (n == "checkpoint" ||
          (c.meta.generation > 0 && n == "journal-" + std::to_string(c.meta.generation)))
        continue;
      if (n.rfind("journal-", 0) == 0 || n.ends_with(".partial"))
        line += "\n    also: " + n + " (" + std::to_string(e.is_regular_file() ? e.file_size(ec) : 0) +
                " bytes; left by an interrupted checkpoint" +
                (worldOk ? ", removed at start-up)" : ")");
    }
    if (!worldOk) {
      ok = false;
      ++bad;
      line += "\n    not restored at start-up; physd --accept-loss " + std::to_string(id) +
              " restores what is good and keeps these files under " + data + "/damaged/";
    }
    *text += line + "\n";
  }
  std::vector<std::string> aside;
  for (const auto& e : fs::directory_iterator(fs::path(data) / "damaged", ec))
    aside.push_back(e.path().string());
  std::sort(aside.begin(), aside.end());
  for (const std::string& a : aside) *text += "set aside earlier: " + a + "\n";
  *text += std::to_string(dirs.size()) + " world(s), " + std::to_string(bad) +
           (bad == 1 ? " has" : " have") + " lost acknowledged data\n";
  return ok;
}

Status readCheckpoint(const std::string& worldDir, Checkpoint* checkpoint, uint32_t* crc) {
  std::vector<uint8_t> bytes;
  if (!readFile(worldDir + "/checkpoint", &bytes))
    return Status::Error(Code::NotFound, worldDir + " has no checkpoint");
  Status s = decodeCheckpoint(bytes, checkpoint);
  if (!s.ok()) return Status::Error(s.code, worldDir + "/checkpoint: " + s.message);
  *crc = storedCrc(bytes);
  return Status::Ok();
}

}  // namespace phys::server
