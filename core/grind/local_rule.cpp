#include "core/grind/local_rule.hpp"

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

namespace nccomp::core::grind {

Derivatives local_derivatives(const UniformProfile& profile, const FitSpec& fit) {
  if (fit.degree < 1 || fit.degree > 8) {
    throw std::invalid_argument("fit degree must be 1..8, got " + std::to_string(fit.degree));
  }
  const int pts = fit.points == 0 ? fit.degree + 1 : fit.points;
  if (pts < fit.degree + 1 || pts > 64) {
    throw std::invalid_argument(
        "fit points must be degree + 1 = " + std::to_string(fit.degree + 1) + " .. 64, got " +
        std::to_string(pts));
  }
  const auto n = static_cast<std::ptrdiff_t>(profile.size());
  if (n < pts) {
    throw std::invalid_argument("a degree-" + std::to_string(fit.degree) + " fit through " +
                                std::to_string(pts) + " samples needs at least " +
                                std::to_string(pts) + " samples, the profile has " +
                                std::to_string(n));
  }
  if (!(profile.spacing_mm > 0.0)) {
    throw std::invalid_argument("profile spacing must be > 0 mm");
  }
  for (std::ptrdiff_t i = 0; i < n; ++i) {
    if (!std::isfinite(profile.u_mm[static_cast<std::size_t>(i)])) {
      throw std::invalid_argument("profile value at z = " + std::to_string(profile.z_at(i)) +
                                  " mm is not finite");
    }
  }
  // On a uniform grid the fitted derivative at offset o inside the stencil is a fixed linear
  // combination of the stencil's samples (Savitzky–Golay): one weight row per offset.
  const int deg = fit.degree;
  Eigen::MatrixXd w1(pts, pts);
  Eigen::MatrixXd w2(pts, pts);
  for (int o = 0; o < pts; ++o) {
    Eigen::MatrixXd a(pts, deg + 1);
    for (int q = 0; q < pts; ++q) {
      const double x = static_cast<double>(q - o);
      double p = 1.0;
      for (int c = 0; c <= deg; ++c) {
        a(q, c) = p;
        p *= x;
      }
    }
    const Eigen::MatrixXd pinv = a.completeOrthogonalDecomposition().pseudoInverse();
    w1.row(o) = pinv.row(1) / profile.spacing_mm;
    w2.row(o) =
        deg >= 2 ? Eigen::RowVectorXd(2.0 * pinv.row(2) / (profile.spacing_mm * profile.spacing_mm))
                 : Eigen::RowVectorXd::Zero(pts);
  }
  Derivatives d;
  d.slope.resize(static_cast<std::size_t>(n));
  d.curvature.resize(static_cast<std::size_t>(n));
  const std::ptrdiff_t back = (pts - 1) / 2;
  for (std::ptrdiff_t i = 0; i < n; ++i) {
    const std::ptrdiff_t s = std::clamp<std::ptrdiff_t>(i - back, 0, n - pts);
    const auto o = static_cast<Eigen::Index>(i - s);
    double k1 = 0.0;
    double k2 = 0.0;
    for (int q = 0; q < pts; ++q) {
      const double u = profile.u_mm[static_cast<std::size_t>(s + q)];
      k1 += w1(o, q) * u;
      k2 += w2(o, q) * u;
    }
    d.slope[static_cast<std::size_t>(i)] = k1;
    d.curvature[static_cast<std::size_t>(i)] = k2;
  }
  return d;
}

LocalTrajectory local_rule_trajectory(const UniformProfile& profile, const Derivatives& d,
                                      const Wheel& wheel) {
  const std::size_t n = profile.size();
  if (d.slope.size() != n) {
    throw std::invalid_argument("local rule: one slope per sample needed");
  }
  LocalTrajectory t;
  t.point.assign(n, TrajectoryPoint{0.0, 0.0});
  t.contact.assign(n, ContactCase::kTangent);
  const double half = wheel.half_width_mm();
  const double r = wheel.radius_mm();
  const double sin_limit = wheel.straight() ? 0.0 : half / r;
  const double end_rise = wheel.rise_mm(half);
  for (std::size_t i = 0; i < n; ++i) {
    const double z = profile.z_at(static_cast<std::ptrdiff_t>(i));
    const double u = profile.u_mm[i];
    const double k1 = d.slope[i];
    const double sec = std::sqrt(1.0 + k1 * k1);
    const double sin_a = k1 / sec;
    const double cos_a = 1.0 / sec;
    if (!wheel.straight() && std::abs(sin_a) <= sin_limit) {
      // 1 − cos a = sin²a / (1 + cos a): no cancellation for gentle slopes.
      t.point[i] = {z - r * sin_a, u - r * sin_a * sin_a / (1.0 + cos_a)};
      t.contact[i] = ContactCase::kTangent;
    } else if (k1 > 0.0) {
      t.point[i] = {z - half, u - end_rise};  // the front (+Z) end rides on the rising flank
      t.contact[i] = ContactCase::kFrontEnd;
    } else {
      t.point[i] = {z + half, u - end_rise};
      t.contact[i] = ContactCase::kRearEnd;
    }
  }
  return t;
}

}  // namespace nccomp::core::grind
