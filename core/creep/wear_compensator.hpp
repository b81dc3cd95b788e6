// Creeping wear correction (seeds.md S0, CN1835822): a measured tool wear is not applied as one
// step but fed in gradually along the cut path (or over time, or at a rate), per support point
// of the cutting edge, at the current engagement angle, along the surface normal.
//
// Lifecycle: configure() (not real-time: validates, may allocate, throws) → step() every loop
// cycle (real-time) → export_state() / import_state() for persistence and config reload.
//
// Sign conventions (see docs/creep.md):
// - wear and the correction c along the normal are positive when the tool must move INTO the
//   material (a worn tool is smaller);
// - axis offsets are −c·n (n = outward unit surface normal), so X/Y/Z offsets move the tool
//   toward the surface;
// - radius / length wear registers get tool_register_sign · (c·sinθ, c·cosθ), θ = engagement
//   angle from the tool axis;
// - entry, retract and transition offsets hold the tool AWAY from the surface (reduce c).
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

#include "core/common/limiter.hpp"
#include "core/common/output.hpp"
#include "core/common/types.hpp"
#include "core/creep/config.hpp"
#include "core/creep/state.hpp"
#include "core/estimation/kalman.hpp"

namespace nccomp::core::creep {

/// What is wrong with a state (field == nullptr: nothing). Plain data, so that checking a state
/// is real-time safe.
struct StateProblem {
  const char* field{nullptr};
  int index{-1};
};

/// Accepted measurements of a tool before its normalised innovations are judged (check_noise()).
inline constexpr std::uint32_t kNisMinCount = 10;

struct CreepCounters {
  std::uint64_t measurements_accepted{0};
  std::uint64_t measurements_refused{0};
  std::uint64_t creeps_folded{0};
  std::uint64_t creeps_superposed{0};
  std::uint64_t events_invalid{0};
  /// Measurements refused by the estimator's gate (also counted in measurements_refused).
  std::uint64_t measurements_gated{0};
  /// Axis samples that named another tool than the active one without a tool-change event.
  std::uint64_t implicit_tool_changes{0};
};

class WearCompensator {
 public:
  WearCompensator() = default;

  /// Validates (std::invalid_argument naming the TOML key) and stores the config; resets the
  /// state to a new tool with no wear. Not real-time.
  void configure(const CreepConfig& config);

  /// One loop cycle at time now_ns: consumes the events that arrived since the last cycle
  /// (AxisSample, ToolMeasurement, ToolChange, ProgramEvent; others are ignored) and appends
  /// offset writes, alarms and measurement records to out. Real-time safe: no allocation, no
  /// locks, no I/O; bounded work (events × support points × creeps).
  void step(TimeNs now_ns, std::span<const Event> events, StepOutput& out) noexcept;

  /// Plain-data copy of the state. Real-time safe.
  [[nodiscard]] CreepState export_state() const noexcept { return s_; }

  /// Resumes from a persisted state: validates it against the config (std::invalid_argument
  /// naming the field) and re-sends every offset on the next step. Not real-time.
  void import_state(const CreepState& state);

  /// The same without exceptions: false (and the state unchanged) if check_state() finds a
  /// problem. Real-time safe.
  bool restore_state(const CreepState& state) noexcept;
  /// The tool's motion between cycles (not state: a restart re-anchors on the first sample), for
  /// a reload's next engine (engine::Module::save_motion()). Bytes written: kMotionBytes, 0 if
  /// buf is too small. Real-time safe.
  std::size_t save_motion(std::span<std::byte> buf) const noexcept;
  /// Continues save_motion()'s bytes; false (nothing changed) if they are not valid. Called
  /// after restore_state() of the same engine's state: the channels' limiters go on from its
  /// channel outputs at the last step's time. Real-time safe.
  bool load_motion(std::span<const std::byte> bytes) noexcept;

  /// Checks a state against the current config. Real-time safe.
  [[nodiscard]] StateProblem check_state(const CreepState& state) const noexcept;

