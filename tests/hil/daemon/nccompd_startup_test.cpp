// Start-up against an NC whose registers the daemon must not trust blindly (issue 17, findings 1
// and 2; docs/daemon.md, "Start-up: registers beyond the limits and modules without state"):
// the nccompd binary on the project's Modbus NC server (sim/modbus_nc NcServer, 127.0.0.1,
// ephemeral port) with its holding registers preset by the test, every value the NC received
// taken from the server's write log.
// - GIVEN the NC holds values beyond max_abs_um (the length wear register at int32 max, the
//   radius register at 250 µm with max_abs_um 200, an axis register at 1e30 as float32), WHEN
//   nccompd starts, THEN it writes nothing to them (not even inward) for 1.5 s of running,
//   raises alarm register_beyond_limit (60) for each and shows them held in status; WHEN the
//   operator releases one (`register release NAME` on the status socket), THEN the daemon's
//   value is written in one move, and no value beyond max_abs_um ever reaches the NC.
// - GIVEN the NC holds -33.0 µm of length wear, WHEN nccompd starts without usable state for
//   its creep module - no state file (a retrofit), a corrupt file that was removed, a state
//   with a valid checksum whose creep entry cannot be read, a creep module added to the config
//   since the state was written - THEN the register keeps -33.0 µm (no write moves it) and the
//   log names the register, the module and why (notice register_adopted, 61); the next
//   measurement (40 µm) creeps from -33.0 to -40.0 µm, never toward 0.
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
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "client/status_client.hpp"
#include "daemon/state_store.hpp"
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

// Holding addresses of the three offset registers.
constexpr std::uint16_t kLength = 200;  // int32, 0.1 µm per count, max_abs_um 200
constexpr std::uint16_t kRadius = 202;  // int32, 0.1 µm per count, max_abs_um 200
constexpr std::uint16_t kAxisX = 204;   // float32, µm, max_abs_um 100

struct Modules {
  bool creep{true};
  bool ramp_on_radius{false};  // a module on the radius register (the "before" of a config change)
};

std::string config_text(std::uint16_t port, const Modules& s) {
  std::ostringstream o;
  o << "[daemon]\nrate_hz = 200\n"
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
    << "[[modbus.offset]]\nregister_index = 0\naddress = " << kLength
    << "\ntype = \"int32\"\nscale = 0.1\n"
    << "[[modbus.offset]]\nregister_index = 1\naddress = " << kRadius
    << "\ntype = \"int32\"\nscale = 0.1\n"
    << "[[modbus.offset]]\nregister_index = 2\naddress = " << kAxisX
    << "\ntype = \"float32\"\nscale = 1.0\n"
    << "[[registers]]\nname = \"T1_length_wear\"\nkind = \"tool_length_wear\"\nbus = \"modbus\"\n"
    << "max_abs_um = 200\nmax_step_um = 5\nmax_rate_um_per_s = 50\n"
    << "[[registers]]\nname = \"T1_radius_wear\"\nkind = \"tool_radius_wear\"\nbus = \"modbus\"\n"
    << "max_abs_um = 200\nmax_step_um = 5\nmax_rate_um_per_s = 50\n"
    << "[[registers]]\nname = \"X_axis_offset\"\nkind = \"axis_offset\"\nbus = \"modbus\"\n"
    << "max_abs_um = 100\nmax_step_um = 5\nmax_rate_um_per_s = 20\n"
    // A commissioning ramp on the axis register: 5 µm at 100 µm/s.
    << "[[ramp]]\nname = \"x_ramp\"\nregister = \"X_axis_offset\"\ntarget_um = 5.0\n"
    << "rate_um_per_s = 100\n";
  if (s.ramp_on_radius) {
    o << "[[ramp]]\nname = \"r_ramp\"\nregister = \"T1_radius_wear\"\ntarget_um = 0.0\n"
      << "rate_um_per_s = 100\n";
  }
  if (s.creep) {
    // Time-based linear creep of the whole measured wear (tip tool, no normals) into the length
    // register; the radius register is the creep's too (0 without a lateral deflection).
    o << "[creep]\ncreep_basis = \"time\"\ncreep_time_s = 2.0\nprofile = \"linear\"\n"
      << "[creep.edge]\ntool_shape = \"tip\"\nnormal_source = \"none\"\n"
      << "fallback_channel = \"length\"\n"
      << "[creep.tool_life]\nexcessive_increment_um = 15.0\n"
      << "[creep.output]\nmode = \"tool_registers\"\nlength_register = \"T1_length_wear\"\n"
      << (s.ramp_on_radius ? "" : "radius_register = \"T1_radius_wear\"\n");
  }
  return o.str();
}

