// durable_bench: what durable worlds cost (docs/SERVER.md "Durable worlds", issue 24).
//
//   durable_bench [--data DIR] [--bodies 10000] [--tick-bodies 1000] [--edits 10] [--ticks 600]
//
// 1. Checkpoint: a world of --bodies boxes (spawned, then stepped once), checkpointed 5 times:
//    milliseconds and bytes per checkpoint, then the restore of that directory (ms).
// 2. Journaling at 60 Hz: a world of --tick-bodies bodies running in real time, --edits
//    ApplyForce commands a tick through the queue (submit, processPending, advance: what the
//    tick thread does), --ticks ticks with durability on and the same with it off, in
//    alternating blocks of 60 ticks; the median and mean wall time per tick of each, and the
//    journal's bytes per command. Ticks are simulated back to back (no sleeping).
#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <numeric>
#include <vector>

#include "phys/protocol/builder.h"
#include "phys/protocol/decoder.h"
#include "phys/server/core.h"

using namespace phys;
using namespace phys::server;
using Clock = std::chrono::steady_clock;
namespace fs = std::filesystem;

namespace {

double msSince(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

CoreConfig config(const std::string& data) {
  CoreConfig c;
  c.presetsFile = std::string(PHYS_SOURCE_DIR) + "/configs/presets.json";
  c.threads = 1;
  c.dataDir = data;
  c.checkpointPeriodS = 1e9;  // only the checkpoints this benchmark asks for
  return c;
}

std::vector<BodyDef> boxes(int n) {
  std::vector<BodyDef> defs;
  const int side = int(std::ceil(std::cbrt(double(n))));
  for (int i = 0; i < n; ++i) {
    BodyDef d;
    d.position = {1.5f * float(i % side), 1.5f * float((i / side) % side),
                  1.0f + 1.5f * float(i / (side * side))};
    ShapeDef s;
    s.geom = ShapeGeom::box({0.5f, 0.5f, 0.5f});
    d.shapes.push_back(s);
    defs.push_back(d);
  }
  BodyDef ground;
  ground.type = BodyType::Static;
  ShapeDef plane;
  plane.geom = ShapeGeom::plane({0, 0, 1}, 0);
  ground.shapes.push_back(plane);
  defs.push_back(ground);
  return defs;
}

uint32_t makeWorld(ServerCore& core, const char* name, int bodies, std::vector<uint64_t>* ids) {
  uint32_t id = 0;
  if (!core.createWorld(name, "", "", &id).ok()) std::exit(2);
  std::vector<BodyDef> defs = boxes(bodies);
  for (size_t at = 0; at < defs.size(); at += 20000) {
    std::vector<BodyDef> part(defs.begin() + long(at),
                              defs.begin() + long(std::min(defs.size(), at + 20000)));
    auto r = protocol::decodeReply(
        core.applyBytes(protocol::CommandBuilder().spawnBodies(part).finish({9, at + 1, id}), 9,
                        at + 1));
    if (!r.ok() || r->status() != protocol::Code::Ok) {
      std::fprintf(stderr, "spawn failed: %s\n", r.ok() && r->message() ? r->message()->c_str() : "");
      std::exit(2);
    }
    if (ids && r->result_as_Ids())
      for (uint64_t b : *r->result_as_Ids()->bodies()) ids->push_back(b);
  }
  return id;
}

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0 : v[v.size() / 2];
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"durable_bench: the cost of checkpoints and journaling"};
  std::string data = (fs::temp_directory_path() / "durable_bench").string();
  int bodies = 10000, tickBodies = 1000, edits = 10, ticks = 600;
  app.add_option("--data", data, "scratch data directory (removed first)");
  app.add_option("--bodies", bodies, "bodies of the checkpointed world");
  app.add_option("--tick-bodies", tickBodies, "bodies of the running world");
  app.add_option("--edits", edits, "ApplyForce commands per tick");
  app.add_option("--ticks", ticks, "ticks of each of the two runs");
  CLI11_PARSE(app, argc, argv);

