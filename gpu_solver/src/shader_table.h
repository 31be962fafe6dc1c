// The embedded SPIR-V of the step's shaders (generated shader_table.cpp).
#pragma once

#include <cstdint>
#include <span>

namespace phys::gpu {
/// The SPIR-V words of shaders/<name>.comp; empty if there is no such shader.
std::span<const uint32_t> shaderCode(const char* name);
}  // namespace phys::gpu