  /// States of the tools out of the spindle (persist them with export_state()). Real-time safe.
  [[nodiscard]] const ToolMemory& tool_memory() const noexcept { return memory_; }
  /// Restores them; false (memory unchanged) if a used slot's state fails check_state(), is of
  /// another tool than its slot says, or a tool appears twice. Real-time safe.
  bool restore_tool_memory(const ToolMemory& memory) noexcept;

  /// Start-up without a usable state (not real-time; before the first step): the NC holds
  /// value_um in channel ch's register. The channel's output starts there and stays there until
  /// the next accepted measurement, from which the difference fades out over one creep span
  /// (AdoptedOutputs). The fallback channel's value also sets the wear baseline (the uniform
  /// wear whose correction without a normal is that value, committed and measured), so the next
  /// measurement's increment is judged and crept from it. False (nothing changed) for an unused
  /// channel or a value the limiter refuses.
  bool adopt_channel(Channel ch, double value_um) noexcept;
  /// The same for a flag read back high: the warning (slot 0), alarm (1) and tool change (3)
  /// flags stay latched as if this module had raised them (acknowledge or a tool change clears
  /// them). False for the other slots (recomputed) and a flag read back low.
  bool adopt_flag(std::size_t slot, double value) noexcept;
  /// What was adopted and is still in force (persisted with the state). Real-time safe.
  [[nodiscard]] const AdoptedOutputs& adoption() const noexcept { return adopted_; }
  /// True while an adopted channel is held or fading out. Real-time safe.
  [[nodiscard]] bool adoption_active() const noexcept;
  /// Restores a saved adoption (validated by adoption_bytes_loadable()). Real-time safe.
  void restore_adoption(const AdoptedOutputs& a) noexcept { adopted_ = a; }

  /// Operator acknowledgement: clears the halt, the alarm and the warning flags and the hold of
  /// the "measurement due" request after a refused measurement (so an overdue measurement is
  /// asked for in the next step). Creeps resume where they were frozen. Real-time safe.
  void clear_alarm() noexcept;

  /// Start-up, after a state with the measurement request high was restored, when the NC still
  /// holds the request high (or cannot say): the request register is written 0 from the next
  /// step for request_rearm_s, then 1 again, so that an NC that reacts to the rising edge sees
  /// one and the measurement cycle cannot stick (docs/creep.md, "the request"). Nothing changes
  /// in the state; a measurement that arrives meanwhile ends it. No-op with request_rearm_s 0 or
  /// the request low. Real-time safe.
  void rearm_request() noexcept;
  /// True while the request register is held at 0 by rearm_request().
  [[nodiscard]] bool rearming() const noexcept { return rearm_; }

