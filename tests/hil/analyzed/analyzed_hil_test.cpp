// nccomp-analyzed end to end (docs/analyzed.md): GIVEN nccompd on the project's Modbus NC server
// (127.0.0.1, ephemeral port) with model A live (a constant tool wear of 0 µm), a measurement log
// rotated every 4 KiB, and nccomp-analyzed following that log with min_new_rows = 60,
// WHEN the NC measures T1's wear 60 times (3 µm ± 0.2 µm), THEN the companion runs the analysis
// once, on those 60 rows (taken across the rotation), the daemon has its model.toml in shadow as
// the candidate (`nccomp model status`), and `nccomp analyze` of the daemon's log directory gives
// the same figures and coefficients; stopped by SIGTERM it exits 0.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <spawn.h>
#include <sys/wait.h>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "sim/modbus_nc/nc_server.hpp"
#include "tests/support/nccompd_process.hpp"
#include "tests/support/status_json.hpp"
#include "tests/support/temp_dir.hpp"
#include "tests/support/wait.hpp"

namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;
using nccomp::sim::modbus_nc::NcServer;
using nccomp::sim::modbus_nc::ServerConfig;
using nccomp::sim::modbus_nc::Tables;
using nccomp::test::number;
using nccomp::test::TempDir;
using nccomp::test::wait_until;

