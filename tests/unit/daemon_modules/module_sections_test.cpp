// GIVEN daemon configs with [checkpoints] and [calibration] sections, WHEN the loader reads them,
// THEN the tools' loaders fill the module configs, errors carry file:line:column and key path,
// registers are checked against [[registers]], and the engine built from them steps by the
// numbers.
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <fstream>
#include <memory>
#include <optional>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "core/checkpoint/module.hpp"
#include "core/checkpoint/probe.hpp"
#include "daemon/config/builtin_sections.hpp"
#include "daemon/logging.hpp"
#include "daemon/loop.hpp"
#include "daemon/sections/calibration/calibration_section.hpp"
#include "daemon/sections/checkpoints/checkpoints_section.hpp"
#include "daemon/sections/checkpoints/startup.hpp"
#include "daemon/status.hpp"
#include "drivers/loopback/loopback_bus.hpp"
#include "tests/unit/daemon_modules/temp_dir.hpp"

namespace nccomp::daemon::sections {
namespace {

using config::load_file;
using testing::TempDir;

std::string reg(const std::string& name, const std::string& kind) {
  return "[[registers]]\nname = \"" + name + "\"\nkind = \"" + kind +
         "\"\nbus = \"loopback\"\nmax_abs_um = 100\nmax_step_um = 50\n"
         "max_rate_um_per_s = 100000\n";
}

/// The reference NC's logical registers 0..75: 0/1 tool wear, 19 the finishing tool's live
/// radius wear, 20..22 X/Y/Z axis offsets, 20..75 checkpoints in the boss example (which uses
/// its own layout: the register kinds differ per test).
std::string registers(int n, int checkpoint_first, int axis_first) {
  std::string s = "[loopback]\n";
  for (int i = 0; i < n; ++i) {
    std::string kind = "tool_length_wear";
    if (i == 19) kind = "tool_radius_wear";
    if (i >= checkpoint_first) kind = "checkpoint";
    if (axis_first >= 0 && i >= axis_first && i < axis_first + 3) kind = "axis_offset";
    s += reg("r" + std::to_string(i), kind);
  }
  return s;
}

const std::string kBoss = std::string(NCCOMP_SOURCE_DIR) + "/tests/unit/checkpoint/data/boss.toml";
const std::string kMachine =
    std::string(NCCOMP_SOURCE_DIR) + "/tools/calibrate/examples/machine.toml";

/// 1-based line of the first line of text that contains needle.
int line_of(const std::string& text, const std::string& needle) {
  const auto pos = text.find(needle);
  if (pos == std::string::npos) return -1;
  int line = 1;
  for (std::size_t i = 0; i < pos; ++i) line += text[i] == '\n' ? 1 : 0;
  return line;
}

std::string errors_of(const std::string& path) {
  auto r = load_file(path);
  return r.config ? std::string() : r.diagnostics.to_string();
}

TEST(CheckpointsSection, ParsesTheDocumentedExampleAndLearnsFromPartToPart) {
  TempDir d;
  // The example as an include: its contour_csv is relative to its own directory.
  const auto f = d.write("a.toml", "include = [\"" + kBoss + "\"]\n" + registers(76, 20, -1));
  auto r = load_file(f);
  ASSERT_TRUE(r.config) << r.diagnostics.to_string();
  const auto* s = checkpoints_section(*r.config);
  ASSERT_NE(s, nullptr);
  EXPECT_EQ(s->checkpoint_count, 56U);  // docs/checkpoints.md: 4 levels × 14 points
  EXPECT_EQ(s->config.compensator.register_base, 20U);
  EXPECT_EQ(s->config.compensator.active_register, 19);
  EXPECT_EQ(s->config.compensator.finishing_tool, 12);
  auto engine = config::build_engine(*r.config);
  ASSERT_EQ(engine->module_count(), 1U);
  EXPECT_EQ(engine->module(0).name(), "checkpoints");

  // Part 1 probed: checkpoint 0 is 6 µm oversize, checkpoint 1 0.5 µm (below the probe's
  // repeatability of 1 µm: written as 0). The probe reads δ = δ' + (r/cos α − r).
  const double delta0_um = core::checkpoint::probe_delta0_um(2.0, 3.0);
  EXPECT_NEAR(delta0_um, 2.745, 5e-4);  // the plan's printout in docs/checkpoints.md
  auto probe = [&](int cp, double corrected_um) {
    core::ProbeMeasurement m;
    m.part = 1;
    m.checkpoint = cp;
    m.wall_angle_deg = 3.0;
    m.ball_radius_mm = 2.0;
    m.raw_deviation_um = corrected_um + delta0_um;
    return m;
  };
  core::StepOutput out;
  std::vector<double> value(76, std::nan(""));
  core::TimeNs now = 0;
  auto step = [&](std::vector<core::Event> ev) {
    now += 1'000'000;
    engine->step(now, ev, out);
    for (const auto& w : out.writes) value[w.register_index] = w.value_um;
  };
  step({probe(0, 6.0), probe(1, 0.5)});
  step({core::ProgramEvent{now, core::ProgramEventKind::kPartStart, 2}});
  step({});  // 56 table registers at 32 per cycle: two cycles
  EXPECT_DOUBLE_EQ(value[20], -6.0);
  EXPECT_DOUBLE_EQ(value[21], 0.0);
  EXPECT_DOUBLE_EQ(value[75], 0.0);
  // The live register pre-positioned to the start of the first level's closed pass: halfway
  // through the seam from checkpoint 13 (0, 8 mm before the start) to checkpoint 0 (−6, 8 mm
  // after it).
  EXPECT_DOUBLE_EQ(value[19], -3.0);
}

TEST(CheckpointsStartup, TheNcsRegistersAreComparedWithTheLearnedTable) {
  TempDir d;
  auto r = load_file(d.write("a.toml", "include = [\"" + kBoss + "\"]\n" + registers(76, 20, -1)));
  ASSERT_TRUE(r.config) << r.diagnostics.to_string();
  auto engine = config::build_engine(*r.config);
  core::StepOutput out;
  core::ProbeMeasurement m;
  m.part = 1;
  m.checkpoint = 0;
  m.wall_angle_deg = 3.0;
  m.ball_radius_mm = 2.0;
  m.raw_deviation_um = 6.0 + core::checkpoint::probe_delta0_um(2.0, 3.0);
  engine->step(1'000'000, std::vector<core::Event>{m}, out);  // table: cp 0 = -6, others 0
  engine->step(
      1'500'000,
      std::vector<core::Event>{core::ProgramEvent{0, core::ProgramEventKind::kPartStart, 2}}, out);
  engine->step(1'600'000, std::vector<core::Event>{}, out);  // all 56 written: the NC has them
  EXPECT_DOUBLE_EQ(engine->register_state(23).output_um, 0.0);

  // nccompd runs this as its "checkpoints" start-up hook.
  bool hooked = false;
  for (const auto& h : startup_hooks()) hooked = hooked || h.first == "checkpoints";
  EXPECT_TRUE(hooked);

  // A bus that cannot read back: nothing compared, said so.
  auto none = reconcile_checkpoints(
      *engine, [](std::uint16_t) { return std::optional<double>{}; }, 0);
  ASSERT_EQ(none.size(), 1U);
  EXPECT_FALSE(none[0].read_back);
  EXPECT_EQ(none[0].message,
            "checkpoints: 56 of 56 checkpoint registers cannot be read back from the NC; the "
            "learned table is written again at the next part start");

  // The NC holds the table except register 23 (checkpoint 3), edited to 2 µm: one mismatch of
  // 2 µm; reconcile_prefer = "daemon" rewrites it on the next step (although the engine had
  // sent 0 before) and raises warning 33.
  auto nc = [](std::uint16_t reg) -> std::optional<double> {
    if (reg == 20) return -6.0;
    if (reg == 23) return 2.0;
    if (reg == 19) return -6.0;  // the live register
    return 0.0;
  };
  auto rep = reconcile_checkpoints(*engine, nc, 2'000'000);
  ASSERT_EQ(rep.size(), 1U);
  EXPECT_TRUE(rep[0].read_back);
  EXPECT_EQ(rep[0].compared, 56U);
  EXPECT_EQ(rep[0].mismatched, 1U);
  EXPECT_DOUBLE_EQ(rep[0].max_difference_um, 2.0);
  EXPECT_FALSE(rep[0].adopted_nc);
  EXPECT_EQ(rep[0].message,
            "checkpoints: 1 of 56 checkpoint registers differ from the table (max 2.000 um); the "
            "table is written again (reconcile_prefer = \"daemon\")");
  engine->step(3'000'000, std::vector<core::Event>{}, out);
  bool alarm33 = false;
  for (const auto& a : out.alarms) {
    alarm33 = alarm33 || a.code == core::AlarmCode::kCheckpointRegisterMismatch;
  }
  EXPECT_TRUE(alarm33);
  double reg23 = std::nan("");
  for (const auto& w : out.writes) {
    if (w.register_index == 23) reg23 = w.value_um;
  }
  EXPECT_DOUBLE_EQ(reg23, 0.0);  // the daemon's value, written again
}

// GIVEN the boss example's 56 checkpoints (two cycles of 32 table writes) restarted from its
// state, and an NC whose checkpoint 40 (register 60, written in the second cycle) an operator set
// to +80.0 µm, beyond the register's max_step_um of 50, WHEN the start-up hook reconciles,
// THEN with reconcile_prefer = "nc" the engine's limiters start from the NC's values and the
// adopted value is the register's target at once: no write ever moves register 60; with "daemon"
// the register is brought back from +80.0 in steps of at most 50 µm.
TEST(CheckpointsStartup, TheEnginesLimitersStartFromTheValuesReadBack) {
  TempDir d;
  std::ifstream in(kBoss);
  std::stringstream boss;
  boss << in.rdbuf();
  auto text_for = [&](const std::string& prefer) {
    std::string t = boss.str();
    const std::string csv = "contour_csv = \"boss_contour.csv\"";
    t.replace(t.find(csv), csv.size(),
              "contour_csv = \"" + std::string(NCCOMP_SOURCE_DIR) +
                  "/tests/unit/checkpoint/data/boss_contour.csv\"");
    const std::string pref = "reconcile_prefer = \"daemon\"";
    t.replace(t.find(pref), pref.size(), "reconcile_prefer = \"" + prefer + "\"");
    return t + registers(76, 20, -1);
  };
  for (const std::string prefer : {"nc", "daemon"}) {
    auto r = load_file(d.write(prefer + ".toml", text_for(prefer)));
    ASSERT_TRUE(r.config) << r.diagnostics.to_string();
    // Before the restart: checkpoint 0 learned −6 µm, the table written at part 2's start.
    auto before = config::build_engine(*r.config);
    core::StepOutput out;
    core::ProbeMeasurement m;
    m.part = 1;
    m.checkpoint = 0;
    m.wall_angle_deg = 3.0;
    m.ball_radius_mm = 2.0;
    m.raw_deviation_um = 6.0 + core::checkpoint::probe_delta0_um(2.0, 3.0);
    before->step(1'000'000, std::vector<core::Event>{m}, out);
    before->step(
        2'000'000,
        std::vector<core::Event>{core::ProgramEvent{0, core::ProgramEventKind::kPartStart, 2}},
        out);
    before->step(3'000'000, std::vector<core::Event>{}, out);
    ASSERT_DOUBLE_EQ(before->register_state(60).output_um, 0.0);
    std::vector<std::byte> state(before->state_capacity());
    state.resize(before->export_state(state));

    auto after = config::build_engine(*r.config);
    ASSERT_TRUE(after->import_state(state, 10'000'000));
    auto nc = [](std::uint16_t reg) -> std::optional<double> {
      if (reg == 20) return -6.0;
      if (reg == 60) return 80.0;  // the operator's edit
      if (reg == 19) return -3.0;  // the live register as the part start left it
      return 0.0;
    };
    const auto rep = reconcile_checkpoints(*after, nc, 10'000'000);
    ASSERT_EQ(rep.size(), 1U);
    EXPECT_EQ(rep[0].mismatched, 1U);
    EXPECT_DOUBLE_EQ(rep[0].max_difference_um, 80.0);
    EXPECT_DOUBLE_EQ(after->register_state(60).output_um, 80.0) << prefer;
    std::vector<double> reg60;
    for (int k = 1; k <= 5; ++k) {
      after->step(10'000'000 + k * 1'000'000, std::vector<core::Event>{}, out);
      for (const auto& w : out.writes) {
        if (w.register_index == 60) reg60.push_back(w.value_um);
      }
    }
    if (prefer == "nc") {
      EXPECT_TRUE(rep[0].adopted_nc);
      EXPECT_TRUE(reg60.empty()) << reg60.size() << " writes, first " << reg60.front();
      EXPECT_DOUBLE_EQ(after->register_state(60).output_um, 80.0);
      EXPECT_DOUBLE_EQ(after->register_state(60).target_um, 80.0);
    } else {
      EXPECT_FALSE(rep[0].adopted_nc);
      EXPECT_EQ(reg60, (std::vector<double>{30.0, 0.0}));  // 80 → 0 in steps of max_step_um 50
    }
    // The other registers agreed with the NC: nothing is written to them.
    EXPECT_DOUBLE_EQ(after->register_state(20).output_um, -6.0);
    EXPECT_EQ(after->counters().writes_forwarded, prefer == "nc" ? 0U : 2U) << prefer;
  }
}

// GIVEN the boss table (reconcile_prefer = "daemon") started without any state and an NC that
// holds a compensation (checkpoint 0 at -6 µm, checkpoint 40 at +80 µm, the live register at
// -3 µm), WHEN nccompd's start-up offers the values read back to the fresh module
// (Engine::adopt_without_state(), then the "checkpoints" hook), THEN the module adopts them as its
// table (the hook finds no mismatch), and neither the next cycles nor the next part start write
// anything but what the NC holds (before, "daemon" rewrote the table from zeros).
TEST(CheckpointsStartup, WithoutStateTheNcsTableIsAdoptedNotRewrittenFromZeros) {
  TempDir d;
  auto r = load_file(d.write("a.toml", "include = [\"" + kBoss + "\"]\n" + registers(76, 20, -1)));
  ASSERT_TRUE(r.config) << r.diagnostics.to_string();
  auto engine = config::build_engine(*r.config);
  auto nc = [](std::uint16_t reg) -> std::optional<double> {
    if (reg == 20) return -6.0;
    if (reg == 60) return 80.0;
    if (reg == 19) return -3.0;
    return 0.0;
  };
  std::size_t adopted = 0;
  for (std::size_t i = 0; i < engine->register_count(); ++i) {
    const auto v = nc(static_cast<std::uint16_t>(i));
    ASSERT_TRUE(engine->anchor_register(i, *v, 0).anchored);
    const auto what = engine->adopt_without_state(i, v, true, 0);
    adopted += what == core::engine::StartupAdoption::kAdopted ? 1U : 0U;
  }
  EXPECT_EQ(adopted, 57U);  // 56 table registers and the live one
  const auto rep = reconcile_checkpoints(*engine, nc, 0);
  ASSERT_EQ(rep.size(), 1U);
  EXPECT_EQ(rep[0].mismatched, 0U) << rep[0].message;
  core::StepOutput out;
  std::vector<core::OffsetWrite> writes;
  for (int k = 1; k <= 5; ++k) {
    std::vector<core::Event> ev;
    if (k == 2) ev.push_back(core::ProgramEvent{0, core::ProgramEventKind::kPartStart, 1});
    engine->step(k * 1'000'000, ev, out);
    for (const auto& w : out.writes) writes.push_back(w);
  }
  for (const auto& w : writes) {
    EXPECT_DOUBLE_EQ(w.value_um, *nc(w.register_index)) << "register " << w.register_index;
  }
  EXPECT_DOUBLE_EQ(engine->register_state(20).output_um, -6.0);
  EXPECT_DOUBLE_EQ(engine->register_state(60).output_um, 80.0);
  EXPECT_EQ(engine->counters().writes_forwarded, 0U);
}

TEST(CheckpointsSection, ErrorsCarryFileLineColumnAndRegistersAreChecked) {
  TempDir d;
  const std::string bad_text = registers(4, 2, -1) + R"(
[checkpoints]
contour = [[0,0],[100,0],[100,"a"],[0,60]]
depth_step_mm = -1
colour = "red"
)";
  const auto bad = d.write("bad.toml", bad_text);
  const std::string e = errors_of(bad);
  EXPECT_NE(e.find(bad + ":" + std::to_string(line_of(bad_text, "contour =")) +
                   ":26: checkpoints.contour[2]: must be a pair of numbers [x_mm, y_mm]"),
            std::string::npos)
      << e;
  EXPECT_NE(e.find(bad + ":" + std::to_string(line_of(bad_text, "colour =")) +
                   ":10: checkpoints.colour: unknown key"),
            std::string::npos)
      << e;
  // A plan of 16 checkpoints (2 levels × 4 corners × 2 points) from register 2 needs registers
  // 2..17: only 4 exist.
  const std::string text = registers(4, 2, -1) + R"(
[checkpoints]
contour = [[0,0],[100,0],[100,60],[0,60]]
z_start_mm = -2
z_end_mm = -7
depth_step_mm = 5
register_base = 2
)";
  const auto few = d.write("few.toml", text);
  const std::string e2 = errors_of(few);
  EXPECT_NE(e2.find(few + ":" + std::to_string(line_of(text, "register_base =")) +
                    ":17: checkpoints.register_base: registers 2..17 are needed for 16 "
                    "checkpoints, the register table has 4"),
            std::string::npos)
      << e2;
}

