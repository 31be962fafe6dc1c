// flood_bench: other clients' reply latency while one participant floods physd (issue 39).
//
//   flood_bench --physd build/server/physd [--seconds 10] [--rate 50] [--scene pyramid_20]
//               [--domain D] [--phases idle,ids,one]
//
// For each phase a fresh physd (the binary given, on loopback: configs/cyclonedds/loopback.xml,
// a start-up world running --scene at 60 Hz) and:
//   idle  nothing else;
//   ids   a flooder process writes empty commands under a new client id each, as fast as it
//         can, and stays (issue 39's finding: 70,000 ids in 2.4 s);
//   one   a flooder process writes valid ListWorlds under one client id, as fast as it can.
// Meanwhile a measuring client (a participant of its own) sends ListWorlds at --rate a second,
// whatever is outstanding, and times each reply (a request unanswered 5 s after the phase is
// lost); and once a second a new client (a new participant and id) sends Hello and waits up to
// 5 s for the reply (admitted or not). Printed per phase: the flooder's commands, the
// measuring client's p50/p99/max and lost requests, new clients admitted and their Hello p50,
// physd's CPU seconds and resident MB, and physd's first log lines about client ids.
//
//   flood_bench --flood ids|one --domain D --report FILE   (the flooder; started by the above)
#include <fcntl.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <mutex>
#include <optional>
#include <random>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "phys/protocol/builder.h"
#include "phys/protocol/decoder.h"
#include "phys/protocol/dds.h"
#include "phys/protocol/dds_envelope.h"

extern char** environ;

