// Issue 21, session_offset in the daemon: GIVEN a model with a session term applied to a
// register WHEN measurement records of the session arrive THEN the model module moves the trim to
// −(posterior mean of the session's offset), allocation-free; a restart within the session
// continues from the state file; a warm start is a new session that starts from the prior, 0.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstdint>
#include <memory>
#include <vector>

#include "core/engine/engine.hpp"
#include "core/model/model.hpp"
#include "core/model/model_module.hpp"
#include "tests/support/alloc_counter.hpp"

namespace cm = nccomp::core::model;
namespace ce = nccomp::core::engine;
namespace core = nccomp::core;

namespace {

/// Emits one contour measurement record (measured_um, applied 0) when one is pending: the
/// measurements another module (S1) would log.
class RecordModule final : public ce::Module {
 public:
  std::string_view name() const noexcept override { return "records"; }
  void attach(const ce::RegisterTable&) override {}
  void step(core::TimeNs now_ns, std::span<const core::Event>,
            core::StepOutput& out) noexcept override {
    if (!pending_) return;
    core::MeasurementRecord r;
    r.time_ns = now_ns;
    r.kind = core::MeasurementKind::kContour;
    r.measured_um = measured_um_;
    out.records.push(r);
    pending_ = false;
  }
  void measure(double um) {
    measured_um_ = um;
    pending_ = true;
  }

 private:
  double measured_um_{0.0};
  bool pending_{false};
};

struct SessionEngine {
  std::unique_ptr<ce::Engine> engine;
  cm::ModelModule* model{nullptr};
  RecordModule* records{nullptr};
};

// session_offset (τ = 4 µm, σ = 1 µm, contour rows) applied to register 0 with gain −1.
SessionEngine session_engine() {
  cm::Term session;
  session.spec.name = "session_offset";
  session.spec.form = cm::Form::kSession;
  session.spec.column = static_cast<int>(cm::kSessionColumn);
  session.spec.per = {static_cast<int>(cm::kSessionColumn), -1};
  session.spec.kind_mask = 0x2;
  session.spec.scale = 4.0;
  session.spec.center = 1.0;
  cm::ModelApply a;
  a.term_index = 0;
  a.register_index = 0;
  a.gain = -1.0;
  SessionEngine s;
  auto m = std::make_unique<cm::ModelModule>(cm::Model({}, {session}), std::vector{a}, false);
  auto r = std::make_unique<RecordModule>();
  s.model = m.get();
  s.records = r.get();
  std::vector<std::unique_ptr<ce::Module>> mods;
  mods.push_back(std::move(r));
  mods.push_back(std::move(m));
  ce::RegisterSpec reg;
  reg.name = "checkpoint_0";
  reg.kind = ce::RegisterKind::kCheckpoint;
  reg.limits.max_abs_um = 100.0;
  reg.limits.max_step_um = 100.0;
  reg.limits.max_rate_um_per_s = 1e6;
  s.engine = std::make_unique<ce::Engine>();
  s.engine->configure({reg}, std::move(mods), {});
  return s;
}

}  // namespace

