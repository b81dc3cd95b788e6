// The highest loop rate nccompd itself sustains with zero overruns over Modbus TCP against the
// project's NC server (sim/modbus_nc, in this process, 127.0.0.1): the real daemon binary, its
// loop (engine with a register and a ramp that changes the offset every cycle), its Modbus
// driver polling at the loop rate (poll_rate_hz left out), status over its socket.
//
// Per rate: start nccompd, wait until the bus is up, let it run 1 s, then take two status
// snapshots `seconds` apart. Sustained = in that window no loop overrun, no driver poll overrun
// (the driver's poll_overruns counter in the status JSON), no dropped event, and the loop ran.
//
// Usage: bench_modbus_nccompd [seconds_per_rate] [--fifo] [--io-fifo[=PRIORITY]]
//        [--io-cpu=CPU]
// --fifo: the daemon's loop thread at SCHED_FIFO 50 ([daemon.realtime] sched_fifo_priority), this
// process (the NC server's thread) too; nccompd is spawned at SCHED_OTHER, so without --io-fifo
// its driver I/O thread stays there (the daemon raises only its loop thread).
// --io-fifo[=P]: also [modbus] io_sched_fifo_priority = P (default 40; needs --fifo, since the
// daemon refuses an I/O priority not below the loop's): the driver's I/O thread raises itself.
// --io-cpu=C: [modbus] io_cpu_affinity = [C].
// The header line and the daemon's log lines about both threads say what each thread got.
#include <fcntl.h>
#include <sched.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <optional>
#include <regex>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "client/status_client.hpp"
#include "sim/modbus_nc/nc_server.hpp"

extern char** environ;

namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;

constexpr int kLoopPriority = 50;

struct Options {
  double seconds{5.0};
  bool fifo{false};
  int io_fifo_priority{0};  // 0 = key not set
  int io_cpu{-1};           // -1 = key not set
};

std::string config_text(std::uint16_t port, double rate_hz, const Options& o) {
  std::ostringstream s;
  s << "[daemon]\nrate_hz = " << rate_hz << "\n";
  if (o.fifo) {
    s << "[daemon.realtime]\nsched_fifo_priority = " << kLoopPriority << "\n";
  }
  s << "[state]\ndirectory = \"state\"\nmin_interval_s = 0.5\n"
    << "[measurement_log]\ndirectory = \"log\"\n"
    << "[status]\nsocket_path = \"status.sock\"\n"
    << "[modbus]\ntransport = \"tcp\"\nhost = \"127.0.0.1\"\nport = " << port << "\n"
    << "response_timeout_s = 0.5\n";
  if (o.io_fifo_priority > 0) {
    s << "io_sched_fifo_priority = " << o.io_fifo_priority << "\n";
  }
  if (o.io_cpu >= 0) {
    s << "io_cpu_affinity = [" << o.io_cpu << "]\n";
  }
  // The reference profile's axis block (12 input registers) and a tool-measurement group.
  s << "[modbus.axis]\n"
    << "x_mm = { table = \"input\", address = 0, type = \"int32\", scale = 0.0001 }\n"
    << "y_mm = { table = \"input\", address = 2, type = \"int32\", scale = 0.0001 }\n"
    << "z_mm = { table = \"input\", address = 4, type = \"int32\", scale = 0.0001 }\n"
    << "program_path_mm = { table = \"input\", address = 6, type = \"int32\", scale = 0.001 }\n"
    << "tool = { table = \"input\", address = 8, type = \"uint16\" }\n"
    << "normal_x = { table = \"input\", address = 9, type = \"int16\", scale = 0.0001 }\n"
    << "normal_y = { table = \"input\", address = 10, type = \"int16\", scale = 0.0001 }\n"
    << "normal_z = { table = \"input\", address = 11, type = \"int16\", scale = 0.0001 }\n"
    << "[modbus.tool_measurement]\n"
    << "sequence = { table = \"input\", address = 100, type = \"uint16\" }\n"
    << "tool = { table = \"input\", address = 101, type = \"uint16\" }\n"
    << "wear_um = { table = \"input\", address = 102, type = \"float32\" }\n"
    << "[[modbus.offset]]\nregister_index = 0\naddress = 200\ntype = \"int32\"\nscale = 0.1\n"
    << "[[registers]]\nname = \"T1_length_wear\"\nkind = \"tool_length_wear\"\nbus = \"modbus\"\n"
    << "max_abs_um = 2000\nmax_step_um = 5\nmax_rate_um_per_s = 1000\n"
    // 50 µm/s towards 1500 µm: a new offset every cycle for 30 s.
    << "[[ramp]]\nname = \"bench\"\nregister = \"T1_length_wear\"\ntarget_um = 1500\n"
    << "rate_um_per_s = 50\n";
  return s.str();
}

/// A number after "key": in the JSON text after position `from` (the first match).
std::optional<double> number(const std::string& json, const std::string& key,
                             std::size_t from = 0) {
  const std::regex re("\"" + key + "\":(-?[0-9.eE+-]+)");
  std::smatch m;
  const std::string tail = json.substr(std::min(from, json.size()));
  if (!std::regex_search(tail, m, re)) {
    return std::nullopt;
  }
  return std::stod(m[1]);
}

