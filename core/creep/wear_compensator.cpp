#include "core/creep/wear_compensator.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <numbers>
#include <stdexcept>
#include <string>
#include <variant>

#include "core/estimation/noise_adaptation.hpp"

namespace nccomp::core::creep {

namespace {

constexpr double kRadToDeg = 180.0 / std::numbers::pi;
constexpr double kTiny = 1e-9;
constexpr double kEase = kBlendFraction;
/// Slope of the eased progress after the ease-in: φ(1) = 1.
constexpr double kEaseGain = 1.0 / (1.0 - 0.5 * kEase);

/// Eased progress φ(u): φ(0) = 0 with zero slope, slope rising linearly to kEaseGain over
/// [0, kEase], constant after; φ(1) = 1.
double eased(double u) noexcept {
  if (!(u > 0.0)) return 0.0;
  if (u >= 1.0) return 1.0;
  return u < kEase ? kEaseGain * u * u / (2.0 * kEase) : kEaseGain * (u - 0.5 * kEase);
}

double eased_slope(double u) noexcept {
  if (u < 0.0 || u >= 1.0) return 0.0;
  return u < kEase ? kEaseGain * u / kEase : kEaseGain;
}

}  // namespace

void WearCompensator::configure(const CreepConfig& config) {
  validate(config);
  for (auto& l : limiters_) l.configure(config.limiter);
  config_ = config;
  table_ = ProfileTable{};
  if (config_.profile == ProfileShape::kTable) {
    std::copy(config_.profile_table.begin(), config_.profile_table.end(), table_.f.begin());
    table_.n = config_.profile_table.size();
  }
  removal_cum_mm3_.clear();
  if (config_.toolpath.has_removal && !config_.toolpath.rows.empty()) {
    const auto& rows = config_.toolpath.rows;
    removal_cum_mm3_.reserve(rows.size());
    double v = 0.0;
    removal_cum_mm3_.push_back(v);
    for (std::size_t j = 1; j < rows.size(); ++j) {
      v += rows[j - 1].removal_mm2 * (rows[j].path_mm - rows[j - 1].path_mm);
      removal_cum_mm3_.push_back(v);
    }
  }
  points_ = config_.edge.edge_points;
  s_ = CreepState{};
  memory_ = ToolMemory{};
  adopted_ = AdoptedOutputs{};
  fade_pending_ = false;
  s_.edge_points = static_cast<std::uint32_t>(points_);
  s_.history_count = 1;  // a new tool: zero wear at zero path, the first point of the rate fit
  counters_ = CreepCounters{};
  have_sample_ = false;
  have_feed_ = false;
  cutting_ = false;
  interrupted_ = false;
  between_parts_ = false;
  have_now_ = false;
  rearm_ = false;
  written_once_.fill(false);
  flag_written_once_.fill(false);
  last_verdict_.fill(LimitVerdict::kPassed);
  target_um_.fill(0.0);
  select_tool_tables();
}

StateProblem WearCompensator::check_state(const CreepState& st) const noexcept {
  const auto bad = [](double v) { return !std::isfinite(v); };
  if (st.version != CreepState::kVersion) return {"version", -1};
  if (st.edge_points != points_) return {"edge_points (differs from creep.edge.edge_points)", -1};
  if (bad(st.cut_path_mm)) return {"cut_path_mm", -1};
  if (bad(st.cut_time_s)) return {"cut_time_s", -1};
  if (bad(st.creep_path_mm)) return {"creep_path_mm", -1};
  if (bad(st.creep_time_s)) return {"creep_time_s", -1};
  if (bad(st.last_measurement_cut_path_mm)) return {"last_measurement_cut_path_mm", -1};
  if (bad(st.last_measurement_cut_time_s)) return {"last_measurement_cut_time_s", -1};
  if (bad(st.last_measurement_creep_path_mm)) return {"last_measurement_creep_path_mm", -1};
  if (bad(st.rate_blend_mm) || st.rate_blend_mm < 0.0) return {"rate_blend_mm", -1};
  if (bad(st.removed_mm3) || st.removed_mm3 < 0.0) return {"removed_mm3", -1};
  if (bad(st.last_measurement_removed_mm3) || st.last_measurement_removed_mm3 < 0.0 ||
      st.last_measurement_removed_mm3 > st.removed_mm3) {
    return {"last_measurement_removed_mm3", -1};
  }
  if (st.history_count < 1 || st.history_count > kMaxRateWindow) return {"history_count", -1};
  for (std::size_t i = 0; i < points_; ++i) {
    const int ii = static_cast<int>(i);
    if (bad(st.committed_um[i])) return {"committed_um", ii};
    if (bad(st.measured_um[i])) return {"measured_um", ii};
    if (bad(st.rate_um_per_mm[i])) return {"rate_um_per_mm", ii};
    if (bad(st.rate_prev_um_per_mm[i])) return {"rate_prev_um_per_mm", ii};
    for (std::size_t h = 0; h < st.history_count; ++h) {
      if (bad(st.history[h].wear_um[i]) || bad(st.history[h].cut_path_mm)) {
        return {"history", static_cast<int>(h)};
      }
    }
  }
  for (std::size_t k = 0; k < kMaxCreeps; ++k) {
    const auto& c = st.creeps[k];
    if (!c.active) continue;
    const int kk = static_cast<int>(k);
    if (k >= config_.max_creeps) return {"creeps (active beyond creep.max_creeps)", kk};
    if (bad(c.start)) return {"creeps", kk};
    for (std::size_t i = 0; i < points_; ++i) {
      if (bad(c.delta_um[i]) || bad(c.span[i]) || c.span[i] < 0.0 || bad(c.carry_slope[i]) ||
          bad(c.carry_span[i]) || c.carry_span[i] < 0.0) {
        return {"creeps", kk};
      }
    }
  }
  if (st.entry.active && (bad(st.entry.start_path_mm) || bad(st.entry.offset_um) ||
                          bad(st.entry.length_mm) || !(st.entry.length_mm > 0.0))) {
    return {"entry", -1};
  }
  for (std::size_t ch = 0; ch < kChannelCount; ++ch) {
    if (bad(st.channel_output_um[ch])) return {"channel_output_um", static_cast<int>(ch)};
  }
  if (st.normal_held) {
    const auto& n = st.held_normal;
    const double len = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    if (!std::isfinite(len) || std::fabs(len - 1.0) > 1e-6) return {"held_normal", -1};
  }
  if (bad(st.refused_cut_path_mm)) return {"refused_cut_path_mm", -1};
  if (bad(st.refused_cut_time_s)) return {"refused_cut_time_s", -1};
  if (bad(st.refused_removed_mm3) || st.refused_removed_mm3 < 0.0) {
    return {"refused_removed_mm3", -1};
  }
  if (!std::isnan(st.rate_q) && (bad(st.rate_q) || st.rate_q < 0.0)) return {"rate_q", -1};
  if (st.nis_count > 0) {
    for (std::size_t i = 0; i < points_; ++i) {
      if (bad(st.nis_sum[i]) || st.nis_sum[i] < 0.0) return {"nis_sum", static_cast<int>(i)};
      if (bad(st.residual_var_sum_um2[i])) return {"residual_var_sum_um2", static_cast<int>(i)};
    }
  }
  if (bad(st.family.rate_q_sum)) return {"family", -1};
  if (bad(st.start_sxx) || st.start_sxx < 0.0) return {"start_sxx", -1};
  for (std::size_t i = 0; i < points_; ++i) {
    if (bad(st.start_sxw[i])) return {"start_sxw", static_cast<int>(i)};
    if (bad(st.rate_prior_um_per_mm[i])) return {"rate_prior_um_per_mm", static_cast<int>(i)};
    if (bad(st.rate_prior_sigma_um_per_mm[i]) || st.rate_prior_sigma_um_per_mm[i] < 0.0) {
      return {"rate_prior_sigma_um_per_mm", static_cast<int>(i)};
    }
    if (bad(st.family_rate.rate_mean_um_per_mm[i]) || bad(st.family_rate.rate_m2[i]) ||
        st.family_rate.rate_m2[i] < 0.0) {
      return {"family_rate", static_cast<int>(i)};
    }
  }
  if (st.estimate_valid) {
    if (bad(st.estimate_path_mm) || st.estimate_path_mm < 0.0 ||
        st.estimate_path_mm > st.cut_path_mm + kTiny) {
      return {"estimate_path_mm", -1};
    }
    for (std::size_t i = 0; i < points_; ++i) {
      const double ww = st.estimate_p_ww[i];
      const double wr = st.estimate_p_wr[i];
      const double rr = st.estimate_p_rr[i];
      if (bad(st.estimate_wear_um[i]) || bad(st.estimate_rate_um_per_mm[i]) || bad(ww) || bad(wr) ||
          bad(rr) || ww < 0.0 || rr < 0.0 || wr * wr > ww * rr * (1.0 + 1e-9) + 1e-300) {
        return {"estimate", static_cast<int>(i)};
      }
    }
  }
  return {};
}

bool WearCompensator::restore_state(const CreepState& st) noexcept {
  if (check_state(st).field != nullptr) return false;
  s_ = st;
  // Kinematics re-anchor on the first sample.
  have_sample_ = false;
  have_feed_ = false;
  cutting_ = false;
  interrupted_ = false;
  between_parts_ = false;
  have_now_ = false;
  // Every value is re-sent on the next step.
  written_once_.fill(false);
  flag_written_once_.fill(false);
  rearm_ = false;
  select_tool_tables();
  return true;
}

namespace {
/// WearCompensator::save_motion()'s bytes.
struct Motion {
  AxisSample last_sample;
  std::array<double, 3> feed_dir;
  TimeNs last_now_ns;
  // have_sample, cutting, interrupted, have_feed, have_now, between_parts
  std::array<std::uint8_t, 8> flags;
};
}  // namespace

std::size_t WearCompensator::save_motion(std::span<std::byte> buf) const noexcept {
  if (buf.size() < sizeof(Motion)) return 0;
  Motion m{};
  m.last_sample = last_sample_;
  m.feed_dir = feed_dir_;
  m.last_now_ns = last_now_ns_;
  m.flags = {have_sample_, cutting_, interrupted_, have_feed_, have_now_, between_parts_};
  std::memcpy(buf.data(), &m, sizeof m);
  return sizeof m;
}

bool WearCompensator::load_motion(std::span<const std::byte> bytes) noexcept {
  if (bytes.size() != sizeof(Motion)) return false;
  Motion m{};
  std::memcpy(&m, bytes.data(), sizeof m);
  for (const std::uint8_t f : m.flags) {
    if (f > 1) return false;
  }
  for (const double v : m.feed_dir) {
    if (!std::isfinite(v)) return false;
  }
  last_sample_ = m.last_sample;
  feed_dir_ = m.feed_dir;
  last_now_ns_ = m.last_now_ns;
  have_sample_ = m.flags[0] == 1;
  cutting_ = m.flags[1] == 1;
  interrupted_ = m.flags[2] == 1;
  have_feed_ = m.flags[3] == 1;
  have_now_ = m.flags[4] == 1;
  between_parts_ = m.flags[5] == 1;
  if (have_now_) {
    // step() resets the limiters only without a last step: they go on from the values the old
    // engine's limiters let through at its last step (the state), not from 0 by max_step_um.
    for (std::size_t ch = 0; ch < kChannelCount; ++ch) {
      limiters_[ch].reset(s_.channel_output_um[ch], last_now_ns_);
    }
  }
  return true;
}

void WearCompensator::import_state(const CreepState& st) {
  const StateProblem p = check_state(st);
  if (p.field != nullptr) {
    std::string what("creep state: ");
    what += p.field;
    if (p.index >= 0) {
      what += '[';
      what += std::to_string(p.index);
      what += ']';
    }
    what += " is invalid (not finite, out of range, or from another config)";
    throw std::invalid_argument(what);
  }
  restore_state(st);
}

void WearCompensator::clear_alarm() noexcept {
  s_.halted = false;
  s_.alarm_flag = false;
  s_.warning_flag = false;
  // The operator has looked: a measurement refused before may be asked for again at once (the
  // request fell when that measurement came and stayed low since).
  s_.request_held = false;
}

void WearCompensator::rearm_request() noexcept {
  if (!s_.measurement_due_flag || config_.output.request_rearm_s <= 0.0 ||
      config_.output.measurement_due_register < 0) {
    return;
  }
  rearm_ = true;
  rearm_started_ = false;
}

void WearCompensator::select_tool_tables() noexcept {
  deflection_index_ = -1;
  for (std::size_t k = 0; k < config_.deflection.size(); ++k) {
    if (config_.deflection[k].tool == s_.tool) {
      deflection_index_ = static_cast<int>(k);
      break;
    }
    if (config_.deflection[k].tool == 0 && deflection_index_ < 0) {
      deflection_index_ = static_cast<int>(k);
    }
  }
  transition_count_ = 0;
  for (std::size_t k = 0; k < config_.transitions.size(); ++k) {
    if (config_.transitions[k].tool == s_.tool) {
      transition_index_[transition_count_++] = static_cast<std::uint8_t>(k);
    }
  }
  update_uncertainty_interval();  // the tool's own estimate
}

// ---------------------------------------------------------------------------------------------

void WearCompensator::step(TimeNs now_ns, std::span<const Event> events, StepOutput& out) noexcept {
  if (!have_now_) {
    // Start-up or resume: the limiters continue from what the NC holds.
    for (std::size_t ch = 0; ch < kChannelCount; ++ch) {
      limiters_[ch].reset(s_.channel_output_um[ch], now_ns);
    }
  } else if (cutting_ && !interrupted_) {
    const double dt_s = std::max(0.0, seconds(now_ns - last_now_ns_));
    s_.cut_time_s += dt_s;
    if (!s_.halted) s_.creep_time_s += dt_s;
  }
  last_now_ns_ = now_ns;
  have_now_ = true;
  if (rearm_ && !rearm_started_) {
    rearm_started_ = true;
    rearm_until_ns_ = now_ns + from_seconds(config_.output.request_rearm_s);
  }

  for (const Event& e : events) {
    if (const auto* a = std::get_if<AxisSample>(&e)) {
      on_axis_sample(now_ns, *a, out);
    } else if (const auto* m = std::get_if<ToolMeasurement>(&e)) {
      on_measurement(now_ns, *m, out);
    } else if (const auto* c = std::get_if<ToolChange>(&e)) {
      on_tool_change(now_ns, *c, out);
    } else if (const auto* p = std::get_if<ProgramEvent>(&e)) {
      switch (p->kind) {
        case ProgramEventKind::kPartStart:
          s_.part = p->part;
          between_parts_ = true;
          break;
        case ProgramEventKind::kPartEnd:
          between_parts_ = true;
          break;
        case ProgramEventKind::kInterruption:
          interrupted_ = true;
          cutting_ = false;
          break;
        case ProgramEventKind::kResume:
          interrupted_ = false;
          break;
      }
    }
  }
  retire_finished_creeps();
  check_measurement_due(now_ns, out);
  compute_targets();
  write_outputs(now_ns, out);
}

void WearCompensator::on_axis_sample(TimeNs now_ns, const AxisSample& a, StepOutput& out) noexcept {
  if (a.tool != 0 && s_.tool != 0 && a.tool != s_.tool) {
    // Another tool in the spindle without a tool-change event (lost, or a driver that does not
    // map one): never apply one tool's wear to another.
    on_tool_change(now_ns, ToolChange{a.time_ns, a.tool, false}, out);
    ++counters_.implicit_tool_changes;
  }
  const bool cut = a.cutting && !interrupted_;
  if (have_sample_ && cut && cutting_) {
    // Only motion between two cutting samples is cut path: the trip to the laser and back, and
    // a program restart further back (sister tool), are not.
    double d = 0.0;
    if (std::isfinite(a.program_path_mm) && std::isfinite(last_sample_.program_path_mm)) {
      d = a.program_path_mm - last_sample_.program_path_mm;
    } else {
      const std::size_t n = std::min<std::size_t>(
          {static_cast<std::size_t>(a.axis_count),
           static_cast<std::size_t>(last_sample_.axis_count), std::size_t{3}});
      double sq = 0.0;
      for (std::size_t k = 0; k < n; ++k) {
        const double dk = a.position_mm[k] - last_sample_.position_mm[k];
        sq += dk * dk;
      }
      d = std::sqrt(sq);
    }
    if (std::isfinite(d) && d > 0.0) {
      s_.cut_path_mm += d;
      if (!s_.halted) s_.creep_path_mm += d;
      if (config_.interval.basis == IntervalBasis::kMaterial) {
        s_.removed_mm3 += removal_mm3(last_sample_, a, d);
      }
    }
    update_feed_direction(a);
  }
  last_sample_ = a;
  have_sample_ = true;
  cutting_ = cut;
  if (a.cutting) between_parts_ = false;
  if (s_.tool == 0 && a.tool != 0) {
    s_.tool = a.tool;
    select_tool_tables();
  }
}

double WearCompensator::slot_clock(const CreepSlot& c) const noexcept {
  return c.path_based ? s_.creep_path_mm : s_.creep_time_s;
}

double WearCompensator::slot_value_um(const CreepSlot& c, std::size_t i) const noexcept {
  const double t = slot_clock(c) - c.start;
  const double span = c.span[i];
  const double l = c.carry_span[i];
  double body = c.delta_um[i];
  double carry = 0.0;
  if (l > 0.0) {
    const double s = c.carry_slope[i];
    const double tc = std::clamp(t, 0.0, l);
    carry = s * (tc - tc * tc / (2.0 * l));
    body -= 0.5 * s * l;
  }
  double f = 1.0;
  if (span > 0.0) {
    const double u = t / span;
    f = profile_fraction(config_.profile, c.eased ? eased(u) : u, &table_);
  }
  return body * f + carry;
}

double WearCompensator::slot_slope(const CreepSlot& c, std::size_t i) const noexcept {
  const double t = slot_clock(c) - c.start;
  const double span = c.span[i];
  const double l = c.carry_span[i];
  double body = c.delta_um[i];
  double slope = 0.0;
  if (l > 0.0) {
    body -= 0.5 * c.carry_slope[i] * l;
    if (t >= 0.0 && t < l) slope += c.carry_slope[i] * (1.0 - t / l);
  }
  if (span > 0.0 && t >= 0.0 && t < span) {
    const double u = t / span;
    const double df = c.eased ? profile_slope(config_.profile, eased(u), &table_) * eased_slope(u)
                              : profile_slope(config_.profile, u, &table_);
    slope += body * df / span;
  }
  return slope;
}

bool WearCompensator::predicting() const noexcept {
  return config_.predict.enabled && s_.rate_known && s_.measurements >= 2;
}

double WearCompensator::predicted_um(std::size_t i) const noexcept {
  if (!predicting()) return 0.0;
  // The rate blends linearly from the one in force before the last measurement to the fitted
  // one over rate_blend_mm of path: the integral of that rate.
  const double p = std::max(0.0, s_.creep_path_mm - s_.last_measurement_creep_path_mm);
  const double r0 = s_.rate_prev_um_per_mm[i];
  const double r1 = s_.rate_um_per_mm[i];
  const double lb = s_.rate_blend_mm;
  const double grown =
      lb > 0.0 && p < lb ? r0 * p + (r1 - r0) * p * p / (2.0 * lb) : r1 * p - (r1 - r0) * 0.5 * lb;
  return std::clamp(grown, 0.0, config_.predict.max_um);
}

double WearCompensator::prediction_slope(std::size_t i) const noexcept {
  if (!predicting()) return 0.0;
  const double g = predicted_um(i);
  if (!(g > 0.0) || g >= config_.predict.max_um) return 0.0;  // clamped: not growing
  const double p = std::max(0.0, s_.creep_path_mm - s_.last_measurement_creep_path_mm);
  const double r0 = s_.rate_prev_um_per_mm[i];
  const double r1 = s_.rate_um_per_mm[i];
  const double lb = s_.rate_blend_mm;
  return lb > 0.0 && p < lb ? r0 + (r1 - r0) * p / lb : r1;
}

double WearCompensator::applied_wear_um(std::size_t i) const noexcept {
  if (i >= points_) return 0.0;
  double w = s_.committed_um[i] + predicted_um(i);
  for (std::size_t k = 0; k < config_.max_creeps; ++k) {
    const auto& c = s_.creeps[k];
    if (c.active) w += slot_value_um(c, i);
  }
  return w;
}

estimation::KalmanFilter<2> WearCompensator::estimator_at(std::size_t i,
                                                          double& path_mm) const noexcept {
  estimation::KalmanFilter<2> kf;
  Eigen::Matrix2d p;
  if (s_.estimate_valid) {
    p << s_.estimate_p_ww[i], s_.estimate_p_wr[i], s_.estimate_p_wr[i], s_.estimate_p_rr[i];
    kf.reset(Eigen::Vector2d(s_.estimate_wear_um[i], s_.estimate_rate_um_per_mm[i]), p);
    path_mm = s_.estimate_path_mm;
    return kf;
  }
  // No estimate yet: start from what is known, so a restart, an upgrade or switching the
  // estimator on neither resets the wear nor applies it twice.
  const auto& e = config_.estimator;
  const double sw = e.measurement_sigma_um;
  // A new tool (no fitted rate) starts from the family's rate prior when it was given one.
  const bool family_prior = !s_.rate_known && s_.rate_prior_sigma_um_per_mm[i] > 0.0;
  const double sr =
      family_prior ? s_.rate_prior_sigma_um_per_mm[i] : e.initial_rate_sigma_um_per_mm;
  const double r0 =
      s_.rate_known ? s_.rate_um_per_mm[i] : (family_prior ? s_.rate_prior_um_per_mm[i] : 0.0);
  p << sw * sw, 0.0, 0.0, sr * sr;
  kf.reset(Eigen::Vector2d(s_.measured_um[i], r0), p);
  path_mm = s_.last_measurement_cut_path_mm;
  return kf;
}

double WearCompensator::rate_q() const noexcept {
  if (std::isfinite(s_.rate_q)) return s_.rate_q;
  const double rn = config_.estimator.rate_noise_um_per_mm_per_sqrt_m;
  return rn * rn / 1000.0;  // the key is per sqrt(m), the filter's clock is mm
}

Eigen::Matrix2d WearCompensator::estimator_noise(double d_mm) const noexcept {
  const double wn = config_.estimator.wear_noise_um_per_sqrt_m;
  return estimation::cv_process_noise(d_mm, wn * wn / 1000.0, rate_q());
}

double WearCompensator::finished_tool_rate_q(const CreepState& st) const noexcept {
  // The model's rate is a random walk from 0 at the tool's start: after L mm of cut path
  // E[rate²] = q·L. The rate is the least-squares slope of the remembered measurements (not the
  // filter's, which depends on the q being learned); its noise variance σ²/Sxx is subtracted,
  // so the estimate is unbiased and may be negative for one tool (the family's mean is clamped).
  const std::size_t first = st.history_has_origin ? 1U : 0U;
  if (st.history_count < first + 3) return kNaN;
  const double n = static_cast<double>(st.history_count - first);
  const double length_mm = st.last_measurement_cut_path_mm;
  if (!(length_mm > 0.0)) return kNaN;
  double mean_x = 0.0;
  for (std::size_t h = first; h < st.history_count; ++h) mean_x += st.history[h].cut_path_mm;
  mean_x /= n;
  double sxx = 0.0;
  for (std::size_t h = first; h < st.history_count; ++h) {
    const double dx = st.history[h].cut_path_mm - mean_x;
    sxx += dx * dx;
  }
  if (!(sxx > 1e-9)) return kNaN;
  const double sigma = config_.estimator.measurement_sigma_um;
  double q = 0.0;
  for (std::size_t i = 0; i < points_; ++i) {
    double mean_y = 0.0;
    for (std::size_t h = first; h < st.history_count; ++h) mean_y += st.history[h].wear_um[i];
    mean_y /= n;
    double sxy = 0.0;
    for (std::size_t h = first; h < st.history_count; ++h) {
      sxy += (st.history[h].cut_path_mm - mean_x) * (st.history[h].wear_um[i] - mean_y);
    }
    const double slope = sxy / sxx;
    q += (slope * slope - sigma * sigma / sxx) / length_mm;
  }
  return q / static_cast<double>(points_);
}

bool WearCompensator::family_rate_prior(std::size_t i, double& mean_um_per_mm,
                                        double& sigma_um_per_mm) const noexcept {
  mean_um_per_mm = kNaN;
  sigma_um_per_mm = kNaN;
  const auto& f = s_.family_rate;
  if (i >= points_ || f.tools < 2) return false;
  const double n = static_cast<double>(f.tools);
  // The predictive spread of one more tool: the tools' sample variance and that of their mean.
  const double var = f.rate_m2[i] / (n - 1.0) * (1.0 + 1.0 / n);
  mean_um_per_mm = f.rate_mean_um_per_mm[i];
  sigma_um_per_mm = std::sqrt(var);
  return sigma_um_per_mm > 0.0 && std::isfinite(sigma_um_per_mm);
}

double WearCompensator::family_rate_q() const noexcept {
  const auto& f = s_.family;
  if (f.tools == 0) return kNaN;
  return std::max(0.0, f.rate_q_sum / static_cast<double>(f.tools));
}

double WearCompensator::nis_mean(std::size_t i) const noexcept {
  if (i >= points_ || s_.nis_count == 0) return kNaN;
  return s_.nis_sum[i] / static_cast<double>(s_.nis_count);
}

double WearCompensator::measurement_sigma_estimate_um(std::size_t i) const noexcept {
  if (i >= points_ || s_.nis_count == 0) return kNaN;
  return std::sqrt(std::max(0.0, s_.residual_var_sum_um2[i] / static_cast<double>(s_.nis_count)));
}

bool WearCompensator::wear_estimate(std::size_t i, double& wear_um,
                                    double& sigma_um) const noexcept {
  wear_um = kNaN;
  sigma_um = kNaN;
  if (!config_.estimator.enabled || !s_.estimate_valid || i >= points_) return false;
  double path = 0.0;
  auto kf = estimator_at(i, path);
  const double d = std::max(0.0, s_.cut_path_mm - path);
  kf.predict(estimation::cv_transition(d), estimator_noise(d));
  wear_um = kf.state()(0);
  sigma_um = std::sqrt(std::max(0.0, kf.covariance()(0, 0)));
  return true;
}

std::size_t WearCompensator::creeps_in_progress() const noexcept {
  std::size_t n = 0;
  for (std::size_t k = 0; k < config_.max_creeps; ++k) n += s_.creeps[k].active ? 1U : 0U;
  return n;
}

void WearCompensator::retire_finished_creeps() noexcept {
  for (std::size_t k = 0; k < config_.max_creeps; ++k) {
    auto& c = s_.creeps[k];
    if (!c.active) continue;
    const double t = slot_clock(c) - c.start;
    bool done = true;
    for (std::size_t i = 0; i < points_ && done; ++i) {
      done = (!(c.span[i] > 0.0) || t >= c.span[i]) &&
             (!(c.carry_span[i] > 0.0) || t >= c.carry_span[i]);
    }
    if (done) {
      for (std::size_t i = 0; i < points_; ++i) s_.committed_um[i] += c.delta_um[i];
      c.active = false;
    }
  }
  if (s_.entry.active && s_.creep_path_mm - s_.entry.start_path_mm >= s_.entry.length_mm) {
    s_.entry.active = false;
  }
}

void WearCompensator::start_creep(const std::array<double, kMaxEdgePoints>& delta_um, bool moving,
                                  StepOutput& out, TimeNs now_ns) noexcept {
  std::array<double, kMaxEdgePoints> delta = delta_um;
  double largest = 0.0;
  for (std::size_t i = 0; i < points_; ++i) largest = std::max(largest, std::fabs(delta[i]));
  if (largest < kTiny) return;  // nothing new: the creeps in progress continue unchanged

  const bool path_based =
      config_.creep_basis == CreepBasis::kPath || config_.creep_basis == CreepBasis::kRatePath;
  const bool step = config_.profile == ProfileShape::kStep;
  CreepSlot* slot = nullptr;
  CreepSlot* oldest = nullptr;
  for (std::size_t k = 0; k < config_.max_creeps; ++k) {
    auto& c = s_.creeps[k];
    if (!c.active) {
      slot = &c;
      break;
    }
    if (oldest == nullptr || c.seq < oldest->seq) oldest = &c;
  }
  // A folded creep's slope and remainder, carried into the new one.
  std::array<double, kMaxEdgePoints> carry_slope{};
  std::array<double, kMaxEdgePoints> carry_rest{};
  std::array<double, kMaxEdgePoints> carry_clock{};
  if (slot == nullptr && oldest == nullptr) return;  // no slot at all (max_creeps >= 1)
  if (slot == nullptr) {
    // All slots busy: what the oldest creep has fed in stays in force, its remainder joins the
    // new creep, so the offset keeps its value (no step) and nothing is lost; its slope is
    // carried into the new creep and fades out there (no kink).
    const double t = slot_clock(*oldest) - oldest->start;
    for (std::size_t i = 0; i < points_; ++i) {
      const double v = slot_value_um(*oldest, i);
      s_.committed_um[i] += v;
      carry_rest[i] = oldest->delta_um[i] - v;
      delta[i] += carry_rest[i];
      // Only on the same clock (the basis may have changed with a config reload) and not for the
      // step profile, which has no slope to keep.
      if (oldest->path_based == path_based && !step) {
        carry_slope[i] = slot_slope(*oldest, i);
        carry_clock[i] = std::max(0.0, std::max(oldest->span[i], oldest->carry_span[i]) - t);
      }
    }
    slot = oldest;
    ++counters_.creeps_folded;
    out.alarm(now_ns, Severity::kInfo, AlarmCode::kCreepUnfinished, s_.tool,
              static_cast<double>(config_.max_creeps));
  }
  *slot = CreepSlot{};
  slot->active = true;
  slot->seq = s_.next_seq++;
  slot->path_based = path_based;
  slot->start = path_based ? s_.creep_path_mm : s_.creep_time_s;
  // Entered with zero slope when the offset moves now and the profile would start with a slope
  // (linear, a table whose first step rises); cosine and smoothstep start flat by themselves.
  slot->eased = moving && !step && profile_slope(config_.profile, 0.0, &table_) > kTiny;
  for (std::size_t i = 0; i < points_; ++i) {
    slot->delta_um[i] = delta[i];
    double span = 0.0;
    switch (config_.creep_basis) {
      case CreepBasis::kPath:
        span = config_.creep_length_mm;
        break;
      case CreepBasis::kTime:
        span = config_.creep_time_s;
        break;
      case CreepBasis::kRateTime:
        span = std::fabs(delta[i]) / config_.creep_rate_um_per_min * 60.0;
        break;
      case CreepBasis::kRatePath:
        span = std::fabs(delta[i]) / config_.creep_rate_um_per_mm;
        break;
    }
    const double s = carry_slope[i];
    if (std::fabs(s) > kTiny) {
      // At a rate the span follows the amount; never shorter than what the folded creep had
      // left, so a small amount does not turn the carried slope into a sudden stop.
      if (config_.creep_basis == CreepBasis::kRateTime ||
          config_.creep_basis == CreepBasis::kRatePath) {
        span = std::max(span, carry_clock[i]);
      }
      // Fade the carried slope out over kBlendFraction of the span, but never further than
      // the new target (same direction: the creep stays monotonic and within its end value) or
      // than the folded creep would have gone (opposite direction).
      const double reach = s * delta[i] > 0.0 ? std::fabs(delta[i]) : std::fabs(carry_rest[i]);
      const double l = std::min(kEase * span, 2.0 * reach / std::fabs(s));
      if (l > kTiny) {
        slot->carry_slope[i] = s;
        slot->carry_span[i] = l;
      }
    }
    slot->span[i] = span;
  }
}

void WearCompensator::start_entry(double offset_um, double length_mm) noexcept {
  if (offset_um >= entry_offset_um()) {
    s_.entry = EntrySlot{true, s_.creep_path_mm, offset_um, length_mm};
  }
}

double WearCompensator::entry_offset_um() const noexcept {
  const auto& e = s_.entry;
  if (!e.active) return 0.0;
  const double u = (s_.creep_path_mm - e.start_path_mm) / e.length_mm;
  return e.offset_um * (1.0 - profile_fraction(config_.profile, u, &table_));
}

double WearCompensator::transition_offset_um() const noexcept {
  if (!have_sample_ || !std::isfinite(last_sample_.program_path_mm)) return 0.0;
  const double p = last_sample_.program_path_mm;
  for (std::size_t k = 0; k < transition_count_; ++k) {
    const auto& t = config_.transitions[transition_index_[k]];
    if (p < t.start_path_mm || p > t.end_path_mm) continue;
    double v = 0.0;
    if (t.in_offset_um > 0.0 && p < t.start_path_mm + t.in_length_mm) {
      const double u = (p - t.start_path_mm) / t.in_length_mm;
      v += t.in_offset_um * (1.0 - profile_fraction(config_.profile, u, &table_));
    }
    if (t.out_offset_um > 0.0 && p > t.end_path_mm - t.out_length_mm) {
      const double u = (p - (t.end_path_mm - t.out_length_mm)) / t.out_length_mm;
      v += t.out_offset_um * profile_fraction(config_.profile, u, &table_);
    }
    return v;
  }
  return 0.0;
}

double WearCompensator::deflection(double wear_um, bool lateral) const noexcept {
  if (deflection_index_ < 0) return 0.0;
  const auto& d = config_.deflection[static_cast<std::size_t>(deflection_index_)];
  const auto& y = lateral ? d.lateral_um : d.normal_um;
  const auto& x = d.wear_um;
  if (!(wear_um > x.front())) return y.front();  // also NaN
  if (wear_um >= x.back()) return y.back();
  const auto it = std::upper_bound(x.begin(), x.end(), wear_um);
  const auto j = static_cast<std::size_t>(it - x.begin());
  const double t = (wear_um - x[j - 1]) / (x[j] - x[j - 1]);
  return y[j - 1] + t * (y[j] - y[j - 1]);
}

bool WearCompensator::normal_now(std::array<double, 3>& n) const noexcept {
  switch (config_.edge.normal_source) {
    case NormalSource::kNone:
      return false;
    case NormalSource::kAxisSample:
      if (!have_sample_ || !last_sample_.has_normal) return false;
      n = last_sample_.normal;
      break;
    case NormalSource::kToolpath: {
      if (!have_sample_ || !std::isfinite(last_sample_.program_path_mm)) return false;
      const auto& tp = config_.toolpath.rows;
      const double p = last_sample_.program_path_mm;
      const auto it = std::upper_bound(tp.begin(), tp.end(), p,
                                       [](double v, const auto& r) { return v < r.path_mm; });
      if (it == tp.begin()) {
        n = tp.front().normal;
      } else if (it == tp.end()) {
        n = tp.back().normal;
      } else {
        const auto& b = *it;
        const auto& a = *(it - 1);
        const double t = (p - a.path_mm) / (b.path_mm - a.path_mm);
        for (std::size_t k = 0; k < 3; ++k) n[k] = a.normal[k] + t * (b.normal[k] - a.normal[k]);
      }
      break;
    }
  }
  const double len = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
  if (!std::isfinite(len) || len < 1e-9) return false;
  for (auto& v : n) v /= len;
  return true;
}

double WearCompensator::toolpath_volume_mm3(double p) const noexcept {
  const auto& rows = config_.toolpath.rows;
  const double fallback = config_.interval.removal_mm3_per_mm;
  if (p <= rows.front().path_mm) return (p - rows.front().path_mm) * fallback;
  if (p >= rows.back().path_mm) {
    return removal_cum_mm3_.back() + (p - rows.back().path_mm) * fallback;
  }
  const auto it = std::upper_bound(rows.begin(), rows.end(), p,
                                   [](double v, const ToolpathRow& r) { return v < r.path_mm; });
  const auto j = static_cast<std::size_t>(it - rows.begin()) - 1;
  return removal_cum_mm3_[j] + rows[j].removal_mm2 * (p - rows[j].path_mm);
}

double WearCompensator::removal_mm3(const AxisSample& from, const AxisSample& to,
                                    double d_mm) const noexcept {
  const auto& iv = config_.interval;
  if (iv.removal_source == RemovalSource::kToolpath && !removal_cum_mm3_.empty() &&
      std::isfinite(from.program_path_mm) && std::isfinite(to.program_path_mm)) {
    // The cross-section of every segment between the two program positions, each over its
    // own length (d_mm is that same program path difference here).
    return std::max(
        0.0, toolpath_volume_mm3(to.program_path_mm) - toolpath_volume_mm3(from.program_path_mm));
  }
  return d_mm * iv.removal_mm3_per_mm;
}

void WearCompensator::update_feed_direction(const AxisSample& a) noexcept {
  const std::size_t n =
      std::min<std::size_t>({static_cast<std::size_t>(a.axis_count),
                             static_cast<std::size_t>(last_sample_.axis_count), std::size_t{3}});
  std::array<double, 3> f{};
  for (std::size_t k = 0; k < n; ++k) f[k] = a.position_mm[k] - last_sample_.position_mm[k];
  // Across the tool axis only: a plunge along the axis keeps the last direction.
  const auto& ax = config_.edge.tool_axis;
  const double along = f[0] * ax[0] + f[1] * ax[1] + f[2] * ax[2];
  for (std::size_t k = 0; k < 3; ++k) f[k] -= along * ax[k];
  const double len = std::sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2]);
  if (!std::isfinite(len) || len < 1e-9) return;
  for (std::size_t k = 0; k < 3; ++k) feed_dir_[k] = f[k] / len;
  have_feed_ = true;
}

