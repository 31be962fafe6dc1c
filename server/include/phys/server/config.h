// physd's configuration (configs/physd.toml), parsed with toml++. No DDS here.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "phys/protocol/security.h"
#include "phys/server/core.h"

namespace phys::server {

/// A world created at start-up.
struct StartupWorld {
  std::string name;
  std::string scene;    ///< a scene of scenes_dir by name; empty: an empty world
  std::string preset;   ///< empty: the presets file's default
  bool run = true;      ///< start running
  double rateHz = 0;    ///< 0: the server's default rate
  std::string backend;  ///< "cpu", "gpu", "auto"; empty: server.backend
  /// Not kept in `[paths] data`: recreated from this entry at every start. A durable
  /// start-up world is created once and restored from its checkpoint afterwards.
  bool ephemeral = false;
};

struct DaemonConfig {
  uint32_t domain = 0;            ///< DDS domain id
  std::string cycloneConfig;      ///< CYCLONEDDS_URI file (absolute); empty: Cyclone's own
  /// [dds] liveliness_s: the lease of phys/status's DDS liveliness. Clients count the daemon
  /// gone (and fail the requests it has not answered) once a lease passes with no sign of it:
  /// a killed or frozen process. 0: no lease (gone only when its status stops coming).
  double livelinessS = 1.0;
  std::string logLevel = "info";  ///< spdlog level name
  double statusPeriodS = 1.0;     ///< phys/status period
  /// 1..99: run the daemon's threads (tick, publisher, Cyclone's) under SCHED_FIFO at this
  /// priority, so subscribers and other processes on a busy host cannot delay a tick; 0: the
  /// normal scheduler. Needs CAP_SYS_NICE (or root, or an rtprio ulimit); else a warning.
  int realtimePriority = 0;
  /// s: how often the daemon hands freed memory back to the system (malloc_trim); 0: never.
  int trimPeriodS = 10;
  /// [security] dir, identity, plugins: DDS Security with the files tools/make_security.sh
  /// writes (docs/SECURITY.md); added to the Cyclone configuration. Empty identity: none.
  protocol::SecurityFiles security;
  CoreConfig core;
  std::vector<StartupWorld> worlds;
};

/// Reads a physd.toml. Relative paths in it are relative to the file's directory. Unknown
/// keys are errors (a typo should not silently keep a default).
Status loadDaemonConfig(const std::string& path, DaemonConfig* out);
/// The same from TOML text; baseDir resolves relative paths.
Status parseDaemonConfig(const std::string& text, const std::string& baseDir, DaemonConfig* out);

}  // namespace phys::server
