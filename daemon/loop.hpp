// The fixed-rate loop thread (architecture.md, "Data flow"; style.md: absolute deadlines, no
// logging, no allocation, no locks, no I/O per cycle).
//
// Each cycle: sleep to the absolute deadline (clock_nanosleep TIMER_ABSTIME) → record the
// wake-up latency → pick up a new configuration at the cycle boundary once no write is in flight
// (state carried over) →
// the buses' receipts of the writes in flight to the engine → drain events from every bus's RX
// ring → engine.step() → offset writes to the buses' TX rings (nothing in dry-run; a write a bus
// does not confirm counts as on the NC once queued, a dropped one as refused) → alarms, notes
// and measurement records to their SPSC rings → state
// export into a pre-allocated blob when it changed → heartbeat and statistics (seqlock).
// Overruns are counted and handled by advance_deadline()'s policy.
#pragma once

#include <atomic>
#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <thread>
#include <vector>

#include "core/common/output.hpp"
#include "core/engine/engine.hpp"
#include "core/rt/config_swap.hpp"
#include "core/rt/seqlock.hpp"
#include "core/rt/spsc_ring.hpp"
#include "daemon/config/builtin_sections.hpp"
#include "daemon/lockstep.hpp"
#include "daemon/measurement_log.hpp"
#include "daemon/state_store.hpp"
#include "daemon/timing.hpp"
#include "drivers/bus.hpp"

