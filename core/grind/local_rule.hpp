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

/// Slopes du/dz and second derivatives d²u/dz² (1/mm) at every sample from a least-squares
/// polynomial of `fit.degree` through `fit.points` neighbouring samples (centred; shifted
/// inward at the ends). Throws std::invalid_argument on a bad spec or too few samples.
struct Derivatives {
  std::vector<double> slope;
  std::vector<double> curvature;  ///< second derivative (1/mm)
};
Derivatives local_derivatives(const UniformProfile& profile, const FitSpec& fit);

enum class ContactCase : std::uint8_t { kTangent = 1, kFrontEnd = 2, kRearEnd = 3 };

struct TrajectoryPoint {
  double z_mm;
  double u_mm;
};

struct LocalTrajectory {
  std::vector<TrajectoryPoint> point;  ///< one T per profile sample, in sample order
  std::vector<ContactCase> contact;
};

/// One T per profile sample by the three-case rule.
LocalTrajectory local_rule_trajectory(const UniformProfile& profile, const Derivatives& d,
                                      const Wheel& wheel);

}  // namespace nccomp::core::grind
