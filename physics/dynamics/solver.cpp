#include "dynamics/solver.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <bit>
#include <cassert>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>

#include "dynamics/solver_ldl.h"
#include "dynamics/solver_wide.h"
#include "base/thread_pool.h"

namespace phys {

void Solver::release() noexcept {
  forEachArray(*this, [](auto& v) { std::remove_reference_t<decltype(v)>().swap(v); });
  pushActive = false;
}

size_t Solver::capacityBytes() const {
  size_t bytes = 0;
  forEachArray(*this, [&](const auto& v) { bytes += v.capacity() * sizeof(v[0]); });
  return bytes;
}

namespace {
// Split push-out: the soft contact's own bias corrects penetration up to this depth (a
// resting contact's sag, so stacks behave exactly as without the split); the pseudo
// velocities push out the rest.
constexpr float kSplitDepth = SolverSettings::kSplitDepth;
// Stiffness is capped at a quarter of the substep rate: stiffer springs are not resolved by
// the integrator and only add energy (and topple stacks).
float cappedHertz(float hertz, float invH) {
  return std::min(hertz, 0.25f * invH);
}
// Parallel chunk sizes: a contact group (a 4-point manifold with friction) takes a fraction
// of a microsecond, a body's integration much less. A loop no larger
// than one chunk runs inline: on this 2-core VM, waking the other core for a loop of a few
// hundred bodies (pyramid_40's 821) cost more than it saved (integrate_positions went from 0.10
// to 0.26 ms per step), while the colors of the solve come back to back and do gain.
constexpr size_t kGroupGrain = 32;
constexpr size_t kBodyGrain = 4096;
/// Colors of the colored Gauss-Seidel scheme (bits of a mask per body).
constexpr int kMaxColors = 64;

std::atomic<bool> gBodyWarmStart{true};

/// max over threads. max is exact and order-free: the same result for any thread count.
void atomicMax(std::atomic<float>& m, float v) {
  float cur = m.load(std::memory_order_relaxed);
  while (v > cur && !m.compare_exchange_weak(cur, v, std::memory_order_relaxed)) {
  }
}
}  // namespace

void setBodyWarmStart(bool on) {
  gBodyWarmStart = on;
}
bool bodyWarmStart() {
  return gBodyWarmStart;
}

/// One iteration's constants.
struct Solver::IterationParams {
  Softness contactSoft, jointSoft;
  float h = 0, invH = 0, linearSlop = 0, maxPushout = 0;
  bool soft = true, useBias = true, skipEquality = false, skipDirect = false;
  ContactRule contact;
  bool splitPushout = false;  ///< penetration is resolved by solvePushout, not here
  bool measure = false;       ///< compute the convergence measure
};

template <class F>
void Solver::parallel(size_t count, size_t grain, F&& fn) {
  if (pool)
    pool->parallelFor(count, grain, fn);
  else if (count > 0)
    fn(size_t(0), count);
}

Row contactRow(const SolverManifold& m, RowKind kind, Vec3 axis, int k) {
  Row r;
  r.kind = kind;
  r.a = m.a;
  r.b = m.b;
  r.linA = -axis;
  r.angA = -cross(m.rA[k], axis);
  r.linB = axis;
  r.angB = cross(m.rB[k], axis);
  return r;
}

ContactTerms ContactRule::terms(const Row& r, float C) const {
  ContactTerms t;
  if (C > 0) {
    t.bias = C * invH;  // speculative: close exactly the gap this substep, no more
  } else if (useBias) {
    // Slop only with Baumgarte: a soft contact's spring has zero rest length, and a slop
    // there only lets bodies sink into each other by that much.
    float slop = !softStabilization && r.kind == RowKind::ContactNormal ? linearSlop : 0;
    float Cs = std::min(0.0f, C + slop);
    // Split push-out: deeper than a resting sag is solvePushout's.
    if (splitPushout && r.kind == RowKind::ContactNormal)
      Cs = std::max(Cs, -SolverSettings::kSplitDepth);
    t.bias = std::max(soft.biasRate * Cs, -maxPushout);
    t.massScale = soft.massScale;
    t.impulseScale = soft.impulseScale;
  }
  return t;
}

Softness makeSoftness(float hertz, float zeta, float h) {
  if (hertz <= 0) return {0, 1, 0};
  // Catto 2011: an implicit spring-damper expressed as bias rate and mass/impulse scales.
  float omega = 2 * kPi * hertz;
  float a1 = 2 * zeta + h * omega;
  float a2 = h * omega * a1;
  float a3 = 1 / (1 + a2);
  return {omega / a1, a2 * a3, a3};
}

void Solver::finishRows(size_t first, size_t last) {
  // Serial: in parallel, the rows the other core wrote in the last step's solve are fetched
  // across cores, and prepare took 1.3 ms instead of 0.7 on pyramid_40.
  for (size_t i = first; i < last; ++i) {
    Row& r = rows[i];
    const SolverBody& A = bodies[size_t(r.a)];
    const SolverBody& B = bodies[size_t(r.b)];
    // Jacobi: each constraint sees a body with its mass divided among its constraints.
    const float sa = jacobi() ? split[size_t(r.a)] : 1;
    const float sb = jacobi() ? split[size_t(r.b)] : 1;
    r.mLinA = r.linA * (A.invMass * sa);
    r.mAngA = (A.isotropic ? r.angA * A.invI.c0.x : A.invI * r.angA) * sa;
    r.mLinB = r.linB * (B.invMass * sb);
    r.mAngB = (B.isotropic ? r.angB * B.invI.c0.x : B.invI * r.angB) * sb;
    float k =
        dot(r.linA, r.mLinA) + dot(r.angA, r.mAngA) + dot(r.linB, r.mLinB) + dot(r.angB, r.mAngB);
    r.effMass = k > 1e-12f ? 1 / k : 0;
  }
  finishBlocks(first, last);
}

void Solver::finishBlocks(size_t first, size_t last) {
  // Block matrices K = J M^-1 J^T of joint row groups and, with the contact block solve, of
  // manifolds' normal rows (after every row has its M^-1 J^T).
  auto coupling = [](const Row& ra, const Row& rb) {
    return dot(ra.linA, rb.mLinA) + dot(ra.angA, rb.mAngA) + dot(ra.linB, rb.mLinB) +
           dot(ra.angB, rb.mAngB);
  };
  for (size_t i = first; i < last; ++i) {
    Row& r = rows[i];
    if (blockContacts && r.kind == RowKind::ContactNormal && r.groupStart) {
      int n = 1;
      while (n < 4 && i + size_t(n) < last && rows[i + size_t(n)].kind == RowKind::ContactNormal &&
             !rows[i + size_t(n)].groupStart)
        ++n;
      if (n < 2) continue;
      std::array<float, 16> K{};
      for (int a = 0; a < n; ++a)
        for (int b = 0; b < n; ++b)
          K[size_t(a * n + b)] = coupling(rows[i + size_t(a)], rows[i + size_t(b)]);
      r.contactPoints = uint8_t(n);
      r.blockIndex = int32_t(contactK.size());
      contactK.push_back(K);
      continue;
    }
    if (r.blockSize < 2) continue;
    Mat3 K = Mat3::diagonal({1, 1, 1});
    for (int a = 0; a < r.blockSize; ++a) {
      for (int b = 0; b < r.blockSize; ++b) {
        (&K.c0)[b][a] = coupling(rows[i + size_t(a)], rows[i + size_t(b)]);
      }
    }
    // A singular block (e.g. both bodies static) gets zero impulses.
    if (r.blockIndex < 0) {
      r.blockIndex = int32_t(blockInvK.size());
      blockInvK.emplace_back();
    }
    blockInvK[size_t(r.blockIndex)] = inverse(K);
  }
}

float Solver::solveBlock(size_t first, const IterationParams& p, Velocity& A, Velocity& B) {
  const Row& r0 = rows[first];
  const int n = r0.blockSize;
  const Softness& soft = p.jointSoft;
  Vec3 err, lambda;
  for (int a = 0; a < n; ++a) {
    const Row& r = rows[first + size_t(a)];
    err[a] = rowVelocity(r, A, B) + (p.useBias ? soft.biasRate * rowError(r) : 0);
    lambda[a] = r.lambda;
  }
  const float massScale = p.useBias ? soft.massScale : 1;
  const float impulseScale = p.useBias ? soft.impulseScale : 0;
  Vec3 d = blockInvK[size_t(r0.blockIndex)] * err * -massScale - lambda * impulseScale;
  float change = 0;
  for (int a = 0; a < n; ++a) {
    Row& r = rows[first + size_t(a)];
    r.lambda += d[a];
    if (d[a] == 0) continue;
    applyImpulse(r, d[a], A, B);
    if (p.measure && r.effMass > 0) change = std::max(change, std::abs(d[a]) / r.effMass);
  }
  return change;
}

namespace {
void integrateVelocity(SolverBody& b, float h, float maxLinearSpeed, float maxAngularSpeed) {
  if (!b.dynamic) return;
  Vec3 v = b.v + b.linearAccel * h;
  Vec3 w = b.w;
  w += b.invI * b.torque * h;
  v *= 1 / (1 + h * b.linearDamping);
  w *= 1 / (1 + h * b.angularDamping);
  // Lengths in double: a huge finite speed overflows a float length to infinity, and the
  // clamp would then zero the velocity instead of capping it.
  double vl = std::sqrt(double(v.x) * v.x + double(v.y) * v.y + double(v.z) * v.z);
  if (vl > maxLinearSpeed) v *= float(maxLinearSpeed / vl);
  double wl = std::sqrt(double(w.x) * w.x + double(w.y) * w.y + double(w.z) * w.z);
  if (wl > maxAngularSpeed) w *= float(maxAngularSpeed / wl);
  b.v = v;
  b.w = w;
}
}  // namespace

void Solver::integrateVelocities(float h, float maxLinearSpeed, float maxAngularSpeed,
                                 BodyWarmStart warm) {
  warmTracked_ = warm != BodyWarmStart::Off;
  if (warmTracked_) {
    warmBase_.resize(bodies.size());
    warmSum_.resize(bodies.size());
  }
  parallel(bodies.size(), kBodyGrain, [&](size_t begin, size_t end) {
    for (size_t i = std::max<size_t>(begin, 1); i < end; ++i) {
      SolverBody& b = bodies[i];
      if (warm == BodyWarmStart::Apply && b.dynamic) {
        // The last substep's impulses: what they changed before integratePositions (in
        // warmSum_ already) and after it.
        warmSum_[i].v += b.v - warmBase_[i].v;
        warmSum_[i].w += b.w - warmBase_[i].w;
      }
      integrateVelocity(b, h, maxLinearSpeed, maxAngularSpeed);
      if (!warmTracked_) continue;
      warmBase_[i] = b;
      if (warm == BodyWarmStart::Apply && b.dynamic) {
        b.v += warmSum_[i].v;
        b.w += warmSum_[i].w;
      }
    }
  });
}

template <class F, class W>
float Solver::forEachScheduled(F&& f, W&& w) {
  if (!wide || !wide->active) return forEachGroup(std::forward<F>(f));
  auto run = [&](size_t begin, size_t end) {
    float m = 0;
    for (size_t k = begin; k < end; ++k) {
      const WideContacts::Item& item = wide->schedule[k];
      if (item.wide) {
        m = std::max(m, w(item.index));
      } else {
        const Group& g = groups[item.index];
        m = std::max(m, f(g, bodies[size_t(g.a)], bodies[size_t(g.b)]));
      }
    }
    return m;
  };
  if (wide->levels() == 0) return run(0, wide->schedule.size());
  // The row groups, then the nested parts' segments phase by phase, a phase's at once (they
  // share no dynamic body, and hold only wide blocks, which write dynamic bodies alone): the
  // bits of the serial pass (solver_wide.h, "Nested parts"). Each segment's largest change
  // in its own slot; max is exact and order-free.
  float m = run(0, wide->segment(0));
  std::array<float, kMaxSegments> segmentMax{};
  wide->forEachSegment(
      [&](size_t i) { segmentMax[i] = run(wide->segment(i), wide->segment(i + 1)); });
  for (float x : segmentMax) m = std::max(m, x);
  return m;
}

template <class F>
float Solver::forEachGroup(F&& f, bool pushChannel) {
  // The contact rows' impulses are in the wide blocks while they are active.
  assert(!wide || !wide->active);
  std::atomic<float> result{0};
  auto vel = [&](size_t i) -> Velocity& {
    return pushChannel ? push[i] : static_cast<Velocity&>(bodies[i]);
  };
  if (jacobi()) {
    // Every group from the same velocities, on its own copy of its two bodies; each body
    // then moves by the average of its groups' changes (the rows' M^-1 J^T carry the split),
    // summed in group order whatever the thread that solved them.
    groupDelta.resize(groups.size());
    parallel(groups.size(), kGroupGrain, [&](size_t begin, size_t end) {
      float m = 0;
      for (size_t gi = begin; gi < end; ++gi) {
        const Group& g = groups[gi];
        const Velocity a0 = vel(size_t(g.a)), b0 = vel(size_t(g.b));
        Velocity a = a0, b = b0;
        m = std::max(m, f(g, a, b));
        groupDelta[gi] = {{a.v - a0.v, a.w - a0.w}, {b.v - b0.v, b.w - b0.w}};
      }
      atomicMax(result, m);
    });
    parallel(bodies.size(), kBodyGrain, [&](size_t begin, size_t end) {
      for (size_t i = std::max<size_t>(begin, 1); i < end; ++i) {
        Vec3 dv, dw;
        for (uint32_t k = bodyRefStart[i]; k < bodyRefStart[i + 1]; ++k) {
          const GroupDelta& d = groupDelta[bodyRefs[k] >> 1];
          const Velocity& side = (bodyRefs[k] & 1) ? d.b : d.a;
          dv += side.v;
          dw += side.w;
        }
        vel(i).v += dv / split[i];
        vel(i).w += dw / split[i];
      }
    });
    return result.load();
  }
  auto serial = [&](uint32_t gi) {
    const Group& g = groups[gi];
    return f(g, vel(size_t(g.a)), vel(size_t(g.b)));
  };
  float m = 0;
  if (scheme == SolverSettings::Scheme::GaussSeidel) {
    for (uint32_t gi = 0; gi < groups.size(); ++gi) m = std::max(m, serial(gi));
    return m;
  }
  // Colored Gauss-Seidel (see indexUnits): joints in order, the colors in parallel, then
  // the overflow in order.
  for (size_t k = 0; k < overflowBegin; ++k) m = std::max(m, serial(serialGroups[k]));
  for (size_t c = 0; c + 1 < colorStart.size(); ++c) {
    const uint32_t first = colorStart[c];
    parallel(colorStart[c + 1] - first, kGroupGrain, [&](size_t begin, size_t end) {
      float cm = 0;
      for (size_t k = begin; k < end; ++k) {
        const Group& g = groups[colorGroups[first + k]];
        // Bodies shared inside a color (the world, kinematic bodies) are never written:
        // their constraints get a scratch copy.
        Velocity& A = vel(size_t(g.a));
        Velocity& B = vel(size_t(g.b));
        Velocity sa = A, sb = B;
        cm = std::max(
            cm, f(g, bodies[size_t(g.a)].dynamic ? A : sa, bodies[size_t(g.b)].dynamic ? B : sb));
      }
      atomicMax(result, cm);
    });
  }
  for (size_t k = overflowBegin; k < serialGroups.size(); ++k)
    m = std::max(m, serial(serialGroups[k]));
  return std::max(m, result.load());
}

/// Rows [begin, end) of a group's units.
static inline void groupRows(const Solver& s, const Solver::Group& g, size_t* begin, size_t* end) {
  *begin = s.units[g.unitBegin];
  *end = g.unitEnd < s.units.size() ? s.units[g.unitEnd] : s.rows.size();
}

void Solver::warmStart() {
  forEachScheduled(
      [&](const Group& g, Velocity& A, Velocity& B) {
        warmStartGroup(g, A, B);
        return 0.0f;
      },
      [&](uint32_t block) {
        wide->warmStart(block, bodies);
        return 0.0f;
      });
  if (wide && wide->active) wide->errorsCurrent = true;
}

void Solver::warmStartGroup(const Group& g, Velocity& A, Velocity& B) {
  size_t begin, end;
  groupRows(*this, g, &begin, &end);
  for (size_t i = begin; i < end; ++i) {
    const Row& r = rows[i];
    if (r.lambda != 0) applyImpulse(r, r.lambda, A, B);
  }
}

ContactRule Solver::contactRule(const SolverSettings& s, float h, bool useBias) {
  ContactRule c;
  c.invH = 1 / h;
  c.softStabilization = s.stabilization == SolverSettings::Stabilization::Soft;
  c.soft = c.softStabilization
               ? makeSoftness(cappedHertz(s.contactHertz, c.invH), s.contactDampingRatio, h)
               : Softness{s.baumgarte * c.invH, 1, 0};
  c.linearSlop = s.linearSlop;
  c.maxPushout = s.maxPushout;
  c.useBias = useBias;
  c.splitPushout = s.splitPushout;
  return c;
}

float Solver::solveIteration(const SolverSettings& s, float h, bool useBias, bool skipEquality,
                             bool skipDirect) {
  IterationParams p;
  p.contact = contactRule(s, h, useBias);
  p.skipDirect = skipDirect;
  // The contact fields the wide blocks and the contact block solve read, from the one rule.
  p.h = h;
  p.invH = p.contact.invH;
  p.soft = p.contact.softStabilization;
  p.contactSoft = p.contact.soft;
  p.jointSoft = p.soft ? makeSoftness(cappedHertz(s.jointHertz, p.invH), s.jointDampingRatio, h)
                       : Softness{s.baumgarte * p.invH, 1, 0};
  p.linearSlop = p.contact.linearSlop;
  p.maxPushout = p.contact.maxPushout;
  p.useBias = useBias;
  p.splitPushout = p.contact.splitPushout;
  p.skipEquality = skipEquality;
  p.measure = s.tolerance > 0;
  WideParams wp;
  wp.invH = p.invH;
  wp.linearSlop = p.linearSlop;
  wp.maxPushout = p.maxPushout;
  wp.biasRate = p.contactSoft.biasRate;
  wp.massScale = p.contactSoft.massScale;
  wp.impulseScale = p.contactSoft.impulseScale;
  wp.soft = p.soft;
  wp.useBias = p.useBias;
  wp.measure = p.measure;
  const float change = forEachScheduled(
      [&](const Group& g, Velocity& A, Velocity& B) { return solveGroup(g, A, B, p); },
      [&](uint32_t block) { return wide->solve(block, bodies, wp); });
  if (wide && wide->active) wide->errorsCurrent = true;  // the pass kept them
  return change;
}

float Solver::solveGroup(const Group& g, Velocity& A, Velocity& B, const IterationParams& p) {
  float change = 0;
  for (uint32_t u = g.unitBegin; u < g.unitEnd; ++u) {
    const size_t i = units[u];
    Row& r = rows[i];
    if (p.skipEquality && r.kind == RowKind::Equality) continue;
    if (p.skipDirect && r.direct) continue;
    if (r.kind == RowKind::Friction) {
      change = std::max(change, solveFrictionPair(r, rows[i + 1], A, B, p.measure));
      continue;
    }
    if (r.blockSize > 1) {
      change = std::max(change, solveBlock(i, p, A, B));
      continue;
    }
    if (r.contactPoints > 1 && p.useBias && p.soft && !p.splitPushout &&
        solveContactBlock(i, p, A, B, &change)) {
      u += r.contactPoints - 1u;  // every normal row is a unit of its own
      continue;
    }
    float vn = rowVelocity(r, A, B);
    float impulse = 0;
    switch (r.kind) {
      case RowKind::ContactNormal:
      case RowKind::Limit: {
        const ContactTerms t = p.contact.terms(r, rowError(r));
        impulse = -r.effMass * t.massScale * (vn + t.bias) - t.impulseScale * r.lambda;
        float next = std::max(r.lambda + impulse, 0.0f);
        impulse = next - r.lambda;
        r.lambda = next;
        r.maxLambda = std::max(r.maxLambda, next);
        break;
      }
      case RowKind::Friction:
        break;  // solved in pairs above
      case RowKind::Equality: {
        float bias = 0, massScale = 1, impulseScale = 0;
        if (p.useBias) {
          bias = p.jointSoft.biasRate * rowError(r);
          massScale = p.jointSoft.massScale;
          impulseScale = p.jointSoft.impulseScale;
        }
        impulse = -r.effMass * massScale * (vn + bias) - impulseScale * r.lambda;
        r.lambda += impulse;
        break;
      }
      case RowKind::Spring: {
        // A spring is soft in both passes: it is the physics, not an error correction.
        Softness sp = makeSoftness(r.hertz, r.dampingRatio, p.h);
        impulse = -r.effMass * sp.massScale * (vn + sp.biasRate * rowError(r)) -
                  sp.impulseScale * r.lambda;
        r.lambda += impulse;
        break;
      }
      case RowKind::Motor: {
        impulse = -r.effMass * (vn - r.target);
        float next = std::clamp(r.lambda + impulse, -r.maxImpulse, r.maxImpulse);
        impulse = next - r.lambda;
        r.lambda = next;
        break;
      }
      case RowKind::Twist: {
        const float bound = r.mu * frictionLoad(r);
        impulse = -r.effMass * vn;
        float next = std::clamp(r.lambda + impulse, -bound, bound);
        impulse = next - r.lambda;
        r.lambda = next;
        break;
      }
    }
    if (impulse == 0) continue;
    applyImpulse(r, impulse, A, B);
    if (p.measure && r.effMass > 0) change = std::max(change, std::abs(impulse) / r.effMass);
  }
  return change;
}

float Solver::equalityBiasRate(const SolverSettings& s, float h) {
  if (s.stabilization == SolverSettings::Stabilization::Baumgarte) return s.baumgarte / h;
  return makeSoftness(std::min(s.jointHertz, 0.25f / h), s.jointDampingRatio, h).biasRate;
}

void Solver::indexUnits() {
  units.clear();
  groups.clear();
  for (size_t i = 0; i < rows.size();) {
    if (rows[i].groupStart || groups.empty()) {
      if (!groups.empty()) groups.back().unitEnd = uint32_t(units.size());
      groups.push_back({uint32_t(units.size()), 0, rows[i].a, rows[i].b});
    }
    units.push_back(uint32_t(i));
    if (rows[i].kind == RowKind::Friction)
      i += 2;
    else if (rows[i].blockSize > 1)
      i += rows[i].blockSize;
    else
      i += 1;
  }
  if (!groups.empty()) groups.back().unitEnd = uint32_t(units.size());
  split.assign(bodies.size(), 0);
  for (const Group& g : groups) {
    split[size_t(g.a)] += 1;
    split[size_t(g.b)] += 1;
  }
  for (float& n : split) n = std::max(n, 1.0f);  // the world and free bodies split nothing

  // Jacobi gathers each dynamic body's changes from its groups, in group order.
  bodyRefStart.assign(bodies.size() + 1, 0);
  bodyRefs.clear();
  if (jacobi()) {
    for (const Group& g : groups) {
      if (bodies[size_t(g.a)].dynamic) bodyRefStart[size_t(g.a) + 1]++;
      if (bodies[size_t(g.b)].dynamic) bodyRefStart[size_t(g.b) + 1]++;
    }
    for (size_t i = 0; i < bodies.size(); ++i) bodyRefStart[i + 1] += bodyRefStart[i];
    bodyRefs.resize(bodyRefStart.back());
    std::vector<uint32_t> fill(bodyRefStart.begin(), bodyRefStart.end() - 1);
    for (uint32_t gi = 0; gi < groups.size(); ++gi) {
      const Group& g = groups[gi];
      if (bodies[size_t(g.a)].dynamic) bodyRefs[fill[size_t(g.a)]++] = gi << 1;
      if (bodies[size_t(g.b)].dynamic) bodyRefs[fill[size_t(g.b)]++] = gi << 1 | 1;
    }
  }
  assignColors();
}

void Solver::assignColors() {
  serialGroups.clear();
  colorGroups.clear();
  colorStart.clear();
  overflowBegin = 0;
  if (scheme != SolverSettings::Scheme::ColoredGaussSeidel) return;
  // Greedy, in group order (deterministic): each contact group takes the lowest color that
  // neither of its dynamic bodies has yet. Static and kinematic bodies do not count: the
  // solve never writes them.
  std::vector<uint64_t> used(bodies.size(), 0);
  std::vector<int8_t> color(groups.size(), -1);
  std::vector<uint32_t> count(kMaxColors + 1, 0), overflow;
  for (uint32_t gi = 0; gi < groups.size(); ++gi) {
    const Group& g = groups[gi];
    if (rows[units[g.unitBegin]].kind != RowKind::ContactNormal) {
      serialGroups.push_back(gi);  // a joint
      continue;
    }
    const bool da = bodies[size_t(g.a)].dynamic, db = bodies[size_t(g.b)].dynamic;
    const uint64_t taken = (da ? used[size_t(g.a)] : 0) | (db ? used[size_t(g.b)] : 0);
    if ((!da && !db) || taken == ~uint64_t(0)) {
      overflow.push_back(gi);
      continue;
    }
    const int c = std::countr_one(taken);
    color[gi] = int8_t(c);
    count[size_t(c) + 1]++;
    if (da) used[size_t(g.a)] |= uint64_t(1) << c;
    if (db) used[size_t(g.b)] |= uint64_t(1) << c;
  }
  int colors = kMaxColors;
  while (colors > 0 && count[size_t(colors)] == 0) --colors;
  colorStart.assign(count.begin(), count.begin() + colors + 1);
  for (int c = 0; c < colors; ++c) colorStart[size_t(c) + 1] += colorStart[size_t(c)];
  colorGroups.resize(colorStart.back());
  std::vector<uint32_t> fill(colorStart.begin(), colorStart.end());
  for (uint32_t gi = 0; gi < groups.size(); ++gi)
    if (color[gi] >= 0) colorGroups[fill[size_t(color[gi])]++] = gi;
  overflowBegin = serialGroups.size();
  serialGroups.insert(serialGroups.end(), overflow.begin(), overflow.end());
}

void Solver::positionPass(const SolverSettings& s, int iterations, bool jacobiPass) {
  // Nonlinear Gauss-Seidel / Jacobi on positions (Catto's NGS, the seed paper's NJ): each
  // row's error at the current poses (linearized from the accumulated deltas) is removed by a
  // fraction, as a displacement; velocities are not touched.
  auto correction = [&](const Row& r) -> float {
    float C = rowError(r);
    switch (r.kind) {
      case RowKind::ContactNormal:
      case RowKind::Limit: {
        float slop = r.kind == RowKind::ContactNormal ? s.linearSlop : 0;
        float c = std::clamp(s.positionBaumgarte * (C + slop), -s.maxPositionCorrection, 0.0f);
        return -r.effMass * c;
      }
      case RowKind::Equality:
        return -r.effMass * std::clamp(s.positionBaumgarte * C, -s.maxPositionCorrection,
                                       s.maxPositionCorrection);
      default:
        return 0;
    }
  };
  auto move = [](SolverBody& b, Vec3 dlin, Vec3 dang) {
    b.dp += dlin;
    b.dtheta += dang;
    b.q = integrateRotation(b.q, dang, 1);
  };
  dv_.assign(bodies.size(), Vec3{});
  dw_.assign(bodies.size(), Vec3{});
  for (int it = 0; it < iterations; ++it) {
    if (!jacobiPass) {
      for (const Row& r : rows) {
        float d = correction(r);
        if (d == 0) continue;
        move(bodies[size_t(r.a)], r.mLinA * d, r.mAngA * d);
        move(bodies[size_t(r.b)], r.mLinB * d, r.mAngB * d);
      }
      continue;
    }
    // Jacobi: every row from the same poses; each body moves by the average of its
    // constraints' displacements (with the Jacobi scheme the rows' M^-1 J^T carry the split).
    std::fill(dv_.begin(), dv_.end(), Vec3{});
    std::fill(dw_.begin(), dw_.end(), Vec3{});
    for (const Row& r : rows) {
      float d = correction(r);
      if (d == 0) continue;
      dv_[size_t(r.a)] += r.mLinA * d;
      dw_[size_t(r.a)] += r.mAngA * d;
      dv_[size_t(r.b)] += r.mLinB * d;
      dw_[size_t(r.b)] += r.mAngB * d;
    }
    for (size_t i = 1; i < bodies.size(); ++i) {
      if (dv_[i] == Vec3{} && dw_[i] == Vec3{}) continue;
      const float n = jacobi() ? split[i] : 1;
      move(bodies[i], dv_[i] / n, dw_[i] / n);
    }
  }
}

namespace {

/// Solves the n x n system M x = b (row-major, n <= 4) by Gaussian elimination with partial
/// pivoting; false if singular.
bool solveSmall(int n, float M[16], float b[4], float x[4]) {
  for (int c = 0; c < n; ++c) {
    int piv = c;
    for (int r = c + 1; r < n; ++r)
      if (std::abs(M[r * 4 + c]) > std::abs(M[piv * 4 + c])) piv = r;
    if (!(std::abs(M[piv * 4 + c]) > 1e-20f)) return false;
    if (piv != c) {
      for (int k = 0; k < n; ++k) std::swap(M[c * 4 + k], M[piv * 4 + k]);
      std::swap(b[c], b[piv]);
    }
    for (int r = c + 1; r < n; ++r) {
      float f = M[r * 4 + c] / M[c * 4 + c];
      for (int k = c; k < n; ++k) M[r * 4 + k] -= f * M[c * 4 + k];
      b[r] -= f * b[c];
    }
  }
  for (int r = n - 1; r >= 0; --r) {
    float v = b[r];
    for (int k = r + 1; k < n; ++k) v -= M[r * 4 + k] * x[k];
    x[r] = v / M[r * 4 + r];
  }
  return true;
}

}  // namespace

bool Solver::solveContactBlock(size_t first, const IterationParams& p, Velocity& A, Velocity& B,
                               float* change) {
  // The manifold's normal rows as one LCP (Box2D v2's block solver, generalized to 4 points
  // by enumerating active sets). The soft update of one row, d = -s m (v + b) - i lambda,
  // is the solution of (K + c K_ii) d = -(v + b) - c K_ii lambda with c = i / s (the
  // spring's compliance relative to the row's own mass); the block form keeps c K_ii on the
  // diagonal, which also keeps the 4 coplanar points of a face (rank 3) solvable, and has the
  // same fixed point as the row-by-row iteration: every iteration reaches it for the
  // manifold at once. Find x = lambda + d >= 0 with w = (K + cD) x + q >= 0, x . w = 0,
  // q = v + b - K lambda.
  const int n = rows[first].contactPoints;
  const std::array<float, 16>& K = contactK[size_t(rows[first].blockIndex)];
  const float c = p.contactSoft.impulseScale / p.contactSoft.massScale;
  float q[4], lambda[4];
  for (int k = 0; k < n; ++k) {
    const Row& r = rows[first + size_t(k)];
    const float C = rowError(r);
    if (C > 0) return false;  // speculative (apart): rigid, solved row by row
    const float bias = std::max(p.contactSoft.biasRate * C, -p.maxPushout);
    q[k] = rowVelocity(r, A, B) + bias;
    lambda[k] = r.lambda;
  }
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j) q[i] -= K[size_t(i * n + j)] * lambda[j];
  // Active sets from all points down to none; the first that is consistent wins.
  float x[4] = {0, 0, 0, 0};
  bool found = false;
  for (int mask = (1 << n) - 1; mask >= 0 && !found; --mask) {
    int idx[4], m = 0;
    for (int k = 0; k < n; ++k)
      if (mask & (1 << k)) idx[m++] = k;
    float M[16], rhs[4], xa[4] = {0, 0, 0, 0};
    for (int a = 0; a < m; ++a) {
      for (int b = 0; b < m; ++b) {
        float kab = K[size_t(idx[a] * n + idx[b])];
        M[a * 4 + b] = a == b ? kab * (1 + c) : kab;
      }
      rhs[a] = -q[idx[a]];
    }
    if (m > 0 && !solveSmall(m, M, rhs, xa)) continue;
    // Feasibility up to rounding: a point carrying no load (x and w both about 0, a box
    // rocking onto an edge) must not fail every active set.
    bool ok = true;
    float trial[4] = {0, 0, 0, 0};
    for (int a = 0; a < m; ++a) {
      const float scale = std::abs(q[idx[a]]) / K[size_t(idx[a] * n + idx[a])];
      ok &= xa[a] >= -1e-5f * scale;
      trial[idx[a]] = std::max(xa[a], 0.0f);
    }
    for (int i = 0; i < n && ok; ++i) {
      if (mask & (1 << i)) continue;
      float w = q[i];
      for (int j = 0; j < n; ++j) w += K[size_t(i * n + j)] * trial[j];
      ok &= w >= -1e-5f * std::abs(q[i]);
    }
    if (!ok) continue;
    std::copy(trial, trial + 4, x);
    found = true;
  }
  if (!found) return false;
  for (int k = 0; k < n; ++k) {
    Row& r = rows[first + size_t(k)];
    const float d = x[k] - r.lambda;
    r.lambda = x[k];
    r.maxLambda = std::max(r.maxLambda, x[k]);
    if (d == 0) continue;
    applyImpulse(r, d, A, B);
    if (p.measure && r.effMass > 0) *change = std::max(*change, std::abs(d) / r.effMass);
  }
  return true;
}

