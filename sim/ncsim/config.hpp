// Parsing of ncsim's TOML config (docs/ncsim.md) with --set overrides. Not real-time.
// Read with formats/ TableReader: every refusal names file:line:column and the key path, unknown
// keys are errors, and every error of a config is reported (formats::DiagnosticsError), not only
// the first. Data files the
// config names (the bus map, PHM 2010 wear curves, FL_THERMAL drift, the [checkpoints] table,
// roll trajectories) are read and validated here, so the model itself does no I/O.
#pragma once

#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "formats/toml/diagnostics.hpp"
#include "sim/ncsim/sim_config.hpp"

namespace nccomp::sim::ncsim {

/// Parses config text; base_dir resolves relative paths. overrides are "path=value" strings
/// (`--set`): a path whose first part names an effect is taken under [effects]
/// (`wear.rate_um_per_m=3`), any other path from the top (`ncsim.seed=4`). value is a TOML
/// value; anything that does not parse as one is taken as a string.
/// read_files = false checks the text only: no data file named in it is opened (fuzzing).
/// program: read only that program's data files (a side-wall plan is not needed to machine a
/// mould face); nullopt reads every program's. Throws formats::DiagnosticsError.
SimConfig parse_sim_config(std::string_view text, const std::string& file,
                           const std::string& base_dir,
                           const std::vector<std::string>& overrides = {}, bool read_files = true,
                           std::optional<ProgramKind> program = std::nullopt);
/// Reads and parses a file. Throws formats::DiagnosticsError.
SimConfig load_sim_config(const std::string& path, const std::vector<std::string>& overrides = {},
                          std::optional<ProgramKind> program = std::nullopt);

/// Reads a numeric CSV with a header; returns the named columns. Throws formats::DiagnosticsError
/// naming file:line. Used for the PHM 2010 and FL_THERMAL files and the roll trajectory / profile.
std::vector<std::vector<double>> read_csv_columns(const std::string& path,
                                                  const std::vector<std::string>& columns);

std::string_view program_name(ProgramKind p) noexcept;
std::string_view bus_name(BusKind b) noexcept;

}  // namespace nccomp::sim::ncsim