bool WearCompensator::material_direction(std::array<double, 3>& m) const noexcept {
  const auto side = config_.edge.material_side;
  if (side == MaterialSide::kNone || !have_feed_) return false;
  const auto& a = config_.edge.tool_axis;
  const auto& f = feed_dir_;
  // Right of the feed (tool axis up) = f × a; left = a × f.
  const std::array<double, 3> right{f[1] * a[2] - f[2] * a[1], f[2] * a[0] - f[0] * a[2],
                                    f[0] * a[1] - f[1] * a[0]};
  const double sgn = side == MaterialSide::kRight ? 1.0 : -1.0;
  for (std::size_t k = 0; k < 3; ++k) m[k] = sgn * right[k];
  return true;
}

void WearCompensator::compute_targets() noexcept {
  const double away_um = entry_offset_um() + transition_offset_um();
  const bool axes = config_.output.mode == OutputMode::kAxes;
  std::array<double, kChannelCount> target{};
  std::array<double, 3> n{};
  double c = 0.0;
  double l = 0.0;
  bool have_normal = normal_now(n);
  if (have_normal) {
    s_.held_normal = n;
    s_.normal_held = true;
  } else if (s_.normal_held && config_.edge.normal_source != NormalSource::kNone) {
    // No normal now (not cutting, an interruption, the trip to the laser, a restart): the last
    // one stays in force, so the split of the correction between the registers, and with it the
    // offset at the surface, does not change until the NC publishes a new one.
    n = s_.held_normal;
    have_normal = true;
  }
  if (have_normal) {
    const auto& ax = config_.edge.tool_axis;
    // A normal against the tool axis (undercut) cannot be reached by the edge: clamp to 90°.
    const double dot = std::clamp(n[0] * ax[0] + n[1] * ax[1] + n[2] * ax[2], 0.0, 1.0);
    const double theta_deg = std::acos(dot) * kRadToDeg;
    engagement_deg_ = theta_deg;
    double w = 0.0;
    if (points_ < 2) {
      w = applied_wear_um(0);
    } else {
      // Only the two support points around the engagement angle are evaluated (cost).
      const double x = theta_deg / 90.0 * static_cast<double>(points_ - 1);
      const auto i0 = std::min(static_cast<std::size_t>(x), points_ - 2);
      const double t = x - static_cast<double>(i0);
      const double w0 = applied_wear_um(i0);
      w = w0 + t * (applied_wear_um(i0 + 1) - w0);
    }
    c = w + deflection(w, false) - away_um;
    l = deflection(w, true);
    // Lateral = the bending direction of the tool: the normal's part across the tool axis.
    std::array<double, 3> lat{n[0] - dot * ax[0], n[1] - dot * ax[1], n[2] - dot * ax[2]};
    const double lat_len = std::sqrt(lat[0] * lat[0] + lat[1] * lat[1] + lat[2] * lat[2]);
    if (lat_len > 1e-6) {
      for (auto& v : lat) v /= lat_len;
    } else {
      lat = {0.0, 0.0, 0.0};
    }
    if (axes) {
      for (std::size_t k = 0; k < 3; ++k) target[k] = -c * n[k] - l * lat[k];
    } else {
      const double sin_t = std::sqrt(std::max(0.0, 1.0 - dot * dot));
      const double sgn = config_.output.tool_register_sign;
      target[static_cast<std::size_t>(Channel::kRadius)] = sgn * (c * sin_t + l);
      target[static_cast<std::size_t>(Channel::kLength)] = sgn * (c * dot);
    }
  } else {
    engagement_deg_ = kNaN;
    double mean = 0.0;
    for (std::size_t i = 0; i < points_; ++i) mean += applied_wear_um(i);
    mean /= static_cast<double>(points_);
    c = mean + deflection(mean, false) - away_um;
    const double sgn = axes ? config_.edge.fallback_sign : config_.output.tool_register_sign;
    target[static_cast<std::size_t>(config_.edge.fallback_channel)] = sgn * c;
    // Lateral deflection without a normal: on the radius register (the NC's radius
    // compensation knows the side), or across the feed direction toward the configured
    // material side on the axes; without a side or a feed direction it is not applied.
    l = deflection(mean, true);
    std::array<double, 3> m{};
    if (!axes) {
      target[static_cast<std::size_t>(Channel::kRadius)] += config_.output.tool_register_sign * l;
    } else if (material_direction(m)) {
      for (std::size_t k = 0; k < 3; ++k) target[k] += l * m[k];
    } else {
      l = 0.0;
    }
  }
  correction_um_ = c;
  lateral_um_ = l;
  apply_adoption(target);
  if (s_.halted) {
    target = s_.channel_output_um;  // stop applying: hold what the NC has
  }
  target_um_ = target;
}

