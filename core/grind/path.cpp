#include "core/grind/path.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <stdexcept>

namespace nccomp::core::grind {

double interpolate(const GridTrajectory& t, double z_mm) noexcept {
  const double x = (z_mm - t.z0_mm) / t.spacing_mm;
  if (!(x > 0.0)) {
    return t.u_mm.front();
  }
  const auto n = t.u_mm.size();
  if (x >= static_cast<double>(n - 1)) {
    return t.u_mm.back();
  }
  const auto i = static_cast<std::size_t>(x);
  const double f = x - static_cast<double>(i);
  return t.u_mm[i] + f * (t.u_mm[i + 1] - t.u_mm[i]);
}

std::vector<TrajectoryPoint> simplify_polyline(const GridTrajectory& t, double below_mm,
                                               double above_mm, double max_move_mm) {
  if (!(below_mm >= 0.0) || !(above_mm >= 0.0) || !(below_mm + above_mm > 0.0) ||
      !std::isfinite(below_mm + above_mm)) {
    throw std::invalid_argument("chord tolerance band must be >= 0 on both sides and > 0 wide");
  }
  std::size_t first = 0;
  std::size_t last = t.u_mm.size();
  while (first < last && std::isnan(t.u_mm[first])) ++first;
  while (last > first && std::isnan(t.u_mm[last - 1])) --last;
  if (last - first < 1) {
    throw std::invalid_argument("trajectory is empty");
  }
  // The band [U − below, U + above] is a symmetric band of half width `half` about U + shift;
  // vertices sit on the shifted trajectory so that concave and convex parts both get long
  // chords (with vertices on U itself, a gouge-free band would force one-sample moves on a
  // crown, whose chords all lie below it).
  const double shift = 0.5 * (above_mm - below_mm);
  const double half = 0.5 * (above_mm + below_mm);
  std::vector<TrajectoryPoint> out;
  const auto z = [&](std::size_t i) { return t.z_at(static_cast<std::ptrdiff_t>(i)); };
  const std::size_t max_steps =
      max_move_mm > 0.0 ? std::max<std::size_t>(
                              1, static_cast<std::size_t>(std::floor(max_move_mm / t.spacing_mm)))
                        : std::numeric_limits<std::size_t>::max();
  std::size_t a = first;
  out.push_back({z(a), t.u_mm[a] + shift});
  while (a + 1 < last) {
    double lo = -std::numeric_limits<double>::infinity();
    double hi = std::numeric_limits<double>::infinity();
    std::size_t good = a + 1;
    for (std::size_t b = a + 1; b < last && b - a <= max_steps; ++b) {
      if (std::isnan(t.u_mm[b])) {
        throw std::invalid_argument("trajectory has a gap at z = " + std::to_string(z(b)));
      }
      const double dz = z(b) - z(a);
      const double du = t.u_mm[b] - t.u_mm[a];
      lo = std::max(lo, (du - half) / dz);
      hi = std::min(hi, (du + half) / dz);
      if (lo > hi) {
        break;
      }
      const double slope = du / dz;
      if (slope >= lo && slope <= hi) {
        good = b;  // the chord a→b passes within the band of every point in between
      }
    }
    a = good;
    out.push_back({z(a), t.u_mm[a] + shift});
  }
  return out;
}

ChordError chord_error(const GridTrajectory& t, std::span<const TrajectoryPoint> poly) {
  ChordError e;
  if (poly.size() < 2) {
    return e;
  }
  std::size_t s = 0;
  const auto n = static_cast<std::ptrdiff_t>(t.u_mm.size());
  for (std::ptrdiff_t i = 0; i < n; ++i) {
    const double z = t.z_at(i);
    const double u = t.u_mm[static_cast<std::size_t>(i)];
    if (z < poly.front().z_mm - 1e-9 || z > poly.back().z_mm + 1e-9 || std::isnan(u)) {
      continue;
    }
    while (s + 2 < poly.size() && poly[s + 1].z_mm < z) {
      ++s;
    }
    const auto& p0 = poly[s];
    const auto& p1 = poly[s + 1];
    const double f = !(p1.z_mm > p0.z_mm) ? 0.0 : (z - p0.z_mm) / (p1.z_mm - p0.z_mm);
    const double d = p0.u_mm + f * (p1.u_mm - p0.u_mm) - u;
    e.below_mm = std::max(e.below_mm, -d);
    e.above_mm = std::max(e.above_mm, d);
  }
  return e;
}

double chord_error_mm(const GridTrajectory& t, std::span<const TrajectoryPoint> poly) {
  return chord_error(t, poly).max_mm();
}

std::vector<TrajectoryPoint> round_vertices(std::span<const TrajectoryPoint> poly, int decimals,
                                            bool u_up) {
  if (decimals < 0 || decimals > 9) {
    throw std::invalid_argument("decimals must be 0..9");
  }
  const double scale = std::pow(10.0, decimals);
  std::vector<TrajectoryPoint> out(poly.begin(), poly.end());
  for (auto& p : out) {
    p.z_mm = std::round(p.z_mm * scale) / scale;
    // 1e-9 of a unit of slack: a value already on the grid must not be pushed up a unit.
    p.u_mm = (u_up ? std::ceil(p.u_mm * scale - 1e-9) : std::round(p.u_mm * scale)) / scale;
  }
  return out;
}

std::string gcode_blocks(std::span<const TrajectoryPoint> poly, const GcodeSpec& spec) {
  if (spec.decimals < 0 || spec.decimals > 9) {
    throw std::invalid_argument("decimals must be 0..9");
  }
  std::string out;
  for (const auto& c : spec.header_comments) {
    out += "; " + c + "\n";
  }
  char buf[160];
  int block = spec.first_block;
  for (std::size_t i = 0; i < poly.size(); ++i) {
    const char* prefix = i == 0 ? " G90 G01" : " G01";
    int len = std::snprintf(buf, sizeof buf, "N%d%s %c%.*f %c%.*f", block, prefix, spec.z_axis,
                            spec.decimals, poly[i].z_mm + 0.0, spec.u_axis, spec.decimals,
                            poly[i].u_mm + 0.0);
    if (i == 0 && spec.feed_mm_per_min > 0.0 && len > 0) {
      std::snprintf(buf + len, sizeof buf - static_cast<std::size_t>(len), " F%.1f",
                    spec.feed_mm_per_min);
    }
    out += buf;
    out += '\n';
    block += spec.block_step;
  }
  return out;
}

std::vector<TableRow> correction_table(const GridTrajectory& t, const UniformProfile& p,
                                       double spacing_mm) {
  if (!(spacing_mm > 0.0) || !std::isfinite(spacing_mm)) {
    throw std::invalid_argument("table spacing must be > 0 mm");
  }
  const double span = p.z_last_mm() - p.z0_mm;
  const double rows = std::floor(span / spacing_mm * (1.0 + 1e-12)) + 1.0;
  if (rows > 1e7) {
    throw std::invalid_argument("table spacing gives more than 10^7 rows");
  }
  std::vector<TableRow> out;
  const auto add = [&](double z) {
    const double ut = interpolate(t, z);
    const double pz = p.interpolate(z);
    out.push_back({z, pz, ut, (ut - pz) * 1000.0});
  };
  const auto n = static_cast<std::size_t>(rows);
  for (std::size_t i = 0; i < n; ++i) {
    add(p.z0_mm + static_cast<double>(i) * spacing_mm);
  }
  if (p.z_last_mm() - out.back().z_mm > 1e-9 * spacing_mm) {
    add(p.z_last_mm());
  }
  return out;
}

double table_interpolation_error_mm(const GridTrajectory& t, const UniformProfile& p,
                                    std::span<const TableRow> table) {
  double worst = 0.0;
  std::size_t s = 0;
  for (std::size_t i = 0; i < p.size() && table.size() >= 2; ++i) {
    const double z = p.z_at(static_cast<std::ptrdiff_t>(i));
    while (s + 2 < table.size() && table[s + 1].z_mm < z) {
      ++s;
    }
    const auto& a = table[s];
    const auto& b = table[s + 1];
    const double f = (z - a.z_mm) / (b.z_mm - a.z_mm);
    const double u = a.u_wheel_mm + f * (b.u_wheel_mm - a.u_wheel_mm);
    worst = std::max(worst, std::abs(interpolate(t, z) - u));
  }
  return worst;
}

}  // namespace nccomp::core::grind
