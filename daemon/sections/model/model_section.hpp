// The daemon's `[model]` section (docs/config.md): the model.toml `nccomp analyze` wrote, loaded
// with its reader (tools/analyze model_io), and `[[model.apply]]` entries mapping fitted terms onto
// registers as additive trims (ModelModule). Not real-time.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "core/model/model.hpp"
#include "core/model/model_module.hpp"
#include "daemon/config/config.hpp"
#include "daemon/sections/model/model_choice.hpp"
#include "daemon/sections/model/shadow.hpp"

namespace nccomp::daemon::sections {

struct ModelApplyConfig {
  std::string term;
  std::string register_name;
  core::model::ModelApply apply;  // register_index resolved in cross_check() / add_modules()
  formats::Where where;
};

struct ModelInputConfig {
  std::string column;
  core::model::ModelInput input;  // column resolved against the model's extra columns
  formats::Where where;
};

struct ModelSection final : config::Section {
  std::string file;  // resolved path of model.toml in force ("" with disabled)
  /// The configuration's own `file` (resolved); file differs when the operator's choice
  /// (model_choice.hpp: `nccomp model load` / `rollback`) replaces it.
  std::string configured_file;
  bool chosen{false};
  /// The operator's choice is no model (rolled back to none): the section adds no module.
  bool disabled{false};
  core::model::Model model;
  bool loaded{false};
  bool each_cycle{false};
  /// Kept for configs of the first version: if given it must be the sensor the measurement log
  /// records as temp_c ([measurement_context] temperature_sensor), the one temp_c terms were
  /// fitted on.
  int temperature_sensor{-1};
  bool has_temperature_sensor{false};
  formats::Where temperature_where;
  std::vector<ModelApplyConfig> applies;
  std::vector<ModelInputConfig> inputs;
  /// [model.shadow]: the rule for a candidate (`nccomp model candidate`).
  ShadowOptions shadow;
  formats::Where where;
};

/// Parses one `[model]` node; `file` is relative to the file holding the table.
std::unique_ptr<ModelSection> parse_model_section(const toml::node& node,
                                                  formats::Diagnostics& diag);

/// The [model] section of a loaded config (nullptr if absent).
const ModelSection* model_section(const config::Config& config);

/// The engine module of a parsed section, registers resolved against `registers` (throws
/// std::invalid_argument naming the entry when a register is missing).
std::unique_ptr<core::model::ModelModule> make_model_module(
    const ModelSection& s, const std::vector<core::engine::RegisterSpec>& registers);

}  // namespace nccomp::daemon::sections