class Daemon : public nccomp::test::NccompdProcess {
 public:
  explicit Daemon(fs::path dir) : NccompdProcess(std::move(dir), NCCOMPD_BIN) {}
};

void set_i32(std::span<std::uint16_t> regs, std::size_t at, std::int32_t v) {
  const auto u = static_cast<std::uint32_t>(v);
  regs[at] = static_cast<std::uint16_t>(u >> 16);
  regs[at + 1] = static_cast<std::uint16_t>(u & 0xFFFF);
}

void set_f32(std::span<std::uint16_t> regs, std::size_t at, float v) {
  std::uint32_t u = 0;
  std::memcpy(&u, &v, sizeof u);
  regs[at] = static_cast<std::uint16_t>(u >> 16);
  regs[at + 1] = static_cast<std::uint16_t>(u & 0xFFFF);
}

std::int32_t holding_i32(NcServer& nc, std::uint16_t address) {
  const auto r = nc.holding(address, 2);
  return static_cast<std::int32_t>((std::uint32_t{r[0]} << 16) | r[1]);
}

/// The values [µm] the NC received at an address since write-log entry `from`, in order.
std::vector<double> received_um(NcServer& nc, std::size_t from, std::uint16_t address) {
  std::vector<double> out;
  const auto log = nc.writes();
  for (std::size_t k = from; k < log.size(); ++k) {
    const auto& w = log[k];
    if (w.address != address || w.values.size() != 2) continue;
    const std::uint32_t u = (std::uint32_t{w.values[0]} << 16) | w.values[1];
    if (address == kAxisX) {
      float f = 0.0F;
      std::memcpy(&f, &u, sizeof f);
      out.push_back(static_cast<double>(f));
    } else {
      out.push_back(0.1 * static_cast<std::int32_t>(u));
    }
  }
  return out;
}

std::string joined(const std::vector<double>& v) {
  std::ostringstream s;
  for (double x : v) s << x << " ";
  return s.str();
}

void publish_tool_measurement(NcServer& nc, std::uint16_t seq, std::uint16_t tool, float wear_um) {
  nc.update([&](Tables& t) {
    set_f32(t.input, 102, wear_um);
    t.input[101] = tool;
    t.input[100] = seq;  // the counter last: values first, then the event (the profile's rule)
  });
}

/// Waits until the daemon runs with its bus up and has seen the NC's axis sample.
void wait_running(const Daemon& d) {
  ASSERT_TRUE(wait_until([&] {
    const std::string s = d.status();
    return s.find("\"state\":\"up\"") != std::string::npos && number(s, "events_accepted") >= 1 &&
           number(s, "cycles") >= 40;
  })) << d.log();
}

/// The NC's machine: X = 10 mm, tool 1 in the spindle.
void machine(NcServer& nc) {
  nc.update([](Tables& t) {
    set_i32(t.input, 0, 100000);
    t.input[8] = 1;
  });
}

// ---------------------------------------------------------------------------------------------
// Finding 1: registers beyond max_abs_um at start-up.

