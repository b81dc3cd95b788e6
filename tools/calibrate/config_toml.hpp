// The `[calibration]` TOML table → core::calib::CalibrationConfig, key for key (docs/
// calibration.md). Unknown keys, wrong types and out-of-range values are refused with the file,
// line and key path. The daemon's config loader can call load_calibration_table() on its parsed
// root table.
#pragma once

#include <string>

#include <toml++/toml.h>

#include "core/calib/config.hpp"

namespace nccomp::tools::calibrate {

/// Reads root["calibration"] (missing table: all defaults) and validates the result. Throws
/// std::invalid_argument "<source>:<line>: calibration.<key>: <why>".
core::calib::CalibrationConfig load_calibration_table(const toml::table& root,
                                                      const std::string& source);
/// The same for the [calibration] node itself (the daemon's config loader hands a section its
/// node, not the root). Throws std::invalid_argument "<source>:<line>: calibration.<key>: <why>".
core::calib::CalibrationConfig load_calibration_node(const toml::node& calibration,
                                                     const std::string& source);
/// Parses TOML text (source names it in errors) and loads its [calibration] table.
core::calib::CalibrationConfig load_calibration_config_text(std::string_view text,
                                                            const std::string& source);
/// Reads and loads a TOML file.
core::calib::CalibrationConfig load_calibration_config_file(const std::string& path);

}  // namespace nccomp::tools::calibrate
