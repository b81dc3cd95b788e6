// Status: a Unix socket (mode 0660) answering `nccomp status` (text) and `nccomp status --json`,
// and an optional Prometheus text endpoint on a loopback TCP port. Runs on its own thread; reads
// the loop's seqlock snapshots and counters, never blocks the loop.
//
// Protocol on the Unix socket: the client sends one line, "text", "json" or "metrics"; the
// daemon answers and closes the connection.
#pragma once

#include <atomic>
#include <functional>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "daemon/logging.hpp"
#include "daemon/loop.hpp"
#include "daemon/measurement_log.hpp"
#include "daemon/state_store.hpp"
#include "drivers/bus.hpp"

namespace nccomp::daemon {

struct StatusContext {
  const Loop* loop{nullptr};
  std::vector<std::pair<std::string, const drivers::Bus*>> buses;
  const EventLogger* logger{nullptr};
  const StatePersister* persister{nullptr};
  const MeasurementLogWriter* measurement_log{nullptr};
  /// Thread-safe providers (the configuration can be reloaded while status runs).
  std::function<std::vector<std::string>()> register_names;
  std::function<std::string()> state_problem;  // empty when the state is fine
  std::string config_path;
  std::string state_path;
};

[[nodiscard]] std::string render_json(const StatusContext& c);
[[nodiscard]] std::string render_text(const StatusContext& c);
[[nodiscard]] std::string render_prometheus(const StatusContext& c);
[[nodiscard]] const char* link_state_name(drivers::LinkState s);

class StatusServer {
 public:
  explicit StatusServer(StatusContext context) : context_(std::move(context)) {}
  ~StatusServer();
  /// Binds the socket (and the TCP port if prometheus_port > 0). Throws std::system_error.
  void start(const std::string& socket_path, const std::string& prometheus_address,
             int prometheus_port);
  void stop();
  /// The TCP port actually bound (useful with port 0 in tests); 0 if none.
  [[nodiscard]] int prometheus_port() const noexcept { return bound_port_; }

 private:
  void run();
  void serve_unix(int fd);
  void serve_http(int fd);

  StatusContext context_;
  std::string socket_path_;
  int unix_fd_{-1};
  int tcp_fd_{-1};
  int bound_port_{0};
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

/// Client side (`nccomp status`): sends request, returns the answer. Throws std::system_error.
[[nodiscard]] std::string query_status(const std::string& socket_path, const std::string& request);

}  // namespace nccomp::daemon
