// The derived lag input (core/engine/input_lag.hpp): the exact step against its closed form,
// agreement with the analysis's lag terms (core/model advance_state), validation, the state across
// a restart, and allocation-free updates.
#include "core/engine/input_lag.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <stdexcept>
#include <vector>

#include "core/engine/engine.hpp"
#include "core/model/model.hpp"
#include "tests/support/alloc_counter.hpp"

namespace nccomp::core::engine {
namespace {

TemperatureSample sample(double t_s, std::uint8_t sensor, double v) {
  return TemperatureSample{from_seconds(t_s), sensor, v};
}

// One cycle: the events in, the lag's published value (NaN if it published none).
double cycle(InputLags& lags, double t_s, const std::vector<Event>& in, std::uint8_t out_sensor) {
  std::array<Event, 8> out{};
  const std::size_t n = lags.update(from_seconds(t_s), in, out, 0);
  for (std::size_t i = 0; i < n; ++i) {
    const auto& s = std::get<TemperatureSample>(out[i]);
    if (s.sensor == out_sensor) return s.temperature_c;
  }
  return std::nan("");
}

InputLags one_lag(double tau_s) {
  InputLags lags;
  const std::vector<InputLagSpec> specs{{5, 40, tau_s}};
  lags.configure(specs);
  return lags;
}

TEST(InputLag, StepInputFollowsTheClosedFormAtIrregularIntervals) {
  const double tau = 1800.0;
  InputLags lags = one_lag(tau);
  EXPECT_TRUE(std::isnan(cycle(lags, 0.0, {}, 40)));  // nothing before the input's first value
  EXPECT_DOUBLE_EQ(cycle(lags, 5.0, {sample(5.0, 5, 20.0)}, 40), 20.0);  // starts at it
  // The input steps to 30 at t = 10 s and stays there (no further samples: the held value).
  EXPECT_DOUBLE_EQ(cycle(lags, 10.0, {sample(10.0, 5, 30.0)}, 40), 20.0);
  for (const double t : {10.001, 17.0, 400.0, 401.5, 3000.0, 9000.0}) {
    const double expected = 30.0 + (20.0 - 30.0) * std::exp(-(t - 10.0) / tau);
    EXPECT_NEAR(cycle(lags, t, {}, 40), expected, 1e-12) << "t = " << t;
  }
}

TEST(InputLag, AgreesWithTheAnalysisLagTermOnTheSameSeries) {
  // nccomp analyze's lag term (Form::kLag) over the same (time, value) series: within 1e-9.
  const double tau = 1234.5;
  InputLags lags = one_lag(tau);
  model::TermSpec spec;
  spec.form = model::Form::kLag;
  spec.column = model::kStandardColumns;  // the first extra column
  spec.scale = tau;
  const std::vector<model::TermSpec> specs{spec};
  model::EvalState state;
  state.lag_value.assign(1, std::nan(""));
  state.lag_input.assign(1, std::nan(""));
  std::mt19937 rng(22);
  std::uniform_real_distribution<double> step(0.5, 120.0);
  std::normal_distribution<double> walk(0.0, 0.3);
  double t = 100.0;
  double u = 21.0;
  double max_diff = 0.0;
  for (int i = 0; i < 2000; ++i) {
    t += step(rng);
    u += walk(rng);
    model::Row row = model::unknown_row();
    row[static_cast<std::size_t>(model::Column::kTime)] = t;
    row[model::kStandardColumns] = u;
    model::advance_state(specs, row, state);
    const double daemon = cycle(lags, t, {sample(t, 5, u)}, 40);
    max_diff = std::max(max_diff, std::abs(daemon - state.lag_value[0]));
  }
  EXPECT_LE(max_diff, 1e-9);
  EXPECT_GT(std::abs(lags.value(0) - u), 0.0);  // a lag, not a copy of the input
}

TEST(InputLag, ConfigurationIsValidated) {
  InputLags lags;
  const auto refused = [&lags](std::vector<InputLagSpec> specs, const char* what) {
    try {
      lags.configure(specs);
      ADD_FAILURE() << "accepted, expected: " << what;
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find(what), std::string::npos) << e.what();
    }
  };
  refused({{5, 40, 0.0}}, "lags[0].tau_s");
  refused({{5, 40, -3.0}}, "lags[0].tau_s");
  refused({{5, 40, std::nan("")}}, "lags[0].tau_s");
  refused({{5, 40, INFINITY}}, "lags[0].tau_s");
  refused({{5, 5, 10.0}}, "lags[0].sensor: equals its input");
  refused({{5, 40, 10.0}, {6, 40, 20.0}},
          "lags[1].sensor: sensor 40 is already the output of lags[0]");
  refused({{5, 40, 10.0}, {40, 41, 20.0}}, "lags[0].sensor: sensor 40 is the input of lags[1]");
  refused(std::vector<InputLagSpec>(kMaxInputLags + 1, InputLagSpec{1, 2, 1.0}), "at most 16");
}

TEST(InputLag, RestartKeepsTheLagAndDecaysOverAKnownDowntime) {
  const double tau = 600.0;
  InputLags a = one_lag(tau);
  InputLags reference = one_lag(tau);
  for (const double t : {0.0, 30.0, 60.0}) {
    const double u = 20.0 + t / 10.0;  // 20, 23, 26
    cycle(a, t, {sample(t, 5, u)}, 40);
    cycle(reference, t, {sample(t, 5, u)}, 40);
  }
  std::array<std::byte, InputLags::kStateBytes> buf{};
  ASSERT_EQ(a.save(buf), InputLags::kStateBytes);

  // Same boot: the clock went on 300 s; the lag decays toward the held 26 over the downtime.
  InputLags b = one_lag(tau);
  ASSERT_TRUE(b.load(buf, from_seconds(360.0)));
  const double after = cycle(b, 360.0, {}, 40);
  EXPECT_NEAR(after, cycle(reference, 360.0, {}, 40), 1e-12);
  EXPECT_GT(after, 20.0);  // not reset to a new first value

  // A reboot (clock back): the value is kept as saved.
  InputLags c = one_lag(tau);
  ASSERT_TRUE(c.load(buf, from_seconds(1.0)));
  EXPECT_DOUBLE_EQ(c.value(0), a.value(0));

  // Another time constant: that lag starts afresh from its input's next value.
  InputLags d = one_lag(2.0 * tau);
  ASSERT_TRUE(d.load(buf, from_seconds(360.0)));
  EXPECT_TRUE(std::isnan(d.value(0)));

  // Bytes that are not a state change nothing.
  buf[0] = std::byte{0};
  EXPECT_FALSE(b.load(buf, from_seconds(400.0)));
  EXPECT_DOUBLE_EQ(b.value(0), after);
}

TEST(InputLag, UpdateIsAllocationFree) {
  InputLags lags = one_lag(100.0);
  std::array<Event, 4> in{sample(1.0, 5, 20.0), sample(1.0, 6, 3.0)};
  std::array<Event, 8> out{};
  std::array<std::byte, InputLags::kStateBytes> buf{};
  test::AllocationScope scope;
  for (int i = 1; i < 100; ++i) {
    (void)lags.update(from_seconds(i), std::span<const Event>(in.data(), 2), out, 0);
  }
  (void)lags.save(buf);
  (void)lags.load(buf, from_seconds(200.0));
  EXPECT_EQ(scope.count(), 0U);
}

// A module that keeps the last sample of one sensor it was handed (what S3 or the model sees).
class SensorWatcher final : public Module {
 public:
  explicit SensorWatcher(std::uint8_t sensor) : sensor_(sensor) {}
  std::string_view name() const noexcept override { return "watcher"; }
  void attach(const RegisterTable& /*registers*/) override {}
  void step(TimeNs /*now_ns*/, std::span<const Event> events,
            StepOutput& /*out*/) noexcept override {
    for (const Event& e : events) {
      if (const auto* t = std::get_if<TemperatureSample>(&e); t && t->sensor == sensor_) {
        last = t->temperature_c;
      }
    }
  }
  double last{std::nan("")};

