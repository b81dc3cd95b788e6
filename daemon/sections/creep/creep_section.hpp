// The daemon's `[creep]` section (docs/creep.md): every key of core::creep::CreepConfig, one
// struct member per key, plus `enabled`. The section adds one CreepModule to the engine.
//
// The four strategies an operator compares are expressed as:
//   no compensation        section absent, or `enabled = false`
//   step correction        profile = "step" (the prior art: the whole increment at once)
//   creeping               profile = "linear" | "cosine" | "smoothstep" | "table"
//   predictive creeping    a creeping profile and [creep.predict] enabled = true
//
// Errors name file:line:column and the key path; values are range-checked here, cross-field
// rules by core::creep::validate() (each issue's key mapped to its position), register names and
// kinds against [[registers]] in cross_check(). Not real-time.
#pragma once

#include <memory>
#include <string>

#include "core/creep/creep_module.hpp"
#include "daemon/config/config.hpp"
#include "formats/toml/key_positions.hpp"

namespace nccomp::daemon::sections {

struct CreepSection final : config::Section {
  /// false: the section is read and checked, but adds no module (no compensation).
  bool enabled{true};
  core::creep::CreepModuleConfig module;
  /// Absolute path of creep.edge.toolpath_file as read ("" = none).
  std::string toolpath_file;
  /// Position of the [creep] table and of every key below it ("creep.edge.edge_points",
  /// "creep.deflection[0].wear_um[2]"), for errors found after parsing.
  formats::Where where;
  formats::KeyPositions key_positions;
};

/// Parses one `[creep]` node. creep.edge.toolpath_file is relative to the directory of the file
/// that holds the table. Problems go to diag; the result is meaningful only if none was added.
std::unique_ptr<CreepSection> parse_creep_section(const toml::node& node,
                                                  formats::Diagnostics& diag);

/// The [creep] section of a loaded config (nullptr if absent).
const CreepSection* creep_section(const config::Config& config);

}  // namespace nccomp::daemon::sections
