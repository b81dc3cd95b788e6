// GIVEN figures of known data WHEN tools/plot draws them THEN everything is inside the canvas,
// ticks are at 1/2/5·10^k and cover the data, time reads in hours / days / UTC dates, the
// legend keeps clear of the axis labels and NaN samples are skipped and counted.
#include "tools/plot/plot.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <regex>
#include <string>
#include <vector>

#include "tests/unit/plot/svg_check.hpp"

namespace plot = nccomp::tools::plot;
namespace svg = nccomp::test::svg;

namespace {

// The mantissa of a 1/2/5·10^k step.
bool is_nice(double step) {
  const double m = step / std::pow(10.0, std::floor(std::log10(step) + 1e-9));
  return std::fabs(m - 1.0) < 1e-6 || std::fabs(m - 2.0) < 1e-6 || std::fabs(m - 5.0) < 1e-6;
}

// Every text and shape lies inside the viewBox.
void expect_inside(const std::string& doc_text) {
  const auto doc = svg::parse(doc_text);
  const auto vb = svg::view_box(doc);
  ASSERT_TRUE(vb.has_value()) << "no viewBox";
  EXPECT_EQ(doc[0].get("width"), "100%");
  std::size_t checked = 0;
  for (const auto& e : doc) {
    const auto b = svg::box(e);
    if (!b) continue;
    ++checked;
    EXPECT_TRUE(b->inside(*vb)) << "<" << e.tag << "> '" << e.text << "' at [" << b->x0 << ", "
                                << b->y0 << ", " << b->x1 << ", " << b->y1 << "] outside [0, 0, "
                                << vb->x1 << ", " << vb->y1 << "]";
  }
  EXPECT_GT(checked, 10U);
}

// A tick label as a number ("1 200" → 1200).
double label_value(std::string s) {
  s.erase(std::remove(s.begin(), s.end(), ' '), s.end());
  return std::stod(s);
}

plot::Figure scatter(std::vector<double> x, std::vector<double> y, plot::Axis xa) {
  plot::Figure f;
  f.title = "residual vs time";
  plot::Panel p;
  p.title = "declared model";
  p.x = std::move(xa);
  p.y = plot::Axis{"residual", "µm", plot::Scale::kLinear, true};
  plot::Series s;
  s.mark = plot::Mark::kPoints;
  s.x = std::move(x);
  s.y = std::move(y);
  p.series.push_back(std::move(s));
  f.panels.push_back(p);
  f.panels.push_back(p);
  f.legend = {{"fitted rows", "#1f5fa8", plot::Mark::kPoints, false},
              {"held-out rows", "#e07000", plot::Mark::kPoints, false}};
  return f;
}

std::vector<const svg::Element*> x_tick_labels(const std::vector<svg::Element>& doc) {
  std::vector<const svg::Element*> out;
  for (const auto* t : svg::texts(doc, "tick-label")) {
    if (t->get("text-anchor") == "middle") out.push_back(t);
  }
  return out;
}

}  // namespace

TEST(PlotTicks, StepsAreNiceAndCoverTheRange) {
  const std::vector<std::pair<double, double>> ranges = {
      {0, 1},   {-3.2, 7.9},  {0.0012, 0.0047}, {166710, 166715}, {-1e6, 2.5e6},
      {42, 42}, {-0.3, -0.1}, {0, 600000},      {1e-7, 3e-7},     {99.5, 100.5}};
  for (const auto& [lo, hi] : ranges) {
    for (int target : {2, 5, 8}) {
      const auto t = plot::nice_ticks(lo, hi, target);
      SCOPED_TRACE(std::to_string(lo) + ".." + std::to_string(hi));
      EXPECT_TRUE(is_nice(t.step)) << t.step;
      EXPECT_LE(t.first, lo);
      EXPECT_GE(t.last, hi);
      if (hi > lo) {  // a constant gets some room around it
        EXPECT_GT(t.first, lo - t.step);
        EXPECT_LT(t.last, hi + t.step);
      }
      ASSERT_GE(t.values.size(), 2U);
      EXPECT_LE(t.values.size(), static_cast<std::size_t>(2 * target + 2));
      for (std::size_t i = 1; i < t.values.size(); ++i) {
        EXPECT_NEAR(t.values[i] - t.values[i - 1], t.step, t.step * 1e-9);
      }
    }
  }
}

TEST(PlotNumbers, NoExponentAndThousandsGrouped) {
  EXPECT_EQ(plot::format_number(0.5, 0.5), "0.5");
  EXPECT_EQ(plot::format_number(12, 2), "12");
  EXPECT_EQ(plot::format_number(1200, 100), "1 200");
  EXPECT_EQ(plot::format_number(-166700, 100), "-166 700");
  EXPECT_EQ(plot::format_number(1.5, 0.5), "1.5");
  EXPECT_EQ(plot::format_number(0.0012, 0.0002), "0.0012");
  EXPECT_EQ(plot::format_number(-1e-18, 0.1), "0");
  // Every tick of a wide and of a narrow range reads without an exponent.
  for (const auto& [lo, hi] : std::vector<std::pair<double, double>>{{0, 2e7}, {1e-6, 9e-6}}) {
    const auto t = plot::nice_ticks(lo, hi, 6);
    for (double v : t.values) {
      const std::string s = plot::format_number(v, t.step);
      EXPECT_EQ(s.find_first_of("eE"), std::string::npos) << s;
      EXPECT_NEAR(label_value(s), v, t.step * 1e-6) << s;
    }
  }
}

