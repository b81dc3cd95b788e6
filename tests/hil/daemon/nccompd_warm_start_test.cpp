// The warm-start operator command end to end (docs/daemon.md, "Warm start"):
// GIVEN the nccompd binary on the project's Modbus NC server (127.0.0.1, ephemeral port) with a
// [measurement_context] (warm_start_idle_s = 3600) and the NC publishing axis positions,
// WHEN the axes first move, THEN that is a warm start by the idle rule (warm_starts 1);
// WHEN the operator runs `nccomp warm-start` (the real nccomp binary) a while later, THEN the
// daemon answers "ok warm start now ...", the machine time restarts at 0 and warm_starts is 2;
// WHEN `nccomp warm-start --at-next-motion`, THEN the machine is cold and the next axis motion is
// warm start 3; a malformed request on the socket is refused with the reason and counted, an
// unknown option is a usage error, and without a daemon the command fails with exit status 1;
// WHEN nccompd restarts (SIGTERM, start), THEN the declared origin and the count are kept.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
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

std::string config_text(std::uint16_t port) {
  std::ostringstream s;
  s << "[daemon]\nrate_hz = 200\n"
    << "[state]\ndirectory = \"state\"\nmin_interval_s = 0.05\n"
    << "[measurement_log]\ndirectory = \"log\"\n"
    << "[status]\nsocket_path = \"status.sock\"\n"
    << "[measurement_context]\nwarm_start_idle_s = 3600\n"
    << "[modbus]\ntransport = \"tcp\"\nhost = \"127.0.0.1\"\nport = " << port << "\n"
    << "poll_rate_hz = 200\nresponse_timeout_s = 0.5\n"
    << "[modbus.axis]\n"
    << "x_mm = { table = \"input\", address = 0, type = \"int32\", scale = 0.0001 }\n"
    << "y_mm = { table = \"input\", address = 2, type = \"int32\", scale = 0.0001 }\n"
    << "z_mm = { table = \"input\", address = 4, type = \"int32\", scale = 0.0001 }\n"
    << "tool = { table = \"input\", address = 8, type = \"uint16\" }\n"
    << "[[modbus.offset]]\nregister_index = 0\naddress = 200\ntype = \"int32\"\nscale = 0.1\n"
    << "[[registers]]\nname = \"T1_length_wear\"\nkind = \"tool_length_wear\"\nbus = \"modbus\"\n"
    << "max_abs_um = 200\nmax_step_um = 5\nmax_rate_um_per_s = 50\n";
  return s.str();
}

