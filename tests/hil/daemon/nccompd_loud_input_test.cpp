// Stale and invalid input is loud (issue 17, finding 4; docs/daemon.md, "Stale or invalid input"):
// the real nccompd on the project's Modbus NC server (127.0.0.1, ephemeral port).
//
// GIVEN [modbus] degraded_alarm_after_s = 0.5 and the daemon running with its link up,
// WHEN the NC answers every read with exception 4 (server failure), THEN within a bounded time
// the daemon logs "alarm bus_input_stale (code 55) subject 0 value 1" once, with a line naming
// the bus, its link state (degraded) and counters, and lists it in its status; the link is never
// taken for down (no bus_alarm 54); WHEN the NC answers again, THEN the clear is logged once with
// how long it lasted and the faults meanwhile, and listed.
//
// GIVEN a [creep] module and the laser's measurement on the NC, WHEN the laser's wear register
// holds NaN as its counter advances, THEN the creep module raises tool_broken_or_mismeasured (23,
// value nan) and halts: the NC's alarm register rises, nothing is applied, the measurement log
// has the row without a value; WHEN six more such measurements follow (each published once the
// driver has read the one before), THEN each is refused (event_invalid 51, the module is halted)
// but logged once per burst: one line when the burst starts, one "end of burst" line with the
// count 6.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
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
using nccomp::sim::modbus_nc::Tables;

