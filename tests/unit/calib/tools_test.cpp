// `nccomp calibrate`'s parts: the [calibration] TOML loader, the script parser and a session run
// on the documented example files.
#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <sstream>
#include <stdexcept>
#include <string>

#include "formats/calib/config_toml.hpp"
#include "formats/calib/render.hpp"
#include "formats/calib/script.hpp"
#include "tools/calibrate/session.hpp"

namespace nccomp::tools::calibrate {
namespace {

using formats::calib::load_calibration_config_file;
using formats::calib::load_calibration_config_text;

std::string error_of(const std::string& toml) {
  try {
    (void)load_calibration_config_text(toml, "m.toml");
  } catch (const std::invalid_argument& e) {
    return e.what();
  }
  return "";
}

TEST(CalibrationToml, KeysMapOneToOne) {
  const auto c = load_calibration_config_text(R"(
[other]
ignored = 1
[calibration]
register_x = 7
register_y = 8
register_z = 9
reference_x_lateral_mm = 250
facet_rule = "proportional"
facet_gain_um_per_um = 0.025
creep_shape = "smoothstep"
prediction = "temperature"
temperature_sensor = 4
end_face_test_grind = false
touches_per_axis = 3
)",
                                              "m.toml");
  EXPECT_EQ(c.register_x, 7);
  EXPECT_EQ(c.register_z, 9);
  EXPECT_DOUBLE_EQ(c.reference_x_lateral_mm, 250.0);
  EXPECT_EQ(c.facet_rule, core::calib::FacetRule::kProportional);
  EXPECT_DOUBLE_EQ(c.facet_gain_um_per_um, 0.025);
  EXPECT_EQ(c.creep_shape, core::ProfileShape::kSmoothstep);
  EXPECT_EQ(c.prediction, core::calib::Prediction::kTemperature);
  EXPECT_EQ(c.temperature_sensor, 4);
  EXPECT_FALSE(c.end_face_test_grind);
  EXPECT_EQ(c.touches_per_axis, 3);
  // Defaults where a key is absent.
  EXPECT_DOUBLE_EQ(c.plausibility_um, 50.0);
}

TEST(CalibrationToml, ErrorsNameFileLineAndKey) {
  EXPECT_EQ(error_of("[calibration]\n\nplausibilty_um = 5\n"),
            "m.toml:3:18: calibration.plausibilty_um: unknown key");
  EXPECT_EQ(error_of("[calibration]\nfacet_rule = \"guess\"\n"),
            "m.toml:2:14: calibration.facet_rule: must be one of \"exact\", \"proportional\", "
            "got \"guess\"");
  EXPECT_EQ(error_of("[calibration]\nregister_x = 70000\n"),
            "m.toml:2:14: calibration.register_x: must be an integer in [0, 65535], got 70000");
  EXPECT_EQ(error_of("[calibration]\nblank_radius_mm = \"5\"\n"),
            "m.toml:2:19: calibration.blank_radius_mm: must be a finite number");
  // Every error, not only the first.
  EXPECT_EQ(error_of("[calibration]\nregister_x = 70000\nfacet_rulez = 1\n"),
            "m.toml:2:14: calibration.register_x: must be an integer in [0, 65535], got 70000\n"
            "m.toml:3:15: calibration.facet_rulez: unknown key");
  EXPECT_NE(error_of("[calibration]\nblank_radius_mm = -5.0\n").find("calibration.blank_radius_mm"),
            std::string::npos);
  EXPECT_NE(error_of("[calibration]\nprediction = \"temperature\"\n")
                .find("calibration.temperature_sensor"),
            std::string::npos);
  // The estimator's keys (issue 22 item 3).
  const auto est = load_calibration_config_text(
      "[calibration]\nprediction = \"estimator\"\ntemperature_sensor = 2\n"
      "estimator_touch_noise_um = 0.4\nestimator_level_noise_um_per_h = 4.5\n"
      "estimator_learn_level_noise = true\nestimator_min_level_noise_um_per_h = 2.5\n"
      "estimator_max_level_noise_um_per_h = 12\n"
      "estimator_prior_gain_sigma = 0.3\nestimator_prior_forgetting = 0.9\n"
      "estimator_slope_sigma_um_per_c = 0.25\nestimator_gate_sigmas = 6\n"
      "estimator_model_slope_um_per_c = [-4.5, -4.5, 0.8, 0]\n"
      "estimator_model_slope_sigma_um_per_c = [1.2, 1.2, 0.1, 0]\n"
      "estimator_input_sensors = [40, 40, -1, 41]\nestimator_shift_prior = false\n",
      "m.toml");
  EXPECT_EQ(est.estimator_input_sensors, (std::array<std::int32_t, 4>{40, 40, -1, 41}));
  EXPECT_FALSE(est.estimator_shift_prior);
  EXPECT_EQ(est.prediction, core::calib::Prediction::kEstimator);
  EXPECT_DOUBLE_EQ(est.estimator_touch_noise_um, 0.4);
  EXPECT_DOUBLE_EQ(est.estimator_level_noise_um_per_h, 4.5);
  EXPECT_TRUE(est.estimator_learn_level_noise);
  EXPECT_DOUBLE_EQ(est.estimator_min_level_noise_um_per_h, 2.5);
  EXPECT_DOUBLE_EQ(est.estimator_max_level_noise_um_per_h, 12.0);
  EXPECT_DOUBLE_EQ(est.estimator_prior_gain_sigma, 0.3);
  EXPECT_DOUBLE_EQ(est.estimator_prior_forgetting, 0.9);
  EXPECT_DOUBLE_EQ(est.estimator_slope_sigma_um_per_c, 0.25);
  EXPECT_DOUBLE_EQ(est.estimator_gate_sigmas, 6.0);
  EXPECT_EQ(est.estimator_model_slope_um_per_c, (std::array<double, 4>{-4.5, -4.5, 0.8, 0.0}));
  EXPECT_EQ(est.estimator_model_slope_sigma_um_per_c, (std::array<double, 4>{1.2, 1.2, 0.1, 0.0}));
  EXPECT_EQ(error_of("[calibration]\nestimator_model_slope_um_per_c = [1, 2]\n"),
            "m.toml:2:34: calibration.estimator_model_slope_um_per_c: must have 4 values (X "
            "lateral, X axial, Y, Z)");
  EXPECT_EQ(error_of("[calibration]\nestimator_input_sensors = [1, 2, 3]\n"),
            "m.toml:2:27: calibration.estimator_input_sensors: must have 4 values (X lateral, X "
            "axial, Y, Z)");
  EXPECT_NE(error_of("[calibration]\nestimator_input_sensors = [1, 2, 3, 256]\n")
                .find("calibration.estimator_input_sensors"),
            std::string::npos);
  EXPECT_EQ(error_of("[calibration]\nestimator_touch_noise_um = \"x\"\n"),
            "m.toml:2:28: calibration.estimator_touch_noise_um: must be a finite number");
  EXPECT_NE(error_of("[calibration]\nestimator_prior_forgetting = 0\n")
                .find("calibration.estimator_prior_forgetting: must be in (0, 1], got 0"),
            std::string::npos);
  EXPECT_NE(error_of("[calibration]\nprediction = \"estimator\"\n"
                     "estimator_slope_sigma_um_per_c = 1\n")
                .find("calibration.temperature_sensor"),
            std::string::npos);
  EXPECT_NE(error_of("calibration = 3\n").find("m.toml:1:15: calibration: must be a table"),
            std::string::npos);
  EXPECT_NE(error_of("[calibration\n").find("m.toml:1"), std::string::npos);
}

TEST(Script, ParsesEveryCommand) {
  const auto touch = std::get<CmdTouch>(parse_line("touch Reference X + axial 258.0379 # c", 1));
  EXPECT_EQ(touch.touch.probe, core::ProbeKind::kReferenceProbe);
  EXPECT_EQ(touch.touch.axis, 0);
  EXPECT_EQ(touch.touch.variant, 1);
  EXPECT_EQ(touch.touch.direction, 1);
  EXPECT_DOUBLE_EQ(touch.touch.trigger_position_mm, 258.0379);
  const auto y = std::get<CmdTouch>(parse_line("touch machine y - -42.5", 2));
  EXPECT_EQ(y.touch.axis, 1);
  EXPECT_EQ(y.touch.direction, -1);
  EXPECT_EQ(y.touch.variant, 0);
  const auto f = std::get<CmdFacets>(parse_line("facets end-face 1.9216 +2.0557", 3));
  EXPECT_EQ(f.face, core::calib::Face::kEndFace);
  EXPECT_DOUBLE_EQ(f.chord_minus_mm, 2.0557);
  EXPECT_DOUBLE_EQ(std::get<CmdWait>(parse_line("  wait\t60 ", 4)).duration_s, 60.0);
  EXPECT_EQ(std::get<CmdTemperature>(parse_line("temperature 3 21.5", 5)).sensor, 3);
  EXPECT_TRUE(std::holds_alternative<CmdEmpty>(parse_line("   # only a comment", 6)));
  EXPECT_TRUE(std::holds_alternative<CmdBegin>(parse_line("begin", 7)));
}

// Each refusal is one Diagnostic: the line, the column of the offending word, the reason; the
// caller names the script's file (file:line:column, as every other format's errors).
TEST(Script, ErrorsNameLineAndWord) {
  const auto msg = [](const std::string& line) -> std::string {
    try {
      (void)parse_line(line, 12);
    } catch (const ScriptError& e) {
      return e.in_file("s.txt");
    }
    return "";
  };
  EXPECT_EQ(msg("touch machine w + 1.0"), "s.txt:12:15: axis must be x, y or z, got 'w'");
  EXPECT_EQ(msg("touch machine y + axial 1.0"),
            "s.txt:12:19: only X is touched axially (along the stylus)");
  EXPECT_EQ(msg("touch machine x + 1.0x"),
            "s.txt:12:19: trigger position must be a finite number, got '1.0x'");
  EXPECT_EQ(msg("facets lateral 1.9 nan"),
            "s.txt:12:20: chord_minus_mm must be a finite number, got 'nan'");
  EXPECT_EQ(msg("facets lateral 1.9 -2"), "s.txt:12:20: chords must be positive [mm]");
  EXPECT_EQ(msg("temperature 300 20"), "s.txt:12:13: sensor must be an integer 0..255, got '300'");
  EXPECT_EQ(msg("  grind"), "s.txt:12:3: unknown command 'grind' (try 'help')");
  EXPECT_NE(msg("touch machine x +").find("s.txt:12:1: usage: touch"), std::string::npos);
  try {
    (void)parse_line("touch machine w + 1.0", 12);
    FAIL() << "accepted axis w";
  } catch (const ScriptError& e) {
    // A prompt has no file: what() names line and column.
    EXPECT_EQ(std::string(e.what()), "line 12, column 15: axis must be x, y or z, got 'w'");
    EXPECT_EQ(e.diagnostic().where.line, 12);
    EXPECT_EQ(e.diagnostic().where.column, 15);
    EXPECT_EQ(e.diagnostic().message, "axis must be x, y or z, got 'w'");
  }
}

std::string run_script(Session& s, const std::string& path) {
  std::ifstream in(path);
  EXPECT_TRUE(in.good()) << path;
  std::string line;
  std::size_t n = 0;
  while (std::getline(in, line)) {
    ++n;
    s.run(parse_line(line, n), n);
  }
  return s.export_state_text();
}

TEST(Session, ExampleScriptsCalibrateAndRecalibrate) {
  const std::string dir = std::string(NCCOMP_SOURCE_DIR) + "/tools/calibrate/examples/";
  const auto cfg = load_calibration_config_file(dir + "machine.toml");
  std::ostringstream log1;
  Session a(cfg, 1795766400.0, log1);
  const std::string state = run_script(a, dir + "initial.calib");
  ASSERT_EQ(a.calibrator().phase(), core::calib::Phase::kReady) << log1.str();
  // The simulated machine behind the example has Ex = +23, Exa = +31, Ey = −12, Ez = +8 µm.
  EXPECT_NEAR(a.calibrator().result().dx_r_um, 23.0, 0.3);
  EXPECT_NEAR(a.calibrator().result().dx_a_um, 31.0, 0.3);
  EXPECT_NEAR(a.calibrator().result().dy_um, -12.0, 2.0);
  EXPECT_NEAR(a.calibrator().result().dz_um, 8.0, 2.0);
  EXPECT_EQ(a.alarm_count(), 0u);

  std::ostringstream log2;
  Session b(cfg, 1795766400.0 + 2700.0 + 3600.0, log2);
  b.import_state_text(state);
  run_script(b, dir + "recalibrate.calib");
  EXPECT_EQ(b.alarm_count(), 1u);  // the dirty sphere
  EXPECT_NE(log2.str().find("ALARM 40 recalibration-implausible axis Y"), std::string::npos);
  EXPECT_EQ(b.calibrator().model(core::calib::Slot::kXLateral).touch_sets, 3);
  // No slewing from zero after the import: the registers resume at the saved corrections.
  EXPECT_EQ(log2.str().find("offset-slew-limited"), std::string::npos) << log2.str();
}

// The dates were computed with Python's datetime (UTC), independently of this code.
TEST(Render, UtcTimes) {
  EXPECT_EQ(formats::calib::format_utc(1795766400.0), "2026-11-27 08:00:00 UTC");
  EXPECT_EQ(formats::calib::format_utc(1795788723.9), "2026-11-27 14:12:03 UTC");
  EXPECT_EQ(formats::calib::format_utc(951868799.0), "2000-02-29 23:59:59 UTC");
  EXPECT_EQ(formats::calib::format_utc(0.0), "1970-01-01 00:00:00 UTC");
  EXPECT_EQ(formats::calib::format_utc(-1.0), "1969-12-31 23:59:59 UTC");
  EXPECT_EQ(formats::calib::format_utc(std::nan("")), "never");
}

TEST(Session, TimeCannotGoBack) {
  const std::string dir = std::string(NCCOMP_SOURCE_DIR) + "/tools/calibrate/examples/";
  std::ostringstream log;
  Session s(load_calibration_config_file(dir + "machine.toml"), 0.0, log);
  s.run(parse_line("time 100", 1), 1);
  EXPECT_THROW(s.run(parse_line("time 50", 2), 2), ScriptError);
}

}  // namespace
}  // namespace nccomp::tools::calibrate
