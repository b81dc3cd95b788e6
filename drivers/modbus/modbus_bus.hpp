// The Modbus driver: a libmodbus client (TCP or RTU) on its own I/O thread.
//
// Per period (1 / poll_rate_hz) the I/O thread reads the config's read blocks, decodes them
// (decoder.hpp) into core events for rx(), takes the offset writes the loop queued in tx() and,
// at most offset_write_rate_hz, writes every changed offset with function 16.
//
// Offsets are absolute: the latest value per register wins, an undelivered one stays pending
// and is re-sent until acknowledged (and, with verify_writes, read back equal); after every
// reconnect all known offsets are written again. A repeated write of an absolute value cannot
// double a correction, so none is lost and none is applied twice. Each finished write is
// reported in write_receipt() (reached once answered and verified, refused if not encodable), so
// that the engine sends a register's next value only after the NC took the last one: a slow poll
// or a back-off then slows the slew, instead of merging the limiter's steps into one.
//
// Stale input (input_watch.hpp): no poll with every block read, or no valid axis sample while the
// axis group is mapped, for longer than degraded_alarm_after_s sets BusStatus::input_stale: an NC
// that answers every read with an exception keeps the link "degraded", never down.
//
// Faults: response and byte timeouts from the config; exception responses are counted per code;
// garbage (bad CRC, wrong transaction id, wrong length) is counted and the input flushed;
// dead_after_failures consecutive timeouts / garbage, or a socket error, drop the connection.
// However it was lost (or a connect failed), the next connect waits the back-off, which doubles
// from reconnect_min_s to reconnect_max_s and returns to reconnect_min_s only after a connection
// stayed healthy for reconnect_reset_after_s (drivers/reconnect_backoff.hpp).
//
// libmodbus blocks in select() up to its timeouts, which is why none of this runs on the loop
// thread: the loop thread only uses rx(), tx() and status(), all wait-free.
//
// Real-time policy (opt-in, io_sched_fifo_priority / io_cpu_affinity): the I/O thread raises
// itself to SCHED_FIFO and pins itself before its first request; what it asked for and what it
// got is in io_thread_setup(), in the status (io_sched_* counters) and, through the
// on_io_thread_setup() callback, in the daemon's log. A refusal is reported, never fatal.
#pragma once

#include <array>
#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#include "core/rt/seqlock.hpp"
#include "core/rt/spsc_ring.hpp"
#include "drivers/bus.hpp"
#include "drivers/input_watch.hpp"
#include "drivers/modbus/config.hpp"
#include "drivers/modbus/decoder.hpp"
#include "drivers/reconnect_backoff.hpp"
#include "drivers/write_receipts.hpp"

