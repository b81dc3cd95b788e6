// Modbus driver benchmark over loopback TCP against the project's libmodbus NC server.
//
// 1. Cycle time: the driver's read-compute-write cycle (read the axis block, decode it into an
//    AxisSample for the loop, take the loop's offset, write it with function 16) against the bare
//    libmodbus round trip of the same registers (read the same block, write the same 2
//    registers), both paced at 1 kHz, alternating rounds, in the same run. In both paths a
//    "loop" thread queues a new absolute offset every 500 us (2 kHz, twice the bus rate), so
//    that every driver cycle finds a changed value and writes; the driver logs the requests of
//    every cycle (CycleRecord), and the table counts the cycles by (reads, writes). The ratio of
//    percentiles driver / bare is taken over the driver cycles that did exactly one read and
//    one write, the bare path's work; the share of such cycles is printed with it.
// 2. Highest loop rate with zero overruns: a minimal fixed-rate loop thread (absolute deadlines)
//    drains rx(), computes an offset from the latest sample and queues it in tx(); the driver
//    polls at the same rate. A rate is sustained when, over the run, neither the loop nor the
//    driver overran and no event was dropped. (The share of loop cycles that found a new sample
//    is printed too; at equal rates it depends on the phase of the two clocks, so it is not a
//    criterion.) nccompd's own loop is measured by bench_modbus_nccompd.
// 3. RTU: bus time per poll of the reference profile at common baud rates (from the frame
//    timing model in config.cpp) and the poll rate it allows.
//
// Usage: bench_modbus [cycles_per_round] [seconds_per_rate] [--fifo]   (4 rounds of each path)
// --fifo: SCHED_FIFO priority 50 for every thread of the bench (the NC server, the driver's I/O
// thread and the loop inherit it), as the daemon's loop may run; reported on stdout.
#include <modbus/modbus.h>
#include <sched.h>
#include <time.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <functional>
#include <string>
#include <thread>
#include <variant>
#include <vector>

#include "drivers/modbus/modbus_bus.hpp"
#include "sim/modbus_nc/nc_server.hpp"

namespace mb = nccomp::drivers::modbus;
using nccomp::core::TimeNs;

namespace {

constexpr int kReadRegisters = 12;  // the reference profile's axis block (input 0..11)

std::string config_text(std::uint16_t port, double rate_hz) {
  return "[modbus]\ntransport = \"tcp\"\nport = " + std::to_string(port) +
         "\npoll_rate_hz = " + std::to_string(rate_hz) +
         R"(
[modbus.axis]
x_mm = { table = "input", address = 0, type = "int32", scale = 0.0001 }
y_mm = { table = "input", address = 2, type = "int32", scale = 0.0001 }
z_mm = { table = "input", address = 4, type = "int32", scale = 0.0001 }
program_path_mm = { table = "input", address = 6, type = "int32", scale = 0.001 }
tool = { table = "input", address = 8, type = "uint16" }
normal_x = { table = "input", address = 9, type = "int16", scale = 0.0001 }
normal_y = { table = "input", address = 10, type = "int16", scale = 0.0001 }
normal_z = { table = "input", address = 11, type = "int16", scale = 0.0001 }
[[modbus.offset]]
register_index = 0
address = 200
type = "int32"
scale = 0.1
)";
}

void sleep_until(TimeNs t) {
  timespec ts{};
  ts.tv_sec = t / 1'000'000'000;
  ts.tv_nsec = t % 1'000'000'000;
  clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr);
}

double pct(std::vector<TimeNs> v, double p) {
  if (v.empty()) {
    return 0.0;
  }
  std::sort(v.begin(), v.end());
  const auto i = static_cast<std::size_t>(p * static_cast<double>(v.size() - 1));
  return static_cast<double>(v[i]) / 1000.0;
}

/// The daemon's loop, reduced to what touches the bus: a thread at a fixed rate (absolute
/// deadlines, no catch-up bursts) that calls `cycle` once per period; counts overruns.
class LoopThread {
 public:
  LoopThread(double rate_hz, std::function<void(TimeNs)> cycle)
      : period_(static_cast<TimeNs>(1e9 / rate_hz)), cycle_(std::move(cycle)) {
    thread_ = std::thread([this] { run(); });
  }
  ~LoopThread() { stop(); }
  LoopThread(const LoopThread&) = delete;
  LoopThread& operator=(const LoopThread&) = delete;
  void stop() {
    running_.store(false);
    if (thread_.joinable()) {
      thread_.join();
    }
  }
  [[nodiscard]] std::uint64_t cycles() const { return cycles_.load(); }
  [[nodiscard]] std::uint64_t overruns() const { return overruns_.load(); }

