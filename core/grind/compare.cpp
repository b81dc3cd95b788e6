#include "core/grind/compare.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

namespace nccomp::core::grind {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// Lowest pass of the polyline through n points pt(0), pt(1), … (each point asked for once).
template <class Points>
std::vector<double> lowest_pass_impl(std::size_t n, Points&& pt, double z0_mm, double spacing_mm,
                                     std::size_t count) {
  std::vector<double> out(count, kNaN);
  if (n == 0) {
    return out;
  }
  const auto last = static_cast<double>(count) - 1.0;
  const auto visit = [&](double x, double u) {
    auto& o = out[static_cast<std::size_t>(x)];
    o = std::isnan(o) ? u : std::min(o, u);
  };
  const auto segment = [&](const TrajectoryPoint& a, const TrajectoryPoint& b) {
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
  };
  TrajectoryPoint a = pt(std::size_t{0});
  if (n == 1) {
    segment(a, a);
    return out;
  }
  for (std::size_t i = 1; i < n; ++i) {
    const TrajectoryPoint b = pt(i);
    segment(a, b);
    a = b;
  }
  return out;
}

void mark_concave(Region& r, double slope, double curvature, const Wheel& wheel) {
  const double rc = concave_radius_mm(slope, curvature);
  if (rc < wheel.radius_mm()) {
    r.concave_below_radius = true;
  }
  if (std::isfinite(rc) && (!(r.min_concave_radius_mm > 0.0) || rc < r.min_concave_radius_mm)) {
    r.min_concave_radius_mm = rc;
  }
}

// Within W/2 of an end of the profile: the wheel overhangs the roll there (and the slope fit's
// stencil is one-sided at the very end).
void mark_near_end(std::vector<Region>& regions, const UniformProfile& p, const Wheel& wheel) {
  const double half = wheel.half_width_mm();
  for (auto& r : regions) {
    r.near_end = r.z_from_mm < p.z0_mm + half || r.z_to_mm > p.z_last_mm() - half;
  }
}

}  // namespace

std::vector<double> lowest_pass_on_grid(std::span<const TrajectoryPoint> q, double z0_mm,
                                        double spacing_mm, std::size_t count) {
  return lowest_pass_impl(
      q.size(), [q](std::size_t i) { return q[i]; }, z0_mm, spacing_mm, count);
}

std::vector<double> lowest_pass_on_grid(const LocalRule& rule, double z0_mm, double spacing_mm,
                                        std::size_t count) {
  return lowest_pass_impl(
      rule.size(), [&rule](std::size_t i) { return rule.at(i).point; }, z0_mm, spacing_mm, count);
}

void RegionBuilder::add(std::size_t t, double v) {
  if (v > tol_mm_) {  // false for NaN
    const double z = z0_mm_ + static_cast<double>(t) * spacing_mm_;
    if (!open_) {
      regions_.push_back(Region{z, z, v, z});
      open_ = true;
    }
    auto& r = regions_.back();
    r.z_to_mm = z;
    if (v > r.worst_mm) {
      r.worst_mm = v;
      r.z_worst_mm = z;
    }
  } else {
    open_ = false;
  }
}

