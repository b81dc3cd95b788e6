// Trim handover on S0's registers (core/engine/engine.hpp, "Trim handover";
// CreepModule::rebase_output()): GIVEN the creep holds Z at −12 µm (12 µm of measured wear,
// fallback sign −1, linear creeps over 50 mm) WHEN a model whose trim on Z is −10 µm is loaded
// into the running engine THEN Z does not move at the switch and the trim comes in along the
// creep profile: −12 − 10 · s / 50 after s mm of cut, −22 from 50 mm on; a restart in the middle
// with the same model continues the fade; taking the model out fades it back out the same way.
// A term the laser sees (kind tool_wear) is not faded in on top of the measured wear: the creep
// keeps only the residual of it, at each measurement (AToolWearTermIsNotCountedTwice...).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <initializer_list>
#include <memory>
#include <vector>

#include "core/creep/creep_module.hpp"
#include "tests/support/alloc_counter.hpp"
#include "tests/unit/creep/rig.hpp"

namespace nccomp::core::creep {
namespace {

using engine::Engine;
using engine::RegisterKind;
using engine::RegisterSpec;

// A model's trim of the Z register (2), with the identity of its model.
class TrimZ final : public engine::Module {
 public:
  TrimZ(double trim, std::uint64_t identity) : trim_(trim), identity_(identity) {}
  std::string_view name() const noexcept override { return "model"; }
  void attach(const engine::RegisterTable& /*registers*/) override {}
  void step(TimeNs now_ns, std::span<const Event> /*events*/, StepOutput& out) noexcept override {
    out.trims.push(OffsetWrite{now_ns, 2, trim_});
  }
  std::uint64_t trim_identity() const noexcept override { return identity_; }
  double trim_;
  std::uint64_t identity_;
};

// A model's tool_wear term on Z: the wear it predicts at the program path, rate × path, as a
// trim of the sign the creep writes (−), all of it seen by the laser (tool_wear_trim_um()); and
// optionally a contour term (kind contour: the push-off a probe of the part sees), added to the
// same trim but not seen by the laser, so not part of tool_wear_trim_um().
class WearTrimZ final : public engine::Module, public engine::ToolWearTrimSource {
 public:
  explicit WearTrimZ(double rate_um_per_mm, double contour_um = 0.0)
      : rate_(rate_um_per_mm), contour_(contour_um) {}
  std::string_view name() const noexcept override { return "model"; }
  void attach(const engine::RegisterTable& /*registers*/) override {}
  void step(TimeNs now_ns, std::span<const Event> events, StepOutput& out) noexcept override {
    for (const Event& e : events) {
      if (const auto* a = std::get_if<AxisSample>(&e)) path_ = a->program_path_mm;
      if (std::holds_alternative<ToolChange>(e)) tool_start_ = path_;  // a new tool's path
    }
    trim_ = -rate_ * (path_ - tool_start_);
    out.trims.push(OffsetWrite{now_ns, 2, trim_ + contour_});
  }
  std::uint64_t trim_identity() const noexcept override { return 11; }
  double tool_wear_trim_um(std::uint16_t register_index) const noexcept override {
    return register_index == 2 ? in_force_ : 0.0;
  }
  void trim_in_force(std::uint16_t register_index) noexcept override {
    if (register_index == 2) in_force_ = trim_;
  }
  double rate_;
  double contour_;
  double path_{0.0};
  double tool_start_{0.0};
  double trim_{0.0};
  double in_force_{0.0};
};

CreepModuleConfig module_config() {
  CreepModuleConfig m;
  m.creep = testing::base_config();  // axes, Z fallback sign −1, 50 mm linear creeps
  m.creep.output.warning_register = -1;
  m.creep.output.alarm_register = -1;
  m.creep.output.measurement_due_register = -1;
  m.creep.output.tool_change_register = -1;
  m.creep.tool_life.min_expected_increment_um = 10.0;
  m.creep.tool_life.excessive_increment_um = 50.0;
  return m;
}

struct Rig {
  Engine engine;
  StepOutput out;
  std::vector<Event> ev;
  TimeNs now{0};
  double path{0.0};
  double nc_z_um{0.0};
  double largest_z_change_um{0.0};
  std::vector<double> z_writes;
  std::vector<double> y_writes;
  std::int32_t tool{1};
  // What the axis samples say (false: the tool stands or moves in the air).
  bool cutting{true};
  // Slew warnings of the engine's and the creep's limiters, over all steps.
  int slewed{0};

