#include "core/engine/input_sum.hpp"

#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

namespace nccomp::core::engine {

namespace {

std::string num(std::size_t v) { return std::to_string(v); }

}  // namespace

void InputSums::configure(std::span<const InputSumSpec> specs, std::span<const InputLagSpec> lags) {
  if (specs.size() > kMaxInputSums) {
    throw std::invalid_argument("sums: " + num(specs.size()) + " entries, at most " +
                                num(kMaxInputSums));
  }
  for (std::size_t i = 0; i < specs.size(); ++i) {
    const InputSumSpec& s = specs[i];
    const std::string at = "sums[" + num(i) + "]";
    if (s.inputs.empty() || s.inputs.size() > kMaxSumInputs) {
      throw std::invalid_argument(at + ".inputs: " + num(s.inputs.size()) + " sensors, 1..." +
                                  num(kMaxSumInputs) + " expected");
    }
    if (s.weights.size() != s.inputs.size()) {
      throw std::invalid_argument(at + ".weights: " + num(s.weights.size()) + " weights for " +
                                  num(s.inputs.size()) + " inputs");
    }
    if (!std::isfinite(s.offset)) {
      throw std::invalid_argument(at + ".offset: must be finite");
    }
    for (std::size_t k = 0; k < s.inputs.size(); ++k) {
      if (!std::isfinite(s.weights[k])) {
        throw std::invalid_argument(at + ".weights[" + num(k) + "]: must be finite");
      }
      if (s.inputs[k] == s.output_sensor) {
        throw std::invalid_argument(at + ".sensor: equals its inputs[" + num(k) + "]");
      }
      for (std::size_t m = 0; m < k; ++m) {
        if (s.inputs[m] == s.inputs[k]) {
          throw std::invalid_argument(at + ".inputs[" + num(k) + "]: sensor " + num(s.inputs[k]) +
                                      " is already inputs[" + num(m) + "]");
        }
      }
    }
    for (std::size_t j = 0; j < specs.size(); ++j) {
      if (j < i && specs[j].output_sensor == s.output_sensor) {
        throw std::invalid_argument(at + ".sensor: sensor " + num(s.output_sensor) +
                                    " is already the output of sums[" + num(j) + "]");
      }
      for (const std::uint8_t in : specs[j].inputs) {
        if (j != i && in == s.output_sensor) {
          throw std::invalid_argument(at + ".sensor: sensor " + num(s.output_sensor) +
                                      " is an input of sums[" + num(j) + "] (no sum of a sum)");
        }
      }
    }
    for (std::size_t j = 0; j < lags.size(); ++j) {
      if (lags[j].output_sensor == s.output_sensor) {
        throw std::invalid_argument(at + ".sensor: sensor " + num(s.output_sensor) +
                                    " is the output of lags[" + num(j) + "]");
      }
      if (lags[j].input_sensor == s.output_sensor) {
        throw std::invalid_argument(at + ".sensor: sensor " + num(s.output_sensor) +
                                    " is the input of lags[" + num(j) +
                                    "] (the lags are computed before the sums)");
      }
    }
  }
  count_ = specs.size();
  for (std::size_t i = 0; i < kMaxInputSums; ++i) {
    Slot& slot = slots_[i];
    slot = Slot{};
    slot.index.fill(kNone);
    out_[i] = 0;
    if (i >= count_) continue;
    const InputSumSpec& s = specs[i];
    out_[i] = s.output_sensor;
    slot.n = s.inputs.size();
    slot.offset = s.offset;
    for (std::size_t k = 0; k < slot.n; ++k) {
      slot.inputs[k] = s.inputs[k];
      slot.weights[k] = s.weights[k];
      slot.index[s.inputs[k]] = static_cast<std::int8_t>(k);
    }
  }
}

std::size_t InputSums::update(TimeNs now_ns, std::span<const Event> events, std::span<Event> out,
                              std::size_t used) noexcept {
  if (count_ == 0) return used;
  for (const Event& e : events) {
    const auto* t = std::get_if<TemperatureSample>(&e);
    if (t == nullptr || !std::isfinite(t->temperature_c)) continue;
    for (std::size_t i = 0; i < count_; ++i) {
      Slot& s = slots_[i];
      const std::int8_t k = s.index[t->sensor];
      if (k == kNone) continue;
      s.last[static_cast<std::size_t>(k)] = t->temperature_c;
      s.seen |= std::uint32_t{1} << static_cast<unsigned>(k);
    }
  }
  for (std::size_t i = 0; i < count_; ++i) {
    Slot& s = slots_[i];
    const std::uint32_t all =
        s.n == 32 ? ~std::uint32_t{0} : (std::uint32_t{1} << static_cast<unsigned>(s.n)) - 1U;
    if (s.seen != all) continue;
    double v = s.offset;
    for (std::size_t k = 0; k < s.n; ++k) v += s.weights[k] * s.last[k];
    s.valid = std::isfinite(v);
    if (!s.valid) continue;  // an overflow: no value rather than inf
    s.value = v;
    if (used < out.size()) out[used++] = TemperatureSample{now_ns, out_[i], v};
  }
  return used;
}

double InputSums::value(std::size_t i) const noexcept {
  if (i >= count_ || !slots_[i].valid) return std::numeric_limits<double>::quiet_NaN();
  return slots_[i].value;
}

}  // namespace nccomp::core::engine
