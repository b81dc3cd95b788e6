// The two reports of `nccomp grind-path`: where the three-case rule differs from the exact
// envelope (with each cause label), and what the wheel cannot grind at all.
#include "core/grind/compare.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#include <vector>

#include "core/grind/envelope.hpp"
#include "core/grind/local_rule.hpp"
#include "tests/unit/grind/sampled.hpp"

namespace nccomp::core::grind {
namespace {

using test::sampled;

// GIVEN a concave dip of radius 2500 mm < R in the middle, THEN the rule cuts below the
// gouge-free envelope there, and only the concave cause is named.
TEST(RuleVsEnvelope, GivenTightConcaveDip_ThenConcaveBelowRadiusOnly) {
  const auto wheel = Wheel::from_arc_height(150.0, 0.5);  // R ≈ 5625 mm
  // Dip of curvature radius 1/(2·2e-4) = 2500 mm in |z| < 20.
  const auto p = sampled(-300.0, 0.5, 1201,
                         [](double z) { return std::abs(z) < 20.0 ? -0.08 + 2e-4 * z * z : 0.0; });
  const LocalRule rule(p, FitSpec{}, wheel);
  const auto exact = exact_trajectory(p, wheel);
  const auto c = compare_rule_with_envelope(rule, exact, 1e-4);
  EXPECT_EQ(c.tangent, p.size());  // slopes up to 0.008 < the arc's end slope 0.0133
  ASSERT_FALSE(c.regions.empty());
  bool found = false;
  for (const auto& r : c.regions) {
    EXPECT_TRUE(r.concave_below_radius) << r.z_from_mm;
    EXPECT_FALSE(r.near_end) << r.z_from_mm;
    EXPECT_FALSE(r.arc_end_contact) << r.z_from_mm;
    EXPECT_GT(r.z_from_mm, -300.0 + 75.0);
    EXPECT_LT(r.z_to_mm, 300.0 - 75.0);
    if (r.z_from_mm < 0.0 && r.z_to_mm > 0.0) {
      found = true;
      EXPECT_NEAR(r.min_concave_radius_mm, 2500.0, 5.0);
      EXPECT_GT(r.worst_mm, 1e-3);  // tens of µm: the rule's tangent wheel cuts the dip's rims
    }
  }
  EXPECT_TRUE(found);
  EXPECT_GT(c.max_below_mm, 1e-3);
}

// GIVEN a gentle convex crown (radius > 40 m) and a slope fit of degree 1 through 41 samples,
// THEN in the middle the centred fit gives the exact slope of the parabola and the rule equals
// the envelope, but within 20 samples of each end the stencil is one-sided: the slope is the
// parabola's 20 samples further in, off by δ = 2a·(20 − k)·Δ at sample k from the end. The
// wheel then touches at the wrong point of its arc and gouges by ½δ²/(2a + 1/R) to second
// order: 0.57 µm at the last sample (checked there against the envelope maximised over a fine
// grid of arc points), ((20 − k)/20)² of it at sample k. Those runs are labelled "near end"
// and nothing else; the default 3-point fit has none.
TEST(RuleVsEnvelope, GivenOneSidedFitAtTheEnds_ThenNearEndOnly) {
  const auto wheel = Wheel::from_arc_height(150.0, 0.5);
  const double a = 3.0 / 2.5e5;  // crown 3 mm over ±500 mm
  const auto p = sampled(-500.0, 1.0, 1001, [&](double z) { return 3.0 - a * z * z; });
  const auto exact = exact_trajectory(p, wheel);
  const LocalRule rule(p, FitSpec{1, 41}, wheel);
  const auto c = compare_rule_with_envelope(rule, exact, 1e-4);
  const double delta = 2.0 * a * 20.0;
  const double predicted = 0.5 * delta * delta / (2.0 * a + 1.0 / wheel.radius_mm());
  EXPECT_NEAR(predicted, 5.71e-4, 1e-6);
  // At the last sample's T: the envelope of the continuous parabola (the wheel may touch only
  // z ≤ 500) minus the rule's U.
  const auto last = rule.at(p.size() - 1);
  double envelope = -std::numeric_limits<double>::infinity();
  for (double s = -75.0; s <= 75.0 && last.point.z_mm + s <= 500.0; s += 1e-3) {
    const double z = last.point.z_mm + s;
    envelope = std::max(envelope, 3.0 - a * z * z - wheel.rise_mm(s));
  }
  EXPECT_NEAR(envelope - last.point.u_mm, predicted, 0.02 * predicted);
  // On the envelope's grid (1 mm) the nearest points lie between the rule's last two T.
  EXPECT_LE(c.max_below_mm, 1.02 * predicted);
  EXPECT_GE(c.max_below_mm, 0.98 * (19.0 * 19.0) / (20.0 * 20.0) * predicted);
  EXPECT_EQ(c.tangent, p.size());  // end slope 0.012 < 0.0133
  ASSERT_EQ(c.regions.size(), 2U);
  for (const auto& r : c.regions) {
    EXPECT_TRUE(r.near_end) << r.z_from_mm;
    EXPECT_FALSE(r.concave_below_radius) << r.z_from_mm;
    EXPECT_FALSE(r.arc_end_contact) << r.z_from_mm;
    EXPECT_EQ(r.min_concave_radius_mm, 0.0);  // convex everywhere
    // T of the last samples: z ∓ R·sin a with slope ±0.012 puts them 67 mm outside the roll.
    EXPECT_GT(std::abs(r.z_worst_mm), 540.0);
    EXPECT_LT(std::abs(r.z_worst_mm), 575.0);
  }
  EXPECT_LT(c.regions[0].z_to_mm, 0.0);
  EXPECT_GT(c.regions[1].z_from_mm, 0.0);
  // The interpolating 3-point fit is exact on a parabola everywhere, ends included.
  const LocalRule exact_fit(p, FitSpec{}, wheel);
  const auto d = compare_rule_with_envelope(exact_fit, exact, 1e-4);
  EXPECT_TRUE(d.regions.empty());
  EXPECT_LT(d.max_below_mm, 1e-6);
}

// GIVEN a roof (two straight flanks of slope ±0.05, steeper than the arc's end slope 0.0133,
// meeting in a convex ridge at z = 0), THEN each flank sample's arc end rides on it (exact on
// its own), but the rule's path jumps from T = −75.5 (front end on the flank at z = −0.5) to
// T = 0 (tangent on the ridge): along that segment U rises linearly by m = 0.525/75.5 per mm
// while the envelope is the ridge touched by the arc, 20 − g(Z). The gouge m·s − g(s) peaks at
// g'(s) = m. The run is labelled "steep flank" only: no concave sample, far from the ends.
TEST(RuleVsEnvelope, GivenSteepFlanksMeetingInARidge_ThenArcEndContactOnly) {
  const auto wheel = Wheel::from_arc_height(150.0, 0.5);
  const auto p = sampled(-300.0, 0.5, 1201, [](double z) { return 20.0 - 0.05 * std::abs(z); });
  const LocalRule rule(p, FitSpec{}, wheel);
  const auto exact = exact_trajectory(p, wheel);
  const auto c = compare_rule_with_envelope(rule, exact, 1e-4);
  EXPECT_EQ(c.tangent, 1U);  // the ridge sample: symmetric slope 0
  EXPECT_EQ(c.front_end, 600U);
  EXPECT_EQ(c.rear_end, 600U);
  const double m = 0.525 / 75.5;
  const double s = m * wheel.radius_mm() / std::sqrt(1.0 + m * m);
  const double predicted = m * s - wheel.rise_mm(s);
  EXPECT_NEAR(predicted, 0.1360, 1e-4);
  EXPECT_NEAR(c.max_below_mm, predicted, 1e-5);  // the grid misses s by ≤ 0.25 mm: ~6e-6 mm
  ASSERT_EQ(c.regions.size(), 2U);  // left and right of the ridge, where the rule touches it
  for (const auto& r : c.regions) {
    EXPECT_TRUE(r.arc_end_contact) << r.z_from_mm;
    EXPECT_FALSE(r.concave_below_radius) << r.z_from_mm;
    EXPECT_FALSE(r.near_end) << r.z_from_mm;
    EXPECT_NEAR(std::abs(r.z_worst_mm), s, 0.5);
    EXPECT_NEAR(r.worst_mm, predicted, 1e-5);
  }
}

// GIVEN the straight grinding line (h = 0) and a flat roll with a 3 % ramp 1.2 mm high between
// z = 80 and 120 (docs/grinding.md's flank example), THEN the rule puts the line's rear end on
// every flat sample before the ramp (slope 0): the line then lies across the ramp and cuts it
// down to the flat, 1.2 mm at the top. The envelope grinds it exactly.
TEST(RuleVsEnvelope, GivenStraightLineOnAFlank_ThenSteepFlankAndProfileEnd) {
  const auto wheel = Wheel::from_arc_height(150.0, 0.0);
  const auto p = sampled(0.0, 0.05, 4001,
                         [](double z) { return z < 80.0 ? 0.0 : std::min(z - 80.0, 40.0) * 0.03; });
  const LocalRule rule(p, FitSpec{}, wheel);
  const auto exact = exact_trajectory(p, wheel);
  const auto c = compare_rule_with_envelope(rule, exact, 1e-4);
  EXPECT_EQ(c.tangent, 0U);  // h = 0: always an end
  EXPECT_NEAR(c.max_below_mm, 1.2, 1e-9);
  ASSERT_EQ(c.regions.size(), 1U);
  const auto& r = c.regions[0];
  EXPECT_NEAR(r.worst_mm, 1.2, 1e-9);
  EXPECT_TRUE(r.arc_end_contact);
  EXPECT_TRUE(r.near_end);  // the run starts at T ≈ 5 mm: the line overhangs z = 0
  EXPECT_LT(r.z_from_mm, 75.0);
  // Its gouge is gone with the envelope: nothing unreachable for a straight line here.
  const auto u = unreachable_regions(rule, exact, 1e-4);
  EXPECT_TRUE(u.regions.empty());
  EXPECT_LT(u.max_left_mm, 1e-12);
}

// GIVEN a narrow groove of radius 1000 mm < R, 10 mm wide each side, THEN the envelope cannot
// reach its bottom: the wheel rests on the rims (z = ±10) and leaves 0.05 − g(10) at z = 0. One
// unreachable run inside the groove, concave, not near an end.
TEST(Unreachable, GivenNarrowGroove_ThenOneConcaveRegionWithTheRimGeometry) {
  const auto wheel = Wheel::from_arc_height(150.0, 0.5);
  const auto p = sampled(-300.0, 0.1, 6001, [](double z) {
    return std::abs(z) < 10.0 ? -0.05 * (1.0 - z * z / 100.0) : 0.0;
  });
  const LocalRule rule(p, FitSpec{}, wheel);
  const auto exact = exact_trajectory(p, wheel);
  const auto u = unreachable_regions(rule, exact, 1e-4);
  ASSERT_EQ(u.regions.size(), 1U);
  const auto& r = u.regions[0];
  const double left_at_bottom = 0.05 - wheel.rise_mm(10.0);  // 41.1 µm
  EXPECT_NEAR(r.worst_mm, left_at_bottom, 1e-6);
  EXPECT_NEAR(r.z_worst_mm, 0.0, 0.15);
  EXPECT_NEAR(u.max_left_mm, r.worst_mm, 1e-15);
  EXPECT_GT(r.z_from_mm, -10.05);
  EXPECT_LT(r.z_to_mm, 10.05);
  EXPECT_LT(r.z_from_mm, -5.0);
  EXPECT_GT(r.z_to_mm, 5.0);
  EXPECT_TRUE(r.concave_below_radius);
  EXPECT_NEAR(r.min_concave_radius_mm, 1000.0, 1.0);
  EXPECT_FALSE(r.near_end);
  EXPECT_FALSE(r.arc_end_contact);
  // A convex crown: nothing unreachable.
  const auto crown = sampled(-500.0, 0.5, 2001, [](double z) { return 0.6 * (1 - z * z / 2.5e5); });
  const LocalRule crown_rule(crown, FitSpec{}, wheel);
  const auto none = unreachable_regions(crown_rule, exact_trajectory(crown, wheel), 1e-4);
  EXPECT_TRUE(none.regions.empty());
  EXPECT_LT(none.max_left_mm, 1e-5);
}

// GIVEN a sine whose valleys (radius 1/(A·k²) = 2533 mm) are tighter than R, THEN one
// unreachable run per valley; the two valleys within W/2 of an end are labelled so; the amount
// left at the middle valley's bottom equals a brute-force B (max over the window for U_T, then
// min over the wheel positions) evaluated there.
TEST(Unreachable, GivenSineValleysTighterThanTheWheel_ThenOneRegionEachAndBruteForceDepth) {
  const auto wheel = Wheel::from_arc_height(150.0, 0.5);
  const double k = 2.0 * std::numbers::pi / 100.0;
  const auto p = sampled(0.0, 0.1, 3001, [&](double z) { return 0.1 * std::sin(k * (z - 150.0)); });
  const LocalRule rule(p, FitSpec{}, wheel);
  const auto exact = exact_trajectory(p, wheel);
  const auto u = unreachable_regions(rule, exact, 1e-4);
  ASSERT_EQ(u.regions.size(), 3U);
  const double valley[3] = {25.0, 125.0, 225.0};
  for (std::size_t v = 0; v < 3; ++v) {
    const auto& r = u.regions[v];
    EXPECT_LT(r.z_from_mm, valley[v]);
    EXPECT_GT(r.z_to_mm, valley[v]);
    EXPECT_TRUE(r.concave_below_radius);
    EXPECT_NEAR(r.min_concave_radius_mm, 1.0 / (0.1 * k * k), 3.0);
    EXPECT_EQ(r.near_end, v != 1) << v;
  }
  // Brute force at the middle valley's bottom z = 125 (sample 1250).
  const std::ptrdiff_t m = half_window_samples(wheel, p.spacing_mm);
  double b = std::numeric_limits<double>::infinity();
  std::vector<double> ut(1);
  for (std::ptrdiff_t t = 1250 - m; t <= 1250 + m; ++t) {
    max_plus_arc_brute(p.u_mm, p.spacing_mm, wheel, t, ut);
    b = std::min(b, ut[0] + wheel.rise_mm(static_cast<double>(1250 - t) * p.spacing_mm));
  }
  const double left = b - p.u_mm[1250];
  EXPECT_NEAR(left, 0.0516, 2e-4);  // ≈ 51.6 µm (docs/grinding.md)
  EXPECT_NEAR(u.regions[1].worst_mm, left, 1e-12);
  EXPECT_NEAR(u.regions[1].z_worst_mm, 125.0, 0.05);
}

TEST(Regions, GivenDeviations_ThenRunsAboveTheToleranceWithTheirWorst) {
  const std::vector<double> dev{0.0, 2.0, 3.0, 1.0, std::nan(""), 5.0, 0.5, 4.0};
  const auto r = regions_above(dev, 10.0, 0.5, 1.5);
  ASSERT_EQ(r.size(), 3U);
  EXPECT_DOUBLE_EQ(r[0].z_from_mm, 10.5);
  EXPECT_DOUBLE_EQ(r[0].z_to_mm, 11.0);
  EXPECT_DOUBLE_EQ(r[0].worst_mm, 3.0);
  EXPECT_DOUBLE_EQ(r[0].z_worst_mm, 11.0);
  EXPECT_DOUBLE_EQ(r[1].z_from_mm, 12.5);  // NaN closes a run
  EXPECT_DOUBLE_EQ(r[1].z_to_mm, 12.5);
  EXPECT_DOUBLE_EQ(r[2].worst_mm, 4.0);
}

// The rule's lowest pass evaluated sample by sample equals the one over the stored points.
TEST(RuleVsEnvelope, GivenRuleEvaluatedBySample_ThenLowestPassEqualsStoredPoints) {
  const auto wheel = Wheel::from_arc_height(150.0, 0.5);
  const auto p = sampled(0.0, 0.1, 3001, [](double z) { return 0.1 * std::sin(z / 16.0); });
  const LocalRule rule(p, FitSpec{}, wheel);
  const auto t = local_rule_trajectory(p, local_derivatives(p, FitSpec{}), wheel);
  const auto exact = exact_trajectory(p, wheel);
  const auto a = lowest_pass_on_grid(t.point, exact.z0_mm, exact.spacing_mm, exact.u_mm.size());
  const auto b = lowest_pass_on_grid(rule, exact.z0_mm, exact.spacing_mm, exact.u_mm.size());
  std::vector<double> kept;
  (void)compare_rule_with_envelope(rule, exact, 1e-4, &kept);
  ASSERT_EQ(a.size(), b.size());
  ASSERT_EQ(a.size(), kept.size());
  std::size_t passed = 0;
  for (std::size_t i = 0; i < a.size(); ++i) {
    if (std::isnan(a[i])) {
      ASSERT_TRUE(std::isnan(b[i]) && std::isnan(kept[i])) << i;
    } else {
      ++passed;
      ASSERT_EQ(a[i], b[i]) << i;
      ASSERT_EQ(a[i], kept[i]) << i;
    }
  }
  EXPECT_GT(passed, 2900U);
}

}  // namespace
}  // namespace nccomp::core::grind
