// The machine context the engine keeps for every measurement record and for modules that
// evaluate the fitted model (architecture.md, "Measurement log"): one place that follows the
// validated events of every cycle, so that each record leaves the engine with the same context
// the model module evaluates with.
//
//   - time_s: seconds since the machine's warm start (the rule below), not since boot; the
//     origin is saved with the engine state, so a fitted warm-up term means the same after a
//     restart;
//   - path_mm: the cut path of the record's tool, counted as the creep module counts it (S0,
//     core/creep/wear_compensator.cpp): the program path where the NC publishes it, else the XYZ
//     distance, only between two cutting samples outside an interruption; a tool that goes out
//     and comes back continues its path, a sister tool starts at 0; remembered for
//     kContextTools tools, saved with the state;
//   - temp_c: the last TemperatureSample of the configured sensor;
//   - machine position, tool, part, and the last value of every temperature sensor (the model
//     module's extra inputs).
//
// Warm start. The machine is *active* in a cycle with axis motion: an AxisSample whose X/Y/Z
// position or program path moved by more than 1 µm since the previous sample. A machine with no
// motion for at least warm_start_idle_s is *cold*; its next activity is a warm start, and time_s
// counts from that cycle. A fresh daemon (no state) takes the machine as cold. Across a restart
// the clock the engine is stepped with decides: if it did not go back (a daemon restart within
// one boot of the computer), the downtime is known exactly and counts as idle time; if it went
// back (a reboot, or a new lock-step run), the downtime is unknown and the machine is taken as
// cold (its next activity is a warm start), the usual case of a cabinet PC switched off with the
// machine. The operator (or a PLC through the status socket: `nccomp warm-start`) may also declare
// it with an OperatorCommand kWarmStart: code[0] = 0 makes this cycle the warm start (time_s
// restarts at 0, the cycle counts as activity), code[0] = 1 makes the machine cold (its next
// motion is the warm start). Any other code is ignored here (the engine refuses it as invalid).
//
// Real-time: update(), annotate(), save() and load() allocate nothing (fixed arrays).
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <span>

#include "core/common/types.hpp"

namespace nccomp::core::engine {

struct ContextOptions {
  /// TemperatureSample sensor whose value is the log's temp_c (and the model's); −1 = none.
  int temperature_sensor{0};
  /// No axis motion for at least this long makes the machine cold: its next motion is a warm
  /// start, the origin of time_s [s]. 60 s … 7 days.
  double warm_start_idle_s{7200.0};
};

/// Tools whose cut path the context remembers (least recently used forgotten first).
inline constexpr std::size_t kContextTools = 32;
/// TemperatureSample sensor indices (std::uint8_t).
inline constexpr std::size_t kTemperatureSensors = 256;

class MachineContext {
 public:
  MachineContext();

  /// Not real-time. Throws std::invalid_argument naming the option that is out of range.
  void configure(const ContextOptions& options);
  [[nodiscard]] const ContextOptions& options() const noexcept { return options_; }

  /// Real-time safe. Follows one cycle's validated events (in order) at now_ns.
  void update(TimeNs now_ns, std::span<const Event> events) noexcept;

  /// Real-time safe. Fills what the module that made the record left unknown (NaN): path_mm =
  /// the cut path of the record's tool (of the unnamed tool when the NC publishes no tool
  /// number), temp_c = the configured sensor's last value; sets session = warm_starts() and
  /// clock_ns = time_ns, then converts time_ns to the time since the warm start (never negative).
  void annotate(MeasurementRecord& r) const noexcept;

  /// Seconds since the warm start at time t_ns (the step clock), ≥ 0.
  [[nodiscard]] double machine_time_s(TimeNs t_ns) const noexcept;
  /// Machine time at the last update().
  [[nodiscard]] double machine_time_s() const noexcept { return machine_time_s(last_step_ns_); }
  /// Seconds since the last axis motion at the last update().
  [[nodiscard]] double idle_s() const noexcept;
  /// Warm starts since the state began (a counter: the model re-evaluates on a change).
  [[nodiscard]] std::uint64_t warm_starts() const noexcept { return warm_starts_; }
  /// True while the machine is cold: its next activity will be a warm start.
  [[nodiscard]] bool cold() const noexcept { return cold_; }
  /// Warm-start commands taken since the context was created (not saved: a count of this
  /// process), and the sequence number of the last one (0 = none).
  [[nodiscard]] std::uint64_t warm_start_commands() const noexcept { return commands_; }
  [[nodiscard]] std::uint32_t last_command_sequence() const noexcept { return last_sequence_; }

