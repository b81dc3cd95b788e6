// Plain-data state of the creeping wear correction, for persistence across restarts and for
// carrying state over a config reload. Offsets are absolute values computed from this state, so
// resuming from it never applies a correction twice.
#pragma once

#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <type_traits>

#include "core/common/types.hpp"
#include "core/creep/config.hpp"

namespace nccomp::core::creep {

/// One wear increment creeping in, per edge support point.
///
/// Value at point i, t = clock − start (clock: creep path [mm] or creep time [s]):
///   v(t) = (delta − s·l/2) · f(g(t / span)) + s · c(t),   c(t) = t − t²/(2l) for t < l, l/2 after
/// with f the profile, g(u) = u, or the eased progress (zero slope at u = 0) when `eased`, and
/// s = carry_slope, l = carry_span (a slope carried over from a creep folded into this one, faded
/// out over l). v(0) = 0, v(end) = delta; the slope at t = 0 is s (eased or zero-slope profiles),
/// so a creep started while the offset moves continues it without a kink.
struct CreepSlot {
  bool active{false};
  /// Progress is counted in cut path [mm] (path, rate-per-path bases) or cutting time [s].
  bool path_based{true};
  /// The profile is entered with zero slope (a creep started while the offset was moving).
  bool eased{false};
  /// Order of creation (the oldest is folded first when all slots are busy).
  std::uint64_t seq{0};
  /// Creep clock (path [mm] or time [s]) when the creep began.
  double start{0.0};
  /// Increment to feed in [µm] and the clock span over which it is fed [mm or s], per point.
  std::array<double, kMaxEdgePoints> delta_um{};
  std::array<double, kMaxEdgePoints> span{};
  /// Slope carried over from a folded creep [µm per mm or per s] and the clock span over which
  /// it fades out (0 = none), per point.
  std::array<double, kMaxEdgePoints> carry_slope{};
  std::array<double, kMaxEdgePoints> carry_span{};
};

/// A scalar offset away from the surface that creeps to zero along the path: sister-tool entry
/// or retract / re-feed.
struct EntrySlot {
  bool active{false};
  double start_path_mm{0.0};
  double offset_um{0.0};
  double length_mm{0.0};
};

/// One accepted measurement kept for fitting the wear rate.
struct HistoryEntry {
  double cut_path_mm{0.0};
  std::array<double, kMaxEdgePoints> wear_um{};
};

/// The tool family's learned process noise (issue 22): every tool of this module is of one
/// family; a finished tool (replaced by a sister) adds its estimate of the rate's random-walk
/// density, WearCompensator::finished_tool_rate_q().
struct FamilyNoise {
  /// Finished tools that gave an estimate.
  std::uint32_t tools{0};
  /// Sum of their estimates [(µm/mm)² per mm of cut path].
  double rate_q_sum{0.0};
};

/// The tool family's learned prior of a new tool's wear rate (issue 22, version 6): every
/// finished tool adds its start rate (CreepState::start_sxw / start_sxx) per support point,
/// Welford's running mean and sum of squared deviations.
struct FamilyRate {
  /// Finished tools that gave a start rate.
  std::uint32_t tools{0};
  /// Mean of their start rates [µm/mm] and the sum of squared deviations from it [(µm/mm)²].
  std::array<double, kMaxEdgePoints> rate_mean_um_per_mm{};
  std::array<double, kMaxEdgePoints> rate_m2{};
};

struct CreepState {
  static constexpr std::uint32_t kVersion = 6;
  std::uint32_t version{kVersion};
  /// Edge support points the state was built with (must match the config on import).
  std::uint32_t edge_points{1};
  std::int32_t tool{0};
  std::int32_t part{0};

  /// Cut path [mm] and cutting time [s] of this tool since it was loaded (logs, intervals).
  double cut_path_mm{0.0};
  double cut_time_s{0.0};
  /// The same, but frozen while halted: the clocks that drive creeps and the prediction.
  double creep_path_mm{0.0};
  double creep_time_s{0.0};

  /// Wear fully in force [µm] (finished creeps, committed predictions), per point.
  std::array<double, kMaxEdgePoints> committed_um{};
  /// Last accepted measured total wear [µm], per point.
  std::array<double, kMaxEdgePoints> measured_um{};
  /// Fitted wear rate [µm/mm of cut path], per point; valid if rate_known.
  std::array<double, kMaxEdgePoints> rate_um_per_mm{};
  bool rate_known{false};
  /// Predictive creeping: the predicted growth rate in force just before the last measurement
  /// [µm/mm], per point, and the cut path over which the prediction's rate blends from it to the
  /// newly fitted rate [mm] (so the prediction's slope has no jump at a measurement).
  std::array<double, kMaxEdgePoints> rate_prev_um_per_mm{};
  double rate_blend_mm{0.0};

  /// Accepted measurements, oldest first; history[0] is the new tool's origin (zero wear at
  /// zero path) while history_has_origin.
  std::array<HistoryEntry, kMaxRateWindow> history{};
  std::uint32_t history_count{1};
  bool history_has_origin{true};

