// physsoak: one scripted client of tools/soak.sh (issue 24 "Soak").
//
//   physsoak --role editor|subscriber|slow|monitor --index I --seconds S [--domain D]
//            [--config XML] [--seed N] [--out FILE] [--memory CSV]
//
// editor: owns the world "soak-<I>" (created, or found again after a restart) and for S
//   seconds sends one command at a time: spawn bodies, remove some, add or remove a joint, apply
//   forces, change the solver, Step, Run, Pause. It keeps what the daemon acknowledged (the
//   live body ids, the tick of the last Step) and, after every daemon restart, checks the
//   restored world against it: every acknowledged body there and no other (bar the one
//   command whose reply the kill cut off), the tick not behind the last acknowledged Step.
//   A request that times out while no daemon restart happens around it is a lost reply.
// subscriber / slow: subscribes to editor worlds' state frames (slow: sleeps 50 ms in its
//   callback) and counts frames.
// monitor: records the daemon's status (tick overruns of every world) once a second, and
//   with --memory the daemon's heap and its worlds' activity every 10 s.
//
// At the end it writes one JSON line to --out (or stdout): its counts.
#include <CLI/CLI.hpp>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <fstream>
#include <iomanip>
#include <map>
#include <random>
#include <set>
#include <sstream>
#include <thread>

#include "phys/client/client.h"

using namespace phys;
using namespace phys::client;
using namespace std::chrono_literals;
using Clock = std::chrono::steady_clock;

