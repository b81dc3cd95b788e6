// Per-checkpoint compensation of side-wall finishing (S1): learned probe errors per checkpoint,
// written in machining order into consecutive NC offset registers, and applied to the finishing
// tool's radius wear when the tool reaches each checkpoint — as a step (the seed) or creeping
// along the path between checkpoints (S0's profiles), so the checkpoints leave no steps.
// Creep stays within a level: on a closed contour it ramps from the level's last checkpoint
// through the seam to the level's first, so the pass meets itself with the same value; between
// levels (the level link) it ramps from one level's seam value to the next one's.
//
// Sign convention (µm, along the wall's air-side normal):
//   δ'  > 0: the wall stands proud of nominal (material left, e.g. push-off).
//   c   > 0: radius wear that moves the tool away from the wall (leaves c more material).
// A surface cut with offset c shows δ' = e + c, where e is the error without compensation, so
// each measurement estimates e = δ' − c_applied, and the offset that cancels it is c = −e.
//
// Lifecycle: configure() validates and allocates (not real-time); step() is real-time;
// export_state() / import_state() / reconcile() are for persistence and start-up (not real-time).
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

#include "core/checkpoint/plan.hpp"
#include "core/common/limiter.hpp"
#include "core/common/output.hpp"
#include "core/common/profile.hpp"
#include "core/common/types.hpp"
#include "core/engine/input_snapshot.hpp"

namespace nccomp::core::engine {
class TrimChange;
}  // namespace nccomp::core::engine

