// physctl: a command-line client of physd over the client SDK (docs/CLIENT.md).
//
//   physctl [--domain N] [--config XML] [--identity NAME [--security-dir DIR]] [--key FILE]
//           list [--json]
//   physctl whoami [--json]           # this physctl's client id (its key file's), for --editors
//   physctl create NAME [--preset P] [--backend cpu|gpu|auto] [--shared | --editors ID,...]
//   physctl access WORLD [--editors ID,...] [--shared | --private]
//   physctl load WORLD SCENE          # a server-side scene name, or a local .json file
//   physctl step WORLD N
//   physctl run WORLD [--rate HZ]
//   physctl pause WORLD
//   physctl watch [WORLD] [--json]    # live table, about twice a second; Ctrl-C exits
//   physctl snapshot save WORLD FILE  # the world's exact snapshot into a local file
//   physctl snapshot restore WORLD FILE
//   physctl ping [--count N] [--json]  # command round trip percentiles (a benchmark)
//   physctl subscribe WORLD [--seconds S] [--warmup W] [--latency-log FILE] [--json]
//                   [--bodies ID,ID,... | --region X0,Y0,Z0,X1,Y1,Z1]
//                                      # receive state frames (of an interest); print
//                                      # delivery, latency and bytes per tick
//   physctl settings WORLD             # the world's settings (gravity, time step, sleeping...)
//   physctl set WORLD [--gravity X,Y,Z] [--time-step S] [--sleep on|off] [--sleep-time S]
//                   [--max-linear-speed V] ... # change them (docs/PROTOCOL.md "World settings")
//   physctl bodies WORLD [ID ...]      # definitions as the world simulates them: names,
//   physctl joints WORLD [ID ...]      # damping, masses, shapes, materials; joints
//
// WORLD is a world id or name. Errors print the server's code and message and exit 1.
//
// Identity: the commands that change worlds (create, load, step, run, pause, snapshot restore,
// access) go out under the client id of a key file kept between runs, like ssh's (--key, else
// $PHYSCTL_KEY, else $XDG_CONFIG_HOME/physd/client.key, else ~/.config/physd/client.key; made
// mode 0600 on first use), so that the worlds one physctl creates the next one may change.
// Such commands take a lock beside the key file while they run: two physctl processes with
// one key at once would take the id from each other on the daemon (one participant holds an id
// at a time), so they run one after the other. The commands that only read (list, watch, ping,
// subscribe, snapshot save) use a fresh key each time and take no lock.
#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <atomic>
#include <cerrno>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <nlohmann/json.hpp>

#include "phys/client/client.h"
#include "phys/protocol/client_key.h"

namespace pc = phys::client;

namespace {

std::atomic<bool> gStop{false};
void onSignal(int) {
  gStop = true;
}

bool readFile(const std::string& path, std::string* out) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return false;
  std::stringstream ss;
  ss << in.rdbuf();
  *out = ss.str();
  return true;
}

bool isNumber(const std::string& s) {
  return !s.empty() && std::all_of(s.begin(), s.end(), [](char c) { return c >= '0' && c <= '9'; });
}

pc::WorldHandle resolve(pc::Client& c, const std::string& world) {
  if (isNumber(world)) return c.world(uint32_t(std::stoul(world)));
  return c.worldNamed(world);
}

using Json = nlohmann::ordered_json;

/// A client id as physd's messages write it: 0x and 16 hex digits.
std::string hexId(uint64_t id) {
  char buf[24];
  std::snprintf(buf, sizeof buf, "0x%016llx", (unsigned long long)id);
  return buf;
}

/// A client id as physctl whoami prints it (0x...) or in decimal; nullopt when neither.
std::optional<uint64_t> parseClientId(const std::string& s) {
  const bool hex = s.size() > 2 && s[0] == '0' && (s[1] == 'x' || s[1] == 'X');
  const std::string digits = hex ? s.substr(2) : s;
  if (digits.empty() || digits.size() > (hex ? 16u : 20u)) return std::nullopt;
  for (char c : digits)
    if (!(hex ? std::isxdigit(uint8_t(c)) : std::isdigit(uint8_t(c)))) return std::nullopt;
  errno = 0;
  const unsigned long long v = std::strtoull(digits.c_str(), nullptr, hex ? 16 : 10);
  if (errno == ERANGE || v == 0) return std::nullopt;
  return uint64_t(v);
}

/// Where physctl keeps its key: --key, else $PHYSCTL_KEY, else the user's config directory
/// ($XDG_CONFIG_HOME/physd/client.key, else ~/.config/physd/client.key); empty when there is
/// no home to keep it in.
std::string keyPath(const std::string& flag) {
  if (!flag.empty()) return flag;
  if (const char* env = std::getenv("PHYSCTL_KEY"); env && *env) return env;
  if (const char* xdg = std::getenv("XDG_CONFIG_HOME"); xdg && *xdg == '/')
    return std::string(xdg) + "/physd/client.key";
  if (const char* home = std::getenv("HOME"); home && *home)
    return std::string(home) + "/.config/physd/client.key";
  return {};
}

/// Holds `path`.lock (flock) while physctl runs, so that physctl processes with one key take
/// turns: on physd one participant holds a client id at a time, and a second process's Hello
/// would take it from the first in the middle of its commands. Makes the key's folder (mode
/// 0700, as XDG and ssh want it) when missing. Returns the lock's descriptor (closed at exit),
/// or -1 with a message on stderr.
int lockKey(const std::string& path) {
  namespace fs = std::filesystem;
  const fs::path dir = fs::path(path).parent_path();
  std::error_code ec;
  if (!dir.empty() && !fs::exists(dir, ec)) {
    fs::create_directories(dir, ec);
    if (!ec) fs::permissions(dir, fs::perms::owner_all, ec);
    if (ec) {
      std::fprintf(stderr, "physctl: cannot make %s for the key file: %s\n", dir.c_str(),
                   ec.message().c_str());
      return -1;
    }
  }
  const std::string lock = path + ".lock";
  const int fd = ::open(lock.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0600);
  if (fd < 0) {
    std::fprintf(stderr, "physctl: cannot open %s: %s\n", lock.c_str(), std::strerror(errno));
    return -1;
  }
  if (::flock(fd, LOCK_EX | LOCK_NB) != 0) {
    std::fprintf(stderr, "physctl: waiting for another physctl using %s ...\n", path.c_str());
    while (::flock(fd, LOCK_EX) != 0 && errno == EINTR) {
    }
  }
  return fd;
}