namespace nccomp::drivers::modbus {

/// Modbus exception codes 1..11 (illegal function, illegal data address, illegal data value,
/// server failure, acknowledge, server busy, negative acknowledge, memory parity, 9 = unused,
/// gateway path unavailable, gateway target failed); index 0 counts unknown codes.
inline constexpr std::size_t kExceptionKinds = 12;

/// The driver's own counters, published with the common BusStatus.
struct ModbusStatus {
  BusStatus bus{};
  std::array<std::uint64_t, kExceptionKinds> exceptions{};
  std::uint64_t timeouts{0};
  std::uint64_t crc_errors{0};
  std::uint64_t bad_responses{0};      // wrong transaction id / length / unit / function
  std::uint64_t connection_errors{0};  // socket / device errors, failed connects
  std::uint64_t connect_attempts{0};   // connects tried (first one, reconnects, read-back)
  // Back-off waits: one per lost connection or failed connect.
  std::uint64_t reconnect_backoffs{0};
  std::uint64_t polls{0};
  std::uint64_t poll_overruns{0};    // a poll period ended before the poll and writes did
  std::uint64_t events_lost{0};      // events a sequence counter skipped (jumps > 1, NC restart)
  std::uint64_t sequence_resets{0};  // a sequence counter moved back: NC restart
  // Same non-zero counter at the first read after a reconnect: an NC restart can't be ruled out.
  std::uint64_t sequence_unchanged_after_reconnect{0};
  // Events the NC produced while nccompd was down (first read after a start with the engine's
  // cursors): the newest of a group delivered, the others lost; and what each group's read found.
  std::uint64_t events_recovered_after_start{0};
  std::uint64_t events_lost_while_down{0};
  std::array<ResumeReport, kGroupCount> resume{};
  std::uint64_t values_invalid{0};       // NaN / inf / not integral / not a valid code: dropped
  std::uint64_t values_out_of_range{0};  // finite but outside the map's min / max: dropped
  std::uint64_t offsets_rejected{0};     // not encodable (NaN, out of range) or unmapped register
  std::uint64_t verify_mismatches{0};
  std::uint32_t offsets_pending{0};  // written by the loop, not yet confirmed on the NC
  core::TimeNs last_cycle_ns{0};     // duration of the last poll + write cycle
  core::TimeNs max_cycle_ns{0};
  int last_errno{0};  // errno of the last fault (libmodbus EMB* codes too)
  // The I/O thread's scheduling as it runs (set once at start, see IoThreadSetup).
  std::uint32_t io_sched_fifo_priority{0};  // its SCHED_FIFO priority; 0 = not SCHED_FIFO
  std::uint32_t io_sched_errno{0};          // io_sched_fifo_priority refused with this errno
  std::uint32_t io_affinity_errno{0};       // io_cpu_affinity refused with this errno
  // The wait the next lost connection will get while the back-off is raised, 0 at its minimum.
  std::uint32_t reconnect_backoff_ms{0};
};

/// What the I/O thread asked for at start and what it got (read back from the kernel).
struct IoThreadSetup {
  int requested_fifo_priority{0};  // io_sched_fifo_priority; 0 = not requested
  int sched_errno{0};              // pthread_setschedparam's result: 0 = granted
  bool affinity_requested{false};  // io_cpu_affinity not empty
  int affinity_errno{0};           // pthread_setaffinity_np's result: 0 = granted
  int policy{0};                   // the thread's policy afterwards (SCHED_OTHER, SCHED_FIFO, ...)
  int priority{0};                 // and its priority
  int tid{0};                      // kernel thread id (for sched_getscheduler, ps -L)
};

/// One log line about the I/O thread's set-up; `warning` when something asked for was refused.
struct IoSetupLine {
  bool warning{false};
  std::string text;
};

/// The log lines for `setup` (one per aspect: scheduling, and the affinity if asked for), e.g.
/// "I/O thread: SCHED_FIFO priority 40" or, refused, "I/O thread: SCHED_FIFO priority 40
/// refused: Operation not permitted (running SCHED_OTHER; ...)". Not real-time.
std::vector<IoSetupLine> describe_io_setup(const IoThreadSetup& setup, const ModbusConfig& config);

/// Names of ModbusBus::extra_counters(), in their order (static strings, for status output).
inline constexpr auto kModbusCounterNames = std::to_array<const char*>({
    "exception_illegal_function",      // 1
    "exception_illegal_address",       // 2
    "exception_illegal_value",         // 3
    "exception_server_failure",        // 4
    "exception_acknowledge",           // 5
    "exception_server_busy",           // 6 (slave busy)
    "exception_negative_acknowledge",  // 7
    "exception_memory_parity",         // 8
    "exception_gateway_path",          // 10
    "exception_gateway_target",        // 11
    "exception_other",                 // unknown codes and 9
    // clang-format off
    "timeouts",
    "crc_errors",
    "bad_responses",
    "connection_errors",
    "connect_attempts",
    "reconnect_backoffs",
    "poll_overruns",
    "events_lost",
    "sequence_resets",
    "sequence_unchanged_after_reconnect",
    "events_recovered_after_start",
    "events_lost_while_down",
    "values_invalid",
    "values_out_of_range",
    "offsets_rejected",
    "verify_mismatches",
    // clang-format on
    "offsets_pending",       // a gauge: offsets not yet confirmed on the NC now
    "reconnect_backoff_ms",  // a gauge: the raised back-off, 0 at reconnect_min_s
    // Gauges set once at start: the I/O thread's scheduling (docs/modbus.md).
    "io_sched_fifo_priority",  // its SCHED_FIFO priority, 0 = normal scheduling
    "io_sched_errno",          // errno of a refused io_sched_fifo_priority (1 = EPERM), else 0
    "io_affinity_errno",       // errno of a refused io_cpu_affinity (22 = EINVAL), else 0
});

/// kModbusCounterNames from this index on are gauges, not counts.
inline constexpr std::size_t kModbusFirstGauge = kModbusCounterNames.size() - 5;
static_assert(std::string_view(kModbusCounterNames[kModbusFirstGauge]) == "offsets_pending");

/// Fills `out` with the counters of `st` in kModbusCounterNames order; returns how many.
std::size_t modbus_counters(const ModbusStatus& st, std::span<BusCounterValue> out) noexcept;

/// One poll + write cycle of the I/O thread (diagnostics, see attach_cycle_log).
struct CycleRecord {
  core::TimeNs duration_ns{0};
  std::uint16_t reads{0};   // read requests sent (polls and read-backs)
  std::uint16_t writes{0};  // function 16 requests sent
};

class ModbusBus final : public Bus {
 public:
  /// Frees a libmodbus context (kept opaque here so that users need not see libmodbus).
  struct ModbusDeleter {
    void operator()(void* ctx) const noexcept;
  };

