// The calibration in a running nccompd (label hil: whole processes; loopback bus).
//
// GIVEN the nccompd binary with a loopback bus, three axis-offset registers and a request flag
// register, and a simulated machine with known errors (sim_machine.hpp)
// WHEN an operator drives the initial calibration over the status socket ("calibrate ..."
//   commands: begin, typed touches, facet chords of the simulated test grinds), then
//   recalibrates with a known drift (on demand and by touches)
// THEN the daemon answers every command with the calibrator's state, refuses and counts bad
//   input without losing state, the registers reach base + drift (checked against the truth),
//   the request register follows; after SIGTERM and a restart mid-creep the registers continue
//   where the NC is (no dip), the drift model and history are back; a daemon with
//   [calibration] state_file adopts an offline calibration of `nccomp calibrate`.
// Privilege separation (root only: users and groups switched in forked children): a member of
//   the status group only may read the calibration status, but the touches it fabricates are
//   refused (logged with uid, user name and pid) and the axis offsets stay; the same touches
//   from a member of the admin group recalibrate.
#include <gtest/gtest.h>

#include <cmath>
#include <sstream>
#include <string>

#include "core/calib/state.hpp"
#include "tests/hil/calib/daemon_process.hpp"
#include "tests/support/run_as.hpp"
#include "tools/calibrate/session.hpp"

