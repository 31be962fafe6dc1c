// The value rules shared by the decoder's checks of wire tables (decoder.cpp) and
// validate.cpp's checks of phys definitions, so that the two say the same about the same
// number. Each check returns false after Derived::invalid(field, what) recorded the failure;
// Derived has `const Limits& lim`.
#pragma once

#include <cmath>
#include <cstdio>
#include <string>
#include <string_view>

#include "phys/protocol/limits.h"

namespace phys::protocol::detail {

/// Bounds with no Limits field of their own (documented in docs/PROTOCOL.md).
inline constexpr float kMaxHertz = 1e6f;         ///< spring, contact and joint stiffness, Hz
inline constexpr float kMaxDampingRatio = 1e6f;  ///< spring, contact and joint damping ratios
inline constexpr float kMaxDirectContactRatio = 1e6f;  ///< SolverSettings::directContactRatio
// World settings (WorldSettings, phys::WorldDef).
inline constexpr float kMaxMargin = 10.0f;  ///< m, speculative_distance and aabb_margin
inline constexpr float kMaxSleepTime = 1e6f;  ///< s, sleep_time
inline constexpr float kMaxGuardEnergyJump = 1e6f;  ///< guard_energy_jump
/// guard_retries: a step the guard redoes costs up to this many steps more.
inline constexpr int kMaxGuardRetries = 4;

inline std::string num(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%g", v);
  return buf;
}

template <class Derived>
class ValueRules {
 public:
  bool finite(float v, std::string_view f) {
    return std::isfinite(v) || self().invalid(f, "must be finite, got " + num(v));
  }
  /// lo <= v <= hi.
  bool range(float v, float lo, float hi, std::string_view f) {
    if (!finite(v, f)) return false;
    if (v < lo || v > hi)
      return self().invalid(f, "must be in [" + num(lo) + ", " + num(hi) + "], got " + num(v));
    return true;
  }
  /// 0 < v <= max.
  bool positive(float v, float max, std::string_view f) {
    if (!finite(v, f)) return false;
    if (!(v > 0)) return self().invalid(f, "must be > 0, got " + num(v));
    if (v > max) return self().invalid(f, "must be <= " + num(max) + ", got " + num(v));
    return true;
  }
  /// 0 <= v <= max.
  bool nonNegative(float v, float max, std::string_view f) {
    if (!finite(v, f)) return false;
    if (v < 0) return self().invalid(f, "must be >= 0, got " + num(v));
    if (v > max) return self().invalid(f, "must be <= " + num(max) + ", got " + num(v));
    return true;
  }
  /// A length of a shape: > 0, >= minSize, <= maxSize.
  bool size(float v, std::string_view f) {
    const Limits& lim = self().lim;
    if (!positive(v, lim.maxSize, f)) return false;
    if (v < lim.minSize)
      return self().invalid(f, "must be >= " + num(lim.minSize) + ", got " + num(v));
    return true;
  }
  /// Every component finite and within [-maxAbs, maxAbs].
  bool vec3(float x, float y, float z, float maxAbs, std::string_view f) {
    const float c[3] = {x, y, z};
    static constexpr const char* kAxis[3] = {".x", ".y", ".z"};
    for (int i = 0; i < 3; ++i)
      if (!range(c[i], -maxAbs, maxAbs, std::string(f) + kAxis[i])) return false;
    return true;
  }
  /// A direction: components within max_size, not zero.
  bool direction3(float x, float y, float z, std::string_view f) {
    if (!vec3(x, y, z, self().lim.maxSize, f)) return false;
    double l2 = double(x) * x + double(y) * y + double(z) * z;
    return l2 >= 1e-12 || self().invalid(f, "must be a non-zero direction");
  }
  /// Finite and within quat_tolerance of unit length.
  bool quat4(float x, float y, float z, float w, std::string_view f) {
    const float c[4] = {x, y, z, w};
    static constexpr const char* kComp[4] = {".x", ".y", ".z", ".w"};
    for (int i = 0; i < 4; ++i)
      if (!finite(c[i], std::string(f) + kComp[i])) return false;
    double n = std::sqrt(double(c[0]) * c[0] + double(c[1]) * c[1] + double(c[2]) * c[2] +
                         double(c[3]) * c[3]);
    const float tol = self().lim.quatTolerance;
    if (!(std::fabs(n - 1.0) < tol))
      return self().invalid(f, "must be a unit quaternion (| |q| - 1 | < " + num(tol) +
                                   "), got |q| = " + num(n));
    return true;
  }

 private:
  Derived& self() { return static_cast<Derived&>(*this); }
};

}  // namespace phys::protocol::detail
