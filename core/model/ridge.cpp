#include "core/model/ridge.hpp"

#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>
#include <utility>

namespace nccomp::core::model {

double RidgeFit::predict(std::span<const double> x) const noexcept {
  if (x.size() != weight.size()) {
    return std::numeric_limits<double>::quiet_NaN();
  }
  double v = offset;
  for (std::size_t j = 0; j < x.size(); ++j) {
    v += weight[j] * x[j];
  }
  return v;
}

RidgeFit fit_ridge(const Eigen::MatrixXd& x, const Eigen::VectorXd& y, double lambda) {
  if (!(lambda > 0.0) || !std::isfinite(lambda)) {
    throw std::invalid_argument("ridge: lambda must be > 0 and finite, got " +
                                std::to_string(lambda));
  }
  if (x.rows() != y.size()) {
    throw std::invalid_argument("ridge: " + std::to_string(x.rows()) + " input rows but " +
                                std::to_string(y.size()) + " values");
  }
  if (x.rows() < 2 || x.cols() < 1) {
    throw std::invalid_argument("ridge: needs at least 2 rows and 1 input");
  }
  if (!x.allFinite() || !y.allFinite()) {
    throw std::invalid_argument("ridge: a value is not finite");
  }
  const auto n = static_cast<double>(x.rows());
  const Eigen::RowVectorXd mean = x.colwise().mean();
  const Eigen::MatrixXd centred = x.rowwise() - mean;
  Eigen::RowVectorXd sd = (centred.colwise().squaredNorm() / n).cwiseSqrt();
  for (Eigen::Index j = 0; j < sd.size(); ++j) {
    if (!(sd(j) > 1e-12 * (1.0 + std::fabs(mean(j))))) {
      sd(j) = std::numeric_limits<double>::infinity();  // a constant column: z = 0, weight 0
    }
  }
  const Eigen::MatrixXd z = centred.array().rowwise() / sd.array();
  const double ym = y.mean();
  Eigen::MatrixXd a = z.transpose() * z;
  a.diagonal().array() += lambda * n;
  const Eigen::VectorXd w = a.ldlt().solve(z.transpose() * (y.array() - ym).matrix());
  RidgeFit f;
  f.lambda = lambda;
  f.offset = ym;
  f.weight.resize(static_cast<std::size_t>(x.cols()));
  for (Eigen::Index j = 0; j < x.cols(); ++j) {
    const double raw = w(j) / sd(j);
    f.weight[static_cast<std::size_t>(j)] = raw;
    f.offset -= raw * mean(j);
  }
  return f;
}

double rolling_origin_rms(const Eigen::MatrixXd& x, const Eigen::VectorXd& y, double lambda,
                          std::size_t blocks) {
  if (blocks < 2 || static_cast<std::size_t>(x.rows()) < 2 * blocks) {
    throw std::invalid_argument("ridge: " + std::to_string(blocks) + " blocks need at least " +
                                std::to_string(2 * blocks) + " rows, got " +
                                std::to_string(x.rows()));
  }
  const auto n = static_cast<std::size_t>(x.rows());
  const auto edge = [&](std::size_t k) { return static_cast<Eigen::Index>(k * n / blocks); };
  double ss = 0.0;
  std::size_t m = 0;
  for (std::size_t k = 1; k < blocks; ++k) {
    const RidgeFit f = fit_ridge(x.topRows(edge(k)), y.head(edge(k)), lambda);
    const Eigen::Map<const Eigen::VectorXd> w(f.weight.data(),
                                              static_cast<Eigen::Index>(f.weight.size()));
    for (Eigen::Index i = edge(k); i < edge(k + 1); ++i) {
      const double r = y(i) - (f.offset + x.row(i).dot(w));
      ss += r * r;
      ++m;
    }
  }
  return std::sqrt(ss / static_cast<double>(m));
}

RidgeFit fit_ridge_rolling(const Eigen::MatrixXd& x, const Eigen::VectorXd& y,
                           std::span<const double> lambdas, std::size_t blocks) {
  if (lambdas.empty()) {
    throw std::invalid_argument("ridge: no lambda to choose from");
  }
  std::vector<double> errors;
  std::size_t best = 0;
  for (std::size_t i = 0; i < lambdas.size(); ++i) {
    errors.push_back(rolling_origin_rms(x, y, lambdas[i], blocks));
    if (errors[i] < errors[best]) {
      best = i;
    }
  }
  RidgeFit f = fit_ridge(x, y, lambdas[best]);
  f.rolling_rms = std::move(errors);
  return f;
}

}  // namespace nccomp::core::model
