// ncsim, the virtual NC (docs/ncsim.md):
//   ncsim --config FILE --program mould_face|side_wall|roll|touch --bus modbus|can --out DIR
//         [--speed FACTOR | --lockstep SOCKET] [--parts N] [--seed N] [--set effect.key=value ...]
//         [--wait-client SECONDS] [--continue DIR] [--lockstep-outage N,AFTER_S,DOWN_S]
// --continue DIR starts where the run whose result is in DIR ended (DIR/end_state.toml: the next
// part number and the tool's cut path, so a worn tool stays worn).
// Speed mode waits up to --wait-client (default 10 s) for the daemon's first polls before the
// clock starts, so that no event is published before the daemon has its baseline.
// Exit status: 0 program done and result written; 1 runtime error; 2 usage; 3 config error;
// 4 the daemon ended the lock-step run before the program was done (result written).
#include <sys/resource.h>

#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "nccomp_version.hpp"
#include "sim/ncsim/config.hpp"
#include "sim/ncsim/result.hpp"
#include "sim/ncsim/run.hpp"

namespace {

constexpr const char* kUsage =
    "usage: ncsim --config FILE --program mould_face|side_wall|roll|touch --bus modbus|can "
    "--out DIR [--speed FACTOR | --lockstep SOCKET] [--parts N] [--seed N] "
    "[--set effect.key=value ...] [--wait-client SECONDS] [--continue DIR] "
    "[--lockstep-outage N,AFTER_S,DOWN_S]\n"
    "       ncsim --help | --version\n";

[[noreturn]] void usage(const std::string& why) {
  std::fprintf(stderr, "ncsim: %s\n%s", why.c_str(), kUsage);
  std::exit(2);
}

void help() {
  std::printf(
      "ncsim — the virtual NC: machines a part, models the machine and serves the NC side of "
      "Modbus or CAN\n%s\n"
      "  --config FILE           ncsim's configuration (TOML; e.g. "
      "/usr/share/nccomp-sim/config/ncsim.toml)\n"
      "  --program NAME          mould_face, side_wall, roll or touch\n"
      "  --bus modbus|can        the bus the daemon talks to (default modbus)\n"
      "  --out DIR               result directory (surface, writes, summary)\n"
      "  --speed FACTOR          real time x FACTOR (default 1)\n"
      "  --lockstep SOCKET       clock master on a Unix socket: nccompd --lockstep SOCKET\n"
      "  --parts N, --seed N     shorthands for --set ncsim.parts=N, --set ncsim.seed=N\n"
      "  --set KEY=VALUE         override a config key, e.g. --set wear.rate_um_per_m=2\n"
      "  --wait-client SECONDS   speed mode: wait this long for the daemon's first poll "
      "(default 10)\n"
      "  --continue DIR          start where the run whose result is in DIR ended\n"
      "  --lockstep-outage N,AFTER_S,DOWN_S\n"
      "                          lock-step, Modbus: AFTER_S after the N-th measure request, "
      "wait for the daemon to go away, machine DOWN_S without it, wait for it to come back\n"
      "  -h, --help              this help; --version the version\n"
      "Exit status: 0 done, 1 run-time error, 2 usage, 3 config error, 4 the daemon ended a "
      "lock-step run early.\n",
      kUsage);
}

}  // namespace

