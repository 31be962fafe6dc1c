// configs/physd.toml -> DaemonConfig.
#include "phys/server/config.h"

#include <toml++/toml.h>

#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>

#include "phys/protocol/cluster.h"

namespace phys::server {

namespace {

namespace fs = std::filesystem;

std::string resolve(const std::string& baseDir, const std::string& p) {
  if (p.empty() || fs::path(p).is_absolute()) return p;
  return (fs::path(baseDir) / p).lexically_normal().string();
}

/// Keys of a table that are not in `known`.
Status checkKeys(const toml::table& t, const std::set<std::string>& known,
                 const std::string& where) {
  for (auto&& [k, v] : t)
    if (!known.count(std::string(k.str())))
      return Status::Error(Code::InvalidArgument,
                           where + ": unknown key '" + std::string(k.str()) + "'");
  return Status::Ok();
}

template <class T>
Status get(const toml::table& t, const char* key, const std::string& where, T* out) {
  const toml::node* n = t.get(key);
  if (!n) return Status::Ok();
  if constexpr (std::is_same_v<T, std::string>) {
    if (auto v = n->value<std::string>()) {
      *out = *v;
      return Status::Ok();
    }
  } else if constexpr (std::is_same_v<T, bool>) {
    if (auto v = n->value<bool>()) {
      *out = *v;
      return Status::Ok();
    }
  } else if constexpr (std::is_floating_point_v<T>) {
    if (auto v = n->value<double>()) {
      *out = T(*v);
      return Status::Ok();
    }
  } else {
    if (auto v = n->value<int64_t>(); v && *v >= 0) {
      *out = T(*v);
      return Status::Ok();
    }
  }
  return Status::Error(Code::InvalidArgument, where + "." + key + " has the wrong type or range");
}

/// A backend name ("cpu", "gpu", "auto") at where.key, if the key is there.
Status getBackend(const toml::table& t, const std::string& where, std::string* text,
                  phys::Backend* out) {
  std::string v;
  Status s = get(t, "backend", where, &v);
  if (!s.ok() || !t.get("backend")) return s;
  phys::Backend b;
  if (!phys::parseBackend(v, &b))
    return Status::Error(
        Code::InvalidArgument,
        where + ".backend must be \"cpu\", \"gpu\" or \"auto\", got \"" + v + "\"");
  if (text) *text = v;
  if (out) *out = b;
  return Status::Ok();
}

#define PHYS_GET(t, key, where, out)     \
  do {                                   \
    Status s_ = get(t, key, where, out); \
    if (!s_.ok()) return s_;             \
  } while (0)

/// A size given in MiB at where.key, if the key is there, as bytes.
Status getMiB(const toml::table& t, const char* key, const std::string& where, uint64_t* bytes) {
  if (!t.get(key)) return Status::Ok();
  uint64_t mb = 0;
  Status s = get(t, key, where, &mb);
  if (s.ok()) *bytes = mb << 20;
  return s;
}

/// A key that is one of two words at where.key, if the key is there, as a bool (true: the
/// first word); *first keeps its value otherwise.
Status getEither(const toml::table& t, const char* key, const std::string& where,
                 const char* yes, const char* no, bool* first) {
  std::string word = *first ? yes : no;
  Status s = get(t, key, where, &word);
  if (!s.ok()) return s;
  if (word != yes && word != no)
    return Status::Error(Code::InvalidArgument, "physd config: " + where + "." + key +
                                                    " must be \"" + yes + "\" or \"" + no +
                                                    "\", got \"" + word + "\"");
  *first = word == yes;
  return Status::Ok();
}

#define PHYS_GET_MIB(t, key, where, out)    \
  do {                                      \
    Status s_ = getMiB(t, key, where, out); \
    if (!s_.ok()) return s_;                \
  } while (0)

/// The checks across keys, once every key is read; fills what follows from them.
Status checkDaemonConfig(DaemonConfig* config) {
  DaemonConfig& c = *config;
  if (c.core.serverId == 0)
    return Status::Error(Code::InvalidArgument, "server.id must be non-zero");
  if (c.core.cluster && c.core.serverId > protocol::kMaxClusterDaemonId)
    return Status::Error(Code::InvalidArgument,
                         "server.id must be 1.." + std::to_string(protocol::kMaxClusterDaemonId) +
                             " with [cluster] enabled (world ids carry it), got " +
                             std::to_string(c.core.serverId));
  if (c.statusPeriodS <= 0)
    return Status::Error(Code::InvalidArgument, "server.status_period_s must be > 0");
  if (!(c.livelinessS == 0 || (c.livelinessS >= 0.05 && c.livelinessS <= 3600)))
    return Status::Error(Code::InvalidArgument,
                         "dds.liveliness_s must be 0 (no lease) or 0.05..3600 s");
  if (!c.core.coordinator.empty()) {
    // Standby and takeover (docs/SERVER.md "Standby and takeover").
    if (!c.core.cluster)
      return Status::Error(Code::InvalidArgument, "cluster.coordinator needs [cluster] enabled");
    if (c.core.dataDir.empty())
      return Status::Error(Code::InvalidArgument,
                           "cluster.coordinator needs [paths] data (a standby takes worlds over "
                           "from their owner's files)");
    if (!c.core.coordinator.starts_with("http://") && !c.core.coordinator.starts_with("https://"))
      return Status::Error(Code::InvalidArgument,
                           "cluster.coordinator must be etcd's client URL (http://host:port), got '" +
                               c.core.coordinator + "'");
    if (c.core.coordinatorPrefix.empty())
      return Status::Error(Code::InvalidArgument, "cluster.coordinator_prefix must not be empty");
    if (!(c.core.renewPeriodS > 0 && c.core.renewPeriodS < c.core.fenceAfterS &&
          c.core.fenceAfterS < c.core.takeoverAfterS && c.core.takeoverAfterS <= 60 &&
          c.core.standbyLeasePeriodS >= 0 && c.core.standbyLeasePeriodS <= 60))
      return Status::Error(Code::InvalidArgument,
                           "cluster: 0 < renew_period_s < fence_after_s < takeover_after_s <= 60 "
                           "must hold (a standby must not take a world its owner still serves), "
                           "and 0 <= lease_period_s <= 60");
  } else if (c.core.standby != 0) {
    return Status::Error(Code::InvalidArgument,
                         "cluster.standby needs cluster.coordinator (etcd's client URL)");
  }
  if (c.core.standby != 0 &&
      (c.core.standby == c.core.serverId || c.core.standby > protocol::kMaxClusterDaemonId))
    return Status::Error(Code::InvalidArgument,
                         "cluster.standby must be another daemon's server.id (1.." +
                             std::to_string(protocol::kMaxClusterDaemonId) + ")");
  c.core.statusPeriodS = c.statusPeriodS;
  if (c.trimPeriodS < 0 || c.trimPeriodS > 86400)
    return Status::Error(Code::InvalidArgument,
                         "server.trim_period_s must be 0 (never) or 1..86400 s");
  if (c.realtimePriority < 0 || c.realtimePriority > 99)
    return Status::Error(Code::InvalidArgument,
                         "server.realtime_priority must be 0 (off) or 1..99, got " +
                             std::to_string(c.realtimePriority));
  return Status::Ok();
}

}  // namespace

namespace {
/// [cluster] (docs/SERVER.md "Several daemons", "Standby and takeover").
Status parseCluster(const toml::table& t, CoreConfig* core) {
  Status s = checkKeys(t,
                       {"enabled", "coordinator", "coordinator_prefix", "standby", "renew_period_s",
                        "fence_after_s", "takeover_after_s", "lease_period_s"},
                       "cluster");
  if (!s.ok()) return s;
  PHYS_GET(t, "enabled", "cluster", &core->cluster);
  PHYS_GET(t, "coordinator", "cluster", &core->coordinator);
  PHYS_GET(t, "coordinator_prefix", "cluster", &core->coordinatorPrefix);
  PHYS_GET(t, "standby", "cluster", &core->standby);
  PHYS_GET(t, "renew_period_s", "cluster", &core->renewPeriodS);
  PHYS_GET(t, "fence_after_s", "cluster", &core->fenceAfterS);
  PHYS_GET(t, "takeover_after_s", "cluster", &core->takeoverAfterS);
  PHYS_GET(t, "lease_period_s", "cluster", &core->standbyLeasePeriodS);
  return Status::Ok();
}
}  // namespace

Status parseDaemonConfig(const std::string& text, const std::string& baseDir, DaemonConfig* out) {
  toml::table root;
  try {
    root = toml::parse(text);
  } catch (const toml::parse_error& e) {
    std::ostringstream os;
    os << "physd config: " << e.description() << " at line " << e.source().begin.line;
    return Status::Error(Code::InvalidArgument, os.str());
  }
  DaemonConfig c;
  Status s = checkKeys(root, {"server", "dds", "cluster", "security", "paths", "limits", "worlds"},
                 "physd config");
  if (!s.ok()) return s;
  if (auto* t = root["server"].as_table()) {
    s = checkKeys(*t,
                  {"name", "id", "log_level", "threads", "default_rate_hz", "max_catch_up_steps",
                   "status_period_s", "bodies_per_chunk", "keyframe_ticks", "refresh", "state_encoding",
                   "frame_ring", "max_worlds",
                   "realtime_priority", "backend", "gpu_allow_cpu_device",
                   "max_bodies_per_world", "max_joints_per_world", "max_bodies_total",
                   "memory_budget_mb", "max_snapshot_files", "max_snapshot_mb",
                   "max_queued_per_client", "max_queued_mb", "max_queued_mb_per_client",
                   "step_slice_ms", "max_contact_pairs", "max_concurrent_loads",
                   "checkpoint_period_s", "journal_max_mb", "max_client_commands_per_s",
                   "max_client_burst", "trim_period_s", "max_keys_per_participant",
                   "max_participant_commands_per_s", "max_participant_burst",
                   "max_queued_mb_per_participant", "max_participant_refusals_per_s",
                   "max_interests_per_client"},
                  "server");
    if (!s.ok()) return s;
    PHYS_GET(*t, "name", "server", &c.core.serverName);
    PHYS_GET(*t, "id", "server", &c.core.serverId);
    PHYS_GET(*t, "log_level", "server", &c.logLevel);
    PHYS_GET(*t, "threads", "server", &c.core.threads);
    PHYS_GET(*t, "default_rate_hz", "server", &c.core.defaultRateHz);
    PHYS_GET(*t, "max_catch_up_steps", "server", &c.core.maxCatchUpSteps);
    PHYS_GET(*t, "status_period_s", "server", &c.statusPeriodS);
    PHYS_GET(*t, "bodies_per_chunk", "server", &c.core.bodiesPerChunk);
    PHYS_GET(*t, "keyframe_ticks", "server", &c.core.keyframeTicks);
    if (c.core.keyframeTicks < 1)
      return Status::Error(Code::InvalidArgument,
                           "physd config: server.keyframe_ticks must be >= 1 (1: every frame a keyframe)");
    s = getEither(*t, "refresh", "server", "rolling", "keyframe", &c.core.rollingRefresh);
    if (!s.ok()) return s;
    bool full = !c.core.compactStates;
    s = getEither(*t, "state_encoding", "server", "full", "compact", &full);
    if (!s.ok()) return s;
    c.core.compactStates = !full;
    PHYS_GET(*t, "frame_ring", "server", &c.core.frameRingCapacity);
    PHYS_GET(*t, "max_worlds", "server", &c.core.maxWorlds);
    PHYS_GET(*t, "realtime_priority", "server", &c.realtimePriority);
    PHYS_GET(*t, "trim_period_s", "server", &c.trimPeriodS);
    s = getBackend(*t, "server", nullptr, &c.core.backend);
    if (!s.ok()) return s;
    PHYS_GET(*t, "gpu_allow_cpu_device", "server", &c.core.gpuAllowCpuDevice);
    // Budgets (docs/SERVER.md "Budgets").
    PHYS_GET(*t, "max_bodies_per_world", "server", &c.core.maxBodiesPerWorld);
    PHYS_GET(*t, "max_joints_per_world", "server", &c.core.maxJointsPerWorld);
    PHYS_GET(*t, "max_bodies_total", "server", &c.core.maxBodiesTotal);
    PHYS_GET(*t, "max_snapshot_files", "server", &c.core.maxSnapshotFiles);
    PHYS_GET(*t, "max_queued_per_client", "server", &c.core.maxQueuedPerClient);
    PHYS_GET(*t, "max_contact_pairs", "server", &c.core.maxContactPairs);
    PHYS_GET(*t, "max_concurrent_loads", "server", &c.core.maxConcurrentLoads);
    PHYS_GET_MIB(*t, "memory_budget_mb", "server", &c.core.memoryBudgetBytes);
    PHYS_GET_MIB(*t, "max_snapshot_mb", "server", &c.core.maxSnapshotBytes);
    PHYS_GET_MIB(*t, "max_queued_mb", "server", &c.core.maxQueuedBytes);
    PHYS_GET_MIB(*t, "max_queued_mb_per_client", "server", &c.core.maxQueuedBytesPerClient);
    PHYS_GET(*t, "max_client_commands_per_s", "server", &c.core.maxClientCommandsPerS);
    PHYS_GET(*t, "max_client_burst", "server", &c.core.maxClientBurst);
    if (!(c.core.maxClientCommandsPerS >= 0) || !(c.core.maxClientBurst >= 1))
      return Status::Error(Code::InvalidArgument,
                           "server.max_client_commands_per_s must be >= 0 (0: no limit) and "
                           "server.max_client_burst >= 1");
    // Per DDS participant, whatever client ids it uses (docs/SERVER.md "Budgets").
    PHYS_GET(*t, "max_keys_per_participant", "server", &c.core.maxKeysPerParticipant);
    PHYS_GET(*t, "max_participant_commands_per_s", "server", &c.core.maxParticipantCommandsPerS);
    PHYS_GET(*t, "max_participant_burst", "server", &c.core.maxParticipantBurst);
    PHYS_GET_MIB(*t, "max_queued_mb_per_participant", "server",
                 &c.core.maxQueuedBytesPerParticipant);
    PHYS_GET(*t, "max_participant_refusals_per_s", "server", &c.core.maxParticipantRefusalsPerS);
    PHYS_GET(*t, "max_interests_per_client", "server", &c.core.maxInterestsPerClient);
    if (c.core.maxKeysPerParticipant == 0 || c.core.maxInterestsPerClient == 0)
      return Status::Error(Code::InvalidArgument,
                           "server.max_keys_per_participant and server.max_interests_per_client "
                           "must be >= 1");
    if (!(c.core.maxParticipantCommandsPerS >= 0) || !(c.core.maxParticipantBurst >= 1) ||
        !(c.core.maxParticipantRefusalsPerS >= 0))
      return Status::Error(Code::InvalidArgument,
                           "server.max_participant_commands_per_s and "
                           "max_participant_refusals_per_s must be >= 0 (0: no limit) and "
                           "server.max_participant_burst >= 1");
    // Durability (docs/SERVER.md "Durable worlds").
    PHYS_GET(*t, "checkpoint_period_s", "server", &c.core.checkpointPeriodS);
    PHYS_GET_MIB(*t, "journal_max_mb", "server", &c.core.journalMaxBytes);
    if (!(c.core.checkpointPeriodS >= 0.1))
      return Status::Error(Code::InvalidArgument, "server.checkpoint_period_s must be >= 0.1");
    if (c.core.journalMaxBytes == 0)
      return Status::Error(Code::InvalidArgument, "server.journal_max_mb must be >= 1");
    double sliceMs = c.core.stepSliceSeconds * 1000;
    PHYS_GET(*t, "step_slice_ms", "server", &sliceMs);
    if (!(sliceMs >= 1 && sliceMs <= 1000))
      return Status::Error(Code::InvalidArgument, "server.step_slice_ms must be in [1, 1000]");
    c.core.stepSliceSeconds = sliceMs / 1000;
    if (c.core.maxQueuedPerClient == 0)
      return Status::Error(Code::InvalidArgument, "server.max_queued_per_client must be >= 1");
    if (c.core.maxConcurrentLoads == 0)
      return Status::Error(Code::InvalidArgument, "server.max_concurrent_loads must be >= 1");
  }
  if (auto* t = root["cluster"].as_table()) {
    s = parseCluster(*t, &c.core);
    if (!s.ok()) return s;
  }
  if (auto* t = root["dds"].as_table()) {
    s = checkKeys(*t, {"domain", "config", "liveliness_s"}, "dds");
    if (!s.ok()) return s;
    PHYS_GET(*t, "domain", "dds", &c.domain);
    PHYS_GET(*t, "liveliness_s", "dds", &c.livelinessS);
    PHYS_GET(*t, "config", "dds", &c.cycloneConfig);
    c.cycloneConfig = resolve(baseDir, c.cycloneConfig);
  }
  if (auto* t = root["security"].as_table()) {
    s = checkKeys(*t, {"dir", "identity", "plugins"}, "security");
    if (!s.ok()) return s;
    std::string dir, identity, plugins;
    PHYS_GET(*t, "dir", "security", &dir);
    PHYS_GET(*t, "identity", "security", &identity);
    PHYS_GET(*t, "plugins", "security", &plugins);
    if (dir.empty() || !protocol::validIdentityName(identity))
      return Status::Error(Code::InvalidArgument,
                           "security: give dir (tools/make_security.sh's folder) and identity "
                           "(1-64 characters of A-Z a-z 0-9 _ . -)");
    c.security = protocol::SecurityFiles::fromDir(resolve(baseDir, dir), identity);
    if (!plugins.empty()) c.security.pluginDir = resolve(baseDir, plugins);
  }
  if (auto* t = root["paths"].as_table()) {
    s = checkKeys(*t, {"presets", "scenes", "snapshots", "data"}, "paths");
    if (!s.ok()) return s;
    PHYS_GET(*t, "presets", "paths", &c.core.presetsFile);
    PHYS_GET(*t, "scenes", "paths", &c.core.scenesDir);
    PHYS_GET(*t, "snapshots", "paths", &c.core.snapshotDir);
    c.core.presetsFile = resolve(baseDir, c.core.presetsFile);
    c.core.scenesDir = resolve(baseDir, c.core.scenesDir);
    c.core.snapshotDir = resolve(baseDir, c.core.snapshotDir);
    PHYS_GET(*t, "data", "paths", &c.core.dataDir);
    c.core.dataDir = resolve(baseDir, c.core.dataDir);
  }
  if (auto* t = root["limits"].as_table()) {
    protocol::Limits& l = c.core.limits;
    s = checkKeys(*t,
                  {"max_bodies_per_command", "max_joints_per_command", "max_ids_per_command",
                   "max_items_per_command", "max_batch_commands", "max_steps_per_command",
                   "max_body_steps_per_command"},
                  "limits");
    if (!s.ok()) return s;
    PHYS_GET(*t, "max_bodies_per_command", "limits", &l.maxBodiesPerCommand);
    PHYS_GET(*t, "max_joints_per_command", "limits", &l.maxJointsPerCommand);
    PHYS_GET(*t, "max_ids_per_command", "limits", &l.maxIdsPerCommand);
    PHYS_GET(*t, "max_items_per_command", "limits", &l.maxItemsPerCommand);
    PHYS_GET(*t, "max_batch_commands", "limits", &l.maxBatchCommands);
    PHYS_GET(*t, "max_steps_per_command", "limits", &l.maxStepsPerCommand);
    PHYS_GET(*t, "max_body_steps_per_command", "limits", &l.maxBodyStepsPerCommand);
  }
  if (const toml::node* wn = root.get("worlds")) {
    const toml::array* arr = wn->as_array();
    if (!arr) return Status::Error(Code::InvalidArgument, "worlds must be an array of tables");
    for (size_t i = 0; i < arr->size(); ++i) {
      const toml::table* t = arr->get(i)->as_table();
      const std::string where = "worlds[" + std::to_string(i) + "]";
      if (!t) return Status::Error(Code::InvalidArgument, where + " must be a table");
      s = checkKeys(*t, {"name", "scene", "preset", "run", "rate_hz", "backend", "ephemeral"},
                    where);
      if (!s.ok()) return s;
      StartupWorld w;
      PHYS_GET(*t, "name", where, &w.name);
      PHYS_GET(*t, "scene", where, &w.scene);
      PHYS_GET(*t, "preset", where, &w.preset);
      PHYS_GET(*t, "run", where, &w.run);
      PHYS_GET(*t, "rate_hz", where, &w.rateHz);
      PHYS_GET(*t, "ephemeral", where, &w.ephemeral);
      s = getBackend(*t, where, &w.backend, nullptr);
      if (!s.ok()) return s;
      if (w.name.empty()) return Status::Error(Code::InvalidArgument, where + ".name is required");
      c.worlds.push_back(std::move(w));
    }
  }
  s = checkDaemonConfig(&c);
  if (!s.ok()) return s;
  *out = std::move(c);
  return Status::Ok();
}

Status loadDaemonConfig(const std::string& path, DaemonConfig* out) {
  std::ifstream f(path);
  if (!f) return Status::Error(Code::NotFound, "cannot read " + path);
  std::stringstream ss;
  ss << f.rdbuf();
  std::string base = fs::path(path).parent_path().string();
  if (base.empty()) base = ".";
  Status s = parseDaemonConfig(ss.str(), base, out);
  if (!s.ok()) s.message = path + ": " + s.message;
  return s;
}

}  // namespace phys::server
