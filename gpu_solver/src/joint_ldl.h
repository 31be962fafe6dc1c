// The joints' direct solve on the device: the host's half. The device factors
// A = J M^-1 J^T of the joints' equality rows as L D L^T every substep and solves with it in
// every iteration (joint_ldl.comp), as the CPU's EqualityLdl (physics/dynamics/solver_ldl.h)
// does with Eigen. Everything that depends only on which rows couple (which joints share a
// dynamic body) is planned here, once per change of the joints or of which bodies are
// dynamic: the islands, a fill-reducing order of each island's rows (Eigen's AMD) and the
// pattern of L (the elimination tree's row patterns, Davis' LDL symbolic step). The device
// then only does arithmetic on fixed index lists.
//
// A workgroup solves an island (joint_ldl.comp), so the plan also says what can run side by
// side: the island's rows are ordered by their level in the elimination tree (any order in
// which children come before parents gives the same L: the level order keeps AMD's fill), and
// a level's columns are factored, and its rows solved, at once. The impulses go to each
// dynamic body from its own list of rows, in row order, by one thread per body.
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include "phys/gpu/shared.h"

namespace phys::gpu {

/// How many of a joint's rows are equality rows. They come first among its rows, in the
/// order prepare_joints.comp builds them: the anchor point (3) unless distance or prismatic,
/// then the rotation lock (3, fixed and prismatic) or the hinge's axes (2), the prismatic's
/// two perpendiculars (2, first), a rigid distance (1).
uint32_t equalityRowCount(const GpuJoint& j);

struct JointLdlPlan {
  std::vector<GpuLdlIsland> islands;
  std::vector<GpuLdlRow> rows;          ///< every island's rows, in elimination order
  std::vector<uint32_t> pattern;        ///< pairs (i, index of L(k, i)), GpuLdlRow's pattern
  std::vector<uint32_t> columnRows;     ///< the row of each entry of L, column by column
  std::vector<uint32_t> entryColumns;   ///< the column of each entry of L
  std::vector<uint32_t> levels;         ///< pairs (first row, end row), GpuLdlIsland's levels
  std::vector<uvec4> bodies;            ///< (body, begin, end, 0) in bodyRows
  std::vector<uint32_t> bodyRows;       ///< each body's rows, ascending
  size_t entries() const { return columnRows.size(); }
};

/// The plan for these joints over bodies with these parameters (PHYS_GPU_BODY_DYNAMIC says
/// which bodies couple rows; a joint with no dynamic body has nothing to solve).
JointLdlPlan planJointLdl(std::span<const GpuJoint> joints, std::span<const GpuBodyParams> params);

}  // namespace phys::gpu
