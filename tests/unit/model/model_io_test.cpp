// GIVEN logs, mappings and model files WHEN read THEN values arrive in their columns, and every
// bad input is refused with its file, line and column named.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <sstream>

#include "formats/model/model_io.hpp"
#include "formats/toml/diagnostics.hpp"
#include "tests/unit/model/synth.hpp"

namespace cm = nccomp::core::model;
namespace io = nccomp::formats::model_io;

namespace {

const char* kHeader =
    "time_s,part,tool,kind,point,x_mm,y_mm,z_mm,angle_deg,path_mm,temp_c,measured_um,applied_um";

std::string error_of(const std::string& csv, const io::Mapping& m = {}) {
  std::istringstream in(csv);
  cm::Dataset d;
  try {
    io::read_log(in, "log.csv", m, d);
  } catch (const nccomp::formats::DiagnosticsError& e) {
    return e.what();
  }
  return "";
}

}  // namespace

TEST(ReadLog, ReadsV1RowsIgnoringExtraColumnsAndEmptyAsUnknown) {
  std::istringstream in(std::string(kHeader) + ",operator\n" +
                        "1.5,3,2,contour,4,10,20,-5,30,1200,,2.5,0.5,anna\n"
                        "2,3,2,tool_wear,1,,,,45,1300,21.5,7,0,bob\r\n");
  cm::Dataset d;
  io::read_log(in, "log.csv", {}, d);
  ASSERT_EQ(d.rows(), 2U);
  EXPECT_DOUBLE_EQ(d.column(0)[0], 1.5);
  EXPECT_DOUBLE_EQ(d.column(3)[0], 1.0);  // contour
  EXPECT_DOUBLE_EQ(d.column(3)[1], 0.0);  // tool_wear
  EXPECT_TRUE(std::isnan(d.column(10)[0]));
  EXPECT_TRUE(std::isnan(d.column(5)[1]));
  EXPECT_DOUBLE_EQ(d.target_um[0], 3.0);  // measured + applied
  EXPECT_DOUBLE_EQ(d.target_um[1], 7.0);
}

TEST(ReadLog, ReadsV2WhereTimeRestartsWithEachSessionAndKeepsTheContextColumns) {
  // Two warm starts in one file (the collector's per-machine log): session 4 from 0 s, session 5
  // from 0 s again; the second session's rows are ordered after the first one's.
  const std::string h = std::string(kHeader) + ",machine,utc,session,spindle_temp_c\n";
  std::istringstream in(h +
                        "10,1,2,contour,4,,,,,,,1.0,0,m1,2024-05-06T07:00:10.000Z,4,30.5\n"
                        "20,1,2,contour,4,,,,,,,2.0,0,m1,2024-05-06T07:00:20.000Z,4,31.0\n"
                        "3,2,2,contour,4,,,,,,,3.0,0,m1,2024-05-06T09:00:03.000Z,5,22.0\n"
                        "8,2,2,contour,4,,,,,,,4.0,0,m1,2024-05-06T09:00:08.000Z,5,\n");
  cm::Dataset d;
  d.extra_columns = {"spindle_temp_c"};
  io::read_log(in, "log.csv", {}, d);
  ASSERT_EQ(d.rows(), 4U);
  EXPECT_DOUBLE_EQ(d.column(0)[2], 3.0);  // time_s as written: since the warm start
  ASSERT_EQ(d.order_s.size(), 4U);
  EXPECT_DOUBLE_EQ(d.order_s[0], 10.0);
  EXPECT_DOUBLE_EQ(d.order_s[1], 20.0);
  EXPECT_DOUBLE_EQ(d.order_s[2], 21.0);  // after 20 s: 20 + 1 - 3 + 3
  EXPECT_DOUBLE_EQ(d.order_s[3], 26.0);
  EXPECT_DOUBLE_EQ(d.column(cm::kStandardColumns)[1], 31.0);
  EXPECT_TRUE(std::isnan(d.column(cm::kStandardColumns)[3]));

  const std::string r = ",,,,,,,1.0,0,m1,2024-05-06T07:00:10.000Z,";
  // Within a session time_s still must not go back, nor the session itself.
  EXPECT_EQ(
      error_of(h + "10,1,2,contour,4" + r + "4,1\n8,1,2,contour,4" + r + "4,1\n").substr(0, 35),
      "log.csv:3:1: time_s: goes backwards");
  EXPECT_EQ(error_of(h + "10,1,2,contour,4" + r + "4,1\n8,1,2,contour,4" + r + "3,1\n"),
            "log.csv:3:16: session: goes backwards (3 after 4); the log must be in time order");
  EXPECT_EQ(error_of(h + "10,1,2,contour,4" + r + "x,1\n"),
            "log.csv:2:16: session: 'x' is not a warm-start number (an integer >= 0)");
  EXPECT_EQ(
      error_of(h + "10,1,2,contour,4" + r + "4,1\n11,1,2,contour,4,,,,,,,1.0,0,m2,," + "4,1\n"),
      "log.csv:3:14: machine: 'm2' in a log of 'm1' (line 2): analyze one machine's log at a "
      "time");
}

