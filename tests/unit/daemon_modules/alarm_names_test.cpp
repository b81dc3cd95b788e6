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
      {AlarmCode::kBusAlarm, "bus_alarm"},
      {AlarmCode::kRegisterBeyondLimit, "register_beyond_limit"},
      {AlarmCode::kRegisterAdopted, "register_adopted"},
      {AlarmCode::kRegisterHeldWithoutState, "register_held_without_state"},
  };
  std::set<std::string> seen;
  for (const auto& [code, name] : expected) {
    EXPECT_EQ(alarm_name(code), name) << static_cast<unsigned>(code);
    EXPECT_TRUE(seen.insert(name).second) << name;
  }
  // A value outside the enum (a corrupt state file) still prints usefully.
  EXPECT_EQ(alarm_name(static_cast<AlarmCode>(77)), "code_77");
}

// GIVEN two buses whose alarm flags rise and fall, WHEN the daemon's main thread looks at their
// status every pass, THEN each rise is reported once as an alarm bus_alarm (54, subject = the
// bus's index, value 1) and each fall once as info (value 0), with a log line naming the bus,
// its link state and why; a flag that stays as it was reports nothing.
TEST(BusAlarmWatch, ReportsEachRiseAndFallOnceWithBusLinkStateAndReason) {
  const std::vector<std::string> names{"can", "modbus"};
  std::vector<drivers::BusStatus> st(2);
  st[0].state = drivers::LinkState::kUp;
  st[1].state = drivers::LinkState::kUp;
  BusAlarmWatch w;
  EXPECT_TRUE(w.update(names, st, 1000).empty());

  // Modbus link down beyond alarm_after_s.
  st[1].state = drivers::LinkState::kDown;
  EXPECT_TRUE(w.update(names, st, 2000).empty());  // down, not yet in alarm: nothing
  st[1].alarm = true;
  st[1].counters.offsets_written = 12;
  st[1].counters.reconnects = 3;
  auto c = w.update(names, st, 3000);
  ASSERT_EQ(c.size(), 1U);
  EXPECT_EQ(c[0].event.code, AlarmCode::kBusAlarm);
  EXPECT_EQ(static_cast<unsigned>(c[0].event.code), 54U);
  EXPECT_EQ(c[0].event.severity, core::Severity::kAlarm);
  EXPECT_EQ(c[0].event.subject, 1);
  EXPECT_EQ(c[0].event.value, 1.0);
  EXPECT_EQ(c[0].event.time_ns, 3000);
  EXPECT_EQ(c[0].message,
            "bus modbus: ALARM: offsets may not reach the NC: the link is not up beyond "
            "alarm_after_s (link down; offsets written 12, retried 0, failed 0; reconnects 3)");
  EXPECT_TRUE(w.update(names, st, 4000).empty());  // still in alarm: reported once

  // CAN: an offset write given up after its retries, on an up link.
  st[0].alarm = true;
  st[0].counters.offsets_failed = 1;
  st[0].counters.offsets_retried = 3;
  c = w.update(names, st, 5000);
  ASSERT_EQ(c.size(), 1U);
  EXPECT_EQ(c[0].event.subject, 0);
  EXPECT_EQ(c[0].message,
            "bus can: ALARM: offsets may not reach the NC: an offset write failed or was refused "
            "(link up; offsets written 0, retried 3, failed 1; reconnects 0)");

  // Both clear in the same pass: two info events, value 0, in bus order.
  st[0].alarm = false;
  st[1].alarm = false;
  st[1].state = drivers::LinkState::kUp;
  st[1].counters.offsets_written = 13;
  c = w.update(names, st, 6000);
  ASSERT_EQ(c.size(), 2U);
  EXPECT_EQ(c[0].event.severity, core::Severity::kInfo);
  EXPECT_EQ(c[0].event.value, 0.0);
  EXPECT_EQ(c[0].event.subject, 0);
  EXPECT_EQ(c[1].event.subject, 1);
  EXPECT_EQ(c[1].event.code, AlarmCode::kBusAlarm);
  EXPECT_EQ(c[1].message,
            "bus modbus: alarm cleared (link up; offsets written 13, retried 0, failed 0; "
            "reconnects 3)");
  EXPECT_TRUE(w.update(names, st, 7000).empty());

  // An old failure does not explain a later alarm: a write undelivered on an up link.
  st[0].alarm = true;
  c = w.update(names, st, 8000);
  ASSERT_EQ(c.size(), 1U);
  EXPECT_NE(c[0].message.find("an offset write is undelivered beyond alarm_after_s (link up"),
            std::string::npos)
      << c[0].message;
}

}  // namespace
}  // namespace nccomp::daemon
