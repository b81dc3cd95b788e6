#include "core/checkpoint/plan.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <stdexcept>
#include <string>

namespace nccomp::core::checkpoint {
namespace {

// A 100 × 60 mm boss, counter-clockwise, material inside, probed at 5 levels.
PlanConfig boss() {
  PlanConfig c;
  c.contour = {{0, 0}, {100, 0}, {100, 60}, {0, 60}};
  c.closed = true;
  c.material = MaterialSide::kInside;
  c.contour_z_mm = 0.0;
  c.z_start_mm = -2.0;
  c.z_end_mm = -22.0;
  c.depth_step_mm = 5.0;
  c.wall_angle_deg = 3.0;
  c.corner_angle_deg = 20.0;
  c.corner_offset_mm = 5.0;
  c.tool_radius_mm = 6.0;
  c.ball_radius_mm = 1.5;
  c.probe_approach_mm = 4.0;
  return c;
}

std::string error_of(const PlanConfig& c) {
  try {
    (void)make_plan(c);
  } catch (const std::invalid_argument& e) {
    return e.what();
  }
  return "";
}

TEST(Plan, CornersLevelsAndMachiningOrder) {
  const Plan p = make_plan(boss());
  ASSERT_EQ(p.levels_z_mm.size(), 5U);
  EXPECT_DOUBLE_EQ(p.levels_z_mm[0], -2.0);
  EXPECT_DOUBLE_EQ(p.levels_z_mm[4], -22.0);
  EXPECT_EQ(p.corner_count, 4U);
  EXPECT_DOUBLE_EQ(p.contour_length_mm, 320.0);
  ASSERT_EQ(p.checkpoints.size(), 40U);
  // Per level: 5 mm after and before each corner, sorted along the contour.
  const double expect_s[8] = {5, 95, 105, 155, 165, 255, 265, 315};
  for (std::size_t i = 0; i < 40; ++i) {
    const Checkpoint& cp = p.checkpoints[i];
    EXPECT_EQ(cp.id, static_cast<std::int32_t>(i));
    EXPECT_EQ(cp.level, static_cast<std::int32_t>(i / 8));
    EXPECT_DOUBLE_EQ(cp.s_mm, expect_s[i % 8]);
    EXPECT_DOUBLE_EQ(cp.z_mm, -2.0 - 5.0 * static_cast<double>(i / 8));
    // Program path: one contour (320 mm) plus a 5 mm plunge per level.
    EXPECT_DOUBLE_EQ(cp.path_mm, static_cast<double>(i / 8) * 325.0 + expect_s[i % 8]);
    EXPECT_DOUBLE_EQ(cp.alpha_deg, 3.0);
    if (i > 0) {
      EXPECT_GT(cp.path_mm, p.checkpoints[i - 1].path_mm);
    }
  }
}

TEST(Plan, NormalsDraftToolAndProbePositions) {
  const Plan p = make_plan(boss());
  // Checkpoint 0: on the bottom edge (y = 0) at x = 5; the material is above (inside), so the
  // probe moves +Y; the 3° draft puts the wall (0 − (−2))·tan 3° = 0.10482 mm further out at −2.
  const Checkpoint& c0 = p.checkpoints[0];
  EXPECT_NEAR(c0.x_mm, 5.0, 1e-12);
  EXPECT_NEAR(c0.y_mm, -0.1048156, 1e-6);
  EXPECT_NEAR(c0.dir_x, 0.0, 1e-12);
  EXPECT_NEAR(c0.dir_y, 1.0, 1e-12);
  EXPECT_NEAR(c0.tool_y_mm, -6.1048156, 1e-6);
  EXPECT_NEAR(c0.start_y_mm, -0.1048156 - 5.5, 1e-6);
  // Checkpoint 2 (s = 105) is on the right edge x = 100: probe moves −X.
  const Checkpoint& c2 = p.checkpoints[2];
  EXPECT_NEAR(c2.x_mm, 100.1048156, 1e-6);
  EXPECT_NEAR(c2.y_mm, 5.0, 1e-12);
  EXPECT_NEAR(c2.dir_x, -1.0, 1e-12);
  // Lowest level, 22 mm below the contour: 22·tan 3° = 1.15297 mm.
  EXPECT_NEAR(p.checkpoints[32].y_mm, -22.0 * std::tan(3.0 * M_PI / 180.0), 1e-9);
}

TEST(Plan, ClockwiseContourAndPocketFlipTheNormal) {
  PlanConfig c = boss();
  c.wall_angle_deg = 0.0;
  c.contour = {{0, 0}, {0, 60}, {100, 60}, {100, 0}};  // clockwise
  Plan p = make_plan(c);
  // First point: (0, 5) on the left edge; material inside (+X side) → probe moves +X.
  EXPECT_NEAR(p.checkpoints[0].x_mm, 0.0, 1e-12);
  EXPECT_NEAR(p.checkpoints[0].y_mm, 5.0, 1e-12);
  EXPECT_NEAR(p.checkpoints[0].dir_x, 1.0, 1e-12);
  c.material = MaterialSide::kOutside;  // a pocket: the probe moves from inside outward
  p = make_plan(c);
  EXPECT_NEAR(p.checkpoints[0].dir_x, -1.0, 1e-12);
  EXPECT_NEAR(p.checkpoints[0].tool_x_mm, 6.0, 1e-12);
}

TEST(Plan, ArcApproximatedBySmallSegmentsIsNotACorner) {
  PlanConfig c = boss();
  c.wall_angle_deg = 0.0;
  // Replace the corner at (100, 60) by a 10 mm radius fillet made of 10 segments of 9°.
  c.contour = {{0, 0}, {100, 0}, {100, 50}};
  for (int k = 1; k < 10; ++k) {
    const double a = static_cast<double>(k) * 9.0 * M_PI / 180.0;
    c.contour.push_back({90.0 + 10.0 * std::cos(a), 50.0 + 10.0 * std::sin(a)});
  }
  c.contour.push_back({90, 60});
  c.contour.push_back({0, 60});
  const Plan p = make_plan(c);
  // The fillet's vertices turn by 9° each (< 20°): 3 corners, not 4.
  EXPECT_EQ(p.corner_count, 3U);
  EXPECT_EQ(p.checkpoints.size(), 5U * 6U);
}

TEST(Plan, ExtraPointsAndRegionsForFlexibleAreas) {
  PlanConfig c = boss();
  c.extra_points_mm = {50.0, 95.0};  // 95 coincides with a corner point: merged
  c.extra_regions = {{170.0, 190.0, 10.0}};
  const Plan p = make_plan(c);
  ASSERT_EQ(p.checkpoints.size(), 5U * 12U);
  const double expect_s[12] = {5, 50, 95, 105, 155, 165, 170, 180, 190, 255, 265, 315};
  for (std::size_t i = 0; i < 12; ++i) {
    EXPECT_DOUBLE_EQ(p.checkpoints[i].s_mm, expect_s[i]) << i;
  }
  EXPECT_EQ(p.checkpoints[1].source, CheckpointSource::kExtra);
  EXPECT_EQ(p.checkpoints[2].source, CheckpointSource::kCorner);
}

TEST(Plan, OpenContourAndShortSegmentsClampTheCornerOffset) {
  PlanConfig c;
  c.contour = {{0, 0}, {50, 0}, {50, 6}, {100, 6}};  // a 6 mm step: corner points 3 mm apart
  c.closed = false;
  c.material = MaterialSide::kLeft;
  c.z_start_mm = -1.0;
  c.z_end_mm = -1.0;
  c.depth_step_mm = 1.0;
  c.corner_offset_mm = 5.0;
  const Plan p = make_plan(c);
  ASSERT_EQ(p.checkpoints.size(),
            3U);  // 45, 53 (= 50 + 3 after the first, 3 before the second), 61
  EXPECT_DOUBLE_EQ(p.checkpoints[0].s_mm, 45.0);
  EXPECT_DOUBLE_EQ(p.checkpoints[1].s_mm, 53.0);
  EXPECT_DOUBLE_EQ(p.checkpoints[2].s_mm, 61.0);
  // Material on the left of +X travel is +Y: probe moves +Y.
  EXPECT_NEAR(p.checkpoints[0].dir_y, 1.0, 1e-12);
}

TEST(Plan, BadConfigsNameTheKey) {
  PlanConfig c = boss();
  c.depth_step_mm = 0.0;
  EXPECT_NE(error_of(c).find("checkpoints.depth_step_mm"), std::string::npos);
  c = boss();
  c.z_end_mm = 5.0;
  EXPECT_NE(error_of(c).find("checkpoints.z_end_mm"), std::string::npos);
  c = boss();
  c.wall_angle_deg = 89.0;
  EXPECT_NE(error_of(c).find("checkpoints.wall_angle_deg"), std::string::npos);
  c = boss();
  c.contour[2] = c.contour[1];
  EXPECT_NE(error_of(c).find("coincide"), std::string::npos);
  c = boss();
  c.contour.resize(2);
  EXPECT_NE(error_of(c).find("at least 3"), std::string::npos);
  c = boss();
  c.corner_angle_deg = 120.0;  // a rectangle has 90° corners only
  EXPECT_NE(error_of(c).find("no checkpoints"), std::string::npos);
  c = boss();
  c.extra_points_mm = {400.0};
  EXPECT_NE(error_of(c).find("extra_points_mm[0]"), std::string::npos);
  c = boss();
  c.extra_regions = {{10.0, 20.0, 0.0}};
  EXPECT_NE(error_of(c).find("extra_regions[0].spacing_mm"), std::string::npos);
  c = boss();
  c.tool_radius_mm = -1.0;
  EXPECT_NE(error_of(c).find("checkpoints.tool_radius_mm"), std::string::npos);
  c = boss();
  c.contour[1].x_mm = std::nan("");
  EXPECT_NE(error_of(c).find("not finite"), std::string::npos);
  c = boss();
  c.closed = false;
  EXPECT_NE(error_of(c).find("checkpoints.material"), std::string::npos);
  c = boss();
  c.depth_step_mm = 0.001;  // 20001 levels
  EXPECT_NE(error_of(c).find("levels"), std::string::npos);
}

TEST(ContourCsv, ParsesPointsCommentsAndCrLf) {
  const auto pts = parse_contour_csv(
      "# boss, machining direction CCW\r\nx_mm,y_mm\r\n0,0\r\n100.5, 0\r\n\n 100.5 ,60\r\n",
      "wall.csv");
  ASSERT_EQ(pts.size(), 3U);
  EXPECT_DOUBLE_EQ(pts[1].x_mm, 100.5);
  EXPECT_DOUBLE_EQ(pts[2].y_mm, 60.0);
}

TEST(ContourCsv, ErrorsNameFileAndLine) {
  const auto err = [](const char* text) {
    try {
      (void)parse_contour_csv(text, "wall.csv");
    } catch (const std::invalid_argument& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  EXPECT_EQ(err("x,y\n1,2\n").rfind("wall.csv:1: header", 0), 0U) << err("x,y\n1,2\n");
  EXPECT_EQ(err("x_mm,y_mm\n1,2\n3,abc\n").rfind("wall.csv:3: column y_mm", 0), 0U);
  EXPECT_EQ(err("x_mm,y_mm\n1,2,3\n").rfind("wall.csv:2: expected exactly two", 0), 0U);
  EXPECT_EQ(err("x_mm,y_mm\n1\n").rfind("wall.csv:2: expected two", 0), 0U);
  EXPECT_EQ(err("x_mm,y_mm\nnan,2\n").rfind("wall.csv:2: column x_mm is not finite", 0), 0U);
  EXPECT_EQ(err("x_mm,y_mm\n1e999,2\n").rfind("wall.csv:2: column x_mm", 0), 0U);
  EXPECT_EQ(err(",\n").rfind("wall.csv:1: header", 0), 0U);
  EXPECT_EQ(err("").rfind("wall.csv: empty", 0), 0U);
  EXPECT_EQ(err("x_mm,y_mm\n# nothing\n").rfind("wall.csv: contour file has a header but no", 0),
            0U);
}

}  // namespace
}  // namespace nccomp::core::checkpoint
