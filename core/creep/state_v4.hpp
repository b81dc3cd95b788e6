// The layout of the creep module's persisted state version 4 (the wear estimator, before the
// process noise learned from the tool family and the check of σ of version 5), kept only so that
// a daemon upgraded across the change resumes with its wear and filter state instead of starting
// fresh. Version 5 appended fields; a version-4 state converts without loss: the tool keeps its
// filter and uses the configured process noise (rate_q NaN), the σ check starts counting at the
// next measurement and the family has no finished tool yet.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <type_traits>

#include "core/creep/state.hpp"

namespace nccomp::core::creep::v4 {

struct CreepState {
  static constexpr std::uint32_t kVersion = 4;
  std::uint32_t version{kVersion};
  std::uint32_t edge_points{1};
  std::int32_t tool{0};
  std::int32_t part{0};

  double cut_path_mm{0.0};
  double cut_time_s{0.0};
  double creep_path_mm{0.0};
  double creep_time_s{0.0};

  std::array<double, kMaxEdgePoints> committed_um{};
  std::array<double, kMaxEdgePoints> measured_um{};
  std::array<double, kMaxEdgePoints> rate_um_per_mm{};
  bool rate_known{false};
  std::array<double, kMaxEdgePoints> rate_prev_um_per_mm{};
  double rate_blend_mm{0.0};

  std::array<HistoryEntry, kMaxRateWindow> history{};
  std::uint32_t history_count{1};
  bool history_has_origin{true};

  std::array<core::creep::CreepSlot, kMaxCreeps> creeps{};
  std::uint64_t next_seq{1};
  EntrySlot entry{};

  double last_measurement_cut_path_mm{0.0};
  double last_measurement_cut_time_s{0.0};
  double last_measurement_creep_path_mm{0.0};
  double last_measurement_program_path_mm{kNaN};
  double removed_mm3{0.0};
  double last_measurement_removed_mm3{0.0};
  std::uint32_t measurements{0};

  bool halted{false};
  bool warning_flag{false};
  bool alarm_flag{false};
  bool measurement_due_flag{false};
  bool tool_change_flag{false};

  std::array<double, kChannelCount> channel_output_um{};

  std::array<double, 3> held_normal{};
  bool normal_held{false};
  bool request_held{false};
  double refused_cut_path_mm{0.0};
  double refused_cut_time_s{0.0};
  double refused_removed_mm3{0.0};

  std::array<double, kMaxEdgePoints> estimate_wear_um{};
  std::array<double, kMaxEdgePoints> estimate_rate_um_per_mm{};
  std::array<double, kMaxEdgePoints> estimate_p_ww{};
  std::array<double, kMaxEdgePoints> estimate_p_wr{};
  std::array<double, kMaxEdgePoints> estimate_p_rr{};
  double estimate_path_mm{0.0};
  bool estimate_valid{false};
};

struct ToolMemory {
  std::array<std::int32_t, kMaxToolMemory> tool{};
  std::array<std::uint64_t, kMaxToolMemory> last_use{};
  std::uint64_t use_counter{0};
  std::array<CreepState, kMaxToolMemory> state{};
};

static_assert(std::is_trivially_copyable_v<CreepState> && std::is_standard_layout_v<CreepState>);
static_assert(std::is_trivially_copyable_v<ToolMemory> && std::is_standard_layout_v<ToolMemory>);

/// Bytes of a version-4 module state (CreepState, then ToolMemory; AdoptedOutputs may follow).
inline constexpr std::size_t kModuleStateBytes = sizeof(CreepState) + sizeof(ToolMemory);

/// True if the bytes at `bytes` can be copied into a version-4 CreepState: version 4 and every
/// bool byte 0 or 1. Real-time safe.
inline bool state_bytes_loadable(const std::byte* bytes) noexcept {
  std::uint32_t version = 0;
  std::memcpy(&version, bytes + offsetof(CreepState, version), sizeof version);
  if (version != CreepState::kVersion) return false;
  const auto is_bool = [bytes](std::size_t offset) {
    return std::to_integer<unsigned>(bytes[offset]) <= 1U;
  };
  for (std::size_t k = 0; k < kMaxCreeps; ++k) {
    const std::size_t slot = offsetof(CreepState, creeps) + k * sizeof(core::creep::CreepSlot);
    if (!is_bool(slot + offsetof(core::creep::CreepSlot, active)) ||
        !is_bool(slot + offsetof(core::creep::CreepSlot, path_based)) ||
        !is_bool(slot + offsetof(core::creep::CreepSlot, eased))) {
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
         is_bool(offsetof(CreepState, estimate_valid));
}

/// Converts a version-4 state (the removal argument is unused). Real-time safe.
inline void upgrade(const CreepState& o, double /*removal_mm3_per_mm*/,
                    core::creep::CreepState& n) noexcept {
  n = core::creep::CreepState{};
  n.edge_points = o.edge_points;
  n.tool = o.tool;
  n.part = o.part;
  n.cut_path_mm = o.cut_path_mm;
  n.cut_time_s = o.cut_time_s;
  n.creep_path_mm = o.creep_path_mm;
  n.creep_time_s = o.creep_time_s;
  n.committed_um = o.committed_um;
  n.measured_um = o.measured_um;
  n.rate_um_per_mm = o.rate_um_per_mm;
  n.rate_known = o.rate_known;
  n.rate_prev_um_per_mm = o.rate_prev_um_per_mm;
  n.rate_blend_mm = o.rate_blend_mm;
  n.history = o.history;
  n.history_count = o.history_count;
  n.history_has_origin = o.history_has_origin;
  n.creeps = o.creeps;
  n.next_seq = o.next_seq;
  n.entry = o.entry;
  n.last_measurement_cut_path_mm = o.last_measurement_cut_path_mm;
  n.last_measurement_cut_time_s = o.last_measurement_cut_time_s;
  n.last_measurement_creep_path_mm = o.last_measurement_creep_path_mm;
  n.last_measurement_program_path_mm = o.last_measurement_program_path_mm;
  n.removed_mm3 = o.removed_mm3;
  n.last_measurement_removed_mm3 = o.last_measurement_removed_mm3;
  n.measurements = o.measurements;
  n.halted = o.halted;
  n.warning_flag = o.warning_flag;
  n.alarm_flag = o.alarm_flag;
  n.measurement_due_flag = o.measurement_due_flag;
  n.tool_change_flag = o.tool_change_flag;
  n.channel_output_um = o.channel_output_um;
  n.held_normal = o.held_normal;
  n.normal_held = o.normal_held;
  n.request_held = o.request_held;
  n.refused_cut_path_mm = o.refused_cut_path_mm;
  n.refused_cut_time_s = o.refused_cut_time_s;
  n.refused_removed_mm3 = o.refused_removed_mm3;
  n.estimate_wear_um = o.estimate_wear_um;
  n.estimate_rate_um_per_mm = o.estimate_rate_um_per_mm;
  n.estimate_p_ww = o.estimate_p_ww;
  n.estimate_p_wr = o.estimate_p_wr;
  n.estimate_p_rr = o.estimate_p_rr;
  n.estimate_path_mm = o.estimate_path_mm;
  n.estimate_valid = o.estimate_valid;
}

}  // namespace nccomp::core::creep::v4
