// physd: the physics daemon. Owns worlds, applies commands from phys/cmd at tick boundaries,
// publishes replies, state frames, world info and status over Cyclone DDS.
//
//   physd --config configs/physd.toml [--domain N] [--accept-loss WORLD|all ...]
//   physd --verify DATA      # every durable world's files under DATA; exit 0, or 1 on damage
#include <malloc.h>
#include <sched.h>
#include <signal.h>
#include <unistd.h>
#include <spdlog/spdlog.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <sstream>
#include <thread>

#include "phys/server/config.h"
#include "phys/server/core.h"
#include "phys/server/endpoint.h"
#include "phys/server/ownership.h"

using namespace phys::server;

namespace {

/// The configuration file with the command line's overrides, and the Cyclone XML (with
/// [security] added): 0, or the exit status after saying why not.
int configure(const std::string& configPath, int64_t domain,
              const std::vector<std::string>& acceptLoss, DaemonConfig* cfgOut,
              std::string* cycloneXmlOut) {
  DaemonConfig& cfg = *cfgOut;
  Status s = loadDaemonConfig(configPath, &cfg);
  if (!s.ok()) {
    spdlog::critical("{}", s.message);
    return 2;
  }
  if (domain >= 0) cfg.domain = uint32_t(domain);
  spdlog::set_level(spdlog::level::from_str(cfg.logLevel));
  for (const std::string& a : acceptLoss) {
    char* end = nullptr;
    const unsigned long id = std::strtoul(a.c_str(), &end, 10);
    if (a == "all") {
      cfg.core.acceptLoss.push_back(0);
    } else if (!a.empty() && end && *end == 0 && id > 0 && id <= UINT32_MAX) {
      cfg.core.acceptLoss.push_back(uint32_t(id));
    } else {
      spdlog::critical("--accept-loss takes world ids or 'all', got '{}'", a);
      return 2;
    }
  }
  if (!acceptLoss.empty() && cfg.core.dataDir.empty()) {
    spdlog::critical("--accept-loss: the config has no [paths] data");
    return 2;
  }

  std::string& cycloneXml = *cycloneXmlOut;
  if (!cfg.cycloneConfig.empty()) {
    std::ifstream f(cfg.cycloneConfig);
    if (!f) {
      spdlog::critical("cannot read Cyclone config {}", cfg.cycloneConfig);
      return 2;
    }
    std::stringstream ss;
    ss << f.rdbuf();
    cycloneXml = ss.str();
  }
  if (cfg.security.enabled()) {
    s = phys::protocol::addSecurity(&cycloneXml, cfg.security);
    if (!s.ok()) {
      spdlog::critical("{}", s.message);
      return 2;
    }
  }
  // With DDS Security (from [security] or a Cyclone configuration that has it, such as
  // configs/cyclonedds/secure.xml), world owners and editors are identities
  // (docs/SECURITY.md "Who owns a world").
  cfg.core.identities = cycloneXml.find("<Security") != std::string::npos;
  if (cfg.core.identities)
    spdlog::info("dds: security on; commands are attributed to identities");
  return 0;
}

/// The scheduler and the allocator, set before any thread starts.
void tuneProcess(const DaemonConfig& cfg) {
  // Real-time scheduling, set before any thread starts so that every thread inherits it.
  if (cfg.realtimePriority > 0) {
    sched_param sp{};
    sp.sched_priority = cfg.realtimePriority;
    if (sched_setscheduler(0, SCHED_FIFO, &sp) == 0)
      spdlog::info("SCHED_FIFO priority {}", cfg.realtimePriority);
    else
      spdlog::warn(
          "server.realtime_priority {}: {} (needs CAP_SYS_NICE, root or an rtprio ulimit); "
          "running with the normal scheduler",
          cfg.realtimePriority, std::strerror(errno));
  }

  // Blocks of 128 KiB and more (a world's contact and row buffers, state frames) come from
  // mmap and go back to the system whole when freed. glibc's default raises this threshold
  // to the largest block freed so far (up to 32 MiB), after which those buffers come from the
  // heaps, and a heap whose peak was reached once keeps its pages even after malloc_trim
  // below (the hour soak: RSS +6.2 % from minute 10 against heap in use +2.6 %, the rest
  // kept after one peak; docs/BENCHMARKS.md "Soak"). Setting it fixes it at 128 KiB.
  mallopt(M_MMAP_THRESHOLD, 128 * 1024);
}

/// The kept worlds restored, then the configuration's start-up worlds made: 0, or the exit
/// status after saying why not.
int startWorlds(ServerCore& core, const DaemonConfig& cfg) {
  Status s = Status::Ok();
  // Durable worlds first (docs/SERVER.md "Durable worlds"): a start-up world that was kept
  // is restored as it was, not created again.
  if (!cfg.core.dataDir.empty()) {
    std::vector<std::string> notes;
    if (core.coordinated()) {
      // Worlds its standby took while it was away are not replayed only to be let go.
      Status read;
      core.takenElsewhere(worldsHeldElsewhere(cfg.core, &read));
      if (!read.ok())
        spdlog::warn("coordinator: {} (kept worlds restored unconfirmed)", read.message);
    }
    s = core.restoreWorlds(&notes);
    for (const std::string& n : notes)
      if (n.find("restored at tick") != std::string::npos)
        spdlog::info("{}", n);
      else if (n.find("not restored") != std::string::npos || n.find("read-only") != std::string::npos)
        spdlog::error("{}", n);
      else
        spdlog::warn("{}", n);
    if (!s.ok()) {
      spdlog::critical("paths.data: {}", s.message);
      return 2;
    }
  }
  for (const StartupWorld& w : cfg.worlds) {
    if (ServerWorld* kept = core.findWorld(w.name); kept && !kept->ephemeral) continue;
    // A kept world that could not be restored is not made afresh under its name: that would
    // hide the loss (and the operator's --accept-loss would then find its name taken).
    const auto& damaged = core.damagedWorlds();
    if (std::any_of(damaged.begin(), damaged.end(),
                    [&](const auto& d) { return d.second.name == w.name; })) {
      spdlog::error("world '{}': not created afresh: the kept world of that name is damaged",
                    w.name);
      continue;
    }
    if (!core.readOnly().empty() && !w.ephemeral) {
      spdlog::error("world '{}': not created: physd is read-only ({})", w.name, core.readOnly());
      continue;
    }
    uint32_t id = 0;
    s = core.createWorld(w.name, w.preset, w.scene, &id, w.backend, w.ephemeral);
    if (!s.ok()) {
      spdlog::critical("world '{}': {}", w.name, s.message);
      return 2;
    }
    if (w.run) core.setRun(id, RunMode::RealTime, w.rateHz);
    const phys::BackendState& b = core.world(id)->world->backendState();
    spdlog::info("world {} '{}': scene '{}', {} bodies, {}, backend {}{}", id, w.name, w.scene,
                 core.world(id)->world->bodyCount(),
                 w.run ? "running at " + std::to_string(core.world(id)->rateHz) + " Hz"
                       : std::string("paused"),
                 phys::toString(b.active), b.device.empty() ? "" : " (" + b.device + ")");
    if (!b.note.empty()) spdlog::warn("world {} '{}': {}", id, w.name, b.note);
  }

  return 0;
}

/// Waits for SIGINT or SIGTERM (blocked in every thread), meanwhile giving the allocator's
/// free pages back every trim period; returns the signal.
int waitForSignal(const sigset_t& signals, const DaemonConfig& cfg) {
  // The daemon's threads allocate and free a world's contacts, rows and frames at every
  // tick, and glibc keeps what was freed, so the resident set creeps up to every arena's
  // high-water mark (the hour soak: 156 MB at minute 10, 247 MB at 60, with the heap in use
  // flat; docs/BENCHMARKS.md "Soak"). malloc_trim(0) returns free pages from the middle of
  // the heaps too.
  int sig = 0;
  if (cfg.trimPeriodS > 0) {
    const timespec period{cfg.trimPeriodS, 0};
    while ((sig = sigtimedwait(&signals, nullptr, &period)) <= 0) malloc_trim(0);
  } else {
    sigwait(&signals, &sig);
  }
  return sig;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"physd: rigid-body physics server over Cyclone DDS"};
  std::string configPath = "configs/physd.toml";
  int64_t domain = -1;
  app.add_option("--config", configPath, "physd.toml")->check(CLI::ExistingFile);
  app.add_option("--domain", domain, "DDS domain id (overrides dds.domain)")
      ->check(CLI::Range(0, 232));
  std::vector<std::string> acceptLoss;
  app.add_option("--accept-loss", acceptLoss,
                 "restore these worlds (ids, or 'all') although their journal is missing or "
                 "damaged: what is good is restored, the files are kept under <data>/damaged/")
      ->take_all();
  std::string verify;
  app.add_option("--verify", verify,
                 "check every world's files under this data directory (read only) and exit: "
                 "0 when none has lost acknowledged data, else 1");
  app.set_version_flag("--version", PHYSD_VERSION);
  CLI11_PARSE(app, argc, argv);

