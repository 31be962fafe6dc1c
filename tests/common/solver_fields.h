// Solver settings changed field by field, from the list (PHYS_SOLVER_FIELDS): the round trips
// through the pinned formats (snapshots, the wire) and the presets see a field lost or two
// swapped.
#pragma once

#include <gtest/gtest.h>

#include <string>
#include <type_traits>

#include "phys/defs/solver_settings.h"

namespace phys::test {

/// A value of field `index` (the list's order) unlike its default, unlike every other field's
/// of its type, and valid alone and with all the others changed (World::validate).
template <class T>
T changedSetting(T d, int index) {
  if constexpr (std::is_same_v<T, bool>) {
    return !d;
  } else if constexpr (std::is_enum_v<T>) {
    // The last value, or the first where that is the default: the colored scheme keeps
    // direct_ldl valid, which Jacobi would not.
    auto names = settingNames(d);
    return d == names.back().value ? names.front().value : names.back().value;
  } else if constexpr (std::is_integral_v<T>) {
    return d + 1 + index;
  } else {
    return d + float(1 + index) / 64;
  }
}

/// The defaults with field `only` changed; every field changed when only is -1.
inline SolverSettings changedSettings(int only = -1) {
  SolverSettings s;
  int i = 0;
#define PHYS_CHANGE(type, member, ...)                               \
  if (only < 0 || only == i) s.member = changedSetting(s.member, i); \
  ++i;
  PHYS_SOLVER_FIELDS(PHYS_CHANGE)
#undef PHYS_CHANGE
  return s;
}

/// Every field of a equal to b's, each named where it differs.
inline void expectSameSettings(const SolverSettings& a, const SolverSettings& b,
                               const std::string& context) {
#define PHYS_SAME(type, member, ...) EXPECT_EQ(a.member, b.member) << context << ": " #member;
  PHYS_SOLVER_FIELDS(PHYS_SAME)
#undef PHYS_SAME
}

}  // namespace phys::test