TEST(ReadLog, NamesFileLineAndColumnOfBadInput) {
  const std::string h = std::string(kHeader) + "\n";
  EXPECT_EQ(error_of(h + "1,1,1,contour,1,x,0,0,0,0,,1,0\n"),
            "log.csv:2:6: x_mm: 'x' is not a finite number");
  EXPECT_EQ(error_of(h + "1,1,1,probe,1,0,0,0,0,0,,1,0\n"),
            "log.csv:2:4: kind: 'probe' is not tool_wear, contour or calib");
  EXPECT_EQ(error_of(h + "5,1,1,contour,1,0,0,0,0,0,,1,0\n4,1,1,contour,1,0,0,0,0,0,,1,0\n")
                .substr(0, 35),
            "log.csv:3:1: time_s: goes backwards");
  EXPECT_EQ(error_of(h + "1,1.5,1,contour,1,0,0,0,0,0,,1,0\n"),
            "log.csv:2:2: part: must be an integer");
  EXPECT_EQ(error_of(h + "1,1,1,contour\n").substr(0, 29), "log.csv:2:5: point: missing (");
  EXPECT_EQ(error_of("time_s,part\n1,2\n"), "log.csv:1: tool: required column missing");
  EXPECT_EQ(error_of(h), "log.csv:1: no data rows");
  EXPECT_EQ(error_of(h + "1,1,1,contour,1,0,0,0,0,0,,inf,0\n"),
            "log.csv:2:12: measured_um: 'inf' is not a finite number");
}

TEST(ReadLog, MapsAForeignUtf8WideCsv) {
  const io::Mapping m = io::read_mapping_text(R"toml(
[columns]
time_s = "時間(s)"
path_mm = "cut"
[scale]
path_mm = 108.0
[constant]
kind = "tool_wear"
tool = 4
[extra]
t1 = "t1(°C)"
[wide]
measured_um = ["flute_1", "flute_2"]
points = [1, 2]
)toml",
                                              "map.toml");
  std::istringstream in(
      "\xEF\xBB\xBF時間(s) ,cut,flute_1,flute_2,t1(°C)\n0,1,10,11,20.5\n15,2,12,,21\n");
  cm::Dataset d;
  d.extra_columns = {"t1"};
  io::read_log(in, "phm.csv", m, d);
  ASSERT_EQ(d.rows(), 4U);
  EXPECT_DOUBLE_EQ(d.column(9)[2], 216.0);
  EXPECT_DOUBLE_EQ(d.column(4)[1], 2.0);
  EXPECT_DOUBLE_EQ(d.column(2)[3], 4.0);
  EXPECT_DOUBLE_EQ(d.column(11)[3], 21.0);
  EXPECT_DOUBLE_EQ(d.target_um[1], 11.0);
  EXPECT_TRUE(std::isnan(d.target_um[3]));
}

