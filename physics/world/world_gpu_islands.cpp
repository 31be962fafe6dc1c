// Islands on the CPU beside the device (docs/ARCHITECTURE.md, "Islands on the CPU beside the
// device"): on the GPU backend, the islands that need physics only the CPU has are stepped by
// the CPU in the same World::step while the device steps the rest of the world:
//  - direct contacts: an island with a touching pair of dynamic bodies whose masses differ
//    by SolverSettings::directContactRatio or more (the CPU solves their normal rows
//    directly; the device would iterate them: mass_ratio_1000 sinks);
//  - restitution's collision phase: an island with a touching (or speculative) contact whose
//    restitution, max(ea, eb), is above zero (impacts.h, the energy limit per island at the
//    step's end; the device has the older pass, without either).
// The held islands' bodies go up to the device as sleeping bodies do (not integrated, not
// dynamic): a device body that touches one meets an immovable body, and the step is then
// undone and taken again with that body's island held too (stepOnDevice), so that no island
// is ever split between the two. The CPU's part is a private CPU World holding copies of the
// held bodies, of every static and kinematic body and of the held bodies' joints; it is kept
// while the held set is unchanged (its contacts warm-start), stepped with the host's settings
// and substeps, and its states are copied into the host mirror (BodyRec) beside the device's.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <string>

#include "world/world_impl.h"

