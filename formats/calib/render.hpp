// Text for the operator, the same offline (`nccomp calibrate`) and against a running daemon
// (`nccomp calibrate --daemon`, answered by nccompd from the module's snapshot): the prompt's
// hint, the status block, alarms, test-grind results and the calibration summary.
#pragma once

#include <string>

#include "core/calib/snapshot.hpp"
#include "core/common/types.hpp"

namespace nccomp::formats::calib {

/// "X", "Y", "Z" for 0..2, "-" otherwise.
const char* axis_name(std::int32_t axis) noexcept;
/// "recalibration-implausible", ... (the names the docs use).
const char* alarm_name(core::AlarmCode code) noexcept;

/// What the operator should do next, one line (without the "-- ").
std::string hint(const core::calib::CalibSnapshot& s);
/// "  ALARM 40 recalibration-implausible axis Y: +59.000 um, nothing applied\n".
std::string alarm_line(const core::AlarmEvent& a);
/// "facets lateral: c+ ... -> grind-again, error ... ; grind again with dx ...\n" (no time).
std::string facet_line(core::calib::Face face, double chord_plus_mm, double chord_minus_mm,
                       const core::calib::FacetResult& r, core::calib::FacetRule rule);
/// "  reference touches: dx lateral ..." after the reference set.
std::string reference_line(const core::calib::CalibrationResult& r);
/// "  calibration: dxR ..." once complete.
std::string calibration_line(const core::calib::CalibrationResult& r);
/// "  nominals stored: ..." once the nominals are in.
std::string nominals_line(const core::calib::CalibState& s);
/// The status block: phase, calibration, per slot nominal / drift / prediction, registers.
/// `when` starts the first line ("[   123.0 s]" offline, the UTC time in the daemon).
std::string status_block(const core::calib::CalibSnapshot& s, const std::string& when);
/// "2026-11-22 06:12:03 UTC" (wall clock [Unix s]); "never" for NaN.
std::string format_utc(double wall_s);

}  // namespace nccomp::formats::calib
