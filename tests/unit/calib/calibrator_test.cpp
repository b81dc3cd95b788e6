// Initial calibration (S3 steps 1–4) on a simulated machine with known errors.
#include "core/calib/calibrator.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <stdexcept>
#include <string>

#include "core/calib/facet.hpp"
#include "tests/support/alloc_counter.hpp"
#include "tests/unit/calib/sim_machine.hpp"
#include "tests/unit/calib/test_config.hpp"

namespace nccomp::test::calib {
namespace {

using core::AlarmCode;
using core::Event;
using core::StepOutput;
using core::calib::Calibrator;
using core::calib::Face;
using core::calib::FacetRule;
using core::calib::FacetStatus;
using core::calib::Phase;
using core::calib::Slot;

bool has_alarm(const StepOutput& out, AlarmCode code) {
  for (const auto& a : out.alarms) {
    if (a.code == code) {
      return true;
    }
  }
  return false;
}

TEST(Calibration, RecoversKnownErrorsWithinProbeNoise) {
  // GIVEN a machine with known axis errors and probe pretravel, touch noise σ = 0.5 µm (three
  // touches per axis), chord noise σ = 0.5 µm
  const auto cfg = test_config();
  Calibrator c;
  c.configure(cfg);
  SimMachine m(cfg, test_errors(), 0.5, 0.5, 0.1, 7);
  core::TimeNs now = core::from_seconds(100.0);
  StepOutput out;
  // WHEN the whole procedure runs
  ASSERT_TRUE(run_initial_calibration(c, m, now, out));
  const auto& r = c.result();
  const auto& e = m.errors();
  // THEN the touches alone carry the pretravel ...
  EXPECT_NEAR(r.dx_touch_lateral_um, e.ex_um + e.pretravel_lateral_um, 1.5);
  EXPECT_NEAR(r.dx_touch_axial_um, e.exa_um + e.pretravel_axial_um, 1.5);
  // ... test grinding removes it: ΔxR, ΔxA within the chord tolerance's worth of error
  // (2 µm of chord ≈ 0.1 µm of position) and the chord noise
  EXPECT_NEAR(r.dx_r_um, e.ex_um, 0.3);
  EXPECT_NEAR(r.dx_a_um, e.exa_um, 0.3);
  EXPECT_NEAR(r.probe_lateral_um, -e.pretravel_lateral_um, 1.5);
  EXPECT_NEAR(r.pivot_um, e.exa_um - e.ex_um, 0.5);
  // ... and ΔxR's probe correction makes Y and Z right too (touch noise of two means of 3)
  EXPECT_NEAR(r.dy_um, e.ey_um, 1.5);
  EXPECT_NEAR(r.dz_um, e.ez_um, 1.5);
  // Without it Y and Z would be off by the pretravel.
  EXPECT_GT(std::fabs(r.dy_touch_um - e.ey_um), 2.5);
  // The registers are driven to the calibration values.
  for (int i = 0; i < 30; ++i) {
    out.clear();
    c.step(now, {}, out);
    now += core::from_seconds(1.0);
  }
  EXPECT_NEAR(c.written_um(0), r.dx_r_um, 0.11);
  EXPECT_NEAR(c.written_um(1), r.dy_um, 0.11);
  EXPECT_NEAR(c.written_um(2), r.dz_um, 0.11);
}

int grinds_to_converge(FacetRule rule, double gain, double nominal_depth_mm, std::uint64_t seed) {
  auto cfg = test_config();
  cfg.facet_rule = rule;
  cfg.facet_gain_um_per_um = gain;
  Calibrator c;
  c.configure(cfg);
  SimMachine m(cfg, test_errors(), 0.5, 0.5, nominal_depth_mm, seed);
  core::TimeNs now = 0;
  StepOutput out;
  if (!run_initial_calibration(c, m, now, out)) {
    return -1;
  }
  EXPECT_NEAR(c.result().dx_r_um, m.errors().ex_um, 0.3);
  return c.result().lateral_grinds;
}

TEST(Calibration, BothFacetRulesConvergeExactInTwoGrinds) {
  // The same simulated machine (the first grind sees the probe's 4 µm pretravel as error),
  // 100 µm deep facets on a 5 mm blank.
  const double matched = core::calib::matched_proportional_gain(5.0, 0.1);
  const int exact = grinds_to_converge(FacetRule::kExact, matched, 0.1, 11);
  const int proportional = grinds_to_converge(FacetRule::kProportional, matched, 0.1, 11);
  const int proportional_half =
      grinds_to_converge(FacetRule::kProportional, 0.5 * matched, 0.1, 11);
  // One grind measures, the corrected second one confirms.
  EXPECT_LE(exact, 2);
  EXPECT_GE(exact, 1);
  // With a gain matched to this blank and depth and a small error it is as good ...
  EXPECT_GE(proportional, exact);
  EXPECT_LE(proportional, 3);
  // ... with half the matched gain it halves the error per grind: ~log2(error / tolerance).
  EXPECT_GE(proportional_half, 5);
  RecordProperty("grinds_exact", exact);
  RecordProperty("grinds_proportional_matched", proportional);
  RecordProperty("grinds_proportional_half_gain", proportional_half);
}

TEST(Calibration, ProportionalGainTooLargeDoesNotConverge) {
  // Twice the matched gain overshoots by the error itself: the facets swap and never agree.
  auto cfg = test_config();
  cfg.facet_rule = FacetRule::kProportional;
  cfg.facet_gain_um_per_um = 2.0 * core::calib::matched_proportional_gain(5.0, 0.1);
  cfg.max_test_grinds = 8;
  Calibrator c;
  c.configure(cfg);
  SimMachine m(cfg, test_errors(), 0.0, 0.0, 0.1, 1);
  core::TimeNs now = 0;
  StepOutput out;
  EXPECT_FALSE(run_initial_calibration(c, m, now, out));
  EXPECT_EQ(c.phase(), Phase::kUncalibrated);
}

TEST(Calibration, NominalsStoredWithTimeAndTemperature) {
  auto cfg = test_config();
  cfg.temperature_sensor = 3;
  Calibrator c;
  c.configure(cfg);
  SimMachine m(cfg, test_errors(), 0.2, 0.2, 0.1, 5);
  core::TimeNs now = core::from_seconds(10.0);
  StepOutput out;
  const Event temp = core::TemperatureSample{now, 3, 21.75};
  const Event other = core::TemperatureSample{now, 4, 99.0};
  const Event both[] = {temp, other};
  c.step(now, both, out);
  ASSERT_TRUE(run_initial_calibration(c, m, now, out));
  for (const auto s : {Slot::kXLateral, Slot::kXAxial, Slot::kY, Slot::kZ}) {
    const auto& n = c.nominal(s);
    EXPECT_EQ(n.valid, 1);
    EXPECT_DOUBLE_EQ(n.temp_c, 21.75);
    EXPECT_GT(n.time_s, 10.0);
    EXPECT_EQ(n.direction, 1);
  }
  // The nominal is the mean trigger position of the machine-probe touches (body at 120 mm,
  // 2 mm contact, no drift yet).
  EXPECT_NEAR(c.nominal(Slot::kXLateral).position_mm, 118.0, 0.001);
  EXPECT_NEAR(c.nominal(Slot::kZ).position_mm, 13.0, 0.001);
  // The last step logged the nominal touches as calib records (X, Y, Z, three each).
  EXPECT_EQ(out.records.size(), 9u);
  for (const auto& rec : out.records) {
    EXPECT_EQ(rec.kind, core::MeasurementKind::kCalib);
    EXPECT_DOUBLE_EQ(rec.temp_c, 21.75);
    EXPECT_LT(std::fabs(rec.measured_um), 1.0);
  }
}

TEST(Calibration, ScatteredReferenceTouchesAreRefused) {
  const auto cfg = test_config();
  Calibrator c;
  c.configure(cfg);
  SimMachine m(cfg, test_errors(), 0.0, 0.0, 0.1, 5);
  StepOutput out;
  core::TimeNs now = 0;
  c.begin_calibration(now, out);
  for (std::size_t slot = 0; slot < 4; ++slot) {
    for (int i = 0; i < 3; ++i) {
      auto t = m.reference_touch(slot, 1, now);
      if (slot == 2 && i == 1) {
        t.trigger_position_mm += 0.009;  // dirt on the disk: 9 µm > 5 µm
      }
      const Event e = t;
      out.clear();
      c.step(now, {&e, 1}, out);
    }
  }
  EXPECT_TRUE(has_alarm(out, AlarmCode::kTouchScatter));
  EXPECT_EQ(c.phase(), Phase::kReferenceTouches);
  EXPECT_TRUE(std::isnan(c.result().dy_touch_um));
}

TEST(Calibration, OperatorInputIsValidated) {
  const auto cfg = test_config();
  Calibrator c;
  c.configure(cfg);
  StepOutput out;
  // Facets before any touch: wrong phase, nothing changes.
  EXPECT_EQ(c.enter_facets(Face::kLateral, 2.0, 2.0, 0, out).status, FacetStatus::kWrongPhase);
  SimMachine m(cfg, test_errors(), 0.0, 0.0, 0.1, 5);
  c.begin_calibration(0, out);
  for (std::size_t slot = 0; slot < 4; ++slot) {
    for (int i = 0; i < 3; ++i) {
      const Event e = m.reference_touch(slot, 1, 0);
      c.step(0, {&e, 1}, out);
    }
  }
  ASSERT_EQ(c.phase(), Phase::kTestGrindLateral);
  out.clear();
  EXPECT_EQ(c.enter_facets(Face::kLateral, 10.5, 2.0, 0, out).status,
            FacetStatus::kInvalidInput);  // chord longer than the blank's diameter
  EXPECT_EQ(c.enter_facets(Face::kLateral, std::nan(""), 2.0, 0, out).status,
            FacetStatus::kInvalidInput);
  EXPECT_EQ(c.enter_facets(Face::kEndFace, 2.0, 2.0, 0, out).status, FacetStatus::kWrongPhase);
  EXPECT_TRUE(has_alarm(out, AlarmCode::kCalibrationInvalidInput));
  EXPECT_EQ(c.phase(), Phase::kTestGrindLateral);
  // A machine-probe touch now is unexpected; an axial Y touch is invalid.
  out.clear();
  const Event mt = m.machine_touch(0, 1, 0);
  c.step(0, {&mt, 1}, out);
  EXPECT_TRUE(has_alarm(out, AlarmCode::kTouchUnexpected));
  core::CalibrationTouch bad = m.reference_touch(2, 1, 0);
  bad.variant = 1;
  const Event be = bad;
  out.clear();
  c.step(0, {&be, 1}, out);
  EXPECT_TRUE(has_alarm(out, AlarmCode::kCalibrationInvalidInput));
}

// Issue 17, finding 4. GIVEN an initial calibration waiting for reference touches, WHEN a touch
// arrives faulted (the driver read NaN / inf / a position beyond the map's range: InputFault, its
// position 0 as the engine delivers it), THEN the calibration raises its invalid-input code 49 as
// an alarm (subject the axis, value NaN) and takes nothing from it: the set in progress keeps its
// touches, and the intact touches that follow complete it without a scatter alarm.
TEST(Calibration, AFaultedTouchAlarmsAndIsNotTaken) {
  const auto cfg = test_config();
  Calibrator c;
  c.configure(cfg);
  SimMachine m(cfg, test_errors(), 0.0, 0.0, 0.1, 5);
  StepOutput out;
  c.begin_calibration(0, out);
  const Event first = m.reference_touch(0, 1, 0);
  c.step(0, {&first, 1}, out);
  core::CalibrationTouch bad = m.reference_touch(0, 1, 0);
  bad.trigger_position_mm = 0.0;
  bad.fault = core::InputFault::kInvalid;
  const Event be = bad;
  out.clear();
  {
    const AllocationScope scope;  // the loop's path: allocation-free
    c.step(0, {&be, 1}, out);
    EXPECT_EQ(scope.count(), 0U);
  }
  ASSERT_EQ(out.alarms.size(), 1U);
  EXPECT_EQ(out.alarms[0].code, AlarmCode::kCalibrationInvalidInput);
  EXPECT_EQ(out.alarms[0].severity, core::Severity::kAlarm);
  EXPECT_EQ(out.alarms[0].subject, 0);
  EXPECT_TRUE(std::isnan(out.alarms[0].value));
  EXPECT_EQ(c.touch_progress().count[0], 1);
  out.clear();
  for (std::size_t slot = 0; slot < 4; ++slot) {
    for (int i = slot == 0 ? 1 : 0; i < 3; ++i) {
      const Event e = m.reference_touch(slot, 1, 0);
      c.step(0, {&e, 1}, out);
    }
  }
  EXPECT_FALSE(has_alarm(out, AlarmCode::kTouchScatter));
  EXPECT_EQ(c.phase(), Phase::kTestGrindLateral);
}

TEST(Calibration, ConfigErrorsNameTheKey) {
  auto cfg = test_config();
  cfg.blank_radius_mm = -1.0;
  try {
    core::calib::validate(cfg);
    FAIL() << "accepted a negative blank radius";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("calibration.blank_radius_mm"), std::string::npos)
        << e.what();
  }
  cfg = test_config();
  cfg.prediction = core::calib::Prediction::kTemperature;
  EXPECT_THROW(core::calib::validate(cfg), std::invalid_argument);
  cfg.temperature_sensor = 2;
  EXPECT_NO_THROW(core::calib::validate(cfg));
  cfg.register_y = cfg.register_x;
  EXPECT_THROW(core::calib::validate(cfg), std::invalid_argument);
}

}  // namespace
}  // namespace nccomp::test::calib
