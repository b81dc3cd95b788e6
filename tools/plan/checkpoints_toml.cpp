#include "tools/plan/checkpoints_toml.hpp"

#include <cmath>
#include <fstream>
#include <limits>
#include <set>
#include <sstream>

#include "core/common/limiter.hpp"
#include "formats/toml_guard.hpp"

namespace nccomp::tools::checkpoints {

namespace cp = core::checkpoint;

namespace {

// Reads the keys of one table with typed, range-checked accessors; reports keys nobody asked for.
class Reader {
 public:
  Reader(const toml::table& t, std::string path, const std::string& file,
         std::vector<ConfigIssue>& issues)
      : t_(t), path_(std::move(path)), file_(file), issues_(issues) {}

  void issue(const toml::node* n, const std::string& key, const std::string& msg) {
    ConfigIssue i;
    i.file = file_;
    const toml::node* at = n != nullptr ? n : &t_;
    i.line = static_cast<int>(at->source().begin.line);
    i.column = static_cast<int>(at->source().begin.column);
    i.key_path = key.empty() ? path_ : path_ + "." + key;
    i.message = msg;
    issues_.push_back(std::move(i));
  }

  const toml::node* get(std::string_view key) {
    known_.insert(std::string(key));
    return t_.get(key);
  }

  double number(std::string_view key, double def, double min, double max) {
    const toml::node* n = get(key);
    if (n == nullptr) return def;
    const std::string k(key);
    if (!n->is_number()) {
      issue(n, k, "must be a number");
      return def;
    }
    const double v = n->value<double>().value_or(def);
    if (!std::isfinite(v) || v < min || v > max) {
      std::ostringstream s;
      s << "must be a finite number in [" << min << ", " << max << "], got " << v;
      issue(n, k, s.str());
      return def;
    }
    return v;
  }

  std::int64_t integer(std::string_view key, std::int64_t def, std::int64_t min, std::int64_t max) {
    const toml::node* n = get(key);
    if (n == nullptr) return def;
    const std::string k(key);
    if (!n->is_integer()) {
      issue(n, k, "must be an integer");
      return def;
    }
    const std::int64_t v = n->value<std::int64_t>().value_or(def);
    if (v < min || v > max) {
      issue(n, k,
            "must be in [" + std::to_string(min) + ", " + std::to_string(max) + "], got " +
                std::to_string(v));
      return def;
    }
    return v;
  }

  bool boolean(std::string_view key, bool def) {
    const toml::node* n = get(key);
    if (n == nullptr) return def;
    if (!n->is_boolean()) {
      issue(n, std::string(key), "must be true or false");
      return def;
    }
    return n->value<bool>().value_or(def);
  }

  std::optional<std::string> string(std::string_view key) {
    const toml::node* n = get(key);
    if (n == nullptr) return std::nullopt;
    if (!n->is_string()) {
      issue(n, std::string(key), "must be a string");
      return std::nullopt;
    }
    return n->value<std::string>();
  }

  /// Index of the value in choices; def if absent or wrong.
  std::size_t choice(std::string_view key, std::size_t def,
                     const std::vector<std::string>& choices) {
    const auto s = string(key);
    if (!s) return def;
    for (std::size_t i = 0; i < choices.size(); ++i) {
      if (*s == choices[i]) return i;
    }
    std::string allowed;
    for (const auto& c : choices) {
      allowed.append(allowed.empty() ? "\"" : ", \"").append(c).append("\"");
    }
    issue(t_.get(key), std::string(key), "must be one of " + allowed + ", got \"" + *s + "\"");
    return def;
  }

  void finish() {
    for (const auto& [k, v] : t_) {
      if (known_.count(std::string(k.str())) == 0) {
        issue(&v, std::string(k.str()), "unknown key");
      }
    }
  }

  [[nodiscard]] const std::string& path() const { return path_; }
  [[nodiscard]] const toml::table& table() const { return t_; }

