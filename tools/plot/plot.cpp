#include "tools/plot/plot.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdarg>
#include <cstdio>
#include <ctime>

namespace nccomp::tools::plot {

namespace {

constexpr double kPad = 10.0;
constexpr double kFont = 12.0;
constexpr double kTitleFont = 15.0;
constexpr double kPanelTitleFont = 13.0;
constexpr double kLegendRow = 18.0;
constexpr double kNoteRow = 16.0;
constexpr double kMaxTicks = 1000.0;

__attribute__((format(printf, 1, 2))) std::string fmt(const char* f, ...) {
  char buf[512];
  va_list ap;
  va_start(ap, f);
  std::vsnprintf(buf, sizeof buf, f, ap);
  va_end(ap);
  return buf;
}

// 1, 2 or 5 × 10^k nearest above span / n.
double nice_step(double span, int n) {
  const double raw = span / std::max(1, n);
  const double mag = std::pow(10.0, std::floor(std::log10(raw)));
  const double f = raw / mag;
  return (f <= 1.0 ? 1.0 : f <= 2.0 ? 2.0 : f <= 5.0 ? 5.0 : 10.0) * mag;
}

struct Range {
  double lo{HUGE_VAL};
  double hi{-HUGE_VAL};
  void add(double v) {
    lo = std::min(lo, v);
    hi = std::max(hi, v);
  }
  [[nodiscard]] bool empty() const { return lo > hi; }
};

// An axis ready to draw: value → position along the axis in tick units, ticks and their labels.
struct AxisLayout {
  double origin{0.0};
  double per_unit{1.0};  // raw value units per tick unit (seconds per minute / hour / day)
  Ticks ticks;
  std::vector<std::string> labels;
  std::string title;
  bool zero_line{false};
  [[nodiscard]] double value(double raw) const { return (raw - origin) / per_unit; }
  // Halves: no overflow even for a range from -1e308 to 1e308.
  [[nodiscard]] double tick_frac(double v) const {
    return (v / 2.0 - ticks.first / 2.0) / (ticks.last / 2.0 - ticks.first / 2.0);
  }
  [[nodiscard]] double frac(double raw) const { return tick_frac(value(raw)); }
  [[nodiscard]] double widest_label() const {
    double w = 0.0;
    for (const auto& l : labels) w = std::max(w, text_width(l, kFont));
    return w;
  }
};

std::string with_unit(const std::string& title, const std::string& unit) {
  return unit.empty() ? title : title + " [" + unit + "]";
}

std::string utc_label(double t_s, double step_s) {
  if (!(std::fabs(t_s) < 253402300800.0)) return format_number(t_s, step_s);  // past year 9999
  const auto t = static_cast<std::time_t>(std::llround(t_s));
  std::tm tm{};
  gmtime_r(&t, &tm);
  char buf[32];
  std::strftime(buf, sizeof buf, step_s >= 86400.0 ? "%Y-%m-%d" : "%m-%d %H:%M", &tm);
  return buf;
}

// UTC ticks on whole minutes, hours or days (days since 1970-01-01 are whole UTC days).
Ticks utc_ticks(double lo, double hi, int target) {
  static constexpr std::array<double, 14> kSteps = {
      60, 120, 300, 600, 900, 1800, 3600, 7200, 10800, 21600, 43200, 86400, 172800, 604800};
  const double raw = (hi - lo) / std::max(1, target);
  double step = 0.0;
  for (double s : kSteps) {
    if (s >= raw) {
      step = s;
      break;
    }
  }
  if (step <= 0.0) step = nice_step(raw / 86400.0, 1) * 86400.0;
  Ticks t;
  t.step = step;
  t.first = std::floor(lo / step) * step;
  t.last = std::ceil(hi / step) * step;
  if (t.last <= t.first) t.last = t.first + step;
  const double n = std::round((t.last - t.first) / step);
  if (!(n <= kMaxTicks)) return nice_ticks(lo, hi, target);
  for (double i = 0; i <= n; ++i) t.values.push_back(t.first + i * step);
  return t;
}

AxisLayout make_axis(const Axis& a, Range r, int target) {
  AxisLayout l;
  if (r.empty()) r = Range{0.0, 1.0};
  if (a.include_zero) {
    r.add(0.0);
    l.zero_line = true;
  }
  Scale scale = a.scale;
  if (scale == Scale::kElapsedTime && !std::isfinite(r.hi - r.lo)) scale = Scale::kLinear;
  switch (scale) {
    case Scale::kLinear:
      l.ticks = nice_ticks(r.lo, r.hi, target);
      l.title = with_unit(a.title, a.unit);
      break;
    case Scale::kElapsedTime: {
      const TimeUnit u = elapsed_unit(r.hi - r.lo);
      l.origin = r.lo;
      l.per_unit = u.seconds;
      l.ticks = nice_ticks(0.0, r.hi > r.lo ? (r.hi - r.lo) / u.seconds : 1.0, target);
      l.title = with_unit(
          (a.title.empty() ? std::string("time") : a.title) + " since the first sample", u.name);
      break;
    }
    case Scale::kUtcTime: {
      l.ticks = utc_ticks(r.lo, r.hi, target);
      l.title = with_unit(a.title.empty() ? std::string("time") : a.title,
                          "UTC, " + utc_label(l.ticks.first, 86400.0).substr(0, 4));
      break;
    }
  }
  for (double v : l.ticks.values) {
    l.labels.push_back(scale == Scale::kUtcTime ? utc_label(v, l.ticks.step)
                                                : format_number(v, l.ticks.step));
  }
  return l;
}

// The x axis: fewer ticks until the widest label fits between neighbours.
AxisLayout make_x_axis(const Axis& a, Range r, double length_px) {
  int target = std::max(2, static_cast<int>(length_px / 70.0));
  for (;;) {
    AxisLayout l = make_axis(a, r, target);
    const double spacing =
        length_px / static_cast<double>(std::max<std::size_t>(1, l.ticks.values.size() - 1));
    if (l.widest_label() + 8.0 <= spacing || target <= 2) return l;
    --target;
  }
}

// Finite samples of a series, decimated to about `budget` points keeping the extremes.
std::vector<std::size_t> kept_samples(const Series& s, std::size_t budget, std::size_t* skipped) {
  const std::size_t n = std::min(s.x.size(), s.y.size());
  *skipped += std::max(s.x.size(), s.y.size()) - n;
  std::vector<std::size_t> finite;
  finite.reserve(n);
  for (std::size_t i = 0; i < n; ++i) {
    if (std::isfinite(s.x[i]) && std::isfinite(s.y[i])) {
      finite.push_back(i);
    } else {
      ++*skipped;
    }
  }
  const std::size_t buckets = std::max<std::size_t>(1, budget / 2);
  if (finite.size() <= 2 * buckets) return finite;
  if (s.mark == Mark::kPoints) {
    // A scatter has no order: decimate along x so each x bucket keeps its lowest and highest.
    std::stable_sort(finite.begin(), finite.end(),
                     [&](std::size_t a, std::size_t b) { return s.x[a] < s.x[b]; });
  }
  std::vector<double> y(finite.size());
  for (std::size_t k = 0; k < finite.size(); ++k) y[k] = s.y[finite[k]];
  std::vector<std::size_t> out;
  for (std::size_t k : decimate(y, buckets)) out.push_back(finite[k]);
  return out;
}

std::string legend_marker(const LegendEntry& e, double x, double cy) {
  const std::string c = xml_escape(e.colour);
  if (e.mark == Mark::kPoints) {
    // A rounded square: a circle to the eye, not a data <circle>.
    return fmt("<rect x=\"%.1f\" y=\"%.1f\" width=\"7\" height=\"7\" rx=\"3.5\" fill=\"%s\"/>\n",
               x + 7.5, cy - 3.5, c.c_str());
  }
  return fmt(
      "<line x1=\"%.1f\" y1=\"%.1f\" x2=\"%.1f\" y2=\"%.1f\" stroke=\"%s\" "
      "stroke-width=\"2\"%s/>\n",
      x, cy, x + 22.0, cy, c.c_str(), e.dashed ? " stroke-dasharray=\"5,3\"" : "");
}

double legend_entry_width(const LegendEntry& e) {
  return 22.0 + 6.0 + text_width(e.label, kFont) + 18.0;
}

}  // namespace

Ticks nice_ticks(double lo, double hi, int target) {
  if (!std::isfinite(lo) || !std::isfinite(hi) || lo > hi) {
    lo = 0.0;
    hi = 1.0;
  }
  if (hi - lo <= 1e-12 * std::max(1.0, std::fabs(lo))) {
    const double half = std::max(0.5, std::fabs(lo) * 0.05);
    lo -= half;
    hi += half;
  }
  Ticks t;
  t.step = nice_step(hi - lo, target);
  t.first = std::floor(lo / t.step) * t.step;
  t.last = std::ceil(hi / t.step) * t.step;
  const double n = std::round((t.last - t.first) / t.step);
  if (!(n >= 1.0 && n <= kMaxTicks)) {
    // Beyond what doubles resolve (a span overflowing, or far below the values' precision):
    // the two ends only.
    return Ticks{lo, hi, std::isfinite(hi - lo) ? hi - lo : HUGE_VAL, {lo, hi}};
  }
  for (double i = 0; i <= n; ++i) {
    const double v = t.first + i * t.step;
    t.values.push_back(std::fabs(v) < t.step * 1e-9 ? 0.0 : v);
  }
  return t;
}

std::string format_number(double v, double step) {
  if (!std::isfinite(v)) return std::isnan(v) ? "NaN" : (v > 0 ? "inf" : "-inf");
  if (!(step > 0.0) || !std::isfinite(step)) step = std::fabs(v) > 0.0 ? std::fabs(v) : 1.0;
  if (std::fabs(v) < step * 1e-6) return "0";
  if (std::fabs(v) >= 1e15 || step < 1e-9) return fmt("%g", v);
  int decimals = 0;
  for (double s = step; decimals < 12 && std::fabs(s - std::round(s)) > 1e-6 * s; s *= 10.0) {
    ++decimals;
  }
  const std::string raw = fmt("%.*f", decimals, v);
  // Thousands grouped with a space; built into a new string (GCC 12 at -O3 reports a false
  // -Wrestrict overlap for std::string::insert in a loop).
  const std::size_t begin = raw[0] == '-' ? 1 : 0;
  const std::size_t end = std::min(raw.find('.'), raw.size());
  std::string s;
  s.reserve(raw.size() + (end - begin) / 3);
  s.append(raw, 0, begin);
  for (std::size_t i = begin; i < end; ++i) {
    if (i > begin && (end - i) % 3 == 0) s.push_back(' ');
    s.push_back(raw[i]);
  }
  s.append(raw, end, std::string::npos);
  if (s.find_first_not_of("-0. ") == std::string::npos) return "0";
  return s;
}

TimeUnit elapsed_unit(double span_s) {
  if (!(span_s > 120.0)) return {"s", 1.0};
  if (span_s <= 2.0 * 3600.0) return {"min", 60.0};
  if (span_s <= 3.0 * 86400.0) return {"h", 3600.0};
  return {"d", 86400.0};
}

std::vector<std::size_t> decimate(const std::vector<double>& y, std::size_t buckets) {
  std::vector<std::size_t> keep;
  buckets = std::max<std::size_t>(1, buckets);
  if (y.size() <= 2 * buckets) {
    keep.reserve(y.size());
    for (std::size_t i = 0; i < y.size(); ++i) keep.push_back(i);
    return keep;
  }
  const std::size_t per = (y.size() + buckets - 1) / buckets;
  for (std::size_t b = 0; b < y.size(); b += per) {
    const std::size_t e = std::min(y.size(), b + per);
    std::size_t lo = b;
    std::size_t hi = b;
    for (std::size_t i = b; i < e; ++i) {
      if (y[i] < y[lo]) lo = i;
      if (y[i] > y[hi]) hi = i;
    }
    keep.push_back(std::min(lo, hi));
    if (lo != hi) keep.push_back(std::max(lo, hi));
  }
  return keep;
}

double text_width(std::string_view text, double font_size_px) {
  std::size_t chars = 0;
  for (char c : text) {
    if ((static_cast<unsigned char>(c) & 0xC0U) != 0x80U) ++chars;
  }
  return 0.6 * font_size_px * static_cast<double>(chars);
}

std::string xml_escape(std::string_view s) {
  std::string o;
  for (char c : s) {
    switch (c) {
      case '<':
        o += "&lt;";
        break;
      case '>':
        o += "&gt;";
        break;
      case '&':
        o += "&amp;";
        break;
      case '"':
        o += "&quot;";
        break;
      default:
        o += c;
    }
  }
  return o;
}

std::string render_svg(const Figure& f) {
  const double pw = f.panel_width_px;
  double ph = f.panel_height_px;
  const std::size_t n_panels = std::max<std::size_t>(1, f.panels.size());
  const Panel empty_panel;
  auto panel = [&](std::size_t p) -> const Panel& {
    return p < f.panels.size() ? f.panels[p] : empty_panel;
  };

  // Shared ranges over every finite sample.
  Range xr;
  Range yr;
  Range y2r;
  std::size_t n_series = 0;
  for (const auto& p : f.panels) {
    for (const auto& s : p.series) {
      ++n_series;
      for (std::size_t i = 0; i < std::min(s.x.size(), s.y.size()); ++i) {
        if (!std::isfinite(s.x[i]) || !std::isfinite(s.y[i])) continue;
        xr.add(s.x[i]);
        (s.right_axis ? y2r : yr).add(s.y[i]);
      }
    }
  }
  const bool has_y2 = panel(0).y2.has_value();
  const int y_target = std::max(2, static_cast<int>(ph / 40.0));

  struct Slot {
    AxisLayout x, y, y2;
    double left{0.0};
    double right{0.0};
    double width{0.0};
    double x0{0.0};
  };
  std::vector<Slot> slots(n_panels);
  double width = 0.0;
  double widest_rotated = 0.0;
  for (std::size_t p = 0; p < n_panels; ++p) {
    Slot& s = slots[p];
    const Panel& pa = panel(p);
    s.x = make_x_axis(pa.x, xr, pw);
    s.y = make_axis(pa.y, yr, y_target);
    if (has_y2) s.y2 = make_axis(pa.y2 ? *pa.y2 : Axis{}, y2r, y_target);
    const double half_first_x = text_width(s.x.labels.front(), kFont) / 2.0;
    const double half_last_x = text_width(s.x.labels.back(), kFont) / 2.0;
    // Rotated title (font height + descent), gap, tick labels, gap.
    s.left = std::max(kPad + kFont * 1.25 + 6.0 + s.y.widest_label() + 7.0, kPad + half_first_x);
    s.right =
        has_y2 ? std::max(7.0 + s.y2.widest_label() + 6.0 + kFont * 1.25 + kPad, kPad + half_last_x)
               : kPad + half_last_x;
    // The x axis title is centred under the plot.
    const double x_title_half = text_width(s.x.title, kFont) / 2.0 + kPad - pw / 2.0;
    s.left = std::max(s.left, x_title_half);
    s.right = std::max(s.right, x_title_half);
    const double title_w = text_width(pa.title, kPanelTitleFont) + 2.0 * kPad;
    if (s.left + pw + s.right < title_w) s.right = title_w - s.left - pw;
    s.width = s.left + pw + s.right;
    s.x0 = width;
    width += s.width;
    widest_rotated = std::max(widest_rotated, text_width(s.y.title, kFont));
    if (has_y2) widest_rotated = std::max(widest_rotated, text_width(s.y2.title, kFont));
  }
  // A rotated axis title longer than the panel is high makes the panel higher.
  ph = std::max(ph, widest_rotated + 10.0);

  std::size_t skipped = 0;
  std::vector<std::vector<std::vector<std::size_t>>> kept(f.panels.size());
  const std::size_t budget =
      std::max<std::size_t>(100, f.max_points / std::max<std::size_t>(1, n_series));
  for (std::size_t p = 0; p < f.panels.size(); ++p) {
    for (const auto& s : f.panels[p].series) kept[p].push_back(kept_samples(s, budget, &skipped));
  }
  std::vector<std::string> notes = f.notes;
  if (skipped > 0) {
    notes.push_back(
        fmt("%zu sample%s not plotted (NaN or infinite)", skipped, skipped == 1 ? "" : "s"));
  }

  // The canvas is wide enough for the title, every legend entry and every note.
  width = std::max(width, text_width(f.title, kTitleFont) + 2.0 * kPad);
  for (const auto& e : f.legend) width = std::max(width, legend_entry_width(e) + 2.0 * kPad);
  for (const auto& n : notes) width = std::max(width, text_width(n, kFont) + 2.0 * kPad);
  // Extra width goes to the last panel's right margin.
  slots.back().right += width - (slots.back().x0 + slots.back().width);
  slots.back().width = width - slots.back().x0;

  // Bands from the top: title, panel titles, plot, x ticks and title, legend, notes.
  double y = kPad;
  const double title_base = y + kTitleFont;
  if (!f.title.empty()) y += kTitleFont + 8.0;
  const double panel_title_base = y + kPanelTitleFont;
  bool panel_titles = false;
  for (const auto& p : f.panels) panel_titles = panel_titles || !p.title.empty();
  if (panel_titles) y += kPanelTitleFont + 6.0;
  const double top = y + 10.0;  // half a tick label above the top tick
  const double bottom = top + ph;
  y = bottom + 46.0;
  // Legend rows: entries left to right, wrapped at the canvas edge.
  struct Placed {
    const LegendEntry* e;
    double x;
    double row_top;
  };
  std::vector<Placed> legend;
  if (!f.legend.empty()) {
    y += 4.0;
    double x = kPad;
    for (const auto& e : f.legend) {
      const double w = legend_entry_width(e);
      if (x > kPad && x + w > width - kPad) {
        x = kPad;
        y += kLegendRow;
      }
      legend.push_back({&e, x, y});
      x += w;
    }
    y += kLegendRow;
  }
  const double notes_top = y;
  y += kNoteRow * static_cast<double>(notes.size());
  const double height = y + kPad;

  std::string o;
  o +=
      fmt("<svg xmlns=\"http://www.w3.org/2000/svg\" viewBox=\"0 0 %.0f %.0f\" width=\"100%%\" "
          "font-family=\"sans-serif\" font-size=\"%.0f\">\n",
          std::ceil(width), std::ceil(height), kFont);
  o += fmt("<rect x=\"0\" y=\"0\" width=\"%.0f\" height=\"%.0f\" fill=\"white\"/>\n",
           std::ceil(width), std::ceil(height));
  if (!f.title.empty()) {
    o += fmt("<text class=\"title\" x=\"%.1f\" y=\"%.1f\" font-size=\"%.0f\" "
             "text-anchor=\"middle\">",
             width / 2.0, title_base, kTitleFont) +
         xml_escape(f.title) + "</text>\n";
  }
  for (std::size_t p = 0; p < n_panels; ++p) {
    const Slot& s = slots[p];
    const Panel& pa = panel(p);
    const double L = s.x0 + s.left;
    const double R = L + pw;
    auto px = [&](double v) { return L + s.x.frac(v) * pw; };
    auto py = [&](const AxisLayout& a, double v) { return bottom - a.frac(v) * ph; };
    o += "<g>\n";
    if (!pa.title.empty()) {
      o += fmt("<text class=\"panel-title\" x=\"%.1f\" y=\"%.1f\" font-size=\"%.0f\">", s.x0 + kPad,
               panel_title_base, kPanelTitleFont) +
           xml_escape(pa.title) + "</text>\n";
    }
    for (std::size_t i = 0; i < s.x.ticks.values.size(); ++i) {
      const double x = L + s.x.tick_frac(s.x.ticks.values[i]) * pw;
      o += fmt("<line x1=\"%.1f\" y1=\"%.1f\" x2=\"%.1f\" y2=\"%.1f\" stroke=\"#e4e4e4\"/>\n", x,
               top, x, bottom + 4.0);
      o += fmt("<text class=\"tick-label\" x=\"%.1f\" y=\"%.1f\" text-anchor=\"middle\">", x,
               bottom + 22.0) +
           xml_escape(s.x.labels[i]) + "</text>\n";
    }
    for (std::size_t i = 0; i < s.y.ticks.values.size(); ++i) {
      const double yy = bottom - s.y.tick_frac(s.y.ticks.values[i]) * ph;
      o += fmt("<line x1=\"%.1f\" y1=\"%.1f\" x2=\"%.1f\" y2=\"%.1f\" stroke=\"#e4e4e4\"/>\n",
               L - 4.0, yy, R, yy);
      o += fmt("<text class=\"tick-label\" x=\"%.1f\" y=\"%.1f\" text-anchor=\"end\">", L - 7.0,
               yy + 4.0) +
           xml_escape(s.y.labels[i]) + "</text>\n";
    }
    if (has_y2) {
      for (std::size_t i = 0; i < s.y2.ticks.values.size(); ++i) {
        const double yy = bottom - s.y2.tick_frac(s.y2.ticks.values[i]) * ph;
        o += fmt("<line x1=\"%.1f\" y1=\"%.1f\" x2=\"%.1f\" y2=\"%.1f\" stroke=\"#a04600\"/>\n", R,
                 yy, R + 4.0, yy);
        o += fmt("<text class=\"tick-label\" x=\"%.1f\" y=\"%.1f\" fill=\"#a04600\">", R + 7.0,
                 yy + 4.0) +
             xml_escape(s.y2.labels[i]) + "</text>\n";
      }
    }
    if (s.y.zero_line) {
      o +=
          fmt("<line x1=\"%.1f\" y1=\"%.1f\" x2=\"%.1f\" y2=\"%.1f\" stroke=\"#999\" "
              "stroke-dasharray=\"4,3\"/>\n",
              L, py(s.y, 0.0), R, py(s.y, 0.0));
    }
    o +=
        fmt("<rect x=\"%.1f\" y=\"%.1f\" width=\"%.1f\" height=\"%.1f\" fill=\"none\" "
            "stroke=\"#444\"/>\n",
            L, top, pw, ph);
    o += fmt("<text class=\"axis-title\" x=\"%.1f\" y=\"%.1f\" text-anchor=\"middle\">",
             (L + R) / 2.0, bottom + 42.0) +
         xml_escape(s.x.title) + "</text>\n";
    o += fmt("<text class=\"axis-title\" transform=\"translate(%.1f,%.1f) rotate(-90)\" "
             "text-anchor=\"middle\">",
             s.x0 + kPad + kFont, (top + bottom) / 2.0) +
         xml_escape(s.y.title) + "</text>\n";
    if (has_y2) {
      o += fmt("<text class=\"axis-title\" transform=\"translate(%.1f,%.1f) rotate(90)\" "
               "text-anchor=\"middle\" fill=\"#a04600\">",
               s.x0 + s.width - kPad - kFont, (top + bottom) / 2.0) +
           xml_escape(s.y2.title) + "</text>\n";
    }
    if (p < f.panels.size()) {
      for (std::size_t k = 0; k < pa.series.size(); ++k) {
        const Series& se = pa.series[k];
        const AxisLayout& ya = se.right_axis && has_y2 ? s.y2 : s.y;
        const std::string colour = xml_escape(se.colour);
        if (se.mark == Mark::kPoints) {
          for (std::size_t i : kept[p][k]) {
            o +=
                fmt("<circle cx=\"%.1f\" cy=\"%.1f\" r=\"1.6\" fill=\"%s\" "
                    "fill-opacity=\"%.2f\"/>\n",
                    px(se.x[i]), py(ya, se.y[i]), colour.c_str(), se.opacity);
          }
        } else {
          o += "<polyline fill=\"none\" stroke=\"" + colour + "\"" +
               (se.dashed ? " stroke-dasharray=\"5,3\" stroke-width=\"1\""
                          : " stroke-width=\"1.2\"") +
               fmt(" stroke-opacity=\"%.2f\" points=\"", se.opacity);
          for (std::size_t i : kept[p][k]) {
            o += fmt("%.1f,%.1f ", px(se.x[i]), py(ya, se.y[i]));
          }
          o += "\"/>\n";
        }
      }
    }
    o += "</g>\n";
  }
  if (!legend.empty()) {
    o += "<g class=\"legend\">\n";
    for (const auto& l : legend) {
      o += legend_marker(*l.e, l.x, l.row_top + kLegendRow / 2.0);
      o += fmt("<text class=\"legend\" x=\"%.1f\" y=\"%.1f\">", l.x + 28.0, l.row_top + 13.0) +
           xml_escape(l.e->label) + "</text>\n";
    }
    o += "</g>\n";
  }
  for (std::size_t i = 0; i < notes.size(); ++i) {
    o += fmt("<text class=\"note\" x=\"%.1f\" y=\"%.1f\">", kPad,
             notes_top + kNoteRow * static_cast<double>(i) + 12.0) +
         xml_escape(notes[i]) + "</text>\n";
  }
  o += "</svg>\n";
  return o;
}

}  // namespace nccomp::tools::plot
