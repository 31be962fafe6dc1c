#include "dynamics/stacks.h"

#include <algorithm>
#include <cmath>

namespace phys {

bool stackStands(std::span<const StackLevel> levels, double g, double omega) {
  // T = omega^2 K - G with K the springs between levels (level 0 on the ground) and G
  // gravity's diagonal; positive definite iff every LDL^T pivot is positive.
  const double w2 = omega * omega;
  const size_t n = levels.size();
  double above = 0;  // mass of the levels above the current one
  double pivot = 0;
  // From the top down, so that the mass above each level accumulates as we go.
  for (size_t k = 0; k < n; ++k) {
    const size_t d = n - 1 - k;
    above += levels[d].mass;
    const double springBelow = w2 * levels[d].bend;
    const double springAbove = d + 1 < n ? w2 * levels[d + 1].bend : 0;
    const double diag = springBelow + springAbove - g * levels[d].height * above;
    // The coupling with the level above is -springAbove.
    pivot = k == 0 ? diag : diag - springAbove * springAbove / pivot;
    if (!(pivot > 0)) return false;
  }
  return true;
}

double stackCriticalOmega(std::span<const StackLevel> levels, double g, double omegaMin,
                          double omegaMax) {
  if (stackStands(levels, g, omegaMin)) return 0;
  if (!stackStands(levels, g, omegaMax)) return 2 * omegaMax;
  double lo = omegaMin, hi = omegaMax;
  while (hi - lo > 1e-3 * hi) {
    const double mid = 0.5 * (lo + hi);
    (stackStands(levels, g, mid) ? hi : lo) = mid;
  }
  return hi;
}

// ---------------------------------------------------------------------------------------------
// The world's stacks, measured from this step's contacts.

StackMeasure StackScratch::measureStacks(const StackInput& in, float dt, const SolverSettings& s) {
  StackMeasure out;
  const float g = length(in.gravity);
  if (!(g > 0)) return out;
  const Vec3 down = in.gravity / g;
  // Horizontal axes, for the spread of the points each level stands on.
  const Vec3 e1 =
      normalize(std::abs(down.x) < 0.9f ? cross(down, Vec3{1, 0, 0}) : cross(down, Vec3{0, 1, 0}));
  const Vec3 e2 = cross(down, e1);

  // Support contacts: touching, with a normal within 45 degrees of gravity; linked per body
  // (stackHead / stackNext over 2 * contact + end). Static and kinematic bodies are depth 0.
  const std::span<const Contact> contacts = in.contacts;
  const size_t nb = in.bodies.size();
  stackDepth.assign(nb, -1);
  stackHead.assign(nb, -1);
  stackNext.assign(2 * contacts.size(), -1);
  stackSupport.assign(contacts.size(), 0);
  stackRise.assign(nb, 0.0f);
  stackQueue.clear();
  for (size_t ci = 0; ci < contacts.size(); ++ci) {
    const Contact& c = contacts[ci];
    const Manifold& m = c.manifold;
    if (m.count == 0 || std::abs(dot(m.normal, down)) < 0.7071f) continue;
    float sep = m.points[0].separation;
    for (int k = 1; k < m.count; ++k) sep = std::min(sep, m.points[k].separation);
    if (sep > 0.5f * in.speculativeDistance) continue;
    stackSupport[ci] = 1;
    const uint32_t ends[2] = {c.bodyA.index, c.bodyB.index};
    for (int e = 0; e < 2; ++e) {
      stackNext[2 * ci + size_t(e)] = stackHead[ends[e]];
      stackHead[ends[e]] = int32_t(2 * ci + size_t(e));
      if (!in.bodies[ends[e]].dynamic && stackDepth[ends[e]] < 0) {
        stackDepth[ends[e]] = 0;
        stackQueue.push_back(int32_t(ends[e]));
      }
    }
  }
  // Breadth first from the supports: a body's depth is its shortest support chain; its rise
  // is its centre's height above the body it was reached from (twice above the contact, for
  // the first level). Stacks are the bodies joined by support contacts: union-find over them
  // (stackRoot), depth 0 excluded.
  stackRoot.assign(nb, -1);
  auto root = [&](int32_t i) {
    while (stackRoot[size_t(i)] != i)
      i = stackRoot[size_t(i)] = stackRoot[size_t(stackRoot[size_t(i)])];
    return i;
  };
  for (size_t q = 0; q < stackQueue.size(); ++q) {
    const uint32_t i = uint32_t(stackQueue[q]);
    const StackBody& bi = in.bodies[i];
    for (int32_t e = stackHead[i]; e >= 0; e = stackNext[size_t(e)]) {
      const Contact& c = contacts[size_t(e) / 2];
      const uint32_t j = (e & 1) ? c.bodyA.index : c.bodyB.index;
      const StackBody& bj = in.bodies[j];
      if (!bj.dynamic) continue;
      if (stackDepth[j] < 0) {
        Vec3 below = bi.com;
        float scale = 1;
        if (!bi.dynamic) {
          below = {};
          for (int k = 0; k < c.manifold.count; ++k) below += c.manifold.points[k].point;
          below = below / float(c.manifold.count);
          scale = 2;
        }
        stackDepth[j] = stackDepth[i] + 1;
        stackRise[j] = scale * std::abs(dot(bj.com - below, down));
        stackRoot[j] = int32_t(j);
        stackQueue.push_back(int32_t(j));
      }
      if (stackDepth[i] > 0) {  // both dynamic: one stack
        const int32_t a = root(int32_t(i)), b = root(int32_t(j));
        if (a != b) stackRoot[size_t(std::max(a, b))] = std::min(a, b);
      }
    }
  }
  // Levels: stack by stack (in order of their lowest body index), bottom first.
  stackIndex.assign(nb, -1);
  stackFirstLevel.clear();
  stackLevels.clear();
  for (uint32_t i = 0; i < nb; ++i) {
    if (stackDepth[i] <= 0 || root(int32_t(i)) != int32_t(i)) continue;
    stackIndex[i] = int32_t(stackFirstLevel.size());
    stackFirstLevel.push_back(0);
  }
  stackDeepest.assign(stackFirstLevel.size(), 0);
  for (uint32_t i = 0; i < nb; ++i)
    if (stackDepth[i] > 0) {
      int32_t& d = stackDeepest[size_t(stackIndex[size_t(root(int32_t(i)))])];
      d = std::max(d, stackDepth[i]);
      out.depth = std::max(out.depth, stackDepth[i]);
    }
  int32_t total = 0;
  for (size_t k = 0; k < stackFirstLevel.size(); ++k) {
    stackFirstLevel[k] = total;
    total += stackDeepest[k];
  }
  stackFirstLevel.push_back(total);
  stackLevels.assign(size_t(total), LevelSums{});
  auto level = [&](uint32_t body) -> LevelSums& {
    const int32_t stack = stackIndex[size_t(root(int32_t(body)))];
    return stackLevels[size_t(stackFirstLevel[size_t(stack)] + stackDepth[body] - 1)];
  };
  for (uint32_t i = 0; i < nb; ++i)
    if (stackDepth[i] > 0) {
      LevelSums& l = level(i);
      l.mass += in.bodies[i].mass;
      l.rise += stackRise[i];
      l.bodies += 1;
    }
  // The points each level stands on: support contacts from one level down. A soft contact's
  // stiffness is m_eff omega^2; m_eff is taken as a cube corner's, a quarter of the bodies'
  // reduced mass (exact for the pyramids' and columns' cubes).
  for (size_t ci = 0; ci < contacts.size(); ++ci) {
    if (!stackSupport[ci]) continue;
    const Contact& c = contacts[ci];
    const uint32_t a = c.bodyA.index, b = c.bodyB.index;
    if (stackDepth[a] < 0 || stackDepth[b] < 0 || std::abs(stackDepth[a] - stackDepth[b]) != 1)
      continue;
    const uint32_t upper = stackDepth[a] > stackDepth[b] ? a : b;
    const float invMass = in.bodies[a].invMass + in.bodies[b].invMass;
    if (!(invMass > 0)) continue;
    const double w = 0.25 / invMass;
    LevelSums& l = level(upper);
    for (int k = 0; k < c.manifold.count; ++k) {
      const double x = dot(c.manifold.points[k].point, e1), y = dot(c.manifold.points[k].point, e2);
      l.w += w;
      l.wx += w * x;
      l.wy += w * y;
      l.wxx += w * x * x;
      l.wxy += w * x * y;
      l.wyy += w * y * y;
    }
  }
  // Stacks standing on a contact that the direct solve takes (direct contacts: its rows are
  // rigid there, whatever the contact frequency) are not the soft stacks this model is of: a
  // light body under a heavy one asks for a stiffness it already has (a pile of ragdolls,
  // held exactly, asked for 117 Hz and 8 substeps against none with every contact iterated;
  // docs/ARCHITECTURE.md, "Direct contacts on jointed bodies").
  stackOnDirect.assign(stackFirstLevel.size(), 0);
  if (s.directContactRatio > 0) {
    directContactsByBody(in, s);
    for (size_t ci = 0; ci < contacts.size(); ++ci) {
      if (!stackSupport[ci] || !stackDirectContact[ci]) continue;
      const Contact& c = contacts[ci];
      for (uint32_t b : {c.bodyA.index, c.bodyB.index})
        if (stackDepth[b] > 0) stackOnDirect[size_t(stackIndex[size_t(root(int32_t(b)))])] = 1;
    }
  }
  // Each stack's critical frequency; the step takes the largest, kStackMargin times over,
  // unless the preset's contacts are that much stiffer already.
  const double margin = SolverSettings::kStackMargin;
  const double omega0 = 2 * kPi * std::min(s.contactHertz, 0.25f * float(s.substeps) / dt);
  // Beyond kStackMaxFactor times the preset's frequency a stack is taken as one that no
  // stiffness should hold: a level on nearly collinear points (a capsule lying on two
  // others asked for 535 Hz in the default scene) tips over anyway.
  const double omegaMax = std::min(double(SolverSettings::kStackMaxFactor) * omega0,
                                   2 * kPi * 0.25 * 64 / dt);  // a quarter of the most substeps
  double need = 0;
  for (size_t k = 0; k + 1 < stackFirstLevel.size(); ++k) {
    if (stackOnDirect[k]) continue;
    stackModel.clear();
    bool degenerate = false;
    for (int32_t d = stackFirstLevel[k]; d < stackFirstLevel[k + 1]; ++d) {
      const LevelSums& l = stackLevels[size_t(d)];
      StackLevel m;
      m.mass = l.mass;
      m.height = l.bodies ? l.rise / l.bodies : 0;
      if (l.w > 0) {
        // The centred second moments; the softer principal axis.
        const double xx = l.wxx - l.wx * l.wx / l.w, yy = l.wyy - l.wy * l.wy / l.w;
        const double xy = l.wxy - l.wx * l.wy / l.w;
        m.bend = std::max(0.0, 0.5 * (xx + yy) - std::sqrt(0.25 * (xx - yy) * (xx - yy) + xy * xy));
      }
      // A level whose points spread less than kStackMinSpread of its height across (a box
      // on another's edge, a capsule on two others) tips over whatever the stiffness.
      const double spread = SolverSettings::kStackMinSpread * m.height;
      if (!(m.bend > l.w * spread * spread)) degenerate = true;
      stackModel.push_back(m);
    }
    if (degenerate) continue;
    const double omega = stackCriticalOmega(stackModel, g, omega0 / margin, omegaMax);
    if (omega <= omegaMax) need = std::max(need, omega);  // else no stiffness holds it
  }
  if (need > 0) out.hertz = float(margin * need / (2 * kPi));
  return out;
}

void StackScratch::directContactsByBody(const StackInput& in, const SolverSettings& s) {
  // World::Impl::findDirectContactIslands's rule (step.cpp), over body indices: islands of
  // touching dynamic bodies (joined by joints too where the LDL hybrid solves them, else
  // without the jointed bodies) that hold a touching pair directContactRatio apart and at
  // most kDirectContactMaxRows touching points. (The direct solve also leaves out, step by
  // step, islands with an impact; a stack on one is stiffened again next time if it stays.)
  const std::span<const Contact> contacts = in.contacts;
  stackDirectContact.assign(contacts.size(), 0);
  if (!(s.directContactRatio > 0) || s.scheme == SolverSettings::Scheme::Jacobi) return;
  const size_t nb = in.bodies.size();
  auto dynamic = [&](uint32_t i) {
    const StackBody& b = in.bodies[i];
    return b.dynamic && !b.asleep;
  };
  const bool jointsExact = s.equalitySolve == SolverSettings::EqualitySolve::DirectLdl;
  DisjointSets& sets = directSets;
  sets.reset(nb);
  auto root = [&](int32_t i) { return sets.root(i); };
  auto join = [&](int32_t a, int32_t b) { sets.join(a, b); };
  std::vector<uint8_t>& jointed = directJointed;
  jointed.assign(nb, 0);
  for (uint32_t i = 0; i < in.joints.capacity(); ++i) {
    if (!in.joints.alive(i)) continue;
    const JointDef& d = in.joints.at(i).def;
    const bool a = !d.bodyA.isNull() && dynamic(d.bodyA.index), b = dynamic(d.bodyB.index);
    if (a) jointed[d.bodyA.index] = 1;
    if (b) jointed[d.bodyB.index] = 1;
    if (jointsExact && a && b) join(int32_t(d.bodyA.index), int32_t(d.bodyB.index));
  }
  auto excluded = [&](uint32_t i) { return !jointsExact && jointed[i]; };
  std::vector<int32_t>& rows = directRows;  // per root: touching points, -1: no heavy pair
  rows.assign(nb, -1);
  std::vector<int32_t>& heavy = directHeavy;  // a body of each heavy pair
  heavy.clear();
  for (const Contact& c : contacts) {
    if (c.manifold.count == 0) continue;
    const uint32_t a = c.bodyA.index, b = c.bodyB.index;
    if (!dynamic(a) || !dynamic(b) || excluded(a) || excluded(b)) continue;
    join(int32_t(a), int32_t(b));
    const float ma = in.bodies[a].mass, mb = in.bodies[b].mass;
    if (std::max(ma, mb) >= s.directContactRatio * std::min(ma, mb)) heavy.push_back(int32_t(a));
  }
  for (int32_t a : heavy) rows[size_t(root(a))] = 0;
  auto islandOf = [&](const Contact& c) -> int32_t {
    const uint32_t a = c.bodyA.index, b = c.bodyB.index;
    const bool da = dynamic(a), db = dynamic(b);
    if ((!da && !db) || (da && excluded(a)) || (db && excluded(b))) return -1;
    return root(int32_t(da ? a : b));
  };
  for (const Contact& c : contacts) {
    if (c.manifold.count == 0) continue;
    const int32_t r = islandOf(c);
    if (r < 0 || rows[size_t(r)] < 0) continue;
    for (int p = 0; p < c.manifold.count; ++p)
      rows[size_t(r)] += c.manifold.points[p].separation <= SolverSettings::kDirectContactGap;
  }
  for (size_t ci = 0; ci < contacts.size(); ++ci) {
    if (contacts[ci].manifold.count == 0) continue;
    const int32_t r = islandOf(contacts[ci]);
    stackDirectContact[ci] = r >= 0 && rows[size_t(r)] > 0 &&
                             rows[size_t(r)] <= SolverSettings::kDirectContactMaxRows;
  }
}

}  // namespace phys
