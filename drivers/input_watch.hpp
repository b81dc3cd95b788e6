// When a bus's input counts as stale (BusStatus::input_stale), one rule for every driver: the
// link has not been healthy, or (where the map has axis signals) no valid axis sample has been
// decoded, for longer than the bus's degraded_alarm_after_s. A link that stays "degraded" (an NC
// that answers every Modbus read with an exception, a CAN controller stuck error-passive) or an
// NC that publishes only NaN / out-of-range positions is thereby as loud as a link that is down.
//
// Pure and real-time safe: the driver's I/O thread reports what it saw, with its own clock.
#pragma once

#include <algorithm>

#include "core/common/types.hpp"

namespace nccomp::drivers {

class InputWatch {
 public:
  /// after_ns: degraded_alarm_after_s; axis_expected: the map has axis signals.
  InputWatch(core::TimeNs after_ns, bool axis_expected) noexcept
      : after_ns_(after_ns), axis_expected_(axis_expected) {}

  /// The bus starts (or restarts) being watched: nothing is stale before after_ns from now.
  void start(core::TimeNs now_ns) noexcept {
    link_ok_ns_ = now_ns;
    axis_ok_ns_ = now_ns;
  }
  /// The link was healthy at now_ns (Modbus: every block read; CAN: link up, not error-passive).
  void link_ok(core::TimeNs now_ns) noexcept { link_ok_ns_ = now_ns; }
  /// A valid axis sample was decoded at now_ns.
  void axis_ok(core::TimeNs now_ns) noexcept { axis_ok_ns_ = now_ns; }

  [[nodiscard]] bool stale(core::TimeNs now_ns) const noexcept {
    const core::TimeNs last = axis_expected_ ? std::min(link_ok_ns_, axis_ok_ns_) : link_ok_ns_;
    return now_ns - last > after_ns_;
  }

 private:
  core::TimeNs after_ns_;
  bool axis_expected_;
  core::TimeNs link_ok_ns_{0};
  core::TimeNs axis_ok_ns_{0};
};

}  // namespace nccomp::drivers
