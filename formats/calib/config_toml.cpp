#include "formats/calib/config_toml.hpp"

#include <algorithm>
#include <cstdint>
#include <vector>

#include "core/common/config_issue.hpp"
#include "formats/toml/guard.hpp"
#include "formats/toml/key_positions.hpp"
#include "formats/toml/table_reader.hpp"

namespace nccomp::formats::calib {

namespace {

using core::calib::CalibrationConfig;

void validate(const CalibrationConfig& c, const toml::node* node, Diagnostics& diag) {
  try {
    core::calib::validate(c);
  } catch (const core::ConfigInvalid& e) {
    KeyPositions positions;
    if (node != nullptr) record_positions(*node, "calibration", positions);
    report(positions, where_of(node, "calibration"), e, diag);
  }
}

CalibrationConfig load(const toml::table& root, const std::string& source) {
  Diagnostics diag;
  CalibrationConfig c = parse_calibration_table(root, diag);
  if (!diag.ok()) throw DiagnosticsError(std::move(diag), source);
  return c;
}

}  // namespace

CalibrationConfig parse_calibration(const toml::node& calibration, Diagnostics& diag) {
  CalibrationConfig c;
  const toml::table* t = calibration.as_table();
  if (t == nullptr) {
    diag.error(&calibration, "calibration", "must be a table ([calibration])");
    return c;
  }
  const std::size_t errors_before = diag.items().size();
  {
    TableReader r(*t, "calibration", diag);
    const auto reg = [&r](const char* key, std::uint16_t def) {
      return static_cast<std::uint16_t>(r.integer(key, def, 0, 65535));
    };
    const auto i32 = [&r](const char* key, std::int32_t def, std::int32_t lo, std::int32_t hi) {
      return static_cast<std::int32_t>(r.integer(key, def, lo, hi));
    };
    c.register_x = reg("register_x", c.register_x);
    c.register_y = reg("register_y", c.register_y);
    c.register_z = reg("register_z", c.register_z);
    c.reference_x_lateral_mm = r.number("reference_x_lateral_mm", c.reference_x_lateral_mm);
    c.reference_x_axial_mm = r.number("reference_x_axial_mm", c.reference_x_axial_mm);
    c.reference_y_mm = r.number("reference_y_mm", c.reference_y_mm);
    c.reference_z_mm = r.number("reference_z_mm", c.reference_z_mm);
    c.reference_contact_mm = r.number("reference_contact_mm", c.reference_contact_mm);
    c.reference_axial_contact_mm =
        r.number("reference_axial_contact_mm", c.reference_axial_contact_mm);
    c.touches_per_axis = i32("touches_per_axis", c.touches_per_axis, 1, 8);
    c.touch_positions =
        r.pick<core::calib::TouchPositions>("touch_positions", c.touch_positions,
                                            {{"machine", core::calib::TouchPositions::kMachine},
                                             {"program", core::calib::TouchPositions::kProgram}});
    c.request_register = i32("request_register", c.request_register, -1, 65535);
    if (r.node().get("state_file") != nullptr) {
      c.state_file = r.string("state_file", std::string());
      if (c.state_file.empty() && r.node().get("state_file")->is_string()) {
        r.error("state_file", "must not be empty (leave the key out for none)");
      }
    }
    c.max_scatter_um = r.number("max_scatter_um", c.max_scatter_um);
    c.touch_set_timeout_s = r.number("touch_set_timeout_s", c.touch_set_timeout_s);
    c.facet_rule =
        r.pick<core::calib::FacetRule>("facet_rule", c.facet_rule,
                                       {{"exact", core::calib::FacetRule::kExact},
                                        {"proportional", core::calib::FacetRule::kProportional}});
    c.blank_radius_mm = r.number("blank_radius_mm", c.blank_radius_mm);
    c.facet_gain_um_per_um = r.number("facet_gain_um_per_um", c.facet_gain_um_per_um);
    c.facet_tolerance_um = r.number("facet_tolerance_um", c.facet_tolerance_um);
    c.max_test_grinds = i32("max_test_grinds", c.max_test_grinds, 1, 50);
    c.end_face_test_grind = r.boolean("end_face_test_grind", c.end_face_test_grind);
    c.plausibility_um = r.number("plausibility_um", c.plausibility_um);
    c.recalibration_interval_s = r.number("recalibration_interval_s", c.recalibration_interval_s);
    c.creep_shape = r.pick<core::ProfileShape>("creep_shape", c.creep_shape,
                                               {{"linear", core::ProfileShape::kLinear},
                                                {"cosine", core::ProfileShape::kCosine},
                                                {"smoothstep", core::ProfileShape::kSmoothstep},
                                                {"step", core::ProfileShape::kStep}});
    c.creep_duration_s = r.number("creep_duration_s", c.creep_duration_s);
    c.prediction =
        r.pick<core::calib::Prediction>("prediction", c.prediction,
                                        {{"none", core::calib::Prediction::kNone},
                                         {"time", core::calib::Prediction::kTime},
                                         {"temperature", core::calib::Prediction::kTemperature},
                                         {"estimator", core::calib::Prediction::kEstimator}});
    c.thermal_time_constant_s = r.number("thermal_time_constant_s", c.thermal_time_constant_s);
    c.temperature_sensor = i32("temperature_sensor", c.temperature_sensor, -1, 255);
    c.temperature_forgetting = r.number("temperature_forgetting", c.temperature_forgetting);
    c.max_temperature_slope_um_per_c =
        r.number("max_temperature_slope_um_per_c", c.max_temperature_slope_um_per_c);
    c.estimator_touch_noise_um = r.number("estimator_touch_noise_um", c.estimator_touch_noise_um);
    c.estimator_level_noise_um_per_h =
        r.number("estimator_level_noise_um_per_h", c.estimator_level_noise_um_per_h);
    c.estimator_learn_level_noise =
        r.boolean("estimator_learn_level_noise", c.estimator_learn_level_noise);
    c.estimator_min_level_noise_um_per_h =
        r.number("estimator_min_level_noise_um_per_h", c.estimator_min_level_noise_um_per_h);
    c.estimator_max_level_noise_um_per_h =
        r.number("estimator_max_level_noise_um_per_h", c.estimator_max_level_noise_um_per_h);
    c.estimator_shift_prior = r.boolean("estimator_shift_prior", c.estimator_shift_prior);
    c.estimator_prior_gain_sigma =
        r.number("estimator_prior_gain_sigma", c.estimator_prior_gain_sigma);
    c.estimator_prior_forgetting =
        r.number("estimator_prior_forgetting", c.estimator_prior_forgetting);
    c.estimator_slope_sigma_um_per_c =
        r.number("estimator_slope_sigma_um_per_c", c.estimator_slope_sigma_um_per_c);
    // Per slot X lateral, X axial, Y, Z: all four or none.
    const auto slots = [&](const char* key, double min, auto& out) {
      const std::vector<double> v = r.number_list(key, min, 1e6);
      if (v.size() == out.size()) {
        std::copy(v.begin(), v.end(), out.begin());
      } else if (r.node().get(key) != nullptr) {
        r.error(key, "must have 4 values (X lateral, X axial, Y, Z)");
      }
    };
    slots("estimator_model_slope_um_per_c", -1e6, c.estimator_model_slope_um_per_c);
    slots("estimator_model_slope_sigma_um_per_c", 0.0, c.estimator_model_slope_sigma_um_per_c);
    {
      const std::vector<std::int64_t> v = r.integer_list("estimator_input_sensors", -1, 255);
      if (v.size() == c.estimator_input_sensors.size()) {
        for (std::size_t i = 0; i < v.size(); ++i) {
          c.estimator_input_sensors[i] = static_cast<std::int32_t>(v[i]);
        }
      } else if (r.node().get("estimator_input_sensors") != nullptr) {
        r.error("estimator_input_sensors", "must have 4 values (X lateral, X axial, Y, Z)");
      }
    }
    c.estimator_gate_sigmas = r.number("estimator_gate_sigmas", c.estimator_gate_sigmas);
    c.write_period_s = r.number("write_period_s", c.write_period_s);
    c.write_deadband_um = r.number("write_deadband_um", c.write_deadband_um);
    c.max_abs_um = r.number("max_abs_um", c.max_abs_um);
    c.max_step_um = r.number("max_step_um", c.max_step_um);
    c.max_rate_um_per_s = r.number("max_rate_um_per_s", c.max_rate_um_per_s);
  }
  // The core's rules would only repeat what is already reported.
  if (diag.items().size() == errors_before) validate(c, &calibration, diag);
  return c;
}

CalibrationConfig parse_calibration_table(const toml::table& root, Diagnostics& diag) {
  const toml::node* node = root.get("calibration");
  if (node != nullptr) return parse_calibration(*node, diag);
  CalibrationConfig c;
  validate(c, nullptr, diag);
  return c;
}

CalibrationConfig load_calibration_config_text(std::string_view text, const std::string& source) {
  toml::table root;
  try {
    root = parse_toml(text, source);
  } catch (const toml::parse_error& e) {
    throw DiagnosticsError(e, source);
  }
  return load(root, source);
}

CalibrationConfig load_calibration_config_file(const std::string& path) {
  toml::table root;
  try {
    root = parse_toml_file(path);
  } catch (const toml::parse_error& e) {
    throw DiagnosticsError(e, path);
  }
  return load(root, path);
}

}  // namespace nccomp::formats::calib
