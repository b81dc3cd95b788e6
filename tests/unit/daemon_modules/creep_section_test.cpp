// GIVEN a daemon config with a [creep] section, WHEN the loader reads it, THEN every documented
// key lands in CreepConfig, every bad key is reported with file:line:column and key path, and
// the engine built from it creeps (or steps, or predicts) the offsets by the numbers.
#include "daemon/sections/creep/creep_section.hpp"

#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <functional>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "core/creep/creep_module.hpp"
#include "daemon/config/builtin_sections.hpp"
#include "daemon/logging.hpp"
#include "daemon/loop.hpp"
#include "daemon/status.hpp"
#include "drivers/loopback/loopback_bus.hpp"
#include "tests/unit/daemon_modules/temp_dir.hpp"

namespace nccomp::daemon::sections {
namespace {

using config::load_file;
using testing::TempDir;

const char* kRegisters = R"(
[loopback]

[[registers]]
name = "X_wear_offset"
kind = "axis_offset"
bus = "loopback"
max_abs_um = 100
max_step_um = 50
max_rate_um_per_s = 100000

[[registers]]
name = "Y_wear_offset"
kind = "axis_offset"
bus = "loopback"
max_abs_um = 100
max_step_um = 50
max_rate_um_per_s = 100000

[[registers]]
name = "Z_wear_offset"
kind = "axis_offset"
bus = "loopback"
max_abs_um = 100
max_step_um = 50
max_rate_um_per_s = 100000

[[registers]]
name = "T1_length_wear"
kind = "tool_length_wear"
bus = "loopback"
max_abs_um = 100
max_step_um = 50
max_rate_um_per_s = 100000
)";

const char* kFlagRegisters = R"(
[[registers]]
name = "creep_warning"
kind = "flag"
bus = "loopback"

[[registers]]
name = "creep_alarm"
kind = "flag"
bus = "loopback"

[[registers]]
name = "measure_request"
kind = "flag"
bus = "loopback"

[[registers]]
name = "sister_request"
kind = "flag"
bus = "loopback"
max_abs_um = 1
)";

