// Helpers of the whole-process calibration tests (daemon_calib_test.cpp, prompt_test.cpp): an
// nccompd process (tests/support/nccompd_process.hpp) on the loopback bus with the machine of
// test_config(), calibrate requests on its status socket, JSON values.
#pragma once

#include <gtest/gtest.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <optional>
#include <regex>
#include <sstream>
#include <string>
#include <thread>

#include <nlohmann/json.hpp>

#include "client/protocol.hpp"
#include "client/status_client.hpp"
#include "tests/support/nccompd_process.hpp"
#include "tests/support/status_json.hpp"
#include "tests/support/temp_dir.hpp"
#include "tests/unit/calib/sim_machine.hpp"
#include "tests/unit/calib/test_config.hpp"

namespace nccomp::test::calib {

namespace fs = std::filesystem;
using namespace std::chrono_literals;

// The machine of test_config() on registers 0..2, request flag on 3.
// limiter_step_um / limiter_rate: the calibration's own limiter (the restart test makes it slow,
// so that a restart that forgot where the NC is would show as a dip).
inline std::string config_text(const std::string& extra_calibration = "",
                               double limiter_step_um = 50.0,
                               double limiter_rate_um_per_s = 500.0) {
  std::ostringstream s;
  s << "[daemon]\nrate_hz = 200\n"
    << "[state]\ndirectory = \"state\"\nmin_interval_s = 0.05\n"
    << "[measurement_log]\ndirectory = \"log\"\n"
    << "[status]\nsocket_path = \"status.sock\"\n"
    << "[loopback]\n";
  for (const char* n : {"X_offset", "Y_offset", "Z_offset"}) {
    s << "[[registers]]\nname = \"" << n << "\"\nkind = \"axis_offset\"\nbus = \"loopback\"\n"
      << "max_abs_um = 200\nmax_step_um = 50\nmax_rate_um_per_s = 500\n";
  }
  s << "[[registers]]\nname = \"calibration_request\"\nkind = \"flag\"\nbus = \"loopback\"\n"
    << "max_abs_um = 10\n";
  const auto c = test_config();
  s << "[calibration]\nregister_x = 0\nregister_y = 1\nregister_z = 2\nrequest_register = 3\n"
    << "reference_x_lateral_mm = " << c.reference_x_lateral_mm << "\n"
    << "reference_x_axial_mm = " << c.reference_x_axial_mm << "\n"
    << "reference_y_mm = " << c.reference_y_mm << "\nreference_z_mm = " << c.reference_z_mm
    << "\nreference_contact_mm = " << c.reference_contact_mm
    << "\nreference_axial_contact_mm = " << c.reference_axial_contact_mm << "\n"
    << "touches_per_axis = 2\nblank_radius_mm = 5.0\nmax_test_grinds = 10\n"
    << "prediction = \"none\"\ncreep_shape = \"linear\"\ncreep_duration_s = 4.0\n"
    << "write_period_s = 0.05\nwrite_deadband_um = 0.01\n"
    << "max_step_um = " << limiter_step_um << "\nmax_rate_um_per_s = " << limiter_rate_um_per_s
    << "\nrecalibration_interval_s = 0\n"
    << extra_calibration;
  return s.str();
}

using test::TempDir;

/// nccompd with the calibration: up once the calibration module answers; a sanitizer report in
/// its log fails the test when it stops.
class Daemon {
 public:
  explicit Daemon(fs::path dir) : process_(std::move(dir), NCCOMPD_BIN) {}
  void start() {
    ASSERT_TRUE(process_.start()) << "cannot spawn " << NCCOMPD_BIN;
    const auto end = std::chrono::steady_clock::now() + 20s;
    while (std::chrono::steady_clock::now() < end) {
      if (const auto a = ask(""); a && a->rfind("ok ", 0) == 0) return;
      std::this_thread::sleep_for(20ms);
    }
    FAIL() << "nccompd did not answer 'calibrate'\n" << log_text();
  }
  /// SIGTERM; the exit status, -1 if it did not end within 10 s.
  int stop() {
    const int status = process_.stop(10s);
    if (status >= 0) {
      // A sanitizer build of nccompd (ASan / TSan presets) reports into the log.
      EXPECT_EQ(log_text().find("Sanitizer"), std::string::npos) << log_text();
    }
    return status;
  }
  [[nodiscard]] bool alive() { return process_.running(); }
  [[nodiscard]] std::optional<std::string> ask(const std::string& command) const {
    try {
      return client::query(socket(), client::calibrate_request(command), 10.0);
    } catch (const std::exception&) {
      return std::nullopt;
    }
  }
  /// The status JSON, "" when there was no answer.
  [[nodiscard]] std::string json() const { return process_.status("json"); }
  [[nodiscard]] std::string socket() const { return process_.socket(); }
  [[nodiscard]] std::string log_text() const { return process_.log(); }

