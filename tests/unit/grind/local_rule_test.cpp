#include "core/grind/local_rule.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <stdexcept>
#include <string>

#include "core/grind/compare.hpp"
#include "core/grind/envelope.hpp"
#include "tests/unit/grind/sampled.hpp"

namespace nccomp::core::grind {
namespace {

using test::sampled;

TEST(LocalRule, GivenPolynomialOfFitDegree_ThenSlopeAndCurvatureAreExactEverywhere) {
  const auto p = sampled(-3.0, 0.25, 25, [](double z) { return 0.5 - 0.2 * z + 0.03 * z * z; });
  for (const FitSpec fit : {FitSpec{2, 0}, FitSpec{2, 5}, FitSpec{3, 0}, FitSpec{4, 9}}) {
    const auto d = local_derivatives(p, fit);
    for (std::size_t i = 0; i < p.size(); ++i) {  // ends too: the stencil shifts inward
      const double z = p.z_at(static_cast<std::ptrdiff_t>(i));
      ASSERT_NEAR(d.slope[i], -0.2 + 0.06 * z, 1e-10) << fit.degree << "/" << fit.points;
      ASSERT_NEAR(d.curvature[i], 0.06, 1e-8) << fit.degree << "/" << fit.points;
    }
  }
  // Degree 1 through 2 points: the forward/backward difference, no curvature.
  const auto d1 = local_derivatives(p, FitSpec{1, 0});
  EXPECT_NEAR(d1.slope[0], (p.u_mm[1] - p.u_mm[0]) / 0.25, 1e-12);
  EXPECT_EQ(d1.curvature[3], 0.0);
}

TEST(LocalRule, GivenBadFit_ThenClearErrors) {
  const auto p = sampled(0.0, 1.0, 3, [](double z) { return z; });
  EXPECT_THROW(local_derivatives(p, FitSpec{0, 0}), std::invalid_argument);
  EXPECT_THROW(local_derivatives(p, FitSpec{9, 0}), std::invalid_argument);
  EXPECT_THROW(local_derivatives(p, FitSpec{2, 2}), std::invalid_argument);  // points < n + 1
  try {
    local_derivatives(p, FitSpec{3, 0});  // 4 points needed, 3 given
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("needs at least 4 samples"), std::string::npos)
        << e.what();
  }
  auto bad = p;
  bad.u_mm[1] = std::nan("");
  EXPECT_THROW(local_derivatives(bad, FitSpec{2, 0}), std::invalid_argument);
}

// The seed's three cases on a straight line: slope below the arc's end slope → tangent,
// above → an arc end rides; h = 0 → always an end.
TEST(LocalRule, GivenStraightLines_ThenTheThreeCases) {
  const auto wheel = Wheel::from_arc_height(150.0, 0.5);
  const double end = wheel.end_slope();  // ≈ 0.01333
  for (const double b : {0.5 * end, -0.5 * end, 2.0 * end, -2.0 * end}) {
    const auto p = sampled(0.0, 1.0, 11, [&](double z) { return b * z; });
    const auto d = local_derivatives(p, FitSpec{});
    const auto t = local_rule_trajectory(p, d, wheel);
    const double a = std::atan(b);
    if (std::abs(b) < end) {
      EXPECT_EQ(t.contact[5], ContactCase::kTangent);
      EXPECT_NEAR(t.point[5].z_mm, 5.0 - wheel.radius_mm() * std::sin(a), 1e-9);
      EXPECT_NEAR(t.point[5].u_mm, 5.0 * b - wheel.radius_mm() * (1 - std::cos(a)), 1e-9);
    } else {
      EXPECT_EQ(t.contact[5], b > 0 ? ContactCase::kFrontEnd : ContactCase::kRearEnd);
      EXPECT_NEAR(t.point[5].z_mm, b > 0 ? 5.0 - 75.0 : 5.0 + 75.0, 1e-12);
      EXPECT_NEAR(t.point[5].u_mm, 5.0 * b - 0.5, 1e-12);
    }
  }
  const auto flat = Wheel::from_arc_height(150.0, 0.0);
  const auto p = sampled(0.0, 1.0, 11, [](double z) { return 0.001 * z; });
  const auto t = local_rule_trajectory(p, local_derivatives(p, FitSpec{}), flat);
  EXPECT_EQ(t.contact[4], ContactCase::kFrontEnd);
  EXPECT_NEAR(t.point[4].z_mm, 4.0 - 75.0, 1e-12);
  EXPECT_NEAR(t.point[4].u_mm, 0.004, 1e-12);
}

// GIVEN a convex, gentle crown, THEN the local rule is exact: it equals the envelope wherever
// both define the trajectory (seeds.md: the rule is local, the envelope global).
TEST(LocalRule, GivenConvexGentleCrown_ThenEqualsEnvelope) {
  const auto wheel = Wheel::from_arc_height(150.0, 0.5);
  const auto p = sampled(-500.0, 0.5, 2001, [](double z) { return 0.6 * (1 - z * z / 2.5e5); });
  const auto exact = exact_trajectory(p, wheel);
  const auto local = local_rule_trajectory(p, local_derivatives(p, FitSpec{}), wheel);
  const auto on_grid =
      lowest_pass_on_grid(local.point, exact.z0_mm, exact.spacing_mm, exact.u_mm.size());
  std::size_t compared = 0;
  double worst = 0.0;
  for (std::size_t i = 0; i < on_grid.size(); ++i) {
    if (!std::isnan(on_grid[i])) {
      ++compared;
      worst = std::max(worst, std::abs(on_grid[i] - exact.u_mm[i]));
    }
  }
  EXPECT_GT(compared, 2000U);
  // Sampling only: linear interpolation between T points, κΔ²/8 ≈ 1.8e-4·0.25/8.
  EXPECT_LT(worst, 1e-5);
  for (auto c : local.contact) {
    EXPECT_EQ(c, ContactCase::kTangent);
  }
}

// The rule evaluated sample by sample (what the command uses) gives the same numbers, bit for
// bit, as the arrays of local_derivatives + local_rule_trajectory.
TEST(LocalRule, GivenSampleBySampleEvaluation_ThenSameNumbersAsTheArrays) {
  const auto p = sampled(-50.0, 0.25, 401, [](double z) { return 1.0 * std::sin(z / 7.0); });
  for (const auto& wheel : {Wheel::from_arc_height(20.0, 0.3), Wheel::from_arc_height(20.0, 0.0)}) {
    for (const FitSpec fit : {FitSpec{2, 0}, FitSpec{1, 9}, FitSpec{4, 7}}) {
      const LocalRule rule(p, fit, wheel);
      const auto d = local_derivatives(p, fit);
      const auto t = local_rule_trajectory(p, d, wheel);
      ASSERT_EQ(rule.size(), p.size());
      std::size_t ends = 0;
      for (std::size_t i = 0; i < p.size(); ++i) {
        const auto s = rule.at(i);
        ASSERT_EQ(s.slope, d.slope[i]);
        ASSERT_EQ(s.curvature, d.curvature[i]);
        ASSERT_EQ(s.point.z_mm, t.point[i].z_mm);
        ASSERT_EQ(s.point.u_mm, t.point[i].u_mm);
        ASSERT_EQ(s.contact, t.contact[i]);
        ends += s.contact != ContactCase::kTangent ? 1 : 0;
      }
      if (wheel.straight()) {
        EXPECT_EQ(ends, p.size());  // h = 0: always an end
      } else {
        // The steep parts (|slope| up to 0.14 > the arc's end slope 0.060) ride on an end.
        EXPECT_GT(ends, 0U);
        EXPECT_LT(ends, p.size());
      }
    }
  }
  EXPECT_THROW(LocalRule(p, FitSpec{2, 1000}, Wheel::from_arc_height(20.0, 0.3)),
               std::invalid_argument);
}

}  // namespace
}  // namespace nccomp::core::grind