TEST(CalibrationSection, ParsesTheExampleAndChecksTheAxisRegisters) {
  TempDir d;
  const auto f = d.write("a.toml", "include = [\"" + kMachine + "\"]\n" + registers(23, 99, 20));
  auto r = load_file(f);
  ASSERT_TRUE(r.config) << r.diagnostics.to_string();
  const auto* s = calibration_section(*r.config);
  ASSERT_NE(s, nullptr);
  EXPECT_EQ(s->config.register_x, 20U);
  EXPECT_EQ(s->config.register_z, 22U);
  EXPECT_DOUBLE_EQ(s->config.reference_x_axial_mm, 262.5);
  EXPECT_DOUBLE_EQ(s->config.plausibility_um, 50.0);
  EXPECT_DOUBLE_EQ(s->config.creep_duration_s, 600.0);
  auto engine = config::build_engine(*r.config);
  ASSERT_EQ(engine->module_count(), 1U);
  EXPECT_EQ(engine->module(0).name(), "calibration");

  // register_x names a tool length register: refused at the key.
  const std::string text = registers(23, 99, 20) + "[calibration]\nregister_x = 3\n";
  const auto g = d.write("b.toml", text);
  EXPECT_NE(errors_of(g).find(g + ":" + std::to_string(line_of(text, "register_x =")) +
                              ":14: calibration.register_x: register 3 "
                              "(\"r3\") must be of kind axis_offset"),
            std::string::npos)
      << errors_of(g);
  const std::string typo = registers(23, 99, 20) + "[calibration]\nplausibility = 3\n";
  const auto h = d.write("c.toml", typo);
  EXPECT_NE(errors_of(h).find(h + ":" + std::to_string(line_of(typo, "plausibility =")) +
                              ":16: calibration.plausibility: unknown key"),
            std::string::npos)
      << errors_of(h);
}

}  // namespace
}  // namespace nccomp::daemon::sections