namespace {

struct Counts {
  uint64_t acked = 0, refused = 0, lost = 0, cutByKill = 0, restarts = 0, checks = 0,
           mismatches = 0, frames = 0, overruns = 0;
  std::string lastMismatch;
};

BodyDef box(std::mt19937& rng) {
  std::uniform_real_distribution<float> u(-8, 8);
  BodyDef d;
  d.position = {u(rng), u(rng), 2 + (u(rng) + 8) * 0.5f};
  ShapeDef s;
  s.geom = ShapeGeom::box({0.3f, 0.3f, 0.3f});
  d.shapes.push_back(s);
  return d;
}

/// Waits up to `wait` for the client to greet a new daemon (reconnects() past `before`).
bool awaitRestart(Client& c, uint64_t before, std::chrono::milliseconds wait) {
  const auto end = Clock::now() + wait;
  while (Clock::now() < end) {
    if (c.reconnects() > before && c.connected()) return true;
    std::this_thread::sleep_for(20ms);
  }
  return false;
}

void editor(Client& c, int index, double seconds, uint32_t seed, Counts* n) {
  std::mt19937 rng(seed);
  const std::string name = "soak-" + std::to_string(index);
  WorldHandle w;
  try {
    w = c.worldNamed(name);
  } catch (const Error&) {
    w = c.createWorld({name, "", std::nullopt, 0}).get();
  }
  std::set<uint64_t> live;  // acknowledged bodies
  // Acknowledged joints (id -> its bodies), at most kMaxJoints: like the bodies (at most 400)
  // the joints stay bounded, so the world's size and activity settle within minutes and the
  // daemon's memory from minute 10 on measures the daemon, not a world that keeps growing
  // (unbounded, the 16 worlds' joints grew all hour and pulled their bodies into piles).
  constexpr size_t kMaxJoints = 40;
  std::map<uint64_t, std::pair<uint64_t, uint64_t>> joints;
  uint64_t ground = 0;
  {
    // What a world found again holds is taken as it is (an earlier soak client's).
    for (const client::BodyState& b : w.queryState().get().bodies) live.insert(b.id);
    if (live.empty()) {
      BodyDef g;
      g.type = BodyType::Static;
      ShapeDef p;
      p.geom = ShapeGeom::plane({0, 0, 1}, 0);
      g.shapes.push_back(p);
      ground = w.spawn(g).get().at(0);
      live.insert(ground);
    }
  }
  uint64_t ackedTick = 0;
  uint64_t seenRestarts = c.reconnects();
  // The restored world against what was acknowledged. The command a kill cut off may or may
  // not have been stored: its bodies (spawned or removed) are allowed either way.
  auto check = [&](size_t maybeSpawned, size_t maybeRemoved) {
    ++n->checks;
    try {
      client::StateFrame s = w.queryState({}, 0, 0, {5000ms}).get();
      std::set<uint64_t> have;
      for (const client::BodyState& b : s.bodies) have.insert(b.id);
      size_t missing = 0, extra = 0;
      for (uint64_t id : live) missing += !have.count(id);
      for (uint64_t id : have) extra += !live.count(id);
      if (missing > maybeRemoved || extra > maybeSpawned || s.tick < ackedTick) {
        ++n->mismatches;
        std::ostringstream os;
        os << "world " << name << ": " << missing << " acknowledged bodies missing, " << extra
           << " unknown, tick " << s.tick << " (acknowledged " << ackedTick << ")";
        n->lastMismatch = os.str();
      }
      live = have;  // from here on, what the restored daemon holds
      ackedTick = std::max(ackedTick, s.tick);
    } catch (const Error& e) {
      ++n->mismatches;
      n->lastMismatch = std::string("query after restart: ") + e.what();
    }
  };
  const char* presets[] = {"soft_step", "pgs", "tjsoft", "ldl_pgs"};
  const auto end = Clock::now() + std::chrono::duration<double>(seconds);
  while (Clock::now() < end) {
    if (c.reconnects() != seenRestarts && c.connected()) {
      // A restart between two commands: nothing was in flight.
      seenRestarts = c.reconnects();
      ++n->restarts;
      check(0, 0);
    }
    const uint64_t before = c.reconnects();
    const int action = int(rng() % 100);
    size_t spawning = 0, removing = 0;
    try {
      CallOptions o{10000ms};  // a loaded machine may be slow; a kill shows as Disconnected
      if (action < 25 && live.size() < 400) {
        std::vector<BodyDef> defs;
        for (int i = 0, k = 1 + int(rng() % 8); i < k; ++i) defs.push_back(box(rng));
        spawning = defs.size();
        std::vector<uint64_t> spawned = w.spawn(defs, o).get();
        live.insert(spawned.begin(), spawned.end());
      } else if (action < 35 && live.size() > 10) {
        auto it = live.begin();
        std::advance(it, rng() % live.size());
        if (*it != ground) {
          const uint64_t id = *it;
          removing = 1;
          // Its joints go with it (forgotten first: if the reply is cut off, the body and
          // its joints may be gone or not; a later removal of such a joint is refused).
          std::erase_if(joints, [id](const auto& j) {
            return j.second.first == id || j.second.second == id;
          });
          w.removeBodies(std::vector<uint64_t>{id}, o).get();
          live.erase(id);
        }
      } else if (action < 42 && joints.size() >= kMaxJoints) {
        auto it = joints.begin();
        std::advance(it, rng() % joints.size());
        const uint64_t id = it->first;
        joints.erase(it);
        w.removeJoints(std::vector<uint64_t>{id}, o).get();
      } else if (action < 42 && live.size() > 3) {
        std::vector<uint64_t> ids(live.begin(), live.end());
        JointDef j;
        j.type = JointType::Distance;
        j.bodyA = BodyId::fromPacked(ids[rng() % ids.size()]);
        j.bodyB = BodyId::fromPacked(ids[rng() % ids.size()]);
        // Rest length: the distance the bodies are apart now (length < 0). A fixed length
        // (1.5 m) pulled bodies from across the world together: every joint added left a
        // cluster behind after it was removed, and with bodies living ~30 minutes in the
        // soak the worlds' contacts kept rising all hour (6,000 to 18,000 in 17 minutes).
        j.length = -1;
        if (j.bodyA != j.bodyB && j.bodyA.packed() != ground && j.bodyB.packed() != ground) {
          const std::vector<uint64_t> added = w.addJoints(std::span<const JointDef>(&j, 1), o).get();
          if (!added.empty()) joints[added[0]] = {j.bodyA.packed(), j.bodyB.packed()};
        }
      } else if (action < 65 && live.size() > 1) {
        auto it = live.begin();
        std::advance(it, rng() % live.size());
        if (*it != ground) w.applyImpulse(*it, {0, 0, 2}, {}, {}, o).get();
      } else if (action < 68) {
        w.setSolver(presets[rng() % 4], {}, o).get();
      } else if (action < 90) {
        ackedTick = w.step(1 + uint32_t(rng() % 10), o).get().tick;
      } else if (action < 95) {
        w.run(60, o).get();
      } else {
        w.pause(o).get();
      }
      ++n->acked;
    } catch (const Error& e) {
      if (e.code() != ErrorCode::Timeout && e.code() != ErrorCode::Disconnected) {
        ++n->refused;  // a clear refusal (e.g. a budget): nothing changed
        continue;
      }
      // No answer: a daemon restart around it cut it off, or the reply was lost.
      if (!awaitRestart(c, before, 30s)) {
        ++n->lost;
        continue;
      }
      ++n->cutByKill;
      ++n->restarts;
      seenRestarts = c.reconnects();
      check(spawning, removing);
    }
  }
}

void subscriber(Client& c, int index, double seconds, bool slow, Counts* n) {
  std::atomic<uint64_t> frames{0};
  std::vector<Subscription> subs;
  const auto end = Clock::now() + std::chrono::duration<double>(seconds);
  // Editors' worlds: subscribe to two of them once they exist.
  while (subs.size() < 2 && Clock::now() < end) {
    try {
      for (const WorldSummary& s : c.listWorlds({3000ms}).get()) {
        if (subs.size() >= 2) break;
        if (s.name.rfind("soak-", 0) != 0 || (s.world + uint32_t(index)) % 3 != 0) continue;
        subs.push_back(c.subscribe(s.world, [&frames, slow](const client::StateFrame&) {
          frames.fetch_add(1);
          if (slow) std::this_thread::sleep_for(50ms);
        }));
      }
    } catch (const Error&) {
    }
    std::this_thread::sleep_for(500ms);
  }
  while (Clock::now() < end) std::this_thread::sleep_for(100ms);
  n->frames = frames.load();
}

/// memory: when not empty, a CSV file that gets a line every 10 s: the unix time, the daemon's
/// heap in use and, summed over its worlds, bodies, awake bodies, joints, contacts and the
/// step buffers' bytes (what the daemon's memory should follow).
void monitor(Client& c, double seconds, const std::string& memory, Counts* n) {
  const auto end = Clock::now() + std::chrono::duration<double>(seconds);
  std::ofstream mem;
  if (!memory.empty()) {
    mem.open(memory, std::ios::app);
    mem << "unix_s,heap_bytes,worlds,bodies,awake,joints,contacts,step_buffer_bytes\n";
  }
  // Overruns per world; a restarted daemon counts from 0 again, so a drop adds what the
  // last daemon had counted.
  std::map<uint32_t, uint64_t> last;
  for (int i = 0; Clock::now() < end; ++i) {
    if (auto st = c.latestStatus()) {
      uint64_t bodies = 0, awake = 0, joints = 0, contacts = 0, buffers = 0;
      for (const auto& w : st->worlds) {
        uint64_t& l = last[w.world];
        if (w.overruns < l) n->overruns += l;
        l = w.overruns;
        bodies += w.bodies, awake += w.awakeBodies, joints += w.joints;
        contacts += w.contacts, buffers += w.stepBufferBytes;
      }
      if (mem.is_open() && i % 10 == 0) {
        const double unix = std::chrono::duration<double>(
                                std::chrono::system_clock::now().time_since_epoch())
                                .count();
        mem << std::fixed << std::setprecision(1) << unix << ',' << st->heapBytes << ','
            << st->worlds.size() << ',' << bodies << ',' << awake << ',' << joints << ','
            << contacts << ',' << buffers << std::endl;
      }
    }
    std::this_thread::sleep_for(1s);
  }
  for (auto& [w, o] : last) n->overruns += o;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"physsoak: a scripted client of tools/soak.sh"};
  std::string role = "editor", configFile, out, memory;
  int index = 0;
  double seconds = 60;
  uint32_t domain = 0, seed = 1;
  app.add_option("--role", role)->check(CLI::IsMember({"editor", "subscriber", "slow", "monitor"}));
  app.add_option("--index", index);
  app.add_option("--seconds", seconds);
  app.add_option("--domain", domain);
  app.add_option("--config", configFile, "Cyclone XML file");
  app.add_option("--seed", seed);
  app.add_option("--out", out, "append the summary line here");
  app.add_option("--memory", memory, "monitor: append the daemon's memory every 10 s here (CSV)");
  CLI11_PARSE(app, argc, argv);