const char* stateOf(const pc::WorldSummary& w) {
  return !w.damage.empty() ? "damaged" : w.running ? "running" : "paused";
}

/// A world's summary for --json: every field of WorldSummary, under snake_case names.
Json worldJson(const pc::WorldSummary& w) {
  Json j;
  j["id"] = w.world;
  j["daemon"] = w.daemon;
  if (w.movingTo) j["moving_to"] = w.movingTo;
  j["name"] = w.name;
  j["preset"] = w.preset;
  j["state"] = stateOf(w);
  j["running"] = w.running;
  j["rate_hz"] = w.rateHz;
  j["tick"] = w.tick;
  j["time_s"] = w.time;
  j["bodies"] = w.bodies;
  j["awake_bodies"] = w.awakeBodies;
  j["sleeping_bodies"] = w.sleepingBodies;
  j["joints"] = w.joints;
  j["contacts"] = w.contacts;
  j["step_buffer_bytes"] = w.stepBufferBytes;
  j["tick_ms"] = w.tickMs;
  j["tick_ms_max"] = w.tickMsMax;
  j["overruns"] = w.overruns;
  j["frames"] = w.frames;
  j["frame_bytes"] = w.frameBytes;
  j["subscribers"] = w.subscribers;
  j["backend"] = w.backend.empty() ? "cpu" : w.backend;
  j["device"] = w.device;
  j["backend_note"] = w.backendNote;
  j["gpu_steps"] = w.gpuSteps;
  j["cpu_steps"] = w.cpuSteps;
  j["damage"] = w.damage;
  return j;
}

Json worldsJson(const std::vector<pc::WorldSummary>& worlds) {
  Json a = Json::array();
  for (const auto& w : worlds) a.push_back(worldJson(w));
  return a;
}

void printJson(const Json& j) {
  std::printf("%s\n", j.dump().c_str());
  std::fflush(stdout);
}

/// The worlds, one a line; a world's backend (and device) after its numbers, and below it
/// why the CPU runs a world that asked for the GPU.
/// cluster: the worlds of a domain of daemons, with a daemon column (and room for their ids);
/// a lone daemon's table is as it always was (scripts read it).
void printWorlds(const std::vector<pc::WorldSummary>& worlds, bool cluster) {
  const int idWidth = cluster ? 10 : 6;
  if (cluster) std::printf("%6s ", "daemon");
  std::printf("%*s  %-20s %-12s %8s %8s %7s %8s %7s %10s %10s %8s %6s %8s %10s  %s\n", idWidth,
              "id", "name", "preset", "awake", "bodies", "joints", "contacts", "buf MB", "tick",
              "time s", "state", "rate", "overruns", "frames", "backend");
  const int noteIndent = idWidth + (cluster ? 7 : 0);
  for (const auto& w : worlds) {
    std::string backend = w.backend.empty() ? "cpu" : w.backend;  // servers before backends
    if (!w.device.empty()) backend += " (" + w.device + ")";
    if (cluster) std::printf("%6llu ", (unsigned long long)w.daemon);
    std::printf("%*u  %-20s %-12s %8u %8u %7u %8u %7.1f %10llu %10.2f %8s %6.0f %8llu %10llu  %s\n",
                idWidth, w.world, w.name.c_str(), w.preset.c_str(), w.awakeBodies, w.bodies,
                w.joints,
                w.contacts, double(w.stepBufferBytes) / 1e6, (unsigned long long)w.tick,
                w.time, stateOf(w), double(w.rateHz),
                (unsigned long long)w.overruns, (unsigned long long)w.frames, backend.c_str());
    if (!w.backendNote.empty())
      std::printf("%*s  note: %s\n", noteIndent, "", w.backendNote.c_str());
    if (!w.damage.empty())
      std::printf("%*s  not restored: %s\n", noteIndent, "", w.damage.c_str());
  }
}

