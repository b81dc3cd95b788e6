// `nccomp model load | rollback | status` end to end (docs/closing-the-loop.md, "Loading a model
// into a running daemon"): GIVEN the nccompd binary on the project's Modbus NC server (127.0.0.1,
// ephemeral port) with a [creep] module on T1_length_wear (5.0 µm of wear crept in: −5.0 µm,
// tool_register_sign −1) and a [model] whose constant term `offset` (2.0 µm in model A) is a
// trim on the same register (gain 1: the NC holds −3.0 µm),
// WHEN the operator loads model B (6.0 µm) with the real nccomp binary, THEN the daemon answers
// with B's path and hash, A kept for rollback and one handover with the creep rebased, and the
// register goes to −5 + 6 = +1.0 µm (fed in along the creep); `model status` says so;
// WHEN the operator rolls back, THEN A is live again (−3.0 µm) and B is kept; after a restart of
// the daemon A is still live and B kept (the record in the state directory);
// a file that is not a model, and a model without the term [[model.apply]] names, are refused
// with the configuration's error (exit status 3) and nothing changes; as root, a caller outside
// the admin group may ask for the status but its load is refused (permission denied, logged).
#include <fcntl.h>
#include <gtest/gtest.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
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

class Daemon : public nccomp::test::NccompdProcess {
 public:
  explicit Daemon(fs::path dir) : NccompdProcess(std::move(dir), NCCOMPD_BIN) {}
};

constexpr std::uint16_t kLength = 200;  // T1_length_wear, int32, 0.1 µm

std::int32_t holding_i32(NcServer& nc, std::uint16_t address) {
  const auto r = nc.holding(address, 2);
  return static_cast<std::int32_t>((std::uint32_t{r[0]} << 16) | r[1]);
}

std::string config_text(std::uint16_t port, const std::string& extra = "") {
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
    << "[[registers]]\nname = \"T1_length_wear\"\nkind = \"tool_length_wear\"\nbus = \"modbus\"\n"
    << "max_abs_um = 200\nmax_step_um = 5\nmax_rate_um_per_s = 50\n"
    << "[creep]\ncreep_basis = \"time\"\ncreep_time_s = 0.5\nprofile = \"linear\"\n"
    << "[creep.edge]\ntool_shape = \"tip\"\nnormal_source = \"none\"\n"
    << "fallback_channel = \"length\"\n"
    << "[creep.output]\nmode = \"tool_registers\"\nlength_register = \"T1_length_wear\"\n"
    << "[model]\nfile = \"a/model.toml\"\nupdate = \"cycle\"\n"
    << "[[model.apply]]\nterm = \"offset\"\nregister = \"T1_length_wear\"\ngain = 1\n"
    << extra;
  return s.str();
}

// A fitted model with one constant term (what nccomp analyze writes, reduced).
std::string model_text(const char* name, double coef_um, const char* kind = "contour") {
  std::ostringstream s;
  s << "[model]\n[[model.term]]\nname = \"" << name << "\"\nform = \"constant\"\n"
    << "kinds = [\"" << kind << "\"]\ngroups = [[0.0, 0.0]]\ncoef_um = [" << coef_um << "]\n";
  return s.str();
}

struct CliRun {
  int exit_code{-1};
  std::string out;
  std::string err;
};

