// GIVEN an analysis WHEN its outputs are written THEN summary.json has exactly the keys of
// issue 11 with the analysis' numbers, and the figures are complete SVG documents.
#include <gtest/gtest.h>

#include <regex>
#include <string>

#include "tests/unit/model/synth.hpp"
#include "tools/analyze/report.hpp"

namespace cm = nccomp::core::model;
namespace synth = nccomp::test::synth;

TEST(Report, SummaryJsonHasExactlyTheIssueKeys) {
  synth::Options opt;
  opt.parts = 30;
  opt.effects = {"part_trend"};
  const cm::Dataset d = synth::generate(opt);
  const cm::AnalysisResult r = cm::analyze(d, synth::config());
  ASSERT_EQ(r.effects.size(), 1U);
  const std::string j = nccomp::tools::analyze::summary_json(d, r);
  // Top-level keys in order, and nothing else at the top level.
  const std::regex top(
      R"(^\{\n  "declared_rms_um": [-0-9.e]+,\n  "effects": \[\n    \{.*\}\n  \],\n  "final_rms_um": [-0-9.e]+,\n  "noise_floor_um": [-0-9.e]+,\n  "outliers": \[\],\n  "prediction_interval": \{"level": 0\.95, "rows": [0-9]+, "half_width_um": [0-9.e-]+, "half_width_max_um": [0-9.e-]+, "coverage": [0-9.e-]+, "method": "validation", "sigma_in_sample_um": [0-9.e-]+, "validation_rms_um": [0-9.e-]+, "validation_rows": [0-9]+\},\n  "warnings": \[\]\n\}\n$)");
  EXPECT_TRUE(std::regex_match(j, top)) << j;
  const std::regex effect(
      R"re(\{"name": "part_trend", "label": "part_trend", "per": \[\], "column": "part", "form": "linear", "params": \{"coef_um": \[[-0-9.e]+\]\}, "rms_before_um": [-0-9.e]+, "rms_after_um": [-0-9.e]+, "heldout_rms_before_um": [-0-9.e]+, "heldout_rms_after_um": [-0-9.e]+, "p_value": [-0-9.e]+, "coef_ci95": \[\[[-0-9.e]+, [-0-9.e]+\]\]\})re");
  EXPECT_TRUE(std::regex_search(j, effect)) << j;
  char buf[64];
  std::snprintf(buf, sizeof buf, "\"final_rms_um\": %.6g,", r.final_stats.fitted.rms_um);
  EXPECT_NE(j.find(buf), std::string::npos);
}

TEST(Report, FiguresAreCompleteSvgWithOnePointPerRow) {
  synth::Options opt;
  opt.parts = 10;
  opt.points_per_part = 10;
  opt.effects = {"position_x"};
  const cm::Dataset d = synth::generate(opt);
  const cm::AnalysisResult r = cm::analyze(d, synth::config());
  const auto cols = nccomp::tools::analyze::plotted_columns(d);
  // time, part, tool, point, x, y, z, angle, path, temp vary; kind is never plotted.
  EXPECT_EQ(cols.size(), 10U);
  const std::string svg = nccomp::tools::analyze::residual_svg(d, r, 5);
  EXPECT_EQ(svg.rfind("<svg", 0), 0U);
  EXPECT_EQ(svg.substr(svg.size() - 7), "</svg>\n");
  std::size_t circles = 0;
  for (std::size_t p = svg.find("<circle"); p != std::string::npos;
       p = svg.find("<circle", p + 1)) {
    ++circles;
  }
  EXPECT_EQ(circles, 2 * d.rows());  // before and after panels
}

TEST(Report, TheCandidatesTriedShowAPolynomialsAndALagsDegree) {
  synth::Options opt;
  opt.parts = 30;
  opt.effects = {"position_x"};
  opt.speed_column = true;
  const cm::Dataset d = synth::generate(opt);
  const cm::AnalysisResult r = cm::analyze(d, synth::config(opt));
  const std::string md = nccomp::tools::analyze::report_markdown(d, r, {"log.csv"}, {});
  // The candidates: position_x|y|z and wear_nonlinear are polynomials of degree 2, the speed's
  // thermal_drift a first-order lag of the speed itself (core/model/analysis.cpp).
  const std::string tried = md.substr(md.find("## Candidates tried"));
  const std::regex row(R"(\n\| [^|]+ \| [^|]+ \| (poly|lag)([^|]*) \|)");
  std::size_t poly = 0;
  std::size_t lag = 0;
  for (auto it = std::sregex_iterator(tried.begin(), tried.end(), row);
       it != std::sregex_iterator(); ++it) {
    const std::string form = (*it)[1];
    EXPECT_EQ((*it)[2].str(), form == "poly" ? " (degree 2)" : " (degree 1)") << (*it)[0];
    ++(form == "poly" ? poly : lag);
  }
  EXPECT_GT(poly, 0U) << tried;
  EXPECT_GT(lag, 0U) << tried;
}
