#include "phys/scene/presets.h"

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <limits>
#include <sstream>
#include <type_traits>

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

/// An enum setting by its JSON name (phys/defs/solver_settings.h's tables).
template <class E>
Status readEnum(const nlohmann::json& v, const std::string& path, E* out) {
  std::string name = v.is_string() ? v.get<std::string>() : "";
  std::string known;
  for (const SettingName<E>& n : settingNames(E{})) {
    if (name == n.json) {
      *out = n.value;
      return Status::Ok();
    }
    known += std::string(known.empty() ? "" : ", ") + "\"" + n.json + "\"";
  }
  return bad(path + ": must be one of " + known);
}

/// A setting of any kind from JSON.
template <class T>
Status readSetting(const nlohmann::json& v, const std::string& path, T* out) {
  if constexpr (std::is_enum_v<T>) {
    return readEnum(v, path, out);
  } else if constexpr (std::is_same_v<T, bool>) {
    if (!v.is_boolean()) return bad(path + ": must be true or false");
    *out = v.get<bool>();
    return Status::Ok();
  } else {
    return readNumber(v, path, out);
  }
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
    // The keys are the list's JSON names (PHYS_SOLVER_FIELDS).
#define PHYS_FROM_JSON(type, member, name, json, ...) \
  if (k == #json)                                     \
    st = readSetting(v, p, &s.member);                \
  else
    PHYS_SOLVER_FIELDS(PHYS_FROM_JSON) {
#undef PHYS_FROM_JSON
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
  nlohmann::json j;
  // An enum by its JSON name.
  auto value = [](auto v) -> nlohmann::json {
    if constexpr (std::is_enum_v<decltype(v)>)
      return settingName(v) ? settingName(v)->json : "?";
    else
      return v;
  };
#define PHYS_TO_JSON(type, member, name, json, ...) j[#json] = value(s.member);
  PHYS_SOLVER_FIELDS(PHYS_TO_JSON)
#undef PHYS_TO_JSON
  return j;
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
