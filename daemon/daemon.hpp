// nccompd's process: configuration → buses → engine → loop thread, plus the logger, state,
// measurement-log and status threads; systemd notify / watchdog; signals (SIGTERM, SIGINT stop,
// SIGHUP reloads). Not real-time: this is the main thread.
#pragma once

#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "core/common/types.hpp"
#include "core/engine/engine.hpp"

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
  /// --check-config: check the configuration (check_config()) instead of running.
  bool check_config{false};
  /// --print-status-socket: print the status socket's path (print_status_socket()) and exit.
  bool print_status_socket{false};
};

/// Runs until SIGTERM / SIGINT (in lock-step also until the peer's BYE or close). Returns the
/// process exit status: 0 after a clean stop, 3 for an invalid configuration, 1 for any other
/// start-up failure.
int run_daemon(const DaemonOptions& options);

/// Loads the configuration as run_daemon() does (the file and its includes, every section, the
/// cross-checks) and builds the engine; touches no bus, no state and no socket. Prints a summary
/// ("FILE: OK", files, sections, loop rate, registers, modules) and returns 0, or prints every
/// error as "file:line:column: key.path: message" and "nccompd: N error(s) in FILE" last on
/// standard error and returns 3 (`nccomp check-config` runs this).
int check_config(const DaemonOptions& options);

/// Prints the path of the status socket the configuration gives ([status] socket_path, else in
/// $RUNTIME_DIRECTORY, else /run/nccompd/status.sock) and returns 0; 3 with the errors as
/// check_config() when the configuration does not load (`nccomp status --config FILE`).
int print_status_socket(const DaemonOptions& options);

/// Reads a logical register's value [µm] back from the NC; nullopt when the bus cannot.
using RegisterReader = std::function<std::optional<double>(std::uint16_t register_index)>;
/// Start-up work of a config section, run once after the state was restored and the buses were
/// started, before the loop thread steps the engine (S1: compare the NC's checkpoint registers
/// with the learned table). Returns lines for the log. Not real-time.
using StartupHook = std::function<std::vector<std::string>(
    core::engine::Engine& engine, const RegisterReader& read, core::TimeNs now_ns)>;
/// Registers a hook (static initialisation of a section's object file).
int register_startup_hook(std::string name, StartupHook hook);
/// The registered hooks, in registration order.
[[nodiscard]] const std::vector<std::pair<std::string, StartupHook>>& startup_hooks();

}  // namespace nccomp::daemon
