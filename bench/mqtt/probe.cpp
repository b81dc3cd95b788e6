// bench_mqtt_probe BROKER_URI USER PASSWORD_FILE SECONDS_AFTER_LAST OUT_JSON
// Subscribes to nccomp/+/+/measurements like the collector (persistent session, QoS 1) and, per
// row, takes its latency = arrival (CLOCK_REALTIME) − the row's utc; counts rows, duplicates
// (seq not above the last of its machine) and gaps per machine. Stops SECONDS_AFTER_LAST seconds
// after the last row arrived (or on SIGTERM) and writes a JSON summary.
#include <algorithm>
#include <atomic>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <ctime>
#include <fstream>
#include <map>
#include <mutex>
#include <nlohmann/json.hpp>
#include <string>
#include <thread>
#include <vector>

#include "tools/mqtt/mqtt_config.hpp"
#include "tools/mqtt/mqtt_link.hpp"

namespace {

std::atomic<bool> g_stop{false};
extern "C" void on_signal(int) { g_stop.store(true); }

std::int64_t real_ms() {
  timespec ts{};
  clock_gettime(CLOCK_REALTIME, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * 1000 + ts.tv_nsec / 1'000'000;
}

/// "2024-05-06T07:08:09.123Z" → ms since the epoch.
std::int64_t utc_ms(const std::string& s) {
  std::tm tm{};
  int ms = 0;
  if (std::sscanf(s.c_str(), "%d-%d-%dT%d:%d:%d.%dZ", &tm.tm_year, &tm.tm_mon, &tm.tm_mday,
                  &tm.tm_hour, &tm.tm_min, &tm.tm_sec, &ms) != 7) {
    return 0;
  }
  tm.tm_year -= 1900;
  tm.tm_mon -= 1;
  return static_cast<std::int64_t>(timegm(&tm)) * 1000 + ms;
}

}  // namespace

int main(int argc, char** argv) {
  namespace mq = nccomp::tools::mqtt;
  if (argc != 6) {
    std::fprintf(stderr, "usage: %s URI USER PASSWORD_FILE SECONDS_AFTER_LAST OUT_JSON\n", argv[0]);
    return 2;
  }
  mq::BrokerOptions b;
  b.uri = argv[1];
  b.username = argv[2];
  b.client_id = "bench-probe";
  const double quiet_s = std::atof(argv[4]);
  std::signal(SIGTERM, on_signal);
  std::signal(SIGINT, on_signal);
  std::mutex mu;
  std::vector<std::int64_t> latency_ms;
  std::map<std::string, std::uint64_t> last_seq;
  std::uint64_t rows = 0, dups = 0, gaps = 0;
  std::atomic<std::int64_t> last_arrival{0};
  mq::MqttLink link(b, mq::read_password_file(argv[3]));
  link.subscribe_on_connect("nccomp/+/+/measurements",
                            [&](const std::string& topic, const std::string& payload) {
                              const std::int64_t now = real_ms();
                              const auto j = nlohmann::json::parse(payload, nullptr, false);
                              if (!j.is_object()) return true;
                              std::lock_guard<std::mutex> lock(mu);
                              const auto seq = j.value("seq", std::uint64_t{0});
                              std::uint64_t& last = last_seq[topic];
                              if (seq <= last) {
                                ++dups;
                              } else {
                                if (last > 0 && seq > last + 1) gaps += seq - last - 1;
                                last = seq;
                                ++rows;
                                latency_ms.push_back(now - utc_ms(j.value("utc", std::string{})));
                              }
                              last_arrival.store(now);
                              return true;
                            });
  link.connect();
  while (!g_stop.load()) {
    for (const auto& e : link.wait(100)) {
      if (e.type == mq::LinkEvent::Type::kConnectionLost ||
          e.type == mq::LinkEvent::Type::kConnectFailed) {
        std::this_thread::sleep_for(std::chrono::milliseconds(500));
        link.connect();
      }
    }
    const std::int64_t last = last_arrival.load();
    if (last > 0 && static_cast<double>(real_ms() - last) > quiet_s * 1000.0) break;
  }
  link.disconnect();
  std::lock_guard<std::mutex> lock(mu);
  std::sort(latency_ms.begin(), latency_ms.end());
  const auto q = [&](double p) {
    return latency_ms.empty()
               ? 0
               : latency_ms[std::min(
                     latency_ms.size() - 1,
                     static_cast<std::size_t>(p * static_cast<double>(latency_ms.size())))];
  };
  nlohmann::json out{{"rows", rows},
                     {"duplicates", dups},
                     {"gaps", gaps},
                     {"machines", last_seq.size()},
                     {"latency_ms_p50", q(0.5)},
                     {"latency_ms_p99", q(0.99)},
                     {"latency_ms_p999", q(0.999)},
                     {"latency_ms_max", latency_ms.empty() ? 0 : latency_ms.back()}};
  std::ofstream(argv[5]) << out.dump(2) << "\n";
  std::printf("%s\n", out.dump().c_str());
  return 0;
}
