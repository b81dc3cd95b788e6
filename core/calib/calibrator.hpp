// Calibration and thermal recalibration of a grinding / EDM machine (S3).
//
// Lifecycle: configure() validates and may throw; everything afterwards is allocation-free.
// The machine side arrives as events through step() (CalibrationTouch, TemperatureSample); the
// operator side (start a calibration, enter the facet chords of a test grind) are plain method
// calls. The Calibrator is not thread-safe: the daemon calls the operator methods on the loop
// thread between two steps (they are allocation-free as well).
//
// Phases (see Phase): reference touches → lateral test grinds (ΔxR) → end-face test grinds (ΔxA)
// → machine-probe nominal touches → ready. In phase ready every complete set of machine-probe
// touches is a recalibration: drift = touch − nominal per axis, checked for scatter and
// plausibility, fed into a drift model (first-order in time or linear in temperature) whose
// prediction is the correction between touches; the step between the old and the new
// prediction is crept in with a core/common/profile.hpp shape, never applied at once.
//
// Output: the axis offset registers X/Y/Z carry base (calibration) + drift correction [µm],
// absolute values, through one OffsetLimiter per axis. During a test grind the X register carries
// the Δx to grind with (Y and Z keep their values). An optional request register (kind flag)
// carries the RequestCode of what the calibrator waits for, so that the NC or PLC can start the
// matching cycle (reference touches, test grind, nominal touches, a due or demanded
// recalibration).
//
// Touch positions are compared in machine coordinates. With touch_positions = "program" the NC
// reports machine − offset; the calibrator adds back the offset it wrote (what the NC holds), so
// that a correction in force does not read as drift and the corrections converge.
#pragma once

#include <array>
#include <cstdint>
#include <span>

#include "core/calib/config.hpp"
#include "core/calib/drift_estimator.hpp"
#include "core/calib/state.hpp"
#include "core/common/limiter.hpp"
#include "core/common/output.hpp"
#include "core/common/types.hpp"

namespace nccomp::core::calib {

/// Test-grind faces.
enum class Face : std::uint8_t { kLateral = 0, kEndFace = 1 };

enum class FacetStatus : std::uint8_t {
  kGrindAgain = 0,     // correction updated: grind again with grind_correction_um
  kConverged = 1,      // facets agree: the face's value is fixed
  kWrongPhase = 2,     // no test grind of this face is expected now
  kInvalidInput = 3,   // chords not finite or outside 0 < c ≤ 2ρ
  kNotConverging = 4,  // max_test_grinds reached or correction out of range: calibration ended
};
const char* to_string(FacetStatus status) noexcept;

struct FacetResult {
  FacetStatus status{FacetStatus::kWrongPhase};
  /// Position error inferred from this grind's facets by the configured rule [µm].
  double error_um{kNaN};
  /// Δ to use for the next grind (kGrindAgain) or the final value (kConverged) [µm].
  double correction_um{kNaN};
  /// Grinds on this face so far, this one included.
  std::int32_t grinds{0};
};

/// A touch set in progress (per slot: values and their count).
struct TouchProgress {
  std::array<std::int32_t, kSlotCount> count{};
  std::int32_t required{1};
};

class Calibrator {
 public:
  static constexpr std::size_t kMaxTouchesPerSlot = 8;

  /// Validates (throws std::invalid_argument naming the key) and stores the config. Keeps the
  /// calibration state (a config reload does not lose the calibration). Not real-time.
  void configure(const CalibrationConfig& config);
  [[nodiscard]] const CalibrationConfig& config() const noexcept { return config_; }

  /// Wall clock minus the monotonic clock of step()'s now_ns [s]; used by export / import.
  void set_clock_offset_s(double wall_minus_monotonic_s) noexcept;
  [[nodiscard]] double clock_offset_s() const noexcept { return clock_offset_s_; }

  /// Starts an initial calibration (discards the previous one; registers keep their values
  /// until the new calibration completes). Allocation-free.
  void begin_calibration(TimeNs now_ns, StepOutput& out) noexcept;
  /// Discards a touch set in progress. Allocation-free.
  void discard_touch_set() noexcept;
  /// On demand: asks the NC for a recalibration touch cycle now (request register →
  /// kRecalibration until the next touch set is evaluated). False, and nothing changes, unless
  /// the calibrator is ready. Allocation-free.
  bool request_recalibration() noexcept;
  /// One touch outside step() (an operator's typed touch); the same checks as a bus touch.
  /// Real-time safe.
  void enter_touch(const CalibrationTouch& touch, TimeNs now_ns, StepOutput& out) noexcept;
  /// Enters the two facet chords [mm] of a test grind: chord_plus from the facet ground from
  /// +X, chord_minus from −X. Allocation-free.
  FacetResult enter_facets(Face face, double chord_plus_mm, double chord_minus_mm, TimeNs now_ns,
                           StepOutput& out) noexcept;

