// Issue 21, sessions: GIVEN logs read from several files (or a v2 log with warm starts, or rows
// after a long gap) WHEN analysed with --validate sessions THEN each session is held out in turn:
// its rows are predicted by the declared and the final terms fitted on the other sessions, per
// session and overall; an effect the declared model lacks shows in the declared figures, not in
// the final ones.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <sstream>
#include <string>
#include <vector>

#include "core/model/analysis.hpp"
#include "formats/model/model_io.hpp"
#include "formats/toml/diagnostics.hpp"
#include "tests/unit/model/synth.hpp"
#include "tools/analyze/report.hpp"

namespace cm = nccomp::core::model;
namespace io = nccomp::formats::model_io;
namespace synth = nccomp::test::synth;

namespace {

const char* kHeader =
    "time_s,part,tool,kind,point,x_mm,y_mm,z_mm,angle_deg,path_mm,temp_c,measured_um,applied_um";

}  // namespace

TEST(Sessions, AreFilesWarmStartsAndGapsLongerThanSessionGap) {
  // Two files; the second is a v2 log with two warm starts (session 4, then 5).
  cm::Dataset d;
  std::istringstream a(std::string(kHeader) +
                       "\n0,1,1,contour,0,,,,,,,1,0\n100,1,1,contour,0,,,,,,,1,0\n"
                       "9000,2,1,contour,0,,,,,,,1,0\n");
  io::read_log(a, "a.csv", {}, d);
  std::istringstream b(std::string(kHeader) +
                       ",machine,utc,session\n"
                       "10,3,1,contour,0,,,,,,,1,0,m,2024-05-06T07:00:10Z,4\n"
                       "20,3,1,contour,0,,,,,,,1,0,m,2024-05-06T07:00:20Z,4\n"
                       "5,4,1,contour,0,,,,,,,1,0,m,2024-05-07T07:00:05Z,5\n");
  io::read_log(b, "b.csv", {}, d);
  ASSERT_EQ(d.row_session, (std::vector<std::uint32_t>{0, 0, 0, 1, 1, 2}));
  // No gap rule: the reader's sessions.
  EXPECT_EQ(cm::sessions_of(d, 0.0), (std::vector<std::uint32_t>{0, 0, 0, 1, 1, 2}));
  // A gap of more than 3600 s (100 → 9000 s) starts a session, numbered in order of appearance.
  EXPECT_EQ(cm::sessions_of(d, 3600.0), (std::vector<std::uint32_t>{0, 0, 1, 2, 2, 3}));
}

TEST(Sessions, LeaveOneSessionOutShowsTheMissingEffectInTheDeclaredModelOnly) {
  synth::Options opt;
  opt.seed = 31;
  opt.parts = 60;
  opt.points_per_part = 12;
  opt.noise_um = 0.5;
  opt.effects = {"position_x"};
  cm::Dataset d = synth::generate(opt);
  // Four sessions of 15 parts each (as if read from four files).
  const auto& part = d.column(static_cast<int>(cm::Column::kPart));
  for (std::size_t i = 0; i < d.rows(); ++i) {
    d.row_session.push_back(static_cast<std::uint32_t>((part[i] - 1.0) / 15.0));
  }
  cm::AnalysisConfig c = synth::config();
  c.validate_sessions = true;
  const cm::AnalysisResult r = cm::analyze(d, c);
  ASSERT_FALSE(r.effects.empty());
  EXPECT_EQ(r.effects[0].spec.name, "position_x");
  ASSERT_EQ(r.session_folds.size(), 4U);
  std::size_t rows = 0;
  for (std::size_t s = 0; s < 4; ++s) {
    const cm::SessionFold& f = r.session_folds[s];
    EXPECT_EQ(f.session, s);
    EXPECT_EQ(f.first_row, s * 15 * 12);
    EXPECT_EQ(f.declared.rows, 15U * 12U);
    EXPECT_EQ(f.final_model.rows, 15U * 12U);
    rows += f.final_model.rows;
    // position_x: 1.2u² + u, u = (x − 200)/100 uniform on [−2, 2]: its variance is
    // 1.44 (16/5 − 16/9) + 4/3 = 3.38 µm², so the declared model misses about
    // sqrt(0.25 + 3.38) = 1.9 µm; the final one only the 0.5 µm noise.
    EXPECT_GT(f.declared.rms_um, 1.5) << s;
    EXPECT_LT(f.final_model.rms_um, 0.6) << s;
  }
  EXPECT_EQ(rows, d.rows());
  EXPECT_EQ(r.sessions_final.rows, d.rows());
  EXPECT_GT(r.sessions_declared.rms_um, 1.5 * r.sessions_final.rms_um);
  const std::string j = nccomp::tools::analyze::summary_json(d, r);
  EXPECT_NE(j.find("\"validation\": {\"by\": \"session\", \"declared_rms_um\": "),
            std::string::npos)
      << j;
  EXPECT_NE(
      j.find("{\"session\": 1, \"first_row\": \"row 1\", \"rows\": 180, \"declared_rms_um\": "),
      std::string::npos)
      << j;
}

TEST(Sessions, OneSessionIsAWarningNotAFigure) {
  synth::Options opt;
  opt.parts = 20;
  cm::AnalysisConfig c = synth::config();
  c.validate_sessions = true;
  const cm::AnalysisResult r = cm::analyze(synth::generate(opt), c);
  EXPECT_TRUE(r.session_folds.empty());
  EXPECT_EQ(r.sessions_final.rows, 0U);
  bool warned = false;
  for (const auto& w : r.warnings) warned = warned || w.code == "sessions_too_few";
  EXPECT_TRUE(warned);
}

