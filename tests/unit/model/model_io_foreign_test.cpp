// GIVEN foreign measured data as published (text ids, counters that restart, several header
// rows) WHEN read through a --map alone THEN the rows arrive with group numbers, continued
// counters and runs as sessions; every bad setting or cell is refused with file:line:column.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <fstream>
#include <sstream>

#include "formats/model/model_io.hpp"
#include "formats/toml/diagnostics.hpp"

namespace cm = nccomp::core::model;
namespace io = nccomp::formats::model_io;

namespace {

constexpr std::size_t kTime = 0;
constexpr std::size_t kPart = 1;
constexpr std::size_t kTool = 2;
constexpr std::size_t kPath = 9;

std::string map_error(const std::string& text) {
  try {
    (void)io::read_mapping_text(text, "map.toml");
  } catch (const nccomp::formats::DiagnosticsError& e) {
    return e.what();
  }
  return "";
}

std::string log_error(const std::string& csv, const io::Mapping& m, cm::Dataset d = {}) {
  std::istringstream in(csv);
  try {
    io::read_log(in, "log.csv", m, d);
  } catch (const nccomp::formats::DiagnosticsError& e) {
    return e.what();
  }
  return "";
}

// Lines 1-4 of every map below; the lines after it continue its [columns].
const char* kBase = "[constant]\nkind = \"tool_wear\"\n[columns]\nmeasured_um = \"vb\"\n";

}  // namespace

TEST(ReadForeign, TextIdsBecomeGroupNumbersByDigitsOrByTable) {
  const io::Mapping m = io::read_mapping_text(
      std::string(kBase) +
          "tool = \"tool\"\n[extra]\nfamily = \"sheet\"\n"
          "[ids]\ntool = \"digits\"\nfamily = { \"Steel plates\" = 1, \"Alu 7075\" = 2 }\n",
      "map.toml");
  std::istringstream in(
      "tool,sheet,vb\nT12,Steel plates,3.5\nc4,Alu 7075,4\n\"T 07\",Steel plates,5\n9,Alu "
      "7075,6\n");
  cm::Dataset d;
  d.extra_columns = {"family"};
  io::read_log(in, "wear.csv", m, d);
  ASSERT_EQ(d.rows(), 4U);
  EXPECT_DOUBLE_EQ(d.column(kTool)[0], 12.0);
  EXPECT_DOUBLE_EQ(d.column(kTool)[1], 4.0);
  EXPECT_DOUBLE_EQ(d.column(kTool)[2], 7.0);
  EXPECT_DOUBLE_EQ(d.column(kTool)[3], 9.0);
  EXPECT_DOUBLE_EQ(d.column(cm::kStandardColumns)[0], 1.0);
  EXPECT_DOUBLE_EQ(d.column(cm::kStandardColumns)[1], 2.0);
  EXPECT_DOUBLE_EQ(d.target_um[1], 4.0);

  // A text without one run of digits, or not in the table, is refused at its cell.
  EXPECT_EQ(log_error("tool,sheet,vb\nT1-2,Steel plates,1\n", m, d),
            "log.csv:2:1: tool: 'T1-2' is not a text id of [ids] (digits: one run of digits, "
            "e.g. T12)");
  EXPECT_EQ(log_error("tool,sheet,vb\nT1,Brass,1\n", m, d),
            "log.csv:2:2: sheet: 'Brass' is not a text id of [ids] (Alu 7075, Steel plates)");
}

