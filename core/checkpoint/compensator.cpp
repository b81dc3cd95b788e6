#include "core/checkpoint/compensator.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>
#include <string>
#include <utility>

#include "core/checkpoint/probe.hpp"
#include "core/common/config_issue.hpp"
#include "core/engine/engine.hpp"
#include "core/estimation/kalman.hpp"

namespace nccomp::core::checkpoint {

namespace {

[[noreturn]] void fail(const std::string& key, const std::string& reason) {
  throw ConfigInvalid("checkpoints." + key, reason);
}

std::string num(double v) {
  std::ostringstream s;
  s << v;
  return s.str();
}

void require_range(ConfigIssues& issues, double v, double lo, double hi, bool lo_open,
                   const std::string& key) {
  const bool ok = std::isfinite(v) && (lo_open ? v > lo : v >= lo) && v <= hi;
  if (!ok) {
    issues.add("checkpoints." + key, std::string("must be in ") + (lo_open ? "(" : "[") + num(lo) +
                                         ", " + num(hi) + "], got " + num(v));
  }
}

constexpr double kHuge = 1e300;
// A reading's α may differ from the plan's by the bus encoding's resolution (0.01° in the
// reference profiles), not more.
constexpr double kAlphaToleranceDeg = 0.02;

// The part noise of a random walk read with noise σ, from the history e_1..e_n of accepted
// readings: each difference Δ = e_k − e_{k−1} = w + v_k − v_{k−1} has E[Δ²] = q + 2σ², so
// q = mean(Δ²) − 2σ² is unbiased; a negative estimate (the parts vary less than the probe) is 0.
double learned_part_noise_um2(const LearnedPoint& p, double sigma_um) noexcept {
  if (p.history_n < 2) return 0.0;
  double sum2 = 0.0;
  for (std::uint32_t k = 1; k < p.history_n; ++k) {
    const double d = p.history[k] - p.history[k - 1];
    sum2 += d * d;
  }
  return std::max(0.0, sum2 / static_cast<double>(p.history_n - 1) - 2.0 * sigma_um * sigma_um);
}

}  // namespace

const char* learning_mode_name(LearningMode m) noexcept {
  return m == LearningMode::kPreviousPart ? "previous_part" : "semi_finishing";
}
const char* apply_mode_name(ApplyMode m) noexcept {
  switch (m) {
    case ApplyMode::kStep:
      return "step";
    case ApplyMode::kCreep:
      return "creep";
    case ApplyMode::kTable:
      return "table";
  }
  return "?";
}
const char* trigger_mode_name(TriggerMode m) noexcept {
  return m == TriggerMode::kPath ? "path" : "position";
}

void CheckpointCompensator::configure(const CompensatorConfig& c, std::vector<Checkpoint> plan,
                                      const LimiterConfig& limits) {
  ConfigIssues issues;
  require_range(issues, c.ewma_weight, 1.0, 1e6, false, "ewma_weight");
  require_range(issues, c.dead_band_um, 0.0, kHuge, false, "dead_band_um");
  require_range(issues, c.feedback, 0.0, 1.0, true, "feedback");
  require_range(issues, c.plausible_um, 0.0, kHuge, true, "plausible_um");
  require_range(issues, c.outlier_sigma, 0.0, kHuge, true, "outlier_sigma");
  if (c.outlier_min_history < 2 || c.outlier_min_history > kHistoryDepth) {
    issues.add("checkpoints.outlier_min_history", "must be in [2, " +
                                                      std::to_string(kHistoryDepth) + "], got " +
                                                      std::to_string(c.outlier_min_history));
  }
  require_range(issues, c.probe_repeatability_um, 0.0, kHuge, false, "probe_repeatability_um");
  require_range(issues, c.write_threshold_um, 0.0, kHuge, false, "write_threshold_um");
  require_range(issues, c.reconcile_tolerance_um, 0.0, kHuge, false, "reconcile_tolerance_um");
  require_range(issues, c.xy_tolerance_mm, 0.0, kHuge, true, "xy_tolerance_mm");
  require_range(issues, c.z_band_mm, 0.0, kHuge, true, "z_band_mm");
  const CheckpointEstimatorConfig& est = c.estimator;
  require_range(issues, est.measurement_sigma_um, 0.0, 1e3, true, "estimator.measurement_sigma_um");
  require_range(issues, est.part_noise_um, 0.0, 1e3, false, "estimator.part_noise_um");
  if (est.learn_min_parts < 3 || est.learn_min_parts > kHistoryDepth) {
    issues.add("checkpoints.estimator.learn_min_parts",
               "must be in [3, " + std::to_string(kHistoryDepth) + "], got " +
                   std::to_string(est.learn_min_parts));
  }
  if (!std::isfinite(est.gate_sigmas) || est.gate_sigmas < 0.0 ||
      (est.gate_sigmas > 0.0 && est.gate_sigmas < 2.0)) {
    issues.add("checkpoints.estimator.gate_sigmas",
               "must be 0 (no gate) or at least 2, got " + num(est.gate_sigmas));
  }
  if (est.enabled && c.learning_mode == LearningMode::kSemiFinishing) {
    issues.add(
        "checkpoints.estimator.enabled",
        "not used with learning_mode = \"semi_finishing\": mode B applies each blank's own "
        "reading, there is nothing to estimate across blanks; remove [checkpoints.estimator] "
        "or set enabled = false");
  }
  if (c.creep_shape == ProfileShape::kTable) {
    issues.add("checkpoints.creep_shape",
               "\"table\" is not available for checkpoints; use linear, cosine or "
               "smoothstep");
  }
  if (plan.empty() || plan.size() > kMaxCheckpoints) {
    issues.add("checkpoints.plan", "needs 1 to " + std::to_string(kMaxCheckpoints) +
                                       " checkpoints, got " + std::to_string(plan.size()));
  }
  const std::size_t last_register = c.register_base + std::max<std::size_t>(plan.size(), 1) - 1;
  if (last_register > 0xFFFF) {
    issues.add("checkpoints.register_base", std::to_string(c.register_base) + " + " +
                                                std::to_string(plan.size()) +
                                                " checkpoints exceeds the register range 0..65535");
  }
  if (c.active_register < -1 || c.active_register > 0xFFFF) {
    issues.add("checkpoints.active_register",
               "must be -1 (table only) or 0..65535, got " + std::to_string(c.active_register));
  }
  if (!plan.empty() && c.active_register >= c.register_base &&
      static_cast<std::size_t>(c.active_register) <= last_register) {
    issues.add("checkpoints.active_register",
               std::to_string(c.active_register) + " lies inside the checkpoint table (registers " +
                   std::to_string(c.register_base) + ".." + std::to_string(last_register) + ")");
  }
  if (c.apply != ApplyMode::kStep && c.apply != ApplyMode::kCreep && c.apply != ApplyMode::kTable) {
    issues.add("checkpoints.apply", "unknown apply mode");
  }
  // A live apply mode without a live register would do nothing at all, silently: the NC would
  // switch offset numbers at the checkpoints (a step) while the config says "creep".
  if (c.apply != ApplyMode::kTable && c.active_register < 0) {
    issues.add("checkpoints.apply",
               std::string("\"") + apply_mode_name(c.apply) +
                   "\" drives the live radius wear register, but active_register = -1 "
                   "(table only: the NC program selects each checkpoint's offset itself, a "
                   "step at every checkpoint, and nothing creeps); set active_register to "
                   "the finishing tool's radius wear register, or apply = \"table\"");
  }
  if (c.apply == ApplyMode::kTable && c.active_register >= 0) {
    issues.add("checkpoints.apply",
               "\"table\" writes no live register, but active_register = " +
                   std::to_string(c.active_register) +
                   " is set; use apply = \"creep\" or \"step\", or active_register = -1");
  }
  issues.throw_if_any();
  for (std::size_t i = 0; i < plan.size(); ++i) {
    const Checkpoint& p = plan[i];
    if (p.id != static_cast<std::int32_t>(i)) {
      fail("plan", "checkpoint " + std::to_string(i) + " has id " + std::to_string(p.id) +
                       " (ids must be the machining order 0, 1, 2, ...)");
    }
    if (!std::isfinite(p.path_mm) || !std::isfinite(p.tool_x_mm) || !std::isfinite(p.tool_y_mm) ||
        !std::isfinite(p.z_mm)) {
      fail("plan", "checkpoint " + std::to_string(i) + " has a non-finite position");
    }
    if (i > 0 && !(p.path_mm > plan[i - 1].path_mm)) {
      fail("plan", "checkpoint " + std::to_string(i) + " path_mm " + num(p.path_mm) +
                       " does not increase (machining order)");
    }
    if (!std::isfinite(p.s_mm) || !std::isfinite(p.pass_length_mm) || p.pass_length_mm < 0.0 ||
        p.s_mm < 0.0 || (p.pass_length_mm > 0.0 && p.s_mm > p.pass_length_mm) ||
        (p.closed && !(p.s_mm < p.pass_length_mm))) {
      fail("plan", "checkpoint " + std::to_string(i) + ": s_mm " + num(p.s_mm) +
                       " does not lie on its level's pass of " + num(p.pass_length_mm) + " mm" +
                       (p.closed ? " (closed: 0 <= s_mm < length)" : ""));
    }
    const bool new_level = i == 0 || p.level != plan[i - 1].level;
    if (i == 0 ? p.level != 0 : (new_level && p.level != plan[i - 1].level + 1)) {
      fail("plan", "checkpoint " + std::to_string(i) + " has level " + std::to_string(p.level) +
                       " (levels must be 0, 1, 2, ... in machining order)");
    }
    if (!new_level) {
      const Checkpoint& q = plan[i - 1];
      const double start_p = p.path_mm - p.s_mm;
      const double start_q = q.path_mm - q.s_mm;
      if (!(p.s_mm > q.s_mm) || p.closed != q.closed ||
          std::fabs(p.pass_length_mm - q.pass_length_mm) > 0.0 ||
          std::fabs(start_p - start_q) > 1e-6 + 1e-12 * std::fabs(p.path_mm) ||
          std::fabs(p.z_mm - q.z_mm) > 0.0) {
        fail("plan", "checkpoint " + std::to_string(i) +
                         " does not continue its level's pass (s_mm must increase along the "
                         "pass, path_mm - s_mm, z_mm, pass_length_mm and closed must agree)");
      }
    } else if (i > 0) {
      const Checkpoint& q = plan[i - 1];
      const double prev_end = q.path_mm - q.s_mm + q.pass_length_mm;
      if (p.path_mm - p.s_mm < prev_end - 1e-6 - 1e-12 * std::fabs(p.path_mm)) {
        fail("plan", "level " + std::to_string(p.level) + " starts on the program path at " +
                         num(p.path_mm - p.s_mm) + " mm, before level " + std::to_string(q.level) +
                         "'s pass ends (" + num(prev_end) + " mm)");
      }
    }
    if (!std::isfinite(p.alpha_deg) || std::fabs(p.alpha_deg) >= kMaxWallAngleDeg) {
      fail("plan", "checkpoint " + std::to_string(i) + " has a wall angle of " + num(p.alpha_deg) +
                       " deg (|alpha| < 89)");
    }
  }
  OffsetLimiter limiter;
  limiter.configure(limits);  // throws naming the limiter field

  // Commit only after everything validated: a refused config leaves the old one intact.
  std::vector<Level> levels;
  for (std::size_t i = 0; i < plan.size(); ++i) {
    const Checkpoint& p = plan[i];
    if (i == 0 || p.level != plan[i - 1].level) {
      levels.push_back(Level{i, i, p.path_mm - p.s_mm, p.pass_length_mm, p.closed, p.z_mm});
    }
    levels.back().last = i;
  }
  config_ = c;
  plan_ = std::move(plan);
  levels_ = std::move(levels);
  points_.assign(plan_.size(), LearnedPoint{});
  dirty_.assign(plan_.size(), 0);
  dirty_count_ = 0;
  dirty_cursor_ = 0;
  limiter_ = limiter;
  limiter_.reset(0.0, 0);
  part_counter_ = 0;
  part_ = 0;
  tool_ = 0;
  next_ = 0;
  have_prev_ = false;
  travel_since_mm_ = 0.0;
  band_level_ = kNone;
  travel_in_band_mm_ = 0.0;
  focus_ = -1;
  live_target_um_ = kNaN;
  awaiting_finish_ = false;
  live_written_um_ = kNaN;
  pending_mismatch_ = 0;
  generation_ = 0;
  counters_ = {};
}

double CheckpointCompensator::register_value_um(std::size_t i) const noexcept {
  const double c = points_[i].offset_um;
  // An offset the probe cannot resolve would only move the wall by noise.
  return std::fabs(c) < config_.probe_repeatability_um ? 0.0 : c;
}

void CheckpointCompensator::mark_dirty(std::size_t i) noexcept {
  if (dirty_[i] == 0) {
    dirty_[i] = 1;
    ++dirty_count_;
  }
}

void CheckpointCompensator::step(TimeNs now_ns, std::span<const Event> events,
                                 StepOutput& out) noexcept {
  if (plan_.empty()) {
    return;
  }
  if (pending_mismatch_ > 0) {
    out.alarm(now_ns, Severity::kWarning, AlarmCode::kCheckpointRegisterMismatch,
              static_cast<std::int32_t>(pending_mismatch_), 0.0);
    pending_mismatch_ = 0;
  }
  for (const Event& ev : events) {
    if (const auto* s = std::get_if<AxisSample>(&ev)) {
      on_sample(*s, out);
    } else if (const auto* m = std::get_if<ProbeMeasurement>(&ev)) {
      on_probe(*m, out);
    } else if (const auto* p = std::get_if<ProgramEvent>(&ev)) {
      if (p->kind == ProgramEventKind::kPartStart) {
        on_part_start(p->time_ns, *p);
      }
    } else if (const auto* t = std::get_if<ToolChange>(&ev)) {
      tool_ = t->tool;
      have_prev_ = false;
    }
  }
  flush_table(now_ns, out);
  preposition(now_ns, out);
}

void CheckpointCompensator::preposition(TimeNs now_ns, StepOutput& out) noexcept {
  // Between part start and the finishing tool's first sample the live register is brought to
  // the first checkpoint's value, so a rate-limited register is there before the tool cuts.
  if (config_.active_register < 0 || !awaiting_finish_) {
    return;
  }
  write_live(start_value_um(), now_ns, out);
}

void CheckpointCompensator::write_live(double target_um, TimeNs now_ns, StepOutput& out) noexcept {
  live_target_um_ = target_um;
  if (std::isfinite(live_written_um_) &&
      std::fabs(target_um - live_written_um_) < config_.write_threshold_um) {
    return;
  }
  const LimitResult r = limiter_.apply(target_um, now_ns);
  const auto reg = static_cast<std::uint16_t>(config_.active_register);
  if (r.rejected()) {
    out.alarm(now_ns, Severity::kAlarm, AlarmCode::kOffsetBeyondAbsoluteLimit, reg, target_um);
    return;
  }
  if (std::isfinite(live_written_um_) && !(std::fabs(r.value_um - live_written_um_) > 0.0)) {
    return;  // the rate limit allowed no movement in this interval: nothing new to send
  }
  out.writes.push(OffsetWrite{now_ns, reg, r.value_um});
  live_written_um_ = r.value_um;
  ++counters_.live_writes;
}

void CheckpointCompensator::on_part_start(TimeNs /*now_ns*/, const ProgramEvent& ev) noexcept {
  part_ = ev.part;
  ++part_counter_;
  ++generation_;
  for (std::size_t i = 0; i < plan_.size(); ++i) {
    points_[i].applied_um = register_value_um(i);
    mark_dirty(i);  // every learned value is written at part start
  }
  next_ = 0;
  have_prev_ = false;
  travel_since_mm_ = 0.0;
  band_level_ = kNone;
  travel_in_band_mm_ = 0.0;
  live_target_um_ = kNaN;
  awaiting_finish_ = true;
}

void CheckpointCompensator::flush_table(TimeNs now_ns, StepOutput& out) noexcept {
  std::size_t written = 0;
  std::size_t scanned = 0;
  while (dirty_count_ > 0 && written < kTableWritesPerStep && scanned < plan_.size() &&
         out.writes.size() < out.writes.capacity()) {
    const std::size_t i = dirty_cursor_;
    dirty_cursor_ = (dirty_cursor_ + 1) % plan_.size();
    ++scanned;
    if (dirty_[i] == 0) {
      continue;
    }
    const auto reg = static_cast<std::uint16_t>(config_.register_base + i);
    out.writes.push(OffsetWrite{now_ns, reg, register_value_um(i)});
    dirty_[i] = 0;
    --dirty_count_;
    ++written;
    ++counters_.table_writes;
  }
}

void CheckpointCompensator::on_probe(const ProbeMeasurement& m, StepOutput& out) noexcept {
  ++counters_.measurements;
  if (m.fault != InputFault::kNone) {
    // The NC reported a reading whose values did not arrive intact: nothing to learn from.
    ++counters_.invalid;
    out.alarm(m.time_ns, Severity::kAlarm, AlarmCode::kProbeInvalidInput, m.checkpoint, kNaN);
    return;
  }
  if (m.checkpoint < 0 || static_cast<std::size_t>(m.checkpoint) >= plan_.size()) {
    ++counters_.invalid;
    out.alarm(m.time_ns, Severity::kAlarm, AlarmCode::kProbeInvalidInput, m.checkpoint,
              m.raw_deviation_um);
    return;
  }
  const auto i = static_cast<std::size_t>(m.checkpoint);
  // The reading is checked as it came (α, r, δ), then corrected with the plan's α of this
  // checkpoint: the probing program passed exactly that α to the macro, so a reading with
  // another α belongs to another wall or comes from a stale program, and is not learned.
  const ProbeCorrection as_read =
      correct_probe(m.raw_deviation_um, m.wall_angle_deg, m.ball_radius_mm);
  if (as_read.status != ProbeStatus::kOk ||
      std::fabs(m.wall_angle_deg - plan_[i].alpha_deg) > kAlphaToleranceDeg) {
    ++counters_.invalid;
    out.alarm(m.time_ns, Severity::kAlarm, AlarmCode::kProbeInvalidInput, m.checkpoint,
              m.raw_deviation_um);
    return;
  }
  const ProbeCorrection corr =
      correct_probe(m.raw_deviation_um, plan_[i].alpha_deg, m.ball_radius_mm);
  focus_ = m.checkpoint;
  const bool mode_a = config_.learning_mode == LearningMode::kPreviousPart;
  // Mode B probes the semi-finished wall, which was cut without per-checkpoint offsets.
  const double applied = mode_a ? points_[i].applied_um : 0.0;
  MeasurementRecord rec;
  rec.time_ns = m.time_ns;
  rec.part = m.part;
  rec.tool = mode_a ? config_.finishing_tool : config_.semi_finishing_tool;
  rec.kind = MeasurementKind::kContour;
  rec.point = m.checkpoint;
  rec.position_mm = m.position_mm;
  rec.angle_deg = plan_[i].alpha_deg;
  rec.measured_um = corr.corrected_um;
  // The log's convention (core/model's Dataset::target_um): measured_um + applied_um is the error
  // the machine made before compensation. The offset c cancelled −c of the error.
  rec.applied_um = 0.0 - applied;  // not -applied: no "-0" in the log
  out.records.push(rec);           // logged whatever is decided below: outliers are data too

  if (std::fabs(corr.corrected_um) > config_.plausible_um) {
    ++counters_.implausible;
    out.alarm(m.time_ns, Severity::kAlarm, AlarmCode::kProbeImplausible, m.checkpoint,
              corr.corrected_um);
    return;
  }
  const double e = corr.corrected_um - applied;
  LearnedPoint& p = points_[i];
  const CheckpointEstimatorConfig& est = config_.estimator;
  const bool filtered = est.enabled && mode_a;
  double variance = p.variance_um2;
  double filter_estimate = e;
  if (filtered && p.count > 0) {
    // One step of the random walk per part, then the reading; the gate replaces the history's
    // outlier rule (both are k·σ tests, the filter's knows the part noise).
    const double r = est.measurement_sigma_um * est.measurement_sigma_um;
    estimation::KalmanFilter<1> kf;
    kf.reset(estimation::KalmanFilter<1>::Vector::Constant(p.learned_um),
             estimation::KalmanFilter<1>::Matrix::Constant(p.filter_n > 0 ? p.variance_um2 : r));
    kf.predict(estimation::KalmanFilter<1>::Matrix::Identity(),
               estimation::KalmanFilter<1>::Matrix::Constant(part_noise_var_um2(i)));
    const estimation::UpdateResult u =
        kf.update(estimation::KalmanFilter<1>::Row::Ones(), e, r, est.gate_sigmas);
    if (!u.accepted) {
      ++counters_.outliers;
      out.alarm(m.time_ns, Severity::kWarning, AlarmCode::kProbeOutlier, m.checkpoint, e);
      return;
    }
    filter_estimate = kf.state()(0);
    variance = kf.covariance()(0, 0);
  } else if (filtered) {
    variance = est.measurement_sigma_um * est.measurement_sigma_um;  // the first reading
  }
  if (!filtered && p.history_n >= config_.outlier_min_history) {
    double mean = 0.0;
    for (std::uint32_t k = 0; k < p.history_n; ++k) mean += p.history[k];
    mean /= static_cast<double>(p.history_n);
    double var = 0.0;
    for (std::uint32_t k = 0; k < p.history_n; ++k) {
      var += (p.history[k] - mean) * (p.history[k] - mean);
    }
    const double sigma = std::sqrt(var / static_cast<double>(p.history_n - 1));
    // A perfectly repeating history would make every new reading an outlier: floor σ at what
    // the probe can resolve.
    const double sigma_eff = std::max(sigma, config_.probe_repeatability_um);
    if (std::fabs(e - mean) > config_.outlier_sigma * sigma_eff) {
      ++counters_.outliers;
      out.alarm(m.time_ns, Severity::kWarning, AlarmCode::kProbeOutlier, m.checkpoint, e);
      return;
    }
  }
  // Mode B applies this blank's own semi-finishing error: an average over earlier blanks would
  // blend their hardness into this one's offsets, which is what mode B is there to avoid.
  const double learned = filtered ? filter_estimate
                         : (!mode_a || p.count == 0)
                             ? e
                             : p.learned_um + (e - p.learned_um) / config_.ewma_weight;
  const double target = -learned;
  const double candidate =
      mode_a ? p.offset_um + config_.feedback * (target - p.offset_um) : config_.feedback * target;
  const bool in_dead_band = std::fabs(candidate - p.offset_um) < config_.dead_band_um;
  if (!in_dead_band && !limiter_.admissible(candidate)) {
    ++counters_.beyond_limit;
    out.alarm(m.time_ns, Severity::kAlarm, AlarmCode::kOffsetBeyondAbsoluteLimit,
              static_cast<std::int32_t>(config_.register_base + i), candidate);
    return;  // nothing changes: a broken wall is reported, not compensated
  }
  p.learned_um = learned;
  ++p.count;
  // Without the estimator the filter does not follow: switched on later, it starts from M.
  p.variance_um2 = filtered ? variance : 0.0;
  p.filter_n = filtered ? p.filter_n + 1 : 0;
  ++generation_;
  if (p.history_n < kHistoryDepth) {
    p.history[p.history_n++] = e;
  } else {
    std::rotate(p.history.begin(), p.history.begin() + 1, p.history.end());
    p.history[kHistoryDepth - 1] = e;
  }
  if (in_dead_band) {
    ++counters_.dead_band_skips;
    return;
  }
  p.offset_um = candidate;
  ++counters_.updates;
  if (!mode_a) {
    mark_dirty(i);  // mode B: the finishing of this very part needs it
  }
}

bool CheckpointCompensator::passes(std::size_t i, const AxisSample& s) const noexcept {
  const Checkpoint& c = plan_[i];
  const double x0 = prev_.position_mm[0];
  const double y0 = prev_.position_mm[1];
  const double z0 = prev_.position_mm[2];
  const double dx = s.position_mm[0] - x0;
  const double dy = s.position_mm[1] - y0;
  const double dz = s.position_mm[2] - z0;
  const double len2 = dx * dx + dy * dy;
  if (!(len2 > 1e-18)) {
    return false;  // no XY motion: nothing passed
  }
  // The foot of the perpendicular from the checkpoint onto this motion: the tool passes the
  // checkpoint between the two samples when it lies in (0, 1], whatever the sample spacing.
  const double t = ((c.tool_x_mm - x0) * dx + (c.tool_y_mm - y0) * dy) / len2;
  if (!(t > 0.0 && t <= 1.0)) {
    return false;
  }
  const double ex = x0 + t * dx - c.tool_x_mm;
  const double ey = y0 + t * dy - c.tool_y_mm;
  const double z = z0 + t * dz;
  return ex * ex + ey * ey <= config_.xy_tolerance_mm * config_.xy_tolerance_mm &&
         std::fabs(z - c.z_mm) <= config_.z_band_mm;
}

bool CheckpointCompensator::detect_path(const AxisSample& s) noexcept {
  const double p = s.program_path_mm;
  if (!std::isfinite(p)) {
    return false;
  }
  const bool jumped_back = have_prev_ && p < prev_.program_path_mm;
  if (!have_prev_ || jumped_back) {
    // First sample of the part, or the program was restarted further back: every checkpoint
    // at or before p counts as passed (its value is in force from here on).
    const auto it = std::upper_bound(plan_.begin(), plan_.end(), p,
                                     [](double v, const Checkpoint& c) { return v < c.path_mm; });
    next_ = static_cast<std::size_t>(it - plan_.begin());
    return true;
  }
  while (next_ < plan_.size() && plan_[next_].path_mm <= p) {
    ++next_;
    ++counters_.triggers;
  }
  return true;
}

bool CheckpointCompensator::in_band(std::size_t level, const AxisSample& s) const noexcept {
  return std::fabs(s.position_mm[2] - levels_[level].z_mm) <= config_.z_band_mm;
}

bool CheckpointCompensator::detect_position(const AxisSample& s, StepOutput& out) noexcept {
  if (!have_prev_) {
    band_level_ = kNone;
    return true;
  }
  const double dx = s.position_mm[0] - prev_.position_mm[0];
  const double dy = s.position_mm[1] - prev_.position_mm[1];
  const double dz = s.position_mm[2] - prev_.position_mm[2];
  travel_since_mm_ += std::sqrt(dx * dx + dy * dy + dz * dz);
  // Several checkpoints may fall into one sample interval at low loop rates: test in order.
  while (next_ < plan_.size()) {
    if (passes(next_, s)) {
      ++next_;
      ++counters_.triggers;
      travel_since_mm_ = 0.0;
      continue;
    }
    // One-ahead: if the following checkpoint triggers, this one was missed (tolerance too tight
    // or the program deviates from the plan). Report it and carry on in order.
    if (next_ + 1 < plan_.size() && passes(next_ + 1, s)) {
      ++counters_.missed;
      out.alarm(s.time_ns, Severity::kWarning, AlarmCode::kCheckpointMissed,
                static_cast<std::int32_t>(next_), 0.0);
      next_ += 2;
      ++counters_.triggers;
      travel_since_mm_ = 0.0;
      continue;
    }
    break;
  }
  // Before a level's first checkpoint, the tool's progress on that level's pass is its XY travel
  // since it entered the level's Z band (the pass starts where the plunge ends).
  if (next_ < plan_.size() &&
      next_ == levels_[static_cast<std::size_t>(plan_[next_].level)].first &&
      in_band(static_cast<std::size_t>(plan_[next_].level), s)) {
    const auto l = static_cast<std::size_t>(plan_[next_].level);
    if (band_level_ != l) {
      band_level_ = l;
      travel_in_band_mm_ = 0.0;
    } else {
      travel_in_band_mm_ += std::sqrt(dx * dx + dy * dy);
    }
  } else {
    band_level_ = kNone;
  }
  return true;
}

double CheckpointCompensator::ramp(double from_um, double to_um, double u) const noexcept {
  return from_um + profile_fraction(config_.creep_shape, u) * (to_um - from_um);
}

double CheckpointCompensator::level_value_um(std::size_t l, std::size_t k,
                                             double done_mm) const noexcept {
  const Level& lv = levels_[l];
  const bool creep = config_.apply == ApplyMode::kCreep;
  // The seam (closed pass): from the last checkpoint through the pass's start/end point to the
  // first, span = the part of the pass not between first and last.
  const bool wraps = lv.closed && lv.length_mm > 0.0;
  const double seam_span_mm =
      wraps ? lv.length_mm - plan_[lv.last].s_mm + plan_[lv.first].s_mm : 0.0;
  const double v_first = register_value_um(lv.first);
  const double v_last = register_value_um(lv.last);
  if (k == kNone) {  // before the level's first checkpoint
    if (!wraps) {
      return v_first;
    }
    if (!creep) {
      return v_last;  // the value of the checkpoint last passed along the closed contour
    }
    const double done = std::min(done_mm, plan_[lv.first].s_mm);
    const double before_seam = lv.length_mm - plan_[lv.last].s_mm;
    return ramp(v_last, v_first, (before_seam + done) / seam_span_mm);
  }
  const double v_k = register_value_um(k);
  if (!creep) {
    return v_k;
  }
  if (k < lv.last) {
    const double span = plan_[k + 1].s_mm - plan_[k].s_mm;
    return ramp(v_k, register_value_um(k + 1), done_mm / span);
  }
  if (!wraps) {
    return v_last;
  }
  return ramp(v_last, v_first, done_mm / seam_span_mm);
}

double CheckpointCompensator::level_start_value_um(std::size_t l) const noexcept {
  return level_value_um(l, kNone, 0.0);
}

double CheckpointCompensator::level_end_value_um(std::size_t l) const noexcept {
  // At the pass's end point (closed: the seam, where the pass started).
  const Level& lv = levels_[l];
  return level_value_um(l, lv.last, lv.length_mm - plan_[lv.last].s_mm);
}

double CheckpointCompensator::start_value_um() const noexcept {
  return plan_.empty() ? 0.0 : level_start_value_um(0);
}

double CheckpointCompensator::path_target_um(double p) const noexcept {
  // The level whose pass started last at or before p.
  std::size_t l = 0;
  {
    const auto it =
        std::upper_bound(levels_.begin(), levels_.end(), p,
                         [](double v, const Level& lv) { return v < lv.start_path_mm; });
    l = it == levels_.begin() ? 0 : static_cast<std::size_t>(it - levels_.begin()) - 1;
  }
  const Level& lv = levels_[l];
  // 1 nm of slack at the pass's end: path_mm − s_mm carries the rounding of both.
  const double s = std::max(0.0, p - lv.start_path_mm);
  if (lv.length_mm > 0.0 && s > lv.length_mm + 1e-6 && l + 1 < levels_.size()) {
    // The level link: step mode switches to the next level's start value at once (the register
    // has the whole link to slew), creep ramps from this level's end value to it.
    const double next_start = level_start_value_um(l + 1);
    if (config_.apply != ApplyMode::kCreep) {
      return next_start;
    }
    const double link_mm = levels_[l + 1].start_path_mm - lv.start_path_mm - lv.length_mm;
    return ramp(level_end_value_um(l), next_start,
                link_mm > 0.0 ? (s - lv.length_mm) / link_mm : 1.0);
  }
  // The level's last checkpoint at or before s.
  const auto first = plan_.begin() + static_cast<std::ptrdiff_t>(lv.first);
  const auto last = plan_.begin() + static_cast<std::ptrdiff_t>(lv.last) + 1;
  const auto it =
      std::upper_bound(first, last, s, [](double v, const Checkpoint& c) { return v < c.s_mm; });
  if (it == first) {
    return level_value_um(l, kNone, s);
  }
  const auto k = static_cast<std::size_t>(it - plan_.begin()) - 1;
  return level_value_um(l, k, s - plan_[k].s_mm);
}

double CheckpointCompensator::position_target_um(const AxisSample& s) const noexcept {
  // The tool centre's travel runs ahead of the contour around convex corners (tool radius ×
  // turn): progress is clamped at the next checkpoint, and after a level's last checkpoint at
  // the pass's end, so the pass still ends with the value it started with.
  const auto after_last = [&](std::size_t l) {
    const Level& lv = levels_[l];
    const double to_end = lv.length_mm - plan_[lv.last].s_mm;
    return level_value_um(l, lv.last, std::min(travel_since_mm_, to_end));
  };
  if (next_ >= plan_.size()) {
    return after_last(levels_.size() - 1);
  }
  const auto l = static_cast<std::size_t>(plan_[next_].level);
  const Level& lv = levels_[l];
  if (next_ > lv.first) {
    return level_value_um(l, next_ - 1,
                          std::min(travel_since_mm_, plan_[next_].s_mm - plan_[next_ - 1].s_mm));
  }
  // Nothing of level l passed yet.
  if (band_level_ == l) {
    return level_value_um(l, kNone, travel_in_band_mm_);
  }
  if (l == 0 || !have_prev_) {
    return level_start_value_um(l);
  }
  // Still on the previous level after its last checkpoint (through its seam) ...
  if (in_band(l - 1, s)) {
    return after_last(l - 1);
  }
  // ... or in the level link: its progress is the plunge from one level's Z to the next.
  const double next_start = level_start_value_um(l);
  if (config_.apply != ApplyMode::kCreep) {
    return next_start;
  }
  const double dz = levels_[l - 1].z_mm - lv.z_mm;
  const double u = std::fabs(dz) > 0.0 ? (levels_[l - 1].z_mm - s.position_mm[2]) / dz : 1.0;
  return ramp(level_end_value_um(l - 1), next_start, u);
}

double CheckpointCompensator::target_value_um(const AxisSample& s) const noexcept {
  return config_.trigger == TriggerMode::kPath ? path_target_um(s.program_path_mm)
                                               : position_target_um(s);
}

void CheckpointCompensator::on_sample(const AxisSample& s, StepOutput& out) noexcept {
  const std::int32_t tool = s.tool != 0 ? s.tool : tool_;
  if (tool != config_.finishing_tool) {
    have_prev_ = false;
    return;
  }
  // Checkpoints passed in this sample (not those counted at a part's first sample or after a
  // program restart: they were cut before the daemon saw the tool there).
  const bool fresh = have_prev_ && !(config_.trigger == TriggerMode::kPath &&
                                     s.program_path_mm < prev_.program_path_mm);
  const std::size_t passed_before = next_;
  const bool ok = config_.trigger == TriggerMode::kPath ? detect_path(s) : detect_position(s, out);
  if (!ok) {
    return;  // no program path published: nothing is known about where the tool is
  }
  prev_ = s;
  have_prev_ = true;
  awaiting_finish_ = false;
  if (next_ > passed_before) {
    focus_ = static_cast<std::int32_t>(next_ - 1);
  }
  cut_first_ = cut_last_ = 0;
  if (fresh) {
    cut_first_ = passed_before;
    cut_last_ = next_;
  }
  if (config_.active_register < 0) {
    live_target_um_ = target_value_um(s);
    return;
  }
  write_live(target_value_um(s), s.time_ns, out);
  // What the wall at these checkpoints is cut with: the live register as the limiter let it
  // through in this cycle (a slewing register has not reached its target yet).
  if (fresh && std::isfinite(live_written_um_)) {
    for (std::size_t i = passed_before; i < next_; ++i) {
      points_[i].applied_um = live_written_um_;
    }
  }
}

void CheckpointCompensator::reset_live(double nc_value_um, TimeNs now_ns) noexcept {
  limiter_.reset(nc_value_um, now_ns);
  live_written_um_ = limiter_.output_um();
}

bool CheckpointCompensator::adopt_register_value(std::size_t i, double nc_value_um) noexcept {
  if (i >= points_.size() || !limiter_.admissible(nc_value_um)) {
    return false;
  }
  points_[i].offset_um = nc_value_um;
  points_[i].applied_um = nc_value_um;
  ++generation_;
  return true;
}

bool CheckpointCompensator::rebase(std::size_t first, std::size_t last, double delta_um,
                                   TimeNs now_ns, const engine::TrimChange* along,
                                   bool cut_trim_known) noexcept {
  if (first > last || last >= points_.size() || !std::isfinite(delta_um)) {
    return false;
  }
  for (std::size_t i = first; i <= last; ++i) {
    if (!limiter_.admissible(points_[i].offset_um + delta_um)) {
      return false;
    }
  }
  const bool mode_a = config_.learning_mode == LearningMode::kPreviousPart;
  for (std::size_t i = first; i <= last; ++i) {
    LearnedPoint& p = points_[i];
    p.offset_um += delta_um;
    p.applied_um += delta_um;
    p.learned_um -= delta_um;
    for (std::uint32_t k = 0; k < p.history_n; ++k) p.history[k] -= delta_um;
    if (mode_a && p.history_n > 0) {
      // The average lags a trend the trims now predict: the residual is the last part's error
      // less the new trim. Applied as an update is (feedback, dead band), at S1's next write.
      double at_cut_um = delta_um;
      if (along != nullptr && std::isfinite(p.cut_inputs.path_mm)) {
        const double old_um = cut_trim_known && std::isfinite(p.cut_trim_um)
                                  ? p.cut_trim_um
                                  : along->old_at_switch_um();
        const double change_um = along->new_at(p.cut_inputs) - old_um;
        if (std::isfinite(change_um)) at_cut_um = -change_um;
      }
      p.learned_um = p.history[p.history_n - 1] + delta_um - at_cut_um;
      const double candidate = p.offset_um + config_.feedback * (-p.learned_um - p.offset_um);
      if (std::fabs(candidate - p.offset_um) >= config_.dead_band_um &&
          limiter_.admissible(candidate)) {
        p.offset_um = candidate;
      }
    }
    // The errors before describe another split of the compensation (a trend the trim took, or
    // gave back): the next reading counts in full, and the outlier rule waits for new ones.
    p.count = 0;
    p.history_n = 0;
    p.filter_n = 0;
    mark_dirty(i);
  }
  if (config_.active_register >= 0 && first == 0 && last + 1 == points_.size()) {
    if (std::isfinite(live_target_um_)) live_target_um_ += delta_um;
    if (std::isfinite(live_written_um_)) {
      live_written_um_ += delta_um;
      limiter_.reset(live_written_um_, now_ns);
    }
  }
  ++generation_;
  return true;
}

void CheckpointCompensator::export_state(CheckpointState& out) const {
  out.version = 4;
  out.part_counter = part_counter_;
  out.part = part_;
  out.points.assign(points_.begin(), points_.end());
}

const char* CheckpointCompensator::invalid_point_reason(const LearnedPoint& p) const noexcept {
  if (!std::isfinite(p.learned_um) || !std::isfinite(p.offset_um) || !std::isfinite(p.applied_um) ||
      !std::isfinite(p.variance_um2)) {
    return "non-finite value";
  }
  if (p.variance_um2 < 0.0) {
    return "negative variance";
  }
  if (const char* why = p.cut_inputs.invalid_reason()) {
    return why;
  }
  if (std::isinf(p.cut_trim_um)) {
    return "cut trim infinite";
  }
  if (p.history_n > kHistoryDepth) {
    return "history longer than its capacity";
  }
  for (std::uint32_t k = 0; k < p.history_n; ++k) {
    if (!std::isfinite(p.history[k])) {
      return "non-finite history entry";
    }
  }
  if (!limiter_.admissible(p.offset_um)) {
    return "offset beyond the absolute limit";
  }
  return nullptr;
}

bool CheckpointCompensator::restore_point(std::size_t i, const LearnedPoint& point) noexcept {
  if (i >= points_.size() || invalid_point_reason(point) != nullptr) {
    return false;
  }
  points_[i] = point;
  mark_dirty(i);
  ++generation_;
  return true;
}

void CheckpointCompensator::restore_counters(std::int64_t part_counter,
                                             std::int32_t part) noexcept {
  part_counter_ = part_counter;
  part_ = part;
  for (std::size_t i = 0; i < plan_.size(); ++i) {
    mark_dirty(i);
  }
  ++generation_;
}

void CheckpointCompensator::import_state(const CheckpointState& st) {
  if (st.version < 1 || st.version > 4) {
    throw std::invalid_argument("checkpoint state: unknown version " + std::to_string(st.version));
  }
  if (st.points.size() != plan_.size()) {
    throw std::invalid_argument("checkpoint state: holds " + std::to_string(st.points.size()) +
                                " checkpoints, the plan has " + std::to_string(plan_.size()) +
                                " (the plan changed: learned values do not fit it)");
  }
  for (std::size_t i = 0; i < st.points.size(); ++i) {
    if (const char* why = invalid_point_reason(st.points[i])) {
      throw std::invalid_argument("checkpoint state: checkpoint " + std::to_string(i) + ": " + why);
    }
  }
  for (std::size_t i = 0; i < st.points.size(); ++i) {
    LearnedPoint p = st.points[i];
    if (st.version == 1) {
      p.variance_um2 = 0.0;  // version 1 had no filter: it starts at the next reading
      p.filter_n = 0;
    }
    if (st.version <= 2) {
      p.cut_inputs = engine::InputSnapshot{};
    }
    if (st.version <= 3) {
      p.cut_trim_um = kNaN;
    }
    (void)restore_point(i, p);
  }
  restore_counters(st.part_counter, st.part);
}

double CheckpointCompensator::part_noise_var_um2(std::size_t i) const noexcept {
  const CheckpointEstimatorConfig& est = config_.estimator;
  const LearnedPoint& p = points_[i];
  if (est.learn_part_noise && p.history_n >= est.learn_min_parts) {
    return learned_part_noise_um2(p, est.measurement_sigma_um);
  }
  return est.part_noise_um * est.part_noise_um;
}

double CheckpointCompensator::predicted_sigma_um(std::size_t i) const noexcept {
  const CheckpointEstimatorConfig& est = config_.estimator;
  const LearnedPoint& p = points_[i];
  if (!est.enabled || p.count == 0) return kNaN;
  const double r = est.measurement_sigma_um * est.measurement_sigma_um;
  return std::sqrt((p.filter_n > 0 ? p.variance_um2 : r) + part_noise_var_um2(i));
}

double CheckpointCompensator::next_gain(std::size_t i) const noexcept {
  const CheckpointEstimatorConfig& est = config_.estimator;
  const LearnedPoint& p = points_[i];
  if (!est.enabled) return kNaN;
  if (p.count == 0) return 1.0;
  const double r = est.measurement_sigma_um * est.measurement_sigma_um;
  const double prior = (p.filter_n > 0 ? p.variance_um2 : r) + part_noise_var_um2(i);
  return prior / (prior + r);
}

ReconcileReport CheckpointCompensator::reconcile(std::span<const double> nc_values_um) {
  if (nc_values_um.size() != plan_.size()) {
    throw std::invalid_argument("checkpoint reconcile: read " +
                                std::to_string(nc_values_um.size()) + " registers, the plan has " +
                                std::to_string(plan_.size()));
  }
  ReconcileReport rep;
  rep.adopted_nc = config_.reconcile_prefer == ReconcilePrefer::kNc;
  for (std::size_t i = 0; i < plan_.size(); ++i) {
    ++rep.compared;
    const double nc = nc_values_um[i];
    const double mine = register_value_um(i);
    const double diff = std::isfinite(nc) ? std::fabs(nc - mine) : kHuge;
    if (diff <= config_.reconcile_tolerance_um) {
      continue;
    }
    ++rep.mismatched;
    rep.max_difference_um = std::max(rep.max_difference_um, diff);
    if (rep.mismatched_ids.size() < 32) {
      rep.mismatched_ids.push_back(static_cast<std::int32_t>(i));
    }
    // An operator may have edited the NC's table on purpose (prefer = nc); a value the limiter
    // would refuse is never adopted.
    // Whatever wins, the part in the machine was cut with what the NC holds.
    if (std::isfinite(nc)) {
      points_[i].applied_um = nc;
    }
    if (rep.adopted_nc && limiter_.admissible(nc)) {
      points_[i].offset_um = nc;
      if (std::fabs(register_value_um(i) - nc) > config_.reconcile_tolerance_um) {
        mark_dirty(i);  // below the repeatability: the register gets the 0 we would write
        ++rep.rewritten;
      }
    } else {
      mark_dirty(i);
      ++rep.rewritten;
    }
  }
  if (rep.adopted_nc && rep.rewritten > 0) {
    // The whole table will be sent again (some read-backs could not be adopted): the adopted
    // values go with it as targets, so the engine's resend does not put its last values over
    // them.
    for (std::size_t i = 0; i < plan_.size(); ++i) {
      const double nc = nc_values_um[i];
      if (std::isfinite(nc) && limiter_.admissible(nc) &&
          std::fabs(nc - register_value_um(i)) <= config_.reconcile_tolerance_um &&
          dirty_[i] == 0) {
        mark_dirty(i);
      }
    }
  }
  pending_mismatch_ = rep.mismatched;
  ++generation_;
  return rep;
}

}  // namespace nccomp::core::checkpoint
