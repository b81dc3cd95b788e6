#include "formats/checkpoints/checkpoints_toml.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "tools/plan/plan_output.hpp"

namespace nccomp::tools::checkpoints {
namespace {

namespace cp = core::checkpoint;
using formats::checkpoints::CheckpointsConfig;
using formats::checkpoints::load_checkpoints_file;
using formats::checkpoints::make_checkpoint_module;
using formats::checkpoints::parse_checkpoints;
using Issue = formats::Diagnostic;

const std::string kData = NCCOMP_CHECKPOINT_DATA;

std::vector<Issue> issues_of(const std::string& text) {
  formats::Diagnostics diag;
  const toml::table root = toml::parse(std::string_view(text), std::string_view("test.toml"));
  (void)parse_checkpoints(*root["checkpoints"].as_table(), "test.toml", kData, diag);
  return diag.items();
}

TEST(CheckpointsToml, ExampleConfigMapsEveryKey) {
  const CheckpointsConfig c = load_checkpoints_file(kData + "/boss.toml", std::nullopt);
  EXPECT_EQ(c.plan.contour.size(), 5U);
  EXPECT_TRUE(c.plan.closed);
  EXPECT_EQ(c.plan.material, cp::MaterialSide::kInside);
  EXPECT_DOUBLE_EQ(c.plan.z_start_mm, -3.0);
  EXPECT_DOUBLE_EQ(c.plan.z_end_mm, -33.0);
  EXPECT_DOUBLE_EQ(c.plan.depth_step_mm, 10.0);
  EXPECT_DOUBLE_EQ(c.plan.wall_angle_deg, 3.0);
  EXPECT_DOUBLE_EQ(c.plan.corner_offset_mm, 8.0);
  ASSERT_EQ(c.plan.extra_points_mm.size(), 1U);
  ASSERT_EQ(c.plan.extra_regions.size(), 1U);
  EXPECT_DOUBLE_EQ(c.plan.extra_regions[0].spacing_mm, 10.0);
  EXPECT_DOUBLE_EQ(c.plan.tool_radius_mm, 8.0);
  EXPECT_DOUBLE_EQ(c.plan.ball_radius_mm, 2.0);
  EXPECT_EQ(c.compensator.learning_mode, cp::LearningMode::kPreviousPart);
  EXPECT_EQ(c.compensator.finishing_tool, 12);
  EXPECT_EQ(c.compensator.semi_finishing_tool, 11);
  EXPECT_EQ(c.compensator.register_base, 20);
  EXPECT_EQ(c.compensator.active_register, 19);
  EXPECT_EQ(c.compensator.apply, cp::ApplyMode::kCreep);
  EXPECT_EQ(c.compensator.trigger, cp::TriggerMode::kPath);
  EXPECT_DOUBLE_EQ(c.compensator.ewma_weight, 3.0);
  EXPECT_DOUBLE_EQ(c.compensator.plausible_um, 150.0);
  EXPECT_EQ(c.compensator.outlier_min_history, 4U);
  EXPECT_EQ(c.compensator.reconcile_prefer, cp::ReconcilePrefer::kDaemon);
  EXPECT_EQ(c.gcode.macro_program, 9860);
  EXPECT_EQ(c.gcode.nc_variable_first, 12020);
  EXPECT_DOUBLE_EQ(c.gcode.safe_z_mm, 30.0);

  const cp::Plan plan = cp::make_plan(c.plan);
  // 5 corners × 2 + 1 extra point + 3 region points = 14 per level, 4 levels.
  EXPECT_EQ(plan.checkpoints.size(), 56U);
  std::ostringstream csv;
  write_plan_csv(csv, plan, c);
  std::istringstream lines(csv.str());
  std::string header;
  std::string first;
  std::getline(lines, header);
  std::getline(lines, first);
  EXPECT_EQ(first.rfind("0,0,corner,20,8.000,8.000,8.0000,-0.1572,-3.0000,0.000000,1.000000,3.000,"
                        "2.745,",
                        0),
            0U)
      << first;
  std::ostringstream gcode;
  write_probing_gcode(gcode, plan, c);
  EXPECT_NE(gcode.str().find("N1 G00 X8.000 Y-7.157\nG01 Z-3.000 F2000.\n"
                             "G65 P9860 I0.0000 J1.0000 D5.000 A3.000 R2.000 E0. (#12020)\n"),
            std::string::npos)
      << gcode.str().substr(0, 400);
  EXPECT_NE(gcode.str().find("E55. (#12075)"), std::string::npos);
}

TEST(CheckpointsToml, EveryProblemIsReportedWithLineAndKey) {
  const auto issues = issues_of(
      "[checkpoints]\n"
      "contour = [[0,0],[100,0],[100,\"a\"],[0,60]]\n"
      "depth_step_mm = -1\n"
      "material = \"inner\"\n"
      "colour = \"red\"\n"
      "apply = 3\n");
  ASSERT_EQ(issues.size(), 5U);
  const auto find = [&](const std::string& key) {
    for (const auto& i : issues) {
      if (i.where.key_path == key) return i;
    }
    return Issue{};
  };
  EXPECT_EQ(find("checkpoints.contour[2]").where.line, 2);
  EXPECT_EQ(find("checkpoints.depth_step_mm").where.line, 3);
  EXPECT_NE(find("checkpoints.material").message.find("\"inside\""), std::string::npos);
  EXPECT_EQ(find("checkpoints.colour").message, "unknown key");
  EXPECT_EQ(find("checkpoints.apply").message, "must be a string");
  EXPECT_EQ(formats::format(find("checkpoints.colour")),
            "test.toml:5:10: checkpoints.colour: unknown key");
}

TEST(CheckpointsToml, SemanticErrorsFromTheCoreCarryTheKeysLine) {
  auto issues = issues_of(
      "[checkpoints]\n"
      "contour = [[0,0],[100,0],[100,60],[0,60]]\n"
      "z_end_mm = 10\n");
  ASSERT_EQ(issues.size(), 1U);
  EXPECT_EQ(issues[0].where.key_path, "checkpoints.z_end_mm");
  EXPECT_EQ(issues[0].where.line, 3);
  issues = issues_of(
      "[checkpoints]\ncontour = [[0,0],[100,0],[100,60],[0,60]]\n"
      "register_base = 20\nactive_register = 22\n");
  ASSERT_EQ(issues.size(), 1U);
  EXPECT_EQ(issues[0].where.key_path, "checkpoints.active_register");
  EXPECT_EQ(issues[0].where.line, 4);
  issues = issues_of("[checkpoints]\nz_end_mm = -5\n");
  ASSERT_EQ(issues.size(), 1U);
  EXPECT_NE(issues[0].message.find("exactly one of contour"), std::string::npos);
  issues = issues_of("[checkpoints]\ncontour_csv = \"missing.csv\"\n");
  ASSERT_EQ(issues.size(), 1U);
  EXPECT_NE(issues[0].message.find("missing.csv: cannot open"), std::string::npos);
}

TEST(CheckpointsToml, ApplyFollowsTheLiveRegisterAndAContradictionNamesItsLine) {
  const std::string contour = "[checkpoints]\ncontour = [[0,0],[100,0],[100,60],[0,60]]\n";
  std::vector<Issue> issues;
  // Table only by default; with a live register the default is creep.
  auto parse = [&](const std::string& text) {
    formats::Diagnostics diag;
    const toml::table root = toml::parse(std::string_view(text), std::string_view("test.toml"));
    auto c = parse_checkpoints(*root["checkpoints"].as_table(), "test.toml", kData, diag);
    issues = diag.items();
    return c;
  };
  EXPECT_EQ(parse(contour).compensator.apply, cp::ApplyMode::kTable);
  EXPECT_TRUE(issues.empty());
  EXPECT_EQ(parse(contour + "active_register = 19\n").compensator.apply, cp::ApplyMode::kCreep);
  EXPECT_EQ(parse(contour + "active_register = 19\napply = \"step\"\n").compensator.apply,
            cp::ApplyMode::kStep);
  EXPECT_TRUE(issues.empty());
  // The trap: creep asked for, no live register.
  (void)parse(contour + "ewma_weight = 2\napply = \"creep\"\n");
  ASSERT_EQ(issues.size(), 1U);
  EXPECT_EQ(formats::format(issues[0]).rfind(
                "test.toml:4:9: checkpoints.apply: \"creep\" drives the live radius wear "
                "register, but active_register = -1",
                0),
            0U)
      << formats::format(issues[0]);
  (void)parse(contour + "apply = \"table\"\nactive_register = 19\n");
  ASSERT_EQ(issues.size(), 1U);
  EXPECT_EQ(issues[0].where.key_path, "checkpoints.apply");
  EXPECT_EQ(issues[0].where.line, 3);
}

TEST(CheckpointsToml, ModeBRefusesAnAveragingWeight) {
  const auto issues = issues_of(
      "[checkpoints]\ncontour = [[0,0],[100,0],[100,60],[0,60]]\n"
      "learning_mode = \"semi_finishing\"\newma_weight = 3\n");
  ASSERT_EQ(issues.size(), 1U);
  EXPECT_EQ(issues[0].where.key_path, "checkpoints.ewma_weight");
  EXPECT_EQ(issues[0].where.line, 4);
  EXPECT_NE(issues[0].message.find("mode B applies each blank's own"), std::string::npos);
  EXPECT_TRUE(issues_of("[checkpoints]\ncontour = [[0,0],[100,0],[100,60],[0,60]]\n"
                        "learning_mode = \"semi_finishing\"\n")
                  .empty());
}

TEST(CheckpointsToml, InlineContourVerticesCarryAlphaAndCornerMarks) {
  const std::string text =
      "[checkpoints]\n"
      "contour = [[0,0], { x_mm = 100, y_mm = 0, alpha_deg = 5, corner = true },\n"
      "           [130, 30], { x_mm = 100, y_mm = 60, alpha_deg = 3, corner = true },\n"
      "           { x_mm = 0, y_mm = 60, corner = false }]\n"
      "wall_angle_deg = 3\nz_start_mm = -2\nz_end_mm = -2\n";
  formats::Diagnostics diag;
  const toml::table root = toml::parse(std::string_view(text), std::string_view("test.toml"));
  const CheckpointsConfig c =
      parse_checkpoints(*root["checkpoints"].as_table(), "test.toml", kData, diag);
  ASSERT_TRUE(diag.ok()) << diag.to_string();
  ASSERT_EQ(c.plan.contour.size(), 5U);
  EXPECT_TRUE(std::isnan(c.plan.contour[0].alpha_deg));
  EXPECT_DOUBLE_EQ(c.plan.contour[1].alpha_deg, 5.0);
  EXPECT_EQ(c.plan.contour[1].corner, cp::CornerMark::kCorner);
  EXPECT_EQ(c.plan.contour[2].corner, cp::CornerMark::kAuto);
  EXPECT_EQ(c.plan.contour[4].corner, cp::CornerMark::kNoCorner);
  const cp::Plan plan = cp::make_plan(c.plan);
  // Corners: (0,0) by its 90° turn, (100,0) and (100,60) marked (45° turns, above 20° anyway),
  // (130,30) by its 90° turn; (0,60) marked as none.
  EXPECT_EQ(plan.corner_count, 4U);
  EXPECT_EQ(plan.marked_corner_count, 2U);
  EXPECT_DOUBLE_EQ(plan.alpha_min_deg, 3.0);
  EXPECT_DOUBLE_EQ(plan.alpha_max_deg, 5.0);
  // The summary, the CSV and the G-code carry each point's α.
  std::ostringstream summary;
  write_plan_summary(summary, plan, c);
  EXPECT_NE(summary.str().find("4 corners (2 marked as sub-curve boundaries)"), std::string::npos)
      << summary.str();
  EXPECT_NE(summary.str().find("wall angle 3.000 .. 5.000 deg (per point: column alpha_deg), "
                               "delta0 = r/cos(a) - r = 1.372 .. 3.820 um"),
            std::string::npos)
      << summary.str();
  std::ostringstream gcode;
  write_probing_gcode(gcode, plan, c);
  EXPECT_NE(gcode.str().find(" A5.000 R1.000 E2."), std::string::npos) << gcode.str();
  EXPECT_NE(gcode.str().find(" A3.000 R1.000 E1."), std::string::npos);
  std::ostringstream csv;
  write_plan_csv(csv, plan, c);
  EXPECT_NE(csv.str().find(",5.000,3.820,"), std::string::npos) << csv.str();
  // Bad vertices name their key and line.
  const auto bad = issues_of(
      "[checkpoints]\ncontour = [[0,0],\n { x_mm = 100 },\n"
      " { x_mm = 100, y_mm = 60, alpha_deg = 95 },\n { x_mm = 0, y_mm = 60, corner = 1 },\n"
      " { x_mm = 0, y_mm = 30, colour = 2 }, \"x\"]\n");
  ASSERT_EQ(bad.size(), 5U);
  EXPECT_EQ(formats::format(bad[0]), "test.toml:3:2: checkpoints.contour[1]: needs x_mm and y_mm");
  EXPECT_EQ(bad[1].where.key_path, "checkpoints.contour[2].alpha_deg");
  EXPECT_EQ(bad[1].where.line, 4);
  EXPECT_EQ(bad[2].where.key_path, "checkpoints.contour[3].corner");
  EXPECT_EQ(bad[2].message, "must be true or false");
  EXPECT_EQ(bad[3].where.key_path, "checkpoints.contour[4].colour");
  EXPECT_EQ(bad[4].where.key_path, "checkpoints.contour[5]");
  EXPECT_NE(bad[4].message.find("or a table"), std::string::npos);
}

TEST(CheckpointsToml, ModuleFromTheExampleAttachesToItsRegisters) {
  const CheckpointsConfig c = load_checkpoints_file(kData + "/boss.toml", std::nullopt);
  auto module = make_checkpoint_module(c);
  ASSERT_NE(module, nullptr);
  EXPECT_EQ(module->name(), "checkpoints");
  // register_base 20 … 75 of kind checkpoint, active_register 19 of kind tool_radius_wear.
  std::vector<core::engine::RegisterSpec> regs(76);
  for (std::size_t i = 0; i < regs.size(); ++i) {
    regs[i].name = std::to_string(i);
    regs[i].name.insert(0, "register_");
    regs[i].kind = i >= 20 ? core::engine::RegisterKind::kCheckpoint
                           : core::engine::RegisterKind::kToolLengthWear;
  }
  EXPECT_THROW(module->attach(core::engine::RegisterTable(regs)), std::invalid_argument);
  regs[19].kind = core::engine::RegisterKind::kToolRadiusWear;
  module->attach(core::engine::RegisterTable(regs));
  EXPECT_EQ(module->compensator().size(), 56U);
  EXPECT_GT(module->state_capacity(), 56U * 100U);
}

TEST(CheckpointsToml, ContourOverrideReplacesTheFilesContour) {
  const CheckpointsConfig c =
      load_checkpoints_file(kData + "/boss.toml", kData + "/boss_contour.csv");
  EXPECT_EQ(c.plan.contour.size(), 5U);
  EXPECT_THROW((void)load_checkpoints_file(kData + "/boss.toml", kData + "/nope.csv"),
               formats::DiagnosticsError);
}

}  // namespace
}  // namespace nccomp::tools::checkpoints

