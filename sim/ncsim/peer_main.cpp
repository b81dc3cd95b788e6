// ncsim_peer: a minimal stand-in for nccompd's lock-step side (contract C2), for benchmarks and
// for trying ncsim without the daemon. Per TICK it does what the daemon's Modbus sync() does —
// one poll of every read block of the map — then answers DONE; it writes no offsets.
//   ncsim_peer --map reference-nc-modbus.toml --port N --lockstep SOCKET
#include <modbus/modbus.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <thread>
#include <vector>

#include "drivers/modbus/config.hpp"
#include "nccomp_version.hpp"
#include "sim/ncsim/lockstep.hpp"

int main(int argc, char** argv) {
  using namespace nccomp;
  std::string map_path;
  std::string sock;
  int port = -1;
  constexpr const char* kUsage =
      "usage: ncsim_peer --map FILE [--port N] --lockstep SOCKET\n"
      "       ncsim_peer --help | --version\n";
  const auto usage = [&](const std::string& why) {
    std::fprintf(stderr, "ncsim_peer: %s\n%s", why.c_str(), kUsage);
    return 2;
  };
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--help" || a == "-h") {
      std::printf(
          "ncsim_peer — a minimal lock-step peer of ncsim: one Modbus poll per TICK, then DONE\n"
          "%s\n"
          "  --map FILE         the [modbus] map ncsim serves (e.g. reference-nc-modbus.toml)\n"
          "  --port N           the NC's Modbus TCP port on 127.0.0.1 (default: the map's)\n"
          "  --lockstep SOCKET  ncsim's lock-step socket (ncsim --lockstep SOCKET)\n"
          "Exit status: 0 the run ended (BYE), 1 no connection, 2 usage, 3 the map is invalid.\n",
          kUsage);
      return 0;
    }
    if (a == "--version") {
      std::printf("ncsim_peer %s\n", nccomp::kVersion);
      return 0;
    }
    if (i + 1 >= argc) {
      return usage("missing value after " + a);
    }
    const std::string v = argv[++i];
    if (a == "--map") {
      map_path = v;
    } else if (a == "--port") {
      char* end = nullptr;
      const long p = std::strtol(v.c_str(), &end, 10);
      if (v.empty() || *end != '\0' || p < 1 || p > 65535) {
        return usage("--port wants 1..65535, got '" + v + "'");
      }
      port = static_cast<int>(p);
    } else if (a == "--lockstep") {
      sock = v;
    } else {
      return usage("unknown option " + a);
    }
  }
  if (map_path.empty() || sock.empty()) {
    return usage("--map and --lockstep are required");
  }
  drivers::modbus::ModbusConfig map;
  try {
    map = drivers::modbus::load_modbus_config(map_path);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "ncsim_peer: %s\n", e.what());
    return 3;
  }
  int fd = -1;
  for (int tries = 0; tries < 1000 && fd < 0; ++tries) {  // 10 s, as the daemon retries
    fd = socket(AF_UNIX, SOCK_SEQPACKET, 0);
    sockaddr_un a{};
    a.sun_family = AF_UNIX;
    std::strncpy(a.sun_path, sock.c_str(), sizeof(a.sun_path) - 1);
    if (connect(fd, reinterpret_cast<sockaddr*>(&a), sizeof(a)) != 0) {
      close(fd);
      fd = -1;
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
  }
  if (fd < 0) {
    std::fprintf(stderr, "ncsim_peer: cannot connect to %s\n", sock.c_str());
    return 1;
  }
  modbus_t* ctx = modbus_new_tcp("127.0.0.1", port < 0 ? map.port : port);
  if (ctx == nullptr || modbus_connect(ctx) != 0) {
    std::fprintf(stderr, "ncsim_peer: cannot connect to the NC's Modbus port\n");
    return 1;
  }
  std::vector<std::uint16_t> regs(256);
  std::vector<std::uint8_t> bits(2048);
  std::uint64_t cycles = 0;
  for (;;) {
    sim::ncsim::LockstepMessage m{};
    const ssize_t n = recv(fd, &m, sizeof(m), 0);
    if (n != static_cast<ssize_t>(sizeof(m)) || m.type != 1) {
      break;
    }
    for (const auto& b : map.blocks) {
      int rc = 0;
      switch (b.table) {
        case drivers::modbus::Table::kHolding:
          rc = modbus_read_registers(ctx, b.start, b.count, regs.data());
          break;
        case drivers::modbus::Table::kInput:
          rc = modbus_read_input_registers(ctx, b.start, b.count, regs.data());
          break;
        case drivers::modbus::Table::kCoil:
          rc = modbus_read_bits(ctx, b.start, b.count, bits.data());
          break;
        case drivers::modbus::Table::kDiscreteInput:
          rc = modbus_read_input_bits(ctx, b.start, b.count, bits.data());
          break;
      }
      if (rc < 0) {
        std::fprintf(stderr, "ncsim_peer: read failed: %s\n", modbus_strerror(errno));
        return 1;
      }
    }
    sim::ncsim::LockstepMessage done{sim::ncsim::kLockstepMagic, 2, m.cycle, m.time_ns};
    if (send(fd, &done, sizeof(done), MSG_NOSIGNAL) != static_cast<ssize_t>(sizeof(done))) {
      break;
    }
    ++cycles;
  }
  rusage ru{};
  getrusage(RUSAGE_SELF, &ru);
  std::printf("ncsim_peer: %llu cycles, %.3f s CPU\n", static_cast<unsigned long long>(cycles),
              static_cast<double>(ru.ru_utime.tv_sec + ru.ru_stime.tv_sec) +
                  1e-6 * static_cast<double>(ru.ru_utime.tv_usec + ru.ru_stime.tv_usec));
  modbus_close(ctx);
  modbus_free(ctx);
  close(fd);
  return 0;
}
