// Calibration and recalibration (S3) as an engine module (core/engine/engine.hpp): the daemon
// builds one from the `[calibration]` config section (formats/calib/config_toml.hpp reads it),
// the engine steps it with the validated events, limits its absolute targets per register and
// persists its state with the rest of the engine's.
//
// Operator commands arrive as OperatorCommand events (the daemon's status socket queues them
// into the loop through an SPSC ring); each is executed on the loop thread before the cycle's
// bus events, and its outcome, together with the calibrator's state, is published to a
// SnapshotSink, from which the daemon answers the operator.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "core/calib/calibrator.hpp"
#include "core/calib/snapshot.hpp"
#include "core/engine/engine.hpp"

namespace nccomp::core::calib {

class CalibrationModule final : public engine::Module {
 public:
  /// Not real-time. Stores the config; it is validated at attach().
  explicit CalibrationModule(CalibrationConfig config, std::string name = "calibration");

  [[nodiscard]] std::string_view name() const noexcept override { return name_; }

  /// Not real-time. Checks register_x/y/z against the table (they must exist and be of kind
  /// axis_offset) and configures the calibrator. Throws core::ConfigInvalid naming the key.
  void attach(const engine::RegisterTable& registers) override;

  /// Real-time safe: runs the cycle's OperatorCommand events (in order), then
  /// Calibrator::step(); publishes a snapshot to the sink after a command, a state change, and
  /// at least once per second.
  void step(TimeNs now_ns, std::span<const Event> events, StepOutput& out) noexcept override;

  /// Bytes of save_state(): the CalibState, then the three axis values last written [µm].
  static constexpr std::size_t kStateBytes = sizeof(CalibState) + 3 * sizeof(double);
  [[nodiscard]] std::size_t state_capacity() const noexcept override { return kStateBytes; }
  /// Real-time safe: the plain-data CalibState (times on the wall clock of
  /// set_clock_offset_s()), byte for byte, and the values last written to X, Y, Z (so that a
  /// restarted daemon's limiter starts where the NC is, instead of slewing from 0).
  std::size_t save_state(std::span<std::byte> buf) const noexcept override;
  /// Real-time safe: false if the bytes are not a valid CalibState (fresh state kept). Also
  /// takes a bare CalibState (sizeof(CalibState) bytes, states saved before the written values
  /// were added).
  bool load_state(std::span<const std::byte> bytes) noexcept override;
  /// Advances when a touch set is evaluated, a phase changes or the operator acts.
  [[nodiscard]] std::uint64_t state_generation() const noexcept override { return generation_; }

  /// Wall clock minus the loop's monotonic clock [s]: set it before load_state() so that the
  /// drift models survive a reboot (with 0 they survive a daemon restart, not a reboot).
  void set_clock_offset_s(double wall_minus_monotonic_s) noexcept {
    clock_offset_s_ = wall_minus_monotonic_s;
    calib_.set_clock_offset_s(wall_minus_monotonic_s);
  }
  /// Changes the clock offset of a module whose state is already loaded: the state keeps its
  /// wall-clock times (exported with the old offset, adopted with the new one). Real-time safe.
  void rebase_clock(double wall_minus_monotonic_s) noexcept;
  [[nodiscard]] double clock_offset_s() const noexcept { return clock_offset_s_; }
  /// Where snapshots go (nullptr = nowhere). Not real-time; before the loop steps the module.
  void set_snapshot_sink(SnapshotSink* sink) noexcept { sink_ = sink; }
  /// Real-time safe: phase, the corrections written [µm] and the last measured drift [µm] per
  /// axis, the drift estimator's estimate and σ per axis, its level noise per axis [µm/h] and
  /// whether that is learned (`level_noise`: learned, configured, unused).
  std::size_t status(std::span<engine::StatusValue> out) const noexcept override;
  /// register_x, register_y, register_z.
  [[nodiscard]] std::vector<std::uint16_t> written_registers() const override {
    return {config_.register_x, config_.register_y, config_.register_z};
  }
  /// Without a state: the axis register's limiter starts from what the NC holds
  /// (Calibrator::sync_register()); an uncalibrated module writes nothing, so the NC keeps it
  /// until a calibration (or a newer [calibration] state_file) computes the axis offsets.
  bool adopt_output(std::uint16_t register_index, double nc_value_um, TimeNs now_ns) override;
  /// Trim handover (core/engine/engine.hpp): Calibrator::rebase() of the register's axis.
  /// Real-time safe.
  bool rebase_output(std::uint16_t register_index, double delta_um,
                     TimeNs now_ns) noexcept override;

  /// The calibrator, for operator commands (on the loop thread between steps) and status.
  [[nodiscard]] Calibrator& calibrator() noexcept { return calib_; }
  [[nodiscard]] const Calibrator& calibrator() const noexcept { return calib_; }
  /// Call after an operator command changed the state, so that it gets persisted.
  void mark_changed() noexcept { ++generation_; }

 private:
  void run_command(const OperatorCommand& c, TimeNs now_ns, StepOutput& out) noexcept;
  void publish(TimeNs now_ns) noexcept;

  CalibrationConfig config_;
  std::string name_;
  Calibrator calib_;
  std::uint64_t generation_{0};
  double clock_offset_s_{0.0};
  SnapshotSink* sink_{nullptr};
  CalibSnapshot snapshot_{};  // the buffer published from (no stack copy of ~4 KB per cycle)
  std::uint64_t published_generation_{~std::uint64_t{0}};
  TimeNs last_publish_ns_{0};
  bool published_{false};
};

}  // namespace nccomp::core::calib
