// Plain-data state of the calibrator (calibration result, machine-probe nominals, drift models,
// creeps in progress, drift history), for persistence by the daemon: trivially copyable, no
// pointers. Times are seconds; Calibrator::export_state() gives them on the wall clock (Unix
// seconds) so that they survive a restart, in which the monotonic clock starts again.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>
#include <type_traits>

#include "core/common/types.hpp"

namespace nccomp::core::calib {

enum class Phase : std::uint8_t {
  kUncalibrated = 0,
  kReferenceTouches = 1,  // waiting for the reference-probe touches of the reference disk
  kTestGrindLateral = 2,  // waiting for facet chords of the lateral test grind (ΔxR)
  kTestGrindEndFace = 3,  // waiting for facet chords of the end-face test grind (ΔxA)
  kNominalTouches = 4,    // calibrated; waiting for the machine-probe nominal touches
  kReady = 5,             // nominals stored; machine-probe touches are recalibrations
};
const char* to_string(Phase phase) noexcept;

/// Touch slots: X is touched twice (across the stylus and along it, A rotated 90°), Y and Z once.
enum class Slot : std::uint8_t { kXLateral = 0, kXAxial = 1, kY = 2, kZ = 3 };
inline constexpr std::size_t kSlotCount = 4;
/// Corrected axes X, Y, Z and the slot that measures each.
inline constexpr std::size_t kAxisCount = 3;
inline constexpr std::array<std::size_t, kAxisCount> kAxisSlot{0, 2, 3};
inline constexpr std::size_t kHistorySize = 64;

/// Result of the initial calibration [µm]; axis corrections are what the NC adds to the axis.
struct CalibrationResult {
  /// From the reference-probe touches alone (trigger − nominal trigger).
  double dx_touch_lateral_um{kNaN};
  double dx_touch_axial_um{kNaN};
  double dy_touch_um{kNaN};
  double dz_touch_um{kNaN};
  /// After test grinding: ΔxR (lateral) and ΔxA (end face).
  double dx_r_um{kNaN};
  double dx_a_um{kNaN};
  /// ΔxR's probe correction applied to Y and Z.
  double dy_um{kNaN};
  double dz_um{kNaN};
  /// The reference probe's lateral / axial trigger deviation: ΔxR − Δx(lateral touch),
  /// ΔxA − Δx(axial touch).
  double probe_lateral_um{kNaN};
  double probe_axial_um{kNaN};
  /// Position of the stylus pivot point D along X relative to nominal: ΔxA − ΔxR.
  double pivot_um{kNaN};
  std::int32_t lateral_grinds{0};
  std::int32_t end_face_grinds{0};
  double time_s{kNaN};
};

/// One machine-probe nominal: mean trigger position of the nominal touches.
struct Nominal {
  std::int32_t valid{0};
  std::int32_t direction{1};
  double position_mm{kNaN};
  double time_s{kNaN};
  /// Mapped temperature at the nominal touches; NaN where no sensor is mapped.
  double temp_c{kNaN};
};

/// Drift model of one slot: anchored at the last touch, so each touch corrects the prediction.
struct DriftModel {
  std::int32_t anchored{0};
  std::int32_t touch_sets{0};
  double anchor_time_s{kNaN};
  double anchor_drift_um{0.0};
  double anchor_temp_c{kNaN};
  /// First-order model in time: drift → asymptote_um with the configured time constant.
  double asymptote_um{0.0};
  /// Linear model in temperature: d(drift)/dT [µm/°C], from a weighted least-squares fit.
  double slope_um_per_c{0.0};
  double sum_w{0.0};
  double sum_t{0.0};
  double sum_d{0.0};
  double sum_tt{0.0};
  double sum_td{0.0};
};

/// A creep in progress: the correction in force is prediction + offset · (1 − f(u)).
struct Creep {
  double start_time_s{kNaN};
  double offset_um{0.0};
};

struct HistoryEntry {
  double time_s{kNaN};
  double temp_c{kNaN};
  std::array<double, kSlotCount> drift_um{};
};

/// Knots of the earlier shifts' mean drift: every kPriorStepS after the nominals, up to 12 h.
inline constexpr std::size_t kPriorKnots = 24;
inline constexpr double kPriorStepS = 1800.0;
/// State of the drift estimator: x = [level, gain, slope].
inline constexpr int kEstimatorStates = 3;

/// Kalman estimate of one slot's drift (prediction = "estimator"): drift(t) = level +
/// gain · prior(t − nominal time) + slope · (T − T at the nominals).
struct DriftEstimate {
  std::int32_t valid{0};
  /// Time the state refers to (last touch set, or the nominals).
  double time_s{kNaN};
  std::array<double, kEstimatorStates> x{};
  /// Covariance, row-major.
  std::array<double, kEstimatorStates * kEstimatorStates> p{};
};

/// Drift of earlier shifts (one shift = from one nominal set to the next) at the knots
/// j · kPriorStepS (j = 1..kPriorKnots) after the nominals, per slot: exponentially weighted sums,
/// so sum / weight is the mean; and the shift in progress, folded in at the next nominals.
struct ShiftHistory {
  std::int32_t shifts{0};
  std::array<std::array<double, kPriorKnots>, kSlotCount> sum_um{};
  std::array<double, kPriorKnots> weight{};
  /// The shift in progress: its drift interpolated at the knots passed so far (linear between
  /// touch sets), and its last touch set (time since the nominals, drift per slot).
  std::int32_t current_knots{0};
  std::array<std::array<double, kPriorKnots>, kSlotCount> current_um{};
  double last_since_s{0.0};
  std::array<double, kSlotCount> last_drift_um{};
  // --- version 3 (appended) ---
  /// Increments of the earlier shifts' drift over each whole hour since their nominals (knot
  /// 2i + 1 minus knot 2i − 1, the shift start being 0), weighted like sum_um: the sum of their
  /// squares per slot, and their weight.
  std::array<double, kSlotCount> increment_sq_sum_um2{};
  double increment_weight{0.0};
};

struct CalibState {
  static constexpr std::int32_t kVersion = 3;
  std::int32_t version{kVersion};
  Phase phase{Phase::kUncalibrated};
  CalibrationResult result{};
  /// Δx of the test grind in progress and grinds so far on the current face.
  double grind_correction_um{kNaN};
  std::int32_t grinds{0};
  std::array<Nominal, kSlotCount> nominals{};
  std::array<DriftModel, kSlotCount> models{};
  std::array<Creep, kSlotCount> creeps{};
  std::array<HistoryEntry, kHistorySize> history{};
  std::int32_t history_count{0};
  std::int32_t history_next{0};
  double last_set_time_s{kNaN};
  // --- version 2 (appended, so a version-1 state is a prefix of the bytes) ---
  std::array<DriftEstimate, kSlotCount> estimates{};
  ShiftHistory shifts{};
};
static_assert(std::is_trivially_copyable_v<CalibState>);
/// Bytes of a version-1 CalibState (everything before `estimates`).
inline constexpr std::size_t kCalibStateV1Bytes = offsetof(CalibState, estimates);
/// Bytes of a version-2 CalibState (everything before the hourly increments).
inline constexpr std::size_t kCalibStateV2Bytes =
    offsetof(CalibState, shifts) + offsetof(ShiftHistory, increment_sq_sum_um2);
static_assert(kCalibStateV2Bytes + 5 * sizeof(double) == sizeof(CalibState));

/// Converts a version-1 state (version 1, version-2 fields at their defaults): the drift
/// history since the nominals becomes the shift in progress, so that it is folded into the
/// earlier shifts' drift at the next nominals. Sets the current version. Real-time safe.
void convert_from_v1(CalibState& state) noexcept;

/// Converts a version-2 state: no hourly increments known yet (the learned level noise starts
/// with the next shift that ends). Sets version 3. Real-time safe.
void convert_from_v2(CalibState& state) noexcept;

/// Adds delta_s to every time field (monotonic ↔ wall clock).
void shift_times(CalibState& state, double delta_s) noexcept;

/// Text form: one "key value" per line, header "nccomp_calib_state 1". Not real-time.
std::string to_text(const CalibState& state);
/// Parses the text form; throws std::invalid_argument naming the line and key. Every key must
/// be present exactly once; unknown keys are refused.
CalibState from_text(std::string_view text);
/// Semantic checks (ranges, finite values where required); throws std::invalid_argument.
void validate(const CalibState& state);
/// The same checks without allocating: nullptr if valid, else a static description naming the
/// key. Real-time safe.
const char* state_problem(const CalibState& state) noexcept;

}  // namespace nccomp::core::calib
