#include "solver.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>

namespace phys {

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
  for (size_t i = first; i < last; ++i) {
    Row& r = rows[i];
    const SolverBody& A = bodies[size_t(r.a)];
    const SolverBody& B = bodies[size_t(r.b)];
    // Jacobi: each constraint sees a body with its mass divided among its constraints.
    const float sa = jacobi ? split[size_t(r.a)] : 1, sb = jacobi ? split[size_t(r.b)] : 1;
    r.mLinA = r.linA * (A.invMass * sa);
    r.mAngA = A.invI * r.angA * sa;
    r.mLinB = r.linB * (B.invMass * sb);
    r.mAngB = B.invI * r.angB * sb;
    float k =
        dot(r.linA, r.mLinA) + dot(r.angA, r.mAngA) + dot(r.linB, r.mLinB) + dot(r.angB, r.mAngB);
    r.effMass = k > 1e-12f ? 1 / k : 0;
  }
  // Block matrices K = J M^-1 J^T of joint row groups (after every row has its M^-1 J^T).
  for (size_t i = first; i < last; ++i) {
    Row& r = rows[i];
    if (r.blockSize < 2) continue;
    Mat3 K = Mat3::diagonal({1, 1, 1});
    for (int a = 0; a < r.blockSize; ++a) {
      for (int b = 0; b < r.blockSize; ++b) {
        const Row& ra = rows[i + size_t(a)];
        const Row& rb = rows[i + size_t(b)];
        float kab = dot(ra.linA, rb.mLinA) + dot(ra.angA, rb.mAngA) + dot(ra.linB, rb.mLinB) +
                    dot(ra.angB, rb.mAngB);
        (&K.c0)[b][a] = kab;
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

void Solver::solveBlock(size_t first, const Softness& soft, bool useBias) {
  const Row& r0 = rows[first];
  const int n = r0.blockSize;
  Vec3 err, lambda;
  for (int a = 0; a < n; ++a) {
    const Row& r = rows[first + size_t(a)];
    err[a] = rowVelocity(r) + (useBias ? soft.biasRate * rowError(r) : 0);
    lambda[a] = r.lambda;
  }
  const float massScale = useBias ? soft.massScale : 1;
  const float impulseScale = useBias ? soft.impulseScale : 0;
  Vec3 d = blockInvK[size_t(r0.blockIndex)] * err * -massScale - lambda * impulseScale;
  for (int a = 0; a < n; ++a) {
    Row& r = rows[first + size_t(a)];
    r.lambda += d[a];
    if (d[a] != 0) applyImpulse(r, d[a]);
  }
}

void Solver::integrateVelocities(float h, float maxLinearSpeed, float maxAngularSpeed) {
  for (size_t i = 1; i < bodies.size(); ++i) {
    SolverBody& b = bodies[i];
    if (!b.dynamic) continue;
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
}

template <class F>
void Solver::forEachGroupAveraged(F&& solveGroup) {
  dv_.assign(bodies.size(), Vec3{});
  dw_.assign(bodies.size(), Vec3{});
  for (const Group& g : groups) {
    SolverBody& A = bodies[size_t(g.a)];
    SolverBody& B = bodies[size_t(g.b)];
    const Vec3 va = A.v, wa = A.w, vb = B.v, wb = B.w;
    solveGroup(g);
    dv_[size_t(g.a)] += A.v - va;
    dw_[size_t(g.a)] += A.w - wa;
    A.v = va;
    A.w = wa;
    dv_[size_t(g.b)] += B.v - vb;
    dw_[size_t(g.b)] += B.w - wb;
    B.v = vb;
    B.w = wb;
  }
  // Summed in group order per body: deterministic whatever the thread count later.
  for (size_t i = 1; i < bodies.size(); ++i) {
    bodies[i].v += dv_[i] / split[i];
    bodies[i].w += dw_[i] / split[i];
  }
}

/// Rows [begin, end) of a group's units.
static inline void groupRows(const Solver& s, const Solver::Group& g, size_t* begin, size_t* end) {
  *begin = s.units[g.unitBegin];
  *end = g.unitEnd < s.units.size() ? s.units[g.unitEnd] : s.rows.size();
}

void Solver::warmStart() {
  if (jacobi) {
    forEachGroupAveraged([&](const Group& g) {
      size_t begin, end;
      groupRows(*this, g, &begin, &end);
      warmStartRows(begin, end);
    });
    return;
  }
  warmStartRows(0, rows.size());
}

void Solver::warmStartRows(size_t begin, size_t end) {
  for (size_t i = begin; i < end; ++i) {
    Row& r = rows[i];
    // The approach speed for restitution: the fastest seen at the start of any substep
    // (before impulses). While still apart (gap C > 0), the speed at the moment of contact
    // is extrapolated ballistically, vn^2 + 2 |a_n| C, with the bodies' constant
    // accelerations: otherwise the substep before impact, which brakes the body to land
    // exactly on the surface, hides up to one substep of gravity from the bounce.
    if (r.kind == RowKind::ContactNormal) {
      float vn = rowVelocity(r);
      float C = rowError(r);
      float an = dot(r.linA, bodies[size_t(r.a)].linearAccel) +
                 dot(r.linB, bodies[size_t(r.b)].linearAccel);
      if (vn < 0 && C > 0 && an < 0) vn = -std::sqrt(vn * vn - 2 * an * C);
      r.relativeVelocity = std::min(r.relativeVelocity, vn);
    }
    if (r.lambda != 0) applyImpulse(r, r.lambda);
  }
}

void Solver::solveIteration(const SolverSettings& s, float h, bool useBias, bool skipEquality) {
  const float invH = 1 / h;
  const bool soft = s.stabilization == SolverSettings::Stabilization::Soft;
  // Stiffness is capped at a quarter of the substep rate: stiffer springs are not resolved
  // by the integrator and only add energy.
  const float cap = 0.25f * invH;
  const Softness contactSoft =
      soft ? makeSoftness(std::min(s.contactHertz, cap), s.contactDampingRatio, h)
           : Softness{s.baumgarte * invH, 1, 0};
  const Softness jointSoft = soft
                                 ? makeSoftness(std::min(s.jointHertz, cap), s.jointDampingRatio, h)
                                 : Softness{s.baumgarte * invH, 1, 0};

  auto solveUnit = [&](size_t i) {
    Row& r = rows[i];
    if (skipEquality && r.kind == RowKind::Equality) return;
    if (r.kind == RowKind::Friction) {
      solveFrictionPair(r, rows[i + 1]);
      return;
    }
    if (r.blockSize > 1) {
      solveBlock(i, jointSoft, useBias);
      return;
    }
    float vn = rowVelocity(r);
    float impulse = 0;
    switch (r.kind) {
      case RowKind::ContactNormal:
      case RowKind::Limit: {
        float C = rowError(r);
        float bias = 0, massScale = 1, impulseScale = 0;
        if (C > 0) {
          bias = C * invH;  // speculative: close exactly the gap this substep, no more
        } else if (useBias) {
          // Slop only with Baumgarte: a soft contact's spring has zero rest length, and a
          // slop there only lets bodies sink into each other by that much.
          float slop = !soft && r.kind == RowKind::ContactNormal ? s.linearSlop : 0;
          float Cs = std::min(0.0f, C + slop);
          bias = std::max(contactSoft.biasRate * Cs, -s.maxPushout);
          massScale = contactSoft.massScale;
          impulseScale = contactSoft.impulseScale;
        }
        impulse = -r.effMass * massScale * (vn + bias) - impulseScale * r.lambda;
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
        if (useBias) {
          bias = jointSoft.biasRate * rowError(r);
          massScale = jointSoft.massScale;
          impulseScale = jointSoft.impulseScale;
        }
        impulse = -r.effMass * massScale * (vn + bias) - impulseScale * r.lambda;
        r.lambda += impulse;
        break;
      }
      case RowKind::Spring: {
        // A spring is soft in both passes: it is the physics, not an error correction.
        Softness sp = makeSoftness(r.hertz, r.dampingRatio, h);
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
    }
    if (impulse != 0) applyImpulse(r, impulse);
  };
  if (jacobi) {
    forEachGroupAveraged([&](const Group& g) {
      for (uint32_t u = g.unitBegin; u < g.unitEnd; ++u) solveUnit(units[u]);
    });
    return;
  }
  for (uint32_t u : units) solveUnit(u);
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
      const float n = jacobi ? split[i] : 1;
      move(bodies[i], dv_[i] / n, dw_[i] / n);
    }
  }
}

void Solver::solveFrictionPair(Row& r1, Row& r2) {
  // Both tangent directions at once, clamped to the friction disc |lambda_t| <= mu lambda_n:
  // isotropic Coulomb friction (clamping each axis alone would allow sqrt(2) mu diagonally).
  float l1 = r1.lambda - r1.effMass * rowVelocity(r1);
  float l2 = r2.lambda - r2.effMass * rowVelocity(r2);
  float bound = r1.mu * rows[size_t(r1.parent)].lambda;
  float len2 = l1 * l1 + l2 * l2;
  if (len2 > bound * bound) {
    float k = len2 > 0 ? bound / std::sqrt(len2) : 0;
    l1 *= k;
    l2 *= k;
  }
  float d1 = l1 - r1.lambda, d2 = l2 - r2.lambda;
  r1.lambda = l1;
  r2.lambda = l2;
  if (d1 != 0) applyImpulse(r1, d1);
  if (d2 != 0) applyImpulse(r2, d2);
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

void Solver::integratePositions(float h) {
  for (size_t i = 1; i < bodies.size(); ++i) {
    SolverBody& b = bodies[i];
    b.dp += b.v * h;
    Quat q0 = b.q;
    if (b.dynamic && b.gyroscopic) {
      rotateFree(b, h);
    } else {
      b.q = integrateRotation(b.q, b.w, h);
    }
    b.dtheta += rotationVector(b.q * conjugate(q0));
  }
}

void Solver::applyRestitution(float threshold) {
  if (jacobi) {
    forEachGroupAveraged([&](const Group& g) {
      size_t begin, end;
      groupRows(*this, g, &begin, &end);
      restitutionRows(begin, end, threshold);
    });
    return;
  }
  restitutionRows(0, rows.size(), threshold);
}

void Solver::restitutionRows(size_t begin, size_t end, float threshold) {
  for (size_t i = begin; i < end; ++i) {
    Row& r = rows[i];
    if (r.kind != RowKind::ContactNormal || r.restitution == 0) continue;
    if (r.relativeVelocity > -threshold || r.maxLambda == 0) continue;
    float vn = rowVelocity(r);
    float impulse = -r.effMass * (vn + r.restitution * r.relativeVelocity);
    float next = std::max(r.lambda + impulse, 0.0f);
    impulse = next - r.lambda;
    r.lambda = next;
    r.maxLambda = std::max(r.maxLambda, next);
    if (impulse != 0) applyImpulse(r, impulse);
  }
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
        e = 0;  // sticking or sliding, friction has no target velocity of its own
        break;
      case RowKind::Motor:
      case RowKind::Spring:
        break;
    }
    sum += e * e;
  }
  return std::sqrt(sum);
}

}  // namespace phys