 private:
  void run() {
    TimeNs next = mb::monotonic_now_ns();
    while (running_.load()) {
      cycle_(next);
      cycles_.fetch_add(1);
      next += period_;
      const TimeNs now = mb::monotonic_now_ns();
      if (now > next) {
        overruns_.fetch_add(1);
        next = now;
      }
      sleep_until(next);
    }
  }
  const TimeNs period_;
  std::function<void(TimeNs)> cycle_;
  std::atomic<bool> running_{true};
  std::atomic<std::uint64_t> cycles_{0};
  std::atomic<std::uint64_t> overruns_{0};
  std::thread thread_;
};

/// The loop's offset: from the newest X and a counter, so that consecutive values differ.
double loop_offset_um(double x_mm, std::uint64_t k) {
  return x_mm * 0.1 + static_cast<double>(k % 1000U) * 0.1;
}

/// The bare libmodbus path: per period one read of the axis block and one function-16 write of
/// the newest offset the loop thread (at loop_hz) queued, as the driver does; the drain of the
/// queue is timed too.
std::vector<TimeNs> bare_round(std::uint16_t port, int cycles, TimeNs period, double loop_hz) {
  modbus_t* ctx = modbus_new_tcp("127.0.0.1", port);
  if (ctx == nullptr || modbus_connect(ctx) != 0) {
    std::fprintf(stderr, "bare: connect failed\n");
    std::exit(1);
  }
  nccomp::core::rt::SpscRing<nccomp::core::OffsetWrite> queue(256);
  std::uint64_t k = 0;
  LoopThread loop(loop_hz, [&](TimeNs now) {
    (void)queue.try_push(nccomp::core::OffsetWrite{now, 0, loop_offset_um(123.0, ++k)});
  });
  std::vector<TimeNs> out;
  out.reserve(static_cast<std::size_t>(cycles));
  std::uint16_t regs[kReadRegisters];
  double value_um = 0.0;
  TimeNs next = mb::monotonic_now_ns();
  // The same 200 ms warm-up the driver rounds get (connection, caches), not measured.
  const int warmup = static_cast<int>(200'000'000 / period);
  for (int i = -warmup; i < cycles; ++i) {
    const TimeNs t0 = mb::monotonic_now_ns();
    if (modbus_read_input_registers(ctx, 0, kReadRegisters, regs) != kReadRegisters) {
      std::fprintf(stderr, "bare: read failed\n");
      std::exit(1);
    }
    nccomp::core::OffsetWrite w;
    while (queue.try_pop(w)) {
      value_um = w.value_um;
    }
    // The same write the driver does: 2 registers, int32 at 0.1 um.
    const auto counts = static_cast<std::uint32_t>(static_cast<std::int32_t>(value_um * 10.0));
    const std::uint16_t reg[2] = {static_cast<std::uint16_t>(counts >> 16U),
                                  static_cast<std::uint16_t>(counts & 0xFFFFU)};
    if (modbus_write_registers(ctx, 200, 2, reg) != 2) {
      std::fprintf(stderr, "bare: write failed\n");
      std::exit(1);
    }
    if (i >= 0) {
      out.push_back(mb::monotonic_now_ns() - t0);
    }
    next += period;
    sleep_until(next);
  }
  loop.stop();
  modbus_close(ctx);
  modbus_free(ctx);
  return out;
}

/// The driver polling at poll_hz, fed by a loop thread at loop_hz.
struct DriverRun {
  std::vector<mb::CycleRecord> cycles;
  std::uint64_t loop_cycles{0};
  std::uint64_t loop_overruns{0};
  std::uint64_t fresh{0};
  mb::ModbusStatus status{};
};

