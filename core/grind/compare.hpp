// Where the three-case local rule and the exact envelope differ, and where P cannot be ground
// by the wheel at all (seeds.md S2: concave regions of curvature radius < R, the profile's
// ends, steep flanks where an arc end grinds). The two reports of `nccomp grind-path` are
// composed here (compare_rule_with_envelope, unreachable_regions) so that they are testable
// without the command; neither keeps more than one N-sized array alive. Not real-time.
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
/// The same for the rule's path (T of sample 0, 1, …, N − 1 joined by lines), evaluated sample
/// by sample.
std::vector<double> lowest_pass_on_grid(const LocalRule& rule, double z0_mm, double spacing_mm,
                                        std::size_t count);

/// A maximal run of grid points where a deviation exceeds a tolerance.
struct Region {
  double z_from_mm{0.0};
  double z_to_mm{0.0};
  double worst_mm{0.0};  ///< largest deviation in the run
  double z_worst_mm{0.0};
  // Circumstances found in the run (the causes seeds.md names):
  bool concave_below_radius{false};   ///< a sample of the run is concave with radius < R
  bool near_end{false};               ///< the run lies (partly) within W/2 of a profile end
  bool arc_end_contact{false};        ///< the rule has an arc end riding (cases 2/3) in the run
  double min_concave_radius_mm{0.0};  ///< smallest concave radius seen (0: none concave)
};

/// Runs of dev[t] > tol on the grid Z_t = z0 + t·Δ (NaN never counts), built value by value.
class RegionBuilder {
 public:
  RegionBuilder(double z0_mm, double spacing_mm, double tol_mm) noexcept
      : z0_mm_(z0_mm), spacing_mm_(spacing_mm), tol_mm_(tol_mm) {}
  /// The next grid point t (t = 0, 1, 2, … in order).
  void add(std::size_t t, double dev_mm);
  [[nodiscard]] std::vector<Region> finish() { return std::move(regions_); }

 private:
  double z0_mm_;
  double spacing_mm_;
  double tol_mm_;
  bool open_{false};
  std::vector<Region> regions_;
};

/// Runs of dev[t] > tol on the grid Z_t = z0 + t·Δ (NaN never counts).
std::vector<Region> regions_above(std::span<const double> dev_mm, double z0_mm, double spacing_mm,
                                  double tol_mm);

/// The three-case rule against the exact envelope on the envelope's grid (the rule's path is
/// taken as its deepest pass over each grid point, lowest_pass_on_grid).
struct RuleComparison {
  std::size_t tangent{0};  ///< samples per contact case
  std::size_t front_end{0};
  std::size_t rear_end{0};
  double max_below_mm{0.0};  ///< rule below the envelope: it gouges (max U_exact − U_rule)
  double max_above_mm{0.0};  ///< rule above the envelope: it leaves material
  std::size_t compared{0};   ///< grid points where both paths exist
  /// Runs where the rule is below the envelope by more than tol, in z order (Z of T). Causes:
  /// from the samples whose path segments (T of sample i to T of sample i + 1) cross the run
  /// (concave radius < R, an arc end riding), and from the run's place (within W/2 of an end of
  /// the profile: the wheel overhangs the roll there, the slope fit's stencil is one-sided).
  std::vector<Region> regions;
};
/// `rule_on_grid`, if given, receives the rule's lowest pass on the envelope's grid (the path
/// the NC outputs follow for --method local) instead of it being freed.
RuleComparison compare_rule_with_envelope(const LocalRule& rule, const GridTrajectory& exact,
                                          double tol_mm,
                                          std::vector<double>* rule_on_grid = nullptr);

/// What the wheel cannot grind: where B of the exact envelope (the profile it actually grinds)
/// is above P by more than tol, on the profile's samples. B is streamed (no N-sized array).
struct Unreachable {
  double max_left_mm{0.0};  ///< max (B − P) over all samples
  double z_at_max_mm{0.0};
  /// Runs of B − P > tol in z order; causes: concave radius < R (from the rule's fit), within
  /// W/2 of a profile end. (An arc end never "causes" anything here: the envelope has no cases.)
  std::vector<Region> regions;
};
Unreachable unreachable_regions(const LocalRule& rule, const GridTrajectory& exact, double tol_mm);

/// Concave radii above this are treated as straight (fit noise).
inline constexpr double kStraightRadiusMm = 1e9;
/// Local curvature radius of a concave part ((1 + K1²)^{3/2} / K2, K2 > 0), +inf elsewhere.
double concave_radius_mm(double slope, double curvature_per_mm) noexcept;

}  // namespace nccomp::core::grind
