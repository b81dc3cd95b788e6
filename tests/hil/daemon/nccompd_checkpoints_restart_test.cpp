// S1 restart agreement at the process level (docs/checkpoints.md, "Persistence and restart"):
// GIVEN the nccompd binary with a [checkpoints] table of 4 checkpoints (table only) on the
// project's Modbus NC server (sim/modbus_nc NcServer, 127.0.0.1, ephemeral port),
// WHEN the NC publishes a part start and 4 probe readings, then the next part start, THEN the
// learned offsets arrive in the NC's 4 holding registers in machining order;
// WHEN nccompd is killed (SIGKILL), an operator edits one checkpoint register on the NC and
// nccompd is started again, THEN it reads the table back before its bus starts, logs the
// mismatch (the reconcile line and warning 33), and
// - with reconcile_prefer = "daemon" writes the learned value back into that register;
// - with reconcile_prefer = "nc" leaves the operator's value in the NC, adopts it as the
//   checkpoint's offset, writes it as such at the next part start, and learns the next reading
//   against it.
// The registers' max_step_um (50) is above the operator's change (2 µm) in these two tests. The
// tests after them (NccompdReadBack) use max_step_um = 5 and max_rate_um_per_s = 50 with an
// operator's edit of +80.0 µm and an NC that lost its registers (all 0): every value the NC
// received after the restart is taken from the server's write log and checked: with "nc" the
// edit stays (no write to that register, 80.0 µm at every sample); with "daemon" the register
// slews from what the NC held, never more than max_step_um per write, and ends at the learned
// value.
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
#include <optional>
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

// Checkpoint i's register is logical register i, holding register 200 + 2i (int32, 0.1 µm).
constexpr std::uint16_t kTableAddress = 200;

std::string config_text(std::uint16_t port, const char* prefer, double max_step_um = 50.0,
                        double max_rate_um_per_s = 1000.0) {
  std::ostringstream s;
  s << "[daemon]\nrate_hz = 200\n"
    << "[state]\ndirectory = \"state\"\nmin_interval_s = 0.05\n"
    << "[measurement_log]\ndirectory = \"log\"\n"
    << "[status]\nsocket_path = \"status.sock\"\n"
    << "[modbus]\ntransport = \"tcp\"\nhost = \"127.0.0.1\"\nport = " << port << "\n"
    << "poll_rate_hz = 200\nresponse_timeout_s = 0.5\n"
    << "[modbus.axis]\n"
    << "x_mm = { table = \"input\", address = 0, type = \"int32\", scale = 0.0001 }\n"
    << "y_mm = { table = \"input\", address = 2, type = \"int32\", scale = 0.0001 }\n"
    << "z_mm = { table = \"input\", address = 4, type = \"int32\", scale = 0.0001 }\n"
    << "program_path_mm = { table = \"input\", address = 6, type = \"int32\", scale = 0.001 }\n"
    << "tool = { table = \"input\", address = 8, type = \"uint16\" }\n"
    << "[modbus.probe_measurement]\n"
    << "sequence = { table = \"input\", address = 110, type = \"uint16\" }\n"
    << "part = { table = \"input\", address = 111, type = \"uint16\" }\n"
    << "checkpoint = { table = \"input\", address = 112, type = \"uint16\" }\n"
    << "raw_deviation_um = { table = \"input\", address = 113, type = \"float32\" }\n"
    << "wall_angle_deg = { table = \"input\", address = 115, type = \"int16\", scale = 0.01 }\n"
    << "ball_radius_mm = { table = \"input\", address = 116, type = \"uint16\", scale = 0.001 }\n"
    << "[modbus.program_event]\n"
    << "sequence = { table = \"input\", address = 150, type = \"uint16\" }\n"
    << "kind = { table = \"input\", address = 151, type = \"uint16\" }\n"
    << "part = { table = \"input\", address = 152, type = \"uint32\" }\n";
  for (int i = 0; i < 4; ++i) {
    s << "[[modbus.offset]]\nregister_index = " << i << "\naddress = " << kTableAddress + 2 * i
      << "\ntype = \"int32\"\nscale = 0.1\n";
  }
  for (int i = 0; i < 4; ++i) {
    s << "[[registers]]\nname = \"D" << 20 + i << "_radius_wear\"\nkind = \"checkpoint\"\n"
      << "bus = \"modbus\"\nmax_abs_um = 200\nmax_step_um = " << max_step_um
      << "\nmax_rate_um_per_s = " << max_rate_um_per_s << "\n";
  }
  // An open straight wall probed at s = 25 and 75 mm on two levels: checkpoints 0..3, table only
  // (the NC program selects D20 + i itself), learned from the previous part.
  s << "[checkpoints]\ncontour = [[0.0, 0.0], [100.0, 0.0]]\nclosed = false\nmaterial = \"left\"\n"
    << "z_start_mm = -5.0\nz_end_mm = -25.0\ndepth_step_mm = 20.0\nwall_angle_deg = 2.0\n"
    << "extra_points_mm = [25.0, 75.0]\nball_radius_mm = 2.0\nregister_base = 0\n"
    << "reconcile_prefer = \"" << prefer << "\"\n";
  return s.str();
}

