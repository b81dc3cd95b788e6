// `nccomp report DIR [--json] [--svg FILE]`: the figures of a machined result (an ncsim result
// directory): maximum step, form error, per-checkpoint wall error, touches, the writes the NC
// took; and a plot of the error along the path. docs/report.md.
#include <CLI/CLI.hpp>

#include <fstream>
#include <iostream>
#include <memory>
#include <string>

#include "tools/nccomp/command.hpp"
#include "tools/report/report.hpp"

namespace {

namespace rp = nccomp::tools::report;
using nccomp::tools::CommandError;

struct Options {
  std::string dir;
  bool json{false};
  std::string svg;
  bool strict{false};
};

void run(const Options& opt) {
  rp::Report r;
  rp::ResultTables tables;
  try {
    r = rp::load_report(opt.dir, &tables);
  } catch (const rp::ReportInputError& e) {
    throw CommandError(nccomp::tools::kExitInvalidInput, e.what());
  }
  std::string svg_text;
  if (!opt.svg.empty()) {
    try {
      svg_text = rp::plot_svg(r, tables);
    } catch (const rp::ReportInputError& e) {
      throw CommandError(nccomp::tools::kExitInvalidInput, e.what());
    }
    std::ofstream out(opt.svg, std::ios::binary | std::ios::trunc);
    out << svg_text;
    out.close();
    if (!out) throw CommandError(nccomp::tools::kExitFailure, opt.svg + ": cannot write");
  }
  std::cout << (opt.json ? rp::report_json(r) : rp::report_text(r));
  if (!opt.svg.empty() && !opt.json) std::cout << "\nplot     " << opt.svg << "\n";
  if (opt.strict && r.bad_rows > 0) {
    throw CommandError(nccomp::tools::kExitInvalidInput,
                       std::to_string(r.bad_rows) + " bad row(s) in " + opt.dir + " (--strict)");
  }
}

void setup(CLI::App& app) {
  auto opt = std::make_shared<Options>();
  auto* sub = app.add_subcommand(
      "report",
      "Figures of a machined result (ncsim --out DIR): step, form error, checkpoints, "
      "touches, writes; an SVG plot of the error along the path");
  sub->add_option("dir", opt->dir, "result directory written by ncsim --out")->required();
  sub->add_flag("--json", opt->json, "print the figures as one JSON object");
  sub->add_option("--svg", opt->svg, "write a plot of error_um along the path to this SVG file");
  sub->add_flag("--strict", opt->strict, "exit 3 when any CSV row was bad (skipped)");
  sub->callback([opt] { run(*opt); });
}

}  // namespace

NCCOMP_REGISTER_COMMAND(report, setup);
