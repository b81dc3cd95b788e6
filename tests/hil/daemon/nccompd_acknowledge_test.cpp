// The "acknowledge" operator command end to end (docs/daemon.md, "Operator commands"):
// GIVEN the nccompd binary on the project's Modbus NC server (127.0.0.1, ephemeral port) with a
// [creep] module (time basis, a measurement due every 1 s of cutting time) whose alarm flag and
// "measurement due" flag are NC registers, and a first good laser measurement crept in,
// WHEN the laser reports the tool broken (the NC's broken register), THEN the alarm register is 1,
// the request register 0 and nothing is applied, also 1.5 s later (halted: no request);
// WHEN the operator runs `nccomp acknowledge` (the real nccomp binary), THEN the daemon answers
// what it cleared (halt and alarm flag, alarm tool_broken_or_mismeasured 23) and logs it, the
// alarm register goes back to 0 and the request register rises (the overdue measurement), and
// the next good measurement is accepted and crept in; a second acknowledge with nothing latched
// is counted and changes nothing, a malformed request is refused with the reason and counted, an
// unknown option is a usage error, and without a daemon the command fails with exit status 1.
// Privilege separation (root only: the test switches users and groups in forked children; group
// "users" stands for nccomp, "adm" for [status] admin_group): a member of the status group only
// gets the status, but `nccomp acknowledge` is refused (exit status 3, the reason; logged with
// uid, user name and pid) and the NC's alarm stays; a member of the admin group acknowledges.
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
#include "tests/support/run_as.hpp"
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
// The ThreadSanitizer build has no `nccomp` binary: the same request line goes to the socket
// directly (what `nccomp acknowledge` sends), the daemon under TSan.
CliRun nccomp(const TempDir& d, const std::vector<std::string>& /*args*/) {
  CliRun r;
  r.out = nccomp::client::query((d.path / "status.sock").string(), "acknowledge");
  r.exit_code = r.out.rfind("error: ", 0) == 0 ? 1 : 0;
  return r;
}
#endif

class Daemon : public nccomp::test::NccompdProcess {
 public:
  explicit Daemon(fs::path dir) : NccompdProcess(std::move(dir), NCCOMPD_BIN) {}
};

bool is(double v, double want) { return std::fabs(v - want) < 1e-9; }

constexpr std::uint16_t kLength = 200;   // T1_length_wear, int32, 0.1 µm (tool_register_sign -1)
constexpr std::uint16_t kAlarm = 240;    // creep_alarm, uint16 flag
constexpr std::uint16_t kRequest = 242;  // measure_request, uint16 flag

std::string config_text(std::uint16_t port) {
  std::ostringstream s;
  s << "[daemon]\nrate_hz = 200\n"
    << "[state]\ndirectory = \"state\"\nmin_interval_s = 0.05\n"
    << "[measurement_log]\ndirectory = \"log\"\n"
    << "[status]\nsocket_path = \"status.sock\"\nadmin_group = \"adm\"\n"
    << "[modbus]\ntransport = \"tcp\"\nhost = \"127.0.0.1\"\nport = " << port << "\n"
    << "poll_rate_hz = 200\nresponse_timeout_s = 0.5\n"
    << "[modbus.axis]\n"
    << "x_mm = { table = \"input\", address = 0, type = \"int32\", scale = 0.0001 }\n"
    << "tool = { table = \"input\", address = 8, type = \"uint16\" }\n"
    << "[modbus.tool_measurement]\n"
    << "sequence = { table = \"input\", address = 100, type = \"uint16\" }\n"
    << "tool = { table = \"input\", address = 101, type = \"uint16\" }\n"
    << "wear_um = { table = \"input\", address = 102, type = \"float32\" }\n"
    << "broken = { table = \"input\", address = 104, type = \"uint16\" }\n"
    << "[[modbus.offset]]\nregister_index = 0\naddress = 200\ntype = \"int32\"\nscale = 0.1\n"
    << "[[modbus.offset]]\nregister_index = 1\naddress = 240\ntype = \"uint16\"\nscale = 1.0\n"
    << "[[modbus.offset]]\nregister_index = 2\naddress = 242\ntype = \"uint16\"\nscale = 1.0\n"
    << "[[registers]]\nname = \"T1_length_wear\"\nkind = \"tool_length_wear\"\nbus = \"modbus\"\n"
    << "max_abs_um = 200\nmax_step_um = 5\nmax_rate_um_per_s = 50\n"
    << "[[registers]]\nname = \"creep_alarm\"\nkind = \"flag\"\nbus = \"modbus\"\n"
    << "[[registers]]\nname = \"measure_request\"\nkind = \"flag\"\nbus = \"modbus\"\n"
    << "[creep]\ncreep_basis = \"time\"\ncreep_time_s = 1.0\nprofile = \"linear\"\n"
    << "[creep.edge]\ntool_shape = \"tip\"\nnormal_source = \"none\"\n"
    << "fallback_channel = \"length\"\n"
    << "[creep.output]\nmode = \"tool_registers\"\nlength_register = \"T1_length_wear\"\n"
    << "alarm_register = \"creep_alarm\"\nmeasurement_due_register = \"measure_request\"\n"
    << "[creep.interval]\nbasis = \"time\"\ninterval_s = 1.0\n";
  return s.str();
}

