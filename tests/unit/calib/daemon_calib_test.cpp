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
#include <fcntl.h>
#include <gtest/gtest.h>
#include <poll.h>
#include <pty.h>
#include <signal.h>
#include <spawn.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <optional>
#include <regex>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "core/calib/state.hpp"
#include "tests/unit/calib/sim_machine.hpp"
#include "tests/unit/calib/test_config.hpp"
#include "tools/calibrate/daemon_client.hpp"
#include "tools/calibrate/session.hpp"

extern char** environ;

namespace nccomp::test::calib {
namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;

// The machine of test_config() on registers 0..2, request flag on 3.
// limiter_step_um / limiter_rate: the calibration's own limiter (the restart test makes it slow,
// so that a restart that forgot where the NC is would show as a dip).
std::string config_text(const std::string& extra_calibration = "", double limiter_step_um = 50.0,
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

struct TempDir {
  TempDir() {
    path = fs::temp_directory_path() /
           ("nccompd_calib_" + std::to_string(::getpid()) + "_" + std::to_string(n++));
    fs::remove_all(path);
    fs::create_directories(path);
  }
  ~TempDir() { fs::remove_all(path); }
  void write(const std::string& name, const std::string& text) const {
    std::ofstream(path / name) << text;
  }
  static inline int n = 0;
  fs::path path;
};

class Daemon {
 public:
  explicit Daemon(fs::path dir) : dir_(std::move(dir)) {}
  ~Daemon() { kill_now(); }
  void start() {
    std::vector<std::string> args{NCCOMPD_BIN, "--config", (dir_ / "nccompd.toml").string()};
    std::vector<char*> argv;
    for (auto& a : args) argv.push_back(a.data());
    argv.push_back(nullptr);
    posix_spawn_file_actions_t fa;
    posix_spawn_file_actions_init(&fa);
    const std::string log = (dir_ / "nccompd.log").string();
    posix_spawn_file_actions_addopen(&fa, 1, log.c_str(), O_WRONLY | O_CREAT | O_APPEND, 0644);
    posix_spawn_file_actions_adddup2(&fa, 1, 2);
    ASSERT_EQ(posix_spawn(&pid_, NCCOMPD_BIN, &fa, nullptr, argv.data(), environ), 0);
    posix_spawn_file_actions_destroy(&fa);
    // Up once the calibration module answers.
    const auto end = std::chrono::steady_clock::now() + 20s;
    while (std::chrono::steady_clock::now() < end) {
      if (const auto a = ask(""); a && a->rfind("ok ", 0) == 0) return;
      std::this_thread::sleep_for(20ms);
    }
    FAIL() << "nccompd did not answer 'calibrate'\n" << log_text();
  }
  int stop() {
    ::kill(pid_, SIGTERM);
    for (int i = 0; i < 1000; ++i) {
      int st = 0;
      if (::waitpid(pid_, &st, WNOHANG) == pid_) {
        pid_ = -1;
        return WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
      }
      std::this_thread::sleep_for(10ms);
    }
    return -1;
  }
  void kill_now() {
    if (pid_ > 0) {
      ::kill(pid_, SIGKILL);
      ::waitpid(pid_, nullptr, 0);
      pid_ = -1;
    }
  }
  [[nodiscard]] bool alive() const { return pid_ > 0 && ::kill(pid_, 0) == 0; }
  [[nodiscard]] std::optional<std::string> ask(const std::string& command) const {
    try {
      return tools::calibrate::daemon_request(socket(), command, 10.0);
    } catch (const std::exception&) {
      return std::nullopt;
    }
  }
  [[nodiscard]] std::string socket() const { return (dir_ / "status.sock").string(); }
  [[nodiscard]] std::string log_text() const {
    std::ifstream in(dir_ / "nccompd.log");
    std::ostringstream s;
    s << in.rdbuf();
    return s.str();
  }

 private:
  fs::path dir_;
  pid_t pid_{-1};
};

std::string raw_request(const std::string& socket, const std::string& line) {
  // daemon_request() prefixes "calibrate "; a status request goes through a bare socket.
  sockaddr_un addr{};
  addr.sun_family = AF_UNIX;
  std::memcpy(addr.sun_path, socket.c_str(), socket.size() + 1);
  const int fd = ::socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
  if (fd < 0) return "";
  if (::connect(fd, reinterpret_cast<const sockaddr*>(&addr), sizeof addr) != 0) {
    ::close(fd);
    return "";
  }
  const std::string req = line + "\n";
  (void)::send(fd, req.data(), req.size(), MSG_NOSIGNAL);
  ::shutdown(fd, SHUT_WR);
  std::string out;
  char buf[4096];
  for (;;) {
    const ssize_t n = ::recv(fd, buf, sizeof buf, 0);
    if (n <= 0) break;
    out.append(buf, static_cast<std::size_t>(n));
  }
  ::close(fd);
  return out;
}

double register_output(const std::string& json, const std::string& name) {
  const std::regex re("\"name\":\"" + name + "\",\"output_um\":(-?[0-9.eE+-]+)");
  std::smatch m;
  return std::regex_search(json, m, re) ? std::stod(m[1]) : std::nan("");
}

double number(const std::string& json, const std::string& key) {
  const std::regex re("\"" + key + "\":(-?[0-9.eE+-]+)");
  std::smatch m;
  return std::regex_search(json, m, re) ? std::stod(m[1]) : std::nan("");
}

std::string text(const std::string& json, const std::string& key) {
  const std::regex re("\"" + key + "\":\"([^\"]*)\"");
  std::smatch m;
  return std::regex_search(json, m, re) ? m[1].str() : "";
}

std::string touch_line(const core::CalibrationTouch& t) {
  char buf[160];
  std::snprintf(buf, sizeof buf, "touch %s %s %s %s %.6f",
                t.probe == core::ProbeKind::kReferenceProbe ? "reference" : "machine",
                t.axis == 0 ? "x" : (t.axis == 1 ? "y" : "z"), t.direction > 0 ? "+" : "-",
                t.variant == 1 ? "axial" : "lateral", t.trigger_position_mm);
  return buf;
}

// The number right after `prefix` in text (NaN if absent).
double value_after(const std::string& text, const std::string& prefix) {
  const auto p = text.find(prefix);
  if (p == std::string::npos) return std::nan("");
  try {
    return std::stod(text.substr(p + prefix.size()));
  } catch (const std::exception&) {
    return std::nan("");
  }
}

double dx_of(const std::string& answer) {
  const std::regex re("with dx ([-+0-9.]+) um");
  std::smatch m;
  return std::regex_search(answer, m, re) ? std::stod(m[1]) : std::nan("");
}

// Waits until pred(json) or the limit; returns the last json.
template <typename Pred>
std::string wait_json(const Daemon& d, Pred pred, std::chrono::milliseconds limit = 10000ms) {
  const auto end = std::chrono::steady_clock::now() + limit;
  std::string j;
  while (std::chrono::steady_clock::now() < end) {
    j = raw_request(d.socket(), "json");
    if (!j.empty() && pred(j)) break;
    std::this_thread::sleep_for(20ms);
  }
  return j;
}

// The whole initial calibration through the socket; returns the last answer.
std::string calibrate(Daemon& d, SimMachine& m) {
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
  std::string j = wait_json(d, [&](const std::string& js) {
    return std::fabs(register_output(js, "Y_offset") - number(js, "y_written_um")) < 1e-6 &&
           text(js, "phase") == "ready";
  });
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
  j = raw_request(d.socket(), "json");
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
    auto j = wait_json(d, [](const std::string& js) {
      return std::fabs(register_output(js, "X_offset") - number(js, "x_written_um")) < 1e-6 &&
             number(js, "x_written_um") > 10.0;
    });
    std::this_thread::sleep_for(500ms);
    base_x = register_output(raw_request(d.socket(), "json"), "X_offset");
    m.set_drift([](double) { return std::array<double, 4>{20.0, 20.0, -8.0, 6.0}; });
    for (std::size_t slot = 0; slot < 4; ++slot) {
      for (int i = 0; i < 2; ++i) (void)d.ask(touch_line(m.machine_touch(slot, 1, 0)));
    }
    std::this_thread::sleep_for(1500ms);  // mid-creep (4 s)
    j = raw_request(d.socket(), "json");
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
    j = raw_request(d.socket(), "json");
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

// ---------------------------------------------------------------------------------------------
// The operator's program itself: `nccomp calibrate` at a terminal (pty) and against the daemon.

struct Output {
  int status{-1};
  std::string text;
};

// Runs nccomp with args on a pseudo-terminal, typing `input` line by line after each prompt.
Output run_on_pty(const std::vector<std::string>& args, const std::vector<std::string>& input) {
  int master = -1;
  const pid_t pid = forkpty(&master, nullptr, nullptr, nullptr);
  if (pid == 0) {
    std::vector<char*> argv;
    std::vector<std::string> a = args;
    for (auto& s : a) argv.push_back(s.data());
    argv.push_back(nullptr);
    ::execv(NCCOMP_BIN, argv.data());
    ::_exit(127);
  }
  Output out;
  std::size_t next = 0;
  const auto end = std::chrono::steady_clock::now() + 30s;
  char buf[4096];
  while (std::chrono::steady_clock::now() < end) {
    pollfd p{master, POLLIN, 0};
    if (::poll(&p, 1, 100) > 0) {
      const ssize_t n = ::read(master, buf, sizeof buf);
      if (n <= 0) break;  // EIO once the child closed the terminal
      out.text.append(buf, static_cast<std::size_t>(n));
    }
    // Type the next line once a new prompt appeared.
    const auto prompts = [&] {
      std::size_t c = 0;
      for (auto pos = out.text.find("calibrate> "); pos != std::string::npos;
           pos = out.text.find("calibrate> ", pos + 1)) {
        ++c;
      }
      return c;
    }();
    if (next < input.size() && prompts > next) {
      const std::string l = input[next++] + "\n";
      (void)::write(master, l.data(), l.size());
    }
  }
  int st = 0;
  ::waitpid(pid, &st, 0);
  ::close(master);
  out.status = WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
  return out;
}

TEST(CalibratePrompt, TerminalPromptShowsTheNextStepAndLetsAWrongLineBeRetyped) {
  TempDir dir;
  const std::string ex = std::string(NCCOMP_SOURCE_DIR) + "/tools/calibrate/examples/";
  const std::string state = (dir.path / "p.state").string();
  const auto out = run_on_pty({"nccomp", "calibrate", "--config", ex + "machine.toml", "--state",
                               state, "--epoch", "1795766400"},
                              {"begin", "touch reference q + 1.0",
                               "touch reference x + lateral 247.0276", "bogus", "quit"});
  EXPECT_EQ(out.status, 0) << out.text;
  // The first prompt, then the reference-touch hint with the progress after a valid touch.
  EXPECT_NE(
      out.text.find("-- not calibrated: 'begin' starts an initial calibration\r\ncalibrate> "),
      std::string::npos)
      << out.text;
  EXPECT_NE(out.text.find("error: line 2: axis must be x, y or z, got 'q'"), std::string::npos)
      << out.text;
  EXPECT_NE(out.text.find("-- touch the reference disk with the reference probe (X lateral 1/2, "
                          "X axial 0/2, Y 0/2, Z 0/2)"),
            std::string::npos)
      << out.text;
  EXPECT_NE(out.text.find("error: line 4: unknown command 'bogus' (try 'help')"),
            std::string::npos);
  EXPECT_NE(out.text.find("saved state " + state), std::string::npos);
  std::ifstream in(state);
  std::ostringstream s;
  s << in.rdbuf();
  EXPECT_EQ(core::calib::from_text(s.str()).phase, core::calib::Phase::kReferenceTouches);
}

TEST(CalibratePrompt, DaemonScriptAndInteractiveModes) {
  TempDir dir;
  dir.write("nccompd.toml", config_text());
  Daemon d(dir.path);
  d.start();
  SimMachine m(test_config(), test_errors(), 0.2, 0.2, 0.1, 53);
  // A script against the daemon: begin, the reference touches, await the test grind.
  std::string script = "begin  # start\n";
  for (std::size_t slot = 0; slot < 4; ++slot) {
    for (int i = 0; i < 2; ++i) script += touch_line(m.reference_touch(slot, 1, 0)) + "\n";
  }
  script += "await test-grind-lateral 10\nstatus\n";
  dir.write("s.calib", script);
  const std::string cmd = std::string(NCCOMP_BIN) + " calibrate --daemon " + d.socket() +
                          " --script " + (dir.path / "s.calib").string() + " 2>&1";
  std::string text;
  int status = -1;
  {
    FILE* p = ::popen(cmd.c_str(), "r");
    ASSERT_NE(p, nullptr);
    char buf[4096];
    std::size_t n = 0;
    while ((n = std::fread(buf, 1, sizeof buf, p)) > 0) text.append(buf, n);
    status = WEXITSTATUS(::pclose(p));
  }
  EXPECT_EQ(status, 0) << text;
  EXPECT_NE(text.find("initial calibration started"), std::string::npos) << text;
  EXPECT_NE(text.find("reference touches: dx lateral"), std::string::npos) << text;
  EXPECT_NE(text.find("phase test-grind-lateral"), std::string::npos) << text;
  EXPECT_NE(text.find("-- grind the blank from +X and -X with dx"), std::string::npos) << text;
  // A device export with the chords of the first grind: a bad one is refused at its line, a good
  // one is entered.
  const auto now = d.ask("");
  ASSERT_TRUE(now);
  const double dx = dx_of(*now);
  const auto [p, q] = m.test_grind(false, dx);
  char csv[256];
  std::snprintf(csv, sizeof csv,
                "# facet microscope "
                "export\nface;chord_plus_mm;chord_minus_mm;operator\nlateral;%.6f;%.6f;mk\n",
                p, q);
  dir.write("device.csv", csv);
  dir.write("bad.csv", "face,chord_plus_mm,chord_minus_mm\nlateral,1.9,-2\n");
  // Interactive over a pipe: every command answered, a refused one does not end the session.
  const std::string cmd2 = "printf 'facets-file " + (dir.path / "bad.csv").string() +
                           "\\nfacets-file " + (dir.path / "device.csv").string() +
                           "\\nquit\\n' | " + std::string(NCCOMP_BIN) + " calibrate --daemon " +
                           d.socket() + " --interactive 2>&1";
  text.clear();
  {
    FILE* pp = ::popen(cmd2.c_str(), "r");
    ASSERT_NE(pp, nullptr);
    char buf[4096];
    std::size_t n = 0;
    while ((n = std::fread(buf, 1, sizeof buf, pp)) > 0) text.append(buf, n);
    status = WEXITSTATUS(::pclose(pp));
  }
  EXPECT_EQ(status, 0) << text;
  EXPECT_NE(text.find("bad.csv:2: chord_minus_mm must be in (0, 1000] mm, got '-2'"),
            std::string::npos)
      << text;
  EXPECT_NE(text.find("device.csv line 3:"), std::string::npos) << text;
  EXPECT_NE(text.find("facets lateral: c+"), std::string::npos) << text;
  EXPECT_NE(text.find("1 command(s) refused"), std::string::npos) << text;
  const auto a = d.ask("");
  EXPECT_TRUE(a->rfind("ok test-grind-lateral", 0) == 0 ||
              a->rfind("ok test-grind-end-face", 0) == 0)
      << *a;
  EXPECT_EQ(d.stop(), 0);
}

}  // namespace
}  // namespace nccomp::test::calib
