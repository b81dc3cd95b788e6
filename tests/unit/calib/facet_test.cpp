// GIVEN facets ground into a cylinder WHEN their chords are turned back into a position error
// THEN the exact rule recovers it for any error; the proportional rule only to first order.
#include "core/calib/facet.hpp"

#include <gtest/gtest.h>

#include <cmath>

namespace nccomp::core::calib {
namespace {

TEST(Facet, ChordAndDepthAreInverse) {
  for (const double rho : {2.0, 5.0, 12.5}) {
    for (const double d : {0.0, 0.01, 0.1, 0.5, 1.9}) {
      const double c = chord_from_depth_mm(rho, d);
      EXPECT_NEAR(depth_from_chord_mm(rho, c), d, 1e-12) << "rho " << rho << " d " << d;
    }
  }
  // c = 2·sqrt(2ρd − d²): ρ = 5, d = 0.1 → 2·sqrt(0.99)
  EXPECT_NEAR(chord_from_depth_mm(5.0, 0.1), 2.0 * std::sqrt(0.99), 1e-12);
  EXPECT_TRUE(std::isnan(depth_from_chord_mm(5.0, 10.5)));
  EXPECT_TRUE(std::isnan(depth_from_chord_mm(5.0, -0.1)));
  EXPECT_TRUE(std::isnan(chord_from_depth_mm(5.0, -0.1)));
}

TEST(Facet, ExactRuleRecoversLargeErrors) {
  const double rho = 5.0;
  const double d0 = 0.1;
  for (const double e_um : {-60.0, -30.0, -1.0, 0.0, 0.5, 25.0, 80.0}) {
    const double cp = chord_from_depth_mm(rho, d0 + e_um / 1000.0);
    const double cm = chord_from_depth_mm(rho, d0 - e_um / 1000.0);
    EXPECT_NEAR(facet_error_exact_um(rho, cp, cm), e_um, 1e-9) << e_um;
  }
}

TEST(Facet, ProportionalRuleIsFirstOrderOnly) {
  const double rho = 5.0;
  const double d0 = 0.1;
  const double gain = matched_proportional_gain(rho, d0);
  EXPECT_NEAR(gain, 2.0 * std::sqrt(0.99) / (8.0 * 4.9), 1e-12);
  // Small error: within 0.1 %.
  {
    const double e_um = 1.0;
    const double cp = chord_from_depth_mm(rho, d0 + e_um / 1000.0);
    const double cm = chord_from_depth_mm(rho, d0 - e_um / 1000.0);
    EXPECT_NEAR(facet_error_proportional_um(gain, cp, cm), e_um, 1e-3);
  }
  // 30 µm on a 100 µm deep facet: the linearisation misses by more than 0.2 µm.
  {
    const double e_um = 30.0;
    const double cp = chord_from_depth_mm(rho, d0 + e_um / 1000.0);
    const double cm = chord_from_depth_mm(rho, d0 - e_um / 1000.0);
    const double est = facet_error_proportional_um(gain, cp, cm);
    EXPECT_GT(std::fabs(est - e_um), 0.2);
    EXPECT_LT(std::fabs(est - e_um), 1.5);
  }
}

}  // namespace
}  // namespace nccomp::core::calib
