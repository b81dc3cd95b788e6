#include "core/grind/local_rule.hpp"

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

namespace nccomp::core::grind {
namespace {

// The three cases for sample (z, u) of fitted slope k1.
LocalRule::Sample place(double z, double u, double k1, double k2, const Wheel& wheel) noexcept {
  const double half = wheel.half_width_mm();
  const double sec = std::sqrt(1.0 + k1 * k1);
  const double sin_a = k1 / sec;
  const double cos_a = 1.0 / sec;
  if (!wheel.straight() && std::abs(sin_a) <= half / wheel.radius_mm()) {
    // 1 − cos a = sin²a / (1 + cos a): no cancellation for gentle slopes.
    const double r = wheel.radius_mm();
    return {{z - r * sin_a, u - r * sin_a * sin_a / (1.0 + cos_a)}, ContactCase::kTangent, k1, k2};
  }
  const double end_rise = wheel.rise_mm(half);
  if (k1 > 0.0) {  // the front (+Z) end rides on the rising flank
    return {{z - half, u - end_rise}, ContactCase::kFrontEnd, k1, k2};
  }
  return {{z + half, u - end_rise}, ContactCase::kRearEnd, k1, k2};
}

}  // namespace

LocalRule::LocalRule(const UniformProfile& profile, const FitSpec& fit, const Wheel& wheel)
    : profile_(&profile), wheel_(wheel) {
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
  points_ = pts;
  const int deg = fit.degree;
  const auto size = static_cast<std::size_t>(pts);
  w1_.assign(size * size, 0.0);
  w2_.assign(size * size, 0.0);
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
    for (int q = 0; q < pts; ++q) {
      const auto k = static_cast<std::size_t>(o) * size + static_cast<std::size_t>(q);
      w1_[k] = pinv(1, q) / profile.spacing_mm;
      w2_[k] = deg >= 2 ? 2.0 * pinv(2, q) / (profile.spacing_mm * profile.spacing_mm) : 0.0;
    }
  }
}

double LocalRule::apply(const std::vector<double>& w, std::size_t i) const noexcept {
  // Centred stencil, shifted inward at the ends.
  const auto n = profile_->size();
  const auto pts = static_cast<std::size_t>(points_);
  const std::size_t back = (pts - 1) / 2;
  const std::size_t s = std::min(i > back ? i - back : 0, n - pts);
  const double* row = w.data() + (i - s) * pts;
  const double* u = profile_->u_mm.data() + s;
  double acc = 0.0;
  for (std::size_t q = 0; q < pts; ++q) {
    acc += row[q] * u[q];
  }
  return acc;
}

double LocalRule::slope(std::size_t i) const noexcept { return apply(w1_, i); }

double LocalRule::curvature(std::size_t i) const noexcept { return apply(w2_, i); }

LocalRule::Sample LocalRule::at(std::size_t i) const noexcept {
  return place(profile_->z_at(static_cast<std::ptrdiff_t>(i)), profile_->u_mm[i], slope(i),
               curvature(i), wheel_);
}

Derivatives local_derivatives(const UniformProfile& profile, const FitSpec& fit) {
  // The wheel does not enter the derivatives; any valid one will do.
  const LocalRule rule(profile, fit, Wheel::from_arc_height(1.0, 0.0));
  // Sized at construction: resize() here trips GCC 12's -Wnull-dereference at -O3.
  Derivatives d{std::vector<double>(profile.size(), 0.0), std::vector<double>(profile.size(), 0.0)};
  for (std::size_t i = 0; i < profile.size(); ++i) {
    d.slope[i] = rule.slope(i);
    d.curvature[i] = rule.curvature(i);
  }
  return d;
}

LocalTrajectory local_rule_trajectory(const UniformProfile& profile, const Derivatives& d,
                                      const Wheel& wheel) {
  const std::size_t n = profile.size();
  if (d.slope.size() != n || d.curvature.size() != n) {
    throw std::invalid_argument("local rule: one slope and curvature per sample needed");
  }
  LocalTrajectory t{std::vector<TrajectoryPoint>(n, TrajectoryPoint{0.0, 0.0}),
                    std::vector<ContactCase>(n, ContactCase::kTangent)};
  for (std::size_t i = 0; i < n; ++i) {
    const auto s = place(profile.z_at(static_cast<std::ptrdiff_t>(i)), profile.u_mm[i], d.slope[i],
                         d.curvature[i], wheel);
    t.point[i] = s.point;
    t.contact[i] = s.contact;
  }
  return t;
}

}  // namespace nccomp::core::grind