namespace nccomp::core::checkpoint {

/// (A) learn from the previous part's finishing (push-off) → next part;
/// (B) learn from semi-finishing with the paired tool → finishing of the same part.
enum class LearningMode : std::uint8_t { kPreviousPart = 0, kSemiFinishing = 1 };
/// How the values reach the wall: kTable = the NC program selects each checkpoint's offset
/// itself (no live register: active_register = −1); kStep / kCreep = the daemon drives the
/// live radius wear register (active_register ≥ 0), switching at each checkpoint or creeping.
enum class ApplyMode : std::uint8_t { kStep = 0, kCreep = 1, kTable = 2 };
/// How a checkpoint is recognised while finishing: by the program path position the NC
/// publishes, or by the tool centre passing within xy_tolerance_mm in XY and z_band_mm in Z.
enum class TriggerMode : std::uint8_t { kPath = 0, kPosition = 1 };
/// After a restart, which side wins where the NC's registers and the learned table differ.
enum class ReconcilePrefer : std::uint8_t { kDaemon = 0, kNc = 1 };

/// Depth of the per-checkpoint history used by the k·σ outlier rule.
inline constexpr std::size_t kHistoryDepth = 16;
/// Table registers written per step at most (StepOutput holds 128 writes shared with others).
inline constexpr std::size_t kTableWritesPerStep = 32;

/// `[checkpoints.estimator]` (docs/estimation.md, "S1"): mode A learns each checkpoint's
/// deviation with a Kalman filter of a random walk instead of the fixed-weight EWMA, so the
/// weight of a new reading (the gain) follows how much that checkpoint really varies from part to
/// part.
struct CheckpointEstimatorConfig {
  bool enabled{false};
  /// Standard deviation of one reading around the deviation that carries over to the next part
  /// [µm]: the probe's repeatability, plus the part's own scatter where it does not carry over.
  double measurement_sigma_um{1.0};
  /// The deviation's random walk: standard deviation of its change from one part to the next
  /// [µm]. Used until learned (or always, with learn_part_noise = false).
  double part_noise_um{1.0};
  /// Learn the part noise per checkpoint from its history: q = mean(Δe²) − 2σ², at least 0.
  bool learn_part_noise{true};
  /// Accepted readings in the checkpoint's history before the learned part noise is used.
  std::uint32_t learn_min_parts{5};
  /// A reading beyond gate_sigmas standard deviations of the predicted innovation is not learned
  /// (warning 31); 0 = no gate.
  double gate_sigmas{5.0};
};

/// The `[checkpoints]` keys of the daemon's config, one member per key (docs/checkpoints.md).
/// The plan keys (contour, levels, …) are in PlanConfig.
struct CompensatorConfig {
  LearningMode learning_mode{LearningMode::kPreviousPart};
  /// Tool numbers: the finishing tool (offsets applied while it is active) and, for mode B, the
  /// paired semi-finishing tool (informational: its probing is what the measurements are).
  std::int32_t finishing_tool{1};
  std::int32_t semi_finishing_tool{0};
  /// Logical register index of checkpoint 0's value; checkpoint i goes to register_base + i.
  std::uint16_t register_base{20};
  /// Logical register of the finishing tool's radius wear written live while finishing, or −1:
  /// table only (the NC program selects the offset number at each checkpoint itself).
  std::int32_t active_register{-1};
  /// kTable exactly when active_register = −1 (configure() refuses the other combinations).
  ApplyMode apply{ApplyMode::kTable};
  ProfileShape creep_shape{ProfileShape::kLinear};
  TriggerMode trigger{TriggerMode::kPath};
  double xy_tolerance_mm{0.5};
  double z_band_mm{1.0};
  /// EWMA weight k ≥ 1 of M_i = M_{i−1} + (E_i − M_{i−1})/k (k = 1: the last part only). Mode A
  /// only: mode B applies each blank's own reading (M_i = E_i), never earlier blanks'.
  double ewma_weight{3.0};
  /// No offset change smaller than this [µm].
  double dead_band_um{1.0};
  /// Fraction of the error applied per update, (0, 1]. Mode A: c ← c + f·(−M − c); mode B:
  /// c = −f·E (a fraction of this blank's error, nothing of the previous blank's offset).
  double feedback{1.0};
  /// |δ'| above this [µm] is implausible: alarm, nothing learned.
  double plausible_um{200.0};
  /// A measurement deviating more than outlier_sigma·σ from its checkpoint's history (with at
  /// least outlier_min_history entries) is logged, not learned. σ is floored at the repeatability.
  double outlier_sigma{3.0};
  std::uint32_t outlier_min_history{4};
  /// Offsets smaller in magnitude than the probe's repeatability [µm] are written as 0.
  double probe_repeatability_um{1.0};
  /// Smallest change of the live register that is sent [µm] (bounds the bus load at 1 kHz).
  double write_threshold_um{0.1};
  /// Read-back agreement tolerance [µm] and the winner on disagreement.
  double reconcile_tolerance_um{0.5};
  ReconcilePrefer reconcile_prefer{ReconcilePrefer::kDaemon};
  CheckpointEstimatorConfig estimator{};
};

/// Learned values of one checkpoint (plain data, for persistence).
struct LearnedPoint {
  /// EWMA M (with the estimator: the filter's estimate) of the uncompensated error e [µm] and the
  /// number of measurements in it.
  double learned_um{0.0};
  std::uint32_t count{0};
  /// Estimator: the variance of learned_um [µm²] and the readings the filter absorbed since it
  /// started (0: it starts at the next reading from learned_um with the variance σ²).
  double variance_um2{0.0};
  std::uint32_t filter_n{0};
  /// Offset c [µm] (before the repeatability rule).
  double offset_um{0.0};
  /// The offset the current part's wall was cut with at this checkpoint [µm]: the table value at
  /// part start, replaced, with a live register, by the live register's value as the limiter
  /// let it through in the cycle the checkpoint triggered (a slewing register cuts with less
  /// than its target). Persisted: a restart between finishing and probing must still subtract
  /// what that part was cut with.
  double applied_um{0.0};
  /// Accepted e values, oldest first; history_n valid entries.
  std::array<double, kHistoryDepth> history{};
  std::uint32_t history_n{0};
  /// The model inputs (the engine's machine context: tool, cut path, time, temperatures,
  /// position) when this checkpoint's wall was last cut, and the trims on the register it was
  /// cut with then [µm]; NaN: not known (no context, no trim source, or a state of an earlier
  /// layout: 3 has the tool and cut path only). A trim handover takes the change of trim at
  /// these inputs, where the last reading was cut.
  engine::InputSnapshot cut_inputs{};
  double cut_trim_um{kNaN};
};

/// Persisted state. version guards the layout (4: with the inputs and trims of each checkpoint's
/// last cut; 3 with its tool and cut path only; 2 without them (not known); 1 without the
/// estimator's variance too (the filter starts at the next reading)); checkpoint_count guards
/// against a changed plan.
struct CheckpointState {
  std::uint32_t version{4};
  std::int64_t part_counter{0};
  std::int32_t part{0};
  std::vector<LearnedPoint> points;
};

struct ReconcileReport {
  std::size_t compared{0};
  std::size_t mismatched{0};
  double max_difference_um{0.0};
  /// Checkpoint ids that differed (first 32).
  std::vector<std::int32_t> mismatched_ids;
  /// True when the NC's values were adopted, false when the daemon's will be rewritten.
  bool adopted_nc{false};
  /// Mismatched registers the table will write again: all of them with prefer = daemon; with
  /// prefer = nc those whose read-back could not be adopted (non-finite, beyond the limit).
  std::size_t rewritten{0};
};

struct CompensatorCounters {
  std::uint64_t measurements{0};
  std::uint64_t updates{0};
  std::uint64_t dead_band_skips{0};
  std::uint64_t implausible{0};
  std::uint64_t outliers{0};
  std::uint64_t invalid{0};
  std::uint64_t beyond_limit{0};
  std::uint64_t triggers{0};
  std::uint64_t missed{0};
  std::uint64_t table_writes{0};
  std::uint64_t live_writes{0};
};

class CheckpointCompensator {
 public:
  CheckpointCompensator() = default;

