// nccompd — the compensation daemon. See docs/daemon.md and nccompd(8).
// Exit status: 0 stopped by a signal (or the lock-step peer's BYE), also after --help and
// --version; 1 a start-up or run-time failure; 2 a usage error (an unknown option, a missing
// value); 3 an invalid configuration.
#include <CLI/CLI.hpp>

#include <string>

#include "daemon/daemon.hpp"
#include "nccomp_version.hpp"

int main(int argc, char** argv) {
  CLI::App app{"nccompd — real-time compensation daemon for CNC machine tools"};
  nccomp::daemon::DaemonOptions options;
  app.add_option("-c,--config", options.config_path, "Configuration file (TOML)")
      ->capture_default_str();
  app.add_flag("--dry-run", options.dry_run, "Compute and log everything, write nothing to the NC");
  app.add_option("--lockstep", options.lockstep_socket,
                 "Lock-step with a simulated NC (ncsim --lockstep SOCKET): its TICKs drive the "
                 "loop; exits 0 when it says BYE or closes the socket");
  auto* check =
      app.add_flag("--check-config", options.check_config,
                   "Check the configuration as a start would (every section, the cross-checks, the "
                   "engine), print every error and exit 0 or 3; touches no bus and no state");
  app.add_flag("--print-status-socket", options.print_status_socket,
               "Print the configuration's status socket path and exit")
      ->excludes(check);
  app.set_version_flag("--version", std::string("nccompd ") + nccomp::kVersion);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    // --help / --version print and exit 0; CLI11's own codes for usage errors are 100+.
    return app.exit(e) == 0 ? 0 : 2;
  }
  if (options.check_config) {
    return nccomp::daemon::check_config(options);
  }
  if (options.print_status_socket) {
    return nccomp::daemon::print_status_socket(options);
  }
  return nccomp::daemon::run_daemon(options);
}