class Daemon : public nccomp::test::NccompdProcess {
 public:
  explicit Daemon(fs::path dir) : NccompdProcess(std::move(dir), NCCOMPD_BIN) {}
};

bool is(double v, double want) { return std::fabs(v - want) < 1e-9; }

std::int32_t holding_i32(NcServer& nc, std::uint16_t address) {
  const auto r = nc.holding(address, 2);
  return static_cast<std::int32_t>((std::uint32_t{r[0]} << 16) | r[1]);
}

std::int32_t table_counts(NcServer& nc, int checkpoint) {
  return holding_i32(nc, static_cast<std::uint16_t>(kTableAddress + 2 * checkpoint));
}

// An operator's edit on the NC while nccompd is down.
void set_table_counts(NcServer& nc, int checkpoint, std::int32_t counts) {
  const auto u = static_cast<std::uint32_t>(counts);
  const auto a = static_cast<std::size_t>(kTableAddress + 2 * checkpoint);
  nc.update([&](Tables& t) {
    t.holding[a] = static_cast<std::uint16_t>(u >> 16);
    t.holding[a + 1] = static_cast<std::uint16_t>(u & 0xFFFF);
  });
}

// The NC side of the event groups: values first, then the counter (the profile's rule).
class NcEvents {
 public:
  explicit NcEvents(NcServer& nc) : nc_(nc) {}
  void part_start(std::uint32_t part) {
    nc_.update([&](Tables& t) {
      t.input[151] = 0;  // kind 0 = part start
      t.input[152] = static_cast<std::uint16_t>(part >> 16);
      t.input[153] = static_cast<std::uint16_t>(part & 0xFFFF);
      t.input[150] = ++program_seq_;
    });
  }
  void probe(std::uint16_t part, std::uint16_t checkpoint, float raw_um) {
    nc_.update([&](Tables& t) {
      std::uint32_t bits = 0;
      std::memcpy(&bits, &raw_um, sizeof bits);
      t.input[111] = part;
      t.input[112] = checkpoint;
      t.input[113] = static_cast<std::uint16_t>(bits >> 16);
      t.input[114] = static_cast<std::uint16_t>(bits & 0xFFFF);
      t.input[115] = 200;   // α = 2.00°, the plan's
      t.input[116] = 2000;  // r = 2.000 mm
      t.input[110] = ++probe_seq_;
    });
  }

 private:
  NcServer& nc_;
  std::uint16_t program_seq_{0};
  std::uint16_t probe_seq_{0};
};

// Corrected deviations δ' [µm] found at the 4 checkpoints of part 1: the learned offsets are
// −δ' (mode A, first part cut without offsets): −6.0, 4.0, −8.0, −2.5 µm = −60, 40, −80, −25
// counts of 0.1 µm.
constexpr double kDeltaUm[4] = {6.0, -4.0, 8.0, 2.5};
constexpr std::int32_t kLearnedCounts[4] = {-60, 40, -80, -25};
// δ0 = r/cos α − r for r = 2 mm, α = 2°: the probe reports δ = δ' + δ0.
const double kDelta0Um = 2000.0 * (1.0 / std::cos(2.0 * M_PI / 180.0) - 1.0);

