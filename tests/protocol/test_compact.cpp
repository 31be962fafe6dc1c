// Compact body states (protocol/compact.h): each field within its documented error bound,
// half floats exact where IEEE binary16 is, and a compact frame decodes to the same bodies.
#include <bit>
#include <cmath>
#include <random>

#include "phys/protocol/compact.h"
#include "protocol_test_util.h"

namespace phys::protocol::test {
namespace {

TEST(Compact, HalfFloatsAreIeeeBinary16) {
  // Exactly representable values round-trip; the rest round to nearest (even).
  for (float f : {0.0f, -0.0f, 1.0f, -2.5f, 65504.0f, 6.103515625e-05f, 5.9604644775390625e-08f,
                  1024.0f, 0.333251953125f}) {
    EXPECT_EQ(std::bit_cast<uint32_t>(fromHalf(toHalf(f))), std::bit_cast<uint32_t>(f)) << f;
  }
  EXPECT_EQ(toHalf(1.0f), 0x3C00);
  EXPECT_EQ(toHalf(-2.0f), 0xC000);
  EXPECT_EQ(toHalf(65504.0f), 0x7BFF);
  EXPECT_EQ(toHalf(1e6f), 0x7C00);                // past the largest: infinity
  EXPECT_EQ(toHalf(1.0f + 1.0f / 4096), 0x3C00);  // a quarter step: down
  EXPECT_EQ(toHalf(1.0f + 3.0f / 2048), 0x3C02);  // a half step from odd 0x3C01: to even
  EXPECT_TRUE(std::isnan(fromHalf(toHalf(NAN))));
  // Relative error at most 2^-11 across the normal range, absolute 2^-25 below it.
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> e(-20, 15);
  for (int i = 0; i < 100000; ++i) {
    const float f =
        std::ldexp(1.0f + float(rng() % 1000000) / 1e6f, int(e(rng))) * (i % 2 ? -1 : 1);
    const float back = fromHalf(toHalf(f));
    const float bound =
        std::fabs(f) >= 6.103515625e-05f ? std::fabs(f) / 2048 : std::ldexp(1.0f, -25);
    ASSERT_LE(std::fabs(back - f), bound) << f;
  }
}

TEST(Compact, StatesAreWithinTheDocumentedBounds) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> u(-1, 1);
  std::vector<wire::BodyState> states;
  for (int i = 0; i < 20000; ++i) {
    phys::Quat q = normalize(phys::Quat{u(rng), u(rng), u(rng), u(rng)});
    states.emplace_back(uint64_t(i + 1), wire::Vec3(50 * u(rng), 50 * u(rng), 5 + 5 * u(rng)),
                        wire::Quat(q.x, q.y, q.z, q.w),
                        wire::Vec3(10 * u(rng), 10 * u(rng), 10 * u(rng)),
                        wire::Vec3(3 * u(rng), 3 * u(rng), 3 * u(rng)));
  }
  const CompactBounds b = compactBounds(states);
  const phys::Vec3 extent = b.hi - b.lo;
  double worstAngle = 0;
  for (const wire::BodyState& s : states) {
    const wire::BodyState r = expandState(compactState(s, b), b);
    ASSERT_EQ(r.id(), s.id());
    // Position: half a 24-bit step of the box (plus the float's own rounding).
    EXPECT_LE(std::fabs(r.position().x() - s.position().x()), extent.x / 2 / 16777215 + 4e-6);
    EXPECT_LE(std::fabs(r.position().y() - s.position().y()), extent.y / 2 / 16777215 + 4e-6);
    EXPECT_LE(std::fabs(r.position().z() - s.position().z()), extent.z / 2 / 16777215 + 1e-6);
    // Rotation: the angle between the two, 2 |q1 - q2| for small angles (q or -q).
    const double dm[4] = {
        double(r.rotation().x()) - s.rotation().x(), double(r.rotation().y()) - s.rotation().y(),
        double(r.rotation().z()) - s.rotation().z(), double(r.rotation().w()) - s.rotation().w()};
    const double dp[4] = {
        double(r.rotation().x()) + s.rotation().x(), double(r.rotation().y()) + s.rotation().y(),
        double(r.rotation().z()) + s.rotation().z(), double(r.rotation().w()) + s.rotation().w()};
    auto norm = [](const double* v) {
      return std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2] + v[3] * v[3]);
    };
    worstAngle = std::max(worstAngle, 2 * std::min(norm(dm), norm(dp)));
    // Velocities: half precision.
    EXPECT_LE(std::fabs(r.linear_velocity().x() - s.linear_velocity().x()),
              std::fabs(s.linear_velocity().x()) / 2048 + 3e-8);
    EXPECT_LE(std::fabs(r.angular_velocity().z() - s.angular_velocity().z()),
              std::fabs(s.angular_velocity().z()) / 2048 + 3e-8);
  }
  EXPECT_LT(worstAngle, 5e-6);
  std::printf("worst rotation error over 20,000 states: %.3g rad\n", worstAngle);
}

