// S1's estimator ([checkpoints.estimator]): per checkpoint a Kalman filter of a random walk, the
// part noise learned from the history, the gate, the state's layouts.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <random>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "core/checkpoint/compensator.hpp"
#include "core/common/config_issue.hpp"
#include "tests/support/alloc_counter.hpp"
#include "tests/unit/checkpoint/helpers.hpp"

namespace nccomp::core::checkpoint {
namespace {

using test::line_plan;
using test::part_start;
using test::probe;
using test::wide_limits;

// The closed form of the random walk's steady-state gain, written out here (not the toolkit's
// random_walk_steady_gain()): the positive root of r·K² + q·K − q = 0.
double k_inf(double q, double r) { return (-q + std::sqrt(q * q + 4.0 * q * r)) / (2.0 * r); }

CompensatorConfig estimator_config(double sigma_um, double part_noise_um, bool learn) {
  CompensatorConfig c;
  c.dead_band_um = 0.0;
  c.probe_repeatability_um = 0.0;
  c.estimator.enabled = true;
  c.estimator.measurement_sigma_um = sigma_um;
  c.estimator.part_noise_um = part_noise_um;
  c.estimator.learn_part_noise = learn;
  return c;
}

// One part: part start (the table applied as the wall's offsets) and a reading per checkpoint of
// the uncompensated errors e (the wall measures e + the applied offset).
void part(CheckpointCompensator& comp, std::int32_t n, const std::vector<double>& e) {
  StepOutput out;
  const Event start = part_start(n);
  comp.step(0, {&start, 1}, out);
  for (std::size_t i = 0; i < e.size(); ++i) {
    out.clear();
    const Event m = probe(n, static_cast<std::int32_t>(i), e[i] + comp.point(i).applied_um);
    comp.step(0, {&m, 1}, out);
  }
}

// GIVEN a fixed part noise (q = 0.5², r = 1²) and a checkpoint read at its estimate part after part
// WHEN the filter has settled
// THEN the weight of the next reading is the closed form K∞ and a reading 1 µm off moves the
//      estimate (and, with feedback 1, the offset) by exactly that weight.
TEST(CheckpointEstimator, TheGainSettlesAtTheRandomWalksClosedForm) {
  for (const auto& [sigma, noise] : {std::pair{1.0, 0.5}, std::pair{0.7, 2.0}}) {
    CheckpointCompensator comp;
    comp.configure(estimator_config(sigma, noise, false), line_plan(1), wide_limits());
    part(comp, 1, {4.0});
    EXPECT_DOUBLE_EQ(comp.learned_um(0), 4.0);  // the first reading is taken as it is
    for (int n = 2; n < 60; ++n) part(comp, n, {4.0});
    const double q = noise * noise;
    const double r = sigma * sigma;
    EXPECT_NEAR(comp.next_gain(0), k_inf(q, r), 1e-12) << sigma << " " << noise;
    const double k = comp.next_gain(0);
    part(comp, 60, {5.0});
    EXPECT_NEAR(comp.learned_um(0), 4.0 + k, 1e-12);
    EXPECT_NEAR(comp.point(0).offset_um, -(4.0 + k), 1e-12);
    // The status's σ: the prediction for the next part, sqrt(P + q) with P = K∞·r at steady state.
    EXPECT_NEAR(comp.predicted_sigma_um(0), std::sqrt(k * r + q), 1e-9);
  }
}

// GIVEN 400 checkpoints whose errors follow independent random walks (part noise 0.8 µm) read
// with probe noise σ = 0.5 µm, 20 parts
// WHEN the part noise is learned from each checkpoint's history (the last 16 readings)
// THEN the mean learned q over the checkpoints is the true 0.64 µm² within 0.1 µm² (the mean of
//      400 estimates has a standard deviation of about 0.03 µm² here), and without subtracting the
//      probe's 2σ² it would be 1.14: the probe noise is not taken for part noise.
TEST(CheckpointEstimator, ThePartNoiseIsLearnedFromGeneratedParts) {
  constexpr std::size_t kN = 400;
  const double q_true = 0.8 * 0.8;
  const double sigma = 0.5;
  CheckpointCompensator comp;
  // The gate is off here: until the history is long enough the small prior (0.1 µm) would refuse
  // some of the walk's steps, and a refused reading is not in the history (the gate: below).
  CompensatorConfig c = estimator_config(sigma, 0.1, true);
  c.estimator.gate_sigmas = 0.0;
  comp.configure(c, line_plan(kN), wide_limits());
  std::mt19937 rng(22);
  std::normal_distribution<double> walk(0.0, std::sqrt(q_true));
  std::normal_distribution<double> noise(0.0, sigma);
  std::vector<double> truth(kN, 10.0);
  for (int n = 1; n <= 20; ++n) {
    std::vector<double> e(kN);
    for (std::size_t i = 0; i < kN; ++i) {
      truth[i] += walk(rng);
      e[i] = truth[i] + noise(rng);
    }
    part(comp, n, e);
  }
  double mean_q = 0.0;
  for (std::size_t i = 0; i < kN; ++i) {
    ASSERT_EQ(comp.point(i).history_n, kHistoryDepth);
    mean_q += comp.part_noise_var_um2(i);
  }
  mean_q /= static_cast<double>(kN);
  EXPECT_NEAR(mean_q, q_true, 0.1);
  // And the gain the filters use is the one of the true q, on average.
  double mean_gain = 0.0;
  for (std::size_t i = 0; i < kN; ++i) mean_gain += comp.next_gain(i);
  mean_gain /= static_cast<double>(kN);
  EXPECT_NEAR(mean_gain, k_inf(q_true, sigma * sigma), 0.05);
}

// GIVEN fewer readings than learn_min_parts
// THEN the configured part noise is used; from learn_min_parts on the history's.
TEST(CheckpointEstimator, TheConfiguredPartNoiseHoldsUntilTheHistoryIsLongEnough) {
  CompensatorConfig c = estimator_config(1.0, 0.5, true);
  c.estimator.learn_min_parts = 4;
  CheckpointCompensator comp;
  comp.configure(c, line_plan(1), wide_limits());
  const double e[] = {0.0, 4.0, 0.0, 4.0};
  for (int n = 0; n < 3; ++n) part(comp, n + 1, {e[n]});
  EXPECT_DOUBLE_EQ(comp.part_noise_var_um2(0), 0.25);
  part(comp, 4, {e[3]});
  // Differences 4, −4, 4: mean square 16, less 2σ² = 2.
  EXPECT_NEAR(comp.part_noise_var_um2(0), 14.0, 1e-12);
  // A history that varies less than the probe gives 0, not a negative variance.
  CheckpointCompensator flat;
  flat.configure(c, line_plan(1), wide_limits());
  for (int n = 1; n <= 6; ++n) part(flat, n, {3.0 + 0.1 * (n % 2)});
  EXPECT_DOUBLE_EQ(flat.part_noise_var_um2(0), 0.0);
}

// GIVEN a settled filter (q = 0.25, r = 1)
// WHEN a reading lies beyond gate_sigmas (5) standard deviations of the predicted innovation
// THEN warning 31 (the reading as its value), counted as an outlier, and nothing changes; a reading
//      just inside the gate is learned.
TEST(CheckpointEstimator, AReadingBeyondTheGateIsNotLearnedAndRaisesTheOutlierWarning) {
  CheckpointCompensator comp;
  comp.configure(estimator_config(1.0, 0.5, false), line_plan(1), wide_limits());
  for (int n = 1; n <= 30; ++n) part(comp, n, {2.0});
  const LearnedPoint before = comp.point(0);
  const double s = std::sqrt(before.variance_um2 + 0.25 + 1.0);
  StepOutput out;
  const Event far = probe(31, 0, 2.0 + 5.01 * s + before.applied_um);
  comp.step(0, {&far, 1}, out);
  ASSERT_EQ(out.alarms.size(), 1U);
  EXPECT_EQ(out.alarms[0].code, AlarmCode::kProbeOutlier);
  EXPECT_EQ(out.alarms[0].severity, Severity::kWarning);
  EXPECT_NEAR(out.alarms[0].value, 2.0 + 5.01 * s, 1e-9);
  EXPECT_EQ(comp.counters().outliers, 1U);
  EXPECT_EQ(comp.point(0).learned_um, before.learned_um);
  EXPECT_EQ(comp.point(0).variance_um2, before.variance_um2);
  EXPECT_EQ(comp.point(0).count, before.count);
  EXPECT_EQ(comp.point(0).history_n, before.history_n);
  EXPECT_EQ(comp.point(0).offset_um, before.offset_um);
  out.clear();
  const Event near = probe(31, 0, 2.0 + 4.99 * s + before.applied_um);
  comp.step(0, {&near, 1}, out);
  EXPECT_TRUE(out.alarms.empty());
  EXPECT_EQ(comp.point(0).count, before.count + 1);
  const double k = (before.variance_um2 + 0.25) / (before.variance_um2 + 0.25 + 1.0);
  EXPECT_NEAR(comp.learned_um(0), 2.0 + k * 4.99 * s, 1e-9);
  // The gate off: the same far reading is learned.
  CompensatorConfig off = estimator_config(1.0, 0.5, false);
  off.estimator.gate_sigmas = 0.0;
  CheckpointCompensator open;
  open.configure(off, line_plan(1), wide_limits());
  for (int n = 1; n <= 30; ++n) part(open, n, {2.0});
  out.clear();
  open.step(0, {&far, 1}, out);
  EXPECT_TRUE(out.alarms.empty());
  EXPECT_EQ(open.point(0).count, 31U);
}

// GIVEN learned filters exported and imported into a fresh compensator (a restart)
// WHEN both see the same next part
// THEN they agree exactly: the filter continues, it is not restarted.
TEST(CheckpointEstimator, TheStateRoundTripContinuesTheFilter) {
  CheckpointCompensator a;
  a.configure(estimator_config(1.0, 0.5, true), line_plan(2), wide_limits());
  for (int n = 1; n <= 8; ++n) part(a, n, {1.0 * n, -0.5 * n * (n % 3)});
  CheckpointState st;
  a.export_state(st);
  EXPECT_EQ(st.version, 4U);
  CheckpointCompensator b;
  b.configure(estimator_config(1.0, 0.5, true), line_plan(2), wide_limits());
  b.import_state(st);
  for (std::size_t i = 0; i < 2; ++i) {
    EXPECT_EQ(b.point(i).variance_um2, a.point(i).variance_um2);
    EXPECT_EQ(b.point(i).filter_n, a.point(i).filter_n);
  }
  part(a, 9, {12.0, -3.0});
  part(b, 9, {12.0, -3.0});
  for (std::size_t i = 0; i < 2; ++i) {
    EXPECT_EQ(b.learned_um(i), a.learned_um(i));
    EXPECT_EQ(b.point(i).variance_um2, a.point(i).variance_um2);
    EXPECT_EQ(b.point(i).offset_um, a.point(i).offset_um);
  }
  // A negative variance is not a state.
  st.points[1].variance_um2 = -1.0;
  CheckpointCompensator c;
  c.configure(estimator_config(1.0, 0.5, true), line_plan(2), wide_limits());
  EXPECT_THROW(c.import_state(st), std::invalid_argument);
}

// GIVEN a state of layout version 1 (the EWMA's: M = 6 after 3 readings, no filter)
// WHEN it is imported with the estimator on and the next reading is 10
// THEN the filter starts from M with the variance σ²: the gain is (σ² + q)/(2σ² + q).
TEST(CheckpointEstimator, AStateOfLayoutVersion1StartsTheFilterFromTheLearnedMean) {
  CheckpointState st;
  st.version = 1;
  st.part_counter = 3;
  st.part = 3;
  st.points.resize(1);
  st.points[0].learned_um = 6.0;
  st.points[0].count = 3;
  st.points[0].offset_um = -6.0;
  st.points[0].applied_um = -6.0;
  st.points[0].history = {4.0, 6.0, 8.0};
  st.points[0].history_n = 3;
  st.points[0].variance_um2 = 123.0;  // not in layout 1: ignored
  st.points[0].filter_n = 9;
  CheckpointCompensator comp;
  comp.configure(estimator_config(1.0, 0.5, true), line_plan(1), wide_limits());
  comp.import_state(st);
  EXPECT_EQ(comp.point(0).filter_n, 0U);
  EXPECT_DOUBLE_EQ(comp.learned_um(0), 6.0);
  EXPECT_NEAR(comp.predicted_sigma_um(0), std::sqrt(1.0 + 0.25), 1e-12);
  part(comp, 4, {10.0});
  const double k = (1.0 + 0.25) / (2.0 + 0.25);
  EXPECT_NEAR(comp.learned_um(0), 6.0 + k * 4.0, 1e-12);
  EXPECT_NEAR(comp.point(0).variance_um2, (1.0 - k) * 1.25, 1e-12);
  EXPECT_EQ(comp.point(0).filter_n, 1U);
}

TEST(CheckpointEstimator, ConfigErrorsNameTheirKeys) {
  const auto issues_of = [](const CompensatorConfig& c) {
    CheckpointCompensator comp;
    try {
      comp.configure(c, line_plan(1), wide_limits());
    } catch (const ConfigInvalid& e) {
      return e.issues();
    }
    return std::vector<ConfigIssue>{};
  };
  CompensatorConfig c = estimator_config(1.0, 0.5, true);
  EXPECT_TRUE(issues_of(c).empty());
  c.estimator.gate_sigmas = 1.5;
  c.estimator.measurement_sigma_um = 0.0;
  c.estimator.learn_min_parts = 2;
  c.estimator.part_noise_um = -1.0;
  c.learning_mode = LearningMode::kSemiFinishing;
  const auto issues = issues_of(c);
  ASSERT_EQ(issues.size(), 5U);
  std::vector<std::string> keys;
  for (const auto& i : issues) keys.push_back(i.key);
  for (const char* k :
       {"checkpoints.estimator.gate_sigmas", "checkpoints.estimator.measurement_sigma_um",
        "checkpoints.estimator.learn_min_parts", "checkpoints.estimator.part_noise_um",
        "checkpoints.estimator.enabled"}) {
    EXPECT_NE(std::find(keys.begin(), keys.end(), k), keys.end()) << k;
  }
  // Off, mode B is fine.
  c = CompensatorConfig{};
  c.learning_mode = LearningMode::kSemiFinishing;
  EXPECT_TRUE(issues_of(c).empty());
}

// The estimator's reading and its part-noise estimate over a full history run on the loop thread.
TEST(CheckpointEstimator, AReadingAllocatesNothing) {
  CheckpointCompensator comp;
  comp.configure(estimator_config(1.0, 0.5, true), line_plan(4), wide_limits());
  for (int n = 1; n <= 20; ++n) part(comp, n, {1.0, 2.0 + 0.3 * n, -1.0, 0.5 * (n % 2)});
  StepOutput out;
  const Event start = part_start(21);
  comp.step(0, {&start, 1}, out);
  out.clear();
  // Readings of the wall as cut: the error plus the offset applied at each checkpoint.
  const double e[] = {1.5, 8.5, -1.2, 40.0};
  std::vector<Event> ev;
  for (std::int32_t i = 0; i < 4; ++i) {
    ev.emplace_back(probe(21, i, e[i] + comp.point(static_cast<std::size_t>(i)).applied_um));
  }
  nccomp::test::AllocationScope scope;
  comp.step(0, ev, out);
  double s = 0.0;
  for (std::size_t i = 0; i < 4; ++i) s += comp.predicted_sigma_um(i) + comp.next_gain(i);
  EXPECT_EQ(scope.count(), 0U);
  EXPECT_EQ(scope.frees(), 0U);
  EXPECT_TRUE(std::isfinite(s));
  ASSERT_EQ(out.alarms.size(), 1U);  // 40 µm at checkpoint 3 is beyond the gate
  EXPECT_EQ(out.alarms[0].subject, 3);
  EXPECT_EQ(out.alarms[0].code, AlarmCode::kProbeOutlier);
}

}  // namespace
}  // namespace nccomp::core::checkpoint