// The daemon's side: the model module learns the session's offset from the cycle's measurement
// records, allocation-free; the trim is −(posterior mean); the learning is its state, so a
// restart within the session continues it; a warm start is a new session (back to 0).
TEST(SessionOffsetDaemon, TheModelModuleLearnsEachSessionFromItsRecordsAndARestartContinues) {
  SessionEngine s = session_engine();
  core::StepOutput out;
  std::int64_t t = 0;
  std::size_t allocations = 0;
  auto step = [&](SessionEngine& e, std::vector<core::Event> ev) {
    const nccomp::test::AllocationScope scope;
    e.engine->step(t += 1'000'000, ev, out);
    allocations += scope.count() + scope.frees();
  };
  step(s, {});
  EXPECT_DOUBLE_EQ(s.model->trim_um(0), 0.0);  // the prior mean
  const std::array<double, 5> measured = {3.1, 2.6, 3.4, 2.9, 3.3};
  std::array<double, 5> trims{};
  for (std::size_t k = 0; k < measured.size(); ++k) {
    s.records->measure(measured[k]);
    step(s, {});  // the record is logged and observed
    step(s, {});  // the trim follows
    trims[k] = s.model->trim_um(0);
  }
  EXPECT_EQ(allocations, 0U);
  EXPECT_NEAR(trims[0], -16.0 * 3.1 / 17.0, 1e-12);
  EXPECT_NEAR(trims[1], -16.0 * 5.7 / 33.0, 1e-12);
  EXPECT_NEAR(trims[4], -16.0 * 15.3 / 81.0, 1e-12);
  EXPECT_NEAR(s.engine->register_state(0).output_um, trims[4], 1e-12);

  // Restart within the session: the state file carries what was learned.
  std::vector<std::byte> state(s.engine->state_capacity());
  state.resize(s.engine->export_state(state));
  SessionEngine s2 = session_engine();
  ASSERT_TRUE(s2.engine->import_state(state, t + 1'000'000));
  step(s2, {});
  EXPECT_NEAR(s2.model->trim_um(0), trims[4], 1e-12);
  s2.records->measure(2.7);
  step(s2, {});
  step(s2, {});
  EXPECT_NEAR(s2.model->trim_um(0), -16.0 * 18.0 / 97.0, 1e-12);

  // A warm start: a new session starts from the prior and learns from its own first record.
  core::OperatorCommand warm;
  warm.time_ns = t;
  warm.sequence = 1;
  warm.kind = core::OperatorCommandKind::kWarmStart;
  step(s2, {warm});
  EXPECT_DOUBLE_EQ(s2.model->trim_um(0), 0.0);
  s2.records->measure(-2.0);
  step(s2, {});
  step(s2, {});
  EXPECT_NEAR(s2.model->trim_um(0), 16.0 * 2.0 / 17.0, 1e-12);
}

// Trim handover along the path: GIVEN a tool_wear term linear in path_mm (0.021 µm/mm) applied
// to register 0 with gain −1, tool 7 at 500 mm of cut path WHEN the engine asks for the trim at
// 120 mm THEN it is the term at 120 mm (−2.52 µm), while the published trim is the one at 500 mm;
// a register without an entry has none (NaN).
TEST(ModelModuleTrimAtPath, EvaluatesTheTermAtTheGivenCutPathAndTheRestAsNow) {
  cm::Term wear;
  wear.spec.name = "tool_wear";
  wear.spec.form = cm::Form::kLinear;
  wear.spec.column = static_cast<int>(cm::Column::kPath);
  wear.groups = {{0.0, 0.0}};
  wear.coef = {0.021};
  cm::ModelApply a;
  a.register_index = 0;
  a.gain = -1.0;
  a.kind = 0.0;
  auto m = std::make_unique<cm::ModelModule>(cm::Model({}, {wear}), std::vector{a}, true);
  cm::ModelModule* model = m.get();
  std::vector<std::unique_ptr<ce::Module>> mods;
  mods.push_back(std::move(m));
  ce::RegisterSpec reg;
  reg.name = "T7_radius_wear";
  reg.kind = ce::RegisterKind::kToolRadiusWear;
  reg.limits.max_abs_um = 100.0;
  reg.limits.max_step_um = 100.0;
  reg.limits.max_rate_um_per_s = 1e6;
  ce::RegisterSpec other = reg;
  other.name = "T8_radius_wear";
  ce::Engine engine;
  engine.configure({reg, other}, std::move(mods), {});
  core::StepOutput out;
  std::int64_t t = 0;
  for (int k = 0; k <= 500; ++k) {
    core::AxisSample s;
    s.time_ns = t += 1'000'000;
    s.position_mm = {static_cast<double>(k), 0.0, 0.0, 0.0, 0.0, 0.0};
    s.program_path_mm = k;
    s.tool = 7;
    engine.step(t, std::vector<core::Event>{s}, out);
  }
  ASSERT_DOUBLE_EQ(engine.context().cut_path_mm(7), 500.0);
  EXPECT_NEAR(model->trim_um(0), -0.021 * 500.0, 1e-12);
  ce::InputSnapshot at;
  at.tool = 7;
  at.path_mm = 120.0;
  EXPECT_NEAR(model->trim_at_inputs(0, at), -0.021 * 120.0, 1e-12);
  EXPECT_TRUE(std::isnan(model->trim_at_inputs(1, at)));
  // Inputs the snapshot does not hold are taken as now: the tool's 500 mm.
  EXPECT_NEAR(model->trim_at_inputs(0, ce::InputSnapshot{}), -0.021 * 500.0, 1e-12);
}

