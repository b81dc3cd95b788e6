// modbus_nc: the NC side of Modbus as a stand-alone server, for commissioning trials and demos.
//
//   modbus_nc [--bind 127.0.0.1] [--port 1502] [--unit 1] [--set TABLE:ADDRESS=VALUE ...]
//   modbus_nc --rtu DEVICE [--baud 115200] [--unit 1] [--set ...]
//
// TABLE is coil, discrete_input, holding or input; VALUE a 16-bit number (0x.. allowed).
// Serves until SIGINT / SIGTERM. The fault-triggering addresses of nc_server.hpp are active.
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include <pthread.h>
#include <signal.h>

#include "nccomp_version.hpp"
#include "sim/modbus_nc/nc_server.hpp"

namespace {

constexpr const char* kUsage =
    "usage: modbus_nc [--bind ADDR] [--port N] [--unit N] [--set TABLE:ADDRESS=VALUE ...]\n"
    "       modbus_nc --rtu DEVICE [--baud N] [--unit N] [--set TABLE:ADDRESS=VALUE ...]\n"
    "       modbus_nc --help | --version\n";

[[noreturn]] void usage(const std::string& why) {
  std::fprintf(stderr, "modbus_nc: %s\n%s", why.c_str(), kUsage);
  std::exit(2);
}

void help() {
  std::printf(
      "modbus_nc — the NC side of Modbus as a stand-alone server (commissioning, demos, tests)\n"
      "%s\n"
      "  --bind ADDR            TCP address to listen on (default 127.0.0.1)\n"
      "  --port N               TCP port (default 1502; 0 = any free port, printed)\n"
      "  --rtu DEVICE           serve Modbus RTU on a serial device instead of TCP\n"
      "  --baud N               RTU baud rate (default 115200)\n"
      "  --unit N               unit (slave) id, 1..247 (default 1)\n"
      "  --set TABLE:ADDR=VALUE preset a value; TABLE is coil, discrete_input, holding or input\n"
      "  -h, --help             this help; --version the version\n"
      "Serves until SIGINT or SIGTERM. Exit status: 0 stopped by a signal, 1 the server could "
      "not start, 2 usage.\n",
      kUsage);
}

long number(const std::string& s, long lo, long hi, const std::string& what) {
  char* end = nullptr;
  const long v = std::strtol(s.c_str(), &end, 0);
  if (s.empty() || *end != '\0' || v < lo || v > hi) {
    usage(what + ": '" + s + "' is not a number in " + std::to_string(lo) + ".." +
          std::to_string(hi));
  }
  return v;
}

}  // namespace

int main(int argc, char** argv) {
  using nccomp::sim::modbus_nc::NcServer;
  using nccomp::sim::modbus_nc::ServerConfig;
  using nccomp::sim::modbus_nc::Tables;
  ServerConfig sc;
  sc.port = 1502;
  struct Set {
    std::string table;
    long address;
    long value;
  };
  std::vector<Set> sets;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--help" || a == "-h") {
      help();
      return 0;
    }
    if (a == "--version") {
      std::printf("modbus_nc %s\n", nccomp::kVersion);
      return 0;
    }
    if (i + 1 >= argc) {
      usage("missing value after " + a);
    }
    const std::string v = argv[++i];
    if (a == "--bind") {
      sc.bind_address = v;
    } else if (a == "--port") {
      sc.port = static_cast<std::uint16_t>(number(v, 0, 65535, "--port"));
    } else if (a == "--rtu") {
      sc.rtu = true;
      sc.device = v;
    } else if (a == "--baud") {
      sc.baud = static_cast<int>(number(v, 300, 4000000, "--baud"));
    } else if (a == "--unit") {
      sc.unit_id = static_cast<std::uint8_t>(number(v, 1, 247, "--unit"));
    } else if (a == "--set") {
      const auto colon = v.find(':');
      const auto eq = v.find('=');
      if (colon == std::string::npos || eq == std::string::npos || eq < colon) {
        usage("--set wants TABLE:ADDRESS=VALUE, got '" + v + "'");
      }
      const std::string table = v.substr(0, colon);
      if (table != "coil" && table != "discrete_input" && table != "holding" && table != "input") {
        usage("--set: unknown table '" + table + "'");
      }
      sets.push_back({table, number(v.substr(colon + 1, eq - colon - 1), 0, 65535, "address"),
                      number(v.substr(eq + 1), 0, 65535, "value")});
    } else {
      usage("unknown option " + a);
    }
  }
  try {
    NcServer server(sc);
    server.update([&](Tables& t) {
      for (const Set& s : sets) {
        const auto at = static_cast<std::size_t>(s.address);
        if (s.table == "coil") {
          t.coils[at] = s.value != 0 ? 1 : 0;
        } else if (s.table == "discrete_input") {
          t.discrete_inputs[at] = s.value != 0 ? 1 : 0;
        } else if (s.table == "holding") {
          t.holding[at] = static_cast<std::uint16_t>(s.value);
        } else {
          t.input[at] = static_cast<std::uint16_t>(s.value);
        }
      }
    });
    // Block the stop signals in every thread (the server thread inherits the mask) and wait for
    // them here, so that a signal cannot land in the server thread unnoticed.
    sigset_t stop_signals;
    sigemptyset(&stop_signals);
    sigaddset(&stop_signals, SIGINT);
    sigaddset(&stop_signals, SIGTERM);
    pthread_sigmask(SIG_BLOCK, &stop_signals, nullptr);
    server.start();
    if (sc.rtu) {
      std::printf("modbus_nc: serving unit %d on %s\n", sc.unit_id, sc.device.c_str());
    } else {
      std::printf("modbus_nc: serving unit %d on %s:%d\n", sc.unit_id, sc.bind_address.c_str(),
                  server.port());
    }
    std::fflush(stdout);
    int sig = 0;
    sigwait(&stop_signals, &sig);
    std::printf("modbus_nc: %llu requests served\n",
                static_cast<unsigned long long>(server.requests()));
    server.stop();
  } catch (const std::exception& e) {
    std::fprintf(stderr, "modbus_nc: %s\n", e.what());
    return 1;
  }
  return 0;
}