  // 1. Checkpoints.
  fs::remove_all(data);
  {
    ServerCore core(config(data));
    if (!core.init().ok()) return 2;
    const uint32_t id = makeWorld(core, "big", bodies, nullptr);
    core.stepWorld(id, 1);
    std::vector<double> ms;
    for (int i = 0; i < 5; ++i) {
      const auto t0 = Clock::now();
      protocol::Status s = core.checkpointNow(id);
      ms.push_back(msSince(t0));
      if (!s.ok()) {
        std::fprintf(stderr, "checkpoint: %s\n", s.message.c_str());
        return 2;
      }
    }
    const uint64_t bytes = fs::file_size(fs::path(data) / "worlds" / std::to_string(id) / "checkpoint");
    std::printf("checkpoint: %d bodies, %llu bytes, median %.1f ms (min %.1f, max %.1f) of 5\n",
                bodies, (unsigned long long)bytes, median(ms), *std::min_element(ms.begin(), ms.end()),
                *std::max_element(ms.begin(), ms.end()));
  }
  {
    const auto t0 = Clock::now();
    ServerCore core(config(data));
    if (!core.init().ok()) return 2;
    std::vector<std::string> notes;
    core.restoreWorlds(&notes);
    std::printf("restore: %.1f ms (checkpoint read, world rebuilt, a new checkpoint written)\n",
                msSince(t0));
  }

  // 2. Journaling at 60 Hz, durable and not, side by side.
  fs::remove_all(data);
  ServerCore on(config(data)), off(config(""));
  if (!on.init().ok() || !off.init().ok()) return 2;
  std::vector<uint64_t> idsOn, idsOff;
  const uint32_t wOn = makeWorld(on, "running", tickBodies, &idsOn);
  const uint32_t wOff = makeWorld(off, "running", tickBodies, &idsOff);
  on.setRun(wOn, RunMode::RealTime, 60);
  off.setRun(wOff, RunMode::RealTime, 60);
  uint64_t seq = 1000;
  std::vector<double> tOn, tOff;
  auto tick = [&](ServerCore& core, uint32_t world, const std::vector<uint64_t>& ids, int t,
                  std::vector<double>* out) {
    const auto t0 = Clock::now();
    for (int e = 0; e < edits; ++e) {
      ++seq;
      Incoming in;
      in.envelopeKey = 9;
      in.envelopeSeq = seq;
      Bytes b = protocol::CommandBuilder()
                    .applyForce(ids[size_t(t * edits + e) % ids.size()], {1, 0, 0})
                    .finish({9, seq, world});
      in.bytes = b.size();
      in.command = protocol::decodeCommand(std::move(b));
      core.submit(std::move(in));
    }
    core.processPending();
    core.advance(1.0 / 60);
    out->push_back(msSince(t0));
    for (;;) {  // the replies: drained as the publisher would
      PublishQueue::Item item = core.out().pop(std::chrono::milliseconds(0));
      if (!item.reliable && !item.frame) break;
    }
  };
  for (int block = 0; block * 60 < ticks; ++block)
    for (int t = block * 60; t < std::min(ticks, (block + 1) * 60); ++t) {
      tick(on, wOn, idsOn, t, &tOn);
      tick(off, wOff, idsOff, t, &tOff);
    }
  const ServerWorld* w = on.world(wOn);
  const double mean = [](const std::vector<double>& v) {
    return std::accumulate(v.begin(), v.end(), 0.0) / double(v.size());
  }(tOn);
  const double meanOff = std::accumulate(tOff.begin(), tOff.end(), 0.0) / double(tOff.size());
  std::printf("60 Hz, %d bodies, %d edits/tick, %d ticks: durable median %.3f ms/tick (mean %.3f), "
              "memory only median %.3f (mean %.3f): +%.3f ms/tick median\n",
              tickBodies, edits, ticks, median(tOn), mean, median(tOff), meanOff,
              median(tOn) - median(tOff));
  if (w->store && w->store->journalRecords() > 0)
    std::printf("journal: %llu records, %llu bytes since the last checkpoint: %.1f bytes/record\n",
                (unsigned long long)w->store->journalRecords(),
                (unsigned long long)w->store->journalBytes(),
                double(w->store->journalBytes()) / double(w->store->journalRecords()));
  fs::remove_all(data);
  return 0;
}