  /// Sizes the rings and buffers (not real-time). The config must come from parse_modbus_config.
  explicit ModbusBus(ModbusConfig config);
  ~ModbusBus() override;
  ModbusBus(const ModbusBus&) = delete;
  ModbusBus& operator=(const ModbusBus&) = delete;

  /// Starts the I/O thread; the connection is made (and re-made) there, so an unreachable NC is
  /// not an error here but a kConnecting / kDown state. Returns once the thread has applied its
  /// scheduling (io_thread_setup()) and, if set, called on_io_thread_setup's callback with it.
  /// Throws if already started.
  void start() override;
  /// Stops the I/O thread (waits at most one response timeout) and closes the connection.
  void stop() override;

  core::rt::SpscRing<core::Event>& rx() override { return rx_; }
  core::rt::SpscRing<core::OffsetWrite>& tx() override { return tx_; }
  [[nodiscard]] bool confirms_writes() const noexcept override { return true; }
  /// Reached once the NC answered the write (and, with verify_writes, held it on read-back);
  /// refused if the value does not fit the register or the register has no mapping.
  [[nodiscard]] core::WriteReceipt write_receipt(
      std::uint16_t register_index) const noexcept override;
  [[nodiscard]] BusStatus status() const override { return status_.load().bus; }
  /// The ModbusStatus counters (kModbusCounterNames) from the seqlock snapshot: exceptions per
  /// code, timeouts, CRC errors, lost events, verify mismatches, pending offsets, ...
  [[nodiscard]] std::size_t extra_counters(std::span<BusCounterValue> out) const override {
    return modbus_counters(status_.load(), out);
  }
  /// Before start(): the decoder resumes each event group from the engine's cursor. Returns true.
  bool resume_events(const core::EventCursorSet& cursors) override;
  /// The first read of each resumed group (from the seqlock snapshot).
  [[nodiscard]] std::size_t events_while_down(std::span<EventsWhileDown> out) const override;

  /// Lock-step (before start()): no polling or writing on the driver's own schedule; sync()
  /// makes the I/O thread do one complete poll, flush() makes it write every pending offset
  /// (the write rate limit does not apply: time is the peer's).
  void set_lockstep(bool on) override { lockstep_ = on; }
  /// Returns once one poll that started after the call is complete and its events are in rx().
  /// False on timeout or if the poll failed (not connected, a read failed).
  bool sync(std::uint64_t cycle, core::TimeNs timeout_ns) override;
  /// Returns once every offset queued in tx() before the call was written and answered by the
  /// NC (and read back equal with verify_writes). False on timeout or a failed write.
  bool flush(std::uint64_t cycle, core::TimeNs timeout_ns) override;
  /// Before start() only: connects (once; a failed connect is not retried by later calls) and
  /// reads the holding register(s) of register_index's offset map with the map's encoding.
  /// nullopt if unmapped, not connected or the read fails. start() drops this connection, so
  /// the I/O thread makes its own. Not real-time.
  [[nodiscard]] std::optional<double> read_offset(std::uint16_t register_index) override;
  [[nodiscard]] bool reads_back() const noexcept override { return true; }
  /// Any thread: the full status with the Modbus counters.
  [[nodiscard]] ModbusStatus modbus_status() const { return status_.load(); }
  [[nodiscard]] const ModbusConfig& config() const noexcept { return config_; }

  /// Before start(): called by start(), on its thread, with the I/O thread's set-up (the daemon
  /// logs it, see describe_io_setup). Not real-time.
  void on_io_thread_setup(std::function<void(const IoThreadSetup&)> fn) {
    on_setup_ = std::move(fn);
  }
  /// After start(): what the I/O thread asked for and got. Read it on start()'s thread (or after
  /// something that synchronises with it); other threads use modbus_status()'s io_* fields.
  [[nodiscard]] const IoThreadSetup& io_thread_setup() const noexcept { return io_setup_; }
  /// While started: the I/O thread's handle (pthread_t), for checks with pthread_getschedparam.
  [[nodiscard]] std::thread::native_handle_type io_native_handle() { return io_.native_handle(); }