  // Observers (real-time safe), for status and tests.
  /// Wear in force at support point i now [µm] (committed + creeping + predicted).
  [[nodiscard]] double applied_wear_um(std::size_t i) const noexcept;
  /// Correction along the surface normal computed in the last step [µm] (positive = into part).
  [[nodiscard]] double correction_um() const noexcept { return correction_um_; }
  /// Lateral deflection compensation applied in the last step [µm] (0 when it had no direction).
  [[nodiscard]] double lateral_um() const noexcept { return lateral_um_; }
  /// Engagement angle used in the last step [deg]; NaN when the fallback (mean wear) was used.
  [[nodiscard]] double engagement_angle_deg() const noexcept { return engagement_deg_; }
  /// Target of a channel before the limiter in the last step [µm].
  [[nodiscard]] double channel_target_um(Channel c) const noexcept {
    return target_um_[static_cast<std::size_t>(c)];
  }
  /// Value the limiter let through in the last step [µm].
  [[nodiscard]] double channel_output_um(Channel c) const noexcept {
    return s_.channel_output_um[static_cast<std::size_t>(c)];
  }
  [[nodiscard]] std::size_t creeps_in_progress() const noexcept;
  /// The estimator's wear at support point i predicted to the current cut path [µm] and its
  /// standard deviation [µm]; false (both NaN) while it has no estimate (estimator off, or no
  /// measurement since it was switched on / the tool was loaded).
  bool wear_estimate(std::size_t i, double& wear_um, double& sigma_um) const noexcept;
  /// Mean normalised innovation square ν²/S of this tool's accepted measurements at support
  /// point i (1 when σ and the process noise fit the measurements); NaN before the first.
  [[nodiscard]] double nis_mean(std::size_t i) const noexcept;
  /// The measurement σ the residuals of this tool suggest: sqrt(mean(ν² − H·P⁻·Hᵀ)) at support
  /// point i [µm] (0 if that mean is negative); NaN before the first measurement.
  [[nodiscard]] double measurement_sigma_estimate_um(std::size_t i) const noexcept;
  /// Random-walk density of the wear rate the active tool's filter uses [(µm/mm)² per mm]: the
  /// family's when it started with it, else the configured rate_noise_um_per_mm_per_sqrt_m;
  /// with adapt_rate_noise, adapted since from the tool's innovations.
  [[nodiscard]] double rate_q() const noexcept;
  /// The family's estimate of that density (mean over its finished tools, ≥ 0); NaN without a
  /// finished tool.
  [[nodiscard]] double family_rate_q() const noexcept;
  /// The family's prior of a new tool's rate at support point i [µm/mm]: the mean of its
  /// finished tools' start rates and the spread of one more tool, s·sqrt(1 + 1/n) (s their
  /// sample standard deviation, n ≥ 2 tools); false (both NaN) with fewer than two tools or a
  /// spread of 0.
  bool family_rate_prior(std::size_t i, double& mean_um_per_mm,
                         double& sigma_um_per_mm) const noexcept;
  /// One finished tool's estimate of that density from its remembered measurements: the
  /// least-squares rate r at its last measurement, L mm into its life, (r² − σ²/Sxx)/L; NaN
  /// with fewer than three measurements. Real-time safe (at most kMaxRateWindow per point).
  [[nodiscard]] double finished_tool_rate_q(const CreepState& st) const noexcept;
  [[nodiscard]] double cut_path_mm() const noexcept { return s_.cut_path_mm; }
  /// Cut path at which the next measurement falls due [mm] (bases path and adaptive, and
  /// material with a constant cross-section; +inf otherwise): one interval after the last
  /// accepted measurement, and after a refused one while the request is held; +inf while halted.
  [[nodiscard]] double next_measurement_path_mm() const noexcept;
  /// Material removed by this tool [mm³] (counted with interval basis "material" only).
  [[nodiscard]] double removed_mm3() const noexcept { return s_.removed_mm3; }
  /// Removed material at which the next measurement falls due [mm³] (+inf unless "material",
  /// and while halted); after a refused measurement as next_measurement_path_mm().
  [[nodiscard]] double next_measurement_removed_mm3() const noexcept;
  /// Program path where a sister tool should restart [mm] (NaN if unknown).
  [[nodiscard]] double restart_program_path_mm() const noexcept;
  [[nodiscard]] bool halted() const noexcept { return s_.halted; }
  /// True if the last axis sample said the tool is cutting (and no interruption since); false
  /// also before the first sample after a restore (motion_known()).
  [[nodiscard]] bool cutting() const noexcept { return cutting_; }
  /// True once an axis sample has come since the state was restored (configure(),
  /// restore_state()): only then does cutting() tell what the tool does.
  [[nodiscard]] bool motion_known() const noexcept { return have_sample_; }
  /// True from a part start or end (ProgramEvent) until the next axis sample that cuts: no
  /// surface of a part is being cut. False after a restore until the next part event; a reload
  /// carries it (save_motion()).
  [[nodiscard]] bool between_parts() const noexcept { return between_parts_; }
  /// Sets it again after a restore_state() within the running process (the module's rebase,
  /// CreepModule::fade_out_shift(): the NC is still where it was). Real-time safe.
  void restore_between_parts(bool between) noexcept { between_parts_ = between; }
  [[nodiscard]] const CreepState& state() const noexcept { return s_; }
  [[nodiscard]] const CreepCounters& counters() const noexcept { return counters_; }
  [[nodiscard]] const CreepConfig& config() const noexcept { return config_; }

