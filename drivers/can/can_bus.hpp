// The SocketCAN driver: one CAN_RAW socket and one I/O thread per interface.
//
// The I/O thread receives (kernel filters from the mapped IDs, error frames on), decodes frames
// with FrameDecoder into core events pushed to rx(), takes offset writes from tx(), sends them and
// waits for the NC's acknowledge where the mapping has one (timeout → re-send → alarm). It rides
// out bus faults without stopping: error-passive (degraded), bus-off (kernel restart-ms or a
// restart it requests over netlink), the interface going down and up or re-created (writes held).
// Its own recovery steps wait a back-off (drivers/reconnect_backoff.hpp): the rebind after the
// interface went down from link_check_s, the restart requests from restart_delay_s, each doubling
// while the bus keeps failing, up to reconnect_max_s, reset after reconnect_reset_after_s up.
// After every recovery each register that holds a value is sent again once, acknowledged or not:
// offsets are absolute, and a frame sent just before the fault may never have reached the NC.
// Every fault is counted in CanStatus and reported through extra_counters() (`nccomp status`).
// The status alarm is raised by a write given up after its retries, and by the link staying down
// or bus-off for longer than alarm_after_s; the latter clears when the bus is back. The input is
// stale (BusStatus::input_stale, input_watch.hpp) when the link has not been up (error-passive
// counts) or, with axis frames mapped, no valid axis sample came, for degraded_alarm_after_s.
//
// Threads: the loop thread is rx()'s only consumer and tx()'s only producer; it never blocks on
// the driver. After pushing into tx() it may call wake() so the write goes out at once (without
// it, the I/O thread notices within 1 ms). status()/can_status() are lock-free from any thread.
#pragma once

#include <array>
#include <atomic>
#include <condition_variable>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <mutex>
#include <span>
#include <string>
#include <thread>
#include <vector>

#include "core/rt/seqlock.hpp"
#include "core/rt/spsc_ring.hpp"
#include "drivers/bus.hpp"
#include "drivers/can/can_config.hpp"
#include "drivers/can/can_mapping.hpp"
#include "drivers/reconnect_backoff.hpp"
#include "drivers/input_watch.hpp"

namespace nccomp::drivers::can {

/// Lock-step (contract C2): the simulated NC ends each cycle's frames with SYNC (this ID, 8 bytes,
/// uint64 cycle little-endian); the daemon answers its flush with SYNC-ACK (same layout).
inline constexpr std::uint32_t kLockstepSyncId = 0x7F0;
inline constexpr std::uint32_t kLockstepSyncAckId = 0x7F1;

/// The CAN driver's own counters, beside the common BusCounters.
struct CanCounters {
  std::uint64_t error_frames{0};         // error frames of any class received
  std::uint64_t error_warning{0};        // controller reached the warning level
  std::uint64_t error_passive{0};        // controller went error-passive
  std::uint64_t bus_off{0};              // bus-off entered
  std::uint64_t bus_recoveries{0};       // bus-off left (restarted frame or traffic again)
  std::uint64_t restart_requests{0};     // netlink restarts asked for (restart = "daemon")
  std::uint64_t restart_failures{0};     // ... refused by the kernel (e.g. vcan: not supported)
  std::uint64_t interface_down{0};       // the interface went down (ENETDOWN / ENODEV)
  std::uint64_t controller_overflow{0};  // CAN_ERR_CRTL_RX/TX_OVERFLOW reported by the controller
  std::uint64_t rx_overflow{0};      // frames the kernel dropped: socket queue full (SO_RXQ_OVFL)
  std::uint64_t enobufs{0};          // ENOBUFS on send: transmit queue full, backed off
  std::uint64_t enobufs_retries{0};  // send rounds retried after an ENOBUFS back-off
  std::uint64_t ack_timeouts{0};     // acknowledge not seen in time (each attempt)
  std::uint64_t ack_retries{0};      // writes re-sent after an acknowledge timeout
  std::uint64_t resent_after_recovery{0};  // held values sent again after a bus recovery
  std::uint64_t link_alarms{0};     // alarm raised: down / bus-off for longer than alarm_after_s
  std::uint64_t tx_unencodable{0};  // offset value does not fit its register's signal
  std::uint64_t tx_unmapped{0};     // offset write for a register without a mapping
  std::uint64_t rejected_unknown_id{0};
  std::uint64_t rejected_wrong_length{0};
  std::uint64_t rejected_out_of_range{0};
  std::uint64_t rejected_not_finite{0};
  std::uint64_t lockstep_syncs{0};      // SYNC frames received (lock-step)
  std::uint64_t lockstep_sync_acks{0};  // SYNC-ACK frames sent (lock-step)
  // Back-off waits of the recovery: interface lost or rebind failed, bus-off or restart refused.
  std::uint64_t reconnect_backoffs{0};
  // Gauge: the longer of the rebind and the restart back-off while raised, 0 at their minimum.
  std::uint64_t reconnect_backoff_ms{0};
};

struct CanStatus {
  BusStatus bus{};
  CanCounters can{};
};

class CanBus final : public Bus {
 public:
  /// Validates nothing more than parse_can_config() did; allocates the rings (not real-time).
  explicit CanBus(CanConfig config);
  ~CanBus() override;
  CanBus(const CanBus&) = delete;
  CanBus& operator=(const CanBus&) = delete;