  /// Validates the config (throws core::ConfigInvalid with every refused key,
  /// "checkpoints.<key>") and allocates all state for the plan's checkpoints. Learned values start
  /// at zero. Not real-time.
  void configure(const CompensatorConfig& config, std::vector<Checkpoint> plan,
                 const LimiterConfig& limits);

  /// Processes the events of one cycle at time now_ns and appends offset writes, alarms and
  /// contour measurement records to out. Real-time safe: no allocation, no locks, no I/O.
  void step(TimeNs now_ns, std::span<const Event> events, StepOutput& out) noexcept;

  /// Copies the learned state into out (reuses out's capacity). Not real-time.
  void export_state(CheckpointState& out) const;
  /// Replaces the learned state; throws std::invalid_argument when it does not fit the plan or
  /// holds non-finite values (nothing changes then). Marks the table for rewriting. Not real-time.
  void import_state(const CheckpointState& state);
  /// Real-time safe form of import_state for binary state (core/checkpoint/module.hpp): checks
  /// and copies without allocating; false (nothing changed) if a point is not valid.
  bool restore_point(std::size_t i, const LearnedPoint& point) noexcept;
  /// Why a point cannot be restored (nullptr = it can). Real-time safe.
  [[nodiscard]] const char* invalid_point_reason(const LearnedPoint& point) const noexcept;
  /// Sets the part counters and marks the whole table for rewriting. Real-time safe.
  void restore_counters(std::int64_t part_counter, std::int32_t part) noexcept;
  /// Advances whenever learned values, offsets or the part changed. Real-time safe.
  [[nodiscard]] std::uint64_t generation() const noexcept { return generation_; }

  /// Compares the values read back from the NC's registers (machining order, one per
  /// checkpoint) with the table. Differences beyond reconcile_tolerance_um: with prefer = daemon
  /// the table is rewritten on the next step; with prefer = nc the NC's values become the
  /// offsets. Either way an alarm 33 is raised on the next step. Not real-time.
  ReconcileReport reconcile(std::span<const double> nc_values_um);

  /// Starts the live register's limiter from the value the NC holds (read back at start-up or
  /// after a reconnect) instead of 0. Not real-time.
  void reset_live(double nc_value_um, TimeNs now_ns) noexcept;
  /// Start-up without a state: checkpoint i's offset (and the value its wall is cut with) becomes
  /// what the NC holds, so the table is not rewritten from zeros; the next measurement is
  /// learned against it. False (nothing changed) for a value the limiter refuses. Not real-time.
  bool adopt_register_value(std::size_t i, double nc_value_um) noexcept;

