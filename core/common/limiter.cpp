#include "core/common/limiter.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

namespace nccomp::core {

namespace {
void require_positive(double v, const char* name) {
  if (!std::isfinite(v) || v <= 0.0) {
    throw std::invalid_argument(std::string("limiter: ") + name +
                                " must be a positive finite number, got " + std::to_string(v));
  }
}
}  // namespace

void OffsetLimiter::configure(const LimiterConfig& config) {
  require_positive(config.max_abs_um, "max_abs_um");
  require_positive(config.max_step_um, "max_step_um");
  require_positive(config.max_rate_um_per_s, "max_rate_um_per_s");
  config_ = config;
  // A reconfiguration must not let a held value escape the new absolute limit silently: it is
  // kept (the NC holds it), and the next value passed or slewed lies within the new bound.
}

void OffsetLimiter::reset(double current_um, TimeNs now_ns) noexcept {
  // A non-finite value says nothing about what the NC holds: the last value known is kept
  // rather than 0, which the next writes would take for the NC's register.
  if (std::isfinite(current_um)) {
    output_um_ = current_um;
  }
  last_ns_ = now_ns;
  has_time_ = true;
}

bool OffsetLimiter::admissible(double target_um) const noexcept {
  return std::isfinite(target_um) && std::fabs(target_um) <= config_.max_abs_um;
}

LimitResult OffsetLimiter::apply(double target_um, TimeNs now_ns) noexcept {
  if (!std::isfinite(target_um)) {
    ++counters_.rejected_non_finite;
    return {output_um_, LimitVerdict::kRejectedNonFinite};
  }
  if (std::fabs(target_um) > config_.max_abs_um) {
    ++counters_.rejected_absolute;
    return {output_um_, LimitVerdict::kRejectedAbsolute};
  }
  double allowed = config_.max_step_um;
  if (has_time_) {
    const double dt_s = std::max(0.0, seconds(now_ns - last_ns_));
    allowed = std::min(allowed, config_.max_rate_um_per_s * dt_s);
  }
  const double change = target_um - output_um_;
  LimitVerdict verdict = LimitVerdict::kPassed;
  double out = target_um;
  if (std::fabs(change) > allowed) {
    // From an origin beyond max_abs_um (an NC that held such a value) the slewed value is
    // brought inside the bound: no value beyond it ever leaves the limiter.
    out = std::clamp(output_um_ + std::copysign(allowed, change), -config_.max_abs_um,
                     config_.max_abs_um);
    verdict = LimitVerdict::kSlewed;
    ++counters_.slewed;
  } else {
    ++counters_.passed;
  }
  output_um_ = out;
  // An earlier stamp than the last one moves the clock back with it: a clock that restarted (a
  // state from before a reboot, a lock-step peer's clock) must not freeze the output until it
  // catches up. The write with the earlier stamp itself was allowed no change (dt clamped to 0).
  last_ns_ = now_ns;
  has_time_ = true;
  return {out, verdict};
}

}  // namespace nccomp::core
