// Recalibration (S3 "recalibration", issue items 3 and 4): drift = touch − nominal, crept in,
// predicted between touches, implausible sets refused.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "core/calib/calibrator.hpp"
#include "tests/support/alloc_counter.hpp"
#include "tests/unit/calib/sim_machine.hpp"
#include "tests/unit/calib/test_config.hpp"

namespace nccomp::test::calib {
namespace {

using core::AlarmCode;
using core::Event;
using core::StepOutput;
using core::TimeNs;
using core::calib::CalibrationConfig;
using core::calib::Calibrator;
using core::calib::Phase;
using core::calib::Prediction;
using core::calib::Slot;

bool has_alarm(const StepOutput& out, AlarmCode code) {
  return std::any_of(out.alarms.begin(), out.alarms.end(),
                     [code](const core::AlarmEvent& a) { return a.code == code; });
}

// Warm-up drift of a first-order machine: X 30 µm, τ = 1.5 h.
std::array<double, 4> warmup(double t_s) {
  const double f = 1.0 - std::exp(-t_s / 5400.0);
  return {30.0 * f, 34.0 * f, -12.0 * f, 18.0 * f};
}

struct ShiftError {
  double rms_um{0.0};
  double max_um{0.0};
  double max_write_change_um{0.0};
  double end_error_um{0.0};
};

// Calibrates at t = 0 (cold), then runs `hours` with a touch set every `interval_s`, stepping
// once per second; returns the X error (true drift − drift correction) over the run.
ShiftError run_shift(CalibrationConfig cfg, double hours, double interval_s, bool recalibrate) {
  cfg.touches_per_axis = 1;
  cfg.recalibration_interval_s = interval_s;
  Calibrator c;
  c.configure(cfg);
  SimMachine m(cfg, test_errors(), 0.3, 0.3, 0.1, 3);
  TimeNs now = 0;
  StepOutput out;
  EXPECT_TRUE(run_initial_calibration(c, m, now, out));
  for (int i = 0; i < 60; ++i) {  // the limiter slews the registers to the calibration values
    out.clear();
    c.step(now, {}, out);
    now += core::from_seconds(1.0);
  }
  const double t0 = core::seconds(now);
  m.set_drift([t0](double t) { return warmup(t - t0); });
  ShiftError e;
  double sum2 = 0.0;
  std::size_t n = 0;
  double last_written = c.written_um(0);
  const auto steps = static_cast<long>(hours * 3600.0);
  const auto every = static_cast<long>(interval_s);
  for (long s = 0; s < steps; ++s) {
    const auto t = static_cast<double>(s);
    now = core::from_seconds(t0 + t);
    out.clear();
    if (recalibrate && s > 0 && s % every == 0) {
      run_touch_set(c, m, now, out);
    } else {
      c.step(now, {}, out);
    }
    for (const auto& w : out.writes) {
      if (w.register_index == cfg.register_x) {
        if (std::isfinite(last_written)) {
          e.max_write_change_um =
              std::max(e.max_write_change_um, std::fabs(w.value_um - last_written));
        }
        last_written = w.value_um;
      }
    }
    if (s < every) {
      continue;  // before the first touch every strategy is uncorrected; compare after it
    }
    const double err = m.drift_um(t0 + t)[0] - c.drift_correction_um(Slot::kXLateral, now);
    sum2 += err * err;
    ++n;
    e.max_um = std::max(e.max_um, std::fabs(err));
    e.end_error_um = err;
  }
  e.rms_um = std::sqrt(sum2 / static_cast<double>(n));
  return e;
}

TEST(Recalibration, TracksWarmUpDrift) {
  auto cfg = test_config();
  cfg.prediction = Prediction::kTime;
  cfg.thermal_time_constant_s = 5400.0;
  const ShiftError none = run_shift(cfg, 4.0, 3600.0, false);
  cfg.creep_shape = core::ProfileShape::kStep;
  cfg.prediction = Prediction::kNone;
  const ShiftError step = run_shift(cfg, 4.0, 3600.0, true);
  cfg.creep_shape = core::ProfileShape::kCosine;
  cfg.prediction = Prediction::kTime;
  const ShiftError predicted = run_shift(cfg, 4.0, 3600.0, true);
  // Without recalibration the error is the drift itself (30 µm · (1 − e^(−4/1.5)) at the end).
  EXPECT_NEAR(none.max_um, 30.0 * (1.0 - std::exp(-4.0 / 1.5)), 0.1);
  RecordProperty("rms_none_um", std::to_string(none.rms_um));
  RecordProperty("rms_step_um", std::to_string(step.rms_um));
  RecordProperty("rms_predicted_um", std::to_string(predicted.rms_um));
  // Hourly steps halve it roughly; prediction tracks the drift to within a couple of µm.
  EXPECT_LT(step.rms_um, 0.6 * none.rms_um);
  EXPECT_LT(predicted.rms_um, 0.75 * step.rms_um);
  // Just before the next touch the held step correction lags by the last hour's drift (2 µm);
  // the prediction is within the touch noise.
  EXPECT_GT(std::fabs(step.end_error_um), 1.5);
  EXPECT_LT(std::fabs(predicted.end_error_um), 1.0);
  // Creeping: no write jumps by more than the slope of the creep allows (step corrections jump
  // by the limiter's max_step_um).
  EXPECT_LT(predicted.max_write_change_um, 0.5);
  EXPECT_GT(step.max_write_change_um, 2.0);
}

// GIVEN the first-order time model (τ = 30 min) and a touch set 60 s after the nominals that
// measures 0.9 µm (what touch noise looks like: the machine has not drifted), THEN the prediction
// an hour later stays at that reading: two sets that close fix the asymptote only with their
// noise amplified 1 / (1 − e^(−60/1800)) = 30 times (it ran to the plausibility bound before:
// the e2e's Y axis had 18 µm of error after an operator's on-demand recalibration).
TEST(Recalibration, TwoCloseTouchSetsDoNotExtrapolateTheirNoise) {
  auto cfg = test_config();
  cfg.prediction = Prediction::kTime;
  cfg.thermal_time_constant_s = 1800.0;
  cfg.touches_per_axis = 1;
  cfg.recalibration_interval_s = 900.0;
  Calibrator c;
  c.configure(cfg);
  SimMachine m(cfg, test_errors(), 0.0, 0.0, 0.1, 3);
  TimeNs now = 0;
  StepOutput out;
  ASSERT_TRUE(run_initial_calibration(c, m, now, out));
  for (int i = 0; i < 60; ++i) {
    out.clear();
    c.step(now, {}, out);
    now += core::from_seconds(1.0);
  }
  m.set_drift([](double) { return std::array<double, 4>{0.9, 0.9, 0.9, 0.9}; });
  out.clear();
  run_touch_set(c, m, now, out);
  for (int i = 0; i < 3600; ++i) {
    now += core::from_seconds(1.0);
    out.clear();
    c.step(now, {}, out);
  }
  for (const Slot s : {Slot::kXLateral, Slot::kY, Slot::kZ}) {
    EXPECT_NEAR(c.predicted_drift_um(s, now), 0.9, 1.0) << static_cast<int>(s);
  }
}

TEST(Recalibration, TemperatureModelLearnsTheSlope) {
  auto cfg = test_config();
  cfg.prediction = Prediction::kTemperature;
  cfg.temperature_sensor = 0;
  cfg.touches_per_axis = 1;
  Calibrator c;
  c.configure(cfg);
  SimMachine m(cfg, test_errors(), 0.0, 0.0, 0.1, 3);
  TimeNs now = 0;
  StepOutput out;
  double temp = 20.0;
  const auto feed_temp = [&](TimeNs t) {
    const Event e = core::TemperatureSample{t, 0, temp};
    out.clear();
    c.step(t, {&e, 1}, out);
  };
  feed_temp(now);
  ASSERT_TRUE(run_initial_calibration(c, m, now, out));
  // X drifts 2.5 µm/°C with the temperature.
  m.set_drift([&temp](double) {
    return std::array<double, 4>{2.5 * (temp - 20.0), 0.0, 0.0, 0.0};
  });
  for (const double t_c : {22.0, 24.0}) {
    temp = t_c;
    now += core::from_seconds(3600.0);
    feed_temp(now);
    out.clear();
    run_touch_set(c, m, now, out);
    EXPECT_FALSE(has_alarm(out, AlarmCode::kRecalibrationImplausible));
  }
  EXPECT_NEAR(c.model(Slot::kXLateral).slope_um_per_c, 2.5, 1e-6);
  // Between touches the correction follows the temperature.
  temp = 25.0;
  now += core::from_seconds(600.0);
  feed_temp(now);
  EXPECT_NEAR(c.predicted_drift_um(Slot::kXLateral, now), 12.5, 1e-6);
}

TEST(Recalibration, ImplausibleChangeRaisesAlarmAndAppliesNothing) {
  auto cfg = test_config();
  cfg.touches_per_axis = 1;
  Calibrator c;
  c.configure(cfg);
  SimMachine m(cfg, test_errors(), 0.0, 0.0, 0.1, 3);
  TimeNs now = 0;
  StepOutput out;
  ASSERT_TRUE(run_initial_calibration(c, m, now, out));
  // A crashed probe: Y reads 60 µm off (> 50 µm plausibility bound).
  m.set_drift([](double) { return std::array<double, 4>{1.0, 1.0, 60.0, 1.0}; });
  now += core::from_seconds(1800.0);
  const double target_before = c.target_um(1, now);
  const auto model_before = c.model(Slot::kY);
  out.clear();
  run_touch_set(c, m, now, out);
  ASSERT_TRUE(has_alarm(out, AlarmCode::kRecalibrationImplausible));
  for (const auto& a : out.alarms) {
    if (a.code == AlarmCode::kRecalibrationImplausible) {
      EXPECT_EQ(a.subject, 1);
      EXPECT_NEAR(a.value, 60.0, 1e-6);
    }
  }
  EXPECT_FALSE(has_alarm(out, AlarmCode::kRecalibrationApplied));
  EXPECT_TRUE(out.records.empty());
  EXPECT_DOUBLE_EQ(c.target_um(1, now), target_before);
  EXPECT_EQ(c.model(Slot::kY).touch_sets, model_before.touch_sets);
  // X was plausible but nothing of the set is applied either.
  EXPECT_DOUBLE_EQ(c.model(Slot::kXLateral).anchor_drift_um, 0.0);
}

// GIVEN a machine calibrated with max_abs_um 45 (X's base value 23 µm) WHEN a plausible touch set
// (X drifted 25 µm, within the 45 µm plausibility bound) would move X to 48 µm THEN the set raises
// offset_beyond_absolute_limit and applies nothing, on any axis.
TEST(Recalibration, ASetThatWouldMoveAnAxisBeyondTheLimitAppliesNothing) {
  auto cfg = test_config();
  cfg.touches_per_axis = 1;
  cfg.max_abs_um = 45.0;
  cfg.plausibility_um = 45.0;  // may not exceed max_abs_um
  Calibrator c;
  c.configure(cfg);
  SimMachine m(cfg, test_errors(), 0.0, 0.0, 0.1, 3);
  TimeNs now = 0;
  StepOutput out;
  ASSERT_TRUE(run_initial_calibration(c, m, now, out));
  const double base_x = c.target_um(0, now);
  ASSERT_NEAR(base_x, test_errors().ex_um, 1e-6);
  const double drift_x = cfg.max_abs_um - base_x + 3.0;
  ASSERT_LT(drift_x, cfg.plausibility_um);
  m.set_drift([drift_x](double) { return std::array<double, 4>{drift_x, 1.0, 1.0, 1.0}; });
  now += core::from_seconds(1800.0);
  std::array<double, 3> before{};
  for (std::size_t a = 0; a < 3; ++a) before[a] = c.target_um(a, now);
  out.clear();
  run_touch_set(c, m, now, out);
  ASSERT_TRUE(has_alarm(out, AlarmCode::kOffsetBeyondAbsoluteLimit));
  EXPECT_FALSE(has_alarm(out, AlarmCode::kRecalibrationImplausible));
  EXPECT_FALSE(has_alarm(out, AlarmCode::kRecalibrationApplied));
  for (std::size_t a = 0; a < 3; ++a) EXPECT_DOUBLE_EQ(c.target_um(a, now), before[a]) << a;
  EXPECT_DOUBLE_EQ(c.model(Slot::kXLateral).anchor_drift_um, 0.0);
}

TEST(Recalibration, ScatteredTouchesRaiseAlarmAndApplyNothing) {
  auto cfg = test_config();
  cfg.touches_per_axis = 2;
  Calibrator c;
  c.configure(cfg);
  SimMachine m(cfg, test_errors(), 0.0, 0.0, 0.1, 3);
  TimeNs now = 0;
  StepOutput out;
  ASSERT_TRUE(run_initial_calibration(c, m, now, out));
  m.set_drift([](double) { return std::array<double, 4>{5.0, 5.0, 5.0, 5.0}; });
  now += core::from_seconds(1800.0);
  std::vector<Event> ev;
  for (std::size_t slot = 0; slot < 4; ++slot) {
    for (int i = 0; i < 2; ++i) {
      auto t = m.machine_touch(slot, 1, now);
      if (slot == 3 && i == 1) {
        t.trigger_position_mm += 0.012;  // dirt on the sphere
      }
      ev.emplace_back(t);
    }
  }
  out.clear();
  c.step(now, ev, out);
  EXPECT_TRUE(has_alarm(out, AlarmCode::kTouchScatter));
  EXPECT_EQ(c.model(Slot::kZ).touch_sets, 1);  // only the nominal
  EXPECT_DOUBLE_EQ(c.drift_correction_um(Slot::kXLateral, now), 0.0);
}

TEST(Recalibration, ScheduleAndIncompleteSetsAreReported) {
  auto cfg = test_config();
  cfg.touches_per_axis = 1;
  cfg.recalibration_interval_s = 600.0;
  cfg.touch_set_timeout_s = 120.0;
  Calibrator c;
  c.configure(cfg);
  SimMachine m(cfg, test_errors(), 0.0, 0.0, 0.1, 3);
  TimeNs now = 0;
  StepOutput out;
  ASSERT_TRUE(run_initial_calibration(c, m, now, out));
  const TimeNs ready = now;
  int due = 0;
  for (int s = 0; s < 1300; ++s) {
    out.clear();
    c.step(ready + core::from_seconds(s), {}, out);
    due += has_alarm(out, AlarmCode::kRecalibrationDue) ? 1 : 0;
  }
  EXPECT_EQ(due, 1);  // raised once, not every cycle
  // Half a set, then nothing: discarded after the timeout.
  now = ready + core::from_seconds(1400.0);
  const Event x = m.machine_touch(0, 1, now);
  c.step(now, {&x, 1}, out);
  EXPECT_EQ(c.touch_progress().count[0], 1);
  out.clear();
  c.step(now + core::from_seconds(121.0), {}, out);
  EXPECT_TRUE(has_alarm(out, AlarmCode::kTouchSetIncomplete));
  EXPECT_EQ(c.touch_progress().count[0], 0);
}

TEST(Recalibration, StepIsAllocationFree) {
  auto cfg = test_config();
  cfg.touches_per_axis = 2;
  cfg.prediction = Prediction::kTemperature;
  cfg.temperature_sensor = 1;
  Calibrator c;
  c.configure(cfg);
  SimMachine m(cfg, test_errors(), 0.3, 0.3, 0.1, 3);
  TimeNs now = 0;
  StepOutput out;
  ASSERT_TRUE(run_initial_calibration(c, m, now, out));
  m.set_drift(warmup);
  // Prepared outside the scope: the events of a few recalibrations and temperature samples.
  std::vector<std::vector<Event>> batches;
  for (int k = 0; k < 5; ++k) {
    std::vector<Event> b;
    b.emplace_back(core::TemperatureSample{now, 1, 20.0 + k});
    const TimeNs t = now + core::from_seconds(600.0 * (k + 1));
    for (std::size_t slot = 0; slot < 4; ++slot) {
      b.emplace_back(m.machine_touch(slot, 1, t));
      b.emplace_back(m.machine_touch(slot, 1, t));
    }
    batches.push_back(std::move(b));
  }
  std::size_t writes = 0;
  std::size_t records = 0;
  const AllocationScope scope;
  for (int k = 0; k < 5; ++k) {
    for (int s = 0; s < 600; ++s) {
      const TimeNs t = now + core::from_seconds(600.0 * k + s + 1);
      out.clear();
      if (s == 599) {
        c.step(t, batches[static_cast<std::size_t>(k)], out);
      } else {
        c.step(t, {}, out);
      }
      writes += out.writes.size();
      records += out.records.size();
    }
  }
  EXPECT_EQ(scope.count(), 0u);
  EXPECT_EQ(records, 5u * 6u);
  EXPECT_GT(writes, 10u);
}

}  // namespace
}  // namespace nccomp::test::calib