  Rig(const TrimZ* model, const CreepModuleConfig& config) : Rig(model, nullptr, config) {}
  // lim: every register's limits, and so the creep's own limiter (CreepModule::attach()).
  explicit Rig(const TrimZ* model, const WearTrimZ* wear_model = nullptr,
               const CreepModuleConfig& config = module_config(),
               const LimiterConfig& lim = {100.0, 50.0, 1e5}) {
    std::vector<std::unique_ptr<engine::Module>> mods;
    mods.push_back(std::make_unique<CreepModule>(config));
    if (model != nullptr) mods.push_back(std::make_unique<TrimZ>(model->trim_, model->identity_));
    if (wear_model != nullptr)
      mods.push_back(std::make_unique<WearTrimZ>(wear_model->rate_, wear_model->contour_));
    engine.configure({{"X_offset", RegisterKind::kAxisOffset, lim},
                      {"Y_offset", RegisterKind::kAxisOffset, lim},
                      {"Z_offset", RegisterKind::kAxisOffset, lim}},
                     std::move(mods));
  }
  void step() {
    engine.step(now, ev, out);
    ev.clear();
    for (const auto& a : out.alarms) slewed += a.code == AlarmCode::kOffsetSlewLimited ? 1 : 0;
    for (const auto& w : out.writes) {
      if (w.register_index == 1) y_writes.push_back(w.value_um);
      if (w.register_index != 2) continue;
      largest_z_change_um = std::max(largest_z_change_um, std::fabs(w.value_um - nc_z_um));
      nc_z_um = w.value_um;
      z_writes.push_back(w.value_um);
    }
  }
  void advance(double ds) {
    now += 10'000'000;
    path += ds;
    AxisSample a;
    a.time_ns = now;
    a.program_path_mm = path;
    a.position_mm = {path, 0.0, 0.0, 0.0, 0.0, 0.0};  // feed along +X
    a.tool = tool;
    a.cutting = cutting;
    ev.emplace_back(a);
    step();
  }
  void measure(double w) {
    ToolMeasurement m;
    m.tool = tool;
    m.wear_um[0] = w;
    now += 1'000'000;
    ev.emplace_back(m);
    step();
  }
  void take_over(const Rig& from) {
    now = from.now;
    path = from.path;
    nc_z_um = from.nc_z_um;
    std::vector<std::byte> buf(from.engine.state_capacity());
    buf.resize(from.engine.export_state(buf));
    ASSERT_TRUE(engine.import_state(buf, now));
  }
  [[nodiscard]] double z_um() const { return engine.register_state(2).output_um; }
  [[nodiscard]] const CreepModule& creep() const {
    return dynamic_cast<const CreepModule&>(engine.module(0));
  }
};

// 12 µm of wear measured and crept in: Z at −12.
void wear_in(Rig& r) {
  r.ev.emplace_back(ToolChange{r.now, 1, false});
  r.advance(0.5);
  r.measure(12.0);
  for (int i = 0; i < 110; ++i) r.advance(0.5);
  ASSERT_NEAR(r.z_um(), -12.0, 1e-9);
}

TEST(CreepHandover, ALoadedTrimDoesNotMoveTheRegisterAndComesInAlongTheCreep) {
  Rig before(nullptr);
  wear_in(before);
  const TrimZ model(-10.0, 7);
  Rig after(&model);
  after.take_over(before);
  for (int i = 0; i < 5; ++i) after.advance(0.0);  // the switch, the machine standing
  EXPECT_LT(after.largest_z_change_um, 1e-9);
  EXPECT_NEAR(after.z_um(), -12.0, 1e-9);
  EXPECT_EQ(after.engine.counters().handover_rebases, 1U);
  EXPECT_EQ(after.engine.counters().handover_unabsorbed, 0U);
  EXPECT_DOUBLE_EQ(after.engine.register_state(2).trim_um, -10.0);
  // Cutting: the creep's channel goes from −2 back to −12 over 50 mm, linearly.
  for (int i = 0; i < 50; ++i) after.advance(0.5);
  EXPECT_NEAR(after.z_um(), -17.0, 1e-9);
  for (int i = 0; i < 60; ++i) after.advance(0.5);
  EXPECT_NEAR(after.z_um(), -22.0, 1e-9);
  double prev = -12.0;
  for (const double v : after.z_writes) {
    EXPECT_LE(v, prev + 1e-9);  // only ever toward the new total
    EXPECT_GE(v, -22.0 - 1e-9);
    prev = v;
  }
  EXPECT_GT(after.z_writes.size(), 20U);       // crept, not stepped
  EXPECT_LT(after.largest_z_change_um, 0.21);  // 10 µm over 50 mm in 0.5 mm steps: 0.1 each
  // The wear measured stays the creep's: a further 3 µm creep in on top.
  after.measure(15.0);
  for (int i = 0; i < 110; ++i) after.advance(0.5);
  EXPECT_NEAR(after.z_um(), -25.0, 1e-9);
}

TEST(CreepHandover, ARestartInTheMiddleContinuesTheFadeAndRollbackFadesItOut) {
  Rig before(nullptr);
  wear_in(before);
  const TrimZ model(-10.0, 7);
  Rig loaded(&model);
  loaded.take_over(before);
  loaded.advance(0.0);  // the switch
  loaded.advance(0.0);  // the kinematics re-anchor after the rebase
  for (int i = 0; i < 50; ++i) loaded.advance(0.5);
  ASSERT_NEAR(loaded.z_um(), -17.0, 1e-9);

  // A restart with the same model: no handover, the fade goes on from 25 of 50 mm.
  Rig restarted(&model);
  restarted.take_over(loaded);
  restarted.advance(0.0);  // the kinematics re-anchor on the first sample
  EXPECT_EQ(restarted.engine.counters().handover_rebases, 0U);
  EXPECT_NEAR(restarted.z_um(), -17.0, 1e-9);
  for (int i = 0; i < 25; ++i) restarted.advance(0.5);
  EXPECT_NEAR(restarted.z_um(), -19.5, 1e-9);
  for (int i = 0; i < 30; ++i) restarted.advance(0.5);
  EXPECT_NEAR(restarted.z_um(), -22.0, 1e-9);

  // Rollback: the model's −10 µm goes back into the creep's channel and fades out of it.
  Rig none(nullptr);
  none.take_over(restarted);
  none.largest_z_change_um = 0.0;
  for (int i = 0; i < 5; ++i) none.advance(0.0);
  EXPECT_LT(none.largest_z_change_um, 1e-9);
  EXPECT_NEAR(none.z_um(), -22.0, 1e-9);
  EXPECT_EQ(none.engine.counters().handover_rebases, 1U);
  for (int i = 0; i < 50; ++i) none.advance(0.5);
  EXPECT_NEAR(none.z_um(), -17.0, 1e-9);
  for (int i = 0; i < 60; ++i) none.advance(0.5);
  EXPECT_NEAR(none.z_um(), -12.0, 1e-9);
}

// The tool wears 0.1 µm per mm of path; the laser measures the true wear every 100 mm.
constexpr double kRate = 0.1;
void cut_to(Rig& r, double path_mm) {
  while (r.path < path_mm - 1e-9) r.advance(0.5);
}

TEST(CreepHandover, AToolWearTermIsNotCountedTwiceTheCreepLearnsItsResidual) {
  // GIVEN the creep alone, the wear measured at 120 mm (12 µm) and crept in.
  Rig before(nullptr);
  before.ev.emplace_back(ToolChange{before.now, 1, false});
  cut_to(before, 120.0);
  before.measure(kRate * 120.0);
  cut_to(before, 175.0);
  ASSERT_NEAR(before.z_um(), -12.0, 1e-9);
  // WHEN a model predicting the wear (−0.1 µm/mm × path on Z, a tool_wear term) is loaded.
  const WearTrimZ model(kRate);
  Rig after(nullptr, &model);
  after.take_over(before);
  for (int i = 0; i < 5; ++i) after.advance(0.0);
  // THEN Z does not move at the switch (the creep takes the model's −17.5 µm)...
  EXPECT_LT(after.largest_z_change_um, 1e-9);
  EXPECT_NEAR(after.z_um(), -12.0, 1e-9);
  EXPECT_EQ(after.engine.counters().handover_rebases, 1U);
  EXPECT_DOUBLE_EQ(after.engine.register_state(2).trim_um, -17.5);
  // ...the model predicts the wear from there, and after each measurement the register holds
  // the true wear (−rate × path), not the measured wear and the model's again (twice it).
  cut_to(after, 260.0);
  EXPECT_NEAR(after.z_um(), -12.0 - kRate * (260.0 - 175.0), 1e-9);
  for (const double at : {260.0, 360.0, 460.0}) {
    after.measure(kRate * at);
    cut_to(after, at + 60.0);  // the creep's 50 mm
    EXPECT_NEAR(after.z_um(), -kRate * (at + 60.0), 1e-9)
        << "60 mm after the measurement at " << at << " mm";
    cut_to(after, at + 100.0);
    EXPECT_NEAR(after.z_um(), -kRate * (at + 100.0), 1e-9) << "before the next measurement";
  }
  EXPECT_LT(after.largest_z_change_um, 0.21);  // every change crept in 0.5 mm steps

  // A restart with the same model in the middle of a creep: nothing moves, the same totals.
  after.measure(kRate * 560.0);
  cut_to(after, 580.0);
  Rig restarted(nullptr, &model);
  restarted.take_over(after);
  const double at_restart_um = after.z_um();
  restarted.advance(0.0);
  restarted.advance(0.0);
  EXPECT_EQ(restarted.engine.counters().handover_rebases, 0U);
  EXPECT_NEAR(restarted.z_um(), at_restart_um, 1e-9);
  cut_to(restarted, 660.0);
  EXPECT_NEAR(restarted.z_um(), -kRate * 660.0, 1e-9);

  // Rollback: the model's share goes back to the creep without a step, which then holds the
  // last measured wear (56 µm) as it did before the model.
  Rig none(nullptr);
  none.take_over(restarted);
  none.largest_z_change_um = 0.0;
  for (int i = 0; i < 5; ++i) none.advance(0.0);
  EXPECT_LT(none.largest_z_change_um, 1e-9);
  EXPECT_NEAR(none.z_um(), -66.0, 1e-9);
  EXPECT_EQ(none.engine.counters().handover_rebases, 1U);
  cut_to(none, 720.0);
  EXPECT_NEAR(none.z_um(), -56.0, 1e-9);
  none.measure(kRate * 720.0);
  cut_to(none, 780.0);
  EXPECT_NEAR(none.z_um(), -72.0, 1e-9);
}

TEST(CreepHandover, AContourTermOnTheWearRegisterIsAddedOnTopAndNotLearnedAway) {
  // GIVEN the creep alone, the wear measured at 120 mm (12 µm) and crept in.
  Rig before(nullptr);
  before.ev.emplace_back(ToolChange{before.now, 1, false});
  cut_to(before, 120.0);
  before.measure(kRate * 120.0);
  cut_to(before, 175.0);
  ASSERT_NEAR(before.z_um(), -12.0, 1e-9);
  // WHEN a model with the wear term and a contour term of −3 µm on Z (the push-off, which the
  // laser does not see: kind contour) is loaded.
  constexpr double kContour = -3.0;
  const WearTrimZ model(kRate, kContour);
  Rig after(nullptr, &model);
  after.take_over(before);
  for (int i = 0; i < 5; ++i) after.advance(0.0);
  EXPECT_LT(after.largest_z_change_um, 1e-9);
  EXPECT_NEAR(after.z_um(), -12.0, 1e-9);
  EXPECT_DOUBLE_EQ(after.engine.register_state(2).trim_um, -17.5 + kContour);
  // THEN after each laser measurement the register holds the true wear plus the contour term:
  // the creep takes only the tool_wear share as its own, the −3 µm stays on top.
  for (const double at : {260.0, 360.0, 460.0}) {
    cut_to(after, at);
    after.measure(kRate * at);
    cut_to(after, at + 60.0);
    EXPECT_NEAR(after.z_um(), -kRate * (at + 60.0) + kContour, 1e-9)
        << "60 mm after the measurement at " << at << " mm";
    cut_to(after, at + 100.0);
    EXPECT_NEAR(after.z_um(), -kRate * (at + 100.0) + kContour, 1e-9)
        << "before the next measurement";
  }
  EXPECT_LT(after.largest_z_change_um, 0.21);  // the contour term crept in, no step
}

TEST(CreepHandover, AnotherToolStartsFromItsOwnWearAndTheModelsTrimForIt) {
  // GIVEN the model from the start and tool 1 measured at 100 mm: Z holds the true wear.
  const WearTrimZ model(kRate);
  Rig r(nullptr, &model);
  r.ev.emplace_back(ToolChange{r.now, 1, false});
  cut_to(r, 100.0);
  r.measure(kRate * 100.0);
  cut_to(r, 160.0);
  ASSERT_NEAR(r.z_um(), -16.0, 1e-9);
  // WHEN a new tool comes in: THEN Z is the new tool's (no wear, no trim yet) at once, not the
  // old tool's share of the model fading out over the new tool's cut...
  r.tool = 2;
  r.ev.emplace_back(ToolChange{r.now, 2, false});
  r.advance(0.0);
  r.advance(0.0);
  EXPECT_NEAR(r.z_um(), 0.0, 1e-9);
  // ...and the model predicts the new tool's wear from its first millimetre.
  cut_to(r, 210.0);
  EXPECT_NEAR(r.z_um(), -kRate * 50.0, 1e-9);
}

TEST(CreepHandover, TheHandoverStepAllocatesNothing) {
  Rig before(nullptr);
  wear_in(before);
  const TrimZ model(-10.0, 7);
  Rig after(&model);
  after.take_over(before);
  AxisSample a;
  a.time_ns = after.now + 10'000'000;
  a.program_path_mm = after.path;
  a.tool = 1;
  const std::array<Event, 1> events{a};
  {
    const test::AllocationScope scope;
    after.engine.step(a.time_ns, events, after.out);
    EXPECT_EQ(scope.count(), 0U);
    EXPECT_EQ(scope.frees(), 0U);
  }
  EXPECT_EQ(after.engine.counters().handover_rebases, 1U);
}

// GIVEN the creep compensates 12 µm of wear with a lateral deflection of 10 µm per 100 µm of
//      wear toward the material on the right of the feed (feed +X: Y at −1.2 µm), cutting
// WHEN the running daemon reloads (the reload's new engine takes the state and the tool's
//      motion, Engine::export_motion(); no model change, so no rebase: a rebase re-anchors the
//      creep's kinematics on the next sample, see CreepModule::fade_out_shift)
// THEN Y stays at −1.2 µm in every cycle (the feed direction is not lost) and the cut path goes
//      on by every cycle's 0.5 mm (no cycle's path lost).
TEST(CreepHandover, TheToolsMotionGoesOnThroughTheSwap) {
  CreepModuleConfig config = module_config();
  config.creep.edge.material_side = MaterialSide::kRight;
  config.creep.deflection.push_back(DeflectionTable{0, {0.0, 100.0}, {0.0, 0.0}, {0.0, 10.0}});
  Rig before(nullptr, config);
  wear_in(before);
  const double lateral_um = -12.0 * 10.0 / 100.0;
  ASSERT_NEAR(before.engine.register_state(1).output_um, lateral_um, 1e-9);
  const auto creep = [](const Rig& r) -> const WearCompensator& {
    return dynamic_cast<const CreepModule&>(r.engine.module(0)).compensator();
  };
  const auto path_of = [&](const Rig& r) { return creep(r).state().cut_path_mm; };
  const double path_before = path_of(before);

  Rig after(nullptr, config);
  after.take_over(before);
  std::vector<std::byte> motion(engine::kMotionBytes);
  std::size_t carried = 0;
  {
    const test::AllocationScope scope;  // as on the loop thread at the swap
    motion.resize(before.engine.export_motion(motion));
    carried = after.engine.import_motion(motion);
    EXPECT_EQ(scope.count() + scope.frees(), 0U);
  }
  EXPECT_EQ(carried, 2U);  // the context's and the creep's
  for (int i = 0; i < 5; ++i) {
    after.advance(0.5);
    EXPECT_NEAR(creep(after).lateral_um(), -lateral_um, 1e-9) << i;
    EXPECT_NEAR(after.engine.register_state(1).output_um, lateral_um, 1e-9) << i;
  }
  EXPECT_EQ(after.engine.counters().handover_rebases, 0U);
  for (const double y : after.y_writes) EXPECT_NEAR(y, lateral_um, 1e-9);
  EXPECT_NEAR(path_of(after), path_before + 5 * 0.5, 1e-9);
  EXPECT_NEAR(after.engine.context().cut_path_mm(1), path_before + 5 * 0.5, 1e-9);
}

// GIVEN the creep holds Z at −12 µm, cutting, the registers' limiter (and so the creep's own) at
//      most 5 µm per write: less than the value in force, as the demo's 20 µm against 26 µm of
//      wear
// WHEN the running daemon reloads (state and the tool's motion into the new engine), with no
//      model change, or with a model whose tool_wear term takes the whole wear (the demo's load:
//      the rebase leaves the creep's channel as it is, so no re-anchoring)
// THEN Z goes on from −12 µm in the first cycle after the swap: the creep's limiter continues
//      from the value in force, not from 0 (before: −12 → −7 → −12, a one-cycle spike of 5 µm).
TEST(CreepHandover, TheCreepsLimiterGoesOnFromTheValueInForceThroughTheSwap) {
  const CreepModuleConfig config = module_config();
  const LimiterConfig lim{100.0, 5.0, 1e5};
  const WearTrimZ wear_model(0.2);  // 0.2 µm/mm: −11.2 µm at the swap's 56 mm of cut path
  for (const WearTrimZ* model : {static_cast<const WearTrimZ*>(nullptr), &wear_model}) {
    Rig before(nullptr, nullptr, config, lim);
    wear_in(before);
    Rig after(nullptr, model, config, lim);
    after.take_over(before);
    std::vector<std::byte> motion(engine::kMotionBytes);
    motion.resize(before.engine.export_motion(motion));
    ASSERT_EQ(after.engine.import_motion(motion), 2U);
    for (int i = 0; i < 5; ++i) after.advance(0.5);
    const char* what = model == nullptr ? "reload" : "model load";
    // The model's trim grows by 0.1 µm per 0.5 mm after the swap's cycle; the creep's channel
    // holds the wear.
    EXPECT_LT(after.largest_z_change_um, 0.1 + 1e-9) << what;
    EXPECT_NEAR(after.z_um(), model == nullptr ? -12.0 : -12.0 - 0.2 * 4 * 0.5, 1e-9) << what;
    EXPECT_EQ(after.engine.counters().handover_rebases, model == nullptr ? 0U : 1U) << what;
  }
}

}  // namespace
}  // namespace nccomp::core::creep

