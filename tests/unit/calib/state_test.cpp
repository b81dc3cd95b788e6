// Persistence (issue item 5): export → text → import resumes where it was, on another clock.
#include <gtest/gtest.h>

#include <stdexcept>
#include <string>

#include "core/calib/calibrator.hpp"
#include "core/calib/state.hpp"
#include "tests/unit/calib/sim_machine.hpp"
#include "tests/unit/calib/test_config.hpp"

namespace nccomp::test::calib {
namespace {

using core::StepOutput;
using core::TimeNs;
using core::calib::Calibrator;
using core::calib::CalibState;
using core::calib::Phase;
using core::calib::Slot;

TEST(State, SurvivesARestartOnANewMonotonicClock) {
  auto cfg = test_config();
  cfg.touches_per_axis = 1;
  cfg.prediction = core::calib::Prediction::kTime;
  Calibrator a;
  a.configure(cfg);
  a.set_clock_offset_s(1.7e9);  // wall clock = monotonic + 1.7e9 s
  SimMachine m(cfg, test_errors(), 0.3, 0.3, 0.1, 9);
  TimeNs now = core::from_seconds(50.0);
  StepOutput out;
  ASSERT_TRUE(run_initial_calibration(a, m, now, out));
  m.set_drift([](double t) { return std::array<double, 4>{t * 1e-3, t * 2e-3, -t * 1e-3, 0.0}; });
  for (int k = 1; k <= 3; ++k) {
    now += core::from_seconds(1800.0);
    out.clear();
    run_touch_set(a, m, now, out);
  }
  now += core::from_seconds(100.0);  // in the middle of a creep
  const std::string text = core::calib::to_text(a.export_state());

  // The daemon restarts: the monotonic clock now reads 20 s where the wall clock is 1.7e9 +
  // (now − 20 s) later.
  Calibrator b;
  b.configure(cfg);
  const TimeNs now_b = core::from_seconds(20.0);
  b.set_clock_offset_s(1.7e9 + core::seconds(now) - 20.0);
  b.import_state(core::calib::from_text(text));
  EXPECT_EQ(b.phase(), Phase::kReady);
  for (std::size_t axis = 0; axis < 3; ++axis) {
    EXPECT_NEAR(b.target_um(axis, now_b), a.target_um(axis, now), 1e-6) << axis;
    EXPECT_NEAR(b.target_um(axis, now_b + core::from_seconds(900.0)),
                a.target_um(axis, now + core::from_seconds(900.0)), 1e-6);
  }
  EXPECT_EQ(b.export_state().history_count, 4);
  EXPECT_DOUBLE_EQ(b.nominal(Slot::kY).position_mm, a.nominal(Slot::kY).position_mm);
  // Round trip of the text itself is exact.
  EXPECT_EQ(core::calib::to_text(b.export_state()).size(), text.size());
}

TEST(State, CorruptTextIsRefusedWithLineAndKey) {
  CalibState s;
  const std::string good = core::calib::to_text(s);
  EXPECT_NO_THROW(core::calib::from_text(good));
  const auto expect_error = [](const std::string& text, const std::string& needle) {
    try {
      (void)core::calib::from_text(text);
      ADD_FAILURE() << "accepted: " << needle;
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
    }
  };
  expect_error("", "no header");
  expect_error("something 1\n", "not a calibration state");
  expect_error("nccomp_calib_state 4\n", "unsupported version");
  std::string missing = good;
  missing.erase(missing.find("grinds 0\n"), 9);
  expect_error(missing, "grinds");
  std::string bad = good;
  bad.replace(bad.find("result.dx_r_um nan"), 18, "result.dx_r_um 1x");
  expect_error(bad, "line 7, key result.dx_r_um");
  expect_error(good + "bogus 1\n", "unknown key");
  expect_error(good + "phase 0\n", "duplicate key");
  std::string phase = good;
  phase.replace(phase.find("phase 0"), 7, "phase 5");  // ready without nominals
  expect_error(phase, "calibrated state");
}

}  // namespace
}  // namespace nccomp::test::calib
