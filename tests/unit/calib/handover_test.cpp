// Trim handover on S3's registers (core/engine/engine.hpp, "Trim handover";
// Calibrator::rebase()): GIVEN a calibrated machine whose X axis drifted +12 µm, measured in
// program coordinates (the NC's offset holds S3's correction and every trim on it), WHEN a model
// whose trim on X is −5 µm is loaded into the running engine THEN the X register does not move
// (S3's correction becomes 17 µm), the next touch set measures the drift less the trim, so S3
// keeps 17 and follows a further drift as a residual; the same model after a restart is not
// rebased again; taking the model out hands the 5 µm back to S3.
#include <gtest/gtest.h>

#include <cmath>
#include <memory>
#include <vector>

#include "core/calib/calib_module.hpp"
#include "core/engine/engine.hpp"
#include "tests/support/alloc_counter.hpp"
#include "tests/unit/calib/sim_machine.hpp"
#include "tests/unit/calib/test_config.hpp"

namespace nccomp::test::calib {
namespace {

using core::Event;
using core::OffsetWrite;
using core::StepOutput;
using core::calib::CalibrationModule;
using core::calib::Phase;
using core::calib::Slot;
using core::engine::Engine;
using core::engine::RegisterKind;
using core::engine::RegisterSpec;

// A model's trim of the X register (0), with the identity of its model.
class TrimX final : public core::engine::Module {
 public:
  TrimX(double trim, std::uint64_t identity) : trim_(trim), identity_(identity) {}
  std::string_view name() const noexcept override { return "model"; }
  void attach(const core::engine::RegisterTable& /*registers*/) override {}
  void step(TimeNs now_ns, std::span<const Event> /*events*/, StepOutput& out) noexcept override {
    out.trims.push(OffsetWrite{now_ns, 0, trim_});
  }
  std::uint64_t trim_identity() const noexcept override { return identity_; }
  double trim_;
  std::uint64_t identity_;
};

CalibrationConfig config() {
  auto c = test_config();
  c.register_x = 0;
  c.register_y = 1;
  c.register_z = 2;
  c.touches_per_axis = 1;
  c.touch_positions = core::calib::TouchPositions::kProgram;
  c.prediction = core::calib::Prediction::kNone;
  c.creep_duration_s = 300.0;
  c.recalibration_interval_s = 0.0;
  c.write_deadband_um = 0.0;
  return c;
}

struct Rig {
  Engine engine;
  SimMachine* sim;
  StepOutput out;
  TimeNs now{0};
  double largest_x_change_um{0.0};