TEST(NccompdStartup, RegistersBeyondMaxAbsAreNeverWrittenUntilReleasedAndNeverBeyondTheLimit) {
  TempDir d;
  NcServer nc(ServerConfig{});
  nc.start();
  machine(nc);
  nc.update([](Tables& t) {
    set_i32(t.holding, kLength, std::numeric_limits<std::int32_t>::max());  // 214748364.7 µm
    set_i32(t.holding, kRadius, 2500);                                      // 250.0 µm
    set_f32(t.holding, kAxisX, 1e30F);
  });
  d.write("nccompd.toml", config_text(nc.port(), Modules{}));
  Daemon daemon(d.path);
  daemon.start();
  wait_running(daemon);
  if (HasFatalFailure()) return;
  // 1.5 s more of running: nothing at all reaches the three registers.
  std::this_thread::sleep_for(1500ms);
  EXPECT_TRUE(received_um(nc, 0, kLength).empty()) << joined(received_um(nc, 0, kLength));
  EXPECT_TRUE(received_um(nc, 0, kRadius).empty()) << joined(received_um(nc, 0, kRadius));
  EXPECT_TRUE(received_um(nc, 0, kAxisX).empty()) << joined(received_um(nc, 0, kAxisX));
  EXPECT_EQ(holding_i32(nc, kLength), std::numeric_limits<std::int32_t>::max());
  EXPECT_EQ(holding_i32(nc, kRadius), 2500);
  const std::string log = daemon.log();
  EXPECT_NE(log.find("register 0 (T1_length_wear): the NC holds 214748364.700 um, beyond "
                     "max_abs_um 200.000: nothing is written to it"),
            std::string::npos)
      << log;
  EXPECT_NE(log.find("register 1 (T1_radius_wear): the NC holds 250.000 um, beyond max_abs_um "
                     "200.000"),
            std::string::npos)
      << log;
  EXPECT_NE(log.find("register 2 (X_axis_offset): the NC holds 1000000015047466219876688855040."
                     "000 um, beyond max_abs_um 100.000"),
            std::string::npos)
      << log;
  for (int i = 0; i < 3; ++i) {
    EXPECT_NE(log.find("error alarm register_beyond_limit (code 60) subject " + std::to_string(i)),
              std::string::npos)
        << i << "\n"
        << log;
  }
  EXPECT_NE(log.find("3 beyond max_abs_um (held)"), std::string::npos) << log;
  const std::string st = daemon.status();
  EXPECT_NE(st.find("\"name\":\"T1_radius_wear\",\"output_um\":250,"), std::string::npos) << st;
  EXPECT_NE(st.find("\"hold\":\"beyond_limit\"}"), std::string::npos) << st;
  const std::string text = daemon.status("text");
  EXPECT_NE(text.find("T1_radius_wear"), std::string::npos);
  EXPECT_NE(text.find("BLOCKED: the NC holds a value beyond max_abs_um"), std::string::npos)
      << text;
  const auto regs_at = text.find("registers:");
  std::printf("%s", text.substr(regs_at, text.find("buses:") - regs_at).c_str());

  // The operator releases the radius register: the creep module's value (0 without wear) is
  // written in one move; the other two stay untouched.
  const std::string answer = daemon.status("register release T1_radius_wear");
  EXPECT_EQ(answer.rfind("ok released 1 register(s)", 0), 0U) << answer;
  EXPECT_NE(answer.find("T1_radius_wear (1): was held beyond max_abs_um (the NC holds 250.000 "
                        "um); 0.000 um is written in one move"),
            std::string::npos)
      << answer;
  ASSERT_TRUE(wait_until([&] { return holding_i32(nc, kRadius) == 0; })) << daemon.log();
  std::this_thread::sleep_for(300ms);
  const auto radius = received_um(nc, 0, kRadius);
  ASSERT_FALSE(radius.empty());
  for (double v : radius) EXPECT_NEAR(v, 0.0, 1e-9) << joined(radius);
  EXPECT_TRUE(received_um(nc, 0, kLength).empty());
  EXPECT_TRUE(received_um(nc, 0, kAxisX).empty());
  EXPECT_NE(daemon.log().find("operator command #1: register release T1_radius_wear: 1 "
                              "register(s) released"),
            std::string::npos)
      << daemon.log();
  // Nothing left to release there; an unknown register is refused.
  EXPECT_EQ(daemon.status("register release T1_radius_wear")
                .rfind("ok register release T1_radius_wear: nothing is held", 0),
            0U);
  EXPECT_EQ(daemon.status("register release T9")
                .rfind("error: register release: no register "
                       "named 'T9' in [[registers]]",
                       0),
            0U);
  // All: the length register gets the creep's 0, the axis register the ramp's 5 µm; with the
  // operator's command where it is built (not under TSan).
#ifdef NCCOMP_BIN
  {
    const std::string cmd = std::string(NCCOMP_BIN) + " register release all -s " +
                            (d.path / "status.sock").string() + " 2>&1";
    FILE* p = ::popen(cmd.c_str(), "r");
    ASSERT_NE(p, nullptr);
    std::string out;
    char buf[256];
    while (std::fgets(buf, sizeof buf, p) != nullptr) out += buf;
    EXPECT_EQ(::pclose(p), 0) << out;
    std::printf("$ nccomp register release all -s ...\n%s", out.c_str());
    EXPECT_EQ(out.rfind("ok released 2 register(s)", 0), 0U) << out;
    EXPECT_NE(out.find("X_axis_offset (2): was held beyond max_abs_um"), std::string::npos) << out;
  }
#else
  EXPECT_EQ(daemon.status("register release all").rfind("ok released 2 register(s)", 0), 0U);
#endif
  ASSERT_TRUE(wait_until([&] {
    return holding_i32(nc, kLength) == 0 && !received_um(nc, 0, kAxisX).empty() &&
           std::fabs(received_um(nc, 0, kAxisX).back() - 5.0) < 1e-6;
  })) << daemon.log();
  daemon.signal(SIGTERM);
  EXPECT_EQ(daemon.wait(), 0) << daemon.log();
  nc.stop();
  // Every value the NC ever received lies within its register's max_abs_um.
  for (double v : received_um(nc, 0, kLength)) EXPECT_LE(std::fabs(v), 200.0);
  for (double v : received_um(nc, 0, kRadius)) EXPECT_LE(std::fabs(v), 200.0);
  for (double v : received_um(nc, 0, kAxisX)) EXPECT_LE(std::fabs(v), 100.0);
  std::printf("after release: length %zu writes, radius %zu, X %zu (X: %s)\n",
              received_um(nc, 0, kLength).size(), received_um(nc, 0, kRadius).size(),
              received_um(nc, 0, kAxisX).size(), joined(received_um(nc, 0, kAxisX)).c_str());
}

