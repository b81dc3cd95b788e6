#include "core/checkpoint/plan.hpp"

#include <algorithm>
#include <array>
#include <charconv>
#include <cmath>
#include <limits>
#include <numbers>
#include <sstream>
#include <stdexcept>
#include <string>

#include "core/checkpoint/probe.hpp"
#include "core/common/config_issue.hpp"

namespace nccomp::core::checkpoint {

namespace {

constexpr double kDegToRad = std::numbers::pi / 180.0;
// Points closer than this along the contour are one checkpoint (a corner point and an extra
// point at the same place must not be probed twice).
constexpr double kMergeDistanceMm = 1e-3;
constexpr double kMaxCoordinateMm = 1e6;

[[noreturn]] void fail(const std::string& key, const std::string& reason) {
  throw ConfigInvalid("checkpoints." + key, reason);
}

std::string num(double v) {
  std::ostringstream s;
  s << v;
  return s.str();
}

void require_finite(double v, const std::string& key) {
  if (!std::isfinite(v)) {
    fail(key, "must be a finite number, got " + num(v));
  }
}

// The polyline with its segments and cumulative arc length.
struct Polyline {
  std::vector<Point2> p;  // vertices; a closed contour repeats the first at the end
  std::vector<double> s;  // arc length at each vertex
  [[nodiscard]] double length() const { return s.back(); }
  [[nodiscard]] std::size_t segments() const { return p.size() - 1; }
};

Polyline make_polyline(const PlanConfig& c) {
  Polyline pl;
  pl.p.reserve(c.contour.size() + 1);
  for (const ContourPoint& v : c.contour) {
    pl.p.push_back({v.x_mm, v.y_mm});
  }
  if (c.closed) {
    pl.p.push_back(pl.p.front());
  }
  pl.s.resize(pl.p.size(), 0.0);
  for (std::size_t i = 1; i < pl.p.size(); ++i) {
    const double len = std::hypot(pl.p[i].x_mm - pl.p[i - 1].x_mm, pl.p[i].y_mm - pl.p[i - 1].y_mm);
    if (!(len > 1e-9)) {
      fail("contour", "points " + std::to_string(i - 1) + " and " +
                          std::to_string(i % c.contour.size()) + " coincide (zero-length segment)");
    }
    pl.s[i] = pl.s[i - 1] + len;
  }
  return pl;
}

// Segment index containing arc length s (segment i spans s[i]..s[i+1]).
std::size_t segment_at(const Polyline& pl, double s) {
  const auto it = std::upper_bound(pl.s.begin(), pl.s.end(), s);
  const auto idx = static_cast<std::size_t>(std::max<std::ptrdiff_t>(0, it - pl.s.begin() - 1));
  return std::min(idx, pl.segments() - 1);
}

double signed_area(const std::vector<ContourPoint>& p) {
  double a = 0.0;
  for (std::size_t i = 0; i < p.size(); ++i) {
    const ContourPoint& u = p[i];
    const ContourPoint& v = p[(i + 1) % p.size()];
    a += u.x_mm * v.y_mm - v.x_mm * u.y_mm;
  }
  return 0.5 * a;
}

}  // namespace

const char* material_side_name(MaterialSide side) noexcept {
  switch (side) {
    case MaterialSide::kLeft:
      return "left";
    case MaterialSide::kRight:
      return "right";
    case MaterialSide::kInside:
      return "inside";
    case MaterialSide::kOutside:
      return "outside";
  }
  return "?";
}

Plan make_plan(const PlanConfig& c) {
  // --- validation, naming the key ---
  if (c.contour.size() < (c.closed ? 3U : 2U)) {
    fail("contour", std::string("needs at least ") + (c.closed ? "3" : "2") + " points, got " +
                        std::to_string(c.contour.size()));
  }
  if (c.contour.size() > kMaxContourPoints) {
    fail("contour", "more than " + std::to_string(kMaxContourPoints) + " points");
  }
  for (std::size_t i = 0; i < c.contour.size(); ++i) {
    if (!std::isfinite(c.contour[i].x_mm) || !std::isfinite(c.contour[i].y_mm)) {
      fail("contour", "point " + std::to_string(i) + " is not finite");
    }
    // Beyond any machine's travel; also keeps lengths and path positions exact to 1 µm.
    if (std::fabs(c.contour[i].x_mm) > kMaxCoordinateMm ||
        std::fabs(c.contour[i].y_mm) > kMaxCoordinateMm) {
      fail("contour", "point " + std::to_string(i) + " is farther than " + num(kMaxCoordinateMm) +
                          " mm from the origin");
    }
  }
  if (!c.closed && (c.material == MaterialSide::kInside || c.material == MaterialSide::kOutside)) {
    fail("material", "\"inside\"/\"outside\" need a closed contour; use \"left\" or \"right\"");
  }
  for (const auto& [v, key] :
       {std::pair{c.contour_z_mm, "contour_z_mm"}, std::pair{c.z_start_mm, "z_start_mm"},
        std::pair{c.z_end_mm, "z_end_mm"},
        std::pair{c.program_path_start_mm, "program_path_start_mm"},
        std::pair{c.level_link_mm, "level_link_mm"}}) {
    require_finite(v, key);
    if (std::fabs(v) > kMaxCoordinateMm) {
      fail(key, "magnitude above " + num(kMaxCoordinateMm) + " mm");
    }
  }
  if (!(c.depth_step_mm > 0.0) || !std::isfinite(c.depth_step_mm)) {
    fail("depth_step_mm", "must be a positive finite number, got " + num(c.depth_step_mm));
  }
  if (c.z_end_mm > c.z_start_mm) {
    fail("z_end_mm",
         "must not be above z_start_mm (" + num(c.z_end_mm) + " > " + num(c.z_start_mm) + ")");
  }
  const double level_span = (c.z_start_mm - c.z_end_mm) / c.depth_step_mm;
  if (level_span + 1.0 > static_cast<double>(kMaxLevels)) {
    fail("depth_step_mm", "gives more than " + std::to_string(kMaxLevels) + " levels");
  }
  require_finite(c.wall_angle_deg, "wall_angle_deg");
  if (std::fabs(c.wall_angle_deg) >= kMaxWallAngleDeg) {
    fail("wall_angle_deg", "must be below 89 degrees in magnitude, got " + num(c.wall_angle_deg));
  }
  for (std::size_t i = 0; i < c.contour.size(); ++i) {
    const ContourPoint& v = c.contour[i];
    const std::string key = "contour[" + std::to_string(i) + "]";
    // NaN = not given; anything else must be a usable angle.
    if (!std::isnan(v.alpha_deg) &&
        (!std::isfinite(v.alpha_deg) || std::fabs(v.alpha_deg) >= kMaxWallAngleDeg)) {
      fail(key + ".alpha_deg",
           "must be a finite angle below 89 degrees in magnitude, got " + num(v.alpha_deg));
    }
    if (v.corner != CornerMark::kAuto && v.corner != CornerMark::kCorner &&
        v.corner != CornerMark::kNoCorner) {
      fail(key + ".corner", "unknown corner mark");
    }
    if (!c.closed && v.corner == CornerMark::kCorner && (i == 0 || i + 1 == c.contour.size())) {
      fail(key + ".corner",
           "an end point of an open contour cannot be a corner (sub-curve boundaries are "
           "interior vertices)");
    }
  }
  if (!(c.corner_angle_deg > 0.0 && c.corner_angle_deg < 180.0)) {
    fail("corner_angle_deg", "must be in (0, 180), got " + num(c.corner_angle_deg));
  }
  if (!(c.corner_offset_mm > 0.0) || !std::isfinite(c.corner_offset_mm)) {
    fail("corner_offset_mm", "must be a positive finite number, got " + num(c.corner_offset_mm));
  }
  for (const auto& [v, key] : {std::pair{c.tool_radius_mm, "tool_radius_mm"},
                               std::pair{c.ball_radius_mm, "ball_radius_mm"},
                               std::pair{c.probe_approach_mm, "probe_approach_mm"}}) {
    if (!(v >= 0.0) || !std::isfinite(v)) {
      fail(key, "must be a finite number >= 0, got " + num(v));
    }
  }

  const Polyline pl = make_polyline(c);
  const double length = pl.length();

  // --- air-side normal: which side of the machining direction the material is on ---
  bool material_left = c.material == MaterialSide::kLeft;
  if (c.material == MaterialSide::kInside || c.material == MaterialSide::kOutside) {
    const double area = signed_area(c.contour);
    if (std::fabs(area) < 1e-12) {
      fail("contour", "closed contour has zero area: inside/outside is undefined");
    }
    // Counter-clockwise (area > 0): the inside is on the left of the direction of travel.
    material_left = (area > 0.0) == (c.material == MaterialSide::kInside);
  }

  // --- wall angle of each segment: a vertex's alpha_deg holds from it on ---
  const std::size_t n_seg = pl.segments();
  std::vector<double> seg_alpha(n_seg, c.wall_angle_deg);
  for (std::size_t i = 0; i < n_seg; ++i) {
    if (!std::isnan(c.contour[i].alpha_deg)) {
      seg_alpha[i] = c.contour[i].alpha_deg;
    } else if (i > 0) {
      seg_alpha[i] = seg_alpha[i - 1];
    }
  }

  // --- corners: vertices marked as sub-curve boundaries, or turning by more than
  //     corner_angle_deg (unless marked as no corner) ---
  std::vector<double> corner_s;
  std::size_t marked = 0;
  // Closed: every vertex (vertex 0 joins the closing segment); open: interior vertices only.
  for (std::size_t v = c.closed ? 0 : 1; v < n_seg; ++v) {
    const CornerMark mark = c.contour[v].corner;
    if (mark == CornerMark::kCorner) {
      corner_s.push_back(pl.s[v]);
      ++marked;
      continue;
    }
    if (mark == CornerMark::kNoCorner) {
      continue;
    }
    const std::size_t in_seg = (v == 0) ? n_seg - 1 : v - 1;
    const std::size_t out_seg = v;
    const double ax = pl.p[in_seg + 1].x_mm - pl.p[in_seg].x_mm;
    const double ay = pl.p[in_seg + 1].y_mm - pl.p[in_seg].y_mm;
    const double bx = pl.p[out_seg + 1].x_mm - pl.p[out_seg].x_mm;
    const double by = pl.p[out_seg + 1].y_mm - pl.p[out_seg].y_mm;
    const double turn_deg = std::fabs(std::atan2(ax * by - ay * bx, ax * bx + ay * by)) / kDegToRad;
    if (turn_deg > c.corner_angle_deg) {
      corner_s.push_back(pl.s[v]);
    }
  }

  // --- positions along the contour ---
  struct Pos {
    double s;
    CheckpointSource source;
  };
  std::vector<Pos> positions;
  for (std::size_t k = 0; k < corner_s.size(); ++k) {
    const double sc = corner_s[k];
    // Never past the middle of the neighbouring sub-curve: the next corner's points live there.
    const auto gap = [&](std::size_t other) {
      double d = std::fabs(corner_s[other] - sc);
      if (c.closed && corner_s.size() == 1) {
        d = length;
      } else if (c.closed) {
        d = std::min(d, length - d);
      }
      return d;
    };
    double before = c.corner_offset_mm;
    double after = c.corner_offset_mm;
    if (corner_s.size() > 1) {
      const std::size_t prev = (k == 0) ? corner_s.size() - 1 : k - 1;
      const std::size_t next = (k + 1) % corner_s.size();
      if (c.closed || k > 0) {
        before = std::min(before, 0.5 * gap(prev));
      }
      if (c.closed || k + 1 < corner_s.size()) {
        after = std::min(after, 0.5 * gap(next));
      }
    }
    if (c.closed && corner_s.size() == 1) {
      before = after = std::min(c.corner_offset_mm, 0.5 * length);
    }
    // Open contours: stay on the contour.
    double s_before = sc - before;
    double s_after = sc + after;
    if (c.closed) {
      s_before = std::fmod(s_before + length, length);
      s_after = std::fmod(s_after, length);
    } else {
      s_before = std::max(s_before, 0.0);
      s_after = std::min(s_after, length);
    }
    positions.push_back({s_before, CheckpointSource::kCorner});
    positions.push_back({s_after, CheckpointSource::kCorner});
  }
  for (std::size_t i = 0; i < c.extra_points_mm.size(); ++i) {
    const double s = c.extra_points_mm[i];
    const std::string key = "extra_points_mm[" + std::to_string(i) + "]";
    require_finite(s, key);
    if (s < 0.0 || s > length) {
      fail(key,
           "position " + num(s) + " mm is outside the contour (length " + num(length) + " mm)");
    }
    positions.push_back({s, CheckpointSource::kExtra});
  }
  for (std::size_t i = 0; i < c.extra_regions.size(); ++i) {
    const ExtraRegion& r = c.extra_regions[i];
    const std::string key = "extra_regions[" + std::to_string(i) + "]";
    require_finite(r.from_mm, key + ".from_mm");
    require_finite(r.to_mm, key + ".to_mm");
    if (r.from_mm < 0.0 || r.to_mm > length || r.to_mm < r.from_mm) {
      fail(key, "region [" + num(r.from_mm) + ", " + num(r.to_mm) +
                    "] mm must satisfy 0 <= from_mm <= to_mm <= contour length " + num(length));
    }
    if (!(r.spacing_mm > 0.0) || !std::isfinite(r.spacing_mm)) {
      fail(key + ".spacing_mm", "must be a positive finite number, got " + num(r.spacing_mm));
    }
    const double count = std::floor((r.to_mm - r.from_mm) / r.spacing_mm + 1e-9);
    if (count + 1.0 > static_cast<double>(kMaxCheckpoints)) {
      fail(key + ".spacing_mm", "gives more than " + std::to_string(kMaxCheckpoints) + " points");
    }
    for (double k = 0.0; k <= count; k += 1.0) {
      positions.push_back({r.from_mm + k * r.spacing_mm, CheckpointSource::kExtra});
    }
  }
  std::stable_sort(positions.begin(), positions.end(),
                   [](const Pos& a, const Pos& b) { return a.s < b.s; });
  std::vector<Pos> merged;
  for (const Pos& p : positions) {
    if (!merged.empty() && p.s - merged.back().s < kMergeDistanceMm) {
      continue;  // the first (corner before extra when equal) wins
    }
    merged.push_back(p);
  }
  if (c.closed && merged.size() > 1 &&
      merged.front().s + length - merged.back().s < kMergeDistanceMm) {
    merged.pop_back();
  }
  if (merged.empty()) {
    fail("contour", "no checkpoints: no corner turns by more than corner_angle_deg (" +
                        num(c.corner_angle_deg) +
                        "), no vertex is marked as a corner and no extra_points_mm / "
                        "extra_regions are configured");
  }

  // --- levels ---
  Plan plan;
  plan.contour_length_mm = length;
  plan.corner_count = corner_s.size();
  plan.marked_corner_count = marked;
  const auto n_levels = static_cast<std::size_t>(std::floor(level_span + 1e-9)) + 1;
  for (std::size_t l = 0; l < n_levels; ++l) {
    plan.levels_z_mm.push_back(c.z_start_mm - static_cast<double>(l) * c.depth_step_mm);
  }
  if (n_levels * merged.size() > kMaxCheckpoints) {
    fail("depth_step_mm", std::to_string(n_levels) + " levels x " + std::to_string(merged.size()) +
                              " points = " + std::to_string(n_levels * merged.size()) +
                              " checkpoints, more than " + std::to_string(kMaxCheckpoints));
  }
  const double link = c.level_link_mm < 0.0 ? c.depth_step_mm : c.level_link_mm;
  std::int32_t id = 0;
  plan.alpha_min_deg = std::numeric_limits<double>::infinity();
  plan.alpha_max_deg = -std::numeric_limits<double>::infinity();
  for (std::size_t l = 0; l < n_levels; ++l) {
    const double z = plan.levels_z_mm[l];
    for (const Pos& p : merged) {
      const std::size_t seg = segment_at(pl, p.s);
      const double alpha_deg = seg_alpha[seg];
      const double draft_mm = (c.contour_z_mm - z) * std::tan(alpha_deg * kDegToRad);
      const Point2& a = pl.p[seg];
      const Point2& b = pl.p[seg + 1];
      const double seg_len = pl.s[seg + 1] - pl.s[seg];
      const double tx = (b.x_mm - a.x_mm) / seg_len;
      const double ty = (b.y_mm - a.y_mm) / seg_len;
      const double u = p.s - pl.s[seg];
      // Air side: right of the direction of travel when the material is on the left.
      const double nx = material_left ? ty : -ty;
      const double ny = material_left ? -tx : tx;
      Checkpoint cp;
      cp.id = id++;
      cp.level = static_cast<std::int32_t>(l);
      cp.source = p.source;
      cp.s_mm = p.s;
      cp.path_mm = c.program_path_start_mm + static_cast<double>(l) * (length + link) + p.s;
      cp.x_mm = a.x_mm + tx * u + nx * draft_mm;
      cp.y_mm = a.y_mm + ty * u + ny * draft_mm;
      cp.z_mm = z;
      cp.dir_x = -nx;
      cp.dir_y = -ny;
      cp.alpha_deg = alpha_deg;
      cp.pass_length_mm = length;
      cp.closed = c.closed;
      plan.alpha_min_deg = std::min(plan.alpha_min_deg, alpha_deg);
      plan.alpha_max_deg = std::max(plan.alpha_max_deg, alpha_deg);
      cp.tool_x_mm = cp.x_mm + nx * c.tool_radius_mm;
      cp.tool_y_mm = cp.y_mm + ny * c.tool_radius_mm;
      cp.start_x_mm = cp.x_mm + nx * (c.ball_radius_mm + c.probe_approach_mm);
      cp.start_y_mm = cp.y_mm + ny * (c.ball_radius_mm + c.probe_approach_mm);
      if (!plan.checkpoints.empty() && !(cp.path_mm > plan.checkpoints.back().path_mm)) {
        fail("level_link_mm", "levels " + std::to_string(l - 1) + " and " + std::to_string(l) +
                                  " share a program path position (an open contour's end and "
                                  "start): make level_link_mm > 0");
      }
      plan.checkpoints.push_back(cp);
    }
  }
  return plan;
}

std::vector<ContourPoint> parse_contour_csv(std::string_view text, std::string_view source) {
  std::vector<ContourPoint> points;
  const std::string src(source);
  const auto error = [&](std::size_t line, const std::string& reason) {
    return std::invalid_argument(src + ":" + std::to_string(line) + ": " + reason);
  };
  const auto trim = [](std::string_view s) {
    while (!s.empty() && (s.front() == ' ' || s.front() == '\t')) s.remove_prefix(1);
    while (!s.empty() && (s.back() == ' ' || s.back() == '\t' || s.back() == '\r')) {
      s.remove_suffix(1);
    }
    return s;
  };
  // Fields of one line (at most kMaxColumns + 1, so a line with too many is recognised).
  constexpr std::size_t kMaxColumns = 4;
  const auto split = [&](std::string_view line, std::array<std::string_view, kMaxColumns + 1>& f) {
    std::size_t n = 0;
    for (;;) {
      const std::size_t comma = line.find(',');
      f[n++] = trim(line.substr(0, comma));
      if (comma == std::string_view::npos || n == f.size()) {
        return n;
      }
      line.remove_prefix(comma + 1);
    }
  };
  enum class Col : std::uint8_t { kX, kY, kAlpha, kCorner };
  std::array<Col, kMaxColumns> cols{};
  std::size_t n_cols = 0;
  std::size_t line_no = 0;
  std::size_t pos = 0;
  while (pos <= text.size()) {
    const std::size_t eol = text.find('\n', pos);
    std::string_view line =
        text.substr(pos, eol == std::string_view::npos ? std::string_view::npos : eol - pos);
    pos = (eol == std::string_view::npos) ? text.size() + 1 : eol + 1;
    ++line_no;
    line = trim(line);
    if (line.empty() || line.front() == '#') {
      continue;
    }
    std::array<std::string_view, kMaxColumns + 1> f{};
    const std::size_t n = split(line, f);
    if (n_cols == 0) {
      if (n < 2 || f[0] != "x_mm" || f[1] != "y_mm" || n > kMaxColumns) {
        throw error(line_no,
                    "header must be 'x_mm,y_mm' optionally followed by 'alpha_deg' and / or "
                    "'corner', got '" +
                        std::string(line) + "'");
      }
      cols[0] = Col::kX;
      cols[1] = Col::kY;
      bool have_alpha = false;
      bool have_corner = false;
      for (std::size_t k = 2; k < n; ++k) {
        if (f[k] == "alpha_deg" && !have_alpha) {
          cols[k] = Col::kAlpha;
          have_alpha = true;
        } else if (f[k] == "corner" && !have_corner) {
          cols[k] = Col::kCorner;
          have_corner = true;
        } else {
          throw error(line_no, "header column " + std::to_string(k + 1) + ": '" +
                                   std::string(f[k]) +
                                   "' is not one of alpha_deg, corner (or appears twice)");
        }
      }
      n_cols = n;
      continue;
    }
    if (n != n_cols) {
      throw error(line_no, "expected " + std::to_string(n_cols) +
                               " comma-separated columns as in the header, got " +
                               std::to_string(std::min(n, kMaxColumns + 1)) +
                               (n > kMaxColumns ? " or more" : "") + ": '" + std::string(line) +
                               "'");
    }
    const auto parse = [&](std::string_view field, const char* name) {
      double v = 0.0;
      const char* first = field.data();
      const char* last = field.data() + field.size();
      const auto [ptr, ec] = std::from_chars(first, last, v);
      if (field.empty() || ec != std::errc() || ptr != last) {
        throw error(line_no, std::string("column ") + name + ": '" + std::string(field) +
                                 "' is not a number");
      }
      if (!std::isfinite(v)) {
        throw error(line_no, std::string("column ") + name + " is not finite");
      }
      return v;
    };
    ContourPoint p;
    for (std::size_t k = 0; k < n_cols; ++k) {
      switch (cols[k]) {
        case Col::kX:
          p.x_mm = parse(f[k], "x_mm");
          break;
        case Col::kY:
          p.y_mm = parse(f[k], "y_mm");
          break;
        case Col::kAlpha:
          if (!f[k].empty()) {
            p.alpha_deg = parse(f[k], "alpha_deg");
            if (std::fabs(p.alpha_deg) >= kMaxWallAngleDeg) {
              throw error(line_no, "column alpha_deg: " + std::string(f[k]) +
                                       " is not below 89 degrees in magnitude");
            }
          }
          break;
        case Col::kCorner:
          if (f[k] == "1") {
            p.corner = CornerMark::kCorner;
          } else if (f[k] == "0") {
            p.corner = CornerMark::kNoCorner;
          } else if (!f[k].empty()) {
            throw error(line_no, "column corner: '" + std::string(f[k]) +
                                     "' must be 1 (sub-curve boundary), 0 (no corner) or empty "
                                     "(by the turn angle)");
          }
          break;
      }
    }
    if (points.size() >= kMaxContourPoints) {
      throw error(line_no, "more than " + std::to_string(kMaxContourPoints) + " points");
    }
    points.push_back(p);
  }
  if (n_cols == 0) {
    throw std::invalid_argument(src + ": empty contour file (no 'x_mm,y_mm' header)");
  }
  if (points.empty()) {
    throw std::invalid_argument(src + ": contour file has a header but no points");
  }
  return points;
}

}  // namespace nccomp::core::checkpoint
