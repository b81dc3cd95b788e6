#include "core/grind/verify.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <stdexcept>
#include <string>

namespace nccomp::core::grind {
namespace {

struct Segment {
  double z_lo;
  double z_hi;
  double z0;
  double u0;
  double z1;
  double u1;
};

// min over Z ∈ [a, b] of U(Z) + g(z − Z) for the segment (Z ∈ its span ∩ the wheel's reach).
double segment_min(const Segment& s, double z, double a, double b, const Wheel& wheel) {
  const double dz = s.z1 - s.z0;
  if (!(std::abs(dz) > 0.0)) {
    return std::min(s.u0, s.u1) + wheel.rise_mm(z - s.z0);
  }
  const double m = (s.u1 - s.u0) / dz;
  double zs = 0.0;
  if (wheel.straight()) {
    zs = m > 0.0 ? a : b;  // linear in Z: the lower end
  } else {
    // g'(s) = s / sqrt(R² − s²) = m  ⇔  s = m·R / sqrt(1 + m²)
    zs = std::clamp(z - m * wheel.radius_mm() / std::sqrt(1.0 + m * m), a, b);
  }
  return s.u0 + m * (zs - s.z0) + wheel.rise_mm(z - zs);
}

}  // namespace

std::vector<double> ground_by_polyline(std::span<const TrajectoryPoint> q, const Wheel& wheel,
                                       std::span<const double> z_eval) {
  if (q.empty()) {
    throw std::invalid_argument("verification: empty trajectory");
  }
  const double half = wheel.half_width_mm();
  bool increasing = q.size() >= 2;
  for (std::size_t i = 0; i + 1 < q.size() && increasing; ++i) {
    increasing =
        q[i + 1].z_mm >= q[i].z_mm && std::isfinite(q[i].u_mm) && std::isfinite(q[i + 1].u_mm);
  }
  if (increasing) {
    // Paths sorted in Z (every grid trajectory): walk the points themselves, no segment copy
    // (48 bytes per point would be ~1 GB at 2·10⁷ points).
    std::vector<double> out(z_eval.size(), std::numeric_limits<double>::infinity());
    for (std::size_t e = 0; e < z_eval.size(); ++e) {
      const double z = z_eval[e];
      const double a = z - half;
      const double b = z + half;
      auto it = std::lower_bound(q.begin(), q.end(), a,
                                 [](const TrajectoryPoint& p, double v) { return p.z_mm < v; });
      std::size_t i = static_cast<std::size_t>(it - q.begin());
      i = i > 0 ? i - 1 : 0;
      double best = std::numeric_limits<double>::infinity();
      for (; i + 1 < q.size() && q[i].z_mm <= b; ++i) {
        const Segment sg{q[i].z_mm, q[i + 1].z_mm, q[i].z_mm,
                         q[i].u_mm, q[i + 1].z_mm, q[i + 1].u_mm};
        const double lo = std::max(a, sg.z_lo);
        const double hi = std::min(b, sg.z_hi);
        if (lo <= hi) {
          best = std::min(best, segment_min(sg, z, lo, hi, wheel));
        }
      }
      out[e] = best;
    }
    return out;
  }
  std::vector<Segment> seg;
  seg.reserve(std::max<std::size_t>(q.size(), 2) - 1);
  if (q.size() == 1) {
    seg.push_back({q[0].z_mm, q[0].z_mm, q[0].z_mm, q[0].u_mm, q[0].z_mm, q[0].u_mm});
  }
  bool sorted = true;
  double longest = 0.0;
  for (std::size_t i = 0; i + 1 < q.size(); ++i) {
    const auto& p0 = q[i];
    const auto& p1 = q[i + 1];
    if (!std::isfinite(p0.z_mm) || !std::isfinite(p0.u_mm) || !std::isfinite(p1.z_mm) ||
        !std::isfinite(p1.u_mm)) {
      throw std::invalid_argument("verification: trajectory point " + std::to_string(i) +
                                  " is not finite");
    }
    Segment s{
        std::min(p0.z_mm, p1.z_mm), std::max(p0.z_mm, p1.z_mm), p0.z_mm, p0.u_mm, p1.z_mm, p1.u_mm};
    if (!seg.empty() && s.z_lo < seg.back().z_lo) {
      sorted = false;
    }
    longest = std::max(longest, s.z_hi - s.z_lo);
    seg.push_back(s);
  }
  if (!sorted) {
    std::sort(seg.begin(), seg.end(),
              [](const Segment& x, const Segment& y) { return x.z_lo < y.z_lo; });
  }
  std::vector<double> out(z_eval.size(), std::numeric_limits<double>::infinity());
  for (std::size_t e = 0; e < z_eval.size(); ++e) {
    const double z = z_eval[e];
    const double a = z - half;
    const double b = z + half;
    auto it = std::lower_bound(seg.begin(), seg.end(), a - longest,
                               [](const Segment& s, double v) { return s.z_lo < v; });
    double best = std::numeric_limits<double>::infinity();
    for (; it != seg.end() && it->z_lo <= b; ++it) {
      const double lo = std::max(a, it->z_lo);
      const double hi = std::min(b, it->z_hi);
      if (lo <= hi) {
        best = std::min(best, segment_min(*it, z, lo, hi, wheel));
      }
    }
    out[e] = best;
  }
  return out;
}

GroundError compare_ground(std::span<const double> z_mm, std::span<const double> b_mm,
                           std::span<const double> p_mm) {
  if (z_mm.size() != b_mm.size() || z_mm.size() != p_mm.size()) {
    throw std::invalid_argument("verification: z, B and P differ in length");
  }
  GroundError r;
  double sum2 = 0.0;
  for (std::size_t i = 0; i < z_mm.size(); ++i) {
    if (std::isinf(b_mm[i])) {
      ++r.unreached;
      continue;
    }
    const double d = b_mm[i] - p_mm[i];
    ++r.points;
    sum2 += d * d;
    if (std::abs(d) > r.max_abs_mm) {
      r.max_abs_mm = std::abs(d);
      r.z_at_max_mm = z_mm[i];
    }
    r.max_gouge_mm = std::max(r.max_gouge_mm, -d);
    r.max_left_mm = std::max(r.max_left_mm, d);
  }
  r.rms_mm = r.points > 0 ? std::sqrt(sum2 / static_cast<double>(r.points)) : 0.0;
  return r;
}

}  // namespace nccomp::core::grind