// A register held beyond the limit stays held over a restart that cannot correct it: the state
// keeps what the NC holds, and the read-back finds it again.
TEST(NccompdStartup, ARegisterBeyondTheLimitStaysHeldOverARestart) {
  TempDir d;
  NcServer nc(ServerConfig{});
  nc.start();
  machine(nc);
  nc.update([](Tables& t) { set_i32(t.holding, kRadius, 2500); });
  d.write("nccompd.toml", config_text(nc.port(), Modules{}));
  for (int run = 0; run < 2; ++run) {
    Daemon daemon(d.path);
    daemon.start();
    wait_running(daemon);
    if (HasFatalFailure()) return;
    std::this_thread::sleep_for(500ms);
    daemon.signal(SIGTERM);
    EXPECT_EQ(daemon.wait(), 0) << daemon.log();
  }
  EXPECT_TRUE(received_um(nc, 0, kRadius).empty()) << joined(received_um(nc, 0, kRadius));
  EXPECT_EQ(holding_i32(nc, kRadius), 2500);
  nc.stop();
}

// ---------------------------------------------------------------------------------------------
// Finding 2: a start without usable module state.

constexpr std::int32_t kHeldCounts = -330;  // -33.0 µm of length wear on the NC

void preset_wear(NcServer& nc) {
  nc.update([](Tables& t) { set_i32(t.holding, kLength, kHeldCounts); });
}

/// Starts nccompd, runs it 1.5 s (sampling the length register every 5 ms: always -33.0 µm) and
/// checks that no value other than -33.0 µm reached it. Returns the log.
std::string expect_register_kept(const TempDir& d, NcServer& nc, Daemon& daemon,
                                 const std::string& why) {
  const std::size_t from = nc.writes().size();
  daemon.start();
  for (int k = 0; k < 100; ++k) {  // from before the bus is up
    EXPECT_EQ(holding_i32(nc, kLength), kHeldCounts) << why << ": after " << k * 5 << " ms";
    std::this_thread::sleep_for(5ms);
  }
  wait_running(daemon);
  for (int k = 0; k < 300; ++k) {
    EXPECT_EQ(holding_i32(nc, kLength), kHeldCounts) << why << ": running, " << k * 5 << " ms";
    std::this_thread::sleep_for(5ms);
  }
  for (double v : received_um(nc, from, kLength)) EXPECT_NEAR(v, -33.0, 1e-9) << why;
  std::printf("%s: %zu writes to the length register, all -33.0 um\n", why.c_str(),
              received_um(nc, from, kLength).size());
  const std::string log = daemon.log();
  EXPECT_NE(log.find("warning register_adopted (code 61) subject 0 value -33"), std::string::npos)
      << why << "\n"
      << log;
  (void)d;
  return log;
}

