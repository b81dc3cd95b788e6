// Derived inputs: the first-order lag of a temperature sensor (any scalar the bus map publishes
// on a sensor channel), published as a sensor of its own, so that every user of a mapped sensor
// (S3's temperature model, the model's extra columns, the measurement log's context) can take the
// lagged value instead of the raw one.
//
// Discretisation (exact for an input held between samples, whatever the interval): over an
// interval dt the input held since the previous sample u drives
//   y += (1 - exp(-dt / tau)) (u - y),
// then the new sample becomes the held input. This is the discretisation of `nccomp analyze`'s
// lag terms (core/model advance_state), so a lag fitted by the analysis and this lag agree on the
// same series. The lag starts at the input's first value (the machine at rest before).
//
// Real-time: update(), save() and load() allocate nothing (fixed arrays).
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <span>

#include "core/common/types.hpp"

namespace nccomp::core::engine {

struct InputLagSpec {
  /// Sensor whose samples are lagged.
  std::uint8_t input_sensor{0};
  /// Sensor the lagged value is published on (must not be mapped by the bus).
  std::uint8_t output_sensor{0};
  /// Time constant [s], > 0 and finite.
  double tau_s{0.0};
};

/// Lags one engine follows at most.
inline constexpr std::size_t kMaxInputLags = 16;

/// Real-time safe. One exact step of a first-order lag: y after dt_s [s] with the input u held.
[[nodiscard]] double lag_step(double y, double u, double dt_s, double tau_s) noexcept;

class InputLags {
 public:
  /// Not real-time. Throws std::invalid_argument naming the entry (lags[i]) and what is wrong:
  /// tau_s not > 0 or not finite, output equal to the input, an output used twice, an output that
  /// is another lag's input, more than kMaxInputLags entries. Resets the state.
  void configure(std::span<const InputLagSpec> specs);
  [[nodiscard]] std::size_t size() const noexcept { return count_; }
  [[nodiscard]] const InputLagSpec& spec(std::size_t i) const noexcept { return specs_[i]; }

  /// Real-time safe. Advances every lag to now_ns with the input it held, takes the cycle's
  /// (validated) samples of its input, and appends one TemperatureSample per started lag (its
  /// output sensor, its value) to out from index `used`. Returns the new number of events in
  /// out (samples that do not fit are dropped; out is sized by the caller).
  std::size_t update(TimeNs now_ns, std::span<const Event> events, std::span<Event> out,
                     std::size_t used) noexcept;

  /// The lag's value; NaN before its input's first sample.
  [[nodiscard]] double value(std::size_t i) const noexcept;

  /// Bytes of save()'s output (fixed).
  static constexpr std::size_t kStateBytes = 4 + 4 + kMaxInputLags * (1 + 1 + 8 + 8 + 8 + 8);
  /// Real-time safe. Writes the lags' values, held inputs and times; returns kStateBytes, or 0
  /// if buf is too small.
  std::size_t save(std::span<std::byte> buf) const noexcept;
  /// Real-time safe. Restores save()'s output for the lags configured now (matched by input,
  /// output and tau_s; others start afresh). A clock that went forward since the save (a
  /// restart within one boot) decays each lag over the downtime with the input it held; a clock
  /// that went back (a reboot) keeps the value, the downtime being unknown. False (nothing
  /// changed) if the bytes are not a valid state.
  bool load(std::span<const std::byte> bytes, TimeNs now_ns) noexcept;

 private:
  struct Slot {
    double value{0.0};
    double held{0.0};
    TimeNs last_ns{0};
    bool started{false};
  };
  std::array<InputLagSpec, kMaxInputLags> specs_{};
  std::array<Slot, kMaxInputLags> slots_{};
  std::size_t count_{0};
};

}  // namespace nccomp::core::engine