  std::array<CreepSlot, kMaxCreeps> creeps{};
  std::uint64_t next_seq{1};
  EntrySlot entry{};

  /// Clocks at the last accepted measurement.
  double last_measurement_cut_path_mm{0.0};
  double last_measurement_cut_time_s{0.0};
  double last_measurement_creep_path_mm{0.0};
  /// Program path position at the last accepted measurement [mm] (NaN if unknown).
  double last_measurement_program_path_mm{kNaN};
  /// Material removed by this tool since it was loaded [mm³] (interval basis "material"), and
  /// the amount at the last accepted measurement.
  double removed_mm3{0.0};
  double last_measurement_removed_mm3{0.0};
  std::uint32_t measurements{0};

  bool halted{false};
  bool warning_flag{false};
  bool alarm_flag{false};
  bool measurement_due_flag{false};
  bool tool_change_flag{false};

  /// Last value sent per channel X, Y, Z, radius, length [µm] (what the NC holds).
  std::array<double, kChannelCount> channel_output_um{};

  // Version 3.
  /// The last surface normal known (unit, machine axes): from the NC's axis samples or the
  /// toolpath file. Held while no normal is known (not cutting, an interruption, the trip to the
  /// laser, a restart) so that the split of the correction between the registers does not change
  /// there. Kept across tool changes (a sister resumes where the last tool stopped).
  std::array<double, 3> held_normal{};
  bool normal_held{false};
  /// A refused measurement answered the last request: the next request falls due one interval
  /// (on the interval's own clock) after that measurement, never while halted; the operator's
  /// clear_alarm() lifts the hold. The clocks at the refused measurement:
  bool request_held{false};
  double refused_cut_path_mm{0.0};
  double refused_cut_time_s{0.0};
  double refused_removed_mm3{0.0};

  // Version 4: the wear estimator ([creep.estimator]), per support point. Its state (wear [µm]
  // and wear rate [µm/mm of cut path]) and covariance hold at cut path estimate_path_mm (the
  // last accepted measurement). Until estimate_valid it starts, at the next measurement, from
  // the last measured wear and the fitted rate: a new tool, a state of an older layout, or a
  // tool measured while the estimator was off.
  std::array<double, kMaxEdgePoints> estimate_wear_um{};
  std::array<double, kMaxEdgePoints> estimate_rate_um_per_mm{};
  /// Covariance [[p_ww, p_wr], [p_wr, p_rr]] in µm², µm²/mm, (µm/mm)².
  std::array<double, kMaxEdgePoints> estimate_p_ww{};
  std::array<double, kMaxEdgePoints> estimate_p_wr{};
  std::array<double, kMaxEdgePoints> estimate_p_rr{};
  double estimate_path_mm{0.0};
  bool estimate_valid{false};

  // Version 5: the process noise learned from the tool family, and the check of σ against the
  // residuals (issue 22).
  /// Random-walk density of the wear rate this tool's filter uses [(µm/mm)² per mm]; NaN: the
  /// configured rate_noise_um_per_mm_per_sqrt_m. Set when the tool starts (the family's
  /// estimate then); with adapt_rate_noise moved after each accepted measurement (its whole
  /// adaptation state, so a restart continues it).
  double rate_q{kNaN};
  /// This tool's accepted measurements per support point: the sum of the normalised innovation
  /// squares ν²/S, and of ν² − H·P⁻·Hᵀ (an unbiased estimate of σ² each) [µm²].
  std::array<double, kMaxEdgePoints> nis_sum{};
  std::array<double, kMaxEdgePoints> residual_var_sum_um2{};
  std::uint32_t nis_count{0};
  /// The warning "measurement noise inconsistent" was raised for this tool (once per tool).
  bool noise_warned{false};
  /// The family's statistics (carried across tool changes, the current ones in force).
  FamilyNoise family{};

