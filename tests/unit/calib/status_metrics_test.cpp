// What the daemon shows of S3's drift estimator (issue 22 item 5: "status and metrics show the
// uncertainty of every compensation value").
//
// GIVEN an engine built by the daemon's loader from a [calibration] with prediction =
//   "estimator" and estimator_learn_level_noise, calibrated on a simulated machine over a first
//   shift whose drift grows 6 µm/h (X) and 3 µm/h (Y), then calibrated again (the first shift
//   becomes an earlier shift), running in the daemon's loop
// WHEN `nccomp status` (text, JSON) and the metrics are rendered
// THEN they show the level noise each axis's estimate uses, learned from the earlier shift (not
//   the configured 10 µm/h) and marked "learned"; the metrics have the estimate's σ in metres
//   under the estimate's own key (x_estimate_um) and pass `promtool check metrics`.
// GIVEN the same without learning THEN the level noise is the configured value, "configured".
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <sstream>
#include <string>
#include <thread>

#include "core/calib/calib_module.hpp"
#include "core/calib/drift_estimator.hpp"
#include "daemon/config/builtin_sections.hpp"
#include "daemon/config/config.hpp"
#include "daemon/logging.hpp"
#include "daemon/loop.hpp"
#include "daemon/status.hpp"
#include "drivers/loopback/loopback_bus.hpp"
#include "tests/unit/calib/sim_machine.hpp"
#include "tests/unit/calib/test_config.hpp"

