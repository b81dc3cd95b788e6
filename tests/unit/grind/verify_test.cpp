#include "core/grind/verify.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "core/grind/envelope.hpp"
#include "core/grind/local_rule.hpp"
#include "tests/unit/grind/sampled.hpp"

namespace nccomp::core::grind {
namespace {

using test::sampled;

std::vector<TrajectoryPoint> as_points(const UniformProfile& p) {
  std::vector<TrajectoryPoint> q(p.size());
  for (std::size_t i = 0; i < p.size(); ++i) {
    q[i] = {p.z_at(static_cast<std::ptrdiff_t>(i)), p.u_mm[i]};
  }
  return q;
}

std::vector<TrajectoryPoint> as_points(const GridTrajectory& t) {
  std::vector<TrajectoryPoint> q(t.u_mm.size());
  for (std::size_t i = 0; i < q.size(); ++i) {
    q[i] = {t.z_at(static_cast<std::ptrdiff_t>(i)), t.u_mm[i]};
  }
  return q;
}

std::vector<double> zs(const UniformProfile& p) {
  std::vector<double> z(p.size());
  for (std::size_t i = 0; i < p.size(); ++i) {
    z[i] = p.z_at(static_cast<std::ptrdiff_t>(i));
  }
  return z;
}

// The usual practice (T follows P) on a straight line of slope b grinds P − R(sqrt(1+b²) − 1)
// inside: the wheel's arc, tangent to the line, sits that far below its lowest point.
TEST(Verify, GivenUsualPracticeOnStraightLine_ThenClosedFormGouge) {
  const auto wheel = Wheel::from_arc_height(150.0, 0.5);
  const double b = 0.002;
  const auto p = sampled(0.0, 1.0, 601, [&](double z) { return b * z; });
  const auto z = zs(p);
  const auto ground = ground_by_polyline(as_points(p), wheel, z);
  const double gouge = wheel.radius_mm() * (std::sqrt(1 + b * b) - 1);  // ≈ 11.25 µm
  for (std::size_t i = 100; i <= 500; i += 25) {
    EXPECT_NEAR(ground[i], p.u_mm[i] - gouge, 1e-12) << z[i];
  }
}

// The issue's example: crown 0.6 mm over ±500 mm, W = 150, h = 0.5. For P = c − a·z² the usual
// practice gouges by P'²/(2(1/R − 2a)) while the best wheel position is on the profile; near the
// end the path stops at z = 500 and the gouge is e(z) = P(z) − P(500) − g(500 − z), largest at
// z = 500/(1 + 2aR) ≈ 486.85 mm: ≈ 15.77 µm, the seed's "about 0.02 mm" (derivation in
// docs/grinding.md). The exact envelope grinds P back to sampling resolution.
TEST(Verify, GivenIssueCrown_ThenUsualPracticeErrsAbout16umAndExactIsAtResolution) {
  const auto wheel = Wheel::from_arc_height(150.0, 0.5);
  const auto p = sampled(-500.0, 0.5, 2001, [](double z) { return 0.6 * (1 - z * z / 2.5e5); });
  const auto z = zs(p);
  const auto usual = compare_ground(z, ground_by_polyline(as_points(p), wheel, z), p.u_mm);
  const double a = 0.6 / 2.5e5;
  const double z_star = 500.0 / (1.0 + 2 * a * wheel.radius_mm());
  const double expect = a * (500.0 * 500.0 - z_star * z_star) - wheel.rise_mm(500.0 - z_star);
  EXPECT_NEAR(expect, 0.015775, 1e-6);
  // Evaluated on the 0.5 mm samples, the nearest is 0.15 mm from z*.
  EXPECT_NEAR(usual.max_gouge_mm, expect, 5e-6);
  EXPECT_NEAR(std::abs(usual.z_at_max_mm), z_star, 0.5);
  EXPECT_LT(usual.max_left_mm, 1e-12);
  EXPECT_GT(usual.rms_mm, 0.003);
  EXPECT_EQ(usual.points, 2001U);

  const auto exact = exact_trajectory(p, wheel);
  const auto e = compare_ground(z, ground_by_polyline(as_points(exact), wheel, z), p.u_mm);
  EXPECT_LT(e.max_abs_mm, 1e-5);  // κΔ²/8 with Δ = 0.5 mm: ~6e-6

  const auto d = local_derivatives(p, FitSpec{});
  const auto local = local_rule_trajectory(p, d, wheel);
  const auto l = compare_ground(z, ground_by_polyline(local.point, wheel, z), p.u_mm);
  EXPECT_LT(l.max_abs_mm, 1e-5);
}

// The two B implementations (deque min-plus on grid values, brute force over polyline
// segments) agree where the trajectory is smooth.
TEST(Verify, GivenExactTrajectory_ThenPolylineAndGridGroundProfilesAgree) {
  const auto wheel = Wheel::from_arc_height(100.0, 0.3);
  const auto p = sampled(-100.0, 0.2, 1001, [](double z) { return 0.05 * std::sin(z / 15.0); });
  const auto t = exact_trajectory(p, wheel);
  const auto z = zs(p);
  const auto poly = ground_by_polyline(as_points(t), wheel, z);
  const auto grid = ground_profile_fast(t, p, wheel);
  double worst = 0.0;
  for (std::size_t i = 0; i < z.size(); ++i) {
    worst = std::max(worst, std::abs(poly[i] - grid[i]));
  }
  EXPECT_LT(worst, 1e-5);
  EXPECT_GT(worst, 0.0);  // they are different algorithms, not the same numbers
}

// Sorted paths take a copy-free walk, any other order the sorted segment list: same numbers.
TEST(Verify, GivenReversedPolyline_ThenSameGroundProfile) {
  const auto wheel = Wheel::from_arc_height(100.0, 0.3);
  const auto p = sampled(-100.0, 0.2, 1001, [](double z) { return 0.05 * std::sin(z / 15.0); });
  const auto t = exact_trajectory(p, wheel);
  auto q = as_points(t);
  const auto z = zs(p);
  const auto forward = ground_by_polyline(q, wheel, z);
  std::reverse(q.begin(), q.end());
  const auto backward = ground_by_polyline(q, wheel, z);
  for (std::size_t i = 0; i < z.size(); ++i) {
    ASSERT_NEAR(forward[i], backward[i], 1e-15) << z[i];
  }
}

// The paths the command verifies without copying them (a grid, the rule sample by sample) give
// the same numbers as the same paths stored as points.
TEST(Verify, GivenGridAndRulePathsReadInPlace_ThenSameAsStoredPoints) {
  const auto wheel = Wheel::from_arc_height(100.0, 0.3);
  const auto p = sampled(-100.0, 0.2, 1001, [](double z) { return 0.05 * std::sin(z / 6.0); });
  const auto t = exact_trajectory(p, wheel);
  const auto z = zs(p);
  const auto grid = ground_by_grid_path(t.z0_mm, t.spacing_mm, t.u_mm, wheel, z);
  const auto stored = ground_by_polyline(as_points(t), wheel, z);
  const auto usual = ground_by_grid_path(p.z0_mm, p.spacing_mm, p.u_mm, wheel, z);
  const auto usual_stored = ground_by_polyline(as_points(p), wheel, z);
  const LocalRule rule(p, FitSpec{}, wheel);
  const auto local = local_rule_trajectory(p, local_derivatives(p, FitSpec{}), wheel);
  const auto by_sample = ground_by_polyline(rule, z);
  const auto rule_stored = ground_by_polyline(local.point, wheel, z);
  for (std::size_t i = 0; i < z.size(); ++i) {
    ASSERT_EQ(grid[i], stored[i]) << z[i];
    ASSERT_EQ(usual[i], usual_stored[i]) << z[i];
    ASSERT_EQ(by_sample[i], rule_stored[i]) << z[i];
  }
  // The rule's path doubles back in the valleys (radius 720 mm < R = 4167 mm): not sorted.
  bool doubles_back = false;
  for (std::size_t i = 1; i < local.point.size(); ++i) {
    doubles_back = doubles_back || local.point[i].z_mm < local.point[i - 1].z_mm;
  }
  EXPECT_TRUE(doubles_back);
  // And the verification sees the rule gouge there while the envelope does not.
  const auto e_rule = compare_ground(z, by_sample, p.u_mm);
  const auto e_exact = compare_ground(z, grid, p.u_mm);
  EXPECT_GT(e_rule.max_gouge_mm, 1e-3);
  // The envelope's grid points joined by chords: on its crests (curvature ≈ P''/(1 + R·P'') ≈
  // 2e-4/mm) a chord of 0.2 mm sags κΔ²/8 ≈ 1e-6 mm below it.
  EXPECT_LT(e_exact.max_gouge_mm, 2e-6);
}

TEST(Verify, GivenNonFinitePoint_ThenThrows) {
  const auto wheel = Wheel::from_arc_height(10.0, 0.1);
  const std::vector<TrajectoryPoint> q{{0.0, 0.0}, {1.0, std::nan("")}, {2.0, 0.0}};
  const std::vector<double> z{0.5};
  EXPECT_THROW(ground_by_polyline(q, wheel, z), std::invalid_argument);
  EXPECT_THROW(ground_by_polyline(std::vector<TrajectoryPoint>{}, wheel, z), std::invalid_argument);
}

TEST(Verify, GivenNoTrajectoryWithinReach_ThenUnreached) {
  const auto wheel = Wheel::from_arc_height(10.0, 0.1);
  const std::vector<TrajectoryPoint> q{{0.0, 0.0}, {1.0, 0.0}};
  const std::vector<double> z{0.5, 20.0};
  const auto b = ground_by_polyline(q, wheel, z);
  EXPECT_NEAR(b[0], 0.0, 1e-15);
  EXPECT_TRUE(std::isinf(b[1]));
  const std::vector<double> pz{0.0, 0.0};
  const auto e = compare_ground(z, b, pz);
  EXPECT_EQ(e.unreached, 1U);
  EXPECT_EQ(e.points, 1U);
}

}  // namespace
}  // namespace nccomp::core::grind
