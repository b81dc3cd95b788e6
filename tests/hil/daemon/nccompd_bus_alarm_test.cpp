// A bus alarm is an alarm of the daemon (docs/daemon.md, "Bus alarms"):
// GIVEN the nccompd binary on the project's Modbus NC server (127.0.0.1, ephemeral port) with
// [modbus] alarm_after_s = 0.3, running with its link up and no alarm,
// WHEN the NC server stops, THEN within a bounded time (5 s) the daemon logs
// "alarm bus_alarm (code 54) subject 0 value 1" and an error line naming the bus, its link state
// and why, its status's alarm list holds code 54 (severity alarm, value 1) and the bus line
// "alarm":true;
// WHEN the NC server starts again on the same port, THEN the daemon logs the clear
// ("info bus_alarm (code 54) subject 0 value 0", "bus modbus: alarm cleared (link up"), the bus's
// alarm is false, the alarm list holds the clear after the rise, each was logged exactly once,
// and the daemon ran through all of it (SIGTERM ends it with exit status 0).
#include <fcntl.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <regex>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "client/status_client.hpp"
#include "sim/modbus_nc/nc_server.hpp"
#include "tests/support/nccompd_process.hpp"
#include "tests/support/status_json.hpp"
#include "tests/support/temp_dir.hpp"
#include "tests/support/wait.hpp"

extern char** environ;

namespace {

using nccomp::test::number;
using nccomp::test::TempDir;
using nccomp::test::wait_until;

namespace fs = std::filesystem;
using namespace std::chrono_literals;
using nccomp::sim::modbus_nc::NcServer;
using nccomp::sim::modbus_nc::ServerConfig;

class Daemon : public nccomp::test::NccompdProcess {
 public:
  explicit Daemon(fs::path dir) : NccompdProcess(std::move(dir), NCCOMPD_BIN) {}
};

std::size_t count(const std::string& text, const std::string& what) {
  std::size_t n = 0;
  for (auto p = text.find(what); p != std::string::npos; p = text.find(what, p + 1)) ++n;
  return n;
}

std::string config_text(std::uint16_t port) {
  std::ostringstream s;
  s << "[daemon]\nrate_hz = 200\n"
    << "[state]\ndirectory = \"state\"\nmin_interval_s = 0.05\n"
    << "[measurement_log]\ndirectory = \"log\"\n"
    << "[status]\nsocket_path = \"status.sock\"\n"
    << "[modbus]\ntransport = \"tcp\"\nhost = \"127.0.0.1\"\nport = " << port << "\n"
    << "poll_rate_hz = 200\nresponse_timeout_s = 0.2\nalarm_after_s = 0.3\n"
    << "reconnect_min_s = 0.05\nreconnect_max_s = 0.2\n"
    << "[modbus.axis]\n"
    << "x_mm = { table = \"input\", address = 0, type = \"int32\", scale = 0.0001 }\n"
    << "tool = { table = \"input\", address = 8, type = \"uint16\" }\n"
    << "[[modbus.offset]]\nregister_index = 0\naddress = 200\ntype = \"int32\"\nscale = 0.1\n"
    << "[[registers]]\nname = \"T1_length_wear\"\nkind = \"tool_length_wear\"\nbus = \"modbus\"\n"
    << "max_abs_um = 200\nmax_step_um = 5\nmax_rate_um_per_s = 1000\n"
    << "[[ramp]]\nname = \"commissioning\"\nregister = \"T1_length_wear\"\ntarget_um = 12.3\n"
    << "rate_um_per_s = 100\n";
  return s.str();
}

// The daemon's status JSON: the bus line's alarm flag ("buses":[{"name":"modbus",...,"alarm":X).
bool bus_alarm_flag(const std::string& json) {
  return json.find("\"name\":\"modbus\"") != std::string::npos &&
         std::regex_search(json, std::regex("\"name\":\"modbus\"[^}]*\"alarm\":true"));
}

const std::string kRiseLog = "error alarm bus_alarm (code 54) subject 0 value 1";
const std::string kClearLog = "info info bus_alarm (code 54) subject 0 value 0";
const std::string kRiseJson =
    "\"severity\":\"alarm\",\"code\":54,\"name\":\"bus_alarm\",\"subject\":0,\"value\":1}";
const std::string kClearJson =
    "\"severity\":\"info\",\"code\":54,\"name\":\"bus_alarm\",\"subject\":0,\"value\":0}";

TEST(NccompdBusAlarm, ALinkDownBeyondAlarmAfterIsLoggedAndListedAndItsClearToo) {
  TempDir d;
  NcServer nc(ServerConfig{});
  nc.start();
  const std::uint16_t port = nc.port();
  std::ofstream(d.path / "nccompd.toml") << config_text(port);
  Daemon daemon(d.path);
  daemon.start();

  // Up, the ramp delivered (12.3 µm = 123 in 0.1 µm), no bus alarm anywhere.
  ASSERT_TRUE(wait_until(
      [&] {
        const std::string s = daemon.status();
        return s.find("\"state\":\"up\"") != std::string::npos && number(s, "cycles") >= 20;
      },
      10000ms))
      << daemon.log();
  ASSERT_TRUE(wait_until([&] { return nc.holding(200, 2)[1] == 123; }, 10000ms)) << daemon.log();
  std::string st = daemon.status();
  EXPECT_FALSE(bus_alarm_flag(st)) << st;
  EXPECT_EQ(st.find("\"code\":54"), std::string::npos) << st;
  EXPECT_EQ(daemon.log().find("bus_alarm"), std::string::npos) << daemon.log();

  // The NC goes away: link down beyond 0.3 s -> the daemon's alarm.
  const auto t_stop = std::chrono::steady_clock::now();
  nc.stop();
  ASSERT_TRUE(wait_until([&] { return daemon.log().find(kRiseLog) != std::string::npos; }, 5000ms))
      << daemon.log();
  const double rise_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t_stop).count();
  std::printf("NC stopped -> bus_alarm logged after %.3f s (alarm_after_s 0.3)\n", rise_s);
  std::string log = daemon.log();
  EXPECT_TRUE(std::regex_search(
      log,
      std::regex("error bus modbus: ALARM: offsets may not reach the NC: the link is not up "
                 "beyond alarm_after_s \\(link (down|connecting); offsets written [1-9][0-9]*, "
                 "retried [0-9]+, failed 0; reconnects [0-9]+\\)")))
      << log;
  ASSERT_TRUE(wait_until(
      [&] {
        st = daemon.status();
        return st.find(kRiseJson) != std::string::npos;
      },
      2000ms))
      << st;
  EXPECT_TRUE(bus_alarm_flag(st)) << st;
  EXPECT_EQ(st.find("\"code\":54,\"name\":\"bus_alarm\",\"subject\":0,\"value\":0"),
            std::string::npos)
      << st;
  // What `nccomp status` prints: the bus line says ALARM, the alarm list has bus_alarm.
  const std::string text = nccomp::client::query((d.path / "status.sock").string(), "text");
  EXPECT_TRUE(std::regex_search(text, std::regex("\n  modbus +(down|connecting) +ALARM"))) << text;
  EXPECT_TRUE(
      std::regex_search(text, std::regex("\n +[0-9.]+ s  alarm +bus_alarm +subject 0 value 1\n")))
      << text;
  std::printf("%s", text.substr(text.find("buses:")).c_str());
  // Still down 1 s later: reported once, not once per look.
  std::this_thread::sleep_for(1000ms);
  EXPECT_TRUE(daemon.running());
  EXPECT_EQ(count(daemon.log(), kRiseLog), 1U) << daemon.log();