TEST(PlotLayout, EverythingIsInsideTheCanvas) {
  std::vector<double> x;
  std::vector<double> y;
  for (int i = 0; i < 300; ++i) {
    x.push_back(1000.0 + 3.7 * i);
    y.push_back(25.0 * std::sin(i * 0.1) - 8.0);
  }
  auto f = scatter(x, y, plot::Axis{"path", "mm", plot::Scale::kLinear, false});
  f.title =
      "a long figure title, longer than the two panels side by side are wide, to see that "
      "the canvas grows to hold it";
  f.panels[0].y2 = plot::Axis{"offset in force, dashed, a long axis title", "µm"};
  plot::Series off;
  off.x = x;
  off.y = std::vector<double>(x.size(), -1234.5);
  off.right_axis = true;
  off.dashed = true;
  f.panels[0].series.push_back(off);
  f.notes = {"a note under the legend"};
  expect_inside(plot::render_svg(f));
}

TEST(PlotTime, ElapsedSecondsReadInDaysOrHours) {
  for (const auto& [span_s, unit] : std::vector<std::pair<double, std::string>>{
           {600000.0, "d"}, {166710.0, "h"}, {5400.0, "min"}}) {
    SCOPED_TRACE(unit);
    std::vector<double> x;
    std::vector<double> y;
    for (int i = 0; i <= 100; ++i) {
      x.push_back(span_s * i / 100.0);
      y.push_back(i % 7 - 3.0);
    }
    const std::string s =
        plot::render_svg(scatter(x, y, plot::Axis{"time", "s", plot::Scale::kElapsedTime}));
    expect_inside(s);
    const auto doc = svg::parse(s);
    for (const auto& e : doc) {
      EXPECT_FALSE(std::regex_search(e.text, std::regex(R"(\de[+-]?\d)"))) << e.text;
    }
    bool titled = false;
    for (const auto* t : svg::texts(doc, "axis-title")) {
      titled = titled || t->text == "time since the first sample [" + unit + "]";
    }
    EXPECT_TRUE(titled);
    const double per = unit == "d" ? 86400.0 : unit == "h" ? 3600.0 : 60.0;
    const auto labels = x_tick_labels(doc);
    ASSERT_GE(labels.size(), 4U);  // two panels
    double lo = 1e300;
    double hi = -1e300;
    for (const auto* l : labels) {
      lo = std::min(lo, label_value(l->text));
      hi = std::max(hi, label_value(l->text));
    }
    EXPECT_EQ(lo, 0.0);
    EXPECT_GE(hi, span_s / per);
    EXPECT_LT(hi, 2.0 * span_s / per);
  }
}

TEST(PlotTime, WallClockSecondsReadAsUtcDates) {
  // 2026-11-27 00:00:00 UTC is 1 795 737 600 s after 1970-01-01.
  const double t0 = 1795737600.0;
  std::vector<double> x;
  std::vector<double> y;
  for (int i = 0; i <= 50; ++i) {
    x.push_back(t0 + 7200.0 + i * 3.0 * 3600.0);
    y.push_back(i % 5);
  }
  const std::string s =
      plot::render_svg(scatter(x, y, plot::Axis{"time", "s", plot::Scale::kUtcTime}));
  expect_inside(s);
  const auto doc = svg::parse(s);
  const auto labels = x_tick_labels(doc);
  ASSERT_GE(labels.size(), 4U);
  const std::regex date(R"(2026-1[12]-\d\d|1[12]-\d\d \d\d:\d\d)");
  for (const auto* l : labels) EXPECT_TRUE(std::regex_match(l->text, date)) << l->text;
  EXPECT_EQ(labels.front()->text, "2026-11-27");  // whole UTC days over a 6-day span
  // Neighbouring labels of one panel do not overlap.
  for (std::size_t i = 1; i < labels.size() / 2; ++i) {
    EXPECT_FALSE(svg::box(*labels[i - 1])->intersects(*svg::box(*labels[i])))
        << labels[i - 1]->text << " / " << labels[i]->text;
  }
  bool utc = false;
  for (const auto* t : svg::texts(doc, "axis-title")) utc = utc || t->text == "time [UTC, 2026]";
  EXPECT_TRUE(utc);
}

