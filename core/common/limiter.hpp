// The offset limiter: every value sent to the NC passes it (architecture.md, "Safety").
//
// - NaN / ±inf: rejected, the output holds its last value.
// - |value| > max_abs_um: rejected, the output holds its last value.
// - change beyond max_step_um per write or max_rate_um_per_s · Δt: slewed — the output moves
//   toward the target by the allowed amount (a rate cap, like Sinumerik's MD32760 or LinuxCNC's
//   external-offset velocity), and keeps moving on later writes.
// - No value beyond max_abs_um is ever returned as passed or slewed: from an origin beyond it
//   (reset() to what an NC held) the first move lands on the bound, not max_step_um inward.
//
// Rejections are alarms; slewing is a warning. Measurements that would push a target beyond
// max_abs_um must be refused by the module before they change any state (admissible()).
#pragma once

#include <cstdint>

#include "core/common/types.hpp"

namespace nccomp::core {

struct LimiterConfig {
  /// Largest absolute offset accepted [µm].
  double max_abs_um{200.0};
  /// Largest change of the output in one write [µm].
  double max_step_um{5.0};
  /// Largest change of the output per second [µm/s].
  double max_rate_um_per_s{50.0};
};

enum class LimitVerdict : std::uint8_t {
  kPassed = 0,
  kSlewed = 1,
  kRejectedNonFinite = 2,
  kRejectedAbsolute = 3,
};

struct LimitResult {
  /// The value to write [µm] (the held value on rejection).
  double value_um{0.0};
  LimitVerdict verdict{LimitVerdict::kPassed};
  [[nodiscard]] bool rejected() const {
    return verdict == LimitVerdict::kRejectedNonFinite ||
           verdict == LimitVerdict::kRejectedAbsolute;
  }
};

struct LimiterCounters {
  std::uint64_t passed{0};
  std::uint64_t slewed{0};
  std::uint64_t rejected_non_finite{0};
  std::uint64_t rejected_absolute{0};
};

class OffsetLimiter {
 public:
  OffsetLimiter() = default;

  /// Validates and stores the limits. Not real-time (may throw std::invalid_argument naming the
  /// offending field).
  void configure(const LimiterConfig& config);

  /// Sets the output to the value the NC holds now (start-up, after restart or read-back); a
  /// non-finite value keeps the last output (only the time is taken). Real-time safe.
  void reset(double current_um, TimeNs now_ns) noexcept;

  /// Limits one write toward target_um at time now_ns. Real-time safe: no allocation, no locks,
  /// no I/O.
  [[nodiscard]] LimitResult apply(double target_um, TimeNs now_ns) noexcept;

  /// True if target_um is finite and inside ±max_abs_um. Real-time safe.
  [[nodiscard]] bool admissible(double target_um) const noexcept;

  [[nodiscard]] double output_um() const noexcept { return output_um_; }
  [[nodiscard]] const LimiterConfig& config() const noexcept { return config_; }
  [[nodiscard]] const LimiterCounters& counters() const noexcept { return counters_; }

 private:
  LimiterConfig config_{};
  double output_um_{0.0};
  TimeNs last_ns_{0};
  bool has_time_{false};
  LimiterCounters counters_{};
};

}  // namespace nccomp::core
