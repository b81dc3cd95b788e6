// [creep.estimator] (issue 22): the creep goes toward the Kalman filter's estimate, a measurement
// beyond the gate raises the plausibility alarm and changes nothing, the filter's state survives
// a restart (and a state of layout version 3 is converted), the config is checked, the status
// shows the estimate, and the engine's step stays allocation-free.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstring>
#include <limits>
#include <memory>
#include <random>
#include <string>
#include <string_view>
#include <vector>

#include "bench/creep/engine_cycle.hpp"
#include "core/common/config_issue.hpp"
#include "core/creep/creep_module.hpp"
#include "core/creep/state_v3.hpp"
#include "core/creep/state_v4.hpp"
#include "core/creep/state_v5.hpp"
#include "tests/support/alloc_counter.hpp"
#include "tests/unit/creep/rig.hpp"

namespace nccomp::core::creep {
namespace {

using engine::RegisterKind;
using engine::RegisterSpec;

/// σ = 1 µm, no process noise, a new tool's rate prior σ 0.01 µm/mm, gate 5σ.
CreepConfig estimator_config() {
  CreepConfig c = testing::base_config();
  c.estimator.enabled = true;
  c.estimator.measurement_sigma_um = 1.0;
  c.estimator.wear_noise_um_per_sqrt_m = 0.0;
  c.estimator.rate_noise_um_per_mm_per_sqrt_m = 0.0;
  c.estimator.initial_rate_sigma_um_per_mm = 0.01;
  c.estimator.gate_sigmas = 5.0;
  return c;
}

TEST(CreepEstimator, TheCreepGoesTowardTheFiltersEstimateNotTheRawMeasurement) {
  // GIVEN a new tool: prior wear 0 ± 1 µm, rate 0 ± 0.01 µm/mm. After 100 mm the predicted
  // covariance is [[1 + 100²·1e-4, 100·1e-4], [·, 1e-4]] = [[2, 0.01], [0.01, 1e-4]], so a
  // measurement of 6 µm (r = 1) gets the gains K = (2/3, 0.01/3): wear 4 µm, rate 0.02 µm/mm.
  testing::Rig r(estimator_config());
  r.run_to(100.0);
  r.measure({6.0});
  EXPECT_EQ(r.comp.counters().measurements_accepted, 1U);
  EXPECT_NEAR(r.comp.state().measured_um[0], 6.0, 0.0);  // the raw value is kept (logged, judged)
  EXPECT_NEAR(r.comp.state().estimate_wear_um[0], 4.0, 1e-12);
  EXPECT_NEAR(r.comp.state().estimate_rate_um_per_mm[0], 0.02, 1e-14);
  // THEN the creep goes to 4 µm over 50 mm (half way: 2 µm), not to 6.
  r.run_to(125.0);
  EXPECT_NEAR(r.z(), -2.0, 1e-9);
  r.run_to(160.0);
  EXPECT_NEAR(r.z(), -4.0, 1e-9);
  // The status value: the estimate predicted to the cut path now (60 mm on) and its σ from
  // P⁺ = [[2/3, 0.01/3], [·, 1e-4 − 1e-4/3]]: var = 2/3 + 2·60·0.01/3 + 60²·(2e-4/3).
  double w = 0.0;
  double sigma = 0.0;
  ASSERT_TRUE(r.comp.wear_estimate(0, w, sigma));
  EXPECT_NEAR(w, 4.0 + 0.02 * 60.0, 1e-9);
  EXPECT_NEAR(sigma, std::sqrt(2.0 / 3.0 + 2.0 * 60.0 * 0.01 / 3.0 + 3600.0 * 2e-4 / 3.0), 1e-9);
  // Without the estimator the same measurement creeps to 6 µm.
  CreepConfig off = estimator_config();
  off.estimator.enabled = false;
  testing::Rig plain(off);
  plain.run_to(100.0);
  plain.measure({6.0});
  plain.run_to(160.0);
  EXPECT_NEAR(plain.z(), -6.0, 1e-9);
  EXPECT_FALSE(plain.comp.wear_estimate(0, w, sigma));
  EXPECT_TRUE(std::isnan(w));
}

TEST(CreepEstimator, AMeasurementBeyondTheGateRaisesThePlausibilityAlarmAndChangesNothing) {
  // After the first measurement (wear 4 µm, rate 0.02 µm/mm at 100 mm) the prediction at 200 mm
  // is 6 µm with variance 2/3 + 2·100·0.01/3 + 100²·(2e-4/3) = 2/3 + 2/3 + 2/3 = 2, so S = 3 and
  // the gate at 5σ is 6 ± 8.66 µm. 20 µm (14 µm off) is within today's plausibility checks
  // (5 × 50 µm) but beyond the gate.
  testing::Rig r(estimator_config());
  r.run_to(100.0);
  r.measure({6.0});
  r.run_to(200.0);
  const CreepState before = r.comp.export_state();
  const double z_before = r.z();
  r.measure({20.0});
  EXPECT_EQ(r.comp.counters().measurements_gated, 1U);
  EXPECT_EQ(r.comp.counters().measurements_refused, 1U);
  EXPECT_EQ(r.comp.counters().measurements_accepted, 1U);
  ASSERT_EQ(r.count(AlarmCode::kToolBrokenOrMismeasured), 1U);
  EXPECT_NEAR(r.alarms.back().value, 14.0, 1e-9);  // the innovation [µm]
  EXPECT_TRUE(r.comp.halted());
  const CreepState& after = r.comp.state();
  EXPECT_EQ(after.measurements, before.measurements);
  EXPECT_EQ(after.measured_um[0], before.measured_um[0]);
  EXPECT_EQ(after.committed_um[0], before.committed_um[0]);
  EXPECT_EQ(after.estimate_wear_um[0], before.estimate_wear_um[0]);
  EXPECT_EQ(after.estimate_rate_um_per_mm[0], before.estimate_rate_um_per_mm[0]);
  EXPECT_EQ(after.estimate_p_ww[0], before.estimate_p_ww[0]);
  EXPECT_EQ(after.estimate_path_mm, before.estimate_path_mm);
  EXPECT_EQ(r.z(), z_before);
  // 14.6 µm (8.6 µm off, just within 5·sqrt(3) = 8.66) is absorbed: the gate, not another check,
  // refused 20.
  testing::Rig ok(estimator_config());
  ok.run_to(100.0);
  ok.measure({6.0});
  ok.run_to(200.0);
  ok.measure({14.6});
  EXPECT_EQ(ok.comp.counters().measurements_accepted, 2U);
  EXPECT_EQ(ok.comp.counters().measurements_gated, 0U);
  // With the gate off (0) the 20 µm is absorbed too.
  CreepConfig no_gate = estimator_config();
  no_gate.estimator.gate_sigmas = 0.0;
  testing::Rig g(no_gate);
  g.run_to(100.0);
  g.measure({6.0});
  g.run_to(200.0);
  g.measure({20.0});
  EXPECT_EQ(g.comp.counters().measurements_accepted, 2U);
  EXPECT_FALSE(g.comp.halted());
}

std::vector<RegisterSpec> registers() {
  const LimiterConfig lim{100.0, 50.0, 1e5};
  return {{"X_offset", RegisterKind::kAxisOffset, lim},
          {"Y_offset", RegisterKind::kAxisOffset, lim},
          {"Z_offset", RegisterKind::kAxisOffset, lim}};
}

CreepModuleConfig module_config(const CreepConfig& c) {
  CreepModuleConfig m;
  m.creep = c;
  m.creep.output.warning_register = -1;
  m.creep.output.alarm_register = -1;
  m.creep.output.measurement_due_register = -1;
  m.creep.output.tool_change_register = -1;
  return m;
}

/// Drives a module directly (as the engine does after validation).
struct ModuleRig {
  CreepModule module;
  std::vector<RegisterSpec> specs{registers()};
  StepOutput out;
  TimeNs now{0};
  double path{0.0};