float Solver::frictionLoad(const Row& r) const {
  if (r.patchPoints == 0) return rows[size_t(r.parent)].lambda;
  float sum = 0;
  for (int k = 0; k < r.patchPoints; ++k) sum += rows[size_t(r.parent + k)].lambda;
  return sum;
}

float Solver::solveFrictionPair(Row& r1, Row& r2, Velocity& A, Velocity& B, bool measure) {
  // Both tangent directions at once, clamped to the friction disc |lambda_t| <= mu lambda_n:
  // isotropic Coulomb friction (clamping each axis alone would allow sqrt(2) mu diagonally).
  float l1 = r1.lambda - r1.effMass * rowVelocity(r1, A, B);
  float l2 = r2.lambda - r2.effMass * rowVelocity(r2, A, B);
  float bound = r1.mu * frictionLoad(r1);
  float len2 = l1 * l1 + l2 * l2;
  if (len2 > bound * bound) {
    float k = len2 > 0 ? bound / std::sqrt(len2) : 0;
    l1 *= k;
    l2 *= k;
  }
  float d1 = l1 - r1.lambda, d2 = l2 - r2.lambda;
  r1.lambda = l1;
  r2.lambda = l2;
  if (d1 != 0) applyImpulse(r1, d1, A, B);
  if (d2 != 0) applyImpulse(r2, d2, A, B);
  if (!measure) return 0;
  float change = 0;
  if (r1.effMass > 0) change = std::abs(d1) / r1.effMass;
  if (r2.effMass > 0) change = std::max(change, std::abs(d2) / r2.effMass);
  return change;
}

