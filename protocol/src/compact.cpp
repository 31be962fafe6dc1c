// Compact body states: see compact.h for the layout and its error bounds.
#include "phys/protocol/compact.h"

#include <algorithm>
#include <bit>
#include <cmath>

namespace phys::protocol {

namespace {

constexpr double kPosScale = double((1u << 24) - 1);
constexpr double kRotScale = double((1u << 20) - 1);
constexpr double kRotSpan = 0.70710678118654752;  // 1/sqrt(2): the smallest three's range

uint32_t fraction24(float x, float lo, float hi) {
  const double e = double(hi) - double(lo);
  if (!(e > 0)) return 0;
  const double f = std::clamp((double(x) - double(lo)) / e, 0.0, 1.0);
  return uint32_t(std::lround(f * kPosScale));
}
float unfraction24(uint32_t q, float lo, float hi) {
  // (A multiplication, not a division: decoding is a subscriber's main cost per body.)
  return float(double(lo) + (double(hi) - double(lo)) * (double(q) * (1.0 / kPosScale)));
}

uint64_t packRotation(const wire::Quat& q) {
  float c[4] = {q.x(), q.y(), q.z(), q.w()};
  int largest = 0;
  for (int i = 1; i < 4; ++i)
    if (std::fabs(c[i]) > std::fabs(c[largest])) largest = i;
  const float sign = c[largest] < 0 ? -1.0f : 1.0f;  // q and -q are the same rotation
  uint64_t bits = uint64_t(largest) << 60;
  int k = 0;
  for (int i = 0; i < 4; ++i) {
    if (i == largest) continue;
    const double v = std::clamp(double(c[i] * sign), -kRotSpan, kRotSpan);
    const uint64_t q20 = uint64_t(std::lround((v + kRotSpan) / (2 * kRotSpan) * kRotScale));
    bits |= q20 << (40 - 20 * k);
    ++k;
  }
  return bits;
}
wire::Quat unpackRotation(uint64_t bits) {
  // In float: the 20-bit steps (1.4e-6) are twenty times float's rounding here, and this is
  // a subscriber's main cost per body.
  const int largest = int((bits >> 60) & 3);
  float c[4] = {};
  float sum = 0;
  int k = 0;
  constexpr float kStep = float(2 * kRotSpan / kRotScale), kSpan = float(kRotSpan);
  for (int i = 0; i < 4; ++i) {
    if (i == largest) continue;
    c[i] = float((bits >> (40 - 20 * k)) & 0xFFFFF) * kStep - kSpan;
    sum += c[i] * c[i];
    ++k;
  }
  c[largest] = std::sqrt(std::max(0.0f, 1.0f - sum));
  const float inv = 1 / std::sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2] + c[3] * c[3]);
  return wire::Quat(c[0] * inv, c[1] * inv, c[2] * inv, c[3] * inv);
}

}  // namespace

uint16_t toHalf(float f) {
  const uint32_t x = std::bit_cast<uint32_t>(f);
  const uint32_t sign = (x >> 16) & 0x8000;
  const uint32_t absx = x & 0x7FFFFFFF;
  if (absx >= 0x7F800000) return uint16_t(sign | 0x7C00 | (absx > 0x7F800000 ? 0x200 : 0));
  if (absx >= 0x477FF000) return uint16_t(sign | 0x7C00);  // rounds past 65504: infinity
  if (absx < 0x38800000) {  // below the smallest normal half (2^-14): subnormal or zero
    if (absx < 0x33000000) return uint16_t(sign);  // under half the smallest subnormal
    // value = m 2^(e - 150); in units of the smallest subnormal half (2^-24): m >> (126 - e).
    const uint32_t m = (absx & 0x7FFFFF) | 0x800000;
    const int shift = 126 - int(absx >> 23);  // 14..24
    uint32_t v = m >> shift;
    const uint32_t rem = m & ((1u << shift) - 1), half = 1u << (shift - 1);
    if (rem > half || (rem == half && (v & 1))) ++v;
    return uint16_t(sign | v);
  }
  uint32_t v = ((absx - 0x38000000) >> 13);  // rebias the exponent, keep 10 mantissa bits
  const uint32_t rem = absx & 0x1FFF;
  if (rem > 0x1000 || (rem == 0x1000 && (v & 1))) ++v;
  return uint16_t(sign | v);
}

