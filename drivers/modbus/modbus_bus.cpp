#include "drivers/modbus/modbus_bus.hpp"

#include <modbus/modbus.h>
#include <pthread.h>
#include <sched.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstring>
#include <ctime>
#include <optional>
#include <span>
#include <sstream>
#include <stdexcept>
#include <string>
#include <variant>

namespace nccomp::drivers::modbus {
namespace {

modbus_t* mb(const std::unique_ptr<void, ModbusBus::ModbusDeleter>& p) {
  return static_cast<modbus_t*>(p.get());
}

constexpr core::TimeNs kNsPerS = 1'000'000'000;

core::TimeNs to_ns(double s) { return static_cast<core::TimeNs>(std::llround(s * 1e9)); }

std::uint32_t to_ms(core::TimeNs ns) {
  return static_cast<std::uint32_t>(std::llround(static_cast<double>(ns) * 1e-6));
}

// While the connection is down: how often the I/O thread takes the loop's writes and publishes
// its status during a back-off wait.
constexpr core::TimeNs kDownTickNs = 20'000'000;

void set_timeout(modbus_t* ctx, double s, bool response) {
  const auto us = static_cast<std::uint64_t>(std::llround(s * 1e6));
  const auto sec = static_cast<std::uint32_t>(us / 1'000'000U);
  const auto usec = static_cast<std::uint32_t>(us % 1'000'000U);
  if (response) {
    modbus_set_response_timeout(ctx, sec, usec);
  } else {
    modbus_set_byte_timeout(ctx, sec, usec);
  }
}

}  // namespace

core::TimeNs monotonic_now_ns() noexcept {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<core::TimeNs>(ts.tv_sec) * kNsPerS + ts.tv_nsec;
}

std::size_t modbus_counters(const ModbusStatus& st, std::span<BusCounterValue> out) noexcept {
  const auto& x = st.exceptions;
  const std::array<std::uint64_t, kModbusCounterNames.size()> values = {
      x[1],
      x[2],
      x[3],
      x[4],
      x[5],
      x[6],
      x[7],
      x[8],
      x[10],
      x[11],
      x[0] + x[9],
      st.timeouts,
      st.crc_errors,
      st.bad_responses,
      st.connection_errors,
      st.connect_attempts,
      st.reconnect_backoffs,
      st.poll_overruns,
      st.events_lost,
      st.sequence_resets,
      st.sequence_unchanged_after_reconnect,
      st.events_recovered_after_start,
      st.events_lost_while_down,
      st.values_invalid,
      st.values_out_of_range,
      st.offsets_rejected,
      st.verify_mismatches,
      st.offsets_pending,
      st.reconnect_backoff_ms,
      st.io_sched_fifo_priority,
      st.io_sched_errno,
      st.io_affinity_errno,
  };
  const std::size_t n = std::min(out.size(), values.size());
  for (std::size_t i = 0; i < n; ++i) {
    out[i] = BusCounterValue{kModbusCounterNames[i], values[i], i >= kModbusFirstGauge};
  }
  return n;
}

std::vector<IoSetupLine> describe_io_setup(const IoThreadSetup& setup, const ModbusConfig& config) {
  // Streams, not std::string operator+: GCC 12 at -O3 reports a false -Wrestrict on
  // "literal" + std::string (see builtin_sections.cpp, 8586b49).
  std::ostringstream got;
  if (setup.policy == SCHED_FIFO || setup.policy == SCHED_RR) {
    got << (setup.policy == SCHED_FIFO ? "SCHED_FIFO" : "SCHED_RR") << " priority "
        << setup.priority;
  } else if (setup.policy == SCHED_OTHER) {
    got << "SCHED_OTHER";
  } else {
    got << "policy " << setup.policy;
  }
  std::vector<IoSetupLine> lines;
  std::ostringstream line;
  line << "I/O thread: ";
  bool warning = false;
  if (setup.requested_fifo_priority > 0 && setup.sched_errno == 0) {
    line << got.str();
  } else if (setup.requested_fifo_priority > 0) {
    warning = true;
    line << "SCHED_FIFO priority " << setup.requested_fifo_priority
         << " refused: " << std::strerror(setup.sched_errno) << " (running " << got.str()
         << "; SCHED_FIFO needs CAP_SYS_NICE or an RLIMIT_RTPRIO of at least "
         << setup.requested_fifo_priority << ")";
  } else if (setup.policy == SCHED_OTHER) {
    line << got.str()
         << " (io_sched_fifo_priority not set; under load its polls may overrun, see "
            "poll_overruns)";
  } else {
    line << got.str()
         << ", inherited from the thread that started it (io_sched_fifo_priority not set)";
  }
  lines.push_back({warning, line.str()});
  if (setup.affinity_requested) {
    std::ostringstream cpus;
    for (std::size_t i = 0; i < config.io_cpu_affinity.size(); ++i) {
      cpus << (i == 0 ? "" : ",") << config.io_cpu_affinity[i];
    }
    std::ostringstream aff;
    aff << "I/O thread: ";
    if (setup.affinity_errno == 0) {
      aff << "pinned to CPU(s) " << cpus.str();
    } else {
      aff << "CPU affinity " << cpus.str() << " refused: " << std::strerror(setup.affinity_errno)
          << " (running on any CPU)";
    }
    lines.push_back({setup.affinity_errno != 0, aff.str()});
  }
  return lines;
}

void ModbusBus::ModbusDeleter::operator()(void* ctx) const noexcept {
  auto* m = static_cast<modbus_t*>(ctx);
  modbus_close(m);
  modbus_free(m);
}

ModbusBus::ModbusBus(ModbusConfig config)
    : config_(std::move(config)),
      rx_(config_.rx_capacity),
      tx_(config_.tx_capacity),
      decoder_(config_),
      input_watch_(to_ns(config_.degraded_alarm_after_s),
                   config_.groups[static_cast<std::size_t>(Group::kAxis)].present),
      block_ok_(config_.blocks.size(), 0),
      bits_(2000, 0),
      slot_of_register_(65536, -1),
      slots_(config_.offsets.size()),
      receipts_(config_.offsets.size()),
      backoff_(to_ns(config_.reconnect_min_s), to_ns(config_.reconnect_max_s),
               to_ns(config_.reconnect_reset_after_s)) {
  for (std::size_t i = 0; i < config_.offsets.size(); ++i) {
    slot_of_register_[config_.offsets[i].register_index] = static_cast<std::int32_t>(i);
  }
}

ModbusBus::~ModbusBus() { stop(); }

void ModbusBus::start() {
  if (io_.joinable()) {
    throw std::logic_error("ModbusBus::start: already started");
  }
  // A connection opened by read_offset() belongs to the caller's thread: the I/O thread starts
  // from a fresh one (and its own failure counting).
  disconnect();
  running_.store(true, std::memory_order_release);
  {
    std::lock_guard<std::mutex> lock(ls_mu_);
    setup_done_ = false;
  }
  io_ = std::thread([this] { run(); });
  {
    // The thread sets itself up before its first request; report what it got from here, the
    // caller's thread (the daemon logs it), not from the I/O thread.
    std::unique_lock<std::mutex> lock(ls_mu_);
    ls_cv_.wait(lock, [this] { return setup_done_; });
  }
  if (on_setup_) {
    on_setup_(io_setup_);
  }
}

void ModbusBus::setup_io_thread() {
  IoThreadSetup s;
  s.tid = static_cast<int>(::gettid());
  s.requested_fifo_priority = config_.io_sched_fifo_priority;
  if (config_.io_sched_fifo_priority > 0) {
    sched_param sp{};
    sp.sched_priority = config_.io_sched_fifo_priority;
    s.sched_errno = pthread_setschedparam(pthread_self(), SCHED_FIFO, &sp);
  }
  if (!config_.io_cpu_affinity.empty()) {
    s.affinity_requested = true;
    cpu_set_t set;
    CPU_ZERO(&set);
    for (int c : config_.io_cpu_affinity) {
      CPU_SET(static_cast<std::size_t>(c), &set);  // 0..1023 (config), CPU_SETSIZE is 1024
    }
    s.affinity_errno = pthread_setaffinity_np(pthread_self(), sizeof(set), &set);
  }
  // What the thread runs at now, whatever was asked: a thread started by a SCHED_FIFO thread
  // inherits its policy, and that is what the status should show.
  int policy = SCHED_OTHER;
  sched_param now{};
  if (pthread_getschedparam(pthread_self(), &policy, &now) == 0) {
    s.policy = policy;
    s.priority = now.sched_priority;
  }
  st_.io_sched_fifo_priority = s.policy == SCHED_FIFO ? static_cast<std::uint32_t>(s.priority) : 0U;
  st_.io_sched_errno = static_cast<std::uint32_t>(s.sched_errno);
  st_.io_affinity_errno = static_cast<std::uint32_t>(s.affinity_errno);
  {
    std::lock_guard<std::mutex> lock(ls_mu_);
    io_setup_ = s;
    setup_done_ = true;
  }
  ls_cv_.notify_all();
}

std::optional<double> ModbusBus::read_offset(std::uint16_t register_index) {
  if (io_.joinable()) {
    return std::nullopt;  // the I/O thread owns the context now
  }
  const OffsetMap* map = nullptr;
  for (const OffsetMap& m : config_.offsets) {
    if (m.register_index == register_index) {
      map = &m;
      break;
    }
  }
  if (map == nullptr) {
    return std::nullopt;
  }
  if (!ctx_) {
    if (readback_connect_failed_ || !connect()) {
      readback_connect_failed_ = true;
      return std::nullopt;
    }
  }
  std::array<std::uint16_t, 2> regs{};
  const int n = width(map->encoding.type);
  rtu_gap();
  const int rc = modbus_read_registers(mb(ctx_), map->address, n, regs.data());
  after_transaction();
  if (rc != n) {
    return std::nullopt;
  }
  const double v = decode(std::span<const std::uint16_t>(regs.data(), static_cast<std::size_t>(n)),
                          map->encoding);
  if (!std::isfinite(v)) {
    return std::nullopt;
  }
  return v;
}

bool ModbusBus::resume_events(const core::EventCursorSet& cursors) {
  if (io_.joinable()) {
    return true;  // the I/O thread owns the decoder now
  }
  decoder_.resume(cursors);
  return true;
}

std::size_t ModbusBus::events_while_down(std::span<EventsWhileDown> out) const {
  const ModbusStatus st = status_.load();
  std::size_t n = 0;
  for (std::size_t gi = 1; gi < kGroupCount && n < out.size(); ++gi) {
    const ResumeReport& r = st.resume[gi];
    if (r.done) {
      out[n++] = EventsWhileDown{static_cast<std::uint8_t>(gi - 1),
                                 r.cursor,
                                 r.counter,
                                 r.events,
                                 r.nc_restarted,
                                 r.delivered};
    }
  }
  return n;
}

void ModbusBus::stop() {
  {
    // Under the mutex, so that the lock-step I/O thread cannot miss the wake-up.
    std::lock_guard<std::mutex> lock(ls_mu_);
    running_.store(false, std::memory_order_release);
  }
  ls_cv_.notify_all();
  if (io_.joinable()) {
    io_.join();
  }
}

void ModbusBus::sleep_until(core::TimeNs t_ns) const {
  // In slices, so that stop() is honoured within 20 ms even during a long back-off.
  constexpr core::TimeNs kSliceNs = 20'000'000;
  for (;;) {
    const core::TimeNs now = monotonic_now_ns();
    if (now >= t_ns || !running_.load(std::memory_order_acquire)) {
      return;
    }
    const core::TimeNs until = std::min(t_ns, now + kSliceNs);
    timespec ts{};
    ts.tv_sec = until / kNsPerS;
    ts.tv_nsec = until % kNsPerS;
    clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr);
  }
}

