// The collision phase of restitution (impacts.h).
#include "dynamics/impacts.h"

#include <algorithm>
#include <cmath>

namespace phys {

namespace {

/// A body moved by dx and turned by the rotation vector dtheta (the solver's deltas kept).
void move(SolverBody& b, Vec3 dx, Vec3 dtheta) {
  b.dp += dx;
  if (dtheta == Vec3{}) return;
  const Quat q0 = b.q;
  b.q = integrateRotation(b.q, dtheta, 1);
  b.dtheta += rotationVector(b.q * conjugate(q0));
}

}  // namespace

void Impacts::add(int32_t a, int32_t b, Vec3 normal, const Vec3* rA, const Vec3* rB,
                  const float* separation, int count, float restitution,
                  const std::vector<SolverBody>& bodies) {
  if (count <= 0) return;
  const SolverBody& A = bodies[size_t(a)];
  const SolverBody& B = bodies[size_t(b)];
  Contact c;
  c.a = a;
  c.b = b;
  c.first = uint32_t(points_.size());
  c.count = uint32_t(count);
  c.n = normal;
  c.accel = dot(normal, B.linearAccel - A.linearAccel);
  for (int k = 0; k < count; ++k) {
    Point p;
    p.n = normal;
    p.angA = -cross(rA[k], normal);
    p.angB = cross(rB[k], normal);
    p.C0 = separation[k];
    Mass m;
    m.angMassA = A.invI * p.angA;
    m.angMassB = B.invI * p.angB;
    m.invMassA = A.invMass;
    m.invMassB = B.invMass;
    const float K = A.invMass + B.invMass + dot(p.angA, m.angMassA) + dot(p.angB, m.angMassB);
    m.effMass = K > 1e-12f ? 1 / K : 0;
    m.restitution = restitution;
    points_.push_back(p);
    masses_.push_back(m);
    c.armA = std::max(c.armA, length(p.angA));
    c.armB = std::max(c.armB, length(p.angB));
  }
  // Rounded up a little: the bound must not rule out a point that approaches.
  c.armA *= 1.0001f;
  c.armB *= 1.0001f;
  contacts_.push_back(c);
}

float Impacts::velocity(const Contact& c, const Point& p,
                        const std::vector<SolverBody>& bodies) const {
  const SolverBody& A = bodies[size_t(c.a)];
  const SolverBody& B = bodies[size_t(c.b)];
  return dot(p.n, B.v - A.v) + dot(p.angA, A.w) + dot(p.angB, B.w);
}

float Impacts::gap(const Contact& c, const Point& p, const std::vector<SolverBody>& bodies) const {
  const SolverBody& A = bodies[size_t(c.a)];
  const SolverBody& B = bodies[size_t(c.b)];
  return p.C0 + dot(p.n, B.dp - A.dp) + dot(p.angA, A.dtheta) + dot(p.angB, B.dtheta);
}

void Impacts::applyImpulse(const Contact& c, uint32_t i, float impulse,
                           std::vector<SolverBody>& bodies) {
  const Point& p = points_[i];
  const Mass& m = masses_[i];
  const Vec3 dvA = p.n * (-m.invMassA * impulse), dwA = m.angMassA * impulse;
  const Vec3 dvB = p.n * (m.invMassB * impulse), dwB = m.angMassB * impulse;
  bodies[size_t(c.a)].v += dvA;
  bodies[size_t(c.a)].w += dwA;
  bodies[size_t(c.b)].v += dvB;
  bodies[size_t(c.b)].w += dwB;
  change_[size_t(c.a)].v += dvA;
  change_[size_t(c.a)].w += dwA;
  change_[size_t(c.b)].v += dvB;
  change_[size_t(c.b)].w += dwB;
  stamp_[size_t(c.a)] = stamp_[size_t(c.b)] = sweep_;
}

bool Impacts::collide(size_t k, std::vector<SolverBody>& bodies, float h, float threshold,
                      bool ahead) {
  const Contact& c = contacts_[k];
  constexpr uint32_t kMax = 4;
  uint32_t active[kMax];
  float vn0[kMax], target[kMax], tau[kMax], lambda[kMax];
  // Ahead: the normal velocity the next substep starts with (its acceleration added). The
  // bodies accelerate towards each other along the normal at g (gravity against the ground).
  const SolverBody& A = bodies[size_t(c.a)];
  const SolverBody& B = bodies[size_t(c.b)];
  const float offset = ahead ? c.accel * h : 0.0f, g = std::max(0.0f, -c.accel);
  const Vec3 relative = B.v - A.v;
  int n = 0;
  for (uint32_t i = c.first; i < c.first + c.count && n < int(kMax); ++i) {
    // Most points of most contacts rest: the velocity alone rules them out.
    const Point& p = points_[i];
    const float vn = dot(p.n, relative) + dot(p.angA, A.w) + dot(p.angB, B.w) + offset;
    if (!(vn < -threshold)) continue;
    const Mass& m = masses_[i];
    if (!(m.effMass > 0)) continue;
    // Closing within the substep: faster than the threshold, and the gap ends below zero.
    const float C = gap(c, p, bodies);
    if (!(C + vn * h < kCloseTolerance)) continue;
    // When: not before either body's current velocity began (its clock), and then as soon
    // as the gap, which the clocks' position shifts keep, is closed.
    const float t0 = std::max(clock_[size_t(c.a)], clock_[size_t(c.b)]);
    const float left = C + vn * t0;
    const float u = -vn, t = std::min(left > 0 ? t0 + left / u : t0, h);
    // The separation speed: e u, but where the bodies accelerate towards each other (g > 0:
    // gravity against the ground) the one that makes the integrator's own energy
    // (v^2 / 2 + g x - g h v / 2, which its free flight keeps) come out e^2 times what it
    // was: with s = h / 2 - tau, v'^2 / 2 + g s v' = e^2 (u^2 / 2 - g s u). Otherwise a
    // bounce's height would be off by up to u h / 2 depending on when in the substep it
    // falls (2 % of the restitution scene's rebound with one substep).
    const float e = m.restitution, gs = g * (0.5f * h - t);
    active[n] = i;
    vn0[n] = vn;
    target[n] =
        g > 0 ? std::max(0.0f, std::sqrt(std::max(0.0f, gs * gs + e * e * u * (u - 2 * gs))) - gs)
              : e * u;
    tau[n] = t;
    lambda[n] = 0;
    ++n;
  }
  if (n == 0) return false;
  if (n == 1) {
    // One point: exactly to its target.
    lambda[0] = masses_[active[0]].effMass * (target[0] - vn0[0]);
    applyImpulse(c, active[0], lambda[0], bodies);
  } else {
    // Several points of one contact: their impulses together, projected Gauss-Seidel,
    // until a pass changes no impulse by more than a millionth of the largest.
    for (int pass = 0; pass < kManifoldPasses; ++pass) {
      float change = 0, largest = 0;
      for (int j = 0; j < n; ++j) {
        const uint32_t i = active[j];
        const float vn = velocity(c, points_[i], bodies) + offset;
        const float next = std::max(lambda[j] + masses_[i].effMass * (target[j] - vn), 0.0f);
        applyImpulse(c, i, next - lambda[j], bodies);
        change = std::max(change, std::fabs(next - lambda[j]));
        largest = std::max(largest, next);
        lambda[j] = next;
      }
      if (change <= 1e-6f * largest) break;
    }
    // dKE = lambda . (vn0 + vn1) / 2 exactly (the impulses' work). Met exactly, the targets
    // would give sum lambda_i (vn0_i + target_i) / 2: <= 0 but for the integrator's gravity
    // term above, G = sum lambda_i max(0, target_i - u_i) / 2. Scaled by a the energy change
    // is a P + a^2 Q / 2 with P = lambda . vn0 <= 0: the largest a <= 1 with no more than a G.
    double P = 0, Q = 0, G = 0;
    for (int j = 0; j < n; ++j) {
      P += double(lambda[j]) * vn0[j];
      Q += double(lambda[j]) * (velocity(c, points_[active[j]], bodies) + offset - vn0[j]);
      G += 0.5 * double(lambda[j]) * std::max(0.0f, target[j] + vn0[j]);
    }
    if (P + 0.5 * Q > G && Q > 0) {
      const float a = float(std::clamp(2 * (G - P) / Q, 0.0, 1.0));
      for (int j = 0; j < n; ++j) {
        applyImpulse(c, active[j], (a - 1) * lambda[j], bodies);
        lambda[j] *= a;
      }
    }
  }
  // At the time of impact: positions shifted (each point's impulse as if applied at its
  // tau: -lambda tau M^-1 J^T, summed over the points), clocks advanced.
  float latest = 0;
  Vec3 dxA, dthetaA, dxB, dthetaB;
  for (int j = 0; j < n; ++j) {
    const float s = -lambda[j] * tau[j];
    const Point& p = points_[active[j]];
    const Mass& m = masses_[active[j]];
    dxA += p.n * (-m.invMassA * s);
    dthetaA += m.angMassA * s;
    dxB += p.n * (m.invMassB * s);
    dthetaB += m.angMassB * s;
    latest = std::max(latest, tau[j]);
  }
  if (A.invMass > 0) move(bodies[size_t(c.a)], dxA, dthetaA);
  if (B.invMass > 0) move(bodies[size_t(c.b)], dxB, dthetaB);
  for (int32_t b : {c.a, c.b}) {
    if (b == 0 || !(bodies[size_t(b)].invMass > 0) || clock_[size_t(b)] >= latest) continue;
    if (clock_[size_t(b)] == 0) clocked_.push_back(b);
    clock_[size_t(b)] = latest;
  }
  return true;
}

void Impacts::clear() {
  contacts_.clear();
  points_.clear();
  masses_.clear();
  change_.clear();
  stamp_.clear();
  sweep_ = 0;
  collisions_ = 0;
}

int Impacts::resolve(std::vector<SolverBody>& bodies, float h, float threshold, bool ahead) {
  if (contacts_.empty()) return 0;
  if (clock_.size() < bodies.size()) clock_.resize(bodies.size(), 0.0f);
  if (change_.size() != bodies.size()) {
    change_.assign(bodies.size(), Velocity{});
    stamp_.assign(bodies.size(), 0);
  }
  int collisions = 0;
  for (int sweep = 0; sweep < kMaxSweeps; ++sweep) {
    // After the first sweep, only contacts whose bodies changed since the sweep before the
    // last (in it, after the contact, or in this one, before it): the others were seen not
    // to approach, and nothing about them changed since.
    ++sweep_;
    int now = 0;
    for (size_t k = 0; k < contacts_.size(); ++k) {
      const Contact& c = contacts_[k];
      if (sweep > 0 && stamp_[size_t(c.a)] + 1 < sweep_ && stamp_[size_t(c.b)] + 1 < sweep_)
        continue;
      // Most contacts rest: the bound on their points' normal velocities rules them out.
      if (!mayApproach(c, bodies, ahead ? c.accel * h : 0.0f, threshold)) continue;
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
  std::vector<Contact>().swap(contacts_);
  std::vector<Point>().swap(points_);
  std::vector<Mass>().swap(masses_);
  std::vector<float>().swap(clock_);
  std::vector<int32_t>().swap(clocked_);
  std::vector<Velocity>().swap(change_);
  std::vector<uint32_t>().swap(stamp_);
}

size_t Impacts::capacityBytes() const {
  return contacts_.capacity() * sizeof(Contact) + points_.capacity() * sizeof(Point) +
         masses_.capacity() * sizeof(Mass) + clock_.capacity() * sizeof(float) +
         clocked_.capacity() * sizeof(int32_t) + change_.capacity() * sizeof(Velocity) +
         stamp_.capacity() * sizeof(uint32_t);
}

}  // namespace phys
