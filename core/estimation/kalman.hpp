// A linear Kalman filter with a fixed-size state (issue 22): predict with a transition and a
// process noise, update with a scalar or a small vector measurement, innovation gating, the
// covariance exposed. Fixed-size Eigen matrices only, so every step is allocation-free; no
// clock, no I/O: time steps come in as arguments (architecture.md, core/ is pure).
//
// Lifecycle: reset() sets the prior; predict() / update() are the real-time steps.
#pragma once

#include <algorithm>
#include <cmath>
#include <limits>

#include <Eigen/Cholesky>
#include <Eigen/Core>

namespace nccomp::core::estimation {

/// What an update did with a measurement.
struct UpdateResult {
  /// False: the measurement was gated (or invalid) and changed nothing.
  bool accepted{false};
  /// Normalised innovation: |ν|/sqrt(S) for a scalar, sqrt(νᵀS⁻¹ν) for a vector (NaN if the
  /// innovation covariance was not positive definite or the measurement not finite).
  double normalized{std::numeric_limits<double>::quiet_NaN()};
};

/// Gate: a measurement whose normalised innovation exceeds gate_sigmas is not absorbed. A
/// gate_sigmas of 0 (or less, or +inf) switches the gate off.
inline bool within_gate(double normalized, double gate_sigmas) noexcept {
  if (!(gate_sigmas > 0.0) || std::isinf(gate_sigmas)) return std::isfinite(normalized);
  return normalized <= gate_sigmas;
}

template <int N>
class KalmanFilter {
 public:
  static_assert(N >= 1 && N <= 8, "a small fixed-size state");
  using Vector = Eigen::Matrix<double, N, 1>;
  using Matrix = Eigen::Matrix<double, N, N>;
  using Row = Eigen::Matrix<double, 1, N>;

  KalmanFilter() noexcept { reset(Vector::Zero(), Matrix::Identity()); }

  /// Sets the state and its covariance (the prior). Real-time safe.
  void reset(const Vector& x, const Matrix& p) noexcept {
    x_ = x;
    p_ = p;
  }

  /// x ← F·x, P ← F·P·Fᵀ + Q. Real-time safe: no allocation, no locks, no I/O.
  void predict(const Matrix& f, const Matrix& q) noexcept {
    x_ = f * x_;
    p_ = f * p_ * f.transpose() + q;
    p_ = 0.5 * (p_ + p_.transpose()).eval();
  }

  /// Predicted measurement h·x and its variance h·P·hᵀ + r for a scalar measurement.
  /// Real-time safe.
  [[nodiscard]] double predicted_measurement(const Row& h) const noexcept { return h * x_; }
  [[nodiscard]] double innovation_variance(const Row& h, double r) const noexcept {
    return (h * p_ * h.transpose())(0, 0) + r;
  }

  /// Scalar measurement z = h·x + v, Var v = r [units² of z]. Gated beyond gate_sigmas of the
  /// innovation's standard deviation (see within_gate()): then nothing changes and accepted is
  /// false. Joseph form, so P stays symmetric positive semi-definite. Real-time safe.
  UpdateResult update(const Row& h, double z, double r, double gate_sigmas) noexcept {
    UpdateResult res;
    const double s = innovation_variance(h, r);
    if (!std::isfinite(z) || !(s > 0.0) || !std::isfinite(s)) return res;
    const double nu = z - predicted_measurement(h);
    res.normalized = std::fabs(nu) / std::sqrt(s);
    if (!within_gate(res.normalized, gate_sigmas)) return res;
    const Vector k = p_ * h.transpose() / s;
    x_ += k * nu;
    const Matrix a = Matrix::Identity() - k * h;
    p_ = a * p_ * a.transpose() + k * r * k.transpose();
    p_ = 0.5 * (p_ + p_.transpose()).eval();
    res.accepted = true;
    return res;
  }

  /// Vector measurement z = H·x + v, Cov v = R (M ≤ 4), gated on sqrt(νᵀS⁻¹ν). Real-time safe.
  template <int M>
  UpdateResult update(const Eigen::Matrix<double, M, N>& h, const Eigen::Matrix<double, M, 1>& z,
                      const Eigen::Matrix<double, M, M>& r, double gate_sigmas) noexcept {
    static_assert(M >= 1 && M <= 4, "a small vector measurement");
    UpdateResult res;
    if (!z.allFinite()) return res;
    const Eigen::Matrix<double, M, M> s = h * p_ * h.transpose() + r;
    const Eigen::LLT<Eigen::Matrix<double, M, M>> llt(s);
    if (llt.info() != Eigen::Success) return res;
    const Eigen::Matrix<double, M, 1> nu = z - h * x_;
    const double d2 = nu.dot(llt.solve(nu));
    res.normalized = std::sqrt(std::max(0.0, d2));
    if (!within_gate(res.normalized, gate_sigmas)) return res;
    // K = P·Hᵀ·S⁻¹, from S·Kᵀ = H·P (S and P symmetric).
    const Eigen::Matrix<double, N, M> k = llt.solve(h * p_).transpose();
    x_ += k * nu;
    const Matrix a = Matrix::Identity() - k * h;
    p_ = a * p_ * a.transpose() + k * r * k.transpose();
    p_ = 0.5 * (p_ + p_.transpose()).eval();
    res.accepted = true;
    return res;
  }

  [[nodiscard]] const Vector& state() const noexcept { return x_; }
  [[nodiscard]] const Matrix& covariance() const noexcept { return p_; }

 private:
  Vector x_;
  Matrix p_;
};

// ---- The constant-velocity (level + rate) model over a scalar "clock" (path or time) -------

/// Transition of a level and its rate over a clock step d: [[1, d], [0, 1]]. Real-time safe.
Eigen::Matrix2d cv_transition(double d) noexcept;

/// Process noise of the level + rate model over a clock step d ≥ 0: a random walk of the
/// level with spectral density q_level [level² per clock unit] plus a random walk of the rate
/// with density q_rate [rate² per clock unit], the rate's walk integrated into the level:
///   Q = q_level·[[d, 0], [0, 0]] + q_rate·[[d³/3, d²/2], [d²/2, d]].
/// Real-time safe.
Eigen::Matrix2d cv_process_noise(double d, double q_level, double q_rate) noexcept;

/// Steady-state Kalman gain of a random walk x' = x + w (Var w = q) measured directly
/// (Var v = r > 0): the positive root of r·K² + q·K − q = 0,
///   K∞ = (−q + sqrt(q² + 4·q·r)) / (2·r),
/// from P⁻ = P⁺ + q and P⁺ = K·r with K = P⁻/(P⁻ + r). It is the weight of the equivalent
/// exponentially weighted moving average. Real-time safe.
double random_walk_steady_gain(double q, double r) noexcept;

}  // namespace nccomp::core::estimation
