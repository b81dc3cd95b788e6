#include "core/calib/snapshot.hpp"

namespace nccomp::core::calib {

const char* to_string(CommandStatus status) noexcept {
  switch (status) {
    case CommandStatus::kNone:
      return "none";
    case CommandStatus::kOk:
      return "ok";
    case CommandStatus::kWrongPhase:
      return "wrong-phase";
    case CommandStatus::kInvalidInput:
      return "invalid-input";
    case CommandStatus::kUnknown:
      return "unknown-command";
  }
  return "?";
}

void make_snapshot(const Calibrator& c, TimeNs now_ns, CalibSnapshot& out) noexcept {
  const auto& cfg = c.config();
  out.time_s = seconds(now_ns);
  out.state = c.export_state();
  out.wall_time_s = out.time_s + c.clock_offset_s();
  out.request = c.request();
  out.progress = c.touch_progress();
  out.registers = {cfg.register_x, cfg.register_y, cfg.register_z};
  for (std::size_t a = 0; a < kAxisCount; ++a) {
    out.target_um[a] = c.target_um(a, now_ns);
    out.written_um[a] = c.written_um(a);
  }
  for (std::size_t s = 0; s < kSlotCount; ++s) {
    const auto slot = static_cast<Slot>(s);
    out.correction_um[s] = c.drift_correction_um(slot, now_ns);
    out.predicted_um[s] = c.predicted_drift_um(slot, now_ns);
  }
  out.temperature_c = c.temperature_c();
  out.recalibration_interval_s = cfg.recalibration_interval_s;
  out.facet_rule = cfg.facet_rule;
  out.temperature_sensor = cfg.temperature_sensor;
}

}  // namespace nccomp::core::calib