TEST(Sessions, SessionGapIsReadAndWrittenAndANegativeOneRefused) {
  const std::string term = "[[model.term]]\nname = \"o\"\nform = \"constant\"\n";
  const io::ModelFile f =
      io::read_model_text("[model]\nsession_gap_s = 7200\n" + term, "c.toml", false);
  EXPECT_DOUBLE_EQ(f.config.session_gap_s, 7200.0);
  try {
    io::read_model_text("[model]\nsession_gap_s = -1\n" + term, "c.toml", false);
    ADD_FAILURE() << "accepted";
  } catch (const nccomp::formats::DiagnosticsError& e) {
    EXPECT_EQ(std::string(e.what()),
              "c.toml:2:17: model.session_gap_s: must be 0 (off) or a time > 0 [s]");
  }
  cm::Term t;
  t.spec.name = "o";
  t.groups = {{0.0, 0.0}};
  t.coef = {1.0};
  const std::string text = io::write_model_toml(cm::Model({}, {t}), f.config, {});
  EXPECT_NE(text.find("session_gap_s = 7200.0\n"), std::string::npos) << text;
}

TEST(Sessions, AHeldOutSessionsGroupNoOtherSessionHasIsAWarning) {
  synth::Options opt;
  opt.seed = 31;
  opt.parts = 60;
  opt.points_per_part = 12;
  opt.noise_um = 0.5;
  cm::Dataset d = synth::generate(opt);
  // Four sessions of 15 parts; the last one cut with tool 9, which no other session used.
  auto& tool = d.columns[static_cast<std::size_t>(cm::Column::kTool)];
  const auto& part = d.column(static_cast<int>(cm::Column::kPart));
  std::size_t last_rows = 0;
  std::size_t last_first = d.rows();
  for (std::size_t i = 0; i < d.rows(); ++i) {
    const auto s = static_cast<std::uint32_t>((part[i] - 1.0) / 15.0);
    d.row_session.push_back(s);
    tool[i] = s == 3 ? 9.0 : 1.0;
    if (s == 3) {
      ++last_rows;
      last_first = std::min(last_first, i);
    }
  }
  cm::AnalysisConfig c = synth::config();
  c.validate_sessions = true;
  cm::TermSpec per_tool;
  per_tool.name = "tool_offset";
  per_tool.form = cm::Form::kConstant;
  per_tool.per = {static_cast<int>(cm::Column::kTool), -1};
  c.declared.push_back(per_tool);
  auto session_warnings = [](const cm::AnalysisResult& r) {
    std::vector<std::string> out;
    for (const auto& w : r.warnings) {
      if (w.code == "heldout_unseen_group" && w.message.rfind("--validate sessions", 0) == 0) {
        out.push_back(w.message);
      }
    }
    return out;
  };
  const cm::AnalysisResult r = cm::analyze(d, c);
  ASSERT_EQ(r.session_folds.size(), 4U);
  const auto w = session_warnings(r);
  ASSERT_EQ(w.size(), 1U);
  EXPECT_EQ(
      w[0].rfind("--validate sessions: session 4 (from row " + std::to_string(last_first + 1) +
                     ") held out: " + std::to_string(last_rows) +
                     " of its rows belong to 1 group no other session has (tool_offset "
                     "tool 9)",
                 0),
      0U)
      << w[0];
  // It is in summary.json's warnings.
  const std::string j = nccomp::tools::analyze::summary_json(d, r);
  EXPECT_NE(j.find("{\"code\": \"heldout_unseen_group\", \"message\": \"--validate sessions: "
                   "session 4"),
            std::string::npos)
      << j;

  // Every session with tool 1: every group is in the other sessions, no warning.
  for (auto& v : tool) v = 1.0;
  EXPECT_TRUE(session_warnings(cm::analyze(d, c)).empty());
}

// A log recorded in one piece (FL_THERMAL: 46 h, no warm start) has no session to hold out:
// validate_block_s cuts it into blocks of that length from its first time instead.
TEST(Sessions, ValidateBlockSHoldsOutBlocksOfTimeFromTheFirstRow) {
  synth::Options opt;
  opt.parts = 40;
  cm::Dataset d = synth::generate(opt);
  const auto& t = d.column(static_cast<int>(cm::Column::kTime));
  ASSERT_EQ(t.size(), d.rows());
  const double t0 = *std::min_element(t.begin(), t.end());
  const double t1 = *std::max_element(t.begin(), t.end());
  ASSERT_GT(t1, t0);
  const double block_s = (t1 - t0) / 3.5;  // blocks 0, 1, 2, 3 (the last one half)
  std::vector<std::size_t> rows(4, 0);
  for (const double v : t) ++rows[static_cast<std::size_t>(std::floor((v - t0) / block_s))];
  cm::AnalysisConfig c = synth::config();
  c.validate_sessions = true;
  c.validate_block_s = block_s;
  const cm::AnalysisResult r = cm::analyze(d, c);
  ASSERT_EQ(r.session_folds.size(), 4U);
  for (std::size_t s = 0; s < 4; ++s) {
    EXPECT_EQ(r.session_folds[s].session, s);
    EXPECT_EQ(r.session_folds[s].final_model.rows, rows[s]) << s;
  }
}
