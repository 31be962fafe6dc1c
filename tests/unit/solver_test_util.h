// Helpers for the tests that drive the solver's rows and wide blocks directly (internal
// headers; the world-level helpers are test_util.h).
#pragma once

#include <cstdint>

#include "dynamics/solver.h"

namespace phys::test {

/// An equality row along x between solver bodies a and b, starting its group: a joint, which
/// the wide schedule solves as a scalar group ahead of the contacts.
inline Row jointRow(int32_t a, int32_t b) {
  Row r;
  r.kind = RowKind::Equality;
  r.a = a;
  r.b = b;
  r.groupStart = true;
  r.linA = {1, 0, 0};
  r.linB = {-1, 0, 0};
  return r;
}

}  // namespace phys::test
