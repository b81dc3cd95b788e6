// GIVEN a face probe capture of two points WHEN the tool cuts past them (registers, normal and cut
// path changing along the way) and the probe then reads them THEN each row carries the reading,
// the tool's cut path where the point was cut and, as applied_um, minus the compensation the wear
// registers made along the face normal there (L·n_z + R·sin θ), so measured + applied is the error
// before compensation; readings of no point, of another position, or of a point not cut this part
// give no row and are counted. No allocation.
#include "daemon/measurement_log_probe.hpp"

#include <gtest/gtest.h>

#include <cmath>

#include "tests/support/alloc_counter.hpp"

namespace nccomp::daemon {
namespace {

FaceProbeConfig two_points() {
  FaceProbeConfig c;
  c.count = 2;
  c.point_mm[0] = {30.0, 0.0};
  c.point_mm[1] = {30.0, 10.0};
  c.capture_radius_mm = 0.5;
  c.length_register = 0;
  c.radius_register = 1;
  return c;
}

core::AxisSample sample(double x, double y, double nz) {
  core::AxisSample a;
  a.position_mm = {x, y, 1.0, 0.0, 0.0, 0.0};
  a.tool = 1;
  a.has_normal = true;
  a.normal = {std::sqrt(1.0 - nz * nz), 0.0, nz};
  return a;
}

core::ProbeMeasurement probe(std::int32_t k, double x, double y, double reading_um) {
  core::ProbeMeasurement m;
  m.time_ns = 5'000'000'000;
  m.part = 3;
  m.checkpoint = k;
  m.raw_deviation_um = reading_um;
  m.position_mm = {x, y, 1.0};
  return m;
}

TEST(FaceProbeCapture, ARowCarriesTheCompensationAndCutPathWhereThePointWasCut) {
  FaceProbeCapture fp(two_points());
  fp.on_part_start();
  // Along pass 0 the length register grows with the wear: −20 µm at x = 29.8, −20.1 at 29.95,
  // −20.2 at 30.1; the normal tilts 0.8 / 0.6. Point 0 (x = 30) lies a third of the way from
  // the second sample to the third: compensation and cut path are interpolated there.
  fp.on_axis(sample(29.8, 0.0, 0.8), -20.0, -1.0, 100.0);
  fp.on_axis(sample(29.95, 0.0, 0.8), -20.1, -1.5, 100.15);
  fp.on_axis(sample(30.1, 0.0, 0.6), -20.2, -2.0, 100.3);
  // Far from both points: nothing captured.
  fp.on_axis(sample(10.0, 5.0, 1.0), -50.0, -9.0, 200.0);
  // Point 1, one sample; a sample that is not cutting (the probe cycle) changes nothing.
  fp.on_axis(sample(30.0, 10.2, 1.0), -25.0, -3.0, 400.0);
  core::AxisSample moving = sample(30.0, 10.0, 1.0);
  moving.cutting = false;
  fp.on_axis(moving, -99.0, -99.0, 999.0);

  core::MeasurementRecord r;
  ASSERT_TRUE(fp.on_probe(probe(0, 29.95, 0.0, 7.5), r));
  EXPECT_EQ(r.kind, core::MeasurementKind::kContour);
  EXPECT_EQ(r.part, 3);
  EXPECT_EQ(r.tool, 1);
  EXPECT_EQ(r.point, 0);
  EXPECT_DOUBLE_EQ(r.measured_um, 7.5);
  EXPECT_NEAR(r.path_mm, 100.2, 1e-12);
  // −(−20.1 · 0.8 + −1.5 · 0.6) = 16.98 µm compensated at x = 29.95, −(−20.2 · 0.6 + −2 · 0.8) =
  // 13.72 at 30.1; at x = 30: 16.98 − (16.98 − 13.72) / 3 = 15.8933, the error before it 23.3933.
  EXPECT_NEAR(r.applied_um, 16.98 - (16.98 - 13.72) / 3.0, 1e-12);
  EXPECT_NEAR(r.measured_um + r.applied_um, 7.5 + 16.98 - (16.98 - 13.72) / 3.0, 1e-12);

  ASSERT_TRUE(fp.on_probe(probe(1, 30.0, 10.2, 5.0), r));
  EXPECT_DOUBLE_EQ(r.path_mm, 400.0);
  EXPECT_NEAR(r.applied_um, 25.0, 1e-12);  // n = (0, 0, 1): the length register alone
  EXPECT_EQ(fp.rejected(), 0U);
}

// ncsim's mould face at its edge passes: z = 1.5 mm · (1 − v²), v = 2y/30 − 1, so at y = 0 the
// slope dz/dy is 0.2 and the normal (0, −0.2, 1)/√1.04; the NC reports the 3 mm ball's centre,
// 3 · 0.2/√1.04 = 0.588 mm off the cut point, beyond a capture radius under half the 1 mm
// stepover. The capture takes the contact point (centre − r·n): the edge points get their rows,
// and the neighbouring pass (y = 1, whose centre lies 0.45 mm from y = 0) is not taken for them.
TEST(FaceProbeCapture, TheEdgePassesOfASlopedFaceAreCapturedAtTheBallsContactPoint) {
  FaceProbeConfig c;
  c.count = 2;
  c.point_mm[0] = {30.0, 0.0};
  c.point_mm[1] = {30.0, 30.0};
  c.capture_radius_mm = 0.4;
  c.ball_radius_mm = 3.0;
  c.length_register = 0;
  c.radius_register = 1;
  FaceProbeCapture fp(c);
  fp.on_part_start();
  const auto pass = [&](double y, double slope, double length_um, double path_mm) {
    const double norm = std::sqrt(1.0 + slope * slope);
    core::AxisSample a;
    a.tool = 1;
    a.has_normal = true;
    a.normal = {0.0, -slope / norm, 1.0 / norm};
    a.position_mm = {30.0, y + 3.0 * a.normal[1], 3.0 * a.normal[2], 0.0, 0.0, 0.0};
    fp.on_axis(a, length_um, 0.0, path_mm);
  };
  pass(0.0, 0.2, -10.0, 100.0);
  pass(1.0, 0.2 * (1.0 - 2.0 / 30.0), -11.0, 160.0);
  pass(29.0, -0.2 * (1.0 - 2.0 / 30.0), -40.0, 1840.0);
  pass(30.0, -0.2, -41.0, 1900.0);

  core::MeasurementRecord r;
  ASSERT_TRUE(fp.on_probe(probe(0, 30.0, 0.0, 3.0), r));
  EXPECT_DOUBLE_EQ(r.path_mm, 100.0);
  EXPECT_NEAR(r.applied_um, 10.0 / std::sqrt(1.04), 1e-12);  // −L·n_z
  ASSERT_TRUE(fp.on_probe(probe(1, 30.0, 30.0, 3.0), r));
  EXPECT_DOUBLE_EQ(r.path_mm, 1900.0);
  EXPECT_NEAR(r.applied_um, 41.0 / std::sqrt(1.04), 1e-12);
  EXPECT_EQ(fp.rejected(), 0U);
}

// A fast feed or a coarse sampling (the daemon in real time beside ncsim at x4: 0.55 mm of path
// per cycle) puts the samples farther apart than the capture radius: the point lies between two
// of them, 0.5 mm from each. Its cut is the place on the segment between them.
TEST(FaceProbeCapture, APointBetweenTwoSamplesFartherApartThanTheRadiusIsCapturedOnTheSegment) {
  FaceProbeConfig c = two_points();
  c.capture_radius_mm = 0.4;
  FaceProbeCapture fp(c);
  fp.on_part_start();
  fp.on_axis(sample(29.5, 0.1, 1.0), -20.0, 0.0, 100.0);
  fp.on_axis(sample(30.5, 0.1, 1.0), -21.0, 0.0, 101.0);
  core::MeasurementRecord r;
  ASSERT_TRUE(fp.on_probe(probe(0, 30.0, 0.0, 2.0), r));
  EXPECT_NEAR(r.path_mm, 100.5, 1e-12);
  EXPECT_NEAR(r.applied_um, 20.5, 1e-12);
  // The point's nearest place along the segment, not the nearer end: a later segment that
  // passes farther (0.3 mm) does not replace it.
  fp.on_axis(sample(29.0, 0.3, 1.0), -30.0, 0.0, 200.0);
  fp.on_axis(sample(31.0, 0.3, 1.0), -30.0, 0.0, 202.0);
  ASSERT_TRUE(fp.on_probe(probe(0, 30.0, 0.0, 2.0), r));
  EXPECT_NEAR(r.path_mm, 100.5, 1e-12);
  // A jump longer than 10 capture radii (one pass's end to the next one's start while the NC
  // says "cutting") is no segment: point 1, passed 0.1 mm off by the straight line from
  // (20, 10.1) to (40, 10.1), is not cut.
  fp.on_axis(sample(20.0, 10.1, 1.0), -30.0, 0.0, 300.0);
  fp.on_axis(sample(40.0, 10.1, 1.0), -30.0, 0.0, 320.0);
  EXPECT_FALSE(fp.on_probe(probe(1, 30.0, 10.0, 2.0), r));
  // A segment between two tools is none either.
  fp.on_axis(sample(29.5, 10.1, 1.0), -30.0, 0.0, 400.0);
  core::AxisSample other = sample(30.5, 10.1, 1.0);
  other.tool = 2;
  fp.on_axis(other, -30.0, 0.0, 5.0);
  EXPECT_FALSE(fp.on_probe(probe(1, 30.0, 10.0, 2.0), r));
  // The tool lifted to the laser at x = 29.6 and came back to cut at x = 30.4: the places
  // between were cut (before it left, after it came back); the samples while it was away,
  // not cutting, are not the cut.
  fp.on_axis(sample(29.6, 10.1, 1.0), -30.0, 0.0, 500.0);
  core::AxisSample lifted = sample(30.0, 10.0, 1.0);
  lifted.cutting = false;
  fp.on_axis(lifted, -99.0, 0.0, 500.0);
  fp.on_axis(sample(30.4, 10.1, 1.0), -32.0, 0.0, 500.8);
  ASSERT_TRUE(fp.on_probe(probe(1, 30.0, 10.0, 2.0), r));
  EXPECT_NEAR(r.path_mm, 500.4, 1e-12);
  EXPECT_NEAR(r.applied_um, 31.0, 1e-12);
}

TEST(FaceProbeCapture, ReadingsOfNoPointOrAnotherPlaceOrAnUncutPointAreCountedNotLogged) {
  FaceProbeCapture fp(two_points());
  fp.on_part_start();
  fp.on_axis(sample(30.0, 0.0, 1.0), -20.0, 0.0, 100.0);
  core::MeasurementRecord r;
  EXPECT_FALSE(fp.on_probe(probe(2, 30.0, 0.0, 1.0), r));   // no point 2
  EXPECT_FALSE(fp.on_probe(probe(-1, 30.0, 0.0, 1.0), r));  // a bad number
  EXPECT_FALSE(fp.on_probe(probe(0, 35.0, 0.0, 1.0), r));   // another position
  EXPECT_FALSE(fp.on_probe(probe(1, 30.0, 10.0, 1.0), r));  // point 1 not cut
  core::ProbeMeasurement faulty = probe(0, 30.0, 0.0, 1.0);
  faulty.fault = core::InputFault::kInvalid;
  EXPECT_FALSE(fp.on_probe(faulty, r));
  EXPECT_FALSE(fp.on_probe(probe(0, std::nan(""), 0.0, 1.0), r));  // no position
  EXPECT_EQ(fp.rejected(), 6U);
  // A sample without a position is no cut of a point.
  fp.on_axis(sample(std::nan(""), 10.0, 1.0), -20.0, 0.0, 100.0);
  EXPECT_FALSE(fp.on_probe(probe(1, 30.0, 10.0, 1.0), r));
  EXPECT_TRUE(fp.on_probe(probe(0, 30.0, 0.0, 1.0), r));
  // A new part: its points are cut again before they are read.
  fp.on_part_start();
  EXPECT_FALSE(fp.on_probe(probe(0, 30.0, 0.0, 1.0), r));
  EXPECT_EQ(fp.rejected(), 8U);
}

TEST(FaceProbeCapture, CaptureAndRowsAllocateNothing) {
  FaceProbeCapture fp(two_points());
  core::MeasurementRecord r;
  const nccomp::test::AllocationScope scope;
  for (int part = 0; part < 3; ++part) {
    fp.on_part_start();
    for (int i = 0; i < 1000; ++i) {
      fp.on_axis(sample(29.5 + 0.001 * i, 0.0, 0.9), -20.0, -1.0, 0.05 * i);
    }
    EXPECT_TRUE(fp.on_probe(probe(0, 30.0, 0.0, 4.0), r));
  }
  EXPECT_EQ(scope.count(), 0U);
}

}  // namespace
}  // namespace nccomp::daemon
