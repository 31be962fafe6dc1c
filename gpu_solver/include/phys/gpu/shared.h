// The GPU step's records (gpu_solver/shaders/shared.h) on the C++ side, with their sizes
// checked against std430 as the shaders see them.
#pragma once

#include <cstddef>

#include "../../../shaders/shared.h"

namespace phys::gpu {
static_assert(sizeof(vec4) == 16 && sizeof(uvec4) == 16);
static_assert(sizeof(GpuBodyState) == 64);
static_assert(sizeof(GpuBodyParams) == 144);
static_assert(sizeof(GpuSolverBody) == 128);
static_assert(sizeof(GpuShape) == 64 && offsetof(GpuShape, body) == 48);
static_assert(sizeof(GpuAabb) == 32);
static_assert(sizeof(GpuPair) == 16);
static_assert(sizeof(GpuBvhNode) == 48);
static_assert(sizeof(GpuManifold) == 160 && offsetof(GpuManifold, count) == 96 &&
              offsetof(GpuManifold, normalImpulse) == 112);
static_assert(sizeof(GpuStepConstants) == 64);
static_assert(sizeof(GpuSortConstants) == 16);
static_assert(sizeof(GpuContact) == 352 && offsetof(GpuContact, rA) == 64 &&
              offsetof(GpuContact, massN) == 192);
static_assert(sizeof(GpuDelta) == 64);
static_assert(sizeof(GpuSolveConstants) == 112);
static_assert(sizeof(GpuJoint) == 176);
static_assert(sizeof(GpuJointRow) == 80);
static_assert(sizeof(GpuJointRows) == 8 * 80 + 96 + 16);
static_assert(sizeof(GpuJointOut) == 64);
static_assert(sizeof(GpuLdlRow) == 32);
static_assert(sizeof(GpuLdlIsland) == 32);
}  // namespace phys::gpu
