#include "sim/ncsim/nc_registers.hpp"

#include <cmath>

namespace nccomp::sim::ncsim {

OffsetRegisters::OffsetRegisters(std::vector<std::uint16_t> known, double limit_um,
                                 double latency_s)
    : value_(kRegisterSpace, 0.0),
      known_(kRegisterSpace, false),
      last_written_(kRegisterSpace, 0.0),
      limit_um_(limit_um),
      latency_s_(latency_s) {
  for (const std::uint16_t k : known) {
    known_[k] = true;
  }
}

WriteResult OffsetRegisters::write(double t_s, std::uint16_t register_index, double value_um) {
  if (!known_[register_index]) {
    ++refused_;
    return WriteResult::kUnknownRegister;
  }
  if (!std::isfinite(value_um) || std::fabs(value_um) > limit_um_) {
    ++refused_;
    return WriteResult::kOutOfRange;
  }
  const double eff = t_s + latency_s_;
  pending_.push_back({eff, register_index, value_um});
  last_written_[register_index] = value_um;
  log_.push_back({t_s, register_index, value_um, eff});
  return WriteResult::kAccepted;
}

void OffsetRegisters::advance(double t_s) {
  while (!pending_.empty() && pending_.front().effective_t_s <= t_s) {
    value_[pending_.front().index] = pending_.front().value_um;
    pending_.pop_front();
  }
}

double OffsetRegisters::value(std::int32_t register_index) const {
  if (register_index < 0 || register_index >= static_cast<std::int32_t>(kRegisterSpace)) {
    return 0.0;
  }
  return value_[static_cast<std::size_t>(register_index)];
}

bool OffsetRegisters::known(std::int32_t register_index) const {
  return register_index >= 0 && register_index < static_cast<std::int32_t>(kRegisterSpace) &&
         known_[static_cast<std::size_t>(register_index)];
}

bool OffsetRegisters::preset(std::uint16_t register_index, double value_um) {
  if (!known_[register_index] || !std::isfinite(value_um) || std::fabs(value_um) > limit_um_) {
    return false;
  }
  value_[register_index] = value_um;
  last_written_[register_index] = value_um;
  preset_.push_back(register_index);
  return true;
}

std::vector<std::pair<std::uint16_t, double>> OffsetRegisters::held_values() const {
  std::vector<bool> seen(kRegisterSpace, false);
  for (const std::uint16_t i : preset_) seen[i] = true;
  for (const WriteRow& w : log_) seen[w.register_index] = true;
  std::vector<std::pair<std::uint16_t, double>> out;
  for (std::size_t i = 0; i < kRegisterSpace; ++i) {
    if (seen[i]) out.emplace_back(static_cast<std::uint16_t>(i), last_written_[i]);
  }
  return out;
}

std::vector<std::pair<std::uint16_t, double>> OffsetRegisters::last_values() const {
  std::vector<std::pair<std::uint16_t, double>> out;
  std::vector<bool> seen(kRegisterSpace, false);
  for (const WriteRow& w : log_) {
    if (!seen[w.register_index]) {
      seen[w.register_index] = true;
      out.emplace_back(w.register_index, last_written_[w.register_index]);
    }
  }
  return out;
}

}  // namespace nccomp::sim::ncsim
