// The process noise adapted from the NIS (core/estimation/noise_adaptation.hpp): the closed form
// of one step, its bounds, and on generated random walks of the level + rate model that the
// adapted q follows a change of the true q and stays near a constant one; no allocation.
#include "core/estimation/noise_adaptation.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include "core/estimation/kalman.hpp"
#include "tests/support/alloc_counter.hpp"

namespace est = nccomp::core::estimation;

namespace {

TEST(NoiseAdaptation, OneStepIsTheLogStepOfTheNisDepartureTimesTheGain) {
  est::NoiseAdaptation a;
  a.window = 20.0;
  a.q_min = 1e-9;
  a.q_max = 1e-3;
  a.max_gain = 4.0;
  // NIS 3, P⁻/S = 0.5: gain 2, log step (3 − 1)·2/20 = 0.2.
  EXPECT_NEAR(est::adapt_process_noise(1e-6, 3.0, 0.5, a), 1e-6 * std::exp(0.2), 1e-18);
  // P⁻/S = 0.1: gain capped at 4; NIS 0 gives the step −4/20.
  EXPECT_NEAR(est::adapt_process_noise(1e-6, 0.0, 0.1, a), 1e-6 * std::exp(-0.2), 1e-18);
  // NIS 1: consistent, unchanged.
  EXPECT_DOUBLE_EQ(est::adapt_process_noise(1e-6, 1.0, 0.3, a), 1e-6);
}

TEST(NoiseAdaptation, StaysWithinItsBoundsAndIgnoresNonFiniteInput) {
  est::NoiseAdaptation a;
  a.window = 2.0;
  a.q_min = 1e-8;
  a.q_max = 1e-5;
  // One wild measurement moves q by at most a factor e.
  EXPECT_NEAR(est::adapt_process_noise(1e-7, 1e6, 1.0, a), 1e-7 * std::exp(1.0), 1e-20);
  double q = 1e-7;
  for (int k = 0; k < 100; ++k) q = est::adapt_process_noise(q, 50.0, 0.5, a);
  EXPECT_DOUBLE_EQ(q, 1e-5);
  for (int k = 0; k < 100; ++k) q = est::adapt_process_noise(q, 0.0, 0.5, a);
  EXPECT_DOUBLE_EQ(q, 1e-8);
  EXPECT_DOUBLE_EQ(est::adapt_process_noise(2e-7, std::nan(""), 0.5, a), 2e-7);
  EXPECT_DOUBLE_EQ(est::adapt_process_noise(2e-7, 2.0, std::nan(""), a), 2e-7);
  // A q outside the bounds (or not yet known) starts at the nearest bound.
  EXPECT_DOUBLE_EQ(est::adapt_process_noise(std::nan(""), 1.0, 0.5, a), 1e-8);
  EXPECT_DOUBLE_EQ(est::adapt_process_noise(1.0, 1.0, 0.5, a), 1e-5);
}

// A wear-like level + rate random walk measured every d with σ = 1: the true rate's walk has
// density true_q[k] before measurement k; the filter runs with the adapted q, starting at q0.
// Returns the adapted q after every measurement.
std::vector<double> adapt_on_walk(const std::vector<double>& true_q, double q0, unsigned seed,
                                  const est::NoiseAdaptation& a) {
  constexpr double d = 1000.0;
  constexpr double r = 1.0;
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> unit(0.0, 1.0);
  double wear = 0.0;
  double rate = 0.0;
  est::KalmanFilter<2> kf;
  kf.reset(Eigen::Vector2d::Zero(), Eigen::Vector2d(r, 1e-4).asDiagonal());
  const Eigen::RowVector2d h(1.0, 0.0);
  double q = q0;
  std::vector<double> out;
  out.reserve(true_q.size());
  for (const double qt : true_q) {
    rate += std::sqrt(qt * d) * unit(rng);
    wear += rate * d;
    const double z = wear + std::sqrt(r) * unit(rng);
    kf.predict(est::cv_transition(d), est::cv_process_noise(d, 0.0, q));
    const double s = kf.innovation_variance(h, r);
    const double nu = z - kf.predicted_measurement(h);
    const double prior_fraction = (s - r) / s;
    kf.update(h, z, r, 0.0);
    q = est::adapt_process_noise(q, nu * nu / s, prior_fraction, a);
    out.push_back(q);
  }
  return out;
}

double geometric_mean(const std::vector<double>& v, std::size_t from, std::size_t to) {
  double s = 0.0;
  for (std::size_t k = from; k < to; ++k) s += std::log(v[k]);
  return std::exp(s / static_cast<double>(to - from));
}

constexpr double kQ1 = 2.5e-10;  // (µm/mm)² per mm: 0.0005 µm/mm per √m

est::NoiseAdaptation bench_adaptation() {
  est::NoiseAdaptation a;
  a.window = 20.0;
  a.q_min = kQ1 / 1000.0;
  a.q_max = kQ1 * 1000.0;
  return a;
}

TEST(NoiseAdaptation, TheAdaptedQFollowsATrueQThatChangesMidLife) {
  // q1 for 300 measurements, then 25·q1 (the rate's walk 5 times faster); the filter starts
  // 25 times too high. Tolerance: over the last 100 measurements of each half, the geometric
  // mean of the adapted q within a factor 4 of the true q in every one of 20 walks, and the
  // median over the walks within a factor 2 (one measurement carries little information on q
  // when P⁻ ≪ σ², so a single walk's estimate scatters).
  std::vector<double> true_q(600, kQ1);
  std::fill(true_q.begin() + 300, true_q.end(), 25.0 * kQ1);
  std::vector<double> first;
  std::vector<double> second;
  for (unsigned seed = 1; seed <= 20; ++seed) {
    const auto q = adapt_on_walk(true_q, 25.0 * kQ1, seed, bench_adaptation());
    first.push_back(geometric_mean(q, 200, 300) / kQ1);
    second.push_back(geometric_mean(q, 500, 600) / (25.0 * kQ1));
    EXPECT_GT(first.back(), 1.0 / 4.0) << "seed " << seed;
    EXPECT_LT(first.back(), 4.0) << "seed " << seed;
    EXPECT_GT(second.back(), 1.0 / 4.0) << "seed " << seed;
    EXPECT_LT(second.back(), 4.0) << "seed " << seed;
  }
  std::sort(first.begin(), first.end());
  std::sort(second.begin(), second.end());
  EXPECT_GT(first[10], 1.0 / 2.0);
  EXPECT_LT(first[10], 2.0);
  EXPECT_GT(second[10], 1.0 / 2.0);
  EXPECT_LT(second[10], 2.0);
}

TEST(NoiseAdaptation, AConstantQStaysWithinABand) {
  // Started at the true q: after 100 measurements every adapted value of 20 walks of 600
  // measurements stays within a factor 12 of it, and each walk's geometric mean within 2.
  const std::vector<double> true_q(600, kQ1);
  for (unsigned seed = 101; seed <= 120; ++seed) {
    const auto q = adapt_on_walk(true_q, kQ1, seed, bench_adaptation());
    const auto [lo, hi] = std::minmax_element(q.begin() + 100, q.end());
    EXPECT_GT(*lo / kQ1, 1.0 / 12.0) << "seed " << seed;
    EXPECT_LT(*hi / kQ1, 12.0) << "seed " << seed;
    const double g = geometric_mean(q, 100, 600) / kQ1;
    EXPECT_GT(g, 0.5) << "seed " << seed;
    EXPECT_LT(g, 2.0) << "seed " << seed;
  }
}

TEST(NoiseAdaptation, AllocatesNothing) {
  const est::NoiseAdaptation a = bench_adaptation();
  double q = kQ1;
  const nccomp::test::AllocationScope scope;
  for (int k = 0; k < 1000; ++k) q = est::adapt_process_noise(q, 0.5 + (k % 3), 0.3, a);
  EXPECT_EQ(scope.count(), 0U);
  EXPECT_GT(q, 0.0);
}

}  // namespace
