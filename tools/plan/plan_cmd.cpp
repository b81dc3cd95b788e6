// `nccomp plan`: the S1 checkpoint plan and probing program from the `[checkpoints]` config.
#include <fstream>
#include <iostream>
#include <memory>
#include <optional>
#include <string>

#include "core/checkpoint/plan.hpp"
#include "formats/checkpoints/checkpoints_toml.hpp"
#include "tools/nccomp/command.hpp"
#include "tools/plan/plan_output.hpp"

namespace {

using nccomp::tools::CommandError;
namespace ck = nccomp::tools::checkpoints;
namespace fc = nccomp::formats::checkpoints;

struct PlanOptions {
  std::string config;
  std::string contour;
  std::string format{"both"};
  std::string out_csv;
  std::string out_gcode;
};

void write_file(const std::string& path, const std::string& what,
                void (*fn)(std::ostream&, const nccomp::core::checkpoint::Plan&,
                           const ck::CheckpointsConfig&),
                const nccomp::core::checkpoint::Plan& plan, const ck::CheckpointsConfig& cfg) {
  std::ofstream f(path);
  if (!f) {
    throw CommandError(nccomp::tools::kExitFailure, path + ": cannot write the " + what);
  }
  fn(f, plan, cfg);
  if (!f.flush()) {
    throw CommandError(nccomp::tools::kExitFailure, path + ": write failed");
  }
}

void run(const PlanOptions& o) {
  ck::CheckpointsConfig cfg;
  try {
    cfg = fc::load_checkpoints_file(
        o.config, o.contour.empty() ? std::nullopt : std::optional<std::string>(o.contour));
  } catch (const nccomp::formats::DiagnosticsError& e) {
    throw CommandError(nccomp::tools::kExitInvalidInput,
                       std::string("invalid config\n") + e.what());
  }
  // parse_checkpoints already built the plan once to validate it; this cannot fail now.
  const nccomp::core::checkpoint::Plan plan = nccomp::core::checkpoint::make_plan(cfg.plan);
  const bool csv = o.format == "csv" || o.format == "both";
  const bool gcode = o.format == "gcode" || o.format == "both";
  if (!o.out_csv.empty()) write_file(o.out_csv, "plan CSV", ck::write_plan_csv, plan, cfg);
  if (!o.out_gcode.empty()) {
    write_file(o.out_gcode, "probing program", ck::write_probing_gcode, plan, cfg);
  }
  ck::write_plan_summary(std::cout, plan, cfg);
  if (csv && o.out_csv.empty()) {
    ck::write_plan_csv(std::cout, plan, cfg);
  }
  if (gcode && o.out_gcode.empty()) {
    if (csv && o.out_csv.empty()) std::cout << "\n";
    ck::write_probing_gcode(std::cout, plan, cfg);
  }
}

void setup(CLI::App& app) {
  auto opts = std::make_shared<PlanOptions>();
  CLI::App* sub = app.add_subcommand(
      "plan",
      "S1 checkpoint plan: probing positions in machining order (CSV) and the probing "
      "program (G-code) from the [checkpoints] table of a config");
  sub->add_option("config", opts->config, "config file with a [checkpoints] table")->required();
  sub->add_option("--contour", opts->contour,
                  "contour CSV (x_mm,y_mm) replacing the config's contour / contour_csv");
  sub->add_option("--format", opts->format, "what to print: csv, gcode or both")
      ->check(CLI::IsMember({"csv", "gcode", "both"}));
  sub->add_option("--out-csv", opts->out_csv, "write the plan CSV to this file");
  sub->add_option("--out-gcode", opts->out_gcode, "write the probing program to this file");
  sub->callback([opts] { run(*opts); });
}

}  // namespace

NCCOMP_REGISTER_COMMAND(plan, setup);
