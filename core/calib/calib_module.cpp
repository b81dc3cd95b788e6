#include "core/calib/calib_module.hpp"

#include <cstring>
#include <stdexcept>
#include <utility>

namespace nccomp::core::calib {

CalibrationModule::CalibrationModule(CalibrationConfig config, std::string name)
    : config_(std::move(config)), name_(std::move(name)) {}

void CalibrationModule::attach(const engine::RegisterTable& registers) {
  const std::pair<const char*, std::uint16_t> regs[] = {{"register_x", config_.register_x},
                                                        {"register_y", config_.register_y},
                                                        {"register_z", config_.register_z}};
  for (const auto& [key, index] : regs) {
    if (index >= registers.size()) {
      throw std::invalid_argument("calibration." + std::string(key) + ": register " +
                                  std::to_string(index) + " is not in the register table (" +
                                  std::to_string(registers.size()) + " registers)");
    }
    if (registers[index].kind != engine::RegisterKind::kAxisOffset) {
      throw std::invalid_argument("calibration." + std::string(key) + ": register " +
                                  std::to_string(index) + " (\"" + registers[index].name +
                                  "\") must be of kind axis_offset");
    }
  }
  calib_.configure(config_);
}

void CalibrationModule::step(TimeNs now_ns, std::span<const Event> events,
                             StepOutput& out) noexcept {
  const Phase before = calib_.phase();
  const std::size_t records = out.records.size();
  const std::size_t alarms = out.alarms.size();
  calib_.step(now_ns, events, out);
  if (calib_.phase() != before || out.records.size() != records || out.alarms.size() != alarms) {
    ++generation_;
  }
}

std::size_t CalibrationModule::save_state(std::span<std::byte> buf) const noexcept {
  if (buf.size() < sizeof(CalibState)) {
    return 0;
  }
  const CalibState s = calib_.export_state();
  std::memcpy(buf.data(), &s, sizeof s);
  return sizeof s;
}

bool CalibrationModule::load_state(std::span<const std::byte> bytes) noexcept {
  if (bytes.empty()) {
    return true;
  }
  if (bytes.size() != sizeof(CalibState)) {
    return false;
  }
  CalibState s;
  std::memcpy(&s, bytes.data(), sizeof s);
  if (state_problem(s) != nullptr) {
    return false;
  }
  calib_.import_state_unchecked(s);
  ++generation_;
  return true;
}

std::size_t CalibrationModule::status(std::span<engine::StatusValue> out) const noexcept {
  const auto& c = calib_;
  const engine::StatusValue values[] = {
      {"phase", 0.0, to_string(c.phase())},
      {"x_written_um", c.written_um(0), nullptr},
      {"y_written_um", c.written_um(1), nullptr},
      {"z_written_um", c.written_um(2), nullptr},
      {"x_last_drift_um", c.model(Slot::kXLateral).anchor_drift_um, nullptr},
      {"y_last_drift_um", c.model(Slot::kY).anchor_drift_um, nullptr},
      {"z_last_drift_um", c.model(Slot::kZ).anchor_drift_um, nullptr},
  };
  std::size_t w = 0;
  for (const auto& v : values) {
    if (w == out.size()) break;
    out[w++] = v;
  }
  return w;
}

}  // namespace nccomp::core::calib