void WearCompensator::apply_adoption(std::array<double, kChannelCount>& target) noexcept {
  auto& a = adopted_;
  if (fade_pending_) {
    // The first measurement after the adoption: from here the held values give way to the
    // computed ones along the creep profile (target = held at the start, computed at the end).
    fade_pending_ = false;
    double largest = 0.0;
    for (std::size_t ch = 0; ch < kChannelCount; ++ch) {
      a.fade_um[ch] = a.held[ch] != 0 ? a.held_um[ch] - target[ch] : 0.0;
      largest = std::max(largest, std::fabs(a.fade_um[ch]));
      a.held[ch] = 0;
    }
    const bool path_based =
        config_.creep_basis == CreepBasis::kPath || config_.creep_basis == CreepBasis::kRatePath;
    a.fade_path_based = path_based ? 1 : 0;
    a.fade_start = path_based ? s_.creep_path_mm : s_.creep_time_s;
    a.fade_span = creep_span(largest);
    a.fading = largest > kTiny ? 1 : 0;
  }
  for (std::size_t ch = 0; ch < kChannelCount; ++ch) {
    if (a.held[ch] != 0) target[ch] = a.held_um[ch];
  }
  if (a.fading != 0) {
    const double clock = a.fade_path_based != 0 ? s_.creep_path_mm : s_.creep_time_s;
    const double u = a.fade_span > 0.0 ? (clock - a.fade_start) / a.fade_span : 1.0;
    const double rest = 1.0 - profile_fraction(config_.profile, u, &table_);
    if (rest <= 0.0) {
      a.fading = 0;
    } else {
      for (std::size_t ch = 0; ch < kChannelCount; ++ch) target[ch] += rest * a.fade_um[ch];
    }
  }
}

