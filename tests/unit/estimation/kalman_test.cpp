// The Kalman toolkit (core/estimation/kalman.hpp) against closed forms: the steady-state gain of
// a random walk, the batch (regularised least-squares) solution of a constant-velocity model
// without process noise, the gate, a vector update against sequential scalar ones, and no
// allocation in predict / update.
#include "core/estimation/kalman.hpp"

#include <gtest/gtest.h>

#include <Eigen/LU>

#include <cmath>
#include <utility>
#include <vector>

#include "tests/support/alloc_counter.hpp"

namespace {

using nccomp::core::estimation::cv_process_noise;
using nccomp::core::estimation::cv_transition;
using nccomp::core::estimation::KalmanFilter;
using nccomp::core::estimation::random_walk_steady_gain;

using KF1 = KalmanFilter<1>;
using KF2 = KalmanFilter<2>;

TEST(Kalman, RandomWalkConvergesToTheClosedFormSteadyStateGain) {
  // GIVEN a random walk (q) measured directly (r), WHEN the filter runs long enough,
  // THEN its gain P⁻/(P⁻ + r) is K∞ = (−q + sqrt(q² + 4qr)) / (2r), and one update moves the
  // estimate by exactly K∞ times the innovation.
  for (const auto& [q, r] : {std::pair{0.04, 1.0}, std::pair{1.0, 1.0}, std::pair{1e-4, 4.0}}) {
    KF1 kf;
    kf.reset(KF1::Vector(0.0), KF1::Matrix(100.0));
    const KF1::Matrix f(1.0);
    const KF1::Matrix qm(q);
    const KF1::Row h(1.0);
    for (int i = 0; i < 20000; ++i) {
      kf.predict(f, qm);
      ASSERT_TRUE(kf.update(h, 0.0, r, 0.0).accepted);
    }
    // K∞ from the Riccati fixed point, solved here independently: P⁻ = (q + sqrt(q²+4qr))/2.
    const double p_prior = 0.5 * (q + std::sqrt(q * q + 4.0 * q * r));
    const double k_fixed_point = p_prior / (p_prior + r);
    EXPECT_NEAR(random_walk_steady_gain(q, r), k_fixed_point, 1e-12);
    kf.predict(f, qm);
    const double x_before = kf.state()(0);
    const double p_before = kf.covariance()(0, 0);
    EXPECT_NEAR(p_before, p_prior, 1e-9 * p_prior);
    ASSERT_TRUE(kf.update(h, 3.0, r, 0.0).accepted);
    EXPECT_NEAR(kf.state()(0) - x_before, k_fixed_point * (3.0 - x_before), 1e-9);
    EXPECT_NEAR(kf.covariance()(0, 0), k_fixed_point * r, 1e-9);
  }
}

TEST(Kalman, ConstantVelocityWithoutProcessNoiseIsTheBatchLeastSquaresSolution) {
  // GIVEN a level + rate model without process noise, a prior (θ0, P0) on (level, rate) at
  // clock 0 and measurements z_i of the level at clocks t_i, THEN the filter's state at t_n is
  // F(t_n)·θ̂ with θ̂ = (P0⁻¹ + Σ hᵢᵀhᵢ/r)⁻¹ (P0⁻¹θ0 + Σ hᵢᵀzᵢ/r), hᵢ = [1, tᵢ], and its
  // covariance F(t_n)·(P0⁻¹ + Σ hᵢᵀhᵢ/r)⁻¹·F(t_n)ᵀ.
  const Eigen::Vector2d theta0(1.0, 0.02);
  Eigen::Matrix2d p0;
  p0 << 4.0, 0.01, 0.01, 0.001;
  const double r = 0.25;
  const std::vector<double> t{10.0, 35.0, 40.0, 90.0, 150.0, 151.0, 230.0};
  const std::vector<double> z{1.7, 2.1, 1.6, 3.2, 4.9, 4.4, 6.8};
  KF2 kf;
  kf.reset(theta0, p0);
  const Eigen::Matrix2d zero = Eigen::Matrix2d::Zero();
  double clock = 0.0;
  Eigen::Matrix2d info = p0.inverse();
  Eigen::Vector2d rhs = info * theta0;
  for (std::size_t i = 0; i < t.size(); ++i) {
    kf.predict(cv_transition(t[i] - clock), zero);
    clock = t[i];
    ASSERT_TRUE(kf.update(Eigen::RowVector2d(1.0, 0.0), z[i], r, 0.0).accepted);
    const Eigen::RowVector2d hi(1.0, t[i]);
    info += hi.transpose() * hi / r;
    rhs += hi.transpose() * z[i] / r;
    const Eigen::Matrix2d cov0 = info.inverse();
    const Eigen::Vector2d at_t = cv_transition(t[i]) * (cov0 * rhs);
    const Eigen::Matrix2d cov_t = cv_transition(t[i]) * cov0 * cv_transition(t[i]).transpose();
    EXPECT_NEAR(kf.state()(0), at_t(0), 1e-9) << i;
    EXPECT_NEAR(kf.state()(1), at_t(1), 1e-11) << i;
    EXPECT_NEAR(kf.covariance()(0, 0), cov_t(0, 0), 1e-9) << i;
    EXPECT_NEAR(kf.covariance()(0, 1), cov_t(0, 1), 1e-11) << i;
    EXPECT_NEAR(kf.covariance()(1, 1), cov_t(1, 1), 1e-13) << i;
  }
}

TEST(Kalman, ConstantVelocityTracksAnExactLineAndItsRate) {
  // Noise-free measurements of 3 + 0.05·t, a vague prior: level and rate converge to the line.
  KF2 kf;
  Eigen::Matrix2d p0 = Eigen::Matrix2d::Zero();
  p0(0, 0) = 1e6;
  p0(1, 1) = 1e2;
  kf.reset(Eigen::Vector2d::Zero(), p0);
  for (int i = 1; i <= 50; ++i) {
    kf.predict(cv_transition(10.0), cv_process_noise(10.0, 0.0, 1e-10));
    kf.update(Eigen::RowVector2d(1.0, 0.0), 3.0 + 0.05 * 10.0 * i, 1.0, 0.0);
  }
  EXPECT_NEAR(kf.state()(0), 3.0 + 0.05 * 500.0, 1e-3);
  EXPECT_NEAR(kf.state()(1), 0.05, 1e-5);
}

TEST(Kalman, ProcessNoiseOfTheLevelAndRateModel) {
  // Q over d for the rate's walk q_r and the level's walk q_l: the integrals ∫Φ G Gᵀ Φᵀ.
  const Eigen::Matrix2d q = cv_process_noise(3.0, 0.5, 2.0);
  EXPECT_DOUBLE_EQ(q(0, 0), 0.5 * 3.0 + 2.0 * 27.0 / 3.0);
  EXPECT_DOUBLE_EQ(q(0, 1), 2.0 * 9.0 / 2.0);
  EXPECT_DOUBLE_EQ(q(1, 0), 2.0 * 9.0 / 2.0);
  EXPECT_DOUBLE_EQ(q(1, 1), 2.0 * 3.0);
}

TEST(Kalman, AMeasurementBeyondTheGateChangesNothingAndIsReported) {
  // Predicted level 10, variance P = 3, r = 1: S = 4, σ = 2. With k = 3 a measurement at
  // 10 + 6 is at the gate (accepted), at 10 + 6.01 beyond it (refused, state and covariance
  // bit for bit unchanged).
  KF1 kf;
  kf.reset(KF1::Vector(10.0), KF1::Matrix(3.0));
  const KF1::Row h(1.0);
  const auto refused = kf.update(h, 16.01, 1.0, 3.0);
  EXPECT_FALSE(refused.accepted);
  EXPECT_NEAR(refused.normalized, 6.01 / 2.0, 1e-12);
  EXPECT_EQ(kf.state()(0), 10.0);
  EXPECT_EQ(kf.covariance()(0, 0), 3.0);
  const auto at_gate = kf.update(h, 16.0, 1.0, 3.0);
  EXPECT_TRUE(at_gate.accepted);
  EXPECT_NEAR(at_gate.normalized, 3.0, 1e-12);
  EXPECT_NEAR(kf.state()(0), 10.0 + 0.75 * 6.0, 1e-12);  // K = P/S = 3/4
  EXPECT_NEAR(kf.covariance()(0, 0), 0.75, 1e-12);       // (1 − K)·P
  // Gate off (0): anything finite is absorbed; NaN never.
  KF1 off;
  off.reset(KF1::Vector(0.0), KF1::Matrix(1.0));
  EXPECT_TRUE(off.update(h, 1e6, 1.0, 0.0).accepted);
  const auto nan = off.update(h, std::nan(""), 1.0, 0.0);
  EXPECT_FALSE(nan.accepted);
  EXPECT_TRUE(std::isnan(nan.normalized));
}

TEST(Kalman, AVectorUpdateWithIndependentNoiseEqualsSequentialScalarUpdates) {
  Eigen::Matrix2d p0;
  p0 << 2.0, 0.3, 0.3, 0.5;
  KF2 a;
  KF2 b;
  a.reset(Eigen::Vector2d(1.0, -1.0), p0);
  b.reset(Eigen::Vector2d(1.0, -1.0), p0);
  Eigen::Matrix2d h;
  h << 1.0, 0.0, 1.0, 2.0;
  const Eigen::Vector2d z(1.5, -0.4);
  Eigen::Matrix2d r = Eigen::Matrix2d::Zero();
  r(0, 0) = 0.2;
  r(1, 1) = 0.7;
  ASSERT_TRUE(a.update<2>(h, z, r, 0.0).accepted);
  ASSERT_TRUE(b.update(h.row(0), z(0), 0.2, 0.0).accepted);
  ASSERT_TRUE(b.update(h.row(1), z(1), 0.7, 0.0).accepted);
  EXPECT_TRUE(a.state().isApprox(b.state(), 1e-12));
  EXPECT_TRUE(a.covariance().isApprox(b.covariance(), 1e-12));
  // Its gate is on the Mahalanobis distance: far off in the second component → refused.
  const auto gated = a.update<2>(h, Eigen::Vector2d(1.5, 50.0), r, 5.0);
  EXPECT_FALSE(gated.accepted);
  EXPECT_GT(gated.normalized, 5.0);
  EXPECT_TRUE(a.state().isApprox(b.state(), 1e-12));
}

TEST(Kalman, PredictAndUpdateAllocateNothing) {
  static_assert(noexcept(std::declval<KF2&>().predict(std::declval<const Eigen::Matrix2d&>(),
                                                      std::declval<const Eigen::Matrix2d&>())));
  static_assert(noexcept(
      std::declval<KF2&>().update(std::declval<const Eigen::RowVector2d&>(), 0.0, 1.0, 5.0)));
  KF2 kf;
  const Eigen::Matrix2d h2 = Eigen::Matrix2d::Identity();
  const Eigen::Matrix2d r2 = Eigen::Matrix2d::Identity();
  nccomp::test::AllocationScope scope;
  for (int i = 0; i < 100; ++i) {
    kf.predict(cv_transition(1.0), cv_process_noise(1.0, 1e-3, 1e-6));
    kf.update(Eigen::RowVector2d(1.0, 0.0), 0.1 * i, 1.0, 5.0);
    kf.update<2>(h2, Eigen::Vector2d(0.1 * i, 0.1), r2, 5.0);
  }
  EXPECT_EQ(scope.count(), 0U);
  EXPECT_EQ(scope.frees(), 0U);
}

}  // namespace
