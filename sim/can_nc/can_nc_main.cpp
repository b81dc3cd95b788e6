// can_nc: the NC side of a CAN signal map, for commissioning and tests.
//
//   can_nc CONFIG check          validate the [can] map and print it (no bus needed)
//   can_nc CONFIG serve [--no-ack] [--count N] [--timeout-s S]
//                                take offset writes off the bus, print them, acknowledge them
// Exit status: 0 done, 1 bus error or timeout, 2 usage, 3 invalid map.
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <optional>
#include <string>

#include "drivers/can/can_config.hpp"
#include "nccomp_version.hpp"
#include "sim/can_nc/can_nc.hpp"

namespace dc = nccomp::drivers::can;

namespace {

const char* type_name(dc::ValueType t) {
  switch (t) {
    case dc::ValueType::kUnsigned:
      return "unsigned";
    case dc::ValueType::kSigned:
      return "signed";
    case dc::ValueType::kFloat:
      return "float";
  }
  return "?";
}

void print_layout(const dc::SignalLayout& l) {
  std::printf("bits %3u+%-2u %-8s %-2s scale %-8g offset %g", l.start_bit, l.length_bits,
              type_name(l.type), l.byte_order == dc::ByteOrder::kBigEndian ? "BE" : "LE", l.scale,
              l.offset);
}

int check(const dc::CanConfig& c) {
  std::printf("interface %s, %s, restart %s, ack timeout %g s x %u retries\n", c.interface.c_str(),
              c.mapping.fd ? "CAN FD" : "classic CAN",
              c.restart == dc::RestartMode::kKernel ? "kernel" : "daemon", c.ack_timeout_s,
              c.ack_retries);
  for (const auto& f : c.mapping.rx) {
    std::printf("rx 0x%03X len %2u %-17s %s\n", f.id, f.length_bytes,
                std::string(dc::event_kind_name(f.event)).c_str(), f.emit ? "emits" : "updates");
    for (const auto& s : f.signals) {
      std::printf("    %-20s ", s.name.c_str());
      print_layout(s.layout);
      std::printf("\n");
    }
  }
  for (const auto& r : c.mapping.offsets) {
    std::printf("offset register %u -> 0x%03X len %u value ", r.register_index, r.id,
                r.length_bytes);
    print_layout(r.value);
    if (r.ack) {
      std::printf(" ack 0x%03X\n", r.ack->id);
    } else {
      std::printf(" no ack\n");
    }
  }
  std::printf("ok: %zu received frames, %zu offset registers\n", c.mapping.rx.size(),
              c.mapping.offsets.size());
  return 0;
}

int serve(const dc::CanConfig& c, bool ack, long count, double timeout_s) {
  nccomp::sim::can_nc::CanNcNode node(c.mapping, c.interface);
  node.acknowledge = ack;
  for (long n = 0; count <= 0 || n < count;) {
    const auto w = node.receive_write(static_cast<int>(timeout_s * 1000));
    if (!w) {
      std::fprintf(stderr, "can_nc: no offset write within %g s\n", timeout_s);
      return 1;
    }
    std::printf("register %u = %.1f um (frame 0x%03X%s)\n", w->register_index, w->value_um,
                w->frame.id, ack ? ", acknowledged" : "");
    std::fflush(stdout);
    ++n;
  }
  return 0;
}

constexpr const char* kUsage =
    "usage: can_nc CONFIG check\n"
    "       can_nc CONFIG serve [--no-ack] [--count N] [--timeout-s S]\n"
    "       can_nc --help | --version\n";

int usage(const std::string& why) {
  std::fprintf(stderr, "can_nc: %s\n%s", why.c_str(), kUsage);
  return 2;
}

void help() {
  std::printf(
      "can_nc — the NC side of a CAN signal map (commissioning, tests)\n%s\n"
      "  check             validate the [can] map of CONFIG and print it (no bus needed)\n"
      "  serve             take offset writes off the map's interface, print and acknowledge "
      "them\n"
      "    --no-ack        do not acknowledge (the daemon retries, then gives up)\n"
      "    --count N       stop after N writes (default: serve until the timeout)\n"
      "    --timeout-s S   give up when no write arrives for S seconds (default 3600)\n"
      "  -h, --help        this help; --version the version\n"
      "Exit status: 0 done, 1 a bus error or no write within the timeout, 2 usage, 3 the map is "
      "invalid (file:line:column and key path).\n",
      kUsage);
}

/// A whole-string number in [lo, hi], or nullopt.
std::optional<double> number(const char* s, double lo, double hi) {
  char* end = nullptr;
  const double v = std::strtod(s, &end);
  if (end == s || *end != '\0' || !(v >= lo) || !(v <= hi)) {
    return std::nullopt;
  }
  return v;
}

}  // namespace

int main(int argc, char** argv) {
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--help" || a == "-h") {
      help();
      return 0;
    }
    if (a == "--version") {
      std::printf("can_nc %s\n", nccomp::kVersion);
      return 0;
    }
  }
  if (argc < 3) {
    return usage("CONFIG and a command (check or serve) are required");
  }
  const std::string cmd = argv[2];
  if (cmd != "check" && cmd != "serve") {
    return usage("unknown command " + cmd);
  }
  bool ack = true;
  long count = 0;
  double timeout_s = 3600;
  for (int i = 3; i < argc; ++i) {
    const std::string a = argv[i];
    if (cmd == "serve" && a == "--no-ack") {
      ack = false;
    } else if (cmd == "serve" && a == "--count" && i + 1 < argc) {
      char* end = nullptr;
      const char* v = argv[++i];
      count = std::strtol(v, &end, 10);
      if (end == v || *end != '\0' || count < 0) {
        return usage(std::string("--count wants a whole number >= 0, got '") + v + "'");
      }
    } else if (cmd == "serve" && a == "--timeout-s" && i + 1 < argc) {
      const auto v = number(argv[++i], 0.001, 1e6);
      if (!v) {
        return usage(std::string("--timeout-s wants seconds in 0.001..1e6, got '") + argv[i] + "'");
      }
      timeout_s = *v;
    } else {
      return usage("unknown option " + a);
    }
  }
  dc::CanConfig c;
  try {
    c = dc::load_can_config(argv[1]);
  } catch (const nccomp::formats::DiagnosticsError& e) {
    std::fprintf(stderr, "can_nc: %s\n", e.what());
    return 3;
  }
  try {
    return cmd == "check" ? check(c) : serve(c, ack, count, timeout_s);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "can_nc: %s\n", e.what());
    return 1;
  }
}
