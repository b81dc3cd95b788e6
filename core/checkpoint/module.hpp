// The S1 compensator as an engine module (core/engine/engine.hpp): the engine steps it with the
// cycle's validated events, limits its targets per register and persists its state as bytes.
//
// Register use (logical indices = indices into the engine's register table):
//   register_base … register_base + N − 1: kind "checkpoint", one per checkpoint in machining
//   order; active_register (if ≥ 0): kind "tool_radius_wear", the finishing tool's live wear.
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "core/checkpoint/compensator.hpp"
#include "core/engine/engine.hpp"

namespace nccomp::core::checkpoint {

class CheckpointModule final : public engine::Module, public engine::ToolWearTrimUser {
 public:
  /// Not real-time. The plan and config are validated in attach().
  CheckpointModule(CompensatorConfig config, std::vector<Checkpoint> plan,
                   std::string name = "checkpoints");

  [[nodiscard]] std::string_view name() const noexcept override { return name_; }
  /// Checks that the table has the registers of the right kinds and configures the compensator
  /// with the limits of the register it writes live (or of the first checkpoint register).
  /// Throws core::ConfigInvalid naming checkpoints.register_base / active_register.
  void attach(const engine::RegisterTable& registers) override;
  /// Real-time safe.
  void step(TimeNs now_ns, std::span<const Event> events, StepOutput& out) noexcept override;
  [[nodiscard]] std::size_t state_capacity() const noexcept override;
  /// Real-time safe: header (magic, version, count, part counter, part) + one fixed-size record
  /// per checkpoint, little-endian host layout (the state file never leaves the machine).
  std::size_t save_state(std::span<std::byte> buf) const noexcept override;
  /// Real-time safe: refuses bytes of another plan size or with invalid values (all or nothing).
  bool load_state(std::span<const std::byte> bytes) noexcept override;
  [[nodiscard]] std::uint64_t state_generation() const noexcept override {
    return compensator_.generation();
  }

  /// Real-time safe: checkpoints, learned (measured at least once), passed this part, part,
  /// parts counted, probe readings, alarms (implausible, outliers).
  std::size_t status(std::span<engine::StatusValue> out) const noexcept override;
  /// The table registers and the live register.
  [[nodiscard]] std::vector<std::uint16_t> written_registers() const override;
  /// Without a state: a table register's value becomes the checkpoint's offset
  /// (CheckpointCompensator::adopt_register_value()); the live register's limiter starts from
  /// the NC's value (it is written again only while finishing, from the adopted table).
  bool adopt_output(std::uint16_t register_index, double nc_value_um, TimeNs now_ns) override;

  /// Trim handover (core/engine/engine.hpp): the live register rebases every checkpoint, a
  /// table register its checkpoint (CheckpointCompensator::rebase()). Real-time safe.
  bool rebase_output(std::uint16_t register_index, double delta_um,
                     TimeNs now_ns) noexcept override;
  /// The same, each checkpoint's residual at the inputs of its last cut, less the trims it was
  /// cut with. Real-time safe.
  bool rebase_output_along(std::uint16_t register_index, double delta_um,
                           const engine::TrimChange& change, TimeNs now_ns) noexcept override;
  /// Keeps the context: each checkpoint's inputs are recorded when the tool passes it.
  void bind_context(const engine::MachineContext& context) override { context_ = &context; }
  /// Keeps the modules that trim: each checkpoint's trims are recorded when the tool passes it.
  void bind_tool_wear_trims(std::vector<const engine::ToolWearTrimSource*> sources) override {
    trim_sources_ = std::move(sources);
  }

  [[nodiscard]] CheckpointCompensator& compensator() noexcept { return compensator_; }
  [[nodiscard]] const CheckpointCompensator& compensator() const noexcept { return compensator_; }

 private:
  CompensatorConfig config_;
  std::vector<Checkpoint> plan_;
  std::string name_;
  CheckpointCompensator compensator_;
  const engine::MachineContext* context_{nullptr};
  std::vector<const engine::ToolWearTrimSource*> trim_sources_;
  bool rebase(std::uint16_t register_index, double delta_um, TimeNs now_ns,
              const engine::TrimChange* along) noexcept;
};

}  // namespace nccomp::core::checkpoint
