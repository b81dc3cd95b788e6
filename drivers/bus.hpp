// The small interface every bus driver implements (style.md: one driver per folder behind a small
// interface; chrony's refclock table, libmodbus's backend table).
//
// Threads: a driver owns its I/O thread(s). The loop thread only touches the two rings and never
// blocks: it drains decoded events from rx() and queues absolute offset writes into tx(). Status
// is published through a seqlock snapshot that any thread may read.
#pragma once

#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>

#include "core/common/types.hpp"
#include "core/rt/seqlock.hpp"
#include "core/rt/spsc_ring.hpp"

namespace nccomp::drivers {

enum class LinkState : std::uint8_t {
  kStopped = 0,
  kConnecting = 1,
  kUp = 2,
  kDegraded = 3,  // up but with faults (error-passive, retries)
  kDown = 4,      // bus-off, interface down, connection lost: recovering
};

/// Counters every driver keeps; drivers add their own in their own status struct.
struct BusCounters {
  std::uint64_t frames_rx{0};        // frames / responses received
  std::uint64_t frames_tx{0};        // frames / requests sent
  std::uint64_t events_decoded{0};   // core events pushed to rx()
  std::uint64_t events_dropped{0};   // rx() ring full: events lost (the loop is too slow)
  std::uint64_t malformed{0};        // rejected input, all reasons
  std::uint64_t offsets_written{0};  // offset writes confirmed (acknowledged / echoed)
  std::uint64_t offsets_retried{0};
  std::uint64_t offsets_failed{0};  // gave up after retries: alarm raised
  std::uint64_t reconnects{0};
  std::uint64_t faults{0};  // bus faults of any kind
};

/// One driver-specific counter for `nccomp status` (text, JSON, metrics): a fault kind, a
/// per-reason reject, an exception code. `name` is a static snake_case string owned by the driver
/// ("bus_off", "exception_illegal_address", "rx_overflow"). A gauge (a value now, which may go
/// down: offsets pending, the current back-off) says so, so the metrics do not export it as a
/// counter; a gauge's unit is in its name (`_ms`).
struct BusCounterValue {
  const char* name{""};
  std::uint64_t value{0};
  bool gauge{false};
};

/// At most this many driver-specific counters are shown per bus.
inline constexpr std::size_t kMaxBusExtraCounters = 48;

struct BusStatus {
  LinkState state{LinkState::kStopped};
  bool alarm{false};  // a write could not be delivered, or the link is down beyond tolerance
  // The NC's input has been unusable for longer than the bus's degraded_alarm_after_s: no intact
  // poll (Modbus) / the link not up (CAN), or no valid axis sample (values NaN / inf / out of
  // range, or none at all). Clears with the next intact input.
  bool input_stale{false};
  core::TimeNs last_rx_ns{0};
  BusCounters counters{};
};

/// What a bus found of one numbered event kind at its first read after resume_events():
/// `events` happened since the cursor (since the NC's restart, if it restarted), the newest was
/// delivered (unless its values were refused), the others lost.
struct EventsWhileDown {
  std::uint8_t kind{0};      // core::numbered_kind() index
  std::uint32_t cursor{0};   // the engine's last event of this kind before nccompd stopped
  std::uint32_t counter{0};  // the NC's counter at the first read
  std::uint32_t events{0};
  bool nc_restarted{false};  // the counter moved back: events before the NC's restart unknown
  bool delivered{false};
};

class Bus {
 public:
  virtual ~Bus() = default;

  /// Opens the bus and starts the I/O thread(s). Not real-time; may throw with a clear message.
  virtual void start() = 0;
  /// Stops the I/O thread(s) and closes the bus. Not real-time. Idempotent.
  virtual void stop() = 0;