namespace nccomp::test::calib {
namespace {

namespace fs = std::filesystem;
namespace cfg = daemon::config;
using core::calib::CalibrationModule;
using core::calib::Slot;
using namespace std::chrono_literals;

std::string estimator_config_text(bool learn) {
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
    << "recalibration_interval_s = 0\nprediction = \"estimator\"\n"
    << "estimator_level_noise_um_per_h = 10\nestimator_min_level_noise_um_per_h = 1\n"
    << "estimator_learn_level_noise = " << (learn ? "true" : "false") << "\n";
  return s.str();
}

double number_after(const std::string& s, const std::string& key) {
  const auto p = s.find(key);
  return p == std::string::npos ? std::nan("") : std::stod(s.substr(p + key.size()));
}

// The engine of `text`, calibrated over one shift (6 µm/h on X, 3 on Y, 6 on Z, 4 hourly touch
// sets) and calibrated again, with its clock moved so that the loop's monotonic now is 10 s
// after the second calibration; rendered by the daemon's status while its loop runs.
struct Rendered {
  std::string text, json, prom;
  core::calib::CalibState state;
};

Rendered run_and_render(const std::string& config_text) {
  Rendered r;
  auto loaded = cfg::load_string(config_text, "nccompd.toml", "/tmp");
  EXPECT_TRUE(loaded.config) << loaded.diagnostics.to_string();
  if (!loaded.config) return r;
  auto rt = std::make_unique<daemon::Runtime>();
  rt->engine = cfg::build_engine(*loaded.config);
  CalibrationModule* module = nullptr;
  for (std::size_t m = 0; m < rt->engine->module_count(); ++m) {
    if (auto* c = dynamic_cast<CalibrationModule*>(&rt->engine->module(m))) module = c;
  }
  EXPECT_NE(module, nullptr);
  if (module == nullptr) return r;
  std::vector<std::string> names;
  for (const auto& e : cfg::registers_section(*loaded.config).registers) {
    rt->register_bus.push_back(0);
    names.push_back(e.spec.name);
  }
  auto& c = module->calibrator();
  SimMachine m(c.config(), test_errors(), 0.0, 0.0, 0.1, 11);
  core::TimeNs now = 0;
  core::StepOutput out;
  m.set_drift([](double) { return std::array<double, 4>{}; });
  EXPECT_TRUE(run_initial_calibration(c, m, now, out));
  const double t_nom = c.nominal(Slot::kXLateral).time_s;
  m.set_drift([t_nom](double t) {
    const double h = std::max(0.0, t - t_nom) / 3600.0;
    return std::array<double, 4>{6.0 * h, 6.0 * h, 3.0 * h, 6.0 * h};
  });
  for (int h = 1; h <= 4; ++h) {
    now = core::from_seconds(t_nom + 3600.0 * h);
    out.clear();
    run_touch_set(c, m, now, out);
  }
  m.set_drift([](double) { return std::array<double, 4>{}; });
  EXPECT_TRUE(run_initial_calibration(c, m, now, out));  // the first shift becomes an earlier one
  r.state = c.export_state();
  // The loop's clock: its now (monotonic) is 10 s after the last step.
  const double mono_s = core::seconds(std::chrono::duration_cast<std::chrono::nanoseconds>(
                                          std::chrono::steady_clock::now().time_since_epoch())
                                          .count());
  module->rebase_clock(core::seconds(now) + 10.0 - mono_s);

  core::rt::ConfigSwap<daemon::Runtime> swap(std::move(rt));
  drivers::loopback::LoopbackBus bus(256, 256);
  bus.start();
  daemon::Loop loop(daemon::LoopOptions{}, swap, {&bus}, nullptr, nullptr);
  daemon::EventLogger logger(loop);
  logger.start();
  loop.start();
  daemon::StatusContext sc;
  sc.loop = &loop;
  sc.buses = {{"loopback", &bus}};
  sc.logger = &logger;
  sc.register_names = [names] { return names; };
  sc.config_path = "nccompd.toml";
  sc.state_path = "state.bin";
  for (int i = 0; i < 500; ++i) {
    r.json = daemon::render_json(sc);
    if (r.json.find("\"phase\":\"ready\"") != std::string::npos &&
        std::isfinite(number_after(r.json, "\"x_estimate_sigma_um\":"))) {
      break;
    }
    std::this_thread::sleep_for(10ms);
  }
  r.text = daemon::render_text(sc);
  r.json = daemon::render_json(sc);
  r.prom = daemon::render_prometheus(sc);
  loop.stop();
  logger.stop();
  bus.stop();
  return r;
}

std::string promtool_lint(const std::string& metrics) {
  const fs::path file =
      fs::temp_directory_path() / ("calib_metrics_" + std::to_string(::getpid()) + ".txt");
  std::ofstream(file) << metrics;
  const std::string cmd = "promtool check metrics <" + file.string() + " 2>&1";
  std::FILE* p = ::popen(cmd.c_str(), "r");
  std::string lint;
  if (p == nullptr) return "popen failed";
  char buf[512];
  std::size_t n = 0;
  while ((n = std::fread(buf, 1, sizeof buf, p)) > 0) lint.append(buf, n);
  const int status = ::pclose(p);
  fs::remove(file);
  return status == 0 ? lint : "exit " + std::to_string(status) + ": " + lint;
}

TEST(CalibrationStatus, LearnedLevelNoiseAndTheEstimatesSigmaInStatusAndMetrics) {
  const Rendered r = run_and_render(estimator_config_text(true));
  ASSERT_NE(r.json.find("\"phase\":\"ready\""), std::string::npos) << r.json;
  ASSERT_GT(r.state.shifts.increment_weight, 0.0);
  // What the estimator learned from the first shift, per axis (its measuring slot).
  const struct {
    const char* axis;
    std::size_t slot;
  } axes[] = {{"x", 0}, {"y", 2}, {"z", 3}};
  for (const auto& a : axes) {
    const double learned =
        core::calib::learned_level_noise_um_per_h(r.state.shifts, a.slot, 10.0, 1.0, 20.0);
    const std::string key = std::string(a.axis) + "_level_noise_um_per_h";
    EXPECT_NEAR(number_after(r.json, "\"" + key + "\":"), learned, 1e-5 * learned) << r.json;
    EXPECT_NEAR(
        number_after(r.prom, "nccompd_module_value{module=\"calibration\",key=\"" + key + "\"} "),
        learned, 1e-9 * learned)
        << r.prom;
    EXPECT_NE(r.text.find(", " + key + " "), std::string::npos) << r.text;
  }
  // Hourly increments of 6 (X) and 3 (Y) µm: learned, not the configured 10 µm/h.
  EXPECT_NEAR(number_after(r.json, "\"x_level_noise_um_per_h\":"), 6.0, 0.5) << r.json;
  EXPECT_NEAR(number_after(r.json, "\"y_level_noise_um_per_h\":"), 3.0, 0.5) << r.json;
  EXPECT_NE(r.text.find("level_noise learned, x_level_noise_um_per_h "), std::string::npos)
      << r.text;
  EXPECT_NE(r.json.find("\"level_noise\":\"learned\""), std::string::npos) << r.json;
  EXPECT_NE(r.prom.find("nccompd_module_text{module=\"calibration\",key=\"level_noise\","
                        "text=\"learned\"} 1\n"),
            std::string::npos)
      << r.prom;
  EXPECT_NE(r.prom.find("nccompd_module_text{module=\"calibration\",key=\"phase\","
                        "text=\"ready\"} 1\n"),
            std::string::npos)
      << r.prom;
  // The estimate's σ, in metres, under the estimate's key.
  for (const char* axis : {"x", "y", "z"}) {
    const double sigma_um =
        number_after(r.json, "\"" + std::string(axis) + "_estimate_sigma_um\":");
    ASSERT_TRUE(std::isfinite(sigma_um) && sigma_um > 0.0) << r.json;
    const double sigma_m =
        number_after(r.prom, "nccompd_module_sigma_meters{module=\"calibration\",key=\"" +
                                 std::string(axis) + "_estimate_um\"} ");
    EXPECT_NEAR(sigma_m, sigma_um * 1e-6, 1e-5 * sigma_um * 1e-6) << r.prom;  // JSON: 6 digits
  }
  EXPECT_EQ(r.prom.find("_estimate_estimate_um"), std::string::npos) << r.prom;
  if (::system("command -v promtool >/dev/null 2>&1") == 0) {
    EXPECT_EQ(promtool_lint(r.prom), "") << r.prom;
  }
}

TEST(CalibrationStatus, ConfiguredLevelNoiseIsShownAsConfigured) {
  const Rendered r = run_and_render(estimator_config_text(false));
  ASSERT_NE(r.json.find("\"phase\":\"ready\""), std::string::npos) << r.json;
  EXPECT_NE(r.text.find("level_noise configured, x_level_noise_um_per_h 10, "
                        "y_level_noise_um_per_h 10, z_level_noise_um_per_h 10"),
            std::string::npos)
      << r.text;
  EXPECT_NE(r.prom.find("nccompd_module_text{module=\"calibration\",key=\"level_noise\","
                        "text=\"configured\"} 1\n"),
            std::string::npos)
      << r.prom;
}

}  // namespace
}  // namespace nccomp::test::calib