std::vector<Region> regions_above(std::span<const double> dev_mm, double z0_mm, double spacing_mm,
                                  double tol_mm) {
  RegionBuilder b(z0_mm, spacing_mm, tol_mm);
  for (std::size_t t = 0; t < dev_mm.size(); ++t) {
    b.add(t, dev_mm[t]);
  }
  return b.finish();
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

RuleComparison compare_rule_with_envelope(const LocalRule& rule, const GridTrajectory& exact,
                                          double tol_mm, std::vector<double>* rule_on_grid) {
  RuleComparison c;
  std::size_t cases[4] = {0, 0, 0, 0};
  auto grid = lowest_pass_impl(
      rule.size(),
      [&](std::size_t i) {
        const auto s = rule.at(i);
        ++cases[static_cast<int>(s.contact)];
        return s.point;
      },
      exact.z0_mm, exact.spacing_mm, exact.u_mm.size());
  c.tangent = cases[static_cast<int>(ContactCase::kTangent)];
  c.front_end = cases[static_cast<int>(ContactCase::kFrontEnd)];
  c.rear_end = cases[static_cast<int>(ContactCase::kRearEnd)];
  RegionBuilder regions(exact.z0_mm, exact.spacing_mm, tol_mm);
  for (std::size_t t = 0; t < grid.size(); ++t) {
    const double below = exact.u_mm[t] - grid[t];  // NaN where the rule's path does not pass
    if (!std::isnan(below)) {
      ++c.compared;
      c.max_below_mm = std::max(c.max_below_mm, below);
      c.max_above_mm = std::max(c.max_above_mm, -below);
    }
    regions.add(t, below);
  }
  c.regions = regions.finish();
  if (rule_on_grid != nullptr) {
    *rule_on_grid = std::move(grid);
  } else {
    std::vector<double>().swap(grid);  // free before the classification pass
  }
  if (!c.regions.empty()) {
    // The rule's path over a run is made of the segments between consecutive samples' T that
    // pass through it: both samples of each such segment belong to the run (a T just outside
    // the run whose segment crosses it is what put the path there).
    const double tol = 0.5 * exact.spacing_mm;
    const auto mark = [&](Region& r, const LocalRule::Sample& s) {
      mark_concave(r, s.slope, s.curvature, rule.wheel());
      if (s.contact != ContactCase::kTangent) {
        r.arc_end_contact = true;
      }
    };
    const auto segment = [&](const LocalRule::Sample& a, const LocalRule::Sample& b) {
      const double lo = std::min(a.point.z_mm, b.point.z_mm) - tol;
      const double hi = std::max(a.point.z_mm, b.point.z_mm) + tol;
      // Runs are disjoint and in z order: the first whose end reaches lo, then on.
      auto it = std::lower_bound(c.regions.begin(), c.regions.end(), lo,
                                 [](const Region& r, double v) { return r.z_to_mm < v; });
      for (; it != c.regions.end() && it->z_from_mm <= hi; ++it) {
        mark(*it, a);
        mark(*it, b);
      }
    };
    auto a = rule.at(0);
    if (rule.size() == 1) {
      segment(a, a);
    }
    for (std::size_t i = 1; i < rule.size(); ++i) {
      const auto b = rule.at(i);
      segment(a, b);
      a = b;
    }
    mark_near_end(c.regions, rule.profile(), rule.wheel());
  }
  return c;
}

Unreachable unreachable_regions(const LocalRule& rule, const GridTrajectory& exact, double tol_mm) {
  const UniformProfile& p = rule.profile();
  Unreachable out;
  RegionBuilder regions(p.z0_mm, p.spacing_mm, tol_mm);
  ground_profile_chunks(exact, p, rule.wheel(), [&](std::size_t first, std::span<const double> b) {
    for (std::size_t k = 0; k < b.size(); ++k) {
      const std::size_t i = first + k;
      const double left = b[k] - p.u_mm[i];
      if (left > out.max_left_mm) {
        out.max_left_mm = left;
        out.z_at_max_mm = p.z_at(static_cast<std::ptrdiff_t>(i));
      }
      regions.add(i, left);
    }
  });
  out.regions = regions.finish();
  // A sample belongs to the run over its own z: the run's samples are its grid points.
  for (auto& r : out.regions) {
    const auto from =
        static_cast<std::size_t>(std::llround((r.z_from_mm - p.z0_mm) / p.spacing_mm));
    const auto to = static_cast<std::size_t>(std::llround((r.z_to_mm - p.z0_mm) / p.spacing_mm));
    for (std::size_t i = from; i <= to && i < p.size(); ++i) {
      mark_concave(r, rule.slope(i), rule.curvature(i), rule.wheel());
    }
  }
  mark_near_end(out.regions, p, rule.wheel());
  return out;
}

}  // namespace nccomp::core::grind
