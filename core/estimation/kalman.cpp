#include "core/estimation/kalman.hpp"

namespace nccomp::core::estimation {

Eigen::Matrix2d cv_transition(double d) noexcept {
  Eigen::Matrix2d f;
  f << 1.0, d, 0.0, 1.0;
  return f;
}

Eigen::Matrix2d cv_process_noise(double d, double q_level, double q_rate) noexcept {
  Eigen::Matrix2d q;
  q << q_level * d + q_rate * d * d * d / 3.0, q_rate * d * d / 2.0, q_rate * d * d / 2.0,
      q_rate * d;
  return q;
}

double random_walk_steady_gain(double q, double r) noexcept {
  return (-q + std::sqrt(q * q + 4.0 * q * r)) / (2.0 * r);
}

}  // namespace nccomp::core::estimation
