// GIVEN a running loop and the status server, WHEN clients ask over the Unix socket and the
// Prometheus port, THEN they get the loop's numbers; the socket is mode 0660.
#include "daemon/status.hpp"

#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <thread>

#include "core/engine/ramp_module.hpp"
#include "daemon/loopback_bus.hpp"

namespace nccomp::daemon {
namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;

std::string http_get(int port, const std::string& path) {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_port = htons(static_cast<std::uint16_t>(port));
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  if (::connect(fd, reinterpret_cast<const sockaddr*>(&a), sizeof a) != 0) {
    ::close(fd);
    return {};
  }
  const std::string req = "GET " + path + " HTTP/1.0\r\n\r\n";
  (void)::send(fd, req.data(), req.size(), 0);
  std::string out;
  char buf[4096];
  ssize_t n = 0;
  while ((n = ::recv(fd, buf, sizeof buf, 0)) > 0) {
    out.append(buf, static_cast<std::size_t>(n));
  }
  ::close(fd);
  return out;
}

/// A loopback bus that also reports driver-specific counters (as the CAN and Modbus drivers do).
class CountingBus final : public drivers::Bus {
 public:
  void start() override { inner_.start(); }
  void stop() override { inner_.stop(); }
  core::rt::SpscRing<core::Event>& rx() override { return inner_.rx(); }
  core::rt::SpscRing<core::OffsetWrite>& tx() override { return inner_.tx(); }
  [[nodiscard]] drivers::BusStatus status() const override { return inner_.status(); }
  [[nodiscard]] std::size_t extra_counters(std::span<drivers::BusCounterValue> out) const override {
    const drivers::BusCounterValue values[] = {{"bus_off", 2}, {"rx_overflow", 0}};
    std::size_t n = 0;
    for (const auto& v : values) {
      if (n < out.size()) out[n++] = v;
    }
    return n;
  }

 private:
  LoopbackBus inner_{64, 64};
};

TEST(StatusServer, AnswersTextJsonAndPrometheus) {
  const fs::path dir = fs::temp_directory_path() / ("nccomp_status_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  auto rt = std::make_unique<Runtime>();
  rt->engine = std::make_unique<core::engine::Engine>();
  std::vector<std::unique_ptr<core::engine::Module>> m;
  m.push_back(std::make_unique<core::engine::RampModule>(
      core::engine::RampConfig{"ramp", "T1", 0.0, 3.0, 1000.0}));
  rt->engine->configure({{"T1", core::engine::RegisterKind::kToolLengthWear, {200.0, 5.0, 5000.0}}},
                        std::move(m));
  rt->register_bus = {0};
  core::rt::ConfigSwap<Runtime> swap(std::move(rt));
  CountingBus bus;
  bus.start();
  Loop loop(LoopOptions{}, swap, {&bus}, nullptr, nullptr);
  EventLogger logger(loop);
  logger.start();
  loop.start();

  StatusContext c;
  c.loop = &loop;
  c.buses = {{"loopback", &bus}};
  c.logger = &logger;
  c.register_names = [] { return std::vector<std::string>{"T1_length_wear"}; };
  c.config_path = "test.toml";
  c.state_path = "state.bin";
  StatusServer server(c);
  const std::string sock = (dir / "s.sock").string();
  server.start(sock, "127.0.0.1", -1);  // -1: any free port (tests)
  struct stat st {};
  ASSERT_EQ(::stat(sock.c_str(), &st), 0);
  EXPECT_EQ(st.st_mode & 0777, 0660U);
  ASSERT_GT(server.prometheus_port(), 0);

  // Wait until the ramp has reached 3 µm and the register snapshot shows it.
  std::string json;
  for (int i = 0; i < 500; ++i) {
    json = query_status(sock, "json");
    if (json.find("\"output_um\":3,") != std::string::npos) {
      break;
    }
    std::this_thread::sleep_for(10ms);
  }
  EXPECT_NE(json.find("\"name\":\"T1_length_wear\",\"output_um\":3,"), std::string::npos) << json;
  EXPECT_NE(json.find("\"buses\":[{\"name\":\"loopback\",\"state\":\"up\""), std::string::npos);
  EXPECT_NE(json.find("\"rate_hz\":1000,"), std::string::npos);
  // Driver-specific counters: all of them in JSON and metrics, only the non-zero ones in text.
  EXPECT_NE(json.find("\"counters\":{\"bus_off\":2,\"rx_overflow\":0}}"), std::string::npos)
      << json;
  const std::string text = query_status(sock, "text");
  EXPECT_NE(text.find("T1_length_wear                3.000 um"), std::string::npos) << text;
  EXPECT_NE(text.find("bus_off 2\n"), std::string::npos) << text;
  EXPECT_EQ(text.find("rx_overflow"), std::string::npos) << text;
  EXPECT_NE(query_status(sock, "bogus").find("error: unknown request 'bogus'"), std::string::npos);
  const std::string http = http_get(server.prometheus_port(), "/metrics");
  EXPECT_EQ(http.rfind("HTTP/1.0 200 OK", 0), 0U) << http;
  EXPECT_NE(http.find("nccompd_register_output_um{register=\"T1_length_wear\"} 3\n"),
            std::string::npos)
      << http;
  EXPECT_NE(http.find("nccompd_bus_up{bus=\"loopback\"} 1\n"), std::string::npos);
  EXPECT_NE(http.find("nccompd_bus_counter_total{bus=\"loopback\",counter=\"bus_off\"} 2\n"),
            std::string::npos)
      << http;
  EXPECT_EQ(http_get(server.prometheus_port(), "/other").rfind("HTTP/1.0 404", 0), 0U);

  server.stop();
  EXPECT_FALSE(fs::exists(sock));
  loop.stop();
  logger.stop();
  bus.stop();
  fs::remove_all(dir);
}

}  // namespace
}  // namespace nccomp::daemon
