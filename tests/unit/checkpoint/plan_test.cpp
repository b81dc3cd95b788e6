#include "core/checkpoint/plan.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <limits>
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

// A boss with a half-round end: a line, a tangent arc (radius 30, 18 chords of 10°), a line
// back and a straight closing edge. The line → arc and arc → line junctions are tangent (the
// polyline turns by 5° there): only marking them makes them sub-curve boundaries. The arc is
// drafted at 5°, the rest at the config's 3°.
PlanConfig rounded_boss() {
  PlanConfig c = boss();
  c.z_start_mm = -2.0;
  c.z_end_mm = -2.0;
  c.contour = {{0, 0}, {100, 0, 5.0, CornerMark::kCorner}};
  for (int k = 1; k < 18; ++k) {
    const double a = -M_PI / 2 + static_cast<double>(k) * 10.0 * M_PI / 180.0;
    c.contour.push_back({100.0 + 30.0 * std::cos(a), 30.0 + 30.0 * std::sin(a)});
  }
  c.contour.push_back({100, 60, 3.0, CornerMark::kCorner});
  c.contour.push_back({0, 60});
  return c;
}

TEST(Plan, MarkedSubCurveBoundariesAreCornersEvenWhereTheContourIsTangent) {
  PlanConfig c = rounded_boss();
  const double chord = 2.0 * 30.0 * std::sin(5.0 * M_PI / 180.0);
  const double arc_end = 100.0 + 18.0 * chord;  // s of the arc → line junction
  const double length = arc_end + 100.0 + 60.0;
  Plan p = make_plan(c);
  EXPECT_NEAR(p.contour_length_mm, length, 1e-9);
  EXPECT_EQ(p.corner_count, 4U);  // two 90° corners + two marked tangent junctions
  EXPECT_EQ(p.marked_corner_count, 2U);
  const double expect_s[8] = {5.0,           95.0,         105.0,         arc_end - 5.0,
                              arc_end + 5.0, arc_end + 95, arc_end + 105, length - 5.0};
  const double expect_alpha[8] = {3.0, 3.0, 5.0, 5.0, 3.0, 3.0, 3.0, 3.0};
  ASSERT_EQ(p.checkpoints.size(), 8U);
  for (std::size_t i = 0; i < 8; ++i) {
    EXPECT_NEAR(p.checkpoints[i].s_mm, expect_s[i], 1e-9) << i;
    EXPECT_DOUBLE_EQ(p.checkpoints[i].alpha_deg, expect_alpha[i]) << i;
    EXPECT_DOUBLE_EQ(p.checkpoints[i].pass_length_mm, p.contour_length_mm);
    EXPECT_TRUE(p.checkpoints[i].closed);
  }
  EXPECT_DOUBLE_EQ(p.alpha_min_deg, 3.0);
  EXPECT_DOUBLE_EQ(p.alpha_max_deg, 5.0);
  // Each point's draft follows its own α: 2 mm below the contour, the arc's wall (5°) stands
  // 2·tan 5° = 0.17498 mm out, the line's (3°) 2·tan 3° = 0.10482 mm.
  EXPECT_NEAR(p.checkpoints[1].y_mm, -2.0 * std::tan(3.0 * M_PI / 180.0), 1e-9);
  const Checkpoint& on_arc = p.checkpoints[2];
  const double r_wall = std::hypot(on_arc.x_mm - 100.0, on_arc.y_mm - 30.0);
  // The chord lies inside the circle; the wall point is 2·tan 5° beyond the chord.
  const double chord_depth = 30.0 * std::cos(5.0 * M_PI / 180.0);
  EXPECT_GT(r_wall, chord_depth + 2.0 * std::tan(5.0 * M_PI / 180.0) - 0.05);
  EXPECT_LT(r_wall, 30.0 + 2.0 * std::tan(5.0 * M_PI / 180.0) + 1e-9);
  // Unmarked, the tangent junctions are no corners (5° < corner_angle_deg): 2 corners, 4 points.
  c.contour[1].corner = CornerMark::kAuto;
  c.contour[19].corner = CornerMark::kAuto;
  p = make_plan(c);
  EXPECT_EQ(p.corner_count, 2U);
  EXPECT_EQ(p.checkpoints.size(), 4U);
  // A vertex marked as no corner is none, whatever its turn: only the 90° corner at (0, 0) left.
  c.contour.back().corner = CornerMark::kNoCorner;
  p = make_plan(c);
  EXPECT_EQ(p.corner_count, 1U);
  EXPECT_EQ(p.checkpoints.size(), 2U);
}

