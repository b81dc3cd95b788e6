// The reconnect back-off the bus drivers share (docs/modbus.md, docs/can.md): however a link is
// lost (a failed connect, a connection dropped after reads, after a write, after timeouts or
// garbage, an interface that flaps, a bus-off that returns), the next attempt waits the current
// back-off, which then doubles up to its cap. It returns to the minimum only once a link stayed
// healthy for reset_after: one answered read does not reset it, so a peer that answers and then
// drops the connection cannot make the I/O thread reconnect at once, again and again (at
// SCHED_FIFO that would starve every normal thread on its CPU).
//
// Pure logic: time comes in as an argument. Real-time safe: no allocation, no lock, no I/O.
#pragma once

#include <algorithm>
#include <cstdint>

#include "core/common/types.hpp"

namespace nccomp::drivers {

class ReconnectBackoff {
 public:
  /// min_ns <= max_ns, both > 0 (the config parsers check it).
  ReconnectBackoff(core::TimeNs min_ns, core::TimeNs max_ns, core::TimeNs reset_after_ns) noexcept
      : min_ns_(min_ns), max_ns_(max_ns), reset_after_ns_(reset_after_ns), delay_ns_(min_ns) {}

  /// The link was lost (or an attempt failed) at now_ns. Returns when the next attempt may
  /// start: now_ns + the current back-off, which then doubles (capped). Real-time safe.
  core::TimeNs lost(core::TimeNs now_ns) noexcept {
    if (healthy_since_ns_ != kNever && now_ns - healthy_since_ns_ >= reset_after_ns_) {
      delay_ns_ = min_ns_;  // it was healthy long enough before this failure
    }
    healthy_since_ns_ = kNever;
    const core::TimeNs wait = delay_ns_;
    delay_ns_ = std::min(delay_ns_ * 2, max_ns_);
    ++waits_;
    return now_ns + wait;
  }

  /// After each stretch of work on the link (a poll cycle, a recovery check): ok = everything
  /// in it succeeded (reads answered, writes accepted, no timeout, no garbage, no fault). A link
  /// that stays ok for reset_after brings the back-off back to its minimum; one failure restarts
  /// that clock. Real-time safe.
  void healthy(core::TimeNs now_ns, bool ok) noexcept {
    if (!ok) {
      healthy_since_ns_ = kNever;
      return;
    }
    if (healthy_since_ns_ == kNever) {
      healthy_since_ns_ = now_ns;
    }
    if (now_ns - healthy_since_ns_ >= reset_after_ns_) {
      delay_ns_ = min_ns_;
    }
  }

  /// The wait the next lost() will schedule [ns]: reconnect_min_s after a healthy stretch,
  /// growing to reconnect_max_s while the link keeps failing.
  [[nodiscard]] core::TimeNs delay_ns() const noexcept { return delay_ns_; }
  /// delay_ns() while above the minimum (the link kept failing), else 0: what status shows, so
  /// that a link that is fine shows nothing.
  [[nodiscard]] core::TimeNs raised_delay_ns() const noexcept {
    return delay_ns_ > min_ns_ ? delay_ns_ : 0;
  }
  /// Waits scheduled so far (one per lost link or failed attempt).
  [[nodiscard]] std::uint64_t waits() const noexcept { return waits_; }

 private:
  static constexpr core::TimeNs kNever = INT64_MIN;
  core::TimeNs min_ns_;
  core::TimeNs max_ns_;
  core::TimeNs reset_after_ns_;
  core::TimeNs delay_ns_;
  core::TimeNs healthy_since_ns_{kNever};
  std::uint64_t waits_{0};
};

}  // namespace nccomp::drivers