namespace nccomp::core::creep {
namespace {

// Between parts there is no surface to keep free of steps: a handover's fade comes in at once
// while the tool does not cut between two parts, through the limiter; within a part (cutting,
// between passes) it fades as before.

// GIVEN the creep holds Z at −12 µm, a part started and the tool not cutting yet
// WHEN a model whose trim on Z is −10 µm is loaded
// THEN Z goes to −22 µm at once (one write, the cycle after the rebase's sample), and stays
//      there when the cut starts (nothing fades in over it any more)
TEST(CreepHandover, ATrimLoadedBetweenPartsIsInForceAtOnce) {
  Rig before(nullptr);
  wear_in(before);
  const TrimZ model(-10.0, 7);
  Rig after(&model);
  after.take_over(before);
  after.cutting = false;
  after.ev.emplace_back(ProgramEvent{after.now, ProgramEventKind::kPartStart, 2});
  after.advance(0.0);  // the switch: the register keeps its total
  EXPECT_NEAR(after.z_um(), -12.0, 1e-9);
  after.advance(0.0);  // the kinematics re-anchor: not cutting
  after.advance(0.0);  // the fade's rest comes in
  EXPECT_NEAR(after.z_um(), -22.0, 1e-9);
  EXPECT_EQ(after.engine.counters().handover_rebases, 1U);
  EXPECT_EQ(after.creep().compensator().adoption().fading, 0);
  EXPECT_EQ(after.slewed, 0);
  after.cutting = true;
  const std::size_t writes = after.z_writes.size();
  for (int i = 0; i < 110; ++i) after.advance(0.5);
  EXPECT_NEAR(after.z_um(), -22.0, 1e-9);
  for (std::size_t i = writes; i < after.z_writes.size(); ++i) {
    EXPECT_NEAR(after.z_writes[i], -22.0, 1e-9) << i;  // no step, no fade in the cut
  }
  // The wear measured stays the creep's: a further 3 µm creep in on top.
  after.measure(15.0);
  for (int i = 0; i < 110; ++i) after.advance(0.5);
  EXPECT_NEAR(after.z_um(), -25.0, 1e-9);
}

// GIVEN a part started, the tool not cutting yet
// WHEN the running daemon reloads with the model (the reload's new engine takes the state and
//      the tool's motion, which carries "between parts")
// THEN the trim is in force before the cut, as without the reload
TEST(CreepHandover, AReloadBetweenPartsCarriesItIntoTheNewEngine) {
  Rig before(nullptr);
  wear_in(before);
  before.cutting = false;
  before.ev.emplace_back(ProgramEvent{before.now, ProgramEventKind::kPartStart, 2});
  before.advance(0.0);
  ASSERT_TRUE(before.creep().compensator().between_parts());
  const TrimZ model(-10.0, 7);
  Rig after(&model);
  after.take_over(before);
  after.cutting = false;
  std::vector<std::byte> motion(engine::kMotionBytes);
  motion.resize(before.engine.export_motion(motion));
  ASSERT_EQ(after.engine.import_motion(motion), 2U);
  for (int i = 0; i < 3; ++i) after.advance(0.0);
  EXPECT_NEAR(after.z_um(), -22.0, 1e-9);
  EXPECT_EQ(after.slewed, 0);
}

// GIVEN the trim of −10 µm fading in along the cut (half of it in after 25 of 50 mm)
// WHEN the cut ends between two passes: THEN the fade waits (the next pass lies beside the last:
//      one surface, no ridge between them); WHEN the part ends: THEN the other half comes in at
//      once, and the next part's cut starts at −22 µm
TEST(CreepHandover, AFadeInProgressWhenThePartEndsIsFinishedAtOnce) {
  Rig before(nullptr);
  wear_in(before);
  const TrimZ model(-10.0, 7);
  Rig after(&model);
  after.take_over(before);
  after.advance(0.0);  // the switch, cutting
  after.advance(0.0);
  for (int i = 0; i < 50; ++i) after.advance(0.5);
  ASSERT_NEAR(after.z_um(), -17.0, 1e-9);
  EXPECT_LT(after.largest_z_change_um, 0.21);  // crept while cutting
  after.cutting = false;
  for (int i = 0; i < 5; ++i) after.advance(0.5);  // the link to the next pass
  EXPECT_NEAR(after.z_um(), -17.0, 1e-9);
  after.ev.emplace_back(ProgramEvent{after.now, ProgramEventKind::kPartEnd, 1});
  after.advance(0.0);  // the part end
  after.advance(0.0);  // the fade's rest comes in
  EXPECT_NEAR(after.z_um(), -22.0, 1e-9);
  after.cutting = true;
  for (int i = 0; i < 60; ++i) after.advance(0.5);
  EXPECT_NEAR(after.z_um(), -22.0, 1e-9);
  EXPECT_EQ(after.slewed, 0);
}

// GIVEN a trim loaded while cutting, 25 of its 50 mm faded in (−17 µm)
// WHEN the daemon restarts (same model: no handover) and the next part starts
// THEN what is left of the fade goes on along the creep from −17 µm (the restarted process does
//      not know it was a handover's: it is not applied at once) and ends at −22 µm, never beyond;
//      AND a trim finished at once before a restart is not applied again after it
TEST(CreepHandover, ARestartDoesNotApplyTheHandoverTwice) {
  Rig before(nullptr);
  wear_in(before);
  const TrimZ model(-10.0, 7);
  Rig loaded(&model);
  loaded.take_over(before);
  loaded.advance(0.0);
  loaded.advance(0.0);
  for (int i = 0; i < 50; ++i) loaded.advance(0.5);
  ASSERT_NEAR(loaded.z_um(), -17.0, 1e-9);

  Rig restarted(&model);
  restarted.take_over(loaded);
  restarted.cutting = false;
  restarted.ev.emplace_back(ProgramEvent{restarted.now, ProgramEventKind::kPartStart, 2});
  for (int i = 0; i < 5; ++i) restarted.advance(0.0);
  EXPECT_EQ(restarted.engine.counters().handover_rebases, 0U);
  EXPECT_NEAR(restarted.z_um(), -17.0, 1e-9);
  restarted.cutting = true;
  for (int i = 0; i < 60; ++i) {
    restarted.advance(0.5);
    EXPECT_GE(restarted.z_um(), -22.0 - 1e-9) << i;
  }
  EXPECT_NEAR(restarted.z_um(), -22.0, 1e-9);

  // Finished at once between parts, then a restart: −22 µm stays, cut or not.
  Rig at_once(&model);
  at_once.take_over(before);
  at_once.cutting = false;
  at_once.ev.emplace_back(ProgramEvent{at_once.now, ProgramEventKind::kPartStart, 2});
  for (int i = 0; i < 3; ++i) at_once.advance(0.0);
  ASSERT_NEAR(at_once.z_um(), -22.0, 1e-9);
  Rig again(&model);
  again.take_over(at_once);
  again.cutting = false;
  again.ev.emplace_back(ProgramEvent{again.now, ProgramEventKind::kPartStart, 3});
  for (int i = 0; i < 5; ++i) again.advance(0.0);
  EXPECT_NEAR(again.z_um(), -22.0, 1e-9);
  again.cutting = true;
  for (int i = 0; i < 110; ++i) again.advance(0.5);
  EXPECT_NEAR(again.z_um(), -22.0, 1e-9);
  EXPECT_LT(again.largest_z_change_um, 1e-9);
  EXPECT_EQ(again.engine.counters().handover_rebases, 0U);
}

// GIVEN the registers' limiter (and so the creep's) at 5 µm per write, or at 200 µm/s (2 µm per
//      10 ms cycle), between parts
// WHEN the −10 µm trim is loaded
// THEN it comes in at half of what one write may move per cycle (2.5 µm, 1 µm): no write beyond
//      the limits and none slewed; −22 µm in the end
TEST(CreepHandover, TheLimiterBoundsATrimInForceAtOnce) {
  const TrimZ model(-10.0, 7);
  for (const LimiterConfig lim :
       {LimiterConfig{100.0, 5.0, 1e5}, LimiterConfig{100.0, 50.0, 200.0}}) {
    const double per_cycle_um = 0.5 * std::min(lim.max_step_um, lim.max_rate_um_per_s * 0.01);
    Rig before(nullptr, nullptr, module_config(), lim);
    wear_in(before);
    Rig after(&model, nullptr, module_config(), lim);
    after.take_over(before);
    after.cutting = false;
    after.ev.emplace_back(ProgramEvent{after.now, ProgramEventKind::kPartStart, 2});
    after.largest_z_change_um = 0.0;
    int steps = 0;
    for (; steps < 40 && std::fabs(after.z_um() + 22.0) > 1e-9; ++steps) after.advance(0.0);
    EXPECT_NEAR(after.z_um(), -22.0, 1e-9) << lim.max_step_um;
    EXPECT_LE(after.largest_z_change_um, per_cycle_um + 1e-9) << lim.max_step_um;
    EXPECT_GE(steps, static_cast<int>(10.0 / per_cycle_um)) << lim.max_step_um;
    EXPECT_EQ(after.slewed, 0) << lim.max_step_um;
  }
}

}  // namespace
}  // namespace nccomp::core::creep