namespace nccomp::daemon::sections {
namespace {

// GIVEN the engine nccompd builds from a config with all three module sections, WHEN its state
// is exported (what the state file holds) and imported by a freshly built engine (a restart),
// THEN each module resumes its own state: creep's wear and creep progress, S1's learned values.
TEST(ModuleState, EveryModuleResumesAfterARestart) {
  TempDir d;
  const std::string text = "include = [\"" + kBoss + "\"]\n" + registers(76, 20, -1) + R"(
[creep]
profile = "linear"
creep_length_mm = 50
[creep.edge]
tool_shape = "tip"
normal_source = "none"
fallback_channel = "length"
[creep.output]
mode = "tool_registers"
length_register = "r0"
)";
  const auto f = d.write("a.toml", text);
  auto r = load_file(f);
  ASSERT_TRUE(r.config) << r.diagnostics.to_string();
  auto a = config::build_engine(*r.config);
  ASSERT_EQ(a->module_count(), 2U);  // checkpoints, creep
  core::StepOutput out;
  core::TimeNs now = 0;
  auto step = [&](core::engine::Engine& e, std::vector<core::Event> ev) {
    now += 1'000'000;
    e.step(now, ev, out);
  };
  double path = 0.0;
  auto sample = [&](core::engine::Engine& e) {
    core::AxisSample s;
    s.tool = 1;
    s.program_path_mm = path;
    step(e, {s});
    path += 0.5;
  };
  step(*a, {core::ToolChange{0, 1, false}});
  sample(*a);
  core::ToolMeasurement tm;
  tm.tool = 1;
  tm.wear_um[0] = 10.0;
  step(*a, {tm});
  for (int i = 0; i < 40; ++i) sample(*a);  // 20 of 50 mm: 4 µm in force
  core::ProbeMeasurement pm;
  pm.part = 1;
  pm.checkpoint = 5;
  pm.wall_angle_deg = 3.0;
  pm.ball_radius_mm = 2.0;
  pm.raw_deviation_um = 8.0 + core::checkpoint::probe_delta0_um(2.0, 3.0);
  step(*a, {pm});
  std::vector<std::byte> bytes(a->state_capacity());
  bytes.resize(a->export_state(bytes));
  ASSERT_FALSE(bytes.empty());

