// Derived inputs: a weighted sum of sensors, offset + Σ weight_i · sensor_i, published as a
// sensor of its own, so that a model fitted off-line over many sensors (temperatures and lags of
// the spindle speed, a ridge fit) can be the one input of a module that takes one sensor (S3's
// drift estimator, [[model.inputs]]).
//
// Inputs are bus sensors and outputs of the lags (input_lag.hpp): the engine updates the lags
// first and hands their samples of the same cycle to the sums. A sum is published once every
// input has had a finite sample, then at every cycle (like the lags) with the last finite sample
// of each input; non-finite samples are not taken (the input keeps its previous value).
//
// The sums hold no state beyond the last sample of each input: they are not saved with the
// engine's state, and after a restart a sum waits for a fresh sample of every input.
//
// Real-time: update() allocates nothing (fixed arrays).
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

#include "core/common/types.hpp"
#include "core/engine/input_lag.hpp"

namespace nccomp::core::engine {

/// Sums one engine follows at most, and inputs of one sum at most.
inline constexpr std::size_t kMaxInputSums = 8;
inline constexpr std::size_t kMaxSumInputs = 32;

struct InputSumSpec {
  /// Sensor the sum is published on (must not be mapped by the bus).
  std::uint8_t output_sensor{0};
  /// Added to the weighted sum; finite.
  double offset{0.0};
  /// Input sensors (bus sensors or lag outputs), 1 … kMaxSumInputs, each once.
  std::vector<std::uint8_t> inputs;
  /// One finite weight per input.
  std::vector<double> weights;
};

class InputSums {
 public:
  /// Not real-time. Throws std::invalid_argument naming the entry (sums[i]) and what is wrong:
  /// no inputs or more than kMaxSumInputs, inputs and weights of different lengths, a weight or
  /// the offset not finite, an input listed twice, the output equal to one of its inputs, an
  /// output used twice or equal to a lag's output or a lag's input (the lags are computed before
  /// the sums), a sum's output used as another sum's input, more than kMaxInputSums entries.
  /// Resets the state.
  void configure(std::span<const InputSumSpec> specs, std::span<const InputLagSpec> lags = {});
  [[nodiscard]] std::size_t size() const noexcept { return count_; }
  [[nodiscard]] std::uint8_t output_sensor(std::size_t i) const noexcept { return out_[i]; }
  [[nodiscard]] std::size_t input_count(std::size_t i) const noexcept { return slots_[i].n; }
  [[nodiscard]] std::uint8_t input_sensor(std::size_t i, std::size_t k) const noexcept {
    return slots_[i].inputs[k];
  }
  [[nodiscard]] double weight(std::size_t i, std::size_t k) const noexcept {
    return slots_[i].weights[k];
  }
  [[nodiscard]] double offset(std::size_t i) const noexcept { return slots_[i].offset; }

  /// Real-time safe. Takes the cycle's (validated) samples of every sum's inputs (the bus's and
  /// the lags' of this cycle), and appends one TemperatureSample per complete sum (its output
  /// sensor, its value) to out from index `used`. Returns the new number of events in out
  /// (samples that do not fit are dropped; out is sized by the caller).
  std::size_t update(TimeNs now_ns, std::span<const Event> events, std::span<Event> out,
                     std::size_t used) noexcept;

  /// The sum's value at the last update; NaN before every input had a sample (or if the sum
  /// overflowed).
  [[nodiscard]] double value(std::size_t i) const noexcept;

 private:
  static constexpr std::int8_t kNone = -1;
  struct Slot {
    std::array<std::uint8_t, kMaxSumInputs> inputs{};
    std::array<double, kMaxSumInputs> weights{};
    std::array<double, kMaxSumInputs> last{};
    /// sensor -> index in inputs (kNone: not an input of this sum).
    std::array<std::int8_t, 256> index{};
    double offset{0.0};
    double value{0.0};
    std::uint32_t seen{0};  // bit k: inputs[k] has had a finite sample
    std::size_t n{0};
    bool valid{false};
  };
  std::array<std::uint8_t, kMaxInputSums> out_{};
  std::array<Slot, kMaxInputSums> slots_{};
  std::size_t count_{0};
};

}  // namespace nccomp::core::engine