bool ModbusBus::connect() {
  ++st_.connect_attempts;
  modbus_t* ctx = nullptr;
  if (config_.transport == Transport::kTcp) {
    const std::string service = std::to_string(config_.port);
    ctx = modbus_new_tcp_pi(config_.host.c_str(), service.c_str());
  } else {
    const char parity = config_.parity == Parity::kNone   ? 'N'
                        : config_.parity == Parity::kEven ? 'E'
                                                          : 'O';
    ctx = modbus_new_rtu(config_.device.c_str(), static_cast<int>(config_.baud), parity,
                         config_.data_bits, config_.stop_bits);
  }
  if (ctx == nullptr) {
    st_.last_errno = errno;
    return false;
  }
  std::unique_ptr<void, ModbusDeleter> holder(ctx);
  modbus_set_slave(ctx, config_.unit_id);
  set_timeout(ctx, config_.response_timeout_s, true);
  set_timeout(ctx, config_.byte_timeout_s, false);
  // Recovery is ours (flush, reconnect, back-off): libmodbus' own would sleep and reconnect
  // inside a call.
  modbus_set_error_recovery(ctx, MODBUS_ERROR_RECOVERY_NONE);
  if (modbus_connect(ctx) == -1) {
    st_.last_errno = errno;
    // modbus_close on a failed connect is harmless; the deleter frees the context.
    return false;
  }
  if (config_.transport == Transport::kRtu && config_.rs485 &&
      modbus_rtu_set_serial_mode(ctx, MODBUS_RTU_RS485) == -1) {
    st_.last_errno = errno;
    return false;
  }
  ctx_ = std::move(holder);
  consecutive_failures_ = 0;
  // last_frame_end_ns_ is kept: the silence is the line's, and a late answer to the request
  // before a reconnect may just have ended on it.
  return true;
}