 private:
  void on_axis_sample(TimeNs now_ns, const AxisSample& a, StepOutput& out) noexcept;
  void on_measurement(TimeNs now_ns, const ToolMeasurement& m, StepOutput& out) noexcept;
  void on_tool_change(TimeNs now_ns, const ToolChange& c, StepOutput& out) noexcept;
  /// moving: the offset moves now (creeps in progress or a growing prediction): the new
  /// increment is then entered with zero slope, so the offset's slope stays continuous.
  void start_creep(const std::array<double, kMaxEdgePoints>& delta_um, bool moving, StepOutput& out,
                   TimeNs now_ns) noexcept;
  void start_entry(double offset_um, double length_mm) noexcept;
  void retire_finished_creeps() noexcept;
  void fit_rates() noexcept;
  /// With adapt_rate_noise, after an accepted measurement: moves the tool's rate_q by the mean
  /// NIS over the support points (estimation::adapt_process_noise()). Real-time safe.
  void adapt_rate_noise() noexcept;
  /// After an accepted measurement with the estimator: adds its normalised innovations to the
  /// tool's sums and raises kMeasurementNoiseInconsistent (once per tool) when their mean is
  /// beyond 3 standard deviations of a χ²(1) mean from 1, after kNisMinCount measurements.
  void check_noise(TimeNs now_ns, StepOutput& out) noexcept;
  /// Process noise of the filter over d_mm of cut path (config wear noise, rate_q()).
  [[nodiscard]] Eigen::Matrix2d estimator_noise(double d_mm) const noexcept;
  /// The estimator of support point i as saved, or (not yet valid) its prior from the last
  /// measured wear and the fitted rate at the last measurement's cut path.
  [[nodiscard]] estimation::KalmanFilter<2> estimator_at(std::size_t i,
                                                         double& path_mm) const noexcept;
  /// Cut path between two measurements [mm] (bases path and adaptive, and material with a
  /// constant cross-section; +inf otherwise).
  [[nodiscard]] double interval_path_mm() const noexcept;
  void check_measurement_due(TimeNs now_ns, StepOutput& out) noexcept;
  void compute_targets() noexcept;
  /// Holds the adopted channels, and fades their difference out after a measurement.
  void apply_adoption(std::array<double, kChannelCount>& target) noexcept;
  /// Clock span [mm or s] of a creep of `amount_um` on the configured basis.
  [[nodiscard]] double creep_span(double amount_um) const noexcept;
  void write_outputs(TimeNs now_ns, StepOutput& out) noexcept;
  void write_flag(TimeNs now_ns, std::int32_t reg, bool value, std::size_t slot,
                  StepOutput& out) noexcept;
  void halt(TimeNs now_ns, AlarmCode code, double value, StepOutput& out) noexcept;
  /// Creep clock of a slot now (creep path [mm] or creep time [s]).
  [[nodiscard]] double slot_clock(const CreepSlot& c) const noexcept;
  /// What a slot has fed in at point i now [µm] (0 at its start, delta_um at its end).
  [[nodiscard]] double slot_value_um(const CreepSlot& c, std::size_t i) const noexcept;
  /// Its slope at point i now [µm per unit of its clock].
  [[nodiscard]] double slot_slope(const CreepSlot& c, std::size_t i) const noexcept;
  [[nodiscard]] double predicted_um(std::size_t i) const noexcept;
  /// Slope of the predicted growth at point i now [µm/mm of path] (0 when capped or off).
  [[nodiscard]] double prediction_slope(std::size_t i) const noexcept;
  [[nodiscard]] bool predicting() const noexcept;
  [[nodiscard]] double entry_offset_um() const noexcept;
  [[nodiscard]] double transition_offset_um() const noexcept;
  [[nodiscard]] double deflection(double wear_um, bool lateral) const noexcept;
  [[nodiscard]] bool normal_now(std::array<double, 3>& n) const noexcept;
  /// Feed direction across the tool axis from two cutting samples (kept through axial moves).
  void update_feed_direction(const AxisSample& a) noexcept;
  /// Unit direction from the tool toward the material without a normal (material_side across
  /// the feed direction); false if no side is configured or no feed direction is known yet.
  [[nodiscard]] bool material_direction(std::array<double, 3>& m) const noexcept;
  /// Cumulative removed volume of the toolpath table at program position p [mm³] (constant
  /// cross-section outside its rows).
  [[nodiscard]] double toolpath_volume_mm3(double p) const noexcept;
  /// Material removed by a cut of d_mm from sample `from` to sample `to` [mm³].
  [[nodiscard]] double removal_mm3(const AxisSample& from, const AxisSample& to,
                                   double d_mm) const noexcept;
  /// Selects the active tool's deflection table and transitions, and derives its interval.
  void select_tool_tables() noexcept;
  /// Interval basis uncertainty: the path after the last measurement at which the estimate's
  /// σ reaches max_sigma_um (within the limits), kept in uncertainty_interval_mm_: it changes
  /// only with the estimator's state, so it is not searched in every cycle.
  void update_uncertainty_interval() noexcept;

