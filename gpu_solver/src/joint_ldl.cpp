#include "joint_ldl.h"

#include <Eigen/OrderingMethods>
#include <Eigen/SparseCore>
#include <algorithm>
#include <map>
#include <numeric>

namespace phys::gpu {

uint32_t equalityRowCount(const GpuJoint& j) {
  switch (j.type) {
    case PHYS_GPU_JOINT_BALL:
      return 3;
    case PHYS_GPU_JOINT_HINGE:
      return 5;
    case PHYS_GPU_JOINT_FIXED:
      return 6;
    case PHYS_GPU_JOINT_PRISMATIC:
      return 5;
    case PHYS_GPU_JOINT_DISTANCE:
      return j.spring.y != 0 ? 1 : 0;
    default:
      return 0;
  }
}

namespace {

/// A union-find over bodies: the joints' islands.
struct Islands {
  std::vector<uint32_t> parent;
  explicit Islands(size_t n) : parent(n) { std::iota(parent.begin(), parent.end(), 0u); }
  uint32_t find(uint32_t x) {
    while (parent[x] != x) x = parent[x] = parent[parent[x]];
    return x;
  }
  void join(uint32_t a, uint32_t b) {
    a = find(a);
    b = find(b);
    if (a != b) parent[std::max(a, b)] = std::min(a, b);
  }
};

/// Whether body b (a GpuWorld index; -1: the world or a static body) takes impulses: only
/// dynamic bodies couple rows and join islands.
bool dynamic(std::span<const GpuBodyParams> params, int b) {
  return b >= 0 && size_t(b) < params.size() &&
         (params[size_t(b)].flags.x & PHYS_GPU_BODY_DYNAMIC) != 0;
}

struct RowRef {
  uint32_t joint, row;
};

/// Davis' symbolic LDL in a given order: row k of L is the set of nodes reached from
/// above[k] (A's entries (i, k), i < k) walking up the elimination tree; a node without a
/// parent yet gets k as its parent. Each row's pattern comes out ascending.
void symbolic(const std::vector<std::vector<int>>& above, std::vector<std::vector<int>>& rowPattern,
              std::vector<int>& parent) {
  const size_t N = above.size();
  parent.assign(N, -1);
  rowPattern.assign(N, {});
  std::vector<int> flag(N, -1);
  for (int k = 0; k < int(N); ++k) {
    flag[size_t(k)] = k;
    for (int i : above[size_t(k)]) {
      for (int j = i; flag[size_t(j)] != k; j = parent[size_t(j)]) {
        if (parent[size_t(j)] == -1) parent[size_t(j)] = k;
        rowPattern[size_t(k)].push_back(j);
        flag[size_t(j)] = k;
      }
    }
    std::sort(rowPattern[size_t(k)].begin(), rowPattern[size_t(k)].end());
  }
}

/// One island's rows: ordered, and L's pattern appended to the plan.
void planIsland(const std::vector<RowRef>& refs, std::span<const GpuJoint> joints,
                std::span<const GpuBodyParams> params, JointLdlPlan& plan) {
  const int n = int(refs.size());
  const size_t N = refs.size();
  // Rows couple through the dynamic bodies they share: every pair of rows on one body.
  std::vector<std::pair<int, int>> onBody;  // (body, row)
  for (int r = 0; r < n; ++r) {
    const GpuJoint& j = joints[refs[size_t(r)].joint];
    if (dynamic(params, j.bodyA)) onBody.push_back({j.bodyA, r});
    if (dynamic(params, j.bodyB) && j.bodyB != j.bodyA) onBody.push_back({j.bodyB, r});
  }
  std::sort(onBody.begin(), onBody.end());
  std::vector<Eigen::Triplet<double>> entries;
  for (size_t a = 0; a < onBody.size();) {
    size_t b = a;
    while (b < onBody.size() && onBody[b].first == onBody[a].first) ++b;
    for (size_t i = a; i < b; ++i)
      for (size_t k = a; k < b; ++k) entries.emplace_back(onBody[i].second, onBody[k].second, 1.0);
    a = b;
  }
  Eigen::SparseMatrix<double> A(n, n);
  A.setFromTriplets(entries.begin(), entries.end());  // duplicates add: only the pattern counts

  // Fill-reducing order (what Eigen's SimplicialLDLT uses on the CPU): order[new] = old.
  Eigen::PermutationMatrix<Eigen::Dynamic, Eigen::Dynamic, int> perm;
  Eigen::AMDOrdering<int> amd;
  amd(A, perm);
  std::vector<int> order(N), position(N);
  for (int i = 0; i < n; ++i) order[size_t(i)] = perm.indices()[i];

  // Upper pattern of A permuted by `order`, by column: above[k] = {i < k : A(i, k) != 0}.
  auto upper = [&](const std::vector<int>& order) {
    for (int i = 0; i < n; ++i) position[size_t(order[size_t(i)])] = i;
    std::vector<std::vector<int>> above(N);
    for (int c = 0; c < A.outerSize(); ++c)
      for (Eigen::SparseMatrix<double>::InnerIterator it(A, c); it; ++it) {
        const int i = position[size_t(it.row())], k = position[size_t(c)];
        if (i < k) above[size_t(k)].push_back(i);
      }
    return above;
  };
  std::vector<std::vector<int>> rowPattern;
  std::vector<int> parent;
  symbolic(upper(order), rowPattern, parent);

  // Levels of AMD's elimination tree: a leaf's is 0, a parent's one more than its highest
  // child's (children come before their parent, so one pass upwards does it). Rows stably
  // sorted by level are still an order in which children come before parents, which gives
  // the same fill; a level's columns then depend only on lower levels' and are contiguous.
  std::vector<int> level(N, 0);
  for (int k = 0; k < n; ++k)
    if (parent[size_t(k)] >= 0)
      level[size_t(parent[size_t(k)])] =
          std::max(level[size_t(parent[size_t(k)])], level[size_t(k)] + 1);
  std::vector<int> byLevel(N);
  std::iota(byLevel.begin(), byLevel.end(), 0);
  std::stable_sort(byLevel.begin(), byLevel.end(),
                   [&](int a, int b) { return level[size_t(a)] < level[size_t(b)]; });
  std::vector<int> levelOrder(N);
  for (size_t m = 0; m < N; ++m) levelOrder[m] = order[size_t(byLevel[m])];
  std::vector<int> rowLevel(N);
  for (size_t m = 0; m < N; ++m) rowLevel[m] = level[size_t(byLevel[m])];
  order.swap(levelOrder);
  symbolic(upper(order), rowPattern, parent);
  std::vector<int> count(N, 0);
  for (int k = 0; k < n; ++k)
    for (int j : rowPattern[size_t(k)]) ++count[size_t(j)];

  const uint32_t first = uint32_t(plan.rows.size());
  const uint32_t base = uint32_t(plan.columnRows.size());
  GpuLdlIsland island{};
  island.firstRow = first;
  island.rows = uint32_t(n);
  island.firstLevel = uint32_t(plan.levels.size() / 2);
  for (int k = 0; k < n;) {
    int end = k;
    while (end < n && rowLevel[size_t(end)] == rowLevel[size_t(k)]) ++end;
    plan.levels.push_back(first + uint32_t(k));
    plan.levels.push_back(first + uint32_t(end));
    k = end;
  }
  island.levels = uint32_t(plan.levels.size() / 2) - island.firstLevel;
  std::vector<uint32_t> columnBegin(N), filled(N, 0);
  uint32_t at = base;
  for (int k = 0; k < n; ++k) {
    columnBegin[size_t(k)] = at;
    at += uint32_t(count[size_t(k)]);
  }
  plan.columnRows.resize(at);
  plan.entryColumns.resize(at);
  for (int k = 0; k < n; ++k) {
    GpuLdlRow row{};
    const RowRef& ref = refs[size_t(order[size_t(k)])];
    row.joint = ref.joint;
    row.row = ref.row;
    row.patternBegin = uint32_t(plan.pattern.size() / 2);
    for (int j : rowPattern[size_t(k)]) {
      // Column j's entries go in row order: L(k, j) is its next one.
      const uint32_t index = columnBegin[size_t(j)] + filled[size_t(j)]++;
      plan.columnRows[index] = first + uint32_t(k);
      plan.entryColumns[index] = first + uint32_t(j);
      plan.pattern.push_back(first + uint32_t(j));
      plan.pattern.push_back(index);
    }
    row.patternEnd = uint32_t(plan.pattern.size() / 2);
    row.columnBegin = columnBegin[size_t(k)];
    row.columnEnd = columnBegin[size_t(k)] + uint32_t(count[size_t(k)]);
    plan.rows.push_back(row);
  }

  // Each dynamic body's rows, ascending (the order the one-thread solve applied them in), the
  // bodies by index.
  std::map<int, std::vector<uint32_t>> rowsOf;
  for (int k = 0; k < n; ++k) {
    const GpuJoint& j = joints[refs[size_t(order[size_t(k)])].joint];
    if (dynamic(params, j.bodyA)) rowsOf[j.bodyA].push_back(first + uint32_t(k));
    if (dynamic(params, j.bodyB) && j.bodyB != j.bodyA)
      rowsOf[j.bodyB].push_back(first + uint32_t(k));
  }
  island.firstBody = uint32_t(plan.bodies.size());
  for (const auto& [body, rows] : rowsOf) {
    const uint32_t begin = uint32_t(plan.bodyRows.size());
    plan.bodyRows.insert(plan.bodyRows.end(), rows.begin(), rows.end());
    plan.bodies.push_back({uint32_t(body), begin, uint32_t(plan.bodyRows.size()), 0});
  }
  island.bodies = uint32_t(plan.bodies.size()) - island.firstBody;
  plan.islands.push_back(island);
}

}  // namespace

JointLdlPlan planJointLdl(std::span<const GpuJoint> joints, std::span<const GpuBodyParams> params) {
  JointLdlPlan plan;
  // Joints with equality rows and a dynamic body, joined into islands through their
  // dynamic bodies (a static or kinematic body joins nothing: it takes no impulse).
  Islands bodies(params.size());
  std::vector<int> anchor(joints.size(), -1);  // a dynamic body of each joint in the solve
  for (size_t j = 0; j < joints.size(); ++j) {
    const GpuJoint& g = joints[j];
    if (equalityRowCount(g) == 0) continue;
    const bool a = dynamic(params, g.bodyA), b = dynamic(params, g.bodyB);
    if (a && b) bodies.join(uint32_t(g.bodyA), uint32_t(g.bodyB));
    if (a || b) anchor[j] = a ? g.bodyA : g.bodyB;
  }
  // Islands numbered by their first joint, rows by joint then row: the plan depends on the
  // joints' order only.
  std::vector<int> islandOf(params.size(), -1);
  std::vector<std::vector<RowRef>> islands;
  for (size_t j = 0; j < joints.size(); ++j) {
    if (anchor[j] < 0) continue;
    const uint32_t root = bodies.find(uint32_t(anchor[j]));
    if (islandOf[root] < 0) {
      islandOf[root] = int(islands.size());
      islands.emplace_back();
    }
    for (uint32_t r = 0; r < equalityRowCount(joints[j]); ++r)
      islands[size_t(islandOf[root])].push_back({uint32_t(j), r});
  }
  for (const std::vector<RowRef>& rows : islands) planIsland(rows, joints, params, plan);
  return plan;
}

}  // namespace phys::gpu