void ModbusBus::disconnect() {
  ctx_.reset();
  consecutive_failures_ = 0;
}

void ModbusBus::rtu_gap() {
  // RTU frames are delimited by 3.5 character times of silence: keep it before each request.
  if (config_.transport != Transport::kRtu || last_frame_end_ns_ == 0) {
    return;
  }
  const core::TimeNs until = last_frame_end_ns_ + to_ns(rtu_frame_gap_s(config_));
  timespec ts{};
  ts.tv_sec = until / kNsPerS;
  ts.tv_nsec = until % kNsPerS;
  // Absolute deadline: a signal (EINTR) only restarts the wait, it never shortens the silence.
  while (monotonic_now_ns() < until &&
         clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr) == EINTR) {
  }
}

void ModbusBus::after_transaction() {
  ++st_.bus.counters.frames_tx;
  last_frame_end_ns_ = monotonic_now_ns();
}

bool ModbusBus::fail(int err) {
  ++st_.bus.counters.faults;
  st_.last_errno = err;
  modbus_t* ctx = mb(ctx_);
  if (err > MODBUS_ENOBASE && err <= MODBUS_ENOBASE + 11) {
    // An exception response: the server is alive and answered.
    ++st_.exceptions[static_cast<std::size_t>(err - MODBUS_ENOBASE)];
    ++st_.bus.counters.frames_rx;
    consecutive_failures_ = 0;
    return true;
  }
  cycle_failed_ = true;
  if (err == ETIMEDOUT) {
    ++st_.timeouts;
  } else if (err == EMBBADCRC) {
    ++st_.crc_errors;
    ++st_.bus.counters.malformed;
  } else if (err == EMBBADDATA || err == EMBBADEXC || err == EMBUNKEXC || err == EMBMDATA ||
             err == EMBBADSLAVE) {
    ++st_.bad_responses;
    ++st_.bus.counters.malformed;
    if (err == EMBUNKEXC) {
      ++st_.exceptions[0];
    }
  } else {
    // Socket / device error (ECONNRESET, EPIPE, EIO ...): the connection is gone.
    ++st_.connection_errors;
    disconnect();
    return false;
  }
  // A late or garbled answer must not be taken for the next one.
  modbus_flush(ctx);
  if (++consecutive_failures_ >= config_.dead_after_failures) {
    // Silence or garbage for this long: a dead peer, a pulled cable or a desynchronised stream.
    disconnect();
    return false;
  }
  return true;
}