  // Version 6: the rate prior learned from the tool family (issue 22).
  /// This tool's start rate: the least-squares line through the origin over its accepted
  /// measurements within family_prior_path_mm of cut path (at least its first), as sums
  /// Σ s·w per point [µm·mm] and Σ s² [mm²]; start_sxx 0: none yet.
  std::array<double, kMaxEdgePoints> start_sxw{};
  double start_sxx{0.0};
  /// Prior of this tool's rate at its start [µm/mm] and its standard deviation per point, set
  /// when the tool starts (the family's then); a sigma of 0: the configured prior, 0 ±
  /// initial_rate_sigma_um_per_mm.
  std::array<double, kMaxEdgePoints> rate_prior_um_per_mm{};
  std::array<double, kMaxEdgePoints> rate_prior_sigma_um_per_mm{};
  /// The family's statistics of start rates (carried across tool changes like family).
  FamilyRate family_rate{};
};

static_assert(std::is_trivially_copyable_v<CreepState>);
static_assert(std::is_standard_layout_v<CreepState>);

/// Tools whose wear state is remembered while another tool is in the spindle.
inline constexpr std::size_t kMaxToolMemory = 8;

/// The states of tools out of the spindle (tool 0 = free slot), so a tool that comes back
/// resumes with its wear, its creeps and its fitted rate instead of starting uncorrected.
struct ToolMemory {
  std::array<std::int32_t, kMaxToolMemory> tool{};
  /// Order of last use (the least recently used slot is reused when all are taken).
  std::array<std::uint64_t, kMaxToolMemory> last_use{};
  std::uint64_t use_counter{0};
  std::array<CreepState, kMaxToolMemory> state{};
};

static_assert(std::is_trivially_copyable_v<ToolMemory>);
static_assert(std::is_standard_layout_v<ToolMemory>);

/// What the NC held when the module started without a usable state (CreepModule::adopt_output(),
/// WearCompensator::adopt_channel()): a held channel keeps the NC's value in force until the next
/// accepted measurement; from there the difference between it and the computed value fades out
/// with the creep profile over one creep span, so the register moves from what the NC held to
/// the new value, never back toward 0. Plain data with byte-sized flags; saved after the state
/// and the tool memory.
struct AdoptedOutputs {
  static constexpr std::uint32_t kVersion = 1;
  std::uint32_t version{kVersion};
  /// 1: channel ch is held at held_um[ch].
  std::array<std::uint8_t, kChannelCount> held{};
  /// 1: fade_um[ch] (held − computed at the measurement) fades out on the creep clock.
  std::uint8_t fading{0};
  std::uint8_t fade_path_based{0};
  std::array<double, kChannelCount> held_um{};
  std::array<double, kChannelCount> fade_um{};
  double fade_start{0.0};
  double fade_span{0.0};
};
static_assert(std::is_trivially_copyable_v<AdoptedOutputs>);

/// True if bytes hold a valid AdoptedOutputs (size, version, 0/1 flags, finite values).
/// Real-time safe.
inline bool adoption_bytes_loadable(const std::byte* bytes, std::size_t size,
                                    AdoptedOutputs& out) noexcept {
  if (size != sizeof(AdoptedOutputs)) return false;
  AdoptedOutputs a;
  std::memcpy(&a, bytes, sizeof a);
  if (a.version != AdoptedOutputs::kVersion || a.fading > 1 || a.fade_path_based > 1) return false;
  for (std::size_t ch = 0; ch < kChannelCount; ++ch) {
    if (a.held[ch] > 1 || !std::isfinite(a.held_um[ch]) || !std::isfinite(a.fade_um[ch])) {
      return false;
    }
  }
  if (!std::isfinite(a.fade_start) || !std::isfinite(a.fade_span) || a.fade_span < 0.0) {
    return false;
  }
  out = a;
  return true;
}

/// True if every bool byte of the CreepState at bytes is 0 or 1 (loading any other value into a
/// bool is undefined behaviour, and a corrupt state file can hold anything). Every bool lies
/// before the fields version 6 appended, so a version-5 state is checked by it too. Real-time
/// safe.
inline bool state_bools_valid(const std::byte* bytes) noexcept {
  const auto is_bool = [bytes](std::size_t offset) {
    return std::to_integer<unsigned>(bytes[offset]) <= 1U;
  };
  for (std::size_t k = 0; k < kMaxCreeps; ++k) {
    const std::size_t slot = offsetof(CreepState, creeps) + k * sizeof(CreepSlot);
    if (!is_bool(slot + offsetof(CreepSlot, active)) ||
        !is_bool(slot + offsetof(CreepSlot, path_based)) ||
        !is_bool(slot + offsetof(CreepSlot, eased))) {
      return false;
    }
  }
  return is_bool(offsetof(CreepState, entry) + offsetof(EntrySlot, active)) &&
         is_bool(offsetof(CreepState, rate_known)) &&
         is_bool(offsetof(CreepState, history_has_origin)) &&
         is_bool(offsetof(CreepState, halted)) && is_bool(offsetof(CreepState, warning_flag)) &&
         is_bool(offsetof(CreepState, alarm_flag)) &&
         is_bool(offsetof(CreepState, measurement_due_flag)) &&
         is_bool(offsetof(CreepState, tool_change_flag)) &&
         is_bool(offsetof(CreepState, normal_held)) &&
         is_bool(offsetof(CreepState, request_held)) &&
         is_bool(offsetof(CreepState, estimate_valid)) &&
         is_bool(offsetof(CreepState, noise_warned));
}

/// True if bytes can be copied into a CreepState: the right size and state_bools_valid(). Values
/// are checked afterwards by WearCompensator::check_state(). Real-time safe.
inline bool state_bytes_loadable(const std::byte* bytes, std::size_t size) noexcept {
  return size == sizeof(CreepState) && state_bools_valid(bytes);
}

/// The same for a ToolMemory (every remembered state). Real-time safe.
inline bool memory_bytes_loadable(const std::byte* bytes, std::size_t size) noexcept {
  if (size != sizeof(ToolMemory)) return false;
  for (std::size_t k = 0; k < kMaxToolMemory; ++k) {
    const std::size_t at = offsetof(ToolMemory, state) + k * sizeof(CreepState);
    if (!state_bytes_loadable(bytes + at, sizeof(CreepState))) return false;
  }
  return true;
}

}  // namespace nccomp::core::creep