 private:
  const toml::table& t_;
  std::string path_;
  const std::string& file_;
  std::vector<ConfigIssue>& issues_;
  std::set<std::string> known_;
};

}  // namespace

std::string format_issue(const ConfigIssue& i) {
  std::ostringstream s;
  s << i.file;
  if (i.line > 0) s << ':' << i.line << ':' << i.column;
  s << ": " << i.key_path << ": " << i.message;
  return s.str();
}

ConfigError::ConfigError(std::vector<ConfigIssue> issues)
    : std::runtime_error([&] {
        std::string all;
        for (const auto& i : issues) {
          if (!all.empty()) all.push_back('\n');
          all.append(format_issue(i));
        }
        return all;
      }()),
      issues_(std::move(issues)) {}

std::vector<cp::ContourPoint> read_contour_csv(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    throw std::invalid_argument(path.string() + ": cannot open contour file");
  }
  std::ostringstream ss;
  ss << in.rdbuf();
  return cp::parse_contour_csv(ss.str(), path.string());
}

CheckpointsConfig parse_checkpoints(const toml::table& table, const std::string& file,
                                    const std::filesystem::path& base_dir,
                                    std::vector<ConfigIssue>& issues,
                                    const std::optional<std::string>& contour_csv_override) {
  const std::size_t issues_before = issues.size();
  CheckpointsConfig out;
  Reader r(table, "checkpoints", file, issues);
  cp::PlanConfig& p = out.plan;
  cp::CompensatorConfig& c = out.compensator;
  constexpr double kBig = 1e9;

  // --- contour: inline array or CSV file, exactly one ---
  const toml::node* inline_contour = r.get("contour");
  auto csv = r.string("contour_csv");
  if (contour_csv_override) {
    // The command line wins over the file.
    inline_contour = nullptr;
    csv = contour_csv_override;
  }
  if ((inline_contour != nullptr) == csv.has_value()) {
    r.issue(nullptr, "",
            "needs exactly one of contour = [[x_mm, y_mm], ...] or contour_csv = "
            "\"file.csv\"");
  } else if (inline_contour != nullptr) {
    out.contour_source = file + ":" + std::to_string(inline_contour->source().begin.line);
    const toml::array* arr = inline_contour->as_array();
    if (arr == nullptr) {
      r.issue(inline_contour, "contour", "must be an array of [x_mm, y_mm] pairs");
    } else {
      for (std::size_t i = 0; i < arr->size(); ++i) {
        const toml::node& e = (*arr)[i];
        const std::string key = "contour[" + std::to_string(i) + "]";
        if (const toml::table* vt = e.as_table()) {
          // A vertex with attributes: { x_mm = .., y_mm = .., alpha_deg = .., corner = .. }.
          Reader v(*vt, r.path() + "." + key, file, issues);
          if (vt->get("x_mm") == nullptr || vt->get("y_mm") == nullptr) {
            v.issue(&e, "", "needs x_mm and y_mm");
          }
          cp::ContourPoint pt;
          pt.x_mm = v.number("x_mm", 0.0, -kBig, kBig);
          pt.y_mm = v.number("y_mm", 0.0, -kBig, kBig);
          if (vt->get("alpha_deg") != nullptr) {
            pt.alpha_deg = v.number("alpha_deg", 0.0, -88.999, 88.999);
          }
          if (vt->get("corner") != nullptr) {
            pt.corner =
                v.boolean("corner", false) ? cp::CornerMark::kCorner : cp::CornerMark::kNoCorner;
          }
          v.finish();
          p.contour.push_back(pt);
          continue;
        }
        const toml::array* pair = e.as_array();
        const toml::node* nx = pair != nullptr && pair->size() == 2 ? pair->get(0) : nullptr;
        const toml::node* ny = pair != nullptr && pair->size() == 2 ? pair->get(1) : nullptr;
        if (nx == nullptr || ny == nullptr || !nx->is_number() || !ny->is_number()) {
          r.issue(&e, key,
                  pair != nullptr ? "must be a pair of numbers [x_mm, y_mm]"
                                  : "must be a pair of numbers [x_mm, y_mm] or a table "
                                    "{ x_mm = .., y_mm = .., alpha_deg = .., corner = .. }");
          continue;
        }
        const double x = nx->value<double>().value_or(0.0);
        const double y = ny->value<double>().value_or(0.0);
        if (!std::isfinite(x) || !std::isfinite(y)) {
          r.issue(&e, key, "must be finite");
          continue;
        }
        p.contour.push_back(cp::ContourPoint{x, y});
      }
    }
  } else {
    std::filesystem::path csv_path(*csv);
    if (csv_path.is_relative() && !contour_csv_override) csv_path = base_dir / csv_path;
    out.contour_source = csv_path.string();
    try {
      p.contour = read_contour_csv(csv_path);
    } catch (const std::invalid_argument& e) {
      r.issue(table.get("contour_csv"), "contour_csv", e.what());
    }
  }

  // --- plan ---
  p.closed = r.boolean("closed", p.closed);
  p.material = static_cast<cp::MaterialSide>(r.choice(
      "material", static_cast<std::size_t>(p.material), {"left", "right", "inside", "outside"}));
  p.contour_z_mm = r.number("contour_z_mm", p.contour_z_mm, -kBig, kBig);
  p.z_start_mm = r.number("z_start_mm", p.z_start_mm, -kBig, kBig);
  p.z_end_mm = r.number("z_end_mm", p.z_end_mm, -kBig, kBig);
  p.depth_step_mm = r.number("depth_step_mm", p.depth_step_mm, 1e-3, kBig);
  p.wall_angle_deg = r.number("wall_angle_deg", p.wall_angle_deg, -88.999, 88.999);
  p.corner_angle_deg = r.number("corner_angle_deg", p.corner_angle_deg, 0.001, 179.999);
  p.corner_offset_mm = r.number("corner_offset_mm", p.corner_offset_mm, 1e-3, kBig);
  if (const toml::node* n = r.get("extra_points_mm")) {
    const toml::array* arr = n->as_array();
    if (arr == nullptr) {
      r.issue(n, "extra_points_mm", "must be an array of numbers [mm along the contour]");
    } else {
      for (std::size_t i = 0; i < arr->size(); ++i) {
        const toml::node& e = (*arr)[i];
        if (!e.is_number()) {
          r.issue(&e, "extra_points_mm[" + std::to_string(i) + "]", "must be a number");
          continue;
        }
        p.extra_points_mm.push_back(e.value<double>().value_or(0.0));
      }
    }
  }
  if (const toml::node* n = r.get("extra_regions")) {
    const toml::array* arr = n->as_array();
    if (arr == nullptr) {
      r.issue(n, "extra_regions",
              "must be an array of tables {from_mm = .., to_mm = .., spacing_mm = ..}");
    } else {
      for (std::size_t i = 0; i < arr->size(); ++i) {
        const toml::node& e = (*arr)[i];
        const std::string key = "extra_regions[" + std::to_string(i) + "]";
        const toml::table* t = e.as_table();
        if (t == nullptr) {
          r.issue(&e, key, "must be a table {from_mm = .., to_mm = .., spacing_mm = ..}");
          continue;
        }
        Reader rr(*t, r.path() + "." + key, file, issues);
        cp::ExtraRegion reg;
        if (t->get("from_mm") == nullptr || t->get("to_mm") == nullptr ||
            t->get("spacing_mm") == nullptr) {
          rr.issue(nullptr, "", "needs from_mm, to_mm and spacing_mm");
        }
        reg.from_mm = rr.number("from_mm", 0.0, 0.0, kBig);
        reg.to_mm = rr.number("to_mm", 0.0, 0.0, kBig);
        reg.spacing_mm = rr.number("spacing_mm", 1.0, 1e-3, kBig);
        rr.finish();
        p.extra_regions.push_back(reg);
      }
    }
  }
  p.tool_radius_mm = r.number("tool_radius_mm", p.tool_radius_mm, 0.0, 1000.0);
  p.ball_radius_mm = r.number("ball_radius_mm", p.ball_radius_mm, 0.0, 100.0);
  p.probe_approach_mm = r.number("probe_approach_mm", p.probe_approach_mm, 0.0, 1000.0);
  p.program_path_start_mm = r.number("program_path_start_mm", p.program_path_start_mm, -kBig, kBig);
  p.level_link_mm = r.number("level_link_mm", p.level_link_mm, -1.0, kBig);

  // --- compensator ---
  c.learning_mode = static_cast<cp::LearningMode>(
      r.choice("learning_mode", 0, {"previous_part", "semi_finishing"}));
  c.finishing_tool = static_cast<std::int32_t>(
      r.integer("finishing_tool", c.finishing_tool, 0, std::numeric_limits<std::int32_t>::max()));
  c.semi_finishing_tool = static_cast<std::int32_t>(r.integer(
      "semi_finishing_tool", c.semi_finishing_tool, 0, std::numeric_limits<std::int32_t>::max()));
  c.register_base =
      static_cast<std::uint16_t>(r.integer("register_base", c.register_base, 0, 65535));
  c.active_register =
      static_cast<std::int32_t>(r.integer("active_register", c.active_register, -1, 65535));
  // Without a live register the NC program applies the table itself: "table". With one, the
  // daemon creeps unless told to step. A contradicting explicit choice is refused by the core
  // (checkpoints.apply) below.
  const std::size_t apply_default = c.active_register >= 0 ? 1 : 2;
  c.apply =
      static_cast<cp::ApplyMode>(r.choice("apply", apply_default, {"step", "creep", "table"}));
  const std::size_t shape = r.choice("creep_shape", 0, {"linear", "cosine", "smoothstep"});
  c.creep_shape = shape == 0   ? core::ProfileShape::kLinear
                  : shape == 1 ? core::ProfileShape::kCosine
                               : core::ProfileShape::kSmoothstep;
  c.trigger = static_cast<cp::TriggerMode>(r.choice("trigger", 0, {"path", "position"}));
  c.xy_tolerance_mm = r.number("xy_tolerance_mm", c.xy_tolerance_mm, 1e-6, 1000.0);
  c.z_band_mm = r.number("z_band_mm", c.z_band_mm, 1e-6, 1000.0);
  c.ewma_weight = r.number("ewma_weight", c.ewma_weight, 1.0, 1e6);
  if (c.learning_mode == cp::LearningMode::kSemiFinishing && table.get("ewma_weight") != nullptr) {
    r.issue(table.get("ewma_weight"), "ewma_weight",
            "not used with learning_mode = \"semi_finishing\": mode B applies each blank's own "
            "semi-finishing reading (an average over blanks would blend earlier blanks' hardness "
            "into this one's offsets); remove the key");
  }
  c.dead_band_um = r.number("dead_band_um", c.dead_band_um, 0.0, kBig);
  c.feedback = r.number("feedback", c.feedback, 1e-6, 1.0);
  c.plausible_um = r.number("plausible_um", c.plausible_um, 1e-6, kBig);
  c.outlier_sigma = r.number("outlier_sigma", c.outlier_sigma, 1e-6, kBig);
  c.outlier_min_history =
      static_cast<std::uint32_t>(r.integer("outlier_min_history", c.outlier_min_history, 2,
                                           static_cast<std::int64_t>(cp::kHistoryDepth)));
  c.probe_repeatability_um =
      r.number("probe_repeatability_um", c.probe_repeatability_um, 0.0, kBig);
  c.write_threshold_um = r.number("write_threshold_um", c.write_threshold_um, 0.0, kBig);
  c.reconcile_tolerance_um =
      r.number("reconcile_tolerance_um", c.reconcile_tolerance_um, 0.0, kBig);
  c.reconcile_prefer =
      static_cast<cp::ReconcilePrefer>(r.choice("reconcile_prefer", 0, {"daemon", "nc"}));

  // --- [checkpoints.gcode] ---
  if (const toml::node* n = r.get("gcode")) {
    if (const toml::table* t = n->as_table()) {
      Reader g(*t, "checkpoints.gcode", file, issues);
      GcodeConfig& gc = out.gcode;
      gc.program_number = static_cast<int>(g.integer("program_number", gc.program_number, 1, 9999));
      gc.macro_program = static_cast<int>(g.integer("macro_program", gc.macro_program, 1, 9999));
      gc.safe_z_mm = g.number("safe_z_mm", gc.safe_z_mm, -kBig, kBig);
      gc.feed_mm_per_min = g.number("feed_mm_per_min", gc.feed_mm_per_min, 1e-3, 1e6);
      gc.nc_variable_first =
          static_cast<int>(g.integer("nc_variable_first", gc.nc_variable_first, 0, 99999));
      g.finish();
    } else {
      r.issue(n, "gcode", "must be a table");
    }
  }
  r.finish();

  if (issues.size() != issues_before) {
    return out;
  }
  // Semantic checks of the core (each message names its key "checkpoints.<key>").
  try {
    const cp::Plan plan = cp::make_plan(out.plan);
    if (out.gcode.safe_z_mm <= plan.levels_z_mm.front()) {
      r.issue(table.get("gcode"), "gcode.safe_z_mm",
              "must be above the highest probing level z_start_mm");
    }
    cp::CheckpointCompensator probe_config;
    probe_config.configure(out.compensator, plan.checkpoints, core::LimiterConfig{});
  } catch (const std::invalid_argument& e) {
    ConfigIssue i;
    i.file = file;
    i.line = static_cast<int>(table.source().begin.line);
    i.column = static_cast<int>(table.source().begin.column);
    std::string msg = e.what();
    // "checkpoints.key: reason" → key path and message.
    const auto colon = msg.find(": ");
    if (msg.rfind("checkpoints.", 0) == 0 && colon != std::string::npos) {
      i.key_path = msg.substr(0, colon);
      const std::string key = i.key_path.substr(std::string("checkpoints.").size());
      const std::string top = key.substr(0, key.find_first_of(".["));
      if (const toml::node* n = table.get(top)) {
        i.line = static_cast<int>(n->source().begin.line);
        i.column = static_cast<int>(n->source().begin.column);
      }
      i.message = msg.substr(colon + 2);
    } else {
      i.key_path = "checkpoints";
      i.message = msg;
    }
    issues.push_back(std::move(i));
  }
  return out;
}

