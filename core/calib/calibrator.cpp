#include "core/calib/calibrator.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <variant>

#include "core/calib/drift_estimator.hpp"
#include "core/calib/facet.hpp"
#include "core/common/profile.hpp"

namespace nccomp::core::calib {

namespace {

constexpr std::size_t kX = static_cast<std::size_t>(Slot::kXLateral);
constexpr std::size_t kXA = static_cast<std::size_t>(Slot::kXAxial);
constexpr std::size_t kY = static_cast<std::size_t>(Slot::kY);
constexpr std::size_t kZ = static_cast<std::size_t>(Slot::kZ);

/// Axis id (0/1/2 = X/Y/Z) of a slot: alarm subject and measurement-record point.
constexpr std::int32_t slot_axis(std::size_t slot) {
  return slot <= kXA ? 0 : static_cast<std::int32_t>(slot - 1);
}

/// Temperature spread below which a slope is not learned [°C²] (0.1 °C standard deviation).
constexpr double kMinTemperatureVariance = 0.01;
// The first-order model's asymptote is refitted from two touches only when the second lies at
// least this share of the rise after the first (1 − e^(−Δt/τ) ≥ 0.2, Δt ≥ 0.22 τ): the touch noise
// is then amplified at most 5 times.
constexpr double kMinAsymptoteSpread = 0.2;

static_assert(std::tuple_size_v<decltype(CalibrationConfig::estimator_model_slope_um_per_c)> ==
              kSlotCount);

EstimatorParams estimator_params(const CalibrationConfig& c, std::size_t slot,
                                 const ShiftHistory& shifts) noexcept {
  const double model_sigma = c.estimator_model_slope_sigma_um_per_c[slot];
  const double level =
      c.estimator_learn_level_noise
          ? learned_level_noise_um_per_h(shifts, slot, c.estimator_level_noise_um_per_h,
                                         c.estimator_min_level_noise_um_per_h,
                                         c.estimator_max_level_noise_um_per_h)
          : c.estimator_level_noise_um_per_h;
  return {c.estimator_touch_noise_um, level, c.estimator_prior_gain_sigma,
          std::isnan(model_sigma) ? c.estimator_slope_sigma_um_per_c : model_sigma,
          c.estimator_gate_sigmas};
}

/// The slope a new shift's estimate starts at: the model's where set, else `learned` when the
/// temperature is used, else 0.
double start_slope(const CalibrationConfig& c, std::size_t slot, double learned) noexcept {
  const double model = c.estimator_model_slope_um_per_c[slot];
  if (!std::isnan(model)) {
    return model;
  }
  return c.estimator_slope_sigma_um_per_c > 0.0 ? learned : 0.0;
}

}  // namespace

const char* to_string(FacetStatus status) noexcept {
  switch (status) {
    case FacetStatus::kGrindAgain:
      return "grind-again";
    case FacetStatus::kConverged:
      return "converged";
    case FacetStatus::kWrongPhase:
      return "wrong-phase";
    case FacetStatus::kInvalidInput:
      return "invalid-input";
    case FacetStatus::kNotConverging:
      return "not-converging";
  }
  return "?";
}

void Calibrator::configure(const CalibrationConfig& config) {
  validate(config);
  const LimiterConfig limits{config.max_abs_um, config.max_step_um, config.max_rate_um_per_s};
  for (auto& l : limiters_) {
    l.configure(limits);
  }
  for (std::size_t s = 0; s < kSlotCount; ++s) {
    // A slot whose input is now another sensor waits for that sensor's first sample.
    if (!configured_ || estimator_input_sensor(config_, s) != estimator_input_sensor(config, s)) {
      input_[s] = kNaN;
    }
  }
  config_ = config;
  configured_ = true;
}

void Calibrator::set_clock_offset_s(double wall_minus_monotonic_s) noexcept {
  clock_offset_s_ = std::isfinite(wall_minus_monotonic_s) ? wall_minus_monotonic_s : 0.0;
}

void Calibrator::begin_calibration(TimeNs now_ns, StepOutput& out) noexcept {
  (void)out;
  // Earlier shifts and the learned temperature slopes outlive a new calibration.
  const ShiftHistory shifts = state_.shifts;
  const auto estimates = state_.estimates;
  state_ = CalibState{};
  state_.shifts = shifts;
  state_.estimates = estimates;
  state_.phase = Phase::kReferenceTouches;
  state_.result.time_s = seconds(now_ns);
  set_ = TouchSet{};
  due_raised_ = false;
  demand_ = false;
}

void Calibrator::discard_touch_set() noexcept { set_ = TouchSet{}; }

bool Calibrator::request_recalibration() noexcept {
  if (!configured_ || state_.phase != Phase::kReady) {
    return false;
  }
  demand_ = true;
  return true;
}

void Calibrator::enter_touch(const CalibrationTouch& touch, TimeNs now_ns,
                             StepOutput& out) noexcept {
  if (configured_) {
    handle_touch(touch, seconds(now_ns), now_ns, out);
  }
}

bool Calibrator::grinding() const noexcept {
  return state_.phase == Phase::kTestGrindLateral || state_.phase == Phase::kTestGrindEndFace;
}

double Calibrator::offset_in_force_um(std::size_t axis) const noexcept {
  if (axis >= kAxisCount) {
    return 0.0;
  }
  return std::isfinite(written_um_[axis]) ? written_um_[axis] : 0.0;
}

RequestCode Calibrator::request() const noexcept {
  switch (state_.phase) {
    case Phase::kUncalibrated:
      return RequestCode::kNone;
    case Phase::kReferenceTouches:
      return RequestCode::kReferenceTouches;
    case Phase::kTestGrindLateral:
      return RequestCode::kTestGrindLateral;
    case Phase::kTestGrindEndFace:
      return RequestCode::kTestGrindEndFace;
    case Phase::kNominalTouches:
      return RequestCode::kNominalTouches;
    case Phase::kReady:
      return recalibration_requested() ? RequestCode::kRecalibration : RequestCode::kNone;
  }
  return RequestCode::kNone;
}

const Nominal& Calibrator::nominal(Slot slot) const noexcept {
  return state_.nominals[static_cast<std::size_t>(slot)];
}
const DriftModel& Calibrator::model(Slot slot) const noexcept {
  return state_.models[static_cast<std::size_t>(slot)];
}

TouchProgress Calibrator::touch_progress() const noexcept {
  TouchProgress p;
  p.count = set_.count;
  p.required = config_.touches_per_axis;
  return p;
}

bool Calibrator::base_valid() const noexcept {
  return state_.phase == Phase::kNominalTouches || state_.phase == Phase::kReady;
}

double Calibrator::base_um(std::size_t axis) const noexcept {
  switch (axis) {
    case 0:
      return state_.result.dx_r_um;
    case 1:
      return state_.result.dy_um;
    case 2:
      return state_.result.dz_um;
    default:
      return kNaN;
  }
}

// ------------------------------------------------------------------------------------------
// Test grinding.

FacetResult Calibrator::enter_facets(Face face, double chord_plus_mm, double chord_minus_mm,
                                     TimeNs now_ns, StepOutput& out) noexcept {
  FacetResult r;
  const Phase expected =
      face == Face::kLateral ? Phase::kTestGrindLateral : Phase::kTestGrindEndFace;
  if (!configured_ || state_.phase != expected) {
    r.status = FacetStatus::kWrongPhase;
    return r;
  }
  const double rho = config_.blank_radius_mm;
  const auto chord_ok = [rho](double c) { return std::isfinite(c) && c > 0.0 && c <= 2.0 * rho; };
  if (!chord_ok(chord_plus_mm) || !chord_ok(chord_minus_mm)) {
    out.alarm(now_ns, Severity::kWarning, AlarmCode::kCalibrationInvalidInput, 0,
              chord_ok(chord_plus_mm) ? chord_minus_mm : chord_plus_mm);
    r.status = FacetStatus::kInvalidInput;
    r.grinds = state_.grinds;
    return r;
  }
  r.grinds = ++state_.grinds;
  r.error_um = config_.facet_rule == FacetRule::kExact
                   ? facet_error_exact_um(rho, chord_plus_mm, chord_minus_mm)
                   : facet_error_proportional_um(config_.facet_gain_um_per_um, chord_plus_mm,
                                                 chord_minus_mm);
  const double chord_diff_um = (chord_plus_mm - chord_minus_mm) * kUmPerMm;
  if (std::fabs(chord_diff_um) <= config_.facet_tolerance_um) {
    r.status = FacetStatus::kConverged;
    r.correction_um = state_.grind_correction_um;
    auto& res = state_.result;
    if (face == Face::kLateral) {
      res.dx_r_um = state_.grind_correction_um;
      res.lateral_grinds = state_.grinds;
      state_.grinds = 0;
      if (config_.end_face_test_grind) {
        state_.phase = Phase::kTestGrindEndFace;
        state_.grind_correction_um = res.dx_touch_axial_um;
        last_write_s_ = -1e300;
      } else {
        res.dx_a_um = res.dx_touch_axial_um;
        finish_calibration(seconds(now_ns), now_ns, out);
      }
    } else {
      res.dx_a_um = state_.grind_correction_um;
      res.end_face_grinds = state_.grinds;
      state_.grinds = 0;
      finish_calibration(seconds(now_ns), now_ns, out);
    }
    return r;
  }
  const double next = state_.grind_correction_um + r.error_um;
  r.correction_um = next;
  if (!limiters_[0].admissible(next)) {
    out.alarm(now_ns, Severity::kAlarm, AlarmCode::kCalibrationOutOfRange, 0, next);
    r.status = FacetStatus::kNotConverging;
    state_.phase = Phase::kUncalibrated;
    return r;
  }
  if (state_.grinds >= config_.max_test_grinds) {
    out.alarm(now_ns, Severity::kAlarm, AlarmCode::kTestGrindNotConverging, 0, chord_diff_um);
    r.status = FacetStatus::kNotConverging;
    state_.phase = Phase::kUncalibrated;
    return r;
  }
  state_.grind_correction_um = next;
  last_write_s_ = -1e300;  // the X register takes the new Δx at the next step
  r.status = FacetStatus::kGrindAgain;
  return r;
}

void Calibrator::finish_calibration(double now_s, TimeNs now_ns, StepOutput& out) noexcept {
  auto& res = state_.result;
  // The reference probe triggers at the same deflection in every lateral direction, so the
  // probe correction that test grinding found on X holds for Y and Z (S3 step 3).
  res.probe_lateral_um = res.dx_r_um - res.dx_touch_lateral_um;
  res.probe_axial_um = res.dx_a_um - res.dx_touch_axial_um;
  res.pivot_um = res.dx_a_um - res.dx_r_um;
  res.dy_um = res.dy_touch_um + res.probe_lateral_um;
  res.dz_um = res.dz_touch_um + res.probe_lateral_um;
  res.time_s = now_s;
  for (std::size_t a = 0; a < kAxisCount; ++a) {
    if (!limiters_[a].admissible(base_um(a))) {
      out.alarm(now_ns, Severity::kAlarm, AlarmCode::kCalibrationOutOfRange,
                static_cast<std::int32_t>(a), base_um(a));
      state_.phase = Phase::kUncalibrated;
      return;
    }
  }
  state_.nominals = {};
  state_.models = {};
  state_.creeps = {};
  state_.history_count = 0;
  state_.history_next = 0;
  state_.phase = Phase::kNominalTouches;
  last_write_s_ = -1e300;
  out.alarm(now_ns, Severity::kInfo, AlarmCode::kCalibrationComplete, 0, res.dx_r_um);
}

// ------------------------------------------------------------------------------------------
// Touches.

void Calibrator::handle_touch(const CalibrationTouch& t, double now_s, TimeNs now_ns,
                              StepOutput& out) noexcept {
  if (t.fault != InputFault::kNone) {
    // A touch the NC reported whose values did not arrive intact: an alarm, not the warning of a
    // malformed operator entry, because the touch cycle on the machine lost a touch. The set in
    // progress waits for it as for any missing touch (touch_set_timeout_s).
    out.alarm(now_ns, Severity::kAlarm, AlarmCode::kCalibrationInvalidInput, t.axis, kNaN);
    return;
  }
  const bool valid = t.axis <= 2 && (t.direction == 1 || t.direction == -1) && t.variant <= 1 &&
                     (t.variant == 0 || t.axis == 0) && std::isfinite(t.trigger_position_mm);
  if (!valid) {
    out.alarm(now_ns, Severity::kWarning, AlarmCode::kCalibrationInvalidInput, t.axis,
              t.trigger_position_mm);
    return;
  }
  const std::size_t slot = t.axis == 0 ? (t.variant == 1 ? kXA : kX) : t.axis + 1u;
  // Everything is compared in machine coordinates: a program-coordinate reading is the machine
  // position minus the offset the NC holds (machine = program + offset).
  const double trigger_mm = config_.touch_positions == TouchPositions::kProgram
                                ? t.trigger_position_mm + offset_in_force_um(t.axis) / kUmPerMm
                                : t.trigger_position_mm;
  const Phase ph = state_.phase;
  const bool reference = ph == Phase::kReferenceTouches && t.probe == ProbeKind::kReferenceProbe;
  const bool machine =
      (ph == Phase::kNominalTouches || ph == Phase::kReady) && t.probe == ProbeKind::kMachineProbe;
  if (!reference && !machine) {
    out.alarm(now_ns, Severity::kWarning, AlarmCode::kTouchUnexpected, slot_axis(slot),
              t.trigger_position_mm);
    return;
  }
  auto& n = set_.count[slot];
  if (ph == Phase::kReady && t.direction != state_.nominals[slot].direction) {
    // A drift is only defined against a nominal touched from the same side.
    out.alarm(now_ns, Severity::kWarning, AlarmCode::kTouchUnexpected, slot_axis(slot),
              t.trigger_position_mm);
    return;
  }
  if (ph == Phase::kNominalTouches && n > 0 && t.direction != set_.direction[slot]) {
    out.alarm(now_ns, Severity::kWarning, AlarmCode::kTouchUnexpected, slot_axis(slot),
              t.trigger_position_mm);
    return;
  }
  if (n >= static_cast<std::int32_t>(kMaxTouchesPerSlot)) {
    out.alarm(now_ns, Severity::kWarning, AlarmCode::kTouchUnexpected, slot_axis(slot),
              t.trigger_position_mm);
    return;
  }
  if (!set_.open) {
    set_.open = true;
    set_.first_time_s = now_s;
  }
  double value = 0.0;
  if (reference) {
    const std::array<double, kSlotCount> centre{config_.reference_x_lateral_mm,
                                                config_.reference_x_axial_mm,
                                                config_.reference_y_mm, config_.reference_z_mm};
    const double contact =
        slot == kXA ? config_.reference_axial_contact_mm : config_.reference_contact_mm;
    value = (trigger_mm - (centre[slot] - t.direction * contact)) * kUmPerMm;
  } else if (ph == Phase::kReady) {
    value = (trigger_mm - state_.nominals[slot].position_mm) * kUmPerMm;
  } else {
    value = trigger_mm * kUmPerMm;
  }
  const auto i = static_cast<std::size_t>(n);
  set_.value[slot][i] = value;
  set_.trigger_mm[slot][i] = trigger_mm;
  set_.direction[slot] = t.direction;
  ++n;
  for (const auto c : set_.count) {
    if (c < config_.touches_per_axis) {
      return;
    }
  }
  evaluate_set(now_s, now_ns, out);
}

double Calibrator::mean(std::size_t slot) const noexcept {
  double s = 0.0;
  const auto n = static_cast<std::size_t>(set_.count[slot]);
  for (std::size_t i = 0; i < n; ++i) {
    s += set_.value[slot][i];
  }
  return n > 0 ? s / static_cast<double>(n) : kNaN;
}

double Calibrator::scatter(std::size_t slot) const noexcept {
  const auto n = static_cast<std::size_t>(set_.count[slot]);
  if (n == 0) {
    return 0.0;
  }
  const auto first = set_.value[slot].begin();
  const auto [lo, hi] = std::minmax_element(first, first + static_cast<std::ptrdiff_t>(n));
  return *hi - *lo;
}

void Calibrator::evaluate_set(double now_s, TimeNs now_ns, StepOutput& out) noexcept {
  bool scattered = false;
  for (std::size_t s = 0; s < kSlotCount; ++s) {
    const double spread = scatter(s);
    if (spread > config_.max_scatter_um) {
      out.alarm(now_ns, Severity::kAlarm, AlarmCode::kTouchScatter, slot_axis(s), spread);
      scattered = true;
    }
  }
  if (!scattered) {
    switch (state_.phase) {
      case Phase::kReferenceTouches:
        evaluate_reference(now_ns, out);
        break;
      case Phase::kNominalTouches:
        evaluate_nominals(now_s, now_ns, out);
        break;
      case Phase::kReady:
        evaluate_recalibration(now_s, now_ns, out);
        break;
      default:
        break;
    }
  }
  if (state_.phase == Phase::kReady) {
    // The requested cycle came (accepted or refused: an alarm tells the operator); the schedule
    // counts from here.
    due_raised_ = false;
    demand_ = false;
    last_attempt_s_ = now_s;
  }
  // A scattered set applies nothing; the touch cycle is repeated as a whole.
  set_ = TouchSet{};
}

void Calibrator::evaluate_reference(TimeNs now_ns, StepOutput& out) noexcept {
  std::array<double, kSlotCount> d{};
  for (std::size_t s = 0; s < kSlotCount; ++s) {
    d[s] = mean(s);
    if (!limiters_[0].admissible(d[s])) {
      out.alarm(now_ns, Severity::kAlarm, AlarmCode::kCalibrationOutOfRange, slot_axis(s), d[s]);
      return;
    }
  }
  auto& r = state_.result;
  r.dx_touch_lateral_um = d[kX];
  r.dx_touch_axial_um = d[kXA];
  r.dy_touch_um = d[kY];
  r.dz_touch_um = d[kZ];
  state_.phase = Phase::kTestGrindLateral;
  state_.grind_correction_um = d[kX];
  state_.grinds = 0;
  last_write_s_ = -1e300;  // the X register takes the Δx to grind with at the next step
}

void Calibrator::evaluate_nominals(double now_s, TimeNs now_ns, StepOutput& out) noexcept {
  // New nominals start a new shift: the one before joins the estimator's prior.
  fold_shift(state_.shifts, config_.estimator_prior_forgetting);
  const bool with_prior = config_.estimator_shift_prior && has_prior(state_.shifts);
  for (std::size_t s = 0; s < kSlotCount; ++s) {
    // The temperature slope is a property of the machine: a model's, or else the one the last
    // shift learned, starts the next.
    const auto& last = state_.estimates[s];
    state_.estimates[s] = start_estimate(now_s, with_prior,
                                         start_slope(config_, s, last.valid == 1 ? last.x[2] : 0.0),
                                         estimator_params(config_, s, state_.shifts));
    auto& n = state_.nominals[s];
    n.valid = 1;
    n.direction = set_.direction[s];
    n.position_mm = mean(s) / kUmPerMm;
    n.time_s = now_s;
    n.temp_c = input_[s];
    // The nominal is drift zero: the first point of every drift model.
    update_model(s, now_s, 0.0);
    state_.creeps[s] = Creep{now_s, 0.0};
  }
  for (std::size_t s = 0; s < kSlotCount; ++s) {
    // Records relative to the nominal (their scatter around it) need the nominal first.
    for (std::size_t i = 0; i < static_cast<std::size_t>(set_.count[s]); ++i) {
      set_.value[s][i] = (set_.trigger_mm[s][i] - state_.nominals[s].position_mm) * kUmPerMm;
    }
  }
  emit_records(now_ns, out);
  auto& h = state_.history[static_cast<std::size_t>(state_.history_next)];
  h = HistoryEntry{now_s, temp_c_, {0.0, 0.0, 0.0, 0.0}};
  state_.history_next = (state_.history_next + 1) % static_cast<std::int32_t>(kHistorySize);
  state_.history_count =
      std::min(state_.history_count + 1, static_cast<std::int32_t>(kHistorySize));
  state_.last_set_time_s = now_s;
  state_.phase = Phase::kReady;
}

void Calibrator::evaluate_recalibration(double now_s, TimeNs now_ns, StepOutput& out) noexcept {
  std::array<double, kSlotCount> drift{};
  bool plausible = true;
  for (std::size_t s = 0; s < kSlotCount; ++s) {
    drift[s] = mean(s);
    const double change = drift[s] - correction(s, now_s);
    if (!(std::fabs(change) <= config_.plausibility_um)) {
      out.alarm(now_ns, Severity::kAlarm, AlarmCode::kRecalibrationImplausible, slot_axis(s),
                change);
      plausible = false;
    }
  }
  for (std::size_t a = 0; a < kAxisCount && plausible; ++a) {
    const double target = base_um(a) + drift[kAxisSlot[a]];
    if (!limiters_[a].admissible(target)) {
      out.alarm(now_ns, Severity::kAlarm, AlarmCode::kOffsetBeyondAbsoluteLimit,
                static_cast<std::int32_t>(a), target);
      plausible = false;
    }
  }
  std::array<DriftEstimate, kSlotCount> estimates = state_.estimates;
  if (plausible && config_.prediction == Prediction::kEstimator) {
    for (std::size_t s = 0; s < kSlotCount; ++s) {
      const EstimatorParams p = estimator_params(config_, s, state_.shifts);
      auto& e = estimates[s];
      if (e.valid != 1) {  // switched to the estimator after the nominals
        e = start_estimate(state_.nominals[s].time_s, has_prior(state_.shifts),
                           start_slope(config_, s, 0.0), p);
      }
      const double prior = prior_drift_um(state_.shifts, s, now_s - state_.nominals[s].time_s);
      const auto r = update_estimate(e, prior, temperature_delta(s), now_s, drift[s], p);
      if (!r.accepted) {
        // Beyond the gate: the estimate does not absorb it, and nothing is applied.
        out.alarm(now_ns, Severity::kAlarm, AlarmCode::kRecalibrationImplausible, slot_axis(s),
                  drift[s] - correction(s, now_s));
        plausible = false;
      }
    }
  }
  if (!plausible) {
    return;  // crashed probe, bent stylus, dirt on the sphere: nothing applied
  }
  state_.estimates = estimates;
  add_shift_point(state_.shifts, now_s - state_.nominals[kX].time_s, drift);
  for (std::size_t s = 0; s < kSlotCount; ++s) {
    const double before = correction(s, now_s);
    update_model(s, now_s, drift[s]);
    // What the new prediction would jump by is crept in, never stepped.
    state_.creeps[s] = Creep{now_s, before - predict(s, now_s)};
  }
  emit_records(now_ns, out);
  auto& h = state_.history[static_cast<std::size_t>(state_.history_next)];
  h = HistoryEntry{now_s, temp_c_, drift};
  state_.history_next = (state_.history_next + 1) % static_cast<std::int32_t>(kHistorySize);
  state_.history_count =
      std::min(state_.history_count + 1, static_cast<std::int32_t>(kHistorySize));
  state_.last_set_time_s = now_s;
  for (std::size_t a = 0; a < kAxisCount; ++a) {
    out.alarm(now_ns, Severity::kInfo, AlarmCode::kRecalibrationApplied,
              static_cast<std::int32_t>(a), drift[kAxisSlot[a]]);
  }
}

void Calibrator::emit_records(TimeNs now_ns, StepOutput& out) const noexcept {
  // The axial X touch has no axis id of its own in the measurement log (point = 0/1/2); its
  // drift is kept in the history, the log carries the three axes the registers correct.
  for (const std::size_t s : kAxisSlot) {
    for (std::size_t i = 0; i < static_cast<std::size_t>(set_.count[s]); ++i) {
      MeasurementRecord r;
      r.time_ns = now_ns;
      r.kind = MeasurementKind::kCalib;
      r.point = slot_axis(s);
      r.position_mm[static_cast<std::size_t>(slot_axis(s))] = set_.trigger_mm[s][i];
      r.temp_c = temp_c_;
      r.measured_um = set_.value[s][i];
      r.applied_um = 0.0;
      out.records.push(r);
    }
  }
}

// ------------------------------------------------------------------------------------------
// Drift models.

void Calibrator::update_model(std::size_t slot, double t_s, double drift_um) noexcept {
  auto& m = state_.models[slot];
  const double tau = config_.thermal_time_constant_s;
  if (m.anchored == 1 && t_s > m.anchor_time_s) {
    // First order: d(t) = A + (d0 − A)·exp(−Δt/τ). The last two touches fix A, so each touch
    // re-aims the prediction. A from two touches carries their noise times 1/(1 − e^(−Δt/τ)):
    // touches closer than kMinAsymptoteSpread of the rise (an on-demand set a minute after the
    // last) keep the earlier A instead of extrapolating their noise (0.9 µm at 45 s of a 30 min
    // rise gave A = −36 µm); a limited A bounds the rest.
    const double a = std::exp(-(t_s - m.anchor_time_s) / tau);
    if (1.0 - a >= kMinAsymptoteSpread) {
      const double asymptote = (drift_um - a * m.anchor_drift_um) / (1.0 - a);
      m.asymptote_um = std::clamp(asymptote, drift_um - config_.plausibility_um,
                                  drift_um + config_.plausibility_um);
    }
  } else {
    m.asymptote_um = drift_um;
  }
  if (std::isfinite(temp_c_)) {
    const double lambda = config_.temperature_forgetting;
    m.sum_w = lambda * m.sum_w + 1.0;
    m.sum_t = lambda * m.sum_t + temp_c_;
    m.sum_d = lambda * m.sum_d + drift_um;
    m.sum_tt = lambda * m.sum_tt + temp_c_ * temp_c_;
    m.sum_td = lambda * m.sum_td + temp_c_ * drift_um;
    const double w = m.sum_w;
    const double mean_t = m.sum_t / w;
    const double var_t = m.sum_tt / w - mean_t * mean_t;
    if (var_t > kMinTemperatureVariance) {
      const double cov = m.sum_td / w - mean_t * (m.sum_d / w);
      m.slope_um_per_c = std::clamp(cov / var_t, -config_.max_temperature_slope_um_per_c,
                                    config_.max_temperature_slope_um_per_c);
    }
  }
  m.anchored = 1;
  ++m.touch_sets;
  m.anchor_time_s = t_s;
  m.anchor_drift_um = drift_um;
  m.anchor_temp_c = temp_c_;
}

double Calibrator::predict(std::size_t slot, double t_s) const noexcept {
  const auto& m = state_.models[slot];
  if (m.anchored != 1) {
    return 0.0;
  }
  switch (config_.prediction) {
    case Prediction::kNone:
      return m.anchor_drift_um;
    case Prediction::kTime: {
      const double dt = std::max(0.0, t_s - m.anchor_time_s);
      return m.asymptote_um +
             (m.anchor_drift_um - m.asymptote_um) * std::exp(-dt / config_.thermal_time_constant_s);
    }
    case Prediction::kEstimator: {
      // Bounded like a touch: between touches the estimate moves the axis by at most what one
      // recalibration could from the last measured drift.
      const double mean = estimate(slot, t_s).mean_um;
      return std::isfinite(mean) ? std::clamp(mean, m.anchor_drift_um - config_.plausibility_um,
                                              m.anchor_drift_um + config_.plausibility_um)
                                 : m.anchor_drift_um;
    }
    case Prediction::kTemperature:
      if (std::isfinite(temp_c_) && std::isfinite(m.anchor_temp_c)) {
        // Bounded like a touch: a broken sensor cannot move the axis by more than a
        // recalibration could.
        const double delta = std::clamp(m.slope_um_per_c * (temp_c_ - m.anchor_temp_c),
                                        -config_.plausibility_um, config_.plausibility_um);
        return m.anchor_drift_um + delta;
      }
      return m.anchor_drift_um;
  }
  return m.anchor_drift_um;
}

double Calibrator::temperature_delta(std::size_t slot) const noexcept {
  const double d = input_[slot] - state_.nominals[slot].temp_c;
  const bool used = config_.estimator_slope_sigma_um_per_c > 0.0 ||
                    !std::isnan(config_.estimator_model_slope_um_per_c[slot]);
  if (!used || !std::isfinite(d)) {
    return 0.0;
  }
  // Bounded like the temperature model: a broken sensor cannot move the axis by more than a
  // recalibration could.
  const double max_slope = config_.max_temperature_slope_um_per_c;
  return std::clamp(d, -config_.plausibility_um / max_slope, config_.plausibility_um / max_slope);
}

EstimatedDrift Calibrator::estimate(std::size_t slot, double t_s) const noexcept {
  const auto& e = state_.estimates[slot];
  if (e.valid != 1 || state_.nominals[slot].valid != 1) {
    return {};
  }
  const double prior = prior_drift_um(state_.shifts, slot, t_s - state_.nominals[slot].time_s);
  return predict_estimate(e, prior, temperature_delta(slot), std::max(t_s, e.time_s),
                          estimator_params(config_, slot, state_.shifts));
}

EstimatedDrift Calibrator::estimated_drift(Slot slot, TimeNs now_ns) const noexcept {
  return estimate(static_cast<std::size_t>(slot), seconds(now_ns));
}

double Calibrator::level_noise_um_per_h(Slot slot) const noexcept {
  if (config_.prediction != Prediction::kEstimator) {
    return kNaN;
  }
  return estimator_params(config_, static_cast<std::size_t>(slot), state_.shifts)
      .level_noise_um_per_h;
}

bool Calibrator::level_noise_learned() const noexcept {
  // learned_level_noise_um_per_h() gives the configured value while no earlier shift has an
  // hour of drift (no increment weight).
  return config_.prediction == Prediction::kEstimator && config_.estimator_learn_level_noise &&
         state_.shifts.increment_weight > 0.0;
}

double Calibrator::correction(std::size_t slot, double t_s) const noexcept {
  const auto& m = state_.models[slot];
  if (m.anchored != 1) {
    return 0.0;
  }
  const auto& c = state_.creeps[slot];
  double f = 1.0;
  if (config_.creep_shape == ProfileShape::kStep || config_.creep_duration_s <= 0.0) {
    f = t_s > c.start_time_s ? 1.0 : 0.0;
  } else {
    f = profile_fraction(config_.creep_shape, (t_s - c.start_time_s) / config_.creep_duration_s);
  }
  return predict(slot, t_s) + c.offset_um * (1.0 - f);
}

double Calibrator::drift_correction_um(Slot slot, TimeNs now_ns) const noexcept {
  return correction(static_cast<std::size_t>(slot), seconds(now_ns));
}
double Calibrator::predicted_drift_um(Slot slot, TimeNs now_ns) const noexcept {
  return predict(static_cast<std::size_t>(slot), seconds(now_ns));
}
double Calibrator::target_um(std::size_t axis, TimeNs now_ns) const noexcept {
  if (grinding() && axis == 0) {
    return state_.grind_correction_um;
  }
  if (!base_valid() || axis >= kAxisCount) {
    return kNaN;
  }
  return base_um(axis) + correction(kAxisSlot[axis], seconds(now_ns));
}

// ------------------------------------------------------------------------------------------
// The cycle.

void Calibrator::step(TimeNs now_ns, std::span<const Event> events, StepOutput& out) noexcept {
  if (!configured_) {
    return;
  }
  const double now_s = seconds(now_ns);
  last_step_ns_ = now_ns;
  for (std::size_t a = 0; a < kAxisCount; ++a) {
    if (std::isfinite(pending_sync_[a])) {
      sync_register(a, pending_sync_[a], now_ns);
      pending_sync_[a] = kNaN;
    }
  }
  for (const Event& e : events) {
    if (const auto* touch = std::get_if<CalibrationTouch>(&e)) {
      handle_touch(*touch, now_s, now_ns, out);
    } else if (const auto* temp = std::get_if<TemperatureSample>(&e)) {
      const auto sensor = static_cast<std::int32_t>(temp->sensor);
      bool used = false;
      for (std::size_t s = 0; s < kSlotCount; ++s) {
        used = used || estimator_input_sensor(config_, s) == sensor;
      }
      if (sensor == config_.temperature_sensor || used) {
        if (std::isfinite(temp->temperature_c)) {
          if (sensor == config_.temperature_sensor) {
            temp_c_ = temp->temperature_c;
          }
          for (std::size_t s = 0; s < kSlotCount; ++s) {
            if (estimator_input_sensor(config_, s) == sensor) {
              input_[s] = temp->temperature_c;
            }
          }
        } else {
          out.alarm(now_ns, Severity::kWarning, AlarmCode::kCalibrationInvalidInput, -1,
                    temp->temperature_c);
        }
      }
    }
  }
  if (set_.open && now_s - set_.first_time_s > config_.touch_set_timeout_s) {
    const auto p = touch_progress();
    std::int32_t have = 0;
    for (const auto c : p.count) {
      have += c;
    }
    out.alarm(now_ns, Severity::kWarning, AlarmCode::kTouchSetIncomplete, -1, have);
    set_ = TouchSet{};
  }
  const double since_s = now_s - std::fmax(state_.last_set_time_s, last_attempt_s_);
  if (state_.phase == Phase::kReady && config_.recalibration_interval_s > 0.0 && !due_raised_ &&
      since_s >= config_.recalibration_interval_s) {
    out.alarm(now_ns, Severity::kInfo, AlarmCode::kRecalibrationDue, -1, since_s);
    due_raised_ = true;
  }
  write_registers(now_s, now_ns, out);
  write_request(now_ns, out);
}

void Calibrator::write_request(TimeNs now_ns, StepOutput& out) noexcept {
  if (config_.request_register < 0) {
    return;
  }
  const auto code = static_cast<std::int32_t>(request());
  // A flag: sent when it changes (the engine re-sends it after a reconnect).
  if (code != written_request_) {
    out.writes.push(OffsetWrite{now_ns, static_cast<std::uint16_t>(config_.request_register),
                                static_cast<double>(code)});
    written_request_ = code;
  }
}

void Calibrator::write_registers(double now_s, TimeNs now_ns, StepOutput& out) noexcept {
  const bool grind = grinding();
  if ((!base_valid() && !grind) || now_s - last_write_s_ < config_.write_period_s) {
    return;
  }
  last_write_s_ = now_s;
  const std::array<std::uint16_t, kAxisCount> reg{config_.register_x, config_.register_y,
                                                  config_.register_z};
  // A test grind is ground with its Δx in force on X; Y and Z keep what they hold.
  const std::size_t axes = grind ? 1 : kAxisCount;
  for (std::size_t a = 0; a < axes; ++a) {
    const double target =
        grind ? state_.grind_correction_um : base_um(a) + correction(kAxisSlot[a], now_s);
    const LimitResult r = limiters_[a].apply(target, now_ns);
    const auto subject = static_cast<std::int32_t>(reg[a]);
    // Alarms and warnings on the edge only: a held or slewed value persists for many cycles.
    if (r.rejected()) {
      if (!rejecting_[a]) {
        out.alarm(now_ns, Severity::kAlarm,
                  r.verdict == LimitVerdict::kRejectedNonFinite
                      ? AlarmCode::kOffsetNonFinite
                      : AlarmCode::kOffsetBeyondAbsoluteLimit,
                  subject, target);
      }
      rejecting_[a] = true;
      continue;
    }
    rejecting_[a] = false;
    const bool slewed = r.verdict == LimitVerdict::kSlewed;
    if (slewed && !slewing_[a]) {
      out.alarm(now_ns, Severity::kWarning, AlarmCode::kOffsetSlewLimited, subject, target);
    }
    slewing_[a] = slewed;
    if (!std::isfinite(written_um_[a]) ||
        std::fabs(r.value_um - written_um_[a]) >= config_.write_deadband_um) {
      out.writes.push(OffsetWrite{now_ns, reg[a], r.value_um});
      written_um_[a] = r.value_um;
    }
  }
}

void Calibrator::sync_register(std::size_t axis, double value_um, TimeNs now_ns) noexcept {
  if (axis < kAxisCount) {
    limiters_[axis].reset(value_um, now_ns);
    written_um_[axis] = limiters_[axis].output_um();
    pending_sync_[axis] = kNaN;  // what the NC holds now wins over a restored value
  }
}

void Calibrator::restore_written(std::size_t axis, double value_um) noexcept {
  if (axis < kAxisCount && std::isfinite(value_um)) {
    pending_sync_[axis] = value_um;
  }
}

bool Calibrator::rebase(std::size_t axis, double delta_um, TimeNs now_ns) noexcept {
  if (!configured_ || axis >= kAxisCount || !std::isfinite(delta_um) || !base_valid() ||
      (grinding() && axis == 0)) {
    return false;
  }
  const std::size_t slot = kAxisSlot[axis];
  auto& m = state_.models[slot];
  const double target = target_um(axis, now_ns);
  if (m.anchored != 1 || !std::isfinite(target) || !limiters_[axis].admissible(target + delta_um)) {
    return false;
  }
  m.anchor_drift_um += delta_um;
  m.asymptote_um += delta_um;
  // The temperature fit as if every drift it saw had been measured in the new split: its
  // intercept moves, its slope stays (cov(T, d + δ) = cov(T, d)).
  m.sum_d += delta_um * m.sum_w;
  m.sum_td += delta_um * m.sum_t;
  auto& e = state_.estimates[slot];
  if (e.valid == 1) {
    e.x[0] += delta_um;  // the level: mean = level + gain · prior + slope · ΔT
  }
  // What the NC holds moves with it (the engine moves the register's total by nothing): the
  // limiter must not slew S3's own value back.
  const double written = std::isfinite(written_um_[axis]) ? written_um_[axis] : target;
  sync_register(axis, written + delta_um, now_ns);
  return true;
}

// ------------------------------------------------------------------------------------------
// Persistence.

CalibState Calibrator::export_state() const noexcept {
  CalibState s = state_;
  shift_times(s, clock_offset_s_);
  return s;
}

void Calibrator::import_state(const CalibState& state) {
  validate(state);
  import_state_unchecked(state);
}

void Calibrator::import_state_unchecked(const CalibState& state) noexcept {
  CalibState s = state;
  shift_times(s, -clock_offset_s_);
  state_ = s;
  set_ = TouchSet{};
  last_write_s_ = -1e300;
  last_attempt_s_ = -1e300;
  due_raised_ = false;
  demand_ = false;
}

}  // namespace nccomp::core::calib
