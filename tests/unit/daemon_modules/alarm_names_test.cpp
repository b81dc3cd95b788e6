// GIVEN every alarm code the core raises, WHEN the daemon logs or reports it, THEN it has its
// own documented name (docs/*.md alarm tables), not the "code_N" fallback.
#include <gtest/gtest.h>

#include <limits>
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
      {AlarmCode::kMeasurementNoiseInconsistent, "measurement_noise_inconsistent"},
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
      {AlarmCode::kBusInputStale, "bus_input_stale"},
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

// Issue 17, finding 4. GIVEN a Modbus bus whose NC answers every read with an exception (link
// "degraded", never down), WHEN its driver sets input_stale (degraded beyond
// degraded_alarm_after_s), THEN the main thread reports bus_input_stale (55, subject the bus,
// value 1, severity alarm) once with a line naming the bus, its link state and counters, nothing
// while it stays, and on the fall one info (value 0) with how long it lasted and the faults and
// malformed frames meanwhile; the offset alarm (54) is tracked apart.
TEST(BusAlarmWatch, InputStaleRisesAndFallsOnceWithWhatHappenedMeanwhile) {
  const std::vector<std::string> names{"modbus"};
  std::vector<drivers::BusStatus> st(1);
  st[0].state = drivers::LinkState::kDegraded;
  st[0].counters.frames_rx = 100;
  st[0].counters.faults = 40;
  BusAlarmWatch w;
  EXPECT_TRUE(w.update(names, st, 1'000'000'000).empty());
  st[0].input_stale = true;
  auto c = w.update(names, st, 2'000'000'000);
  ASSERT_EQ(c.size(), 1U);
  EXPECT_EQ(c[0].event.code, AlarmCode::kBusInputStale);
  EXPECT_EQ(static_cast<unsigned>(c[0].event.code), 55U);
  EXPECT_EQ(c[0].event.severity, core::Severity::kAlarm);
  EXPECT_EQ(c[0].event.subject, 0);
  EXPECT_EQ(c[0].event.value, 1.0);
  EXPECT_EQ(c[0].message,
            "bus modbus: ALARM: input from the NC is stale: the link not healthy or no valid axis "
            "sample for longer than degraded_alarm_after_s; positions and measurements are not "
            "arriving (link degraded; frames rx 100, faults 40, malformed 0; its counters in "
            "`nccomp status`)");
  st[0].counters.frames_rx = 160;
  st[0].counters.faults = 100;
  EXPECT_TRUE(w.update(names, st, 3'000'000'000).empty());
  st[0].alarm = true;  // the offset alarm too: its own report
  c = w.update(names, st, 3'500'000'000);
  ASSERT_EQ(c.size(), 1U);
  EXPECT_EQ(c[0].event.code, AlarmCode::kBusAlarm);
  st[0].alarm = false;
  st[0].input_stale = false;
  st[0].state = drivers::LinkState::kUp;
  st[0].counters.faults = 130;
  st[0].counters.frames_rx = 200;
  c = w.update(names, st, 9'250'000'000);
  ASSERT_EQ(c.size(), 2U);
  EXPECT_EQ(c[0].event.code, AlarmCode::kBusInputStale);
  EXPECT_EQ(c[0].event.severity, core::Severity::kInfo);
  EXPECT_EQ(c[0].event.value, 0.0);
  EXPECT_EQ(c[0].message,
            "bus modbus: input stale cleared after 7.2 s (link up; meanwhile faults 90, "
            "malformed 0, frames rx 100)");
  EXPECT_EQ(c[1].event.code, AlarmCode::kBusAlarm);
  EXPECT_TRUE(w.update(names, st, 10'000'000'000).empty());
}

// Issue 17, finding 4: logged once per burst. GIVEN the log's burst filter, WHEN the same alarm
// (NaN measurement of tool 5) comes 5 times 100 ms apart, THEN only the first is logged and,
// 2 s after the last, one end line says 5 in 0.4 s; a different value, subject or code is its
// own burst; info lines are always logged; a clear (info, same code and subject) ends the rise's
// burst at once, so a new rise is logged; a single alarm gives no end line.
TEST(AlarmBursts, OneLineWhenABurstStartsAndOneWithTheCountWhenItEnds) {
  using Burst = AlarmBursts::Burst;
  constexpr core::TimeNs kMs = 1'000'000;
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const core::AlarmEvent broken{0, core::Severity::kAlarm, AlarmCode::kToolBrokenOrMismeasured, 5,
                                nan};
  AlarmBursts b;
  std::vector<Burst> ended;
  int logged = 0;
  for (int k = 0; k < 5; ++k) {
    logged += b.add(broken, k * 100 * kMs, ended) ? 1 : 0;
  }
  EXPECT_EQ(logged, 1);
  core::AlarmEvent other = broken;
  other.subject = 6;
  EXPECT_TRUE(b.add(other, 450 * kMs, ended));
  other = broken;
  other.value = 1.0;
  EXPECT_TRUE(b.add(other, 460 * kMs, ended));
  const core::AlarmEvent due{0, core::Severity::kInfo, AlarmCode::kMeasurementDue, 5, 1.0};
  EXPECT_TRUE(b.add(due, 470 * kMs, ended));
  EXPECT_TRUE(b.add(due, 480 * kMs, ended));
  b.expire(2399 * kMs, ended);
  EXPECT_TRUE(ended.empty());
  b.expire(2400 * kMs, ended);
  ASSERT_EQ(ended.size(), 1U);
  EXPECT_EQ(ended[0].count, 5U);
  EXPECT_EQ(burst_end_line(ended[0]),
            "end of burst: tool_broken_or_mismeasured (code 23, alarm) subject 5 value nan: 5 in "
            "0.4 s (only the first was logged)");
  ended.clear();
  b.expire(5000 * kMs, ended);  // the single ones end without a line
  EXPECT_TRUE(ended.empty());

  const core::AlarmEvent rise{0, core::Severity::kAlarm, AlarmCode::kBusInputStale, 0, 1.0};
  const core::AlarmEvent clear{0, core::Severity::kInfo, AlarmCode::kBusInputStale, 0, 0.0};
  EXPECT_TRUE(b.add(rise, 6000 * kMs, ended));
  EXPECT_FALSE(b.add(rise, 6100 * kMs, ended));
  EXPECT_TRUE(b.add(clear, 6200 * kMs, ended));
  ASSERT_EQ(ended.size(), 1U);
  EXPECT_EQ(ended[0].count, 2U);
  EXPECT_TRUE(b.add(rise, 6300 * kMs, ended));
  ended.clear();
  EXPECT_FALSE(b.add(rise, 6400 * kMs, ended));
  b.expire(std::numeric_limits<core::TimeNs>::max(), ended);  // the logger stops
  ASSERT_EQ(ended.size(), 1U);
  EXPECT_EQ(ended[0].count, 2U);
}

}  // namespace
}  // namespace nccomp::daemon