void ModbusBus::poll(core::TimeNs now_ns) {
  (void)now_ns;
  std::fill(block_ok_.begin(), block_ok_.end(), std::uint8_t{0});
  bool any = false;
  for (std::size_t i = 0; i < config_.blocks.size() && ctx_; ++i) {
    const ReadBlock& b = config_.blocks[i];
    std::span<std::uint16_t> buf = decoder_.block(i);
    rtu_gap();
    modbus_t* ctx = mb(ctx_);
    ++cycle_reads_;
    int rc = -1;
    switch (b.table) {
      case Table::kHolding:
        rc = modbus_read_registers(ctx, b.start, b.count, buf.data());
        break;
      case Table::kInput:
        rc = modbus_read_input_registers(ctx, b.start, b.count, buf.data());
        break;
      case Table::kCoil:
        rc = modbus_read_bits(ctx, b.start, b.count, bits_.data());
        break;
      case Table::kDiscreteInput:
        rc = modbus_read_input_bits(ctx, b.start, b.count, bits_.data());
        break;
    }
    const int err = errno;
    after_transaction();
    if (rc != b.count) {
      if (!fail(rc == -1 ? err : EMBBADDATA)) {
        break;
      }
      continue;
    }
    if (is_bit_table(b.table)) {
      for (std::size_t k = 0; k < b.count; ++k) {
        buf[k] = bits_[k] != 0 ? 1 : 0;
      }
    }
    ++st_.bus.counters.frames_rx;
    consecutive_failures_ = 0;
    block_ok_[i] = 1;
    any = true;
  }
  ++st_.polls;
  bool axis_seen = false;
  const bool all_read = ctx_ && std::all_of(block_ok_.begin(), block_ok_.end(),
                                            [](std::uint8_t ok) { return ok != 0; });
  if (!any) {
    note_input(all_read, axis_seen);
    return;
  }
  const core::TimeNs t = monotonic_now_ns();
  st_.bus.last_rx_ns = t;
  for (const core::Event& e : decoder_.decode(t, block_ok_)) {
    axis_seen = axis_seen || std::holds_alternative<core::AxisSample>(e);
    if (rx_.try_push(e)) {
      const core::EventOrigin* o = core::origin_of(e);
      st_.bus.counters.events_decoded += o != nullptr && o->counter_only ? 0U : 1U;
    } else {
      ++st_.bus.counters.events_dropped;
    }
  }
  const DecodeCounters& dc = decoder_.counters();
  st_.events_lost = dc.events_lost;
  st_.sequence_resets = dc.sequence_resets;
  st_.sequence_unchanged_after_reconnect = dc.sequence_unchanged_after_reconnect;
  st_.events_recovered_after_start = dc.events_recovered_after_start;
  st_.events_lost_while_down = dc.events_lost_while_down;
  st_.resume = decoder_.resume_reports();
  st_.values_invalid = dc.values_invalid;
  st_.values_out_of_range = dc.values_out_of_range;
  note_input(all_read, axis_seen);
}

