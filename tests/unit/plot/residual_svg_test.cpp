// GIVEN an analysis result WHEN `nccomp analyze` draws residual against a column THEN the figure
// scales (viewBox), stays inside its canvas, reads time in days or as UTC dates (never
// 1.6671e+05), has nice ticks with units, and skips NaN residuals with a note.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <regex>
#include <string>

#include "tests/unit/plot/svg_check.hpp"
#include "tools/analyze/report.hpp"

namespace cm = nccomp::core::model;
namespace svg = nccomp::test::svg;

namespace {

// n rows: time_s from t0 over span_s, x_mm 0…(n−1)·2.5, residuals of a few µm.
void make(std::size_t n, double t0, double span_s, cm::Dataset* d, cm::AnalysisResult* r) {
  auto& t = d->columns[static_cast<std::size_t>(cm::Column::kTime)];
  auto& x = d->columns[static_cast<std::size_t>(cm::Column::kX)];
  for (std::size_t i = 0; i < n; ++i) {
    const double f = static_cast<double>(i) / static_cast<double>(n - 1);
    t.push_back(t0 + span_s * f);
    x.push_back(2.5 * static_cast<double>(i));
    d->target_um.push_back(0.0);
    r->declared_residual_um.push_back(6.0 * std::sin(7.0 * f) + 1.0);
    r->final_residual_um.push_back(0.8 * std::cos(11.0 * f));
    r->heldout.push_back(static_cast<std::uint8_t>(i % 5 == 0 ? 1 : i % 17 == 0 ? 2 : 0));
  }
}

std::vector<std::string> tick_labels(const std::vector<svg::Element>& doc, const char* anchor) {
  std::vector<std::string> out;
  for (const auto* e : svg::texts(doc, "tick-label")) {
    if (e->get("text-anchor") == anchor) out.push_back(e->text);
  }
  return out;
}

void expect_inside(const std::vector<svg::Element>& doc) {
  const auto vb = svg::view_box(doc);
  ASSERT_TRUE(vb.has_value()) << "no viewBox: the figure cannot scale";
  for (const auto& e : doc) {
    const auto b = svg::box(e);
    if (b) {
      EXPECT_TRUE(b->inside(*vb)) << "<" << e.tag << "> '" << e.text << "' outside";
    }
  }
}

bool has_title(const std::vector<svg::Element>& doc, const std::string& title) {
  for (const auto* t : svg::texts(doc, "axis-title")) {
    if (t->text == title) return true;
  }
  return false;
}

}  // namespace

TEST(ResidualSvg, TimeOverSixDaysReadsInDaysInsideAScalableCanvas) {
  cm::Dataset d;
  cm::AnalysisResult r;
  make(400, 0.0, 600000.0, &d, &r);
  const std::string s = nccomp::tools::analyze::residual_svg(d, r, 0);
  const auto doc = svg::parse(s);
  for (const auto& e : doc) {
    EXPECT_FALSE(std::regex_search(e.text, std::regex(R"(\de[+-]?\d)"))) << "exponent: " << e.text;
  }
  expect_inside(doc);
  EXPECT_TRUE(has_title(doc, "time since the first sample [d]"));
  EXPECT_TRUE(has_title(doc, "residual [µm]"));
  const auto x = tick_labels(doc, "middle");
  ASSERT_GE(x.size(), 4U);
  EXPECT_EQ(x.front(), "0");
  // 600 000 s = 6.94 d: the last tick is the first whole tick at or above it.
  const double last = std::stod(x[x.size() / 2 - 1]);
  EXPECT_GE(last, 600000.0 / 86400.0);
  EXPECT_LE(last, 8.0);
  // The y ticks cover the residuals (−5 … 7 µm) and hold 0.
  double lo = 1e300;
  double hi = -1e300;
  for (const auto& l : tick_labels(doc, "end")) {
    lo = std::min(lo, std::stod(l));
    hi = std::max(hi, std::stod(l));
  }
  double rlo = 0.0;
  double rhi = 0.0;
  for (double v : r.declared_residual_um) {
    rlo = std::min(rlo, v);
    rhi = std::max(rhi, v);
  }
  EXPECT_LE(lo, rlo);
  EXPECT_GE(hi, rhi);
  std::size_t circles = 0;
  for (const auto& e : doc) circles += e.tag == "circle" ? 1U : 0U;
  EXPECT_EQ(circles, 2 * d.rows());
}

TEST(ResidualSvg, WallClockTimeReadsAsUtcDates) {
  cm::Dataset d;
  cm::AnalysisResult r;
  make(100, 1795737600.0 + 3600.0, 2 * 86400.0, &d, &r);  // from 2026-11-27 01:00 UTC
  const auto doc = svg::parse(nccomp::tools::analyze::residual_svg(d, r, 0));
  expect_inside(doc);
  EXPECT_TRUE(has_title(doc, "time [UTC, 2026]"));
  const auto x = tick_labels(doc, "middle");
  ASSERT_FALSE(x.empty());
  for (const auto& l : x) {
    EXPECT_TRUE(std::regex_match(l, std::regex(R"((2026-)?11-(2[789]|30)( \d\d:00)?)"))) << l;
  }
}

TEST(ResidualSvg, ColumnUnitIsInTheAxisTitleAndNanResidualsAreCounted) {
  cm::Dataset d;
  cm::AnalysisResult r;
  make(50, 0.0, 100.0, &d, &r);
  r.final_residual_um[3] = std::numeric_limits<double>::quiet_NaN();
  d.columns[static_cast<std::size_t>(cm::Column::kX)][7] = std::numeric_limits<double>::quiet_NaN();
  const auto doc = svg::parse(nccomp::tools::analyze::residual_svg(d, r, 5));
  expect_inside(doc);
  EXPECT_TRUE(has_title(doc, "x [mm]"));
  // Row 7 (no x) in both panels, row 3 in the right one.
  const auto notes = svg::texts(doc, "note");
  ASSERT_EQ(notes.size(), 1U);
  EXPECT_EQ(notes[0]->text, "3 samples not plotted (NaN or infinite)");
  std::size_t circles = 0;
  for (const auto& e : doc) circles += e.tag == "circle" ? 1U : 0U;
  EXPECT_EQ(circles, 2 * d.rows() - 3);
}
