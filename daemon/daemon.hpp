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
  /// --lockstep SOCKET: run in lock-step with a simulated NC listening on this Unix socket
  /// (docs/daemon.md, "Lock-step with ncsim"). Empty = the normal fixed-rate loop.
  std::string lockstep_socket;
  /// How long to keep trying to connect to the lock-step socket [s].
  double lockstep_connect_timeout_s{10.0};
};

/// Runs until SIGTERM / SIGINT (in lock-step also until the peer's BYE or close). Returns the process exit status: 0 after a clean stop, 3 for an
/// invalid configuration, 1 for any other start-up failure.
int run_daemon(const DaemonOptions& options);

}  // namespace nccomp::daemon