void ModbusBus::note_input(bool all_read, bool axis_seen) {
  const core::TimeNs now = monotonic_now_ns();
  if (all_read) {
    input_watch_.link_ok(now);
  }
  if (axis_seen) {
    input_watch_.axis_ok(now);
  }
  if (lockstep_) {
    // The peer is the clock: judged at its polls only, so that a paused peer is not stale.
    st_.bus.input_stale = input_watch_.stale(now);
  }
}

core::WriteReceipt ModbusBus::write_receipt(std::uint16_t register_index) const noexcept {
  const std::int32_t idx = slot_of_register_[register_index];
  return idx < 0 ? kUnmappedReceipt : receipts_.load(static_cast<std::size_t>(idx));
}

void ModbusBus::drain_tx(core::TimeNs now_ns) {
  core::OffsetWrite w;
  while (tx_.try_pop(w)) {
    const std::int32_t idx = slot_of_register_[w.register_index];
    if (idx < 0) {
      ++st_.offsets_rejected;
      ++st_.bus.counters.offsets_failed;
      continue;
    }
    OffsetSlot& s = slots_[static_cast<std::size_t>(idx)];
    // Latest value wins: an older pending value for this register is replaced, and never
    // reported. The engine's offsets wait for their receipt, so only a flag (or a writer
    // without receipts) gets here with a value still pending.
    if (!s.dirty) {
      s.dirty_since_ns = now_ns;
    }
    s.value_um = w.value_um;
    s.sequence = w.sequence;
    s.has_value = true;
    s.dirty = true;
  }
}

