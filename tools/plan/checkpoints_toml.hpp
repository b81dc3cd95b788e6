// The `[checkpoints]` table of the operator config (docs/checkpoints.md) → the S1 plan and
// compensator configs, one key per struct member. Shared by `nccomp plan` and, through the
// library nccomp_checkpoints_toml, by whatever loads the daemon's config. Not real-time.
#pragma once

#include <toml++/toml.h>

#include <filesystem>
#include <optional>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

#include <memory>

#include "core/checkpoint/compensator.hpp"
#include "core/checkpoint/module.hpp"
#include "core/checkpoint/plan.hpp"

namespace nccomp::tools::checkpoints {

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

/// One problem in the config: position in the file, key path, message.
struct ConfigIssue {
  std::string file;
  int line{0};
  int column{0};
  std::string key_path;
  std::string message;
};

/// "file:line:column: key.path: message".
std::string format_issue(const ConfigIssue& issue);

/// Thrown by load_checkpoints_file with every issue, one per line.
class ConfigError : public std::runtime_error {
 public:
  explicit ConfigError(std::vector<ConfigIssue> issues);
  [[nodiscard]] const std::vector<ConfigIssue>& issues() const noexcept { return issues_; }

 private:
  std::vector<ConfigIssue> issues_;
};

/// Parses the `[checkpoints]` table (unknown keys are issues). A relative contour_csv is
/// resolved against base_dir. Problems are appended to issues (parsing goes on after one, so the
/// operator sees all of them); the returned value is valid only if no issue was added. Then the
/// plan is built once (make_plan) and the compensator validated, and their errors are issues too.
/// contour_csv_override (if set) replaces the table's contour / contour_csv keys.
CheckpointsConfig parse_checkpoints(
    const toml::table& table, const std::string& file, const std::filesystem::path& base_dir,
    std::vector<ConfigIssue>& issues,
    const std::optional<std::string>& contour_csv_override = std::nullopt);

/// Loads `path`, takes its `[checkpoints]` table and parses it; contour_csv_override (if set)
/// replaces the contour. Throws ConfigError.
CheckpointsConfig load_checkpoints_file(const std::string& path,
                                        const std::optional<std::string>& contour_csv_override);

/// The engine module for a parsed config (what a daemon config section adds to the engine):
/// builds the plan; the module checks its registers when the engine attaches it. Not real-time.
std::unique_ptr<core::checkpoint::CheckpointModule> make_checkpoint_module(
    const CheckpointsConfig& config);

/// Reads a contour CSV file (core::checkpoint::parse_contour_csv); throws std::invalid_argument
/// naming the file (and line).
std::vector<core::checkpoint::ContourPoint> read_contour_csv(const std::filesystem::path& path);

}  // namespace nccomp::tools::checkpoints
