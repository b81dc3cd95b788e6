// Calibration and recalibration (S3) as an engine module (core/engine/engine.hpp): the daemon
// builds one from the `[calibration]` config section (tools/calibrate/config_toml.hpp reads it),
// the engine steps it with the validated events, limits its absolute targets per register and
// persists its state with the rest of the engine's.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "core/calib/calibrator.hpp"
#include "core/engine/engine.hpp"

namespace nccomp::core::calib {

class CalibrationModule final : public engine::Module {
 public:
  /// Not real-time. Stores the config; it is validated at attach().
  explicit CalibrationModule(CalibrationConfig config, std::string name = "calibration");

  [[nodiscard]] std::string_view name() const noexcept override { return name_; }

  /// Not real-time. Checks register_x/y/z against the table (they must exist and be of kind
  /// axis_offset) and configures the calibrator. Throws std::invalid_argument naming the key.
  void attach(const engine::RegisterTable& registers) override;

  /// Real-time safe: forwards to Calibrator::step().
  void step(TimeNs now_ns, std::span<const Event> events, StepOutput& out) noexcept override;

  [[nodiscard]] std::size_t state_capacity() const noexcept override { return sizeof(CalibState); }
  /// Real-time safe: the plain-data CalibState (times on the wall clock of
  /// set_clock_offset_s()), byte for byte.
  std::size_t save_state(std::span<std::byte> buf) const noexcept override;
  /// Real-time safe: false if the bytes are not a valid CalibState (fresh state kept).
  bool load_state(std::span<const std::byte> bytes) noexcept override;
  /// Advances when a touch set is evaluated, a phase changes or the operator acts.
  [[nodiscard]] std::uint64_t state_generation() const noexcept override { return generation_; }

  /// Wall clock minus the loop's monotonic clock [s]: set it before load_state() so that the
  /// drift models survive a reboot (with 0 they survive a daemon restart, not a reboot).
  void set_clock_offset_s(double wall_minus_monotonic_s) noexcept {
    calib_.set_clock_offset_s(wall_minus_monotonic_s);
  }
  /// Real-time safe: phase, the corrections written [µm] and the last measured drift [µm] per
  /// axis.
  std::size_t status(std::span<engine::StatusValue> out) const noexcept override;
  /// register_x, register_y, register_z.
  [[nodiscard]] std::vector<std::uint16_t> written_registers() const override {
    return {config_.register_x, config_.register_y, config_.register_z};
  }

  /// The calibrator, for operator commands (on the loop thread between steps) and status.
  [[nodiscard]] Calibrator& calibrator() noexcept { return calib_; }
  [[nodiscard]] const Calibrator& calibrator() const noexcept { return calib_; }
  /// Call after an operator command changed the state, so that it gets persisted.
  void mark_changed() noexcept { ++generation_; }

 private:
  CalibrationConfig config_;
  std::string name_;
  Calibrator calib_;
  std::uint64_t generation_{0};
};

}  // namespace nccomp::core::calib
