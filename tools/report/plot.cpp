// SVG plot of a machined result: error along the path per pass (or along the contour per part
// and layer), the offset in force on a second axis. Hand-written SVG: no plotting dependency.
#include <algorithm>
#include <cmath>
#include <cstdarg>
#include <cstdio>
#include <map>
#include <string>
#include <vector>

#include "tools/report/report.hpp"

namespace nccomp::tools::report {

namespace {

__attribute__((format(printf, 1, 2))) std::string fmt(const char* f, ...) {
  char buf[512];
  va_list ap;
  va_start(ap, f);
  std::vsnprintf(buf, sizeof buf, f, ap);
  va_end(ap);
  return buf;
}

struct Series {
  std::vector<double> x;
  std::vector<double> y;   // error [µm]
  std::vector<double> y2;  // offset [µm]
};

struct Range {
  double lo{0.0};
  double hi{0.0};
  bool empty{true};
  void add(double v) {
    if (empty) {
      lo = hi = v;
      empty = false;
    } else {
      lo = std::min(lo, v);
      hi = std::max(hi, v);
    }
  }
  // Never a zero-width range (a constant offset still gets an axis).
  void widen() {
    if (empty) {
      lo = -1.0;
      hi = 1.0;
    } else if (hi - lo < 1e-9) {
      lo -= 0.5;
      hi += 0.5;
    }
  }
};

// Tick step 1, 2 or 5 × 10^k giving about `n` ticks.
double nice_step(double span, int n) {
  const double raw = span / n;
  const double mag = std::pow(10.0, std::floor(std::log10(raw)));
  const double f = raw / mag;
  return (f < 1.5 ? 1.0 : f < 3.5 ? 2.0 : f < 7.5 ? 5.0 : 10.0) * mag;
}

// Keeps at most ~2·buckets points: per bucket of consecutive samples its minimum and maximum in
// path order, so a step stays a step in the plot however many samples a pass has.
std::vector<std::size_t> decimate(const std::vector<double>& y, std::size_t buckets) {
  std::vector<std::size_t> keep;
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

std::string colour(double t, bool offset) {
  // Light → dark in cut order: early passes pale, the last pass darkest.
  const double from[2][3] = {{150, 185, 235}, {250, 195, 130}};
  const double to[2][3] = {{8, 40, 120}, {170, 70, 0}};
  const int k = offset ? 1 : 0;
  int c[3];
  for (int i = 0; i < 3; ++i) {
    c[i] = static_cast<int>(std::lround(from[k][i] + t * (to[k][i] - from[k][i])));
  }
  return fmt("rgb(%d,%d,%d)", c[0], c[1], c[2]);
}

}  // namespace

std::string plot_svg(const Report& r, const ResultTables& t) {
  std::vector<Series> series;
  std::string x_label;
  std::string title;
  std::string group_word;
  if (t.surface && t.surface->rows() > 0) {
    const CsvTable& s = *t.surface;
    const std::size_t c_pass = s.column("pass");
    const std::size_t c_path = s.column("path_mm");
    const std::size_t c_err = s.column("error_um");
    const std::size_t c_off = s.column("offset_um");
    std::map<long long, std::vector<std::size_t>> passes;
    for (std::size_t i = 0; i < s.rows(); ++i) {
      passes[static_cast<long long>(s.at(i, c_pass))].push_back(i);
    }
    for (auto& [p, rows] : passes) {
      std::stable_sort(rows.begin(), rows.end(), [&](std::size_t a, std::size_t b) {
        return s.at(a, c_path) < s.at(b, c_path);
      });
      Series se;
      for (const std::size_t i : rows) {
        se.x.push_back(s.at(i, c_path));
        se.y.push_back(s.at(i, c_err));
        se.y2.push_back(s.at(i, c_off));
      }
      series.push_back(std::move(se));
    }
    x_label = "path [mm]";
    group_word = "pass";
    title = "surface error along the path, " + r.info.program;
  } else if (t.walls && t.walls->rows() > 0) {
    const CsvTable& w = *t.walls;
    const std::size_t c_part = w.column("part");
    const std::size_t c_layer = w.column("layer");
    const std::size_t c_s = w.column("s_mm");
    const std::size_t c_err = w.column("error_um");
    const std::size_t c_off = w.column("offset_um");
    std::map<std::pair<long long, long long>, std::vector<std::size_t>> groups;
    for (std::size_t i = 0; i < w.rows(); ++i) {
      groups[{static_cast<long long>(w.at(i, c_part)), static_cast<long long>(w.at(i, c_layer))}]
          .push_back(i);
    }
    for (auto& [k, rows] : groups) {
      std::stable_sort(rows.begin(), rows.end(),
                       [&](std::size_t a, std::size_t b) { return w.at(a, c_s) < w.at(b, c_s); });
      Series se;
      for (const std::size_t i : rows) {
        se.x.push_back(w.at(i, c_s));
        se.y.push_back(w.at(i, c_err));
        se.y2.push_back(w.at(i, c_off));
      }
      series.push_back(std::move(se));
    }
    x_label = "position along the contour s [mm]";
    group_word = "part/layer";
    title = "wall error along the contour, " + r.info.program;
  } else {
    throw ReportInputError(r.dir + ": nothing to plot (no surface.csv or walls.csv rows)");
  }

  Range xr;
  Range yr;
  Range y2r;
  for (const auto& se : series) {
    for (std::size_t i = 0; i < se.x.size(); ++i) {
      xr.add(se.x[i]);
      yr.add(se.y[i]);
      y2r.add(se.y2[i]);
    }
  }
  xr.widen();
  yr.widen();
  y2r.widen();
  const double W = 1000;
  const double H = 560;
  const double L = 80;
  const double R = 80;
  const double T = 50;
  const double B = 60;
  const double pw = W - L - R;
  const double ph = H - T - B;
  // Round the value ranges out to whole ticks.
  const double xs = nice_step(xr.hi - xr.lo, 10);
  const double ys = nice_step(yr.hi - yr.lo, 8);
  const double y2s = nice_step(y2r.hi - y2r.lo, 8);
  const double x0 = std::floor(xr.lo / xs) * xs;
  const double x1 = std::ceil(xr.hi / xs) * xs;
  const double y0 = std::floor(yr.lo / ys) * ys;
  const double y1 = std::ceil(yr.hi / ys) * ys;
  const double v0 = std::floor(y2r.lo / y2s) * y2s;
  const double v1 = std::ceil(y2r.hi / y2s) * y2s;
  auto px = [&](double x) { return L + (x - x0) / (x1 - x0) * pw; };
  auto py = [&](double y) { return T + ph - (y - y0) / (y1 - y0) * ph; };
  auto py2 = [&](double v) { return T + ph - (v - v0) / (v1 - v0) * ph; };

  std::string o;
  o +=
      fmt("<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"%.0f\" height=\"%.0f\" "
          "viewBox=\"0 0 %.0f %.0f\" font-family=\"sans-serif\" font-size=\"12\">\n",
          W, H, W, H);
  o += "<rect width=\"100%\" height=\"100%\" fill=\"white\"/>\n";
  o += fmt("<text x=\"%.0f\" y=\"24\" font-size=\"15\" text-anchor=\"middle\">", W / 2) + title +
       "</text>\n";
  // Grid and ticks.
  for (double x = x0; x <= x1 + xs * 1e-6; x += xs) {
    o += fmt("<line x1=\"%.1f\" y1=\"%.1f\" x2=\"%.1f\" y2=\"%.1f\" stroke=\"#e4e4e4\"/>\n", px(x),
             T, px(x), T + ph);
    o += fmt("<text x=\"%.1f\" y=\"%.1f\" text-anchor=\"middle\">%g</text>\n", px(x), T + ph + 16,
             std::fabs(x) < xs * 1e-6 ? 0.0 : x);
  }
  for (double y = y0; y <= y1 + ys * 1e-6; y += ys) {
    o += fmt("<line x1=\"%.1f\" y1=\"%.1f\" x2=\"%.1f\" y2=\"%.1f\" stroke=\"#e4e4e4\"/>\n", L,
             py(y), L + pw, py(y));
    o += fmt("<text x=\"%.1f\" y=\"%.1f\" text-anchor=\"end\">%g</text>\n", L - 6, py(y) + 4,
             std::fabs(y) < ys * 1e-6 ? 0.0 : y);
  }
  for (double v = v0; v <= v1 + y2s * 1e-6; v += y2s) {
    o += fmt("<text x=\"%.1f\" y=\"%.1f\" fill=\"#a04600\">%g</text>\n", L + pw + 6, py2(v) + 4,
             std::fabs(v) < y2s * 1e-6 ? 0.0 : v);
  }
  if (y0 < 0.0 && y1 > 0.0) {
    o += fmt("<line x1=\"%.1f\" y1=\"%.1f\" x2=\"%.1f\" y2=\"%.1f\" stroke=\"#999\"/>\n", L,
             py(0.0), L + pw, py(0.0));
  }
  o +=
      fmt("<rect x=\"%.1f\" y=\"%.1f\" width=\"%.1f\" height=\"%.1f\" fill=\"none\" "
          "stroke=\"black\"/>\n",
          L, T, pw, ph);
  o += fmt("<text x=\"%.1f\" y=\"%.1f\" text-anchor=\"middle\">", L + pw / 2, H - 18) + x_label +
       "</text>\n";
  o +=
      fmt("<text transform=\"translate(%.1f,%.1f) rotate(-90)\" text-anchor=\"middle\">"
          "error [um] (+ = material left)</text>\n",
          22.0, T + ph / 2);
  o +=
      fmt("<text transform=\"translate(%.1f,%.1f) rotate(90)\" text-anchor=\"middle\" "
          "fill=\"#a04600\">offset in force [um] (dashed)</text>\n",
          W - 22, T + ph / 2);

  // Point budget: a readable file even for a few hundred passes of a thousand samples.
  const std::size_t buckets =
      std::max<std::size_t>(50, 60000 / std::max<std::size_t>(1, series.size()));
  const std::size_t n = series.size();
  for (int pass_kind = 1; pass_kind >= 0; --pass_kind) {  // offsets underneath the errors
    for (std::size_t k = 0; k < n; ++k) {
      const auto& se = series[k];
      const auto& y = pass_kind == 1 ? se.y2 : se.y;
      const auto keep = decimate(y, buckets);
      const double tcol = n > 1 ? static_cast<double>(k) / static_cast<double>(n - 1) : 1.0;
      o += "<polyline fill=\"none\" stroke=\"" + colour(tcol, pass_kind == 1) + "\"";
      o +=
          pass_kind == 1 ? " stroke-dasharray=\"5,3\" stroke-width=\"1\"" : " stroke-width=\"1.2\"";
      o += " points=\"";
      for (const std::size_t i : keep) {
        o += fmt("%.1f,%.1f ", px(se.x[i]), pass_kind == 1 ? py2(y[i]) : py(y[i]));
      }
      o += "\"/>\n";
    }
  }
  // Legend.
  o +=
      fmt("<text x=\"%.1f\" y=\"%.1f\">%zu %s lines, pale = first, dark = last; error solid "
          "(left axis), offset dashed (right axis)</text>\n",
          L + 8, T + 16, n, group_word.c_str());
  if (r.surface) {
    o +=
        fmt("<text x=\"%.1f\" y=\"%.1f\">form error RMS %.3f um, max %.3f um; max step %.3f um "
            "within a pass, %.3f um between passes</text>\n",
            L + 8, T + 32, r.surface->form.rms_um, std::fabs(r.surface->form.max_abs.value_um),
            r.surface->max_step.value_um, r.surface->max_step_between_passes.value_um);
  } else if (r.walls) {
    o += fmt("<text x=\"%.1f\" y=\"%.1f\">form error RMS %.3f um, max %.3f um</text>\n", L + 8,
             T + 32, r.walls->form.rms_um, std::fabs(r.walls->form.max_abs.value_um));
  }
  o += "</svg>\n";
  return o;
}

}  // namespace nccomp::tools::report