int main(int argc, char** argv) {
  using namespace nccomp::sim::ncsim;
  std::string config_path;
  RunOptions opt;
  bool have_program = false;
  bool have_speed = false;
  std::vector<std::string> sets;
  std::string continue_dir;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--help" || a == "-h") {
      help();
      return 0;
    }
    if (a == "--version") {
      std::printf("ncsim %s\n", nccomp::kVersion);
      return 0;
    }
    if (i + 1 >= argc) {
      usage("missing value after " + a);
    }
    const std::string v = argv[++i];
    if (a == "--config") {
      config_path = v;
    } else if (a == "--program") {
      have_program = true;
      if (v == "mould_face") {
        opt.program = ProgramKind::kMouldFace;
      } else if (v == "side_wall") {
        opt.program = ProgramKind::kSideWall;
      } else if (v == "roll") {
        opt.program = ProgramKind::kRoll;
      } else if (v == "touch") {
        opt.program = ProgramKind::kTouch;
      } else {
        usage("unknown program '" + v + "'");
      }
    } else if (a == "--bus") {
      if (v == "modbus") {
        opt.bus = BusKind::kModbus;
      } else if (v == "can") {
        opt.bus = BusKind::kCan;
      } else {
        usage("unknown bus '" + v + "'");
      }
    } else if (a == "--out") {
      opt.out_dir = v;
    } else if (a == "--speed") {
      char* end = nullptr;
      opt.speed = std::strtod(v.c_str(), &end);
      if (v.empty() || *end != '\0' || !(opt.speed > 0.0) || opt.speed > 1e6) {
        usage("--speed wants a factor > 0, got '" + v + "'");
      }
      have_speed = true;
    } else if (a == "--wait-client") {
      char* end = nullptr;
      opt.wait_client_s = std::strtod(v.c_str(), &end);
      if (v.empty() || *end != '\0' || !(opt.wait_client_s >= 0.0) || opt.wait_client_s > 3600) {
        usage("--wait-client wants seconds 0..3600, got '" + v + "'");
      }
    } else if (a == "--lockstep") {
      opt.lockstep_socket = v;
    } else if (a == "--lockstep-outage") {
      int n = 0;
      double after_s = 0.0;
      double down_s = 0.0;
      char tail = 0;
      if (std::sscanf(v.c_str(), "%d,%lf,%lf%c", &n, &after_s, &down_s, &tail) != 3 || n < 1 ||
          !(after_s >= 0.0) || after_s > 3600.0 || !(down_s > 0.0) || down_s > 3600.0) {
        usage(
            "--lockstep-outage wants N,AFTER_S,DOWN_S (N >= 1, 0 <= AFTER_S <= 3600, "
            "0 < DOWN_S <= 3600), got '" +
            v + "'");
      }
      opt.outage_at_request = n;
      opt.outage_after_s = after_s;
      opt.outage_s = down_s;
    } else if (a == "--parts") {
      sets.push_back("ncsim.parts=" + v);
    } else if (a == "--seed") {
      sets.push_back("ncsim.seed=" + v);
    } else if (a == "--set") {
      sets.push_back(v);
    } else if (a == "--continue") {
      continue_dir = v;
    } else {
      usage("unknown option " + a);
    }
  }
  if (config_path.empty() || !have_program || opt.out_dir.empty()) {
    usage("--config, --program and --out are required");
  }
  if (have_speed && !opt.lockstep_socket.empty()) {
    usage("--speed and --lockstep exclude each other");
  }
  if (opt.outage_at_request > 0 && opt.lockstep_socket.empty()) {
    usage("--lockstep-outage needs --lockstep");
  }
  SimConfig config;
  try {
    if (!continue_dir.empty()) {
      // The end state first: an explicit --set still wins.
      std::vector<std::string> all = continuation_overrides(continue_dir);
      all.insert(all.end(), sets.begin(), sets.end());
      sets = std::move(all);
    }
    config = load_sim_config(config_path, sets, opt.program);
  } catch (const nccomp::formats::DiagnosticsError& e) {
    for (const nccomp::formats::Diagnostic& d : e.diagnostics().items()) {
      std::fprintf(stderr, "ncsim: %s\n", nccomp::formats::format(d).c_str());
    }
    return 3;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "ncsim: %s\n", e.what());
    return 3;
  }
  try {
    opt.on_ready = [&](std::uint16_t port) {
      if (opt.lockstep_socket.empty()) {
        std::printf("ncsim: %s on 127.0.0.1:%u, speed x%g (waiting up to %g s for the daemon)\n",
                    std::string(program_name(opt.program)).c_str(), port, opt.speed,
                    opt.wait_client_s);
      } else {
        std::printf("ncsim: %s on 127.0.0.1:%u, lock-step on %s\n",
                    std::string(program_name(opt.program)).c_str(), port,
                    opt.lockstep_socket.c_str());
      }
      std::fflush(stdout);
    };
    const RunSummary s = run(config, opt);
    rusage ru{};
    getrusage(RUSAGE_SELF, &ru);
    const double cpu_s = static_cast<double>(ru.ru_utime.tv_sec + ru.ru_stime.tv_sec) +
                         1e-6 * static_cast<double>(ru.ru_utime.tv_usec + ru.ru_stime.tv_usec);
    std::printf(
        "ncsim: %s %s: %.3f s simulated, %llu cycles, %zu offset writes taken, %llu "
        "refused, %.3f s CPU; result in %s\n",
        s.completed ? "done" : "stopped early", std::string(program_name(opt.program)).c_str(),
        s.sim_time_s, static_cast<unsigned long long>(s.cycles), s.writes,
        static_cast<unsigned long long>(s.refused), cpu_s, opt.out_dir.c_str());
    return s.completed ? 0 : 4;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "ncsim: %s\n", e.what());
    return 1;
  }
}