namespace {

/// Rotation by angle a about principal axis i (0, 1, 2).
Quat axisRotation(int i, float a) {
  Quat r;
  float s = std::sin(0.5f * a);
  r.w = std::cos(0.5f * a);
  (&r.x)[i] = s;
  return r;
}

/// Free rotation of a body over h by the symplectic splitting of Dullweber, Leimkuhler and
/// McLachlan (1997): exact rotations about the principal axes, 1(h/2) 2(h/2) 3(h) 2(h/2)
/// 1(h/2). World angular momentum is conserved exactly and the energy error stays bounded,
/// which is how the gyroscopic term (a T-handle flipping, a tumbling box) comes out right.
/// An explicit step gains energy; the implicit Newton step of SOLVER_NOTES loses half of a
/// tumbling box's energy in 60 s.
void rotateFree(SolverBody& b, float h) {
  Quat Q = b.q * b.principal;  // principal frame -> world
  const Vec3 I = b.principalMoments;
  // Principal components of L, from w through the same moments used to go back below, so
  // the round trip adds no bias.
  Vec3 L = mulComponents(I, invRotate(Q, b.w));
  const int axes[5] = {0, 1, 2, 1, 0};
  const float frac[5] = {0.5f, 0.5f, 1, 0.5f, 0.5f};
  const float L0 = length(L);
  for (int k = 0; k < 5; ++k) {
    int i = axes[k], j = (i + 1) % 3, m = (i + 2) % 3;
    float angle = frac[k] * h * L[i] / I[i];
    Q = Q * axisRotation(i, angle);
    // The body turns by +angle about axis i, so L's body components turn by -angle.
    float c = std::cos(angle), sn = std::sin(angle);
    float Lj = c * L[j] + sn * L[m], Lm = -sn * L[j] + c * L[m];
    L[j] = Lj;
    L[m] = Lm;
  }
  // The exact flow keeps |L|; restoring it removes the bias float rounding adds.
  float Ln = length(L);
  if (Ln > 0) L *= L0 / Ln;
  Q = normalize(Q);
  b.q = normalize(Q * conjugate(b.principal));
  b.w = rotate(Q, Vec3{L.x / I.x, L.y / I.y, L.z / I.z});
}

}  // namespace

