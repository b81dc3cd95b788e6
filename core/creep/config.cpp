#include "core/creep/config.hpp"

#include <cmath>
#include <string>
#include <utility>

#include "core/common/config_issue.hpp"

namespace nccomp::core::creep {

namespace {

std::string num(double v) { return std::to_string(v); }

// Each check adds an issue and returns false when the value is refused.
class Checker {
 public:
  void fail(std::string key, std::string reason) { issues_.add(std::move(key), std::move(reason)); }

  bool positive(double v, const std::string& key) {
    if (!std::isfinite(v) || v <= 0.0) {
      fail(key, "must be a positive finite number, got " + num(v));
      return false;
    }
    return true;
  }

  bool non_negative(double v, const std::string& key) {
    if (!std::isfinite(v) || v < 0.0) {
      fail(key, "must be a finite number >= 0, got " + num(v));
      return false;
    }
    return true;
  }

  bool finite(double v, const std::string& key) {
    if (!std::isfinite(v)) {
      fail(key, "must be finite, got " + num(v));
      return false;
    }
    return true;
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
      if (!finite(x[i], key + "[" + std::to_string(i) + "]")) continue;
      if (i > 0 && !(x[i] > x[i - 1])) {
        fail(key + "[" + std::to_string(i) + "]",
             "must be strictly increasing, got " + num(x[i]) + " after " + num(x[i - 1]));
      }
    }
  }

  void throw_if_any() { issues_.throw_if_any(); }

 private:
  ConfigIssues issues_;
};

}  // namespace