// docs/PROTOCOL.md "Compact states" is enough to decode compact states (issue 40: a client
// written from it read the rotation's fields in the wrong order). This decoder follows the
// document, not compact.cpp: the bit layout and the formulas, in double; its results are
// within the document's bounds, stated exactly (half a step plus half a float ulp for
// positions, 5e-6 rad as 2 acos |q . q'| for rotations).
TEST(Compact, ADecoderWrittenFromTheDocumentIsWithinItsBounds) {
  const double s2 = std::sqrt(2.0), span = 1 / std::sqrt(2.0);
  // The rotation (0.1, -0.2, 0.3, w): w the largest (index 3), x in bits 40-59, y in 20-39,
  // z in 0-19, each round((v + 1/sqrt 2) / sqrt 2 * (2^20 - 1)).
  {
    const float w = std::sqrt(1 - 0.01f - 0.04f - 0.09f);
    const wire::BodyState st(1, wire::Vec3(), wire::Quat(0.1f, -0.2f, 0.3f, w), wire::Vec3(),
                             wire::Vec3());
    const uint64_t bits = compactState(st, CompactBounds{}).rotation();
    auto field = [&](double v) { return uint64_t(std::lround((v + span) / s2 * 1048575)); };
    EXPECT_EQ(bits >> 60, 3u);
    EXPECT_EQ((bits >> 40) & 0xFFFFF, field(0.1f));
    EXPECT_EQ((bits >> 20) & 0xFFFFF, field(-0.2f));
    EXPECT_EQ(bits & 0xFFFFF, field(0.3f));
    // y the largest, negative: made positive (the quaternion negated); x, z, w in order.
    const wire::BodyState sy(1, wire::Vec3(), wire::Quat(0.1f, -0.9f, 0.3f, 0.2f), wire::Vec3(),
                             wire::Vec3());
    const uint64_t by = compactState(sy, CompactBounds{}).rotation();
    EXPECT_EQ(by >> 60, 1u);
    EXPECT_EQ((by >> 40) & 0xFFFFF, field(-0.1f));
    EXPECT_EQ((by >> 20) & 0xFFFFF, field(-0.3f));
    EXPECT_EQ(by & 0xFFFFF, field(-0.2f));
  }
  std::mt19937 rng(41);
  std::normal_distribution<double> n(0, 1);
  double worstAngle = 0, worstPosition = 0;  // the latter: error over the documented bound
  for (double extent : {1.0, 100.0, 20000.0}) {
    std::uniform_real_distribution<float> u(float(-extent / 2), float(extent / 2));
    std::vector<wire::BodyState> states;
    for (int i = 0; i < 20000; ++i) {
      double q[4] = {n(rng), n(rng), n(rng), n(rng)};
      if (i % 5 == 0) q[i % 4] = q[(i + 1) % 4];  // two components of one magnitude
      const double l = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
      states.emplace_back(uint64_t(i + 1), wire::Vec3(u(rng) + float(extent), u(rng), u(rng)),
                          wire::Quat(float(q[0] / l), float(q[1] / l), float(q[2] / l),
                                     float(q[3] / l)),
                          wire::Vec3(), wire::Vec3());
    }
    const CompactBounds b = compactBounds(states);
    const double lo[3] = {b.lo.x, b.lo.y, b.lo.z}, hi[3] = {b.hi.x, b.hi.y, b.hi.z};
    for (const wire::BodyState& s : states) {
      const wire::CompactBodyState c = compactState(s, b);
      // Position: bytes 3a..3a+2, least significant first; x' = float(min + e * q / (2^24-1)).
      const float x[3] = {s.position().x(), s.position().y(), s.position().z()};
      for (int a = 0; a < 3; ++a) {
        const uint8_t* p = c.position()->Data() + 3 * a;
        const uint32_t q = uint32_t(p[0]) | uint32_t(p[1]) << 8 | uint32_t(p[2]) << 16;
        const double e = hi[a] - lo[a];
        const float back = float(lo[a] + e * (q * (1.0 / 16777215)));
        const double ulp = std::nextafter(std::fabs(back), INFINITY) - std::fabs(back);
        const double bound = e / 16777215 / 2 + ulp / 2;
        worstPosition = std::max(worstPosition, std::fabs(double(back) - x[a]) / bound);
      }
      // Rotation: the largest's index in bits 60-61, the other three in index order from
      // bits 40-59 down; v = n sqrt 2 / (2^20 - 1) - 1/sqrt 2, the largest from the rest.
      const uint64_t bits = c.rotation();
      const int largest = int(bits >> 60);
      double r[4];
      double sum = 0;
      for (int i = 0, k = 0; i < 4; ++i) {
        if (i == largest) continue;
        r[i] = double((bits >> (40 - 20 * k)) & 0xFFFFF) * (s2 / 1048575) - span;
        sum += r[i] * r[i];
        ++k;
      }
      r[largest] = std::sqrt(std::max(0.0, 1 - sum));
      // The angle between the two, both normalized in double (acos near 1 would magnify the
      // sent float quaternion's own distance from unit length).
      const double o[4] = {s.rotation().x(), s.rotation().y(), s.rotation().z(), s.rotation().w()};
      const double norm = std::sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2] + r[3] * r[3]) *
                          std::sqrt(o[0] * o[0] + o[1] * o[1] + o[2] * o[2] + o[3] * o[3]);
      const double dot = (r[0] * o[0] + r[1] * o[1] + r[2] * o[2] + r[3] * o[3]) / norm;
      worstAngle = std::max(worstAngle, 2 * std::acos(std::min(1.0, std::fabs(dot))));
    }
  }
  EXPECT_LE(worstPosition, 1.0) << "a position error over half a step plus half an ulp";
  EXPECT_LT(worstAngle, 5e-6);
  std::printf("document's decoder: worst rotation error %.3g rad, worst position error %.3g of "
              "its bound\n",
              worstAngle, worstPosition);
}