struct Snapshot {
  double cycles{0};
  double overruns{0};
  double missed{0};
  double p99_us{0};
  double max_us{0};
  double poll_overruns{0};
  double events_dropped{0};
  double offsets_written{0};
  double writes_sent{0};
  bool up{false};
};

std::optional<Snapshot> snapshot(const std::string& socket) {
  std::string j;
  try {
    j = nccomp::client::query(socket, "json");
  } catch (const std::exception&) {
    return std::nullopt;
  }
  const auto loop = j.find("\"loop\":{");
  const auto bus = j.find("{\"name\":\"modbus\"");
  if (loop == std::string::npos || bus == std::string::npos) {
    return std::nullopt;
  }
  Snapshot s;
  s.cycles = number(j, "cycles", loop).value_or(-1);
  s.overruns = number(j, "overruns", loop).value_or(-1);
  s.missed = number(j, "missed_deadlines", loop).value_or(-1);
  s.p99_us = number(j, "p99", loop).value_or(-1);
  s.max_us = number(j, "max", loop).value_or(-1);
  s.writes_sent = number(j, "writes_sent", loop).value_or(-1);
  s.events_dropped = number(j, "events_dropped", bus).value_or(-1);
  s.offsets_written = number(j, "offsets_written", bus).value_or(-1);
  s.poll_overruns = number(j, "poll_overruns", bus).value_or(-1);
  s.up = j.find("{\"name\":\"modbus\",\"state\":\"up\"", bus) == bus;
  return s;
}

pid_t spawn_daemon(const fs::path& dir) {
  std::string bin = NCCOMPD_BIN;
  std::string flag = "--config";
  std::string cfg = (dir / "nccompd.toml").string();
  std::vector<char*> argv{bin.data(), flag.data(), cfg.data(), nullptr};
  posix_spawn_file_actions_t fa;
  posix_spawn_file_actions_init(&fa);
  const std::string log = (dir / "nccompd.log").string();
  posix_spawn_file_actions_addopen(&fa, 1, log.c_str(), O_WRONLY | O_CREAT | O_APPEND, 0644);
  posix_spawn_file_actions_adddup2(&fa, 1, 2);
  // The daemon starts at normal priority whatever this process runs at: only its loop thread
  // raises itself ([daemon.realtime]), as in production.
  posix_spawnattr_t attr;
  posix_spawnattr_init(&attr);
  sched_param sp{};
  posix_spawnattr_setschedpolicy(&attr, SCHED_OTHER);
  posix_spawnattr_setschedparam(&attr, &sp);
  posix_spawnattr_setflags(&attr, POSIX_SPAWN_SETSCHEDULER);
  pid_t pid = -1;
  if (posix_spawn(&pid, bin.c_str(), &fa, &attr, argv.data(), environ) != 0) {
    std::perror("posix_spawn nccompd");
    std::exit(1);
  }
  posix_spawnattr_destroy(&attr);
  posix_spawn_file_actions_destroy(&fa);
  return pid;
}

int stop_daemon(pid_t pid) {
  ::kill(pid, SIGTERM);
  for (int i = 0; i < 1000; ++i) {
    int st = 0;
    if (::waitpid(pid, &st, WNOHANG) == pid) {
      return WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
    }
    std::this_thread::sleep_for(10ms);
  }
  ::kill(pid, SIGKILL);
  ::waitpid(pid, nullptr, 0);
  return -1;
}

/// The daemon's log lines about its threads' scheduling ("loop thread: ...", "I/O thread: ...").
std::string thread_lines(const fs::path& log_path) {
  std::ifstream in(log_path);
  std::string line;
  std::string out;
  while (std::getline(in, line)) {
    if (line.find("loop thread: SCHED") != std::string::npos ||
        line.find("I/O thread:") != std::string::npos) {
      out += "    " + line + "\n";
    }
  }
  return out;
}

int usage() {
  std::fprintf(stderr,
               "usage: bench_modbus_nccompd [seconds_per_rate] [--fifo] [--io-fifo[=PRIORITY]] "
               "[--io-cpu=CPU]\n");
  return 2;
}

}  // namespace