/// The next measurement creeps from what the NC held: every value between -33.0 and -40.0 µm,
/// never moving back, ending at -40.0 µm.
void expect_creep_from_held(NcServer& nc, Daemon& daemon, std::uint16_t seq) {
  const std::size_t from = nc.writes().size();
  publish_tool_measurement(nc, seq, 1, 40.0F);
  ASSERT_TRUE(wait_until([&] { return holding_i32(nc, kLength) == -400; }, 15000ms))
      << holding_i32(nc, kLength) << "\n"
      << daemon.log();
  const auto w = received_um(nc, from, kLength);
  ASSERT_FALSE(w.empty());
  double prev = -33.0;
  for (double v : w) {
    EXPECT_LE(v, prev + 1e-9) << joined(w);
    EXPECT_GE(v, -40.0 - 1e-9) << joined(w);
    prev = v;
  }
  // A creep, not a step: many small writes (2 s at 200 Hz, 0.1 µm resolution).
  EXPECT_GE(w.size(), 20U) << joined(w);
  std::printf("next measurement: %zu writes from %.1f to %.1f um\n", w.size(), w.front(), w.back());
  EXPECT_EQ(daemon.log().find("tool_excessively_worn"), std::string::npos) << daemon.log();
}

TEST(NccompdStartup, WithoutAStateFileTheNcsWearIsAdoptedAndTheNextMeasurementCreepsFromIt) {
  TempDir d;
  NcServer nc(ServerConfig{});
  nc.start();
  machine(nc);
  preset_wear(nc);
  d.write("nccompd.toml", config_text(nc.port(), Modules{}));
  Daemon daemon(d.path);
  const std::string log = expect_register_kept(d, nc, daemon, "no state file");
  EXPECT_NE(log.find("register 0 (T1_length_wear): module creep has no usable state (no state "
                     "file); the NC's -33.000 um is its starting point: nothing is written to the "
                     "register until a new measurement"),
            std::string::npos)
      << log;
  EXPECT_NE(log.find("0 beyond max_abs_um (held), 3 adopted without state, 0 held without state"),
            std::string::npos)
      << log;
  // The creep module took the NC's compensation as the wear in force (33 µm, the sign of the
  // tool registers is -1).
  const std::string st = daemon.status();
  EXPECT_DOUBLE_EQ(number(st, "wear_in_force_um"), 33.0) << st;
  // The next laser measurement, 40 µm: an increment of 7 µm from the adopted 33, crept in.
  expect_creep_from_held(nc, daemon, 1);
  daemon.signal(SIGTERM);
  EXPECT_EQ(daemon.wait(), 0) << daemon.log();
  nc.stop();
}

TEST(NccompdStartup, ACorruptStateFileThatWasRemovedLeavesTheNcsWear) {
  TempDir d;
  NcServer nc(ServerConfig{});
  nc.start();
  machine(nc);
  preset_wear(nc);
  d.write("nccompd.toml", config_text(nc.port(), Modules{}));
  fs::create_directories(d.path / "state");
  d.write("state/state.bin", "NCCOMPST this is not a state file");
  {
    Daemon corrupt(d.path);
    corrupt.start();
    ASSERT_TRUE(wait_until([&] {
      return corrupt.log().find("error alarm state_corrupt (code 50)") != std::string::npos;
    })) << corrupt.log();
    corrupt.signal(SIGTERM);
    EXPECT_EQ(corrupt.wait(), 0) << corrupt.log();
  }
  EXPECT_TRUE(received_um(nc, 0, kLength).empty());
  // The docs' advice: remove the file and restart.
  fs::remove(d.path / "state" / "state.bin");
  Daemon daemon(d.path);
  const std::string log = expect_register_kept(d, nc, daemon, "corrupt file removed");
  EXPECT_NE(log.rfind("module creep has no usable state (no state file)"), std::string::npos)
      << log;
  daemon.signal(SIGTERM);
  EXPECT_EQ(daemon.wait(), 0) << daemon.log();
  nc.stop();
}