TEST(ReadForeign, ACounterRestartingOnDecreaseContinuesAndStartsARun) {
  const io::Mapping m = io::read_mapping_text(std::string(kBase) +
                                                  "path_mm = \"cut\"\n[scale]\npath_mm = 100.0\n"
                                                  "[restarts]\npath_mm = \"on_decrease\"\n",
                                              "map.toml");
  std::istringstream in("cut,vb\n1,1\n2,2\n3,3\n1,4\n2,5\n");
  cm::Dataset d;
  io::read_log(in, "a.csv", m, d);
  ASSERT_EQ(d.rows(), 5U);
  const double path[] = {100, 200, 300, 400, 500};
  const std::uint32_t session[] = {0, 0, 0, 1, 1};
  for (std::size_t r = 0; r < 5; ++r) {
    EXPECT_DOUBLE_EQ(d.column(kPath)[r], path[r]) << r;
    EXPECT_EQ(d.row_session[r], session[r]) << r;
  }
  // The next file restarts too (from 1 < 500 read before): it continues after 500.
  std::istringstream in2("cut,vb\n1,6\n2,7\n");
  io::read_log(in2, "b.csv", m, d);
  ASSERT_EQ(d.rows(), 7U);
  EXPECT_DOUBLE_EQ(d.column(kPath)[5], 600.0);
  EXPECT_DOUBLE_EQ(d.column(kPath)[6], 700.0);
  EXPECT_EQ(d.row_session[5], 2U);
}

TEST(ReadForeign, APartCounterPerFileContinuesFromThePreviousFile) {
  const io::Mapping m = io::read_mapping_text(
      std::string(kBase) + "part = \"part\"\n[restarts]\npart = \"per_file\"\n", "map.toml");
  cm::Dataset d;
  std::istringstream a("part,vb\n1,1\n2,2\n");
  io::read_log(a, "day1.csv", m, d);
  // Day 2 counts again from 3 (higher than day 1's last part): per_file continues it anyway.
  std::istringstream b("part,vb\n3,1\n4,2\n");
  io::read_log(b, "day2.csv", m, d);
  ASSERT_EQ(d.rows(), 4U);
  EXPECT_DOUBLE_EQ(d.column(kPart)[1], 2.0);
  EXPECT_DOUBLE_EQ(d.column(kPart)[2], 5.0);
  EXPECT_DOUBLE_EQ(d.column(kPart)[3], 6.0);
  EXPECT_EQ(d.row_session[2], 1U);
}

TEST(ReadForeign, ATimeColumnThatRestartsKeepsItsValuesAndOrdersTheRunAfter) {
  const io::Mapping m = io::read_mapping_text(
      std::string(kBase) + "time_s = \"t\"\n[restarts]\ntime_s = \"on_decrease\"\n", "map.toml");
  std::istringstream in("t,vb\n0,1\n10,2\n20,3\n5,4\n15,5\n");
  cm::Dataset d;
  io::read_log(in, "a.csv", m, d);
  ASSERT_EQ(d.rows(), 5U);
  EXPECT_DOUBLE_EQ(d.column(kTime)[3], 5.0);   // time since the run started
  const double order[] = {0, 10, 20, 21, 31};  // 20 + 1 − 5 + t
  const std::uint32_t session[] = {0, 0, 0, 1, 1};
  for (std::size_t r = 0; r < 5; ++r) {
    EXPECT_DOUBLE_EQ(d.order_s[r], order[r]) << r;
    EXPECT_EQ(d.row_session[r], session[r]) << r;
  }
  // A second file whose times start again is ordered after the first (a mapped file without
  // [restarts] keeps its times: parallel series).
  std::istringstream in2("t,vb\n0,6\n");
  io::read_log(in2, "b.csv", m, d);
  EXPECT_DOUBLE_EQ(d.order_s[5], 32.0);
  EXPECT_EQ(d.row_session[5], 2U);

  // per_file: a decrease within a file is still an error.
  const io::Mapping per_file = io::read_mapping_text(
      std::string(kBase) + "time_s = \"t\"\n[restarts]\ntime_s = \"per_file\"\n", "map.toml");
  EXPECT_EQ(log_error("t,vb\n0,1\n10,2\n5,3\n", per_file).substr(0, 38),
            "log.csv:4:1: time_s: goes backwards (5");
}