std::string read(const std::string& path) {
  std::ifstream in(path);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

/// The ```toml block after "### Example" in docs/creep.md: the documentation must stay loadable.
std::string doc_example() {
  const std::string md = read(std::string(NCCOMP_SOURCE_DIR) + "/docs/creep.md");
  const auto h = md.find("### Example");
  const auto b = md.find("```toml\n", h);
  const auto e = md.find("```", b + 8);
  if (h == std::string::npos || b == std::string::npos || e == std::string::npos) return {};
  return md.substr(b + 8, e - b - 8);
}

/// "file:line:column: " of the value of the first line of text that contains needle.
std::string at(const std::string& file, const std::string& text, const std::string& needle) {
  const auto pos = text.find(needle);
  if (pos == std::string::npos) return "<" + needle + " not in the text>";
  int line = 1;
  std::size_t bol = 0;
  for (std::size_t i = 0; i < pos; ++i) {
    if (text[i] == '\n') {
      ++line;
      bol = i + 1;
    }
  }
  const auto eq = text.find("= ", pos);
  const auto col = static_cast<int>(eq + 2 - bol + 1);
  return file + ":" + std::to_string(line) + ":" + std::to_string(col) + ": ";
}

std::string errors_of(const std::string& path) {
  auto r = load_file(path);
  return r.config ? std::string() : r.diagnostics.to_string();
}

TEST(CreepSection, ParsesTheDocumentedExampleKeyForKey) {
  const std::string ex = doc_example();
  ASSERT_FALSE(ex.empty());
  TempDir d;
  const auto f = d.write("a.toml", std::string(kRegisters) + kFlagRegisters + ex);
  auto r = load_file(f);
  ASSERT_TRUE(r.config) << r.diagnostics.to_string();
  const auto* s = creep_section(*r.config);
  ASSERT_NE(s, nullptr);
  EXPECT_TRUE(s->enabled);
  const auto& c = s->module.creep;
  EXPECT_EQ(c.creep_basis, core::creep::CreepBasis::kPath);
  EXPECT_DOUBLE_EQ(c.creep_length_mm, 300.0);
  EXPECT_EQ(c.profile, core::ProfileShape::kCosine);
  EXPECT_EQ(c.on_unfinished, core::creep::UnfinishedPolicy::kSuperpose);
  EXPECT_EQ(c.max_creeps, 4U);
  EXPECT_EQ(c.edge.tool_shape, core::creep::ToolShape::kBall);
  EXPECT_EQ(c.edge.edge_points, 7U);
  EXPECT_EQ(c.edge.normal_source, core::creep::NormalSource::kAxisSample);
  EXPECT_EQ(c.edge.fallback_channel, core::creep::Channel::kZ);
  EXPECT_EQ(c.output.mode, core::creep::OutputMode::kAxes);
  EXPECT_EQ(s->module.registers.channel[0], "X_wear_offset");
  EXPECT_EQ(s->module.registers.channel[2], "Z_wear_offset");
  EXPECT_EQ(s->module.registers.measurement_due, "measure_request");
  EXPECT_EQ(s->module.registers.tool_change, "sister_request");
  EXPECT_EQ(c.interval.basis, core::creep::IntervalBasis::kAdaptive);
  EXPECT_DOUBLE_EQ(c.interval.target_increment_um, 3.0);
  EXPECT_DOUBLE_EQ(c.interval.min_interval_mm, 200.0);
  EXPECT_DOUBLE_EQ(c.interval.max_interval_mm, 3000.0);
  EXPECT_DOUBLE_EQ(c.tool_life.wear_limit_um, 40.0);
  EXPECT_DOUBLE_EQ(c.tool_life.excessive_increment_um, 15.0);
  EXPECT_EQ(c.tool_life.on_excessive, core::creep::ExcessivePolicy::kSister);
  EXPECT_DOUBLE_EQ(c.tool_life.noise_um, 2.0);
  EXPECT_TRUE(c.predict.enabled);
  EXPECT_EQ(c.predict.window, 5U);
  EXPECT_DOUBLE_EQ(c.entry.sister_offset_um, 5.0);
  EXPECT_DOUBLE_EQ(c.entry.sister_length_mm, 20.0);
  EXPECT_DOUBLE_EQ(c.entry.sister_restart_back_mm, 30.0);
  ASSERT_EQ(c.deflection.size(), 1U);
  EXPECT_EQ(c.deflection[0].tool, 0);
  ASSERT_EQ(c.deflection[0].wear_um.size(), 3U);
  EXPECT_DOUBLE_EQ(c.deflection[0].normal_um[2], 4.0);
  EXPECT_DOUBLE_EQ(c.deflection[0].lateral_um[1], 1.0);
  // Defaults where the example is silent.
  EXPECT_DOUBLE_EQ(c.output.write_resolution_um, 0.1);
  EXPECT_DOUBLE_EQ(c.tool_life.implausible_factor, 5.0);

  auto engine = config::build_engine(*r.config);
  ASSERT_EQ(engine->module_count(), 1U);
  EXPECT_EQ(engine->module(0).name(), "creep");
}

TEST(CreepSection, ReadsEveryOtherKey) {
  TempDir d;
  d.write("paths/normals.csv", "path_mm,nx,ny,nz,removal_mm2\n0,0,0,1,0.75\n100,1,0,0,0\n");
  // In an included file: the toolpath file is relative to that file's directory.
  d.write("paths/creep.toml", R"(
[creep]
creep_basis = "rate_path"
creep_time_s = 30
creep_rate_um_per_min = 2.5
creep_rate_um_per_mm = 0.05
profile = "table"
profile_table = [0, 0.1, 0.5, 1]
on_unfinished = "alarm"
max_creeps = 2
[creep.edge]
tool_shape = "bull_nose"
edge_points = 3
normal_source = "toolpath"
toolpath_file = "normals.csv"
tool_axis = [1, 0, 0]
fallback_channel = "radius"
fallback_sign = 1
material_side = "left"
[creep.output]
mode = "tool_registers"
length_register = "T1_length_wear"
tool_register_sign = 1
write_resolution_um = 0.5
refresh_interval_s = 0
[creep.limiter]
max_abs_um = 70
max_step_um = 7
max_rate_um_per_s = 700
[creep.interval]
basis = "material"
interval_mm = 11
interval_s = 12
removal_mm3_per_mm = 0.5
removal_source = "toolpath"
interval_mm3 = 99
[creep.tool_life]
implausible_factor = 3
min_expected_increment_um = 4
on_excessive = "stop"
[creep.predict]
enabled = false
window = 8
max_um = 9
[creep.entry]
retract_um = 2
refeed_length_mm = 6
[[creep.transition]]
tool = 2
start_path_mm = 10
end_path_mm = 60
in_offset_um = 3
in_length_mm = 5
out_offset_um = 4
out_length_mm = 6
)");
  const auto f =
      d.write("main.toml", std::string("include = [\"paths/creep.toml\"]\n") + kRegisters);
  auto r = load_file(f);
  ASSERT_TRUE(r.config) << r.diagnostics.to_string();
  const auto& s = *creep_section(*r.config);
  const auto& c = s.module.creep;
  EXPECT_EQ(c.creep_basis, core::creep::CreepBasis::kRatePath);
  EXPECT_DOUBLE_EQ(c.creep_time_s, 30.0);
  EXPECT_DOUBLE_EQ(c.creep_rate_um_per_min, 2.5);
  EXPECT_DOUBLE_EQ(c.creep_rate_um_per_mm, 0.05);
  EXPECT_EQ(c.profile, core::ProfileShape::kTable);
  EXPECT_EQ(c.profile_table, (std::vector<double>{0.0, 0.1, 0.5, 1.0}));
  EXPECT_EQ(c.on_unfinished, core::creep::UnfinishedPolicy::kAlarm);
  EXPECT_EQ(c.max_creeps, 2U);
  EXPECT_EQ(c.edge.tool_shape, core::creep::ToolShape::kBullNose);
  EXPECT_EQ(c.edge.normal_source, core::creep::NormalSource::kToolpath);
  EXPECT_EQ(s.toolpath_file, (d.path() / "paths/normals.csv").string());
  ASSERT_EQ(c.toolpath.rows.size(), 2U);
  EXPECT_TRUE(c.toolpath.has_normals);
  EXPECT_TRUE(c.toolpath.has_removal);
  EXPECT_DOUBLE_EQ(c.toolpath.rows[1].path_mm, 100.0);
  EXPECT_DOUBLE_EQ(c.toolpath.rows[1].normal[0], 1.0);
  EXPECT_DOUBLE_EQ(c.toolpath.rows[0].removal_mm2, 0.75);
  EXPECT_EQ(c.edge.material_side, core::creep::MaterialSide::kLeft);
  EXPECT_EQ(c.interval.removal_source, core::creep::RemovalSource::kToolpath);
  EXPECT_DOUBLE_EQ(c.edge.tool_axis[0], 1.0);
  EXPECT_EQ(c.edge.fallback_channel, core::creep::Channel::kRadius);
  EXPECT_DOUBLE_EQ(c.edge.fallback_sign, 1.0);
  EXPECT_EQ(c.output.mode, core::creep::OutputMode::kToolRegisters);
  EXPECT_EQ(s.module.registers.channel[4], "T1_length_wear");
  EXPECT_DOUBLE_EQ(c.output.tool_register_sign, 1.0);
  EXPECT_DOUBLE_EQ(c.output.write_resolution_um, 0.5);
  EXPECT_DOUBLE_EQ(c.output.refresh_interval_s, 0.0);
  EXPECT_DOUBLE_EQ(c.limiter.max_step_um, 7.0);
  EXPECT_EQ(c.interval.basis, core::creep::IntervalBasis::kMaterial);
  EXPECT_DOUBLE_EQ(c.interval.interval_mm, 11.0);
  EXPECT_DOUBLE_EQ(c.interval.interval_s, 12.0);
  EXPECT_DOUBLE_EQ(c.interval.removal_mm3_per_mm, 0.5);
  EXPECT_DOUBLE_EQ(c.interval.interval_mm3, 99.0);
  EXPECT_DOUBLE_EQ(c.tool_life.implausible_factor, 3.0);
  EXPECT_DOUBLE_EQ(c.tool_life.min_expected_increment_um, 4.0);
  EXPECT_FALSE(c.predict.enabled);
  EXPECT_EQ(c.predict.window, 8U);
  EXPECT_DOUBLE_EQ(c.predict.max_um, 9.0);
  EXPECT_DOUBLE_EQ(c.entry.retract_um, 2.0);
  EXPECT_DOUBLE_EQ(c.entry.refeed_length_mm, 6.0);
  ASSERT_EQ(c.transitions.size(), 1U);
  EXPECT_EQ(c.transitions[0].tool, 2);
  EXPECT_DOUBLE_EQ(c.transitions[0].out_length_mm, 6.0);
}

TEST(CreepSection, BadKeysAreReportedWithFileLineColumnAndKeyPath) {
  TempDir d;
  const std::string text = std::string(kRegisters) + R"(
[creep]
creep_length_mm = -5
profile = "ramp"
[creep.edge]
edge_points = 40
edge_pointz = 3
fallback_sign = 0.5
[creep.output]
z_register = "Z_wear_offset"
[[creep.deflection]]
tool = 1
wear_um = [0, "ten"]
normal_um = [0, 1]
)";
  const auto f = d.write("bad.toml", text);
  const std::string e = errors_of(f);
  EXPECT_NE(e.find(at(f, text, "creep_length_mm = -5") +
                   "creep.creep_length_mm: must be a number in [0, 1e+09], got -5"),
            std::string::npos)
      << e;
  EXPECT_NE(e.find(at(f, text, "profile = \"ramp\"") +
                   "creep.profile: must be one of \"linear\", \"cosine\", \"smoothstep\", "
                   "\"table\", \"step\", got \"ramp\""),
            std::string::npos)
      << e;
  EXPECT_NE(e.find(at(f, text, "edge_points = 40") +
                   "creep.edge.edge_points: must be an integer in [1, 32], got 40"),
            std::string::npos)
      << e;
  EXPECT_NE(e.find(at(f, text, "edge_pointz = 3") + "creep.edge.edge_pointz: unknown key"),
            std::string::npos)
      << e;
  EXPECT_NE(
      e.find(at(f, text, "fallback_sign = 0.5") + "creep.edge.fallback_sign: must be +1 or -1"),
      std::string::npos)
      << e;
  EXPECT_NE(e.find("creep.deflection[0].wear_um[1]: must be a number"), std::string::npos) << e;
  EXPECT_NE(e.find("creep.deflection[0].lateral_um: missing required key"), std::string::npos) << e;
}