  /// Loop thread (consumer): decoded events, oldest first.
  virtual core::rt::SpscRing<core::Event>& rx() = 0;
  /// Loop thread (producer): absolute offset writes to deliver. A write for a register replaces
  /// an older pending write for the same register (offsets are absolute).
  virtual core::rt::SpscRing<core::OffsetWrite>& tx() = 0;
  /// Whether write_receipt() reports what became of the writes. False (default): the bus
  /// delivers every write it takes, in order, so the loop counts a write as on the NC once
  /// it is in tx() (loopback).
  [[nodiscard]] virtual bool confirms_writes() const noexcept { return false; }
  /// Loop thread, real-time safe (no allocation, no lock, never blocks): the receipt of the
  /// newest write of register_index the bus finished with (core::WriteReceipt), so that the
  /// engine limits the register's next write from what the NC holds. A write that another
  /// replaced before it went out is never reported; the one that replaced it is.
  [[nodiscard]] virtual core::WriteReceipt write_receipt(
      std::uint16_t register_index) const noexcept {
    (void)register_index;
    return {};
  }
  /// Any thread: a consistent snapshot of the driver's state and counters.
  [[nodiscard]] virtual BusStatus status() const = 0;
  /// Any thread, not real-time (the status thread): the driver's own counters beyond
  /// BusCounters (fault kinds, per-reason rejects, exception codes, lost events), so that an
  /// operator sees them in `nccomp status`. Writes at most out.size() entries, always the same
  /// names in the same order for one driver, and returns how many it wrote. Default: none.
  [[nodiscard]] virtual std::size_t extra_counters(std::span<BusCounterValue> out) const {
    (void)out;
    return 0;
  }
  /// Loop thread, after pushing into tx(): lets a driver that sleeps between frames send at
  /// once. Real-time safe (no allocation, no lock, never blocks). Default: nothing to do.
  virtual void wake() noexcept {}

  // Lock-step with a simulated NC (docs/daemon.md, "Lock-step with ncsim"): the peer is the
  // clock; per cycle the loop calls sync(), steps the engine, pushes writes, calls flush().
  // Buses without bus-side timing (loopback) keep the defaults, which return at once.

  /// Before start(): the driver does bus I/O only when sync() / flush() ask for it (no polling
  /// or writing on its own schedule), so that a lock-step run is deterministic. Not real-time.
  virtual void set_lockstep(bool on) { (void)on; }
  /// Loop thread, lock-step only: returns once all NC state the peer published before its TICK
  /// of `cycle` is in rx(). Blocks at most timeout_ns; false on timeout (the caller counts it
  /// and completes the cycle anyway). No allocation.
  virtual bool sync(std::uint64_t cycle, core::TimeNs timeout_ns) {
    (void)cycle;
    (void)timeout_ns;
    return true;
  }
  /// Loop thread, lock-step only: returns once every write pushed into tx() before the call is
  /// on the wire and taken by the NC side (see the driver). Blocks at most timeout_ns; false on
  /// timeout. No allocation.
  virtual bool flush(std::uint64_t cycle, core::TimeNs timeout_ns) {
    (void)cycle;
    (void)timeout_ns;
    return true;
  }

  // Events while nccompd was down (docs/daemon.md): a bus whose NC numbers its events resumes
  // them from the engine's cursors, restored from the state file.

  /// Before start() (not real-time): the engine's cursors of this bus (core::EventCursorSet, the
  /// counter of the last event of each kind it took before nccompd stopped). A bus that numbers
  /// its events delivers, at its first read, the newest event the NC produced since and counts
  /// the others lost; a kind without a cursor starts from the NC's counter as it finds it. False
  /// (default): the bus cannot tell which events it missed (CAN: frames carry no counter).
  virtual bool resume_events(const core::EventCursorSet& cursors) {
    (void)cursors;
    return false;
  }
  /// Any thread, not real-time: per kind with a cursor, what the first read found, once it
  /// happened. Writes at most out.size() entries and returns how many. Default: none.
  [[nodiscard]] virtual std::size_t events_while_down(std::span<EventsWhileDown> out) const {
    (void)out;
    return 0;
  }

  /// Start-up, before start() only (the caller's thread, not real-time): reads the value [µm]
  /// the NC holds in the offset register mapped to the engine's `register_index`, so that the
  /// daemon can compare it with its restored state (S1 reconcile). nullopt when the bus cannot
  /// read back (default), the register is not mapped, or the NC does not answer.
  [[nodiscard]] virtual std::optional<double> read_offset(std::uint16_t register_index) {
    (void)register_index;
    return std::nullopt;
  }
  /// Whether read_offset() can return values at all (false: CAN, loopback). A bus that can, but
  /// returned nullopt, did not answer: the daemon then knows nothing of what the NC holds.
  [[nodiscard]] virtual bool reads_back() const noexcept { return false; }
};

}  // namespace nccomp::drivers