/// Runs nccompd on a fresh NC until it has learned part 1 and written the table at part 2's
/// start, then kills it with SIGKILL.
void learn_then_kill(const TempDir& d, NcServer& nc, NcEvents& ev, Daemon& daemon) {
  daemon.start();
  // The first poll takes the event counters as a baseline: wait for the bus to be up and polled.
  ASSERT_TRUE(wait_until([&] {
    const std::string s = daemon.status();
    return s.find("\"state\":\"up\"") != std::string::npos && number(s, "cycles") >= 20;
  })) << daemon.log();
  ev.part_start(1);
  ASSERT_TRUE(wait_until([&] { return is(number(daemon.status(), "part"), 1.0); })) << daemon.log();
  for (std::uint16_t i = 0; i < 4; ++i) {
    ev.probe(1, i, static_cast<float>(kDeltaUm[i] + kDelta0Um));
    // One reading per poll at most: wait until the daemon has taken this one.
    ASSERT_TRUE(wait_until([&] { return is(number(daemon.status(), "probe_readings"), i + 1.0); }))
        << daemon.log();
  }
  ASSERT_EQ(number(daemon.status(), "learned"), 4.0);
  ev.part_start(2);  // mode A: the learned table is written at the next part start
  ASSERT_TRUE(wait_until([&] {
    for (int i = 0; i < 4; ++i) {
      if (table_counts(nc, i) != kLearnedCounts[i]) return false;
    }
    return true;
  })) << daemon.log();
  // The state is persisted at most every 0.05 s: give the persister ten times that.
  std::this_thread::sleep_for(500ms);
  daemon.signal(SIGKILL);
  EXPECT_EQ(daemon.wait(), 128 + SIGKILL);
  ASSERT_TRUE(fs::exists(d.path / "state" / "state.bin"));
}

TEST(NccompdCheckpointsRestart, PreferDaemonRewritesTheRegisterAnOperatorChanged) {
  TempDir d;
  NcServer nc(ServerConfig{});
  nc.start();
  d.write("nccompd.toml", config_text(nc.port(), "daemon"));
  NcEvents ev(nc);
  {
    Daemon first(d.path);
    learn_then_kill(d, nc, ev, first);
    if (HasFatalFailure()) return;
  }
  // While nccompd is down, an operator changes checkpoint 2's register (D22) from the learned
  // −8.0 µm to −10.0 µm on the NC.
  set_table_counts(nc, 2, -100);
  ASSERT_EQ(table_counts(nc, 2), -100);
  Daemon second(d.path);
  second.start();
  // The learned −8.0 µm is written back; the other registers are rewritten with their values.
  ASSERT_TRUE(wait_until([&] { return table_counts(nc, 2) == kLearnedCounts[2]; })) << second.log();
  for (int i = 0; i < 4; ++i) EXPECT_EQ(table_counts(nc, i), kLearnedCounts[i]) << i;
  ASSERT_TRUE(wait_until([&] {
    return second.log().find("warning checkpoint_register_mismatch (code 33) subject 1") !=
           std::string::npos;
  })) << second.log();
  const std::string log = second.log();
  EXPECT_NE(log.find("state resumed from"), std::string::npos) << log;
  EXPECT_NE(log.find("checkpoints: 1 of 4 checkpoint registers differ from the table (max 2.000 "
                     "um); the table is written again (reconcile_prefer = \"daemon\")"),
            std::string::npos)
      << log;
  // The restarted daemon still has what it learned: 4 checkpoints, offsets −6 .. −2.5 µm.
  const std::string st = second.status();
  EXPECT_EQ(number(st, "learned"), 4.0) << st;
  EXPECT_NEAR(number(st, "learned_max_um"), 8.0, 1e-4) << st;
  second.signal(SIGTERM);
  EXPECT_EQ(second.wait(), 0) << second.log();
  nc.stop();
}