TEST(CreepSection, EstimatorKeysFromTheDocsExampleAndTheirErrors) {
  // docs/estimation.md's example, key for key; then every refused value with file:line:column.
  const std::string md = read(std::string(NCCOMP_SOURCE_DIR) + "/docs/estimation.md");
  const auto h = md.find("### Example");
  const auto b = md.find("```toml\n", h);
  const auto e = md.find("```", b + 8);
  ASSERT_TRUE(h != std::string::npos && b != std::string::npos && e != std::string::npos);
  TempDir d;
  const auto f = d.write("a.toml", std::string(kRegisters) + md.substr(b + 8, e - b - 8));
  auto r = load_file(f);
  ASSERT_TRUE(r.config) << r.diagnostics.to_string();
  const auto& est = creep_section(*r.config)->module.creep.estimator;
  EXPECT_TRUE(est.enabled);
  EXPECT_DOUBLE_EQ(est.measurement_sigma_um, 1.0);
  EXPECT_DOUBLE_EQ(est.wear_noise_um_per_sqrt_m, 0.0);
  EXPECT_DOUBLE_EQ(est.rate_noise_um_per_mm_per_sqrt_m, 0.0005);
  EXPECT_DOUBLE_EQ(est.initial_rate_sigma_um_per_mm, 0.01);
  EXPECT_DOUBLE_EQ(est.gate_sigmas, 5.0);
  EXPECT_TRUE(est.learn_rate_noise);
  EXPECT_EQ(est.family_min_tools, 3U);
  EXPECT_TRUE(est.learn_rate_prior);
  EXPECT_DOUBLE_EQ(est.family_prior_path_mm, 1000.0);
  EXPECT_TRUE(est.adapt_rate_noise);
  EXPECT_DOUBLE_EQ(est.adapt_window_measurements, 20.0);
  EXPECT_DOUBLE_EQ(est.min_rate_noise_um_per_mm_per_sqrt_m, 0.00005);
  EXPECT_DOUBLE_EQ(est.max_rate_noise_um_per_mm_per_sqrt_m, 0.005);

  const std::string text = std::string(kRegisters) + R"(
[creep]
creep_length_mm = 50
[creep.output]
z_register = "Z_wear_offset"
[creep.estimator]
enabled = true
measurement_sigma_um = 0
rate_noise_um_per_mm_per_sqrt_m = -0.1
gate_sigmas = 1.5
sigma_um = 1
family_min_tools = 0
family_prior_path_mm = 0
adapt_window_measurements = 0
)";
  const auto g = d.write("bad.toml", text);
  const std::string err = errors_of(g);
  EXPECT_NE(err.find(at(g, text, "measurement_sigma_um = 0") +
                     "creep.estimator.measurement_sigma_um: must be"),
            std::string::npos)
      << err;
  EXPECT_NE(err.find(at(g, text, "rate_noise_um_per_mm_per_sqrt_m = -0.1") +
                     "creep.estimator.rate_noise_um_per_mm_per_sqrt_m: must be a number in [0, "),
            std::string::npos)
      << err;
  EXPECT_NE(err.find(at(g, text, "sigma_um = 1") + "creep.estimator.sigma_um: unknown key"),
            std::string::npos)
      << err;
  EXPECT_NE(err.find(at(g, text, "family_min_tools = 0") + "creep.estimator.family_min_tools: "),
            std::string::npos)
      << err;
  EXPECT_NE(err.find(at(g, text, "family_prior_path_mm = 0") +
                     "creep.estimator.family_prior_path_mm: must be"),
            std::string::npos)
      << err;
  EXPECT_NE(err.find(at(g, text, "adapt_window_measurements = 0") +
                     "creep.estimator.adapt_window_measurements: must be a number in [1, 1000]"),
            std::string::npos)
      << err;
  // The gate's own rule is core::creep::validate()'s, pointed at the key.
  const std::string text2 = std::string(kRegisters) + R"(
