// The derived sum input (core/engine/input_sum.hpp): its value, that it waits for every input,
// that non-finite samples are not taken, validation, allocation-free updates, and in the engine:
// a lag's output as an input in the same cycle, and what modules see.
#include "core/engine/input_sum.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>
#include <vector>

#include "core/engine/engine.hpp"
#include "tests/support/alloc_counter.hpp"

namespace nccomp::core::engine {
namespace {

TemperatureSample sample(double t_s, std::uint8_t sensor, double v) {
  return TemperatureSample{from_seconds(t_s), sensor, v};
}

// One cycle: the events in, the sum's published value (NaN if it published none), and the number
// of samples published.
double cycle(InputSums& sums, double t_s, const std::vector<Event>& in, std::uint8_t out_sensor,
             std::size_t* published = nullptr) {
  std::array<Event, 16> out{};
  const std::size_t n = sums.update(from_seconds(t_s), in, out, 0);
  if (published != nullptr) *published = n;
  for (std::size_t i = 0; i < n; ++i) {
    const auto& s = std::get<TemperatureSample>(out[i]);
    if (s.sensor == out_sensor) return s.temperature_c;
  }
  return std::nan("");
}

InputSumSpec spec(std::uint8_t out, double offset, std::vector<std::uint8_t> inputs,
                  std::vector<double> weights) {
  InputSumSpec s;
  s.output_sensor = out;
  s.offset = offset;
  s.inputs = std::move(inputs);
  s.weights = std::move(weights);
  return s;
}

InputSums example() {
  InputSums sums;
  const std::vector<InputSumSpec> specs{spec(60, -12.5, {1, 2, 40, 41}, {0.8, -1.2, 3.1, 0.4})};
  sums.configure(specs);
  return sums;
}

TEST(InputSum, WaitsForEveryInputThenPublishesOffsetPlusTheWeightedSumEveryCycle) {
  InputSums sums = example();
  std::size_t n = 99;
  EXPECT_TRUE(std::isnan(cycle(sums, 0.0, {}, 60, &n)));
  EXPECT_EQ(n, 0U);
  // Three of four inputs: nothing yet.
  EXPECT_TRUE(std::isnan(
      cycle(sums, 1.0, {sample(1, 1, 20.0), sample(1, 2, 21.0), sample(1, 40, 19.0)}, 60, &n)));
  EXPECT_EQ(n, 0U);
  EXPECT_TRUE(std::isnan(sums.value(0)));
  // The fourth (two cycles later): published, with the earlier inputs' last values.
  const double v1 = -12.5 + 0.8 * 20.0 - 1.2 * 21.0 + 3.1 * 19.0 + 0.4 * 1500.0;
  EXPECT_DOUBLE_EQ(cycle(sums, 2.0, {sample(2, 41, 1500.0)}, 60, &n), v1);
  EXPECT_EQ(n, 1U);
  EXPECT_DOUBLE_EQ(sums.value(0), v1);
  // Every cycle, with or without new samples (like the lags).
  EXPECT_DOUBLE_EQ(cycle(sums, 3.0, {}, 60), v1);
  // A new sample of one input; two samples of one sensor in a cycle: the last one counts.
  const double v2 = v1 + 3.1 * (25.0 - 19.0);
  EXPECT_DOUBLE_EQ(cycle(sums, 4.0, {sample(4, 40, 22.0), sample(4, 40, 25.0)}, 60), v2);
  // Other sensors do not matter.
  EXPECT_DOUBLE_EQ(cycle(sums, 5.0, {sample(5, 3, 99.0), sample(5, 60, 1e9)}, 60), v2);
}

TEST(InputSum, NonFiniteSamplesAreNotTaken) {
  InputSums sums = example();
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  // A NaN does not count as an input's first sample.
  EXPECT_TRUE(std::isnan(cycle(
      sums, 1.0, {sample(1, 1, 20.0), sample(1, 2, 21.0), sample(1, 40, 19.0), sample(1, 41, nan)},
      60)));
  const double v = -12.5 + 0.8 * 20.0 - 1.2 * 21.0 + 3.1 * 19.0 + 0.4 * 7.0;
  EXPECT_DOUBLE_EQ(cycle(sums, 2.0, {sample(2, 41, 7.0)}, 60), v);
  // Later: an input's NaN or inf keeps its previous value.
  EXPECT_DOUBLE_EQ(cycle(sums, 3.0, {sample(3, 1, nan), sample(3, 2, inf)}, 60), v);
  // A sum that overflows publishes nothing rather than inf, and comes back with its inputs.
  InputSums big;
  const std::vector<InputSumSpec> specs{spec(9, 0.0, {1, 2}, {1e300, 1e300})};
  big.configure(specs);
  std::size_t n = 99;
  EXPECT_TRUE(std::isnan(cycle(big, 1.0, {sample(1, 1, 1e10), sample(1, 2, 1.0)}, 9, &n)));
  EXPECT_EQ(n, 0U);
  EXPECT_TRUE(std::isnan(big.value(0)));
  EXPECT_DOUBLE_EQ(cycle(big, 2.0, {sample(2, 1, 1.0)}, 9), 2e300);
}

TEST(InputSum, SeveralSumsShareInputs) {
  InputSums sums;
  const std::vector<InputSumSpec> specs{spec(60, 0.0, {1, 2}, {1.0, 1.0}),
                                        spec(61, 1.0, {2}, {-2.0})};
  sums.configure(specs);
  std::array<Event, 4> out{};
  const std::vector<Event> in{sample(1, 2, 5.0)};
  ASSERT_EQ(sums.update(from_seconds(1.0), in, out, 0), 1U);  // sum 60 waits for sensor 1
  EXPECT_EQ(std::get<TemperatureSample>(out[0]).sensor, 61);
  EXPECT_DOUBLE_EQ(std::get<TemperatureSample>(out[0]).temperature_c, -9.0);
  const std::vector<Event> in2{sample(2, 1, 3.0)};
  ASSERT_EQ(sums.update(from_seconds(2.0), in2, out, 1), 3U);  // appended after index 1
  EXPECT_DOUBLE_EQ(std::get<TemperatureSample>(out[1]).temperature_c, 8.0);
  EXPECT_DOUBLE_EQ(std::get<TemperatureSample>(out[2]).temperature_c, -9.0);
  // An output that does not fit is dropped, the count stays within out.
  std::array<Event, 1> small{};
  EXPECT_EQ(sums.update(from_seconds(3.0), {}, small, 0), 1U);
}

TEST(InputSum, ThirtyTwoInputs) {
  InputSums sums;
  std::vector<std::uint8_t> inputs;
  std::vector<double> weights;
  std::vector<Event> in;
  double expected = 0.25;
  for (std::size_t k = 0; k < kMaxSumInputs; ++k) {
    const double x = static_cast<double>(k);
    inputs.push_back(static_cast<std::uint8_t>(100 + k));
    weights.push_back(0.5 + x);
    in.push_back(sample(1, static_cast<std::uint8_t>(100 + k), 2.0 * x));
    expected += (0.5 + x) * 2.0 * x;
  }
  const std::vector<InputSumSpec> specs{spec(7, 0.25, inputs, weights)};
  sums.configure(specs);
  const std::vector<Event> most(in.begin(), in.end() - 1);
  EXPECT_TRUE(std::isnan(cycle(sums, 1.0, most, 7)));
  EXPECT_DOUBLE_EQ(cycle(sums, 2.0, {in.back()}, 7), expected);
}

TEST(InputSum, ConfigurationIsValidated) {
  InputSums sums;
  const auto refused = [&sums](std::vector<InputSumSpec> specs, const char* what,
                               std::vector<InputLagSpec> lags = {}) {
    try {
      sums.configure(specs, lags);
      ADD_FAILURE() << "accepted, expected: " << what;
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find(what), std::string::npos) << e.what();
    }
  };
  const double nan = std::nan("");
  refused({spec(60, 0.0, {}, {})}, "sums[0].inputs: 0 sensors");
  refused({spec(60, 0.0, std::vector<std::uint8_t>(33, 1), std::vector<double>(33, 1.0))},
          "sums[0].inputs: 33 sensors");
  refused({spec(60, 0.0, {1, 2}, {1.0})}, "sums[0].weights: 1 weights for 2 inputs");
  refused({spec(60, 0.0, {1}, {1.0, 2.0})}, "sums[0].weights: 2 weights for 1 inputs");
  refused({spec(60, 0.0, {1, 2}, {1.0, nan})}, "sums[0].weights[1]: must be finite");
  refused({spec(60, 0.0, {1}, {INFINITY})}, "sums[0].weights[0]: must be finite");
  refused({spec(60, nan, {1}, {1.0})}, "sums[0].offset: must be finite");
  refused({spec(60, -INFINITY, {1}, {1.0})}, "sums[0].offset: must be finite");
  refused({spec(60, 0.0, {1, 60}, {1.0, 1.0})}, "sums[0].sensor: equals its inputs[1]");
  refused({spec(60, 0.0, {1, 2, 1}, {1.0, 1.0, 1.0})}, "sums[0].inputs[2]: sensor 1 is already");
  refused({spec(60, 0.0, {1}, {1.0}), spec(60, 0.0, {2}, {1.0})},
          "sums[1].sensor: sensor 60 is already the output of sums[0]");
  refused({spec(60, 0.0, {1}, {1.0}), spec(61, 0.0, {60}, {1.0})},
          "sums[0].sensor: sensor 60 is an input of sums[1]");
  refused({spec(61, 0.0, {60}, {1.0}), spec(60, 0.0, {1}, {1.0})},
          "sums[1].sensor: sensor 60 is an input of sums[0]");
  refused({spec(40, 0.0, {1}, {1.0})}, "sums[0].sensor: sensor 40 is the output of lags[0]",
          {{5, 40, 60.0}});
  refused({spec(5, 0.0, {1}, {1.0})}, "sums[0].sensor: sensor 5 is the input of lags[0]",
          {{5, 40, 60.0}});
  refused(std::vector<InputSumSpec>(kMaxInputSums + 1, spec(60, 0.0, {1}, {1.0})), "at most 8");
  // A lag's output as an input is fine.
  const std::vector<InputSumSpec> ok{spec(60, 0.0, {1, 40}, {1.0, 1.0})};
  const std::vector<InputLagSpec> lags{{5, 40, 60.0}};
  EXPECT_NO_THROW(sums.configure(ok, lags));
  EXPECT_EQ(sums.size(), 1U);
  EXPECT_EQ(sums.input_count(0), 2U);
  EXPECT_EQ(sums.input_sensor(0, 1), 40);
}

TEST(InputSum, UpdateIsAllocationFree) {
  InputSums sums = example();
  std::array<Event, 8> in{sample(1, 1, 20.0), sample(1, 2, 3.0), sample(1, 40, 3.0),
                          sample(1, 41, 3.0), sample(1, 7, 3.0)};
  std::array<Event, 8> out{};
  test::AllocationScope scope;
  for (int i = 1; i < 100; ++i) {
    (void)sums.update(from_seconds(i), std::span<const Event>(in.data(), 5), out, 0);
  }
  EXPECT_EQ(scope.count(), 0U);
  EXPECT_FALSE(std::isnan(sums.value(0)));
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
        ++count;
      }
    }
  }
  double last{std::nan("")};
  int count{0};

 private:
  std::uint8_t sensor_;
};

