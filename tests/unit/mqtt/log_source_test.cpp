// GIVEN nccompd's measurement log as the daemon writes and rotates it WHEN the publisher's source
// polls it THEN it takes every complete v2 row once, in order, across rotations and restarts
// (the cursor), never a partial row, and reports what it skips.
#include "tools/mqtt/log_source.hpp"

#include <gtest/gtest.h>

#include <filesystem>

#include "formats/measurement_log/measurement_log.hpp"
#include "tests/unit/mqtt/temp_dir.hpp"

namespace nccomp::tools::mqtt {
namespace {

using test::TempDir;
namespace fs = std::filesystem;

const std::string kHeader = formats::measurement_log::csv_header({{"spindle_rpm", 3}});

std::string row(int point, const std::string& machine = "m1") {
  return std::to_string(point) + ".000000,7,12,contour," + std::to_string(point) +
         ",1.0000,,,,,,2.5000,0.0000," + machine + ",2024-05-06T07:00:00.000Z,4,8000.0000\n";
}

std::vector<int> points(const std::vector<LogRow>& rows) {
  std::vector<int> p;
  for (const auto& r : rows) p.push_back(r.columns.at("point").get<int>());
  return p;
}

TEST(LogSource, RowsBecomeTypedJsonInHeaderOrder) {
  nlohmann::ordered_json j;
  std::string error;
  std::vector<std::string> header;
  for (const char* c : {"time_s", "part", "kind", "x_mm", "machine", "utc", "session", "rpm"}) {
    header.push_back(c);
  }
  ASSERT_TRUE(
      row_to_json(header, "1.500000,3,contour,,m1,2024-05-06T07:00:00.000Z,4,8000.5", j, error))
      << error;
  EXPECT_EQ(j.dump(), R"({"time_s":1.5,"part":3,"kind":"contour","x_mm":null,"machine":"m1",)"
                      R"("utc":"2024-05-06T07:00:00.000Z","session":4,"rpm":8000.5})");
  EXPECT_EQ(json_to_row(header, j), "1.5,3,contour,,m1,2024-05-06T07:00:00.000Z,4,8000.5");
  EXPECT_FALSE(row_to_json(header, "1.5,3,contour", j, error));
  EXPECT_EQ(error, "3 fields, the header has 8");
  EXPECT_FALSE(row_to_json(header, "1.5,3.5,contour,,m1,u,4,1", j, error));
  EXPECT_EQ(error, "column 'part': '3.5' is not an integer");
  EXPECT_FALSE(row_to_json(header, "1.5,3,contour,x,m1,u,4,1", j, error));
  EXPECT_EQ(error, "column 'x_mm': 'x' is not a finite number");
  EXPECT_EQ(LogCursor::parse("12:345:678"), (LogCursor{12, 345, 678}));
  EXPECT_THROW(LogCursor::parse("12:345"), std::invalid_argument);
}

TEST(LogSource, FollowsRotationsTakesWholeRowsOnceAndResumesFromItsCursor) {
  TempDir d("nccomp_logsrc");
  d.write("measurements.csv", kHeader + "\n" + row(1) + row(2) + "3.0000");  // 3 is being written
  LogSource s(d.str());
  std::vector<LogProblem> problems;
  auto rows = s.poll(100, problems);
  EXPECT_EQ(points(rows), (std::vector<int>{1, 2}));
  EXPECT_TRUE(problems.empty());
  EXPECT_EQ(rows[0].columns.at("spindle_rpm").get<double>(), 8000.0);
  // The daemon completes row 3, adds 4, rotates (.1 → .2, current → .1), writes 5 and 6.
  d.append("measurements.csv",
           "00,7,12,contour,3,1.0000,,,,,,2.5000,0.0000,m1,"
           "2024-05-06T07:00:00.000Z,4,8000.0000\n" +
               row(4));
  fs::rename(d.path() / "measurements.csv", d.path() / "measurements.csv.1");
  d.write("measurements.csv", kHeader + "\n" + row(5));
  d.append("measurements.csv", row(6));
  rows = s.poll(2, problems);  // at most 2 per poll
  EXPECT_EQ(points(rows), (std::vector<int>{3, 4}));
  const LogCursor saved = s.cursor();
  // A restart of the publisher from the saved cursor, after two more rotations.
  fs::rename(d.path() / "measurements.csv.1", d.path() / "measurements.csv.2");
  fs::rename(d.path() / "measurements.csv", d.path() / "measurements.csv.1");
  d.write("measurements.csv", kHeader + "\n" + row(7));
  LogSource again(d.str());
  again.set_cursor(saved);
  rows = again.poll(100, problems);
  EXPECT_EQ(points(rows), (std::vector<int>{5, 6, 7}));
  EXPECT_TRUE(problems.empty());
  EXPECT_EQ(again.files_missed(), 0U);
  EXPECT_TRUE(again.poll(100, problems).empty());
}

TEST(LogSource, AFileRotatedAwayUnreadAV1FileAndABadRowAreReported) {
  TempDir d("nccomp_logsrc2");
  d.write("measurements.csv", kHeader + "\n" + row(1));
  LogSource s(d.str());
  std::vector<LogProblem> problems;
  EXPECT_EQ(points(s.poll(100, problems)), (std::vector<int>{1}));
  // The file the cursor is in is deleted (keep_files exceeded) before the rest was read.
  fs::remove(d.path() / "measurements.csv");
  d.write("measurements.csv.1", std::string(formats::measurement_log::kV1Header) +
                                    "\n1.0,0,0,tool_wear,0,,,,,,,1.0,0.0\n");
  d.write("measurements.csv", kHeader + "\n" + row(8) + "x\n" + row(9));
  const auto rows = s.poll(100, problems);
  EXPECT_EQ(points(rows), (std::vector<int>{8, 9}));
  EXPECT_EQ(s.files_missed(), 1U);
  ASSERT_EQ(problems.size(), 3U);
  EXPECT_NE(problems[0].message.find("rotated away"), std::string::npos);
  EXPECT_NE(problems[1].message.find("not a v2 log"), std::string::npos);
  EXPECT_EQ(problems[1].file, (d.path() / "measurements.csv.1").string());
  EXPECT_NE(problems[2].message.find("not a measurement row (1 fields"), std::string::npos)
      << problems[2].message;
}

TEST(LogSource, AReusedInodeIsNotTakenForTheOldFile) {
  TempDir d("nccomp_logsrc3");
  d.write("measurements.csv", kHeader + "\n" + row(1) + row(2));
  LogSource s(d.str());
  std::vector<LogProblem> problems;
  ASSERT_EQ(s.poll(1, problems).size(), 1U);
  LogCursor c = s.cursor();
  c.head_hash ^= 1;  // another file under the same inode
  s.set_cursor(c);
  const auto rows = s.poll(100, problems);
  EXPECT_EQ(points(rows), (std::vector<int>{1, 2}));  // read from the start of the file there is
  EXPECT_EQ(s.files_missed(), 1U);
}

}  // namespace
}  // namespace nccomp::tools::mqtt