double WearCompensator::creep_span(double amount_um) const noexcept {
  switch (config_.creep_basis) {
    case CreepBasis::kPath:
      return config_.creep_length_mm;
    case CreepBasis::kTime:
      return config_.creep_time_s;
    case CreepBasis::kRateTime:
      return std::fabs(amount_um) / config_.creep_rate_um_per_min * 60.0;
    case CreepBasis::kRatePath:
      return std::fabs(amount_um) / config_.creep_rate_um_per_mm;
  }
  return 0.0;
}

bool WearCompensator::adoption_active() const noexcept {
  if (adopted_.fading != 0) return true;
  for (const auto h : adopted_.held) {
    if (h != 0) return true;
  }
  return false;
}

bool WearCompensator::adopt_channel(Channel ch, double value_um) noexcept {
  const auto k = static_cast<std::size_t>(ch);
  if (config_.output.channel_register[k] < 0 || !limiters_[k].admissible(value_um)) {
    return false;
  }
  adopted_.held[k] = 1;
  adopted_.held_um[k] = value_um;
  s_.channel_output_um[k] = value_um;  // the limiter starts here at the first step
  const bool axes = config_.output.mode == OutputMode::kAxes;
  if (ch != config_.edge.fallback_channel || s_.measurements > 0) return true;
  // The wear baseline: without a normal the fallback channel carries sign · (w + deflection(w)),
  // plus the lateral deflection on a radius register; find the uniform w ≥ 0 behind the value.
  const double sign = axes ? config_.edge.fallback_sign : config_.output.tool_register_sign;
  const bool lateral = !axes && ch == Channel::kRadius;
  const auto h = [&](double w) {
    return w + deflection(w, false) + (lateral ? deflection(w, true) : 0.0);
  };
  const double c = value_um / sign;
  double lo = 0.0;
  double hi = limiters_[k].config().max_abs_um;
  if (!(c > h(lo)) || c > h(hi)) return true;  // no wear, or no uniform wear explains it
  for (int it = 0; it < 200; ++it) {
    const double mid = 0.5 * (lo + hi);
    if (!(mid > lo && mid < hi)) break;  // adjacent doubles
    (h(mid) < c ? lo : hi) = mid;
  }
  const double w = std::fabs(h(lo) - c) < std::fabs(h(hi) - c) ? lo : hi;
  for (std::size_t i = 0; i < points_; ++i) {
    s_.committed_um[i] = w;
    s_.measured_um[i] = w;
    s_.history[0].wear_um[i] = w;
  }
  // The baseline is the first point of the rate fit, at this tool's path (not the origin).
  s_.history[0].cut_path_mm = s_.cut_path_mm;
  s_.history_count = 1;
  s_.history_has_origin = false;
  return true;
}

