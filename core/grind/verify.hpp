// Independent verification of a trajectory (seeds.md S2, last paragraph): the profile a wheel
// grinds when T follows the polyline Q, B(z) = min over Q of [U + g(z − Z)], compared with P.
//
// Deliberately a different algorithm from envelope.cpp: brute force over every segment of the
// polyline within the wheel's reach, each minimised in closed form (U is linear along a segment
// and g convex, so U(Z) + g(z − Z) has one stationary point where g'(z − Z) equals the segment's
// slope). It evaluates the polyline itself — the path the NC interpolates — not grid values, and
// accepts any point order (the local rule's trajectory doubles back in concave regions).
// Cost: O(N) to bound blocks of 512 segments, then O(E·(S_w + N/512)) for E evaluation points
// and S_w segments in the blocks within W/2 of each; no copy of the path. Not real-time.
// For paths on the profile's grid, verify_grid.hpp computes B at every sample in O(N log M).
#pragma once

#include <cstddef>
#include <span>
#include <vector>

#include "core/grind/local_rule.hpp"
#include "core/grind/wheel.hpp"

namespace nccomp::core::grind {

/// B at every z of z_eval (+inf where no part of Q is within W/2 of z). Throws
/// std::invalid_argument on an empty path or a non-finite point.
std::vector<double> ground_by_polyline(std::span<const TrajectoryPoint> q, const Wheel& wheel,
                                       std::span<const double> z_eval);
/// The same for the path through (z0 + t·Δ, u[t]), t = 0 … (a grid trajectory such as the exact
/// envelope, or the profile itself for the usual practice "T follows P"), without copying it.
std::vector<double> ground_by_grid_path(double z0_mm, double spacing_mm,
                                        std::span<const double> u_mm, const Wheel& wheel,
                                        std::span<const double> z_eval);
/// The same for the three-case rule's path (T of samples 0 … N − 1), evaluated sample by sample.
std::vector<double> ground_by_polyline(const LocalRule& rule, std::span<const double> z_eval);

struct GroundError {
  std::size_t points{0};     ///< evaluation points compared
  std::size_t unreached{0};  ///< points no wheel position reaches (B = +inf), left out
  double max_abs_mm{0.0};    ///< max |B − P|
  double z_at_max_mm{0.0};
  double rms_mm{0.0};
  double max_gouge_mm{0.0};  ///< max (P − B): material removed below the target
  double max_left_mm{0.0};   ///< max (B − P): material left above the target
};
GroundError compare_ground(std::span<const double> z_mm, std::span<const double> b_mm,
                           std::span<const double> p_mm);

/// compare_ground's figures accumulated one point at a time (the same numbers for the same
/// points in the same order), for B streamed in chunks instead of held as an array.
class GroundErrorSum {
 public:
  void add(double z_mm, double b_mm, double p_mm) noexcept;
  [[nodiscard]] GroundError result() const noexcept;

 private:
  GroundError r_;
  double sum2_{0.0};
};

}  // namespace nccomp::core::grind
