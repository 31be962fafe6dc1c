#include "phys/scene/presets.h"

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <limits>
#include <sstream>

#include "settings_json.h"

namespace phys {

namespace {

Status bad(const std::string& m) {
  return Status::Error(StatusCode::InvalidArgument, m);
}

template <class T>
Status readNumber(const nlohmann::json& v, const std::string& path, T* out) {
  if (!v.is_number()) return bad(path + ": must be a number");
  double d = v.get<double>();
  if (!std::isfinite(d)) return bad(path + ": must be finite");
  if constexpr (std::is_integral_v<T>) {
    if (!v.is_number_integer()) return bad(path + ": must be an integer");
    // Range check before the cast: converting an out-of-range double is undefined.
    if (d < double(std::numeric_limits<T>::min()) || d > double(std::numeric_limits<T>::max()))
      return bad(path + ": out of range");
  }
  *out = T(d);
  return Status::Ok();
}

/// The JSON names of an enum's values: one table serves parsing and writing.
template <class E>
struct EnumName {
  E value;
  const char* name;
};
using S = SolverSettings;
constexpr EnumName<S::Scheme> kSchemes[] = {
    {S::Scheme::GaussSeidel, "gauss_seidel"},
    {S::Scheme::Jacobi, "jacobi"},
    {S::Scheme::ColoredGaussSeidel, "colored_gauss_seidel"}};
constexpr EnumName<S::PositionPass> kPositionPasses[] = {
    {S::PositionPass::None, "none"},
    {S::PositionPass::NonlinearGaussSeidel, "nonlinear_gauss_seidel"},
    {S::PositionPass::NonlinearJacobi, "nonlinear_jacobi"}};
constexpr EnumName<S::EqualitySolve> kEqualitySolves[] = {
    {S::EqualitySolve::Iterative, "iterative"}, {S::EqualitySolve::DirectLdl, "direct_ldl"}};
constexpr EnumName<S::Stabilization> kStabilizations[] = {
    {S::Stabilization::Soft, "soft"}, {S::Stabilization::Baumgarte, "baumgarte"}};

template <class E, size_t N>
Status readEnum(const nlohmann::json& v, const std::string& path, const EnumName<E> (&names)[N],
                E* out) {
  std::string name = v.is_string() ? v.get<std::string>() : "";
  std::string known;
  for (const EnumName<E>& n : names) {
    if (name == n.name) {
      *out = n.value;
      return Status::Ok();
    }
    known += std::string(known.empty() ? "" : ", ") + "\"" + n.name + "\"";
  }
  return bad(path + ": must be one of " + known);
}

template <class E, size_t N>
const char* enumName(const EnumName<E> (&names)[N], E value) {
  for (const EnumName<E>& n : names)
    if (n.value == value) return n.name;
  return "?";
}

}  // namespace

Status solverSettingsFromJson(const nlohmann::json& j, const std::string& path, SolverSettings* out,
                              std::initializer_list<const char*> ignore) {
  if (!j.is_object()) return bad(path + ": must be an object");
  SolverSettings s = *out;
  for (auto it = j.begin(); it != j.end(); ++it) {
    const std::string& k = it.key();
    const nlohmann::json& v = it.value();
    const std::string p = path + "." + k;
    Status st;
    if (k == "substeps")
      st = readNumber(v, p, &s.substeps);
    else if (k == "iterations")
      st = readNumber(v, p, &s.iterations);
    else if (k == "relax_iterations")
      st = readNumber(v, p, &s.relaxIterations);
    else if (k == "baumgarte")
      st = readNumber(v, p, &s.baumgarte);
    else if (k == "contact_hertz")
      st = readNumber(v, p, &s.contactHertz);
    else if (k == "contact_damping_ratio")
      st = readNumber(v, p, &s.contactDampingRatio);
    else if (k == "joint_hertz")
      st = readNumber(v, p, &s.jointHertz);
    else if (k == "joint_damping_ratio")
      st = readNumber(v, p, &s.jointDampingRatio);
    else if (k == "max_pushout")
      st = readNumber(v, p, &s.maxPushout);
    else if (k == "linear_slop")
      st = readNumber(v, p, &s.linearSlop);
    else if (k == "restitution_threshold")
      st = readNumber(v, p, &s.restitutionThreshold);
    else if (k == "tolerance")
      st = readNumber(v, p, &s.tolerance);
    else if (k == "direct_contact_ratio")
      st = readNumber(v, p, &s.directContactRatio);
    else if (k == "warm_start" || k == "restitution" || k == "block_contacts" ||
             k == "geometric_stiffness" || k == "split_pushout" || k == "patch_friction" ||
             k == "stack_stiffening") {
      if (!v.is_boolean()) return bad(p + ": must be true or false");
      bool* field = k == "warm_start"       ? &s.warmStart
                    : k == "restitution"    ? &s.restitution
                    : k == "block_contacts" ? &s.blockContacts
                    : k == "split_pushout"  ? &s.splitPushout
                    : k == "patch_friction" ? &s.patchFriction
                    : k == "stack_stiffening" ? &s.stackStiffening
                                            : &s.geometricStiffness;
      *field = v.get<bool>();
    } else if (k == "position_iterations") {
      st = readNumber(v, p, &s.positionIterations);
    } else if (k == "position_baumgarte") {
      st = readNumber(v, p, &s.positionBaumgarte);
    } else if (k == "max_position_correction") {
      st = readNumber(v, p, &s.maxPositionCorrection);
    } else if (k == "scheme") {
      st = readEnum(v, p, kSchemes, &s.scheme);
    } else if (k == "position_pass") {
      st = readEnum(v, p, kPositionPasses, &s.positionPass);
    } else if (k == "equality") {
      st = readEnum(v, p, kEqualitySolves, &s.equalitySolve);
    } else if (k == "stabilization") {
      st = readEnum(v, p, kStabilizations, &s.stabilization);
    } else {
      bool skip = false;
      for (const char* ig : ignore) skip |= k == ig;
      if (!skip) return bad(p + ": unknown field");
    }
    if (!st.ok()) return st;
  }
  Status st = World::validate(s);
  if (!st.ok()) return bad(path + ": " + st.message);
  *out = s;
  return Status::Ok();
}

nlohmann::json solverSettingsToJson(const SolverSettings& s) {
  return {{"substeps", s.substeps},
          {"iterations", s.iterations},
          {"tolerance", s.tolerance},
          {"relax_iterations", s.relaxIterations},
          {"stabilization", enumName(kStabilizations, s.stabilization)},
          {"baumgarte", s.baumgarte},
          {"contact_hertz", s.contactHertz},
          {"contact_damping_ratio", s.contactDampingRatio},
          {"joint_hertz", s.jointHertz},
          {"joint_damping_ratio", s.jointDampingRatio},
          {"max_pushout", s.maxPushout},
          {"linear_slop", s.linearSlop},
          {"warm_start", s.warmStart},
          {"restitution", s.restitution},
          {"block_contacts", s.blockContacts},
          {"split_pushout", s.splitPushout},
          {"patch_friction", s.patchFriction},
          {"stack_stiffening", s.stackStiffening},
          {"direct_contact_ratio", s.directContactRatio},
          {"geometric_stiffness", s.geometricStiffness},
          {"restitution_threshold", s.restitutionThreshold},
          {"equality", enumName(kEqualitySolves, s.equalitySolve)},
          {"scheme", enumName(kSchemes, s.scheme)},
          {"position_pass", enumName(kPositionPasses, s.positionPass)},
          {"position_iterations", s.positionIterations},
          {"position_baumgarte", s.positionBaumgarte},
          {"max_position_correction", s.maxPositionCorrection}};
}

Status parsePresets(const std::string& text, const std::string& source,
                    std::map<std::string, Preset>* out, std::string* defaultName) {
  nlohmann::json j = nlohmann::json::parse(text, nullptr, false);
  if (j.is_discarded()) return bad(source + ": not valid JSON");
  if (!j.is_object() || !j.contains("presets") || !j["presets"].is_object())
    return bad(source + ": needs an object \"presets\"");
  std::map<std::string, Preset> presets;
  for (auto it = j["presets"].begin(); it != j["presets"].end(); ++it) {
    Preset p;
    p.name = it.key();
    const std::string path = source + ": presets." + p.name;
    if (it.value().contains("description")) {
      if (!it.value()["description"].is_string())
        return bad(path + ".description: must be a string");
      p.description = it.value()["description"].get<std::string>();
    }
    Status st = solverSettingsFromJson(it.value(), path, &p.settings, {"description"});
    if (!st.ok()) return st;
    presets[p.name] = p;
  }
  std::string def = j.value("default", std::string());
  if (def.empty() || !presets.count(def))
    return bad(source + ": default: must name one of the presets");
  *out = std::move(presets);
  if (defaultName) *defaultName = def;
  return Status::Ok();
}

Status loadPresetsFile(const std::string& path, std::map<std::string, Preset>* out,
                       std::string* defaultName) {
  std::ifstream f(path);
  if (!f) return Status::Error(StatusCode::NotFound, path + ": cannot open presets file");
  std::stringstream ss;
  ss << f.rdbuf();
  return parsePresets(ss.str(), path, out, defaultName);
}

std::string defaultPresetsPath() {
  if (const char* env = std::getenv("PHYS_PRESETS")) return env;
#ifdef PHYS_SOURCE_DIR
  std::string p = std::string(PHYS_SOURCE_DIR) + "/configs/presets.json";
  if (std::filesystem::exists(p)) return p;
#endif
  if (std::filesystem::exists("configs/presets.json")) return "configs/presets.json";
  return {};
}

}  // namespace phys
