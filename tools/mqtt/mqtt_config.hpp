// The configuration of `nccomp publish` (config/nccomp-publish.toml, docs/mqtt.md) and the
// broker options `nccomp collect` shares with it. TOML read with formats/ TableReader: every
// error names file:line:column and key path, unknown keys and sections are refused.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>

#include "formats/toml/diagnostics.hpp"

namespace nccomp::tools::mqtt {

/// How to reach and log in to the broker.
struct BrokerOptions {
  /// tcp://host:port or mqtt://host:port; ssl://host:port or mqtts://host:port for TLS.
  std::string uri{"tcp://127.0.0.1:1883"};
  std::string client_id;
  std::string username;
  /// A file holding the password (first line); never the password itself in a config.
  std::string password_file;
  /// TLS: the CA certificate(s) the broker's certificate is checked against; client
  /// certificate and key for brokers that ask for them.
  std::string ca_file;
  std::string cert_file;
  std::string key_file;
  int keepalive_s{30};
  /// How long the broker keeps this client's session (its unacknowledged QoS 1 messages)
  /// while it is away [s].
  std::int64_t session_expiry_s{7 * 86400};
  int max_inflight{64};
  /// Reconnect back-off: 1 s, doubled after each failure, up to this [s].
  double reconnect_max_s{30.0};
};

struct PublishConfig {
  std::string site;
  std::string machine;
  double heartbeat_s{10.0};
  std::string log_directory{"/var/log/nccompd"};
  double log_poll_s{0.2};
  /// Empty: no status socket (no alarms, model or daemon status published).
  std::string status_socket{"/run/nccompd/status.sock"};
  double status_poll_s{1.0};
  BrokerOptions broker;
  std::string queue_directory{"/var/lib/nccomp-publish"};
  std::int64_t max_messages{3'600'000};
  double queue_fsync_interval_s{1.0};
};

/// Reads and validates the file; nullopt with every error in diag.
[[nodiscard]] std::optional<PublishConfig> load_publish_config(const std::string& path,
                                                               nccomp::formats::Diagnostics& diag);

/// Checks broker options that do not depend on a file position (the command line of `nccomp
/// collect`): an error message, or "" if they are fine.
[[nodiscard]] std::string check_broker(const BrokerOptions& b);

/// The password from `path`: its first line. Refused (std::runtime_error naming the file and the
/// fix) if other users may read or write the file, if it is not a regular file, or if it is empty.
[[nodiscard]] std::string read_password_file(const std::string& path);

/// "nccomp/<site>/<machine>/<what>".
[[nodiscard]] std::string topic(std::string_view site, std::string_view machine,
                                std::string_view what);

}  // namespace nccomp::tools::mqtt