namespace nccomp::tools::checkpoints {
namespace {

// The example of docs/estimation.md ("S1"), key for key, and the errors with their positions.
TEST(CheckpointsToml, EstimatorKeysFromTheDocsExampleAndTheirErrors) {
  const std::string contour = "[checkpoints]\ncontour = [[0,0],[100,0],[100,60],[0,60]]\n";
  formats::Diagnostics diag;
  const std::string text = contour +
                           "[checkpoints.estimator]\n"
                           "enabled = true\n"
                           "measurement_sigma_um = 0.7\n"
                           "part_noise_um = 1.0\n"
                           "learn_part_noise = true\n"
                           "learn_min_parts = 5\n"
                           "gate_sigmas = 5\n";
  const toml::table root = toml::parse(std::string_view(text), std::string_view("test.toml"));
  const CheckpointsConfig c =
      parse_checkpoints(*root["checkpoints"].as_table(), "test.toml", kData, diag);
  EXPECT_TRUE(diag.items().empty());
  const cp::CheckpointEstimatorConfig& e = c.compensator.estimator;
  EXPECT_TRUE(e.enabled);
  EXPECT_DOUBLE_EQ(e.measurement_sigma_um, 0.7);
  EXPECT_DOUBLE_EQ(e.part_noise_um, 1.0);
  EXPECT_TRUE(e.learn_part_noise);
  EXPECT_EQ(e.learn_min_parts, 5U);
  EXPECT_DOUBLE_EQ(e.gate_sigmas, 5.0);
  // Off by default, today's EWMA.
  EXPECT_FALSE(cp::CompensatorConfig{}.estimator.enabled);

  auto issues = issues_of(contour + "[checkpoints.estimator]\nenabled = true\ngate_sigmas = 1\n");
  ASSERT_EQ(issues.size(), 1U);
  EXPECT_EQ(formats::format(issues[0]),
            "test.toml:5:15: checkpoints.estimator.gate_sigmas: must be 0 (no gate) or at least "
            "2, got 1");
  issues = issues_of(contour + "[checkpoints.estimator]\nlearn_min_parts = 2\nsigma = 1\n");
  ASSERT_EQ(issues.size(), 2U);
  EXPECT_EQ(issues[0].where.key_path, "checkpoints.estimator.learn_min_parts");
  EXPECT_EQ(issues[0].where.line, 4);
  EXPECT_EQ(formats::format(issues[1]), "test.toml:5:9: checkpoints.estimator.sigma: unknown key");
  issues = issues_of(contour +
                     "learning_mode = \"semi_finishing\"\n[checkpoints.estimator]\n"
                     "enabled = true\n");
  ASSERT_EQ(issues.size(), 1U);
  EXPECT_EQ(issues[0].where.key_path, "checkpoints.estimator.enabled");
  EXPECT_EQ(issues[0].where.line, 5);
}

}  // namespace
}  // namespace nccomp::tools::checkpoints

namespace nccomp::tools::checkpoints {
namespace {

// The shipped S1 example (ncsim's side wall) carries the estimator's table, off: it loads, and
// every key has the documented default.
TEST(CheckpointsToml, TheShippedSideWallExampleHasTheEstimatorOffWithItsDefaults) {
  const CheckpointsConfig c = load_checkpoints_file(
      kData + "/../../../../sim/ncsim/config/side_wall_checkpoints.toml", std::nullopt);
  const cp::CheckpointEstimatorConfig& e = c.compensator.estimator;
  const cp::CheckpointEstimatorConfig defaults{};
  EXPECT_FALSE(e.enabled);
  EXPECT_DOUBLE_EQ(e.measurement_sigma_um, defaults.measurement_sigma_um);
  EXPECT_DOUBLE_EQ(e.part_noise_um, defaults.part_noise_um);
  EXPECT_EQ(e.learn_part_noise, defaults.learn_part_noise);
  EXPECT_EQ(e.learn_min_parts, defaults.learn_min_parts);
  EXPECT_DOUBLE_EQ(e.gate_sigmas, defaults.gate_sigmas);
}

}  // namespace
}  // namespace nccomp::tools::checkpoints