  [[nodiscard]] bool has_tool() const noexcept { return current_ >= 0; }
  /// Tool in the spindle (0 = the NC names none).
  [[nodiscard]] std::int32_t tool() const noexcept;
  [[nodiscard]] bool has_part() const noexcept { return has_part_; }
  [[nodiscard]] std::int32_t part() const noexcept { return part_; }
  /// Cut path of the tool in the spindle [mm] (0 before any tool is known).
  [[nodiscard]] double cut_path_mm() const noexcept;
  /// Cut path of `tool` [mm]; NaN if the context does not know the tool.
  [[nodiscard]] double cut_path_mm(std::int32_t tool) const noexcept;
  /// Last value of a temperature sensor [°C]; NaN if none has arrived (or out of range).
  [[nodiscard]] double temperature_c(int sensor) const noexcept;
  /// The log's temp_c: the configured sensor's last value, or NaN.
  [[nodiscard]] double temp_c() const noexcept {
    return temperature_c(options_.temperature_sensor);
  }
  /// Machine position X/Y/Z of the last axis sample [mm]; NaN before the first one.
  [[nodiscard]] const std::array<double, 3>& position_mm() const noexcept { return position_mm_; }
  [[nodiscard]] bool interrupted() const noexcept { return interrupted_; }

  /// Bytes of save()'s output (fixed).
  static constexpr std::size_t kStateBytes = 4 * 4 + 8 * 4 + 4 * 2 + kContextTools * 24;
  /// Real-time safe. Writes the state that must survive a restart; returns kStateBytes, or 0 if
  /// buf is too small.
  std::size_t save(std::span<std::byte> buf) const noexcept;
  /// Real-time safe. Restores save()'s output at now_ns (see "Warm start" above for the
  /// downtime); false (and nothing changed) if the bytes are not a valid state.
  bool load(std::span<const std::byte> bytes, TimeNs now_ns) noexcept;
  /// Real-time safe. The last axis sample and whether it was cutting (interrupted): what load()
  /// forgets, carried by a reload into the next engine's context (Engine::export_motion()).
  /// Returns kMotionSize, 0 if buf is too small.
  static constexpr std::size_t kMotionSize = sizeof(AxisSample) + 8;
  std::size_t save_motion(std::span<std::byte> buf) const noexcept;
  /// Real-time safe. False (nothing changed) if the bytes are not save_motion()'s.
  bool load_motion(std::span<const std::byte> bytes) noexcept;
  /// Advances on a warm start, a tool or part change, every 10 mm of cut path and every minute
  /// of activity (so that a crash loses little); not on every cycle.
  [[nodiscard]] std::uint64_t generation() const noexcept { return generation_; }

 private:
  struct ToolSlot {
    std::int32_t tool{0};
    bool used{false};
    double path_mm{0.0};
    std::uint64_t last_use{0};
  };
  void on_axis_sample(TimeNs now_ns, const AxisSample& a) noexcept;
  void on_tool_change(std::int32_t tool, bool sister) noexcept;
  void on_command(TimeNs now_ns, const OperatorCommand& c) noexcept;
  [[nodiscard]] int find_slot(std::int32_t tool) const noexcept;
  int take_slot(std::int32_t tool) noexcept;

  ContextOptions options_{};
  TimeNs idle_limit_ns_{0};
  // Clock (step-clock domain).
  TimeNs origin_ns_{0};
  TimeNs last_activity_ns_{0};
  TimeNs last_step_ns_{0};
  TimeNs activity_saved_ns_{0};
  bool has_step_{false};
  bool cold_{true};
  std::uint64_t warm_starts_{0};
  std::uint64_t commands_{0};
  std::uint32_t last_sequence_{0};
  // Tools and path.
  std::array<ToolSlot, kContextTools> tools_{};
  int current_{-1};
  std::uint64_t use_counter_{0};
  double path_saved_mm_{0.0};
  AxisSample last_sample_{};
  bool have_sample_{false};
  bool cutting_{false};
  bool interrupted_{false};
  // Part, position, temperatures.
  std::int32_t part_{0};
  bool has_part_{false};
  std::array<double, 3> position_mm_{};
  std::array<double, kTemperatureSensors> temperature_c_{};
  std::uint64_t generation_{0};
};

}  // namespace nccomp::core::engine