namespace nccomp::test::calib {
namespace {

TEST(NccompdCalibration, OperatorCalibratesOverTheSocketAndRecalibrationsTrack) {
  TempDir dir;
  dir.write("nccompd.toml", config_text());
  Daemon d(dir.path);
  d.start();
  SimMachine m(test_config(), test_errors(), 0.2, 0.2, 0.1, 17);

  // Bad input: refused with the reason, counted, nothing changes, the daemon keeps running.
  auto a = d.ask("facets lateral abc 1.9");
  ASSERT_TRUE(a);
  EXPECT_EQ(*a, "error: calibrate: chord_plus_mm must be a finite number, got 'abc'\n");
  a = d.ask("touch machine q + 1.0");
  EXPECT_EQ(*a, "error: calibrate: axis must be x, y or z, got 'q'\n");
  a = d.ask("time 5");
  EXPECT_NE(a->find("error: calibrate: 'time' is not a daemon command"), std::string::npos) << *a;
  a = d.ask("facets lateral 1.99 1.98");  // valid, but no calibration started
  EXPECT_EQ(a->rfind("error: calibrate facets lateral 1.99 1.98: wrong-phase (phase "
                     "uncalibrated)",
                     0),
            0u)
      << *a;
  a = d.ask(std::string(500, 'x'));
  EXPECT_NE(a->find("longer than 400"), std::string::npos);
  a = d.ask("status");
  EXPECT_NE(a->find("commands: 0 taken by the calibrator, 1 refused by it, 4 refused by the "
                    "daemon"),
            std::string::npos)
      << *a;
  EXPECT_TRUE(d.alive());

  const std::string done = calibrate(d, m);
  // The registers reach the calibration: ΔxR, Δy, Δz against the simulated truth.
  const auto e = test_errors();
  std::string j = wait_settled(d);
  const double base_x = register_output(j, "X_offset");
  const double base_y = register_output(j, "Y_offset");
  const double base_z = register_output(j, "Z_offset");
  EXPECT_NEAR(base_x, e.ex_um, 0.5) << j;
  EXPECT_NEAR(base_y, e.ey_um, 1.0) << j;
  EXPECT_NEAR(base_z, e.ez_um, 1.0) << j;
  EXPECT_DOUBLE_EQ(register_output(j, "calibration_request"), 0.0);
  RecordProperty("base_x_um", std::to_string(base_x));

  // On demand: the request register goes to 5 until a touch set is evaluated.
  a = d.ask("recalibrate");
  ASSERT_TRUE(a);
  EXPECT_EQ(a->rfind("ok ready recalibration", 0), 0u) << *a;
  j = wait_json(d, [](const std::string& js) {
    return std::fabs(register_output(js, "calibration_request") - 5.0) < 1e-9;
  });
  EXPECT_DOUBLE_EQ(register_output(j, "calibration_request"), 5.0);
  // The machine has drifted: X +9, X axial +11, Y −5, Z +3.5 µm.
  m.set_drift([](double) { return std::array<double, 4>{9.0, 11.0, -5.0, 3.5}; });
  for (std::size_t slot = 0; slot < 4; ++slot) {
    for (int i = 0; i < 2; ++i) a = d.ask(touch_line(m.machine_touch(slot, 1, 0)));
  }
  // The answer to the touch completing the set shows the drifts it applied (truth ± noise).
  EXPECT_NEAR(value_after(*a, "info 47 recalibration-applied axis X: "), 9.0, 0.6) << *a;
  EXPECT_NEAR(value_after(*a, "info 47 recalibration-applied axis Y: "), -5.0, 0.6) << *a;
  EXPECT_NEAR(value_after(*a, "info 47 recalibration-applied axis Z: "), 3.5, 0.6) << *a;
  EXPECT_EQ(a->rfind("ok ready none", 0), 0u) << *a;
  // Crept in over 4 s: the registers end at base + drift.
  j = wait_json(d, [&](const std::string& js) {
    return std::fabs(register_output(js, "X_offset") - (base_x + 9.0)) < 0.5 &&
           std::fabs(register_output(js, "calibration_request")) < 1e-9;
  });
  EXPECT_NEAR(register_output(j, "X_offset"), base_x + 9.0, 0.5) << j;
  EXPECT_NEAR(register_output(j, "Y_offset"), base_y - 5.0, 0.5) << j;
  EXPECT_NEAR(register_output(j, "Z_offset"), base_z + 3.5, 0.5) << j;
  EXPECT_DOUBLE_EQ(register_output(j, "calibration_request"), 0.0);
  // A dirty sphere: Y reads 70 µm off → alarm 40, nothing applied (the answer says so).
  m.set_drift([](double) { return std::array<double, 4>{9.0, 11.0, 65.0, 3.5}; });
  for (std::size_t slot = 0; slot < 4; ++slot) {
    for (int i = 0; i < 2; ++i) a = d.ask(touch_line(m.machine_touch(slot, 1, 0)));
  }
  EXPECT_NEAR(value_after(*a, "ALARM 40 recalibration-implausible axis Y: "), 70.0, 0.6) << *a;
  EXPECT_NE(a->find("um, nothing applied"), std::string::npos) << *a;
  std::this_thread::sleep_for(300ms);
  j = d.json();
  EXPECT_NEAR(register_output(j, "Y_offset"), base_y - 5.0, 0.5) << j;
  a = d.ask("status");
  EXPECT_NEAR(value_after(*a, "X lateral: nominal "), 118.0, 0.01) << *a;
  EXPECT_NEAR(value_after(*a, "last drift "), 9.0, 0.6) << *a;
  EXPECT_NE(a->find("(2 sets)"), std::string::npos) << *a;
  EXPECT_EQ(d.stop(), 0) << d.log_text();
  const std::string log = d.log_text();
  EXPECT_NE(log.find("operator command refused: calibrate: chord_plus_mm must be a finite number"),
            std::string::npos);
}

TEST(NccompdCalibration, RestartMidCreepContinuesWhereTheNcIs) {
  TempDir dir;
  // 1 µm per write, 20 µm/s: a limiter that restarted from 0 would pull X down for seconds.
  dir.write("nccompd.toml", config_text("", 1.0, 20.0));
  SimMachine m(test_config(), test_errors(), 0.2, 0.2, 0.1, 29);
  double before_x = 0.0;
  double base_x = 0.0;
  {
    Daemon d(dir.path);
    d.start();
    calibrate(d, m);
    auto j = wait_settled(d);
    base_x = register_output(j, "X_offset");
    m.set_drift([](double) { return std::array<double, 4>{20.0, 20.0, -8.0, 6.0}; });
    for (std::size_t slot = 0; slot < 4; ++slot) {
      for (int i = 0; i < 2; ++i) (void)d.ask(touch_line(m.machine_touch(slot, 1, 0)));
    }
    std::this_thread::sleep_for(1500ms);  // mid-creep (4 s)
    j = d.json();
    before_x = register_output(j, "X_offset");
    EXPECT_GT(before_x, base_x + 2.0) << j;
    EXPECT_LT(before_x, base_x + 18.0) << j;
    EXPECT_EQ(d.stop(), 0);
  }
  Daemon d(dir.path);
  d.start();
  // From the first status on, X continues from where it was (never back towards 0) and ends at
  // base + 20.
  double lowest = 1e9;
  std::string j;
  const auto end = std::chrono::steady_clock::now() + 8s;
  while (std::chrono::steady_clock::now() < end) {
    j = d.json();
    const double x = register_output(j, "X_offset");
    if (std::isfinite(x)) lowest = std::min(lowest, x);
    if (std::fabs(x - (base_x + 20.0)) < 0.3) break;
    std::this_thread::sleep_for(10ms);
  }
  EXPECT_GE(lowest, before_x - 0.5) << "the X register dipped after the restart";
  EXPECT_NEAR(register_output(j, "X_offset"), base_x + 20.0, 0.5) << j;
  EXPECT_EQ(text(j, "phase"), "ready");
  EXPECT_NEAR(number(j, "x_last_drift_um"), 20.0, 1.0);
  const std::string log = d.log_text();
  EXPECT_NE(log.find("calibration: resumed phase ready"), std::string::npos) << log;
  EXPECT_EQ(d.stop(), 0);
}

TEST(NccompdCalibration, AdoptsAnOfflineCalibrationFromStateFile) {
  TempDir dir;
  // Offline: the documented example, calibrated with `nccomp calibrate`'s session.
  const std::string ex = std::string(NCCOMP_SOURCE_DIR) + "/tools/calibrate/examples/";
  std::ostringstream log;
  // The same machine as the daemon's config (test_config geometry): a session driven by the
  // simulated machine, state written as `nccomp calibrate --state` does.
  auto cfg = test_config();
  cfg.touches_per_axis = 2;
  tools::calibrate::Session s(cfg, 1.79e9, log);
  SimMachine m(cfg, test_errors(), 0.2, 0.2, 0.1, 41);
  std::string script = "begin\n";
  for (std::size_t slot = 0; slot < 4; ++slot) {
    for (int i = 0; i < 2; ++i) script += touch_line(m.reference_touch(slot, 1, 0)) + "\n";
  }
  std::size_t n = 0;
  std::istringstream in(script);
  std::string line;
  while (std::getline(in, line)) {
    ++n;
    s.run(tools::calibrate::parse_line(line, n), n);
  }
  for (const bool end_face : {false, true}) {
    const auto want =
        end_face ? core::calib::Phase::kTestGrindEndFace : core::calib::Phase::kTestGrindLateral;
    while (s.calibrator().phase() == want) {
      const auto [p, q] = m.test_grind(end_face, s.calibrator().grind_correction_um());
      char buf[120];
      std::snprintf(buf, sizeof buf, "facets %s %.6f %.6f", end_face ? "end-face" : "lateral", p,
                    q);
      ++n;
      s.run(tools::calibrate::parse_line(buf, n), n);
    }
  }
  for (std::size_t slot = 0; slot < 4; ++slot) {
    for (int i = 0; i < 2; ++i) {
      ++n;
      s.run(tools::calibrate::parse_line(touch_line(m.machine_touch(slot, 1, 0)), n), n);
    }
  }
  ASSERT_EQ(s.calibrator().phase(), core::calib::Phase::kReady) << log.str();
  dir.write("offline.state", s.export_state_text());
  const double dx_r = s.calibrator().result().dx_r_um;
  dir.write("nccompd.toml", config_text("state_file = \"offline.state\"\n"));
  {
    Daemon d(dir.path);
    d.start();
    const auto j = wait_json(d, [&](const std::string& js) {
      return std::fabs(register_output(js, "X_offset") - dx_r) < 0.01;
    });
    EXPECT_NEAR(register_output(j, "X_offset"), dx_r, 0.01) << j;
    EXPECT_EQ(text(j, "phase"), "ready");
    EXPECT_NE(d.log_text().find("calibration: adopted the calibration of"), std::string::npos)
        << d.log_text();
    EXPECT_EQ(d.stop(), 0);
  }
  // Restarted with the same file: the daemon's own state is as new, the file is not applied
  // again.
  Daemon d(dir.path);
  d.start();
  EXPECT_NE(d.log_text().find("is not newer than the calibration the daemon holds"),
            std::string::npos)
      << d.log_text();
  EXPECT_EQ(d.stop(), 0);
}

TEST(NccompdCalibration, OnlyTheAdminGroupFeedsTheCalibrator) {
  if (::geteuid() != 0) {
    GTEST_SKIP() << "switching to other users and groups needs root (CI runs as root)";
  }
  const auto users = nccomp::test::gid_of("users");  // stands for nccomp
  const auto adm = nccomp::test::gid_of("adm");      // stands for nccomp-admin
  const auto nogroup = nccomp::test::gid_of("nogroup");
  ASSERT_TRUE(users && adm && nogroup) << "groups users, adm, nogroup";
  TempDir dir;
  std::string cfg = config_text();
  const std::string sock_key = "socket_path = \"status.sock\"\n";
  cfg.insert(cfg.find(sock_key) + sock_key.size(), "admin_group = \"adm\"\n");
  dir.write("nccompd.toml", cfg);
  Daemon d(dir.path);
  d.start();
  ASSERT_EQ(::chown(d.socket().c_str(), static_cast<uid_t>(-1), *users), 0);
  SimMachine m(test_config(), test_errors(), 0.2, 0.2, 0.1, 23);
  calibrate(d, m);  // by root
  const double base_x = register_output(wait_settled(d), "X_offset");

  // A member of the status group only: the calibration status yes, fabricated touches no.
  const nccomp::test::Identity op{65534, *nogroup, {*users}};
  const nccomp::test::Identity admin{65534, *nogroup, {*users, *adm}};
  const std::string name = nccomp::test::user_name_of(65534);
  EXPECT_EQ(
      nccomp::test::request_as(op, d.socket(), "calibrate status").answer.rfind("ok ready", 0), 0U);
  m.set_drift([](double) { return std::array<double, 4>{15.0, 15.0, 0.0, 0.0}; });
  std::vector<std::string> touches;
  for (std::size_t slot = 0; slot < 4; ++slot) {
    for (int i = 0; i < 2; ++i) touches.push_back(touch_line(m.machine_touch(slot, 1, 0)));
  }
  pid_t refused_pid = -1;
  for (const auto& t : touches) {
    const auto r = nccomp::test::request_as(op, d.socket(), "calibrate " + t);
    EXPECT_EQ(r.answer.rfind("error: permission denied: 'calibrate' changes the machine; uid "
                             "65534 (" +
                                 name + ") is not root and not in group 'adm'",
                             0),
              0U)
        << r.answer;
    refused_pid = r.pid;
  }
  EXPECT_EQ(nccomp::test::request_as(op, d.socket(), "calibrate recalibrate")
                .answer.rfind("error: permission denied: ", 0),
            0U);
  std::this_thread::sleep_for(500ms);
  std::string j = d.json();
  EXPECT_NEAR(register_output(j, "X_offset"), base_x, 1e-9) << j;
  EXPECT_EQ(text(j, "phase"), "ready");
  EXPECT_NE(d.log_text().find("operator command refused: 'calibrate " + touches.back() +
                              "' from uid 65534 (" + name + ") pid " + std::to_string(refused_pid) +
                              ": permission denied"),
            std::string::npos)
      << d.log_text();

  // The same touches from a member of the admin group: taken, the drift creeps in.
  pid_t admin_pid = -1;
  for (const auto& t : touches) {
    const auto r = nccomp::test::request_as(admin, d.socket(), "calibrate " + t);
    EXPECT_EQ(r.answer.rfind("ok ", 0), 0U) << r.answer;
    admin_pid = r.pid;
  }
  j = wait_json(
      d, [&](const std::string& js) { return register_output(js, "X_offset") > base_x + 10.0; });
  EXPECT_GT(register_output(j, "X_offset"), base_x + 10.0) << j;
  EXPECT_NE(d.log_text().find("operator command from uid 65534 (" + name + ") pid " +
                              std::to_string(admin_pid) + ": calibrate " + touches.back()),
            std::string::npos)
      << d.log_text();
  EXPECT_EQ(d.stop(), 0);
}

}  // namespace
}  // namespace nccomp::test::calib