  // The NC is back on the same port: the alarm clears.
  nc.start();
  ASSERT_EQ(nc.port(), port);
  ASSERT_TRUE(
      wait_until([&] { return daemon.log().find(kClearLog) != std::string::npos; }, 10000ms))
      << daemon.log();
  log = daemon.log();
  EXPECT_TRUE(std::regex_search(
      log, std::regex("info bus modbus: alarm cleared \\(link up; offsets written [1-9][0-9]*, "
                      "retried [0-9]+, failed 0; reconnects [1-9][0-9]*\\)")))
      << log;
  ASSERT_TRUE(wait_until(
      [&] {
        st = daemon.status();
        return st.find(kClearJson) != std::string::npos;
      },
      2000ms))
      << st;
  EXPECT_FALSE(bus_alarm_flag(st)) << st;
  EXPECT_LT(st.find(kRiseJson), st.find(kClearJson)) << st;  // the rise, then the clear
  EXPECT_EQ(count(st, "\"code\":54"), 2U) << st;
  EXPECT_EQ(count(log, kRiseLog), 1U);
  EXPECT_EQ(count(log, kClearLog), 1U);
  EXPECT_TRUE(daemon.running());
  const std::string text2 = nccomp::client::query((d.path / "status.sock").string(), "text");
  EXPECT_TRUE(
      std::regex_search(text2, std::regex("\n +[0-9.]+ s  info +bus_alarm +subject 0 value 0\n")))
      << text2;
  EXPECT_EQ(text2.find("ALARM"), std::string::npos) << text2;
  std::printf("%s", text2.substr(text2.find("buses:")).c_str());

  std::istringstream lines(log);
  for (std::string line; std::getline(lines, line);) {
    if (line.find("bus_alarm") != std::string::npos ||
        line.find("bus modbus: ALARM") != std::string::npos ||
        line.find("bus modbus: alarm cleared") != std::string::npos) {
      std::printf("%s\n", line.c_str());
    }
  }
  EXPECT_EQ(daemon.stop(), 0);
  nc.stop();
}

}  // namespace