  /// Opens the socket (throws std::runtime_error naming the interface if it cannot: no such
  /// interface, no AF_CAN, FD mapping on a classic interface, restart = "daemon" without the
  /// rights it needs, see restart_permission_problem()) and starts the I/O thread.
  void start() override;
  void stop() override;

  core::rt::SpscRing<core::Event>& rx() override { return rx_ring_; }
  core::rt::SpscRing<core::OffsetWrite>& tx() override { return tx_ring_; }
  [[nodiscard]] BusStatus status() const override { return status_.load().bus; }
  [[nodiscard]] CanStatus can_status() const { return status_.load(); }
  /// The CanCounters by name (kCanCounterNames order), from one status snapshot. Any thread.
  [[nodiscard]] std::size_t extra_counters(std::span<BusCounterValue> out) const override;

  /// Loop thread, after pushing into tx(): wakes the I/O thread (one eventfd write; no
  /// allocation, no lock, never blocks).
  void wake() noexcept override;

  /// Lock-step (before start()): also receive the SYNC frames (kLockstepSyncId). The mapping
  /// must not use the two lock-step IDs (start() throws otherwise).
  void set_lockstep(bool on) override { lockstep_ = on; }
  /// Returns once the SYNC frame of `cycle` (or a later one) was received: every frame the NC
  /// sent before it is decoded and in rx() (one socket, in order). False on timeout.
  bool sync(std::uint64_t cycle, core::TimeNs timeout_ns) override;
  /// Returns once every write queued before the call was sent and a SYNC-ACK with `cycle` went
  /// out after them. Acknowledges of the writes are not awaited (the NC sends them after it read
  /// the SYNC-ACK). False on timeout (link down, transmit queue full throughout).
  bool flush(std::uint64_t cycle, core::TimeNs timeout_ns) override;

 private:
  enum class WriteState : std::uint8_t { kIdle, kPending, kAwaitAck, kFailed };
  struct Slot {
    const TxRegister* reg{nullptr};
    WriteState state{WriteState::kIdle};
    double value_um{0.0};
    bool has_value{false};  // payload holds the register's latest value (encodable)
    bool resend{false};     // pending because of a recovery: counted when it goes out
    std::uint32_t attempts{0};
    std::int64_t deadline_ns{0};
    std::array<std::uint8_t, kMaxPayloadBytes> payload{};
  };

  void open_socket();
  void close_socket() noexcept;
  void run() noexcept;
  void receive_all(std::int64_t now_ns) noexcept;
  void handle_error_frame(std::uint32_t can_id, const std::uint8_t* data,
                          std::int64_t now_ns) noexcept;
  void handle_ack(std::uint32_t key, const std::uint8_t* data, std::size_t len) noexcept;
  void take_writes() noexcept;
  void send_pending(std::int64_t now_ns) noexcept;
  void check_acks(std::int64_t now_ns) noexcept;
  void link_down(std::int64_t now_ns) noexcept;
  void check_link(std::int64_t now_ns) noexcept;
  void went_down(std::int64_t now_ns) noexcept;
  void recovered() noexcept;
  void queue_full(std::int64_t now_ns) noexcept;
  void publish(std::int64_t now_ns) noexcept;
  Slot* slot_for(std::uint16_t register_index) noexcept;