  CreepConfig config_{};
  ProfileTable table_{};
  /// Cumulative removed volume at each toolpath row [mm³] (removal_source = toolpath).
  std::vector<double> removal_cum_mm3_;
  std::size_t points_{1};
  CreepState s_{};
  ToolMemory memory_{};
  AdoptedOutputs adopted_{};
  /// A measurement was accepted while channels are held: the fade starts in compute_targets().
  bool fade_pending_{false};
  CreepCounters counters_{};
  /// The estimators after the update of the measurement being judged (stored only if accepted).
  std::array<estimation::KalmanFilter<2>, kMaxEdgePoints> estimate_scratch_{};
  /// Their ν²/S, ν² − H·P⁻·Hᵀ [µm²] and H·P⁻·Hᵀ/S (added to the state only if accepted).
  std::array<double, kMaxEdgePoints> nis_scratch_{};
  std::array<double, kMaxEdgePoints> residual_scratch_{};
  std::array<double, kMaxEdgePoints> prior_fraction_scratch_{};
  std::array<OffsetLimiter, kChannelCount> limiters_{};

  // Kinematics of the last axis sample (not persisted: re-anchored by the first sample; a reload
  // carries them, save_motion()).
  bool have_sample_{false};
  bool cutting_{false};
  bool interrupted_{false};
  bool between_parts_{false};
  AxisSample last_sample_{};
  std::array<double, 3> feed_dir_{};
  bool have_feed_{false};
  TimeNs last_now_ns_{0};
  bool have_now_{false};
  // rearm_request(): the request register is written 0 until rearm_until_ns_ (set at the first
  // step after it was asked for).
  bool rearm_{false};
  bool rearm_started_{false};
  TimeNs rearm_until_ns_{0};
  int deflection_index_{-1};
  double uncertainty_interval_mm_{0.0};
  std::array<std::uint8_t, kMaxTransitions> transition_index_{};
  std::size_t transition_count_{0};

  // Results of the last step.
  double correction_um_{0.0};
  double lateral_um_{0.0};
  double engagement_deg_{kNaN};
  std::array<double, kChannelCount> target_um_{};
  std::array<double, kChannelCount> written_um_{};
  std::array<TimeNs, kChannelCount> written_ns_{};
  std::array<bool, kChannelCount> written_once_{};
  std::array<LimitVerdict, kChannelCount> last_verdict_{};
  // Flag registers: warning, alarm, measurement due, tool change, restart path.
  static constexpr std::size_t kFlagSlots = 5;
  std::array<double, kFlagSlots> flag_written_{};
  std::array<bool, kFlagSlots> flag_written_once_{};
  std::array<TimeNs, kFlagSlots> flag_written_ns_{};
};

}  // namespace nccomp::core::creep
