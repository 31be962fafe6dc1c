// The step: World::step (guard rails around stepOnce) and World::stepOnce, which shows every
// stage in order, then the stages' own code (bounds, pairs, contacts, solver bodies and rows,
// impulses, finalize). The solver's passes are in physics/dynamics/, the collision
// routines in physics/collision/, the device's step in world_gpu.cpp.
#include "phys/world/world.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstring>
#include <limits>
#include <new>
#include <type_traits>

#include "dynamics/joints.h"
#include "world/world_impl.h"

namespace phys {

namespace {

/// Contacts per chunk of the parallel narrow phase and manifold build (a box pair's narrow
/// phase takes about 0.2 us).
constexpr size_t kContactGrain = 256;

double nowMs() {
  return std::chrono::duration<double, std::milli>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

/// The twist arm of a one-point manifold (SolverSettings::patchFriction): 2a/3 of a Hertz
/// patch, a = sqrt(R kPointPatchDepth), R the reduced radius of curvature (0: two flat shapes).
float pointPatchArm(const ShapeGeom& a, const ShapeGeom& b) {
  auto curvature = [](const ShapeGeom& g) {  // 1 / R
    return g.type == ShapeType::Sphere || g.type == ShapeType::Capsule ? 1 / g.radius : 0.0f;
  };
  const float k = curvature(a) + curvature(b);
  if (!(k > 0)) return 0;
  return (2.0f / 3.0f) * std::sqrt(SolverSettings::kPointPatchDepth / k);
}

/// Times one stage into its profile field.
class StageTimer {
 public:
  explicit StageTimer(double* field) : field_(field), start_(nowMs()) {}
  ~StageTimer() { *field_ += nowMs() - start_; }

 private:
  double* field_;
  double start_;
};

}  // namespace

// ---------------------------------------------------------------------------------------------
// The step

void World::step() {
  Impl& w = *impl_;
  // Nothing thrown inside a step leaves it (a daemon steps worlds built from its clients'
  // messages): the step is undone instead (stepFailed).
  w.snapshotValid = w.stepTouched = w.snapshotEnergyKnown = w.mirrorScan.valid = false;
  try {
    w.stats.guardRetries = 0;
    double guardMs = 0;  // StepProfile::guard (stepOnce starts the profile afresh)
    if (!w.def.guard) {
      stepOnce(w.def.solver.substeps);
    } else {
      double t = nowMs();
      w.takeSnapshot();
      guardMs += nowMs() - t;
      int substeps = w.def.solver.substeps;
      stepOnce(substeps);
      t = nowMs();
      std::string fault = w.checkHealth();
      guardMs += nowMs() - t;
      for (int retry = 0; !fault.empty() && retry < w.def.guardRetries; ++retry) {
        // Roll back and redo with a safer setting: twice the substeps.
        w.stats.guardRetries++;
        w.stats.lastGuardEvent = "step " + std::to_string(w.stats.step) + ": " + fault;
        w.restoreSnapshot();
        // Twice what the failed attempt took (stack stiffening may have taken more than asked).
        substeps = std::min(std::max(substeps, w.stats.substeps) * 2, 64);
        stepOnce(substeps);
        fault = w.checkHealth();
      }
      if (w.stats.guardRetries > 0) w.stats.guardEvents++;
      if (!fault.empty()) {
        w.quarantine();
        // The statistics describe the world as it is now, not the failed attempt: that one's
        // energy and residual may be NaN, and a world whose statistics are not finite cannot
        // be saved (saveSnapshot), which a durable server does every few seconds. The
        // residual of a solve that diverged is reported as the largest double.
        w.stats.energyAfter = energy();
        if (!std::isfinite(w.stats.velocityResidual))
          w.stats.velocityResidual = std::numeric_limits<double>::max();
      }
    }
    if (w.stats.pairsDropped > 0) w.stats.pairLimitSteps++;
    // Bodies past the world's extent stop at its edge (a body falling forever, a kinematic
    // body sent away): beyond it no state could be sent, and floats lose the centimetre.
    {
      const double t = nowMs();
      w.keepInsideWorld();
      guardMs += nowMs() - t;
    }
    w.profile.guard = guardMs;
    // Islands and sleeping, once the step is accepted (islands.cpp): rest timers, and the
    // islands that rested long enough fall asleep. Part of the step's time.
    {
      const double t0 = nowMs();
      w.updateSleep(w.def.timeStep);
      const double ms = nowMs() - t0;
      w.profile.buildIslands += ms;
      w.profile.total += ms;
    }
    w.followActivity();
    // The step is accepted: the guard's copy no longer stands for anything. Bodies woken
    // from now until the next step (an edit, a solver change waking every island) are not
    // added to it (wakeIsland), which would only grow it.
    w.snapshotValid = w.stepTouched = false;
  } catch (const PairLimitReached&) {  // PairOverflow::Refuse
    w.stepRefused();
  } catch (const std::exception& e) {  // std::bad_alloc, std::length_error: all the step throws
    w.stepFailed(e.what());
  }
}

void World::stepOnce(int substeps) {
  Impl& w = *impl_;
  w.stepTouched = true;
  const float dt = w.def.timeStep;
  SolverSettings s = w.def.solver;
  s.substeps = substeps;
  StepProfile& p = w.profile;
  p = StepProfile();
  const double t0 = nowMs();
  // The guard's copy, taken just before, summed it (one pass over the bodies, not two).
  w.stats.energyBefore = w.snapshotEnergyKnown ? w.snapshotEnergy : w.stepEnergy();
  w.snapshotEnergyKnown = w.mirrorScan.valid = false;

  {
    StageTimer t(&p.applyCommands);
    w.applyCommands();
  }
  w.lastStepOnCpu = false;
  // The GPU backend takes the whole step when it covers everything the step needs
  // (world_gpu.cpp); otherwise the CPU stages below take it from the same host mirror.
  // (An auto world its calibration puts on the CPU takes the CPU's path alone: its results
  // are a CPU world's, bit for bit.)
  const bool onDevice = w.device && w.deviceTakesStep();
  if (onDevice) w.rescaleWarmStarts(dt / float(substeps));  // joints' go up when stale
  if (onDevice && w.stepOnDevice(substeps)) {
    // The device does not measure stacks: it runs the preset's substeps. Its joint impulses
    // come back to the host in that unit.
    w.stats.substeps = substeps;
    w.stats.substepTime = dt / float(substeps);
    w.stats.stackDepth = 0;
    w.stats.stackHertz = 0;
    w.stats.contactsBetweenHalves = -1;
    w.stats.contactParts = 0;
    w.time += dt;
    w.stats.step++;
    // The mirror pass summed it on its way (mirrorScan), as World::energy would.
    w.stats.energyAfter = w.mirrorScan.valid ? w.mirrorScan.energy : w.stepEnergy();
    p.total = nowMs() - t0;
    // What the host did beside the device's stages and the parts stepOnDevice measured.
    const double device = p.syncToDevice + p.updateBounds + p.broadPhase + p.narrowPhase +
                          p.prepare + p.integrateVelocities + p.integratePositions +
                          p.warmStart + p.solve + p.relax + p.restitution + p.positionPass +
                          p.storeImpulses + p.finalize + p.readback;
    p.hostOther = std::max(
        0.0, p.total - device - p.applyCommands - p.hostUpload - p.hostReadback - p.hostMirror);
    return;
  }
  {
    StageTimer t(&p.updateBounds);
    w.updateBounds(dt);
  }
  {
    StageTimer t(&p.broadPhase);
    w.broadPhaseStage();
  }
  {
    StageTimer t(&p.narrowPhase);
    w.narrowPhase(dt);
  }
  {
    // Sleeping islands that an awake body now touches join this step (islands.cpp).
    StageTimer t(&p.buildIslands);
    w.wakeTouched();
  }
  {
    // Islands and colors are not needed by the serial solver; the stacks' depth is.
    StageTimer t(&p.buildIslands);
    w.stiffenForStacks(dt, &s);
  }
  w.stats.substeps = s.substeps;
  const float h = dt / float(s.substeps);
  // The split push-out only where there is something to push out: a step whose contacts are
  // all shallower than kSplitDepth is the unsplit solve (vectorized contacts, no pseudo
  // velocities), the same bits as without the option.
  if (s.splitPushout && !(w.stats.maxPenetration > SolverSettings::kSplitDepth))
    s.splitPushout = false;
  {
    StageTimer t(&p.prepare);
    w.rescaleWarmStarts(h);
    w.buildSolverBodies(s);
  }
  Solver& solver = w.solver;
  // Joints solved directly (LDL hybrid) or iterated with everything else.
  bool direct = false;
  if (s.equalitySolve == SolverSettings::EqualitySolve::DirectLdl) {
    StageTimer t(&p.prepare);
    if (w.directSolveFits()) {
      w.ldl.analyze(solver);
      direct = w.ldl.factor(solver);
    }
  }
  const float equalityBias = Solver::equalityBiasRate(s, h);
  // Direct contacts on jointed bodies see the joints through the LDL hybrid (setup's Schur
  // complement): without it this step, those islands are iterated.
  if (!direct) w.directContacts.dropJointed(solver);
  const bool directContacts = !w.directContacts.empty();
  auto iterate = [&](bool useBias) {
    float change = solver.solveIteration(s, h, useBias, direct, directContacts);
    // Direct contacts, then the joints: in an island with joints, the direct solve's
    // impulses are those with the joints holding, which the LDL solve then carries through
    // them (docs/ARCHITECTURE.md, "Direct contacts on jointed bodies").
    if (directContacts)
      change = std::max(change, w.directContacts.solve(solver, Solver::contactRule(s, h, useBias),
                                                       equalityBias));
    if (direct) change = std::max(change, w.ldl.solve(solver, equalityBias, useBias));
    return change;
  };
  auto collide = [&](bool ahead) {
    if (!s.restitution || w.impacts.empty()) return;
    StageTimer t(&p.restitution);
    w.impacts.resolve(solver.bodies, h, s.restitutionThreshold, ahead);
  };
  // Warm starting by bodies (Solver::BodyWarmStart) where every row keeps its Jacobian
  // through the step and only the rows change velocities: the substeps after the first add
  // each body's impulses of the last substep, a pass over the bodies instead of the contacts.
  // (Without contacts there is nothing to warm-start: no sums to keep.)
  const bool warmByBodies = bodyWarmStart() && !w.contactOrder.empty() && w.stepJoints.empty() &&
                            !solver.jacobi() && !s.splitPushout && !direct && !directContacts &&
                            w.impacts.empty();
  int iterationsUsed = 0;
  for (int sub = 0; sub < s.substeps; ++sub) {
    using Warm = Solver::BodyWarmStart;
    const Warm warm = !warmByBodies ? Warm::Off : sub == 0 ? Warm::Track : Warm::Apply;
    {
      StageTimer t(&p.integrateVelocities);
      solver.integrateVelocities(h, w.def.maxLinearSpeed, w.def.maxAngularSpeed, warm);
    }
    if (sub > 0) {
      StageTimer t(&p.prepare);
      w.refreshJoints(h);
      if (direct) direct = w.ldl.factor(solver);
      if (!direct) w.directContacts.dropJointed(solver);
    }
    // Restitution: the collision phase (impacts.h) on this substep's velocities, for the
    // contacts that close within it.
    collide(false);
    if (warm != Warm::Apply) {
      StageTimer t(&p.warmStart);
      solver.warmStart();
    }
    {
      StageTimer t(&p.solve);
      // Convergence control: stop once an iteration barely changes any row's velocity.
      for (int it = 0; it < s.iterations; ++it) {
        ++iterationsUsed;
        if (iterate(true) <= s.tolerance && s.tolerance > 0) break;
      }
    }
    {
      StageTimer t(&p.integratePositions);
      if (s.splitPushout) solver.solvePushout(s, h, s.iterations, direct ? &w.ldl : nullptr);
      solver.integratePositions(h);
    }
    if (s.relaxIterations > 0) {
      // The relax pass meets the gaps of the next substep: a contact that closes within it
      // would be stopped there as a speculative contact (rigid, no bounce) before the next
      // collision phase could see it approach. So the phase runs here too, ahead.
      collide(true);
      StageTimer t(&p.relax);
      for (int it = 0; it < s.relaxIterations; ++it) iterate(false);
    }
  }
  if (w.impacts.collisions() > 0) {
    // The collisions' velocity changes, scaled back where an island would end with more
    // energy than it began the step with plus its forces' work.
    StageTimer t(&p.restitution);
    const std::vector<Velocity>& dv = w.impacts.changes();
    w.beforeRestitution.resize(solver.bodies.size());
    for (size_t i = 0; i < solver.bodies.size(); ++i)
      w.beforeRestitution[i] = {solver.bodies[i].v - dv[i].v, solver.bodies[i].w - dv[i].w};
    w.limitRestitutionEnergy(w.beforeRestitution);
  }
  if (w.wide.active) {
    StageTimer t(&p.storeImpulses);
    w.wide.store(w.contacts, w.manifoldContact);  // for the next step's warm start
  }
  if (s.positionPass != SolverSettings::PositionPass::None && s.positionIterations > 0) {
    StageTimer t(&p.positionPass);
    solver.positionPass(s, s.positionIterations,
                        s.positionPass == SolverSettings::PositionPass::NonlinearJacobi);
  }
  {
    StageTimer t(&p.storeImpulses);
    w.stats.velocityResidual = solver.velocityResidual(h);
    w.stats.iterationsUsed = iterationsUsed;
    w.storeImpulses();
    w.stats.substepTime = h;
  }
  {
    StageTimer t(&p.finalize);
    w.finalize(h);
  }
  w.backend.cpuSteps++;
  w.lastStepOnCpu = true;
  w.deviceStale();  // the CPU moved the bodies: the device's copy is old

  w.time += dt;
  w.stats.step++;
  w.stats.energyAfter = w.stepEnergy();
  p.total = nowMs() - t0;
}

void World::Impl::rescaleWarmStarts(float h) {
  // Warm starts are impulses per substep: the substeps just changed length (stack
  // stiffening, a guard retry, a new time step), so last step's impulses are scaled to keep
  // the forces they stand for.
  const float k = impulseScale(stats.substepTime, h);
  stats.substepTime = h;  // their unit from here on
  if (k == 1) return;
  scaleImpulses(&contacts, k);
  // The awake joints only: a sleeping island's joints keep the unit they fell asleep in and
  // are scaled when it wakes (wakeIsland), like its contacts. (Scaling them here too scaled
  // them at every change of substep length while they slept, and a guard retry, which rolls
  // back only the awake ones, changes it twice: the physd soak's sleeping joints grew to
  // infinity, and their worlds could not be saved.)
  for (uint32_t i = 0; i < joints.capacity(); ++i) {
    if (!joints.alive(i)) continue;
    JointRec& j = joints.at(i);
    if (jointAsleep(j)) continue;
    for (float& f : j.impulses) f *= k;
  }
}

bool World::Impl::jointAsleep(const JointRec& j) const {
  // Its island sleeps when its dynamic bodies do (a joint keeps them in one island).
  const BodyRec* a = j.def.bodyA.isNull() ? nullptr : bodies.get(j.def.bodyA);
  const BodyRec* b = bodies.get(j.def.bodyB);
  return (a && a->asleep()) || (b && b->asleep());
}

void World::Impl::storeImpulses() {
  // Hand each row's impulse back to its contact point or joint for the next warm start
  // (contacts as rows: none when every contact was a manifold, below).
  if (contactRowsBuilt) {
    for (Contact& c : contacts) {
      if (c.firstRow < 0) continue;
      const int n = c.manifold.count;
      for (int i = 0; i < n; ++i) c.normalImpulse[i] = solver.rows[size_t(c.firstRow + i)].lambda;
      if (solver.rows[size_t(c.firstRow + n)].patchPoints > 0) {
        for (int d = 0; d < 3; ++d)
          c.patchImpulse(d) = solver.rows[size_t(c.firstRow + n + d)].lambda;
        continue;
      }
      for (int i = 0; i < n; ++i) {
        c.tangentImpulse[i][0] = solver.rows[size_t(c.firstRow + n + 2 * i)].lambda;
        c.tangentImpulse[i][1] = solver.rows[size_t(c.firstRow + n + 2 * i + 1)].lambda;
      }
    }
  }
  // (Contacts solved in wide blocks got theirs from WideContacts::store, in stepOnce.)
  for (uint32_t i : stepJoints) {
    JointRec& j = joints.at(i);
    j.impulseCount = std::min(j.rowCount, int32_t(JointRec::kMaxRows));
    for (int32_t k = 0; k < j.impulseCount; ++k)
      j.impulses[k] = solver.rows[size_t(j.firstRow + k)].lambda;
  }
}

void World::Impl::takeSnapshot() {
  // The awake bodies and their contacts and joints: a sleeping island does not change in a
  // step (one woken inside it is added by wakeIsland). One pass over the bodies, on the
  // world's threads: their copy, the kinetic energy and lift the health check allows for,
  // and the world's energy (World::energy's terms), which the step's energyBefore takes
  // from here. The terms are summed afterwards in World::energy's order: the same bits.
  snapshotEnergyKnown = false;
  const size_t n = awakeBodies.size();
  // Every slot is written below: resize only initializes those the copy did not have (at a
  // million bodies, clearing and refilling zeroed some 80 MB a step).
  snapshot.bodies.resize(n);
  energyTerms.resize(n);
  const Vec3 gravity = def.gravity;
  const double g = length(gravity);
  forEachRange(n, [&](size_t begin, size_t end) {
    for (size_t k = begin; k < end; ++k) {
      const uint32_t i = awakeBodies[k];
      const BodyRec& b = bodies.at(i);
      snapshot.bodies[k] = {i, b.xf, b.com, b.v, b.w, b.force, b.torque};
      if (b.type != BodyType::Dynamic) {
        energyTerms[k] = {0, 0, 0};
        continue;
      }
      energyTerms[k] = {
          bodyEnergy(b, gravity),
          0.5 * b.mass * double(lengthSquared(b.v)) +
              0.5 * double(dot(invRotate(b.xf.q, b.w), b.inertiaLocal * invRotate(b.xf.q, b.w))),
          0.1 * g * b.mass};
    }
  });
  snapshot.kinetic = 0;
  snapshot.liftEnergy = 1;
  double energy = 0;
  for (size_t k = 0; k < n; ++k) {  // a body that is not dynamic adds +0.0: no bit changes
    snapshot.kinetic += energyTerms[k].kinetic;
    snapshot.liftEnergy += energyTerms[k].lift;
    energy += energyTerms[k].energy;
  }
  if (sleepingBodyCount > 0) energy += sleepingPotential();
  // The contacts (58,000 of 196 bytes in many_pyramids) copied on the world's threads.
  snapshot.contacts.resize(contacts.size());
  forEachRange(contacts.size(), [&](size_t begin, size_t end) {
    std::copy(contacts.begin() + std::ptrdiff_t(begin), contacts.begin() + std::ptrdiff_t(end),
              snapshot.contacts.begin() + std::ptrdiff_t(begin));
  });
  snapshot.jointImpulses.clear();
  collectStepJoints();
  for (uint32_t i : stepJoints) {
    const JointRec& j = joints.at(i);
    Snapshot::JointImpulses ji{i, j.impulseCount, {}};
    std::copy(j.impulses, j.impulses + JointRec::kMaxRows, ji.impulses);
    snapshot.jointImpulses.push_back(ji);
  }
  snapshot.time = time;
  snapshot.step = stats.step;
  snapshot.substepTime = stats.substepTime;
  snapshotValid = true;
  snapshotEnergy = energy;
  snapshotEnergyKnown = true;
}

bool World::Impl::directSolveFits() {
  // The direct solve couples every two equality rows that share a dynamic body
  // (solver_ldl.cpp): K rows on one body make a dense K x K block, K^2 memory and K^3 work
  // per substep (1,000 distance joints on one body took 0.8 s a step, 10,000 would take
  // minutes). Past kMaxDirectRowsPerBody the joints are iterated with everything else, as
  // when the factorization fails: bit for bit the iterative equality solve.
  if (joints.size() == 0) return true;
  equalityRowsAt.assign(solver.bodies.size(), 0);
  for (const Row& r : solver.rows) {
    if (r.kind != RowKind::Equality) continue;
    for (int32_t b : {r.a, r.b}) {
      if (b == 0 || !(solver.bodies[size_t(b)].invMass > 0)) continue;
      if (++equalityRowsAt[size_t(b)] > kMaxDirectRowsPerBody) return false;
    }
  }
  return true;
}

uint32_t World::Impl::pairLimit() const {
  if (def.maxContactPairs > 0) return def.maxContactPairs;
  const uint64_t perShape = uint64_t(WorldDef::kAutoContactPairsPerShape) * shapes.size();
  return uint32_t(std::clamp<uint64_t>(perShape, WorldDef::kMinAutoContactPairs, UINT32_MAX));
}

namespace {
/// The vectors a step fills and empties again, sized by its pairs or by its awake bodies
/// (releaseStepBuffers, stepBufferBytes: one list for both); the persistent contacts, the
/// solver's arrays, the broad phase's scratch, the union-find and the SIMD blocks are
/// handled beside it.
template <class Impl, class F>
void forEachStepScratch(Impl& w, F&& f) {
  // Pair-sized.
  f(w.snapshot.contacts);
  f(w.contactScratch);
  f(w.pairs);
  f(w.manifolds);
  f(w.manifoldContact);
  f(w.contactOrder);
  f(w.directIsland);
  // Body-sized.
  f(w.snapshot.bodies);
  f(w.energyTerms);
  f(w.snapshot.jointImpulses);
  f(w.solverCom);
  f(w.solverPart);
  f(w.beforeRestitution);
  f(w.equalityRowsAt);
  f(w.stackBodies);
  auto& t = w.stacks;
  f(t.stackDepth), f(t.stackHead), f(t.stackNext), f(t.stackQueue), f(t.stackRoot);
  f(t.stackIndex), f(t.stackDeepest), f(t.stackFirstLevel), f(t.stackSupport), f(t.stackRise);
  f(t.stackLevels), f(t.stackModel), f(t.stackDirectContact), f(t.stackOnDirect);
  f(t.directJointed), f(t.directRows), f(t.directHeavy);
  // Shape-sized.
  f(w.boundsTight), f(w.boundsLeft);
}
}  // namespace

void World::Impl::releaseStepBuffers() noexcept {
  forEachStepScratch(*this, [](auto& v) { std::remove_reference_t<decltype(v)>().swap(v); });
  solver.release();
  impacts.release();
  broadPhase.releaseScratch();
  islandSets.release();
  stacks.directSets.release();
  directContacts.release();
  wide.release();
}

size_t World::stepBufferBytes() const {
  const Impl& w = *impl_;
  size_t bytes = w.contacts.capacity() * sizeof(Contact) + w.wide.capacityBytes() +
                 w.solver.capacityBytes() + w.impacts.capacityBytes() +
                 w.broadPhase.scratchBytes() + w.islandSets.capacityBytes() +
                 w.stacks.directSets.capacityBytes() + w.directContacts.capacityBytes();
  forEachStepScratch(w, [&](const auto& v) { bytes += v.capacity() * sizeof(v[0]); });
  return bytes;
}

void World::Impl::followActivity() noexcept {
  // The buffers a step fills keep the capacity of the largest step they served: those sized
  // by its pairs (contacts, the guard's copy of them, pairs, manifolds, rows, SIMD blocks)
  // and those sized by its awake bodies (the solver's bodies, the guard's copy of them, the
  // stacks' and islands' scratch). A world that once had 3,000 contact pairs and now has 500
  // would hold the memory of 3,000 for good, and a long-lived world's memory would creep up
  // with every new peak (the pairs of a world whose islands sleep and wake swing between
  // hundreds and thousands, a solver change wakes every body at once, and the running
  // maximum keeps setting records: a soak's daemon gained megabytes over its first half hour
  // that way). So the buffers follow the world's activity: once a whole window of steps
  // needed under two thirds of the pairs, or of the awake bodies, they were grown for, they
  // all go back and the next step grows them to its own size. At most one release per
  // window; results do not depend on capacities.
  ActivityWindow& a = activity;
  a.pairs.see(contacts.size());
  a.bodies.see(awakeBodies.size());
  if (++a.steps < ActivityWindow::kSteps) return;
  const bool release = a.pairs.fell() || a.bodies.fell();
  if (release) {
    releaseStepBuffers();
    contacts.shrink_to_fit();  // kept (warm starts), at its own size; never throws (a
                               // failed copy leaves it as it is)
  }
  a.steps = 0;
  a.pairs.next(release);
  a.bodies.next(release);
}

void World::Impl::stepFailed(const char* what) noexcept {
  // Back to the state before the step. The guard's copy has it. Without one (guard off) the
  // bodies are as they were anyway, since only finalize writes them and nothing after it
  // allocates, but the contacts may be halfway through the step (matched, rescaled,
  // collided): they go, and the next step starts them cold. When the guard's copy itself
  // failed, nothing had been touched yet.
  if (snapshotValid) {
    restoreSnapshot(/*moveContacts=*/true);  // no copy: that could fail too
  } else if (stepTouched) {
    std::vector<Contact>().swap(contacts);
  }
  snapshotValid = stepTouched = false;
  // The step's buffers (what a failed allocation was most likely growing) go back.
  releaseStepBuffers();
  // The broad phase may have failed inside a tree update: built again from the proxies' fat
  // boxes, which are always current (the pairs depend on nothing else), or at least made to
  // find its pairs from scratch.
  broadPhase.forgetPairs();
  try {
    rebuildBroadPhase();
  } catch (...) {
  }
  deviceStale();
  stats.stepFailures++;
  try {
    stats.lastGuardEvent = "step " + std::to_string(stats.step) + " failed (" + what +
                           ") and was not taken: the world is as it was before it";
  } catch (...) {
    // Out of memory even for the message: the counter says it.
  }
}

void World::Impl::stepRefused() noexcept {
  const uint64_t failures = stats.stepFailures;
  stepFailed("refused");
  stats.stepFailures = failures;
  stats.stepsRefused++;
  try {
    stats.lastGuardEvent = "step " + std::to_string(stats.step) + " was not taken: its bodies make more than " +
                           std::to_string(stats.pairLimit) + " contact pairs (at least " +
                           std::to_string(stats.pairsDropped) +
                           " more); separate or remove the crowded bodies";
  } catch (...) {
  }
}

void World::Impl::rebuildBroadPhase() {
  // Aside, then swapped in: a failure leaves the old one in place.
  BroadPhase fresh;
  std::vector<int32_t> proxyOf(shapes.capacity(), -1);
  for (uint32_t i = 0; i < shapes.capacity(); ++i) {
    if (!shapes.alive(i) || shapes.at(i).proxy < 0) continue;
    const ShapeRec& s = shapes.at(i);
    proxyOf[i] = fresh.createProxyWithFatBox(broadPhase.fatAABB(s.proxy), i,
                                             proxyStatic(*bodies.get(s.body)));
  }
  broadPhase = std::move(fresh);
  for (uint32_t i = 0; i < shapes.capacity(); ++i)
    if (proxyOf[i] >= 0) shapes.at(i).proxy = proxyOf[i];
}

void World::Impl::restoreSnapshot(bool moveContacts) {
  mirrorScan.valid = false;  // the bodies change
  for (const Snapshot::Body& s : snapshot.bodies) {
    BodyRec& b = bodies.at(s.index);
    b.xf = s.xf;
    b.com = s.com;
    b.v = s.v;
    b.w = s.w;
    b.force = s.force;
    b.torque = s.torque;
  }
  if (moveContacts)
    contacts.swap(snapshot.contacts);
  else
    contacts = snapshot.contacts;
  for (const Snapshot::JointImpulses& ji : snapshot.jointImpulses) {
    JointRec& j = joints.at(ji.index);
    j.impulseCount = ji.count;
    std::copy(ji.impulses, ji.impulses + JointRec::kMaxRows, j.impulses);
  }
  time = snapshot.time;
  stats.step = snapshot.step;
  stats.substepTime = snapshot.substepTime;
  deviceStale();
}

const char* World::Impl::bodyFault(const BodyRec& b, const Snapshot::Body& before) const {
  if (!isFinite(b.xf.p) || !isFinite(b.xf.q) || !isFinite(b.v) || !isFinite(b.w))
    return "has a non-finite state";
  // The speed clamp only bites when something has blown up.
  if (length(b.v) >= 0.999f * def.maxLinearSpeed || length(b.w) >= 0.999f * def.maxAngularSpeed)
    return "reached the speed limit";
  // Positions integrate the velocities the solve leaves, which the clamp has not seen yet: a
  // solve that blew up can move a body far (found by fuzz_apply: a body with inertia moments
  // (1.2e-38, 2, 3) went 1.5e7 m in one step, then left it below the speed limit). A dynamic
  // body's centre of mass moves at most maxLinearSpeed, plus what a push-out adds, per second;
  // twice that in one step is a blow-up. (Kinematic bodies move at their set velocity.)
  if (b.type == BodyType::Dynamic) {
    const double d = length(Vec3{b.com.x - before.com.x, b.com.y - before.com.y,
                                 b.com.z - before.com.z});
    if (d > 2.0 * (double(def.maxLinearSpeed) + double(def.solver.maxPushout)) * def.timeStep)
      return "moved farther in one step than its speed limit allows";
  }
  return nullptr;
}

World::Impl::QuickHealth World::Impl::quickHealth() const {
  // |x| < bound / 1.75 on every axis puts a vector's length below the bound with room to
  // spare for rounding (length <= sqrt(3) max |x|); a NaN or an infinity fails it.
  return {0.999f * def.maxLinearSpeed / 1.75f, 0.999f * def.maxAngularSpeed / 1.75f,
          float(2.0 * (double(def.maxLinearSpeed) + double(def.solver.maxPushout)) *
                def.timeStep / 1.75)};
}

bool World::Impl::QuickHealth::clear(const BodyRec& b, const Snapshot::Body& s) const {
  const auto inside = [](Vec3 a, float m) {
    return std::fabs(a.x) < m && std::fabs(a.y) < m && std::fabs(a.z) < m;
  };
  constexpr float big = std::numeric_limits<float>::max();
  const Quat q = b.xf.q;
  return inside(b.v, vMax) && inside(b.w, wMax) && inside(b.xf.p, big) &&
         inside({q.x, q.y, q.z}, big) && std::fabs(q.w) < big &&
         (b.type != BodyType::Dynamic ||
          inside({b.com.x - s.com.x, b.com.y - s.com.y, b.com.z - s.com.z}, dMax));
}

bool World::Impl::insideExtent(const BodyRec& b) {
  constexpr float e = WorldDef::kWorldExtent;
  const Vec3 p = b.xf.p;
  return std::fabs(p.x) < e && std::fabs(p.y) < e && std::fabs(p.z) < e;
}

std::string World::Impl::checkHealth() const {
  // Nearly every body is far inside bodyFault's bounds: the quick test accepts those, and
  // only the rest take bodyFault's exact tests, whose verdict it is (the same faults, found
  // with less work a body: this runs over every awake body every step). A device step's
  // mirror pass ran the quick test already (mirrorScan): only the bodies from the first it
  // did not clear are looked at again. On the world's threads; the fault reported is the
  // first in the copy's order, as from one thread (the lowest index at fault, whichever
  // thread found it).
  const QuickHealth quick = quickHealth();
  const size_t from = mirrorScan.valid ? mirrorScan.healthFrom : 0;
  const size_t n = snapshot.bodies.size();
  std::atomic<size_t> first{n};
  forEachRange(n - std::min(from, n), [&](size_t begin, size_t end) {
    for (size_t k = from + begin; k < from + end && k < first.load(std::memory_order_relaxed);
         ++k) {
      const Snapshot::Body& s = snapshot.bodies[k];
      const BodyRec& b = bodies.at(s.index);
      if (quick.clear(b, s) || !bodyFault(b, s)) continue;
      lowerTo(first, k);
      return;  // later bodies of this range come after k
    }
  });
  if (const size_t k = first.load(); k < n) {
    const Snapshot::Body& s = snapshot.bodies[k];
    return "body " + std::to_string(s.index) + " " + bodyFault(bodies.at(s.index), s);
  }
  // A joint's impulses are kept for the next step's warm start and saved with the world: a
  // step whose solve left one non-finite failed there even if its bodies look sound (the
  // physd soak found such joints, and the worlds holding them could not be checkpointed).
  for (uint32_t i : stepJoints) {
    const JointRec& j = joints.at(i);
    for (int32_t k = 0; k < j.impulseCount; ++k)
      if (!std::isfinite(j.impulses[k]))
        return "joint " + std::to_string(i) + " has a non-finite impulse";
  }
  double gain = stats.energyAfter - stats.energyBefore;
  double allowed = def.guardEnergyJump * snapshot.kinetic + snapshot.liftEnergy;
  if (!(gain <= allowed))
    return "energy rose " + std::to_string(gain) + " J in one step (allowed " +
           std::to_string(allowed) + " J)";
  return {};
}

void World::Impl::quarantine() {
  // Retries did not help: put each body at fault back where it was, at rest, and let the
  // rest of the world keep its step. A bad body never poisons the others.
  mirrorScan.valid = false;  // the bodies change
  for (const Snapshot::Body& s : snapshot.bodies) {
    BodyRec& b = bodies.at(s.index);
    if (!bodyFault(b, s)) continue;
    b.xf = s.xf;
    b.com = s.com;
    b.v = b.w = {};
    stats.guardQuarantined++;
    stats.lastGuardEvent += "; body " + std::to_string(s.index) + " stopped";
  }
  deviceStale();
  for (Contact& c : contacts) {  // impulses computed from the bad state are not reused
    std::fill(std::begin(c.normalImpulse), std::end(c.normalImpulse), 0.0f);
    for (auto& t : c.tangentImpulse) t[0] = t[1] = 0;
  }
  // Nor are the joints': a NaN impulse kept for warm starting poisons the next step, which
  // then fails and stops its bodies again, every step (found by the physd soak: worlds whose
  // guard stopped a hundred bodies a step for the rest of the run, and could not be saved).
  for (uint32_t i = 0; i < joints.capacity(); ++i) {
    if (!joints.alive(i)) continue;
    JointRec* j = &joints.at(i);
    bool finite = isFinite(j->state.reactionForce) && isFinite(j->state.reactionTorque) &&
                  std::isfinite(j->state.positionError) && std::isfinite(j->state.angleError);
    for (float f : j->impulses) finite = finite && std::isfinite(f);
    if (finite) continue;
    std::fill(std::begin(j->impulses), std::end(j->impulses), 0.0f);
    j->impulseCount = 0;
    const JointId id = j->state.id;
    j->state = JointState{};
    j->state.id = id;
  }
}

void World::Impl::keepInsideWorld() {
  constexpr float e = WorldDef::kWorldExtent;
  // Nearly always every body is inside: the world's threads look for the first that is not
  // (as checkHealth does; from where a device step's mirror pass stopped finding them all
  // inside), and only from there on does the loop below run.
  const size_t from = mirrorScan.valid ? mirrorScan.insideFrom : 0;
  const size_t n = awakeBodies.size();
  std::atomic<size_t> first{n};
  forEachRange(n - std::min(from, n), [&](size_t begin, size_t end) {
    for (size_t k = from + begin; k < from + end && k < first.load(std::memory_order_relaxed);
         ++k) {
      if (insideExtent(bodies.at(awakeBodies[k]))) continue;
      lowerTo(first, k);
      return;
    }
  });
  for (size_t k = first.load(); k < n; ++k) {
    const uint32_t i = awakeBodies[k];
    BodyRec& b = bodies.at(i);
    const Vec3 p = b.xf.p;
    const Vec3 in{std::clamp(p.x, -e, e), std::clamp(p.y, -e, e), std::clamp(p.z, -e, e)};
    // On the edge and heading out: held there (at 1e6 m a float's step is 6 cm, so a slow
    // body would otherwise gather speed in place until it jumps out again).
    auto out = [&](float x, float v) { return (x >= e && v > 0) || (x <= -e && v < 0); };
    const bool leaving = out(in.x, b.v.x) || out(in.y, b.v.y) || out(in.z, b.v.z);
    if (in == p && !leaving) continue;
    b.xf.p = in;
    b.com += in - p;
    b.v = b.w = {};
    deviceEdited(i);
    if (in == p) continue;  // held on the edge: stopped already when it got there
    stats.guardQuarantined++;
    stats.lastGuardEvent = "step " + std::to_string(stats.step) + ": body " + std::to_string(i) +
                           " left the world's extent (" + std::to_string(int64_t(e)) +
                           " m) and was stopped at its edge";
  }
}

void World::Impl::applyCommands() {
  // In-process edits are applied immediately (the world is single-threaded between steps),
  // and physd applies its commands between ticks (server/src/commands.cpp): nothing is
  // queued for the step yet.
}

void World::Impl::updateBounds(float dt) {
  // Tight boxes are swept by this step's motion and padded by half the speculative distance,
  // so every pair that can touch during the step is found. They are computed on the world's
  // threads (each body writes its own shapes' slots); the broad phase then takes the ones
  // that left their fat boxes, in body order, on this thread (most do not: a resting pile
  // moves none).
  boundsTight.resize(shapes.capacity());
  boundsLeft.resize(shapes.capacity());
  forEachRange(awakeBodies.size(), [&](size_t begin, size_t end) {
    for (size_t k = begin; k < end; ++k) {
      const BodyRec& b = bodies.at(awakeBodies[k]);
      for (ShapeId sid : b.shapes) {
        const ShapeRec& s = *shapes.get(sid);
        AABB box = computeAABB(s.def.geom, shapeTransform(b, s));
        Vec3 sweep = b.v * dt;
        box.lo += vmin(sweep, {});
        box.hi += vmax(sweep, {});
        float pad = 0.5f * def.speculativeDistance + length(b.w) * dt * s.boundRadius;
        boundsTight[sid.index] = inflate(box, pad);
        boundsLeft[sid.index] = !contains(broadPhase.fatAABB(s.proxy), boundsTight[sid.index]);
      }
    }
  });
  for (uint32_t slot : awakeBodies)
    for (ShapeId sid : bodies.at(slot).shapes)
      if (boundsLeft[sid.index])
        broadPhase.moveProxy(shapes.get(sid)->proxy, boundsTight[sid.index], def.aabbMargin);
}

void World::Impl::broadPhaseStage() {
  // At most pairLimit() pairs (WorldDef::maxContactPairs): the contacts, manifolds and rows
  // below are at most that many too (per pair: one contact, one manifold, 12 rows).
  stats.pairLimit = pairLimit();
  stats.pairsDropped = broadPhase.computePairs(&pairs, stats.pairLimit);
  if (stats.pairsDropped > 0 && def.pairOverflow == WorldDef::PairOverflow::Refuse)
    throw PairLimitReached();
  // Merge the sorted pair list with the sorted contact list: surviving contacts keep their
  // impulses for warm starting, new pairs start cold, vanished pairs are dropped. While the
  // pairs are the contacts one for one (a resting world: every step), the contacts stay where
  // they are (`inPlace` of them so far); from the first that is not, they are copied into the
  // merged list.
  contactScratch.clear();
  size_t ci = 0, inPlace = 0;
  bool merging = false;
  for (const ProxyPair& pr : pairs) {
    const ShapeRec& sa = shapes.at(pr.a);
    const ShapeRec& sb = shapes.at(pr.b);
    if (sa.body == sb.body) continue;
    const BodyRec& A = *bodies.get(sa.body);
    const BodyRec& B = *bodies.get(sb.body);
    if (A.type != BodyType::Dynamic && B.type != BodyType::Dynamic) continue;
    if (!noCollide.empty() && noCollide.count(bodyPairKey(sa.body.index, sb.body.index))) continue;
    while (ci < contacts.size() && (contacts[ci].shapeA < pr.a ||
                                    (contacts[ci].shapeA == pr.a && contacts[ci].shapeB < pr.b)))
      ++ci;
    // Same slots, same shapes (generation), so a shape removed and another added in its
    // slot since the last step does not inherit the old one's impulses.
    const bool survives = ci < contacts.size() && contacts[ci].shapeA == pr.a &&
                          contacts[ci].shapeB == pr.b && contacts[ci].idA == shapes.idAt(pr.a) &&
                          contacts[ci].idB == shapes.idAt(pr.b);
    if (!merging && survives && ci == inPlace) {
      Contact& c = contacts[inPlace++];
      c.friction = std::sqrt(sa.def.material.friction * sb.def.material.friction);
      c.restitution = std::max(sa.def.material.restitution, sb.def.material.restitution);
      continue;
    }
    if (!merging) {
      merging = true;
      contactScratch.assign(contacts.begin(), contacts.begin() + std::ptrdiff_t(inPlace));
    }
    if (survives) {
      contactScratch.push_back(contacts[ci]);
    } else {
      Contact c;
      c.shapeA = pr.a;
      c.shapeB = pr.b;
      c.bodyA = sa.body;
      c.bodyB = sb.body;
      c.idA = shapes.idAt(pr.a);
      c.idB = shapes.idAt(pr.b);
      contactScratch.push_back(c);
    }
    Contact& c = contactScratch.back();
    c.friction = std::sqrt(sa.def.material.friction * sb.def.material.friction);
    c.restitution = std::max(sa.def.material.restitution, sb.def.material.restitution);
  }
  if (merging)
    contacts.swap(contactScratch);
  else
    contacts.resize(inPlace);  // the pairs that vanished were the last contacts
  stats.pairs = int(pairs.size());
  stats.broadPhaseTestsPerShape = 0;  // the device's figure (world_gpu.cpp)
}

void World::Impl::narrowPhase(float dt) {
  // Every contact on its own (reads bodies and shapes, writes only itself), in parallel;
  // the statistics are a max and a sum, the same for any split.
  std::atomic<int> points{0};
  std::atomic<float> deepest{0};
  auto collideRange = [&](size_t begin, size_t end) {
    int chunkPoints = 0;
    float chunkDeepest = 0;
    for (size_t ci = begin; ci < end; ++ci) {
      Contact& c = contacts[ci];
      const ShapeRec& sa = shapes.at(c.shapeA);
      const ShapeRec& sb = shapes.at(c.shapeB);
      const BodyRec& A = *bodies.get(c.bodyA);
      const BodyRec& B = *bodies.get(c.bodyB);
      // The margin grows with the speeds so a fast body meets a speculative contact before
      // it can pass through anything (no tunnelling without a separate continuous pass).
      float reach = (length(A.v) + length(A.w) * sa.boundRadius + length(B.v) +
                     length(B.w) * sb.boundRadius) *
                    dt;
      float margin = def.speculativeDistance + reach;
      Manifold m;
      collide(sa.def.geom, shapeTransform(A, sa), sb.def.geom, shapeTransform(B, sb), margin, &m);
      // Carry impulses of points whose features persist (warm starting).
      float ni[Manifold::kMaxPoints] = {}, ti[Manifold::kMaxPoints][2] = {};
      for (int i = 0; i < m.count; ++i) {
        const ContactPoint& cp = m.points[i];
        for (int k = 0; k < c.manifold.count; ++k) {
          if (c.manifold.points[k].featureId == cp.featureId) {
            ni[i] = c.normalImpulse[k];
            ti[i][0] = c.tangentImpulse[k][0];
            ti[i][1] = c.tangentImpulse[k][1];
            break;
          }
        }
        chunkDeepest = std::max(chunkDeepest, -cp.separation);
      }
      // Patch friction keeps the manifold's friction impulses while any point persists.
      if (def.solver.patchFriction) {
        bool persists = false;
        for (int i = 0; i < m.count && !persists; ++i)
          for (int k = 0; k < c.manifold.count; ++k)
            persists = persists || c.manifold.points[k].featureId == m.points[i].featureId;
        if (persists) std::memcpy(ti, c.tangentImpulse, sizeof ti);
      }
      c.manifold = m;
      std::memcpy(c.normalImpulse, ni, sizeof ni);
      std::memcpy(c.tangentImpulse, ti, sizeof ti);
      chunkPoints += m.count;
    }
    points += chunkPoints;
    float seen = deepest.load();
    while (chunkDeepest > seen && !deepest.compare_exchange_weak(seen, chunkDeepest)) {
    }
  };
  // Hull collisions grow per-thread scratch (collide_poly.cpp): an allocation that fails
  // there must neither leave a worker (std::terminate) nor leave the caller's chunk while the
  // workers still run the loop. It is noted, and thrown once the loop is over (World::step
  // undoes the step).
  std::atomic<bool> failed{false};
  auto collideOrNote = [&](size_t begin, size_t end) {
    try {
      collideRange(begin, end);
    } catch (...) {
      failed.store(true);
    }
  };
  if (pool)
    pool->parallelFor(contacts.size(), kContactGrain, collideOrNote);
  else
    collideOrNote(0, contacts.size());
  if (failed.load()) throw std::bad_alloc();
  stats.contactPoints = points.load();
  stats.maxPenetration = double(deepest.load());
  stats.contacts = int(contacts.size());
}

void World::Impl::stiffenForStacks(float dt, SolverSettings* s) {
  if (!s->stackStiffening) return forgetStacks();
  // Stacks change slowly next to their buckling (seconds): measured every
  // kStackInterval-th step, the frequency is kept in between (in StepStats, so a restored
  // snapshot continues the same way).
  if (stats.step % SolverSettings::kStackInterval == 0) measureStacks(dt, *s);
  const float effective = std::min(s->contactHertz, 0.25f * float(s->substeps) / dt);
  if (!(stats.stackHertz > effective)) return;
  s->contactHertz = std::max(s->contactHertz, stats.stackHertz);
  const double needed = std::ceil(4.0 * double(stats.stackHertz) * double(dt));
  s->substeps = std::max(s->substeps, int(std::min(needed, 64.0)));
}

void World::Impl::measureStacks(float dt, const SolverSettings& s) {
  // Every slot, dead ones too (their default records): no contact or joint names those.
  stackBodies.resize(bodies.capacity());
  for (uint32_t i = 0; i < bodies.capacity(); ++i) {
    const BodyRec& b = bodies.at(i);
    stackBodies[i] = {b.com, b.mass, b.invMass, b.type == BodyType::Dynamic, b.asleep()};
  }
  const StackMeasure m = stacks.measureStacks(
      {stackBodies, joints, contacts, def.gravity, def.speculativeDistance}, dt, s);
  stats.stackDepth = m.depth;
  stats.stackHertz = m.hertz;
}

SolverManifold World::Impl::solverManifold(const Contact& c, const SolverSettings& s) const {
  SolverManifold m;
  const BodyRec& A = *bodies.get(c.bodyA);
  const BodyRec& B = *bodies.get(c.bodyB);
  m.a = A.solverIndex;
  m.b = B.solverIndex;
  m.count = c.manifold.count;
  m.normal = c.manifold.normal;
  tangentBasis(m.normal, &m.t1, &m.t2);
  m.friction = c.friction;
  m.restitution = c.restitution;
  for (int k = 0; k < m.count; ++k) {
    const ContactPoint& cp = c.manifold.points[k];
    m.rA[k] = cp.point - A.com;
    m.rB[k] = cp.point - B.com;
    m.separation[k] = cp.separation;
    m.normalImpulse[k] = s.warmStart ? c.normalImpulse[k] : 0;
    m.tangentImpulse[k][0] = s.warmStart ? c.tangentImpulse[k][0] : 0;
    m.tangentImpulse[k][1] = s.warmStart ? c.tangentImpulse[k][1] : 0;
  }
  if (s.patchFriction && m.count > 0) {
    m.patch = true;
    Vec3 centroid;
    for (int k = 0; k < m.count; ++k) centroid += c.manifold.points[k].point;
    centroid = centroid * (1.0f / float(m.count));
    m.patchRA = centroid - A.com;
    m.patchRB = centroid - B.com;
    float arm = 0;
    for (int k = 0; k < m.count; ++k) arm += length(c.manifold.points[k].point - centroid);
    m.twistArm = arm / float(m.count);
    if (m.count == 1)
      m.twistArm = pointPatchArm(shapes.at(c.shapeA).def.geom, shapes.at(c.shapeB).def.geom);
    // Switching friction models between steps warm-starts one step from the other model's
    // slots; the friction clamps bound what that can do.
    for (int d = 0; d < 3; ++d) m.patchImpulse[d] = s.warmStart ? c.patchImpulse(d) : 0;
  }
  return m;
}

void World::Impl::contactRowsOf(const Contact& c, const SolverManifold& m) {
  for (int k = 0; k < m.count; ++k) {
    Row r = contactRow(m, RowKind::ContactNormal, m.normal, k);
    r.C0 = m.separation[k];
    r.lambda = m.normalImpulse[k];
    r.restitution = m.restitution;
    r.groupStart = k == 0;
    solver.rows.push_back(r);
  }
  if (m.patch) {
    // Patch friction: a tangent pair at the centroid, then the twist row.
    for (int d = 0; d < 2; ++d) {
      const Vec3 t = d == 0 ? m.t1 : m.t2;
      Row r;
      r.kind = RowKind::Friction;
      r.a = m.a;
      r.b = m.b;
      r.linA = -t;
      r.angA = -cross(m.patchRA, t);
      r.linB = t;
      r.angB = cross(m.patchRB, t);
      r.mu = m.friction;
      r.parent = c.firstRow;
      r.patchPoints = uint8_t(m.count);
      r.lambda = m.patchImpulse[d];
      solver.rows.push_back(r);
    }
    Row r;
    r.kind = RowKind::Twist;
    r.a = m.a;
    r.b = m.b;
    r.angA = -m.normal;
    r.angB = m.normal;
    r.mu = m.friction * m.twistArm;
    r.parent = c.firstRow;
    r.patchPoints = uint8_t(m.count);
    r.lambda = m.patchImpulse[2];
    solver.rows.push_back(r);
    return;
  }
  for (int k = 0; k < m.count; ++k) {
    for (int d = 0; d < 2; ++d) {
      Row r = contactRow(m, RowKind::Friction, d == 0 ? m.t1 : m.t2, k);
      r.mu = m.friction;
      r.parent = c.firstRow + k;
      r.lambda = m.tangentImpulse[k][d];
      solver.rows.push_back(r);
    }
  }
}

std::vector<float> World::Impl::jointStiffness() const {
  // Each joint's force |f| at each dynamic body's arm |r| (N m/rad), by body slot.
  std::vector<float> k(bodies.capacity(), 0.0f);
  for (uint32_t i = 0; i < joints.capacity(); ++i) {
    if (!joints.alive(i)) continue;
    const JointRec& j = joints.at(i);
    const float f = length(j.state.reactionForce);
    if (!(f > 0)) continue;
    const BodyRec* A = j.def.bodyA.isNull() ? nullptr : bodies.get(j.def.bodyA);
    const BodyRec& B = *bodies.get(j.def.bodyB);
    BodyPose pa = A ? poseOf(*A) : BodyPose{}, pb = poseOf(B);
    JointFrame fr = jointFrame(j, A ? &pa : nullptr, pb);
    if (A && A->type == BodyType::Dynamic) k[j.def.bodyA.index] += f * length(fr.rA);
    if (B.type == BodyType::Dynamic) k[j.def.bodyB.index] += f * length(fr.rB);
  }
  return k;
}

void World::Impl::addGeometricStiffness(float h) {
  // Andrews, Teichmann and Kry 2017: a joint force f at arm r turns into a torque that
  // changes as the body turns, a stiffness of about |f| |r| (N m/rad). Our Jacobians are
  // frozen over a substep, so that stiffness is integrated explicitly and blows up once
  // omega h > ~1: a 1 kg link between a 1000 kg ball and the anchor, at the bottom of the
  // swing (tension 3e4 N), has omega of about 340 rad/s. Adding h^2 k to the inertia (the
  // implicit-Euler term, from last step's joint forces) makes the link's rotation stable at
  // any substep; a light body under a large load turns a little more slowly.
  if (stepJoints.empty()) return;
  const std::vector<float> bySlot = jointStiffness();
  std::vector<float> k(solver.bodies.size(), 0.0f);
  for (uint32_t slot = 0; slot < bySlot.size(); ++slot)
    if (bySlot[slot] > 0) k[size_t(bodies.at(slot).solverIndex)] = bySlot[slot];
  for (size_t i = 1; i < solver.bodies.size(); ++i) {
    if (!(k[i] > 0)) continue;
    SolverBody& sb = solver.bodies[i];
    const Mat3 R = toMat3(sb.q);
    Mat3 I = R * sb.inertiaLocal * transpose(R);  // world inertia, as invI was made
    const float add = h * h * k[i];
    I.c0.x += add;
    I.c1.y += add;
    I.c2.z += add;
    sb.invI = inverse(I);
    sb.isotropic = false;
  }
}

void World::Impl::buildSolverBodies(const SolverSettings& s) {
  // Prepare: the compact solver bodies (index 0 is the static world), then one row per
  // joint axis and per contact normal and friction direction.
  const float h = def.timeStep / float(s.substeps);
  solver.rows.clear();
  solver.blockInvK.clear();
  solver.contactK.clear();
  solver.blockContacts = s.blockContacts;
  // The awake bodies (static and sleeping ones are solver body 0, the world), on the world's
  // threads: each writes its own slots.
  const size_t awake = awakeBodies.size();
  solver.bodies.resize(awake + 1);
  solver.bodies[0] = SolverBody{};
  solver.bodies[0].isotropic = true;  // zero inverse inertia
  solverCom.resize(awake + 1);
  solverCom[0] = Vec3{};
  forEachRange(awake, [&](size_t begin, size_t end) {
    for (size_t k = begin; k < end; ++k) {
      BodyRec& b = bodies.at(awakeBodies[k]);
      b.solverIndex = int32_t(k + 1);
      SolverBody sb;
      sb.v = b.v;
      sb.w = b.w;
      sb.q = b.xf.q;
      sb.dynamic = b.type == BodyType::Dynamic;
      sb.isotropic = !sb.dynamic;  // zero inverse inertia
      if (sb.dynamic) {
        sb.invMass = b.invMass;
        // A multiple of the identity is one in every frame: kept exact, not rounded through
        // the rotation (Solver::finishRows and the wide blocks take the one number).
        const Mat3& L = b.invInertiaLocal;
        sb.isotropic = L.c0 == Vec3{L.c0.x, 0, 0} && L.c1 == Vec3{0, L.c0.x, 0} &&
                       L.c2 == Vec3{0, 0, L.c0.x};
        if (sb.isotropic) {
          sb.invI = L;
        } else {
          const Mat3 R = toMat3(b.xf.q);
          sb.invI = R * L * transpose(R);
        }
        sb.inertiaLocal = b.inertiaLocal;
        sb.linearAccel = def.gravity * b.gravityScale + b.force * b.invMass;
        sb.torque = b.torque;
        sb.linearDamping = b.linearDamping;
        sb.angularDamping = b.angularDamping;
        // Equal principal moments (a cube, a sphere) have no gyroscopic torque (w x I w = 0):
        // the plain rotation update of non-gyroscopic bodies serves, a quarter of the cost.
        // It turns by 2 atan(|w| h / 2) instead of |w| h, an O((|w| h)^3) difference.
        const Vec3 I = b.principalMoments;
        const float spread = std::max({I.x, I.y, I.z}) - std::min({I.x, I.y, I.z});
        sb.gyroscopic = b.gyroscopic && spread > 1e-5f * std::max({I.x, I.y, I.z});
        sb.principal = b.principal;
        sb.principalMoments = b.principalMoments;
      }
      solver.bodies[k + 1] = sb;
      solverCom[k + 1] = b.com;
    }
  });
  stats.bodies = int(bodies.size());
  stats.awake = int(awake);
  collectStepJoints();
  if (s.geometricStiffness) addGeometricStiffness(h);

  // Joints first: the solver meets them before contacts in every iteration.
  int jointsBuilt = 0;
  for (uint32_t i : stepJoints) {
    JointRec& j = joints.at(i);
    const BodyRec* A = j.def.bodyA.isNull() ? nullptr : bodies.get(j.def.bodyA);
    const BodyRec& B = *bodies.get(j.def.bodyB);
    BodyPose pa = A ? poseOf(*A) : BodyPose{}, pb = poseOf(B);
    buildJointRows(j, A ? &pa : nullptr, pb, A ? A->solverIndex : 0, B.solverIndex, h, &solver);
    // Warm start from last step's impulses when the joint still has the same rows.
    if (s.warmStart && j.impulseCount == j.rowCount) {
      for (int32_t k = 0; k < j.rowCount; ++k)
        solver.rows[size_t(j.firstRow + k)].lambda = j.impulses[k];
    }
    ++jointsBuilt;
  }
  stats.joints = jointsBuilt;

  // Contacts: 3 rows per point (normal, two friction directions), or with the vectorized
  // Gauss-Seidel scheme no rows but a manifold each, which the wide blocks take (bit-identical
  // to the rows; solver_wide.h). Not for the split push-out and the position pass, which
  // read the contact rows between the iterations, nor for the contact block solve.
  // Built serially: building them in parallel needs the vector sized first, and
  // value-initializing 28,000 rows of 160 bytes (pyramid_40) cost more than the parallel
  // build saved.
  const bool split = orderContacts(s, contactParts);
  // Mass-ratio islands' normal rows are solved directly, which needs rows: such a step is
  // the scalar solve (bit-identical to the wide blocks).
  const bool directContactsNeeded = findDirectContactIslands(s);
  const bool vectorized =
      vectorizedContacts() && s.scheme == SolverSettings::Scheme::GaussSeidel && !s.blockContacts &&
      !s.splitPushout && !directContactsNeeded &&
      (s.positionPass == SolverSettings::PositionPass::None || s.positionIterations == 0);
  manifoldContact.clear();
  contactRowsBuilt = !vectorized && !contactOrder.empty();
  std::vector<std::vector<uint32_t>> directRows;  // per island, its normal rows
  std::vector<int32_t> islandSlot(directContactsNeeded ? solver.bodies.size() : 0, -1);
  for (size_t k = 0; k < contactOrder.size(); ++k) {
    Contact& c = contacts[contactOrder[k]];
    if (vectorized) {
      manifoldContact.push_back(contactOrder[k]);
      continue;
    }
    c.firstRow = int32_t(solver.rows.size());
    contactRowsOf(c, solverManifold(c, s));
    if (directContactsNeeded && directIsland[k] >= 0) {
      int32_t& slot = islandSlot[size_t(directIsland[k])];
      if (slot < 0) {
        slot = int32_t(directRows.size());
        directRows.emplace_back();
      }
      for (int p = 0; p < c.manifold.count; ++p)
        if (c.manifold.points[p].separation <= SolverSettings::kDirectContactGap)
          directRows[size_t(slot)].push_back(uint32_t(c.firstRow + p));
    }
  }
  // Every field of a manifold is assigned below: resizing without a clear spares zeroing
  // the entries that were there last step.
  manifolds.resize(manifoldContact.size());
  auto makeManifolds = [&](size_t begin, size_t end) {
    for (size_t i = begin; i < end; ++i)
      manifolds[i] = solverManifold(contacts[manifoldContact[i]], s);
  };
  if (pool)
    pool->parallelFor(manifolds.size(), kContactGrain, makeManifolds);
  else
    makeManifolds(0, manifolds.size());
  solver.scheme = s.scheme;
  solver.indexUnits();
  solver.finishRows(0, solver.rows.size());
  solver.wide = &wide;
  if (vectorized)
    wide.build(solver, manifolds, split ? &contactParts : nullptr);
  else
    wide.clear();
  directContacts.setup(solver, std::move(directRows));
  solver.markTrackedRotations(manifolds);
  // Restitution's collision phase: the elastic contacts' normal rows, with the bodies' own
  // masses (impacts.h).
  impacts.clear();
  if (s.restitution && anyContact([](const Contact& c) { return c.restitution > 0; })) {
    for (uint32_t ci : contactOrder) {
      const Contact& c = contacts[ci];
      if (!(c.restitution > 0)) continue;
      const BodyRec& A = *bodies.get(c.bodyA);
      const BodyRec& B = *bodies.get(c.bodyB);
      Vec3 rA[Manifold::kMaxPoints], rB[Manifold::kMaxPoints];
      float separation[Manifold::kMaxPoints];
      for (int k = 0; k < c.manifold.count; ++k) {
        rA[k] = c.manifold.points[k].point - A.com;
        rB[k] = c.manifold.points[k].point - B.com;
        separation[k] = c.manifold.points[k].separation;
      }
      impacts.add(A.solverIndex, B.solverIndex, c.manifold.normal, rA, rB, separation,
                  c.manifold.count, c.restitution, solver.bodies);
    }
  }
  stats.vectorizedManifolds = int(manifolds.size());
}

int World::Impl::limitRestitutionEnergy(const std::vector<Velocity>& before) {
  // An impact with restitution at most 1 cannot end with more energy than it started with.
  // Each collision of the step's phases makes none (impacts.h), but the step is more than its
  // collisions: the integrator's energy at a step's end rises by g h v / 2 on the way up after
  // a bounce (an e = 1 ball gained 1.6 % in 10 s with the default without this), and the
  // point-by-point pass this replaced made energy at simultaneous contacts (5.2 % of 1000
  // random elastic configurations; +60 % on a struck row of five balls). `before` is the
  // velocities less the collisions' changes dv: the velocities are v(a) = v_before + a dv,
  // and the largest a in [0, 1] whose island energy stays within the budget is taken (the
  // energy is quadratic in a).
  const size_t n = solver.bodies.size();
  std::vector<uint8_t> changed(n, 0);
  bool any = false;
  for (size_t i = 1; i < n; ++i) {
    const SolverBody& b = solver.bodies[i];
    if (!b.dynamic) continue;
    const Velocity& v0 = before[i];
    if (b.v.x != v0.v.x || b.v.y != v0.v.y || b.v.z != v0.v.z || b.w.x != v0.w.x ||
        b.w.y != v0.w.y || b.w.z != v0.w.z)
      changed[i] = 1, any = true;
  }
  if (!any) return 0;
  // Islands over the touching dynamic bodies: energy moves through every contact.
  DisjointSets sets;
  sets.reset(n);
  auto find = [&](int32_t i) { return sets.root(i); };
  for (uint32_t ci : contactOrder) {
    const Contact& c = contacts[ci];
    const int32_t a = bodies.at(c.bodyA.index).solverIndex, b = bodies.at(c.bodyB.index).solverIndex;
    if (a > 0 && b > 0 && solver.bodies[size_t(a)].dynamic && solver.bodies[size_t(b)].dynamic)
      sets.join(a, b);
  }
  std::vector<uint8_t> hit(n, 0);  // roots of islands with a changed body
  for (size_t i = 1; i < n; ++i)
    if (changed[i]) hit[size_t(find(int32_t(i)))] = 1;
  // Per island: the budget (kinetic energy at the step's start plus the work of gravity and
  // applied forces over the step) and the energy after the pass, q2 a^2 + q1 a + q0.
  struct Sums {
    double budget = 0, q0 = 0, q1 = 0, q2 = 0;
  };
  std::vector<Sums> sums(n);
  for (size_t i = 1; i < n; ++i) {
    const SolverBody& sb = solver.bodies[i];
    if (!sb.dynamic) continue;
    const int32_t root = find(int32_t(i));
    if (!hit[size_t(root)]) continue;
    const BodyRec& b = bodies.at(awakeBodies[i - 1]);
    const double m = b.mass;
    auto rot = [&](Quat q, Vec3 u, Vec3 v) {  // u^T I v, world vectors, I at orientation q
      return double(dot(invRotate(q, u), b.inertiaLocal * invRotate(q, v)));
    };
    Sums& s = sums[size_t(root)];
    s.budget += 0.5 * m * double(dot(b.v, b.v)) + 0.5 * rot(b.xf.q, b.w, b.w) +
                m * double(dot(sb.linearAccel, sb.dp)) + double(dot(sb.torque, sb.dtheta));
    const Velocity& v0 = before[i];
    const Vec3 dv = sb.v - v0.v, dw = sb.w - v0.w;
    s.q0 += 0.5 * m * double(dot(v0.v, v0.v)) + 0.5 * rot(sb.q, v0.w, v0.w);
    s.q1 += m * double(dot(v0.v, dv)) + rot(sb.q, v0.w, dw);
    s.q2 += 0.5 * m * double(dot(dv, dv)) + 0.5 * rot(sb.q, dw, dw);
  }
  std::vector<float> scale(n, 1.0f);
  int scaled = 0;
  for (size_t r = 1; r < n; ++r) {
    if (!hit[r]) continue;
    const Sums& s = sums[r];
    const double limit = s.budget + 1e-9 * std::fabs(s.budget);
    if (s.q2 + s.q1 + s.q0 <= limit) continue;
    // The largest a in [0, 1] with q2 a^2 + q1 a + q0 <= limit (the larger root: a = 1 is
    // over); when no a in [0, 1] is within, the a of least energy. (a = 0 itself can be over:
    // a ball that bounced in mid-step has fallen less far than the velocity it had before
    // the bounce would say.)
    double a = 0;
    const double disc = s.q1 * s.q1 - 4 * s.q2 * (s.q0 - limit);
    const double upper = s.q2 > 0 && disc >= 0 ? (-s.q1 + std::sqrt(disc)) / (2 * s.q2) : -1;
    if (upper >= 0)
      a = upper;
    else if (s.q2 > 0)
      a = -s.q1 / (2 * s.q2);
    scale[r] = float(std::clamp(a, 0.0, 1.0));
    ++scaled;
  }
  if (scaled == 0) return 0;
  for (size_t i = 1; i < n; ++i) {
    if (!changed[i]) continue;
    const float a = scale[size_t(find(int32_t(i)))];
    if (a == 1) continue;
    SolverBody& sb = solver.bodies[i];
    sb.v = before[i].v + (sb.v - before[i].v) * a;
    sb.w = before[i].w + (sb.w - before[i].w) * a;
  }
  return scaled;
}

bool World::Impl::findDirectContactIslands(const SolverSettings& s) {
  directIsland.assign(contactOrder.size(), -1);
  if (!(s.directContactRatio > 0) || s.scheme == SolverSettings::Scheme::Jacobi) return false;
  // Islands over the awake dynamic bodies (solver indices; static and kinematic bodies join
  // none), and which of them hold a touching pair of mass ratio directContactRatio or more.
  DisjointSets sets;
  sets.reset(solver.bodies.size());
  auto find = [&](int32_t i) { return sets.root(i); };
  auto dynamicIndex = [&](BodyId id) {
    const BodyRec& b = bodies.at(id.index);
    return b.type == BodyType::Dynamic && b.solverIndex > 0 ? b.solverIndex : 0;
  };
  // Joints (docs/ARCHITECTURE.md, "Direct contacts on jointed bodies"): solved by the LDL
  // hybrid, they join their bodies' islands, and the direct solve sees them through the
  // Schur complement of their rows (DirectContacts::setup). Iterated, they would fight the
  // direct rows through every light jointed body: the contacts of jointed bodies are then
  // iterated too.
  const bool jointsExact = s.equalitySolve == SolverSettings::EqualitySolve::DirectLdl;
  std::vector<uint8_t> jointed;
  if (!stepJoints.empty()) {
    jointed.assign(solver.bodies.size(), 0);
    for (uint32_t i : stepJoints) {
      const JointRec& j = joints.at(i);
      const int32_t a = j.def.bodyA.isNull() ? 0 : dynamicIndex(j.def.bodyA);
      const int32_t b = dynamicIndex(j.def.bodyB);
      jointed[size_t(a)] = jointed[size_t(b)] = 1;
      if (jointsExact && a != 0 && b != 0) sets.join(a, b);
    }
    jointed[0] = 0;
  }
  auto excluded = [&](int32_t i) { return !jointsExact && !jointed.empty() && jointed[size_t(i)]; };
  // The heavy pairs first: most steps have none (looked for on the world's threads), and then
  // need no islands (the sets' roots, the lowest index of each, do not depend on the order of
  // the joins).
  auto heavy = [&](const Contact& c) {
    const int32_t a = dynamicIndex(c.bodyA), b = dynamicIndex(c.bodyB);
    if (a == 0 || b == 0 || excluded(a) || excluded(b)) return false;
    const float ma = bodies.at(c.bodyA.index).mass, mb = bodies.at(c.bodyB.index).mass;
    return std::max(ma, mb) >= s.directContactRatio * std::min(ma, mb);
  };
  if (!anyContact(heavy)) return false;
  std::vector<std::pair<int32_t, int32_t>> heavyPairs;
  for (uint32_t ci : contactOrder) {
    const Contact& c = contacts[ci];
    const int32_t a = dynamicIndex(c.bodyA), b = dynamicIndex(c.bodyB);
    if (a == 0 || b == 0 || excluded(a) || excluded(b)) continue;
    const float ma = bodies.at(c.bodyA.index).mass, mb = bodies.at(c.bodyB.index).mass;
    if (std::max(ma, mb) >= s.directContactRatio * std::min(ma, mb)) heavyPairs.push_back({a, b});
  }
  if (heavyPairs.empty()) return false;
  for (uint32_t ci : contactOrder) {
    const Contact& c = contacts[ci];
    const int32_t a = dynamicIndex(c.bodyA), b = dynamicIndex(c.bodyB);
    if (a != 0 && b != 0 && !excluded(a) && !excluded(b)) sets.join(a, b);
  }
  // Normal rows per island (contacts with static bodies count for their dynamic body's).
  std::vector<int32_t> rowsOf(solver.bodies.size(), -1);  // -1: not a mass-ratio island
  for (const auto& [a, b] : heavyPairs) rowsOf[size_t(find(a))] = 0;
  std::vector<int32_t> root(contactOrder.size(), 0);
  for (size_t k = 0; k < contactOrder.size(); ++k) {
    const Contact& c = contacts[contactOrder[k]];
    const int32_t a = dynamicIndex(c.bodyA), b = dynamicIndex(c.bodyB);
    if ((a == 0 && b == 0) || excluded(a) || excluded(b)) continue;
    root[k] = find(a != 0 ? a : b);
    if (rowsOf[size_t(root[k])] >= 0)
      for (int p = 0; p < c.manifold.count; ++p)
        rowsOf[size_t(root[k])] +=
            c.manifold.points[p].separation <= SolverSettings::kDirectContactGap;
  }
  bool any = false;
  for (size_t k = 0; k < contactOrder.size(); ++k) {
    const int32_t r = root[k];
    if (r == 0 || rowsOf[size_t(r)] <= 0 ||
        rowsOf[size_t(r)] > SolverSettings::kDirectContactMaxRows) {
      continue;
    }
    directIsland[k] = r;
    any = true;
  }
  return any;
}

bool World::Impl::orderContacts(const SolverSettings& s, ContactParts& parts) {
  // The Gauss-Seidel order of the touching contacts: with many contacts, in nested parts (the
  // leaves' contacts, then the separators', the deepest cuts first: solver_wide.h, "Nested
  // parts"), so that the leaves, then each depth's separators, run on all threads at once; the
  // same order with any thread count, and in the rows as in the wide blocks.
  contactOrder.clear();
  for (uint32_t ci = 0; ci < contacts.size(); ++ci) {
    Contact& c = contacts[ci];
    c.firstRow = -1;
    // Not between a sleeping body and a resting kinematic one (wakeTouched woke the others).
    if (c.manifold.count > 0 &&
        (sleepingBodyCount == 0 ||
         (!bodies.at(c.bodyA.index).asleep() && !bodies.at(c.bodyB.index).asleep())))
      contactOrder.push_back(ci);
  }
  parts.levels =
      s.scheme == SolverSettings::Scheme::GaussSeidel ? partLevels(contactOrder.size()) : 0;
  parts.end.clear();
  stats.contactsBetweenHalves = -1;
  stats.contactParts = 0;
  if (parts.levels == 0) return false;
  std::vector<std::pair<int32_t, int32_t>> pairs(contactOrder.size());  // solver bodies
  forEachRange(pairs.size(), [&](size_t begin, size_t end) {
    for (size_t k = begin; k < end; ++k) {
      const Contact& c = contacts[contactOrder[k]];
      pairs[k] = {bodies.get(c.bodyA)->solverIndex, bodies.get(c.bodyB)->solverIndex};
    }
  });
  splitParts(solver.bodies, solverCom, pairs, parts.levels, solverPart, pool.get());
  // The contacts by segment (a stable counting sort: each leaf keeps the contacts' order),
  // then each separator's by colour (solver_wide.h), so that they fill blocks.
  const size_t segments = segmentCount(parts.levels), leaves = size_t(1) << parts.levels;
  std::vector<uint32_t> segmentOf(pairs.size());
  forEachRange(pairs.size(), [&](size_t begin, size_t end) {
    for (size_t k = begin; k < end; ++k)
      segmentOf[k] = contactSegment(solverPart, parts.levels, pairs[k].first, pairs[k].second);
  });
  std::vector<uint32_t> start(segments + 1, 0);
  for (uint32_t seg : segmentOf) ++start[seg + 1];
  for (size_t i = 0; i < segments; ++i) start[i + 1] += start[i];
  std::vector<uint32_t> bySegment(pairs.size());  // indices into contactOrder and pairs
  {
    std::vector<uint32_t> at(start.begin(), start.end() - 1);
    for (uint32_t k = 0; k < pairs.size(); ++k) bySegment[at[segmentOf[k]]++] = k;
  }
  std::vector<uint32_t> order;
  order.reserve(contactOrder.size());
  std::vector<std::pair<int32_t, int32_t>> separator;
  for (size_t i = 0; i < segments; ++i) {
    const auto first = bySegment.begin() + std::ptrdiff_t(start[i]);
    const auto last = bySegment.begin() + std::ptrdiff_t(start[i + 1]);
    if (i < leaves) {
      for (auto it = first; it != last; ++it) order.push_back(contactOrder[*it]);
    } else {
      separator.clear();
      for (auto it = first; it != last; ++it) separator.push_back(pairs[*it]);
      for (uint32_t j : colorOrder(solver.bodies, separator))
        order.push_back(contactOrder[first[std::ptrdiff_t(j)]]);
    }
    parts.end.push_back(uint32_t(order.size()));
  }
  contactOrder.swap(order);
  stats.contactsBetweenHalves = int(contactOrder.size() - start[leaves]);
  stats.contactParts = int(leaves);
  return true;
}

void World::Impl::refreshJoints(float h) {
  for (uint32_t i : stepJoints) {
    JointRec& j = joints.at(i);
    const BodyRec* A = j.def.bodyA.isNull() ? nullptr : bodies.get(j.def.bodyA);
    const BodyRec& B = *bodies.get(j.def.bodyB);
    auto current = [&](const BodyRec& b) {
      // Static bodies all share solver body 0 (the world): their pose is their own.
      if (b.solverIndex == 0) return poseOf(b);
      const SolverBody& sb = solver.bodies[size_t(b.solverIndex)];
      return BodyPose{sb.q, b.com + sb.dp, b.localCenter};
    };
    BodyPose pa = A ? current(*A) : BodyPose{}, pb = current(B);
    refreshJointRows(j, A ? &pa : nullptr, pb, A ? A->solverIndex : 0, B.solverIndex, h, &solver);
  }
}

void World::Impl::finalize(float hSub) {
  forEachRange(awakeBodies.size(), [&](size_t begin, size_t end) {
    for (size_t k = begin; k < end; ++k) {
      BodyRec& b = bodies.at(awakeBodies[k]);
      b.force = b.torque = {};
      const SolverBody& sb = solver.bodies[size_t(b.solverIndex)];
      b.v = sb.v;
      b.w = sb.w;
      b.com += sb.dp;
      b.xf.q = sb.q;
      b.xf.p = b.com - rotate(b.xf.q, b.localCenter);
    }
  });
  // Joint reactions (the rows' impulses per substep as forces on B) and errors at the new poses.
  for (uint32_t i : stepJoints) {
    JointRec& j = joints.at(i);
    Vec3 f, tq;
    for (int32_t r = j.firstRow; r < j.firstRow + j.rowCount; ++r) {
      const Row& row = solver.rows[size_t(r)];
      f += row.linB * (row.lambda / hSub);
      // Only rows that are pure rotation: the moment of the force above is not included.
      if (row.linB == Vec3{}) tq += row.angB * (row.lambda / hSub);
    }
    j.state.reactionForce = f;
    j.state.reactionTorque = tq;
  }
  measureJoints();
}

void World::Impl::measureJoints() {
  for (uint32_t i : stepJoints) {
    JointRec& j = joints.at(i);
    const BodyRec* A = j.def.bodyA.isNull() ? nullptr : bodies.get(j.def.bodyA);
    BodyPose pa = A ? poseOf(*A) : BodyPose{}, pb = poseOf(*bodies.get(j.def.bodyB));
    measureJoint(j, A ? &pa : nullptr, pb, &j.state.positionError, &j.state.angleError);
  }
}

}  // namespace phys
