// The `[checkpoints]` table of the operator config (docs/checkpoints.md) → the S1 plan and
// compensator configs, one key per struct member. Read by `nccomp plan`, the daemon's
// [checkpoints] section and ncsim, so that all of them agree on the plan. Every problem is
// reported at its file:line:column and key path, all of them. Not real-time.
#pragma once

#include <toml++/toml.h>

#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "core/checkpoint/compensator.hpp"
#include "core/checkpoint/module.hpp"
#include "core/checkpoint/plan.hpp"
#include "formats/toml/diagnostics.hpp"

namespace nccomp::formats::checkpoints {

/// `[checkpoints.gcode]`: how `nccomp plan` writes the probing program (never read by the daemon).
struct GcodeConfig {
  /// Program number of the probing program (O-number).
  int program_number{9100};
  /// Program number of the measuring macro called with G65 P<macro_program>.
  int macro_program{9860};
  /// Clearance height for moves between checkpoints [mm].
  double safe_z_mm{50.0};
  /// Feed of the descent to the probing height [mm/min].
  double feed_mm_per_min{2000.0};
  /// First NC variable of the checkpoint table, for the comments only (e.g. 12020 = Fanuc D20
  /// radius wear in offset memory C); 0 = no comments.
  int nc_variable_first{0};
};

struct CheckpointsConfig {
  core::checkpoint::PlanConfig plan;
  core::checkpoint::CompensatorConfig compensator;
  GcodeConfig gcode;
  /// Where the contour came from ("<file>:<line>" of the inline array, or the CSV path).
  std::string contour_source;
};

/// Parses the `[checkpoints]` table (unknown keys are errors); `file` names the inline contour's
/// source. A relative contour_csv is resolved against base_dir. Every problem goes to diag
/// (parsing goes on after one); the result is valid only if diag got none. Then the plan is built
/// once (make_plan) and the compensator validated, their issues reported at their keys.
/// contour_csv_override (if set) replaces the table's contour / contour_csv keys.
CheckpointsConfig parse_checkpoints(
    const toml::table& table, const std::string& file, const std::filesystem::path& base_dir,
    Diagnostics& diag, const std::optional<std::string>& contour_csv_override = std::nullopt);

/// Loads `path`, takes its `[checkpoints]` table and parses it; contour_csv_override (if set)
/// replaces the contour. Throws DiagnosticsError with every error.
CheckpointsConfig load_checkpoints_file(const std::string& path,
                                        const std::optional<std::string>& contour_csv_override);

/// The engine module for a parsed config (what a daemon config section adds to the engine):
/// builds the plan; the module checks its registers when the engine attaches it. Not real-time.
std::unique_ptr<core::checkpoint::CheckpointModule> make_checkpoint_module(
    const CheckpointsConfig& config);

/// Reads a contour CSV file (core::checkpoint::parse_contour_csv); throws std::invalid_argument
/// naming the file (and line).
std::vector<core::checkpoint::ContourPoint> read_contour_csv(const std::filesystem::path& path);

}  // namespace nccomp::formats::checkpoints