/// Live table from phys/status and the worlds' state frames until Ctrl-C. json: one JSON
/// object a line instead of each table (for scripts).
int watch(pc::Client& c, const std::string& only, bool json) {
  struct Live {
    pc::Subscription sub;
    uint64_t lastFrames = 0;
    double fps = 0;
  };
  std::map<uint32_t, Live> live;
  const bool tty = isatty(STDOUT_FILENO);
  auto last = std::chrono::steady_clock::now();
  while (!gStop) {
    for (int i = 0; i < 10 && !gStop; ++i)
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    if (gStop) break;
    const auto now = std::chrono::steady_clock::now();
    const double dt = std::chrono::duration<double>(now - last).count();
    last = now;
    std::optional<pc::ServerStatus> status = c.latestStatus();
    std::string out;
    char line[256];
    Json j;
    if (!status) {
      std::snprintf(line, sizeof line, "waiting for physd on domain %u ...\n", c.options().domain);
      out += line;
      j["waiting"] = true;
      j["domain"] = c.options().domain;
    } else {
      std::vector<pc::WorldSummary> worlds;
      for (const auto& w : status->worlds)
        if (only.empty() || w.name == only || (isNumber(only) && std::to_string(w.world) == only))
          worlds.push_back(w);
      // Subscribe to the worlds shown; forget the ones gone.
      for (auto it = live.begin(); it != live.end();)
        if (std::none_of(worlds.begin(), worlds.end(),
                         [&](const pc::WorldSummary& w) { return w.world == it->first; }))
          it = live.erase(it);
        else
          ++it;
      for (const auto& w : worlds)
        if (!live.count(w.world) && w.damage.empty()) live[w.world].sub = c.subscribe(w.world);
      std::snprintf(line, sizeof line, "%s %s  up %.0f s  commands %llu  errors %llu  heap %.1f MB\n",
                    status->serverName.c_str(), status->serverVersion.c_str(), status->uptimeS,
                    (unsigned long long)status->commands, (unsigned long long)status->errors,
                    double(status->heapBytes) / 1e6);
      out += line;
      j["server"] = status->serverName;
      j["version"] = status->serverVersion;
      j["uptime_s"] = status->uptimeS;
      j["commands"] = status->commands;
      j["errors"] = status->errors;
      j["heap_bytes"] = status->heapBytes;
      j["frames_dropped"] = status->framesDropped;
      j["read_only"] = status->readOnly;
      j["worlds"] = Json::array();
      if (!status->readOnly.empty()) out += "READ-ONLY: " + status->readOnly + "\n";
      std::snprintf(line, sizeof line, "%5s  %-18s %10s %10s %8s %8s %15s %10s %8s %6s %5s\n",
                    "id", "world", "tick", "sim time", "tick ms", "max ms", "awake/bodies",
                    "bytes/tick", "state", "frm/s", "subs");
      out += line;
      for (const auto& w : worlds) {
        Json& jw = j["worlds"].emplace_back(worldJson(w));
        if (!w.damage.empty()) {
          std::snprintf(line, sizeof line, "%5u  %-18s ", w.world, w.name.c_str());
          out += line + std::string("damaged, not restored: ") + w.damage + "\n";
          continue;
        }
        Live& l = live[w.world];
        uint64_t tick = w.tick;
        double time = w.time;
        uint32_t bodies = w.bodies;
        if (auto f = l.sub.latest()) {
          if (f->tick >= tick) {
            tick = f->tick;
            time = f->time;
            bodies = f->total;
          }
        }
        const uint64_t frames = l.sub.framesReceived();
        l.fps = dt > 0 ? double(frames - l.lastFrames) / dt : 0;
        l.lastFrames = frames;
        const std::string awake = std::to_string(w.awakeBodies) + "/" + std::to_string(bodies);
        // What the last frame cost on the wire: the server's count, or what this watch got.
        uint64_t bytes = w.frameBytes;
        if (auto f = l.sub.latest(); f && f->bytes > 0) bytes = f->bytes;
        std::snprintf(line, sizeof line, "%5u  %-18s %10llu %10.2f %8.3f %8.3f %15s %10llu %8s %6.1f %5u\n",
                      w.world, w.name.c_str(), (unsigned long long)tick, time, double(w.tickMs),
                      double(w.tickMsMax), awake.c_str(), (unsigned long long)bytes, w.running ? "running" : "paused", l.fps,
                      w.subscribers);
        out += line;
        jw["frame_tick"] = tick;  // the newer of the status's tick and the last frame's
        jw["frame_bytes"] = bytes;
        jw["frames_per_s"] = l.fps;
      }
      if (worlds.empty()) out += only.empty() ? "(no worlds)\n" : "(no such world)\n";
      // The last few phys/events since watch started (guard rails).
      const std::vector<pc::Event> events = c.recentEvents();
      j["events"] = Json::array();
      for (size_t i = events.size() > 3 ? events.size() - 3 : 0; i < events.size(); ++i) {
        const pc::Event& e = events[i];
        j["events"].push_back({{"world", e.world}, {"tick", e.tick}, {"code", e.code},
                               {"message", e.message}});
        std::snprintf(line, sizeof line, "event world %u tick %llu %s: ", e.world,
                      (unsigned long long)e.tick, e.code.c_str());
        out += line + e.message + "\n";
      }
    }
    if (json) {
      printJson(j);
      continue;
    }
    if (tty) std::fputs("\033[H\033[2J", stdout);
    std::fputs(out.c_str(), stdout);
    if (!tty) std::fputs("\n", stdout);
    std::fflush(stdout);
  }
  return 0;
}

