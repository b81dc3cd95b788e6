// Cost of one WearCompensator::step() (issue 3): 3 axes, 16 edge support points, 4 creeps in
// progress, a surface normal with every sample, prediction and deflection on — one axis sample
// per cycle as at the loop rate. Each call is timed on its own (steady_clock); the timer's own
// cost is measured the same way and reported, not subtracted.
//
//   bench_creep_cost [CYCLES]
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "core/common/output.hpp"
#include "core/creep/wear_compensator.hpp"

namespace {

using namespace nccomp::core;
using namespace nccomp::core::creep;
using Clock = std::chrono::steady_clock;

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

}  // namespace

int main(int argc, char** argv) {
  const std::size_t cycles = argc > 1 ? std::stoul(argv[1]) : 200000;
  CreepConfig c;
  c.creep_basis = CreepBasis::kPath;
  c.creep_length_mm = 1e6;  // the 4 creeps stay in progress for the whole run
  c.profile = ProfileShape::kCosine;
  c.max_creeps = 4;
  c.edge.tool_shape = ToolShape::kBall;
  c.edge.edge_points = 16;
  c.edge.normal_source = NormalSource::kAxisSample;
  c.output.mode = OutputMode::kAxes;
  c.output.channel_register = {0, 1, 2, -1, -1};
  c.output.warning_register = 10;
  c.output.alarm_register = 11;
  c.output.measurement_due_register = 12;
  c.output.tool_change_register = 13;
  c.interval.basis = IntervalBasis::kAdaptive;
  c.predict.enabled = true;
  c.deflection = {{0, {0.0, 20.0, 50.0}, {0.0, 2.0, 6.0}, {0.0, 1.0, 4.0}}};
  c.limiter = {500.0, 50.0, 1e4};
  c.tool_life.min_expected_increment_um = 100.0;
  WearCompensator comp;
  comp.configure(c);

  StepOutput out;
  std::vector<Event> ev;
  ev.reserve(4);
  TimeNs now = 0;
  double path = 0.0;
  AxisSample a;
  a.has_normal = true;
  a.tool = 1;
  auto cycle = [&](bool with_measurement, double wear_base) {
    ev.clear();
    now += 1'000'000;  // 1 kHz loop
    path += 0.026;     // 1555 mm/min
    const double ang = 0.001 * path;
    a.time_ns = now;
    a.program_path_mm = path;
    a.position_mm = {path, 0.5 * path, 0.0, 0.0, 0.0, 0.0};
    a.normal = {std::sin(ang), 0.0, std::cos(ang)};
    ev.emplace_back(a);
    if (with_measurement) {
      ToolMeasurement m;
      m.tool = 1;
      m.point_count = 16;
      for (std::size_t i = 0; i < 16; ++i) m.wear_um[i] = wear_base + 0.2 * static_cast<double>(i);
      ev.emplace_back(m);
    }
    out.clear();
    comp.step(now, ev, out);
  };
  ev.emplace_back(ToolChange{now, 1, false});
  comp.step(now, ev, out);
  for (int k = 0; k < 4; ++k) {
    for (int i = 0; i < 200; ++i) cycle(false, 0.0);
    cycle(true, 3.0 * (k + 1) * (k + 1));
  }
  if (comp.creeps_in_progress() != 4) {
    std::fprintf(stderr, "setup: %zu creeps in progress, expected 4\n", comp.creeps_in_progress());
    return 1;
  }
  for (std::size_t i = 0; i < 10000; ++i) cycle(false, 0.0);  // warm-up

  std::vector<double> t_step(cycles), t_timer(cycles);
  for (std::size_t i = 0; i < cycles; ++i) {
    const auto t0 = Clock::now();
    cycle(false, 0.0);
    const auto t1 = Clock::now();
    t_step[i] = std::chrono::duration<double, std::nano>(t1 - t0).count();
  }
  for (std::size_t i = 0; i < cycles; ++i) {
    const auto t0 = Clock::now();
    const auto t1 = Clock::now();
    t_timer[i] = std::chrono::duration<double, std::nano>(t1 - t0).count();
  }
  // Cycles that carry a 16-point measurement (folding the oldest creep, 16 log records).
  std::vector<double> t_meas(2000);
  for (std::size_t i = 0; i < t_meas.size(); ++i) {
    for (int k = 0; k < 5; ++k) cycle(false, 0.0);
    const double base = comp.state().measured_um[0] + 0.5;
    const auto t0 = Clock::now();
    cycle(true, base);
    const auto t1 = Clock::now();
    t_meas[i] = std::chrono::duration<double, std::nano>(t1 - t0).count();
  }
  if (comp.creeps_in_progress() != 4 || comp.halted()) {
    std::fprintf(stderr, "run: %zu creeps in progress, halted %d\n", comp.creeps_in_progress(),
                 comp.halted() ? 1 : 0);
    return 1;
  }
  const Stats s = stats(t_step);
  const Stats t = stats(t_timer);
  const Stats m = stats(t_meas);
  std::printf("| cycle | n | median [ns] | p99 [ns] | p99.9 [ns] | max [ns] |\n");
  std::printf("| --- | --- | --- | --- | --- | --- |\n");
  std::printf(
      "| step(): 1 axis sample, 3 axes, 16 points, 4 creeps | %zu | %.0f | %.0f | %.0f | %.0f |\n",
      cycles, s.median_ns, s.p99_ns, s.p999_ns, s.max_ns);
  std::printf(
      "| step() + 16-point measurement (fold, 16 records) | %zu | %.0f | %.0f | %.0f | %.0f |\n",
      t_meas.size(), m.median_ns, m.p99_ns, m.p999_ns, m.max_ns);
  std::printf("| timer alone (steady_clock pair) | %zu | %.0f | %.0f | %.0f | %.0f |\n", cycles,
              t.median_ns, t.p99_ns, t.p999_ns, t.max_ns);
  return 0;
}
