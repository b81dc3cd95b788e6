// S3 figures: how many test grinds each facet rule needs, and the axis error over an 8-hour
// shift for: no recalibration; hourly recalibration with step corrections; hourly with creeping;
// hourly with creeping and prediction (time model, temperature model). Two drifts: a simulated
// first-order warm-up, and the real FL_THERMAL spindle drift (../shared/data/
// fl_thermal_spindle_drift, see its SOURCE.md).
//
//   bench_calib_shift [--data ../shared/data/fl_thermal_spindle_drift/data.csv] [--json]
//   (default: the one beside the source tree this was built from)
//
// Prints markdown tables (bench/results/calib.md); --json prints the FL_THERMAL rows only, one
// object per line: {"axis","strategy","shift","rms_um","first_hour_max_um"}.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <functional>
#include <span>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "core/calib/calibrator.hpp"
#include "core/calib/facet.hpp"
#include "core/model/ridge.hpp"
#include "tests/unit/calib/sim_machine.hpp"
#include "tests/unit/calib/test_config.hpp"

namespace {

using nccomp::core::Event;
using nccomp::core::from_seconds;
using nccomp::core::StepOutput;
using nccomp::core::TimeNs;
using nccomp::core::calib::CalibrationConfig;
using nccomp::core::calib::Calibrator;
using nccomp::core::calib::FacetRule;
using nccomp::core::calib::Prediction;
using nccomp::core::calib::Slot;
using nccomp::test::calib::MachineErrors;
using nccomp::test::calib::SimMachine;

constexpr double kTouchNoiseUm = 0.5;
constexpr double kChordNoiseUm = 0.5;

// ---------------------------------------------------------------------------------------------
// Facet rules.

void facet_table() {
  std::printf(
      "## Test grinds to convergence (blank radius 5 mm, tolerance 2 um of chord, "
      "chord noise %.1f um, touch noise %.1f um)\n\n",
      kChordNoiseUm, kTouchNoiseUm);
  std::printf(
      "The first grind's error is the reference probe's lateral pretravel (the touches "
      "cannot see it). Grinds include the final, confirming one; 'x' = not converged in "
      "30. Mean over 20 seeds; in brackets the worst seed.\n\n");
  const double matched_01 = nccomp::core::calib::matched_proportional_gain(5.0, 0.1);
  std::printf(
      "| first-grind error | facet depth | exact | proportional, gain matched at 0.1 mm "
      "(%.4f) | proportional, 0.5x | proportional, 2x | residual dxR - Ex, exact |\n",
      matched_01);
  std::printf("|---|---|---|---|---|---|---|\n");
  for (const double depth : {0.1, 0.05}) {
    for (const double err : {4.0, 15.0, 30.0, 60.0}) {
      std::printf("| %.0f um | %.2f mm |", err, depth);
      double worst_residual = 0.0;
      for (int variant = 0; variant < 4; ++variant) {
        double sum = 0.0;
        int worst = 0;
        int failed = 0;
        for (std::uint64_t seed = 1; seed <= 20; ++seed) {
          auto cfg = nccomp::test::calib::test_config();
          cfg.facet_rule = variant == 0 ? FacetRule::kExact : FacetRule::kProportional;
          cfg.facet_gain_um_per_um = matched_01 * (variant == 2 ? 0.5 : (variant == 3 ? 2.0 : 1.0));
          cfg.max_test_grinds = 30;
          cfg.end_face_test_grind = false;
          MachineErrors e = nccomp::test::calib::test_errors();
          e.pretravel_lateral_um = err;
          Calibrator c;
          c.configure(cfg);
          SimMachine m(cfg, e, kTouchNoiseUm, kChordNoiseUm, depth, seed);
          TimeNs now = 0;
          StepOutput out;
          if (!nccomp::test::calib::run_initial_calibration(c, m, now, out)) {
            ++failed;
            continue;
          }
          const int g = c.result().lateral_grinds;
          sum += g;
          worst = std::max(worst, g);
          if (variant == 0) {
            worst_residual = std::max(worst_residual, std::fabs(c.result().dx_r_um - e.ex_um));
          }
        }
        if (failed > 0) {
          std::printf(" x (%d/20 failed) |", failed);
        } else {
          std::printf(" %.2f (%d) |", sum / 20.0, worst);
        }
      }
      if (worst_residual > 0.0) {
        std::printf(" %.2f um |\n", worst_residual);
      } else {
        std::printf(" - |\n");
      }
    }
  }
  std::printf("\n");
}

// ---------------------------------------------------------------------------------------------
// Shift simulation.

// The estimator's temperature input: t5, or chosen before each shift by the fit on the earlier
// shifts: the best of the 16 FL sensors for X (ch3), t5 through a first-order lag with a fitted
// time constant, or both (sensor and lag).
// kValidated: sensor and lag, chosen by how well each earlier shift j >= 1 was predicted from
// the shifts before j (tried after the first run, see bench/results/calib.md).
// kShrunk: per axis a shrunk (ridge) model of the drift on every sensor and four lags of the
// spindle speed, fitted on the earlier shifts (shrunk_inputs()); each slot's estimator input is
// its axis's model (estimator_input_sensors), slope 1 +- 0.5 a priori.
enum class InputMode { kT5, kBestSensor, kT5Lag, kBestSensorLag, kValidated, kShrunk };

struct Strategy {
  const char* name;
  bool recalibrate;
  nccomp::core::ProfileShape shape;
  Prediction prediction;
  bool temperature_slope{false};  // estimator: also the t5 temperature slope
  double level_noise_um_per_h{6.0};
  double gate_sigmas{5.0};
  double slope_sigma_um_per_c{1.0};
  // Bound of the slope; with plausibility_um it bounds the temperature step the estimator
  // takes (calibrator.cpp, temperature_delta).
  double max_slope_um_per_c{20.0};
  // > 0: the sensor is a first-order lag of the spindle speed [krpm] with this time constant
  // [s], computed here from the data set's speed (what a speed-driven state would see).
  double speed_lag_s{0.0};
  // The prior of each shift's slope: a model fitted on the earlier shifts only (model_prior()).
  bool model_prior{false};
  // Which temperature input, chosen per shift on the earlier shifts only (choose_input()).
  InputMode input{InputMode::kT5};
  bool learn_level_noise{false};  // estimator_learn_level_noise (bounds 3..20 um/h)
  double gain_sigma{0.5};         // estimator_prior_gain_sigma: the shape's per-shift gain
  double forgetting{0.8};         // estimator_prior_forgetting: weight of older shifts' shape
};

// A model's slopes per slot and their sigma (CalibrationConfig::estimator_model_slope_*).
struct ModelPrior {
  std::array<double, 4> slope_um_per_c{};
  std::array<double, 4> sigma_um_per_c{};
  // > 0: max_temperature_slope_um_per_c for this shift (set with the fitted slopes).
  double max_slope_um_per_c{0.0};
};

const std::array<Strategy, 12> kStrategies{{
    {"none", false, nccomp::core::ProfileShape::kStep, Prediction::kNone},
    {"hourly, step", true, nccomp::core::ProfileShape::kStep, Prediction::kNone},
    {"hourly, creep", true, nccomp::core::ProfileShape::kCosine, Prediction::kNone},
    {"hourly, creep + time model", true, nccomp::core::ProfileShape::kCosine, Prediction::kTime},
    {"hourly, creep + temperature model", true, nccomp::core::ProfileShape::kCosine,
     Prediction::kTemperature},
    {"hourly, creep + estimator", true, nccomp::core::ProfileShape::kCosine,
     Prediction::kEstimator},
    {"hourly, creep + estimator with temperature", true, nccomp::core::ProfileShape::kCosine,
     Prediction::kEstimator, true},
    {"hourly, creep + estimator with temperature, slope bound 5 um/degC", true,
     nccomp::core::ProfileShape::kCosine, Prediction::kEstimator, true, 6.0, 5.0, 1.0, 5.0},
    {"hourly, creep + estimator with the earlier shifts' t5 model", true,
     nccomp::core::ProfileShape::kCosine, Prediction::kEstimator, true, 6.0, 5.0, 1.0, 5.0, 0.0,
     true},
    {"hourly, creep + estimator, level noise learned from the earlier shifts", true,
     nccomp::core::ProfileShape::kCosine, Prediction::kEstimator, false, 6.0, 5.0, 1.0, 20.0, 0.0,
     false, InputMode::kT5, true},
    {"hourly, creep + estimator with a shrunk model of every sensor fitted on the earlier shifts",
     true, nccomp::core::ProfileShape::kCosine, Prediction::kEstimator, false, 6.0, 5.0, 0.5, 1.0,
     0.0, false, InputMode::kShrunk},
    {"hourly, creep + estimator with the sensor and lag fitted on the earlier shifts", true,
     nccomp::core::ProfileShape::kCosine, Prediction::kEstimator, true, 6.0, 5.0, 1.0, 5.0, 0.0,
     true, InputMode::kBestSensorLag},
}};

struct AxisStats {
  double rms_um{0.0};
  double max_um{0.0};
  double max_jump_um{0.0};  // largest change of the applied correction within one second
  double rms_after_first_touch_um{0.0};
  double first_hour_max_um{0.0};  // before the first touch
};

using DriftFn = std::function<std::array<double, 4>(double t_s)>;  // from shift start
using TempFn = std::function<double(double t_s)>;
// Per axis (X, Y, Z) an estimator input of its own, on sensors 1, 2, 3 (X lateral and axial
// share X's): CalibrationConfig::estimator_input_sensors.
using AxisInputs = std::array<TempFn, 3>;

// carried: the calibration state the machine ends its previous shift with; it is replaced by
// this shift's final state. Only the earlier shifts' drift in it
// (CalibState::shifts) outlives the new calibration at the shift start.
std::array<AxisStats, 3> run_shift(const Strategy& s, const DriftFn& drift, const TempFn& temp,
                                   double tau_s, double hours,
                                   nccomp::core::calib::CalibState* carried = nullptr,
                                   const ModelPrior* model = nullptr,
                                   const AxisInputs* inputs = nullptr) {
  auto cfg = nccomp::test::calib::test_config();
  cfg.touches_per_axis = 1;
  cfg.creep_shape = s.shape;
  cfg.creep_duration_s = 600.0;
  cfg.prediction = s.prediction;
  cfg.thermal_time_constant_s = tau_s;
  cfg.temperature_sensor = temp ? 0 : -1;
  cfg.recalibration_interval_s = 3600.0;
  cfg.plausibility_um = 50.0;
  // Estimator noises chosen a priori (docs/calibration.md), not fitted to these data: touch
  // σ 0.5 µm on the touch and on the nominal, so about 0.7 µm on the drift.
  cfg.estimator_touch_noise_um = 0.7;
  cfg.estimator_prior_gain_sigma = s.gain_sigma;
  cfg.estimator_prior_forgetting = s.forgetting;
  cfg.estimator_learn_level_noise = s.learn_level_noise;
  cfg.estimator_slope_sigma_um_per_c = s.temperature_slope ? s.slope_sigma_um_per_c : 0.0;
  cfg.max_temperature_slope_um_per_c = s.max_slope_um_per_c;
  if (model != nullptr && model->max_slope_um_per_c > 0.0) {
    cfg.max_temperature_slope_um_per_c = model->max_slope_um_per_c;
  }
  if (model != nullptr) {
    cfg.estimator_model_slope_um_per_c = model->slope_um_per_c;
    cfg.estimator_model_slope_sigma_um_per_c = model->sigma_um_per_c;
  }
  cfg.estimator_level_noise_um_per_h = s.level_noise_um_per_h;
  cfg.estimator_gate_sigmas = s.gate_sigmas;
  if (inputs != nullptr) {
    cfg.estimator_input_sensors = {1, 1, 2, 3};
    cfg.estimator_shift_prior = false;
  }
  Calibrator c;
  c.configure(cfg);
  if (carried != nullptr) {
    c.import_state(*carried);
  }
  SimMachine m(cfg, nccomp::test::calib::test_errors(), kTouchNoiseUm, kChordNoiseUm, 0.1, 42);
  StepOutput out;
  // Calibrate (and take the nominals) at the start of the shift, on the machine as it is then.
  TimeNs now = 0;
  const auto feed_temp = [&](double t_shift_s) {
    if (temp) {
      const Event e = nccomp::core::TemperatureSample{now, 0, temp(t_shift_s)};
      out.clear();
      c.step(now, {&e, 1}, out);
    }
    if (inputs != nullptr) {
      for (std::uint8_t a = 0; a < 3; ++a) {
        const Event e = nccomp::core::TemperatureSample{
            now, static_cast<std::uint8_t>(a + 1), (*inputs)[a](t_shift_s)};
        out.clear();
        c.step(now, {&e, 1}, out);
      }
    }
  };
  feed_temp(0.0);
  m.set_drift([](double) { return std::array<double, 4>{}; });
  if (!nccomp::test::calib::run_initial_calibration(c, m, now, out)) {
    throw std::runtime_error("calibration failed");
  }
  for (int i = 0; i < 60; ++i) {  // the limiter slews the registers to the calibration values
    out.clear();
    c.step(now, {}, out);
    now += from_seconds(1.0);
  }
  const std::array<double, 3> base{c.result().dx_r_um, c.result().dy_um, c.result().dz_um};
  const double t0 = nccomp::core::seconds(now);
  m.set_drift([&drift, t0](double t) { return drift(t - t0); });
  std::array<double, 3> sum2{};
  std::array<double, 3> sum2_late{};
  std::array<AxisStats, 3> st{};
  std::array<double, 3> prev{};
  const auto steps = static_cast<long>(hours * 3600.0);
  for (long k = 0; k < steps; ++k) {
    const double t = static_cast<double>(k);
    now = from_seconds(t0 + t);
    if ((temp || inputs != nullptr) && k % 15 == 0) {
      feed_temp(t);  // the sensor is sampled like the data set: every 15 s
    }
    out.clear();
    if (s.recalibrate && k > 0 && k % 3600 == 0) {
      nccomp::test::calib::run_touch_set(c, m, now, out);
      for (const auto& a : out.alarms) {
        if (a.severity == nccomp::core::Severity::kAlarm) {
          std::fprintf(stderr, "alarm %d at %.0f s value %.2f\n", static_cast<int>(a.code), t,
                       a.value);
        }
      }
    } else {
      c.step(now, {}, out);
    }
    const auto truth = drift(t);
    for (std::size_t a = 0; a < 3; ++a) {
      // What the NC applies: the register value after the limiter, minus the calibration.
      const double corr = c.written_um(a) - base[a];
      const double err = truth[nccomp::core::calib::kAxisSlot[a]] - corr;
      sum2[a] += err * err;
      st[a].max_um = std::max(st[a].max_um, std::fabs(err));
      if (k >= 3600) {
        sum2_late[a] += err * err;
      } else {
        st[a].first_hour_max_um = std::max(st[a].first_hour_max_um, std::fabs(err));
      }
      if (k > 0) {
        st[a].max_jump_um = std::max(st[a].max_jump_um, std::fabs(corr - prev[a]));
      }
      prev[a] = corr;
    }
  }
  for (std::size_t a = 0; a < 3; ++a) {
    st[a].rms_um = std::sqrt(sum2[a] / static_cast<double>(steps));
    st[a].rms_after_first_touch_um = std::sqrt(sum2_late[a] / static_cast<double>(steps - 3600));
  }
  if (carried != nullptr) {
    *carried = c.export_state();
  }
  return st;
}

void first_order_table() {
  const double tau_true = 5400.0;
  const DriftFn drift = [tau_true](double t) {
    const double f = 1.0 - std::exp(-std::max(0.0, t) / tau_true);
    return std::array<double, 4>{30.0 * f, 34.0 * f, -12.0 * f, 18.0 * f};
  };
  std::printf(
      "## 8-hour shift, simulated first-order warm-up (X: 30 um, tau 1.5 h; touch noise "
      "%.1f um; touches every hour; creep 600 s cosine)\n\n",
      kTouchNoiseUm);
  std::printf(
      "| strategy | model tau | X RMS error | X RMS error after the first touch (1-8 h) "
      "| X max error | largest 1-s change of the applied X correction |\n"
      "|---|---|---|---|---|---|\n");
  for (const auto& s : kStrategies) {
    if (s.prediction == Prediction::kTemperature || s.prediction == Prediction::kEstimator) {
      continue;  // no temperature, no earlier shifts in this simulation
    }
    const std::array<double, 3> taus{5400.0, 3600.0, 10800.0};
    const std::array<const char*, 3> tau_names{"1.5 h (true)", "1 h", "3 h"};
    for (std::size_t i = 0; i < taus.size(); ++i) {
      if (s.prediction != Prediction::kTime && i > 0) {
        continue;
      }
      const auto st = run_shift(s, drift, nullptr, taus[i], 8.0);
      std::printf("| %s | %s | %.2f um | %.2f um | %.2f um | %.2f um |\n", s.name,
                  s.prediction == Prediction::kTime ? tau_names[i] : "-", st[0].rms_um,
                  st[0].rms_after_first_touch_um, st[0].max_um, st[0].max_jump_um);
    }
  }
  std::printf("\n");
}

// ---------------------------------------------------------------------------------------------
// FL_THERMAL.

struct Thermal {
  std::vector<double> t_s, ch1, ch3, ch5, t5, rpm;
  std::array<std::vector<double>, 16> t;  // t1..t16
};

Thermal load_thermal(const std::string& path) {
  std::ifstream in(path);
  if (!in) {
    throw std::runtime_error(path + ": cannot be read");
  }
  Thermal d;
  std::string line;
  std::size_t line_no = 0;
  while (std::getline(in, line)) {
    ++line_no;
    if (line_no == 1) {
      if (line.find("spindle(RPM)") == std::string::npos ||
          line.find("ch5(um)") == std::string::npos) {
        throw std::runtime_error(path + ":1: not the FL_THERMAL header");
      }
      continue;
    }
    std::vector<double> v;
    std::stringstream ss(line);
    std::string cell;
    while (std::getline(ss, cell, ',')) {
      std::size_t used = 0;
      double x = 0.0;
      try {
        x = std::stod(cell, &used);
      } catch (const std::exception&) {
        used = 0;
      }
      if (used == 0 || !std::isfinite(x)) {
        throw std::runtime_error(path + ":" + std::to_string(line_no) + ": column " +
                                 std::to_string(v.size() + 1) + " is not a number: '" + cell + "'");
      }
      v.push_back(x);
    }
    if (v.size() != 23) {
      throw std::runtime_error(path + ":" + std::to_string(line_no) +
                               ": expected 23 columns, got " + std::to_string(v.size()));
    }
    if (!d.t_s.empty() && v[0] <= d.t_s.back()) {
      throw std::runtime_error(path + ":" + std::to_string(line_no) + ": time not increasing");
    }
    d.t_s.push_back(v[0]);
    d.rpm.push_back(v[1]);
    d.ch1.push_back(v[2]);
    d.ch3.push_back(v[4]);
    d.ch5.push_back(v[6]);
    d.t5.push_back(v[11]);  // t5(°C): column 12 (time, rpm, ch1..ch5, t1..t16)
    for (std::size_t i = 0; i < d.t.size(); ++i) {
      d.t[i].push_back(v[7 + i]);
    }
  }
  return d;
}

double interp(const std::vector<double>& t, const std::vector<double>& y, double x) {
  if (x <= t.front()) {
    return y.front();
  }
  if (x >= t.back()) {
    return y.back();
  }
  const auto it = std::upper_bound(t.begin(), t.end(), x);
  const auto i = static_cast<std::size_t>(it - t.begin());
  const double f = (x - t[i - 1]) / (t[i] - t[i - 1]);
  return y[i - 1] + f * (y[i] - y[i - 1]);
}

// A first-order lag of x (the data's 15 s step) with time constant tau_s, from x's first value;
// tau_s 0: x itself. Causal: each value depends on the past only.
std::vector<double> lag_series(const std::vector<double>& x, double tau_s) {
  if (!(tau_s > 0.0)) {
    return x;
  }
  const double a = 1.0 - std::exp(-15.0 / tau_s);
  std::vector<double> y;
  y.reserve(x.size());
  double v = x.front();
  for (const double xi : x) {
    v += a * (xi - v);
    y.push_back(v);
  }
  return y;
}

struct InputChoice {
  std::size_t sensor{4};  // index into Thermal::t (4 = t5)
  double tau_s{0.0};
  double r2{0.0};
};

// The temperature input for X, chosen on the shifts before shift k only: among the sensors and
// lags the mode allows, the one whose least-squares line through 0 (drift of ch3 on the change
// of the input, both relative to the shift start, every 15 s sample of shifts 0..k-1) leaves
// the smallest residual: R² = 1 − Σ(y − b·x)² / Σy².
InputChoice choose_input(const Thermal& d, const std::array<double, 5>& starts, std::size_t k,
                         InputMode mode) {
  const bool validated = mode == InputMode::kValidated && k >= 2;
  const bool any_sensor = mode == InputMode::kBestSensor || mode == InputMode::kBestSensorLag ||
                          mode == InputMode::kValidated;
  const bool any_lag = mode == InputMode::kT5Lag || mode == InputMode::kBestSensorLag ||
                       mode == InputMode::kValidated;
  InputChoice best{4, 0.0, -1e300};
  double best_sse = 1e300;
  for (std::size_t sensor = 0; sensor < d.t.size(); ++sensor) {
    if (!any_sensor && sensor != 4) {
      continue;
    }
    for (const double tau_min : {0.0, 15.0, 30.0, 60.0, 90.0, 120.0, 180.0, 240.0}) {
      if (!any_lag && tau_min > 0.0) {
        continue;
      }
      const std::vector<double> x = lag_series(d.t[sensor], tau_min * 60.0);
      double sxy = 0.0;
      double sxx = 0.0;
      double syy = 0.0;
      double sse = 0.0;  // validated: shift j predicted with the slope of shifts 0..j-1
      for (std::size_t j = 0; j < k; ++j) {
        const double b_before = sxx > 0.0 ? sxy / sxx : 0.0;
        double jxy = 0.0;
        double jxx = 0.0;
        double jyy = 0.0;
        const auto i0 = static_cast<std::size_t>(
            std::lower_bound(d.t_s.begin(), d.t_s.end(), starts[j] * 3600.0) - d.t_s.begin());
        for (std::size_t i = i0; i < d.t_s.size() && d.t_s[i] < (starts[j] + 8.0) * 3600.0; ++i) {
          const double xi = x[i] - x[i0];
          const double yi = d.ch3[i] - d.ch3[i0];
          jxy += xi * yi;
          jxx += xi * xi;
          jyy += yi * yi;
        }
        if (j > 0) {
          sse += jyy - 2.0 * b_before * jxy + b_before * b_before * jxx;
        }
        sxy += jxy;
        sxx += jxx;
        syy += jyy;
      }
      if (!(sxx > 0.0) || !(syy > 0.0)) {
        continue;
      }
      const double r2 = sxy * sxy / (sxx * syy);  // = 1 − Σ(y − b·x)² / Σy² at b = sxy / sxx
      if (validated ? sse < best_sse : r2 > best.r2) {
        best = {sensor, tau_min * 60.0, r2};
        best_sse = sse;
      }
    }
  }
  return best;
}

// What nccomp analyze's thermal_drift term would give from the shifts before shift k: per axis
// the least-squares slope of the drift on the temperature (both relative to the shift start,
// every 15 s sample of shifts 0..k-1), clamped to the slope bound. Its sigma: the samples of
// a shift are serially correlated, so the shifts are the independent units: the standard
// deviation of the per-shift slopes times sqrt(1 + 1/n) (the spread of a new shift's slope);
// with one earlier shift there is no spread and the configured sigma stays. Nothing of shift k
// itself enters.
ModelPrior model_prior(const Thermal& d, const std::vector<double>& input,
                       const std::array<double, 5>& starts, std::size_t k, double fallback_sigma,
                       double bound) {
  ModelPrior m;
  const std::array<const std::vector<double>*, 3> ch{&d.ch3, &d.ch1, &d.ch5};
  for (std::size_t a = 0; a < 3; ++a) {
    double sxy = 0.0;
    double sxx = 0.0;
    std::vector<double> per_shift;
    for (std::size_t j = 0; j < k; ++j) {
      const auto i0 = static_cast<std::size_t>(
          std::lower_bound(d.t_s.begin(), d.t_s.end(), starts[j] * 3600.0) - d.t_s.begin());
      double jxy = 0.0;
      double jxx = 0.0;
      for (std::size_t i = i0; i < d.t_s.size() && d.t_s[i] < (starts[j] + 8.0) * 3600.0; ++i) {
        const double x = input[i] - input[i0];
        const double y = (*ch[a])[i] - (*ch[a])[i0];
        jxy += x * y;
        jxx += x * x;
      }
      sxy += jxy;
      sxx += jxx;
      per_shift.push_back(jxy / jxx);
    }
    const double b = std::clamp(sxy / sxx, -bound, bound);
    double sigma = fallback_sigma;
    if (per_shift.size() >= 2) {
      const double n = static_cast<double>(per_shift.size());
      double mean = 0.0;
      for (const double v : per_shift) {
        mean += v / n;
      }
      double ss = 0.0;
      for (const double v : per_shift) {
        ss += (v - mean) * (v - mean);
      }
      sigma = std::sqrt(ss / (n - 1.0)) * std::sqrt(1.0 + 1.0 / n);
    }
    const std::array<std::size_t, 3> first_slot{0, 2, 3};
    m.slope_um_per_c[first_slot[a]] = b;
    m.sigma_um_per_c[first_slot[a]] = sigma;
    if (a == 0) {  // X axial: the same gauge as X lateral in this replay
      m.slope_um_per_c[1] = b;
      m.sigma_um_per_c[1] = sigma;
    }
  }
  return m;
}

// The shrunk model of InputMode::kShrunk for shift k: per axis (ch3, ch1, ch5) a ridge fit
// (core/model/ridge.hpp) of the gauge on the 16 temperatures and four first-order lags of the
// spindle speed [krpm] (tau 15, 45, 135, 405 min), on every 15 s sample of shifts 0..k-1 only;
// lambda among 1e-4..1 by the rolling-origin error over 4 blocks of those samples. Returns the
// model's value at every sample of the data set (what a derived sensor, [[input_sums]] over the
// sensors and [[input_lags]] of the speed, would publish).
struct ShrunkInputs {
  std::array<std::vector<double>, 3> value;
  std::array<double, 3> lambda{};
  std::array<double, 3> rolling_rms_um{};
};

ShrunkInputs shrunk_inputs(const Thermal& d, const std::array<double, 5>& starts, std::size_t k) {
  constexpr std::array<double, 4> kSpeedLagsS{900.0, 2700.0, 8100.0, 24300.0};
  constexpr std::array<double, 5> kLambdas{1e-4, 1e-3, 1e-2, 1e-1, 1.0};
  const std::size_t inputs = d.t.size() + kSpeedLagsS.size();
  std::vector<double> krpm;
  krpm.reserve(d.rpm.size());
  for (const double r : d.rpm) {
    krpm.push_back(r / 1000.0);
  }
  std::vector<std::vector<double>> columns(d.t.begin(), d.t.end());
  for (const double tau : kSpeedLagsS) {
    columns.push_back(lag_series(krpm, tau));
  }
  const auto n = static_cast<Eigen::Index>(d.t_s.size());
  Eigen::MatrixXd all(n, static_cast<Eigen::Index>(inputs));
  for (std::size_t j = 0; j < inputs; ++j) {
    for (Eigen::Index i = 0; i < n; ++i) {
      all(i, static_cast<Eigen::Index>(j)) = columns[j][static_cast<std::size_t>(i)];
    }
  }
  const auto fitted = static_cast<Eigen::Index>(
      std::lower_bound(d.t_s.begin(), d.t_s.end(), starts[k] * 3600.0) - d.t_s.begin());
  const std::array<const std::vector<double>*, 3> ch{&d.ch3, &d.ch1, &d.ch5};
  ShrunkInputs out;
  for (std::size_t a = 0; a < 3; ++a) {
    const Eigen::Map<const Eigen::VectorXd> y(ch[a]->data(), fitted);
    const auto f = nccomp::core::model::fit_ridge_rolling(all.topRows(fitted), y, kLambdas, 4);
    out.lambda[a] = f.lambda;
    out.rolling_rms_um[a] = *std::min_element(f.rolling_rms.begin(), f.rolling_rms.end());
    out.value[a].reserve(static_cast<std::size_t>(n));
    std::vector<double> row(inputs);
    for (Eigen::Index i = 0; i < n; ++i) {
      for (std::size_t j = 0; j < inputs; ++j) {
        row[j] = all(i, static_cast<Eigen::Index>(j));
      }
      out.value[a].push_back(f.predict(row));
    }
  }
  return out;
}

struct ShrunkLog {
  std::string strategy;
  std::size_t shift;
  std::array<double, 3> lambda;
  std::array<double, 3> rolling_rms_um;
};
std::vector<ShrunkLog> shrunk_log;  // the fits the shrunk-model rows used, per shift

struct Row {
  const char* strategy;
  std::size_t axis;
  std::array<AxisStats, 5> shift;
};

constexpr std::array<const char*, 3> kAxisNames{"X (ch3)", "Y (ch1)", "Z (ch5)"};

struct ModelLog {
  const char* strategy;
  std::size_t shift;
  ModelPrior prior;
};
std::vector<ModelLog> model_log;  // the priors the model rows used, printed below them

struct InputLog {
  std::string strategy;
  std::size_t shift;
  InputChoice choice;
  ModelPrior prior;
};
std::vector<InputLog> input_log;  // the inputs the fitted-input rows chose, per shift

std::vector<Row> thermal_rows(const Thermal& d, const std::array<double, 5>& starts,
                              std::span<const Strategy> strategies) {
  std::vector<Row> rows;
  for (const auto& s : strategies) {
    std::array<std::array<AxisStats, 3>, 5> res{};
    // The shifts run in the data set's order on one machine: the state each ends with goes into
    // the next, so shift k is seeded by shifts 0..k-1 (shift 0 by none) and scored on its own
    // data only. A default state is a new machine.
    nccomp::core::calib::CalibState carried{};
    for (std::size_t k = 0; k < starts.size(); ++k) {
      const double t_start = starts[k] * 3600.0;
      const std::array<double, 3> zero{interp(d.t_s, d.ch3, t_start), interp(d.t_s, d.ch1, t_start),
                                       interp(d.t_s, d.ch5, t_start)};
      const DriftFn drift = [&d, t_start, zero](double t) {
        const double x = t_start + std::max(0.0, t);
        const double dx = interp(d.t_s, d.ch3, x) - zero[0];
        return std::array<double, 4>{dx, dx, interp(d.t_s, d.ch1, x) - zero[1],
                                     interp(d.t_s, d.ch5, x) - zero[2]};
      };
      std::vector<double> lagged;
      ModelPrior prior;
      const bool shrunk = s.input == InputMode::kShrunk && k > 0;
      const bool fitted_input = s.input != InputMode::kT5 && s.input != InputMode::kShrunk && k > 0;
      ShrunkInputs model_inputs;
      AxisInputs axis_inputs;
      if (shrunk) {
        // Slope 1 +- the row's slope sigma on each axis's model (the model predicts the drift in
        // um; 0.5 in the main row, the gain sigma of the other rows), bound the row's slope bound
        // (1 in the main row: the model's term moves an axis at most plausibility_um from its
        // nominal, like a temperature term at its bound; shrunk_table() varies both). The
        // earlier shifts' mean drift is not a regressor (estimator_shift_prior = false): the
        // model predicts the shape.
        model_inputs = shrunk_inputs(d, starts, k);
        prior.slope_um_per_c = {1.0, 1.0, 1.0, 1.0};
        prior.sigma_um_per_c.fill(s.slope_sigma_um_per_c);
        prior.max_slope_um_per_c = s.max_slope_um_per_c;
        for (std::size_t a = 0; a < 3; ++a) {
          axis_inputs[a] = [&d, &model_inputs, a, t_start](double t) {
            return interp(d.t_s, model_inputs.value[a], t_start + std::max(0.0, t));
          };
        }
        shrunk_log.push_back({s.name, k, model_inputs.lambda, model_inputs.rolling_rms_um});
      }
      if (fitted_input) {
        // Sensor and lag from the earlier shifts, the model's slopes on that input from them
        // too; the slope bound 1.25 x the largest fitted slope (at least the row's bound).
        const InputChoice ch = choose_input(d, starts, k, s.input);
        lagged = lag_series(d.t[ch.sensor], ch.tau_s);
        prior = model_prior(d, lagged, starts, k, s.slope_sigma_um_per_c, 1e9);
        double largest = 0.0;
        for (const double b : prior.slope_um_per_c) {
          largest = std::max(largest, std::fabs(b));
        }
        prior.max_slope_um_per_c = std::max(s.max_slope_um_per_c, 1.25 * largest);
        input_log.push_back({s.name, k, ch, prior});
      } else if (s.speed_lag_s > 0.0) {
        const double a = 1.0 - std::exp(-15.0 / s.speed_lag_s);  // the data's 15 s step
        double y = 0.0;
        for (const double rpm : d.rpm) {
          y += a * (rpm / 1000.0 - y);
          lagged.push_back(y);
        }
      }
      TempFn temp = [&d, &lagged, t_start](double t) {
        return interp(d.t_s, lagged.empty() ? d.t5 : lagged, t_start + std::max(0.0, t));
      };
      if (s.input == InputMode::kShrunk && !s.temperature_slope) {
        temp = nullptr;  // shift 0: the estimator without a temperature, as "hourly, creep + estimator"
      }
      const bool with_model = s.model_prior && k > 0;
      if (with_model && !fitted_input) {
        prior = model_prior(d, d.t5, starts, k, s.slope_sigma_um_per_c, s.max_slope_um_per_c);
        model_log.push_back({s.name, k, prior});
      }
      res[k] = run_shift(s, drift, temp, 3600.0, 8.0, &carried,
                         with_model || shrunk ? &prior : nullptr, shrunk ? &axis_inputs : nullptr);
    }
    for (std::size_t a = 0; a < 3; ++a) {
      Row r{s.name, a, {}};
      for (std::size_t k = 0; k < starts.size(); ++k) {
        r.shift[k] = res[k][a];
      }
      rows.push_back(r);
    }
  }
  return rows;
}

// The rest of a summary row: per axis of variant i, mean RMS over the shifts / largest
// first-hour error.
void print_summary(const std::vector<Row>& rows, std::size_t i) {
  for (std::size_t a = 0; a < 3; ++a) {
    const Row& r = rows[i * 3 + a];
    double mean = 0.0;
    double worst = 0.0;
    for (const auto& st : r.shift) {
      mean += st.rms_um / static_cast<double>(r.shift.size());
      worst = std::max(worst, st.first_hour_max_um);
    }
    std::printf(" %.2f / %.2f |", mean, worst);
  }
  std::printf("\n");
}

// Which input drives the estimator's slope state: t5 with the slope bound of the config default
// (20 um/degC) and of 5 um/degC, and a first-order lag of the spindle speed with several time
// constants. Level noise 6 um/h, gate 5 sigma, the earlier shifts' mean drift as the prior.
void input_table(const Thermal& d, const std::array<double, 5>& starts) {
  std::printf(
      "### Estimator: which input drives the slope state\n\n"
      "Mean RMS over the five shifts / largest first-hour error [um]. Speed lag: the sensor is "
      "a first-order lag of the spindle speed in krpm, computed by the bench from the data "
      "set's speed (slope in um/krpm). Level noise 6 um/h, gate 5 sigma.\n\n"
      "| input | slope bound | slope sigma | X | Y | Z |\n|---|---|---|---|---|---|\n");
  std::vector<Strategy> variants;
  for (const double lag : {0.0, 900.0, 1800.0, 3600.0, 5400.0}) {
    for (const double bound : {20.0, 5.0}) {
      if (lag > 0.0 && bound > 5.0) {
        continue;  // the speed in krpm: the default bound would stop it at 2.5 krpm
      }
      for (const double sigma : {1.0, 5.0}) {
        variants.push_back({"", true, nccomp::core::ProfileShape::kCosine, Prediction::kEstimator,
                            true, 6.0, 5.0, sigma, bound, lag});
      }
    }
  }
  const std::vector<Row> rows = thermal_rows(d, starts, variants);
  for (std::size_t i = 0; i < variants.size(); ++i) {
    const auto& v = variants[i];
    if (v.speed_lag_s > 0.0) {
      std::printf("| speed lag %.0f min | %.0f | %.0f |", v.speed_lag_s / 60.0,
                  v.max_slope_um_per_c, v.slope_sigma_um_per_c);
    } else {
      std::printf("| t5 | %.0f | %.0f |", v.max_slope_um_per_c, v.slope_sigma_um_per_c);
    }
    print_summary(rows, i);
  }
  std::printf("\n");
}

// X (issue 22 item 3): what a thermal engineer would try, each fitted on the earlier shifts
// only. The shape: the earlier shifts' mean drift since the nominals (the shifts start with the
// spindle's warm start) times a per-shift gain the touches learn, with the gain's prior σ and
// the older shifts' weight varied. A second temperature: the FL sensor that explains ch3 best on
// the earlier shifts. A first-order thermal lag: of t5 or of any sensor, its time constant
// fitted on the earlier shifts.
void x_table(const Thermal& d, const std::array<double, 5>& starts) {
  std::printf(
      "### X: the shape, a second temperature, a thermal lag (fitted on the earlier shifts only)\n"
      "\nMean RMS over the five shifts / largest first-hour error [um]. Level noise 6 um/h "
      "unless learned, gate 5 sigma. Fitted inputs: before each shift k >= 1 the sensor (t1..t16) "
      "and / or the lag (0, 15, 30, 60, 90, 120, 180, 240 min) with the best R^2 for ch3 on shifts "
      "0..k-1, the model's slopes on it as the prior (sigma from the per-shift spread), the slope "
      "bound 1.25 x the largest fitted slope; shift 0-8 h runs with t5.\n\n"
      "| variant | gain sigma | forgetting | X | Y | Z |\n|---|---|---|---|---|---|\n");
  using nccomp::core::ProfileShape;
  std::vector<Strategy> v;
  std::vector<std::string> names;
  for (const double forgetting : {0.8, 1.0, 0.5}) {
    for (const double gain : {0.5, 1.0, 2.0}) {
      v.push_back({"shape", true, ProfileShape::kCosine, Prediction::kEstimator});
      v.back().gain_sigma = gain;
      v.back().forgetting = forgetting;
      names.emplace_back("shape (no temperature)");
    }
  }
  const std::array<std::pair<InputMode, const char*>, 4> inputs{
      {{InputMode::kBestSensor, "best sensor for ch3"},
       {InputMode::kT5Lag, "t5 with a fitted lag"},
       {InputMode::kBestSensorLag, "best sensor and lag"},
       {InputMode::kValidated, "sensor and lag that predicted each earlier shift best"}}};
  for (const auto& [mode, name] : inputs) {
    for (const bool learn : {false, true}) {
      v.push_back({"input", true, ProfileShape::kCosine, Prediction::kEstimator, true, 6.0, 5.0,
                   1.0, 5.0, 0.0, true, mode, learn});
      names.push_back(std::string(name) + (learn ? ", level noise learned" : ""));
    }
  }
  v.push_back({"shape", true, ProfileShape::kCosine, Prediction::kEstimator, false, 6.0, 5.0, 1.0,
               20.0, 0.0, false, InputMode::kT5, true});
  names.emplace_back("shape, level noise learned");
  const std::vector<Row> rows = thermal_rows(d, starts, v);
  for (std::size_t i = 0; i < v.size(); ++i) {
    std::printf("| %s | %.1f | %.1f |", names[i].c_str(), v[i].gain_sigma, v[i].forgetting);
    print_summary(rows, i);
  }
  std::printf(
      "\n### The fitted inputs of the row \"%s\"\n\n"
      "| shift | sensor | lag [min] | R^2 on the earlier shifts | X slope [um/degC] | Y | Z | "
      "slope bound |\n|---|---|---|---|---|---|---|---|\n",
      kStrategies.back().name);
  for (const auto& l : input_log) {
    if (l.strategy != kStrategies.back().name) {
      continue;
    }
    std::printf("| %.0f-%.0f h | t%zu | %.0f | %.3f |", starts[l.shift], starts[l.shift] + 8.0,
                l.choice.sensor + 1, l.choice.tau_s / 60.0, l.choice.r2);
    for (const std::size_t slot : {0U, 2U, 3U}) {
      std::printf(" %+.2f +- %.2f |", l.prior.slope_um_per_c[slot], l.prior.sigma_um_per_c[slot]);
    }
    std::printf(" %.2f |\n", l.prior.max_slope_um_per_c);
  }
  std::printf("\n");
}

// The shrunk-model row's two a-priori choices varied: the slope's sigma and its bound (which also
// bounds how far the model's term moves an axis: plausibility_um 50 / bound).
void shrunk_table(const Thermal& d, const std::array<double, 5>& starts) {
  std::printf(
      "### The shrunk model as the input: its slope's sigma and bound\n\n"
      "Mean RMS over the five shifts / largest first-hour error [um]; the row \"%s\" with "
      "the slope sigma and bound varied (the main row: 0.5, 1).\n\n"
      "| slope sigma | slope bound | X | Y | Z |\n|---|---|---|---|---|\n",
      kStrategies[kStrategies.size() - 2].name);
  std::vector<Strategy> v;
  for (const double sigma : {0.0, 0.2, 0.5, 1.0}) {
    for (const double bound : {1.0, 1.25, 2.0}) {
      v.push_back(kStrategies[kStrategies.size() - 2]);
      v.back().slope_sigma_um_per_c = sigma;
      v.back().max_slope_um_per_c = bound;
    }
  }
  const std::vector<Row> rows = thermal_rows(d, starts, v);
  for (std::size_t i = 0; i < v.size(); ++i) {
    std::printf("| %.1f | %.2f |", v[i].slope_sigma_um_per_c, v[i].max_slope_um_per_c);
    print_summary(rows, i);
  }
  std::printf("\n");
}

void thermal_tables(const std::string& path, bool json) {
  const Thermal d = load_thermal(path);
  const std::array<double, 5> starts{0.0, 8.0, 16.0, 24.0, 32.0};
  const std::vector<Row> rows = thermal_rows(d, starts, kStrategies);
  if (json) {
    // One object per strategy, axis and shift, then per strategy and axis over all shifts
    // ("all": mean RMS, largest first-hour error) and over the seeded shifts 8-40 h.
    for (const auto& r : rows) {
      const auto emit = [&](const std::string& shift, double rms, double first) {
        std::printf(
            "{\"axis\":\"%c\",\"strategy\":\"%s\",\"shift\":\"%s\",\"rms_um\":%.4f,"
            "\"first_hour_max_um\":%.4f}\n",
            "XYZ"[r.axis], r.strategy, shift.c_str(), rms, first);
      };
      double mean = 0.0;
      double first = 0.0;
      double mean_seeded = 0.0;
      double first_seeded = 0.0;
      for (std::size_t k = 0; k < starts.size(); ++k) {
        const auto& st = r.shift[k];
        emit(std::to_string(static_cast<int>(starts[k])) + "-" +
                 std::to_string(static_cast<int>(starts[k] + 8.0)) + " h",
             st.rms_um, st.first_hour_max_um);
        mean += st.rms_um / static_cast<double>(starts.size());
        first = std::max(first, st.first_hour_max_um);
        if (k > 0) {
          mean_seeded += st.rms_um / static_cast<double>(starts.size() - 1);
          first_seeded = std::max(first_seeded, st.first_hour_max_um);
        }
      }
      emit("all", mean, first);
      emit("8-40 h", mean_seeded, first_seeded);
    }
    return;
  }
  std::printf("## 8-hour shifts driven by the FL_THERMAL spindle drift\n\n");
  std::printf(
      "X <- ch3 (radial, largest), Y <- ch1 (radial), Z <- ch5 (axial growth), each "
      "relative to its value at the shift start (the nominals are taken then); "
      "temperature sensor <- t5 (spindle bearing / motor area, follows the speed). "
      "Touch noise %.1f um, touches every hour, creep 600 s cosine, time model tau 1 h. "
      "The shifts run in order on one machine; the estimator is seeded by the shifts before "
      "(shift 0-8 h by none).\n\n",
      kTouchNoiseUm);
  std::printf("| strategy | axis |");
  for (const double s : starts) {
    std::printf(" shift %.0f-%.0f h RMS / max |", s, s + 8.0);
  }
  std::printf(" mean RMS |\n|---|---|");
  for (std::size_t i = 0; i <= starts.size(); ++i) {
    std::printf("---|");
  }
  std::printf("\n");
  for (const auto& r : rows) {
    std::printf("| %s | %s |", r.strategy, kAxisNames[r.axis]);
    double mean = 0.0;
    for (std::size_t k = 0; k < starts.size(); ++k) {
      std::printf(" %.2f / %.2f |", r.shift[k].rms_um, r.shift[k].max_um);
      mean += r.shift[k].rms_um / static_cast<double>(starts.size());
    }
    std::printf(" %.2f |\n", mean);
  }
  std::printf(
      "\n### Largest error in the first hour (before the first touch)\n\n| strategy | axis |");
  for (const double s : starts) {
    std::printf(" shift %.0f-%.0f h |", s, s + 8.0);
  }
  std::printf(" largest |\n|---|---|");
  for (std::size_t i = 0; i <= starts.size(); ++i) {
    std::printf("---|");
  }
  std::printf("\n");
  for (const auto& r : rows) {
    std::printf("| %s | %s |", r.strategy, kAxisNames[r.axis]);
    double worst = 0.0;
    for (std::size_t k = 0; k < starts.size(); ++k) {
      std::printf(" %.2f |", r.shift[k].first_hour_max_um);
      worst = std::max(worst, r.shift[k].first_hour_max_um);
    }
    std::printf(" %.2f |\n", worst);
  }
  std::printf(
      "\n### The model rows' prior: slope on t5 [um/degC] +- sigma, fitted on the shifts before\n"
      "\n| shift | X | Y | Z |\n|---|---|---|---|\n");
  for (const auto& m : model_log) {
    std::printf("| %.0f-%.0f h |", starts[m.shift], starts[m.shift] + 8.0);
    for (const std::size_t slot : {0U, 2U, 3U}) {
      std::printf(" %+.2f +- %.2f |", m.prior.slope_um_per_c[slot], m.prior.sigma_um_per_c[slot]);
    }
    std::printf("\n");
  }
  std::printf(
      "\n### The shrunk models of the row \"%s\": lambda / rolling-origin RMS on the earlier "
      "shifts [um]\n\n| shift | X (ch3) | Y (ch1) | Z (ch5) |\n|---|---|---|---|\n",
      kStrategies[kStrategies.size() - 2].name);
  for (const auto& l : shrunk_log) {
    std::printf("| %.0f-%.0f h |", starts[l.shift], starts[l.shift] + 8.0);
    for (std::size_t a = 0; a < 3; ++a) {
      std::printf(" %g / %.2f |", l.lambda[a], l.rolling_rms_um[a]);
    }
    std::printf("\n");
  }
  std::printf(
      "\n### Estimator: sensitivity to the level noise and the gate\n\n"
      "The rows above use estimator_level_noise_um_per_h = 6, estimator_gate_sigmas = 5. "
      "Mean RMS over the five shifts / largest first-hour error [um].\n\n"
      "| temperature | level noise [um/h] | gate [sigma] | X | Y | Z "
      "|\n|---|---|---|---|---|---|\n");
  std::vector<Strategy> variants;
  for (const bool temperature : {false, true}) {
    for (const double level : {1.0, 3.0, 6.0, 10.0}) {
      for (const double gate : {0.0, 5.0}) {
        variants.push_back({"", true, nccomp::core::ProfileShape::kCosine, Prediction::kEstimator,
                            temperature, level, gate});
      }
    }
  }
  const std::vector<Row> sens = thermal_rows(d, starts, variants);
  for (std::size_t i = 0; i < variants.size(); ++i) {
    std::printf("| %s | %.0f | %s |", variants[i].temperature_slope ? "t5" : "-",
                variants[i].level_noise_um_per_h, variants[i].gate_sigmas > 0.0 ? "5" : "off");
    print_summary(sens, i);
  }
  std::printf("\n");
  input_table(d, starts);
  x_table(d, starts);
  shrunk_table(d, starts);
}

}  // namespace

int main(int argc, char** argv) {
  std::string data = NCCOMP_FL_THERMAL_CSV;
  bool json = false;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--data" && i + 1 < argc) {
      data = argv[++i];
    } else if (a == "--json") {
      json = true;
    } else {
      std::fprintf(stderr, "usage: bench_calib_shift [--data FL_THERMAL/data.csv] [--json]\n");
      return 2;
    }
  }
  try {
    if (!json) {
      facet_table();
      first_order_table();
    }
    thermal_tables(data, json);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "bench_calib_shift: %s\n", e.what());
    return 1;
  }
  return 0;
}
