#include "core/grind/compare.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

namespace nccomp::core::grind {

std::vector<double> lowest_pass_on_grid(std::span<const TrajectoryPoint> q, double z0_mm,
                                        double spacing_mm, std::size_t count) {
  std::vector<double> out(count, std::numeric_limits<double>::quiet_NaN());
  const auto last = static_cast<double>(count) - 1.0;
  const auto visit = [&](double x, double u) {
    auto& o = out[static_cast<std::size_t>(x)];
    o = std::isnan(o) ? u : std::min(o, u);
  };
  const std::size_t segments = q.size() > 1 ? q.size() - 1 : q.size();
  for (std::size_t i = 0; i < segments; ++i) {
    const auto& a = q[i];
    const auto& b = q[std::min(i + 1, q.size() - 1)];
    const double xa = (a.z_mm - z0_mm) / spacing_mm;
    const double xb = (b.z_mm - z0_mm) / spacing_mm;
    const double lo = std::max(0.0, std::ceil(std::min(xa, xb) - 1e-9));
    const double hi = std::min(last, std::floor(std::max(xa, xb) + 1e-9));
    for (double x = lo; x <= hi; x += 1.0) {
      if (!(std::abs(xb - xa) > 0.0)) {
        visit(x, std::min(a.u_mm, b.u_mm));
      } else {
        const double f = std::clamp((x - xa) / (xb - xa), 0.0, 1.0);
        visit(x, a.u_mm + f * (b.u_mm - a.u_mm));
      }
    }
  }
  return out;
}

std::vector<Region> regions_above(std::span<const double> dev_mm, double z0_mm, double spacing_mm,
                                  double tol_mm) {
  std::vector<Region> out;
  bool open = false;
  for (std::size_t t = 0; t < dev_mm.size(); ++t) {
    const double z = z0_mm + static_cast<double>(t) * spacing_mm;
    const double v = dev_mm[t];
    if (v > tol_mm) {  // false for NaN
      if (!open) {
        out.push_back(Region{z, z, v, z});
        open = true;
      }
      auto& r = out.back();
      r.z_to_mm = z;
      if (v > r.worst_mm) {
        r.worst_mm = v;
        r.z_worst_mm = z;
      }
    } else {
      open = false;
    }
  }
  return out;
}

double concave_radius_mm(double slope, double curvature_per_mm) noexcept {
  if (!(curvature_per_mm > 0.0)) {
    return std::numeric_limits<double>::infinity();
  }
  const double s = 1.0 + slope * slope;
  const double r = s * std::sqrt(s) / curvature_per_mm;
  // Radii beyond 10⁹ mm are the fit's rounding noise on straight parts, not concavity.
  return r > kStraightRadiusMm ? std::numeric_limits<double>::infinity() : r;
}

void classify_regions(std::vector<Region>& regions, std::span<const double> key_z_mm,
                      const UniformProfile& profile, const Derivatives& d,
                      const LocalTrajectory* local, const Wheel& wheel) {
  if (regions.empty()) {
    return;
  }
  const double half = wheel.half_width_mm();
  const double z_first = profile.z0_mm;
  const double z_last = profile.z_last_mm();
  const double tol = 0.5 * profile.spacing_mm;
  for (std::size_t i = 0; i < key_z_mm.size() && i < profile.size(); ++i) {
    const double key = key_z_mm[i];
    auto it = std::upper_bound(regions.begin(), regions.end(), key,
                               [](double v, const Region& r) { return v < r.z_from_mm - 0; });
    if (it == regions.begin()) {
      continue;
    }
    --it;
    if (key > it->z_to_mm + tol || key < it->z_from_mm - tol) {
      continue;
    }
    const double z = profile.z_at(static_cast<std::ptrdiff_t>(i));
    const double rc = concave_radius_mm(d.slope[i], d.curvature[i]);
    if (rc < wheel.radius_mm()) {
      it->concave_below_radius = true;
    }
    if (std::isfinite(rc) &&
        (!(it->min_concave_radius_mm > 0.0) || rc < it->min_concave_radius_mm)) {
      it->min_concave_radius_mm = rc;
    }
    if (z - z_first < half || z_last - z < half) {
      it->near_end = true;
    }
    if (local != nullptr && local->contact[i] != ContactCase::kTangent) {
      it->arc_end_contact = true;
    }
  }
}

}  // namespace nccomp::core::grind
