// Events the NC publishes while nccompd is down (issue 17, finding 3; docs/daemon.md, "Events
// while nccompd was down"), with the nccompd binary on the project's Modbus NC server (127.0.0.1,
// ephemeral port) and a [creep] module whose "measurement due" flag is an NC register:
// GIVEN a first laser measurement crept in and the next one asked for, WHEN nccompd is killed
// (SIGKILL) and the laser publishes two measurements before it is started again, THEN the
// restarted daemon delivers the newest once (crept in), counts the other lost, logs it, and the
// request cycle goes on; a clean restart with nothing published delivers nothing.
// GIVEN the request up when nccompd is killed and nothing published while it is down, WHEN it
// starts again while the NC still holds the request, THEN the NC's register is written 0 and
// then 1 (a rising edge the NC reacts to), and the measurement that answers it is applied.
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

class Daemon : public nccomp::test::NccompdProcess {
 public:
  explicit Daemon(fs::path dir) : NccompdProcess(std::move(dir), NCCOMPD_BIN) {}
};

constexpr std::uint16_t kLength = 200;   // T1_length_wear, int32, 0.1 µm (tool_register_sign -1)
constexpr std::uint16_t kRequest = 242;  // measure_request, uint16 flag

std::string config_text(std::uint16_t port) {
  std::ostringstream s;
  s << "[daemon]\nrate_hz = 200\n"
    << "[state]\ndirectory = \"state\"\nmin_interval_s = 0.05\n"
    << "[measurement_log]\ndirectory = \"log\"\n"
    << "[status]\nsocket_path = \"status.sock\"\n"
    << "[modbus]\ntransport = \"tcp\"\nhost = \"127.0.0.1\"\nport = " << port << "\n"
    << "poll_rate_hz = 200\nresponse_timeout_s = 0.5\n"
    << "[modbus.axis]\n"
    << "x_mm = { table = \"input\", address = 0, type = \"int32\", scale = 0.0001 }\n"
    << "tool = { table = \"input\", address = 8, type = \"uint16\" }\n"
    << "[modbus.tool_measurement]\n"
    << "sequence = { table = \"input\", address = 100, type = \"uint16\" }\n"
    << "tool = { table = \"input\", address = 101, type = \"uint16\" }\n"
    << "wear_um = { table = \"input\", address = 102, type = \"float32\" }\n"
    << "[[modbus.offset]]\nregister_index = 0\naddress = 200\ntype = \"int32\"\nscale = 0.1\n"
    << "[[modbus.offset]]\nregister_index = 1\naddress = 242\ntype = \"uint16\"\nscale = 1.0\n"
    << "[[registers]]\nname = \"T1_length_wear\"\nkind = \"tool_length_wear\"\nbus = \"modbus\"\n"
    << "max_abs_um = 200\nmax_step_um = 5\nmax_rate_um_per_s = 50\n"
    << "[[registers]]\nname = \"measure_request\"\nkind = \"flag\"\nbus = \"modbus\"\n"
    << "[creep]\ncreep_basis = \"time\"\ncreep_time_s = 1.0\nprofile = \"linear\"\n"
    << "[creep.edge]\ntool_shape = \"tip\"\nnormal_source = \"none\"\n"
    << "fallback_channel = \"length\"\n"
    << "[creep.output]\nmode = \"tool_registers\"\nlength_register = \"T1_length_wear\"\n"
    << "measurement_due_register = \"measure_request\"\n"
    << "[creep.interval]\nbasis = \"time\"\ninterval_s = 1.0\n";
  return s.str();
}

std::int32_t holding_i32(NcServer& nc, std::uint16_t address) {
  const auto r = nc.holding(address, 2);
  return static_cast<std::int32_t>((std::uint32_t{r[0]} << 16) | r[1]);
}

int holding(NcServer& nc, std::uint16_t address) { return nc.holding(address, 1)[0]; }

// The laser's result: values first, then the event counter (the profile's rule).
void publish_tool_measurement(NcServer& nc, std::uint16_t seq, float wear_um) {
  nc.update([&](Tables& t) {
    std::uint32_t bits = 0;
    std::memcpy(&bits, &wear_um, sizeof bits);
    t.input[101] = 1;
    t.input[102] = static_cast<std::uint16_t>(bits >> 16);
    t.input[103] = static_cast<std::uint16_t>(bits & 0xFFFF);
    t.input[100] = seq;
  });
}

/// The values the NC received for `address` in write requests number `from` on.
std::vector<std::uint16_t> written(NcServer& nc, std::size_t from, std::uint16_t address) {
  std::vector<std::uint16_t> v;
  const auto all = nc.writes();
  for (std::size_t i = from; i < all.size(); ++i) {
    if (all[i].address == address && !all[i].values.empty()) v.push_back(all[i].values[0]);
  }
  return v;
}

/// nccompd up on the NC, a first measurement of 5.0 µm crept in, the next one asked for (the
/// daemon's state holds the raised request), then killed.
void run_until_killed_with_the_request_up(NcServer& nc, Daemon& daemon) {
  daemon.start();
  ASSERT_TRUE(wait_until([&] {
    const std::string s = daemon.status();
    return s.find("\"state\":\"up\"") != std::string::npos && number(s, "cycles") >= 20;
  })) << daemon.log();
  ASSERT_TRUE(wait_until([&] { return holding(nc, kRequest) == 1; })) << daemon.log();
  publish_tool_measurement(nc, 1, 5.0F);
  ASSERT_TRUE(wait_until([&] { return holding_i32(nc, kLength) == -50; }))
      << holding_i32(nc, kLength) << "\n"
      << daemon.status();
  ASSERT_TRUE(wait_until([&] { return holding(nc, kRequest) == 1; })) << daemon.status();
  // The state with the raised request is written within min_interval_s (0.05 s).
  std::this_thread::sleep_for(300ms);
  daemon.kill();
}

