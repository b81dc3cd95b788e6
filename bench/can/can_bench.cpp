// CAN driver benchmark on vcan0 (run in the VM: bench/can/run_bench.sh).
//
// 1. Latency: the NC side sends a trigger frame (tool change, tool = sequence number); a loop
//    thread drains rx() and answers each event with an offset write (register 3, value = the
//    sequence number in 0.1 µm counts) and wake(); the NC side timestamps the offset frame's
//    arrival. One trigger in flight at a time; p50/p99/p99.9/max over N events.
// 2. Rate: the NC side sends mapped frames (temperature, valid) paced at R frames/s; the driver
//    must decode every one (no kernel drop, no ring drop) while candump, started by the script,
//    receives the same traffic; the highest R with zero loss is reported.
//
//   bench_can CONFIG {latency N | rate R N}
#include <linux/can.h>
#include <linux/can/raw.h>
#include <net/if.h>
#include <poll.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <thread>
#include <vector>

#include "drivers/can/can_bus.hpp"
#include "drivers/can/can_config.hpp"

namespace dc = nccomp::drivers::can;

namespace {

std::int64_t now_ns() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * 1'000'000'000 + ts.tv_nsec;
}

int open_peer(const std::string& ifname, canid_t filter_id) {
  const int s = ::socket(PF_CAN, SOCK_RAW, CAN_RAW);
  ifreq ifr{};
  std::strncpy(ifr.ifr_name, ifname.c_str(), IFNAMSIZ - 1);
  if (s < 0 || ::ioctl(s, SIOCGIFINDEX, &ifr) < 0) {
    std::perror("peer socket");
    std::exit(2);
  }
  can_filter f{filter_id, CAN_SFF_MASK | CAN_EFF_FLAG | CAN_RTR_FLAG};
  ::setsockopt(s, SOL_CAN_RAW, CAN_RAW_FILTER, &f, sizeof f);
  sockaddr_can a{};
  a.can_family = AF_CAN;
  a.can_ifindex = ifr.ifr_ifindex;
  if (::bind(s, reinterpret_cast<sockaddr*>(&a), sizeof a) < 0) {
    std::perror("peer bind");
    std::exit(2);
  }
  return s;
}

void send_frame(int s, canid_t id, const std::uint8_t* d, std::uint8_t len) {
  can_frame f{};
  f.can_id = id;
  f.len = len;
  std::memcpy(f.data, d, len);
  while (::write(s, &f, sizeof f) != static_cast<ssize_t>(sizeof f)) {
    if (errno != ENOBUFS && errno != EINTR) {
      std::perror("peer write");
      std::exit(2);
    }
    pollfd p{s, POLLOUT, 0};
    ::poll(&p, 1, 1);
  }
}

double pct(std::vector<std::int64_t>& v, double p) {
  const auto k = static_cast<std::size_t>(p * static_cast<double>(v.size() - 1));
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(k), v.end());
  return static_cast<double>(v[k]) / 1000.0;
}

int latency(dc::CanConfig cfg, int n) {
  dc::CanBus bus(std::move(cfg));
  bus.start();
  std::atomic<bool> stop{false};
  // The loop: answers each tool change with an offset write of the tool number.
  std::thread loop([&] {
    nccomp::core::Event e;
    while (!stop.load(std::memory_order_relaxed)) {
      if (bus.rx().try_pop(e)) {
        if (const auto* tc = std::get_if<nccomp::core::ToolChange>(&e)) {
          (void)bus.tx().try_push(
              nccomp::core::OffsetWrite{tc->time_ns, 3, static_cast<double>(tc->tool) * 0.1});
          bus.wake();
        }
      } else {
        std::this_thread::yield();
      }
    }
  });
  const int peer = open_peer("vcan0", 0x303);
  std::vector<std::int64_t> lat;
  lat.reserve(static_cast<std::size_t>(n));
  int lost = 0;
  for (int i = 0; i < n + 100; ++i) {
    const auto seq = static_cast<std::uint16_t>((i % 60000) + 1);
    const std::uint8_t d[4] = {static_cast<std::uint8_t>(seq & 0xFF),
                               static_cast<std::uint8_t>(seq >> 8), 0, 0};
    const std::int64_t t0 = now_ns();
    send_frame(peer, 0x140, d, 4);
    bool got = false;
    while (!got) {
      pollfd p{peer, POLLIN, 0};
      if (::poll(&p, 1, 1000) <= 0) {
        ++lost;
        break;
      }
      can_frame f{};
      if (::read(peer, &f, sizeof f) == static_cast<ssize_t>(sizeof f)) {
        const auto v = static_cast<std::uint16_t>(f.data[0] | (f.data[1] << 8));
        got = v == seq;
      }
    }
    const std::int64_t t1 = now_ns();
    if (got && i >= 100) {  // the first 100 warm caches and page in the code
      lat.push_back(t1 - t0);
    }
  }
  stop = true;
  loop.join();
  const auto st = bus.can_status();
  bus.stop();
  ::close(peer);
  std::printf("latency trigger->offset frame over %zu events (lost %d): p50 %.1f us  p99 %.1f us  "
              "p99.9 %.1f us  max %.1f us\n",
              lat.size(), lost, pct(lat, 0.5), pct(lat, 0.99), pct(lat, 0.999),
              pct(lat, 1.0));
  std::printf("driver: frames_rx %llu frames_tx %llu events %llu written %llu\n",
              static_cast<unsigned long long>(st.bus.counters.frames_rx),
              static_cast<unsigned long long>(st.bus.counters.frames_tx),
              static_cast<unsigned long long>(st.bus.counters.events_decoded),
              static_cast<unsigned long long>(st.bus.counters.offsets_written));
  return lost == 0 ? 0 : 1;
}

