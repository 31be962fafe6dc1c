// JSON <-> SolverSettings, shared by the presets file and scene files.
#pragma once

#include <nlohmann/json.hpp>
#include <string>

#include "phys/world/world.h"

namespace phys {

/// Reads the SolverSettings fields present in `j` (snake_case) over *out; unknown keys other
/// than those in `ignore` are errors. `path` prefixes error messages (e.g. "file: solver").
Status solverSettingsFromJson(const nlohmann::json& j, const std::string& path, SolverSettings* out,
                              std::initializer_list<const char*> ignore = {});
nlohmann::json solverSettingsToJson(const SolverSettings& s);

}  // namespace phys