/// Receives WORLD's state frames for `seconds` after `warmup` seconds and prints one line:
/// complete ticks received against the ticks between the first and the last one seen, and the
/// tick-to-subscriber latency (this host's wall clock minus the frame's stamp_ns, taken when
/// the SDK has reassembled the tick). A benchmark (tools/fanout_bench.sh runs eight).
/// latencyLog: when not empty, a file that gets one line per tick received, "tick latency_ms".
/// json: the line as one JSON object instead (for scripts).
int subscribe(pc::Client& c, const std::string& world, double warmup, double seconds,
              const std::string& latencyLog, const pc::Interest& interest, bool json) {
  std::unique_ptr<std::FILE, int (*)(std::FILE*)> log(nullptr, &std::fclose);
  if (!latencyLog.empty()) {
    log.reset(std::fopen(latencyLog.c_str(), "w"));
    if (!log) {
      std::fprintf(stderr, "physctl: cannot write %s: %s\n", latencyLog.c_str(),
                   std::strerror(errno));
      return 1;
    }
  }
  pc::WorldHandle w = resolve(c, world);
  struct Record {
    uint64_t tick;
    double latencyMs;
    uint32_t bodies;
    uint64_t bytes;  ///< what the server sent for the tick (keyframe or delta)
  };
  std::mutex m;
  std::vector<Record> records;
  records.reserve(size_t(seconds * 240) + 16);
  std::atomic<bool> measuring{false};
  pc::Subscription sub = w.subscribe(interest, [&](const pc::StateFrame& f) {
    const auto now = std::chrono::system_clock::now().time_since_epoch();
    const double ms = double(std::chrono::duration_cast<std::chrono::nanoseconds>(now).count() -
                             int64_t(f.stampNs)) /
                      1e6;
    if (!measuring.load()) return;
    std::lock_guard<std::mutex> lk(m);
    records.push_back({f.tick, ms, uint32_t(f.bodies.size()), f.bytes});
  });
  auto sleepFor = [](double s) {
    const auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(s);
    while (!gStop && std::chrono::steady_clock::now() < end)
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
  };
  sleepFor(warmup);
  measuring = true;
  sleepFor(seconds);
  measuring = false;
  sub.reset();
  std::lock_guard<std::mutex> lk(m);
  if (records.empty()) {
    if (json)
      printJson({{"subscriber", int(getpid())}, {"world", w.id()}, {"seconds", seconds},
                 {"received", 0}});
    else
      std::printf("subscriber %d: world %u: no frames in %.1f s\n", int(getpid()), w.id(),
                  seconds);
    return 1;
  }
  const uint64_t first = records.front().tick, last = records.back().tick;
  const uint64_t expected = last - first + 1;
  std::vector<double> lat;
  uint32_t minBodies = UINT32_MAX;
  double bytes = 0;
  for (const Record& r : records) {
    lat.push_back(r.latencyMs);
    minBodies = std::min(minBodies, r.bodies);
    bytes += double(r.bytes);
  }
  if (log) {
    for (const Record& r : records)
      std::fprintf(log.get(), "%llu %.3f\n", (unsigned long long)r.tick, r.latencyMs);
  }
  std::sort(lat.begin(), lat.end());
  auto pct = [&](double q) {
    return lat[std::min(lat.size() - 1, size_t(q * double(lat.size())))];
  };
  if (json) {
    printJson({{"subscriber", int(getpid())},
               {"world", w.id()},
               {"seconds", seconds},
               {"first_tick", first},
               {"last_tick", last},
               {"received", records.size()},
               {"expected", expected},
               {"delivered_percent", 100.0 * double(records.size()) / double(expected)},
               {"bodies_min", minBodies},
               {"latency_ms", {{"p50", pct(0.5)}, {"p99", pct(0.99)}, {"max", lat.back()}}},
               {"bytes_per_tick", bytes / double(records.size())}});
    return 0;
  }
  std::printf(
      "subscriber %d: world %u ticks %llu..%llu received %zu expected %llu delivered %.3f%% "
      "bodies_min %u latency_ms p50 %.3f p99 %.3f max %.3f bytes_per_tick %.0f\n",
      int(getpid()), w.id(), (unsigned long long)first, (unsigned long long)last, records.size(),
      (unsigned long long)expected, 100.0 * double(records.size()) / double(expected), minBodies,
      pct(0.5), pct(0.99), lat.back(), bytes / double(records.size()));
  return 0;
}

std::string num(float v) {
  char b[32];
  std::snprintf(b, sizeof b, "%g", double(v));
  return b;
}

std::string vec3(phys::Vec3 v) {
  char b[96];
  std::snprintf(b, sizeof b, "(%g, %g, %g)", double(v.x), double(v.y), double(v.z));
  return b;
}

/// A world setting's value as `physctl settings` prints it and `physctl set` takes it.
std::string settingText(phys::Vec3 v) {
  return vec3(v);
}
std::string settingText(bool b) {
  return b ? "on" : "off";
}
std::string settingText(float f) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%g", double(f));
  return buf;
}
std::string settingText(int i) {
  return std::to_string(i);
}

