// nccompd's process: configuration → buses → engine → loop thread, plus the logger, state,
// measurement-log and status threads; systemd notify / watchdog; signals (SIGTERM, SIGINT stop,
// SIGHUP reloads). Not real-time: this is the main thread.
#pragma once

#include <string>

namespace nccomp::daemon {

struct DaemonOptions {
  std::string config_path{"/etc/nccompd/nccompd.toml"};
  /// --dry-run: compute and log everything, write nothing to the NC (ORed with the config).
  bool dry_run{false};
};

/// Runs until SIGTERM / SIGINT. Returns the process exit status: 0 after a clean stop, 3 for an
/// invalid configuration, 1 for any other start-up failure.
int run_daemon(const DaemonOptions& options);

}  // namespace nccomp::daemon
