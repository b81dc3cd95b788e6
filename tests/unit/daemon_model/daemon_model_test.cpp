// GIVEN an engine with a module owning a register and another publishing an additive trim, or a
// daemon config with [model] and a model.toml with known coefficients, WHEN the engine steps,
// THEN the register gets base + trim through its limiter, inadmissible sums change nothing, a
// restart does not apply the trim twice, and config errors name file, line and key.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <memory>
#include <string>
#include <vector>

#include "core/engine/engine.hpp"
#include "core/model/model.hpp"
#include "daemon/config/builtin_sections.hpp"
#include "daemon/sections/model/model_module.hpp"
#include "daemon/sections/model/model_section.hpp"
#include "tests/support/alloc_counter.hpp"
#include "tests/unit/daemon_modules/temp_dir.hpp"
#include "tools/analyze/model_io.hpp"

namespace nccomp::daemon::sections {
namespace {

namespace ce = core::engine;
namespace cm = core::model;
using testing::TempDir;

/// Writes a fixed target (base) or a fixed trim on register 0 each step.
class FixedModule final : public ce::Module {
 public:
  FixedModule(std::string name, bool trim, double value_um)
      : value_um_(value_um), name_(std::move(name)), trim_(trim) {}
  std::string_view name() const noexcept override { return name_; }
  void attach(const ce::RegisterTable&) override {}
  void step(core::TimeNs now_ns, std::span<const core::Event>,
            core::StepOutput& out) noexcept override {
    if (trim_) {
      out.trims.push(core::OffsetWrite{now_ns, 0, value_um_});
    } else {
      out.writes.push(core::OffsetWrite{now_ns, 0, value_um_});
    }
  }
  std::vector<std::uint16_t> written_registers() const override {
    return trim_ ? std::vector<std::uint16_t>{} : std::vector<std::uint16_t>{0};
  }
  double value_um_;