DriverRun driver_round(std::uint16_t port, double poll_hz, double loop_hz, TimeNs duration) {
  mb::ModbusBus bus(mb::parse_modbus_config(config_text(port, poll_hz), "bench"));
  nccomp::core::rt::SpscRing<mb::CycleRecord> log(1 << 20);
  bus.attach_cycle_log(&log);
  bus.start();
  DriverRun r;
  // Let it connect and warm up.
  const TimeNs warm_end = mb::monotonic_now_ns() + 200'000'000;
  while (mb::monotonic_now_ns() < warm_end) {
    nccomp::core::Event e;
    while (bus.rx().try_pop(e)) {
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
  mb::CycleRecord rec;
  while (log.try_pop(rec)) {
  }
  const std::uint64_t overruns_before = bus.modbus_status().poll_overruns;
  std::uint64_t k = 0;
  std::uint64_t fresh = 0;
  double x_mm = 0.0;
  {
    // The loop: drain events, compute from the newest sample, queue the absolute offset.
    LoopThread loop(loop_hz, [&](TimeNs now) {
      bool got = false;
      nccomp::core::Event e;
      while (bus.rx().try_pop(e)) {
        if (const auto* s = std::get_if<nccomp::core::AxisSample>(&e)) {
          x_mm = s->position_mm[0];
          got = true;
        }
      }
      fresh += got ? 1U : 0U;
      (void)bus.tx().try_push(nccomp::core::OffsetWrite{now, 0, loop_offset_um(x_mm, ++k)});
    });
    std::this_thread::sleep_for(std::chrono::nanoseconds(duration));
    loop.stop();
    r.loop_cycles = loop.cycles();
    r.loop_overruns = loop.overruns();
  }
  r.fresh = fresh;
  bus.stop();
  while (log.try_pop(rec)) {
    r.cycles.push_back(rec);
  }
  r.status = bus.modbus_status();
  r.status.poll_overruns -= overruns_before;
  return r;
}

std::vector<TimeNs> durations(const std::vector<mb::CycleRecord>& c, int reads, int writes) {
  std::vector<TimeNs> out;
  for (const auto& r : c) {
    if ((reads < 0 || r.reads == reads) && (writes < 0 || r.writes == writes)) {
      out.push_back(r.duration_ns);
    }
  }
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  std::setvbuf(stdout, nullptr, _IOLBF, 0);
  if (argc > 3 && std::string(argv[3]) == "--fifo") {
    sched_param p{};
    p.sched_priority = 50;
    if (sched_setscheduler(0, SCHED_FIFO, &p) != 0) {
      std::perror("sched_setscheduler(SCHED_FIFO)");
      return 1;
    }
    std::printf("scheduling: SCHED_FIFO priority 50 (inherited by all threads)\n");
  } else {
    std::printf("scheduling: SCHED_OTHER\n");
  }
  const int cycles = argc > 1 ? std::atoi(argv[1]) : 5000;
  const double seconds = argc > 2 ? std::atof(argv[2]) : 2.0;
  nccomp::sim::modbus_nc::NcServer server(nccomp::sim::modbus_nc::ServerConfig{});
  server.update([](nccomp::sim::modbus_nc::Tables& t) {
    for (int i = 0; i < kReadRegisters; ++i) {
      t.input[static_cast<std::size_t>(i)] = static_cast<std::uint16_t>(100 + i);
    }
    // A unit surface normal (0, 0, 1): anything else is refused by the decoder.
    t.input[9] = 0;
    t.input[10] = 0;
    t.input[11] = 10000;
  });
  server.start();
  const std::uint16_t port = server.port();

  // 1. Cycle time at 1 kHz, alternating bare / driver rounds; the loop queues at 2 kHz.
  const double rate = 1000.0;
  const double loop_rate = 2000.0;
  std::vector<TimeNs> bare;
  std::vector<mb::CycleRecord> drv;
  for (int round = 0; round < 4; ++round) {
    const auto b = bare_round(port, cycles, static_cast<TimeNs>(1e9 / rate), loop_rate);
    bare.insert(bare.end(), b.begin(), b.end());
    const auto d = driver_round(port, rate, loop_rate, static_cast<TimeNs>(cycles * 1e9 / rate));
    drv.insert(drv.end(), d.cycles.begin(), d.cycles.end());
  }
  const std::vector<TimeNs> rw = durations(drv, 1, 1);
  const std::vector<TimeNs> all = durations(drv, -1, -1);
  std::size_t read_only = 0;
  std::size_t other = 0;
  std::uint64_t writes = 0;
  for (const auto& c : drv) {
    writes += c.writes;
    read_only += c.reads == 1 && c.writes == 0 ? 1U : 0U;
    other += (c.reads == 1 && c.writes <= 1) ? 0U : 1U;
  }
  std::printf(
      "cycle time at %.0f Hz (read %d input registers + write 2 holding registers), the "
      "loop queueing a new offset at %.0f Hz\n",
      rate, kReadRegisters, loop_rate);
  std::printf(
      "driver cycles: %zu; 1 read + 1 write: %zu (%.2f %%); 1 read + 0 writes: %zu; "
      "other: %zu; writes per cycle: %.4f\n",
      drv.size(), rw.size(),
      100.0 * static_cast<double>(rw.size()) /
          static_cast<double>(std::max<std::size_t>(drv.size(), 1)),
      read_only, other,
      static_cast<double>(writes) / static_cast<double>(std::max<std::size_t>(drv.size(), 1)));
  std::printf("| path | cycles | p50 [us] | p99 [us] | p99.9 [us] |\n|---|---|---|---|---|\n");
  std::printf("| bare libmodbus, 1 read + 1 write | %zu | %.1f | %.1f | %.1f |\n", bare.size(),
              pct(bare, 0.5), pct(bare, 0.99), pct(bare, 0.999));
  std::printf("| driver cycle, 1 read + 1 write | %zu | %.1f | %.1f | %.1f |\n", rw.size(),
              pct(rw, 0.5), pct(rw, 0.99), pct(rw, 0.999));
  std::printf("| **ratio driver / bare** | | **%.3f** | **%.3f** | **%.3f** |\n",
              pct(rw, 0.5) / pct(bare, 0.5), pct(rw, 0.99) / pct(bare, 0.99),
              pct(rw, 0.999) / pct(bare, 0.999));
  std::printf("| driver cycle, all | %zu | %.1f | %.1f | %.1f |\n\n", all.size(), pct(all, 0.5),
              pct(all, 0.99), pct(all, 0.999));

  // 2. Highest rate with zero overruns (loop and driver at the same rate).
  std::printf(
      "| rate [Hz] | loop cycles | loop overruns | driver overruns | writes per driver cycle | "
      "fresh samples | driver p99 [us] |\n");
  std::printf("|---|---|---|---|---|---|---|\n");
  double best = 0.0;
  for (double r : {500.0, 1000.0, 2000.0, 4000.0, 8000.0, 10000.0}) {
    const DriverRun d = driver_round(port, r, r, static_cast<TimeNs>(seconds * 1e9));
    const double fresh = static_cast<double>(d.fresh) / static_cast<double>(d.loop_cycles);
    std::uint64_t w = 0;
    for (const auto& c : d.cycles) {
      w += c.writes;
    }
    const bool ok = d.loop_overruns == 0 && d.status.poll_overruns == 0 &&
                    d.status.bus.counters.events_dropped == 0 && d.loop_cycles > 0;
    std::printf(
        "| %.0f | %llu | %llu | %llu | %.3f | %.1f %% | %.1f |%s\n", r,
        static_cast<unsigned long long>(d.loop_cycles),
        static_cast<unsigned long long>(d.loop_overruns),
        static_cast<unsigned long long>(d.status.poll_overruns),
        static_cast<double>(w) / static_cast<double>(std::max<std::size_t>(d.cycles.size(), 1)),
        fresh * 100.0, pct(durations(d.cycles, -1, -1), 0.99), ok ? "" : " (not sustained)");
    if (ok) {
      best = r;
    }
  }
  std::printf("\nhighest rate sustained with zero overruns: %.0f Hz\n\n", best);
  server.stop();

  // 3. RTU budget of the reference profile.
  std::printf(
      "| RTU baud | merge_gap_registers | frame gap [ms] | reference profile: bus time per poll "
      "[ms] | max poll rate [Hz] |\n|---|---|---|---|---|\n");
  for (int merge : {0, 16}) {
    for (int baud : {9600, 19200, 38400, 115200}) {
      std::string text =
          "[modbus]\ntransport = \"rtu\"\ndevice = \"/dev/null\"\nbaud = " + std::to_string(baud) +
          "\npoll_rate_hz = 0.01\nmerge_gap_registers = " + std::to_string(merge) + "\n";
      // The reference map below [modbus]'s own keys.
      FILE* f = std::fopen(NCCOMP_REFERENCE_PROFILE, "r");
      std::string ref;
      char buf[4096];
      std::size_t n = 0;
      while ((n = std::fread(buf, 1, sizeof(buf), f)) > 0) {
        ref.append(buf, n);
      }
      std::fclose(f);
      text += ref.substr(ref.find("[modbus.axis]"));
      const mb::ModbusConfig c = mb::parse_modbus_config(text, "reference");
      std::printf("| %d | %d | %.3f | %.2f (%zu requests) | %.1f |\n", baud, merge,
                  mb::rtu_frame_gap_s(c) * 1e3, c.poll_bus_time_s * 1e3, c.blocks.size(),
                  0.9 / c.poll_bus_time_s);
    }
  }
  return 0;
}