[creep]
creep_length_mm = 50
[creep.output]
z_register = "Z_wear_offset"
[creep.estimator]
enabled = true
gate_sigmas = 1.5
)";
  const auto g2 = d.write("gate.toml", text2);
  EXPECT_NE(errors_of(g2).find(at(g2, text2, "gate_sigmas = 1.5") +
                               "creep.estimator.gate_sigmas: must be 0 (no gate) or a finite "
                               "number >= 2, got 1.5"),
            std::string::npos)
      << errors_of(g2);

  // Measuring when needed: the interval basis "uncertainty" and its bound; it needs the estimator.
  const std::string text3 = std::string(kRegisters) + R"(
[creep]
creep_length_mm = 50
[creep.output]
z_register = "Z_wear_offset"
[creep.interval]
basis = "uncertainty"
max_sigma_um = 1.5
[creep.estimator]
enabled = true
)";
  auto r3 = load_file(d.write("when_needed.toml", text3));
  ASSERT_TRUE(r3.config) << r3.diagnostics.to_string();
  const auto& iv = creep_section(*r3.config)->module.creep.interval;
  EXPECT_EQ(iv.basis, core::creep::IntervalBasis::kUncertainty);
  EXPECT_DOUBLE_EQ(iv.max_sigma_um, 1.5);
  std::string text4 = text3;
  text4.replace(text4.find("enabled = true"), 14, "enabled = false");
  const auto g4 = d.write("when_needed_off.toml", text4);
  EXPECT_NE(errors_of(g4).find(at(g4, text4, "basis = \"uncertainty\"") +
                               "creep.interval.basis: \"uncertainty\" needs [creep.estimator] "
                               "enabled = true"),
            std::string::npos)
      << errors_of(g4);
}

TEST(CreepSection, CrossFieldRulesPointAtTheKey) {
  TempDir d;
  const std::string text = std::string(kRegisters) + R"(
[creep]
creep_length_mm = 50
[creep.output]
mode = "tool_registers"
z_register = "Z_wear_offset"
[creep.edge]
fallback_channel = "length"
)";
  const auto f = d.write("a.toml", text);
  EXPECT_NE(errors_of(f).find(at(f, text, "mode = \"tool_registers\"") +
                              "creep.output.mode: \"tool_registers\": x/y/z_register must be -1"),
            std::string::npos)
      << errors_of(f);
}

TEST(CreepSection, RegisterNamesAndKindsAreCheckedAgainstTheRegisters) {
  TempDir d;
  const std::string unknown = std::string(kRegisters) + R"(
[creep]
[creep.output]
z_register = "Z_offset_typo"
)";
  const auto f1 = d.write("a.toml", unknown);
  EXPECT_NE(errors_of(f1).find(at(f1, unknown, "z_register =") +
                               "creep.output.z_register: no register "
                               "named 'Z_offset_typo' in [[registers]]"),
            std::string::npos)
      << errors_of(f1);
  const std::string kind = std::string(kRegisters) + R"(
[creep]
[creep.output]
z_register = "T1_length_wear"
)";
  const auto f2 = d.write("b.toml", kind);
  EXPECT_NE(errors_of(f2).find(at(f2, kind, "z_register =") +
                               "creep.output.z_register: register "
                               "'T1_length_wear' is of kind tool_length_wear, expected "
                               "axis_offset"),
            std::string::npos)
      << errors_of(f2);
  const std::string nofile = std::string(kRegisters) + R"(
[creep]
[creep.edge]
normal_source = "toolpath"
toolpath_file = "missing.csv"
[creep.output]
z_register = "Z_wear_offset"
)";
  const auto f3 = d.write("c.toml", nofile);
  EXPECT_NE(errors_of(f3).find(at(f3, nofile, "toolpath_file =") +
                               "creep.edge.toolpath_file: cannot read toolpath file '" +
                               (d.path() / "missing.csv").string() + "': not a regular file"),
            std::string::npos)
      << errors_of(f3);
  d.write("bad.csv", "path_mm,nx,ny,nz\n0,0,0,1\n0,0,0,1\n");
  const std::string badfile = std::string(kRegisters) + R"(
[creep]
[creep.edge]
normal_source = "toolpath"
toolpath_file = "bad.csv"
[creep.output]
z_register = "Z_wear_offset"
)";
  const auto f4 = d.write("d.toml", badfile);
  EXPECT_NE(errors_of(f4).find(":3: "), std::string::npos) << errors_of(f4);
}