 private:
  std::uint8_t sensor_;
};

std::unique_ptr<Engine> lag_engine(double tau_s, SensorWatcher*& watcher) {
  auto e = std::make_unique<Engine>();
  auto w = std::make_unique<SensorWatcher>(40);
  watcher = w.get();
  std::vector<std::unique_ptr<Module>> mods;
  mods.push_back(std::move(w));
  EngineOptions options;
  options.lags = {{5, 40, tau_s}};
  e->configure({}, std::move(mods), options);
  return e;
}

TEST(InputLagEngine, ModulesAndTheContextSeeTheLagAndARestartContinuesIt) {
  const double tau = 900.0;
  SensorWatcher* w1 = nullptr;
  auto e1 = lag_engine(tau, w1);
  InputLags reference = one_lag(tau);
  StepOutput out;
  double y = 0.0;
  for (int k = 0; k <= 20; ++k) {
    const double t = 60.0 * k;
    const std::vector<Event> in{sample(t, 5, 20.0 + 0.5 * k)};
    e1->step(from_seconds(t), in, out);
    y = cycle(reference, t, in, 40);
    ASSERT_DOUBLE_EQ(w1->last, y) << k;
    ASSERT_DOUBLE_EQ(e1->context().temperature_c(40), y) << k;
  }
  EXPECT_DOUBLE_EQ(e1->input_lags().value(0), y);

  std::vector<std::byte> buf(e1->state_capacity());
  const std::size_t n = e1->export_state(buf);
  ASSERT_GT(n, 0U);
  SensorWatcher* w2 = nullptr;
  auto e2 = lag_engine(tau, w2);
  std::size_t skipped = 99;
  ASSERT_TRUE(
      e2->import_state(std::span<const std::byte>(buf.data(), n), from_seconds(1500.0), &skipped));
  EXPECT_EQ(skipped, 0U);
  e2->step(from_seconds(1500.0), {}, out);
  EXPECT_DOUBLE_EQ(w2->last, cycle(reference, 1500.0, {}, 40));  // continued, not restarted
}

TEST(InputLagEngine, ConfigureRefusesABadLag) {
  Engine e;
  EngineOptions options;
  options.lags = {{5, 40, 0.0}};
  EXPECT_THROW(e.configure({}, {}, options), std::invalid_argument);
}

}  // namespace
}  // namespace nccomp::core::engine
