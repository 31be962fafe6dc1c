// The codec's rules on phys definitions (validate.h).
#include "phys/protocol/validate.h"

#include <cmath>
#include <cstdio>

#include "value_rules.h"

namespace phys::protocol {

namespace {

using detail::kMaxGuardEnergyJump;
using detail::kMaxGuardRetries;
using detail::kMaxMargin;
using detail::kMaxSleepTime;
using detail::num;
using detail::ValueRules;

/// Check helpers in the decoder's words (value_rules.h): each returns false after recording
/// the first failure.
struct V : ValueRules<V> {
  V(const Limits& limits, std::string path) : lim(limits), base(std::move(path)) {}
  const Limits& lim;
  std::string base;
  Status status = Status::Ok();

  std::string path(std::string_view field) const {
    std::string p = base;
    if (!field.empty()) p += (p.empty() ? "" : ".") + std::string(field);
    return p;
  }
  bool fail(Code code, std::string_view field, const std::string& what) {
    status = Status::Error(code, path(field) + " " + what);
    return false;
  }
  bool invalid(std::string_view f, const std::string& what) {
    return fail(Code::InvalidArgument, f, what);
  }
  bool vec(Vec3 v, float maxAbs, std::string_view f) { return vec3(v.x, v.y, v.z, maxAbs, f); }
};

}  // namespace

bool validUtf8(std::string_view s) {
  size_t i = 0, n = s.size();
  while (i < n) {
    unsigned char c = static_cast<unsigned char>(s[i]);
    if (c < 0x80) {
      ++i;
      continue;
    }
    int len;
    uint32_t cp;
    if ((c & 0xE0) == 0xC0) {
      len = 2;
      cp = c & 0x1F;
    } else if ((c & 0xF0) == 0xE0) {
      len = 3;
      cp = c & 0x0F;
    } else if ((c & 0xF8) == 0xF0) {
      len = 4;
      cp = c & 0x07;
    } else {
      return false;
    }
    if (i + size_t(len) > n) return false;
    for (int k = 1; k < len; ++k) {
      unsigned char cc = static_cast<unsigned char>(s[i + size_t(k)]);
      if ((cc & 0xC0) != 0x80) return false;
      cp = (cp << 6) | (cc & 0x3F);
    }
    static constexpr uint32_t kMin[5] = {0, 0, 0x80, 0x800, 0x10000};
    if (cp < kMin[len] || cp > 0x10FFFF || (cp >= 0xD800 && cp <= 0xDFFF)) return false;
    i += size_t(len);
  }
  return true;
}

std::string shortQuote(std::string_view text, size_t maxBytes) {
  if (text.size() <= maxBytes) return "\"" + std::string(text) + "\"";
  // Cut at a character boundary.
  size_t cut = maxBytes;
  while (cut > 0 && (static_cast<unsigned char>(text[cut]) & 0xC0) == 0x80) --cut;
  return "\"" + std::string(text.substr(0, cut)) + "...\" (" + std::to_string(text.size()) +
         " bytes)";
}

Status checkName(std::string_view name, uint32_t maxBytes, std::string_view path) {
  const std::string p(path);
  if (name.size() > maxBytes)
    return Status::Error(Code::ResourceExhausted, p + " is " + std::to_string(name.size()) +
                                                      " bytes, the limit is " +
                                                      std::to_string(maxBytes));
  if (!validUtf8(name)) return Status::Error(Code::InvalidArgument, p + " is not valid UTF-8");
  for (char ch : name) {
    unsigned char c = static_cast<unsigned char>(ch);
    if (c < 0x20 || c == 0x7F)
      return Status::Error(Code::InvalidArgument, p + " must not contain control characters");
  }
  return Status::Ok();
}

// checkBodyDef and checkJointDef: decoder.cpp, the decoder's own checks on the definition
// written as its wire table (one set of rules).

Status checkWorldParams(phys::Vec3 gravity, float timeStep, const Limits& lim,
                        std::string_view path) {
  V v{lim, std::string(path)};
  if (!v.vec(gravity, lim.maxGravity, "gravity")) return v.status;
  if (!v.positive(timeStep, lim.maxTimeStep, "time_step")) return v.status;
  if (timeStep < lim.minTimeStep)
    v.invalid("time_step", "must be >= " + num(lim.minTimeStep) + ", got " + num(timeStep));
  return v.status;
}

Status checkWorldSettings(const phys::WorldDef& d, const Limits& lim, std::string_view path) {
  Status st = checkWorldParams(d.gravity, d.timeStep, lim, path);
  if (!st.ok()) return st;
  V v{lim, std::string(path)};
  auto run = [&]() -> bool {
    if (!v.positive(d.sleep.time, kMaxSleepTime, "sleep_time") ||
        !v.nonNegative(d.sleep.linearSpeed, lim.maxLinearSpeed, "sleep_linear_speed") ||
        !v.nonNegative(d.sleep.angularSpeed, lim.maxAngularSpeed, "sleep_angular_speed") ||
        !v.positive(d.maxLinearSpeed, lim.maxLinearSpeed, "max_linear_speed") ||
        !v.positive(d.maxAngularSpeed, lim.maxAngularSpeed, "max_angular_speed") ||
        !v.nonNegative(d.speculativeDistance, kMaxMargin, "speculative_distance") ||
        !v.nonNegative(d.aabbMargin, kMaxMargin, "aabb_margin") ||
        !v.nonNegative(d.guardEnergyJump, kMaxGuardEnergyJump, "guard_energy_jump"))
      return false;
    if (d.guardRetries < 0 || d.guardRetries > kMaxGuardRetries)
      return v.invalid("guard_retries", "must be in [0, " + std::to_string(kMaxGuardRetries) +
                                            "], got " + std::to_string(d.guardRetries));
    return true;
  };
  run();
  return v.status;
}

}  // namespace phys::protocol
