// The layout of the creep module's persisted state version 5 (the process noise learned from the
// tool family, before the rate prior learned from it of version 6), kept only so that a daemon
// upgraded across the change resumes with its wear, filter and family state instead of starting
// fresh. Version 6 appended fields after the family, so a version-5 state is the first bytes of
// a version-6 one and converts without loss: the new fields start empty (no start rate of the
// tool in the spindle, the configured rate prior, no family rate statistics).
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <type_traits>

#include "core/creep/state.hpp"

namespace nccomp::core::creep::v5 {

/// Bytes of a version-5 CreepState: the current layout up to its version-6 fields.
inline constexpr std::size_t kStateBytes = offsetof(core::creep::CreepState, start_sxw);
static_assert(kStateBytes == offsetof(core::creep::CreepState, family) + sizeof(FamilyNoise),
              "version 6 appends its fields right after the family");

struct alignas(alignof(core::creep::CreepState)) CreepState {
  std::array<std::byte, kStateBytes> bytes;
};
static_assert(sizeof(CreepState) == kStateBytes);

struct ToolMemory {
  std::array<std::int32_t, kMaxToolMemory> tool{};
  std::array<std::uint64_t, kMaxToolMemory> last_use{};
  std::uint64_t use_counter{0};
  std::array<CreepState, kMaxToolMemory> state{};
};

static_assert(std::is_trivially_copyable_v<CreepState> && std::is_standard_layout_v<CreepState>);
static_assert(std::is_trivially_copyable_v<ToolMemory> && std::is_standard_layout_v<ToolMemory>);

/// Bytes of a version-5 module state (CreepState, then ToolMemory; AdoptedOutputs and the
/// residual shift may follow).
inline constexpr std::size_t kModuleStateBytes = sizeof(CreepState) + sizeof(ToolMemory);

/// True if the bytes at `bytes` can be copied into a version-5 CreepState: version 5 and every
/// bool byte 0 or 1. Real-time safe.
inline bool state_bytes_loadable(const std::byte* bytes) noexcept {
  std::uint32_t version = 0;
  std::memcpy(&version, bytes + offsetof(core::creep::CreepState, version), sizeof version);
  return version == 5 && state_bools_valid(bytes);
}

/// Converts a version-5 state (the removal argument is unused). Real-time safe.
inline void upgrade(const CreepState& o, double /*removal_mm3_per_mm*/,
                    core::creep::CreepState& n) noexcept {
  n = core::creep::CreepState{};
  std::memcpy(static_cast<void*>(&n), o.bytes.data(), kStateBytes);
  n.version = core::creep::CreepState::kVersion;
}

}  // namespace nccomp::core::creep::v5