Vec3 integratedTurn(Vec3 w, float h) {
  // q becomes (1 + (h/2) w) q normalized. Formed from the two quaternions' product instead,
  // it cost a product, a square root and an atan2 a body and substep, and the product's
  // rounding was some 1e-7 rad of a turn of 1e-4.
  const float k = 0.5f * h;
  const float u = k * k * lengthSquared(w);  // x^2, x = tan of half the turn
  // 2 atan(x) / x = 2 (1 - x^2/3 + x^4/5 - x^6/7 + ...): below x = 0.1 the next term,
  // x^8/9 < 1.2e-9, is under float rounding.
  if (u < 0.01f) return w * (2 * k * (1 - u * (1.0f / 3 - u * (1.0f / 5 - u * (1.0f / 7)))));
  const float x = std::sqrt(u);
  return w * (2 * k * std::atan(x) / x);
}

void Solver::markTrackedRotations(std::span<const SolverManifold> manifolds) {
  // dtheta is read by the rows' position error (C0 + J . deltas), the joints' rows rebuilt
  // each substep, the manifolds' wide blocks, the collision phase (its contacts are rows or
  // manifolds too), the position pass (rows) and the forces' work (the torque's): a body in
  // none of those is free, and its rotation vector would be computed for nobody.
  for (SolverBody& b : bodies) b.tracksRotation = b.torque != Vec3{};
  for (const Row& r : rows) bodies[size_t(r.a)].tracksRotation = bodies[size_t(r.b)].tracksRotation = true;
  for (const SolverManifold& m : manifolds)
    bodies[size_t(m.a)].tracksRotation = bodies[size_t(m.b)].tracksRotation = true;
}

