// Compact body states (StateFrame.compact): 40 bytes a body instead of 64, with bounded
// error. docs/PROTOCOL.md "Compact states" states the bounds; tests/protocol/test_compact.cpp
// checks them.
//   position: 24 bits per axis, a fraction of the frame's box (bounds_min..bounds_max): the
//             error is at most half a step, extent / (2^24 - 1) / 2 per axis (3 um across a
//             100 m world), plus half a float ulp at the position (the decoded value's
//             rounding to float);
//   rotation: smallest three, 20 bits per component over [-1/sqrt(2), 1/sqrt(2)], the three
//             in index order (x y z w) in bits 40-59, 20-39 and 0-19, the largest's index in
//             bits 60-61: each component within 6.8e-7 before renormalizing, the rotation
//             within 5e-6 rad (4.8e-6 the worst of 3 million random ones, decoded in float);
//   velocities: IEEE half precision per component: relative error at most 2^-11 (4.9e-4)
//             for magnitudes from 6.1e-5 to 65504 (m/s, rad/s), absolute at most 2^-25 (3e-8)
//             below; infinity above 65504.
#pragma once

#include <cstdint>
#include <span>

#include "phys/defs/math.h"
#include "phys/protocol/wire.h"

namespace phys::protocol {

struct CompactBounds {
  phys::Vec3 lo, hi;
};

/// The box of the states' positions (all zero for none).
CompactBounds compactBounds(std::span<const wire::BodyState> states);
wire::CompactBodyState compactState(const wire::BodyState& s, const CompactBounds& b);
wire::BodyState expandState(const wire::CompactBodyState& c, const CompactBounds& b);

/// IEEE 754 binary16, round to nearest even; overflow to infinity.
uint16_t toHalf(float f);
float fromHalf(uint16_t h);

}  // namespace phys::protocol