  /// One cycle: consumes the events, updates the creeping corrections and writes the axis
  /// registers. Real-time safe: no allocation, no locks, no I/O.
  void step(TimeNs now_ns, std::span<const Event> events, StepOutput& out) noexcept;

  /// Tells the limiter of axis (0..2) what the NC's register holds now (start-up, read-back).
  void sync_register(std::size_t axis, double value_um, TimeNs now_ns) noexcept;
  /// The same when the time is not known (restoring a saved state): applied at the start of the
  /// next step(), at its time. Non-finite values are ignored. Real-time safe.
  void restore_written(std::size_t axis, double value_um) noexcept;

  /// Trim handover (core/engine/engine.hpp): a model's trim on axis (0..2) changed by −delta_um.
  /// The axis's drift model moves by delta_um in every prediction mode (the last measured
  /// drift, the asymptote, the temperature fit's intercept, the estimator's level), so its
  /// correction, the value written and the limiter move by exactly delta_um; the next touch set
  /// re-anchors the model on what it measures. With touch_positions = "program" that is the
  /// drift less the trim (the NC's offset holds both), so S3 learns the residual. False,
  /// nothing changed: not calibrated, X during a test grind, no touch set since the nominals,
  /// or a target the limiter refuses. Real-time safe.
  bool rebase(std::size_t axis, double delta_um, TimeNs now_ns) noexcept;

  /// State with times on the wall clock (set_clock_offset_s). Allocation-free.
  [[nodiscard]] CalibState export_state() const noexcept;
  /// Validates (throws std::invalid_argument) and adopts a state exported before a restart.
  void import_state(const CalibState& state);
  /// Adopts a state that passed state_problem() == nullptr. Real-time safe.
  void import_state_unchecked(const CalibState& state) noexcept;

  // --- inspection (allocation-free) ----------------------------------------------------------
  [[nodiscard]] Phase phase() const noexcept { return state_.phase; }
  [[nodiscard]] const CalibrationResult& result() const noexcept { return state_.result; }
  [[nodiscard]] const Nominal& nominal(Slot slot) const noexcept;
  [[nodiscard]] const DriftModel& model(Slot slot) const noexcept;
  /// Δx of the test grind in progress [µm].
  [[nodiscard]] double grind_correction_um() const noexcept { return state_.grind_correction_um; }
  [[nodiscard]] TouchProgress touch_progress() const noexcept;
  /// Drift correction in force for a slot at now_ns (prediction + creep) [µm].
  [[nodiscard]] double drift_correction_um(Slot slot, TimeNs now_ns) const noexcept;
  /// Predicted drift of a slot at now_ns (no creep) [µm].
  [[nodiscard]] double predicted_drift_um(Slot slot, TimeNs now_ns) const noexcept;
  /// The drift estimator's estimate of a slot at now_ns and its σ [µm] (NaN unless the
  /// estimator has a state: prediction = "estimator", nominals taken).
  [[nodiscard]] EstimatedDrift estimated_drift(Slot slot, TimeNs now_ns) const noexcept;
  /// The level noise the drift estimator uses for a slot now [µm/h]: learned from the earlier
  /// shifts' hourly increments (estimator_learn_level_noise, once an earlier shift has an hour
  /// of drift; clamped to the bounds), else estimator_level_noise_um_per_h. NaN unless
  /// prediction = "estimator". Real-time safe.
  [[nodiscard]] double level_noise_um_per_h(Slot slot) const noexcept;
  /// True when level_noise_um_per_h() is the learned value, false when it is the configured one
  /// (or prediction is not the estimator). Real-time safe.
  [[nodiscard]] bool level_noise_learned() const noexcept;
  /// Time of the last step() [ns] (0 before the first).
  [[nodiscard]] TimeNs last_step_ns() const noexcept { return last_step_ns_; }
  /// Register target of axis 0..2 (base + drift correction) [µm]; NaN before calibration.
  [[nodiscard]] double target_um(std::size_t axis, TimeNs now_ns) const noexcept;
  /// Last value written to axis 0..2 [µm] (NaN before the first write).
  [[nodiscard]] double written_um(std::size_t axis) const noexcept { return written_um_[axis]; }
  /// What the NC holds on axis 0..2 as far as the calibrator knows: the last value written or
  /// synced, 0 before any [µm]. Program-coordinate touches are corrected by it.
  [[nodiscard]] double offset_in_force_um(std::size_t axis) const noexcept;
  /// What the calibrator waits for (the request register's value).
  [[nodiscard]] RequestCode request() const noexcept;
  /// A recalibration was asked for (due by the schedule or on demand) and no set evaluated since.
  [[nodiscard]] bool recalibration_requested() const noexcept { return due_raised_ || demand_; }
  [[nodiscard]] double temperature_c() const noexcept { return temp_c_; }
  [[nodiscard]] const OffsetLimiter& limiter(std::size_t axis) const noexcept {
    return limiters_[axis];
  }

