// A model of the cut for the creeping-correction benchmarks: a face finished in raster passes
// while the tool wears, the tool measured every N passes (mid-pass, as when the NC interrupts a
// long surface), and the real core (WearCompensator) computing the offsets the NC would apply.
// The surface error at a point is the true wear at the engagement point minus the correction in
// force when that point was cut, along the surface normal. The correction's own jump is the change
// of the wear in force at the current engagement point between two neighbouring samples (at the
// same engagement angle, so the change of the angle along a curved pass does not count): what the
// creep itself adds per sample, the quantity the bound h·Δs/L is about.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <functional>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "core/common/output.hpp"
#include "core/creep/wear_compensator.hpp"

namespace nccomp::bench::creep {

using namespace nccomp::core;
using namespace nccomp::core::creep;

struct Scenario {
  std::string name;
  int passes{60};
  double pass_length_mm{100.0};
  double ds_mm{0.5};
  double feed_mm_per_s{1555.0 / 60.0};
  int measure_every_passes{6};
  double creep_length_mm{200.0};
  std::size_t edge_points{1};
  /// Curved face: a cylinder of radius_mm about Y, passes along X over ±max_angle_deg; the
  /// surface normal (and so the engagement angle on a ball-end mill) changes along each pass.
  bool curved{false};
  double radius_mm{50.0};
  double max_angle_deg{60.0};
  /// Correction through the radius-wear register (mean wear) instead of X/Y/Z along the normal.
  bool tool_registers{false};
  /// True wear [µm] at engagement angle θ [deg] after s [mm] of cut path.
  std::function<double(double, double)> wear_um;
  double noise_um{0.5};
  std::uint64_t seed{1};
  /// Measurements the predictive strategy fits its wear rate to.
  std::size_t predict_window{5};
  /// [creep.estimator] of the estimator strategies (enabled by the strategy); its
  /// measurement_sigma_um is set to noise_um unless that is 0.
  EstimatorConfig estimator{};
  /// "Measured when needed" (interval basis uncertainty): the bound on the estimate's σ [µm] and
  /// the limits of the path between measurements [mm].
  double max_sigma_um{1.0};
  double min_interval_mm{108.0};
  double max_interval_mm{2160.0};
  /// The tool family's earlier tools (the strategies with a learned process noise): their true
  /// wear [µm] at cut path s [mm] and their life [mm]. Each is cut, measured every
  /// measure_every_passes with noise of its own (the same for every strategy) and replaced by its
  /// sister before the scored tool starts, so the scored tool's filter starts with the q learned
  /// from them (family_min_tools = their number).
  std::vector<std::function<double(double)>> family;
  std::vector<double> family_length_mm;
};

struct Strategy {
  std::string name;
  bool apply{true};
  ProfileShape profile{ProfileShape::kLinear};
  bool predict{false};
  bool estimator{false};
  /// Fed noise-free measurements (the config, σ included, stays that of the noisy run): the
  /// limit of what a measurement every k cuts can know.
  bool noise_free{false};
  /// Measured when the module asks (interval basis uncertainty), not every measure_every_passes.
  bool on_request{false};
  /// [creep.estimator] learn_rate_noise: the Scenario's family is cut first.
  bool learned{false};
  /// [creep.estimator] adapt_rate_noise: the rate noise follows the innovations within the life.
  bool adapted{false};
  /// [creep.estimator] learn_rate_prior (with learned): the scored tool's rate prior is the
  /// family's.
  bool learned_prior{false};
};

struct Result {
  double max_step_along_um{0.0};   // largest jump between neighbouring points of one pass
  double max_step_across_um{0.0};  // largest jump between neighbouring passes (same x)
  double max_jump_um{0.0};         // largest change of the correction itself between two samples
  double rms_um{0.0};
  double rms_second_half_um{0.0};  // RMS over the second half of the path (steady state)
  double max_abs_um{0.0};
  double mean_increment_um{0.0};  // h: mean measured increment between measurements
  double max_increment_um{0.0};
  int measurements{0};
  int refused{0};  // measurements refused (the estimator's gate, plausibility)
  /// The rate noise the scored tool's filter starts with [µm/mm per sqrt(m)] (learned or
  /// config), and ends with (adapted).
  double rate_noise_um_per_mm_per_sqrt_m{0.0};
  double rate_noise_end_um_per_mm_per_sqrt_m{0.0};
  /// The estimate's σ predicted to each measurement, just before it: mean over the measurements
  /// in the second half of the life [µm] (NaN without the estimator).
  double sigma_before_measurement_um{std::numeric_limits<double>::quiet_NaN()};
  /// Measurements in the first 50 cuts of the scored tool.
  int measurements_first_50_passes{0};
  /// The scored tool's rate prior [µm/mm], mean and σ (0 ± initial_rate_sigma_um_per_mm unless
  /// learned from the family).
  double rate_prior_um_per_mm{0.0};
  double rate_prior_sigma_um_per_mm{0.0};
};

inline const std::vector<Strategy>& strategies() {
  static const std::vector<Strategy> s{
      {"no correction", false, ProfileShape::kStep, false},
      {"prior art: step", true, ProfileShape::kStep, false},
      {"creeping, linear", true, ProfileShape::kLinear, false},
      {"creeping, cosine", true, ProfileShape::kCosine, false},
      {"predictive creeping, linear", true, ProfileShape::kLinear, true},
      {"creeping, estimator", true, ProfileShape::kLinear, false, true},
      {"predictive creeping, estimator", true, ProfileShape::kLinear, true, true},
      {"creeping, estimator, noise-free", true, ProfileShape::kLinear, false, true, true},
      {"predictive creeping, estimator, noise-free", true, ProfileShape::kLinear, true, true, true},
      {"predictive creeping, estimator, measured when needed", true, ProfileShape::kLinear, true,
       true, false, true},
      {"predictive creeping, estimator, learned q", true, ProfileShape::kLinear, true, true, false,
       false, true},
      {"predictive creeping, estimator, learned q, noise-free", true, ProfileShape::kLinear, true,
       true, true, false, true},
      {"predictive creeping, estimator, learned q, measured when needed", true,
       ProfileShape::kLinear, true, true, false, true, true},
      {"predictive creeping, estimator, learned q, adapted", true, ProfileShape::kLinear, true,
       true, false, false, true, true},
      {"predictive creeping, estimator, learned q, adapted, noise-free", true,
       ProfileShape::kLinear, true, true, true, false, true, true},
      {"predictive creeping, estimator, learned q, adapted, measured when needed", true,
       ProfileShape::kLinear, true, true, false, true, true, true},
      {"predictive creeping, estimator, learned q and rate prior", true, ProfileShape::kLinear,
       true, true, false, false, true, false, true},
      {"predictive creeping, estimator, learned q and rate prior, noise-free", true,
       ProfileShape::kLinear, true, true, true, false, true, false, true},
      {"predictive creeping, estimator, learned q and rate prior, measured when needed", true,
       ProfileShape::kLinear, true, true, false, true, true, false, true},
      {"predictive creeping, estimator, learned q and rate prior, adapted", true,
       ProfileShape::kLinear, true, true, false, false, true, true, true},
      {"predictive creeping, estimator, learned q and rate prior, adapted, noise-free", true,
       ProfileShape::kLinear, true, true, true, false, true, true, true},
      {"predictive creeping, estimator, learned q and rate prior, adapted, measured when needed",
       true, ProfileShape::kLinear, true, true, false, true, true, true, true},
  };
  return s;
}

inline Result run(const Scenario& sc, const Strategy& st) {
  CreepConfig c;
  c.creep_basis = CreepBasis::kPath;
  c.creep_length_mm = sc.creep_length_mm;
  c.profile = st.profile;
  c.on_unfinished = UnfinishedPolicy::kSuperpose;
  c.edge.edge_points = sc.edge_points;
  c.edge.tool_shape = sc.edge_points > 1 ? ToolShape::kBall : ToolShape::kTip;
  if (sc.tool_registers) {
    c.output.mode = OutputMode::kToolRegisters;
    c.output.channel_register = {-1, -1, -1, 0, -1};
    c.edge.normal_source = NormalSource::kNone;
    c.edge.fallback_channel = Channel::kRadius;
  } else {
    c.output.mode = OutputMode::kAxes;
    c.output.channel_register = {0, 1, 2, -1, -1};
    c.edge.normal_source = NormalSource::kAxisSample;
  }
  // The prior art is a true step: the limiter must not turn it into a ramp here.
  c.limiter = {1000.0, 1000.0, 1e9};
  c.tool_life.min_expected_increment_um = 1000.0;
  c.tool_life.noise_um = 6.0 * sc.noise_um + 1.0;
  c.predict.enabled = st.predict;
  c.predict.window = sc.predict_window;
  c.predict.max_um = 50.0;
  c.estimator = sc.estimator;
  c.estimator.enabled = st.estimator;
  if (sc.noise_um > 0.0) c.estimator.measurement_sigma_um = sc.noise_um;
  if (st.on_request) {
    c.interval.basis = IntervalBasis::kUncertainty;
    c.interval.max_sigma_um = sc.max_sigma_um;
    c.interval.min_interval_mm = sc.min_interval_mm;
    c.interval.max_interval_mm = sc.max_interval_mm;
  }
  const bool learn = st.learned && !sc.family.empty();
  if (learn) {
    c.estimator.learn_rate_noise = true;
    c.estimator.family_min_tools = sc.family.size();
    c.estimator.learn_rate_prior = st.learned_prior;
  }
  c.estimator.adapt_rate_noise = st.adapted;
  WearCompensator comp;
  comp.configure(c);
  StepOutput out;
  std::vector<Event> ev;
  TimeNs now = 0;
  ev.emplace_back(ToolChange{now, 1, false});
  comp.step(now, ev, out);
  std::int32_t tool = 1;
  std::uint64_t refused_before = 0;
  if (learn) {
    // The family's earlier tools: cut in 5 mm samples (only the measurements' positions matter
    // to what is learned), measured every measure_every_passes, then replaced by their sister.
    const double step_mm = 5.0;
    const double every_mm = sc.measure_every_passes * sc.pass_length_mm;
    for (std::size_t h = 0; h < sc.family.size(); ++h) {
      std::mt19937_64 rng_h(sc.seed + 1000 + h);
      std::normal_distribution<double> noise_h(0.0, sc.noise_um);
      double next = every_mm - 0.5 * sc.pass_length_mm;
      for (double s = 0.0; s <= sc.family_length_mm[h]; s += step_mm) {
        ev.clear();
        now += from_seconds(step_mm / sc.feed_mm_per_s);
        if (s >= next) {
          next += every_mm;
          ToolMeasurement m;
          m.time_ns = now;
          m.tool = tool;
          m.point_count = static_cast<std::uint8_t>(sc.edge_points);
          const double w = sc.family[h](s) + noise_h(rng_h);
          for (std::size_t p = 0; p < sc.edge_points; ++p) m.wear_um[p] = w;
          ev.emplace_back(m);
        }
        AxisSample a;
        a.time_ns = now;
        a.position_mm = {s, 0.0, 0.0, 0.0, 0.0, 0.0};
        a.program_path_mm = s;
        a.tool = tool;
        ev.emplace_back(a);
        out.clear();
        comp.step(now, ev, out);
      }
      ev.clear();
      ev.emplace_back(ToolChange{now, ++tool, true});
      out.clear();
      comp.step(now, ev, out);
    }
    refused_before = comp.counters().measurements_refused;
  }

  std::mt19937_64 rng(sc.seed);
  std::normal_distribution<double> noise(0.0, sc.noise_um);
  const int n = static_cast<int>(std::lround(sc.pass_length_mm / sc.ds_mm));
  const double interval_mm = sc.measure_every_passes * sc.pass_length_mm;
  double next_meas = interval_mm - 0.5 * sc.pass_length_mm;
  std::vector<double> prev_pass(static_cast<std::size_t>(n), 0.0);
  std::vector<double> this_pass(static_cast<std::size_t>(n), 0.0);
  std::vector<double> last_measured(sc.edge_points, 0.0);
  std::vector<double> w_prev(sc.edge_points, 0.0);
  std::vector<double> w_now(sc.edge_points, 0.0);
  bool have_prev = false;
  // The wear in force at engagement angle θ (interpolated between support points as the core
  // does), or the mean along the edge when the correction goes on a tool register.
  const auto at_engagement = [&](const std::vector<double>& w, double theta_deg) {
    const std::size_t points = w.size();
    if (sc.tool_registers) {
      double m = 0.0;
      for (const double v : w) m += v;
      return m / static_cast<double>(points);
    }
    if (points < 2) return w[0];
    const double x = theta_deg / 90.0 * static_cast<double>(points - 1);
    const auto i0 = std::min(static_cast<std::size_t>(x), points - 2);
    const double t = x - static_cast<double>(i0);
    return w[i0] + t * (w[i0 + 1] - w[i0]);
  };
  Result r;
  r.rate_noise_um_per_mm_per_sqrt_m = std::sqrt(comp.rate_q() * 1000.0);
  const double prior_sigma = comp.state().rate_prior_sigma_um_per_mm[0];
  r.rate_prior_um_per_mm = prior_sigma > 0.0 ? comp.state().rate_prior_um_per_mm[0] : 0.0;
  r.rate_prior_sigma_um_per_mm =
      prior_sigma > 0.0 ? prior_sigma : c.estimator.initial_rate_sigma_um_per_mm;
  double sum_sq = 0.0;
  std::size_t count = 0;
  double sum_sq_after = 0.0;
  std::size_t count_after = 0;
  double inc_sum = 0.0;
  double sigma_sum = 0.0;
  int sigma_count = 0;
  for (int j = 0; j < sc.passes; ++j) {
    for (int i = 0; i < n; ++i) {
      const double x_local = (i + 0.5) * sc.ds_mm;
      const double s = j * sc.pass_length_mm + x_local;
      // Raster: every other pass runs backward; x is the position across the face.
      const double x = (j % 2 == 0) ? x_local : sc.pass_length_mm - x_local;
      std::array<double, 3> nrm{0.0, 0.0, 1.0};
      if (sc.curved) {
        const double a_deg = -sc.max_angle_deg + 2.0 * sc.max_angle_deg * x / sc.pass_length_mm;
        const double a = a_deg * std::numbers::pi / 180.0;
        nrm = {std::sin(a), 0.0, std::cos(a)};
      }
      const double theta_deg = std::acos(std::clamp(nrm[2], 0.0, 1.0)) * 180.0 / std::numbers::pi;
      ev.clear();
      now += from_seconds(sc.ds_mm / sc.feed_mm_per_s);
      if (st.on_request ? comp.state().measurement_due_flag : s >= next_meas) {
        // The NC interrupts here; the laser measures; machining resumes at the same position.
        next_meas += interval_mm;
        double w_est = 0.0;
        double sigma = 0.0;
        if (j >= sc.passes / 2 && comp.wear_estimate(0, w_est, sigma)) {
          sigma_sum += sigma;
          ++sigma_count;
        }
        if (j < 50) ++r.measurements_first_50_passes;
        ToolMeasurement m;
        m.time_ns = now;
        m.tool = tool;
        m.point_count = static_cast<std::uint8_t>(sc.edge_points);
        double inc_max = 0.0;
        for (std::size_t p = 0; p < sc.edge_points; ++p) {
          const double e = noise(rng);  // drawn in every strategy: the same noise sequence
          const double w =
              sc.wear_um(support_angle_deg(p, sc.edge_points), s) + (st.noise_free ? 0.0 : e);
          m.wear_um[p] = w;
          inc_max = std::max(inc_max, w - last_measured[p]);
          last_measured[p] = w;
        }
        ++r.measurements;
        inc_sum += inc_max;
        r.max_increment_um = std::max(r.max_increment_um, inc_max);
        if (st.apply) ev.emplace_back(m);
      }
      AxisSample a;
      a.time_ns = now;
      a.position_mm = {x, j * 1.0, 0.0, 0.0, 0.0, 0.0};
      a.program_path_mm = s;
      a.tool = tool;
      a.has_normal = true;
      a.normal = nrm;
      ev.emplace_back(a);
      out.clear();
      comp.step(now, ev, out);
      for (std::size_t p = 0; p < sc.edge_points; ++p) w_now[p] = comp.applied_wear_um(p);
      if (have_prev) {
        r.max_jump_um = std::max(r.max_jump_um, std::fabs(at_engagement(w_now, theta_deg) -
                                                          at_engagement(w_prev, theta_deg)));
      }
      w_prev.swap(w_now);
      have_prev = true;
      double applied = 0.0;
      if (sc.tool_registers) {
        applied = -comp.channel_output_um(Channel::kRadius);
      } else {
        applied = -(comp.channel_output_um(Channel::kX) * nrm[0] +
                    comp.channel_output_um(Channel::kY) * nrm[1] +
                    comp.channel_output_um(Channel::kZ) * nrm[2]);
      }
      const double e = sc.wear_um(theta_deg, s) - applied;
      // Index by position across the face, so neighbouring passes compare the same x.
      const auto xi = static_cast<std::size_t>(j % 2 == 0 ? i : n - 1 - i);
      this_pass[xi] = e;
      sum_sq += e * e;
      ++count;
      if (j >= sc.passes / 2) {
        sum_sq_after += e * e;
        ++count_after;
      }
      r.max_abs_um = std::max(r.max_abs_um, std::fabs(e));
    }
    for (int i = 1; i < n; ++i) {
      const auto k = static_cast<std::size_t>(i);
      r.max_step_along_um =
          std::max(r.max_step_along_um, std::fabs(this_pass[k] - this_pass[k - 1]));
    }
    if (j > 0) {
      for (std::size_t k = 0; k < this_pass.size(); ++k) {
        r.max_step_across_um =
            std::max(r.max_step_across_um, std::fabs(this_pass[k] - prev_pass[k]));
      }
    }
    prev_pass.swap(this_pass);
  }
  r.rms_um = std::sqrt(sum_sq / static_cast<double>(count));
  r.rms_second_half_um =
      count_after > 0 ? std::sqrt(sum_sq_after / static_cast<double>(count_after)) : 0.0;
  r.mean_increment_um = r.measurements > 0 ? inc_sum / r.measurements : 0.0;
  r.refused = static_cast<int>(comp.counters().measurements_refused - refused_before);
  r.rate_noise_end_um_per_mm_per_sqrt_m = std::sqrt(comp.rate_q() * 1000.0);
  if (sigma_count > 0) r.sigma_before_measurement_um = sigma_sum / sigma_count;
  return r;
}

}  // namespace nccomp::bench::creep