TEST(NccompdCheckpointsRestart, PreferNcAdoptsTheRegisterAnOperatorChanged) {
  TempDir d;
  NcServer nc(ServerConfig{});
  nc.start();
  d.write("nccompd.toml", config_text(nc.port(), "nc"));
  NcEvents ev(nc);
  {
    Daemon first(d.path);
    learn_then_kill(d, nc, ev, first);
    if (HasFatalFailure()) return;
  }
  set_table_counts(nc, 2, -100);  // D22: −8.0 → −10.0 µm by the operator
  Daemon second(d.path);
  second.start();
  ASSERT_TRUE(wait_until([&] {
    return second.log().find("warning checkpoint_register_mismatch (code 33) subject 1") !=
           std::string::npos;
  })) << second.log();
  EXPECT_NE(second.log().find("checkpoints: 1 of 4 checkpoint registers differ from the table "
                              "(max 2.000 um); the NC's values are adopted (reconcile_prefer = "
                              "\"nc\")"),
            std::string::npos)
      << second.log();
  // The operator's value stays in the NC: nothing is written over it after the start.
  for (int k = 0; k < 50; ++k) {
    ASSERT_EQ(table_counts(nc, 2), -100) << "after " << k * 20 << " ms\n" << second.log();
    std::this_thread::sleep_for(20ms);
  }
  // At the next part start the whole table is written: checkpoint 2 with the adopted −10.0 µm.
  ev.part_start(3);
  ASSERT_TRUE(wait_until([&] { return is(number(second.status(), "part"), 3.0); })) << second.log();
  std::this_thread::sleep_for(200ms);
  EXPECT_EQ(table_counts(nc, 0), kLearnedCounts[0]);
  EXPECT_EQ(table_counts(nc, 1), kLearnedCounts[1]);
  EXPECT_EQ(table_counts(nc, 2), -100);
  EXPECT_EQ(table_counts(nc, 3), kLearnedCounts[3]);
  // Part 3's reading at checkpoint 2 is learned against the −10.0 µm it was cut with: a wall
  // 1.5 µm too deep (δ' = −1.5) means the error without compensation was −1.5 + 10 = 8.5 µm;
  // ewma_weight 3 (default): M = 8 + (8.5 − 8)/3 = 8.1667, offset −8.1667 µm = −82 counts at
  // part 4.
  ev.probe(3, 2, static_cast<float>(-1.5 + kDelta0Um));
  ASSERT_TRUE(wait_until([&] { return is(number(second.status(), "probe_readings"), 1.0); }))
      << second.log();
  const std::string st = second.status();
  EXPECT_EQ(number(st, "checkpoint"), 2.0) << st;
  EXPECT_NEAR(number(st, "checkpoint_learned_um"), 8.0 + (8.5 - 8.0) / 3.0, 1e-3) << st;
  EXPECT_NEAR(number(st, "checkpoint_offset_um"), -(8.0 + (8.5 - 8.0) / 3.0), 1e-3) << st;
  // `nccomp status` (text): the module's line, as docs/checkpoints.md shows it.
  const std::string text = second.status("text");
  const auto at = text.find("module checkpoints:");
  ASSERT_NE(at, std::string::npos) << text;
  const std::string line = text.substr(at, text.find('\n', at) - at);
  std::printf("%s\n", line.c_str());
  EXPECT_NE(line.find("checkpoint 2, checkpoint_learned_um 8.16667, checkpoint_count 2, "
                      "checkpoint_offset_um -8.16667"),
            std::string::npos)
      << line;
  ev.part_start(4);
  EXPECT_TRUE(wait_until([&] { return table_counts(nc, 2) == -82; })) << table_counts(nc, 2);
  second.signal(SIGTERM);
  EXPECT_EQ(second.wait(), 0) << second.log();
  nc.stop();
}

// ---------------------------------------------------------------------------------------------
// Read-back at start-up (docs/daemon.md, "State and crashes"): the registers' limiters start from
// what the NC holds. max_step_um = 5, max_rate_um_per_s = 50: at 200 Hz the rate allows 0.25 µm
// per cycle, so even a few loop cycles the Modbus driver coalesces ("latest value wins") stay
// below max_step_um on the NC.

constexpr double kStepUm = 5.0;
constexpr double kRateUmPerS = 50.0;

