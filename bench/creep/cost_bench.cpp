// Cost of `core.step()` with the creep module (issue 3): the engine (core::engine::Engine::step,
// what the loop thread calls every cycle: event validation, the module, per-register limiters,
// write batching) with the creep module attached, 3 axes, 16 edge support points, 4 creeps in
// progress, a surface normal with every sample, prediction, deflection and adaptive interval on
// (bench/creep/engine_cycle.hpp; the unit test CreepRealTime.EngineStepWithTheCreepModule-
// AllocatesNothing runs the same cycle). Its peer in the same run: the creep module alone
// (CreepModule::step on the same stream). Each call is timed on its own (steady_clock); the
// timer's own cost is measured the same way and reported, not subtracted. The same engine cycle
// with [creep.estimator] on (a Kalman filter per support point, updated at each measurement) is
// timed in the same run (issue 22).
//
//   bench_creep_cost [CYCLES]
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <string>
#include <vector>

#include "bench/creep/engine_cycle.hpp"

namespace {

using Clock = std::chrono::steady_clock;
using nccomp::bench::creep::EngineCycle;

struct Stats {
  double median_ns, p99_ns, p999_ns, max_ns;
};

Stats stats(std::vector<double>& v) {
  std::sort(v.begin(), v.end());
  auto at = [&](double q) {
    return v[static_cast<std::size_t>(q * static_cast<double>(v.size() - 1))];
  };
  return {at(0.5), at(0.99), at(0.999), v.back()};
}

double elapsed_ns(Clock::time_point t0, Clock::time_point t1) {
  return std::chrono::duration<double, std::nano>(t1 - t0).count();
}

/// Times `cycles` plain cycles, then 2000 cycles that carry a measurement (5 plain cycles
/// between them). Fails loudly if the setup is not what the table says.
void run(EngineCycle& rig, std::size_t cycles, std::vector<double>& t_step,
         std::vector<double>& t_meas) {
  for (std::size_t i = 0; i < 10000; ++i) rig.cycle();  // warm-up
  t_step.resize(cycles);
  for (std::size_t i = 0; i < cycles; ++i) {
    const auto t0 = Clock::now();
    rig.cycle();
    const auto t1 = Clock::now();
    t_step[i] = elapsed_ns(t0, t1);
  }
  const auto accepted = rig.module().compensator().counters().measurements_accepted;
  const auto folded = rig.module().compensator().counters().creeps_folded;
  t_meas.resize(2000);
  for (std::size_t i = 0; i < t_meas.size(); ++i) {
    for (int k = 0; k < 5; ++k) rig.cycle();
    const double base = rig.next_wear_base_um();
    const auto t0 = Clock::now();
    rig.measure(base);
    const auto t1 = Clock::now();
    t_meas[i] = elapsed_ns(t0, t1);
  }
  const auto& k = rig.module().compensator().counters();
  if (rig.creeps_in_progress() != 4 || rig.module().compensator().halted() ||
      k.measurements_accepted - accepted != t_meas.size() ||
      k.creeps_folded - folded != t_meas.size()) {
    std::fprintf(stderr,
                 "run: %zu creeps in progress, halted %d, %llu of %zu measurements accepted, "
                 "%llu folded\n",
                 rig.creeps_in_progress(), rig.module().compensator().halted() ? 1 : 0,
                 static_cast<unsigned long long>(k.measurements_accepted - accepted), t_meas.size(),
                 static_cast<unsigned long long>(k.creeps_folded - folded));
    std::exit(1);
  }
}

}  // namespace

int main(int argc, char** argv) {
  const std::size_t cycles = argc > 1 ? std::stoul(argv[1]) : 200000;
  auto engine = std::make_unique<EngineCycle>(true);
  auto alone = std::make_unique<EngineCycle>(false);
  auto with_estimator = std::make_unique<EngineCycle>(true, true);
  std::vector<double> e_step, e_meas, m_step, m_meas, k_step, k_meas;
  run(*engine, cycles, e_step, e_meas);
  run(*alone, cycles, m_step, m_meas);
  run(*with_estimator, cycles, k_step, k_meas);
  std::vector<double> t_timer(cycles);
  for (std::size_t i = 0; i < cycles; ++i) {
    const auto t0 = Clock::now();
    const auto t1 = Clock::now();
    t_timer[i] = elapsed_ns(t0, t1);
  }
  const Stats es = stats(e_step);
  const Stats em = stats(e_meas);
  const Stats ms = stats(m_step);
  const Stats mm = stats(m_meas);
  const Stats t = stats(t_timer);
  const Stats ks = stats(k_step);
  const Stats km = stats(k_meas);
  std::printf("| cycle | n | median [ns] | p99 [ns] | p99.9 [ns] | max [ns] |\n");
  std::printf("| --- | --- | --- | --- | --- | --- |\n");
  const auto row = [](const char* what, std::size_t n, const Stats& s) {
    std::printf("| %s | %zu | %.0f | %.0f | %.0f | %.0f |\n", what, n, s.median_ns, s.p99_ns,
                s.p999_ns, s.max_ns);
  };
  row("Engine::step() with the creep module: 1 axis sample, 3 axes, 16 points, 4 creeps", cycles,
      es);
  row("  the same + 16-point measurement (fold, 16 records)", e_meas.size(), em);
  row("peer: CreepModule::step() alone, same stream", cycles, ms);
  row("  the same + 16-point measurement", m_meas.size(), mm);
  row("Engine::step() with the creep module and [creep.estimator], same stream", cycles, ks);
  row("  the same + 16-point measurement (16 filter updates)", k_meas.size(), km);
  row("timer alone (steady_clock pair)", cycles, t);
  std::printf("\nengine / module alone, median: %.2f; p99.9: %.2f\n", es.median_ns / ms.median_ns,
              es.p999_ns / ms.p999_ns);
  return 0;
}
