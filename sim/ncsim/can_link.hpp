// ncsim's CAN side: publishes the NC state and events as the daemon's CAN map says (frames
// built by sim/can_nc's encode_event), takes offset writes with the NC's range check (an accepted
// write is acknowledged by echoing its payload on the map's ack ID; a refused one is not
// acknowledged, so the daemon's driver retries and then raises its alarm), and does the CAN part
// of lock-step (contract C2): SYNC (ID 0x7F0, 8 bytes = cycle, little-endian) after the cycle's
// frames; after DONE, reads the bus until the daemon's SYNC-ACK (0x7F1) of that cycle.
#pragma once

#include <string>

#include "drivers/can/can_config.hpp"
#include "sim/ncsim/nc_link.hpp"

namespace nccomp::sim::ncsim {

inline constexpr std::uint32_t kCanSyncId = 0x7F0;
inline constexpr std::uint32_t kCanSyncAckId = 0x7F1;

class CanLink final : public NcLink {
 public:
  CanLink(drivers::can::CanConfig config, std::string interface, double limit_um);
  ~CanLink() override;
  CanLink(const CanLink&) = delete;
  CanLink& operator=(const CanLink&) = delete;

  /// Opens a CAN_RAW socket on the interface (offset write IDs and SYNC-ACK only). Throws.
  void start() override;
  void stop() override;
  void publish(const core::AxisSample& axis, const std::array<double, 2>& temperatures_c,
               const std::vector<core::Event>& events, double hold_s) override;
  void before_tick(std::uint64_t cycle) override;
  bool after_done(std::uint64_t cycle, double timeout_s) override;
  std::vector<ReceivedOffset> take_writes() override;
  [[nodiscard]] std::uint64_t writes_refused() const override { return refused_; }
  [[nodiscard]] bool events_pending() const override { return false; }
  [[nodiscard]] bool client_ready() const override { return true; }
  [[nodiscard]] std::uint16_t port() const override { return 0; }
  [[nodiscard]] std::uint64_t events_unmapped() const noexcept { return unmapped_; }

 private:
  /// Reads one frame (waiting up to timeout_ms, 0 = not at all); handles writes. Returns the
  /// SYNC-ACK cycle if the frame was one, -1 for other frames, -2 when nothing came.
  long long read_one(int timeout_ms);

  drivers::can::CanConfig config_;
  std::string interface_;
  double limit_um_;
  int sock_{-1};
  std::vector<ReceivedOffset> writes_;
  std::uint64_t refused_{0};
  std::uint64_t unmapped_{0};
  std::array<double, 2> last_temperature_c_{-1e9, -1e9};
};

}  // namespace nccomp::sim::ncsim