  ClientOptions o;
  o.domain = domain;
  o.name = "physsoak-" + role + "-" + std::to_string(index);
  if (!configFile.empty()) {
    std::ifstream f(configFile);
    std::stringstream ss;
    ss << f.rdbuf();
    o.cycloneXml = ss.str();
  }
  o.connectTimeout = 30s;
  o.requestTimeout = 5s;
  Counts n;
  int rc = 0;
  try {
    Client c(o);
    c.connect();
    if (role == "editor") editor(c, index, seconds, seed, &n);
    if (role == "subscriber" || role == "slow") subscriber(c, index, seconds, role == "slow", &n);
    if (role == "monitor") monitor(c, seconds, memory, &n);
    n.restarts = std::max<uint64_t>(n.restarts, c.reconnects());
  } catch (const std::exception& e) {
    std::fprintf(stderr, "physsoak %s %d: %s\n", role.c_str(), index, e.what());
    rc = 1;
  }
  std::ostringstream line;
  line << "{\"role\":\"" << role << "\",\"index\":" << index << ",\"ok\":" << (rc == 0 ? "true" : "false")
       << ",\"acked\":" << n.acked << ",\"refused\":" << n.refused << ",\"lost\":" << n.lost
       << ",\"cut_by_kill\":" << n.cutByKill << ",\"restarts\":" << n.restarts
       << ",\"checks\":" << n.checks << ",\"mismatches\":" << n.mismatches
       << ",\"frames\":" << n.frames << ",\"overruns\":" << n.overruns << ",\"last_mismatch\":\""
       << n.lastMismatch << "\"}\n";
  if (out.empty()) {
    std::fputs(line.str().c_str(), stdout);
  } else {
    std::ofstream f(out, std::ios::app);
    f << line.str();
  }
  return rc;
}
