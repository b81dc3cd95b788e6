// The NC side of the CAN bus, driven by the same signal map as the daemon's driver: encodes core
// events into the NC's frames (the reverse of FrameDecoder) and takes offset writes off the bus,
// acknowledging them the way the reference NC does (echo of the payload on the ack ID).
// Reused by the HIL tests, the CAN benchmark and, later, `ncsim`.
//
// Not real-time; one thread uses a node at a time.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "core/common/types.hpp"
#include "drivers/can/can_mapping.hpp"

namespace nccomp::sim::can_nc {

/// One CAN frame as the NC sends it.
struct Frame {
  std::uint32_t id{0};
  bool extended{false};
  std::uint8_t length_bytes{0};
  std::array<std::uint8_t, drivers::can::kMaxPayloadBytes> data{};
};

/// The frames that carry an event in the mapping, the emitting frame last. Throws
/// std::invalid_argument if a value does not fit its signal or the event kind is not mapped.
std::vector<Frame> encode_event(const drivers::can::CanMapping& mapping, const core::Event& event);

/// An offset write the NC received.
struct ReceivedWrite {
  std::uint16_t register_index{0};
  double value_um{0.0};
  Frame frame{};
};

class CanNcNode {
 public:
  /// Opens a CAN_RAW socket on interface (receives only the offset write IDs). Throws on error.
  CanNcNode(const drivers::can::CanMapping& mapping, const std::string& interface);
  ~CanNcNode();
  CanNcNode(const CanNcNode&) = delete;
  CanNcNode& operator=(const CanNcNode&) = delete;

  void send(const Frame& frame);
  void send_event(const core::Event& event);

  /// Waits up to timeout_ms for an offset write; acknowledges it if `acknowledge` and the
  /// register has an ack ID.
  std::optional<ReceivedWrite> receive_write(int timeout_ms);

  /// false: writes are taken but never acknowledged (to test the driver's timeout path).
  bool acknowledge{true};
  [[nodiscard]] int fd() const { return sock_; }

 private:
  const drivers::can::CanMapping& mapping_;
  int sock_{-1};
};

}  // namespace nccomp::sim::can_nc