/// The values (µm) the NC received in checkpoint register i's holding registers, from the
/// server's write log starting at entry `from`, in order.
std::vector<double> received_um(NcServer& nc, std::size_t from, int checkpoint) {
  const auto address = static_cast<std::uint16_t>(kTableAddress + 2 * checkpoint);
  std::vector<double> out;
  const auto log = nc.writes();
  for (std::size_t k = from; k < log.size(); ++k) {
    const auto& w = log[k];
    if (w.address != address || w.values.size() != 2) continue;
    const auto counts = static_cast<std::int32_t>((std::uint32_t{w.values[0]} << 16) | w.values[1]);
    out.push_back(0.1 * counts);
  }
  return out;
}

std::string joined(const std::vector<double>& v) {
  std::ostringstream s;
  for (double x : v) s << x << " ";
  return s.str();
}

/// Every step of `values` from `start_um` on is at most kStepUm; the last value is `end_um`.
void expect_slewed(const std::vector<double>& values, double start_um, double end_um,
                   const std::string& what) {
  ASSERT_FALSE(values.empty()) << what;
  double prev = start_um;
  double largest = 0.0;
  for (double v : values) {
    largest = std::max(largest, std::fabs(v - prev));
    prev = v;
  }
  EXPECT_LE(largest, kStepUm + 1e-9) << what << ": " << joined(values);
  EXPECT_NEAR(values.back(), end_um, 1e-9) << what << ": " << joined(values);
  std::printf("%s: %zu writes, %.1f -> %.1f um, largest step %.2f um\n", what.c_str(),
              values.size(), start_um, values.back(), largest);
}

TEST(NccompdReadBack, PreferNcKeepsAnEditLargerThanMaxStepAtEverySample) {
  TempDir d;
  NcServer nc(ServerConfig{});
  nc.start();
  d.write("nccompd.toml", config_text(nc.port(), "nc", kStepUm, kRateUmPerS));
  NcEvents ev(nc);
  {
    Daemon first(d.path);
    learn_then_kill(d, nc, ev, first);
    if (HasFatalFailure()) return;
  }
  // D22: learned −8.0 µm; the operator sets +80.0 µm (88 µm away, 17.6 × max_step_um).
  set_table_counts(nc, 2, 800);
  const std::size_t from = nc.writes().size();
  Daemon second(d.path);
  second.start();
  // Sampled every 5 ms from the start (before the bus is up) for 1.5 s: always 80.0 µm.
  for (int k = 0; k < 300; ++k) {
    ASSERT_EQ(table_counts(nc, 2), 800) << "after " << k * 5 << " ms\n" << second.log();
    std::this_thread::sleep_for(5ms);
  }
  ASSERT_TRUE(wait_until([&] {
    return second.log().find("warning checkpoint_register_mismatch (code 33) subject 1") !=
           std::string::npos;
  })) << second.log();
  const std::string log = second.log();
  EXPECT_NE(log.find("register 2 (D22_radius_wear): the NC holds 80.000 um, the state -8.000 um "
                     "(+88.000 um); the next writes start from the NC's value"),
            std::string::npos)
      << log;
  EXPECT_NE(log.find("registers: 4 of 4 read back from the NC, 1 differ from the state"),
            std::string::npos)
      << log;
  EXPECT_NE(log.find("checkpoints: 1 of 4 checkpoint registers differ from the table (max "
                     "88.000 um); the NC's values are adopted (reconcile_prefer = \"nc\")"),
            std::string::npos)
      << log;
  // At the next part start the table is written: D22 is the adopted 80.0 µm, which the NC
  // already holds; the others are at their learned values.
  ev.part_start(3);
  ASSERT_TRUE(wait_until([&] { return is(number(second.status(), "part"), 3.0); })) << second.log();
  for (int k = 0; k < 60; ++k) {
    ASSERT_EQ(table_counts(nc, 2), 800) << "after part start + " << k * 5 << " ms";
    std::this_thread::sleep_for(5ms);
  }
  // Every value the NC received in D22 since the restart: none moved it from 80.0 µm.
  for (double v : received_um(nc, from, 2)) EXPECT_NEAR(v, 80.0, 1e-9);
  std::printf("D22 after the restart: %zu writes, all 80.0 um\n", received_um(nc, from, 2).size());
  for (int i : {0, 1, 3}) EXPECT_EQ(table_counts(nc, i), kLearnedCounts[i]) << i;
  // The daemon shows what the NC holds and what it aims at: both the operator's value.
  const std::string st = second.status();
  EXPECT_NE(st.find("\"name\":\"D22_radius_wear\",\"output_um\":80,\"target_um\":80,"),
            std::string::npos)
      << st;
  second.signal(SIGTERM);
  EXPECT_EQ(second.wait(), 0) << second.log();
  nc.stop();
}

