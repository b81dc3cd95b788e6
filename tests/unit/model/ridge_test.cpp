// core/model/ridge.hpp: the shrunk fit against closed forms, and λ chosen by the rolling-origin
// error on the fitted rows.
#include "core/model/ridge.hpp"

#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <random>
#include <stdexcept>
#include <vector>

namespace nccomp::core::model {
namespace {

TEST(Ridge, OneInputIsTheLeastSquaresSlopeShrunkByOnePlusLambda) {
  // One standardised input z: w_z = (z'y / n) / (1 + λ), so the raw slope is
  // cov(x, y) / (var(x) (1 + λ)) and the line passes through the means.
  const Eigen::VectorXd x0{{1.0, 2.0, 4.0, 7.0, 8.0}};
  const Eigen::VectorXd y{{3.0, 2.5, 6.0, 9.0, 12.0}};
  const Eigen::MatrixXd x = x0;
  const double xm = x0.mean();
  const double ym = y.mean();
  const double cov = ((x0.array() - xm) * (y.array() - ym)).mean();
  const double var = (x0.array() - xm).square().mean();
  for (const double lambda : {1e-6, 0.1, 1.0, 10.0}) {
    const RidgeFit f = fit_ridge(x, y, lambda);
    ASSERT_EQ(f.weight.size(), 1U);
    const double slope = cov / (var * (1.0 + lambda));
    EXPECT_NEAR(f.weight[0], slope, 1e-12 * std::fabs(slope)) << lambda;
    EXPECT_NEAR(f.offset, ym - slope * xm, 1e-9) << lambda;
    const std::array<double, 1> at{xm};
    EXPECT_NEAR(f.predict(at), ym, 1e-9);
  }
}

TEST(Ridge, ASmallLambdaRecoversAnExactLinearModel) {
  std::mt19937 rng(3);
  std::normal_distribution<double> n01;
  Eigen::MatrixXd x(200, 3);
  Eigen::VectorXd y(200);
  for (int i = 0; i < 200; ++i) {
    x.row(i) << 20.0 + n01(rng), 25.0 + 3.0 * n01(rng), n01(rng);
    y(i) = 3.0 + 2.0 * x(i, 0) - 1.0 * x(i, 1) + 0.5 * x(i, 2);
  }
  const RidgeFit f = fit_ridge(x, y, 1e-10);
  EXPECT_NEAR(f.weight[0], 2.0, 1e-6);
  EXPECT_NEAR(f.weight[1], -1.0, 1e-6);
  EXPECT_NEAR(f.weight[2], 0.5, 1e-6);
  EXPECT_NEAR(f.offset, 3.0, 1e-4);
}

TEST(Ridge, CollinearInputsShareTheWeightAndAConstantInputGetsNone) {
  // Two copies of one input: the penalty splits its weight equally; the fit stays finite where
  // least squares has no unique solution. A constant column carries no information.
  Eigen::MatrixXd x(6, 3);
  Eigen::VectorXd y(6);
  for (int i = 0; i < 6; ++i) {
    x.row(i) << i, i, 21.5;
    y(i) = 1.0 + 0.5 * i;
  }
  const RidgeFit f = fit_ridge(x, y, 0.01);
  EXPECT_NEAR(f.weight[0], f.weight[1], 1e-12);
  EXPECT_EQ(f.weight[2], 0.0);
  // Together they are one input shrunk by 1 + λ / 2 (each copy holds half the variance).
  EXPECT_NEAR(f.weight[0] + f.weight[1], 0.5 / (1.0 + 0.01 / 2.0), 1e-12);
}

TEST(Ridge, RefusesWhatItCannotFit) {
  const Eigen::MatrixXd x = Eigen::MatrixXd::Ones(4, 2);
  const Eigen::VectorXd y = Eigen::VectorXd::Ones(4);
  EXPECT_THROW((void)fit_ridge(x, y, 0.0), std::invalid_argument);
  EXPECT_THROW((void)fit_ridge(x, y, -1.0), std::invalid_argument);
  EXPECT_THROW((void)fit_ridge(x, y, std::nan("")), std::invalid_argument);
  EXPECT_THROW((void)fit_ridge(x, Eigen::VectorXd::Ones(3), 1.0), std::invalid_argument);
  Eigen::MatrixXd bad = x;
  bad(2, 1) = std::nan("");
  EXPECT_THROW((void)fit_ridge(bad, y, 1.0), std::invalid_argument);
  const std::vector<double> none;
  EXPECT_THROW((void)fit_ridge_rolling(x, y, none, 2), std::invalid_argument);
  const std::vector<double> one{1.0};
  EXPECT_THROW((void)fit_ridge_rolling(x, y, one, 3), std::invalid_argument);  // 4 rows, 3 blocks
}

TEST(Ridge, TheRollingOriginErrorPredictsEachBlockFromTheBlocksBefore) {
  // Two blocks of 4 rows: the second predicted by the fit to the first, by hand.
  Eigen::MatrixXd x(8, 1);
  Eigen::VectorXd y(8);
  for (int i = 0; i < 8; ++i) {
    x(i, 0) = i * i * 0.5;
    y(i) = std::sin(i) + i;
  }
  const RidgeFit first = fit_ridge(x.topRows(4), y.head(4), 0.3);
  double ss = 0.0;
  for (int i = 4; i < 8; ++i) {
    const std::array<double, 1> at{x(i, 0)};
    ss += std::pow(y(i) - first.predict(at), 2);
  }
  EXPECT_NEAR(rolling_origin_rms(x, y, 0.3, 2), std::sqrt(ss / 4.0), 1e-12);
}

TEST(Ridge, LambdaIsChosenByTheRollingOriginError) {
  std::mt19937 rng(11);
  std::normal_distribution<double> n01;
  const std::vector<double> lambdas{1e-4, 1e-2, 1.0, 100.0};
  // Nothing but noise in 12 inputs: the strongest shrinkage predicts the later blocks best.
  Eigen::MatrixXd x(120, 12);
  Eigen::VectorXd y(120);
  for (int i = 0; i < 120; ++i) {
    for (int j = 0; j < 12; ++j) {
      x(i, j) = n01(rng);
    }
    y(i) = n01(rng);
  }
  RidgeFit f = fit_ridge_rolling(x, y, lambdas, 4);
  ASSERT_EQ(f.rolling_rms.size(), lambdas.size());
  EXPECT_EQ(f.lambda, 100.0);
  for (const double e : f.rolling_rms) {
    EXPECT_GE(e, f.rolling_rms[3]);
  }
  // An exact linear relation: the weakest shrinkage.
  for (int i = 0; i < 120; ++i) {
    y(i) = x(i, 0) - 2.0 * x(i, 5);
  }
  f = fit_ridge_rolling(x, y, lambdas, 4);
  EXPECT_EQ(f.lambda, 1e-4);
  EXPECT_NEAR(f.rolling_rms[0], rolling_origin_rms(x, y, 1e-4, 4), 1e-12);
}

}  // namespace
}  // namespace nccomp::core::model