bool ModbusBus::write_one(std::size_t slot_index) {
  const OffsetMap& map = config_.offsets[slot_index];
  OffsetSlot& slot = slots_[slot_index];
  std::array<std::uint16_t, 2> regs{};
  const int n = width(map.encoding.type);
  if (encode(slot.value_um, map.encoding, regs) != EncodeResult::kOk) {
    // Not representable on the NC (NaN, beyond the register's range): the NC keeps its last
    // value and the status alarm says so. Never clamp silently.
    ++st_.offsets_rejected;
    ++st_.bus.counters.offsets_failed;
    slot.rejected = true;
    slot.dirty = false;
    receipts_.publish(slot_index, slot.sequence, core::WriteOutcome::kRefused);
    return true;
  }
  if (slot.resend) {
    ++st_.bus.counters.offsets_retried;
  }
  rtu_gap();
  ++cycle_writes_;
  int rc = modbus_write_registers(mb(ctx_), map.address, n, regs.data());
  int err = errno;
  after_transaction();
  if (rc != n) {
    slot.resend = true;
    return fail(rc == -1 ? err : EMBBADDATA);
  }
  ++st_.bus.counters.frames_rx;
  consecutive_failures_ = 0;
  if (config_.verify_writes) {
    std::array<std::uint16_t, 2> back{};
    rtu_gap();
    ++cycle_reads_;
    rc = modbus_read_registers(mb(ctx_), map.address, n, back.data());
    err = errno;
    after_transaction();
    if (rc != n) {
      slot.resend = true;
      return fail(rc == -1 ? err : EMBBADDATA);
    }
    ++st_.bus.counters.frames_rx;
    if (back[0] != regs[0] || (n == 2 && back[1] != regs[1])) {
      ++st_.verify_mismatches;
      ++st_.bus.counters.faults;
      slot.resend = true;
      return true;
    }
  }
  ++st_.bus.counters.offsets_written;
  slot.dirty = false;
  slot.rejected = false;
  slot.resend = false;
  receipts_.publish(slot_index, slot.sequence, core::WriteOutcome::kReached);
  return true;
}

void ModbusBus::write_offsets() {
  for (std::size_t i = 0; i < slots_.size() && ctx_; ++i) {
    if (slots_[i].dirty && !write_one(i)) {
      break;
    }
  }
}

void ModbusBus::publish(core::TimeNs now_ns) {
  std::uint32_t pending = 0;
  bool alarm = false;
  const core::TimeNs tolerance = to_ns(config_.alarm_after_s);
  for (const OffsetSlot& s : slots_) {
    pending += s.dirty ? 1U : 0U;
    alarm = alarm || s.rejected || (s.dirty && now_ns - s.dirty_since_ns > tolerance);
  }
  if (!ctx_ && down_since_ns_ != 0 && now_ns - down_since_ns_ > tolerance) {
    alarm = true;
  }
  st_.offsets_pending = pending;
  st_.bus.alarm = alarm;
  if (!lockstep_) {
    st_.bus.input_stale = st_.bus.state != LinkState::kStopped && input_watch_.stale(now_ns);
  }
  status_.store(st_);
}

bool ModbusBus::request(std::uint64_t& req, const std::uint64_t& done, const bool& ok,
                        core::TimeNs timeout_ns) {
  std::unique_lock<std::mutex> lock(ls_mu_);
  const std::uint64_t want = ++req;
  ls_cv_.notify_all();
  const bool completed =
      ls_cv_.wait_for(lock, std::chrono::nanoseconds(timeout_ns), [&] { return done >= want; });
  return completed && ok;
}

bool ModbusBus::sync(std::uint64_t cycle, core::TimeNs timeout_ns) {
  (void)cycle;  // one poll per request: the request counter orders them
  return request(sync_req_, sync_done_, sync_ok_, timeout_ns);
}