  auto b = config::build_engine(*r.config);
  std::size_t skipped = 0;
  ASSERT_TRUE(b->import_state(bytes, now, &skipped));
  EXPECT_EQ(skipped, 0U);
  EXPECT_NEAR(b->register_state(0).output_um, -4.0, 0.1);  // creep's length wear, as sent
  const auto& cp = dynamic_cast<const core::checkpoint::CheckpointModule&>(b->module(0));
  EXPECT_EQ(cp.compensator().learned_count(5), 1U);
  EXPECT_DOUBLE_EQ(cp.compensator().learned_um(5), 8.0);
  // The creep continues where it was: 30 more mm finish it at the full 10 µm, nothing doubled.
  path = 1000.0;  // wherever the NC's program is after the restart: re-anchored
  for (int i = 0; i < 40; ++i) sample(*b);  // first sample re-anchors, then 19.5 mm more
  EXPECT_NEAR(b->register_state(0).output_um, -4.0 - 6.0 * 19.5 / 30.0, 0.1);
  for (int i = 0; i < 40; ++i) sample(*b);
  EXPECT_NEAR(b->register_state(0).output_um, -10.0, 1e-9);
}

}  // namespace
}  // namespace nccomp::daemon::sections

namespace nccomp::daemon::sections {
namespace {

TEST(ModuleRegisters, TwoModulesOnOneRegisterAreRefused) {
  TempDir d;
  // creep's Z offset and calibration's register_z are the same register.
  const std::string text = registers(23, 99, 20) + R"(
[creep]
[creep.edge]
tool_shape = "tip"
normal_source = "none"
[creep.output]
z_register = "r22"
[calibration]
register_x = 20
register_y = 21
register_z = 22
)";
  auto r = load_file(d.write("a.toml", text));
  ASSERT_TRUE(r.config) << r.diagnostics.to_string();
  try {
    (void)config::build_engine(*r.config);
    FAIL() << "two writers of r22 accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_STREQ(e.what(),
                 "engine: register 'r22' is written by module 'calibration' and by 'creep'; give "
                 "each module its own registers");
  }
}

}  // namespace
}  // namespace nccomp::daemon::sections