TEST(NccompdReadBack, PreferDaemonSlewsBackFromTheEditWithinTheLimits) {
  TempDir d;
  NcServer nc(ServerConfig{});
  nc.start();
  d.write("nccompd.toml", config_text(nc.port(), "daemon", kStepUm, kRateUmPerS));
  NcEvents ev(nc);
  {
    Daemon first(d.path);
    learn_then_kill(d, nc, ev, first);
    if (HasFatalFailure()) return;
  }
  set_table_counts(nc, 2, 800);  // +80.0 µm over the learned −8.0 µm
  const std::size_t from = nc.writes().size();
  Daemon second(d.path);
  const auto t0 = std::chrono::steady_clock::now();
  second.start();
  ASSERT_TRUE(wait_until([&] { return table_counts(nc, 2) == kLearnedCounts[2]; }, 20000ms))
      << table_counts(nc, 2) << "\n"
      << second.log();
  const double took_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  // 88 µm at 50 µm/s cannot take less than 1.76 s (the start-up before the first write only
  // adds to it).
  EXPECT_GE(took_s, 88.0 / kRateUmPerS) << took_s;
  const auto d22 = received_um(nc, from, 2);
  expect_slewed(d22, 80.0, -8.0, "D22 from the operator's +80.0 back to the learned -8.0");
  // The engine's writes are 0.25 µm apart (50 µm/s at 200 Hz): far more than the 18 writes of
  // a register that steps max_step_um each time.
  EXPECT_GT(d22.size(), 88U / 5U + 1U);
  EXPECT_LE(d22.front(), 80.0 - 0.1);      // the first write moves toward −8.0 ...
  EXPECT_GE(d22.front(), 80.0 - kStepUm);  // ... from the NC's value, not from −8.0
  const std::string log = second.log();
  EXPECT_NE(log.find("register 2 (D22_radius_wear): the NC holds 80.000 um, the state -8.000 um "
                     "(+88.000 um); the next writes start from the NC's value"),
            std::string::npos)
      << log;
  EXPECT_NE(log.find("the table is written again (reconcile_prefer = \"daemon\")"),
            std::string::npos)
      << log;
  for (int i = 0; i < 4; ++i) EXPECT_EQ(table_counts(nc, i), kLearnedCounts[i]) << i;
  second.signal(SIGTERM);
  EXPECT_EQ(second.wait(), 0) << second.log();
  nc.stop();
}

TEST(NccompdReadBack, AnNcThatLostItsRegistersGetsTheTableBackFromZeroWithinTheLimits) {
  TempDir d;
  NcServer nc(ServerConfig{});
  nc.start();
  d.write("nccompd.toml", config_text(nc.port(), "daemon", kStepUm, kRateUmPerS));
  NcEvents ev(nc);
  {
    Daemon first(d.path);
    learn_then_kill(d, nc, ev, first);
    if (HasFatalFailure()) return;
  }
  // The NC was power-cycled and came back with its offset registers at 0.
  for (int i = 0; i < 4; ++i) set_table_counts(nc, i, 0);
  const std::size_t from = nc.writes().size();
  Daemon second(d.path);
  second.start();
  ASSERT_TRUE(wait_until([&] {
    for (int i = 0; i < 4; ++i) {
      if (table_counts(nc, i) != kLearnedCounts[i]) return false;
    }
    return true;
  })) << second.log();
  for (int i = 0; i < 4; ++i) {
    expect_slewed(received_um(nc, from, i), 0.0, 0.1 * kLearnedCounts[i],
                  "checkpoint " + std::to_string(i) + " from 0");
  }
  EXPECT_NE(second.log().find("registers: 4 of 4 read back from the NC, 4 differ from the state"),
            std::string::npos)
      << second.log();
  second.signal(SIGTERM);
  EXPECT_EQ(second.wait(), 0) << second.log();
  nc.stop();
}

}  // namespace