  /// Diagnostics: before start(), a ring that receives every connected poll + write cycle of
  /// the free-running I/O thread: its duration and the requests it sent (dropped when full; the
  /// I/O thread never waits for it). For benchmarks and latency statistics; the ring must
  /// outlive the driver's I/O thread.
  void attach_cycle_log(core::rt::SpscRing<CycleRecord>* ring) noexcept { cycle_log_ = ring; }

 private:
  struct OffsetSlot {
    bool has_value{false};
    bool dirty{false};
    bool rejected{false};
    bool resend{false};  // a re-send (after a failure or a reconnect), counted as a retry
    double value_um{0.0};
    std::uint64_t sequence{0};  // OffsetWrite::sequence of value_um
    core::TimeNs dirty_since_ns{0};
  };

  void run();
  /// I/O thread, first thing: applies io_sched_fifo_priority / io_cpu_affinity, records the result.
  void setup_io_thread();
  void run_lockstep();
  /// Connects if needed, first waiting out the back-off; false while not connected.
  bool ensure_connected(bool& ever_connected);
  /// The connection was lost, or a connect failed, at now_ns: schedules the next connect.
  void lost(core::TimeNs now_ns);
  /// Loop thread: posts a request and waits for its completion.
  bool request(std::uint64_t& req, const std::uint64_t& done, const bool& ok,
               core::TimeNs timeout_ns);
  bool connect();
  void disconnect();
  void poll(core::TimeNs now_ns);
  void drain_tx(core::TimeNs now_ns);
  void write_offsets();
  bool write_one(std::size_t slot_index);
  /// Classifies a failed libmodbus call. Returns false when the connection was dropped.
  bool fail(int err);
  void rtu_gap();
  void after_transaction();
  void publish(core::TimeNs now_ns);
  /// After a poll: whether every block was read and whether a valid axis sample came out.
  void note_input(bool all_read, bool axis_seen);
  void sleep_until(core::TimeNs t_ns) const;

  const ModbusConfig config_;
  core::rt::SpscRing<core::Event> rx_;
  core::rt::SpscRing<core::OffsetWrite> tx_;
  core::rt::Seqlock<ModbusStatus> status_;
  std::atomic<bool> running_{false};
  std::thread io_;
  std::function<void(const IoThreadSetup&)> on_setup_;
  // Written by the I/O thread before it sets setup_done_ (under ls_mu_), read by start() after.
  IoThreadSetup io_setup_{};
  bool setup_done_{false};

  // I/O thread only.
  std::unique_ptr<void, ModbusDeleter> ctx_;
  PollDecoder decoder_;
  InputWatch input_watch_;
  std::vector<std::uint8_t> block_ok_;
  std::vector<std::uint8_t> bits_;
  // register_index → offsets index, -1 = unmapped; fixed after the constructor, so the loop thread
  // reads it too (write_receipt()).
  std::vector<std::int32_t> slot_of_register_;
  std::vector<OffsetSlot> slots_;
  WriteReceipts receipts_;
  ModbusStatus st_{};
  std::uint32_t consecutive_failures_{0};
  ReconnectBackoff backoff_;
  core::TimeNs next_connect_ns_{0};
  // A transaction of this cycle timed out, was garbled or lost the connection: not healthy.
  bool cycle_failed_{false};
  core::TimeNs down_since_ns_{0};
  core::TimeNs last_frame_end_ns_{0};
  core::rt::SpscRing<CycleRecord>* cycle_log_{nullptr};
  std::uint16_t cycle_reads_{0};
  std::uint16_t cycle_writes_{0};

  // Lock-step: requests from the loop thread, completions from the I/O thread (both under
  // ls_mu_; the loop thread blocks here by design, it is driven by the peer, not the clock).
  bool lockstep_{false};
  std::mutex ls_mu_;
  std::condition_variable ls_cv_;
  std::uint64_t sync_req_{0};
  std::uint64_t sync_done_{0};
  bool sync_ok_{false};
  std::uint64_t flush_req_{0};
  std::uint64_t flush_done_{0};
  bool flush_ok_{false};
  // read_offset() before start(): true once a connect for it failed (no second wait).
  bool readback_connect_failed_{false};
};

/// CLOCK_MONOTONIC [ns] (the driver time-stamps events on reception).
core::TimeNs monotonic_now_ns() noexcept;

}  // namespace nccomp::drivers::modbus