[[maybe_unused]] std::string slurp(const fs::path& p) {
  std::ifstream in(p);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

[[maybe_unused]] pid_t spawn(const std::vector<std::string>& args, const fs::path& out,
                             const fs::path& err, bool append) {
  std::vector<std::string> a = args;
  std::vector<char*> argv;
  for (auto& s : a) argv.push_back(s.data());
  argv.push_back(nullptr);
  posix_spawn_file_actions_t fa;
  posix_spawn_file_actions_init(&fa);
  const int flags = O_WRONLY | O_CREAT | (append ? O_APPEND : O_TRUNC);
  posix_spawn_file_actions_addopen(&fa, 1, out.c_str(), flags, 0644);
  posix_spawn_file_actions_addopen(&fa, 2, err.c_str(), flags, 0644);
  pid_t pid = -1;
  EXPECT_EQ(posix_spawn(&pid, argv[0], &fa, nullptr, argv.data(), environ), 0);
  posix_spawn_file_actions_destroy(&fa);
  return pid;
}

[[maybe_unused]] int wait_exit(pid_t pid) {
  int st = 0;
  ::waitpid(pid, &st, 0);
  return WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
}

struct CliRun {
  int exit_code{-1};
  std::string out;
  std::string err;
};

#ifdef NCCOMP_BIN
CliRun nccomp(const TempDir& d, const std::vector<std::string>& args) {
  std::vector<std::string> a{NCCOMP_BIN};
  a.insert(a.end(), args.begin(), args.end());
  CliRun r;
  r.exit_code = wait_exit(spawn(a, d.path / "cli.out", d.path / "cli.err", false));
  r.out = slurp(d.path / "cli.out");
  r.err = slurp(d.path / "cli.err");
  return r;
}
#else
// The ThreadSanitizer build has no `nccomp` binary: the same request lines go to the socket
// directly (what `nccomp warm-start [--at-next-motion]` sends), the daemon under TSan.
CliRun nccomp(const TempDir& d, const std::vector<std::string>& args) {
  bool next_motion = false;
  for (const auto& a : args) next_motion = next_motion || a == "--at-next-motion";
  CliRun r;
  r.out = nccomp::client::query((d.path / "status.sock").string(),
                                next_motion ? "warm-start at-next-motion" : "warm-start now");
  r.exit_code = r.out.rfind("error: ", 0) == 0 ? 1 : 0;
  return r;
}
#endif

class Daemon : public nccomp::test::NccompdProcess {
 public:
  explicit Daemon(fs::path dir) : NccompdProcess(std::move(dir), NCCOMPD_BIN) {}
};

bool is(double v, double want) { return std::fabs(v - want) < 1e-9; }

// The NC moves X to x_mm (0.1 µm counts, int32 high word first).
void move_x(NcServer& nc, double x_mm) {
  const auto counts = static_cast<std::uint32_t>(static_cast<std::int32_t>(x_mm * 10000.0));
  nc.update([&](Tables& t) {
    t.input[0] = static_cast<std::uint16_t>(counts >> 16);
    t.input[1] = static_cast<std::uint16_t>(counts & 0xFFFF);
    t.input[8] = 1;  // tool 1
  });
}

TEST(NccompWarmStart, TheOperatorDeclaresAWarmStartNowOrAtTheNextMotion) {
  TempDir d;
  NcServer nc(ServerConfig{});
  nc.start();
  std::ofstream(d.path / "nccompd.toml") << config_text(nc.port());
  const std::string socket = (d.path / "status.sock").string();
  Daemon daemon(d.path);
  daemon.start();
  ASSERT_TRUE(wait_until([&] {
    const std::string s = daemon.status();
    return s.find("\"state\":\"up\"") != std::string::npos && number(s, "cycles") >= 20;
  })) << daemon.log();
  EXPECT_EQ(number(daemon.status(), "warm_starts"), 0.0);
  EXPECT_EQ(number(daemon.status(), "cold"), 1.0);  // a fresh daemon takes the machine as cold

  // The axes move: a warm start by the idle rule.
  move_x(nc, 10.0);
  ASSERT_TRUE(wait_until([&] { return is(number(daemon.status(), "warm_starts"), 1.0); }))
      << daemon.status();
  std::this_thread::sleep_for(1200ms);
  ASSERT_GE(number(daemon.status(), "machine_time_s"), 1.0);

  // The operator declares the warm start now (the spindle's warm-up program begins, say).
  const CliRun now = nccomp(d, {"warm-start", "--socket", socket});
  EXPECT_EQ(now.exit_code, 0) << now.out << now.err;
  std::printf("%s", now.out.c_str());
  EXPECT_EQ(now.out,
            "ok warm start now: the measurement log's time_s counts from 0\n"
            "  warm starts: 2 (since the state began); warm-start commands taken: 1; operator "
            "commands refused by the daemon: 0\n");
  // The status (published every 10 cycles) shows the new origin within a fraction of a second.
  ASSERT_TRUE(wait_until([&] { return is(number(daemon.status(), "warm_starts"), 2.0); }));
  EXPECT_LT(number(daemon.status(), "machine_time_s"), 0.5) << daemon.status();
  EXPECT_EQ(number(daemon.status(), "cold"), 0.0);

  // A malformed request on the socket: refused with the reason, counted, nothing changes.
  const std::string bad = nccomp::client::query(socket, "warm-start tomorrow");
  EXPECT_EQ(bad,
            "error: warm-start: unknown argument 'tomorrow' (expected nothing, 'now' or "
            "'at-next-motion')\n");
#ifdef NCCOMP_BIN
  // An unknown option never reaches the daemon: CLI11's usage error.
  const CliRun usage = nccomp(d, {"warm-start", "--socket", socket, "--tomorrow"});
  EXPECT_NE(usage.exit_code, 0);
  EXPECT_NE(usage.err.find("--tomorrow"), std::string::npos) << usage.err;
#endif

  // The machine is cold now (switched off and on while nccompd ran): the next motion is the
  // warm start. The socket is found through the configuration this time.
  const CliRun cold =
      nccomp(d, {"warm-start", "--at-next-motion", "--config", (d.path / "nccompd.toml").string()});
  EXPECT_EQ(cold.exit_code, 0) << cold.out << cold.err;
  std::printf("%s", cold.out.c_str());
  EXPECT_EQ(cold.out,
            "ok the machine is cold: its next axis motion is the warm start\n"
            "  warm starts: 2 (since the state began); warm-start commands taken: 2; operator "
            "commands refused by the daemon: 1\n");
  ASSERT_TRUE(wait_until([&] { return is(number(daemon.status(), "cold"), 1.0); }));
  std::this_thread::sleep_for(500ms);
  EXPECT_EQ(number(daemon.status(), "warm_starts"), 2.0);  // standing: no warm start yet
  EXPECT_GE(number(daemon.status(), "machine_time_s"), 0.5);
  move_x(nc, 12.0);
  ASSERT_TRUE(wait_until([&] { return is(number(daemon.status(), "warm_starts"), 3.0); }))
      << daemon.status();
  EXPECT_LT(number(daemon.status(), "machine_time_s"), 0.5);
  EXPECT_EQ(number(daemon.status(), "cold"), 0.0);

  const std::string log = daemon.log();
  EXPECT_NE(log.find("operator command #1: warm-start now (warm starts 2, warm-start commands 1)"),
            std::string::npos)
      << log;
  EXPECT_NE(log.find("operator command refused: warm-start: unknown argument 'tomorrow'"),
            std::string::npos)
      << log;
  EXPECT_NE(log.find("operator command #2: warm-start at the next motion (warm starts 2, "
                     "warm-start commands 2)"),
            std::string::npos)
      << log;

  // A restart keeps the declared origin (saved with the state) and the count.
  std::this_thread::sleep_for(1000ms);
  ASSERT_EQ(daemon.stop(), 0) << daemon.log();
  Daemon again(d.path);
  again.start();
  ASSERT_TRUE(wait_until([&] { return number(again.status(), "cycles") >= 20; })) << again.log();
  const std::string st = again.status();
  EXPECT_EQ(number(st, "warm_starts"), 3.0) << st;
  EXPECT_GE(number(st, "machine_time_s"), 1.0) << st;  // from the motion, not from this start
  EXPECT_EQ(again.stop(), 0);
  nc.stop();

#ifdef NCCOMP_BIN
  // Without a daemon: exit status 1 and the reason.
  const CliRun none = nccomp(d, {"warm-start", "--socket", socket});
  EXPECT_EQ(none.exit_code, 1);
  EXPECT_NE(none.err.find("cannot connect to '" + socket + "'"), std::string::npos) << none.err;
#endif
}

}  // namespace