bool ModbusBus::flush(std::uint64_t cycle, core::TimeNs timeout_ns) {
  (void)cycle;
  return request(flush_req_, flush_done_, flush_ok_, timeout_ns);
}

void ModbusBus::lost(core::TimeNs now_ns) {
  next_connect_ns_ = backoff_.lost(now_ns);
  st_.reconnect_backoffs = backoff_.waits();
  st_.reconnect_backoff_ms = to_ms(backoff_.raised_delay_ns());
}

bool ModbusBus::ensure_connected(bool& ever_connected) {
  if (ctx_) {
    return true;
  }
  core::TimeNs now = monotonic_now_ns();
  if (down_since_ns_ == 0) {
    down_since_ns_ = now;
  }
  if (now < next_connect_ns_) {
    sleep_until(next_connect_ns_);
    if (!running_.load(std::memory_order_acquire)) {
      return false;
    }
    now = monotonic_now_ns();
  }
  if (!connect()) {
    ++st_.connection_errors;
    ++st_.bus.counters.faults;
    st_.bus.state = ever_connected ? LinkState::kDown : LinkState::kConnecting;
    lost(monotonic_now_ns());
    publish(monotonic_now_ns());
    return false;
  }
  down_since_ns_ = 0;
  if (!ever_connected) {
    // The first connection: offsets queued before it are first writes, already dirty.
    ever_connected = true;
    return true;
  }
  ++st_.bus.counters.reconnects;
  // The NC may have restarted: its event counters are checked at their next read ...
  decoder_.note_reconnect();
  // ... and, as it may have lost what it had, every known offset is written again.
  for (OffsetSlot& s : slots_) {
    if (s.has_value && !s.rejected) {
      if (!s.dirty) {
        s.dirty_since_ns = now;
      }
      s.dirty = true;
      s.resend = true;
    }
  }
  return true;
}

void ModbusBus::run_lockstep() {
  bool ever_connected = false;
  down_since_ns_ = monotonic_now_ns();
  input_watch_.start(down_since_ns_);
  st_.bus.state = LinkState::kConnecting;
  publish(down_since_ns_);
  // Connect before the first TICK arrives, so that the first cycle does not wait for it.
  (void)ensure_connected(ever_connected);
  for (;;) {
    std::uint64_t sync_want = 0;
    std::uint64_t flush_want = 0;
    {
      std::unique_lock<std::mutex> lock(ls_mu_);
      ls_cv_.wait_for(lock, std::chrono::milliseconds(100), [&] {
        return !running_.load(std::memory_order_acquire) || sync_req_ > sync_done_ ||
               flush_req_ > flush_done_;
      });
      if (!running_.load(std::memory_order_acquire)) {
        break;
      }
      sync_want = sync_req_ > sync_done_ ? sync_req_ : 0;
      flush_want = flush_req_ > flush_done_ ? flush_req_ : 0;
    }
    if (sync_want == 0 && flush_want == 0) {
      if (!ctx_) {
        (void)ensure_connected(ever_connected);
      }
      publish(monotonic_now_ns());
      continue;
    }
    if (!ensure_connected(ever_connected)) {
      continue;  // the loop's wait times out and is counted; the request stays open
    }
    const core::TimeNs start = monotonic_now_ns();
    const std::uint64_t faults_before = st_.bus.counters.faults;
    cycle_failed_ = false;
    bool flush_ok = true;
    bool sync_ok = true;
    // The older request first: a flush of cycle k is always asked before the sync of k + 1.
    if (flush_want != 0) {
      drain_tx(start);
      write_offsets();
      for (const OffsetSlot& slot : slots_) {
        flush_ok = flush_ok && !slot.dirty;
      }
      flush_ok = flush_ok && ctx_ != nullptr;
    }
    if (sync_want != 0 && ctx_) {
      poll(monotonic_now_ns());
      for (const std::uint8_t ok : block_ok_) {
        sync_ok = sync_ok && ok != 0;
      }
    }
    sync_ok = sync_ok && ctx_ != nullptr;
    const core::TimeNs now = monotonic_now_ns();
    st_.last_cycle_ns = now - start;
    st_.max_cycle_ns = std::max(st_.max_cycle_ns, st_.last_cycle_ns);
    if (!ctx_) {
      st_.bus.state = LinkState::kDown;
      down_since_ns_ = now;
      lost(now);
    } else {
      backoff_.healthy(now, !cycle_failed_);
      st_.reconnect_backoff_ms = to_ms(backoff_.raised_delay_ns());
      st_.bus.state =
          st_.bus.counters.faults != faults_before ? LinkState::kDegraded : LinkState::kUp;
    }
    publish(now);
    {
      std::lock_guard<std::mutex> lock(ls_mu_);
      if (flush_want != 0) {
        flush_done_ = flush_want;
        flush_ok_ = flush_ok;
      }
      if (sync_want != 0) {
        sync_done_ = sync_want;
        sync_ok_ = sync_ok;
      }
    }
    ls_cv_.notify_all();
  }
  disconnect();
  st_.bus.state = LinkState::kStopped;
  publish(monotonic_now_ns());
}