  explicit ModuleRig(const CreepConfig& c) : module(module_config(c)) {
    module.attach(engine::RegisterTable(specs));
    std::array<Event, 1> ev{ToolChange{now, 1, false}};
    step(ev);
    advance(0.0);  // the first sample anchors the path
  }
  void step(std::span<const Event> ev) {
    out.clear();
    module.step(now, ev, out);
  }
  void advance(double ds) {
    now += 10'000'000;
    path += ds;
    AxisSample a;
    a.time_ns = now;
    a.program_path_mm = path;
    a.tool = 1;
    a.cutting = true;
    std::array<Event, 1> ev{a};
    step(ev);
  }
  void run_to(double p) {
    while (path + 0.5 <= p + 1e-9) advance(0.5);
  }
  void measure(double w) {
    ToolMeasurement m;
    m.tool = 1;
    m.wear_um[0] = w;
    now += 1'000'000;
    std::array<Event, 1> ev{m};
    step(ev);
  }
  [[nodiscard]] double z() const { return module.compensator().channel_output_um(Channel::kZ); }
};

TEST(CreepEstimator, TheFiltersStateSurvivesARestartWithoutResetOrDouble) {
  // GIVEN a run with three measurements, saved in the middle of a creep; WHEN a fresh process
  // loads the saved bytes and both carry on with the same path and measurements; THEN the
  // filter's state, the offsets and the next estimate are identical (no reset to the prior, no
  // measurement absorbed twice).
  CreepConfig c = estimator_config();
  c.estimator.rate_noise_um_per_mm_per_sqrt_m = 0.01;
  ModuleRig a(c);
  const std::array<double, 3> wear{3.0, 5.5, 7.0};
  for (std::size_t k = 0; k < wear.size(); ++k) {
    a.run_to(100.0 * static_cast<double>(k + 1));
    a.measure(wear[k]);
  }
  a.run_to(320.0);  // 20 of 50 mm into the last creep
  std::vector<std::byte> bytes(a.module.state_capacity());
  ASSERT_EQ(a.module.save_state(bytes), bytes.size());
  ModuleRig b(c);
  ASSERT_TRUE(b.module.load_state(bytes));
  const auto& sa = a.module.compensator().state();
  const auto& sb = b.module.compensator().state();
  ASSERT_TRUE(sb.estimate_valid);
  EXPECT_EQ(sb.estimate_wear_um[0], sa.estimate_wear_um[0]);
  EXPECT_EQ(sb.estimate_rate_um_per_mm[0], sa.estimate_rate_um_per_mm[0]);
  EXPECT_EQ(sb.estimate_p_ww[0], sa.estimate_p_ww[0]);
  EXPECT_EQ(sb.estimate_p_wr[0], sa.estimate_p_wr[0]);
  EXPECT_EQ(sb.estimate_p_rr[0], sa.estimate_p_rr[0]);
  EXPECT_EQ(sb.estimate_path_mm, sa.estimate_path_mm);
  // The restarted process re-anchors its path on the first sample: the NC's program path is
  // wherever it is, the cut path continues from the saved one.
  b.path = 5000.0;
  b.advance(0.0);
  for (int i = 0; i < 160; ++i) {  // 80 mm: the creep ends, then the next measurement
    a.advance(0.5);
    b.advance(0.5);
    ASSERT_NEAR(b.z(), a.z(), 1e-12) << i;
  }
  a.measure(9.0);
  b.measure(9.0);
  EXPECT_EQ(sb.estimate_wear_um[0], sa.estimate_wear_um[0]);
  EXPECT_EQ(sb.estimate_p_ww[0], sa.estimate_p_ww[0]);
  for (int i = 0; i < 120; ++i) {
    a.advance(0.5);
    b.advance(0.5);
  }
  EXPECT_NEAR(b.z(), a.z(), 1e-12);
  EXPECT_NEAR(a.z(), -sa.estimate_wear_um[0], 1e-9);  // the creep ended on the estimate
}

TEST(CreepEstimator, AStateOfLayoutVersion3IsConvertedAndTheFilterStartsFromIt) {
  // A version-3 state (before the estimator), with what was adopted at start-up after it: the
  // wear, the fitted rate, the creeps and the adoption are kept; the filter is not yet valid and
  // starts, at the next measurement, from the last measured wear (22 µm at 120 mm) and the
  // fitted rate (0.1 µm/mm) with the prior covariance diag(σ², σ_r0²) = diag(1, 1e-4).
  CreepConfig c = estimator_config();
  ModuleRig m(c);
  v3::CreepState s;
  s.edge_points = 1;
  s.tool = 1;
  s.cut_path_mm = 130.0;
  s.creep_path_mm = 130.0;
  s.committed_um[0] = 22.0;
  s.measured_um[0] = 22.0;
  s.rate_um_per_mm[0] = 0.1;
  s.rate_known = true;
  s.measurements = 2;
  s.last_measurement_cut_path_mm = 120.0;
  s.last_measurement_creep_path_mm = 120.0;
  s.channel_output_um[2] = -22.0;
  s.normal_held = false;
  v3::ToolMemory mem;
  mem.tool[2] = 7;
  mem.last_use[2] = 1;
  mem.use_counter = 1;
  mem.state[2].edge_points = 1;
  mem.state[2].tool = 7;
  mem.state[2].measured_um[0] = 9.0;
  mem.state[2].committed_um[0] = 9.0;
  AdoptedOutputs adopted;
  adopted.held[2] = 1;
  adopted.held_um[2] = -21.5;
  std::vector<std::byte> bytes(v3::kModuleStateBytes + sizeof(AdoptedOutputs));
  std::memcpy(bytes.data(), &s, sizeof s);
  std::memcpy(bytes.data() + sizeof s, &mem, sizeof mem);
  std::memcpy(bytes.data() + v3::kModuleStateBytes, &adopted, sizeof adopted);
  ASSERT_NE(bytes.size(), m.module.state_capacity());
  {
    nccomp::test::AllocationScope scope;
    ASSERT_TRUE(m.module.load_state(bytes));
    EXPECT_EQ(scope.count(), 0U);
  }
  const auto& comp = m.module.compensator();
  const auto& st = comp.state();
  EXPECT_EQ(st.version, CreepState::kVersion);
  EXPECT_FALSE(st.estimate_valid);
  EXPECT_NEAR(st.committed_um[0], 22.0, 0.0);
  EXPECT_NEAR(st.cut_path_mm, 130.0, 0.0);
  EXPECT_EQ(comp.adoption().held[2], 1);
  EXPECT_NEAR(comp.adoption().held_um[2], -21.5, 0.0);
  EXPECT_EQ(comp.tool_memory().tool[2], 7);
  EXPECT_EQ(comp.tool_memory().state[2].version, CreepState::kVersion);
  // Without the AdoptedOutputs (a version-3 state written before adoption existed) it loads too.
  ModuleRig m2(c);
  ASSERT_TRUE(m2.module.load_state(std::span(bytes).first(v3::kModuleStateBytes)));
  EXPECT_EQ(m2.module.compensator().adoption().held[2], 0);
  // The next measurement, 24 µm at 140 mm (d = 20 mm): predicted wear 22 + 0.1·20 = 24 with
  // P⁻ = [[1 + 400·1e-4, 20·1e-4], [·, 1e-4]] = [[1.04, 0.002], [·, 1e-4]]: innovation 0, so
  // the estimate stays 24 and its variance is 1.04·1/(2.04).
  m.path = 0.0;
  m.advance(0.0);
  m.run_to(10.0);
  m.measure(24.0);
  ASSERT_TRUE(st.estimate_valid);
  EXPECT_EQ(comp.counters().measurements_accepted, 1U);
  EXPECT_NEAR(st.estimate_wear_um[0], 24.0, 1e-9);
  EXPECT_NEAR(st.estimate_rate_um_per_mm[0], 0.1, 1e-12);
  EXPECT_NEAR(st.estimate_p_ww[0], 1.04 / 2.04, 1e-12);
  // A version-3-sized blob with a corrupt bool is refused and changes nothing.
  ModuleRig fresh(c);
  bytes[offsetof(v3::CreepState, request_held)] = std::byte{2};
  EXPECT_FALSE(fresh.module.load_state(bytes));
  EXPECT_EQ(fresh.module.compensator().state().measurements, 0U);
}

TEST(CreepEstimator, ACorruptFilterStateIsRefused) {
  CreepConfig c = estimator_config();
  WearCompensator comp;
  comp.configure(c);
  CreepState s = comp.export_state();
  s.estimate_valid = true;
  s.estimate_p_ww[0] = 1.0;
  s.estimate_p_rr[0] = 1e-4;
  EXPECT_EQ(comp.check_state(s).field, nullptr);
  s.estimate_p_wr[0] = 0.02;  // |p_wr| > sqrt(p_ww·p_rr) = 0.01: not a covariance
  ASSERT_NE(comp.check_state(s).field, nullptr);
  EXPECT_EQ(std::string_view(comp.check_state(s).field), "estimate");
  s.estimate_p_wr[0] = 0.0;
  s.estimate_wear_um[0] = kNaN;
  EXPECT_NE(comp.check_state(s).field, nullptr);
  s.estimate_wear_um[0] = 0.0;
  s.estimate_path_mm = 10.0;  // ahead of the tool's cut path (0)
  ASSERT_NE(comp.check_state(s).field, nullptr);
  EXPECT_EQ(std::string_view(comp.check_state(s).field), "estimate_path_mm");
}

TEST(CreepEstimator, ConfigErrorsNameTheKey) {
  const auto issues = [](const CreepConfig& c) {
    try {
      validate(c);
    } catch (const std::invalid_argument& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  CreepConfig c = estimator_config();
  EXPECT_EQ(issues(c), "");
  c.estimator.measurement_sigma_um = 0.0;
  c.estimator.rate_noise_um_per_mm_per_sqrt_m = -1.0;
  c.estimator.gate_sigmas = 1.5;
  c.estimator.family_min_tools = 0;
  const std::string e = issues(c);
  EXPECT_NE(e.find("creep.estimator.family_min_tools: must be 1..1000, got 0"), std::string::npos)
      << e;
  EXPECT_NE(e.find("creep.estimator.measurement_sigma_um"), std::string::npos) << e;
  EXPECT_NE(e.find("creep.estimator.rate_noise_um_per_mm_per_sqrt_m"), std::string::npos) << e;
  EXPECT_NE(e.find("creep.estimator.gate_sigmas: must be 0 (no gate) or a finite number >= 2"),
            std::string::npos)
      << e;
  c = estimator_config();
  c.estimator.initial_rate_sigma_um_per_mm = std::nan("");
  EXPECT_NE(issues(c).find("creep.estimator.initial_rate_sigma_um_per_mm"), std::string::npos);
  c.estimator.enabled = false;  // off: not judged
  EXPECT_EQ(issues(c), "");
}

TEST(CreepEstimator, StatusShowsTheEstimateAndItsSigma) {
  ModuleRig m(estimator_config());
  std::array<engine::StatusValue, engine::kMaxStatusValues> v{};
  const auto find = [&](std::size_t n, std::string_view key) -> const engine::StatusValue* {
    for (std::size_t i = 0; i < n; ++i) {
      if (std::string_view(v[i].key) == key) return &v[i];
    }
    return nullptr;
  };
  std::size_t n = m.module.status(v);
  ASSERT_NE(find(n, "wear_estimate_um"), nullptr);
  EXPECT_TRUE(std::isnan(find(n, "wear_estimate_um")->value));  // no measurement yet
  EXPECT_STREQ(find(n, "mode")->text, "creeping, estimator");
  m.run_to(100.0);
  m.measure(6.0);
  m.run_to(160.0);
  n = m.module.status(v);
  EXPECT_NEAR(find(n, "wear_estimate_um")->value, 5.2, 1e-9);  // as in the first test
  EXPECT_NEAR(find(n, "wear_sigma_um")->value,
              std::sqrt(2.0 / 3.0 + 2.0 * 60.0 * 0.01 / 3.0 + 3600.0 * 2e-4 / 3.0), 1e-9);
  CreepConfig off = estimator_config();
  off.estimator.enabled = false;
  ModuleRig p(off);
  n = p.module.status(v);
  EXPECT_EQ(find(n, "wear_estimate_um"), nullptr);
  EXPECT_EQ(find(n, "wear_sigma_um"), nullptr);
  EXPECT_STREQ(find(n, "mode")->text, "creeping");
}

TEST(CreepRealTime, EngineStepWithTheEstimatorAllocatesNothing) {
  // The costed cycle (16 support points, 4 creeps, prediction) with the estimator on: each
  // measurement runs 16 filters' predict and update.
  auto rig = std::make_unique<bench::creep::EngineCycle>(true, true);
  const auto& k = rig->module().compensator().counters();
  const auto accepted = k.measurements_accepted;
  std::array<engine::StatusValue, engine::kMaxStatusValues> status{};
  nccomp::test::AllocationScope scope;
  for (int i = 0; i < 1000; ++i) {
    if (i % 50 == 25) {
      rig->measure(rig->next_wear_base_um());
    } else {
      rig->cycle();
    }
    (void)rig->module().status(status);
  }
  EXPECT_EQ(scope.count(), 0U);
  EXPECT_EQ(scope.frees(), 0U);
  EXPECT_EQ(k.measurements_accepted, accepted + 20U);
  EXPECT_TRUE(rig->module().compensator().state().estimate_valid);
}

}  // namespace
}  // namespace nccomp::core::creep

namespace nccomp::core::creep {
namespace {

TEST(CreepEstimator, UncertaintyIntervalAsksForAMeasurementWhenSigmaReachesTheBound) {
  // GIVEN a new tool (wear 0 ± 1 µm, rate 0 ± 0.01 µm/mm, no process noise) and a bound of
  // 2 µm: σ(d)² = 1 + 1e-4·d² reaches 4 at d = sqrt(3e4) = 173.2 mm.
  CreepConfig c = estimator_config();
  c.interval.basis = IntervalBasis::kUncertainty;
  c.interval.max_sigma_um = 2.0;
  c.interval.min_interval_mm = 10.0;
  c.interval.max_interval_mm = 1000.0;
  testing::Rig r(c);
  EXPECT_NEAR(r.comp.next_measurement_path_mm(), std::sqrt(3e4), 1e-6);
  r.run_to(173.0);
  EXPECT_EQ(r.count(AlarmCode::kMeasurementDue), 0U);
  r.run_to(173.5);
  EXPECT_EQ(r.count(AlarmCode::kMeasurementDue), 1U);
  // WHEN it is measured at d0 = 173.5 mm, THEN the next request comes where the posterior's
  // σ reaches 2 again: P⁻ = [[1 + 1e-4·d0², 1e-4·d0], [·, 1e-4]], K = P⁻h/(P⁻ww + 1),
  // P⁺ = (I − Kh)P⁻, and σ²(d) = P⁺ww + 2d·P⁺wr + d²·P⁺rr = 4 solved for d.
  const double d0 = 173.5;
  const double pww = 1.0 + 1e-4 * d0 * d0;
  const double pwr = 1e-4 * d0;
  const double prr = 1e-4;
  const double s = pww + 1.0;
  const double aww = pww - pww * pww / s;
  const double awr = pwr - pww * pwr / s;
  const double arr = prr - pwr * pwr / s;
  const double d =
      (-2.0 * awr + std::sqrt(4.0 * awr * awr + 4.0 * arr * (4.0 - aww))) / (2.0 * arr);
  r.measure({3.0});
  ASSERT_EQ(r.comp.counters().measurements_accepted, 1U);
  EXPECT_NEAR(r.comp.next_measurement_path_mm(), d0 + d, 1e-6);
  // The limits hold: a bound the estimate never reaches asks at max_interval_mm, one it is
  // already beyond at min_interval_mm.
  c.interval.max_sigma_um = 1e3;
  testing::Rig far(c);
  EXPECT_NEAR(far.comp.next_measurement_path_mm(), 1000.0, 0.0);
  c.interval.max_sigma_um = 0.5;
  testing::Rig near(c);
  EXPECT_NEAR(near.comp.next_measurement_path_mm(), 10.0, 0.0);
  // It needs the estimator.
  c.estimator.enabled = false;
  EXPECT_THROW(validate(c), std::invalid_argument);
}

}  // namespace
}  // namespace nccomp::core::creep

namespace nccomp::core::creep {
namespace {

/// The estimator of these tests without process noise and without the gate, and a tool life
/// that takes the test's deliberately noisy measurements.
CreepConfig family_config() {
  CreepConfig c = estimator_config();
  c.estimator.gate_sigmas = 0.0;
  c.tool_life.noise_um = 100.0;
  return c;
}

/// Measures tool `r.tool` at cut paths 100, 200, … (steps of 100 mm from `from_mm` of program
/// path) with the wear given by `wear(j)`, j = 1, 2, …
template <class F>
void measure_every_100_mm(testing::Rig& r, double from_mm, int count, F wear) {
  for (int j = 1; j <= count; ++j) {
    r.run_to(from_mm + 100.0 * j);
    r.measure({wear(j)});
  }
}

TEST(CreepEstimatorFamily, AFinishedToolsRateNoiseIsLearnedAndANewToolStartsWithIt) {
  // GIVEN tools measured at 100, 200, 300, 400 mm of their cut path without noise: the
  // least-squares rate of the four is the true slope a, Sxx = 150² + 50² + 50² + 150² = 50000,
  // so one finished tool estimates q = (a² − σ²/Sxx) / 400 with σ = 1.
  CreepConfig c = family_config();
  c.estimator.rate_noise_um_per_mm_per_sqrt_m = 0.0005;  // q = 2.5e-10 per mm until learned
  c.estimator.learn_rate_noise = true;
  c.estimator.family_min_tools = 2;
  const double q_config = 0.0005 * 0.0005 / 1000.0;
  const double q1 = (0.05 * 0.05 - 1.0 / 50000.0) / 400.0;
  const double q2 = (0.02 * 0.02 - 1.0 / 50000.0) / 400.0;
  testing::Rig r(c);
  EXPECT_NEAR(r.comp.rate_q(), q_config, 1e-24);
  measure_every_100_mm(r, 0.0, 4, [](int j) { return 0.05 * 100.0 * j; });
  EXPECT_NEAR(r.comp.finished_tool_rate_q(r.comp.state()), q1, 1e-18);
  // WHEN its sister replaces it: the family has one tool, fewer than family_min_tools, so the
  // sister still runs with the configured noise.
  r.tool_change(2, true);
  EXPECT_EQ(r.comp.state().family.tools, 1U);
  EXPECT_NEAR(r.comp.family_rate_q(), q1, 1e-18);
  EXPECT_NEAR(r.comp.rate_q(), q_config, 1e-24);
  measure_every_100_mm(r, 400.0, 4, [](int j) { return 0.02 * 100.0 * j; });
  r.tool_change(3, true);
  const double q_family = 0.5 * (q1 + q2);
  EXPECT_EQ(r.comp.state().family.tools, 2U);
  EXPECT_NEAR(r.comp.family_rate_q(), q_family, 1e-18);
  // THEN the third tool's filter runs with the family's q: from the prior diag(1, 1e-4) over
  // 100 mm, P⁻_ww = 1 + 100²·1e-4 + q·100³/3, and after a measurement P⁺_ww = P⁻/(P⁻ + 1).
  EXPECT_NEAR(r.comp.rate_q(), q_family, 1e-18);
  r.run_to(900.0);
  r.measure({1.0});
  const double p_minus = 2.0 + q_family * 1e6 / 3.0;
  EXPECT_NEAR(r.comp.state().estimate_p_ww[0], p_minus / (p_minus + 1.0), 1e-12);
  // Without learning the same history leaves the configured noise in force.
  CreepConfig off = c;
  off.estimator.learn_rate_noise = false;
  testing::Rig o(off);
  measure_every_100_mm(o, 0.0, 4, [](int j) { return 0.05 * 100.0 * j; });
  o.tool_change(2, true);
  measure_every_100_mm(o, 400.0, 4, [](int j) { return 0.02 * 100.0 * j; });
  o.tool_change(3, true);
  EXPECT_EQ(o.comp.state().family.tools, 2U);
  EXPECT_NEAR(o.comp.rate_q(), q_config, 1e-24);
}

TEST(CreepEstimatorFamily, TheFamilySurvivesARestartAndToolsComingBackKeepTheirOwnNoise) {
  CreepConfig c = family_config();
  c.estimator.learn_rate_noise = true;
  c.estimator.family_min_tools = 1;
  testing::Rig r(c);
  measure_every_100_mm(r, 0.0, 4, [](int j) { return 0.05 * 100.0 * j; });
  r.tool_change(2, true);  // finished: the family knows one tool, tool 2 starts with its q
  const double q1 = (0.05 * 0.05 - 1.0 / 50000.0) / 400.0;
  ASSERT_NEAR(r.comp.rate_q(), q1, 1e-18);
  r.tool_change(7, false);  // tool 2 remembered; tool 7 new, also with the family's q
  EXPECT_NEAR(r.comp.rate_q(), q1, 1e-18);
  const CreepState saved = r.comp.export_state();
  WearCompensator b;
  b.configure(c);
  b.import_state(saved);
  EXPECT_EQ(b.state().family.tools, 1U);
  EXPECT_NEAR(b.family_rate_q(), q1, 1e-18);
  EXPECT_NEAR(b.rate_q(), q1, 1e-18);
  // A corrupt learned noise is refused with the state.
  CreepState bad = saved;
  bad.rate_q = -1.0;
  EXPECT_EQ(std::string_view(b.check_state(bad).field), "rate_q");
  bad = saved;
  bad.family.rate_q_sum = std::numeric_limits<double>::infinity();
  EXPECT_EQ(std::string_view(b.check_state(bad).field), "family");
}

/// An independent level + rate Kalman filter (plain arithmetic, no Eigen), q = 0, measured
/// every d mm: the normalised innovation squares and the residual variances of a sequence.
struct ReferenceFilter {
  double w{0.0}, r{0.0}, pww{1.0}, pwr{0.0}, prr{1e-4};
  double nis_sum{0.0}, resid_sum{0.0};
  int n{0};
  void measure(double d, double z, double sigma2) {
    w += r * d;
    pww += 2.0 * d * pwr + d * d * prr;
    pwr += d * prr;
    const double s = pww + sigma2;
    const double nu = z - w;
    nis_sum += nu * nu / s;
    resid_sum += nu * nu - pww;
    ++n;
    const double kw = pww / s;
    const double kr = pwr / s;
    w += kw * nu;
    r += kr * nu;
    const double pww0 = pww, pwr0 = pwr;
    pww -= kw * pww0;
    pwr -= kw * pwr0;
    prr -= kr * pwr0;
  }
  [[nodiscard]] double nis_mean() const { return nis_sum / n; }
};

TEST(CreepEstimatorNoise, TheNisMeanIsTrackedAndAWrongSigmaIsReportedOnce) {
  // GIVEN σ configured 1 µm, but the laser scatters ±3 µm around a constant 10 µm.
  testing::Rig r(family_config());
  ReferenceFilter ref;
  for (int j = 1; j <= 15; ++j) {
    const double z = 10.0 + (j % 2 == 0 ? 3.0 : -3.0);
    r.run_to(100.0 * j);
    r.measure({z});
    ref.measure(100.0, z, 1.0);
    ASSERT_EQ(r.comp.counters().measurements_accepted, static_cast<std::uint64_t>(j));
    EXPECT_NEAR(r.comp.nis_mean(0), ref.nis_mean(), 1e-9) << j;
    EXPECT_NEAR(r.comp.measurement_sigma_estimate_um(0), std::sqrt(ref.resid_sum / j), 1e-9) << j;
    // THEN from the 10th measurement on (not before) the warning is raised, once per tool.
    const auto warned = r.count(AlarmCode::kMeasurementNoiseInconsistent);
    if (j < 10) {
      EXPECT_EQ(warned, 0U) << j;
    } else {
      EXPECT_EQ(warned, 1U) << j;
    }
    if (j == 10) {
      ASSERT_GT(ref.nis_mean() - 1.0, 3.0 * std::sqrt(2.0 / 10.0));
      const AlarmEvent* a = nullptr;
      for (const auto& x : r.alarms) {
        if (x.code == AlarmCode::kMeasurementNoiseInconsistent) a = &x;
      }
      ASSERT_NE(a, nullptr);
      EXPECT_NEAR(a->value, ref.nis_mean(), 1e-9);
      EXPECT_EQ(a->severity, Severity::kWarning);
      EXPECT_EQ(a->subject, 1);
      EXPECT_FALSE(r.comp.state().warning_flag);  // a log line, not the warning register
    }
  }
  // A new tool counts afresh.
  r.tool_change(2, true);
  EXPECT_TRUE(std::isnan(r.comp.nis_mean(0)));
  EXPECT_EQ(r.comp.state().nis_count, 0U);
  EXPECT_FALSE(r.comp.state().noise_warned);
}

TEST(CreepEstimatorNoise, ATooLargeSigmaIsReportedWhenTheMeanIsBeyondTheBandBelow) {
  // GIVEN exact measurements of a wear rate of 0.01 µm/mm with σ configured 1 µm: ν²/S falls
  // toward 0.
  // The warning comes at the first n ≥ 10 where 1 − mean > 3·sqrt(2/n), computed here with the
  // reference filter.
  testing::Rig r(family_config());
  ReferenceFilter ref;
  int expected_at = 0;
  for (int j = 1; j <= 40; ++j) {
    r.run_to(100.0 * j);
    r.measure({1.0 * j});
    ref.measure(100.0, 1.0 * j, 1.0);
    if (expected_at == 0 && j >= 10 && std::fabs(ref.nis_mean() - 1.0) > 3.0 * std::sqrt(2.0 / j)) {
      expected_at = j;
    }
    EXPECT_EQ(r.count(AlarmCode::kMeasurementNoiseInconsistent),
              expected_at != 0 && j >= expected_at ? 1U : 0U)
        << j;
  }
  ASSERT_GT(expected_at, 10);
  ASSERT_LT(expected_at, 40);
}

TEST(CreepEstimatorNoise, ConsistentNoiseRaisesNoWarning) {
  // Gaussian noise of the configured σ (seeded) on a straight wear line: 200 measurements.
  testing::Rig r(family_config());
  std::mt19937_64 rng(22);
  std::normal_distribution<double> noise(0.0, 1.0);
  for (int j = 1; j <= 200; ++j) {
    r.run_to(100.0 * j);
    r.measure({0.01 * 100.0 * j + noise(rng)});
  }
  EXPECT_EQ(r.comp.counters().measurements_accepted, 200U);
  EXPECT_EQ(r.count(AlarmCode::kMeasurementNoiseInconsistent), 0U);
  EXPECT_NEAR(r.comp.nis_mean(0), 1.0, 3.0 * std::sqrt(2.0 / 200.0));
}

TEST(CreepEstimatorFamily, AStateOfLayoutVersion4IsConverted) {
  // A version-4 state with a valid filter: kept as it is; the tool uses the configured noise
  // (rate_q NaN), the σ check starts from zero and the family is empty.
  CreepConfig c = family_config();
  ModuleRig m(c);
  v4::CreepState s;
  s.edge_points = 1;
  s.tool = 1;
  s.cut_path_mm = 130.0;
  s.creep_path_mm = 130.0;
  s.committed_um[0] = 22.0;
  s.measured_um[0] = 22.0;
  s.measurements = 2;
  s.last_measurement_cut_path_mm = 120.0;
  s.last_measurement_creep_path_mm = 120.0;
  s.estimate_wear_um[0] = 21.5;
  s.estimate_rate_um_per_mm[0] = 0.1;
  s.estimate_p_ww[0] = 0.5;
  s.estimate_p_wr[0] = 0.001;
  s.estimate_p_rr[0] = 1e-5;
  s.estimate_path_mm = 120.0;
  s.estimate_valid = true;
  v4::ToolMemory mem;
  mem.tool[1] = 4;
  mem.last_use[1] = 1;
  mem.use_counter = 1;
  mem.state[1].edge_points = 1;
  mem.state[1].tool = 4;
  mem.state[1].measured_um[0] = 9.0;
  std::vector<std::byte> bytes(v4::kModuleStateBytes + sizeof(AdoptedOutputs));
  std::memcpy(bytes.data(), &s, sizeof s);
  std::memcpy(bytes.data() + sizeof s, &mem, sizeof mem);
  AdoptedOutputs none;
  std::memcpy(bytes.data() + v4::kModuleStateBytes, &none, sizeof none);
  ASSERT_NE(bytes.size(), m.module.state_capacity());
  {
    nccomp::test::AllocationScope scope;
    ASSERT_TRUE(m.module.load_state(bytes));
    EXPECT_EQ(scope.count(), 0U);
  }
  const auto& st = m.module.compensator().state();
  EXPECT_EQ(st.version, CreepState::kVersion);
  EXPECT_TRUE(st.estimate_valid);
  EXPECT_EQ(st.estimate_wear_um[0], 21.5);
  EXPECT_EQ(st.estimate_p_wr[0], 0.001);
  EXPECT_TRUE(std::isnan(st.rate_q));
  EXPECT_EQ(st.nis_count, 0U);
  EXPECT_EQ(st.family.tools, 0U);
  EXPECT_EQ(m.module.compensator().tool_memory().state[1].measured_um[0], 9.0);
  ModuleRig m2(c);
  EXPECT_TRUE(m2.module.load_state(std::span(bytes).first(v4::kModuleStateBytes)));
  // A corrupt bool is refused, nothing changes.
  ModuleRig fresh(c);
  bytes[offsetof(v4::CreepState, estimate_valid)] = std::byte{2};
  EXPECT_FALSE(fresh.module.load_state(bytes));
  EXPECT_EQ(fresh.module.compensator().state().measurements, 0U);
}

}  // namespace
}  // namespace nccomp::core::creep

namespace nccomp::core::creep {
namespace {

/// family_config() with the rate noise adapted within the tool's life: starts at 0.001 µm/mm/√m
/// (q = 1e-9 per mm), window 5 measurements, bounds 0.0001..0.01.
CreepConfig adapt_config() {
  CreepConfig c = family_config();
  c.estimator.rate_noise_um_per_mm_per_sqrt_m = 0.001;
  c.estimator.adapt_rate_noise = true;
  c.estimator.adapt_window_measurements = 5.0;
  c.estimator.min_rate_noise_um_per_mm_per_sqrt_m = 0.0001;
  c.estimator.max_rate_noise_um_per_mm_per_sqrt_m = 0.01;
  return c;
}

/// The level + rate filter with process noise q written out in scalars, and the adaptation of
/// docs/estimation.md: log q moves by (ν²/S − 1)·min(S/P⁻, 4)/window, clamped to ±1, q to
/// [q_min, q_max].
struct AdaptingReference {
  double w{0.0}, r{0.0}, pww{1.0}, pwr{0.0}, prr{1e-4};
  double q{1e-9};
  double q_min{1e-11}, q_max{1e-7}, window{5.0};
  void measure(double d, double z) {
    w += r * d;
    pww += 2.0 * d * pwr + d * d * prr + q * d * d * d / 3.0;
    pwr += d * prr + q * d * d / 2.0;
    prr += q * d;
    const double s = pww + 1.0;
    const double nu = z - w;
    const double gain = std::min(s / pww, 4.0);
    const double step = std::clamp((nu * nu / s - 1.0) * gain / window, -1.0, 1.0);
    const double kw = pww / s;
    const double kr = pwr / s;
    w += kw * nu;
    r += kr * nu;
    const double pww0 = pww, pwr0 = pwr;
    pww -= kw * pww0;
    pwr -= kw * pwr0;
    prr -= kr * pwr0;
    q = std::clamp(q * std::exp(step), q_min, q_max);
  }
};

TEST(CreepEstimatorAdapt, TheRateNoiseFollowsTheToolsInnovations) {
  // GIVEN wear that accelerates (w = 1e-5·s² µm: the rate grows from 0 to 0.04 µm/mm over
  // 2000 mm), measured exactly every 100 mm; the filter lags, its innovations exceed what it
  // expects, so q rises. Every measurement's q against the scalar reference.
  testing::Rig r(adapt_config());
  AdaptingReference ref;
  for (int j = 1; j <= 20; ++j) {
    const double s = 100.0 * j;
    r.run_to(s);
    r.measure({1e-5 * s * s});
    ref.measure(100.0, 1e-5 * s * s);
    ASSERT_NEAR(r.comp.rate_q(), ref.q, 1e-9 * ref.q) << j;
    EXPECT_NEAR(r.comp.state().estimate_wear_um[0], ref.w, 1e-9) << j;
  }
  EXPECT_GT(r.comp.rate_q(), 3e-9);
  // A wear that grows exactly linearly is predicted better than the filter expects: q falls.
  testing::Rig lin(adapt_config());
  for (int j = 1; j <= 20; ++j) {
    lin.run_to(100.0 * j);
    lin.measure({0.01 * 100.0 * j});
  }
  EXPECT_LT(lin.comp.rate_q(), 1e-9);
  EXPECT_GE(lin.comp.rate_q(), 1e-11);
  // Without adapt_rate_noise the tool keeps the configured q.
  CreepConfig off = adapt_config();
  off.estimator.adapt_rate_noise = false;
  testing::Rig fixed(off);
  for (int j = 1; j <= 20; ++j) {
    fixed.run_to(100.0 * j);
    fixed.measure({1e-5 * 1e4 * j * j});
  }
  EXPECT_DOUBLE_EQ(fixed.comp.rate_q(), 1e-9);
}

/// Measures whenever the module asks (interval basis uncertainty, bound 1.5 µm, 50..1000 mm)
/// from 0 to 6000 mm of cut path, with the exact wear; the number of measurements taken.
std::size_t measurements_when_needed(const CreepConfig& base, double (*wear_um)(double)) {
  CreepConfig c = base;
  c.interval.basis = IntervalBasis::kUncertainty;
  c.interval.max_sigma_um = 1.5;
  c.interval.min_interval_mm = 50.0;
  c.interval.max_interval_mm = 1000.0;
  testing::Rig r(c);
  for (double s = r.comp.next_measurement_path_mm(); s <= 6000.0;
       s = r.comp.next_measurement_path_mm()) {
    r.run_to(std::ceil(s));
    r.measure({wear_um(r.program_path_mm)});
  }
  return r.comp.counters().measurements_accepted;
}

TEST(CreepEstimatorAdapt, WhenNeededMeasuresLessWhereTheWearIsSteadyThanWhereItAccelerates) {
  // GIVEN two tools worn 60 µm over the same 6000 mm, measured exactly when the module asks at
  // the same bound: one at a steady 0.01 µm/mm, one whose rate grows from 0 to 0.02 µm/mm
  // (w = 60·(s/6000)²). The steady tool's innovations are below what the filter expects (q
  // falls, the intervals reach the 1000 mm limit), the accelerating one's grow beyond it once
  // the lag builds up (q rises, the intervals shrink).
  const auto steady = [](double s) { return 0.01 * s; };
  const auto accelerating = [](double s) { return 60.0 * (s / 6000.0) * (s / 6000.0); };
  const std::size_t n_steady = measurements_when_needed(adapt_config(), steady);
  const std::size_t n_accel = measurements_when_needed(adapt_config(), accelerating);
  EXPECT_LT(n_steady, n_accel);
  // With a fixed q the filter's covariance does not depend on the measured values: the same
  // schedule for both tools, which is what the adaptation changes.
  CreepConfig fixed = adapt_config();
  fixed.estimator.adapt_rate_noise = false;
  EXPECT_EQ(measurements_when_needed(fixed, steady), measurements_when_needed(fixed, accelerating));
}

TEST(CreepEstimatorAdapt, TheAdaptedNoiseSurvivesARestartAndANewToolStartsAfresh) {
  // GIVEN an adapting run saved after 8 measurements; WHEN a fresh process loads it and both
  // carry on with the same measurements; THEN the adapted q continues (not the configured one)
  // and the two stay identical.
  const CreepConfig c = adapt_config();
  ModuleRig a(c);
  for (int j = 1; j <= 8; ++j) {
    a.run_to(100.0 * j);
    a.measure(1e-5 * 1e4 * j * j);
  }
  const double adapted = a.module.compensator().rate_q();
  ASSERT_GT(std::fabs(std::log(adapted / 1e-9)), 0.5);  // moved from the configured q
  std::vector<std::byte> bytes(a.module.state_capacity());
  ASSERT_EQ(a.module.save_state(bytes), bytes.size());
  ModuleRig b(c);
  ASSERT_TRUE(b.module.load_state(bytes));
  EXPECT_EQ(b.module.compensator().rate_q(), adapted);
  b.path = 3000.0;
  b.advance(0.0);
  for (int j = 9; j <= 12; ++j) {
    for (int i = 0; i < 200; ++i) {
      a.advance(0.5);
      b.advance(0.5);
    }
    a.measure(1e-5 * 1e4 * j * j);
    b.measure(1e-5 * 1e4 * j * j);
    EXPECT_EQ(b.module.compensator().rate_q(), a.module.compensator().rate_q()) << j;
  }
  // A sister starts from the configured value again (no family here).
  testing::Rig r(c);
  for (int j = 1; j <= 8; ++j) {
    r.run_to(100.0 * j);
    r.measure({1e-5 * 1e4 * j * j});
  }
  ASSERT_GT(std::fabs(std::log(r.comp.rate_q() / 1e-9)), 0.5);
  r.tool_change(2, true);
  EXPECT_DOUBLE_EQ(r.comp.rate_q(), 1e-9);
}

TEST(CreepEstimatorAdapt, ConfigErrorsNameTheKey) {
  CreepConfig c = adapt_config();
  EXPECT_NO_THROW(validate(c));
  c.estimator.min_rate_noise_um_per_mm_per_sqrt_m = 0.02;  // above the max
  try {
    validate(c);
    ADD_FAILURE() << "min > max accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("creep.estimator.max_rate_noise_um_per_mm_per_sqrt_m: "
                                         "must be finite and at least"),
              std::string::npos)
        << e.what();
  }
  c = adapt_config();
  c.estimator.min_rate_noise_um_per_mm_per_sqrt_m = 0.0;
  c.estimator.adapt_window_measurements = 0.5;
  try {
    validate(c);
    ADD_FAILURE() << "accepted";
  } catch (const std::invalid_argument& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find("creep.estimator.min_rate_noise_um_per_mm_per_sqrt_m"), std::string::npos);
    EXPECT_NE(m.find("creep.estimator.adapt_window_measurements: must be 1..1000, got 0.5"),
              std::string::npos)
        << m;
  }
  c.estimator.adapt_rate_noise = false;  // off: not judged
  EXPECT_NO_THROW(validate(c));
}

}  // namespace
}  // namespace nccomp::core::creep

