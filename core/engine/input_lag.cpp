#include "core/engine/input_lag.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <limits>
#include <stdexcept>
#include <string>

namespace nccomp::core::engine {

namespace {

constexpr std::uint32_t kMagic = 0x47414c4eU;  // "NLAG"

template <typename T>
void put(std::byte* p, std::size_t& at, const T& v) noexcept {
  std::memcpy(p + at, &v, sizeof(T));
  at += sizeof(T);
}
template <typename T>
T get(const std::byte* p, std::size_t& at) noexcept {
  T v{};
  std::memcpy(&v, p + at, sizeof(T));
  at += sizeof(T);
  return v;
}

}  // namespace

double lag_step(double y, double u, double dt_s, double tau_s) noexcept {
  if (!(dt_s > 0.0)) return y;
  return u + (y - u) * std::exp(-dt_s / tau_s);
}

void InputLags::configure(std::span<const InputLagSpec> specs) {
  if (specs.size() > kMaxInputLags) {
    throw std::invalid_argument("lags: " + std::to_string(specs.size()) + " entries, at most " +
                                std::to_string(kMaxInputLags));
  }
  for (std::size_t i = 0; i < specs.size(); ++i) {
    const InputLagSpec& s = specs[i];
    const std::string at = "lags[" + std::to_string(i) + "]";
    if (!(s.tau_s > 0.0) || !std::isfinite(s.tau_s)) {
      throw std::invalid_argument(at + ".tau_s: must be > 0 and finite");
    }
    if (s.output_sensor == s.input_sensor) {
      throw std::invalid_argument(at + ".sensor: equals its input sensor");
    }
    for (std::size_t j = 0; j < specs.size(); ++j) {
      if (j < i && specs[j].output_sensor == s.output_sensor) {
        throw std::invalid_argument(at + ".sensor: sensor " + std::to_string(s.output_sensor) +
                                    " is already the output of lags[" + std::to_string(j) + "]");
      }
      if (specs[j].input_sensor == s.output_sensor) {
        throw std::invalid_argument(at + ".sensor: sensor " + std::to_string(s.output_sensor) +
                                    " is the input of lags[" + std::to_string(j) + "]");
      }
    }
  }
  count_ = specs.size();
  for (std::size_t i = 0; i < kMaxInputLags; ++i) {
    specs_[i] = i < count_ ? specs[i] : InputLagSpec{};
    slots_[i] = Slot{};
  }
}

std::size_t InputLags::update(TimeNs now_ns, std::span<const Event> events, std::span<Event> out,
                              std::size_t used) noexcept {
  for (std::size_t i = 0; i < count_; ++i) {
    Slot& s = slots_[i];
    if (s.started && now_ns > s.last_ns) {
      s.value = lag_step(s.value, s.held, seconds(now_ns - s.last_ns), specs_[i].tau_s);
    }
    if (s.started) s.last_ns = std::max(s.last_ns, now_ns);
    for (const Event& e : events) {
      const auto* t = std::get_if<TemperatureSample>(&e);
      if (t == nullptr || t->sensor != specs_[i].input_sensor) continue;
      if (!std::isfinite(t->temperature_c)) continue;
      if (!s.started) {
        s.value = t->temperature_c;
        s.last_ns = now_ns;
        s.started = true;
      }
      s.held = t->temperature_c;
    }
    if (s.started && used < out.size()) {
      out[used++] = TemperatureSample{now_ns, specs_[i].output_sensor, s.value};
    }
  }
  return used;
}

double InputLags::value(std::size_t i) const noexcept {
  if (i >= count_ || !slots_[i].started) return std::numeric_limits<double>::quiet_NaN();
  return slots_[i].value;
}

std::size_t InputLags::save(std::span<std::byte> buf) const noexcept {
  if (buf.size() < kStateBytes) return 0;
  std::byte* p = buf.data();
  std::size_t at = 0;
  put(p, at, kMagic);
  put(p, at, static_cast<std::uint32_t>(count_));
  for (std::size_t i = 0; i < kMaxInputLags; ++i) {
    const Slot& s = slots_[i];
    put(p, at, specs_[i].input_sensor);
    put(p, at, specs_[i].output_sensor);
    put(p, at, specs_[i].tau_s);
    put(p, at, s.started ? s.value : std::numeric_limits<double>::quiet_NaN());
    put(p, at, s.held);
    put(p, at, s.last_ns);
  }
  return at;
}

bool InputLags::load(std::span<const std::byte> bytes, TimeNs now_ns) noexcept {
  if (bytes.size() != kStateBytes) return false;
  const std::byte* p = bytes.data();
  std::size_t at = 0;
  if (get<std::uint32_t>(p, at) != kMagic) return false;
  const auto n = get<std::uint32_t>(p, at);
  if (n > kMaxInputLags) return false;
  std::array<InputLagSpec, kMaxInputLags> saved{};
  std::array<Slot, kMaxInputLags> read{};
  for (std::size_t i = 0; i < kMaxInputLags; ++i) {
    saved[i].input_sensor = get<std::uint8_t>(p, at);
    saved[i].output_sensor = get<std::uint8_t>(p, at);
    saved[i].tau_s = get<double>(p, at);
    read[i].value = get<double>(p, at);
    read[i].held = get<double>(p, at);
    read[i].last_ns = get<TimeNs>(p, at);
    read[i].started = std::isfinite(read[i].value);
    if (read[i].started && !std::isfinite(read[i].held)) return false;
  }
  for (std::size_t i = 0; i < count_; ++i) {
    slots_[i] = Slot{};
    for (std::size_t j = 0; j < n; ++j) {
      if (saved[j].input_sensor != specs_[i].input_sensor ||
          saved[j].output_sensor != specs_[i].output_sensor ||
          std::bit_cast<std::uint64_t>(saved[j].tau_s) !=
              std::bit_cast<std::uint64_t>(specs_[i].tau_s) ||
          !read[j].started) {
        continue;
      }
      Slot s = read[j];
      if (now_ns > s.last_ns) {
        s.value = lag_step(s.value, s.held, seconds(now_ns - s.last_ns), specs_[i].tau_s);
      }
      s.last_ns = now_ns;
      slots_[i] = s;
      break;
    }
  }
  return true;
}

}  // namespace nccomp::core::engine
