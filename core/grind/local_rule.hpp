// The seed's three-case local rule (seeds.md S2, steps 2–4, exact form): at every sample the
// slope K1 from a local polynomial through neighbouring samples, then
//  case 1 (tangent, |sin a| ≤ W/(2R)):  Z_T = z − R·sin a,   U_T = u − R·(1 − cos a)
//  case 2/3 (an arc end rides):         Z_T = z ∓ W/2,       U_T = u − g(W/2)
// with a = atan K1. For h = 0 the contact is always an end: Z_T = z − sign(K1)·W/2 (K1 = 0 takes
// the rear end, Z_T = z + W/2). The rule is local: it is exact where P is convex or gently
// concave (curvature radius > R) and away from the ends; elsewhere it gouges (see compare.hpp).
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "core/grind/profile.hpp"
#include "core/grind/wheel.hpp"

namespace nccomp::core::grind {

struct FitSpec {
  int degree{2};  ///< polynomial degree n, 1..8
  int points{0};  ///< samples in the fit, ≥ n + 1 (0: n + 1, an interpolating polynomial)
};

enum class ContactCase : std::uint8_t { kTangent = 1, kFrontEnd = 2, kRearEnd = 3 };

struct TrajectoryPoint {
  double z_mm;
  double u_mm;
};

/// The rule evaluated sample by sample, without storing N-sized arrays (at 2·10⁷ samples the
/// slopes, curvatures and T points would take 800 MB): the slope fit's weights are computed once
/// (Savitzky–Golay: on a uniform grid the fitted derivatives at offset o inside the stencil are
/// fixed linear combinations of the stencil's samples), every query costs O(fit points).
/// Keeps a pointer to the profile: it must outlive the rule.
class LocalRule {
 public:
  /// Validates the fit against the profile (degree 1..8, points degree + 1 .. 64, at least
  /// `points` samples, every value finite, spacing > 0). Throws std::invalid_argument.
  LocalRule(const UniformProfile& profile, const FitSpec& fit, const Wheel& wheel);

  struct Sample {
    TrajectoryPoint point;  ///< T for this sample
    ContactCase contact;
    double slope;      ///< fitted du/dz
    double curvature;  ///< fitted d²u/dz² (1/mm)
  };
  [[nodiscard]] std::size_t size() const noexcept { return profile_->size(); }
  [[nodiscard]] const UniformProfile& profile() const noexcept { return *profile_; }
  [[nodiscard]] const Wheel& wheel() const noexcept { return wheel_; }
  [[nodiscard]] int fit_points() const noexcept { return points_; }
  [[nodiscard]] double slope(std::size_t i) const noexcept;
  [[nodiscard]] double curvature(std::size_t i) const noexcept;
  /// T of sample i by the three cases (i < size()).
  [[nodiscard]] Sample at(std::size_t i) const noexcept;

 private:
  [[nodiscard]] double apply(const std::vector<double>& w, std::size_t i) const noexcept;
  const UniformProfile* profile_;
  Wheel wheel_;
  int points_{0};
  std::vector<double> w1_;  ///< slope weights, row o (offset in the stencil) of points × points
  std::vector<double> w2_;  ///< second-derivative weights, the same layout
};

/// Slopes du/dz and second derivatives d²u/dz² (1/mm) at every sample from a least-squares
/// polynomial of `fit.degree` through `fit.points` neighbouring samples (centred; shifted
/// inward at the ends). Throws std::invalid_argument on a bad spec or too few samples.
/// (Arrays of N: for tests and small profiles; the command uses LocalRule.)
struct Derivatives {
  std::vector<double> slope;
  std::vector<double> curvature;  ///< second derivative (1/mm)
};
Derivatives local_derivatives(const UniformProfile& profile, const FitSpec& fit);

struct LocalTrajectory {
  std::vector<TrajectoryPoint> point;  ///< one T per profile sample, in sample order
  std::vector<ContactCase> contact;
};

/// One T per profile sample by the three-case rule (arrays of N; the same numbers as
/// LocalRule::at for the same slopes).
LocalTrajectory local_rule_trajectory(const UniformProfile& profile, const Derivatives& d,
                                      const Wheel& wheel);

}  // namespace nccomp::core::grind
