// Runs nccompd's Loop (the daemon's own loop code, in process) with the loopback bus and a
// ramping register for --seconds at --rate-hz, optionally SCHED_FIFO --priority and mlockall,
// then prints the wake-up latency quantiles (from the loop's own histogram), overruns, and the
// page faults and allocations of the loop thread after warm-up.
//
//   bench_daemon_loop --seconds 60 --rate-hz 1000 --priority 80 --lock-memory
#include <sys/mman.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <thread>

#include "core/engine/ramp_module.hpp"
#include "daemon/loop.hpp"
#include "drivers/loopback/loopback_bus.hpp"
#ifdef NCCOMP_COUNT_ALLOCATIONS
#include "tests/support/alloc_counter.hpp"
#endif

using namespace nccomp;

int main(int argc, char** argv) {
  double seconds = 10.0;
  double rate_hz = 1000.0;
  int priority = 0;
  bool lock_memory = false;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--seconds" && i + 1 < argc) {
      seconds = std::atof(argv[++i]);
    } else if (a == "--rate-hz" && i + 1 < argc) {
      rate_hz = std::atof(argv[++i]);
    } else if (a == "--priority" && i + 1 < argc) {
      priority = std::atoi(argv[++i]);
    } else if (a == "--lock-memory") {
      lock_memory = true;
    } else {
      std::fprintf(stderr, "usage: %s [--seconds S] [--rate-hz R] [--priority P] [--lock-memory]\n",
                   argv[0]);
      return 2;
    }
  }
  if (lock_memory && mlockall(MCL_CURRENT | MCL_FUTURE) != 0) {
    std::fprintf(stderr, "mlockall failed: %s\n", std::strerror(errno));
  }
  auto rt = std::make_unique<daemon::Runtime>();
  rt->engine = std::make_unique<core::engine::Engine>();
  std::vector<std::unique_ptr<core::engine::Module>> modules;
  // A ramp that never finishes within the run: a write every cycle, like a creep in progress.
  modules.push_back(std::make_unique<core::engine::RampModule>(
      core::engine::RampConfig{"ramp", "T1", 0.0, 1e5, 10.0}));
  rt->engine->configure({{"T1", core::engine::RegisterKind::kToolLengthWear, {2e5, 5.0, 50.0}}},
                        std::move(modules));
  rt->register_bus = {0};
  core::rt::ConfigSwap<daemon::Runtime> swap(std::move(rt));
  drivers::loopback::LoopbackBus bus(1024, 1024);
  bus.start();
  daemon::LoopOptions o;
  o.rate_hz = rate_hz;
  o.sched_fifo_priority = priority;
  o.prefault_stack_kib = 256;
  o.warmup_cycles = 1000;
#ifdef NCCOMP_COUNT_ALLOCATIONS
  o.thread_allocations = []() noexcept { return nccomp::test::thread_allocations(); };
  o.thread_deallocations = []() noexcept { return nccomp::test::thread_deallocations(); };
#endif
  daemon::Loop loop(o, swap, {&bus}, nullptr, nullptr);
  const auto rep = loop.start();
  if (rep.sched_requested && rep.sched_errno != 0) {
    std::fprintf(stderr, "SCHED_FIFO %d refused: %s\n", priority, std::strerror(rep.sched_errno));
  }
  // Drain the alarm/note rings like the logger thread would.
  const auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
  while (std::chrono::steady_clock::now() < end) {
    core::AlarmEvent a;
    while (loop.alarms().try_pop(a)) {
    }
    daemon::LoopNote n;
    while (loop.notes().try_pop(n)) {
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  loop.stop();
  bus.stop();
  const auto s = loop.stats();
  const auto& h = loop.latency();
  std::printf("nccompd_loop samples=%llu rate_hz=%.0f priority=%d sched_ok=%d mlockall=%d\n",
              static_cast<unsigned long long>(h.count()), rate_hz, priority,
              rep.sched_requested && rep.sched_errno == 0 ? 1 : 0, lock_memory ? 1 : 0);
  std::printf("nccompd_loop latency_us p50=%.0f p99=%.0f p99.9=%.0f max=%.0f\n", h.quantile_us(0.5),
              h.quantile_us(0.99), h.quantile_us(0.999), static_cast<double>(h.max_ns()) / 1000.0);
  std::printf("nccompd_loop cycles=%llu overruns=%llu missed=%llu max_cycle_us=%.1f\n",
              static_cast<unsigned long long>(s.cycles),
              static_cast<unsigned long long>(s.overruns),
              static_cast<unsigned long long>(s.missed_deadlines),
              static_cast<double>(s.max_step_ns) / 1000.0);
  std::printf(
      "nccompd_loop after_warmup minor_faults=%lld major_faults=%lld allocations=%lld "
      "frees=%lld\n",
      static_cast<long long>(s.minor_faults_after_warmup),
      static_cast<long long>(s.major_faults_after_warmup),
      static_cast<long long>(s.allocations_after_warmup),
      static_cast<long long>(s.frees_after_warmup));
  return 0;
}