bool WearCompensator::adopt_flag(std::size_t slot, double value) noexcept {
  if (!(value >= 0.5)) return false;
  switch (slot) {
    case 0:
      s_.warning_flag = true;
      return true;
    case 1:
      s_.alarm_flag = true;
      return true;
    case 3:
      s_.tool_change_flag = true;
      return true;
    default:
      return false;
  }
}

void WearCompensator::write_outputs(TimeNs now_ns, StepOutput& out) noexcept {
  const auto& o = config_.output;
  const auto refresh_ns = from_seconds(o.refresh_interval_s);
  for (std::size_t ch = 0; ch < kChannelCount; ++ch) {
    const std::int32_t reg = o.channel_register[ch];
    if (reg < 0) continue;
    const LimitResult r = limiters_[ch].apply(target_um_[ch], now_ns);
    if (r.verdict != last_verdict_[ch]) {
      // Edge-triggered, so a held limit does not flood the alarm ring every cycle.
      switch (r.verdict) {
        case LimitVerdict::kPassed:
          break;
        case LimitVerdict::kSlewed:
          out.alarm(now_ns, Severity::kWarning, AlarmCode::kOffsetSlewLimited, reg, target_um_[ch]);
          break;
        case LimitVerdict::kRejectedNonFinite:
          out.alarm(now_ns, Severity::kAlarm, AlarmCode::kOffsetNonFinite, reg, target_um_[ch]);
          break;
        case LimitVerdict::kRejectedAbsolute:
          out.alarm(now_ns, Severity::kAlarm, AlarmCode::kOffsetBeyondAbsoluteLimit, reg,
                    target_um_[ch]);
          break;
      }
      last_verdict_[ch] = r.verdict;
    }
    s_.channel_output_um[ch] = r.value_um;
    const double diff = std::fabs(r.value_um - written_um_[ch]);
    const bool reached = std::fabs(r.value_um - target_um_[ch]) < kTiny;
    const bool due = !written_once_[ch] || diff >= o.write_resolution_um ||
                     (reached && diff > kTiny) ||
                     (refresh_ns > 0 && now_ns - written_ns_[ch] >= refresh_ns);
    if (due) {
      out.writes.push(OffsetWrite{now_ns, static_cast<std::uint16_t>(reg), r.value_um});
      written_um_[ch] = r.value_um;
      written_ns_[ch] = now_ns;
      written_once_[ch] = true;
    }
  }
  write_flag(now_ns, o.warning_register, s_.warning_flag, 0, out);
  write_flag(now_ns, o.alarm_register, s_.alarm_flag, 1, out);
  // Re-armed (start-up): 0 until rearm_until_ns_, or until a measurement lowered the request.
  rearm_ = rearm_ && s_.measurement_due_flag && now_ns < rearm_until_ns_;
  write_flag(now_ns, o.measurement_due_register, s_.measurement_due_flag && !rearm_, 2, out);
  write_flag(now_ns, o.tool_change_register, s_.tool_change_flag, 3, out);
  const double restart_mm = restart_program_path_mm();
  if (o.restart_path_register >= 0 && std::isfinite(restart_mm)) {
    const double v = restart_mm * kUmPerMm;
    const bool due = !flag_written_once_[4] || std::fabs(v - flag_written_[4]) > kTiny ||
                     (refresh_ns > 0 && now_ns - flag_written_ns_[4] >= refresh_ns);
    if (due) {
      out.writes.push(OffsetWrite{now_ns, static_cast<std::uint16_t>(o.restart_path_register), v});
      flag_written_[4] = v;
      flag_written_ns_[4] = now_ns;
      flag_written_once_[4] = true;
    }
  }
}

