// GIVEN every alarm code the core raises, WHEN the daemon logs or reports it, THEN it has its
// own documented name (docs/*.md alarm tables), not the "code_N" fallback.
#include <gtest/gtest.h>

#include <set>
#include <string>
#include <utility>
#include <vector>

#include "daemon/logging.hpp"

namespace nccomp::daemon {
namespace {

using core::AlarmCode;

TEST(AlarmNames, EveryCodeHasItsDocumentedName) {
  const std::vector<std::pair<AlarmCode, std::string>> expected{
      {AlarmCode::kOffsetNonFinite, "offset_non_finite"},
      {AlarmCode::kOffsetBeyondAbsoluteLimit, "offset_beyond_absolute_limit"},
      {AlarmCode::kOffsetSlewLimited, "offset_slew_limited"},
      {AlarmCode::kCreepUnfinished, "creep_unfinished"},
      {AlarmCode::kToolLifeReached, "tool_life_reached"},
      {AlarmCode::kToolExcessivelyWorn, "tool_excessively_worn"},
      {AlarmCode::kToolBrokenOrMismeasured, "tool_broken_or_mismeasured"},
      {AlarmCode::kMeasurementDue, "measurement_due"},
      {AlarmCode::kProbeImplausible, "probe_implausible"},
      {AlarmCode::kProbeOutlier, "probe_outlier"},
      {AlarmCode::kProbeInvalidInput, "probe_invalid_input"},
      {AlarmCode::kCheckpointRegisterMismatch, "checkpoint_register_mismatch"},
      {AlarmCode::kCheckpointMissed, "checkpoint_missed"},
      {AlarmCode::kRecalibrationImplausible, "recalibration_implausible"},
      {AlarmCode::kTouchScatter, "touch_scatter"},
      {AlarmCode::kRecalibrationDue, "recalibration_due"},
      {AlarmCode::kTouchSetIncomplete, "touch_set_incomplete"},
      {AlarmCode::kCalibrationOutOfRange, "calibration_out_of_range"},
      {AlarmCode::kTouchUnexpected, "touch_unexpected"},
      {AlarmCode::kTestGrindNotConverging, "test_grind_not_converging"},
      {AlarmCode::kRecalibrationApplied, "recalibration_applied"},
      {AlarmCode::kCalibrationComplete, "calibration_complete"},
      {AlarmCode::kCalibrationInvalidInput, "calibration_invalid_input"},
      {AlarmCode::kStateCorrupt, "state_corrupt"},
      {AlarmCode::kEventInvalid, "event_invalid"},
      {AlarmCode::kRegisterUnknown, "register_unknown"},
      {AlarmCode::kOffsetWriteDropped, "offset_write_dropped"},
  };
  std::set<std::string> seen;
  for (const auto& [code, name] : expected) {
    EXPECT_EQ(alarm_name(code), name) << static_cast<unsigned>(code);
    EXPECT_TRUE(seen.insert(name).second) << name;
  }
  // A value outside the enum (a corrupt state file) still prints usefully.
  EXPECT_EQ(alarm_name(static_cast<AlarmCode>(77)), "code_77");
}

}  // namespace
}  // namespace nccomp::daemon
