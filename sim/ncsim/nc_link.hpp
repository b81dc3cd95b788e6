// The bus side of the virtual NC, one implementation per bus (Modbus: modbus_link.hpp, CAN:
// can_link.hpp): publishes the NC's state and events, takes offset writes with the NC's range
// check, and does the bus's part of the lock-step handshake (contract C2). Main thread only.
#pragma once

#include <array>
#include <cstdint>
#include <vector>

#include "core/common/types.hpp"

namespace nccomp::sim::ncsim {

struct ReceivedOffset {
  std::uint16_t register_index{0};
  double value_um{0.0};
};

class NcLink {
 public:
  virtual ~NcLink() = default;
  virtual void start() = 0;
  virtual void stop() = 0;
  /// Publishes the state now and the events raised since the last call. hold_s: keep a polled
  /// event visible at least this long (wall time) before the next of its kind (speed mode).
  virtual void publish(const core::AxisSample& axis, const std::array<double, 2>& temperatures_c,
                       const std::vector<core::Event>& events, double hold_s) = 0;
  /// Lock-step, after publish() and before TICK: CAN sends SYNC(cycle); Modbus nothing.
  virtual void before_tick(std::uint64_t cycle) = 0;
  /// Lock-step, after DONE: returns once every write the daemon pushed in this cycle is in
  /// take_writes() (CAN: SYNC-ACK(cycle) seen; Modbus: already true). False on timeout.
  virtual bool after_done(std::uint64_t cycle, double timeout_s) = 0;
  /// Accepted offset writes since the last call, in arrival order.
  virtual std::vector<ReceivedOffset> take_writes() = 0;
  /// Before start(): the offset registers the NC holds when the run starts, so that a daemon
  /// reading them back sees them (a continued run). Default: the bus has no read-back.
  virtual void preset_offsets(const std::vector<std::pair<std::uint16_t, double>>& values) {
    (void)values;
  }
  /// Writes refused by the NC's range check on the bus side.
  [[nodiscard]] virtual std::uint64_t writes_refused() const = 0;
  /// Events still waiting to be published.
  [[nodiscard]] virtual bool events_pending() const = 0;
  /// Speed mode: has a daemon started polling (Modbus: two polls seen)? CAN: always true.
  [[nodiscard]] virtual bool client_ready() const = 0;
  /// Modbus TCP port (0 for CAN).
  [[nodiscard]] virtual std::uint16_t port() const = 0;
};

}  // namespace nccomp::sim::ncsim