namespace nccomp::daemon {

/// What the loop steps; swapped as a whole on reload (core::rt::ConfigSwap).
struct Runtime {
  std::unique_ptr<core::engine::Engine> engine;
  /// Per register index: which bus (index into the loop's bus list) takes its writes; -1 none.
  std::vector<int> register_bus;
  bool dry_run{false};
  /// Counts configurations: 1 at start, +1 per accepted reload.
  std::uint64_t generation{1};
};

/// Things the loop wants logged; the logger thread turns them into messages.
enum class NoteCode : std::uint8_t {
  kOverrun = 0,            // a = missed deadlines, b = lateness [µs]
  kConfigSwapped = 1,      // a = new generation, b = cycles it waited for the bus's receipts
  kStateCarryFailed = 2,   // a = new generation: the new config could not take the old state
  kStateExportFailed = 3,  // a = bytes needed
  kWriteDropped = 4,       // a = register index (TX ring full or no bus)
  kDryRunEntered = 5,      // a = new generation: the state as the NC has it is kept aside
  kDryRunLeft = 6,         // a = new generation: it starts from the state before the dry run
  kFaceProbeRejected = 7,  // a = point · 8 + FaceProbeReject, b = the reading [µm]
};

struct LoopNote {
  core::TimeNs time_ns{0};
  NoteCode code{NoteCode::kOverrun};
  std::int64_t a{0};
  double b{0.0};
};

struct LoopOptions {
  double rate_hz{1000.0};
  config::OverrunPolicy overrun_policy{config::OverrunPolicy::kSkipMissed};
  std::size_t max_events_per_cycle{256};
  int sched_fifo_priority{0};
  std::vector<int> cpu_affinity;
  std::size_t prefault_stack_kib{0};
  /// Shortest time between two state exports [s].
  double state_min_interval_s{0.5};
  /// Bytes of the carry-over buffer used on reload (≥ every engine's state_capacity()).
  std::size_t state_buffer_bytes{64 * 1024};
  /// Cycles after start before the page-fault / allocation baselines are taken.
  std::uint64_t warmup_cycles{100};
  /// Optional: the calling thread's allocation count (tests and benchmarks link a counting
  /// operator new and pass nccomp::test::thread_allocations). Must be real-time safe.
  std::uint64_t (*thread_allocations)() noexcept {nullptr};
  /// Optional, the same for frees (operator delete / free of a non-null pointer).
  std::uint64_t (*thread_deallocations)() noexcept {nullptr};
  /// Lock-step (contract C2): non-null = the loop is driven by this peer's TICKs instead of the
  /// clock (connected before start(); must outlive the loop). Events are stamped with the
  /// tick's time, the engine steps at it, and DONE follows the buses' flush().
  LockstepPeer* lockstep{nullptr};
  /// Lock-step: longest wait in one bus's sync() or flush() [ns]; a timeout is counted and the
  /// cycle completes anyway (no deadlock with the peer).
  core::TimeNs lockstep_bus_timeout_ns{2'000'000'000};
  /// Longest a reload waits for a cycle without a write in flight [cycles] (then it swaps
  /// anyway, and the new engine sends those registers' values again).
  std::uint64_t swap_wait_max_cycles{250};
  /// Test hook (NCCOMPD_TEST_STALL_AFTER_CYCLES): after this many cycles the loop thread stops
  /// cycling and only waits for stop(), like a loop stuck in a blocking call, so the process
  /// tests can show that the systemd watchdog is then no longer fed. 0 = never (production).
  std::uint64_t test_stall_after_cycles{0};
};

/// What the loop thread got from the OS at start (logged by the caller: the loop never logs).
struct LoopSetupReport {
  bool sched_requested{false};
  int sched_errno{0};
  bool affinity_requested{false};
  int affinity_errno{0};
  std::size_t prefaulted_kib{0};
};

/// Trim handovers (core/engine/engine.hpp, "Trim handover") over every configuration this loop
/// ran: each reload builds a new engine whose own counters start at 0.
struct HandoverStats {
  std::uint64_t handovers{0};
  std::uint64_t rebases{0};     // registers whose writer took the change
  std::uint64_t unabsorbed{0};  // registers whose total moved by it, through the limiter
  /// Of the last handover: the largest change of a register's trims, and the largest one no
  /// writer took [µm].
  double last_trim_change_um{0.0};
  double last_unabsorbed_um{0.0};
};

/// base, then what engine counters c add to it. Real-time safe.
[[nodiscard]] HandoverStats add_handovers(const HandoverStats& base,
                                          const core::engine::EngineCounters& c) noexcept;

struct LoopStats {
  core::TimeNs period_ns{0};
  core::TimeNs started_ns{0};
  core::TimeNs last_wake_ns{0};
  std::uint64_t cycles{0};
  std::uint64_t overruns{0};
  std::uint64_t missed_deadlines{0};
  core::TimeNs last_latency_ns{0};
  core::TimeNs max_step_ns{0};  // longest cycle body (wake → done)
  std::uint64_t events_in{0};
  std::uint64_t writes_sent{0};
  std::uint64_t writes_dry_run{0};
  std::uint64_t writes_dropped{0};
  std::uint64_t alarms{0};
  std::uint64_t alarms_dropped{0};  // alarm ring full
  std::uint64_t notes_dropped{0};
  std::uint64_t records{0};
  std::uint64_t records_dropped{0};  // measurement ring full or no writer
  std::uint64_t face_probe_rejected{0};  // face probe readings that gave no row
  std::uint64_t state_exports{0};
  std::uint64_t state_export_busy{0};  // persister behind: export postponed
  std::uint64_t state_export_failed{0};
  std::uint64_t config_generation{0};  // the configuration the loop runs (swapped in)
  /// The cycle (the count in `cycles`) in which the loop swapped that configuration in; 0 when it
  /// runs since the start.
  std::uint64_t config_since_cycle{0};
  /// Cycles the published configuration has waited for the bus's receipts (0: none waits).
  std::uint64_t swap_waiting{0};
  std::uint64_t reloads{0};
  std::int64_t minor_faults_after_warmup{-1};  // -1 until the baseline is taken
  std::int64_t major_faults_after_warmup{-1};
  std::int64_t allocations_after_warmup{-1};  // -1 = not measured
  std::int64_t frees_after_warmup{-1};        // -1 = not measured
  bool hold{false};
  bool dry_run{false};
  core::engine::EngineCounters engine{};
  HandoverStats handover{};
  // Lock-step only.
  bool lockstep{false};
  std::uint64_t lockstep_cycle{0};      // cycle of the last TICK
  core::TimeNs lockstep_time_ns{0};     // its simulated time
  std::uint64_t sync_timeouts{0};       // bus sync() that timed out (all buses)
  std::uint64_t flush_timeouts{0};      // bus flush() that timed out
  std::int32_t last_timeout_bus{-1};    // index of the bus of the last timeout
  std::uint64_t last_timeout_cycle{0};  // and its cycle
  core::TimeNs max_wait_ns{0};          // longest wait for a TICK between two cycles
};

// Room for a whole S1 table of a few hundred checkpoints (docs/checkpoints.md); copied every
// 10 cycles (24 bytes per register).
inline constexpr std::size_t kMaxSnapshotRegisters = 512;

struct RegisterSnapshot {
  std::uint64_t config_generation{0};
  std::uint32_t count{0};
  std::array<core::engine::RegisterState, kMaxSnapshotRegisters> regs{};
};

inline constexpr std::size_t kMaxSnapshotModules = 8;

/// The engine modules' own status values (core::engine::Module::status()), for `nccomp status`.
struct ModuleSnapshot {
  std::array<char, 48> name{};  // NUL-terminated, truncated
  std::uint32_t count{0};
  std::array<core::engine::StatusValue, core::engine::kMaxStatusValues> values{};
};
struct ModulesSnapshot {
  std::uint64_t config_generation{0};
  std::uint32_t count{0};
  std::array<ModuleSnapshot, kMaxSnapshotModules> modules{};
};

class Loop {
 public:
  /// Not real-time: sizes every ring and buffer. buses, persister, measurement_log must outlive
  /// the loop; persister and measurement_log may be null.
  Loop(LoopOptions options, core::rt::ConfigSwap<Runtime>& swap, std::vector<drivers::Bus*> buses,
       StatePersister* persister, MeasurementLogWriter* measurement_log);
  ~Loop();
  Loop(const Loop&) = delete;
  Loop& operator=(const Loop&) = delete;

