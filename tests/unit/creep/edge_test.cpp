// Items 3 and 6 of issue 3: edge-wear profile at the current engagement angle along the surface
// normal (axes or tool registers, or the mean on one axis), per-support-point creep, and the
// wear-dependent deflection table.
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>

#include "tests/unit/creep/rig.hpp"

namespace nccomp::core::creep {
namespace {

using testing::base_config;
using testing::Rig;

const double kS45 = std::sqrt(0.5);

CreepConfig ball_config() {
  auto c = base_config();
  c.edge.tool_shape = ToolShape::kBall;
  c.edge.edge_points = 4;  // 0°, 30°, 60°, 90°
  c.edge.normal_source = NormalSource::kAxisSample;
  c.creep_length_mm = 10.0;
  return c;
}

TEST(CreepEdge, WearAtTheEngagementAngleAlongTheNormalSplitIntoAxes) {
  Rig r(ball_config());
  r.has_normal = true;
  r.normal = {kS45, 0.0, kS45};  // 45° wall in XZ
  r.measure({4.0, 8.0, 12.0, 16.0});
  r.run_to(20.0);
  EXPECT_NEAR(r.comp.engagement_angle_deg(), 45.0, 1e-9);
  EXPECT_NEAR(r.comp.correction_um(), 10.0, 1e-9);  // halfway between 8 (30°) and 12 (60°)
  EXPECT_NEAR(r.x(), -10.0 * kS45, 1e-9);
  EXPECT_NEAR(r.comp.channel_output_um(Channel::kY), 0.0, 1e-12);
  EXPECT_NEAR(r.z(), -10.0 * kS45, 1e-9);
  // Flat floor: the tip's wear, on Z only.
  r.normal = {0.0, 0.0, 1.0};
  r.advance(0.5);
  EXPECT_NEAR(r.z(), -4.0, 1e-9);
  EXPECT_NEAR(r.x(), 0.0, 1e-12);
  // Vertical wall facing −Y: the side wear, on +Y toward the wall.
  r.normal = {0.0, -1.0, 0.0};
  r.advance(0.5);
  EXPECT_NEAR(r.comp.channel_output_um(Channel::kY), 16.0, 1e-9);
  EXPECT_NEAR(r.z(), 0.0, 1e-9);
}

TEST(CreepEdge, ToolRegistersTakeRadiusAndLengthComponents) {
  auto c = ball_config();
  c.output.mode = OutputMode::kToolRegisters;
  c.output.channel_register = {-1, -1, -1, 3, 4};
  c.edge.fallback_channel = Channel::kLength;
  Rig r(c);
  r.has_normal = true;
  r.normal = {0.5, 0.0, std::sqrt(0.75)};  // 30°
  r.measure({4.0, 8.0, 12.0, 16.0});
  r.run_to(20.0);
  EXPECT_NEAR(r.comp.correction_um(), 8.0, 1e-9);
  EXPECT_NEAR(r.comp.channel_output_um(Channel::kRadius), -8.0 * 0.5, 1e-9);
  EXPECT_NEAR(r.comp.channel_output_um(Channel::kLength), -8.0 * std::sqrt(0.75), 1e-9);
  EXPECT_NEAR(r.last_write(3), -4.0, 1e-9);
}

TEST(CreepEdge, WithoutANormalTheMeanWearGoesOnTheFallbackAxis) {
  Rig r(ball_config());
  r.has_normal = false;
  r.measure({4.0, 8.0, 12.0, 16.0});
  r.run_to(20.0);
  EXPECT_TRUE(std::isnan(r.comp.engagement_angle_deg()));
  EXPECT_NEAR(r.z(), -10.0, 1e-9);
  EXPECT_NEAR(r.x(), 0.0, 1e-12);
}

TEST(CreepEdge, NormalFromAToolpathTableByProgramPosition) {
  auto c = ball_config();
  c.edge.normal_source = NormalSource::kToolpath;
  c.toolpath_normals = {{0.0, {0.0, 0.0, 1.0}}, {100.0, {1.0, 0.0, 0.0}}};
  Rig r(c);
  r.measure({4.0, 8.0, 12.0, 16.0});
  r.run_to(50.0);  // interpolated normal (0.5, 0, 0.5) → 45°
  EXPECT_NEAR(r.comp.engagement_angle_deg(), 45.0, 1e-9);
  EXPECT_NEAR(r.x(), -10.0 * kS45, 1e-9);
  r.run_to(150.0);  // beyond the table: its last normal, 90°
  EXPECT_NEAR(r.x(), -16.0, 1e-9);
}

TEST(CreepEdge, ANewProfileCreepsInPerSupportPoint) {
  Rig r(ball_config());
  r.measure({4.0, 8.0, 12.0, 16.0});
  r.run_to(20.0);
  r.measure({6.0, 8.0, 12.0, 26.0});
  r.run_to(25.0);  // half of the 10 mm creep
  EXPECT_NEAR(r.comp.applied_wear_um(0), 5.0, 1e-9);
  EXPECT_NEAR(r.comp.applied_wear_um(1), 8.0, 1e-9);
  EXPECT_NEAR(r.comp.applied_wear_um(2), 12.0, 1e-9);
  EXPECT_NEAR(r.comp.applied_wear_um(3), 21.0, 1e-9);
}

TEST(CreepEdge, AtARateEachSupportPointCreepsOverItsOwnLength) {
  auto c = ball_config();
  c.creep_basis = CreepBasis::kRatePath;
  c.creep_rate_um_per_mm = 1.0;
  Rig r(c);
  r.measure({4.0, 8.0, 12.0, 16.0});
  r.run_to(6.0);
  EXPECT_NEAR(r.comp.applied_wear_um(0), 4.0, 1e-9);  // done after 4 mm
  EXPECT_NEAR(r.comp.applied_wear_um(1), 6.0, 1e-9);  // same slope 1 µm/mm everywhere
  EXPECT_NEAR(r.comp.applied_wear_um(3), 6.0, 1e-9);
  r.run_to(16.0);
  EXPECT_NEAR(r.comp.applied_wear_um(3), 16.0, 1e-9);
  EXPECT_EQ(r.comp.creeps_in_progress(), 0U);
}

TEST(CreepEdge, ASinglePointMeasurementAppliesAlongTheWholeEdge) {
  Rig r(ball_config());
  r.measure({7.0});
  r.run_to(20.0);
  for (std::size_t i = 0; i < 4; ++i) EXPECT_NEAR(r.comp.applied_wear_um(i), 7.0, 1e-9);
}

TEST(CreepEdge, AMeasurementWithTheWrongPointCountIsRefused) {
  Rig r(ball_config());
  r.measure({1.0, 2.0});
  EXPECT_EQ(r.count(AlarmCode::kEventInvalid), 1U);
  EXPECT_EQ(r.comp.counters().measurements_accepted, 0U);
}

// ---- item 6 ------------------------------------------------------------------------------

TEST(CreepDeflection, OverCompensationGrowsWithWearInNormalAndLateralDirections) {
  auto c = ball_config();
  c.deflection = {{0, {0.0, 20.0}, {0.0, 4.0}, {0.0, 10.0}}};
  Rig r(c);
  r.has_normal = true;
  r.normal = {kS45, 0.0, kS45};
  r.measure({4.0, 8.0, 12.0, 16.0});
  r.run_to(20.0);
  // Wear 10 at 45°: normal 10 + 2, lateral 5 across the tool axis (+X here).
  EXPECT_NEAR(r.comp.correction_um(), 12.0, 1e-9);
  EXPECT_NEAR(r.comp.lateral_um(), 5.0, 1e-9);
  EXPECT_NEAR(r.x(), -12.0 * kS45 - 5.0, 1e-9);
  EXPECT_NEAR(r.z(), -12.0 * kS45, 1e-9);
  // Beyond the table's last row: held at its end value.
  r.measure({30.0, 30.0, 30.0, 30.0});
  r.run_to(40.0);
  EXPECT_NEAR(r.comp.correction_um(), 34.0, 1e-9);
  EXPECT_NEAR(r.comp.lateral_um(), 10.0, 1e-9);
}

TEST(CreepDeflection, APerToolTableWinsOverTheDefault) {
  auto c = base_config();
  c.deflection = {{0, {0.0, 10.0}, {0.0, 1.0}, {0.0, 0.0}},
                  {5, {0.0, 10.0}, {0.0, 3.0}, {0.0, 0.0}}};
  Rig r(c);
  r.measure({10.0});
  r.run_to(60.0);
  EXPECT_NEAR(r.z(), -11.0, 1e-9);
  r.tool_change(5, false);
  r.measure({10.0});
  r.run_to(120.0);
  EXPECT_NEAR(r.z(), -13.0, 1e-9);
}

}  // namespace
}  // namespace nccomp::core::creep
