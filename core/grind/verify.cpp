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

// B over the polyline through n points pt(0), pt(1), … in any order. The segments are visited
// in blocks of kBlock whose Z spans are computed first (one pass, 16 bytes per block): an
// evaluation point looks only into blocks within the wheel's reach. No point or segment is
// copied, so paths of 2·10⁷ points need no extra N-sized memory.
template <class Points>
std::vector<double> ground_impl(std::size_t n, const Points& pt, const Wheel& wheel,
                                std::span<const double> z_eval) {
  if (n == 0) {
    throw std::invalid_argument("verification: empty trajectory");
  }
  constexpr std::size_t kBlock = 512;
  const std::size_t segments = n > 1 ? n - 1 : 1;  // one point: a degenerate segment
  const std::size_t blocks = (segments + kBlock - 1) / kBlock;
  struct Span {
    double lo;
    double hi;
  };
  std::vector<Span> span(blocks);
  for (std::size_t k = 0; k < blocks; ++k) {
    const std::size_t first = k * kBlock;
    const std::size_t last = std::min(first + kBlock, n - 1);  // last point of the block
    Span s{std::numeric_limits<double>::infinity(), -std::numeric_limits<double>::infinity()};
    for (std::size_t i = first; i <= last; ++i) {
      const TrajectoryPoint p = pt(i);
      if (!std::isfinite(p.z_mm) || !std::isfinite(p.u_mm)) {
        throw std::invalid_argument("verification: trajectory point " + std::to_string(i) +
                                    " is not finite");
      }
      s.lo = std::min(s.lo, p.z_mm);
      s.hi = std::max(s.hi, p.z_mm);
    }
    span[k] = s;
  }
  const double half = wheel.half_width_mm();
  std::vector<double> out(z_eval.size(), std::numeric_limits<double>::infinity());
  for (std::size_t e = 0; e < z_eval.size(); ++e) {
    const double z = z_eval[e];
    const double a = z - half;
    const double b = z + half;
    double best = std::numeric_limits<double>::infinity();
    for (std::size_t k = 0; k < blocks; ++k) {
      if (span[k].hi < a || span[k].lo > b) {
        continue;
      }
      const std::size_t first = k * kBlock;
      const std::size_t end = std::min(first + kBlock, segments);
      TrajectoryPoint p0 = pt(first);
      for (std::size_t i = first; i < end; ++i) {
        const TrajectoryPoint p1 = n > 1 ? pt(i + 1) : p0;
        const Segment sg{std::min(p0.z_mm, p1.z_mm),
                         std::max(p0.z_mm, p1.z_mm),
                         p0.z_mm,
                         p0.u_mm,
                         p1.z_mm,
                         p1.u_mm};
        const double lo = std::max(a, sg.z_lo);
        const double hi = std::min(b, sg.z_hi);
        if (lo <= hi) {
          best = std::min(best, segment_min(sg, z, lo, hi, wheel));
        }
        p0 = p1;
      }
    }
    out[e] = best;
  }
  return out;
}

}  // namespace

std::vector<double> ground_by_polyline(std::span<const TrajectoryPoint> q, const Wheel& wheel,
                                       std::span<const double> z_eval) {
  return ground_impl(
      q.size(), [q](std::size_t i) { return q[i]; }, wheel, z_eval);
}

std::vector<double> ground_by_grid_path(double z0_mm, double spacing_mm,
                                        std::span<const double> u_mm, const Wheel& wheel,
                                        std::span<const double> z_eval) {
  return ground_impl(
      u_mm.size(),
      [&](std::size_t i) {
        return TrajectoryPoint{z0_mm + static_cast<double>(i) * spacing_mm, u_mm[i]};
      },
      wheel, z_eval);
}

std::vector<double> ground_by_polyline(const LocalRule& rule, std::span<const double> z_eval) {
  return ground_impl(
      rule.size(), [&rule](std::size_t i) { return rule.at(i).point; }, rule.wheel(), z_eval);
}

GroundError compare_ground(std::span<const double> z_mm, std::span<const double> b_mm,
                           std::span<const double> p_mm) {
  if (z_mm.size() != b_mm.size() || z_mm.size() != p_mm.size()) {
    throw std::invalid_argument("verification: z, B and P differ in length");
  }
  GroundErrorSum sum;
  for (std::size_t i = 0; i < z_mm.size(); ++i) {
    sum.add(z_mm[i], b_mm[i], p_mm[i]);
  }
  return sum.result();
}

void GroundErrorSum::add(double z_mm, double b_mm, double p_mm) noexcept {
  if (std::isinf(b_mm)) {
    ++r_.unreached;
    return;
  }
  const double d = b_mm - p_mm;
  ++r_.points;
  sum2_ += d * d;
  if (std::abs(d) > r_.max_abs_mm) {
    r_.max_abs_mm = std::abs(d);
    r_.z_at_max_mm = z_mm;
  }
  r_.max_gouge_mm = std::max(r_.max_gouge_mm, -d);
  r_.max_left_mm = std::max(r_.max_left_mm, d);
}

GroundError GroundErrorSum::result() const noexcept {
  GroundError r = r_;
  r.rms_mm = r.points > 0 ? std::sqrt(sum2_ / static_cast<double>(r.points)) : 0.0;
  return r;
}

}  // namespace nccomp::core::grind