namespace nccomp::core::creep {
namespace {

/// family_config() learning the rate prior from finished tools (at least 2).
CreepConfig prior_config() {
  CreepConfig c = family_config();
  c.estimator.learn_rate_prior = true;
  c.estimator.family_min_tools = 2;
  c.estimator.family_prior_path_mm = 1000.0;
  return c;
}

TEST(CreepEstimatorFamilyPrior, AFirstToolAndAFamilyOfOneStartFromTheConfiguredPrior) {
  // GIVEN an empty family: the first tool's filter is today's (0 ± 0.01 µm/mm): 6 µm measured
  // at 100 mm gives wear 4 µm and rate 0.02 µm/mm (CreepEstimator's first test).
  testing::Rig r(prior_config());
  EXPECT_EQ(r.comp.state().rate_prior_sigma_um_per_mm[0], 0.0);
  r.run_to(100.0);
  r.measure({6.0});
  EXPECT_NEAR(r.comp.state().estimate_wear_um[0], 4.0, 1e-12);
  EXPECT_NEAR(r.comp.state().estimate_rate_um_per_mm[0], 0.02, 1e-14);
  // Its start rate: through the origin, 6/100 µm/mm.
  EXPECT_NEAR(r.comp.state().start_sxw[0] / r.comp.state().start_sxx, 0.06, 1e-15);
  // WHEN a sister replaces it, the family knows one tool: no spread yet, the sister starts from
  // the configured prior too.
  r.tool_change(2, true);
  EXPECT_EQ(r.comp.state().family_rate.tools, 1U);
  EXPECT_NEAR(r.comp.state().family_rate.rate_mean_um_per_mm[0], 0.06, 1e-15);
  double mean = 0.0;
  double sigma = 0.0;
  EXPECT_FALSE(r.comp.family_rate_prior(0, mean, sigma));
  EXPECT_EQ(r.comp.state().rate_prior_sigma_um_per_mm[0], 0.0);
  EXPECT_EQ(r.comp.state().start_sxx, 0.0);
}

TEST(CreepEstimatorFamilyPrior, TheFamilysStatisticsConvergeOnGeneratedToolLives) {
  // GIVEN 300 tools whose start rates are drawn from N(0.05, 0.01²) µm/mm, each measured at
  // 100..400 mm (σ = 1 µm) and replaced by its sister. One tool's start rate is Σs·w/Σs²
  // (Σs² = 300000 mm²), so the family's spread is sqrt(0.01² + 1/300000).
  CreepConfig c = prior_config();
  testing::Rig r(c);
  std::mt19937_64 rng(22);
  std::normal_distribution<double> start_rate(0.05, 0.01);
  std::normal_distribution<double> noise(0.0, 1.0);
  const int tools = 300;
  std::vector<double> fitted;  // each tool's start rate, computed here independently
  double from_mm = 0.0;
  for (int t = 0; t < tools; ++t) {
    const double a = start_rate(rng);
    double sxw = 0.0;
    for (int j = 1; j <= 4; ++j) {
      r.run_to(from_mm + 100.0 * j, 5.0);
      const double w = a * 100.0 * j + noise(rng);
      r.measure({w});
      sxw += 100.0 * j * w;
    }
    fitted.push_back(sxw / 300000.0);
    from_mm += 400.0;
    r.tool_change(t + 2, true);
  }
  ASSERT_EQ(r.comp.counters().measurements_accepted, 4U * tools);
  const auto& f = r.comp.state().family_rate;
  ASSERT_EQ(f.tools, static_cast<std::uint32_t>(tools));
  // THEN the running statistics are those of the tools' start rates (two-pass here) ...
  double mean = 0.0;
  for (const double x : fitted) mean += x / tools;
  double ss = 0.0;
  for (const double x : fitted) ss += (x - mean) * (x - mean);
  EXPECT_NEAR(f.rate_mean_um_per_mm[0], mean, 1e-12);
  EXPECT_NEAR(f.rate_m2[0], ss, 1e-9 * ss);
  // ... which converge on the generating distribution: the mean within 4 standard errors, the
  // spread within 20 % (its standard error is about 4 % at 300 tools).
  const double spread = std::sqrt(0.01 * 0.01 + 1.0 / 300000.0);
  EXPECT_NEAR(f.rate_mean_um_per_mm[0], 0.05, 4.0 * spread / std::sqrt(tools));
  double prior_mean = 0.0;
  double prior_sigma = 0.0;
  ASSERT_TRUE(r.comp.family_rate_prior(0, prior_mean, prior_sigma));
  EXPECT_NEAR(prior_sigma, spread, 0.2 * spread);
  EXPECT_NEAR(prior_sigma, std::sqrt(ss / (tools - 1) * (1.0 + 1.0 / tools)), 1e-15);
  // AND the new tool's filter starts from that prior: P = diag(1, σp²), x = (0, μ); over 100 mm
  // P⁻ = [[1 + 100²σp², 100σp²], [·, σp²]], so 7 µm measured there moves the wear from 100μ by
  // the gain P⁻_ww/(P⁻_ww + 1).
  EXPECT_EQ(r.comp.state().rate_prior_um_per_mm[0], prior_mean);
  EXPECT_EQ(r.comp.state().rate_prior_sigma_um_per_mm[0], prior_sigma);
  r.run_to(from_mm + 100.0, 5.0);
  r.measure({7.0});
  const double v = prior_sigma * prior_sigma;
  const double pww = 1.0 + 1e4 * v;
  const double pwr = 100.0 * v;
  const double nu = 7.0 - 100.0 * prior_mean;
  EXPECT_NEAR(r.comp.state().estimate_wear_um[0], 100.0 * prior_mean + pww / (pww + 1.0) * nu,
              1e-12);
  EXPECT_NEAR(r.comp.state().estimate_rate_um_per_mm[0], prior_mean + pwr / (pww + 1.0) * nu,
              1e-14);
}

TEST(CreepEstimatorFamilyPrior, AStartRateCountsOnlyTheFirstStretchOfALife) {
  // GIVEN family_prior_path_mm = 250: the measurements at 100 and 200 mm count, 300 does not.
  CreepConfig c = prior_config();
  c.estimator.family_prior_path_mm = 250.0;
  testing::Rig r(c);
  measure_every_100_mm(r, 0.0, 3, [](int j) { return j == 3 ? 100.0 : 5.0 * j; });
  EXPECT_NEAR(r.comp.state().start_sxx, 100.0 * 100.0 + 200.0 * 200.0, 1e-9);
  EXPECT_NEAR(r.comp.state().start_sxw[0] / r.comp.state().start_sxx, 0.05, 1e-15);
  // A tool first measured beyond it still gives its first measurement.
  testing::Rig late(c);
  late.run_to(500.0);
  late.measure({10.0});
  late.run_to(600.0);
  late.measure({12.0});
  EXPECT_NEAR(late.comp.state().start_sxw[0] / late.comp.state().start_sxx, 10.0 / 500.0, 1e-15);
}

TEST(CreepEstimatorFamilyPrior, ATightFamilyPriorDelaysANewToolsFirstRequest) {
  // GIVEN two finished tools with start rates 0.05 and 0.06 µm/mm (noise-free, measured at
  // 100..400 mm) and measured when needed (max_sigma_um = 2, q = 0): a new tool's σ after d mm
  // is sqrt(1 + d²·σr²), so its first request falls at d = sqrt(2² − 1)/σr.
  CreepConfig c = prior_config();
  c.interval.basis = IntervalBasis::kUncertainty;
  c.interval.max_sigma_um = 2.0;
  c.interval.min_interval_mm = 10.0;
  c.interval.max_interval_mm = 5000.0;
  testing::Rig r(c);
  // Today's prior (σr = 0.01) asks at sqrt(3)/0.01 mm.
  EXPECT_NEAR(r.comp.next_measurement_path_mm(), std::sqrt(3.0) / 0.01, 1e-3);
  measure_every_100_mm(r, 0.0, 4, [](int j) { return 0.05 * 100.0 * j; });
  r.tool_change(2, true);
  measure_every_100_mm(r, 400.0, 4, [](int j) { return 0.06 * 100.0 * j; });
  {
    // The fold and the new prior at the tool change allocate nothing (real-time safe).
    const std::array<Event, 1> change{ToolChange{r.now_ns, 3, true}};
    StepOutput out;
    nccomp::test::AllocationScope scope;
    r.comp.step(r.now_ns, change, out);
    EXPECT_EQ(scope.count(), 0U);
  }
  r.tool = 3;
  // Sample standard deviation of {0.05, 0.06}: 0.01/√2; the spread of a third: ·sqrt(3/2).
  const double sr = 0.01 / std::sqrt(2.0) * std::sqrt(1.5);
  EXPECT_NEAR(r.comp.state().rate_prior_um_per_mm[0], 0.055, 1e-15);
  EXPECT_NEAR(r.comp.state().rate_prior_sigma_um_per_mm[0], sr, 1e-15);
  EXPECT_NEAR(r.comp.next_measurement_path_mm(), std::sqrt(3.0) / sr, 1e-3);
  // Without learning the prior the same family leaves today's schedule.
  CreepConfig off = c;
  off.estimator.learn_rate_prior = false;
  testing::Rig o(off);
  measure_every_100_mm(o, 0.0, 4, [](int j) { return 0.05 * 100.0 * j; });
  o.tool_change(2, true);
  measure_every_100_mm(o, 400.0, 4, [](int j) { return 0.06 * 100.0 * j; });
  o.tool_change(3, true);
  EXPECT_EQ(o.comp.state().family_rate.tools, 2U);
  EXPECT_NEAR(o.comp.next_measurement_path_mm(), std::sqrt(3.0) / 0.01, 1e-3);
}

TEST(CreepEstimatorFamilyPrior, TheFamilyAndTheToolsPriorSurviveARestart) {
  CreepConfig c = prior_config();
  testing::Rig r(c);
  measure_every_100_mm(r, 0.0, 4, [](int j) { return 0.05 * 100.0 * j; });
  r.tool_change(2, true);
  measure_every_100_mm(r, 400.0, 4, [](int j) { return 0.06 * 100.0 * j; });
  r.tool_change(3, true);
  r.run_to(900.0);
  r.measure({5.0});  // the new tool has a start sum of its own
  const CreepState saved = r.comp.export_state();
  WearCompensator b;
  b.configure(c);
  b.import_state(saved);
  EXPECT_EQ(b.state().family_rate.tools, 2U);
  EXPECT_EQ(b.state().family_rate.rate_mean_um_per_mm[0], saved.family_rate.rate_mean_um_per_mm[0]);
  EXPECT_EQ(b.state().family_rate.rate_m2[0], saved.family_rate.rate_m2[0]);
  EXPECT_EQ(b.state().rate_prior_sigma_um_per_mm[0], saved.rate_prior_sigma_um_per_mm[0]);
  EXPECT_EQ(b.state().start_sxx, 100.0 * 100.0);
  // Corrupt statistics are refused with the state, naming the field.
  CreepState bad = saved;
  bad.family_rate.rate_m2[0] = -1.0;
  EXPECT_EQ(std::string_view(b.check_state(bad).field), "family_rate");
  bad = saved;
  bad.rate_prior_sigma_um_per_mm[0] = std::numeric_limits<double>::quiet_NaN();
  EXPECT_EQ(std::string_view(b.check_state(bad).field), "rate_prior_sigma_um_per_mm");
  bad = saved;
  bad.start_sxx = -1.0;
  EXPECT_EQ(std::string_view(b.check_state(bad).field), "start_sxx");
}

TEST(CreepEstimatorFamilyPrior, AStateOfLayoutVersion5IsConverted) {
  // A version-5 state (the current one up to the family's noise) with its adoption and residual
  // shift, and without them: the filter, the family's noise and the remembered tools are kept;
  // the rate prior's fields start empty.
  CreepConfig c = prior_config();
  c.estimator.learn_rate_noise = true;
  ModuleRig m(c);
  CreepState s;
  s.edge_points = 1;
  s.tool = 1;
  s.cut_path_mm = 130.0;
  s.creep_path_mm = 130.0;
  s.committed_um[0] = 22.0;
  s.measured_um[0] = 22.0;
  s.measurements = 2;
  s.last_measurement_cut_path_mm = 120.0;
  s.last_measurement_creep_path_mm = 120.0;
  s.estimate_wear_um[0] = 21.5;
  s.estimate_rate_um_per_mm[0] = 0.1;
  s.estimate_p_ww[0] = 0.5;
  s.estimate_p_wr[0] = 0.001;
  s.estimate_p_rr[0] = 1e-5;
  s.estimate_path_mm = 120.0;
  s.estimate_valid = true;
  s.rate_q = 3e-10;
  s.family.tools = 2;
  s.family.rate_q_sum = 5e-10;
  s.version = 5;
  CreepState remembered;
  remembered.edge_points = 1;
  remembered.tool = 4;
  remembered.measured_um[0] = 9.0;
  remembered.version = 5;
  v5::ToolMemory mem;
  mem.tool[1] = 4;
  mem.last_use[1] = 1;
  mem.use_counter = 1;
  std::memcpy(mem.state[1].bytes.data(), &remembered, v5::kStateBytes);
  CreepModule::ResidualShift residual;
  residual.shift_um[3] = 1.5;
  AdoptedOutputs none;
  std::vector<std::byte> bytes(v5::kModuleStateBytes + sizeof none + sizeof residual);
  std::memcpy(bytes.data(), &s, v5::kStateBytes);
  std::memcpy(bytes.data() + v5::kStateBytes, &mem, sizeof mem);
  std::memcpy(bytes.data() + v5::kModuleStateBytes, &none, sizeof none);
  std::memcpy(bytes.data() + v5::kModuleStateBytes + sizeof none, &residual, sizeof residual);
  ASSERT_NE(bytes.size(), m.module.state_capacity());
  {
    nccomp::test::AllocationScope scope;
    ASSERT_TRUE(m.module.load_state(bytes));
    EXPECT_EQ(scope.count(), 0U);
  }
  const auto& st = m.module.compensator().state();
  EXPECT_EQ(st.version, CreepState::kVersion);
  EXPECT_TRUE(st.estimate_valid);
  EXPECT_EQ(st.estimate_wear_um[0], 21.5);
  EXPECT_EQ(st.rate_q, 3e-10);
  EXPECT_EQ(st.family.tools, 2U);
  EXPECT_EQ(st.family.rate_q_sum, 5e-10);
  EXPECT_EQ(st.start_sxx, 0.0);
  EXPECT_EQ(st.rate_prior_sigma_um_per_mm[0], 0.0);
  EXPECT_EQ(st.family_rate.tools, 0U);
  EXPECT_EQ(m.module.compensator().tool_memory().state[1].measured_um[0], 9.0);
  EXPECT_EQ(m.module.compensator().tool_memory().state[1].version, CreepState::kVersion);
  // The residual shift came along: saved again, it is in the current layout's bytes.
  std::vector<std::byte> again(m.module.state_capacity());
  ASSERT_EQ(m.module.save_state(again), again.size());
  CreepModule::ResidualShift back;
  std::memcpy(&back, again.data() + again.size() - sizeof back, sizeof back);
  EXPECT_EQ(back.shift_um[3], 1.5);
  // Without the residual shift, and without the adoption, too.
  ModuleRig m2(c);
  EXPECT_TRUE(m2.module.load_state(std::span(bytes).first(v5::kModuleStateBytes + sizeof none)));
  ModuleRig m3(c);
  EXPECT_TRUE(m3.module.load_state(std::span(bytes).first(v5::kModuleStateBytes)));
  EXPECT_EQ(m3.module.compensator().state().family.tools, 2U);
  // A corrupt bool is refused, nothing changes.
  ModuleRig fresh(c);
  bytes[offsetof(CreepState, estimate_valid)] = std::byte{2};
  EXPECT_FALSE(fresh.module.load_state(bytes));
  EXPECT_EQ(fresh.module.compensator().state().measurements, 0U);
}

TEST(CreepEstimatorFamilyPrior, ItsPathIsChecked) {
  CreepConfig c = prior_config();
  c.estimator.family_prior_path_mm = 0.0;
  try {
    validate(c);
    FAIL() << "accepted family_prior_path_mm = 0";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("creep.estimator.family_prior_path_mm"), std::string::npos)
        << e.what();
  }
}

}  // namespace
}  // namespace nccomp::core::creep
