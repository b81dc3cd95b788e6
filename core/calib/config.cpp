#include "core/calib/config.hpp"

#include <cmath>
#include <sstream>
#include <string>

#include "core/common/config_issue.hpp"

namespace nccomp::core::calib {

namespace {

// Each check adds an issue "calibration.<key>": why, got value.
class Checker {
 public:
  void fail(const char* key, const std::string& why, double value) {
    std::ostringstream s;
    s << why << ", got " << value;
    issues_.add(std::string("calibration.") + key, s.str());
  }
  void finite(double v, const char* key) {
    if (!std::isfinite(v)) fail(key, "must be a finite number", v);
  }
  void positive(double v, const char* key) {
    if (!std::isfinite(v) || v <= 0.0) fail(key, "must be a positive finite number", v);
  }
  void non_negative(double v, const char* key) {
    if (!std::isfinite(v) || v < 0.0) fail(key, "must be a finite number >= 0", v);
  }
  void throw_if_any() { issues_.throw_if_any(); }

 private:
  ConfigIssues issues_;
};

}  // namespace

std::int32_t estimator_input_sensor(const CalibrationConfig& config, std::size_t slot) noexcept {
  const std::int32_t own = slot < config.estimator_input_sensors.size()
                               ? config.estimator_input_sensors[slot]
                               : -1;
  return own >= 0 ? own : config.temperature_sensor;
}

void validate(const CalibrationConfig& c) {
  Checker k;
  if (c.register_x == c.register_y || c.register_x == c.register_z ||
      c.register_y == c.register_z) {
    k.fail("register_x", "register_x, register_y and register_z must differ", c.register_x);
  }
  k.finite(c.reference_x_lateral_mm, "reference_x_lateral_mm");
  k.finite(c.reference_x_axial_mm, "reference_x_axial_mm");
  k.finite(c.reference_y_mm, "reference_y_mm");
  k.finite(c.reference_z_mm, "reference_z_mm");
  k.non_negative(c.reference_contact_mm, "reference_contact_mm");
  k.non_negative(c.reference_axial_contact_mm, "reference_axial_contact_mm");
  if (c.touches_per_axis < 1 || c.touches_per_axis > 8) {
    k.fail("touches_per_axis", "must be 1..8", c.touches_per_axis);
  }
  k.positive(c.max_scatter_um, "max_scatter_um");
  k.positive(c.touch_set_timeout_s, "touch_set_timeout_s");
  k.positive(c.blank_radius_mm, "blank_radius_mm");
  k.positive(c.facet_gain_um_per_um, "facet_gain_um_per_um");
  k.positive(c.facet_tolerance_um, "facet_tolerance_um");
  if (c.max_test_grinds < 1 || c.max_test_grinds > 50) {
    k.fail("max_test_grinds", "must be 1..50", c.max_test_grinds);
  }
  k.positive(c.plausibility_um, "plausibility_um");
  k.non_negative(c.recalibration_interval_s, "recalibration_interval_s");
  if (c.creep_shape == ProfileShape::kTable) {
    k.fail("creep_shape", "must be linear, cosine, smoothstep or step",
           static_cast<double>(c.creep_shape));
  }
  if (c.creep_shape != ProfileShape::kStep) {
    k.positive(c.creep_duration_s, "creep_duration_s");
  } else {
    k.non_negative(c.creep_duration_s, "creep_duration_s");
  }
  k.positive(c.thermal_time_constant_s, "thermal_time_constant_s");
  if (c.temperature_sensor < -1 || c.temperature_sensor > 255) {
    k.fail("temperature_sensor", "must be -1 (none) or a sensor index 0..255",
           c.temperature_sensor);
  } else if (c.prediction == Prediction::kTemperature && c.temperature_sensor < 0) {
    k.fail("temperature_sensor", "prediction = \"temperature\" needs a mapped sensor",
           c.temperature_sensor);
  }
  if (!std::isfinite(c.temperature_forgetting) || c.temperature_forgetting <= 0.0 ||
      c.temperature_forgetting > 1.0) {
    k.fail("temperature_forgetting", "must be in (0, 1]", c.temperature_forgetting);
  }
  k.positive(c.max_temperature_slope_um_per_c, "max_temperature_slope_um_per_c");
  k.positive(c.estimator_touch_noise_um, "estimator_touch_noise_um");
  k.non_negative(c.estimator_level_noise_um_per_h, "estimator_level_noise_um_per_h");
  k.positive(c.estimator_min_level_noise_um_per_h, "estimator_min_level_noise_um_per_h");
  if (!(c.estimator_max_level_noise_um_per_h >= c.estimator_min_level_noise_um_per_h) ||
      !std::isfinite(c.estimator_max_level_noise_um_per_h)) {
    k.fail("estimator_max_level_noise_um_per_h", "must be finite and >= the minimum",
           c.estimator_max_level_noise_um_per_h);
  }
  k.non_negative(c.estimator_prior_gain_sigma, "estimator_prior_gain_sigma");
  if (!std::isfinite(c.estimator_prior_forgetting) || c.estimator_prior_forgetting <= 0.0 ||
      c.estimator_prior_forgetting > 1.0) {
    k.fail("estimator_prior_forgetting", "must be in (0, 1]", c.estimator_prior_forgetting);
  }
  k.non_negative(c.estimator_slope_sigma_um_per_c, "estimator_slope_sigma_um_per_c");
  bool inputs_valid = true;
  for (const std::int32_t s : c.estimator_input_sensors) {
    if (s < -1 || s > 255) {
      k.fail("estimator_input_sensors", "must be -1 (temperature_sensor) or a sensor index 0..255",
             s);
      inputs_valid = false;
    }
  }
  bool every_slot_has_input = true;
  for (std::size_t i = 0; i < c.estimator_input_sensors.size(); ++i) {
    every_slot_has_input = every_slot_has_input && estimator_input_sensor(c, i) >= 0;
  }
  if (inputs_valid && c.prediction == Prediction::kEstimator &&
      c.estimator_slope_sigma_um_per_c > 0.0 && !every_slot_has_input) {
    k.fail("temperature_sensor",
           "estimator_slope_sigma_um_per_c > 0 needs a mapped sensor (or estimator_input_sensors "
           "for every slot)",
           c.temperature_sensor);
  }
  bool model_slope_without_input = false;
  for (std::size_t i = 0; i < c.estimator_model_slope_um_per_c.size(); ++i) {
    const double m = c.estimator_model_slope_um_per_c[i];
    const double sd = c.estimator_model_slope_sigma_um_per_c[i];
    if (std::isnan(m) != std::isnan(sd)) {
      k.fail("estimator_model_slope_sigma_um_per_c",
             "set for exactly the slots that have estimator_model_slope_um_per_c", sd);
    } else if (!std::isnan(m)) {
      model_slope_without_input = model_slope_without_input || estimator_input_sensor(c, i) < 0;
      if (!std::isfinite(m) || std::fabs(m) > c.max_temperature_slope_um_per_c) {
        k.fail("estimator_model_slope_um_per_c", "must be within ± max_temperature_slope_um_per_c",
               m);
      }
      k.non_negative(sd, "estimator_model_slope_sigma_um_per_c");
    }
  }
  if (inputs_valid && c.prediction == Prediction::kEstimator && model_slope_without_input) {
    k.fail("temperature_sensor",
           "estimator_model_slope_um_per_c needs a mapped sensor (or the slot's "
           "estimator_input_sensors)",
           c.temperature_sensor);
  }
  k.non_negative(c.estimator_gate_sigmas, "estimator_gate_sigmas");
  k.positive(c.write_period_s, "write_period_s");
  k.non_negative(c.write_deadband_um, "write_deadband_um");
  k.positive(c.max_abs_um, "max_abs_um");
  k.positive(c.max_step_um, "max_step_um");
  k.positive(c.max_rate_um_per_s, "max_rate_um_per_s");
  if (c.touch_positions != TouchPositions::kMachine &&
      c.touch_positions != TouchPositions::kProgram) {
    k.fail("touch_positions", "must be machine or program", static_cast<double>(c.touch_positions));
  }
  if (c.request_register < -1 || c.request_register > 65535) {
    k.fail("request_register", "must be -1 (none) or a register index 0..65535",
           c.request_register);
  } else if (c.request_register == c.register_x || c.request_register == c.register_y ||
             c.request_register == c.register_z) {
    k.fail("request_register", "must differ from register_x, register_y and register_z",
           c.request_register);
  }
  if (c.plausibility_um > c.max_abs_um) {
    k.fail("plausibility_um", "must not exceed max_abs_um", c.plausibility_um);
  }
  k.throw_if_any();
}

const char* to_string(FacetRule rule) noexcept {
  switch (rule) {
    case FacetRule::kExact:
      return "exact";
    case FacetRule::kProportional:
      return "proportional";
  }
  return "?";
}

const char* to_string(Prediction prediction) noexcept {
  switch (prediction) {
    case Prediction::kNone:
      return "none";
    case Prediction::kTime:
      return "time";
    case Prediction::kTemperature:
      return "temperature";
    case Prediction::kEstimator:
      return "estimator";
  }
  return "?";
}

const char* to_string(ProfileShape shape) noexcept {
  switch (shape) {
    case ProfileShape::kLinear:
      return "linear";
    case ProfileShape::kCosine:
      return "cosine";
    case ProfileShape::kSmoothstep:
      return "smoothstep";
    case ProfileShape::kTable:
      return "table";
    case ProfileShape::kStep:
      return "step";
  }
  return "?";
}

bool parse_facet_rule(const std::string& s, FacetRule& out) noexcept {
  if (s == "exact") {
    out = FacetRule::kExact;
  } else if (s == "proportional") {
    out = FacetRule::kProportional;
  } else {
    return false;
  }
  return true;
}

bool parse_prediction(const std::string& s, Prediction& out) noexcept {
  if (s == "none") {
    out = Prediction::kNone;
  } else if (s == "time") {
    out = Prediction::kTime;
  } else if (s == "temperature") {
    out = Prediction::kTemperature;
  } else if (s == "estimator") {
    out = Prediction::kEstimator;
  } else {
    return false;
  }
  return true;
}

const char* to_string(TouchPositions positions) noexcept {
  switch (positions) {
    case TouchPositions::kMachine:
      return "machine";
    case TouchPositions::kProgram:
      return "program";
  }
  return "?";
}

bool parse_touch_positions(const std::string& s, TouchPositions& out) noexcept {
  if (s == "machine") {
    out = TouchPositions::kMachine;
  } else if (s == "program") {
    out = TouchPositions::kProgram;
  } else {
    return false;
  }
  return true;
}

const char* to_string(RequestCode code) noexcept {
  switch (code) {
    case RequestCode::kNone:
      return "none";
    case RequestCode::kReferenceTouches:
      return "reference-touches";
    case RequestCode::kTestGrindLateral:
      return "test-grind-lateral";
    case RequestCode::kTestGrindEndFace:
      return "test-grind-end-face";
    case RequestCode::kNominalTouches:
      return "nominal-touches";
    case RequestCode::kRecalibration:
      return "recalibration";
  }
  return "?";
}

bool parse_creep_shape(const std::string& s, ProfileShape& out) noexcept {
  if (s == "linear") {
    out = ProfileShape::kLinear;
  } else if (s == "cosine") {
    out = ProfileShape::kCosine;
  } else if (s == "smoothstep") {
    out = ProfileShape::kSmoothstep;
  } else if (s == "step") {
    out = ProfileShape::kStep;
  } else {
    return false;
  }
  return true;
}

}  // namespace nccomp::core::calib
