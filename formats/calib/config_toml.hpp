// The `[calibration]` TOML table → core::calib::CalibrationConfig, key for key (docs/
// calibration.md). Wrong types, out-of-range values and unknown keys, then
// core::calib::validate()'s issues, are reported at their key's file, line and column, all of them.
// Read by the daemon's [calibration] section and by `nccomp calibrate`. Not real-time.
#pragma once

#include <toml++/toml.h>

#include <string>
#include <string_view>

#include "core/calib/config.hpp"
#include "formats/toml/diagnostics.hpp"

namespace nccomp::formats::calib {

/// Reads the [calibration] node (a table) and validates the result; every problem goes to diag.
/// The result is meaningful only if diag got no error.
core::calib::CalibrationConfig parse_calibration(const toml::node& calibration, Diagnostics& diag);

/// Reads root["calibration"] (missing table: all defaults, validated).
core::calib::CalibrationConfig parse_calibration_table(const toml::table& root, Diagnostics& diag);

/// Parses TOML text (source names it in errors) and loads its [calibration] table. Throws
/// DiagnosticsError with every error.
core::calib::CalibrationConfig load_calibration_config_text(std::string_view text,
                                                            const std::string& source);
/// Reads and loads a TOML file. Throws DiagnosticsError with every error.
core::calib::CalibrationConfig load_calibration_config_file(const std::string& path);

}  // namespace nccomp::formats::calib
