// A small SVG plotting library shared by `nccomp report` and `nccomp analyze` (issue 23): panels
// side by side, nice ticks with units, time axes in minutes / hours / days or as UTC dates, a
// legend and notes in their own bands, a viewBox so the figure scales to its container.
// Standard library only.
#pragma once

#include <cstddef>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace nccomp::tools::plot {

/// How an axis shows its values.
enum class Scale {
  kLinear,       // the values as they are
  kElapsedTime,  // seconds: shown in s / min / h / d (by span) since the smallest value
  kUtcTime,      // seconds since 1970-01-01 UTC: shown as UTC dates and times
};

struct Axis {
  std::string title;
  /// Shown as "title [unit]"; time axes choose their own unit.
  std::string unit;
  Scale scale{Scale::kLinear};
  /// The range always holds 0, and a line is drawn there.
  bool include_zero{false};
};

enum class Mark { kLine, kPoints };

struct Series {
  std::vector<double> x;
  std::vector<double> y;
  std::string colour{"#1f5fa8"};
  Mark mark{Mark::kLine};
  bool dashed{false};
  /// Against the panel's y2 axis.
  bool right_axis{false};
  double opacity{1.0};
};

struct Panel {
  std::string title;
  Axis x;
  Axis y;
  std::optional<Axis> y2;
  std::vector<Series> series;
};

struct LegendEntry {
  std::string label;
  std::string colour;
  Mark mark{Mark::kLine};
  bool dashed{false};
};

/// Panels side by side share their x, y and y2 ranges (so they compare at a glance). Samples
/// with a NaN or infinite coordinate are skipped and counted in a note.
struct Figure {
  std::string title;
  std::vector<Panel> panels;
  std::vector<LegendEntry> legend;
  /// Lines of text under the legend.
  std::vector<std::string> notes;
  double panel_width_px{400.0};
  double panel_height_px{240.0};
  /// Point budget of the whole figure, shared by its series, at least 100 each (decimation
  /// keeps the extremes).
  std::size_t max_points{120000};
};

/// The figure as one SVG document (viewBox set, width 100 %).
std::string render_svg(const Figure& figure);

/// Ticks every `step` (1, 2 or 5 × 10^k) from `first` ≤ lo to `last` ≥ hi.
struct Ticks {
  double first{0.0};
  double last{0.0};
  double step{1.0};
  std::vector<double> values;
};
/// About `target` nice ticks covering [lo, hi]; an empty or zero-width range gets one anyway.
Ticks nice_ticks(double lo, double hi, int target);

/// `v` with as many decimals as `step` needs, no exponent, thousands grouped with a space
/// ("1 200", "0.5", "-12"); "0" for a value within rounding of zero.
std::string format_number(double v, double step);

/// The unit an elapsed span reads best in.
struct TimeUnit {
  const char* name;
  double seconds;
};
TimeUnit elapsed_unit(double span_s);

/// Indices of at most about 2·buckets samples of `y` in order: per bucket of consecutive samples
/// its minimum and maximum, so a step or a spike survives any decimation.
std::vector<std::size_t> decimate(const std::vector<double>& y, std::size_t buckets);

/// Estimated width of `text` in px: 0.6 × font size per character (UTF-8 code point).
double text_width(std::string_view text, double font_size_px);

/// `s` with &, <, > and " escaped.
std::string xml_escape(std::string_view s);

}  // namespace nccomp::tools::plot