TEST(InputSumEngine, ASumOfALagSeesTheLagOfTheSameCycle) {
  const double tau = 300.0;
  auto e = std::make_unique<Engine>();
  auto w = std::make_unique<SensorWatcher>(60);
  SensorWatcher* watcher = w.get();
  std::vector<std::unique_ptr<Module>> mods;
  mods.push_back(std::move(w));
  EngineOptions options;
  options.lags = {{5, 40, tau}};
  options.sums = {spec(60, 1.5, {5, 40}, {2.0, -3.0})};
  e->configure({}, std::move(mods), options);
  InputLags reference;
  const std::vector<InputLagSpec> lag_specs{{5, 40, tau}};
  reference.configure(lag_specs);
  StepOutput out;
  for (int k = 0; k <= 30; ++k) {
    const double t = 20.0 * k;
    const double u = 20.0 + 0.3 * k;
    const std::vector<Event> in{sample(t, 5, u)};
    e->step(from_seconds(t), in, out);
    std::array<Event, 2> lag_out{};
    ASSERT_EQ(reference.update(from_seconds(t), in, lag_out, 0), 1U);
    const double lag = std::get<TemperatureSample>(lag_out[0]).temperature_c;
    const double expected = 1.5 + 2.0 * u - 3.0 * lag;
    ASSERT_DOUBLE_EQ(watcher->last, expected) << k;
    ASSERT_DOUBLE_EQ(e->context().temperature_c(60), expected) << k;
    ASSERT_DOUBLE_EQ(e->input_sums().value(0), expected) << k;
    ASSERT_EQ(watcher->count, k + 1) << k;  // one sample per cycle from the first
  }
  // Without new samples the sum follows the lag every cycle.
  e->step(from_seconds(1000.0), {}, out);
  std::array<Event, 2> lag_out{};
  ASSERT_EQ(reference.update(from_seconds(1000.0), {}, lag_out, 0), 1U);
  EXPECT_DOUBLE_EQ(watcher->last, 1.5 + 2.0 * (20.0 + 0.3 * 30) -
                                      3.0 * std::get<TemperatureSample>(lag_out[0]).temperature_c);
}

TEST(InputSumEngine, ConfigureRefusesABadSumNamingIt) {
  Engine e;
  EngineOptions options;
  options.lags = {{5, 40, 60.0}};
  options.sums = {spec(60, 0.0, {1}, {1.0}), spec(40, 0.0, {1}, {1.0})};
  try {
    e.configure({}, {}, options);
    ADD_FAILURE() << "accepted";
  } catch (const std::invalid_argument& x) {
    EXPECT_NE(std::string(x.what()).find("engine: input sums[1].sensor"), std::string::npos)
        << x.what();
  }
}

}  // namespace
}  // namespace nccomp::core::engine