int main(int argc, char** argv) {
  std::setvbuf(stdout, nullptr, _IOLBF, 0);
  Options o;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--fifo") {
      o.fifo = true;
    } else if (a == "--io-fifo") {
      o.io_fifo_priority = 40;
    } else if (a.rfind("--io-fifo=", 0) == 0) {
      o.io_fifo_priority = std::atoi(a.c_str() + 10);
      if (o.io_fifo_priority < 1 || o.io_fifo_priority >= kLoopPriority) {
        std::fprintf(stderr, "--io-fifo: priority 1..%d (below the loop's %d)\n", kLoopPriority - 1,
                     kLoopPriority);
        return 2;
      }
    } else if (a.rfind("--io-cpu=", 0) == 0) {
      o.io_cpu = std::atoi(a.c_str() + 9);
    } else if (i == 1 && !a.empty() && a[0] != '-') {
      o.seconds = std::atof(a.c_str());
    } else {
      return usage();
    }
  }
  if (o.io_fifo_priority > 0 && !o.fifo) {
    std::fprintf(stderr,
                 "--io-fifo needs --fifo: nccompd refuses an I/O thread at SCHED_FIFO above a "
                 "loop at normal scheduling\n");
    return 2;
  }
  const double seconds = o.seconds;
  const bool fifo = o.fifo;
  if (fifo) {
    sched_param p{};
    p.sched_priority = kLoopPriority;
    if (sched_setscheduler(0, SCHED_FIFO, &p) != 0) {
      std::perror("sched_setscheduler(SCHED_FIFO)");
      return 1;
    }
  }
  std::string io = o.io_fifo_priority > 0
                       ? "driver I/O thread SCHED_FIFO " + std::to_string(o.io_fifo_priority) +
                             " (io_sched_fifo_priority)"
                       : std::string("driver I/O thread SCHED_OTHER");
  if (o.io_cpu >= 0) {
    io += ", pinned to CPU " + std::to_string(o.io_cpu);
  }
  const std::string mode =
      fifo ? "loop thread and NC server SCHED_FIFO " + std::to_string(kLoopPriority) + ", " + io
           : "SCHED_OTHER, " + io;
  std::printf("nccompd over Modbus TCP (127.0.0.1) against sim/modbus_nc, %.1f s per rate, %s\n",
              seconds, mode.c_str());
  nccomp::sim::modbus_nc::NcServer server(nccomp::sim::modbus_nc::ServerConfig{});
  server.update([](nccomp::sim::modbus_nc::Tables& t) {
    t.input[1] = 1000;    // X = 0.1 mm
    t.input[11] = 10000;  // unit normal (0, 0, 1)
    t.input[8] = 1;
  });
  server.start();
  const fs::path dir =
      fs::temp_directory_path() / ("bench_modbus_nccompd_" + std::to_string(getpid()));
  std::printf(
      "| loop rate [Hz] | cycles | measured rate [Hz] | loop overruns | missed deadlines | driver "
      "poll overruns | events dropped | offsets written | loop latency p99 [us] (whole run) | max "
      "[us] |\n"
      "|---|---|---|---|---|---|---|---|---|---|\n");
  double best = 0.0;
  std::string granted;
  for (double rate : {250.0, 500.0, 1000.0, 2000.0, 4000.0}) {
    fs::remove_all(dir);
    fs::create_directories(dir);
    std::ofstream(dir / "nccompd.toml") << config_text(server.port(), rate, o);
    const pid_t pid = spawn_daemon(dir);
    const std::string sock = (dir / "status.sock").string();
    std::optional<Snapshot> a;
    for (int i = 0; i < 500; ++i) {
      a = snapshot(sock);
      if (a && a->up) {
        break;
      }
      std::this_thread::sleep_for(20ms);
    }
    if (!a || !a->up) {
      stop_daemon(pid);
      std::ifstream in(dir / "nccompd.log");
      std::ostringstream log;
      log << in.rdbuf();
      std::printf("| %.0f | the bus did not come up; nccompd's log: |\n%s\n", rate,
                  log.str().c_str());
      continue;
    }
    std::this_thread::sleep_for(1s);  // warm-up, not measured
    a = snapshot(sock);
    const auto t0 = std::chrono::steady_clock::now();
    std::this_thread::sleep_for(std::chrono::duration<double>(seconds));
    const std::optional<Snapshot> b = snapshot(sock);
    const double span =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    const int rc = stop_daemon(pid);
    if (granted.empty()) {
      // What the OS granted (the same at every rate), from the daemon's own log.
      granted = thread_lines(dir / "nccompd.log");
    }
    if (!a || !b) {
      std::printf("| %.0f | status not readable |\n", rate);
      continue;
    }
    const double overruns = b->overruns - a->overruns;
    const double polls_over = b->poll_overruns - a->poll_overruns;
    const double dropped = b->events_dropped - a->events_dropped;
    const double cycles = b->cycles - a->cycles;
    // Counts (parsed as doubles): zero means below one half.
    const bool ok = overruns < 0.5 && polls_over < 0.5 && dropped < 0.5 && cycles > 0.5 && rc == 0;
    std::printf("| %.0f | %.0f | %.1f | %.0f | %.0f | %.0f | %.0f | %.0f | %.1f | %.1f |%s\n", rate,
                cycles, cycles / span, overruns, b->missed - a->missed, polls_over, dropped,
                b->offsets_written - a->offsets_written, b->p99_us, b->max_us,
                ok ? "" : (rc != 0 ? " (exit status not 0)" : " (not sustained)"));
    if (ok) {
      best = rate;
    }
  }
  std::printf("\nnccompd's log on its threads' scheduling:\n%s", granted.c_str());
  std::printf("\nhighest loop rate nccompd sustained with zero overruns: %.0f Hz\n", best);
  server.stop();
  fs::remove_all(dir);
  return 0;
}
