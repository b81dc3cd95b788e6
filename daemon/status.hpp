// Status: a Unix socket (mode 0660) answering `nccomp status` (text) and `nccomp status --json`,
// and an optional Prometheus text endpoint on a loopback TCP port. Reads the loop's seqlock
// snapshots and counters, never blocks the loop.
//
// Protocol on the Unix socket (client/protocol.hpp): the client sends one line, "text", "json" or
// "metrics", or an operator command (daemon/commands/command.hpp); the daemon answers and closes
// the connection. The client side is client/status_client.hpp.
//
// Threads: one I/O thread multiplexes every client with poll(): non-blocking reads and writes,
// each client with a deadline (client_timeout_s for its request, the same again for taking the
// answer) after which it is cut off, at most max_clients at once (more are answered "busy").
// Status requests are answered on the I/O thread (rendering reads snapshots only); operator
// commands, which wait for the loop, run one at a time on a command thread. So no client, slow
// or waiting for a command, delays another's status.
#pragma once

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <mutex>
#include <span>
#include <string>
#include <string_view>
#include <thread>
#include <utility>
#include <vector>

#include "core/engine/engine.hpp"
#include "daemon/commands/command.hpp"
#include "daemon/logging.hpp"
#include "daemon/loop.hpp"
#include "daemon/measurement_log.hpp"
#include "daemon/sections/model/shadow.hpp"
#include "daemon/state_store.hpp"
#include "drivers/bus.hpp"

namespace nccomp::daemon {

/// What the status server counts about its clients (any thread may read).
struct StatusServerCounters {
  std::atomic<std::uint64_t> clients{0};       // connections accepted
  std::atomic<std::uint64_t> timed_out{0};     // cut off at their deadline
  std::atomic<std::uint64_t> turned_away{0};   // refused: max_clients, or commands queued
  std::atomic<std::uint64_t> bad_requests{0};  // too long, unknown, or not GET /metrics
};

struct StatusContext {
  const Loop* loop{nullptr};
  std::vector<std::pair<std::string, const drivers::Bus*>> buses;
  const EventLogger* logger{nullptr};
  const StatePersister* persister{nullptr};
  const MeasurementLogWriter* measurement_log{nullptr};
  /// Thread-safe providers (the configuration can be reloaded while status runs).
  std::function<std::vector<std::string>()> register_names;
  /// Each register's kind and limiter limits, in index order (empty: not shown).
  std::function<std::vector<core::engine::RegisterSpec>()> register_specs;
  std::function<std::string()> state_problem;  // empty when the state is fine
  /// The models' scores in shadow (unset: not shown).
  std::function<sections::ShadowStatus()> shadow;
  /// The live model, the one kept for rollback (unset: not shown).
  std::function<ModelState()> model;
  std::string config_path;
  std::string state_path;
  /// The server's own counters (set by StatusServer; null: not shown).
  const StatusServerCounters* server{nullptr};
};

struct StatusServerOptions {
  std::string socket_path;
  std::string prometheus_address{"127.0.0.1"};
  /// 0 = no Prometheus endpoint; -1 = any free port (tests).
  int prometheus_port{0};
  /// Who may run operator commands that change the machine.
  CommandPolicy policy;
  /// A client's time for its request (from its connection on), and again for taking its
  /// answer; then it is cut off [s].
  double client_timeout_s{2.0};
  /// Clients served at once, Unix socket and HTTP together; more are answered "busy".
  int max_clients{32};
};

[[nodiscard]] std::string render_json(const StatusContext& c);
[[nodiscard]] std::string render_text(const StatusContext& c);
/// The Prometheus text format (version 0.0.4); `promtool check metrics` passes on it.
[[nodiscard]] std::string render_prometheus(const StatusContext& c);
/// The estimate key a status key `<stem>_sigma_um` is the σ of in nccompd_module_sigma_meters:
/// `<stem>_estimate_um` (S0's wear_sigma_um: wear_estimate_um), and for a stem that already ends
/// in `_estimate` the stem with `_um` (S3's x_estimate_sigma_um: x_estimate_um); empty for
/// another key (exposed for tests).
[[nodiscard]] std::string sigma_estimate_key(std::string_view key);
/// The input_lags module's key `sensor_N_lag` / `sensor_N_input`: {"N", "lag" or "input"};
/// empty strings for another key (exposed for tests).
[[nodiscard]] std::pair<std::string, std::string> input_lag_key(std::string_view key);
/// The input_sums module's key `sensor_N_sum`: "N"; empty for another key (exposed for tests).
[[nodiscard]] std::string input_sum_key(std::string_view key);
/// The `le` edges [µs] of nccompd_loop_wake_latency_seconds (exposed for tests).
[[nodiscard]] std::span<const std::uint64_t> prometheus_latency_edges_us();
[[nodiscard]] const char* link_state_name(drivers::LinkState s);

class StatusServer {
 public:
  explicit StatusServer(StatusContext context);
  ~StatusServer();
  StatusServer(const StatusServer&) = delete;
  StatusServer& operator=(const StatusServer&) = delete;
  /// Binds the socket (and the TCP port if prometheus_port != 0) and starts the threads. Throws
  /// std::system_error.
  void start(const StatusServerOptions& options);
  /// Closes every connection; waits for a command in progress (at most its handler's timeout).
  void stop();
  /// The TCP port actually bound (useful with port -1 in tests); 0 if none.
  [[nodiscard]] int prometheus_port() const noexcept { return bound_port_; }
  [[nodiscard]] const StatusServerCounters& counters() const noexcept { return counters_; }

 private:
  struct Client;
  struct Job {
    std::uint64_t client{0};
    std::string line;
    Caller caller;
  };
  void run();
  void run_commands();
  void accept_clients(int listen_fd, bool http, std::vector<Client>& clients);
  void read_request(Client& c);
  void start_answer(Client& c, std::string text);
  void answer(Client& c);
  void take_finished(std::vector<Client>& clients);

  StatusContext context_;
  StatusServerOptions options_;
  StatusServerCounters counters_;
  int unix_fd_{-1};
  int tcp_fd_{-1};
  int wake_fd_{-1};  // eventfd: the command thread has finished a command
  int bound_port_{0};
  std::uint64_t next_client_{1};
  std::size_t commands_in_flight_{0};  // I/O thread only
  std::atomic<bool> stop_{false};
  std::thread thread_;
  std::thread command_thread_;
  std::mutex jobs_mu_;
  std::condition_variable jobs_cv_;
  std::deque<Job> jobs_;
  std::vector<std::pair<std::uint64_t, std::string>> finished_;
};

}  // namespace nccomp::daemon
