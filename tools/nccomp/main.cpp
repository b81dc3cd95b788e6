// nccomp — the operator's command: plan, grind-path, calibrate, analyze, check-config, status, …
// Each subcommand registers itself (tools/nccomp/command.hpp).
#include <CLI/CLI.hpp>

#include <exception>
#include <iostream>

#include "tools/nccomp/command.hpp"

int main(int argc, char** argv) {
  CLI::App app{"nccomp — operator command of the nccomp compensation daemon"};
  app.require_subcommand(1);
  app.set_version_flag("--version", "nccomp 0.1.0");
  for (const auto& entry : nccomp::tools::registered_commands()) {
    entry.setup(app);
  }
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  } catch (const nccomp::tools::CommandError& e) {
    std::cerr << "nccomp: error: " << e.what() << "\n";
    return e.code();
  } catch (const std::exception& e) {
    std::cerr << "nccomp: error: " << e.what() << "\n";
    return nccomp::tools::kExitFailure;
  }
  return nccomp::tools::kExitOk;
}
