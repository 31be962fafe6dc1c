// Solver presets: named points of the solver space, kept as data in configs/presets.json.
#pragma once

#include <map>
#include <string>

#include "phys/world/world.h"

namespace phys {

struct Preset {
  std::string name;
  std::string description;
  SolverSettings settings;
};

/// Parses a presets file: {"default": NAME, "presets": {NAME: {"description": ..., field: value}}}
/// where the fields are SolverSettings' in snake_case. Errors name the source, preset and field.
Status parsePresets(const std::string& json, const std::string& source,
                    std::map<std::string, Preset>* out, std::string* defaultName);
Status loadPresetsFile(const std::string& path, std::map<std::string, Preset>* out,
                       std::string* defaultName);

/// The presets file of the source tree (configs/presets.json), found next to the binary's
/// source dir or through PHYS_PRESETS; empty when not found.
std::string defaultPresetsPath();

}  // namespace phys