 private:
  struct TouchSet {
    std::array<std::array<double, kMaxTouchesPerSlot>, kSlotCount> value{};
    std::array<std::array<double, kMaxTouchesPerSlot>, kSlotCount> trigger_mm{};
    std::array<std::int32_t, kSlotCount> count{};
    std::array<std::int32_t, kSlotCount> direction{};
    bool open{false};
    double first_time_s{0.0};
  };

  void handle_touch(const CalibrationTouch& touch, double now_s, TimeNs now_ns,
                    StepOutput& out) noexcept;
  void evaluate_set(double now_s, TimeNs now_ns, StepOutput& out) noexcept;
  void evaluate_reference(TimeNs now_ns, StepOutput& out) noexcept;
  void evaluate_nominals(double now_s, TimeNs now_ns, StepOutput& out) noexcept;
  void evaluate_recalibration(double now_s, TimeNs now_ns, StepOutput& out) noexcept;
  void finish_calibration(double now_s, TimeNs now_ns, StepOutput& out) noexcept;
  void update_model(std::size_t slot, double t_s, double drift_um) noexcept;
  [[nodiscard]] double predict(std::size_t slot, double t_s) const noexcept;
  [[nodiscard]] double correction(std::size_t slot, double t_s) const noexcept;
  [[nodiscard]] EstimatedDrift estimate(std::size_t slot, double t_s) const noexcept;
  /// Mapped temperature minus the one at the slot's nominals, 0 unless the estimator uses it.
  [[nodiscard]] double temperature_delta(std::size_t slot) const noexcept;
  [[nodiscard]] double mean(std::size_t slot) const noexcept;
  [[nodiscard]] double scatter(std::size_t slot) const noexcept;
  [[nodiscard]] bool base_valid() const noexcept;
  [[nodiscard]] double base_um(std::size_t axis) const noexcept;
  void emit_records(TimeNs now_ns, StepOutput& out) const noexcept;
  void write_registers(double now_s, TimeNs now_ns, StepOutput& out) noexcept;
  void write_request(TimeNs now_ns, StepOutput& out) noexcept;
  [[nodiscard]] bool grinding() const noexcept;

  CalibrationConfig config_{};
  bool configured_{false};
  CalibState state_{};
  TouchSet set_{};
  double clock_offset_s_{0.0};
  double temp_c_{kNaN};
  /// Each slot's estimator input (estimator_input_sensor()): temp_c_'s sensor unless the slot
  /// has its own.
  std::array<double, kSlotCount> input_{kNaN, kNaN, kNaN, kNaN};
  TimeNs last_step_ns_{0};
  std::array<OffsetLimiter, kAxisCount> limiters_{};
  std::array<double, kAxisCount> written_um_{kNaN, kNaN, kNaN};
  std::array<bool, kAxisCount> slewing_{};
  std::array<bool, kAxisCount> rejecting_{};
  std::array<double, kAxisCount> pending_sync_{kNaN, kNaN, kNaN};
  double last_write_s_{-1e300};
  /// Last set evaluated in phase ready (accepted or refused): the schedule counts from it too.
  double last_attempt_s_{-1e300};
  std::int32_t written_request_{-1};  // -1: not written yet
  bool due_raised_{false};
  bool demand_{false};
};

}  // namespace nccomp::core::calib
