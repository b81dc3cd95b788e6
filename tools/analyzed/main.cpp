// nccomp-analyzed: re-runs the analysis of `nccomp analyze` on nccompd's measurement log when
// enough new rows have come in, and hands a better model to the daemon as a candidate in shadow
// (docs/analyzed.md). A process of its own beside the daemon (systemd/nccomp-analyzed.service):
// it reads the log files and the status socket, never the loop, and keeps off the loop's CPU.
// Exit status: 0 stopped by SIGTERM / SIGINT (also --help, --version, --check of a good
// configuration); 1 cannot start (the work directory); 2 a usage error; 3 a bad configuration.
#include <sched.h>
#include <signal.h>

#include <CLI/CLI.hpp>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <fstream>
#include <memory>
#include <sstream>
#include <stdexcept>
#include <string>

#include "client/status_client.hpp"
#include "formats/model/model_io.hpp"
#include "formats/toml/diagnostics.hpp"
#include "nccomp_version.hpp"
#include "tools/analyzed/analyzed_config.hpp"
#include "tools/analyzed/service.hpp"

namespace {

// One line per event on stderr: the journal under systemd, which takes the sd-daemon(3) prefix
// as the line's priority (journalctl -p warning shows the warnings and errors).
void log_line(std::string_view level, const std::string& line) {
  static const bool journal = std::getenv("JOURNAL_STREAM") != nullptr;
  const char* prefix = !journal             ? ""
                       : level == "error"   ? "<3>"
                       : level == "warning" ? "<4>"
                                            : "<6>";
  std::fprintf(stderr, "%s%.*s %s\n", prefix, static_cast<int>(level.size()), level.data(),
               line.c_str());
  std::fflush(stderr);
}

// Every CPU but `avoid`; logged, and a failure is a warning (the unit's CPUAffinity= may hold).
void keep_off_cpus(const std::vector<int>& avoid) {
  if (avoid.empty()) return;
  cpu_set_t set;
  CPU_ZERO(&set);
  if (::sched_getaffinity(0, sizeof set, &set) != 0) {
    log_line("warning", "cannot read the CPU affinity; avoid_cpus not applied");
    return;
  }
  for (const int cpu : avoid) CPU_CLR(static_cast<std::size_t>(cpu), &set);
  std::string on;
  for (std::size_t cpu = 0; cpu < CPU_SETSIZE; ++cpu) {
    if (CPU_ISSET(cpu, &set)) on += (on.empty() ? "" : ",") + std::to_string(cpu);
  }
  if (on.empty()) {
    log_line("warning", "avoid_cpus leaves no CPU this process may use: not applied");
  } else if (::sched_setaffinity(0, sizeof set, &set) != 0) {
    log_line("warning", "cannot set the CPU affinity to " + on + ": avoid_cpus not applied");
  } else {
    log_line("info", "running on CPUs " + on + " (avoid_cpus)");
  }
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "nccomp-analyzed — continuous analysis of nccompd's log, candidates in shadow "
      "(docs/analyzed.md)"};
  app.set_version_flag("--version", std::string("nccomp-analyzed ") + nccomp::kVersion);
  std::string config_path = "/etc/nccompd/nccomp-analyzed.toml";
  bool check = false;
  bool once = false;
  app.add_option("-c,--config", config_path, "The configuration")->capture_default_str();
  app.add_flag("--check", check,
               "Check the configuration and the analysis's model config, and exit");
  app.add_flag("--once", once, "Take the new rows, run if enough came in, and exit");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e) == 0 ? 0 : 2;
  }
  nccomp::formats::Diagnostics diag;
  const auto config = nccomp::tools::analyzed::load_analyzed_config(config_path, diag);
  if (!config) {
    std::fprintf(stderr, "%s", diag.to_string().c_str());
    return 3;
  }
  if (check) {
    // The analysis's model config is read again at every run (the operator may edit it).
    try {
      std::ifstream in(config->analysis_config, std::ios::binary);
      if (!in) throw std::runtime_error(config->analysis_config + ": cannot open");
      std::stringstream text;
      text << in.rdbuf();
      (void)nccomp::formats::model_io::read_model_text(text.str(), config->analysis_config, false);
    } catch (const std::exception& e) {
      std::fprintf(stderr, "%s\n", e.what());
      return 3;
    }
    std::printf("%s: ok\n", config_path.c_str());
    return 0;
  }

  sigset_t stop_signals;
  sigemptyset(&stop_signals);
  sigaddset(&stop_signals, SIGTERM);
  sigaddset(&stop_signals, SIGINT);
  pthread_sigmask(SIG_BLOCK, &stop_signals, nullptr);
  ::signal(SIGPIPE, SIG_IGN);
  keep_off_cpus(config->avoid_cpus);

  nccomp::tools::analyzed::ServiceDeps deps;
  const std::string socket = config->status_socket;
  deps.query = [socket](std::string_view request) {
    return nccomp::client::query(socket, request);
  };
  deps.log = log_line;
  std::unique_ptr<nccomp::tools::analyzed::Service> service;
  try {
    service = std::make_unique<nccomp::tools::analyzed::Service>(*config, deps);
  } catch (const std::exception& e) {
    log_line("error", std::string("cannot start: ") + e.what());
    return 1;
  }
  const auto& s = service->state();
  log_line("info",
           "following " + config->log_directory + " (" + std::to_string(s.rows_total) +
               " rows taken, " + std::to_string(s.rows_total - s.rows_at_last_run) +
               " since the last run, a run every " + std::to_string(config->min_new_rows) +
               " new rows); work directory " + config->work_directory +
               (config->submit ? ", candidates to " + socket : ", candidates not submitted"));
  const double whole = std::floor(config->poll_interval_s);
  const timespec period{static_cast<time_t>(whole),
                        static_cast<long>((config->poll_interval_s - whole) * 1e9)};
  for (;;) {
    service->poll();
    if (once) break;
    const int sig = ::sigtimedwait(&stop_signals, nullptr, &period);
    if (sig == SIGTERM || sig == SIGINT) {
      log_line("info", std::string("stopping (") + (sig == SIGINT ? "SIGINT" : "SIGTERM") + ")");
      break;
    }
  }
  log_line("info", "stopped: " + std::to_string(s.rows_total) + " rows taken, " +
                       std::to_string(s.rows_skipped) + " skipped, " + std::to_string(s.runs) +
                       " runs, " + std::to_string(s.submitted) + " candidates submitted");
  return 0;
}
