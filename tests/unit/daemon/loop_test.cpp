// GIVEN the loop thread wired to a loopback bus, WHEN it runs at 1 kHz, THEN events reach the
// engine, writes reach the bus, records reach the measurement log, a reload carries the state
// over at a cycle boundary, and nothing allocates on the loop thread after warm-up.
#include "daemon/loop.hpp"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <limits>
#include <mutex>
#include <optional>
#include <thread>
#include <vector>

#include "core/engine/ramp_module.hpp"
#include "drivers/loopback/loopback_bus.hpp"
#include "drivers/write_receipts.hpp"
#include "tests/support/alloc_counter.hpp"

namespace nccomp::daemon {
namespace {

using drivers::loopback::LoopbackBus;

namespace fs = std::filesystem;
using namespace std::chrono_literals;

// Turns each tool measurement into a measurement record (what S0 will do for real).
class RecordModule final : public core::engine::Module {
 public:
  std::string_view name() const noexcept override { return "records"; }
  void attach(const core::engine::RegisterTable& /*registers*/) override {}
  void step(core::TimeNs now_ns, std::span<const core::Event> events,
            core::StepOutput& out) noexcept override {
    for (const auto& e : events) {
      if (const auto* m = std::get_if<core::ToolMeasurement>(&e)) {
        core::MeasurementRecord r;
        r.time_ns = now_ns;
        r.tool = m->tool;
        r.measured_um = m->wear_um[0];
        out.records.push(r);
      }
    }
  }
};

std::unique_ptr<Runtime> make_runtime(double target_um, double rate_um_per_s, bool dry_run,
                                      std::uint64_t generation) {
  auto rt = std::make_unique<Runtime>();
  rt->engine = std::make_unique<core::engine::Engine>();
  std::vector<std::unique_ptr<core::engine::Module>> m;
  m.push_back(std::make_unique<core::engine::RampModule>(
      core::engine::RampConfig{"ramp", "T1", 0.0, target_um, rate_um_per_s}));
  m.push_back(std::make_unique<RecordModule>());
  rt->engine->configure({{"T1", core::engine::RegisterKind::kToolLengthWear, {200.0, 5.0, 500.0}}},
                        std::move(m));
  rt->register_bus = {0};
  rt->dry_run = dry_run;
  rt->generation = generation;
  return rt;
}

struct Rig {
  explicit Rig(bool dry_run = false)
      : dir(fs::temp_directory_path() /
            ("nccomp_loop_" + std::to_string(::getpid()) + "_" + std::to_string(counter++))),
        bus(256, 256),
        swap(make_runtime(100.0, 100.0, dry_run, 1)) {
    fs::create_directories(dir);
    persister = std::make_unique<StatePersister>((dir / "state.bin").string(), 4096);
    mlog = std::make_unique<MeasurementLogWriter>(dir.string(), 1 << 20, 2, 256);
    LoopOptions o;
    o.rate_hz = 1000.0;
    o.state_min_interval_s = 0.02;
    o.state_buffer_bytes = 4096;
    o.warmup_cycles = 20;
    o.thread_allocations = []() noexcept { return nccomp::test::thread_allocations(); };
    o.thread_deallocations = []() noexcept { return nccomp::test::thread_deallocations(); };
    loop = std::make_unique<Loop>(o, swap, std::vector<drivers::Bus*>{&bus}, persister.get(),
                                  mlog.get());
    bus.start();
    persister->start(0);
    mlog->start();
  }
  ~Rig() {
    loop->stop();
    persister->stop();
    mlog->stop();
    bus.stop();
    fs::remove_all(dir);
  }
  // Waits (bounded) until pred holds; the loop runs on its own thread.
  template <typename P>
  bool wait_for(P pred, std::chrono::milliseconds limit = 5000ms) {
    const auto end = std::chrono::steady_clock::now() + limit;
    while (!pred()) {
      if (std::chrono::steady_clock::now() > end) {
        return false;
      }
      std::this_thread::sleep_for(2ms);
    }
    return true;
  }
  static inline int counter = 0;
  fs::path dir;
  LoopbackBus bus;
  core::rt::ConfigSwap<Runtime> swap;
  std::unique_ptr<StatePersister> persister;
  std::unique_ptr<MeasurementLogWriter> mlog;
  std::unique_ptr<Loop> loop;
};

TEST(Loop, RampReachesTheBusAndStateIsPersisted) {
  Rig rig;
  rig.loop->start();
  ASSERT_TRUE(rig.wait_for([&] { return rig.loop->stats().cycles >= 300; }));
  rig.loop->stop();
  const double out = rig.swap.current().engine->register_state(0).output_um;
  EXPECT_GT(out, 5.0);  // 100 µm/s for ≥ 0.3 s of cycles (minus start-up)
  ASSERT_TRUE(rig.wait_for([&] {
    auto d = rig.bus.delivered(0);
    return d && !(*d < out) && !(*d > out);  // exactly equal
  })) << "the bus must receive exactly the engine's last output";
  const auto s = rig.loop->stats();
  EXPECT_EQ(s.writes_dropped, 0U);
  EXPECT_EQ(s.writes_sent, s.engine.writes_forwarded);
  EXPECT_GT(s.state_exports, 0U);
  EXPECT_EQ(s.allocations_after_warmup, 0) << "the loop thread allocated after warm-up";
  EXPECT_EQ(s.frees_after_warmup, 0) << "the loop thread freed after warm-up";
  rig.persister->stop();
  const auto f = read_state_file((rig.dir / "state.bin").string());
  ASSERT_EQ(f.status, StateFileStatus::kOk) << f.reason;
  auto fresh = make_runtime(100.0, 100.0, false, 1);
  ASSERT_TRUE(fresh->engine->import_state(f.payload, 0));
  EXPECT_GT(fresh->engine->register_state(0).output_um, 0.0);
  EXPECT_LE(fresh->engine->register_state(0).output_um, out);
}

TEST(Loop, EventsAreValidatedAndRecordsReachTheMeasurementLog) {
  Rig rig;
  rig.loop->start();
  for (int i = 0; i < 5; ++i) {
    core::ToolMeasurement m;
    m.tool = 7;
    m.wear_um[0] = 1.5 * i;
    ASSERT_TRUE(rig.bus.inject(m));
  }
  core::AxisSample bad;
  bad.position_mm[0] = std::numeric_limits<double>::quiet_NaN();
  ASSERT_TRUE(rig.bus.inject(bad));
  ASSERT_TRUE(rig.wait_for([&] { return rig.mlog->rows() >= 5; }));
  ASSERT_TRUE(rig.wait_for([&] { return rig.loop->stats().engine.events_invalid >= 1; }));
  rig.loop->stop();
  const auto s = rig.loop->stats();
  EXPECT_EQ(s.events_in, 6U);
  EXPECT_EQ(s.engine.events_accepted, 5U);
  EXPECT_EQ(s.engine.events_invalid, 1U);
  EXPECT_EQ(s.records, 5U);
  EXPECT_EQ(rig.mlog->rows(), 5U);
  bool invalid_alarm = false;
  core::AlarmEvent a;
  while (rig.loop->alarms().try_pop(a)) {
    invalid_alarm = invalid_alarm || a.code == core::AlarmCode::kEventInvalid;
  }
  EXPECT_TRUE(invalid_alarm);
}

TEST(Loop, ReloadSwapsAtACycleBoundaryAndCarriesTheState) {
  Rig rig;
  rig.loop->start();
  // The first configuration's ramp reaches its target, 100 µm (1 s at 100 µm/s).
  ASSERT_TRUE(rig.wait_for([&] { return rig.loop->registers().regs[0].output_um >= 100.0; }));
  // New configuration: same register, the ramp heads slowly (1 µm/s) for -50 µm instead. With
  // the state carried over it starts at 100 µm; a fresh engine would start its ramp at 0.
  const auto first = rig.loop->stats();
  EXPECT_EQ(first.config_since_cycle, 0U) << "the first configuration runs since the start";
  rig.swap.publish(make_runtime(-50.0, 1.0, false, 2));
  ASSERT_TRUE(rig.wait_for([&] { return rig.loop->stats().config_generation == 2; }));
  const auto swapped_in = rig.loop->stats();
  // The cycle of the swap: after the publish, and at most the cycles run when it was seen.
  EXPECT_GT(swapped_in.config_since_cycle, first.cycles);
  EXPECT_LE(swapped_in.config_since_cycle, swapped_in.cycles);
  std::this_thread::sleep_for(200ms);
  const double after = rig.loop->registers().regs[0].output_um;
  rig.loop->stop();
  EXPECT_EQ(rig.swap.reclaim(), 1U);
  const auto s = rig.loop->stats();
  EXPECT_EQ(s.reloads, 1U);
  // The new engine continued from the old one's value: 200 ms at 1 µm/s moves it by 0.2 µm
  // (a slow sanitizer run by a few µm at most), never back toward 0 (the limiter alone would
  // have brought a fresh ramp 100 µm down in 0.2 s at 500 µm/s).
  EXPECT_LE(after, 100.0);
  EXPECT_GT(after, 90.0) << "the ramp's state was not carried over the reload";
  const auto& e = *rig.swap.current().engine;
  EXPECT_TRUE(e.register_state(0).has_target);
  EXPECT_LE(e.register_state(0).output_um, after);
  const auto d = rig.bus.delivery(0);
  ASSERT_TRUE(d.has_value());
  EXPECT_LE(d->largest_step_um, 5.0) << "a write jumped past max_step_um at the swap";
  LoopNote n;
  bool swapped = false;
  bool carry_failed = false;
  while (rig.loop->notes().try_pop(n)) {
    swapped = swapped || (n.code == NoteCode::kConfigSwapped && n.a == 2);
    carry_failed = carry_failed || n.code == NoteCode::kStateCarryFailed;
  }
  EXPECT_TRUE(swapped);
  EXPECT_FALSE(carry_failed);
  EXPECT_EQ(s.allocations_after_warmup, 0);
  EXPECT_EQ(s.frees_after_warmup, 0) << "the retired configuration is freed off the loop thread";
}

TEST(Loop, DryRunWritesNothingToTheBus) {
  Rig rig(true);
  rig.loop->start();
  ASSERT_TRUE(rig.wait_for([&] { return rig.loop->stats().writes_dry_run >= 50; }));
  rig.loop->stop();
  std::this_thread::sleep_for(5ms);
  EXPECT_FALSE(rig.bus.delivered(0).has_value());
  EXPECT_EQ(rig.loop->stats().writes_sent, 0U);
}

// A dry run computes offsets the NC never receives. Leaving it by a reload (dry_run = false)
// must not treat them as sent: the NC still holds what it held before (here: nothing, 0), so
// the first real writes start from there through the limiter (max_step_um = 5), instead of
// jumping to the dry run's value in one step.
TEST(Loop, LeavingDryRunByReloadStartsFromWhatTheNcHoldsThroughTheLimiter) {
  Rig rig(true);
  rig.loop->start();
  ASSERT_TRUE(rig.wait_for([&] { return rig.loop->registers().regs[0].output_um > 20.0; }));
  EXPECT_FALSE(rig.bus.delivered(0).has_value());
  rig.swap.publish(make_runtime(100.0, 100.0, false, 2));
  ASSERT_TRUE(rig.wait_for([&] { return rig.loop->stats().config_generation == 2; }));
  ASSERT_TRUE(rig.wait_for([&] {
    const auto d = rig.bus.delivery(0);
    return d && d->writes >= 20;
  }));
  rig.loop->stop();
  const auto d = rig.bus.delivery(0);
  ASSERT_TRUE(d.has_value());
  EXPECT_LE(std::fabs(d->first_um), 5.0) << "first real write after the dry run";
  EXPECT_LE(d->largest_step_um, 5.0) << "a write jumped past max_step_um";
  bool left = false;
  LoopNote n;
  while (rig.loop->notes().try_pop(n)) {
    left = left || n.code == NoteCode::kDryRunLeft;
  }
  EXPECT_TRUE(left);
  EXPECT_EQ(rig.loop->stats().allocations_after_warmup, 0);
  EXPECT_EQ(rig.loop->stats().frees_after_warmup, 0);
}

// A dry run never persists: the state file keeps what the NC really got (here there is none).
TEST(Loop, DryRunPersistsNothing) {
  Rig rig(true);
  rig.loop->start();
  ASSERT_TRUE(rig.wait_for([&] { return rig.loop->stats().writes_dry_run >= 100; }));
  rig.loop->stop();
  EXPECT_EQ(rig.loop->stats().state_exports, 0U);
  rig.persister->stop();
  EXPECT_EQ(read_state_file((rig.dir / "state.bin").string()).status, StateFileStatus::kAbsent);
  std::vector<std::byte> buf(4096);
  EXPECT_EQ(rig.loop->final_state(buf), 0U) << "nothing real happened: nothing to write at exit";
}

// Entering dry run by a reload: the state as the NC has it at that moment is persisted, while the
// dry run's own values never reach the file (neither while it runs nor at exit).
TEST(Loop, EnteringDryRunPersistsTheRealStateOnly) {
  Rig rig;
  rig.loop->start();
  ASSERT_TRUE(rig.wait_for([&] { return rig.loop->registers().regs[0].output_um > 10.0; }));
  rig.swap.publish(make_runtime(100.0, 100.0, true, 2));
  ASSERT_TRUE(rig.wait_for([&] { return rig.loop->stats().config_generation == 2; }));
  const auto real = rig.bus.delivery(0);
  ASSERT_TRUE(rig.wait_for([&] { return rig.loop->stats().writes_dry_run >= 200; }));
  rig.loop->stop();
  ASSERT_TRUE(real.has_value());
  const double nc_um = rig.bus.delivery(0)->last_um;  // what the NC holds: the last real write
  EXPECT_GT(rig.swap.current().engine->register_state(0).output_um, nc_um + 5.0)
      << "the dry run moved on";
  rig.persister->stop();
  const auto f = read_state_file((rig.dir / "state.bin").string());
  ASSERT_EQ(f.status, StateFileStatus::kOk) << f.reason;
  auto fresh = make_runtime(100.0, 100.0, false, 1);
  ASSERT_TRUE(fresh->engine->import_state(f.payload, 0));
  EXPECT_DOUBLE_EQ(fresh->engine->register_state(0).output_um, nc_um);
  // The file holds it already: the exit has nothing to add (and never the dry run's values).
  std::vector<std::byte> buf(4096);
  EXPECT_EQ(rig.loop->final_state(buf), 0U);
}

// A module that takes 5.5 ms in one cycle (the 50th): with 1 ms cycles that cycle overruns.
class SlowOnceModule final : public core::engine::Module {
 public:
  std::string_view name() const noexcept override { return "slow"; }
  void attach(const core::engine::RegisterTable& /*registers*/) override {}
  void step(core::TimeNs /*now_ns*/, std::span<const core::Event> /*events*/,
            core::StepOutput& /*out*/) noexcept override {
    if (++steps_ == 50) {
      std::this_thread::sleep_for(5500us);
    }
  }