// The creep learns the residual of the trims the laser sees (CreepModule::bind_tool_wear_trims()):
// the model module tells them apart by the entry's kind, per register.
TEST(ModelModuleToolWearTrim, OnlyTheEntriesOfKindToolWearOnTheRegisterCount) {
  cm::Term offset;
  offset.spec.name = "offset";
  offset.spec.form = cm::Form::kConstant;
  offset.spec.kind_mask = 0x3;  // tool_wear and contour rows
  offset.groups = {{0.0, 0.0}};
  offset.coef = {2.5};
  std::vector<cm::ModelApply> applies(3);
  applies[0].register_index = 0;
  applies[0].gain = -1.0;
  applies[0].kind = 0.0;  // tool_wear
  applies[1].register_index = 0;
  applies[1].gain = 2.0;
  applies[1].kind = 1.0;  // contour
  applies[2].register_index = 1;
  applies[2].gain = 3.0;
  applies[2].kind = 0.0;
  cm::ModelModule m(cm::Model({}, {offset}), applies, false);
  ce::RegisterSpec reg;
  reg.kind = ce::RegisterKind::kCheckpoint;
  reg.limits = {100.0, 100.0, 1e6};
  reg.name = "r0";
  std::vector<ce::RegisterSpec> regs{reg, reg};
  regs[1].name = "r1";
  m.attach(ce::RegisterTable(regs));
  core::StepOutput out;
  m.step(1'000'000, {}, out);
  ASSERT_EQ(out.trims.size(), 2U);
  EXPECT_DOUBLE_EQ(out.trims[0].value_um, -2.5 + 5.0);
  // Published, not yet accepted by an engine: nothing is in force.
  EXPECT_DOUBLE_EQ(m.tool_wear_trim_um(0), 0.0);
  m.trim_in_force(0);
  m.trim_in_force(1);
  m.trim_in_force(2);
  EXPECT_DOUBLE_EQ(m.tool_wear_trim_um(0), -2.5);
  EXPECT_DOUBLE_EQ(m.tool_wear_trim_um(1), 7.5);
  EXPECT_DOUBLE_EQ(m.tool_wear_trim_um(2), 0.0);
}

// GIVEN a tool_wear term of 0.021 µm/mm of cut path on a register limited to 5 µm WHEN the tool
// has cut 500 mm (the model's trim, −10.5 µm, is refused by the engine with an alarm from
// 239 mm on) THEN the wear share the creep takes out of its laser measurement is the trim in force
// (−0.021 × 238 µm), not the refused one: the register would otherwise hold less than the wear.
TEST(ModelModuleToolWearTrim, ARefusedTrimIsNotTheWearShareInForce) {
  cm::Term wear;
  wear.spec.name = "tool_wear";
  wear.spec.form = cm::Form::kLinear;
  wear.spec.column = static_cast<int>(cm::Column::kPath);
  wear.groups = {{0.0, 0.0}};
  wear.coef = {0.021};
  cm::ModelApply a;
  a.register_index = 0;
  a.gain = -1.0;
  a.kind = 0.0;
  auto m = std::make_unique<cm::ModelModule>(cm::Model({}, {wear}), std::vector{a}, true);
  cm::ModelModule* model = m.get();
  std::vector<std::unique_ptr<ce::Module>> mods;
  mods.push_back(std::move(m));
  ce::RegisterSpec reg;
  reg.name = "T7_radius_wear";
  reg.kind = ce::RegisterKind::kToolRadiusWear;
  reg.limits.max_abs_um = 5.0;
  reg.limits.max_step_um = 100.0;
  reg.limits.max_rate_um_per_s = 1e6;
  ce::Engine engine;
  engine.configure({reg}, std::move(mods), {});
  core::StepOutput out;
  std::int64_t t = 0;
  for (int k = 0; k <= 500; ++k) {
    core::AxisSample s;
    s.time_ns = t += 1'000'000;
    s.position_mm = {static_cast<double>(k), 0.0, 0.0, 0.0, 0.0, 0.0};
    s.program_path_mm = k;
    s.tool = 7;
    engine.step(t, std::vector<core::Event>{s}, out);
  }
  ASSERT_DOUBLE_EQ(engine.context().cut_path_mm(7), 500.0);
  EXPECT_NEAR(model->trim_um(0), -0.021 * 500.0, 1e-12);
  EXPECT_GT(engine.counters().writes_rejected, 0U);
  EXPECT_NEAR(model->tool_wear_trim_um(0), -0.021 * 238.0, 1e-9);
}