std::unique_ptr<cp::CheckpointModule> make_checkpoint_module(const CheckpointsConfig& config) {
  cp::Plan plan = cp::make_plan(config.plan);
  return std::make_unique<cp::CheckpointModule>(config.compensator, std::move(plan.checkpoints));
}

CheckpointsConfig load_checkpoints_file(const std::string& path,
                                        const std::optional<std::string>& contour_csv_override) {
  toml::table root;
  try {
    root = formats::parse_toml_file(path);
  } catch (const toml::parse_error& e) {
    ConfigIssue i;
    i.file = path;
    i.line = static_cast<int>(e.source().begin.line);
    i.column = static_cast<int>(e.source().begin.column);
    i.key_path = "(toml)";
    i.message = std::string(e.description());
    throw ConfigError({i});
  }
  const toml::node* node = root.get("checkpoints");
  if (node == nullptr || !node->is_table()) {
    ConfigIssue i;
    i.file = path;
    i.key_path = "checkpoints";
    i.message = node == nullptr ? "no [checkpoints] table in this file" : "must be a table";
    throw ConfigError({i});
  }
  const std::filesystem::path base = std::filesystem::path(path).parent_path();
  std::vector<ConfigIssue> issues;
  CheckpointsConfig cfg =
      parse_checkpoints(*node->as_table(), path, base, issues, contour_csv_override);
  if (!issues.empty()) {
    throw ConfigError(std::move(issues));
  }
  return cfg;
}

}  // namespace nccomp::tools::checkpoints
