// GIVEN TOML files, WHEN the daemon's loader reads them, THEN every section lands in its typed
// value, and every error names file, line and key path.
#include "daemon/config/config.hpp"

#include <gtest/gtest.h>

#include <sys/wait.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <string>

#include "core/engine/input_lag.hpp"
#include "daemon/config/builtin_sections.hpp"
#include "daemon/sections/creep/creep_section.hpp"

namespace nccomp::daemon::config {

using formats::Diagnostics;
using formats::format;
namespace {

namespace fs = std::filesystem;

class TempDir {
 public:
  TempDir() {
    path_ = fs::temp_directory_path() /
            ("nccomp_cfg_" + std::to_string(::getpid()) + "_" + std::to_string(counter_++));
    fs::create_directories(path_);
  }
  ~TempDir() { fs::remove_all(path_); }
  std::string write(const std::string& name, const std::string& text) const {
    std::ofstream(path_ / name) << text;
    return (path_ / name).string();
  }
  const fs::path& path() const { return path_; }

 private:
  static inline int counter_ = 0;
  fs::path path_;
};

const char* kRegisters = R"(
[loopback]

[[registers]]
name = "T1_length_wear"
kind = "tool_length_wear"
bus = "loopback"
max_abs_um = 200
max_step_um = 5
max_rate_um_per_s = 50
)";

TEST(ConfigLoader, ReadsBuiltinSectionsWithUnitsAndDefaults) {
  TempDir d;
  const auto f = d.write("a.toml", std::string(R"(
[daemon]
rate_hz = 500
dry_run = true
overrun_policy = "restart"
[daemon.realtime]
sched_fifo_priority = 80
cpu_affinity = [1]
lock_memory = true
prefault_stack_kib = 256
[state]
directory = "state"
min_interval_s = 0.25
)") + kRegisters);
  auto r = load_file(f);
  ASSERT_TRUE(r.config) << r.diagnostics.to_string();
  const auto& dm = daemon_section(*r.config);
  EXPECT_DOUBLE_EQ(dm.rate_hz, 500.0);
  EXPECT_TRUE(dm.dry_run);
  EXPECT_EQ(dm.overrun_policy, OverrunPolicy::kRestart);
  EXPECT_EQ(dm.sched_fifo_priority, 80);
  ASSERT_EQ(dm.cpu_affinity.size(), 1U);
  EXPECT_EQ(dm.cpu_affinity[0], 1);
  EXPECT_TRUE(dm.lock_memory);
  EXPECT_EQ(dm.prefault_stack_kib, 256U);
  EXPECT_DOUBLE_EQ(state_section(*r.config).min_interval_s, 0.25);
  EXPECT_EQ(r.config->resolve(state_section(*r.config).directory), (d.path() / "state").string());
  // Absent sections take their defaults.
  EXPECT_EQ(log_section(*r.config).target, "auto");
  EXPECT_EQ(status_section(*r.config).prometheus_port, 0);
  ASSERT_EQ(registers_section(*r.config).registers.size(), 1U);
  const auto& reg = registers_section(*r.config).registers[0];
  EXPECT_EQ(reg.spec.name, "T1_length_wear");
  EXPECT_DOUBLE_EQ(reg.spec.limits.max_rate_um_per_s, 50.0);
  auto engine = build_engine(*r.config);
  EXPECT_EQ(engine->register_count(), 1U);
}

TEST(ConfigLoader, MeasurementLogV2KeysAreReadAndEveryMistakeIsNamed) {
  TempDir d;
  auto r = load_file(d.write("a.toml", std::string(R"([measurement_log]
machine_id = "mill-07"
fsync_interval_s = 0.5
context_columns = [{ name = "spindle_temp_c", sensor = 3 }, { name = "feed_override_pct", sensor = 40 }]
)") + kRegisters));
  ASSERT_TRUE(r.config) << r.diagnostics.to_string();
  const auto& m = measurement_log_section(*r.config);
  EXPECT_EQ(m.machine_id, "mill-07");
  EXPECT_DOUBLE_EQ(m.fsync_interval_s, 0.5);
  ASSERT_EQ(m.context_columns.size(), 2U);
  EXPECT_EQ(m.context_columns[1].name, "feed_override_pct");
  EXPECT_EQ(m.context_columns[1].sensor, 40);

  r = load_file(d.write("b.toml", R"([measurement_log]
machine_id = "mill/07"
context_columns = [
  { name = "Spindle", sensor = 3 },
  { name = "temp_c", sensor = 1 },
  { name = "x_c", sensor = 256 },
  { name = "y_c", sensor = 2, unit = "c" },
  { name = "z_c" },
  { name = "y_c", sensor = 4 },
]
)"));
  ASSERT_FALSE(r.config);
  const auto& items = r.diagnostics.items();
  ASSERT_EQ(items.size(), 7U) << r.diagnostics.to_string();
  EXPECT_EQ(items[0].where.key_path, "measurement_log.machine_id");
  EXPECT_EQ(items[0].where.line, 2);
  EXPECT_NE(items[0].message.find("not a machine id"), std::string::npos) << items[0].message;
  EXPECT_EQ(items[1].where.key_path, "measurement_log.context_columns[0].name");
  EXPECT_NE(items[1].message.find("snake_case"), std::string::npos) << items[1].message;
  EXPECT_EQ(items[2].where.key_path, "measurement_log.context_columns[1].name");
  EXPECT_NE(items[2].message.find("a column of the log already"), std::string::npos);
  EXPECT_EQ(items[3].where.key_path, "measurement_log.context_columns[2].sensor");
  EXPECT_EQ(items[4].where.key_path, "measurement_log.context_columns[3].unit");
  EXPECT_EQ(items[4].message, "unknown key");
  EXPECT_EQ(items[5].where.key_path, "measurement_log.context_columns[4].sensor");
  EXPECT_EQ(items[6].where.key_path, "measurement_log.context_columns[5].name");
  EXPECT_NE(items[6].message.find("named twice"), std::string::npos);
  EXPECT_EQ(items[6].where.line, 9);
}

TEST(ConfigLoader, MeasurementLogFaceProbeIsReadAndItsMistakesAreNamed) {
  TempDir d;
  auto r = load_file(d.write("a.toml", std::string(R"([measurement_log.face_probe]
points_x_mm = [30.0, 30]
points_y_mm = [0.0, 8.0]
capture_radius_mm = 0.5
ball_radius_mm = 3.0
length_register = "T1_length_wear"
radius_register = "T1_length_wear"
)") + kRegisters));
  ASSERT_TRUE(r.config) << r.diagnostics.to_string();
  const auto& m = measurement_log_section(*r.config);
  ASSERT_EQ(m.face_probe_points_mm.size(), 2U);
  EXPECT_DOUBLE_EQ(m.face_probe_points_mm[1][0], 30.0);
  EXPECT_DOUBLE_EQ(m.face_probe_points_mm[1][1], 8.0);
  EXPECT_DOUBLE_EQ(m.face_probe_capture_radius_mm, 0.5);
  EXPECT_DOUBLE_EQ(m.face_probe_ball_radius_mm, 3.0);
  EXPECT_EQ(m.face_probe_length_register, "T1_length_wear");

  r = load_file(d.write("b.toml", std::string(R"([measurement_log.face_probe]
points_x_mm = [30.0, 30.0]
points_y_mm = [0.0]
length_register = "T1_length_wear"
radius_register = "T1_length_wear"
)") + kRegisters));
  ASSERT_FALSE(r.config);
  ASSERT_EQ(r.diagnostics.items().size(), 1U) << r.diagnostics.to_string();
  EXPECT_EQ(r.diagnostics.items()[0].where.key_path, "measurement_log.face_probe.points_y_mm");
  EXPECT_NE(r.diagnostics.items()[0].message.find("got 2 and 1"), std::string::npos);

  // The register names are checked once every section parsed.
  r = load_file(d.write("c.toml", std::string(R"([measurement_log.face_probe]
points_x_mm = [30.0]
points_y_mm = [0.0]
length_register = "T1_length_wear"
radius_register = "T1_radius_wear"
)") + kRegisters));
  ASSERT_FALSE(r.config);
  const auto& items = r.diagnostics.items();
  ASSERT_EQ(items.size(), 1U) << r.diagnostics.to_string();
  EXPECT_EQ(items[0].where.key_path, "measurement_log.face_probe.radius_register");
  EXPECT_EQ(items[0].where.line, 5);
  EXPECT_NE(items[0].message.find("no register named 'T1_radius_wear'"), std::string::npos)
      << items[0].message;
}

TEST(ConfigLoader, UnknownKeyNamesFileLineAndKeyPath) {
  TempDir d;
  const auto f =
      d.write("a.toml", "[daemon]\nrate_hz = 1000\n\n[daemon.realtime]\nlock_memry = true\n");
  auto r = load_file(f);
  ASSERT_FALSE(r.config);
  ASSERT_EQ(r.diagnostics.items().size(), 1U);
  const auto& e = r.diagnostics.items()[0];
  EXPECT_EQ(e.where.file, f);
  EXPECT_EQ(e.where.line, 5);
  EXPECT_EQ(e.where.key_path, "daemon.realtime.lock_memry");
  EXPECT_EQ(e.message, "unknown key");
  EXPECT_EQ(format(e), f + ":5:14: daemon.realtime.lock_memry: unknown key");
}

// The service's user (nccomp) could not read a root-owned /etc/nccompd, and the daemon said
// "no such file" (issue 20): the reason must be the system's. Root reads everything, so as root
// the load runs in a child that drops to nobody.
TEST(ConfigLoader, AFileTheUserMayNotReadIsReportedAsPermissionDenied) {
  TempDir dir;
  const std::string file = dir.write("nccompd.toml", "[daemon]\nrate_hz = 1000\n");
  fs::permissions(file, fs::perms::owner_read | fs::perms::owner_write);
  fs::permissions(dir.path(), fs::perms::owner_all);
  int pipefd[2];
  ASSERT_EQ(::pipe(pipefd), 0);
  const pid_t pid = ::fork();
  ASSERT_GE(pid, 0);
  if (pid == 0) {
    ::close(pipefd[0]);
    if (::geteuid() == 0 && (::setgid(65534) != 0 || ::setuid(65534) != 0)) {
      ::_exit(2);
    }
    const auto r = load_file(file);
    const std::string text = r.config ? "loaded" : r.diagnostics.to_string();
    (void)!::write(pipefd[1], text.data(), text.size());
    ::_exit(0);
  }
  ::close(pipefd[1]);
  std::string text;
  char buf[512];
  for (ssize_t n; (n = ::read(pipefd[0], buf, sizeof(buf))) > 0;) {
    text.append(buf, static_cast<std::size_t>(n));
  }
  ::close(pipefd[0]);
  int st = 0;
  ::waitpid(pid, &st, 0);
  ASSERT_TRUE(WIFEXITED(st) && WEXITSTATUS(st) == 0) << "child could not drop to nobody";
  EXPECT_EQ(text, file + ": cannot read '" + file + "': Permission denied\n");
  fs::permissions(dir.path(), fs::perms::owner_all | fs::perms::group_all | fs::perms::others_all);
}

TEST(ConfigLoader, UnknownSectionListsTheKnownOnes) {
  TempDir d;
  const auto f = d.write("a.toml", "[creeep]\nx = 1\n");
  auto r = load_file(f);
  ASSERT_EQ(r.diagnostics.items().size(), 1U);
  EXPECT_EQ(r.diagnostics.items()[0].where.key_path, "creeep");
  EXPECT_EQ(r.diagnostics.items()[0].where.line, 1);
  const std::string& m = r.diagnostics.items()[0].message;
  EXPECT_EQ(m.rfind("unknown section (known sections: ", 0), 0U) << m;
  EXPECT_NE(m.find("daemon"), std::string::npos) << m;
  EXPECT_NE(m.find("registers"), std::string::npos) << m;
}

TEST(ConfigLoader, CollectsEveryErrorWithItsLine) {
  TempDir d;
  const auto f = d.write("a.toml", R"([daemon]
rate_hz = 0
dry_run = "yes"
overrun_policy = "catch_up"
[daemon.realtime]
sched_fifo_priority = 100
cpu_affinity = [1, "x"]
)");
  auto r = load_file(f);
  ASSERT_FALSE(r.config);
  const auto& items = r.diagnostics.items();
  ASSERT_EQ(items.size(), 5U) << r.diagnostics.to_string();
  EXPECT_EQ(items[0].where.key_path, "daemon.rate_hz");
  EXPECT_EQ(items[0].where.line, 2);
  EXPECT_NE(items[0].message.find("must be a number in [1, 10000]"), std::string::npos);
  EXPECT_EQ(items[1].where.key_path, "daemon.dry_run");
  EXPECT_EQ(items[1].message, "must be true or false");
  EXPECT_EQ(items[2].where.key_path, "daemon.overrun_policy");
  EXPECT_EQ(items[2].where.line, 4);
  EXPECT_EQ(items[3].where.key_path, "daemon.realtime.sched_fifo_priority");
  EXPECT_EQ(items[4].where.key_path, "daemon.realtime.cpu_affinity[1]");
  EXPECT_EQ(items[4].where.line, 7);
}

TEST(ConfigLoader, MissingRequiredKeyInArrayOfTables) {
  TempDir d;
  const auto f = d.write("a.toml", R"([loopback]
[[registers]]
name = "a"
kind = "tool_length_wear"
bus = "loopback"
max_abs_um = 200
max_step_um = 5
[[registers]]
name = "a"
kind = "wear"
bus = "loopback"
max_abs_um = 200
max_step_um = 5
max_rate_um_per_s = 50
)");
  auto r = load_file(f);
  const auto& items = r.diagnostics.items();
  ASSERT_EQ(items.size(), 3U) << r.diagnostics.to_string();
  EXPECT_EQ(items[0].where.key_path, "registers[0].max_rate_um_per_s");
  EXPECT_EQ(items[0].message, "missing required key");
  EXPECT_EQ(items[1].where.key_path, "registers[1].name");
  EXPECT_EQ(items[1].where.line, 9);
  EXPECT_EQ(items[2].where.key_path, "registers[1].kind");
}

TEST(ConfigLoader, IncludesResolveRelativeToTheIncludingFile) {
  TempDir d;
  fs::create_directories(d.path() / "sub");
  d.write("sub/regs.toml", std::string("include = [\"more.toml\"]\n") + kRegisters);
  d.write("sub/more.toml", "[status]\nprometheus_port = 9464\n");
  const auto f = d.write("main.toml", "include = [\"sub/regs.toml\"]\n[daemon]\nrate_hz = 250\n");
  auto r = load_file(f);
  ASSERT_TRUE(r.config) << r.diagnostics.to_string();
  EXPECT_EQ(r.config->files().size(), 3U);
  EXPECT_EQ(status_section(*r.config).prometheus_port, 9464);
  EXPECT_EQ(registers_section(*r.config).registers.size(), 1U);
}

TEST(ConfigLoader, StatusAdminGroupAndClientLimits) {
  TempDir d;
  auto defaults = load_file(d.write("a.toml", "[status]\nsocket_path = \"s.sock\"\n"));
  ASSERT_TRUE(defaults.config) << defaults.diagnostics.to_string();
  EXPECT_EQ(status_section(*defaults.config).admin_group, "nccomp-admin");
  EXPECT_DOUBLE_EQ(status_section(*defaults.config).client_timeout_s, 2.0);
  EXPECT_EQ(status_section(*defaults.config).max_clients, 32);
  auto set = load_file(d.write(
      "b.toml",
      "[status]\nadmin_group = \"cnc_setters\"\nclient_timeout_s = 0.5\nmax_clients = 4\n"));
  ASSERT_TRUE(set.config) << set.diagnostics.to_string();
  EXPECT_EQ(status_section(*set.config).admin_group, "cnc_setters");
  EXPECT_DOUBLE_EQ(status_section(*set.config).client_timeout_s, 0.5);
  EXPECT_EQ(status_section(*set.config).max_clients, 4);
  const auto f = d.write("c.toml",
                         "[status]\nadmin_group = \"cnc setters\"\nclient_timeout_s = 0\n"
                         "max_clients = 0\n");
  auto bad = load_file(f);
  EXPECT_FALSE(bad.config);
  const auto& items = bad.diagnostics.items();
  ASSERT_EQ(items.size(), 3U) << bad.diagnostics.to_string();
  EXPECT_EQ(items[0].where.file, f);
  EXPECT_EQ(items[0].where.line, 2);
  EXPECT_EQ(items[0].where.key_path, "status.admin_group");
  EXPECT_NE(items[0].message.find("must be a group name"), std::string::npos) << items[0].message;
  EXPECT_EQ(items[1].where.key_path, "status.client_timeout_s");
  EXPECT_EQ(items[2].where.key_path, "status.max_clients");
}

TEST(ConfigLoader, ErrorsInIncludedFilesNameThatFile) {
  TempDir d;
  const auto inc = d.write("inc.toml", "[status]\n\nprometheus_port = 70000\n");
  const auto f = d.write("main.toml", "include = [\"inc.toml\", \"missing.toml\"]\n");
  auto r = load_file(f);
  const auto& items = r.diagnostics.items();
  ASSERT_EQ(items.size(), 2U) << r.diagnostics.to_string();
  EXPECT_EQ(items[0].where.file, f);
  EXPECT_EQ(items[0].where.key_path, "include[1]");
  EXPECT_NE(items[0].message.find("missing.toml"), std::string::npos);
  EXPECT_EQ(items[1].where.file, inc);
  EXPECT_EQ(items[1].where.line, 3);
  EXPECT_EQ(items[1].where.key_path, "status.prometheus_port");
}

TEST(ConfigLoader, KeyDefinedInTwoFilesIsAnErrorNamingBothPlaces) {
  TempDir d;
  const auto inc = d.write("inc.toml", "[daemon]\nrate_hz = 100\n");
  const auto f = d.write("main.toml", "include = [\"inc.toml\"]\n[daemon]\n\nrate_hz = 200\n");
  auto r = load_file(f);
  ASSERT_EQ(r.diagnostics.items().size(), 1U) << r.diagnostics.to_string();
  const auto& e = r.diagnostics.items()[0];
  EXPECT_EQ(e.where.file, inc);
  EXPECT_EQ(e.where.line, 2);
  EXPECT_EQ(e.where.key_path, "daemon.rate_hz");
  EXPECT_EQ(e.message, "key is already defined at " + f + ":4");
}

TEST(ConfigLoader, TopLevelArrayOfTablesInTwoFilesIsAnError) {
  TempDir d;
  d.write("inc.toml", std::string(kRegisters));
  const auto f = d.write("main.toml", std::string("include = [\"inc.toml\"]\n") +
                                          "[[registers]]\nname = \"x\"\nkind = \"checkpoint\"\n");
  auto r = load_file(f);
  ASSERT_FALSE(r.config);
  EXPECT_NE(r.diagnostics.to_string().find("registers: section is already defined at " + f),
            std::string::npos)
      << r.diagnostics.to_string();
}

// A section may be split over files: [daemon] in the main file, [daemon.realtime] in an included
// one; the keys of both arrive, errors in either part name their own file.
TEST(ConfigLoader, SectionSplitOverFilesIsMerged) {
  TempDir d;
  fs::create_directories(d.path() / "rt");
  const auto inc = d.write("rt/realtime.toml",
                           "[daemon.realtime]\nsched_fifo_priority = 70\nlock_memory = true\n");
  const auto f = d.write("main.toml", std::string("include = [\"rt/realtime.toml\"]\n") +
                                          "[daemon]\nrate_hz = 250\n" + kRegisters);
  auto r = load_file(f);
  ASSERT_TRUE(r.config) << r.diagnostics.to_string();
  EXPECT_DOUBLE_EQ(daemon_section(*r.config).rate_hz, 250.0);
  EXPECT_EQ(daemon_section(*r.config).sched_fifo_priority, 70);
  EXPECT_TRUE(daemon_section(*r.config).lock_memory);

  d.write("rt/realtime.toml", "[daemon.realtime]\nsched_fifo_priority = 70\nlock_memry = true\n");
  auto bad = load_file(f);
  ASSERT_EQ(bad.diagnostics.items().size(), 1U) << bad.diagnostics.to_string();
  EXPECT_EQ(bad.diagnostics.items()[0].where.file, inc);
  EXPECT_EQ(bad.diagnostics.items()[0].where.line, 3);
  EXPECT_EQ(bad.diagnostics.items()[0].where.key_path, "daemon.realtime.lock_memry");
}

// Edge-wear (deflection) tables in their own files, one per tool: [[creep.deflection]] entries of
// several included files are appended in include order; an error in one names its own file.
TEST(ConfigLoader, CreepDeflectionTablesFromIncludedFiles) {
  TempDir d;
  fs::create_directories(d.path() / "tables");
  d.write("tables/t1.toml",
          "# tool 1\n[[creep.deflection]]\ntool = 1\nwear_um = [0.0, 20.0]\n"
          "normal_um = [0.0, 1.5]\nlateral_um = [0.0, 0.0]\n");
  const auto t2 = d.write("tables/t2.toml",
                          "[[creep.deflection]]\ntool = 2\nwear_um = [0.0, 10.0, 30.0]\n"
                          "normal_um = [0.0, 0.5, 2.0]\nlateral_um = [0.0, 0.0, 0.25]\n");
  const std::string main_text = std::string(R"(include = ["tables/t1.toml", "tables/t2.toml"]
[loopback]
[[registers]]
name = "Z_wear"
kind = "axis_offset"
bus = "loopback"
max_abs_um = 200
max_step_um = 5
max_rate_um_per_s = 50
[creep]
creep_length_mm = 100.0
[creep.edge]
tool_shape = "tip"
normal_source = "none"
[creep.output]
z_register = "Z_wear"
)");
  const auto f = d.write("main.toml", main_text);
  auto r = load_file(f);
  ASSERT_TRUE(r.config) << r.diagnostics.to_string();
  const auto* creep = sections::creep_section(*r.config);
  ASSERT_NE(creep, nullptr);
  const auto& tables = creep->module.creep.deflection;
  ASSERT_EQ(tables.size(), 2U);
  EXPECT_EQ(tables[0].tool, 1);
  EXPECT_EQ(tables[1].tool, 2);
  ASSERT_EQ(tables[1].normal_um.size(), 3U);
  EXPECT_DOUBLE_EQ(tables[1].normal_um[2], 2.0);
  EXPECT_DOUBLE_EQ(creep->module.creep.creep_length_mm, 100.0);
  EXPECT_NO_THROW((void)build_engine(*r.config));

  // wear_um not increasing in the second file: the error is there, at its own line.
  d.write("tables/t2.toml",
          "[[creep.deflection]]\ntool = 2\nwear_um = [0.0, 30.0, 10.0]\n"
          "normal_um = [0.0, 0.5, 2.0]\nlateral_um = [0.0, 0.0, 0.25]\n");
  auto bad = load_file(f);
  ASSERT_FALSE(bad.config);
  ASSERT_GE(bad.diagnostics.items().size(), 1U);
  const auto& e = bad.diagnostics.items()[0];
  EXPECT_EQ(e.where.file, t2) << bad.diagnostics.to_string();
  EXPECT_EQ(e.where.line, 3) << bad.diagnostics.to_string();
  EXPECT_EQ(e.where.key_path.rfind("creep.deflection[1].wear_um", 0), 0U)
      << bad.diagnostics.to_string();
}

// An engine-level refusal (two modules writing one register) names file, line and key: the key
// of the second module that names the register, and where the register and the first module are.
TEST(ConfigEngine, TwoModulesOnOneRegisterNameFileLineAndKey) {
  TempDir d;
  const auto f = d.write("a.toml", R"(include = ["calibration.toml"]
[loopback]
[[registers]]
name = "X_off"
kind = "axis_offset"
bus = "loopback"
max_abs_um = 100
max_step_um = 5
max_rate_um_per_s = 20
[[registers]]
name = "Y_off"
kind = "axis_offset"
bus = "loopback"
max_abs_um = 100
max_step_um = 5
max_rate_um_per_s = 20
[[registers]]
name = "Z_off"
kind = "axis_offset"
bus = "loopback"
max_abs_um = 100
max_step_um = 5
max_rate_um_per_s = 20
[creep]
[creep.edge]
tool_shape = "tip"
normal_source = "none"
[creep.output]
z_register = "Z_off"
)");
  const auto cal = d.write("calibration.toml", R"([calibration]
register_x = 0
register_y = 1
register_z = 2
)");
  auto r = load_file(f);
  ASSERT_TRUE(r.config) << r.diagnostics.to_string();
  Diagnostics diag;
  EXPECT_EQ(build_engine(*r.config, diag), nullptr);
  ASSERT_EQ(diag.items().size(), 1U) << diag.to_string();
  const auto& e = diag.items()[0];
  // Modules are built in section order: calibration first, then creep.
  EXPECT_EQ(e.where.file, f);
  EXPECT_EQ(e.where.line, 29);
  EXPECT_EQ(e.where.key_path, "creep.output.z_register");
  EXPECT_EQ(e.message, "register 'Z_off' (registers[2], " + f +
                           ":17) is written by module 'calibration' (calibration.register_z, " +
                           cal + ":4) and by 'creep'; give each module its own registers");
}

TEST(ConfigLoader, IncludeCycleIsDetected) {
  TempDir d;
  d.write("b.toml", "include = [\"a.toml\"]\n");
  const auto f = d.write("a.toml", "include = [\"b.toml\"]\n");
  auto r = load_file(f);
  ASSERT_EQ(r.diagnostics.items().size(), 1U) << r.diagnostics.to_string();
  EXPECT_NE(r.diagnostics.items()[0].message.find("included twice"), std::string::npos);
}

TEST(ConfigLoader, SyntaxErrorNamesLineAndColumn) {
  TempDir d;
  const auto f = d.write("a.toml", "[daemon]\nrate_hz = = 3\n");
  auto r = load_file(f);
  ASSERT_EQ(r.diagnostics.items().size(), 1U);
  EXPECT_EQ(r.diagnostics.items()[0].where.file, f);
  EXPECT_EQ(r.diagnostics.items()[0].where.line, 2);
  EXPECT_NE(r.diagnostics.items()[0].message.find("TOML syntax error"), std::string::npos);
}

TEST(ConfigLoader, CrossChecksBusAndRampReferences) {
  TempDir d;
  const auto f = d.write("a.toml", std::string(kRegisters) + R"(
[[registers]]
name = "r2"
kind = "checkpoint"
bus = "modbus"
max_abs_um = 100
max_step_um = 5
max_rate_um_per_s = 50

[[ramp]]
name = "commissioning"
register = "T2_length_wear"
target_um = 10
rate_um_per_s = 1
)");
  auto r = load_file(f);
  const auto& items = r.diagnostics.items();
  ASSERT_EQ(items.size(), 2U) << r.diagnostics.to_string();
  // Sorted by section name: ramp before registers.
  EXPECT_EQ(items[0].where.key_path, "ramp[0].register");
  EXPECT_EQ(items[1].where.key_path, "registers[1].bus");
  EXPECT_EQ(items[1].where.line, 12);
  EXPECT_NE(items[1].message.find("buses: loopback"), std::string::npos);
}

TEST(ConfigLoader, RampBuildsAModuleOnItsRegister) {
  TempDir d;
  const auto f = d.write("a.toml", std::string(kRegisters) + R"(
[[ramp]]
name = "commissioning"
register = "T1_length_wear"
target_um = 10
rate_um_per_s = 1
)");
  auto r = load_file(f);
  ASSERT_TRUE(r.config) << r.diagnostics.to_string();
  auto e = build_engine(*r.config);
  ASSERT_EQ(e->module_count(), 1U);
  EXPECT_EQ(e->module(0).name(), "ramp/commissioning");
}

TEST(ConfigLoader, InputLagsBuildTheEngineLagsAndAStatusModule) {
  TempDir d;
  const auto f = d.write("a.toml", std::string(kRegisters) + R"(
[[input_lags]]
sensor = 40
input_sensor = 5
tau_s = 1800
)");
  auto r = load_file(f);
  ASSERT_TRUE(r.config) << r.diagnostics.to_string();
  auto e = build_engine(*r.config);
  ASSERT_EQ(e->input_lags().size(), 1U);
  EXPECT_EQ(e->input_lags().spec(0).input_sensor, 5);
  EXPECT_EQ(e->input_lags().spec(0).output_sensor, 40);
  EXPECT_DOUBLE_EQ(e->input_lags().spec(0).tau_s, 1800.0);
  ASSERT_EQ(e->module_count(), 1U);
  EXPECT_EQ(e->module(0).name(), "input_lags");
  // Its status: the lag's value once its input has a sample, then its input's.
  core::StepOutput out;
  const std::vector<core::Event> in{core::TemperatureSample{0, 5, 21.5}};
  e->step(0, in, out);
  std::array<core::engine::StatusValue, 4> st{};
  ASSERT_EQ(e->module(0).status(st), 2U);
  EXPECT_STREQ(st[0].key, "sensor_40_lag");
  EXPECT_DOUBLE_EQ(st[0].value, 21.5);
  EXPECT_STREQ(st[1].key, "sensor_40_input");
  EXPECT_DOUBLE_EQ(st[1].value, 21.5);
}

TEST(ConfigLoader, InputLagErrorsNameFileLineAndKey) {
  TempDir d;
  const auto f = d.write("a.toml", std::string(kRegisters) + R"(
[[input_lags]]
sensor = 40
input_sensor = 5
tau_s = 0

[[input_lags]]
sensor = 40
input_sensor = 6
tau_s = 60

[[input_lags]]
sensor = 7
input_sensor = 7
tau_s = nan

[[input_lags]]
sensor = 41
input_sensor = 40
tau_s = 60
)");
  auto r = load_file(f);
  const auto& items = r.diagnostics.items();
  // Sensor 40 is the lag of both earlier entries: two errors for input_lags[3].
  ASSERT_EQ(items.size(), 6U) << r.diagnostics.to_string();
  EXPECT_EQ(items[0].where.key_path, "input_lags[0].tau_s");
  EXPECT_EQ(items[0].where.line, 15);
  EXPECT_EQ(items[1].where.key_path, "input_lags[1].sensor");
  EXPECT_NE(items[1].message.find("already the lag of input_lags[0]"), std::string::npos);
  EXPECT_EQ(items[2].where.key_path, "input_lags[2].tau_s");
  EXPECT_EQ(items[3].where.key_path, "input_lags[2].sensor");
  EXPECT_NE(items[3].message.find("equals input_sensor"), std::string::npos);
  EXPECT_EQ(items[4].where.key_path, "input_lags[3].sensor");
  EXPECT_NE(items[4].message.find("a lag of a lag"), std::string::npos);
  EXPECT_EQ(items[5].where.key_path, "input_lags[3].sensor");
  EXPECT_NE(r.diagnostics.to_string().find("a.toml:28:10: input_lags[3].sensor"), std::string::npos)
      << r.diagnostics.to_string();
}

// Every [[section]] of the daemon's config is an array of tables: a plain table, or more
// entries than the engine computes, is refused naming the section and its line.
TEST(ConfigLoader, ArraysOfTablesRefuseAPlainTableAndTooManyEntries) {
  TempDir d;
  for (const std::string section : {"registers", "ramp", "input_lags", "input_sums"}) {
    const auto f = d.write(section + ".toml", "[" + section + "]\nsensor = 40\n");
    const auto r = load_file(f);
    EXPECT_NE(r.diagnostics.to_string().find(section + ".toml:1:1: " + section +
                                             ": must be an array of tables ([[" + section + "]])"),
              std::string::npos)
        << r.diagnostics.to_string();
  }
  std::string lags = kRegisters;
  for (std::size_t i = 0; i <= nccomp::core::engine::kMaxInputLags; ++i) {
    lags +=
        "[[input_lags]]\nsensor = " + std::to_string(100 + i) + "\ninput_sensor = 5\ntau_s = 60\n";
  }
  const auto r = load_file(d.write("lags.toml", lags));
  EXPECT_NE(r.diagnostics.to_string().find("input_lags: at most " +
                                           std::to_string(nccomp::core::engine::kMaxInputLags) +
                                           " entries"),
            std::string::npos)
      << r.diagnostics.to_string();
}

TEST(ConfigLoader, InputSumsBuildTheEngineSumsAndAStatusModule) {
  TempDir d;
  const auto f = d.write("a.toml", std::string(kRegisters) + R"(
[[input_lags]]
sensor = 40
input_sensor = 5
tau_s = 1800

[[input_sums]]
sensor = 60
offset = -12.5
inputs = [1, 2, 40]
weights = [0.8, -1.2, 3]

[[input_sums]]
sensor = 61
inputs = [5]
weights = [2]
)");
  auto r = load_file(f);
  ASSERT_TRUE(r.config) << r.diagnostics.to_string();
  auto e = build_engine(*r.config);
  const auto& sums = e->input_sums();
  ASSERT_EQ(sums.size(), 2U);
  EXPECT_EQ(sums.output_sensor(0), 60);
  EXPECT_DOUBLE_EQ(sums.offset(0), -12.5);
  ASSERT_EQ(sums.input_count(0), 3U);
  EXPECT_EQ(sums.input_sensor(0, 2), 40);
  EXPECT_DOUBLE_EQ(sums.weight(0, 1), -1.2);
  EXPECT_DOUBLE_EQ(sums.weight(0, 2), 3.0);
  EXPECT_EQ(sums.output_sensor(1), 61);
  EXPECT_DOUBLE_EQ(sums.offset(1), 0.0);  // the default
  ASSERT_EQ(e->module_count(), 2U);
  EXPECT_EQ(e->module(1).name(), "input_sums");
  // Its status: each sum's value once every input has a sample (sensor 40, the lag of sensor 5,
  // starts at 5's first value in the same cycle).
  core::StepOutput out;
  std::array<core::engine::StatusValue, 4> st{};
  e->step(0, std::vector<core::Event>{core::TemperatureSample{0, 5, 21.0}}, out);
  ASSERT_EQ(e->module(1).status(st), 1U);
  EXPECT_STREQ(st[0].key, "sensor_61_sum");
  EXPECT_DOUBLE_EQ(st[0].value, 42.0);
  e->step(1,
          std::vector<core::Event>{core::TemperatureSample{1, 1, 20.0},
                                   core::TemperatureSample{1, 2, 10.0}},
          out);
  ASSERT_EQ(e->module(1).status(st), 2U);
  EXPECT_STREQ(st[0].key, "sensor_60_sum");
  EXPECT_NEAR(st[0].value, -12.5 + 16.0 - 12.0 + 3.0 * 21.0, 1e-9);
  EXPECT_STREQ(st[1].key, "sensor_61_sum");
}

TEST(ConfigLoader, InputSumErrorsNameFileLineAndKey) {
  TempDir d;
  const auto f = d.write("a.toml", std::string(kRegisters) + R"(
[[input_sums]]
sensor = 60
inputs = [1, 2]
weights = [1.0]

[[input_sums]]
sensor = 61
inputs = [1, 61, 1]
weights = [1, 2, 3]
offset = nan

[[input_sums]]
sensor = 60
inputs = []
weights = []

[[input_sums]]
sensor = 62
inputs = [60, "x"]
weights = [1, inf]

[[input_sums]]
sensor = 40
weights = [1]

[[input_sums]]
sensor = 5
inputs = [1]
weights = [1]
gain = 2

[[input_lags]]
sensor = 40
input_sensor = 5
tau_s = 60
)");
  auto r = load_file(f);
  EXPECT_FALSE(r.config);
  const std::string all = r.diagnostics.to_string();
  // Each expected error once, at its file:line:column and key; nothing else.
  const std::vector<std::string> expected{
      "a.toml:15:11: input_sums[0].weights: 1 weights for 2 inputs",
      "a.toml:21:10: input_sums[1].offset: must be a number",
      "a.toml:18:10: input_sums[1].sensor: is one of its inputs (inputs[1])",
      "a.toml:19:10: input_sums[1].inputs: sensor 1 is listed twice (inputs[0] and inputs[2])",
      "a.toml:25:10: input_sums[2].inputs: must name 1 to 32 sensors, got 0",
      "a.toml:24:10: input_sums[2].sensor: sensor 60 is already the sum of input_sums[0]",
      "a.toml:30:15: input_sums[3].inputs[1]: must be an integer",
      "a.toml:31:15: input_sums[3].weights[1]: must be a number",
      "a.toml:29:10: input_sums[3].sensor: a sum of a sum (input_sums[0])",
      "a.toml:29:10: input_sums[3].sensor: a sum of a sum (input_sums[2])",
      "a.toml:33:1: input_sums[4].inputs: missing required key",
      "a.toml:41:8: input_sums[5].gain: unknown key",
  };
  for (const auto& x : expected) {
    EXPECT_NE(all.find(x), std::string::npos) << "missing: " << x << "\nin:\n" << all;
  }
  EXPECT_EQ(r.diagnostics.items().size(), expected.size()) << all;

  // Against [[input_lags]] (checked once every section parsed): a sum on a lag's sensor, and a
  // lag of a sum (the lags are computed first). A sum of a lag is fine (the test above).
  const auto g = d.write("b.toml", std::string(kRegisters) + R"(
[[input_sums]]
sensor = 40
inputs = [1]
weights = [1]

[[input_sums]]
sensor = 5
inputs = [1, 2]
weights = [1, 2]

[[input_lags]]
sensor = 40
input_sensor = 5
tau_s = 60
)");
  auto r2 = load_file(g);
  EXPECT_FALSE(r2.config);
  const std::string all2 = r2.diagnostics.to_string();
  ASSERT_EQ(r2.diagnostics.items().size(), 2U) << all2;
  EXPECT_NE(all2.find("b.toml:13:10: input_sums[0].sensor: sensor 40 is already the lag of "
                      "input_lags[0]"),
            std::string::npos)
      << all2;
  EXPECT_NE(all2.find("b.toml:18:10: input_sums[1].sensor: a lag of a sum (input_lags[0])"),
            std::string::npos)
      << all2;
}

// The shipped examples load, with the bus sections registered (daemon/sections/modbus, can).
TEST(ConfigExamples, ShippedConfigsLoad) {
  auto loop = load_file(std::string(NCCOMP_SOURCE_DIR) + "/config/nccompd-loopback.toml");
  ASSERT_TRUE(loop.config) << loop.diagnostics.to_string();
  EXPECT_NO_THROW((void)build_engine(*loop.config));
  auto main = load_file(std::string(NCCOMP_SOURCE_DIR) + "/config/nccompd.toml");
  ASSERT_TRUE(main.config) << main.diagnostics.to_string();
  EXPECT_TRUE(main.config->has("modbus"));
  EXPECT_NO_THROW((void)build_engine(*main.config));
}

}  // namespace
}  // namespace nccomp::daemon::config