  Rig(SimMachine& machine, const TrimX* model) : sim(&machine) {
    std::vector<std::unique_ptr<core::engine::Module>> m;
    m.push_back(std::make_unique<CalibrationModule>(config()));
    if (model != nullptr) m.push_back(std::make_unique<TrimX>(model->trim_, model->identity_));
    std::vector<RegisterSpec> regs;
    for (const char* n : {"X_offset", "Y_offset", "Z_offset"}) {
      regs.push_back({n, RegisterKind::kAxisOffset, {500.0, 50.0, 1e6}});
    }
    engine.configure(std::move(regs), std::move(m));
  }
  CalibrationModule& module() { return dynamic_cast<CalibrationModule&>(engine.module(0)); }
  // One engine step at now, then 1 s on; the NC (ncsim's offsets) takes every write.
  void step(std::span<const Event> events = {}) {
    engine.step(now, events, out);
    for (const auto& w : out.writes) {
      if (w.register_index == 0) {
        largest_x_change_um =
            std::max(largest_x_change_um, std::fabs(w.value_um - sim->offset_um[0]));
      }
      if (w.register_index < 3) sim->offset_um[w.register_index] = w.value_um;
    }
    now += core::from_seconds(1.0);
  }
  void idle(int seconds) {
    for (int s = 0; s < seconds; ++s) step();
  }
  void touch_set() {
    std::array<Event, 4> t{};
    for (std::size_t slot = 0; slot < 4; ++slot) t[slot] = sim->machine_touch(slot, 1, now);
    step(t);
  }
  void take_over(const Rig& from) {
    now = from.now;
    std::vector<std::byte> buf(from.engine.state_capacity());
    buf.resize(from.engine.export_state(buf));
    ASSERT_TRUE(engine.import_state(buf, now));
    largest_x_change_um = 0.0;
  }
  double x_correction_um() {
    return module().calibrator().drift_correction_um(Slot::kXLateral, now);
  }
};

// Calibrated through the engine, then an X drift of +12 µm measured and crept in.
void calibrate(Rig& r) {
  r.module().calibrator().begin_calibration(r.now, r.out);
  for (std::size_t slot = 0; slot < 4; ++slot) {
    const Event e = r.sim->reference_touch(slot, 1, r.now);
    r.step({&e, 1});
  }
  for (const bool end_face : {false, true}) {
    auto& c = r.module().calibrator();
    while (c.phase() == (end_face ? Phase::kTestGrindEndFace : Phase::kTestGrindLateral)) {
      r.idle(30);
      const auto [plus, minus] = r.sim->test_grind(end_face, r.sim->offset_um[0]);
      StepOutput scratch;
      c.enter_facets(end_face ? core::calib::Face::kEndFace : core::calib::Face::kLateral, plus,
                     minus, r.now, scratch);
    }
  }
  r.idle(60);
  for (std::size_t slot = 0; slot < 4; ++slot) {
    const Event e = r.sim->machine_touch(slot, 1, r.now);
    r.step({&e, 1});
  }
  ASSERT_EQ(r.module().calibrator().phase(), Phase::kReady);
  r.sim->set_drift([](double) { return std::array<double, 4>{12.0, 12.0, 0.0, 0.0}; });
  r.idle(3600);
  r.touch_set();
  r.idle(400);  // the creep (300 s) is done
}

TEST(CalibrationHandover, ALoadedTrimKeepsTheAxisWhereItIsAndS3LearnsTheResidual) {
  SimMachine sim(config(), test_errors(), 0.0, 0.0, 0.1, 5);
  sim.set_program_frame(true);
  Rig before(sim, nullptr);
  calibrate(before);
  const double base_x = before.module().calibrator().result().dx_r_um;
  ASSERT_NEAR(before.x_correction_um(), 12.0, 1e-9);
  const double x0 = sim.offset_um[0];
  ASSERT_NEAR(x0, base_x + 12.0, 1e-9);

  const TrimX model(-5.0, 7);
  Rig after(sim, &model);
  after.take_over(before);
  after.idle(20);
  // The register stays: S3 takes 12 − (−5) = 17 µm, the trim −5.
  EXPECT_LT(after.largest_x_change_um, 1e-9);
  EXPECT_NEAR(sim.offset_um[0], x0, 1e-9);
  EXPECT_NEAR(after.x_correction_um(), 17.0, 1e-9);
  EXPECT_DOUBLE_EQ(after.engine.register_state(0).trim_um, -5.0);
  EXPECT_EQ(after.engine.counters().handover_rebases, 1U);
  EXPECT_EQ(after.engine.counters().handover_unabsorbed, 0U);

  // The next touch set reads machine − (S3 + trim) and adds back S3's 17: a drift of 17, the
  // residual the model leaves. Nothing moves.
  after.idle(3600);
  after.touch_set();
  after.idle(400);
  EXPECT_NEAR(after.x_correction_um(), 17.0, 1e-9);
  EXPECT_NEAR(sim.offset_um[0], base_x + 12.0, 1e-9);
  EXPECT_LT(after.largest_x_change_um, 1e-9);
  // A further drift of 2 µm is S3's: it creeps in, the axis ends at base + 14.
  sim.set_drift([](double) { return std::array<double, 4>{14.0, 14.0, 0.0, 0.0}; });
  after.idle(3600);
  after.touch_set();
  after.idle(400);
  EXPECT_NEAR(after.x_correction_um(), 19.0, 1e-9);
  EXPECT_NEAR(sim.offset_um[0], base_x + 14.0, 1e-9);
}

TEST(CalibrationHandover, ARestartWithTheSameModelKeepsTheRebaseAndRollbackHandsItBack) {
  SimMachine sim(config(), test_errors(), 0.0, 0.0, 0.1, 5);
  sim.set_program_frame(true);
  Rig before(sim, nullptr);
  calibrate(before);
  const double x0 = sim.offset_um[0];
  const TrimX model(-5.0, 7);
  Rig with(sim, &model);
  with.take_over(before);
  with.idle(20);
  ASSERT_NEAR(with.x_correction_um(), 17.0, 1e-9);

  Rig restarted(sim, &model);
  restarted.take_over(with);
  restarted.idle(20);
  EXPECT_NEAR(restarted.x_correction_um(), 17.0, 1e-9);
  EXPECT_EQ(restarted.engine.counters().handover_rebases, 0U);
  EXPECT_LT(restarted.largest_x_change_um, 1e-9);

  Rig none(sim, nullptr);
  none.take_over(restarted);
  none.idle(20);
  EXPECT_NEAR(none.x_correction_um(), 12.0, 1e-9);
  EXPECT_NEAR(sim.offset_um[0], x0, 1e-9);
  EXPECT_LT(none.largest_x_change_um, 1e-9);
  EXPECT_EQ(none.engine.counters().handover_rebases, 1U);
}

TEST(CalibrationHandover, TheHandoverStepAllocatesNothing) {
  SimMachine sim(config(), test_errors(), 0.0, 0.0, 0.1, 5);
  sim.set_program_frame(true);
  Rig before(sim, nullptr);
  calibrate(before);
  const TrimX model(-5.0, 7);
  Rig after(sim, &model);
  after.take_over(before);
  {
    const AllocationScope scope;
    after.engine.step(after.now, {}, after.out);
    EXPECT_EQ(scope.count(), 0U);
    EXPECT_EQ(scope.frees(), 0U);
  }
  EXPECT_EQ(after.engine.counters().handover_rebases, 1U);
}

}  // namespace
}  // namespace nccomp::test::calib
