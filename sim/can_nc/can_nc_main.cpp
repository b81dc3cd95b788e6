// can_nc: the NC side of a CAN signal map, for commissioning and tests.
//
//   can_nc CONFIG check          validate the [can] map and print it (no bus needed)
//   can_nc CONFIG serve [--no-ack] [--count N] [--timeout-s S]
//                                take offset writes off the bus, print them, acknowledge them
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <string>

#include "drivers/can/can_config.hpp"
#include "sim/can_nc/can_nc.hpp"

namespace dc = nccomp::drivers::can;

namespace {

const char* type_name(dc::ValueType t) {
  switch (t) {
    case dc::ValueType::kUnsigned: return "unsigned";
    case dc::ValueType::kSigned: return "signed";
    case dc::ValueType::kFloat: return "float";
  }
  return "?";
}

void print_layout(const dc::SignalLayout& l) {
  std::printf("bits %3u+%-2u %-8s %-2s scale %-8g offset %g", l.start_bit, l.length_bits,
              type_name(l.type), l.byte_order == dc::ByteOrder::kBigEndian ? "BE" : "LE", l.scale,
              l.offset);
}

int check(const dc::CanConfig& c) {
  std::printf("interface %s, %s, restart %s, ack timeout %g s x %u retries\n",
              c.interface.c_str(), c.mapping.fd ? "CAN FD" : "classic CAN",
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

}  // namespace

int main(int argc, char** argv) {
  if (argc < 3) {
    std::fprintf(stderr,
                 "usage: can_nc CONFIG check | can_nc CONFIG serve [--no-ack] [--count N] "
                 "[--timeout-s S]\n");
    return 2;
  }
  try {
    const dc::CanConfig c = dc::load_can_config(argv[1]);
    const std::string cmd = argv[2];
    if (cmd == "check") {
      return check(c);
    }
    if (cmd == "serve") {
      bool ack = true;
      long count = 0;
      double timeout_s = 3600;
      for (int i = 3; i < argc; ++i) {
        const std::string a = argv[i];
        if (a == "--no-ack") {
          ack = false;
        } else if (a == "--count" && i + 1 < argc) {
          count = std::strtol(argv[++i], nullptr, 10);
        } else if (a == "--timeout-s" && i + 1 < argc) {
          timeout_s = std::strtod(argv[++i], nullptr);
        } else {
          std::fprintf(stderr, "can_nc: unknown option %s\n", a.c_str());
          return 2;
        }
      }
      return serve(c, ack, count, timeout_s);
    }
    std::fprintf(stderr, "can_nc: unknown command %s\n", cmd.c_str());
    return 2;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "can_nc: %s\n", e.what());
    return 1;
  }
}