TEST(ReadForeign, SeveralHeaderRowsTakeTheNamesFromTheChosenRow) {
  // A spreadsheet export: a title row, the names, a units row.
  const io::Mapping m = io::read_mapping_text(
      "header_rows = 3\nnames_row = 2\n" + std::string(kBase) + "time_s = \"Time\"\n", "map.toml");
  std::istringstream in("Wear test 2024,,\r\nTime,vb,note\r\ns,um,\r\n0,1.5,a\r\n60,2.5,b\r\n");
  cm::Dataset d;
  io::read_log(in, "sheet.csv", m, d);
  ASSERT_EQ(d.rows(), 2U);
  EXPECT_DOUBLE_EQ(d.column(kTime)[1], 60.0);
  EXPECT_DOUBLE_EQ(d.target_um[1], 2.5);
  EXPECT_EQ(d.row_line[0], 4U);  // lines count the header rows
  EXPECT_EQ(log_error("Title\nTime,vb\ns,um\n0,x\n", m),
            "log.csv:4:2: vb: 'x' is not a finite number");
  EXPECT_EQ(log_error("Title\nTime,dev\ns,um\n0,1\n", m),
            "log.csv:2: vb: not in the header (mapped to 'measured_um')");
  EXPECT_EQ(log_error("Title\nTime,vb\n", m),
            "log.csv:3: the file ends within its 3 header rows (header_rows)");
  // The default names row is the last header row.
  const io::Mapping last =
      io::read_mapping_text("header_rows = 2\n" + std::string(kBase), "map.toml");
  std::istringstream in2("Wear test\nvb\n7\n");
  cm::Dataset d2;
  io::read_log(in2, "s.csv", last, d2);
  ASSERT_EQ(d2.rows(), 1U);
  EXPECT_DOUBLE_EQ(d2.target_um[0], 7.0);
}