TEST(Compact, ACompactDeltaFrameDecodes) {
  std::vector<wire::BodyState> states = {
      wire::BodyState(7, wire::Vec3(1, 2, 3), wire::Quat(0, 0, 0, 1), wire::Vec3(0, 0, -1),
                      wire::Vec3(0, 0, 0)),
      wire::BodyState(9, wire::Vec3(-4, 0, 1), wire::Quat(0, 0, 0.6f, 0.8f), wire::Vec3(),
                      wire::Vec3(0.5f, 0, 0))};
  FrameHeader h{3, 12, 0.2, 1};
  h.keyframe = false;
  h.baseTick = 11;
  h.compact = true;
  const std::vector<uint64_t> removed = {5};
  std::vector<Bytes> chunks = encodeStateFrames(h, states, 1, removed, 40);
  ASSERT_EQ(chunks.size(), 2u);
  for (size_t c = 0; c < chunks.size(); ++c) {
    auto f = decodeStateFrame(std::move(chunks[c]));
    ASSERT_TRUE(f.ok()) << f.status.message;
    EXPECT_FALSE(f->keyframe());
    EXPECT_EQ(f->base_tick(), 11u);
    EXPECT_EQ(f->total_bodies(), 40u);
    EXPECT_EQ(f->bodies(), nullptr);
    ASSERT_EQ(f->compact()->size(), 1u);
    EXPECT_EQ(f->compact()->Get(0)->id(), states[c].id());
    EXPECT_EQ(f->removed() != nullptr, c == 0);  // in chunk 0 only
    // Full and compact sizes: 64 and 40 bytes a body.
    EXPECT_EQ(sizeof(wire::BodyState), 64u);
    EXPECT_EQ(sizeof(wire::CompactBodyState), 40u);
  }
}

TEST(Compact, AKeyframeWithRemovedBodiesIsRefused) {
  FrameHeader h{3, 12, 0.2, 1};
  std::vector<uint64_t> removed = {5};
  Bytes b = encodeStateFrame(h, 0, 1, 0, {}, removed);
  auto f = decodeStateFrame(std::move(b));
  EXPECT_FALSE(f.ok());
}

}  // namespace
}  // namespace phys::protocol::test
