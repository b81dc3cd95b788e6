// Modbus driver benchmark over loopback TCP against the project's libmodbus NC server.
//
// 1. Cycle time: the driver's read-compute-write cycle (read the axis block, decode it into an
//    AxisSample for the loop, take the loop's offset, write it with function 16) against the bare
//    libmodbus round trip of the same registers (read the same block, write the same 2
//    registers), both paced at the same rate, alternating rounds, in the same run. Ratio of
//    percentiles = driver / bare.
// 2. Highest loop rate with zero overruns: a minimal fixed-rate loop thread (absolute deadlines)
//    drains rx(), computes an offset from the latest sample and queues it in tx(); the driver
//    polls at the same rate. A rate is sustained when, over the run, neither the loop nor the
//    driver overran and no event was dropped. (The share of loop cycles that found a new sample
//    is printed too; at equal rates it depends on the phase of the two clocks, so it is not a
//    criterion.)
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
  std::sort(v.begin(), v.end());
  const auto i = static_cast<std::size_t>(p * static_cast<double>(v.size() - 1));
  return static_cast<double>(v[i]) / 1000.0;
}

std::vector<TimeNs> bare_round(std::uint16_t port, int cycles, TimeNs period) {
  modbus_t* ctx = modbus_new_tcp("127.0.0.1", port);
  if (ctx == nullptr || modbus_connect(ctx) != 0) {
    std::fprintf(stderr, "bare: connect failed\n");
    std::exit(1);
  }
  std::vector<TimeNs> out;
  out.reserve(static_cast<std::size_t>(cycles));
  std::uint16_t regs[kReadRegisters];
  TimeNs next = mb::monotonic_now_ns();
  // The same 200 ms warm-up the driver rounds get (connection, caches), not measured.
  const int warmup = static_cast<int>(200'000'000 / period);
  for (int i = -warmup; i < cycles; ++i) {
    const TimeNs t0 = mb::monotonic_now_ns();
    if (modbus_read_input_registers(ctx, 0, kReadRegisters, regs) != kReadRegisters) {
      std::fprintf(stderr, "bare: read failed\n");
      std::exit(1);
    }
    // The same write the driver does: 2 registers of a changing value.
    const std::uint16_t w[2] = {0, static_cast<std::uint16_t>(i)};
    if (modbus_write_registers(ctx, 200, 2, w) != 2) {
      std::fprintf(stderr, "bare: write failed\n");
      std::exit(1);
    }
    if (i >= 0) {
      out.push_back(mb::monotonic_now_ns() - t0);
    }
    next += period;
    sleep_until(next);
  }
  modbus_close(ctx);
  modbus_free(ctx);
  return out;
}

/// The driver at `rate_hz` with a fixed-rate loop thread; returns the driver's cycle times.
struct DriverRun {
  std::vector<TimeNs> cycles;
  std::uint64_t loop_cycles{0};
  std::uint64_t loop_overruns{0};
  std::uint64_t fresh{0};
  mb::ModbusStatus status{};
};

DriverRun driver_round(std::uint16_t port, double rate_hz, TimeNs duration) {
  mb::ModbusBus bus(mb::parse_modbus_config(config_text(port, rate_hz), "bench"));
  nccomp::core::rt::SpscRing<TimeNs> log(1 << 20);
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
  TimeNs discard = 0;
  while (log.try_pop(discard)) {
  }
  const std::uint64_t overruns_before = bus.modbus_status().poll_overruns;
  const auto period = static_cast<TimeNs>(1e9 / rate_hz);
  TimeNs next = mb::monotonic_now_ns();
  const TimeNs end = next + duration;
  double counter = 0.0;
  while (next < end) {
    // The loop: drain events, compute from the newest sample, queue the absolute offset.
    bool got = false;
    double x_mm = 0.0;
    nccomp::core::Event e;
    while (bus.rx().try_pop(e)) {
      if (const auto* s = std::get_if<nccomp::core::AxisSample>(&e)) {
        x_mm = s->position_mm[0];
        got = true;
      }
    }
    r.fresh += got ? 1 : 0;
    counter += 1.0;
    (void)bus.tx().try_push(
        nccomp::core::OffsetWrite{next, 0, x_mm * 0.1 + std::fmod(counter, 100.0)});
    ++r.loop_cycles;
    next += period;
    if (mb::monotonic_now_ns() > next) {
      ++r.loop_overruns;
      next = mb::monotonic_now_ns();
    }
    sleep_until(next);
  }
  bus.stop();
  while (log.try_pop(discard)) {
    r.cycles.push_back(discard);
  }
  r.status = bus.modbus_status();
  r.status.poll_overruns -= overruns_before;
  return r;
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

  // 1. Cycle time at 1 kHz, alternating bare / driver rounds.
  const double rate = 1000.0;
  std::vector<TimeNs> bare;
  std::vector<TimeNs> drv;
  for (int round = 0; round < 4; ++round) {
    const auto b = bare_round(port, cycles, static_cast<TimeNs>(1e9 / rate));
    bare.insert(bare.end(), b.begin(), b.end());
    const auto d = driver_round(port, rate, static_cast<TimeNs>(cycles * 1e9 / rate));
    drv.insert(drv.end(), d.cycles.begin(), d.cycles.end());
  }
  std::printf("cycle time at %.0f Hz (read %d input registers + write 2 holding registers)\n", rate,
              kReadRegisters);
  std::printf("| path | cycles | p50 [us] | p99 [us] | p99.9 [us] |\n|---|---|---|---|---|\n");
  std::printf("| bare libmodbus | %zu | %.1f | %.1f | %.1f |\n", bare.size(), pct(bare, 0.5),
              pct(bare, 0.99), pct(bare, 0.999));
  std::printf("| driver cycle | %zu | %.1f | %.1f | %.1f |\n", drv.size(), pct(drv, 0.5),
              pct(drv, 0.99), pct(drv, 0.999));
  std::printf("| ratio driver / bare | | %.3f | %.3f | %.3f |\n\n", pct(drv, 0.5) / pct(bare, 0.5),
              pct(drv, 0.99) / pct(bare, 0.99), pct(drv, 0.999) / pct(bare, 0.999));

  // 2. Highest rate with zero overruns.
  std::printf(
      "| rate [Hz] | loop cycles | loop overruns | driver overruns | fresh samples | driver p99 "
      "[us] |\n");
  std::printf("|---|---|---|---|---|---|\n");
  double best = 0.0;
  for (double r : {500.0, 1000.0, 2000.0, 4000.0, 8000.0, 10000.0}) {
    const DriverRun d = driver_round(port, r, static_cast<TimeNs>(seconds * 1e9));
    const double fresh = static_cast<double>(d.fresh) / static_cast<double>(d.loop_cycles);
    const bool ok = d.loop_overruns == 0 && d.status.poll_overruns == 0 &&
                    d.status.bus.counters.events_dropped == 0 && d.loop_cycles > 0;
    std::printf("| %.0f | %llu | %llu | %llu | %.1f %% | %.1f |%s\n", r,
                static_cast<unsigned long long>(d.loop_cycles),
                static_cast<unsigned long long>(d.loop_overruns),
                static_cast<unsigned long long>(d.status.poll_overruns), fresh * 100.0,
                d.cycles.empty() ? 0.0 : pct(d.cycles, 0.99), ok ? "" : " (not sustained)");
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