void validate(const CreepConfig& c) {
  Checker k;
  k.positive(c.creep_length_mm, "creep.creep_length_mm");
  k.positive(c.creep_time_s, "creep.creep_time_s");
  k.positive(c.creep_rate_um_per_min, "creep.creep_rate_um_per_min");
  k.positive(c.creep_rate_um_per_mm, "creep.creep_rate_um_per_mm");
  if (c.profile == ProfileShape::kTable) {
    const auto& t = c.profile_table;
    if (t.size() < 2 || t.size() > kMaxProfileTable) {
      k.fail("creep.profile_table", "must have 2.." + std::to_string(kMaxProfileTable) +
                                        " values when creep.profile = \"table\", got " +
                                        std::to_string(t.size()));
    } else if (std::fabs(t.front()) > 1e-12 || std::fabs(t.back() - 1.0) > 1e-12) {
      k.fail("creep.profile_table", "must start at 0 and end at 1");
    } else {
      for (std::size_t i = 0; i < t.size(); ++i) {
        if (!k.finite(t[i], "creep.profile_table[" + std::to_string(i) + "]")) continue;
        if (i > 0 && t[i] < t[i - 1]) {
          k.fail("creep.profile_table[" + std::to_string(i) + "]", "must be non-decreasing");
        }
      }
    }
  }
  if (c.max_creeps < 1 || c.max_creeps > kMaxCreeps) {
    k.fail("creep.max_creeps",
           "must be 1.." + std::to_string(kMaxCreeps) + ", got " + std::to_string(c.max_creeps));
  }

  const auto& e = c.edge;
  if (e.edge_points < 1 || e.edge_points > kMaxEdgePoints) {
    k.fail("creep.edge.edge_points", "must be 1.." + std::to_string(kMaxEdgePoints) + ", got " +
                                         std::to_string(e.edge_points));
  } else if (e.tool_shape == ToolShape::kTip && e.edge_points != 1) {
    k.fail("creep.edge.edge_points", "must be 1 for tool_shape = \"tip\"");
  }
  const double axis_norm =
      std::sqrt(e.tool_axis[0] * e.tool_axis[0] + e.tool_axis[1] * e.tool_axis[1] +
                e.tool_axis[2] * e.tool_axis[2]);
  if (!std::isfinite(axis_norm) || std::fabs(axis_norm - 1.0) > 1e-6) {
    k.fail("creep.edge.tool_axis", "must be a unit vector, |axis| = " + num(axis_norm));
  }
  k.sign(e.fallback_sign, "creep.edge.fallback_sign");
  const auto& tp = c.toolpath;
  if (!tp.rows.empty()) {
    if (tp.rows.size() < 2) k.fail("creep.edge.toolpath_file", "needs at least 2 rows");
    for (std::size_t i = 0; i < tp.rows.size(); ++i) {
      const auto& r = tp.rows[i];
      const std::string row = "row " + std::to_string(i + 1) + ": ";
      if (!std::isfinite(r.path_mm)) {
        k.fail("creep.edge.toolpath_file", row + "path_mm must be finite, got " + num(r.path_mm));
      } else if (i > 0 && !(r.path_mm > tp.rows[i - 1].path_mm)) {
        k.fail("creep.edge.toolpath_file", row + "path_mm must be strictly increasing");
      }
      if (tp.has_normals) {
        const double n = std::sqrt(r.normal[0] * r.normal[0] + r.normal[1] * r.normal[1] +
                                   r.normal[2] * r.normal[2]);
        if (!std::isfinite(n) || std::fabs(n - 1.0) > 1e-3) {
          k.fail("creep.edge.toolpath_file", row + "normal must be a unit vector, |n| = " + num(n));
        }
      }
      if (tp.has_removal && !(std::isfinite(r.removal_mm2) && r.removal_mm2 >= 0.0)) {
        k.fail("creep.edge.toolpath_file",
               row + "removal_mm2 must be a finite number >= 0, got " + num(r.removal_mm2));
      }
    }
  }
  if (e.normal_source == NormalSource::kToolpath && (tp.rows.size() < 2 || !tp.has_normals)) {
    k.fail("creep.edge.toolpath_file",
           "needs at least 2 rows with normals (nx, ny, nz) for normal_source = \"toolpath\"");
  }
  if (e.material_side != MaterialSide::kNone && e.material_side != MaterialSide::kLeft &&
      e.material_side != MaterialSide::kRight) {
    k.fail("creep.edge.material_side", "must be \"none\", \"left\" or \"right\"");
  }

  const auto& o = c.output;
  static constexpr std::array<const char*, kChannelCount> kChannelKeys{
      "creep.output.x_register", "creep.output.y_register", "creep.output.z_register",
      "creep.output.radius_register", "creep.output.length_register"};
  bool any_channel = false;
  for (std::size_t i = 0; i < kChannelCount; ++i) {
    k.register_index(o.channel_register[i], kChannelKeys[i]);
    any_channel = any_channel || o.channel_register[i] >= 0;
  }
  if (!any_channel) k.fail("creep.output", "maps no offset register (x/y/z/radius/length)");
  if (o.mode == OutputMode::kAxes && (o.channel_register[3] >= 0 || o.channel_register[4] >= 0)) {
    k.fail("creep.output.mode", "\"axes\": radius_register / length_register must be -1");
  }
  if (o.mode == OutputMode::kToolRegisters &&
      (o.channel_register[0] >= 0 || o.channel_register[1] >= 0 || o.channel_register[2] >= 0)) {
    k.fail("creep.output.mode", "\"tool_registers\": x/y/z_register must be -1");
  }
  const bool fallback_is_axis = e.fallback_channel == Channel::kX ||
                                e.fallback_channel == Channel::kY ||
                                e.fallback_channel == Channel::kZ;
  if (fallback_is_axis != (o.mode == OutputMode::kAxes)) {
    k.fail("creep.edge.fallback_channel",
           "must be an axis (x/y/z) in mode \"axes\" and "
           "radius/length in mode \"tool_registers\"");
  }
  k.sign(o.tool_register_sign, "creep.output.tool_register_sign");
  k.register_index(o.warning_register, "creep.output.warning_register");
  k.register_index(o.alarm_register, "creep.output.alarm_register");
  k.register_index(o.measurement_due_register, "creep.output.measurement_due_register");
  k.register_index(o.tool_change_register, "creep.output.tool_change_register");
  k.register_index(o.restart_path_register, "creep.output.restart_path_register");
  k.positive(o.write_resolution_um, "creep.output.write_resolution_um");
  k.non_negative(o.refresh_interval_s, "creep.output.refresh_interval_s");
  k.non_negative(o.request_rearm_s, "creep.output.request_rearm_s");

  k.positive(c.limiter.max_abs_um, "creep.limiter.max_abs_um");
  k.positive(c.limiter.max_step_um, "creep.limiter.max_step_um");
  k.positive(c.limiter.max_rate_um_per_s, "creep.limiter.max_rate_um_per_s");

  const auto& iv = c.interval;
  switch (iv.basis) {
    case IntervalBasis::kOff:
      break;
    case IntervalBasis::kPath:
      k.positive(iv.interval_mm, "creep.interval.interval_mm");
      break;
    case IntervalBasis::kTime:
      k.positive(iv.interval_s, "creep.interval.interval_s");
      break;
    case IntervalBasis::kUncertainty:
      if (!c.estimator.enabled) {
        k.fail("creep.interval.basis", "\"uncertainty\" needs [creep.estimator] enabled = true");
      }
      k.positive(iv.max_sigma_um, "creep.interval.max_sigma_um");
      [[fallthrough]];
    case IntervalBasis::kAdaptive:
      if (iv.basis == IntervalBasis::kAdaptive) {
        k.positive(iv.target_increment_um, "creep.interval.target_increment_um");
      }
      k.positive(iv.min_interval_mm, "creep.interval.min_interval_mm");
      k.positive(iv.max_interval_mm, "creep.interval.max_interval_mm");
      if (iv.max_interval_mm < iv.min_interval_mm) {
        k.fail("creep.interval.max_interval_mm", "must be >= min_interval_mm");
      }
      break;
    case IntervalBasis::kMaterial:
      k.positive(iv.removal_mm3_per_mm, "creep.interval.removal_mm3_per_mm");
      k.positive(iv.interval_mm3, "creep.interval.interval_mm3");
      if (iv.removal_source == RemovalSource::kToolpath &&
          (tp.rows.size() < 2 || !tp.has_removal)) {
        k.fail("creep.interval.removal_source",
               "\"toolpath\": creep.edge.toolpath_file needs a removal_mm2 column");
      }
      break;
  }

  const auto& tl = c.tool_life;
  k.non_negative(tl.wear_limit_um, "creep.tool_life.wear_limit_um");
  k.non_negative(tl.excessive_increment_um, "creep.tool_life.excessive_increment_um");
  if (!std::isfinite(tl.implausible_factor) || tl.implausible_factor < 1.0) {
    k.fail("creep.tool_life.implausible_factor", "must be >= 1, got " + num(tl.implausible_factor));
  }
  k.positive(tl.min_expected_increment_um, "creep.tool_life.min_expected_increment_um");
  k.non_negative(tl.noise_um, "creep.tool_life.noise_um");

  if (c.predict.enabled) {
    if (c.predict.window < 2 || c.predict.window > kMaxRateWindow) {
      k.fail("creep.predict.window", "must be 2.." + std::to_string(kMaxRateWindow) + ", got " +
                                         std::to_string(c.predict.window));
    }
    k.positive(c.predict.max_um, "creep.predict.max_um");
  }

  if (c.estimator.enabled) {
    const auto& est = c.estimator;
    k.positive(est.measurement_sigma_um, "creep.estimator.measurement_sigma_um");
    k.non_negative(est.wear_noise_um_per_sqrt_m, "creep.estimator.wear_noise_um_per_sqrt_m");
    k.non_negative(est.rate_noise_um_per_mm_per_sqrt_m,
                   "creep.estimator.rate_noise_um_per_mm_per_sqrt_m");
    k.positive(est.initial_rate_sigma_um_per_mm, "creep.estimator.initial_rate_sigma_um_per_mm");
    if (!std::isfinite(est.gate_sigmas) || est.gate_sigmas < 0.0 ||
        (est.gate_sigmas > 0.0 && est.gate_sigmas < 2.0)) {
      k.fail("creep.estimator.gate_sigmas",
             "must be 0 (no gate) or a finite number >= 2, got " + num(est.gate_sigmas));
    }
    k.positive(est.family_prior_path_mm, "creep.estimator.family_prior_path_mm");
    if (est.family_min_tools < 1 || est.family_min_tools > kMaxFamilyMinTools) {
      k.fail("creep.estimator.family_min_tools", "must be 1.." +
                                                     std::to_string(kMaxFamilyMinTools) + ", got " +
                                                     std::to_string(est.family_min_tools));
    }
    if (est.adapt_rate_noise) {
      if (!(est.adapt_window_measurements >= 1.0 && est.adapt_window_measurements <= 1000.0)) {
        k.fail("creep.estimator.adapt_window_measurements",
               "must be 1..1000, got " + num(est.adapt_window_measurements));
      }
      k.positive(est.min_rate_noise_um_per_mm_per_sqrt_m,
                 "creep.estimator.min_rate_noise_um_per_mm_per_sqrt_m");
      if (!(est.max_rate_noise_um_per_mm_per_sqrt_m >= est.min_rate_noise_um_per_mm_per_sqrt_m) ||
          !std::isfinite(est.max_rate_noise_um_per_mm_per_sqrt_m)) {
        k.fail("creep.estimator.max_rate_noise_um_per_mm_per_sqrt_m",
               "must be finite and at least min_rate_noise_um_per_mm_per_sqrt_m (" +
                   num(est.min_rate_noise_um_per_mm_per_sqrt_m) + "), got " +
                   num(est.max_rate_noise_um_per_mm_per_sqrt_m));
      }
    }
  }

  k.non_negative(c.entry.sister_offset_um, "creep.entry.sister_offset_um");
  k.positive(c.entry.sister_length_mm, "creep.entry.sister_length_mm");
  k.non_negative(c.entry.sister_restart_back_mm, "creep.entry.sister_restart_back_mm");
  k.non_negative(c.entry.retract_um, "creep.entry.retract_um");
  k.positive(c.entry.refeed_length_mm, "creep.entry.refeed_length_mm");

  for (std::size_t t = 0; t < c.deflection.size(); ++t) {
    const auto& d = c.deflection[t];
    const std::string key = "creep.deflection[" + std::to_string(t) + "]";
    if (d.tool < 0) k.fail(key + ".tool", "must be >= 0 (0 = every tool)");
    for (std::size_t j = 0; j < t; ++j) {
      if (c.deflection[j].tool == d.tool) {
        k.fail(key + ".tool", "repeats tool " + std::to_string(d.tool));
        break;
      }
    }
    if (d.wear_um.empty() || d.wear_um.size() > kMaxDeflectionRows) {
      k.fail(key + ".wear_um", "must have 1.." + std::to_string(kMaxDeflectionRows) + " values");
      continue;
    }
    bool lengths_match = true;
    if (d.normal_um.size() != d.wear_um.size()) {
      k.fail(key + ".normal_um", "must match wear_um in length");
      lengths_match = false;
    }
    if (d.lateral_um.size() != d.wear_um.size()) {
      k.fail(key + ".lateral_um", "must match wear_um in length");
      lengths_match = false;
    }
    if (!lengths_match) continue;
    k.increasing_table(d.wear_um, key + ".wear_um");
    for (std::size_t i = 0; i < d.wear_um.size(); ++i) {
      k.finite(d.normal_um[i], key + ".normal_um[" + std::to_string(i) + "]");
      k.finite(d.lateral_um[i], key + ".lateral_um[" + std::to_string(i) + "]");
    }
  }

  if (c.transitions.size() > kMaxTransitions) {
    k.fail("creep.transition", "has more than " + std::to_string(kMaxTransitions) + " entries");
  }
  for (std::size_t t = 0; t < c.transitions.size(); ++t) {
    const auto& tr = c.transitions[t];
    const std::string key = "creep.transition[" + std::to_string(t) + "]";
    if (tr.tool <= 0) k.fail(key + ".tool", "must be a tool number > 0");
    k.finite(tr.start_path_mm, key + ".start_path_mm");
    k.finite(tr.end_path_mm, key + ".end_path_mm");
    if (!(tr.end_path_mm > tr.start_path_mm)) {
      k.fail(key + ".end_path_mm", "must be > start_path_mm");
    }
    k.non_negative(tr.in_offset_um, key + ".in_offset_um");
    k.non_negative(tr.out_offset_um, key + ".out_offset_um");
    k.non_negative(tr.in_length_mm, key + ".in_length_mm");
    k.non_negative(tr.out_length_mm, key + ".out_length_mm");
    if (tr.in_length_mm + tr.out_length_mm > tr.end_path_mm - tr.start_path_mm) {
      k.fail(key, "in_length_mm + out_length_mm exceed the transition's path range");
    }
    if (tr.in_offset_um > 0.0 && !(tr.in_length_mm > 0.0)) {
      k.fail(key + ".in_length_mm", "must be > 0 when in_offset_um > 0");
    }
    if (tr.out_offset_um > 0.0 && !(tr.out_length_mm > 0.0)) {
      k.fail(key + ".out_length_mm", "must be > 0 when out_offset_um > 0");
    }
  }
  k.throw_if_any();
}

}  // namespace nccomp::core::creep