void Solver::integratePositions(float h) {
  if (wide) wide->errorsCurrent = false;
  parallel(bodies.size(), kBodyGrain, [&](size_t begin, size_t end) {
    for (size_t i = std::max<size_t>(begin, 1); i < end; ++i) {
      SolverBody& b = bodies[i];
      // Warm starting by bodies: the impulses' change so far; a gyroscopic turn of w below
      // is not an impulse, so the base moves with it.
      if (warmTracked_) warmSum_[i] = {b.v - warmBase_[i].v, b.w - warmBase_[i].w};
      if (pushActive && (push[i].v != Vec3{} || push[i].w != Vec3{})) {
        // Pushed out this substep: the pseudo velocity moves the body, the velocity stays
        // (plain rotation here: a buried body's gyroscopic term is not what matters).
        b.dp += (b.v + push[i].v) * h;
        const Vec3 w = b.w + push[i].w;
        b.q = integrateRotation(b.q, w, h);
        if (b.tracksRotation) b.dtheta += integratedTurn(w, h);
      } else if (b.dynamic && b.gyroscopic) {
        b.dp += b.v * h;
        const Quat q0 = b.q;
        rotateFree(b, h);
        if (b.tracksRotation) b.dtheta += rotationVector(b.q * conjugate(q0));
      } else {
        b.dp += b.v * h;
        b.q = integrateRotation(b.q, b.w, h);
        if (b.tracksRotation) b.dtheta += integratedTurn(b.w, h);
      }
      if (warmTracked_) warmBase_[i] = b;
    }
  });
  pushActive = false;
}