std::string slurp(const fs::path& p) {
  std::ifstream in(p);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

class Daemon : public nccomp::test::NccompdProcess {
 public:
  explicit Daemon(fs::path dir) : NccompdProcess(std::move(dir), NCCOMPD_BIN) {}
};

std::size_t count(const std::string& text, const std::string& what) {
  std::size_t n = 0;
  for (auto p = text.find(what); p != std::string::npos; p = text.find(what, p + 1)) ++n;
  return n;
}

bool up(const Daemon& d) {
  const std::string s = d.status();
  return s.find("\"state\":\"up\"") != std::string::npos && number(s, "cycles") >= 20;
}

void print_lines(const std::string& log, const std::vector<std::string>& keys) {
  std::istringstream lines(log);
  for (std::string line; std::getline(lines, line);) {
    for (const auto& k : keys) {
      if (line.find(k) != std::string::npos) {
        std::printf("%s\n", line.c_str());
        break;
      }
    }
  }
}

std::string common_sections(std::uint16_t port) {
  std::ostringstream s;
  s << "[daemon]\nrate_hz = 200\n"
    << "[state]\ndirectory = \"state\"\nmin_interval_s = 0.05\n"
    << "[measurement_log]\ndirectory = \"log\"\n"
    << "[status]\nsocket_path = \"status.sock\"\n"
    << "[modbus]\ntransport = \"tcp\"\nhost = \"127.0.0.1\"\nport = " << port << "\n"
    << "poll_rate_hz = 200\nresponse_timeout_s = 0.5\ndegraded_alarm_after_s = 0.5\n"
    << "[modbus.axis]\n"
    << "x_mm = { table = \"input\", address = 0, type = \"int32\", scale = 0.0001 }\n"
    << "tool = { table = \"input\", address = 8, type = \"uint16\" }\n";
  return s.str();
}

const std::string kStaleRise = "error alarm bus_input_stale (code 55) subject 0 value 1";
const std::string kStaleClear = "info info bus_input_stale (code 55) subject 0 value 0";

TEST(NccompdLoudInput, AnNcThatAnswersEveryReadWithAnExceptionRaisesBusInputStale) {
  TempDir d;
  NcServer nc(ServerConfig{});
  nc.start();
  std::ofstream(d.path / "nccompd.toml")
      << common_sections(nc.port())
      << "[[modbus.offset]]\nregister_index = 0\naddress = 200\ntype = \"int32\"\nscale = 0.1\n"
      << "[[registers]]\nname = \"T1_length_wear\"\nkind = \"tool_length_wear\"\n"
      << "bus = \"modbus\"\nmax_abs_um = 200\nmax_step_um = 5\nmax_rate_um_per_s = 1000\n"
      << "[[ramp]]\nname = \"commissioning\"\nregister = \"T1_length_wear\"\ntarget_um = 12.3\n"
      << "rate_um_per_s = 100\n";
  Daemon daemon(d.path);
  daemon.start();
  ASSERT_TRUE(wait_until([&] { return up(daemon); })) << daemon.log();
  EXPECT_EQ(daemon.log().find("bus_input_stale"), std::string::npos) << daemon.log();

  const auto t0 = std::chrono::steady_clock::now();
  nc.set_read_exception(4);
  ASSERT_TRUE(wait_until([&] { return daemon.log().find(kStaleRise) != std::string::npos; }))
      << daemon.log();
  std::printf(
      "every read answered with exception 4 -> bus_input_stale logged after %.3f s "
      "(degraded_alarm_after_s 0.5)\n",
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
  EXPECT_TRUE(std::regex_search(
      daemon.log(),
      std::regex("error bus modbus: ALARM: input from the NC is stale: the link not healthy or "
                 "no valid axis sample for longer than degraded_alarm_after_s; positions and "
                 "measurements are not arriving \\(link degraded; frames rx [0-9]+, faults "
                 "[1-9][0-9]*, malformed 0; its counters in `nccomp status`\\)")))
      << daemon.log();
  std::string st;
  ASSERT_TRUE(wait_until([&] {
    st = daemon.status();
    return st.find("\"code\":55,\"name\":\"bus_input_stale\",\"subject\":0,\"value\":1") !=
           std::string::npos;
  })) << st;
  EXPECT_NE(st.find("\"state\":\"degraded\",\"alarm\":false,\"input_stale\":true"),
            std::string::npos)
      << st;
  // What `nccomp status` prints meanwhile (for docs/daemon.md), and the metrics.
  const std::string sock = (d.path / "status.sock").string();
  const std::string text = nccomp::client::query(sock, "text");
  EXPECT_TRUE(std::regex_search(
      text, std::regex("\n +[0-9.]+ s  alarm +bus_input_stale +subject 0 value 1\n")))
      << text;
  EXPECT_TRUE(std::regex_search(text, std::regex("\n  modbus +degraded +INPUT STALE rx "))) << text;
  EXPECT_NE(
      nccomp::client::query(sock, "metrics").find("nccompd_bus_input_stale{bus=\"modbus\"} 1\n"),
      std::string::npos);
  std::printf("%s", text.substr(text.find("buses:")).c_str());
  EXPECT_GE(number(st, "exception_server_failure"), 10.0) << st;
  std::this_thread::sleep_for(1000ms);  // still answering with exceptions: reported once
  EXPECT_EQ(count(daemon.log(), kStaleRise), 1U) << daemon.log();
  EXPECT_EQ(daemon.log().find("bus_alarm"), std::string::npos) << daemon.log();

  nc.set_read_exception(0);
  ASSERT_TRUE(wait_until([&] { return daemon.log().find(kStaleClear) != std::string::npos; }))
      << daemon.log();
  const std::string log = daemon.log();
  EXPECT_TRUE(std::regex_search(
      log, std::regex("info bus modbus: input stale cleared after [0-9.]+ s \\(link up; "
                      "meanwhile faults [1-9][0-9]*, malformed 0, frames rx [1-9][0-9]*\\)")))
      << log;
  EXPECT_EQ(count(log, kStaleRise), 1U);
  EXPECT_EQ(count(log, kStaleClear), 1U);
  ASSERT_TRUE(wait_until([&] {
    st = daemon.status();
    return st.find("\"code\":55,\"name\":\"bus_input_stale\",\"subject\":0,\"value\":0") !=
           std::string::npos;
  })) << st;
  EXPECT_NE(st.find("\"input_stale\":false"), std::string::npos) << st;
  EXPECT_NE(
      nccomp::client::query(sock, "metrics").find("nccompd_bus_input_stale{bus=\"modbus\"} 0\n"),
      std::string::npos);
  print_lines(log, {"bus_input_stale", "input from the NC is stale", "input stale cleared"});
  EXPECT_TRUE(daemon.running());
  EXPECT_EQ(daemon.stop(), 0);
}

constexpr std::uint16_t kLength = 200;  // T1_length_wear, int32, 0.1 µm
constexpr std::uint16_t kAlarm = 240;   // creep_alarm, uint16 flag

// The laser's result: values first, then the event counter (the profile's rule).
void publish_wear(NcServer& nc, std::uint16_t seq, float wear_um) {
  nc.update([&](Tables& t) {
    std::uint32_t bits = 0;
    std::memcpy(&bits, &wear_um, sizeof bits);
    t.input[101] = 1;
    t.input[102] = static_cast<std::uint16_t>(bits >> 16);
    t.input[103] = static_cast<std::uint16_t>(bits & 0xFFFF);
    t.input[100] = seq;
  });
}

TEST(NccompdLoudInput, ANaNWearRaisesTheCreepAlarmAndABurstIsLoggedOnce) {
  TempDir d;
  NcServer nc(ServerConfig{});
  nc.start();
  nc.update([](Tables& t) { t.input[8] = 1; });  // tool 1 in the spindle
  std::ofstream(d.path / "nccompd.toml")
      << common_sections(nc.port()) << "[modbus.tool_measurement]\n"
      << "sequence = { table = \"input\", address = 100, type = \"uint16\" }\n"
      << "tool = { table = \"input\", address = 101, type = \"uint16\" }\n"
      << "wear_um = { table = \"input\", address = 102, type = \"float32\" }\n"
      << "[[modbus.offset]]\nregister_index = 0\naddress = 200\ntype = \"int32\"\nscale = 0.1\n"
      << "[[modbus.offset]]\nregister_index = 1\naddress = 240\ntype = \"uint16\"\nscale = 1.0\n"
      << "[[registers]]\nname = \"T1_length_wear\"\nkind = \"tool_length_wear\"\n"
      << "bus = \"modbus\"\nmax_abs_um = 200\nmax_step_um = 5\nmax_rate_um_per_s = 50\n"
      << "[[registers]]\nname = \"creep_alarm\"\nkind = \"flag\"\nbus = \"modbus\"\n"
      << "[creep]\ncreep_basis = \"time\"\ncreep_time_s = 1.0\nprofile = \"linear\"\n"
      << "[creep.edge]\ntool_shape = \"tip\"\nnormal_source = \"none\"\n"
      << "fallback_channel = \"length\"\n"
      << "[creep.output]\nmode = \"tool_registers\"\nlength_register = \"T1_length_wear\"\n"
      << "alarm_register = \"creep_alarm\"\n";
  Daemon daemon(d.path);
  daemon.start();
  ASSERT_TRUE(wait_until([&] { return up(daemon); })) << daemon.log();

  publish_wear(nc, 1, std::nanf(""));
  const std::string rise = "error alarm tool_broken_or_mismeasured (code 23) subject 1 value nan";
  ASSERT_TRUE(wait_until([&] { return daemon.log().find(rise) != std::string::npos; }))
      << daemon.log();
  ASSERT_TRUE(wait_until([&] { return nc.holding(kAlarm, 1)[0] == 1; })) << daemon.log();
  std::string st;
  ASSERT_TRUE(wait_until([&] {
    st = daemon.status();
    return std::fabs(number(st, "halted") - 1.0) < 1e-9 &&
           std::fabs(number(st, "latched_alarm") - 23.0) < 1e-9;
  })) << st;
  EXPECT_NE(st.find("\"code\":23,\"name\":\"tool_broken_or_mismeasured\",\"subject\":1"),
            std::string::npos)
      << st;
  EXPECT_GE(number(st, "values_invalid"), 1.0) << st;

  // Six more, each once the driver has read the one before (its values_invalid counted it).
  for (std::uint16_t seq = 2; seq <= 7; ++seq) {
    publish_wear(nc, seq, seq % 2 == 0 ? std::numeric_limits<float>::infinity() : std::nanf(""));
    ASSERT_TRUE(wait_until([&] { return number(daemon.status(), "values_invalid") >= seq; }))
        << daemon.status();
  }
  const std::string refused = "warning warning event_invalid (code 51) subject 1 value 0";
  const std::string end = "end of burst: event_invalid (code 51, warning) subject 1 value 0: 6 in";
  ASSERT_TRUE(wait_until([&] { return daemon.log().find(end) != std::string::npos; }))
      << daemon.log();
  const std::string log = daemon.log();
  EXPECT_EQ(count(log, rise), 1U) << log;
  EXPECT_EQ(count(log, refused), 1U) << log;
  EXPECT_EQ(count(log, end), 1U) << log;
  EXPECT_EQ(number(daemon.status(), "values_invalid"), 7.0) << daemon.status();
  // Nothing applied: the length register never moved from 0.
  EXPECT_EQ(nc.holding(kLength, 2)[1], 0);
  EXPECT_EQ(nc.holding(kLength, 2)[0], 0);
  print_lines(log, {"(code 23)", "(code 51)", "end of burst"});
  EXPECT_TRUE(daemon.running());
  EXPECT_EQ(daemon.stop(), 0);

  // Every measurement is in the measurement log, without a value (measured_um empty, applied_um
  // 0; then the v2 columns machine, utc, session).
  const std::string rows = slurp(d.path / "log" / "measurements.csv");
  EXPECT_EQ(count(rows, ",tool_wear,"), 7U) << rows;
  EXPECT_TRUE(
      std::regex_search(rows, std::regex(",tool_wear,0,[^\n]*,,0[.0]*,[^,\n]*,[^,\n]*,[0-9]+\n")))
      << rows;
}

}  // namespace