std::int32_t holding_i32(NcServer& nc, std::uint16_t address) {
  const auto r = nc.holding(address, 2);
  return static_cast<std::int32_t>((std::uint32_t{r[0]} << 16) | r[1]);
}

int holding(NcServer& nc, std::uint16_t address) { return nc.holding(address, 1)[0]; }

// The laser's result: values first, then the event counter (the profile's rule).
void publish_tool_measurement(NcServer& nc, std::uint16_t seq, float wear_um, bool broken) {
  nc.update([&](Tables& t) {
    std::uint32_t bits = 0;
    std::memcpy(&bits, &wear_um, sizeof bits);
    t.input[101] = 1;
    t.input[102] = static_cast<std::uint16_t>(bits >> 16);
    t.input[103] = static_cast<std::uint16_t>(bits & 0xFFFF);
    t.input[104] = broken ? 1 : 0;
    t.input[100] = seq;
  });
}

TEST(NccompAcknowledge, TheOperatorLiftsABrokenToolHaltAndTheNextMeasurementIsAccepted) {
  TempDir d;
  NcServer nc(ServerConfig{});
  nc.start();
  nc.update([](Tables& t) { t.input[8] = 1; });  // tool 1 in the spindle, cutting
  std::ofstream(d.path / "nccompd.toml") << config_text(nc.port());
  const std::string socket = (d.path / "status.sock").string();
  Daemon daemon(d.path);
  daemon.start();
  ASSERT_TRUE(wait_until([&] {
    const std::string s = daemon.status();
    return s.find("\"state\":\"up\"") != std::string::npos && number(s, "cycles") >= 20;
  })) << daemon.log();

  // 1 s of cutting: the first measurement is due; 5.0 µm is measured and crept in over 1 s.
  ASSERT_TRUE(wait_until([&] { return holding(nc, kRequest) == 1; })) << daemon.log();
  publish_tool_measurement(nc, 1, 5.0F, false);
  ASSERT_TRUE(wait_until([&] { return holding_i32(nc, kLength) == -50; }))
      << holding_i32(nc, kLength) << "\n"
      << daemon.status();
  EXPECT_EQ(holding(nc, kAlarm), 0);

  // The next one is due; the laser, wet with coolant, reports the tool broken.
  ASSERT_TRUE(wait_until([&] { return holding(nc, kRequest) == 1; })) << daemon.status();
  publish_tool_measurement(nc, 2, 6.0F, true);
  ASSERT_TRUE(wait_until([&] { return holding(nc, kAlarm) == 1; })) << daemon.log();
  ASSERT_TRUE(wait_until([&] {
    const std::string s = daemon.status();
    return is(number(s, "halted"), 1.0) && is(number(s, "latched_alarm"), 23.0);
  })) << daemon.status();
  EXPECT_EQ(holding(nc, kRequest), 0);
  // Halted: 1.5 s of cutting (more than the interval) asks for nothing and applies nothing.
  std::this_thread::sleep_for(1500ms);
  EXPECT_EQ(holding(nc, kRequest), 0);
  EXPECT_EQ(holding(nc, kAlarm), 1);
  EXPECT_EQ(holding_i32(nc, kLength), -50);
  EXPECT_EQ(number(daemon.status(), "measurements_accepted"), 1.0);

  // The operator has checked the tool: it is fine. `nccomp acknowledge`: by a member of the
  // admin group when the test can switch users (root), else by the daemon's own user.
  const bool as_root = ::geteuid() == 0;
  CliRun ack;
  pid_t refused_pid = -1;
  pid_t admin_pid = -1;
  if (as_root) {
    const auto users = nccomp::test::gid_of("users");
    const auto adm = nccomp::test::gid_of("adm");
    const auto nogroup = nccomp::test::gid_of("nogroup");
    ASSERT_TRUE(users && adm && nogroup) << "groups users, adm, nogroup";
    ASSERT_EQ(::chown(socket.c_str(), static_cast<uid_t>(-1), *users), 0);  // systemd's Group=
    const nccomp::test::Identity op{65534, *nogroup, {*users}};
    const nccomp::test::Identity admin{65534, *nogroup, {*users, *adm}};
    const std::string name = nccomp::test::user_name_of(65534);
    EXPECT_NE(nccomp::test::request_as(op, socket, "json").answer.find("\"halted\":1"),
              std::string::npos);
    const std::string why =
        "permission denied: 'acknowledge' changes the machine; uid 65534 (" + name +
        ") is not root and not in group 'adm' ([status] admin_group)\n  an administrator grants "
        "it with: usermod -aG adm " +
        name + " (effective at the user's next login)";
#ifdef NCCOMP_BIN
    const auto refused =
        nccomp::test::run_as(op, {NCCOMP_BIN, "acknowledge", "--socket", socket},
                             (d.path / "cli.out").string(), (d.path / "cli.err").string());
    EXPECT_EQ(refused.exit_code, 3);
    EXPECT_EQ(slurp(d.path / "cli.out"), "");
    EXPECT_EQ(slurp(d.path / "cli.err"), "nccomp: error: " + why + "\n");
    std::printf("%s", slurp(d.path / "cli.err").c_str());
#else
    const auto refused = nccomp::test::request_as(op, socket, "acknowledge");
    EXPECT_EQ(refused.answer, "error: " + why + "\n");
#endif
    // Refused: the halt and the NC's alarm flag stay.
    std::this_thread::sleep_for(300ms);
    EXPECT_EQ(holding(nc, kAlarm), 1);
    EXPECT_EQ(number(daemon.status(), "halted"), 1.0);
#ifdef NCCOMP_BIN
    const auto allowed =
        nccomp::test::run_as(admin, {NCCOMP_BIN, "acknowledge", "--socket", socket},
                             (d.path / "cli.out").string(), (d.path / "cli.err").string());
    ack.exit_code = allowed.exit_code;
    ack.out = slurp(d.path / "cli.out");
    ack.err = slurp(d.path / "cli.err");
#else
    const auto allowed = nccomp::test::request_as(admin, socket, "acknowledge");
    ack.out = allowed.answer;
    ack.exit_code = allowed.exit_code == 0 && ack.out.rfind("ok ", 0) == 0 ? 0 : 1;
#endif
    refused_pid = refused.pid;
    admin_pid = allowed.pid;
  } else {
    ack = nccomp(d, {"acknowledge", "--socket", socket});
  }
  const std::string refused_count = as_root ? "1" : "0";
  EXPECT_EQ(ack.exit_code, 0) << ack.out << ack.err;
  std::printf("%s", ack.out.c_str());
  EXPECT_EQ(ack.out,
            "ok acknowledged: creep: halt and alarm flag cleared (alarm tool_broken_or_mismeasured "
            "23)\n"
            "  creep: now halted 0, latched alarm none, acknowledgements taken 1\n"
            "  acknowledge commands taken by the loop: 1; operator commands refused by the "
            "daemon: " +
                refused_count + "\n");
  // The NC sees the alarm fall and the overdue measurement asked for.
  ASSERT_TRUE(wait_until([&] { return holding(nc, kAlarm) == 0; }, 2000ms));
  ASSERT_TRUE(wait_until([&] { return holding(nc, kRequest) == 1; }, 2000ms));
  EXPECT_EQ(holding_i32(nc, kLength), -50);

  // The re-measurement is good: accepted, crept in (7.0 µm), the request falls.
  publish_tool_measurement(nc, 3, 7.0F, false);
  ASSERT_TRUE(wait_until([&] { return holding_i32(nc, kLength) == -70; }))
      << holding_i32(nc, kLength) << "\n"
      << daemon.status();
  EXPECT_EQ(holding(nc, kAlarm), 0);
  const std::string st = daemon.status();
  EXPECT_EQ(number(st, "measurements_accepted"), 2.0) << st;
  EXPECT_EQ(number(st, "halted"), 0.0) << st;
  EXPECT_EQ(number(st, "acknowledged"), 1.0) << st;
  EXPECT_NE(st.find("\"last_acknowledge\":\"halt and alarm flag cleared\""), std::string::npos)
      << st;

  // Nothing latched: counted, nothing changes.
  const CliRun again = nccomp(d, {"acknowledge", "--config", (d.path / "nccompd.toml").string()});
  EXPECT_EQ(again.exit_code, 0) << again.out << again.err;
  std::printf("%s", again.out.c_str());
  EXPECT_EQ(again.out,
            "ok acknowledged: creep: nothing latched\n"
            "  creep: now halted 0, latched alarm none, acknowledgements taken 2\n"
            "  acknowledge commands taken by the loop: 2; operator commands refused by the "
            "daemon: " +
                refused_count + "\n");
  EXPECT_EQ(holding_i32(nc, kLength), -70);

  // A malformed request on the socket: refused with the reason, counted.
  const std::string bad = nccomp::client::query(socket, "acknowledge creep");
  EXPECT_EQ(bad, "error: acknowledge: unknown argument 'creep' (expected nothing or 'all')\n");
#ifdef NCCOMP_BIN
  const CliRun usage = nccomp(d, {"acknowledge", "--socket", socket, "--all-of-them"});
  EXPECT_NE(usage.exit_code, 0);
  EXPECT_NE(usage.err.find("--all-of-them"), std::string::npos) << usage.err;
#endif

  const std::string log = daemon.log();
  std::istringstream lines(log);
  for (std::string line; std::getline(lines, line);) {
    if (line.find("operator command") != std::string::npos ||
        line.find("tool_broken") != std::string::npos) {
      std::printf("%s\n", line.c_str());
    }
  }
  EXPECT_NE(log.find("operator command #1: acknowledge: creep: halt and alarm flag cleared (alarm "
                     "tool_broken_or_mismeasured 23)"),
            std::string::npos)
      << log;
  EXPECT_NE(log.find("operator command #2: acknowledge: creep: nothing latched"), std::string::npos)
      << log;
  EXPECT_NE(log.find("operator command refused: acknowledge: unknown argument 'creep'"),
            std::string::npos)
      << log;
  if (as_root) {
    const std::string name = nccomp::test::user_name_of(65534);
    EXPECT_NE(log.find("operator command refused: 'acknowledge' from uid 65534 (" + name +
                       ") pid " + std::to_string(refused_pid) + ": permission denied: uid 65534 (" +
                       name + ") is not root and not in group 'adm' ([status] admin_group)\n"),
              std::string::npos)
        << log;
    EXPECT_NE(log.find("operator command from uid 65534 (" + name + ") pid " +
                       std::to_string(admin_pid) + ": acknowledge\n"),
              std::string::npos)
        << log;
  }
  EXPECT_EQ(daemon.stop(), 0);
  nc.stop();

#ifdef NCCOMP_BIN
  // Without a daemon: exit status 1 and the reason.
  const CliRun none = nccomp(d, {"acknowledge", "--socket", socket});
  EXPECT_EQ(none.exit_code, 1);
  EXPECT_NE(none.err.find("cannot connect to '" + socket + "'"), std::string::npos) << none.err;
#endif
}

}  // namespace