/// The blob of module `name` in an engine state payload (docs: core/engine/engine.cpp, the
/// state bytes): its offset in the payload and its length.
std::pair<std::size_t, std::size_t> module_entry(const std::vector<std::byte>& p,
                                                 const std::string& name) {
  std::size_t at = 0;
  const auto get = [&](auto& v) {
    std::memcpy(&v, p.data() + at, sizeof v);
    at += sizeof v;
  };
  const auto get_name = [&] {
    std::uint16_t n = 0;
    get(n);
    std::string s(reinterpret_cast<const char*>(p.data() + at), n);
    at += n;
    return s;
  };
  std::uint32_t magic = 0;
  std::uint32_t version = 0;
  std::uint32_t nregs = 0;
  get(magic);
  get(version);
  get(nregs);
  for (std::uint32_t k = 0; k < nregs; ++k) {
    (void)get_name();
    at += 2 * sizeof(double) + 1;
  }
  std::uint32_t nmods = 0;
  get(nmods);
  for (std::uint32_t k = 0; k < nmods; ++k) {
    const std::string n = get_name();
    std::uint32_t len = 0;
    get(len);
    if (n == name) return {at, len};
    at += len;
  }
  return {0, 0};
}

TEST(NccompdStartup, AValidStateWhoseCreepEntryCannotBeReadLeavesTheNcsWear) {
  TempDir d;
  NcServer nc(ServerConfig{});
  nc.start();
  machine(nc);
  d.write("nccompd.toml", config_text(nc.port(), Modules{}));
  {
    // A first run on a fresh NC: a measurement of 10 µm creeps in; stopped cleanly.
    Daemon first(d.path);
    first.start();
    wait_running(first);
    if (HasFatalFailure()) return;
    publish_tool_measurement(nc, 1, 1, 10.0F);
    ASSERT_TRUE(wait_until([&] { return holding_i32(nc, kLength) == -100; })) << first.log();
    first.signal(SIGTERM);
    ASSERT_EQ(first.wait(), 0) << first.log();
  }
  // The creep entry's first bytes (its layout version) made unreadable, the checksum valid.
  const std::string path = (d.path / "state" / "state.bin").string();
  auto sf = nccomp::daemon::read_state_file(path);
  ASSERT_EQ(sf.status, nccomp::daemon::StateFileStatus::kOk);
  const auto [at, len] = module_entry(sf.payload, "creep");
  ASSERT_GT(len, 4U);
  sf.payload[at] = std::byte{0x7F};
  sf.payload[at + 1] = std::byte{0x7F};
  nccomp::daemon::write_state_file(path, sf.payload, sf.sequence + 1);
  // The NC holds -33.0 µm (another compensation in force than the state's -10.0 µm).
  preset_wear(nc);
  Daemon daemon(d.path);
  const std::string log = expect_register_kept(d, nc, daemon, "creep entry unreadable");
  EXPECT_NE(log.find("1 unknown entries skipped"), std::string::npos) << log;
  EXPECT_NE(log.find("register 0 (T1_length_wear): module creep has no usable state (its entry "
                     "in the state file could not be read); the NC's -33.000 um is its starting "
                     "point"),
            std::string::npos)
      << log;
  expect_creep_from_held(nc, daemon, 2);
  daemon.signal(SIGTERM);
  EXPECT_EQ(daemon.wait(), 0) << daemon.log();
  nc.stop();
}

