// The calibration section's start-up work in nccompd (daemon/sections/calibration/daemon_link):
// the clock origin across a reboot, the adoption of an offline state, the read-back of the axis
// registers.
//
// GIVEN an engine built from a [calibration] config by the daemon's loader, calibrated on a
// simulated machine and mid-creep after a recalibration, its state saved
// WHEN a new engine (a rebooted machine: the monotonic clock starts again at 5 s, the wall clock
//   went on by a minute) restores the bytes and runs the start-up hook
// THEN the targets are those the old engine had at the same wall-clock time (creep and drift
//   model continued across the reboot); a newer offline state from `state_file` is adopted and
//   an older one is not; registers read back from the NC become the limiter's start.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <sstream>

#include "core/calib/calib_module.hpp"
#include "daemon/config/builtin_sections.hpp"
#include "daemon/config/config.hpp"
#include "daemon/sections/calibration/daemon_link.hpp"
#include "tests/unit/calib/sim_machine.hpp"
#include "tests/unit/calib/test_config.hpp"

namespace nccomp::test::calib {
namespace {

namespace fs = std::filesystem;
namespace cfg = daemon::config;
using core::calib::CalibrationModule;

std::string config_text(const std::string& extra = "") {
  std::ostringstream s;
  s << "[loopback]\n";
  for (const char* n : {"X_offset", "Y_offset", "Z_offset"}) {
    s << "[[registers]]\nname = \"" << n << "\"\nkind = \"axis_offset\"\nbus = \"loopback\"\n"
      << "max_abs_um = 200\nmax_step_um = 50\nmax_rate_um_per_s = 500\n";
  }
  const auto c = test_config();
  s << "[calibration]\nregister_x = 0\nregister_y = 1\nregister_z = 2\n"
    << "reference_x_lateral_mm = " << c.reference_x_lateral_mm << "\n"
    << "reference_x_axial_mm = " << c.reference_x_axial_mm << "\n"
    << "reference_y_mm = " << c.reference_y_mm << "\nreference_z_mm = " << c.reference_z_mm
    << "\nreference_contact_mm = " << c.reference_contact_mm
    << "\nreference_axial_contact_mm = " << c.reference_axial_contact_mm << "\n"
    << "touches_per_axis = 1\nmax_test_grinds = 20\ncreep_duration_s = 600\n"
    << "prediction = \"time\"\nthermal_time_constant_s = 3600\n"
    << extra;
  return s.str();
}

struct Built {
  std::unique_ptr<cfg::Config> config;
  std::unique_ptr<core::engine::Engine> engine;
  CalibrationModule* module{nullptr};
};

Built build(const std::string& text, const std::string& dir = "/tmp") {
  auto loaded = cfg::load_string(text, "nccompd.toml", dir);
  EXPECT_TRUE(loaded.config) << loaded.diagnostics.to_string();
  Built b;
  b.config = std::move(loaded.config);
  b.engine = cfg::build_engine(*b.config);
  for (std::size_t m = 0; m < b.engine->module_count(); ++m) {
    if (auto* c = dynamic_cast<CalibrationModule*>(&b.engine->module(m))) b.module = c;
  }
  EXPECT_NE(b.module, nullptr);
  return b;
}

TEST(CalibrationStartup, DriftModelAndCreepSurviveAReboot) {
  // Before: the loop's clock is monotonic, 50000 s since boot; the wall clock is W0 there.
  const double w0 = 1.80e9;
  const double mono0 = 50000.0;
  Built a = build(config_text());
  const auto lines0 =
      daemon::sections::calibration_startup(*a.engine, {}, core::from_seconds(mono0), w0);
  ASSERT_FALSE(lines0.empty());
  auto& ca = a.module->calibrator();
  SimMachine m(ca.config(), test_errors(), 0.2, 0.2, 0.1, 3);
  core::TimeNs now = core::from_seconds(mono0);
  core::StepOutput out;
  ASSERT_TRUE(run_initial_calibration(ca, m, now, out));
  m.set_drift([](double) { return std::array<double, 4>{12.0, 12.0, -4.0, 6.0}; });
  now += core::from_seconds(1800.0);
  out.clear();
  run_touch_set(ca, m, now, out);
  now += core::from_seconds(200.0);  // mid-creep
  std::vector<std::byte> blob(a.engine->state_capacity());
  const std::size_t n = a.engine->export_state(blob);
  ASSERT_GT(n, 0u);
  const double wall_at_save = w0 + (core::seconds(now) - mono0);

  // After a reboot a minute later: monotonic 5 s, wall = wall_at_save + 60 s.
  Built b = build(config_text());
  const core::TimeNs boot = core::from_seconds(5.0);
  ASSERT_TRUE(b.engine->import_state(std::span<const std::byte>(blob.data(), n), boot));
  const auto lines =
      daemon::sections::calibration_startup(*b.engine, {}, boot, wall_at_save + 60.0);
  bool resumed = false;
  for (const auto& l : lines) resumed |= l.find("calibration: resumed phase ready") == 0;
  EXPECT_TRUE(resumed);
  const auto& cb = b.module->calibrator();
  for (double later : {0.0, 100.0, 3000.0}) {
    for (std::size_t axis = 0; axis < 3; ++axis) {
      EXPECT_NEAR(cb.target_um(axis, boot + core::from_seconds(later)),
                  ca.target_um(axis, now + core::from_seconds(60.0 + later)), 1e-6)
          << "axis " << axis << " at +" << later << " s";
    }
  }
  // The creep (600 s, started 260 s before the reboot's now) is still running: its remainder is
  // the difference from the prediction.
  EXPECT_GT(std::fabs(cb.drift_correction_um(core::calib::Slot::kXLateral, boot) -
                      cb.predicted_drift_um(core::calib::Slot::kXLateral, boot)),
            1e-3);
}

TEST(CalibrationStartup, AdoptsANewerOfflineStateAndReadsTheRegistersBack) {
  const fs::path dir = fs::temp_directory_path() / ("calib_link_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  // An offline calibration (what `nccomp calibrate --state` writes), made at wall time 1.79e9.
  Built off = build(config_text());
  auto& co = off.module->calibrator();
  co.set_clock_offset_s(1.79e9);
  SimMachine m(co.config(), test_errors(), 0.2, 0.2, 0.1, 4);
  core::TimeNs now = 0;
  core::StepOutput out;
  ASSERT_TRUE(run_initial_calibration(co, m, now, out));
  std::ofstream(dir / "offline.state") << core::calib::to_text(co.export_state());

  Built d = build(config_text("state_file = \"offline.state\"\n"), dir.string());
  // The NC holds X 3.5, Y -1, Z unreadable.
  const daemon::RegisterReader read = [](std::uint16_t r) -> std::optional<double> {
    if (r == 0) return 3.5;
    if (r == 1) return -1.0;
    return std::nullopt;
  };
  auto lines = daemon::sections::calibration_startup(*d.engine, read, core::from_seconds(10.0),
                                                     1.79e9 + 5000.0);
  std::string all;
  for (const auto& l : lines) all += l + "\n";
  EXPECT_NE(all.find("adopted the calibration of " + (dir / "offline.state").string()),
            std::string::npos)
      << all;
  EXPECT_NE(all.find("axis registers read back from the NC: X +3.500 Y -1.000 um"),
            std::string::npos)
      << all;
  const auto& cd = d.module->calibrator();
  EXPECT_EQ(cd.phase(), core::calib::Phase::kReady);
  EXPECT_DOUBLE_EQ(cd.result().dx_r_um, co.result().dx_r_um);
  EXPECT_DOUBLE_EQ(cd.written_um(0), 3.5);
  EXPECT_DOUBLE_EQ(cd.written_um(1), -1.0);
  // The first write slews from what the NC holds (limiter 5 µm per write), not from 0.
  out.clear();
  d.module->step(core::from_seconds(10.0), {}, out);
  for (const auto& w : out.writes) {
    if (w.register_index == 0) {
      EXPECT_NEAR(w.value_um, 3.5 + 5.0, 1e-9);
    }
    if (w.register_index == 1) {
      EXPECT_NEAR(w.value_um, -1.0 - 5.0, 1e-9);
    }
  }
  // The daemon now holds that calibration with a later touch set: the same file is not newer.
  auto& dm = *d.module;
  m.set_drift([](double) { return std::array<double, 4>{1.0, 1.0, 1.0, 1.0}; });
  out.clear();
  run_touch_set(dm.calibrator(), m, core::from_seconds(4000.0), out);
  std::vector<std::byte> blob(d.engine->state_capacity());
  const std::size_t n = d.engine->export_state(blob);
  Built again = build(config_text("state_file = \"offline.state\"\n"), dir.string());
  ASSERT_TRUE(again.engine->import_state(std::span<const std::byte>(blob.data(), n), 0));
  lines = daemon::sections::calibration_startup(*again.engine, {}, core::from_seconds(10.0),
                                                1.79e9 + 9000.0);
  all.clear();
  for (const auto& l : lines) all += l + "\n";
  EXPECT_NE(all.find("is not newer than the calibration the daemon holds"), std::string::npos)
      << all;
  EXPECT_EQ(again.module->calibrator().model(core::calib::Slot::kXLateral).touch_sets, 2);
  // A corrupt file is refused with the reason; the daemon's state stays.
  std::ofstream(dir / "offline.state") << "nccomp_calib_state 1\nphase ready\n";
  Built bad = build(config_text("state_file = \"offline.state\"\n"), dir.string());
  lines = daemon::sections::calibration_startup(*bad.engine, {}, 0, 1.79e9);
  all.clear();
  for (const auto& l : lines) all += l + "\n";
  EXPECT_NE(all.find("refused: calibration state, line 2, key phase"), std::string::npos) << all;
  EXPECT_EQ(bad.module->calibrator().phase(), core::calib::Phase::kUncalibrated);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace nccomp::test::calib
