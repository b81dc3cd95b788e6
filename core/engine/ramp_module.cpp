#include "core/engine/ramp_module.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <stdexcept>
#include <utility>

namespace nccomp::core::engine {

namespace {
constexpr std::uint32_t kRampStateVersion = 1;
struct RampState {
  std::uint32_t version;
  std::uint32_t reserved;
  double value_um;
  double target_um;
};
}  // namespace

RampModule::RampModule(RampConfig config) : config_(std::move(config)) {
  if (!std::isfinite(config_.start_um) || !std::isfinite(config_.target_um)) {
    throw std::invalid_argument("ramp '" + config_.name +
                                "': start_um and target_um must be finite");
  }
  if (!std::isfinite(config_.rate_um_per_s) || config_.rate_um_per_s <= 0.0) {
    throw std::invalid_argument("ramp '" + config_.name + "': rate_um_per_s must be > 0");
  }
  value_um_ = config_.start_um;
}

void RampModule::attach(const RegisterTable& registers) {
  const int idx = registers.find(config_.register_name);
  if (idx < 0) {
    throw std::invalid_argument("ramp '" + config_.name + "': no register named '" +
                                config_.register_name + "'");
  }
  register_index_ = static_cast<std::uint16_t>(idx);
}

bool RampModule::done() const noexcept { return std::fabs(value_um_ - config_.target_um) <= 0.0; }

void RampModule::step(TimeNs now_ns, std::span<const Event> /*events*/, StepOutput& out) noexcept {
  // The first step after start or restore only takes the time: the ramp resumes from its value,
  // it does not make up for the time the daemon was down.
  const double dt_s = has_last_ ? std::max(0.0, seconds(now_ns - last_ns_)) : 0.0;
  last_ns_ = now_ns;
  has_last_ = true;
  const double remaining = config_.target_um - value_um_;
  const double advance = std::min(std::fabs(remaining), config_.rate_um_per_s * dt_s);
  if (advance > 0.0) {
    value_um_ = std::fabs(remaining) <= advance ? config_.target_um
                                                : value_um_ + std::copysign(advance, remaining);
    ++generation_;
  }
  out.writes.push(OffsetWrite{now_ns, register_index_, value_um_});
}

bool RampModule::adopt_output(std::uint16_t register_index, double nc_value_um, TimeNs /*now_ns*/) {
  if (register_index != register_index_ || !std::isfinite(nc_value_um)) {
    return false;
  }
  value_um_ = nc_value_um;
  has_last_ = false;
  ++generation_;
  return true;
}

std::size_t RampModule::state_capacity() const noexcept { return sizeof(RampState); }

std::size_t RampModule::save_state(std::span<std::byte> buf) const noexcept {
  if (buf.size() < sizeof(RampState)) {
    return 0;
  }
  const RampState s{kRampStateVersion, 0, value_um_, config_.target_um};
  std::memcpy(buf.data(), &s, sizeof(s));
  return sizeof(s);
}

bool RampModule::load_state(std::span<const std::byte> bytes) noexcept {
  if (bytes.size() != sizeof(RampState)) {
    return false;
  }
  RampState s{};
  std::memcpy(&s, bytes.data(), sizeof(s));
  if (s.version != kRampStateVersion || !std::isfinite(s.value_um) || !std::isfinite(s.target_um)) {
    return false;
  }
  // A changed target in the config (reload) keeps the progress: the ramp heads for the new one.
  value_um_ = s.value_um;
  has_last_ = false;
  ++generation_;
  return true;
}

}  // namespace nccomp::core::engine
