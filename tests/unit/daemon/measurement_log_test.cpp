// GIVEN measurement records, WHEN the writer thread logs them, THEN the CSV has the v2 header
// (formats/measurement_log), UTC derived from the record's monotonic time, whole rows only (a
// partial row left by a crash is cut when the file is opened again), and rotates by size keeping
// keep_files files.
#include "daemon/measurement_log.hpp"

#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <csignal>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <sstream>
#include <thread>
#include <vector>

#include "tests/support/alloc_counter.hpp"

namespace nccomp::daemon {
namespace {

namespace fs = std::filesystem;
namespace ml = formats::measurement_log;

struct TempDir {
  fs::path path;
  explicit TempDir(const std::string& name)
      : path(fs::temp_directory_path() / (name + "_" + std::to_string(::getpid()))) {
    fs::remove_all(path);
  }
  ~TempDir() { fs::remove_all(path); }
};

std::vector<std::string> read_lines(const fs::path& p) {
  std::ifstream in(p);
  std::vector<std::string> lines;
  for (std::string l; std::getline(in, l);) lines.push_back(l);
  return lines;
}

std::size_t fields(const std::string& line) {
  return static_cast<std::size_t>(std::count(line.begin(), line.end(), ',')) + 1;
}

void push(MeasurementLogWriter& w, const core::MeasurementRecord& r) {
  while (!w.ring().try_push(r)) std::this_thread::sleep_for(std::chrono::milliseconds(1));
}

std::int64_t now_ns(clockid_t id) {
  timespec ts{};
  clock_gettime(id, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * 1'000'000'000 + ts.tv_nsec;
}

TEST(MeasurementLog, UtcComesFromTheRecordsMonotonicTimeNotFromTheTimeOfWriting) {
  TempDir dir("nccomp_mlog_utc");
  MeasurementLogOptions o;
  o.directory = dir.path.string();
  o.machine_id = "m1";
  MeasurementLogWriter w(o);
  w.start();
  // A record measured 90 s ago (monotonic clock): its utc is 90 s before now, not now.
  core::MeasurementRecord r;
  r.clock_ns = now_ns(CLOCK_MONOTONIC) - 90'000'000'000;
  const std::int64_t expected_ns = now_ns(CLOCK_REALTIME) - 90'000'000'000;
  push(w, r);
  w.stop();
  const auto lines = read_lines(dir.path / "measurements.csv");
  ASSERT_EQ(lines.size(), 2U);
  std::tm tm{};
  int ms = 0;
  const std::size_t at = lines[1].find(",m1,") + 4;
  ASSERT_NE(at, std::string::npos + 4);
  std::istringstream in(lines[1].substr(at, 24));
  in >> std::get_time(&tm, "%Y-%m-%dT%H:%M:%S");
  ASSERT_FALSE(in.fail()) << lines[1];
  in.ignore(1);
  in >> ms;
  const std::int64_t got_ns = (static_cast<std::int64_t>(timegm(&tm)) * 1000 + ms) * 1'000'000;
  EXPECT_NEAR(static_cast<double>(got_ns - expected_ns) / 1e9, 0.0, 1.0) << lines[1];
}

TEST(MeasurementLog, StampFillsTheContextColumnsFromTheMachineContextWithoutAllocating) {
  MeasurementLogOptions o;
  o.directory = "unused";
  o.context_columns = {{"spindle_rpm", 7}, {"bed_temp_c", 1}, {"never_c", 9}};
  MeasurementLogWriter w(o);
  core::engine::MachineContext c;
  const std::vector<core::Event> ev = {core::TemperatureSample{0, 7, 8000.0},
                                       core::TemperatureSample{0, 1, 21.5}};
  c.update(0, ev);
  core::MeasurementRecord r;
  {
    const nccomp::test::AllocationScope scope;
    w.stamp(r, c);
    EXPECT_EQ(scope.count(), 0U);
    EXPECT_EQ(scope.frees(), 0U);
  }
  EXPECT_DOUBLE_EQ(r.context[0], 8000.0);
  EXPECT_DOUBLE_EQ(r.context[1], 21.5);
  EXPECT_TRUE(std::isnan(r.context[2]));  // no sample yet: an empty cell
  EXPECT_TRUE(std::isnan(r.context[3]));
  o.context_columns.resize(core::kMaxContextValues + 1, {"x", 0});
  EXPECT_THROW(MeasurementLogWriter{o}, std::invalid_argument);
}

TEST(MeasurementLog, RotatesBySizeAndKeepsHeaderInEveryFile) {
  TempDir dir("nccomp_mlog");
  {
    MeasurementLogWriter w(dir.path.string(), 4096, 2, 1024);
    w.start();
    core::MeasurementRecord r;
    r.kind = core::MeasurementKind::kToolWear;
    for (int i = 0; i < 300; ++i) {
      r.time_ns = i * 1'000'000'000LL;
      r.point = i;
      push(w, r);
    }
    w.stop();
    EXPECT_EQ(w.rows(), 300U);
    EXPECT_GE(w.rotations(), 3U);
    EXPECT_EQ(w.errors(), 0U);
  }
  EXPECT_TRUE(fs::exists(dir.path / "measurements.csv"));
  EXPECT_TRUE(fs::exists(dir.path / "measurements.csv.1"));
  EXPECT_TRUE(fs::exists(dir.path / "measurements.csv.2"));
  EXPECT_FALSE(fs::exists(dir.path / "measurements.csv.3"));
  const std::string header = ml::csv_header({});
  for (const char* name : {"measurements.csv", "measurements.csv.1", "measurements.csv.2"}) {
    const auto lines = read_lines(dir.path / name);
    ASSERT_FALSE(lines.empty()) << name;
    EXPECT_EQ(lines[0], header) << name;
    EXPECT_LE(fs::file_size(dir.path / name), 4096U) << name;
    // Rotation never splits a row: every row has the header's field count.
    for (std::size_t i = 1; i < lines.size(); ++i) {
      EXPECT_EQ(fields(lines[i]), fields(header)) << name << ":" << i + 1 << ": " << lines[i];
    }
  }
  // The newest rows are in the current file: its last row is point 299.
  const auto current = read_lines(dir.path / "measurements.csv");
  EXPECT_EQ(current.back().rfind("299.000000,0,0,tool_wear,299,", 0), 0U) << current.back();
}

TEST(MeasurementLog, AV1FileOrOtherColumnsAreRotatedAwayNotAppendedTo) {
  TempDir dir("nccomp_mlog_v1");
  fs::create_directories(dir.path);
  {
    std::ofstream v1(dir.path / "measurements.csv");
    v1 << ml::kV1Header << "\n1.000000,0,0,tool_wear,0,,,,,,,1.0000,0.0000\n";
  }
  MeasurementLogOptions o;
  o.directory = dir.path.string();
  o.machine_id = "m1";
  o.context_columns = {{"bed_temp_c", 1}};
  {
    MeasurementLogWriter w(o);
    w.start();
    core::MeasurementRecord r;
    r.time_ns = 5'000'000'000;
    push(w, r);
    w.stop();
    EXPECT_EQ(w.rotations(), 1U);
  }
  const auto old = read_lines(dir.path / "measurements.csv.1");
  ASSERT_EQ(old.size(), 2U);
  EXPECT_EQ(old[0], ml::kV1Header);
  const auto now = read_lines(dir.path / "measurements.csv");
  ASSERT_EQ(now.size(), 2U);
  EXPECT_EQ(now[0], std::string(ml::kV1Header) + ",machine,utc,session,bed_temp_c");
  EXPECT_EQ(now[1].rfind("5.000000,", 0), 0U);
  EXPECT_EQ(fields(now[1]), fields(now[0]));
  // The same columns again: a restart appends.
  {
    MeasurementLogWriter w(o);
    w.start();
    core::MeasurementRecord r;
    r.time_ns = 6'000'000'000;
    push(w, r);
    w.stop();
    EXPECT_EQ(w.rotations(), 0U);
  }
  EXPECT_EQ(read_lines(dir.path / "measurements.csv").size(), 3U);
}

TEST(MeasurementLog, APartialRowLeftByACrashIsCutWhenTheFileIsOpened) {
  TempDir dir("nccomp_mlog_cut");
  fs::create_directories(dir.path);
  const std::string header = ml::csv_header({});
  {
    std::ofstream f(dir.path / "measurements.csv");
    f << header << "\n1.000000,0,0,tool_wear,0,,,,,,,1.0000,0.0000,m,2024-01-01T00:00:00.000Z,0\n"
      << "2.000000,0,0,tool_wear,1,,,,,,,1.00";  // the crash
  }
  MeasurementLogWriter w(dir.path.string(), 1 << 20, 2);
  w.start();
  core::MeasurementRecord r;
  r.time_ns = 3'000'000'000;
  r.point = 2;
  push(w, r);
  w.stop();
  EXPECT_EQ(w.errors(), 1U);  // the cut is counted
  const auto lines = read_lines(dir.path / "measurements.csv");
  ASSERT_EQ(lines.size(), 3U);
  EXPECT_EQ(lines[1].rfind("1.000000,", 0), 0U);
  EXPECT_EQ(lines[2].rfind("3.000000,0,0,tool_wear,2,", 0), 0U) << lines[2];
  EXPECT_EQ(fields(lines[2]), fields(header));
}

TEST(MeasurementLog, AKilledWriterLeavesOnlyWholeRowsAndLosesAtMostTheUnwrittenOnes) {
  // A child process logs rows as fast as it can and is killed (SIGKILL) in the middle; the
  // parent then reopens the log. The rows are the first n ones in order (nothing skipped), and
  // after a restart every line is a whole row.
  TempDir dir("nccomp_mlog_kill");
  const std::string header = ml::csv_header({{"a_c", 0}});
  const pid_t pid = ::fork();
  ASSERT_GE(pid, 0);
  if (pid == 0) {
    MeasurementLogOptions o;
    o.directory = dir.path.string();
    o.machine_id = "m";
    o.context_columns = {{"a_c", 0}};
    o.max_file_bytes = std::uint64_t{1} << 30;
    MeasurementLogWriter w(o);
    w.start();
    core::MeasurementRecord r;
    for (int i = 0;; ++i) {
      r.time_ns = i * 1'000'000LL;
      r.point = i;
      push(w, r);
    }
  }
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  ::kill(pid, SIGKILL);
  int status = 0;
  ::waitpid(pid, &status, 0);
  auto lines = read_lines(dir.path / "measurements.csv");
  ASSERT_GT(lines.size(), 2U);
  ASSERT_EQ(lines[0], header);
  // The kill may cut the write in progress (the kernel stops a write for a fatal signal): only
  // the last line may be partial.
  for (std::size_t i = 1; i + 1 < lines.size(); ++i) {
    ASSERT_EQ(fields(lines[i]), fields(header)) << i + 1 << ": " << lines[i];
    const std::string point = "," + std::to_string(i - 1) + ",";
    ASSERT_NE(lines[i].find(",tool_wear" + point), std::string::npos) << lines[i];
  }
  // A partial row, if the kill cut one, is removed by the next writer; its rows follow.
  MeasurementLogOptions o;
  o.directory = dir.path.string();
  o.machine_id = "m";
  o.context_columns = {{"a_c", 0}};
  o.max_file_bytes = std::uint64_t{1} << 30;
  MeasurementLogWriter again(o);
  again.start();
  core::MeasurementRecord r;
  r.time_ns = 1'000'000'000'000;
  push(again, r);
  again.stop();
  EXPECT_EQ(again.rotations(), 0U);
  lines = read_lines(dir.path / "measurements.csv");
  EXPECT_EQ(lines.back().rfind("1000.000000,", 0), 0U) << lines.back();
  for (std::size_t i = 1; i < lines.size(); ++i) {
    EXPECT_EQ(fields(lines[i]), fields(header)) << i + 1 << ": " << lines[i];
  }
}

}  // namespace
}  // namespace nccomp::daemon
