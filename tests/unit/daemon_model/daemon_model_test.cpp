// GIVEN an engine with a module owning a register and another publishing an additive trim, or a
// daemon config with [model] and a model.toml with known coefficients, WHEN the engine steps,
// THEN the register gets base + trim through its limiter, inadmissible sums change nothing, a
// restart does not apply the trim twice, and config errors name file, line and key.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <fstream>
#include <map>
#include <memory>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "core/engine/engine.hpp"
#include "core/model/model.hpp"
#include "core/model/model_module.hpp"
#include "daemon/commands/model.hpp"
#include "daemon/config/builtin_sections.hpp"
#include "daemon/measurement_log.hpp"
#include "daemon/sections/model/model_section.hpp"
#include "formats/model/model_io.hpp"
#include "tests/support/alloc_counter.hpp"
#include "tests/unit/daemon_modules/temp_dir.hpp"

namespace nccomp::daemon::sections {
namespace {

namespace ce = core::engine;
namespace cm = core::model;
using cm::ModelApply;
using cm::ModelModule;
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
  EXPECT_DOUBLE_EQ(last_write(out, std::nan("")), 19.0);
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
    sent.push_back(last_write(out, std::nan("")));
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
    EXPECT_DOUBLE_EQ(last_write(out, std::nan("")), 13.0);
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
  EXPECT_DOUBLE_EQ(last_write(out, std::nan("")), 13.0);
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
  return formats::model_io::write_model_toml(trend_model(), cm::AnalysisConfig{}, {"test"});
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

// [model.shadow]: the keys reach the options; a min_parts whose sign test can never pass at alpha
// and an unknown promote are refused at their line with the key path.
TEST(ModelSection, ShadowKeysAndAMinPartsThatCanNeverPass) {
  TempDir d;
  d.write("fit/model.toml", model_toml());
  auto r = config::load_file(
      d.write("a.toml", registers_toml() + kApply +
                            "[model.shadow]\nmin_parts = 12\nalpha = 0.01\nmargin_um = 0.2\n"
                            "promote = \"operator\"\nhistory_size = 50\n"));
  ASSERT_TRUE(r.config) << r.diagnostics.to_string();
  const ShadowOptions& o = model_section(*r.config)->shadow;
  EXPECT_EQ(o.min_parts, 12);
  EXPECT_DOUBLE_EQ(o.alpha, 0.01);
  EXPECT_DOUBLE_EQ(o.margin_um, 0.2);
  EXPECT_EQ(o.promote, ShadowPromote::kOperator);
  EXPECT_EQ(o.history_size, 50);
  // 4 parts: the smallest p-value is 1/16 > 0.05.
  auto bad = config::load_file(d.write(
      "b.toml",
      registers_toml() + kApply + "[model.shadow]\nmin_parts = 4\npromote = \"sometimes\"\n"));
  ASSERT_FALSE(bad.config);
  const std::string err = bad.diagnostics.to_string();
  EXPECT_NE(err.find("b.toml:"), std::string::npos) << err;
  EXPECT_NE(err.find("model.shadow.min_parts: min_parts = 4 can never pass the sign test at "
                     "alpha = 0.05: at least 5 parts are needed"),
            std::string::npos)
      << err;
  EXPECT_NE(err.find("model.shadow.promote"), std::string::npos) << err;
}

// Issue 18: a model file with several errors is refused at the file key, and each of its errors
// is listed at its own line of the model file (the section kept only the first, inside one
// message at the file key).
TEST(ModelSection, EveryErrorOfTheModelFileIsListedAtItsLine) {
  TempDir d;
  const std::string model =
      d.write("fit/model.toml",
              "[model]\nalpha = 0.9\n[[model.term]]\nname = \"\"\nform = \"constant\"\n"
              "groups = [[0, 0]]\ncoef_um = [1]\n");
  auto r = config::load_file(d.write("a.toml", registers_toml() + kApply));
  ASSERT_FALSE(r.config);
  std::vector<int> lines;
  for (const auto& item : r.diagnostics.items()) {
    if (item.where.file == model) lines.push_back(item.where.line);
  }
  EXPECT_EQ(lines, (std::vector<int>{2, 4})) << r.diagnostics.to_string();
  EXPECT_NE(r.diagnostics.to_string().find("model.file: cannot load the model " + model),
            std::string::npos)
      << r.diagnostics.to_string();
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

  auto r2 = config::load_file(
      d.write("b.toml", registers_toml() + "[model]\nfile = \"missing.toml\"\n[[model.apply]]\n"
                                           "term = \"part_trend\"\nregister = \"checkpoint_0\"\n"));
  ASSERT_FALSE(r2.config);
  EXPECT_NE(r2.diagnostics.to_string().find("model.file"), std::string::npos)
      << r2.diagnostics.to_string();

  auto r3 = config::load_file(d.write(
      "c.toml", registers_toml() + "[model]\nfile = \"fit/model.toml\"\n[[model.apply]]\n"
                                   "term = \"part_trend\"\nregister = \"warn\"\npoint = 0\n"
                                   "[[model.apply]]\nterm = \"part_trend\"\nregister = \"nope\"\n"
                                   "point = 1\n"));
  ASSERT_FALSE(r3.config);
  const std::string e3 = r3.diagnostics.to_string();
  EXPECT_NE(e3.find("'warn' is a flag"), std::string::npos) << e3;
  EXPECT_NE(e3.find("no [[registers]] entry named 'nope'"), std::string::npos) << e3;

  auto r4 = config::load_file(
      d.write("d.toml", registers_toml() + "[model]\nfile = \"fit/model.toml\"\n[[model.apply]]\n"
                                           "term = \"part_trend\"\nregister = \"checkpoint_0\"\n"
                                           "colour = 1\n"));
  ASSERT_FALSE(r4.config);
  const std::string e4 = r4.diagnostics.to_string();
  EXPECT_NE(e4.find("d.toml:26:10: model.apply[0].colour: unknown key"), std::string::npos) << e4;
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
  ModelModule m(position_model(), {ax, az}, true);
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

std::vector<ce::RegisterSpec> two_registers() {
  auto a = one_register(100.0, 100.0);
  auto b = a;
  b[0].name = "checkpoint_1";
  a.push_back(b[0]);
  return a;
}

/// An engine with one ModelModule (each cycle) and, optionally, more modules.
std::unique_ptr<ce::Engine> model_engine(cm::Model model, std::vector<ModelApply> applies,
                                         const ModelModule** out = nullptr,
                                         std::vector<std::unique_ptr<ce::Module>> more = {},
                                         ce::EngineOptions options = {}) {
  std::vector<std::unique_ptr<ce::Module>> mods;
  auto m = std::make_unique<ModelModule>(std::move(model), std::move(applies), true);
  if (out != nullptr) *out = m.get();
  mods.push_back(std::move(m));
  for (auto& x : more) mods.push_back(std::move(x));
  auto e = std::make_unique<ce::Engine>();
  e->configure(two_registers(), std::move(mods), options);
  return e;
}

TEST(ModelModuleContext, CutPathIsTheEnginesPerToolAndSurvivesARestart) {
  ModelApply aw;
  aw.term_index = 2;
  aw.register_index = 0;
  const ModelModule* m = nullptr;
  auto e = model_engine(position_model(), {aw}, &m);
  ASSERT_EQ(&m->context(), &e->context());  // the engine's context, not a copy
  core::StepOutput out;
  std::int64_t t = 0;
  auto step = [&](ce::Engine& eng, std::vector<core::Event> ev) {
    eng.step(t += 1'000'000, ev, out);
  };
  // 101 cutting samples 1 mm apart along X: 100 mm of cut path → 0.01 × 100 = 1 µm.
  for (int k = 0; k <= 100; ++k) step(*e, {sample(static_cast<double>(k), 0.0, 7, true)});
  EXPECT_NEAR(e->context().cut_path_mm(), 100.0, 1e-9);
  EXPECT_NEAR(m->trim_um(0), -1.0, 1e-12);
  EXPECT_NEAR(e->register_state(0).output_um, -1.0, 1e-12);
  // A rapid back to x = 0: no path.
  for (int k = 0; k < 50; ++k) step(*e, {sample(100.0 - 2.0 * k, 0.0, 7, false)});
  EXPECT_NEAR(e->context().cut_path_mm(), 100.0, 1e-9);
  // The program path, where the NC publishes it, is used instead of the XYZ distance.
  core::AxisSample p1 = sample(0.0, 0.0, 7, true);
  p1.program_path_mm = 500.0;
  core::AxisSample p2 = sample(0.0, 0.0, 7, true);  // no axis motion...
  p2.program_path_mm = 525.0;                       // ...but 25 mm along the program path
  step(*e, {p1});
  step(*e, {p2});
  EXPECT_NEAR(m->trim_um(0), -1.25, 1e-12);
  // Restart: the engine's state carries the path; the trim is published again, once.
  std::vector<std::byte> state(e->state_capacity());
  state.resize(e->export_state(state));
  const ModelModule* m2 = nullptr;
  auto e2 = model_engine(position_model(), {aw}, &m2);
  ASSERT_TRUE(e2->import_state(state, t + 1'000'000));
  EXPECT_NEAR(e2->context().cut_path_mm(), 125.0, 1e-9);
  step(*e2, {});
  EXPECT_NEAR(m2->trim_um(0), -1.25, 1e-12);
  EXPECT_NEAR(e2->register_state(0).output_um, -1.25, 1e-12);
  // Another tool: its own path from 0; tool 7 back: its 125 mm continue (as creep counts).
  step(*e2, {core::ToolChange{t, 8, false}});
  EXPECT_DOUBLE_EQ(m2->trim_um(0), 0.0);
  for (int k = 0; k <= 10; ++k) step(*e2, {sample(static_cast<double>(k), 0.0, 8, true)});
  EXPECT_NEAR(m2->trim_um(0), -0.1, 1e-12);
  step(*e2, {sample(10.0, 0.0, 8, false), core::ToolChange{t, 7, false}});
  EXPECT_NEAR(m2->trim_um(0), -1.25, 1e-12);
  // A tool the axis samples name without an event, never seen before: 0.
  step(*e2, {sample(10.0, 0.0, 9, true)});
  EXPECT_DOUBLE_EQ(m2->trim_um(0), 0.0);
  // An entry that fixes the tool evaluates that tool's path whatever is in the spindle.
  ModelApply fixed = aw;
  fixed.tool = 8;
  const ModelModule* m3 = nullptr;
  auto e3 = model_engine(position_model(), {fixed}, &m3);
  ASSERT_TRUE(e3->import_state(state, t + 1'000'000));
  step(*e3, {});
  EXPECT_TRUE(std::isnan(e3->context().cut_path_mm(8)));  // state from before tool 8 was used
  EXPECT_DOUBLE_EQ(m3->trim_um(0), 0.0);
}

TEST(ModelModuleContext, CuttingAdvancesTheStateGenerationEvery10MmNotEveryMm) {
  ModelApply ax;  // a position term: nothing the model applies uses the path
  ax.term_index = 0;
  ax.register_index = 0;
  auto e = model_engine(position_model(), {ax});
  core::StepOutput out;
  std::int64_t t = 0;
  e->step(t += 1'000'000, std::vector<core::Event>{sample(0.0, 0.0, 1, true)}, out);
  e->step(t += 1'000'000, std::vector<core::Event>{sample(0.1, 0.0, 1, true)}, out);
  const auto c0 = e->context().generation();
  // 1000 samples 0.1 mm apart: 100 mm. The module adds nothing to the state generation (it
  // keeps no state; the first version advanced it every 1 mm), the context every 10 mm.
  for (int k = 2; k <= 1001; ++k) {
    e->step(t += 1'000'000, std::vector<core::Event>{sample(0.1 * k, 0.0, 1, true)}, out);
  }
  EXPECT_NEAR(e->context().cut_path_mm(), 100.1, 1e-6);
  EXPECT_EQ(e->module(0).state_generation(), 0U);
  EXPECT_EQ(e->context().generation() - c0, 10U);
}

/// thermal_drift: 4 µm × (1 − exp(−time_s / 5400 s)), one coefficient.
cm::Model warmup_model() {
  cm::Term w;
  w.spec.name = "thermal_drift";
  w.spec.form = cm::Form::kExpRise;
  w.spec.column = static_cast<int>(cm::Column::kTime);
  w.spec.scale = 5400.0;
  w.groups = {{0.0, 0.0}};
  w.coef = {4.0};
  return cm::Model({}, {w});
}

/// Emits one contour record at each step with a ProbeMeasurement (what S1 does).
class ProbeLog final : public ce::Module {
 public:
  std::string_view name() const noexcept override { return "probe"; }
  void attach(const ce::RegisterTable&) override {}
  void step(core::TimeNs, std::span<const core::Event> events,
            core::StepOutput& out) noexcept override {
    for (const auto& e : events) {
      if (const auto* p = std::get_if<core::ProbeMeasurement>(&e)) {
        core::MeasurementRecord r;
        r.time_ns = p->time_ns;
        r.tool = 1;
        r.kind = core::MeasurementKind::kContour;
        out.records.push(r);
      }
    }
  }
};

double warmup_um(double t_s) { return 4.0 * (1.0 - std::exp(-t_s / 5400.0)); }

TEST(ModelTimeOrigin, AWarmUpTermEvaluatesTheSameAfterARestartAsTheLogsTimeS) {
  constexpr std::int64_t kS = 1'000'000'000;
  ModelApply a;
  a.register_index = 0;
  auto make = [&](const ModelModule** m) {
    std::vector<std::unique_ptr<ce::Module>> more;
    more.push_back(std::make_unique<ProbeLog>());
    return model_engine(warmup_model(), {a}, m, std::move(more));
  };
  const ModelModule* m1 = nullptr;
  auto e1 = make(&m1);
  core::StepOutput out;
  // The daemon starts 1000 s after boot; the machine stands until 1200 s (boot-based clock).
  e1->step(1000 * kS, std::vector<core::Event>{sample(0.0, 0.0, 1, false)}, out);
  e1->step(1100 * kS, std::vector<core::Event>{sample(0.0, 0.0, 1, false)}, out);
  EXPECT_NEAR(m1->trim_um(0), -warmup_um(100.0), 1e-12);  // time since the daemon's start
  // 1200 s: the first motion, the warm start. 3600 s later, a probe record.
  e1->step(1200 * kS, std::vector<core::Event>{sample(5.0, 0.0, 1, false)}, out);
  EXPECT_NEAR(m1->trim_um(0), 0.0, 1e-12);
  e1->step(4800 * kS,
           std::vector<core::Event>{sample(6.0, 0.0, 1, false),
                                    core::ProbeMeasurement{4800 * kS, 1, 0, 0.0, 0.0, 1.0, {}}},
           out);
  ASSERT_EQ(out.records.size(), 1U);
  EXPECT_EQ(out.records[0].time_ns, 3600 * kS);  // the log's time_s
  EXPECT_NEAR(m1->trim_um(0), -warmup_um(3600.0), 1e-12);
  std::vector<std::byte> state(e1->state_capacity());
  state.resize(e1->export_state(state));

  // nccompd restarts: 100 s later on the same clock. The term and the log continue from the
  // same origin, as if the daemon had run on: 3700 s since the warm start, not 4900 s since boot.
  const ModelModule* m2 = nullptr;
  auto e2 = make(&m2);
  ASSERT_TRUE(e2->import_state(state, 4900 * kS));
  e2->step(4900 * kS,
           std::vector<core::Event>{core::ProbeMeasurement{4900 * kS, 1, 0, 0.0, 0.0, 1.0, {}}},
           out);
  EXPECT_NEAR(m2->trim_um(0), -warmup_um(3700.0), 1e-12);
  ASSERT_EQ(out.records.size(), 1U);
  EXPECT_EQ(out.records[0].time_ns, 3700 * kS);
  // The register follows (through its limiter, which restarted at the restored value).
  e2->step(4901 * kS, {}, out);
  EXPECT_NEAR(e2->register_state(0).output_um, -warmup_um(3701.0), 1e-12);
  // (The same term on the time since boot would be off by this much.)
  EXPECT_GT(warmup_um(4900.0) - warmup_um(3700.0), 0.3);

  // A reboot (the clock starts again, now 60 s): the time goes on from 3600 s, and the machine
  // is cold: its first motion is a warm start and the warm-up term starts again from 0.
  const ModelModule* m3 = nullptr;
  auto e3 = make(&m3);
  ASSERT_TRUE(e3->import_state(state, 60 * kS));
  e3->step(60 * kS, std::vector<core::Event>{sample(6.0, 0.0, 1, false)}, out);
  EXPECT_NEAR(m3->trim_um(0), -warmup_um(3600.0), 1e-12);
  e3->step(70 * kS, std::vector<core::Event>{sample(7.0, 0.0, 1, false)}, out);
  EXPECT_NEAR(m3->trim_um(0), 0.0, 1e-12);
  e3->step(670 * kS, std::vector<core::Event>{sample(8.0, 0.0, 1, false)}, out);
  EXPECT_NEAR(m3->trim_um(0), -warmup_um(600.0), 1e-12);
}

TEST(ModelSection, TermsTheLoopCannotEvaluateAsConfiguredAreRefused) {
  TempDir d;
  d.write("fit/model.toml",
          formats::model_io::write_model_toml(position_model(), cm::AnalysisConfig{}, {"test"}));
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

/// The two new kinds of term of the analysis (issue 21): temp_c*x_mm, an interaction (basis
/// temp_c − 20, x_mm − 100, their product; coef 1, 0.01, 0.001), and thermal_drift linear in
/// temp_c per point on calib rows (point 0 → 0.5, 1 → −0.3, 2 → 0.1 µm/°C).
cm::Model interaction_and_group_model() {
  cm::Term screw;
  screw.spec.name = "temp_c*x_mm";
  screw.spec.form = cm::Form::kInteraction;
  screw.spec.column = static_cast<int>(cm::Column::kTemp);
  screw.spec.column_b = static_cast<int>(cm::Column::kX);
  screw.spec.center = 20.0;
  screw.spec.center_b = 100.0;
  screw.groups = {{0.0, 0.0}};
  screw.coef = {1.0, 0.01, 0.001};
  cm::Term drift;
  drift.spec.name = "thermal_drift";
  drift.spec.form = cm::Form::kLinear;
  drift.spec.column = static_cast<int>(cm::Column::kTemp);
  drift.spec.per = {static_cast<int>(cm::Column::kPoint), -1};
  drift.spec.kind_mask = 0x4;
  drift.groups = {{0.0, 0.0}, {1.0, 0.0}, {2.0, 0.0}};
  drift.coef = {0.5, -0.3, 0.1};
  return cm::Model({}, {screw, drift});
}

/// "name:LINE:8: " of the first `term = ` line of `text` (the value starts in column 8).
std::string term_where(const std::string& name, const std::string& text) {
  const std::size_t at = text.find("\nterm = ");
  const auto line = std::count(text.begin(), text.begin() + static_cast<std::ptrdiff_t>(at), '\n');
  return name + ":" + std::to_string(line + 2) + ":8: ";
}

TEST(ModelSection, AnInteractionWithAPositionNeedsUpdateCycleWhicheverColumnIsThePosition) {
  TempDir d;
  d.write("fit/model.toml", formats::model_io::write_model_toml(interaction_and_group_model(),
                                                                cm::AnalysisConfig{}, {"test"}));
  const auto text = [](const std::string& update) {
    return registers_toml() + "[model]\nfile = \"fit/model.toml\"\nupdate = \"" + update +
           "\"\n[[model.apply]]\nterm = \"temp_c*x_mm\"\nregister = \"checkpoint_0\"\n";
  };
  // x_mm is the interaction's second column: it changes within a part.
  auto r = config::load_file(d.write("a.toml", text("part")));
  EXPECT_FALSE(r.config);
  const std::string err = r.diagnostics.to_string();
  EXPECT_NE(err.find(term_where("a.toml", text("part")) +
                     "model.apply[0].term: term 'temp_c*x_mm' depends on x_mm, which changes "
                     "within a part: set update = \"cycle\" in [model]"),
            std::string::npos)
      << err;
  auto ok = config::load_file(d.write("b.toml", text("cycle")));
  ASSERT_TRUE(ok.config) << ok.diagnostics.to_string();
  auto e = config::build_engine(*ok.config);
  const auto* m = static_cast<const ModelModule*>(&e->module(0));
  ASSERT_EQ(m->name(), "model");
  core::StepOutput out;
  // 25 °C at x = 150: 1·5 + 0.01·50 + 0.001·5·50 = 5.75 µm, trim −5.75.
  e->step(
      1'000'000'000,
      std::vector<core::Event>{core::TemperatureSample{0, 0, 25.0}, sample(150.0, 0.0, 1, true)},
      out);
  EXPECT_NEAR(m->trim_um(0), -5.75, 1e-12);
  // The entry chooses it by its column as model.toml writes it, a*b.
  auto by_column = config::load_file(
      d.write("c.toml", text("cycle") + "column = \"temp_c*x_mm\"\nform = \"interaction\"\n"));
  EXPECT_TRUE(by_column.config) << by_column.diagnostics.to_string();
}

// Issue 21: an angle profile × wear term (contact_angle*tool_wear, form profile_wear) needs the
// entry's angle and, as its path grows within a part, update = "cycle".
TEST(ModelSection, AnAngleProfileTimesWearNeedsTheEntrysAngleAndUpdateCycle) {
  cm::Term t;
  t.spec.name = "contact_angle*tool_wear";
  t.spec.form = cm::Form::kProfileWear;
  t.spec.column = static_cast<int>(cm::Column::kAngle);
  t.spec.column_b = static_cast<int>(cm::Column::kPath);
  t.spec.center = 30.0;
  t.spec.scale = 20.0;
  t.spec.kind_mask = 0x2;
  t.groups = {{0.0, 0.0}};
  t.coef = {0.002, 0.001, 0.0005};
  TempDir d;
  d.write("fit/model.toml",
          formats::model_io::write_model_toml(cm::Model({}, {t}), cm::AnalysisConfig{}, {"test"}));
  const auto text = [](const std::string& update, const std::string& angle) {
    return registers_toml() + "[model]\nfile = \"fit/model.toml\"\nupdate = \"" + update +
           "\"\n[[model.apply]]\nterm = \"contact_angle*tool_wear\"\nregister = "
           "\"checkpoint_0\"\n" +
           angle;
  };
  const std::string no_angle = text("cycle", "");
  auto r = config::load_file(d.write("a.toml", no_angle));
  EXPECT_FALSE(r.config);
  EXPECT_NE(r.diagnostics.to_string().find(
                term_where("a.toml", no_angle) +
                "model.apply[0].term: term 'contact_angle*tool_wear' depends on angle_deg, which "
                "the daemon's loop does not know"),
            std::string::npos)
      << r.diagnostics.to_string();
  const std::string per_part = text("part", "angle_deg = 50\n");
  r = config::load_file(d.write("b.toml", per_part));
  EXPECT_FALSE(r.config);
  EXPECT_NE(r.diagnostics.to_string().find(
                term_where("b.toml", per_part) +
                "model.apply[0].term: term 'contact_angle*tool_wear' depends on path_mm, which "
                "changes within a part: set update = \"cycle\" in [model]"),
            std::string::npos)
      << r.diagnostics.to_string();
  auto ok = config::load_file(d.write("c.toml", text("cycle", "angle_deg = 50\n")));
  ASSERT_TRUE(ok.config) << ok.diagnostics.to_string();
  auto e = config::build_engine(*ok.config);
  const auto* m = static_cast<const ModelModule*>(&e->module(0));
  core::StepOutput out;
  // 101 cutting samples 1 mm apart: 100 mm of path. u = (50 − 30) / 20 = 1:
  // (0.002 + 0.001 + 0.0005) × 100 = 0.35 µm, trim −0.35.
  for (int k = 0; k <= 100; ++k) {
    e->step((k + 1) * 1'000'000LL, std::vector<core::Event>{sample(k, 0.0, 1, true)}, out);
  }
  EXPECT_NEAR(m->trim_um(0), -0.35, 1e-12);
}

/// A term fitted on rows of one kind evaluates to 0 for every other kind (core/model/model.cpp):
/// an entry of another kind must be refused, not accepted to apply nothing. thermal_drift of
/// interaction_and_group_model() is fitted on calib rows only.
TEST(ModelSection, ATermFittedOnOtherKindsIsRefusedNotAppliedAsZero) {
  TempDir d;
  d.write("fit/model.toml", formats::model_io::write_model_toml(interaction_and_group_model(),
                                                                cm::AnalysisConfig{}, {"test"}));
  const auto text = [](const std::string& kind) {
    return registers_toml() +
           "[model]\nfile = \"fit/model.toml\"\nupdate = \"cycle\"\n[[model.apply]]\n"
           "term = \"thermal_drift\"\nregister = \"checkpoint_0\"\npoint = 0\n" +
           kind;
  };
  // No kind: the entry's default, contour.
  const std::vector<std::pair<std::string, std::string>> refused = {
      {"", "contour"},
      {"kind = \"contour\"\n", "contour"},
      {"kind = \"tool_wear\"\n", "tool_wear"}};
  for (const auto& [key, named] : refused) {
    auto r = config::load_file(d.write("a.toml", text(key)));
    EXPECT_FALSE(r.config) << key;
    const std::string err = r.diagnostics.to_string();
    EXPECT_NE(err.find(term_where("a.toml", text(key)) +
                       "model.apply[0].term: term 'thermal_drift' was fitted on calib rows only "
                       "and contributes nothing to kind = " +
                       named +
                       ": give the entry the kind of the rows the term describes "
                       "(kind = \"calib\")"),
              std::string::npos)
        << err;
  }
  auto ok = config::load_file(d.write("b.toml", text("kind = \"calib\"\n")));
  EXPECT_TRUE(ok.config) << ok.diagnostics.to_string();
}

/// [calibration] with touch_positions = "machine" measures the whole drift into its X/Y/Z
/// registers whatever the NC's offset holds (core/calib/calibrator.hpp): a model's trim on one of
/// them would be counted on top of it, twice. With "program" the touches see the trim and S3
/// learns what the term leaves: accepted. The [calibration] table is the documented example
/// (registers 20..22), as given and with "program".
TEST(ModelSection, ATrimOnACalibrationRegisterNeedsTouchPositionsProgram) {
  TempDir d;
  d.write("fit/model.toml", formats::model_io::write_model_toml(interaction_and_group_model(),
                                                                cm::AnalysisConfig{}, {"test"}));
  std::ifstream in(std::string(NCCOMP_SOURCE_DIR) + "/tools/calibrate/examples/machine.toml");
  std::stringstream example;
  example << in.rdbuf();
  const std::string machine = example.str();
  const std::string needle = "touch_positions = \"machine\"";
  ASSERT_NE(machine.find(needle), std::string::npos);
  std::string program = machine;
  program.replace(program.find(needle), needle.size(), "touch_positions = \"program\"");
  std::string registers = "[loopback]\n";
  for (int i = 0; i < 23; ++i) {
    registers += "[[registers]]\nname = \"r" + std::to_string(i) + "\"\nkind = \"" +
                 (i >= 20 ? "axis_offset" : "tool_length_wear") +
                 "\"\nbus = \"loopback\"\nmax_abs_um = 100\nmax_step_um = 50\n"
                 "max_rate_um_per_s = 100000\n";
  }
  const std::string model =
      "[model]\nfile = \"fit/model.toml\"\n[[model.apply]]\nterm = \"thermal_drift\"\n"
      "register = \"r21\"\nkind = \"calib\"\npoint = 1\n";
  auto r = config::load_file(d.write("a.toml", registers + machine + model));
  EXPECT_FALSE(r.config);
  const std::string err = r.diagnostics.to_string();
  EXPECT_NE(err.find("model.apply[0].register: 'r21' takes [calibration]'s correction, which "
                     "measures the whole drift with touch_positions = \"machine\": the term's "
                     "trim would count it twice; set [calibration] touch_positions = "
                     "\"program\" (the calibration then learns what the term leaves)"),
            std::string::npos)
      << err;
  auto ok = config::load_file(d.write("b.toml", registers + program + model));
  EXPECT_TRUE(ok.config) << ok.diagnostics.to_string();
  // A register [calibration] does not write is no concern of it.
  std::string other = model;
  other.replace(other.find("r21"), 3, "r3");
  auto r3 = config::load_file(d.write("c.toml", registers + machine + other));
  EXPECT_TRUE(r3.config) << r3.diagnostics.to_string();
}

TEST(ModelSection, APerGroupTermNeedsItsGroupInEachEntry) {
  TempDir d;
  d.write("fit/model.toml", formats::model_io::write_model_toml(interaction_and_group_model(),
                                                                cm::AnalysisConfig{}, {"test"}));
  const auto text = [](const std::string& keys) {
    return registers_toml() +
           "[model]\nfile = \"fit/model.toml\"\nupdate = \"cycle\"\n[[model.apply]]\n"
           "term = \"thermal_drift\"\nregister = \"checkpoint_0\"\nkind = \"calib\"\n" +
           keys;
  };
  // No point: the term has no coefficient for the entry, it would contribute 0.
  auto r = config::load_file(d.write("a.toml", text("")));
  EXPECT_FALSE(r.config);
  const std::string err = r.diagnostics.to_string();
  EXPECT_NE(err.find(term_where("a.toml", text("")) +
                     "model.apply[0].term: term 'thermal_drift' has one coefficient set per "
                     "point and the entry gives no point: add point = N (the model has point = 0, "
                     "1, 2), or it would contribute nothing"),
            std::string::npos)
      << err;
  // A point the model has no group of would contribute 0 too.
  auto r2 = config::load_file(d.write("b.toml", text("point = 5\n")));
  EXPECT_FALSE(r2.config);
  const std::string err2 = r2.diagnostics.to_string();
  EXPECT_NE(err2.find(term_where("b.toml", text("point = 5\n")) +
                      "model.apply[0].term: term 'thermal_drift' has no group point = 5 (the model "
                      "has point = 0, 1, 2): it would contribute nothing"),
            std::string::npos)
      << err2;
  // Two group columns: trend_model's offset has (kind, point) groups of contour rows only.
  d.write("fit/trend.toml", model_toml());
  auto r3 = config::load_file(
      d.write("d.toml", registers_toml() +
                            "[model]\nfile = \"fit/trend.toml\"\n[[model.apply]]\n"
                            "term = \"offset\"\nregister = \"checkpoint_0\"\nkind = \"calib\"\n"
                            "point = 0\n"));
  EXPECT_FALSE(r3.config);
  const std::string err3 = r3.diagnostics.to_string();
  EXPECT_NE(err3.find("model.apply[0].term: term 'offset' has no group kind = calib, point = 0 "
                      "(the model has (kind = contour, point = 0), (kind = contour, point = 1)): "
                      "it would contribute nothing"),
            std::string::npos)
      << err3;
  // With its group: that group's coefficient, −1 × −0.3 µm/°C × 25 °C.
  auto ok = config::load_file(d.write("c.toml", text("point = 1\n")));
  ASSERT_TRUE(ok.config) << ok.diagnostics.to_string();
  auto e = config::build_engine(*ok.config);
  const auto* m = static_cast<const ModelModule*>(&e->module(0));
  core::StepOutput out;
  e->step(1'000'000'000, std::vector<core::Event>{core::TemperatureSample{0, 0, 25.0}}, out);
  EXPECT_NEAR(m->trim_um(0), 7.5, 1e-12);
}

/// ambient: thermal_drift linear in the extra column ambient_c (−0.88 µm/°C); speed: a
/// first-order lag of spindle_rpm with τ = 600 s (0.0047 µm/rpm); contact: poly degree 1 in
/// angle_deg (0.05 µm/°, centre 0, scale 1).
cm::Model extra_model() {
  cm::Term amb;
  amb.spec.name = "ambient";
  amb.spec.form = cm::Form::kLinear;
  amb.spec.column = static_cast<int>(cm::kStandardColumns);
  amb.groups = {{0.0, 0.0}};
  amb.coef = {-0.88};
  cm::Term speed;
  speed.spec.name = "speed";
  speed.spec.form = cm::Form::kLag;
  speed.spec.column = static_cast<int>(cm::kStandardColumns) + 1;
  speed.spec.scale = 600.0;
  speed.groups = {{0.0, 0.0}};
  speed.coef = {0.0047};
  cm::Term contact;
  contact.spec.name = "contact";
  contact.spec.form = cm::Form::kPoly;
  contact.spec.column = static_cast<int>(cm::Column::kAngle);
  contact.spec.degree = 1;
  contact.spec.scale = 1.0;
  contact.groups = {{0.0, 0.0}};
  contact.coef = {0.05};
  return cm::Model({"ambient_c", "spindle_rpm"}, {amb, speed, contact});
}

TEST(ModelInputs, ExtraColumnsFedFromSensorsAreCompensated) {
  TempDir d;
  d.write("fit/model.toml",
          formats::model_io::write_model_toml(extra_model(), cm::AnalysisConfig{}, {"test"}));
  const std::string text = registers_toml() +
                           "[model]\nfile = \"fit/model.toml\"\nupdate = \"cycle\"\n"
                           "[[model.inputs]]\ncolumn = \"ambient_c\"\nsensor = 1\n"
                           "[[model.inputs]]\ncolumn = \"spindle_rpm\"\nsensor = 7\n"
                           "[[model.apply]]\nterm = \"ambient\"\nregister = \"checkpoint_0\"\n"
                           "[[model.apply]]\nterm = \"speed\"\nregister = \"checkpoint_1\"\n"
                           "[[model.apply]]\nterm = \"contact\"\nregister = \"checkpoint_1\"\n"
                           "angle_deg = 30\ngain = 1\n";
  auto r = config::load_file(d.write("a.toml", text));
  ASSERT_TRUE(r.config) << r.diagnostics.to_string();
  auto e = config::build_engine(*r.config);
  ASSERT_EQ(e->module_count(), 1U);  // no [measurement_context]: the defaults (sensor 0)
  const auto* m = static_cast<const ModelModule*>(&e->module(0));
  ASSERT_EQ(m->name(), "model");
  constexpr std::int64_t kS = 1'000'000'000;
  core::StepOutput out;
  // Ambient 25 °C on sensor 1, the spindle at 0 rpm on sensor 7 (a speed register the bus map
  // publishes on a sensor channel).
  e->step(10 * kS,
          std::vector<core::Event>{core::TemperatureSample{0, 1, 25.0},
                                   core::TemperatureSample{0, 7, 0.0}},
          out);
  EXPECT_NEAR(m->trim_um(0), 0.88 * 25.0, 1e-12);  // gain −1 × −0.88 × 25
  EXPECT_NEAR(m->trim_um(1), 0.0, 1e-12);
  EXPECT_NEAR(m->trim_um(2), 0.05 * 30.0, 1e-12);  // the entry's wall angle
  // The spindle goes to 5000 rpm: the lag follows with τ = 600 s.
  e->step(20 * kS, std::vector<core::Event>{core::TemperatureSample{0, 7, 5000.0}}, out);
  e->step(620 * kS, {}, out);
  EXPECT_NEAR(m->trim_um(1), -0.0047 * 5000.0 * (1.0 - std::exp(-1.0)), 1e-9);
  EXPECT_NEAR(e->register_state(1).output_um, -0.0047 * 5000.0 * (1.0 - std::exp(-1.0)) + 1.5,
              1e-9);
  // Ambient 20 °C: the trim follows at once.
  e->step(621 * kS, std::vector<core::Event>{core::TemperatureSample{0, 1, 20.0}}, out);
  EXPECT_NEAR(m->trim_um(0), 0.88 * 20.0, 1e-12);
}

TEST(ModelInputs, UnmappedColumnsWrongInputsAndAnotherTemperatureSensorAreRefused) {
  TempDir d;
  d.write("fit/model.toml",
          formats::model_io::write_model_toml(extra_model(), cm::AnalysisConfig{}, {"test"}));
  const auto load = [&](const std::string& name, const std::string& body) {
    return config::load_file(d.write(
        name,
        registers_toml() + "[model]\nfile = \"fit/model.toml\"\nupdate = \"cycle\"\n" + body));
  };
  const auto expect_error = [](const config::LoadResult& r, const std::string& what) {
    EXPECT_FALSE(r.config);
    EXPECT_NE(r.diagnostics.to_string().find(what), std::string::npos) << r.diagnostics.to_string();
  };
  expect_error(load("a.toml", "[[model.apply]]\nterm = \"ambient\"\nregister = \"checkpoint_0\"\n"),
               "term 'ambient' depends on ambient_c, which the daemon's loop does not know: map it "
               "to a sensor with [[model.inputs]] column = \"ambient_c\" sensor = N");
  expect_error(load("b.toml", "[[model.apply]]\nterm = \"contact\"\nregister = \"checkpoint_0\"\n"),
               "depends on angle_deg, which the daemon's loop does not know: give the entry");
  expect_error(load("c.toml",
                    "[[model.inputs]]\ncolumn = \"t9_c\"\nsensor = 1\n"
                    "[[model.apply]]\nterm = \"contact\"\nregister = \"checkpoint_0\"\n"
                    "angle_deg = 10\n"),
               "model.inputs[0].column: 't9_c' is not an extra column of");
  expect_error(load("d.toml",
                    "[[model.inputs]]\ncolumn = \"temp_c\"\nsensor = 1\n"
                    "[[model.apply]]\nterm = \"contact\"\nregister = \"checkpoint_0\"\n"
                    "angle_deg = 10\n"),
               "'temp_c' is a log column the loop knows already");
  // temp_c: [model] may not read another sensor than the one the log records.
  const std::string ok_apply =
      "[[model.apply]]\nterm = \"contact\"\nregister = \"checkpoint_0\"\nangle_deg = 10\n";
  expect_error(load("e.toml", "temperature_sensor = 2\n" + ok_apply),
               "sensor 2 differs from the sensor the measurement log records as temp_c (0");
  auto ok = load("f.toml", "temperature_sensor = 2\n" + ok_apply +
                               "[measurement_context]\ntemperature_sensor = 2\n"
                               "warm_start_idle_s = 1800\n");
  ASSERT_TRUE(ok.config) << ok.diagnostics.to_string();
  auto e = config::build_engine(*ok.config);
  EXPECT_EQ(e->context().options().temperature_sensor, 2);
  EXPECT_DOUBLE_EQ(e->context().options().warm_start_idle_s, 1800.0);
  expect_error(load("g.toml", ok_apply + "[measurement_context]\nwarm_start_idle_s = 5\n"),
               "measurement_context.warm_start_idle_s");
}

TEST(MeasurementContextSection, StatusShowsTheMachineClockAndPath) {
  TempDir d;
  auto r = config::load_file(d.write("a.toml", registers_toml() +
                                                   "[measurement_context]\nwarm_start_idle_s = "
                                                   "600\ntemperature_sensor = 3\n"));
  ASSERT_TRUE(r.config) << r.diagnostics.to_string();
  auto e = config::build_engine(*r.config);
  constexpr std::int64_t kS = 1'000'000'000;
  core::StepOutput out;
  e->step(100 * kS, std::vector<core::Event>{sample(0.0, 0.0, 4, true)}, out);
  e->step(101 * kS,
          std::vector<core::Event>{sample(3.0, 4.0, 4, true), core::TemperatureSample{0, 3, 21.5}},
          out);
  e->step(161 * kS, std::vector<core::Event>{sample(3.0, 4.0, 4, true)}, out);
  std::array<ce::StatusValue, ce::kMaxStatusValues> v{};
  const std::size_t n = e->module(0).status(v);
  std::map<std::string, double> got;
  for (std::size_t i = 0; i < n; ++i) got[v[i].key] = v[i].value;
  EXPECT_DOUBLE_EQ(got["machine_time_s"], 60.0);
  EXPECT_DOUBLE_EQ(got["idle_s"], 60.0);
  EXPECT_DOUBLE_EQ(got["warm_starts"], 1.0);
  EXPECT_DOUBLE_EQ(got["cold"], 0.0);
  EXPECT_DOUBLE_EQ(got["tool"], 4.0);
  EXPECT_DOUBLE_EQ(got["cut_path_mm"], 5.0);
  EXPECT_DOUBLE_EQ(got["temp_c"], 21.5);
}

std::vector<std::string> read_lines(const std::string& path) {
  std::ifstream in(path);
  std::vector<std::string> lines;
  std::string line;
  while (std::getline(in, line)) lines.push_back(line);
  return lines;
}

TEST(MeasurementLogTime, AWarmStartStartsANewFileAndARestartContinuesTheCurrentOne) {
  TempDir d;
  const std::string dir = (d.path() / "log").string();
  constexpr std::int64_t kS = 1'000'000'000;
  auto push = [](MeasurementLogWriter& w, std::int64_t t_ns, int point) {
    core::MeasurementRecord r;
    r.time_ns = t_ns;
    r.point = point;
    r.kind = core::MeasurementKind::kContour;
    while (!w.ring().try_push(r)) std::this_thread::sleep_for(std::chrono::milliseconds(1));
  };
  {
    MeasurementLogWriter w(dir, 1 << 20, 5);
    w.start();
    push(w, 100 * kS, 0);
    push(w, 200 * kS, 1);
    push(w, 200 * kS, 2);  // the same time: no new file
    w.stop();
    EXPECT_EQ(w.time_rotations(), 0U);
  }
  {
    // A restart appends; its first row (250 s) continues the file, the warm start (5 s) does not.
    MeasurementLogWriter w(dir, 1 << 20, 5);
    w.start();
    push(w, 250 * kS, 3);
    push(w, 5 * kS, 4);
    push(w, 9 * kS, 5);
    w.stop();
    EXPECT_EQ(w.time_rotations(), 1U);
    EXPECT_EQ(w.rotations(), 1U);
    EXPECT_EQ(w.rows(), 3U);
  }
  {
    // A restart after the warm start: the current file ends at 9 s, so 3 s starts another file.
    MeasurementLogWriter w(dir, 1 << 20, 5);
    w.start();
    push(w, 3 * kS, 6);
    w.stop();
    EXPECT_EQ(w.time_rotations(), 1U);
  }
  const auto older = read_lines(dir + "/measurements.csv.2");
  const auto warm = read_lines(dir + "/measurements.csv.1");
  const auto current = read_lines(dir + "/measurements.csv");
  ASSERT_EQ(older.size(), 5U);
  EXPECT_EQ(older[0], formats::measurement_log::csv_header({}));
  EXPECT_EQ(older[4].rfind("250.000000,", 0), 0U) << older[4];
  ASSERT_EQ(warm.size(), 3U);
  EXPECT_EQ(warm[0], formats::measurement_log::csv_header({}));
  EXPECT_EQ(warm[1].rfind("5.000000,", 0), 0U) << warm[1];
  EXPECT_EQ(warm[2].rfind("9.000000,", 0), 0U) << warm[2];
  ASSERT_EQ(current.size(), 2U);
  EXPECT_EQ(current[1].rfind("3.000000,", 0), 0U) << current[1];
}

std::string read_text(const std::string& path) {
  std::ifstream in(path);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

TEST(MeasurementRows, S1ProbeRowsCarryTheFinishingToolsCutPathAndTheSensor) {
  // The checkpoint example of docs/checkpoints.md (finishing tool 12, live radius register 19,
  // table from 20) and the log's temperature on sensor 2.
  TempDir d;
  std::string regs = "[loopback]\n";
  for (int i = 0; i < 76; ++i) {
    const std::string kind =
        i == 19 ? "tool_radius_wear" : (i >= 20 ? "checkpoint" : "tool_length_wear");
    regs += "[[registers]]\nname = \"r" + std::to_string(i) + "\"\nkind = \"" + kind +
            "\"\nbus = \"loopback\"\nmax_abs_um = 100\nmax_step_um = 50\n"
            "max_rate_um_per_s = 100000\n";
  }
  auto r =
      config::load_file(d.write("a.toml", "include = [\"" + std::string(NCCOMP_SOURCE_DIR) +
                                              "/tests/unit/checkpoint/data/boss.toml\"]\n" + regs +
                                              "[measurement_context]\ntemperature_sensor = 2\n"));
  ASSERT_TRUE(r.config) << r.diagnostics.to_string();
  auto e = config::build_engine(*r.config);
  constexpr std::int64_t kS = 1'000'000'000;
  core::StepOutput out;
  std::int64_t t = 100 * kS;
  // Tool 12 finishes the part: 41 cutting samples 1 mm apart (40 mm), from 100 s.
  e->step(t,
          std::vector<core::Event>{core::ToolChange{t, 12, false}, sample(0.0, 0.0, 12, true),
                                   core::TemperatureSample{t, 2, 22.75}},
          out);
  for (int k = 1; k <= 40; ++k) {
    e->step(t += kS / 10, std::vector<core::Event>{sample(k, 0.0, 12, true)}, out);
  }
  // The probe (tool 30 in the spindle, no cutting) measures checkpoint 5 at 160 s.
  t = 160 * kS;
  e->step(t,
          std::vector<core::Event>{core::ToolChange{t, 30, false}, sample(40.0, 0.0, 30, false),
                                   core::ProbeMeasurement{t, 1, 5, 3.0, 3.0, 2.0, {1, 2, 3}}},
          out);
  ASSERT_EQ(out.records.size(), 1U);
  const core::MeasurementRecord& rec = out.records[0];
  EXPECT_EQ(rec.kind, core::MeasurementKind::kContour);
  EXPECT_EQ(rec.tool, 12);
  EXPECT_DOUBLE_EQ(rec.path_mm, 40.0);
  EXPECT_DOUBLE_EQ(rec.temp_c, 22.75);
  // Since the warm start, the first motion at 100.1 s.
  EXPECT_EQ(rec.time_ns, 59'900'000'000);
  const std::string row = formats::measurement_log::format_row(rec, "m", "", 0);
  EXPECT_EQ(row.rfind("59.900000,1,12,contour,5,", 0), 0U) << row;
  EXPECT_NE(row.find(",40.000,22.750,"), std::string::npos) << row;
}

TEST(MeasurementRows, S0ToolWearRowsCarryTheSensor) {
  // The creep example of docs/creep.md with its registers; the temperature on sensor 0 (the
  // default when there is no [measurement_context]).
  const std::string md = read_text(std::string(NCCOMP_SOURCE_DIR) + "/docs/creep.md");
  const auto h = md.find("### Example");
  const auto b = md.find("```toml\n", h);
  const auto x = md.find("```", b + 8);
  ASSERT_NE(x, std::string::npos);
  std::string regs = "[loopback]\n";
  for (const char* n : {"X_wear_offset", "Y_wear_offset", "Z_wear_offset"}) {
    regs += std::string("[[registers]]\nname = \"") + n +
            "\"\nkind = \"axis_offset\"\nbus = \"loopback\"\nmax_abs_um = 100\nmax_step_um = "
            "50\nmax_rate_um_per_s = 100000\n";
  }
  for (const char* n : {"creep_warning", "creep_alarm", "measure_request", "sister_request"}) {
    regs += std::string("[[registers]]\nname = \"") + n +
            "\"\nkind = \"flag\"\nbus = \"loopback\"\nmax_abs_um = 1\n";
  }
  TempDir d;
  auto r = config::load_file(d.write("a.toml", regs + md.substr(b + 8, x - b - 8)));
  ASSERT_TRUE(r.config) << r.diagnostics.to_string();
  auto e = config::build_engine(*r.config);
  constexpr std::int64_t kS = 1'000'000'000;
  core::StepOutput out;
  std::int64_t t = 10 * kS;
  e->step(t,
          std::vector<core::Event>{core::ToolChange{t, 1, false}, sample(0.0, 0.0, 1, true),
                                   core::TemperatureSample{t, 0, 24.5}},
          out);
  for (int k = 1; k <= 30; ++k) {
    e->step(t += kS, std::vector<core::Event>{sample(k, 0.0, 1, true)}, out);
  }
  core::ToolMeasurement m;
  m.time_ns = t + kS;
  m.tool = 1;
  m.point_count = 1;
  m.wear_um[0] = 2.0;
  e->step(t += kS, std::vector<core::Event>{m}, out);
  ASSERT_EQ(out.records.size(), 7U);  // one row per edge support point
  for (const auto& rec : out.records) {
    EXPECT_EQ(rec.kind, core::MeasurementKind::kToolWear);
    EXPECT_DOUBLE_EQ(rec.path_mm, 30.0);  // creep's own count, the same as the context's
    EXPECT_DOUBLE_EQ(rec.temp_c, 24.5);
    EXPECT_EQ(rec.time_ns, 30 * kS);  // warm start at the first motion, 11 s
  }
  EXPECT_DOUBLE_EQ(e->context().cut_path_mm(), 30.0);
}

TEST(ModelInputs, TheFlThermalModelRunsInTheLoopWithItsExtraColumnsOnSensors) {
  // The model analyze fitted to FL_THERMAL gauge ch1 (docs/closing-the-loop.md): four terms are
  // called thermal_drift; the column chooses. t5 (temp_c) is the log's sensor 0, the ambient t1
  // is sensor 1, the spindle speed is published on sensor channel 5.
  const std::string model =
      std::string(NCCOMP_SOURCE_DIR) + "/bench/model/figures/fl_thermal_ch1/model.toml";
  const cm::Model fitted = formats::model_io::load_model_file(model);
  TempDir d;
  const std::string head = registers_toml() + "[model]\nfile = \"" + model +
                           "\"\nupdate = \"cycle\"\n"
                           "[[model.inputs]]\ncolumn = \"t1_c\"\nsensor = 1\n"
                           "[[model.inputs]]\ncolumn = \"spindle_rpm\"\nsensor = 5\n";
  auto ambiguous = config::load_file(d.write(
      "a.toml", head + "[[model.apply]]\nterm = \"thermal_drift\"\nregister = \"checkpoint_0\"\n"));
  ASSERT_FALSE(ambiguous.config);
  EXPECT_NE(ambiguous.diagnostics.to_string().find(
                "term 'thermal_drift' appears 4 times in " + model +
                " (offset (constant), thermal_drift (temp_c, linear), thermal_drift "
                "(spindle_rpm, lag), thermal_drift (t1_c, linear), level_change (time_s, step), "
                "thermal_drift (time_s, exp_rise)): choose one with column = … and / or form = …"),
            std::string::npos)
      << ambiguous.diagnostics.to_string();
  auto r = config::load_file(d.write(
      "b.toml", head + "[[model.apply]]\nterm = \"thermal_drift\"\ncolumn = \"spindle_rpm\"\n"
                       "register = \"checkpoint_0\"\n"
                       "[[model.apply]]\nterm = \"thermal_drift\"\ncolumn = \"t1_c\"\n"
                       "register = \"checkpoint_1\"\n"
                       "[[model.apply]]\nterm = \"thermal_drift\"\ncolumn = \"temp_c\"\n"
                       "form = \"linear\"\nregister = \"checkpoint_1\"\n"));
  ASSERT_TRUE(r.config) << r.diagnostics.to_string();
  const auto* s = model_section(*r.config);
  ASSERT_EQ(s->applies.size(), 3U);
  EXPECT_EQ(s->applies[0].apply.term_index, 2U);
  EXPECT_EQ(s->applies[1].apply.term_index, 3U);
  EXPECT_EQ(s->applies[2].apply.term_index, 1U);
  auto e = config::build_engine(*r.config);
  const auto* m = static_cast<const ModelModule*>(&e->module(0));
  constexpr std::int64_t kS = 1'000'000'000;
  core::StepOutput out;
  // Cold spindle, then 5000 rpm; t5 = 31 °C, t1 = 19.5 °C.
  e->step(kS,
          std::vector<core::Event>{core::TemperatureSample{0, 5, 0.0},
                                   core::TemperatureSample{0, 0, 31.0},
                                   core::TemperatureSample{0, 1, 19.5}},
          out);
  e->step(2 * kS, std::vector<core::Event>{core::TemperatureSample{0, 5, 5000.0}}, out);
  const double tau_s = fitted.terms()[2].spec.scale;
  e->step(2 * kS + static_cast<std::int64_t>(tau_s * 1e9), {}, out);
  EXPECT_NEAR(m->trim_um(0), -fitted.terms()[2].coef[0] * 5000.0 * (1.0 - std::exp(-1.0)), 1e-6);
  // t1's term counts from its reference (model.toml's center).
  EXPECT_NEAR(m->trim_um(1), -fitted.terms()[3].coef[0] * (19.5 - fitted.terms()[3].spec.center),
              1e-9);
  EXPECT_NEAR(m->trim_um(2), -fitted.terms()[1].coef[0] * 31.0, 1e-9);
  // 5000 rpm for one time constant: about 15 µm of the 23.5 µm the speed term predicts at rest.
  EXPECT_GT(std::fabs(m->trim_um(0)), 10.0);
}

}  // namespace
}  // namespace nccomp::daemon::sections

namespace nccomp::daemon::sections {
namespace {

// The trim handover (core/engine/engine.hpp) tells "another model" from "the same model again"
// by the module's trim identity: equal for an equal model and mapping, different when a
// coefficient, a gain or the register changes.
TEST(ModelHandover, TheTrimIdentityFollowsTheModelAndItsMapping) {
  const auto identity = [](cm::Model model, double gain, std::uint16_t reg) {
    ModelApply a;
    a.term_index = 1;
    a.register_index = reg;
    a.gain = gain;
    a.point = 0.0;
    return ModelModule(std::move(model), {a}, false).trim_identity();
  };
  const std::uint64_t base = identity(trend_model(), -1.0, 0);
  EXPECT_NE(base, 0U);
  EXPECT_EQ(identity(trend_model(), -1.0, 0), base);
  cm::Model refit = trend_model();
  std::vector<cm::Term> terms = refit.terms();
  terms[1].coef[0] = 0.021;
  EXPECT_NE(identity(cm::Model({}, terms), -1.0, 0), base);
  EXPECT_NE(identity(trend_model(), -2.0, 0), base);
  EXPECT_NE(identity(trend_model(), -1.0, 1), base);
}

}  // namespace
}  // namespace nccomp::daemon::sections

namespace nccomp::daemon::sections {
namespace {

// The operator's choice (`nccomp model load` / `rollback`): GIVEN a config whose [model] names
// fit/model.toml, WHEN a choice for that file names another model THEN the section loads that one
// (chosen); a choice of no model gives a section that adds no module; a choice made for another
// configured file is not applied; the record's text form round-trips and refuses what is not it.
TEST(ModelChoice, AChoiceReplacesTheConfiguredFileWhileTheConfigNamesIt) {
  TempDir d;
  d.write("fit/model.toml", model_toml());
  const std::string other = d.write("fit2/model.toml", model_toml());
  const std::string cfg = d.write("a.toml", registers_toml() + kApply);
  const std::string configured =
      (std::filesystem::path(cfg).parent_path() / "fit/model.toml").lexically_normal().string();
  ModelChoice c;
  c.configured = configured;
  c.live.file = other;
  set_model_choice(c);
  auto r = config::load_file(cfg);
  ASSERT_TRUE(r.config) << r.diagnostics.to_string();
  const auto* s = model_section(*r.config);
  ASSERT_NE(s, nullptr);
  EXPECT_TRUE(s->chosen);
  EXPECT_EQ(s->file, other);
  EXPECT_EQ(s->configured_file, configured);
  EXPECT_TRUE(s->loaded);

  c.live.file.clear();  // rolled back to no model
  set_model_choice(c);
  r = config::load_file(cfg);
  ASSERT_TRUE(r.config) << r.diagnostics.to_string();
  s = model_section(*r.config);
  EXPECT_TRUE(s->disabled);
  std::vector<std::unique_ptr<ce::Module>> mods;
  for (const auto* p : config::section_parsers()) p->add_modules(*r.config, mods);
  for (const auto& m : mods) EXPECT_NE(m->name(), "model");

  c.configured = "/elsewhere/model.toml";  // made for another configured file
  c.live.file = other;
  set_model_choice(c);
  r = config::load_file(cfg);
  ASSERT_TRUE(r.config) << r.diagnostics.to_string();
  EXPECT_FALSE(model_section(*r.config)->chosen);
  EXPECT_EQ(model_section(*r.config)->file, configured);

  // A chosen file that is not a model: the configuration's error names it at the file key.
  c.configured = configured;
  c.live.file = d.write("bad.toml", "not [ a model\n");
  set_model_choice(c);
  r = config::load_file(cfg);
  EXPECT_FALSE(r.config);
  EXPECT_NE(r.diagnostics.to_string().find("cannot load the model " + c.live.file +
                                           " (nccomp model load)"),
            std::string::npos)
      << r.diagnostics.to_string();
  set_model_choice(std::nullopt);
}

TEST(ModelChoice, TheRecordRoundTripsAndRefusesWhatIsNotIt) {
  ModelChoice c;
  c.configured = "/etc/nccompd/fit/model.toml";
  c.live = {"/srv/fit 2/model.toml", "0123456789abcdef", "2024-05-06T07:08:09Z"};
  c.previous = {"", "", ""};
  const ModelChoice back = model_choice_from_text(to_text(c));
  EXPECT_EQ(back.configured, c.configured);
  EXPECT_EQ(back.live.file, c.live.file);
  EXPECT_EQ(back.live.hash, c.live.hash);
  EXPECT_EQ(back.live.since_utc, c.live.since_utc);
  EXPECT_EQ(back.previous.file, "");
  EXPECT_THROW((void)model_choice_from_text("nccomp_model_choice 2\n"), std::invalid_argument);
  EXPECT_THROW((void)model_choice_from_text(to_text(c) + "extra 1\n"), std::invalid_argument);
  EXPECT_THROW((void)model_choice_from_text(to_text(c) + "live_file x\n"), std::invalid_argument);
  std::string missing = to_text(c);
  missing.erase(missing.find("previous_since"));
  EXPECT_THROW((void)model_choice_from_text(missing), std::invalid_argument);
  // The hash is FNV-1a 64 of the bytes: "a" is af63dc4c8601ec8c.
  TempDir d;
  EXPECT_EQ(model_file_hash(d.write("a.txt", "a")), "af63dc4c8601ec8c");
  EXPECT_THROW(
      (void)model_file_hash(
          (std::filesystem::path(d.write("b.txt", "")).parent_path() / "missing").string()),
      std::runtime_error);
}

}  // namespace
}  // namespace nccomp::daemon::sections

namespace nccomp::daemon::commands {
namespace {

// GIVEN the configuration names A and the operator loaded B, then rolled back to A (the choice
// is still recorded: B is kept to roll back to)
// THEN `nccomp model status` says that A is the configuration's own file, chosen again; with B
// live it says B runs in place of A; without a choice, that A is the configuration's file.
TEST(ModelStatusText, SaysWhetherTheLiveModelIsTheConfigurationsOwnFile) {
  ModelState m;
  m.has_section = true;
  m.configured = "/etc/nccompd/a/model.toml";
  m.chosen = true;
  m.live.file = "/etc/nccompd/a/model.toml";
  m.previous.file = "/srv/fit/b/model.toml";
  std::string text = model_status_text(m, HandoverStats{});
  EXPECT_NE(text.find("\n  the configuration's [model] file, chosen again by nccomp model load / "
                      "rollback\n"),
            std::string::npos)
      << text;
  EXPECT_EQ(text.find("in place of"), std::string::npos) << text;

  m.live.file = "/srv/fit/b/model.toml";
  m.previous.file = "/etc/nccompd/a/model.toml";
  text = model_status_text(m, HandoverStats{});
  EXPECT_NE(text.find("\n  chosen by nccomp model load / rollback, in place of the "
                      "configuration's /etc/nccompd/a/model.toml\n"),
            std::string::npos)
      << text;

  m.chosen = false;
  m.live.file = m.configured;
  text = model_status_text(m, HandoverStats{});
  EXPECT_NE(text.find("\n  the configuration's [model] file\n"), std::string::npos) << text;
}

}  // namespace
}  // namespace nccomp::daemon::commands
