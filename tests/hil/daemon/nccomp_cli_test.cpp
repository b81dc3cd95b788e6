// GIVEN the operator command `nccomp` as built, WHEN it runs as a process:
// - `nccomp check-config` on the shipped config, THEN exit 0 and the summary (files, sections,
//   registers, modules); on a file with errors, THEN exit 3 and every error as
//   file:line:column: key.path: message on stderr, the engine's refusals (two modules on one
//   register) included; it runs `nccompd --check-config` (the one NCCOMPD names, if set), which
//   starts nothing;
// - `nccomp status` against a running nccompd (loopback bus, commissioning ramp), THEN exit 0 and
//   the text, JSON and Prometheus forms with the daemon's numbers; without a daemon, THEN exit 1
//   and the reason.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "tests/support/status_json.hpp"
#include "tests/support/temp_dir.hpp"

extern char** environ;

namespace {

using nccomp::test::number;
using nccomp::test::TempDir;

namespace fs = std::filesystem;
using namespace std::chrono_literals;

std::string slurp(const fs::path& p) {
  std::ifstream in(p);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

pid_t spawn(const std::vector<std::string>& args, const fs::path& out, const fs::path& err) {
  std::vector<std::string> a = args;
  std::vector<char*> argv;
  for (auto& s : a) {
    argv.push_back(s.data());
  }
  argv.push_back(nullptr);
  posix_spawn_file_actions_t fa;
  posix_spawn_file_actions_init(&fa);
  posix_spawn_file_actions_addopen(&fa, 1, out.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
  posix_spawn_file_actions_addopen(&fa, 2, err.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
  pid_t pid = -1;
  EXPECT_EQ(posix_spawn(&pid, argv[0], &fa, nullptr, argv.data(), environ), 0);
  posix_spawn_file_actions_destroy(&fa);
  return pid;
}

int wait_exit(pid_t pid) {
  int st = 0;
  ::waitpid(pid, &st, 0);
  return WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
}

struct CliRun {
  int exit_code{-1};
  std::string out;
  std::string err;
};

CliRun nccomp(const TempDir& d, const std::vector<std::string>& args) {
  std::vector<std::string> a{NCCOMP_BIN};
  a.insert(a.end(), args.begin(), args.end());
  const fs::path out = d.path / "cli.out";
  const fs::path err = d.path / "cli.err";
  CliRun r;
  r.exit_code = wait_exit(spawn(a, out, err));
  r.out = slurp(out);
  r.err = slurp(err);
  return r;
}

TEST(NccompCli, CheckConfigOfTheShippedConfigSucceeds) {
  TempDir d;
  const std::string file = std::string(NCCOMP_SOURCE_DIR) + "/config/nccompd.toml";
  const CliRun r = nccomp(d, {"check-config", file});
  EXPECT_EQ(r.exit_code, 0) << r.out << r.err;
  EXPECT_NE(r.out.find(file + ": OK"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("config/reference-nc-modbus.toml"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("  loop: 1000 Hz\n"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("  registers: 9\n"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("  modules: 2 (calibration, creep)\n"), std::string::npos) << r.out;
  EXPECT_EQ(r.err, "");
  const CliRun q = nccomp(d, {"check-config", "--quiet", file});
  EXPECT_EQ(q.exit_code, 0);
  EXPECT_EQ(q.out, "");
}

TEST(NccompCli, CheckConfigReportsEveryErrorWithFileLineAndKey) {
  TempDir d;
  const auto f = d.write("bad.toml",
                         "[daemon]\nrate_hz = 20000\ndry_run = 3\n[daemon.realtime]\n"
                         "lock_memry = true\n[[registers]]\nname = \"a\"\n");
  const CliRun r = nccomp(d, {"check-config", f});
  EXPECT_EQ(r.exit_code, 3);
  EXPECT_EQ(r.out, "");
  EXPECT_NE(r.err.find(f + ":2:11: daemon.rate_hz: must be a number in [1, 10000], got 20000"),
            std::string::npos)
      << r.err;
  EXPECT_NE(r.err.find(f + ":3:11: daemon.dry_run: must be true or false"), std::string::npos)
      << r.err;
  EXPECT_NE(r.err.find(f + ":5:14: daemon.realtime.lock_memry: unknown key"), std::string::npos)
      << r.err;
  EXPECT_NE(r.err.find("registers[0].kind: missing required key"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("error(s) in " + f), std::string::npos) << r.err;
}

TEST(NccompCli, CheckConfigLocatesEngineRefusals) {
  TempDir d;
  std::string regs = "[loopback]\n";
  for (const char* n : {"X_off", "Y_off", "Z_off"}) {
    regs += std::string("[[registers]]\nname = \"") + n +
            "\"\nkind = \"axis_offset\"\nbus = \"loopback\"\nmax_abs_um = 100\n"
            "max_step_um = 5\nmax_rate_um_per_s = 20\n";
  }
  const auto f = d.write(
      "two.toml", regs + "[creep]\n[creep.edge]\ntool_shape = \"tip\"\nnormal_source = \"none\"\n" +
                      "[creep.output]\nz_register = \"Z_off\"\n" +
                      "[calibration]\nregister_x = 0\nregister_y = 1\nregister_z = 2\n");
  const CliRun r = nccomp(d, {"check-config", f});
  EXPECT_EQ(r.exit_code, 3);
  // registers: 3 × 7 lines + [loopback]; [creep] at 23, z_register at 28, register_z at 32.
  EXPECT_NE(r.err.find(f + ":28:14: creep.output.z_register: register 'Z_off' (registers[2], " + f +
                       ":16) is written by module 'calibration' (calibration.register_z, " + f +
                       ":32) and by 'creep'; give each module its own registers"),
            std::string::npos)
      << r.err;
  EXPECT_NE(r.err.find("nccomp: error: 1 error(s) in " + f), std::string::npos) << r.err;
}

// nccompd --check-config is the check `nccomp check-config` runs: the summary of a start that
// does not happen (no state directory, no measurement log, no status socket); its errors end with
// nccompd's count line. --print-status-socket gives the socket the configuration names.
TEST(NccompdCheckConfig, LoadsAsAStartWouldAndStartsNothing) {
  TempDir d;
  const auto cfg = d.write("nccompd.toml",
                           "[daemon]\nrate_hz = 500\n[state]\ndirectory = \"state\"\n"
                           "[measurement_log]\ndirectory = \"log\"\n"
                           "[status]\nsocket_path = \"run/status.sock\"\n[loopback]\n"
                           "[[registers]]\nname = \"T1_length_wear\"\nkind = \"tool_length_wear\"\n"
                           "bus = \"loopback\"\nmax_abs_um = 200\nmax_step_um = 5\n"
                           "max_rate_um_per_s = 50\n");
  const fs::path out = d.path / "nccompd.out";
  const fs::path err = d.path / "nccompd.err";
  EXPECT_EQ(wait_exit(spawn({NCCOMPD_BIN, "--config", cfg, "--check-config"}, out, err)), 0)
      << slurp(err);
  // [log] is not in the file: the section with its defaults, as in a start.
  EXPECT_EQ(slurp(out), cfg + ": OK\n  files: " + cfg +
                            "\n  sections: daemon log loopback measurement_log registers state "
                            "status"
                            "\n  loop: 500 Hz\n  registers: 1\n  modules: 0\n");
  EXPECT_EQ(slurp(err), "");
  EXPECT_FALSE(fs::exists(d.path / "state"));
  EXPECT_FALSE(fs::exists(d.path / "log"));
  EXPECT_FALSE(fs::exists(d.path / "run"));

  EXPECT_EQ(wait_exit(spawn({NCCOMPD_BIN, "--config", cfg, "--print-status-socket"}, out, err)), 0);
  EXPECT_EQ(slurp(out), (d.path / "run" / "status.sock").string() + "\n");

  const auto bad = d.write("bad.toml", "[daemon]\nrate_hz = 0\n");
  EXPECT_EQ(wait_exit(spawn({NCCOMPD_BIN, "--config", bad, "--check-config"}, out, err)), 3);
  EXPECT_EQ(slurp(out), "");
  EXPECT_EQ(slurp(err), bad + ":2:11: daemon.rate_hz: must be a number in [1, 10000], got 0\n" +
                            "nccompd: 1 error(s) in " + bad + "\n");
}

// `nccomp check-config` runs the nccompd that NCCOMPD names and passes its output and exit status
// through, nccompd's count line as nccomp's error; an NCCOMPD that is no program is an error.
TEST(NccompCli, CheckConfigRunsTheNccompdNamedByNCCOMPD) {
  TempDir d;
  const std::string ok = d.write("ok.sh", "#!/bin/sh\necho \"checked: $*\"\n");
  const std::string bad = d.write("bad.sh",
                                  "#!/bin/sh\necho \"f.toml:1:1: a.b: wrong\" >&2\n"
                                  "echo \"nccompd: 1 error(s) in f.toml\" >&2\nexit 3\n");
  fs::permissions(ok, fs::perms::owner_all);
  fs::permissions(bad, fs::perms::owner_all);

  ::setenv("NCCOMPD", ok.c_str(), 1);
  const CliRun r = nccomp(d, {"check-config", "f.toml"});
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(r.out, "checked: --config f.toml --check-config\n");
  EXPECT_EQ(r.err, "");
  EXPECT_EQ(nccomp(d, {"check-config", "--quiet", "f.toml"}).out, "");

  ::setenv("NCCOMPD", bad.c_str(), 1);
  const CliRun e = nccomp(d, {"check-config", "f.toml"});
  EXPECT_EQ(e.exit_code, 3);
  EXPECT_EQ(e.out, "");
  EXPECT_EQ(e.err, "f.toml:1:1: a.b: wrong\nnccomp: error: 1 error(s) in f.toml\n");

  const std::string none = (d.path / "none").string();
  ::setenv("NCCOMPD", none.c_str(), 1);
  const CliRun m = nccomp(d, {"check-config", "f.toml"});
  ::unsetenv("NCCOMPD");
  EXPECT_EQ(m.exit_code, 1);
  EXPECT_EQ(m.err, "nccomp: error: NCCOMPD=" + none + " is not an executable file\n");
}

TEST(NccompCli, StatusTalksToTheRunningDaemon) {
  TempDir d;
  const auto cfg = d.write("nccompd.toml",
                           "[daemon]\nrate_hz = 1000\n[state]\ndirectory = \"state\"\n"
                           "[measurement_log]\ndirectory = \"log\"\n"
                           "[status]\nsocket_path = \"status.sock\"\n[loopback]\n"
                           "[[registers]]\nname = \"T1_length_wear\"\nkind = \"tool_length_wear\"\n"
                           "bus = \"loopback\"\nmax_abs_um = 200\nmax_step_um = 5\n"
                           "max_rate_um_per_s = 50\n[[ramp]]\nname = \"commissioning\"\n"
                           "register = \"T1_length_wear\"\ntarget_um = 7.5\nrate_um_per_s = 50\n");
  const pid_t daemon =
      spawn({NCCOMPD_BIN, "--config", cfg}, d.path / "nccompd.out", d.path / "nccompd.log");
  // Until the ramp has reached its target (7.5 µm at 50 µm/s).
  CliRun json;
  const auto end = std::chrono::steady_clock::now() + 20s;
  while (std::chrono::steady_clock::now() < end) {
    json = nccomp(d, {"status", "--config", cfg, "--json"});
    if (json.exit_code == 0 && number(json.out, "output_um") >= 7.5) {
      break;
    }
    std::this_thread::sleep_for(50ms);
  }
  EXPECT_EQ(json.exit_code, 0) << json.err << slurp(d.path / "nccompd.log");
  EXPECT_DOUBLE_EQ(number(json.out, "output_um"), 7.5) << json.out;
  EXPECT_DOUBLE_EQ(number(json.out, "rate_hz"), 1000.0) << json.out;
  EXPECT_GT(number(json.out, "cycles"), 100.0) << json.out;
  EXPECT_EQ(number(json.out, "pid"), static_cast<double>(daemon)) << json.out;

  const CliRun text = nccomp(d, {"status", "--socket", (d.path / "status.sock").string()});
  EXPECT_EQ(text.exit_code, 0) << text.err;
  EXPECT_NE(text.out.find("nccompd pid " + std::to_string(daemon) + ", config " + cfg),
            std::string::npos)
      << text.out;
  EXPECT_NE(text.out.find("loop:    1000.0 Hz configured"), std::string::npos) << text.out;
  EXPECT_NE(text.out.find("T1_length_wear                7.500 um"), std::string::npos) << text.out;
  EXPECT_NE(text.out.find("loopback   up"), std::string::npos) << text.out;

  const CliRun metrics = nccomp(d, {"status", "--config", cfg, "--metrics"});
  EXPECT_EQ(metrics.exit_code, 0) << metrics.err;
  EXPECT_NE(
      metrics.out.find("nccompd_register_output_meters{register=\"T1_length_wear\"} 7.5e-06\n"),
      std::string::npos)
      << metrics.out;
  EXPECT_NE(metrics.out.find("nccompd_bus_up{bus=\"loopback\"} 1\n"), std::string::npos)
      << metrics.out;

  ::kill(daemon, SIGTERM);
  EXPECT_EQ(wait_exit(daemon), 0) << slurp(d.path / "nccompd.log");

  // No daemon any more: exit 1 and the reason on stderr.
  const CliRun gone = nccomp(d, {"status", "--config", cfg});
  EXPECT_EQ(gone.exit_code, 1);
  EXPECT_EQ(gone.out, "");
  EXPECT_NE(gone.err.find("status.sock"), std::string::npos) << gone.err;
}

}  // namespace
