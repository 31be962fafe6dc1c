// Fuzz target: an engine snapshot (World::saveSnapshot's bytes) restored into a world that
// already holds one, then stepped (issue 39: a snapshot the restore accepted crashed the next
// step, so restoring alone proves little). The input's header is sealed first (payload size
// and checksum recomputed, fuzz/snapshot_forge.h), as a forger would: every mutation reaches
// the parser instead of failing the checksum.
//
// Besides crashes and sanitizer reports, it aborts when the restore breaks its contract:
//  - a rejected snapshot: an error other than InvalidArgument, without a message, or a world
//    that changed (its saved bytes differ from before);
//  - an accepted one: a world that cannot be saved again, or whose saved bytes another world
//    does not accept (what a restore accepts is a state the engine can carry on from).
// The accepted world is then stepped kSteps times, its queries called, and saved once more,
// unless its settings ask for more solver work than the presets do: what a step costs under
// settings the API accepts as well (1,000 iterations, 64 substeps, 1,000 guard retries) is
// the budgets' business (docs/ARCHITECTURE.md, "What one step may cost"), not this
// target's, and such steps would only hit libFuzzer's timeout.
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "phys/world/world.h"
#include "snapshot_forge.h"

namespace {

using phys::forge::Bytes;

constexpr int kSteps = 3;

[[noreturn]] void die(const std::string& what) {
  std::fprintf(stderr, "fuzz_restore: %s\n", what.c_str());
  std::fflush(stderr);
  std::abort();
}

/// The world every input is restored into: snapshot_forge.h's (bodies awake and asleep,
/// joints, contacts, free slots).
const Bytes& targetSnapshot() {
  static const Bytes bytes = [] {
    phys::World w(phys::forge::worldDef());
    phys::forge::buildWorld(w);
    Bytes b;
    if (!w.saveSnapshot(&b).ok()) die("the target world cannot be saved");
    return b;
  }();
  return bytes;
}

/// At most the presets' solver work (pjnj: 1 x (50 + 4) iterations, ldl_pgs: 16 x (1 + 1),
/// soft_step: 6 x (2 + 1)) and the default guard retries.
bool affordable(const phys::WorldDef& d) {
  const phys::SolverSettings& s = d.solver;
  return s.substeps * (s.iterations + s.relaxIterations + s.positionIterations) <= 64 &&
         d.guardRetries <= 2;
}

Bytes save(const phys::World& w, const char* what) {
  Bytes b;
  phys::Status st = w.saveSnapshot(&b);
  if (!st.ok()) die(std::string(what) + ": saveSnapshot failed: " + st.message);
  return b;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const Bytes& target = targetSnapshot();
  Bytes snap(data, data + size);
  phys::forge::seal(&snap);

  phys::World w(phys::forge::worldDef());
  if (!w.restoreSnapshot(target.data(), target.size()).ok()) die("the target does not restore");
  phys::Status st = w.restoreSnapshot(snap.data(), snap.size());
  if (!st.ok()) {
    if (st.code != phys::StatusCode::InvalidArgument || st.message.empty())
      die("a rejected snapshot: code " + std::to_string(int(st.code)) + ", message '" +
          st.message + "'");
    if (save(w, "after a rejected restore") != target)
      die("a rejected snapshot changed the world: " + st.message);
    return 0;
  }

  // Accepted: a state the engine can save and restore again.
  const Bytes again = save(w, "after an accepted restore");
  phys::World other(phys::forge::worldDef());
  st = other.restoreSnapshot(again.data(), again.size());
  if (!st.ok()) die("the saved bytes of an accepted snapshot do not restore: " + st.message);

  if (!affordable(w.def())) return 0;
  for (int i = 0; i < kSteps; ++i) w.step();
  // The queries a server makes of a world.
  (void)w.contacts();
  (void)w.energy();
  (void)w.stateHash();
  for (phys::BodyId id : w.bodies()) {
    phys::BodyState s;
    (void)w.getBody(id, &s);
  }
  for (phys::JointId id : w.joints()) {
    phys::JointDef d;
    phys::JointState js;
    (void)w.getJoint(id, &d, &js);
  }
  Bytes after;
  (void)w.saveSnapshot(&after);  // may refuse a state that went non-finite
  return 0;
}