/// Every setting GetWorld reports, one "name value" line each (WorldSettings' names, in
/// PHYS_WORLD_FIELDS' order), then the preset and the solver's substeps and iterations.
void printSettings(const pc::WorldSettings& s) {
  const phys::WorldDef& d = s.def;
#define PHYS_PRINT_SETTING(type, member, path, name) \
  std::printf("%s %s\n", #name, settingText(d.path).c_str());
  PHYS_WORLD_FIELDS(PHYS_PRINT_SETTING)
#undef PHYS_PRINT_SETTING
  std::printf("preset %s\nsubsteps %d\niterations %d\n", s.preset.c_str(), d.solver.substeps,
              d.solver.iterations);
}

/// physctl set's options: one per world setting (PHYS_WORLD_FIELDS), its wire name with
/// dashes (--time-step, --sleep-linear-speed, ...), read into the texts below.
struct SetOptions {
  std::map<std::string, std::vector<float>> vectors;
  std::map<std::string, float> numbers;
  std::map<std::string, std::string> flags;
  std::map<std::string, int> counts;

  static std::string option(const char* name) {
    std::string s = std::string("--") + name;
    std::replace(s.begin(), s.end(), '_', '-');
    return s;
  }
  void add(CLI::App* cmd, const char* name, phys::Vec3*) {
    cmd->add_option(option(name), vectors[name], "x,y,z")->delimiter(',')->expected(3);
  }
  void add(CLI::App* cmd, const char* name, float*) {
    cmd->add_option(option(name), numbers[name], "")->check(CLI::Number);
  }
  void add(CLI::App* cmd, const char* name, bool*) {
    cmd->add_option(option(name), flags[name], "on or off")->check(CLI::IsMember({"on", "off"}));
  }
  void add(CLI::App* cmd, const char* name, int*) {
    cmd->add_option(option(name), counts[name], "")->check(CLI::NonNegativeNumber);
  }
  void read(const char* name, std::optional<phys::Vec3>* out) {
    const std::vector<float>& v = vectors[name];
    *out = phys::Vec3{v[0], v[1], v[2]};
  }
  void read(const char* name, std::optional<float>* out) { *out = numbers[name]; }
  void read(const char* name, std::optional<bool>* out) { *out = flags[name] == "on"; }
  void read(const char* name, std::optional<int>* out) { *out = counts[name]; }
};

/// A body's definition: a line of its own fields, a line per shape.
void printBody(const pc::BodyInfo& b) {
  const phys::BodyDef& d = b.def;
  std::printf("0x%llx %s %s mass %g kg%s damping %g %g gravity_scale %g%s%s\n",
              (unsigned long long)b.id, d.name.empty() ? "-" : ("\"" + d.name + "\"").c_str(),
              phys::toString(d.type), double(b.mass.mass),
              d.type != phys::BodyType::Dynamic ? "" : d.mass > 0 ? " (given)" : " (shapes)",
              double(d.linearDamping), double(d.angularDamping), double(d.gravityScale),
              d.gyroscopic ? "" : " gyroscopic off", d.allowSleep ? "" : " allow_sleep off");
  std::printf("    position %s velocity %s angular %s\n", vec3(d.position).c_str(),
              vec3(d.linearVelocity).c_str(), vec3(d.angularVelocity).c_str());
  for (const phys::ShapeDef& sh : d.shapes) {
    const phys::ShapeGeom& g = sh.geom;
    std::string size;
    switch (g.type) {
      case phys::ShapeType::Sphere:
        size = "radius " + num(g.radius);
        break;
      case phys::ShapeType::Box:
        size = "half_extents " + vec3(g.halfExtents);
        break;
      case phys::ShapeType::Capsule:
        size = "radius " + num(g.radius) + " half_height " + num(g.halfHeight);
        break;
      case phys::ShapeType::Plane:
        size = "normal " + vec3(g.normal) + " offset " + num(g.offset);
        break;
      case phys::ShapeType::Hull:
        size = std::to_string(g.hull ? g.hull->vertices.size() : 0) + " vertices";
        break;
    }
    std::printf("    %s %s at %s friction %g restitution %g density %g\n", phys::toString(g.type),
                size.c_str(), vec3(sh.local.p).c_str(), double(sh.material.friction),
                double(sh.material.restitution), double(sh.material.density));
  }
}

void printJoint(const pc::JointInfo& j) {
  const phys::JointDef& d = j.def;
  std::printf("0x%llx %s %s bodies 0x%llx 0x%llx anchors %s %s", (unsigned long long)j.id,
              d.name.empty() ? "-" : ("\"" + d.name + "\"").c_str(), phys::toString(d.type),
              (unsigned long long)d.bodyA.packed(), (unsigned long long)d.bodyB.packed(),
              vec3(d.anchorA).c_str(), vec3(d.anchorB).c_str());
  if (d.enableLimit) std::printf(" limits %g %g", double(d.lower), double(d.upper));
  if (d.enableMotor)
    std::printf(" motor %g max %g", double(d.motorSpeed), double(d.maxMotorForce));
  if (d.type == phys::JointType::Distance)
    std::printf(" length %g spring %g Hz %g", double(d.length), double(d.springHertz),
                double(d.springDampingRatio));
  std::printf("%s\n", d.collideConnected ? " collide_connected" : "");
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"physctl: command-line client of physd"};
  app.require_subcommand(1);
  uint32_t domain = 0;
  std::string config;
  int timeoutMs = 10000;
  app.add_option("--domain", domain, "DDS domain id")->check(CLI::Range(0, 232));
  app.add_option("--config", config,
                 "Cyclone XML file (default: $CYCLONEDDS_URI, else the source tree's "
                 "configs/cyclonedds/loopback.xml)");
  app.add_option("--timeout", timeoutMs, "connect and request timeout, ms")
      ->check(CLI::PositiveNumber);
  std::string identity, securityDir = std::string(PHYS_SOURCE_DIR) + "/build/security";
  app.add_option("--identity", identity,
                 "DDS Security identity (docs/SECURITY.md): its certificate and key, the CA and "
                 "the signed documents are read from --security-dir");
  app.add_option("--security-dir", securityDir,
                 "the folder tools/make_security.sh wrote (default: the source tree's "
                 "build/security)");
  std::string keyFlag;
  app.add_option("--key", keyFlag,
                 "this physctl's key file: its client id, kept between runs, owns the worlds "
                 "it creates (default: $PHYSCTL_KEY, else $XDG_CONFIG_HOME/physd/client.key, "
                 "else ~/.config/physd/client.key; made mode 0600 when missing)");
  bool json = false;

  std::string world, name, preset, scene, file, backend;
  uint32_t steps = 1;
  float rate = 60;

  uint64_t daemon = 0;
  auto* list = app.add_subcommand("list", "list the worlds (of every daemon of the domain)");
  list->add_flag("--json", json, "a JSON array of the worlds (every field, for scripts)");
  list->add_option("--daemon", daemon, "only this daemon's worlds (its server.id)");
  auto* daemonsCmd = app.add_subcommand(
      "daemons", "list the daemons of the domain (their phys/status): id, name, worlds, load");
  daemonsCmd->add_flag("--json", json, "a JSON array of the daemons");
  auto* whoami = app.add_subcommand(
      "whoami", "print this physctl's client id (its key file's): what --editors names");
  whoami->add_flag("--json", json, "the id and the key file as a JSON object");
  std::vector<std::string> editors;
  bool shared = false, isPrivate = false;
  auto* create = app.add_subcommand("create", "create a world (paused), owned by this physctl");
  create->add_option("NAME", name, "world name")->required();
  create->add_option("--preset", preset, "solver preset");
  create->add_option("--daemon", daemon,
                     "the daemon (server.id) to create it on; default: in a domain of daemons "
                     "the one with the fewest awake bodies");
  create->add_option("--backend", backend, "cpu, gpu or auto (default: the server's)")
      ->check(CLI::IsMember({"cpu", "gpu", "auto"}));
  auto* createShared =
      create->add_flag("--shared", shared, "every client may change the world (not destroy it)");
  create->add_option("--editors", editors,
                     "these clients (ids, comma-separated, as physctl whoami prints them) may "
                     "change the world too")
      ->delimiter(',')
      ->excludes(createShared);
  auto* access = app.add_subcommand(
      "access", "set who besides its owner may change WORLD (the owner only; replaces the "
                "world's editors and shared flag)");
  access->add_option("WORLD", world, "world id or name")->required();
  access->add_option("--editors", editors,
                     "these clients (ids, comma-separated, as physctl whoami prints them); "
                     "without it: none")
      ->delimiter(',');
  auto* accessShared = access->add_flag("--shared", shared, "every client may change it");
  auto* accessPrivate =
      access->add_flag("--private", isPrivate, "only the owner and --editors (the default)");
  accessShared->excludes(accessPrivate);
  auto* load = app.add_subcommand("load", "load a scene into a world");
  load->add_option("WORLD", world, "world id or name")->required();
  load->add_option("SCENE", scene, "server-side scene name, or a local .json file")->required();
  auto* step = app.add_subcommand("step", "take N steps now");
  step->add_option("WORLD", world, "world id or name")->required();
  step->add_option("N", steps, "steps")->required()->check(CLI::Range(1u, 100000u));
  auto* run = app.add_subcommand("run", "run a world in real time");
  run->add_option("WORLD", world, "world id or name")->required();
  run->add_option("--rate", rate, "steps per second (0: as fast as possible)")
      ->check(CLI::Range(0.0f, 10000.0f));
  auto* pause = app.add_subcommand("pause", "pause a world");
  pause->add_option("WORLD", world, "world id or name")->required();
  uint64_t toDaemon = 0;
  auto* moveCmd = app.add_subcommand(
      "move", "move a world to another daemon of the domain (its owner only; docs/SERVER.md "
              "\"Moving a world\")");
  moveCmd->add_option("WORLD", world, "world id or name")->required();
  moveCmd->add_option("DAEMON", toDaemon, "the daemon's server.id (physctl daemons)")->required();
  auto* watchCmd = app.add_subcommand("watch", "live table of the worlds (Ctrl-C exits)");
  watchCmd->add_option("WORLD", world, "only this world (id or name)");
  watchCmd->add_flag("--json", json, "one JSON object a line instead of the table");
  int pings = 1000;
  auto* ping = app.add_subcommand(
      "ping", "command round trip: N ListWorlds requests one after another; prints percentiles");
  ping->add_option("--count", pings, "round trips (default 1000)")->check(CLI::Range(1, 1000000));
  ping->add_flag("--json", json, "the percentiles as a JSON object");
  double subSeconds = 10, subWarmup = 2;
  auto* subscribeCmd = app.add_subcommand(
      "subscribe", "receive WORLD's state frames; print delivered ticks and latency percentiles");
  subscribeCmd->add_option("WORLD", world, "world id or name")->required();
  subscribeCmd->add_option("--seconds", subSeconds, "measuring time, s (default 10)")
      ->check(CLI::PositiveNumber);
  subscribeCmd->add_option("--warmup", subWarmup, "seconds ignored first (default 2)")
      ->check(CLI::NonNegativeNumber);
  std::string latencyLog;
  subscribeCmd->add_option("--latency-log", latencyLog,
                           "write one line per received tick, \"tick latency_ms\", to this file");
  subscribeCmd->add_flag("--json", json, "the result line as a JSON object");
  std::vector<uint64_t> interestBodies;
  std::vector<float> interestRegion;
  subscribeCmd->add_option("--bodies", interestBodies,
                           "only these bodies (ids, comma-separated): an interest (docs/PROTOCOL.md)")
      ->delimiter(',');
  subscribeCmd->add_option("--region", interestRegion,
                           "only the bodies inside the box x0,y0,z0,x1,y1,z1 (m): an interest")
      ->delimiter(',')
      ->expected(6);
  auto* settingsCmd = app.add_subcommand("settings", "print a world's settings");
  settingsCmd->add_option("WORLD", world, "world id or name")->required();
  // set: each option given becomes a field of one SetWorld (all or nothing).
  auto* setCmd = app.add_subcommand(
      "set", "change a world's settings (each option given; docs/PROTOCOL.md \"World settings\")");
  setCmd->add_option("WORLD", world, "world id or name")->required();
  SetOptions setOptions;
#define PHYS_SET_OPTION(type, member, path, name) \
  setOptions.add(setCmd, #name, static_cast<type*>(nullptr));
  PHYS_WORLD_FIELDS(PHYS_SET_OPTION)
#undef PHYS_SET_OPTION
  std::vector<std::string> defIds;
  auto* bodiesCmd = app.add_subcommand(
      "bodies", "print bodies' definitions as the world simulates them (all, or the ids given)");
  bodiesCmd->add_option("WORLD", world, "world id or name")->required();
  bodiesCmd->add_option("ID", defIds, "body ids (hex 0x... or decimal)");
  auto* jointsCmd = app.add_subcommand("joints", "print joints' definitions (all, or the ids given)");
  jointsCmd->add_option("WORLD", world, "world id or name")->required();
  jointsCmd->add_option("ID", defIds, "joint ids (hex 0x... or decimal)");
  auto* snapshot = app.add_subcommand("snapshot", "save or restore a world's snapshot");
  snapshot->require_subcommand(1);
  auto* save = snapshot->add_subcommand("save", "save WORLD's snapshot into a local FILE");
  save->add_option("WORLD", world, "world id or name")->required();
  save->add_option("FILE", file, "local file")->required();
  auto* restore = snapshot->add_subcommand("restore", "restore WORLD from a local FILE");
  restore->add_option("WORLD", world, "world id or name")->required();
  restore->add_option("FILE", file, "local file")->required()->check(CLI::ExistingFile);

  CLI11_PARSE(app, argc, argv);

  pc::ClientOptions options;
  options.domain = domain;
  options.name = "physctl";
  options.connectTimeout = options.requestTimeout = std::chrono::milliseconds(timeoutMs);
  if (config.empty() && !std::getenv("CYCLONEDDS_URI")) {
    const std::string loopback = std::string(PHYS_SOURCE_DIR) + "/configs/cyclonedds/loopback.xml";
    if (std::filesystem::exists(loopback)) config = loopback;
  }
  if (!config.empty() && !readFile(config, &options.cycloneXml)) {
    std::fprintf(stderr, "physctl: cannot read Cyclone config %s\n", config.c_str());
    return 2;
  }
  if (!identity.empty()) options.security = pc::SecurityFiles::fromDir(securityDir, identity);

  std::vector<uint64_t> editorIds;
  for (const std::string& e : editors) {
    const std::optional<uint64_t> id = parseClientId(e);
    if (!id) {
      std::fprintf(stderr,
                   "physctl: --editors: '%s' is not a client id (0x and up to 16 hex digits, "
                   "as physctl whoami prints it, or a decimal number)\n",
                   e.c_str());
      return 2;
    }
    editorIds.push_back(*id);
  }
  // The commands that change worlds (and whoami) act as this physctl's kept key; the others
  // only read and use a fresh one (no lock, any number at once).
  const bool keyed = *whoami || *create || *load || *step || *run || *pause || *restore ||
                     *access || *moveCmd;
  int keyLock = -1;
  if (keyed) {
    options.keyFile = keyPath(keyFlag);
    if (options.keyFile.empty()) {
      std::fprintf(stderr,
                   "physctl: no home for the key file ($HOME unset): give --key FILE or "
                   "$PHYSCTL_KEY\n");
      return 2;
    }
    keyLock = lockKey(options.keyFile);
    if (keyLock < 0) return 2;
  }
  if (*whoami) {
    phys::protocol::ClientKey key;
    const phys::protocol::Status s = phys::protocol::ClientKey::load(options.keyFile, true, &key);
    if (!s.ok()) {
      std::fprintf(stderr, "physctl: %s\n", s.message.c_str());
      return 1;
    }
    if (json)
      printJson({{"client_id", hexId(key.clientId())}, {"key_file", options.keyFile}});
    else
      std::printf("%s\n", hexId(key.clientId()).c_str());
    return 0;
  }

  try {
    pc::Client client(options);
    if (*watchCmd) {
      std::signal(SIGINT, onSignal);
      std::signal(SIGTERM, onSignal);
      return watch(client, world, json);
    }
    client.connect();
    if (*subscribeCmd) {
      std::signal(SIGINT, onSignal);
      std::signal(SIGTERM, onSignal);
      pc::Interest interest;
      interest.bodies = interestBodies;
      if (!interestRegion.empty())
        interest.region = std::make_pair(
            phys::Vec3{interestRegion[0], interestRegion[1], interestRegion[2]},
            phys::Vec3{interestRegion[3], interestRegion[4], interestRegion[5]});
      if (!interest.bodies.empty() && interest.region) {
        std::fprintf(stderr, "physctl: give --bodies or --region, not both\n");
        return 2;
      }
      return subscribe(client, world, subWarmup, subSeconds, latencyLog, interest, json);
    }
    if (*list) {
      pc::CallOptions lo;
      lo.daemon = daemon;
      if (json) {
        printJson(worldsJson(client.listWorlds(lo).get()));
      } else {
        const std::vector<pc::DaemonInfo> ds = client.daemons();
        printWorlds(client.listWorlds(lo).get(),
                    std::any_of(ds.begin(), ds.end(),
                                [](const pc::DaemonInfo& d) { return d.cluster; }));
      }
    } else if (*daemonsCmd) {
      const std::vector<pc::DaemonInfo> ds = client.daemons();
      if (json) {
        Json a = Json::array();
        for (const pc::DaemonInfo& d : ds)
          a.push_back({{"id", d.id}, {"name", d.name}, {"cluster", d.cluster},
                       {"worlds", d.worlds}, {"awake_bodies", d.awakeBodies},
                       {"since_sample_s", d.sinceSampleS}, {"peers", d.peers}});
        printJson(a);
      } else {
        std::printf("%6s  %-20s %-8s %7s %12s %10s\n", "id", "name", "cluster", "worlds",
                    "awake bodies", "sample s");
        for (const pc::DaemonInfo& d : ds)
          std::printf("%6llu  %-20s %-8s %7u %12llu %10.1f\n", (unsigned long long)d.id,
                      d.name.c_str(), d.cluster ? "yes" : "no", d.worlds,
                      (unsigned long long)d.awakeBodies, d.sinceSampleS);
      }
    } else if (*ping) {
      // A benchmark, not a check: wall time from sending a request to its reply, through the
      // SDK, the envelope, DDS and the server's tick boundary (ListWorlds changes nothing).
      for (int i = 0; i < 20; ++i) client.listWorlds().get();  // warm up the path
      std::vector<double> us;
      us.reserve(size_t(pings));
      for (int i = 0; i < pings; ++i) {
        const auto t0 = std::chrono::steady_clock::now();
        client.listWorlds().get();
        us.push_back(
            std::chrono::duration<double, std::micro>(std::chrono::steady_clock::now() - t0)
                .count());
      }
      std::sort(us.begin(), us.end());
      auto pct = [&](double q) {
        return us[std::min(us.size() - 1, size_t(q * double(us.size())))];
      };
      if (json)
        printJson({{"round_trips", pings},
                   {"request", "ListWorlds"},
                   {"us", {{"p50", pct(0.5)}, {"p90", pct(0.9)}, {"p99", pct(0.99)},
                           {"max", us.back()}}}});
      else
        std::printf(
            "%d round trips (ListWorlds): p50 %.0f us, p90 %.0f us, p99 %.0f us, max %.0f us\n",
            pings, pct(0.5), pct(0.9), pct(0.99), us.back());
    } else if (*create) {
      pc::CreateWorldArgs args{name, preset, std::nullopt, 0, backend};
      args.editors = editorIds;
      args.shared = shared;
      pc::CallOptions co;
      co.daemon = daemon;
      pc::WorldHandle w = client.createWorld(args, co).get();
      std::string who = options.security.enabled() ? "identity " + identity
                                                   : "client " + hexId(client.clientId());
      if (shared)
        who += ", shared";
      else if (!editorIds.empty())
        who += " and " + std::to_string(editorIds.size()) + " editor" +
               (editorIds.size() == 1 ? "" : "s");
      std::printf("created world %u '%s' (owner %s)\n", w.id(), name.c_str(), who.c_str());
      // Where it runs (a world that asked for the GPU may run on the CPU; the note says why).
      for (const pc::WorldSummary& s : client.listWorlds().get())
        if (s.world == w.id()) {
          std::printf("backend %s%s\n", s.backend.empty() ? "cpu" : s.backend.c_str(),
                      s.device.empty() ? "" : (" (" + s.device + ")").c_str());
          if (!s.backendNote.empty()) std::printf("note: %s\n", s.backendNote.c_str());
        }
    } else if (*load) {
      pc::WorldHandle w = resolve(client, world);
      pc::Ids ids;
      std::string sceneJson;
      if (scene.size() > 5 && scene.ends_with(".json") && readFile(scene, &sceneJson))
        ids = w.loadSceneJson(sceneJson).get();
      else
        ids = w.loadScene(scene).get();
      std::printf("world %u: loaded %s (%zu bodies, %zu joints)\n", w.id(), scene.c_str(),
                  ids.bodies.size(), ids.joints.size());
    } else if (*step) {
      pc::WorldHandle w = resolve(client, world);
      pc::Ack a = w.step(steps).get();
      std::printf("world %u: tick %llu\n", w.id(), (unsigned long long)a.tick);
    } else if (*run) {
      pc::WorldHandle w = resolve(client, world);
      w.run(rate).get();
      std::printf("world %u: running at %g Hz\n", w.id(), double(rate));
    } else if (*pause) {
      pc::WorldHandle w = resolve(client, world);
      pc::Ack a = w.pause().get();
      std::printf("world %u: paused at tick %llu\n", w.id(), (unsigned long long)a.tick);
    } else if (*moveCmd) {
      pc::WorldHandle w = resolve(client, world);
      const auto t0 = std::chrono::steady_clock::now();
      pc::Ack a = w.move(toDaemon).get();
      const double ms = std::chrono::duration<double, std::milli>(
                            std::chrono::steady_clock::now() - t0).count();
      std::printf("world %u: moved to daemon %llu after tick %llu (%.1f ms)\n", w.id(),
                  (unsigned long long)toDaemon, (unsigned long long)a.tick, ms);
    } else if (*settingsCmd) {
      printSettings(resolve(client, world).settings().get());
    } else if (*setCmd) {
      pc::WorldOverrides o;
#define PHYS_SET_READ(type, member, path, name) \
  if (setCmd->count(SetOptions::option(#name)) > 0) setOptions.read(#name, &o.member);
      PHYS_WORLD_FIELDS(PHYS_SET_READ)
#undef PHYS_SET_READ
      if (o.empty()) {
        std::fprintf(stderr, "physctl: set: give at least one setting (physctl set --help)\n");
        return 2;
      }
      pc::WorldHandle w = resolve(client, world);
      pc::Ack a = w.setWorld(o).get();
      std::printf("world %u: settings changed at tick %llu\n", w.id(), (unsigned long long)a.tick);
    } else if (*bodiesCmd || *jointsCmd) {
      std::vector<uint64_t> ids;
      for (const std::string& t : defIds) ids.push_back(std::stoull(t, nullptr, 0));
      pc::WorldHandle w = resolve(client, world);
      if (*bodiesCmd) {
        // The ids asked for, page after page (a reply holds as many as fit); or all of them.
        std::vector<pc::BodyInfo> bodies;
        if (ids.empty()) {
          bodies = w.allBodies().get();
        } else {
          for (size_t at = 0; at < ids.size();) {
            pc::BodiesPage p = w.getBodies(std::span(ids).subspan(at)).get();
            if (p.bodies.empty()) break;
            at += p.bodies.size();
            for (pc::BodyInfo& b : p.bodies) bodies.push_back(std::move(b));
          }
        }
        for (const pc::BodyInfo& b : bodies) printBody(b);
      } else {
        std::vector<pc::JointInfo> joints;
        if (ids.empty()) {
          joints = w.allJoints().get();
        } else {
          for (size_t at = 0; at < ids.size();) {
            pc::JointsPage p = w.getJoints(std::span(ids).subspan(at)).get();
            if (p.joints.empty()) break;
            at += p.joints.size();
            for (pc::JointInfo& j : p.joints) joints.push_back(std::move(j));
          }
        }
        for (const pc::JointInfo& j : joints) printJoint(j);
      }
    } else if (*save) {
      pc::WorldHandle w = resolve(client, world);
      pc::Bytes bytes = w.saveSnapshot().get();
      std::ofstream out(file, std::ios::binary);
      out.write(reinterpret_cast<const char*>(bytes.data()), std::streamsize(bytes.size()));
      if (!out) {
        std::fprintf(stderr, "physctl: cannot write %s\n", file.c_str());
        return 1;
      }
      std::printf("world %u: %zu bytes saved to %s\n", w.id(), bytes.size(), file.c_str());
    } else if (*restore) {
      pc::WorldHandle w = resolve(client, world);
      std::string bytes;
      if (!readFile(file, &bytes)) {
        std::fprintf(stderr, "physctl: cannot read %s\n", file.c_str());
        return 1;
      }
      w.restoreSnapshot({reinterpret_cast<const uint8_t*>(bytes.data()), bytes.size()}).get();
      std::printf("world %u: restored from %s\n", w.id(), file.c_str());
    } else if (*access) {
      pc::WorldHandle w = resolve(client, world);
      w.setAccess(editorIds, shared).get();
      if (shared) {
        std::printf("world %u: shared (every client may change it; its owner alone destroys "
                    "it or sets its access)\n",
                    w.id());
      } else if (editorIds.empty()) {
        std::printf("world %u: private (its owner %s alone may change it)\n", w.id(),
                    hexId(client.clientId()).c_str());
      } else {
        std::printf("world %u: its owner and these editors may change it:", w.id());
        for (uint64_t id : editorIds) std::printf(" %s", hexId(id).c_str());
        std::printf("\n");
      }
    }
  } catch (const pc::Error& e) {
    std::fprintf(stderr, "physctl: %s: %s\n", pc::toString(e.code()), e.message().c_str());
    return 1;
  }
  return 0;
}
