// S1's trim handover with a model whose terms read inputs other than the cut path (temperature,
// time since the warm start): each checkpoint's residual takes the trims, old and new, as they
// were where that checkpoint was cut, not as at the switch (issue 19, item 1).
#include <gtest/gtest.h>

#include <cmath>
#include <cstddef>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "core/checkpoint/module.hpp"
#include "core/engine/engine.hpp"
#include "core/model/model.hpp"
#include "core/model/model_module.hpp"
#include "tests/unit/checkpoint/helpers.hpp"

namespace nccomp::core::checkpoint {
namespace {

namespace cm = core::model;
using test::line_plan;
using test::part_start;
using test::probe;
using test::sample;

constexpr std::size_t kPoints = 3;
constexpr TimeNs kCycleNs = 100'000'000;  // 0.1 s per cycle: a time term moves visibly

std::vector<engine::RegisterSpec> registers() {
  std::vector<engine::RegisterSpec> r;
  LimiterConfig lim;
  lim.max_abs_um = 100.0;
  lim.max_step_um = 100.0;
  lim.max_rate_um_per_s = 1e7;
  r.push_back({"d19_radius_wear", engine::RegisterKind::kToolRadiusWear, lim});
  for (std::size_t i = 0; i < kPoints; ++i) {
    r.push_back({"cp" + std::to_string(i), engine::RegisterKind::kCheckpoint, lim});
  }
  return r;
}

CompensatorConfig s1_config() {
  CompensatorConfig c;
  c.finishing_tool = 12;
  c.register_base = 1;
  c.active_register = 0;
  c.ewma_weight = 1.0;
  c.dead_band_um = 0.0;
  c.probe_repeatability_um = 0.0;
  c.write_threshold_um = 0.0;
  c.apply = ApplyMode::kStep;
  return c;
}

/// A model of one linear term on `column` (value − center, `um_per_unit`), trimming the live
/// register with gain −1, re-evaluated every cycle.
std::unique_ptr<cm::ModelModule> linear_model(cm::Column column, double center,
                                              double um_per_unit) {
  cm::Term t;
  t.spec.name = "effect";
  t.spec.form = cm::Form::kLinear;
  t.spec.column = static_cast<int>(column);
  t.spec.center = center;
  t.groups = {{0.0, 0.0}};
  t.coef = {um_per_unit};
  cm::ModelApply a;
  a.register_index = 0;
  a.gain = -1.0;
  return std::make_unique<cm::ModelModule>(cm::Model({}, {t}), std::vector{a}, true);
}

std::unique_ptr<engine::Engine> make_engine(std::unique_ptr<cm::ModelModule> model) {
  auto e = std::make_unique<engine::Engine>();
  std::vector<std::unique_ptr<engine::Module>> mods;
  mods.push_back(std::make_unique<CheckpointModule>(s1_config(), line_plan(kPoints)));
  if (model) mods.push_back(std::move(model));
  e->configure(registers(), std::move(mods));
  return e;
}

const CheckpointCompensator& s1(const engine::Engine& e) {
  return dynamic_cast<const CheckpointModule&>(e.module(0)).compensator();
}

/// The temperature while the tool is at x: one degree more every 10 mm, constant around each
/// checkpoint (10, 20, 30 mm): 21, 22, 23 °C where they are cut.
double temp_at(double x_mm) { return 20.0 + std::floor((x_mm + 5.0) / 10.0); }

struct Cut {
  std::vector<double> temp_c;  // at each checkpoint's cut
  std::vector<double> time_s;  // machine time at each checkpoint's cut
};

/// Cuts part `part` along x = 0…40 mm, one cycle per mm, with the temperature temp_at(x).
Cut cut_part(engine::Engine& e, std::int32_t part, TimeNs& t) {
  StepOutput out;
  std::vector<Event> ev = {part_start(part)};
  e.step(t += kCycleNs, ev, out);
  Cut c;
  for (int x = 0; x <= 40; ++x) {
    AxisSample s = sample(x, 0, -5, x, 12, t += kCycleNs);
    s.cutting = true;
    ev = {TemperatureSample{t, 0, temp_at(x)}, s};
    e.step(t, ev, out);
    if (x % 10 == 0 && x > 0 && x < 40) {
      c.temp_c.push_back(temp_at(x));
      c.time_s.push_back(e.context().machine_time_s());
    }
  }
  return c;
}

std::vector<std::byte> state_of(const engine::Engine& e) {
  std::vector<std::byte> buf(e.state_capacity());
  buf.resize(e.export_state(buf));
  return buf;
}

/// Hands `state` to `e` in a cycle at swap_temp_c, 2 s after t.
void hand_over(engine::Engine& e, const std::vector<std::byte>& state, TimeNs& t,
               double swap_temp_c) {
  ASSERT_TRUE(e.import_state(state, t));
  StepOutput out;
  t += 20 * kCycleNs;
  std::vector<Event> ev = {TemperatureSample{t, 0, swap_temp_c}};
  e.step(t, ev, out);
  ASSERT_EQ(e.counters().handover_rebases, 1U);
}

// GIVEN S1 alone cut part 1 with checkpoints at 21, 22, 23 °C and probed an error of 2 µm/°C
//      above 20 °C (2, 4, 6 µm), and the machine is at 25 °C when a model of exactly that effect
//      (trim −2 µm/°C × (temp_c − 20)) is loaded with S1's state
// WHEN the handover rebases S1
// THEN each residual takes the trim at its own checkpoint's 21, 22, 23 °C: 0 (the model explains
//      the error), not the trim at 25 °C (−8, −6, −4), and part 2 is cut with the whole −2 µm/°C.
TEST(HandoverInputs, ALoadTakesAThermalTrimAtEachCheckpointsOwnTemperature) {
  constexpr double kUmPerC = 2.0;
  auto a = make_engine(nullptr);
  TimeNs t = 0;
  const Cut cut = cut_part(*a, 1, t);
  ASSERT_EQ(cut.temp_c, (std::vector<double>{21.0, 22.0, 23.0}));
  StepOutput out;
  std::vector<Event> ev;
  for (std::size_t i = 0; i < kPoints; ++i) {
    ev.push_back(probe(1, static_cast<std::int32_t>(i), kUmPerC * (cut.temp_c[i] - 20.0)));
  }
  a->step(t += kCycleNs, ev, out);
  ASSERT_NEAR(s1(*a).learned_um(2), 6.0, 1e-9);

  auto b = make_engine(linear_model(cm::Column::kTemp, 20.0, kUmPerC));
  hand_over(*b, state_of(*a), t, 25.0);
  for (std::size_t i = 0; i < kPoints; ++i) {
    EXPECT_NEAR(s1(*b).learned_um(i), 0.0, 1e-9) << i;
    EXPECT_NEAR(s1(*b).register_value_um(i), 0.0, 1e-9) << i;
  }
  // Part 2 at 21…23 °C: S1's share 0, the trim the whole −2 µm/°C.
  ev = {part_start(2)};
  b->step(t += kCycleNs, ev, out);
  for (int x = 0; x <= 40; ++x) {
    AxisSample s = sample(x, 0, -5, x, 12, t += kCycleNs);
    s.cutting = true;
    ev = {TemperatureSample{t, 0, temp_at(x)}, s};
    b->step(t, ev, out);
    if (x % 10 == 5) {  // between two checkpoints: the model's trim has followed the temperature
      const engine::RegisterState r = b->register_state(0);
      EXPECT_NEAR(r.target_um + r.trim_um, -kUmPerC * (temp_at(x) - 20.0), 1e-9) << x;
    }
  }
}

// GIVEN S1 alone cut part 1 (checkpoints passed 1.1, 2.1, 3.1 s after the warm start) and
//      probed an error growing 1.5 µm per second since the warm start; the switch comes 2 s
//      after the last cut
// WHEN a model of exactly that effect (time_s, −1.5 µm/s) is loaded with S1's state
// THEN each residual takes the trim at its checkpoint's own machine time: 0.
TEST(HandoverInputs, ALoadTakesATimeTrimAtEachCheckpointsOwnMachineTime) {
  constexpr double kUmPerS = 1.5;
  auto a = make_engine(nullptr);
  TimeNs t = 0;
  const Cut cut = cut_part(*a, 1, t);
  ASSERT_EQ(cut.time_s.size(), kPoints);
  ASSERT_GT(cut.time_s[1] - cut.time_s[0], 0.5);
  StepOutput out;
  std::vector<Event> ev;
  for (std::size_t i = 0; i < kPoints; ++i) {
    ev.push_back(probe(1, static_cast<std::int32_t>(i), kUmPerS * cut.time_s[i]));
  }
  a->step(t += kCycleNs, ev, out);

  auto b = make_engine(linear_model(cm::Column::kTime, 0.0, kUmPerS));
  hand_over(*b, state_of(*a), t, 23.0);
  for (std::size_t i = 0; i < kPoints; ++i) {
    EXPECT_NEAR(s1(*b).learned_um(i), 0.0, 1e-9) << i;
  }
}

// GIVEN S1 and a thermal model (trim −2 µm/°C × (temp_c − 20)) cut part 1 at 21, 22, 23 °C on a
//      machine whose error is 3 µm/°C: the probe reads the 1 µm/°C the model missed (1, 2, 3 µm)
// WHEN the model is taken out (a rollback) with S1's state saved at 24 °C
// THEN S1 takes back the trim each checkpoint was cut with (−2, −4, −6 µm), not the −8 µm of
//      the switch: it holds the whole error where it was cut, 3, 6, 9 µm (not 9, 10, 11).
TEST(HandoverInputs, ARollbackTakesTheOldTrimAtEachCheckpointsOwnTemperature) {
  constexpr double kModelUmPerC = 2.0;
  constexpr double kTrueUmPerC = 3.0;
  auto b = make_engine(linear_model(cm::Column::kTemp, 20.0, kModelUmPerC));
  TimeNs t = 0;
  const Cut cut = cut_part(*b, 1, t);
  StepOutput out;
  std::vector<Event> ev;
  for (std::size_t i = 0; i < kPoints; ++i) {
    // Cut with the trim −2 µm/°C at its own temperature, S1's offset 0 (nothing learned yet).
    const double rise_c = cut.temp_c[i] - 20.0;
    ev.push_back(probe(1, static_cast<std::int32_t>(i), (kTrueUmPerC - kModelUmPerC) * rise_c));
  }
  b->step(t += kCycleNs, ev, out);
  ASSERT_NEAR(s1(*b).learned_um(0), 1.0, 1e-9);

  auto c = make_engine(nullptr);
  hand_over(*c, state_of(*b), t, 25.0);
  for (std::size_t i = 0; i < kPoints; ++i) {
    EXPECT_NEAR(s1(*c).learned_um(i), kTrueUmPerC * (cut.temp_c[i] - 20.0), 1e-9) << i;
    EXPECT_NEAR(s1(*c).register_value_um(i), -kTrueUmPerC * (cut.temp_c[i] - 20.0), 1e-9) << i;
  }
}

}  // namespace
}  // namespace nccomp::core::checkpoint
