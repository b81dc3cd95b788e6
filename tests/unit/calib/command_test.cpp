// Operator commands as events (the daemon's command channel), the snapshots the module
// publishes for the operator's side, and a restart of the module mid-creep.
//
// GIVEN a CalibrationModule with a snapshot sink
// WHEN the whole initial calibration is driven by OperatorCommand events (begin, typed touches,
//   facets), then a recalibration on demand
// THEN each command's outcome is published under its sequence number with its status and the
//   facet result, bad commands are refused and counted without changing anything, the module's
//   step() (commands and publication included) allocates nothing, and a module restored from
//   the saved bytes writes on from the value the NC holds (no slew from 0).
#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "core/calib/calib_module.hpp"
#include "core/calib/snapshot.hpp"
#include "tests/support/alloc_counter.hpp"
#include "tests/unit/calib/sim_machine.hpp"
#include "tests/unit/calib/test_config.hpp"

namespace nccomp::test::calib {
namespace {

using core::Event;
using core::OperatorCommand;
using core::OperatorCommandKind;
using core::StepOutput;
using core::TimeNs;
using core::calib::CalibrationModule;
using core::calib::CalibSnapshot;
using core::calib::CommandStatus;
using core::calib::FacetStatus;
using core::calib::Phase;
using core::engine::RegisterKind;
using core::engine::RegisterSpec;
using core::engine::RegisterTable;

struct Sink final : core::calib::SnapshotSink {
  void publish(const CalibSnapshot& s) noexcept override {
    last = s;
    ++count;
  }
  CalibSnapshot last{};
  std::size_t count{0};
};

std::vector<RegisterSpec> specs() {
  std::vector<RegisterSpec> r(4);
  const char* names[] = {"X", "Y", "Z", "request"};
  for (std::size_t i = 0; i < 4; ++i) {
    r[i].name = names[i];
    r[i].kind = i < 3 ? RegisterKind::kAxisOffset : RegisterKind::kFlag;
  }
  return r;
}

CalibrationConfig cfg() {
  auto c = test_config();
  c.register_x = 0;
  c.register_y = 1;
  c.register_z = 2;
  c.request_register = 3;
  c.touches_per_axis = 1;
  return c;
}

OperatorCommand command(std::uint32_t seq, OperatorCommandKind kind) {
  OperatorCommand c;
  c.sequence = seq;
  c.kind = kind;
  return c;
}

OperatorCommand touch_command(std::uint32_t seq, const core::CalibrationTouch& t) {
  auto c = command(seq, OperatorCommandKind::kCalibrationTouch);
  c.code = {static_cast<std::int8_t>(t.probe == core::ProbeKind::kReferenceProbe ? 1 : 0),
            static_cast<std::int8_t>(t.axis), t.direction, static_cast<std::int8_t>(t.variant)};
  c.value = {t.trigger_position_mm, 0.0};
  return c;
}

class Driver {
 public:
  Driver() : m_(cfg(), test_errors(), 0.3, 0.3, 0.1, 9) {
    module_.attach(RegisterTable(specs_));
    module_.set_snapshot_sink(&sink_);
  }
  /// One cycle with one command; returns the snapshot answering it.
  const CalibSnapshot& send(const OperatorCommand& c) {
    const Event e = c;
    out_.clear();
    module_.step(now_, {&e, 1}, out_);
    now_ += core::from_seconds(1.0);
    return sink_.last;
  }
  void idle(int cycles) {
    for (int i = 0; i < cycles; ++i) {
      out_.clear();
      module_.step(now_, {}, out_);
      now_ += core::from_seconds(1.0);
    }
  }
  CalibrationModule module_{cfg()};
  Sink sink_;
  SimMachine m_;
  TimeNs now_{0};
  StepOutput out_;
  std::vector<RegisterSpec> specs_{specs()};
};

TEST(CalibrationCommands, DriveTheWholeCalibrationAndAnswerEachCommand) {
  Driver d;
  d.idle(1);
  EXPECT_EQ(d.sink_.last.state.phase, Phase::kUncalibrated);
  std::uint32_t seq = 0;
  // Facets before a calibration started: refused, nothing changes.
  auto f = command(++seq, OperatorCommandKind::kCalibrationFacets);
  f.value = {1.99, 1.98};
  auto s = d.send(f);
  EXPECT_EQ(s.last_command.sequence, seq);
  EXPECT_EQ(s.last_command.status, CommandStatus::kWrongPhase);
  EXPECT_EQ(s.commands_refused, 1u);
  // Recalibration on demand is refused before a calibration exists.
  s = d.send(command(++seq, OperatorCommandKind::kCalibrationRecalibrate));
  EXPECT_EQ(s.last_command.status, CommandStatus::kWrongPhase);
  s = d.send(command(++seq, OperatorCommandKind::kCalibrationBegin));
  EXPECT_EQ(s.last_command.status, CommandStatus::kOk);
  EXPECT_EQ(s.state.phase, Phase::kReferenceTouches);
  EXPECT_EQ(s.request, core::calib::RequestCode::kReferenceTouches);
  // A touch with a machine probe now is not expected: refused with warning 45 attached.
  s = d.send(touch_command(++seq, d.m_.machine_touch(0, 1, d.now_)));
  EXPECT_EQ(s.last_command.status, CommandStatus::kWrongPhase);
  ASSERT_EQ(s.last_command.alarm_count, 1u);
  EXPECT_EQ(s.last_command.alarms[0].code, core::AlarmCode::kTouchUnexpected);
  // A malformed touch (axis 7): invalid input.
  auto bad = touch_command(++seq, d.m_.reference_touch(0, 1, d.now_));
  bad.code[1] = 7;
  s = d.send(bad);
  EXPECT_EQ(s.last_command.status, CommandStatus::kInvalidInput);
  EXPECT_EQ(s.progress.count[0], 0);
  for (std::size_t slot = 0; slot < 4; ++slot) {
    s = d.send(touch_command(++seq, d.m_.reference_touch(slot, 1, d.now_)));
    EXPECT_EQ(s.last_command.status, CommandStatus::kOk) << slot;
  }
  EXPECT_EQ(s.state.phase, Phase::kTestGrindLateral);
  // Chords out of range: invalid, the grind count does not move.
  f = command(++seq, OperatorCommandKind::kCalibrationFacets);
  f.value = {11.0, 1.98};  // longer than the blank's diameter
  s = d.send(f);
  EXPECT_EQ(s.last_command.status, CommandStatus::kInvalidInput);
  EXPECT_EQ(s.state.grinds, 0);
  int grinds = 0;
  for (const bool end_face : {false, true}) {
    const auto want = end_face ? Phase::kTestGrindEndFace : Phase::kTestGrindLateral;
    while (d.sink_.last.state.phase == want) {
      d.idle(20);  // X slews to the Δx to grind with
      const double dx = d.module_.calibrator().grind_correction_um();
      EXPECT_NEAR(d.sink_.last.written_um[0], dx, 1e-9);
      const auto [p, q] = d.m_.test_grind(end_face, dx);
      f = command(++seq, OperatorCommandKind::kCalibrationFacets);
      f.code[0] = end_face ? 1 : 0;
      f.value = {p, q};
      s = d.send(f);
      ++grinds;
      EXPECT_EQ(s.last_command.status, CommandStatus::kOk);
      EXPECT_TRUE(s.last_command.facet.status == FacetStatus::kGrindAgain ||
                  s.last_command.facet.status == FacetStatus::kConverged);
      EXPECT_EQ(s.last_command.phase_before, want);
    }
  }
  EXPECT_LE(grinds, 6);
  EXPECT_EQ(s.state.phase, Phase::kNominalTouches);
  EXPECT_NEAR(s.state.result.dx_r_um, test_errors().ex_um, 0.5);
  EXPECT_NEAR(s.state.result.dx_a_um, test_errors().exa_um, 0.5);
  // The completion's info 48 is attached to the command that completed it.
  bool complete = false;
  for (std::uint32_t i = 0; i < s.last_command.alarm_count; ++i) {
    complete |= s.last_command.alarms[i].code == core::AlarmCode::kCalibrationComplete;
  }
  EXPECT_TRUE(complete);
  d.idle(60);
  for (std::size_t slot = 0; slot < 4; ++slot) {
    s = d.send(touch_command(++seq, d.m_.machine_touch(slot, 1, d.now_)));
  }
  EXPECT_EQ(s.state.phase, Phase::kReady);
  EXPECT_NEAR(s.target_um[0], s.state.result.dx_r_um, 1e-9);
  // On demand: the request goes up; a touch set (from the bus) clears it.
  s = d.send(command(++seq, OperatorCommandKind::kCalibrationRecalibrate));
  EXPECT_EQ(s.last_command.status, CommandStatus::kOk);
  EXPECT_EQ(s.request, core::calib::RequestCode::kRecalibration);
  d.m_.set_drift([](double) { return std::array<double, 4>{5.0, 5.0, -2.0, 1.0}; });
  std::array<Event, 4> set{};
  for (std::size_t slot = 0; slot < 4; ++slot) set[slot] = d.m_.machine_touch(slot, 1, d.now_);
  d.out_.clear();
  d.module_.step(d.now_, set, d.out_);
  EXPECT_EQ(d.sink_.last.request, core::calib::RequestCode::kNone);
  EXPECT_NEAR(d.sink_.last.state.models[0].anchor_drift_um, 5.0, 1.0);
  // Unknown kinds are refused.
  s = d.send(command(++seq, static_cast<OperatorCommandKind>(77)));
  EXPECT_EQ(s.last_command.status, CommandStatus::kUnknown);
  EXPECT_EQ(s.commands_refused, 6u);
  // The wall clock of the snapshot follows the clock offset.
  d.module_.set_clock_offset_s(1.8e9);
  s = d.send(command(++seq, OperatorCommandKind::kCalibrationStatus));
  EXPECT_NEAR(s.wall_time_s - s.time_s, 1.8e9, 1e-3);
}

TEST(CalibrationCommands, StepWithCommandsAndPublicationAllocatesNothing) {
  Driver d;
  d.idle(2);
  std::uint32_t seq = 0;
  std::size_t allocations = 0;
  {
    const AllocationScope scope;
    d.send(command(++seq, OperatorCommandKind::kCalibrationBegin));
    for (std::size_t slot = 0; slot < 4; ++slot) {
      d.send(touch_command(++seq, d.m_.reference_touch(slot, 1, d.now_)));
    }
    auto f = command(++seq, OperatorCommandKind::kCalibrationFacets);
    f.value = {1.99, 1.98};
    d.send(f);
    d.send(command(++seq, OperatorCommandKind::kCalibrationStatus));
    d.idle(5);
    allocations = scope.count();
  }
  EXPECT_EQ(allocations, 0u);
  EXPECT_GE(d.sink_.count, 9u);
  EXPECT_EQ(d.sink_.last.last_command.sequence, seq);
}

TEST(CalibrationCommands, RestoredModuleWritesOnFromTheValueTheNcHolds) {
  Driver d;
  ASSERT_TRUE(run_initial_calibration(d.module_.calibrator(), d.m_, d.now_, d.out_));
  d.idle(120);  // registers slewed to the calibration
  d.m_.set_drift([](double) { return std::array<double, 4>{9.0, 9.0, 4.0, -3.0}; });
  std::array<Event, 4> set{};
  for (std::size_t slot = 0; slot < 4; ++slot) set[slot] = d.m_.machine_touch(slot, 1, d.now_);
  d.out_.clear();
  d.module_.step(d.now_, set, d.out_);
  d.idle(200);  // mid-creep (600 s)
  const double held_x = d.module_.calibrator().written_um(0);
  ASSERT_TRUE(std::isfinite(held_x));
  std::vector<std::byte> buf(d.module_.state_capacity());
  ASSERT_EQ(d.module_.save_state(buf), CalibrationModule::kStateBytes);

  // Restart: a new module, a monotonic clock that starts again near 0 (reboot) with the clock
  // offset telling where the wall clock is.
  const double wall_before = 1.79e9;  // wall = monotonic + offset before ...
  d.module_.set_clock_offset_s(wall_before);
  ASSERT_EQ(d.module_.save_state(buf), CalibrationModule::kStateBytes);
  const TimeNs t_old = d.now_;
  const double restart_mono_s = 5.0;  // ... and after: the same wall time 5 s after boot
  CalibrationModule restored(cfg());
  const auto sp = specs();
  restored.attach(RegisterTable(sp));
  restored.set_clock_offset_s(wall_before + core::seconds(t_old) - restart_mono_s);
  ASSERT_TRUE(restored.load_state(buf));
  StepOutput out;
  const TimeNs t_new = core::from_seconds(restart_mono_s);
  restored.step(t_new, {}, out);
  // The first write after the restart continues from where the NC is, never from 0.
  for (const auto& w : out.writes) {
    if (w.register_index == 0) {
      EXPECT_NEAR(w.value_um, held_x, 5.0 + 1e-9);
      EXPECT_LT(std::fabs(w.value_um - held_x), 1.0) << "a jump of the X register";
    }
  }
  // And the creep and model continue: the same target as the old module at the same wall time.
  for (std::size_t axis = 0; axis < 3; ++axis) {
    EXPECT_NEAR(restored.calibrator().target_um(axis, t_new + core::from_seconds(100.0)),
                d.module_.calibrator().target_um(axis, t_old + core::from_seconds(100.0)), 1e-6)
        << axis;
  }
  // A state saved without the written values (older daemons) is still taken.
  CalibrationModule old_format(cfg());
  old_format.attach(RegisterTable(sp));
  EXPECT_TRUE(old_format.load_state(
      std::span<const std::byte>(buf.data(), sizeof(core::calib::CalibState))));
  EXPECT_EQ(old_format.calibrator().phase(), Phase::kReady);
  EXPECT_FALSE(old_format.load_state(
      std::span<const std::byte>(buf.data(), sizeof(core::calib::CalibState) + 1)));
}

TEST(CalibrationCommands, RebaseClockKeepsTheWallClockTimes) {
  Driver d;
  ASSERT_TRUE(run_initial_calibration(d.module_.calibrator(), d.m_, d.now_, d.out_));
  d.module_.set_clock_offset_s(1000.0);
  const auto before = d.module_.calibrator().export_state();
  const double target = d.module_.calibrator().target_um(0, d.now_ + core::from_seconds(50.0));
  d.module_.rebase_clock(1300.0);  // the loop's clock origin moved 300 s earlier
  const auto after = d.module_.calibrator().export_state();
  EXPECT_DOUBLE_EQ(after.nominals[0].time_s, before.nominals[0].time_s);
  EXPECT_NEAR(d.module_.calibrator().target_um(
                  0, d.now_ - core::from_seconds(300.0) + core::from_seconds(50.0)),
              target, 1e-9);
}

}  // namespace
}  // namespace nccomp::test::calib
