// The touch-reading convention (machine vs program coordinates), the request register the NC
// polls, and the X register during test grinds.
//
// GIVEN a simulated machine whose NC reports program coordinates (machine position − the axis
// offset it holds), with a constant drift after the nominals
// WHEN it is recalibrated every hour, the NC taking every register write
// THEN with touch_positions = "program" every correction after the first equals the drift (within
//   the touch noise) and the axis error stays below 1 µm: the corrections converge;
//   with the wrong setting ("machine") the same machine makes them alternate between the drift
//   and about zero (the failure the convention exists for).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "core/calib/calibrator.hpp"
#include "tests/unit/calib/sim_machine.hpp"
#include "tests/unit/calib/test_config.hpp"

namespace nccomp::test::calib {
namespace {

using core::Event;
using core::StepOutput;
using core::TimeNs;
using core::calib::Calibrator;
using core::calib::Phase;
using core::calib::RequestCode;
using core::calib::Slot;
using core::calib::TouchPositions;

// The NC: takes every write of the three axis registers.
void take_writes(const CalibrationConfig& cfg, const StepOutput& out, SimMachine& m) {
  const std::array<std::uint16_t, 3> reg{cfg.register_x, cfg.register_y, cfg.register_z};
  for (const auto& w : out.writes) {
    for (std::size_t a = 0; a < 3; ++a) {
      if (w.register_index == reg[a]) {
        m.offset_um[a] = w.value_um;
      }
    }
  }
}

struct Convergence {
  std::vector<double> correction_um;  // X correction in force after each recalibration's creep
  std::vector<double> error_um;       // true X error (drift − correction) then
};

Convergence run(TouchPositions positions, int sets) {
  auto cfg = test_config();
  cfg.touch_positions = positions;
  cfg.touches_per_axis = 2;
  cfg.prediction = core::calib::Prediction::kNone;
  cfg.creep_duration_s = 300.0;
  cfg.recalibration_interval_s = 0.0;
  Calibrator c;
  c.configure(cfg);
  SimMachine m(cfg, test_errors(), 0.3, 0.3, 0.1, 21);
  m.set_program_frame(true);
  // An old calibration is still in force when the new one starts (program frame: it shifts
  // the reference touches too).
  m.offset_um = {7.0, -3.0, 2.0};
  c.sync_register(0, 7.0, 0);
  c.sync_register(1, -3.0, 0);
  c.sync_register(2, 2.0, 0);
  TimeNs now = 0;
  StepOutput out;
  // The initial calibration step by step, the NC taking the writes as they come.
  out.clear();
  c.begin_calibration(now, out);
  const auto one = [&](const core::CalibrationTouch& t) {
    const Event e = t;
    out.clear();
    c.step(now, {&e, 1}, out);
    take_writes(cfg, out, m);
    now += core::from_seconds(1.0);
  };
  const auto idle = [&](double seconds) {
    for (double s = 0; s < seconds; s += 1.0) {
      out.clear();
      c.step(now, {}, out);
      take_writes(cfg, out, m);
      now += core::from_seconds(1.0);
    }
  };
  for (std::size_t slot = 0; slot < 4; ++slot) {
    for (int i = 0; i < cfg.touches_per_axis; ++i) {
      one(m.reference_touch(slot, 1, now));
    }
  }
  for (const bool end_face : {false, true}) {
    const auto face = end_face ? core::calib::Face::kEndFace : core::calib::Face::kLateral;
    while (c.phase() == (end_face ? Phase::kTestGrindEndFace : Phase::kTestGrindLateral)) {
      idle(30.0);  // the X register slews to the Δx to grind with
      EXPECT_NEAR(m.offset_um[0], c.grind_correction_um(), 1e-9);
      const auto [plus, minus] = m.test_grind(end_face, m.offset_um[0]);
      out.clear();
      c.enter_facets(face, plus, minus, now, out);
    }
  }
  idle(60.0);
  for (std::size_t slot = 0; slot < 4; ++slot) {
    for (int i = 0; i < cfg.touches_per_axis; ++i) one(m.machine_touch(slot, 1, now));
  }
  EXPECT_EQ(c.phase(), Phase::kReady);
  const double base_x = c.result().dx_r_um;
  EXPECT_NEAR(base_x, test_errors().ex_um, 1.0);
  // A constant drift after the nominals: X +12, X axial +15, Y −6, Z +4 µm.
  m.set_drift([](double) { return std::array<double, 4>{12.0, 15.0, -6.0, 4.0}; });
  Convergence r;
  for (int k = 0; k < sets; ++k) {
    idle(3600.0);
    for (std::size_t slot = 0; slot < 4; ++slot) {
      for (int i = 0; i < cfg.touches_per_axis; ++i) one(m.machine_touch(slot, 1, now));
    }
    idle(400.0);  // the creep (300 s) is done
    const double corr = c.drift_correction_um(Slot::kXLateral, now);
    r.correction_um.push_back(corr);
    // The register the NC holds is base + correction: the error left is drift − correction.
    r.error_um.push_back(12.0 - (m.offset_um[0] - base_x));
  }
  return r;
}

TEST(TouchConvention, ProgramCoordinatesConvergeOverRepeatedRecalibrations) {
  const Convergence ok = run(TouchPositions::kProgram, 8);
  for (std::size_t k = 0; k < ok.correction_um.size(); ++k) {
    EXPECT_NEAR(ok.correction_um[k], 12.0, 0.8) << "set " << k;
    EXPECT_LT(std::fabs(ok.error_um[k]), 0.8) << "set " << k;
  }
  // No alternation: consecutive corrections differ by the touch noise only.
  for (std::size_t k = 1; k < ok.correction_um.size(); ++k) {
    EXPECT_LT(std::fabs(ok.correction_um[k] - ok.correction_um[k - 1]), 1.0) << k;
  }
}

TEST(TouchConvention, MachineSettingOnAProgramCoordinateNcAlternates) {
  const Convergence bad = run(TouchPositions::kMachine, 6);
  // Set 1 reads the drift; with it in force set 2 reads ~0 and takes it out again, and so on.
  ASSERT_EQ(bad.correction_um.size(), 6u);
  for (std::size_t k = 0; k < bad.correction_um.size(); ++k) {
    const double expect = k % 2 == 0 ? 12.0 : 0.0;
    EXPECT_NEAR(bad.correction_um[k], expect, 1.5) << "set " << k;
  }
}

TEST(RequestRegister, FollowsThePhaseTheScheduleAndTheOperator) {
  auto cfg = test_config();
  cfg.touches_per_axis = 1;
  cfg.request_register = 50;
  cfg.recalibration_interval_s = 1800.0;
  Calibrator c;
  c.configure(cfg);
  SimMachine m(cfg, test_errors(), 0.2, 0.2, 0.1, 5);
  TimeNs now = 0;
  StepOutput out;
  std::vector<double> codes;  // every value written to the request register
  const auto step = [&](std::span<const Event> ev = {}) {
    out.clear();
    c.step(now, ev, out);
    for (const auto& w : out.writes) {
      if (w.register_index == 50) codes.push_back(w.value_um);
    }
    now += core::from_seconds(1.0);
  };
  step();
  ASSERT_EQ(codes, std::vector<double>{0.0});  // defined from the first cycle: nothing wanted
  EXPECT_FALSE(c.request_recalibration());     // not calibrated: refused
  out.clear();
  c.begin_calibration(now, out);
  step();
  EXPECT_EQ(codes.back(), 1.0);  // reference touches
  for (std::size_t s = 0; s < 4; ++s) {
    const Event e = m.reference_touch(s, 1, now);
    step({&e, 1});
  }
  EXPECT_EQ(codes.back(), 2.0);  // lateral test grind
  // The X register carries the Δx to grind with; Y and Z are not written.
  bool x_written = false;
  for (int i = 0; i < 30; ++i) {
    out.clear();
    c.step(now, {}, out);
    for (const auto& w : out.writes) {
      EXPECT_NE(w.register_index, cfg.register_y);
      EXPECT_NE(w.register_index, cfg.register_z);
      x_written |= w.register_index == cfg.register_x;
    }
    now += core::from_seconds(1.0);
  }
  EXPECT_TRUE(x_written);
  EXPECT_NEAR(c.written_um(0), c.grind_correction_um(), 1e-9);
  EXPECT_DOUBLE_EQ(c.target_um(0, now), c.grind_correction_um());
  for (const bool end_face : {false, true}) {
    const auto want = end_face ? Phase::kTestGrindEndFace : Phase::kTestGrindLateral;
    while (c.phase() == want) {
      const auto [p, q] = m.test_grind(end_face, c.grind_correction_um());
      out.clear();
      c.enter_facets(end_face ? core::calib::Face::kEndFace : core::calib::Face::kLateral, p, q,
                     now, out);
      step();
      if (c.phase() == want) {
        EXPECT_EQ(codes.back(), end_face ? 3.0 : 2.0);
      }
    }
  }
  EXPECT_EQ(codes.back(), 4.0);  // nominal touches
  for (std::size_t s = 0; s < 4; ++s) {
    const Event e = m.machine_touch(s, 1, now);
    step({&e, 1});
  }
  EXPECT_EQ(codes.back(), 0.0);  // ready, nothing due
  EXPECT_EQ(c.request(), RequestCode::kNone);
  // The schedule: due 1800 s after the nominals.
  for (int i = 0; i < 1790; ++i) step();
  EXPECT_EQ(codes.back(), 0.0);
  for (int i = 0; i < 20; ++i) step();
  EXPECT_EQ(codes.back(), 5.0);
  // The touch set clears it.
  for (std::size_t s = 0; s < 4; ++s) {
    const Event e = m.machine_touch(s, 1, now);
    step({&e, 1});
  }
  EXPECT_EQ(codes.back(), 0.0);
  // On demand, long before the next due time.
  for (int i = 0; i < 60; ++i) step();
  EXPECT_TRUE(c.request_recalibration());
  step();
  EXPECT_EQ(codes.back(), 5.0);
  // A scattered (refused) set clears it too: the alarm tells the operator.
  std::array<Event, 4> set{};
  for (std::size_t s = 0; s < 4; ++s) set[s] = m.machine_touch(s, 1, now);
  out.clear();
  c.step(now, set, out);  // one touch per slot: no scatter; accepted
  for (const auto& w : out.writes) {
    if (w.register_index == 50) codes.push_back(w.value_um);
  }
  EXPECT_EQ(codes.back(), 0.0);
  // Only changes are written: 0,1,2,(3 or 2 again not repeated),4,0,5,0,5,0.
  for (std::size_t i = 1; i < codes.size(); ++i) EXPECT_NE(codes[i], codes[i - 1]) << i;
}

TEST(RequestRegister, ConfigIsChecked) {
  auto cfg = test_config();
  cfg.request_register = cfg.register_y;
  Calibrator c;
  EXPECT_THROW(c.configure(cfg), std::invalid_argument);
  cfg.request_register = -2;
  EXPECT_THROW(c.configure(cfg), std::invalid_argument);
  cfg.request_register = 70000;
  EXPECT_THROW(c.configure(cfg), std::invalid_argument);
}

}  // namespace
}  // namespace nccomp::test::calib