std::string slurp(const fs::path& p) {
  std::ifstream in(p);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

std::string config_text(std::uint16_t port) {
  std::ostringstream s;
  s << "[daemon]\nrate_hz = 200\n"
    << "[state]\ndirectory = \"state\"\nmin_interval_s = 0.05\n"
    << "[measurement_log]\ndirectory = \"log\"\nmax_file_bytes = 4096\n"
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
    << "[[registers]]\nname = \"T1_length_wear\"\nkind = \"tool_length_wear\"\nbus = \"modbus\"\n"
    << "max_abs_um = 200\nmax_step_um = 5\nmax_rate_um_per_s = 50\n"
    << "[creep]\ncreep_basis = \"time\"\ncreep_time_s = 0.5\nprofile = \"linear\"\n"
    << "[creep.edge]\ntool_shape = \"tip\"\nnormal_source = \"none\"\n"
    << "fallback_channel = \"length\"\n"
    << "[creep.output]\nmode = \"tool_registers\"\nlength_register = \"T1_length_wear\"\n"
    << "[model]\nfile = \"a/model.toml\"\nupdate = \"cycle\"\n"
    << "[[model.apply]]\nterm = \"offset\"\nregister = \"T1_length_wear\"\ngain = 1\n"
    << "kind = \"tool_wear\"\n[model.shadow]\nmin_parts = 5\n";
  return s.str();
}

// The coef_um lines of a model.toml (its header comments differ by who wrote it).
std::vector<std::string> coefficients(const std::string& model) {
  std::vector<std::string> out;
  std::istringstream in(model);
  for (std::string l; std::getline(in, l);) {
    if (l.rfind("coef_um", 0) == 0) out.push_back(l);
  }
  return out;
}

int run_nccomp(const std::vector<std::string>& args, const fs::path& out) {
  std::vector<std::string> a{NCCOMP_BIN};
  a.insert(a.end(), args.begin(), args.end());
  std::vector<char*> argv;
  for (auto& s : a) argv.push_back(s.data());
  argv.push_back(nullptr);
  posix_spawn_file_actions_t fa;
  posix_spawn_file_actions_init(&fa);
  posix_spawn_file_actions_addopen(&fa, 1, out.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
  posix_spawn_file_actions_adddup2(&fa, 1, 2);
  pid_t pid = -1;
  EXPECT_EQ(posix_spawn(&pid, argv[0], &fa, nullptr, argv.data(), environ), 0);
  posix_spawn_file_actions_destroy(&fa);
  int st = 0;
  ::waitpid(pid, &st, 0);
  return WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
}

TEST(NccompAnalyzed, EnoughNewRowsPutTheAnalysedModelInShadowWithTheFiguresOfNccompAnalyze) {
  constexpr int kRows = 60;
  TempDir d;
  NcServer nc(ServerConfig{});
  nc.start();
  nc.update([](Tables& t) { t.input[8] = 1; });
  fs::create_directories(d.path / "a");
  fs::create_directories(d.path / "svc");
  const std::string a = (d.path / "a" / "model.toml").string();
  std::ofstream(a) << "[model]\n[[model.term]]\nname = \"offset\"\nform = \"constant\"\n"
                   << "kinds = [\"tool_wear\"]\ngroups = [[0.0, 0.0]]\ncoef_um = [0]\n";
  std::ofstream(d.path / "nccompd.toml") << config_text(nc.port());
  std::ofstream(d.path / "svc" / "analyzed.toml")
      << "[source]\nlog_directory = \"../log\"\npoll_interval_s = 0.1\n"
      << "[analysis]\nconfig = \"../a/model.toml\"\nmin_new_rows = " << kRows << "\n"
      << "min_improvement_um = 1.0\n[output]\ndirectory = \"work\"\n"
      << "[daemon]\nstatus_socket = \"../status.sock\"\n";
  nccomp::test::NccompdProcess daemon(d.path, NCCOMPD_BIN);
  ASSERT_TRUE(daemon.start());
  ASSERT_TRUE(wait_until([&] { return number(daemon.status(), "cycles") >= 20; })) << daemon.log();
  nccomp::test::NccompdProcess analyzed(d.path / "svc", NCCOMP_ANALYZED_BIN);
  ASSERT_TRUE(analyzed.start({}, "analyzed.toml"));

  std::uint16_t sequence = 0;
  for (int i = 0; i < kRows; ++i) {
    const float wear_um = 3.0F + 0.2F * static_cast<float>(std::sin(1.7 * i + 0.3 * i * i));
    ++sequence;
    const double before = number(daemon.status(), "rows_scored");
    nc.update([&](Tables& t) {
      std::uint32_t bits = 0;
      std::memcpy(&bits, &wear_um, sizeof bits);
      t.input[101] = 1;
      t.input[102] = static_cast<std::uint16_t>(bits >> 16);
      t.input[103] = static_cast<std::uint16_t>(bits & 0xFFFF);
      t.input[100] = sequence;
    });
    ASSERT_TRUE(wait_until([&] { return number(daemon.status(), "rows_scored") > before; }))
        << i << "\n"
        << daemon.log();
  }
  EXPECT_TRUE(fs::exists(d.path / "log" / "measurements.csv.1")) << "the log did not rotate";

  ASSERT_TRUE(wait_until(
      [&] { return daemon.status().find("\"phase\":\"candidate\"") != std::string::npos; }, 60s))
      << slurp(d.path / "svc" / "nccompd.log") << daemon.log();
  std::vector<fs::path> runs;
  for (const auto& e : fs::directory_iterator(d.path / "svc" / "work" / "runs")) {
    runs.push_back(e.path());
  }
  ASSERT_EQ(runs.size(), 1U) << slurp(d.path / "svc" / "nccompd.log");
  const fs::path run = runs[0];
  EXPECT_EQ(run.filename().string().rfind("000001-", 0), 0U) << run;
  const auto status = nlohmann::json::parse(daemon.wait_status(
      [](const std::string& j) { return j.find("\"phase\":\"candidate\"") != std::string::npos; }));
  EXPECT_EQ(status["shadow"]["other"]["file"], (run / "model.toml").string());
  EXPECT_EQ(status["model"]["live"]["file"], a);
  // The daemon has the candidate before the run's decision.json is written.
  ASSERT_TRUE(wait_until([&] { return fs::exists(run / "decision.json"); }));
  const auto decision = nlohmann::json::parse(slurp(run / "decision.json"));
  EXPECT_EQ(decision["decision"], "submitted");
  EXPECT_EQ(decision["rows"], kRows);

  const fs::path model_status = d.path / "model-status.out";
  ASSERT_EQ(run_nccomp({"model", "status", "--socket", daemon.socket()}, model_status), 0);
  EXPECT_NE(slurp(model_status).find((run / "model.toml").string()), std::string::npos)
      << slurp(model_status);

  // The same rows analysed directly, from the daemon's own files given one by one, oldest
  // first (the order in which `--log DIR` reads a log and its rotated measurements.csv.N).
  std::vector<std::string> args{"analyze"};
  for (int n = 8; n >= 0; --n) {
    const fs::path f =
        d.path / "log" / ("measurements.csv" + (n > 0 ? "." + std::to_string(n) : ""));
    if (fs::exists(f)) args.insert(args.end(), {"--log", f.string()});
  }
  const fs::path direct = d.path / "direct";
  args.insert(args.end(), {"--config", a, "--out", direct.string()});
  ASSERT_EQ(run_nccomp(args, d.path / "analyze.out"), 0) << slurp(d.path / "analyze.out");
  EXPECT_NE(slurp(d.path / "analyze.out").find("rows: " + std::to_string(kRows) + " "),
            std::string::npos)
      << slurp(d.path / "analyze.out");
  const auto mine = nlohmann::json::parse(slurp(run / "summary.json"));
  const auto theirs = nlohmann::json::parse(slurp(direct / "summary.json"));
  for (const char* key : {"declared_rms_um", "final_rms_um", "noise_floor_um"}) {
    ASSERT_TRUE(theirs.contains(key)) << key << " " << theirs.dump();
    EXPECT_EQ(mine[key], theirs[key]) << key;
  }
  EXPECT_EQ(mine["effects"], theirs["effects"]);
  EXPECT_EQ(mine["prediction_interval"], theirs["prediction_interval"]);
  const auto coef = coefficients(slurp(run / "model.toml"));
  ASSERT_FALSE(coef.empty());
  EXPECT_EQ(coef, coefficients(slurp(direct / "model.toml")));
  // The live model predicts 0: the new one's RMS on the rows is lower by about the 3 µm of wear.
  EXPECT_GT(decision["live_rms_um"].get<double>() - decision["new_rms_um"].get<double>(), 2.5);

  EXPECT_EQ(analyzed.stop(), 0) << slurp(d.path / "svc" / "nccompd.log");
  EXPECT_NE(slurp(d.path / "svc" / "nccompd.log").find("1 candidates submitted"),
            std::string::npos);
  EXPECT_EQ(daemon.stop(), 0);
}

}  // namespace