namespace nccomp::daemon::sections {
namespace {

// GIVEN the boss example with [checkpoints.estimator] on, nccompd's loop on a loopback bus
// WHEN checkpoint 0 has been read once
// THEN its σ is in the status (checkpoint_sigma_um = sqrt(σ² + q) = sqrt(1 + 1) µm with the
//      defaults) and is its own metric in metres, nccompd_module_sigma_meters, under the key of
//      its estimate.
TEST(CheckpointsSection, TheEstimatorsSigmaIsInTheStatusAndAMetricInMetres) {
  using namespace std::chrono_literals;
  TempDir d;
  // The example with its contour file named absolutely, and the estimator's table after it.
  std::ifstream in(kBoss);
  std::stringstream boss;
  boss << in.rdbuf();
  std::string text = boss.str();
  const std::string csv = "contour_csv = \"boss_contour.csv\"";
  const auto at = text.find(csv);
  ASSERT_NE(at, std::string::npos);
  text.replace(at, csv.size(),
               "contour_csv = \"" + std::string(NCCOMP_SOURCE_DIR) +
                   "/tests/unit/checkpoint/data/boss_contour.csv\"");
  auto r = load_file(d.write(
      "a.toml", text + "\n[checkpoints.estimator]\nenabled = true\n" + registers(76, 20, -1)));
  ASSERT_TRUE(r.config) << r.diagnostics.to_string();
  auto rt = std::make_unique<Runtime>();
  rt->engine = config::build_engine(*r.config);
  std::vector<std::string> names;
  for (const auto& e : config::registers_section(*r.config).registers) {
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
  c.config_path = "a.toml";
  c.state_path = "state.bin";
  core::ProbeMeasurement m;
  m.part = 1;
  m.checkpoint = 0;
  m.wall_angle_deg = 3.0;
  m.ball_radius_mm = 2.0;
  m.raw_deviation_um = 6.0 + core::checkpoint::probe_delta0_um(2.0, 3.0);
  ASSERT_TRUE(bus.inject(m));
  bool done = false;
  for (int i = 0; i < 500 && !done; ++i) {
    done = render_json(c).find("\"probe_readings\":1") != std::string::npos;
    if (!done) std::this_thread::sleep_for(10ms);
  }
  ASSERT_TRUE(done) << render_json(c);
  std::this_thread::sleep_for(50ms);  // the status is published every 10 cycles
  const std::string json = render_json(c);
  const std::string prom = render_prometheus(c);
  loop.stop();
  logger.stop();
  bus.stop();
  const auto number_after = [](const std::string& s, const std::string& key) {
    const auto p = s.find(key);
    return p == std::string::npos ? std::nan("") : std::stod(s.substr(p + key.size()));
  };
  EXPECT_NEAR(number_after(json, "\"checkpoint_estimate_um\":"), 6.0, 1e-9) << json;
  const double sigma_um = number_after(json, "\"checkpoint_sigma_um\":");
  EXPECT_NEAR(sigma_um, std::sqrt(2.0), 1e-5) << json;  // JSON: 6 digits
  EXPECT_NEAR(number_after(prom,
                           "nccompd_module_sigma_meters{module=\"checkpoints\",key=\""
                           "checkpoint_estimate_um\"} "),
              std::sqrt(2.0) * 1e-6, 1e-11)
      << prom;
}

}  // namespace
}  // namespace nccomp::daemon::sections