  CanConfig config_;
  FrameDecoder decoder_;
  core::rt::SpscRing<core::Event> rx_ring_;
  core::rt::SpscRing<core::OffsetWrite> tx_ring_;
  core::rt::Seqlock<CanStatus> status_;
  InputWatch input_watch_;  // I/O thread (start() before it runs)

  // I/O thread state (touched only by it once started).
  CanStatus st_{};
  std::vector<Slot> slots_;  // one per mapped register, sorted by index
  std::vector<std::pair<std::uint32_t, std::size_t>> ack_index_;  // ack key → slot
  int sock_{-1};
  int event_fd_{-1};
  int ifindex_{0};
  bool fd_frames_{false};
  bool bus_off_{false};
  bool if_down_{false};
  std::int64_t down_since_ns_{0};  // when the bus went down / bus-off (0 = up)
  bool link_alarm_{false};         // down for longer than alarm_after_s
  std::int64_t next_link_check_ns_{0};
  std::int64_t next_restart_ns_{0};
  std::int64_t next_rebind_ns_{0};
  ReconnectBackoff rebind_backoff_;   // interface down → rebind
  ReconnectBackoff restart_backoff_;  // bus-off → netlink restart request (restart = "daemon")
  std::int64_t backoff_until_ns_{0};
  std::int64_t backoff_ns_{0};
  std::uint64_t ovfl_base_{0};  // drops counted by sockets closed before
  std::uint32_t ovfl_last_{0};  // the current socket's cumulative drop count

  std::atomic<bool> running_{false};
  std::thread thread_;

  // Lock-step (ls_mu_ guards the request / completion counters; see sync() and flush()).
  bool lockstep_{false};
  std::mutex ls_mu_;
  std::condition_variable ls_cv_;
  std::uint64_t synced_plus1_{0};  // last SYNC cycle + 1 (0 = none yet)
  std::uint64_t flush_req_{0};
  std::uint64_t flush_done_{0};
  std::uint64_t flush_cycle_{0};
  /// I/O thread: the open flush request being served (0 = none).
  std::uint64_t serving_flush_{0};
  std::uint64_t serving_cycle_{0};
  void serve_flush() noexcept;
  void handle_sync(const std::uint8_t* data, std::size_t len) noexcept;
};

/// The names extra_counters() reports, in its order (static strings, snake_case).
inline constexpr std::array<const char*, 26> kCanCounterNames{
    "error_frames",          "error_warning",
    "error_passive",         "bus_off",
    "bus_recoveries",        "restart_requests",
    "restart_failures",      "interface_down",
    "link_alarms",           "controller_overflow",
    "rx_overflow",           "enobufs",
    "enobufs_retries",       "ack_timeouts",
    "ack_retries",           "resent_after_recovery",
    "rejected_wrong_length", "rejected_out_of_range",
    "rejected_not_finite",   "rejected_unknown_id",
    "tx_unencodable",        "tx_unmapped",
    "lockstep_syncs",        "lockstep_sync_acks",
    "reconnect_backoffs",    "reconnect_backoff_ms"};

/// What keeps this process from asking for bus-off restarts (restart = "daemon"): "" if nothing,
/// else what is missing ("no CAP_NET_ADMIN in its effective capabilities", "AF_NETLINK sockets
/// refused: ...", both joined by "; "). The shipped systemd unit allows neither; the drop-in
/// systemd/nccompd-can-restart.conf does. Not real-time.
std::string restart_permission_problem();

/// Asks the kernel to restart a CAN controller out of bus-off (netlink IFLA_CAN_RESTART, as
/// `ip link set canX type can restart`). Returns 0 or the errno. Not real-time.
int request_can_restart(int ifindex) noexcept;

}  // namespace nccomp::drivers::can