// GIVEN nccompd's log directory, a missing path, or the log file itself WHEN read as a log THEN
// the first two are errors naming the path (a directory is not reported as an empty file) and
// the third is read.
TEST(ReadLogFile, ADirectoryOrAMissingPathIsAnErrorNamingThePath) {
  namespace fs = std::filesystem;
  const fs::path dir = fs::path(::testing::TempDir()) / "read_log_file_test";
  fs::remove_all(dir);
  fs::create_directories(dir);
  const auto error_of_file = [](const fs::path& p) -> std::string {
    cm::Dataset d;
    try {
      io::read_log_file(p.string(), {}, d);
    } catch (const nccomp::formats::DiagnosticsError& e) {
      return e.what();
    }
    return "";
  };
  EXPECT_EQ(error_of_file(dir), dir.string() + ": is a directory, not a log file");
  EXPECT_EQ(error_of_file(dir / "missing.csv"), (dir / "missing.csv").string() + ": cannot open");
  {
    std::ofstream f(dir / "measurements.csv");
    f << kHeader << "\n1,1,1,contour,1,0,0,0,0,0,,1.5,0\n";
  }
  EXPECT_EQ(error_of_file(dir), dir.string() + ": is a directory: give the log file in it, " +
                                    (dir / "measurements.csv").string());
  cm::Dataset d;
  io::read_log_file((dir / "measurements.csv").string(), {}, d);
  ASSERT_EQ(d.rows(), 1U);
  fs::remove_all(dir);
}

