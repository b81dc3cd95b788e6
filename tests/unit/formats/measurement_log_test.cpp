// The measurement log's CSV format: GIVEN a record, THEN one row with empty cells for unknown
// values and the v2 columns; the v2 header; UTC in ISO 8601 with milliseconds; the machine id
// rule; the last row's time of a file's tail (what the writer reads when it appends).
#include "formats/measurement_log/measurement_log.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <string>

namespace nccomp::formats::measurement_log {
namespace {

TEST(MeasurementLogFormat, RowFormatHasEmptyCellsForUnknownsAndTheV2Columns) {
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
  r.session = 42;
  r.context[0] = 31.25;
  r.context[2] = 8000.0;
  EXPECT_EQ(format_row(r, "mill-7", "2024-05-06T07:08:09.123Z", 3),
            "1.500000,3,12,contour,7,1.0000,2.5000,-3.0000,5.0000,,,4.2500,1.0000,mill-7,"
            "2024-05-06T07:08:09.123Z,42,31.2500,,8000.0000");
  EXPECT_EQ(csv_header({{"spindle_temp_c", 3}, {"bed_temp_c", 1}}),
            std::string(kV1Header) + ",machine,utc,session,spindle_temp_c,bed_temp_c");
}

TEST(MeasurementLogFormat, UtcIsIso8601WithMilliseconds) {
  EXPECT_EQ(format_utc(0), "1970-01-01T00:00:00.000Z");
  // 2024-02-29T23:59:59.999 UTC = 1709251199 s (a leap day).
  EXPECT_EQ(format_utc(1'709'251'199'999'000'000), "2024-02-29T23:59:59.999Z");
  EXPECT_EQ(format_utc(-1'000'000), "1969-12-31T23:59:59.999Z");
}

TEST(MeasurementLogFormat, MachineIdsAreOneTo64SafeCharactersStartingWithALetterOrDigit) {
  EXPECT_TRUE(valid_machine_id("mill-7"));
  EXPECT_TRUE(valid_machine_id("M1.cell_2"));
  EXPECT_TRUE(valid_machine_id(std::string(64, 'a')));
  EXPECT_FALSE(valid_machine_id(std::string(65, 'a')));
  EXPECT_FALSE(valid_machine_id(""));
  EXPECT_FALSE(valid_machine_id("-mill"));
  EXPECT_FALSE(valid_machine_id("_mill"));
  EXPECT_FALSE(valid_machine_id("mill/7"));  // an MQTT topic level separator
  EXPECT_FALSE(valid_machine_id("mill+"));   // an MQTT wildcard
  EXPECT_FALSE(valid_machine_id("mill 7"));
  EXPECT_TRUE(valid_machine_id(host_machine_id()));
}

TEST(MeasurementLogFormat, LastRowTimeIsTheLastCompleteRowsFirstCell) {
  const std::string h = std::string(kV1Header) + "\n";
  EXPECT_EQ(last_row_time_s(h + "1.5,0\n2.25,1\n", true), 2.25);
  // A partial last line (no newline) still counts when it starts with a number and a comma.
  EXPECT_EQ(last_row_time_s(h + "1.5,0\n2.25,1", true), 2.25);
  // The first line of a tail may be cut: it is not taken.
  EXPECT_TRUE(std::isinf(last_row_time_s("5,0\n", false)));
  EXPECT_EQ(last_row_time_s("5,0\n7,1\n", false), 7.0);
  // A header only, garbage, non-finite numbers: none.
  EXPECT_TRUE(std::isinf(last_row_time_s(h, true)));
  EXPECT_TRUE(std::isinf(last_row_time_s("abc,def\n", true)));
  EXPECT_TRUE(std::isinf(last_row_time_s("inf,0\nnan,1\n", true)));
  EXPECT_LT(last_row_time_s("", true), 0.0);
}

// GIVEN the names a log directory may hold WHEN ranked in the rotation THEN the log itself is 0,
// its rotated files their number, and every other name -1 (nothing half-parsed).
TEST(MeasurementLogFormat, RotationNumberRanksALogsOwnFilesOnly) {
  std::string log;
  EXPECT_EQ(rotation_number("measurements.csv", log), 0);
  EXPECT_EQ(log, "measurements.csv");
  EXPECT_EQ(rotation_number("measurements.csv.1", log), 1);
  EXPECT_EQ(log, "measurements.csv");
  EXPECT_EQ(rotation_number("m2.csv.999999999", log), 999999999);
  EXPECT_EQ(log, "m2.csv");
  log = "unchanged";
  for (const char* other : {"measurements.csv.0", "measurements.csv.01", "measurements.csv.",
                            "measurements.csv.1x", "measurements.csv.1000000000", ".csv",
                            "measurements.txt.1", "measurements.csv.bak", "notes", ".csv.3"}) {
    EXPECT_EQ(rotation_number(other, log), -1) << other;
  }
  EXPECT_EQ(log, "unchanged");
}

}  // namespace
}  // namespace nccomp::formats::measurement_log
