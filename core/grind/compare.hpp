// Where the three-case local rule and the exact envelope differ, and where P cannot be ground
// by the wheel at all (seeds.md S2: concave regions of curvature radius < R, the profile's
// ends, steep flanks where an arc end grinds). Not real-time.
#pragma once

#include <cstddef>
#include <span>
#include <vector>

#include "core/grind/envelope.hpp"
#include "core/grind/local_rule.hpp"

namespace nccomp::core::grind {

/// The lowest U of polyline Q over each grid point Z_t = z0 + t·Δ it passes (the deepest pass
/// decides what is cut); NaN where Q does not pass.
std::vector<double> lowest_pass_on_grid(std::span<const TrajectoryPoint> q, double z0_mm,
                                        double spacing_mm, std::size_t count);

/// A maximal run of grid points where a deviation exceeds a tolerance.
struct Region {
  double z_from_mm{0.0};
  double z_to_mm{0.0};
  double worst_mm{0.0};  ///< largest deviation in the run
  double z_worst_mm{0.0};
  // Causes found among the profile samples that belong to the run:
  bool concave_below_radius{false};   ///< local curvature radius of a concave part < R
  bool near_end{false};               ///< within W/2 of the profile's ends
  bool arc_end_contact{false};        ///< the local rule has an arc end riding (cases 2/3)
  double min_concave_radius_mm{0.0};  ///< smallest concave radius seen (0: none concave)
};

/// Runs of dev[t] > tol on the grid Z_t = z0 + t·Δ (NaN never counts).
std::vector<Region> regions_above(std::span<const double> dev_mm, double z0_mm, double spacing_mm,
                                  double tol_mm);

/// Marks causes on the regions: sample i of the profile belongs to the region holding
/// `key_z[i]` (its T position for trajectory differences, its own z for unreachable parts).
void classify_regions(std::vector<Region>& regions, std::span<const double> key_z_mm,
                      const UniformProfile& profile, const Derivatives& d,
                      const LocalTrajectory* local, const Wheel& wheel);

/// Concave radii above this are treated as straight (fit noise).
inline constexpr double kStraightRadiusMm = 1e9;
/// Local curvature radius of a concave part ((1 + K1²)^{3/2} / K2, K2 > 0), +inf elsewhere.
double concave_radius_mm(double slope, double curvature_per_mm) noexcept;

}  // namespace nccomp::core::grind
