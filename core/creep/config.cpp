#include "core/creep/config.hpp"

#include <cmath>
#include <stdexcept>
#include <string>

namespace nccomp::core::creep {

namespace {

[[noreturn]] void fail(const std::string& key, const std::string& what) {
  throw std::invalid_argument("creep config: " + key + " " + what);
}

std::string num(double v) { return std::to_string(v); }

void positive(double v, const std::string& key) {
  if (!std::isfinite(v) || v <= 0.0) fail(key, "must be a positive finite number, got " + num(v));
}

void non_negative(double v, const std::string& key) {
  if (!std::isfinite(v) || v < 0.0) fail(key, "must be a finite number >= 0, got " + num(v));
}

void finite(double v, const std::string& key) {
  if (!std::isfinite(v)) fail(key, "must be finite, got " + num(v));
}

void sign(double v, const std::string& key) {
  if (!(std::fabs(v - 1.0) < 1e-12 || std::fabs(v + 1.0) < 1e-12)) {
    fail(key, "must be +1 or -1, got " + num(v));
  }
}

void register_index(std::int32_t r, const std::string& key) {
  if (r < -1 || r > 65535) fail(key, "must be -1 (unused) or 0..65535, got " + std::to_string(r));
}

void increasing_table(const std::vector<double>& x, const std::string& key) {
  for (std::size_t i = 0; i < x.size(); ++i) {
    finite(x[i], key + "[" + std::to_string(i) + "]");
    if (i > 0 && !(x[i] > x[i - 1])) {
      fail(key + "[" + std::to_string(i) + "]",
           "must be strictly increasing, got " + num(x[i]) + " after " + num(x[i - 1]));
    }
  }
}

}  // namespace

void validate(const CreepConfig& c) {
  positive(c.creep_length_mm, "creep.creep_length_mm");
  positive(c.creep_time_s, "creep.creep_time_s");
  positive(c.creep_rate_um_per_min, "creep.creep_rate_um_per_min");
  positive(c.creep_rate_um_per_mm, "creep.creep_rate_um_per_mm");
  if (c.profile == ProfileShape::kTable) {
    const auto& t = c.profile_table;
    if (t.size() < 2 || t.size() > kMaxProfileTable) {
      fail("creep.profile_table", "must have 2.." + std::to_string(kMaxProfileTable) +
                                      " values when creep.profile = \"table\", got " +
                                      std::to_string(t.size()));
    }
    if (std::fabs(t.front()) > 1e-12 || std::fabs(t.back() - 1.0) > 1e-12) {
      fail("creep.profile_table", "must start at 0 and end at 1");
    }
    for (std::size_t i = 0; i < t.size(); ++i) {
      finite(t[i], "creep.profile_table[" + std::to_string(i) + "]");
      if (i > 0 && t[i] < t[i - 1]) {
        fail("creep.profile_table[" + std::to_string(i) + "]", "must be non-decreasing");
      }
    }
  }
  if (c.max_creeps < 1 || c.max_creeps > kMaxCreeps) {
    fail("creep.max_creeps",
         "must be 1.." + std::to_string(kMaxCreeps) + ", got " + std::to_string(c.max_creeps));
  }

  const auto& e = c.edge;
  if (e.edge_points < 1 || e.edge_points > kMaxEdgePoints) {
    fail("creep.edge.edge_points",
         "must be 1.." + std::to_string(kMaxEdgePoints) + ", got " + std::to_string(e.edge_points));
  }
  if (e.tool_shape == ToolShape::kTip && e.edge_points != 1) {
    fail("creep.edge.edge_points", "must be 1 for tool_shape = \"tip\"");
  }
  const double axis_norm =
      std::sqrt(e.tool_axis[0] * e.tool_axis[0] + e.tool_axis[1] * e.tool_axis[1] +
                e.tool_axis[2] * e.tool_axis[2]);
  if (!std::isfinite(axis_norm) || std::fabs(axis_norm - 1.0) > 1e-6) {
    fail("creep.edge.tool_axis", "must be a unit vector, |axis| = " + num(axis_norm));
  }
  sign(e.fallback_sign, "creep.edge.fallback_sign");
  const auto& tp = c.toolpath;
  if (!tp.rows.empty()) {
    if (tp.rows.size() < 2) fail("creep.edge.toolpath_file", "needs at least 2 rows");
    for (std::size_t i = 0; i < tp.rows.size(); ++i) {
      const auto& r = tp.rows[i];
      const std::string key = "creep.edge.toolpath_file row " + std::to_string(i + 1);
      finite(r.path_mm, key + " path_mm");
      if (i > 0 && !(r.path_mm > tp.rows[i - 1].path_mm)) {
        fail(key, "path_mm must be strictly increasing");
      }
      if (tp.has_normals) {
        const double n = std::sqrt(r.normal[0] * r.normal[0] + r.normal[1] * r.normal[1] +
                                   r.normal[2] * r.normal[2]);
        if (!std::isfinite(n) || std::fabs(n - 1.0) > 1e-3) {
          fail(key, "normal must be a unit vector, |n| = " + num(n));
        }
      }
      if (tp.has_removal && !(std::isfinite(r.removal_mm2) && r.removal_mm2 >= 0.0)) {
        fail(key, "removal_mm2 must be a finite number >= 0, got " + num(r.removal_mm2));
      }
    }
  }
  if (e.normal_source == NormalSource::kToolpath && (tp.rows.size() < 2 || !tp.has_normals)) {
    fail("creep.edge.toolpath_file",
         "needs at least 2 rows with normals (nx, ny, nz) for normal_source = \"toolpath\"");
  }
  if (e.material_side != MaterialSide::kNone && e.material_side != MaterialSide::kLeft &&
      e.material_side != MaterialSide::kRight) {
    fail("creep.edge.material_side", "must be \"none\", \"left\" or \"right\"");
  }

  const auto& o = c.output;
  static constexpr std::array<const char*, kChannelCount> kChannelKeys{
      "creep.output.x_register", "creep.output.y_register", "creep.output.z_register",
      "creep.output.radius_register", "creep.output.length_register"};
  bool any_channel = false;
  for (std::size_t i = 0; i < kChannelCount; ++i) {
    register_index(o.channel_register[i], kChannelKeys[i]);
    any_channel = any_channel || o.channel_register[i] >= 0;
  }
  if (!any_channel) fail("creep.output", "maps no offset register (x/y/z/radius/length)");
  if (o.mode == OutputMode::kAxes && (o.channel_register[3] >= 0 || o.channel_register[4] >= 0)) {
    fail("creep.output.mode", "is \"axes\": radius_register / length_register must be -1");
  }
  if (o.mode == OutputMode::kToolRegisters &&
      (o.channel_register[0] >= 0 || o.channel_register[1] >= 0 || o.channel_register[2] >= 0)) {
    fail("creep.output.mode", "is \"tool_registers\": x/y/z_register must be -1");
  }
  const bool fallback_is_axis = e.fallback_channel == Channel::kX ||
                                e.fallback_channel == Channel::kY ||
                                e.fallback_channel == Channel::kZ;
  if (fallback_is_axis != (o.mode == OutputMode::kAxes)) {
    fail("creep.edge.fallback_channel",
         "must be an axis (x/y/z) in mode \"axes\" and "
         "radius/length in mode \"tool_registers\"");
  }
  sign(o.tool_register_sign, "creep.output.tool_register_sign");
  register_index(o.warning_register, "creep.output.warning_register");
  register_index(o.alarm_register, "creep.output.alarm_register");
  register_index(o.measurement_due_register, "creep.output.measurement_due_register");
  register_index(o.tool_change_register, "creep.output.tool_change_register");
  register_index(o.restart_path_register, "creep.output.restart_path_register");
  positive(o.write_resolution_um, "creep.output.write_resolution_um");
  non_negative(o.refresh_interval_s, "creep.output.refresh_interval_s");
  non_negative(o.request_rearm_s, "creep.output.request_rearm_s");

  positive(c.limiter.max_abs_um, "creep.limiter.max_abs_um");
  positive(c.limiter.max_step_um, "creep.limiter.max_step_um");
  positive(c.limiter.max_rate_um_per_s, "creep.limiter.max_rate_um_per_s");

  const auto& iv = c.interval;
  switch (iv.basis) {
    case IntervalBasis::kOff:
      break;
    case IntervalBasis::kPath:
      positive(iv.interval_mm, "creep.interval.interval_mm");
      break;
    case IntervalBasis::kTime:
      positive(iv.interval_s, "creep.interval.interval_s");
      break;
    case IntervalBasis::kAdaptive:
      positive(iv.target_increment_um, "creep.interval.target_increment_um");
      positive(iv.min_interval_mm, "creep.interval.min_interval_mm");
      positive(iv.max_interval_mm, "creep.interval.max_interval_mm");
      if (iv.max_interval_mm < iv.min_interval_mm) {
        fail("creep.interval.max_interval_mm", "must be >= min_interval_mm");
      }
      break;
    case IntervalBasis::kMaterial:
      positive(iv.removal_mm3_per_mm, "creep.interval.removal_mm3_per_mm");
      positive(iv.interval_mm3, "creep.interval.interval_mm3");
      if (iv.removal_source == RemovalSource::kToolpath &&
          (tp.rows.size() < 2 || !tp.has_removal)) {
        fail("creep.interval.removal_source",
             "is \"toolpath\": creep.edge.toolpath_file needs a removal_mm2 column");
      }
      break;
  }

  const auto& tl = c.tool_life;
  non_negative(tl.wear_limit_um, "creep.tool_life.wear_limit_um");
  non_negative(tl.excessive_increment_um, "creep.tool_life.excessive_increment_um");
  if (!std::isfinite(tl.implausible_factor) || tl.implausible_factor < 1.0) {
    fail("creep.tool_life.implausible_factor", "must be >= 1, got " + num(tl.implausible_factor));
  }
  positive(tl.min_expected_increment_um, "creep.tool_life.min_expected_increment_um");
  non_negative(tl.noise_um, "creep.tool_life.noise_um");

  if (c.predict.enabled) {
    if (c.predict.window < 2 || c.predict.window > kMaxRateWindow) {
      fail("creep.predict.window", "must be 2.." + std::to_string(kMaxRateWindow) + ", got " +
                                       std::to_string(c.predict.window));
    }
    positive(c.predict.max_um, "creep.predict.max_um");
  }

  non_negative(c.entry.sister_offset_um, "creep.entry.sister_offset_um");
  positive(c.entry.sister_length_mm, "creep.entry.sister_length_mm");
  non_negative(c.entry.sister_restart_back_mm, "creep.entry.sister_restart_back_mm");
  non_negative(c.entry.retract_um, "creep.entry.retract_um");
  positive(c.entry.refeed_length_mm, "creep.entry.refeed_length_mm");

  for (std::size_t k = 0; k < c.deflection.size(); ++k) {
    const auto& d = c.deflection[k];
    const std::string key = "creep.deflection[" + std::to_string(k) + "]";
    if (d.tool < 0) fail(key + ".tool", "must be >= 0 (0 = every tool)");
    for (std::size_t j = 0; j < k; ++j) {
      if (c.deflection[j].tool == d.tool)
        fail(key + ".tool", "repeats tool " + std::to_string(d.tool));
    }
    if (d.wear_um.empty() || d.wear_um.size() > kMaxDeflectionRows) {
      fail(key + ".wear_um", "must have 1.." + std::to_string(kMaxDeflectionRows) + " values");
    }
    if (d.normal_um.size() != d.wear_um.size())
      fail(key + ".normal_um", "must match wear_um in length");
    if (d.lateral_um.size() != d.wear_um.size()) {
      fail(key + ".lateral_um", "must match wear_um in length");
    }
    increasing_table(d.wear_um, key + ".wear_um");
    for (std::size_t i = 0; i < d.wear_um.size(); ++i) {
      finite(d.normal_um[i], key + ".normal_um[" + std::to_string(i) + "]");
      finite(d.lateral_um[i], key + ".lateral_um[" + std::to_string(i) + "]");
    }
  }

  if (c.transitions.size() > kMaxTransitions) {
    fail("creep.transition", "has more than " + std::to_string(kMaxTransitions) + " entries");
  }
  for (std::size_t k = 0; k < c.transitions.size(); ++k) {
    const auto& t = c.transitions[k];
    const std::string key = "creep.transition[" + std::to_string(k) + "]";
    if (t.tool <= 0) fail(key + ".tool", "must be a tool number > 0");
    finite(t.start_path_mm, key + ".start_path_mm");
    finite(t.end_path_mm, key + ".end_path_mm");
    if (!(t.end_path_mm > t.start_path_mm)) fail(key + ".end_path_mm", "must be > start_path_mm");
    non_negative(t.in_offset_um, key + ".in_offset_um");
    non_negative(t.out_offset_um, key + ".out_offset_um");
    non_negative(t.in_length_mm, key + ".in_length_mm");
    non_negative(t.out_length_mm, key + ".out_length_mm");
    if (t.in_length_mm + t.out_length_mm > t.end_path_mm - t.start_path_mm) {
      fail(key, "in_length_mm + out_length_mm exceed the transition's path range");
    }
    if (t.in_offset_um > 0.0 && !(t.in_length_mm > 0.0)) {
      fail(key + ".in_length_mm", "must be > 0 when in_offset_um > 0");
    }
    if (t.out_offset_um > 0.0 && !(t.out_length_mm > 0.0)) {
      fail(key + ".out_length_mm", "must be > 0 when out_offset_um > 0");
    }
  }
}

}  // namespace nccomp::core::creep
