// GIVEN measurement messages from the publishers WHEN the collector stores them THEN it writes
// one v2 log per machine, never a row twice (also after its own restart), counts the sequence
// numbers that never came, and refuses what is not a measurement row of the topic's machine.
#include "tools/mqtt/collector.hpp"

#include <gtest/gtest.h>

#include <sstream>

#include "formats/measurement_log/measurement_log.hpp"
#include "formats/model/model_io.hpp"
#include "tests/unit/mqtt/temp_dir.hpp"

namespace nccomp::tools::mqtt {
namespace {

using test::TempDir;

std::string message(std::uint64_t seq, const std::string& machine, double time_s, int session = 4,
                    bool extra = false) {
  nlohmann::ordered_json j;
  j["seq"] = seq;
  j["time_s"] = time_s;
  j["part"] = 1;
  j["tool"] = 12;
  j["kind"] = "contour";
  j["point"] = static_cast<int>(seq);
  for (const char* c : {"x_mm", "y_mm", "z_mm", "angle_deg", "path_mm", "temp_c"}) j[c] = nullptr;
  j["measured_um"] = 2.5;
  j["applied_um"] = 0.0;
  j["machine"] = machine;
  j["utc"] = "2024-05-06T07:00:00.000Z";
  j["session"] = session;
  if (extra) j["spindle_rpm"] = 8000;
  return j.dump();
}

TEST(CollectorStore, OneLogPerMachineNoRowTwiceAlsoAfterARestart) {
  TempDir d("nccomp_coll");
  std::string error;
  {
    CollectorStore s(d.str());
    using R = CollectorStore::Result;
    EXPECT_EQ(s.add("nccomp/s1/m1/measurements", message(1, "m1", 1.0), error), R::kWritten);
    EXPECT_EQ(s.add("nccomp/s1/m1/measurements", message(2, "m1", 2.0), error), R::kWritten);
    EXPECT_EQ(s.add("nccomp/s1/m1/measurements", message(2, "m1", 2.0), error), R::kDuplicate);
    EXPECT_EQ(s.add("nccomp/s1/m2/measurements", message(1, "m2", 5.0), error), R::kWritten);
    EXPECT_EQ(s.add("nccomp/s1/m1/measurements", message(5, "m1", 3.0), error), R::kWritten);
    EXPECT_EQ(s.stats().missing, 2U);  // 3 and 4 never came
    EXPECT_EQ(s.stats().duplicates, 1U);
  }
  {
    // A new collector (a restart) reads the last sequence back: 5 and below are duplicates.
    CollectorStore s(d.str());
    EXPECT_EQ(s.last_seq("s1", "m1"), 5U);
    EXPECT_EQ(s.add("nccomp/s1/m1/measurements", message(4, "m1", 2.5), error),
              CollectorStore::Result::kDuplicate);
    EXPECT_EQ(s.add("nccomp/s1/m1/measurements", message(6, "m1", 1.0, 5), error),
              CollectorStore::Result::kWritten);
  }
  const auto lines = test::read_lines(d.path() / "s1" / "m1.csv");
  ASSERT_EQ(lines.size(), 5U);
  EXPECT_EQ(lines[0], formats::measurement_log::csv_header({}) + ",seq");
  EXPECT_EQ(lines[3], "3.0,1,12,contour,5,,,,,,,2.5,0.0,m1,2024-05-06T07:00:00.000Z,4,5");
  EXPECT_EQ(test::read_lines(d.path() / "s1" / "m2.csv").size(), 2U);
  // The collected log is a v2 log nccomp analyze reads: session 5 restarts time_s.
  std::ifstream in(d.path() / "s1" / "m1.csv");
  core::model::Dataset data;
  formats::model_io::read_log(in, "m1.csv", {}, data);
  EXPECT_EQ(data.rows(), 4U);
}

TEST(CollectorStore, RefusesWhatIsNotAMeasurementRowOfTheTopicsMachine) {
  TempDir d("nccomp_coll_bad");
  CollectorStore s(d.str());
  std::string error;
  using R = CollectorStore::Result;
  EXPECT_EQ(s.add("nccomp/s1/m1/measurements", message(1, "m2", 1.0), error), R::kRefused);
  EXPECT_NE(error.find("not the topic's"), std::string::npos) << error;
  EXPECT_EQ(s.add("nccomp/s1/m1/measurements", "{\"seq\":1}", error), R::kRefused);
  EXPECT_NE(error.find("not a v2 row"), std::string::npos) << error;
  EXPECT_EQ(s.add("nccomp/s1/m1/measurements", "[1,2]", error), R::kRefused);
  EXPECT_EQ(s.add("nccomp/s1/m1/measurements", "{", error), R::kRefused);
  auto j = nlohmann::ordered_json::parse(message(1, "m1", 1.0));
  j["kind"] = "contour,1";
  EXPECT_EQ(s.add("nccomp/s1/m1/measurements", j.dump(), error), R::kRefused);
  EXPECT_NE(error.find("not a cell of the log"), std::string::npos) << error;
  j = nlohmann::ordered_json::parse(message(1, "m1", 1.0));
  j["Bad,Name"] = 1;
  EXPECT_EQ(s.add("nccomp/s1/m1/measurements", j.dump(), error), R::kRefused);
  j = nlohmann::ordered_json::parse(message(1, "m1", 1.0));
  j["seq"] = -1;
  EXPECT_EQ(s.add("nccomp/s1/m1/measurements", j.dump(), error), R::kRefused);
  EXPECT_EQ(s.add("nccomp/s1/m1/alarms", message(1, "m1", 1.0), error), R::kRefused);
  EXPECT_EQ(s.stats().refused, 8U);
  EXPECT_EQ(s.stats().written, 0U);
}

TEST(CollectorStore, OtherColumnsStartANewFileAndKeepTheOld) {
  TempDir d("nccomp_coll_cols");
  CollectorStore s(d.str());
  std::string error;
  ASSERT_EQ(s.add("nccomp/s1/m1/measurements", message(1, "m1", 1.0), error),
            CollectorStore::Result::kWritten);
  ASSERT_EQ(s.add("nccomp/s1/m1/measurements", message(2, "m1", 2.0, 4, true), error),
            CollectorStore::Result::kWritten);
  EXPECT_EQ(test::read_lines(d.path() / "s1" / "m1.csv.1").size(), 2U);
  const auto now = test::read_lines(d.path() / "s1" / "m1.csv");
  ASSERT_EQ(now.size(), 2U);
  EXPECT_EQ(now[0], formats::measurement_log::csv_header({}) + ",spindle_rpm,seq");
}

}  // namespace
}  // namespace nccomp::tools::mqtt
