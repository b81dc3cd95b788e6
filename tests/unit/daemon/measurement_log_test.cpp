// GIVEN measurement records, WHEN the writer thread logs them, THEN the CSV has the v1 header,
// empty cells for unknown values, and rotates by size keeping keep_files files.
#include "daemon/measurement_log.hpp"

#include <gtest/gtest.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <thread>

namespace nccomp::daemon {
namespace {

namespace fs = std::filesystem;

TEST(MeasurementLog, RowFormatHasEmptyCellsForUnknowns) {
  core::MeasurementRecord r;
  r.time_ns = 1'500'000'000;
  r.part = 3;
  r.tool = 12;
  r.kind = core::MeasurementKind::kContour;
  r.point = 7;
  r.position_mm = {1.0, 2.5, -3.0};
  r.angle_deg = 5.0;
  r.measured_um = 4.25;
  r.applied_um = 1.0;
  EXPECT_EQ(format_measurement_row(r),
            "1.500000,3,12,contour,7,1.0000,2.5000,-3.0000,5.0000,,,4.2500,1.0000");
}

TEST(MeasurementLog, RotatesBySizeAndKeepsHeaderInEveryFile) {
  const fs::path dir = fs::temp_directory_path() / ("nccomp_mlog_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  {
    MeasurementLogWriter w(dir.string(), 4096, 2, 1024);
    w.start();
    core::MeasurementRecord r;
    r.kind = core::MeasurementKind::kToolWear;
    for (int i = 0; i < 300; ++i) {
      r.time_ns = i * 1'000'000'000LL;
      r.point = i;
      while (!w.ring().try_push(r)) {
        std::this_thread::sleep_for(std::chrono::milliseconds(1));
      }
    }
    w.stop();
    EXPECT_EQ(w.rows(), 300U);
    EXPECT_GE(w.rotations(), 3U);
    EXPECT_EQ(w.errors(), 0U);
  }
  EXPECT_TRUE(fs::exists(dir / "measurements.csv"));
  EXPECT_TRUE(fs::exists(dir / "measurements.csv.1"));
  EXPECT_TRUE(fs::exists(dir / "measurements.csv.2"));
  EXPECT_FALSE(fs::exists(dir / "measurements.csv.3"));
  for (const char* name : {"measurements.csv", "measurements.csv.1", "measurements.csv.2"}) {
    std::ifstream in(dir / name);
    std::string header;
    std::getline(in, header);
    EXPECT_EQ(header, kMeasurementCsvHeader) << name;
    EXPECT_LE(fs::file_size(dir / name), 4096U) << name;
  }
  // The newest rows are in the current file: its last row is point 299.
  std::ifstream in(dir / "measurements.csv");
  std::string line;
  std::string last;
  while (std::getline(in, line)) {
    last = line;
  }
  EXPECT_EQ(last.rfind("299.000000,0,0,tool_wear,299,", 0), 0U) << last;
  fs::remove_all(dir);
}

}  // namespace
}  // namespace nccomp::daemon