  if (!verify.empty()) {  // no config, no DDS: the files only
    std::string text;
    const bool ok = verifyDataDir(verify, &text);
    std::fputs(text.c_str(), stdout);
    return ok ? 0 : 1;
  }

  DaemonConfig cfg;
  std::string cycloneXml;
  if (int rc = configure(configPath, domain, acceptLoss, &cfg, &cycloneXml)) return rc;
  tuneProcess(cfg);

  // SIGINT and SIGTERM are taken by sigwait below; every thread started after this inherits
  // the blocked mask, so none of them is interrupted.
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGINT);
  sigaddset(&signals, SIGTERM);
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);

  ServerCore core(cfg.core);
  Status s = core.init();
  if (!s.ok()) {
    spdlog::critical("presets: {}", s.message);
    return 2;
  }
  core.setLog([](bool error, const std::string& line) {
    if (error)
      spdlog::error("{}", line);
    else
      spdlog::info("{}", line);
  });
  if (int rc = startWorlds(core, cfg)) return rc;

  EndpointConfig endpointConfig{cfg.domain, cycloneXml, cfg.core.identities};
  endpointConfig.liveliness = std::chrono::milliseconds(int64_t(cfg.livelinessS * 1000));
  DdsEndpoint endpoint(&core, endpointConfig);
  s = endpoint.start();
  if (!s.ok()) {
    spdlog::critical("dds: {}", s.message);
    return 1;
  }
  TickThread tick(&core, std::chrono::milliseconds(int64_t(cfg.statusPeriodS * 1000)));
  tick.start();
  // Standby and takeover: the hold in etcd, registrations, takeovers.
  Ownership ownership(&core);
  if (core.coordinated()) {
    ownership.start();
    spdlog::info("coordinator {} (keys under '{}'), standby {}", cfg.core.coordinator,
                 cfg.core.coordinatorPrefix, cfg.core.standby);
  }
  spdlog::info("physd {} '{}' on domain {}{}", PHYSD_VERSION, cfg.core.serverName, cfg.domain,
               core.readOnly().empty() ? "" : " (read-only: " + core.readOnly() + ")");

  // The main thread waits for a signal, and meanwhile trims the allocator's heaps.
  const int sig = waitForSignal(signals, cfg);
  spdlog::info("signal {}: shutting down", sig);
  // Shutdown finishes within a second whatever the tick thread is in (one engine step can be
  // long): past the deadline the process exits 0 without waiting for it.
  std::thread([] {
    std::this_thread::sleep_for(std::chrono::milliseconds(900));
    // Not spdlog: the main thread may be in static destruction by now.
    static const char kMsg[] = "physd: shutdown took more than 0.9 s; exiting now\n";
    if (::write(2, kMsg, sizeof kMsg - 1) < 0) {
    }
    std::_Exit(0);
  }).detach();
  ownership.stop();
  tick.stop();
  endpoint.stop();
  const auto& c = core.counters();
  spdlog::info("physd stopped: {} commands, {} rejected, {} steps, {} state frames dropped",
               c.commands, c.errors, c.steps, core.out().framesDropped());
  return 0;
}