 private:
  std::uint64_t steps_{0};
};

// A slow cycle is an overrun: counted once, its skipped deadlines counted (skip_missed keeps the
// 1 ms grid: 5.5 ms late → at least 5 deadlines past), noted for the log, and the loop goes on
// at its rate afterwards (no catch-up burst: the cycles stay below elapsed time / period).
TEST(Loop, SlowCycleIsCountedAsAnOverrun) {
  auto rt = std::make_unique<Runtime>();
  rt->engine = std::make_unique<core::engine::Engine>();
  std::vector<std::unique_ptr<core::engine::Module>> m;
  m.push_back(std::make_unique<SlowOnceModule>());
  rt->engine->configure({{"T1", core::engine::RegisterKind::kToolLengthWear, {200.0, 5.0, 500.0}}},
                        std::move(m));
  rt->register_bus = {0};
  core::rt::ConfigSwap<Runtime> swap(std::move(rt));
  LoopbackBus bus(16, 16);
  bus.start();
  LoopOptions o;
  o.rate_hz = 1000.0;
  Loop loop(o, swap, {&bus}, nullptr, nullptr);
  const auto t0 = std::chrono::steady_clock::now();
  loop.start();
  const auto end = t0 + 5s;
  while (loop.stats().cycles < 200 && std::chrono::steady_clock::now() < end) {
    std::this_thread::sleep_for(2ms);
  }
  loop.stop();
  const double elapsed_ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  bus.stop();
  const LoopStats s = loop.stats();
  ASSERT_GE(s.cycles, 200U);
  EXPECT_GE(s.overruns, 1U);
  EXPECT_GE(s.missed_deadlines, 5U);
  EXPECT_GE(s.max_step_ns, 5'500'000);
  EXPECT_LT(static_cast<double>(s.cycles), elapsed_ms + 1.0) << "a catch-up burst";
  bool noted = false;
  LoopNote n;
  while (loop.notes().try_pop(n)) {
    if (n.code == NoteCode::kOverrun && n.a >= 5 && n.b >= 5500.0) {
      noted = true;
    }
  }
  EXPECT_TRUE(noted) << "the overrun note (missed deadlines, lateness in us) for the logger";
}

// The engine keeps its event cursors per bus (docs/daemon.md, "Events while nccompd was down"):
// the loop stamps every numbered event with the index of the bus it drained it from.
TEST(Loop, NumberedEventsCarryTheirBusIndexToTheEnginesCursors) {
  core::rt::ConfigSwap<Runtime> swap(make_runtime(100.0, 100.0, false, 1));
  LoopbackBus first(16, 16);
  LoopbackBus second(16, 16);
  first.start();
  second.start();
  core::ProgramEvent part_start;
  part_start.origin = core::EventOrigin{3, 0, true, false};
  core::ToolMeasurement m;
  m.tool = 7;
  m.wear_um[0] = 1.0;
  m.origin = core::EventOrigin{12, 0, true, false};  // the driver leaves the bus to the loop
  ASSERT_TRUE(first.inject(part_start));
  ASSERT_TRUE(second.inject(m));
  LoopOptions o;
  o.rate_hz = 1000.0;
  Loop loop(o, swap, {&first, &second}, nullptr, nullptr);
  loop.start();
  const auto end = std::chrono::steady_clock::now() + 5s;
  while (loop.stats().engine.events_accepted < 2 && std::chrono::steady_clock::now() < end) {
    std::this_thread::sleep_for(2ms);
  }
  loop.stop();
  first.stop();
  second.stop();
  const core::engine::EventCursors& c = swap.current().engine->event_cursors();
  EXPECT_TRUE(c.bus(0)[4].known);
  EXPECT_EQ(c.bus(0)[4].sequence, 3U);
  EXPECT_FALSE(c.bus(0)[0].known);
  EXPECT_TRUE(c.bus(1)[0].known);
  EXPECT_EQ(c.bus(1)[0].sequence, 12U);
  EXPECT_FALSE(c.bus(1)[4].known);
}

TEST(Loop, HoldWritesNothingAndPersistsNothing) {
  Rig rig;
  rig.loop->set_hold(true);
  rig.loop->start();
  ASSERT_TRUE(rig.wait_for([&] { return rig.loop->stats().cycles >= 100; }));
  rig.loop->stop();
  const auto s = rig.loop->stats();
  EXPECT_TRUE(s.hold);
  EXPECT_EQ(s.writes_sent, 0U);
  EXPECT_GT(s.engine.writes_held, 0U);
  EXPECT_EQ(s.state_exports, 0U);
  EXPECT_FALSE(rig.bus.delivered(0).has_value());
}

// A bus that stops draining its TX ring (link down, I/O thread stuck): writes are dropped and
// counted, and once the bus drains again the engine's latest value is re-sent, not lost.
TEST(Loop, DroppedWritesAreCountedAndResentWhenTheBusDrainsAgain) {
  LoopbackBus stuck(16, 2);  // not started yet: nobody empties its 2-slot TX ring
  core::rt::ConfigSwap<Runtime> swap(make_runtime(100.0, 100.0, false, 1));
  LoopOptions o;
  o.warmup_cycles = 20;
  o.thread_allocations = []() noexcept { return nccomp::test::thread_allocations(); };
  o.thread_deallocations = []() noexcept { return nccomp::test::thread_deallocations(); };
  Loop loop(o, swap, {&stuck}, nullptr, nullptr);
  loop.start();
  const auto end = std::chrono::steady_clock::now() + 5s;
  while (loop.stats().writes_dropped < 20 && std::chrono::steady_clock::now() < end) {
    std::this_thread::sleep_for(2ms);
  }
  EXPECT_GE(loop.stats().writes_dropped, 20U);
  bool noted = false;
  LoopNote n;
  while (loop.notes().try_pop(n)) {
    noted = noted || (n.code == NoteCode::kWriteDropped && n.a == 0);
  }
  EXPECT_TRUE(noted);
  stuck.start();  // the bus recovers
  // Let the ramp (100 µm at 100 µm/s) finish while the loop runs: its last value must reach the
  // NC although earlier writes were dropped. Stopping the loop while the ramp still moves would
  // race the last write against the TX ring (the loop may drop it in its final cycle).
  const auto end2 = std::chrono::steady_clock::now() + 5s;
  std::optional<double> d;
  while (std::chrono::steady_clock::now() < end2) {
    d = stuck.delivered(0);
    if (d && !(*d < 100.0) && !(*d > 100.0)) {
      break;
    }
    std::this_thread::sleep_for(2ms);
  }
  loop.stop();
  const double out = swap.current().engine->register_state(0).output_um;
  EXPECT_DOUBLE_EQ(out, 100.0);
  ASSERT_TRUE(d.has_value());
  EXPECT_DOUBLE_EQ(*d, out);
  EXPECT_EQ(loop.stats().allocations_after_warmup, 0);
  EXPECT_EQ(loop.stats().frees_after_warmup, 0);
  stuck.stop();
}

// A bus like the Modbus driver at a 20 Hz poll: every 50 ms its I/O thread takes what the loop
// queued, keeps the latest value of register 0 (older ones are replaced, never written), writes
// it to its "NC" and publishes the receipt.
class SlowCoalescingBus final : public drivers::Bus {
 public:
  SlowCoalescingBus() : rx_(16), tx_(256), receipts_(1) {}
  ~SlowCoalescingBus() override { stop(); }
  void start() override {
    thread_ = std::thread([this] {
      while (!stop_.load()) {
        std::this_thread::sleep_for(50ms);
        core::OffsetWrite w;
        std::optional<core::OffsetWrite> latest;
        while (tx_.try_pop(w)) {
          latest = w;
        }
        if (latest) {
          std::lock_guard<std::mutex> lock(mu_);
          nc_.push_back(latest->value_um);
          receipts_.publish(0, latest->sequence, core::WriteOutcome::kReached);
        }
      }
    });
  }
  void stop() override {
    stop_.store(true);
    if (thread_.joinable()) {
      thread_.join();
    }
  }
  core::rt::SpscRing<core::Event>& rx() override { return rx_; }
  core::rt::SpscRing<core::OffsetWrite>& tx() override { return tx_; }
  [[nodiscard]] drivers::BusStatus status() const override { return {}; }
  [[nodiscard]] bool confirms_writes() const noexcept override { return true; }
  [[nodiscard]] core::WriteReceipt write_receipt(std::uint16_t r) const noexcept override {
    return r == 0 ? receipts_.load(0) : drivers::kUnmappedReceipt;
  }
  std::vector<double> nc() {
    std::lock_guard<std::mutex> lock(mu_);
    return nc_;
  }