void WearCompensator::write_flag(TimeNs now_ns, std::int32_t reg, bool value, std::size_t slot,
                                 StepOutput& out) noexcept {
  if (reg < 0) return;
  const double v = value ? 1.0 : 0.0;
  const auto refresh_ns = from_seconds(config_.output.refresh_interval_s);
  const bool due = !flag_written_once_[slot] || std::fabs(v - flag_written_[slot]) > 0.5 ||
                   (refresh_ns > 0 && now_ns - flag_written_ns_[slot] >= refresh_ns);
  if (!due) return;
  out.writes.push(OffsetWrite{now_ns, static_cast<std::uint16_t>(reg), v});
  flag_written_[slot] = v;
  flag_written_ns_[slot] = now_ns;
  flag_written_once_[slot] = true;
}

// ---------------------------------------------------------------------------------------------

void WearCompensator::halt(TimeNs now_ns, AlarmCode code, double value, StepOutput& out) noexcept {
  s_.halted = true;
  s_.alarm_flag = true;
  ++counters_.measurements_refused;
  out.alarm(now_ns, Severity::kAlarm, code, s_.tool, value);
}

void WearCompensator::on_measurement(TimeNs now_ns, const ToolMeasurement& m,
                                     StepOutput& out) noexcept {
  // Every laser measurement answers the request, whatever is decided about it below: the flag
  // falls. Until it is accepted, the next request waits for one interval after this one (a
  // refused measurement is not asked for again in the same cycle, nor at every cycle by an NC
  // that reacts to the level of the flag).
  s_.measurement_due_flag = false;
  s_.request_held = true;
  s_.refused_cut_path_mm = s_.cut_path_mm;
  s_.refused_cut_time_s = s_.cut_time_s;
  s_.refused_removed_mm3 = s_.removed_mm3;
  const std::size_t n_meas = m.point_count;
  if (n_meas != points_ && n_meas != 1) {
    ++counters_.events_invalid;
    ++counters_.measurements_refused;
    out.alarm(now_ns, Severity::kWarning, AlarmCode::kEventInvalid, m.tool,
              static_cast<double>(n_meas));
    return;
  }
  std::array<double, kMaxEdgePoints> w{};
  for (std::size_t i = 0; i < points_; ++i) {
    w[i] = m.broken || m.fault != InputFault::kNone ? kNaN : m.wear_um[n_meas == 1 ? 0 : i];
  }
  // Every measurement is logged, one row per support point, whatever is decided below.
  for (std::size_t i = 0; i < points_; ++i) {
    MeasurementRecord r{};
    r.time_ns = m.time_ns;
    r.part = s_.part;
    r.tool = m.tool;
    r.kind = MeasurementKind::kToolWear;
    r.point = static_cast<std::int32_t>(i);
    for (std::size_t k = 0; k < 3; ++k) r.position_mm[k] = last_sample_.position_mm[k];
    r.angle_deg = support_angle_deg(i, points_);
    r.path_mm = s_.cut_path_mm;
    r.measured_um = w[i];
    r.applied_um = 0.0;
    out.records.push(r);
  }
  if (m.fault != InputFault::kNone && !s_.halted) {
    // The laser's result did not arrive intact (the driver's fault, e.g. NaN in the register):
    // the tool in the spindle counts as mismeasured, whatever tool number came with it.
    halt(now_ns, AlarmCode::kToolBrokenOrMismeasured, kNaN, out);
    return;
  }
  if (s_.tool != 0 && m.tool != s_.tool) {
    ++counters_.events_invalid;
    ++counters_.measurements_refused;
    out.alarm(now_ns, Severity::kWarning, AlarmCode::kEventInvalid, m.tool,
              static_cast<double>(s_.tool));
    return;
  }
  if (s_.tool == 0) {
    s_.tool = m.tool;
    select_tool_tables();
  }
  if (s_.halted) {
    // Halted: logged above, applied only after the operator clears the alarm or changes tool.
    ++counters_.measurements_refused;
    out.alarm(now_ns, Severity::kWarning, AlarmCode::kEventInvalid, m.tool, 0.0);
    return;
  }

  // Plausibility: broken, NaN, shrinking beyond the noise, a jump many times the expected one.
  double max_inc = -std::numeric_limits<double>::infinity();
  double min_inc = std::numeric_limits<double>::infinity();
  double max_wear = 0.0;
  for (std::size_t i = 0; i < points_; ++i) {
    if (!std::isfinite(w[i])) {
      halt(now_ns, AlarmCode::kToolBrokenOrMismeasured, w[i], out);
      return;
    }
    const double inc = w[i] - s_.measured_um[i];
    max_inc = std::max(max_inc, inc);
    min_inc = std::min(min_inc, inc);
    max_wear = std::max(max_wear, std::fabs(w[i]));
  }
  const auto& tl = config_.tool_life;
  if (min_inc < -tl.noise_um) {
    halt(now_ns, AlarmCode::kToolBrokenOrMismeasured, min_inc, out);
    return;
  }
  double max_rate = 0.0;
  if (s_.rate_known) {
    for (std::size_t i = 0; i < points_; ++i) max_rate = std::max(max_rate, s_.rate_um_per_mm[i]);
  }
  const double since_mm = s_.cut_path_mm - s_.last_measurement_cut_path_mm;
  const double expected_um = std::max(tl.min_expected_increment_um, max_rate * since_mm);
  if (max_inc > tl.implausible_factor * expected_um) {
    halt(now_ns, AlarmCode::kToolBrokenOrMismeasured, max_inc, out);
    return;
  }
  if (tl.excessive_increment_um > 0.0 && max_inc > tl.excessive_increment_um) {
    if (tl.on_excessive == ExcessivePolicy::kStop) {
      halt(now_ns, AlarmCode::kToolExcessivelyWorn, max_inc, out);
    } else {
      ++counters_.measurements_refused;
      s_.warning_flag = true;
      s_.tool_change_flag = true;
      out.alarm(now_ns, Severity::kWarning, AlarmCode::kToolExcessivelyWorn, s_.tool, max_inc);
    }
    return;
  }
  // The limiter's absolute bound, checked before any state changes: a tool worn beyond what
  // may be compensated is reported, not compensated.
  const double worst_um =
      max_wear + std::fabs(deflection(max_wear, false)) + std::fabs(deflection(max_wear, true));
  if (!limiters_[0].admissible(worst_um)) {
    ++counters_.measurements_refused;
    s_.alarm_flag = true;
    out.alarm(now_ns, Severity::kAlarm, AlarmCode::kOffsetBeyondAbsoluteLimit, s_.tool, worst_um);
    return;
  }

  // The estimator, predicted to this cut path: a measurement beyond its gate at any support point
  // is implausible (alarm 23, value: the largest innovation [µm]) and changes nothing.
  if (config_.estimator.enabled) {
    const auto& e = config_.estimator;
    const double r = e.measurement_sigma_um * e.measurement_sigma_um;
    const Eigen::RowVector2d h(1.0, 0.0);
    bool gated = false;
    double worst_innovation_um = 0.0;
    for (std::size_t i = 0; i < points_; ++i) {
      double path = 0.0;
      auto& kf = estimate_scratch_[i];
      kf = estimator_at(i, path);
      const double d = std::max(0.0, s_.cut_path_mm - path);
      kf.predict(estimation::cv_transition(d), estimator_noise(d));
      const double innovation = w[i] - kf.predicted_measurement(h);
      const double s = kf.innovation_variance(h, r);
      nis_scratch_[i] = innovation * innovation / s;
      residual_scratch_[i] = innovation * innovation - (s - r);
      prior_fraction_scratch_[i] = (s - r) / s;
      if (!kf.update(h, w[i], r, e.gate_sigmas).accepted) {
        gated = true;
        if (std::fabs(innovation) > std::fabs(worst_innovation_um)) {
          worst_innovation_um = innovation;
        }
      }
    }
    if (gated) {
      ++counters_.measurements_gated;
      halt(now_ns, AlarmCode::kToolBrokenOrMismeasured, worst_innovation_um, out);
      return;
    }
  }

  if (creeps_in_progress() > 0) {
    double remaining = 0.0;
    for (std::size_t i = 0; i < points_; ++i) {
      double r = 0.0;
      for (std::size_t k = 0; k < config_.max_creeps; ++k) {
        const auto& c = s_.creeps[k];
        if (c.active) r += c.delta_um[i] - slot_value_um(c, i);
      }
      remaining = std::max(remaining, std::fabs(r));
    }
    switch (config_.on_unfinished) {
      case UnfinishedPolicy::kSuperpose:
        out.alarm(now_ns, Severity::kInfo, AlarmCode::kCreepUnfinished, s_.tool, remaining);
        break;
      case UnfinishedPolicy::kWarn:
        s_.warning_flag = true;
        out.alarm(now_ns, Severity::kWarning, AlarmCode::kCreepUnfinished, s_.tool, remaining);
        break;
      case UnfinishedPolicy::kAlarm:
        halt(now_ns, AlarmCode::kCreepUnfinished, remaining, out);
        return;
    }
    ++counters_.creeps_superposed;
  }

  // Accept. The prediction made so far becomes committed; the new creep corrects it. The offset
  // moves now if creeps are in progress or the prediction grows: the new creep then starts with
  // zero slope and the prediction's rate blends from the one in force (no kink).
  bool moving = predicting();
  for (std::size_t k = 0; k < config_.max_creeps && !moving; ++k) {
    const auto& c = s_.creeps[k];
    if (!c.active) continue;
    const double t = slot_clock(c) - c.start;
    for (std::size_t i = 0; i < points_ && !moving; ++i) {
      moving = t < c.span[i] || t < c.carry_span[i];
    }
  }
  std::array<double, kMaxEdgePoints> rate_now{};
  for (std::size_t i = 0; i < points_; ++i) rate_now[i] = prediction_slope(i);
  std::array<double, kMaxEdgePoints> delta{};
  for (std::size_t i = 0; i < points_; ++i) {
    s_.committed_um[i] += predicted_um(i);
    double target = s_.committed_um[i];
    for (std::size_t k = 0; k < config_.max_creeps; ++k) {
      const auto& c = s_.creeps[k];
      if (c.active) target += c.delta_um[i];
    }
    // With the estimator the creep goes toward its estimate, not the raw measurement.
    const double goal = config_.estimator.enabled ? estimate_scratch_[i].state()(0) : w[i];
    delta[i] = goal - target;
    s_.measured_um[i] = w[i];
  }
  const double interval_mm = s_.creep_path_mm - s_.last_measurement_creep_path_mm;
  s_.last_measurement_cut_path_mm = s_.cut_path_mm;
  s_.last_measurement_cut_time_s = s_.cut_time_s;
  s_.last_measurement_creep_path_mm = s_.creep_path_mm;
  s_.last_measurement_removed_mm3 = s_.removed_mm3;
  s_.rate_prev_um_per_mm = rate_now;
  s_.rate_blend_mm = kEase * std::max(0.0, interval_mm);
  if (have_sample_) s_.last_measurement_program_path_mm = last_sample_.program_path_mm;
  s_.request_held = false;
  ++s_.measurements;
  ++counters_.measurements_accepted;
  for (const auto h : adopted_.held) fade_pending_ = fade_pending_ || h != 0;

  if (s_.history_count == kMaxRateWindow) {
    std::copy(s_.history.begin() + 1, s_.history.end(), s_.history.begin());
    --s_.history_count;
    s_.history_has_origin = false;
  }
  auto& h = s_.history[s_.history_count++];
  h.cut_path_mm = s_.cut_path_mm;
  h.wear_um = w;
  // The tool's start rate for the family: its first measurement, and every one within
  // family_prior_path_mm of its life.
  if (s_.measurements == 1 || s_.cut_path_mm <= config_.estimator.family_prior_path_mm) {
    for (std::size_t i = 0; i < points_; ++i) s_.start_sxw[i] += s_.cut_path_mm * w[i];
    s_.start_sxx += s_.cut_path_mm * s_.cut_path_mm;
  }
  fit_rates();
  if (config_.estimator.enabled) {
    for (std::size_t i = 0; i < points_; ++i) {
      const auto& kf = estimate_scratch_[i];
      s_.estimate_wear_um[i] = kf.state()(0);
      s_.estimate_rate_um_per_mm[i] = kf.state()(1);
      s_.estimate_p_ww[i] = kf.covariance()(0, 0);
      s_.estimate_p_wr[i] = kf.covariance()(0, 1);
      s_.estimate_p_rr[i] = kf.covariance()(1, 1);
      // The prediction and the adaptive interval use the estimated rate (wear does not heal).
      s_.rate_um_per_mm[i] = std::max(0.0, kf.state()(1));
    }
    s_.estimate_path_mm = s_.cut_path_mm;
    s_.estimate_valid = true;
    s_.rate_known = true;
    adapt_rate_noise();
    update_uncertainty_interval();
    check_noise(now_ns, out);
  } else {
    s_.estimate_valid = false;  // switched on later: starts from the measured state
  }

  start_creep(delta, moving, out, now_ns);
  if (config_.entry.retract_um > 0.0) {
    start_entry(config_.entry.retract_um, config_.entry.refeed_length_mm);
  }
  if (tl.wear_limit_um > 0.0 && max_wear >= tl.wear_limit_um) {
    s_.tool_change_flag = true;
    out.alarm(now_ns, Severity::kWarning, AlarmCode::kToolLifeReached, s_.tool, max_wear);
  }
}