// A spreadsheet saved in a German or French locale: fields separated by ';', a decimal comma.
TEST(ReadForeign, ASemicolonFileWithADecimalCommaIsReadAsWritten) {
  const io::Mapping m = io::read_mapping_text(
      "separator = \";\"\ndecimal = \",\"\n" + std::string(kBase) +
          "time_s = \"Zeit (s)\"\n[extra]\nt1_c = \"Temp; Bett\"\n[scale]\nmeasured_um = 1000.0\n",
      "map.toml");
  std::istringstream in(
      "Zeit (s);vb;\"Temp; Bett\"\r\n0;0,0125;20,5\r\n15;+0,013;-1,25e1\r\n30;;21\r\n");
  cm::Dataset d;
  d.extra_columns = {"t1_c"};
  io::read_log(in, "export.csv", m, d);
  ASSERT_EQ(d.rows(), 3U);
  EXPECT_DOUBLE_EQ(d.column(kTime)[1], 15.0);
  EXPECT_DOUBLE_EQ(d.target_um[0], 12.5);
  EXPECT_DOUBLE_EQ(d.target_um[1], 13.0);
  EXPECT_TRUE(std::isnan(d.target_um[2]));
  EXPECT_DOUBLE_EQ(d.column(cm::kStandardColumns)[0], 20.5);
  EXPECT_DOUBLE_EQ(d.column(cm::kStandardColumns)[1], -12.5);

  // A '.' in a decimal-comma file is a thousands separator or another locale's number: refused
  // at its cell, never read as 1.2345 or 12345.
  EXPECT_EQ(log_error("Zeit (s);vb;\"Temp; Bett\"\n0;1.234,5;20\n", m, d),
            "log.csv:2:2: vb: '1.234,5' is not a finite number (the map's decimal mark is ',': "
            "no '.', no thousands separators)");
  EXPECT_EQ(log_error("Zeit (s);vb;\"Temp; Bett\"\n0;+-1,5;20\n", m, d),
            "log.csv:2:2: vb: '+-1,5' is not a finite number");
  EXPECT_EQ(log_error("Zeit (s);vb;\"Temp; Bett\"\n0;0.5;20\n", m, d).substr(0, 45),
            "log.csv:2:2: vb: '0.5' is not a finite number");
  // An unquoted separator in a field would shift the columns after it.
  EXPECT_EQ(log_error("Zeit (s);vb;\"Temp; Bett\"\n0;1;2;3\n", m, d),
            "log.csv:2: the row has 4 fields, the header 3 (an unquoted ';' in a field?)");

  // Tab-separated, decimal point; a wide file with a decimal comma.
  const io::Mapping tab = io::read_mapping_text(
      "separator = \"\\t\"\n" + std::string(kBase) + "time_s = \"t\"\n", "map.toml");
  std::istringstream in2("t\tvb\n0\t1.5\n1\t2.5\n");
  cm::Dataset d2;
  io::read_log(in2, "tab.tsv", tab, d2);
  ASSERT_EQ(d2.rows(), 2U);
  EXPECT_DOUBLE_EQ(d2.target_um[1], 2.5);
  const io::Mapping wide = io::read_mapping_text(
      "separator = \";\"\ndecimal = \",\"\n[constant]\nkind = \"tool_wear\"\n[columns]\n"
      "time_s = \"cut\"\n[wide]\nmeasured_um = [\"f1\", \"f2\"]\npoints = [1, 2]\n",
      "map.toml");
  std::istringstream in3("cut;f1;f2\n1;31,5;19,25\n");
  cm::Dataset d3;
  io::read_log(in3, "wide.csv", wide, d3);
  ASSERT_EQ(d3.rows(), 2U);
  EXPECT_DOUBLE_EQ(d3.target_um[0], 31.5);
  EXPECT_DOUBLE_EQ(d3.target_um[1], 19.25);
  EXPECT_EQ(log_error("cut;f1;f2\n1;31.5;19\n", wide, d3).substr(0, 46),
            "log.csv:2:2: f1: '31.5' is not a finite number");

  // The same file read without the settings: its header is one field, and the error says so.
  const io::Mapping plain = io::read_mapping_text(std::string(kBase), "map.toml");
  EXPECT_EQ(log_error("Zeit (s);vb\n0;1,5\n", plain),
            "log.csv:1: vb: not in the header (mapped to 'measured_um') (the header is one field "
            "holding ';': set separator = \";\" in the map)");
  EXPECT_EQ(log_error("t\tvb\n0\t1.5\n", plain),
            "log.csv:1: vb: not in the header (mapped to 'measured_um') (the header is one field "
            "holding tabs: set separator = \"\\t\" in the map)");

  // A decimal comma in a quoted cell of a comma-separated file.
  EXPECT_EQ(
      log_error("t,vb\n0,\"1,5\"\n", plain),
      "log.csv:2:2: vb: '1,5' is not a finite number (a decimal comma? set decimal = \",\" in "
      "the map)");

  // The settings themselves.
  EXPECT_EQ(map_error("decimal = \",\"\n" + std::string(kBase)),
            "map.toml:1:11: decimal: \",\" is the field separator too: set separator = \";\" "
            "(or \"\\t\")");
  EXPECT_EQ(map_error("separator = \"|\"\n" + std::string(kBase)),
            "map.toml:1:13: separator: must be \",\", \";\" or \"\\t\" (a tab)");
  EXPECT_EQ(map_error("decimal = \"·\"\nseparator = \";\"\n" + std::string(kBase)),
            "map.toml:1:11: decimal: must be \".\" or \",\"");
}

