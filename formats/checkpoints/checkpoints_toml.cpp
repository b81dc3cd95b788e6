#include "formats/checkpoints/checkpoints_toml.hpp"

#include <cmath>
#include <fstream>
#include <limits>
#include <sstream>

#include "core/common/config_issue.hpp"
#include "core/common/limiter.hpp"
#include "formats/toml/guard.hpp"
#include "formats/toml/key_positions.hpp"
#include "formats/toml/table_reader.hpp"

namespace nccomp::formats::checkpoints {

namespace cp = core::checkpoint;

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
                                    const std::filesystem::path& base_dir, Diagnostics& diag,
                                    const std::optional<std::string>& contour_csv_override) {
  const std::size_t errors_before = diag.items().size();
  CheckpointsConfig out;
  cp::PlanConfig& p = out.plan;
  cp::CompensatorConfig& c = out.compensator;
  constexpr double kBig = 1e9;
  {
    TableReader r(table, "checkpoints", diag);

    // --- contour: inline array or CSV file, exactly one ---
    const toml::node* inline_contour = r.value("contour");
    std::optional<std::string> csv;
    if (const toml::node* n = r.value("contour_csv")) {
      if (const auto* s = n->as_string()) {
        csv = s->get();
      } else {
        r.error("contour_csv", "must be a string");
      }
    }
    if (contour_csv_override) {
      // The command line wins over the file.
      inline_contour = nullptr;
      csv = contour_csv_override;
    }
    if ((inline_contour != nullptr) == csv.has_value()) {
      diag.error(where_of(&table, "checkpoints"),
                 "needs exactly one of contour = [[x_mm, y_mm], ...] or contour_csv = "
                 "\"file.csv\"");
    } else if (inline_contour != nullptr) {
      out.contour_source = file + ":" + std::to_string(inline_contour->source().begin.line);
      const toml::array* arr = inline_contour->as_array();
      if (arr == nullptr) {
        r.error("contour", "must be an array of [x_mm, y_mm] pairs");
      } else {
        for (std::size_t i = 0; i < arr->size(); ++i) {
          const toml::node& e = (*arr)[i];
          const std::string key = "checkpoints.contour[" + std::to_string(i) + "]";
          if (const toml::table* vt = e.as_table()) {
            // A vertex with attributes: { x_mm = .., y_mm = .., alpha_deg = .., corner = .. }.
            TableReader v(*vt, key, diag);
            if (vt->get("x_mm") == nullptr || vt->get("y_mm") == nullptr) {
              diag.error(&e, key, "needs x_mm and y_mm");
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
            p.contour.push_back(pt);
            continue;
          }
          const toml::array* pair = e.as_array();
          const toml::node* nx = pair != nullptr && pair->size() == 2 ? pair->get(0) : nullptr;
          const toml::node* ny = pair != nullptr && pair->size() == 2 ? pair->get(1) : nullptr;
          if (nx == nullptr || ny == nullptr || !nx->is_number() || !ny->is_number()) {
            diag.error(&e, key,
                       pair != nullptr ? "must be a pair of numbers [x_mm, y_mm]"
                                       : "must be a pair of numbers [x_mm, y_mm] or a table "
                                         "{ x_mm = .., y_mm = .., alpha_deg = .., corner = .. }");
            continue;
          }
          const double x = nx->value<double>().value_or(0.0);
          const double y = ny->value<double>().value_or(0.0);
          if (!std::isfinite(x) || !std::isfinite(y)) {
            diag.error(&e, key, "must be finite");
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
        r.error("contour_csv", e.what());
      }
    }

    // --- plan ---
    p.closed = r.boolean("closed", p.closed);
    p.material = r.pick<cp::MaterialSide>("material", p.material,
                                          {{"left", cp::MaterialSide::kLeft},
                                           {"right", cp::MaterialSide::kRight},
                                           {"inside", cp::MaterialSide::kInside},
                                           {"outside", cp::MaterialSide::kOutside}});
    p.contour_z_mm = r.number("contour_z_mm", p.contour_z_mm, -kBig, kBig);
    p.z_start_mm = r.number("z_start_mm", p.z_start_mm, -kBig, kBig);
    p.z_end_mm = r.number("z_end_mm", p.z_end_mm, -kBig, kBig);
    p.depth_step_mm = r.number("depth_step_mm", p.depth_step_mm, 1e-3, kBig);
    p.wall_angle_deg = r.number("wall_angle_deg", p.wall_angle_deg, -88.999, 88.999);
    p.corner_angle_deg = r.number("corner_angle_deg", p.corner_angle_deg, 0.001, 179.999);
    p.corner_offset_mm = r.number("corner_offset_mm", p.corner_offset_mm, 1e-3, kBig);
    if (const toml::node* n = r.value("extra_points_mm")) {
      const toml::array* arr = n->as_array();
      if (arr == nullptr) {
        r.error("extra_points_mm", "must be an array of numbers [mm along the contour]");
      } else {
        for (std::size_t i = 0; i < arr->size(); ++i) {
          const toml::node& e = (*arr)[i];
          if (!e.is_number()) {
            diag.error(&e, "checkpoints.extra_points_mm[" + std::to_string(i) + "]",
                       "must be a number");
            continue;
          }
          p.extra_points_mm.push_back(e.value<double>().value_or(0.0));
        }
      }
    }
    if (const toml::node* n = r.value("extra_regions")) {
      const toml::array* arr = n->as_array();
      if (arr == nullptr) {
        r.error("extra_regions",
                "must be an array of tables {from_mm = .., to_mm = .., spacing_mm = ..}");
      } else {
        for (std::size_t i = 0; i < arr->size(); ++i) {
          const toml::node& e = (*arr)[i];
          const std::string key = "checkpoints.extra_regions[" + std::to_string(i) + "]";
          const toml::table* t = e.as_table();
          if (t == nullptr) {
            diag.error(&e, key, "must be a table {from_mm = .., to_mm = .., spacing_mm = ..}");
            continue;
          }
          TableReader rr(*t, key, diag);
          cp::ExtraRegion reg;
          if (t->get("from_mm") == nullptr || t->get("to_mm") == nullptr ||
              t->get("spacing_mm") == nullptr) {
            diag.error(where_of(t, key), "needs from_mm, to_mm and spacing_mm");
          }
          reg.from_mm = rr.number("from_mm", 0.0, 0.0, kBig);
          reg.to_mm = rr.number("to_mm", 0.0, 0.0, kBig);
          reg.spacing_mm = rr.number("spacing_mm", 1.0, 1e-3, kBig);
          p.extra_regions.push_back(reg);
        }
      }
    }
    p.tool_radius_mm = r.number("tool_radius_mm", p.tool_radius_mm, 0.0, 1000.0);
    p.ball_radius_mm = r.number("ball_radius_mm", p.ball_radius_mm, 0.0, 100.0);
    p.probe_approach_mm = r.number("probe_approach_mm", p.probe_approach_mm, 0.0, 1000.0);
    p.program_path_start_mm =
        r.number("program_path_start_mm", p.program_path_start_mm, -kBig, kBig);
    p.level_link_mm = r.number("level_link_mm", p.level_link_mm, -1.0, kBig);

    // --- compensator ---
    c.learning_mode =
        r.pick<cp::LearningMode>("learning_mode", cp::LearningMode::kPreviousPart,
                                 {{"previous_part", cp::LearningMode::kPreviousPart},
                                  {"semi_finishing", cp::LearningMode::kSemiFinishing}});
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
    c.apply = r.pick<cp::ApplyMode>(
        "apply", c.active_register >= 0 ? cp::ApplyMode::kCreep : cp::ApplyMode::kTable,
        {{"step", cp::ApplyMode::kStep},
         {"creep", cp::ApplyMode::kCreep},
         {"table", cp::ApplyMode::kTable}});
    c.creep_shape = r.pick<core::ProfileShape>("creep_shape", core::ProfileShape::kLinear,
                                               {{"linear", core::ProfileShape::kLinear},
                                                {"cosine", core::ProfileShape::kCosine},
                                                {"smoothstep", core::ProfileShape::kSmoothstep}});
    c.trigger = r.pick<cp::TriggerMode>(
        "trigger", cp::TriggerMode::kPath,
        {{"path", cp::TriggerMode::kPath}, {"position", cp::TriggerMode::kPosition}});
    c.xy_tolerance_mm = r.number("xy_tolerance_mm", c.xy_tolerance_mm, 1e-6, 1000.0);
    c.z_band_mm = r.number("z_band_mm", c.z_band_mm, 1e-6, 1000.0);
    c.ewma_weight = r.number("ewma_weight", c.ewma_weight, 1.0, 1e6);
    if (c.learning_mode == cp::LearningMode::kSemiFinishing &&
        table.get("ewma_weight") != nullptr) {
      r.error("ewma_weight",
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
    c.reconcile_prefer = r.pick<cp::ReconcilePrefer>(
        "reconcile_prefer", cp::ReconcilePrefer::kDaemon,
        {{"daemon", cp::ReconcilePrefer::kDaemon}, {"nc", cp::ReconcilePrefer::kNc}});

    // --- [checkpoints.estimator] (mode A's Kalman filter; the core checks the combinations) ---
    if (const toml::table* t = r.table("estimator")) {
      TableReader e(*t, "checkpoints.estimator", diag);
      cp::CheckpointEstimatorConfig& est = c.estimator;
      est.enabled = e.boolean("enabled", est.enabled);
      est.measurement_sigma_um =
          e.number("measurement_sigma_um", est.measurement_sigma_um, 1e-6, 1e3);
      est.part_noise_um = e.number("part_noise_um", est.part_noise_um, 0.0, 1e3);
      est.learn_part_noise = e.boolean("learn_part_noise", est.learn_part_noise);
      est.learn_min_parts = static_cast<std::uint32_t>(e.integer(
          "learn_min_parts", est.learn_min_parts, 3, static_cast<std::int64_t>(cp::kHistoryDepth)));
      est.gate_sigmas = e.number("gate_sigmas", est.gate_sigmas, 0.0, 1e3);
    }

    // --- [checkpoints.gcode] ---
    if (const toml::table* t = r.table("gcode")) {
      {
        TableReader g(*t, "checkpoints.gcode", diag);
        GcodeConfig& gc = out.gcode;
        gc.program_number =
            static_cast<int>(g.integer("program_number", gc.program_number, 1, 9999));
        gc.macro_program = static_cast<int>(g.integer("macro_program", gc.macro_program, 1, 9999));
        gc.safe_z_mm = g.number("safe_z_mm", gc.safe_z_mm, -kBig, kBig);
        gc.feed_mm_per_min = g.number("feed_mm_per_min", gc.feed_mm_per_min, 1e-3, 1e6);
        gc.nc_variable_first =
            static_cast<int>(g.integer("nc_variable_first", gc.nc_variable_first, 0, 99999));
      }
    }
  }

  if (diag.items().size() != errors_before) {
    return out;
  }
  // Semantic checks of the core, each issue at its key (or the nearest parent in the file).
  try {
    const cp::Plan plan = cp::make_plan(out.plan);
    if (out.gcode.safe_z_mm <= plan.levels_z_mm.front()) {
      const toml::node* gcode = table.get("gcode");
      diag.error(where_of(gcode != nullptr ? gcode : &table, "checkpoints.gcode.safe_z_mm"),
                 "must be above the highest probing level z_start_mm");
    }
    cp::CheckpointCompensator probe_config;
    probe_config.configure(out.compensator, plan.checkpoints, core::LimiterConfig{});
  } catch (const core::ConfigInvalid& e) {
    KeyPositions positions;
    record_positions(table, "checkpoints", positions);
    report(positions, where_of(&table, "checkpoints"), e, diag);
  } catch (const std::invalid_argument& e) {
    diag.error(where_of(&table, "checkpoints"), e.what());
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
    root = parse_toml_file(path);
  } catch (const toml::parse_error& e) {
    throw DiagnosticsError(e, path);
  }
  Diagnostics diag;
  const toml::node* node = root.get("checkpoints");
  if (node == nullptr || !node->is_table()) {
    Where w = where_of(node, "checkpoints");
    w.file = path;
    diag.error(std::move(w), node == nullptr ? "no [checkpoints] table in this file"
                                             : "must be a table ([checkpoints])");
    throw DiagnosticsError(std::move(diag), path);
  }
  const std::filesystem::path base = std::filesystem::path(path).parent_path();
  CheckpointsConfig cfg =
      parse_checkpoints(*node->as_table(), path, base, diag, contour_csv_override);
  if (!diag.ok()) throw DiagnosticsError(std::move(diag), path);
  return cfg;
}

}  // namespace nccomp::formats::checkpoints