#ifdef NCCOMP_BIN
CliRun nccomp_as_root(const TempDir& d, const std::vector<std::string>& args) {
  std::vector<std::string> a{NCCOMP_BIN};
  a.insert(a.end(), args.begin(), args.end());
  std::vector<char*> argv;
  for (auto& s : a) argv.push_back(s.data());
  argv.push_back(nullptr);
  posix_spawn_file_actions_t fa;
  posix_spawn_file_actions_init(&fa);
  const std::string out = (d.path / "cli.out").string();
  const std::string err = (d.path / "cli.err").string();
  posix_spawn_file_actions_addopen(&fa, 1, out.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
  posix_spawn_file_actions_addopen(&fa, 2, err.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
  pid_t pid = -1;
  EXPECT_EQ(posix_spawn(&pid, argv[0], &fa, nullptr, argv.data(), environ), 0);
  posix_spawn_file_actions_destroy(&fa);
  int st = 0;
  ::waitpid(pid, &st, 0);
  return {WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st), slurp(out), slurp(err)};
}
#else
// The ThreadSanitizer build has no `nccomp` binary: the request line goes to the socket as
// `nccomp model ...` sends it (the path already absolute).
CliRun nccomp_as_root(const TempDir& d, const std::vector<std::string>& args) {
  std::string line = "model";
  for (std::size_t i = 1; i < args.size() && args[i] != "--socket"; ++i) line += " " + args[i];
  CliRun r;
  r.out = nccomp::client::query((d.path / "status.sock").string(), line);
  r.exit_code = r.out.rfind("error: ", 0) == 0 ? 3 : 0;
  if (r.exit_code != 0) r.err = "nccomp: " + r.out;
  return r;
}
#endif

TEST(NccompModel, LoadRollbackAndRestartWithRefusals) {
  TempDir d;
  NcServer nc(ServerConfig{});
  nc.start();
  nc.update([](Tables& t) { t.input[8] = 1; });  // tool 1 in the spindle
  fs::create_directories(d.path / "a");
  fs::create_directories(d.path / "b");
  std::ofstream(d.path / "a" / "model.toml") << model_text("offset", 2.0);
  std::ofstream(d.path / "b" / "model.toml") << model_text("offset", 6.0);
  std::ofstream(d.path / "b" / "other.toml") << model_text("part_trend", 1.0);
  std::ofstream(d.path / "b" / "garbage.toml") << "this is [not a model\n";
  std::ofstream(d.path / "nccompd.toml") << config_text(nc.port());
  const std::string socket = (d.path / "status.sock").string();
  const std::string a = (d.path / "a" / "model.toml").string();
  const std::string b = (d.path / "b" / "model.toml").string();
  Daemon daemon(d.path);
  ASSERT_TRUE(daemon.start());
  ASSERT_TRUE(wait_until([&] { return number(daemon.status(), "cycles") >= 20; }, 15s))
      << daemon.log();
  // 5.0 µm of wear measured: −5.0 µm + the trim of model A (2.0) = −3.0 µm.
  nc.update([](Tables& t) {
    const float w = 5.0F;
    std::uint32_t bits = 0;
    std::memcpy(&bits, &w, sizeof bits);
    t.input[101] = 1;
    t.input[102] = static_cast<std::uint16_t>(bits >> 16);
    t.input[103] = static_cast<std::uint16_t>(bits & 0xFFFF);
    t.input[100] = 1;
  });
  ASSERT_TRUE(wait_until([&] { return holding_i32(nc, kLength) == -30; }, 15s))
      << holding_i32(nc, kLength) << "\n"
      << daemon.log();

  CliRun st = nccomp_as_root(d, {"model", "status", "--socket", socket});
  ASSERT_EQ(st.exit_code, 0) << st.out << st.err;
  std::printf("%s", st.out.c_str());
  EXPECT_EQ(st.out.rfind("ok model: " + a + " (hash ", 0), 0U) << st.out;
  EXPECT_NE(st.out.find("previous (nccomp model rollback returns to it): none"), std::string::npos)
      << st.out;

  // Load B: one handover, the creep takes the 4 µm and feeds them in.
  CliRun load = nccomp_as_root(d, {"model", "load", b, "--socket", socket});
  ASSERT_EQ(load.exit_code, 0) << load.out << load.err << daemon.log();
  std::printf("%s", load.out.c_str());
  EXPECT_EQ(load.out.rfind("ok model loaded: " + b + " (hash ", 0), 0U) << load.out;
  EXPECT_NE(load.out.find("previous (nccomp model rollback returns to it): " + a),
            std::string::npos)
      << load.out;
  EXPECT_NE(load.out.find("  configuration 2 running\n"), std::string::npos) << load.out;
  EXPECT_NE(load.out.find("handovers: 1 (registers rebased 1, not absorbed 0); last: largest "
                          "trim change 4.000 um, 0.000 um through the limiter"),
            std::string::npos)
      << load.out;
  ASSERT_TRUE(wait_until([&] { return holding_i32(nc, kLength) == 10; }, 15s))
      << holding_i32(nc, kLength) << "\n"
      << daemon.log();
  EXPECT_NE(daemon.log().find("operator command from uid 0 (root)"), std::string::npos);
  EXPECT_NE(daemon.log().find("model load " + b), std::string::npos) << daemon.log();
  const std::string json = daemon.status();
  EXPECT_EQ(number(json, "handovers"), 1.0) << json;
  EXPECT_EQ(number(json, "rebased"), 1.0) << json;
  EXPECT_EQ(number(json, "last_trim_change_um"), 4.0) << json;

  // Refusals change nothing: not a model, and a model without the term [[model.apply]] names.
  const std::string garbage = (d.path / "b" / "garbage.toml").string();
  CliRun bad = nccomp_as_root(d, {"model", "load", garbage, "--socket", socket});
  EXPECT_EQ(bad.exit_code, 3) << bad.out << bad.err;
  std::printf("%s", bad.err.c_str());
  EXPECT_NE(bad.err.find("model load: refused, nothing changed"), std::string::npos) << bad.err;
  EXPECT_NE(bad.err.find("nccompd.toml:"), std::string::npos) << bad.err;
  EXPECT_NE(bad.err.find("cannot load the model " + garbage + " (nccomp model load)"),
            std::string::npos)
      << bad.err;
  const std::string other = (d.path / "b" / "other.toml").string();
  CliRun unfit = nccomp_as_root(d, {"model", "load", other, "--socket", socket});
  EXPECT_EQ(unfit.exit_code, 3) << unfit.out << unfit.err;
  EXPECT_NE(unfit.err.find("model.apply[0].term: no term 'offset' in " + other), std::string::npos)
      << unfit.err;
  st = nccomp_as_root(d, {"model", "status", "--socket", socket});
  EXPECT_EQ(st.out.rfind("ok model: " + b + " (hash ", 0), 0U) << st.out;
  EXPECT_NE(st.out.find("  configuration 2\n"), std::string::npos) << st.out;
  EXPECT_EQ(holding_i32(nc, kLength), 10);

  // As root the test can be someone else: outside the admin group, status yes, load no.
  if (::geteuid() == 0) {
    const auto users = nccomp::test::gid_of("users");
    const auto nogroup = nccomp::test::gid_of("nogroup");
    ASSERT_TRUE(users && nogroup) << "groups users, nogroup";
    ASSERT_EQ(::chown(socket.c_str(), static_cast<uid_t>(-1), *users), 0);
    const nccomp::test::Identity op{65534, *nogroup, {*users}};
    EXPECT_EQ(nccomp::test::request_as(op, socket, "model status").answer.rfind("ok model: ", 0),
              0U);
    const auto refused = nccomp::test::request_as(op, socket, "model load " + a);
    EXPECT_EQ(refused.answer.rfind("error: permission denied: 'model' changes the machine; uid "
                                   "65534",
                                   0),
              0U)
        << refused.answer;
    EXPECT_NE(daemon.log().find("operator command refused: 'model load " + a + "' from uid 65534"),
              std::string::npos)
        << daemon.log();
  }

  // Rollback: A again, B kept; the creep takes the 4 µm back.
  CliRun back = nccomp_as_root(d, {"model", "rollback", "--socket", socket});
  ASSERT_EQ(back.exit_code, 0) << back.out << back.err;
  std::printf("%s", back.out.c_str());
  EXPECT_EQ(back.out.rfind("ok model rolled back to: " + a + " (hash ", 0), 0U) << back.out;
  EXPECT_NE(back.out.find("previous (nccomp model rollback returns to it): " + b),
            std::string::npos)
      << back.out;
  ASSERT_TRUE(wait_until([&] { return holding_i32(nc, kLength) == -30; }, 15s))
      << holding_i32(nc, kLength);

  // A restart keeps the choice: A live, B kept for rollback.
  EXPECT_EQ(daemon.stop(), 0) << daemon.log();
  ASSERT_TRUE(daemon.start());
  ASSERT_TRUE(wait_until([&] { return daemon.try_status().has_value(); }, 15s)) << daemon.log();
  st = nccomp_as_root(d, {"model", "status", "--socket", socket});
  std::printf("%s", st.out.c_str());
  EXPECT_EQ(st.out.rfind("ok model: " + a + " (hash ", 0), 0U) << st.out;
  // A is the configuration's own file (not an operator's choice in its place).
  EXPECT_NE(st.out.find("  the configuration's [model] file, chosen again by nccomp model load / "
                        "rollback\n"),
            std::string::npos)
      << st.out;
  EXPECT_EQ(st.out.find("in place of"), std::string::npos) << st.out;
  EXPECT_NE(st.out.find("previous (nccomp model rollback returns to it): " + b), std::string::npos)
      << st.out;
  EXPECT_EQ(daemon.stop(), 0) << daemon.log();
}

// A candidate in shadow (docs/closing-the-loop.md, "A candidate in shadow"): GIVEN the daemon above
// with model A live (tool wear predicted 0 µm) and [model.shadow] min_parts = 5, WHEN a non-admin
// caller and a file that is not a model are refused, the operator makes B (5.0 µm) the candidate
// and the NC measures 5.0 µm of wear five times (each tool measurement, without a part number, is
// a part of its own), THEN the rule promotes B (5 of 5 parts, p = 1/32) with the handover of a
// load (A kept for rollback), the next five parts confirm it, and a restart keeps the history.
// B's trim predicts the wear the laser measures (kind tool_wear), so the creep keeps B's share
// out of what it measured and the register stays at −5.0 µm: the wear is not counted twice.
TEST(NccompModel, ACandidateInShadowIsPromotedByTheRuleAndTheHistoryPersists) {
  TempDir d;
  NcServer nc(ServerConfig{});
  nc.start();
  nc.update([](Tables& t) { t.input[8] = 1; });
  fs::create_directories(d.path / "a");
  fs::create_directories(d.path / "b");
  std::ofstream(d.path / "a" / "model.toml") << model_text("offset", 0.0, "tool_wear");
  std::ofstream(d.path / "b" / "model.toml") << model_text("offset", 5.0, "tool_wear");
  std::ofstream(d.path / "b" / "garbage.toml") << "this is [not a model\n";
  std::ofstream(d.path / "nccompd.toml") << config_text(
      nc.port(), "kind = \"tool_wear\"\n[model.shadow]\nmin_parts = 5\nalpha = 0.05\n");
  const std::string socket = (d.path / "status.sock").string();
  const std::string a = (d.path / "a" / "model.toml").string();
  const std::string b = (d.path / "b" / "model.toml").string();
  Daemon daemon(d.path);
  ASSERT_TRUE(daemon.start());
  ASSERT_TRUE(wait_until([&] { return number(daemon.status(), "cycles") >= 20; })) << daemon.log();
  std::uint16_t sequence = 0;
  const auto measure = [&](float wear_um) {
    ++sequence;
    // One record per measurement: wait until the shadow has scored it.
    const double before = number(daemon.status(), "rows_scored");
    nc.update([&](Tables& t) {
      std::uint32_t bits = 0;
      std::memcpy(&bits, &wear_um, sizeof bits);
      t.input[101] = 1;
      t.input[102] = static_cast<std::uint16_t>(bits >> 16);
      t.input[103] = static_cast<std::uint16_t>(bits & 0xFFFF);
      t.input[100] = sequence;
    });
    return wait_until([&] { return number(daemon.status(), "rows_scored") > before; });
  };
  ASSERT_TRUE(measure(5.0F)) << daemon.log();
  ASSERT_TRUE(wait_until([&] { return holding_i32(nc, kLength) == -50; }))
      << holding_i32(nc, kLength) << "\n"
      << daemon.log();

  if (::geteuid() == 0) {
    const auto users = nccomp::test::gid_of("users");
    const auto nogroup = nccomp::test::gid_of("nogroup");
    ASSERT_TRUE(users && nogroup) << "groups users, nogroup";
    ASSERT_EQ(::chown(socket.c_str(), static_cast<uid_t>(-1), *users), 0);
    const nccomp::test::Identity op{65534, *nogroup, {*users}};
    const auto refused = nccomp::test::request_as(op, socket, "model candidate " + b);
    EXPECT_EQ(refused.answer.rfind("error: permission denied: 'model' changes the machine", 0), 0U)
        << refused.answer;
    EXPECT_NE(
        daemon.log().find("operator command refused: 'model candidate " + b + "' from uid 65534"),
        std::string::npos)
        << daemon.log();
  }
  const std::string garbage = (d.path / "b" / "garbage.toml").string();
  CliRun bad = nccomp_as_root(d, {"model", "candidate", garbage, "--socket", socket});
  EXPECT_EQ(bad.exit_code, 3) << bad.out << bad.err;
  EXPECT_NE(bad.err.find("model candidate: refused, nothing changed"), std::string::npos)
      << bad.err;
  EXPECT_NE(bad.err.find("cannot load the model " + garbage), std::string::npos) << bad.err;
  EXPECT_NE(daemon.status().find("\"phase\":\"none\""), std::string::npos) << daemon.status();

  CliRun cand = nccomp_as_root(d, {"model", "candidate", b, "--socket", socket});
  ASSERT_EQ(cand.exit_code, 0) << cand.out << cand.err << daemon.log();
  std::printf("%s", cand.out.c_str());
  EXPECT_EQ(cand.out.rfind("ok model candidate: " + b, 0), 0U) << cand.out;
  EXPECT_NE(daemon.status().find("\"phase\":\"candidate\""), std::string::npos) << daemon.status();
  for (int i = 0; i < 4; ++i) ASSERT_TRUE(measure(5.0F)) << daemon.log();
  // Four parts: the rule waits for the fifth.
  CliRun st = nccomp_as_root(d, {"model", "status", "--socket", socket});
  EXPECT_EQ(st.out.rfind("ok model: " + a, 0), 0U) << st.out;
  EXPECT_NE(st.out.find("paired parts 4 of 5: other better on 4, live better on 0"),
            std::string::npos)
      << st.out;
  ASSERT_TRUE(measure(5.0F)) << daemon.log();
  // The promotion's handover makes B live first and records the decision after it: wait for the
  // record.
  ASSERT_TRUE(wait_until([&] {
    const std::string out = nccomp_as_root(d, {"model", "status", "--socket", socket}).out;
    return out.rfind("ok model: " + b, 0) == 0 &&
           out.find("promoted by shadow rule") != std::string::npos;
  })) << daemon.log();
  st = nccomp_as_root(d, {"model", "status", "--socket", socket});
  std::printf("%s", st.out.c_str());
  EXPECT_NE(st.out.find("previous (nccomp model rollback returns to it): " + a), std::string::npos)
      << st.out;
  EXPECT_NE(st.out.find("promoted by shadow rule: live " + a + ", other " + b +
                        "; 5 parts: other better on 5, live better on 0, ties 0, p = 0.03125, "
                        "rms live 5.000 um, other 0.000 um"),
            std::string::npos)
      << st.out;
  EXPECT_NE(st.out.find("watching the model the promotion replaced: " + a), std::string::npos)
      << st.out;
  // The handover of a load: B's +5 µm is the creep's residual's share, the register stays at
  // −5.0 µm (with the trim added to the measured wear it would creep to 0.0 µm within 0.6 s).
  // The loop swaps in a cycle without a write in flight (up to 250 cycles after the reload
  // that made B the live model): wait for it.
  EXPECT_TRUE(wait_until([&] { return number(daemon.status(), "handovers") >= 1.0; }, 15s));
  EXPECT_EQ(number(daemon.status(), "handovers"), 1.0);
  std::this_thread::sleep_for(1500ms);
  EXPECT_EQ(holding_i32(nc, kLength), -50) << daemon.log();
  // The model A replaced is not better over the next five parts: B stays.
  for (int i = 0; i < 5; ++i) ASSERT_TRUE(measure(5.0F)) << daemon.log();
  ASSERT_TRUE(measure(5.0F)) << daemon.log();
  ASSERT_TRUE(wait_until([&] {
    return nccomp_as_root(d, {"model", "status", "--socket", socket}).out.find("confirmed by") !=
           std::string::npos;
  })) << daemon.log();
  EXPECT_NE(daemon.log().find("model shadow: "), std::string::npos);
  std::this_thread::sleep_for(1000ms);
  EXPECT_EQ(holding_i32(nc, kLength), -50) << daemon.log();

  // A restart keeps the history (the state directory's model-shadow) and B live.
  EXPECT_EQ(daemon.stop(), 0) << daemon.log();
  ASSERT_TRUE(daemon.start());
  ASSERT_TRUE(wait_until([&] { return daemon.try_status().has_value(); })) << daemon.log();
  st = nccomp_as_root(d, {"model", "status", "--socket", socket});
  std::printf("%s", st.out.c_str());
  EXPECT_EQ(st.out.rfind("ok model: " + b, 0), 0U) << st.out;
  EXPECT_NE(st.out.find("history (3 decisions):"), std::string::npos) << st.out;
  EXPECT_NE(st.out.find("candidate by uid 0 (root)"), std::string::npos) << st.out;
  EXPECT_NE(st.out.find("promoted by shadow rule"), std::string::npos) << st.out;
  EXPECT_NE(st.out.find("confirmed by shadow rule"), std::string::npos) << st.out;
  EXPECT_EQ(daemon.stop(), 0) << daemon.log();
}

// Demotion: GIVEN model A live predicting 10 µm of wear (trim +10 µm) and B predicting 5 µm,
// WHEN the NC measures 5.0 µm five times, THEN B is promoted; WHEN the wear then reads 8.0 µm five
// times (A's error 2 µm, B's 3 µm on every part), THEN the rule demotes B: A is live again, B kept
// for rollback. The trims predict the wear the laser measures (kind tool_wear): the creep keeps
// their share out of the measured wear, so the register holds the measured wear through both
// handovers, −5.0 µm and then −8.0 µm (added to it, it would read 0.0 and +2.0 µm).
TEST(NccompModel, APromotedModelIsDemotedWhenTheModelItReplacedDoesBetter) {
  TempDir d;
  NcServer nc(ServerConfig{});
  nc.start();
  nc.update([](Tables& t) { t.input[8] = 1; });
  fs::create_directories(d.path / "a");
  fs::create_directories(d.path / "b");
  std::ofstream(d.path / "a" / "model.toml") << model_text("offset", 10.0, "tool_wear");
  std::ofstream(d.path / "b" / "model.toml") << model_text("offset", 5.0, "tool_wear");
  std::ofstream(d.path / "nccompd.toml")
      << config_text(nc.port(), "kind = \"tool_wear\"\n[model.shadow]\nmin_parts = 5\n");
  const std::string socket = (d.path / "status.sock").string();
  const std::string a = (d.path / "a" / "model.toml").string();
  const std::string b = (d.path / "b" / "model.toml").string();
  Daemon daemon(d.path);
  ASSERT_TRUE(daemon.start());
  ASSERT_TRUE(wait_until([&] { return number(daemon.status(), "cycles") >= 20; })) << daemon.log();
  std::uint16_t sequence = 0;
  const auto measure = [&](float wear_um) {
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
    return wait_until([&] { return number(daemon.status(), "rows_scored") > before; });
  };
  ASSERT_TRUE(measure(5.0F)) << daemon.log();
  ASSERT_TRUE(wait_until([&] { return holding_i32(nc, kLength) == -50; }))
      << holding_i32(nc, kLength) << "\n"
      << daemon.log();
  CliRun cand = nccomp_as_root(d, {"model", "candidate", b, "--socket", socket});
  ASSERT_EQ(cand.exit_code, 0) << cand.out << cand.err << daemon.log();
  for (int i = 0; i < 5; ++i) ASSERT_TRUE(measure(5.0F)) << daemon.log();
  ASSERT_TRUE(wait_until([&] {
    return nccomp_as_root(d, {"model", "status", "--socket", socket})
               .out.rfind("ok model: " + b, 0) == 0;
  })) << daemon.log();
  std::this_thread::sleep_for(1000ms);
  EXPECT_EQ(holding_i32(nc, kLength), -50) << daemon.log();
  for (int i = 0; i < 5; ++i) ASSERT_TRUE(measure(8.0F)) << daemon.log();
  ASSERT_TRUE(wait_until([&] {
    return nccomp_as_root(d, {"model", "status", "--socket", socket})
               .out.rfind("ok model: " + a, 0) == 0;
  })) << daemon.log();
  ASSERT_TRUE(wait_until([&] { return holding_i32(nc, kLength) == -80; }))
      << holding_i32(nc, kLength) << "\n"
      << daemon.log();
  std::this_thread::sleep_for(1000ms);
  EXPECT_EQ(holding_i32(nc, kLength), -80) << daemon.log();
  CliRun st = nccomp_as_root(d, {"model", "status", "--socket", socket});
  std::printf("%s", st.out.c_str());
  EXPECT_EQ(st.out.rfind("ok model: " + a, 0), 0U) << st.out;
  EXPECT_NE(st.out.find("previous (nccomp model rollback returns to it): " + b), std::string::npos)
      << st.out;
  EXPECT_NE(st.out.find("demoted by shadow rule: live " + b + ", other " + a +
                        "; 5 parts: other better on 5, live better on 0, ties 0, p = 0.03125, "
                        "rms live 3.000 um, other 2.000 um"),
            std::string::npos)
      << st.out;
  EXPECT_NE(daemon.status().find("\"phase\":\"none\""), std::string::npos);
  EXPECT_TRUE(wait_until([&] { return number(daemon.status(), "handovers") >= 2.0; }, 15s));
  EXPECT_EQ(number(daemon.status(), "handovers"), 2.0);
  EXPECT_EQ(daemon.stop(), 0) << daemon.log();
}

// promote = "operator": GIVEN the same daemon, WHEN B passes the rule, THEN it is only announced
// (A stays live, the register stays), `model promote` before that was refused, and the operator's
// `model promote` makes B live with the load's handover and records who did it (B's trim predicts
// the wear the laser measures: the register stays at the measured −5.0 µm).
TEST(NccompModel, WithPromoteOperatorTheRuleAnnouncesAndTheOperatorPromotes) {
  TempDir d;
  NcServer nc(ServerConfig{});
  nc.start();
  nc.update([](Tables& t) { t.input[8] = 1; });
  fs::create_directories(d.path / "a");
  fs::create_directories(d.path / "b");
  std::ofstream(d.path / "a" / "model.toml") << model_text("offset", 0.0, "tool_wear");
  std::ofstream(d.path / "b" / "model.toml") << model_text("offset", 5.0, "tool_wear");
  std::ofstream(d.path / "nccompd.toml")
      << config_text(nc.port(),
                     "kind = \"tool_wear\"\n[model.shadow]\nmin_parts = 5\npromote = "
                     "\"operator\"\n");
  const std::string socket = (d.path / "status.sock").string();
  const std::string a = (d.path / "a" / "model.toml").string();
  const std::string b = (d.path / "b" / "model.toml").string();
  Daemon daemon(d.path);
  ASSERT_TRUE(daemon.start());
  ASSERT_TRUE(wait_until([&] { return number(daemon.status(), "cycles") >= 20; })) << daemon.log();
  std::uint16_t sequence = 0;
  const auto measure = [&](float wear_um) {
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
    return wait_until([&] { return number(daemon.status(), "rows_scored") > before; });
  };
  ASSERT_TRUE(measure(5.0F)) << daemon.log();
  ASSERT_TRUE(wait_until([&] { return holding_i32(nc, kLength) == -50; })) << daemon.log();
  CliRun cand = nccomp_as_root(d, {"model", "candidate", b, "--socket", socket});
  ASSERT_EQ(cand.exit_code, 0) << cand.out << cand.err << daemon.log();
  CliRun early = nccomp_as_root(d, {"model", "promote", "--socket", socket});
  EXPECT_EQ(early.exit_code, 3) << early.out << early.err;
  EXPECT_NE(early.err.find("has not been found better yet (0 of 5 parts scored)"),
            std::string::npos)
      << early.err;
  for (int i = 0; i < 5; ++i) ASSERT_TRUE(measure(5.0F)) << daemon.log();
  ASSERT_TRUE(wait_until([&] {
    return daemon.status().find("\"phase\":\"announced\"") != std::string::npos;
  })) << daemon.status();
  // Announced only: A live, the register where it was.
  std::this_thread::sleep_for(300ms);
  CliRun st = nccomp_as_root(d, {"model", "status", "--socket", socket});
  EXPECT_EQ(st.out.rfind("ok model: " + a, 0), 0U) << st.out;
  EXPECT_NE(st.out.find("announced by shadow rule"), std::string::npos) << st.out;
  // nccomp status: A scored on the measurement before the candidate and the five with it.
  const std::string text = nccomp::client::query(socket, "text");
  EXPECT_NE(text.find("model scores: live 6 parts, mse 25 um^2; announced " + b +
                      " 5 parts, mse 0 um^2, p 0.03125\n"),
            std::string::npos)
      << text;
  EXPECT_EQ(holding_i32(nc, kLength), -50);
  CliRun promote = nccomp_as_root(d, {"model", "promote", "--socket", socket});
  ASSERT_EQ(promote.exit_code, 0) << promote.out << promote.err << daemon.log();
  std::printf("%s", promote.out.c_str());
  EXPECT_EQ(promote.out.rfind("ok model promoted: " + b, 0), 0U) << promote.out;
  EXPECT_NE(promote.out.find("previous (nccomp model rollback returns to it): " + a),
            std::string::npos)
      << promote.out;
  std::this_thread::sleep_for(1500ms);
  EXPECT_EQ(holding_i32(nc, kLength), -50) << daemon.log();
  EXPECT_EQ(number(daemon.status(), "handovers"), 1.0);
  st = nccomp_as_root(d, {"model", "status", "--socket", socket});
  EXPECT_NE(st.out.find("promoted by uid 0 (root)"), std::string::npos) << st.out;
  EXPECT_NE(st.out.find("watching the model the promotion replaced: " + a), std::string::npos)
      << st.out;
  EXPECT_EQ(daemon.stop(), 0) << daemon.log();
}

}  // namespace