  /// Trim handover (core/engine/engine.hpp): another module's trim on these values changed by
  /// −delta_um. Checkpoints first … last (the live register: all of them) move their offset and
  /// the value their wall was cut with by delta_um, and what they learned (the error left for
  /// them, its history) by −delta_um, so the learning continues on the residual; the live value
  /// and its limiter move with them (no slew of S1's own). Mode A then takes the last part's
  /// error less the trim as the residual (the average lagged the trend the trim now predicts)
  /// and updates the offset from it as a probe would (feedback, dead band): the register moves
  /// at S1's next write, through the limiter. The history is cleared and the next reading
  /// counts in full (as a first one): the errors before belong to another split of the
  /// compensation. False, nothing changed, if an offset would leave the absolute limit.
  /// With `along` (mode A), the residual of a checkpoint whose last cut inputs are known takes
  /// the change of trim at those inputs instead of delta_um: the new trims at cut_inputs less
  /// the trims it was cut with (cut_trim_um if cut_trim_known, else the old trims at the
  /// switch). The last part's checkpoints were cut before the switch, at another path,
  /// temperature and time. Real-time safe.
  bool rebase(std::size_t first, std::size_t last, double delta_um, TimeNs now_ns,
              const engine::TrimChange* along = nullptr, bool cut_trim_known = false) noexcept;
  /// The checkpoints [first, last) the last step() saw the tool cut (not those counted at a
  /// part's first sample or after a program restart). Real-time safe.
  [[nodiscard]] std::size_t cut_first() const noexcept { return cut_first_; }
  [[nodiscard]] std::size_t cut_last() const noexcept { return cut_last_; }
  /// Records checkpoint i's cut: the inputs and the trims it was cut with. Real-time safe.
  void record_cut(std::size_t i, const engine::InputSnapshot& inputs, double trim_um) noexcept {
    points_[i].cut_inputs = inputs;
    points_[i].cut_trim_um = trim_um;
  }

  /// The value of checkpoint i's register [µm] (after the repeatability rule).
  [[nodiscard]] double register_value_um(std::size_t i) const noexcept;
  [[nodiscard]] double learned_um(std::size_t i) const noexcept { return points_[i].learned_um; }
  [[nodiscard]] std::uint32_t learned_count(std::size_t i) const noexcept {
    return points_[i].count;
  }
  [[nodiscard]] std::size_t size() const noexcept { return plan_.size(); }
  /// Checkpoints passed by the finishing tool in the current part.
  [[nodiscard]] std::size_t passed() const noexcept { return next_; }
  /// The live radius wear target [µm] of the last sample (NaN before finishing started).
  [[nodiscard]] double live_target_um() const noexcept { return live_target_um_; }
  /// The value the live register holds (last write after the limiter) [µm]; NaN before the
  /// first write.
  [[nodiscard]] double live_written_um() const noexcept { return live_written_um_; }
  /// The checkpoint of the last event (probe reading or trigger), −1 before any. Real-time safe.
  [[nodiscard]] std::int32_t focus_checkpoint() const noexcept { return focus_; }
  /// The live target at the start of the first level's pass (what the register is pre-positioned
  /// to before finishing) [µm].
  [[nodiscard]] double start_value_um() const noexcept;
  [[nodiscard]] bool table_pending() const noexcept { return dirty_count_ > 0; }
  [[nodiscard]] const CompensatorCounters& counters() const noexcept { return counters_; }
  [[nodiscard]] const CompensatorConfig& config() const noexcept { return config_; }
  [[nodiscard]] const std::vector<Checkpoint>& plan() const noexcept { return plan_; }
  [[nodiscard]] std::int64_t part_counter() const noexcept { return part_counter_; }
  [[nodiscard]] std::int32_t part() const noexcept { return part_; }
  [[nodiscard]] const LearnedPoint& point(std::size_t i) const noexcept { return points_[i]; }
  /// Estimator: the part-to-part variance q [µm²] checkpoint i's filter uses now (learned from
  /// its history or part_noise_um²). Real-time safe.
  [[nodiscard]] double part_noise_var_um2(std::size_t i) const noexcept;
  /// Estimator: the standard deviation of learned_um as the prediction of the next part's error,
  /// sqrt(P + q) [µm]; NaN before the first reading or with the estimator off. Real-time safe.
  [[nodiscard]] double predicted_sigma_um(std::size_t i) const noexcept;
  /// Estimator: the weight the next reading at checkpoint i gets, (P + q) / (P + q + σ²) (1 before
  /// the first reading; NaN with the estimator off). Real-time safe.
  [[nodiscard]] double next_gain(std::size_t i) const noexcept;

