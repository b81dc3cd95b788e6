#include "core/grind/path.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <vector>

namespace nccomp::core::grind {
namespace {

GridTrajectory grid(double z0, double dz, std::size_t n, auto&& fn) {
  GridTrajectory t{z0, dz, std::vector<double>(n)};
  for (std::size_t i = 0; i < n; ++i) {
    t.u_mm[i] = fn(t.z_at(static_cast<std::ptrdiff_t>(i)));
  }
  return t;
}

TEST(Path, GivenStraightTrajectory_ThenOneMove) {
  const auto t = grid(-10.0, 0.01, 2001, [](double z) { return 0.3 + 0.002 * z; });
  const auto poly = simplify_polyline(t, 1e-4, 1e-4, 0.0);
  ASSERT_EQ(poly.size(), 2U);
  EXPECT_NEAR(poly.back().z_mm, 10.0, 1e-12);
  EXPECT_LT(chord_error_mm(t, poly), 1e-12);
  // A move length cap splits it.
  EXPECT_EQ(simplify_polyline(t, 1e-4, 1e-4, 5.0).size(), 5U);
}

// GIVEN a parabola of curvature κ, THEN chords of length L err by κL²/8: the greedy cone
// reaches the tolerance and never exceeds it.
TEST(Path, GivenCurvedTrajectory_ThenChordErrorWithinToleranceAndNearIt) {
  const double kappa = 2e-4;
  const auto t = grid(-300.0, 0.05, 12001, [&](double z) { return 0.5 * kappa * z * z; });
  const double tol = 0.5e-3;
  const auto poly = simplify_polyline(t, tol, tol, 0.0);
  const double err = chord_error_mm(t, poly);
  EXPECT_LE(err, tol + 1e-12);
  EXPECT_GT(err, 0.8 * tol);
  // Chord length for tolerance tol: sqrt(8·tol/κ) = 4.47 mm → about 134 moves over 600 mm.
  EXPECT_NEAR(static_cast<double>(poly.size() - 1), 600.0 / std::sqrt(8 * tol / kappa), 3.0);
  const auto rounded = round_vertices(poly, 4);
  EXPECT_LE(chord_error_mm(t, rounded), tol + 0.5e-4 + 1e-12);
}

// GIVEN a crown-like (concave-down) trajectory and a gouge-free band [U, U + tol], THEN no chord
// dips below it, and the moves are as long as with a symmetric band of the same width.
TEST(Path, GivenGougeFreeBand_ThenPolylineNeverBelowTrajectory) {
  const double kappa = 2e-4;
  const auto t = grid(-300.0, 0.05, 12001, [&](double z) { return 0.6 - 0.5 * kappa * z * z; });
  const double tol = 1e-3;
  const auto poly = simplify_polyline(t, 0.0, tol, 0.0);
  const auto e = chord_error(t, poly);
  EXPECT_LT(e.below_mm, 1e-12);
  EXPECT_LE(e.above_mm, tol + 1e-12);
  // Vertices sit tol/2 above, chords sag by up to tol/2 toward the trajectory.
  EXPECT_NEAR(e.above_mm, 0.5 * tol, 1e-12);
  const auto symmetric = simplify_polyline(t, 0.5 * tol, 0.5 * tol, 0.0);
  EXPECT_EQ(poly.size(), symmetric.size());
  // Rounding U up keeps it gouge-free.
  const auto rounded = round_vertices(poly, 4, true);
  EXPECT_LT(chord_error(t, rounded).below_mm, 1e-12);
  EXPECT_LE(chord_error(t, rounded).above_mm, tol + 1e-4 + 1e-12);
  EXPECT_THROW(simplify_polyline(t, 0.0, 0.0, 0.0), std::invalid_argument);
  EXPECT_THROW(simplify_polyline(t, -1e-3, 1e-3, 0.0), std::invalid_argument);
}

TEST(Path, GivenVertices_ThenGcodeBlocks) {
  const std::vector<TrajectoryPoint> poly{{-1.0, 0.25}, {0.5, -0.000049}, {2.0, 0.123456}};
  GcodeSpec spec;
  spec.feed_mm_per_min = 300.0;
  spec.header_comments = {"test"};
  EXPECT_EQ(gcode_blocks(poly, spec),
            "; test\n"
            "N10 G90 G01 Z-1.0000 X0.2500 F300.0\n"
            "N20 G01 Z0.5000 X-0.0000\n"
            "N30 G01 Z2.0000 X0.1235\n");
}

TEST(Path, GivenTrajectoryAndProfile_ThenCorrectionTable) {
  const UniformProfile p{0.0, 0.1, std::vector<double>(101, 0.2)};  // flat 0.2 mm, z 0..10
  const auto t = grid(-2.0, 0.1, 141, [](double z) { return 0.2 + 0.001 * z * z; });
  const auto table = correction_table(t, p, 3.0);
  ASSERT_EQ(table.size(), 5U);  // 0, 3, 6, 9 and the end 10
  EXPECT_NEAR(table[1].z_mm, 3.0, 1e-12);
  EXPECT_NEAR(table[1].u_wheel_mm, 0.209, 1e-12);
  EXPECT_NEAR(table[1].correction_um, 9.0, 1e-9);
  EXPECT_NEAR(table.back().z_mm, 10.0, 1e-12);
  EXPECT_NEAR(table.back().correction_um, 100.0, 1e-9);
  // Linear interpolation of a parabola between rows 3 mm apart: κL²/8 = 0.002·9/8.
  EXPECT_NEAR(table_interpolation_error_mm(t, p, table), 0.002 * 9.0 / 8.0, 1e-6);
  EXPECT_THROW(correction_table(t, p, 0.0), std::invalid_argument);
}

}  // namespace
}  // namespace nccomp::core::grind