void Solver::solvePushout(const SolverSettings& s, float h, int iterations, EqualityLdl* ldl) {
  push.assign(bodies.size(), Velocity{});
  pushActive = true;
  // Warm start from the last substep's push impulses (zero at the step's first substep).
  forEachGroup(
      [&](const Group& g, Velocity& A, Velocity& B) {
        size_t begin, end;
        groupRows(*this, g, &begin, &end);
        for (size_t i = begin; i < end; ++i)
          if (rows[i].pushLambda != 0) applyImpulse(rows[i], rows[i].pushLambda, A, B);
        return 0.0f;
      },
      /*pushChannel=*/true);
  IterationParams p;
  p.h = h;
  p.invH = 1 / h;
  p.contactSoft = makeSoftness(cappedHertz(s.contactHertz, p.invH), s.contactDampingRatio, h);
  p.maxPushout = s.maxPushout;
  p.skipEquality = ldl != nullptr;
  for (int it = 0; it < iterations; ++it) {
    forEachGroup([&](const Group& g, Velocity& A, Velocity& B) { return pushoutGroup(g, A, B, p); },
                 /*pushChannel=*/true);
    if (ldl) ldl->solvePush(*this);
  }
}

float Solver::pushoutGroup(const Group& g, Velocity& A, Velocity& B, const IterationParams& p) {
  // The soft contact's position bias, on the pseudo velocities alone (Catto's split
  // impulses with the soft step's spring): J v_push = -bias with a separate impulse >= 0.
  size_t begin, end;
  groupRows(*this, g, &begin, &end);
  for (size_t i = begin; i < end; ++i) {
    Row& r = rows[i];
    if (r.kind == RowKind::Equality && !p.skipEquality) {
      // The joint holds the push-out's pseudo velocities as it holds the real ones: rigid, no
      // bias (the velocity solve corrects the joint's own error), no warm start.
      const float impulse = -r.effMass * rowVelocity(r, A, B);
      if (impulse != 0) applyImpulse(r, impulse, A, B);
      continue;
    }
    if (r.kind != RowKind::ContactNormal) continue;
    const float C = rowError(r) + kSplitDepth;
    if (C >= 0 && r.pushLambda == 0) continue;
    float bias = 0, massScale = 1, impulseScale = 0;
    if (C < 0) {
      bias = std::max(p.contactSoft.biasRate * C, -p.maxPushout);
      massScale = p.contactSoft.massScale;
      impulseScale = p.contactSoft.impulseScale;
    }
    const float vn = rowVelocity(r, A, B);
    float impulse = -r.effMass * massScale * (vn + bias) - impulseScale * r.pushLambda;
    const float next = std::max(r.pushLambda + impulse, 0.0f);
    impulse = next - r.pushLambda;
    r.pushLambda = next;
    if (impulse != 0) applyImpulse(r, impulse, A, B);
  }
  return 0;
}

double Solver::velocityResidual(float h) const {
  double sum = 0;
  for (const Row& r : rows) {
    double e = 0;
    float vn = rowVelocity(r);
    switch (r.kind) {
      case RowKind::ContactNormal:
      case RowKind::Limit: {
        // Active rows should hold J v = 0; inactive ones only must not close past the gap.
        float gap = std::max(rowError(r), 0.0f) / h;
        e = r.lambda > 0 ? vn : std::min(0.0f, vn + gap);
        break;
      }
      case RowKind::Equality:
        e = vn;
        break;
      case RowKind::Friction:
      case RowKind::Twist:
        e = 0;  // sticking or sliding, friction has no target velocity of its own
        break;
      case RowKind::Motor:
      case RowKind::Spring:
        break;
    }
    sum += e * e;
  }
  // The contacts solved in wide blocks (after every row, as their rows would be).
  if (wide && wide->blockCount() > 0) sum = wide->residual(bodies, h, sum);
  return std::sqrt(sum);
}

}  // namespace phys
