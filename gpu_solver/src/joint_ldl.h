// The joints' direct solve on the device: the host's half. The device factors
// A = J M^-1 J^T of the joints' equality rows as L D L^T every substep and solves with it in
// every iteration (joint_ldl.comp), as the CPU's EqualityLdl (physics/dynamics/solver_ldl.h)
// does with Eigen. Everything that depends only on which rows couple (which joints share a
// dynamic body) is planned here, once per change of the joints or of which bodies are
// dynamic: the islands, a fill-reducing order of each island's rows (Eigen's AMD) and the
// pattern of L (the elimination tree's row patterns, Davis' LDL symbolic step). The device
// then only does arithmetic on fixed index lists.
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
  std::vector<uvec4> islands;        ///< (first row, rows, 0, 0)
  std::vector<GpuLdlRow> rows;       ///< every island's rows, in elimination order
  std::vector<uint32_t> pattern;     ///< pairs (i, index of L(k, i)), GpuLdlRow's pattern
  std::vector<uint32_t> columnRows;  ///< the row of each entry of L, column by column
  size_t entries() const { return columnRows.size(); }
};

/// The plan for these joints over bodies with these parameters (PHYS_GPU_BODY_DYNAMIC says
/// which bodies couple rows; a joint with no dynamic body has nothing to solve).
JointLdlPlan planJointLdl(std::span<const GpuJoint> joints, std::span<const GpuBodyParams> params);

}  // namespace phys::gpu
