// SVG plot of a machined result: error along the path per pass (or along the contour per part
// and layer), the offset in force on a second axis, drawn by tools/plot.
#include <algorithm>
#include <cmath>
#include <cstdarg>
#include <cstdio>
#include <map>
#include <string>
#include <vector>

#include "tools/plot/plot.hpp"
#include "tools/report/report.hpp"

namespace nccomp::tools::report {

namespace plot = tools::plot;

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
    x_label = "path";
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
    x_label = "position along the contour s";
    group_word = "part/layer";
    title = "wall error along the contour, " + r.info.program;
  } else {
    throw ReportInputError(r.dir + ": nothing to plot (no surface.csv or walls.csv rows)");
  }

  // Offsets underneath the errors; light → dark in cut order.
  plot::Panel panel;
  panel.x = plot::Axis{x_label, "mm", plot::Scale::kLinear, false};
  panel.y = plot::Axis{"error (+ = material left)", "µm", plot::Scale::kLinear, false};
  panel.y2 = plot::Axis{"offset in force, dashed", "µm", plot::Scale::kLinear, false};
  const std::size_t n = series.size();
  auto shade = [&](std::size_t k) {
    return n > 1 ? static_cast<double>(k) / static_cast<double>(n - 1) : 1.0;
  };
  for (int offset = 1; offset >= 0; --offset) {
    for (std::size_t k = 0; k < n; ++k) {
      plot::Series s;
      s.x = series[k].x;
      s.y = offset == 1 ? series[k].y2 : series[k].y;
      s.colour = colour(shade(k), offset == 1);
      s.dashed = offset == 1;
      s.right_axis = offset == 1;
      panel.series.push_back(std::move(s));
    }
  }
  plot::Figure fig;
  fig.title = title;
  fig.panel_width_px = 800.0;
  fig.panel_height_px = 400.0;
  // A readable file even for a few hundred passes of a thousand samples.
  fig.max_points = 60000;
  fig.panels.push_back(std::move(panel));
  const std::string first = n > 1 ? ", first " + group_word : "";
  const std::string last = n > 1 ? ", last " + group_word : "";
  fig.legend.push_back({"error" + first, colour(0.0, false), plot::Mark::kLine, false});
  if (n > 1) fig.legend.push_back({"error" + last, colour(1.0, false), plot::Mark::kLine, false});
  fig.legend.push_back({"offset (right axis)" + first, colour(0.0, true), plot::Mark::kLine, true});
  if (n > 1) {
    fig.legend.push_back(
        {"offset (right axis)" + last, colour(1.0, true), plot::Mark::kLine, true});
  }
  fig.notes.push_back(fmt("%zu %s lines, pale = first, dark = last", n, group_word.c_str()));
  if (r.surface) {
    fig.notes.push_back(
        fmt("form error RMS %.3f µm, max %.3f µm; max step %.3f µm within a pass, "
            "%.3f µm between passes",
            r.surface->form.rms_um, std::fabs(r.surface->form.max_abs.value_um),
            r.surface->max_step.value_um, r.surface->max_step_between_passes.value_um));
  } else if (r.walls) {
    fig.notes.push_back(fmt("form error RMS %.3f µm, max %.3f µm", r.walls->form.rms_um,
                            std::fabs(r.walls->form.max_abs.value_um)));
  }
  return plot::render_svg(fig);
}

}  // namespace nccomp::tools::report