TEST(ReadMapping, RefusesUnknownKeysAndColumns) {
  auto err = [](const char* text) {
    try {
      io::read_mapping_text(text, "map.toml");
    } catch (const nccomp::formats::DiagnosticsError& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  EXPECT_EQ(err("[columns]\nspeed = \"x\"\n"),
            "map.toml:2:9: columns.speed: not a measurement-log column");
  EXPECT_EQ(err("[colums]\n").substr(0, 26), "map.toml:1:1: .colums: unk");
  EXPECT_EQ(err("[constant]\nkind = \"probe\"\n"),
            "map.toml:2:8: constant.kind: unknown kind 'probe'");
  EXPECT_EQ(err("[columns\n").substr(0, 11), "map.toml:1:");
}

TEST(ModelFile, RoundTripsThroughTomlAndEvaluatesTheSame) {
  nccomp::test::synth::Options opt;
  opt.parts = 20;
  opt.effects = {"periodic_x", "thermal_drift"};
  const cm::Dataset d = nccomp::test::synth::generate(opt);
  const cm::AnalysisResult r = cm::analyze(d, nccomp::test::synth::config());
  ASSERT_FALSE(r.effects.empty());
  const std::string text =
      io::write_model_toml(r.final_model, nccomp::test::synth::config(), {"t"});
  const io::ModelFile f = io::read_model_text(text, "model.toml", true);
  const cm::Model back(f.extra_columns, f.fitted_terms);
  cm::EvalState s1 = r.final_model.make_state();
  cm::EvalState s2 = back.make_state();
  for (std::size_t i = 0; i < d.rows(); ++i) {
    const cm::Row row = d.row(i);
    ASSERT_NEAR(r.final_model.evaluate(row, s1), back.evaluate(row, s2), 1e-9) << i;
  }
}

TEST(ModelFile, RefusesBadTerms) {
  auto err = [](const char* text, bool fitted = false) {
    try {
      io::read_model_text(text, "c.toml", fitted);
    } catch (const nccomp::formats::DiagnosticsError& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  EXPECT_EQ(err("[model]\n"), "c.toml: model.term: declare at least one [[model.term]]");
  EXPECT_EQ(err("[[model.term]]\nname = \"a\"\nform = \"cubic\"\n"),
            "c.toml:3:8: model.term[0].form: unknown form 'cubic' (constant, linear, poly, "
            "exp_rise, sine, step, lag, exp_growth, hinge, wear, interaction, session)");
  EXPECT_EQ(err("[[model.term]]\nname = \"a\"\nform = \"sine\"\ncolumn = \"x_mm\"\n"),
            "c.toml:1:1: model.term[0].scale: missing (form sine needs its scale / period / time "
            "constant)");
  EXPECT_EQ(err("[[model.term]]\nname = \"a\"\nform = \"constant\"\nkinds = [\"probe\"]\n"),
            "c.toml:4:9: model.term[0].kinds: unknown kind 'probe' (tool_wear, contour, calib)");
  EXPECT_EQ(err("[[model.term]]\nname = \"a\"\nform = \"constant\"\n", true),
            "c.toml:1:1: model.term[0]: no groups / coef_um: not a fitted model");
  EXPECT_EQ(
      err("[[model.term]]\nname = \"a\"\nform = \"constant\"\ngroups = [[0, 0]]\n"
          "coef_um = [1, 2]\n"),
      "c.toml:5:11: model.term[0].coef_um: expected 1 values (groups × basis functions), got 2");
  EXPECT_EQ(err("[model]\nalpha = 0.9\n[[model.term]]\nname = \"a\"\nform = \"constant\"\n"),
            "c.toml:2:9: model.alpha: must be within (0, 0.5)");
}

// Issue 18: every error of a model.toml is reported at once, each at its own line and column
// (the reader stopped at the first one). what() is the caught type's, so this test also ran on
// the former reader.
TEST(ModelFile, ReportsEveryErrorOfTheFileAtOnce) {
  const std::string text =
      "[model]\nalpha = 0.9\nmax_effects = 2.5\n"         // lines 2, 3
      "[[model.term]]\nname = \"a\"\nform = \"cubic\"\n"  // line 6
      "[[model.term]]\nname = \"\"\nform = \"sine\"\ncolumn = \"x_mm\"\nspeed = 1\n";
  std::string what;
  try {
    (void)io::read_model_text(text, "c.toml", false);
  } catch (const std::exception& e) {
    what = e.what();
  }
  EXPECT_EQ(
      what,
      "c.toml:2:9: model.alpha: must be within (0, 0.5)\n"
      "c.toml:3:15: model.max_effects: must be an integer within [0, 16]\n"
      "c.toml:6:8: model.term[0].form: unknown form 'cubic' (constant, linear, poly, "
      "exp_rise, sine, step, lag, exp_growth, hinge, wear, interaction, session)\n"
      "c.toml:11:9: model.term[1].speed: unknown key (allowed: name, form, column, per, "
      "kinds, degree, center, center_b, scale, between_session_sigma_um, noise_sigma_um, groups, "
      "coef_um)\n"
      "c.toml:8:8: model.term[1].name: must not be empty\n"
      "c.toml:7:1: model.term[1].scale: missing (form sine needs its scale / period / time "
      "constant)");
}

TEST(ReadMapping, ReportsEveryErrorOfTheFileAtOnce) {
  std::string what;
  try {
    (void)io::read_mapping_text(
        "[columns]\nspeed = \"x\"\n[constant]\nkind = \"probe\"\n[scale]\nx_mm = \"2\"\n",
        "map.toml");
  } catch (const nccomp::formats::DiagnosticsError& e) {
    what = e.what();
    EXPECT_EQ(e.diagnostics().items().size(), 3U);
  }
  EXPECT_EQ(what,
            "map.toml:2:9: columns.speed: not a measurement-log column\n"
            "map.toml:6:8: scale.x_mm: must be a number\n"
            "map.toml:4:8: constant.kind: unknown kind 'probe'");
}

// A CSV error's place is structured: the row's line, the field (1-based) and the column's name.
TEST(ReadLog, AnErrorCarriesLineFieldAndColumnName) {
  std::istringstream in(std::string(kHeader) + "\n1,1,1,contour,1,0,0,0,0,0,,1,0\n" +
                        "2,1,1,contour,1,0,0,zz,0,0,,1,0\n");
  cm::Dataset d;
  try {
    io::read_log(in, "log.csv", {}, d);
    ADD_FAILURE() << "accepted z_mm = zz";
  } catch (const nccomp::formats::DiagnosticsError& e) {
    ASSERT_EQ(e.diagnostics().items().size(), 1U);
    const auto& w = e.diagnostics().items()[0].where;
    EXPECT_EQ(w.file, "log.csv");
    EXPECT_EQ(w.line, 3);
    EXPECT_EQ(w.column, 8);  // time_s, part, tool, kind, point, x_mm, y_mm, z_mm
    EXPECT_EQ(w.key_path, "z_mm");
  }
}

// Issue 21: a [scale] on measured_um mapped under [columns] was applied twice (37.1 → 37 101).
TEST(ReadLog, AppliesAScaleOnceWhereverTheColumnIsMapped) {
  const io::Mapping cols = io::read_mapping_text(
      "[columns]\ntime_s = \"t\"\nmeasured_um = \"dev_mm\"\n[scale]\nmeasured_um = 1000.0\n"
      "[constant]\nkind = \"contour\"\n",
      "map.toml");
  std::istringstream in("t,dev_mm\n0,0.0371\n1,-0.002\n");
  cm::Dataset d;
  io::read_log(in, "a.csv", cols, d);
  ASSERT_EQ(d.rows(), 2U);
  EXPECT_NEAR(d.target_um[0], 37.1, 1e-9);
  EXPECT_NEAR(d.target_um[1], -2.0, 1e-9);

  const io::Mapping wide = io::read_mapping_text(
      "[columns]\ntime_s = \"t\"\n[scale]\nmeasured_um = 1000.0\n[constant]\nkind = \"contour\"\n"
      "[wide]\nmeasured_um = [\"p1\", \"p2\"]\npoints = [1, 2]\n",
      "map.toml");
  std::istringstream in2("t,p1,p2\n0,0.0371,0.001\n");
  cm::Dataset d2;
  io::read_log(in2, "b.csv", wide, d2);
  ASSERT_EQ(d2.rows(), 2U);
  EXPECT_NEAR(d2.target_um[0], 37.1, 1e-9);
  EXPECT_NEAR(d2.target_um[1], 1.0, 1e-9);
}

// Issue 21: a row with more fields than the header (a decimal comma) was read with its columns
// shifted.
TEST(ReadLog, RefusesARowWithMoreFieldsThanTheHeader) {
  const std::string h = std::string(kHeader) + "\n";
  EXPECT_EQ(error_of(h + "1,1,1,contour,1,0,0,0,0,0,,1,0\n2,1,1,contour,1,0,0,0,0,0,,37,1,0\n"),
            "log.csv:3: the row has 14 fields, the header 13 (a decimal comma or an unquoted "
            "comma in a field?)");
  const io::Mapping m = io::read_mapping_text(
      "[columns]\ntime_s = \"t\"\nmeasured_um = \"dev\"\n[constant]\nkind = \"contour\"\n",
      "map.toml");
  EXPECT_EQ(error_of("t,dev\n0,37.1\n1,37,1\n", m),
            "log.csv:3: the row has 3 fields, the header 2 (a decimal comma or an unquoted "
            "comma in a field?)");
}

// Found by fuzz_model_log: a time of -5.6e18 s ordered a later run before the rows of the file
// read first (the order's offset lost the last digits). A time beyond ±1e12 s is refused; a date
// in milliseconds with its [scale] is read.
TEST(ReadLog, RefusesATimeBeyondATrillionSecondsNamingTheCell) {
  const std::string h = std::string(kHeader) + "\n";
  EXPECT_EQ(error_of(h + "0,1,1,contour,1,0,0,0,0,0,,1,0\n-5.6e18,1,1,contour,1,0,0,0,0,0,,1,0\n"),
            "log.csv:3:1: time_s: -5.6e+18 s is beyond ±1e12 s: map seconds (a date or a counter "
            "in ms or µs needs a [scale])");
  const io::Mapping ms = io::read_mapping_text(
      "[columns]\ntime_s = \"t_ms\"\nmeasured_um = \"dev\"\n[constant]\nkind = \"contour\"\n",
      "map.toml");
  EXPECT_EQ(error_of("t_ms,dev\n1764374400000,1\n", ms).substr(0, 42),
            "log.csv:2:1: time_s: 1.7643744e+12 s is be");
  const io::Mapping scaled = io::read_mapping_text(
      "[columns]\ntime_s = \"t_ms\"\nmeasured_um = \"dev\"\n[constant]\nkind = \"contour\"\n"
      "[scale]\ntime_s = 0.001\n",
      "map.toml");
  std::istringstream in("t_ms,dev\n1764374400000,1\n1764374415000,2\n");
  cm::Dataset d;
  io::read_log(in, "log.csv", scaled, d);
  ASSERT_EQ(d.rows(), 2U);
  EXPECT_DOUBLE_EQ(d.column(0)[1] - d.column(0)[0], 15.0);
}

// Issue 21: a scale of a column the mapping does not read did nothing, silently.
TEST(ReadMapping, RefusesAScaleOfAColumnItDoesNotRead) {
  auto err = [](const std::string& text) {
    try {
      io::read_mapping_text(text, "map.toml");
    } catch (const nccomp::formats::DiagnosticsError& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  EXPECT_EQ(err("[columns]\nmeasured_um = \"d\"\n[scale]\nx_mm = 2.0\n"),
            "map.toml:4:8: scale.x_mm: not a column mapped under [columns], [extra] or [wide]");
  EXPECT_EQ(err("[columns]\nmeasured_um = \"d\"\n[constant]\ntool = 3\n[scale]\ntool = 2.0\n"),
            "map.toml:6:8: scale.tool: a [constant] is not scaled (write it in the target unit)");
  EXPECT_EQ(err("[columns]\nmeasured_um = \"d\"\n[scale]\nspeed = 2.0\n"),
            "map.toml:4:9: scale.speed: not a column mapped under [columns], [extra] or [wide]");
  EXPECT_EQ(err("[columns]\nmeasured_um = \"d\"\n[extra]\nspeed = \"rpm\"\n[scale]\nspeed = 2.0\n"),
            "");
}

// Issue 21: an exclude naming no effect excluded nothing, silently; a column's kind (temperature
// or not) is declared in the config or the map and survives model.toml.
TEST(ModelFile, RefusesAnUnknownExcludeAndKeepsColumnKinds) {
  const std::string head = "[[model.term]]\nname = \"a\"\nform = \"constant\"\n[model.search]\n";
  auto err = [](const std::string& text) {
    try {
      io::read_model_text(text, "c.toml", false);
    } catch (const nccomp::formats::DiagnosticsError& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  EXPECT_EQ(err(head + "exclude = [\"thermal_drfit\"]\n").substr(0, 76),
            "c.toml:5:11: model.search.exclude: no effect is called 'thermal_drfit' (ther");
  EXPECT_EQ(err(head + "linear_columns = [\"depth_mm\"]\nexclude = [\"linear_depth_mm\"]\n"), "");
  // docs/analyze.md names it; the analysis honours it (core/model/analysis.cpp).
  EXPECT_EQ(err(head + "exclude = [\"session_offset\"]\n"), "");
  EXPECT_EQ(err(head + "exclude = [\"linear_depth_mm\"]\n").substr(0, 71),
            "c.toml:5:11: model.search.exclude: no effect is called 'linear_depth_mm");
  EXPECT_EQ(err(head + "column_kind = { t2 = \"warm\" }\n"),
            "c.toml:5:22: model.search.column_kind.t2: 'warm' is not temperature or other");

  const io::ModelFile f =
      io::read_model_text(head +
                              "linear_columns = [\"t2\", \"depth_c\"]\n"
                              "column_kind = { t2 = \"temperature\", depth_c = \"other\" }\n",
                          "c.toml", false);
  const auto& so = f.config.search;
  ASSERT_EQ(f.extra_columns, (std::vector<std::string>{"t2", "depth_c"}));
  EXPECT_EQ(cm::linear_effect_name(so.linear_columns[0], f.extra_columns, so), "thermal_drift");
  EXPECT_EQ(cm::linear_effect_name(so.linear_columns[1], f.extra_columns, so), "linear_depth_c");
  // Written back into model.toml and read again: the same declaration.
  const cm::Model m(f.extra_columns, {});
  const io::ModelFile back = io::read_model_text(
      io::write_model_toml(m, f.config, {}) + "[[model.term]]\nname = \"a\"\nform = \"constant\"\n",
      "model.toml", false);
  EXPECT_EQ(back.config.search.column_is_temperature, so.column_is_temperature);

  const io::Mapping map = io::read_mapping_text(
      "[columns]\nmeasured_um = \"d\"\n[extra]\nt2 = \"T2\"\n[column_kind]\nt2 = \"temperature\"\n",
      "map.toml");
  EXPECT_EQ(map.column_kind, (std::vector<std::pair<std::string, bool>>{{"t2", true}}));
  try {
    io::read_mapping_text("[columns]\nmeasured_um = \"d\"\n[column_kind]\nt3 = \"other\"\n",
                          "map.toml");
    ADD_FAILURE() << "t3 is not mapped";
  } catch (const nccomp::formats::DiagnosticsError& e) {
    EXPECT_EQ(std::string(e.what()),
              "map.toml:4:6: column_kind.t3: not a log column nor a column of [extra]");
  }
}

// Issue 21, item 2: [model] interval chooses the prediction interval's scale; model.toml carries
// it, and another value is refused with its place.
TEST(ModelFile, ReadsAndWritesTheIntervalMethod) {
  const std::string term = "[[model.term]]\nname = \"a\"\nform = \"constant\"\n";
  EXPECT_EQ(io::read_model_text("[model]\n" + term, "c.toml", false).config.interval,
            cm::IntervalMethod::kValidation);
  const io::ModelFile in =
      io::read_model_text("[model]\ninterval = \"in_sample\"\n" + term, "c.toml", false);
  EXPECT_EQ(in.config.interval, cm::IntervalMethod::kInSample);
  EXPECT_EQ(io::read_model_text("[model]\ninterval = \"validation\"\n" + term, "c.toml", false)
                .config.interval,
            cm::IntervalMethod::kValidation);
  try {
    (void)io::read_model_text("[model]\ninterval = \"bootstrap\"\n" + term, "c.toml", false);
    ADD_FAILURE() << "accepted interval = \"bootstrap\"";
  } catch (const nccomp::formats::DiagnosticsError& e) {
    EXPECT_EQ(std::string(e.what()),
              "c.toml:2:12: model.interval: 'bootstrap' is not validation or in_sample");
  }
  nccomp::test::synth::Options opt;
  opt.parts = 20;
  opt.effects = {"part_trend"};
  const cm::AnalysisResult r =
      cm::analyze(nccomp::test::synth::generate(opt), nccomp::test::synth::config());
  for (const cm::IntervalMethod m :
       {cm::IntervalMethod::kInSample, cm::IntervalMethod::kValidation}) {
    cm::AnalysisConfig c = nccomp::test::synth::config();
    c.interval = m;
    const std::string text = io::write_model_toml(r.final_model, c, {"t"});
    EXPECT_EQ(io::read_model_text(text, "model.toml", true).config.interval, m) << text;
  }
}