TEST(CreepSection, TheToolpathFileMustHaveTheColumnsItIsUsedFor) {
  TempDir d;
  d.write("removal.csv", "path_mm,removal_mm2\n0,0.5\n100,2\n");
  d.write("normals.csv", "path_mm,nx,ny,nz\n0,0,0,1\n100,1,0,0\n");
  const std::string no_normals = std::string(kRegisters) + R"(
[creep]
[creep.edge]
normal_source = "toolpath"
toolpath_file = "removal.csv"
[creep.output]
z_register = "Z_wear_offset"
)";
  const auto f1 = d.write("a.toml", no_normals);
  EXPECT_NE(errors_of(f1).find(at(f1, no_normals, "normal_source =") +
                               "creep.edge.normal_source: \"toolpath\" needs normals (nx, ny, "
                               "nz) in creep.edge.toolpath_file"),
            std::string::npos)
      << errors_of(f1);
  const std::string no_file = std::string(kRegisters) + R"(
[creep]
[creep.output]
z_register = "Z_wear_offset"
[creep.interval]
basis = "material"
removal_source = "toolpath"
)";
  const auto f2 = d.write("b.toml", no_file);
  EXPECT_NE(errors_of(f2).find(at(f2, no_file, "removal_source =") +
                               "creep.interval.removal_source: \"toolpath\" needs "
                               "creep.edge.toolpath_file with a removal_mm2 column"),
            std::string::npos)
      << errors_of(f2);
  const std::string no_removal = std::string(kRegisters) + R"(
[creep]
[creep.edge]
toolpath_file = "normals.csv"
[creep.output]
z_register = "Z_wear_offset"
[creep.interval]
basis = "material"
removal_source = "toolpath"
)";
  const auto f3 = d.write("c.toml", no_removal);
  EXPECT_NE(errors_of(f3).find(at(f3, no_removal, "removal_source =") +
                               "creep.interval.removal_source: \"toolpath\": "
                               "creep.edge.toolpath_file needs a removal_mm2 column"),
            std::string::npos)
      << errors_of(f3);
  d.write("neg.csv", "path_mm,removal_mm2\n0,0.5\n100,-2\n");
  const std::string negative = std::string(kRegisters) + R"(
[creep]
[creep.edge]
toolpath_file = "neg.csv"
[creep.output]
z_register = "Z_wear_offset"
)";
  const auto f4 = d.write("d.toml", negative);
  EXPECT_NE(errors_of(f4).find("neg.csv:3: removal_mm2 must be 0..10000 mm², got -2"),
            std::string::npos)
      << errors_of(f4);
}

// A synthetic stream through the engine the loader builds: tool 1, program path advancing
// 0.5 mm per cycle, one laser measurement of 20 µm at the tip.
struct Stream {
  std::unique_ptr<core::engine::Engine> engine;
  core::StepOutput out;
  core::TimeNs now{0};
  double path_mm{0.0};
  std::vector<double> z;  // Z register (index 2) after each cycle; NaN before the first write
  double last_z{std::nan("")};

  explicit Stream(const config::Config& c) : engine(config::build_engine(c)) {
    step({core::ToolChange{0, 1, false}});
  }
  void step(std::vector<core::Event> ev) {
    now += 1'000'000;
    engine->step(now, ev, out);
    for (const auto& w : out.writes) {
      if (w.register_index == 2) last_z = w.value_um;
    }
    z.push_back(last_z);
  }
  void advance(double ds_mm) {
    path_mm += ds_mm;
    core::AxisSample a;
    a.time_ns = now;
    a.program_path_mm = path_mm;
    a.tool = 1;
    step({a});
  }
  void measure(double wear_um) {
    core::ToolMeasurement m;
    m.tool = 1;
    m.wear_um[0] = wear_um;
    step({m});
  }
};

std::string strategy(const std::string& creep) {
  return std::string(kRegisters) + creep + R"(
[creep.edge]
tool_shape = "tip"
normal_source = "none"
[creep.output]
z_register = "Z_wear_offset"
write_resolution_um = 0.01
)";
}

std::unique_ptr<config::Config> load_ok(const TempDir& d, const std::string& text) {
  auto r = load_file(d.write("s.toml", text));
  EXPECT_TRUE(r.config) << r.diagnostics.to_string();
  return std::move(r.config);
}

TEST(CreepSection, NoCompensationWhenAbsentOrDisabled) {
  TempDir d;
  auto absent = load_ok(d, kRegisters);
  ASSERT_TRUE(absent);
  EXPECT_EQ(config::build_engine(*absent)->module_count(), 0U);
  auto off = load_ok(d, strategy("[creep]\nenabled = false\n"));
  ASSERT_TRUE(off);
  EXPECT_EQ(config::build_engine(*off)->module_count(), 0U);
  Stream s(*off);
  s.advance(0.0);
  s.measure(20.0);
  for (int i = 0; i < 100; ++i) s.advance(0.5);
  EXPECT_TRUE(std::isnan(s.last_z));  // nothing ever written
}

TEST(CreepSection, StepCorrectionAppliesTheWholeIncrementAtOnce) {
  TempDir d;
  auto c = load_ok(d, strategy("[creep]\nprofile = \"step\"\n"));
  ASSERT_TRUE(c);
  Stream s(*c);
  s.advance(0.0);
  s.measure(20.0);
  s.advance(0.5);
  EXPECT_NEAR(s.last_z, -20.0, 1e-9);
}

