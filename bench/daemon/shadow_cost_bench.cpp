// The loop's cost with a candidate model in shadow (issue 19): nccompd's loop thread steps the
// engine and queues the cycle's measurement records on an SPSC ring; the measurement log's
// writer thread drains the ring every 20 ms and scores each record by the live model and, with a
// candidate in shadow, by the candidate too (daemon/sections/model/shadow: Shadow::observe). The
// candidate never runs on the loop thread, so what it can cost the loop is the writer thread's
// extra work beside it (caches, memory bandwidth, the other vCPU).
//
// Each run: the engine cycle of bench_creep_cost (bench/creep/engine_cycle.hpp: the creep module,
// 3 axes, 16 support points, 4 creeps in progress, prediction and deflection on), a 16-point
// laser measurement every 50 cycles (16 records), each cycle timed on its own (steady_clock) on
// the loop side: Engine::step plus queuing its records. The cycles run back to back, not paced at
// the loop's rate, so the writer scores far more records per second beside the loop than in the
// daemon: a worst case. A = the live model scored alone, B = the live model and a candidate; A and
// B alternate in pairs, so both see the same machine.
//
//   bench_shadow_cost [PAIRS] [CYCLES]
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <thread>
#include <vector>

#include "bench/creep/engine_cycle.hpp"
#include "core/common/output.hpp"
#include "core/model/model.hpp"
#include "core/rt/spsc_ring.hpp"
#include "daemon/sections/model/shadow.hpp"

namespace {

using Clock = std::chrono::steady_clock;
using nccomp::bench::creep::EngineCycle;
namespace cm = nccomp::core::model;
namespace ds = nccomp::daemon::sections;

struct Quantiles {
  double p50_ns, p99_ns, p999_ns, max_ns;
};

Quantiles quantiles(std::vector<double>& v) {
  std::sort(v.begin(), v.end());
  auto at = [&](double q) {
    return v[static_cast<std::size_t>(q * static_cast<double>(v.size() - 1))];
  };
  return {at(0.5), at(0.99), at(0.999), v.back()};
}

cm::Model wear_model(double um_per_mm) {
  cm::Term wear;
  wear.spec.name = "tool_wear";
  wear.spec.form = cm::Form::kLinear;
  wear.spec.column = static_cast<int>(cm::Column::kPath);
  wear.groups = {{0.0, 0.0}};
  wear.coef = {um_per_mm};
  return cm::Model({}, {wear});
}

struct RunResult {
  Quantiles plain;    // cycles with an axis sample only
  Quantiles measure;  // cycles that carry a laser measurement (16 records)
  std::uint64_t rows_scored;
  bool candidate_scored;
};

RunResult run(bool with_candidate, std::size_t cycles) {
  ds::Shadow shadow;
  shadow.configure(ds::ShadowOptions{}, {});
  shadow.set_live("live.toml", "1", wear_model(0.008));
  if (with_candidate) shadow.set_candidate("candidate.toml", "2", wear_model(0.0085));

  EngineCycle rig;
  // Room for every record of the run: the loop runs back to back, not paced at the loop's rate.
  nccomp::core::rt::SpscRing<nccomp::core::MeasurementRecord> ring(std::size_t{1} << 17);
  std::atomic<bool> stop{false};
  std::thread writer([&] {
    nccomp::core::MeasurementRecord r;
    while (!stop.load(std::memory_order_acquire)) {
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
      while (ring.try_pop(r)) shadow.observe(r);
    }
    while (ring.try_pop(r)) shadow.observe(r);
  });

  std::vector<double> t_plain;
  std::vector<double> t_measure;
  t_plain.reserve(cycles);
  t_measure.reserve(cycles / 50 + 1);
  std::uint64_t dropped = 0;
  for (std::size_t i = 0; i < 10000; ++i) rig.cycle();  // warm-up
  for (std::size_t i = 0; i < cycles; ++i) {
    const bool measure = i % 50 == 49;
    const double base = measure ? rig.next_wear_base_um() : 0.0;
    const auto t0 = Clock::now();
    if (measure) {
      rig.measure(base);
    } else {
      rig.cycle();
    }
    for (const auto& rec : rig.out().records) {
      if (!ring.try_push(rec)) ++dropped;
    }
    const auto t1 = Clock::now();
    (measure ? t_measure : t_plain)
        .push_back(std::chrono::duration<double, std::nano>(t1 - t0).count());
  }
  stop.store(true, std::memory_order_release);
  writer.join();
  const ds::ShadowStatus s = shadow.status();
  if (dropped != 0 || s.rows_scored == 0 || rig.creeps_in_progress() != 4) {
    std::fprintf(stderr, "run: %llu records dropped, %llu scored, %zu creeps in progress\n",
                 static_cast<unsigned long long>(dropped),
                 static_cast<unsigned long long>(s.rows_scored), rig.creeps_in_progress());
    std::exit(1);
  }
  return {quantiles(t_plain), quantiles(t_measure), s.rows_scored,
          s.phase == ds::ShadowPhase::kCandidate};
}

}  // namespace

int main(int argc, char** argv) {
  const int pairs = argc > 1 ? std::atoi(argv[1]) : 10;
  const auto cycles = static_cast<std::size_t>(argc > 2 ? std::atol(argv[2]) : 200000);
  if (pairs < 1 || cycles < 1000 || cycles > 300000) {
    std::fprintf(stderr, "usage: bench_shadow_cost [PAIRS >= 1] [CYCLES 1000..300000]\n");
    return 2;
  }
  std::printf(
      "| pair | plain cycles, A: live alone p50 / p99 / p99.9 / max [ns] | B: live + candidate "
      "[ns] | B/A p99.9 | measurement cycles, A p50 / p99.9 [ns] | B p50 / p99.9 [ns] | rows "
      "scored A / B |\n|---|---|---|---|---|---|---|\n");
  std::vector<double> ratios;
  for (int k = 0; k < pairs; ++k) {
    const RunResult a = run(false, cycles);
    const RunResult b = run(true, cycles);
    if (a.candidate_scored || !b.candidate_scored) {
      std::fprintf(stderr, "pair %d: the candidate was not where it should be\n", k + 1);
      return 1;
    }
    const double r = b.plain.p999_ns / a.plain.p999_ns;
    ratios.push_back(r);
    std::printf(
        "| %d | %.0f / %.0f / %.0f / %.0f | %.0f / %.0f / %.0f / %.0f | %.3f | %.0f / %.0f | %.0f "
        "/ "
        "%.0f | %llu / %llu |\n",
        k + 1, a.plain.p50_ns, a.plain.p99_ns, a.plain.p999_ns, a.plain.max_ns, b.plain.p50_ns,
        b.plain.p99_ns, b.plain.p999_ns, b.plain.max_ns, r, a.measure.p50_ns, a.measure.p999_ns,
        b.measure.p50_ns, b.measure.p999_ns, static_cast<unsigned long long>(a.rows_scored),
        static_cast<unsigned long long>(b.rows_scored));
  }
  std::sort(ratios.begin(), ratios.end());
  const std::size_t n = ratios.size();
  const double median = n % 2 == 1 ? ratios[n / 2] : 0.5 * (ratios[n / 2 - 1] + ratios[n / 2]);
  std::printf("\nplain cycles: median B/A p99.9 over %d pairs: %.3f (min %.3f, max %.3f)\n", pairs,
              median, ratios.front(), ratios.back());
  return 0;
}
