// `nccomp check-config FILE`: loads the file and its includes exactly as nccompd does, parses
// every section, cross-checks references and builds the engine (registers, modules, limits).
// Prints every error, the engine's refusals included, as file:line:column: key.path: message;
// exit status 3 on any error.
#include <iostream>
#include <string>

#include "daemon/config/builtin_sections.hpp"
#include "daemon/config/config.hpp"
#include "tools/nccomp/command.hpp"

namespace {

void setup(CLI::App& app) {
  auto* sub = app.add_subcommand("check-config", "Validate an nccompd configuration file");
  auto file = std::make_shared<std::string>();
  auto quiet = std::make_shared<bool>(false);
  sub->add_option("file", *file, "Configuration file (TOML)")->required();
  sub->add_flag("-q,--quiet", *quiet, "Print nothing when the file is valid");
  sub->callback([file, quiet] {
    namespace cfg = nccomp::daemon::config;
    auto result = cfg::load_file(*file);
    if (result.config) {
      // Engine-level refusals (e.g. two modules writing one register) are reported like every
      // other error: file:line:column: key.path: message.
      auto engine = cfg::build_engine(*result.config, result.diagnostics);
      if (engine) {
        if (!*quiet) {
          std::cout << *file << ": OK\n  files:";
          for (const auto& f : result.config->files()) {
            std::cout << " " << f;
          }
          std::cout << "\n  sections:";
          for (const auto& s : result.config->section_names()) {
            std::cout << " " << s;
          }
          const auto& d = cfg::daemon_section(*result.config);
          std::cout << "\n  loop: " << d.rate_hz << " Hz" << (d.dry_run ? " (dry run)" : "")
                    << "\n  registers: " << engine->register_count()
                    << "\n  modules: " << engine->module_count();
          for (std::size_t i = 0; i < engine->module_count(); ++i) {
            std::cout << (i == 0 ? " (" : ", ") << engine->module(i).name();
          }
          std::cout << (engine->module_count() > 0 ? ")" : "") << "\n";
        }
        return;
      }
    }
    std::cerr << result.diagnostics.to_string();
    throw nccomp::tools::CommandError(
        nccomp::tools::kExitInvalidInput,
        std::to_string(result.diagnostics.items().size()) + " error(s) in " + *file);
  });
}

}  // namespace

NCCOMP_REGISTER_COMMAND(check_config, setup);
