// What a model's trims are computed from, taken from the machine context at one moment: a
// checkpoint's cut (core/checkpoint). A trim handover (engine.hpp, "Trim handover") evaluates the
// new trims at each checkpoint's own inputs, so a term of the temperature, the time since the
// warm start or the position counts as it was where the last reading was cut, not as at the
// switch. Fixed size; NaN = not known (the model takes that input as it is now).
#pragma once

#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>

#include "core/engine/context.hpp"

namespace nccomp::core::engine {

/// Temperature sensors a snapshot keeps besides temp_c: the lowest-numbered ones with a value.
inline constexpr std::size_t kSnapshotSensors = 8;

struct InputSnapshot {
  static constexpr double kUnknown = std::numeric_limits<double>::quiet_NaN();
  double time_s{kUnknown};   // since the warm start
  double session{kUnknown};  // warm starts counted
  double part{kUnknown};
  double tool{kUnknown};
  double path_mm{kUnknown};  // the tool's cut path
  double temp_c{kUnknown};
  std::array<double, 3> position_mm{kUnknown, kUnknown, kUnknown};
  /// sensors valid entries: sensor number and its value [°C].
  std::array<std::uint8_t, kSnapshotSensors> sensor{};
  std::array<double, kSnapshotSensors> sensor_c{};
  std::uint32_t sensors{0};

  /// The value of `sensor` kept, or NaN. Real-time safe.
  [[nodiscard]] double temperature_c(int which) const noexcept {
    for (std::uint32_t k = 0; k < sensors && k < kSnapshotSensors; ++k) {
      if (sensor[k] == which) return sensor_c[k];
    }
    return kUnknown;
  }
  /// Null if every value is finite or NaN, in range (as snapshot() writes them), else what is
  /// wrong (a state file's record). Real-time safe.
  [[nodiscard]] const char* invalid_reason() const noexcept {
    const auto bad = [](double v) { return std::isinf(v); };
    if (bad(time_s) || time_s < 0.0 || bad(session) || session < 0.0 || bad(part) || bad(tool) ||
        bad(path_mm) || path_mm < 0.0 || bad(temp_c)) {
      return "cut inputs infinite or negative";
    }
    for (const double p : position_mm) {
      if (bad(p)) return "cut position infinite";
    }
    if (sensors > kSnapshotSensors) return "more cut sensors than kept";
    for (std::uint32_t k = 0; k < sensors; ++k) {
      if (!std::isfinite(sensor_c[k])) return "cut sensor value not finite";
    }
    return nullptr;
  }
};

/// The context's inputs now. Real-time safe (scans the sensors: call it when a checkpoint is
/// passed, not every cycle).
[[nodiscard]] inline InputSnapshot snapshot(const MachineContext& c) noexcept {
  InputSnapshot s;
  s.time_s = c.machine_time_s();
  s.session = static_cast<double>(c.warm_starts());
  if (c.has_part()) s.part = c.part();
  if (c.has_tool()) {
    s.tool = c.tool();
    s.path_mm = c.cut_path_mm();
  }
  s.temp_c = c.temp_c();
  s.position_mm = c.position_mm();
  for (std::size_t k = 0; k < kTemperatureSensors && s.sensors < kSnapshotSensors; ++k) {
    const double v = c.temperature_c(static_cast<int>(k));
    if (std::isfinite(v)) {
      s.sensor[s.sensors] = static_cast<std::uint8_t>(k);
      s.sensor_c[s.sensors] = v;
      ++s.sensors;
    }
  }
  return s;
}

}  // namespace nccomp::core::engine