int rate(dc::CanConfig cfg, double rate_hz, int n) {
  dc::CanBus bus(std::move(cfg));
  bus.start();
  std::atomic<bool> stop{false};
  std::atomic<std::uint64_t> consumed{0};
  std::thread loop([&] {
    nccomp::core::Event e;
    while (!stop.load(std::memory_order_relaxed)) {
      if (bus.rx().try_pop(e)) {
        consumed.fetch_add(1, std::memory_order_relaxed);
      } else {
        std::this_thread::sleep_for(std::chrono::microseconds(200));  // a 5 kHz loop
      }
    }
  });
  const int peer = open_peer("vcan0", 0x7FF);
  // rate_hz <= 0: unpaced, as fast as the sender's write() goes (cangen -g 0).
  const auto period_ns = rate_hz > 0 ? static_cast<std::int64_t>(1e9 / rate_hz) : 0;
  const std::int64_t t0 = now_ns();
  for (int i = 0; i < n; ++i) {
    const std::int64_t due = t0 + i * period_ns;
    while (period_ns > 0 && now_ns() < due) {
    }
    const std::uint8_t d[4] = {static_cast<std::uint8_t>(i & 0xFF), 0, 0xD2, 0x04};
    send_frame(peer, 0x160, d, 4);
  }
  const double sent_s = static_cast<double>(now_ns() - t0) / 1e9;
  std::this_thread::sleep_for(std::chrono::milliseconds(500));
  stop = true;
  loop.join();
  const auto st = bus.can_status();
  bus.stop();
  ::close(peer);
  const auto lost = static_cast<long long>(n) - static_cast<long long>(consumed.load());
  std::printf("rate %.0f frames/s requested (0 = unpaced), %.0f achieved: sent %d decoded %llu consumed %llu "
              "kernel_drops %llu ring_drops %llu lost %lld\n",
              rate_hz, n / sent_s, n,
              static_cast<unsigned long long>(st.bus.counters.events_decoded),
              static_cast<unsigned long long>(consumed.load()),
              static_cast<unsigned long long>(st.can.rx_overflow),
              static_cast<unsigned long long>(st.bus.counters.events_dropped), lost);
  return lost == 0 ? 0 : 1;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 3) {
    std::fprintf(stderr, "usage: %s CONFIG {latency N | rate R N}\n", argv[0]);
    return 2;
  }
  dc::CanConfig cfg = dc::load_can_config(argv[1]);
  if (const char* rcvbuf = std::getenv("NCCOMP_BENCH_RCVBUF_BYTES"); rcvbuf != nullptr && *rcvbuf != 0) {
    cfg.socket_rcvbuf_bytes = static_cast<std::uint32_t>(std::strtoul(rcvbuf, nullptr, 10));
  }
  std::printf("socket_rcvbuf_bytes %u (0 = system default)\n", cfg.socket_rcvbuf_bytes);
  const std::string mode = argv[2];
  if (mode == "latency" && argc == 4) {
    return latency(std::move(cfg), std::atoi(argv[3]));
  }
  if (mode == "rate" && argc == 5) {
    return rate(std::move(cfg), std::atof(argv[3]), std::atoi(argv[4]));
  }
  std::fprintf(stderr, "usage: %s CONFIG {latency N | rate R N}\n", argv[0]);
  return 2;
}