 private:
  std::string name_;
  bool trim_;
};

std::vector<ce::RegisterSpec> one_register(double max_abs_um, double max_step_um) {
  ce::RegisterSpec r;
  r.name = "checkpoint_0";
  r.kind = ce::RegisterKind::kCheckpoint;
  r.limits.max_abs_um = max_abs_um;
  r.limits.max_step_um = max_step_um;
  r.limits.max_rate_um_per_s = 1e6;
  return {r};
}

double last_write(const core::StepOutput& out, double fallback) {
  return out.writes.empty() ? fallback : out.writes[out.writes.size() - 1].value_um;
}

TEST(EngineTrims, TheRegisterGetsTargetPlusTrimThroughItsLimits) {
  std::vector<std::unique_ptr<ce::Module>> mods;
  mods.push_back(std::make_unique<FixedModule>("base", false, 10.0));
  mods.push_back(std::make_unique<FixedModule>("trim", true, -3.5));
  auto* trim = static_cast<FixedModule*>(mods[1].get());
  ce::Engine e;
  e.configure(one_register(20.0, 100.0), std::move(mods));
  core::StepOutput out;
  e.step(1'000'000, {}, out);
  ASSERT_EQ(out.writes.size(), 1U);
  EXPECT_DOUBLE_EQ(out.writes[0].value_um, 6.5);
  EXPECT_DOUBLE_EQ(e.register_state(0).target_um, 10.0);
  EXPECT_DOUBLE_EQ(e.register_state(0).trim_um, -3.5);
  // 10 + 12 = 22 > max_abs 20: refused with an alarm, the register keeps 6.5.
  trim->value_um_ = 12.0;
  e.step(2'000'000, {}, out);
  EXPECT_TRUE(out.writes.empty());
  ASSERT_FALSE(out.alarms.empty());
  EXPECT_EQ(out.alarms[0].code, core::AlarmCode::kOffsetBeyondAbsoluteLimit);
  EXPECT_DOUBLE_EQ(out.alarms[0].value, 22.0);
  EXPECT_DOUBLE_EQ(e.register_state(0).output_um, 6.5);
  // 10 + 9 = 19: admissible, sent.
  trim->value_um_ = 9.0;
  e.step(3'000'000, {}, out);
  EXPECT_DOUBLE_EQ(last_write(out, NAN), 19.0);
  // A NaN trim: refused, nothing changes.
  trim->value_um_ = std::nan("");
  e.step(4'000'000, {}, out);
  EXPECT_TRUE(out.writes.empty());
  ASSERT_FALSE(out.alarms.empty());
  EXPECT_EQ(out.alarms[0].code, core::AlarmCode::kOffsetNonFinite);
  EXPECT_DOUBLE_EQ(e.register_state(0).output_um, 19.0);
}

TEST(EngineTrims, TheStepLimitAppliesToTheSum) {
  std::vector<std::unique_ptr<ce::Module>> mods;
  mods.push_back(std::make_unique<FixedModule>("base", false, 4.0));
  mods.push_back(std::make_unique<FixedModule>("trim", true, 4.0));
  ce::Engine e;
  e.configure(one_register(100.0, 5.0), std::move(mods));
  core::StepOutput out;
  std::vector<double> sent;
  for (int k = 1; k <= 3; ++k) {
    e.step(k * 1'000'000, {}, out);
    sent.push_back(last_write(out, NAN));
  }
  // 0 → 8 in steps of at most 5 µm.
  EXPECT_DOUBLE_EQ(sent[0], 5.0);
  EXPECT_DOUBLE_EQ(sent[1], 8.0);
  EXPECT_TRUE(std::isnan(sent[2]));  // at target: nothing more written
}

TEST(EngineTrims, ARestartDoesNotApplyTheTrimTwice) {
  std::vector<std::byte> state;
  {
    std::vector<std::unique_ptr<ce::Module>> mods;
    mods.push_back(std::make_unique<FixedModule>("base", false, 10.0));
    mods.push_back(std::make_unique<FixedModule>("trim", true, 3.0));
    ce::Engine e;
    e.configure(one_register(100.0, 100.0), std::move(mods));
    core::StepOutput out;
    e.step(1'000'000, {}, out);
    EXPECT_DOUBLE_EQ(last_write(out, NAN), 13.0);
    state.resize(e.state_capacity());
    state.resize(e.export_state(state));
    ASSERT_FALSE(state.empty());
  }
  std::vector<std::unique_ptr<ce::Module>> mods;
  mods.push_back(std::make_unique<FixedModule>("base", false, 10.0));
  mods.push_back(std::make_unique<FixedModule>("trim", true, 3.0));
  ce::Engine e;
  e.configure(one_register(100.0, 100.0), std::move(mods));
  ASSERT_TRUE(e.import_state(state, 5'000'000));
  EXPECT_DOUBLE_EQ(e.register_state(0).output_um, 13.0);
  EXPECT_DOUBLE_EQ(e.register_state(0).target_um, 10.0);  // the saved target has no trim in it
  core::StepOutput out;
  e.step(6'000'000, {}, out);
  e.step(7'000'000, {}, out);
  EXPECT_DOUBLE_EQ(e.register_state(0).output_um, 13.0);  // not 16
  e.resend_all();
  e.step(8'000'000, {}, out);
  EXPECT_DOUBLE_EQ(last_write(out, NAN), 13.0);
}

/// A fitted model: a constant per checkpoint (not applied) and part_trend = 0.02 µm per part ×
/// part, one coefficient per checkpoint: point 0 → 0.02, point 1 → 0.05.
cm::Model trend_model() {
  cm::Term offset;
  offset.spec.name = "offset";
  offset.spec.form = cm::Form::kConstant;
  offset.spec.per = {static_cast<int>(cm::Column::kKind), static_cast<int>(cm::Column::kPoint)};
  offset.groups = {{1.0, 0.0}, {1.0, 1.0}};
  offset.coef = {3.0, -2.0};
  cm::Term trend;
  trend.spec.name = "part_trend";
  trend.spec.form = cm::Form::kLinear;
  trend.spec.column = static_cast<int>(cm::Column::kPart);
  trend.spec.per = {static_cast<int>(cm::Column::kPoint), -1};
  trend.spec.kind_mask = 0x2;
  trend.groups = {{0.0, 0.0}, {1.0, 0.0}};
  trend.coef = {0.02, 0.05};
  return cm::Model({}, {offset, trend});
}

std::string model_toml() {
  return tools::model_io::write_model_toml(trend_model(), cm::AnalysisConfig{}, {"test"});
}

std::string registers_toml() {
  std::string s = "[loopback]\n";
  for (const char* n : {"checkpoint_0", "checkpoint_1", "warn"}) {
    const bool flag = std::string(n) == "warn";
    s += std::string("[[registers]]\nname = \"") + n + "\"\nkind = \"" +
         (flag ? "flag" : "checkpoint") + "\"\nbus = \"loopback\"\nmax_abs_um = 100\n" +
         (flag ? "" : "max_step_um = 50\nmax_rate_um_per_s = 100000\n");
  }
  return s;
}

const char* kApply =
    "[model]\nfile = \"fit/model.toml\"\n"
    "[[model.apply]]\nterm = \"part_trend\"\nregister = \"checkpoint_0\"\npoint = 0\n"
    "[[model.apply]]\nterm = \"part_trend\"\nregister = \"checkpoint_1\"\npoint = 1\ngain = -2\n";

TEST(ModelSection, AFittedTermBecomesTheExpectedTrimAtPartStart) {
  TempDir d;
  d.write("fit/model.toml", model_toml());
  auto r = config::load_file(d.write("a.toml", registers_toml() + kApply));
  ASSERT_TRUE(r.config) << r.diagnostics.to_string();
  const auto* s = model_section(*r.config);
  ASSERT_NE(s, nullptr);
  ASSERT_EQ(s->applies.size(), 2U);
  EXPECT_EQ(s->applies[0].apply.term_index, 1U);
  std::vector<ce::RegisterSpec> specs;
  for (const auto& e : config::registers_section(*r.config).registers) specs.push_back(e.spec);
  std::vector<std::unique_ptr<ce::Module>> mods;
  mods.push_back(make_model_module(*s, specs));
  const auto* m = static_cast<const ModelModule*>(mods[0].get());
  ce::Engine e;
  e.configure(specs, std::move(mods));
  core::StepOutput out;
  // Before the first part start the part is unknown: the term contributes nothing.
  e.step(1'000'000, {}, out);
  EXPECT_DOUBLE_EQ(m->trim_um(0), 0.0);
  const std::vector<core::Event> ev = {
      core::ProgramEvent{2'000'000, core::ProgramEventKind::kPartStart, 25}};
  e.step(2'000'000, ev, out);
  // trim = gain × coef(point) × part: −1 × 0.02 × 25 = −0.5; −2 × 0.05 × 25 = −2.5.
  EXPECT_NEAR(m->trim_um(0), -0.5, 1e-12);
  EXPECT_NEAR(m->trim_um(1), -2.5, 1e-12);
  EXPECT_NEAR(e.register_state(0).output_um, -0.5, 1e-12);
  EXPECT_NEAR(e.register_state(1).output_um, -2.5, 1e-12);
  EXPECT_EQ(e.counters().writes_forwarded, 4U);  // 0 at start-up, then the part-25 trims
  // The part does not change: no new evaluation, no write.
  e.step(3'000'000, ev, out);
  EXPECT_TRUE(out.writes.empty());
  // Restart: state restored, the trim is published again once, not added to the saved value.
  std::vector<std::byte> state(e.state_capacity());
  state.resize(e.export_state(state));
  std::vector<std::unique_ptr<ce::Module>> mods2;
  mods2.push_back(make_model_module(*s, specs));
  ce::Engine e2;
  e2.configure(specs, std::move(mods2));
  ASSERT_TRUE(e2.import_state(state, 4'000'000));
  e2.step(5'000'000, {}, out);
  EXPECT_NEAR(e2.register_state(0).output_um, -0.5, 1e-12);
  EXPECT_NEAR(e2.register_state(1).output_um, -2.5, 1e-12);
}

TEST(ModelSection, SteppingAllocatesNothingEvenWhenEvaluatingEachCycle) {
  TempDir d;
  d.write("fit/model.toml", model_toml());
  const std::string text = registers_toml() + std::string(kApply);
  auto r = config::load_file(
      d.write("a.toml", text.substr(0, text.find("[model]")) +
                            "[model]\nfile = \"fit/model.toml\"\nupdate = \"cycle\"\n" +
                            text.substr(text.find("[[model.apply]]"))));
  ASSERT_TRUE(r.config) << r.diagnostics.to_string();
  std::vector<ce::RegisterSpec> specs;
  for (const auto& e : config::registers_section(*r.config).registers) specs.push_back(e.spec);
  std::vector<std::unique_ptr<ce::Module>> mods;
  mods.push_back(make_model_module(*model_section(*r.config), specs));
  const auto* m = static_cast<const ModelModule*>(mods[0].get());
  ce::Engine e;
  e.configure(specs, std::move(mods));
  core::StepOutput out;
  double sum_um = 0.0;
  const nccomp::test::AllocationScope scope;
  for (std::int32_t k = 1; k <= 200; ++k) {
    const core::Event ev[] = {
        core::ProgramEvent{k * 1'000'000LL, core::ProgramEventKind::kPartStart, k / 20}};
    e.step(k * 1'000'000LL, ev, out);
    sum_um += m->trim_um(1);
  }
  EXPECT_EQ(scope.count(), 0U);
  // Last part 10: −2 × 0.05 × 10 = −1.
  EXPECT_NEAR(m->trim_um(1), -1.0, 1e-12);
  EXPECT_NEAR(e.register_state(1).output_um, -1.0, 1e-12);
  EXPECT_LT(sum_um, 0.0);
}

TEST(ModelSection, ErrorsNameFileLineAndKey) {
  TempDir d;
  d.write("fit/model.toml", model_toml());
  const std::string bad_term =
      "[model]\nfile = \"fit/model.toml\"\n[[model.apply]]\nterm = \"tool_wear\"\n"
      "register = \"checkpoint_0\"\n";
  auto r = config::load_file(d.write("a.toml", registers_toml() + bad_term));
  ASSERT_FALSE(r.config);
  const std::string err = r.diagnostics.to_string();
  EXPECT_NE(err.find("a.toml:"), std::string::npos) << err;
  EXPECT_NE(err.find("model.apply[0].term"), std::string::npos) << err;
  EXPECT_NE(err.find("no term 'tool_wear'"), std::string::npos) << err;

  auto r2 = config::load_file(d.write(
      "b.toml", registers_toml() + "[model]\nfile = \"missing.toml\"\n[[model.apply]]\n"
                                   "term = \"part_trend\"\nregister = \"checkpoint_0\"\n"));
  ASSERT_FALSE(r2.config);
  EXPECT_NE(r2.diagnostics.to_string().find("model.file"), std::string::npos)
      << r2.diagnostics.to_string();

  auto r3 = config::load_file(d.write(
      "c.toml", registers_toml() + "[model]\nfile = \"fit/model.toml\"\n[[model.apply]]\n"
                                   "term = \"part_trend\"\nregister = \"warn\"\n"
                                   "[[model.apply]]\nterm = \"part_trend\"\nregister = \"nope\"\n"));
  ASSERT_FALSE(r3.config);
  const std::string e3 = r3.diagnostics.to_string();
  EXPECT_NE(e3.find("'warn' is a flag"), std::string::npos) << e3;
  EXPECT_NE(e3.find("no [[registers]] entry named 'nope'"), std::string::npos) << e3;

  auto r4 = config::load_file(d.write(
      "d.toml", registers_toml() + "[model]\nfile = \"fit/model.toml\"\n[[model.apply]]\n"
                                   "term = \"part_trend\"\nregister = \"checkpoint_0\"\n"
                                   "colour = 1\n"));
  ASSERT_FALSE(r4.config);
  const std::string e4 = r4.diagnostics.to_string();
  EXPECT_NE(e4.find("d.toml:26:10: model.apply[0].colour: unknown key"), std::string::npos)
      << e4;
}

/// position_x: poly degree 2 in u = x / 100 (coef 2, 0.5); periodic_z: sine of period 40 mm
/// (coef 1 on sin, 0 on cos); path_wear: 0.01 µm per mm of cut path; angle_term: linear in
/// angle_deg (which the loop does not know).
cm::Model position_model() {
  cm::Term px;
  px.spec.name = "position_x";
  px.spec.form = cm::Form::kPoly;
  px.spec.column = static_cast<int>(cm::Column::kX);
  px.spec.degree = 2;
  px.spec.center = 0.0;
  px.spec.scale = 100.0;
  px.groups = {{0.0, 0.0}};
  px.coef = {2.0, 0.5};
  cm::Term pz;
  pz.spec.name = "periodic_z";
  pz.spec.form = cm::Form::kSine;
  pz.spec.column = static_cast<int>(cm::Column::kZ);
  pz.spec.scale = 40.0;
  pz.groups = {{0.0, 0.0}};
  pz.coef = {1.0, 0.0};
  cm::Term wear;
  wear.spec.name = "path_wear";
  wear.spec.form = cm::Form::kLinear;
  wear.spec.column = static_cast<int>(cm::Column::kPath);
  wear.groups = {{0.0, 0.0}};
  wear.coef = {0.01};
  cm::Term angle;
  angle.spec.name = "angle_term";
  angle.spec.form = cm::Form::kLinear;
  angle.spec.column = static_cast<int>(cm::Column::kAngle);
  angle.groups = {{0.0, 0.0}};
  angle.coef = {0.1};
  return cm::Model({}, {px, pz, wear, angle});
}

core::AxisSample sample(double x, double z, std::int32_t tool, bool cutting) {
  core::AxisSample a;
  a.position_mm[0] = x;
  a.position_mm[1] = 0.0;
  a.position_mm[2] = z;
  a.tool = tool;
  a.cutting = cutting;
  return a;
}

TEST(ModelModuleContext, PositionAndPeriodicTermsFollowTheAxisSamplesEachCycle) {
  ModelApply ax;
  ax.term_index = 0;
  ax.register_index = 0;
  ModelApply az;
  az.term_index = 1;
  az.register_index = 1;
  ModelModule m(position_model(), {ax, az}, true, 0);
  core::StepOutput out;
  // No axis sample yet: the positions are unknown, the terms contribute nothing.
  m.step(1'000'000, {}, out);
  EXPECT_DOUBLE_EQ(m.trim_um(0), 0.0);
  EXPECT_DOUBLE_EQ(m.trim_um(1), 0.0);
  // x = 50: u = 0.5 → 2·0.5 + 0.5·0.25 = 1.125 µm, trim −1.125; z = 10: sin(2π·10/40) = 1.
  const core::Event e1[] = {sample(50.0, 10.0, 1, true)};
  m.step(2'000'000, e1, out);
  EXPECT_NEAR(m.trim_um(0), -1.125, 1e-12);
  EXPECT_NEAR(m.trim_um(1), -1.0, 1e-12);
  // x = −100: u = −1 → −2 + 0.5 = −1.5 µm, trim +1.5; z = 30: sin(3π/2) = −1 → trim +1.
  const core::Event e2[] = {sample(-100.0, 30.0, 1, true)};
  m.step(3'000'000, e2, out);
  EXPECT_NEAR(m.trim_um(0), 1.5, 1e-12);
  EXPECT_NEAR(m.trim_um(1), 1.0, 1e-12);
  // Published each cycle, one trim per entry (the module appends; the engine clears `out`).
  ASSERT_EQ(out.trims.size(), 6U);
  EXPECT_NEAR(out.trims[4].value_um, 1.5, 1e-12);
  EXPECT_EQ(out.trims[5].register_index, 1U);
}

TEST(ModelModuleContext, CutPathGrowsOnlyWhileCuttingResetsOnToolChangeAndSurvivesARestart) {
  ModelApply aw;
  aw.term_index = 2;
  aw.register_index = 0;
  ModelModule m(position_model(), {aw}, true, 0);
  core::StepOutput out;
  std::int64_t t = 0;
  // 101 cutting samples 1 mm apart along X: 100 mm of cut path → 0.01 × 100 = 1 µm.
  for (int k = 0; k <= 100; ++k) {
    const core::Event e[] = {sample(static_cast<double>(k), 0.0, 7, true)};
    m.step(t += 1'000'000, e, out);
  }
  EXPECT_NEAR(m.cut_path_mm(), 100.0, 1e-9);
  EXPECT_NEAR(m.trim_um(0), -1.0, 1e-12);
  // A rapid back to x = 0 and 50 non-cutting samples: no path.
  for (int k = 0; k < 50; ++k) {
    const core::Event e[] = {sample(100.0 - 2.0 * k, 0.0, 7, false)};
    m.step(t += 1'000'000, e, out);
  }
  EXPECT_NEAR(m.cut_path_mm(), 100.0, 1e-9);
  // The program path, where the NC publishes it, is used instead of the XYZ distance.
  core::AxisSample p1 = sample(0.0, 0.0, 7, true);
  p1.program_path_mm = 500.0;
  core::AxisSample p2 = sample(0.0, 0.0, 7, true);  // no axis motion...
  p2.program_path_mm = 525.0;                        // ...but 25 mm along the program path
  const core::Event ep1[] = {p1};
  const core::Event ep2[] = {p2};
  m.step(t += 1'000'000, ep1, out);
  m.step(t += 1'000'000, ep2, out);
  EXPECT_NEAR(m.cut_path_mm(), 125.0, 1e-9);
  EXPECT_NEAR(m.trim_um(0), -1.25, 1e-12);
  // Restart: the path comes back from the state.
  std::vector<std::byte> state(m.state_capacity());
  state.resize(m.save_state(state));
  ModelModule m2(position_model(), {aw}, true, 0);
  ASSERT_TRUE(m2.load_state(state));
  EXPECT_NEAR(m2.cut_path_mm(), 125.0, 1e-9);
  m2.step(t += 1'000'000, {}, out);
  EXPECT_NEAR(m2.trim_um(0), -1.25, 1e-12);
  // A state with a non-finite path is refused.
  std::vector<std::byte> bad = state;
  const double nan = std::nan("");
  std::memcpy(bad.data() + 16, &nan, 8);
  ModelModule m3(position_model(), {aw}, true, 0);
  EXPECT_FALSE(m3.load_state(bad));
  // Tool change (event): a new tool's path starts at 0.
  const core::Event tc[] = {core::ToolChange{t, 8, false}};
  m2.step(t += 1'000'000, tc, out);
  EXPECT_DOUBLE_EQ(m2.cut_path_mm(), 0.0);
  EXPECT_DOUBLE_EQ(m2.trim_um(0), 0.0);
  // A tool change seen only in the axis samples (no event) resets the path too.
  for (int k = 0; k <= 10; ++k) {
    const core::Event e[] = {sample(static_cast<double>(k), 0.0, 8, true)};
    m2.step(t += 1'000'000, e, out);
  }
  EXPECT_NEAR(m2.cut_path_mm(), 10.0, 1e-9);
  const core::Event e9[] = {sample(10.0, 0.0, 9, true)};
  m2.step(t += 1'000'000, e9, out);
  EXPECT_DOUBLE_EQ(m2.cut_path_mm(), 0.0);
}

TEST(ModelSection, TermsTheLoopCannotEvaluateAsConfiguredAreRefused) {
  TempDir d;
  d.write("fit/model.toml",
          tools::model_io::write_model_toml(position_model(), cm::AnalysisConfig{}, {"test"}));
  const auto load = [&](const std::string& name, const std::string& update,
                        const std::string& term) {
    return config::load_file(d.write(
        name, registers_toml() + "[model]\nfile = \"fit/model.toml\"\nupdate = \"" + update +
                  "\"\n[[model.apply]]\nterm = \"" + term + "\"\nregister = \"checkpoint_0\"\n"));
  };
  auto r1 = load("a.toml", "part", "position_x");
  ASSERT_FALSE(r1.config);
  EXPECT_NE(r1.diagnostics.to_string().find(
                "model.apply[0].term: term 'position_x' depends on x_mm, which changes within a "
                "part: set update = \"cycle\""),
            std::string::npos)
      << r1.diagnostics.to_string();
  auto r2 = load("b.toml", "part", "path_wear");
  ASSERT_FALSE(r2.config);
  EXPECT_NE(r2.diagnostics.to_string().find("depends on path_mm"), std::string::npos)
      << r2.diagnostics.to_string();
  auto r3 = load("c.toml", "cycle", "angle_term");
  ASSERT_FALSE(r3.config);
  EXPECT_NE(r3.diagnostics.to_string().find(
                "depends on angle_deg, which the daemon's loop does not know"),
            std::string::npos)
      << r3.diagnostics.to_string();
  for (const char* ok : {"position_x", "periodic_z", "path_wear"}) {
    auto r = load(std::string("ok_") + ok + ".toml", "cycle", ok);
    EXPECT_TRUE(r.config) << ok << ": " << r.diagnostics.to_string();
  }
}

}  // namespace
}  // namespace nccomp::daemon::sections