TEST(CreepSection, CreepingFeedsTheIncrementOverTheCreepLength) {
  TempDir d;
  auto c = load_ok(d, strategy("[creep]\nprofile = \"linear\"\ncreep_length_mm = 50\n"));
  ASSERT_TRUE(c);
  Stream s(*c);
  s.advance(0.0);
  s.measure(20.0);
  for (int i = 0; i < 50; ++i) s.advance(0.5);  // 25 of 50 mm
  EXPECT_NEAR(s.last_z, -10.0, 1e-9);
  double max_step = 0.0;
  for (std::size_t i = 1; i < s.z.size(); ++i) {
    if (!std::isnan(s.z[i - 1])) max_step = std::max(max_step, std::fabs(s.z[i] - s.z[i - 1]));
  }
  EXPECT_LE(max_step, 20.0 * 0.5 / 50.0 + 1e-9);  // h·Δs/L
  for (int i = 0; i < 60; ++i) s.advance(0.5);
  EXPECT_NEAR(s.last_z, -20.0, 1e-9);
}

TEST(CreepSection, PredictiveCreepingFeedsTheFittedWearRateBetweenMeasurements) {
  TempDir d;
  const std::string creep = "[creep]\nprofile = \"linear\"\ncreep_length_mm = 50\n";
  auto plain = load_ok(d, strategy(creep));
  auto pred = load_ok(d, strategy(creep + "[creep.predict]\nenabled = true\nmax_um = 100\n"));
  ASSERT_TRUE(plain && pred);
  Stream a(*plain);
  Stream b(*pred);
  for (Stream* s : {&a, &b}) {
    s->advance(0.0);
    s->measure(2.0);
    for (int i = 0; i < 200; ++i) s->advance(0.5);  // 100 mm
    s->measure(12.0);                               // 0.1 µm/mm
    for (int i = 0; i < 300; ++i) s->advance(0.5);  // 150 mm
  }
  EXPECT_NEAR(a.last_z, -12.0, 1e-9);
  // Prediction adds the fitted rate × path since the measurement, 0.1 µm/mm × 150 mm, the rate
  // blended in from 0 over 0.2 of the last interval (20 mm): 15 − 0.1 · 20 / 2 = 14 µm.
  EXPECT_NEAR(b.last_z - a.last_z, -14.0, 1e-6);
}

TEST(CreepSection, MeasurementDueByMaterialRemovedFromTheToolpathFile) {
  // Roughing-like cross-sections along the program: 0.2 mm² for 100 mm, then 1.5 mm²: 50 mm³
  // are removed after 100 + 30/1.5 = 120 mm (a constant 0.2 mm² would say 250 mm).
  TempDir d;
  d.write("part.csv", "# CAM export\npath_mm,removal_mm2\n0,0.2\n100,1.5\n1000,0\n");
  const std::string text = std::string(kRegisters) + kFlagRegisters + R"(
[creep]
[creep.edge]
tool_shape = "tip"
normal_source = "none"
toolpath_file = "part.csv"
[creep.output]
z_register = "Z_wear_offset"
measurement_due_register = "measure_request"
[creep.interval]
basis = "material"
removal_source = "toolpath"
removal_mm3_per_mm = 0.2
interval_mm3 = 50
)";
  auto c = load_ok(d, text);
  ASSERT_TRUE(c);
  Stream s(*c);
  double due = std::nan("");
  double due_at_mm = std::nan("");
  s.advance(0.0);
  while (s.path_mm < 200.0 && std::isnan(due_at_mm)) {
    s.advance(0.5);
    for (const auto& w : s.out.writes) {
      if (w.register_index == 6) due = w.value_um;  // measure_request
    }
    if (due > 0.5) due_at_mm = s.path_mm;
  }
  EXPECT_NEAR(due_at_mm, 120.0, 1e-9);
}

TEST(CreepSection, AnExcessiveIncrementRaisesTheAlarmFlagAtOnceAndAppliesNothing) {
  TempDir d;
  const std::string text = std::string(kRegisters) + kFlagRegisters + R"(
[creep]
profile = "linear"
[creep.edge]
tool_shape = "tip"
normal_source = "none"
[creep.output]
z_register = "Z_wear_offset"
alarm_register = "creep_alarm"
[creep.tool_life]
excessive_increment_um = 15
on_excessive = "stop"
)";
  auto c = load_ok(d, text);
  ASSERT_TRUE(c);
  Stream s(*c);
  s.advance(0.0);
  core::ToolMeasurement m;
  m.tool = 1;
  m.wear_um[0] = 20.0;  // > 15: excessively worn
  s.engine->step(s.now + 1'000'000, std::vector<core::Event>{m}, s.out);
  bool alarm22 = false;
  for (const auto& a : s.out.alarms)
    alarm22 = alarm22 || a.code == core::AlarmCode::kToolExcessivelyWorn;
  EXPECT_TRUE(alarm22);
  double flag = std::nan("");
  for (const auto& w : s.out.writes) {
    if (w.register_index == 5) flag = w.value_um;  // creep_alarm
  }
  EXPECT_DOUBLE_EQ(flag, 1.0);  // a flag register: 0 → 1 in one write, never slewed
  for (int i = 0; i < 100; ++i) s.advance(0.5);
  EXPECT_TRUE(std::isnan(s.last_z) || std::fabs(s.last_z) < 1e-12);  // nothing applied
}

TEST(CreepSection, FlagOutputsNeedFlagRegisters) {
  TempDir d;
  const std::string text = std::string(kRegisters) + R"(
[creep]
[creep.output]
z_register = "Z_wear_offset"
warning_register = "Y_wear_offset"
)";
  const auto f = d.write("a.toml", text);
  EXPECT_NE(errors_of(f).find(at(f, text, "warning_register =") +
                              "creep.output.warning_register: register 'Y_wear_offset' is of kind "
                              "axis_offset, expected flag"),
            std::string::npos)
      << errors_of(f);
}

}  // namespace
}  // namespace nccomp::daemon::sections

