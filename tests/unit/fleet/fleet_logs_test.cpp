// `nccomp analyze` over several machines' logs (tools/analyze/fleet.hpp): which logs form a
// fleet, and the logs it refuses, with file:line.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "formats/model/model_io.hpp"
#include "tools/analyze/fleet.hpp"

namespace fs = std::filesystem;
namespace an = nccomp::tools::analyze;

namespace {

class FleetLogs : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ =
        fs::temp_directory_path() /
        ("nccomp-fleet-logs-" + std::to_string(::testing::UnitTest::GetInstance()->random_seed()) +
         "-" + ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_ / "site");
  }
  void TearDown() override { fs::remove_all(dir_); }

  // A v2 log of `machine` (two rows), or a v1 log when machine is empty.
  std::string log(const std::string& name, const std::string& machine) {
    const fs::path p = dir_ / name;
    std::ofstream f(p);
    f << "time_s,part,tool,kind,point,x_mm,y_mm,z_mm,angle_deg,path_mm,temp_c,measured_um,"
         "applied_um"
      << (machine.empty() ? "" : ",machine,utc,session") << "\n";
    for (int i = 0; i < 2; ++i) {
      f << i << ",1,1,contour,0,0,0,0,0,0,20,1.5,0"
        << (machine.empty() ? ""
                            : "," + machine + ",2026-11-27T10:00:0" + std::to_string(i) + "Z,1")
        << "\n";
    }
    return p.string();
  }

  fs::path dir_;
};

std::string error_of(const std::vector<std::string>& logs) {
  try {
    an::group_logs(logs);
  } catch (const std::invalid_argument& e) {
    return e.what();
  }
  return "";
}

}  // namespace

// GIVEN logs of two machines, one as a directory WHEN grouped THEN one group per machine in order
// of first appearance, each machine's files in the order given.
TEST_F(FleetLogs, GroupsByMachine) {
  const std::string a1 = log("a1.csv", "mill-1");
  const std::string b = log("site/b.csv", "mill-2");
  const std::string a2 = log("site/c.csv", "mill-1");
  const auto g = an::group_logs({a1, (dir_ / "site").string()});
  ASSERT_EQ(g.size(), 2U);
  EXPECT_EQ(g[0].machine, "mill-1");
  EXPECT_EQ(g[0].files, (std::vector<std::string>{a1, a2}));
  EXPECT_EQ(g[1].machine, "mill-2");
  EXPECT_EQ(g[1].files, (std::vector<std::string>{b}));
}

// GIVEN a directory as nccompd leaves it (measurements.csv and its rotated files .1 the newest
// to .11 the oldest) WHEN grouped THEN every file is read, oldest first and the current one last
// (only *.csv were read before: the rotated rows were silently left out).
TEST_F(FleetLogs, ADirectoryTakesTheRotatedFilesOldestFirst) {
  fs::create_directories(dir_ / "log");
  const std::string cur = log("log/measurements.csv", "mill-1");
  const std::string r1 = log("log/measurements.csv.1", "mill-1");
  const std::string r2 = log("log/measurements.csv.2", "mill-1");
  const std::string r11 = log("log/measurements.csv.11", "mill-1");
  log("log/notes.txt.1", "mill-1");  // not a log
  const auto g = an::group_logs({(dir_ / "log").string()});
  ASSERT_EQ(g.size(), 1U);
  EXPECT_EQ(g[0].files, (std::vector<std::string>{r11, r2, r1, cur}));
}

// GIVEN one machine's v2 logs with a v1 log between them WHEN grouped THEN one group of all
// files in the order given (no fleet: a single machine's analysis as before).
TEST_F(FleetLogs, OneMachineWithAV1LogIsNoFleet) {
  const std::string a = log("a.csv", "mill-1");
  const std::string v1 = log("old.csv", "");
  const std::string c = log("c.csv", "mill-1");
  const auto g = an::group_logs({a, v1, c});
  ASSERT_EQ(g.size(), 1U);
  EXPECT_EQ(g[0].machine, "mill-1");
  EXPECT_EQ(g[0].files, (std::vector<std::string>{a, v1, c}));
}

// GIVEN logs of several machines with a v1 log, an id that cannot name a file, the id "type",
// or an empty directory WHEN grouped THEN each is refused naming the file (and line).
TEST_F(FleetLogs, RefusesWhatCannotBeAFleet) {
  const std::string a = log("a.csv", "mill-1");
  const std::string b = log("b.csv", "mill-2");
  EXPECT_NE(error_of({a, b, log("old.csv", "")}).find("old.csv: no machine column"),
            std::string::npos);
  const std::string bad = log("bad.csv", "mill/3");
  EXPECT_NE(error_of({a, bad}).find("bad.csv:2: column 'machine': 'mill/3' is not a machine id"),
            std::string::npos)
      << error_of({a, bad});
  const std::string type = log("type.csv", "type");
  EXPECT_NE(error_of({a, type}).find("type.csv:2: column 'machine': 'type' is reserved"),
            std::string::npos);
  fs::create_directories(dir_ / "empty");
  EXPECT_NE(error_of({(dir_ / "empty").string()}).find("no *.csv file in the directory"),
            std::string::npos);
}