 private:
  test::NccompdProcess process_;
};

inline double register_output(const std::string& json, const std::string& name) {
  const std::regex re("\"name\":\"" + name + "\",\"output_um\":(-?[0-9.eE+-]+)");
  std::smatch m;
  return std::regex_search(json, m, re) ? std::stod(m[1]) : std::nan("");
}

inline double number(const std::string& json, const std::string& key) {
  return test::find_number(json, key).value_or(std::nan(""));
}

/// A string of the calibration module's status (modules[name = "calibration"].status), "" if
/// none: other objects of the status JSON have keys of the same name (the shadow's "phase").
inline std::string text(const std::string& json, const std::string& key) {
  const auto doc = nlohmann::json::parse(json, nullptr, false);
  if (doc.is_discarded() || !doc.contains("modules")) return "";
  for (const auto& m : doc["modules"]) {
    if (m.value("name", "") != "calibration" || !m.contains("status")) continue;
    const auto& s = m["status"];
    return s.contains(key) && s[key].is_string() ? s[key].get<std::string>() : "";
  }
  return "";
}

inline std::string touch_line(const core::CalibrationTouch& t) {
  char buf[160];
  std::snprintf(buf, sizeof buf, "touch %s %s %s %s %.6f",
                t.probe == core::ProbeKind::kReferenceProbe ? "reference" : "machine",
                t.axis == 0 ? "x" : (t.axis == 1 ? "y" : "z"), t.direction > 0 ? "+" : "-",
                t.variant == 1 ? "axial" : "lateral", t.trigger_position_mm);
  return buf;
}

// The number right after `prefix` in text (NaN if absent).
inline double value_after(const std::string& text, const std::string& prefix) {
  const auto p = text.find(prefix);
  if (p == std::string::npos) return std::nan("");
  try {
    return std::stod(text.substr(p + prefix.size()));
  } catch (const std::exception&) {
    return std::nan("");
  }
}

inline double dx_of(const std::string& answer) {
  const std::regex re("with dx ([-+0-9.]+) um");
  std::smatch m;
  return std::regex_search(answer, m, re) ? std::stod(m[1]) : std::nan("");
}

// Waits until pred(json) or the limit; returns the last json.
template <typename Pred>
inline std::string wait_json(const Daemon& d, Pred pred,
                             std::chrono::milliseconds limit = 10000ms) {
  const auto end = std::chrono::steady_clock::now() + limit;
  std::string j;
  while (std::chrono::steady_clock::now() < end) {
    j = d.json();
    if (!j.empty() && pred(j)) break;
    std::this_thread::sleep_for(20ms);
  }
  return j;
}

// Waits until the calibrator's X, Y and Z registers have reached their targets (the status
// block's "target T um, written W um" equal), then until the loop has published its register
// snapshot again (every 10 cycles: 20 cycles later); returns that status JSON.
inline std::string wait_settled(const Daemon& d, std::chrono::milliseconds limit = 10000ms) {
  const auto end = std::chrono::steady_clock::now() + limit;
  const std::regex re(R"(register \d+ \([XYZ]\): target ([-+0-9.]+) um, written ([-+0-9.]+) um)");
  while (std::chrono::steady_clock::now() < end) {
    const auto a = d.ask("status");
    int settled = 0;
    if (a) {
      for (auto it = std::sregex_iterator(a->begin(), a->end(), re); it != std::sregex_iterator();
           ++it) {
        if (std::fabs(std::stod((*it)[1]) - std::stod((*it)[2])) < 0.002) ++settled;
      }
    }
    if (settled == 3) {
      const double c0 = number(d.json(), "cycles");
      while (std::chrono::steady_clock::now() < end) {
        const std::string j = d.json();
        if (number(j, "cycles") >= c0 + 20) return j;
        std::this_thread::sleep_for(10ms);
      }
    }
    std::this_thread::sleep_for(20ms);
  }
  ADD_FAILURE() << "the calibration registers did not settle\n" << d.ask("status").value_or("");
  return d.json();
}

// The whole initial calibration through the socket; returns the last answer.
inline std::string calibrate(Daemon& d, SimMachine& m) {
  auto a = d.ask("begin");
  EXPECT_TRUE(a && a->rfind("ok reference-touches reference-touches", 0) == 0) << a.value_or("");
  for (std::size_t slot = 0; slot < 4; ++slot) {
    for (int i = 0; i < 2; ++i) {
      a = d.ask(touch_line(m.reference_touch(slot, 1, 0)));
      EXPECT_TRUE(a && a->rfind("ok ", 0) == 0) << a.value_or("");
    }
  }
  EXPECT_NE(a->find("reference touches: dx lateral"), std::string::npos) << *a;
  for (const bool end_face : {false, true}) {
    const std::string face = end_face ? "end-face" : "lateral";
    const std::string phase = end_face ? "test-grind-end-face" : "test-grind-lateral";
    for (int grind = 0; grind < 10 && a->find("ok " + phase) == 0; ++grind) {
      const double dx = dx_of(*a);
      EXPECT_TRUE(std::isfinite(dx)) << *a;
      const auto [p, q] = m.test_grind(end_face, dx);
      char buf[120];
      std::snprintf(buf, sizeof buf, "facets %s %.6f %.6f", face.c_str(), p, q);
      a = d.ask(buf);
      EXPECT_TRUE(a && a->rfind("ok ", 0) == 0) << a.value_or("");
    }
  }
  EXPECT_EQ(a->rfind("ok nominal-touches nominal-touches", 0), 0u) << *a;
  EXPECT_NE(a->find("calibration: dxR"), std::string::npos) << *a;
  for (std::size_t slot = 0; slot < 4; ++slot) {
    for (int i = 0; i < 2; ++i) a = d.ask(touch_line(m.machine_touch(slot, 1, 0)));
  }
  EXPECT_EQ(a->rfind("ok ready none", 0), 0u) << *a;
  EXPECT_NE(a->find("nominals stored:"), std::string::npos) << *a;
  return *a;
}

}  // namespace nccomp::test::calib
