// ncsim's Modbus side: publishes the NC state and events into sim/modbus_nc's NcServer tables by
// the daemon's own register map (drivers/modbus config), and takes offset writes off it with the
// NC's range check (a refused write is answered with exception 3, the register keeps its value).
//
// Events ride on sequence counters (reference-nc-modbus.toml): per publish() at most one new
// event per group is put out, the rest wait, so a poller that sees every publish loses none
// (lock-step: one poll per cycle). hold_s keeps an event on the registers at least that long
// (wall time) before the next of its group, for a daemon polling in real time.
#pragma once

#include <array>
#include <chrono>
#include <cstdint>
#include <deque>
#include <mutex>
#include <vector>

#include "core/common/types.hpp"
#include "drivers/modbus/config.hpp"
#include "sim/modbus_nc/nc_server.hpp"
#include "sim/ncsim/nc_link.hpp"

namespace nccomp::sim::ncsim {

class ModbusLink final : public NcLink {
 public:
  /// port < 0: the map's port; 0: ephemeral. limit_um: the NC's range check [µm].
  ModbusLink(drivers::modbus::ModbusConfig map, int port, double limit_um);
  void start() override;
  void stop() override;
  [[nodiscard]] std::uint16_t port() const override { return server_.port(); }
  /// Requests the server answered so far (any client).
  [[nodiscard]] std::uint64_t requests() const noexcept { return server_.requests(); }

  /// Queues events, then publishes the state and the next event of each group.
  void publish(const core::AxisSample& axis, const std::array<double, 2>& temperatures_c,
               const std::vector<core::Event>& events, double hold_s) override;
  /// Modbus needs no marker: a write request is answered before the daemon's flush() returns.
  void before_tick(std::uint64_t /*cycle*/) override {}
  bool after_done(std::uint64_t /*cycle*/, double /*timeout_s*/) override { return true; }
  /// Offset writes accepted since the last call, in arrival order.
  std::vector<ReceivedOffset> take_writes() override;
  /// The holding registers of the preset offsets, encoded as the daemon writes them.
  void preset_offsets(const std::vector<std::pair<std::uint16_t, double>>& values) override;
  /// Events not mapped in the register map (never published).
  [[nodiscard]] std::uint64_t events_unmapped() const noexcept { return unmapped_; }
  [[nodiscard]] std::uint64_t writes_refused() const override;
  /// True while events wait to be published.
  [[nodiscard]] bool events_pending() const override;
  [[nodiscard]] bool client_ready() const override {
    return server_.requests() >= 2 * map_.blocks.size();
  }
  [[nodiscard]] const drivers::modbus::ModbusConfig& map() const noexcept { return map_; }

 private:
  bool filter(const modbus_nc::WriteRecord& w);

  drivers::modbus::ModbusConfig map_;
  double limit_um_;
  modbus_nc::NcServer server_;
  std::array<std::deque<core::Event>, drivers::modbus::kGroupCount> queue_{};
  std::array<std::uint16_t, drivers::modbus::kGroupCount> sequence_{};
  std::array<std::chrono::steady_clock::time_point, drivers::modbus::kGroupCount> last_put_{};
  std::uint64_t unmapped_{0};
  mutable std::mutex mutex_;  // writes_ / refused_ (server thread → main thread)
  std::vector<ReceivedOffset> writes_;
  std::uint64_t refused_{0};
};

}  // namespace nccomp::sim::ncsim