void WearCompensator::adapt_rate_noise() noexcept {
  const auto& e = config_.estimator;
  if (!e.adapt_rate_noise || points_ == 0) return;
  double nis = 0.0;
  double prior_fraction = 0.0;
  for (std::size_t i = 0; i < points_; ++i) {
    nis += nis_scratch_[i];
    prior_fraction += prior_fraction_scratch_[i];
  }
  const double n = static_cast<double>(points_);
  estimation::NoiseAdaptation a;
  a.window = e.adapt_window_measurements;
  // The keys are per sqrt(m), the filter's clock is mm.
  a.q_min = e.min_rate_noise_um_per_mm_per_sqrt_m * e.min_rate_noise_um_per_mm_per_sqrt_m / 1000.0;
  a.q_max = e.max_rate_noise_um_per_mm_per_sqrt_m * e.max_rate_noise_um_per_mm_per_sqrt_m / 1000.0;
  s_.rate_q = estimation::adapt_process_noise(rate_q(), nis / n, prior_fraction / n, a);
}

void WearCompensator::check_noise(TimeNs now_ns, StepOutput& out) noexcept {
  ++s_.nis_count;
  for (std::size_t i = 0; i < points_; ++i) {
    s_.nis_sum[i] += nis_scratch_[i];
    s_.residual_var_sum_um2[i] += residual_scratch_[i];
  }
  const std::uint32_t n = s_.nis_count;
  if (s_.noise_warned || n < kNisMinCount) return;
  // With the right σ and process noise each ν²/S is χ²(1): mean 1, variance 2, so the mean of n
  // has the standard deviation sqrt(2/n). Beyond 3 of them the configured noise is wrong.
  const double band = 3.0 * std::sqrt(2.0 / static_cast<double>(n));
  double worst = 1.0;
  for (std::size_t i = 0; i < points_; ++i) {
    const double m = s_.nis_sum[i] / static_cast<double>(n);
    if (std::fabs(m - 1.0) > std::fabs(worst - 1.0)) worst = m;
  }
  if (std::fabs(worst - 1.0) > band) {
    s_.noise_warned = true;
    out.alarm(now_ns, Severity::kWarning, AlarmCode::kMeasurementNoiseInconsistent, s_.tool, worst);
  }
}

void WearCompensator::fit_rates() noexcept {
  const std::size_t window = config_.predict.enabled ? config_.predict.window : 2;
  std::size_t n = std::min<std::size_t>(window, s_.history_count);
  std::size_t first = s_.history_count - n;
  // The new tool's origin (zero wear at zero path) stands in only until two real measurements
  // exist: break-in wear is fastest at the start, so a secant from the origin over-predicts.
  if (first == 0 && s_.history_has_origin && s_.history_count >= 3) {
    first = 1;
    --n;
  }
  double mean_x = 0.0;
  for (std::size_t h = first; h < s_.history_count; ++h) mean_x += s_.history[h].cut_path_mm;
  mean_x /= static_cast<double>(n);
  double sxx = 0.0;
  for (std::size_t h = first; h < s_.history_count; ++h) {
    const double dx = s_.history[h].cut_path_mm - mean_x;
    sxx += dx * dx;
  }
  if (n < 2 || !(sxx > 1e-12)) {
    s_.rate_known = false;
    return;
  }
  for (std::size_t i = 0; i < points_; ++i) {
    double mean_y = 0.0;
    for (std::size_t h = first; h < s_.history_count; ++h) mean_y += s_.history[h].wear_um[i];
    mean_y /= static_cast<double>(n);
    double sxy = 0.0;
    for (std::size_t h = first; h < s_.history_count; ++h) {
      sxy += (s_.history[h].cut_path_mm - mean_x) * (s_.history[h].wear_um[i] - mean_y);
    }
    // Wear does not heal: a negative fitted rate is noise.
    s_.rate_um_per_mm[i] = std::max(0.0, sxy / sxx);
  }
  s_.rate_known = true;
}

double WearCompensator::interval_path_mm() const noexcept {
  const auto& iv = config_.interval;
  switch (iv.basis) {
    case IntervalBasis::kPath:
      return iv.interval_mm;
    case IntervalBasis::kMaterial:
      if (iv.removal_source == RemovalSource::kConstant) {
        return iv.interval_mm3 / iv.removal_mm3_per_mm;
      }
      break;  // depends on where the program goes
    case IntervalBasis::kAdaptive: {
      double max_rate = 0.0;
      if (s_.rate_known) {
        for (std::size_t i = 0; i < points_; ++i) {
          max_rate = std::max(max_rate, s_.rate_um_per_mm[i]);
        }
      }
      // Before a rate is known (new tool, break-in wear is fastest) measure at the minimum.
      if (!s_.rate_known) return iv.min_interval_mm;
      if (!(max_rate > 0.0)) return iv.max_interval_mm;
      return std::clamp(iv.target_increment_um / max_rate, iv.min_interval_mm, iv.max_interval_mm);
    }
    case IntervalBasis::kUncertainty:
      return uncertainty_interval_mm_;
    case IntervalBasis::kOff:
    case IntervalBasis::kTime:
      break;
  }
  return std::numeric_limits<double>::infinity();
}

