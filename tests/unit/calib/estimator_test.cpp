// The drift estimator (prediction = "estimator", issue 22 item 3): the earlier shifts' drift as
// the prior, the Kalman update against its closed form, the gate, restart without doubling,
// version-1 states converted, allocation-free steps.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <initializer_list>
#include <stdexcept>
#include <string>
#include <vector>

#include "core/calib/calib_module.hpp"
#include "core/calib/calibrator.hpp"
#include "core/calib/drift_estimator.hpp"
#include "core/calib/state.hpp"
#include "tests/support/alloc_counter.hpp"
#include "tests/unit/calib/sim_machine.hpp"
#include "tests/unit/calib/test_config.hpp"

namespace nccomp::test::calib {
namespace {

using core::AlarmCode;
using core::StepOutput;
using core::TimeNs;
using core::calib::Calibrator;
using core::calib::CalibState;
using core::calib::Prediction;
using core::calib::ShiftHistory;
using core::calib::Slot;

bool has_alarm(const StepOutput& out, AlarmCode code) {
  return std::any_of(out.alarms.begin(), out.alarms.end(),
                     [code](const core::AlarmEvent& a) { return a.code == code; });
}

CalibrationConfig estimator_config() {
  auto cfg = test_config();
  cfg.touches_per_axis = 1;
  cfg.prediction = Prediction::kEstimator;
  cfg.recalibration_interval_s = 0.0;
  return cfg;
}

// Drift of every slot: `rate` µm per hour since t0, the same on every slot but Y (half).
SimMachine::DriftFn linear_drift(double t0, double rate_um_per_h) {
  return [t0, rate_um_per_h](double t) {
    const double d = std::max(0.0, t - t0) / 3600.0 * rate_um_per_h;
    return std::array<double, 4>{d, d, 0.5 * d, d};
  };
}

// A shift: calibration and nominals, then a touch set every hour for `hours`; the drift grows
// by rate_um_per_h from the nominals. Returns the time of the nominals [ns].
TimeNs run_calibrated_shift(Calibrator& c, SimMachine& m, TimeNs& now, double rate_um_per_h,
                            int hours) {
  StepOutput out;
  m.set_drift([](double) { return std::array<double, 4>{}; });
  EXPECT_TRUE(run_initial_calibration(c, m, now, out));
  const TimeNs t_nom = core::from_seconds(c.nominal(Slot::kXLateral).time_s);
  m.set_drift(linear_drift(core::seconds(t_nom), rate_um_per_h));
  for (int h = 1; h <= hours; ++h) {
    now = t_nom + core::from_seconds(3600.0 * h);
    out.clear();
    run_touch_set(c, m, now, out);
    EXPECT_TRUE(has_alarm(out, AlarmCode::kRecalibrationApplied)) << h;
  }
  return t_nom;
}

// The X, Y, Z offset registers 0, 1, 2 (a RegisterTable points to them: keep them alive).
std::vector<core::engine::RegisterSpec> xyz_specs() {
  std::vector<core::engine::RegisterSpec> specs(3);
  for (std::size_t i = 0; i < 3; ++i) {
    specs[i].name = i == 0 ? "X_offset" : (i == 1 ? "Y_offset" : "Z_offset");
    specs[i].kind = core::engine::RegisterKind::kAxisOffset;
  }
  return specs;
}

// The text form of s as an older version writes it: that version's header, without the keys
// that start with one of the newer prefixes.
std::string older_text(const CalibState& s, int version,
                       std::initializer_list<const char*> newer_prefixes) {
  const std::string text = core::calib::to_text(s);
  std::string out;
  std::size_t pos = 0;
  while (pos < text.size()) {
    const std::size_t nl = text.find('\n', pos);
    const std::string line = text.substr(pos, nl - pos);
    pos = nl + 1;
    if (std::any_of(newer_prefixes.begin(), newer_prefixes.end(),
                    [&line](const char* p) { return line.rfind(p, 0) == 0; })) {
      continue;
    }
    out +=
        (line.rfind("nccomp_calib_state", 0) == 0 ? "nccomp_calib_state " + std::to_string(version)
                                                  : line) +
        "\n";
  }
  return out;
}

TEST(DriftEstimator, EarlierShiftsGiveTheMeanDriftAtTheKnots) {
  ShiftHistory h;
  EXPECT_FALSE(core::calib::has_prior(h));
  EXPECT_DOUBLE_EQ(core::calib::prior_drift_um(h, 0, 1800.0), 0.0);
  // Shift 1: 10 µm at 1 h, 14 µm at 2 h (linear in between, from 0 at the nominals).
  core::calib::add_shift_point(h, 3600.0, {10.0, 0.0, 0.0, 0.0});
  core::calib::add_shift_point(h, 7200.0, {14.0, 0.0, 0.0, 0.0});
  EXPECT_EQ(h.current_knots, 4);
  EXPECT_FALSE(core::calib::has_prior(h));  // the shift in progress is not its own prior
  core::calib::fold_shift(h, 0.5);
  ASSERT_TRUE(core::calib::has_prior(h));
  EXPECT_EQ(h.shifts, 1);
  EXPECT_EQ(h.current_knots, 0);
  // Knots 0.5 h = 5, 1 h = 10, 1.5 h = 12, 2 h = 14; held after the last.
  EXPECT_DOUBLE_EQ(core::calib::prior_drift_um(h, 0, 900.0), 2.5);
  EXPECT_DOUBLE_EQ(core::calib::prior_drift_um(h, 0, 2700.0), 7.5);
  EXPECT_DOUBLE_EQ(core::calib::prior_drift_um(h, 0, 6300.0), 13.0);
  EXPECT_DOUBLE_EQ(core::calib::prior_drift_um(h, 0, 36000.0), 14.0);
  // Shift 2 reaches only 1 h with 4 µm: knot 1 h = (0.5·10 + 4) / 1.5 = 6, knot 2 h keeps 14.
  core::calib::add_shift_point(h, 3600.0, {4.0, 0.0, 0.0, 0.0});
  core::calib::fold_shift(h, 0.5);
  EXPECT_EQ(h.shifts, 2);
  EXPECT_DOUBLE_EQ(core::calib::prior_drift_um(h, 0, 3600.0), 6.0);
  EXPECT_DOUBLE_EQ(core::calib::prior_drift_um(h, 0, 7200.0), 14.0);
}

TEST(DriftEstimator, LevelUpdateIsTheScalarKalmanStep) {
  core::calib::EstimatorParams p;
  p.touch_noise_um = 0.7;
  p.level_noise_um_per_h = 6.0;
  p.slope_sigma_um_per_c = 0.0;
  auto e = core::calib::start_estimate(0.0, false, 0.0, p);
  // One hour later: P⁻ = 0.49 + 36, K = P⁻ / (P⁻ + 0.49), x = K·z, P⁺ = K·0.49.
  const double pm = 0.49 + 36.0;
  const double k = pm / (pm + 0.49);
  const auto r = core::calib::update_estimate(e, 0.0, 0.0, 3600.0, 10.0, p);
  ASSERT_TRUE(r.accepted);
  EXPECT_NEAR(e.x[0], k * 10.0, 1e-12);
  EXPECT_NEAR(e.p[0], k * 0.49, 1e-12);
  EXPECT_NEAR(r.normalized, 10.0 / std::sqrt(pm + 0.49), 1e-12);
  // The prediction 30 min later: same mean, variance P⁺ + 18.
  const auto d = core::calib::predict_estimate(e, 0.0, 0.0, 5400.0, p);
  EXPECT_NEAR(d.mean_um, k * 10.0, 1e-12);
  EXPECT_NEAR(d.sigma_um, std::sqrt(k * 0.49 + 18.0), 1e-12);
}

// GIVEN a machine that drifted 6 µm/h in an earlier shift WHEN the next shift starts THEN the
// estimator predicts that drift before the first touch (the other strategies hold 0); without
// an earlier shift it predicts 0.
TEST(DriftEstimator, FirstHourIsPredictedFromEarlierShifts) {
  const auto cfg = estimator_config();
  Calibrator c;
  c.configure(cfg);
  SimMachine m(cfg, test_errors(), 0.0, 0.0, 0.1, 5);
  TimeNs now = 0;
  {
    // The first shift has no earlier one: nothing before its first touch.
    Calibrator fresh;
    fresh.configure(cfg);
    StepOutput out;
    TimeNs t = 0;
    ASSERT_TRUE(run_initial_calibration(fresh, m, t, out));
    EXPECT_DOUBLE_EQ(fresh.predicted_drift_um(Slot::kXLateral, t + core::from_seconds(1800.0)),
                     0.0);
  }
  run_calibrated_shift(c, m, now, 6.0, 3);
  now += core::from_seconds(8.0 * 3600.0);
  StepOutput out;
  m.set_drift([](double) { return std::array<double, 4>{}; });
  ASSERT_TRUE(run_initial_calibration(c, m, now, out));
  const TimeNs t_nom = core::from_seconds(c.nominal(Slot::kXLateral).time_s);
  EXPECT_EQ(c.export_state().shifts.shifts, 1);
  const TimeNs half_hour = t_nom + core::from_seconds(1800.0);
  // Earlier shift: 6 µm/h on X (3 µm at 0.5 h), 3 µm/h on Y; the prior's gain is 1.
  EXPECT_NEAR(c.predicted_drift_um(Slot::kXLateral, half_hour), 3.0, 1e-9);
  EXPECT_NEAR(c.predicted_drift_um(Slot::kY, half_hour), 1.5, 1e-9);
  const auto est = c.estimated_drift(Slot::kXLateral, half_hour);
  EXPECT_NEAR(est.mean_um, 3.0, 1e-9);
  // σ² = level (0.7² + 36·0.5) + gain (0.5·3)²
  EXPECT_NEAR(est.sigma_um, std::sqrt(0.49 + 18.0 + 2.25), 1e-9);
  // The time model of the same machine holds 0 until the first touch.
  auto time_cfg = cfg;
  time_cfg.prediction = Prediction::kTime;
  Calibrator t;
  t.configure(time_cfg);
  t.import_state(c.export_state());
  EXPECT_NEAR(t.predicted_drift_um(Slot::kXLateral, half_hour), 0.0, 1e-9);
}

// GIVEN earlier shifts that reached 18 µm at 3 h and plausibility_um 10 WHEN the next shift has
// no touch yet THEN the prediction stops at 10 µm from the last measured drift (0).
TEST(DriftEstimator, PredictionIsBoundedByThePlausibilityFromTheLastTouch) {
  auto cfg = estimator_config();
  cfg.plausibility_um = 10.0;
  Calibrator c;
  c.configure(cfg);
  SimMachine m(cfg, test_errors(), 0.0, 0.0, 0.1, 5);
  TimeNs now = 0;
  run_calibrated_shift(c, m, now, 6.0, 3);
  StepOutput out;
  m.set_drift([](double) { return std::array<double, 4>{}; });
  ASSERT_TRUE(run_initial_calibration(c, m, now, out));
  const TimeNs t_nom = core::from_seconds(c.nominal(Slot::kXLateral).time_s);
  EXPECT_NEAR(c.predicted_drift_um(Slot::kXLateral, t_nom + core::from_seconds(3600.0)), 6.0, 1e-9);
  EXPECT_NEAR(c.estimated_drift(Slot::kXLateral, t_nom + core::from_seconds(3.0 * 3600.0)).mean_um,
              18.0, 1e-9);
  EXPECT_DOUBLE_EQ(c.predicted_drift_um(Slot::kXLateral, t_nom + core::from_seconds(3.0 * 3600.0)),
                   10.0);
}

// GIVEN an estimate that expects Y 3 ± 6.1 µm at 1 h WHEN a touch set reads Y 45 µm (a change
// of 42 µm, within plausibility_um 50, beyond 5 σ) THEN alarm 40 and nothing changes: estimate,
// registers, earlier-shift drift.
TEST(DriftEstimator, GatedTouchSetRaisesTheAlarmAndChangesNothing) {
  const auto cfg = estimator_config();
  Calibrator c;
  c.configure(cfg);
  SimMachine m(cfg, test_errors(), 0.0, 0.0, 0.1, 5);
  TimeNs now = 0;
  run_calibrated_shift(c, m, now, 6.0, 2);
  StepOutput out;
  m.set_drift([](double) { return std::array<double, 4>{}; });
  ASSERT_TRUE(run_initial_calibration(c, m, now, out));
  const TimeNs t_nom = core::from_seconds(c.nominal(Slot::kXLateral).time_s);
  m.set_drift([t0 = core::seconds(t_nom)](double t) {
    const double d = (t - t0) / 3600.0 * 6.0;
    return std::array<double, 4>{d, d, 45.0, d};
  });
  now = t_nom + core::from_seconds(3600.0);
  const CalibState before = c.export_state();
  const double target_before = c.target_um(1, now);
  out.clear();
  run_touch_set(c, m, now, out);
  ASSERT_TRUE(has_alarm(out, AlarmCode::kRecalibrationImplausible));
  EXPECT_FALSE(has_alarm(out, AlarmCode::kRecalibrationApplied));
  const CalibState after = c.export_state();
  EXPECT_EQ(std::memcmp(&before.estimates, &after.estimates, sizeof before.estimates), 0);
  EXPECT_EQ(std::memcmp(&before.shifts, &after.shifts, sizeof before.shifts), 0);
  EXPECT_EQ(after.models[2].touch_sets, before.models[2].touch_sets);
  EXPECT_DOUBLE_EQ(c.target_um(1, now), target_before);
  // A plausible set afterwards is taken.
  m.set_drift(linear_drift(core::seconds(t_nom), 6.0));
  now += core::from_seconds(60.0);
  out.clear();
  run_touch_set(c, m, now, out);
  EXPECT_TRUE(has_alarm(out, AlarmCode::kRecalibrationApplied));
}

// GIVEN the estimator mid-shift WHEN the daemon restarts (state through text, a new monotonic
// clock) THEN targets and estimates continue unchanged, and the next touch set gives the same
// correction as without the restart (the drift is not applied twice).
TEST(DriftEstimator, RestartContinuesWithoutApplyingTheDriftTwice) {
  auto cfg = estimator_config();
  cfg.temperature_sensor = 0;
  cfg.estimator_slope_sigma_um_per_c = 1.0;
  Calibrator a;
  a.configure(cfg);
  a.set_clock_offset_s(1.7e9);
  SimMachine m(cfg, test_errors(), 0.2, 0.2, 0.1, 8);
  TimeNs now = 0;
  run_calibrated_shift(a, m, now, 5.0, 2);
  StepOutput out;
  m.set_drift([](double) { return std::array<double, 4>{}; });
  ASSERT_TRUE(run_initial_calibration(a, m, now, out));
  const TimeNs t_nom = core::from_seconds(a.nominal(Slot::kXLateral).time_s);
  m.set_drift(linear_drift(core::seconds(t_nom), 5.0));
  now = t_nom + core::from_seconds(3600.0);
  const core::Event temp = core::TemperatureSample{now, 0, 23.0};
  out.clear();
  a.step(now, {&temp, 1}, out);
  out.clear();
  run_touch_set(a, m, now, out);
  now += core::from_seconds(300.0);  // in the middle of the creep
  out.clear();
  a.step(now, {}, out);
  const std::string text = core::calib::to_text(a.export_state());

  Calibrator b;
  b.configure(cfg);
  const TimeNs now_b = core::from_seconds(20.0);
  b.set_clock_offset_s(1.7e9 + core::seconds(now) - 20.0);
  b.import_state(core::calib::from_text(text));
  out.clear();
  b.step(now_b, {&temp, 1}, out);
  for (const Slot s : {Slot::kXLateral, Slot::kY, Slot::kZ}) {
    EXPECT_NEAR(b.estimated_drift(s, now_b).mean_um, a.estimated_drift(s, now).mean_um, 1e-9);
    EXPECT_NEAR(b.estimated_drift(s, now_b).sigma_um, a.estimated_drift(s, now).sigma_um, 1e-9);
  }
  for (std::size_t axis = 0; axis < 3; ++axis) {
    EXPECT_NEAR(b.target_um(axis, now_b), a.target_um(axis, now), 1e-6) << axis;
  }
  // The next touch set, one hour on, on both.
  const TimeNs next_a = t_nom + core::from_seconds(7200.0);
  const TimeNs next_b = now_b + (next_a - now);
  std::array<core::Event, 4> ev_a{};
  std::array<core::Event, 4> ev_b{};
  for (std::size_t s = 0; s < 4; ++s) {
    ev_a[s] = m.machine_touch(s, 1, next_a);
    ev_b[s] = ev_a[s];
    std::get<core::CalibrationTouch>(ev_b[s]).time_ns = next_b;
  }
  out.clear();
  a.step(next_a, ev_a, out);
  out.clear();
  b.step(next_b, ev_b, out);
  for (std::size_t axis = 0; axis < 3; ++axis) {
    const TimeNs later = core::from_seconds(1200.0);
    EXPECT_NEAR(b.target_um(axis, next_b + later), a.target_um(axis, next_a + later), 1e-6) << axis;
  }
  EXPECT_EQ(b.export_state().shifts.current_knots, a.export_state().shifts.current_knots);
}

// A version-1 state (text and the module's bytes) is converted: its touch sets since the
// nominals become the shift in progress, the prior of the next shift.
TEST(DriftEstimator, VersionOneStatesAreConverted) {
  auto cfg = test_config();
  cfg.register_x = 0;
  cfg.register_y = 1;
  cfg.register_z = 2;
  cfg.touches_per_axis = 1;
  cfg.prediction = Prediction::kTime;
  Calibrator c;
  c.configure(cfg);
  SimMachine m(cfg, test_errors(), 0.0, 0.0, 0.1, 5);
  TimeNs now = 0;
  run_calibrated_shift(c, m, now, 6.0, 2);
  CalibState v1 = c.export_state();
  v1.version = 1;
  v1.estimates = {};
  v1.shifts = {};
  // Text: the version-1 keys only.
  const std::string v1_text = older_text(v1, 1, {"estimate.", "shifts."});
  const CalibState from_text = core::calib::from_text(v1_text);
  EXPECT_EQ(from_text.version, CalibState::kVersion);
  // Touch sets at 1 h (6 µm) and 2 h (12 µm): knots 0.5 .. 2 h.
  EXPECT_EQ(from_text.shifts.current_knots, 4);
  EXPECT_NEAR(from_text.shifts.current_um[0][0], 3.0, 1e-6);
  EXPECT_NEAR(from_text.shifts.current_um[0][3], 12.0, 1e-6);
  // The module's bytes, with and without the three written values.
  const auto specs = xyz_specs();
  const core::engine::RegisterTable table(specs);
  for (const bool written : {false, true}) {
    std::vector<std::byte> bytes(core::calib::kCalibStateV1Bytes + (written ? 24 : 0));
    std::memcpy(bytes.data(), &v1, core::calib::kCalibStateV1Bytes);
    const double w[3] = {30.0, -12.0, 8.0};
    if (written) {
      std::memcpy(bytes.data() + core::calib::kCalibStateV1Bytes, w, sizeof w);
    }
    core::calib::CalibrationModule mod(cfg);
    mod.attach(table);
    ASSERT_TRUE(mod.load_state(bytes)) << written;
    const CalibState s = mod.calibrator().export_state();
    EXPECT_EQ(s.version, CalibState::kVersion);
    EXPECT_EQ(s.shifts.current_knots, 4);
    EXPECT_NEAR(mod.calibrator().target_um(0, now), c.target_um(0, now), 1e-9);
  }
  // A version-1 header on version-2 bytes is refused.
  std::vector<std::byte> bad(core::calib::kCalibStateV1Bytes);
  CalibState v2 = c.export_state();
  std::memcpy(bad.data(), &v2, bad.size());
  core::calib::CalibrationModule mod(cfg);
  mod.attach(table);
  EXPECT_FALSE(mod.load_state(bad));
}

// GIVEN a version-2 state (text and the module's bytes) WHEN it is loaded THEN it is version 3
// with no hourly increments (the configured level noise until the next shift ends) and the
// same shifts.
TEST(DriftEstimator, VersionTwoStatesAreConverted) {
  auto cfg = estimator_config();
  cfg.register_x = 0;
  cfg.register_y = 1;
  cfg.register_z = 2;
  Calibrator c;
  c.configure(cfg);
  SimMachine m(cfg, test_errors(), 0.0, 0.0, 0.1, 5);
  TimeNs now = 0;
  run_calibrated_shift(c, m, now, 6.0, 2);
  StepOutput out;
  m.set_drift([](double) { return std::array<double, 4>{}; });
  ASSERT_TRUE(run_initial_calibration(c, m, now, out));  // folds the first shift
  const CalibState v3 = c.export_state();
  ASSERT_GT(v3.shifts.increment_weight, 0.0);
  const CalibState t = core::calib::from_text(older_text(v3, 2, {"shifts.increment_"}));
  EXPECT_EQ(t.version, 3);
  EXPECT_EQ(t.shifts.increment_weight, 0.0);
  EXPECT_EQ(t.shifts.shifts, v3.shifts.shifts);
  EXPECT_EQ(t.shifts.sum_um, v3.shifts.sum_um);
  // The version-3 keys under a version-2 header are unknown.
  std::string mixed = core::calib::to_text(v3);
  mixed.replace(0, mixed.find('\n'), "nccomp_calib_state 2");
  EXPECT_THROW(core::calib::from_text(mixed), std::invalid_argument);
  const auto specs = xyz_specs();
  const core::engine::RegisterTable table(specs);
  CalibState v2 = v3;
  v2.version = 2;
  std::vector<std::byte> bytes(core::calib::kCalibStateV2Bytes);
  std::memcpy(bytes.data(), &v2, bytes.size());
  core::calib::CalibrationModule mod(cfg);
  mod.attach(table);
  ASSERT_TRUE(mod.load_state(bytes));
  const CalibState b = mod.calibrator().export_state();
  EXPECT_EQ(b.version, 3);
  EXPECT_EQ(b.shifts.increment_weight, 0.0);
  EXPECT_EQ(b.shifts.sum_um, v3.shifts.sum_um);
  // Version-3 bytes cut to version 2's length but still saying 3 are refused.
  std::memcpy(bytes.data(), &v3, bytes.size());
  core::calib::CalibrationModule mod3(cfg);
  mod3.attach(table);
  EXPECT_FALSE(mod3.load_state(bytes));
}

// GIVEN shifts whose drift is a random walk of σ 5 µm per hour, touched every hour WHEN they are
// folded one after the other THEN the learned level noise is the RMS of the hourly increments
// (computed here from the generated steps), approaches σ, is clamped to the bounds, and is the
// configured value before any shift ended.
TEST(DriftEstimator, LevelNoiseIsLearnedFromTheEarlierShiftsHourlyIncrements) {
  ShiftHistory h;
  EXPECT_DOUBLE_EQ(core::calib::learned_level_noise_um_per_h(h, 0, 6.0, 1.0, 20.0), 6.0);
  std::uint64_t state = 12345;
  const auto gauss = [&state]() {  // Box-Muller on a 64-bit LCG
    const auto uniform = [&state]() {
      state = state * 6364136223846793005ULL + 1442695040888963407ULL;
      return (static_cast<double>(state >> 11) + 0.5) / 9007199254740992.0;
    };
    const double u1 = uniform();
    const double u2 = uniform();
    return std::sqrt(-2.0 * std::log(u1)) * std::cos(6.283185307179586 * u2);
  };
  constexpr double kSigma = 5.0;
  double sum_sq = 0.0;
  double n = 0.0;
  for (int shift = 0; shift < 50; ++shift) {
    std::array<double, 4> d{};
    for (int hour = 1; hour <= 8; ++hour) {
      for (std::size_t s = 0; s < 4; ++s) {
        const double step = (s == 2 ? 0.5 : 1.0) * kSigma * gauss();
        d[s] += step;
        if (s == 0) {
          sum_sq += step * step;
        }
      }
      n += 1.0;
      core::calib::add_shift_point(h, 3600.0 * hour, d);
    }
    core::calib::fold_shift(h, 1.0);
    if (shift == 0) {
      EXPECT_NEAR(core::calib::learned_level_noise_um_per_h(h, 0, 6.0, 0.1, 100.0),
                  std::sqrt(sum_sq / n), 1e-9);
    }
  }
  const double learned = core::calib::learned_level_noise_um_per_h(h, 0, 6.0, 0.1, 100.0);
  EXPECT_NEAR(learned, std::sqrt(sum_sq / n), 1e-9);
  EXPECT_NEAR(learned, kSigma, 0.1 * kSigma);  // 400 increments: about 3.5 % standard error
  EXPECT_NEAR(core::calib::learned_level_noise_um_per_h(h, 2, 6.0, 0.1, 100.0), 0.5 * kSigma,
              0.1 * kSigma);
  EXPECT_DOUBLE_EQ(core::calib::learned_level_noise_um_per_h(h, 0, 6.0, 0.1, 3.0), 3.0);
  EXPECT_DOUBLE_EQ(core::calib::learned_level_noise_um_per_h(h, 0, 6.0, 8.0, 20.0), 8.0);
  // Forgetting weighs the increments like the mean: one shift of +2 µm/h after one of +4 µm/h
  // with forgetting 0.5 gives (0.5 · 2 · 16 + 2 · 4) / (0.5 · 2 + 2) over two hours each.
  ShiftHistory g;
  core::calib::add_shift_point(g, 3600.0, {4.0, 0.0, 0.0, 0.0});
  core::calib::add_shift_point(g, 7200.0, {8.0, 0.0, 0.0, 0.0});
  core::calib::fold_shift(g, 0.5);
  core::calib::add_shift_point(g, 3600.0, {2.0, 0.0, 0.0, 0.0});
  core::calib::add_shift_point(g, 7200.0, {4.0, 0.0, 0.0, 0.0});
  core::calib::fold_shift(g, 0.5);
  EXPECT_NEAR(core::calib::learned_level_noise_um_per_h(g, 0, 6.0, 0.1, 100.0),
              std::sqrt((0.5 * 2.0 * 16.0 + 2.0 * 4.0) / 3.0), 1e-12);
}

// GIVEN estimator_learn_level_noise WHEN the first shift runs THEN its estimate grows by the
// configured level noise; WHEN the next shift starts THEN it grows by the RMS of the first
// shift's hourly increments (X 6 µm/h, Y 3 µm/h), each slot its own.
TEST(DriftEstimator, CalibratorUsesTheLearnedLevelNoiseFromTheSecondShift) {
  auto cfg = estimator_config();
  cfg.estimator_learn_level_noise = true;
  cfg.estimator_level_noise_um_per_h = 10.0;
  cfg.estimator_min_level_noise_um_per_h = 1.0;
  Calibrator c;
  c.configure(cfg);
  SimMachine m(cfg, test_errors(), 0.0, 0.0, 0.1, 7);
  TimeNs now = 0;
  StepOutput out;
  m.set_drift([](double) { return std::array<double, 4>{}; });
  ASSERT_TRUE(run_initial_calibration(c, m, now, out));
  TimeNs t_nom = core::from_seconds(c.nominal(Slot::kXLateral).time_s);
  const double touch2 = cfg.estimator_touch_noise_um * cfg.estimator_touch_noise_um;
  // First shift: no earlier shift, gain 0 ± 0, slope 0 ± 0: σ² = touch² + 10² · 1 h.
  EXPECT_NEAR(c.estimated_drift(Slot::kXLateral, t_nom + core::from_seconds(3600.0)).sigma_um,
              std::sqrt(touch2 + 100.0), 1e-9);
  t_nom = run_calibrated_shift(c, m, now, 6.0, 4);
  m.set_drift([](double) { return std::array<double, 4>{}; });
  ASSERT_TRUE(run_initial_calibration(c, m, now, out));
  t_nom = core::from_seconds(c.nominal(Slot::kXLateral).time_s);
  const TimeNs t1 = t_nom + core::from_seconds(3600.0);
  // Second shift at 1 h: prior(1 h) = 6 µm (X) and 3 µm (Y) with gain σ 0.5, level 6 and 3 µm/h.
  const double g2 = cfg.estimator_prior_gain_sigma * cfg.estimator_prior_gain_sigma;
  EXPECT_NEAR(c.estimated_drift(Slot::kXLateral, t1).sigma_um, std::sqrt(touch2 + 36.0 * g2 + 36.0),
              1e-6);
  EXPECT_NEAR(c.estimated_drift(Slot::kY, t1).sigma_um, std::sqrt(touch2 + 9.0 * g2 + 9.0), 1e-6);
}

TEST(DriftEstimator, StepIsAllocationFree) {
  auto cfg = estimator_config();
  cfg.temperature_sensor = 1;
  cfg.estimator_slope_sigma_um_per_c = 1.0;
  Calibrator c;
  c.configure(cfg);
  SimMachine m(cfg, test_errors(), 0.3, 0.3, 0.1, 3);
  TimeNs now = 0;
  run_calibrated_shift(c, m, now, 4.0, 2);
  StepOutput out;
  m.set_drift([](double) { return std::array<double, 4>{}; });
  ASSERT_TRUE(run_initial_calibration(c, m, now, out));  // the earlier shift is the prior now
  const TimeNs t_nom = core::from_seconds(c.nominal(Slot::kXLateral).time_s);
  m.set_drift(linear_drift(core::seconds(t_nom), 4.0));
  std::vector<std::vector<core::Event>> batches;
  for (int k = 0; k < 4; ++k) {
    std::vector<core::Event> b;
    const TimeNs t = t_nom + core::from_seconds(600.0 * (k + 1));
    b.emplace_back(core::TemperatureSample{t, 1, 20.0 + k});
    for (std::size_t slot = 0; slot < 4; ++slot) {
      b.emplace_back(m.machine_touch(slot, 1, t));
    }
    batches.push_back(std::move(b));
  }
  std::size_t applied = 0;
  double sigma = 0.0;
  const AllocationScope scope;
  for (int k = 0; k < 4; ++k) {
    for (int s = 1; s <= 600; ++s) {
      const TimeNs t = t_nom + core::from_seconds(600.0 * k + s);
      out.clear();
      if (s == 600) {
        c.step(t, batches[static_cast<std::size_t>(k)], out);
        applied += has_alarm(out, AlarmCode::kRecalibrationApplied) ? 1u : 0u;
      } else {
        c.step(t, {}, out);
      }
      sigma += c.estimated_drift(Slot::kY, t).sigma_um;
    }
  }
  EXPECT_EQ(scope.count(), 0u);
  EXPECT_EQ(applied, 4u);
  EXPECT_GT(sigma, 0.0);
}

// GIVEN a model's slopes and σ per slot (the prior from nccomp analyze) WHEN new nominals are
// taken THEN every slot's estimate starts at the model's slope with its σ (not at the slope the
// shift before learned), the first hour's prediction is slope · ΔT before any touch, and a
// slot with σ 0 keeps the model's slope through a touch set.
TEST(DriftEstimator, ModelSlopeIsThePriorOfEveryShift) {
  auto cfg = estimator_config();
  cfg.temperature_sensor = 0;
  cfg.estimator_slope_sigma_um_per_c = 1.0;  // the other slots' σ: replaced by the model's
  cfg.estimator_model_slope_um_per_c = {2.0, 2.0, -1.0, 0.5};
  cfg.estimator_model_slope_sigma_um_per_c = {0.3, 0.3, 0.0, 0.2};
  Calibrator c;
  c.configure(cfg);
  SimMachine m(cfg, test_errors(), 0.0, 0.0, 0.1, 11);
  TimeNs now = 0;
  StepOutput out;
  const auto feed = [&](double temp_c) {
    const core::Event e = core::TemperatureSample{now, 0, temp_c};
    out.clear();
    c.step(now, {&e, 1}, out);
  };
  feed(20.0);
  run_calibrated_shift(c, m, now, 5.0, 2);  // an earlier shift: its slopes are learned
  feed(20.0);
  m.set_drift([](double) { return std::array<double, 4>{}; });
  ASSERT_TRUE(run_initial_calibration(c, m, now, out));
  const CalibState st = c.export_state();
  const std::array<double, 4> slope{2.0, 2.0, -1.0, 0.5};
  const std::array<double, 4> sigma{0.3, 0.3, 0.0, 0.2};
  for (std::size_t s = 0; s < 4; ++s) {
    EXPECT_DOUBLE_EQ(st.estimates[s].x[2], slope[s]) << s;
    EXPECT_DOUBLE_EQ(st.estimates[s].p[8], sigma[s] * sigma[s]) << s;
  }
  // Before the first touch: gain · prior + slope · ΔT; the prior is 0 at the nominals.
  const double t_nom = c.nominal(Slot::kXLateral).time_s;
  now = core::from_seconds(t_nom);
  feed(22.0);
  for (const Slot s : {Slot::kXLateral, Slot::kY, Slot::kZ}) {
    EXPECT_NEAR(c.estimated_drift(s, now).mean_um, 2.0 * slope[static_cast<std::size_t>(s)], 1e-9);
  }
  // A touch set 1 h on reading 3 µm more than the model on Y: σ 0 keeps Y's slope.
  const TimeNs t1 = now + core::from_seconds(3600.0);
  m.set_drift([t_nom](double t) {
    const double k = t > t_nom ? 1.0 : 0.0;
    return std::array<double, 4>{4.0 * k, 4.0 * k, 1.0 * k, 1.0 * k};
  });
  now = t1;
  out.clear();
  run_touch_set(c, m, now, out);
  EXPECT_DOUBLE_EQ(c.export_state().estimates[2].x[2], -1.0);
  EXPECT_NE(c.export_state().estimates[3].x[2], 0.5);  // σ 0.2: Z's slope learns
}

// GIVEN each slot's own input sensor (a drift model's prediction in µm, slope 1; Y's on the
// temperature sensor, slope 2) and the earlier shifts' mean drift switched off WHEN the next
// shift starts THEN each slot follows its own sensor from the nominals, the earlier shift's drift
// adds nothing, and a non-finite sample of a slot's sensor is refused with an alarm.
TEST(DriftEstimator, EachSlotTakesItsOwnInputSensorAndTheShiftPriorCanBeOff) {
  auto cfg = estimator_config();
  cfg.temperature_sensor = 0;
  cfg.estimator_input_sensors = {5, 5, -1, 7};
  cfg.max_temperature_slope_um_per_c = 2.0;  // an input step counts up to plausibility_um / 2
  cfg.estimator_model_slope_um_per_c = {1.0, 1.0, 2.0, 1.0};
  cfg.estimator_model_slope_sigma_um_per_c = {0.0, 0.0, 0.0, 0.0};
  for (const bool shift_prior : {true, false}) {
    cfg.estimator_shift_prior = shift_prior;
    Calibrator c;
    c.configure(cfg);
    SimMachine m(cfg, test_errors(), 0.0, 0.0, 0.1, 13);
    TimeNs now = 0;
    StepOutput out;
    const auto feed = [&](std::uint8_t sensor, double value) {
      const core::Event e = core::TemperatureSample{now, sensor, value};
      out.clear();
      c.step(now, {&e, 1}, out);
    };
    feed(0, 20.0);
    feed(5, 100.0);
    feed(7, -3.0);
    run_calibrated_shift(c, m, now, 6.0, 3);  // an earlier shift: 6 µm/h on X
    now += core::from_seconds(8.0 * 3600.0);
    m.set_drift([](double) { return std::array<double, 4>{}; });
    ASSERT_TRUE(run_initial_calibration(c, m, now, out));
    const double t_nom = c.nominal(Slot::kXLateral).time_s;
    EXPECT_DOUBLE_EQ(c.nominal(Slot::kXLateral).temp_c, 100.0);
    EXPECT_DOUBLE_EQ(c.nominal(Slot::kY).temp_c, 20.0);
    EXPECT_DOUBLE_EQ(c.nominal(Slot::kZ).temp_c, -3.0);
    now = core::from_seconds(t_nom + 1800.0);
    // The inputs as at the nominals: only the earlier shift's mean drift (3 µm at 0.5 h on X).
    EXPECT_NEAR(c.estimated_drift(Slot::kXLateral, now).mean_um, shift_prior ? 3.0 : 0.0, 1e-9);
    feed(5, 110.0);
    feed(0, 21.0);
    feed(7, -1.0);
    const double shape = shift_prior ? 3.0 : 0.0;
    EXPECT_NEAR(c.estimated_drift(Slot::kXLateral, now).mean_um, shape + 10.0, 1e-9);
    EXPECT_NEAR(c.estimated_drift(Slot::kXAxial, now).mean_um, shape + 10.0, 1e-9);
    EXPECT_NEAR(c.estimated_drift(Slot::kY, now).mean_um, shape / 2.0 + 2.0, 1e-9);
    EXPECT_NEAR(c.estimated_drift(Slot::kZ, now).mean_um, shape + 2.0, 1e-9);
    feed(7, std::nan(""));
    EXPECT_TRUE(has_alarm(out, AlarmCode::kCalibrationInvalidInput));
    EXPECT_NEAR(c.estimated_drift(Slot::kZ, now).mean_um, shape + 2.0, 1e-9);
  }
}

TEST(DriftEstimator, InputSensorsAreChecked) {
  auto cfg = estimator_config();
  cfg.estimator_model_slope_um_per_c = {1.0, 1.0, 1.0, 1.0};
  cfg.estimator_model_slope_sigma_um_per_c = {0.5, 0.5, 0.5, 0.5};
  cfg.estimator_input_sensors = {3, 3, 4, 5};  // every slot has a sensor: no temperature needed
  EXPECT_NO_THROW(core::calib::validate(cfg));
  cfg.estimator_input_sensors = {3, 3, -1, 5};  // Y has a model slope but no sensor
  try {
    core::calib::validate(cfg);
    FAIL() << "accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("calibration.temperature_sensor"), std::string::npos)
        << e.what();
  }
  cfg.estimator_input_sensors = {3, 3, 300, -2};
  try {
    core::calib::validate(cfg);
    FAIL() << "accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("calibration.estimator_input_sensors"), std::string::npos)
        << e.what();
  }
}

TEST(DriftEstimator, ConfigKeysAreChecked) {
  auto cfg = estimator_config();
  cfg.estimator_touch_noise_um = 0.0;
  cfg.estimator_prior_forgetting = 1.5;
  cfg.estimator_level_noise_um_per_h = -1.0;
  cfg.estimator_min_level_noise_um_per_h = 0.0;
  cfg.estimator_max_level_noise_um_per_h = -1.0;
  cfg.estimator_slope_sigma_um_per_c = 1.0;  // with no sensor mapped
  cfg.estimator_gate_sigmas = std::nan("");
  cfg.estimator_model_slope_um_per_c = {1.0, 1.0, 30.0, 0.0};  // Y beyond the slope bound 20
  cfg.estimator_model_slope_sigma_um_per_c = {0.1, -0.1, 0.1, std::nan("")};
  try {
    core::calib::validate(cfg);
    FAIL() << "accepted";
  } catch (const std::invalid_argument& e) {
    const std::string what = e.what();
    for (const char* key :
         {"calibration.estimator_touch_noise_um", "calibration.estimator_prior_forgetting",
          "calibration.estimator_level_noise_um_per_h", "calibration.temperature_sensor",
          "calibration.estimator_min_level_noise_um_per_h",
          "calibration.estimator_max_level_noise_um_per_h", "calibration.estimator_gate_sigmas",
          "calibration.estimator_model_slope_um_per_c",
          "calibration.estimator_model_slope_sigma_um_per_c"}) {
      EXPECT_NE(what.find(key), std::string::npos) << key << " in " << what;
    }
  }
}

}  // namespace
}  // namespace nccomp::test::calib