TEST(PlotLayout, LegendKeepsClearOfAxisLabels) {
  std::vector<double> x = {0, 1, 2, 3};
  auto f = scatter(x, {1, -2, 3, -4}, plot::Axis{"position along the contour s", "mm"});
  f.panel_width_px = 200;
  for (int i = 0; i < 12; ++i) {
    f.legend.push_back(
        {"legend entry number " + std::to_string(i), "#333", plot::Mark::kLine, i % 2 == 1});
  }
  const std::string s = plot::render_svg(f);
  expect_inside(s);
  const auto doc = svg::parse(s);
  std::vector<svg::Box> labels;
  for (const char* cls : {"tick-label", "axis-title", "title", "panel-title", "note"}) {
    for (const auto* t : svg::texts(doc, cls)) labels.push_back(*svg::box(*t));
  }
  // The legend's texts and markers (everything in <g class="legend">).
  std::vector<svg::Box> legend;
  bool in_legend = false;
  for (const auto& e : doc) {
    if (e.tag == "g") in_legend = e.get("class") == "legend";
    if (in_legend && svg::box(e)) legend.push_back(*svg::box(e));
  }
  ASSERT_EQ(legend.size(), 2 * f.legend.size());
  for (const auto& l : legend) {
    for (const auto& a : labels) EXPECT_FALSE(l.intersects(a));
  }
}

TEST(PlotData, NanAndInfSamplesAreSkippedAndCounted) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  auto f = scatter({0, 1, 2, nan, 4, 5, 6, 7, inf, 9}, {1, nan, 3, 4, 5, -inf, 7, 8, 9, 10},
                   plot::Axis{"x", "mm"});
  f.panels.pop_back();
  const std::string s = plot::render_svg(f);
  expect_inside(s);
  const auto doc = svg::parse(s);
  std::size_t circles = 0;
  for (const auto& e : doc) circles += e.tag == "circle" ? 1U : 0U;
  EXPECT_EQ(circles, 6U);
  const auto notes = svg::texts(doc, "note");
  ASSERT_EQ(notes.size(), 1U);
  EXPECT_EQ(notes[0]->text, "4 samples not plotted (NaN or infinite)");
  EXPECT_EQ(s.find("nan"), std::string::npos);
  // With nothing non-finite, no note.
  const std::string clean = plot::render_svg(scatter({0, 1}, {1, 2}, plot::Axis{"x", "mm"}));
  EXPECT_EQ(clean.find("not plotted"), std::string::npos);
}

TEST(PlotData, DecimationKeepsExtremesAndPointsStayPoints) {
  std::vector<double> y(100000);
  for (std::size_t i = 0; i < y.size(); ++i) y[i] = std::sin(static_cast<double>(i) * 1e-3);
  y[31337] = 60.0;
  y[77777] = -60.0;
  const auto keep = plot::decimate(y, 500);
  EXPECT_LE(keep.size(), 1000U);
  EXPECT_NE(std::find(keep.begin(), keep.end(), 31337U), keep.end());
  EXPECT_NE(std::find(keep.begin(), keep.end(), 77777U), keep.end());
  EXPECT_TRUE(std::is_sorted(keep.begin(), keep.end()));

  // A scatter over the budget keeps its extreme points, as circles.
  std::vector<double> x(y.size());
  for (std::size_t i = 0; i < x.size(); ++i) x[i] = static_cast<double>((i * 7919) % x.size());
  auto f = scatter(x, y, plot::Axis{"x", "mm"});
  f.panels.pop_back();
  f.max_points = 2000;
  const auto doc = svg::parse(plot::render_svg(f));
  std::size_t circles = 0;
  double top = 1e300;
  double low = -1e300;
  double frame_top = 0;
  double frame_bottom = 0;
  for (const auto& e : doc) {
    if (e.tag == "polyline") ADD_FAILURE() << "points drawn as a line";
    if (e.tag == "rect" && e.get("stroke") == "#444") {
      frame_top = e.num("y");
      frame_bottom = frame_top + e.num("height");
    }
    if (e.tag != "circle") continue;
    ++circles;
    top = std::min(top, e.num("cy"));
    low = std::max(low, e.num("cy"));
  }
  EXPECT_LE(circles, 2000U);
  EXPECT_GT(circles, 100U);
  // ±60 are the extremes and whole ticks (step 20): the extreme points lie on the frame.
  EXPECT_NEAR(top, frame_top, 0.11);
  EXPECT_NEAR(low, frame_bottom, 0.11);
}

TEST(PlotData, ExtremeFiniteValuesStayInsideTheCanvas) {
  const double big = std::numeric_limits<double>::max();
  const std::vector<std::vector<double>> cases = {{-big, big},      {1e-300, 2e-300}, {5, 5, 5},
                                                  {1e15, 1e15 + 1}, {-1e20, 3e20},    {0}};
  for (const auto& v : cases) {
    for (const auto scale :
         {plot::Scale::kLinear, plot::Scale::kElapsedTime, plot::Scale::kUtcTime}) {
      SCOPED_TRACE(std::to_string(v.front()) + " scale " + std::to_string(static_cast<int>(scale)));
      const std::string s = plot::render_svg(scatter(v, v, plot::Axis{"t", "s", scale}));
      expect_inside(s);
      EXPECT_EQ(s.find("nan"), std::string::npos);
      EXPECT_EQ(s.find("inf"), std::string::npos);
      std::size_t circles = 0;
      for (const auto& e : svg::parse(s)) circles += e.tag == "circle" ? 1U : 0U;
      EXPECT_EQ(circles, 2 * v.size());
    }
  }
}
