#include "daemon/loop.hpp"

#include <pthread.h>
#include <sched.h>
#include <sys/resource.h>
#include <time.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstring>
#include <variant>

namespace nccomp::daemon {

namespace {

core::TimeNs now_ns() noexcept {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<core::TimeNs>(ts.tv_sec) * 1'000'000'000 + ts.tv_nsec;
}

timespec to_timespec(core::TimeNs t) noexcept {
  timespec ts{};
  ts.tv_sec = static_cast<time_t>(t / 1'000'000'000);
  ts.tv_nsec = static_cast<long>(t % 1'000'000'000);
  return ts;
}

// Touches `kib` KiB of this thread's stack so its pages exist before the first cycle (with
// mlockall(MCL_FUTURE) they then stay resident). Recursion keeps each frame's array live.
std::size_t prefault_stack(std::size_t kib) noexcept {
  constexpr std::size_t kChunk = 16 * 1024;
  std::size_t done = 0;
  struct Local {
    static std::size_t touch(std::size_t left) noexcept {
      volatile unsigned char buf[kChunk];
      for (std::size_t i = 0; i < kChunk; i += 4096) {
        buf[i] = 0;
      }
      buf[kChunk - 1] = 0;
      // Keep the compiler from dropping the stores (the pages must really be touched).
      __asm__ __volatile__("" : : "r"(&buf[0]) : "memory");
      return left <= kChunk ? kChunk : kChunk + touch(left - kChunk);
    }
  };
  if (kib > 0) {
    done = Local::touch(kib * 1024) / 1024;
  }
  return done;
}

void thread_faults(std::int64_t& minflt, std::int64_t& majflt) noexcept {
  rusage ru{};
  if (getrusage(RUSAGE_THREAD, &ru) == 0) {
    minflt = ru.ru_minflt;
    majflt = ru.ru_majflt;
  }
}

}  // namespace

HandoverStats add_handovers(const HandoverStats& base,
                            const core::engine::EngineCounters& c) noexcept {
  HandoverStats h = base;
  h.handovers += c.handovers;
  h.rebases += c.handover_rebases;
  h.unabsorbed += c.handover_unabsorbed;
  if (c.handovers > 0) {
    h.last_trim_change_um = c.last_handover_trim_change_um;
    h.last_unabsorbed_um = c.last_handover_unabsorbed_um;
  }
  return h;
}

Loop::Loop(LoopOptions options, core::rt::ConfigSwap<Runtime>& swap,
           std::vector<drivers::Bus*> buses, StatePersister* persister,
           MeasurementLogWriter* measurement_log)
    : options_(std::move(options)),
      swap_(swap),
      buses_(std::move(buses)),
      persister_(persister),
      measurement_log_(measurement_log),
      period_ns_(static_cast<core::TimeNs>(std::llround(1e9 / options_.rate_hz))),
      carry_(options_.state_buffer_bytes),
      motion_carry_(core::engine::kMotionBytes),
      anchor_(options_.state_buffer_bytes),
      alarms_(1024),
      notes_(1024) {
  events_.reserve(options_.max_events_per_cycle);
}

Loop::~Loop() { stop(); }

LoopSetupReport Loop::start() {
  if (swap_.current().dry_run && !thread_.joinable()) {
    // Starting in dry run: the NC holds what the restored state says (or, fresh, nothing from
    // us). That is the state the file keeps and a later real run starts from.
    anchor_size_ = swap_.current().engine->export_state(anchor_);
    anchor_persisted_ = true;
  }
  stop_.store(false);
  setup_done_.store(false);
  thread_ = std::thread([this] { run(); });
  while (!setup_done_.load(std::memory_order_acquire)) {
    std::this_thread::yield();
  }
  return report_;
}

void Loop::stop() {
  stop_.store(true, std::memory_order_release);
  if (thread_.joinable()) {
    thread_.join();
  }
}

std::size_t Loop::final_state(std::span<std::byte> buf) const {
  const Runtime& rt = swap_.current();
  if (!rt.dry_run) {
    return rt.engine->export_state(buf);
  }
  if (anchor_persisted_ || anchor_size_ == 0 || buf.size() < anchor_size_) {
    return 0;
  }
  std::copy_n(anchor_.data(), anchor_size_, buf.data());
  return anchor_size_;
}

void Loop::log_face_probe(const core::engine::Engine& engine) noexcept {
  FaceProbeCapture& fp = measurement_log_->face_probe();
  const FaceProbeConfig& c = fp.config();
  if (c.length_register >= engine.register_count() ||
      c.radius_register >= engine.register_count()) {
    return;  // a reload with fewer registers: the capture waits for a restart
  }
  for (const core::Event& e : events_) {
    const core::EventOrigin* o = core::origin_of(e);
    if (o != nullptr && o->counter_only) continue;  // not an event (the bus's first read)
    if (const auto* a = std::get_if<core::AxisSample>(&e)) {
      fp.on_axis(*a, engine.register_state(c.length_register).output_um,
                 engine.register_state(c.radius_register).output_um,
                 engine.context().cut_path_mm(a->tool));
    } else if (const auto* p = std::get_if<core::ProgramEvent>(&e)) {
      if (p->kind == core::ProgramEventKind::kPartStart) fp.on_part_start();
    } else if (const auto* m = std::get_if<core::ProbeMeasurement>(&e)) {
      core::MeasurementRecord r;
      if (!fp.on_probe(*m, r)) {
        local_.face_probe_rejected = fp.rejected();  // the capture counts them
        note(m->time_ns, NoteCode::kFaceProbeRejected,
             static_cast<std::int64_t>(m->checkpoint) * 8 +
                 static_cast<std::int64_t>(fp.last_reject()),
             m->raw_deviation_um);
        continue;
      }
      ++local_.records;
      engine.context().annotate(r);  // session, machine time, temperature: as the engine's rows
      measurement_log_->stamp(r, engine.context());
      if (!measurement_log_->ring().try_push(r)) ++local_.records_dropped;
    }
  }
}

void Loop::note(core::TimeNs t, NoteCode code, std::int64_t a, double b) noexcept {
  if (!notes_.try_push(LoopNote{t, code, a, b})) {
    ++local_.notes_dropped;
  }
}

void Loop::run() {
  // Set-up on the thread itself (before the first deadline): results go to the report, which
  // the starting thread logs. Failure is not fatal: the loop runs with what it got.
  if (options_.sched_fifo_priority > 0) {
    report_.sched_requested = true;
    sched_param sp{};
    sp.sched_priority = options_.sched_fifo_priority;
    report_.sched_errno = pthread_setschedparam(pthread_self(), SCHED_FIFO, &sp);
  }
  if (!options_.cpu_affinity.empty()) {
    report_.affinity_requested = true;
    cpu_set_t set;
    CPU_ZERO(&set);
    for (int c : options_.cpu_affinity) {
      if (c >= 0 && c < CPU_SETSIZE) {
        CPU_SET(static_cast<std::size_t>(c), &set);
      }
    }
    report_.affinity_errno = pthread_setaffinity_np(pthread_self(), sizeof(set), &set);
  }
  report_.prefaulted_kib = prefault_stack(options_.prefault_stack_kib);
  local_.period_ns = period_ns_;
  local_.config_generation = swap_.current().generation;
  setup_done_.store(true, std::memory_order_release);
  if (options_.lockstep != nullptr) {
    run_lockstep();
    return;
  }

  core::TimeNs deadline = now_ns() + period_ns_;
  local_.started_ns = deadline;
  while (!stop_.load(std::memory_order_acquire)) {
    const timespec ts = to_timespec(deadline);
    while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr) == EINTR) {
    }
    const core::TimeNs wake = now_ns();
    const core::TimeNs latency = wake - deadline;
    latency_.record(latency);
    local_.last_latency_ns = latency;
    local_.last_wake_ns = wake;
    cycle(wake);
    const core::TimeNs done = now_ns();
    local_.max_step_ns = std::max(local_.max_step_ns, done - wake);
    const Deadline next = advance_deadline(deadline, done, period_ns_, options_.overrun_policy);
    if (next.missed > 0) {
      ++local_.overruns;
      local_.missed_deadlines += next.missed;
      note(done, NoteCode::kOverrun, static_cast<std::int64_t>(next.missed),
           static_cast<double>(done - deadline) / 1000.0);
    }
    deadline = next.next_ns;
    finish_cycle();
    if (options_.test_stall_after_cycles != 0 &&
        local_.cycles == options_.test_stall_after_cycles) {
      // Test hook only: the heartbeat stops advancing while the process stays alive.
      while (!stop_.load(std::memory_order_acquire)) {
        std::this_thread::sleep_for(std::chrono::milliseconds(10));
      }
    }
  }
  // Final fault count for whoever reads the statistics after stop().
  if (local_.cycles > options_.warmup_cycles) {
    std::int64_t mn = 0;
    std::int64_t mj = 0;
    thread_faults(mn, mj);
    local_.minor_faults_after_warmup = mn - minflt_base_;
    local_.major_faults_after_warmup = mj - majflt_base_;
    stats_.store(local_);
  }
}

void Loop::run_lockstep() {
  // The peer is the clock: wait for its TICK (in slices, so that stop() is honoured), bring every
  // bus up to the NC state of that instant, step at the tick's time, put the writes on the wire,
  // answer DONE. Nothing here sleeps to a deadline, so the run is as fast as both sides are and
  // its results do not depend on wall time.
  LockstepPeer& peer = *options_.lockstep;
  local_.lockstep = true;
  constexpr core::TimeNs kSliceNs = 100'000'000;
  core::TimeNs wait_start = now_ns();
  while (!stop_.load(std::memory_order_acquire)) {
    LockstepMessage tick;
    const LockstepPeer::Wait w = peer.wait_tick(tick, kSliceNs);
    if (w == LockstepPeer::Wait::kTimeout) {
      continue;
    }
    if (w == LockstepPeer::Wait::kEnd) {
      break;
    }
    const core::TimeNs woke = now_ns();
    local_.max_wait_ns = std::max(local_.max_wait_ns, woke - wait_start);
    local_.last_wake_ns = tick.time_ns;
    local_.lockstep_cycle = tick.cycle;
    local_.lockstep_time_ns = tick.time_ns;
    if (local_.cycles == 0) {
      local_.started_ns = tick.time_ns;
    }
    for (std::size_t b = 0; b < buses_.size(); ++b) {
      if (!buses_[b]->sync(tick.cycle, options_.lockstep_bus_timeout_ns)) {
        ++local_.sync_timeouts;
        local_.last_timeout_bus = static_cast<std::int32_t>(b);
        local_.last_timeout_cycle = tick.cycle;
      }
    }
    cycle(tick.time_ns, true);
    for (std::size_t b = 0; b < buses_.size(); ++b) {
      if (!buses_[b]->flush(tick.cycle, options_.lockstep_bus_timeout_ns)) {
        ++local_.flush_timeouts;
        local_.last_timeout_bus = static_cast<std::int32_t>(b);
        local_.last_timeout_cycle = tick.cycle;
      }
    }
    const core::TimeNs done = now_ns();
    local_.max_step_ns = std::max(local_.max_step_ns, done - woke);
    finish_cycle();
    if (!peer.send_done(tick.cycle, tick.time_ns)) {
      break;
    }
    wait_start = now_ns();
  }
  if (stop_.load(std::memory_order_acquire) && peer.end() == LockstepEnd::kRunning) {
    peer.send_bye();
    lockstep_end_.store(static_cast<std::uint8_t>(LockstepEnd::kStopped),
                        std::memory_order_release);
  } else {
    lockstep_end_.store(static_cast<std::uint8_t>(peer.end()), std::memory_order_release);
  }
  stats_.store(local_);
  finished_.store(true, std::memory_order_release);
}

void Loop::finish_cycle() noexcept {
  // Baselines after warm-up; then every 1000 cycles (getrusage is a cheap syscall, not I/O).
  if (local_.cycles == options_.warmup_cycles) {
    thread_faults(minflt_base_, majflt_base_);
    local_.minor_faults_after_warmup = 0;
    local_.major_faults_after_warmup = 0;
    if (options_.thread_allocations != nullptr) {
      alloc_base_ = options_.thread_allocations();
      local_.allocations_after_warmup = 0;
    }
    if (options_.thread_deallocations != nullptr) {
      free_base_ = options_.thread_deallocations();
      local_.frees_after_warmup = 0;
    }
  } else if (local_.cycles > options_.warmup_cycles && local_.cycles % 1000 == 0) {
    std::int64_t mn = 0;
    std::int64_t mj = 0;
    thread_faults(mn, mj);
    local_.minor_faults_after_warmup = mn - minflt_base_;
    local_.major_faults_after_warmup = mj - majflt_base_;
  }
  if (options_.thread_allocations != nullptr && local_.cycles > options_.warmup_cycles) {
    local_.allocations_after_warmup =
        static_cast<std::int64_t>(options_.thread_allocations() - alloc_base_);
  }
  if (options_.thread_deallocations != nullptr && local_.cycles > options_.warmup_cycles) {
    local_.frees_after_warmup =
        static_cast<std::int64_t>(options_.thread_deallocations() - free_base_);
  }
  stats_.store(local_);
  heartbeat_.fetch_add(1, std::memory_order_release);
}

void Loop::take_receipts(const Runtime& rt, core::TimeNs wake_ns) noexcept {
  core::engine::Engine& engine = *rt.engine;
  for (std::size_t i = 0; i < engine.register_count(); ++i) {
    if (engine.write_in_flight(i) == 0) {
      continue;
    }
    const int b = i < rt.register_bus.size() ? rt.register_bus[i] : -1;
    if (b >= 0 && static_cast<std::size_t>(b) < buses_.size()) {
      const drivers::Bus& bus = *buses_[static_cast<std::size_t>(b)];
      engine.write_receipt(i, bus.write_receipt(static_cast<std::uint16_t>(i)), wake_ns);
    }
  }
}

void Loop::swap_in(core::TimeNs wake_ns) {
  const Runtime& old = swap_.current();
  // A write still in flight would reach the new engine as "the NC holds it or the value
  // before", sent again as it is: one more bus round trip in which the register does not move
  // (in real time it then caught up by two or three counts). The swap waits for a cycle in which
  // the bus has confirmed every write, at most swap_wait_max_cycles.
  take_receipts(old, wake_ns);
  bool in_flight = false;
  for (std::size_t i = 0; i < old.engine->register_count() && !in_flight; ++i) {
    in_flight = old.engine->write_in_flight(i) != 0;
  }
  if (in_flight && swap_waited_ < options_.swap_wait_max_cycles) {
    ++swap_waited_;
    local_.swap_waiting = swap_waited_;
    return;
  }
  const double waited = static_cast<double>(swap_waited_);
  swap_waited_ = 0;
  local_.swap_waiting = 0;
  const bool was_dry = old.dry_run;
  const std::uint64_t old_generation = old.engine->state_generation();
  const std::uint64_t old_sequence = old.engine->write_sequence();
  const core::engine::EngineCounters old_counters = old.engine->counters();
  const std::size_t n = old.engine->export_state(carry_);
  const std::size_t motion = old.engine->export_motion(motion_carry_);
  if (n == 0 && old.engine->state_capacity() > 0) {
    note(wake_ns, NoteCode::kStateExportFailed,
         static_cast<std::int64_t>(old.engine->state_capacity()), 0.0);
  } else if (swap_.pickup()) {
    // `old` may be freed by the reclaiming thread from here on: only rt is used below.
    const Runtime& rt = swap_.current();
    // The buses may still report the old engine's writes: the new one numbers its own after.
    rt.engine->continue_write_sequence(old_sequence);
    std::span<const std::byte> carried(carry_.data(), n);
    if (!was_dry && rt.dry_run) {
      // Entering dry run: what the NC has now is kept aside (and persisted soon, unless the
      // file holds it already); the dry run itself carries on from the same state.
      std::copy_n(carry_.data(), n, anchor_.data());
      anchor_size_ = n;
      anchor_persisted_ = old_generation == persisted_generation_;
      note(wake_ns, NoteCode::kDryRunEntered, static_cast<std::int64_t>(rt.generation), 0.0);
    } else if (was_dry && !rt.dry_run) {
      // Leaving dry run: the dry run's register values were never sent. The new engine starts
      // from the state as the NC has it, and its limiters from those values.
      carried = std::span<const std::byte>(anchor_.data(), anchor_size_);
      note(wake_ns, NoteCode::kDryRunLeft, static_cast<std::int64_t>(rt.generation), 0.0);
    }
    if (!carried.empty() && !rt.engine->import_state(carried, wake_ns)) {
      note(wake_ns, NoteCode::kStateCarryFailed, static_cast<std::int64_t>(rt.generation), 0.0);
    }
    // The tool moves on through the swap: no cycle of cut path or feed direction is lost.
    (void)rt.engine->import_motion(std::span<const std::byte>(motion_carry_.data(), motion));
    handover_base_ = add_handovers(handover_base_, old_counters);
    ++local_.reloads;
    local_.config_generation = rt.generation;
    local_.config_since_cycle = local_.cycles;
    persisted_generation_ = ~std::uint64_t{0};  // persist under the new configuration soon
    note(wake_ns, NoteCode::kConfigSwapped, static_cast<std::int64_t>(rt.generation), waited);
  }
}

void Loop::cycle(core::TimeNs wake_ns, bool stamp) {
  ++local_.cycles;
  // A reload: export the running engine's state first (the retired configuration may be freed
  // by the reclaiming thread as soon as pickup() returns), then hand it to the new engine.
  if (swap_.pending()) {
    swap_in(wake_ns);
  }
  const Runtime& rt = swap_.current();
  core::engine::Engine& engine = *rt.engine;
  const bool hold = hold_.load(std::memory_order_relaxed);
  engine.set_hold(hold);
  local_.hold = hold;
  local_.dry_run = rt.dry_run;
  // The limiter bounds what reaches the NC: each register's next write waits for the bus's
  // receipt of the last one (core/engine/engine.hpp, "Write receipts").
  engine.set_write_receipts(true);
  take_receipts(rt, wake_ns);

  events_.clear();
  for (std::size_t b = 0; b < buses_.size(); ++b) {
    core::Event e;
    while (events_.size() < options_.max_events_per_cycle && buses_[b]->rx().try_pop(e)) {
      // The engine keeps its event cursors per bus: the bus is the index in this list.
      core::EventOrigin* o = core::origin_of(e);
      if (o != nullptr) {
        o->bus = static_cast<std::uint8_t>(b);
      }
      // A counter_only event only moves the engine's cursor: not an event in the statistics.
      local_.events_in += o != nullptr && o->counter_only ? 0U : 1U;
      events_.push_back(e);  // capacity reserved: no allocation
    }
  }
  if (stamp) {
    // Lock-step: the NC state was published for the tick's instant; the driver's reception
    // time is wall time and would make the run depend on scheduling.
    for (core::Event& e : events_) {
      std::visit([wake_ns](auto& ev) { ev.time_ns = wake_ns; }, e);
    }
  }

  engine.step(wake_ns, std::span<const core::Event>(events_.data(), events_.size()), out_);

  std::uint64_t woken = 0;  // buses that got a write this cycle (bit per bus, the first 64)
  for (const core::OffsetWrite& w : out_.writes) {
    if (rt.dry_run) {
      // Never sent: the dry-run engine moves on as if the NC had taken it.
      ++local_.writes_dry_run;
      engine.write_receipt(w.register_index, {w.sequence, core::WriteOutcome::kReached}, wake_ns);
      continue;
    }
    const int b =
        w.register_index < rt.register_bus.size() ? rt.register_bus[w.register_index] : -1;
    drivers::Bus* bus = b >= 0 && static_cast<std::size_t>(b) < buses_.size()
                            ? buses_[static_cast<std::size_t>(b)]
                            : nullptr;
    if (bus != nullptr && bus->tx().try_push(w)) {
      ++local_.writes_sent;
      if (b < 64) {
        woken |= std::uint64_t{1} << b;
      }
      if (!bus->confirms_writes()) {
        // It delivers every write it takes, in order.
        engine.write_receipt(w.register_index, {w.sequence, core::WriteOutcome::kReached}, wake_ns);
      }
    } else {
      // The NC keeps what it held: the engine writes the register again from there.
      ++local_.writes_dropped;
      engine.write_receipt(w.register_index, {w.sequence, core::WriteOutcome::kRefused}, wake_ns);
      note(wake_ns, NoteCode::kWriteDropped, w.register_index, w.value_um);
    }
  }
  // A driver that sleeps between frames (CAN) sends at once instead of at its next poll.
  for (std::size_t b = 0; b < buses_.size() && b < 64; ++b) {
    if ((woken >> b) & 1U) {
      buses_[b]->wake();
    }
  }
  for (const core::AlarmEvent& a : out_.alarms) {
    ++local_.alarms;
    if (!alarms_.try_push(a)) {
      ++local_.alarms_dropped;
    }
  }
  for (core::MeasurementRecord r : out_.records) {
    ++local_.records;
    if (measurement_log_ != nullptr) measurement_log_->stamp(r, engine.context());
    if (measurement_log_ == nullptr || !measurement_log_->ring().try_push(r)) {
      ++local_.records_dropped;
    }
  }
  if (measurement_log_ != nullptr && measurement_log_->face_probe().enabled()) {
    log_face_probe(engine);
  }

  // State: export when it changed, at most every state_min_interval_s, never in hold mode (the
  // corrupt file stays for the operator to inspect). In dry run only the state kept aside when
  // the dry run began is written (once): the dry run's values never reach the file, so a restart
  // without --dry-run resumes from what the NC really has.
  if (persister_ != nullptr && !hold && rt.dry_run) {
    if (!anchor_persisted_ && anchor_size_ > 0) {
      if (StatePersister::Blob* blob = persister_->acquire()) {
        if (anchor_size_ <= blob->data.size()) {
          std::copy_n(anchor_.data(), anchor_size_, blob->data.data());
          blob->size = anchor_size_;
          persister_->submit(blob);
          ++local_.state_exports;
        } else {
          persister_->release(blob);
          ++local_.state_export_failed;
        }
        anchor_persisted_ = true;  // tried once; the exit writes it (final_state) if it failed
      } else {
        ++local_.state_export_busy;
      }
    }
  } else if (persister_ != nullptr && !hold) {
    const std::uint64_t gen = engine.state_generation();
    const double since_s = core::seconds(wake_ns - last_export_ns_);
    if (gen != persisted_generation_ && since_s >= options_.state_min_interval_s) {
      if (StatePersister::Blob* blob = persister_->acquire()) {
        const std::size_t n = engine.export_state(blob->data);
        if (n > 0) {
          blob->size = n;
          persister_->submit(blob);
          ++local_.state_exports;
          persisted_generation_ = gen;
          last_export_ns_ = wake_ns;
        } else {
          persister_->release(blob);
          ++local_.state_export_failed;
          last_export_ns_ = wake_ns;  // do not retry every cycle
        }
      } else {
        ++local_.state_export_busy;
      }
    }
  }

  local_.engine = engine.counters();
  local_.handover = add_handovers(handover_base_, local_.engine);
  if (local_.cycles % 10 == 1) {
    RegisterSnapshot snap;
    snap.config_generation = rt.generation;
    snap.count =
        static_cast<std::uint32_t>(std::min(engine.register_count(), kMaxSnapshotRegisters));
    for (std::size_t i = 0; i < snap.count; ++i) {
      snap.regs[i] = engine.register_state(i);
    }
    registers_.store(snap);
    ModulesSnapshot mods;
    mods.config_generation = rt.generation;
    mods.count = static_cast<std::uint32_t>(std::min(engine.module_count(), kMaxSnapshotModules));
    for (std::size_t m = 0; m < mods.count; ++m) {
      const auto& mod = engine.module(m);
      auto& ms = mods.modules[m];
      const std::string_view name = mod.name();
      const std::size_t len = std::min(name.size(), ms.name.size() - 1);
      std::copy_n(name.data(), len, ms.name.data());
      ms.name[len] = '\0';
      ms.count = static_cast<std::uint32_t>(mod.status(ms.values));
    }
    modules_.store(mods);
  }
}

}  // namespace nccomp::daemon
