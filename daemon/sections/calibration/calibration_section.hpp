// The daemon's `[calibration]` section (docs/calibration.md): parsed by
// formats::calib::parse_calibration() (the loader `nccomp calibrate` uses), registers
// checked against [[registers]] in cross_check(), one CalibrationModule added to the engine.
// Not real-time.
#pragma once

#include <memory>

#include "core/calib/config.hpp"
#include "daemon/config/config.hpp"
#include "formats/toml/key_positions.hpp"

namespace nccomp::daemon::sections {

struct CalibrationSection final : config::Section {
  core::calib::CalibrationConfig config;
  formats::Where where;
  formats::KeyPositions key_positions;
};

/// Parses one `[calibration]` node.
std::unique_ptr<CalibrationSection> parse_calibration_section(const toml::node& node,
                                                              formats::Diagnostics& diag);

/// The [calibration] section of a loaded config (nullptr if absent).
const CalibrationSection* calibration_section(const config::Config& config);

}  // namespace nccomp::daemon::sections
