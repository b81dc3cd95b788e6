// `nccomp publish` (docs/mqtt.md): a companion process of nccompd that publishes the measurement
// log's rows, the daemon's alarms and acknowledgements, model changes and a heartbeat to an MQTT
// broker, through a bounded queue on disk. It reads what the daemon has already written (the log
// files, the status socket) and never talks to the loop: a slow or absent broker cannot stall
// the daemon. Not real-time.
#pragma once

#include <atomic>
#include <cstdint>
#include <memory>
#include <set>
#include <string>

#include "tools/mqtt/disk_queue.hpp"
#include "tools/mqtt/log_source.hpp"
#include "tools/mqtt/mqtt_config.hpp"
#include "tools/mqtt/mqtt_link.hpp"
#include "tools/mqtt/status_digest.hpp"

namespace nccomp::tools::mqtt {

class Publisher {
 public:
  /// Opens the queue (throws std::runtime_error / std::system_error naming the file).
  Publisher(PublishConfig config, std::string password);
  ~Publisher();

  /// Runs until `stop` is set; returns the exit status.
  int run(const std::atomic<bool>& stop);

 private:
  void handle(const LinkEvent& e, std::int64_t now);
  void poll_log();
  void poll_status();
  void send();
  void heartbeat(bool online);
  void warn_every(const std::string& key, const std::string& text, std::int64_t now,
                  std::int64_t every_ns);

  PublishConfig config_;
  DiskQueue queue_;
  LogSource source_;
  StatusMemory memory_;
  std::unique_ptr<MqttLink> link_;
  std::set<std::uint64_t> in_flight_;
  bool connected_{false};
  std::int64_t next_connect_ns_{0};
  double backoff_s_{1.0};
  std::int64_t paused_until_ns_{0};
  std::int64_t next_log_ns_{0};
  std::int64_t next_status_ns_{0};
  std::int64_t next_heartbeat_ns_{0};
  std::uint64_t heartbeat_seq_{0};
  std::uint64_t published_{0};
  std::uint64_t refused_{0};
  std::uint64_t source_problems_{0};
  std::uint64_t last_dropped_{0};
  bool daemon_reachable_{false};
  std::string source_error_;
  nlohmann::ordered_json daemon_summary_ = nullptr;
  std::map<std::string, std::int64_t> last_warned_;
};

}  // namespace nccomp::tools::mqtt