TEST(ReadForeign, RefusesBadSettingsWithFileLineAndColumn) {
  const std::string b = kBase;
  EXPECT_EQ(map_error(b + "x_mm = \"x\"\n[ids]\nx_mm = \"digits\"\n"),
            "map.toml:7:8: ids.x_mm: text ids are for tool, point or part mapped under "
            "[columns], or a column of [extra]");
  EXPECT_EQ(
      map_error("[constant]\nkind = \"tool_wear\"\ntool = 3\n[columns]\nmeasured_um = \"vb\"\n"
                "[ids]\ntool = \"digits\"\n")
          .substr(0, 25),
      "map.toml:7:8: ids.tool: t");
  EXPECT_EQ(map_error(b + "tool = \"t\"\n[ids]\ntool = \"letters\"\n"),
            "map.toml:7:8: ids.tool: must be \"digits\" or a table of text = number");
  EXPECT_EQ(map_error(b + "tool = \"t\"\n[ids]\ntool = { T1 = 1.5 }\n"),
            "map.toml:7:15: ids.tool.T1: must be an integer");
  EXPECT_EQ(map_error(b + "tool = \"t\"\n[ids]\ntool = \"digits\"\n[scale]\ntool = 2.0\n"),
            "map.toml:9:8: scale.tool: a column of [ids] is not scaled");
  EXPECT_EQ(map_error(b + "part = \"p\"\n[restarts]\npart = \"daily\"\n"),
            "map.toml:7:8: restarts.part: 'daily' is not per_file or on_decrease");
  EXPECT_EQ(map_error(b + "[restarts]\npart = \"per_file\"\n"),
            "map.toml:6:8: restarts.part: not a column mapped under [columns] or [extra]");
  EXPECT_EQ(map_error(b + "part = \"p\"\ntime_s = \"t\"\n[restarts]\n"
                          "part = \"per_file\"\ntime_s = \"on_decrease\"\n"),
            "map.toml:9:10: restarts.time_s: one counter only (already part)");
  EXPECT_EQ(map_error("header_rows = 0\n" + b),
            "map.toml:1:15: header_rows: must be an integer from 1 to 100");
  EXPECT_EQ(map_error("header_rows = 2\nnames_row = 3\n" + b),
            "map.toml:2:13: names_row: beyond header_rows = 2");
  EXPECT_EQ(map_error(b + "[restart]\n").substr(0, 42),
            "map.toml:5:1: .restart: unknown key (allow");
}

// The PHM 2010 per-cut table as published: cutter "c1", "c4", "c6" and its cut counter that
// restarts at 1 for each cutter, read by a map alone.
TEST(ReadForeign, ReadsThePhm2010PerCutTableAsPublished) {
  const std::string path = std::string(NCCOMP_SOURCE_DIR) +
                           "/../shared/data/phm2010_milling_wear/phm2010_wear_percut.csv";
  std::ifstream in(path);
  ASSERT_TRUE(in) << "PHM 2010 data not found at " << path << " (../shared beside the checkout)";
  const io::Mapping m = io::read_mapping_text(R"toml(
[columns]
tool = "cutter"
time_s = "cut"
path_mm = "cut"
measured_um = "max_wear"
[ids]
tool = "digits"
[restarts]
time_s = "on_decrease"
[scale]
path_mm = 108.0
[constant]
kind = "tool_wear"
)toml",
                                              "percut.map.toml");
  cm::Dataset d;
  io::read_log(in, "phm2010_wear_percut.csv", m, d);
  ASSERT_EQ(d.rows(), 945U);
  // Row r is cut r % 315 + 1 of cutter c1, c4, c6; each cutter one run, ordered one after the
  // other, its path from 108 mm.
  const double tools[] = {1, 4, 6};
  for (std::size_t r = 0; r < d.rows(); ++r) {
    const std::size_t run = r / 315;
    const double cut = static_cast<double>(r % 315 + 1);
    ASSERT_DOUBLE_EQ(d.column(kTool)[r], tools[run]) << r;
    ASSERT_DOUBLE_EQ(d.column(kPath)[r], 108.0 * cut) << r;
    ASSERT_DOUBLE_EQ(d.column(kTime)[r], cut) << r;
    ASSERT_EQ(d.row_session[r], run) << r;
    if (r > 0) {
      ASSERT_GT(d.order_s[r], d.order_s[r - 1]) << r;
    }
  }
  EXPECT_NEAR(d.target_um[0], 48.89261732, 1e-9);  // c1, cut 1
}