namespace nccomp::daemon::sections {
namespace {

/// config/nccompd.toml with its bus swapped for the loopback bus (the bus sections are not
/// this test's business): every other line as shipped.
std::string shipped_config_on_loopback() {
  std::string text = read(std::string(NCCOMP_SOURCE_DIR) + "/config/nccompd.toml");
  const auto inc = text.find("include = [");
  if (inc != std::string::npos) text.erase(inc, text.find('\n', inc) - inc);
  for (auto p = text.find("bus = \"modbus\""); p != std::string::npos;
       p = text.find("bus = \"modbus\"", p)) {
    text.replace(p, 14, "bus = \"loopback\"");
  }
  return text + "\n[loopback]\n";
}

TEST(ShippedConfig, CreepsTheMeasuredWearIntoTheToolRegistersAlongTheNormal) {
  TempDir d;
  auto r = load_file(d.write("nccompd.toml", shipped_config_on_loopback()));
  ASSERT_TRUE(r.config) << r.diagnostics.to_string();
  auto engine = config::build_engine(*r.config);
  ASSERT_EQ(engine->module_count(), 2U);  // creep, calibration
  EXPECT_EQ(engine->module(0).name(), "calibration");
  EXPECT_EQ(engine->module(1).name(), "creep");
  const int length = 0;  // T1_length_wear
  const int radius = 1;  // T1_radius_wear
  core::StepOutput out;
  core::TimeNs now = 0;
  double values[2] = {std::nan(""), std::nan("")};
  auto step = [&](std::vector<core::Event> ev) {
    now += 1'000'000;  // 1 kHz
    engine->step(now, ev, out);
    for (const auto& w : out.writes) {
      if (w.register_index < 2) values[w.register_index] = w.value_um;
    }
  };
  const double theta = 30.0 * M_PI / 180.0;
  double path = 0.0;
  auto sample = [&](double ds) {
    path += ds;
    core::AxisSample a;
    a.time_ns = now;
    a.program_path_mm = path;
    a.tool = 1;
    a.has_normal = true;
    a.normal = {std::sin(theta), 0.0, std::cos(theta)};
    step({a});
  };
  step({core::ToolChange{0, 1, false}});
  sample(0.0);
  core::ToolMeasurement m;
  m.tool = 1;
  m.wear_um[0] = 12.0;  // one value: the whole edge (below excessive_increment_um = 15)
  step({m});
  // 0.1 mm per cycle = 6 m/min: the cosine ramp's steepest slope (π/2 · 12 µm / 200 mm · 100 mm/s
  // = 9.4 µm/s) stays below the registers' 50 µm/s.
  for (int i = 0; i < 1000; ++i) sample(0.1);  // half of creep_length_mm = 200
  // Cosine at half way: half of the wear; split by the engagement angle, negative (Fanuc sign).
  // (Written when moved by write_resolution_um = 0.1 µm: within 0.1 µm of the ramp.)
  EXPECT_NEAR(values[length], -6.0 * std::cos(theta), 0.1);
  EXPECT_NEAR(values[radius], -6.0 * std::sin(theta), 0.1);
  for (int i = 0; i < 1100; ++i) sample(0.1);
  EXPECT_NEAR(values[length], -12.0 * std::cos(theta), 1e-9);
  EXPECT_NEAR(values[radius], -12.0 * std::sin(theta), 1e-9);
}

// nccomp status, as the daemon renders it, with the loop running the shipped config: the wear of
// every tool the creep module remembers, not only the one in the spindle.
TEST(ShippedConfig, StatusShowsTheWearOfEveryRememberedTool) {
  using namespace std::chrono_literals;
  TempDir d;
  auto loaded = config::load_file(d.write("nccompd.toml", shipped_config_on_loopback()));
  ASSERT_TRUE(loaded.config) << loaded.diagnostics.to_string();
  auto rt = std::make_unique<Runtime>();
  rt->engine = config::build_engine(*loaded.config);
  std::vector<std::string> names;
  for (const auto& e : config::registers_section(*loaded.config).registers) {
    rt->register_bus.push_back(0);
    names.push_back(e.spec.name);
  }
  core::rt::ConfigSwap<Runtime> swap(std::move(rt));
  drivers::loopback::LoopbackBus bus(256, 256);
  bus.start();
  Loop loop(LoopOptions{}, swap, {&bus}, nullptr, nullptr);
  EventLogger logger(loop);
  logger.start();
  loop.start();
  StatusContext c;
  c.loop = &loop;
  c.buses = {{"loopback", &bus}};
  c.logger = &logger;
  c.register_names = [names] { return names; };
  c.config_path = "nccompd.toml";
  c.state_path = "state.bin";
  const auto wait_for = [](const std::function<bool()>& done) {
    for (int i = 0; i < 500; ++i) {
      if (done()) return true;
      std::this_thread::sleep_for(10ms);
    }
    return false;
  };
  double path = 0.0;
  // Tool 1 measured 12 µm, tool 2 measured 5 µm, then tool 3 in the spindle, measured 3 µm.
  for (const auto& [tool, wear] : {std::pair{1, 12.0}, std::pair{2, 5.0}, std::pair{3, 3.0}}) {
    ASSERT_TRUE(bus.inject(core::ToolChange{0, tool, false}));
    for (int k = 0; k < 3; ++k) {
      core::AxisSample a;
      a.tool = tool;
      a.program_path_mm = path;
      path += 1.0;
      ASSERT_TRUE(bus.inject(a));
    }
    core::ToolMeasurement m;
    m.tool = tool;
    m.wear_um[0] = wear;
    ASSERT_TRUE(bus.inject(m));
    const int n = tool;  // clang 14 cannot capture a structured binding
    ASSERT_TRUE(wait_for([&] {
      return render_json(c).find("\"tool\":" + std::to_string(n) + ",") != std::string::npos &&
             render_json(c).find("\"measurements_accepted\":" + std::to_string(n)) !=
                 std::string::npos;
    })) << render_json(c);
  }
  const std::string text = render_text(c);
  EXPECT_NE(
      text.find("module creep: mode creeping, tool 3, wear_in_force_um 0, wear_measured_um 3,"),
      std::string::npos)
      << text;
  EXPECT_NE(text.find("measurements_refused 0, T2_wear_um 5, T1_wear_um 12\n"), std::string::npos)
      << text;
  const std::string json = render_json(c);
  EXPECT_NE(json.find("\"measurements_refused\":0,\"T2_wear_um\":5,\"T1_wear_um\":12}"),
            std::string::npos)
      << json;
  const std::string prom = render_prometheus(c);
  EXPECT_NE(prom.find("nccompd_module_value{module=\"creep\",key=\"T1_wear_um\"} 12\n"),
            std::string::npos)
      << prom;
  loop.stop();
  logger.stop();
  bus.stop();
}

// With [creep.estimator] on: the check of σ (nis_mean, measurement_sigma_estimate_um) and the
// rate noise in use in the text and JSON status, and the estimate's σ as its own metric, in
// metres, which Prometheus' linter accepts.
TEST(ShippedConfig, TheEstimatorsSigmaCheckIsInTheStatusAndItsSigmaIsAMetric) {
  using namespace std::chrono_literals;
  TempDir d;
  std::string text = shipped_config_on_loopback();
  const auto est = text.find("[creep.estimator]");
  ASSERT_NE(est, std::string::npos);
  const auto on = text.find("enabled = false", est);
  ASSERT_NE(on, std::string::npos);
  text.replace(on, 15, "enabled = true");
  auto loaded = config::load_file(d.write("nccompd.toml", text));
  ASSERT_TRUE(loaded.config) << loaded.diagnostics.to_string();
  auto rt = std::make_unique<Runtime>();
  rt->engine = config::build_engine(*loaded.config);
  std::vector<std::string> names;
  for (const auto& e : config::registers_section(*loaded.config).registers) {
    rt->register_bus.push_back(0);
    names.push_back(e.spec.name);
  }
  core::rt::ConfigSwap<Runtime> swap(std::move(rt));
  drivers::loopback::LoopbackBus bus(256, 256);
  bus.start();
  Loop loop(LoopOptions{}, swap, {&bus}, nullptr, nullptr);
  EventLogger logger(loop);
  logger.start();
  loop.start();
  StatusContext c;
  c.loop = &loop;
  c.buses = {{"loopback", &bus}};
  c.logger = &logger;
  c.register_names = [names] { return names; };
  c.config_path = "nccompd.toml";
  c.state_path = "state.bin";
  ASSERT_TRUE(bus.inject(core::ToolChange{0, 1, false}));
  double path = 0.0;
  for (int j = 1; j <= 2; ++j) {
    for (int k = 0; k < 3; ++k) {
      core::AxisSample a;
      a.tool = 1;
      a.program_path_mm = path;
      path += 1.0;
      ASSERT_TRUE(bus.inject(a));
    }
    core::ToolMeasurement m;
    m.tool = 1;
    m.wear_um[0] = 2.0 * j;
    ASSERT_TRUE(bus.inject(m));
  }
  bool done = false;
  for (int i = 0; i < 500 && !done; ++i) {
    done = render_json(c).find("\"measurements_accepted\":2") != std::string::npos;
    if (!done) std::this_thread::sleep_for(10ms);
  }
  ASSERT_TRUE(done) << render_json(c);
  const std::string status = render_text(c);
  const std::string json = render_json(c);
  const std::string prom = render_prometheus(c);
  loop.stop();
  logger.stop();
  bus.stop();
  EXPECT_NE(status.find("mode creeping, estimator"), std::string::npos) << status;
  for (const char* key :
       {"nis_mean", "measurement_sigma_estimate_um", "rate_noise_um_per_mm_per_sqrt_m"}) {
    EXPECT_NE(status.find(std::string(", ") + key + " "), std::string::npos) << key << status;
    EXPECT_NE(json.find(std::string("\"") + key + "\":"), std::string::npos) << key << json;
  }
  // The configured rate noise, as shipped (nothing learned yet).
  EXPECT_NE(json.find("\"rate_noise_um_per_mm_per_sqrt_m\":0.0005"), std::string::npos) << json;
  const auto number_after = [](const std::string& s, const std::string& key) {
    const auto p = s.find(key);
    return p == std::string::npos ? std::nan("") : std::stod(s.substr(p + key.size()));
  };
  const double sigma_um = number_after(json, "\"wear_sigma_um\":");
  ASSERT_TRUE(std::isfinite(sigma_um) && sigma_um > 0.0) << json;
  const double sigma_m =
      number_after(prom, "nccompd_module_sigma_meters{module=\"creep\",key=\"wear_estimate_um\"} ");
  EXPECT_NEAR(sigma_m, sigma_um * 1e-6, 1e-5 * sigma_um * 1e-6) << prom;  // JSON: 6 digits
  if (::system("command -v promtool >/dev/null 2>&1") == 0) {
    const auto file = d.write("metrics.txt", prom);
    const std::string cmd = "promtool check metrics <" + file + " 2>&1";
    std::FILE* p = ::popen(cmd.c_str(), "r");
    ASSERT_NE(p, nullptr);
    std::string lint;
    char buf[512];
    std::size_t n = 0;
    while ((n = std::fread(buf, 1, sizeof buf, p)) > 0) lint.append(buf, n);
    EXPECT_EQ(::pclose(p), 0) << lint;
    EXPECT_EQ(lint, "") << prom;
  }
}

}  // namespace
}  // namespace nccomp::daemon::sections