TEST(NccompdStartup, ACreepModuleAddedSinceTheStateWasWrittenLeavesTheNcsWear) {
  TempDir d;
  NcServer nc(ServerConfig{});
  nc.start();
  machine(nc);
  // Before: registers and ramps only (no [creep]).
  d.write("nccompd.toml", config_text(nc.port(), Modules{false, true}));
  {
    Daemon first(d.path);
    first.start();
    wait_running(first);
    if (HasFatalFailure()) return;
    std::this_thread::sleep_for(300ms);
    first.signal(SIGTERM);
    ASSERT_EQ(first.wait(), 0) << first.log();
  }
  ASSERT_TRUE(fs::exists(d.path / "state" / "state.bin"));
  // The NC's length wear was set by hand (or by the machine's own cycle); then [creep] is added.
  preset_wear(nc);
  d.write("nccompd.toml", config_text(nc.port(), Modules{true, true}));
  Daemon daemon(d.path);
  const std::string log = expect_register_kept(d, nc, daemon, "creep added to the config");
  EXPECT_NE(log.find("state resumed from"), std::string::npos) << log;
  EXPECT_NE(log.find("register 0 (T1_length_wear): module creep has no usable state (it is not in "
                     "the state file: added to the configuration since)"),
            std::string::npos)
      << log;
  daemon.signal(SIGTERM);
  EXPECT_EQ(daemon.wait(), 0) << daemon.log();
  // Restarted before any measurement, with the state the adoption wrote: still -33.0 µm.
  Daemon again(d.path);
  const std::size_t from = nc.writes().size();
  again.start();
  wait_running(again);
  std::this_thread::sleep_for(500ms);
  EXPECT_EQ(holding_i32(nc, kLength), kHeldCounts);
  for (double v : received_um(nc, from, kLength)) EXPECT_NEAR(v, -33.0, 1e-9);
  again.signal(SIGTERM);
  EXPECT_EQ(again.wait(), 0) << again.log();
  nc.stop();
}

// The Modbus NC does not answer at start-up (it comes up later): the daemon knows nothing of
// what it holds, so the registers of its modules without state are held, not zeroed: nothing is
// written when the NC comes up; a restart that reads the NC then adopts its value.
TEST(NccompdStartup, AnNcThatDidNotAnswerAtStartUpIsNotWrittenAndARestartAdoptsItsValue) {
  TempDir d;
  std::uint16_t port = 0;
  {
    NcServer probe(ServerConfig{});
    probe.start();
    port = probe.port();
    probe.stop();
  }
  d.write("nccompd.toml", config_text(port, Modules{}));
  Daemon daemon(d.path);
  daemon.start();
  ASSERT_TRUE(wait_until([&] { return daemon.log().find("loop running") != std::string::npos; }))
      << daemon.log();
  ServerConfig sc;
  sc.port = port;
  NcServer nc(sc);
  nc.start();
  machine(nc);
  preset_wear(nc);
  wait_running(daemon);
  if (HasFatalFailure()) return;
  std::this_thread::sleep_for(1000ms);
  EXPECT_TRUE(received_um(nc, 0, kLength).empty()) << joined(received_um(nc, 0, kLength));
  EXPECT_EQ(holding_i32(nc, kLength), kHeldCounts);
  const std::string log = daemon.log();
  EXPECT_NE(log.find("register 0 (T1_length_wear): module creep has no usable state (no state "
                     "file) and the NC did not answer the read-back: nothing is written to it "
                     "(alarm register_held_without_state, code 62) until `nccomp register "
                     "release T1_length_wear`"),
            std::string::npos)
      << log;
  EXPECT_NE(log.find("warning register_held_without_state (code 62) subject 0 value nan"),
            std::string::npos)
      << log;
  EXPECT_NE(daemon.status().find("\"hold\":\"without_state\""), std::string::npos);
  // The operator restarts nccompd now that the NC answers: the module adopts its -33.0 µm.
  daemon.signal(SIGTERM);
  EXPECT_EQ(daemon.wait(), 0) << daemon.log();
  Daemon again(d.path);
  again.start();
  wait_running(again);
  if (HasFatalFailure()) return;
  std::this_thread::sleep_for(1000ms);
  EXPECT_TRUE(received_um(nc, 0, kLength).empty()) << joined(received_um(nc, 0, kLength));
  EXPECT_EQ(holding_i32(nc, kLength), kHeldCounts);
  EXPECT_NE(again.log().find("module creep has no usable state (the register is held without "
                             "state since an earlier start); the NC's -33.000 um is its starting "
                             "point"),
            std::string::npos)
      << again.log();
  EXPECT_EQ(again.status().find("\"hold\":\"without_state\""), std::string::npos);
  again.signal(SIGTERM);
  EXPECT_EQ(again.wait(), 0) << again.log();
  nc.stop();
}

}  // namespace