 private:
  void on_part_start(TimeNs now_ns, const ProgramEvent& ev) noexcept;
  void on_probe(const ProbeMeasurement& m, StepOutput& out) noexcept;
  void on_sample(const AxisSample& s, StepOutput& out) noexcept;
  bool detect_path(const AxisSample& s) noexcept;
  bool detect_position(const AxisSample& s, StepOutput& out) noexcept;
  [[nodiscard]] bool passes(std::size_t i, const AxisSample& s) const noexcept;
  [[nodiscard]] bool in_band(std::size_t level, const AxisSample& s) const noexcept;
  [[nodiscard]] double target_value_um(const AxisSample& s) const noexcept;
  [[nodiscard]] double path_target_um(double path_mm) const noexcept;
  [[nodiscard]] double position_target_um(const AxisSample& s) const noexcept;
  /// The value on level l's pass: after checkpoint k of the level (kNone = before its first)
  /// and done_mm further along the contour.
  [[nodiscard]] double level_value_um(std::size_t l, std::size_t k, double done_mm) const noexcept;
  [[nodiscard]] double level_end_value_um(std::size_t l) const noexcept;
  [[nodiscard]] double level_start_value_um(std::size_t l) const noexcept;
  [[nodiscard]] double ramp(double from_um, double to_um, double u) const noexcept;
  void flush_table(TimeNs now_ns, StepOutput& out) noexcept;
  void preposition(TimeNs now_ns, StepOutput& out) noexcept;
  void write_live(double target_um, TimeNs now_ns, StepOutput& out) noexcept;
  void mark_dirty(std::size_t i) noexcept;

  /// One level of the plan: its checkpoints first..last, where its pass starts on the program
  /// path, its length (0 = unknown) and whether it is closed.
  struct Level {
    std::size_t first{0};
    std::size_t last{0};
    double start_path_mm{0.0};
    double length_mm{0.0};
    bool closed{false};
    double z_mm{0.0};
  };
  static constexpr std::size_t kNone = static_cast<std::size_t>(-1);

  CompensatorConfig config_{};
  std::vector<Checkpoint> plan_;
  std::vector<Level> levels_;
  std::vector<LearnedPoint> points_;
  std::vector<std::uint8_t> dirty_;
  std::size_t dirty_count_{0};
  std::size_t dirty_cursor_{0};
  OffsetLimiter limiter_;
  std::int64_t part_counter_{0};
  std::int32_t part_{0};
  std::int32_t tool_{0};
  // Trigger tracking for the current part.
  std::size_t next_{0};
  bool have_prev_{false};
  AxisSample prev_{};
  /// Path travelled since the last trigger [mm] (trigger = position: the creep's progress).
  double travel_since_mm_{0.0};
  std::size_t cut_first_{0};
  std::size_t cut_last_{0};
  /// trigger = position: the level whose Z band the tool is in before that level's first
  /// checkpoint (kNone: none), and its XY travel since it entered the band [mm] (≈ the contour
  /// position on that level's pass).
  std::size_t band_level_{kNone};
  double travel_in_band_mm_{0.0};
  std::int32_t focus_{-1};
  double live_target_um_{kNaN};
  double live_written_um_{kNaN};
  /// Part started, finishing not yet: the live register is pre-positioned to checkpoint 0.
  bool awaiting_finish_{false};
  std::size_t pending_mismatch_{0};
  std::uint64_t generation_{0};
  CompensatorCounters counters_{};
};

const char* learning_mode_name(LearningMode m) noexcept;
const char* apply_mode_name(ApplyMode m) noexcept;
const char* trigger_mode_name(TriggerMode m) noexcept;

}  // namespace nccomp::core::checkpoint
