// `nccomp check-config FILE`: checks the file exactly as nccompd loads it, by running
// `nccompd --config FILE --check-config` (the daemon's loader: the file and its includes, every
// section, the cross-checks and the engine with its registers, modules and limits). Passes its
// output through: every error, the engine's refusals included, as
// file:line:column: key.path: message; exit status 3 on any error.
#include <iostream>
#include <memory>
#include <string>

#include "tools/daemonctl/nccompd_process.hpp"
#include "tools/nccomp/command.hpp"

namespace {

void setup(CLI::App& app) {
  auto* sub = app.add_subcommand("check-config", "Validate an nccompd configuration file");
  auto file = std::make_shared<std::string>();
  auto quiet = std::make_shared<bool>(false);
  sub->add_option("file", *file, "Configuration file (TOML)")->required();
  sub->add_flag("-q,--quiet", *quiet, "Print nothing when the file is valid");
  sub->callback([file, quiet] {
    const std::string summary = nccomp::tools::run_nccompd_config_flag(*file, "--check-config");
    if (!*quiet) {
      std::cout << summary;
    }
  });
}

}  // namespace

NCCOMP_REGISTER_COMMAND(check_config, setup);