void ModbusBus::run() {
  setup_io_thread();
  if (lockstep_) {
    run_lockstep();
    return;
  }
  const core::TimeNs period = to_ns(1.0 / config_.poll_rate_hz);
  const core::TimeNs write_period = to_ns(1.0 / config_.offset_write_rate_hz);
  bool ever_connected = false;
  core::TimeNs next = monotonic_now_ns();
  core::TimeNs next_write = next;
  down_since_ns_ = next;
  input_watch_.start(next);
  st_.bus.state = LinkState::kConnecting;
  publish(next);
  while (running_.load(std::memory_order_acquire)) {
    core::TimeNs now = monotonic_now_ns();
    drain_tx(now);
    if (!ctx_) {
      if (now < next_connect_ns_) {
        // Back-off: keep taking the loop's writes (latest value wins; the engine sends a
        // register's next value only after this one's receipt) and publishing the state.
        publish(now);
        sleep_until(std::min(next_connect_ns_, now + kDownTickNs));
        continue;
      }
      if (!ensure_connected(ever_connected)) {
        continue;
      }
      next = monotonic_now_ns();
      next_write = next;
    }
    const core::TimeNs cycle_start = monotonic_now_ns();
    const std::uint64_t faults_before = st_.bus.counters.faults;
    cycle_failed_ = false;
    cycle_reads_ = 0;
    cycle_writes_ = 0;
    poll(cycle_start);
    drain_tx(monotonic_now_ns());
    if (ctx_ && monotonic_now_ns() >= next_write) {
      write_offsets();
      next_write += write_period;
      if (next_write < monotonic_now_ns()) {
        next_write = monotonic_now_ns();
      }
    }
    now = monotonic_now_ns();
    st_.last_cycle_ns = now - cycle_start;
    st_.max_cycle_ns = std::max(st_.max_cycle_ns, st_.last_cycle_ns);
    if (cycle_log_ != nullptr && ctx_) {
      (void)cycle_log_->try_push(CycleRecord{st_.last_cycle_ns, cycle_reads_, cycle_writes_});
    }
    if (!ctx_) {
      st_.bus.state = LinkState::kDown;
      down_since_ns_ = now;
      lost(now);
    } else {
      st_.bus.state =
          st_.bus.counters.faults != faults_before ? LinkState::kDegraded : LinkState::kUp;
      backoff_.healthy(now, !cycle_failed_);
      st_.reconnect_backoff_ms = to_ms(backoff_.raised_delay_ns());
    }
    publish(now);
    if (!ctx_) {
      continue;  // the next connect waits the back-off, however the connection was lost
    }
    next += period;
    if (now > next) {
      // Overrun: count it and restart the schedule from now instead of bursting to catch up.
      ++st_.poll_overruns;
      next = now;
      continue;
    }
    sleep_until(next);
  }
  disconnect();
  st_.bus.state = LinkState::kStopped;
  publish(monotonic_now_ns());
}

}  // namespace nccomp::drivers::modbus
