#include "core/calib/calib_module.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <iterator>
#include <stdexcept>
#include <utility>
#include <variant>

#include "core/common/config_issue.hpp"

namespace nccomp::core::calib {

CalibrationModule::CalibrationModule(CalibrationConfig config, std::string name)
    : config_(std::move(config)), name_(std::move(name)) {}

void CalibrationModule::attach(const engine::RegisterTable& registers) {
  const std::pair<const char*, std::uint16_t> regs[] = {{"register_x", config_.register_x},
                                                        {"register_y", config_.register_y},
                                                        {"register_z", config_.register_z}};
  for (const auto& [key, index] : regs) {
    if (index >= registers.size()) {
      throw ConfigInvalid("calibration." + std::string(key),
                          "register " + std::to_string(index) + " is not in the register table (" +
                              std::to_string(registers.size()) + " registers)");
    }
    if (registers[index].kind != engine::RegisterKind::kAxisOffset) {
      throw ConfigInvalid("calibration." + std::string(key), "register " + std::to_string(index) +
                                                                 " (\"" + registers[index].name +
                                                                 "\") must be of kind axis_offset");
    }
  }
  if (config_.request_register >= 0) {
    const auto index = static_cast<std::size_t>(config_.request_register);
    if (index >= registers.size()) {
      throw ConfigInvalid("calibration.request_register",
                          "register " + std::to_string(index) + " is not in the register table (" +
                              std::to_string(registers.size()) + " registers)");
    }
    if (registers[index].kind != engine::RegisterKind::kFlag) {
      throw ConfigInvalid("calibration.request_register", "register " + std::to_string(index) +
                                                              " (\"" + registers[index].name +
                                                              "\") must be of kind flag");
    }
  }
  calib_.configure(config_);
}

bool CalibrationModule::adopt_output(std::uint16_t register_index, double nc_value_um,
                                     TimeNs now_ns) {
  const std::array<std::uint16_t, 3> reg{config_.register_x, config_.register_y,
                                         config_.register_z};
  for (std::size_t a = 0; a < reg.size(); ++a) {
    if (reg[a] == register_index && std::isfinite(nc_value_um)) {
      calib_.sync_register(a, nc_value_um, now_ns);
      ++generation_;
      return true;
    }
  }
  return false;
}

bool CalibrationModule::rebase_output(std::uint16_t register_index, double delta_um,
                                      TimeNs now_ns) noexcept {
  const std::array<std::uint16_t, 3> reg{config_.register_x, config_.register_y,
                                         config_.register_z};
  for (std::size_t a = 0; a < reg.size(); ++a) {
    if (reg[a] == register_index) {
      if (!calib_.rebase(a, delta_um, now_ns)) {
        return false;
      }
      ++generation_;
      return true;
    }
  }
  return false;
}

void CalibrationModule::run_command(const OperatorCommand& c, TimeNs now_ns,
                                    StepOutput& out) noexcept {
  CommandOutcome o;
  o.sequence = c.sequence;
  o.kind = c.kind;
  o.phase_before = calib_.phase();
  o.status = CommandStatus::kOk;
  const std::size_t alarms_before = out.alarms.size();
  switch (c.kind) {
    case OperatorCommandKind::kCalibrationBegin:
      calib_.begin_calibration(now_ns, out);
      break;
    case OperatorCommandKind::kCalibrationFacets: {
      if (c.code[0] != 0 && c.code[0] != 1) {
        o.status = CommandStatus::kInvalidInput;
        break;
      }
      o.facet = calib_.enter_facets(c.code[0] == 0 ? Face::kLateral : Face::kEndFace, c.value[0],
                                    c.value[1], now_ns, out);
      if (o.facet.status == FacetStatus::kWrongPhase) {
        o.status = CommandStatus::kWrongPhase;
      } else if (o.facet.status == FacetStatus::kInvalidInput) {
        o.status = CommandStatus::kInvalidInput;
      }
      break;
    }
    case OperatorCommandKind::kCalibrationDiscard:
      calib_.discard_touch_set();
      break;
    case OperatorCommandKind::kCalibrationRecalibrate:
      if (!calib_.request_recalibration()) {
        o.status = CommandStatus::kWrongPhase;
      }
      break;
    case OperatorCommandKind::kCalibrationTouch: {
      CalibrationTouch t;
      t.time_ns = now_ns;
      const bool probe_ok = c.code[0] == 0 || c.code[0] == 1;
      t.probe = c.code[0] == 1 ? ProbeKind::kReferenceProbe : ProbeKind::kMachineProbe;
      t.axis = static_cast<std::uint8_t>(c.code[1]);
      t.direction = c.code[2];
      t.variant = static_cast<std::uint8_t>(c.code[3]);
      t.trigger_position_mm = c.value[0];
      if (!probe_ok || c.code[1] < 0 || c.code[3] < 0) {
        o.status = CommandStatus::kInvalidInput;
        break;
      }
      calib_.enter_touch(t, now_ns, out);
      // The calibrator refuses with a warning: 49 = malformed, 45 = not expected now.
      for (std::size_t i = alarms_before; i < out.alarms.size(); ++i) {
        if (out.alarms[i].code == AlarmCode::kCalibrationInvalidInput) {
          o.status = CommandStatus::kInvalidInput;
        } else if (out.alarms[i].code == AlarmCode::kTouchUnexpected) {
          o.status = CommandStatus::kWrongPhase;
        }
      }
      break;
    }
    case OperatorCommandKind::kCalibrationStatus:
      break;
    case OperatorCommandKind::kNone:
    default:
      o.status = CommandStatus::kUnknown;
      break;
  }
  for (std::size_t i = alarms_before; i < out.alarms.size(); ++i) {
    if (o.alarm_count < o.alarms.size()) {
      o.alarms[o.alarm_count] = out.alarms[i];
    }
    ++o.alarm_count;
  }
  if (c.kind != OperatorCommandKind::kCalibrationStatus) {
    if (o.status == CommandStatus::kOk) {
      ++snapshot_.commands_taken;
    } else {
      ++snapshot_.commands_refused;
    }
  }
  if (c.kind != OperatorCommandKind::kCalibrationStatus && o.status == CommandStatus::kOk) {
    mark_changed();
  }
  snapshot_.last_command = o;
}

void CalibrationModule::step(TimeNs now_ns, std::span<const Event> events,
                             StepOutput& out) noexcept {
  const Phase before = calib_.phase();
  const std::size_t records = out.records.size();
  const std::size_t alarms = out.alarms.size();
  bool commanded = false;
  for (const Event& e : events) {
    const auto* c = std::get_if<OperatorCommand>(&e);
    // kWarmStart is the engine's machine context's command, not the calibrator's; kAcknowledge
    // clears latched alarms, and the calibrator latches none (a refused touch set or
    // recalibration is re-run or discarded with its own commands).
    if (c != nullptr && c->kind != OperatorCommandKind::kWarmStart &&
        c->kind != OperatorCommandKind::kAcknowledge) {
      run_command(*c, now_ns, out);
      commanded = true;
    }
  }
  calib_.step(now_ns, events, out);
  if (calib_.phase() != before || out.records.size() != records || out.alarms.size() != alarms) {
    ++generation_;
  }
  if (sink_ != nullptr && (commanded || !published_ || generation_ != published_generation_ ||
                           now_ns - last_publish_ns_ >= 1'000'000'000)) {
    publish(now_ns);
  }
}

void CalibrationModule::publish(TimeNs now_ns) noexcept {
  make_snapshot(calib_, now_ns, snapshot_);
  ++snapshot_.publishes;
  sink_->publish(snapshot_);
  published_ = true;
  published_generation_ = generation_;
  last_publish_ns_ = now_ns;
}

void CalibrationModule::rebase_clock(double wall_minus_monotonic_s) noexcept {
  const CalibState s = calib_.export_state();
  const std::array<double, 3> written{calib_.written_um(0), calib_.written_um(1),
                                      calib_.written_um(2)};
  set_clock_offset_s(wall_minus_monotonic_s);
  calib_.import_state_unchecked(s);
  for (std::size_t a = 0; a < 3; ++a) {
    calib_.restore_written(a, written[a]);
  }
  ++generation_;
}

std::size_t CalibrationModule::save_state(std::span<std::byte> buf) const noexcept {
  if (buf.size() < kStateBytes) {
    return 0;
  }
  const CalibState s = calib_.export_state();
  std::memcpy(buf.data(), &s, sizeof s);
  for (std::size_t a = 0; a < 3; ++a) {
    const double w = calib_.written_um(a);
    std::memcpy(buf.data() + sizeof s + a * sizeof(double), &w, sizeof w);
  }
  return kStateBytes;
}

bool CalibrationModule::load_state(std::span<const std::byte> bytes) noexcept {
  if (bytes.empty()) {
    return true;
  }
  // Version 3, versions 1 and 2 (prefixes of version 3's bytes), each with or without the
  // values written.
  constexpr std::size_t kWrittenBytes = 3 * sizeof(double);
  const bool v1 =
      bytes.size() == kCalibStateV1Bytes || bytes.size() == kCalibStateV1Bytes + kWrittenBytes;
  const bool v2 =
      bytes.size() == kCalibStateV2Bytes || bytes.size() == kCalibStateV2Bytes + kWrittenBytes;
  if (bytes.size() != sizeof(CalibState) && bytes.size() != kStateBytes && !v1 && !v2) {
    return false;
  }
  const std::size_t state_bytes =
      v1 ? kCalibStateV1Bytes : (v2 ? kCalibStateV2Bytes : sizeof(CalibState));
  CalibState s;
  std::memcpy(&s, bytes.data(), state_bytes);
  if (v2) {
    if (s.version != 2) {
      return false;
    }
    convert_from_v2(s);
  }
  if (v1) {
    if (s.version != 1) {
      return false;
    }
    s.version = CalibState::kVersion;  // for the checks of the version-1 fields
    if (state_problem(s) != nullptr) {
      return false;
    }
    convert_from_v1(s);
  }
  if (state_problem(s) != nullptr) {
    return false;
  }
  calib_.import_state_unchecked(s);
  if (bytes.size() == state_bytes + kWrittenBytes) {
    for (std::size_t a = 0; a < 3; ++a) {
      double w = kNaN;
      std::memcpy(&w, bytes.data() + state_bytes + a * sizeof(double), sizeof w);
      calib_.restore_written(a, w);  // NaN (never written) is ignored
    }
  }
  ++generation_;
  return true;
}

std::size_t CalibrationModule::status(std::span<engine::StatusValue> out) const noexcept {
  const auto& c = calib_;
  std::array<EstimatedDrift, kAxisCount> est{};
  for (std::size_t a = 0; a < kAxisCount; ++a) {
    est[a] = c.estimated_drift(static_cast<Slot>(kAxisSlot[a]), c.last_step_ns());
  }
  const engine::StatusValue values[] = {
      {"phase", 0.0, to_string(c.phase())},
      {"request", 0.0, to_string(c.request())},
      {"x_written_um", c.written_um(0), nullptr},
      {"y_written_um", c.written_um(1), nullptr},
      {"z_written_um", c.written_um(2), nullptr},
      {"x_last_drift_um", c.model(Slot::kXLateral).anchor_drift_um, nullptr},
      {"y_last_drift_um", c.model(Slot::kY).anchor_drift_um, nullptr},
      {"z_last_drift_um", c.model(Slot::kZ).anchor_drift_um, nullptr},
      {"grind_dx_um", c.grind_correction_um(), nullptr},
      {"x_estimate_um", est[0].mean_um, nullptr},
      {"x_estimate_sigma_um", est[0].sigma_um, nullptr},
      {"y_estimate_um", est[1].mean_um, nullptr},
      {"y_estimate_sigma_um", est[1].sigma_um, nullptr},
      {"z_estimate_um", est[2].mean_um, nullptr},
      {"z_estimate_sigma_um", est[2].sigma_um, nullptr},
      // The estimator's level noise per axis (its measuring slot) and where it comes from.
      {"level_noise", 0.0,
       c.config().prediction != Prediction::kEstimator
           ? "unused"
           : (c.level_noise_learned() ? "learned" : "configured")},
      {"x_level_noise_um_per_h", c.level_noise_um_per_h(Slot::kXLateral), nullptr},
      {"y_level_noise_um_per_h", c.level_noise_um_per_h(Slot::kY), nullptr},
      {"z_level_noise_um_per_h", c.level_noise_um_per_h(Slot::kZ), nullptr},
      {"commands_refused", static_cast<double>(snapshot_.commands_refused), nullptr},
  };
  static_assert(std::size(values) <= engine::kMaxStatusValues);
  std::size_t w = 0;
  for (const auto& v : values) {
    if (w == out.size()) break;
    out[w++] = v;
  }
  return w;
}

}  // namespace nccomp::core::calib
