// The collision phase of restitution (impacts.h).
#include "dynamics/impacts.h"

#include <algorithm>
#include <cmath>

namespace phys {

namespace {

float rowError(const Row& r, const std::vector<SolverBody>& bodies) {
  const SolverBody& A = bodies[size_t(r.a)];
  const SolverBody& B = bodies[size_t(r.b)];
  return r.C0 + dot(r.linA, A.dp) + dot(r.angA, A.dtheta) + dot(r.linB, B.dp) +
         dot(r.angB, B.dtheta);
}

float rowVelocity(const Row& r, const std::vector<SolverBody>& bodies) {
  return Solver::rowVelocity(r, bodies[size_t(r.a)], bodies[size_t(r.b)]);
}


/// A body moved by dx and turned by the rotation vector dtheta (the solver's deltas kept).
void move(SolverBody& b, Vec3 dx, Vec3 dtheta) {
  b.dp += dx;
  if (dtheta == Vec3{}) return;
  const Quat q0 = b.q;
  b.q = integrateRotation(b.q, dtheta, 1);
  b.dtheta += rotationVector(b.q * conjugate(q0));
}

}  // namespace

void Impacts::add(const SolverManifold& m, const std::vector<SolverBody>& bodies) {
  if (m.count == 0) return;
  if (start_.empty()) start_.push_back(0);
  const SolverBody& A = bodies[size_t(m.a)];
  const SolverBody& B = bodies[size_t(m.b)];
  for (int k = 0; k < m.count; ++k) {
    Row r = contactRow(m, RowKind::ContactNormal, m.normal, k);
    r.C0 = m.separation[k];
    r.restitution = m.restitution;
    r.mLinA = r.linA * A.invMass;
    r.mAngA = A.invI * r.angA;
    r.mLinB = r.linB * B.invMass;
    r.mAngB = B.invI * r.angB;
    const float K =
        dot(r.linA, r.mLinA) + dot(r.angA, r.mAngA) + dot(r.linB, r.mLinB) + dot(r.angB, r.mAngB);
    r.effMass = K > 1e-12f ? 1 / K : 0;
    rows_.push_back(r);
  }
  start_.push_back(uint32_t(rows_.size()));
}

void Impacts::applyImpulse(const Row& r, float impulse, std::vector<SolverBody>& bodies) {
  Solver::applyImpulse(r, impulse, bodies[size_t(r.a)], bodies[size_t(r.b)]);
  Solver::applyImpulse(r, impulse, change_[size_t(r.a)], change_[size_t(r.b)]);
  stamp_[size_t(r.a)] = stamp_[size_t(r.b)] = sweep_;
}

void Impacts::shift(const Row& r, float lambda, float tau, std::vector<SolverBody>& bodies) {
  const float s = -lambda * tau;
  if (s == 0) return;
  if (bodies[size_t(r.a)].invMass > 0) move(bodies[size_t(r.a)], r.mLinA * s, r.mAngA * s);
  if (bodies[size_t(r.b)].invMass > 0) move(bodies[size_t(r.b)], r.mLinB * s, r.mAngB * s);
}

bool Impacts::collide(size_t k, std::vector<SolverBody>& bodies, float h, float threshold,
                      bool ahead) {
  const uint32_t begin = start_[k], end = start_[k + 1];
  constexpr int kMax = 4;
  uint32_t active[kMax];
  float offset[kMax], vn0[kMax], target[kMax], tau[kMax], lambda[kMax];
  int n = 0;
  for (uint32_t i = begin; i < end && n < kMax; ++i) {
    const Row& r = rows_[i];
    if (!(r.effMass > 0)) continue;
    // Ahead: the normal velocity the next substep starts with (its acceleration added).
    const float off = ahead ? h * (dot(r.linA, bodies[size_t(r.a)].linearAccel) +
                                   dot(r.linB, bodies[size_t(r.b)].linearAccel))
                            : 0.0f;
    const float vn = rowVelocity(r, bodies) + off;
    if (!(vn < -threshold)) continue;
    // Closing within the substep: faster than the threshold, and the gap ends below zero.
    const float C = rowError(r, bodies);
    if (!(C + vn * h < kCloseTolerance)) continue;
    // When: not before either body's current velocity began (its clock), and then as soon
    // as the gap, which the clocks' position shifts keep, is closed.
    const float t0 = std::max(clock_[size_t(r.a)], clock_[size_t(r.b)]);
    const float gap = C + vn * t0;
    const float u = -vn, t = std::min(gap > 0 ? t0 + gap / u : t0, h);
    // The separation speed: e u, but where the bodies accelerate towards each other (g > 0:
    // gravity against the ground) the one that makes the integrator's own energy
    // (v^2 / 2 + g x - g h v / 2, which its free flight keeps) come out e^2 times what it
    // was: with s = h / 2 - tau, v'^2 / 2 + g s v' = e^2 (u^2 / 2 - g s u). Otherwise a
    // bounce's height would be off by up to u h / 2 depending on when in the substep it
    // falls (2 % of the restitution scene's rebound with one substep).
    const float g = std::max(0.0f, -(dot(r.linA, bodies[size_t(r.a)].linearAccel) +
                                     dot(r.linB, bodies[size_t(r.b)].linearAccel)));
    const float e = r.restitution, gs = g * (0.5f * h - t);
    active[n] = i;
    offset[n] = off;
    vn0[n] = vn;
    target[n] = g > 0 ? std::max(0.0f, std::sqrt(std::max(0.0f, gs * gs + e * e * u * (u - 2 * gs))) - gs)
                      : e * u;
    tau[n] = t;
    lambda[n] = 0;
    ++n;
  }
  if (n == 0) return false;
  if (n == 1) {
    // One point: exactly to its target.
    lambda[0] = rows_[active[0]].effMass * (target[0] - vn0[0]);
    applyImpulse(rows_[active[0]], lambda[0], bodies);
  } else {
    // Several points of one contact: their impulses together, projected Gauss-Seidel.
    for (int pass = 0; pass < kManifoldPasses; ++pass) {
      for (int j = 0; j < n; ++j) {
        const Row& r = rows_[active[j]];
        const float vn = rowVelocity(r, bodies) + offset[j];
        const float next = std::max(lambda[j] + r.effMass * (target[j] - vn), 0.0f);
        applyImpulse(r, next - lambda[j], bodies);
        lambda[j] = next;
      }
    }
    // dKE = lambda . (vn0 + vn1) / 2 exactly (the impulses' work). Met exactly, the targets
    // would give sum lambda_i (vn0_i + target_i) / 2: <= 0 but for the integrator's gravity
    // term above, G = sum lambda_i max(0, target_i - u_i) / 2. Scaled by a the energy change
    // is a P + a^2 Q / 2 with P = lambda . vn0 <= 0: the largest a <= 1 with no more than a G.
    double P = 0, Q = 0, G = 0;
    for (int j = 0; j < n; ++j) {
      P += double(lambda[j]) * vn0[j];
      Q += double(lambda[j]) * (rowVelocity(rows_[active[j]], bodies) + offset[j] - vn0[j]);
      G += 0.5 * double(lambda[j]) * std::max(0.0f, target[j] + vn0[j]);
    }
    if (P + 0.5 * Q > G && Q > 0) {
      const float a = float(std::clamp(2 * (G - P) / Q, 0.0, 1.0));
      for (int j = 0; j < n; ++j) {
        applyImpulse(rows_[active[j]], (a - 1) * lambda[j], bodies);
        lambda[j] *= a;
      }
    }
  }
  // At the time of impact: positions shifted, clocks advanced.
  float latest = 0;
  for (int j = 0; j < n; ++j) {
    shift(rows_[active[j]], lambda[j], tau[j], bodies);
    latest = std::max(latest, tau[j]);
  }
  const Row& r = rows_[active[0]];
  for (int32_t b : {r.a, r.b}) {
    if (b == 0 || !(bodies[size_t(b)].invMass > 0) || clock_[size_t(b)] >= latest) continue;
    if (clock_[size_t(b)] == 0) clocked_.push_back(b);
    clock_[size_t(b)] = latest;
  }
  return true;
}

void Impacts::clear() {
  rows_.clear();
  start_.clear();
  change_.clear();
  stamp_.clear();
  sweep_ = 0;
  collisions_ = 0;
}

int Impacts::resolve(std::vector<SolverBody>& bodies, float h, float threshold, bool ahead) {
  if (rows_.empty()) return 0;
  if (clock_.size() < bodies.size()) clock_.resize(bodies.size(), 0.0f);
  if (change_.size() != bodies.size()) {
    change_.assign(bodies.size(), Velocity{});
    stamp_.assign(bodies.size(), 0);
  }
  int collisions = 0;
  const size_t contacts = start_.size() - 1;
  for (int sweep = 0; sweep < kMaxSweeps; ++sweep) {
    // After the first sweep, only contacts whose bodies changed since the sweep before the
    // last (in it, after the contact, or in this one, before it): the others were seen not
    // to approach, and nothing about them changed since.
    ++sweep_;
    int now = 0;
    for (size_t k = 0; k < contacts; ++k) {
      const Row& r = rows_[start_[k]];
      if (sweep > 0 && stamp_[size_t(r.a)] + 1 < sweep_ && stamp_[size_t(r.b)] + 1 < sweep_)
        continue;
      now += collide(k, bodies, h, threshold, ahead);
    }
    collisions += now;
    if (now == 0) break;
  }
  for (int32_t b : clocked_) clock_[size_t(b)] = 0;
  clocked_.clear();
  collisions_ += collisions;
  return collisions;
}

void Impacts::release() noexcept {
  std::vector<Row>().swap(rows_);
  std::vector<uint32_t>().swap(start_);
  std::vector<float>().swap(clock_);
  std::vector<int32_t>().swap(clocked_);
  std::vector<Velocity>().swap(change_);
  std::vector<uint32_t>().swap(stamp_);
}

size_t Impacts::capacityBytes() const {
  return rows_.capacity() * sizeof(Row) + start_.capacity() * sizeof(uint32_t) +
         clock_.capacity() * sizeof(float) + clocked_.capacity() * sizeof(int32_t) +
         change_.capacity() * sizeof(Velocity) + stamp_.capacity() * sizeof(uint32_t);
}

}  // namespace phys
