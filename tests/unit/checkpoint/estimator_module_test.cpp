// S1's estimator through the engine module: the state bytes of layout 2 and the conversion of
// layout 1, the status values and the allocation-free engine step.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <memory>
#include <string_view>
#include <vector>

#include "core/checkpoint/module.hpp"
#include "core/engine/engine.hpp"
#include "tests/support/alloc_counter.hpp"
#include "tests/unit/checkpoint/helpers.hpp"

namespace nccomp::core::checkpoint {
namespace {

using test::line_plan;
using test::part_start;
using test::probe;
using test::sample;

std::vector<engine::RegisterSpec> registers(std::size_t n) {
  std::vector<engine::RegisterSpec> r;
  LimiterConfig lim;
  lim.max_abs_um = 100.0;
  lim.max_step_um = 50.0;
  lim.max_rate_um_per_s = 1e6;
  r.push_back({"d19_radius_wear", engine::RegisterKind::kToolRadiusWear, lim});
  for (std::size_t i = 0; i < n; ++i) {
    r.push_back({"cp" + std::to_string(i), engine::RegisterKind::kCheckpoint, lim});
  }
  return r;
}

CompensatorConfig estimator_config() {
  CompensatorConfig c;
  c.finishing_tool = 12;
  c.register_base = 1;
  c.active_register = 0;
  c.dead_band_um = 0.0;
  c.probe_repeatability_um = 0.0;
  c.write_threshold_um = 0.0;
  c.apply = ApplyMode::kStep;
  c.estimator.enabled = true;
  c.estimator.measurement_sigma_um = 1.0;
  c.estimator.part_noise_um = 0.5;
  return c;
}

std::unique_ptr<CheckpointModule> attached(std::size_t n) {
  auto m = std::make_unique<CheckpointModule>(estimator_config(), line_plan(n));
  const auto regs = registers(n);
  m->attach(engine::RegisterTable(regs));
  return m;
}

// Part n: start, then readings of the errors e (the wall as cut: e + the applied offset).
void part(CheckpointModule& m, std::int32_t n, const std::vector<double>& e) {
  StepOutput out;
  const Event start = part_start(n);
  m.step(0, {&start, 1}, out);
  std::vector<Event> ev;
  for (std::size_t i = 0; i < e.size(); ++i) {
    ev.emplace_back(
        probe(n, static_cast<std::int32_t>(i), e[i] + m.compensator().point(i).applied_um));
  }
  out.clear();
  m.step(0, ev, out);
}

// Layout 1 of the state bytes, written out here as the file had it (not the module's structs).
struct HeaderV1 {
  std::uint32_t magic;
  std::uint32_t version;
  std::uint32_t count;
  std::int32_t part;
  std::int64_t part_counter;
};
struct RecordV1 {
  double learned_um;
  double offset_um;
  double applied_um;
  std::uint32_t count;
  std::uint32_t history_n;
  double history[16];
};

// GIVEN the bytes of a layout-1 state (before the estimator: M = 6 after 3 readings)
// WHEN a module with the estimator loads them and reads 10 at the next part
// THEN nothing is dropped (offsets, counters, history), and the filter starts from M with the
//      variance σ²: the estimate moves by (σ² + q)/(2σ² + q) of the innovation.
TEST(CheckpointEstimatorModule, AStateOfLayoutVersion1IsConvertedAndTheFilterStartsFromIt) {
  std::vector<std::byte> bytes(sizeof(HeaderV1) + 2 * sizeof(RecordV1));
  const HeaderV1 h{0x31504B43, 1, 2, 3, 3};
  std::memcpy(bytes.data(), &h, sizeof h);
  for (int i = 0; i < 2; ++i) {
    RecordV1 r{};
    r.learned_um = 6.0 + i;
    r.offset_um = -(6.0 + i);
    r.applied_um = -(6.0 + i);
    r.count = 3;
    r.history_n = 3;
    r.history[0] = 4.0;
    r.history[1] = 6.0;
    r.history[2] = 8.0;
    std::memcpy(bytes.data() + sizeof h + static_cast<std::size_t>(i) * sizeof r, &r, sizeof r);
  }
  auto m = attached(2);
  ASSERT_TRUE(m->load_state(bytes));
  const auto& c = m->compensator();
  EXPECT_EQ(c.part_counter(), 3);
  EXPECT_DOUBLE_EQ(c.register_value_um(1), -7.0);
  EXPECT_EQ(c.point(1).history_n, 3U);
  EXPECT_EQ(c.point(0).filter_n, 0U);
  part(*m, 4, {10.0, 7.0});
  const double k = (1.0 + 0.25) / (2.0 + 0.25);
  EXPECT_NEAR(c.learned_um(0), 6.0 + k * 4.0, 1e-12);
  EXPECT_NEAR(c.learned_um(1), 7.0, 1e-12);
  EXPECT_NEAR(c.point(0).variance_um2, (1.0 - k) * 1.25, 1e-12);
  // A layout-1 file of the wrong length is refused.
  bytes.pop_back();
  EXPECT_FALSE(attached(2)->load_state(bytes));
}

// GIVEN a module after 6 parts with the estimator, its state saved (layout 2)
// WHEN a fresh module loads the bytes (a restart) and both see part 7
// THEN they agree exactly (the filter continued), and the bytes name layout 4.
TEST(CheckpointEstimatorModule, TheFiltersStateSurvivesARestartThroughTheBytes) {
  auto a = attached(2);
  for (int n = 1; n <= 6; ++n) part(*a, n, {2.0 + 0.5 * n, -3.0 + (n % 2)});
  std::vector<std::byte> buf(a->state_capacity());
  ASSERT_EQ(a->save_state(buf), buf.size());
  std::uint32_t version = 0;
  std::memcpy(&version, buf.data() + 4, sizeof version);
  EXPECT_EQ(version, 4U);
  auto b = attached(2);
  ASSERT_TRUE(b->load_state(buf));
  for (std::size_t i = 0; i < 2; ++i) {
    EXPECT_EQ(b->compensator().point(i).variance_um2, a->compensator().point(i).variance_um2);
    EXPECT_EQ(b->compensator().point(i).filter_n, 6U);
  }
  part(*a, 7, {9.0, -1.0});
  part(*b, 7, {9.0, -1.0});
  for (std::size_t i = 0; i < 2; ++i) {
    EXPECT_EQ(b->compensator().learned_um(i), a->compensator().learned_um(i));
    EXPECT_EQ(b->compensator().register_value_um(i), a->compensator().register_value_um(i));
  }
}

double status_value(const CheckpointModule& m, const char* key) {
  std::array<engine::StatusValue, engine::kMaxStatusValues> v{};
  const std::size_t n = m.status(v);
  for (std::size_t i = 0; i < n; ++i) {
    if (std::string_view(v[i].key) == key) return v[i].value;
  }
  ADD_FAILURE() << "no status value " << key;
  return -1e300;
}

// GIVEN two checkpoints, the first read once, the second three times
// THEN the status shows the focus checkpoint's estimate, its σ predicted to the next part
//      sqrt(P + q), the next reading's weight, and the largest σ over the table; 20 values.
TEST(CheckpointEstimatorModule, StatusShowsTheEstimateItsSigmaAndTheGain) {
  auto m = attached(2);
  std::array<engine::StatusValue, engine::kMaxStatusValues> v{};
  ASSERT_EQ(m->status(v), 20U);
  EXPECT_TRUE(std::isnan(status_value(*m, "sigma_max_um")));
  part(*m, 1, {3.0, 5.0});
  part(*m, 2, {3.0, 5.0});
  StepOutput out;
  const Event start = part_start(3);
  m->step(0, {&start, 1}, out);
  out.clear();
  const Event only_second = probe(3, 1, 5.0 + m->compensator().point(1).applied_um);
  m->step(0, {&only_second, 1}, out);
  // Checkpoint 1: P1 = σ² = 1; P2 = (1 + q)·σ²/(1 + q + σ²) = 1.25/2.25; P3 likewise from P2.
  const double q = 0.25;
  const double p2 = 1.25 / 2.25;
  const double p3 = (p2 + q) / (p2 + q + 1.0);
  EXPECT_EQ(status_value(*m, "checkpoint"), 1.0);
  EXPECT_NEAR(status_value(*m, "checkpoint_estimate_um"), 5.0, 1e-12);
  EXPECT_NEAR(status_value(*m, "checkpoint_sigma_um"), std::sqrt(p3 + q), 1e-12);
  EXPECT_NEAR(status_value(*m, "checkpoint_gain"), (p3 + q) / (p3 + q + 1.0), 1e-12);
  // Checkpoint 0 was read twice: its σ is the larger one.
  EXPECT_NEAR(status_value(*m, "sigma_max_um"), std::sqrt(p2 + q), 1e-12);
}

// The engine's step with the estimator on (readings, samples, the state saved) allocates and frees
// nothing.
TEST(CheckpointEstimatorModule, EngineStepAllocatesNothing) {
  auto eng = std::make_unique<engine::Engine>();
  std::vector<std::unique_ptr<engine::Module>> mods;
  mods.push_back(std::make_unique<CheckpointModule>(estimator_config(), line_plan(8)));
  eng->configure(registers(8), std::move(mods));
  std::vector<Event> probes;
  for (int i = 0; i < 8; ++i) probes.emplace_back(probe(1, i, 1.0 + i));
  const Event start = part_start(1);
  StepOutput out;
  std::vector<std::byte> buf(eng->state_capacity());
  nccomp::test::AllocationScope scope;
  for (int p = 0; p < 20; ++p) {
    out.clear();
    eng->step(0, {&start, 1}, out);
    for (int k = 0; k < 100; ++k) {
      const Event s = sample(k, 0, -5, k, 12, k * 1'000'000);
      out.clear();
      eng->step(k * 1'000'000, {&s, 1}, out);
    }
    out.clear();
    eng->step(0, probes, out);
    (void)eng->export_state(buf);
  }
  EXPECT_EQ(scope.count(), 0U);
  EXPECT_EQ(scope.frees(), 0U);
}

}  // namespace
}  // namespace nccomp::core::checkpoint
