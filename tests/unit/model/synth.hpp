// Generated measurement logs for the analysis tests and the benchmark: parts machined at
// irregular times (long and short parts, breaks, an overnight stop) so that time and part
// number are not proportional; tools changed every few parts (path resets); probe points at
// random positions and wall angles; a temperature with a day cycle. One or more undeclared
// effects of issue 11 are switched on by name, at a few µm against the probe noise.
#pragma once

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <numbers>
#include <ostream>
#include <random>
#include <string>
#include <vector>

#include "core/model/analysis.hpp"

namespace nccomp::test::synth {

namespace cm = core::model;

struct Options {
  std::uint64_t seed{1};
  std::size_t parts{60};
  std::size_t points_per_part{20};
  double noise_um{0.5};
  /// Effect names of issue 11 (thermal_drift = warm-up in time, thermal_temp = linear in temp_c,
  /// thermal_speed = a first-order lag of the spindle speed, wear_proportional = 0.3 × the
  /// tool's wear curve).
  std::vector<std::string> effects;
  /// A laser measurement of the tool after every part: tool_wear rows at edge points 0 and 1
  /// (the tools wear at different rates, with a break-in), noise 0.3 µm.
  bool tool_wear_rows{false};
  /// An extra column spindle_rpm (one speed per part); the effect thermal_speed follows it.
  bool speed_column{false};
  /// Serial correlation of the probe noise: each checkpoint's noise is an AR(1) series from part
  /// to part with this coefficient and standard deviation noise_um (0: independent noise).
  double noise_ar1_rho{0.0};
  /// Sessions (warm starts): the parts split into this many consecutive blocks, each its own
  /// Dataset::row_session (0: none, one session).
  std::size_t sessions{0};
  /// A different offset of the contour rows per session (a machine re-homed each morning),
  /// drawn N(0, σ²) with this σ [µm] from the seed (0: none). session_offsets_um() gives them.
  double session_sigma_um{0.0};
};

/// Session of part p (1-based) of `opt`.
inline std::uint32_t session_of_part(const Options& opt, double part) {
  return static_cast<std::uint32_t>((static_cast<std::size_t>(part) - 1) * opt.sessions /
                                    opt.parts);
}

/// The true offset [µm] of each session of `opt` (its own random stream: the other draws of
/// generate() do not change with it).
inline std::vector<double> session_offsets_um(const Options& opt) {
  std::mt19937_64 rng(opt.seed * 7919U + 17U);
  std::normal_distribution<double> gauss(0.0, 1.0);
  std::vector<double> out(opt.sessions, 0.0);
  for (auto& v : out) v = opt.session_sigma_um * gauss(rng);
  return out;
}

/// True wear [µm] of `tool` at edge point `point` after `path_mm` of cut: a break-in over 300 mm
/// and a steady rate; each tool wears at its own rate.
inline double tool_wear_um(int tool, int point, double path_mm) {
  const double rate_um_per_mm = 0.002 + 0.0012 * static_cast<double>(tool % 3);
  const double break_in_um = 2.0 + 0.8 * static_cast<double>(tool % 2);
  const double edge = point == 0 ? 1.0 : 0.7;
  return edge * (break_in_um * (1.0 - std::exp(-path_mm / 300.0)) + rate_um_per_mm * path_mm);
}

/// Time constant [s] and gain [µm/rpm] of the thermal_speed effect.
inline constexpr double kSpeedTauS = 1800.0;
inline constexpr double kSpeedGainUmPerRpm = 8e-4;

/// The true value of each effect (µm) at a context; also used to check fitted terms.
inline double effect_um(const std::string& name, const cm::Row& r, double run_s) {
  const double t = r[0];
  const double x = r[5];
  const double angle = r[8];
  const double path = r[9];
  const double temp = r[10];
  const double part = r[1];
  const double y = r[6];
  const double z = r[7];
  if (name == "thermal_drift") return 4.0 * (1.0 - std::exp(-t / 5400.0));
  if (name == "thermal_temp") return 2.5 * (temp - 20.0);
  // Each checkpoint its own rate, −1.2 … +1.2 µm/K by point mod 5 (mean 0: no shared rate).
  if (name == "thermal_temp_per_point") {
    return (0.6 * std::fmod(r[4], 5.0) - 1.2) * (temp - 20.0);
  }
  if (name == "position_x") {
    const double u = (x - 200.0) / 100.0;
    return 1.2 * u * u + 1.0 * u;
  }
  if (name == "position_y") {
    const double u = (y - 150.0) / 75.0;
    return 1.0 * u * u - 0.8 * u;
  }
  if (name == "position_z") {
    const double u = (z + 25.0) / 12.5;
    return -1.1 * u * u + 0.9 * u;
  }
  if (name == "periodic_x") return 2.5 * std::sin(2.0 * std::numbers::pi * x / 25.0 + 0.7);
  if (name == "periodic_y") return 2.0 * std::sin(2.0 * std::numbers::pi * y / 20.0 - 1.1);
  if (name == "periodic_z") return 1.8 * std::cos(2.0 * std::numbers::pi * z / 8.0 + 0.3);
  if (name == "wear_proportional") return 0.3 * tool_wear_um(static_cast<int>(r[2]), 0, path);
  if (name == "tool_wear") return 1.5e-3 * path;
  if (name == "wear_nonlinear") return 4.0 * (1.0 - std::exp(-path / 400.0));
  if (name == "part_trend") return 0.08 * part;
  if (name == "level_change") return t >= 0.4 * run_s ? 4.0 : 0.0;
  if (name == "contact_angle") {
    const double u = (angle - 30.0) / 20.0;
    return 2.0 * u * u;
  }
  return 0.0;
}

/// Declared model of the tests: one constant per checkpoint of the contour.
inline std::vector<cm::TermSpec> declared_terms() {
  cm::TermSpec offset;
  offset.name = "offset";
  offset.form = cm::Form::kConstant;
  offset.per = {static_cast<int>(cm::Column::kPoint), -1};
  return {offset};
}

inline cm::Dataset generate(const Options& opt) {
  std::mt19937_64 rng(opt.seed);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  std::normal_distribution<double> gauss(0.0, 1.0);
  cm::Dataset d;
  for (std::size_t c = 0; c < cm::kStandardColumns; ++c)
    d.columns[c].reserve(opt.parts * opt.points_per_part);
  // Per-checkpoint constants of the declared model.
  std::vector<double> point_offset(opt.points_per_part);
  for (auto& v : point_offset) v = 6.0 * (uni(rng) - 0.5);
  std::vector<cm::Row> rows;
  double t = 0.0;
  int tool = 1;
  double path = 0.0;
  std::size_t parts_on_tool = 0;
  std::size_t tool_life = 4 + static_cast<std::size_t>(uni(rng) * 5.0);
  const double phase = 2.0 * std::numbers::pi * uni(rng);
  if (opt.speed_column) d.extra_columns = {"spindle_rpm"};
  std::vector<double> rpm;  // per row (speed_column)
  for (std::size_t p = 0; p < opt.parts; ++p) {
    if (parts_on_tool >= tool_life) {
      tool = tool % 3 + 1;
      path = 0.0;
      parts_on_tool = 0;
      tool_life = 4 + static_cast<std::size_t>(uni(rng) * 5.0);
    }
    // Irregular part times: short and long parts, breaks, now and then a long stop.
    const double duration_s = 300.0 + 1500.0 * uni(rng) * uni(rng) * 2.0;
    double gap_s = 60.0 + 600.0 * uni(rng);
    if (uni(rng) < 0.08) gap_s += 3600.0 * (1.0 + 3.0 * uni(rng));
    t += gap_s + duration_s;
    path += duration_s * (0.25 + 0.3 * uni(rng));  // feed varies with the part's program
    ++parts_on_tool;
    const double part_rpm = opt.speed_column ? 1000.0 * std::floor(2.0 + 7.0 * uni(rng)) : 0.0;
    for (std::size_t k = 0; k < opt.points_per_part; ++k) {
      cm::Row r = cm::unknown_row();
      r[0] = t + 4.0 * static_cast<double>(k);
      r[1] = static_cast<double>(p + 1);
      r[2] = tool;
      r[3] = 1.0;  // contour
      r[4] = static_cast<double>(k);
      r[5] = 400.0 * uni(rng);
      r[6] = 300.0 * uni(rng);
      r[7] = -50.0 * uni(rng);
      r[8] = 60.0 * uni(rng);
      r[9] = path;
      r[10] = 20.0 + 1.5 * std::sin(2.0 * std::numbers::pi * r[0] / 86400.0 + phase) +
              0.05 * gauss(rng);
      rows.push_back(r);
      rpm.push_back(part_rpm);
    }
    if (opt.tool_wear_rows) {
      // The laser measures the tool after the part: two edge points.
      for (int e = 0; e < 2; ++e) {
        cm::Row r = cm::unknown_row();
        r[0] = t + 4.0 * static_cast<double>(opt.points_per_part) + 30.0 + e;
        r[1] = static_cast<double>(p + 1);
        r[2] = tool;
        r[3] = 0.0;  // tool_wear
        r[4] = e;
        r[5] = 0.0;
        r[6] = 0.0;
        r[7] = 0.0;
        r[9] = path;
        r[10] = rows.back()[10];
        rows.push_back(r);
        rpm.push_back(0.0);
      }
    }
  }
  const double run_s = rows.empty() ? 0.0 : rows.back()[0];
  double lag = 0.0;  // thermal_speed: the lag of the rows' speed, held between rows
  std::vector<double> point_noise(opt.points_per_part, 0.0);  // AR(1) state per checkpoint
  std::vector<std::uint8_t> point_seen(opt.points_per_part, 0);
  const double innovation = std::sqrt(1.0 - opt.noise_ar1_rho * opt.noise_ar1_rho);
  const std::vector<double> session_offset = session_offsets_um(opt);
  for (std::size_t i = 0; i < rows.size(); ++i) {
    const cm::Row& r = rows[i];
    if (i == 0) {
      lag = rpm[0];
    } else {
      lag = rpm[i - 1] + (lag - rpm[i - 1]) * std::exp(-(r[0] - rows[i - 1][0]) / kSpeedTauS);
    }
    double y = 0.0;
    if (r[3] < 0.5) {  // tool_wear
      y = tool_wear_um(static_cast<int>(r[2]), static_cast<int>(r[4]), r[9]) + 0.3 * gauss(rng);
    } else {
      const auto k = static_cast<std::size_t>(r[4]);
      double& noise = point_noise[k];
      const double z = opt.noise_um * gauss(rng);
      noise = point_seen[k] != 0U ? opt.noise_ar1_rho * noise + innovation * z : z;
      point_seen[k] = 1;
      y = point_offset[k] + noise;
      if (opt.sessions > 0) y += session_offset[session_of_part(opt, r[1])];
      for (const auto& e : opt.effects) {
        y += e == "thermal_speed" ? kSpeedGainUmPerRpm * lag : effect_um(e, r, run_s);
      }
    }
    for (std::size_t c = 0; c < cm::kStandardColumns; ++c) d.columns[c].push_back(r[c]);
    if (opt.speed_column) {
      d.columns.resize(cm::kStandardColumns + 1);
      d.columns[cm::kStandardColumns].push_back(rpm[i]);
    }
    d.target_um.push_back(y);
    if (opt.sessions > 0) d.row_session.push_back(session_of_part(opt, r[1]));
  }
  return d;
}

/// The declared model when the log has tool_wear rows: one constant per checkpoint of the
/// contour, and the wear curve per tool and edge point (the break-in length known, 300 mm).
inline std::vector<cm::TermSpec> declared_with_wear() {
  cm::TermSpec offset;
  offset.name = "offset";
  offset.form = cm::Form::kConstant;
  offset.per = {static_cast<int>(cm::Column::kPoint), -1};
  offset.kind_mask = 0x2;
  cm::TermSpec rate;
  rate.name = "wear";
  rate.form = cm::Form::kLinear;
  rate.column = static_cast<int>(cm::Column::kPath);
  rate.per = {static_cast<int>(cm::Column::kTool), static_cast<int>(cm::Column::kPoint)};
  rate.kind_mask = 0x1;
  cm::TermSpec break_in = rate;
  break_in.name = "wear_break_in";
  break_in.form = cm::Form::kExpRise;
  break_in.scale = 300.0;
  return {offset, rate, break_in};
}

/// The analysis config of a generated log: the declared model, the search on the contour rows
/// (with the extra column, if any, as a lag candidate).
inline cm::AnalysisConfig config(const Options& opt = {}) {
  cm::AnalysisConfig c;
  c.declared = opt.tool_wear_rows ? declared_with_wear() : declared_terms();
  c.search.period_min_mm = 5.0;
  if (opt.tool_wear_rows) c.search.kind_mask = 0x2;
  if (opt.speed_column) c.search.lag_columns = {static_cast<int>(cm::kStandardColumns)};
  return c;
}

/// Writes `d` as a v1 measurement log (measured_um = target, applied_um = 0).
inline void write_csv(std::ostream& o, const cm::Dataset& d) {
  o << "time_s,part,tool,kind,point,x_mm,y_mm,z_mm,angle_deg,path_mm,temp_c,measured_um,"
       "applied_um\n";
  static const char* kinds[] = {"tool_wear", "contour", "calib"};
  char buf[512];
  auto cell = [](double v, int decimals) {
    if (!std::isfinite(v)) return std::string();
    char c[64];
    std::snprintf(c, sizeof c, "%.*f", decimals, v);
    return std::string(c);
  };
  for (std::size_t i = 0; i < d.rows(); ++i) {
    const cm::Row r = d.row(i);
    std::snprintf(buf, sizeof buf, "%.3f,%d,%d,%s,%d,%s,%s,%s,%s,%s,%s,%.4f,0\n", r[0],
                  static_cast<int>(r[1]), static_cast<int>(r[2]), kinds[static_cast<int>(r[3])],
                  static_cast<int>(r[4]), cell(r[5], 4).c_str(), cell(r[6], 4).c_str(),
                  cell(r[7], 4).c_str(), cell(r[8], 3).c_str(), cell(r[9], 2).c_str(),
                  cell(r[10], 4).c_str(), d.target_um[i]);
    o << buf;
  }
}

}  // namespace nccomp::test::synth