 private:
  core::rt::SpscRing<core::Event> rx_;
  core::rt::SpscRing<core::OffsetWrite> tx_;
  drivers::WriteReceipts receipts_;
  std::mutex mu_;
  std::vector<double> nc_;
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

// Issue 17 follow-up: the loop at 1 kHz, the limiter allowing 500 µm/s (0.5 µm per cycle, 25 µm
// per 50 ms) and 5 µm per write, a bus that writes every 50 ms. Every value the NC receives is
// within max_step_um of the one before (without receipts the bus merged 50 cycles into one
// step of 25 µm), and the register still reaches its target.
TEST(Loop, ASlowBusNeverStepsTheNcPastMaxStep) {
  SlowCoalescingBus bus;
  core::rt::ConfigSwap<Runtime> swap(make_runtime(60.0, 1000.0, false, 1));
  LoopOptions o;
  o.warmup_cycles = 20;
  o.thread_allocations = []() noexcept { return nccomp::test::thread_allocations(); };
  o.thread_deallocations = []() noexcept { return nccomp::test::thread_deallocations(); };
  Loop loop(o, swap, {&bus}, nullptr, nullptr);
  bus.start();
  loop.start();
  const auto end = std::chrono::steady_clock::now() + 10s;
  while (std::chrono::steady_clock::now() < end) {
    const auto nc = bus.nc();
    if (!nc.empty() && !(nc.back() < 60.0) && !(nc.back() > 60.0)) {
      break;
    }
    std::this_thread::sleep_for(5ms);
  }
  loop.stop();
  bus.stop();
  const auto nc = bus.nc();
  ASSERT_FALSE(nc.empty());
  EXPECT_DOUBLE_EQ(nc.back(), 60.0);
  double before = 0.0;
  for (std::size_t i = 0; i < nc.size(); ++i) {
    EXPECT_LE(std::fabs(nc[i] - before), 5.0 + 1e-9) << "write " << i << " stepped past 5 um";
    before = nc[i];
  }
  EXPECT_GE(nc.size(), 12U);  // 60 µm at 5 µm per write
  const auto s = loop.stats();
  EXPECT_GT(s.engine.writes_awaiting_nc, 0U);
  EXPECT_EQ(s.writes_dropped, 0U);
  EXPECT_EQ(s.allocations_after_warmup, 0) << "the loop thread allocated after warm-up";
  EXPECT_EQ(s.frees_after_warmup, 0) << "the loop thread freed after warm-up";
}

// A bus whose receipts the test gives: what the loop queues stays in flight until confirm().
class ManualBus final : public drivers::Bus {
 public:
  ManualBus() : rx_(16), tx_(256), receipts_(1) {}
  void start() override {}
  void stop() override {}
  core::rt::SpscRing<core::Event>& rx() override { return rx_; }
  core::rt::SpscRing<core::OffsetWrite>& tx() override { return tx_; }
  [[nodiscard]] drivers::BusStatus status() const override { return {}; }
  [[nodiscard]] bool confirms_writes() const noexcept override { return true; }
  [[nodiscard]] core::WriteReceipt write_receipt(std::uint16_t r) const noexcept override {
    return r == 0 ? receipts_.load(0) : drivers::kUnmappedReceipt;
  }
  /// The next write the loop queued (waits up to 5 s).
  std::optional<core::OffsetWrite> next_write() {
    const auto end = std::chrono::steady_clock::now() + 5s;
    core::OffsetWrite w;
    while (std::chrono::steady_clock::now() < end) {
      if (tx_.try_pop(w)) return w;
      std::this_thread::sleep_for(1ms);
    }
    return std::nullopt;
  }
  void confirm(std::uint64_t sequence) {
    receipts_.publish(0, sequence, core::WriteOutcome::kReached);
  }

