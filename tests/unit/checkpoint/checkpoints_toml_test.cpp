#include "tools/plan/checkpoints_toml.hpp"

#include <gtest/gtest.h>

#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "tools/plan/plan_output.hpp"

namespace nccomp::tools::checkpoints {
namespace {

namespace cp = core::checkpoint;

const std::string kData = NCCOMP_CHECKPOINT_DATA;

std::vector<ConfigIssue> issues_of(const std::string& text) {
  std::vector<ConfigIssue> issues;
  const toml::table root = toml::parse(std::string_view(text), std::string_view("test.toml"));
  (void)parse_checkpoints(*root["checkpoints"].as_table(), "test.toml", kData, issues);
  return issues;
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
      if (i.key_path == key) return i;
    }
    return ConfigIssue{};
  };
  EXPECT_EQ(find("checkpoints.contour[2]").line, 2);
  EXPECT_EQ(find("checkpoints.depth_step_mm").line, 3);
  EXPECT_NE(find("checkpoints.material").message.find("\"inside\""), std::string::npos);
  EXPECT_EQ(find("checkpoints.colour").message, "unknown key");
  EXPECT_EQ(find("checkpoints.apply").message, "must be a string");
  EXPECT_EQ(format_issue(find("checkpoints.colour")),
            "test.toml:5:10: checkpoints.colour: unknown key");
}

TEST(CheckpointsToml, SemanticErrorsFromTheCoreCarryTheKeysLine) {
  auto issues = issues_of(
      "[checkpoints]\n"
      "contour = [[0,0],[100,0],[100,60],[0,60]]\n"
      "z_end_mm = 10\n");
  ASSERT_EQ(issues.size(), 1U);
  EXPECT_EQ(issues[0].key_path, "checkpoints.z_end_mm");
  EXPECT_EQ(issues[0].line, 3);
  issues = issues_of(
      "[checkpoints]\ncontour = [[0,0],[100,0],[100,60],[0,60]]\n"
      "register_base = 20\nactive_register = 22\n");
  ASSERT_EQ(issues.size(), 1U);
  EXPECT_EQ(issues[0].key_path, "checkpoints.active_register");
  EXPECT_EQ(issues[0].line, 4);
  issues = issues_of("[checkpoints]\nz_end_mm = -5\n");
  ASSERT_EQ(issues.size(), 1U);
  EXPECT_NE(issues[0].message.find("exactly one of contour"), std::string::npos);
  issues = issues_of("[checkpoints]\ncontour_csv = \"missing.csv\"\n");
  ASSERT_EQ(issues.size(), 1U);
  EXPECT_NE(issues[0].message.find("missing.csv: cannot open"), std::string::npos);
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
  EXPECT_THROW((void)load_checkpoints_file(kData + "/boss.toml", kData + "/nope.csv"), ConfigError);
}

}  // namespace
}  // namespace nccomp::tools::checkpoints