namespace {

using Clock = std::chrono::steady_clock;
using namespace std::chrono_literals;
namespace dds = phys::protocol::dds;
namespace fs = std::filesystem;
using phys::protocol::CommandBuilder;

double msSince(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

/// A raw client: a participant of its own, a phys/cmd writer and a phys/reply reader.
struct RawClient {
  explicit RawClient(uint32_t domain) {
    std::string err;
    ok = p.create(domain, "", &err) && cmdTopic.create(p, "phys/cmd", &err) &&
         replyTopic.create(p, "phys/reply", &err) &&
         cmd.create(p, cmdTopic, phys::protocol::kCommandQos, phys::protocol::PayloadKind::Command,
                    &err) &&
         replies.create(p, replyTopic, phys::protocol::kReplyQos, &err);
    if (!ok) std::fprintf(stderr, "flood_bench: %s\n", err.c_str());
  }
  bool matched(std::chrono::milliseconds timeout) {
    const auto end = Clock::now() + timeout;
    while (Clock::now() < end) {
      if (cmd.matched() > 0 && replies.matched() > 0) return true;
      std::this_thread::sleep_for(5ms);
    }
    return false;
  }
  /// Replies to `key`, by seq, taken now.
  void take(uint64_t key, const std::function<void(uint64_t seq)>& fn) {
    replies.take([&](const phys_wire_Envelope& env) {
      if (env.key != key) return;
      auto b = phys::protocol::envelopeBytes(env);
      auto r = phys::protocol::decodeReply(std::vector<uint8_t>(b.begin(), b.end()));
      if (r.ok()) fn(r->seq());
    });
  }
  bool ok = false;
  dds::Participant p;
  dds::Topic cmdTopic, replyTopic;
  dds::Writer cmd;
  dds::Reader replies;
};

// --- The flooder (a process of its own: its writes do not share this process's DDS threads) -

std::atomic<bool> gStop{false};
void onTerm(int) { gStop = true; }

int flood(const std::string& mode, uint32_t domain, const std::string& report) {
  signal(SIGTERM, onTerm);
  RawClient c(domain);
  if (!c.ok || !c.matched(30s)) return 2;
  std::mt19937_64 rng(std::random_device{}());
  const uint64_t base = (rng() | 1ull << 63) & ~0xFFFFFFFFull;
  const uint64_t one = base | 0x1;
  const phys::protocol::Bytes list = CommandBuilder().listWorlds().finish({one, 1, 0});
  uint64_t written = 0, failed = 0;
  phys_wire_Envelope env{};
  const auto t0 = Clock::now();
  for (uint64_t i = 0; !gStop.load(); ++i) {
    if (mode == "ids")
      phys::protocol::wrapEnvelope(&env, base + i, 1, phys::protocol::PayloadKind::Command, {});
    else
      phys::protocol::wrapEnvelope(&env, one, i + 1, phys::protocol::PayloadKind::Command, list);
    if (dds_write(c.cmd.get(), &env) == DDS_RETCODE_OK)
      ++written;
    else
      ++failed;
  }
  std::ofstream(report) << written << " " << failed << " " << msSince(t0) / 1000 << "\n";
  return 0;
}

// --- physd -----------------------------------------------------------------------------------

struct ProcStat {
  double cpuS = 0;
  double rssMb = 0;
};
ProcStat procStat(pid_t pid) {
  ProcStat s;
  std::ifstream f("/proc/" + std::to_string(pid) + "/stat");
  std::string line;
  std::getline(f, line);
  const size_t close = line.rfind(')');
  if (close != std::string::npos) {
    std::istringstream in(line.substr(close + 2));
    std::vector<std::string> fields;
    for (std::string w; in >> w;) fields.push_back(w);
    // Fields from 3 (state) on: utime is field 14, stime 15.
    if (fields.size() > 13)
      s.cpuS = double(std::stoull(fields[11]) + std::stoull(fields[12])) /
               double(sysconf(_SC_CLK_TCK));
  }
  std::ifstream st("/proc/" + std::to_string(pid) + "/status");
  while (std::getline(st, line))
    if (line.rfind("VmRSS:", 0) == 0) s.rssMb = std::stod(line.substr(6)) / 1024;
  return s;
}

pid_t spawn(const std::vector<std::string>& args, const std::string& out) {
  posix_spawn_file_actions_t fa;
  posix_spawn_file_actions_init(&fa);
  if (!out.empty()) {
    posix_spawn_file_actions_addopen(&fa, 1, out.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    posix_spawn_file_actions_adddup2(&fa, 1, 2);
  }
  std::vector<char*> argv;
  for (const std::string& a : args) argv.push_back(const_cast<char*>(a.c_str()));
  argv.push_back(nullptr);
  pid_t pid = 0;
  const int rc = posix_spawn(&pid, argv[0], &fa, nullptr, argv.data(), environ);
  posix_spawn_file_actions_destroy(&fa);
  return rc == 0 ? pid : -1;
}

void stop(pid_t pid) {
  if (pid <= 0) return;
  kill(pid, SIGTERM);
  for (int i = 0; i < 500; ++i) {
    if (waitpid(pid, nullptr, WNOHANG) == pid) return;
    std::this_thread::sleep_for(10ms);
  }
  kill(pid, SIGKILL);
  waitpid(pid, nullptr, 0);
}

// --- Measuring --------------------------------------------------------------------------------

struct Phase {
  std::string name;
  uint64_t flooderWrote = 0;
  double flooderS = 0;
  size_t requests = 0, answered = 0;
  double p50 = 0, p99 = 0, max = 0;  ///< ms; infinity: not answered
  int newcomers = 0, admitted = 0;
  double helloP50 = 0;
  double cpuS = 0, rssMb = 0;
  std::vector<std::string> log;  ///< physd's first lines about client ids
};

double percentile(std::vector<double> v, double q) {
  if (v.empty()) return INFINITY;
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, size_t(q * double(v.size() - 1) + 0.5))];
}

/// New clients, one a second: each a participant of its own that sends Hello once matched.
void newcomers(uint32_t domain, std::atomic<bool>* done, Phase* ph, std::mutex* m,
               std::vector<double>* hellos) {
  std::mt19937_64 rng(std::random_device{}());
  while (!done->load()) {
    const auto started = Clock::now();
    {
      RawClient c(domain);
      const uint64_t key = rng() >> 1 | 1;
      bool admitted = false;
      if (c.ok && c.matched(5s)) {
        const auto t0 = Clock::now();
        c.cmd.write(key, CommandBuilder().hello("newcomer").finish({key, 1, 0}), 1);
        while (!admitted && Clock::now() - t0 < 5s) {
          c.take(key, [&](uint64_t seq) { admitted |= seq == 1; });
          if (admitted) {
            std::lock_guard<std::mutex> lock(*m);
            hellos->push_back(msSince(t0));
          }
          std::this_thread::sleep_for(1ms);
        }
      }
      std::lock_guard<std::mutex> lock(*m);
      ++ph->newcomers;
      ph->admitted += admitted;
    }
    while (!done->load() && Clock::now() - started < 1s) std::this_thread::sleep_for(10ms);
  }
}

Phase run(const std::string& name, const std::string& physd, const std::string& self,
          uint32_t domain, double seconds, double rate, const std::string& scene) {
  Phase ph;
  ph.name = name;
  const fs::path dir = fs::temp_directory_path() / ("flood_bench_" + std::to_string(getpid()));
  fs::create_directories(dir);
  const std::string src = PHYS_SOURCE_DIR;
  {
    std::ofstream f(dir / "physd.toml");
    f << "[server]\nname = \"flood-bench\"\nlog_level = \"warn\"\nstatus_period_s = 1.0\n"
      << "[dds]\ndomain = " << domain << "\nconfig = \"" << src
      << "/configs/cyclonedds/loopback.xml\"\n"
      << "[paths]\npresets = \"" << src << "/configs/presets.json\"\nscenes = \"" << src
      << "/configs/scenes\"\n";
    if (!scene.empty())
      f << "[[worlds]]\nname = \"beside\"\nscene = \"" << scene << "\"\nrun = true\nrate_hz = 60\n";
  }
  const pid_t daemon =
      spawn({physd, "--config", (dir / "physd.toml").string()}, (dir / "physd.log").string());
  RawClient probe(domain);
  const uint64_t key = 0xBE7C000000000000ull | uint64_t(getpid()) << 16;
  uint64_t seq = 0;
  // Ready: Hello answered.
  bool ready = false;
  for (auto end = Clock::now() + 30s; !ready && Clock::now() < end;) {
    if (!probe.matched(1s)) continue;
    const uint64_t s = ++seq;
    probe.cmd.write(key, CommandBuilder().hello("probe").finish({key, s, 0}), s);
    for (auto t = Clock::now(); !ready && Clock::now() - t < 1s; std::this_thread::sleep_for(2ms))
      probe.take(key, [&](uint64_t r) { ready |= r == s; });
  }
  if (!ready) {
    std::fprintf(stderr, "flood_bench: physd did not answer (log: %s)\n",
                 (dir / "physd.log").c_str());
    stop(daemon);
    return ph;
  }
  pid_t flooder = -1;
  const std::string report = (dir / "flooder.txt").string();
  if (name != "idle") {
    flooder = spawn({self, "--flood", name, "--domain", std::to_string(domain), "--report", report},
                    "");
    std::this_thread::sleep_for(1500ms);  // matched, and flooding
  }
  const ProcStat before = procStat(daemon);
  std::atomic<bool> done{false};
  std::mutex m;
  std::vector<double> hellos;
  std::thread newcomerThread(newcomers, domain, &done, &ph, &m, &hellos);
  // Open loop: a request every 1/rate s, whatever is outstanding.
  std::map<uint64_t, Clock::time_point> sent;
  std::vector<double> latencies;
  const auto period = std::chrono::duration<double>(1.0 / rate);
  const auto t0 = Clock::now();
  auto next = t0;
  auto takeReplies = [&] {
    probe.take(key, [&](uint64_t s) {
      auto it = sent.find(s);
      if (it == sent.end()) return;
      latencies.push_back(msSince(it->second));
      sent.erase(it);
    });
  };
  while (Clock::now() - t0 < std::chrono::duration<double>(seconds)) {
    if (Clock::now() >= next) {
      const uint64_t s = ++seq;
      probe.cmd.write(key, CommandBuilder().listWorlds().finish({key, s, 0}), s);
      sent[s] = Clock::now();
      ++ph.requests;
      next += std::chrono::duration_cast<Clock::duration>(period);
    }
    takeReplies();
    std::this_thread::sleep_for(500us);
  }
  const ProcStat after = procStat(daemon);
  // Late replies count (their latency says how late), up to 5 s; the flooder still floods.
  for (auto end = Clock::now() + 5s; !sent.empty() && Clock::now() < end;
       std::this_thread::sleep_for(1ms))
    takeReplies();
  done = true;
  newcomerThread.join();
  if (flooder > 0) {
    stop(flooder);
    std::ifstream f(report);
    uint64_t failed = 0;
    f >> ph.flooderWrote >> failed >> ph.flooderS;
  }
  stop(daemon);
  ph.answered = latencies.size();
  std::vector<double> all = latencies;
  all.insert(all.end(), sent.size(), INFINITY);  // unanswered
  ph.p50 = percentile(all, 0.5);
  ph.p99 = percentile(all, 0.99);
  ph.max = percentile(all, 1.0);
  ph.helloP50 = percentile(hellos, 0.5);
  ph.cpuS = after.cpuS - before.cpuS;
  ph.rssMb = after.rssMb;
  std::ifstream log(dir / "physd.log");
  for (std::string line; std::getline(log, line);)
    if ((line.find("client id") != std::string::npos ||
         line.find("client key") != std::string::npos) &&
        ph.log.size() < 3)
      ph.log.push_back(line);
  fs::remove_all(dir);
  return ph;
}

std::string ms(double v) {
  if (!std::isfinite(v)) return "none";
  char s[32];
  std::snprintf(s, sizeof s, v < 10 ? "%.2f" : "%.0f", v);
  return s;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"flood_bench: other clients' reply latency while one participant floods physd"};
  std::string physd, floodMode, report, phases = "idle,ids,one", scene = "pyramid_20";
  uint32_t domain = 100 + uint32_t(getpid() % 100);
  double seconds = 10, rate = 50;
  app.add_option("--physd", physd, "the physd binary to measure");
  app.add_option("--domain", domain, "DDS domain (default: from the process id)");
  app.add_option("--seconds", seconds, "measured seconds per phase");
  app.add_option("--rate", rate, "the measuring client's requests a second");
  app.add_option("--scene", scene, "start-up world running at 60 Hz beside (\"\": none)");
  app.add_option("--phases", phases, "idle, ids, one (comma-separated)");
  app.add_option("--flood", floodMode, "run as the flooder: ids or one")->check(CLI::IsMember({"ids", "one"}));
  app.add_option("--report", report, "the flooder's count goes here");
  CLI11_PARSE(app, argc, argv);
  const std::string uri = "file://" + std::string(PHYS_SOURCE_DIR) + "/configs/cyclonedds/loopback.xml";
  setenv("CYCLONEDDS_URI", uri.c_str(), 0);
  if (!floodMode.empty()) return flood(floodMode, domain, report);
  if (physd.empty()) {
    std::fprintf(stderr, "flood_bench: give --physd\n");
    return 2;
  }
  const std::string self = fs::canonical("/proc/self/exe").string();
  std::printf("physd %s, domain %u, %.0f s a phase, %.0f requests a second, scene '%s'\n\n",
              physd.c_str(), domain, seconds, rate, scene.c_str());
  std::printf("| phase | flooder's commands | requests | answered | p50 ms | p99 ms | max ms | "
              "new clients admitted | their Hello p50 ms | physd CPU s | physd RSS MB |\n");
  std::printf("|---|---|---|---|---|---|---|---|---|---|---|\n");
  std::fflush(stdout);
  std::vector<std::vector<std::string>> logs;
  std::stringstream list(phases);
  for (std::string name; std::getline(list, name, ',');) {
    Phase p = run(name, physd, self, domain, seconds, rate, scene);
    char flooder[64] = "-";
    if (p.flooderS > 0)
      std::snprintf(flooder, sizeof flooder, "%llu (%.0f/s)", (unsigned long long)p.flooderWrote,
                    double(p.flooderWrote) / p.flooderS);
    std::printf("| %s | %s | %zu | %zu | %s | %s | %s | %d of %d | %s | %.1f | %.0f |\n",
                p.name.c_str(), flooder, p.requests, p.answered, ms(p.p50).c_str(),
                ms(p.p99).c_str(), ms(p.max).c_str(), p.admitted, p.newcomers,
                ms(p.helloP50).c_str(), p.cpuS, p.rssMb);
    std::fflush(stdout);
    logs.push_back(p.log);
  }
  std::printf("\nphysd's first log lines about client ids, per phase:\n");
  for (auto& l : logs)
    for (auto& line : l) std::printf("  %s\n", line.c_str());
  return 0;
}