 private:
  core::rt::SpscRing<core::Event> rx_;
  core::rt::SpscRing<core::OffsetWrite> tx_;
  drivers::WriteReceipts receipts_;
};

// GIVEN a ramp whose write is in flight (the bus has not confirmed it)
// WHEN a reload is published
// THEN the swap waits for the receipt (the new engine would otherwise send the same value again
//      and wait for that one's receipt: one more bus round trip in which the register does not
//      move, which in real time the register caught up with in one write), then the new engine
//      writes the next value at once; with a bus that never confirms, the swap comes after
//      swap_wait_max_cycles and the value in flight is sent again as it is; the loop publishes
//      how many cycles the configuration waited, and 0 once it is swapped in.
TEST(Loop, AReloadSwapsWhenTheBusHasConfirmedTheWritesInFlight) {
  for (const bool confirmed : {true, false}) {
    ManualBus bus;
    core::rt::ConfigSwap<Runtime> swap(make_runtime(100.0, 100.0, false, 1));
    LoopOptions o;
    o.swap_wait_max_cycles = confirmed ? 1'000'000 : 50;
    Loop loop(o, swap, {&bus}, nullptr, nullptr);
    loop.start();
    const auto first = bus.next_write();
    ASSERT_TRUE(first.has_value());
    swap.publish(make_runtime(100.0, 100.0, false, 2));
    if (confirmed) {
      std::this_thread::sleep_for(100ms);  // 100 cycles at 1 kHz
      EXPECT_EQ(loop.stats().config_generation, 1U) << "swapped with a write in flight";
      // What `nccomp model status` shows as the pending configuration's wait.
      EXPECT_GE(loop.stats().swap_waiting, 50U);
      bus.confirm(first->sequence);
    }
    const auto end = std::chrono::steady_clock::now() + 5s;
    while (loop.stats().config_generation != 2 && std::chrono::steady_clock::now() < end) {
      std::this_thread::sleep_for(1ms);
    }
    EXPECT_EQ(loop.stats().config_generation, 2U);
    EXPECT_EQ(loop.stats().swap_waiting, 0U);
    const auto after = bus.next_write();
    loop.stop();
    ASSERT_TRUE(after.has_value());
    EXPECT_GT(after->sequence, first->sequence);
    if (confirmed) {
      // The ramp moved on while the write was in flight: a new value, through the limiter.
      EXPECT_GT(after->value_um, first->value_um);
      EXPECT_LE(after->value_um - first->value_um, 5.0 + 1e-9);
    } else {
      EXPECT_DOUBLE_EQ(after->value_um, first->value_um);  // the NC holds it or the one before
    }
  }
}

}  // namespace
}  // namespace nccomp::daemon
