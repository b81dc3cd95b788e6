// A shrunk (ridge) linear fit of one measured value on many inputs at once: the alternative to
// picking a few of many nearly collinear sensors (16 temperatures of one machine move together).
// Each input is standardised on the fitted rows; the fit minimises
//   Σ (y − b − Σ_j w_j z_j)² + λ n Σ_j w_j²,   z_j = (x_j − mean_j) / sd_j,
// with n the number of rows, so λ is comparable across row counts. λ is chosen on the fitted rows
// alone by a rolling-origin error (the rows split into `blocks` blocks in their order; each block
// after the first predicted by a fit to the blocks before it), never on rows it is judged on.
// The result in raw units, value = offset + Σ_j weight_j x_j, is what a derived sensor
// ([[input_sums]]) computes in the daemon. Off the loop: allocates.
#pragma once

#include <Eigen/Dense>
#include <cstddef>
#include <span>
#include <vector>

namespace nccomp::core::model {

struct RidgeFit {
  double lambda{0.0};
  /// Raw units: value = offset + Σ weight[j] · x[j].
  double offset{0.0};
  std::vector<double> weight;
  /// The rolling-origin RMS error of each λ tried, in the order given (empty for fit_ridge()).
  std::vector<double> rolling_rms;

  [[nodiscard]] double predict(std::span<const double> x) const noexcept;
};

/// Ridge fit at one λ > 0 on the rows of x (one row per observation, one column per input).
/// Throws std::invalid_argument for λ ≤ 0 or not finite, a size mismatch, fewer than 2 rows or
/// a non-finite value. A constant column gets weight 0.
RidgeFit fit_ridge(const Eigen::MatrixXd& x, const Eigen::VectorXd& y, double lambda);

/// RMS error of each block after the first, predicted by the fit (at λ) to the blocks before it.
double rolling_origin_rms(const Eigen::MatrixXd& x, const Eigen::VectorXd& y, double lambda,
                          std::size_t blocks);

/// The λ among `lambdas` with the smallest rolling-origin error, fitted on every row. Throws
/// std::invalid_argument for an empty list, blocks < 2 or a block with fewer than 2 rows.
RidgeFit fit_ridge_rolling(const Eigen::MatrixXd& x, const Eigen::VectorXd& y,
                           std::span<const double> lambdas, std::size_t blocks);

}  // namespace nccomp::core::model
