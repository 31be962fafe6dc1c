// Durable worlds' files: checkpoints written atomically, journals appended and synced
// (store.h describes the layout).
#include "phys/server/store.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>
#include <zlib.h>

#include <cerrno>
#include <cstring>
#include <filesystem>

namespace phys::server {

namespace fs = std::filesystem;
using Code = protocol::Code;

namespace {

constexpr char kCheckpointMagic[8] = {'P', 'H', 'Y', 'S', 'C', 'K', 'P', 'T'};
constexpr uint32_t kCheckpointVersion = 1;
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

bool readFile(const std::string& path, std::vector<uint8_t>* out) {
  int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return false;
  struct stat st {};
  if (::fstat(fd, &st) != 0) {
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
  if (r.ok && version != kCheckpointVersion)
    return Status::Error(Code::Unsupported, "checkpoint version " + std::to_string(version) +
                                                "; this physd reads " +
                                                std::to_string(kCheckpointVersion));
  Checkpoint c;
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

Status WorldStore::openJournal(uint64_t generation, uint64_t goodSize) {
  const std::string path = journalPath(generation);
  int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_CLOEXEC, 0644);
  if (fd < 0) return ioError("cannot open " + path, errno);
  // Past the last good record: cut (a torn tail), and append from there.
  if (::ftruncate(fd, off_t(goodSize)) != 0 || ::lseek(fd, off_t(goodSize), SEEK_SET) < 0) {
    const int e = errno;
    ::close(fd);
    return ioError("cannot prepare " + path, e);
  }
  if (fd_ >= 0) ::close(fd_);
  fd_ = fd;
  generation_ = generation;
  size_ = goodSize;
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
  // The new journal exists (empty) before the checkpoint that names it.
  {
    const std::string path = journalPath(next);
    int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    if (fd < 0) return ioError("cannot create " + path, errno);
    ::close(fd);
  }
  s = writeFileAtomically(dir_ + "/checkpoint", encodeCheckpoint(c));
  if (!s.ok()) {
    ::unlink(journalPath(next).c_str());
    return s;
  }
  const uint64_t old = generation_;
  s = openJournal(next, 0);
  if (!s.ok()) return s;  // the checkpoint stands; appends fail until a new journal opens
  records_ = 0;
  if (old > 0) ::unlink(journalPath(old).c_str());
  return Status::Ok();
}

Status WorldStore::append(uint64_t tick, JournalRecord::Kind kind,
                          std::span<const uint8_t> payload) {
  if (fd_ < 0) return Status::Error(Code::Internal, "the journal of " + dir_ + " is not open");
  std::vector<uint8_t> rec(kJournalRecordHeader + payload.size());
  const uint32_t len = uint32_t(payload.size());
  std::memcpy(rec.data(), &len, 4);
  std::memcpy(rec.data() + 8, &tick, 8);
  rec[16] = uint8_t(kind);
  std::memcpy(rec.data() + 17, payload.data(), payload.size());
  const uint32_t sum = crc(std::span<const uint8_t>(rec).subspan(8));
  std::memcpy(rec.data() + 4, &sum, 4);
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
  if (fd_ < 0 || ::fdatasync(fd_) != 0)
    return ioError("cannot sync " + journalPath(generation_), fd_ < 0 ? EBADF : errno);
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

Status WorldStore::load(Checkpoint* checkpoint, std::vector<JournalRecord>* records,
                        std::vector<std::string>* notes) {
  std::vector<uint8_t> bytes;
  if (!readFile(dir_ + "/checkpoint", &bytes))
    return Status::Error(Code::NotFound, dir_ + " has no checkpoint");
  Status s = decodeCheckpoint(bytes, checkpoint);
  if (!s.ok()) return Status::Error(s.code, dir_ + "/checkpoint: " + s.message);
  bytes.clear();
  const uint64_t g = checkpoint->meta.generation;
  const std::string path = journalPath(g);
  records->clear();
  uint64_t good = 0;
  if (readFile(path, &bytes)) {
    size_t at = 0;
    while (bytes.size() - at >= kJournalRecordHeader) {
      uint32_t len = 0, sum = 0;
      std::memcpy(&len, bytes.data() + at, 4);
      std::memcpy(&sum, bytes.data() + at + 4, 4);
      if (len > kMaxRecordPayload || bytes.size() - at - kJournalRecordHeader < len) break;
      auto body = std::span<const uint8_t>(bytes).subspan(at + 8, 9 + size_t(len));
      if (crc(body) != sum) break;
      JournalRecord r;
      std::memcpy(&r.tick, body.data(), 8);
      r.kind = JournalRecord::Kind(body[8]);
      r.payload.assign(body.begin() + 9, body.end());
      if (r.kind != JournalRecord::Kind::Command && r.kind != JournalRecord::Kind::Mark) break;
      records->push_back(std::move(r));
      at += kJournalRecordHeader + len;
    }
    good = at;
    if (good < bytes.size())
      notes->push_back(path + ": " + std::to_string(bytes.size() - good) +
                       " bytes after record " + std::to_string(records->size()) +
                       " are torn or corrupt (a crash while writing, or damage); dropped: the "
                       "world is restored up to the last good record");
  }
  // Journals of other generations are left from a checkpoint that a crash interrupted.
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(dir_, ec)) {
    const std::string n = e.path().filename().string();
    if ((n.rfind("journal-", 0) == 0 && n != "journal-" + std::to_string(g)) ||
        n.ends_with(".partial"))
      fs::remove(e.path(), ec);
  }
  s = openJournal(g, good);
  records_ = records->size();
  return s;
}

}  // namespace phys::server