float fromHalf(uint16_t h) {
  const uint32_t sign = uint32_t(h & 0x8000) << 16;
  const uint32_t e = (h >> 10) & 0x1F, m = h & 0x3FF;
  if (e == 0) {  // zero or subnormal: m 2^-24, exactly (a power of two, no ldexp call)
    const float v = float(m) * 0x1p-24f;
    return sign ? -v : v;
  }
  if (e == 31) return std::bit_cast<float>(sign | 0x7F800000 | (m << 13));
  return std::bit_cast<float>(sign | ((e + 112) << 23) | (m << 13));
}

CompactBounds compactBounds(std::span<const wire::BodyState> states) {
  CompactBounds b;
  if (states.empty()) return b;
  const wire::Vec3& p0 = states[0].position();
  b.lo = b.hi = {p0.x(), p0.y(), p0.z()};
  for (const wire::BodyState& s : states) {
    const wire::Vec3& p = s.position();
    b.lo = vmin(b.lo, {p.x(), p.y(), p.z()});
    b.hi = vmax(b.hi, {p.x(), p.y(), p.z()});
  }
  return b;
}

wire::CompactBodyState compactState(const wire::BodyState& s, const CompactBounds& b) {
  const uint32_t q[3] = {fraction24(s.position().x(), b.lo.x, b.hi.x),
                         fraction24(s.position().y(), b.lo.y, b.hi.y),
                         fraction24(s.position().z(), b.lo.z, b.hi.z)};
  uint8_t position[9];
  for (int a = 0; a < 3; ++a)
    for (int k = 0; k < 3; ++k) position[3 * a + k] = uint8_t(q[a] >> (8 * k));
  const wire::Vec3& v = s.linear_velocity();
  const wire::Vec3& w = s.angular_velocity();
  const uint16_t lin[3] = {toHalf(v.x()), toHalf(v.y()), toHalf(v.z())};
  const uint16_t ang[3] = {toHalf(w.x()), toHalf(w.y()), toHalf(w.z())};
  return wire::CompactBodyState(
      s.id(), packRotation(s.rotation()), flatbuffers::span<const uint8_t, 9>(position),
      flatbuffers::span<const uint16_t, 3>(lin), flatbuffers::span<const uint16_t, 3>(ang));
}

wire::BodyState expandState(const wire::CompactBodyState& c, const CompactBounds& b) {
  const uint8_t* bytes = c.position()->Data();
  uint32_t q[3];
  for (int a = 0; a < 3; ++a)
    q[a] = uint32_t(bytes[3 * a]) | uint32_t(bytes[3 * a + 1]) << 8 | uint32_t(bytes[3 * a + 2]) << 16;
  const wire::Vec3 p(unfraction24(q[0], b.lo.x, b.hi.x), unfraction24(q[1], b.lo.y, b.hi.y),
                     unfraction24(q[2], b.lo.z, b.hi.z));
  const wire::Vec3 v(fromHalf(c.linear_velocity()->Get(0)), fromHalf(c.linear_velocity()->Get(1)),
                     fromHalf(c.linear_velocity()->Get(2)));
  const wire::Vec3 w(fromHalf(c.angular_velocity()->Get(0)), fromHalf(c.angular_velocity()->Get(1)),
                     fromHalf(c.angular_velocity()->Get(2)));
  return wire::BodyState(c.id(), p, unpackRotation(c.rotation()), v, w);
}

}  // namespace phys::protocol
