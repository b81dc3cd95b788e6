// The sections the daemon itself defines: [daemon], [state], [log], [measurement_log], [status],
// [[registers]], [[ramp]], [loopback]. Their keys are documented in docs/config.md and, with a
// comment above each, in config/nccompd.toml.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "core/engine/engine.hpp"
#include "core/engine/ramp_module.hpp"
#include "daemon/config/config.hpp"
#include "formats/measurement_log/measurement_log.hpp"

namespace nccomp::daemon::config {

enum class OverrunPolicy : std::uint8_t {
  /// Keep the phase: skip the missed deadlines, wake at the next one on the original grid.
  kSkipMissed = 0,
  /// Restart the grid one period after the late wake-up.
  kRestart = 1,
};

struct DaemonSection final : Section {
  double rate_hz{1000.0};
  bool dry_run{false};
  std::size_t max_events_per_cycle{256};
  OverrunPolicy overrun_policy{OverrunPolicy::kSkipMissed};
  /// 0 = SCHED_OTHER (no real-time priority).
  int sched_fifo_priority{0};
  std::vector<int> cpu_affinity;
  bool lock_memory{false};
  std::size_t prefault_stack_kib{0};
};

struct StateSection final : Section {
  /// Empty = $STATE_DIRECTORY (systemd) or /var/lib/nccompd.
  std::string directory;
  double min_interval_s{0.5};
};

struct LogSection final : Section {
  std::string level{"info"};
  /// "auto" (journald when started by systemd), "journal", "terminal".
  std::string target{"auto"};
};

struct MeasurementLogSection final : Section {
  bool enabled{true};
  /// Empty = $LOGS_DIRECTORY (systemd) or /var/log/nccompd.
  std::string directory;
  std::uint64_t max_file_bytes{16U * 1024U * 1024U};
  int keep_files{8};
  /// Rows reach the disk (fdatasync) at least this often [s]; 0 = every batch.
  double fsync_interval_s{1.0};
  /// The log's `machine` column (and the MQTT topics'); empty = the host name.
  std::string machine_id;
  /// Context columns after the v2 columns: a name and the sensor channel whose value is logged.
  std::vector<formats::measurement_log::ContextColumn> context_columns;
  /// [measurement_log.face_probe]: probe readings of the finished face as contour rows. Empty
  /// points = off; the registers are resolved by name when the daemon starts.
  bool has_face_probe{false};
  std::vector<std::array<double, 2>> face_probe_points_mm;
  double face_probe_capture_radius_mm{1.0};
  double face_probe_ball_radius_mm{0.0};
  std::string face_probe_length_register;
  std::string face_probe_radius_register;
  formats::Where face_probe_length_where;
  formats::Where face_probe_radius_where;
};

struct StatusSection final : Section {
  /// Empty = $RUNTIME_DIRECTORY/status.sock (systemd) or /run/nccompd/status.sock.
  std::string socket_path;
  /// 0 = no Prometheus endpoint.
  int prometheus_port{0};
  std::string prometheus_address{"127.0.0.1"};
  /// Members may run operator commands that change the machine (acknowledge, warm-start,
  /// calibrate ...); status is for everyone who can open the socket.
  std::string admin_group{"nccomp-admin"};
  /// A client's time for its request, and again for taking its answer [s].
  double client_timeout_s{2.0};
  /// Status clients served at once (Unix socket and Prometheus together).
  int max_clients{32};
};

struct RegisterEntry {
  core::engine::RegisterSpec spec;
  /// Name of the bus section that takes this register's writes.
  std::string bus;
  formats::Where where;
};

struct RegistersSection final : Section {
  std::vector<RegisterEntry> registers;
};

struct RampEntry {
  core::engine::RampConfig config;
  formats::Where where;
};

struct RampSection final : Section {
  std::vector<RampEntry> ramps;
};

struct InputLagEntry {
  core::engine::InputLagSpec spec;
  formats::Where where;
};

/// [[input_lags]]: derived sensors, the first-order lag of a sensor (core/engine/input_lag.hpp).
struct InputLagsSection final : Section {
  std::vector<InputLagEntry> lags;
};

struct InputSumEntry {
  core::engine::InputSumSpec spec;
  formats::Where where;
  formats::Where sensor_where;
};

/// [[input_sums]]: derived sensors, offset + a weighted sum of sensors
/// (core/engine/input_sum.hpp).
struct InputSumsSection final : Section {
  std::vector<InputSumEntry> sums;
};

struct LoopbackSection final : Section {
  std::size_t rx_capacity{1024};
  std::size_t tx_capacity{1024};
};

/// Typed accessors with defaults (the parsers' absent() values).
const DaemonSection& daemon_section(const Config& c);
const StateSection& state_section(const Config& c);
const LogSection& log_section(const Config& c);
const MeasurementLogSection& measurement_log_section(const Config& c);
const StatusSection& status_section(const Config& c);
const RegistersSection& registers_section(const Config& c);

/// Builds a configured engine from the config: the registers, every section's modules. Not
/// real-time. Throws std::invalid_argument with the engine's message.
std::unique_ptr<core::engine::Engine> build_engine(const Config& c);

/// The same, for `nccomp check-config` and nccompd: an engine refusal (e.g. two modules writing
/// one register) is reported to diag at the file, line and key it concerns (the key of the module
/// section that names the register, and where the other one is), and nullptr is returned.
std::unique_ptr<core::engine::Engine> build_engine(const Config& c, formats::Diagnostics& diag);

}  // namespace nccomp::daemon::config
