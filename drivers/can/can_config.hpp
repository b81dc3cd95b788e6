// The [can] section of a config file: interface, timing and the signal map (can_mapping.hpp).
// Read with formats/ TableReader: unknown keys are errors, every error of a map is reported (not
// only the first), each naming file:line:column and key path in the one wording of formats/.
// Not real-time (allocates).
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>

#include <toml++/toml.h>

#include "drivers/can/can_mapping.hpp"
#include "formats/toml/diagnostics.hpp"

namespace nccomp::drivers::can {

/// How the daemon gets out of bus-off.
enum class RestartMode : std::uint8_t {
  kKernel = 0,  // the interface's restart-ms does it; the driver waits for the restart frame
  kDaemon = 1,  // the driver asks for a restart (netlink IFLA_CAN_RESTART) after restart_delay_s
};

struct CanConfig {
  /// Network interface, e.g. "can0" or "vcan0".
  std::string interface { "can0" };
  RestartMode restart{RestartMode::kKernel};
  /// Bus-off → daemon restart request delay [s]; the first wait of the restart back-off, which
  /// doubles per further request or bus-off up to reconnect_max_s.
  double restart_delay_s{0.1};
  /// Time to wait for an offset write's acknowledge before re-sending it [s].
  double ack_timeout_s{0.05};
  /// Re-sends after the first attempt before the write is given up (alarm).
  std::uint32_t ack_retries{3};
  /// First back-off after ENOBUFS (transmit queue full); doubles up to 64 × [s].
  double enobufs_backoff_s{0.0005};
  /// While the interface is down: how often its state is checked [s]; also the first wait before
  /// the driver rebinds after the interface went down, which doubles per further loss or failed
  /// rebind up to reconnect_max_s.
  double link_check_s{0.05};
  /// Cap of both back-offs [s] (a restart_delay_s or link_check_s above it is not doubled) ...
  double reconnect_max_s{5.0};
  /// ... which return to their first wait once the bus stayed up (not down, not bus-off) this
  /// long [s]; at least reconnect_max_s.
  double reconnect_reset_after_s{10.0};
  /// The interface down or the controller bus-off for longer than this raises the status alarm
  /// (cleared when the bus is back) [s].
  double alarm_after_s{1.0};
  /// The link not up (error-passive, down, bus-off), or no valid axis sample while the map has
  /// axis frames, for longer than this: the input is stale (BusStatus::input_stale) [s].
  double degraded_alarm_after_s{5.0};
  /// Capacity of the decoded-event ring (power of two) and of the offset-write ring.
  std::uint32_t rx_ring_events{4096};
  std::uint32_t tx_ring_writes{256};
  /// Kernel socket receive buffer [bytes]; 0 keeps the system default.
  std::uint32_t socket_rcvbuf_bytes{0};
  CanMapping mapping;
};

/// Reads an already parsed [can] table (the daemon's config loader hands it over), reporting every
/// error to `diag` (file:line:column, key path; errors on nodes without a source path name
/// `file`); nullopt if there was one. Validates the mapping.
std::optional<CanConfig> read_can_table(const toml::table& can, std::string_view file,
                                        formats::Diagnostics& diag);
/// The same, throwing formats::DiagnosticsError (every error, one per line).
CanConfig parse_can_table(const toml::table& can, const std::string& file_name);
/// Parses the [can] table of TOML text (other top-level tables are ignored: they belong to
/// other parts of the daemon). file names the source in messages. Throws
/// formats::DiagnosticsError.
CanConfig parse_can_config(std::string_view toml_text, const std::string& file);
/// Reads and parses a file. Throws formats::DiagnosticsError (also if it cannot be read).
CanConfig load_can_config(const std::string& path);

}  // namespace nccomp::drivers::can