namespace phys {

struct CpuIslands {
  std::unique_ptr<World> world;    ///< the CPU's part: copies of the held islands (or null)
  bool rebuild = true;             ///< the held set or the world's structure changed
  std::vector<uint32_t> members;   ///< host slots of the held bodies, ascending
  std::vector<uint32_t> hostOf;    ///< private body slot -> host body slot
  std::vector<int32_t> jointHost;  ///< private joint slot -> host joint slot (-1: none)
  /// Host slot -> the last step a body stays held without a reason of its own this step
  /// (kHold steps after its island last had one: a bouncing ball or a pile that opens for
  /// a step does not go back and forth, losing its warm start each time).
  std::vector<uint64_t> holdUntil;
  std::vector<uint8_t> whyOf;  ///< host slot -> why its island was last held (kDirect | kElastic)
  /// The touching pairs (host body slots, static bodies included) of the last step: the
  /// device's and the CPU part's.
  std::vector<std::pair<uint32_t, uint32_t>> deviceTouches, cpuTouches;
  int islandCount = 0;   ///< held islands this step
  /// Whether a shape has a restitution above 0 (cpuIslandsWatch), as found since the
  /// world's structure last changed (-1: not looked at since). Shapes and materials change
  /// only with the structure (the device's shape records go up again then), so a step need
  /// not scan every shape of a world (a million of them, every step, before).
  int elasticShapes = -1;
  static constexpr uint64_t kHold = 30;
  static constexpr uint32_t kDirect = 1, kElastic = 2;
};

void CpuIslandsDeleter::operator()(CpuIslands* c) const {
  delete c;
}

namespace {

float elasticity(const Pool<ShapeRec, ShapeTag>& shapes, const BodyRec& b) {
  float e = 0;
  for (ShapeId sid : b.shapes) e = std::max(e, shapes.get(sid)->def.material.restitution);
  return e;
}

float reachOf(const Pool<ShapeRec, ShapeTag>& shapes, const BodyRec& b) {
  float r = 0;
  for (ShapeId sid : b.shapes) r = std::max(r, shapes.get(sid)->boundRadius);
  return r;
}

/// The pose and motion a step changes, copied between the host and the private world (the
/// same bits: the CPU part starts from exactly the host's state).
void copyState(const BodyRec& from, BodyRec* to) {
  to->xf = from.xf;
  to->com = from.com;
  to->v = from.v;
  to->w = from.w;
  to->force = from.force;
  to->torque = from.torque;
}

}  // namespace

bool World::Impl::cpuIslandsWatch() const {
  // PHYS_GPU_CPU_ISLANDS=0 turns them off (the device iterates every island, as before
  // issue 42 point 5): a diagnostic, to measure what they change (docs/BENCHMARKS.md).
  static const bool off = [] {
    const char* e = std::getenv("PHYS_GPU_CPU_ISLANDS");
    return e && std::string(e) == "0";
  }();
  if (off) return false;
  // Whether any island could need the CPU: a cheap test over the world, so that a world
  // without (the common one) reads no contacts back and is stepped exactly as before.
  const SolverSettings& s = def.solver;
  if (s.restitution) {
    int& elastic = cpuIslands->elasticShapes;
    if (elastic < 0) {
      elastic = 0;
      for (uint32_t i = 0; i < shapes.capacity() && elastic == 0; ++i)
        if (shapes.alive(i) && shapes.at(i).def.material.restitution > 0) elastic = 1;
    }
    if (elastic > 0) return true;
  }
  if (!(s.directContactRatio > 0) || s.scheme == SolverSettings::Scheme::Jacobi) return false;
  float lo = 0, hi = 0;
  for (uint32_t slot : awakeBodies) {
    const BodyRec& b = bodies.at(slot);
    if (b.type != BodyType::Dynamic) continue;
    lo = lo == 0 ? b.mass : std::min(lo, b.mass);
    hi = std::max(hi, b.mass);
  }
  return lo > 0 && hi >= s.directContactRatio * lo;
}

std::vector<uint32_t> World::Impl::chooseCpuIslands(
    const std::vector<std::pair<uint32_t, uint32_t>>& touches, uint32_t* reasons,
    int* islandCount) {
  CpuIslands& c = *cpuIslands;
  const SolverSettings& s = def.solver;
  const bool ratio = s.directContactRatio > 0 && s.scheme != SolverSettings::Scheme::Jacobi;
  const uint64_t step = stats.step;
  const size_t n = bodies.capacity();
  if (c.holdUntil.size() < n) c.holdUntil.resize(n, 0);
  if (c.whyOf.size() < n) c.whyOf.resize(n, 0);
  auto dynamic = [&](uint32_t slot) {
    const BodyRec& b = bodies.at(slot);
    return b.type == BodyType::Dynamic && b.awake();
  };
  // Islands over the awake dynamic bodies (by host slot; the root is the lowest slot),
  // joined by touching pairs and joints, as updateSleep's; static and kinematic bodies join
  // none. Why each island needs the CPU, by root.
  DisjointSets sets;
  sets.reset(n);
  std::vector<uint8_t> why(n, 0), held(n, 0);
  std::vector<uint32_t> marked;  // (slot, reason) pairs flattened: a touch's reason
  for (auto [a, b] : touches) {
    if (!bodies.alive(a) || !bodies.alive(b)) continue;
    const BodyRec& A = bodies.at(a);
    const BodyRec& B = bodies.at(b);
    const bool da = dynamic(a), db = dynamic(b);
    if (!da && !db) continue;
    if (da && db) sets.join(int32_t(a), int32_t(b));
    uint32_t r = 0;
    if (s.restitution && std::max(elasticity(shapes, A), elasticity(shapes, B)) > 0)
      r |= CpuIslands::kElastic;
    if (ratio && da && db && std::max(A.mass, B.mass) >= s.directContactRatio * std::min(A.mass, B.mass))
      r |= CpuIslands::kDirect;
    if (r) marked.push_back(da ? a : b), marked.push_back(r);
  }
  for (uint32_t i = 0; i < joints.capacity(); ++i) {
    if (!joints.alive(i)) continue;
    const JointDef& d = joints.at(i).def;
    if (d.bodyA.isNull()) continue;
    if (dynamic(d.bodyA.index) && dynamic(d.bodyB.index))
      sets.join(int32_t(d.bodyA.index), int32_t(d.bodyB.index));
  }
  for (size_t k = 0; k < marked.size(); k += 2)
    why[size_t(sets.root(int32_t(marked[k])))] |= uint8_t(marked[k + 1]);
  // A held body within its hold keeps its island held (the reasons it was held for).
  for (uint32_t slot : c.members)
    if (bodies.alive(slot) && dynamic(slot) && c.holdUntil[slot] >= step)
      held[size_t(sets.root(int32_t(slot)))] = 1;
  std::vector<uint32_t> out;
  uint32_t all = 0;
  int count = 0;
  for (uint32_t slot : awakeBodies) {
    if (!dynamic(slot)) continue;
    const size_t r = size_t(sets.root(int32_t(slot)));
    if (!why[r] && !held[r]) continue;
    out.push_back(slot);
    if (why[r]) {
      c.holdUntil[slot] = step + CpuIslands::kHold;
      c.whyOf[slot] = why[r];
    }
    all |= why[r];
    count += r == slot;
  }
  if (reasons) *reasons = all;
  if (islandCount) *islandCount = count;
  return out;  // ascending: awakeBodies is
}

bool World::Impl::holdCpuIslands(std::vector<uint32_t> next) {
  CpuIslands& c = *cpuIslands;
  // A sleeping island that a held body may reach this step wakes and is held too: the device
  // pairs neither held nor sleeping bodies (neither is dynamic there), and the CPU's part
  // holds neither. Bounding spheres: the body's reach, its travel in the step, the contact
  // margin; O(held x sleeping), only while both exist.
  if (sleepingBodyCount > 0 && !next.empty()) {
    const float dt = def.timeStep;
    std::vector<int32_t> wake;
    for (uint32_t i = 0; i < bodies.capacity(); ++i) {
      if (!bodies.alive(i) || !bodies.at(i).asleep()) continue;
      const BodyRec& z = bodies.at(i);
      const float rz = reachOf(shapes, z);
      for (uint32_t slot : next) {
        const BodyRec& b = bodies.at(slot);
        const float r = rz + reachOf(shapes, b) + length(b.v) * dt + def.speculativeDistance +
                        def.aabbMargin;
        if (lengthSquared(b.com - z.com) <= r * r) {
          wake.push_back(z.island);
          break;
        }
      }
    }
    std::sort(wake.begin(), wake.end());
    wake.erase(std::unique(wake.begin(), wake.end()), wake.end());
    for (int32_t k : wake) {
      for (uint32_t slot : islands[size_t(k)].bodies) {
        next.push_back(slot);
        if (c.holdUntil.size() <= slot) c.holdUntil.resize(slot + 1, 0);
        c.holdUntil[slot] = stats.step + CpuIslands::kHold;
        if (c.whyOf.size() <= slot) c.whyOf.resize(slot + 1, 0);
      }
      wakeIsland(k);
    }
    std::sort(next.begin(), next.end());
    next.erase(std::unique(next.begin(), next.end()), next.end());
  }
  if (next == c.members) return false;
  // The bodies that join or leave go up to the device again (held: as a sleeping body;
  // released: dynamic, from the state the CPU gave them), and so do the joints.
  std::vector<uint32_t> changed;
  std::set_symmetric_difference(c.members.begin(), c.members.end(), next.begin(), next.end(),
                                std::back_inserter(changed));
  for (uint32_t slot : changed) {
    if (!bodies.alive(slot)) continue;
    BodyRec& b = bodies.at(slot);
    b.held = std::binary_search(next.begin(), next.end(), slot);
    deviceEdited(slot);
    if (!b.joints.empty()) deviceJointsChanged();
  }
  c.members = std::move(next);
  c.rebuild = true;
  return true;
}

bool World::Impl::cpuIslandsBegin(bool structureChanged) {
  if (!cpuIslands) cpuIslands.reset(new CpuIslands);
  CpuIslands& c = *cpuIslands;
  if (structureChanged) {
    c.rebuild = true;
    c.elasticShapes = -1;
  }
  // Members that died, fell asleep or stopped being dynamic leave without a word.
  std::erase_if(c.members, [&](uint32_t slot) {
    if (!bodies.alive(slot)) return true;
    BodyRec& b = bodies.at(slot);
    if (b.type == BodyType::Dynamic && b.awake() && b.held) return false;
    b.held = false;
    c.rebuild = true;
    deviceEdited(slot);
    return true;
  });
  if (!cpuIslandsWatch()) {
    holdCpuIslands({});
    c.deviceTouches.clear();
    c.cpuTouches.clear();
    c.world.reset();
    backend.cpuIslands = backend.cpuIslandBodies = 0;
    backend.cpuIslandMs = 0;
    return false;
  }
  std::vector<std::pair<uint32_t, uint32_t>> touches = c.deviceTouches;
  touches.insert(touches.end(), c.cpuTouches.begin(), c.cpuTouches.end());
  holdCpuIslands(chooseCpuIslands(touches, nullptr, &c.islandCount));
  // The held bodies' states go up (the CPU moved them last step): where a device body
  // meets them this step.
  for (uint32_t slot : c.members) deviceEdited(slot);
  return true;
}

bool World::Impl::cpuIslandsGrow(const std::vector<std::pair<uint32_t, uint32_t>>& deviceNow) {
  CpuIslands& c = *cpuIslands;
  c.deviceTouches = deviceNow;
  std::vector<std::pair<uint32_t, uint32_t>> touches = deviceNow;
  touches.insert(touches.end(), c.cpuTouches.begin(), c.cpuTouches.end());
  int count = 0;
  std::vector<uint32_t> next = chooseCpuIslands(touches, nullptr, &count);
  // Within a step the held set only grows (a body released goes at the next step's start).
  std::vector<uint32_t> grown;
  std::set_union(next.begin(), next.end(), c.members.begin(), c.members.end(),
                 std::back_inserter(grown));
  if (grown == c.members) return false;
  c.islandCount = count;
  holdCpuIslands(std::move(grown));
  backend.cpuIslandRetakes++;
  return true;
}

void World::Impl::buildCpuIslandWorld() {
  CpuIslands& c = *cpuIslands;
  WorldDef cd = def;
  cd.backend = Backend::Cpu;
  cd.threads = 1;
  cd.sleep.enabled = false;  // the host's islands sleep (updateSleep), not these copies
  cd.guard = false;          // the host's guard rails take the whole step
  c.world = std::make_unique<World>(cd);
  World& cw = *c.world;
  std::vector<BodyId> mine(bodies.capacity());
  c.hostOf.clear();
  auto add = [&](uint32_t slot) {
    const BodyRec& b = bodies.at(slot);
    BodyId id;
    if (!cw.createBody(bodyDefOf(shapes, b), &id).ok()) return;
    mine[slot] = id;
    if (c.hostOf.size() <= id.index) c.hostOf.resize(id.index + 1, 0);
    c.hostOf[id.index] = slot;
    copyState(b, &cw.impl_->bodies.at(id.index));
  };
  // Every static and kinematic body (the ground, what carries or walls the islands), then
  // the held bodies.
  for (uint32_t i = 0; i < bodies.capacity(); ++i)
    if (bodies.alive(i) && bodies.at(i).type != BodyType::Dynamic) add(i);
  for (uint32_t slot : c.members) add(slot);
  // The held bodies' joints (a joint's dynamic bodies are in one island), with their
  // reference frames and warm starts as the host has them.
  c.jointHost.clear();
  for (uint32_t i = 0; i < joints.capacity(); ++i) {
    if (!joints.alive(i)) continue;
    const JointRec& j = joints.at(i);
    const bool heldB = bodies.at(j.def.bodyB.index).held;
    const bool heldA = !j.def.bodyA.isNull() && bodies.at(j.def.bodyA.index).held;
    if (!heldA && !heldB) continue;
    JointDef d = j.def;
    if (!d.bodyA.isNull()) d.bodyA = mine[d.bodyA.index];
    d.bodyB = mine[d.bodyB.index];
    JointId id;
    if (!cw.createJoint(d, &id).ok()) continue;
    JointRec& mj = cw.impl_->joints.at(id.index);
    mj.relRot0 = j.relRot0;
    mj.refA = j.refA;
    mj.refB = j.refB;
    mj.length = j.length;
    mj.impulseCount = j.impulseCount;
    std::copy(std::begin(j.impulses), std::end(j.impulses), std::begin(mj.impulses));
    mj.state = j.state;
    if (c.jointHost.size() <= id.index) c.jointHost.resize(id.index + 1, -1);
    c.jointHost[id.index] = int32_t(i);
  }
  cw.impl_->stats.substepTime = stats.substepTime;
  c.rebuild = false;
}

void World::Impl::cpuIslandsStep(int substeps) {
  CpuIslands& c = *cpuIslands;
  backend.cpuIslandBodies = int(c.members.size());
  backend.cpuIslands = c.members.empty() ? 0 : c.islandCount;
  backend.cpuIslandMs = 0;
  if (c.members.empty()) {
    c.world.reset();
    c.cpuTouches.clear();
    return;
  }
  const auto t0 = std::chrono::steady_clock::now();
  if (c.rebuild || !c.world) buildCpuIslandWorld();
  World& cw = *c.world;
  Impl& cpu = *cw.impl_;
  // The step starts from the host's states (edits since the last step included); the
  // kinematic bodies move on both sides alike.
  for (uint32_t k = 0; k < c.hostOf.size(); ++k) {
    if (!cpu.bodies.alive(k)) continue;
    BodyRec& mine = cpu.bodies.at(k);
    if (mine.type != BodyType::Static) copyState(bodies.at(c.hostOf[k]), &mine);
  }
  cw.stepOnce(substeps);
  // Back into the host mirror: the held bodies' states (forces last one step) and their
  // joints' impulses and reactions.
  for (uint32_t k = 0; k < c.hostOf.size(); ++k) {
    if (!cpu.bodies.alive(k)) continue;
    const BodyRec& mine = cpu.bodies.at(k);
    if (mine.type != BodyType::Dynamic) continue;
    BodyRec& b = bodies.at(c.hostOf[k]);
    copyState(mine, &b);
    b.force = b.torque = {};
  }
  for (uint32_t k = 0; k < c.jointHost.size(); ++k) {
    if (c.jointHost[k] < 0 || !cpu.joints.alive(k)) continue;
    const JointRec& mj = cpu.joints.at(k);
    JointRec& j = joints.at(uint32_t(c.jointHost[k]));
    j.impulseCount = mj.impulseCount;
    std::copy(std::begin(mj.impulses), std::end(mj.impulses), std::begin(j.impulses));
    j.state = mj.state;
  }
  // Its touching pairs, in host slots: next step's islands and, with sleeping, this step's
  // (updateSleep's edges beside the device's: cpuIslandsFinish).
  c.cpuTouches.clear();
  for (const Contact& ct : cpu.contacts)
    if (ct.manifold.count > 0)
      c.cpuTouches.push_back({c.hostOf[ct.bodyA.index], c.hostOf[ct.bodyB.index]});
  backend.cpuIslandMs =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

void World::Impl::cpuIslandsFinish() {
  CpuIslands& c = *cpuIslands;
  if (c.members.empty() || !c.world) return;
  if (sleepActive())
    deviceTouches.insert(deviceTouches.end(), c.cpuTouches.begin(), c.cpuTouches.end());
  // The step's statistics cover both parts.
  const Impl& cpu = *c.world->impl_;
  const StepStats& cs = cpu.stats;
  stats.pairs += cs.pairs;
  stats.contacts += cs.contacts;
  stats.contactPoints += cs.contactPoints;
  stats.joints += cs.joints;
  stats.maxPenetration = std::max(stats.maxPenetration, cs.maxPenetration);
  stats.velocityResidual = std::max(stats.velocityResidual, cs.velocityResidual);
  stats.iterationsUsed = std::max(stats.iterationsUsed, cs.iterationsUsed);
  backend.cpuIslandSteps++;
  backend.cpuIslandBodySteps += c.members.size();
  // Why, as each held body's island last needed the CPU (a ball in the air between two
  // bounces is held for its elastic contacts).
  uint32_t reasons = 0;
  for (uint32_t slot : c.members) reasons |= slot < c.whyOf.size() ? c.whyOf[slot] : 0;
  std::string why;
  if (reasons & CpuIslands::kDirect) why = "direct contacts (a touching pair of mass ratio >= directContactRatio)";
  if (reasons & CpuIslands::kElastic)
    why += std::string(why.empty() ? "" : " and ") + "restitution (an elastic contact)";
  if (reasons == 0) why = "a sleeping island the held ones reach";
  backend.cpuIslandReason = why;
}

}  // namespace phys