  /// Starts the thread and waits until it has applied its scheduling setup.
  LoopSetupReport start();
  /// Asks the thread to finish its cycle and joins it. Idempotent.
  void stop();
  /// After stop() (not real-time): the state to write at exit into buf; returns its size, or 0
  /// when there is nothing to write. Normally the engine's state. In dry run it is the state as
  /// the NC has it (kept aside when the dry run began), and 0 if the file already holds it: the
  /// dry run's own values were never sent, so they never reach the state file.
  [[nodiscard]] std::size_t final_state(std::span<std::byte> buf) const;
  [[nodiscard]] bool running() const noexcept { return thread_.joinable(); }

  /// Hold mode (state corrupt): applied to every engine at the next cycle. Any thread.
  void set_hold(bool hold) noexcept { hold_.store(hold, std::memory_order_relaxed); }

  /// Lock-step: true once the run ended (BYE, the peer gone, a protocol error); the thread has
  /// then left its loop. Any thread.
  [[nodiscard]] bool finished() const noexcept { return finished_.load(std::memory_order_acquire); }
  /// Lock-step: why it ended (valid once finished()).
  [[nodiscard]] LockstepEnd lockstep_end() const noexcept {
    return static_cast<LockstepEnd>(lockstep_end_.load(std::memory_order_acquire));
  }

  /// Advances once per cycle: the watchdog's proof of life. Any thread.
  [[nodiscard]] std::uint64_t heartbeat() const noexcept {
    return heartbeat_.load(std::memory_order_acquire);
  }
  [[nodiscard]] LoopStats stats() const noexcept { return stats_.load(); }
  [[nodiscard]] RegisterSnapshot registers() const noexcept { return registers_.load(); }
  [[nodiscard]] ModulesSnapshot modules() const noexcept { return modules_.load(); }
  [[nodiscard]] const LatencyHistogram& latency() const noexcept { return latency_; }

  /// Consumers (the logger thread).
  core::rt::SpscRing<core::AlarmEvent>& alarms() noexcept { return alarms_; }
  core::rt::SpscRing<LoopNote>& notes() noexcept { return notes_; }

 private:
  void run();
  void run_lockstep();
  /// Fault / allocation baselines, statistics and heartbeat at the end of a cycle.
  void finish_cycle() noexcept;
  /// stamp: lock-step, every drained event gets wake_ns as its time.
  void cycle(core::TimeNs wake_ns, bool stamp = false);
  /// Real-time safe: the cycle's events through the face probe's capture
  /// (measurement_log_probe.hpp); a probe reading's row goes to the measurement log.
  void log_face_probe(const core::engine::Engine& engine) noexcept;
  /// The buses' receipts of rt's writes in flight to its engine. Real-time safe.
  void take_receipts(const Runtime& rt, core::TimeNs wake_ns) noexcept;
  /// The swap of a pending configuration (cycle()'s first part). Real-time safe.
  void swap_in(core::TimeNs wake_ns);
  void note(core::TimeNs t, NoteCode code, std::int64_t a, double b) noexcept;

  LoopOptions options_;
  core::rt::ConfigSwap<Runtime>& swap_;
  std::vector<drivers::Bus*> buses_;
  StatePersister* persister_;
  MeasurementLogWriter* measurement_log_;
  core::TimeNs period_ns_;

  std::vector<core::Event> events_;
  core::StepOutput out_{};
  std::vector<std::byte> carry_;
  // A reload: the tool's motion the old engine followed (last sample, feed direction), for the
  // new one (core::engine::Engine::export_motion()).
  std::vector<std::byte> motion_carry_;
  // Dry run: the engine state as the NC has it (the last state whose writes really went out),
  // taken when the dry run began. The dry-run engine's registers advance as if written; on leaving
  // the dry run (reload) the new engine starts from this state, never from the dry run's values.
  std::vector<std::byte> anchor_;
  std::size_t anchor_size_{0};
  bool anchor_persisted_{true};  // the state file already holds anchor_
  core::rt::SpscRing<core::AlarmEvent> alarms_;
  core::rt::SpscRing<LoopNote> notes_;
  LatencyHistogram latency_;
  core::rt::Seqlock<LoopStats> stats_;
  core::rt::Seqlock<RegisterSnapshot> registers_;
  core::rt::Seqlock<ModulesSnapshot> modules_;
  LoopStats local_{};
  std::uint64_t persisted_generation_{~std::uint64_t{0}};
  std::uint64_t swap_waited_{0};  // cycles a pending configuration waited for receipts
  core::TimeNs last_export_ns_{0};
  /// The handovers of the configurations before the running one.
  HandoverStats handover_base_{};
  std::int64_t minflt_base_{0};
  std::int64_t majflt_base_{0};
  std::uint64_t alloc_base_{0};
  std::uint64_t free_base_{0};

  std::atomic<bool> stop_{false};
  std::atomic<bool> hold_{false};
  std::atomic<bool> setup_done_{false};
  std::atomic<bool> finished_{false};
  std::atomic<std::uint8_t> lockstep_end_{0};
  std::atomic<std::uint64_t> heartbeat_{0};
  LoopSetupReport report_{};
  std::thread thread_;
};

}  // namespace nccomp::daemon