TEST(Plan, ContourCsvCarriesAlphaAndSubCurveBoundaries) {
  // The rounded boss as the CSV an operator writes: α and corner only where they change.
  const PlanConfig inline_config = rounded_boss();
  std::string csv = "# rounded boss\nx_mm,y_mm,alpha_deg,corner\n";
  for (const ContourPoint& v : inline_config.contour) {
    char row[128];
    std::snprintf(row, sizeof row, "%.17g,%.17g,", v.x_mm, v.y_mm);
    csv += row;
    if (!std::isnan(v.alpha_deg)) csv += std::to_string(v.alpha_deg);
    csv += ",";
    if (v.corner == CornerMark::kCorner) csv += "1";
    csv += "\n";
  }
  PlanConfig c = inline_config;
  c.contour = parse_contour_csv(csv, "rounded.csv");
  ASSERT_EQ(c.contour.size(), inline_config.contour.size());
  EXPECT_TRUE(std::isnan(c.contour[0].alpha_deg));
  EXPECT_DOUBLE_EQ(c.contour[1].alpha_deg, 5.0);
  EXPECT_EQ(c.contour[1].corner, CornerMark::kCorner);
  EXPECT_EQ(c.contour[2].corner, CornerMark::kAuto);
  const Plan a = make_plan(inline_config);
  const Plan b = make_plan(c);
  ASSERT_EQ(a.checkpoints.size(), b.checkpoints.size());
  for (std::size_t i = 0; i < a.checkpoints.size(); ++i) {
    EXPECT_NEAR(a.checkpoints[i].s_mm, b.checkpoints[i].s_mm, 1e-9);
    EXPECT_DOUBLE_EQ(a.checkpoints[i].alpha_deg, b.checkpoints[i].alpha_deg);
  }
  // The columns in the other order, and 0 = never a corner.
  const auto pts = parse_contour_csv("x_mm,y_mm,corner,alpha_deg\n0,0,0,2.5\n10,0,,\n", "o.csv");
  EXPECT_EQ(pts[0].corner, CornerMark::kNoCorner);
  EXPECT_DOUBLE_EQ(pts[0].alpha_deg, 2.5);
  EXPECT_EQ(pts[1].corner, CornerMark::kAuto);
  EXPECT_TRUE(std::isnan(pts[1].alpha_deg));
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
  c = boss();
  c.contour[2].alpha_deg = 89.0;
  EXPECT_NE(error_of(c).find("checkpoints.contour[2].alpha_deg: must be a finite angle below 89"),
            std::string::npos)
      << error_of(c);
  c = boss();
  c.contour[1].alpha_deg = std::numeric_limits<double>::infinity();
  EXPECT_NE(error_of(c).find("checkpoints.contour[1].alpha_deg"), std::string::npos);
  c = boss();
  c.closed = false;
  c.material = MaterialSide::kLeft;
  c.contour[3].corner = CornerMark::kCorner;  // the open contour's end point
  EXPECT_NE(error_of(c).find("checkpoints.contour[3].corner: an end point"), std::string::npos);
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
  EXPECT_EQ(err("x_mm,y_mm\n1,2,3\n"),
            "wall.csv:2: expected 2 comma-separated columns as in the header, got 3: '1,2,3'");
  EXPECT_EQ(err("x_mm,y_mm\n1\n").rfind("wall.csv:2: expected 2 comma-separated", 0), 0U);
  EXPECT_EQ(
      err("x_mm,y_mm,alpha_deg\n1,2,3,4,5,6\n")
          .rfind("wall.csv:2: expected 3 comma-separated columns as in the header, got 5 or more",
                 0),
      0U);
  EXPECT_EQ(err("x_mm,y_mm,colour\n1,2,3\n").rfind("wall.csv:1: header column 3: 'colour'", 0), 0U);
  EXPECT_EQ(err("x_mm,y_mm,corner,corner\n").rfind("wall.csv:1: header column 4", 0), 0U);
  EXPECT_EQ(err("x_mm,y_mm,alpha_deg\n1,2,89\n"),
            "wall.csv:2: column alpha_deg: 89 is not below 89 degrees in magnitude");
  EXPECT_EQ(err("x_mm,y_mm,alpha_deg\n1,2,x\n"),
            "wall.csv:2: column alpha_deg: 'x' is not a number");
  EXPECT_EQ(
      err("x_mm,y_mm,corner\n1,2,yes\n").rfind("wall.csv:2: column corner: 'yes' must be 1", 0),
      0U);
  EXPECT_EQ(err("x_mm,y_mm\nnan,2\n").rfind("wall.csv:2: column x_mm is not finite", 0), 0U);
  EXPECT_EQ(err("x_mm,y_mm\n1e999,2\n").rfind("wall.csv:2: column x_mm", 0), 0U);
  EXPECT_EQ(err(",\n").rfind("wall.csv:1: header", 0), 0U);
  EXPECT_EQ(err("").rfind("wall.csv: empty", 0), 0U);
  EXPECT_EQ(err("x_mm,y_mm\n# nothing\n").rfind("wall.csv: contour file has a header but no", 0),
            0U);
}

}  // namespace
}  // namespace nccomp::core::checkpoint
