#include "tools/calibrate/config_toml.hpp"

#include <cmath>
#include <cstdint>
#include <functional>
#include <limits>
#include <map>
#include <sstream>
#include <stdexcept>

#include "formats/toml_guard.hpp"

namespace nccomp::tools::calibrate {

namespace {

using core::calib::CalibrationConfig;

[[noreturn]] void fail(const std::string& source, const toml::node* node, const std::string& key,
                       const std::string& why) {
  std::ostringstream s;
  s << source;
  if (node != nullptr && node->source().begin.line > 0) {
    s << ':' << node->source().begin.line;
  }
  s << ": calibration." << key << ": " << why;
  throw std::invalid_argument(s.str());
}

double as_number(const std::string& src, const toml::node& n, const std::string& key) {
  if (const auto* f = n.as_floating_point()) {
    return f->get();
  }
  if (const auto* i = n.as_integer()) {
    return static_cast<double>(i->get());
  }
  fail(src, &n, key, "must be a number");
}

std::int64_t as_integer(const std::string& src, const toml::node& n, const std::string& key,
                        std::int64_t lo, std::int64_t hi) {
  const auto* i = n.as_integer();
  if (i == nullptr) {
    fail(src, &n, key, "must be an integer");
  }
  if (i->get() < lo || i->get() > hi) {
    fail(src, &n, key,
         "must be in " + std::to_string(lo) + ".." + std::to_string(hi) + ", got " +
             std::to_string(i->get()));
  }
  return i->get();
}

std::string as_string(const std::string& src, const toml::node& n, const std::string& key) {
  const auto* s = n.as_string();
  if (s == nullptr) {
    fail(src, &n, key, "must be a string");
  }
  return s->get();
}

}  // namespace

CalibrationConfig load_calibration_table(const toml::table& root, const std::string& src) {
  const toml::node* table_node = root.get("calibration");
  if (table_node == nullptr) {
    CalibrationConfig c;
    core::calib::validate(c);
    return c;
  }
  return load_calibration_node(*table_node, src);
}

CalibrationConfig load_calibration_node(const toml::node& calibration, const std::string& src) {
  CalibrationConfig c;
  const toml::node* table_node = &calibration;
  const toml::table* t = table_node->as_table();
  if (t == nullptr) {
    std::ostringstream s;
    s << src << ':' << table_node->source().begin.line << ": calibration: must be a table";
    throw std::invalid_argument(s.str());
  }
  using Setter = std::function<void(const toml::node&, const std::string&)>;
  const auto num = [&src](double& field) -> Setter {
    return [&field, &src](const toml::node& n, const std::string& k) {
      field = as_number(src, n, k);
      if (!std::isfinite(field)) {
        fail(src, &n, k, "must be finite");
      }
    };
  };
  const auto reg = [&src](std::uint16_t& field) -> Setter {
    return [&field, &src](const toml::node& n, const std::string& k) {
      field = static_cast<std::uint16_t>(as_integer(src, n, k, 0, 65535));
    };
  };
  const auto i32 = [&src](std::int32_t& field, std::int64_t lo, std::int64_t hi) -> Setter {
    return [&field, &src, lo, hi](const toml::node& n, const std::string& k) {
      field = static_cast<std::int32_t>(as_integer(src, n, k, lo, hi));
    };
  };
  const std::map<std::string, Setter> keys{
      {"register_x", reg(c.register_x)},
      {"register_y", reg(c.register_y)},
      {"register_z", reg(c.register_z)},
      {"reference_x_lateral_mm", num(c.reference_x_lateral_mm)},
      {"reference_x_axial_mm", num(c.reference_x_axial_mm)},
      {"reference_y_mm", num(c.reference_y_mm)},
      {"reference_z_mm", num(c.reference_z_mm)},
      {"reference_contact_mm", num(c.reference_contact_mm)},
      {"reference_axial_contact_mm", num(c.reference_axial_contact_mm)},
      {"touches_per_axis", i32(c.touches_per_axis, 1, 8)},
      {"touch_positions",
       [&](const toml::node& n, const std::string& k) {
         if (!core::calib::parse_touch_positions(as_string(src, n, k), c.touch_positions)) {
           fail(src, &n, k, "must be \"machine\" or \"program\"");
         }
       }},
      {"request_register", i32(c.request_register, -1, 65535)},
      {"state_file",
       [&](const toml::node& n, const std::string& k) {
         c.state_file = as_string(src, n, k);
         if (c.state_file.empty()) {
           fail(src, &n, k, "must not be empty (leave the key out for none)");
         }
       }},
      {"max_scatter_um", num(c.max_scatter_um)},
      {"touch_set_timeout_s", num(c.touch_set_timeout_s)},
      {"facet_rule",
       [&](const toml::node& n, const std::string& k) {
         if (!core::calib::parse_facet_rule(as_string(src, n, k), c.facet_rule)) {
           fail(src, &n, k, "must be \"exact\" or \"proportional\"");
         }
       }},
      {"blank_radius_mm", num(c.blank_radius_mm)},
      {"facet_gain_um_per_um", num(c.facet_gain_um_per_um)},
      {"facet_tolerance_um", num(c.facet_tolerance_um)},
      {"max_test_grinds", i32(c.max_test_grinds, 1, 50)},
      {"end_face_test_grind",
       [&](const toml::node& n, const std::string& k) {
         const auto* b = n.as_boolean();
         if (b == nullptr) {
           fail(src, &n, k, "must be true or false");
         }
         c.end_face_test_grind = b->get();
       }},
      {"plausibility_um", num(c.plausibility_um)},
      {"recalibration_interval_s", num(c.recalibration_interval_s)},
      {"creep_shape",
       [&](const toml::node& n, const std::string& k) {
         if (!core::calib::parse_creep_shape(as_string(src, n, k), c.creep_shape)) {
           fail(src, &n, k, "must be \"linear\", \"cosine\", \"smoothstep\" or \"step\"");
         }
       }},
      {"creep_duration_s", num(c.creep_duration_s)},
      {"prediction",
       [&](const toml::node& n, const std::string& k) {
         if (!core::calib::parse_prediction(as_string(src, n, k), c.prediction)) {
           fail(src, &n, k, "must be \"none\", \"time\" or \"temperature\"");
         }
       }},
      {"thermal_time_constant_s", num(c.thermal_time_constant_s)},
      {"temperature_sensor", i32(c.temperature_sensor, -1, 255)},
      {"temperature_forgetting", num(c.temperature_forgetting)},
      {"max_temperature_slope_um_per_c", num(c.max_temperature_slope_um_per_c)},
      {"write_period_s", num(c.write_period_s)},
      {"write_deadband_um", num(c.write_deadband_um)},
      {"max_abs_um", num(c.max_abs_um)},
      {"max_step_um", num(c.max_step_um)},
      {"max_rate_um_per_s", num(c.max_rate_um_per_s)},
  };
  for (const auto& [key, node] : *t) {
    const std::string k(key.str());
    const auto it = keys.find(k);
    if (it == keys.end()) {
      fail(src, &node, k, "unknown key");
    }
    it->second(node, k);
  }
  try {
    core::calib::validate(c);
  } catch (const std::invalid_argument& e) {
    // validate() names the key; add the file.
    throw std::invalid_argument(src + ": " + e.what());
  }
  return c;
}

CalibrationConfig load_calibration_config_text(std::string_view text, const std::string& source) {
  toml::table root;
  try {
    root = formats::parse_toml(text, source);
  } catch (const toml::parse_error& e) {
    std::ostringstream s;
    s << source << ':' << e.source().begin.line << ": " << e.description();
    throw std::invalid_argument(s.str());
  }
  return load_calibration_table(root, source);
}

CalibrationConfig load_calibration_config_file(const std::string& path) {
  toml::table root;
  try {
    root = formats::parse_toml_file(path);
  } catch (const toml::parse_error& e) {
    std::ostringstream s;
    s << path << ':' << e.source().begin.line << ": " << e.description();
    throw std::invalid_argument(s.str());
  }
  return load_calibration_table(root, path);
}

}  // namespace nccomp::tools::calibrate