TEST(NccompdEventsWhileDown, TheNewestMeasurementPublishedWhileDownIsAppliedOnceTheOtherCounted) {
  TempDir d;
  NcServer nc(ServerConfig{});
  nc.start();
  nc.update([](Tables& t) { t.input[8] = 1; });  // tool 1 in the spindle, cutting
  std::ofstream(d.path / "nccompd.toml") << config_text(nc.port());
  Daemon daemon(d.path);
  run_until_killed_with_the_request_up(nc, daemon);
  if (HasFatalFailure()) return;

  // While it is down the laser measures twice: 6.0 µm, then 7.0 µm.
  publish_tool_measurement(nc, 2, 6.0F);
  publish_tool_measurement(nc, 3, 7.0F);
  std::this_thread::sleep_for(200ms);
  daemon.start();
  // The newest (7.0 µm) is crept in over 1 s; the request falls, and rises again after 1 s of
  // cutting: the cycle goes on.
  ASSERT_TRUE(wait_until([&] { return holding_i32(nc, kLength) == -70; }))
      << holding_i32(nc, kLength) << "\n"
      << daemon.log();
  ASSERT_TRUE(wait_until([&] { return holding(nc, kRequest) == 0; }, 2000ms)) << daemon.log();
  const std::string st = daemon.status();
  EXPECT_EQ(number(st, "events_recovered_after_start"), 1.0) << st;
  EXPECT_EQ(number(st, "events_lost_while_down"), 1.0) << st;
  EXPECT_EQ(number(st, "events_lost"), 0.0) << st;
  EXPECT_EQ(number(st, "measurements_accepted"), 1.0) << st;
  ASSERT_TRUE(wait_until([&] { return holding(nc, kRequest) == 1; })) << daemon.status();
  publish_tool_measurement(nc, 4, 8.0F);
  ASSERT_TRUE(wait_until([&] { return holding_i32(nc, kLength) == -80; }))
      << holding_i32(nc, kLength) << "\n"
      << daemon.status();
  const std::string log = daemon.log();
  EXPECT_NE(log.find("bus modbus: event counters resume from the state (tool_measurement #1)"),
            std::string::npos)
      << log;
  EXPECT_NE(log.find("bus modbus: 2 events of tool_measurement happened while nccompd was down "
                     "(counter #1 -> #3): the newest delivered, 1 lost"),
            std::string::npos)
      << log;

  // A clean restart with nothing published meanwhile delivers nothing: 8.0 µm stays.
  EXPECT_EQ(daemon.stop(), 0);
  daemon.start();
  ASSERT_TRUE(wait_until([&] {
    return daemon.log().find("no tool_measurement event while nccompd was down (counter #4)") !=
           std::string::npos;
  })) << daemon.log();
  std::this_thread::sleep_for(300ms);
  EXPECT_EQ(holding_i32(nc, kLength), -80);
  const std::string st2 = daemon.status();
  EXPECT_EQ(number(st2, "events_recovered_after_start"), 0.0) << st2;
  EXPECT_EQ(number(st2, "measurements_accepted"), 0.0) << st2;
  std::istringstream lines(daemon.log());
  for (std::string line; std::getline(lines, line);) {
    if (line.find("nccompd was down") != std::string::npos ||
        line.find("event counters") != std::string::npos) {
      std::printf("%s\n", line.c_str());
    }
  }
  EXPECT_EQ(daemon.stop(), 0);
  nc.stop();
}

TEST(NccompdEventsWhileDown, ARequestUpWhenTheDaemonStoppedIsRaisedAgainAsARisingEdge) {
  TempDir d;
  NcServer nc(ServerConfig{});
  nc.start();
  nc.update([](Tables& t) { t.input[8] = 1; });
  std::ofstream(d.path / "nccompd.toml") << config_text(nc.port());
  Daemon daemon(d.path);
  run_until_killed_with_the_request_up(nc, daemon);
  if (HasFatalFailure()) return;

  // Nothing published while it is down; the NC still holds the request at 1 (it may have sent
  // the tool to the laser already and lost its answer, or never react to a level).
  ASSERT_EQ(holding(nc, kRequest), 1);
  const std::size_t before = nc.writes().size();
  daemon.start();
  // The NC sees 0 and then 1: a rising edge.
  ASSERT_TRUE(wait_until([&] {
    const auto v = written(nc, before, kRequest);
    return v.size() >= 2;
  })) << daemon.log();
  const auto v = written(nc, before, kRequest);
  EXPECT_EQ(v[0], 0) << daemon.log();
  EXPECT_EQ(v[1], 1) << daemon.log();
  EXPECT_EQ(holding(nc, kRequest), 1);
  // The laser answers it: applied, the request falls.
  publish_tool_measurement(nc, 2, 6.0F);
  ASSERT_TRUE(wait_until([&] { return holding_i32(nc, kLength) == -60; }))
      << holding_i32(nc, kLength) << "\n"
      << daemon.status();
  ASSERT_TRUE(wait_until([&] { return holding(nc, kRequest) == 0; }, 2000ms)) << daemon.log();
  const std::string log = daemon.log();
  EXPECT_NE(log.find("creep: the measurement request was up when nccompd stopped and the NC still "
                     "holds it: it is lowered for 1 s and raised again, so that the NC sees a "
                     "rising edge"),
            std::string::npos)
      << log;
  EXPECT_NE(log.find("bus modbus: no tool_measurement event while nccompd was down (counter #1)"),
            std::string::npos)
      << log;
  EXPECT_EQ(daemon.stop(), 0);
  nc.stop();
}

}  // namespace
