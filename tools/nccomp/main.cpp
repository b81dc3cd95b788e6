// nccomp — the operator's command: plan, grind-path, calibrate, analyze, check-config, status, …
// Each subcommand registers itself (tools/nccomp/command.hpp).
// Exit status (every subcommand): 0 done (also --help, --version); 1 a failure (a file that
// cannot be written, no daemon); 2 a usage error; 3 invalid input; a subcommand may add its own
// (nccomp(1)).
#include <CLI/CLI.hpp>

#include <exception>
#include <iostream>
#include <string>

#include "nccomp_version.hpp"
#include "tools/nccomp/command.hpp"

int main(int argc, char** argv) {
  CLI::App app{"nccomp — operator command of the nccomp compensation daemon"};
  app.require_subcommand(1);
  app.set_version_flag("--version", std::string("nccomp ") + nccomp::kVersion);
  for (const auto& entry : nccomp::tools::registered_commands()) {
    entry.setup(app);
  }
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    // --help prints and exits 0; CLI11's own codes for usage errors are 100+.
    return app.exit(e) == nccomp::tools::kExitOk ? nccomp::tools::kExitOk
                                                 : nccomp::tools::kExitUsage;
  } catch (const nccomp::tools::CommandError& e) {
    std::cerr << "nccomp: error: " << e.what() << "\n";
    return e.code();
  } catch (const std::exception& e) {
    std::cerr << "nccomp: error: " << e.what() << "\n";
    return nccomp::tools::kExitFailure;
  }
  return nccomp::tools::kExitOk;
}
