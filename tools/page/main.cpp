// nccomp-page: the operator's web page of one nccompd (docs/operator-page.md). A process of its
// own beside the daemon: it reads the daemon's status socket, never the loop, and serves the
// page on 127.0.0.1 unless told otherwise.
// Exit status: 0 stopped by SIGTERM / SIGINT (also --help, --version); 1 cannot listen; 2 a
// usage error (an unknown option, a bad --listen).
#include <arpa/inet.h>
#include <signal.h>

#include <CLI/CLI.hpp>
#include <chrono>
#include <cstdio>
#include <ctime>
#include <mutex>
#include <string>
#include <thread>

#include "client/protocol.hpp"
#include "client/status_client.hpp"
#include "nccomp_version.hpp"
#include "tools/page/page_server.hpp"
#include "tools/page/page_service.hpp"
#include "tools/page/peer_identity.hpp"

namespace {

std::mutex log_mutex;

void log_line(std::string_view level, const std::string& line) {
  const auto now = std::chrono::system_clock::now();
  const std::time_t t = std::chrono::system_clock::to_time_t(now);
  const auto ms =
      std::chrono::duration_cast<std::chrono::milliseconds>(now.time_since_epoch()).count() % 1000;
  std::tm tm{};
  ::gmtime_r(&t, &tm);
  char stamp[32];
  std::strftime(stamp, sizeof stamp, "%Y-%m-%d %H:%M:%S", &tm);
  const std::lock_guard lock(log_mutex);
  std::fprintf(stderr, "%s.%03d %.*s %s\n", stamp, static_cast<int>(ms),
               static_cast<int>(level.size()), level.data(), line.c_str());
  std::fflush(stderr);
}

// "HOST:PORT" with HOST an IPv4 address; false with the reason in why.
bool split_listen(const std::string& listen, std::string& host, int& port, std::string& why) {
  const auto colon = listen.rfind(':');
  if (colon == std::string::npos) {
    why = "--listen '" + listen + "': expected ADDRESS:PORT, e.g. 127.0.0.1:8470";
    return false;
  }
  host = listen.substr(0, colon);
  in_addr a{};
  if (::inet_pton(AF_INET, host.c_str(), &a) != 1) {
    why = "--listen '" + listen + "': '" + host + "' is not an IPv4 address";
    return false;
  }
  try {
    std::size_t used = 0;
    port = std::stoi(listen.substr(colon + 1), &used);
    if (used != listen.size() - colon - 1 || port < 0 || port > 65535) throw std::out_of_range("");
  } catch (const std::exception&) {
    why = "--listen '" + listen + "': the port must be 0..65535";
    return false;
  }
  return true;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"nccomp-page — the operator's web page of nccompd (docs/operator-page.md)"};
  app.set_version_flag("--version", std::string("nccomp-page ") + nccomp::kVersion);
  std::string listen = "127.0.0.1:8470";
  std::string socket_path{nccomp::client::kDefaultSocketPath};
  nccomp::page::PageOptions options;
  int max_watchers = 8;
  app.add_option("-l,--listen", listen, "ADDRESS:PORT to serve the page on (port 0: any free)")
      ->capture_default_str();
  app.add_option("-s,--socket", socket_path, "nccompd's status socket")->capture_default_str();
  app.add_option("--admin-group", options.admin_group,
                 "Who may act through the page (acknowledge, model promote / rollback): root and "
                 "this group (as nccompd's "
                 "[status] admin_group)")
      ->capture_default_str();
  app.add_option("--report-dir", options.report_dir,
                 "The latest analysis report (nccomp analyze --out DIR) to show");
  app.add_flag("--remote-actions", options.remote_actions,
               "Listening beyond this host: let clients on other hosts act (no user can "
               "be checked for them)");
  app.add_option("--poll-interval-s", options.poll_interval_s,
                 "Status requests to nccompd while a page watches [s]")
      ->capture_default_str()
      ->check(CLI::Range(0.05, 10.0));
  app.add_option("--max-watchers", max_watchers, "Pages watching at once")
      ->capture_default_str()
      ->check(CLI::Range(1, 64));
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    // --help prints and exits 0; CLI11's own codes for usage errors are 100+.
    return app.exit(e) == 0 ? 0 : 2;
  }

  std::string host;
  int port = 0;
  std::string why;
  if (!split_listen(listen, host, port, why)) {
    std::fprintf(stderr, "nccomp-page: error: %s\n", why.c_str());
    return 2;
  }
  const bool loopback = nccomp::page::is_loopback_ipv4(host);
  options.actions = loopback || options.remote_actions;

  // Signals to one thread: blocked before any thread starts, taken by sigwait below.
  sigset_t stop_signals;
  sigemptyset(&stop_signals);
  sigaddset(&stop_signals, SIGTERM);
  sigaddset(&stop_signals, SIGINT);
  pthread_sigmask(SIG_BLOCK, &stop_signals, nullptr);
  ::signal(SIGPIPE, SIG_IGN);

  nccomp::page::PageServer server(max_watchers);
  try {
    port = server.bind(host, port);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "nccomp-page: error: %s\n", e.what());
    return 1;
  }
  if (loopback) {
    const std::string p = std::to_string(port);
    options.allowed_hosts = {host + ":" + p, "localhost:" + p, "127.0.0.1:" + p};
  }
  const std::string admin_group = options.admin_group;
  nccomp::page::PageDeps deps;
  deps.query = [socket_path](std::string_view request) {
    return nccomp::client::query(socket_path, request);
  };
  deps.client_uid = nccomp::page::loopback_client_uid;
  deps.permission = [admin_group](uid_t uid) {
    return nccomp::page::may_change_machine(uid, admin_group);
  };
  deps.log = log_line;
  nccomp::page::PageService service(options, deps);
  service.start();

  log_line("info", "nccomp-page listening on http://" + host + ":" + std::to_string(port) +
                       "/, nccompd's status socket " + socket_path);
  if (options.actions) {
    log_line("info", loopback
                         ? "actions (acknowledge, model promote / rollback): root and group '" +
                               admin_group + "' (the user owning the browser's connection)"
                         : "actions: from any host (--remote-actions); users on this "
                           "host: root and group '" +
                               admin_group + "'");
  } else {
    log_line("warning", "actions are off: the page listens on " + host +
                            ", beyond this host (--remote-actions turns it on)");
  }

  std::thread signals([&] {
    int sig = 0;
    sigwait(&stop_signals, &sig);
    log_line("info", std::string("stopping (") + (sig == SIGINT ? "SIGINT" : "SIGTERM") + ")");
    service.stop();
    server.stop();
  });
  server.serve(service);
  // serve() also returns if the listener fails: wake the signal thread to end.
  ::kill(::getpid(), SIGTERM);
  signals.join();
  log_line("info", "stopped: " + std::to_string(service.actions_done()) + " action(s) done, " +
                       std::to_string(service.actions_refused()) + " refused, " +
                       std::to_string(service.bad_requests()) + " bad request(s)");
  return 0;
}