void WearCompensator::update_uncertainty_interval() noexcept {
  const auto& iv = config_.interval;
  if (iv.basis != IntervalBasis::kUncertainty) return;
  // Path since the last measurement at which some support point's σ exceeds max_sigma_um. The
  // variance grows monotonically with the path (a cubic): bisect within the limits.
  const auto too_uncertain = [&](double since_mm) {
    for (std::size_t i = 0; i < points_; ++i) {
      double from_mm = 0.0;
      auto kf = estimator_at(i, from_mm);
      const double d = std::max(0.0, s_.last_measurement_cut_path_mm + since_mm - from_mm);
      kf.predict(estimation::cv_transition(d), estimator_noise(d));
      if (std::sqrt(std::max(0.0, kf.covariance()(0, 0))) > iv.max_sigma_um) return true;
    }
    return false;
  };
  double lo = iv.min_interval_mm;
  double hi = iv.max_interval_mm;
  if (too_uncertain(lo)) {
    uncertainty_interval_mm_ = lo;
    return;
  }
  if (!too_uncertain(hi)) {
    uncertainty_interval_mm_ = hi;
    return;
  }
  for (int it = 0; it < 40; ++it) {  // 2^-40 of the span: far below a path sample
    const double mid = 0.5 * (lo + hi);
    (too_uncertain(mid) ? hi : lo) = mid;
  }
  uncertainty_interval_mm_ = hi;
}

double WearCompensator::next_measurement_path_mm() const noexcept {
  if (s_.halted) return std::numeric_limits<double>::infinity();
  const double len = interval_path_mm();
  const double next = s_.last_measurement_cut_path_mm + len;
  return s_.request_held ? std::max(next, s_.refused_cut_path_mm + len) : next;
}

double WearCompensator::next_measurement_removed_mm3() const noexcept {
  if (config_.interval.basis != IntervalBasis::kMaterial || s_.halted) {
    return std::numeric_limits<double>::infinity();
  }
  const double len = config_.interval.interval_mm3;
  const double next = s_.last_measurement_removed_mm3 + len;
  return s_.request_held ? std::max(next, s_.refused_removed_mm3 + len) : next;
}

void WearCompensator::check_measurement_due(TimeNs now_ns, StepOutput& out) noexcept {
  const auto& iv = config_.interval;
  // Halted: a measurement now would be refused; the operator or a tool change comes first.
  if (iv.basis == IntervalBasis::kOff || s_.measurement_due_flag || s_.halted) return;
  bool due = false;
  if (iv.basis == IntervalBasis::kTime) {
    due = s_.cut_time_s - s_.last_measurement_cut_time_s >= iv.interval_s &&
          (!s_.request_held || s_.cut_time_s - s_.refused_cut_time_s >= iv.interval_s);
  } else if (iv.basis == IntervalBasis::kMaterial) {
    // A hair of tolerance: the volume is a sum of many products.
    due = s_.removed_mm3 >= next_measurement_removed_mm3() - 1e-9 * iv.interval_mm3;
  } else {
    due = s_.cut_path_mm >= next_measurement_path_mm();
  }
  if (due) {
    s_.measurement_due_flag = true;
    out.alarm(now_ns, Severity::kInfo, AlarmCode::kMeasurementDue, s_.tool,
              s_.cut_path_mm - s_.last_measurement_cut_path_mm);
  }
}

double WearCompensator::restart_program_path_mm() const noexcept {
  const double p = s_.last_measurement_program_path_mm;
  if (!std::isfinite(p)) return kNaN;
  return std::max(0.0, p - config_.entry.sister_restart_back_mm);
}

void WearCompensator::on_tool_change(TimeNs /*now_ns*/, const ToolChange& c,
                                     StepOutput& /*out*/) noexcept {
  const bool new_tool = c.tool != s_.tool || c.sister;
  if (new_tool && s_.tool == 0 && adoption_active()) {
    // The first tool named after a start without state: the NC's offsets (and the wear baseline
    // read from them) are this tool's, as with the first axis sample naming it.
    s_.tool = c.tool;
    select_tool_tables();
    return;
  }
  if (new_tool) {
    // Another tool: what was adopted belonged to the one before (remembered with its state).
    adopted_ = AdoptedOutputs{};
    fade_pending_ = false;
  }
  if (!new_tool) {
    // The same tool back in the spindle (e.g. after a measurement outside the machine).
    if (config_.entry.retract_um > 0.0) {
      start_entry(config_.entry.retract_um, config_.entry.refeed_length_mm);
    }
    return;
  }
  // Kept across the change: where a sister restarts, and what the NC holds now.
  const double restart_mm = s_.last_measurement_program_path_mm;
  const auto held_um = s_.channel_output_um;
  // The surface does not change with the tool: the new one starts with the last normal known.
  const auto held_normal = s_.held_normal;
  const bool normal_held = s_.normal_held;
  const std::uint64_t seq = s_.next_seq;
  // The family outlives its tools; a tool replaced by its sister is finished and adds its
  // estimate of the rate's process noise.
  FamilyNoise family = s_.family;
  FamilyRate family_rate = s_.family_rate;
  if (c.sister && s_.tool != 0 && config_.estimator.enabled) {
    const double q = finished_tool_rate_q(s_);
    if (std::isfinite(q)) {
      ++family.tools;
      family.rate_q_sum += q;
    }
    if (s_.start_sxx > 0.0) {
      // Welford's update of the start rates' mean and sum of squared deviations.
      ++family_rate.tools;
      const double n = static_cast<double>(family_rate.tools);
      for (std::size_t i = 0; i < points_; ++i) {
        const double r = s_.start_sxw[i] / s_.start_sxx;
        const double d = r - family_rate.rate_mean_um_per_mm[i];
        family_rate.rate_mean_um_per_mm[i] += d / n;
        family_rate.rate_m2[i] += d * (r - family_rate.rate_mean_um_per_mm[i]);
      }
    }
  }
  if (s_.tool != 0) {
    // The outgoing tool: remembered until it comes back, forgotten when a sister replaces it.
    std::size_t slot = kMaxToolMemory;
    for (std::size_t k = 0; k < kMaxToolMemory && slot == kMaxToolMemory; ++k) {
      if (memory_.tool[k] == s_.tool) slot = k;
    }
    if (c.sister) {
      if (slot < kMaxToolMemory) memory_.tool[slot] = 0;
    } else {
      for (std::size_t k = 0; k < kMaxToolMemory && slot == kMaxToolMemory; ++k) {
        if (memory_.tool[k] == 0) slot = k;
      }
      if (slot == kMaxToolMemory) {
        slot = 0;
        for (std::size_t k = 1; k < kMaxToolMemory; ++k) {
          if (memory_.last_use[k] < memory_.last_use[slot]) slot = k;
        }
      }
      memory_.tool[slot] = s_.tool;
      memory_.last_use[slot] = ++memory_.use_counter;
      memory_.state[slot] = s_;
    }
  }
  bool restored = false;
  if (!c.sister) {
    for (std::size_t k = 0; k < kMaxToolMemory && !restored; ++k) {
      if (memory_.tool[k] == c.tool && c.tool != 0) {
        s_ = memory_.state[k];
        memory_.tool[k] = 0;
        restored = true;
      }
    }
  }
  if (!restored) {
    CreepState fresh{};
    fresh.edge_points = s_.edge_points;
    fresh.tool = c.tool;
    fresh.part = s_.part;
    fresh.history_count = 1;
    fresh.history_has_origin = true;
    fresh.last_measurement_program_path_mm = restart_mm;
    s_ = fresh;
  }
  s_.family = family;
  s_.family_rate = family_rate;
  if (!restored) {
    // A new tool's filter runs with the family's process noise and rate prior once enough tools
    // are finished.
    const auto& e = config_.estimator;
    s_.rate_q = e.learn_rate_noise && family.tools >= e.family_min_tools ? family_rate_q() : kNaN;
    if (e.learn_rate_prior && family_rate.tools >= e.family_min_tools) {
      for (std::size_t i = 0; i < points_; ++i) {
        double mean = 0.0;
        double sigma = 0.0;
        if (family_rate_prior(i, mean, sigma)) {
          s_.rate_prior_um_per_mm[i] = mean;
          s_.rate_prior_sigma_um_per_mm[i] = sigma;
        }
      }
    }
  }
  s_.channel_output_um = held_um;
  s_.held_normal = held_normal;
  s_.normal_held = normal_held;
  s_.next_seq = std::max(s_.next_seq, seq);
  select_tool_tables();
  if (c.sister && config_.entry.sister_offset_um > 0.0) {
    start_entry(config_.entry.sister_offset_um, config_.entry.sister_length_mm);
  } else if (config_.entry.retract_um > 0.0) {
    start_entry(config_.entry.retract_um, config_.entry.refeed_length_mm);
  }
}

bool WearCompensator::restore_tool_memory(const ToolMemory& memory) noexcept {
  for (std::size_t k = 0; k < kMaxToolMemory; ++k) {
    if (memory.tool[k] == 0) continue;
    if (memory.tool[k] < 0 || memory.state[k].tool != memory.tool[k]) return false;
    if (check_state(memory.state[k]).field != nullptr) return false;
    for (std::size_t j = 0; j < k; ++j) {
      if (memory.tool[j] == memory.tool[k]) return false;
    }
  }
  memory_ = memory;
  return true;
}

}  // namespace nccomp::core::creep
