// GIVEN result directories generated here from known surfaces (a known step, a known ramp, a
// known form error), WHEN `nccomp report`'s library reads them, THEN it reports exactly those
// figures; malformed input is refused or counted with file:line.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <numbers>
#include <optional>
#include <string>
#include <vector>

#include "tests/unit/plot/svg_check.hpp"
#include "tools/report/report.hpp"

namespace {

namespace fs = std::filesystem;
namespace rp = nccomp::tools::report;

struct TempDir {
  TempDir() {
    path = fs::temp_directory_path() /
           ("nccomp_report_test_" + std::to_string(::getpid()) + "_" + std::to_string(n++));
    fs::remove_all(path);
    fs::create_directories(path);
  }
  ~TempDir() { fs::remove_all(path); }
  void write(const std::string& name, const std::string& text) const {
    std::ofstream(path / name, std::ios::binary) << text;
  }
  static inline int n = 0;
  fs::path path;
};

std::string g6(double v) {
  char b[64];
  std::snprintf(b, sizeof b, "%.6g", v);
  return b;
}

std::string result_json(const std::string& program, const std::string& files,
                        const std::string& extra_effects = "") {
  return "{\"format\":\"ncsim-result-1\",\"program\":\"" + program +
         "\",\"bus\":\"modbus\",\"sim_time_s\":12.5,\"parts\":1,\"seed\":7,"
         "\"effects\":{\"wear\":{\"enabled\":true,\"rate_um_per_m\":2.5},"
         "\"thermal\":{\"enabled\":false}" +
         extra_effects +
         "},\"writes_received\":3,\"registers\":{\"0\":-8.5,\"22\":1.25},\"alarms_seen\":0,"
         "\"files\":[" +
         files + "]}";
}

// A raster face: `passes` passes along X from 0 to 100 mm at 0.1 mm, pass k at y = k mm; the
// error and offset at (pass, x) come from the functions.
template <typename ErrFn, typename OffFn>
std::string surface_csv(int passes, ErrFn err, OffFn off) {
  std::string s = "pass,path_mm,x_mm,y_mm,z_mm,error_um,offset_um\n";
  double path = 0.0;
  for (int p = 0; p < passes; ++p) {
    for (int i = 0; i <= 1000; ++i) {
      const double x = 0.1 * i;
      s += std::to_string(p) + "," + g6(path) + "," + g6(x) + "," + g6(p * 1.0) + ",0," +
           g6(err(p, x)) + "," + g6(off(p, x)) + "\n";
      path += 0.1;
    }
  }
  return s;
}

// An 8 µm wear is removed either as one step (prior art) at pass 5, x = 50 mm, or by creeping
// the same 8 µm in over 200 mm of path.
TEST(ReportSurface, AKnownEightMicronStepIsReportedAsEightMicrons) {
  TempDir d;
  auto off = [](int p, double x) { return (p > 5 || (p == 5 && x >= 50.0)) ? -8.0 : 0.0; };
  // Uncompensated error 8 µm; the offset removes it at once.
  auto err = [&](int p, double x) { return 8.0 + off(p, x); };
  d.write("surface.csv", surface_csv(10, err, off));
  d.write("result.json", result_json("mould_face", "\"surface.csv\""));
  const auto r = rp::load_report(d.path.string());
  ASSERT_TRUE(r.surface);
  EXPECT_EQ(r.surface->passes, 10U);
  EXPECT_EQ(r.surface->form.samples, 10U * 1001U);
  EXPECT_NEAR(r.surface->max_step.value_um, 8.0, 1e-9);
  EXPECT_EQ(r.surface->max_step.group, 5);
  EXPECT_NEAR(r.surface->max_step.position_mm, 5 * 100.1 + 50.0, 1e-3);
  EXPECT_NEAR(r.surface->max_offset_step.value_um, 8.0, 1e-9);
  // Pass 6 lies next to pass 5, whose first half was still uncorrected: 8 µm between passes.
  EXPECT_EQ(r.surface->along, "x_mm");
  EXPECT_NEAR(r.surface->max_step_between_passes.value_um, 8.0, 1e-9);
  EXPECT_NEAR(r.surface->max_offset_jump_between_passes.value_um, 0.0, 1e-12);
  // Form error: 5.5 passes at 8 µm, 4.5 at 0 (exact count: pass 5 has x < 50 for 500 samples).
  const double n8 = 5 * 1001 + 500;
  const double n = 10 * 1001;
  EXPECT_NEAR(r.surface->form.rms_um, std::sqrt(64.0 * n8 / n), 1e-9);
  EXPECT_NEAR(std::fabs(r.surface->form.max_abs.value_um), 8.0, 1e-12);
  EXPECT_NEAR(r.surface->form.mean_um, 8.0 * n8 / n, 1e-9);
  EXPECT_EQ(r.bad_rows, 0U);
  EXPECT_EQ(r.info.program, "mould_face");
  EXPECT_EQ(r.info.seed, 7);
  ASSERT_EQ(r.info.effects.size(), 2U);
  EXPECT_TRUE(r.info.effects[0].second.enabled);
  EXPECT_FALSE(r.info.effects[1].second.enabled);
  EXPECT_DOUBLE_EQ(r.info.registers.at(0), -8.5);
}

TEST(ReportSurface, CreepingTheSameEightMicronsOverTwoHundredMillimetresLeavesAFourNanometreStep) {
  TempDir d;
  // Offset ramps from 0 to −8 µm over 200 mm of path starting at pass 5, x = 50 mm.
  const double start = 5 * 100.1 + 50.0;
  auto off = [&](int p, double x) {
    const double path = p * 100.1 + x;  // path_mm of that sample (0.1 mm per sample)
    const double f = std::clamp((path - start) / 200.0, 0.0, 1.0);
    return -8.0 * f;
  };
  auto err = [&](int p, double x) { return 8.0 + off(p, x); };
  d.write("surface.csv", surface_csv(10, err, off));
  d.write("result.json", result_json("mould_face", "\"surface.csv\""));
  const auto r = rp::load_report(d.path.string());
  ASSERT_TRUE(r.surface);
  // h·Δs/L = 8 µm · 0.1 mm / 200 mm = 0.004 µm (the %.6g rounding adds at most 1e-5 µm).
  EXPECT_NEAR(r.surface->max_step.value_um, 0.004, 2e-5);
  EXPECT_NEAR(r.surface->max_offset_step.value_um, 0.004, 2e-5);
  // The jump at a pass boundary inside the ramp: one sample's share too (0.1 mm apart in path).
  EXPECT_LT(r.surface->max_offset_jump_between_passes.value_um, 0.01);
}

TEST(ReportSurface, SineFormErrorHasRmsAmplitudeOverRootTwo) {
  TempDir d;
  // Two full periods along every pass: RMS = A/√2 over whole periods (1000 intervals + 1 sample).
  auto err = [](int, double x) { return 3.0 * std::sin(2.0 * std::numbers::pi * x / 50.0); };
  auto off = [](int, double) { return 0.0; };
  d.write("surface.csv", surface_csv(3, err, off));
  d.write("result.json", result_json("roll", "\"surface.csv\""));
  const auto r = rp::load_report(d.path.string());
  ASSERT_TRUE(r.surface);
  EXPECT_NEAR(r.surface->form.rms_um, 3.0 / std::sqrt(2.0), 0.01);
  EXPECT_NEAR(std::fabs(r.surface->form.max_abs.value_um), 3.0, 1e-4);
  EXPECT_NEAR(r.surface->max_step_between_passes.value_um, 0.0, 1e-9);
  // Steepest slope 3·2π/50 µm/mm over 0.1 mm.
  EXPECT_NEAR(r.surface->max_step.value_um, 3.0 * 2.0 * std::numbers::pi / 50.0 * 0.1, 1e-4);
}

TEST(ReportSurface, PassesAreComparedAtTheSamePositionEvenWhenTheRasterZigzags) {
  TempDir d;
  // Odd passes run backwards (x from 100 to 0); pass k has a constant error of 2k µm, so
  // neighbouring passes differ by exactly 2 µm everywhere.
  std::string s = "pass,path_mm,x_mm,y_mm,z_mm,error_um,offset_um\n";
  double path = 0.0;
  for (int p = 0; p < 4; ++p) {
    for (int i = 0; i <= 200; ++i) {
      const double x = p % 2 == 0 ? 0.5 * i : 100.0 - 0.5 * i;
      s += std::to_string(p) + "," + g6(path) + "," + g6(x) + "," + g6(p) + ",0," + g6(2.0 * p) +
           ",0\n";
      path += 0.5;
    }
  }
  d.write("surface.csv", s);
  d.write("result.json", result_json("mould_face", "\"surface.csv\""));
  const auto r = rp::load_report(d.path.string());
  ASSERT_TRUE(r.surface);
  EXPECT_NEAR(r.surface->max_step.value_um, 0.0, 1e-12);
  EXPECT_NEAR(r.surface->max_step_between_passes.value_um, 2.0, 1e-12);
}

TEST(ReportWalls, PerCheckpointWallErrorAndPerPartFormError) {
  TempDir d;
  // Three parts, two layers, contour 0..40 mm; part k's wall error is 6/(k+1) µm everywhere, so
  // the learned compensation shows as a falling error part after part.
  std::string w = "part,layer,z_mm,s_mm,error_um,offset_um\n";
  std::string c = "part,checkpoint,layer,z_mm,s_mm,error_um,probed_um\n";
  for (int part = 1; part <= 3; ++part) {
    const double e = 6.0 / part;
    for (int layer = 0; layer < 2; ++layer) {
      for (int i = 0; i <= 400; ++i) {
        w += std::to_string(part) + "," + std::to_string(layer) + "," + g6(-2.0 * layer) + "," +
             g6(0.1 * i) + "," + g6(e) + "," + g6(-(6.0 - e)) + "\n";
      }
      for (int cp = 0; cp < 2; ++cp) {
        // Checkpoint 2·layer + cp at s = 10 / 30 mm; the probe reads 0.5 µm high.
        c += std::to_string(part) + "," + std::to_string(2 * layer + cp) + "," +
             std::to_string(layer) + "," + g6(-2.0 * layer) + "," + g6(10.0 + 20.0 * cp) + "," +
             g6(e) + "," + g6(e + 0.5) + "\n";
      }
    }
  }
  d.write("walls.csv", w);
  d.write("checkpoints.csv", c);
  d.write("result.json", result_json("side_wall", "\"walls.csv\",\"checkpoints.csv\""));
  const auto r = rp::load_report(d.path.string());
  ASSERT_TRUE(r.walls);
  EXPECT_EQ(r.walls->parts, 3U);
  EXPECT_EQ(r.walls->layers, 2U);
  ASSERT_EQ(r.walls->per_part.size(), 3U);
  EXPECT_NEAR(r.walls->per_part[0].form.rms_um, 6.0, 1e-9);
  EXPECT_NEAR(r.walls->per_part[2].form.rms_um, 2.0, 1e-5);
  EXPECT_NEAR(std::fabs(r.walls->form.max_abs.value_um), 6.0, 1e-9);
  EXPECT_NEAR(r.walls->form.rms_um, std::sqrt((36.0 + 9.0 + 4.0) / 3.0), 1e-5);
  EXPECT_NEAR(r.walls->max_step.value_um, 0.0, 1e-12);
  ASSERT_EQ(r.checkpoints.size(), 4U);
  for (const auto& cp : r.checkpoints) {
    EXPECT_EQ(cp.parts, 3U);
    EXPECT_EQ(cp.first_part, 1);
    EXPECT_EQ(cp.last_part, 3);
    EXPECT_NEAR(cp.first_error_um, 6.0, 1e-9);
    EXPECT_NEAR(cp.last_error_um, 2.0, 1e-5);
    EXPECT_NEAR(cp.max_abs_error_um, 6.0, 1e-9);
    EXPECT_NEAR(cp.probe_rms_um, 0.5, 1e-5);
    EXPECT_EQ(cp.layer, cp.checkpoint / 2);
  }
  EXPECT_NEAR(r.checkpoints[1].s_mm, 30.0, 1e-9);
  EXPECT_NEAR(r.checkpoints[2].z_mm, -2.0, 1e-9);
}

TEST(ReportTouches, GroupsTouchesAndMeasuresHowTheyFollowTheDrift) {
  TempDir d;
  // Axis X from + and −: the trigger moves with the drift (+) resp. against it (−), 1 µm per
  // cycle, plus a fixed 0.2 µm miss on every other touch of the + group.
  std::string t = "cycle,probe,axis,direction,variant,trigger_position_mm,true_drift_um\n";
  for (int cyc = 0; cyc < 10; ++cyc) {
    const double drift = 1.0 * cyc;
    const double miss = cyc % 2 == 1 ? 0.2 : 0.0;
    t += std::to_string(cyc) + ",0,0,1,0," + g6(50.0 + (drift + miss) / 1000.0) + "," + g6(drift) +
         "\n";
    t += std::to_string(cyc) + ",0,0,-1,0," + g6(-50.0 - drift / 1000.0) + "," + g6(drift) + "\n";
  }
  d.write("touches.csv", t);
  d.write("result.json", result_json("touch", "\"touches.csv\""));
  const auto r = rp::load_report(d.path.string());
  ASSERT_EQ(r.touches.size(), 2U);
  // Groups ordered by key: direction −1 first.
  const auto& minus = r.touches[0];
  const auto& plus = r.touches[1];
  EXPECT_EQ(minus.direction, -1);
  EXPECT_EQ(plus.touches, 10U);
  EXPECT_NEAR(minus.trigger_spread_um, 9.0, 1e-6);
  EXPECT_NEAR(minus.tracking_rms_um, 0.0, 1e-6);
  EXPECT_NEAR(plus.trigger_spread_um, 9.2, 1e-6);
  // Half the touches miss by 0.2 µm: RMS 0.2/√2.
  EXPECT_NEAR(plus.tracking_rms_um, 0.2 / std::sqrt(2.0), 1e-6);
  EXPECT_NEAR(plus.drift_last_um, 9.0, 1e-12);
}

TEST(ReportWrites, PerRegisterCountsValuesAndLatency) {
  TempDir d;
  std::string w = "t_s,register_index,value_um,effective_t_s\n";
  w += "0.5,0,-1,0.52\n1.0,0,-3.5,1.02\n1.5,22,0.25,1.53\n2.0,0,-4,2.02\n";
  d.write("writes.csv", w);
  d.write("surface.csv", surface_csv(
                             1, [](int, double) { return 1.0; }, [](int, double) { return 0.0; }));
  d.write("result.json", result_json("mould_face", "\"surface.csv\",\"writes.csv\""));
  const auto r = rp::load_report(d.path.string());
  ASSERT_EQ(r.writes.size(), 2U);
  EXPECT_EQ(r.writes[0].register_index, 0);
  EXPECT_EQ(r.writes[0].writes, 3U);
  EXPECT_DOUBLE_EQ(r.writes[0].first_value_um, -1.0);
  EXPECT_DOUBLE_EQ(r.writes[0].last_value_um, -4.0);
  EXPECT_DOUBLE_EQ(r.writes[0].max_change_um, 2.5);
  EXPECT_NEAR(r.writes[0].mean_latency_s, 0.02, 1e-12);
  EXPECT_EQ(r.writes[1].register_index, 22);
  EXPECT_NEAR(r.writes[1].mean_latency_s, 0.03, 1e-12);
  // One pass: no between-pass figures.
  ASSERT_TRUE(r.surface);
  EXPECT_EQ(r.surface->passes, 1U);
  EXPECT_EQ(r.surface->along, "");
}

TEST(ReportCsv, BadRowsAreSkippedCountedAndNamedWithFileAndLine) {
  const std::string text =
      "pass,path_mm,x_mm,y_mm,z_mm,error_um,offset_um\n"
      "0,0,0,0,0,1,0\n"
      "0,0.1,0.1,0,0,nan,0\n"  // line 3: not finite
      "0.5,0.2,0.2,0,0,1,0\n"  // line 4: fraction in an integer column
      "0,0.3,0.3,0,0,1\n"      // line 5: too few fields
      "0,0.4,0.4,0,0,1x,0\n"   // line 6: trailing garbage
      "\n"                     // line 7: gap
      "0,0.5,0.5,0,0,2,0\r\n"  // CRLF accepted
      "0,0.6,0.6,0,0,,0\n";    // line 9: empty field
  const auto t = rp::parse_csv(text, "dir/surface.csv", rp::surface_schema());
  EXPECT_EQ(t.rows(), 2U);
  EXPECT_EQ(t.bad_rows, 6U);
  ASSERT_EQ(t.bad_row_messages.size(), 6U);
  EXPECT_EQ(t.bad_row_messages[0], "dir/surface.csv:3: column error_um: not finite: 'nan'");
  EXPECT_EQ(t.bad_row_messages[1], "dir/surface.csv:4: column pass: not an integer: '0.5'");
  EXPECT_EQ(t.bad_row_messages[2], "dir/surface.csv:5: expected 7 fields, got 6");
  EXPECT_EQ(t.bad_row_messages[3], "dir/surface.csv:6: column error_um: not a number: '1x'");
  EXPECT_EQ(t.bad_row_messages[4], "dir/surface.csv:7: empty line");
  EXPECT_EQ(t.bad_row_messages[5], "dir/surface.csv:9: column error_um: empty field");
  EXPECT_EQ(t.lines[1], 8U);
  EXPECT_DOUBLE_EQ(t.at(1, 5), 2.0);
}

TEST(ReportCsv, AWrongHeaderIsRefusedNamingTheFile) {
  try {
    (void)rp::parse_csv("pass,path_mm,x_mm,y_mm,z_mm,error_um\n0,0,0,0,0,1\n", "d/surface.csv",
                        rp::surface_schema());
    FAIL() << "accepted a wrong header";
  } catch (const rp::ReportInputError& e) {
    EXPECT_NE(std::string(e.what()).find("d/surface.csv:1: header must be "), std::string::npos)
        << e.what();
  }
  EXPECT_THROW((void)rp::parse_csv("", "d/x.csv", rp::writes_schema()), rp::ReportInputError);
  // A comment line before the header is not allowed (C3: exactly the header first).
  EXPECT_THROW((void)rp::parse_csv("# ncsim\nt_s,register_index,value_um,effective_t_s\n",
                                   "d/w.csv", rp::writes_schema()),
               rp::ReportInputError);
}

TEST(ReportResultJson, MissingOrMalformedPartsAreRefusedNamingTheKey) {
  auto refuse = [](const std::string& json, const std::string& expect) {
    try {
      (void)rp::result_info_from_json(rp::parse_json(json, "r.json"), "r.json");
      ADD_FAILURE() << "accepted: " << json;
    } catch (const rp::ReportInputError& e) {
      EXPECT_NE(std::string(e.what()).find(expect), std::string::npos) << e.what();
    }
  };
  refuse("{\"format\":\"x\"}", "format \"x\" is not \"ncsim-result-1\"");
  refuse("[1,2", "r.json:1:5: expected ']'");
  refuse("{\"a\":tru}", "r.json:1:6:");
  refuse(std::string(100, '['), "nested deeper than 64 levels");
  std::string ok = result_json("mould_face", "\"surface.csv\"");
  refuse(
      std::string(ok).replace(ok.find("\"program\":\"mould_face\""), 22, "\"program\":\"drill\""),
      "program \"drill\"");
  refuse(std::string(ok).replace(ok.find("\"surface.csv\""), 13, "\"../etc\""),
         "not a plain file name");
  refuse(std::string(ok).replace(ok.find("\"seed\":7"), 8, "\"seed\":-1"), "\"seed\" must be");
  const auto info = rp::result_info_from_json(rp::parse_json(ok, "r.json"), "r.json");
  ASSERT_EQ(info.effects[0].second.params.size(), 1U);
  EXPECT_EQ(info.effects[0].second.params[0].first, "rate_um_per_m");
  EXPECT_EQ(info.effects[0].second.params[0].second, "2.5");
}

TEST(ReportLoad, AProgramsFileThatIsMissingIsAnError) {
  TempDir d;
  d.write("result.json", result_json("side_wall", "\"walls.csv\""));
  try {
    (void)rp::load_report(d.path.string());
    FAIL() << "accepted a side_wall result without walls.csv";
  } catch (const rp::ReportInputError& e) {
    EXPECT_NE(std::string(e.what()).find("walls.csv: missing"), std::string::npos) << e.what();
  }
}

TEST(ReportOutput, JsonCarriesTheFiguresAndSvgHasOneLinePerPassAndOffset) {
  TempDir d;
  auto off = [](int p, double) { return p >= 2 ? -5.0 : 0.0; };
  auto err = [&](int p, double) { return 5.0 + off(p, 0.0); };
  d.write("surface.csv", surface_csv(4, err, off));
  d.write("result.json", result_json("mould_face", "\"surface.csv\""));
  rp::ResultTables tables;
  const auto r = rp::load_report(d.path.string(), &tables);
  const auto j = rp::parse_json(rp::report_json(r), "report.json");
  const auto* surface = j.find("surface");
  ASSERT_NE(surface, nullptr);
  EXPECT_NEAR(surface->find("max_step_between_passes_um")->number, 5.0, 1e-9);
  EXPECT_NEAR(surface->find("max_offset_jump_between_passes_um")->number, 5.0, 1e-9);
  EXPECT_NEAR(surface->find("max_step_um")->number, 0.0, 1e-12);
  EXPECT_NEAR(surface->find("form")->find("rms_um")->number, std::sqrt(25.0 / 2.0),
              1e-7);  // %.9g in the JSON
  EXPECT_EQ(j.find("program")->string, "mould_face");
  EXPECT_EQ(j.find("bad_rows")->number, 0.0);
  const std::string svg = rp::plot_svg(r, tables);
  std::size_t lines = 0;
  for (std::size_t p = svg.find("<polyline"); p != std::string::npos;
       p = svg.find("<polyline", p + 1)) {
    ++lines;
  }
  EXPECT_EQ(lines, 8U);
  EXPECT_EQ(svg.rfind("<svg", 0), 0U);
  EXPECT_NE(svg.find("</svg>"), std::string::npos);
  const std::string text = rp::report_text(r);
  EXPECT_NE(text.find("5.000 um between neighbouring passes along x_mm"), std::string::npos)
      << text;
}

// The plot scales (viewBox, width 100 %), everything is inside it, the axes carry their units,
// and the legend and the figures sit in bands under the plot, not on the data.
TEST(ReportOutput, SvgIsInsideItsCanvasWithUnitsAndTheLegendOffTheData) {
  TempDir d;
  auto off = [](int p, double x) { return p >= 2 && x > 40.0 ? -1200.0 : 0.0; };
  auto err = [&](int p, double x) { return 5.0 + 0.01 * x * p + off(p, x) / 400.0; };
  d.write("surface.csv", surface_csv(5, err, off));
  d.write("result.json", result_json("mould_face", "\"surface.csv\""));
  rp::ResultTables tables;
  const auto r = rp::load_report(d.path.string(), &tables);
  namespace svg = nccomp::test::svg;
  const auto doc = svg::parse(rp::plot_svg(r, tables));
  const auto vb = svg::view_box(doc);
  ASSERT_TRUE(vb.has_value());
  EXPECT_EQ(doc[0].get("width"), "100%");
  std::optional<svg::Box> frame;
  for (const auto& e : doc) {
    const auto b = svg::box(e);
    if (b) {
      EXPECT_TRUE(b->inside(*vb)) << "<" << e.tag << "> '" << e.text << "'";
    }
    if (e.tag == "rect" && e.get("fill") == "none") frame = b;
  }
  ASSERT_TRUE(frame.has_value());
  std::vector<std::string> titles;
  for (const auto* t : svg::texts(doc, "axis-title")) titles.push_back(t->text);
  EXPECT_EQ(titles, (std::vector<std::string>{"path [mm]", "error (+ = material left) [µm]",
                                              "offset in force, dashed [µm]"}));
  // The offset axis reaches −1 200 µm, written without an exponent.
  bool grouped = false;
  for (const auto* t : svg::texts(doc, "tick-label")) grouped = grouped || t->text == "-1 200";
  EXPECT_TRUE(grouped);
  std::size_t below = 0;
  for (const char* cls : {"legend", "note"}) {
    for (const auto* t : svg::texts(doc, cls)) {
      EXPECT_FALSE(svg::box(*t)->intersects(*frame)) << t->text;
      ++below;
    }
  }
  EXPECT_EQ(below, 4U + 2U);  // error / offset × first / last pass; the pass count, the figures
}

}  // namespace
