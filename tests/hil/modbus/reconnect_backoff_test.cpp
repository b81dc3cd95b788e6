// Reconnect back-off on every path (issue 17, finding 7): peers that make the driver lose its
// connection over and over, on loopback TCP and on a serial device that is not there. However the
// connection is lost, the next connect waits the back-off, which doubles from reconnect_min_s to
// reconnect_max_s and returns to reconnect_min_s only after a connection stayed healthy for
// reconnect_reset_after_s. So over a window of t seconds from start there are at most
//   1 + ceil(log2(reconnect_max_s / reconnect_min_s)) + t / reconnect_max_s
// connections (the first, one per wait below the cap, then one per capped wait), and the I/O
// thread sleeps through the waits. Before the fix a connection that had answered once was re-made
// at once: a gateway that answers reads and hangs up on writes got 28 035 connections in 10 s.
#include <gtest/gtest.h>
#include <pthread.h>
#include <sys/socket.h>
#include <time.h>

#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#include "tests/hil/modbus/hil_common.hpp"

namespace nccomp::test::modbus {
namespace {

constexpr double kMinS = 0.01;
constexpr double kMaxS = 0.2;
constexpr double kWindowS = 2.0;

/// A [modbus] header with this file's back-off (the other timings as in tcp_header).
std::string backoff_header(std::uint16_t port, const std::string& extra = "") {
  return "[modbus]\ntransport = \"tcp\"\nhost = \"127.0.0.1\"\nport = " + std::to_string(port) +
         "\npoll_rate_hz = 200\nresponse_timeout_s = 0.1\nbyte_timeout_s = 0.05\n"
         "reconnect_min_s = " +
         std::to_string(kMinS) + "\nreconnect_max_s = " + std::to_string(kMaxS) +
         "\nalarm_after_s = 0.3\n" + extra + "\n";
}

const char* const kMap = R"(
[modbus.axis]
x_mm = { table = "input", address = 0, type = "int32" }
[[modbus.offset]]
register_index = 0
address = 200
type = "int32"
)";

/// The most connections the back-off allows in `elapsed_s` from the first one (see the top).
int max_connections(double elapsed_s) {
  const int doublings = static_cast<int>(std::ceil(std::log2(kMaxS / kMinS)));
  return 1 + doublings + static_cast<int>(elapsed_s / kMaxS);
}

/// A well-formed answer to a read (function 3 / 4: zeros) or a write (function 16: the echo).
std::vector<std::uint8_t> answer(const std::vector<std::uint8_t>& req) {
  if (req.size() < 12) {
    return {};
  }
  const std::uint8_t fn = req[7];
  if (fn == 16) {
    return {req[0], req[1], 0, 0, 0, 6, req[6], 16, req[8], req[9], req[10], req[11]};
  }
  if (fn != 3 && fn != 4) {
    return {};
  }
  const auto n = static_cast<std::uint8_t>(2 * ((req[10] << 8U) | req[11]));
  std::vector<std::uint8_t> r{req[0], req[1], 0, 0, 0, static_cast<std::uint8_t>(3 + n),
                              req[6], fn,     n};
  r.resize(r.size() + n, 0);
  return r;
}

double io_thread_cpu_s(mb::ModbusBus& bus) {
  clockid_t cid{};
  EXPECT_EQ(pthread_getcpuclockid(bus.io_native_handle(), &cid), 0);
  timespec ts{};
  clock_gettime(cid, &ts);
  return static_cast<double>(ts.tv_sec) + static_cast<double>(ts.tv_nsec) * 1e-9;
}

std::optional<std::uint64_t> extra(const mb::ModbusBus& bus, std::string_view name) {
  std::array<drivers::BusCounterValue, drivers::kMaxBusExtraCounters> out{};
  const std::size_t n = bus.extra_counters(out);
  for (std::size_t i = 0; i < n; ++i) {
    if (name == out[i].name) {
      return out[i].value;
    }
  }
  return std::nullopt;
}

struct Window {
  int connections{0};
  double elapsed_s{0.0};
  double cpu_s{0.0};
};

/// Starts `bus` (an offset queued first), lets it run kWindowS against `raw`, stops it.
Window run_against(RawTcpServer& raw, mb::ModbusBus& bus) {
  push_offset(bus, 0, 12.0);
  const auto t0 = std::chrono::steady_clock::now();
  bus.start();
  std::this_thread::sleep_for(std::chrono::duration<double>(kWindowS));
  Window r;
  r.connections = raw.connections();
  r.elapsed_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  r.cpu_s = io_thread_cpu_s(bus);
  bus.stop();
  std::printf("%d connections in %.2f s (bound %d), I/O thread CPU %.3f s\n", r.connections,
              r.elapsed_s, max_connections(r.elapsed_s), r.cpu_s);
  return r;
}

void expect_backed_off(const Window& r, const mb::ModbusBus& bus) {
  EXPECT_LE(r.connections, max_connections(r.elapsed_s)) << "reconnects faster than the back-off";
  EXPECT_GE(r.connections, 4) << "the driver stopped reconnecting";
  // A thread that waits out its back-off sleeps through almost all of the window; one that
  // reconnects at once is busy all of it.
  EXPECT_LT(r.cpu_s, 0.1 * r.elapsed_s);
  const mb::ModbusStatus st = bus.modbus_status();
  EXPECT_EQ(st.connect_attempts, static_cast<std::uint64_t>(r.connections));
  // Every lost connection scheduled one wait; none of them was healthy, so it grew to the cap.
  EXPECT_GE(extra(bus, "reconnect_backoffs").value_or(0),
            static_cast<std::uint64_t>(r.connections - 1));
  EXPECT_EQ(extra(bus, "reconnect_backoff_ms"), std::optional<std::uint64_t>(200U));
}

// GIVEN a gateway that answers every read and hangs up when a write arrives (the issue's storm:
// 28 035 connections and 3.9 s CPU in 10 s) and an offset to write, WHEN the driver runs 2 s,
// THEN it reconnects on the back-off schedule and its I/O thread mostly sleeps.
TEST(ModbusHilBackoff, GatewayThatHangsUpOnWritesIsReconnectedOnTheBackOffSchedule) {
  RawTcpServer raw(answer, [](const std::vector<std::uint8_t>& req, int) {
    return req.size() >= 8 && req[7] == 16;
  });
  auto bus = make_bus(backoff_header(raw.port()) + kMap);
  const Window r = run_against(raw, *bus);
  expect_backed_off(r, *bus);
  EXPECT_GE(raw.requests(), 2 * r.connections - 1);  // each connection: a read, then the write
  EXPECT_GT(bus->modbus_status().bus.counters.frames_rx, 0U);
}

// GIVEN a peer that answers the first request of each connection and hangs up on the second
// (a gateway with a request limit), WHEN the driver runs 2 s, THEN the same bound holds.
TEST(ModbusHilBackoff, PeerThatAnswersOnceThenHangsUpIsReconnectedOnTheBackOffSchedule) {
  RawTcpServer raw(answer,
                   [](const std::vector<std::uint8_t>&, int before) { return before >= 1; });
  auto bus = make_bus(backoff_header(raw.port()) + kMap);
  const Window r = run_against(raw, *bus);
  expect_backed_off(r, *bus);
}

// GIVEN a peer that accepts and closes before answering anything, THEN the same bound holds.
TEST(ModbusHilBackoff, PeerThatHangsUpAtOnceIsReconnectedOnTheBackOffSchedule) {
  RawTcpServer raw(answer);
  raw.hang_up_on_request(true);
  auto bus = make_bus(backoff_header(raw.port()) + kMap);
  const Window r = run_against(raw, *bus);
  expect_backed_off(r, *bus);
}

// GIVEN a peer that answers the first request of each connection and garbles every later answer
// (wrong transaction id), WHEN dead_after_failures = 3 drops each connection, THEN the bound holds.
TEST(ModbusHilBackoff, PeerThatAnswersOnceThenSendsGarbageIsReconnectedOnTheBackOffSchedule) {
  RawTcpServer raw(
      RawTcpServer::ConnectionResponder([](const std::vector<std::uint8_t>& req, int before) {
        auto r = answer(req);
        if (before > 0 && !r.empty()) {
          r[1] = static_cast<std::uint8_t>(r[1] ^ 0x55U);
        }
        return r;
      }),
      nullptr);
  auto bus = make_bus(backoff_header(raw.port(), "dead_after_failures = 3") + kMap);
  const Window r = run_against(raw, *bus);
  expect_backed_off(r, *bus);
  EXPECT_GE(bus->modbus_status().bad_responses,
            static_cast<std::uint64_t>(3 * (r.connections - 1)));
}

// GIVEN a peer that answers the first request of each connection and then stays silent, WHEN
// dead_after_failures = 3 response timeouts drop each connection, THEN every drop waits the
// back-off too: it grows to the cap, as no connection was healthy (each lasts at least 3 x 0.1 s
// here, so the bound is no test of that).
TEST(ModbusHilBackoff, PeerThatAnswersOnceThenGoesSilentIsReconnectedAfterTheBackOff) {
  RawTcpServer raw(
      RawTcpServer::ConnectionResponder([](const std::vector<std::uint8_t>& req, int before) {
        return before == 0 ? answer(req) : std::vector<std::uint8_t>{};
      }),
      nullptr);
  auto bus = make_bus(backoff_header(raw.port(), "dead_after_failures = 3") + kMap);
  const Window r = run_against(raw, *bus);
  const mb::ModbusStatus st = bus->modbus_status();
  EXPECT_LE(r.connections, max_connections(r.elapsed_s));
  EXPECT_GE(r.connections, 3);
  EXPECT_GE(st.timeouts, static_cast<std::uint64_t>(3 * (r.connections - 1)));
  EXPECT_GE(st.reconnect_backoffs, static_cast<std::uint64_t>(r.connections - 1));
  EXPECT_EQ(st.reconnect_backoff_ms, 200U);
}

// GIVEN a gateway that hangs up on writes until the back-off reached its cap, WHEN it then
// behaves, THEN the back-off returns to reconnect_min_s (status: reconnect_backoff_ms 0), but only
// after the connection stayed healthy for reconnect_reset_after_s (0.4 s), not at its first answer.
TEST(ModbusHilBackoff, BackOffReturnsToTheMinimumOnlyAfterAHealthyStretch) {
  std::atomic<bool> flaky{true};
  RawTcpServer raw(answer, [&](const std::vector<std::uint8_t>& req, int) {
    return flaky.load() && req.size() >= 8 && req[7] == 16;
  });
  auto bus = make_bus(backoff_header(raw.port(), "reconnect_reset_after_s = 0.4") + kMap);
  push_offset(*bus, 0, 12.0);
  bus->start();
  ASSERT_TRUE(wait_until([&] { return extra(*bus, "reconnect_backoff_ms") == 200U; }));
  flaky.store(false);
  const auto t0 = std::chrono::steady_clock::now();
  const int c0 = raw.connections();
  ASSERT_TRUE(wait_until([&] { return extra(*bus, "reconnect_backoff_ms") == 0U; }));
  const double took = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  // One more connection (the one that stayed up), made at most one capped wait after t0.
  EXPECT_LE(raw.connections(), c0 + 1);
  EXPECT_GE(took, 0.4);
  EXPECT_EQ(bus->modbus_status().offsets_pending, 0U);
  bus->stop();
}

// GIVEN an RTU device that does not exist, THEN opening it is retried on the same schedule.
TEST(ModbusHilBackoff, MissingSerialDeviceIsRetriedOnTheBackOffSchedule) {
  auto bus = make_bus(
      "[modbus]\ntransport = \"rtu\"\ndevice = \"/dev/nccomp-no-such-tty\"\n"
      "baud = 115200\nparity = \"none\"\npoll_rate_hz = 20\n"
      "reconnect_min_s = " +
      std::to_string(kMinS) + "\nreconnect_max_s = " + std::to_string(kMaxS) + "\n" + kMap);
  const auto t0 = std::chrono::steady_clock::now();
  bus->start();
  std::this_thread::sleep_for(std::chrono::duration<double>(kWindowS));
  const mb::ModbusStatus st = bus->modbus_status();
  const double elapsed =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  bus->stop();
  EXPECT_LE(st.connect_attempts, static_cast<std::uint64_t>(max_connections(elapsed)));
  EXPECT_GE(st.connect_attempts, 4U);
  EXPECT_EQ(st.connection_errors, st.connect_attempts);
  EXPECT_EQ(st.reconnect_backoffs, st.connect_attempts);
  EXPECT_EQ(st.bus.state, drivers::LinkState::kConnecting);
}

// GIVEN a port nobody listens on (connect refused), THEN connects follow the same schedule.
TEST(ModbusHilBackoff, RefusedConnectIsRetriedOnTheBackOffSchedule) {
  std::uint16_t port = 0;
  {
    RawTcpServer gone(answer);
    port = gone.port();
  }  // closed: connects to it are refused
  auto bus = make_bus(backoff_header(port) + kMap);
  const auto t0 = std::chrono::steady_clock::now();
  bus->start();
  std::this_thread::sleep_for(std::chrono::duration<double>(kWindowS));
  const mb::ModbusStatus st = bus->modbus_status();
  const double elapsed =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  const double cpu = io_thread_cpu_s(*bus);
  bus->stop();
  EXPECT_LE(st.connect_attempts, static_cast<std::uint64_t>(max_connections(elapsed)));
  EXPECT_GE(st.connect_attempts, 4U);
  EXPECT_EQ(st.connection_errors, st.connect_attempts);
  EXPECT_LT(cpu, 0.1 * elapsed);
}

}  // namespace
}  // namespace nccomp::test::modbus
