// Restitution as a collision phase (issue 41). Before a substep's contact solve, each elastic
// contact that approaches faster than the restitution threshold and closes within the
// substep is resolved as a collision of its two bodies on the velocities of the moment: its
// impulses make each approaching point separate at e times its approach speed. The contacts
// are swept in order, again and again, until none approaches that fast (at most kMaxSweeps
// sweeps; what is left goes to the inelastic solve), so an impact travels through touching
// bodies as the sequence of pairwise collisions it is (Guendelman, Bridson and Fedkiw 2003):
// a row of equal balls struck at one end passes the striker's velocity from ball to ball and
// the last one leaves with it: in one sweep when the contacts come in the shock's order, in
// one sweep per ball against it.
//
// Energy: a collision of two bodies cannot make kinetic energy when e <= 1. With impulses
// lambda >= 0 that meet the targets exactly, dKE = sum_i lambda_i (vn_i + vn'_i) / 2 and
// vn'_i = -e vn_i. A contact of several points is solved together (a box landing flat
// bounces without spinning) by a few projected Gauss-Seidel passes, which may miss the
// targets slightly; its impulses are then scaled back until dKE is no more than the targets
// allow. (Against gravity the target is the one that scales the integrator's own energy by
// e^2, see collide(), which can be a little more kinetic energy than e u.) The phase records
// the velocity changes it made, and at the step's end World::Impl::limitRestitutionEnergy
// scales them back in any island whose energy would end above its energy at the step's
// start plus the work of its forces.
//
// Time of impact: inside a substep bodies move in straight lines at their velocities, so a
// point with gap C > 0 closing at speed u meets at tau = C / u into the substep. Its
// velocity change dv is then applied at tau, not at the substep's start: the bodies' positions
// are moved by -dv tau, so that integrating the new velocities over the whole substep puts
// them where the old ones for tau and the new ones for h - tau would. The bodies' clocks
// carry that time on: a body set moving at tau can only meet the next body at tau or later
// (its shifted position stands for that), so a row struck across a gap hands the impulse on
// at the moment of contact and every ball ends where it should, the striker touching the row.
// Without it a bounce would start up to a substep early, a gap of up to u h short of the
// surface (2 % of a restitution scene's rebound with 6 substeps, 7 % with one).
//
// Look-ahead: the relax pass after a substep's positions meets the next substep's gaps, and
// would stop a contact closing within the next substep as a rigid speculative contact (no
// bounce) before the next phase saw it approach. So the phase also runs just before the
// relax pass, on the velocities the next substep will start with (plus its acceleration,
// gravity: v + a h), for the contacts that close within the next substep; the energy it
// keeps is then that of those velocities.
#pragma once

#include <cstdint>
#include <vector>

#include "dynamics/solver.h"

namespace phys {

class Impacts {
 public:
  /// Sweeps at most per phase: a row of balls built against the shock needs one per ball.
  static constexpr int kMaxSweeps = 32;
  /// Projected Gauss-Seidel passes over a contact's approaching points (2-4 points).
  static constexpr int kManifoldPasses = 8;
  /// m: a point closes within the substep when its gap would end below this. A gap that
  /// closes exactly at the substep's end is met by the relax pass as a resting contact
  /// (rigid, no bounce): it must be taken here, rounding included.
  static constexpr float kCloseTolerance = 1e-4f;

  /// Before a step's contacts are added: no contacts, no collisions, no velocity changes.
  void clear();
  bool empty() const { return contacts_.empty(); }
  /// Appends an elastic contact (restitution > 0) between solver bodies a and b: its
  /// points (rA, rB from the bodies' centres of mass, separation: the gap at the step's
  /// start) along the normal from A to B, with the bodies' own masses (not the Jacobi
  /// scheme's split ones).
  void add(int32_t a, int32_t b, Vec3 normal, const Vec3* rA, const Vec3* rB,
           const float* separation, int count, float restitution,
           const std::vector<SolverBody>& bodies);
  /// The collision phase for a substep of length h: with `ahead`, for the next substep from
  /// the current positions and the velocities plus a h (see the file comment). Returns the
  /// collisions it resolved.
  int resolve(std::vector<SolverBody>& bodies, float h, float threshold, bool ahead);
  /// Collisions resolved since clear(), and per solver body the sum of the velocity
  /// changes they made (what World::Impl::limitRestitutionEnergy scales at the step's end).
  int collisions() const { return collisions_; }
  const std::vector<Velocity>& changes() const { return change_; }

  void release() noexcept;
  size_t capacityBytes() const;

 private:
  /// A point's normal row, J = (-n, angA, n, angB): what a sweep reads of every point.
  struct Point {
    Vec3 n, angA, angB;
    float C0;  ///< the gap at the step's start
  };
  /// A point's masses, read only when it collides: M^-1 J^T is (-n invMassA, angMassA,
  /// n invMassB, angMassB).
  struct Mass {
    Vec3 angMassA, angMassB;
    float invMassA, invMassB, effMass, restitution;
  };
  /// A contact: its two solver bodies, its points, and what rules most resting contacts
  /// out at once: the normal, and the longest lever arm of its points on each body (|angA|,
  /// |angB|), so that no point's normal velocity is below n . (vB - vA) - armA |wA| -
  /// armB |wB|.
  struct Contact {
    int32_t a = 0, b = 0;
    uint32_t first = 0, count = 0;
    Vec3 n;
    float armA = 0, armB = 0;
    float accel = 0;  ///< n . (aB - aA): the bodies' constant accelerations along the normal
  };
  /// Whether some point of contact c may approach faster than the threshold (the bound).
  bool mayApproach(const Contact& c, const std::vector<SolverBody>& bodies, float offset,
                   float threshold) const {
    const SolverBody& A = bodies[size_t(c.a)];
    const SolverBody& B = bodies[size_t(c.b)];
    const float bound = dot(c.n, B.v - A.v) + offset - c.armA * length(A.w) - c.armB * length(B.w);
    return bound < -threshold;
  }
  float velocity(const Contact& c, const Point& p, const std::vector<SolverBody>& bodies) const;
  float gap(const Contact& c, const Point& p, const std::vector<SolverBody>& bodies) const;
  /// Resolves contact k if any of its points approaches: true when it did.
  bool collide(size_t k, std::vector<SolverBody>& bodies, float h, float threshold, bool ahead);
  /// Applies an impulse at point i of contact c and records the velocity changes.
  void applyImpulse(const Contact& c, uint32_t i, float impulse, std::vector<SolverBody>& bodies);
  std::vector<Contact> contacts_;
  std::vector<Point> points_;
  std::vector<Mass> masses_;
  std::vector<float> clock_;      ///< per solver body: when its current velocity began
  std::vector<int32_t> clocked_;  ///< the bodies whose clock_ is not 0
  std::vector<Velocity> change_;  ///< per solver body: the velocity changes since clear()
  std::vector<uint32_t> stamp_;   ///< per solver body: the sweep that last changed it
  uint32_t sweep_ = 0;            ///< sweeps since clear()
  int collisions_ = 0;
};

}  // namespace phys
